"""Per-species polar order and nematic order: exact states, statistics of random headings,
agreement with the engine's observables.csv, ``flocking analyze`` outputs and error paths."""

import csv
import json
import math
import warnings

import gsd.hoomd
import numpy as np
import pytest
from click.testing import CliRunner

import flocking
import flocking.analysis as fa
from flocking.analysis import order
from flocking.analysis.snapshots import Snapshot
from flocking.cli import main
from flocking.observables import extra_values, moment_sums


def random_units(rng, shape):
    v = rng.normal(size=shape)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def write_typed(path, frames, types, typeid, box):
    """A GSD file in the engine's layout: types and typeid in frame 0 only."""
    with gsd.hoomd.open(path, "w") as f:
        for i, (step, points, velocities) in enumerate(frames):
            frame = gsd.hoomd.Frame()
            frame.configuration.step = step
            frame.configuration.box = [box, box, 0, 0, 0, 0]
            frame.configuration.dimensions = 2
            frame.particles.N = len(points)
            frame.particles.position = np.c_[points, np.zeros(len(points))].astype(np.float32)
            frame.particles.velocity = np.c_[velocities, np.zeros(len(points))].astype(np.float32)
            if i == 0:
                frame.particles.types = list(types)
                frame.particles.typeid = np.asarray(typeid, np.uint32)
            f.append(frame)


def quiet(compute, *args, **kwargs):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        return compute(*args, **kwargs)


# -- exact and statistical states ---------------------------------------------------------

def test_aligned_and_random_species(tmp_path):
    # species "lead" (ids 0..99, interleaved with the others) all along one direction that
    # turns from frame to frame; "crowd" (400) isotropic and independent in every frame
    rng = np.random.default_rng(3)
    n_lead, n_crowd, frames_count = 100, 400, 200
    typeid = np.r_[np.zeros(n_lead, int), np.ones(n_crowd, int)]
    order_ids = rng.permutation(n_lead + n_crowd)
    typeid = typeid[order_ids]
    frames = []
    for t in range(frames_count):
        v = random_units(rng, (n_lead + n_crowd, 2))
        angle = 0.1 * t
        v[typeid == 0] = [math.cos(angle), math.sin(angle)]
        frames.append((10 * t, rng.uniform(-8, 8, (n_lead + n_crowd, 2)), 0.5 * v))
    path = tmp_path / "typed.gsd"
    write_typed(path, frames, ["lead", "crowd"], typeid, 16.0)

    lead = fa.PolarOrder(species="lead").compute(path)
    np.testing.assert_allclose(lead.series, 1.0, atol=1e-7)  # float32 velocities
    assert lead.n == n_lead and lead.samples == frames_count
    crowd = fa.PolarOrder(species="crowd").compute(path)
    # |sum of N random unit vectors| in 2D: Rayleigh, E = sqrt(pi N / 4), var = N (1 - pi / 4)
    expected = math.sqrt(math.pi / (4 * n_crowd))
    sd_mean = math.sqrt((1 - math.pi / 4) / n_crowd / frames_count)
    assert abs(crowd.mean - expected) < 4 * sd_mean
    assert crowd.n == n_crowd
    # independent frames: tau ~ 1/2, so the error of the mean is the standard error
    assert crowd.mean_error == pytest.approx(sd_mean, rel=0.3)
    # the whole flock is neither, and PerSpecies gives both at once over the same window
    whole = fa.PolarOrder().compute(path)
    assert crowd.mean < whole.mean < lead.mean
    both = fa.PerSpecies(fa.PolarOrder(start=500)).compute(path)
    assert both.names == ("lead", "crowd") and both.window_start == 500
    np.testing.assert_array_equal(both["crowd"].series, crowd.series)
    assert both["crowd"].window_start == both["lead"].window_start == 500
    data = json.loads(json.dumps(both.to_dict()))
    assert data["species"]["lead"]["n"] == n_lead and data["names"] == ["lead", "crowd"]
    assert data["parameters"] == {"quantity": "PolarOrder", "start": 500, "dt": None}


@pytest.mark.parametrize("dim", [2, 3])
def test_antiparallel_halves_are_nematic_not_polar(dim):
    rng = np.random.default_rng(4)
    axis = random_units(rng, (dim,))
    u = np.r_[np.tile(axis, (250, 1)), np.tile(-axis, (250, 1))]
    frames = [(10.0, rng.uniform(0, 10, (500, dim)), u[rng.permutation(500)]) for _ in range(3)]
    s = fa.NematicOrder().compute(frames)
    np.testing.assert_allclose(s.series, 1.0, atol=1e-12)
    np.testing.assert_allclose(fa.PolarOrder().compute(frames).series, 0.0, atol=1e-12)


def regular_polygon(m, dim):
    angles = 2 * np.pi * np.arange(m) / m
    u = np.zeros((m, dim))
    u[:, 0], u[:, 1] = np.cos(angles), np.sin(angles)
    return u


def test_nematic_exact_values():
    # 2D: headings of a regular m-gon (m >= 3) have sum exp(2 i theta) = 0
    for m in (3, 5, 8):
        assert order.nematic_order(regular_polygon(m, 2)) == pytest.approx(0.0, abs=1e-14)
    # a square's headings, 0 and 90 degrees: S = 0 in 2D (perpendicular axes cancel)
    assert order.nematic_order(np.array([[1.0, 0], [0, 1.0]])) == pytest.approx(0.0, abs=1e-15)
    # 3D: isotropic in a plane: <u u> = diag(1/2, 1/2, 0), Q = diag(1/4, 1/4, -1/2), S = 1/4
    assert order.nematic_order(regular_polygon(6, 3)) == pytest.approx(0.25, abs=1e-14)
    # the three axes: <u u> = I / 3, Q = 0
    assert order.nematic_order(np.eye(3)) == pytest.approx(0.0, abs=1e-14)
    # a fraction p along z, the rest in the plane: Q_zz = 3/2 p - 1/2 is the largest when p > 1/2
    u = np.r_[np.tile([0, 0, 1.0], (3, 1)), regular_polygon(4, 3)[:1]]
    assert order.nematic_order(u) == pytest.approx(1.5 * 0.75 - 0.5, abs=1e-14)


def test_nematic_is_invariant_under_rotation_and_reversal():
    rng = np.random.default_rng(5)
    for dim in (2, 3):
        u = random_units(rng, (300, dim)) + np.r_[3.0, np.zeros(dim - 1)]
        u /= np.linalg.norm(u, axis=1, keepdims=True)
        q, _ = np.linalg.qr(rng.normal(size=(dim, dim)))
        flips = rng.choice([-1.0, 1.0], size=(300, 1))
        s = order.nematic_order(u)
        assert 0.1 < s < 1
        assert order.nematic_order(flips * u @ q.T) == pytest.approx(s, abs=1e-12)


@pytest.mark.parametrize("dim", [2, 3])
def test_nematic_agrees_with_the_engines_formula(dim):
    # the engine turns moment sums into the nematic order (observables.extra_values)
    rng = np.random.default_rng(6)
    model = flocking.Model(n=400, box=10.0, dim=dim, alignment_rule="nematic")
    for _ in range(5):
        u = random_units(rng, (400, dim)) + rng.normal(size=dim)
        u /= np.linalg.norm(u, axis=1, keepdims=True)
        engine = extra_values(model, moment_sums(model, u))[-1]
        assert order.nematic_order(u) == pytest.approx(engine, abs=1e-13)


def test_isotropic_nematic_order_is_small():
    # 2D: |<exp 2 i theta>| of N isotropic headings is Rayleigh like the polar order
    rng = np.random.default_rng(7)
    n, frames = 500, 200
    values = [order.nematic_order(random_units(rng, (n, 2))) for _ in range(frames)]
    expected = math.sqrt(math.pi / (4 * n))
    assert abs(np.mean(values) - expected) < 4 * math.sqrt((1 - math.pi / 4) / n / frames)


# -- the engine's own records ---------------------------------------------------------------

@pytest.fixture(scope="module", params=[2, 3])
def engine_run(request, tmp_path_factory):
    """A run with two species and nematic alignment (reference backend), its GSD file every
    10 steps and observables.csv every step."""
    dim = request.param
    out = tmp_path_factory.mktemp(f"run{dim}d")
    model = flocking.Model(n=300, box=6.0 if dim == 2 else 5.0, dim=dim, noise=0.6, alignment_rule="nematic",
                           seed=3, species=[{"name": "lead", "fraction": 0.3, "noise": 0.1},
                                            {"name": "crowd", "fraction": 0.7}])
    sim = flocking.Simulation(model, backend="reference")
    sim.writers += [flocking.GSDWriter(out / "trajectory.gsd", every=10),
                    flocking.ObservablesWriter(out / "observables.csv")]
    sim.run(200)
    return out


def test_frames_agree_with_observables_csv(engine_run):
    # frames hold float32 velocities: each unit heading is off by at most ~2e-7, so any of
    # these averages by at most that much
    quantities = [fa.PolarOrder(), fa.PolarOrder(species="lead"), fa.PolarOrder(species="crowd"),
                  fa.NematicOrder()]
    for q in quantities:
        from_frames = quiet(q.compute, engine_run / "trajectory.gsd")
        from_csv = quiet(type(q)(species=q.species).compute, engine_run)
        assert from_frames.samples == 21 and from_csv.samples == 201  # every 10 steps; every step
        np.testing.assert_array_equal(from_csv.steps[::10], from_frames.steps)
        np.testing.assert_allclose(from_frames.series, from_csv.series[::10], rtol=0, atol=2e-7)
    counts = {"lead": 90, "crowd": 210}
    for name, count in counts.items():
        assert quiet(fa.PolarOrder(species=name).compute, engine_run).n == count


def test_csv_columns_are_read(engine_run):
    with open(engine_run / "observables.csv", newline="") as f:
        rows = list(csv.reader(f))
    column = rows[0].index("polar_order_crowd")
    crowd = quiet(fa.PolarOrder(species="crowd").compute, engine_run / "observables.csv")
    assert crowd.series.tolist() == [float(r[column]) for r in rows[1:]]
    assert order.species_names(engine_run / "observables.csv") == ("lead", "crowd")
    assert order.species_names(engine_run) == ("lead", "crowd")


def test_a_polar_run_gives_its_nematic_order_from_the_frames(tmp_path):
    model = flocking.Model(n=200, box=8.0, noise=0.5, seed=1)
    sim = flocking.Simulation(model, backend="reference")
    sim.writers += [flocking.GSDWriter(tmp_path / "trajectory.gsd", every=4),
                    flocking.ObservablesWriter(tmp_path / "observables.csv")]
    sim.run(20)
    s = quiet(fa.NematicOrder().compute, tmp_path)
    assert s.steps.tolist() == list(range(0, 21, 4)) and s.n == 200
    with flocking.open(tmp_path / "trajectory.gsd") as traj:
        expected = [order.nematic_order(frame.headings) for frame in traj]
    np.testing.assert_allclose(s.series, expected, rtol=0, atol=1e-15)
    with pytest.raises(flocking.ParameterError, match=r"^system: .*observables.csv' has no nematic_order column"):
        fa.NematicOrder().compute(tmp_path / "observables.csv")
    # one species, named as the model names it
    assert order.species_names(tmp_path) == ("A",)
    with pytest.raises(flocking.ParameterError, match="^system: holds one species; per-species"):
        fa.PerSpecies().compute(tmp_path)


# -- errors ---------------------------------------------------------------------------------

def test_species_errors(engine_run):
    with pytest.raises(flocking.ParameterError, match=r"^species: must be one of lead, crowd \(got 'C'\)"):
        fa.PolarOrder(species="C").compute(engine_run)
    with pytest.raises(flocking.ParameterError, match=r"^species: must be one of lead, crowd \(got 'C'\)"):
        fa.NematicOrder(species="C").compute(engine_run / "trajectory.gsd")
    with pytest.raises(flocking.ParameterError, match=r"^species: must be the name of a species \(got 1\)"):
        fa.PolarOrder(species=1)
    with pytest.raises(flocking.ParameterError, match="^species: a series of values holds no species"):
        fa.PolarOrder(species="lead").compute(np.ones(10))
    with pytest.raises(flocking.ParameterError, match="^quantity: must be a PolarOrder"):
        fa.PerSpecies(fa.PolarOrder(species="lead"))
    with pytest.raises(flocking.ParameterError, match="^quantity: must be a PolarOrder"):
        fa.PerSpecies(fa.Clusters())
    frames = [(8.0, np.zeros((4, 2)), np.tile([1.0, 0.0], (4, 1)))] * 2
    with pytest.raises(flocking.ParameterError, match="^system: holds no particle types"):
        fa.PolarOrder(species="A").compute(frames)
    with pytest.raises(flocking.ParameterError, match="^system: holds no particle types; per-species"):
        fa.PerSpecies().compute(frames)
    with pytest.raises(fa.NotComputedError):
        fa.PerSpecies().names  # noqa: B018


def test_a_species_absent_from_a_frame():
    snap = Snapshot(0, [8.0, 8.0], np.zeros((3, 2)), np.tile([1.0, 0.0], (3, 1)), typeid=[0, 0, 0],
                    types=["A", "B"])
    with pytest.raises(flocking.ParameterError, match="^system: frame at step 0 holds no particle of species B"):
        fa.PolarOrder(species="B").compute([snap, snap])
    assert fa.PolarOrder(species="A").compute([snap, snap]).mean == 1.0


# -- plots ----------------------------------------------------------------------------------

def test_plots_label_the_species(engine_run):
    from flocking.viz import style

    per = quiet(fa.PerSpecies(fa.NematicOrder(start=50)).compute, engine_run)
    ax = per.plot()
    assert ax.get_ylabel() == r"nematic order $S$" and ax.get_xlabel() == style.LABELS["time"]
    texts = [t.get_text() for t in ax.get_legend().get_texts()]
    assert texts[0] == "window (given)"
    assert texts[1].startswith(r"$\langle S_{\mathrm{lead}}\rangle = ")
    ax = quiet(fa.PolarOrder(species="crowd").compute, engine_run).plot(theme="light")
    assert ax.get_legend().get_texts()[0].get_text() == r"$\varphi_{\mathrm{crowd}}(t)$"
    assert order.mathtext_text("a b_$") == r"a\ b\_\$"


# -- flocking analyze -----------------------------------------------------------------------

def run(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


def test_analyze_writes_the_species_and_nematic_outputs(engine_run, tmp_path):
    out = tmp_path / "analysis"
    res = run("analyze", engine_run, "--only", "polar,species,nematic,clusters", "--out", out, "--size", "slide")
    assert res.exit_code == 0, res.output
    data = json.loads((out / "analysis.json").read_text())
    assert set(data["species"]["species"]) == {"lead", "crowd"}
    assert data["nematic"]["quantity"] == "NematicOrder" and data["nematic"]["samples"] > 2
    with open(out / "polar_order_species.csv", newline="") as f:
        rows = list(csv.reader(f))
    assert rows[0] == ["step", "time", "polar_order_lead", "polar_order_crowd", "in_window"]
    assert len(rows) == 202  # every step of observables.csv
    with open(engine_run / "observables.csv", newline="") as f:
        obs = list(csv.reader(f))
    assert [r[2] for r in rows[1:]] == [r[obs[0].index("polar_order_lead")] for r in obs[1:]]
    with open(out / "nematic_order_window.csv", newline="") as f:
        assert next(csv.reader(f)) == ["step", "time", "nematic_order", "in_window"]
    for stem in ("polar_order_species", "nematic_order_window"):
        assert (out / f"{stem}.png").read_bytes()[:4] == b"\x89PNG"
    assert "polar order per species: lead " in res.output and "nematic order: <S> " in res.output


def test_the_window_leaves_out_the_nematic_transient(engine_run, tmp_path):
    # from a random start the polar order of a nematic run stays near 0 (no transient) while
    # the nematic order grows: the window is where the later series has settled
    res = run("analyze", engine_run, "--only", "polar,nematic", "--out", tmp_path, "--no-plots")
    assert res.exit_code == 0, res.output
    data = json.loads((tmp_path / "analysis.json").read_text())
    alone = quiet(fa.NematicOrder(start="auto").compute, engine_run)
    assert data["window"]["start_step"] == alone.window_start > 0
    assert data["nematic"]["window_start"] == data["polar"]["window_start"] == alone.window_start
    assert "in the nematic order" in data["window"]["rule"]


def test_analyze_of_a_plain_run_has_neither(tmp_path):
    out = tmp_path / "run"
    res = run("run", "--n", 100, "--box", 6, "--steps", 20, "--every", 5, "--backend", "reference", "--out", out,
              "-q", "--no-plots")
    assert res.exit_code == 0, res.output
    res = run("analyze", out, "--only", "polar,clusters", "-q", "--no-plots")
    assert res.exit_code == 0, res.output
    res = run("analyze", out, "-q", "--no-plots")
    assert res.exit_code == 0, res.output
    data = json.loads((out / "analysis.json").read_text())
    assert "species" not in data and "nematic" not in data and "polar" in data
    assert not (out / "polar_order_species.csv").exists() and not (out / "nematic_order_window.csv").exists()
    # asked for: the nematic order of any run, from its frames; species need several
    res = run("analyze", out, "--only", "nematic", "-q", "--no-plots")
    assert res.exit_code == 0, res.output
    with open(out / "nematic_order_window.csv", newline="") as f:
        assert len(list(csv.reader(f))) == 6  # every frame, steps 0 to 20
    res = run("analyze", out, "--only", "species", "--out", tmp_path / "nothing", "-q")
    assert res.exit_code == 2
    assert res.output.strip().splitlines() == [
        f"Error: RUN_DIR {str(out)!r}: species: holds one species; per-species quantities need two or more"]
    assert not (tmp_path / "nothing").exists()


def test_analyze_finds_species_in_a_foreign_gsd_file(tmp_path):
    rng = np.random.default_rng(8)
    typeid = np.repeat([0, 1], 50)
    frames = [(t, rng.uniform(-4, 4, (100, 2)), np.r_[np.tile([1.0, 0.0], (50, 1)), random_units(rng, (50, 2))])
              for t in range(0, 100, 10)]
    write_typed(tmp_path / "foreign.gsd", frames, ["X", "Y"], typeid, 8.0)
    res = run("analyze", tmp_path / "foreign.gsd", "--only", "polar,species", "--start", 0, "--no-plots")
    assert res.exit_code == 0, res.output
    data = json.loads((tmp_path / "analysis.json").read_text())
    assert data["species"]["names"] == ["X", "Y"] and data["species"]["species"]["X"]["mean"] == 1.0
    assert "nematic" not in data
