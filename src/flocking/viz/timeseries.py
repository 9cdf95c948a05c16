"""The polar order of a run against time, in the house style (``polar_order.png``).

The dashed line is the mean of the second half of the run and the band around it its
error: the error of the mean from the integrated autocorrelation time
(:class:`flocking.analysis.PolarOrder`), not the standard deviation of the values,
which does not shrink with the length of the run. The legend says which it is.

>>> rng = np.random.default_rng(0)
>>> phi = np.clip(0.9 + 0.02 * rng.standard_normal(400), 0, 1)
>>> fig = polar_order_figure(np.arange(400), phi, theme="light")
>>> print(fig.axes[0].get_legend().get_texts()[0].get_text())
second half: $\\langle\\varphi\\rangle$ = 0.8982 $\\pm$ 0.0014
(error of the mean; autocorrelation time $\\tau_\\mathrm{int}$ = 0.5 steps)
"""

from __future__ import annotations

import warnings

import numpy as np

from . import style as house
from .caption import describe


def with_error(value: float, error: float) -> str:
    """``value +- error`` (mathtext) with the error to two significant digits, at least
    three decimals.

    >>> with_error(0.92513, 0.00213), with_error(0.0031, 0.00004), with_error(0.5, 0.0)
    ('0.9251 $\\\\pm$ 0.0021', '0.003100 $\\\\pm$ 0.000040', '0.500 $\\\\pm$ 0.000')
    """
    decimals = 3
    if error > 0 and np.isfinite(error):
        decimals = max(3, 1 - int(np.floor(np.log10(error))))
    return fr"{value:.{decimals}f} $\pm$ {error:.{decimals}f}"


def second_half(steps, phi):
    """:class:`~flocking.analysis.PolarOrder` over the second half of the series, or
    ``None`` when it is too short (under 8 values)."""
    from ..analysis.order import PolarOrder

    if len(phi) < 8:
        return None
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # the legend reports the drift instead
        return PolarOrder(start=0.5).compute(np.asarray(phi, float))


def polar_order_figure(steps, phi, parameters=None, dim=2, n=0, box_lengths=(1, 1), theme="dark",
                       size="page"):
    """The polar order against the step, with the mean of the second half and its error."""
    t = house.get_theme(theme)
    fig, ax = house.figure(size, t)
    colors = house.palette(t)
    steps, phi = np.asarray(steps), np.asarray(phi, float)
    ax.plot(steps, phi, color=colors[0], lw=1.0, label=None)
    op = second_half(steps, phi)
    if op is not None:
        window = steps[op.window]
        spacing = float(np.median(np.diff(steps))) if len(steps) > 1 else 1.0
        tau = op.tau * spacing
        label = (fr"second half: $\langle\varphi\rangle$ = {with_error(op.mean, op.mean_error)}"
                 "\n" fr"(error of the mean; autocorrelation time $\tau_\mathrm{{int}}$ = {tau:.3g} steps)")
        if not op.equilibrated:
            label += f"\nnot equilibrated: halves differ by {abs(op.drift):.0f} errors"
        ax.fill_between([window[0], window[-1]], op.mean - op.mean_error, op.mean + op.mean_error,
                        color=colors[1], alpha=0.35, lw=0)
        ax.plot([window[0], window[-1]], [op.mean, op.mean], color=colors[1], lw=1.2, ls="--", label=label)
        house.legend(ax, t, loc="best")
    ax.set_ylim(0, 1.02)
    if len(steps) > 1:
        ax.set_xlim(steps[0], steps[-1])
    house.label_axes(ax, "step", "phi")
    main, details = describe(parameters, dim, n, box_lengths)
    house.title(fig, main, details)
    return fig
