"""The house style: sizes, wrapped titles, files by extension, and pictures whose text all fits."""

from __future__ import annotations

import os

import numpy as np
import pytest
from matplotlib.font_manager import FontProperties

import flocking
from flocking.analysis import PolarOrder
from flocking.viz import style
from flocking.viz.caption import describe
from flocking.viz.scene import Scene
from flocking.viz.timeseries import polar_order_figure

#: every option that adds to the caption
BUSY = flocking.Model(dim=2, n=500, box=(1500.0, 1000.0), noise=0.4, noise_type="vectorial",
                      neighbours="topological", k=6, alignment=0.5, delay=3, dt=0.25, update="forward",
                      speeds="uniform", seed=12345)


def busy_frame():
    rng = np.random.default_rng(0)
    points = np.zeros((500, 3), np.float32)
    points[:, :2] = rng.uniform(-500, 500, (500, 2))
    velocities = np.zeros((500, 3), np.float32)
    velocities[:, 0] = 0.5
    return flocking.Frame(123456, 2, (1500.0, 1000.0), points, velocities)


def overflow(fig) -> float:
    """How far (points) anything drawn on ``fig`` (text, ticks, keys) reaches past its edges."""
    renderer = fig.canvas.get_renderer()
    tight = fig.get_tightbbox(renderer)             # inches, only what is drawn
    box = fig.bbox_inches
    return 72.0 * max(box.x0 - tight.x0, box.y0 - tight.y0, tight.x1 - box.x1, tight.y1 - box.y1, 0.0)


def dense_frame(dim):
    """40000 particles in 2D (a density map at every size), or 3000 in 3D."""
    rng = np.random.default_rng(1)
    n = 40000 if dim == 2 else 3000
    points = np.zeros((n, 3), np.float32)
    points[:, :dim] = rng.uniform(-10, 10, (n, dim))
    velocities = rng.normal(size=(n, 3)).astype(np.float32)
    velocities[:, dim:] = 0
    return flocking.Frame(5000, dim, (20.0,) * dim, points, velocities)


def overlapping(fig, a, b) -> bool:
    renderer = fig.canvas.get_renderer()
    return a.get_window_extent(renderer).overlaps(b.get_window_extent(renderer))


@pytest.mark.parametrize("size", ["column", "slide", 6.0])
@pytest.mark.parametrize("theme", ["dark", "light"])
def test_no_text_is_clipped_with_wide_ticks_and_every_parameter(size, theme):
    frame = busy_frame()
    scene = Scene.for_frame(frame, BUSY, theme=theme, size=size, dpi=100)
    scene.draw(frame).rgb()
    assert overflow(scene.figure) <= 1.0
    caption = scene.figure._supxlabel.get_text()
    assert "vectorial" in caption and "seed 12345" in caption and "\n" in caption  # wrapped, not cut
    assert not overlapping(scene.figure, scene.figure._supxlabel, scene.ax.xaxis.label)
    # the heading key's labels are legible: at least 10 pixels at the default movie resolution
    if size == 6.0:
        movie = Scene.for_frame(frame, BUSY, theme=theme, size=6.0, dpi=120)
        sizes = [t.get_fontsize() * 120 / 72 for t in movie.key_axes.texts]
        assert min(sizes) >= 10


@pytest.mark.parametrize("size", ["column", "slide", 6.0])
@pytest.mark.parametrize("dim", [2, 3])
def test_density_and_3d_pictures_keep_their_keys_whole_and_apart(size, dim):
    frame = dense_frame(dim)
    for theme in ("dark", "light"):
        scene = Scene.for_frame(frame, BUSY if dim == 2 else None, theme=theme, size=size, dpi=100)
        scene.draw(frame).rgb()
        assert scene.style == ("density" if dim == 2 else "perspective")
        assert overflow(scene.figure) <= 1.0
        fig, key = scene.figure, scene.key_axes
        wheel = key.images[0].get_window_extent(fig.canvas.get_renderer())
        assert wheel.width >= 4 * 0.75 * style.fontsize(fig) * 100 / 72      # a wheel, not a dot
        for text in key.texts:                                             # labels inside the key's box
            assert key.get_window_extent().contains(*text.get_window_extent().get_points().mean(0))
        if dim == 2:
            assert not overlapping(fig, scene._key_label, scene.colorbar.ax)
            assert not overlapping(fig, key, scene.colorbar.ax)


def test_sizes_fonts_and_pixels():
    assert style.resolve_size("column") == (3.4, 2.6, 8.0)
    assert style.resolve_size((5.0, 3.0))[:2] == (5.0, 3.0)
    for bad in ("poster", 0.1, (3.0, "x"), (1, 2, 3)):
        with pytest.raises(flocking.ParameterError, match="size"):
            style.resolve_size(bad)
    frame = busy_frame()
    scene = Scene.for_frame(frame, size="slide", dpi=100)
    assert scene.pixels == (800, 448) and scene.rgb().shape == (448, 800, 3)  # multiples of 16 for H.264


@pytest.mark.parametrize("size, count, grid", [
    ("column", 4, (4, 1)), ("page", 3, (1, 3)), ("page", 4, (2, 2)), ("page", 5, (2, 3)), ("slide", 3, (2, 2)),
    ((14.0, 3.0), 4, (1, 4)), ((12.0, 3.0), 4, (2, 2)),
])
def test_panels_fit_the_width_and_keep_every_label_inside(size, count, grid):
    fig, axes = style.panels(size, "light", count)
    assert len(axes) == count == len(fig.axes)
    assert axes[0].get_subplotspec().get_geometry()[:2] == grid
    width, height, fontsize = style.resolve_size(size)
    assert fig.get_size_inches()[0] == width
    assert fig.get_size_inches()[1] == pytest.approx(height if grid[0] == 1 else 0.7 * height * grid[0])
    for ax in axes:
        assert ax.get_position().width * width >= 0.6 * style.PANEL_EMS * fontsize / 72  # the plot, less its ticks
        style.label_axes(ax, r"noise $\eta$", "binder")
        ax.set_title("a panel title", fontsize=fontsize)
    style.title(fig, "A title that is long enough to wrap at a column's width, or so", "a · caption")
    fig.canvas.draw()
    assert overflow(fig) <= 1.0
    for a, b in zip(axes, axes[1:]):
        assert not overlapping(fig, a, b)


def test_panels_refuse_a_count_or_size_they_cannot_lay_out():
    for bad in (0, -1, 2.5, True, "3"):
        with pytest.raises(flocking.ParameterError, match=r"^count: must be a whole number >= 1"):
            style.panels("page", "light", bad)
    with pytest.raises(flocking.ParameterError, match=r"^size: must be one of column, page, slide or \(width, height\)"):
        style.panels(5.0, "light", 2)


def test_wrapping_counts_what_mathtext_shows_and_never_splits_a_formula():
    assert style.visible_length(r"$\eta$ = 0.4 (vectorial)") == len("x = 0.4 (vectorial)")
    fig, _ = style.figure("column")
    main, details = describe(BUSY.to_dict(), 2, 500, (1500.0, 1000.0))
    wrapped = style.wrap_text(details, fig, 7.0)
    lines = wrapped.split("\n")
    assert len(lines) >= 2 and " ".join(lines).replace("  ", " ") .count("$") == details.count("$")
    assert all(line.count("$") % 2 == 0 for line in lines)
    renderer = fig.canvas.get_renderer()
    prop = FontProperties(size=7.0)
    widths = [renderer.get_text_width_height_descent(line, prop, ismath=True)[0] for line in lines]
    assert max(widths) <= 0.96 * 3.4 * renderer.dpi


@pytest.mark.parametrize("ext, magic", [("png", b"\x89PNG"), ("svg", b"<?xml"), ("pdf", b"%PDF")])
def test_save_writes_the_format_of_the_extension(tmp_path, ext, magic):
    fig, ax = style.figure("column", "light")
    ax.plot([0, 1], [0, 1])
    path = style.save(fig, tmp_path / f"f.{ext}", dpi=50)
    assert open(path, "rb").read(5).startswith(magic)
    assert os.listdir(tmp_path) == [f"f.{ext}"]


def test_a_failed_save_keeps_the_old_file(tmp_path, monkeypatch):
    fig, _ = style.figure("column")
    path = tmp_path / "f.png"
    path.write_bytes(b"old")

    def broken(f, **kw):
        f.write(b"half a picture")
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(fig, "savefig", broken)
    with pytest.raises(OSError):
        style.save(fig, path)
    assert path.read_bytes() == b"old" and os.listdir(tmp_path) == ["f.png"]


def test_bad_resolutions_and_formats_are_refused():
    for bad in (0, 5, 2000, float("nan"), "high"):
        with pytest.raises(flocking.ParameterError, match=r"^dpi: must be in \[10, 1000\]"):
            style.check_dpi(bad)
    assert style.check_dpi(None) is None and style.check_dpi(72) == 72.0
    with pytest.raises(flocking.ParameterError, match="output: must end in .png, .svg or .pdf"):
        style.check_format("a.jpg")


@pytest.mark.parametrize("theme", ["dark", "light"])
def test_polar_order_figure_shows_the_error_of_the_mean_not_the_spread(theme):
    rng = np.random.default_rng(7)
    x = np.zeros(2000)
    for t in range(1, len(x)):                       # correlated noise: tau = 0.5 (1 + 0.9) / (1 - 0.9) = 9.5
        x[t] = 0.9 * x[t - 1] + 0.01 * rng.standard_normal()
    phi = 0.6 + x
    steps = np.arange(0, 2 * len(phi), 2)           # a value every 2 steps
    fig = polar_order_figure(steps, phi, BUSY.to_dict(), 2, 500, (1500.0, 1000.0), theme=theme)
    ax = fig.axes[0]
    op = PolarOrder(start=0.5).compute(phi)
    band = ax.collections[0].get_paths()[0].vertices
    assert band[:, 1].max() - band[:, 1].min() == pytest.approx(2 * op.mean_error, rel=1e-9)
    assert band[:, 0].min() == steps[op.window][0] and band[:, 0].max() == steps[-1]
    assert 2 * op.mean_error < phi[1000:].std()     # the old legend's +- was the spread
    label = ax.get_legend().get_texts()[0].get_text()
    assert "error of the mean" in label and f"= {2 * op.tau:.3g} steps" in label
    assert ax.get_ylabel() == style.LABELS["phi"] and ax.get_xlabel() == style.LABELS["step"]
    fig.canvas.draw()
    assert overflow(fig) <= 1.0


def test_the_throughput_figure_is_in_the_house_style_and_names_machine_and_threads(tmp_path, monkeypatch):
    from flocking import throughput as bench

    rows = [dict(group="2d-metric", n=n, init=init, implementation=impl, threads=2, repeats=3,
                 particle_steps_per_s=rate * n ** 0.01)
            for impl, rate in (("flocking", 2e7), ("kdtree", 5e5)) for init in ("random", "clustered")
            for n in (10**4, 10**5)]
    result = {"machine": {"cpu": "Test CPU 9000", "cores": 2, "numba": "0.0"}, "rows": rows}
    shown = {}
    monkeypatch.setattr(style, "save", lambda fig, path, dpi=None: shown.setdefault("fig", fig))
    bench.plot(result, tmp_path / "t.png", theme="dark")
    fig = shown["fig"]
    ax = fig.axes[0]
    caption = fig._supxlabel.get_text().replace("\n", " ")
    assert "Test CPU 9000, 2 cores" in caption and "2 threads for every implementation" in caption
    assert ax.get_xscale() == ax.get_yscale() == "log" and ax.get_xlabel() == "particles $N$"
    assert {line.get_color() for line in ax.get_lines()} <= set(style.palette("dark"))
    assert [t.get_text() for t in ax.get_legend().get_texts()] == [
        "flocking, random start", "flocking, clustered start", "kdtree, random start", "kdtree, clustered start"]
