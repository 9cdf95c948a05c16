"""A script run once per thread count, for the tests that a run does not depend on it."""

import os
import subprocess
import sys

import numpy as np

import flocking

SRC = os.path.dirname(os.path.dirname(flocking.__file__))  # this checkout's src/, for subprocesses


def results_by_threads(script: str, folder, counts=("1", "2")) -> list[np.ndarray]:
    """The array ``script`` saves to the path it is given (``sys.argv[1]``), from a fresh
    process for each ``NUMBA_NUM_THREADS`` of ``counts``."""
    results = []
    for threads in counts:
        env = dict(os.environ, NUMBA_NUM_THREADS=threads, PYTHONPATH=SRC)
        path = os.path.join(folder, f"t{threads}.npy")
        subprocess.run([sys.executable, "-c", script, path], check=True, env=env)
        results.append(np.load(path))
    return results
