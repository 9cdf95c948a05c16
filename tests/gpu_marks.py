"""Whether the tests can reach CUDA, and the skip marks that follow from it (one answer for
every test module).

``SIMULATOR``: numba's CUDA simulator is on in this process, so the cuda backend runs
(slowly) without a device. ``DEVICE``: a real NVIDIA GPU is there (never with the
simulator on).
"""

from __future__ import annotations

import os

import pytest

SIMULATOR = os.environ.get("NUMBA_ENABLE_CUDASIM") == "1"


def _device() -> bool:
    if SIMULATOR:
        return False
    try:
        from numba import cuda

        return bool(cuda.is_available())
    except Exception:  # noqa: BLE001 - any failure to reach a device means no device
        return False


DEVICE = _device()
#: the cuda backend can run here, on a device or in the simulator
CUDA_RUNS = DEVICE or SIMULATOR

#: a test that needs a real GPU
gpu = pytest.mark.skipif(not DEVICE, reason="needs an NVIDIA GPU with numba-cuda")
#: a test of what happens where the cuda backend cannot run
no_gpu = pytest.mark.skipif(CUDA_RUNS, reason="a GPU is present")
