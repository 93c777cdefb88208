"""A simulated arm with friction, effort offsets, encoders and pushes, with Pinocchio as its physics.

The ground truth of the contact tests, the contact benchmark and the calibration example. The
joints follow a prescribed smooth motion (a sum of sines per joint, with optional pauses); the
motors' torques are what Pinocchio's inverse dynamics (``rnea``) needs for it, plus joint friction
and what the motors spend on their own rotors (armature, if given), minus the torque of the pushes
(tau_m = rnea(q, qd, qdd) + armature qdd + tau_f(qd) - J^T F): the arm is held on
its path, as a stiff position controller holds it. A driver then reports, at ``rate`` Hz with
jittered stamps:

- positions through an encoder of ``encoder_bits`` bits per turn;
- velocities with Gaussian noise of ``velocity_noise`` rad/s;
- efforts = (tau_m - offset) / scale plus Gaussian noise of ``effort_noise`` N m.

The true external torque, in neforward_ros's sign (measured - model: J^T w, w the wrench the arm
exerts on what pushes it, -F), is kept with the recording, with each push's start and end. Nothing
here uses neforward_ros's dynamics.

Usage: python examples/arm_simulator.py OUTPUT [--urdf FILE --tool LINK] [--seconds 60] [--pushes] [--pause T]
       [--seed 0] [--arm-seed 7] [--velocity-noise 0.002]
writes the recording OUTPUT and, beside it, OUTPUT.truth.npz: the true external torques at every
stamp, the pushes' intervals and the arm's friction, offsets and scales.
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

EPOCH = 1_700_000_000 * 10**9


@dataclass(frozen=True)
class Push:
    """A force on the arm: ``force`` N along the world (root) axes, at ``offset`` m from ``link``'s
    origin in its frame, from ``start`` to ``start + duration`` s, rising and falling over ``ramp`` s
    (a raised cosine; 0: a step)."""

    start: float
    duration: float
    force: tuple[float, float, float]
    ramp: float = 0.005


@dataclass(frozen=True)
class Joints:
    """Per moving joint (the URDF's non-fixed, non-mimic joints, in its order)."""

    coulomb: np.ndarray
    viscous: np.ndarray
    velocity_scale: np.ndarray
    offset: np.ndarray
    scale: np.ndarray
    stribeck: np.ndarray
    stribeck_velocity: np.ndarray
    armature: np.ndarray | None = None  # kg m^2: each motor's rotor inertia at the joint; None: none


@dataclass
class Arm:
    """What is simulated (see the module docstring)."""

    urdf: Path
    tool: str
    joints: Joints
    tool_offset: tuple[float, float, float] = (0.0, 0.0, 0.05)
    rate: float = 500.0
    jitter: float = 0.05  # of the period, uniform
    encoder_bits: int = 17
    velocity_noise: float = 0.002
    effort_noise: float = 0.05
    amplitude: float = 0.6  # rad, per joint, of the motion about its centre
    frequency: float = 0.08  # Hz, the motion's fundamental (5 harmonics)
    pauses: tuple[tuple[float, float], ...] = ()  # (start, duration) s where the motion stops
    pushes: tuple[Push, ...] = ()
    still: tuple[int, ...] = ()  # joint columns held still (a gripper)
    payload: tuple[float, tuple[float, float, float]] | None = None  # kg, m in the tool's frame: a point mass
    seed: int = 0


@dataclass
class Simulated:
    """What the driver reported, and the truth."""

    names: list[str]
    stamps: np.ndarray  # (T,) int ns
    q: np.ndarray  # measured
    qd: np.ndarray
    effort: np.ndarray
    true_q: np.ndarray
    true_qd: np.ndarray
    true_qdd: np.ndarray
    true_external: np.ndarray  # J^T w, neforward_ros's sign
    push_force: np.ndarray  # (T,) N, magnitude
    intervals: list[tuple[int, int]] = field(default_factory=list)  # each push's start, end (ns)


def random_joints(n: int, rng: np.random.Generator, *, stribeck: bool = False) -> Joints:
    """Friction of 0.5-2 N m Coulomb, 0.1-0.6 N m s/rad viscous, offsets of +-1 N m, scales 0.9-1.1."""
    return Joints(
        coulomb=rng.uniform(0.5, 2.0, n),
        viscous=rng.uniform(0.1, 0.6, n),
        velocity_scale=rng.uniform(0.005, 0.03, n),
        offset=rng.uniform(-1.0, 1.0, n),
        scale=rng.uniform(0.9, 1.1, n),
        stribeck=rng.uniform(0.2, 0.6, n) if stribeck else np.zeros(n),
        stribeck_velocity=np.full(n, 0.05),
    )


def _phase(t: np.ndarray, pauses: tuple[tuple[float, float], ...]) -> tuple[np.ndarray, ...]:
    """The motion's time phi(t) and its first two derivatives: phi' falls smoothly to 0 over 0.5 s
    at each pause and rises again after it."""
    rate = np.ones_like(t)
    slope = np.zeros_like(t)
    for start, duration in pauses:
        edge = 0.5
        for a, b, falling in ((start - edge, start, True), (start + duration, start + duration + edge, False)):
            inside = (t >= a) & (t < b)
            x = (t[inside] - a) / edge
            shape = 0.5 * (1 + np.cos(np.pi * x)) if falling else 0.5 * (1 - np.cos(np.pi * x))
            d_shape = (-0.5 if falling else 0.5) * np.pi * np.sin(np.pi * x) / edge
            rate[inside] *= shape
            slope[inside] = d_shape
        rate[(t >= start) & (t < start + duration)] = 0.0
    dt = np.diff(t, prepend=t[0])
    phi = np.cumsum(rate * dt)
    return phi, rate, slope


def motion(arm: Arm, t: np.ndarray, n: int, centre: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """q, qd, qdd (T, n): five harmonics per joint with random phases, through the pausing phase."""
    rng = np.random.default_rng(arm.seed + 1000)
    harmonics = np.arange(1, 6)
    weights = rng.normal(0, 1, (n, 5)) / harmonics
    weights *= arm.amplitude / np.abs(weights).sum(axis=1, keepdims=True)
    phases = rng.uniform(0, 2 * np.pi, (n, 5))
    phi, rate, slope = _phase(t, arm.pauses)
    w = 2 * np.pi * arm.frequency * harmonics
    arg = phi[:, None, None] * w[None, None, :] + phases[None]
    f = centre + np.sum(weights * np.sin(arg), axis=-1)
    d1 = np.sum(weights * w * np.cos(arg), axis=-1)
    d2 = -np.sum(weights * w**2 * np.sin(arg), axis=-1)
    qd = d1 * rate[:, None]
    qdd = d2 * rate[:, None] ** 2 + d1 * slope[:, None]
    for j in arm.still:
        f[:, j], qd[:, j], qdd[:, j] = centre[j], 0.0, 0.0
    return f, qd, qdd


def friction(joints: Joints, qd: np.ndarray) -> np.ndarray:
    stribeck = joints.stribeck * np.exp(-np.square(qd / joints.stribeck_velocity))
    return (joints.coulomb + stribeck) * np.tanh(qd / joints.velocity_scale) + joints.viscous * qd


def simulate(arm: Arm, seconds: float) -> Simulated:
    import pinocchio as pin

    text = arm.urdf.read_text()
    model = pin.buildModelFromXML(text, mimic=True)
    moving = [k for k in range(1, model.njoints) if model.joints[k].nv == 1]
    names = [model.names[k] for k in moving]
    if len(names) != model.nv:
        raise ValueError("the simulator takes arms of revolute, continuous and prismatic joints only")
    n = len(names)

    def configuration(q_row: np.ndarray) -> np.ndarray:
        """Pinocchio's q of our joint positions (cos, sin for a continuous joint)."""
        out = np.zeros(model.nq)
        for column, k in enumerate(moving):
            joint = model.joints[k]
            if joint.nq == 2:
                out[joint.idx_q], out[joint.idx_q + 1] = np.cos(q_row[column]), np.sin(q_row[column])
            else:
                out[joint.idx_q] = q_row[column]
        return out

    tool = model.getFrameId(arm.tool)
    point = model.addFrame(
        pin.Frame("push_point", model.frames[tool].parentJoint, tool,
                  model.frames[tool].placement * pin.SE3(np.eye(3), np.array(arm.tool_offset)), pin.FrameType.OP_FRAME)
    )  # fmt: skip
    if arm.payload is not None:  # a point mass on the tool, which the URDF does not have
        mass, com = arm.payload
        frame = model.frames[tool]
        model.appendBodyToJoint(frame.parentJoint, pin.Inertia(mass, np.array(com), np.zeros((3, 3))), frame.placement)
    data = model.createData()
    rng = np.random.default_rng(arm.seed)
    count = int(seconds * arm.rate)
    t = (np.arange(count) + rng.uniform(-arm.jitter, arm.jitter, count)) / arm.rate
    lower = np.array(
        [model.lowerPositionLimit[model.joints[k].idx_q] if model.joints[k].nq == 1 else -np.inf for k in moving]
    )
    upper = np.array([model.upperPositionLimit[model.joints[k].idx_q] if model.joints[k].nq == 1 else np.inf
                      for k in moving])  # fmt: skip
    limited = np.isfinite(lower) & np.isfinite(upper)
    centre = np.zeros(n)
    centre[limited] = np.where(upper[limited] - lower[limited] < 10, 0.5 * (lower[limited] + upper[limited]), 0.0)
    centre = np.clip(centre + rng.uniform(-0.3, 0.3, n), lower + 0.7, upper - 0.7)
    q, qd, qdd = motion(arm, t, n, centre)
    force = np.zeros((count, 3))
    magnitude = np.zeros(count)
    intervals = []
    for push in arm.pushes:
        envelope = np.zeros(count)
        rise = (t - push.start) / push.ramp if push.ramp > 0 else np.where(t >= push.start, 1.0, -1.0)
        fall = (push.start + push.duration - t) / push.ramp if push.ramp > 0 else np.where(
            t < push.start + push.duration, 1.0, -1.0)  # fmt: skip
        level = np.clip(np.minimum(rise, fall), 0.0, 1.0)
        envelope = 0.5 * (1 - np.cos(np.pi * level)) if push.ramp > 0 else level
        force += envelope[:, None] * np.asarray(push.force)
        magnitude += envelope * np.linalg.norm(push.force)
        intervals.append((EPOCH + round(push.start * 1e9), EPOCH + round((push.start + push.duration) * 1e9)))
    tau_motion = np.zeros((count, n))
    tau_push = np.zeros((count, n))
    for k in range(count):
        configuration_k = configuration(q[k])
        tau_motion[k] = pin.rnea(model, data, configuration_k, qd[k], qdd[k])
        if magnitude[k] > 0:
            pin.computeJointJacobians(model, data, configuration_k)
            pin.updateFramePlacements(model, data)
            jacobian = pin.getFrameJacobian(model, data, point, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)
            tau_push[k] = jacobian[:3].T @ force[k]
    joints = arm.joints
    rotors = 0.0 if joints.armature is None else joints.armature * qdd
    tau_m = tau_motion + rotors + friction(joints, qd) - tau_push
    step = 2 * np.pi / 2**arm.encoder_bits
    measured_q = np.round(q / step) * step
    measured_qd = qd + rng.normal(0, arm.velocity_noise, qd.shape)
    effort = (tau_m - joints.offset) / joints.scale + rng.normal(0, arm.effort_noise, qd.shape)
    stamps = EPOCH + np.round(t * 1e9).astype(np.int64)
    return Simulated(names, stamps, measured_q, measured_qd, effort, q, qd, qdd, -tau_push, magnitude, intervals)


def write(simulated: Simulated, urdf: str, output: Path) -> None:
    """A rosbag2 (MCAP) recording: /robot_description (transient local) and /joint_states."""
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    from neforward_ros.interface import topics
    from neforward_ros.stamps import time_message
    from neforward_ros.wire import cdr

    store = get_typestore(Stores.ROS2_JAZZY)
    from rosbags.rosbag2.metadata import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime

    forever = QosTime(2147483647, 4294967295)
    latched = Qos(QosHistory.KEEP_LAST, 1, QosReliability.RELIABLE, QosDurability.TRANSIENT_LOCAL, forever,
                  forever, QosLiveliness.AUTOMATIC, forever, False)  # fmt: skip
    with Writer(output, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        description = writer.add_connection(
            "/robot_description", topics.STRING_TYPE, typestore=store, offered_qos_profiles=[latched]
        )
        first = int(simulated.stamps[0])
        writer.write(description, first - 10**6, cdr.encode(topics.STRING_TYPE, {"data": urdf}))
        joint_states = writer.add_connection("/joint_states", topics.JOINT_STATE_TYPE, typestore=store)
        names = simulated.names
        for k, stamp in enumerate(simulated.stamps.tolist()):
            contents = {
                "header": {"stamp": time_message(stamp)},
                "name": names,
                "position": simulated.q[k].tolist(),
                "velocity": simulated.qd[k].tolist(),
                "effort": simulated.effort[k].tolist(),
            }
            writer.write(joint_states, stamp, cdr.encode(topics.JOINT_STATE_TYPE, contents))


def read_outputs(output: Path) -> tuple[dict[int, np.ndarray], list[tuple[int, bool]]]:
    """What ``neforward bag`` wrote: the external torques by stamp, and ~/contact's states with their
    recording times, in order."""
    from rosbags.rosbag2 import Reader

    from neforward_ros.stamps import stamp_ns
    from neforward_ros.wire.rostypes import deserialize

    external, contact = {}, []
    with Reader(output) as reader:
        for connection, log_time, raw in reader.messages():
            if connection.topic == "/neforward/external_torques":
                message = deserialize(connection.msgtype, raw)
                external[stamp_ns(message["header"]["stamp"])] = np.array(message["effort"])
            elif connection.topic == "/neforward/contact":
                contact.append((log_time, bool(deserialize(connection.msgtype, raw)["data"])))
    return external, contact


def standard_pushes(start: float, spacing: float = 4.0, magnitude: float = 15.0) -> tuple[Push, ...]:
    """Three pushes: downwards for 2 s, sideways for 1 s, forwards for 1.5 s."""
    return (
        Push(start, 2.0, (0.0, 0.0, -magnitude)),
        Push(start + spacing, 1.0, (0.0, magnitude, 0.0)),
        Push(start + 2 * spacing, 1.5, (magnitude, 0.0, 0.0)),
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("output", type=Path, help="the recording to write (a folder; must not exist)")
    parser.add_argument("--urdf", type=Path, default=Path(__file__).resolve().parent.parent / "config" / "panda.urdf")
    parser.add_argument("--tool", default="panda_hand", help="the link pushed")
    parser.add_argument("--seconds", type=float, default=60.0)
    parser.add_argument("--pushes", action="store_true", help="three 15 N pushes on the tool, from 3 s, 5 s apart")
    parser.add_argument("--pause", type=float, help="a 2 s pause of the whole arm from this time, s")
    parser.add_argument("--seed", type=int, default=0, help="the motion's and the noise's")
    parser.add_argument("--arm-seed", type=int, default=7, help="the arm's friction, offsets and scales")
    parser.add_argument("--velocity-noise", type=float, default=0.002, help="rad/s")
    args = parser.parse_args()
    import pinocchio as pin

    n = pin.buildModelFromXML(args.urdf.read_text(), mimic=True).nv
    joints = random_joints(n, np.random.default_rng(args.arm_seed))
    pushes = standard_pushes(3.0, 5.0) if args.pushes else ()
    pauses = ((args.pause, 2.0),) if args.pause is not None else ()
    still = (n - 1,) if n == 8 else ()  # the bundled arm's finger
    arm = Arm(args.urdf, args.tool, joints, pushes=pushes, pauses=pauses, seed=args.seed, still=still,
              velocity_noise=args.velocity_noise)  # fmt: skip
    simulated = simulate(arm, args.seconds)
    write(simulated, args.urdf.read_text(), args.output)
    truth = args.output.with_name(args.output.name + ".truth.npz")
    np.savez(truth, names=np.array(simulated.names), stamps=simulated.stamps, external=simulated.true_external,
             intervals=np.array(simulated.intervals, dtype=np.int64).reshape(-1, 2), coulomb=joints.coulomb,
             viscous=joints.viscous, offset=joints.offset, scale=joints.scale)  # fmt: skip
    print(f"{args.output}: {len(simulated.stamps)} joint states over {args.seconds:g} s at {arm.rate:g} Hz; "
          f"the truth in {truth}")  # fmt: skip


if __name__ == "__main__":
    main()
