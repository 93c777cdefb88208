"""Write a rosbag2 recording of the bundled arm that picks up a payload its URDF does not know.

The arm's 8 joints move on slow sines, sampled at 500 Hz with +-10 % stamp jitter and 1e-4 rad
position noise, like a driver's JointState. From 2 s to 4 s a 2 kg mass hangs 10 cm below the hand:
the efforts the recording carries are then those of the arm with the mass (computed with
neforward_ros's inverse dynamics on the URDF with the mass added, plus 0.05 N m of noise), while the
joint states alone cannot show it. ``neforward bag --torques --contact ...`` on the recording finds
the payload in the external torques.

Usage: python examples/payload_recording.py OUTPUT [--seconds 6]
"""

from __future__ import annotations

import argparse
import xml.etree.ElementTree as ElementTree
from pathlib import Path

import numpy as np

from neforward_ros import inverse_dynamics, load_model
from neforward_ros.interface import topics
from neforward_ros.stamps import time_message
from neforward_ros.wire import cdr

URDF = Path(__file__).resolve().parent.parent / "config" / "panda.urdf"
EPOCH = 1_700_000_000 * 10**9
MASS, GRASP, RELEASE = 2.0, 2.0, 4.0


def with_payload(urdf: Path) -> str:
    root = ElementTree.parse(urdf).getroot()
    link = ElementTree.SubElement(root, "link", {"name": "payload"})
    inertial = ElementTree.SubElement(link, "inertial")
    ElementTree.SubElement(inertial, "mass", {"value": str(MASS)})
    ElementTree.SubElement(inertial, "inertia", dict.fromkeys(("ixx", "ixy", "ixz", "iyy", "iyz", "izz"), "0"))
    joint = ElementTree.SubElement(root, "joint", {"name": "payload_joint", "type": "fixed"})
    ElementTree.SubElement(joint, "parent", {"link": "panda_hand"})
    ElementTree.SubElement(joint, "child", {"link": "payload"})
    ElementTree.SubElement(joint, "origin", {"xyz": "0 0 0.1"})
    return ElementTree.tostring(root, encoding="unicode")


def trajectory(t: np.ndarray, n: int):
    """Every joint on a slow sine (the finger, the last column, by 1 cm), the arm leaning out."""
    k = np.arange(n)
    w = 2 * np.pi * (0.2 + 0.05 * k)
    amplitude = np.where(k == n - 1, 0.01, 0.4)
    offset = np.where(k == 1, 0.8, 0.0) + np.where(k == 3, -1.5, 0.0) + np.where(k == n - 1, 0.02, 0.0)
    arg = np.outer(t, w) + k
    return amplitude * np.sin(arg) + offset, amplitude * w * np.cos(arg), -amplitude * w**2 * np.sin(arg)


def main() -> None:
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("output", help="the recording to write (a folder; must not exist)")
    parser.add_argument("--seconds", type=float, default=6.0)
    args = parser.parse_args()
    arm, loaded = load_model(URDF), load_model(with_payload(URDF))
    names = list(arm.joint_names)
    rng = np.random.default_rng(0)
    count = int(args.seconds * 500)
    t = (np.arange(count) + rng.uniform(-0.1, 0.1, count)) / 500.0
    q, qd, qdd = trajectory(t, len(names))
    holding = (t >= GRASP) & (t < RELEASE)
    effort = inverse_dynamics(arm, q, qd, qdd).joint_torque
    effort[holding] = inverse_dynamics(loaded, q[holding], qd[holding], qdd[holding]).joint_torque
    effort += rng.normal(0.0, 0.05, effort.shape)
    measured_q = q + rng.normal(0.0, 1e-4, q.shape)
    store = get_typestore(Stores.ROS2_JAZZY)
    with Writer(Path(args.output), version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        description = writer.add_connection("/robot_description", topics.STRING_TYPE, typestore=store)
        writer.write(description, EPOCH, cdr.encode(topics.STRING_TYPE, {"data": URDF.read_text()}))
        joint_states = writer.add_connection("/joint_states", topics.JOINT_STATE_TYPE, typestore=store)
        for k in range(count):
            stamp = EPOCH + round(t[k] * 1e9)
            contents = {
                "header": {"stamp": time_message(stamp)},
                "name": names,
                "position": measured_q[k].tolist(),
                "effort": effort[k].tolist(),
            }
            writer.write(joint_states, stamp, cdr.encode(topics.JOINT_STATE_TYPE, contents))
    span = f"a {MASS:g} kg payload from {GRASP:g} s to {RELEASE:g} s"
    print(f"{args.output}: {count} joint states over {args.seconds:g} s; {span}")


if __name__ == "__main__":
    main()
