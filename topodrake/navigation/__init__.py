"""Following plans: the follower state machine as batched functions and the
batched navigation engine (N cars, each following its own route)."""
