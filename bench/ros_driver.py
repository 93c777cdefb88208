"""The rclpy side of bench_ros.py, run with ROS 2's Python in the benchmark's ROS environment.

python ros_driver.py drive --names a,b,c --rate 500 --seconds 3 --topic /neforward/link_states
    publishes JointState (positions only, stamped with the wall clock at publishing) and takes
    the outputs raw; prints one JSON line: sent, received, latencies (ms).
python ros_driver.py echo
    the floor: an rclpy node that publishes each JointState it takes, as it came, on /echo.
python ros_driver.py rounds --count 5000
    what the executor's round per message costs: a subscriber that does nothing takes ``count``
    queued JointStates once through the executor (one round each) and once taking the queued ones in
    its callback with the node's own ``ros_node.take_queued``; prints one JSON line of us per message.
python ros_driver.py serialization --urdf robot.urdf
    the cost of one link_states message built as an rclpy message object and serialized, against
    neforward_ros.cdr's encoder, on the same contents; prints one JSON line.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import threading
import time

import rclpy
from builtin_interfaces.msg import Time
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import QoSProfile
from sensor_msgs.msg import JointState
from trajectory_msgs.msg import MultiDOFJointTrajectory

NS = 1_000_000_000


def stamp_of(data: bytes) -> int:
    """Header stamp of a serialized message that starts with a std_msgs/Header."""
    sec = int.from_bytes(data[4:8], "little", signed=True)
    return sec * NS + int.from_bytes(data[8:12], "little")


def drive(arguments: argparse.Namespace) -> None:
    rclpy.init()
    node = Node("bench_driver")
    deep = QoSProfile(depth=100_000)
    publisher = node.create_publisher(JointState, "/joint_states", deep)
    received: list[tuple[int, int]] = []

    def take(data: bytes) -> None:
        received.append((time.time_ns(), stamp_of(data)))

    subscription = node.create_subscription(JointState if arguments.topic == "/echo" else MultiDOFJointTrajectory,
                                            arguments.topic, take, deep, raw=True)  # fmt: skip
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    deadline = time.monotonic() + 30
    while not (publisher.get_subscription_count() and subscription.get_publisher_count()):
        if time.monotonic() > deadline:
            print(json.dumps({"error": "no match"}))
            return
        executor.spin_once(timeout_sec=0.05)
    end = time.monotonic() + 0.5
    while time.monotonic() < end:
        executor.spin_once(timeout_sec=0.05)
    spinning = threading.Event()

    def spin() -> None:
        while not spinning.is_set():
            executor.spin_once(timeout_sec=0.01)

    thread = threading.Thread(target=spin, daemon=True)
    thread.start()
    names = arguments.names.split(",")
    count = int(arguments.rate * arguments.seconds)
    stamps = []
    start = time.monotonic()
    for k in range(count):
        delay = start + k / arguments.rate - time.monotonic()
        if delay > 0:
            time.sleep(delay)
        t = k / arguments.rate
        message = JointState(name=names, position=[0.3 * math.sin(t * (j + 1)) for j in range(len(names))])
        now = time.time_ns()
        message.header.stamp = Time(sec=now // NS, nanosec=now % NS)
        publisher.publish(message)
        stamps.append(now)
    time.sleep(1.5)
    spinning.set()
    thread.join(timeout=5)
    print(json.dumps({"stamps": stamps, "received": received}))
    node.destroy_node()
    rclpy.try_shutdown()


def echo(arguments: argparse.Namespace) -> None:
    rclpy.init()
    node = Node("bench_echo")
    publisher = node.create_publisher(JointState, "/echo", 10)
    node.create_subscription(JointState, "/joint_states", publisher.publish, 10, raw=True)
    try:
        rclpy.spin(node)
    except KeyboardInterrupt:
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()


def rounds(arguments: argparse.Namespace) -> None:
    from neforward_ros.ros_node import take_queued

    rclpy.init()
    node = Node("bench_rounds")
    deep = QoSProfile(depth=arguments.count * 2)
    publisher = node.create_publisher(JointState, "/rounds", deep)
    got = [0]
    subscription = None
    taking = False

    def count(data: bytes) -> None:
        got[0] += 1

    def take(data: bytes) -> None:
        count(data)
        if taking:  # as the node's callback does
            take_queued(subscription, JointState, count)

    subscription = node.create_subscription(JointState, "/rounds", take, deep, raw=True)
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    message = JointState(name=[f"j{k}" for k in range(7)], position=[0.1] * 7)
    costs = {}
    for taking in (False, True):
        got[0] = 0
        for _ in range(arguments.count):  # queued before the subscriber spins
            publisher.publish(message)
        time.sleep(0.5)
        start = time.perf_counter()
        deadline = time.monotonic() + 60
        while got[0] < arguments.count and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.05)
        costs["taken" if taking else "rounds"] = (time.perf_counter() - start) / max(got[0], 1) * 1e6
        costs["received_taken" if taking else "received_rounds"] = got[0]
    print(json.dumps(costs))
    node.destroy_node()
    rclpy.try_shutdown()


def serialization(arguments: argparse.Namespace) -> None:
    import numpy as np
    from motion_family import EPOCH_NS
    from rclpy.serialization import serialize_message
    from rosidl_runtime_py.set_message import set_message_fields

    from neforward_ros import load_model
    from neforward_ros.computation.result import make_result
    from neforward_ros.interface import messages, topics
    from neforward_ros.kinematics.forward import kinematics_table, root_state
    from neforward_ros.wire import cdr

    model = load_model(arguments.urdf)
    n = len(model.joint_names)
    q = np.linspace(-0.5, 0.5, n)
    result = make_result(model, EPOCH_NS, kinematics_table(model, q, q, q, root_state()))

    def typed() -> bytes:  # set_message_fields consumes its contents: both paths build them anew
        message = MultiDOFJointTrajectory()
        set_message_fields(message, messages.link_states(result))
        return serialize_message(message)

    def ours() -> bytes:
        return cdr.encode(topics.LINK_STATES_TYPE, messages.link_states(result))

    assert typed() == ours(), "the two paths must give the same bytes"
    timings = {}
    for name, function in (("typed", typed), ("cdr", ours)):
        best = math.inf
        for _ in range(5):
            start = time.perf_counter()
            for _ in range(200):
                function()
            best = min(best, (time.perf_counter() - start) / 200)
        timings[name] = best * 1e6
    print(json.dumps(timings))


def main() -> None:
    parser = argparse.ArgumentParser()
    commands = parser.add_subparsers(dest="command", required=True)
    d = commands.add_parser("drive")
    d.add_argument("--names", required=True)
    d.add_argument("--rate", type=float, required=True)
    d.add_argument("--seconds", type=float, required=True)
    d.add_argument("--topic", required=True)
    commands.add_parser("echo")
    r = commands.add_parser("rounds")
    r.add_argument("--count", type=int, default=5000)
    s = commands.add_parser("serialization")
    s.add_argument("--urdf", required=True)
    arguments = parser.parse_args()
    {"drive": drive, "echo": echo, "rounds": rounds, "serialization": serialization}[arguments.command](arguments)


if __name__ == "__main__":
    sys.exit(main())
