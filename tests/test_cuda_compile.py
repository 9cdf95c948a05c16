"""The CUDA kernels compile for a real GPU (sm_90 PTX) without one.

numba's CUDA simulator (tests/test_cuda.py) runs the kernels as Python, so it cannot see a
kernel that a GPU's compiler would refuse (a type numba-cuda cannot lower, a Python
feature a device function lacks). Here every kernel goes through numba's CUDA compiler
and NVVM to PTX, for the plain model and for one with every extension compiled in; the
test skips where NVVM (the CUDA toolkit's libnvvm) is not installed.
"""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from gpu_marks import SIMULATOR

#: what each script starts with: sm_90 without a device, and an exit where NVVM is missing
PREAMBLE = r"""
import sys, types
import numba.cuda.dispatcher as dispatcher
from numba import cuda
# device functions ask the current device for its compute capability: there is none
dispatcher.get_current_device = lambda: types.SimpleNamespace(compute_capability=(9, 0))
from flocking.backends import cuda_kernels
from flocking.backends.cuda_sort import Launch
from flocking.backends.features import Features
try:
    cuda.compile_ptx(lambda a: None, "void(float64[:])", cc=(9, 0))
except Exception as err:
    print("NO-NVVM", type(err).__name__, err)
    sys.exit(0)
"""

SCRIPT = PREAMBLE + r"""
precision, dim, k, extended = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), sys.argv[4] == "1"
features = Features(True, True, True, True, True) if extended else Features()
species = 2 if extended else 1
kernels = cuda_kernels.build(precision, dim, k, Launch(256, 8, 8), features, species)
for name, signature in cuda_kernels.signatures(precision, dim, species).items():
    kernel = getattr(kernels.sort if name in ("digits", "scatter") else kernels, name)
    ptx, _ = cuda.compile_ptx(kernel.py_func, signature, cc=(9, 0))
    assert ".entry" in ptx, name
    if name == "step":
        no_delay = ptx
    if precision == "float32" and name == "step":
        # float32 kernels do their per-particle arithmetic in float32: the only doubles
        # are the random numbers' 53-bit fractions, converted once each
        assert ptx.count("cvt.rn.f32.f64") >= 1 and "sqrt.rn.f64" not in ptx, "a float64 square root"
# the device's zeroing of the cell starts, the sort's status and the delay ring
from flocking.backends import cuda_init
for dtype in ("int32", "int64", precision):
    ptx, _ = cuda.compile_ptx(cuda_init.filler().py_func, f"void({dtype}[::1], int64)", cc=(9, 0))
    assert ".entry" in ptx, dtype
# the step of a delayed model (the ring read before the neighbour search) compiles too
delayed = cuda_kernels.build(precision, dim, k, Launch(256, 8, 8), features, species, True)
ptx, _ = cuda.compile_ptx(delayed.step.py_func, cuda_kernels.signatures(precision, dim, species)["step"], cc=(9, 0))
assert ".entry" in ptx and ptx != no_delay, "the delayed step"
print("COMPILED")
"""

CASES = [("float32", 2, 0, False), ("float64", 3, 7, True)]
MORE = [(p, d, k, e) for p in ("float64", "float32") for d in (2, 3) for k in (0, 7) for e in (False, True)
        if (p, d, k, e) not in CASES]


def compiled(script: str, *args: str) -> str:
    """Run ``script`` (:data:`PREAMBLE` and more) in a process without the simulator; its
    output, once it has printed ``COMPILED`` (a skip where NVVM is missing)."""
    if SIMULATOR:
        pytest.skip("the CUDA simulator is on in this process")
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_ENABLE_CUDASIM"}
    out = subprocess.run([sys.executable, "-c", script, *args], capture_output=True, text=True, env=env, timeout=900)
    if "NO-NVVM" in out.stdout:
        pytest.skip(f"no NVVM here to compile CUDA kernels ({out.stdout.strip()[8:][:120]})")
    assert out.returncode == 0 and "COMPILED" in out.stdout, out.stdout[-2000:] + out.stderr[-4000:]
    return out.stdout


def compile_case(precision, dim, k, extended):
    compiled(SCRIPT, precision, str(dim), str(k), "1" if extended else "0")


@pytest.mark.parametrize("precision, dim, k, extended", CASES)
def test_kernels_compile_for_sm90(precision, dim, k, extended):
    compile_case(precision, dim, k, extended)


@pytest.mark.slow
@pytest.mark.parametrize("precision, dim, k, extended", MORE)
def test_every_kernel_variant_compiles_for_sm90(precision, dim, k, extended):
    compile_case(precision, dim, k, extended)


GATHER = PREAMBLE + r"""
import subprocess, tempfile
# the plain model's gather; then that of two species with a coupling and nematic alignment,
# as bench_cuda.py's cases "extensions" and "extensions-but-cohesion" compile it (cohesion
# adds nothing to the gather)
every = Features(extended=True, coupling=True, nematic=True, cone=True)
for label, features, species, precision, dim in (
        [("plain", Features(), 1, p, d) for p in ("float32", "float64") for d in (2, 3)]
        + [("extended", every, 2, "float32", 2)]):
    kernels = cuda_kernels.build(precision, dim, 0, Launch(256, 8, 8), features, species)
    signature = cuda_kernels.signatures(precision, dim, species)["gather"]
    ptx, _ = cuda.compile_ptx(kernels.gather.py_func, signature, cc=(9, 0))
    with tempfile.NamedTemporaryFile("w", suffix=".ptx") as f:
        f.write(ptx)
        f.flush()
        out = subprocess.run(["ptxas", "-arch=sm_90", "-v", f.name, "-o", "/dev/null"], capture_output=True,
                             text=True).stderr
    print(label, precision, dim, out.replace("\n", " "))
print("COMPILED")
"""


def test_gathers_fit_32_registers():
    """The gather, a copy bound by memory, runs faster with every warp slot of an SM filled:
    at most 32 registers a thread, without spilling to local memory, as before the rewrite
    (ptxas, sm_90): the plain model's in both precisions and dimensions, and the 2D float32
    one of two species. Computing the slot before zeroing the block's sums took the plain
    one to 38-40 (2D float32 steps 1.5 % slower on an H200), a species look-up that looped
    at run time took the extended one to 40."""
    import re
    import shutil

    if shutil.which("ptxas") is None:
        pytest.skip("no ptxas (the CUDA toolkit) here")
    reports = [line for line in compiled(GATHER).splitlines() if line.startswith(("plain", "extended"))]
    assert len(reports) == 5
    for line in reports:
        assert int(re.search(r"Used (\d+) registers", line).group(1)) <= 32, line[:80]
        assert "0 bytes spill stores" in line and "0 bytes spill loads" in line, line[:80]
