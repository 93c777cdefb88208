"""End-to-end latency and sustained rate of the rclpy node, ``ros2 run neforward_ros neforward_node``,
on a real ROS 2 Jazzy (rmw_cyclonedds on loopback), against an rclpy echo floor in the same run.

Needs ROS 2 Jazzy at /opt/ros/jazzy and the ROS Python with the package's dependencies (``make test``
prepares .venv-ros; the script uses it, or NEFORWARD_ROS_PYTHON). It builds the package with colcon
in a temporary workspace, then for each robot and rate: an rclpy driver publishes JointState
(positions only, stamped with the wall clock at publishing) for a few seconds and takes
``/neforward/link_states`` raw; latency is receive time minus input stamp. The node runs in causal
mode and in the default fixed-lag mode, where latency is counted, as in bench_dds.py, from the
input that completed the output (the first one ``lag`` after it): processing, not the lag. The
floor is an rclpy node that publishes every JointState it takes straight back, with no computation.

It also prints what one round of rclpy's executor costs per message (``ros_driver.py rounds``: queued
messages taken one round each, or in the callback as the node takes them), and what building one
link_states message costs the two ways the rclpy node could do it:
as an rclpy message object, serialized by rclpy, or with neforward_ros.cdr's encoder (what it does).

Usage: python bench/bench_ros.py [--seconds 3] [--rates 250,500,1000,2000] [--method kalman] [--robots arm]
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
    parser.add_argument("--rates", default="500,1000,2000")
    parser.add_argument("--robots", default="arm,humanoid", help="which robots (comma-separated)")
    parser.add_argument("--modes", default="fixed_lag,causal")
    parser.add_argument("--fixed-window", action="store_true", help="estimator.adaptive false (the fixed window)")
    parser.add_argument("--method", default="polyfit", help="estimator.method (polyfit, kalman)")
    parser.add_argument("--depth", type=int, default=500, help="the node's qos_depth (its default: 500)")
    args = parser.parse_args()
    if not os.environ.get("NEFORWARD_ROS_PYTHON") and (ROOT / ".venv-ros" / "bin" / "python").exists():
        os.environ["NEFORWARD_ROS_PYTHON"] = str(ROOT / ".venv-ros" / "bin" / "python")
    from bench_dds import print_row, summary
    from ros.ros_harness import Graph, Workspace, why_not_runnable

    from neforward_ros import load_model
    from neforward_ros.dds.loopback import write_config
    from neforward_ros.estimation.settings import StreamSettings

    reason = why_not_runnable()
    if reason:
        sys.exit(f"bench_ros: {reason}")
    directory = Path(tempfile.mkdtemp(prefix="neforward-bench-ros-"))
    workspace = Workspace(directory / "ws")
    config = write_config(directory)

    graph = Graph(workspace, config, directory)

    def measured(what: str, *command: str) -> dict:
        """The JSON line a ros_driver.py command prints (ROS 2's Python), or exit saying what failed."""
        done = graph.run(workspace.python, str(DRIVER), *command)
        if done.returncode != 0:
            sys.exit(f"bench_ros: the {what} measurement failed:\n{done.stderr}")
        return json.loads(done.stdout)

    costs = measured("serialization", "serialization", "--urdf", str(ROBOTS["arm (13 links, 8 joints)"]))
    print(
        f"one arm link_states message: rclpy message object + rclpy serialization {costs['typed']:.0f} us, "
        f"neforward_ros.cdr {costs['cdr']:.0f} us ({costs['typed'] / costs['cdr']:.1f}x faster; same bytes)"
    )
    rounds = measured("executor", "rounds", "--count", "5000")
    print(
        f"5000 queued JointStates to a subscriber that does nothing: {rounds['rounds']:.0f} us each through "
        f"rclpy's executor (a round each), {rounds['taken']:.0f} us taken in its callback as the node takes "
        f"them ({rounds['rounds'] / rounds['taken']:.1f}x)"
    )
    print(f"rmw_cyclonedds on loopback; {args.seconds:g} s per rate; latency from the completing input")
    print(
        f"{'robot':<10} {'mode':<10} {'rate':>6} {'floor p50':>10} {'p99':>6} {'node p50':>9} {'p99':>6}"
        f" {'above floor':>12} {'lost':>12} {'warm-up ms':>10}"
    )
    for label, path in ROBOTS.items():
        if not any(wanted in label for wanted in args.robots.split(",")):
            continue
        names = ",".join(load_model(path).joint_names)
        for mode in args.modes.split(","):
            lag_ns = round(StreamSettings(method=args.method, mode=mode).effective_lag * 1e9)
            params = directory / f"{path.stem}-{mode}.yaml"
            params.write_text(
                f"/**/neforward:\n  ros__parameters:\n    qos_depth: {args.depth}\n    estimator:\n"
                f"      mode: {mode}\n      method: {args.method}\n"
                f"      adaptive: {'false' if args.fixed_window else 'true'}\n"
                f"    robot_description: {json.dumps(path.read_text())}\n"
            )
            for rate in (float(r) for r in args.rates.split(",")):
                results = {}
                for what in ("floor", "node"):
                    graph = Graph(workspace, config, directory)
                    if what == "floor":
                        graph.start(workspace.python, str(DRIVER), "echo")
                        topic = "/echo"
                    else:
                        process = graph.start(
                            "ros2", "run", "neforward_ros", "neforward_node", "--ros-args", "--params-file", str(params)
                        )
                        process.wait_for("model")
                        topic = "/neforward/link_states"
                    try:
                        done = graph.run(
                            workspace.python, str(DRIVER), "drive", "--names", names, "--rate", str(rate),
                            "--seconds", str(args.seconds), "--topic", topic, timeout=120,
                        )  # fmt: skip
                    finally:
                        graph.stop_all()
                    measured = json.loads(done.stdout.strip().splitlines()[-1])
                    stamps = np.array(measured["stamps"], dtype=np.int64)
                    received = [(int(a), int(b)) for a, b in measured["received"]]
                    lag = lag_ns if what == "node" else 0
                    results[what] = summary(stamps, received, lag, what == "node")
                labels = [f"{label.split()[0]:<10}", f"{mode:<10}", f"{rate:>6.0f}"]
                print_row(labels, results["floor"], results["node"])


if __name__ == "__main__":
    main()
