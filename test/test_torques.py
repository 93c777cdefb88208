"""The node's dynamics outputs: ~/joint_torques, ~/external_torques, ~/<link>/wrench and ~/contact,
against Pinocchio for the robot carrying a payload the model does not know."""

from __future__ import annotations

import xml.etree.ElementTree as ElementTree

import numpy as np
import pytest

from neforward_ros import inverse_dynamics, load_model
from neforward_ros.node.pipeline import Pipeline, TrajectoryPoint
from neforward_ros.parameters.settings import node_settings

from conftest import CONFIG_DIR, EPOCH_NS
from oracle import GRAVITY, pin

PANDA = CONFIG_DIR / "panda.urdf"
MODEL = load_model(PANDA)
PAYLOAD_MASS = 2.0
PAYLOAD_AT = np.array([0.0, 0.0, 0.1])  # in the hand's frame


def with_payload() -> str:
    """The arm's URDF with a point mass fixed to its hand: what the drivers' efforts will show."""
    root = ElementTree.parse(PANDA).getroot()
    link = ElementTree.SubElement(root, "link", {"name": "payload"})
    inertial = ElementTree.SubElement(link, "inertial")
    ElementTree.SubElement(inertial, "origin", {"xyz": "0 0 0"})
    ElementTree.SubElement(inertial, "mass", {"value": str(PAYLOAD_MASS)})
    ElementTree.SubElement(inertial, "inertia", dict.fromkeys(("ixx", "ixy", "ixz", "iyy", "iyz", "izz"), "0"))
    joint = ElementTree.SubElement(root, "joint", {"name": "payload_joint", "type": "fixed"})
    ElementTree.SubElement(joint, "parent", {"link": "panda_hand"})
    ElementTree.SubElement(joint, "child", {"link": "payload"})
    ElementTree.SubElement(joint, "origin", {"xyz": " ".join(map(str, PAYLOAD_AT))})
    return ElementTree.tostring(root, encoding="unicode")


class Loaded:
    """Pinocchio's model of the arm with the payload: efforts, and J^T w of the payload's wrench."""

    def __init__(self) -> None:
        self.model = pin.buildModelFromXML(with_payload(), mimic=True)
        self.data = self.model.createData()
        self.frame = self.model.getFrameId("payload")
        self.columns = [self.model.joints[self.model.getJointId(n)].idx_v for n in MODEL.joint_names]

    def vectors(self, q, qd, qdd):
        qp, vp, ap = np.zeros(self.model.nq), np.zeros(self.model.nv), np.zeros(self.model.nv)
        qp[self.columns], vp[self.columns], ap[self.columns] = q, qd, qdd
        return qp, vp, ap

    def efforts(self, q, qd, qdd) -> np.ndarray:
        return pin.rnea(self.model, self.data, *self.vectors(q, qd, qdd))[self.columns]

    def jacobian_transpose_wrench(self, q, qd, qdd) -> np.ndarray:
        """J(q)^T w: w the wrench the arm exerts on the payload, m (a - g) at its point, no moment."""
        qp, vp, ap = self.vectors(q, qd, qdd)
        aligned = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED
        pin.forwardKinematics(self.model, self.data, qp, vp, ap)
        pin.updateFramePlacements(self.model, self.data)
        accel = pin.getFrameClassicalAcceleration(self.model, self.data, self.frame, aligned).linear
        jacobian = pin.computeFrameJacobian(self.model, self.data, qp, self.frame, aligned)[:3]
        return (jacobian.T @ (PAYLOAD_MASS * (accel - GRAVITY)))[self.columns]


def random_state(seed: int):
    rng = np.random.default_rng(seed)
    n = len(MODEL.joint_names)
    return rng.uniform(-1.5, 1.5, n), rng.uniform(-2, 2, n), rng.uniform(-5, 5, n)


def supplied(pipeline: Pipeline, stamp: int, q, qd, qdd, efforts):
    point = TrajectoryPoint(q.tolist(), qd.tolist(), qdd.tolist(), 0, list(efforts))
    return pipeline.on_joint_trajectory(stamp, list(MODEL.joint_names), [point])


def test_external_torques_are_the_payloads_jacobian_transpose_wrench_and_zero_without_it() -> None:
    loaded = Loaded()
    pipeline = Pipeline(
        node_settings(
            {"robot_description": PANDA.read_text(), "publish_torques": True, "acceleration_source": "supplied"}
        )
    )
    for seed in range(5):
        q, qd, qdd = random_state(seed)
        (result,) = supplied(pipeline, EPOCH_NS + seed, q, qd, qdd, loaded.efforts(q, qd, qdd))
        expected = loaded.jacobian_transpose_wrench(q, qd, qdd)
        np.testing.assert_allclose(
            result.dynamics.external, expected, rtol=0, atol=1e-6 * max(1, np.abs(expected).max())
        )
        contents = dict(pipeline.messages(result))
        np.testing.assert_allclose(
            contents["~/external_torques"]["effort"], expected, atol=1e-6 * max(1, np.abs(expected).max())
        )
        np.testing.assert_allclose(
            contents["~/joint_torques"]["effort"],
            inverse_dynamics(MODEL, q, qd, qdd).joint_torque,
            rtol=1e-12,
            atol=1e-9,
        )
        assert contents["~/joint_torques"]["name"] == list(MODEL.joint_names)
        # the efforts of the arm without the payload: nothing external
        bare_torque = inverse_dynamics(MODEL, q, qd, qdd).joint_torque
        (bare,) = supplied(pipeline, EPOCH_NS + 100 + seed, q, qd, qdd, bare_torque)
        assert np.abs(bare.dynamics.external).max() <= 1e-9


def test_effort_scale_and_offset_are_applied_before_the_difference() -> None:
    names = list(MODEL.joint_names)
    pipeline = Pipeline(
        node_settings(
            {
                "robot_description": PANDA.read_text(),
                "publish_torques": True,
                "acceleration_source": "supplied",
                "effort.joint_names": [names[1], names[3]],
                "effort.scale": [2.0, -1.0],
                "effort.offset": [0.5, 0.0],
            }
        )
    )
    q, qd, qdd = random_state(9)
    model_torque = inverse_dynamics(MODEL, q, qd, qdd).joint_torque
    raw = model_torque.copy()
    raw[1] = (model_torque[1] - 0.5) / 2.0  # so that 2 * raw + 0.5 is the model's torque
    raw[3] = -model_torque[3]
    (result,) = supplied(pipeline, EPOCH_NS, q, qd, qdd, raw)
    assert np.abs(result.dynamics.external).max() <= 1e-9


def test_wrench_messages_are_the_joint_wrenches_in_the_link_frame() -> None:
    pipeline = Pipeline(
        node_settings(
            {
                "robot_description": PANDA.read_text(),
                "wrench_links": ["panda_link4", "panda_hand"],
                "acceleration_source": "supplied",
                "frame_prefix": "left/",
            }
        )
    )
    q, qd, qdd = random_state(3)
    (result,) = supplied(pipeline, EPOCH_NS, q, qd, qdd, [])
    contents = dict(pipeline.messages(result))
    expected = inverse_dynamics(MODEL, q, qd, qdd)
    for link in ("panda_link4", "panda_hand"):
        message = contents[f"~/{link}/wrench"]
        k = MODEL.link_index[link]
        assert message["header"]["frame_id"] == "left/" + link
        force = [message["wrench"]["force"][a] for a in "xyz"]
        torque = [message["wrench"]["torque"][a] for a in "xyz"]
        np.testing.assert_allclose(force, expected.force[k], rtol=1e-12, atol=1e-9)
        np.testing.assert_allclose(torque, expected.moment[k], rtol=1e-12, atol=1e-9)
    assert "~/joint_torques" not in contents  # publish_torques is off
    # the encoded bytes are those of the contents
    from neforward_ros.wire import cdr

    types = {output.topic: output.type for output in pipeline.outputs()}
    assert pipeline.encode(result) == [(t, cdr.encode(types[t], c)) for t, c in pipeline.messages(result)]


def test_contact_turns_on_when_a_payload_is_grasped_and_off_when_released_with_debounce() -> None:
    """Joint states at 500 Hz, positions and efforts, the payload in the hand from 1.0 s to 2.0 s; the
    estimator's defaults; contact thresholds of 2 N m on the shoulder and elbow joints."""
    loaded = Loaded()
    names = list(MODEL.joint_names)
    pipeline = Pipeline(
        node_settings(
            {
                "robot_description": PANDA.read_text(),
                "contact.joint_names": [names[1], names[3]],
                "contact.thresholds": [2.0, 2.0],
                "contact.debounce": 0.05,
                "publish_torques": True,
            }
        )
    )
    t = np.arange(1500) / 500.0
    k = np.arange(len(names))
    w = 2 * np.pi * (0.2 + 0.05 * k)
    q = 0.4 * np.sin(np.outer(t, w) + k) + np.where(k == 3, -1.5, 0.0) + np.where(k == 1, 0.8, 0.0)  # leaning out
    qd = 0.4 * w * np.cos(np.outer(t, w) + k)
    qdd = -0.4 * w**2 * np.sin(np.outer(t, w) + k)
    states = []
    for i in range(len(t)):
        held = 1.0 <= t[i] < 2.0
        effort = (
            loaded.efforts(q[i], qd[i], qdd[i]) if held else inverse_dynamics(MODEL, q[i], qd[i], qdd[i]).joint_torque
        )
        states += pipeline.on_joint_state(EPOCH_NS + round(t[i] * 1e9), names, q[i].tolist(), [], effort.tolist())
    stamps = np.array([(r.stamp_ns - EPOCH_NS) / 1e9 for r in states])
    contact = np.array([r.contact for r in states])
    assert contact[(stamps > 0.2) & (stamps < 1.0)].sum() == 0
    assert contact[(stamps > 1.1) & (stamps < 1.95)].all()
    assert not contact[stamps > 2.1].any()
    onset = stamps[np.argmax(contact)]
    assert 1.05 - 0.01 <= onset <= 1.1  # the debounce: 0.05 s after the payload appears
    external = np.array([r.dynamics.external for r in states])
    truth = np.array([loaded.jacobian_transpose_wrench(q[i], qd[i], qdd[i]) for i in np.searchsorted(t, stamps)])
    inside = (stamps > 1.15) & (stamps < 1.85)
    error = np.abs(external[inside] - truth[inside]).max()
    assert error <= 0.02 * np.abs(truth[inside]).max(), error  # estimated accelerations: close, not exact


@pytest.mark.parametrize(
    "parameters, text",
    [
        ({"contact.joint_names": ["a"], "contact.thresholds": []}, "same length"),
        ({"contact.joint_names": ["a"], "contact.thresholds": [0.0]}, "positive"),
        ({"effort.joint_names": ["a"], "effort.scale": [1.0, 2.0]}, "same length"),
    ],
)
def test_bad_dynamics_parameters_are_refused(parameters, text) -> None:
    from neforward_ros import InputError

    with pytest.raises(InputError, match=text):
        node_settings(parameters)
