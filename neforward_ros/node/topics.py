"""The node's topics: names (relative, so namespaces and remapping apply) and ROS 2 types."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

JOINT_STATES = "joint_states"
JOINT_STATES_ACCEL = "joint_states_accel"
ROBOT_DESCRIPTION = "robot_description"
LINK_STATES = "~/link_states"
COM_STATES = "~/com_states"
MARKERS = "~/markers"


LINK_STATES_TYPE = "trajectory_msgs/msg/MultiDOFJointTrajectory"
ACCEL_TYPE = "geometry_msgs/msg/AccelStamped"
TWIST_TYPE = "geometry_msgs/msg/TwistStamped"
IMU_TYPE = "sensor_msgs/msg/Imu"
MARKERS_TYPE = "visualization_msgs/msg/MarkerArray"
JOINT_STATE_TYPE = "sensor_msgs/msg/JointState"
JOINT_TRAJECTORY_TYPE = "trajectory_msgs/msg/JointTrajectory"
STRING_TYPE = "std_msgs/msg/String"


@dataclass(frozen=True)
class Output:
    """A topic the node publishes: relative name and ROS 2 type (``pkg/msg/Type``)."""

    topic: str
    type: str


def output_list(accel_links: Sequence[str], imu_links: Sequence[str], publish_markers: bool) -> list[Output]:
    """The node's outputs, relative names: link_states, com_states, per-link topics, markers."""
    out = [Output(LINK_STATES, LINK_STATES_TYPE), Output(COM_STATES, LINK_STATES_TYPE)]
    for link in accel_links:
        out += [Output(accel_topic(link), ACCEL_TYPE), Output(twist_topic(link), TWIST_TYPE)]
    out += [Output(imu_topic(link), IMU_TYPE) for link in imu_links]
    if publish_markers:
        out.append(Output(MARKERS, MARKERS_TYPE))
    return out


def accel_topic(link: str) -> str:
    return f"~/{link}/accel"


def twist_topic(link: str) -> str:
    return f"~/{link}/twist"


def imu_topic(link: str) -> str:
    return f"~/{link}/imu"
