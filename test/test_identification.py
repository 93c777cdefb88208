"""Inertial identification (neforward_ros.calibration.inertial) on a simulated arm whose URDF's inertial
parameters are wrong: the identified model's torques on another motion against Pinocchio's rnea on
the true URDF, and physical consistency."""

from __future__ import annotations

import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest

from neforward_ros import load_model
from neforward_ros.calibration.inertial import _pseudo_inertia, from_cholesky, identify, to_cholesky
from neforward_ros.kinematics.regressor import link_parameters, torque_regressor

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "examples"))
import arm_simulator as sim
from test_contact import arm, arm_urdf


def perturbed(model, rng):
    """The URDF's masses, centres of mass and inertias off by up to 30 %, 3 cm and 30 %."""
    mass = np.array(model.mass) * rng.uniform(0.7, 1.3, len(model.mass))
    com = np.array(model.com_in_link) + rng.uniform(-0.03, 0.03, (len(mass), 3))
    inertia = np.array(model.inertia_in_link) * rng.uniform(0.7, 1.3, (len(mass), 1))
    return replace(model, mass=tuple(mass.tolist()), com_in_link=tuple(map(tuple, com.tolist())),
                   inertia_in_link=tuple(map(tuple, inertia.tolist())), inertia_warnings=())  # fmt: skip


def rnea(path, model, q, qd, qdd) -> np.ndarray:
    pmodel = pin.buildModelFromUrdf(str(path))
    pdata = pmodel.createData()
    index = [pmodel.joints[pmodel.getJointId(name)].idx_v for name in model.joint_names]
    out = []
    for a, b, c in zip(q, qd, qdd, strict=True):
        qp, vp, ap = pin.neutral(pmodel), np.zeros(pmodel.nv), np.zeros(pmodel.nv)
        qp[index], vp[index], ap[index] = a, b, c  # the xArm's joints are revolute: q index = v index
        out.append(pin.rnea(pmodel, pdata, qp, vp, ap)[index])
    return np.array(out)


def test_the_log_cholesky_numbers_give_back_the_parameters_and_only_physical_ones() -> None:
    rng = np.random.default_rng(0)
    model = load_model(arm_urdf())
    for p in link_parameters(model)[1:]:
        np.testing.assert_allclose(from_cholesky(to_cholesky(p)), p, rtol=1e-9, atol=1e-12)
    for theta in rng.normal(0.0, 1.5, (200, 10)):  # any numbers: a mass > 0 and a positive-definite pseudo-inertia
        p = from_cholesky(theta)
        assert p[0] > 0 and np.linalg.eigvalsh(_pseudo_inertia(p)).min() > -1e-12 * np.abs(p).max()


@pytest.mark.parametrize("seed", [11, 12])
def test_identified_parameters_predict_the_true_torques_on_another_motion(seed) -> None:
    rng = np.random.default_rng(seed)
    truth = load_model(arm_urdf())
    wrong = perturbed(truth, rng)
    moving = sim.simulate(arm(seed), 30.0)
    joints = arm(seed).joints
    n = len(truth.joint_names)
    found = identify(wrong, moving.true_q, moving.true_qd, moving.true_qdd, moving.effort, np.ones(n, bool),
                     (0.0, 0.0, -9.81), joints.scale, joints.velocity_scale, np.ones(n, bool))  # fmt: skip
    assert (found.links and not found.notes) or "stay near" in " ".join(found.notes)
    for p in found.parameters:  # physically consistent
        assert p[0] > 0 and np.linalg.eigvalsh(_pseudo_inertia(p)).min() >= -1e-12
    other = sim.simulate(arm(seed + 100), 10.0)  # another motion
    q, qd, qdd = other.true_q[::20], other.true_qd[::20], other.true_qdd[::20]
    expected = rnea(arm_urdf(), truth, q, qd, qdd)
    regressor = torque_regressor(wrong, q, qd, qdd)
    identified = link_parameters(wrong)
    identified[[wrong.link_index[name] for name in found.links]] = found.parameters
    before = np.einsum("tjlk,lk->tj", regressor, link_parameters(wrong)) - expected
    after = np.einsum("tjlk,lk->tj", regressor, identified) - expected
    rms = lambda x: np.sqrt(np.mean(x**2, axis=0))  # noqa: E731
    scale = rms(expected)
    assert np.all(rms(after) <= 0.3 * rms(before) + 0.01 * scale), (rms(before) / scale, rms(after) / scale)
    assert np.all(rms(after) <= 0.05 * scale + 0.02), rms(after) / scale  # N m: the efforts have 0.05 of noise


def test_efforts_that_are_not_torques_identify_nothing_and_say_what_to_give() -> None:
    model = load_model(arm_urdf())
    moving = sim.simulate(arm(13), 20.0)
    n = len(model.joint_names)
    currents = moving.effort / 10.0  # a drive gain of 10 N m per A
    found = identify(model, moving.true_q, moving.true_qd, moving.true_qdd, currents, np.ones(n, bool),
                     (0.0, 0.0, -9.81), np.ones(n), None, np.zeros(n, bool))  # fmt: skip
    assert not found.links and "--effort-scale" in found.notes[0] and "are not torques" in found.notes[0]
