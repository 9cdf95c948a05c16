"""Notebook displays: a frame as a PNG, a trajectory as a small H.264 video.

The video is an mp4 (H.264 through the ffmpeg that ``imageio-ffmpeg`` ships) inlined
in a ``<video>`` tag, so it needs no kernel once drawn and the notebook stays small:
60 frames of 2048 particles at the default size take 0.8 MB of HTML (the PNG frames of
an earlier player took 7 MB; ``tests/test_viz.py`` holds it under 1 MB).
``Trajectory._repr_html_`` and ``Frame._repr_png_`` call into this module, so ``traj``
or ``traj[-1]`` as the last line of a cell shows the flock.

>>> import flocking, numpy as np
>>> frame = flocking.Frame(0, 2, [4, 4], np.zeros((3, 3)), np.eye(3) * 0.5)
>>> frame_png(frame, size=2, dpi=40)[:4]
b'\\x89PNG'
"""

from __future__ import annotations

import base64
import io
import os
import tempfile

import numpy as np

from .movie import encode_mp4, fix_density_scale, open_run, select_frames, write_movie
from .scene import Scene

#: x264 quality of notebook videos: smaller files than movies (CRF 18), still sharp enough.
NOTEBOOK_CRF = 30


def _png(rgb: np.ndarray) -> bytes:
    from PIL import Image

    buffer = io.BytesIO()
    Image.fromarray(rgb).save(buffer, format="png")
    return buffer.getvalue()


def frame_png(frame, parameters=None, theme="dark", size=5.0, dpi=100, **options) -> bytes:
    """PNG bytes of one frame (a whole picture: title, key, time label)."""
    scene = Scene.for_frame(frame, parameters, theme=theme, size=size, dpi=dpi, **options)
    return _png(scene.draw(frame).rgb())


class HTMLAnimation:
    """An animation as HTML; a notebook shows it (``_repr_html_``), ``save`` writes a page."""

    def __init__(self, html_text: str):
        self.html = html_text

    def _repr_html_(self) -> str:
        return self.html

    def save(self, path: str) -> None:
        from ..files import write_text

        write_text(path, f"<!doctype html><meta charset='utf-8'><body style='background:#111'>{self.html}</body>")


def trajectory_mp4(trajectory, max_frames=60, fps=10.0, theme="dark", size=5.0, dpi=80,
                   start=None, stop=None, stride=None, crf=NOTEBOOK_CRF, **options) -> bytes:
    """H.264 bytes of up to ``max_frames`` evenly spaced frames (or every ``stride``-th)."""
    traj, owned = open_run(trajectory)
    try:
        if stride is None:
            span = len(select_frames(len(traj), start, stop, 1))
            stride = max(1, -(-span // max(int(max_frames), 1)))
        indices = select_frames(len(traj), start, stop, stride)
        first = traj[indices[0]]
        scene = Scene.for_frame(first, traj.parameters, theme=theme, size=size, dpi=dpi, **options)
        fix_density_scale(scene, traj, indices)
        frames = (scene.draw(first if k == 0 else traj[i]).rgb() for k, i in enumerate(indices))
        with tempfile.TemporaryDirectory() as folder:
            path = os.path.join(folder, "movie.mp4")
            encode_mp4(path, frames, scene.pixels, fps, crf)
            with open(path, "rb") as f:
                return f.read()
    finally:
        if owned:
            traj.close()


def trajectory_html(trajectory, **options) -> str:
    """A ``<video>`` tag that plays :func:`trajectory_mp4` (same options), inlined as base64."""
    data = base64.b64encode(trajectory_mp4(trajectory, **options)).decode("ascii")
    return ('<video controls loop autoplay muted playsinline style="max-width:100%" '
            f'src="data:video/mp4;base64,{data}"></video>')


def animate(trajectory, output=None, **options):
    """A movie of ``trajectory`` (a :class:`~flocking.Trajectory`, a GSD path or a run folder).

    With ``output`` (``.mp4`` or ``.gif``) the movie is written there and its path
    returned (options as :func:`~flocking.viz.write_movie`); without, an
    :class:`HTMLAnimation` that a notebook plays (options as :func:`trajectory_mp4`).
    """
    if output is not None:
        return write_movie(trajectory, output, **options)
    return HTMLAnimation(trajectory_html(trajectory, **options))
