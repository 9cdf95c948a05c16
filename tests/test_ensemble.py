"""flocking.Ensemble on the CPU fallback: the API, its errors, and its files.

The GPU path (one set of launches for all replicas, each equal bit for bit to its model
alone) is tested under numba's CUDA simulator in tests/test_cuda.py.
"""

from __future__ import annotations

import numpy as np
import pytest

import flocking
from flocking.backends.cpu import CPUBackend
from flocking.ensemble import groups

BASE = flocking.Model(n=60, box=6.0, noise=1.0, seed=1)
VARIANTS = [dict(seed=2), dict(seed=3, noise=2.5, alignment=0.5, delay=2), dict(seed=4, speed=0.2, speeds="uniform")]


def models():
    return [BASE.replace(**v) for v in VARIANTS]


def test_replicas_equal_their_models_alone():
    ens = flocking.Ensemble(models(), backend="cpu")
    phi = ens.advance(7)
    assert phi.shape == (3, 7) and ens.step == 7 and ens.replicas == 3
    for r, model in enumerate(models()):
        alone = CPUBackend(model, flocking.State.random(model))
        assert (alone.advance(7) == phi[r]).all()
        state = alone.state
        assert (ens.states[r].positions == state.positions).all()
        assert (ens.states[r].headings == state.headings).all()
        assert sorted(ens.memory()[r]) == sorted(alone.memory())
    assert "ring" in ens.memory()[1] and ens.memory()[1]["ring"].shape == (2, 60, 3)


def test_states_are_kept_until_the_next_step():
    ens = flocking.Ensemble(models()[:2], backend="cpu")
    first = ens.states
    assert ens.states is first
    ens.advance(1)
    assert ens.states is not first and ens.states[0].step == 1


def test_states_by_kind_are_drawn_for_each_model():
    ms = models()
    ens = flocking.Ensemble(ms, ["aligned", "random", flocking.State.random(ms[2])], backend="cpu")
    assert ens.states[0].polar_order() == pytest.approx(1.0, abs=1e-12)
    for r in (1, 2):
        expected = flocking.State.random(ms[r])
        assert (ens.states[r].positions == expected.positions).all()
        assert (ens.states[r].headings == expected.headings).all()
    assert ens.advance(3).shape == (3, 3)
    with pytest.raises(flocking.ParameterError, match=r"^state: must be a State, 'random' or 'aligned' \(got 'copy'\)$"):
        flocking.Ensemble([BASE], ["copy"], backend="cpu")


@pytest.mark.parametrize("change, message", [
    (dict(n=61), r"^models: every replica must have the same n \(model 0 has 60, model 1 61\)$"),
    (dict(radius=1.5), r"^models: every replica must have the same radius"),
    (dict(neighbours="topological"), r"^models: every replica must have the same neighbours"),
])
def test_incompatible_models_are_refused(change, message):
    with pytest.raises(flocking.ParameterError, match=message):
        flocking.Ensemble([BASE, BASE.replace(**change)], backend="cpu")


def test_bad_arguments_are_refused():
    with pytest.raises(flocking.ParameterError, match=r"^models: give at least one model$"):
        flocking.Ensemble([], backend="cpu")
    with pytest.raises(flocking.ParameterError, match=r"^precision: 'float32' needs backend='cuda'"):
        flocking.Ensemble([BASE], backend="cpu", precision="float32")
    with pytest.raises(flocking.ParameterError, match=r"^backend: must be one of"):
        flocking.Ensemble([BASE], backend="tpu")
    late = flocking.State.random(BASE)
    late.step = 5
    with pytest.raises(flocking.ParameterError, match=r"^states: replicas advance together"):
        flocking.Ensemble([BASE, BASE], [flocking.State.random(BASE), late], backend="cpu")
    with pytest.raises(flocking.ParameterError, match=r"^memories: one per model \(2; got 1\)$"):
        flocking.Ensemble([BASE, BASE], backend="cpu", memories=[None])
    ens = flocking.Ensemble([BASE], backend="cpu")
    with pytest.raises(flocking.ParameterError, match=r"^replica: must be in \[0, 1\) \(got 1\)$"):
        ens.replica(1)
    with pytest.raises(flocking.ParameterError, match=r"^writers: one list per replica \(1; got 2\)$"):
        ens.run(3, writers=[[], []])


def test_groups_split_models_that_can_share_an_ensemble():
    ms = [BASE, BASE.replace(dim=3, box=4.0), BASE.replace(seed=9, delay=4), BASE.replace(dt=0.5)]
    assert groups(ms) == [[0, 2], [1], [3]]
    assert groups([]) == []


def test_run_writes_each_replica_and_its_checkpoint_continues_alone(tmp_path):
    """Per-replica GSD and CSV files hold the steps of the replica's own run; a replica's
    checkpoint, loaded as a single simulation and run on, matches the ensemble run on."""
    ms = models()
    ens = flocking.Ensemble(ms, backend="cpu")
    writers = [[flocking.GSDWriter(tmp_path / f"r{r}.gsd", every=5),
                flocking.ObservablesWriter(tmp_path / f"r{r}.csv"),
                flocking.CheckpointWriter(tmp_path / f"r{r}.npz", every=10)] for r in range(3)]
    phi = ens.run(12, writers=writers)
    assert phi.shape == (3, 12) and ens.step == 12
    for r, model in enumerate(ms):
        alone = flocking.Simulation(model, backend="cpu")
        alone.run(12)
        assert (np.asarray(alone.polar_order[1:]) == phi[r]).all()
        with flocking.open(tmp_path / f"r{r}.gsd") as traj:
            assert [f.step for f in traj] == [0, 5, 10, 12]
            assert np.allclose(traj[-1].headings, alone.state.headings, atol=1e-6)
        rows = np.loadtxt(tmp_path / f"r{r}.csv", delimiter=",", skiprows=1)
        assert rows.shape == (13, 2) and (rows[1:, 1] == phi[r]).all()
        resumed = flocking.Simulation.load_checkpoint(tmp_path / f"r{r}.npz")
        assert resumed.step == 12 and resumed.backend.name == "cpu"
        assert (resumed.state.positions == ens.states[r].positions).all()
    after = ens.advance(4)
    for r in range(3):
        resumed = flocking.Simulation.load_checkpoint(tmp_path / f"r{r}.npz")
        resumed.run(4)
        assert (np.asarray(resumed.polar_order[1:]) == after[r]).all()
        assert (resumed.state.headings == ens.states[r].headings).all()
