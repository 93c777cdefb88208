"""StreamingEstimator: accuracy against the exact derivatives of a known signal, equality with the
whole-recording estimator, and every kind of bad input followed by estimates that are still right."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from neforward_ros import InputError
from neforward_ros.estimation.batch import estimate_derivatives
from neforward_ros.estimation.estimate import JointEstimate
from neforward_ros.estimation.settings import StreamSettings
from neforward_ros.estimation.stream import StreamingEstimator

from conftest import EPOCH_NS, LogRecorder, jittered_stamps, reference, relative_rms

NAMES = ("a", "b")


def signal(t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Two joints: the reference signal and a phase-shifted copy; (T, 2) each."""
    parts = [reference(t), reference(t, 1.0)]
    return tuple(np.stack([p[i] for p in parts], axis=1) for i in range(3))


def to_ns(t: np.ndarray) -> np.ndarray:
    return EPOCH_NS + np.round(t * 1e9).astype(np.int64)


def feed(estimator, stamps_ns, positions, velocities=None, names=NAMES) -> list[JointEstimate]:
    out = []
    for k, stamp in enumerate(stamps_ns):
        v = () if velocities is None else list(velocities[k])
        out += estimator.update(int(stamp), list(names), list(positions[k]), v)
    return out


def stacked(out: list[JointEstimate]) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    return (
        np.array([e.stamp_ns for e in out]),
        np.array([e.positions for e in out]),
        np.array([e.velocities for e in out]),
        np.array([e.accelerations for e in out]),
    )


def truth_at(stamps_ns: np.ndarray, t: np.ndarray, ns: np.ndarray):
    """The exact signal at the output stamps (which are input stamps)."""
    index = np.searchsorted(ns, stamps_ns)
    assert np.array_equal(ns[index], stamps_ns), "output stamps must be input stamps"
    return tuple(x[index] for x in signal(t))


def test_fixed_lag_equals_the_whole_recording_estimator_on_interior_samples() -> None:
    t = jittered_stamps(2000, seed=3)
    ns = to_ns(t)
    q, _, _ = signal(t)
    noisy = q + np.random.default_rng(4).normal(0.0, 1e-4, q.shape)
    estimator = StreamingEstimator(NAMES, settings=StreamSettings(mode="fixed_lag"))
    out = feed(estimator, ns, noisy)
    stamps, positions, qd, qdd = stacked(out)
    # Emitted as soon as the newest stamp is lag (0.1 s) past, less half the shortest of the last 8
    # stamp intervals (jittered stamps come early), each stamped with its own sample's stamp.
    assert np.array_equal(stamps, ns[: len(stamps)])
    tolerance = int(np.diff(ns[-9:]).min()) // 2
    assert ns[-1] - stamps[-1] >= 100_000_000 - tolerance > ns[-1] - ns[len(stamps)]
    # An estimate exactly where the centred window (0.1 s either side) has samples from its start on:
    # none from a half-empty window at the start.
    ready = np.array([e.all_ready for e in out])
    np.testing.assert_array_equal(ready, stamps - 100_000_000 >= ns[0])
    qd_batch, qdd_batch = estimate_derivatives(ns, noisy)
    interior = slice(int(np.argmax(ready)), len(stamps))
    np.testing.assert_allclose(qdd[interior], qdd_batch[interior], rtol=0, atol=1e-9 * np.abs(qdd_batch).max())
    np.testing.assert_allclose(qd[interior], qd_batch[interior], rtol=0, atol=1e-9 * np.abs(qd_batch).max())
    np.testing.assert_array_equal(positions[ready], noisy[: len(stamps)][ready])  # the sample itself, not a fit
    # flush() gives the last lag's stamps too, without estimates: their windows have no samples after them.
    rest = estimator.flush()
    assert [e.stamp_ns for e in rest] == list(ns[len(stamps) :])
    assert not any(e.ready.any() for e in rest)


def test_difference_method_streams_equal_to_its_batch_form() -> None:
    t = jittered_stamps(400, seed=5)
    ns = to_ns(t)
    q, _, _ = signal(t)
    estimator = StreamingEstimator(NAMES, settings=StreamSettings(method="difference", mode="fixed_lag"))
    out = feed(estimator, ns, q)
    stamps, _, qd, qdd = stacked(out)
    ready = np.array([e.all_ready for e in out])
    assert ready[60:].all() and not ready[:40].any()  # from window / 2 = 0.1 s of history on
    qd_batch, qdd_batch = estimate_derivatives(ns, q, method="difference")
    np.testing.assert_allclose(qdd[ready], qdd_batch[: len(stamps)][ready], rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(qd[ready], qd_batch[: len(stamps)][ready], rtol=1e-9, atol=1e-9)


@pytest.mark.parametrize("noise", [0.0, 1e-4])
def test_accuracy_of_each_mode_on_the_reference_signal(noise: float) -> None:
    """Fixed-lag: as the batch estimator. Causal: larger error, but no delay (measured, README)."""
    t = jittered_stamps(3000, seed=6)
    ns = to_ns(t)
    q, _, _ = signal(t)
    q = q + np.random.default_rng(7).normal(0.0, noise, q.shape)
    for mode, bound in (("fixed_lag", 2e-3 if noise == 0 else 0.02), ("causal", 0.1)):
        estimator = StreamingEstimator(NAMES, settings=StreamSettings(mode=mode))
        stamps, _, _, qdd = stacked(feed(estimator, ns, q))
        _, _, qdd_true = truth_at(stamps, t, ns)
        steady = slice(250, None)  # (causal: from a start, its first estimate waits for the record, 0.2 + 0.15 s)
        assert relative_rms(qdd[steady], qdd_true[steady]) <= bound, mode
        if mode == "causal":  # stamped with the newest sample, and no measurable lag behind it
            assert np.array_equal(stamps, ns)
            t_out = (stamps - EPOCH_NS) / 1e9
            delays = np.arange(-0.02, 0.0601, 0.002)
            errors = [relative_rms(qdd[steady], signal(t_out - d)[2][steady]) for d in delays]
            assert abs(delays[int(np.argmin(errors))]) <= 0.01


def test_message_velocities_are_used_or_ignored_as_configured() -> None:
    t = jittered_stamps(600, seed=8)
    ns = to_ns(t)
    q, qd_true, _qdd_true = signal(t)
    offset = 0.5  # a velocity bias that differentiating positions cannot produce: tells the sources apart
    for source, expected_offset in (("auto", offset), ("message", offset), ("differentiate", 0.0)):
        estimator = StreamingEstimator(NAMES, settings=StreamSettings(mode="fixed_lag", velocity_source=source))
        stamps, _, qd, qdd = stacked(feed(estimator, ns, q, velocities=qd_true + offset))
        _, qd_at, qdd_at = truth_at(stamps, t, ns)
        steady = slice(60, None)
        assert relative_rms(qd[steady] - expected_offset, qd_at[steady]) <= 1e-3, source
        assert relative_rms(qdd[steady], qdd_at[steady]) <= 2e-3, source


def test_message_source_without_velocities_differentiates_and_says_so_once() -> None:
    log = LogRecorder()
    t = jittered_stamps(300)
    q, _, _ = signal(t)
    estimator = StreamingEstimator(NAMES, settings=StreamSettings(velocity_source="message"), log=log)
    stamps, _, _, qdd = stacked(feed(estimator, to_ns(t), q))
    assert log.count("has no velocity") == 2  # once per joint
    _, _, qdd_true = truth_at(stamps, t, to_ns(t))
    assert relative_rms(qdd[60:], qdd_true[60:]) <= 5e-3


def test_continuous_joint_is_unwrapped_across_pi() -> None:
    t = jittered_stamps(1000)
    angle = 3.0 + 6.0 * t + 0.3 * np.sin(4.0 * t)  # turns about once a second
    wrapped = np.angle(np.exp(1j * angle))
    estimator = StreamingEstimator(["c"], wrap=[True], settings=StreamSettings(mode="fixed_lag"))
    stamps, _, qd, qdd = stacked(feed(estimator, to_ns(t), wrapped[:, None], names=["c"]))
    index = np.searchsorted(to_ns(t), stamps)
    assert np.isfinite(qd[50:]).all()
    assert np.nanmax(np.abs(qd[:, 0] - (6.0 + 1.2 * np.cos(4.0 * t[index])))) <= 1e-3
    assert np.max(np.abs(qdd[60:, 0] + 4.8 * np.sin(4.0 * t[index][60:]))) <= 1e-2


def test_partial_messages_from_two_drivers_keep_per_joint_histories_and_ages() -> None:
    """Arm joint 'a' at 500 Hz and gripper joint 'b' at 100 Hz, in separate messages. Their stamps are
    irregular (+-10 % of a period): from the start, each stream's estimates wait until its clock has a
    first look at whether they are write times (40 samples, 0.4 s for the gripper: the estimates from
    0.35 s on, 175 arm messages)."""
    t = jittered_stamps(1500, seed=9)
    ns = to_ns(t)
    q, _, _ = signal(t)
    estimator = StreamingEstimator(NAMES, settings=StreamSettings(mode="fixed_lag"))
    out = []
    for k in range(len(t)):
        out += estimator.update(int(ns[k]), ["a"], [q[k, 0]])
        if k % 5 == 0:
            out += estimator.update(int(ns[k]), ["b"], [q[k, 1]])
    stamps, _, _qd, qdd = stacked(out)
    _, _qd_true, qdd_true = truth_at(stamps, t, ns)
    ready = np.array([e.all_ready for e in out])
    assert ready[175:].all()
    assert relative_rms(qdd[175:, 0], qdd_true[175:, 0]) <= 2e-3
    assert relative_rms(qdd[175:, 1], qdd_true[175:, 1]) <= 2e-2  # fewer samples for the gripper
    ages = np.array([e.ages for e in out])
    assert np.all(ages[:, 0] == 0.0)  # every stamp is an arm sample
    assert 0.0 < ages[175:, 1].max() <= 0.011  # the gripper's newest sample is up to 5 periods old
    assert np.all(estimator.ages() >= 0.0)


def test_duplicated_stamps_are_skipped() -> None:
    t = jittered_stamps(400)
    ns = to_ns(t)
    q, _, _ = signal(t)
    once = stacked(feed(StreamingEstimator(NAMES), ns, q))
    twice = stacked(feed(StreamingEstimator(NAMES), np.repeat(ns, 2), np.repeat(q, 2, axis=0)))
    for a, b in zip(once, twice, strict=True):
        np.testing.assert_array_equal(a, b)


def test_stamps_going_backwards_restart_with_one_log_line_and_later_estimates_are_right() -> None:
    log = LogRecorder()
    t = jittered_stamps(600)
    ns = to_ns(t)
    q, _, _ = signal(t)
    estimator = StreamingEstimator(NAMES, settings=StreamSettings(mode="fixed_lag"), log=log)
    first = feed(estimator, ns, q)
    looped = feed(estimator, ns, q)  # a bag playing in a loop
    assert log.count("went back in time") == 1
    assert {e.segment for e in first} == {0} and {e.segment for e in looped} == {0, 1}
    # The first segment's last lag is flushed at the loop rather than lost.
    old = [e.stamp_ns for e in looped if e.segment == 0]
    assert [e.stamp_ns for e in first] + old == list(ns)
    again = [e for e in looped if e.segment == 1]
    stamps, _, _, qdd = stacked(again)
    _, _, qdd_true = truth_at(stamps, t, ns)
    assert relative_rms(qdd[60:], qdd_true[60:]) <= 2e-3
    assert np.all(np.diff(stamps) > 0)


def test_a_gap_longer_than_max_gap_restarts_the_history() -> None:
    log = LogRecorder()
    t = jittered_stamps(1000)
    ns = to_ns(t)
    q, _, _ = signal(t)
    q[500:] += 2.0  # the joint moved while nothing was heard: old samples must not be used
    keep = np.r_[0:250, 500:1000]  # half a second missing
    estimator = StreamingEstimator(NAMES, settings=StreamSettings(mode="causal", max_gap=0.3), log=log)
    out = feed(estimator, ns[keep], q[keep])
    assert log.count("history restarted") == 1  # throttled: both joints, one line
    after = [e for e in out if e.stamp_ns >= ns[500]]
    assert not after[0].all_ready  # one sample: no estimate yet
    stamps, positions, _, qdd = stacked(after[110:])  # the causal fit's 0.2 s window is full
    _, _, qdd_true = truth_at(stamps, t, ns)
    assert relative_rms(qdd, qdd_true) <= 0.1
    np.testing.assert_array_equal(positions, q[np.searchsorted(ns, stamps)])


def test_nan_and_inf_drop_the_field_and_later_estimates_are_right() -> None:
    log = LogRecorder()
    t = jittered_stamps(800)
    ns = to_ns(t)
    q, qd_true, _ = signal(t)
    velocities = qd_true.copy()
    positions = q.copy()
    positions[300, 0] = np.nan
    positions[301, 1] = np.inf
    velocities[400:402, 0] = np.nan
    estimator = StreamingEstimator(NAMES, settings=StreamSettings(mode="fixed_lag"), log=log)
    out = feed(estimator, ns, positions, velocities)
    # one line per kind (the second NaN position, a moment later, is within the throttle period)
    assert log.count("non-finite position of 1 joint: 'a'") == 1 and log.count("non-finite velocities") == 1
    stamps, out_positions, qd, qdd = stacked(out)
    assert np.all(np.isfinite(out_positions[60:])) and np.all(np.isfinite(qdd[60:]))
    _, qd_at, qdd_at = truth_at(stamps, t, ns)
    assert relative_rms(qdd[60:], qdd_at[60:]) <= 2e-3
    assert np.max(np.abs(qd[60:] - qd_at[60:])) < 3e-3  # differentiated positions where velocity was NaN


@pytest.mark.parametrize(
    "names, positions, velocities, text",
    [
        (["a", "b"], [0.0], [], "2 names but 1 positions"),
        (["a", "b"], ["x", "y"], [], "positions are not numbers"),
        (["a", "b"], None, [1.0], "velocities ignored: 1 values for 2 names"),
        (["a", "b"], None, ["fast", "slow"], "velocities are not numbers"),
    ],
)
def test_malformed_messages_are_logged_not_raised(names, positions, velocities, text) -> None:
    log = LogRecorder()
    t = jittered_stamps(400)
    ns = to_ns(t)
    q, _, _qdd_true = signal(t)
    estimator = StreamingEstimator(NAMES, log=log)
    out = feed(estimator, ns[:200], q[:200])
    positions = list(q[200]) if positions is None else positions  # a good sample with a bad velocity field
    out += estimator.update(int(ns[200]), names, positions, velocities)
    assert log.count(text) == 1
    out += feed(estimator, ns[201:], q[201:])
    stamps, _, _, qdd = stacked(out[60:])
    _, _, qdd_at = truth_at(stamps, t, ns)
    assert relative_rms(qdd, qdd_at) <= 2e-3


def test_unknown_names_warn_once_each_and_ignored_names_not_at_all() -> None:
    log = LogRecorder()
    estimator = StreamingEstimator(NAMES, ignored_names=["mimic"], log=log)
    for k in range(5):
        estimator.update(EPOCH_NS + k * 2_000_000, ["a", "ghost", "b", "mimic"], [0.0, 1.0, 0.0, 2.0])
    assert log.count("'ghost'") == 1
    assert log.count("mimic") == 0
    assert len(log.lines) == 1


def test_zero_stamps_use_the_receive_time_and_say_so_once() -> None:
    log = LogRecorder()
    t = jittered_stamps(300)
    q, _, _ = signal(t)
    estimator = StreamingEstimator(NAMES, log=log)
    out = []
    for k, receive in enumerate(to_ns(t)):
        out += estimator.update(0, list(NAMES), list(q[k]), receive_ns=int(receive))
    out += estimator.flush()
    assert log.count("zero header.stamp") == 1
    assert [e.stamp_ns for e in out] == list(to_ns(t))
    assert estimator.update(0, list(NAMES), [0.0, 0.0]) == []  # and no receive time: dropped, logged
    assert log.count("zero stamp and no receive time") == 1


def test_joints_never_heard_are_not_ready_and_nan() -> None:
    estimator = StreamingEstimator(NAMES, settings=StreamSettings(mode="causal"))
    out = []
    for k in range(250):  # 0.5 s: more than the 0.2 s window the causal fit needs, and its record (about 0.15 s)
        out += estimator.update(EPOCH_NS + k * 2_000_000, ["a"], [0.01 * k * k])
    last = out[-1]
    assert last.ready.tolist() == [True, False]
    assert np.isnan(last.accelerations[1]) and np.isinf(last.ages[1])
    assert last.accelerations[0] == pytest.approx(0.02 / 0.002**2, rel=1e-9)


@pytest.mark.parametrize(
    "kwargs, text",
    [
        ({"mode": "instant"}, "unknown mode 'instant'"),
        ({"velocity_source": "magic"}, "unknown velocity_source 'magic'"),
        ({"lag": 0.5}, "lag must be between 0 and window"),
        ({"max_gap": 0.0}, "max_gap must be a positive"),
        ({"window": 0.0}, "window must be a positive"),
    ],
)
def test_bad_settings_raise(kwargs, text) -> None:
    with pytest.raises(InputError, match=text):
        StreamSettings(**kwargs)


messages = st.lists(
    st.tuples(
        st.sampled_from([0, 1, 1, 1, 2, -1, -30]),  # stamp step in ms: duplicates, forward, backwards
        st.lists(st.sampled_from(["a", "b", "c", "unknown"]), min_size=0, max_size=4),
        st.lists(st.sampled_from([0.0, 0.5, -1.0, np.nan, np.inf, 3.1]), min_size=0, max_size=4),
        st.sampled_from(["none", "same", "short"]),
    ),
    max_size=80,
)


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(messages, st.sampled_from(["causal", "fixed_lag"]), st.sampled_from(["polyfit", "kalman", "difference"]))
def test_random_message_sequences_never_raise_never_emit_nan_for_ready_joints(sequence, mode, method) -> None:
    estimator = StreamingEstimator(
        ["a", "b", "c"], wrap=[False, True, False], settings=StreamSettings(mode=mode, method=method, lag=0.004)
    )
    stamp = EPOCH_NS
    newest = stamp
    out = []
    for step_ms, names, values, velocity_kind in sequence:
        stamp += step_ms * 1_000_000
        newest = max(newest, stamp)
        positions = (values * 4)[: len(names)] if values else [0.0] * len(names)
        if len(values) == 1:
            positions = positions[:-1]  # sometimes a length mismatch
        velocities = {"none": [], "same": list(reversed(positions)), "short": positions[:1]}[velocity_kind]
        out += estimator.update(stamp, names, positions, velocities)
    # Then, after more than max_gap, clean input: a constant acceleration of 2 on every joint. More than
    # max_gap after the newest stamp sent: the stamps may have gone back since (once this took the last
    # one, and a joint's history went on across a 0.48 s silence and a jump, as it should).
    restart = max([newest, *(e.stamp_ns for e in out)]) + 600_000_000
    clean = []
    for k in range(250):  # 0.5 s: the supports (0.2 s) are covered from 0.2 s on (a start's record: about 0.15 s more)
        tk = k * 0.002
        clean += estimator.update(restart + k * 2_000_000, ["a", "b", "c"], [tk * tk, 0.1 + tk * tk, tk * tk])
    clean += estimator.flush()
    ready = [e for e in clean if e.all_ready]
    assert len(ready) >= 40
    # kalman: noise-free samples give the bank a noise of rounding size (an encoder step read from t^2's
    # smallest change), under which its models' likelihoods, and so their weights, turn on rounding: the
    # slowest model (0.6 s) still weighs a little 0.3 s after the restart (found by this test: 1.4e-3)
    np.testing.assert_allclose(ready[-1].accelerations, 2.0, rtol=1e-6 if method != "kalman" else 5e-3)
    out += clean
    for estimate in out:
        finite = (
            np.isfinite(estimate.positions) & np.isfinite(estimate.velocities) & np.isfinite(estimate.accelerations)
        )
        assert np.array_equal(finite, estimate.ready)
    for previous, current in itertools.pairwise(out):
        if current.segment == previous.segment:
            assert current.stamp_ns > previous.stamp_ns
        else:
            assert current.segment > previous.segment
