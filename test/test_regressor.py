"""The inverse-dynamics regressor (neforward_ros.kinematics.regressor) against Pinocchio: its columns
against ``computeJointTorqueRegressor``, and Y @ pi against ``rnea`` for random physical parameters."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from neforward_ros import inverse_dynamics, load_model
from neforward_ros.kinematics.regressor import link_parameters, split_parameters, torque_regressor

from conftest import TEST_ROBOTS

PIN_ORDER = [0, 1, 2, 3, 4, 5, 7, 6, 8, 9]  # ours (ixx ixy ixz iyy iyz izz) in Pinocchio's (ixx ixy iyy ixz iyz izz)
ROBOTS = ["panda", "arm_6r", "tree", "prismatic", "planar_2r", "humanoid"]


def driven(model):
    """(Pinocchio joint name, our column, multiplier, offset) of every movable joint, mimic joints too."""
    return [
        (joint.name, joint.q_index, joint.multiplier, joint.offset)
        for joint in model.parent_joints
        if joint is not None and joint.q_index >= 0
    ]


def pinocchio_vectors(pmodel, model, q, qd, qdd):
    """Our columns as Pinocchio's q, v, a (built without mimic support: a mimic joint is a joint of its
    own, given its leader's motion)."""
    qp, vp, ap = pin.neutral(pmodel), np.zeros(pmodel.nv), np.zeros(pmodel.nv)
    for name, column, multiplier, offset in driven(model):
        joint = pmodel.joints[pmodel.getJointId(name)]
        angle = multiplier * q[column] + offset
        if joint.nq == 2:  # a continuous joint: (cos, sin)
            qp[joint.idx_q], qp[joint.idx_q + 1] = np.cos(angle), np.sin(angle)
        else:
            qp[joint.idx_q] = angle
        vp[joint.idx_v], ap[joint.idx_v] = multiplier * qd[column], multiplier * qdd[column]
    return qp, vp, ap


def in_our_columns(pmodel, model, rows: np.ndarray) -> np.ndarray:
    """Pinocchio's per-joint rows summed into our columns (a mimic joint's, times its multiplier, into
    its leader's): the generalized forces of our coordinates."""
    out = np.zeros((len(model.joint_names), *rows.shape[1:]))
    for name, column, multiplier, _ in driven(model):
        out[column] += multiplier * rows[pmodel.joints[pmodel.getJointId(name)].idx_v]
    return out


@pytest.mark.parametrize("robot", ROBOTS)
def test_the_regressor_columns_are_pinocchios(robot) -> None:
    path = TEST_ROBOTS[robot]
    model = load_model(path)
    pmodel = pin.buildModelFromUrdf(str(path))
    pdata = pmodel.createData()
    rng = np.random.default_rng(3)
    q, qd, qdd = rng.uniform(-1.5, 1.5, (3, 4, len(model.joint_names)))
    regressor = torque_regressor(model, q, qd, qdd)
    checked = 0
    for t in range(len(q)):
        vectors = pinocchio_vectors(pmodel, model, q[t], qd[t], qdd[t])
        expected = in_our_columns(pmodel, model, pin.computeJointTorqueRegressor(pmodel, pdata, *vectors))
        for jid in range(1, pmodel.njoints):
            name = pmodel.names[jid]
            child = next(i for i, joint in enumerate(model.parent_joints) if joint is not None and joint.name == name)
            block = expected[:, 10 * (jid - 1) : 10 * jid]
            np.testing.assert_allclose(regressor[t, :, child][:, PIN_ORDER], block, atol=1e-10, err_msg=name)
            checked += 1
    assert checked >= len(q) * len(model.joint_names)


@pytest.mark.parametrize("robot", [*ROBOTS, "mimic", "fixed_between", "inertias"])
def test_the_regressor_times_random_physical_parameters_is_rnea(robot) -> None:
    """Random masses, centres of mass and inertias on every link (fixed ones too): Y @ pi against
    Pinocchio's rnea with its bodies made of them (and against our inverse dynamics)."""
    path = TEST_ROBOTS[robot]
    model = load_model(path)
    rng = np.random.default_rng(5)
    links = len(model.link_names)
    mass = rng.uniform(0.5, 3.0, links)
    com = rng.uniform(-0.1, 0.1, (links, 3))
    axes = np.linalg.qr(rng.normal(size=(links, 3, 3)))[0]
    inertia_c = axes @ (rng.uniform(0.01, 0.05, (links, 3))[:, :, None] * np.swapaxes(axes, 1, 2))
    from dataclasses import replace

    changed = replace(
        model,
        mass=tuple(mass.tolist()),
        com_in_link=tuple(map(tuple, com.tolist())),
        inertia_in_link=tuple(tuple(m.reshape(9).tolist()) for m in inertia_c),
        inertia_warnings=(),
    )
    parameters = link_parameters(changed)
    m, c, i_c = split_parameters(parameters)
    np.testing.assert_allclose(m, mass) and np.testing.assert_allclose(c, com, atol=1e-12)
    np.testing.assert_allclose(i_c, inertia_c, atol=1e-12)
    q, qd, qdd = rng.uniform(-1.5, 1.5, (3, 6, len(model.joint_names)))
    tau = np.einsum("tjlk,lk->tj", torque_regressor(model, q, qd, qdd), parameters)
    np.testing.assert_allclose(tau, inverse_dynamics(changed, q, qd, qdd).joint_torque, atol=1e-9)
    pmodel = pin.buildModelFromUrdf(str(path))
    pdata = pmodel.createData()
    # Rebuild the inertias of every joint body from our links: the body frame's placement in its joint.
    for jid in range(pmodel.njoints):
        pmodel.inertias[jid] = pin.Inertia.Zero()
    for frame in pmodel.frames:
        if frame.type == pin.FrameType.BODY and frame.name in model.link_index:
            k = model.link_index[frame.name]
            body = pin.Inertia(mass[k], com[k], inertia_c[k])
            pmodel.inertias[frame.parentJoint] += frame.placement.act(body)
    for t in range(len(q)):
        expected = in_our_columns(
            pmodel, model, pin.rnea(pmodel, pdata, *pinocchio_vectors(pmodel, model, q[t], qd[t], qdd[t]))
        )
        np.testing.assert_allclose(tau[t], expected, atol=1e-9)
