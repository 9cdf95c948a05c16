"""What the commands leave on disk: every file made as the umask says, and nothing at all
when a command refuses its input."""

import os
import stat

import pytest
from click.testing import CliRunner

import flocking
from flocking.cli import main

SWEEP = """
[sweep]
seed = 3
[base]
n = 20
box = 4.0
steps = 4
[grid]
noise = [0.5, 1.0]
"""


def invoke(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


def tree(root) -> dict[str, int]:
    """Every file and folder under ``root`` (relative path -> permission bits)."""
    found = {}
    for folder, dirs, files in os.walk(root):
        for name in dirs + files:
            path = os.path.join(folder, name)
            found[os.path.relpath(path, root)] = stat.S_IMODE(os.stat(path).st_mode)
    return found


@pytest.fixture
def umask():
    """Set the process's umask for a test; the one before comes back after it."""
    before = os.umask(0o022)
    os.umask(before)
    yield lambda mask: os.umask(mask)
    os.umask(before)


@pytest.mark.parametrize("mask", [0o022, 0o002])
def test_every_output_is_made_as_the_umask_says(tmp_path, monkeypatch, umask, mask):
    """gsd made trajectory.gsd 0640 whatever the umask; every output is now 0666 & ~umask
    (0644 under 022, 0664 under 002), and every folder 0777 & ~umask."""
    monkeypatch.chdir(tmp_path)
    umask(mask)
    result = invoke("run", "--n", 50, "--box", 5, "--steps", 4, "--every", 2, "--movie", "--out", "r", "-q")
    assert result.exit_code == 0, result.output
    assert invoke("run", "--resume", "r", "--steps", 6, "-q").exit_code == 0  # gsd appends to the file it made
    assert invoke("analyze", "r", "--only", "polar,clusters", "--out", "a", "-q").exit_code == 0
    assert invoke("animate", "r", "-o", "frame.svg", "-q").exit_code == 0
    made = {"r/trajectory.gsd", "r/observables.csv", "r/config.toml", "r/checkpoint.npz", "r/movie.mp4",
            "r/snapshot.png", "r/polar_order.png", "a/analysis.json", "a/cluster_sizes.png", "frame.svg"}
    if _has("xarray", "netCDF4"):
        (tmp_path / "grid.toml").write_text(SWEEP)
        result = invoke("sweep", "grid.toml", "--serial", "--out", "s", "-q")
        assert result.exit_code == 0, result.output
        assert invoke("plot-sweep", "s", "--out", "s/figure.png", "-q").exit_code == 0
        made |= {"s/results.nc", "s/figure.png"}
    found = tree(tmp_path)
    assert made <= found.keys()
    files = {p: m for p, m in found.items() if os.path.isfile(tmp_path / p) and p != "grid.toml"}
    folders = {p: m for p, m in found.items() if os.path.isdir(tmp_path / p)}
    assert files == dict.fromkeys(files, 0o666 & ~mask)
    assert folders == dict.fromkeys(folders, 0o777 & ~mask)


def _has(*modules) -> bool:
    import importlib.util

    return all(importlib.util.find_spec(m) is not None for m in modules)


def test_the_writer_keeps_the_mode_of_a_trajectory_it_appends_to(tmp_path, umask):
    path = tmp_path / "t.gsd"
    umask(0o022)
    sim = flocking.Simulation(flocking.Model(n=10, box=4.0))
    sim.writers.append(flocking.GSDWriter(path, every=1))
    sim.run(2)
    os.chmod(path, 0o600)
    sim.writers[0].close()
    sim.writers[:] = [flocking.GSDWriter(path, every=1, mode="a")]
    sim.run(2)
    sim.writers[0].close()
    assert stat.S_IMODE(os.stat(path).st_mode) == 0o600
    assert [f.step for f in flocking.open(path)] == [0, 1, 2, 3, 4]


@pytest.fixture
def run_dir(tmp_path_factory):
    out = tmp_path_factory.mktemp("done") / "run"
    assert invoke("run", "--n", 40, "--box", 5, "--steps", 4, "--every", 2, "--out", out, "-q",
                  "--no-plots").exit_code == 0
    return out


REFUSED = [
    # flocking run, into the default folder (runs/run-0001) or a named one
    (["run", "--noise", "9"], "--noise: must be in [0, 2*pi]"),
    (["run", "--n", "10", "--box", "8", "--obstacle", "4,4,0.2"], "--obstacle: must be radii above one step"),
    (["run", "--obstacle", "4,4"], "--obstacle: must be X,Y,R in 2D"),
    (["run", "--species-b", "1"], "--species-b: must be a fraction in (0, 1) (got 1.0)"),
    (["run", "--cross-coupling", "-1"], "--cross-coupling: needs two species"),
    (["run", "--precision", "float32"], "--precision: 'float32' needs the cuda backend"),
    (["run", "--format", "jpg", "--out", "o"], "--format: must be one of png, svg, pdf (got 'jpg')"),
    (["run", "--init", "missing.gsd", "--out", "o"], "--init: must be 'random', 'aligned' or an existing .gsd file"),
    (["run", "--config", "center.toml"], "obstacles: unknown key 'center'"),
    (["run", "--out", "notes.txt/run"], "--out: cannot make 'notes.txt/run': "),
    (["run", "--out", "notes.txt"], "--out: 'notes.txt' exists and is not a folder"),
    (["run", "--resume", "nowhere"], "--resume: 'nowhere' is not a run folder"),
    (["run", "--n", "100", "--box", "16", "--steps", "1", "--field", "0,0", "--field-strength", "0.5",
      "--backend", "reference", "--out", "X"], "--field: "),
    # the other commands that write
    (["animate", "{run}", "-o", "x.mov"], "--out: must end in .mp4 or .gif (a movie), or .png, .svg or .pdf"),
    (["animate", "{run}", "-o", "nowhere/x.png"], "--out: no folder 'nowhere' to write 'x.png' in"),
    (["animate", "{run}", "--first-frame", "5", "-o", "m.gif"], "--first-frame: must be a frame index from -3 to 2"),
    (["animate", "{run}", "--first-frame", "2", "--last-frame", "1", "-o", "m.gif"], "--last-frame: must not come"),
    (["animate", "{run}", "--frame", "3", "-o", "x.png"], "--frame: must be a frame index from -3 to 2"),
    (["animate", "{run}", "--rotate", "-o", "m.mp4"], "--rotate: turns the camera around a 3D box"),
    (["analyze", "{run}", "--only", "polar,nope", "--out", "a"], "--only: must be a comma-separated list"),
    (["analyze", "{run}", "--cluster-radius", "-1", "--out", "a"], "--cluster-radius: "),
    (["analyze", "{run}", "--out", "notes.txt"], "--out: 'notes.txt' exists and is not a folder"),
    (["sweep", "bad.toml"], "grid.nosie: unknown parameter; did you mean 'noise'?"),
    (["sweep", "good.toml", "--results", "r.txt"], "--results: must end in .nc"),
    (["sweep", "good.toml", "--out", "notes.txt"], "--out: 'notes.txt' exists and is not a folder"),
    (["plot-sweep", "nothing.nc", "--out", "f.jpg"], "--out: must end in .png, .svg or .pdf"),
    (["bench", "--repeats", "0"], "--repeats: must be at least 1"),
    (["bench", "--out", "notes.txt"], "--out: 'notes.txt' exists and is not a folder"),
]


@pytest.mark.parametrize("args, message", REFUSED)
def test_a_refused_command_writes_nothing(tmp_path, monkeypatch, run_dir, args, message):
    """Bad input of every kind (the model, its extensions, a backend's precision, output
    paths and formats, a config file, frames that do not exist) is refused in one line,
    exit code 2, before a file or folder is made."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "notes.txt").write_text("mine")
    (tmp_path / "center.toml").write_text("n = 100\nobstacles = [{center = [8.0, 8.0], radius = 2.0}]\n")
    (tmp_path / "bad.toml").write_text("[grid]\nnosie = [1.0, 2.0]\n")
    (tmp_path / "good.toml").write_text(SWEEP)
    before = tree(tmp_path)
    run_before = tree(run_dir)
    result = invoke(*[a.format(run=run_dir) for a in args])
    assert result.exit_code == 2, result.output
    assert result.output.startswith("Error: ") and message in result.output
    assert len(result.output.splitlines()) == 1
    assert tree(tmp_path) == before and tree(run_dir) == run_before
