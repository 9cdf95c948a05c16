"""Our trajectories open in gsd, freud and MDAnalysis; HOOMD-convention files open in ours."""

import warnings

import gsd.hoomd
import numpy as np
import pytest

import flocking
from flocking.backends.cpu import CPUBackend


@pytest.fixture(scope="module", params=[2, 3])
def run(request, tmp_path_factory):
    dim = request.param
    path = tmp_path_factory.mktemp(f"interop{dim}") / "t.gsd"
    model = flocking.Model(dim=dim, n=500, box=(9.0, 7.0, 6.0)[:dim], speeds="uniform", noise=0.8, seed=5)
    sim = flocking.Simulation(model)
    sim.writers.append(flocking.GSDWriter(path, every=5))
    sim.run(10)
    return path, model, sim.state


def test_gsd_reader_sees_hoomd_conventions(run):
    path, model, state = run
    with gsd.hoomd.open(path) as f:
        assert len(f) == 3
        fr = f[-1]
        assert fr.configuration.dimensions == model.dim
        assert fr.configuration.step == 10
        assert np.allclose(fr.configuration.box[: model.dim], model.box)
        centred = state.positions - np.asarray(model.box) / 2
        assert np.allclose(fr.particles.position[:, : model.dim], centred, atol=1e-5)
        v = state.speeds[:, None] * state.headings
        assert np.allclose(fr.particles.velocity[:, : model.dim], v, atol=1e-6)
        if model.dim == 2:
            assert np.all(fr.particles.position[:, 2] == 0) and np.all(fr.particles.velocity[:, 2] == 0)


def test_freud_accepts_our_frames_and_counts_the_same_neighbours(run):
    freud = pytest.importorskip("freud")
    path, model, state = run
    frame = flocking.open(path)[-1]
    box = freud.box.Box.from_box(frame.box)
    assert box.is2D == (model.dim == 2)
    assert np.allclose([box.Lx, box.Ly], model.box[:2])
    # freud takes the frame itself (box, points) and a raw gsd frame alike
    query = freud.locality.AABBQuery.from_system(frame)
    with gsd.hoomd.open(path) as f:
        raw = freud.locality.AABBQuery.from_system(f[-1])
    assert np.allclose(raw.points, query.points)
    nlist = query.query(frame.points, {"r_max": model.radius, "exclude_ii": True}).toNeighborList()
    counts = np.bincount(nlist.query_point_indices, minlength=model.n)
    ours = CPUBackend(model, state).neighbour_sums()[:, model.dim] - 1  # 1 + count, per id
    assert np.array_equal(counts, ours.astype(int))


def test_mdanalysis_reads_box_and_positions(run):
    mda = pytest.importorskip("MDAnalysis")
    path, model, state = run
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        u = mda.Universe(str(path))
    assert len(u.atoms) == model.n and len(u.trajectory) == 3
    assert np.allclose(u.dimensions[: model.dim], model.box, rtol=1e-6)
    ts = u.trajectory[-1]
    ours = flocking.open(path)[-1]
    assert np.array_equal(ts.positions, ours.points)


def _hoomd_file(path, dim, with_velocity):
    """A file as HOOMD-blue writes it: Lz = 0 in 2D, orientations, maybe no velocities."""
    rng = np.random.default_rng(1)
    n = 40
    box = [6.0, 5.0, 0.0 if dim == 2 else 4.0, 0, 0, 0]
    pos = rng.uniform(-0.5, 0.5, (n, 3)) * np.array(box[:3])
    if dim == 2:
        theta = rng.uniform(-np.pi, np.pi, n)
        q = np.stack([np.cos(theta / 2), 0 * theta, 0 * theta, np.sin(theta / 2)], axis=1)
        heading = np.stack([np.cos(theta), np.sin(theta), 0 * theta], axis=1)
    else:
        axis = rng.normal(size=(n, 3))
        axis /= np.linalg.norm(axis, axis=1, keepdims=True)
        angle = rng.uniform(0, np.pi, n)
        q = np.concatenate([np.cos(angle / 2)[:, None], np.sin(angle / 2)[:, None] * axis], axis=1)
        # Rodrigues: the body x axis rotated about `axis` by `angle`
        x = np.array([1.0, 0, 0])
        heading = (x * np.cos(angle)[:, None] + np.cross(axis, x) * np.sin(angle)[:, None]
                   + axis * (axis @ x)[:, None] * (1 - np.cos(angle))[:, None])
    f = gsd.hoomd.Frame()
    f.configuration.step = 1000
    f.configuration.dimensions = dim
    f.configuration.box = box
    f.particles.N = n
    f.particles.types = ["A"]
    f.particles.position = pos.astype(np.float32)
    f.particles.orientation = q.astype(np.float32)
    if with_velocity:
        f.particles.velocity = (0.3 * heading).astype(np.float32)
    with gsd.hoomd.open(path, "w") as out:
        out.append(f)
    return pos, heading, box


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("with_velocity", [True, False])
def test_hoomd_convention_files_open_in_ours(tmp_path, dim, with_velocity):
    path = tmp_path / "hoomd.gsd"
    pos, heading, box = _hoomd_file(path, dim, with_velocity)
    with flocking.open(path) as traj:
        assert traj.model is None  # not written by flocking
        frame = traj[0]
    assert frame.dim == dim and frame.step == 1000
    assert np.allclose(frame.box_lengths, box[:dim])
    assert np.allclose(frame.positions, pos[:, :dim], atol=1e-5)
    assert np.allclose(frame.headings, heading[:, :dim], atol=1e-5)
    # and a run can start from it
    model = flocking.Model(dim=dim, n=40, box=box[:dim], noise=0.5)
    state = flocking.State.from_gsd(path, model)
    assert state.step == 1000 and np.all(state.positions >= 0) and np.all(state.positions < box[:dim])
    assert frame.polar_order == pytest.approx(np.linalg.norm(heading[:, :dim].sum(axis=0)) / 40, abs=1e-5)


def test_ovito_opens_a_run_with_its_species_velocities_and_box(tmp_path):
    """OVITO's Python module (``pip install ovito``; skipped where it cannot be imported)
    reads what `flocking run` writes: every frame's positions (centred, as HOOMD has them),
    velocities (speed x heading), the species as particle types, the box and its dimension."""
    ovito_io = pytest.importorskip("ovito.io")
    from click.testing import CliRunner

    from flocking.cli import main

    out = tmp_path / "run"
    result = CliRunner().invoke(main, ["run", "--n", "120", "--box", "8,6", "--steps", "10", "--every", "5",
                                       "--species-b", "0.25", "--out", str(out), "-q", "--no-plots"])
    assert result.exit_code == 0, result.output
    pipeline = ovito_io.import_file(str(out / "trajectory.gsd"))
    with gsd.hoomd.open(out / "trajectory.gsd") as f:
        assert pipeline.source.num_frames == len(f) == 3
        for i, frame in enumerate(f):
            data = pipeline.compute(i)
            assert data.attributes["Timestep"] == frame.configuration.step
            assert np.array_equal(np.asarray(data.particles.positions), frame.particles.position)
            assert np.array_equal(np.asarray(data.particles.velocities), frame.particles.velocity)
    types = data.particles.particle_types
    assert [t.name for t in types.types] == ["A", "B"]
    assert np.bincount(np.asarray(types)).tolist() == [90, 30]  # species B: ids 90 to 119
    assert np.asarray(types)[90:].min() == 1
    cell = np.asarray(data.cell[...])
    assert np.allclose(cell[:2, :2], np.diag([8.0, 6.0])) and np.allclose(cell[:2, 3], [-4.0, -3.0])
    assert data.cell.is2D
    speeds = np.linalg.norm(np.asarray(data.particles.velocities), axis=1)
    assert np.allclose(speeds, 0.5, rtol=1e-6)
