"""Vicsek et al. 1995 (examples/vicsek1995.py), scaled down: the computation of the
script on small systems and short runs, its physics asserted with tolerances from the
measured errors, and the aligned start the script gives its largest N. The slow tests take
89 s of wall clock (81 CPU-seconds) on the project's 2 cores beside another one-thread job,
21 s with NUMBA_NUM_THREADS=1 (these small systems run faster on one thread)."""

from __future__ import annotations

import re

import numpy as np
import pytest
from scripts import load_script

vicsek = load_script("examples/vicsek1995.py")

REPLICAS, STEPS, DISCARD = 4, 3000, 1000
NOISES = (1.0, 1.5, 2.0, 2.5, 3.0, 3.5, 4.0, 4.5, 2 * np.pi)


@pytest.fixture(scope="module")
def fig2a():
    """Per system time means (v_a, v_a^2) at density 4 for N = 40 and 400."""
    return {n: vicsek.order(n, 4.0, NOISES, REPLICAS, STEPS, DISCARD, seed=7) for n in (40, 400)}


@pytest.mark.slow
def test_the_fully_random_limit_is_the_mean_length_of_random_unit_vectors(fig2a):
    # eta = 2 pi draws every heading anew, uniform on the circle, every step: v_a is then
    # |mean of N independent unit vectors|, whose mean is sqrt(pi / (4 N)) (1 - 1/(16 N) + ...)
    # (a two-dimensional random walk of N unit steps). Tolerance: 4 standard errors over the
    # systems plus the 1/(16 N) correction left out.
    for n, (m1, _) in fig2a.items():
        mean, error = vicsek.mean_error(m1[-1])
        expected = np.sqrt(np.pi / (4 * n))
        assert abs(mean - expected) < 4 * error + expected / (16 * n), (n, mean, error, expected)


@pytest.mark.slow
def test_order_falls_with_noise_and_more_steeply_for_more_particles(fig2a):
    # Fig. 2a: every curve falls from near 1 (eta = 1: 0.95 in the script's runs) and the
    # larger system lies below at high noise. Differences are asserted at 5 combined standard
    # errors, far from the measured gaps (0.95 against 0.1 to 0.4).
    for n, (m1, _) in fig2a.items():
        mean, error = vicsek.mean_error(m1)
        assert mean[0] > 0.9
        assert np.all(mean[:-1] > mean[1:] - 3 * np.hypot(error[:-1], error[1:])), (n, mean)
    (small, ds), (large, dl) = (vicsek.mean_error(fig2a[n][0]) for n in (40, 400))
    high = NOISES.index(4.5)
    assert small[high] - large[high] > 5 * np.hypot(ds[high], dl[high])
    # the susceptibility of the larger system peaks inside the range, not at its ends
    chi = vicsek.susceptibility(400, *fig2a[400])
    assert 0 < int(np.argmax(chi[:-1])) < len(NOISES) - 2, chi


@pytest.mark.slow
def test_the_aligned_start_settles_to_the_order_of_the_random_start(fig2a):
    # The script starts its largest N with every heading equal; that must not change the
    # steady state. At N = 400 the two starts' v_a (4 systems each, 3000 steps, the first
    # 1000 left out) agree within 4 combined standard errors at every noise but 2 pi
    # (there v_a is the random floor, start or not).
    aligned, _ = vicsek.order(400, 4.0, NOISES[:-1], REPLICAS, STEPS, DISCARD, seed=7, start="aligned")
    (ma, ea), (mr, er) = vicsek.mean_error(aligned), vicsek.mean_error(fig2a[400][0][:-1])
    assert np.all(np.abs(ma - mr) < 4 * np.hypot(ea, er)), (ma, mr, ea, er)


@pytest.mark.slow
def test_beta_agrees_with_the_paper_within_the_errors(fig2a):
    # The script's fit on N = 400 below the susceptibility's peak, its 68 % interval from a
    # bootstrap over the systems; the paper's beta = 0.45 +- 0.07. Agreement within three
    # combined standard deviations (ours: half the interval's width).
    m1, m2 = fig2a[400]
    chi = vicsek.susceptibility(400, m1, m2)
    peak = NOISES[int(np.argmax(chi[:-1]))]
    keep = [i for i, eta in enumerate(NOISES) if 1.0 <= eta < peak]
    noises, per = np.asarray(NOISES)[keep], m1[keep]
    beta, eta_c, _ = vicsek.fit_beta(noises, *vicsek.mean_error(per))
    lo, hi = vicsek.interval(vicsek.bootstrap(vicsek.fit_beta, noises, per, 100, seed=1))
    paper, paper_error = vicsek.PAPER["beta"]
    assert eta_c > noises.max()
    assert abs(beta - paper) < 3 * np.hypot((hi - lo) / 2, paper_error), (beta, lo, hi)


@pytest.mark.slow
def test_order_grows_with_density_at_fixed_noise():
    # Fig. 2b at L = 20, eta = 2: rho = 0.1 (N = 40) against rho = 2 (N = 800); the script's
    # runs give 0.28 +- 0.01 and 0.64 +- 0.03. Asserted at 5 combined standard errors.
    low = vicsek.mean_error(vicsek.order(40, 0.1, [2.0], REPLICAS, STEPS, DISCARD, seed=3)[0][0])
    high = vicsek.mean_error(vicsek.order(800, 2.0, [2.0], REPLICAS, STEPS, DISCARD, seed=3)[0][0])
    assert high[0] - low[0] > 5 * np.hypot(low[1], high[1]), (low, high)


def test_the_fits_recover_exact_power_laws():
    # Quick and exact: noiseless power laws give back their exponents and eta_c.
    eta = np.linspace(1.0, 3.0, 9)
    values = 0.9 * ((3.4 - eta) / 3.4) ** 0.45
    beta, eta_c, lna = vicsek.fit_beta(eta, values, 0.01 * values)
    assert beta == pytest.approx(0.45, abs=1e-5) and eta_c == pytest.approx(3.4, abs=1e-4)
    assert lna == pytest.approx(np.log(0.9), abs=1e-5)
    rho = np.array([0.1, 0.2, 0.5, 1.0])
    delta, lnb = vicsek.fit_delta(rho, 0.4 * rho**0.35, np.full(4, 0.01))
    assert delta == pytest.approx(0.35, abs=1e-9) and lnb == pytest.approx(np.log(0.4), abs=1e-9)


@pytest.mark.parametrize("argv, message", [
    (["--beta-sizes", "4000,500"], r"--beta-sizes: each must be one of --sizes"),
    (["--beta-sizes", "4000,"], r"--beta-sizes: comma-separated numbers, each >= 1"),
    (["--noises", "0,1,2", "--beta-from", "1.5"], r"--beta-from: at least 3 of --noises must be >= it"),
    (["--beta-noises", "1.5,-2"], r"--beta-noises: comma-separated numbers, each >= 0"),
    (["--delta-max", "0.1"], r"--delta-max: at least 2 of --densities must be <= it"),
    (["--sizes", "40,4k"], r"--sizes: comma-separated numbers, each >= 1 \(got '40,4k'\)$"),
    (["--noises=-1,1,2,3"], r"--noises: comma-separated numbers, each >= 0"),
    (["--densities", "0,1"], r"--densities: comma-separated numbers, each > 0"),
    (["--replicas", "1"], r"--replicas: must be >= 2 \(got 1\)$"),
    (["--discard", "8000"], r"--discard: must be below --steps 8000 \(got 8000\)$"),
    (["--bootstrap", "0"], r"--bootstrap: must be >= 1"),
    (["--threads", "0"], r"--threads: must be >= 1"),
    (["--out", "v.jpg"], r"output: must end in .png, .svg or .pdf"),
    (["--theme", "pink"], r"theme: must be one of dark, light"),
    (["--size", "poster"], r"size: must be one of column, page, slide"),
])
def test_bad_arguments_are_refused_in_one_line_before_any_run(argv, message, capsys):
    with pytest.raises(SystemExit) as exit_:
        vicsek.parse(argv)
    assert exit_.value.code == 2
    assert re.search(message, capsys.readouterr().err.splitlines()[-1])


def test_a_beta_window_left_empty_by_the_peak_still_draws_the_figure(tmp_path, capsys):
    # Three noises: at most two lie below the susceptibility's peak, too few for the
    # three-parameter fit of beta. The run says so and draws the other panels.
    out = tmp_path / "v.png"
    res = vicsek.main(["--sizes", "40", "--beta-sizes", "40", "--noises", "0,2,4", "--beta-noises", "", "--beta-from", "0",
                       "--densities", "0.5,1", "--replicas", "2", "--steps", "40", "--discard", "10",
                       "--bootstrap", "5", "--out", str(out)])
    assert res["beta"] == {40: None} and res["delta"]["densities"].tolist() == [0.5, 1.0]
    assert "beta (N = 40): not fitted:" in capsys.readouterr().out
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_the_finer_noises_run_only_for_the_sizes_fitted_and_leave_the_others_seeds_alone(tmp_path):
    # --beta-noises adds noises to the sizes fitted for beta, after --noises in the order
    # their seeds are numbered, so every point of --noises is the same run, bit for bit,
    # with or without them; the results come out in ascending noise.
    common = ["--sizes", "40,100", "--beta-sizes", "40", "--noises", "0,1,2,3", "--beta-from", "0",
              "--densities", "0.5,1", "--replicas", "2", "--steps", "30", "--discard", "10", "--bootstrap", "5"]
    args = vicsek.parse(common + ["--beta-noises", "2.5,1,0.5"])
    assert vicsek.noises_of(40, args) == [0.0, 1.0, 2.0, 3.0, 2.5, 0.5]
    assert vicsek.noises_of(100, args) == [0.0, 1.0, 2.0, 3.0]
    finer = vicsek.main(common + ["--beta-noises", "2.5,1,0.5", "--out", str(tmp_path / "a.png")])
    plain = vicsek.main(common + ["--beta-noises", "", "--out", str(tmp_path / "b.png")])
    noises, m, e = finer["fig2a"][40]
    assert noises.tolist() == [0.0, 0.5, 1.0, 2.0, 2.5, 3.0]
    same = [0, 2, 3, 5]
    np.testing.assert_array_equal(m[same], plain["fig2a"][40][1])
    np.testing.assert_array_equal(e[same], plain["fig2a"][40][2])
    assert finer["fig2a"][100][0].tolist() == [0.0, 1.0, 2.0, 3.0]
    np.testing.assert_array_equal(finer["fig2a"][100][1], plain["fig2a"][100][1])
