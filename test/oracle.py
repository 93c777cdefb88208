"""Pinocchio as the test oracle: the same link quantities computed by its own algorithms.

Pinocchio builds mimic joints itself (``mimic=True``) and leaves gravity out, so the oracle adds
``-R^T g`` to its classical accelerations. Centres of mass are read from the URDF by a separate
XML parse here, and become Pinocchio operational frames.
"""

from __future__ import annotations

import xml.etree.ElementTree as ElementTree
from pathlib import Path

import numpy as np
import pinocchio as pin  # test modules that use this one are skipped without it (conftest.REQUIREMENTS)

GRAVITY = np.array([0.0, 0.0, -9.81])


def unfixed_urdf(path: Path) -> str:
    """The URDF with every fixed joint made a revolute one (kept at 0 by the callers): Pinocchio merges
    the links of fixed joints into their parent's body, and a joint of its own for each link gives
    the wrench through every joint (``data.f``) and an external force on every link."""
    root = ElementTree.parse(path).getroot()
    for joint in root.iter("joint"):
        if joint.get("type") == "fixed":
            joint.set("type", "revolute")
            ElementTree.SubElement(joint, "axis", {"xyz": "0 0 1"})
            ElementTree.SubElement(joint, "limit", {"lower": "-1", "upper": "1", "effort": "1", "velocity": "1"})
    return ElementTree.tostring(root, encoding="unicode")


def com_offsets_from_xml(path: Path) -> dict[str, np.ndarray]:
    offsets = {}
    for link in ElementTree.parse(path).getroot().iter("link"):
        origin = link.find("inertial/origin")
        xyz = origin.get("xyz", "0 0 0") if origin is not None else "0 0 0"
        offsets[link.get("name")] = np.array([float(v) for v in xyz.split()])
    return offsets


class PinocchioOracle:
    """Pinocchio's model of a URDF; ``unfix``: with every fixed joint made a joint (see unfixed_urdf);
    ``mimic=False``: mimic joints as independent joints; ``free_flyer``: the root on a free-flyer
    joint (a floating base: the first 7 entries of q and 6 of v and a are the base's)."""

    def __init__(self, path: Path, unfix: bool = False, mimic: bool = True, free_flyer: bool = False) -> None:
        text = unfixed_urdf(path) if unfix else path.read_text()
        if free_flyer:  # the root link on a free-flyer joint: a floating base
            self.model = pin.buildModelFromXML(text, pin.JointModelFreeFlyer(), mimic=mimic)
        else:
            self.model = pin.buildModelFromXML(text, mimic=mimic)
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

    def pin_vectors(self, joint_names, q, qd, qdd) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Pinocchio's configuration, velocity and acceleration vectors for our joint columns."""
        model = self.model
        qp, vp, ap = np.zeros(model.nq), np.zeros(model.nv), np.zeros(model.nv)
        for k, (iq, nq, iv) in enumerate(self.joint_layout(joint_names)):
            if nq == 2:  # continuous joint: Pinocchio stores (cos q, sin q)
                qp[iq], qp[iq + 1] = np.cos(q[k]), np.sin(q[k])
            else:
                qp[iq] = q[k]
            vp[iv], ap[iv] = qd[k], qdd[k]
        return qp, vp, ap

    def fill(self, link_names, qp, vp, ap) -> dict[str, np.ndarray]:
        """Per link, as an efficient Pinocchio user would collect them: LOCAL omega, alpha, velocity,
        accel and com_accel (specific forces, gravity added in one vectorised step); position and
        rotation in the root frame. What bench_recursion.py times against forward_recursion."""
        model, data, local = self.model, self.data, pin.ReferenceFrame.LOCAL
        velocities, accels, com_accels, placements = [], [], [], []
        pin.forwardKinematics(model, data, qp, vp, ap)
        pin.updateFramePlacements(model, data)
        for link in link_names:
            body, com = self.link_frames[link]
            velocities.append(pin.getFrameVelocity(model, data, body, local).np)
            accels.append(pin.getFrameClassicalAcceleration(model, data, body, local).np)
            com_accels.append(pin.getFrameClassicalAcceleration(model, data, com, local).np)
            placements.append(data.oMf[body].homogeneous)
        velocity, accel, com_accel = np.array(velocities), np.array(accels), np.array(com_accels)
        pose = np.array(placements)
        rotation = pose[:, :3, :3]
        minus_g_in_link = -GRAVITY @ rotation  # row k: R_k^T (-g)
        return {
            "omega": velocity[:, 3:],
            "alpha": accel[:, 3:],
            "velocity": velocity[:, :3],
            "accel": accel[:, :3] + minus_g_in_link,
            "com_accel": com_accel[:, :3] + minus_g_in_link,
            "position": pose[:, :3, 3],
            "rotation": rotation,
        }

    def calls_only(self, link_names, qp, vp, ap) -> None:
        """The same Pinocchio calls with nothing collected: a floor, not the same outputs."""
        model, data, local = self.model, self.data, pin.ReferenceFrame.LOCAL
        pin.forwardKinematics(model, data, qp, vp, ap)
        pin.updateFramePlacements(model, data)
        for link in link_names:
            body, com = self.link_frames[link]
            pin.getFrameVelocity(model, data, body, local)
            pin.getFrameClassicalAcceleration(model, data, body, local)
            pin.getFrameClassicalAcceleration(model, data, com, local)

    def kinematics(self, joint_names, link_names, q, qd, qdd) -> dict[str, np.ndarray]:
        """Per link, in the link frame (LOCAL): omega, alpha, velocity, accel and com_accel (specific
        forces), com_velocity; in the root frame: position, rotation (link -> root), com_position."""
        model, data = self.model, self.data
        out = self.fill(link_names, *self.pin_vectors(joint_names, q, qd, qdd))
        local = pin.ReferenceFrame.LOCAL
        out["com_position"] = np.array([data.oMf[self.link_frames[link][1]].translation for link in link_names])
        out["com_velocity"] = np.array(
            [pin.getFrameVelocity(model, data, self.link_frames[link][1], local).linear for link in link_names]
        )
        return out

    def link_joints(self, parent_joint_names: list[str | None]) -> list[int]:
        """Pinocchio's joint id for each link's parent joint (0, the universe, for the root); needs unfix."""
        return [0 if name is None else self.model.getJointId(name) for name in parent_joint_names]

    def rnea_only(self, qp, vp, ap) -> np.ndarray:
        """pin.rnea alone: the joint torques, the wrenches left in data.f (a floor, not the same outputs)."""
        return pin.rnea(self.model, self.data, qp, vp, ap)

    def rnea_fill(self, joint_ids: list[int], qp, vp, ap, fext=None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """pin.rnea, and per link the wrench through its joint (data.f), as an efficient Pinocchio user
        collects them: (tau, force (n_links, 3), moment (n_links, 3)). The root's is left zero."""
        model, data = self.model, self.data
        tau = pin.rnea(model, data, qp, vp, ap) if fext is None else pin.rnea(model, data, qp, vp, ap, fext)
        f = data.f
        return tau, np.array([f[i].linear for i in joint_ids]), np.array([f[i].angular for i in joint_ids])
