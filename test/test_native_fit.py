"""The adaptive fit in C (neforward_ros.estimation.native_fit) against the numpy one it replaces.

On a family of windows the two must agree: rates 100 Hz to 2 kHz with jitter, degrees 2 to 6 and
two of them fused, centred, lagged and causal windows, smooth, noisy and quantised joints, still
joints, one to eleven columns, either derivative: the same window chosen (the same strain flags), estimates within
rounding. The node (one window at a time) and the bag tool (every target of a recording) take the
very same numbers from it. Without a compiler, or with NEFORWARD_NATIVE=off, numpy serves.
"""

from __future__ import annotations

import numpy as np
import pytest

from neforward_ros.estimation import adaptive, native_fit
from neforward_ros.kinematics import native

pytestmark = pytest.mark.skipif(native.compiler() is None, reason="no C compiler (cc) here: numpy serves")


CONSTANTS = (adaptive.GAMMA, adaptive.ROUGHNESS, adaptive._GAIN, adaptive.FLOOR, adaptive.GROWTH, adaptive.LATTICE)
"""The rule's constants, as the package passes them to the C fit after the degree and derivative."""


def library():
    found = native_fit.FIT.get(wait=True)
    assert found is not None, "the C adaptive fit did not build"
    return found


def window(rng: np.random.Generator):
    rate = float(rng.choice([100.0, 250.0, 500.0, 1000.0, 2000.0]))
    n = int(rng.integers(1, 12))
    h = 0.1
    lead = float(rng.choice([h, 0.0, 0.03, 0.07]))
    # degree 6 where the default fits it (windows reaching past the estimate): a one-sided window of
    # degree 6 on a noise-free joint has intervals as narrow as the rounding of its normal equations,
    # which then decides the window in either computation
    order = int(rng.choice([2, 3, 4, 5, 6] if lead > 0.05 else [2, 3, 4, 5]))
    lower = int(rng.integers(2, order)) if order > 2 and rng.random() < 0.5 else None
    count = int(2 * h * rate) + 1
    t = np.sort(np.arange(count) / rate + rng.uniform(-0.05, 0.05, count) / rate) + 3.0
    target = t[-1] - lead
    y = np.sin(2 * np.pi * t[:, None] * rng.uniform(0.1, 8.0, n) + rng.uniform(0, 6, n)) * rng.uniform(0.01, 1, n)
    kind = int(rng.integers(3))
    if kind == 1:
        y = y + rng.normal(0.0, 1e-3, y.shape)
    elif kind == 2:
        step = 2 * np.pi / 2 ** int(rng.integers(10, 20))
        y = np.round(y / step) * step
    still = bool(rng.random() < 0.15)
    if still:
        y[:, 0] = 0.3
    derivative = rng.choice([1, 2], n)
    return t, y, target, h, order, lower, lead, derivative, still


def test_c_and_numpy_choose_the_same_windows_and_agree_to_rounding() -> None:
    lib = library()
    rng = np.random.default_rng(2026)
    worst = 0.0
    for _ in range(1500):
        t, y, target, h, order, lower, lead, derivative, still = window(rng)
        # two degrees fused: numpy fits each on its own, C both from one set of sums
        want = adaptive.python_adaptive_fit(t, y, target, h, order, lead, derivative, lower)
        got = native_fit.fit(lib, t, y, target, *adaptive._ladder_and_leads(h, lead), order, derivative,
                             *CONSTANTS, lower)  # fmt: skip
        assert got is not None
        got = tuple(entry[0] for entry in got)  # the one degree's
        np.testing.assert_array_equal(got[4], want[4])  # strained: the same windows chosen
        moving = slice(1, None) if still else slice(None)
        for k in (0, 1, 2):
            # the estimate, its spread, and the rounding of the samples through the fit (a joint whose
            # samples are all alike has estimates of rounding only)
            scale = np.abs(want[k]) + want[3] * h ** (2 - k) + 1e-5 * np.abs(y).max(axis=0) / h**k
            error = np.abs(got[k] - want[k])[moving] / scale[moving]
            # rounding, through the conditioning of each degree's normal equations: a causal window is the
            # worst conditioned (degree 5: up to 5.2e-7 against a spread read from jittered stamps'
            # divided differences; lagged and centred windows, degrees up to 6: 1.3e-8; over 3000 windows)
            bound = 2e-6 if lead < 0.05 else 5e-8
            assert np.all(error <= bound), (k, order, lead, error.max())
            worst = max(worst, float(error.max(initial=0.0)))
        # the stated spread holds the distance between two levels' estimates, each of them within the
        # rounding above: within that rounding too
        k = np.where(derivative == 2, 2, 1)
        columns = np.arange(len(k))
        chosen = np.abs(np.stack(want[:3])[k, columns])
        rounding = bound * (chosen + want[3] * h ** (2 - k) + 1e-5 * np.abs(y).max(axis=0) / h**k)
        assert np.all(np.abs(got[3] - want[3]) <= 1e-6 * want[3] + 2.0 * rounding)
        # the degree choice's two: the chosen level's noise, and the noise's between it and the level
        # the stated spread is measured against (a difference of two levels' variances)
        full = adaptive._numpy_fit(t, y, target, h, order, lead, derivative, lower)
        np.testing.assert_allclose(got[5], full[3], rtol=1e-6)
        np.testing.assert_allclose(got[6], full[6], rtol=1e-5, atol=1e-6 * float(np.max(full[3])))
        if still:  # a still joint: rounding only, within its stated floor
            assert abs(got[2][0]) <= 1e-6 and abs(want[2][0]) <= 1e-6
    assert worst > 0.0  # two computations, not one


def test_the_node_and_the_bag_take_the_very_same_numbers() -> None:
    """One target on its window's samples (the node) and every target on the whole recording (the
    bag tool): bitwise the same."""
    library()
    rng = np.random.default_rng(5)
    count, n = 6000, 5
    t = (np.arange(count) + rng.uniform(-0.1, 0.1, count)) / 500.0
    y = np.sin(t[:, None] * np.arange(1, n + 1)) + rng.normal(0.0, 1e-4, (count, n))
    for order, lower in ((4, None), (6, 4)):  # one degree; the default's two, fused
        whole = adaptive.adaptive_fits(t, y, t, 0.1, order, 0.1, lower=lower)
        for i in range(60, count - 60, 37):
            lo, hi = np.searchsorted(t, t[i] - 0.1), np.searchsorted(t, t[i] + 0.1, side="right")
            one = adaptive.adaptive_fit(t[lo:hi], y[lo:hi], t[i], 0.1, order, 0.1, np.full(n, 2), lower)
            for k in range(4):
                np.testing.assert_array_equal(one[k], whole[k][i])


def test_further_degrees_from_one_call_are_each_degrees_own_numbers() -> None:
    """The default's degrees 6, 4 and 2 from one call (the power sums and the noise read once): what one
    call per degree gives, the same windows chosen (the sums of a window are added ring by ring from the
    smallest window of any of the call's degrees: a lower degree's smaller windows change the order of
    the additions, so the higher degree's numbers agree to rounding); and a whole recording's (the bag
    tool's) bitwise the node's, one target at a time."""
    lib = library()
    rng = np.random.default_rng(31)
    worst = 0.0
    for _ in range(300):
        t, y, target, h, order, lower, lead, derivative, _ = window(rng)
        if order < 4:
            continue
        also = tuple(int(d) for d in rng.choice(np.arange(2, order), size=2, replace=False))
        ladder = adaptive._ladder_and_leads(h, lead)
        together = native_fit.fit(lib, t, y, target, *ladder, order, derivative, *CONSTANTS, lower, also)
        alone = [native_fit.fit(lib, t, y, target, *ladder, degree, derivative, *CONSTANTS, fused)
                 for degree, fused in zip((order, *also), (lower, None, None), strict=True)]  # fmt: skip
        assert together is not None and together[0].shape == (1 + len(also), len(derivative))
        for i, one in enumerate(alone):
            got, want = tuple(entry[i] for entry in together), tuple(entry[0] for entry in one)
            np.testing.assert_array_equal(got[4], want[4])  # the same windows
            for k in range(3):  # the estimates, as in the C-numpy comparison above
                scale = np.abs(want[k]) + want[3] * h ** (2 - k) + 1e-5 * np.abs(y).max(axis=0) / h**k
                error = float(np.max(np.abs(got[k] - want[k]) / scale))
                assert error <= 1e-7, (k, order, also, lead, error)
                worst = max(worst, error)
            # the stated deviation holds differences of nearby levels' estimates: their rounding, relative
            # to it, is larger (up to 5e-4 in 1500 windows, causal ones; 2e-5 centred or lagged)
            assert np.all(np.abs(got[3] - want[3]) <= 2e-3 * want[3]), (order, also, lead)
    assert worst > 0.0  # the additions' order does differ somewhere
    node_is_bag(rng, 1.0, (6, 4, 2), finer=False)


def node_is_bag(rng: np.random.Generator, speed: float, degrees: tuple[int, ...], finer: bool) -> tuple:
    """Asserts that :func:`adaptive.degree_fit` on one target's window (the node) gives bitwise what
    :func:`adaptive.degree_fits` gives at every target of a recording (the bag tool), on sines of ``speed``
    rad/s per joint index at 500 Hz with jitter and noise; returns the recording's fits."""
    count, n = 3000, 3
    t = (np.arange(count) + rng.uniform(-0.1, 0.1, count)) / 500.0
    y = np.sin(speed * t[:, None] * np.arange(1, n + 1)) + rng.normal(0.0, 1e-4, (count, n))
    whole = adaptive.degree_fits(t, y, t, 0.1, degrees, 0.1, finer=finer)
    for i in range(60, count - 60, 53):
        lo, hi = np.searchsorted(t, t[i] - 0.1), np.searchsorted(t, t[i] + 0.1, side="right")
        one = adaptive.degree_fit(t[lo:hi], y[lo:hi], t[i], 0.1, degrees, 0.1, np.full(n, 2), finer=finer)
        for k in range(4):
            np.testing.assert_array_equal(one[k], whole[k][:, i])
        np.testing.assert_array_equal(one[5], whole[4][:, i])  # the noise's deviation
        np.testing.assert_array_equal(one[6], whole[5][:, i])  # and the noise's between it and its neighbour
    return whole


def test_the_finer_fit_is_the_rules_next_smaller_window_in_c_and_numpy_and_node_and_bag() -> None:
    """The default's finer fit (``finer``): the first degree's fit at the next smaller window than its
    rule chose. C and numpy take the same level (the same strain, the rule's) and agree to rounding; the
    others from the same call are unchanged; the whole recording's are bitwise the node's."""
    lib = library()
    rng = np.random.default_rng(77)
    shifted = 0
    for _ in range(400):
        t, y, target, h, order, _, lead, derivative, still = window(rng)
        if order < 4:
            continue
        ladder = adaptive._ladder_and_leads(h, lead)
        got = native_fit.fit(lib, t, y, target, *ladder, order, derivative, *CONSTANTS, None, (3,), 0.0, True)
        plain = native_fit.fit(lib, t, y, target, *ladder, order, derivative, *CONSTANTS, None, (3,))
        assert got is not None and plain is not None and got[0].shape == (3, len(derivative))
        for k in range(7):  # the rule's own fits, after the finer one, are those of a call without it
            np.testing.assert_array_equal(got[k][1:], plain[k])
        want = adaptive._numpy_fit(t, y, target, h, order, lead, derivative, None, finer=True)
        np.testing.assert_array_equal(got[4][0], want[4])  # the rule's strain
        moving = slice(1, None) if still else slice(None)
        for k in (0, 1, 2):
            scale = np.abs(want[k]) + want[3] * h ** (2 - k) + 1e-5 * np.abs(y).max(axis=0) / h**k
            error = np.abs(got[k][0] - want[k])[moving] / scale[moving]
            assert np.all(error <= (2e-6 if lead < 0.05 else 5e-8)), (k, order, lead, error.max())
        np.testing.assert_allclose(got[5][0], want[3], rtol=1e-6)  # a smaller window's noise
        shifted += int(np.count_nonzero(got[5][0] > got[5][1]))
    assert shifted > 0  # a noisier, smaller window somewhere
    whole = node_is_bag(rng, 3.0, (6, 4, 3), finer=True)
    assert whole[0].shape == (4, 3000, 3) and np.any(whole[2][0] != whole[2][1])


def test_targets_with_too_few_samples_take_numpy_and_no_compiler_takes_numpy_everywhere(monkeypatch) -> None:
    library()
    rng = np.random.default_rng(6)
    t = np.arange(400) / 500.0
    y = np.sin(3 * t[:, None]) + rng.normal(0.0, 1e-4, (400, 2))
    targets = np.array([-0.5, -0.095, 0.3, 0.5])  # the first two: too few samples for any window
    got = adaptive.adaptive_fits(t, y, targets, 0.1, 4, 0.1)
    np.testing.assert_array_equal(got[2][:2], adaptive.python_adaptive_fits(t, y, targets[:2], 0.1, 4, 0.1)[2])
    np.testing.assert_allclose(got[2][2:], adaptive.python_adaptive_fits(t, y, targets, 0.1, 4, 0.1)[2][2:], rtol=1e-8)
    monkeypatch.setenv("NEFORWARD_NATIVE", "off")
    fresh = native_fit.NativeAdaptiveFit()
    assert fresh.get(wait=True) is None


def test_a_whole_recording_shared_among_threads_gives_the_very_same_numbers(monkeypatch) -> None:
    """From PARALLEL_TARGETS targets on, the C fit runs on every core; each thread's targets come out
    bitwise as one thread's would (a broken slice or pointer would shift or drop targets)."""
    library()
    rng = np.random.default_rng(6)
    count, n = 5000, 3
    t = np.sort(rng.uniform(0.0, 10.0, count))
    y = np.cos(t[:, None] * np.arange(1, n + 1)) + rng.normal(0.0, 1e-4, (count, n))
    monkeypatch.setattr(native_fit, "PARALLEL_TARGETS", 10**9)
    serial = adaptive.adaptive_fits(t, y, t, 0.1, 4, 0.1)
    monkeypatch.setattr(native_fit, "PARALLEL_TARGETS", 100)
    monkeypatch.setattr(native_fit.os, "cpu_count", lambda: 3)  # three parts, also on a one-core machine
    shared = adaptive.adaptive_fits(t, y, t, 0.1, 4, 0.1)
    for k in range(4):
        np.testing.assert_array_equal(shared[k], serial[k])


def test_c_and_numpy_floor_the_noise_alike_where_the_times_are_uncertain() -> None:
    """With the samples' times uncertain by ``timing`` (a causal fit's until the stream's clock can tell
    whether its stamps are write times), C and numpy floor the noise read at
    :func:`~neforward_ros.estimation.adaptive.timing_noise` alike: the same windows chosen, the estimates
    within rounding; and the floor changes the chosen window of many."""
    lib = library()
    rng = np.random.default_rng(2027)
    changed = 0
    for _ in range(400):
        t, y, target, h, order, lower, lead, derivative, still = window(rng)
        timing = float(rng.uniform(0.01, 0.2)) * float(np.median(np.diff(t)))
        want = adaptive.python_adaptive_fit(t, y, target, h, order, lead, derivative, lower, timing)
        got = native_fit.fit(lib, t, y, target, *adaptive._ladder_and_leads(h, lead), order, derivative,
                             *CONSTANTS, lower, (), timing)  # fmt: skip
        assert got is not None
        got = tuple(entry[0] for entry in got)
        np.testing.assert_array_equal(got[4], want[4])
        moving = slice(1, None) if still else slice(None)
        bound = 2e-6 if lead < 0.05 else 5e-8
        for k in (0, 1, 2):
            scale = np.abs(want[k]) + want[3] * h ** (2 - k) + 1e-5 * np.abs(y).max(axis=0) / h**k
            assert np.all(np.abs(got[k] - want[k])[moving] / scale[moving] <= bound), (k, order, lead)
        plain = adaptive.python_adaptive_fit(t, y, target, h, order, lead, derivative, lower)
        changed += not np.array_equal(plain[2], want[2])
    assert changed >= 100, changed
