"""Estimators that tune themselves, and say when they cannot.

On motions and seeds the estimator benchmark (bench/bench_estimator_family.py) does not use: chirps
sweeping up to several hertz, smooth steps (tanh-shaped moves between rests), at 250 and 800 Hz,
with 14-bit encoders or Gaussian noise.

- the adaptive polyfit (the default) is never much worse than the fixed window and far better where
  the motion is fast; the self-tuning Kalman bank follows a motion no single default fitted;
- each estimate states its acceleration's standard deviation, and the errors stay within it;
- a mismatched motion raises a warning naming the joint and what to change, a matched one none;
- explicit parameters win (a fixed window, an explicit length scale or noise);
- the virtual IMU carries the linear acceleration's covariance that follows.
"""

from __future__ import annotations

import logging
from types import SimpleNamespace

import numpy as np
import pytest

from neforward_ros.estimation import adaptive as adaptive_module
from neforward_ros.estimation import degree_choice
from neforward_ros.estimation.adaptive import GAMMA, DeviationPool, pooled_std
from neforward_ros.estimation.kalman_bank import KalmanBank
from neforward_ros.estimation.motion import KalmanSettings
from neforward_ros.estimation.settings import StreamSettings
from neforward_ros.estimation.stream import StreamingEstimator

from conftest import CONFIG_DIR, EPOCH_NS, LogRecorder


def chirp(t: np.ndarray, top: float, shift: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """A sweep from 0.2 Hz to ``top`` Hz over the signal, 0.3 rad: q and q-ddot."""
    span = t[-1] - t[0]
    rate = (top - 0.2) / span
    phase = 2 * np.pi * (0.2 * t + 0.5 * rate * t**2) + shift
    omega = 2 * np.pi * (0.2 + rate * t)
    alpha = 2 * np.pi * rate
    q = 0.3 * np.sin(phase)
    qdd = 0.3 * (np.cos(phase) * alpha - np.sin(phase) * omega**2)
    return q, qdd


def smooth_steps(t: np.ndarray, shift: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Moves of 0.6 rad between rests, each a tanh over about 0.15 s, every 0.8 s."""
    q = np.zeros_like(t)
    qdd = np.zeros_like(t)
    width = 0.05
    for k, centre in enumerate(np.arange(0.5, t[-1], 0.8) + shift):
        x = (t - centre) / width
        sign = 1.0 if k % 2 == 0 else -1.0
        th = np.tanh(x)
        q += sign * 0.3 * (th + 1.0)
        qdd += sign * 0.3 * (-2.0 * th * (1.0 - th**2)) / width**2
    return q, qdd


def sampled(kind: str, rate: float, seconds: float, seed: int, bits: int | None = 14, noise: float = 0.0):
    rng = np.random.default_rng(seed)
    count = int(seconds * rate)
    t = (np.arange(count) + rng.uniform(-0.05, 0.05, count)) / rate
    columns = []
    truth = []
    for joint in range(2):
        q, qdd = chirp(t, 4.0, joint) if kind == "chirp" else smooth_steps(t, 0.1 * joint)
        columns.append(q)
        truth.append(qdd)
    q = np.stack(columns, axis=1) + rng.normal(0.0, noise, (count, 2))
    if bits is not None:
        step = 2 * np.pi / 2**bits
        q = np.round(q / step) * step
    return t, EPOCH_NS + np.round(t * 1e9).astype(np.int64), q, np.stack(truth, axis=1)


def run(settings: StreamSettings, stamps: np.ndarray, q: np.ndarray, log=None):
    names = ["a", "b"]
    estimator = StreamingEstimator(names, settings=settings, log=log or (lambda level, message: None))
    out = []
    for k in range(len(stamps)):
        out += estimator.update(int(stamps[k]), names, q[k].tolist())
    ready = [e for e in out if e.all_ready]
    index = np.searchsorted(stamps, [e.stamp_ns for e in ready])
    return index, np.array([e.accelerations for e in ready]), np.array([e.acceleration_std for e in ready])


def relative(index, estimate, truth, t):
    keep = (t[index] > 1.0) & (t[index] < t[-1] - 0.5)
    return float(np.sqrt(np.mean((estimate[keep] - truth[index][keep]) ** 2) / np.mean(truth[index][keep] ** 2)))


@pytest.mark.parametrize("kind, rate", [("chirp", 250.0), ("steps", 800.0)])
def test_adaptive_windows_follow_fast_motion_and_keep_slow_motion_quiet(kind: str, rate: float) -> None:
    t, stamps, q, truth = sampled(kind, rate, 6.0, seed=31)
    fixed = relative(*run(StreamSettings(adaptive=False), stamps, q)[:2], truth, t)
    adaptive = relative(*run(StreamSettings(), stamps, q)[:2], truth, t)
    assert adaptive <= fixed, (adaptive, fixed)
    assert adaptive <= 0.08, adaptive


def test_the_kalman_bank_follows_what_no_single_default_fitted() -> None:
    """A chirp to 4 Hz: the former default (length scale 0.4 s, noise 1e-4) against the bank."""
    t, stamps, q, truth = sampled("chirp", 800.0, 6.0, seed=32)
    former = StreamSettings(method="kalman", kalman=KalmanSettings(noise=1e-4, length_scale=0.4))
    bank = StreamSettings(method="kalman")
    before = relative(*run(former, stamps, q)[:2], truth, t)
    after = relative(*run(bank, stamps, q)[:2], truth, t)
    assert after <= 0.5 * before and after <= 0.05, (after, before)


def test_each_estimate_states_an_uncertainty_that_covers_its_error() -> None:
    """The default's: the chosen fit's noise part, where the noise dominates (a slow sweep, noisy
    samples); where the motion's curvature does, the window's bias adds up to about GAMMA of it (the
    README says so). The Kalman bank states its filters' posterior spread, which holds only where its
    models fit the motion: what its innovations check says."""
    rng = np.random.default_rng(33)
    count = 4800
    t = (np.arange(count) + rng.uniform(-0.05, 0.05, count)) / 800.0
    truth = np.stack([chirp(t, 1.0, s)[1] for s in (0.0, 1.0)], axis=1)
    q = np.stack([chirp(t, 1.0, s)[0] for s in (0.0, 1.0)], axis=1) + rng.normal(0.0, 2e-4, (count, 2))
    stamps = EPOCH_NS + np.round(t * 1e9).astype(np.int64)
    index, estimate, std = run(StreamSettings(), stamps, q)
    keep = (t[index] > 1.0) & (t[index] < t[-1] - 0.5)
    error = np.abs(estimate[keep] - truth[index][keep])
    sigma = std[keep]
    assert np.all(np.isfinite(sigma)) and np.all(sigma > 0)
    assert np.mean(error <= 3.0 * sigma) >= 0.9, np.mean(error <= 3.0 * sigma)
    assert np.mean(error <= (1.0 + GAMMA) * sigma) >= 0.99
    assert np.median(error / sigma) >= 0.05, np.median(error / sigma)  # not a uselessly wide bound


def coloured_honesty(rate: float, cutoff: float, seed: int, monkeypatch=None) -> np.ndarray:
    """RMS of (error / stated sigma) per joint of the default on a 2 Hz chirp whose positions carry
    coloured noise (white noise through a 2nd-order low-pass at ``cutoff``, 2e-4 rad RMS: a real
    arm's logged positions have most of their noise well below the sampling rate's Nyquist
    frequency), stamps jittered by +-30 %. ``monkeypatch``: the stated sigma left unpooled (each
    estimate's own) and the noise taken as white (the degree choice's colour c left at 1)."""
    from scipy.signal import butter, lfilter

    rng = np.random.default_rng(seed)
    count = int(6.0 * rate)
    t = (np.arange(count) + rng.uniform(-0.3, 0.3, count)) / rate
    b, a = butter(2, cutoff, fs=rate)
    noise = lfilter(b, a, rng.normal(0.0, 1.0, (count, 2)), axis=0)
    q = np.stack([chirp(t, 2.0, s)[0] for s in (0.0, 1.0)], axis=1) + 2e-4 * noise / noise.std(axis=0)
    truth = np.stack([chirp(t, 2.0, s)[1] for s in (0.0, 1.0)], axis=1)
    if monkeypatch is not None:  # neither the last half window's deviations nor the noise's colour
        monkeypatch.setattr(DeviationPool, "state", lambda self, stamp, own: own)
        coloured = degree_choice.terms

        def white(accelerations: np.ndarray, *deviations: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            rows, counted = coloured(accelerations, *deviations)
            rows = rows.copy()
            rows[2 * len(accelerations) + 2] = 0.0  # degree 6's distances beyond its noise: c = 1 (the finer
            # fit's colour, which only keeps it out where coloured, left as read)
            return rows, counted

        monkeypatch.setattr(degree_choice, "terms", white)
        # the node's choice in numpy, where terms makes the sums (its C makes them itself)
        uncompiled = SimpleNamespace(FIT=SimpleNamespace(get=lambda wait=False: None))
        monkeypatch.setattr(degree_choice, "native_fit", uncompiled)
    index, estimate, std = run(StreamSettings(), EPOCH_NS + np.round(t * 1e9).astype(np.int64), q)
    keep = (t[index] > 1.0) & (t[index] < t[-1] - 0.5)
    return np.sqrt(np.mean(((estimate[keep] - truth[index][keep]) / std[keep]) ** 2, axis=0))


@pytest.mark.parametrize("rate, colour, seed", [(1000.0, 0.05, 45), (1000.0, 0.1, 41), (500.0, 0.2, 45)])
def test_the_stated_deviation_holds_under_coloured_noise(rate: float, colour: float, seed: int, monkeypatch) -> None:
    """Issue 26: the stated sigma is honest where the noise is coloured, as a real arm's is (the
    Panda's recording: ``bench/bench_realdata.py``): RMS of error / sigma within 0.5..2 there, here
    within 0.3..2, for noise coloured at 5-20 % of the rate, well above the motion's band (noise
    within the motion's band, 10 Hz at 200 Hz, is motion to any estimator: RMS z 2.3-2.5 there).
    The degree choice reads the noise's colour off the reference's distances to its next window over
    the last second and states each estimate's coloured noise (RMS z 1.4-1.7 unpooled); pooled over
    the last half window's (adaptive.DeviationPool) too. Neither (the mutation: unpooled, and the
    colour left at 1), it does not hold: 1.7-3.0 where the stated sigma gives 0.6-1.04 (since the finer
    fit of 2026-11-30, 1.77 and 1.99 on the first case: asserted over 1.6)."""
    honesty = coloured_honesty(rate, colour * rate, seed)
    assert np.all((honesty >= 0.3) & (honesty <= 2.0)), honesty.round(2)
    unpooled = coloured_honesty(rate, colour * rate, seed, monkeypatch)
    assert np.any(unpooled > 1.6), unpooled.round(2)


def trapezoidal_moves(t: np.ndarray, first: float) -> tuple[np.ndarray, np.ndarray]:
    """Moves every 1.3 s from ``first`` on, alternating in sign: 12 rad/s^2 for 0.2 s, coasting 0.3 s,
    -12 rad/s^2 for 0.2 s (the acceleration jumps at four corners per move): q and q-ddot."""
    q, qdd = np.full_like(t, 0.3), np.zeros_like(t)
    for k, start in enumerate(np.arange(first, t[-1] - 1.0, 1.3)):
        accel, s = 12.0 * (-1.0) ** k, t - start
        speed = accel * 0.2
        ramp = np.clip(s, 0.0, 0.2)
        down = np.clip(s - 0.5, 0.0, 0.2)
        q += 0.5 * accel * ramp**2 + speed * np.clip(s - 0.2, 0.0, 0.3) + speed * down - 0.5 * accel * down**2
        qdd += np.where((s >= 0.0) & (s < 0.2), accel, 0.0) - np.where((s >= 0.5) & (s < 0.7), accel, 0.0)
    return q, qdd


@pytest.mark.parametrize("rate, bits, seed", [(100.0, 20, 61), (100.0, 16, 62), (250.0, 20, 63)])
def test_the_stated_deviation_holds_where_the_acceleration_jumps(rate: float, bits: int, seed: int) -> None:
    """Trapezoidal-velocity moves: at each corner even the smallest window's bias breaks the
    intersection and the smallest is chosen, with no smaller window to measure its bias against. Its
    stated sigma then adds the distance to the next larger window's estimate (a bound: that window's
    bias is larger): RMS of error / sigma at most 3 per joint (1.9-2.7 measured; with the noise alone
    there, 3.1-9.8)."""
    rng = np.random.default_rng(seed)
    count = int(6.0 * rate)
    t = (np.arange(count) + rng.uniform(-0.05, 0.05, count)) / rate
    moves = [trapezoidal_moves(t, 0.7 + 0.2 * j) for j in range(2)]
    step = 2 * np.pi / 2**bits
    q = np.round(np.stack([m[0] for m in moves], axis=1) / step) * step
    truth = np.stack([m[1] for m in moves], axis=1)
    index, estimate, std = run(StreamSettings(), EPOCH_NS + np.round(t * 1e9).astype(np.int64), q)
    keep = (t[index] > 1.0) & (t[index] < t[-1] - 0.5)
    honesty = np.sqrt(np.mean(((estimate[keep] - truth[index][keep]) / std[keep]) ** 2, axis=0))
    assert np.all(honesty <= 3.0), honesty.round(2)


def test_where_the_smallest_window_is_chosen_its_distance_to_the_next_larger_is_stated() -> None:
    """adaptive.stated_std on three levels (largest first) of one target, two columns."""
    estimates = np.array([[1.0, 1.0], [2.0, 2.0], [4.0, 4.0]])
    valid = np.array([[True, True], [True, True], [True, False]])
    noise = np.array([0.5, 0.5])
    # column 0 chose level 1: the next smaller (level 2) is valid; column 1 chose level 1, the smallest valid
    stated = adaptive_module.stated_std(estimates, valid, np.array([1, 1]), noise)
    np.testing.assert_allclose(stated, [np.hypot(0.5, 2.0), np.hypot(0.5, 1.0)])
    # the smallest level chosen where it is the only valid one: the noise alone
    alone = adaptive_module.stated_std(estimates[:1], valid[:1], np.array([0, 0]), noise)
    np.testing.assert_allclose(alone, noise)


def test_a_pooled_deviation_is_the_rms_of_the_last_half_window_and_never_below_its_own(monkeypatch) -> None:
    """adaptive.pooled_std against a direct loop over each estimate's window (s - window / 2, s]; the
    node's DeviationPool, fed one estimate at a time, against it."""
    rng = np.random.default_rng(44)
    stamps = np.cumsum(rng.integers(1, 9, 400)) * 1_000_000  # 1-8 ms apart
    std = rng.lognormal(-3.0, 2.0, (400, 3))
    std[rng.random((400, 3)) < 0.1] = np.nan
    pooled = pooled_std(stamps, std, 0.06)
    expected = np.full_like(std, np.nan)
    for i, stamp in enumerate(stamps):
        inside = std[(stamps > stamp - 30_000_000) & (stamps <= stamp)]
        for j in range(3):
            if np.isfinite(std[i, j]):
                values = inside[:, j][np.isfinite(inside[:, j])]
                expected[i, j] = max(std[i, j], float(np.sqrt(np.mean(values**2))))
    np.testing.assert_allclose(pooled, expected, rtol=1e-10)
    assert pooled_std(stamps[:0], std[:0], 0.06).shape == (0, 3)
    monkeypatch.setattr(adaptive_module, "POOL_CHUNK", 7)  # chunks smaller than a window
    np.testing.assert_allclose(pooled_std(stamps, std, 0.06), expected, rtol=1e-10)
    monkeypatch.setattr(adaptive_module, "PRECISION", 0.5)  # every window summed directly
    np.testing.assert_allclose(pooled_std(stamps, std, 0.06), expected, rtol=1e-10)
    pool = DeviationPool(0.06, 3)  # the node's, one estimate at a time: the same windows
    one_by_one = np.array([pool.state(int(stamp), row) for stamp, row in zip(stamps, std, strict=True)])
    np.testing.assert_allclose(one_by_one, pooled, rtol=1e-10)
    pool.clear()
    np.testing.assert_array_equal(pool.state(int(stamps[-1]), std[-1]), std[-1])


def test_a_mismatched_motion_is_said_and_a_matched_one_is_not() -> None:
    # polyfit on a 4 Hz chirp sampled at 40 Hz: the smallest window, over and over
    rng = np.random.default_rng(34)
    count = 400
    t = (np.arange(count) + rng.uniform(-0.05, 0.05, count)) / 40.0
    fast = np.stack([0.3 * np.sin(2 * np.pi * 4.0 * t), 0.3 * np.cos(2 * np.pi * 3.5 * t)], axis=1)
    stamps = EPOCH_NS + np.round(t * 1e9).astype(np.int64)
    log = LogRecorder()
    run(StreamSettings(window=0.5), stamps, fast, log)
    said = [m for level, m in log.lines if level == logging.WARNING and "strained" in m]
    assert said and "'a'" in said[0] and "raise the joint-state rate" in said[0]
    # kalman with an explicit length scale far too long for the motion
    t, stamps, q, _ = sampled("chirp", 500.0, 5.0, seed=35)
    log = LogRecorder()
    run(StreamSettings(method="kalman", kalman=KalmanSettings(length_scale=3.0, noise=1e-5)), stamps, q, log)
    said = [m for level, m in log.lines if level == logging.WARNING and "innovations" in m]
    assert said and "estimator.kalman.length_scale" in said[0]
    # matched: the defaults on a slow motion well sampled
    slow_t = np.arange(2500) / 500.0
    slow = np.stack([0.3 * np.sin(2 * np.pi * 0.7 * slow_t), 0.2 * np.cos(2 * np.pi * 0.4 * slow_t)], axis=1)
    slow_stamps = EPOCH_NS + np.round(slow_t * 1e9).astype(np.int64)
    step = 2 * np.pi / 2**17
    for settings in (StreamSettings(), StreamSettings(method="kalman"), StreamSettings(method="kalman", mode="causal")):
        log = LogRecorder()
        run(settings, slow_stamps, np.round(slow / step) * step, log)
        assert not [m for level, m in log.lines if level == logging.WARNING], log.lines


def test_explicit_parameters_win() -> None:
    _, stamps, q, _ = sampled("chirp", 500.0, 3.0, seed=36)
    names = ["a", "b"]
    explicit = StreamingEstimator(names, settings=StreamSettings(method="kalman", kalman=KalmanSettings(
        noise=3e-4, length_scale=0.2)))  # fmt: skip
    for k in range(200):
        explicit.update(int(stamps[k]), names, q[k].tolist())
    bank: KalmanBank = explicit._groups[0].track
    assert len(bank.models) == 1 and bank.models.models[0].settings.length_scale == 0.2
    assert bank.track._noise == pytest.approx(3e-4**2)
    automatic = StreamingEstimator(names, settings=StreamSettings(method="kalman"))
    for k in range(200):
        automatic.update(int(stamps[k]), names, q[k].tolist())
    bank = automatic._groups[0].track
    assert len(bank.models) == 4
    step = 2 * np.pi / 2**14
    assert step**2 / 12 <= bank.track._noise <= 5 * step**2 / 12  # read from the samples: about the step's
    # a fixed window: no stated uncertainty
    _, _, spread = run(StreamSettings(adaptive=False), stamps, q)
    assert np.isnan(spread).all()


def test_the_virtual_imu_carries_the_acceleration_covariance() -> None:
    from neforward_ros import load_model
    from neforward_ros.node.pipeline import Pipeline
    from neforward_ros.parameters.settings import node_settings

    urdf = (CONFIG_DIR / "panda.urdf").read_text()
    model = load_model(urdf)
    names = list(model.joint_names)
    rng = np.random.default_rng(37)
    t = np.arange(600) / 500.0
    q = 0.3 * np.sin(2 * np.pi * 0.8 * t[:, None] + np.arange(len(names)))
    step = 2 * np.pi / 2**16
    q = np.round((q + rng.normal(0, 1e-5, q.shape)) / step) * step
    for adaptive, known in ((True, True), (False, False)):
        pipeline = Pipeline(node_settings({"robot_description": urdf, "imu_links": ["panda_hand"],
                                           "estimator.adaptive": adaptive}), log=LogRecorder())  # fmt: skip
        messages = []
        for k in range(len(t)):
            for result in pipeline.on_joint_state(EPOCH_NS + int(t[k] * 1e9), names, q[k].tolist()):
                messages += [m for topic, m in pipeline.messages(result) if topic.endswith("/imu")]
        covariance = np.array(messages[-1]["linear_acceleration_covariance"]).reshape(3, 3)
        if known:
            assert np.all(np.linalg.eigvalsh(covariance) >= -1e-12) and np.trace(covariance) > 0
            np.testing.assert_allclose(covariance, covariance.T, atol=1e-15)
        else:
            assert not covariance.any()  # all zero: unknown, as sensor_msgs/Imu defines it


def test_joint_estimates_publish_each_acceleration_and_its_deviation() -> None:
    """~/joint_estimates (publish_joint_estimates): per joint the acceleration the result comes from and
    its standard deviation, which covers its error against the analytic truth as the estimator's own
    does; the bytes every runtime publishes decode to the same; a fixed window states none."""
    from neforward_ros import load_model
    from neforward_ros.interface.encoder import Encoder
    from neforward_ros.interface.topics import JOINT_ESTIMATES, JOINT_TRAJECTORY_TYPE
    from neforward_ros.node.pipeline import Pipeline
    from neforward_ros.parameters.settings import node_settings
    from neforward_ros.wire.rostypes import deserialize

    urdf = (CONFIG_DIR / "panda.urdf").read_text()
    names = list(load_model(urdf).joint_names)
    rng = np.random.default_rng(41)
    count = 2400
    t = (np.arange(count) + rng.uniform(-0.05, 0.05, count)) / 600.0
    shifts = np.linspace(0.0, 2.0, len(names))
    q = np.stack([chirp(t, 1.2, s)[0] for s in shifts], axis=1) + rng.normal(0.0, 2e-4, (count, len(names)))
    truth = np.stack([chirp(t, 1.2, s)[1] for s in shifts], axis=1)
    stamps = EPOCH_NS + np.round(t * 1e9).astype(np.int64)
    for adaptive in (True, False):
        settings = node_settings({"robot_description": urdf, "publish_joint_estimates": True,
                                  "estimator.adaptive": adaptive})  # fmt: skip
        pipeline, encoder = Pipeline(settings, log=LogRecorder()), Encoder(settings)
        found = []
        for k in range(count):
            for result in pipeline.on_joint_state(int(stamps[k]), names, q[k].tolist()):
                contents = dict(pipeline.messages(result))[JOINT_ESTIMATES]
                data = dict(encoder.encode(result))[JOINT_ESTIMATES]
                found.append((result.stamp_ns, contents, deserialize(JOINT_TRAJECTORY_TYPE, data)))
        assert len(found) > count * 0.9
        stamp, contents, decoded = found[len(found) // 2]
        assert decoded["joint_names"] == names == contents["joint_names"]
        (point,) = decoded["points"]
        np.testing.assert_array_equal(point["accelerations"], contents["points"][0]["accelerations"])
        assert decoded["header"]["stamp"]["sec"] * 10**9 + decoded["header"]["stamp"]["nanosec"] == stamp
        index = np.searchsorted(stamps, [s for s, _, _ in found])
        estimate = np.array([c["points"][0]["accelerations"] for _, c, _ in found])
        spread = [c["points"][0]["effort"] for _, c, _ in found]
        keep = (t[index] > 1.0) & (t[index] < t[-1] - 0.5)
        error = np.abs(estimate - truth[index])[keep]
        assert np.sqrt(np.mean(error**2) / np.mean(truth[index][keep] ** 2)) < 0.05
        if adaptive:
            sigma = np.array(spread)[keep]
            assert sigma.shape == error.shape and np.all(sigma > 0)
            assert np.mean(error <= 3.0 * sigma) >= 0.9, np.mean(error <= 3.0 * sigma)
            assert np.median(error / sigma) >= 0.05  # a bound that says something
        else:
            assert all(s == [] for s in spread)  # a fixed window states none


def test_the_bank_reads_no_noise_from_joints_at_rest_after_a_restart() -> None:
    """A fresh bank (a restart) whose joints mostly rest at non-zero positions while one moves through
    a 16-bit encoder, on jittered stamps: the resting joints' sixth differences are of rounding size
    (1e-16 of their position), no evidence of noise; the noise read is the moving joint's, about its
    encoder step / sqrt(12), not the floor (a floor of 1e-6 rad made the filter trust every sample
    and its accelerations swing by tens of rad/s^2 after a time reset)."""
    rng = np.random.default_rng(7)
    count, step = 200, 2 * np.pi / 2**16
    stamps = EPOCH_NS + np.cumsum(rng.integers(1_900_000, 2_100_000, count))
    t = (stamps - stamps[0]) / 1e9
    resting = np.array([0.31, -1.17, 2.05, 0.77, -0.42, 1.6])
    moving = np.round(0.4 * np.sin(2.0 * t) / step) * step
    bank = KalmanBank(KalmanSettings(), smooth=False)
    missing = np.full(7, np.nan)
    for k in range(count):
        bank.add(int(stamps[k]), np.r_[resting, moving[k]], missing)
    noise = np.sqrt(bank.read_noise["positions"])
    assert 0.3 * step / np.sqrt(12) <= noise <= 3.0 * step, (noise, step / np.sqrt(12))


@pytest.mark.parametrize("bits", [None, 26])
def test_the_bank_reads_a_moving_joints_noise_below_its_floor_as_the_floor(bits: int | None) -> None:
    """Samples finer than the bank's noise floor (1e-6 rad): a 26-bit encoder, or simulated positions
    as exact as doubles. Their sixth differences read below the floor, which a joint at rest gives
    too; these joints move, so the noise is at most the floor, and the bank reads the floor. It kept
    the fallback (1e-4 rad, a hundred times the floor) and smoothed the chirp's acceleration: 0.20 %
    off at 20 ms and 1.4 % causal, more than through a 16-bit encoder (0.15 % and 1.3 %); with the
    floor 0.013 % and 0.17 % (the truth in closed form)."""
    t, stamps, q, truth = sampled("chirp", 500.0, 4.0, seed=11, bits=bits)
    for mode, bound in (("fixed_lag", 0.0005), ("causal", 0.005)):
        index, estimate, _ = run(StreamSettings(method="kalman", mode=mode), stamps, q)
        error = relative(index, estimate, truth, t)
        assert error < bound, (mode, error)


@pytest.mark.parametrize("settings", [StreamSettings(), StreamSettings(mode="causal")], ids=["default", "causal"])
def test_a_robot_at_rest_or_dwelling_between_moves_is_not_said_to_strain(settings: StreamSettings) -> None:
    """An idle arm (a joint held exactly, one flickering between two encoder steps, one with a noise of
    0.7 step) and minimum-jerk moves with dwells at 800 Hz: nothing for the user to change. Before, a
    joint at rest counted as strained (its noise against a spread of nearly nothing), and an idle robot
    or one dwelling half the time was told to raise its joint-state rate; so was a move's start or end,
    a few tens of milliseconds of strain that at 800 Hz filled the last 50 estimates."""
    rng = np.random.default_rng(1)
    count, rate, step = 2500, 500.0, 2 * np.pi / 2**16
    idle = np.stack(
        [
            0.5 * np.ones(count),
            0.3 + step * (rng.random(count) < 0.3),
            -1.2 + step * np.round(rng.normal(0.0, 0.7, count)),
        ],
        axis=1,
    )
    idle = np.round(idle / step) * step
    stamps = EPOCH_NS + np.round(np.arange(count) / rate * 1e9).astype(np.int64)
    names = ["a", "b", "c"]
    for q, when in ((idle, stamps), moves_with_dwells()):
        log = LogRecorder()
        estimator = StreamingEstimator(names, settings=settings, log=log)
        for k in range(len(when)):
            estimator.update(int(when[k]), names, q[k].tolist())
        assert not [m for level, m in log.lines if level == logging.WARNING], log.lines


def moves_with_dwells() -> tuple[np.ndarray, np.ndarray]:
    """Three joints' minimum-jerk moves of 0.6 s with dwells of 0.4 s, at 800 Hz with +-5 % jitter,
    through a 12-bit encoder: (positions (T, 3), stamps (T,))."""
    rng = np.random.default_rng(5)
    count = 3200
    t = (np.arange(count) + rng.uniform(-0.05, 0.05, count)) / 800.0
    phase = np.mod(t + np.array([[0.0], [0.3], [0.6]]), 1.0).T  # (T, 3): moving during the first 0.6 s
    s = np.clip(phase / 0.6, 0.0, 1.0)
    shape = 10 * s**3 - 15 * s**4 + 6 * s**5
    cycle = np.floor(t + np.array([[0.0], [0.3], [0.6]])).T
    q = 0.8 * np.where(cycle % 2 == 0, shape, 1.0 - shape)
    step = 2 * np.pi / 2**12
    return np.round(q / step) * step, EPOCH_NS + np.round(t * 1e9).astype(np.int64)
