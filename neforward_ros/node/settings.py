"""The node's ROS 2 parameters, declared once for every runtime.

The rclpy adapter declares them from :data:`PARAMETERS` (with their descriptions), the no-ROS runtime
reads the same names from a ROS 2 params file and ``-p`` arguments, and :func:`node_settings` turns
the values into validated settings. The README table and ``config/neforward.yaml`` are checked
against this table by the tests.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from neforward_ros.errors import InputError
from neforward_ros.estimation.fit import DEFAULT_ORDER, DEFAULT_WINDOW
from neforward_ros.estimation.motion import KalmanSettings
from neforward_ros.estimation.settings import (
    DEFAULT_KALMAN_LAG,
    DEFAULT_MAX_GAP,
    METHODS,
    MODES,
    VELOCITY_SOURCES,
    StreamSettings,
)
from neforward_ros.node.base_source import BASE_SOURCES
from neforward_ros.node.policy import PUBLISH_POLICIES
from neforward_ros.node.ros_args import RosArgs, parse_ros_args
from neforward_ros.recursion import DEFAULT_GRAVITY

NODE_NAME = "neforward"
ACCELERATION_SOURCES = ("estimate", "supplied")
_KALMAN = KalmanSettings()


@dataclass(frozen=True)
class Parameter:
    """One ROS 2 parameter: name, type (``bool``, ``int``, ``double``, ``string``, ``double[]``,
    ``string[]``), default, meaning, and whether it can change while the node runs."""

    name: str
    type: str
    default: Any
    description: str
    read_only: bool = True


PARAMETERS: tuple[Parameter, ...] = (
    Parameter(
        "robot_description",
        "string",
        "",
        "URDF XML of the robot. Empty: the model comes from the robot_description topic (transient local). "
        "Setting it at run time reloads the model; an invalid URDF is rejected and the previous model kept.",
        read_only=False,
    ),
    Parameter("root_link", "string", "", "Link whose frame is the root frame. Empty: the URDF's root link."),
    Parameter(
        "gravity",
        "double[]",
        list(DEFAULT_GRAVITY),
        "Gravity in the root frame, m/s^2. Accelerations are specific forces (a - g); zeros give kinematic ones.",
        read_only=False,
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
    Parameter(
        "estimator.method",
        "string",
        "polyfit",
        "polyfit (local polynomial fit), kalman (Kalman filter / fixed-lag smoother, accurate at low delay) "
        "or difference (a baseline).",
    ),
    Parameter(
        "estimator.mode",
        "string",
        "fixed_lag",
        "fixed_lag (each estimate lag behind the newest sample) or causal (at the newest sample, no delay).",
    ),
    Parameter(
        "estimator.window",
        "double",
        DEFAULT_WINDOW,
        "polyfit: width of the local fit, s. kalman: the samples an estimate needs before its stamp, s.",
    ),
    Parameter("estimator.order", "int", DEFAULT_ORDER, "Degree of the local polynomial (polyfit)."),
    Parameter(
        "estimator.lag",
        "double",
        -1.0,
        f"fixed_lag delay, s, at most window. Negative: window / 2 (polyfit), {DEFAULT_KALMAN_LAG} (kalman).",
    ),
    Parameter(
        "estimator.kalman.noise",
        "double",
        _KALMAN.noise,
        "kalman: standard deviation of the positions' noise, rad (m); quantisation step / sqrt(12) for an encoder.",
    ),
    Parameter(
        "estimator.kalman.velocity_noise",
        "double",
        _KALMAN.velocity_noise,
        "kalman: standard deviation of the noise of velocities the messages carry, rad/s (m/s).",
    ),
    Parameter(
        "estimator.kalman.length_scale",
        "double",
        _KALMAN.length_scale,
        "kalman: s; about 0.65 / (the highest frequency of the joints' motion, Hz).",
    ),
    Parameter(
        "estimator.kalman.magnitude",
        "double",
        _KALMAN.magnitude,
        "kalman: typical excursion of the joints' motion about its trend, rad (m).",
    ),
    Parameter("max_gap", "double", DEFAULT_MAX_GAP, "A joint silent for longer than this, s, restarts its history."),
    Parameter(
        "publish_policy",
        "string",
        "partial",
        "When some joints have no estimate: partial (publish the links every joint above which has one), "
        "wait (publish nothing), or hold (joints silent for longer than max_gap held at hold.positions).",
    ),
    Parameter("hold.joint_names", "string[]", [], "hold: joints with a hold position other than 0."),
    Parameter("hold.positions", "double[]", [], "hold: their positions, rad (m), in the order of hold.joint_names."),
    Parameter(
        "publish_torques",
        "bool",
        False,
        "Publish ~/joint_torques (the model's) and ~/external_torques (measured effort - model) for every stamp "
        "where every joint has an estimate.",
    ),
    Parameter("effort.joint_names", "string[]", [], "Joints whose efforts are scaled and offset before use."),
    Parameter("effort.scale", "double[]", [], "Their scales (measured = scale * effort + offset), in that order."),
    Parameter("effort.offset", "double[]", [], "Their offsets, N m (N), in that order."),
    Parameter("wrench_links", "string[]", [], "Links that get ~/<link>/wrench: what their parent joint transmits."),
    Parameter("contact.joint_names", "string[]", [], "Joints watched for contact: ~/contact (std_msgs/Bool)."),
    Parameter("contact.thresholds", "double[]", [], "|external torque| above which each is in contact, N m (N)."),
    Parameter(
        "contact.debounce", "double", 0.02, "s a change (contact or none) must last before ~/contact follows it."
    ),
    Parameter(
        "base.source",
        "string",
        "fixed",
        "The base's motion: fixed (at rest; gravity in the root frame), imu (sensor_msgs/Imu on base.topic) or "
        "odometry (nav_msgs/Odometry on base.topic).",
    ),
    Parameter("base.topic", "string", "", "The base source's topic. Empty: imu, or odom for odometry."),
    Parameter(
        "base.link",
        "string",
        "",
        "The link the base source measures (IMU frame, odometry child frame). Empty: the message's frame id.",
    ),
    Parameter(
        "base.max_delay",
        "double",
        0.5,
        "s a joint state waits for the base motion at its stamp before it is dropped with a warning.",
    ),
    Parameter(
        "world_frame",
        "string",
        "",
        "With a base source that gives orientation: frame id of ~/world_link_states. Empty: not published.",
    ),
    Parameter("accel_links", "string[]", [], "Links that get ~/<link>/accel and ~/<link>/twist (link frame)."),
    Parameter("imu_links", "string[]", [], "Links that get a virtual IMU, ~/<link>/imu (sensor_msgs/Imu)."),
    Parameter("publish_markers", "bool", False, "Publish ~/markers: an arrow per link for its COM acceleration."),
    Parameter("marker_scale", "double", 0.02, "Arrow length per unit of acceleration, m per m/s^2.", read_only=False),
    Parameter(
        "frame_prefix",
        "string",
        "",
        "Prefix of every frame_id, as robot_state_publisher's frame_prefix.",
        read_only=False,
    ),
    Parameter(
        "qos_depth",
        "int",
        500,
        "Keep-last depth of the input subscriptions (joint states, supplied states, base): 500 holds 0.5 s of a "
        "1 kHz stream, so that a stall of the node (a model reload, the machine busy) loses nothing.",
    ),
)
"""Every parameter, in README order. ROS 2's own (``use_sim_time``, ...) and ``qos_overrides.*`` are not listed."""

DEFAULTS: Mapping[str, Any] = {p.name: p.default for p in PARAMETERS}

ROS_OWN_PARAMETERS = ("use_sim_time", "start_type_description_service")
"""Parameters every ROS 2 Jazzy node declares itself; accepted in files, not ours to interpret."""

QOS_OVERRIDES = "qos_overrides."
QOS_POLICIES = {"reliability": ("reliable", "best_effort", "system_default"), "history": ("keep_last", "keep_all")}
QOS_POLICIES_INT = ("depth",)
QOS_ENTITIES = ("publisher", "subscription")


@dataclass(frozen=True)
class QosOverride:
    """QoS policies a parameter file sets for one topic's publisher or subscription, ROS 2 style:
    ``qos_overrides./joint_states.subscription.reliability: best_effort``. None keeps the node's own."""

    reliability: str | None = None
    history: str | None = None
    depth: int | None = None


@dataclass(frozen=True)
class NodeSettings:
    """Validated parameter values.

    Attributes:
        robot_description: URDF XML, or "" to wait for the robot_description topic.
        root_link: root link name, or None for the URDF's root.
        gravity: m/s^2 in the root frame.
        acceleration_source: "estimate" or "supplied".
        estimator: the streaming estimator's settings.
        publish_policy: "partial", "wait" or "hold".
        hold_positions: joint name -> position held under the "hold" policy (others: 0).
        publish_torques: whether ~/joint_torques and ~/external_torques are published.
        effort_scale, effort_offset: joint name -> measured = scale * effort + offset (others 1, 0).
        wrench_links: links with ~/<link>/wrench.
        contact_thresholds: joint name -> |external torque| threshold; empty: no ~/contact.
        contact_debounce: s.
        base_source: "fixed", "imu" or "odometry".
        base_topic: its topic (relative name).
        base_link: the link it measures, or "" for the message's frame id.
        base_max_delay: s.
        world_frame: frame id of ~/world_link_states, or "" for none.
        accel_links, imu_links: links with per-link topics.
        publish_markers: whether ~/markers is published.
        marker_scale: m per m/s^2.
        frame_prefix: prepended to every frame_id.
        qos_depth: input keep-last depth.
        qos_overrides: (fully qualified topic, ``publisher`` or ``subscription``) -> policies.
    """

    robot_description: str = ""
    root_link: str | None = None
    gravity: tuple[float, float, float] = DEFAULT_GRAVITY
    acceleration_source: str = "estimate"
    estimator: StreamSettings = field(default_factory=StreamSettings)
    publish_policy: str = "partial"
    hold_positions: Mapping[str, float] = field(default_factory=dict)
    publish_torques: bool = False
    effort_scale: Mapping[str, float] = field(default_factory=dict)
    effort_offset: Mapping[str, float] = field(default_factory=dict)
    wrench_links: tuple[str, ...] = ()
    contact_thresholds: Mapping[str, float] = field(default_factory=dict)
    contact_debounce: float = 0.02
    base_source: str = "fixed"
    base_topic: str = ""
    base_link: str = ""
    base_max_delay: float = 0.5
    world_frame: str = ""
    accel_links: tuple[str, ...] = ()
    imu_links: tuple[str, ...] = ()
    publish_markers: bool = False
    marker_scale: float = 0.02
    frame_prefix: str = ""
    qos_depth: int = 500
    qos_overrides: Mapping[tuple[str, str], QosOverride] = field(default_factory=dict)

    @property
    def dynamics_needed(self) -> bool:
        """Whether any output needs the backward pass (torques, wrenches, contact)."""
        return bool(self.publish_torques or self.wrench_links or self.contact_thresholds)

    @property
    def world_states(self) -> bool:
        """Whether world_link_states is published: a world_frame and a base source that can orient it."""
        return bool(self.world_frame) and self.base_source != "fixed"

    @property
    def named_links(self) -> tuple[str, ...]:
        """The links that accel_links, imu_links and wrench_links name (each must be the model's)."""
        return (*self.accel_links, *self.imu_links, *self.wrench_links)

    @property
    def named_joints(self) -> tuple[tuple[str, Mapping[str, float]], ...]:
        """(parameter, joint -> value) of the per-joint parameters: hold, effort, contact (each joint
        must be one of the model's)."""
        return (
            ("hold.joint_names", self.hold_positions),
            ("effort.joint_names", self.effort_scale),
            ("contact.joint_names", self.contact_thresholds),
        )

    def qos_override(self, topic: str, entity: str) -> QosOverride:
        """The overrides for a fully qualified topic's ``publisher`` or ``subscription``."""
        return self.qos_overrides.get((topic, entity), QosOverride())


def node_settings(values: Mapping[str, Any]) -> NodeSettings:
    """Settings from parameter values (missing ones take their defaults).

    Raises:
        InputError: an unknown parameter, a value of the wrong type, or an invalid value; the
            message names the parameter.
    """
    qos = {name: value for name, value in values.items() if name.startswith(QOS_OVERRIDES)}
    own = {name: value for name, value in values.items() if name not in qos}
    unknown = sorted(set(own) - set(DEFAULTS) - set(ROS_OWN_PARAMETERS))
    if unknown:
        raise InputError(f"unknown parameter(s): {', '.join(unknown)}; known: {', '.join(DEFAULTS)}")
    for name in ROS_OWN_PARAMETERS:
        if name in own and not isinstance(own[name], bool):
            raise InputError(f"parameter {name} must be bool, got {own[name]!r}")
    merged = {**DEFAULTS, **{k: v for k, v in own.items() if v is not None and k in DEFAULTS}}
    for parameter in PARAMETERS:
        merged[parameter.name] = _check_type(parameter, merged[parameter.name])

    gravity = merged["gravity"]
    if len(gravity) != 3:
        raise InputError(f"parameter gravity must have 3 components, got {len(gravity)}")
    for name, choices in (
        ("velocity_source", VELOCITY_SOURCES),
        ("acceleration_source", ACCELERATION_SOURCES),
        ("publish_policy", PUBLISH_POLICIES),
        ("base.source", BASE_SOURCES),
        ("estimator.method", METHODS),
    ):
        if merged[name] not in choices:
            raise InputError(f"parameter {name} must be one of {', '.join(choices)}, got {merged[name]!r}")
    if merged["estimator.mode"] not in MODES:
        raise InputError(
            f"parameter estimator.mode must be one of {', '.join(MODES)}, got {merged['estimator.mode']!r}"
        )
    if merged["qos_depth"] < 1:
        raise InputError(f"parameter qos_depth must be at least 1, got {merged['qos_depth']}")
    hold_positions = _per_joint(merged, "hold.joint_names", "hold.positions")
    effort_scale = _per_joint(merged, "effort.joint_names", "effort.scale", default=1.0)
    effort_offset = _per_joint(merged, "effort.joint_names", "effort.offset", default=0.0)
    contact_thresholds = _per_joint(merged, "contact.joint_names", "contact.thresholds")
    if any(not v > 0.0 for v in contact_thresholds.values()):
        raise InputError("parameter contact.thresholds must hold positive numbers")
    if not merged["base.max_delay"] > 0.0:
        raise InputError(
            f"parameter base.max_delay must be a positive number of seconds, got {merged['base.max_delay']}"
        )
    if not merged["contact.debounce"] >= 0.0:
        raise InputError(f"parameter contact.debounce must be at least 0 s, got {merged['contact.debounce']}")
    lag = merged["estimator.lag"]
    try:
        kalman = KalmanSettings(
            noise=merged["estimator.kalman.noise"],
            velocity_noise=merged["estimator.kalman.velocity_noise"],
            length_scale=merged["estimator.kalman.length_scale"],
            magnitude=merged["estimator.kalman.magnitude"],
        )
        estimator = StreamSettings(
            method=merged["estimator.method"],
            window=merged["estimator.window"],
            order=merged["estimator.order"],
            mode=merged["estimator.mode"],
            lag=None if lag < 0 else lag,
            max_gap=merged["max_gap"],
            velocity_source=merged["velocity_source"],
            kalman=kalman,
        )
    except InputError as exc:
        raise InputError(f"estimator parameters: {exc}") from exc
    return NodeSettings(
        robot_description=merged["robot_description"],
        root_link=merged["root_link"] or None,
        gravity=tuple(gravity),
        acceleration_source=merged["acceleration_source"],
        estimator=estimator,
        publish_policy=merged["publish_policy"],
        hold_positions=hold_positions,
        publish_torques=merged["publish_torques"],
        effort_scale=effort_scale,
        effort_offset=effort_offset,
        wrench_links=tuple(merged["wrench_links"]),
        contact_thresholds=contact_thresholds,
        contact_debounce=merged["contact.debounce"],
        base_source=merged["base.source"],
        base_topic=merged["base.topic"] or {"imu": "imu", "odometry": "odom"}.get(merged["base.source"], ""),
        base_link=merged["base.link"],
        base_max_delay=merged["base.max_delay"],
        world_frame=merged["world_frame"],
        accel_links=tuple(merged["accel_links"]),
        imu_links=tuple(merged["imu_links"]),
        publish_markers=merged["publish_markers"],
        marker_scale=merged["marker_scale"],
        frame_prefix=merged["frame_prefix"],
        qos_depth=merged["qos_depth"],
        qos_overrides=_qos_overrides(qos),
    )


def _per_joint(merged: Mapping[str, Any], names: str, values: str, default: float | None = None) -> dict[str, float]:
    """Joint name -> value from two parallel array parameters; with a default, the values may be left
    empty (every joint the default)."""
    joints, numbers = merged[names], merged[values]
    if default is not None and not numbers:
        numbers = [default] * len(joints)
    if len(joints) != len(numbers):
        raise InputError(
            f"parameters {names} and {values} must have the same length, got {len(joints)} and {len(numbers)}"
        )
    return dict(zip(joints, numbers, strict=True))


def _qos_overrides(values: Mapping[str, Any]) -> dict[tuple[str, str], QosOverride]:
    """``qos_overrides.<topic>.<publisher|subscription>.<policy>`` values, checked, grouped per entity."""
    grouped: dict[tuple[str, str], dict[str, Any]] = {}
    for name, value in values.items():
        parts = name[len(QOS_OVERRIDES) :].rsplit(".", 2)
        if len(parts) != 3 or not parts[0].startswith("/") or parts[1] not in QOS_ENTITIES:
            raise InputError(
                f"parameter {name}: QoS overrides are named qos_overrides.<fully qualified topic>."
                "<publisher|subscription>.<policy>, e.g. qos_overrides./joint_states.subscription.reliability"
            )
        topic, entity, policy = parts
        if policy in QOS_POLICIES:
            if value not in QOS_POLICIES[policy]:
                raise InputError(f"parameter {name} must be one of {', '.join(QOS_POLICIES[policy])}, got {value!r}")
        elif policy in QOS_POLICIES_INT:
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise InputError(f"parameter {name} must be a positive integer, got {value!r}")
        else:
            known = ", ".join([*QOS_POLICIES, *QOS_POLICIES_INT])
            raise InputError(f"parameter {name}: this node lets a file override {known}, not {policy}")
        grouped.setdefault((topic, entity), {})[policy] = value
    return {key: QosOverride(**policies) for key, policies in grouped.items()}


def node_name_matches(key: str, fully_qualified_name: str) -> bool:
    """Whether a params-file key names this node, by rcl's rules.

    A key without a leading ``/`` is taken from the root (``neforward`` is ``/neforward``, which a
    node in namespace ``/robot1`` does not match); ``*`` matches one name token and ``**`` any number,
    so ``/**`` matches every node and ``/**/neforward`` a node called neforward in any namespace.
    """
    pattern = [t for t in key.strip().strip("/").split("/") if t]
    name = [t for t in fully_qualified_name.strip("/").split("/") if t]

    def match(p: int, n: int) -> bool:
        if p == len(pattern):
            return n == len(name)
        if pattern[p] == "**":
            return any(match(p + 1, m) for m in range(n, len(name) + 1))
        return n < len(name) and pattern[p] in ("*", name[n]) and match(p + 1, n + 1)

    return match(0, 0)


def load_params_file(path: str | Path, node_name: str = NODE_NAME, namespace: str = "/") -> dict[str, Any]:
    """Parameter values for a node from a ROS 2 params file.

    The file maps node names to ``ros__parameters``; the entries that name this node by rcl's rules
    (see :func:`node_name_matches`) apply, in file order. Nested mappings give dotted names
    (``estimator: {window: 0.2}`` is ``estimator.window``).

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
    fully_qualified = namespace.rstrip("/") + "/" + node_name
    values: dict[str, Any] = {}
    for key, entry in document.items():
        if not node_name_matches(str(key), fully_qualified):
            continue
        if not isinstance(entry, dict) or not isinstance(entry.get("ros__parameters"), dict):
            raise InputError(f"params file {path}: {key} has no ros__parameters mapping")
        values.update(_flatten(entry["ros__parameters"]))
    return values


def command_line_parameters(
    tokens: Sequence[str], *, strict: bool = True, params_file: str | None = None
) -> tuple[RosArgs, dict[str, Any]]:
    """The ``--ros-args`` section of a node command line and the parameter values it gives.

    Values come from the params files in order (``params_file`` first when given), then ``-p``
    rules. Both runtimes call this, so a file or value is accepted or rejected alike by both.

    Raises:
        InputError: a malformed section or an unreadable params file.
    """
    parsed = parse_ros_args(tokens, NODE_NAME, strict=strict)
    node_name = parsed.node_name or NODE_NAME
    namespace = parsed.namespace or "/"
    values: dict[str, Any] = {}
    for path in [*([params_file] if params_file else []), *parsed.params_files]:
        values.update(load_params_file(path, node_name, namespace))
    values.update(parsed.params)
    return parsed, values


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
        if isinstance(value, int) and not isinstance(value, bool):
            raise InputError(_whole_number(parameter.name, value))
        if not isinstance(value, float) or not math.isfinite(value):
            raise InputError(problem)
        return value
    if kind == "string":
        if not isinstance(value, str):
            raise InputError(problem)
        return value
    if not isinstance(value, (list, tuple)):
        raise InputError(problem)
    if kind == "double[]":
        whole = [v for v in value if isinstance(v, int) and not isinstance(v, bool)]
        if whole:
            raise InputError(_whole_number(parameter.name, whole[0]))
        if not all(isinstance(v, float) and math.isfinite(v) for v in value):
            raise InputError(problem)
        return list(value)
    if not all(isinstance(v, str) for v in value):  # string[]
        raise InputError(problem)
    return list(value)


def _whole_number(name: str, value: int) -> str:
    return (
        f"parameter {name} must be double, got the integer {value}: "
        f"ROS 2 reads a number without a decimal point as an integer; write {value}.0"
    )
