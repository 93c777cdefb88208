"""Measured joint states of every joint at the newest stamp: the momentum observer's input.

The observer (:mod:`.observer`) needs every joint's position and velocity at one stamp. Messages
that passed the node's checks (:mod:`neforward_ros.estimation.joint_messages`,
:mod:`neforward_ros.estimation.timeline`) come here in order; each joint's newest sample is kept,
and a message whose stamp is newer than any before gives the states of that stamp, with each joint's
newest sample (a driver that sends every joint in one message: all of that message). Nothing is
given while some joint has no sample within max_gap, or no velocity; the observer restarts after
such a stretch, after a time reset, and at the start.

The node feeds it message by message; the bag tool feeds it a recording's messages in the same
order, so that both observe the same samples.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from neforward_ros.computation.observer import RawStates


class RawAssembler:
    """See the module docstring.

    Args:
        joints: how many joints (the model's columns).
        max_gap_ns: the estimator's max_gap, ns.
    """

    def __init__(self, joints: int, max_gap_ns: int) -> None:
        self._max_gap = max_gap_ns
        self.q = np.full(joints, np.nan)
        self.qd = np.full(joints, np.nan)
        self.efforts = np.full(joints, np.nan)
        self.stamps = np.full(joints, np.iinfo(np.int64).min // 2, dtype=np.int64)
        self._last: int | None = None  # the newest stamp given
        self._pending_restart = True
        self.missing_velocity = False  # whether the last refusal was for want of velocities

    def restart(self) -> None:
        """A new stream (time went back): forget every sample."""
        self.__init__(len(self.q), self._max_gap)  # type: ignore[misc]

    def add(
        self, stamp: int, joints: Sequence[int], q: Sequence[float], qd: Sequence[float], efforts: Sequence[float]
    ) -> RawStates | None:
        """One message's samples (joint indices and their values, NaN where not given); the states at
        its stamp, or None."""
        index = np.asarray(joints, dtype=np.intp)
        newer = self.stamps[index] < stamp
        if not newer.all():
            index = index[newer]
            q, qd, efforts = (np.asarray(x, dtype=float)[newer] for x in (q, qd, efforts))
        self.stamps[index] = stamp
        self.q[index], self.qd[index], self.efforts[index] = q, qd, efforts
        if self._last is not None and stamp <= self._last:
            return None
        fresh = bool(np.all(self.stamps >= stamp - self._max_gap))
        moving = bool(np.all(np.isfinite(self.qd)))
        self.missing_velocity = fresh and not moving
        if not (fresh and moving):
            self._pending_restart = True
            return None
        restart = self._pending_restart or self._last is None or stamp - self._last > self._max_gap
        self._pending_restart = False
        self._last = stamp
        return RawStates(stamp, self.q.copy(), self.qd.copy(), self.efforts.copy(), restart)
