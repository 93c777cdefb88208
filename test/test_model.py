"""load_model: tree order, joint columns, mimic joints, sources, and every error path."""

from __future__ import annotations

import dataclasses
import importlib.util
import logging
import sys

import numpy as np
import pytest

from neforward_ros import InputError, ModelError, NeforwardError, forward_recursion, load_model

from conftest import CONFIG_DIR, TEST_ROBOTS


def urdf(body: str, name: str = "r") -> str:
    return f'<?xml version="1.0"?>\n<robot name="{name}">\n{body}\n</robot>'


def revolute(name: str, parent: str, child: str, extra: str = "") -> str:
    return (
        f'<joint name="{name}" type="revolute"><parent link="{parent}"/><child link="{child}"/>'
        f'<axis xyz="0 0 1"/><limit lower="-1" upper="1" effort="1" velocity="1"/>{extra}</joint>'
    )


CHAIN = urdf('<link name="a"/><link name="b"/><link name="c"/>' + revolute("j1", "a", "b") + revolute("j2", "b", "c"))


def test_panda_layout() -> None:
    model = load_model(TEST_ROBOTS["panda"])
    assert model.root_link == "panda_link0"
    assert len(model.link_names) == 13
    assert model.joint_names == (*tuple(f"panda_joint{i}" for i in range(1, 8)), "panda_finger_joint1")
    assert model.mimic_joint_names == ("panda_finger_joint2",)
    assert model.link_index["panda_tcp"] == model.link_names.index("panda_tcp")
    assert model.joint_index["panda_finger_joint1"] == 7


def test_links_parent_before_children_and_joint_columns_in_urdf_order() -> None:
    model = load_model(TEST_ROBOTS["tree"])
    assert model.link_names[0] == "pelvis"
    for k, joint in enumerate(model.parent_joints[1:], start=1):
        assert joint.parent_index < k
    assert model.joint_names == ("waist", "neck", "l_shoulder", "l_elbow", "r_shoulder", "r_elbow")


def test_com_from_inertial_origin_and_origin_without_inertial() -> None:
    model = load_model(TEST_ROBOTS["planar_2r"])
    assert model.com_in_link[model.link_index["link1"]] == (0.25, 0.0, 0.0)
    assert model.com_in_link[model.link_index["tip"]] == (0.0, 0.0, 0.0)


def test_model_is_immutable() -> None:
    model = load_model(TEST_ROBOTS["planar_2r"])
    with pytest.raises(dataclasses.FrozenInstanceError):
        model.link_names = ()  # type: ignore[misc]
    with pytest.raises(TypeError):
        model.link_index["x"] = 3  # type: ignore[index]


def test_xml_string_equals_file_and_pathlike() -> None:
    path = TEST_ROBOTS["arm_6r"]
    from_path = load_model(path)
    from_str_path = load_model(str(path))
    from_xml = load_model(path.read_text())
    q = np.linspace(-1, 1, len(from_path.joint_names))
    for other in (from_str_path, from_xml):
        assert other.link_names == from_path.link_names
        np.testing.assert_array_equal(
            forward_recursion(other, q, q, q).accel, forward_recursion(from_path, q, q, q).accel
        )


def test_unresolvable_meshes_do_not_matter() -> None:
    body = (
        '<link name="a"><visual><geometry><mesh filename="package://nowhere/meshes/a.dae"/></geometry></visual>'
        '<collision><geometry><mesh filename="package://nowhere/meshes/a.stl"/></geometry></collision></link>'
        '<link name="b"><visual><geometry><mesh filename="file:///no/such/file.stl"/></geometry></visual></link>'
        + revolute("j", "a", "b")
    )
    model = load_model(urdf(body))
    assert model.link_names == ("a", "b")


def test_chosen_root_link_uses_its_subtree() -> None:
    model = load_model(CHAIN, root_link="b")
    assert model.link_names == ("b", "c")
    assert model.joint_names == ("j2",)


def test_mimic_chain_composes_multiplier_and_offset() -> None:
    body = (
        '<link name="a"/><link name="b"/><link name="c"/><link name="d"/>'
        + revolute("lead", "a", "b")
        + revolute("f1", "a", "c", '<mimic joint="lead" multiplier="2" offset="0.1"/>')
        + revolute("f2", "a", "d", '<mimic joint="f1" multiplier="-0.5" offset="0.3"/>')
    )
    model = load_model(urdf(body))
    assert model.joint_names == ("lead",)
    f2 = model.parent_joints[model.link_index["d"]]
    # f2 = -0.5 * (2 lead + 0.1) + 0.3 = -lead + 0.25
    assert (f2.mimic_of, f2.multiplier, f2.offset) == ("lead", -1.0, pytest.approx(0.25))


def test_axis_is_normalised() -> None:
    body = (
        '<link name="a"/><link name="b"/><joint name="j" type="continuous"><parent link="a"/>'
        '<child link="b"/><axis xyz="0 0 2"/></joint>'
    )
    assert load_model(urdf(body)).parent_joints[1].axis == (0.0, 0.0, 1.0)


@pytest.mark.parametrize("source, message", [
    ("/no/such/robot.urdf", "cannot read URDF file"),
    ("", "URDF source is empty"),
    ("<robot name='x'><link name='a'></robot>", "malformed URDF XML"),
    ("<sdf version='1.6'/>", "expected <robot>"),
    (urdf(""), "no links"),
    (urdf('<link name="a"/><link name="a"/>'), "link 'a' is defined twice"),
    (urdf('<link name="a"/><link name="b"/>' + revolute("j", "a", "nope")),
     "joint 'j' names child link 'nope', which is not defined"),
    (urdf('<link name="a"/><link name="b"/><joint name="j" type="revolute"><child link="b"/></joint>'),
     "joint 'j' (line 3) names no parent link"),
    (urdf('<link name="a"/><link name="b"/><joint name="j"><parent link="a"/><child link="b"/></joint>'),
     "joint 'j' (line 3) has no type"),
    (urdf('<link name="a"/><link name="b"/>'
          + revolute("j", "a", "b").replace('<axis xyz="0 0 1"/>', '<origin xyz="0 1"/>')),
     "joint 'j' (line 3) <origin xyz>: '0 1' is not three numbers"),
    (urdf('<link name="a"/><link name="b"/>' + revolute("j", "a", "b").replace('"0 0 1"', '"0 0 one"')),
     "<axis xyz>: 'one' is not a number"),
    (urdf('<link name="a"/><link name="b"/>' + revolute("j", "a", "b").replace('"0 0 1"', '"0 0 nan"')),
     "'nan' is not a finite number"),
    (urdf('<link/>'), "a <link> without a name at line 3"),
    (urdf('<link name="a"/><link name="b"/><link name="c"/>' + revolute("j1", "a", "c")
          + revolute("j2", "b", "c")), "link 'c' is the child of two joints, 'j1' and 'j2'"),
    (urdf('<link name="a"/><link name="b"/><link name="c"/>' + revolute("j1", "a", "b")),
     "several root links (a, c)"),
    (urdf('<link name="r"/><link name="a"/><link name="b"/>' + revolute("j0", "r", "a") + revolute("j1", "a", "b")
          + revolute("j2", "b", "a")), "child of two joints"),
    (urdf('<link name="a"/><link name="b"/>' + revolute("j1", "a", "b") + revolute("j2", "b", "a")),
     "cycle through links"),
    (urdf('<link name="a"/><link name="b"/><joint name="w" type="wobbly"><parent link="a"/><child link="b"/></joint>'),
     "unknown type 'wobbly'"),
    (urdf('<link name="a"/><link name="b"/><joint name="z" type="revolute"><parent link="a"/><child link="b"/>'
          '<axis xyz="0 0 0"/></joint>'), "joint 'z' is revolute with a zero axis"),
    (urdf('<link name="a"/>') + "<robot/>", "Extra content at the end of the document at line 4"),
])  # fmt: skip
def test_bad_urdf_raises_model_error_naming_the_problem(source: str, message: str) -> None:
    with pytest.raises(ModelError) as info:
        load_model(source)
    assert message in str(info.value)
    assert isinstance(info.value, NeforwardError) and isinstance(info.value, ValueError)


def test_a_floating_joint_below_a_world_link_is_the_base() -> None:
    model = load_model(
        urdf(
            '<link name="world"/><link name="base"/><link name="leg"/><joint name="free" type="floating">'
            '<parent link="world"/><child link="base"/></joint>' + revolute("hip", "base", "leg")
        )
    )
    assert model.root_link == "base" and model.floating_base == "free"
    assert model.link_names == ("base", "leg") and model.joint_names == ("hip",)
    assert load_model(CHAIN).floating_base is None


def test_unknown_root_link() -> None:
    with pytest.raises(ModelError, match="root_link 'nope' is not a link"):
        load_model(CHAIN, root_link="nope")


@pytest.mark.parametrize("extra, independent, why", [
    ('<mimic joint="ghost"/>', "j1", "which is not a joint of the URDF"),
    ('<mimic joint="f"/>', "j1", "which is fixed"),
    ('<mimic joint="j2"/>', "j2", "cycle of mimic joints (j1 -> j2 -> j1)"),  # broken where it closes
])  # fmt: skip
def test_a_mimic_joint_without_a_movable_leader_is_independent_with_a_warning(extra, independent, why) -> None:
    """As Pinocchio reads it by default (urdfdom reads the file; alex_psyonic_hands in example-robot-data)."""
    body = (
        '<link name="a"/><link name="b"/><link name="c"/><link name="d"/>'
        '<joint name="f" type="fixed"><parent link="a"/><child link="d"/></joint>'
        + revolute("j1", "a", "b", extra)
        + revolute("j2", "a", "c", '<mimic joint="j1" multiplier="2"/>')
    )
    said = []
    model = load_model(urdf(body), log=lambda level, message: said.append((level, message)))
    assert model.joint_names == (independent,)
    follower = "j2" if independent == "j1" else "j1"
    assert model.parent_joints[model.link_index["c" if follower == "j2" else "b"]].mimic_of == independent
    assert len(model.warnings) == 1 and f"mimic joint {independent!r}" in model.warnings[0] and why in model.warnings[0]
    assert said == [(logging.WARNING, model.warnings[0])]


def test_a_mimic_leader_above_root_link_makes_the_follower_independent() -> None:
    body = (
        '<link name="a"/><link name="b"/><link name="c"/>'
        + revolute("j1", "a", "b")
        + revolute("j2", "b", "c", '<mimic joint="j1"/>')
    )
    model = load_model(urdf(body), root_link="b", log=lambda *_: None)
    assert model.joint_names == ("j2",) and "which is not below root_link" in model.warnings[0]


@pytest.mark.parametrize("kind", ["floating", "planar"])
def test_a_floating_or_planar_joint_below_the_root_is_fixed_with_a_warning(kind: str) -> None:
    """As KDL (robot_state_publisher) takes it; Pinocchio at its neutral configuration agrees."""
    body = (
        '<link name="a"/><link name="b"/><link name="c"/>'
        + revolute("j", "a", "b")
        + f'<joint name="odd" type="{kind}"><parent link="b"/><child link="c"/><origin xyz="0 0 0.5"/>'
        '<axis xyz="0 0 1"/></joint>'
    )
    model = load_model(urdf(body), log=lambda *_: None)
    assert model.joint_names == ("j",) and model.link_names == ("a", "b", "c")
    assert model.parent_joints[2].kind.value == "fixed" and model.parent_joints[2].origin_xyz == (0.0, 0.0, 0.5)
    assert len(model.warnings) == 1 and f"joint 'odd' is {kind}" in model.warnings[0]


def test_non_string_source() -> None:
    with pytest.raises(ModelError, match="must be a path or an XML string"):
        load_model(42)  # type: ignore[arg-type]


@pytest.mark.parametrize("q, qd, qdd, message", [
    ([0.0], [0.0, 0.0], [0.0, 0.0], r"q has shape \(1,\); expected \(2,\) or \(T, 2\)"),
    ([0.0, 0.0], [0.0, 0.0], [[0.0, 0.0]], "must have the same shape"),
    (np.zeros((2, 2, 2)), np.zeros((2, 2, 2)), np.zeros((2, 2, 2)), "q has shape"),
    ([0.0, 0.0], [0.0, float("nan")], [0.0, 0.0], "qd has a non-finite value \\(nan\\) at joint 'j2'"),
    (np.zeros((3, 2)), np.zeros((3, 2)), [[0, 0], [0, 0], [float("inf"), 0]],
     "qdd has a non-finite value \\(inf\\) at sample 2, joint 'j1'"),
    (["a", "b"], [0.0, 0.0], [0.0, 0.0], "q is not an array of numbers"),
])  # fmt: skip
def test_bad_joint_arrays_raise_input_error(q, qd, qdd, message: str) -> None:
    model = load_model(CHAIN)
    with pytest.raises(InputError, match=message):
        forward_recursion(model, q, qd, qdd)


@pytest.mark.parametrize("gravity", [(0.0, 0.0), (0.0, float("nan"), -9.81), "down"])
def test_bad_gravity_raises_input_error(gravity) -> None:
    model = load_model(CHAIN)
    with pytest.raises(InputError, match="gravity"):
        forward_recursion(model, [0.0, 0.0], [0.0, 0.0], [0.0, 0.0], gravity=gravity)


def test_continuous_columns_mark_the_wrapping_joints() -> None:
    xml = (
        "<robot name='c'><link name='a'/><link name='b'/><link name='c'/><link name='d'/>"
        "<joint name='r' type='revolute'><parent link='a'/><child link='b'/><axis xyz='0 0 1'/>"
        "<limit lower='-1' upper='1' effort='1' velocity='1'/></joint>"
        "<joint name='w' type='continuous'><parent link='b'/><child link='c'/><axis xyz='1 0 0'/></joint>"
        "<joint name='m' type='continuous'><parent link='c'/><child link='d'/><axis xyz='1 0 0'/>"
        "<mimic joint='w'/></joint></robot>"
    )
    model = load_model(xml)
    assert model.joint_names == ("r", "w") and model.continuous_columns == (False, True)


def test_importing_the_package_imports_no_urdf_library_and_loading_a_model_imports_yourdfpy() -> None:
    """yourdfpy (with trimesh, about a second) is imported when a URDF is first read, not before:
    commands that read no URDF do not pay for it."""
    import os
    import subprocess

    code = (
        "import sys; from neforward_ros import load_model; import neforward_ros.cli; "
        "names = ('yourdfpy', 'trimesh', 'lxml'); before = [m for m in names if m in sys.modules]; "
        f"load_model({str(TEST_ROBOTS['panda'])!r}); "
        "print(before, sorted(m for m in names if m in sys.modules))"
    )
    run = subprocess.run(
        [sys.executable, "-c", code],
        env={**os.environ, "NEFORWARD_CACHE": "off"},
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert run.stdout.strip() == "[] ['lxml', 'trimesh', 'yourdfpy']", run.stderr


def test_a_urdf_without_a_robot_name_loads_as_urdfdom_and_pinocchio_load_it() -> None:
    """example-robot-data's ur3.urdf has no name attribute on <robot>."""
    text = (CONFIG_DIR / "panda.urdf").read_text().replace('<robot name="panda"', "<robot", 1)
    assert '<robot name="panda"' not in text
    model = load_model(text)
    assert model.name == "robot" and len(model.link_names) == 13


def test_xacro_files_are_expanded_or_refused_with_a_hint(tmp_path) -> None:
    source = (
        '<robot name="x" xmlns:xacro="http://www.ros.org/wiki/xacro"><xacro:property name="L" value="0.5"/>'
        '<link name="a"/><link name="b"/><joint name="j" type="revolute"><parent link="a"/><child link="b"/>'
        '<origin xyz="0 0 ${L}"/><axis xyz="0 0 1"/><limit lower="0" upper="1" effort="1" velocity="1"/>'
        "</joint></robot>"
    )
    path = tmp_path / "arm.urdf.xacro"
    path.write_text(source)
    if importlib.util.find_spec("xacro") is not None:
        model = load_model(path)
        assert model.parent_joints[1].origin_xyz[2] == pytest.approx(0.5)
    else:
        with pytest.raises(ModelError, match="pip install xacro"):
            load_model(path)
    with pytest.raises(ModelError, match="unexpanded xacro"):
        load_model(source)  # text (a robot_description) that nobody expanded


NO_XACRO_ROBOT = (
    '<robot name="gen" xmlns:xacro="http://www.ros.org/wiki/xacro" xmlns:gazebo="http://example/gazebo">'
    "<!-- ---------------- generated by xacro -- do not edit ---------------- -->"
    '<link name="a"/><link name="b"/>' + revolute("j", "a", "b") + '<gazebo reference="b"><gazebo:plugin '
    'filename="libx.so" args="a&b"/><xacro:unused_macro/><value>${not_expanded}</value></gazebo>'
    '<transmission name="t"><xacro:insert_block name="x"/></transmission><xacro:property name="p" value="1"/>'
    '<unbound:element with="an undeclared prefix"/></robot>'
)


@pytest.fixture
def without_xacro(monkeypatch):
    """`import xacro` fails, as in a plain install of the package (the test extras install xacro)."""
    monkeypatch.setitem(sys.modules, "xacro", None)


def test_a_urdf_that_declares_xacro_and_carries_leftovers_loads_as_urdfdom_reads_it(tmp_path, without_xacro) -> None:
    """xacro's own output keeps xmlns:xacro; leftovers where urdfdom does not read, undeclared prefixes,
    `--` in comments and a bare `&` are all read by urdfdom (TinyXML2), and so here, file or text."""
    path = tmp_path / "robot.urdf"
    path.write_text(NO_XACRO_ROBOT)
    said = []
    for source in (path, NO_XACRO_ROBOT):
        model = load_model(source, log=lambda level, message: said.append(message))
        assert model.link_names == ("a", "b") and model.joint_names == ("j",)
        assert len(model.warnings) == 1 and "xacro markup where urdfdom does not read" in model.warnings[0]
    assert said == [model.warnings[0]] * 2


@pytest.mark.parametrize("use", [
    '<xacro:include filename="arm.xacro"/>',
    '<xacro:arm prefix="left_"/>',
    '<link name="c"><inertial><mass value="${m}"/></inertial></link>',
    '<link name="c"><visual><geometry><mesh filename="$(find pkg)/c.stl"/></geometry></visual></link>',
])  # fmt: skip
def test_a_description_that_uses_xacro_needs_it(tmp_path, without_xacro, use: str) -> None:
    text = f'<robot name="x" xmlns:xacro="http://ros.org/wiki/xacro"><link name="a"/>{use}</robot>'
    path = tmp_path / "robot.urdf"
    path.write_text(text)
    with pytest.raises(ModelError, match=r"is a xacro file: install xacro .*pip install xacro"):
        load_model(path)
    with pytest.raises(ModelError, match="the URDF text is an unexpanded xacro file"):
        load_model(text)


def test_inertias_off_by_rounding_pass_and_impossible_ones_are_used_with_a_warning() -> None:
    """iCub's ankle: -1.4e-20 kg m^2 next to moments of 1e-5 (rounding); TIAGo's antenna: a products
    term larger than the moments (impossible); Pinocchio takes both as given."""

    def link(name: str, mass: str, ixx: str, ixy: str, iyy: str) -> str:
        return (
            f'<link name="{name}"><inertial><mass value="{mass}"/><inertia ixx="{ixx}" ixy="{ixy}" ixz="0" '
            f'iyy="{iyy}" iyz="0" izz="1e-5"/></inertial></link>'
        )

    body = (
        link("a", "1", "5.000000001e-6", "5.00000001e-6", "5e-6")  # moments 1e-5, 1e-5, -1e-14: rounding
        + link("b", "1e-6", "2.371e-8", "6.119e-8", "2.833e-8")  # TIAGo's antenna
        + link("c", "-0.5", "1e-5", "0", "1e-5")
        + revolute("j1", "a", "b")
        + revolute("j2", "a", "c")
    )
    model = load_model(urdf(body))
    assert model.warnings == ()
    assert [w.split("'")[1] for w in model.inertia_warnings] == ["b", "c"]
    assert "negative principal moment" in model.inertia_warnings[0] and "negative mass" in model.inertia_warnings[1]
    b = model.link_index["b"]
    assert model.inertia_in_link[b][1] == pytest.approx(6.119e-8) and model.mass[model.link_index["c"]] == -0.5


def test_an_origin_with_quat_xyzw_as_urdf_1_1_gives_it() -> None:
    half = np.sqrt(0.5)
    joint = revolute("j", "a", "b").replace("<axis", f'<origin xyz="1 2 3" quat_xyzw="0 0 {half} {half}"/><axis')
    model = load_model(urdf('<link name="a"/><link name="b"/>' + joint))
    np.testing.assert_allclose(model.parent_joints[1].origin_rotation, [0, -1, 0, 1, 0, 0, 0, 0, 1], atol=1e-15)
    expected = load_model(
        urdf(
            '<link name="a"/><link name="b"/>'
            + joint.replace(f'quat_xyzw="0 0 {half} {half}"', 'rpy="0 0 1.5707963267948966"')
        )
    )
    np.testing.assert_allclose(
        model.parent_joints[1].origin_rotation, expected.parent_joints[1].origin_rotation, atol=1e-15
    )


def test_a_robot_without_a_movable_joint_computes_everywhere() -> None:
    """A camera rig (iris_simple in example-robot-data, a table): no columns, every link known."""
    from neforward_ros import inverse_dynamics

    body = (
        '<link name="base"><inertial><mass value="2"/><inertia ixx="1" ixy="0" ixz="0" iyy="1" iyz="0" izz="1"/>'
        '</inertial></link><link name="cam"/><joint name="f" type="fixed"><parent link="base"/><child link="cam"/>'
        '<origin xyz="0.1 0 0.2" rpy="0 0.3 0"/></joint>'
    )
    model = load_model(urdf(body))
    assert model.joint_names == ()
    for shape in ((0,), (4, 0)):
        z = np.zeros(shape)
        kin = forward_recursion(model, z, z, z)
        np.testing.assert_allclose(
            kin.accel[..., 1, :],
            np.broadcast_to([-9.81 * np.sin(0.3), 0, 9.81 * np.cos(0.3)], kin.accel[..., 1, :].shape),
            atol=1e-12,
        )
        dyn = inverse_dynamics(model, z, z, z)
        assert dyn.joint_torque.shape == (*shape[:-1], 0)
        np.testing.assert_allclose(dyn.force[..., 0, :], np.broadcast_to([0, 0, 2 * 9.81], dyn.force[..., 0, :].shape))
