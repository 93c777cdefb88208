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
JOINT_TORQUES = "~/joint_torques"
JOINT_ESTIMATES = "~/joint_estimates"
EXTERNAL_TORQUES = "~/external_torques"
CONTACT = "~/contact"
CONTACT_WRENCH = "~/contact_wrench"
WORLD_LINK_STATES = "~/world_link_states"


LINK_STATES_TYPE = "trajectory_msgs/msg/MultiDOFJointTrajectory"
ACCEL_TYPE = "geometry_msgs/msg/AccelStamped"
TWIST_TYPE = "geometry_msgs/msg/TwistStamped"
IMU_TYPE = "sensor_msgs/msg/Imu"
MARKERS_TYPE = "visualization_msgs/msg/MarkerArray"
JOINT_STATE_TYPE = "sensor_msgs/msg/JointState"
JOINT_TRAJECTORY_TYPE = "trajectory_msgs/msg/JointTrajectory"
STRING_TYPE = "std_msgs/msg/String"
WRENCH_TYPE = "geometry_msgs/msg/WrenchStamped"
BOOL_TYPE = "std_msgs/msg/Bool"
IMU_INPUT_TYPE = IMU_TYPE
ODOMETRY_TYPE = "nav_msgs/msg/Odometry"


@dataclass(frozen=True)
class Output:
    """A topic the node publishes: relative name and ROS 2 type (``pkg/msg/Type``)."""

    topic: str
    type: str


def output_list(
    accel_links: Sequence[str],
    imu_links: Sequence[str],
    publish_markers: bool,
    publish_torques: bool = False,
    wrench_links: Sequence[str] = (),
    contact: bool = False,
    world: bool = False,
    contact_wrench: bool = False,
    joint_estimates: bool = False,
) -> list[Output]:
    """The node's outputs, relative names: link_states, com_states, world_link_states, per-link topics,
    joint estimates, markers, joint torques, external torques, per-link wrenches, contact, contact
    wrench."""
    out = [Output(LINK_STATES, LINK_STATES_TYPE), Output(COM_STATES, LINK_STATES_TYPE)]
    if world:
        out.append(Output(WORLD_LINK_STATES, LINK_STATES_TYPE))
    for link in accel_links:
        out += [Output(accel_topic(link), ACCEL_TYPE), Output(twist_topic(link), TWIST_TYPE)]
    out += [Output(imu_topic(link), IMU_TYPE) for link in imu_links]
    if joint_estimates:
        out.append(Output(JOINT_ESTIMATES, JOINT_TRAJECTORY_TYPE))
    if publish_markers:
        out.append(Output(MARKERS, MARKERS_TYPE))
    if publish_torques:
        out += [Output(JOINT_TORQUES, JOINT_STATE_TYPE), Output(EXTERNAL_TORQUES, JOINT_STATE_TYPE)]
    out += [Output(wrench_topic(link), WRENCH_TYPE) for link in wrench_links]
    if contact:
        out.append(Output(CONTACT, BOOL_TYPE))
    if contact_wrench:
        out.append(Output(CONTACT_WRENCH, WRENCH_TYPE))
    return out


def accel_topic(link: str) -> str:
    return f"~/{link}/accel"


def twist_topic(link: str) -> str:
    return f"~/{link}/twist"


def imu_topic(link: str) -> str:
    return f"~/{link}/imu"


def wrench_topic(link: str) -> str:
    return f"~/{link}/wrench"
