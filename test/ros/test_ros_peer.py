"""``neforward run``, the node without ROS over Cyclone DDS, as a peer of a real ROS 2 Jazzy graph:
the ros2 tools see it like any node, and an rclpy client gets from it what it gets from neforward_node."""

from __future__ import annotations

import re

import numpy as np
import yaml

from neforward_ros import load_model
from neforward_ros.dds.types import type_hash

from .ros_checks import moving_plan, stamp_ns
from .ros_harness import PANDA

MODEL = load_model(PANDA)
TYPES = {
    "link_states": "trajectory_msgs/msg/MultiDOFJointTrajectory",
    "com_states": "trajectory_msgs/msg/MultiDOFJointTrajectory",
    "panda_hand/imu": "sensor_msgs/msg/Imu",
}


def numbers(message) -> list[float]:
    """Every number of a message, in order."""
    if isinstance(message, dict):
        return [x for value in message.values() for x in numbers(value)]
    if isinstance(message, list):
        return [x for value in message for x in numbers(value)]
    return [float(message)] if isinstance(message, (int, float)) and not isinstance(message, bool) else []


def test_neforward_run_is_a_ros2_node_with_the_same_outputs_as_neforward_node(graph, tmp_path) -> None:
    params = tmp_path / "params.yaml"
    params.write_text(yaml.safe_dump({"/**/neforward": {"ros__parameters": {"imu_links": ["panda_hand"]}}}))
    common = ["--ros-args", "--params-file", str(params), "-r", "joint_states:=/joint_states"]
    ros = graph.start("ros2", "run", "neforward_ros", "neforward_node", *common, "-r", "__ns:=/ros")
    dds = graph.start(
        "ros2", "run", "neforward_ros", "neforward", "run", "--urdf", str(PANDA), *common, "-r", "__ns:=/dds"
    )
    graph.latch(PANDA, "/ros/robot_description")  # neforward_node takes the model from the topic
    ros.wait_for("model 'panda'")
    dds.wait_for("model 'panda'")

    nodes = graph.ros2("node", "list", "--no-daemon").stdout.split()
    assert "/ros/neforward" in nodes and "/dds/neforward" in nodes, nodes
    for suffix, typename in TYPES.items():
        hashes = {}
        for namespace in ("ros", "dds"):
            info = graph.ros2("topic", "info", "-v", "--no-daemon", f"/{namespace}/neforward/{suffix}").stdout
            assert "Node name: neforward" in info and f"Node namespace: /{namespace}" in info, info
            hashes[namespace] = re.findall(r"Topic type hash: (\S+)", info)
        assert hashes["ros"] == hashes["dds"] == [type_hash(typename)], hashes  # rclpy's own hash = ours

    record = {f"/{ns}/neforward/{suffix}": typename for ns in ("ros", "dds") for suffix, typename in TYPES.items()}
    received = graph.client(moving_plan(MODEL, count=100, record=record, expect=60))
    for suffix in TYPES:
        from_ros, from_dds = received[f"/ros/neforward/{suffix}"], received[f"/dds/neforward/{suffix}"]
        assert len(from_ros) == len(from_dds) == 60, suffix  # fixed lag: all but the first and last 0.1 s
        assert [stamp_ns(m) for m in from_ros] == [stamp_ns(m) for m in from_dds]
        np.testing.assert_allclose(numbers(from_dds), numbers(from_ros), rtol=1e-12, atol=1e-12, err_msg=suffix)
        assert [m["header"]["frame_id"] for m in from_ros] == [m["header"]["frame_id"] for m in from_dds]

    graph.feeder(moving_plan(MODEL, count=100_000, rate=100.0))
    echo = graph.ros2(
        "topic", "echo", "--once", "--no-daemon", "/dds/neforward/panda_hand/imu", TYPES["panda_hand/imu"]
    )
    assert echo.returncode == 0 and "linear_acceleration:" in echo.stdout  # ros2cli decodes the DDS node's bytes
