"""Notebook displays: a frame as a PNG, a trajectory as a self-contained HTML/JS player.

The player holds its frames as base64 PNGs and needs neither ffmpeg nor a kernel once
drawn: a play button, a slider and the frame's step. ``Trajectory._repr_html_`` and
``Frame._repr_png_`` call into this module, so ``traj`` or ``traj[-1]`` as the last line
of a cell shows the flock.

>>> import flocking, numpy as np
>>> frame = flocking.Frame(0, 2, [4, 4], np.zeros((3, 3)), np.eye(3) * 0.5)
>>> frame_png(frame, size=2, dpi=40)[:4]
b'\\x89PNG'
"""

from __future__ import annotations

import base64
import html
import io
import uuid

import numpy as np

from .movie import _open, select_frames, write_movie
from .render import Scene


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
        with open(path, "w", encoding="utf-8") as f:
            f.write(f"<!doctype html><meta charset='utf-8'><body style='background:#111'>{self.html}</body>")


_PLAYER = """<div id="{id}" style="display:inline-block;font-family:sans-serif;font-size:13px">
<img style="display:block;max-width:100%" src="data:image/png;base64,{first}">
<div style="margin-top:4px;display:flex;align-items:center;gap:8px">
<button type="button" style="width:4.5em">&#9654; play</button>
<input type="range" min="0" max="{last}" value="0" style="flex:1">
<span style="min-width:8em;font-family:monospace">step {step0}</span></div></div>
<script>(function(){{
const root=document.getElementById("{id}"), frames={frames}, steps={steps}, fps={fps};
const img=root.querySelector("img"), btn=root.querySelector("button"),
      bar=root.querySelector("input"), label=root.querySelector("span");
let i=0, timer=null;
function show(k){{i=k; img.src="data:image/png;base64,"+frames[k]; bar.value=k; label.textContent="step "+steps[k];}}
function stop(){{clearInterval(timer); timer=null; btn.innerHTML="&#9654; play";}}
btn.onclick=function(){{ if(timer){{stop(); return;}}
  btn.innerHTML="&#10073;&#10073; pause";
  timer=setInterval(function(){{show((i+1)%frames.length);}}, 1000/fps);}};
bar.oninput=function(){{stop(); show(parseInt(bar.value));}};
}})();</script>"""


def trajectory_html(trajectory, max_frames=60, fps=10.0, theme="dark", size=5.0, dpi=90,
                    start=None, stop=None, stride=None, **options) -> str:
    """HTML (with a small JS player) of up to ``max_frames`` evenly spaced frames."""
    traj, owned = _open(trajectory)
    try:
        if stride is None:
            span = len(select_frames(len(traj), start, stop, 1))
            stride = max(1, -(-span // int(max_frames)))
        indices = select_frames(len(traj), start, stop, stride)
        first = traj[indices[0]]
        scene = Scene.for_frame(first, traj.parameters, theme=theme, size=size, dpi=dpi, **options)
        frames, steps = [], []
        for k, i in enumerate(indices):
            frame = first if k == 0 else traj[i]
            frames.append(base64.b64encode(_png(scene.draw(frame).rgb())).decode("ascii"))
            steps.append(frame.step)
    finally:
        if owned:
            traj.close()
    return _PLAYER.format(id="flock-" + uuid.uuid4().hex[:12], first=frames[0], last=len(frames) - 1,
                          step0=html.escape(str(steps[0])), frames="[" + ",".join(f'"{f}"' for f in frames) + "]",
                          steps=steps, fps=float(fps))


def animate(trajectory, output=None, **options):
    """A movie of ``trajectory`` (a :class:`~flocking.Trajectory`, a GSD path or a run folder).

    With ``output`` (``.mp4`` or ``.gif``) the movie is written there and its path
    returned (options as :func:`~flocking.viz.write_movie`); without, an
    :class:`HTMLAnimation` that a notebook plays (options as :func:`trajectory_html`).
    """
    if output is not None:
        return write_movie(trajectory, output, **options)
    return HTMLAnimation(trajectory_html(trajectory, **options))
