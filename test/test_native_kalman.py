"""The Kalman bank's filter step in C (neforward_ros.estimation.native_kalman) against the numpy one it
replaces, and against the dense Gaussian-process posterior through the existing test of the track
(test_estimators.py, which runs whichever serves); the bank's mixture and causal predictions in C
(Mixer, Ahead) against numpy's likewise, and C taking over numpy's state part-way.

On a family of streams the two must agree to rounding: 100 Hz to 1 kHz with jitter, one to nine
joints, positions alone or with velocities, causal and fixed-lag (the smoother's live steps moved, its
buffers grown and compacted as steps are forgotten), a track copied part-way for some of its joints
(``select``: its buffers are then column copies), 16-bit and 20-bit encoders (covariances of condition
up to about 1e13). Without a compiler, or with NEFORWARD_NATIVE=off, numpy serves.
"""

from __future__ import annotations

import numpy as np
import pytest

from neforward_ros.estimation import native_fit
from neforward_ros.estimation.kalman_bank import KalmanBank
from neforward_ros.estimation.motion import KalmanSettings
from neforward_ros.kinematics import native

pytestmark = pytest.mark.skipif(native.compiler() is None, reason="no C compiler (cc) here: numpy serves")

EPOCH_NS = 1_700_000_000_000_000_000


def stream(rng: np.random.Generator, rate: float, joints: int, bits: int, seconds: float = 1.2):
    count = int(seconds * rate)
    t = np.arange(count) / rate + rng.uniform(-0.05, 0.05, count) / rate
    frequency = rng.uniform(0.3, 4.0, joints)
    phase = rng.uniform(0, 6, joints)
    amplitude = rng.uniform(0.1, 1.0, joints)
    q = np.sin(2 * np.pi * frequency * t[:, None] + phase) * amplitude
    v = 2 * np.pi * frequency * np.cos(2 * np.pi * frequency * t[:, None] + phase) * amplitude
    step = 2 * np.pi / 2**bits
    return (EPOCH_NS + (t * 1e9).astype(np.int64)), np.round(q / step) * step, v


def run(stamps, q, v, lag: int, native_step: bool, monkeypatch, split: int | None):
    """Every estimate (mixture and its deviations), each model's state and covariance, likelihood
    scores and normalised innovations, of a bank fed the stream."""
    with monkeypatch.context() as patch:
        if not native_step:
            patch.setattr(native_fit.FIT, "get", lambda wait=False: None)
        bank = KalmanBank(KalmanSettings(), smooth=lag > 0)
        columns = list(range(q.shape[1]))
        out = []
        for k in range(len(stamps)):
            if k == split:  # the later samples of some joints only, with the history so far
                columns = columns[::2]
                bank = bank.select(columns)
            bank.add(int(stamps[k]), q[k, columns], v[k, columns])
            target = int(stamps[max(k - lag, 0)])
            mixture, std = bank.estimate(target)
            bank.forget_before(target)
            newest = bank.track.steps[-1]
            out.append((mixture, std, newest.filtered, newest.covariance, bank.scores, bank.track.nis))
        used = bank.track._stepper is not None and bank._mixer is not None
    return out, used


@pytest.mark.parametrize("seed", range(8))
def test_the_c_step_agrees_with_numpy_to_rounding(seed: int, monkeypatch) -> None:
    assert native_fit.FIT.get(wait=True) is not None, "the C library did not build"
    rng = np.random.default_rng(seed)
    rate = float(rng.choice([100.0, 250.0, 500.0, 1000.0]))
    joints = int(rng.integers(1, 10))
    bits = int(rng.choice([16, 20]))
    stamps, q, v = stream(rng, rate, joints, bits)
    if seed % 2:
        v[:] = np.nan  # positions alone
    lag = int(rng.choice([0, round(0.02 * rate), round(0.05 * rate)]))
    split = len(stamps) // 3 if seed % 4 >= 2 and joints > 1 else None
    expected, numpy_used = run(stamps, q, v, lag, False, monkeypatch, split)
    got, native_used = run(stamps, q, v, lag, True, monkeypatch, split)
    assert native_used and not numpy_used
    # Relative to each quantity's largest entry. A recursion over covariances of condition up to 1e13 takes
    # the rounding of the two (their products' terms added in other orders) to 3e-7 of the covariances and
    # the estimates, 2e-5 of the states (the Matern states' entries span orders of magnitude), 1e-3 of
    # the normalised innovations (noise at a 20-bit encoder's step) and 4e-3 of the stated deviation (a
    # joint's revision ratio: the difference of its filtered and smoothed variances, of nearly equal
    # size). A wrong product, sign or buffer moves them by their own size.
    tolerances = {"mixture": 3e-6, "std": 3e-2, "state": 2e-4, "covariance": 3e-6, "scores": 2e-4, "nis": 1e-2}
    for k, (one, other) in enumerate(zip(got, expected, strict=True)):
        for (name, tolerance), a, b in zip(tolerances.items(), one, other, strict=True):
            scale = float(np.nanmax(np.abs(b)))
            assert np.allclose(a, b, rtol=0.0, atol=tolerance * scale, equal_nan=True), (k, name, a, b)


@pytest.mark.parametrize(("seed", "lag", "velocities"), [(0, 0, False), (1, 20, False), (2, 20, True), (3, 0, True)])
def test_the_c_mixture_equals_numpy_s(seed: int, lag: int, velocities: bool, monkeypatch) -> None:
    """The models' mixture, its deviations and the revisions (KalmanBank.estimates) in C against numpy's,
    the filter's step in C for both: the same arithmetic in the same order, so equal to the last few bits
    (numpy's exp and pow may be other implementations than the C library's), by the likelihood's weights
    (fixed lag), the predictions' shares (causal, once they have a record) and one model alone."""
    assert native_fit.FIT.get(wait=True) is not None, "the C library did not build"
    rng = np.random.default_rng(100 + seed)
    stamps, q, v = stream(rng, 1000.0, 5, 16)
    if not velocities:
        v[:] = np.nan
    outputs = []
    for native_mix in (False, True):
        with monkeypatch.context() as patch:
            if not native_mix:
                patch.setattr(KalmanBank, "_mixer_for", lambda self, count, joints: None)
            banks = [KalmanBank(KalmanSettings(), lag > 0), KalmanBank(KalmanSettings(length_scale=0.1), lag > 0)]
            out, choosing = [], False
            for k in range(len(stamps)):
                target = int(stamps[max(k - lag, 0)])
                for bank in banks:
                    bank.add(int(stamps[k]), q[k], v[k])
                    out.append(np.concatenate(bank.estimate(target), axis=None))
                    out.append(np.concatenate([bank.revisions, bank.weights().ravel()]))
                    bank.forget_before(target)
                choosing |= banks[0]._choosing
            assert (banks[0]._mixer is not None) == native_mix
            assert choosing == (lag == 0)
        outputs.append(np.concatenate(out))
    numpy_mix, c_mix = outputs
    assert np.allclose(c_mix, numpy_mix, rtol=1e-12, atol=0.0, equal_nan=True)


@pytest.mark.parametrize("lag", [0, 20])
def test_the_library_ready_part_way_takes_over_numpy_s_state(lag: int, monkeypatch) -> None:
    """The library is built in a thread while the first samples are filtered in numpy: the C step, mixture
    and predictions then take over from numpy's state (the filtered state, the smoother's buffers, the
    kept predictions), and go on as numpy would have, to rounding."""
    assert native_fit.FIT.get(wait=True) is not None, "the C library did not build"
    rng = np.random.default_rng(7)
    stamps, q, v = stream(rng, 1000.0, 4, 16)
    v[:] = np.nan
    library = native_fit.FIT.get()
    outputs = []
    for ready_at in (None, 500):
        bank = KalmanBank(KalmanSettings(), smooth=lag > 0)
        out = []
        for k in range(len(stamps)):
            ready = ready_at is not None and k >= ready_at
            monkeypatch.setattr(native_fit.FIT, "get", lambda wait=False, ready=ready: library if ready else None)
            bank.add(int(stamps[k]), q[k], v[k])
            target = int(stamps[max(k - lag, 0)])
            out.append(np.concatenate(bank.estimate(target), axis=None))
            bank.forget_before(target)
        assert (bank._mixer is not None) == (ready_at is not None)
        assert (bank._ahead is not None) == (ready_at is not None and lag == 0)
        outputs.append(np.array(out))
    numpy_only, switched = outputs
    assert np.array_equal(switched[:500], numpy_only[:500])
    scale = np.nanmax(np.abs(numpy_only), axis=0)  # each position's, velocity's, acceleration's and deviation's
    assert np.isclose(switched, numpy_only, rtol=0.0, atol=3e-6 * scale, equal_nan=True).all()
