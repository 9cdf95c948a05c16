"""Memory: GSD frames written without copies are the frames gsd.hoomd writes, and a run
with a trajectory stays well under 120 bytes a particle."""

import json
import os
import tracemalloc

import gsd.hoomd
import numpy as np
import pytest

import flocking
from flocking import GSDWriter, Model, Simulation, State
from flocking.state import frame_arrays
from flocking.trajectory import PARAMETERS_KEY
from flocking.writers import Writer


class HoomdWriter(Writer):
    """The oracle: each frame built from ``sim.state`` and appended with gsd.hoomd."""

    def __init__(self, path, every, mode="w"):
        self.path, self.every, self.mode = path, every, mode
        self._file = None

    def begin(self, sim):
        self._file = gsd.hoomd.open(self.path, mode=self.mode)
        self._last = int(self._file[-1].configuration.step) if len(self._file) else None

    def write(self, sim):
        if self._last is not None and sim.step <= self._last:
            return
        state, model = sim.state, sim.model
        frame = gsd.hoomd.Frame()
        frame.configuration.step = state.step
        frame.configuration.dimensions = model.dim
        box = np.array([1.0, 1.0, 1.0, 0.0, 0.0, 0.0])
        box[: model.dim] = model.box
        frame.configuration.box = box
        frame.particles.N = state.n
        frame.particles.types = ["A"]
        frame.particles.typeid = np.zeros(state.n, dtype=np.uint32)
        frame.particles.position, frame.particles.velocity = frame_arrays(state, model.box)
        if len(self._file) == 0:
            frame.log[PARAMETERS_KEY] = np.frombuffer(json.dumps(sim.parameters()).encode(), dtype=np.uint8)
        self._file.append(frame)
        self._file.flush()
        self._last = state.step

    def close(self):
        self._file.close()


def _run_both(tmp_path, model, state, backend, mode):
    sim = Simulation(model, state, backend)
    ours, oracle = tmp_path / "ours.gsd", tmp_path / "oracle.gsd"
    sim.writers += [GSDWriter(ours, 3, mode=mode), HoomdWriter(oracle, 3, mode=mode)]
    sim.run(7)
    return sim, ours, oracle


CASES = {
    "2d": (Model(n=500, density=1.0, seed=3), "random", "cpu"),
    "3d-uniform-speeds": (Model(dim=3, n=400, density=1.0, speeds="uniform", seed=4), "random", "cpu"),
    # no noise, aligned: every frame's velocities equal frame 0's, so that chunk is left out
    "2d-still-velocities": (Model(n=300, density=1.0, noise=0.0, seed=5), "aligned", "cpu"),
    "3d-reference": (Model(dim=3, n=60, box=3.0, seed=6), "random", "reference"),
}


@pytest.mark.parametrize("threaded", [False, True], ids=["in-line", "threaded"])
@pytest.mark.parametrize("case", CASES)
def test_gsd_frames_are_those_gsd_hoomd_writes_fresh_and_appended(tmp_path, case, threaded, monkeypatch):
    if threaded:  # every frame written by the writer's thread, as large ones are
        monkeypatch.setattr(GSDWriter, "threaded_from", 0)
    model, init, backend = CASES[case]
    state = getattr(State, init)(model)
    sim, ours, oracle = _run_both(tmp_path, model, state, backend, "w")
    # appended: steps 7..14, step 7 already in both files
    sim.writers[:] = [GSDWriter(ours, 3, mode="a"), HoomdWriter(oracle, 3, mode="a")]
    sim.run(7)
    assert ours.read_bytes() == oracle.read_bytes()
    with gsd.hoomd.open(ours) as a, gsd.hoomd.open(oracle) as b:
        assert [f.configuration.step for f in a] == [0, 3, 6, 7, 9, 12, 14]
        assert len(a) == len(b)
        for fa, fb in zip(a, b):
            assert fa.configuration.step == fb.configuration.step
            assert fa.configuration.dimensions == fb.configuration.dimensions == model.dim
            assert np.array_equal(fa.configuration.box, fb.configuration.box)
            assert fa.particles.N == model.n
            for name in ("position", "velocity"):
                x, y = getattr(fa.particles, name), getattr(fb.particles, name)
                assert x.dtype == np.float32 and x.shape == (model.n, 3) and x.tobytes() == y.tobytes()
            assert fa.log[PARAMETERS_KEY].tobytes() == fb.log[PARAMETERS_KEY].tobytes()
    with flocking.open(ours) as traj:
        assert traj.model == model
        assert np.array_equal(traj[-1].points, frame_arrays(sim.state, model.box)[0])


@pytest.mark.parametrize("kw", [{}, {"dim": 3, "speeds": "uniform"}, {"delay": 2}])
def test_cpu_frame_arrays_round_as_numpy_does(kw):
    model = Model(n=3000, density=1.5, seed=7, **kw)
    sim = Simulation(model)
    sim.run(3)
    expected = frame_arrays(sim.state, model.box)
    got = sim.backend.frame_arrays()
    for x, y in zip(got, expected):
        assert x.dtype == np.float32 and x.shape == (model.n, 3) and x.tobytes() == y.tobytes()
    sim.run(1)  # the frame lives in the spare buffers; the run is unchanged by it
    again = Simulation(model)
    again.run(4)
    assert np.array_equal(sim.state.positions, again.state.positions)


def test_a_run_with_a_trajectory_stays_under_120_bytes_a_particle(tmp_path):
    # compile outside the count (tracemalloc sees numba's compiler too)
    warm = Simulation(Model(n=1000, density=2.0, noise=1.0))
    warm.writers.append(GSDWriter(tmp_path / "warm.gsd", 100))
    warm.run(2)
    n = 200_000
    tracemalloc.start()
    try:
        sim = Simulation(Model(n=n, density=2.0, noise=1.0))
        sim.writers.append(GSDWriter(tmp_path / "t.gsd", 100))
        sim.run(101)
        peak = tracemalloc.get_traced_memory()[1] / n
    finally:
        tracemalloc.stop()
    # the backend holds 82: positions and headings double-buffered (64), ids (8), cells (4),
    # cell starts and histograms (~6); the writer's copy of a frame in flight 24 (N is
    # large enough for frames to be written by a thread)
    assert 64 < peak < 120
    with gsd.hoomd.open(tmp_path / "t.gsd") as f:
        assert [fr.configuration.step for fr in f] == [0, 100, 101]
    assert os.path.getsize(tmp_path / "t.gsd") > 3 * 24 * n


def test_a_failed_threaded_frame_is_raised_and_every_file_closed(tmp_path, monkeypatch):
    """An error in the writer's thread reaches the caller at the next write, and the run
    still closes every writer."""
    monkeypatch.setattr(GSDWriter, "threaded_from", 0)
    sim = Simulation(Model(n=300, density=1.0, seed=2))
    gsd_writer = GSDWriter(tmp_path / "t.gsd", 2)
    observables = flocking.ObservablesWriter(tmp_path / "obs.csv")
    sim.writers += [gsd_writer, observables]
    calls = []

    def fail_second(chunks):
        calls.append(1)
        if len(calls) == 2:
            raise OSError(28, "No space left on device")
        GSDWriter._append(gsd_writer, chunks)

    monkeypatch.setattr(gsd_writer, "_append", fail_second)
    with pytest.raises(OSError, match="No space left"):
        sim.run(10)
    assert sim.step <= 4  # raised by the write after the failed one, not at the end
    assert gsd_writer._file is None and observables._file is None
    with gsd.hoomd.open(tmp_path / "t.gsd") as f:
        assert [fr.configuration.step for fr in f] == [0]


def test_a_checkpoint_waits_for_the_frame_in_flight(tmp_path, monkeypatch):
    """A checkpoint never gets ahead of the trajectory: it finishes the frame in flight."""
    import time

    monkeypatch.setattr(GSDWriter, "threaded_from", 0)
    sim = Simulation(Model(n=300, density=1.0, seed=2))
    writer = GSDWriter(tmp_path / "t.gsd", 0)
    sim.writers.append(writer)
    writer.begin(sim)
    slow = GSDWriter._append

    def append_slowly(self, chunks):
        time.sleep(0.3)
        slow(self, chunks)

    monkeypatch.setattr(GSDWriter, "_append", append_slowly)
    writer.write(sim)
    assert writer._thread is not None and writer._thread.is_alive()
    sim.save_checkpoint(tmp_path / "c.npz")
    assert writer._thread is None
    with gsd.hoomd.open(tmp_path / "t.gsd") as f:
        assert [fr.configuration.step for fr in f] == [0]
    writer.close()


def test_writers_carry_on_over_several_runs_of_a_simulation(tmp_path):
    """``run`` closes its writers; running again appends instead of starting the files over."""
    sim = Simulation(Model(n=50, box=5.0, seed=1))
    sim.writers += [GSDWriter(tmp_path / "t.gsd", every=2), flocking.ObservablesWriter(tmp_path / "o.csv")]
    sim.run(4)
    sim.run(4)
    with gsd.hoomd.open(tmp_path / "t.gsd") as f:
        assert [int(fr.configuration.step) for fr in f] == [0, 2, 4, 6, 8]
    rows = (tmp_path / "o.csv").read_text().splitlines()
    assert rows[0] == "step,polar_order" and [int(r.split(",")[0]) for r in rows[1:]] == list(range(9))


def test_small_frames_are_flushed_in_batches_and_by_sync(tmp_path, monkeypatch):
    """gsd's flush fsyncs: small frames wait for the next flush (or a checkpoint's sync),
    frame 0 does not."""
    monkeypatch.setattr(GSDWriter, "flush_interval", 3600.0)
    sim = Simulation(Model(n=100, box=8.0, seed=3))
    writer = GSDWriter(tmp_path / "t.gsd", 1)
    sim.writers.append(writer)
    writer.begin(sim)
    writer.write(sim)
    for _ in range(3):
        sim.backend.advance(1)
        writer.write(sim)

    def steps():
        with gsd.hoomd.open(tmp_path / "t.gsd") as f:
            return [int(fr.configuration.step) for fr in f]

    assert steps() == [0]
    sim.save_checkpoint(tmp_path / "c.npz")  # syncs the writers first
    assert steps() == [0, 1, 2, 3]
    writer.close()
    assert steps() == [0, 1, 2, 3]
