"""The CUDA backend against the reference, under numba's CUDA simulator (no GPU needed).

The simulator must be switched on before numba is imported, so every simulated case
runs in one subprocess with ``NUMBA_ENABLE_CUDASIM=1`` (the harness below); each test
then checks one case's result. Tests marked ``gpu`` need a real device and skip cleanly
without one.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time

import numpy as np
import pytest

import flocking
from flocking.backends.reference import ReferenceBackend
from gpu_marks import gpu, no_gpu
from test_extensions import EXTENSIONS

TESTS = os.path.dirname(os.path.abspath(__file__))
SRC = os.path.join(os.path.dirname(TESTS), "src")

#: name -> (model keywords, steps, precision); small systems, a few steps each
CASES = {
    "2d": (dict(), 2, "float64"),
    "2d-delay": (dict(delay=2), 3, "float64"),
    "2d-topological-rectangular": (dict(neighbours="topological", k=3, box=(4.0, 6.5)), 2, "float64"),
    "2d-clustered": (dict(box=8.0, noise=0.2), 2, "float64"),
    "3d-topological-delay": (dict(dim=3, neighbours="topological", k=4, delay=2), 3, "float64"),
    "2d-float32": (dict(), 2, "float32"),
}

#: more cases, each option already covered above in another combination (``-m slow``: the
#: simulator takes minutes for all of them on two cores)
MORE_CASES = {
    "2d-box-below-3R": (dict(box=2.5, radius=1.0), 2, "float64"),
    # one species with its own speed: no extension, and the speed is the state's, not model.speed
    "2d-one-species-speed": (dict(species=[{"fraction": 1.0, "speed": 0.3}]), 2, "float64"),
    "2d-vectorial-forward": (dict(noise_type="vectorial", update="forward"), 2, "float64"),
    "2d-alignment-uniform-speeds": (dict(alignment=0.5, speeds="uniform"), 2, "float64"),
    "2d-later-step": (dict(noise_type="vectorial", noise=0.8), 1, "float64"),
    "3d": (dict(dim=3), 2, "float64"),
    "3d-vectorial-forward-alignment": (dict(dim=3, noise_type="vectorial", update="forward",
                                            alignment=0.3), 2, "float64"),
    "3d-box-below-3R": (dict(dim=3, box=(2.5, 5.0, 2.0)), 2, "float64"),
    "3d-float32-topological-vectorial": (dict(dim=3, neighbours="topological", k=4,
                                              noise_type="vectorial"), 2, "float32"),
}

#: extension cases of tests/test_extensions.py as ``name:dim:precision``, each against the
#: reference under the simulator: every extension in 2D, in the default run ...
EXTENDED = ["all-with-delay:2:float64", "topological:2:float64", "all-with-delay:2:float32"]
#: ... and every other combination with ``-m slow``
MORE_EXTENDED = [f"{name}:{dim}:float64" for dim in (2, 3) for name in EXTENSIONS
                 if f"{name}:{dim}:float64" not in EXTENDED and not (dim == 3 and name == "chirality")] + [
    "topological:3:float32", "obstacles:3:float32"]

#: datasets of the sort test (see ``sorts`` in the harness)
SORTS = ["one-cell", "three-crowded-cells", "random-12-bit"]

HARNESS = r"""
import json, sys, tempfile, os, warnings
import numpy as np
import flocking
from flocking.backends.cuda import CUDABackend, radix_sort
from flocking.backends.reference import ReferenceBackend
from numba.cuda.simulator.cudadrv import devicearray

def nonnegative(access):
    # the simulator indexes device arrays with NumPy, where -1 is the last element:
    # make a negative index (out of bounds on a GPU) raise as one past the end does
    def checked(self, idx, *value):
        for i in idx if isinstance(idx, tuple) else (idx,):
            if isinstance(i, (int, np.integer)) and i < 0:
                raise IndexError(f"negative index {idx} into a device array")
        return access(self, idx, *value)
    return checked

devicearray.FakeCUDAArray.__getitem__ = nonnegative(devicearray.FakeCUDAArray.__getitem__)
devicearray.FakeCUDAArray.__setitem__ = nonnegative(devicearray.FakeCUDAArray.__setitem__)

def start(name, model):
    state = flocking.State.random(model)
    if name == "2d-clustered":  # every particle in one cell: no capacity may overflow
        state.positions = 0.3 + 0.6 * (state.positions / np.asarray(model.box))
    if name == "2d-later-step":  # a state other than the initial one, at step 1
        ref = ReferenceBackend(model, state)
        ref.advance(1)
        state = ref.state
    return state

def same_state(a, b):
    return bool((a.positions == b.positions).all() and (a.headings == b.headings).all()
                and (a.speeds == b.speeds).all() and a.step == b.step)

def cases(spec):
    out = {}
    for name, (kw, steps, precision) in spec.items():
        model = flocking.Model(**{"n": 40, "box": 5.0, "noise": 1.0, "seed": 7, **kw})
        state = start(name, model)
        gpu = CUDABackend(model, state, precision=precision)
        phi = gpu.advance(steps)
        ref = ReferenceBackend(model, state)
        phi_ref = ref.advance(steps)
        a, b = gpu.state, ref.state
        res = dict(
            dh=float(np.abs(a.headings - b.headings).max()),
            dp=float(np.abs(a.positions - b.positions).max()),
            dphi=float(np.abs(phi - phi_ref).max()),
            ds=float(np.abs(a.speeds - b.speeds).max()),
            step=[gpu.step, a.step, b.step],
            unit=float(np.abs(np.linalg.norm(a.headings, axis=1) - 1).max()),
            inside=bool(((a.positions >= 0) & (a.positions < np.asarray(model.box))).all()),
        )
        if name == "2d-clustered":  # the same run again, bit for bit
            again = CUDABackend(model, state, precision=precision)
            res["repeat"] = bool((again.advance(steps) == phi).all()
                                 and (again.state.headings == a.headings).all())
        out[name] = res
    return out

def ensemble(name, base, variants, precision, steps=3, more=2):
    # each replica against the same model alone, bit for bit; then a replica's
    # checkpoint continued alone against the ensemble continued
    models = [base.replace(**v) for v in variants]
    ens = flocking.Ensemble(models, backend="cuda", precision=precision)
    phi = ens.advance(steps)
    alone = [CUDABackend(m, flocking.State.random(m), precision=precision) for m in models]
    res = {"phi": [bool((phi[r] == b.advance(steps)).all()) for r, b in enumerate(alone)],
           "state": [same_state(ens.states[r], b.state) for r, b in enumerate(alone)],
           "memory": [sorted(m) == sorted(b.memory()) and all((m[k] == b.memory()[k]).all() for k in m)
                      for m, b in zip(ens.memory(), alone)]}
    path = os.path.join(tempfile.mkdtemp(), "replica.npz")
    last = len(models) - 1
    ens.replica(last).save_checkpoint(path)
    sim = flocking.Simulation.load_checkpoint(path)
    sim.run(more)
    phi_more = ens.advance(more)
    a, b = sim.state, ens.states[last]
    res["resumed"] = bool(same_state(a, b) and (np.asarray(sim.polar_order[1:]) == phi_more[last]).all())
    res["resumed_dh"] = float(np.abs(a.headings - b.headings).max())
    res["resumed_backend"] = sim.backend.name
    return res

def safety(kw, precision):
    # NaN, infinite and huge coordinates: no kernel may go out of bounds, and every
    # other particle takes the reference's step; then a NaN heading on top (whose
    # particle's position turns NaN), for three steps. (The reference sums headings with
    # a matrix product, in which one NaN heading spoils every sum: not compared there.)
    model = flocking.Model(**{"n": 40, "box": 5.0, "noise": 1.0, "seed": 7, **kw})
    state = flocking.State.random(model)
    bad = [[np.nan, 1.0], [np.inf, -np.inf], [1e300, -1e300], [2.0, np.nan], [-1e300, 3.0]]
    for i, p in enumerate(bad):
        state.positions[i] = p
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        gpu = CUDABackend(model, state, precision=precision)
        gpu.advance(1)
        ref = ReferenceBackend(model, state)
        ref.advance(1)
        a, b = gpu.state, ref.state
        state.headings[len(bad)] = [np.nan, np.nan]
        worse = CUDABackend(model, state, precision=precision)
        worse.advance(3)
    rest = slice(len(bad), None)
    return dict(dh=float(np.abs(a.headings - b.headings)[rest].max()),
                dp=float(np.abs(a.positions - b.positions)[rest].max()), step=worse.step,
                nan_heading=bool(np.isnan(worse.state.positions[len(bad)]).any()))

def sorts(shape, names, scale):
    # records (cell << 32 | slot) in any order: sorted stably by cell, however crowded
    rng = np.random.default_rng(1)
    data = {"one-cell": (np.zeros(300 * scale, dtype=np.int64), 1),
            "three-crowded-cells": (rng.choice([5, 9, 700], 500 * scale, p=[0.7, 0.2, 0.1]), 12),
            "random-12-bit": (rng.integers(0, 4096, 700 * scale), 12)}
    out = {}
    for name in names:
        keys, bits = data[name]
        rec = (keys.astype(np.uint64) << np.uint64(32)) | rng.permutation(len(keys)).astype(np.uint64)
        got = radix_sort(rec, bits, shape)
        out[name] = bool((got == rec[np.argsort(rec >> np.uint64(32), kind="stable")]).all())
    return out

def extended(names):
    # each extension case of tests/test_extensions.py (60 particles), one step at a time
    # from the oracle's state, against the reference: every difference, moments included
    sys.path.insert(0, TESTS)
    from test_extensions import sized
    from flocking.space import Space

    out = {}
    for key in names:
        name, dim, precision = key.split(":")
        # about 3 neighbours each in the 6^d box
        model = sized(name, int(dim), 60 if dim == "2" else 120)
        state = flocking.State.random(model)
        worst = dict(dp=0.0, dh=0.0, dphi=0.0, dmoments=0.0)
        inside, outside = True, False
        for _ in range(2):
            gpu, ref = CUDABackend(model, state, precision=precision), ReferenceBackend(model, state)
            phi, phi_ref = gpu.advance(1), ref.advance(1)
            a, b = gpu.state, ref.state
            d = a.positions - b.positions
            box, periodic = np.asarray(model.box), ~np.asarray(model.walls)
            d = np.where(periodic, d - box * np.round(d / box), d)
            for key_, value in (("dp", d), ("dh", a.headings - b.headings), ("dphi", phi - phi_ref),
                                ("dmoments", gpu.moments - ref.moments)):
                worst[key_] = max(worst[key_], float(np.abs(value).max()))
            inside &= bool(((a.positions >= 0) & (a.positions <= box)).all())
            outside |= bool(Space.of(model).in_obstacle(a.positions).any())
            state = b
        out[key] = dict(worst, inside=inside, in_obstacle=outside,
                        width=[list(gpu.moments.shape), list(ref.moments.shape)])
    return out

def extended_ensemble():
    # replicas with their own chirality, field strength, noise and seed (one species set,
    # one coupling, walls, a cone): each bit for bit what it gives alone, and the
    # observables an ensemble run records per species and nematic order from its sums
    base = flocking.Model(n=40, box=5.0, noise=1.0, boundary="wall,periodic", vision=2.5,
                          species=[{"fraction": 0.5}, {"fraction": 0.5, "noise": 0.4}],
                          coupling=[[1.0, -1.0], [0.5, 1.0]], alignment_rule="nematic", field=[0.0, 1.0])
    models = [base.replace(seed=1, chirality=0.2), base.replace(seed=2, field_strength=0.3, noise=2.0)]
    ens = flocking.Ensemble(models, backend="cuda")
    phi = ens.advance(3)
    moments = ens._engine.moments
    alone = [CUDABackend(m, flocking.State.random(m)) for m in models]
    res = {"phi": [bool((phi[r] == b.advance(3)).all()) for r, b in enumerate(alone)],
           "moments": [bool((moments[r] == b.moments).all()) for r, b in enumerate(alone)],
           "state": [same_state(ens.states[r], b.state) for r, b in enumerate(alone)]}
    ens = flocking.Ensemble(models, backend="cuda")
    writers = [[flocking.ObservablesWriter(os.path.join(tempfile.mkdtemp(), "o.csv"))] for _ in models]
    ens.run(2, writers)
    res["columns"] = open(writers[0][0].path).readline().strip().split(",")
    # every extension switched off: bit for bit the plain model
    plain = flocking.Model(n=40, box=5.0, noise=0.8, seed=2)
    off = plain.replace(boundary="periodic", obstacles=[], vision=np.pi, alignment_rule="polar", chirality=0.0,
                        field_strength=0.0, coupling=[[1.0]], species=[{"fraction": 1.0}])
    a, b = CUDABackend(plain, flocking.State.random(plain)), CUDABackend(off, flocking.State.random(off))
    res["off_is_plain"] = bool((a.advance(3) == b.advance(3)).all()) and same_state(a.state, b.state)
    return res

job = json.loads(sys.argv[1])
out = {}
if "extended" in job:
    out["extended"] = extended(job["extended"])
if "extended_ensemble" in job:
    out["extended_ensemble"] = extended_ensemble()
if "cases" in job:
    out["cases"] = cases(job["cases"])
if "ensembles" in job:
    out["ensembles"] = {}
    if "2d" in job["ensembles"]:
        base = flocking.Model(n=40, box=5.0, noise=1.0, seed=7)
        out["ensembles"]["2d"] = ensemble(
            "2d", base, [dict(seed=3), dict(seed=4, noise=2.5, alignment=0.6, speed=0.3, delay=2),
                         dict(seed=5, speeds="uniform", delay=1)], "float64")
    if "3d-topological-float32" in job["ensembles"]:
        base = flocking.Model(dim=3, n=40, box=5.0, noise=1.0, neighbours="topological", k=4)
        out["ensembles"]["3d-topological-float32"] = ensemble(
            "3d", base, [dict(seed=1, delay=1), dict(seed=2, noise=0.3)], "float32", 2, 1)
if "safety" in job:
    out["safety"] = {"metric": safety({}, "float64"),
                     "topological-float32": safety(dict(neighbours="topological", k=3), "float32")}
if "sorts" in job:
    out["sorts"] = sorts(tuple(job["sorts"]["shape"]), job["sorts"]["names"], job["sorts"]["scale"])
print("RESULT" + json.dumps(out))
"""


def simulate(*jobs: dict) -> dict:
    """Run ``HARNESS`` on each job under numba's CUDA simulator, each in its own subprocess,
    all at once (the simulator runs on one core); the results of all jobs in one dict."""
    env = {**os.environ, "NUMBA_ENABLE_CUDASIM": "1", "PYTHONPATH": SRC}
    harness = f"TESTS = {TESTS!r}\n" + HARNESS
    procs = [subprocess.Popen([sys.executable, "-c", harness, json.dumps(job)], env=env, text=True,
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE) for job in jobs]
    out = {}
    for proc in procs:
        stdout, stderr = proc.communicate(timeout=600)
        lines = [line for line in stdout.splitlines() if line.startswith("RESULT")]
        assert proc.returncode == 0 and lines, stderr[-3000:]
        for key, value in json.loads(lines[-1][len("RESULT"):]).items():
            out.setdefault(key, {}).update(value)
    return out


@pytest.fixture(scope="module")
def simulated():
    """Every simulated check of the default run, in two subprocesses side by side."""
    return simulate({"cases": CASES, "safety": True},
                    {"ensembles": ["2d"], "sorts": {"shape": [16, 4, 16], "names": SORTS, "scale": 1}})


@pytest.fixture(scope="module")
def simulated_more():
    return simulate({"cases": MORE_CASES}, {"ensembles": ["3d-topological-float32"]})


@pytest.mark.parametrize("name", CASES)
def test_simulated_run_matches_reference(simulated, name):
    check_case(simulated["cases"][name], name, *CASES[name])


@pytest.mark.slow
@pytest.mark.parametrize("name", MORE_CASES)
def test_more_simulated_runs_match_reference(simulated_more, name):
    check_case(simulated_more["cases"][name], name, *MORE_CASES[name])


def check_case(res: dict, name: str, kw: dict, steps: int, precision: str) -> None:
    """A simulated run of ``steps`` steps against the reference from the same state."""
    # float64: the same formulas in the same order, so rounding alone (a few ulp per step);
    # float32: single-precision rounding of positions ~5 and headings ~1
    tol_h, tol_p = (1e-12, 1e-12) if precision == "float64" else (2e-5, 2e-5)
    assert res["dh"] < tol_h and res["dphi"] < tol_h and res["dp"] < tol_p
    assert res["ds"] < (1e-15 if precision == "float64" else 1e-7)
    first = 1 if name == "2d-later-step" else 0
    assert res["step"] == [first + steps] * 3
    assert res["unit"] < (1e-14 if precision == "float64" else 1e-15)
    assert res["inside"]


@pytest.fixture(scope="module")
def simulated_extended():
    """The default extension cases and the extended ensemble, in two subprocesses (each
    about 15 s alone on the project's machine)."""
    return simulate({"extended": EXTENDED}, {"extended_ensemble": True})


@pytest.fixture(scope="module")
def simulated_more_extended():
    half = len(MORE_EXTENDED) // 2
    return simulate({"extended": MORE_EXTENDED[:half]}, {"extended": MORE_EXTENDED[half:]})


def check_extended(res: dict, key: str) -> None:
    """One step at a time against the reference from the same state: positions, headings,
    polar order and the moment sums (per species, nematic products) to rounding; no
    particle beyond a wall or inside an obstacle."""
    tol = 1e-12 if key.endswith("float64") else 2e-5
    assert res["dp"] < tol and res["dh"] < tol and res["dphi"] < tol
    assert res["dmoments"] < (1e-10 if key.endswith("float64") else 2e-3)
    assert res["width"][0] == res["width"][1]
    assert res["inside"] and not res["in_obstacle"]


@pytest.mark.parametrize("key", EXTENDED)
def test_simulated_extensions_match_reference(simulated_extended, key):
    check_extended(simulated_extended["extended"][key], key)


@pytest.mark.slow
@pytest.mark.parametrize("key", MORE_EXTENDED)
def test_more_simulated_extensions_match_reference(simulated_more_extended, key):
    check_extended(simulated_more_extended["extended"][key], key)


def test_simulated_extended_replicas_equal_single_runs(simulated_extended):
    """Replicas with their own chirality, field strength, noise and seed give bit for bit
    what each gives alone (polar order, moment sums, state), and an ensemble run records
    each species' polar order and the nematic order."""
    res = simulated_extended["extended_ensemble"]
    assert all(res["phi"]) and all(res["moments"]) and all(res["state"])
    assert res["columns"][-3:] == ["polar_order_A", "polar_order_B", "nematic_order"]


def test_simulated_extensions_switched_off_are_bitwise_the_plain_model(simulated_extended):
    assert simulated_extended["extended_ensemble"]["off_is_plain"]


def test_simulated_clustered_run_is_deterministic(simulated):
    assert simulated["cases"]["2d-clustered"]["repeat"]


ENSEMBLES = ["2d", pytest.param("3d-topological-float32", marks=pytest.mark.slow)]


def simulated_ensemble(request, name: str) -> dict:
    """The simulated ensemble ``name``: 2D in the default run, 3D with ``-m slow``."""
    fixture = "simulated" if name == "2d" else "simulated_more"
    return request.getfixturevalue(fixture)["ensembles"][name]


@pytest.mark.parametrize("name", ENSEMBLES)
def test_simulated_ensemble_replicas_equal_single_runs(request, name):
    """Each replica (its own seed, noise, alignment, speed, speed rule, delay) gives bit
    for bit what its model gives alone: polar order, state and delay memory."""
    res = simulated_ensemble(request, name)
    assert all(res["phi"]) and all(res["state"]) and all(res["memory"])


@pytest.mark.parametrize("name", ENSEMBLES)
def test_simulated_replica_checkpoint_continues_alone(request, name):
    """A replica's checkpoint, loaded by Simulation.load_checkpoint on the cuda backend
    and run on, takes exactly the steps the ensemble takes in float64. In float32 the
    checkpoint holds the state as ``state`` gives it (float64, headings renormalised), so
    the continued run agrees to float32 rounding only."""
    res = simulated_ensemble(request, name)
    assert res["resumed_backend"] == "cuda"
    if name.endswith("float32"):
        assert res["resumed_dh"] < 1e-5
    else:
        assert res["resumed"]


@pytest.mark.parametrize("name", ["metric", "topological-float32"])
def test_simulated_broken_coordinates_stay_in_bounds(simulated, name):
    """NaN, infinite and 1e300 coordinates run without an out-of-bounds access (the
    simulator raises on an index past the end, and the harness on a negative one) and leave every other particle the reference's step; a NaN
    heading on top runs three steps too."""
    res = simulated["safety"][name]
    tol = 1e-12 if name == "metric" else 2e-5
    assert res["dh"] < tol and res["dp"] < tol
    assert res["step"] == 3 and res["nan_heading"]


@pytest.mark.parametrize("name", SORTS)
def test_simulated_radix_sort_orders_by_cell_then_input(simulated, name):
    """The sort alone: records end up sorted by cell, stably, however crowded the cells
    (up to three tiles of 256 and three passes of 4 bits in the simulator's shape)."""
    assert simulated["sorts"][name]


@pytest.mark.slow
def test_simulated_radix_sort_in_the_gpu_shape():
    """The sort in the launch shape of a real GPU (256 threads, 8-bit digits, tiles of
    2048): 2000 records in two tiles, two passes, 1400 of them in one cell (about 20 s
    under the simulator)."""
    res = simulate({"sorts": {"shape": [256, 8, 8], "names": ["three-crowded-cells"], "scale": 4}})
    assert res["sorts"] == {"three-crowded-cells": True}


def test_precision_is_validated():
    model = flocking.Model(n=10, box=3.0, noise=1.0)
    from flocking.backends.cuda import CUDABackend

    with pytest.raises(flocking.ParameterError, match=r"^precision: must be 'float64' or 'float32' \(got 'half'\)$"):
        CUDABackend(model, flocking.State.random(model), precision="half")


@no_gpu
def test_no_gpu_gives_one_line_error(tmp_path):
    from click.testing import CliRunner

    from flocking.cli import main

    result = CliRunner().invoke(main, ["run", "--backend", "cuda", "--n", "20", "--box", "4",
                                       "--noise", "1", "--steps", "2", "--out", str(tmp_path / "r"), "-q"])
    assert result.exit_code == 2
    assert "needs an NVIDIA GPU with numba-cuda" in result.output
    assert "Traceback" not in result.output
    assert not (tmp_path / "r" / "trajectory.gsd").exists()


# -- real device --------------------------------------------------------------------

@pytest.mark.gpu
@gpu
@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("neighbours", ["metric", "topological"])
def test_device_step_matches_reference(dim, neighbours):
    from flocking.backends.cuda import CUDABackend

    model = flocking.Model(dim=dim, n=1500, density=2.0, noise=1.0, neighbours=neighbours, seed=4)
    state = flocking.State.random(model)
    gpu_backend, ref = CUDABackend(model, state), ReferenceBackend(model, state)
    for _ in range(3):
        gpu_backend.advance(1)
        ref.advance(1)
        assert np.abs(gpu_backend.state.headings - ref.state.headings).max() < 1e-12


def device_extension_cases():
    cases = [(name, dim, "float64") for dim in (2, 3) for name in EXTENSIONS if (name, dim) != ("chirality", 3)]
    return cases + [("all-with-delay", 2, "float32"), ("topological", 3, "float32")]


@pytest.mark.gpu
@gpu
@pytest.mark.parametrize(("name", "dim", "precision"), device_extension_cases())
def test_device_extensions_match_reference(name, dim, precision):
    """Every extension case of tests/test_extensions.py on the device against the
    reference, one step at a time from the reference's state (1500 particles; in the
    box-below-3R case all of them in a box 2.6 wide), moment sums included."""
    from flocking.backends.cuda import CUDABackend
    from flocking.space import Space
    from test_extensions import assert_same_state, sized

    box = {} if name == "box-below-3R" else {"box": 20.0 if dim == 2 else 8.0}
    model = sized(name, dim, 1500, **box)
    tol, tol_moments = (1e-12, 1e-9) if precision == "float64" else (2e-5, 5e-3)
    state = flocking.State.random(model)
    for _ in range(3):
        gpu_backend, ref = CUDABackend(model, state, precision=precision), ReferenceBackend(model, state)
        np.testing.assert_allclose(gpu_backend.advance(1), ref.advance(1), rtol=0, atol=tol)
        np.testing.assert_allclose(gpu_backend.moments, ref.moments, rtol=0, atol=tol_moments)
        assert_same_state(gpu_backend.state, ref.state, model, tol)
        positions = gpu_backend.state.positions
        assert ((positions >= 0) & (positions <= np.asarray(model.box))).all()
        assert not Space.of(model).in_obstacle(positions).any()
        state = ref.state


@pytest.mark.gpu
@gpu
def test_device_statistics_match_cpu():
    """Ordered phase, 2D: the mean polar order of the two backends agrees within the
    run-to-run spread (different seeds, so independent runs)."""
    from flocking.backends.cpu import CPUBackend
    from flocking.backends.cuda import CUDABackend

    means = {}
    for name, cls in (("cpu", CPUBackend), ("cuda", CUDABackend)):
        runs = []
        for seed in range(4):
            model = flocking.Model(n=4000, density=2.0, noise=1.0, seed=seed + (100 if name == "cuda" else 0))
            backend = cls(model, flocking.State.random(model))
            runs.append(backend.advance(600)[300:].mean())
        means[name] = (np.mean(runs), np.std(runs, ddof=1) / 2)
    (a, ea), (b, eb) = means["cpu"], means["cuda"]
    assert abs(a - b) < 4 * np.hypot(ea, eb) + 1e-3


@pytest.mark.gpu
@gpu
def test_device_float32_throughput():
    """At least 1e8 particle-steps/s at N = 1e6 in float32 (the target at 1e7 is 1e9)."""
    from flocking.backends.cuda import CUDABackend

    model = flocking.Model(n=1_000_000, density=2.0, noise=1.0, seed=1)
    backend = CUDABackend(model, flocking.State.random(model), precision="float32")
    backend.advance(5)
    t0 = time.perf_counter()
    backend.advance(50)
    rate = 50 * model.n / (time.perf_counter() - t0)
    assert rate > 1e8


@pytest.mark.gpu
@gpu
@pytest.mark.parametrize("kw", [dict(), dict(delay=3), dict(dim=3, neighbours="topological", k=7)])
def test_device_graphs_equal_host_launches(kw):
    """Replaying the captured CUDA graph takes bit for bit the steps of host launches
    (more steps than the device's polar-order table holds, so it wraps)."""
    from flocking.backends.cuda import CUDABackend

    model = flocking.Model(**{"n": 20_000, "density": 2.0, "noise": 1.0, "seed": 5, **kw})
    state = flocking.State.random(model)
    a, b = CUDABackend(model, state), CUDABackend(model, state, graphs=False)
    steps = a._engine.rows + 7
    assert (a.advance(steps) == b.advance(steps)).all()
    assert a._engine._graph is not None, "no CUDA graph was captured on this device"
    assert (a.state.headings == b.state.headings).all() and (a.state.positions == b.state.positions).all()


@pytest.mark.gpu
@gpu
def test_device_radix_sort_of_crowded_cells():
    """A million records, half of them in one cell, a fifth in three others: sorted
    stably by cell (many tiles, three passes)."""
    from flocking.backends.cuda import radix_sort

    rng = np.random.default_rng(2)
    m = 1_000_000
    keys = np.where(rng.random(m) < 0.5, 12345, rng.integers(0, 2**20, m))
    keys[rng.random(m) < 0.2] = rng.choice([7, 99, 2**20 - 1])
    rec = (keys.astype(np.uint64) << np.uint64(32)) | rng.permutation(m).astype(np.uint64)
    assert (radix_sort(rec, 20) == rec[np.argsort(rec >> np.uint64(32), kind="stable")]).all()


@pytest.mark.gpu
@gpu
def test_device_ensemble_replicas_equal_single_runs():
    from flocking.backends.cuda import CUDABackend

    base = flocking.Model(n=1024, density=2.0, noise=1.0)
    models = [base.replace(seed=s, noise=0.5 + s, delay=s % 3, alignment=1.0 - 0.1 * s) for s in range(5)]
    ens = flocking.Ensemble(models, precision="float32")
    phi = ens.advance(40)
    for r, model in enumerate(models):
        alone = CUDABackend(model, flocking.State.random(model), precision="float32")
        assert (alone.advance(40) == phi[r]).all()
        assert (alone.state.headings == ens.states[r].headings).all()


@pytest.mark.gpu
@gpu
def test_device_sort_costs_the_same_however_crowded():
    """Sorting 4e6 records all in one cell takes no longer than sorting them spread over
    2**21 cells (within 1.5x; the per-cell insertion sort it replaced was quadratic in
    the crowding)."""
    from flocking.backends.cuda import radix_sort

    rng = np.random.default_rng(3)
    m = 4_000_000
    slots = rng.permutation(m).astype(np.uint64)
    times = []
    for keys in (rng.integers(0, 2**21, m), np.full(m, 2**20)):
        rec = (keys.astype(np.uint64) << np.uint64(32)) | slots
        radix_sort(rec, 21)  # compile
        t0 = time.perf_counter()
        radix_sort(rec, 21)
        times.append(time.perf_counter() - t0)
    assert times[1] < 1.5 * times[0]
