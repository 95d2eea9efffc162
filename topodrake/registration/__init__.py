"""Scan registration: batched 2-D ICP between lidar scans and the
teach-and-repeat controller that follows taught scans by registering
against them (no training)."""
