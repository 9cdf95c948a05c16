"""`flocking run` as a user types it: outputs, conventions, repeatability and every error path."""

import math
import os
import signal
import subprocess
import sys
import time

import gsd.hoomd
import numpy as np
import pytest
from click.testing import CliRunner

import flocking
from flocking.cli import main

SRC = os.path.dirname(os.path.dirname(flocking.__file__))


def run(*args, check=True):
    result = CliRunner().invoke(main, ["run", *map(str, args)])
    if check:
        assert result.exit_code == 0, result.output
    return result


def test_default_like_run_writes_a_complete_folder(tmp_path):
    out = tmp_path / "r"
    run("--n", 300, "--steps", 25, "--every", 10, "--out", out, "--quiet")
    assert {p.name for p in out.iterdir()} == {"config.toml", "observables.csv", "trajectory.gsd", "checkpoint.npz",
                                               "snapshot.png", "polar_order.png"}
    with gsd.hoomd.open(out / "trajectory.gsd") as f:
        assert [fr.configuration.step for fr in f] == [0, 10, 20, 25]
        fr = f[-1]
        assert fr.configuration.dimensions == 2
        box = fr.configuration.box
        pos = fr.particles.position
        assert np.all(pos[:, :2] >= -box[:2] / 2) and np.all(pos[:, :2] < box[:2] / 2)
        assert np.all(pos[:, 2] == 0)
        speed = np.linalg.norm(fr.particles.velocity, axis=1)
        assert np.allclose(speed, 0.5, rtol=1e-6)
    traj = flocking.open(out / "trajectory.gsd")
    assert traj.model.n == 300 and traj.parameters["backend"] == "cpu"
    assert traj.parameters["run"]["every"] == 10
    lines = (out / "observables.csv").read_text().splitlines()
    assert lines[0] == "step,polar_order"
    assert len(lines) == 1 + 26
    steps, phi = np.loadtxt(out / "observables.csv", delimiter=",", skiprows=1, unpack=True)
    assert np.array_equal(steps, np.arange(26))
    assert np.all((phi >= 0) & (phi <= 1))
    # the last frame's polar order is the last row's
    assert traj[-1].polar_order == pytest.approx(phi[-1], abs=1e-6)


def test_config_repeats_the_run_exactly(tmp_path):
    a, b = tmp_path / "a", tmp_path / "b"
    run("--dim", 3, "--n", 200, "--box", "4,5,3", "--neighbours", "topological", "--k", 5, "--noise-type",
        "vectorial", "--noise", 0.3, "--alignment", 0.5, "--delay", 2, "--speeds", "uniform", "--update",
        "forward", "--dt", 0.5, "--seed", 11, "--steps", 30, "--every", 7, "--out", a, "-q")
    run("--config", a / "config.toml", "--out", b, "-q")
    for name in ("observables.csv", "config.toml"):
        assert (a / name).read_bytes() == (b / name).read_bytes()
    # the trajectories hold the same data (their bytes may differ: gsd lays frames out as flushed)
    result = CliRunner().invoke(main, ["compare", str(a), str(b)])
    assert result.exit_code == 0 and "identical data" in result.output


def test_command_line_overrides_the_config_file(tmp_path):
    cfg = tmp_path / "c.toml"
    cfg.write_text('n = 100\nbox = 5.0\nnoise = 0.5\nsteps = 3\nneighbours = "topological"\n')
    run("--config", cfg, "--noise", 2.0, "--out", tmp_path / "o", "-q")
    model = flocking.open(tmp_path / "o" / "trajectory.gsd").model
    assert model.noise == 2.0 and model.n == 100 and model.neighbours == "topological"


def test_every_zero_keeps_first_and_last(tmp_path):
    run("--n", 50, "--steps", 13, "--every", 0, "--out", tmp_path / "o", "-q")
    assert [f.step for f in flocking.open(tmp_path / "o" / "trajectory.gsd")] == [0, 13]


def test_noise_scale_unit_and_rectangular_box(tmp_path):
    run("--box", "4,5", "--density", 2, "--noise", 0.25, "--noise-scale", "unit", "--steps", 2,
        "--out", tmp_path / "o", "-q")
    traj = flocking.open(tmp_path / "o" / "trajectory.gsd")
    assert traj.model.noise == pytest.approx(np.pi / 2)
    assert traj.model.n == 40 and list(traj[0].box_lengths) == [4.0, 5.0]


def test_init_aligned_and_continue_from_a_trajectory(tmp_path):
    run("--n", 100, "--box", 5, "--init", "aligned", "--noise", 0.0, "--steps", 5, "--out", tmp_path / "a", "-q")
    traj = flocking.open(tmp_path / "a" / "trajectory.gsd")
    assert np.allclose(traj[0].headings, [1.0, 0.0])
    # continue: size, box and parameters come from the file; the step counter goes on
    run("--init", tmp_path / "a" / "trajectory.gsd", "--steps", 4, "--out", tmp_path / "b", "-q")
    cont = flocking.open(tmp_path / "b" / "trajectory.gsd")
    assert cont.model == traj.model
    assert cont[0].step == 5 and cont[-1].step == 9
    assert np.allclose(cont[0].points, traj[-1].points, atol=1e-6)


def test_run_3d_topological(tmp_path):
    run("--dim", 3, "--n", 400, "--neighbours", "topological", "--steps", 5, "--out", tmp_path / "o", "-q")
    f = flocking.open(tmp_path / "o" / "trajectory.gsd")[-1]
    assert f.dim == 3 and f.points.shape == (400, 3)
    assert np.allclose(np.linalg.norm(f.headings, axis=1), 1.0, atol=1e-6)


@pytest.mark.parametrize("args, message", [
    (["--noise", "7"], "--noise: must be in [0, 2*pi] for angular noise"),
    (["--noise", "-1"], "--noise: must be in [0, 2*pi]"),
    (["--alignment", "2"], "--alignment: must be in [0, 1]"),
    (["--delay", "-3"], "--delay: must be a whole number >= 0"),
    (["--n", "0"], "--n: must be a whole number >= 1"),
    (["--dim", "4"], "--dim: must be one of 2, 3"),
    (["--box", "4,5,6"], "--box: must be one number or 2 numbers for dim=2"),
    (["--box", "-2"], "--box: must be a finite number > 0"),
    (["--radius", "0"], "--radius: must be in (0, 1e+150]"),
    (["--k", "0"], "--k: must be a whole number >= 1"),
    (["--speed", "0"], "--speed: must be a finite number > 0"),
    (["--dt", "-1"], "--dt: must be a finite number > 0"),
    (["--seed", "-1"], "--seed: must be a whole number >= 0"),
    (["--steps", "-1"], "--steps: must be a whole number >= 0"),
    (["--every", "-1"], "--every: must be a whole number >= 0"),
    (["--n", "10", "--density", "1", "--box", "3"], "give at most two of them"),
    (["--init", "nowhere.gsd"], "--init: must be 'random', 'aligned' or an existing .gsd file"),
    (["--backend", "gpu"], "--backend: must be one of"),
    (["--noise-type", "gaussian"], "--noise-type: must be one of angular, vectorial (got 'gaussian')"),
    (["--update", "sideways"], "--update: must be one of backward, forward (got 'sideways')"),
    (["--n", "abc"], "--n: 'abc' is not a valid integer"),
    (["--noise", "loud"], "--noise: 'loud' is not a valid float"),
    (["--theme", "neon"], "--theme: must be one of dark, light (got 'neon')"),
    (["--dpi", "5"], "--dpi: must be in [10, 1000] (got 5.0)"),
    (["--format", "jpg"], "--format: must be one of png, svg, pdf (got 'jpg')"),
    (["--color", "red"], "--color: must be one of auto, heading, species, deviation (got 'red')"),
    (["--config", "missing.toml"], "--config: cannot read"),
])
def test_bad_input_is_refused_before_anything_is_written(tmp_path, args, message):
    out = tmp_path / "o"
    result = CliRunner().invoke(main, ["run", *args, "--out", str(out)])
    assert result.exit_code == 2
    assert result.output.startswith("Error: ") and message in result.output
    assert len(result.output.splitlines()) == 1  # one line: no usage block, no traceback
    assert not out.exists()


def test_bad_config_files(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text("nosie = 1.0\n")
    result = CliRunner().invoke(main, ["run", "--config", str(bad), "--out", str(tmp_path / "o")])
    assert result.exit_code == 2 and "nosie: unknown parameter; did you mean 'noise'?" in result.output
    bad.write_text("noise = [1, \n")
    result = CliRunner().invoke(main, ["run", "--config", str(bad), "--out", str(tmp_path / "o")])
    assert result.exit_code == 2 and "not valid TOML" in result.output
    bad.write_text('noise = "high"\n')
    result = CliRunner().invoke(main, ["run", "--config", str(bad), "--out", str(tmp_path / "o")])
    assert result.exit_code == 2 and "--noise: must be a number (got 'high')" in result.output
    assert not (tmp_path / "o").exists()


def test_corrupt_init_file_is_refused(tmp_path):
    bad = tmp_path / "bad.gsd"
    bad.write_bytes(b"this is not a gsd file at all" * 10)
    result = CliRunner().invoke(main, ["run", "--init", str(bad), "--out", str(tmp_path / "o")])
    assert result.exit_code == 2 and "--init: cannot read a frame" in result.output
    assert not (tmp_path / "o").exists()


def test_non_empty_output_folder_needs_force(tmp_path):
    out = tmp_path / "o"
    out.mkdir()
    (out / "keep.txt").write_text("precious")
    result = CliRunner().invoke(main, ["run", "--n", "20", "--steps", "2", "--out", str(out)])
    assert result.exit_code == 2 and "not empty; use --force" in result.output
    assert sorted(os.listdir(out)) == ["keep.txt"]
    run("--n", 20, "--steps", 2, "--out", out, "--force", "-q")
    assert (out / "trajectory.gsd").exists() and (out / "keep.txt").read_text() == "precious"


RUN_OUTPUTS = {"config.toml", "observables.csv", "trajectory.gsd", "checkpoint.npz"}


def test_force_replaces_an_earlier_run_entirely(tmp_path):
    """Nothing of the earlier run (pictures, movie, analysis) stays beside the new one."""
    out = tmp_path / "o"
    run("--n", 300, "--steps", 20, "--every", 10, "--out", out, "-q")
    assert CliRunner().invoke(main, ["analyze", str(out), "-q", "--no-plots", "--only", "polar,clusters"]).exit_code == 0
    (out / "movie.mp4").write_bytes(b"an old movie")
    (out / "trajectory.gsd.4242.tmp").write_bytes(b"left by a killed writer")
    before = set(os.listdir(out))
    assert {"analysis.json", "cluster_sizes.csv", "snapshot.png"} <= before
    result = run("--n", 50, "--steps", 3, "--out", out, "--force", "--no-plots")
    assert set(os.listdir(out)) == RUN_OUTPUTS
    assert f"removed {len(before)} files of an earlier run" in result.output
    assert flocking.open(out / "trajectory.gsd").model.n == 50


def test_force_keeps_what_flocking_did_not_write(tmp_path):
    out = tmp_path / "o"
    run("--n", 100, "--steps", 5, "--out", out, "-q")
    (out / "notes.txt").write_text("my notes")
    (out / "snapshot-for-talk.png").write_bytes(b"mine")
    (out / "analysis").mkdir()
    (out / "analysis" / "analysis.json").write_text("{}")
    result = run("--n", 60, "--steps", 3, "--out", out, "--force", "--no-plots")
    assert set(os.listdir(out)) == RUN_OUTPUTS | {"notes.txt", "snapshot-for-talk.png", "analysis"}
    assert (out / "notes.txt").read_text() == "my notes" and (out / "analysis" / "analysis.json").exists()
    assert "kept analysis, notes.txt, snapshot-for-talk.png" in result.output


def test_force_refuses_to_clear_the_trajectory_it_starts_from(tmp_path):
    out = tmp_path / "o"
    run("--n", 100, "--steps", 5, "--out", out, "-q")
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    result = run("--init", out / "trajectory.gsd", "--steps", 3, "--out", out, "--force", check=False)
    assert result.exit_code == 2 and "--init:" in result.output and "--force would clear" in result.output
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before
    # a bad parameter with --force is refused before anything is removed, too
    result = run("--n", 100, "--noise", 9, "--out", out, "--force", check=False)
    assert result.exit_code == 2 and {p.name: p.read_bytes() for p in out.iterdir()} == before


def help_of(command, param) -> str:
    """The help line of an option as ``--help`` shows it (with click's own ``[default: ...]``)."""
    import click

    return " ".join(param.get_help_record(click.Context(command, info_name=command.name))[1].split())


def test_help_shows_every_default():
    """Every option that takes a value shows its default, and it is the one a run uses."""
    from flocking.cli.run import run as run_command
    from flocking.config import RunConfig

    help_text = CliRunner().invoke(main, ["run", "--help"], terminal_width=400, max_content_width=400).output
    text = " ".join(help_text.split())
    used = RunConfig.from_dict({}).to_dict()  # what a run without options resolves to
    derived = {"n": "density x volume", "density": "2 when needed", "box": "32 when needed",
               "out": "runs/run-NNNN, a new one", "plots": "--plots; with --resume, as the run began",
               "movie": "--no-movie; with --resume, as the run began", "noise_scale": "radians",
               "vision": "pi, all around", "field": "none", "boundary": "periodic",
               "theme": "dark", "dpi": "200", "fmt": "png", "color": "auto", "obstacles": "none",
               "species_b": "none, one species", "cross_coupling": "1",
               "cohesion_radii": "0.2,0.5,0.8 x R", "fields": "none", "fields_every": "as --every"}
    plain = flocking.Model()  # config.toml leaves out extensions that are off: their defaults are Model's
    assert plain.vision == math.pi and plain.field is None
    assert used["n"] == 2048 and used["box"] == [32.0, 32.0]  # density 2 x 32 x 32
    checked = set()
    for param in run_command.params:
        if param.name in ("config_file", "resume_dir", "force", "quiet", "show", "help"):
            continue
        value = used.get(param.name, getattr(plain, param.name, None))
        shown = derived.get(param.name, f"{value:g}" if isinstance(value, float) else str(value))
        assert help_of(run_command, param).endswith(f"[default: {shown}]"), param.name
        assert help_of(run_command, param) in text, param.name
        checked.add(param.name)
    assert {"neighbours", "noise_type", "update", "speeds", "noise_scale", "precision", "backend", "obstacles",
            "species_b", "cross_coupling", "theme", "fmt"} <= checked
    # flocking play shares the model options and shows the sizes a new tab starts with
    play = " ".join(CliRunner().invoke(main, ["play", "--help"], terminal_width=400, max_content_width=400)
                    .output.split())
    assert "density, box). [default: 4000]" in play and "[default: from n and density]" in play


def test_warm_up_model_takes_the_kernels_of_the_run():
    """The tiny model compiled before a run has three cells a side exactly when the run does."""
    from flocking.backends.cells import cell_grid
    from flocking.cli.run import tiny_model

    for model in (flocking.Model(n=100_000), flocking.Model(n=100_000, radius=2.5), flocking.Model(dim=3, radius=3),
                  flocking.Model(box=7, radius=2.5), flocking.Model(n=10**6, density=0.05),
                  flocking.Model(dim=3, box=[40, 40, 5], radius=2)):
        tiny = tiny_model(model)
        assert tiny.n <= max(64, round(model.density * (3.5 * model.radius) ** model.dim) + 1)
        assert tiny.density == pytest.approx(model.density, rel=0.05)
        assert (cell_grid(tiny) >= 3).all() == (cell_grid(model) >= 3).all(), model


def test_analyse_is_accepted_and_listed_once(tmp_path):
    run("--n", 100, "--steps", 5, "--out", tmp_path / "o", "-q", "--no-plots")
    result = CliRunner().invoke(main, ["analyse", str(tmp_path / "o"), "--only", "polar", "-q", "--no-plots"])
    assert result.exit_code == 0, result.output
    assert (tmp_path / "o" / "analysis.json").exists()
    commands = CliRunner().invoke(main, ["--help"]).output.split("Commands:")[1].split()
    assert commands.count("analyze") == 1 and "analyse" not in commands
    assert "No such command" in CliRunner().invoke(main, ["analyzer"]).output


def test_default_output_folders_never_overwrite(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    run("--n", 20, "--steps", 1, "-q")
    run("--n", 20, "--steps", 1, "-q")
    assert sorted(os.listdir(tmp_path / "runs")) == ["run-0001", "run-0002"]


def test_interrupted_run_leaves_valid_files(tmp_path):
    out = tmp_path / "o"
    env = dict(os.environ, PYTHONPATH=SRC)
    proc = subprocess.Popen([sys.executable, "-m", "flocking", "run", "--n", "20000", "--steps", "100000",
                             "--every", "5", "--out", str(out)], env=env, stderr=subprocess.PIPE, text=True)
    deadline = time.time() + 60
    while time.time() < deadline:
        if (out / "observables.csv").exists() and len((out / "observables.csv").read_text().splitlines()) > 30:
            break
        time.sleep(0.2)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 130
    assert "stopped at step" in err and "Traceback" not in err
    traj = flocking.open(out / "trajectory.gsd")
    steps = [f.step for f in traj]
    assert len(steps) >= 2 and steps[-1] < 100000
    rows = np.loadtxt(out / "observables.csv", delimiter=",", skiprows=1)
    assert rows[-1, 0] == steps[-1]  # the stop step's frame is written
    assert np.array_equal(rows[:, 0], np.arange(len(rows)))


def test_compilation_is_announced_before_it_starts(monkeypatch):
    """warm_up says so when numba starts compiling (its cache-miss event), not after."""
    import numba

    from flocking.cli import run as run_module
    from flocking.config import RunConfig

    events = []

    @numba.njit  # not cached: compiled on its first call in this process
    def fresh(x):
        return x + 1

    class Compiling:
        def __init__(self, *args, **kwargs):
            self.backend = self

        def run(self, steps):
            events.append("compile starts")
            fresh(1)
            events.append("compiled")

        def frame_arrays(self):
            return None

    monkeypatch.setattr("flocking.simulation.Simulation", Compiling)
    took = run_module.warm_up(RunConfig.from_dict({"n": 10, "box": 5}), announce=lambda: events.append("announced"))
    assert events == ["compile starts", "announced", "compiled"] and took > 0


def test_cached_kernels_are_not_announced():
    from flocking.cli import run as run_module
    from flocking.config import RunConfig

    cfg = RunConfig.from_dict({"n": 10, "box": 5})
    run_module.warm_up(cfg)  # compiles or loads
    said = []
    assert run_module.warm_up(cfg, announce=lambda: said.append(1)) is None and said == []


@pytest.mark.slow
def test_first_run_of_a_kind_announces_compilation_with_an_empty_cache(tmp_path):
    env = dict(os.environ, PYTHONPATH=SRC, NUMBA_CACHE_DIR=str(tmp_path / "cache"))
    proc = subprocess.run([sys.executable, "-m", "flocking", "run", "--n", "100", "--steps", "2", "--no-plots",
                           "--out", str(tmp_path / "o")], env=env, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr
    lines = proc.stderr.splitlines()
    announce = next(i for i, line in enumerate(lines) if "compiling the kernels" in line)
    done = next(i for i, line in enumerate(lines) if "compiled in" in line)
    assert announce < done
