"""Parameter values -> validated :class:`NodeSettings`: every check both runtimes and the bag tool make."""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from neforward_ros.errors import InputError
from neforward_ros.estimation.motion import KalmanSettings
from neforward_ros.estimation.settings import METHODS, MODES, VELOCITY_SOURCES, StreamSettings
from neforward_ros.kinematics.effort_model import DEFAULT_STRIBECK_VELOCITY, DEFAULT_VELOCITY_SCALE
from neforward_ros.kinematics.forward import DEFAULT_GRAVITY
from neforward_ros.model import RobotModel, with_payload
from neforward_ros.model.inertials import with_inertials
from neforward_ros.parameters.qos_overrides import QOS_OVERRIDES, QosOverride, qos_overrides
from neforward_ros.parameters.table import (
    ACCELERATION_SOURCES,
    BASE_SOURCES,
    DEFAULT_OBSERVER_GAIN,
    DEFAULT_VELOCITY_CUTOFF,
    DEFAULTS,
    EXTERNAL_METHODS,
    PARAMETERS,
    PUBLISH_POLICIES,
    ROS_OWN_PARAMETERS,
    Parameter,
)


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
        publish_joint_estimates: whether ~/joint_estimates is published.
        effort_scale, effort_offset: joint name -> measured = scale * effort + offset (others 1, 0).
        effort_armature: joint name -> its rotor's inertia at the joint, kg m^2 (kg) (others 0).
        friction: ``friction.*`` by field (coulomb, viscous, velocity_scale, stribeck,
            stribeck_velocity) -> joint name -> value (see
            :class:`neforward_ros.kinematics.effort_model.EffortModel`).
        external_method: "auto", "observer" or "difference".
        observer_gain: 1/s; observer_gains: joint name -> its own gain.
        slow_gain: 1/s, the second, slower observer's gain (0: none); dead_zones: joint name -> N m (N),
            how far the two observers may differ with the slow one's output published (others 0).
        velocity_cutoff: Hz, the observer's velocity low-pass (0: none).
        payload: (link, mass kg, centre of mass in the link frame m), or None.
        inertials: per link (name, mass kg, centre of mass m, inertia about it (6) kg m^2) replacing
            the URDF's (``inertial.*``).
        wrench_links: links with ~/<link>/wrench.
        contact_thresholds: joint name -> |external torque| threshold; empty: no ~/contact.
        contact_rest_thresholds: joint name -> threshold of the departure from the still arm's
            baseline (:mod:`neforward_ros.computation.contact`); empty: no rest test.
        contact_accelerations: joint name -> the largest |acceleration| its threshold holds for, beyond
            which it grows in proportion (rad/s^2, m/s^2); empty: at every acceleration.
        contact_debounce: s.
        contact_release: in contact, the fraction of their thresholds the joints must stay over.
        contact_static_friction: the fraction of the Coulomb friction added to the thresholds near rest.
        contact_link: the link of ~/contact_wrench, or "" for none.
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
    publish_joint_estimates: bool = False
    effort_scale: Mapping[str, float] = field(default_factory=dict)
    effort_offset: Mapping[str, float] = field(default_factory=dict)
    effort_armature: Mapping[str, float] = field(default_factory=dict)
    friction: Mapping[str, Mapping[str, float]] = field(default_factory=dict)
    external_method: str = "auto"
    observer_gain: float = DEFAULT_OBSERVER_GAIN
    observer_gains: Mapping[str, float] = field(default_factory=dict)
    slow_gain: float = 0.0
    dead_zones: Mapping[str, float] = field(default_factory=dict)
    velocity_cutoff: float = DEFAULT_VELOCITY_CUTOFF
    payload: tuple[str, float, tuple[float, float, float]] | None = None
    inertials: tuple[tuple[str, float, tuple[float, ...], tuple[float, ...]], ...] = ()
    wrench_links: tuple[str, ...] = ()
    contact_thresholds: Mapping[str, float] = field(default_factory=dict)
    contact_rest_thresholds: Mapping[str, float] = field(default_factory=dict)
    contact_accelerations: Mapping[str, float] = field(default_factory=dict)
    contact_debounce: float = 0.02
    contact_release: float = 1.0
    contact_static_friction: float = 1.0
    contact_link: str = ""
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
        """The links that accel_links, imu_links, wrench_links, contact.link, payload.link and
        inertial.link_names name (each must be the model's)."""
        contact = (self.contact_link,) if self.contact_link else ()
        payload = (self.payload[0],) if self.payload else ()
        inertial = tuple(entry[0] for entry in self.inertials)
        return (*self.accel_links, *self.imu_links, *self.wrench_links, *contact, *payload, *inertial)

    @property
    def named_joints(self) -> tuple[tuple[str, Mapping[str, float]], ...]:
        """(parameter, joint -> value) of the per-joint parameters: hold, effort, contact (each joint
        must be one of the model's)."""
        return (
            ("hold.joint_names", self.hold_positions),
            ("effort.joint_names", self.effort_scale),
            ("contact.joint_names", self.contact_thresholds),
            ("friction.joint_names", self.friction.get("coulomb", {})),
            ("external_torques.joint_names", self.observer_gains),
        )

    def model_of(self, model: RobotModel) -> RobotModel:
        """The model the computation uses: the URDF's, with ``inertial.*``'s parameters and
        ``payload.*``'s point mass when given (for links of the model; the callers report others)."""
        known = [entry for entry in self.inertials if entry[0] in model.link_index]
        if known:
            model = with_inertials(model, *zip(*known, strict=True))
        if self.payload is None or self.payload[0] not in model.link_index:
            return model
        return with_payload(model, *self.payload)

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
        ("external_torques.method", EXTERNAL_METHODS),
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
    effort_armature = _per_joint(merged, "effort.joint_names", "effort.armature", default=0.0)
    if any(not v >= 0.0 for v in effort_armature.values()):
        raise InputError("parameter effort.armature must hold numbers >= 0 (kg m^2; kg)")
    contact_thresholds = _per_joint(merged, "contact.joint_names", "contact.thresholds")
    contact_rest_thresholds = {}
    if merged["contact.rest_thresholds"]:
        contact_rest_thresholds = _per_joint(merged, "contact.joint_names", "contact.rest_thresholds")
    contact_accelerations = {}
    if merged["contact.accelerations"]:
        contact_accelerations = _per_joint(merged, "contact.joint_names", "contact.accelerations")
    friction = {
        field_name: _per_joint(merged, "friction.joint_names", f"friction.{field_name}", default=default)
        for field_name, default in (
            ("coulomb", None),
            ("viscous", 0.0),
            ("velocity_scale", DEFAULT_VELOCITY_SCALE),
            ("stribeck", 0.0),
            ("stribeck_velocity", DEFAULT_STRIBECK_VELOCITY),
        )
    }
    for field_name in ("coulomb", "viscous", "stribeck"):
        if any(v < 0.0 for v in friction[field_name].values()):
            raise InputError(f"parameter friction.{field_name} must hold numbers >= 0")
    for field_name in ("velocity_scale", "stribeck_velocity"):
        if any(not v > 0.0 for v in friction[field_name].values()):
            raise InputError(f"parameter friction.{field_name} must hold positive numbers")
    payload = None
    if merged["payload.link"]:
        com = merged["payload.com"]
        if len(com) != 3 or not merged["payload.mass"] >= 0.0:
            raise InputError("parameters payload.mass (kg, >= 0) and payload.com (x, y, z in m) describe the payload")
        payload = (merged["payload.link"], merged["payload.mass"], (float(com[0]), float(com[1]), float(com[2])))
    inertials = _inertials(merged)
    observer_gains = _per_joint(
        merged, "external_torques.joint_names", "external_torques.gains", default=merged["external_torques.gain"]
    )
    if not merged["external_torques.gain"] > 0.0 or any(not v > 0.0 for v in observer_gains.values()):
        raise InputError("parameters external_torques.gain and external_torques.gains must be positive (1/s)")
    dead_zones = _per_joint(merged, "external_torques.joint_names", "external_torques.dead_zones", default=0.0)
    if not merged["external_torques.slow_gain"] >= 0.0 or any(not v >= 0.0 for v in dead_zones.values()):
        raise InputError("parameters external_torques.slow_gain (1/s) and external_torques.dead_zones must be >= 0")
    if not merged["external_torques.velocity_cutoff"] >= 0.0:
        raise InputError("parameter external_torques.velocity_cutoff must be at least 0 Hz")
    if any(not v > 0.0 for v in contact_thresholds.values()):
        raise InputError("parameter contact.thresholds must hold positive numbers")
    if any(not v > 0.0 for v in contact_rest_thresholds.values()):
        raise InputError("parameter contact.rest_thresholds must hold positive numbers")
    if any(not v > 0.0 for v in contact_accelerations.values()):
        raise InputError("parameter contact.accelerations must hold positive numbers (rad/s^2; m/s^2)")
    if not merged["base.max_delay"] > 0.0:
        raise InputError(
            f"parameter base.max_delay must be a positive number of seconds, got {merged['base.max_delay']}"
        )
    if not 0.0 <= merged["contact.static_friction"] <= 1.0:
        value = merged["contact.static_friction"]
        raise InputError(f"parameter contact.static_friction must be in [0, 1], got {value}")
    if not 0.0 < merged["contact.release"] <= 1.0:
        raise InputError(f"parameter contact.release must be in (0, 1], got {merged['contact.release']}")
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
            order=merged["estimator.order"] or None,
            adaptive=merged["estimator.adaptive"],
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
        publish_joint_estimates=merged["publish_joint_estimates"],
        effort_scale=effort_scale,
        effort_offset=effort_offset,
        effort_armature=effort_armature,
        friction=friction,
        payload=payload,
        inertials=inertials,
        external_method=merged["external_torques.method"],
        observer_gain=merged["external_torques.gain"],
        observer_gains=observer_gains,
        slow_gain=merged["external_torques.slow_gain"],
        dead_zones=dead_zones,
        velocity_cutoff=merged["external_torques.velocity_cutoff"],
        wrench_links=tuple(merged["wrench_links"]),
        contact_thresholds=contact_thresholds,
        contact_rest_thresholds=contact_rest_thresholds,
        contact_accelerations=contact_accelerations,
        contact_debounce=merged["contact.debounce"],
        contact_release=merged["contact.release"],
        contact_static_friction=merged["contact.static_friction"],
        contact_link=merged["contact.link"],
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
        qos_overrides=qos_overrides(qos),
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


def _inertials(merged: Mapping[str, Any]) -> tuple[tuple[str, float, tuple[float, ...], tuple[float, ...]], ...]:
    links = list(merged["inertial.link_names"])
    masses, coms, inertias = (list(merged[f"inertial.{k}"]) for k in ("mass", "com", "inertia"))
    if len(masses) != len(links) or len(coms) != 3 * len(links) or len(inertias) != 6 * len(links):
        raise InputError(
            "parameters inertial.mass, inertial.com and inertial.inertia need 1, 3 and 6 numbers per link of "
            f"inertial.link_names ({len(links)} links: got {len(masses)}, {len(coms)}, {len(inertias)})"
        )
    if any(not m >= 0.0 for m in masses) or not all(math.isfinite(x) for x in [*masses, *coms, *inertias]):
        raise InputError("parameters inertial.*: finite numbers, masses >= 0")
    return tuple(
        (link, float(masses[k]), tuple(float(x) for x in coms[3 * k : 3 * k + 3]),
         tuple(float(x) for x in inertias[6 * k : 6 * k + 6]))
        for k, link in enumerate(links)
    )  # fmt: skip
