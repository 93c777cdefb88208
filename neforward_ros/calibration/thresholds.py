"""Contact thresholds from the distribution of a free motion's external torques, which one outlier cannot blind.

The external torques the node publishes on free motion with the fitted parameters are what a
threshold must stay above. Their largest value is not a measure of that: a real arm's recording has
short excursions (a sample or two where the model misses a sudden stop, a stamp glitch) far above
everything else, and a threshold set by one of them makes detection blind. So, per joint:

- the samples are split by speed into :data:`SPEED_BINS` groups of equal size (friction makes the
  residual depend on speed), each of at least :data:`MIN_BIN` samples (fewer samples: one group);
- each group's :data:`QUANTILE` quantile of |external torque| is taken, and the threshold is
  :data:`MARGIN` times the largest of them (at least :data:`FLOOR`);
- what the thresholds leave above them in the free motion is reported as outliers: stretches of
  consecutive samples over some joint's threshold (an *excursion*), with their length, joint, value
  and time. The contact debounce is made longer than the longest excursion up to
  :data:`MAX_DEBOUNCE` (one sample interval more), so that what the free motion did raises no
  contact; a longer stretch over the thresholds is said (a contact during the calibration motion?).

The largest |acceleration| of each joint in the free motion is kept too (``contact.accelerations``):
beyond it the model was never checked, and the detector grows the thresholds in proportion.

Where the recordings hold the arm still (every joint slower than its friction's velocity scale for
:data:`neforward_ros.computation.contact.REST_DWELL`), the rest thresholds are measured the same way
on what the detector's rest test watches there, the external torques' departure from their baseline
(:mod:`neforward_ros.computation.contact`): :data:`MARGIN` times its :data:`QUANTILE` quantile, from at
least :data:`MIN_REST` samples at rest.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from neforward_ros.stamps import NS

QUANTILE = 0.99
"""The quantile of |external torque| in each speed group."""
MARGIN = 3.0
"""Thresholds: this many times the largest group quantile."""
SPEED_BINS = 3
"""Speed groups per joint (terciles of |velocity|)."""
MIN_BIN = 200
"""The fewest samples a speed group has; fewer samples make one group."""
FLOOR = 0.05
"""N m (N): the least contact threshold."""
MIN_REST = 100
"""The fewest samples at rest the rest thresholds are measured on."""
MAX_DEBOUNCE = 0.1
"""s: the longest debounce chosen to ride over the free motion's excursions."""
ACCELERATION_QUANTILE = 0.999
"""The quantile of |acceleration| taken as the free motion's largest (``contact.accelerations``)."""
LEAST_ACCELERATION = 0.01
"""rad/s^2 (m/s^2): the least ``contact.accelerations`` written (a joint the free motion never moved)."""


@dataclass(frozen=True)
class Excursion:
    """A stretch of consecutive samples of one recording over some joint's threshold.

    Attributes:
        recording: the index of its recording.
        start_s, seconds: its start (s since its recording's first sample) and length (s, first to
            last sample).
        samples: how many samples.
        joint: the column of the joint furthest over its threshold, ``value`` its external torque
            there (N m or N), ``ratio`` the value over the threshold.
    """

    recording: int
    start_s: float
    seconds: float
    samples: int
    joint: int
    value: float
    ratio: float


def robust_thresholds(external: np.ndarray, velocity: np.ndarray, watched: np.ndarray) -> np.ndarray:
    """Per joint, the contact threshold (see the module docstring); NaN for joints not ``watched``.

    Args:
        external: (T, n) the free motion's external torques, NaN where unknown.
        velocity: (T, n) the joint velocities at the same samples.
        watched: (n,) bool, the joints to threshold (those with a measured effort).
    """
    n = external.shape[1]
    out = np.full(n, np.nan)
    for j in np.flatnonzero(watched):
        known = np.isfinite(external[:, j]) & np.isfinite(velocity[:, j])
        values, speeds = np.abs(external[known, j]), np.abs(velocity[known, j])
        if not len(values):
            out[j] = FLOOR
            continue
        groups = SPEED_BINS if len(values) >= SPEED_BINS * MIN_BIN else 1
        order = np.argsort(speeds, kind="stable")
        level = max(float(np.quantile(values[part], QUANTILE)) for part in np.array_split(order, groups))
        out[j] = max(MARGIN * level, FLOOR)
    return out


def largest_accelerations(accelerations: np.ndarray, watched: np.ndarray) -> np.ndarray:
    """Per joint, the largest |acceleration| of the free motion as the contact detector reads it
    (``accelerations`` (T, n), NaN where it reads none: :meth:`.ContactDetector.accelerations_of`),
    rad/s^2 (m/s^2): its :data:`ACCELERATION_QUANTILE` quantile (a stamp glitch is no acceleration), at
    least :data:`LEAST_ACCELERATION`; NaN for joints not ``watched``."""
    out = np.full(accelerations.shape[1], np.nan)
    for j in np.flatnonzero(watched):
        known = accelerations[np.isfinite(accelerations[:, j]), j]
        level = float(np.quantile(known, ACCELERATION_QUANTILE)) if len(known) else 0.0
        out[j] = max(level, LEAST_ACCELERATION)
    return out


def rest_thresholds(departures: np.ndarray, watched: np.ndarray) -> np.ndarray | None:
    """Per joint, the rest threshold (see the module docstring) from the free motion's departures
    from the rest baseline ((T, n), NaN where the arm is not at rest); None where fewer than
    :data:`MIN_REST` samples are at rest; NaN for joints not ``watched``."""
    out = np.full(departures.shape[1], np.nan)
    for j in np.flatnonzero(watched):
        values = np.abs(departures[np.isfinite(departures[:, j]), j])
        if len(values) < MIN_REST:
            return None
        out[j] = max(MARGIN * float(np.quantile(values, QUANTILE)), FLOOR)
    return out


def excursions(
    external: np.ndarray, stamps_ns: np.ndarray, recording: np.ndarray, thresholds: np.ndarray
) -> list[Excursion]:
    """The stretches of the free motion over the thresholds, in recording order (see :class:`Excursion`);
    ``stamps_ns`` (T,) int and ``recording`` (T,) int say where each sample is."""
    limits = np.where(np.isfinite(thresholds), thresholds, np.inf)
    ratio = np.where(np.isfinite(external), np.abs(external), 0.0) / limits
    over = (ratio > 1.0).any(axis=1)
    edges = np.flatnonzero(np.diff(np.r_[0, over.astype(np.int8), 0]))
    out = []
    for a, b in zip(edges[::2].tolist(), edges[1::2].tolist(), strict=True):
        for part in np.split(np.arange(a, b), np.flatnonzero(np.diff(recording[a:b])) + 1):
            first, last = int(part[0]), int(part[-1])
            row, joint = np.unravel_index(int(np.argmax(ratio[first : last + 1])), ratio[first : last + 1].shape)
            k = int(recording[first])
            origin = int(stamps_ns[np.argmax(recording == k)])
            out.append(
                Excursion(
                    recording=k,
                    start_s=(int(stamps_ns[first]) - origin) / NS,
                    seconds=(int(stamps_ns[last]) - int(stamps_ns[first])) / NS,
                    samples=last - first + 1,
                    joint=int(joint),
                    value=float(external[first + int(row), int(joint)]),
                    ratio=float(ratio[first + int(row), int(joint)]),
                )
            )
    return out


def debounce_over(found: list[Excursion], interval: float, least: float) -> float:
    """The contact debounce, s: at least ``least``, and longer than every excursion up to
    :data:`MAX_DEBOUNCE` by ``interval`` (the sample interval), so that they raise no contact."""
    ridden = [e.seconds for e in found if e.seconds + interval <= MAX_DEBOUNCE]
    longest = max(ridden, default=-np.inf) + interval
    return float(max(least, min(longest, MAX_DEBOUNCE)))
