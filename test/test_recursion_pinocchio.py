"""forward_recursion against Pinocchio, the reference implementation, on every test robot.

Pinocchio computes the same quantities by its own algorithms (forwardKinematics with frame
accessors). It builds mimic joints itself (``mimic=True``) and leaves gravity out, so the test adds
``-R^T g`` to its classical accelerations. Centres of mass are read from the URDF by a separate
XML parse here, and become Pinocchio operational frames.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from neforward_ros import forward_recursion, load_model

from conftest import TEST_ROBOTS, assert_close
from oracle import GRAVITY, PinocchioOracle, pin

REL = 1e-9


FIELDS = ("omega", "alpha", "velocity", "accel", "com_accel", "com_velocity", "position", "rotation", "com_position")


def random_states(n_joints: int, n_samples: int, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    q = rng.uniform(-2.0, 2.0, (n_samples, n_joints))
    qd = rng.uniform(-3.0, 3.0, (n_samples, n_joints))
    qdd = rng.uniform(-10.0, 10.0, (n_samples, n_joints))
    return q, qd, qdd


def test_every_field_matches_pinocchio(robot_path: Path) -> None:
    model = load_model(robot_path)
    oracle = PinocchioOracle(robot_path)
    q, qd, qdd = random_states(len(model.joint_names), 20, seed=len(model.link_names))
    batch = forward_recursion(model, q, qd, qdd, gravity=GRAVITY)
    for t in range(len(q)):
        expected = oracle.kinematics(model.joint_names, model.link_names, q[t], qd[t], qdd[t])
        single = forward_recursion(model, q[t], qd[t], qdd[t], gravity=GRAVITY)
        for field in FIELDS:
            assert_close(getattr(single, field), expected[field], REL, f"{robot_path.name} sample {t} {field}")
            assert_close(getattr(batch, field)[t], expected[field], REL, f"{robot_path.name} batch {t} {field}")


def test_root_frame_view_matches_pinocchio_local_world_aligned(robot_path: Path) -> None:
    model = load_model(robot_path)
    oracle = PinocchioOracle(robot_path)
    q, qd, qdd = random_states(len(model.joint_names), 3, seed=7)
    for t in range(len(q)):
        kin = forward_recursion(model, q[t], qd[t], qdd[t], gravity=GRAVITY).in_root()
        oracle.kinematics(model.joint_names, model.link_names, q[t], qd[t], qdd[t])
        aligned = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED
        for k, link in enumerate(model.link_names):
            body, com = oracle.link_frames[link]
            velocity = pin.getFrameVelocity(oracle.model, oracle.data, body, aligned)
            accel = pin.getFrameClassicalAcceleration(oracle.model, oracle.data, body, aligned)
            com_accel = pin.getFrameClassicalAcceleration(oracle.model, oracle.data, com, aligned)
            assert_close(kin.omega[k], velocity.angular, REL, f"{link} omega")
            assert_close(kin.velocity[k], velocity.linear, REL, f"{link} velocity")
            assert_close(kin.alpha[k], accel.angular, REL, f"{link} alpha")
            assert_close(kin.accel[k], accel.linear - GRAVITY, REL, f"{link} accel")
            assert_close(kin.com_accel[k], com_accel.linear - GRAVITY, REL, f"{link} com_accel")


def test_orientations_are_the_rotations_as_unit_quaternions_with_w_not_negative(robot_path: Path) -> None:
    from scipy.spatial.transform import Rotation

    model = load_model(robot_path)
    oracle = PinocchioOracle(robot_path)
    q, qd, qdd = random_states(len(model.joint_names), 5, seed=3)
    batch = forward_recursion(model, q, qd, qdd)
    for t in range(len(q)):
        expected = oracle.kinematics(model.joint_names, model.link_names, q[t], qd[t], qdd[t])["rotation"]
        for orientation in (batch.orientation[t], forward_recursion(model, q[t], qd[t], qdd[t]).orientation):
            assert np.all(orientation[:, 3] >= 0.0)
            assert_close(np.linalg.norm(orientation, axis=1), np.ones(len(model.link_names)), 1e-12, "norm")
            assert_close(Rotation.from_quat(orientation).as_matrix(), expected, REL, f"{robot_path.name} {t}")


def test_batches_computed_in_several_chunks_match_pinocchio(monkeypatch) -> None:
    """Batches go through the recursion a chunk of samples at a time: stitching them must not matter."""
    from neforward_ros.kinematics import forward as recursion

    monkeypatch.setattr(recursion, "_CHUNK", 7)
    path = TEST_ROBOTS["humanoid"]
    model = load_model(path)
    oracle = PinocchioOracle(path)
    q, qd, qdd = random_states(len(model.joint_names), 30, seed=11)
    batch = forward_recursion(model, q, qd, qdd, gravity=GRAVITY)
    for t in range(len(q)):
        expected = oracle.kinematics(model.joint_names, model.link_names, q[t], qd[t], qdd[t])
        for field in FIELDS:
            assert_close(getattr(batch, field)[t], expected[field], REL, f"sample {t} {field}")
