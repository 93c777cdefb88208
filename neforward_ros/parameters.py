"""The node's ROS 2 parameters, declared once for every runtime.

The rclpy adapter declares them from :data:`PARAMETERS` (with their descriptions), the no-ROS runtime
reads the same names from a ROS 2 params file and ``-p`` arguments, and :func:`node_settings` turns
the values into validated settings. The README table and ``config/neforward.yaml`` are checked
against this table by the tests.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from neforward_ros.derivatives import (
    DEFAULT_MAX_GAP,
    DEFAULT_ORDER,
    DEFAULT_WINDOW,
    METHODS,
    MODES,
    VELOCITY_SOURCES,
    StreamSettings,
)
from neforward_ros.errors import InputError
from neforward_ros.recursion import DEFAULT_GRAVITY

NODE_NAME = "neforward"
ACCELERATION_SOURCES = ("estimate", "supplied")


@dataclass(frozen=True)
class Parameter:
    """One ROS 2 parameter: name, type (``bool``, ``int``, ``double``, ``string``, ``double[]``,
    ``string[]``), default and meaning."""

    name: str
    type: str
    default: Any
    description: str


PARAMETERS: tuple[Parameter, ...] = (
    Parameter(
        "robot_description",
        "string",
        "",
        "URDF XML of the robot. Empty: the model comes from the robot_description topic (transient local).",
    ),
    Parameter("root_link", "string", "", "Link whose frame is the root frame. Empty: the URDF's root link."),
    Parameter(
        "gravity",
        "double[]",
        list(DEFAULT_GRAVITY),
        "Gravity in the root frame, m/s^2. Accelerations are specific forces (a - g); zeros give kinematic ones.",
    ),
    Parameter(
        "velocity_source",
        "string",
        "auto",
        "Joint velocities: auto (the message's where present), message, or differentiate (from positions).",
    ),
    Parameter(
        "acceleration_source",
        "string",
        "estimate",
        "estimate: from joint_states. supplied: q, qd, qdd as given on joint_states_accel "
        "(trajectory_msgs/JointTrajectory).",
    ),
    Parameter("estimator.method", "string", "polyfit", f"Derivative estimator: {' or '.join(METHODS)}."),
    Parameter("estimator.mode", "string", "fixed_lag", "fixed_lag (accurate, delayed by lag) or causal (no delay)."),
    Parameter("estimator.window", "double", DEFAULT_WINDOW, "Width of the local fit, s."),
    Parameter("estimator.order", "int", DEFAULT_ORDER, "Degree of the local polynomial."),
    Parameter("estimator.lag", "double", -1.0, "fixed_lag delay, s, at most window. Negative: window / 2."),
    Parameter("max_gap", "double", DEFAULT_MAX_GAP, "A joint silent for longer than this, s, restarts its history."),
    Parameter("accel_links", "string[]", [], "Links that get ~/<link>/accel and ~/<link>/twist (link frame)."),
    Parameter("imu_links", "string[]", [], "Links that get a virtual IMU, ~/<link>/imu (sensor_msgs/Imu)."),
    Parameter("publish_markers", "bool", False, "Publish ~/markers: an arrow per link for its COM acceleration."),
    Parameter("marker_scale", "double", 0.02, "Arrow length per unit of acceleration, m per m/s^2."),
    Parameter("frame_prefix", "string", "", "Prefix of every frame_id, as robot_state_publisher's frame_prefix."),
    Parameter("qos_depth", "int", 10, "Keep-last depth of the joint_states and joint_states_accel subscriptions."),
)
"""Every parameter, in README order. ``use_sim_time`` is ROS 2's own and is not listed."""

DEFAULTS: Mapping[str, Any] = {p.name: p.default for p in PARAMETERS}


@dataclass(frozen=True)
class NodeSettings:
    """Validated parameter values.

    Attributes:
        robot_description: URDF XML, or "" to wait for the robot_description topic.
        root_link: root link name, or None for the URDF's root.
        gravity: m/s^2 in the root frame.
        acceleration_source: "estimate" or "supplied".
        estimator: the streaming estimator's settings.
        accel_links, imu_links: links with per-link topics.
        publish_markers: whether ~/markers is published.
        marker_scale: m per m/s^2.
        frame_prefix: prepended to every frame_id.
        qos_depth: input keep-last depth.
    """

    robot_description: str = ""
    root_link: str | None = None
    gravity: tuple[float, float, float] = DEFAULT_GRAVITY
    acceleration_source: str = "estimate"
    estimator: StreamSettings = field(default_factory=StreamSettings)
    accel_links: tuple[str, ...] = ()
    imu_links: tuple[str, ...] = ()
    publish_markers: bool = False
    marker_scale: float = 0.02
    frame_prefix: str = ""
    qos_depth: int = 10


def node_settings(values: Mapping[str, Any]) -> NodeSettings:
    """Settings from parameter values (missing ones take their defaults).

    Raises:
        InputError: an unknown parameter, a value of the wrong type, or an invalid value; the
            message names the parameter.
    """
    unknown = sorted(set(values) - set(DEFAULTS) - {"use_sim_time"})
    if unknown:
        raise InputError(f"unknown parameter(s): {', '.join(unknown)}; known: {', '.join(DEFAULTS)}")
    merged = {**DEFAULTS, **{k: v for k, v in values.items() if v is not None}}
    for parameter in PARAMETERS:
        merged[parameter.name] = _check_type(parameter, merged[parameter.name])

    gravity = merged["gravity"]
    if len(gravity) != 3:
        raise InputError(f"parameter gravity must have 3 components, got {len(gravity)}")
    for name, choices in (("velocity_source", VELOCITY_SOURCES), ("acceleration_source", ACCELERATION_SOURCES)):
        if merged[name] not in choices:
            raise InputError(f"parameter {name} must be one of {', '.join(choices)}, got {merged[name]!r}")
    if merged["estimator.mode"] not in MODES:
        raise InputError(
            f"parameter estimator.mode must be one of {', '.join(MODES)}, got {merged['estimator.mode']!r}"
        )
    if merged["qos_depth"] < 1:
        raise InputError(f"parameter qos_depth must be at least 1, got {merged['qos_depth']}")
    lag = merged["estimator.lag"]
    try:
        estimator = StreamSettings(
            method=merged["estimator.method"],
            window=merged["estimator.window"],
            order=merged["estimator.order"],
            mode=merged["estimator.mode"],
            lag=None if lag < 0 else lag,
            max_gap=merged["max_gap"],
            velocity_source=merged["velocity_source"],
        )
    except InputError as exc:
        raise InputError(f"estimator parameters: {exc}") from exc
    return NodeSettings(
        robot_description=merged["robot_description"],
        root_link=merged["root_link"] or None,
        gravity=tuple(gravity),
        acceleration_source=merged["acceleration_source"],
        estimator=estimator,
        accel_links=tuple(merged["accel_links"]),
        imu_links=tuple(merged["imu_links"]),
        publish_markers=merged["publish_markers"],
        marker_scale=merged["marker_scale"],
        frame_prefix=merged["frame_prefix"],
        qos_depth=merged["qos_depth"],
    )


def load_params_file(path: str | Path, node_name: str = NODE_NAME) -> dict[str, Any]:
    """Parameter values for ``node_name`` from a ROS 2 params file.

    The file maps node names (``neforward``, ``/neforward``, a namespaced ``/ns/neforward`` or the
    wildcard ``/**``) to ``ros__parameters``; nested mappings give dotted names
    (``estimator: {window: 0.2}`` is ``estimator.window``). Entries for other nodes are ignored.

    Raises:
        InputError: the file is missing or is not such YAML.
    """
    import yaml

    try:
        document = yaml.safe_load(Path(path).read_text())
    except (OSError, yaml.YAMLError) as exc:
        raise InputError(f"cannot read params file {path}: {exc}") from exc
    if not isinstance(document, dict):
        raise InputError(f"params file {path} is not a mapping of node names to ros__parameters")
    values: dict[str, Any] = {}
    for key, entry in document.items():
        name = str(key).rstrip("/")
        if name not in ("/**", node_name, f"/{node_name}") and not name.endswith(f"/{node_name}"):
            continue
        if not isinstance(entry, dict) or not isinstance(entry.get("ros__parameters"), dict):
            raise InputError(f"params file {path}: {key} has no ros__parameters mapping")
        values.update(_flatten(entry["ros__parameters"]))
    return values


def _flatten(mapping: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    out: dict[str, Any] = {}
    for key, value in mapping.items():
        if isinstance(value, dict):
            out.update(_flatten(value, f"{prefix}{key}."))
        else:
            out[f"{prefix}{key}"] = value
    return out


def _check_type(parameter: Parameter, value: Any) -> Any:
    kind = parameter.type
    problem = f"parameter {parameter.name} must be {kind}, got {value!r}"
    if kind == "bool":
        if not isinstance(value, bool):
            raise InputError(problem)
        return value
    if kind == "int":
        if isinstance(value, bool) or not isinstance(value, int):
            raise InputError(problem)
        return value
    if kind == "double":
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise InputError(problem)
        return float(value)
    if kind == "string":
        if not isinstance(value, str):
            raise InputError(problem)
        return value
    if not isinstance(value, (list, tuple)):
        raise InputError(problem)
    if kind == "double[]":
        if not all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in value):
            raise InputError(problem)
        return [float(v) for v in value]
    if not all(isinstance(v, str) for v in value):  # string[]
        raise InputError(problem)
    return list(value)
