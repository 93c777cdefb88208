"""The demo's robot and motion: the bundled arm (or any URDF) swinging every joint on its own sine."""

from __future__ import annotations

import math

import numpy as np

from neforward_ros.model import JointKind, RobotModel

LOWEST_HZ, HIGHEST_HZ = 0.3, 1.2


def demo_trajectory(model: RobotModel, times: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A smooth trajectory of every joint column: q = amplitude * sin(2 pi f t + phase).

    Rotating joints swing 0.5 rad, prismatic ones 0.02 m, each at its own frequency, spread evenly
    over 0.3-1.2 Hz whatever the number of joints (a robot's motion, not a vibration).
    """
    amplitude = np.full(len(model.joint_names), 0.5)
    for joint in model.parent_joints:
        if joint is not None and joint.mimic_of is None and joint.kind is JointKind.PRISMATIC:
            amplitude[joint.q_index] = 0.02
    k = np.arange(len(model.joint_names))
    omega = 2.0 * math.pi * (LOWEST_HZ + (HIGHEST_HZ - LOWEST_HZ) * k / max(len(k) - 1, 1))
    phase = 0.7 * k
    arg = np.outer(times, omega) + phase
    return amplitude * np.sin(arg), amplitude * omega * np.cos(arg), -amplitude * omega**2 * np.sin(arg)
