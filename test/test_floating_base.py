"""Floating bases against Pinocchio with a free-flyer root joint: the root's motion given directly,
and given by an IMU on another link."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from neforward_ros import BaseMotion, InputError, forward_recursion, inverse_dynamics, load_model
from neforward_ros.kinematics.root_motion import base_from_link

from conftest import TEST_ROBOTS, assert_close
from oracle import GRAVITY, PinocchioOracle, pin

REL = 1e-9
FIELDS = ("omega", "alpha", "velocity", "accel", "com_accel", "com_velocity")


def random_base(rng) -> tuple[np.ndarray, BaseMotion]:
    """A base pose (x, y, z, qx, qy, qz, qw) and motion."""
    quaternion = rng.normal(size=4)
    pose = np.r_[rng.uniform(-1, 1, 3), quaternion / np.linalg.norm(quaternion)]
    motion = BaseMotion(
        omega=rng.uniform(-2, 2, 3),
        alpha=rng.uniform(-5, 5, 3),
        specific_force=rng.uniform(-15, 15, 3),
        velocity=rng.uniform(-1, 1, 3),
    )
    return pose, motion


def pinocchio_state(oracle: PinocchioOracle, model, pose, motion: BaseMotion, q, qd, qdd):
    """Pinocchio's q, v, a: the base's spatial velocity and acceleration (LOCAL) from ours: its
    linear acceleration is the classical one (specific force + gravity in the base frame) - w x v."""
    qp, vp, ap = oracle.pin_vectors(model.joint_names, q, qd, qdd)
    rotation = pin.Quaternion(pose[6], *pose[3:6]).toRotationMatrix()  # base -> world
    w, v = np.asarray(motion.omega), np.asarray(motion.velocity)
    classical = np.asarray(motion.specific_force) + rotation.T @ GRAVITY
    qp[:7], vp[:6], ap[:6] = pose, np.r_[v, w], np.r_[classical - np.cross(w, v), motion.alpha]
    return qp, vp, ap, rotation


def test_base_motion_given_at_the_root_matches_a_free_flyer(robot_path: Path) -> None:
    model = load_model(robot_path)
    oracle = PinocchioOracle(robot_path, free_flyer=True)
    rng = np.random.default_rng(len(model.link_names))
    n = len(model.joint_names)
    poses, motions, states = [], [], []
    for _ in range(6):
        pose, motion = random_base(rng)
        poses.append(pose)
        motions.append(motion)
        states.append(tuple(rng.uniform(-2, 2, n) for _ in range(3)))
    batch_base = BaseMotion(
        *(np.array([getattr(m, f) for m in motions]) for f in ("omega", "alpha", "velocity", "specific_force"))
    )
    q, qd, qdd = (np.array([s[k] for s in states]) for k in range(3))
    batch = forward_recursion(model, q, qd, qdd, base=batch_base)
    for t, (pose, motion) in enumerate(zip(poses, motions, strict=True)):
        qp, vp, ap, rotation = pinocchio_state(oracle, model, pose, motion, q[t], qd[t], qdd[t])
        expected = oracle.fill(model.link_names, qp, vp, ap)
        single = forward_recursion(model, q[t], qd[t], qdd[t], base=motion)
        for field in FIELDS[:5]:
            assert_close(getattr(single, field), expected[field], REL, f"{robot_path.name} {t} {field}")
            assert_close(getattr(batch, field)[t], expected[field], REL, f"{robot_path.name} batch {t} {field}")
        # poses relative to the root: Pinocchio's are in the world
        relative = np.einsum("ij,kj->ki", rotation.T, expected["position"] - pose[:3])
        assert_close(single.position, relative, REL, "position")
        assert_close(single.rotation, np.einsum("ji,kjl->kil", rotation, expected["rotation"]), REL, "rotation")


def test_base_motion_from_an_imu_on_another_link_matches_a_free_flyer() -> None:
    """A virtual IMU on a link below joints (its omega, alpha, specific force and velocity, from
    Pinocchio) gives back the root's motion, and with it every link's."""
    for robot, imu_link in (("humanoid", "torso_3"), ("panda", "panda_link4"), ("inertias", "wrist")):
        path = TEST_ROBOTS[robot]
        model = load_model(path)
        oracle = PinocchioOracle(path, free_flyer=True)
        rng = np.random.default_rng(3)
        n = len(model.joint_names)
        for _ in range(4):
            pose, motion = random_base(rng)
            q, qd, qdd = (rng.uniform(-2, 2, n) for _ in range(3))
            qp, vp, ap, _ = pinocchio_state(oracle, model, pose, motion, q, qd, qdd)
            expected = oracle.fill(model.link_names, qp, vp, ap)
            k = model.link_index[imu_link]
            recovered = base_from_link(
                model,
                imu_link,
                q,
                qd,
                qdd,
                omega=expected["omega"][k],
                alpha=expected["alpha"][k],
                specific_force=expected["accel"][k],
                velocity=expected["velocity"][k],
            )
            for field in ("omega", "alpha", "specific_force", "velocity"):
                assert_close(getattr(recovered, field), getattr(motion, field), REL, f"{robot} base {field}")
            kin = forward_recursion(model, q, qd, qdd, base=recovered)
            for field in FIELDS[:5]:
                assert_close(getattr(kin, field), expected[field], REL, f"{robot} {field}")


def test_batched_base_from_link_equals_single_samples() -> None:
    model = load_model(TEST_ROBOTS["humanoid"])
    rng = np.random.default_rng(5)
    n = len(model.joint_names)
    q, qd, qdd = (rng.uniform(-2, 2, (5, n)) for _ in range(3))
    vectors = {name: rng.uniform(-3, 3, (5, 3)) for name in ("omega", "alpha", "specific_force", "velocity")}
    batch = base_from_link(model, "torso_2", q, qd, qdd, **vectors)
    for t in range(5):
        single = base_from_link(model, "torso_2", q[t], qd[t], qdd[t], **{k: v[t] for k, v in vectors.items()})
        for field in ("omega", "alpha", "specific_force", "velocity"):
            assert_close(getattr(batch, field)[t], getattr(single, field), 1e-12, field)


def test_inverse_dynamics_with_a_moving_base_matches_pinocchio() -> None:
    """The joint torques of a robot on a moving base: Pinocchio's rnea on the free-flyer model, whose
    first six entries are the wrench the base needs (here the root's joint wrench)."""
    for robot in ("panda", "inertias", "humanoid"):
        path = TEST_ROBOTS[robot]
        model = load_model(path)
        oracle = PinocchioOracle(path, free_flyer=True)
        rng = np.random.default_rng(7)
        n = len(model.joint_names)
        columns = [iv for _, _, iv in oracle.joint_layout(model.joint_names)]
        for _ in range(3):
            pose, motion = random_base(rng)
            q, qd, qdd = (rng.uniform(-2, 2, n) for _ in range(3))
            qp, vp, ap, _ = pinocchio_state(oracle, model, pose, motion, q, qd, qdd)
            tau = pin.rnea(oracle.model, oracle.data, qp, vp, ap)
            ours = inverse_dynamics(model, q, qd, qdd, base=motion)
            assert_close(ours.joint_torque, tau[columns], REL, f"{robot} torques")
            assert_close(np.r_[ours.force[0], ours.moment[0]], tau[:6], REL, f"{robot} base wrench")


def test_a_fixed_base_is_the_default_and_bad_base_shapes_are_refused() -> None:
    model = load_model(TEST_ROBOTS["planar_2r"])
    zeros = np.zeros(2)
    fixed = forward_recursion(model, zeros, zeros, zeros)
    at_rest = forward_recursion(
        model, zeros, zeros, zeros, base=BaseMotion([0, 0, 0], [0, 0, 0], [0, 0, 0], [0, 0, 9.81])
    )
    assert_close(at_rest.accel, fixed.accel, 1e-15, "a base at rest reads what a fixed base reads")
    with pytest.raises(InputError, match="base omega has shape"):
        forward_recursion(
            model,
            zeros,
            zeros,
            zeros,
            base=BaseMotion(omega=[0, 0], alpha=[0, 0, 0], velocity=[0, 0, 0], specific_force=[0, 0, 0]),
        )
    with pytest.raises(InputError, match="non-finite"):
        forward_recursion(
            model,
            zeros,
            zeros,
            zeros,
            base=BaseMotion(omega=[0, 0, np.nan], alpha=[0, 0, 0], velocity=[0, 0, 0], specific_force=[0, 0, 0]),
        )
    with pytest.raises(InputError, match="not in robot"):
        base_from_link(model, "nope", zeros, zeros, zeros, omega=[0, 0, 0], alpha=[0, 0, 0], specific_force=[0, 0, 0])
