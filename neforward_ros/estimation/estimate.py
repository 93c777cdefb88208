"""One stamp's joint states, as the streaming estimator gives them."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class JointEstimate:
    """The state of every joint at one stamp.

    Arrays are in the estimator's joint order. A joint that is not ``ready`` has NaN entries: no
    sample yet, none for longer than max_gap, or samples that do not yet cover the estimator's
    support around the stamp (after a start, a restart, a gap or a model reload).

    Attributes:
        stamp_ns: the stamp the estimate refers to, integer nanoseconds (the input's clock).
        segment: counts history restarts caused by time going backwards; stamps increase strictly
            within a segment.
        positions: rad or m.
        velocities: rad/s or m/s.
        accelerations: rad/s^2 or m/s^2.
        ages: seconds from each joint's newest sample at or before the stamp to the stamp.
        ready: per joint, whether the entries are estimates.
        efforts: the efforts the messages carried (N m or N), at the stamp: a sample's own at its
            stamp, else interpolated between the samples around it; NaN where there are none. None
            when not known at all (supplied states without efforts).
        acceleration_std: the estimate's own standard deviation of each acceleration (from the
            noise read from the samples: the fit's, or the filter's or smoother's posterior scaled by
            the recent innovations), rad/s^2 (m/s^2); NaN where the estimator does not give one; None
            when not known at all.
    """

    stamp_ns: int
    segment: int
    positions: np.ndarray
    velocities: np.ndarray
    accelerations: np.ndarray
    ages: np.ndarray
    ready: np.ndarray
    efforts: np.ndarray | None = None
    acceleration_std: np.ndarray | None = None

    @property
    def all_ready(self) -> bool:
        return bool(np.all(self.ready))
