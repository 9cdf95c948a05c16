"""The house style of every chart the project draws: runs, analysis, sweeps.

One look in two themes (``dark`` for slides and screens, ``light`` for paper), sizes
named for where a figure goes, labels in mathtext, a title with the parameters that
matter wrapped to the figure's width, and output by file extension (``.png``, ``.svg``,
``.pdf``). Figures are plain :class:`matplotlib.figure.Figure` objects on an Agg
canvas: no display and no pyplot state are involved.

>>> fig, ax = figure("column", theme="light")
>>> _ = ax.plot([0, 1], [0, 1], color=palette("light")[0])
>>> label_axes(ax, "step", "phi")
>>> ax.get_ylabel()
'polar order $\\\\varphi$'
>>> float(fig.get_figwidth())
3.4
>>> check_format("run.tiff")
Traceback (most recent call last):
...
flocking.checks.ParameterError: output: must end in .png, .svg or .pdf (got 'run.tiff')
"""

from __future__ import annotations

import os

import numpy as np

from ..model import ParameterError
from .colors import get_theme

#: Figure sizes in inches (width, height): a paper column, two columns, a slide.
SIZES = {
    "column": (3.4, 2.6),
    "page": (7.0, 3.2),
    "slide": (8.0, 4.5),
}

#: The narrowest a panel of :func:`panels` is drawn, in font sizes (ems): 18 ems is
#: 2.25 in at page width's 9 pt, room for a tick column, a label and a legend.
PANEL_EMS = 18.0

#: Base font size (points) of each size: what journals ask of a column figure, what
#: reads from the back of a room on a slide.
FONT_SIZES = {"column": 8.0, "page": 9.0, "slide": 13.0}

#: File formats a figure can be written to, by extension.
FORMATS = ("png", "svg", "pdf")

#: Default resolution of raster output (dots per inch).
DPI = 200

#: Axis labels of the quantities the project plots, in mathtext.
LABELS = {
    "step": "step $t$",
    "time": r"time $t\,\Delta t$",
    "phi": r"polar order $\varphi$",
    "mean_phi": r"order $\langle\varphi\rangle$",
    "chi": r"susceptibility $\chi$",
    "binder": r"Binder cumulant $G$",
    "eta": r"noise $\eta$",
    "n": "particles $N$",
    "density": r"density $\rho$",
    "r": "distance $r$ (units of $R$)",
    "corr": "$C(r)$",
    "mean_count": r"$\langle n\rangle$",
    "count_std": r"$\Delta n$",
    "lag": r"lag $\Delta t$",
    "msd": r"$\langle|\Delta\mathbf{r}|^2\rangle$ (units of $R^2$)",
    "box_size": r"box size $\ell$ (units of $R$)",
    "boxes": r"occupied boxes $N(\ell)$",
    "cluster_size": "cluster size $s$",
    "x": "$x$ (units of $R$)",
    "y": "$y$ (units of $R$)",
    "z": "$z$ (units of $R$)",
    "profile": r"density $\rho(x)$",
    "k": r"wavenumber $k$ (units of $1/R$)",
    "structure": "structure factor $S(k)$",
}

#: Line colours that read on both backgrounds, in the order curves take them.
_PALETTES = {
    "dark": ("#4cc9f0", "#f4a261", "#90be6d", "#f15bb5", "#c77dff", "#ffd166", "#e5e5e5"),
    "light": ("#1f5fa8", "#d1495b", "#2e8540", "#8e44ad", "#e08e0b", "#00798c", "#444444"),
}


def palette(theme="dark") -> tuple[str, ...]:
    """Colours for successive curves in ``theme``."""
    return _PALETTES[get_theme(theme).name]


def species_colors(count: int, theme="dark") -> np.ndarray:
    """``(count, 3)`` RGB of ``count`` species: the palette's colours, in turn
    (qualitative, chosen to read on both themes).

    >>> species_colors(2, "light").round(3).tolist()
    [[0.122, 0.373, 0.659], [0.82, 0.286, 0.357]]
    """
    from matplotlib.colors import to_rgb

    colours = palette(theme)
    return np.array([to_rgb(colours[s % len(colours)]) for s in range(count)]).reshape(-1, 3)


def check_format(path: str | os.PathLike) -> str:
    """The format of ``path`` from its extension, refused unless it is one of :data:`FORMATS`."""
    ext = os.path.splitext(os.fspath(path))[1].lower().lstrip(".")
    if ext not in FORMATS:
        raise ParameterError(f"output: must end in .png, .svg or .pdf (got {os.fspath(path)!r})")
    return ext


def check_figure_args(parser, args) -> None:
    """Exit through ``parser.error`` (its one line, status 2) if ``args.out``,
    ``args.theme`` or ``args.size`` (an example script's options) would be refused when
    its figure is drawn and saved: checked before the script's runs, so nothing is lost."""
    try:
        check_format(args.out)
        get_theme(args.theme)
        resolve_size(args.size)
    except ParameterError as error:
        parser.error(str(error))


def resolve_size(size) -> tuple[float, float | None, float]:
    """``(width, height, font size)`` of a figure size: a name of :data:`SIZES`, a width
    in inches (height ``None``: the caller's choice) or ``(width, height)``.

    >>> resolve_size("slide"), resolve_size(5.2)[:2]
    ((8.0, 4.5, 13.0), (5.2, None))
    """
    if isinstance(size, str):
        if size not in SIZES:
            raise ParameterError(f"size: must be one of {', '.join(SIZES)} or a width in inches (got {size!r})")
        return (*SIZES[size], FONT_SIZES[size])
    if np.ndim(size) == 0:
        width, height = size, None
    elif np.shape(size) == (2,):
        width, height = size
    else:
        raise ParameterError(f"size: must be one of {', '.join(SIZES)} or a width in inches (got {size!r})")
    for value in (width, height):
        if value is not None and not (isinstance(value, (int, float, np.number)) and 0.5 <= value <= 100):
            raise ParameterError(f"size: must be in [0.5, 100] inches (got {size!r})")
    width = float(width)
    fontsize = float(np.interp(width, [3.4, 7.0, 8.0], [8.0, 9.0, 13.0]))
    return width, None if height is None else float(height), fontsize


def new_figure(width: float, height: float, theme="dark", fontsize: float = 10.0, dpi: float | None = None,
               pyplot: bool = False, layout: str | None = "constrained"):
    """An empty figure in the house style: on its own Agg canvas, or through pyplot (so a
    notebook shows it) when ``pyplot``; :func:`title` and friends read its theme."""
    t = get_theme(theme)
    if pyplot:
        import matplotlib.pyplot as plt

        fig = plt.figure(figsize=(width, height), dpi=dpi, layout=layout)
    else:
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.figure import Figure

        fig = Figure(figsize=(width, height), dpi=dpi, layout=layout)
        FigureCanvasAgg(fig)
    fig.set_facecolor(t.figure)
    fig._flocking_theme = t.name  # read by the helpers below
    fig._flocking_fontsize = fontsize
    return fig


def figure(size="column", theme="dark", nrows: int = 1, ncols: int = 1, **subplots):
    """A new ``(fig, axes)`` in the house style; ``size`` is a name of :data:`SIZES` or
    ``(width, height)`` in inches. Layout is constrained, so labels are never clipped."""
    t = get_theme(theme)
    width, height, fontsize = resolve_size(size)
    if height is None:
        raise ParameterError(f"size: must be one of {', '.join(SIZES)} or (width, height) (got {size!r})")
    fig = new_figure(width, height, t, fontsize)
    axes = fig.subplots(nrows, ncols, squeeze=True, **subplots)
    for ax in np.atleast_1d(axes).ravel():
        style_axes(ax, t)
    return fig, axes


def panels_across(width: float, fontsize: float) -> int:
    """How many panels fit side by side in ``width`` inches at ``fontsize`` points, each
    at least :data:`PANEL_EMS` font sizes wide (at least one).

    >>> panels_across(3.4, 8.0), panels_across(7.0, 9.0), panels_across(8.0, 13.0)
    (1, 3, 2)
    """
    return max(1, int(width // (PANEL_EMS * fontsize / 72)))


def panels(size="column", theme="dark", count: int = 1, **subplots):
    """A new ``(fig, axes)`` of ``count`` panels laid out for the width of ``size``
    (as :func:`figure`; ``axes`` a list): as many side by side as stay at least
    :data:`PANEL_EMS` font sizes wide each (:func:`panels_across`: three at page width, one
    in a column, two on a slide), the rest in further rows, each row as tall as the size is (0.7 of that when
    there are several rows) and any empty slot of the last row removed.

    >>> fig, axes = panels("column", "light", 3)
    >>> len(axes), fig.get_size_inches().round(2).tolist()
    (3, [3.4, 5.46])
    >>> [a.get_subplotspec().get_geometry()[:2] for a in panels("page", "light", 4)[1]][0]
    (2, 2)
    """
    t = get_theme(theme)
    width, height, size_pt = resolve_size(size)
    if height is None:
        raise ParameterError(f"size: must be one of {', '.join(SIZES)} or (width, height) (got {size!r})")
    if isinstance(count, bool) or not isinstance(count, (int, np.integer)) or count < 1:
        raise ParameterError(f"count: must be a whole number >= 1 (got {count!r})")
    across = min(count, panels_across(width, size_pt))
    rows = -(-count // across)
    across = -(-count // rows)  # as even as the rows allow: four panels as 2 x 2, not 3 + 1
    fig = new_figure(width, height if rows == 1 else 0.7 * height * rows, t, size_pt)
    grid = fig.subplots(rows, across, squeeze=False, **subplots).ravel()
    for ax in grid[count:]:
        ax.remove()
    axes = list(grid[:count])
    for ax in axes:
        style_axes(ax, t)
    return fig, axes


def fontsize(fig) -> float:
    """The base font size of a figure made by :func:`figure` (10 for any other)."""
    return getattr(fig, "_flocking_fontsize", 10.0)


def style_axes(ax, theme="dark") -> None:
    """Colours, ticks, grid and spines of one axes in ``theme``."""
    t = get_theme(theme)
    ax.set_facecolor(t.background if t.name == "dark" else t.figure)
    ax.tick_params(colors=t.text, which="both", labelsize=0.9 * fontsize(ax.figure))
    ax.xaxis.label.set_color(t.text)
    ax.yaxis.label.set_color(t.text)
    ax.title.set_color(t.text)
    ax.grid(color=t.edge, alpha=0.35, lw=0.5)
    for spine in ax.spines.values():
        spine.set_color(t.edge)


def label_axes(ax, x: str | None = None, y: str | None = None) -> None:
    """Axis labels, by key of :data:`LABELS` or as given."""
    size = fontsize(ax.figure)
    if x is not None:
        ax.set_xlabel(LABELS.get(x, x), fontsize=size)
    if y is not None:
        ax.set_ylabel(LABELS.get(y, y), fontsize=size)


def legend(ax, theme="dark", **options):
    """A frameless legend whose text follows the theme."""
    t = get_theme(theme)
    options.setdefault("fontsize", 0.85 * fontsize(ax.figure))
    options.setdefault("frameon", False)
    return ax.legend(labelcolor=t.text, **options)


def shade_window(ax, start: float, stop: float, theme="dark", label: str | None = None):
    """Shade the stretch ``[start, stop]`` of the x axis that a mean is taken over: a
    band in the theme's edge colour, plain to see on either background, outlined in it.
    Returns the band."""
    t = get_theme(theme)
    fill = (*t.edge, 0.35 if t.name == "dark" else 0.22)
    return ax.axvspan(start, stop, facecolor=fill, edgecolor=t.edge, lw=0.9, label=label, zorder=0)


def visible_length(text: str) -> int:
    """Characters ``text`` shows once mathtext is typeset (``$\\eta$`` is one).

    >>> visible_length(r"$\\eta$ = 1 \u00b7 $v_0$ = 0.5")
    16
    """
    import re

    def math(match):
        body = re.sub(r"\\[A-Za-z]+", "x", match.group(1))
        return re.sub(r"[{}_^]|\\.", "", body)

    return len(re.sub(r"\$(.*?)\$", math, text))


def wrap_text(text: str, fig, fontsize: float, weight: str = "normal") -> str:
    """``text`` broken at ``" \u00b7 "`` (or, within a part too long for a line, at spaces)
    into lines that fit the figure's width, measured as the text will be drawn."""
    from matplotlib.font_manager import FontProperties

    limit = 0.96 * fig.get_figwidth() * 72  # points
    get_renderer = getattr(fig.canvas, "get_renderer", None)
    if get_renderer is None:  # a canvas that cannot measure text: estimate
        def width(line):
            return 0.55 * fontsize * visible_length(line)
    else:
        renderer, prop = get_renderer(), FontProperties(size=fontsize, weight=weight)

        def width(line):
            w, _, _ = renderer.get_text_width_height_descent(line, prop, ismath=line.count("$") >= 2)
            return w * 72 / renderer.dpi

    def fill(parts, sep):
        lines, line = [], ""
        for part in parts:
            candidate = part if not line else f"{line}{sep}{part}"
            if not line or width(candidate) <= limit:
                line = candidate
            else:
                lines.append(line)
                line = part
        return lines + [line]

    lines = []
    for line in fill(text.split(" \u00b7 "), " \u00b7 "):
        lines.extend(fill(line.split(" "), " ") if width(line) > limit else [line])
    return "\n".join(lines)


def title(fig, main: str, details: str = "") -> None:
    """A bold ``main`` title on top and, if given, a caption of ``details`` (the
    parameters, joined by ``" · "``) along the bottom; both wrapped to the figure's width
    and placed by the constrained layout, so neither is ever clipped."""
    t = get_theme(getattr(fig, "_flocking_theme", "dark"))
    size = 1.1 * fontsize(fig)
    fig.suptitle(wrap_text(main, fig, size, "bold"), color=t.text, fontsize=size, fontweight="bold")
    if details:
        fig.supxlabel(wrap_text(details, fig, 0.8 * size), color=t.text, fontsize=0.8 * size, alpha=0.85)


def check_dpi(dpi) -> float | None:
    """``dpi`` as a float in [10, 1000] (``None``: the default, :data:`DPI`)."""
    if dpi is None:
        return None
    try:
        value = float(dpi)
    except (TypeError, ValueError):
        value = float("nan")
    if not 10 <= value <= 1000:  # NaN fails too
        raise ParameterError(f"dpi: must be in [10, 1000] (got {dpi!r})")
    return value


def save(fig, path: str | os.PathLike, dpi: float | None = None) -> str:
    """Write ``fig`` to ``path`` in the format its extension names, atomically (a file
    that was there stays whole until the new one replaces it); returns the path."""
    from ..files import replace_atomically

    fmt = check_format(path)
    path = os.fspath(path)
    dpi = check_dpi(dpi) or DPI
    with replace_atomically(path, "wb") as f:
        fig.savefig(f, format=fmt, dpi=dpi, facecolor=fig.get_facecolor())
    return path
