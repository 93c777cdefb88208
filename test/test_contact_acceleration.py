"""The contact detector beyond the calibrated accelerations (neforward_ros.computation.contact): a
model identified on a motion is not trusted beyond its accelerations, so every moving threshold grows
by the largest |acceleration| / calibrated largest among the joints (at least 1). Expected states
derived by hand; the accelerations read against the exact ones."""

from __future__ import annotations

import numpy as np

from neforward_ros.computation.contact import ACCELERATION_SPAN, ContactDetector
from neforward_ros.logs import ThrottledLog

STEP = 10_000_000  # 100 Hz
DEBOUNCE = 0.03


def states(external: np.ndarray, velocity: np.ndarray, accelerations: list[float] | None) -> list[bool]:
    """The detector (thresholds 10, the debounce 30 ms) on (T, n) external torques and velocities."""
    n = external.shape[1]
    detector = ContactDetector(np.full(n, 10.0), DEBOUNCE, tuple(f"j{k}" for k in range(n)),
                               ThrottledLog(lambda *_: None), 0.6, None,
                               None if accelerations is None else np.array(accelerations))  # fmt: skip
    stamps = np.arange(len(external), dtype=np.int64) * STEP
    usable = np.ones(len(external), dtype=bool)
    return [bool(x) for x in detector.update_many(stamps, external, usable, velocity=velocity)]


def ramp(acceleration: float, count: int = 20) -> np.ndarray:
    """A velocity growing at ``acceleration`` rad/s^2, sampled at 100 Hz: (count, 1)."""
    return (acceleration * np.arange(count) * STEP / 1e9)[:, None]


def test_a_torque_over_the_threshold_during_an_acceleration_beyond_the_calibrated_is_no_contact() -> None:
    """25 over a threshold of 10 from the fourth stamp on. At 6 rad/s^2 against a calibrated 2, the
    threshold is 30 once the velocities span 20 ms (the third stamp): no contact. At 1 rad/s^2, or
    without calibrated accelerations, 30 ms after the first stamp over: a contact."""
    pushed = np.where(np.arange(20) >= 3, 25.0, 0.0)[:, None]
    assert not any(states(pushed, ramp(6.0), [2.0]))
    assert states(pushed, ramp(1.0), [2.0]) == [False] * 6 + [True] * 14
    assert states(pushed, ramp(6.0), None) == [False] * 6 + [True] * 14
    # 35 is over even the grown threshold (30): a contact all the same
    assert states(pushed + 10.0 * (pushed > 0), ramp(6.0), [2.0]) == [False] * 6 + [True] * 14


def test_one_joints_hard_stop_grows_every_joints_threshold() -> None:
    """Joint 0 decelerates at 6 rad/s^2 (3x its calibrated 2); joint 1, still, sees 25: no contact,
    the inertia matrix couples the joints' errors. Joint 0 at 1 rad/s^2: joint 1's 25 is a contact."""
    external = np.zeros((20, 2))
    external[3:, 1] = 25.0
    still = np.zeros((20, 1))
    assert not any(states(external, np.hstack([1.0 - ramp(6.0), still]), [2.0, 2.0]))
    assert any(states(external, np.hstack([1.0 - ramp(1.0), still]), [2.0, 2.0]))


def test_the_acceleration_is_read_over_a_span_not_one_sample() -> None:
    """At 1 kHz, velocities of a 3 rad/s^2 ramp with a noise of 1e-3 rad/s: read over the last 20 ms,
    the acceleration's error has a standard deviation of about 1e-3 * sqrt(2) / 0.02 = 0.07 rad/s^2; a
    one-sample difference would have about 1.4."""
    rng = np.random.default_rng(3)
    count = 2000
    stamps = np.arange(count, dtype=np.int64) * 1_000_000
    velocity = (3.0 * stamps / 1e9 + rng.normal(0.0, 1e-3, count))[:, None]
    detector = ContactDetector(np.full(1, 10.0), DEBOUNCE, ("j0",), ThrottledLog(lambda *_: None))
    read = detector.accelerations_of(stamps, velocity)[:, 0]
    first = round(ACCELERATION_SPAN * 1000)
    assert np.isnan(read[:first]).all() and np.isfinite(read[first:]).all()
    error = read[first:] - 3.0
    assert abs(error.mean()) < 0.01 and error.std() < 0.1, (error.mean(), error.std())
