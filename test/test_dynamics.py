"""inverse_dynamics against Pinocchio (rnea, and data.f for the wrench through every joint) on every
test robot, single and batched, with and without external wrenches; against M(q) qdd + C(q, qd) qd
+ g(q) from Pinocchio's crba, Coriolis matrix and generalized gravity; against the power balance
along a trajectory; and the inertia checks of the model."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from neforward_ros import InputError, forward_recursion, inverse_dynamics, load_model

from conftest import TEST_ROBOTS, URDF_DIR, assert_close
from oracle import GRAVITY, PinocchioOracle, pin

REL = 1e-9


def random_states(n: int, count: int, seed: int):
    rng = np.random.default_rng(seed)
    return tuple(rng.uniform(low, high, (count, n)) for low, high in ((-2, 2), (-3, 3), (-10, 10)))


def parent_joint_names(model) -> list[str | None]:
    return [None if joint is None else joint.name for joint in model.parent_joints]


def expected(oracle: PinocchioOracle, model, ids, q, qd, qdd, fext=None):
    """Pinocchio's torques in our column order, and its per-link wrenches (root: the base reaction)."""
    qp, vp, ap = oracle.pin_vectors(model.joint_names, q, qd, qdd)
    tau, force, moment = oracle.rnea_fill(ids, qp, vp, ap, fext)
    torque = np.array([tau[iv] for _, _, iv in oracle.joint_layout(model.joint_names)])
    # The root: what the world applies to it = its own inertial wrench + what it passes to its children.
    base = oracle.model.inertias[0] * oracle.data.a_gf[0]
    for j in range(1, oracle.model.njoints):
        if oracle.model.parents[j] == 0:
            base += oracle.data.liMi[j].act(oracle.data.f[j])
    if fext is not None:
        base -= fext[0]
    force[0], moment[0] = base.linear, base.angular
    return torque, force, moment


def test_torques_and_joint_wrenches_match_pinocchio(robot_path: Path) -> None:
    model = load_model(robot_path)
    oracle = PinocchioOracle(robot_path, unfix=True)
    ids = oracle.link_joints(parent_joint_names(model))
    q, qd, qdd = random_states(len(model.joint_names), 12, seed=len(model.link_names))
    batch = inverse_dynamics(model, q, qd, qdd, gravity=GRAVITY)
    for t in range(len(q)):
        torque, force, moment = expected(oracle, model, ids, q[t], qd[t], qdd[t])
        single = inverse_dynamics(model, q[t], qd[t], qdd[t], gravity=GRAVITY)
        reused = inverse_dynamics(model, q[t], qd[t], qdd[t], kinematics=forward_recursion(model, q[t], qd[t], qdd[t]))
        for label, ours in (("single", single), ("reused kinematics", reused)):
            assert_close(ours.joint_torque, torque, REL, f"{robot_path.name} {t} {label} torque")
            assert_close(ours.force, force, REL, f"{robot_path.name} {t} {label} force")
            assert_close(ours.moment, moment, REL, f"{robot_path.name} {t} {label} moment")
        assert_close(batch.joint_torque[t], torque, REL, f"{robot_path.name} {t} batch torque")
        assert_close(batch.force[t], force, REL, f"{robot_path.name} {t} batch force")
        assert_close(batch.moment[t], moment, REL, f"{robot_path.name} {t} batch moment")
    reused_batch = inverse_dynamics(model, q, qd, qdd, kinematics=forward_recursion(model, q, qd, qdd))
    assert_close(reused_batch.joint_torque, batch.joint_torque, REL, "batch from kinematics")


def test_external_wrenches_match_pinocchio_fext(robot_path: Path) -> None:
    model = load_model(robot_path)
    oracle = PinocchioOracle(robot_path, unfix=True)
    ids = oracle.link_joints(parent_joint_names(model))
    q, qd, qdd = random_states(len(model.joint_names), 4, seed=2)
    rng = np.random.default_rng(8)
    wrenches = rng.uniform(-20, 20, (4, len(model.link_names), 6))
    batch = inverse_dynamics(model, q, qd, qdd, external_wrenches=wrenches)
    for t in range(len(q)):
        fext = [pin.Force.Zero() for _ in range(oracle.model.njoints)]
        for link, joint in enumerate(ids):
            fext[joint] = fext[joint] + pin.Force(wrenches[t, link, :3], wrenches[t, link, 3:])
        torque, force, moment = expected(oracle, model, ids, q[t], qd[t], qdd[t], fext)
        single = inverse_dynamics(model, q[t], qd[t], qdd[t], external_wrenches=wrenches[t])
        for ours in (single, batch):
            index = () if ours is single else (t,)
            assert_close(ours.joint_torque[index], torque, REL, f"{robot_path.name} {t} torque")
            assert_close(ours.force[index], force, REL, f"{robot_path.name} {t} force")
            assert_close(ours.moment[index], moment, REL, f"{robot_path.name} {t} moment")


def test_torques_equal_mass_matrix_coriolis_and_gravity_from_pinocchio(robot_path: Path) -> None:
    """tau = S^T (M(q) S qdd + C(q, qd) S qd + g(q)): crba, computeCoriolisMatrix and
    computeGeneralizedGravity on Pinocchio's model with every joint independent (none of them the
    recursive Newton-Euler algorithm), S mapping our columns to all joints (a mimic joint follows its
    leader: its rate is the multiplier times the leader's)."""
    model = load_model(robot_path)
    oracle = PinocchioOracle(robot_path, mimic=False)
    nv = oracle.model.nv
    selection = np.zeros((nv, len(model.joint_names)))
    offsets = {}
    for joint in model.parent_joints:
        if joint is None or joint.q_index < 0:
            continue
        idx_v = oracle.model.joints[oracle.model.getJointId(joint.name)].idx_v
        selection[idx_v, joint.q_index] = joint.multiplier
        offsets[joint.name] = (joint.q_index, joint.multiplier, joint.offset)
    q, qd, qdd = random_states(len(model.joint_names), 5, seed=5)
    ours = inverse_dynamics(model, q, qd, qdd, gravity=GRAVITY)
    for t in range(len(q)):
        names = list(offsets)
        full_q = np.array([m * q[t][k] + c for k, m, c in offsets.values()])
        qp, _, _ = oracle.pin_vectors(names, full_q, np.zeros(len(names)), np.zeros(len(names)))
        vp, ap = selection @ qd[t], selection @ qdd[t]
        mass = pin.crba(oracle.model, oracle.data, qp)
        mass = np.triu(mass) + np.triu(mass, 1).T
        coriolis = pin.computeCoriolisMatrix(oracle.model, oracle.data, qp, vp)
        gravity = pin.computeGeneralizedGravity(oracle.model, oracle.data, qp)
        tau = selection.T @ (mass @ ap + coriolis @ vp + gravity)
        assert_close(ours.joint_torque[t], tau, REL, f"{robot_path.name} sample {t}")


def test_power_balance_along_a_trajectory() -> None:
    """tau . qd = d/dt (kinetic energy) - sum_i m_i g . v_ci, with the energy from the forward
    recursion's velocities and its derivative by finite differences."""
    path = TEST_ROBOTS["inertias"]
    model = load_model(path)
    n = len(model.joint_names)
    k = np.arange(n)
    w, amplitude = 2 * np.pi * (0.4 + 0.2 * k), np.where(k == 1, 0.05, 0.8)

    def state(t):
        arg = np.outer(t, w) + k
        return amplitude * np.sin(arg), amplitude * w * np.cos(arg), -amplitude * w**2 * np.sin(arg)

    def energy(t):
        kin = forward_recursion(model, *state(t)).in_root()
        inertia = np.einsum(
            "tkij,kjl,tkml->tkim", kin.rotation, np.reshape(model.inertia_in_link, (-1, 3, 3)), kin.rotation
        )
        mass = np.asarray(model.mass)
        spin = np.einsum("tki,tkij,tkj->t", kin.omega, inertia, kin.omega)
        return 0.5 * (np.einsum("k,tki,tki->t", mass, kin.com_velocity, kin.com_velocity) + spin), kin, mass

    t = np.linspace(0.1, 2.0, 40)
    h = 1e-4
    rate = (-energy(t + 2 * h)[0] + 8 * energy(t + h)[0] - 8 * energy(t - h)[0] + energy(t - 2 * h)[0]) / (12 * h)
    _, kin, mass = energy(t)
    gravity_power = np.einsum("k,tki,i->t", mass, kin.com_velocity, np.array(GRAVITY))
    q, qd, qdd = state(t)
    power = np.einsum("tj,tj->t", inverse_dynamics(model, q, qd, qdd, gravity=GRAVITY).joint_torque, qd)
    assert_close(power, rate - gravity_power, 1e-7, "power")


def test_inputs_are_checked() -> None:
    model = load_model(TEST_ROBOTS["planar_2r"])
    with pytest.raises(InputError, match="qd has shape"):
        inverse_dynamics(model, [0.0, 0.0], [0.0], [0.0, 0.0])
    with pytest.raises(InputError, match="non-finite"):
        inverse_dynamics(model, [0.0, np.nan], [0.0, 0.0], [0.0, 0.0])
    with pytest.raises(InputError, match="external_wrenches has shape"):
        inverse_dynamics(model, [0.0, 0.0], [0.0, 0.0], [0.0, 0.0], external_wrenches=np.zeros((2, 6)))
    with pytest.raises(InputError, match="in link frames"):
        kin = forward_recursion(model, [0.0, 0.0], [0.0, 0.0], [0.0, 0.0]).in_root()
        inverse_dynamics(model, [0.0, 0.0], [0.0, 0.0], [0.0, 0.0], kinematics=kin)


def test_model_reads_masses_and_inertias_rotated_into_the_link_frame() -> None:
    model = load_model(URDF_DIR / "inertias.urdf")
    from scipy.spatial.transform import Rotation

    upper = model.link_index["upper"]
    rotation = Rotation.from_euler("xyz", [-0.546, 0.109, -0.872]).as_matrix()  # URDF rpy: fixed axes x, y, z
    raw = np.array(
        [[0.0152089, 0.00329188, 0.000827773], [0.00329188, 0.0198304, 0.00320515], [0.000827773, 0.00320515, 0.018975]]
    )
    assert model.mass[upper] == 1.2
    np.testing.assert_allclose(
        np.reshape(model.inertia_in_link[upper], (3, 3)), rotation @ raw @ rotation.T, atol=1e-15
    )
    tool = model.link_index["tool_frame"]
    assert model.mass[tool] == 0.0 and model.inertia_in_link[tool] == (0.0,) * 9  # no <inertial>: massless


def _one_link(mass: str, inertia: str) -> str:
    return (
        f'<robot name="r"><link name="a"/><link name="b"><inertial><mass value="{mass}"/><inertia {inertia}/>'
        '</inertial></link><joint name="j" type="revolute"><parent link="a"/><child link="b"/><axis xyz="0 0 1"/>'
        '<limit lower="-1" upper="1" effort="1" velocity="1"/></joint></robot>'
    )


@pytest.mark.parametrize("mass, inertia, kept_mass", [
    ("nan", 'ixx="1" ixy="0" ixz="0" iyy="1" iyz="0" izz="1"', 0.0),
    ("1", 'ixx="inf" ixy="0" ixz="0" iyy="1" iyz="0" izz="1"', 1.0),
])  # fmt: skip
def test_a_mass_or_inertia_that_is_not_a_number_keeps_what_urdfdom_keeps_with_a_warning_naming_the_link(
    mass: str, inertia: str, kept_mass: float
) -> None:
    """urdfdom's conversion refuses nan and inf, and it ignores the failure of the link: a mass that
    is not a number leaves the link massless, an inertia that is not one leaves it without rotational
    inertia (test_corpus checks these readings against Pinocchio)."""
    model = load_model(_one_link(mass, inertia))
    b = model.link_index["b"]
    assert model.mass[b] == kept_mass and model.inertia_in_link[b] == (0.0,) * 9
    assert len(model.inertia_warnings) == 1
    assert re.search(r"link 'b' .* not a finite number", model.inertia_warnings[0]), model.inertia_warnings


@pytest.mark.parametrize("mass, inertia, text", [
    ("-1", 'ixx="1" ixy="0" ixz="0" iyy="1" iyz="0" izz="1"', "a negative mass (-1 kg)"),
    ("1", 'ixx="1" ixy="0" ixz="0" iyy="-1" iyz="0" izz="1"', "a negative principal moment"),
    ("1", 'ixx="1" ixy="2" ixz="0" iyy="1" iyz="0" izz="1"', "a negative principal moment"),
])  # fmt: skip
def test_impossible_masses_and_inertias_are_used_as_given_with_a_warning_naming_the_link(mass, inertia, text) -> None:
    """As Pinocchio uses them: it builds such files, and so the torques agree with its rnea."""
    model = load_model(_one_link(mass, inertia))
    assert len(model.inertia_warnings) == 1 and text in model.inertia_warnings[0]
    assert model.inertia_warnings[0].startswith("link 'b'")
    q = [0.3]
    expected = pinocchio_torque(_one_link(mass, inertia), q, [0.5], [-0.7])
    np.testing.assert_allclose(inverse_dynamics(model, q, [0.5], [-0.7]).joint_torque, expected, rtol=1e-12, atol=1e-12)


def test_rounding_noise_in_a_massive_robots_zero_inertia_is_not_a_warning() -> None:
    """iCub's published models (icub-models) write a 0.5 kg link's zero inertia as ixx = iyy =
    -5.42101e-20 and another's as ixz = 2.4e-35: rounding, beside the robot's moments of 1e-3 kg m^2.
    A moment of -1e-5 beside them is no rounding, and still warned."""

    def robot(small: str) -> str:
        return (
            '<robot name="r"><link name="a"/>'
            '<link name="b"><inertial><mass value="5"/><inertia ixx="0.02" ixy="0" ixz="0" iyy="0.03" iyz="0" '
            'izz="0.04"/></inertial></link>'
            f'<link name="c"><inertial><origin xyz="0 0 0.03"/><mass value="0.526"/><inertia {small}/>'
            "</inertial></link>"
            '<joint name="j1" type="revolute"><parent link="a"/><child link="b"/><axis xyz="0 0 1"/>'
            '<limit lower="-1" upper="1" effort="1" velocity="1"/></joint>'
            '<joint name="j2" type="revolute"><parent link="b"/><child link="c"/><origin xyz="0.2 0 0"/>'
            '<axis xyz="0 1 0"/><limit lower="-1" upper="1" effort="1" velocity="1"/></joint></robot>'
        )

    noise = 'ixx="-5.42101e-20" ixy="0" ixz="0" iyy="-5.42101e-20" iyz="0" izz="0"'
    assert load_model(robot(noise)).inertia_warnings == ()
    assert load_model(robot('ixx="0" ixy="0" ixz="2.40741e-35" iyy="0" iyz="0" izz="0"')).inertia_warnings == ()
    wrong = load_model(robot('ixx="-1e-5" ixy="0" ixz="0" iyy="1e-5" iyz="0" izz="1e-5"')).inertia_warnings
    assert len(wrong) == 1 and wrong[0].startswith("link 'c'") and "negative principal moment" in wrong[0]
    q, qd, qdd = [0.3, -0.2], [0.5, 0.4], [-0.7, 1.1]
    expected = pinocchio_torque(robot(noise), q, qd, qdd)
    torque = inverse_dynamics(load_model(robot(noise)), q, qd, qdd).joint_torque
    np.testing.assert_allclose(torque, expected, rtol=1e-12)


def pinocchio_torque(text: str, q, qd, qdd) -> np.ndarray:
    import pinocchio as pin

    pmodel = pin.buildModelFromXML(text)
    return pin.rnea(pmodel, pmodel.createData(), np.array(q, float), np.array(qd, float), np.array(qdd, float))


def test_a_triangle_inequality_violation_is_a_warning_and_the_inertia_is_used_as_given(caplog) -> None:
    """Real URDFs break it by a few percent (Talos's grippers in example-robot-data); Pinocchio and
    KDL use such inertias as given, and so does inverse_dynamics, after a warning."""
    urdf = (
        '<robot name="r"><link name="a"/><link name="b"><inertial><mass value="1"/>'
        '<inertia ixx="0.000115" ixy="0.000052" ixz="0.000025" iyy="0.000153" iyz="0.000034" izz="0.00019"/>'
        '</inertial></link><joint name="j" type="revolute"><parent link="a"/><child link="b"/><axis xyz="0 0 1"/>'
        '<limit lower="-1" upper="1" effort="1" velocity="1"/></joint></robot>'
    )
    model = load_model(urdf)
    assert len(model.inertia_warnings) == 1 and "triangle inequality" in model.inertia_warnings[0]
    with caplog.at_level("WARNING", logger="neforward_ros"):
        inverse_dynamics(model, [0.1], [0.2], [0.3])
        inverse_dynamics(model, [0.1], [0.2], [0.3])
    assert sum("triangle inequality" in r.message for r in caplog.records) == 1  # once per model
