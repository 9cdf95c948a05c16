"""The LLVM intrinsics compile for whatever target numba compiles for.

A form of an intrinsic that the target lacks does not raise: LLVM aborts the process. So
each target is compiled in a subprocess of its own (``NUMBA_CPU_NAME`` and
``NUMBA_CPU_FEATURES`` set as a portable cache sets them), and a bad choice is a failed test
here rather than a dead process for a user.
"""

import os
import platform
import subprocess
import sys
import textwrap

import pytest
from llvmlite.binding import llvm_version_info

from flocking.backends import intrinsics

X86 = platform.machine().lower() in ("x86_64", "amd64", "i686", "x86")
BASE = "+64bit,+cmov,+cx8,+cx16,+fxsr,+mmx,+sse,+sse2,+sse3,+ssse3,+sse4.1,+sse4.2,+popcnt,+sahf"
AVX2 = BASE + ",+avx,+avx2,+bmi,+bmi2,+f16c,+fma,+lzcnt,+movbe,+xsave"
#: name -> (NUMBA_CPU_NAME, NUMBA_CPU_FEATURES or None for numba's default, the form chosen)
TARGETS = {
    "generic": ("generic", None, "select"),
    "avx2": ("haswell", AVX2 + ",-avx512f,-avx512vl", "avx2"),
    "avx512": ("skylake-avx512", AVX2 + ",+avx512f,+avx512vl,+avx512bw,+avx512dq,+avx512cd",
               "avx512" if llvm_version_info >= (19,) else "avx2"),
}

# every intrinsic in one kernel, compiled eagerly (for its signature) at import; run only
# where this machine has the target's features
KERNEL = textwrap.dedent("""
    import sys
    import numba
    import numpy as np
    from flocking.backends import intrinsics as X

    form = sys.argv[1]
    compress = X.compress4 if form == "chosen" else X.compress_intrinsic(form)

    @numba.njit("float64[:](float64[:], boolean[:], int64[:], float64[:, :, :])")
    def kernel(v, b, counter, ring):
        X.prefetch(ring, 0, 1)
        t = compress(v[0], v[1], v[2], v[3], b[0], b[1], b[2], b[3])
        m = X.mask4(b[0], b[1], b[2], b[3])
        old = X.fetch_add(counter)
        return np.array([t[0], t[1], t[2], t[3], float(m), float(old), float(counter[0])])

    print(X.COMPRESS, flush=True)
    if sys.argv[2] == "run":
        out = kernel(np.array([1.5, -2.0, 3.0, 4.0]), np.array([False, True, True, False]),
                     np.zeros(1, np.int64), np.zeros((2, 2, 1)))
        print(" ".join(repr(float(x)) for x in out))
""")


def host_runs(features: str) -> bool:
    return intrinsics.enabled(features) <= intrinsics.enabled(intrinsics.get_host_cpu_features())


def compile_for(target, form, tmp_path, run):
    name, features, _ = TARGETS[target]
    env = dict(os.environ, NUMBA_CPU_NAME=name, NUMBA_CACHE_DIR=str(tmp_path))
    env.pop("NUMBA_CPU_FEATURES", None)
    if features is not None:
        env["NUMBA_CPU_FEATURES"] = features
    env["PYTHONPATH"] = os.pathsep.join([os.path.join(os.path.dirname(__file__), "..", "src"),
                                         env.get("PYTHONPATH", "")])
    return subprocess.run([sys.executable, "-c", KERNEL, form, "run" if run else "compile"], env=env,
                          capture_output=True, text=True, timeout=300)


@pytest.mark.skipif(not X86, reason="the x86 targets are compiled on x86 machines")
@pytest.mark.parametrize("target", sorted(TARGETS))
def test_every_intrinsic_compiles_for_the_target_numba_compiles_for(target, tmp_path):
    features = TARGETS[target][1]
    run = features is None or host_runs(features)
    done = compile_for(target, "chosen", tmp_path, run)
    assert done.returncode == 0, done.stderr[-2000:]
    lines = done.stdout.split("\n")
    assert lines[0] == TARGETS[target][2]
    if run:
        # the compress keeps lanes 1 and 2, the mask is 0b0110, the counter went 0 -> 1
        assert lines[1] == "-2.0 3.0 0.0 0.0 6.0 0.0 1.0"


@pytest.mark.skipif(not X86, reason="the x86 targets are compiled on x86 machines")
def test_the_permutation_compiled_for_a_generic_target_is_what_aborts(tmp_path):
    # why the choice must follow the target: this form on a machine without AVX2 kills the
    # process inside LLVM (no Python error), as NUMBA_CPU_NAME=generic did before
    done = compile_for("generic", "avx2", tmp_path, run=False)
    assert done.returncode != 0
    assert "LLVM ERROR" in done.stderr


def test_the_target_is_numbas_not_the_hosts(monkeypatch):
    # NUMBA_CPU_NAME=generic sets NUMBA_CPU_FEATURES to "" (the architecture's baseline):
    # an empty string is the target's features, not a reason to read the host's
    monkeypatch.setattr(intrinsics.numba.core.config, "CPU_FEATURES", "")
    monkeypatch.setattr(intrinsics, "get_host_cpu_features", lambda: "+avx2,+avx512f,+avx512vl")
    assert intrinsics.target_features() == ""
    assert intrinsics.compress_form(intrinsics.target_features(), (22, 1, 0)) == "select"
    monkeypatch.setattr(intrinsics.numba.core.config, "CPU_FEATURES", None)
    assert intrinsics.compress_form(intrinsics.target_features(), (22, 1, 0)) == "avx512"


def test_a_form_the_module_does_not_have_is_refused():
    with pytest.raises(ValueError, match="form: must be one of"):
        intrinsics.compress_intrinsic("neon")


def test_the_prefetch_is_named_for_the_pointers_llvmlite_writes():
    from llvmlite import ir

    typed = str(ir.IntType(8).as_pointer()) == "i8*"
    assert intrinsics.PREFETCH == ("llvm.prefetch.p0i8" if typed else "llvm.prefetch.p0")


@pytest.mark.slow
@pytest.mark.skipif(not X86, reason="the x86 targets are compiled on x86 machines")
@pytest.mark.parametrize("target", ["generic", "avx2"])
def test_a_cohesion_run_compiled_for_a_portable_target_gives_the_same_bits(target, tmp_path):
    # the whole kernel with every intrinsic (cohesion notes through the compress; a delay
    # prefetches its ring), compiled for the target as a cluster's shared cache would be:
    # it runs, and its trajectory is bit for bit the one compiled for this machine
    script = textwrap.dedent("""
        import hashlib, sys
        import numpy as np
        from flocking import Model, Simulation, State
        model = Model(n=3000, box=20.0, noise=0.4, seed=3, cohesion=0.8, delay=2)
        sim = Simulation(model, State.random(model), backend="cpu")
        sim.run(6)
        s = sim.state
        print(hashlib.sha256(s.positions.tobytes() + s.headings.tobytes()).hexdigest())
    """)
    if not host_runs(TARGETS[target][1] or ""):
        pytest.skip("this machine cannot run the target's code")
    here = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=900,
                          env=dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "host")))
    assert here.returncode == 0, here.stderr[-2000:]
    name, features, _ = TARGETS[target]
    env = dict(os.environ, NUMBA_CPU_NAME=name, NUMBA_CACHE_DIR=str(tmp_path / target))
    env.pop("NUMBA_CPU_FEATURES", None)
    if features is not None:
        env["NUMBA_CPU_FEATURES"] = features
    there = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=900, env=env)
    assert there.returncode == 0, there.stderr[-2000:]
    assert there.stdout == here.stdout
