"""edge: a low-cost structured-light range finder on a pan-tilt unit."""

__version__ = "0.1.0"
