"""Statistics of the polar order over a window: the quantities of MODEL.md (Observables).

>>> import numpy as np
>>> m = polar_moments(np.array([0.5, 0.5, 0.5]), n=100)
>>> m["mean"], m["susceptibility"], round(m["binder"], 6)
(0.5, 0.0, 0.666667)
"""

from __future__ import annotations

import numpy as np


def polar_moments(phi, n: int) -> dict[str, float]:
    """``<phi>``, ``<phi^2>``, ``<phi^4>``, ``chi = N (<phi^2> - <phi>^2)`` and
    ``G = 1 - <phi^4> / (3 <phi^2>^2)`` of a time series ``phi`` of ``n`` particles."""
    phi = np.asarray(phi, dtype=np.float64)
    if phi.size == 0:
        raise ValueError("polar_moments: the window holds no value")
    mean, m2, m4 = phi.mean(), np.mean(phi**2), np.mean(phi**4)
    binder = 1.0 - m4 / (3.0 * m2 * m2) if m2 > 0 else float("nan")
    return {"mean": float(mean), "phi2": float(m2), "phi4": float(m4),
            "susceptibility": float(n * (m2 - mean * mean)), "binder": float(binder)}
