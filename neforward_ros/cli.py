"""The ``neforward`` command.

- ``neforward calibrate``: recordings of free motion in, the joints' effort and friction model and
  contact thresholds out, as a params file (:mod:`neforward_ros.calibration`).
- ``neforward bag``: recordings in, the node's outputs out (:mod:`neforward_ros.bag`); ``neforward
  play``: a recording's topics (or a CSV's joint states) over DDS (:mod:`neforward_ros.dds.play`).
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
import os
import signal
import sys
from collections.abc import Sequence

from neforward_ros import ctrl_c, terminal
from neforward_ros.errors import NeforwardError
from neforward_ros.resources import DEFAULT_ROBOT


class _HelpFormatter(argparse.ArgumentDefaultsHelpFormatter):
    """Shows an option's default where it has a meaningful one (not for flags and unset options)."""

    def _get_help_string(self, action: argparse.Action) -> str:
        if action.default in (None, False, [], "", argparse.SUPPRESS) or "%(default)" in (action.help or ""):
            return action.help or ""
        return super()._get_help_string(action)


class _VersionAction(argparse.Action):
    """--version: looks the version up only when asked (importlib.metadata is slow to import)."""

    def __init__(self, option_strings: list[str], dest: str = argparse.SUPPRESS, **kwargs: object) -> None:
        super().__init__(option_strings, dest, nargs=0, default=argparse.SUPPRESS, help="show the version and exit")

    def __call__(self, parser: argparse.ArgumentParser, *args: object) -> None:
        print(f"{parser.prog} {version()}")
        parser.exit()


def version() -> str:
    from importlib.metadata import PackageNotFoundError
    from importlib.metadata import version as installed

    try:
        return installed("neforward_ros")
    except PackageNotFoundError:
        return "unknown (not installed)"


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="neforward",
        description="Every link's angular velocity, angular acceleration and linear acceleration from joint "
        "states and a URDF: the ROS 2 node without ROS (run, echo, play), offline on recordings (bag), "
        "and a demo.",
        formatter_class=_HelpFormatter,
    )
    parser.add_argument("--version", action=_VersionAction)
    commands = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    def command(name: str, help: str) -> argparse.ArgumentParser:
        return commands.add_parser(name, help=help, description=help, formatter_class=_HelpFormatter)

    demo = command("demo", "the node live on loopback DDS, fed by a synthetic 500 Hz joint-state publisher")
    demo.add_argument("--urdf", help=f"URDF file (default: the bundled {DEFAULT_ROBOT})")
    demo.add_argument("--seconds", type=float, default=10.0, help="how long to publish, s")
    demo.add_argument("--rate", type=float, default=500.0, help="joint-state rate, Hz")
    demo.add_argument("--method", choices=("polyfit", "kalman", "difference"), default="polyfit", help="estimator")
    demo.add_argument("--mode", choices=("fixed_lag", "causal"), default="fixed_lag", help="estimator mode")
    demo.add_argument("--root-link", help="the link whose frame is the root frame (default: the URDF's root)")
    table = command("table", "print every link's omega, alpha, accel and com_accel along a trajectory (no DDS)")
    table.add_argument("--urdf", help=f"URDF file (default: the bundled {DEFAULT_ROBOT})")
    table.add_argument("--seconds", type=float, default=1.0, help="trajectory duration, s")
    table.add_argument("--samples", type=int, default=5, help="instants to print")
    table.add_argument("--root-link", help="the link whose frame is the root frame (default: the URDF's root)")
    run = command("run", "the node over Cyclone DDS without ROS: the topics, types and parameters of neforward_node")
    run.add_argument("--urdf", help="URDF or xacro file (default: wait for the robot_description topic)")
    run.add_argument("--params", help="ROS 2 params file (neforward: ros__parameters: ...)")
    run.add_argument(
        "--ros-args",
        dest="ros_args_marker",
        action="store_true",
        help="the rest are ROS 2 arguments: -r from:=to (also __ns, __node), -p name:=value, --params-file F",
    )
    echo = command("echo", "print a topic's messages as YAML, like ros2 topic echo")
    echo.add_argument("topic", help="topic name, e.g. /neforward/link_states")
    echo.add_argument(
        "--type", help="message type pkg/msg/Type (default: known for neforward's topics, else discovered)"
    )
    echo.add_argument("--count", type=int, help="exit after this many messages")
    play = command(
        "play", "publish a rosbag2 recording's topics (or a CSV of joint states) over DDS with the original timing"
    )
    play.add_argument("input", help="rosbag2 recording (folder, .mcap or .db3), or a CSV of joint positions")
    play.add_argument("--rate", type=float, default=1.0, help="speed factor (2: twice as fast)")
    play.add_argument("--loop", action="store_true", help="start again at the end, until Ctrl-C")
    play.add_argument("--delay", type=float, default=0.0, help="s to wait after the robot_description, before the rest")
    play.add_argument(
        "--topics", nargs="+", metavar="TOPIC", help="only these topics (default: every topic of the recording)"
    )
    play.add_argument("--csv-topic", default="/joint_states", help="the topic a CSV's joint states go to")
    bag = command("bag", "rosbag2 recordings of joint states in, the node's outputs out (rosbag2, CSV, plot)")
    from neforward_ros.bag.arguments import add_bag_arguments

    add_bag_arguments(bag)
    calibrate = command(
        "calibrate",
        "recordings of free motion in: each joint's effort offset and scale, its friction and a contact threshold "
        "out, as a params file",
    )
    from neforward_ros.calibration.commands import add_calibrate_arguments

    add_calibrate_arguments(calibrate)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """The command; returns its exit status (130 after Ctrl-C, as shells count it).

    Run in-process, it leaves SIGINT's handler and ``sys.unraisablehook`` as it found them (a command
    sees a Ctrl-C met in a finalizer again, and ignores one once its work is done:
    :mod:`neforward_ros.ctrl_c`).
    """
    try:
        return _command(argv)
    finally:
        ctrl_c.release()


def _command(argv: Sequence[str] | None) -> int:
    """:func:`main`, with Ctrl-C left held off where the command's work is done."""
    try:
        argv = list(sys.argv[1:] if argv is None else argv)
        ros_args: list[str] = []
        if "--ros-args" in argv:  # everything after it belongs to ROS, as with ros2 run
            split = argv.index("--ros-args")
            argv, ros_args = argv[: split + 1], argv[split + 1 :]
        args = build_parser().parse_args(argv)
        # The command's modules (and the C extensions they load) are imported while a Ctrl-C still ends
        # the process at once: one that lands inside a C extension's import can come out as an
        # ImportError that no longer says it was an interrupt.
        _preload(args.command)
        _ctrl_c_raises()
        if args.command == "table":
            if args.samples < 1 or not (math.isfinite(args.seconds) and args.seconds >= 0):
                raise NeforwardError("--samples must be at least 1 and --seconds a non-negative number")
            from neforward_ros.demo.table import print_table

            print_table(args.urdf, args.seconds, args.samples, args.root_link)
        elif args.command == "demo":
            if not (math.isfinite(args.seconds) and args.seconds > 0 and math.isfinite(args.rate) and args.rate > 0):
                raise NeforwardError("--seconds and --rate must be positive numbers")
            from neforward_ros.demo.live import live_demo
            from neforward_ros.estimation.settings import StreamSettings

            estimator = StreamSettings(method=args.method, mode=args.mode)
            return live_demo(args.seconds, args.urdf, args.rate, estimator, args.root_link)
        elif args.command == "run":
            from neforward_ros.dds.commands import run_node

            return run_node(args.urdf, args.params, ros_args)
        elif args.command == "bag":
            from neforward_ros.bag.commands import run_bag

            return run_bag(args)
        elif args.command == "calibrate":
            from neforward_ros.calibration.commands import run_calibrate

            return run_calibrate(args)
        elif args.command == "play":
            from neforward_ros.dds.play import play

            return play(args.input, args.rate, args.loop, args.topics, args.csv_topic, args.delay)
        elif args.command == "echo":
            from neforward_ros.dds.commands import echo

            return echo(args.topic, args.type, args.count)
    except (NeforwardError, FileNotFoundError) as exc:
        if ctrl_c.came():  # an error that a library made of the Ctrl-C (an ImportError: "needs matplotlib")
            terminal.say("neforward: interrupted")
            return 130
        terminal.say(f"neforward: error: {exc}")
        return 1
    except BrokenPipeError:  # output piped into `head` and the like
        sys.stderr.close()
        return 0
    except BaseException as exc:  # Ctrl-C (perhaps wrapped): every command has cleaned up on its way out
        if not (_interrupted(exc) or ctrl_c.came()):
            raise
        terminal.say("neforward: interrupted")
        return 130
    return 0


_COMMAND_MODULES = {
    "bag": ("neforward_ros.bag.commands", "neforward_ros.bag.process"),
    "calibrate": ("neforward_ros.calibration.commands", "neforward_ros.calibration.calibrate"),
    "run": ("neforward_ros.dds.commands", "cyclonedds.domain"),
    "echo": ("neforward_ros.dds.commands", "cyclonedds.domain"),
    "play": ("neforward_ros.dds.play", "cyclonedds.domain"),
    "demo": ("neforward_ros.demo.live", "cyclonedds.domain"),
    "table": ("neforward_ros.demo.table",),
}


def _preload(command: str) -> None:
    """Import what the command runs on; a module that cannot be imported is left for the command to
    report."""
    import importlib

    for name in ("numpy", *_COMMAND_MODULES.get(command, ())):
        try:
            importlib.import_module(name)
        except ImportError:
            pass


def _ctrl_c_raises() -> None:
    """From here on a Ctrl-C raises KeyboardInterrupt, which every command cleans up after (until now
    :mod:`neforward_ros.command` ended the process at once)."""
    command = sys.modules.get("neforward_ros.command")
    if command is not None and signal.getsignal(signal.SIGINT) is command.interrupted_early:
        signal.signal(signal.SIGINT, ctrl_c.interrupt)
    ctrl_c.acted_on()


def _interrupted(exc: BaseException) -> bool:
    """Whether ``exc`` stands for a Ctrl-C: some code turns the KeyboardInterrupt it meets into another
    error (Python itself, in a class's ``__set_name__`` while a module is being imported)."""
    seen = set()
    current: BaseException | None = exc
    while current is not None and id(current) not in seen:
        if isinstance(current, KeyboardInterrupt):
            return True
        seen.add(id(current))
        current = current.__cause__ or current.__context__
    return False


def entry() -> None:
    """The ``neforward`` executable: :func:`main`'s status as the process's exit status.

    After Ctrl-C the status is 130 even where a library saw the interrupt on its way out (CPython
    then re-raises SIGINT at exit): everything was cleaned up already, so the exit is immediate. It is
    immediate too wherever a Ctrl-C came: a C extension whose import it landed in may be left half made,
    and the interpreter's shutdown can crash on that (:mod:`neforward_ros.ctrl_c`).
    """
    status = _command(None)  # where the work is done, Ctrl-C stays held off until the exit
    # The work is done (or cleaned up): a Ctrl-C now, while the interpreter shuts down, must not
    # turn the outcome into a traceback or a death by SIGINT.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    if status == 130 or ctrl_c.came():
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(status)
    sys.exit(status)


if __name__ == "__main__":
    entry()
