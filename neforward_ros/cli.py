"""The ``neforward`` command.

- ``neforward demo``: the node live over loopback DDS, fed by a synthetic 500 Hz joint-state
  publisher, with a live view and a latency summary (:mod:`neforward_ros.demo.live`).
- ``neforward run``: the node over Cyclone DDS without ROS; ``neforward echo``: print a topic.
- ``neforward table``: each link's omega, alpha, accel and com_accel along a short trajectory of a
  bundled (or ``--urdf``) robot, computed in one batched call of
  :func:`neforward_ros.forward_recursion`, with no DDS at all.
"""

from __future__ import annotations

import argparse
import math
import sys
from collections.abc import Sequence

from neforward_ros.errors import NeforwardError
from neforward_ros.recursion import DEFAULT_GRAVITY
from neforward_ros.resources import DEFAULT_ROBOT


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="neforward", description=__doc__.splitlines()[0])
    commands = parser.add_subparsers(dest="command", required=True)
    demo = commands.add_parser(
        "demo", help="the node live on loopback DDS with a synthetic 500 Hz joint-state publisher and a live view"
    )
    demo.add_argument("--urdf", help=f"URDF file (default: the bundled {DEFAULT_ROBOT})")
    demo.add_argument("--seconds", type=float, default=10.0, help="how long to publish, s (default 10)")
    demo.add_argument("--rate", type=float, default=500.0, help="joint-state rate, Hz (default 500)")
    demo.add_argument(
        "--method", choices=("polyfit", "kalman", "difference"), default="polyfit", help="estimator (default polyfit)"
    )
    demo.add_argument("--mode", choices=("fixed_lag", "causal"), default="fixed_lag", help="default fixed_lag")
    demo.add_argument("--root-link", help="the link whose frame is the root frame (default: the URDF's root)")
    table = commands.add_parser("table", help="print every link's omega, alpha, accel, com_accel along a trajectory")
    table.add_argument("--urdf", help=f"URDF file (default: the bundled {DEFAULT_ROBOT})")
    table.add_argument("--seconds", type=float, default=1.0, help="trajectory duration in s (default 1)")
    table.add_argument("--samples", type=int, default=5, help="instants to print (default 5)")
    table.add_argument("--root-link", help="the link whose frame is the root frame (default: the URDF's root)")
    run = commands.add_parser(
        "run",
        help="the neforward node over Cyclone DDS, without ROS (same topics, types, parameters as neforward_node)",
    )
    run.add_argument("--urdf", help="URDF file (default: wait for the robot_description topic)")
    run.add_argument("--params", help="ROS 2 params file (neforward: ros__parameters: ...)")
    run.add_argument(
        "--ros-args",
        dest="ros_args_marker",
        action="store_true",
        help="the rest are ROS 2 arguments: -r from:=to (also __ns, __node), -p name:=value, --params-file F",
    )
    echo = commands.add_parser("echo", help="print a topic's messages as YAML, like ros2 topic echo")
    echo.add_argument("topic", help="topic name, e.g. /neforward/link_states")
    echo.add_argument(
        "--type", help="message type pkg/msg/Type (default: known for neforward's topics, else discovered)"
    )
    echo.add_argument("--count", type=int, help="exit after this many messages")
    bag = commands.add_parser("bag", help="a rosbag2 recording of joint states in; the node's outputs out")
    bag.add_argument("input", help="rosbag2 recording (folder or .mcap/.db3), sqlite3 or MCAP")
    bag.add_argument("-o", "--output", required=True, help="output recording (must not exist)")
    bag.add_argument("--urdf", help="URDF file (default: the recording's robot_description topic)")
    bag.add_argument("--joint-states", help="joint-state topic (default: the recording's JointState topic)")
    bag.add_argument("--csv", help="also write a CSV: one row per sample, columns per link and component")
    bag.add_argument("--plot", help="also write a PNG of every link's |a| and |alpha| with the peaks marked")
    bag.add_argument("--format", choices=("mcap", "sqlite3"), default="mcap", help="output storage (default mcap)")
    bag.add_argument("--accel-links", default="", help="comma-separated links that also get accel and twist topics")
    bag.add_argument("--imu-links", default="", help="comma-separated links that also get an imu topic")
    bag.add_argument("--gravity", type=float, nargs=3, default=None, metavar=("X", "Y", "Z"), help="m/s^2")
    bag.add_argument(
        "--publish-policy",
        choices=("partial", "wait", "hold"),
        default="partial",
        help="stamps where some joints have no estimate: partial writes the links they do not move (default), "
        "wait writes nothing, hold holds joints with no sample near (see --hold)",
    )
    bag.add_argument(
        "--hold",
        action="append",
        default=[],
        metavar="JOINT=POSITION",
        help="with --publish-policy hold: a joint's held position (others 0); repeat for more joints",
    )
    bag.add_argument(
        "--torques",
        action="store_true",
        help="also write joint_torques (the model's) and external_torques (recorded effort - model)",
    )
    bag.add_argument("--wrench-links", default="", help="comma-separated links that also get a wrench topic")
    bag.add_argument(
        "--effort",
        action="append",
        default=[],
        metavar="JOINT=SCALE[,OFFSET]",
        help="measured effort = SCALE * recorded effort + OFFSET for a joint; repeat for more joints",
    )
    bag.add_argument(
        "--contact",
        action="append",
        default=[],
        metavar="JOINT=THRESHOLD",
        help="write contact (std_msgs/Bool): a joint's |external torque| threshold; repeat for more joints",
    )
    bag.add_argument("--contact-debounce", type=float, default=0.02, help="s (default 0.02)")
    bag.add_argument(
        "--base",
        choices=("fixed", "imu", "odometry"),
        default="fixed",
        help="the root link's motion: fixed (default), or from a sensor_msgs/Imu or nav_msgs/Odometry topic",
    )
    bag.add_argument("--base-topic", help="the base topic (default: the recording's one topic of that type)")
    bag.add_argument("--base-link", default="", help="the link the base topic measures (default: its frame id)")
    bag.add_argument("--world-frame", default="", help="also write world_link_states with this frame id")
    bag.add_argument("--root-link", help="the link whose frame is the root frame (default: the URDF's root)")
    return parser


def _per_joint(items: Sequence[str], option: str, width: int = 1) -> dict[str, list[float]]:
    """JOINT=V (or V,W with width 2) items as joint -> numbers."""
    out = {}
    for item in items:
        name, _, value = item.partition("=")
        try:
            numbers = [float(v) for v in value.split(",")]
        except ValueError:
            numbers = []
        if not name.strip() or not 1 <= len(numbers) <= width:
            shape = "JOINT=NUMBER" if width == 1 else "JOINT=NUMBER[,NUMBER]"
            raise NeforwardError(f"{option} takes {shape}, got {item!r}")
        out[name.strip()] = numbers
    return out


def main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    ros_args: list[str] = []
    if "--ros-args" in argv:  # everything after it belongs to ROS, as with ros2 run
        split = argv.index("--ros-args")
        argv, ros_args = argv[: split + 1], argv[split + 1 :]
    args = build_parser().parse_args(argv)
    try:
        if args.command == "table":
            if args.samples < 1 or not (math.isfinite(args.seconds) and args.seconds >= 0):
                raise NeforwardError("--samples must be at least 1 and --seconds a non-negative number")
            from neforward_ros.demo.table import print_table

            print_table(args.urdf, args.seconds, args.samples, args.root_link)
        elif args.command == "demo":
            if not (math.isfinite(args.seconds) and args.seconds > 0 and math.isfinite(args.rate) and args.rate > 0):
                raise NeforwardError("--seconds and --rate must be positive numbers")
            from neforward_ros.demo.live import live_demo
            from neforward_ros.estimation.stream import StreamSettings

            estimator = StreamSettings(method=args.method, mode=args.mode)
            return live_demo(args.seconds, args.urdf, args.rate, estimator, args.root_link)
        elif args.command == "run":
            from neforward_ros.dds.commands import run_node

            return run_node(args.urdf, args.params, ros_args)
        elif args.command == "bag":
            from neforward_ros.bag import BagOptions, Progress, describe, process_bag

            efforts = _per_joint(args.effort, "--effort", width=2)
            options = BagOptions(
                urdf=args.urdf,
                joint_states_topic=args.joint_states,
                storage=args.format,
                accel_links=tuple(filter(None, args.accel_links.split(","))),
                imu_links=tuple(filter(None, args.imu_links.split(","))),
                gravity=tuple(args.gravity) if args.gravity else DEFAULT_GRAVITY,
                publish_policy=args.publish_policy,
                hold_positions={k: v[0] for k, v in _per_joint(args.hold, "--hold").items()},
                publish_torques=args.torques,
                wrench_links=tuple(filter(None, args.wrench_links.split(","))),
                effort_scale={k: v[0] for k, v in efforts.items()},
                effort_offset={k: v[1] if len(v) > 1 else 0.0 for k, v in efforts.items()},
                contact_thresholds={k: v[0] for k, v in _per_joint(args.contact, "--contact").items()},
                contact_debounce=args.contact_debounce,
                base_source=args.base,
                base_topic=args.base_topic,
                base_link=args.base_link,
                world_frame=args.world_frame,
                root_link=args.root_link,
            )
            report = process_bag(
                args.input, args.output, options, csv_path=args.csv, plot_path=args.plot, progress=Progress()
            )
            print(describe(report))
        elif args.command == "echo":
            from neforward_ros.dds.commands import echo

            return echo(args.topic, args.type, args.count)
    except (NeforwardError, FileNotFoundError) as exc:
        print(f"neforward: error: {exc}", file=sys.stderr)
        return 1
    except BrokenPipeError:  # output piped into `head` and the like
        sys.stderr.close()
        return 0
    return 0


if __name__ == "__main__":
    sys.exit(main())
