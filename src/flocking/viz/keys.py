"""The keys beside the box: what the colours mean (the heading wheel, the deviation disc,
the species' names), with an empty text under each for the readout of the step
(:func:`.caption.time_text`).
"""

from __future__ import annotations

import numpy as np

from .colors import DEVIATION_FULL, get_theme, wheel_image
from .style import species_colors

#: Points per data unit of a key's axes at the narrowest (a key at least 9 font sizes
#: wide, less the layout's padding, spans 4 units), in font sizes: text placed by it
#: never runs out of the axes.
_UNIT = 1.6


def _below(ax, theme, fs: float, label: str, top: float, readout: int):
    """The key's caption ``label`` from ``y = top`` down (data units, centred at 0), an
    empty text of ``readout`` lines for :func:`time_text` under it (``None`` if 0), and
    the axes' limits around both."""
    t = get_theme(theme)
    small = 0.75 * fs
    caption = ax.text(0.0, top, label, ha="center", va="top", color=t.text, fontsize=small, linespacing=1.2)
    y = top - (label.count("\n") + 1) * 1.2 * 0.75 / _UNIT - 0.3
    text = None
    if readout:
        text = ax.text(0.0, y, "", ha="center", va="top", color=t.text, fontsize=0.85 * fs, family="monospace",
                       linespacing=1.3)
        y -= readout * 1.3 * 0.85 / _UNIT
    ax.set_xlim(-2.0, 2.0)
    ax.set_ylim(min(y - 0.05, -2.3), 1.65)
    return caption, text


def heading_key(ax, dim: int, theme, fs: float, ink: bool = False, readout: int = 2):
    """The colour wheel of headings on ``ax`` (its axes turned off): a ring in 2D, a disc
    grey toward +-z in 3D, in the colours of particles or (``ink``) of density maps.
    Returns ``(label, readout)``: the key's caption and an empty text of ``readout`` lines
    under it for :func:`time_text` (``None`` if 0). Every label lies inside the axes'
    limits, so a layout never shrinks the wheel to make room."""
    t = get_theme(theme)
    ax.imshow(wheel_image(192, dim, t, ink), interpolation="antialiased", extent=(-1, 1, -1, 1))
    ax.set_axis_off()
    small = 0.75 * fs
    for angle, text, ha in ((0, "0\u00b0", "left"), (90, "90\u00b0", "center"), (180, "180\u00b0", "right"),
                            (270, "270\u00b0", "center")):
        a = np.radians(angle)
        ax.text(1.1 * np.cos(a), 1.1 * np.sin(a), text, ha=ha, va="center" if angle in (0, 180)
                else ("bottom" if angle == 90 else "top"), color=t.text, fontsize=small)
    label = "heading" if dim == 2 else "heading\n(grey: $\\pm z$)"
    if ink:
        label = "heading\n(grey: no order)"
    return _below(ax, t, fs, label, -1.62, readout)


def deviation_key(ax, dim: int, theme, fs: float, readout: int = 2):
    """The key of :func:`.colors.deviation_colors`: the disc of 3D headings, grey at its
    centre (along the mean heading) and full at its rim (:data:`.colors.DEVIATION_FULL`
    or more), its top the turn toward +z (2D: to the left); laid out as
    :func:`heading_key`, and returns ``(label, readout)`` as it does."""
    t = get_theme(theme)
    ax.imshow(wheel_image(192, 3, t), interpolation="antialiased", extent=(-1, 1, -1, 1))
    ax.set_axis_off()
    ax.text(0.0, 1.1, "+z" if dim == 3 else "left", ha="center", va="bottom", color=t.text, fontsize=0.75 * fs)
    full = f"{np.degrees(DEVIATION_FULL):.0f}\u00b0"
    return _below(ax, t, fs, f"heading relative\nto the flock's mean\n(grey: along it;\nrim: {full} or more)",
                  -1.2, readout)


def species_key(ax, types, theme, fs: float, readout: int = 2):
    """The species' names beside squares of their colours, top down, on ``ax`` (spaced
    in points, so the rows read alike at every size); returns ``(None, readout)``, the
    readout (``readout`` lines, none if 0) under the last name."""
    t = get_theme(theme)
    ax.set_axis_off()
    small = 0.75 * fs
    line = 1.6 * small
    anchor = dict(xy=(0.12, 0.98), xycoords="axes fraction", textcoords="offset points", va="top",
                  fontsize=small, annotation_clip=False)
    ax.annotate("species", xytext=(0, 0), color=t.text, **anchor)
    for s, (name, rgb) in enumerate(zip(types, species_colors(len(types), t))):
        y = -line * (s + 1.2)
        ax.annotate("\u25a0", xytext=(0, y), color=tuple(rgb), **anchor)
        ax.annotate(name, xytext=(1.4 * small, y), color=t.text, **anchor)
    if not readout:
        return None, None
    return None, ax.annotate("", xytext=(0, -line * (len(types) + 2.0)), color=t.text, linespacing=1.3,
                             family="monospace", **{**anchor, "fontsize": 0.85 * fs})
