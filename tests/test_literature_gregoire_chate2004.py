"""examples/gregoire_chate2004.py, scaled down to its smaller size, N = 512 (box 16): the
discontinuous onset of the Vicsek model with vectorial noise (Gregoire and Chate 2004),
in about three minutes of a busy core.

What the full script printed at this size (docs/literature.md): 80000 steps at eta = 0.615
switch 140 times between the disordered state (a histogram peak at phi = 0.19) and the
ordered one (0.75); the Binder cumulant, 2/3 deep in the ordered phase, falls to
0.076 +- 0.059 at eta = 0.6175, below its value 0.308 +- 0.014 at eta = 0.63, which is
near the 1/3 of a disordered two-component order (runs of 40000 steps; the test runs the
same curve with 20000). The tolerances are the errors the analysis gives (autocorrelation
time for means, block jackknife for G): three of them.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scripts import load_script


@pytest.mark.slow
def test_a_run_at_the_threshold_switches_between_two_states():
    gc = load_script("examples/gregoire_chate2004.py")
    run = gc.switching(16.0, 0.615, steps=40_000, equilibrate=2_000, seed=2004, bins=50)
    assert run["n"] == 512 and run["counts"].sum() == 38_000
    # the cut between the two states lies between their peaks (0.19 and 0.75 in the full run)
    assert 0.3 < run["cut"] < 0.6 and 0.05 < run["ordered_share"] < 0.95
    # switches: the full run counted 140 in 76000 steps, so about 70 are expected here; a count
    # of that size (Poisson) falls below 70 - 3 sqrt(70) = 45 rarely
    assert run["switches"] >= 45
    # two peaks: the cut is the valley between two maxima of the histogram (a single peak gives
    # 0.4, which no bin centre equals); the ordered peak is sharp (more than twice the density
    # at the cut), the disordered one broad (N = 512: phi of order N^-1/2 and clusters) but above it
    assert run["cut"] != 0.4
    centres = 0.5 * (run["edges"][1:] + run["edges"][:-1])
    at_cut = run["density"][np.argmin(abs(centres - run["cut"]))]
    assert run["density"][centres > run["cut"]].max() > 2 * at_cut
    assert run["density"][centres < run["cut"]].max() > at_cut


@pytest.mark.slow
def test_the_binder_cumulant_dips_at_the_threshold():
    gc = load_script("examples/gregoire_chate2004.py")
    res = gc.binder_curve(16.0, gc.NOISES, steps=20_000, equilibrate=4_000, seed=2004)  # the script's L = 16
    g, err = np.array(res["binder"]), np.array(res["binder_error"])
    assert res["noise"][0] == 0.605 and res["noise"][-1] == 0.63
    assert abs(g[0] - 2 / 3) < 3 * err[0] + 0.01  # ordered: phi barely fluctuates
    assert abs(g[-1] - 1 / 3) < 3 * err[-1] + 0.05  # disordered: near the Gaussian value of 2 components
    # the dip: the lowest G below the disordered value by more than three combined errors
    k = int(np.argmin(g))
    assert 0 < k < len(g) - 1
    assert g[k] < g[-1] - 3 * math.hypot(err[k], err[-1])
    assert res["order"][0] > 0.7 and res["order"][-1] < 0.15
