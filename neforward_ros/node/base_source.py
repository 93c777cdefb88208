"""The base's motion from a base IMU or odometry, aligned to the joint states' stamps.

:class:`BaseTracker` takes the base messages as they come (``sensor_msgs/Imu`` or
``nav_msgs/Odometry``, decoded), estimates what they do not carry with the same streaming estimator
as the joints (angular acceleration from the IMU's angular velocity; linear and angular
acceleration from the odometry's twist), and answers, for a joint-state stamp, the motion of the
link the source measures at that stamp: interpolated between its estimates on either side, or
"not yet" when the base estimates have not reached the stamp, or None with the reason when they
never will (a gap, a reset, a stamp older than what is kept). The link's motion becomes the root's
with :func:`neforward_ros.base.base_from_link`.
"""

from __future__ import annotations

import logging
import math
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from neforward_ros.estimation.settings import StreamSettings
from neforward_ros.estimation.stream import StreamingEstimator
from neforward_ros.logs import LogFunction, ThrottledLog
from neforward_ros.rotations import rotation_matrix
from neforward_ros.stamps import NS

BASE_SOURCES = ("fixed", "imu", "odometry")
NOT_YET = "not yet"


@dataclass(frozen=True)
class BaseMessage:
    """A base source's message, decoded.

    Attributes:
        stamp_ns: header stamp (0: not set, the receive time is used).
        frame_id: the frame it measures: an Imu's header.frame_id, an Odometry's child_frame_id.
        omega: angular velocity in that frame, rad/s.
        linear: an Imu's linear_acceleration (the specific force), or an Odometry's linear velocity
            in the child frame.
        orientation: (x, y, z, w) of that frame in the world; None when the message has none.
        position: an Odometry's position of that frame in the world; None for an Imu.
        receive_ns: when it was received.
    """

    stamp_ns: int
    frame_id: str
    omega: Sequence[float]
    linear: Sequence[float]
    orientation: Sequence[float] | None
    position: Sequence[float] | None = None
    receive_ns: int | None = None


@dataclass(frozen=True)
class LinkSample:
    """The motion of the link a base source measures, at one stamp, in that link's frame.

    Attributes:
        omega, alpha: rad/s, rad/s^2.
        specific_force: at the link origin, m/s^2.
        velocity: of the link origin, m/s; None when the source does not give it (an IMU).
        orientation: the link frame in the world frame as a quaternion (x, y, z, w); None if unknown.
        position: the link origin in the world frame, m; None if unknown (an IMU).
    """

    omega: np.ndarray
    alpha: np.ndarray
    specific_force: np.ndarray
    velocity: np.ndarray | None
    orientation: np.ndarray | None
    position: np.ndarray | None


class BaseTracker:
    """Base messages in, the measured link's motion at any covered stamp out.

    Args:
        source: ``"imu"`` or ``"odometry"``.
        settings: the joint estimator's settings (the same mode, lag and window are used).
        gravity: gravity in the world frame, m/s^2 (odometry: the specific force needs it).
        log: ``log(level, message)``.
    """

    KEPT = 4096  # estimates kept for interpolation (seconds at any base rate)

    def __init__(
        self, source: str, settings: StreamSettings, gravity: Sequence[float], log: LogFunction | None = None
    ) -> None:
        self.source = source
        self.gravity = np.asarray(gravity, dtype=float)
        self._log = ThrottledLog(log)
        channels = ("wx", "wy", "wz", "fx", "fy", "fz") if source == "imu" else ("vx", "vy", "vz", "wx", "wy", "wz")
        self._channels = channels
        # The same estimator as the joints', on the base's channels; velocities it is not given.
        self._estimator = StreamingEstimator(
            channels, settings=StreamSettings(**{**settings.__dict__, "velocity_source": "differentiate"}), log=log
        )
        self._poses: deque[tuple[int, np.ndarray | None, np.ndarray | None]] = deque(maxlen=self.KEPT)
        self._estimates: deque[tuple[int, int, np.ndarray, np.ndarray]] = deque(maxlen=self.KEPT)
        self._max_gap_ns = round(settings.max_gap * NS)
        self.frame_id = ""

    # -- input ------------------------------------------------------------------------------

    def on_message(self, message: BaseMessage) -> int:
        """One base message; returns how many new estimates it completed."""
        values = [*message.omega, *message.linear] if self.source == "imu" else [*message.linear, *message.omega]
        return self._add(
            message.stamp_ns, message.frame_id, values, message.orientation, message.position, message.receive_ns
        )

    def _add(self, stamp_ns, frame_id, values, orientation, position, receive_ns) -> int:
        if not all(math.isfinite(v) for v in values):
            self._log.every("base-nan", logging.WARNING, f"base {self.source} message with non-finite values: dropped")
            return 0
        self.frame_id = frame_id or self.frame_id
        pose_orientation = _unit_quaternion(orientation)
        pose_position = np.asarray(position, dtype=float) if position is not None else None
        if pose_position is not None and not np.all(np.isfinite(pose_position)):
            pose_position = None
        estimates = self._estimator.update(stamp_ns, self._channels, values, receive_ns=receive_ns)
        stamp = stamp_ns if stamp_ns > 0 else (receive_ns or 0)
        self._poses.append((stamp, pose_orientation, pose_position))
        count = 0
        for estimate in estimates:
            if estimate.all_ready:
                self._estimates.append((estimate.stamp_ns, estimate.segment, estimate.positions, estimate.velocities))
                count += 1
        return count

    # -- output -----------------------------------------------------------------------------

    def newest(self) -> int | None:
        """The newest stamp with an estimate."""
        return self._estimates[-1][0] if self._estimates else None

    def at(self, stamp_ns: int) -> LinkSample | str:
        """The measured link's motion at the stamp, or why not: ``NOT_YET`` when the estimates have
        not reached it (wait), another reason when they never will (drop)."""
        estimates = self._estimates
        if not estimates or stamp_ns > estimates[-1][0]:
            return NOT_YET
        if stamp_ns < estimates[0][0]:
            return "no base motion that early"
        stamps = [e[0] for e in estimates]
        k = int(np.searchsorted(stamps, stamp_ns, side="right")) - 1
        before = estimates[k]
        after = estimates[min(k + 1, len(estimates) - 1)]
        if after[0] - before[0] > self._max_gap_ns or after[1] != before[1]:
            return "a gap in the base motion"
        weight = 0.0 if after[0] == before[0] else (stamp_ns - before[0]) / (after[0] - before[0])
        values = before[2] + weight * (after[2] - before[2])
        rates = before[3] + weight * (after[3] - before[3])
        orientation, position = self._pose_at(stamp_ns)
        if self.source == "imu":
            omega, alpha, force = values[:3], rates[:3], values[3:]
            return LinkSample(omega, alpha, force, None, orientation, None)
        velocity, omega = values[:3], values[3:]
        acceleration, alpha = rates[:3], rates[3:]
        if orientation is None:
            return "no orientation in the odometry: its specific force needs gravity in the base frame"
        classical = acceleration + np.cross(omega, velocity)  # d/dt of the world velocity, base axes
        gravity_here = _rotate_inverse(orientation, self.gravity)
        return LinkSample(omega, alpha, classical - gravity_here, velocity, orientation, position)

    def _pose_at(self, stamp_ns: int) -> tuple[np.ndarray | None, np.ndarray | None]:
        """The pose samples interpolated at the stamp (normalised linear interpolation of quaternions)."""
        poses = self._poses
        stamps = [p[0] for p in poses]
        k = int(np.searchsorted(stamps, stamp_ns, side="right")) - 1
        if k < 0:
            return None, None
        before, after = poses[k], poses[min(k + 1, len(poses) - 1)]
        weight = 0.0 if after[0] == before[0] else min(max((stamp_ns - before[0]) / (after[0] - before[0]), 0.0), 1.0)
        orientation = None
        if before[1] is not None and after[1] is not None:
            other = after[1] if np.dot(before[1], after[1]) >= 0 else -after[1]
            mixed = before[1] + weight * (other - before[1])
            orientation = mixed / np.linalg.norm(mixed)
        position = None
        if before[2] is not None and after[2] is not None:
            position = before[2] + weight * (after[2] - before[2])
        return orientation, position

    def forget_before(self, stamp_ns: int) -> None:
        """Drop what no later stamp needs: estimates and poses older than the one at or before it."""
        for queue in (self._estimates, self._poses):
            while len(queue) > 2 and queue[1][0] <= stamp_ns:
                queue.popleft()


def _unit_quaternion(values: Sequence[float] | None) -> np.ndarray | None:
    if values is None:
        return None
    q = np.asarray(values, dtype=float)
    norm = float(np.linalg.norm(q)) if q.shape == (4,) and np.all(np.isfinite(q)) else 0.0
    return q / norm if norm > 0.5 else None  # all zeros: "no orientation" by convention


def _rotate_inverse(q: np.ndarray, vector: np.ndarray) -> np.ndarray:
    """R(q)^T v: a world vector in the frame q orients."""
    return rotation_matrix(q).T @ vector


class Aligner:
    """Joint estimates waiting for the base motion at their stamps.

    Estimates are released, in stamp order, once the base estimates cover their stamps; an estimate
    the base motion will never cover (a gap, a reset, a stamp older than what is kept) or that has
    waited ``max_delay`` (by the joint stamps' clock) is dropped with a throttled warning.
    """

    def __init__(self, tracker: BaseTracker, max_delay: float, log: LogFunction | None = None) -> None:
        self.tracker = tracker
        self._max_delay_ns = round(max_delay * NS)
        self._waiting: deque = deque()
        self._newest = 0
        self._log = ThrottledLog(log)

    def add(self, estimates: Sequence) -> None:
        for estimate in estimates:
            self._waiting.append(estimate)
            self._newest = max(self._newest, estimate.stamp_ns)

    def ready(self) -> list[tuple[object, LinkSample]]:
        """(estimate, the measured link's motion at its stamp) for every estimate now covered."""
        out = []
        waiting = self._waiting
        while waiting:
            estimate = waiting[0]
            sample = self.tracker.at(estimate.stamp_ns)
            if isinstance(sample, LinkSample):
                out.append((waiting.popleft(), sample))
                continue
            if sample == NOT_YET and self._newest - estimate.stamp_ns <= self._max_delay_ns:
                break  # the base messages may still come
            waiting.popleft()
            why = "none came within base.max_delay" if sample == NOT_YET else sample
            self._log.every(
                ("base-missing", why),
                logging.WARNING,
                f"nothing published for a joint state: no base motion at its stamp ({why})",
            )
        if out:
            self.tracker.forget_before(out[-1][0].stamp_ns)
        return out
