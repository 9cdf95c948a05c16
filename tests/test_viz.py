"""Pictures and movies, checked by looking at their pixels and decoding their files."""

from __future__ import annotations

import os
import subprocess
import sys

import numpy as np
import pytest
from click.testing import CliRunner

import flocking
from flocking.cli import main
from flocking.viz.colors import THEMES, heading_colors, hsv_to_rgb
from flocking.viz.live import LiveView
from flocking.viz.movie import write_movie, write_plots
from flocking.viz.raster import density_image, perspective_image
from flocking.viz.render import Scene

SRC = os.path.join(os.path.dirname(__file__), os.pardir, "src")


def make_frame(positions, angles, box=(20.0, 20.0), step=0):
    """A hand-built 2D frame: particles at ``positions`` heading along ``angles`` (radians)."""
    n = len(positions)
    points = np.zeros((n, 3), np.float32)
    points[:, :2] = positions
    velocities = np.zeros((n, 3), np.float32)
    velocities[:, 0], velocities[:, 1] = 0.5 * np.cos(angles), 0.5 * np.sin(angles)
    return flocking.Frame(step, 2, box, points, velocities)


def pixel(scene, rgb, x, y):
    """The RGB of the pixel where data point (x, y) lands."""
    px, py = scene.ax.transData.transform((x, y))
    return rgb[int(round(rgb.shape[0] - py)), int(round(px))].astype(int)


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    """A small real run: 30 particles, 13 frames, reference backend (no JIT)."""
    folder = tmp_path_factory.mktemp("run")
    result = CliRunner().invoke(main, ["run", "--n", "30", "--density", "1", "--steps", "24", "--every", "2",
                                       "--backend", "reference", "--out", str(folder), "--force", "-q"])
    assert result.exit_code == 0, result.output
    return folder


def test_hsv_matches_the_colour_circle():
    hue = np.array([0.0, 1 / 6, 1 / 3, 0.5, 2 / 3, 5 / 6])
    expected = [[1, 0, 0], [1, 1, 0], [0, 1, 0], [0, 1, 1], [0, 0, 1], [1, 0, 1]]
    assert np.allclose(hsv_to_rgb(hue, 1.0, 1.0), expected)
    # a 3D heading along z is pale, one in the plane is saturated
    rgb = heading_colors(np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0]]), THEMES["dark"])
    assert rgb[0].min() > 0.8 and np.allclose(rgb[1], [1, 0, 0])


@pytest.mark.parametrize("theme", ["dark", "light"])
def test_arrows_have_heading_colours_at_their_places(theme):
    positions = np.array([[-5.0, -5.0], [5.0, -5.0], [-5.0, 5.0], [5.0, 5.0]])
    angles = np.radians([0.0, 90.0, 180.0, 270.0])
    frame = make_frame(positions, angles)
    scene = Scene.for_frame(frame, theme=theme, style="arrows", size=4, dpi=100, arrow_scale=2.0,
                            time_label=False)
    rgb = scene.draw(frame).rgb()
    value = THEMES[theme].value
    expected = hsv_to_rgb(angles / (2 * np.pi), 1.0, value) * 255
    for (x, y), colour in zip(positions, expected):
        assert np.abs(pixel(scene, rgb, x, y) - colour).max() <= 12, (x, y)
    background = np.array(THEMES[theme].background) * 255
    for x, y in [(0.0, 0.0), (-8.0, 0.0), (0.0, 8.0)]:  # far from every arrow
        assert np.abs(pixel(scene, rgb, x, y) - background).max() <= 3
    # the arrow points along its heading: along +x for the first, not along y
    tip = pixel(scene, rgb, -5.0 + 1.0, -5.0)
    side = pixel(scene, rgb, -5.0, -5.0 + 1.5)
    assert tip[0] > 200 and np.abs(side - background).max() <= 3


def test_density_rendering_hue_is_mean_heading_and_brightness_is_density():
    rng = np.random.default_rng(0)
    dense = rng.uniform([-10, -10], [-5, 10], (4000, 2))       # a band heading +y
    sparse = rng.uniform([2, -10], [10, 10], (400, 2))          # sparser, heading -x
    frame = make_frame(np.vstack([dense, sparse]), np.r_[np.full(4000, np.pi / 2), np.full(400, np.pi)])
    scene = Scene.for_frame(frame, style="density", size=4, dpi=100, time_label=False)
    rgb = scene.draw(frame).rgb()
    band = pixel(scene, rgb, -7.5, 0.0)
    gas = pixel(scene, rgb, 6.0, 0.0)
    empty = pixel(scene, rgb, -1.5, 0.0)
    # +y is hue 90 degrees, (0.5, 1, 0) times a brightness near the top of the scale
    assert band[1] > 170 and abs(band[0] / band[1] - 0.5) < 0.08 and band[2] <= 10
    assert gas[0] < 10 and gas[1] > 20 and abs(int(gas[1]) - int(gas[2])) <= 12  # -x: cyan, dimmer
    assert band.sum() > gas.sum() and empty.max() <= 5


def test_density_image_counts_and_bins():
    pos = np.array([[-1.5, 1.5], [1.5, -1.5], [1.5, -1.5]])
    head = np.array([[0.0, 1.0], [-1.0, 0.0], [-1.0, 0.0]])
    img = density_image(pos, head, (4.0, 4.0), (4, 4), THEMES["dark"], blur=False)
    assert np.allclose(img[3, 3], [0, 1, 1])                   # 2 particles: full brightness, cyan
    assert img[0, 0, 1] > img[0, 0, 2] and img[0, 0].max() < 1  # 1 particle: dimmer, hue 90
    assert np.count_nonzero(img.sum(axis=2)) == 2


def test_perspective_image_shows_the_particle_in_its_colour():
    theme = THEMES["dark"]
    points = np.zeros((1, 3))
    img = perspective_image(points, np.array([[1.0, 0.0, 0.0]]), (10.0, 10.0, 10.0), 101, theme)
    centre = img[48:53, 48:53].reshape(-1, 3).max(axis=0)
    assert centre[0] > 0.5 and centre[1] < 0.1 and centre[2] < 0.1   # red: heading +x
    up = perspective_image(points, np.array([[0.0, 0.0, 1.0]]), (10.0, 10.0, 10.0), 101, theme)
    assert up[48:53, 48:53].reshape(-1, 3).max(axis=0).min() > 0.4   # pale: heading +z
    edges = img.sum(axis=2) > 0
    border = np.ones_like(edges)
    border[2:-2, 2:-2] = False
    assert edges.sum() > 300 and not (edges & border).any()         # box frame in view, not clipped


def test_3d_scene_renders_and_rotates():
    rng = np.random.default_rng(2)
    n = 500
    points = rng.uniform(-4, 4, (n, 3)).astype(np.float32)
    velocities = np.tile([0.5, 0.0, 0.0], (n, 1)).astype(np.float32)
    frame = flocking.Frame(10, 3, (8.0, 8.0, 8.0), points, velocities)
    scene = Scene.for_frame(frame, size=3, dpi=100)
    a = scene.draw(frame).rgb()
    b = scene.draw(frame, azim=30.0).rgb()
    assert scene.artist.style == "perspective" and a.shape == (a.shape[0], 304, 3)
    box = a[int(a.shape[0] * 0.3):int(a.shape[0] * 0.8), 40:200]
    reds = (box[..., 0] > 120) & (box[..., 1] < 60) & (box[..., 2] < 60)
    assert reds.sum() > 200                      # particles heading +x are red
    assert np.abs(a.astype(int) - b).sum() > 0   # another camera angle, another picture


def test_mp4_decodes_with_frames_size_and_codec(run_dir, tmp_path):
    import imageio_ffmpeg

    out = write_movie(run_dir, tmp_path / "m.mp4", fps=10, size=3, dpi=80, stride=2, start=1)
    reader = imageio_ffmpeg.read_frames(out)
    meta = next(reader)
    frames = list(reader)
    assert meta["codec"] == "h264" and meta["size"] == (240, 224)
    assert len(frames) == len(range(1, 13, 2)) == 6
    assert not [p for p in os.listdir(tmp_path) if "part" in p]


def test_gif_and_rotating_3d(tmp_path):
    from PIL import Image

    path = tmp_path / "t.gsd"
    sim = flocking.Simulation(flocking.Model(dim=3, n=60, box=4.0, seed=3), backend="reference")
    sim.writers.append(flocking.GSDWriter(path, every=1))
    sim.run(4)
    gif = write_movie(path, tmp_path / "m.gif", size=2, dpi=80, rotate=True, theme="light")
    with Image.open(gif) as im:
        assert im.n_frames == 5 and im.size == (160, 160)
        im.seek(0)
        first = np.asarray(im.convert("RGB"))
        im.seek(3)
        assert np.abs(first.astype(int) - np.asarray(im.convert("RGB"))).sum() > 0


def test_animate_command_and_its_errors(run_dir, tmp_path):
    runner = CliRunner()
    out = tmp_path / "a.mp4"
    ok = runner.invoke(main, ["animate", str(run_dir), "--output", str(out), "--size", "2", "--dpi", "64",
                              "--theme", "light", "--no-time-label", "--stop", "3", "-q"])
    assert ok.exit_code == 0, ok.output and out.stat().st_size > 0
    for args, word in [(["animate", str(tmp_path / "nope")], "no such run folder"),
                       (["animate", str(run_dir), "--theme", "purple"], "--theme: must be one of dark, light"),
                       (["animate", str(run_dir), "--output", str(tmp_path / "m.avi")], "--output"),
                       (["animate", str(run_dir), "--stride", "0"], "--stride"),
                       (["animate", str(run_dir), "--start", "50"], "select none")]:
        bad = runner.invoke(main, args)
        lines = bad.output.strip().splitlines()
        assert bad.exit_code != 0 and len(lines) == 1 and lines[0].startswith("Error:") and word in lines[0]
    assert sorted(os.listdir(tmp_path)) == ["a.mp4"]


def test_run_leaves_pictures_unless_no_plots(tmp_path, run_dir):
    from PIL import Image

    for name in ("snapshot.png", "polar_order.png"):
        with Image.open(run_dir / name) as im:
            assert im.format == "PNG" and min(im.size) > 300
    out = tmp_path / "bare"
    r = CliRunner().invoke(main, ["run", "--n", "20", "--density", "1", "--steps", "4", "--backend", "reference",
                                  "--out", str(out), "--no-plots", "-q"])
    assert r.exit_code == 0 and not [p for p in os.listdir(out) if p.endswith(".png")]
    assert sorted(os.listdir(out)) == ["checkpoint.npz", "config.toml", "observables.csv", "trajectory.gsd"]


def test_run_movie_and_show_without_display(tmp_path, monkeypatch):
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    out = tmp_path / "shown"
    r = CliRunner().invoke(main, ["run", "--n", "20", "--density", "1", "--steps", "6", "--every", "2",
                                  "--backend", "reference", "--out", str(out), "--show", "--movie", "-q"])
    assert r.exit_code == 0, r.output
    notes = [line for line in r.output.splitlines() if "--show" in line]
    assert len(notes) == 1 and "no display" in notes[0] and "running without" in notes[0]
    assert {"movie.mp4", "snapshot.png", "polar_order.png"} <= set(os.listdir(out))


def test_live_view_refuses_a_non_interactive_backend(monkeypatch, capsys):
    import matplotlib

    monkeypatch.setenv("DISPLAY", ":0")
    matplotlib.use("Agg")
    view = LiveView(every=1)
    sim = flocking.Simulation(flocking.Model(n=10, box=3.0), backend="reference")
    sim.writers.append(view)
    sim.run(3)
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "'agg' cannot open a window" in err[0].lower()
    assert view.scene is None and sim.step == 3


def test_notebook_reprs(run_dir):
    with flocking.open(run_dir / "trajectory.gsd") as traj:
        html = traj._repr_html_()
        png = traj[-1]._repr_png_()
        anim = flocking.animate(traj, max_frames=5, size=2, dpi=50)
    assert png[:8] == b"\x89PNG\r\n\x1a\n"
    assert "<script>" in html and html.count("iVBOR") == 13 + 1   # every frame as base64 PNG, the first shown
    assert anim._repr_html_().count("iVBOR") == 5 + 1


def test_plot_frame_on_given_axes_and_alone():
    from matplotlib.figure import Figure

    frame = make_frame(np.array([[0.0, 0.0], [2.0, 2.0]]), np.array([0.0, 1.0]))
    ax = Figure().add_subplot()
    assert flocking.plot_frame(frame, ax=ax) is ax and len(ax.collections) == 1
    import matplotlib.pyplot as plt

    ax = flocking.plot_frame(frame, theme="light")
    assert ax.figure.texts and ax.get_xlim() == (-10.0, 10.0)
    plt.close(ax.figure)
    with pytest.raises(flocking.ParameterError, match="theme"):
        flocking.plot_frame(frame, theme="neon")


def test_write_plots_titles_carry_the_parameters(run_dir):
    from flocking.viz.render import describe

    with flocking.open(run_dir / "trajectory.gsd") as traj:
        title, subtitle = describe(traj.parameters, 2, 30, traj[0].box_lengths)
    assert "N = 30" in title and "2D" in title and "\u03b7 = 1" in subtitle and "R = 1" in subtitle
    assert write_plots(str(run_dir))[0].endswith("snapshot.png")


def test_import_flocking_does_not_import_matplotlib():
    code = "import sys, flocking; print('matplotlib' in sys.modules); print(callable(flocking.animate))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                         env={**os.environ, "PYTHONPATH": os.path.abspath(SRC)}).stdout.split()
    assert out == ["False", "True"]
    with pytest.raises(AttributeError, match="no attribute 'plot_frames'"):
        flocking.plot_frames
