"""The examples: every config loads as a valid run, and examples/measure.py, whose numbers
examples/README.md quotes, finds the right neighbour pairs and bands."""

from __future__ import annotations

import pathlib
import subprocess
import sys

import numpy as np
import pytest
from scripts import load_script

from flocking.config import RunConfig
from flocking.trajectory import Frame

EXAMPLES = pathlib.Path(__file__).resolve().parents[1] / "examples"
SWEEPS = sorted(p for p in EXAMPLES.glob("*.toml") if "[grid]" in p.read_text())
RUNS = sorted(set(EXAMPLES.glob("*.toml")) - set(SWEEPS))
FIGURE_SCRIPTS = sorted(p for p in EXAMPLES.glob("*.py") if all(o in p.read_text() for o in ('"--out"', '"--theme"')))


measure = load_script("examples/measure.py")


@pytest.mark.parametrize("path", RUNS, ids=lambda p: p.name)
def test_every_example_run_config_loads(path):
    config = RunConfig.from_toml(path.read_text(), source=str(path))
    assert config.steps > 0
    assert config.model.n > 0


@pytest.mark.parametrize("path", SWEEPS, ids=lambda p: p.name)
def test_every_example_sweep_loads(path):
    from flocking.sweep.spec import SweepSpec

    assert len(SweepSpec.load(path).points()) > 1


def test_the_example_configs_were_found():
    assert {p.name for p in RUNS} >= {"channel.toml", "nematic_lanes.toml", "obstacle_mill.toml", "binary_mixture.toml"}
    assert {p.name for p in SWEEPS} >= {"vicsek1995.toml", "gregoire_chate2004.toml"}


def _brute_pairs(frame, radius):
    x = frame.points[:, : frame.dim].astype(np.float64)
    periodic = ~np.asarray(frame.walls)
    i, j = np.triu_indices(len(x), 1)
    d = x[i] - x[j]
    d = np.where(periodic, d - frame.box_lengths * np.round(d / frame.box_lengths), d)
    close = np.einsum("ij,ij->i", d, d) < radius * radius
    return set(zip(i[close].tolist(), j[close].tolist()))


@pytest.mark.parametrize("dim, box, walls", [
    (2, [10.0, 7.0], [False, False]),
    (2, [10.0, 7.0], [True, False]),
    (2, [5.0, 5.0], [True, True]),
    (2, [1.5, 2.5], [False, False]),          # one and two cells per axis
    (3, [4.0, 3.0, 5.0], [False, True, False]),
    (3, [2.0, 2.0, 2.0], [False, False, False]),
])
def test_measure_pairs_are_exactly_those_closer_than_the_radius(dim, box, walls):
    rng = np.random.default_rng(dim + len(box) + sum(walls))
    box = np.array(box)
    points = np.zeros((300, 3))
    points[:, :dim] = (rng.random((300, dim)) - 0.5) * box  # centred, as in a trajectory
    frame = Frame(0, dim, box, points, points, walls=walls)
    i, j = measure.pairs(frame, 1.0)
    found = set(zip(i.tolist(), j.tolist()))
    assert len(found) == len(i)  # each pair once
    assert np.all(i < j)
    assert found == _brute_pairs(frame, 1.0)


def _frame_2d(xy, box):
    points = np.zeros((len(xy), 3))
    points[:, :2] = np.asarray(xy) - np.asarray(box) / 2
    return Frame(0, 2, box, points, points)


def test_measure_band_is_a_quarter_for_a_uniform_density_and_one_for_a_band():
    rng = np.random.default_rng(3)
    box = [64.0, 32.0]
    uniform = rng.random((20000, 2)) * box
    # 20000 particles, 8 strips of 32: the densest window exceeds 1/4 by a few sigma at most
    sigma = np.sqrt(0.25 * 0.75 / 20000)
    assert 0.25 <= measure.band(_frame_2d(uniform, box), 0.0) < 0.25 + 5 * sigma
    along_x = np.column_stack([rng.random(4000) * 64.0, 20.0 + rng.random(4000) * 3.0])
    assert measure.band(_frame_2d(along_x, box), np.radians(5.0)) == 1.0
    along_y = np.column_stack([30.0 + rng.random(4000) * 5.0, rng.random(4000) * 32.0])
    assert measure.band(_frame_2d(along_y, box), np.radians(-85.0)) == 1.0
    # a band along the box's diagonal (direction (64, 32)), which closes on itself
    t = rng.random(4000)
    diagonal = np.mod(np.column_stack([t * 64.0, t * 32.0 + rng.random(4000) * 2.0]), box)
    angle = np.arctan2(32.0, 64.0)
    assert measure.band(_frame_2d(diagonal, box), angle + 0.05) == 1.0
    # cut across the wrong line, the same band looks almost uniform
    assert measure.band(_frame_2d(diagonal, box), 0.0) < 0.35


@pytest.mark.parametrize("extra, shown", [
    ('boundary = "wall"\nobstacles = [{centre = [6.0, 6.0], radius = 2.0}]\n', ["milling"]),
    ('species = [{name = "A", fraction = 0.5}, {name = "B", fraction = 0.5}]\ncoupling = [[1.0, -1.0], [-1.0, 1.0]]\n',
     ["phi_A", "phi_B", "phi"]),
    ('alignment_rule = "nematic"\n', ["nematic", "phi"]),
])
def test_the_figure_shows_the_numbers_measure_prints(tmp_path, extra, shown):
    from click.testing import CliRunner
    from matplotlib.image import imread

    from flocking.cli import main

    config = tmp_path / "run.toml"
    config.write_text(f"n = 60\nbox = 12.0\nnoise = 0.5\nsteps = 40\nevery = 4\n{extra}")
    run = tmp_path / "run"
    result = CliRunner().invoke(main, ["run", "--config", str(config), "--backend", "reference", "--no-plots",
                                       "--out", str(run), "-q"])
    assert result.exit_code == 0, result.output
    printed = measure.measure(str(run))
    out = tmp_path / "figure.png"
    means = measure.figure(str(run), str(out), theme="dark", size="column", dpi=60)
    assert list(means) == shown and imread(out).shape[1] == round(3.4 * 60)
    for key, value in means.items():  # the legend's means are measure's, over the same frames
        assert value == pytest.approx(printed[key], abs=1e-12)
    assert printed["from_step"] == 20 and printed["to_step"] == 40 and printed["frames"] == 6


def test_measure_rounds_as_the_readme_quotes():
    assert [measure.short(v) for v in (0.9583, -0.7237, 0.01512, 0.1)] == ["0.96", "-0.72", "0.015", "0.10"]
    assert measure.story({"obstacles": [{}]}, ("A",)) == measure.MILLING
    assert [key for key, _, _ in measure.story({}, ("A", "B"))] == ["phi_A", "phi_B", "phi"]


def test_the_figure_scripts_were_found():
    assert {p.stem for p in FIGURE_SCRIPTS} >= {"vicsek1995", "gregoire_chate2004", "chate2008", "finite_size",
                                                "ginelli_chate2010", "cohesion", "informed_individuals"}


@pytest.mark.parametrize("path", FIGURE_SCRIPTS, ids=lambda p: p.stem)
def test_a_figure_script_refuses_a_bad_figure_option_before_it_runs(path, tmp_path):
    # a format, theme or size the figure cannot take ends the script at once, in one line,
    # with nothing written, rather than in a traceback after its runs
    good = {"--out": str(tmp_path / "figure.png"), "--theme": "light", "--size": "page"}
    bad = {"--out": (str(tmp_path / "figure.jpg"), "output: must end in .png, .svg or .pdf"),
           "--theme": ("pink", "theme: must be one of dark, light (got 'pink')"),
           "--size": ("poster", "size: must be one of column, page, slide")}
    for option, (value, message) in bad.items():
        argv = [word for pair in {**good, option: value}.items() for word in pair]
        done = subprocess.run([sys.executable, str(path), *argv], capture_output=True, text=True, timeout=120,
                              cwd=tmp_path)
        assert done.returncode == 2, done.stderr
        assert message in done.stderr.splitlines()[-1]
        assert "Traceback" not in done.stderr and list(tmp_path.iterdir()) == []
