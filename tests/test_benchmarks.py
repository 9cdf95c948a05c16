"""The benchmark scripts that need a GPU still run: each is exercised on a tiny system under
numba's CUDA simulator (in a subprocess, since the simulator must be on before numba is
imported), so a change to the engine that breaks one is seen without a GPU."""

from __future__ import annotations

import ctypes
import importlib
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numba
import pytest

ROOT = Path(__file__).resolve().parents[1]

ANATOMY = r"""
import sys
import numpy as np
sys.path.insert(0, "benchmarks")
import cuda_anatomy
import flocking
from flocking.backends.cuda import Engine

model = flocking.Model(n=64, density=2.0, noise=1.0, seed=3, delay=2)
state = flocking.State.random(model)
# the launches of a step, made one by one, are the step that advance() takes
one, other = Engine([model], [state], graphs=False), Engine([model], [state], graphs=False)
names = [name for name, _ in one.launches()]
for _ in range(3):
    for _, launch in one.launches():
        launch()
other.advance(3)
a, b = one.states()[0], other.states()[0]
assert (a.positions == b.positions).all() and (a.headings == b.headings).all()
cuda_anatomy.STEPS, cuda_anatomy.REPEATS = 1, 1
cuda_anatomy.anatomy("tiny", one, steps=1)
print("NAMES", " ".join(names))
"""


@pytest.mark.slow
def test_cuda_anatomy_times_the_launches_that_make_a_step():
    """``Engine.launches`` (which ``benchmarks/cuda_anatomy.py`` times one by one) made in
    turn is bit for bit the step that ``advance`` takes, and the script reports each."""
    env = {**os.environ, "NUMBA_ENABLE_CUDASIM": "1", "PYTHONPATH": str(ROOT / "src")}
    out = subprocess.run([sys.executable, "-c", ANATOMY], cwd=ROOT, env=env, capture_output=True, text=True,
                         timeout=600)
    assert out.returncode == 0, out.stderr[-3000:]
    names = next(line for line in out.stdout.splitlines() if line.startswith("NAMES")).split()[1:]
    assert names[:2] == ["step", "digits"] and names[-2:] == ["gather", "finish"]
    assert all(name.startswith("scatter") for name in names[2:-2]) and len(names) > 4
    report = next(line for line in out.stdout.splitlines() if line.startswith("tiny: M = 64"))
    assert "host launches" in report


@pytest.mark.slow
def test_same_process_compares_a_tree_with_itself(tmp_path):
    """``benchmarks/same_process.py`` imports a tree twice under names of its own and
    reports, per copy, the case's rate against the plain model, and the speed of the plain
    model and of the case against the first copy (1 for the first; timings of a tiny system
    say nothing more)."""
    out = subprocess.run([sys.executable, "benchmarks/same_process.py", "src", "src", "--cases", "vision 2.1",
                          "--n", "3000", "--rounds", "3", "--steps", "1"], cwd=ROOT, capture_output=True,
                         text=True, timeout=900, env={**os.environ, "NUMBA_CACHE_DIR": str(tmp_path)})
    assert out.returncode == 0, out.stderr[-3000:]
    rows = [line.split() for line in out.stdout.splitlines() if line.startswith("src ")]
    plain = [row for row in rows if row[1] == "plain"]
    cases = [row for row in rows if row[1:3] == ["vision", "2.1"]]
    assert len(rows) == 4 and len(plain) == 2 and len(cases) == 2
    assert float(plain[0][-1]) == 1.0 and float(cases[0][-1]) == 1.0
    assert float(plain[1][-1]) > 0.0 and float(cases[1][-1]) > 0.0
    assert all(float(row[5]) > 0.0 for row in cases)
    bad = subprocess.run([sys.executable, "benchmarks/same_process.py", "src", "--cases", "gravity"], cwd=ROOT,
                         capture_output=True, text=True, timeout=120)
    assert bad.returncode == 2 and "--cases: 'gravity' is not one of" in bad.stderr
    same = subprocess.run([sys.executable, "benchmarks/same_process.py", "src", "--cases", "vision 2.1", "--n",
                           "3000", "--rounds", "2", "--steps", "1", "--same-state", "3"], cwd=ROOT,
                          capture_output=True, text=True, timeout=900,
                          env={**os.environ, "NUMBA_CACHE_DIR": str(tmp_path)})
    assert same.returncode == 0, same.stderr[-3000:]
    assert "every round from the state of 'vision 2.1' after 3 steps" in same.stdout
    assert [line.split()[1:3] for line in same.stdout.splitlines() if line.startswith("src ")] == [
        ["plain", "speed"], ["vision", "2.1"]]
    bad = subprocess.run([sys.executable, "benchmarks/same_process.py", "src", "--same-state", "-1"], cwd=ROOT,
                         capture_output=True, text=True, timeout=120)
    assert bad.returncode == 2 and bad.stderr.strip().splitlines()[-1].endswith(
        "--same-state: -1 is not a number of steps (0 or more)")


def bench_module(name):
    """The script ``benchmarks/<name>.py``, imported."""
    sys.path.insert(0, str(ROOT / "benchmarks"))
    try:
        return importlib.import_module(name)
    finally:
        sys.path.remove(str(ROOT / "benchmarks"))


def test_same_process_takes_case_names_that_hold_commas():
    """``--cases`` splits on commas, but a name such as "walls, cone, chirality, field"
    is taken whole (the longest known name first), and an unknown one is named alone."""
    split_cases = bench_module("same_process").split_cases
    known = bench_module("bench_extensions").cases(1000, 2.0)
    assert split_cases("walls,walls, cone, chirality, field,two species, coupling", known) == \
        ["walls", "walls, cone, chirality, field", "two species, coupling"]
    assert split_cases(" cohesion ", known) == ["cohesion"]
    with pytest.raises(ValueError, match="^gravity$"):
        split_cases("walls,gravity,cohesion", known)


@pytest.fixture(scope="module")
def jit_code(tmp_path_factory):
    """A function compiled by numba, what ``jit_profile.dump_code`` returned, the regions
    ``jit_profile.regions`` read back, and the one of them that holds the function."""
    jit_profile = bench_module("jit_profile")
    twice = numba.cfunc("float64(float64)")(lambda x: 2.0 * x + 1.0)
    folder = str(tmp_path_factory.mktemp("code"))
    written = jit_profile.dump_code(folder)
    found = jit_profile.regions(folder)
    holding = next(r for r in found if r[0] <= twice.address < r[0] + r[1])
    return jit_profile, twice, written, found, holding


def test_jit_profile_dumps_the_code_that_numba_compiled(jit_code):
    """``dump_code`` writes every anonymous executable region: one holds the compiled
    function, byte for byte as it is in memory, and ``regions`` reads them back."""
    _, twice, written, found, (start, _, path) = jit_code
    assert twice.ctypes(3.0) == 7.0
    assert [region[:2] for region in found] == sorted(written)
    with open(path, "rb") as f:
        f.seek(twice.address - start)
        assert f.read(32) == ctypes.string_at(twice.address, 32)


def test_jit_profile_counts_samples_per_region_and_block():
    jit_profile = bench_module("jit_profile")
    found = [(0x1000, 0x800, "a"), (0x4000, 0x100, "b")]
    addresses = [0x1000, 0x10FF, 0x1100, 0x17FF, 0x1800, 0x40FF, 0x4100, 0x0]
    assert jit_profile.per_region(addresses, found) == {0x1000: 4, 0x4000: 1}
    assert jit_profile.per_block(addresses, 0x1000, 0x800) == {0x000: 2, 0x100: 1, 0x700: 1}
    assert jit_profile.per_block(addresses, 0x1000, 0x800, width=0x400) == {0x000: 3, 0x400: 1}


@pytest.mark.skipif(shutil.which("objdump") is None, reason="objdump (binutils) is not installed")
def test_jit_profile_lists_the_sampled_instruction_with_its_share(jit_code):
    """The listing of the region holding the function has a line at the function's first
    instruction, which carries the share of the samples given there (3 of 4)."""
    jit_profile, twice, _, _, (start, _, path) = jit_code
    lines = jit_profile.listing(path, start, [twice.address] * 3 + [start - 1], total=4)
    first = next(line for line in lines if int(line.split()[1], 16) == twice.address - start)
    assert first.split()[0] == "75.00"
    assert sum(float(line.split()[0]) for line in lines) == 75.0


def test_jit_profile_runs_a_case_and_dumps_its_code(tmp_path, capsys):
    jit_profile = bench_module("jit_profile")
    jit_profile.run("plain", warm=1, steps=2, n=300, dim=2, folder=str(tmp_path))
    out = capsys.readouterr().out.splitlines()
    assert out[0].startswith("plain: ") and out[0].endswith("particle-steps/s over 2 steps after 1")
    assert out[1] == f"{len(jit_profile.regions(str(tmp_path)))} regions of code written to {tmp_path}"
    assert jit_profile.regions(str(tmp_path))
