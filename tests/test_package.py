"""What importing edge does to the process, before any of its modules run."""

from __future__ import annotations

import os
import subprocess
import sys

SHOW = "import edge, os; print(os.environ['OPENBLAS_NUM_THREADS'])"


def test_edge_runs_numpy_on_one_blas_thread_unless_the_user_says_otherwise():
    env = {k: v for k, v in os.environ.items() if k != "OPENBLAS_NUM_THREADS"}
    ours = subprocess.run([sys.executable, "-c", SHOW], env=env, capture_output=True, text=True, check=True)
    theirs = subprocess.run([sys.executable, "-c", SHOW], env={**env, "OPENBLAS_NUM_THREADS": "4"},
                            capture_output=True, text=True, check=True)
    assert (ours.stdout.strip(), theirs.stdout.strip()) == ("1", "4")
