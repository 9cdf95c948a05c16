"""Sweep figures: what a reader sees (axes, units, legend, caption, reference lines, error
bars), the finite-size view's crossings and exponent, formats, themes, sizes and refusals.

Results are made from synthetic records (no simulation): known values in, known figure out.
"""

from __future__ import annotations

import math
import os
import re

import numpy as np
import pytest
from matplotlib.colors import to_rgb

xr = pytest.importorskip("xarray")

from flocking.model import ParameterError  # noqa: E402
from flocking.sweep.figures import draw, plot, summarise  # noqa: E402
from flocking.sweep.results import gather  # noqa: E402
from flocking.sweep.point import RECORD_FORMAT  # noqa: E402
from flocking.sweep.runner import PointStore  # noqa: E402
from flocking.sweep.spec import SweepSpec  # noqa: E402
from flocking.viz.colors import THEMES  # noqa: E402

ETA_C, GAMMA_NU = 2.0, 1.75  # where the synthetic Binder curves cross; chi_max ~ L^(gamma/nu)


def synthetic(tmp_path, grid, base=None, replicas=3, error=0.01, sweep=None):
    """Results of a sweep whose records hold a smooth transition at ``ETA_C``: ``G``
    falls from 2/3 to 1/3, more steeply for larger N (the curves cross at ``ETA_C``),
    ``chi`` peaks there at ``N^(gamma / (2 nu))``; replicas agree to within ``error``."""
    base = {"steps": 40, **({"density": 2.0} if base is None else base)}
    spec = SweepSpec.from_dict({"sweep": {"replicas": replicas, "discard": 20, **(sweep or {})}, "base": base,
                                "grid": grid})
    out = str(tmp_path / "out")
    store = PointStore(out)
    rng = np.random.default_rng(0)
    for p in spec.points():
        n, eta = p.config.model.n, p.params.get("noise", ETA_C)
        width = 2.0 / math.sqrt(n)
        g = 0.5 - np.tanh((eta - ETA_C) / width) / 6
        chi = n ** (GAMMA_NU / 2) * math.exp(-((eta - ETA_C) / width) ** 2)
        order = 0.5 - np.tanh((eta - ETA_C) / width) / 2.5
        noise = error * rng.standard_normal(3)
        moments = {"mean": order + noise[0], "phi2": order**2, "phi4": order**4,
                   "susceptibility": chi * (1 + noise[1]), "binder": g + noise[2]}
        errors = {"mean": error, "phi2": error, "phi4": error, "susceptibility": error * chi, "binder": error}
        store.save({"id": p.id, "params": p.params, "replica": p.replica, "seed": p.config.model.seed,
                    "status": "done", "format": RECORD_FORMAT, "moments": moments, "errors": errors, "tau": 2.0,
                    "drift": 0.1, "samples": 20, "first_step": 21, "elapsed": 0.0})
    return gather(spec, out)


def caption(fig) -> str:
    return fig._supxlabel.get_text().replace("\n", " ")


def texts(ax) -> list[str]:
    return [t.get_text() for t in ax.texts]


def legend_texts(ax) -> list[str]:
    return [t.get_text() for t in ax.get_legend().get_texts()]


# -- the order view -------------------------------------------------------------------------------

@pytest.mark.parametrize("theme", ["dark", "light"])
def test_order_view_says_what_is_plotted(tmp_path, theme):
    ds = synthetic(tmp_path, {"noise": {"start": 0.5, "stop": 3.5, "num": 7}, "n": [100, 400]})
    fig = draw(ds, theme=theme, size="page")
    axes = fig.axes
    assert len(axes) == 3
    assert all(ax.get_xlabel() == r"angular noise $\eta$ (rad)" for ax in axes)
    assert [ax.get_ylabel() for ax in axes] == [r"order $\langle\varphi\rangle$", r"susceptibility $\chi$",
                                               r"Binder cumulant $G$"]
    assert legend_texts(axes[0]) == ["$N$ = 100", "$N$ = 400"]
    assert fig._suptitle.get_text() == "2D Vicsek model with angular noise: order, susceptibility and Binder cumulant"
    text = caption(fig)
    for part in [r"$N$ = 100, 400", r"$\rho$ = 2", "$v_0$ = 0.5", "$R$ = 1", "backward update",
                 "40 steps, first 20 discarded", "mean of 3 replicas",
                 "the within-run one (autocorrelation time) or the replicas' scatter if larger"]:
        assert part in text, part
    # Binder reference lines: labelled, inside the axes, in the theme's text colour
    binder = axes[2]
    assert {"2/3 ordered", "1/3 disordered"} <= set(texts(binder))
    low, high = binder.get_ylim()
    assert low < 1 / 3 and high > 2 / 3
    levels = [line for line in binder.get_lines() if list(line.get_ydata()) in ([1 / 3] * 2, [2 / 3] * 2)]
    assert len(levels) == 2
    assert all(np.allclose(to_rgb(line.get_color()), THEMES[theme].text) for line in levels)
    assert np.allclose(fig.get_facecolor()[:3], THEMES[theme].figure)
    # no label covers a point: G reaches 1/3 on the right, so "1/3 disordered" sits on the left
    fig.canvas.draw()
    points = np.vstack([binder.transData.transform(np.column_stack(line.get_data()))
                        for line in binder.get_lines() if line.get_marker() == "o"])
    for label in binder.texts:
        box = label.get_window_extent()
        assert not any(box.contains(*p) for p in points), label.get_text()
    assert [t.get_position()[0] for t in binder.texts if t.get_text() == "1/3 disordered"] == [0.02]


def test_error_bars_are_the_combined_errors(tmp_path):
    ds = synthetic(tmp_path, {"noise": [1.0, 2.0, 3.0], "n": [100]}, error=0.02)
    x, curves, stats = summarise(ds)
    assert (x, curves) == ("noise", ["n"])
    mean, error = stats["order"]
    values = ds["order"].sel(n=100).values
    within = 0.02 * math.sqrt(3) / 3
    sem = values.std(axis=1, ddof=1) / math.sqrt(3)
    assert np.allclose(error.sel(n=100).values, np.maximum(within, sem))
    assert np.allclose(mean.sel(n=100).values, values.mean(axis=1))
    fig = draw(ds)
    segments = fig.axes[0].collections[0].get_segments()  # the error bars of the first curve
    heights = [seg[1][1] - seg[0][1] for seg in segments]
    assert np.allclose(heights, 2 * error.sel(n=100).values)


def test_one_size_still_names_n_and_old_files_say_their_error_bars_are_standard_errors(tmp_path):
    ds = synthetic(tmp_path, {"noise": [1.0, 2.0, 3.0]}, base={"n": 256, "density": 2.0})
    fig = draw(ds, theme="light")
    assert "$N$ = 256" in caption(fig) and fig.axes[0].get_legend() is None
    old = ds.drop_vars([v for v in ds.data_vars if v.endswith("_error")])
    assert "bars: standard error over replicas" in caption(draw(old))


@pytest.mark.parametrize("base, label", [
    ({"noise_scale": "unit"}, r"angular noise $\eta' = \eta/2\pi$"),
    ({"noise_type": "vectorial"}, r"vectorial noise $\eta$"),
])
def test_the_noise_axis_says_how_the_noise_was_given(tmp_path, base, label):
    ds = synthetic(tmp_path, {"noise": [0.1, 0.3, 0.5]}, base={"n": 100, "density": 2.0, **base})
    fig = draw(ds)
    assert fig.axes[0].get_xlabel() == label
    assert ("vectorial noise" in fig._suptitle.get_text()) == (base.get("noise_type") == "vectorial")


def test_sizes_on_the_x_axis_are_logarithmic_with_their_values_as_ticks(tmp_path):
    ds = synthetic(tmp_path, {"n": [64, 256, 1024, 4096], "noise": [1.5, 2.5]})
    fig = draw(ds, x="n", size="slide")
    ax = fig.axes[0]
    assert ax.get_xscale() == "log" and ax.get_xlabel() == "particles $N$"
    fig.canvas.draw()
    assert [t.get_text() for t in ax.get_xticklabels() if t.get_text()] == ["64", "256", "1024", "4096"]
    assert legend_texts(ax) == [r"$\eta$ = 1.5", r"$\eta$ = 2.5"]
    assert "$N$" not in caption(fig).split(" \u00b7 ")[0]  # on the axis, not in the caption


def test_a_paper_column_stacks_the_panels(tmp_path):
    ds = synthetic(tmp_path, {"noise": [1.0, 2.0, 3.0], "n": [100, 400]})
    fig = draw(ds, size="column", theme="light")
    assert tuple(fig.get_size_inches())[0] == pytest.approx(3.4)
    boxes = [ax.get_position() for ax in fig.axes]
    assert boxes[0].y0 > boxes[1].y0 > boxes[2].y0 and boxes[0].x0 == pytest.approx(boxes[2].x0, abs=0.05)
    assert [ax.get_xlabel() for ax in fig.axes][-1] == r"angular noise $\eta$ (rad)"


# -- the finite-size view -------------------------------------------------------------------------

def test_fss_view_marks_binder_crossings_and_fits_the_exponent(tmp_path):
    noise = {"start": 1.0, "stop": 3.0, "num": 21}
    ds = synthetic(tmp_path, {"noise": noise, "n": [256, 1024, 4096]}, error=0.002)
    fig = draw(ds, view="fss", theme="light")
    left, right = fig.axes
    assert left.get_ylabel() == r"Binder cumulant $G$" and {"2/3 ordered", "1/3 disordered"} <= set(texts(left))
    marks = [line for line in left.get_lines() if line.get_label() == "crossing"]
    crossings = [x for line in left.get_lines() if line.get_marker() == "x" for x in line.get_xdata()]
    assert marks and crossings and all(abs(x - ETA_C) < 0.1 for x in crossings)
    assert right.get_xscale() == "log" and right.get_yscale() == "log"
    fit = [t for t in legend_texts(right) if t.startswith("fit, 3 sizes:")][0]
    value, error = (float(v) for v in re.findall(r"[-\d.]+", fit.split("=")[1]))
    assert abs(value - GAMMA_NU) < max(4 * error, 0.05)  # the grid misses the peak only slightly here
    assert r"$\gamma/\nu$ = $d$ " + "\u00d7" + r" slope of $\ln\chi_{max}$ against $\ln N$" in caption(fig)


def test_fss_view_marks_no_crossing_that_the_grid_does_not_resolve(tmp_path):
    # curves that cross at 2.0, sampled at 1.9 and 2.1 (apart by many errors) and at three values
    # within 0.001 of 2.0 (where they agree within their errors): the data swap the curves'
    # order somewhere between 1.9 and 2.1, four grid steps, and do not place the crossing
    grid = {"noise": [1.9, 1.999, 2.0, 2.001, 2.1], "n": [256, 4096]}
    fig = draw(synthetic(tmp_path, grid, error=0.002), view="fss", theme="light")
    assert not [line for line in fig.axes[0].get_lines() if line.get_marker() == "x"]
    assert r"$N$ = 256 and 4096 swap order between $\eta$ = 1.9 and 2.1, no crossing resolved" in caption(fig)
    # sampled at 1.9, 2.0 and 2.1: two grid steps, the crossing is marked between them
    fine = draw(synthetic(tmp_path / "fine", {"noise": [1.9, 2.0, 2.1], "n": [256, 4096]}, error=0.002),
                view="fss")
    crossings = [x for line in fine.axes[0].get_lines() if line.get_marker() == "x" for x in line.get_xdata()]
    assert len(crossings) == 1 and 1.9 < crossings[0] < 2.1 and "no crossing" not in caption(fine)


@pytest.mark.parametrize("grid, options, message", [
    ({"noise": [1.0, 2.0], "n": [100]}, {"view": "fss"}, "view: fss needs at least two system sizes"),
    ({"noise": [1.0, 2.0], "n": [100, 400], "speed": [0.1, 0.5]}, {"view": "fss"}, "also sweeps speed"),
    ({"noise": [1.0, 2.0], "n": [100, 400]}, {"view": "fss", "x": "n"}, "x: the fss view draws sizes as curves"),
    ({"noise": [1.0, 2.0]}, {"x": "speed"}, "x: must be one of the swept parameters noise"),
    ({"noise": [1.0, 2.0]}, {"view": "phase"}, "view: must be one of order, fss"),
    ({"noise": [1.0, 2.0]}, {"size": "poster"}, "size: must be one of column, page, slide"),
    ({"noise": [1.0, 2.0]}, {"theme": "sepia"}, "theme: must be one of dark, light"),
    ({"noise": [1.0, 2.0], "neighbours": ["metric", "topological"]}, {"x": "neighbours"}, "does not take numbers"),
])
def test_figures_refuse_what_they_cannot_draw(tmp_path, grid, options, message):
    ds = synthetic(tmp_path, grid, base={"density": 2.0, **({} if "n" in grid else {"n": 100})})
    with pytest.raises(ParameterError, match=re.escape(message)):
        draw(ds, **options)


def test_fss_needs_one_density(tmp_path):
    ds = synthetic(tmp_path, {"noise": [1.0, 2.0], "n": [100, 400]}, base={"box": 10.0})
    with pytest.raises(ParameterError, match="view: fss needs one density for every size"):
        draw(ds, view="fss")


@pytest.mark.parametrize("ext, magic", [("png", b"\x89PNG"), ("svg", b"<?xml"), ("pdf", b"%PDF")])
def test_the_extension_chooses_the_format(tmp_path, ext, magic):
    ds = synthetic(tmp_path, {"noise": [1.0, 2.0, 3.0], "n": [100, 400]})
    path = plot(ds, str(tmp_path / f"fig.{ext}"), view="fss", theme="light", size="column", dpi=50)
    with open(path, "rb") as f:
        assert f.read(len(magic)) == magic
    with pytest.raises(ParameterError, match="output: must end in .png, .svg or .pdf"):
        plot(ds, str(tmp_path / "fig.jpg"))
    assert sorted(os.listdir(tmp_path)) == sorted(["out", f"fig.{ext}"])


def test_a_3d_sweep_draws_the_disordered_binder_value_of_3d(tmp_path):
    ds = synthetic(tmp_path, {"noise": [1.0, 2.0, 3.0]}, base={"dim": 3, "n": 100, "density": 1.0})
    fig = draw(ds)
    assert fig._suptitle.get_text() == "3D Vicsek model with angular noise: order, susceptibility and Binder cumulant"
    assert {"2/3 ordered", "4/9 disordered"} <= set(texts(fig.axes[2]))
    assert "1/3 disordered" not in texts(fig.axes[2])
