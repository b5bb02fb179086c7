"""Drivers for the rig's parts, each behind a small interface (``edge.hw.base``) with a real and a
simulated backend chosen by configuration."""
