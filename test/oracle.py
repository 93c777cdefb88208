"""Pinocchio as the test oracle: the same link quantities computed by its own algorithms.

Pinocchio builds mimic joints itself (``mimic=True``) and leaves gravity out, so the oracle adds
``-R^T g`` to its classical accelerations. Centres of mass are read from the URDF by a separate
XML parse here, and become Pinocchio operational frames.
"""

from __future__ import annotations

import xml.etree.ElementTree as ElementTree
from pathlib import Path

import numpy as np
import pytest

pin = pytest.importorskip("pinocchio", reason="Pinocchio (PyPI 'pin') is the test oracle; install the test extras")

GRAVITY = np.array([0.0, 0.0, -9.81])


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
        """Per link, in the link frame (LOCAL): omega, alpha, velocity, accel and com_accel (specific
        forces), com_velocity; in the root frame: position, rotation (link -> root), com_position."""
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
        keys = (
            "omega",
            "alpha",
            "velocity",
            "accel",
            "com_accel",
            "position",
            "rotation",
            "com_position",
            "com_velocity",
        )
        out = {key: [] for key in keys}
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
            out["com_position"].append(data.oMf[com].translation.copy())
            out["com_velocity"].append(pin.getFrameVelocity(model, data, com, local).linear.copy())
        return {key: np.array(values) for key, values in out.items()}
