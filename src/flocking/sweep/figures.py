"""Figures of a sweep's results, in the house style (:mod:`flocking.viz.style`).

Two views of a results Dataset (:mod:`flocking.sweep.results`):

- ``order``: the order ``<phi>``, the susceptibility ``chi`` and the Binder cumulant ``G``
  against one swept parameter, one curve per value of the others (per system size);
- ``fss``: finite-size scaling: ``G`` against the control parameter for every size, with
  a crossing of the curves of successive sizes marked only where the grid resolves it
  (they swap order within two grid steps, apart by 3 errors at both ends; a swap across
  a wider stretch is named in the caption, not marked), and the largest ``chi`` on the
  grid against the size on log-log axes with the fitted exponent ``gamma / nu``.

Points are means over replicas; their error bars combine each run's own error (from its
autocorrelation time) with the scatter between replicas (:func:`flocking.sweep.stats.combine`).
The title names the model, the caption every parameter that was not swept, the run length
and transient, and which error a bar shows.
"""

from __future__ import annotations

import itertools
import json
import math
import os

import numpy as np

from ..config import RUN_DEFAULTS
from ..model import ParameterError
from ..viz import style
from ..viz.colors import get_theme
from . import stats

VIEWS = ("order", "fss")
#: Parameters that set the system size: one curve each, logarithmic when on the x axis.
SIZE_KEYS = ("n", "box")
#: The results drawn against the swept parameter, as the Dataset names them.
QUANTITIES = ("order", "susceptibility", "binder")
_SYMBOLS = {"n": "$N$", "density": r"$\rho$", "box": "$L$", "speed": "$v_0$", "radius": "$R$", "k": "$k$",
            "noise": r"$\eta$", "alignment": r"$\varepsilon$", "delay": "delay", "dt": r"$\Delta t$",
            "steps": "steps", "dim": "$d$"}
_Y = {"order": "mean_phi", "susceptibility": "chi", "binder": "binder"}
#: Parameters named in a caption only where they differ from these (docs/model.md's defaults).
_DEFAULTS = {"alignment": 1.0, "delay": 0, "dt": 1.0}


def summarise(ds, x: str | None = None):
    """``(x, curves, stats)``: the axis, the other swept dimensions, and for ``order``,
    ``susceptibility`` and ``binder`` the mean over replicas and its error
    (:func:`flocking.sweep.stats.combine`; the standard error alone where a file holds no
    within-run errors).

    ``x`` defaults to the first swept parameter that does not set the system size.
    """
    import xarray as xr

    dims = [d for d in ds["order"].dims if d != "replica"]
    if not dims:
        raise ParameterError("results: nothing was swept; there is no curve to draw")
    if x is None:
        others = [d for d in dims if d not in (*SIZE_KEYS, "density")]
        x = (others or dims)[0]
    elif x not in dims:
        raise ParameterError(f"x: must be one of the swept parameters {', '.join(dims)} (got {x!r})")
    curves = [d for d in dims if d != x]
    out = {}
    for name in QUANTITIES:
        values = ds[name].transpose(..., "replica")
        errors = ds[f"{name}_error"].transpose(..., "replica") if f"{name}_error" in ds else np.nan
        mean, error = stats.combine(values.values, getattr(errors, "values", errors))
        coords = {d: values[d] for d in values.dims[:-1]}
        out[name] = (xr.DataArray(mean, coords, values.dims[:-1]), xr.DataArray(error, coords, values.dims[:-1]))
    return x, curves, out


def draw(ds, x: str | None = None, view: str = "order", theme: str = "dark", size: str = "page"):
    """The figure of ``view`` (``order`` or ``fss``) of the results ``ds``: a matplotlib
    Figure in the house style, ``size`` one of ``column`` (panels stacked), ``page``, ``slide``."""
    if view not in VIEWS:
        raise ParameterError(f"view: must be one of {', '.join(VIEWS)} (got {view!r})")
    return (_order if view == "order" else _fss)(ds, x, theme, size)


def plot(ds, path: str | os.PathLike, x: str | None = None, view: str = "order", theme: str = "dark",
         size: str = "page", dpi: float | None = None) -> str:
    """:func:`draw` into ``path``, whose extension (.png, .svg, .pdf) chooses the format."""
    style.check_format(path)
    return style.save(draw(ds, x, view, theme, size), path, dpi=dpi)


# -- the order view -----------------------------------------------------------------------------

def _order(ds, x, theme, size):
    x, curves, summary = summarise(ds, x)
    setup = _Setup(ds)
    fig, axes = _panels(size, theme, 3)
    combos = list(itertools.product(*(range(ds.sizes[c]) for c in curves)))
    xs = _axis_values(ds, x)
    graded = len(combos) > len(style.palette(theme)) and len(curves) == 1 and ds[curves[0]].dtype.kind in "fiu"
    colours = _graded(theme, len(combos)) if graded else style.palette(theme)
    for k, combo in enumerate(combos):
        sel = dict(zip(curves, combo))
        label = ", ".join(setup.value_label(c, ds[c].values[i]) for c, i in sel.items()) or None
        for ax, name in zip(axes, QUANTITIES):
            mean, error = (a.isel(sel).transpose(x).values for a in summary[name])
            _errorbar(ax, xs, mean, error, colours[k % len(colours)], label, fig)
    for ax, name in zip(axes, QUANTITIES):
        style.label_axes(ax, setup.axis_label(x) if ax is axes[-1] or size != "column" else None, _Y[name])
        _scale(ax, x, xs)
    axes[0].set_ylim(bottom=0)
    if graded:
        _colour_key(fig, axes, theme, ds[curves[0]].values, setup.axis_label(curves[0]), size)
    elif combos and curves:
        style.legend(axes[0], theme)
    _binder_references(axes[2], theme, setup.single("dim"))
    style.title(fig, f"{setup.model_name()}: order, susceptibility and Binder cumulant",
                " \u00b7 ".join(setup.caption(exclude=(x,)) + [setup.error_caption()]))
    return fig


# -- the finite-size view -----------------------------------------------------------------------

def _fss(ds, x, theme, size):
    sizes = [d for d in ds["order"].dims if d in SIZE_KEYS]
    if len(sizes) > 1:
        raise ParameterError(f"view: fss needs one swept size parameter (got {' and '.join(sizes)})")
    if not sizes or ds.sizes[sizes[0]] < 2:
        raise ParameterError("view: fss needs at least two system sizes (n or box swept)")
    key = sizes[0]
    x, curves, summary = summarise(ds, x)
    if x == key:
        raise ParameterError(f"x: the fss view draws sizes as curves; choose a control parameter, not {x!r}")
    extra = [c for c in curves if c != key]
    if extra:
        raise ParameterError(f"view: fss needs a sweep over one parameter and the size; this one also "
                             f"sweeps {', '.join(extra)} (select a value with xarray's sel first)")
    setup = _Setup(ds)
    if len(setup.values("density")) > 1:
        raise ParameterError("view: fss needs one density for every size (sweep n at a fixed density, "
                             "or box at a fixed density)")
    fig, (left, right) = _panels(size, theme, 2)
    colours = style.palette(theme)
    xs = _axis_values(ds, x)
    mean_g, error_g = (a.transpose(key, x).values for a in summary["binder"])
    mean_chi, error_chi = (a.transpose(key, x).values for a in summary["susceptibility"])
    labels = [setup.value_label(key, v) for v in ds[key].values]
    for k, label in enumerate(labels):
        _errorbar(left, xs, mean_g[k], error_g[k], colours[k % len(colours)], label, fig)
    marked, unresolved = False, []
    for k in range(len(labels) - 1):
        swap = _order_swap(xs, mean_g[k], error_g[k], mean_g[k + 1], error_g[k + 1])
        if swap is None:
            continue
        x0, x1, crossing = swap
        if crossing is None:
            unresolved.append(f"{labels[k]} and {_number(ds[key].values[k + 1], 3)} swap order between "
                              f"{setup.symbol(x)} = {_number(x0, 3)} and {_number(x1, 3)}, no crossing resolved")
            continue
        left.plot(*([v] for v in crossing), marker="x", ms=1.2 * style.fontsize(fig), mew=1.5, ls="none",
                  color=_text_colour(theme), label=None if marked else "crossing", zorder=5)
        marked = True
    style.label_axes(left, setup.axis_label(x), "binder")
    _scale(left, x, xs)
    style.legend(left, theme)
    _binder_references(left, theme, setup.single("dim"))

    n = np.array([setup.size_of(key, v) for v in ds[key].values], dtype=float)
    peaks = np.array([stats.peak(xs, mean_chi[k], error_chi[k]) for k in range(len(n))])
    ok = np.isfinite(peaks[:, 1])
    right.errorbar(n[ok], peaks[ok, 1], yerr=_bars(peaks[ok, 2]), marker="o", ms=0.45 * style.fontsize(fig),
                   capsize=2, lw=0, elinewidth=1.0, color=colours[0], label=r"$\chi_{max}$ on the grid")
    slope, intercept, slope_error = stats.exponent(n, peaks[:, 1], peaks[:, 2])
    dim = setup.single("dim", 2)
    if math.isfinite(slope):
        grid = np.geomspace(n[ok].min(), n[ok].max(), 50)
        right.plot(grid, np.exp(intercept) * grid**slope, color=colours[1], lw=1.2, ls="--",
                   label=rf"fit, {int(ok.sum())} sizes: $\gamma/\nu$ = {dim * slope:.2f} $\pm$ {dim * slope_error:.2f}")
    _scale(right, "n", n[ok])
    right.set_yscale("log")
    _log_ticks(right.yaxis)
    style.label_axes(right, "n", r"peak susceptibility $\chi_{max}$")
    style.legend(right, theme)
    caption = setup.caption(exclude=(x,)) + [
        setup.error_caption(),
        *(["\u00d7: crossing of successive sizes (apart by 3 errors within two grid steps of it)"]
          if marked else []),
        *unresolved,
        rf"$\chi_{{max}}$: largest mean $\chi$ on the grid of {setup.symbol(x)}; $\gamma/\nu$ = $d$ " + "\u00d7"
        + rf" slope of $\ln\chi_{{max}}$ against $\ln N$ at fixed density ($d$ = {dim})"]
    style.title(fig, f"Finite-size scaling of the {setup.model_name()}", " \u00b7 ".join(caption))
    return fig


def _order_swap(x, a, ea, b, eb):
    """Where curve ``b`` swaps order with curve ``a`` for sure: ``(x0, x1, crossing)``, the
    grid values between which ``b - a`` changes sign, both differences larger than three
    combined errors (curves lying on each other's noise do not count), and the crossing
    ``(x, G)`` when ``x0`` and ``x1`` are at most two grid steps apart (``None`` when more
    values between them differ by less: the data do not place it); of several swaps,
    the one with the largest differences on both sides; ``None`` when they never swap.

    >>> x = np.arange(5.0)
    >>> a, b, e = np.zeros(5), np.array([0.1, 0.1, -0.1, -0.1, -0.1]), np.full(5, 0.01)
    >>> _order_swap(x, a, e, b, e)
    (1.0, 2.0, (1.5, 0.0))
    >>> b[1] = b[2] = 0.0   # the swap is somewhere between x = 0 and 3
    >>> _order_swap(x, a, e, b, e)
    (0.0, 3.0, None)
    """
    d = np.asarray(b) - np.asarray(a)
    z = np.abs(d) / np.hypot(np.nan_to_num(ea), np.nan_to_num(eb))
    significant = np.flatnonzero(np.isfinite(d) & (z > 3))
    best, strength = None, 0.0
    for i, j in zip(significant[:-1], significant[1:]):
        if d[i] * d[j] < 0 and min(z[i], z[j]) > strength:
            crossing = None
            if j - i <= 2:
                found = stats.crossings(x[i:j + 1], a[i:j + 1], b[i:j + 1])
                xc = found[len(found) // 2]
                crossing = (float(xc), float(np.interp(xc, x, a)))
            best, strength = (float(x[i]), float(x[j]), crossing), min(z[i], z[j])
    return best


# -- pieces -------------------------------------------------------------------------------------

class _Setup:
    """What the configurations of a results Dataset have in common, in words."""

    def __init__(self, ds):
        from ..config import RunConfig

        self.ds = ds
        first = ds["config"].isel(replica=0) if "replica" in ds["config"].dims else ds["config"]
        texts = [t for t in np.asarray(first.values).ravel() if t]
        self.configs = [RunConfig.from_toml(str(t)) for t in texts]
        self.discard = json.loads(ds.attrs.get("discard", "0.5"))
        self.replicas = int(ds.sizes.get("replica", 1))
        self.has_errors = "order_error" in ds and bool(np.isfinite(ds["order_error"]).any())

    def values(self, name: str) -> list:
        """The distinct values of a run parameter across the sweep, in order of appearance."""
        out = []
        for cfg in self.configs:
            value = getattr(cfg if name in RUN_DEFAULTS else cfg.model, name)
            value = tuple(value) if isinstance(value, (list, tuple)) else value
            if not any(_same(value, v) for v in out):
                out.append(value)
        return out

    def single(self, name: str, default=None):
        values = self.values(name)
        return values[0] if len(values) == 1 else default

    def noise_scale(self) -> str:
        """``unit`` when the sweep gave angular noise as ``eta'`` in [0, 1], else ``radians``."""
        if "noise" not in self.ds.dims or self.single("noise_type") != "angular":
            return "radians"
        from ..config import RunConfig

        first = self.ds["config"].isel(replica=0) if "replica" in self.ds["config"].dims else self.ds["config"]
        for value in self.ds["noise"].values:
            if value > 0:
                text = str(first.sel(noise=value).values.ravel()[0])
                eta = RunConfig.from_toml(text).model.noise
                return "unit" if math.isclose(eta, 2 * math.pi * value, rel_tol=1e-9) and \
                    not math.isclose(eta, value, rel_tol=1e-9) else "radians"
        return "radians"

    def model_name(self) -> str:
        dim = self.single("dim")
        noise = self.single("noise_type")
        neighbours = self.single("neighbours")
        words = [w for w in (f"{noise} noise" if noise else None,
                             {"metric": None, "topological": f"{self.single('k', '')} nearest neighbours",
                              "voronoi": "Voronoi neighbours"}
                             .get(neighbours)) if w]
        name = f"{dim}D Vicsek model" if dim else "Vicsek model"
        return name + (f" with {' and '.join(words)}" if words else "")

    def symbol(self, name: str) -> str:
        if name == "noise" and self.noise_scale() == "unit":
            return r"$\eta'$"
        return _SYMBOLS.get(name, name)

    def axis_label(self, name: str) -> str:
        if name == "noise":
            noise = self.single("noise_type")
            if noise == "angular":
                return (r"angular noise $\eta' = \eta/2\pi$" if self.noise_scale() == "unit"
                        else r"angular noise $\eta$ (rad)")
            return r"vectorial noise $\eta$" if noise == "vectorial" else r"noise $\eta$"
        if name == "n":
            return style.LABELS["n"]
        if name == "box":
            return "box side $L$"
        if name == "density":
            return style.LABELS["density"]
        return self.symbol(name)

    def value_label(self, name: str, value) -> str:
        if name == "box":
            value = json.loads(value) if isinstance(value, str) and value.startswith("[") else value
        return f"{self.symbol(name)} = {_number(value, 3)}"

    def size_of(self, key: str, value) -> float:
        """The particle count ``N`` of the runs at ``key = value`` (the x axis of the fss view)."""
        if key == "n":
            return float(value)
        return float(np.nanmax(self.ds["n"].sel({key: value}).values))

    def caption(self, exclude=()) -> list[str]:
        """Parameters as ``symbol = value`` parts; swept ones list their values."""
        parts = []
        neighbours = self.single("neighbours")
        names = ["n", "density", "speed"] + (["k"] if neighbours == "topological" else ["radius"])
        names += [name for name, default in _DEFAULTS.items() if self.values(name) != [default]]
        if "noise" not in self.ds.dims:
            names.append("noise")
        for name in names:
            if name in exclude:
                continue
            values = self.values(name)
            if not values:
                continue
            shown = ", ".join(_number(v) for v in sorted(values)) if len(values) <= 5 else \
                f"{_number(min(values))} to {_number(max(values))}"
            parts.append(f"{self.symbol(name)} = {shown}")
        update = self.single("update")
        if update:
            parts.append(f"{update} update")
        steps = self.values("steps")
        if len(steps) == 1:
            parts.append(f"{steps[0]} steps, first {self._discarded(steps[0])} discarded")
        elif steps:
            parts.append(f"{min(steps)} to {max(steps)} steps, transient {self._discard_text()} discarded")
        return parts

    def error_caption(self) -> str:
        reps = f"mean of {self.replicas} replica{'s' * (self.replicas != 1)}"
        if self.has_errors:
            return (f"{reps}; bars: \u00b11 error, the within-run one (autocorrelation time) or the "
                    f"replicas' scatter if larger")
        return f"{reps}; bars: standard error over replicas (no within-run errors in this file)"

    def _discarded(self, steps: int) -> int:
        from .spec import SweepSpec

        return SweepSpec(base={}, grid={}, discard=self.discard).discard_steps(steps)

    def _discard_text(self) -> str:
        return f"{self.discard:.0%}" if isinstance(self.discard, float) else f"{self.discard} steps"


def _same(a, b) -> bool:
    if isinstance(a, float) and isinstance(b, float):
        return math.isclose(a, b, rel_tol=1e-9)
    return a == b


def _number(value, digits: int = 4) -> str:
    if isinstance(value, (tuple, list)):
        return "\u00d7".join(_number(v, digits) for v in value) if len(set(value)) > 1 else _number(value[0], digits)
    if isinstance(value, (float, np.floating)):
        return f"{float(value):.{digits}g}"
    return str(value.item() if isinstance(value, np.generic) else value)


def _panels(size: str, theme, count: int):
    """``count`` panels: stacked in a paper column, side by side on a page or a slide; the
    named size's width and font, with room added below for the caption."""
    if size not in style.SIZES:
        raise ParameterError(f"size: must be one of {', '.join(style.SIZES)} (got {size!r})")
    width, height = style.SIZES[size]
    if size == "column":
        fig, axes = style.figure((width, 0.9 + 1.9 * count), theme, nrows=count, ncols=1, sharex=count == 3)
    else:
        fig, axes = style.figure((width, height + 0.9), theme, nrows=1, ncols=count)
    return fig, list(axes)


def _axis_values(ds, x: str) -> np.ndarray:
    values = ds[x].values
    if values.dtype.kind in "fiu":
        return values.astype(float)
    if x == "box":  # a box per axis: its first side
        return np.array([json.loads(v)[0] if str(v).startswith("[") else float(v) for v in values])
    raise ParameterError(f"x: {x!r} does not take numbers; choose a numeric swept parameter")


def _scale(ax, x: str, values) -> None:
    """Sizes on a logarithmic axis, ticked at the sizes swept (when there are a few)."""
    if x in SIZE_KEYS:
        from matplotlib import ticker

        ax.set_xscale("log")
        if len(values) <= 6:
            ax.xaxis.set_major_locator(ticker.FixedLocator(values))
            ax.xaxis.set_major_formatter(ticker.FuncFormatter(lambda v, _: f"{v:g}"))
            ax.xaxis.set_minor_formatter(ticker.NullFormatter())


def _log_ticks(axis) -> None:
    """Plain numbers at 1, 2 and 5 of each decade of a logarithmic axis."""
    from matplotlib import ticker

    axis.set_major_locator(ticker.LogLocator(subs=(1.0, 2.0, 5.0)))
    axis.set_major_formatter(ticker.FuncFormatter(lambda v, _: f"{v:g}"))
    axis.set_minor_formatter(ticker.NullFormatter())


def _bars(error):
    error = np.asarray(error, dtype=float)
    return np.where(np.isfinite(error), error, 0.0)


def _errorbar(ax, x, mean, error, colour, label, fig) -> None:
    ok = np.isfinite(mean)
    ax.errorbar(x[ok], mean[ok], yerr=_bars(error[ok]), marker="o", ms=0.4 * style.fontsize(fig), capsize=2,
                lw=1.1, elinewidth=0.9, color=colour, label=label)


def _graded(theme, count: int) -> list:
    """``count`` colours along viridis, the part of it that reads on the theme's background."""
    from matplotlib import colormaps

    low, high = (0.0, 0.85) if get_theme(theme).name == "light" else (0.25, 1.0)
    return [colormaps["viridis"](v) for v in np.linspace(low, high, count)]


def _colour_key(fig, axes, theme, values, label: str, size: str) -> None:
    """A colour bar for curves coloured by :func:`_graded`: one step per value."""
    from matplotlib.cm import ScalarMappable
    from matplotlib.colors import BoundaryNorm, ListedColormap

    t = get_theme(theme)
    edges = np.arange(len(values) + 1) - 0.5
    mappable = ScalarMappable(BoundaryNorm(edges, len(values)), ListedColormap(_graded(theme, len(values))))
    bar = fig.colorbar(mappable, ax=axes, location="bottom" if size == "column" else "right",
                       fraction=0.05, pad=0.02, aspect=40)
    step = max(1, len(values) // 6)
    bar.set_ticks(range(0, len(values), step), labels=[_number(v, 3) for v in values[::step]])
    bar.set_label(label, color=t.text, fontsize=style.fontsize(fig))
    bar.ax.tick_params(colors=t.text, labelsize=0.85 * style.fontsize(fig))
    bar.outline.set_edgecolor(t.edge)


def _text_colour(theme):
    return get_theme(theme).text


def _binder_references(ax, theme, dim: int | None) -> None:
    """The Binder cumulant of a perfectly ordered state (2/3) and of a disordered one
    (an isotropic Gaussian vector: ``1 - (d + 2) / 3d``, 1/3 in 2D, 4/9 in 3D) as lines,
    each labelled where the curves leave room."""
    colour = _text_colour(theme)
    levels = [(2 / 3, "--", "2/3 ordered")]
    if dim in (2, 3):
        levels.append((1 / 3, ":", "1/3 disordered") if dim == 2 else (4 / 9, ":", "4/9 disordered"))
    bottom, top = ax.get_ylim()
    ax.set_ylim(min(bottom, levels[-1][0] - 0.06), max(top, 2 / 3 + 0.06))
    for level, ls, text in levels:
        ax.axhline(level, color=colour, ls=ls, lw=0.9, alpha=0.7, zorder=0)
        x, ha, above = _free_corner(ax, level)
        ax.text(x, level, text, transform=ax.get_yaxis_transform(), ha=ha, va="bottom" if above else "top",
                color=colour, alpha=0.85, fontsize=0.8 * style.fontsize(ax.figure))


def _free_corner(ax, level: float) -> tuple[float, str, bool]:
    """``(x in axes units, alignment, above)`` of a label on the line ``y = level``: at the
    left or right end, above or below the line, where the fewest data points (error bars
    included) fall in a box about 40% of the width wide and 8% of the height tall. Above
    2/3 is always free (G <= 2/3), so that label sits there, on the right."""
    if level > 0.5:
        return 0.98, "right", True
    low, high = ax.get_ylim()
    height = 0.08 * (high - low)
    (x0, x1) = ax.get_xlim()
    xs, ys = [], []
    for container in ax.containers:  # errorbar containers: points and their bars
        line, _, bars = container.lines
        xs.extend(line.get_xdata())
        ys.extend(line.get_ydata())
        for collection in bars:
            for segment in collection.get_segments():
                xs.extend(np.asarray(segment)[:, 0])
                ys.extend(np.asarray(segment)[:, 1])
    to_axes = ax.transScale + ax.transLimits  # data -> axes fraction, log axes included
    points = to_axes.transform(np.column_stack([xs, ys])) if xs else np.empty((0, 2))
    band = lambda y: (level - height <= y) & (y <= level + height)  # noqa: E731
    best, fewest = (0.98, "right", False), None
    for x, ha, inside in ((0.98, "right", points[:, 0] >= 0.6), (0.02, "left", points[:, 0] <= 0.4)):
        for above in (False, True):
            y = points[:, 1] * (high - low) + low
            hits = inside & band(y) & ((y >= level) if above else (y <= level))
            if fewest is None or hits.sum() < fewest:
                best, fewest = (x, ha, above), int(hits.sum())
    return best


__all__ = ["VIEWS", "draw", "plot", "summarise"]
