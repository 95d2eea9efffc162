"""The waypoint network C_WP: training (CPU; GPU at scale), policies, noisy oracle, evaluation."""
