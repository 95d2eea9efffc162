"""The follower's contract: context frames, routes, and the C_WP and RE protocols.

The networks, the map and the follower import this package, not each other.
"""
