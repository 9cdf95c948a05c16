"""``flocking analyze``: outputs, the window, hints in the command's terms, units and figures."""

import csv
import json
import os
import warnings

import numpy as np
import pytest
from click.testing import CliRunner

from flocking.cli import main
from test_analysis_profile import banded, write_gsd


def run(*args):
    res = CliRunner().invoke(main, [str(a) for a in args])
    return res


def rows(path):
    with open(path, newline="") as f:
        return list(csv.reader(f))


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    out = tmp_path_factory.mktemp("runs") / "run"
    res = run("run", "--n", 800, "--box", 20, "--noise", 0.5, "--radius", 1.5, "--dt", 0.5, "--steps", 60,
              "--every", 5, "--out", out, "-q")
    assert res.exit_code == 0, res.output
    return out


@pytest.fixture(scope="module")
def transient_dir(tmp_path_factory):
    # from a random start the order grows for about 200 steps, then holds near 0.92
    out = tmp_path_factory.mktemp("runs") / "transient"
    res = run("run", "--n", 1000, "--density", 2, "--noise", 1.0, "--steps", 1200, "--every", 20, "--out", out,
              "-q", "--no-plots")
    assert res.exit_code == 0, res.output
    return out


def test_everything_is_written(run_dir):
    res = run("analyze", run_dir, "--start", 20, "-q")
    assert res.exit_code == 0, res.output
    data = json.loads((run_dir / "analysis.json").read_text())
    assert set(data) >= {"polar", "fluctuations", "structure", "correlation", "profile", "clusters", "boxcount", "msd", "window"}
    assert data["clusters"]["radius_used"] == 1.5 and data["model"]["n"] == 800
    for stem in ("polar_order_window", "number_fluctuations", "structure_factor", "velocity_correlation", "density_profile",
                 "cluster_sizes", "box_counting", "msd"):
        assert len(rows(run_dir / f"{stem}.csv")) > 1
        assert (run_dir / f"{stem}.png").read_bytes()[:4] == b"\x89PNG"
    polar = rows(run_dir / "polar_order_window.csv")
    assert polar[0] == ["step", "time", "polar_order", "in_window"] and len(polar) == 62
    assert data["polar"]["samples"] == 41 and data["polar"]["window_start"] == 20
    assert rows(run_dir / "cluster_sizes.csv")[0] == ["size", "clusters_all_frames", "clusters_per_frame"]
    assert rows(run_dir / "density_profile.csv")[0][1] == "density"
    hist = rows(run_dir / "polar_order_histogram.csv")
    assert hist[0] == ["low", "high", "count", "density"] and len(hist) == 51
    assert sum(int(r[2]) for r in hist[1:]) == 41  # every value of the window, once
    assert (run_dir / "polar_order_histogram.png").read_bytes()[:4] == b"\x89PNG"


def test_histogram_bins_and_its_counts(run_dir, tmp_path):
    import flocking.analysis as fa

    res = run("analyze", run_dir, "--only", "polar", "--start", 20, "--bins", 4, "--out", tmp_path, "-q",
              "--no-plots")
    assert res.exit_code == 0, res.output
    hist = rows(tmp_path / "polar_order_histogram.csv")
    assert [r[:2] for r in hist[1:]] == [["0.0", "0.25"], ["0.25", "0.5"], ["0.5", "0.75"], ["0.75", "1.0"]]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the short run drifts: the counts, not the mean, are tested
        expected = fa.PolarOrder(start=20).compute(run_dir).histogram(4).counts.tolist()
    assert [int(r[2]) for r in hist[1:]] == expected and sum(expected) == 41
    assert sorted(os.listdir(tmp_path)) == ["analysis.json", "polar_order_histogram.csv", "polar_order_window.csv"]


def test_times_are_in_the_model_units(run_dir, tmp_path):
    # the run has dt = 0.5: every time is step x 0.5, every speed per unit time
    res = run("analyze", run_dir, "--only", "polar,msd,profile", "--max-lag", 30, "--out", tmp_path, "-q",
              "--no-plots")
    assert res.exit_code == 0, res.output
    polar = np.array(rows(tmp_path / "polar_order_window.csv")[1:], dtype=float)
    np.testing.assert_array_equal(polar[:, 1], 0.5 * polar[:, 0])
    msd = rows(tmp_path / "msd.csv")
    assert msd[0] == ["lag_steps", "lag_time", "msd", "origins"]
    lags = np.array(msd[1:], dtype=float)
    assert lags[:, 0].tolist() == [5, 10, 15, 20, 25, 30]
    np.testing.assert_array_equal(lags[:, 1], 0.5 * lags[:, 0])
    data = json.loads((tmp_path / "analysis.json").read_text())
    assert data["msd"]["dt_used"] == data["profile"]["dt_used"] == data["polar"]["dt_used"] == 0.5
    assert data["time_unit"] == "t = step * dt"


def test_the_transient_is_left_out_by_default(transient_dir, tmp_path):
    res = run("analyze", transient_dir, "--only", "polar,clusters", "--out", tmp_path, "--no-plots")
    assert res.exit_code == 0, res.output
    data = json.loads((tmp_path / "analysis.json").read_text())
    start = data["window"]["start_step"]
    phi = np.array(rows(transient_dir / "observables.csv")[1:], dtype=float)[:, 1]
    assert data["window"]["rule"] == "transient detected"
    assert np.argmax(phi > 0.6) < start < 600  # past the steep rise, keeping most of the run
    assert f"window: from step {start} (transient detected; --start STEP to choose)" in res.output
    assert data["polar"]["window_start"] == start and data["polar"]["equilibrated"]
    assert data["clusters"]["num_frames"] == len(range(int(np.ceil(start / 20)) * 20, 1201, 20))
    # the window's mean agrees with the last half's, within their errors; the whole run's does not
    # (by many errors of a steady window, its own error being inflated by the transient it holds)
    res = run("analyze", transient_dir, "--only", "polar", "--start", 0.5, "--out", tmp_path / "half", "-q")
    half = json.loads((tmp_path / "half" / "analysis.json").read_text())["polar"]
    assert abs(data["polar"]["mean"] - half["mean"]) < 4 * np.hypot(data["polar"]["mean_error"], half["mean_error"])
    res = run("analyze", transient_dir, "--only", "polar", "--start", 0, "--out", tmp_path / "all")
    whole = json.loads((tmp_path / "all" / "analysis.json").read_text())["polar"]
    assert half["mean"] - whole["mean"] > 4 * half["mean_error"] and not whole["equilibrated"]
    # ... and the hint names the command's option, with a step to give it
    assert "discard more with --start " in res.output and "start=" not in res.output
    suggested = whole["suggested_start"]
    assert f"--start {suggested}" in res.output and suggested > 0


def test_a_run_of_zero_steps(tmp_path):
    out = tmp_path / "zero"
    assert run("run", "--n", 300, "--box", 10, "--steps", 0, "--out", out, "-q", "--no-plots").exit_code == 0
    res = run("analyze", out, "--no-plots")
    assert res.exit_code == 0, res.output
    assert "polar: skipped: holds 1 polar order value; statistics need at least 2 (a run of at least one step)" \
        in res.output
    assert "msd: skipped: the MSD needs at least two frames (got 1)" in res.output
    assert "--start" not in res.output.replace("--start STEP to choose", "")
    data = json.loads((out / "analysis.json").read_text())
    assert "polar" not in data and data["clusters"]["num_frames"] == 1
    res = run("analyze", out, "--only", "polar,msd", "--out", tmp_path / "none")
    assert res.exit_code == 2
    assert res.output.startswith(f"Error: RUN_DIR {str(out)!r}: polar: holds 1 polar order value")
    assert len(res.output.strip().splitlines()) == 1 and not (tmp_path / "none").exists()


def test_msd_of_frames_too_far_apart_is_skipped_with_the_reason(tmp_path):
    out = tmp_path / "far"
    res = run("run", "--n", 200, "--box", 16, "--steps", 80, "--every", 40, "--out", out, "-q", "--no-plots")
    assert res.exit_code == 0
    res = run("analyze", out, "--only", "msd,clusters", "--start", 0, "--no-plots")
    assert res.exit_code == 0, res.output
    assert "msd: skipped: frames 40 steps apart let a particle move up to 20" in res.output
    assert "(flocking run --every 15)" in res.output
    assert not (out / "msd.csv").exists() and (out / "cluster_sizes.csv").exists()


def test_clusters_summary_says_which_fraction(run_dir, tmp_path):
    res = run("analyze", run_dir, "--only", "clusters", "--out", tmp_path, "--no-plots")
    data = json.loads((tmp_path / "analysis.json").read_text())["clusters"]
    line = (f"clusters (closer than {data['radius_used']:g}): largest {data['largest_fraction_mean']:.3f} of N (mean over {data['num_frames']} frames; "
            f"last frame {data['largest_fraction']:.3f}), weight-average size {data['weight_average_size']:.4g}, "
            f"number-average size {data['number_average_size']:.4g}")
    assert data["weight_average_size"] < 1e4  # printed to 4 digits
    assert line in res.output


@pytest.mark.parametrize("args, message", [
    (["--cluster-k", "0"], "--cluster-k: must be a whole number >= 1 (got 0)"),
    (["--cluster-k", "100000"], "--cluster-k: must be at most the number of other particles"),
    (["--cluster-k", "3", "--cluster-radius", "1"], "--cluster-k: links by distance or by the k nearest, not both"),
])
def test_cluster_k_refusals_write_nothing(run_dir, tmp_path, args, message):
    res = run("analyze", run_dir, "--only", "clusters", "--out", tmp_path / "out", "--no-plots", *args)
    assert res.exit_code != 0 and message in res.output and "Traceback" not in res.output
    assert not (tmp_path / "out").exists()


def test_clusters_by_the_k_nearest_from_the_command_line(run_dir, tmp_path):
    res = run("analyze", run_dir, "--only", "clusters", "--out", tmp_path, "--no-plots", "--cluster-k", "3")
    assert res.exit_code == 0, res.output
    data = json.loads((tmp_path / "analysis.json").read_text())["clusters"]
    assert data["k_used"] == 3 and "clusters (each with its 3 nearest): largest" in res.output


def test_profile_csv_is_in_the_file_coordinates(tmp_path):
    rng = np.random.default_rng(14)
    pts = banded(rng, 100.0, 400, 1200, 22.5, 5.0, cross=20.0) - [50.0, 10.0]
    write_gsd(tmp_path / "t.gsd", [(0, [100.0, 20.0], pts, np.tile([0.5, 0.0], (len(pts), 1)))])
    res = run("analyze", tmp_path / "t.gsd", "--only", "profile", "--no-plots")
    assert res.exit_code == 0, res.output
    table = rows(tmp_path / "density_profile.csv")
    assert table[0] == ["x", "density"]
    x, density = np.array(table[1:], dtype=float).T
    assert x.min() > -50 and x.max() < 50
    assert x[np.argmax(density)] == pytest.approx(-25.0, abs=3)
    assert "density profile along x: bands in 1 of 1 frames (1 in the last)" in res.output


@pytest.mark.parametrize("fmt", ["svg", "pdf"])
def test_figures_in_vector_formats_and_themes(run_dir, tmp_path, fmt):
    res = run("analyze", run_dir, "--only", "fluctuations,clusters", "--out", tmp_path, "--format", fmt,
              "--theme", "light", "--size", "slide", "-q")
    assert res.exit_code == 0, res.output
    assert sorted(p for p in os.listdir(tmp_path) if not p.endswith((".csv", ".json"))) == \
        [f"cluster_sizes.{fmt}", f"number_fluctuations.{fmt}"]
    head = (tmp_path / f"cluster_sizes.{fmt}").read_bytes()[:200]
    assert (b"<svg" in head or b"<?xml" in head) if fmt == "svg" else head.startswith(b"%PDF")


def test_dpi_and_size_set_the_pixels(run_dir, tmp_path):
    from PIL import Image

    res = run("analyze", run_dir, "--only", "boxcount", "--out", tmp_path, "--dpi", 100, "--size", "column", "-q")
    assert res.exit_code == 0, res.output
    assert Image.open(tmp_path / "box_counting.png").size == (340, 260)


@pytest.mark.parametrize("args, message", [
    (["analyze", "/no/such/dir"], "RUN_DIR"),
    (["analyze", "{run}", "--only", "polar,nope"], "--only"),
    (["analyze", "{run}", "--start", "abc"], "--start"),
    (["analyze", "{run}", "--start", "2.5"], "--start"),
    (["analyze", "{run}", "--start", "100000"], "--start: leaves 0 value(s)"),
    (["analyze", "{run}", "--frames", "0"], "--frames"),
    (["analyze", "{run}", "--max-lag", "0"], "--max-lag"),
    (["analyze", "{run}", "--bins", "0"], "--bins: must be a whole number >= 1 (got 0)"),
    (["analyze", "{run}", "--bins", "-2"], "--bins: must be a whole number >= 1 (got -2)"),
    (["analyze", "{run}", "--r-max", "-1", "--only", "correlation"], "--r-max"),
    (["analyze", "{run}", "--method", "magic"], "--method: must be one of"),
    (["analyze", "{run}", "--theme", "pink"], "--theme"),
    (["analyze", "{run}", "--format", "tiff"], "--format"),
    (["analyze", "{run}", "--size", "poster"], "--size"),
    (["analyze", "{run}", "--dpi", "0"], "--dpi"),
    (["analyze", "{empty}"], "trajectory"),
    (["analyze", "{bad}"], "RUN_DIR"),
])
def test_errors_are_one_line_and_write_nothing(run_dir, tmp_path, args, message):
    empty = tmp_path / "empty"
    empty.mkdir()
    bad = tmp_path / "bad.gsd"
    bad.write_text("not gsd")
    args = [a.format(run=run_dir, empty=empty, bad=bad) for a in args] + ["--out", str(tmp_path / "out")]
    res = CliRunner().invoke(main, args)
    assert res.exit_code == 2
    assert message in res.output and res.output.startswith("Error: ")
    assert len(res.output.strip().splitlines()) == 1 and "Traceback" not in res.output
    assert not (tmp_path / "out").exists()


def test_only_and_out(run_dir, tmp_path):
    out = tmp_path / "res"
    res = run("analyze", run_dir / "trajectory.gsd", "--only", "clusters,boxcount", "--frames", 2, "--cluster-radius", 0.5,
              "--out", out, "--no-plots", "-q")
    assert res.exit_code == 0, res.output
    data = json.loads((out / "analysis.json").read_text())
    assert set(data) >= {"clusters", "boxcount"} and "polar" not in data
    assert data["clusters"]["num_frames"] == 2 and data["clusters"]["radius_used"] == 0.5
    assert sorted(os.listdir(out)) == ["analysis.json", "box_counting.csv", "cluster_sizes.csv"]


def test_nan_results_say_why_in_the_summary_and_the_json(tmp_path):
    # headings turning along x (C(r) positive up to about 15) and no band: the summary and analysis.json say why
    n = 120
    g = (np.arange(n) + 0.5) * (40.0 / n) - 20.0
    x, y = np.meshgrid(g, g, indexing="ij")
    pts = np.c_[x.ravel(), y.ravel()]
    vel = np.c_[np.cos(2 * np.pi * pts[:, 0] / 40.0), np.sin(2 * np.pi * pts[:, 0] / 40.0)]
    write_gsd(tmp_path / "t.gsd", [(0, [40.0, 40.0], pts, vel)])
    res = run("analyze", tmp_path / "t.gsd", "--only", "correlation,profile", "--r-max", 5, "--no-plots")
    assert res.exit_code == 0, res.output
    assert "velocity correlation: no zero of C(r) up to r_max = 5 (see notes)" in res.output
    assert "correlation: correlation length: NaN, C(r) stays positive up to r_max = 5 (no zero crossing)" in res.output
    assert "band_width, band_speed: NaN, no significant band in 1 frame" in res.output
    data = json.loads((tmp_path / "analysis.json").read_text())
    assert data["correlation"]["correlation_length"] is None
    assert data["correlation"]["notes"][0].startswith("correlation length: NaN")
    assert "correlation length: NaN" in data["notes"]["correlation"]


def test_a_channel_run_is_measured_with_its_walls(tmp_path):
    out = tmp_path / "channel"
    res = run("run", "--n", 400, "--box", "32,8", "--boundary", "periodic,wall", "--noise", 1.0, "--steps", 40,
              "--every", 20, "--out", out, "-q", "--no-plots")
    assert res.exit_code == 0, res.output
    res = run("analyze", out, "--only", "clusters,correlation,profile", "--start", 0, "--no-plots")
    assert res.exit_code == 0, res.output
    assert "clusters: walls on y: no link across them" in res.output
    data = json.loads((out / "analysis.json").read_text())
    assert data["profile"]["candidates"] == [[1, 0]] and data["correlation"]["r_max_used"] == 8.0
