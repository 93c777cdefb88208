"""The root link's motion from the motion of another link: a base IMU that is not on the root.

The forward recursion is affine in the root's motion, link by link: for any link L,
omega_L = R^T omega_0 + (what the joints add), alpha_L = R^T alpha_0 + (terms in omega_0 and the
joints), a_L = R^T a_0 + (terms in omega_0, alpha_0 and the joints), v_L = R^T v_0 + (terms in
omega_0), with R the rotation L -> root at q. So each root quantity follows from L's, in turn, by
running the recursion with the root quantities found so far and the unknown one zero, and rotating
the difference: three passes of the generated kernel, for one sample or a batch.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from neforward_ros.errors import InputError
from neforward_ros.kinematics.forward import BaseMotion, check_joint_arrays, kinematics_table
from neforward_ros.kinematics.forward_kernel import SLICES
from neforward_ros.model import RobotModel


def base_from_link(
    model: RobotModel,
    link: str,
    q: Any,
    qd: Any,
    qdd: Any,
    *,
    omega: Any,
    alpha: Any,
    specific_force: Any,
    velocity: Any = None,
) -> BaseMotion:
    """The root link's motion given that of ``link`` (a link with an IMU, say) at the joint states.

    Args:
        model: the robot.
        link: a link of the model.
        q, qd, qdd: joint states, (n,) or (T, n).
        omega, alpha, specific_force: the link's angular velocity, angular acceleration and the
            specific force at its origin, in its own frame: (3,) or (T, 3).
        velocity: the linear velocity of its origin, in its frame; None: unknown, and the root's
            is then taken as 0 (link velocities are then relative to the root origin's motion).

    Returns:
        :class:`~neforward_ros.BaseMotion` in the root frame, (3,) or (T, 3) fields.

    Raises:
        InputError: an unknown link, or arrays that do not match.
    """
    index = model.link_index.get(link)
    if index is None:
        raise InputError(f"link {link!r} is not in robot {model.name!r}")
    q, qd, qdd = check_joint_arrays(model, q, qd, qdd)
    samples = None if q.ndim == 1 else q.shape[0]
    shape = (3,) if samples is None else (samples, 3)

    def vector(name: str, value: Any) -> np.ndarray:
        array = np.broadcast_to(np.asarray(value, dtype=float), shape)
        if not np.all(np.isfinite(array)):
            raise InputError(f"{name} has a non-finite value")
        return array

    w_link, al_link, f_link = vector("omega", omega), vector("alpha", alpha), vector("specific_force", specific_force)
    v_link = None if velocity is None else vector("velocity", velocity)
    zero = np.zeros(shape)

    def run(w: np.ndarray, al: np.ndarray) -> np.ndarray:
        """The link's row with the root at (w, al, v = 0, a = 0)."""
        root = BaseMotion(omega=w, alpha=al, specific_force=zero, velocity=zero).root(samples)
        return kinematics_table(model, q, qd, qdd, root)[..., index, :]

    def rotate(rotation: np.ndarray, vectors: np.ndarray) -> np.ndarray:
        return np.einsum("...ij,...j->...i", rotation, vectors)

    row = run(zero, zero)
    rotation = row[..., SLICES["rotation"]].reshape((*shape[:-1], 3, 3))  # link -> root
    w_root = rotate(rotation, w_link - row[..., SLICES["omega"]])
    row = run(w_root, zero)
    al_root = rotate(rotation, al_link - row[..., SLICES["alpha"]])
    v_root = zero if v_link is None else rotate(rotation, v_link - row[..., SLICES["velocity"]])
    row = run(w_root, al_root)
    a_root = rotate(rotation, f_link - row[..., SLICES["accel"]])
    return BaseMotion(omega=w_root, alpha=al_root, specific_force=a_root, velocity=v_root)


def link_pose(model: RobotModel, q: np.ndarray, index: int) -> tuple[np.ndarray, np.ndarray]:
    """One link's rotation link -> root, (3, 3), and origin in the root frame, (3,), at q (n,); or
    (T, 3, 3) and (T, 3) at q (T, n)."""
    zeros = np.zeros_like(q)
    row = kinematics_table(model, q, zeros, zeros, (0.0,) * 12)[..., index, :]
    return row[..., SLICES["rotation"]].reshape((*row.shape[:-1], 3, 3)), row[..., SLICES["position"]]
