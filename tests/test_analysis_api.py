"""PolarOrder statistics and its window, input handling, the object layer and error paths."""

import json
import math
import warnings

import gsd.hoomd
import numpy as np
import pytest
from click.testing import CliRunner

import flocking
import flocking.analysis as fa
from flocking.cli import main


def ar1(rng, n, rho, mu=0.5, sigma=0.01, count=1):
    x = np.empty((count, n))
    x[:, 0] = rng.standard_normal(count) * sigma / math.sqrt(1 - rho**2)
    noise = rng.standard_normal((count, n)) * sigma
    for t in range(1, n):
        x[:, t] = rho * x[:, t - 1] + noise[:, t]
    return mu + x


def test_polar_error_bars_cover_the_truth_at_the_right_rate():
    # AR(1): tau_int = (1 + rho) / (2 (1 - rho)) = 9.5; the true mean is 0.5
    rng = np.random.default_rng(0)
    series = ar1(rng, 4000, 0.9, count=300)
    inside1 = inside2 = 0
    for x in series:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            op = fa.PolarOrder().compute(x, n=100)
        inside1 += abs(op.mean - 0.5) < op.mean_error
        inside2 += abs(op.mean - 0.5) < 2 * op.mean_error
    sd = math.sqrt(0.68 * 0.32 / 300)
    assert abs(inside1 / 300 - 0.683) < 3.5 * sd
    assert abs(inside2 / 300 - 0.954) < 3.5 * math.sqrt(0.954 * 0.046 / 300)


def test_polar_tau_and_moments_of_ar1():
    rng = np.random.default_rng(1)
    x = ar1(rng, 50000, 0.8)[0]
    op = fa.PolarOrder().compute(x, n=1000)
    assert op.tau == pytest.approx(0.5 * 1.8 / 0.2, rel=0.15)
    expected = flocking.observables.polar_moments(x, 1000)
    assert op.mean == expected["mean"] and op.binder == expected["binder"]
    assert op.susceptibility == pytest.approx(1000 * np.var(x))
    # chi error: the variance estimate of a Gaussian AR(1): rel. error sqrt(2 * 2 tau' / T)
    tau2 = 0.5 * (1 + 0.64) / (1 - 0.64)  # tau of x^2 fluctuations: rho^2
    assert op.susceptibility_error / op.susceptibility == pytest.approx(
        math.sqrt(4 * tau2 / len(x)), rel=0.35)
    assert op.equilibrated


def test_polar_window_and_drift_warning():
    rng = np.random.default_rng(2)
    x = np.r_[np.linspace(0.0, 0.8, 500), 0.8 + 0.01 * rng.standard_normal(1500)]
    with pytest.warns(RuntimeWarning, match="equilibrated"):
        op = fa.PolarOrder().compute(x, n=10)
    assert not op.equilibrated
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        op = fa.PolarOrder(start=600).compute(x, n=10)
        assert op.samples == 1400 and op.window.sum() == 1400
        op = fa.PolarOrder(start=0.5).compute(x, n=10)
        assert op.samples == 1000
    assert op.mean == pytest.approx(0.8, abs=0.002)


def test_polar_from_run_folder_trajectory_and_frames(tmp_path):
    out = tmp_path / "run"
    res = CliRunner().invoke(main, ["run", "--n", "300", "--box", "10", "--noise", "0.5", "--steps", "40",
                                    "--every", "5", "--out", str(out), "-q"])
    assert res.exit_code == 0, res.output
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        from_csv = fa.PolarOrder().compute(str(out))
        from_csv_file = fa.PolarOrder().compute(out / "observables.csv", n=300)
        from_gsd = fa.PolarOrder().compute(out / "trajectory.gsd")
        with flocking.open(out / "trajectory.gsd") as traj:
            from_traj = fa.PolarOrder().compute(traj)
            frames = list(traj)
        from_frames = fa.PolarOrder().compute(frames)
        with gsd.hoomd.open(out / "trajectory.gsd") as raw:
            from_raw = fa.PolarOrder().compute(raw)
    assert from_csv.n == 300 and from_csv.samples == 41
    assert from_csv.mean == from_csv_file.mean
    assert from_gsd.steps.tolist() == list(range(0, 41, 5))
    np.testing.assert_allclose(from_gsd.series, from_csv.series[::5], atol=1e-6)
    for other in (from_traj, from_frames, from_raw):
        np.testing.assert_array_equal(other.series, from_gsd.series)


def test_inputs_agree(tmp_path):
    model = flocking.Model(n=400, box=12.0, noise=0.4, seed=5)
    sim = flocking.Simulation(model)
    path = tmp_path / "t.gsd"
    sim.writers.append(flocking.GSDWriter(path, every=5))
    sim.run(10)
    with flocking.open(path) as traj:
        frame = traj[-1]
    vc = lambda s: fa.VelocityCorrelation(r_max=3.0).compute(s).correlation  # noqa: E731
    ref = vc(frame)
    np.testing.assert_allclose(vc((frame.box, frame.points, frame.velocities)), ref)
    np.testing.assert_allclose(vc((12.0, frame.positions + 6.0, frame.headings)), ref)
    np.testing.assert_allclose(vc([frame]), ref)
    with gsd.hoomd.open(path) as raw:
        np.testing.assert_allclose(vc(raw[len(raw) - 1]), ref)
    # a run folder and a path: its stored radius is the cluster radius
    cl = fa.Clusters().compute(path)
    assert cl.radius_used == 1.0 and cl.k_used == 0 and cl.num_frames == 3
    assert fa.Clusters(frames=1).compute(tmp_path.joinpath("t.gsd")).num_frames == 1


def test_clusters_of_a_topological_run_by_its_k_nearest(tmp_path):
    model = flocking.Model(n=300, box=10.0, noise=0.4, neighbours="topological", k=4, seed=2)
    sim = flocking.Simulation(model)
    sim.writers.append(flocking.GSDWriter(tmp_path / "t.gsd", every=5))
    sim.run(5)
    by_k = fa.Clusters(k=4).compute(tmp_path / "t.gsd")
    assert by_k.k_used == 4 and math.isnan(by_k.radius_used)
    frame = fa.snapshots.as_frames(tmp_path / "t.gsd")[-1]
    np.testing.assert_array_equal(by_k.cluster_idx, fa.Clusters(k=4).compute([frame]).cluster_idx)
    by_radius = fa.Clusters().compute(tmp_path / "t.gsd")  # the run's radius, as for any run
    assert by_radius.k_used == 0 and by_radius.radius_used == model.radius


def test_results_before_compute_and_read_only():
    for cls in (fa.PolarOrder, fa.NematicOrder, fa.PerSpecies, fa.NumberFluctuations, fa.VelocityCorrelation,
                fa.DensityProfile, fa.Clusters, fa.BoxCounting, fa.MeanSquareDisplacement):
        obj = cls()
        name = cls._keys[1]
        with pytest.raises(fa.NotComputedError, match="compute"):
            getattr(obj, name)
        with pytest.raises(RuntimeError):
            obj.to_dict()
    bc = fa.BoxCounting().compute(np.ones((8, 8), bool))
    with pytest.raises(AttributeError):
        bc.dimension = 3
    with pytest.raises(ValueError):
        bc.counts[0] = 7
    assert json.loads(json.dumps(bc.to_dict()))["dimension"] == pytest.approx(2.0)


@pytest.mark.parametrize("make", [
    lambda: fa.PolarOrder(start=-1), lambda: fa.PolarOrder(start=2.5), lambda: fa.PolarOrder(start="x"),
    lambda: fa.NematicOrder(start=-1), lambda: fa.NematicOrder(dt=0), lambda: fa.PolarOrder(species=""),
    lambda: fa.NumberFluctuations(sizes=[-1]), lambda: fa.NumberFluctuations(fit_range=(5, 1)),
    lambda: fa.NumberFluctuations(frames=0), lambda: fa.VelocityCorrelation(r_max=0),
    lambda: fa.VelocityCorrelation(method="fft"), lambda: fa.VelocityCorrelation(r_max=1, dr=2),
    lambda: fa.DensityProfile(direction=3), lambda: fa.DensityProfile(direction=(0, 0)),
    lambda: fa.DensityProfile(direction=(1, 0.5)), lambda: fa.DensityProfile(threshold=-1),
    lambda: fa.Clusters(radius=-2), lambda: fa.BoxCounting(fit_range=(3, 1)),
    lambda: fa.MeanSquareDisplacement(max_lag=0),
])
def test_bad_parameters(make):
    with pytest.raises(flocking.ParameterError):
        make()


def test_bad_inputs(tmp_path):
    pts = np.random.default_rng(0).uniform(0, 5, (50, 2))
    cases = [
        (fa.Clusters(), "no/such/path"),
        (fa.Clusters(), str(tmp_path)),                       # a folder without trajectory
        (fa.Clusters(), 42),
        (fa.Clusters(), []),
        (fa.Clusters(), (5.0, np.zeros((3, 4)))),
        (fa.Clusters(), ((-1.0, 5.0), pts)),
        (fa.Clusters(), ([5.0, 5.0, 0, 0.1, 0, 0], pts)),   # tilted
        (fa.VelocityCorrelation(), (5.0, pts)),              # no velocities
        (fa.NumberFluctuations(sizes=[6.0]), (5.0, pts)),
        (fa.PolarOrder(), np.array([])),
        (fa.PolarOrder(start=100), np.ones(50)),
        (fa.MeanSquareDisplacement(), (5.0, pts)),
        (fa.BoxCounting(), np.zeros((4, 4), bool)),
        (fa.BoxCounting(fit_range=(100, 200)), np.ones((4, 4), bool)),
        (fa.DensityProfile(direction=2), (5.0, pts)),
    ]
    not_gsd = tmp_path / "x.gsd"
    not_gsd.write_text("hello")
    cases.append((fa.Clusters(), str(not_gsd)))
    for obj, system in cases:
        with pytest.raises(flocking.ParameterError):
            obj.compute(system)
    with pytest.raises(flocking.ParameterError, match="n:"):
        fa.PolarOrder().compute(np.ones(10), n=0)


def test_dicts_are_plain_json():
    rng = np.random.default_rng(1)
    pts = rng.uniform(0, 20, (3000, 2))
    u = rng.normal(size=(3000, 2))
    frames = [fa.snapshots.from_box_points(20.0, (pts + 0.1 * t) % 20, u, step=t) for t in range(4)]
    objs = [fa.PolarOrder().compute(rng.uniform(0, 1, 100), n=5), fa.NumberFluctuations().compute(frames),
            fa.VelocityCorrelation(r_max=5).compute(frames), fa.DensityProfile().compute(frames),
            fa.Clusters().compute(frames), fa.BoxCounting().compute(frames),
            fa.MeanSquareDisplacement().compute(frames)]
    for obj in objs:
        data = json.loads(json.dumps(obj.to_dict(), allow_nan=False))
        assert data["quantity"] == type(obj).__name__
        assert set(data) == {"quantity", "parameters", "notes", *type(obj)._keys}
        missing = [key for key in type(obj)._keys if isinstance(getattr(obj, key), float)  # NaN: each has a reason
                   and math.isnan(getattr(obj, key))]
        assert all(any(key in note for note in data["notes"]) for key in missing), (type(obj).__name__, missing)
    assert objs[-1].msd[0] == pytest.approx(2 * 0.1**2)


# --- the window: a transient found, or half the run ----------------------------------

def test_auto_window_finds_the_end_of_a_transient():
    # a relaxation over 500 steps, then an AR(1) steady state (tau = 9.5 samples) around 0.8
    rng = np.random.default_rng(3)
    steady = ar1(rng, 5500, 0.9, mu=0.8)[0]
    x = np.r_[0.8 * (1 - np.exp(-np.arange(500) / 100.0)) + (steady[:500] - 0.8), steady[500:]]
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the window found is steady: no drift warning
        op = fa.PolarOrder(start="auto").compute(x, n=100)
    assert op.window_rule == "detected"
    # candidates are T/64 apart; the transient's last 1/e^3 (0.04 = 1 error of 0.002 x 20) ends by step 300
    assert 300 <= op.window_start <= 500 + len(x) // 64
    assert op.equilibrated and op.suggested_start is None
    assert op.mean == pytest.approx(0.8, abs=4 * op.mean_error)
    with pytest.warns(RuntimeWarning, match=r"start=\d+"):
        whole = fa.PolarOrder().compute(x, n=100)
    assert whole.window_rule == "all" and not whole.equilibrated
    assert whole.suggested_start >= 300


def test_auto_window_keeps_a_steady_series_and_halves_a_drifting_one():
    rng = np.random.default_rng(4)
    steady = ar1(rng, 4000, 0.8)[0]
    op = fa.PolarOrder(start="auto").compute(steady, n=100)
    assert op.window_rule == "detected" and op.window_start <= len(steady) // 8
    # a drift all along: no window is steady, so the second half is kept and flagged
    drifting = steady + np.linspace(0, 0.5, len(steady))
    with pytest.warns(RuntimeWarning, match="equilibrated"):
        op = fa.PolarOrder(start="auto").compute(drifting, n=100)
    assert op.window_rule == "half the run" and op.window_start == 2000 and op.samples == 2000
    assert not op.equilibrated and op.suggested_start > 2000
    short = fa.PolarOrder(start="auto").compute(steady[:40], n=100)  # too short to look for a transient
    assert short.window_rule == "half the run" and short.window_start == 20


@pytest.mark.filterwarnings("ignore:PolarOrder")  # 40 steps from a random start: a transient only
def test_polar_times_follow_dt(tmp_path):
    model = flocking.Model(n=200, box=10.0, noise=0.5, dt=0.25, seed=2)
    sim = flocking.Simulation(model)
    sim.writers.append(flocking.GSDWriter(tmp_path / "t.gsd", every=4))
    sim.run(40)
    op = fa.PolarOrder().compute(tmp_path / "t.gsd")
    assert op.dt_used == 0.25
    np.testing.assert_array_equal(op.times, op.steps * 0.25)
    assert op.tau_time == pytest.approx(op.tau * 4 * 0.25)
    assert fa.PolarOrder(dt=2.0).compute(tmp_path / "t.gsd").times[-1] == 80.0
    series = fa.PolarOrder().compute(np.full(5, 0.5))
    assert series.dt_used == 1.0 and series.times.tolist() == [0, 1, 2, 3, 4]


def test_polar_needs_two_values():
    with pytest.raises(flocking.ParameterError, match=r"^system: holds 1 polar order value; .*at least 2"):
        fa.PolarOrder().compute(np.array([0.5]))
    with pytest.raises(flocking.ParameterError, match="^start: leaves 1 value"):
        fa.PolarOrder(start=9).compute(np.ones(10))
    with pytest.raises(flocking.ParameterError, match="^start:"):
        fa.PolarOrder(start="later")


# --- the distribution of the order in the window ----------------------------------------

def test_histogram_counts_the_window_exactly():
    # 10 values, the first 4 left out by start=4: 0.05 and 0.15 in bin 0, 0.45 in bin 2 and
    # 0.5 on an edge (bin 2 of [0.4, 0.6) ... with 5 bins), 0.95, 1.0 and a rounding error above
    # 1 in the last bin (1 belongs to it)
    series = np.array([0.9, 0.9, 0.9, 0.9, 0.05, 0.15, 0.45, 0.5, 0.95, 1.0 + 1e-15])
    op = fa.PolarOrder(start=4).compute(series)
    hist = op.histogram(bins=5)
    np.testing.assert_allclose(hist.edges, [0.0, 0.2, 0.4, 0.6, 0.8, 1.0])
    assert hist.counts.tolist() == [2, 0, 2, 0, 2]
    np.testing.assert_allclose(hist.density, np.array([2, 0, 2, 0, 2]) / (6 * 0.2))
    assert np.sum(hist.density * np.diff(hist.edges)) == pytest.approx(1.0)
    assert fa.PolarOrder().compute(series).histogram(bins=1).counts.tolist() == [10]


def test_histogram_of_a_bimodal_series_has_two_peaks():
    rng = np.random.default_rng(3)
    series = rng.permutation(np.r_[0.1 + 0.02 * rng.standard_normal(3000), 0.8 + 0.02 * rng.standard_normal(1000)])
    hist = fa.PolarOrder().compute(series).histogram(bins=10)
    assert hist.counts.sum() == 4000 and hist.counts[0] + hist.counts[1] == 3000
    assert hist.counts[7] + hist.counts[8] == 1000 and hist.counts[2:7].sum() == 0


@pytest.mark.parametrize("bins", [0, -3, 2.5, True, "10", None])
def test_histogram_refuses_bad_bins(bins):
    op = fa.NematicOrder().compute(np.array([0.2, 0.4, 0.6]))
    with pytest.raises(fa.order.ParameterError, match=r"^bins: must be a whole number >= 1 \(got "):
        op.histogram(bins)


def test_histogram_before_compute():
    with pytest.raises(fa.NotComputedError):
        fa.PolarOrder().histogram()


def test_histogram_plot(tmp_path):
    from flocking.viz import style

    op = fa.PolarOrder().compute(np.random.default_rng(4).permutation(np.linspace(0.0, 1.0, 101)), n=100)
    fig, ax = style.figure("column", theme="light")
    op.plot_histogram(ax, bins=20)
    heights = [p for p in ax.patches]
    assert len(heights) == 2 and ax.get_xlabel() and ax.get_ylabel() == "probability density"
    style.save(fig, tmp_path / "h.png")
    assert (tmp_path / "h.png").read_bytes()[:4] == b"\x89PNG"
