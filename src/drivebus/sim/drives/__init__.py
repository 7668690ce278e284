"""Simulated twins of the seed drives, one module per family."""
