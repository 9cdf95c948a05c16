"""The scale of 3D views: three edges of the box, each ticked in box coordinates, placed
where the camera sees them on the box's outline; and the camera's zoom that leaves their
labels room.
"""

from __future__ import annotations

import numpy as np

from . import style as house
from .perspective import Camera


def make_rulers(ax, box, theme) -> list:
    """Per axis: its tick marks (one line), tick labels and name, placed by
    :func:`place_rulers`."""
    t, fs = theme, house.fontsize(ax.figure)
    rulers = []
    for axis, name in enumerate("xyz"):
        ticks = nice_ticks(box[axis])[1:]  # no 0: two rulers start at most corners
        (marks,) = ax.plot([], [], color=t.text, lw=0.8, zorder=6, solid_capstyle="butt")
        labels = [ax.text(0, 0, f"{v:g}", color=t.text, fontsize=0.75 * fs, ha="center", va="center",
                          zorder=6) for v in ticks]
        title = ax.text(0, 0, house.LABELS[name], color=t.text, fontsize=0.8 * fs, ha="center",
                        va="center", zorder=6, rotation_mode="anchor")
        rulers.append((axis, ticks, marks, labels, title))
    return rulers


def place_rulers(rulers, ax, box, pixels, azim, elev, zoom) -> None:
    """Put each axis' ruler on the edge along it that the camera sees on the box's
    outline: x and y on the bottom face's edges nearest the camera (the top face's
    seen from below), z on the vertical edge furthest left; labels offset outward
    from the box's centre on screen, each name along its edge. ``pixels``, ``azim``,
    ``elev`` and ``zoom`` are the camera's of the view (:class:`.perspective.Camera`)."""
    cam = Camera(box, pixels, azim, elev, zoom)
    half = box / 2
    toward = -cam.forward  # from the box's centre toward the camera
    (u0,), (v0,), _ = cam.project(np.zeros((1, 3)))
    point = pixels / max(ax.get_window_extent().width, 1) * ax.figure.dpi / 72  # pixels in a point
    fs = house.fontsize(ax.figure)
    tick, gap = 0.35 * fs * point, 0.9 * fs * point
    for axis, ticks, marks, labels, title in rulers:
        corner = np.zeros(3)
        if axis < 2:
            other = 1 - axis
            corner[other] = np.copysign(half[other], toward[other])
            corner[2] = -np.copysign(half[2], toward[2])
        else:
            corner = min((np.array([sx * half[0], sy * half[1], 0.0]) for sx in (-1, 1) for sy in (-1, 1)),
                         key=lambda c: cam.project(c[None])[0][0])
        along = np.eye(3)[axis]
        start = corner - (corner[axis] + half[axis]) * along  # the end at coordinate 0
        u, v, _ = cam.project(start + np.outer([0.0, *ticks, half[axis]], along))
        u, v = u - 0.5, v - 0.5  # pixel centres are at +0.5; imshow puts pixel k at k
        (mu, mv), ends = (u[-1], v[-1]), (u[:-1], v[:-1])
        out = np.array([mu - (u0 - 0.5), mv - (v0 - 0.5)])
        out /= max(np.linalg.norm(out), 1e-9)
        xs, ys = [], []
        for k in range(len(ticks)):
            x, y = ends[0][k + 1], ends[1][k + 1]
            xs += [x, x + tick * out[0], np.nan]
            ys += [y, y + tick * out[1], np.nan]
            labels[k].set_position((x + (tick + gap) * out[0], y + (tick + gap) * out[1]))
        marks.set_data(xs, ys)
        angle = np.degrees(np.arctan2(-(ends[1][-1] - ends[1][0]), ends[0][-1] - ends[0][0]))
        angle = (angle + 90.0) % 180.0 - 90.0  # upright
        title.set_rotation(angle)
        title.set_position((mu + (tick + 2.5 * gap) * out[0], mv + (tick + 2.5 * gap) * out[1]))


def ruler_zoom(points: float, fontsize: float) -> float:
    """The camera's zoom of a 3D view ``points`` wide (1/72 inch) whose rulers' labels,
    in ``fontsize``, reach about 3.2 font sizes beyond the box's outline: the box (about
    0.94 of the view across at zoom 1, from most directions) shrinks to leave them room.

    >>> round(ruler_zoom(300.0, 8.7), 2), round(ruler_zoom(160.0, 8.0), 2)
    (0.87, 0.72)
    """
    return float(np.clip((0.5 - 3.2 * fontsize / points) / 0.47, 0.5, 0.95))


def nice_ticks(length: float) -> list[float]:
    """Ticks for an axis from 0 to ``length``: both ends and, between them, multiples
    of a round step (1, 2 or 5 times a power of ten) that leave room beside the ends.

    >>> nice_ticks(32.0), nice_ticks(100.0), nice_ticks(4.0)
    ([0.0, 10.0, 20.0, 32.0], [0.0, 50.0, 100.0], [0.0, 1.0, 2.0, 3.0, 4.0])
    """
    raw = length / 4
    power = 10.0 ** np.floor(np.log10(raw))
    step = min(m * power for m in (1, 2, 5, 10) if m * power >= raw * 0.999)
    inside = [float(k * step) for k in range(1, int(length // step) + 1) if 0.2 * length <= k * step <= 0.8 * length]
    return [0.0, *inside, float(length)]
