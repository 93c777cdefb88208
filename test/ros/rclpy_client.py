"""A real rclpy client of the node, run by the ROS suite in its own process with ROS 2's Python.

It does what a ROS user's own node would: publishes joint states of a moving robot (or supplied
states, or a robot description, or a /clock) with ordinary typed rclpy publishers, subscribes to the
node's outputs with ordinary typed subscriptions, and writes everything it received as JSON (each
message through rosidl_runtime_py's message_to_ordereddict) for the test to check.

    python rclpy_client.py stream --plan plan.json --out received.json
    python rclpy_client.py latch --urdf robot.urdf          # robot_description, transient local, until SIGINT

The plan (JSON) names the joints, the trajectory q_j(t) = amplitude_j sin(2 pi frequency_j t + phase_j)
with t = (stamp - epoch) seconds, the rate and count, what to put in each message, and the topics
to record (name -> type).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import rclpy
from builtin_interfaces.msg import Duration, Time
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rosgraph_msgs.msg import Clock
from rosidl_runtime_py.convert import message_to_ordereddict
from rosidl_runtime_py.utilities import get_message
from sensor_msgs.msg import JointState
from std_msgs.msg import String
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint

NS = 1_000_000_000
LONGEST = 60.0
"""s: the most a client waits for the expected outputs after its last input (its harness allows 120 s in all)."""


def trajectory(plan: dict, t: float) -> tuple[list[float], list[float], list[float]]:
    q, qd, qdd = [], [], []
    for amplitude, frequency, phase in zip(plan["amplitude"], plan["frequency"], plan["phase"], strict=True):
        w = 2.0 * math.pi * frequency
        q.append(amplitude * math.sin(w * t + phase))
        qd.append(amplitude * w * math.cos(w * t + phase))
        qdd.append(-amplitude * w * w * math.sin(w * t + phase))
    return q, qd, qdd


def stamp(ns: int) -> Time:
    return Time(sec=ns // NS, nanosec=ns % NS)


class Client(Node):
    def __init__(self, plan: dict) -> None:
        super().__init__("neforward_test_client")
        self.plan = plan
        self.received: dict[str, list] = {topic: [] for topic in plan.get("record", {})}
        self.recorders = [
            self.create_subscription(get_message(typename), topic, self._keeper(topic), QoSProfile(depth=10_000))
            for topic, typename in plan.get("record", {}).items()
        ]
        reliability = ReliabilityPolicy.BEST_EFFORT if plan.get("best_effort") else ReliabilityPolicy.RELIABLE
        qos = QoSProfile(depth=10_000, reliability=reliability)
        kind = JointTrajectory if plan.get("supplied") else JointState
        self.publisher = self.create_publisher(kind, plan.get("topic", "/joint_states"), qos)
        self.clock = self.create_publisher(Clock, "/clock", 10) if plan.get("sim_time_ns") else None

    def _keeper(self, topic: str):
        def keep(message) -> None:
            self.received[topic].append(message_to_ordereddict(message))

        return keep

    def spin_for(self, seconds: float) -> None:
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline:
            rclpy.spin_once(self, timeout_sec=0.01)

    def wait_matched(self, timeout: float) -> bool:
        """Until the node subscribes to what we publish and publishes what we record."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            clock_matched = self.clock is None or self.clock.get_subscription_count()  # sim time: the node's /clock
            if (
                self.publisher.get_subscription_count()
                and clock_matched
                and all(s.get_publisher_count() for s in self.recorders)
            ):
                self.spin_for(0.5)  # the other side of the match
                return True
            rclpy.spin_once(self, timeout_sec=0.05)
        return False

    def message(self, k: int):
        plan = self.plan
        t_ns = k * round(NS / plan["rate"])
        q, qd, qdd = trajectory(plan, t_ns / NS)
        header_ns = 0 if plan.get("zero_stamps") else plan["epoch_ns"] + t_ns
        names = plan["names"]
        omit = plan.get("omit", [])
        if omit:  # joints nobody publishes
            keep = [i for i, name in enumerate(names) if name not in omit]
            names = [names[i] for i in keep]
            q, qd, qdd = ([x[i] for i in keep] for x in (q, qd, qdd))
        if plan.get("supplied"):
            message = JointTrajectory(joint_names=names)
            message.header.stamp = stamp(header_ns)
            point = JointTrajectoryPoint(positions=q, velocities=qd, accelerations=qdd)
            offset = plan.get("time_from_start_ns", 0)
            point.time_from_start = Duration(sec=offset // NS, nanosec=offset % NS)
            message.points = [point]
            return message
        message = JointState(name=names, position=q)
        message.header.stamp = stamp(header_ns)
        if plan.get("velocities"):
            message.velocity = qd
        if plan.get("efforts"):  # one row per message, for the names sent
            message.effort = [float(e) for e in plan["efforts"][k]]
        return message

    def stream(self) -> None:
        plan = self.plan
        period = 1.0 / plan["rate"]
        start = time.monotonic()
        for k in range(plan["count"]):
            delay = start + k * period - time.monotonic()
            if delay > 0 and not plan.get("burst"):  # a burst: every message at once, stamped at the rate
                self.spin_for(delay)
            if self.clock is not None:
                step = plan.get("sim_step_ns", round(NS / plan["rate"]))  # the clock's advance per message
                self.clock.publish(Clock(clock=stamp(plan["sim_time_ns"] + k * step)))
            self.publisher.publish(self.message(k))
            rclpy.spin_once(self, timeout_sec=0)
        # Then until every recorded topic has the outputs expected, or none has come for ``linger`` s: on a
        # loaded machine the node, and this client turning each message into a dict, may still be working
        # through a backlog when the last input goes out (at most LONGEST s).
        expected = plan.get("expect", 0)
        quiet = plan.get("linger", 3.0)
        count, changed = -1, time.monotonic()
        deadline = time.monotonic() + max(quiet, LONGEST)
        while time.monotonic() < deadline:
            self.spin_for(0.05)
            if expected and all(len(v) >= expected for v in self.received.values()):
                break
            now_count = sum(len(v) for v in self.received.values())
            if now_count != count:
                count, changed = now_count, time.monotonic()
            elif time.monotonic() - changed >= quiet:
                break


def stream(arguments: argparse.Namespace) -> int:
    plan = json.loads(Path(arguments.plan).read_text())
    rclpy.init()
    client = Client(plan)
    try:
        if not client.wait_matched(plan.get("match_timeout", 30.0)):
            print("client: the node never matched our publisher and subscriptions", file=sys.stderr)
            if not plan.get("publish_unmatched"):
                return 2
        client.stream()
        Path(arguments.out).write_text(json.dumps(client.received))
    except KeyboardInterrupt:  # a background feeder, stopped by its test
        pass
    finally:
        client.destroy_node()
        rclpy.try_shutdown()
    return 0


def latch(arguments: argparse.Namespace) -> int:
    rclpy.init()
    node = Node("neforward_test_description")
    qos = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL, reliability=ReliabilityPolicy.RELIABLE)
    publisher = node.create_publisher(String, arguments.topic, qos)
    publisher.publish(String(data=Path(arguments.urdf).read_text()))
    print("published", flush=True)
    try:
        rclpy.spin(node)
    except KeyboardInterrupt:
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


def main() -> int:
    parser = argparse.ArgumentParser()
    commands = parser.add_subparsers(dest="command", required=True)
    s = commands.add_parser("stream")
    s.add_argument("--plan", required=True)
    s.add_argument("--out", required=True)
    la = commands.add_parser("latch")
    la.add_argument("--urdf", required=True)
    la.add_argument("--topic", default="/robot_description")
    arguments = parser.parse_args()
    return stream(arguments) if arguments.command == "stream" else latch(arguments)


if __name__ == "__main__":
    sys.exit(main())
