"""load_model: tree order, joint columns, mimic joints, sources, and every error path."""

from __future__ import annotations

import dataclasses
import importlib.util

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
     "invalid URDF"),
    (urdf('<link name="a"/><link name="b"/><link name="c"/>' + revolute("j1", "a", "c")
          + revolute("j2", "b", "c")), "link 'c' is the child of two joints, 'j1' and 'j2'"),
    (urdf('<link name="a"/><link name="b"/><link name="c"/>' + revolute("j1", "a", "b")),
     "several root links (a, c)"),
    (urdf('<link name="r"/><link name="a"/><link name="b"/>' + revolute("j0", "r", "a") + revolute("j1", "a", "b")
          + revolute("j2", "b", "a")), "child of two joints"),
    (urdf('<link name="a"/><link name="b"/>' + revolute("j1", "a", "b") + revolute("j2", "b", "a")),
     "cycle through links"),
    (urdf('<link name="a"/><link name="b"/><link name="c"/>' + revolute("j", "a", "b")
          + '<joint name="fb" type="floating"><parent link="b"/><child link="c"/></joint>'), "joint 'fb' is floating"),
    (urdf('<link name="a"/><link name="b"/><joint name="pl" type="planar"><parent link="a"/><child link="b"/>'
          '<axis xyz="0 0 1"/></joint>'), "joint 'pl' is planar"),
    (urdf('<link name="a"/><link name="b"/><joint name="w" type="wobbly"><parent link="a"/><child link="b"/></joint>'),
     "unknown type 'wobbly'"),
    (urdf('<link name="a"/><link name="b"/><joint name="z" type="revolute"><parent link="a"/><child link="b"/>'
          '<axis xyz="0 0 0"/></joint>'), "joint 'z' has an invalid axis"),
    (urdf('<link name="a"/><link name="b"/>' + revolute("j", "a", "b", '<mimic joint="ghost"/>')),
     "follows 'ghost', which is not a joint"),
    (urdf('<link name="a"/><link name="b"/><link name="c"/><joint name="f" type="fixed"><parent link="a"/>'
          '<child link="b"/></joint>' + revolute("j", "a", "c", '<mimic joint="f"/>')), "follows 'f', which is fixed"),
    (urdf('<link name="a"/><link name="b"/><link name="c"/>' + revolute("j1", "a", "b", '<mimic joint="j2"/>')
          + revolute("j2", "a", "c", '<mimic joint="j1"/>')), "in a cycle"),
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


def test_mimic_leader_above_root_link() -> None:
    body = (
        '<link name="a"/><link name="b"/><link name="c"/>'
        + revolute("j1", "a", "b")
        + revolute("j2", "b", "c", '<mimic joint="j1"/>')
    )
    with pytest.raises(ModelError, match="which is above root_link"):
        load_model(urdf(body), root_link="b")


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


def test_models_read_back_from_the_cache_equal_the_parsed_ones(tmp_path, monkeypatch) -> None:
    monkeypatch.setenv("NEFORWARD_CACHE", str(tmp_path))
    import json

    parsed = {}
    for name, path in TEST_ROBOTS.items():
        parsed[name] = load_model(path)
        assert load_model(path) == parsed[name]  # from the file now
    assert len(list(tmp_path.glob("models/*.json"))) == len(TEST_ROBOTS)
    for path in tmp_path.glob("models/*.json"):  # corrupt them all: parsed again, and rewritten
        path.write_text("{not json")
    assert load_model(TEST_ROBOTS["panda"]) == parsed["panda"]
    assert sum(1 for path in tmp_path.glob("models/*.json") if path.read_text().startswith('{"')) == 1
    json.loads(next(p for p in tmp_path.glob("models/*.json") if p.read_text().startswith('{"')).read_text())
    sub = load_model(TEST_ROBOTS["panda"], root_link="panda_link4")  # another root: another entry
    assert sub.root_link == "panda_link4" and load_model(TEST_ROBOTS["panda"], root_link="panda_link4") == sub


def test_a_cached_model_needs_no_urdf_parser(tmp_path) -> None:
    """The point of the cache: yourdfpy (and trimesh) are not imported for a URDF seen before."""
    import os
    import subprocess
    import sys

    code = (
        "import sys; from neforward_ros import load_model; "
        f"load_model({str(TEST_ROBOTS['panda'])!r}); print('yourdfpy' in sys.modules)"
    )
    environment = {**os.environ, "NEFORWARD_CACHE": str(tmp_path)}
    runs = [
        subprocess.run([sys.executable, "-c", code], env=environment, capture_output=True, text=True, timeout=60)
        for _ in range(2)
    ]
    assert [run.stdout.strip() for run in runs] == ["True", "False"], [run.stderr for run in runs]
    off = subprocess.run(
        [sys.executable, "-c", code], env={**environment, "NEFORWARD_CACHE": "off"}, capture_output=True, text=True
    )
    assert off.stdout.strip() == "True"


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
