"""Baselines the topological navigation is compared with (SPTM)."""
