"""The freud-style object layer shared by every analysis class.

A quantity takes its parameters in the constructor; ``compute(system)`` fills its
results and returns the object; results are read-only properties that raise
:class:`NotComputedError` until ``compute`` ran. ``to_dict()`` gives plain JSON types
(NaN becomes ``None``) and ``plot(ax=None, theme=None)`` draws on a matplotlib axes in the
house style (:mod:`flocking.viz.style`), imported lazily: on the axes given, touching
nothing else of its figure, or on a new ``column``-sized figure when none is given. The
colours follow ``theme`` (``"dark"`` or ``"light"``); by default that of a house-style
figure, else the one that reads on the axes' background. ``notes`` says why any result is
NaN or was not found, and how the walls and obstacles of the input were treated.
"""

from __future__ import annotations

import math
import numbers

import numpy as np

from ..model import ParameterError


class NotComputedError(RuntimeError, AttributeError):
    """A result was read before ``compute`` ran."""


def result(name: str, doc: str = "") -> property:
    """A read-only property that returns ``self._results[name]`` once ``compute`` ran."""

    def get(self):
        try:
            return self._results[name]
        except (AttributeError, KeyError):
            raise NotComputedError(
                f"{type(self).__name__}.{name}: not computed yet; call compute(...) first") from None

    return property(get, doc=doc)


class Analysis:
    """Base class: stores results as read-only values and converts them to JSON."""

    #: the results that :meth:`to_dict` reports, in order
    _keys: tuple[str, ...] = ()

    notes = result("notes", "Why a result is NaN or was not found, and how walls and obstacles were treated: a "
                            "tuple of sentences (empty when there is nothing to say).")

    def _store(self, notes=(), **values) -> None:
        stored = {"notes": tuple(notes)}
        for key, value in values.items():
            if isinstance(value, np.ndarray):
                value = value.copy()
                value.flags.writeable = False
            stored[key] = value
        self._results = stored

    @property
    def computed(self) -> bool:
        return hasattr(self, "_results")

    def parameters(self) -> dict:
        """The constructor's parameters."""
        return {}

    def to_dict(self) -> dict:
        """Parameters and results as plain JSON types (NaN and infinities become ``None``)."""
        out = {"quantity": type(self).__name__, "parameters": _plain(self.parameters())}
        out.update({key: _plain(getattr(self, key)) for key in self._keys})
        out["notes"] = list(self.notes)
        return out

    def _axes(self, ax, theme):
        """``(ax, theme name)``: the axes to draw on (a new house-style figure's when
        ``ax`` is ``None``) and the theme whose colours to draw with."""
        from ..viz import style
        from ..viz.colors import get_theme

        if theme is not None:
            theme = get_theme(theme).name
        if ax is None:
            _, ax = style.figure("column", theme=theme or "dark")
        return ax, theme or theme_of(ax)

    def __repr__(self) -> str:
        params = ", ".join(f"{k}={v!r}" for k, v in self.parameters().items())
        return f"{type(self).__name__}({params})"


def theme_of(ax) -> str:
    """The theme of a house-style figure, else ``"dark"`` on a dark background and
    ``"light"`` on a light one."""
    from matplotlib.colors import to_rgb

    name = getattr(ax.figure, "_flocking_theme", None)
    if name is not None:
        return name
    r, g, b = to_rgb(ax.get_facecolor())
    return "dark" if 0.2126 * r + 0.7152 * g + 0.0722 * b < 0.5 else "light"


def legend(ax, theme: str):
    """The house legend on a backing of the axes' own colour, so that curves under it
    never cross its text."""
    from ..viz import style

    return style.legend(ax, theme, loc="best", frameon=True, facecolor=ax.get_facecolor(), edgecolor="none",
                        framealpha=0.8)


def log_ticks(ax) -> None:
    """Tick labels of the log axes of ``ax`` as plain numbers (``20``, ``0.5``) between
    0.001 and 10^4, powers of ten beyond; minor ticks labelled only where matplotlib
    would (an axis spanning few decades)."""
    from matplotlib import ticker

    class Plain(ticker.LogFormatterSciNotation):
        def __call__(self, x, pos=None):
            label = super().__call__(x, pos)
            return f"{x:g}" if label and 1e-3 <= abs(x) < 1e4 else label

    for axis in (ax.xaxis, ax.yaxis):
        if axis.get_scale() == "log":
            axis.set_major_formatter(Plain())
            axis.set_minor_formatter(Plain(labelOnlyBase=False, minor_thresholds=(1, 0.4)))


def _plain(value):
    if isinstance(value, np.ndarray):
        return [_plain(v) for v in value.tolist()]
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, numbers.Integral):
        return int(value)
    if isinstance(value, numbers.Real):
        value = float(value)
        return value if math.isfinite(value) else None
    return value


def positive(name: str, value, *, integer: bool = False, allow_none: bool = False):
    """Check a strictly positive number (or ``None`` when allowed)."""
    if value is None and allow_none:
        return None
    kind = numbers.Integral if integer else numbers.Real
    if isinstance(value, bool) or not isinstance(value, kind) or not math.isfinite(value) or value <= 0:
        raise ParameterError(f"{name}: must be a positive {'integer' if integer else 'number'} (got {value!r})")
    return int(value) if integer else float(value)


def fit_line(x, y, sigma=None):
    """Least-squares line ``y = a x + b``: ``(slope, intercept, slope_error)``.

    The error is the formal one from ``sigma`` (when given), scaled up by
    ``sqrt(chi^2 / dof)`` when the scatter exceeds it; without ``sigma`` it comes from
    the residuals alone, so a perfect fit has error 0, and a line through two points
    (no degree of freedom) has none: NaN.

    >>> fit_line([0, 1, 2], [1, 3, 5])
    (2.0, 1.0, 0.0)
    >>> fit_line([0, 1], [1, 3])
    (2.0, 1.0, nan)
    """
    x, y = np.asarray(x, float), np.asarray(y, float)
    if len(x) < 2:
        return float("nan"), float("nan"), float("nan")
    w = np.ones_like(x) if sigma is None else 1.0 / np.maximum(np.asarray(sigma, float), 1e-300) ** 2
    sw, sx, sy = w.sum(), (w * x).sum(), (w * y).sum()
    delta = sw * (w * x * x).sum() - sx * sx
    slope = (sw * (w * x * y).sum() - sx * sy) / delta
    intercept = (sy - slope * sx) / sw
    dof = len(x) - 2
    chi2 = float((w * (y - slope * x - intercept) ** 2).sum())
    if dof == 0 and sigma is None:
        return float(slope), float(intercept), float("nan")
    scale = chi2 / dof if dof > 0 else 0.0
    if sigma is not None:
        scale = max(scale, 1.0)
    error = math.sqrt(max(sw / delta * scale, 0.0))
    return float(slope), float(intercept), float(round(error, 15))


def format_value(value, error=float("nan"), pm: str = r" \pm ") -> str:
    """``value pm error`` with the value rounded to the error's second significant digit
    (the value alone, to 4 digits or as a whole number from 10^4 on, without a finite
    positive error); mathtext's ``\\pm`` by default, for text ``pm=" ± "``.

    >>> format_value(2.64417, 0.01234), format_value(2.64417), format_value(0.5, 0.0), format_value(17160.4)
    ('2.644 \\\\pm 0.012', '2.644', '0.5', '17160')
    """
    if not math.isfinite(value):
        return "n/a"
    if not math.isfinite(error) or error <= 0:
        return f"{value:.0f}" if 1e4 <= abs(value) < 1e9 else f"{value:.4g}"
    decimals = max(0, 1 - math.floor(math.log10(error)))
    return f"{value:.{decimals}f}{pm}{error:.{decimals}f}"


def walls_text(space) -> str:
    """The axes of ``space`` closed by walls, in words (``""`` when none).

    >>> from flocking.space import Space
    >>> walls_text(Space((4.0, 4.0, 4.0), walls=(True, False, True))), walls_text(Space((4.0, 4.0)))
    ('walls on x and z', '')
    """
    axes = [a for a, wall in zip("xyz", space.walls) if wall]
    return f"walls on {' and '.join(axes)}" if axes else ""


def pair_notes(space, what: str) -> list[str]:
    """What a quantity of pairs does at the walls and obstacles of ``space``: ``what``
    (``"no link"``, ``"no pair"``) across walls; pairs across obstacles count.

    >>> from flocking.space import Space
    >>> for note in pair_notes(Space((8.0, 8.0), walls=(False, True), obstacles=[(4.0, 4.0, 1.0)]), "no link"):
    ...     print(note)
    walls on y: no link across them (the minimum image along periodic axes only)
    1 obstacle: pairs across it count, as in the engine, whose neighbours see across obstacles
    """
    notes = []
    if any(space.walls):
        notes.append(f"{walls_text(space)}: {what} across them (the minimum image along periodic axes only)")
    if space.obstacles:
        many = len(space.obstacles) > 1
        notes.append(f"{len(space.obstacles)} obstacle{'s' * many}: pairs across {'them' if many else 'it'} count, "
                     "as in the engine, whose neighbours see across obstacles")
    return notes
