"""The rclpy adapter: ``ros2 run neforward_ros neforward_node`` (node name ``neforward``).

Thin by design: it declares the parameters of :mod:`neforward_ros.parameters`, subscribes with raw
(serialized) subscriptions, hands the bytes to :class:`neforward_ros.handlers.MessageHandlers`, and
publishes the serialized messages it gets back, exactly as the no-ROS DDS node does. The only
module that imports rclpy.
"""

from __future__ import annotations

import gc
import logging
import signal
import sys
from collections.abc import Callable
from typing import Any

import rclpy
from rcl_interfaces.msg import ParameterDescriptor, SetParametersResult
from rclpy.event_handler import SubscriptionEventCallbacks
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy, qos_policy_name_from_kind
from rclpy.qos_overriding_options import QoSOverridingOptions
from rclpy.subscription import Subscription
from rosidl_runtime_py.utilities import get_message
from sensor_msgs.msg import JointState
from std_msgs.msg import String
from trajectory_msgs.msg import JointTrajectory

from neforward_ros.errors import NeforwardError
from neforward_ros.interface.topics import IMU_TYPE, JOINT_STATES, JOINT_STATES_ACCEL, ODOMETRY_TYPE, ROBOT_DESCRIPTION
from neforward_ros.logs import BoundedLog
from neforward_ros.model import load_model
from neforward_ros.node.handlers import MessageHandlers
from neforward_ros.node.pipeline import Pipeline
from neforward_ros.parameters.files import command_line_parameters
from neforward_ros.parameters.ros_args import ros_args_section
from neforward_ros.parameters.settings import node_settings
from neforward_ros.parameters.table import DEFAULTS, NODE_NAME, PARAMETERS

OUTPUT_QOS_DEPTH = 10
TAKEN_PER_CALLBACK = 16
"""Further messages an input subscription's callback takes from its queue, when they have queued, before
it hands back to the executor (whose round per message, rebuilding its wait set in Python, costs about
0.2 ms on a 2-core machine, a fifth of a 1 kHz stream's budget, against 18 us taken here:
``bench/bench_ros.py`` prints both). The bound keeps the node's other callbacks (the other inputs,
parameters) served while a backlog is worked off."""


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
            descriptor = ParameterDescriptor(
                description=parameter.description,
                read_only=parameter.read_only,
                dynamic_typing=parameter.default == [],
            )
            self.declare_parameter(parameter.name, parameter.default, descriptor)
        self.settings = node_settings(self._values())
        self._bounded_log = BoundedLog(self._log_to_ros)
        self.pipeline = Pipeline(self.settings, log=self._bounded_log)
        overridable = QoSOverridingOptions.with_default_policies()
        self._output_publishers = {
            output.topic: self.create_publisher(
                get_message(output.type), output.topic, OUTPUT_QOS_DEPTH, qos_overriding_options=overridable
            )
            for output in self.pipeline.outputs()
        }
        self.handlers = MessageHandlers(self.pipeline, self._publish, log=self._bounded_log)
        input_qos = QoSProfile(depth=self.settings.qos_depth)
        if self.settings.acceleration_source == "supplied":
            self._raw_subscription(JointTrajectory, JOINT_STATES_ACCEL, self.handlers.on_joint_trajectory, input_qos)
        else:
            self._raw_subscription(JointState, JOINT_STATES, self.handlers.on_joint_state, input_qos)
        if self.settings.base_source != "fixed":
            kind = IMU_TYPE if self.settings.base_source == "imu" else ODOMETRY_TYPE
            self._raw_subscription(get_message(kind), self.settings.base_topic, self.handlers.on_base, input_qos)
        if not self.settings.robot_description:
            latched = QoSProfile(
                depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL, reliability=ReliabilityPolicy.RELIABLE
            )
            self.create_subscription(String, ROBOT_DESCRIPTION, self.handlers.on_description, latched, raw=True)
        self.add_on_set_parameters_callback(self._on_set_parameters)

    def _values(self) -> dict[str, Any]:
        return {p.name: _plain(self.get_parameter(p.name).value) for p in PARAMETERS}

    def _raw_subscription(self, message_type: type, topic: str, handler: Any, qos: QoSProfile) -> None:
        def receive(data: bytes) -> None:
            handler(data, self.get_clock().now().nanoseconds)  # sim time when use_sim_time is set

        def callback(data: bytes) -> None:
            receive(data)
            take_queued(subscription, message_type, receive)

        def incompatible(event: Any) -> None:
            policy = qos_policy_name_from_kind(event.last_policy_kind)
            self._bounded_log(
                logging.WARNING,
                f"a publisher on {self.resolve_topic_name(topic)} offers QoS incompatible with this subscription "
                f"({policy}): its messages are not received. For a best-effort publisher, set the parameter "
                f"qos_overrides.{self.resolve_topic_name(topic)}.subscription.reliability: best_effort",
            )

        subscription = self.create_subscription(
            message_type,
            topic,
            callback,
            qos,
            raw=True,
            qos_overriding_options=QoSOverridingOptions.with_default_policies(),
            event_callbacks=SubscriptionEventCallbacks(incompatible_qos=incompatible),
        )

    def _publish(self, topic: str, payload: bytes) -> None:
        self._output_publishers[topic].publish(payload)

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

    def _on_set_parameters(self, parameters: list[rclpy.parameter.Parameter]) -> SetParametersResult:
        """Run-time changes (rclpy has already refused the read-only ones): check, then apply."""
        changed = {p.name: _plain(p.value) for p in parameters if p.name in DEFAULTS}
        if not changed:
            return SetParametersResult(successful=True)
        try:
            settings = node_settings({**self._values(), **changed})
            text = changed.get("robot_description")
            if text is not None:
                if not text:
                    raise NeforwardError("robot_description cannot be emptied while the node runs")
                model = load_model(text, root_link=settings.root_link, log=self._bounded_log)
                self.pipeline.set_model(model, "robot_description parameter")
        except NeforwardError as exc:
            return SetParametersResult(successful=False, reason=str(exc))
        self.pipeline.update_settings(settings)
        return SetParametersResult(successful=True)


def take_queued(subscription: Subscription, message_type: type, receive: Callable[[bytes], None]) -> None:
    """Hand ``receive`` the serialized messages that have queued on a raw subscription, taken as rclpy's
    executor takes them (the same call), up to :data:`TAKEN_PER_CALLBACK`: each round of the executor
    costs about 0.2 ms of its own."""
    for _ in range(TAKEN_PER_CALLBACK):
        with subscription.handle:
            taken = subscription.handle.take_message(message_type, True)
        if taken is None:
            return
        receive(taken[0])


def _plain(value: Any) -> Any:
    """Parameter values as plain Python (rclpy gives arrays as array.array)."""
    if isinstance(value, (str, bytes)) or not hasattr(value, "__len__"):
        return value
    return list(value)


def _interrupt_once(signum: int, frame: Any) -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    raise KeyboardInterrupt


def main(args: list[str] | None = None) -> int:
    argv = sys.argv if args is None else args
    try:
        # The checks `neforward run` makes, before rcl reads the same arguments: the same files and
        # values are accepted or refused by both runtimes, with the same one-line message.
        node_settings(command_line_parameters(ros_args_section(argv), strict=False)[1])
    except NeforwardError as exc:
        print(f"{NODE_NAME}: error: {exc}", file=sys.stderr)
        return 1
    # Ctrl-C raises KeyboardInterrupt once; later ones (a terminal signals the whole process group,
    # and ros2 launch forwards one more) are ignored so that the shutdown completes. rclpy's own
    # handler, installed by init, wakes the executor and then calls this one.
    signal.signal(signal.SIGINT, _interrupt_once)
    node = None
    try:
        try:
            rclpy.init(args=argv)
            node = NeforwardNode()
        except (KeyboardInterrupt, ExternalShutdownException):
            raise
        except Exception as exc:
            if not rclpy.ok():  # Ctrl-C during start-up: rclpy's handler invalidated the context first, and
                return 0  # the call that failed on it raised this, not KeyboardInterrupt
            print(f"{NODE_NAME}: error: {exc}", file=sys.stderr)
            return 1
        # Everything allocated so far lives as long as the node: keep it out of the collector's full
        # passes, which would otherwise walk it now and then and show up as latency spikes.
        gc.freeze()
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
