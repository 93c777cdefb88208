"""forward_recursion against Pinocchio, the reference implementation, on every test robot.

Pinocchio computes the same quantities by its own algorithms (forwardKinematics with frame
accessors). It builds mimic joints itself (``mimic=True``) and leaves gravity out, so the test adds
``-R^T g`` to its classical accelerations. Centres of mass are read from the URDF by a separate
XML parse here, and become Pinocchio operational frames.
"""

from __future__ import annotations

import xml.etree.ElementTree as ElementTree
from pathlib import Path

import numpy as np
import pytest

from neforward_ros import forward_recursion, load_model

from conftest import assert_close

pin = pytest.importorskip("pinocchio", reason="Pinocchio (PyPI 'pin') is the test oracle; install the test extras")

GRAVITY = np.array([0.0, 0.0, -9.81])
REL = 1e-9


def com_offsets_from_xml(path: Path) -> dict[str, np.ndarray]:
    offsets = {}
    for link in ElementTree.parse(path).getroot().iter("link"):
        origin = link.find("inertial/origin")
        xyz = origin.get("xyz", "0 0 0") if origin is not None else "0 0 0"
        offsets[link.get("name")] = np.array([float(v) for v in xyz.split()])
    return offsets


class PinocchioOracle:
    def __init__(self, path: Path) -> None:
        self.model = pin.buildModelFromXML(path.read_text(), mimic=True)
        coms = com_offsets_from_xml(path)
        self.link_frames: dict[str, tuple[int, int]] = {}
        for link, com in coms.items():
            body = self.model.getFrameId(link, pin.FrameType.BODY)
            frame = self.model.frames[body]
            placement = frame.placement * pin.SE3(np.eye(3), com)
            com_frame = self.model.addFrame(
                pin.Frame(f"{link}__com", frame.parentJoint, body, placement, pin.FrameType.OP_FRAME)
            )
            self.link_frames[link] = (body, com_frame)
        self.data = self.model.createData()

    def joint_layout(self, joint_names: tuple[str, ...]) -> list[tuple[int, int, int]]:
        layout = []
        for name in joint_names:
            joint = self.model.joints[self.model.getJointId(name)]
            layout.append((joint.idx_q, joint.nq, joint.idx_v))
        return layout

    def kinematics(self, joint_names, link_names, q, qd, qdd) -> dict[str, np.ndarray]:
        model, data = self.model, self.data
        qp, vp, ap = np.zeros(model.nq), np.zeros(model.nv), np.zeros(model.nv)
        for k, (iq, nq, iv) in enumerate(self.joint_layout(joint_names)):
            if nq == 2:  # continuous joint: Pinocchio stores (cos q, sin q)
                qp[iq], qp[iq + 1] = np.cos(q[k]), np.sin(q[k])
            else:
                qp[iq] = q[k]
            vp[iv], ap[iv] = qd[k], qdd[k]
        pin.forwardKinematics(model, data, qp, vp, ap)
        pin.updateFramePlacements(model, data)
        local = pin.ReferenceFrame.LOCAL
        out = {key: [] for key in ("omega", "alpha", "velocity", "accel", "com_accel", "position", "rotation")}
        for link in link_names:
            body, com = self.link_frames[link]
            rotation = data.oMf[body].rotation
            minus_g_in_link = rotation.T @ -GRAVITY
            velocity = pin.getFrameVelocity(model, data, body, local)
            accel = pin.getFrameClassicalAcceleration(model, data, body, local)
            com_accel = pin.getFrameClassicalAcceleration(model, data, com, local)
            out["omega"].append(velocity.angular.copy())
            out["velocity"].append(velocity.linear.copy())
            out["alpha"].append(accel.angular.copy())
            out["accel"].append(accel.linear + minus_g_in_link)
            out["com_accel"].append(com_accel.linear + minus_g_in_link)
            out["position"].append(data.oMf[body].translation.copy())
            out["rotation"].append(rotation.copy())
        return {key: np.array(values) for key, values in out.items()}


FIELDS = ("omega", "alpha", "velocity", "accel", "com_accel", "position", "rotation")


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
