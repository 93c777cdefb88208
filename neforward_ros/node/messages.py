"""ROS 2 message contents built from results: the one place messages are built.

Every builder returns the message as nested dicts and lists keyed by the ROS 2 field names
(``{"header": {"stamp": {"sec": ..., "nanosec": ...}, "frame_id": ...}, ...}``), with fields left
out where the message default is meant. Each runtime turns these into its own message objects:
the rclpy adapter with ``rosidl_runtime_py.set_message_fields``, the DDS runtime and the bag tool
through :mod:`neforward_ros.wire`. So the rclpy node, the no-ROS node and the bag output carry
the same numbers in the same fields.

Frames and points (see the README topic table):
- link_states / com_states (trajectory_msgs/MultiDOFJointTrajectory): poses, twists and
  accelerations of each link origin / centre of mass, every vector along the root frame's axes,
  ``header.frame_id`` the root link.
- <link>/accel, <link>/twist: the link origin's, in the link frame.
- <link>/imu: angular velocity and specific force in the link frame; orientation of the link in
  the root frame.
Linear accelerations are classical (not spatial) accelerations minus gravity: the specific force an
accelerometer reads; with gravity set to zero they are kinematic accelerations.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from neforward_ros.node.result import Result
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


def multi_dof_blocks(
    positions: np.ndarray,
    orientations: np.ndarray,
    linear_velocities: np.ndarray,
    angular_velocities: np.ndarray,
    linear_accelerations: np.ndarray,
    angular_accelerations: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The numbers of a MultiDOFJointTrajectory point: transforms (..., n, 7) = translation,
    rotation (x, y, z, w); velocities (..., n, 6) = linear, angular; accelerations likewise."""
    return (
        np.concatenate([positions, orientations], axis=-1),
        np.concatenate([linear_velocities, angular_velocities], axis=-1),
        np.concatenate([linear_accelerations, angular_accelerations], axis=-1),
    )


def link_states_blocks(result: Result) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`multi_dof_blocks` of link_states (works on batched results too)."""
    root = result.in_root
    return multi_dof_blocks(
        root.position, result.orientation_in_root, root.velocity, root.omega, root.accel, root.alpha
    )


def com_states_blocks(result: Result) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`multi_dof_blocks` of com_states (works on batched results too)."""
    root = result.in_root
    return multi_dof_blocks(
        result.com_position_in_root,
        result.orientation_in_root,
        result.com_velocity_in_root,
        root.omega,
        root.com_accel,
        root.alpha,
    )


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
    a real accelerometer reads). Covariances are all zero, which sensor_msgs/Imu defines as
    "covariance unknown": the values are exact for the model, with no sensor noise model.
    """
    kin = result.in_link
    zeros = [0.0] * 9
    return {
        "header": header(result.stamp_ns, frame_prefix + result.link_names[link]),
        "orientation": _quaternion(result.orientation_in_root[link]),
        "orientation_covariance": zeros,
        "angular_velocity": vector3(kin.omega[link]),
        "angular_velocity_covariance": list(zeros),
        "linear_acceleration": vector3(kin.accel[link]),
        "linear_acceleration_covariance": list(zeros),
    }


def markers(result: Result, frame_prefix: str = "", scale: float = 0.02) -> Message:
    """visualization_msgs/MarkerArray: per link an ARROW from its centre of mass along its COM
    acceleration (specific force), ``scale`` m per m/s^2, in the root frame; id = link index."""
    root = result.in_root
    out = []
    frame = frame_prefix + result.root_link
    for k in range(len(result.link_names)):
        start = result.com_position_in_root[k]
        end = start + scale * root.com_accel[k]
        out.append(
            {
                "header": header(result.stamp_ns, frame),
                "ns": MARKER_NAMESPACE,
                "id": k,
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


def per_link_messages(
    result: Result, accel_links: Sequence[str], imu_links: Sequence[str], frame_prefix: str
) -> list[tuple[str, dict[str, Any]]]:
    """(topic, contents) of the per-link outputs of one result, in :func:`output_list` order.

    Links the result's model does not have are left out (the pipeline logs them once).
    """
    out: list[tuple[str, dict[str, Any]]] = []
    for link in accel_links:
        if link in result.link_names:
            k = result.link_names.index(link)
            out.append((f"~/{link}/accel", accel_stamped(result, k, frame_prefix)))
            out.append((f"~/{link}/twist", twist_stamped(result, k, frame_prefix)))
    for link in imu_links:
        if link in result.link_names:
            out.append((f"~/{link}/imu", imu(result, result.link_names.index(link), frame_prefix)))
    return out
