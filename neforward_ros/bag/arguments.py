"""``neforward bag``'s command line: its flags, and the node parameters they give.

Every node parameter can be set offline as on the node: ``--params FILE`` (a ROS 2 params file,
``neforward: ros__parameters: ...``, e.g. ``config/neforward.yaml``) and ``-p name:=value`` (the
value read as YAML, as ``ros2 run ... --ros-args -p`` reads it). The flags below are shorthands for
the parameters used most offline. Precedence, lowest first: the params file, the flags, ``-p``.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING, Any

from neforward_ros.bag.options import STORAGES
from neforward_ros.errors import InputError
from neforward_ros.parameters.files import joint_numbers

if TYPE_CHECKING:
    pass


def add_bag_arguments(bag: argparse.ArgumentParser) -> None:
    bag.add_argument(
        "inputs",
        nargs="+",
        metavar="INPUT",
        help="rosbag2 recording (folder, .mcap or .db3); several, or a folder of recordings, for a fleet",
    )
    bag.add_argument(
        "-o",
        "--output",
        required=True,
        help="output recording (must not exist); for several inputs, the folder that gets one output per input",
    )
    bag.add_argument("--urdf", help="URDF or xacro file (default: the recording's robot_description topic)")
    bag.add_argument("--joint-states", help="joint-state topic (default: the recording's JointState topic)")
    bag.add_argument(
        "--csv",
        nargs="?",
        const="",
        help="also write a CSV, one row per sample (a path; bare: OUTPUT.csv, the only form for several inputs)",
    )
    bag.add_argument(
        "--plot",
        nargs="?",
        const="",
        help="also write a PNG of the links' |a| and |alpha| (a path; bare: OUTPUT.png)",
    )
    bag.add_argument("--format", choices=STORAGES, default="mcap", help="output storage")
    bag.add_argument("--jobs", type=int, help="recordings processed at once (several inputs; default: every core)")
    bag.add_argument(
        "--params", metavar="FILE", help="ROS 2 params file for the node (neforward: ros__parameters: ...)"
    )
    bag.add_argument(
        "-p",
        "--param",
        action="append",
        default=[],
        metavar="NAME:=VALUE",
        help="a node parameter (see the README's table), e.g. -p estimator.mode:=causal; repeat for more",
    )
    shorthands = bag.add_argument_group("shorthands for node parameters")
    shorthands.add_argument("--root-link", help="root_link: the link whose frame is the root frame")
    shorthands.add_argument(
        "--method", choices=("polyfit", "kalman", "difference"), help="estimator.method (default: polyfit)"
    )
    shorthands.add_argument("--mode", choices=("fixed_lag", "causal"), help="estimator.mode (default: fixed_lag)")
    shorthands.add_argument("--accel-links", help="accel_links, comma-separated: links with accel and twist topics")
    shorthands.add_argument("--imu-links", help="imu_links, comma-separated: links with an imu topic")
    shorthands.add_argument(
        "--gravity", type=float, nargs=3, metavar=("X", "Y", "Z"), help="gravity, m/s^2 (default: 0 0 -9.81)"
    )
    shorthands.add_argument(
        "--publish-policy",
        choices=("partial", "wait", "hold"),
        help="publish_policy: stamps where some joints have no estimate (default: partial)",
    )
    shorthands.add_argument(
        "--hold",
        action="append",
        default=[],
        metavar="JOINT=POSITION",
        help="hold.joint_names/positions: a joint's held position (others 0); repeat for more joints",
    )
    shorthands.add_argument(
        "--torques", action="store_true", default=None, help="publish_torques: joint_torques and external_torques"
    )
    shorthands.add_argument(
        "--joint-estimates",
        action="store_true",
        default=None,
        help="publish_joint_estimates: joint_estimates (q, qd, qdd used, and each qdd's standard deviation)",
    )
    shorthands.add_argument("--wrench-links", help="wrench_links, comma-separated: links with a wrench topic")
    shorthands.add_argument(
        "--effort",
        action="append",
        default=[],
        metavar="JOINT=SCALE[,OFFSET]",
        help="effort.*: measured effort = SCALE * recorded + OFFSET for a joint; repeat for more joints",
    )
    shorthands.add_argument(
        "--contact",
        action="append",
        default=[],
        metavar="JOINT=THRESHOLD",
        help="contact.*: a joint's |external torque| threshold (writes contact); repeat for more joints",
    )
    shorthands.add_argument("--contact-debounce", type=float, help="contact.debounce, s (default: 0.02)")
    shorthands.add_argument(
        "--base", choices=("fixed", "imu", "odometry"), help="base.source: the root's motion (default: fixed)"
    )
    shorthands.add_argument("--base-topic", help="the recording's base topic (default: its one topic of that type)")
    shorthands.add_argument("--base-link", help="base.link: the link the base topic measures")
    shorthands.add_argument("--world-frame", help="world_frame: also write world_link_states with this frame id")


def parameter_values(args: argparse.Namespace) -> dict[str, Any]:
    """The node parameter values the parsed command line gives: the params file's, the flags', then
    the ``-p`` rules' (not yet validated: :func:`~neforward_ros.parameters.settings.node_settings` does).

    Raises:
        InputError: an unreadable params file, or a malformed flag or ``-p``.
    """
    from neforward_ros.parameters.files import command_line_parameters, load_params_file

    values: dict[str, Any] = {}
    if args.params:
        if not Path(args.params).is_file():
            raise InputError(f"no such params file: {args.params}")
        values.update(load_params_file(args.params))
    values.update(_shorthand_values(args))
    tokens = [token for rule in args.param for token in ("-p", rule)]
    values.update(command_line_parameters(tokens)[1])
    return values


def _shorthand_values(args: argparse.Namespace) -> dict[str, Any]:
    values: dict[str, Any] = {}
    for flag, name in (
        ("root_link", "root_link"),
        ("method", "estimator.method"),
        ("mode", "estimator.mode"),
        ("publish_policy", "publish_policy"),
        ("torques", "publish_torques"),
        ("joint_estimates", "publish_joint_estimates"),
        ("contact_debounce", "contact.debounce"),
        ("base", "base.source"),
        ("base_link", "base.link"),
        ("world_frame", "world_frame"),
    ):
        if getattr(args, flag) is not None:
            values[name] = getattr(args, flag)
    for flag, name in (("accel_links", "accel_links"), ("imu_links", "imu_links"), ("wrench_links", "wrench_links")):
        text = getattr(args, flag)
        if text is not None:
            values[name] = [link.strip() for link in text.split(",") if link.strip()]
    if args.gravity is not None:
        values["gravity"] = list(args.gravity)
    if args.hold:
        held = joint_numbers(args.hold, "--hold")
        values["hold.joint_names"], values["hold.positions"] = list(held), [v[0] for v in held.values()]
    if args.effort:
        efforts = joint_numbers(args.effort, "--effort", width=2)
        values["effort.joint_names"] = list(efforts)
        values["effort.scale"] = [v[0] for v in efforts.values()]
        values["effort.offset"] = [v[1] if len(v) > 1 else 0.0 for v in efforts.values()]
    if args.contact:
        thresholds = joint_numbers(args.contact, "--contact")
        values["contact.joint_names"], values["contact.thresholds"] = (
            list(thresholds),
            [v[0] for v in thresholds.values()],
        )
    return values
