"""The node's ROS 2 parameters, declared once for every runtime and the bag tool.

The rclpy adapter declares them from :data:`PARAMETERS` (with their descriptions), the no-ROS runtime
and the bag tool read the same names from a ROS 2 params file and ``-p`` arguments, and
:func:`neforward_ros.parameters.settings.node_settings` turns the values into validated settings. The
README table and ``config/neforward.yaml`` are checked against this table by the tests.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from neforward_ros.estimation.fit import ADAPTIVE_ORDER, DEFAULT_ORDER, DEFAULT_WINDOW
from neforward_ros.estimation.motion import KalmanSettings
from neforward_ros.estimation.settings import DEFAULT_KALMAN_LAG, DEFAULT_MAX_GAP
from neforward_ros.kinematics.effort_model import DEFAULT_STRIBECK_VELOCITY, DEFAULT_VELOCITY_SCALE
from neforward_ros.kinematics.forward import DEFAULT_GRAVITY

PUBLISH_POLICIES = ("partial", "wait", "hold")
BASE_SOURCES = ("fixed", "imu", "odometry")
NODE_NAME = "neforward"
ACCELERATION_SOURCES = ("estimate", "supplied")
EXTERNAL_METHODS = ("auto", "observer", "difference")
DEFAULT_OBSERVER_GAIN = 250.0
"""1/s: the momentum observer's gain (see the README's contact section for how it was chosen)."""
DEFAULT_VELOCITY_CUTOFF = 16.0
"""Hz: the momentum observer's velocity low-pass (see the README's contact section)."""
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
    Parameter(
        "estimator.order",
        "int",
        0,
        f"Degree of the local polynomial (polyfit). 0: {ADAPTIVE_ORDER} for adaptive windows at a fixed lag, "
        f"{DEFAULT_ORDER} for a fixed window or a causal fit.",
    ),
    Parameter(
        "estimator.adaptive",
        "bool",
        True,
        "polyfit: choose each joint's window per estimate, up to estimator.window, by the intersection of "
        "confidence intervals with the noise read from its samples; false: always estimator.window.",
    ),
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
        "kalman: standard deviation of the positions' noise, rad (m); quantisation step / sqrt(12) for an encoder. "
        "0: read from the samples.",
    ),
    Parameter(
        "estimator.kalman.velocity_noise",
        "double",
        _KALMAN.velocity_noise,
        "kalman: standard deviation of the noise of velocities the messages carry, rad/s (m/s). 0: read from them.",
    ),
    Parameter(
        "estimator.kalman.length_scale",
        "double",
        _KALMAN.length_scale,
        "kalman: s; about 0.65 / (the highest frequency of the joints' motion, Hz). 0: a bank of models, mixed per "
        "joint by how well each predicts it.",
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
    Parameter(
        "publish_joint_estimates",
        "bool",
        False,
        "Publish ~/joint_estimates: the joint positions, velocities and accelerations each result comes from, "
        "with each acceleration's standard deviation as the estimator states it.",
    ),
    Parameter("effort.joint_names", "string[]", [], "Joints whose efforts are scaled and offset before use."),
    Parameter("effort.scale", "double[]", [], "Their scales (measured = scale * effort + offset), in that order."),
    Parameter("effort.offset", "double[]", [], "Their offsets, N m (N), in that order."),
    Parameter(
        "effort.armature",
        "double[]",
        [],
        "Their rotors' inertias at the joint (armature: rotor inertia x gear ratio^2), kg m^2 (kg), in that "
        "order; empty: 0. The motor torque behind external torques adds armature x joint acceleration.",
    ),
    Parameter(
        "friction.joint_names",
        "string[]",
        [],
        "Joints with friction in the model torque: (coulomb + stribeck exp(-(v/stribeck_velocity)^2)) "
        "tanh(v/velocity_scale) + viscous v, v the joint velocity.",
    ),
    Parameter("friction.coulomb", "double[]", [], "Their Coulomb friction, N m (N), in that order."),
    Parameter("friction.viscous", "double[]", [], "Their viscous friction, N m s/rad (N s/m); empty: 0."),
    Parameter(
        "friction.velocity_scale",
        "double[]",
        [],
        f"Their smooth sign's velocity scale, rad/s (m/s); empty: {DEFAULT_VELOCITY_SCALE} each.",
    ),
    Parameter("friction.stribeck", "double[]", [], "Their static friction beyond Coulomb, N m (N); empty: 0."),
    Parameter(
        "friction.stribeck_velocity",
        "double[]",
        [],
        f"Their Stribeck velocity, rad/s (m/s); empty: {DEFAULT_STRIBECK_VELOCITY} each.",
    ),
    Parameter(
        "external_torques.method",
        "string",
        "auto",
        "How ~/external_torques and ~/contact are estimated: observer (a generalized-momentum observer at the "
        "newest sample, from positions, velocities and efforts), difference (measured - model at the estimator's "
        "stamps, with its accelerations), or auto (observer when the joint states carry velocities and efforts "
        "and the base is fixed).",
    ),
    Parameter(
        "external_torques.gain",
        "double",
        DEFAULT_OBSERVER_GAIN,
        "observer: its gain, 1/s (its time constant is 1/gain).",
    ),
    Parameter(
        "external_torques.velocity_cutoff",
        "double",
        DEFAULT_VELOCITY_CUTOFF,
        "observer: Hz, the first-order low-pass of the velocities its momentum is computed from (the torques "
        "are not filtered); 0: none.",
    ),
    Parameter(
        "external_torques.slow_gain",
        "double",
        0.0,
        "observer: a second observer's gain, 1/s, below external_torques.gain (0: none). Then each joint's "
        "external torque is the slow observer's where the two agree within its dead zone, else the fast one's: the "
        "fast one's speed at a push's start and end, the slow one's quiet in free motion (neforward calibrate sets "
        "it).",
    ),
    Parameter(
        "external_torques.joint_names",
        "string[]",
        [],
        "observer: joints with a gain or a dead zone of their own.",
    ),
    Parameter(
        "external_torques.gains",
        "double[]",
        [],
        "observer: their gains, 1/s, in that order; empty: external_torques.gain each.",
    ),
    Parameter(
        "external_torques.dead_zones",
        "double[]",
        [],
        "observer: their dead zones, N m (N), in that order (with a slow_gain); empty: 0 each (the fast observer's "
        "output).",
    ),
    Parameter(
        "payload.link",
        "string",
        "",
        "A link carrying a payload the URDF does not have (neforward calibrate --payload fits it). Empty: none.",
    ),
    Parameter("payload.mass", "double", 0.0, "The payload's mass, kg: a point mass, merged into the link's inertia."),
    Parameter("payload.com", "double[]", [0.0, 0.0, 0.0], "The payload's centre of mass in the link's frame, m."),
    Parameter(
        "inertial.link_names",
        "string[]",
        [],
        "Links whose inertial parameters replace the URDF's (neforward calibrate identifies them). Empty: none.",
    ),
    Parameter("inertial.mass", "double[]", [], "Their masses, kg, in the order of inertial.link_names."),
    Parameter("inertial.com", "double[]", [], "Their centres of mass in the link frame, m: x, y, z per link."),
    Parameter(
        "inertial.inertia",
        "double[]",
        [],
        "Their inertias about the centre of mass, link axes, kg m^2: ixx, ixy, ixz, iyy, iyz, izz per link.",
    ),
    Parameter("wrench_links", "string[]", [], "Links that get ~/<link>/wrench: what their parent joint transmits."),
    Parameter("contact.joint_names", "string[]", [], "Joints watched for contact: ~/contact (std_msgs/Bool)."),
    Parameter("contact.thresholds", "double[]", [], "|external torque| above which each is in contact, N m (N)."),
    Parameter(
        "contact.rest_thresholds",
        "double[]",
        [],
        "observer: while the arm is still (every joint slower than its friction.velocity_scale for 0.2 s), the "
        "departure of each one's external torque from its value at rest above which it is in contact, N m (N); empty: "
        "contact.thresholds at rest too. neforward calibrate measures them where its recordings hold still.",
    ),
    Parameter(
        "contact.accelerations",
        "double[]",
        [],
        "The largest |acceleration| each joint's contact.thresholds hold for, rad/s^2 (m/s^2): beyond it (a "
        "harder stop than the calibration's motion made), the model's errors grow and so does its threshold, by "
        "|acceleration| / this. Empty: at every acceleration. neforward calibrate measures them.",
    ),
    Parameter(
        "contact.debounce", "double", 0.02, "s a change (contact or none) must last before ~/contact follows it."
    ),
    Parameter(
        "contact.release",
        "double",
        1.0,
        "In contact, the fraction of its threshold a joint's |external torque| must stay over; below it on every "
        "watched joint for contact.debounce, the contact ends (1: no hysteresis).",
    ),
    Parameter(
        "contact.static_friction",
        "double",
        1.0,
        "observer: the fraction of each joint's Coulomb (and Stribeck) friction added to its threshold near rest, "
        "where friction can hold up to that much (0: none; neforward calibrate's thresholds cover rest).",
    ),
    Parameter(
        "contact.link",
        "string",
        "",
        "A link that gets ~/contact_wrench (geometry_msgs/WrenchStamped): the wrench at its origin, in its frame, "
        "that the external torques show, by least squares through its Jacobian. Empty: none.",
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
