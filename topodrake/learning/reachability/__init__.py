"""The reachability estimator RE: the estimator, rollout labels, training, calibration."""
