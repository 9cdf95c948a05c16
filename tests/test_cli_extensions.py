"""`flocking run --obstacle`, `--species-b`, `--cross-coupling` and `--cohesion`: the common
extension cases as options, what they become in the model, and their one-line refusals."""

import re
import tomllib

import numpy as np
import pytest
from click.testing import CliRunner

import flocking
from flocking.cli import main
from flocking.cli.run import CONFIG_EXAMPLE
from flocking.config import RunConfig


def run(*args, check=True):
    result = CliRunner().invoke(main, ["run", *map(str, args)])
    if check:
        assert result.exit_code == 0, result.output
    return result


def test_obstacles_are_discs_in_box_coordinates_that_no_particle_enters(tmp_path):
    out = tmp_path / "o"
    run("--n", 300, "--box", 16, "--speed", 0.3, "--steps", 40, "--every", 4, "--obstacle", "4,12,2.5",
        "--obstacle", "11.5,4,1.5", "--out", out, "-q", "--no-plots")
    traj = flocking.open(out / "trajectory.gsd")
    assert [(o.centre, o.radius) for o in traj.model.obstacles] == [((4.0, 12.0), 2.5), ((11.5, 4.0), 1.5)]
    assert "obstacles = [{centre = [4.0, 12.0], radius = 2.5}, {centre = [11.5, 4.0], radius = 1.5}]" in \
        (out / "config.toml").read_text()
    box = np.array([16.0, 16.0])
    for frame in traj:
        corner = frame.points[:, :2] + box / 2  # the file is centred; the options are box coordinates
        for (cx, cy), radius in [((4.0, 12.0), 2.5), ((11.5, 4.0), 1.5)]:
            d = corner - (cx, cy)
            d -= box * np.round(d / box)
            assert np.hypot(*d.T).min() >= radius
    # an obstacle near a corner of the box in corner coordinates is where it is drawn: its disc empty
    hits = np.histogram2d(*np.concatenate([f.points[:, :2] + 8 for f in traj]).T, bins=16, range=[[0, 16]] * 2)[0]
    assert hits[3, 11] == 0 and hits[11, 3] == 0 and hits[11, 11] > 0


def test_a_sphere_in_3d(tmp_path):
    run("--dim", 3, "--n", 200, "--box", 8, "--steps", 3, "--obstacle", "4,4,4,1.5", "--out", tmp_path / "o", "-q",
        "--no-plots")
    model = flocking.open(tmp_path / "o" / "trajectory.gsd").model
    assert [(o.centre, o.radius) for o in model.obstacles] == [((4.0, 4.0, 4.0), 1.5)]


def test_the_dimension_of_a_config_file_sets_what_an_obstacle_takes(tmp_path):
    cfg = tmp_path / "c.toml"
    cfg.write_text("dim = 3\nn = 100\nbox = 8.0\nsteps = 1\n")
    run("--config", cfg, "--obstacle", "4,4,4,1.5", "--out", tmp_path / "o", "-q", "--no-plots")
    assert flocking.open(tmp_path / "o" / "trajectory.gsd").model.obstacles[0].centre == (4.0, 4.0, 4.0)
    result = run("--config", cfg, "--obstacle", "4,4,1.5", "--out", tmp_path / "p", check=False)
    assert result.exit_code == 2 and "--obstacle: must be X,Y,Z,R in 3D" in result.output


def test_two_species_and_their_coupling(tmp_path):
    out = tmp_path / "o"
    run("--n", 200, "--box", 10, "--steps", 5, "--species-b", 0.25, "--cross-coupling", -1, "--out", out, "-q",
        "--no-plots")
    model = flocking.open(out / "trajectory.gsd").model
    assert model.species_names == ("A", "B") and model.species_counts == (150, 50)
    assert model.coupling == ((1.0, -1.0), (-1.0, 1.0))
    assert (out / "observables.csv").read_text().splitlines()[0] == "step,polar_order,polar_order_A,polar_order_B"
    import gsd.hoomd

    with gsd.hoomd.open(out / "trajectory.gsd") as f:
        assert np.bincount(f[0].particles.typeid).tolist() == [150, 50]
    # without --cross-coupling the two species align with each other: no coupling matrix
    run("--n", 200, "--box", 10, "--steps", 1, "--species-b", 0.5, "--out", tmp_path / "p", "-q", "--no-plots")
    model = flocking.open(tmp_path / "p" / "trajectory.gsd").model
    assert model.species_counts == (100, 100) and model.coupling is None


def test_the_options_replace_what_a_config_file_says(tmp_path):
    cfg = tmp_path / "c.toml"
    cfg.write_text('n = 90\nbox = 12.0\nsteps = 2\nobstacles = [{centre = [3.0, 3.0], radius = 1.0}]\n'
                   'species = [{fraction = 0.5}, {fraction = 0.3}, {fraction = 0.2}]\n'
                   'coupling = [[1, 0, 0], [0, 1, 0], [0, 0, 1]]\n')
    run("--config", cfg, "--obstacle", "6,6,2", "--species-b", "0.4", "--out", tmp_path / "a", "-q", "--no-plots")
    model = flocking.open(tmp_path / "a" / "trajectory.gsd").model
    assert [(o.centre, o.radius) for o in model.obstacles] == [((6.0, 6.0), 2.0)]
    assert model.species_counts == (54, 36) and model.coupling is None  # the file's 3 x 3 matrix went with its species
    # a file with two species takes --cross-coupling for them
    cfg.write_text('n = 90\nbox = 12.0\nsteps = 2\nspecies = [{fraction = 0.5}, {fraction = 0.5, noise = 2.0}]\n')
    run("--config", cfg, "--cross-coupling", "0.5", "--out", tmp_path / "b", "-q", "--no-plots")
    model = flocking.open(tmp_path / "b" / "trajectory.gsd").model
    assert model.coupling == ((1.0, 0.5), (0.5, 1.0)) and model.species[1].noise == 2.0


@pytest.mark.parametrize("args, message", [
    (["--obstacle", "8,8"], "--obstacle: must be X,Y,R in 2D, centre in box coordinates and radius, such as 16,16,4 "
                            "(got '8,8')"),
    (["--dim", "3", "--obstacle", "8,8,2"], "--obstacle: must be X,Y,Z,R in 3D"),
    (["--obstacle", "8,eight,2"], "--obstacle: must be 3 numbers such as 16,16,4 (got '8,eight,2')"),
    (["--box", "16", "--obstacle", "8,8,9"], "--obstacle: obstacle 0 must keep at least one step (0.5) from its own "
                                              "periodic image"),
    (["--box", "16", "--obstacle", "8,8,2", "--obstacle", "10,8,2"], "--obstacle: obstacles 0 and 1 overlap"),
    (["--box", "16", "--obstacle", "20,8,2"], "--obstacle: must be centres inside the box"),
    (["--species-b", "0"], "--species-b: must be a fraction in (0, 1) (got 0.0)"),
    (["--species-b", "1.5"], "--species-b: must be a fraction in (0, 1) (got 1.5)"),
    (["--n", "10", "--species-b", "0.01"], "--species-b: "),
    (["--cross-coupling", "-1"], "--cross-coupling: needs two species, from --species-b or a config file (got 0)"),
    (["--species-b", "0.5", "--cross-coupling", "2000"], "--cross-coupling: "),
    (["--species-b", "0.5", "--cross-coupling", "nan"], "--cross-coupling: "),
    (["--species-b", "half"], "--species-b: 'half' is not a valid float"),
    (["--cohesion", "-1"], "--cohesion: must be in [0, 1000] (got -1.0)"),
    (["--cohesion", "1", "--cohesion-radii", "0.5,0.2,0.8"], "--cohesion-radii: must be three lengths r_c, r_e, r_a "
                                                             "with 0 <= r_c < r_e < r_a"),
    (["--cohesion", "1", "--cohesion-radii", "0.2,0.5"], "--cohesion-radii: must be three lengths"),
])
def test_refusals_are_one_line_naming_the_option(tmp_path, args, message):
    out = tmp_path / "o"
    result = run(*args, "--out", out, check=False)
    assert result.exit_code == 2 and result.output.startswith(f"Error: {message}"), result.output
    assert len(result.output.splitlines()) == 1 and not out.exists()


def test_cohesion_and_its_radii_reach_the_model_and_the_config(tmp_path):
    out = tmp_path / "c"
    run("--n", 200, "--box", 10, "--cohesion", 1.5, "--cohesion-radii", "0.1,0.4,0.7", "--steps", 3, "--out", out,
        "-q", "--no-plots")
    config = tomllib.loads((out / "config.toml").read_text())
    assert config["cohesion"] == 1.5 and config["cohesion_radii"] == [0.1, 0.4, 0.7]
    model = RunConfig.from_dict(RunConfig.load(out / "config.toml")).model
    assert model.extensions == ("cohesion",) and model.cohesion_radii == (0.1, 0.4, 0.7)
    # the radii default to Gregoire and Chate's, in units of R, written out resolved
    run("--n", 200, "--box", 10, "--radius", 2, "--cohesion", 1, "--steps", 1, "--out", tmp_path / "d", "-q",
        "--no-plots")
    assert tomllib.loads((tmp_path / "d" / "config.toml").read_text())["cohesion_radii"] == [0.4, 1.0, 1.6]


def test_cross_coupling_refused_for_a_config_file_with_three_species(tmp_path):
    cfg = tmp_path / "c.toml"
    cfg.write_text("n = 90\nspecies = [{fraction = 0.5}, {fraction = 0.3}, {fraction = 0.2}]\n")
    result = run("--config", cfg, "--cross-coupling", "-1", "--out", tmp_path / "o", check=False)
    assert result.output == "Error: --cross-coupling: needs two species, from --species-b or a config file (got 3)\n"


def test_the_example_config_of_run_help_is_a_valid_run():
    """What `flocking run --help` shows for the lists and tables no option sets is a config
    that runs: three species, their coupling matrix, two obstacles, walls and a field."""
    text = "\n".join(line[2:] for line in CONFIG_EXAMPLE.splitlines() if line.startswith("  "))
    data = tomllib.loads(text)
    cfg = RunConfig.from_dict(data)
    assert len(cfg.model.species) == 3 and len(cfg.model.obstacles) == 2 and cfg.model.coupling[0][2] == -1
    help_text = CliRunner().invoke(main, ["run", "--help"], terminal_width=120).output
    for line in text.splitlines():
        assert line.strip() in help_text  # shown unwrapped
    assert re.search(r"box coordinates, each axis from 0 to L", " ".join(help_text.split()))
