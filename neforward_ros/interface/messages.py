"""ROS 2 message contents built from results: the one place messages are built.

Every builder returns the message as nested dicts and lists keyed by the ROS 2 field names
(``{"header": {"stamp": {"sec": ..., "nanosec": ...}, "frame_id": ...}, ...}``), with fields left
out where the message default is meant. :mod:`.encoder` turns them into CDR bytes (patching the
per-model templates of link_states and com_states instead, with the same bytes), which every
runtime publishes and the bag tool records: the rclpy node, the no-ROS node and the bag output carry
the same numbers in the same fields.

Frames and points (see the README topic table):
- link_states / com_states (trajectory_msgs/MultiDOFJointTrajectory): poses, twists and
  accelerations of each link origin / centre of mass, every vector along the root frame's axes,
  ``header.frame_id`` the root link.
- <link>/accel, <link>/twist: the link origin's, in the link frame.
- <link>/imu: angular velocity and specific force in the link frame; orientation of the link in
  the root frame.
- joint_estimates (trajectory_msgs/JointTrajectory): the joint states a result comes from, one point,
  and each acceleration's standard deviation in the point's ``effort``.
- joint_torques, external_torques (sensor_msgs/JointState): the model's joint torques, and measured
  effort minus them, with the joint states they come from.
- <link>/wrench: what the link receives through its parent joint, link frame, about its origin.
- contact (std_msgs/Bool): the debounced contact state.
- contact_wrench (geometry_msgs/WrenchStamped): the wrench at ``contact.link``'s origin, in its frame,
  that the external torques show.
External torques, contact and contact wrench come either with a result (measured - model at the
estimator's stamps) or with an observation (the momentum observer at the newest samples).
Linear accelerations are classical (not spatial) accelerations minus gravity: the specific force an
accelerometer reads; with gravity set to zero they are kinematic accelerations.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from neforward_ros.computation.result import Blocks, Observation, Result
from neforward_ros.interface.topics import (
    COM_STATES,
    CONTACT,
    CONTACT_WRENCH,
    EXTERNAL_TORQUES,
    JOINT_ESTIMATES,
    JOINT_TORQUES,
    LINK_STATES,
    MARKERS,
    WORLD_LINK_STATES,
    accel_topic,
    imu_topic,
    twist_topic,
    wrench_topic,
)
from neforward_ros.parameters.settings import NodeSettings
from neforward_ros.stamps import time_message

Message = dict[str, Any]

MARKER_NAMESPACE = "com_accel"
_ARROW = 0  # visualization_msgs/Marker ARROW
_ADD = 0  # visualization_msgs/Marker ADD


def header(stamp: int, frame_id: str) -> Message:
    return {"stamp": time_message(stamp), "frame_id": frame_id}


def vector3(v: np.ndarray) -> Message:
    x, y, z = v.tolist()
    return {"x": x, "y": y, "z": z}


def link_states_blocks(result: Result) -> Blocks:
    """link_states' transforms (n, 7), velocities (n, 6), accelerations (n, 6): pose of each link frame,
    (v, omega) and (specific force, alpha) of its origin, along the root axes."""
    return result.blocks[0]


def com_states_blocks(result: Result) -> Blocks:
    """The same for each link's centre of mass (its pose has the link's rotation)."""
    return result.blocks[1]


def _quaternion(q: np.ndarray) -> Message:
    x, y, z, w = q.tolist()
    return {"x": x, "y": y, "z": z, "w": w}


def _multi_dof(result: Result, frame_prefix: str, blocks: tuple[np.ndarray, np.ndarray, np.ndarray]) -> Message:
    transforms, velocities, accelerations = [], [], []
    for t, v, a in zip(*(block.tolist() for block in blocks), strict=True):
        transforms.append(
            {
                "translation": {"x": t[0], "y": t[1], "z": t[2]},
                "rotation": {"x": t[3], "y": t[4], "z": t[5], "w": t[6]},
            }
        )
        velocities.append({"linear": {"x": v[0], "y": v[1], "z": v[2]}, "angular": {"x": v[3], "y": v[4], "z": v[5]}})
        accelerations.append(
            {"linear": {"x": a[0], "y": a[1], "z": a[2]}, "angular": {"x": a[3], "y": a[4], "z": a[5]}}
        )
    return {
        "header": header(result.stamp_ns, frame_prefix + result.root_link),
        "joint_names": list(result.link_names),
        "points": [
            {
                "transforms": transforms,
                "velocities": velocities,
                "accelerations": accelerations,
                "time_from_start": {"sec": 0, "nanosec": 0},
            }
        ],
    }


def link_states(result: Result, frame_prefix: str = "") -> Message:
    """trajectory_msgs/MultiDOFJointTrajectory: for each link (``joint_names`` = link names), the pose of
    its frame in the root frame, the twist (v of the origin, omega) and the acceleration (specific
    force at the origin, alpha), vectors along the root axes; one point, stamped with the input's stamp."""
    return _multi_dof(result, frame_prefix, link_states_blocks(result))


def com_states(result: Result, frame_prefix: str = "") -> Message:
    """As :func:`link_states` for each link's centre of mass: translation = the COM in the root frame
    (rotation = the link's), twist and acceleration of the COM point, along the root axes."""
    return _multi_dof(result, frame_prefix, com_states_blocks(result))


def accel_stamped(result: Result, link: int, frame_prefix: str = "") -> Message:
    """geometry_msgs/AccelStamped of the link origin in the link frame: linear = specific force, angular = alpha."""
    kin = result.in_link
    return {
        "header": header(result.stamp_ns, frame_prefix + result.link_names[link]),
        "accel": {"linear": vector3(kin.accel[link]), "angular": vector3(kin.alpha[link])},
    }


def twist_stamped(result: Result, link: int, frame_prefix: str = "") -> Message:
    """geometry_msgs/TwistStamped of the link origin in the link frame: linear = v, angular = omega."""
    kin = result.in_link
    return {
        "header": header(result.stamp_ns, frame_prefix + result.link_names[link]),
        "twist": {"linear": vector3(kin.velocity[link]), "angular": vector3(kin.omega[link])},
    }


def imu(result: Result, link: int, frame_prefix: str = "") -> Message:
    """sensor_msgs/Imu of an ideal IMU at the link origin, axes along the link frame.

    orientation: the link frame's orientation in the root frame. angular_velocity: omega in the link
    frame. linear_acceleration: the specific force in the link frame (+9.81 m/s^2 upward at rest, as
    a real accelerometer reads). linear_acceleration_covariance: what the joint accelerations'
    estimated uncertainty gives through the link's Jacobian (the estimator's, see
    :attr:`Result.imu_covariance`); all zero, which sensor_msgs/Imu defines as "covariance unknown",
    where the estimator gives none. The other covariances are zero: unknown.
    """
    kin = result.in_link
    zeros = [0.0] * 9
    name = result.link_names[link]
    covariance = list(zeros)
    known = result.imu_covariance.get(name) if result.imu_covariance is not None else None
    if known is not None and known.shape == (3, 3) and np.isfinite(known).all():
        covariance = known.reshape(9).tolist()
    return {
        "header": header(result.stamp_ns, frame_prefix + result.link_names[link]),
        "orientation": _quaternion(kin.orientation[link]),
        "orientation_covariance": zeros,
        "angular_velocity": vector3(kin.omega[link]),
        "angular_velocity_covariance": list(zeros),
        "linear_acceleration": vector3(kin.accel[link]),
        "linear_acceleration_covariance": covariance,
    }


def markers(result: Result, frame_prefix: str = "", scale: float = 0.02) -> Message:
    """visualization_msgs/MarkerArray: per link an ARROW from its centre of mass along its COM
    acceleration (specific force), ``scale`` m per m/s^2, in the root frame; id = the link's index in
    the model (the same link keeps its id when only some links are published)."""
    root = result.in_root
    out = []
    frame = frame_prefix + result.root_link
    ids = result.ids
    for k in range(len(result.link_names)):
        start = root.com_position[k]
        end = start + scale * root.com_accel[k]
        out.append(
            {
                "header": header(result.stamp_ns, frame),
                "ns": MARKER_NAMESPACE,
                "id": ids[k],
                "type": _ARROW,
                "action": _ADD,
                "pose": {"orientation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}},
                "scale": {"x": 0.01, "y": 0.02, "z": 0.0},  # shaft and head diameter; default head length
                "color": {"r": 1.0, "g": 0.4, "b": 0.0, "a": 1.0},
                "points": [vector3(start), vector3(end)],
                "text": result.link_names[k],
            }
        )
    return {"markers": out}


def world_link_states(result: Result, world_frame: str, gravity: Sequence[float]) -> Message:
    """trajectory_msgs/MultiDOFJointTrajectory in the world frame (``header.frame_id`` = world_frame),
    from a moving base's orientation (and position, for odometry): each link's pose in the world,
    its twist, and its kinematic acceleration (gravity removed: the specific force plus ``gravity``,
    the world frame's) and alpha, every vector along the world's axes."""
    assert result.world is not None
    rotation, origin = result.world
    (poses, twists, accels) = result.blocks[0]
    positions = poses[:, :3] @ rotation.T + origin
    world_quaternion = _quaternion_of(rotation)
    orientations = np.array([_hamilton(world_quaternion, q) for q in poses[:, 3:]])
    twists = np.concatenate([twists[:, :3] @ rotation.T, twists[:, 3:] @ rotation.T], axis=1)
    linear = accels[:, :3] @ rotation.T + np.asarray(gravity, dtype=float)
    accels = np.concatenate([linear, accels[:, 3:] @ rotation.T], axis=1)
    message = _multi_dof(result, "", (np.concatenate([positions, orientations], axis=1), twists, accels))
    message["header"]["frame_id"] = world_frame
    return message


def _quaternion_of(rotation: np.ndarray) -> np.ndarray:
    from neforward_ros.rotations import quaternions

    return quaternions(rotation[None])[0]


def _hamilton(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a * b for quaternions (x, y, z, w), with w >= 0."""
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    q = np.array(
        [
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
            aw * bw - ax * bx - ay * by - az * bz,
        ]
    )
    return q if q[3] >= 0 else -q


def joint_torques(result: Result) -> Message:
    """sensor_msgs/JointState: every joint column with its position and velocity (as estimated) and, as
    ``effort``, the torque (N m; N for a prismatic joint) the model says its motor produces."""
    dynamics = result.dynamics
    assert dynamics is not None
    return {
        "header": header(result.stamp_ns, ""),
        "name": list(dynamics.joint_names),
        "position": dynamics.positions.tolist(),
        "velocity": dynamics.velocities.tolist(),
        "effort": dynamics.torques.tolist(),
    }


def external_torques(result: Result | Observation) -> Message | None:
    """sensor_msgs/JointState of the joints whose input carried an effort: ``effort`` = measured
    (scaled, offset) - model (with friction), positive where the motor gives more than the motion
    needs, as it does holding an unmodelled payload up; None when no joint has one. From a result
    (the difference, at the estimator's stamp) or an observation (the momentum observer's)."""
    source = result.dynamics if isinstance(result, Result) else result
    if source is None:
        return None
    external = source.external
    keep = np.flatnonzero(np.isfinite(external))
    if len(keep) == 0:
        return None
    return {
        "header": header(result.stamp_ns, ""),
        "name": [source.joint_names[k] for k in keep],
        "position": source.positions[keep].tolist(),
        "velocity": source.velocities[keep].tolist(),
        "effort": external[keep].tolist(),
    }


def wrench_stamped(result: Result, link: int, frame_prefix: str = "") -> Message:
    """geometry_msgs/WrenchStamped: what the link receives from its parent through its parent joint
    (force N, torque N m about the link origin), in the link frame; the root's from the world."""
    dynamics = result.dynamics
    assert dynamics is not None
    k = result.ids[link]  # the dynamics cover every link of the model
    return {
        "header": header(result.stamp_ns, frame_prefix + result.link_names[link]),
        "wrench": {"force": vector3(dynamics.force[k]), "torque": vector3(dynamics.moment[k])},
    }


def dynamics_messages(
    result: Result, publish_torques: bool, wrench_links: Sequence[str], frame_prefix: str
) -> list[tuple[str, Message]]:
    """(topic, contents) of the joint-torque, wrench and contact outputs of one result, in
    :func:`output_list` order: none without dynamics (a stamp where some joint has no state)."""
    out: list[tuple[str, Message]] = []
    if result.dynamics is None:
        return out
    if publish_torques:
        out.append((JOINT_TORQUES, joint_torques(result)))
        external = external_torques(result)
        if external is not None:
            out.append((EXTERNAL_TORQUES, external))
    for link in wrench_links:
        if link in result.link_names:
            out.append((wrench_topic(link), wrench_stamped(result, result.link_names.index(link), frame_prefix)))
    if result.contact is not None:
        out.append((CONTACT, {"data": result.contact}))
    return out


def joint_estimates(result: Result) -> Message | None:
    """trajectory_msgs/JointTrajectory, one point: ``joint_names`` = the joint columns that have a state
    at this stamp; ``positions``, ``velocities``, ``accelerations`` = the states the result comes from
    (rad, rad/s, rad/s^2; m, m/s, m/s^2 for a prismatic joint; estimated, supplied or held); ``effort``
    = each acceleration's standard deviation as the estimator states it (same units as the
    accelerations; NaN for a joint it states none for), empty when it states none at all (a fixed
    window, supplied states). ``time_from_start`` is zero: the point is at ``header.stamp``. None
    without joint states (``publish_joint_estimates`` off) or when no joint has one."""
    joints = result.joints
    if joints is None:
        return None
    keep = np.flatnonzero(joints.known)
    if len(keep) == 0:
        return None
    spread = joints.acceleration_std[keep]
    return {
        "header": header(result.stamp_ns, ""),
        "joint_names": [joints.joint_names[k] for k in keep],
        "points": [
            {
                "positions": joints.positions[keep].tolist(),
                "velocities": joints.velocities[keep].tolist(),
                "accelerations": joints.accelerations[keep].tolist(),
                "effort": spread.tolist() if np.isfinite(spread).any() else [],
            }
        ],
    }


def per_link_messages(
    result: Result, accel_links: Sequence[str], imu_links: Sequence[str], frame_prefix: str
) -> list[tuple[str, Message]]:
    """(topic, contents) of the per-link outputs of one result and of its joint estimates, in
    :func:`output_list` order.

    Links the result's model does not have are left out (the pipeline logs them once).
    """
    out: list[tuple[str, Message]] = []
    for link in accel_links:
        if link in result.link_names:
            k = result.link_names.index(link)
            out.append((accel_topic(link), accel_stamped(result, k, frame_prefix)))
            out.append((twist_topic(link), twist_stamped(result, k, frame_prefix)))
    for link in imu_links:
        if link in result.link_names:
            out.append((imu_topic(link), imu(result, result.link_names.index(link), frame_prefix)))
    joints = joint_estimates(result)
    if joints is not None:
        out.append((JOINT_ESTIMATES, joints))
    return out


def all_messages(result: Result, settings: NodeSettings) -> list[tuple[str, Message]]:
    """(topic, contents) of every output of one result, in :func:`output_list` order."""
    prefix = settings.frame_prefix
    out = [(LINK_STATES, link_states(result, prefix)), (COM_STATES, com_states(result, prefix))]
    if settings.world_frame and result.world is not None:
        out.append((WORLD_LINK_STATES, world_link_states(result, settings.world_frame, settings.gravity)))
    out += per_link_messages(result, settings.accel_links, settings.imu_links, prefix)
    if settings.publish_markers:
        out.append((MARKERS, markers(result, prefix, settings.marker_scale)))
    return out + dynamics_messages(result, settings.publish_torques, settings.wrench_links, prefix)


def contact_wrench(observation: Observation, frame_prefix: str = "") -> Message | None:
    """geometry_msgs/WrenchStamped: the wrench at the contact link's origin, in its frame (force N,
    torque N m), whose J^T is closest to the external torques: what the robot exerts on what it
    touches there (the push it receives, negated); None where the torques are unknown."""
    wrench = observation.wrench
    if wrench is None or not np.isfinite(wrench).all():
        return None
    return {
        "header": header(observation.stamp_ns, frame_prefix + observation.link),
        "wrench": {"force": vector3(wrench[0:3]), "torque": vector3(wrench[3:6])},
    }


def observation_messages(observation: Observation, settings: NodeSettings) -> list[tuple[str, Message]]:
    """(topic, contents) of the outputs of one observation, in :func:`output_list` order."""
    out: list[tuple[str, Message]] = []
    if settings.publish_torques:
        external = external_torques(observation)
        if external is not None:
            out.append((EXTERNAL_TORQUES, external))
    if observation.contact is not None:
        out.append((CONTACT, {"data": observation.contact}))
    wrench = contact_wrench(observation, settings.frame_prefix)
    if wrench is not None:
        out.append((CONTACT_WRENCH, wrench))
    return out
