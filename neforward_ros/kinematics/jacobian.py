"""A link's Jacobian, and the wrench at a link that given joint torques show.

:func:`link_jacobian` is Pinocchio's ``getFrameJacobian`` in ``LOCAL_WORLD_ALIGNED``: rows the linear
velocity of the link origin, then the angular velocity, both along the root axes; a column per joint
of ``model.joint_names`` (a mimic joint adds to its leader's column, times the multiplier).
"""

from __future__ import annotations

import numpy as np

from neforward_ros.kinematics.forward import kinematics_table, root_state
from neforward_ros.kinematics.forward_kernel import SLICES
from neforward_ros.model import JointKind, RobotModel


def path_joints(model: RobotModel, link: int) -> list[int]:
    """The links whose parent joint moves ``link`` (itself and its ancestors), with a non-fixed joint."""
    out = []
    at: int | None = link
    while at is not None:
        joint = model.parent_joints[at]
        if joint is None:
            break
        if joint.kind is not JointKind.FIXED:
            out.append(at)
        at = joint.parent_index
    return out


def jacobian_from_table(model: RobotModel, table: np.ndarray, link: int) -> np.ndarray:
    """(..., 6, n) from the forward kernel's rows ((n_links, ROW) or (T, n_links, ROW))."""
    leading = table.shape[:-2]
    rotation = table[..., SLICES["rotation"]].reshape(*leading, -1, 3, 3)
    position = table[..., SLICES["position"]]
    out = np.zeros((*leading, 6, len(model.joint_names)))
    target = position[..., link, :]
    for child in path_joints(model, link):
        joint = model.parent_joints[child]
        assert joint is not None
        axis = rotation[..., child, :, :] @ np.asarray(joint.axis, dtype=float)  # along the root axes
        column = joint.q_index
        if joint.kind is JointKind.PRISMATIC:
            out[..., 0:3, column] += joint.multiplier * axis
        else:
            out[..., 0:3, column] += joint.multiplier * np.cross(axis, target - position[..., child, :])
            out[..., 3:6, column] += joint.multiplier * axis
    return out


def link_jacobian(model: RobotModel, q: np.ndarray, link: str) -> np.ndarray:
    """The Jacobian of ``link`` at joint positions q ((n,) or (T, n)): (6, n) or (T, 6, n)."""
    q = np.asarray(q, dtype=float)
    zeros = np.zeros_like(q)
    table = kinematics_table(model, q, zeros, zeros, root_state())
    return jacobian_from_table(model, table, model.link_index[link])


def wrench_at_link(model: RobotModel, q: np.ndarray, torques: np.ndarray, link: str) -> np.ndarray:
    """The wrench w at ``link`` (force N, then moment N m about its origin, along its own axes) with
    J^T w closest to ``torques`` (least squares; the least-norm one where J^T has a null space, as on a
    link moved by fewer than six joints): (6,) or (T, 6); NaN where a torque is NaN."""
    q = np.asarray(q, dtype=float)
    zeros = np.zeros_like(q)
    table = kinematics_table(model, q, zeros, zeros, root_state())
    index = model.link_index[link]
    jacobian = jacobian_from_table(model, table, index)
    torques = np.asarray(torques, dtype=float)
    known = np.isfinite(torques).all(axis=-1)
    solve = np.linalg.pinv(np.swapaxes(jacobian, -1, -2), rcond=1e-9)  # (..., 6, n)
    in_root = np.einsum("...ij,...j->...i", solve, np.where(np.isfinite(torques), torques, 0.0))
    rotation = table[..., index, SLICES["rotation"]].reshape(*q.shape[:-1], 3, 3)  # link -> root
    force = np.einsum("...ji,...j->...i", rotation, in_root[..., 0:3])
    moment = np.einsum("...ji,...j->...i", rotation, in_root[..., 3:6])
    out = np.concatenate([force, moment], axis=-1)
    return np.where(known[..., None], out, np.nan)
