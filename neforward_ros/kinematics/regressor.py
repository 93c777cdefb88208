"""The joint torques as a linear function of the links' inertial parameters (the inverse-dynamics regressor).

Each link's ten inertial parameters, in its own frame (Pinocchio's dynamic parameters, in this order):
mass m (kg), first moment h = m c (kg m, c the centre of mass), and the rotational inertia about the
link frame's origin, I_o = I_c + m (|c|^2 1 - c c^T) (kg m^2), as (ixx, ixy, ixz, iyy, iyz, izz).

The net wrench on link i about its origin, in its frame, is linear in them (omega, alpha the link's
angular velocity and acceleration, a its origin's classical acceleration minus gravity, all from the
forward recursion, in the link frame):

    f = m a + (S(alpha) + S(omega)^2) h
    n = I_o alpha + omega x (I_o omega) - S(a) h

and a joint's torque (force) is the sum over the links it carries of that wrench moved to the joint
and projected on its axis; a mimic joint adds its torque, times its multiplier, to its leader's
column. So tau = Y(q, qd, qdd) pi with pi the parameters of every link stacked: Y is checked against
Pinocchio's ``computeJointTorqueRegressor`` (``test/test_regressor.py``).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from neforward_ros.kinematics.forward import DEFAULT_GRAVITY, forward_recursion
from neforward_ros.model import JointKind, RobotModel

PARAMETERS = ("m", "mcx", "mcy", "mcz", "ixx", "ixy", "ixz", "iyy", "iyz", "izz")
"""The order of a link's ten inertial parameters."""


UPPER = ([0, 0, 0, 1, 1, 2], [0, 1, 2, 1, 2, 2])
"""The (row, column) indices of (ixx, ixy, ixz, iyy, iyz, izz) in a 3x3 inertia."""


def origin_inertia(parameters: np.ndarray) -> np.ndarray:
    """(..., 10) -> (..., 3, 3): the rotational inertia about the link origin the parameters hold."""
    ixx, ixy, ixz, iyy, iyz, izz = (parameters[..., 4 + k] for k in range(6))
    return np.stack([np.stack([ixx, ixy, ixz], -1), np.stack([ixy, iyy, iyz], -1), np.stack([ixz, iyz, izz], -1)], -2)


def skew(v: np.ndarray) -> np.ndarray:
    """(..., 3) -> (..., 3, 3) cross-product matrices, ``skew(a) @ b = a x b``."""
    out = np.zeros((*v.shape, 3))
    out[..., 0, 1], out[..., 0, 2] = -v[..., 2], v[..., 1]
    out[..., 1, 0], out[..., 1, 2] = v[..., 2], -v[..., 0]
    out[..., 2, 0], out[..., 2, 1] = -v[..., 1], v[..., 0]
    return out


def _inertia_map(w: np.ndarray) -> np.ndarray:
    """(..., 3) -> (..., 3, 6): ``I @ w`` as a linear map of (ixx, ixy, ixz, iyy, iyz, izz)."""
    out = np.zeros((*w.shape[:-1], 3, 6))
    x, y, z = w[..., 0], w[..., 1], w[..., 2]
    out[..., 0, 0], out[..., 0, 1], out[..., 0, 2] = x, y, z
    out[..., 1, 1], out[..., 1, 3], out[..., 1, 4] = x, y, z
    out[..., 2, 2], out[..., 2, 4], out[..., 2, 5] = x, y, z
    return out


def link_parameters(model: RobotModel) -> np.ndarray:
    """(n_links, 10) every link's inertial parameters as the model has them (see the module docstring)."""
    out = np.zeros((len(model.link_names), 10))
    for i in range(len(model.link_names)):
        m = float(model.mass[i]) if model.mass else 0.0
        c = np.asarray(model.com_in_link[i], dtype=float)
        inertia_c = np.asarray(model.inertia_in_link[i], dtype=float).reshape(3, 3) if model.inertia_in_link else 0
        inertia_o = inertia_c + m * (float(c @ c) * np.eye(3) - np.outer(c, c))
        out[i, 0], out[i, 1:4] = m, m * c
        out[i, 4:] = inertia_o[UPPER]
    return out


def split_parameters(parameters: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(..., 10) -> (mass (...), centre of mass (..., 3) m, inertia about it (..., 3, 3) kg m^2), link
    axes; a massless link has its centre of mass at its origin."""
    m = parameters[..., 0]
    h = parameters[..., 1:4]
    safe = np.where(m > 0, m, 1.0)
    c = np.where((m > 0)[..., None], h / safe[..., None], 0.0)
    inertia_o = origin_inertia(parameters)
    cc = np.einsum("...i,...i->...", c, c)
    shift = m[..., None, None] * (cc[..., None, None] * np.eye(3) - np.einsum("...i,...j->...ij", c, c))
    return m, c, inertia_o - shift


def torque_regressor(
    model: RobotModel, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray, gravity: Sequence[float] = DEFAULT_GRAVITY
) -> np.ndarray:
    """(T, n_joints, n_links, 10): the joint torques (N m; N for a prismatic joint) as
    ``np.einsum("tjlk,lk->tj", Y, parameters)`` for any links' parameters; a fixed base.

    Args:
        q, qd, qdd: (T, n_joints) in the model's column order (rad, rad/s, rad/s^2; m for prismatic).
        gravity: in the root frame, m/s^2.
    """
    q, qd, qdd = (np.atleast_2d(np.asarray(x, dtype=float)) for x in (q, qd, qdd))
    kin = forward_recursion(model, q, qd, qdd, gravity=gravity)
    omega, alpha, accel = kin.omega, kin.alpha, kin.accel  # (T, L, 3), link frames
    samples, links = omega.shape[:2]
    wrench = np.zeros((samples, links, 6, 10))  # [f; n] about the link origin, link frame
    wrench[..., :3, 0] = accel
    wrench[..., :3, 1:4] = skew(alpha) + skew(omega) @ skew(omega)
    wrench[..., 3:, 1:4] = -skew(accel)
    wrench[..., 3:, 4:] = _inertia_map(alpha) + skew(omega) @ _inertia_map(omega)
    rotation = kin.rotation  # (T, L, 3, 3) link -> root
    force = rotation @ wrench[..., :3, :]  # (T, L, 3, 10), root axes
    moment = rotation @ wrench[..., 3:, :]
    out = np.zeros((samples, len(model.joint_names), links, 10))
    parents = [-1 if joint is None else joint.parent_index for joint in model.parent_joints]
    for k, joint in enumerate(model.parent_joints):
        if joint is None or joint.kind is JointKind.FIXED or joint.q_index < 0:
            continue
        axis = rotation[:, k] @ np.asarray(joint.axis, dtype=float)  # (T, 3) root axes
        for i in range(links):  # the links joint k carries: k and its descendants
            a = i
            while a != -1 and a != k:
                a = parents[a]
            if a != k:
                continue
            if joint.kind is JointKind.PRISMATIC:
                row = np.einsum("tx,txp->tp", axis, force[:, i])
            else:
                lever = kin.position[:, i] - kin.position[:, k]  # (T, 3)
                moved = moment[:, i] + np.cross(lever[:, :, None], force[:, i], axis=1)
                row = np.einsum("tx,txp->tp", axis, moved)
            out[:, joint.q_index, i] += joint.multiplier * row
    return out
