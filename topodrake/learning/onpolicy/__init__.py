"""The follower's own states: on-policy samples, DAgger, and RE labelled and calibrated there."""
