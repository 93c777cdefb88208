"""The rclpy adapter: ``ros2 run neforward_ros neforward_node`` (node name ``neforward``).

Thin by design: it declares the parameters of :mod:`neforward_ros.parameters`, subscribes, hands the
fields of each message to :class:`neforward_ros.pipeline.Pipeline` and publishes what it returns.
The only module that imports rclpy.
"""

from __future__ import annotations

import logging
import sys
from functools import cache
from typing import Any

import rclpy
from rcl_interfaces.msg import ParameterDescriptor
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rosidl_runtime_py.utilities import get_message
from sensor_msgs.msg import JointState
from std_msgs.msg import String
from trajectory_msgs.msg import JointTrajectory

from neforward_ros import messages
from neforward_ros.parameters import NODE_NAME, PARAMETERS, node_settings
from neforward_ros.pipeline import (
    JOINT_STATES,
    JOINT_STATES_ACCEL,
    ROBOT_DESCRIPTION,
    Pipeline,
    Result,
    TrajectoryPoint,
)

OUTPUT_QOS_DEPTH = 10


class NeforwardNode(Node):
    """Subscribes to joint states (or supplied states) and publishes every link's kinematics.

    Raises at construction (the caller prints one line and exits non-zero): InputError for an
    invalid parameter value, ModelError for an invalid ``robot_description`` parameter.
    """

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(NODE_NAME, **kwargs)
        for parameter in PARAMETERS:
            # An empty list default would be typed BYTE_ARRAY by rclpy; dynamic typing lets a
            # params file give the string list (rclpy issue 912).
            descriptor = ParameterDescriptor(description=parameter.description, dynamic_typing=parameter.default == [])
            self.declare_parameter(parameter.name, parameter.default, descriptor)
        values = {p.name: _plain(self.get_parameter(p.name).value) for p in PARAMETERS}
        self.settings = node_settings(values)
        self.pipeline = Pipeline(self.settings, log=self._log_to_ros)
        self._output_publishers = {
            output.topic: self.create_publisher(get_message(output.type), output.topic, OUTPUT_QOS_DEPTH)
            for output in self.pipeline.outputs()
        }
        input_qos = QoSProfile(depth=self.settings.qos_depth)
        if self.settings.acceleration_source == "supplied":
            self.create_subscription(JointTrajectory, JOINT_STATES_ACCEL, self._on_joint_trajectory, input_qos)
        else:
            self.create_subscription(JointState, JOINT_STATES, self._on_joint_state, input_qos)
        if not self.settings.robot_description:
            latched = QoSProfile(
                depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL, reliability=ReliabilityPolicy.RELIABLE
            )
            self.create_subscription(String, ROBOT_DESCRIPTION, self._on_description, latched)

    def _log_to_ros(self, level: int, message: str) -> None:
        logger = self.get_logger()
        if level >= logging.ERROR:
            logger.error(message)
        elif level >= logging.WARNING:
            logger.warning(message)
        elif level >= logging.INFO:
            logger.info(message)
        else:
            logger.debug(message)

    def _now_ns(self) -> int:
        return self.get_clock().now().nanoseconds  # sim time when use_sim_time is set

    def _on_description(self, message: String) -> None:
        self.pipeline.set_description(message.data)

    def _on_joint_state(self, message: JointState) -> None:
        results = self.pipeline.on_joint_state(
            messages.stamp_ns(message.header.stamp),
            list(message.name),
            list(message.position),
            list(message.velocity),
            receive_ns=self._now_ns(),
        )
        self._publish_results(results)

    def _on_joint_trajectory(self, message: JointTrajectory) -> None:
        points = [
            TrajectoryPoint(
                list(p.positions), list(p.velocities), list(p.accelerations), messages.stamp_ns(p.time_from_start)
            )
            for p in message.points
        ]
        stamp = messages.stamp_ns(message.header.stamp)
        self._publish_results(
            self.pipeline.on_joint_trajectory(stamp, list(message.joint_names), points, receive_ns=self._now_ns())
        )

    def _publish_results(self, results: list[Result]) -> None:
        for result in results:
            for topic, contents in self.pipeline.messages(result):
                publisher = self._output_publishers[topic]
                publisher.publish(to_message(publisher.msg_type, contents))


def to_message(message_type: type, contents: dict[str, Any]) -> Any:
    """An rclpy message of ``message_type`` from the contents built by :mod:`neforward_ros.messages`."""
    message = message_type()
    for name, value in contents.items():
        if isinstance(value, dict):
            value = to_message(type(getattr(message, name)), value)
        elif isinstance(value, list) and value and isinstance(value[0], dict):
            element_type = _element_type(message_type, name)
            value = [to_message(element_type, item) for item in value]
        setattr(message, name, value)
    return message


@cache
def _element_type(message_type: type, field: str) -> type:
    """Message class of the elements of a sequence field, e.g. ``sequence<geometry_msgs/Transform>``."""
    spec = message_type.get_fields_and_field_types()[field]
    inner = spec.split("<", 1)[1].split(",")[0].rstrip(">") if "<" in spec else spec.split("[")[0]
    package, name = inner.split("/")
    return get_message(f"{package}/msg/{name}")


def _plain(value: Any) -> Any:
    """Parameter values as plain Python (rclpy gives arrays as array.array)."""
    if isinstance(value, (str, bytes)) or not hasattr(value, "__len__"):
        return value
    return list(value)


def main(args: list[str] | None = None) -> int:
    rclpy.init(args=args)
    node = None
    try:
        try:
            node = NeforwardNode()
        except Exception as exc:
            print(f"{NODE_NAME}: error: {exc}", file=sys.stderr)
            return 1
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
