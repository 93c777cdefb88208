"""``neforward calibrate`` from its parsed command line: the fit, its report, the params file."""

from __future__ import annotations

import argparse
import os
import signal
from pathlib import Path
from typing import TYPE_CHECKING, Any

from neforward_ros import ctrl_c
from neforward_ros.errors import InputError

if TYPE_CHECKING:  # imported when the command runs: the command line of every command builds this parser
    from neforward_ros.calibration.calibrate import Calibration


def add_calibrate_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("inputs", nargs="+", metavar="RECORDING", help="rosbag2 recordings of free motion (no contact)")
    parser.add_argument("-o", "--output", required=True, help="the params file to write (must not exist)")
    parser.add_argument("--urdf", help="URDF or xacro file (default: the recordings' robot_description topic)")
    parser.add_argument("--joint-states", help="joint-state topic (default: the recordings' JointState topic)")
    parser.add_argument(
        "--params", metavar="FILE", help="ROS 2 params file: kept in the output, and the prior of what is not fitted"
    )
    parser.add_argument(
        "-p", "--param", action="append", default=[], metavar="NAME:=VALUE", help="a node parameter, as --params"
    )
    parser.add_argument(
        "--effort-scale",
        action="append",
        default=[],
        metavar="JOINT=GAIN",
        help="a joint's effort scale, torque per effort unit (a datasheet's drive gain): the prior, kept where the "
        "motion cannot tell it, and the units of the inertial parameters; repeat for more joints",
    )
    parser.add_argument("--stribeck", action="store_true", help="also fit a Stribeck term per joint")
    parser.add_argument(
        "--no-inertia",
        action="store_true",
        help="keep the URDF's inertial parameters (default: identify those the motion excites, inertial.*)",
    )
    parser.add_argument(
        "--payload", metavar="LINK", help="also fit the mass and centre of mass of a payload on this link (payload.*)"
    )


def run_calibrate(args: argparse.Namespace) -> int:
    """Calibrate, print the report, write the params file (all at once: nothing after Ctrl-C)."""
    from neforward_ros.bag.report import Progress
    from neforward_ros.calibration.calibrate import calibrate
    from neforward_ros.calibration.params_file import params_yaml
    from neforward_ros.parameters.files import command_line_parameters, joint_numbers, load_params_file

    output = Path(args.output)
    if output.exists():
        raise InputError(f"{output} exists already; remove it or choose another name")
    if not output.absolute().parent.is_dir():
        raise InputError(f"cannot write {output}: no such folder {output.absolute().parent}")
    values: dict[str, Any] = {}
    if args.params:
        if not Path(args.params).is_file():
            raise InputError(f"no such params file: {args.params}")
        values.update(load_params_file(args.params))
    values.update(command_line_parameters([t for rule in args.param for t in ("-p", rule)])[1])
    if args.effort_scale:
        given = values.get("effort.joint_names", ())
        scales = dict(zip(given, values.get("effort.scale", ()) or [1.0] * len(given), strict=False))
        others = {  # the params file's other effort.* values, by joint
            key: dict(zip(given, values[key], strict=False))
            for key in ("effort.offset", "effort.armature")
            if values.get(key)
        }
        for name, (gain,) in joint_numbers(args.effort_scale, "--effort-scale").items():
            if not gain > 0.0:
                raise InputError(f"--effort-scale takes JOINT=GAIN with a positive gain, got {name}={gain:g}")
            scales[name] = gain
        values["effort.joint_names"] = list(scales)
        values["effort.scale"] = [float(v) for v in scales.values()]
        for key, by_joint in others.items():
            values[key] = [float(by_joint.get(name, 0.0)) for name in scales]
    found = calibrate(
        [Path(p) for p in args.inputs],
        values,
        urdf=args.urdf,
        joint_states_topic=args.joint_states,
        stribeck=args.stribeck,
        payload=args.payload,
        inertia=not args.no_inertia,
        progress=ctrl_c.checking(Progress()),  # a Ctrl-C that a library swallowed stops it at its next step
    )
    ctrl_c.check()
    text = params_yaml(found.parameters, header=_header(found, args.inputs))
    partial = output.with_name(f".{output.name}.partial-{os.getpid()}")
    partial.write_text(text)
    stops = {signal.SIGINT, signal.SIGTERM}
    blocked = signal.pthread_sigmask(signal.SIG_BLOCK, stops)
    try:
        partial.rename(output)
        for pending in signal.sigpending() & stops:
            signal.sigwait({pending})
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, blocked)
        partial.unlink(missing_ok=True)
    try:
        print(describe(found, output))
    except KeyboardInterrupt:
        pass  # the file is written: saying so is all that was left
    return 0


def describe(found: Calibration, output: Path) -> str:
    """The report: each joint's fitted parameters, its external torque RMS before and after, and its
    contact threshold; then what could not be fitted."""
    from neforward_ros.calibration.thresholds import MARGIN, QUANTILE

    rows = [
        f"calibrated on {found.samples} joint states; external torques by the {found.method}",
        f"{'joint':<24}{'scale':>8}{'offset':>9}{'coulomb':>9}{'viscous':>9}{'v_scale':>9}{'armature':>10}"
        f"{'RMS before':>12}{'RMS after':>11}{'threshold':>11}",
    ]
    for k, (name, fit) in enumerate(zip(found.joint_names, found.fits, strict=True)):
        armature = f"{fit.armature:>10.4g}" if "armature" in fit.fitted or fit.armature else f"{'-':>10}"
        rows.append(
            f"{name:<24}{fit.scale:>8.3f}{fit.offset:>9.3f}{fit.coulomb:>9.3f}{fit.viscous:>9.3f}"
            f"{fit.velocity_scale:>9.4f}{armature}{found.before[k]:>12.3f}{found.after[k]:>11.3f}"
            f"{found.thresholds[k]:>11.3f}"
        )
    rows.append(
        f"(RMS: the external torque in this free motion, N m (N), with the given parameters and with the fitted "
        f"ones; threshold: {MARGIN:g} x the largest {100 * QUANTILE:g}th percentile of its |external torque| over "
        "three speed ranges; armature: the rotor's inertia at the joint, kg m^2 (kg), '-' where the motion did not "
        "tell it)"
    )
    if found.accelerations is not None:
        pairs = zip(found.joint_names, found.accelerations.tolist(), strict=True)
        largest = [f"{n} {a:.3g}" for n, a in pairs if a == a]  # NaN: not watched
        rows.append(
            "largest accelerations of this motion, rad/s^2 (m/s^2) (the thresholds hold up to them, and grow in "
            f"proportion beyond: the model was not checked there): {', '.join(largest)}"
        )
    if found.rest_thresholds is not None:
        pairs = zip(found.joint_names, found.rest_thresholds.tolist(), strict=True)
        rest = [f"{n} {t:.3g}" for n, t in pairs if t == t]  # NaN: not watched
        rows.append(
            f"rest thresholds (the departure from a still arm's baseline, {MARGIN:g} x its {100 * QUANTILE:g}th "
            f"percentile where these recordings hold still): {', '.join(rest)}"
        )
    slow_gain = found.parameters.get("external_torques.slow_gain", 0.0)
    if slow_gain and "external_torques.dead_zones" in found.parameters:
        zones = zip(found.parameters["external_torques.joint_names"], found.parameters["external_torques.dead_zones"],
                    strict=True)  # fmt: skip
        rows.append(
            f"observer at two speeds (the velocities' noise is much of the external torque; contact stays on the "
            f"fast one): a slow one at {slow_gain:g} /s, whose output is published where the two agree within "
            "these dead zones: " + ", ".join(f"{n} {z:.3g}" for n, z in zones if z > 0)
        )
    if found.identified is not None and found.identified.links:
        ident = found.identified
        told = int(ident.told.sum())
        rows.append(
            f"inertial parameters: {told} of {ident.told.size} identified on {len(ident.links)} links ({ident.rank} "
            "combinations excited); the torque equation's RMS residual per joint, URDF -> identified: "
            + ", ".join(f"{a:.3g} -> {b:.3g}" for a, b in zip(ident.residual_before, ident.residual_after, strict=True))
        )
    if found.payload is not None:
        p = found.payload
        if p.mass > 0:
            rows.append(
                f"payload on {p.link}: {p.mass:.3f} kg at ({p.com[0]:.3f}, {p.com[1]:.3f}, {p.com[2]:.3f}) m in its "
                f"frame (the fit's residual {p.residual_without:.3g} -> {p.residual:.3g} N m RMS)"
            )
        else:
            rows.append(f"payload on {p.link}: none found (the best mass was under 0.02 kg)")
    rows += [f"warning: {note}" for note in found.notes]
    rows.append(f"wrote {output}")
    return "\n".join(rows)


def _header(found: Calibration, inputs: list[str]) -> str:
    worst = float(max(found.after)) if len(found.after) else float("nan")
    return (
        f"Written by neforward calibrate from {', '.join(inputs)}: {found.samples} joint states of free motion.\n"
        f"External torques by the {found.method}; the largest RMS left in that motion: {worst:.3g} N m.\n"
        "Use: neforward bag REC -o OUT --params FILE; neforward run --params FILE;\n"
        "ros2 run neforward_ros neforward_node --ros-args --params-file FILE"
    )
