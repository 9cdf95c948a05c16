"""Under numba's CUDA simulator: fields binned on the device, states drawn on the device
(bit for bit the host's), host allocations of a run from a device-made state; and the
size check with a mocked free-memory value (no device needed)."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest
from click.testing import CliRunner

import flocking
import flocking.config
from flocking.backends import sizes
from flocking.checks import ParameterError
from flocking.config import RunConfig
from flocking.cli import main

TESTS = os.path.dirname(os.path.abspath(__file__))
SRC = os.path.join(os.path.dirname(TESTS), "src")

HARNESS = r"""
import json, sys, tracemalloc
import numpy as np
import flocking
import flocking.config
from flocking.backends.cuda import CUDABackend
from flocking.fields import Grid, bin_sums

def states(keys, draws):
    out = {}
    for key in keys:
        kind, dim, precision = key.split(":")
        kw = dict(box=(6.0, 4.5), delay=1) if dim == "2" else dict(box=(5.0, 4.0, 3.0))
        model = flocking.Model(n=50, dim=int(dim), seed=11, noise=0.5, **kw)
        a = CUDABackend(model, kind, precision=precision)
        b = CUDABackend(model, getattr(flocking.State, kind)(model), precision=precision)
        sa, sb = a.state, b.state
        same = bool((sa.positions == sb.positions).all() and (sa.headings == sb.headings).all())
        first = [a.polar_order_now(), b.polar_order_now()]
        steps = bool((a.advance(2) == b.advance(2)).all() and (a.state.headings == b.state.headings).all())
        out[key] = dict(same=same, steps=steps, first=first)
    if draws:
        model = flocking.Model(n=50, box=6.0, seed=4, noise=0.5)
        sim = flocking.Simulation(model, "aligned", backend="cuda")
        out["simulation"] = [sim.polar_order[0], sim.backend.name]
        ens = flocking.Ensemble([model, model.replace(seed=9)], backend="cuda")
        host = [flocking.State.random(m).polar_order() for m in ens.models]
        out["ensemble"] = [float(abs(ens._last[r] - host[r])) for r in range(2)]
    return out

FIELD_MODELS = {"2d": {}, "3d": dict(dim=3, box=5.0),
                "nematic-species": dict(alignment_rule="nematic",
                                        species=[{"fraction": 0.4}, {"fraction": 0.6, "name": "B"}])}

def fields(keys, replicas):
    out = {}
    for key in keys:
        name, precision = key.split(":")
        model = flocking.Model(**{"n": 60, "box": 6.0, "seed": 3, **FIELD_MODELS[name]})
        gpu = CUDABackend(model, "random", precision=precision)
        gpu.advance(1)
        grid = Grid.of(model, 1.4)
        sums = gpu.fields(grid)
        state = gpu.state
        oracle = bin_sums(grid, state)
        out[key] = dict(
            counts=bool((sums[:, 0] == oracle[:, 0]).all()), diff=float(np.abs(sums - oracle).max()),
            total=float(sums[:, 0].sum()),
            pol=float(np.abs(sums[:, 1:1 + model.dim].sum(axis=(0, 2)) - state.headings.sum(axis=0)).max()))
    if not replicas:
        return out
    base = flocking.Model(n=40, box=5.0, seed=1)
    ens = flocking.Ensemble([base, base.replace(seed=2)], backend="cuda")
    grid = Grid.of(base, 1.0)
    out["replicas"] = [bool(np.array_equal(ens.replica(r).fields(grid)[:, 0],
                                           bin_sums(grid, ens.states[r])[:, 0])) for r in range(2)]
    return out

def allocations(n):
    # host memory a cuda run from a device-made state allocates, leaving out the
    # simulator's own arrays (which stand for the device's)
    model = flocking.Model(n=n, density=1.0, seed=2)
    tracemalloc.start(12)
    sim = flocking.Simulation(model, "random", backend="cuda", history=False)
    snap = tracemalloc.take_snapshot()
    tracemalloc.stop()
    host = snap.filter_traces([tracemalloc.Filter(False, "*numba/cuda/simulator/*", all_frames=True)])
    traces = host.statistics("traceback")
    return dict(total=sum(s.size for s in traces), largest=max(s.size for s in traces), phi=sim.polar_order[0])

def copies():
    # states copied in pieces of 7 particles equal those copied whole, bit for bit; and
    # the host's peak while copying N = 1024 stays near the states' own bytes
    import flocking.backends.cuda as backend
    out = {}
    base = flocking.Model(n=50, box=6.0, seed=5, noise=0.5, speeds="uniform")
    ens = flocking.Ensemble([base, base.replace(seed=6)], backend="cuda", precision="float32")
    backend.COPY_CHUNK = 1 << 20
    whole = ens._engine.states()
    backend.COPY_CHUNK = 7
    pieces = ens._engine.states()
    out["same"] = all(bool((a.positions == b.positions).all() and (a.headings == b.headings).all()
                           and (a.speeds == b.speeds).all()) for a, b in zip(whole, pieces))
    backend.COPY_CHUNK = 128
    gpu = CUDABackend(flocking.Model(n=1024, density=1.0, seed=2), "random")
    tracemalloc.start()
    state = gpu.state
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    own = state.positions.nbytes + state.headings.nbytes
    out["peak"] = [peak, own]
    return out

def stubbed(n):
    # the host's side of a run of N from a device-made state, with the kernels' launches
    # made no-ops and the simulator's device arrays put in memory that tracemalloc does not
    # trace (anonymous maps, standing for the device's): the peak it traces is then all the
    # host allocates, freed or not
    import mmap
    import numba.cuda as numba_cuda
    import numba.cuda.simulator.kernel as simulated_kernel
    from numba.cuda.simulator.cudadrv.devicearray import FakeCUDAArray

    def device(shape, dtype):
        dtype = np.dtype(dtype)
        size = int(np.prod(shape, dtype=np.int64)) * dtype.itemsize
        return np.ndarray(shape, dtype, buffer=mmap.mmap(-1, max(size, 1)))

    def to_device(ary, stream=0, copy=True, to=None):
        a = np.asarray(ary)
        out = to._ary if to is not None else device(a.shape, a.dtype)
        np.copyto(out, a)
        return to if to is not None else FakeCUDAArray(out)

    CUDABackend(flocking.Model(n=20, box=4.0, delay=2), "random")  # kernels compiled, module globals made
    numba_cuda.device_array = lambda shape, dtype=np.float64, strides=None, order="C", stream=0: \
        FakeCUDAArray(device(shape, dtype))
    numba_cuda.to_device = to_device
    launched = set()
    simulated_kernel.FakeCUDAKernel.__call__ = lambda self, *args: launched.add(self.fn.__name__)
    out = {}
    for name, kw in (("plain", {}), ("delay", dict(delay=2))):
        model = flocking.Model(n=n, density=1.0, seed=2, **kw)
        tracemalloc.start()
        sim = flocking.Simulation(model, "random", backend="cuda", history=False)
        sim.run(3)
        out[name] = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
        del sim
    out["launched"] = sorted(launched)
    return out

job = json.loads(sys.argv[1])
out = {}
if "states" in job:
    out["states"] = states(*job["states"])
if "fields" in job:
    out["fields"] = fields(*job["fields"])
if "copies" in job:
    out["copies"] = copies()
if "stubbed" in job:
    out["stubbed"] = stubbed(job["stubbed"])
if "allocations" in job:
    CUDABackend(flocking.Model(n=20, box=4.0), "random")  # kernels compiled, module globals made
    out["allocations"] = {str(n): allocations(n) for n in job["allocations"]}
print("RESULT" + json.dumps(out))
"""


def simulate(*jobs: dict) -> dict:
    """``HARNESS`` on each job in its own subprocess under the simulator, side by side."""
    env = {**os.environ, "NUMBA_ENABLE_CUDASIM": "1", "PYTHONPATH": SRC}
    procs = [subprocess.Popen([sys.executable, "-c", HARNESS, json.dumps(job)], env=env, text=True,
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE) for job in jobs]
    out = {}
    for proc in procs:
        stdout, stderr = proc.communicate(timeout=900)
        lines = [line for line in stdout.splitlines() if line.startswith("RESULT")]
        assert proc.returncode == 0 and lines, stderr[-3000:]
        out.update(json.loads(lines[-1][len("RESULT"):]))
    return out


#: the default suite's states and fields (kind:dim:precision, model:precision); the other
#: combinations run in the slow stage (``-m slow``), where CI runs them on every change
STATES = ["random:2:float64", "aligned:3:float32"]
MORE_STATES = [f"{k}:{d}:{p}" for k in ("random", "aligned") for d in (2, 3) for p in ("float64", "float32")
               if f"{k}:{d}:{p}" not in STATES]
FIELDS = ["2d:float64", "nematic-species:float32"]
MORE_FIELDS = [f"{n}:{p}" for n in ("2d", "3d", "nematic-species") for p in ("float64", "float32")
               if f"{n}:{p}" not in FIELDS]


@pytest.fixture(scope="module")
def simulated():
    return simulate({"states": [STATES, True]}, {"fields": [FIELDS, True], "copies": True})


@pytest.fixture(scope="module")
def simulated_more():
    return simulate({"states": [MORE_STATES, False]}, {"fields": [MORE_FIELDS, False]})


def check_state(got: dict) -> None:
    assert got["same"] and got["steps"]
    assert got["first"][0] == got["first"][1]


@pytest.mark.parametrize("key", STATES)
def test_device_made_state_is_the_hosts_bit_for_bit(simulated, key):
    check_state(simulated["states"][key])


@pytest.mark.slow
@pytest.mark.parametrize("key", MORE_STATES)
def test_more_device_made_states_are_the_hosts_bit_for_bit(simulated_more, key):
    check_state(simulated_more["states"][key])


def test_simulation_and_ensemble_draw_on_the_device(simulated):
    phi, name = simulated["states"]["simulation"]
    assert name == "cuda" and abs(phi - 1.0) < 1e-12
    assert max(simulated["states"]["ensemble"]) < 1e-14


def check_fields(got: dict, key: str) -> None:
    assert got["counts"] and got["total"] == 60.0
    assert got["diff"] < (1e-12 if key.endswith("float64") else 1e-5)  # float32: the state is renormalised
    assert got["pol"] < (1e-12 if key.endswith("float64") else 1e-5)


@pytest.mark.parametrize("key", FIELDS)
def test_device_fields_equal_the_oracle(simulated, key):
    check_fields(simulated["fields"][key], key)


@pytest.mark.slow
@pytest.mark.parametrize("key", MORE_FIELDS)
def test_more_device_fields_equal_the_oracle(simulated_more, key):
    check_fields(simulated_more["fields"][key], key)


def test_states_come_back_in_pieces_bit_for_bit(simulated):
    """Pieces of 7 particles (replicas of 50, per-particle speeds) give the states a whole
    copy gives; copying 1024 particles in pieces of 128 peaks below 1.5 times the states'
    own arrays (a whole copy held the slot-order arrays beside them: twice)."""
    got = simulated["copies"]
    assert got["same"]
    peak, own = got["peak"]
    assert peak < 1.5 * own


def test_ensemble_replicas_fields_on_the_device(simulated):
    assert simulated["fields"]["replicas"] == [True, True]


@pytest.mark.slow
def test_device_made_run_allocates_no_array_of_n_on_the_host():
    """At 4096 and 512 particles (the simulator's threads make larger N take minutes under
    tracemalloc) the host holds a few kilobytes, the same at both sizes: none of N."""
    got = simulate({"allocations": [512, 4096]})["allocations"]
    small, large = got["512"], got["4096"]
    assert large["largest"] < 4 * 4096 / 4  # below a quarter of an int32 array of N
    assert large["total"] - small["total"] < 4 * (4096 - 512) / 8  # not growing as N


def test_a_million_particle_run_allocates_no_array_of_n_on_the_host():
    """N = 10**6 drawn on the device and 3 steps, with and without a delay, the launches
    made no-ops (the simulator would take hours to run them): at its peak the host holds
    tens of kilobytes, none of them N-sized (the cell starts, the sort's status words and
    the delay ring were host arrays of N or more copied over: 6 MB at the peak, before they
    were zeroed on the device); the launches are those of drawing, zeroing, sorting and
    stepping."""
    got = simulate({"stubbed": 10**6})["stubbed"]
    assert got["plain"] < 10**6 / 16 and got["delay"] < 10**6 / 16
    assert {"draw_state", "fill", "scatter", "step"} <= set(got["launched"])


# -- the size check ---------------------------------------------------------------------

def test_bytes_per_particle_follow_the_engines_arrays():
    model = flocking.Model(n=10**6, box=1000.0)
    assert sizes.per_particle(model, "float64") == 2 * (2 * 2 * 8 + 4) + 16 + 1
    assert sizes.per_particle(model, "float32") == 2 * (2 * 2 * 4 + 4) + 16 + 1
    assert sizes.per_particle(model.replace(delay=3), "float64") == 89 + 3 * 3 * 8
    assert sizes.per_particle(model.replace(speeds="uniform"), "float32") == 57 + 8
    assert sizes.device_bytes([model] * 4, "float64") >= 4 * 89 * 10**6


def test_size_check_refuses_in_one_line_naming_the_largest_n():
    model = flocking.Model(n=10**7, box=3000.0)
    free = 2**29
    with pytest.raises(ParameterError) as err:
        sizes.check_device([model], "float64", free=free)
    text = str(err.value)
    assert "\n" not in text and text.startswith("n: 10000000 particles (2D, float64) need")
    fit = int(text.split("at most ")[1].split(" ")[0])
    fit32 = int(text.split("float32: at most ")[1].rstrip(")"))
    assert sizes.device_bytes([flocking.Model(n=fit, box=3000.0)], "float64") <= sizes.USABLE * free
    # conservative by at most the cell starts (4 bytes a cell, cells <= N)
    assert sizes.device_bytes([flocking.Model(n=int(fit * 1.05), box=3000.0)], "float64") > sizes.USABLE * free
    assert fit32 > 1.4 * fit
    sizes.check_device([flocking.Model(n=fit, box=3000.0)], "float64", free=free)  # what it names fits
    with pytest.raises(ParameterError, match=r"^n: 8 replicas of 10000000 particles .* particles a replica fit$"):
        sizes.check_device([model] * 8, "float32", free=8 * free)
    sizes.check_device([model] * 10**3, "float64", free=0)  # unknown free memory: no check


def test_cli_and_ensemble_refuse_what_the_card_cannot_hold(monkeypatch, tmp_path):
    monkeypatch.setattr(sizes, "device_free", lambda: 4 * 2**30)
    monkeypatch.setattr(flocking.config, "available_memory", lambda: 2**50)  # the host holds it
    out = tmp_path / "o"
    result = CliRunner().invoke(main, ["run", "--backend", "cuda", "--n", "100000000", "--density", "1",
                                       "--out", str(out)])
    assert result.exit_code == 2 and len(result.output.strip().splitlines()) == 1
    assert "need 8.66 GiB on the GPU, more than the 4 GiB free: at most" in result.output
    assert "(float32: at most" in result.output and not out.exists()
    with pytest.raises(ParameterError, match="particles a replica fit"):
        flocking.Ensemble([flocking.Model(n=10**8, density=1.0, seed=s) for s in range(3)], backend="cuda")


def test_host_check_names_the_largest_n():
    cfg = RunConfig.from_dict({"n": 10**6})
    with pytest.raises(ParameterError, match=r"^n: 1000000 particles need about .* available: at most about \d+ fit$"):
        cfg.check_memory(available=10**7)
