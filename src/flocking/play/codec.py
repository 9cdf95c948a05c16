"""The binary frame a :class:`~.session.Session` streams to the page, and its inverse.

Frames (:func:`encode_frame`) are little-endian: a 36-byte header (``b"FLK1"``, dim,
flags, 2 spare bytes, N as uint32, the step as float64, the polar order and the three box
lengths as float32), then the positions quantised to uint16 (``q = floor(x / L * 65536)``,
N x dim, particle order), then the headings: one uint8 angle per particle in 2D, an
azimuth and a ``z`` byte per particle in 3D. ``static/frame.js`` reads them in the page.
"""

from __future__ import annotations

import math
import struct
from typing import Any

import numpy as np

from ..model import Model
from ..state import State

HEADER = struct.Struct("<4sBBHIdf3f")
MAGIC = b"FLK1"
RUNNING = 1  # flag bit


def encode_frame(state: State, model: Model, phi: float, running: bool = True) -> bytes:
    """The binary frame of ``state`` (see the module docstring for the layout)."""
    n, dim = state.positions.shape
    box = np.asarray(model.box, dtype=np.float64)
    q = np.floor(state.positions * (65536.0 / box))
    positions = np.clip(q, 0, 65535).astype("<u2")
    h = state.headings
    azimuth = np.arctan2(h[:, 1], h[:, 0]) * (256.0 / (2.0 * math.pi))
    azimuth = np.round(azimuth).astype(np.int64) % 256
    if dim == 2:
        headings = azimuth.astype(np.uint8)
    else:
        z = np.round((np.clip(h[:, 2], -1.0, 1.0) + 1.0) * 127.5).astype(np.uint8)
        headings = np.stack([azimuth.astype(np.uint8), z], axis=1)
    lengths = (*model.box, 0.0) if dim == 2 else model.box
    header = HEADER.pack(MAGIC, dim, RUNNING if running else 0, 0, n, float(state.step), phi, *lengths)
    return header + positions.tobytes() + headings.tobytes()


def decode_frame(data: bytes) -> dict[str, Any]:
    """The inverse of :func:`encode_frame`, to quantisation (for tests and tools).

    Positions come back at the centres of their bins (error at most ``L / 131072``),
    headings as unit vectors.
    """
    magic, dim, flags, _, n, step, phi, *box = HEADER.unpack_from(data)
    if magic != MAGIC:
        raise ValueError("not a flocking play frame")
    box = np.array(box[:dim])
    offset = HEADER.size
    q = np.frombuffer(data, "<u2", n * dim, offset).reshape(n, dim)
    offset += 2 * n * dim
    raw = np.frombuffer(data, np.uint8, n * (dim - 1), offset).reshape(n, dim - 1)
    angle = raw[:, 0] * (2.0 * math.pi / 256.0)
    if dim == 2:
        headings = np.stack([np.cos(angle), np.sin(angle)], axis=1)
    else:
        z = raw[:, 1] / 127.5 - 1.0
        rho = np.sqrt(np.maximum(0.0, 1.0 - z * z))
        headings = np.stack([rho * np.cos(angle), rho * np.sin(angle), z], axis=1)
    return {"dim": dim, "n": n, "step": int(step), "phi": phi, "running": bool(flags & RUNNING),
            "box": box, "positions": (q + 0.5) * (box / 65536.0), "headings": headings}
