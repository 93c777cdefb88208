"""Write a rosbag2 recording of the bundled quadruped trotting in place, with a base IMU.

``config/quadruped.urdf``: a 12 kg trunk on a floating joint, four 3-joint legs. The legs trot at
2 Hz (diagonal pairs in phase) while the trunk bounces twice per stride and rolls and pitches a
little. The recording has ``/joint_states`` (500 Hz, +-10 % stamp jitter, 1e-4 rad of position
noise) and ``/imu`` (400 Hz, sensor_msgs/Imu from ``imu_link``, fixed to the trunk off its origin and
turned a quarter turn: angular velocity, specific force and orientation, with 1e-3 rad/s and
1e-2 m/s^2 of noise), as a legged robot's drivers record them. The IMU's readings are those of
the true motion, from :func:`neforward_ros.forward_recursion` with the trunk's true motion.

``neforward bag trot --base imu --world-frame world`` then gives every link's motion, the feet's
included, the base's taken from the IMU.

Usage: python examples/quadruped_trot.py OUTPUT [--seconds 4]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from neforward_ros import BaseMotion, forward_recursion, load_model
from neforward_ros.interface import topics
from neforward_ros.rotations import quaternions
from neforward_ros.stamps import time_message
from neforward_ros.wire import cdr

URDF = Path(__file__).resolve().parent.parent / "config" / "quadruped.urdf"
EPOCH = 1_700_000_000 * 10**9
STRIDE_HZ = 2.0
GRAVITY = np.array([0.0, 0.0, -9.81])


def _axis_rotation(angle: np.ndarray, axis: int) -> np.ndarray:
    out = np.zeros((len(angle), 3, 3))
    j, k = (axis + 1) % 3, (axis + 2) % 3
    out[:, axis, axis] = 1.0
    out[:, j, j] = out[:, k, k] = np.cos(angle)
    out[:, j, k], out[:, k, j] = -np.sin(angle), np.sin(angle)
    return out


def trunk_pose(t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rotation trunk -> world and position of the trunk's origin: a bounce at twice the stride
    frequency, a small roll and pitch."""
    w = 2 * np.pi * STRIDE_HZ
    roll, pitch = 0.03 * np.sin(w * t), 0.02 * np.sin(w * t + 1.0)
    rotation = _axis_rotation(pitch, 1) @ _axis_rotation(roll, 0)
    position = np.stack([0.0 * t, 0.0 * t, 0.45 + 0.015 * np.sin(2 * w * t)], axis=1)
    return rotation, position


def trunk_motion(t: np.ndarray, h: float = 1e-4) -> BaseMotion:
    """The trunk's true motion in its own frame (4th-order differences of its analytic pose)."""

    def d(f, x):
        return (-f(x + 2 * h) + 8 * f(x + h) - 8 * f(x - h) + f(x - 2 * h)) / (12 * h)

    def omega(x):
        rotation, rate = trunk_pose(x)[0], d(lambda y: trunk_pose(y)[0], x)
        skew = np.einsum("tji,tjk->tik", rotation, rate)
        return np.stack([skew[:, 2, 1], skew[:, 0, 2], skew[:, 1, 0]], axis=1)

    rotation = trunk_pose(t)[0]
    velocity = d(lambda x: trunk_pose(x)[1], t)
    acceleration = d(lambda x: d(lambda y: trunk_pose(y)[1], x), t)
    return BaseMotion(
        omega=omega(t),
        alpha=d(omega, t),
        specific_force=np.einsum("tji,tj->ti", rotation, acceleration - GRAVITY),
        velocity=np.einsum("tji,tj->ti", rotation, velocity),
    )


def legs(t: np.ndarray, joint_names: tuple[str, ...]):
    """A trot: hip and knee flexion on sines, diagonal legs (lf, rh) and (rf, lh) half a period apart."""
    w = 2 * np.pi * STRIDE_HZ
    q, qd, qdd = (np.zeros((len(t), len(joint_names))) for _ in range(3))
    for k, name in enumerate(joint_names):
        leg, joint = name.split("_")
        phase = 0.0 if leg in ("lf", "rh") else np.pi
        mean, amplitude = {"haa": (0.0, 0.05), "hfe": (0.6, 0.25), "kfe": (-1.2, 0.35)}[joint]
        arg = w * t + phase + (0.5 if joint == "kfe" else 0.0)
        q[:, k] = mean + amplitude * np.sin(arg)
        qd[:, k] = amplitude * w * np.cos(arg)
        qdd[:, k] = -amplitude * w * w * np.sin(arg)
    return q, qd, qdd


def main() -> None:
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("output", help="the recording to write (a folder; must not exist)")
    parser.add_argument("--seconds", type=float, default=4.0)
    args = parser.parse_args()
    model = load_model(URDF)
    names = list(model.joint_names)
    rng = np.random.default_rng(0)
    count = int(args.seconds * 500)
    t_joint = (np.arange(count) + rng.uniform(-0.1, 0.1, count)) / 500.0
    q, _, _ = legs(t_joint, model.joint_names)
    q = q + rng.normal(0.0, 1e-4, q.shape)
    t_imu = np.arange(int(args.seconds * 400)) / 400.0 + 0.0011
    imu_q, imu_qd, imu_qdd = legs(t_imu, model.joint_names)
    kin = forward_recursion(model, imu_q, imu_qd, imu_qdd, base=trunk_motion(t_imu))
    k = model.link_index["imu_link"]
    omega = kin.omega[:, k] + rng.normal(0.0, 1e-3, (len(t_imu), 3))
    force = kin.accel[:, k] + rng.normal(0.0, 1e-2, (len(t_imu), 3))
    orientation = quaternions(trunk_pose(t_imu)[0] @ kin.rotation[:, k])  # imu_link -> world
    store = get_typestore(Stores.ROS2_JAZZY)
    events = [(t, 0, i) for i, t in enumerate(t_joint)] + [(t, 1, i) for i, t in enumerate(t_imu)]
    with Writer(Path(args.output), version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        description = writer.add_connection("/robot_description", topics.STRING_TYPE, typestore=store)
        writer.write(description, EPOCH, cdr.encode(topics.STRING_TYPE, {"data": URDF.read_text()}))
        joint_states = writer.add_connection("/joint_states", topics.JOINT_STATE_TYPE, typestore=store)
        imu = writer.add_connection("/imu", topics.IMU_TYPE, typestore=store)
        for t, kind, i in sorted(events):
            stamp = EPOCH + round(t * 1e9)
            if kind == 0:
                contents = {"header": {"stamp": time_message(stamp)}, "name": names, "position": q[i].tolist()}
                writer.write(joint_states, stamp, cdr.encode(topics.JOINT_STATE_TYPE, contents))
                continue
            x, y, z, w = orientation[i].tolist()
            contents = {
                "header": {"stamp": time_message(stamp), "frame_id": "imu_link"},
                "orientation": {"x": x, "y": y, "z": z, "w": w},
                "angular_velocity": dict(zip("xyz", omega[i].tolist(), strict=True)),
                "linear_acceleration": dict(zip("xyz", force[i].tolist(), strict=True)),
            }
            writer.write(imu, stamp, cdr.encode(topics.IMU_TYPE, contents))
    print(f"{args.output}: {count} joint states and {len(t_imu)} IMU messages over {args.seconds:g} s of trotting")


if __name__ == "__main__":
    main()
