"""Pictures and movies, checked by looking at their pixels and decoding their files."""

from __future__ import annotations

import base64
import os
import re
import subprocess
import sys

import numpy as np
import pytest
from click.testing import CliRunner

import flocking
from flocking.cli import main
from flocking.viz.colors import THEMES, angle_colors
from flocking.viz.live import LiveView
from flocking.viz.movie import write_movie, write_picture, write_plots
from flocking.viz.particles import box_coordinates
from flocking.viz.scene import Scene

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
    px, py = scene.ax.transData.transform(box_coordinates([x, y], scene.box))  # (x, y) centred, as frames are
    return rgb[int(round(rgb.shape[0] - py)), int(round(px))].astype(int)


def decode_mp4(path):
    import imageio_ffmpeg

    reader = imageio_ffmpeg.read_frames(str(path))
    meta = next(reader)
    return meta, list(reader)


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    """A small real run: 30 particles, 13 frames, reference backend (no JIT)."""
    folder = tmp_path_factory.mktemp("run")
    result = CliRunner().invoke(main, ["run", "--n", "30", "--density", "1", "--steps", "24", "--every", "2",
                                       "--backend", "reference", "--out", str(folder), "--force", "-q"])
    assert result.exit_code == 0, result.output
    return folder


@pytest.fixture(scope="module")
def run_3d(tmp_path_factory):
    path = tmp_path_factory.mktemp("run3d") / "t.gsd"
    sim = flocking.Simulation(flocking.Model(dim=3, n=60, box=4.0, seed=3), backend="reference")
    sim.writers.append(flocking.GSDWriter(path, every=1))
    sim.run(4)
    return path


@pytest.mark.parametrize("theme", ["dark", "light"])
def test_arrows_have_heading_colours_at_their_places(theme):
    positions = np.array([[-5.0, -5.0], [5.0, -5.0], [-5.0, 5.0], [5.0, 5.0]])
    angles = np.radians([0.0, 90.0, 180.0, 270.0])
    frame = make_frame(positions, angles)
    scene = Scene.for_frame(frame, theme=theme, style="arrows", size=4, dpi=100, time_label=False)
    rgb = scene.draw(frame).rgb()
    expected = angle_colors(angles, THEMES[theme]) * 255
    for (x, y), colour in zip(positions, expected):
        assert np.abs(pixel(scene, rgb, x, y) - colour).max() <= 12, (x, y)
    background = np.array(THEMES[theme].background) * 255
    for x, y in [(0.0, 0.0), (-8.0, 0.0), (0.0, 8.0)]:  # far from every arrow
        assert np.abs(pixel(scene, rgb, x, y) - background).max() <= 3
    # the arrow (9 long: 0.9 spacings) points along its heading: along +x for the first, not y
    tip = pixel(scene, rgb, -5.0 + 3.0, -5.0)
    side = pixel(scene, rgb, -5.0, -5.0 + 3.5)
    assert np.abs(tip - expected[0]).max() <= 12 and np.abs(side - background).max() <= 3


def test_density_scene_has_a_colour_bar_that_covers_the_densest_region():
    rng = np.random.default_rng(0)
    band = rng.uniform([-10, -10], [-5, 10], (30000, 2))        # a band heading +y
    gas = rng.uniform([0, -10], [10, 10], (6000, 2))             # sparser, disordered
    frame = make_frame(np.vstack([band, gas]), np.r_[np.full(30000, np.pi / 2), rng.uniform(0, 6.3, 6000)])
    scene = Scene.for_frame(frame, size=4, dpi=100, time_label=False)
    rgb = scene.draw(frame).rgb()
    assert scene.style == "density"                               # auto: 36000 particles leave no room
    bar = scene.colorbar
    assert bar is not None and "density" in bar.ax.get_ylabel()
    assert bar.norm.vmax == scene.density_max >= 30000 / 100 * 0.99  # the band's density, 300 per unit area
    inside, outside = pixel(scene, rgb, -7.5, 0.0), pixel(scene, rgb, 5.0, 0.0)
    green = angle_colors(np.pi / 2, THEMES["dark"], ink=True) * 255
    assert np.abs(inside - green).max() < 40                      # +y colour, near full brightness
    assert max(outside) - min(outside) <= 6 and 10 < outside.mean() < inside.mean()  # grey, dimmer
    assert "no order" in scene._key_label.get_text()


def test_3d_scene_renders_rotates_and_ticks_three_edges_in_box_coordinates():
    rng = np.random.default_rng(2)
    n = 500
    points = rng.uniform(-4, 4, (n, 3)).astype(np.float32)
    velocities = np.tile([0.5, 0.0, 0.0], (n, 1)).astype(np.float32)
    frame = flocking.Frame(10, 3, (8.0, 8.0, 8.0), points, velocities)
    scene = Scene.for_frame(frame, size=3, dpi=100, color="heading")
    a = scene.draw(frame).rgb()
    b = scene.draw(frame, azim=30.0).rgb()
    assert scene.artist.style == "perspective" and a.shape[1] == 304
    reds = (a[..., 0] > a[..., 1] + 40) & (a[..., 0] > a[..., 2] + 40)
    assert reds.sum() > 500                                       # cones heading +x are red
    assert np.abs(a.astype(int) - b).sum() > 0                    # another camera angle, another picture
    # each axis' ruler: ticks at the box coordinates 2 to 8 along an edge of the box, named with its unit
    for axis, ticks, marks, labels, title in scene.artist.rulers:
        assert ticks == [2.0, 4.0, 6.0, 8.0] and [t.get_text() for t in labels] == ["2", "4", "6", "8"]
        assert title.get_text() == f"${'xyz'[axis]}$ (units of $R$)"
    # the tick at coordinate v of the z ruler sits where the camera sees (corner, v - L/2), seen from 30 degrees
    from flocking.viz.perspective import Camera

    artist = scene.artist
    cam = Camera(artist.box, artist.pixels, 30.0, 25.0, artist.zoom)
    axis, ticks, marks, labels, title = artist.rulers[2]
    x, y = marks.get_data()
    corners = [np.array([sx, sy, 0.0]) * 4 for sx in (-1, 1) for sy in (-1, 1)]
    corner = min(corners, key=lambda c: cam.project(c[None])[0][0])  # the leftmost vertical edge
    u, v, _ = cam.project(corner + np.outer(np.array(ticks) - 4.0, [0, 0, 1]))
    np.testing.assert_allclose(np.c_[x[::3], y[::3]], np.c_[u - 0.5, v - 0.5], atol=1e-9)
    assert np.all(np.diff(y[::3]) < 0)                            # up the picture as z grows
    figure = scene.figure.bbox  # every ruler's labels inside the picture
    for *_, labels, title in artist.rulers:
        for text in (*labels, title):
            box = text.get_window_extent()
            assert figure.x0 <= box.x0 and box.x1 <= figure.x1 and figure.y0 <= box.y0 and box.y1 <= figure.y1


def test_mp4_decodes_with_frames_size_and_codec(run_dir, tmp_path):
    out = write_movie(run_dir, tmp_path / "m.mp4", fps=10, size=3, dpi=80, stride=2, start=1)
    meta, frames = decode_mp4(out)
    assert meta["codec"] == "h264" and meta["size"][0] == 240 and meta["size"][1] % 16 == 0
    assert len(frames) == len(range(1, 13, 2)) == 6
    assert not [p for p in os.listdir(tmp_path) if "part" in p]


def test_gif_uses_one_dithered_palette_so_the_colour_wheel_does_not_band(run_dir, tmp_path):
    from PIL import Image

    gif = write_movie(run_dir, tmp_path / "m.gif", size=4, dpi=100, stop=3)
    with flocking.open(run_dir / "trajectory.gsd") as traj:
        scene = Scene.for_frame(traj[0], traj.parameters, size=4, dpi=100)
        truth = scene.draw(traj[0]).rgb().astype(float)
    with Image.open(gif) as im:
        assert im.n_frames == 3 and im.size == truth.shape[1::-1]
        palettes = set()
        for k in range(3):
            im.seek(k)
            palettes.add(bytes(im.getpalette() or []))
        im.seek(0)
        first = np.asarray(im.convert("RGB"), float)

    def local_mean(a, k=5):  # what the eye sees of a dithered picture
        return sum(np.roll(np.roll(a, dy, 0), dx, 1) for dy in range(-2, 3) for dx in range(-2, 3)) / k**2

    box = scene.key_axes.get_window_extent()
    rows = slice(int(truth.shape[0] - box.y1), int(truth.shape[0] - box.y0))
    cols = slice(int(box.x0), int(box.x1))
    error = np.abs(local_mean(first) - local_mean(truth))[rows, cols]
    # the wheel's colours within a couple of levels everywhere; an undithered palette
    # of its own per frame (what GIFs had) is off by 4 levels or more at its bands
    assert np.percentile(error, 99) < 2.5 and len(palettes - {b""}) == 1  # later frames: no palette of their own


def test_rotating_3d_gif_and_picture_files(run_3d, tmp_path):
    from PIL import Image

    gif = write_movie(run_3d, tmp_path / "m.gif", size=2, dpi=80, rotate=True, theme="light")
    with Image.open(gif) as im:
        assert im.n_frames == 5 and im.size[0] == 160
        im.seek(0)
        first = np.asarray(im.convert("RGB"))
        im.seek(3)
        assert np.abs(first.astype(int) - np.asarray(im.convert("RGB"))).sum() > 0
    for ext, magic in (("png", b"\x89PNG"), ("svg", b"<?xml"), ("pdf", b"%PDF")):
        path = write_picture(run_3d, tmp_path / f"f.{ext}", frame=2, size="column", dpi=60, theme="light")
        assert open(path, "rb").read(5).startswith(magic)
    with pytest.raises(flocking.ParameterError, match=r"^frame: must be a frame index in \[-5, 4\] \(got 9\)"):
        write_picture(run_3d, tmp_path / "g.png", frame=9)


def test_a_2d_trajectory_refuses_to_rotate(run_dir, tmp_path):
    with pytest.raises(flocking.ParameterError, match="^rotate: turns the camera around a 3D box; this "
                                                      "trajectory is 2D$"):
        write_movie(run_dir, tmp_path / "m.mp4", rotate=True)
    assert os.listdir(tmp_path) == []


def test_animate_command_movies_pictures_and_their_errors(run_dir, tmp_path):
    runner = CliRunner()
    out = tmp_path / "a.mp4"
    ok = runner.invoke(main, ["animate", str(run_dir), "--out", str(out), "--size", "page", "--dpi", "32",
                              "--theme", "light", "--no-time-label", "--last-frame", "2", "-q"])
    assert ok.exit_code == 0, ok.output
    assert decode_mp4(out)[0]["size"][0] == 224  # a page, 7 in wide, at 32 pixels per inch
    pic = runner.invoke(main, ["animate", str(run_dir), "-o", str(tmp_path / "p.svg"), "--frame", "2",
                               "--size", "column", "--theme", "light", "-q"])
    assert pic.exit_code == 0, pic.output
    svg = (tmp_path / "p.svg").read_text()
    assert svg.startswith("<?xml") and "<image" in svg and "<path" in svg
    for args, word in [(["animate", str(tmp_path / "nope")], "no such run folder"),
                       (["animate", str(run_dir), "--theme", "purple"], "--theme: must be one of dark, light"),
                       (["animate", str(run_dir), "--out", str(tmp_path / "m.mov")],
                        "--out: must end in .mp4 or .gif (a movie), or .png, .svg or .pdf (one frame)"),
                       (["animate", str(run_dir), "--stride", "0"], "--stride"),
                       (["animate", str(run_dir), "--first-frame", "50"], "--first-frame: must be a frame index"),
                       (["animate", str(run_dir), "--rotate"], "--rotate: turns the camera around a 3D box"),
                       (["animate", str(run_dir), "--frame", "2"], "--frame: only a picture"),
                       (["animate", str(run_dir), "-o", str(tmp_path / "x.png"), "--fps", "5"],
                        "--fps: only a movie"),
                       (["animate", str(run_dir), "-o", str(tmp_path / "x.png"), "--frame", "99"], "--frame"),
                       (["animate", str(run_dir), "-o", str(tmp_path / "x.png"), "--dpi", "0"],
                        "--dpi: must be in [10, 1000]"),
                       (["animate", str(run_dir), "-o", str(tmp_path / "x.png"), "--size", "poster"], "--size"),
                       (["animate", str(run_dir), "--arrow-scale", "0"], "--arrow-scale: must be a number > 0"),
                       (["animate", str(run_dir), "-o", str(tmp_path / "x.pdf"), "--arrow-scale", "nan"],
                        "--arrow-scale: must be a number > 0")]:
        bad = runner.invoke(main, args)
        lines = bad.output.strip().splitlines()
        assert bad.exit_code == 2 and len(lines) == 1 and lines[0].startswith("Error:") and word in lines[0], \
            (args, bad.output)
    assert sorted(os.listdir(tmp_path)) == ["a.mp4", "p.svg"]


def test_run_leaves_pictures_in_the_theme_resolution_and_format_asked(tmp_path, run_dir):
    from PIL import Image

    with Image.open(run_dir / "snapshot.png") as im:
        assert im.format == "PNG" and im.info["dpi"][0] == pytest.approx(200, abs=1) and min(im.size) > 800
    with Image.open(run_dir / "polar_order.png") as im:
        assert im.size == (1400, 640)                              # page size (7 x 3.2 in) at 200 dpi
    runner = CliRunner()
    out = tmp_path / "light"
    r = runner.invoke(main, ["run", "--n", "20", "--density", "1", "--steps", "4", "--backend", "reference",
                             "--out", str(out), "--theme", "light", "--dpi", "50", "--format", "pdf", "-q"])
    assert r.exit_code == 0, r.output
    assert {"snapshot.pdf", "polar_order.pdf"} <= set(os.listdir(out)) and not list(out.glob("*.png"))
    assert (out / "snapshot.pdf").read_bytes()[:4] == b"%PDF"
    out = tmp_path / "bare"
    r = runner.invoke(main, ["run", "--n", "20", "--density", "1", "--steps", "4", "--backend", "reference",
                             "--out", str(out), "--no-plots", "-q"])
    assert r.exit_code == 0 and sorted(os.listdir(out)) == ["checkpoint.npz", "config.toml", "observables.csv",
                                                            "trajectory.gsd"]
    for args, message in [(["--theme", "neon"], "--theme: must be one of dark, light (got 'neon')"),
                          (["--dpi", "5"], "--dpi: must be in [10, 1000] (got 5.0)"),
                          (["--format", "jpg"], "--format: must be one of png, svg, pdf (got 'jpg')")]:
        out = tmp_path / "refused"
        r = runner.invoke(main, ["run", "--n", "20", "--steps", "4", "--backend", "reference", "--out", str(out),
                                 "-q", *args])
        assert r.exit_code == 2 and r.output.strip() == f"Error: {message}" and not out.exists()


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


def video_frames(html, path):
    """Frames of the mp4 inlined in a notebook's ``<video>`` tag."""
    path.write_bytes(base64.b64decode(re.search(r'src="data:video/mp4;base64,([^"]+)"', html).group(1)))
    meta, frames = decode_mp4(path)
    assert meta["codec"] == "h264"
    return frames


def test_notebook_shows_a_small_h264_video(tmp_path):
    # 60 frames of the default 2048 particles: the player of PNG frames took 7 MB
    path = tmp_path / "t.gsd"
    sim = flocking.Simulation(flocking.Model(n=2048, box=32.0, noise=1.0, seed=1), backend="cpu")
    sim.writers.append(flocking.GSDWriter(path, every=5))
    sim.run(295)
    with flocking.open(path) as traj:
        assert len(traj) == 60
        html = traj._repr_html_()
        png = traj[-1]._repr_png_()
        short = flocking.animate(traj, max_frames=7, size=2, dpi=50)._repr_html_()
    assert png[:8] == b"\x89PNG\r\n\x1a\n"
    assert html.startswith("<video") and "autoplay" in html and "loop" in html
    assert len(html) < 1_000_000
    assert len(video_frames(html, tmp_path / "all.mp4")) == 60
    assert len(video_frames(short, tmp_path / "short.mp4")) == 7     # every 9th of 60: 0, 9, ..., 45, 54


def test_plot_frame_draws_on_given_axes_and_nothing_else():
    from matplotlib.figure import Figure

    frame = make_frame(np.array([[0.0, 0.0], [2.0, 2.0]]), np.array([0.0, 1.0]))
    fig = Figure()
    ax = fig.add_subplot()
    ax.set_facecolor("#101010")
    ax.set_title("mine")
    before = (len(fig.axes), fig.get_facecolor(), len(fig.texts), ax.get_facecolor(), ax.get_title())
    assert flocking.plot_frame(frame, ax=ax) is ax and len(ax.collections) == 1
    assert (len(fig.axes), fig.get_facecolor(), len(fig.texts), ax.get_facecolor(), ax.get_title()) == before
    # the theme follows the axes' background: dark here, so the dark theme's lighter colours
    colours = ax.collections[0].get_facecolor()[:, :3]
    assert np.allclose(colours[0], angle_colors(0.0, THEMES["dark"]))
    light = Figure().add_subplot()
    flocking.plot_frame(frame, ax=light)
    assert np.allclose(light.collections[0].get_facecolor()[0, :3], angle_colors(0.0, THEMES["light"]))


def test_plot_frame_alone_takes_a_model_or_parameters():
    import matplotlib.pyplot as plt

    frame = make_frame(np.array([[0.0, 0.0], [2.0, 2.0]]), np.array([0.0, 1.0]))
    model = flocking.Model(n=2, box=20.0, noise=0.7, neighbours="topological", k=3)
    for parameters in (model, model.to_dict(), {"model": model.to_dict(), "steps": 10}):
        ax = flocking.plot_frame(frame, theme="light", parameters=parameters)
        caption = ax.figure._supxlabel.get_text()
        assert r"angular noise $\eta$ = 0.7" in caption and "$k$ = 3 nearest" in caption
        assert caption.startswith(r"$\rho$ = 0.005 · ")  # N / L^2 = 2 / 400
        assert ax.get_xlim() == ax.get_ylim() == (0.0, 20.0)  # box coordinates, as the engine's
        plt.close(ax.figure)
    with pytest.raises(flocking.ParameterError, match="theme"):
        flocking.plot_frame(frame, theme="neon")
    with pytest.raises(flocking.ParameterError, match="^parameters: must be a Model or a dict"):
        flocking.plot_frame(frame, parameters=[1, 2])


def test_write_plots_titles_carry_the_parameters(run_dir):
    from flocking.viz.caption import describe

    with flocking.open(run_dir / "trajectory.gsd") as traj:
        title, subtitle = describe(traj.parameters, 2, 30, traj[0].box_lengths)
    assert "$N$ = 30" in title and "2D" in title and r"$\eta$ = 1" in subtitle and "$R$ = 1" in subtitle
    assert [os.path.basename(p) for p in write_plots(str(run_dir), theme="light", dpi=40)] == \
        ["snapshot.png", "polar_order.png"]


def test_trajectory_repr_and_polar_order_property(run_dir):
    with flocking.open(run_dir / "trajectory.gsd") as traj:
        text = repr(traj)
        last = traj[-1]
        phi = last.polar_order
    assert text == (f"Trajectory({str(run_dir / 'trajectory.gsd')!r}, frames=13, steps 0..24, n=30, dim=2, "
                    f"box={last.box_lengths.tolist()})")
    assert repr(traj).endswith("closed)")
    assert isinstance(phi, float) and phi == pytest.approx(np.linalg.norm(last.headings.sum(0)) / 30, abs=1e-12)


def test_import_flocking_does_not_import_matplotlib():
    code = "import sys, flocking; print('matplotlib' in sys.modules); print(callable(flocking.animate))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                         env={**os.environ, "PYTHONPATH": os.path.abspath(SRC)}).stdout.split()
    assert out == ["False", "True"]
    with pytest.raises(AttributeError, match="no attribute 'plot_frames'"):
        flocking.plot_frames
