"""Published robots, not our fixtures: every URDF of two published corpora loads from the file and
as robot_description text with the xacro package unimportable, and for every one Pinocchio builds,
link kinematics and joint torques agree with Pinocchio's at random states to 1e-9:

- example-robot-data (69 files: Panda, UR, TIAGo, Talos, iCub, Go2, G1, ANYmal, Baxter, PR2 ...);
- pybullet_data, shipped with pybullet (1095 files: KUKA iiwa, Franka Panda, xArm, Husky, Minitaur,
  Laikago, A1, Aliengo, R2D2, and a thousand generated objects).

Pinocchio reads the file itself (urdfdom), with mimic joints as independent joints (its default):
a mimic joint of ours is given its leader's state times the multiplier, and its torque is added to
its leader's times the multiplier, as the README states. Centres of mass are checked through the
joint torques (every link's mass and centre of mass enter them) and by the rigid-body identity on
Pinocchio's link motion.
"""

from __future__ import annotations

import importlib.metadata
import importlib.util
import sys
from pathlib import Path

import numpy as np
import pytest

from neforward_ros import ModelError, forward_recursion, inverse_dynamics, load_model

from conftest import assert_close

pin = pytest.importorskip("pinocchio", reason="pip install pin (Pinocchio, the test oracle; a test extra)")


def example_robot_data() -> list[Path]:
    try:
        files = importlib.metadata.files("example-robot-data") or []
    except importlib.metadata.PackageNotFoundError:
        return []
    return sorted(Path(str(f.locate())) for f in files if str(f).endswith(".urdf"))


def pybullet_data() -> list[Path]:
    spec = importlib.util.find_spec("pybullet_data")
    if spec is None or not spec.submodule_search_locations:
        return []
    return sorted(Path(next(iter(spec.submodule_search_locations))).rglob("*.urdf"))


CORPORA = {
    "example-robot-data": (example_robot_data, "pip install example-robot-data (a test extra)", 60),
    "pybullet_data": (pybullet_data, "pip install pybullet (a test extra: its pybullet_data)", 1000),
}
GRAVITY = np.array([0.0, 0.0, -9.81])
STATES = 2
TOLERANCE = 1e-9


@pytest.fixture
def without_xacro(monkeypatch):
    """`import xacro` fails, as in a plain install of the package (the test extras install xacro)."""
    monkeypatch.setitem(sys.modules, "xacro", None)


def pinocchio_model(text: str):
    try:
        return pin.buildModelFromXML(text)
    except (RuntimeError, ValueError):
        return None


class Mapping:
    """Our joint columns and mimic joints -> Pinocchio's configuration, velocity and acceleration."""

    def __init__(self, model, pmodel) -> None:
        self.model, self.pmodel = model, pmodel
        self.entries = []  # (pinocchio joint, our column, multiplier, offset)
        for joint in model.parent_joints:
            if joint is None or joint.q_index < 0:
                continue
            self.entries.append(
                (pmodel.joints[pmodel.getJointId(joint.name)], joint.q_index, joint.multiplier, joint.offset)
            )

    def vectors(self, q, qd, qdd):
        qp, vp, ap = pin.neutral(self.pmodel), np.zeros(self.pmodel.nv), np.zeros(self.pmodel.nv)
        for joint, column, m, o in self.entries:
            angle = m * q[column] + o
            if joint.nq == 2:  # continuous: (cos, sin)
                qp[joint.idx_q : joint.idx_q + 2] = np.cos(angle), np.sin(angle)
            else:
                qp[joint.idx_q] = angle
            vp[joint.idx_v], ap[joint.idx_v] = m * qd[column], m * qdd[column]
        return qp, vp, ap

    def torques(self, tau):
        ours = np.zeros(len(self.model.joint_names))
        for joint, column, m, _ in self.entries:
            ours[column] += m * tau[joint.idx_v]
        return ours


def check_against_pinocchio(model, pmodel, seed: int) -> None:
    data = pmodel.createData()
    mapping = Mapping(model, pmodel)
    rng = np.random.default_rng(seed)
    n = len(model.joint_names)
    states = [rng.uniform(-1.0, 1.0, (STATES, n)), rng.normal(0.0, 1.0, (STATES, n)), rng.normal(0.0, 2.0, (STATES, n))]
    frames = [pmodel.getFrameId(link, pin.FrameType.BODY) for link in model.link_names]
    root = frames[0]
    batch = forward_recursion(model, *states, gravity=GRAVITY)  # the root frame is Pinocchio's world here
    torques = inverse_dynamics(model, *states, gravity=GRAVITY).joint_torque
    local = pin.ReferenceFrame.LOCAL
    for k in range(STATES):
        q, qd, qdd = (s[k] for s in states)
        single = forward_recursion(model, q, qd, qdd, gravity=GRAVITY)
        qp, vp, ap = mapping.vectors(q, qd, qdd)
        pin.forwardKinematics(pmodel, data, qp, vp, ap)
        pin.updateFramePlacements(pmodel, data)
        root_pose = data.oMf[root]
        for i, (link, frame) in enumerate(zip(model.link_names, frames, strict=True)):
            pose = root_pose.actInv(data.oMf[frame])
            rotation = data.oMf[frame].rotation
            velocity = pin.getFrameVelocity(pmodel, data, frame, local)
            accel = pin.getFrameClassicalAcceleration(pmodel, data, frame, local)
            minus_g = -rotation.T @ GRAVITY
            r = np.asarray(model.com_in_link[i])
            w, al, a = velocity.angular, accel.angular, accel.linear + minus_g
            expected = {
                "omega": w, "alpha": al, "velocity": velocity.linear, "accel": a,
                "com_accel": a + np.cross(al, r) + np.cross(w, np.cross(w, r)),
                "position": pose.translation, "rotation": pose.rotation,
            }  # fmt: skip
            for name, value in expected.items():
                for result, where in ((single, ()), (batch, (k,))):
                    assert_close(getattr(result, name)[(*where, i)], value, TOLERANCE, f"{model.name} {link} {name}")
        tau = mapping.torques(pin.rnea(pmodel, data, qp, vp, ap))
        assert_close(torques[k], tau, TOLERANCE, f"{model.name} joint torques")
        assert_close(inverse_dynamics(model, q, qd, qdd, gravity=GRAVITY).joint_torque, tau, TOLERANCE, "single")


@pytest.mark.parametrize("corpus", sorted(CORPORA))
def test_every_published_urdf_loads_from_file_and_text_without_xacro_and_agrees_with_pinocchio(
    corpus: str, without_xacro, capsys
) -> None:
    find, install, least = CORPORA[corpus]
    files = find()
    if not files:
        pytest.skip(f"{corpus} is not installed: {install}")
    built = agreed = 0
    refused = []
    quiet = lambda level, message: None  # noqa: E731  (the models' warnings are tested elsewhere)
    for number, path in enumerate(files):
        text = path.read_text(errors="replace")
        pmodel = pinocchio_model(text)
        try:
            from_file = load_model(path, log=quiet)
            from_text = load_model(text, log=quiet)
        except ModelError as exc:
            assert pmodel is None, f"{path.name}: Pinocchio builds it, load_model refuses it: {exc}"
            refused.append(f"{path.name} ({exc})")
            continue
        assert from_file == from_text, path.name
        if pmodel is None:
            continue
        built += 1
        check_against_pinocchio(from_file, pmodel, seed=number)
        agreed += 1
    with capsys.disabled():
        print(
            f"\n{corpus}: {agreed} of {built} URDFs that Pinocchio builds load (file and text, no xacro) and agree "
            f"with it to {TOLERANCE:g}; {len(files)} files in all; refused, as Pinocchio refuses them: "
            f"{'; '.join(refused[:5]) or 'none'}{' ...' if len(refused) > 5 else ''}"
        )
    assert agreed == built and built >= least
