"""Frames read back from GSD files know the species, walls and obstacles their run had."""

from __future__ import annotations

import gsd.hoomd
import numpy as np
import pytest

import flocking
from flocking.trajectory import Frame


@pytest.fixture(scope="module")
def extended_run(tmp_path_factory):
    """A 2D run with walls on x, one obstacle and two species, 4 frames (reference backend)."""
    model = flocking.Model(n=24, box=[12.0, 10.0], seed=5, boundary=["wall", "periodic"],
                           obstacles=[{"centre": [4.0, 6.0], "radius": 1.5}],
                           species=[{"name": "slow", "n": 10, "speed": 0.2}, {"name": "fast", "n": 14}])
    path = tmp_path_factory.mktemp("ext") / "t.gsd"
    sim = flocking.Simulation(model, backend="reference")
    sim.writers.append(flocking.GSDWriter(path, every=2))
    sim.run(6)
    return model, path


def test_species_walls_and_obstacles_come_back_in_every_frame(extended_run):
    model, path = extended_run
    with flocking.open(path) as traj:
        frames = list(traj)
    assert len(frames) == 4
    for frame in frames:
        assert frame.types == ("slow", "fast")
        assert frame.typeid.tolist() == [0] * 10 + [1] * 14
        assert frame.walls == (True, False)
        # centred coordinates, as the points: (4, 6) in a 12 x 10 box is (-2, 1)
        np.testing.assert_allclose(frame.obstacles, [[-2.0, 1.0, 1.5]])
        # every particle is outside the obstacle and inside the walls
        gap = np.linalg.norm(frame.positions - frame.obstacles[0, :2], axis=1)
        assert (gap >= 1.5).all()
        assert (np.abs(frame.positions[:, 0]) <= 6.0).all()


def test_species_follow_the_particle_ids_of_the_model(extended_run):
    model, path = extended_run
    with flocking.open(path) as traj:
        last = traj[-1]
    speeds = last.speeds
    for s, name in enumerate(model.species_names):
        expected = dict(zip(model.species_names, model.species_values("speed")))[name]
        np.testing.assert_allclose(speeds[last.typeid == s], expected, rtol=1e-6)


def test_a_plain_run_reads_as_one_type_without_walls_or_obstacles(tmp_path):
    path = tmp_path / "plain.gsd"
    sim = flocking.Simulation(flocking.Model(n=8, box=4.0), backend="reference")
    sim.writers.append(flocking.GSDWriter(path, every=1))
    sim.run(2)
    with flocking.open(path) as traj:
        for frame in traj:
            assert frame.types == ("A",)
            assert frame.typeid.tolist() == [0] * 8
            assert frame.walls == (False, False)
            assert frame.obstacles.shape == (0, 3)
    with gsd.hoomd.open(path) as f:  # nothing was added to the file for them
        assert "log/flocking/walls" not in f.file.find_matching_chunk_names("log/")


def test_another_programs_types_are_read_as_freud_and_ovito_do(tmp_path):
    path = tmp_path / "other.gsd"
    frame = gsd.hoomd.Frame()
    frame.configuration.box = [6, 6, 0, 0, 0, 0]
    frame.configuration.dimensions = 2
    frame.particles.N = 4
    frame.particles.position = np.zeros((4, 3), np.float32)
    frame.particles.types = ["head", "tail"]
    frame.particles.typeid = np.array([1, 0, 1, 2], np.uint32)  # id 2 has no name
    with gsd.hoomd.open(path, "w") as f:
        f.append(frame)
    with flocking.open(path) as traj:
        read = traj[0]
    assert read.types == ("head", "tail", "2")
    assert read.typeid.tolist() == [1, 0, 1, 2]
    assert read.walls == (False, False) and len(read.obstacles) == 0


def test_3d_obstacles_are_spheres_in_centred_coordinates(tmp_path):
    model = flocking.Model(dim=3, n=20, box=8.0, boundary="wall", obstacles=[{"centre": [2, 4, 5], "radius": 1.0}])
    path = tmp_path / "t3.gsd"
    sim = flocking.Simulation(model, backend="reference")
    sim.writers.append(flocking.GSDWriter(path, every=1))
    sim.run(1)
    with flocking.open(path) as traj:
        last = traj[-1]
    assert last.walls == (True, True, True)
    np.testing.assert_allclose(last.obstacles, [[-2.0, 0.0, 1.0, 1.0]])


def test_a_frame_refuses_type_ids_beyond_its_types():
    with pytest.raises(ValueError, match="typeid"):
        Frame(0, 2, [4, 4], np.zeros((2, 3)), np.zeros((2, 3)), typeid=[0, 1], types=["A"])
