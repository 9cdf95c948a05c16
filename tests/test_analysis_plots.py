"""The analysis classes' plot(ax): the house style, either theme, and nothing outside the axes given."""

import numpy as np
import pytest
from matplotlib.colors import to_hex
from matplotlib.figure import Figure

import flocking.analysis as fa
from flocking.viz import style
from flocking.viz.colors import get_theme


@pytest.fixture(scope="module")
def computed():
    rng = np.random.default_rng(1)
    pts = rng.uniform(0, 20, (3000, 2))
    pts[:1000, 0] = rng.uniform(5, 8, 1000)  # a band, so the profile has one to draw
    u = np.tile([1.0, 0.0], (3000, 1)) + 0.3 * rng.normal(size=(3000, 2))
    frames = [fa.snapshots.from_box_points(20.0, (pts + [0.2 * t, 0.0]) % 20, u, step=t) for t in range(4)]
    typed = [fa.snapshots.Snapshot(f.step, f.box, f.positions, f.headings, typeid=np.arange(3000) % 2, types=["A", "B"])
             for f in frames]
    return [fa.PolarOrder().compute(0.5 + 0.01 * rng.standard_normal(200), n=5),
            fa.NumberFluctuations().compute(frames), fa.VelocityCorrelation(r_max=5).compute(frames),
            fa.DensityProfile(bin_width=0.5).compute(frames), fa.Clusters().compute(frames),
            fa.BoxCounting().compute(frames), fa.MeanSquareDisplacement().compute(frames),
            fa.NematicOrder().compute(frames), fa.PerSpecies(fa.PolarOrder(start=2)).compute(typed)]


def line_colours(ax):
    return {to_hex(line.get_color()) for line in ax.get_lines()}


def test_plots_touch_only_the_axes_given(computed):
    import matplotlib.pyplot as plt

    for obj in computed:
        fig = Figure(figsize=(6, 3))
        ax, other = fig.subplots(1, 2)
        before = (to_hex(fig.get_facecolor()), to_hex(ax.get_facecolor()), fig.get_size_inches().tolist())
        figures = plt.get_fignums()
        assert obj.plot(ax) is ax
        assert ax.has_data() and ax.get_xlabel() and ax.get_ylabel()
        assert not other.has_data() and not other.get_xlabel() and other.get_legend() is None
        assert fig._suptitle is None and fig._supxlabel is None and not fig.texts and len(fig.axes) == 2
        assert (to_hex(fig.get_facecolor()), to_hex(ax.get_facecolor()), fig.get_size_inches().tolist()) == before
        assert plt.get_fignums() == figures


@pytest.mark.parametrize("theme", ["dark", "light"])
def test_colours_follow_the_theme(computed, theme):
    colours = {to_hex(c) for c in style.palette(theme)}
    background = "black" if theme == "dark" else "white"
    for obj in computed:
        fig, ax = style.figure("column", theme=theme)  # a house figure says its theme
        obj.plot(ax)
        assert line_colours(ax) <= colours, type(obj).__name__
        fig = Figure()
        ax = fig.subplots()
        ax.set_facecolor(background)  # a user's axes: the theme that reads on its background
        obj.plot(ax)
        assert line_colours(ax) <= colours, type(obj).__name__
        legend = ax.get_legend()
        if legend is not None:
            assert {to_hex(t.get_color()) for t in legend.get_texts()} == {to_hex(get_theme(theme).text)}
        ax = Figure().subplots()
        obj.plot(ax, theme=theme)  # or the theme asked for
        assert line_colours(ax) <= colours


def test_a_plot_without_axes_gets_a_house_figure(computed):
    import matplotlib.pyplot as plt

    figures = plt.get_fignums()
    ax = computed[1].plot()
    assert ax.figure.get_size_inches().tolist() == list(style.SIZES["column"])
    assert getattr(ax.figure, "_flocking_theme") == "dark"
    assert computed[1].plot(theme="light").figure._flocking_theme == "light"
    assert plt.get_fignums() == figures  # no pyplot state


def test_labels_are_mathtext(computed):
    expected = [("time", "phi"), ("mean_count", "count_std"), ("r", "corr"), (None, None),
                ("cluster_size", None), ("box_size", "boxes"), ("lag", "msd")]
    for obj, (x, y) in zip(computed, expected):
        ax = obj.plot()
        if x:
            assert ax.get_xlabel() == style.LABELS[x]
        if y:
            assert ax.get_ylabel() == style.LABELS[y]
    profile = computed[3].plot()
    assert profile.get_ylabel() == r"density $\rho(x)$" and profile.get_xlabel().startswith("$x$")


def test_legends_state_what_the_summary_states(computed):
    clusters, boxcount, profile = computed[4], computed[5], computed[3]
    texts = [t.get_text() for t in clusters.plot().get_legend().get_texts()]
    assert f"largest: {clusters.largest_fraction_mean:.3f} $N$" in texts
    assert f"mean of {clusters.num_frames} frames" in texts
    texts = [t.get_text() for t in boxcount.plot().get_legend().get_texts()]
    assert any(t.startswith("$D = ") for t in texts)
    assert profile.band_count == 1
    texts = [t.get_text() for t in profile.plot().get_legend().get_texts()]
    assert f"band, width {profile.band_widths[0]:.3g}" in texts


def test_every_figure_renders_at_every_size(computed, tmp_path):
    # vector formats: see test_analysis_cli.py
    for obj in computed:
        for size in ("column", "slide"):
            fig, ax = style.figure(size, theme="light")
            obj.plot(ax)
            style.title(fig, type(obj).__name__, "2D · N = 3000 · L = 20")
            style.save(fig, tmp_path / "f.png", dpi=30)
            assert (tmp_path / "f.png").stat().st_size > 0
