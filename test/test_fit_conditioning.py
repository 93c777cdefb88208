"""Fits on samples bunched in time (fit.LEAST_PIVOT, fit.ROUNDING_PIVOT, adaptive.DIVISORS and EXACT).

A writer that stamps each message when it writes it and stalls under load catches up in bursts: ten
samples 20-40 us apart every 15 ms, each position at its own stamp. Found with ``neforward demo`` on a
machine with every core busy: the node's peaks were off by up to 1500x, from windows of two or three
bursts whose normal equations had lost every digit (and a singular one dropped a message). The oracles
here: LAPACK's Cholesky factor and an SVD least-squares solve of the same design, and the closed form of
the motion sampled (its q'' at each stamp).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from neforward_ros.estimation import adaptive, native_fit
from neforward_ros.estimation.adaptive import FLOOR, grid_step, noise_of, rounding
from neforward_ros.estimation.fit import LEAST_PIVOT, block_fits, lapack_inverse, spd_inverse
from neforward_ros.estimation.settings import StreamSettings
from neforward_ros.estimation.stream import StreamingEstimator

from conftest import EPOCH_NS

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "bench"))
from motion_family import bunched_times, sines

SETTINGS = {
    "default": StreamSettings(),
    "polyfit causal": StreamSettings(mode="causal"),
    "kalman 20 ms": StreamSettings(method="kalman"),
    "kalman causal": StreamSettings(method="kalman", mode="causal"),
}


def gram_of(tau: np.ndarray, degree: int) -> np.ndarray:
    powers = tau[None, :] ** np.arange(2 * degree + 1)[:, None]
    sums = powers.sum(axis=1)
    k = np.arange(degree + 1)
    return sums[k[:, None] + k[None, :]]


def random_design(rng: np.random.Generator) -> tuple[np.ndarray, int]:
    """tau of 1-11 bursts of 1-11 samples, centred ([-1, 1]) or one-sided ([-2, 0]), and a degree."""
    degree = int(rng.choice([2, 4, 6]))
    low = -2.0 if rng.random() < 0.5 else -1.0
    centres = np.sort(rng.uniform(low, low + 2.0, rng.integers(1, 12)))
    tau = (centres[:, None] + 10 ** rng.uniform(-4, -0.5) * rng.random((len(centres), rng.integers(1, 12)))).ravel()
    return np.sort(tau[(tau >= low) & (tau <= low + 2.0)]), degree


def test_the_least_relative_pivot_is_lapacks_and_ill_posed_systems_give_nan() -> None:
    rng = np.random.default_rng(0)
    grams, pivots = [], []
    while len(grams) < 300:
        tau, degree = random_design(rng)
        if len(tau) < 6 + 3 or degree != 6:
            continue
        gram = gram_of(tau, 6)
        try:
            low = np.linalg.cholesky(gram)
        except np.linalg.LinAlgError:
            continue
        grams.append(gram)
        pivots.append(np.min(np.diag(low) ** 2 / np.diag(gram)))
    inverse, least = spd_inverse(np.stack(grams))
    by_lapack, least_by_lapack = lapack_inverse(np.stack(grams))  # (a few matrices' way)
    pivots = np.array(pivots)
    np.testing.assert_allclose(least_by_lapack, pivots, rtol=1e-12)
    np.testing.assert_array_equal(np.isnan(by_lapack), np.isnan(inverse))
    well = pivots > 1e-6  # where the two factorisations' rounding cannot tell the pivots apart
    np.testing.assert_allclose(least[well], pivots[well], rtol=1e-6)
    for k in np.flatnonzero(well):
        np.testing.assert_allclose(inverse[k], np.linalg.inv(grams[k]), rtol=1e-6, atol=1e-9 * np.abs(inverse[k]).max())
    ill = least < LEAST_PIVOT
    assert ill.any() and (~ill).sum() > 100  # both sides exercised
    assert np.isnan(inverse[ill]).all() and np.isfinite(inverse[~ill]).all()
    two_bursts = np.concatenate([-0.5 + 1e-3 * np.arange(5), 0.5 + 1e-3 * np.arange(5)])
    assert np.isnan(spd_inverse(gram_of(two_bursts, 6)[None])[0]).all()  # 10 samples, 2 instants, degree 6


def test_a_fit_made_states_its_variance_and_its_rounding_within_its_raised_floor() -> None:
    """Above LEAST_PIVOT the normal equations' variance factor is the SVD solve's within 2 %, and q''
    of a polynomial of the fit's degree sampled exactly is within two of the least deviations the rule
    takes (FLOOR of the position, here the window's largest, raised by ``rounding``); below it, no fit."""
    rng = np.random.default_rng(1)
    made = refused = 0
    for _ in range(3000):
        tau, degree = random_design(rng)
        if len(tau) < degree + 3:
            continue
        h = 10 ** rng.uniform(-3, -1)
        coefficients = rng.normal(size=degree + 1) * 10.0 * h ** np.arange(degree + 1)
        coefficients[0] = rng.uniform(-3.0, 3.0)
        y = np.polynomial.polynomial.polyval(tau, coefficients)
        _, _, d2, _, var2, pivot = block_fits(tau[None], np.ones((1, len(tau)), bool), y[:, None], h, degree)
        if pivot[0] < LEAST_PIVOT:
            refused += 1
            assert np.isnan(d2).all() and np.isnan(var2).all()
            continue
        made += 1
        design = np.vander(tau, degree + 1, increasing=True)
        u, s, vt = np.linalg.svd(design, full_matrices=False)
        pseudo = vt.T @ np.diag(1.0 / s) @ u.T
        oracle = 4.0 * (pseudo @ pseudo.T)[2, 2] / h**4
        assert abs(var2[0] / oracle - 1.0) < 0.02, (pivot[0], var2[0], oracle)
        truth = 2.0 * coefficients[2] / h**2
        least = FLOOR * np.abs(y).max() * rounding(pivot)[0] * np.sqrt(oracle)
        assert abs(d2[0, 0] - truth) <= 2.0 * least + 1e-12 * abs(truth), (pivot[0], d2[0, 0], truth, least)
    assert made > 1000 and refused > 50


def test_the_encoders_step_is_found_where_bursts_hide_its_rounding() -> None:
    """Bunched readings repeat within a burst and change by several steps between bursts: the sixth
    differences (mostly within bursts) read almost no noise, and the step is the largest whole fraction
    of the smallest change that the readings lie on; the compiled reading takes the same (its fit's
    deviation is numpy's)."""
    step = 2.0 * np.pi / 2**16
    times = bunched_times(4, seconds=1.0)
    window = (times > 0.4) & (times < 0.6)
    for speed in (2.0, 4.0, 7.0):  # steps a burst
        q = 0.3 + speed * step / 0.015 * times[:, None] + 1e-3 * np.sin(5.0 * times[:, None] + np.arange(3))
        q = np.round(q / step) * step
        t, y = times[window], q[window]
        np.testing.assert_allclose(noise_of(t, y)[1], step, rtol=1e-9)
        middle = t[len(t) // 2]
        c = adaptive.adaptive_fit(t, y, middle, 0.1, 4, 0.1, np.full(3, 2))
        numpy = adaptive.python_adaptive_fit(t, y, middle, 0.1, 4, 0.1, np.full(3, 2))
        np.testing.assert_allclose(c[3], numpy[3], rtol=1e-6)
    # regular stamps, each reading two or three steps on: the differences show the rounding, and no
    # fraction of the smallest change is taken for a step (the noise they read stands)
    rng = np.random.default_rng(2)
    y = 0.3 + np.cumsum(rng.choice([2, 3], size=(100, 3)), axis=0) * step
    assert (noise_of(np.arange(100) / 500.0, y)[1] == 0.0).all()
    t = np.arange(200) / 1000.0
    smooth = np.sin(3.0 * t)[:, None] + np.array([0.0, 1.0])
    assert (noise_of(t, smooth)[1] == 0.0).all()  # no grid in a smooth motion's samples
    ramp = 0.2 + 1e-3 * np.arange(200)[:, None] * np.ones(2)
    assert (grid_step(np.diff(ramp, axis=0), np.full(2, 1e-3), np.zeros(2)) == 0.0).all()  # one change: no grid


def test_a_ratio_of_two_changes_gives_its_reduced_denominator() -> None:
    """exact_denominator against Python's fractions: N2 / N1 for counts up to 10^4 (float64, as an
    encoder's counts times its step give them) is the reduced fraction's denominator where that is at
    most LARGEST_DIVISOR, else 0; a ratio off a whole number of any such step by far more than EXACT
    (a float32 reading's rounding) gives 0 or a denominator whose multiple misses the ratio."""
    from fractions import Fraction

    rng = np.random.default_rng(5)
    step = 2.0 * np.pi / 2**20
    counts = rng.integers(1, 10_000, size=(5000, 2))
    ratio = (counts[:, 1] * step) / (counts[:, 0] * step)
    expected = [Fraction(int(b), int(a)).denominator for a, b in counts]
    expected = np.array([d if d <= adaptive.LARGEST_DIVISOR else 0 for d in expected], dtype=float)
    got = adaptive.exact_denominator(np.maximum(ratio, 1.0))
    above = ratio >= 1.0
    np.testing.assert_array_equal(got[above], expected[above])
    assert (got[above] > 1).mean() > 0.5  # most are fractions
    few = np.maximum(ratio[:60], 1.0)  # one window's ratios are expanded one by one: the same numbers
    np.testing.assert_array_equal(adaptive.exact_denominator(few), got[:60])
    blurred = ratio[above] * (1.0 + 1e-5 * rng.standard_normal(above.sum()))
    found = adaptive.exact_denominator(blurred)
    assert (np.abs(found * blurred - np.round(found * blurred)) <= adaptive.EXACT)[found > 0].all()


@pytest.mark.parametrize("fits_with", ["c", "numpy"])
def test_the_step_is_found_where_the_smallest_change_is_many_steps(fits_with: str, monkeypatch) -> None:
    """A 100 Hz writer stalled 30 ms at a time, 16 bits: a joint moving tens to hundreds of steps
    between bursts, its step 1/14 of its smallest change and less. Read as the step (with eight
    divisors it was not, the noise read nothing, and the causal settings took a step crossed within a
    burst for a real slope: q'' 220 rad/s^2 for 0.86, 25 stated deviations off). The compiled
    reading's fit states numpy's deviation."""
    if fits_with == "numpy":
        monkeypatch.setattr(native_fit, "FIT", native_fit.NativeAdaptiveFit())
        monkeypatch.setenv("NEFORWARD_NATIVE", "off")
    else:  # the compiled fit, built before the first target (until then numpy serves)
        assert native_fit.FIT.get(wait=True) is not None or pytest.skip("no C compiler here")
    step = 2.0 * np.pi / 2**16
    times = bunched_times(0, rate=100.0, seconds=2.0, period=0.03)
    found = 0
    for speed in (15.3, 48.7, 141.1, 390.2):  # steps a burst
        q = 0.3 + speed * step / 0.03 * times[:, None] + 2e-3 * np.sin(9.0 * times[:, None] + np.arange(3))
        q = np.round(q / step) * step
        for end in np.arange(0.4, 1.9, 0.1):
            window = (times > end - 0.2) & (times <= end)
            t, y = times[window], q[window]
            _, read = noise_of(t, y)
            # where one is read: the step, or a multiple whose grid the window's readings happen to lie
            # on (every change an even number of steps: its rounding stated larger, not smaller)
            multiple = read[read > 0.0] / step
            np.testing.assert_allclose(multiple, np.round(multiple), rtol=0, atol=1e-9)
            found += np.sum(np.abs(read - step) <= 1e-9 * step)
            c = adaptive.adaptive_fit(t, y, t[-1], 0.1, 4, 0.0, np.full(3, 2))
            numpy = adaptive.python_adaptive_fit(t, y, t[-1], 0.1, 4, 0.0, np.full(3, 2))
            # the same step read, the same deviation: one-sided fits on bursts (pivots down to 1e-10) carry
            # their rounding into the level estimates' distances, 2e-6 of them here; another step would
            # differ by far more than 1e-3
            np.testing.assert_allclose(c[3], numpy[3], rtol=1e-3)
    assert found >= 0.8 * 4 * 15 * 3, found


@pytest.fixture(params=["c", "numpy"])
def fits_by(request, monkeypatch):
    if request.param == "numpy":
        monkeypatch.setenv("NEFORWARD_NATIVE", "off")
        monkeypatch.setattr(native_fit, "FIT", native_fit.NativeAdaptiveFit())
    else:
        assert native_fit.FIT.get(wait=True) is not None or pytest.skip("no C compiler here")
    return request.param


def stream(times: np.ndarray, q: np.ndarray, settings: StreamSettings) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(sample index, q'', its stated standard deviation) of each estimate, ``q`` fed one message at a time."""
    names = [f"j{k}" for k in range(q.shape[1])]
    logged = []
    estimator = StreamingEstimator(names, settings=settings, log=lambda level, message: logged.append(message))
    stamps = EPOCH_NS + np.round(times * 1e9).astype(np.int64)
    out = [e for k in range(len(times)) for e in estimator.update(int(stamps[k]), names, q[k].tolist())]
    assert not [m for m in logged if "dropped" in m], logged
    at = np.searchsorted(stamps, [e.stamp_ns for e in out])
    return at, np.array([e.accelerations for e in out]), np.array([e.acceleration_std for e in out])


@pytest.mark.parametrize("setting", list(SETTINGS))
def test_exact_positions_at_bursty_stamps(setting: str, fits_by: str) -> None:
    """The demo's case: each position exact at its stamp. Every estimate after the first half second
    within 2 % of the joint's largest |q''| (was off by up to 7e4x, and a message dropped)."""
    worst = 0.0
    for seed in (0, 1):
        times = bunched_times(seed)
        q, qdd = sines(times, 1.0, np.random.default_rng(10 + seed), 3)
        at, accelerations, _ = stream(times, q, SETTINGS[setting])
        late = times[at] > 0.5
        assert late.sum() > 1000 and np.isfinite(accelerations[late]).all()
        worst = max(worst, np.max(np.abs(accelerations[late] - qdd[at[late]]) / np.abs(qdd).max(axis=0)))
    assert worst < 0.02, worst


@pytest.mark.parametrize("setting", list(SETTINGS))
def test_quantised_positions_at_bursty_stamps_are_as_good_as_at_regular_ones(setting: str) -> None:
    """Through 14-16-bit encoders, the q'' error at bursty stamps: RMS at most twice (plus 0.5 % of the
    RMS q'') that at regular stamps of the same count, and no estimate off by more than 10 % of the
    joint's largest |q''| (an encoder's step hidden from the noise reading by the bursts' repeated
    readings let windows of three bursts be fitted as exact: 35x)."""
    for seed, fmax, bits in ((2, 1.0, 16), (3, 3.0, 14)):
        bursty = bunched_times(seed, seconds=2.5)
        regular = np.round((np.arange(len(bursty)) + 0.5) * bursty[-1] / len(bursty) * 1e9) / 1e9
        errors = []
        for times in (regular, bursty):
            q, qdd = sines(times, fmax, np.random.default_rng(100 + seed), 3)
            step = 2.0 * np.pi / 2**bits
            at, accelerations, _ = stream(times, np.round(q / step) * step, SETTINGS[setting])
            late = times[at] > 0.6
            error = accelerations[late] - qdd[at[late]]
            errors.append((np.sqrt(np.mean(error**2, axis=0)) / np.sqrt(np.mean(qdd**2, axis=0)),
                           np.max(np.abs(error) / np.abs(qdd).max(axis=0))))  # fmt: skip
        (rms_regular, _), (rms_bursty, worst) = errors
        assert (rms_bursty <= 2.0 * rms_regular + 0.005).all(), (seed, rms_regular, rms_bursty)
        assert worst < 0.1, (seed, worst)


@pytest.mark.parametrize("setting", list(SETTINGS))
def test_slow_bunched_stamps_state_what_they_cannot_show(setting: str) -> None:
    """A 100 Hz writer stalled 30 ms at a time (three or four messages 40 us apart), 16 bits, and a 200 Hz
    one, 18 bits: every estimate after 0.8 s (the causal choice's first waits for its record: 0.65-0.71 s
    here) within six times its stated deviation plus
    1 % of the joint's largest |q''| of the truth (3.7 at most, every setting, four seeds at 100 Hz:
    ``bench/bench_bunched_stamps.py --slow``).
    The causal settings' one-sided fits were 25 such units off at 100 Hz (q'' 220 rad/s^2 for 0.86)
    where the encoder's step, 1/14 of the smallest change, was not found; at 200 Hz, kalman 20 ms 12.6
    (a bank model chosen by its record, 4.1 rad/s^2 off after a gap, stated 0.09)."""
    for rate, bits, seed in ((100.0, 16, 0), (100.0, 16, 2), (200.0, 18, 1)):
        step = 2.0 * np.pi / 2**bits
        times = bunched_times(seed, rate=rate, seconds=3.0, period=0.03)
        q, qdd = sines(times, 1.0, np.random.default_rng(seed), 3)
        at, accelerations, stds = stream(times, np.round(q / step) * step, SETTINGS[setting])
        late = times[at] > 0.8
        error = accelerations[late] - qdd[at[late]]
        stated = stds[late]
        assert late.sum() > 200 and np.isfinite(error).all()
        largest = np.abs(qdd).max(axis=0)
        assert (np.abs(error) <= 6.0 * (stated + 0.01 * largest)).all(), (
            rate,
            seed,
            np.max(np.abs(error) / (stated + 0.01 * largest)),
        )
