"""End-to-end latency and sustained rate of the rclpy node, ``ros2 run neforward_ros neforward_node``,
on a real ROS 2 Jazzy (rmw_cyclonedds on loopback), against an rclpy echo floor in the same run.

Needs ROS 2 Jazzy at /opt/ros/jazzy and the ROS Python with the package's dependencies (``make test``
prepares .venv-ros; the script uses it, or NEFORWARD_ROS_PYTHON). It builds the package with colcon
in a temporary workspace, then for each robot and rate: an rclpy driver publishes JointState
(positions only, stamped with the wall clock at publishing) for a few seconds and takes
``/neforward/link_states`` raw; latency is receive time minus input stamp. The node runs in causal
mode, so the latency is processing, not the estimator's lag. The floor is an rclpy node that
publishes every JointState it takes straight back, with no computation.

It also prints what building one link_states message costs the two ways the rclpy node could do it:
as an rclpy message object, serialized by rclpy, or with neforward_ros.cdr's encoder (what it does).

Usage: python bench/bench_ros.py [--seconds 3] [--rates 250,500,1000,2000]
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "test"))
DRIVER = Path(__file__).with_name("ros_driver.py")
ROBOTS = {
    "arm (13 links, 8 joints)": ROOT / "config" / "panda.urdf",
    "humanoid (34 links, 33 joints)": ROOT / "test" / "urdf" / "humanoid.urdf",
}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=3.0)
    parser.add_argument("--rates", default="250,500,1000,2000")
    parser.add_argument("--robots", default=",".join(ROBOTS), help="which robots (comma-separated labels)")
    parser.add_argument("--depth", type=int, default=10, help="the node's qos_depth")
    args = parser.parse_args()
    if not os.environ.get("NEFORWARD_ROS_PYTHON") and (ROOT / ".venv-ros" / "bin" / "python").exists():
        os.environ["NEFORWARD_ROS_PYTHON"] = str(ROOT / ".venv-ros" / "bin" / "python")
    from ros.ros_harness import Graph, Workspace, why_not_runnable

    from neforward_ros import load_model
    from neforward_ros.dds.loopback import write_config

    reason = why_not_runnable()
    if reason:
        sys.exit(f"bench_ros: {reason}")
    directory = Path(tempfile.mkdtemp(prefix="neforward-bench-ros-"))
    workspace = Workspace(directory / "ws")
    config = write_config(directory)

    graph = Graph(workspace, config, directory)
    done = graph.run(workspace.python, str(DRIVER), "serialization", "--urdf", str(ROBOTS["arm (13 links, 8 joints)"]))
    if done.returncode != 0:
        sys.exit(f"bench_ros: the serialization measurement failed:\n{done.stderr}")
    costs = json.loads(done.stdout)
    print(
        f"one arm link_states message: rclpy message object + rclpy serialization {costs['typed']:.0f} us, "
        f"neforward_ros.cdr {costs['cdr']:.0f} us ({costs['typed'] / costs['cdr']:.1f}x faster; same bytes)"
    )
    print(f"rmw_cyclonedds on loopback; {args.seconds:g} s per rate; latency = output received - input stamp")
    print(
        f"{'robot':<32} {'rate Hz':>8} {'what':>6} {'p50 ms':>8} {'p99 ms':>8} {'lost':>6}"
        f" {'p50/floor':>10} {'p99/floor':>10}"
    )
    for label, path in ROBOTS.items():
        if not any(wanted in label for wanted in args.robots.split(",")):
            continue
        names = ",".join(load_model(path).joint_names)
        params = directory / f"{path.stem}.yaml"
        params.write_text(
            f"/**/neforward:\n  ros__parameters:\n    qos_depth: {args.depth}\n    estimator:\n      mode: causal\n"
            f"    robot_description: {json.dumps(path.read_text())}\n"
        )
        for rate in (float(r) for r in args.rates.split(",")):
            results = {}
            for what in ("floor", "node"):
                graph = Graph(workspace, config, directory)
                if what == "floor":
                    process = graph.start(workspace.python, str(DRIVER), "echo")
                    topic, expected_loss = "/echo", 0
                else:
                    process = graph.start(
                        "ros2", "run", "neforward_ros", "neforward_node", "--ros-args", "--params-file", str(params)
                    )
                    process.wait_for("model")
                    topic, expected_loss = "/neforward/link_states", 2
                try:
                    done = graph.run(
                        workspace.python, str(DRIVER), "drive", "--names", names, "--rate", str(rate),
                        "--seconds", str(args.seconds), "--topic", topic, timeout=120,
                    )  # fmt: skip
                finally:
                    graph.stop_all()
                measured = json.loads(done.stdout.strip().splitlines()[-1])
                latencies = measured.get("latencies") or [float("nan")]
                p50, p99 = np.percentile(latencies, [50, 99])
                results[what] = (p50, p99)
                lost = measured.get("sent", 0) - expected_loss - measured.get("received", 0)
                ratio = ""
                if what == "node":
                    ratio = f"{p50 / results['floor'][0]:>10.1f} {p99 / results['floor'][1]:>10.1f}"
                print(f"{label:<32} {rate:>8.0f} {what:>6} {p50:>8.2f} {p99:>8.2f} {lost:>6} {ratio}", flush=True)


if __name__ == "__main__":
    main()
