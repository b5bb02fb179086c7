"""edge: a low-cost structured-light range finder on a pan-tilt unit."""

import os

__version__ = "0.1.0"

# One BLAS thread unless the user says otherwise. edge's matrices are small (3 × 3 rotations, a
# spot's few hundred pixels, one frame's rays); OpenBLAS's extra threads gain nothing on them and
# spin between calls, which measured here doubled the CPU time of the simulator's rendering and
# takes cores from the loop on a Pi. It must be set before numpy is first imported.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
