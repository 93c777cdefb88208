"""Published robots, not our fixtures: every URDF of two published corpora loads from the file and
as robot_description text with the xacro package unimportable, and for every one Pinocchio builds,
link kinematics and joint torques agree with Pinocchio's at random states to 1e-9:

- example-robot-data (69 files: Panda, UR, TIAGo, Talos, iCub, Go2, G1, ANYmal, Baxter, PR2 ...);
- pybullet_data, shipped with pybullet (1095 files: KUKA iiwa, Franka Panda, xArm, Husky, Minitaur,
  Laikago, A1, Aliengo, R2D2, and a thousand generated objects);
- icub-models (the iCub humanoids of several labs, 16 files of 32 joints, written by a CAD converter:
  inertias with rounding noise such as -5.42e-20 kg m^2).

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


def package_files(distribution: str) -> list[Path]:
    try:
        files = importlib.metadata.files(distribution) or []
    except importlib.metadata.PackageNotFoundError:
        return []
    return sorted(Path(str(f.locate())) for f in files if str(f).endswith(".urdf"))


def example_robot_data() -> list[Path]:
    return package_files("example-robot-data")


def pybullet_data() -> list[Path]:
    spec = importlib.util.find_spec("pybullet_data")
    if spec is None or not spec.submodule_search_locations:
        return []
    return sorted(Path(next(iter(spec.submodule_search_locations))).rglob("*.urdf"))


CORPORA = {
    "example-robot-data": (
        lambda: package_files("example-robot-data"),
        "pip install example-robot-data (a test extra)",
        60,
    ),
    "icub-models": (lambda: package_files("icub-models"), "pip install icub-models (a test extra)", 10),
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


def yourdfpy_difference(path: Path, model) -> str:
    """How yourdfpy's own ``URDF.load`` would read a file otherwise than urdfdom, or "": it refuses it,
    or a link's <inertial> fails urdfdom's reading (yourdfpy gives a missing ixx, iyy or izz 1 kg m^2)."""
    import logging

    import yourdfpy

    logging.getLogger("yourdfpy").disabled = True  # it logs the first parse's error before recovering
    try:
        yourdfpy.URDF.load(str(path), build_scene_graph=False, load_meshes=False)
    except Exception as exc:  # yourdfpy raises whatever its parse meets
        return f"yourdfpy refuses it: {type(exc).__name__}: {exc}"
    finally:
        logging.getLogger("yourdfpy").disabled = False
    failed = [w.split(":")[0] for w in model.inertia_warnings if "urdfdom" in w]
    return f"<inertial> read as urdfdom reads it: {', '.join(failed)}" if failed else ""


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
    differs = []  # files Pinocchio builds where yourdfpy's own URDF.load reads otherwise than urdfdom
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
        if pmodel is not None:
            difference = yourdfpy_difference(path, from_file)
            if difference:
                differs.append(f"{path.name} ({difference})")
        if pmodel is None:
            continue
        built += 1
        check_against_pinocchio(from_file, pmodel, seed=number)
        agreed += 1
    with capsys.disabled():
        print(
            f"\n{corpus}: {agreed} of {built} URDFs that Pinocchio builds load (file and text, no xacro) and agree "
            f"with it to {TOLERANCE:g}; {len(files)} files in all; refused, as Pinocchio refuses them: "
            f"{'; '.join(refused[:5]) or 'none'}{' ...' if len(refused) > 5 else ''}. Where yourdfpy's URDF.load "
            f"alone reads otherwise than urdfdom, and this package follows urdfdom: {len(differs)} files: "
            f"{'; '.join(differs[:5]) or 'none'}{' ...' if len(differs) > 5 else ''}"
        )
    assert agreed == built and built >= least


def _one_link_robot(link_body: str) -> str:
    """A revolute joint carrying link ``l1`` (with ``link_body``) and a second joint below it, so that
    ``l1``'s mass, centre of mass and inertia all enter the joint torques."""
    return (
        '<robot name="r"><link name="base"/>'
        f'<link name="l1">{link_body}</link>'
        '<link name="l2"><inertial><origin xyz="0 0.1 0"/><mass value="1"/>'
        '<inertia ixx="0.01" ixy="0" ixz="0" iyy="0.02" iyz="0" izz="0.03"/></inertial></link>'
        '<joint name="j1" type="revolute"><parent link="base"/><child link="l1"/><axis xyz="0 1 1"/>'
        '<limit lower="-1" upper="1" effort="1" velocity="1"/></joint>'
        '<joint name="j2" type="revolute"><parent link="l1"/><child link="l2"/><origin xyz="0.3 0 0"/>'
        '<axis xyz="1 0 0"/><limit lower="-1" upper="1" effort="1" velocity="1"/></joint></robot>'
    )


COMPLETE = '<inertia ixx="0.1" ixy="0.01" ixz="0" iyy="0.2" iyz="0" izz="0.3"/>'
FAILING_INERTIALS = {
    # what urdfdom fails on -> (the <inertial>, what the warning says urdfdom keeps)
    "no <inertia>": ('<origin xyz="0.1 0.2 0.3" rpy="0.3 0 0"/><mass value="2.0"/>', "keeps its mass (2 kg)"),
    "products missing": (
        '<origin xyz="0.1 0.2 0.3"/><mass value="2.0"/><inertia ixx="0.1" iyy="0.2" izz="0.3"/>',
        "<inertia> without ixy ixz iyz",
    ),
    "a moment not a number": (
        '<origin xyz="0.1 0.2 0.3"/><mass value="2"/>' + COMPLETE.replace('iyy="0.2"', 'iyy="x"'),
        "not a finite number",
    ),
    "no <mass>": ('<origin xyz="0.1 0.2 0.3"/>' + COMPLETE, "massless"),
    "<mass> without value": ('<origin xyz="0.1 0.2 0.3"/><mass/>' + COMPLETE, "massless"),
    "mass with a unit": ('<mass value="2kg"/>' + COMPLETE, "massless"),
    "mass nan": ('<mass value="nan"/>' + COMPLETE, "massless"),
    "origin of two numbers": ('<origin xyz="0.1 0.2"/><mass value="2"/>' + COMPLETE, "massless"),
}


@pytest.mark.parametrize("case", sorted(FAILING_INERTIALS))
def test_a_link_whose_inertial_fails_loads_as_urdfdom_loads_it(case: str) -> None:
    """urdfdom ignores parseLink's failure: the link stays, with what was read before the failure
    (yourdfpy would give a missing ixx, iyy or izz 1 kg m^2). Pinocchio, which reads with urdfdom,
    is the oracle: link motion and joint torques agree, and the warning says what was kept."""
    inertial, said = FAILING_INERTIALS[case]
    text = _one_link_robot(f"<inertial>{inertial}</inertial>")
    said_here: list[str] = []
    model = load_model(text, log=lambda level, message: said_here.append(message))
    assert model.link_names == ("base", "l1", "l2")
    assert len(model.inertia_warnings) == 1 and said in model.inertia_warnings[0], model.inertia_warnings
    assert "link 'l1'" in model.inertia_warnings[0]
    check_against_pinocchio(model, pin.buildModelFromXML(text), seed=7)


def test_the_complete_inertial_of_the_same_link_agrees_too() -> None:
    """The control for the test above: the full <inertial> is read, with no warning."""
    text = _one_link_robot(f'<inertial><origin xyz="0.1 0.2 0.3" rpy="0.3 0 0"/><mass value="2"/>{COMPLETE}</inertial>')
    model = load_model(text)
    assert model.inertia_warnings == () and model.mass[1] == 2.0
    check_against_pinocchio(model, pin.buildModelFromXML(text), seed=8)


@pytest.mark.parametrize("geometry", ["<capsule radius='0.1' length='0.2'/>", "<plane normal='0 0 1'/>", ""])
def test_a_geometry_urdfdom_cannot_read_does_not_stop_the_model(geometry: str) -> None:
    """yourdfpy refuses a whole file for a <visual> geometry it does not know (pybullet's <capsule>,
    <plane>); urdfdom drops the link's visuals and keeps the link; nothing here reads visuals."""
    inertial = f'<inertial><mass value="2"/>{COMPLETE}</inertial>'
    text = _one_link_robot(f"{inertial}<visual><geometry>{geometry}</geometry></visual>")
    model = load_model(text)
    assert model.mass[1] == 2.0 and model.inertia_warnings == ()
    check_against_pinocchio(model, pin.buildModelFromXML(text), seed=9)


@pytest.mark.parametrize(
    "change, message",
    [
        (('<origin xyz="0.3 0 0"/>', '<origin xyz="0.3 0 0" rpy="0 0 0 1"/>'), "<origin rpy>: '0 0 0 1' is not three"),
        (('<origin xyz="0.3 0 0"/>', '<origin xyz="0.3 0 0 0"/>'), "<origin xyz>: '0.3 0 0 0' is not three"),
        (('upper="1" effort', 'upper="1." effort'), None),  # urdfdom reads "1." as 1, as Python does
        (('upper="1" effort', 'upper="1.5." effort'), "could not convert string to float: '1.5.'"),
    ],
)
def test_what_yourdfpy_reads_leniently_urdfdom_refuses_and_so_does_load_model(change, message) -> None:
    """yourdfpy cuts a four-number rpy to three and a four-number xyz to three; urdfdom refuses both,
    and a limit that is not a number."""
    text = _one_link_robot(f'<inertial><mass value="2"/>{COMPLETE}</inertial>').replace(*change, 1)
    pmodel = pinocchio_model(text)
    if message is None:
        assert pmodel is not None
        check_against_pinocchio(load_model(text), pmodel, seed=10)
        return
    assert pmodel is None
    with pytest.raises(ModelError, match=r"joint .j[12]. \(line 1\)") as info:
        load_model(text)
    assert message in str(info.value)


@pytest.mark.parametrize(
    "document",
    [
        '<robot name="r"><link name="a"/><link name="b"></robot>',  # mismatched tags
        '<robot name="r"><link name="a"/><link name="b',  # truncated, as a half-received description
        '<robot name="r"><link name="a" name="b"/></robot>',
    ],
)
def test_a_broken_document_is_refused_though_lxml_could_recover_part_of_it(document: str) -> None:
    """libxml2's recovery, which yourdfpy falls back on, would load the part before the break: a
    truncated robot_description would be a smaller robot. TinyXML2 (urdfdom) refuses these."""
    assert pinocchio_model(document) is None
    with pytest.raises(ModelError, match=r"malformed URDF XML: .* at line 1"):
        load_model(document)


def test_what_tinyxml2_tolerates_loads() -> None:
    """An undeclared prefix, -- in a comment and a bare & load, as urdfdom loads them."""
    text = _one_link_robot(f'<inertial><mass value="2"/>{COMPLETE}</inertial>')
    text = text.replace('<link name="base"/>', '<!-- ---- base -- --><link name="base" gazebo:x="a & b"/><gz:plugin/>')
    pmodel = pinocchio_model(text)
    assert pmodel is not None
    check_against_pinocchio(load_model(text), pmodel, seed=11)
