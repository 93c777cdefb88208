"""The rclpy node in-process: JointState in, link_states / accel / imu out, checked against
forward_recursion. Runs where ROS 2 Jazzy is sourced; skipped elsewhere (rclpy is not on PyPI).
The same node runs end to end over real DDS without ROS in test_dds_*.py."""

from __future__ import annotations

import time

import numpy as np
import pytest

rclpy = pytest.importorskip(
    "rclpy", reason="rclpy is not importable: ROS 2 Jazzy is not installed or not sourced on this machine"
)

from geometry_msgs.msg import AccelStamped  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.node import Node  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy  # noqa: E402
from sensor_msgs.msg import Imu, JointState  # noqa: E402
from std_msgs.msg import String  # noqa: E402
from trajectory_msgs.msg import MultiDOFJointTrajectory  # noqa: E402

from neforward_ros import forward_recursion, load_model  # noqa: E402
from neforward_ros.ros_node import NeforwardNode  # noqa: E402

from conftest import CONFIG_DIR  # noqa: E402

PANDA = CONFIG_DIR / "panda.urdf"
TIMEOUT = 10.0


@pytest.fixture
def context():
    ctx = rclpy.Context()
    rclpy.init(context=ctx)
    yield ctx
    rclpy.try_shutdown(context=ctx)


class Harness:
    def __init__(self, context, overrides: list[Parameter]) -> None:
        self.context = context
        self.tester = Node("neforward_tester", context=context)
        self.received: dict[str, list] = {"link_states": [], "accel": [], "imu": []}
        self.tester.create_subscription(
            MultiDOFJointTrajectory, "/neforward/link_states", self.received["link_states"].append, 10
        )
        self.tester.create_subscription(AccelStamped, "/neforward/panda_hand/accel", self.received["accel"].append, 10)
        self.tester.create_subscription(Imu, "/neforward/panda_hand/imu", self.received["imu"].append, 10)
        self.joint_states = self.tester.create_publisher(JointState, "/joint_states", 10)
        self.overrides = overrides
        self.node: NeforwardNode | None = None
        self.executor = SingleThreadedExecutor(context=context)
        self.executor.add_node(self.tester)

    def start_node(self) -> None:
        self.node = NeforwardNode(context=self.context, parameter_overrides=self.overrides)
        self.executor.add_node(self.node)

    def spin_until(self, done, timeout: float = TIMEOUT) -> bool:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            self.executor.spin_once(timeout_sec=0.02)
            if done():
                return True
        return False

    def close(self) -> None:
        self.executor.shutdown()
        if self.node is not None:
            self.node.destroy_node()
        self.tester.destroy_node()


def publish_still_robot(harness: Harness, q: np.ndarray, names: tuple[str, ...], count: int = 20) -> None:
    stamp0 = 1_700_000_000
    for k in range(count):
        message = JointState()
        message.header.stamp.sec = stamp0
        message.header.stamp.nanosec = k * 2_000_000
        message.name = list(names)
        message.position = q.tolist()
        harness.joint_states.publish(message)
        harness.spin_until(lambda: False, timeout=0.01)


def check_outputs(harness: Harness, model, q: np.ndarray) -> None:
    assert harness.spin_until(lambda: all(harness.received.values())), f"no output: {harness.received}"
    expected = forward_recursion(model, q, np.zeros_like(q), np.zeros_like(q))
    root = expected.in_root()
    hand = model.link_index["panda_hand"]
    message = harness.received["link_states"][-1]
    assert message.header.frame_id == model.root_link
    assert list(message.joint_names) == list(model.link_names)
    point = message.points[0]
    for k in range(len(model.link_names)):
        t = point.transforms[k].translation
        np.testing.assert_allclose([t.x, t.y, t.z], root.position[k], atol=1e-9)
        a = point.accelerations[k].linear
        np.testing.assert_allclose([a.x, a.y, a.z], root.accel[k], atol=1e-6)  # +9.81 up at rest
    accel = harness.received["accel"][-1]
    assert accel.header.frame_id == "panda_hand"
    a = accel.accel.linear
    np.testing.assert_allclose([a.x, a.y, a.z], expected.accel[hand], atol=1e-6)
    imu = harness.received["imu"][-1]
    a = imu.linear_acceleration
    np.testing.assert_allclose([a.x, a.y, a.z], expected.accel[hand], atol=1e-6)
    assert list(imu.linear_acceleration_covariance) == [0.0] * 9


COMMON = [
    Parameter("accel_links", value=["panda_hand"]),
    Parameter("imu_links", value=["panda_hand"]),
    Parameter("estimator.mode", value="causal"),
]


def test_model_from_the_parameter(context) -> None:
    model = load_model(PANDA)
    harness = Harness(context, [Parameter("robot_description", value=PANDA.read_text()), *COMMON])
    try:
        harness.start_node()
        harness.spin_until(lambda: harness.joint_states.get_subscription_count() > 0)
        q = np.linspace(-0.5, 0.5, len(model.joint_names))
        publish_still_robot(harness, q, model.joint_names)
        check_outputs(harness, model, q)
    finally:
        harness.close()


def test_model_from_the_transient_local_topic_published_before_the_node_started(context) -> None:
    model = load_model(PANDA)
    harness = Harness(context, COMMON)
    latched = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL, reliability=ReliabilityPolicy.RELIABLE)
    description = harness.tester.create_publisher(String, "/robot_description", latched)
    try:
        description.publish(String(data=PANDA.read_text()))
        harness.start_node()
        assert harness.spin_until(lambda: harness.node.pipeline.model is not None), "model never arrived"
        harness.spin_until(lambda: harness.joint_states.get_subscription_count() > 0)
        q = np.linspace(0.3, -0.3, len(model.joint_names))
        publish_still_robot(harness, q, model.joint_names)
        check_outputs(harness, model, q)
    finally:
        harness.close()
