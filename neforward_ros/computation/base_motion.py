"""A moving base's motion, from a base IMU or odometry, at the joint states' stamps: one module for the
node (message by message) and the bag tool (a recording's base topic), the same code for both.

- :func:`base_message` decodes a ``sensor_msgs/Imu`` or ``nav_msgs/Odometry`` (its contents, as
  :func:`neforward_ros.wire.rostypes.deserialize` gives them) into a :class:`BaseMessage`.
- :class:`BaseTracker` takes the messages in order and estimates what they do not carry with the
  joints' streaming estimator and settings (angular acceleration from the IMU's angular velocity;
  linear and angular acceleration from the odometry's twist), one estimate per message stamp.
- :func:`motion_at` gives the measured link's motion at joint-state stamps from those estimates:
  linearly interpolated between the estimates on either side (orientation and position between
  the messages' poses), or why not: not yet (the estimates have not reached the stamp: wait), or
  never (earlier than what is kept, a gap longer than max_gap or a time reset between them, an
  odometry without orientation).
- :class:`Aligner` holds the node's joint estimates until the base motion at their stamps is known.
- :func:`root_and_world` turns the link's motion into the root's (the recursion's initial state,
  :func:`neforward_ros.kinematics.root_motion.base_from_link`) and the root's pose in the world.
"""

from __future__ import annotations

import logging
import math
from collections import deque
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from neforward_ros.computation.inputs import LinkMotion
from neforward_ros.estimation.estimate import JointEstimate
from neforward_ros.estimation.settings import StreamSettings
from neforward_ros.estimation.stream import StreamingEstimator
from neforward_ros.kinematics.root_motion import base_from_link, link_pose
from neforward_ros.logs import LogFunction, ThrottledLog
from neforward_ros.model import RobotModel
from neforward_ros.rotations import rotation_matrix
from neforward_ros.stamps import NS, stamp_ns

NOT_YET = "not yet"
NO_ORIENTATION = "no orientation in the odometry: its specific force needs gravity in the base frame"
CHANNELS = {"imu": ("wx", "wy", "wz", "fx", "fy", "fz"), "odometry": ("vx", "vy", "vz", "wx", "wy", "wz")}
"""The estimated channels of each source: an IMU's angular velocity and specific force, an odometry's
linear and angular velocity (in the measured link's frame)."""


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
        receive_ns: when it was received (a recording: when it was recorded).
    """

    stamp_ns: int
    frame_id: str
    omega: Sequence[float]
    linear: Sequence[float]
    orientation: Sequence[float] | None
    position: Sequence[float] | None = None
    receive_ns: int | None = None


def _xyz(vector: dict) -> list[float]:
    return [vector["x"], vector["y"], vector["z"]]


def base_message(source: str, contents: dict, receive_ns: int | None = None) -> BaseMessage:
    """A ``sensor_msgs/Imu`` (``source`` "imu") or ``nav_msgs/Odometry`` ("odometry") as contents."""
    if source == "imu":
        q = contents["orientation"]
        return BaseMessage(
            stamp_ns(contents["header"]["stamp"]),
            contents["header"]["frame_id"],
            _xyz(contents["angular_velocity"]),
            _xyz(contents["linear_acceleration"]),
            # REP-145: an orientation covariance starting with -1 means "no orientation"
            [q["x"], q["y"], q["z"], q["w"]] if contents["orientation_covariance"][0] != -1.0 else None,
            None,
            receive_ns,
        )
    pose, twist = contents["pose"]["pose"], contents["twist"]["twist"]
    q = pose["orientation"]
    return BaseMessage(
        stamp_ns(contents["header"]["stamp"]),
        contents["child_frame_id"],
        _xyz(twist["angular"]),
        _xyz(twist["linear"]),
        [q["x"], q["y"], q["z"], q["w"]],
        _xyz(pose["position"]),
        receive_ns,
    )


@dataclass(frozen=True)
class BaseTrack:
    """A base source's estimates and poses, as arrays.

    Attributes:
        stamps: (N,) the estimates' stamps, increasing within a segment; segments: (N,) their segments.
        values, rates: (N, 6) the channels (:data:`CHANNELS`) and their time derivatives.
        pose_stamps: (M,) the messages' stamps; orientation (M, 4) and position (M, 3), NaN where a
            message has none.
    """

    stamps: np.ndarray
    segments: np.ndarray
    values: np.ndarray
    rates: np.ndarray
    pose_stamps: np.ndarray
    orientation: np.ndarray
    position: np.ndarray


def motion_at(
    track: BaseTrack, stamps: Any, link: str, source: str, gravity: Sequence[float], max_gap_ns: int
) -> tuple[LinkMotion, list[str | None]]:
    """The measured link's motion at joint-state stamps ((T,) int ns), and per stamp None where it is
    known, else why not (:data:`NOT_YET`, or why never). Rows where it is not known hold NaN."""
    targets = np.asarray(stamps, dtype=np.int64)
    count = len(targets)
    reasons: list[str | None] = [None] * count
    n = len(track.stamps)
    nan = np.full((count, 6), np.nan)
    values, rates = nan, nan.copy()
    if n:
        k = np.searchsorted(track.stamps, targets, side="right") - 1
        before = np.clip(k, 0, n - 1)
        after = np.minimum(before + 1, n - 1)
        span = track.stamps[after] - track.stamps[before]
        weight = np.where(span > 0, (targets - track.stamps[before]) / np.where(span > 0, span, 1), 0.0)[:, None]
        values = track.values[before] + weight * (track.values[after] - track.values[before])
        rates = track.rates[before] + weight * (track.rates[after] - track.rates[before])
        gap = (span > max_gap_ns) | (track.segments[after] != track.segments[before])
    for i, target in enumerate(targets.tolist()):
        if not n or target > track.stamps[-1]:
            reasons[i] = NOT_YET
        elif target < track.stamps[0]:
            reasons[i] = "no base motion that early"
        elif gap[i]:
            reasons[i] = "a gap in the base motion"
    orientation, position = _poses_at(track, targets)
    known = np.array([r is None for r in reasons], dtype=bool)
    if source == "imu":
        motion = LinkMotion(link, values[:, :3], rates[:, :3], values[:, 3:], None, orientation, position)
    else:
        velocity, omega = values[:, :3], values[:, 3:]
        acceleration, alpha = rates[:, :3], rates[:, 3:]
        oriented = np.isfinite(orientation).all(axis=1)
        for i in np.flatnonzero(known & ~oriented):
            reasons[i] = NO_ORIENTATION
        # the classical acceleration (d/dt of the world velocity, link axes) less gravity, in link axes
        gravity_in_link = np.einsum("tji,j->ti", rotation_matrix(orientation), np.asarray(gravity, dtype=float))
        force = acceleration + np.cross(omega, velocity) - gravity_in_link
        motion = LinkMotion(link, omega, alpha, force, velocity, orientation, position)
    return motion, reasons


def _poses_at(track: BaseTrack, targets: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The messages' orientations (normalised linear interpolation, sign-aligned) and positions
    (linear) at the targets, within the messages on either side; NaN before the first or where one
    of the two has none."""
    count, m = len(targets), len(track.pose_stamps)
    if not m:
        return np.full((count, 4), np.nan), np.full((count, 3), np.nan)
    k = np.searchsorted(track.pose_stamps, targets, side="right") - 1
    before = np.clip(k, 0, m - 1)
    after = np.minimum(before + 1, m - 1)
    span = track.pose_stamps[after] - track.pose_stamps[before]
    weight = np.clip(np.where(span > 0, (targets - track.pose_stamps[before]) / np.where(span > 0, span, 1), 0.0), 0, 1)
    a, b = track.orientation[before], track.orientation[after]
    b = np.where(np.sum(a * b, axis=1, keepdims=True) < 0, -b, b)
    mixed = a + weight[:, None] * (b - a)
    orientation = mixed / np.linalg.norm(mixed, axis=1, keepdims=True)
    position = track.position[before] + weight[:, None] * (track.position[after] - track.position[before])
    early = (k < 0)[:, None]
    return np.where(early, np.nan, orientation), np.where(early, np.nan, position)


class BaseTracker:
    """Base messages in, one estimate per message stamp, the measured link's motion at any covered
    stamp out (:func:`motion_at`).

    Args:
        source: ``"imu"`` or ``"odometry"``.
        settings: the joint estimator's settings (the same method, mode, lag and window are used).
        gravity: gravity in the world frame, m/s^2 (odometry: the specific force needs it).
        log: ``log(level, message)``.
        keep: estimates kept (the node forgets what no later stamp needs; the bag tool keeps all).
    """

    def __init__(
        self,
        source: str,
        settings: StreamSettings,
        gravity: Sequence[float],
        log: LogFunction | None = None,
        keep: int | None = 4096,
    ) -> None:
        self.source = source
        self.gravity = tuple(float(g) for g in gravity)
        self._max_gap_ns = round(settings.max_gap * NS)
        self._log = ThrottledLog(log)
        # The same estimator as the joints', on the base's channels; velocities it is not given.
        self._estimator = StreamingEstimator(
            CHANNELS[source], settings=replace(settings, velocity_source="differentiate"), log=log
        )
        self._poses: deque[tuple[int, list[float], list[float]]] = deque(maxlen=keep)
        self._estimates: deque[JointEstimate] = deque(maxlen=keep)
        self.frame_id = ""

    def on_message(self, message: BaseMessage) -> int:
        """One base message; returns how many new estimates it completed."""
        if self.source == "imu":
            values = [*message.omega, *message.linear]
        else:
            values = [*message.linear, *message.omega]
        if not all(math.isfinite(v) for v in values):
            self._log.every("base-nan", logging.WARNING, f"base {self.source} message with non-finite values: dropped")
            return 0
        self.frame_id = message.frame_id or self.frame_id
        channels = CHANNELS[self.source]
        estimates = self._estimator.update(message.stamp_ns, channels, values, receive_ns=message.receive_ns)
        stamp = message.stamp_ns if message.stamp_ns > 0 else (message.receive_ns or 0)
        self._poses.append((stamp, _unit_quaternion(message.orientation), _finite(message.position, 3)))
        count = 0
        for estimate in estimates:
            if estimate.all_ready:
                self._estimates.append(estimate)
                count += 1
        return count

    def track(self) -> BaseTrack:
        """What is kept, as arrays."""
        estimates = self._estimates
        poses = self._poses
        return BaseTrack(
            np.array([e.stamp_ns for e in estimates], dtype=np.int64),
            np.array([e.segment for e in estimates], dtype=np.int64),
            np.array([e.positions for e in estimates]).reshape(-1, 6),
            np.array([e.velocities for e in estimates]).reshape(-1, 6),
            np.array([p[0] for p in poses], dtype=np.int64),
            np.array([p[1] for p in poses]).reshape(-1, 4),
            np.array([p[2] for p in poses]).reshape(-1, 3),
        )

    def motion_at(self, stamps: Any, link: str) -> tuple[LinkMotion, list[str | None]]:
        """:func:`motion_at` on what is kept."""
        return motion_at(self.track(), stamps, link, self.source, self.gravity, self._max_gap_ns)

    def newest(self) -> int | None:
        """The newest stamp with an estimate."""
        return self._estimates[-1].stamp_ns if self._estimates else None

    def forget_before(self, stamp_ns: int) -> None:
        """Drop what no later stamp needs: estimates and poses older than the one at or before it."""
        for queue, stamp_of in ((self._estimates, lambda e: e.stamp_ns), (self._poses, lambda p: p[0])):
            while len(queue) > 2 and stamp_of(queue[1]) <= stamp_ns:
                queue.popleft()


def _unit_quaternion(values: Sequence[float] | None) -> list[float]:
    q = np.asarray(values if values is not None else (), dtype=float)
    norm = float(np.linalg.norm(q)) if q.shape == (4,) and np.all(np.isfinite(q)) else 0.0
    return (q / norm).tolist() if norm > 0.5 else [math.nan] * 4  # all zeros: "no orientation" by convention


def _finite(values: Sequence[float] | None, size: int) -> list[float]:
    v = np.asarray(values if values is not None else (), dtype=float)
    return v.tolist() if v.shape == (size,) and np.all(np.isfinite(v)) else [math.nan] * size


class Aligner:
    """Joint estimates waiting for the base motion at their stamps (the node).

    Estimates are released, in stamp order, once the base estimates cover their stamps; an estimate
    the base motion will never cover (a gap, a reset, a stamp older than what is kept) or that has
    waited ``max_delay`` (by the joint stamps' clock) is dropped with a throttled warning.
    """

    def __init__(self, tracker: BaseTracker, max_delay: float, link: str, log: LogFunction | None = None) -> None:
        self.tracker = tracker
        self.link = link
        self._max_delay_ns = round(max_delay * NS)
        self._waiting: deque[JointEstimate] = deque()
        self._newest = 0
        self._log = ThrottledLog(log)

    def add(self, estimates: Iterable[JointEstimate]) -> None:
        for estimate in estimates:
            self._waiting.append(estimate)
            self._newest = max(self._newest, estimate.stamp_ns)

    def ready(self) -> list[tuple[JointEstimate, LinkMotion]]:
        """(estimate, the measured link's motion at its stamp) for every estimate now covered."""
        out: list[tuple[JointEstimate, LinkMotion]] = []
        waiting = self._waiting
        if not waiting:
            return out
        link = self.link or self.tracker.frame_id
        motion, reasons = self.tracker.motion_at([e.stamp_ns for e in waiting], link)
        released = 0
        for i, reason in enumerate(reasons):
            estimate = waiting[0]
            if reason is None:
                out.append((waiting.popleft(), motion.part(i)))
                released += 1
                continue
            if reason == NOT_YET and self._newest - estimate.stamp_ns <= self._max_delay_ns:
                break  # the base messages may still come
            waiting.popleft()
            why = "none came within base.max_delay" if reason == NOT_YET else reason
            self._log.every(
                ("base-missing", why),
                logging.WARNING,
                f"nothing published for a joint state: no base motion at its stamp ({why})",
            )
        if out:
            self.tracker.forget_before(out[-1][0].stamp_ns)
        return out


def root_and_world(
    model: RobotModel, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray, motion: LinkMotion, world: bool
) -> tuple[Any, tuple[np.ndarray, np.ndarray] | None]:
    """The root's state for the recursion (12 floats, or 12 (T,) arrays) from the measured link's
    motion at these joint states, and, when ``world``, the root's pose in the world: rotation root ->
    world ((3, 3) or (T, 3, 3); NaN where the source gives no orientation) and position ((3,) or
    (T, 3); the root origin's, zero where the source gives none, as for an IMU)."""
    single = q.ndim == 1
    base = base_from_link(
        model,
        motion.link,
        q,
        qd,
        qdd,
        omega=motion.omega,
        alpha=motion.alpha,
        specific_force=motion.specific_force,
        velocity=motion.velocity,
    )
    root = base.root(None if single else len(q))
    if not world:
        return root, None
    link_to_root, link_in_root = link_pose(model, q, model.link_index[motion.link])
    world_root = rotation_matrix(motion.orientation) @ np.swapaxes(link_to_root, -1, -2)  # root -> world
    offset = np.einsum("...ij,...j->...i", world_root, link_in_root)
    position = np.where(np.isfinite(motion.position), motion.position - offset, 0.0)
    return root, (world_root, position)
