"""A recording's base motion: a sensor_msgs/Imu or nav_msgs/Odometry topic, at the joint states' stamps.

As the node's base sources do (:mod:`neforward_ros.node.base_source`), with the whole recording at
hand: the measured link's angular velocity (and, for odometry, linear velocity) interpolated between
the base samples around each joint-state stamp, its derivatives from the whole-recording fit, the
specific force from the IMU (interpolated) or from the odometry's acceleration and orientation; a
stamp gets none where the base samples do not cover the fit's window there, or are further than
max_gap apart around it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from neforward_ros.bag.options import BagOptions
from neforward_ros.base import base_from_link
from neforward_ros.errors import InputError
from neforward_ros.estimation.batch import estimate_at
from neforward_ros.estimation.coverage import covered_mask
from neforward_ros.kernel import SLICES
from neforward_ros.model import RobotModel
from neforward_ros.node import topics
from neforward_ros.recursion import kinematics_table
from neforward_ros.rotations import rotation_matrix
from neforward_ros.stamps import NS


@dataclass
class BaseSamples:
    """The base topic's messages, decoded (N samples, stamps increasing).

    Attributes:
        topic, frame_id: the topic, and the frame its messages measure (IMU frame, odometry child frame).
        stamps: (N,) int ns.
        omega: (N, 3); linear: (N, 3) the IMU's specific force or the odometry's linear velocity.
        orientation: (N, 4) quaternions (x, y, z, w), NaN where a message has none.
        position: (N, 3) the odometry's, NaN for an IMU.
    """

    topic: str
    frame_id: str
    stamps: np.ndarray
    omega: np.ndarray
    linear: np.ndarray
    orientation: np.ndarray
    position: np.ndarray


def read_base(reader: Any, options: BagOptions) -> BaseSamples | None:
    """The base topic's samples (None for a fixed base).

    Raises:
        InputError: no such topic in the recording (the message lists what there is), or no usable sample.
    """
    settings = options.settings
    if settings.base_source == "fixed":
        return None
    kind = topics.IMU_TYPE if settings.base_source == "imu" else topics.ODOMETRY_TYPE
    available = {c.topic: c.msgtype for c in reader.connections}
    topic = options.base_topic
    if topic is None:
        candidates = sorted(name for name, msgtype in available.items() if msgtype == kind)
        named = "/" + settings.base_topic.lstrip("/")  # the node's base.topic, in the root namespace
        if len(candidates) > 1 and named in candidates:
            candidates = [named]
        if len(candidates) != 1:
            listing = ", ".join(f"{n} ({t})" for n, t in sorted(available.items())) or "none"
            raise InputError(
                f"--base {settings.base_source} needs one {kind} topic (--base-topic to choose); topics: {listing}"
            )
        topic = candidates[0]
    if available.get(topic) != kind:
        raise InputError(f"the recording has no {kind} topic {topic}")
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_JAZZY)
    rows, frame = [], ""
    for connection, _, raw in reader.messages(connections=[c for c in reader.connections if c.topic == topic]):
        m = store.deserialize_cdr(raw, connection.msgtype)
        stamp = m.header.stamp.sec * NS + m.header.stamp.nanosec
        if settings.base_source == "imu":
            q = m.orientation
            has_orientation = m.orientation_covariance[0] != -1.0
            row = (
                stamp,
                _xyz(m.angular_velocity),
                _xyz(m.linear_acceleration),
                [q.x, q.y, q.z, q.w] if has_orientation else [np.nan] * 4,
                [np.nan] * 3,
            )
            frame = frame or m.header.frame_id
        else:
            pose, twist = m.pose.pose, m.twist.twist
            q = pose.orientation
            row = (stamp, _xyz(twist.angular), _xyz(twist.linear), [q.x, q.y, q.z, q.w], _xyz(pose.position))
            frame = frame or m.child_frame_id
        rows.append(row)
    stamps = np.array([r[0] for r in rows], dtype=np.int64)
    order = np.argsort(stamps, kind="stable")
    columns = [np.array([r[i] for r in rows], dtype=float).reshape(len(rows), -1)[order] for i in range(1, 5)]
    stamps = stamps[order]
    finite = np.isfinite(columns[0]).all(axis=1) & np.isfinite(columns[1]).all(axis=1)
    unique = np.r_[True, np.diff(stamps) > 0]
    keep = finite & unique
    if keep.sum() < 3:
        raise InputError(f"the base topic {topic} has fewer than 3 usable messages")
    return BaseSamples(topic, frame, stamps[keep], *(c[keep] for c in columns))


def _xyz(vector: Any) -> list[float]:
    return [vector.x, vector.y, vector.z]


@dataclass
class BaseAtStamps:
    """The measured link's motion at the joint states' stamps (M targets).

    Attributes:
        ok: (M,) whether the base motion is known there.
        omega, alpha, specific_force: (M, 3) in the link's frame.
        velocity: (M, 3), or None for an IMU.
        orientation: (M, 4) of the link in the world, NaN where unknown; position: (M, 3), NaN likewise.
    """

    ok: np.ndarray
    omega: np.ndarray
    alpha: np.ndarray
    specific_force: np.ndarray
    velocity: np.ndarray | None
    orientation: np.ndarray
    position: np.ndarray


def base_at(base: BaseSamples, targets_ns: np.ndarray, options: BagOptions) -> BaseAtStamps:
    """The base motion at the targets (see the module docstring)."""
    settings = options.settings
    origin = int(min(base.stamps[0], targets_ns.min()))
    t = (base.stamps - origin) / NS
    targets = (targets_ns - origin) / NS
    batch = options.batch_estimator
    support = batch.support
    after = np.clip(np.searchsorted(t, targets), 1, len(t) - 1)
    ok = covered_mask(t, targets, support) & (targets >= t[0]) & (targets <= t[-1])
    ok &= t[after] - t[after - 1] <= settings.estimator.max_gap

    def interpolate(values: np.ndarray) -> np.ndarray:
        return np.stack([np.interp(targets, t, values[:, k]) for k in range(values.shape[1])], axis=1)

    omega = interpolate(base.omega)
    _, alpha, _ = estimate_at(t, base.omega, targets, method=batch.method, window=batch.window, order=batch.order)
    orientation = _nlerp(t, base.orientation, targets)
    position = interpolate(base.position)
    if settings.base_source == "imu":
        return BaseAtStamps(ok, omega, alpha, interpolate(base.linear), None, orientation, position)
    velocity = interpolate(base.linear)
    _, acceleration, _ = estimate_at(
        t, base.linear, targets, method=batch.method, window=batch.window, order=batch.order
    )
    ok &= np.isfinite(orientation).all(axis=1)
    gravity = np.asarray(settings.gravity, dtype=float)
    gravity_in_link = np.array(
        [rotation_matrix(q).T @ gravity if np.isfinite(q).all() else np.full(3, np.nan) for q in orientation]
    )
    force = acceleration + np.cross(omega, velocity) - gravity_in_link
    return BaseAtStamps(ok, omega, alpha, force, velocity, orientation, position)


def _nlerp(t: np.ndarray, quaternions: np.ndarray, targets: np.ndarray) -> np.ndarray:
    """Quaternions interpolated (normalised linear interpolation, sign-aligned) at the targets."""
    after = np.clip(np.searchsorted(t, targets), 1, len(t) - 1)
    before = after - 1
    weight = np.clip((targets - t[before]) / (t[after] - t[before]), 0.0, 1.0)[:, None]
    a, b = quaternions[before], quaternions[after]
    b = np.where(np.sum(a * b, axis=1, keepdims=True) < 0, -b, b)
    mixed = a + weight * (b - a)
    return mixed / np.linalg.norm(mixed, axis=1, keepdims=True)


def root_states(
    model: RobotModel, link: str, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray, at: BaseAtStamps
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """For T samples where the base motion is known: the root's state (T, 12) as the recursion takes
    it, and the root's pose in the world: rotation root -> world (T, 3, 3) and position (T, 3), NaN
    where the source gives no orientation (position: zeros when it gives none)."""
    motion = base_from_link(
        model, link, q, qd, qdd, omega=at.omega, alpha=at.alpha, specific_force=at.specific_force, velocity=at.velocity
    )
    root = np.stack(motion.root(len(q)), axis=1)
    zeros = np.zeros_like(q)
    row = kinematics_table(model, q, zeros, zeros, (0.0,) * 12)[:, model.link_index[link]]
    link_to_root = row[:, SLICES["rotation"]].reshape(-1, 3, 3)
    known = np.isfinite(at.orientation).all(axis=1)
    world_link = np.full((len(q), 3, 3), np.nan)
    world_link[known] = [rotation_matrix(x) for x in at.orientation[known]]
    world_root = world_link @ np.transpose(link_to_root, (0, 2, 1))
    offset = np.einsum("tij,tj->ti", world_root, row[:, SLICES["position"]])
    position = np.where(np.isfinite(at.position), at.position - offset, 0.0)
    return root, world_root, position
