"""Walls, obstacles and species in pictures: checked pixel by pixel, in every style and theme."""

from __future__ import annotations

import os

import numpy as np
import pytest
from click.testing import CliRunner

import flocking
from flocking.cli import main
from flocking.model import ParameterError
from flocking.space import Space
from flocking.viz.colors import THEMES
from flocking.viz.density import DensityField
from flocking.viz.live import frame_of
from flocking.viz.particles import box_coordinates
from flocking.viz.perspective import perspective_image
from flocking.viz.scene import Scene, plot_frame
from flocking.viz.style import species_colors

BOX = (20.0, 20.0)
OBSTACLE = [4.0, 3.0, 3.0]  # centre (centred coordinates), radius


def frame_2d(positions, angles, typeid=None, types=None, walls=(True, False), obstacles=(OBSTACLE,)):
    n = len(positions)
    points = np.zeros((n, 3), np.float32)
    points[:, :2] = positions
    velocities = np.zeros((n, 3), np.float32)
    velocities[:, 0], velocities[:, 1] = 0.5 * np.cos(angles), 0.5 * np.sin(angles)
    return flocking.Frame(0, 2, BOX, points, velocities, typeid=typeid, types=types, walls=walls,
                          obstacles=np.array(obstacles).reshape(-1, 3))


def grid_frame(spacing=1.0, **options):
    """Particles on a square grid filling the box (none inside the obstacle), all heading +x."""
    c = np.arange(-BOX[0] / 2 + spacing / 2, BOX[0] / 2, spacing)
    x, y = np.meshgrid(c, c)
    pos = np.column_stack([x.ravel(), y.ravel()])
    pos = pos[np.hypot(*(pos - OBSTACLE[:2]).T) > OBSTACLE[2]]
    return frame_2d(pos, np.zeros(len(pos)), **options)


def pixel(scene, rgb, x, y):
    px, py = scene.ax.transData.transform(box_coordinates([x, y], scene.box))  # (x, y) centred, as frames are
    return rgb[int(round(rgb.shape[0] - py)), int(round(px))].astype(int)


def near(colour, expected, tolerance=6) -> bool:
    return np.abs(np.asarray(colour, float) - np.asarray(expected, float) * 255).max() <= tolerance


@pytest.mark.parametrize("theme", ["dark", "light"])
@pytest.mark.parametrize("style", ["arrows", "density"])
def test_obstacle_is_solid_and_walls_are_drawn_only_on_wall_axes(theme, style):
    # particles everywhere, and two put inside the obstacle on purpose: none may show through
    frame = grid_frame()
    inside = frame_2d([[4.0, 3.0], [5.5, 3.0]], [0.0, 1.0])
    points = np.concatenate([frame.points, inside.points])
    velocities = np.concatenate([frame.velocities, inside.velocities])
    frame = flocking.Frame(0, 2, BOX, points, velocities, walls=(True, False), obstacles=[OBSTACLE])
    t = THEMES[theme]
    scene = Scene.for_frame(frame, theme=theme, style=style, size=4, dpi=100, time_label=False, color="heading")
    rgb = scene.draw(frame).rgb()
    for dx, dy in [(0, 0), (1.5, 0), (-2.0, 1.0), (0.5, -2.2)]:
        assert near(pixel(scene, rgb, 4.0 + dx, 3.0 + dy), t.obstacle), (dx, dy)
    # the walls (x = +-10) are solid lines in the text colour, on their whole length
    for y in (-8.0, 0.0, 8.0):
        assert near(pixel(scene, rgb, -10.0, y), t.text, 10) and near(pixel(scene, rgb, 10.0, y), t.text, 10)
    # the periodic sides (y = +-10) are not
    for x in (-8.0, 0.0):
        assert not near(pixel(scene, rgb, x, 10.0), t.text, 60) and not near(pixel(scene, rgb, x, -10.0), t.text, 60)


def test_walls_on_the_other_axis_and_no_walls():
    frame = grid_frame(walls=(False, True), obstacles=())
    scene = Scene.for_frame(frame, theme="dark", style="arrows", size=4, dpi=100, time_label=False)
    rgb = scene.draw(frame).rgb()
    text = THEMES["dark"].text
    assert near(pixel(scene, rgb, 0.0, 10.0), text, 10) and near(pixel(scene, rgb, 0.0, -10.0), text, 10)
    assert not near(pixel(scene, rgb, -10.0, 0.0), text, 60)
    assert len(scene.artist.boundaries) == 2  # two lines, no disc
    plain = Scene.for_frame(grid_frame(walls=(False, False), obstacles=()), size=4, dpi=100)
    assert plain.draw(grid_frame(walls=(False, False), obstacles=())).artist.boundaries == []


def test_an_obstacle_across_a_periodic_side_shows_on_both_sides():
    frame = frame_2d([[0.0, 0.0]], [0.0], walls=(False, False), obstacles=[[9.0, 0.0, 2.0]])
    scene = Scene.for_frame(frame, theme="light", style="arrows", size=4, dpi=100, time_label=False)
    rgb = scene.draw(frame).rgb()
    obstacle = THEMES["light"].obstacle
    assert near(pixel(scene, rgb, 9.5, 0.0), obstacle) and near(pixel(scene, rgb, -9.5, 0.0), obstacle)
    walled_x = Space(BOX, (True, False), [[9.0, 0.0, 2.0]], (-10.0, -10.0))  # no image across a wall
    np.testing.assert_allclose(walled_x.obstacle_images(), [[9.0, 0.0, 2.0]])


@pytest.mark.parametrize("theme", ["dark", "light"])
def test_two_species_get_two_colours_and_a_legend_naming_them(theme):
    positions = np.array([[-6.0, -6.0], [6.0, -6.0], [-6.0, 6.0], [-2.0, -2.0]])
    typeid = [0, 1, 1, 0]
    frame = frame_2d(positions, np.zeros(4), typeid=typeid, types=["prey", "predator"], obstacles=())
    scene = Scene.for_frame(frame, theme=theme, style="arrows", size=4, dpi=100, time_label=False)
    assert scene.color == "species"  # the default for several species
    rgb = scene.draw(frame).rgb()
    colours = species_colors(2, THEMES[theme])
    assert np.abs(colours[0] - colours[1]).max() > 0.3
    for (x, y), s in zip(positions, typeid):
        assert near(pixel(scene, rgb, x, y), colours[s], 12), (x, y)
    texts = [t.get_text() for t in scene.key_axes.texts]
    assert texts[0] == "species" and "prey" in texts and "predator" in texts
    # coloured by heading instead: both species heading +x get the same colour, and the wheel
    by_heading = Scene.for_frame(frame, theme=theme, style="arrows", size=4, dpi=100, time_label=False,
                                 color="heading")
    rgb = by_heading.draw(frame).rgb()
    assert np.abs(pixel(by_heading, rgb, -6, -6) - pixel(by_heading, rgb, 6, -6)).max() <= 12
    assert "prey" not in [t.get_text() for t in by_heading.key_axes.texts]


def test_one_species_is_coloured_by_heading_unless_asked():
    frame = frame_2d([[0.0, 0.0]], [0.0], obstacles=())
    assert Scene.for_frame(frame, size=3, dpi=50).color == "heading"
    assert Scene.for_frame(frame, size=3, dpi=50, color="species").color == "species"


def test_plot_frame_on_given_axes_draws_walls_obstacles_and_a_species_legend():
    from matplotlib.figure import Figure

    frame = frame_2d([[-6.0, -6.0], [6.0, -6.0]], [0.0, 0.0], typeid=[0, 1], types=["A", "B"])
    ax = Figure().subplots()
    plot_frame(frame, ax=ax)
    assert [t.get_text() for t in ax.get_legend().get_texts()] == ["A", "B"]
    assert len(ax.collections) == 2 and len(ax.lines) == 2  # arrows and discs; two wall lines
    ax = Figure().subplots()
    plot_frame(frame, ax=ax, color="heading")
    assert ax.get_legend() is None


def test_density_is_cut_at_walls_and_counts_only_free_space():
    frame = grid_frame(spacing=0.25)
    shape = (80, 80)
    holes = Space.of_frame(frame).obstacle_images()
    field = DensityField(frame.positions, frame.headings, BOX, shape, walls=frame.walls, obstacles=holes)
    rho = 16.0  # particles per unit area on the grid
    free = field.free
    # beside the walls, around the obstacle and in the open: the same density (within the grid's
    # discreteness), where cutting the kernel without dividing by the free area would halve it
    assert np.abs(field.density[free] / rho - 1).max() < 0.08
    assert (field.density[~free] == 0).all()
    # nothing leaks across a wall: particles in the left half only leave the right wall dark
    left = frame.positions[:, 0] < 0
    walled = DensityField(frame.positions[left], frame.headings[left], BOX, shape, walls=(True, False))
    periodic = DensityField(frame.positions[left], frame.headings[left], BOX, shape)
    assert walled.density[:, -1].max() < 1e-6 * rho < periodic.density[:, -1].max()


def test_density_mixes_the_species_colours_in_their_proportions():
    frame = grid_frame(spacing=0.25, obstacles=())
    typeid = (frame.positions[:, 0] > 0).astype(int)
    field = DensityField(frame.positions, frame.headings, BOX, (64, 64), walls=frame.walls, typeid=typeid, types=2)
    np.testing.assert_allclose(field.fractions.sum(axis=0), 1.0, atol=1e-9)
    assert field.fractions[0, :, :16].min() > 0.99 and field.fractions[1, :, -16:].min() > 0.99
    frame = flocking.Frame(0, 2, BOX, frame.points, frame.velocities, typeid=typeid, types=["L", "R"],
                           walls=frame.walls)
    for theme in ("dark", "light"):
        scene = Scene.for_frame(frame, theme=theme, style="density", size=4, dpi=100, time_label=False)
        rgb = scene.draw(frame).rgb()
        colours = species_colors(2, THEMES[theme])
        left, right = pixel(scene, rgb, -6, 0) / 255, pixel(scene, rgb, 6, 0) / 255
        # the same brightness scale applies to both; their hues are the species'
        assert np.argmax(np.abs(left - right)) == np.argmax(np.abs(colours[0] - colours[1]))
        assert np.dot(left - right, colours[0] - colours[1]) > 0


def test_3d_obstacles_are_spheres_that_hide_particles_and_wall_edges_stand_out():
    box = (8.0, 8.0, 8.0)
    dark = THEMES["dark"]
    inside = perspective_image(np.zeros((1, 3)), np.array([[1.0, 0.0, 0.0]]), box, 96, dark, length=1.0,
                               colors=np.array([[1.0, 0.0, 0.0]]), obstacles=np.array([[0.0, 0.0, 0.0, 2.0]]))
    centre = inside[44:52, 44:52]
    assert centre.min() > 0.15 and np.ptp(centre, axis=-1).max() < 0.05  # grey, not the red particle
    empty = perspective_image(np.zeros((0, 3)), np.zeros((0, 3)), box, 96, dark)
    assert empty[44:52, 44:52].max() < 0.01
    # wall edges: in the text colour (light grey, fogged with depth), far brighter than the plain
    # edges' grey, and on the 8 edges of the two wall faces only
    walled = perspective_image(np.zeros((0, 3)), np.zeros((0, 3)), box, 96, dark, walls=(True, False, False))
    everywhere = perspective_image(np.zeros((0, 3)), np.zeros((0, 3)), box, 96, dark, walls=(True, True, True))
    assert np.mean(dark.edge) < 0.45 < 0.6 < np.mean(dark.text)
    count = [int((img.mean(axis=-1) > 0.45).sum()) for img in (empty, walled, everywhere)]
    assert count[0] == 0 and 100 < count[1] < count[2]


def test_color_is_refused_in_one_line_everywhere(tmp_path):
    frame = frame_2d([[0.0, 0.0]], [0.0])
    message = "color: must be one of auto, heading, species, deviation (got 'rainbow')"
    for call in (lambda: Scene.for_frame(frame, color="rainbow"), lambda: plot_frame(frame, color="rainbow"),
                 lambda: flocking.viz.LiveView(color="rainbow")):
        with pytest.raises(ParameterError) as err:
            call()
        assert str(err.value) == message
    out = tmp_path / "refused"
    for args in (["run", "--n", "20", "--steps", "4", "--backend", "reference", "--out", str(out), "-q"],
                 ["run", "--n", "20", "--steps", "4", "--backend", "reference", "--out", str(out), "-q",
                  "--no-plots", "--show"]):
        r = CliRunner().invoke(main, [*args, "--color", "rainbow"])
        assert r.exit_code == 2 and r.output.strip() == f"Error: --{message}" and not out.exists(), r.output


def test_a_run_with_extensions_draws_them_from_the_command_line(tmp_path):
    config = tmp_path / "ext.toml"
    config.write_text('n = 60\nbox = 12.0\nboundary = "wall,periodic"\n'
                      'obstacles = [{centre = [6.0, 6.0], radius = 2.0}]\n'
                      'species = [{name = "A", fraction = 0.5}, {name = "B", fraction = 0.5, noise = 2.0}]\n')
    out = tmp_path / "run"
    runner = CliRunner()
    r = runner.invoke(main, ["run", "--config", str(config), "--steps", "4", "--every", "2", "--backend", "reference",
                             "--out", str(out), "--dpi", "60", "-q"])
    assert r.exit_code == 0, r.output
    from PIL import Image

    with flocking.open(out / "trajectory.gsd") as traj:
        scene = Scene.for_frame(traj[-1], traj.parameters, size=6.0, dpi=60)
        scene.draw(traj[-1])
    snapshot = np.asarray(Image.open(out / "snapshot.png").convert("RGB"))
    assert snapshot.shape[:2] == (scene.pixels[1], scene.pixels[0])
    # the obstacle where the config put it, centre (6, 6): the axes show box coordinates, 0 to L
    assert scene.ax.get_xlim() == scene.ax.get_ylim() == (0.0, 12.0)
    px, py = scene.ax.transData.transform((6.0, 6.0))
    assert near(snapshot[int(round(snapshot.shape[0] - py)), int(round(px))], THEMES["dark"].obstacle, 10)
    px, py = scene.ax.transData.transform((0.0, 6.0))  # the wall at x = 0 (2 pixels wide at 60 dpi)
    assert near(snapshot[int(round(snapshot.shape[0] - py)), int(round(px))], THEMES["dark"].text, 20)
    for colour in ("heading", "species", "deviation"):
        movie = tmp_path / f"{colour}.mp4"
        r = runner.invoke(main, ["animate", str(out), "-o", str(movie), "--color", colour, "--size", "column", "-q"])
        assert r.exit_code == 0 and movie.stat().st_size > 0, r.output
    r = runner.invoke(main, ["animate", str(out), "-o", str(tmp_path / "x.png"), "--color", "stripes"])
    assert r.exit_code == 2 and r.output.strip().splitlines() == [
        "Error: --color: must be one of auto, heading, species, deviation (got 'stripes')"]
    assert not os.path.exists(tmp_path / "x.png")


def test_the_live_view_sees_species_walls_and_obstacles():
    model = flocking.Model(n=10, box=8.0, boundary="wall", obstacles=[{"centre": [4, 4], "radius": 1}],
                           species=[{"n": 4}, {"n": 6, "name": "B"}])
    frame = frame_of(flocking.Simulation(model, backend="reference"))
    assert frame.types == ("A", "B") and frame.typeid.tolist() == [0] * 4 + [1] * 6
    assert frame.walls == (True, True) and frame.obstacles.tolist() == [[0.0, 0.0, 1.0]]
