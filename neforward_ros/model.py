"""URDF -> immutable :class:`RobotModel`, built once and shared by every computation.

The model holds what the forward recursion needs and nothing else: the link tree in an order where
every parent comes before its children, each link's parent joint with its constants, the centre of
mass of each link, and the column order of the joint vector q. Meshes are never loaded.

Frames: each link frame is the URDF link frame, which coincides with the child frame of the link's
parent joint. Rotations are stored row-major as 9-tuples and map child-frame coordinates to
parent-frame coordinates (``x_parent = R @ x_child``). Units are SI (m, rad).
"""

from __future__ import annotations

import enum
import io
import logging
import math
import os
import xml.etree.ElementTree as ElementTree
from collections.abc import Mapping
from dataclasses import dataclass
from functools import cached_property
from types import MappingProxyType

import numpy as np

from neforward_ros import disk_cache
from neforward_ros.errors import ModelError

Vec3 = tuple[float, float, float]
Mat3 = tuple[float, float, float, float, float, float, float, float, float]
"""A 3x3 matrix stored row-major."""


class JointKind(enum.Enum):
    """The URDF joint types the recursion supports."""

    FIXED = "fixed"
    REVOLUTE = "revolute"
    CONTINUOUS = "continuous"
    PRISMATIC = "prismatic"


@dataclass(frozen=True, slots=True)
class ParentJoint:
    """The joint that attaches a link to its parent link.

    At joint position ``qj`` the child frame sits, in the parent frame, at
    ``origin_rotation @ Rot(axis, qj)`` and ``origin_xyz`` for a rotating joint, and at
    ``origin_rotation`` and ``origin_xyz + axis_in_parent * qj`` for a prismatic one.

    Attributes:
        name: URDF joint name.
        kind: joint type.
        parent_index: index of the parent link in :attr:`RobotModel.link_names`.
        origin_xyz: child origin in the parent frame at qj = 0 (m).
        origin_rotation: rotation child -> parent at qj = 0 (from the URDF ``rpy``).
        axis: unit joint axis in the child frame; (0, 0, 0) for fixed joints.
        q_index: column of q that drives this joint (the leader's column for a mimic joint);
            -1 for a fixed joint.
        multiplier, offset: ``qj = multiplier * q[q_index] + offset``; (1, 0) unless mimic.
        mimic_of: name of the independent joint this one follows, or None.
        rotation_terms: ``origin_rotation``, ``origin_rotation @ K`` and ``origin_rotation @ K @ K``
            (27 numbers, each matrix row-major) with K the cross-product matrix of ``axis``, so that
            for a rotating joint ``origin_rotation @ Rot(axis, qj) = origin_rotation
            + sin(qj) origin_rotation @ K + (1 - cos(qj)) origin_rotation @ K @ K`` (Rodrigues).
        axis_in_parent: ``origin_rotation @ axis``, the prismatic direction in the parent frame.
    """

    name: str
    kind: JointKind
    parent_index: int
    origin_xyz: Vec3
    origin_rotation: Mat3
    axis: Vec3
    q_index: int
    multiplier: float
    offset: float
    mimic_of: str | None
    rotation_terms: tuple[float, ...]
    axis_in_parent: Vec3


@dataclass(frozen=True)
class RobotModel:
    """An immutable kinematic tree built from a URDF by :func:`load_model`.

    Attributes:
        name: the URDF robot name.
        link_names: every link of the tree, root first, each parent before its children
            (depth-first, children in URDF joint order). Indexes the outputs of the recursion.
        joint_names: the independent movable joints (revolute, continuous, prismatic; not mimic
            joints) in URDF order: the column order of q, qd and qdd.
        parent_joints: for each link (indexed like ``link_names``) the joint to its parent;
            None for the root.
        com_in_link: for each link, its centre of mass in its own frame (m); the link origin
            when the URDF gives no ``<inertial>``.
        link_index, joint_index: name -> index in ``link_names`` / ``joint_names``.
        mass: for each link, kg (0 without ``<inertial>``: a massless link).
        inertia_in_link: for each link, its inertia tensor about its centre of mass, along the link
            frame's axes (the URDF's ``<inertia>`` rotated by the ``<inertial><origin>`` rpy), kg m^2,
            row-major.
        inertia_warnings: inertias that no rigid body can have but that are used as given (principal
            moments violating the triangle inequality), one message per link.
        floating_base: the floating joint by which the URDF's root (a world link) holds the root
            link, when it has one: the root link's motion is then an input (a base source), not
            fixed. None for a fixed-base URDF.
    """

    name: str
    link_names: tuple[str, ...]
    joint_names: tuple[str, ...]
    parent_joints: tuple[ParentJoint | None, ...]
    com_in_link: tuple[Vec3, ...]
    link_index: Mapping[str, int]
    joint_index: Mapping[str, int]
    mass: tuple[float, ...] = ()
    inertia_in_link: tuple[Mat3, ...] = ()
    inertia_warnings: tuple[str, ...] = ()
    floating_base: str | None = None

    @property
    def root_link(self) -> str:
        """Name of the root link, whose frame is the root frame."""
        return self.link_names[0]

    @property
    def mimic_joint_names(self) -> tuple[str, ...]:
        """Movable joints that follow another joint (not columns of q), in link order."""
        return tuple(j.name for j in self.parent_joints if j is not None and j.mimic_of is not None)

    @cached_property
    def driving_columns(self) -> np.ndarray:
        """(n_links, n_joints) bool: whether column j of q moves link i, i.e. drives a joint on the path
        from the root to it (a mimic joint counts as its leader's column). A link is determined by
        the columns marked in its row."""
        drives = np.zeros((len(self.link_names), len(self.joint_names)), dtype=bool)
        for link, joint in enumerate(self.parent_joints):
            if joint is None:
                continue
            drives[link] = drives[joint.parent_index]  # parents come before their children
            if joint.q_index >= 0:
                drives[link, joint.q_index] = True
        drives.flags.writeable = False
        return drives

    def determined_links(self, known: np.ndarray) -> np.ndarray:
        """Per link, whether every column that moves it is known; ``known`` (..., n_joints) bool."""
        return ~np.any(self.driving_columns & ~np.asarray(known, dtype=bool)[..., None, :], axis=-1)

    @property
    def continuous_columns(self) -> tuple[bool, ...]:
        """Per column of q, True for a continuous joint: its positions wrap at +-pi."""
        columns = [False] * len(self.joint_names)
        for joint in self.parent_joints:
            if joint is not None and joint.mimic_of is None and joint.kind is JointKind.CONTINUOUS:
                columns[joint.q_index] = True
        return tuple(columns)


_SUPPORTED_TYPES = {kind.value: kind for kind in JointKind}
_UNSUPPORTED_TYPES = {"floating", "planar"}


def load_model(source: str | os.PathLike[str], *, root_link: str | None = None) -> RobotModel:
    """Build a :class:`RobotModel` from a URDF.

    Args:
        source: a URDF file path, or the URDF XML text itself (what a ``robot_description``
            parameter or topic holds). A string whose first non-blank character is ``<`` is
            taken as XML. A ``.xacro`` file (or one declaring the xacro namespace) is expanded
            with the ``xacro`` package first. A ``<robot>`` without a name is named ``robot``.
        root_link: the link whose frame is the root frame; the recursion covers the subtree
            below it and treats it as fixed in the inertial frame. Default: the URDF's root link.

    Raises:
        ModelError: the file is missing, the XML is malformed, the URDF is not a single tree
            (cycles, several roots, a link with two parents, unknown links), a joint is floating
            or planar or has a zero axis, a mimic joint follows an unknown or fixed joint, or
            ``root_link`` is not a link of the URDF, a xacro file that cannot be expanded (or
            the ``xacro`` package is missing: the message says how to expand it), or XML text
            that is unexpanded xacro.
    """
    xml_bytes = _read_source(source)
    stored = disk_cache.load("models", xml_bytes, root_link or "")
    if stored is not None:
        try:
            return _from_contents(stored)
        except (KeyError, TypeError, ValueError):
            pass  # an unreadable file: parse, and write it anew
    model = _build_model(_parse_urdf(xml_bytes), root_link)
    disk_cache.store("models", xml_bytes, root_link or "", value=_contents(model))
    return model


def require_urdf_parser() -> None:
    """Raise a clear ModelError now, at start-up, when the URDF parser (yourdfpy) is not installed,
    rather than later from inside a message callback."""
    import importlib.util

    if importlib.util.find_spec("yourdfpy") is None:
        raise ModelError("the URDF parser yourdfpy is not installed in this Python: pip install yourdfpy")


def _read_source(source: str | os.PathLike[str]) -> bytes:
    if isinstance(source, str) and source.lstrip().startswith("<"):
        if _XACRO_NAMESPACE in source:
            raise ModelError(
                "the URDF text is an unexpanded xacro file: expand it first (xacro robot.urdf.xacro > robot.urdf)"
            )
        return source.encode("utf-8")
    if not isinstance(source, (str, os.PathLike)):
        raise ModelError(f"URDF source must be a path or an XML string, not {type(source).__name__}")
    path = os.fspath(source)
    if not path.strip():
        raise ModelError("URDF source is empty: give a file path or the URDF XML text")
    try:
        with open(path, "rb") as stream:
            contents = stream.read()
    except OSError as exc:
        raise ModelError(f"cannot read URDF file {path!r}: {exc.strerror or exc}") from exc
    if path.endswith(".xacro") or _XACRO_NAMESPACE.encode() in contents:
        return _expand_xacro(path)
    return contents


_XACRO_NAMESPACE = "http://www.ros.org/wiki/xacro"


def _expand_xacro(path: str) -> bytes:
    """The URDF a xacro file expands to (with the xacro package, as ROS 2 launch files do)."""
    try:
        import xacro
    except ImportError as exc:
        raise ModelError(
            f"{path} is a xacro file: install xacro to read it directly (pip install xacro), "
            f"or expand it first: xacro {path} > robot.urdf"
        ) from exc
    try:
        return xacro.process_file(path).toxml().encode("utf-8")
    except BaseException as exc:  # xacro raises its own errors, and SystemExit on some
        if isinstance(exc, KeyboardInterrupt):
            raise
        raise ModelError(f"xacro could not expand {path}: {exc}") from exc


def _parse_urdf(xml_bytes: bytes):  # -> yourdfpy.Robot
    # Parse strictly first: yourdfpy falls back to a recovering parser on malformed XML, which
    # could turn a broken file into a silently different robot.
    try:
        root = ElementTree.fromstring(xml_bytes)
    except ElementTree.ParseError as exc:
        raise ModelError(f"malformed URDF XML: {exc}") from exc
    if root.tag != "robot":
        raise ModelError(f"not a URDF: the root element is <{root.tag}>, expected <robot>")
    if not root.get("name"):  # optional for urdfdom and Pinocchio (example-robot-data's ur3.urdf has none)
        root.set("name", "robot")
        xml_bytes = ElementTree.tostring(root)

    import yourdfpy  # imported here: it pulls in trimesh, which only model loading needs

    # yourdfpy logs its own complaints before raising; ours carry the message instead.
    yourdfpy_logger = logging.getLogger("yourdfpy")
    previous_level = yourdfpy_logger.level
    yourdfpy_logger.setLevel(logging.CRITICAL)
    try:
        urdf = yourdfpy.URDF.load(
            io.BytesIO(xml_bytes),
            build_scene_graph=False,
            build_collision_scene_graph=False,
            load_meshes=False,
            load_collision_meshes=False,
        )
    except Exception as exc:  # yourdfpy raises bare KeyError/AttributeError/ValueError
        raise ModelError(f"invalid URDF: {type(exc).__name__}: {exc}") from exc
    finally:
        yourdfpy_logger.setLevel(previous_level)
    return urdf.robot


def _build_model(robot, root_link: str | None) -> RobotModel:
    link_by_name = {}
    for link in robot.links:
        if link.name in link_by_name:
            raise ModelError(f"link {link.name!r} is defined twice")
        link_by_name[link.name] = link
    if not link_by_name:
        raise ModelError("the URDF has no links")

    joint_by_name = {}
    parent_joint_of: dict[str, object] = {}
    for joint in robot.joints:
        if joint.name in joint_by_name:
            raise ModelError(f"joint {joint.name!r} is defined twice")
        joint_by_name[joint.name] = joint
        for role, link_name in (("parent", joint.parent), ("child", joint.child)):
            if link_name not in link_by_name:
                raise ModelError(f"joint {joint.name!r} names {role} link {link_name!r}, which is not defined")
        if joint.child in parent_joint_of:
            other = parent_joint_of[joint.child].name
            raise ModelError(
                f"link {joint.child!r} is the child of two joints, {other!r} and {joint.name!r}: a URDF must be a tree"
            )
        parent_joint_of[joint.child] = joint

    _check_no_cycle(link_by_name, parent_joint_of)
    roots = [name for name in link_by_name if name not in parent_joint_of]
    if len(roots) > 1:
        raise ModelError(f"the URDF has several root links ({', '.join(roots)}); it must have one")
    floating_base = None
    if root_link is None:
        root_link = roots[0]
        # A URDF whose root (a "world" link) holds the robot by a floating joint: that joint is the
        # base. The robot is the subtree below it; its motion comes from a base source.
        below = [j for j in robot.joints if j.parent == root_link]
        if len(below) == 1 and below[0].type == "floating":
            floating_base = below[0].name
            root_link = below[0].child
    elif root_link not in link_by_name:
        raise ModelError(f"root_link {root_link!r} is not a link of the URDF")

    children: dict[str, list] = {name: [] for name in link_by_name}
    for joint in robot.joints:  # URDF order, so children come in URDF order
        children[joint.parent].append(joint)

    link_names: list[str] = []
    tree_joints: list = [None]
    stack = [(root_link, None)]
    while stack:
        link_name, joint = stack.pop()
        link_names.append(link_name)
        if joint is not None:
            tree_joints.append(joint)
        stack.extend((j.child, j) for j in reversed(children[link_name]))
    link_index = {name: i for i, name in enumerate(link_names)}

    in_tree = {j.name for j in tree_joints if j is not None}
    for joint in tree_joints[1:]:
        _check_joint_type(joint)
    movable = [j for j in robot.joints if j.name in in_tree and _SUPPORTED_TYPES[j.type] is not JointKind.FIXED]
    independent = [j.name for j in movable if j.mimic is None]
    joint_index = {name: i for i, name in enumerate(independent)}

    parent_joints: list[ParentJoint | None] = [None]
    for joint in tree_joints[1:]:
        parent_joints.append(_parent_joint(joint, link_index[joint.parent], joint_by_name, joint_index, in_tree))

    com_in_link = tuple(_com(link_by_name[name]) for name in link_names)
    inertias = [_inertia(link_by_name[name]) for name in link_names]
    warnings = tuple(warning for _, _, warning in inertias if warning)
    return RobotModel(
        name=robot.name or "",
        link_names=tuple(link_names),
        joint_names=tuple(independent),
        parent_joints=tuple(parent_joints),
        com_in_link=com_in_link,
        link_index=MappingProxyType(link_index),
        joint_index=MappingProxyType(joint_index),
        mass=tuple(mass for mass, _, _ in inertias),
        inertia_in_link=tuple(inertia for _, inertia, _ in inertias),
        inertia_warnings=warnings,
        floating_base=floating_base,
    )


def _check_no_cycle(link_by_name: dict, parent_joint_of: dict) -> None:
    for start in link_by_name:
        seen = [start]
        link = start
        while link in parent_joint_of:
            link = parent_joint_of[link].parent
            if link == start:
                raise ModelError(f"the joints form a cycle through links {' -> '.join(reversed(seen))}")
            if link in seen:
                break  # a cycle further up; reported when its own links are the start
            seen.append(link)


def _check_joint_type(joint) -> None:
    if joint.type in _SUPPORTED_TYPES:
        return
    if joint.type in _UNSUPPORTED_TYPES:
        raise ModelError(
            f"joint {joint.name!r} is {joint.type}: a floating joint is supported only between the URDF's root "
            "(a world link) and the robot's base, and planar joints not at all; choose root_link below it"
        )
    raise ModelError(f"joint {joint.name!r} has unknown type {joint.type!r}")


def _parent_joint(joint, parent_index: int, joint_by_name, joint_index, in_tree) -> ParentJoint:
    kind = _SUPPORTED_TYPES[joint.type]
    origin = np.eye(4) if joint.origin is None else np.asarray(joint.origin, dtype=float)
    if origin.shape != (4, 4) or not np.all(np.isfinite(origin)):
        raise ModelError(f"joint {joint.name!r} has an invalid <origin>")
    rotation = origin[:3, :3]

    if kind is JointKind.FIXED:
        axis = np.zeros(3)
        q_index, multiplier, offset, leader = -1, 1.0, 0.0, None
    else:
        axis = _unit_axis(joint)
        leader, multiplier, offset = _resolve_mimic(joint, joint_by_name, in_tree)
        q_index = joint_index[leader if leader is not None else joint.name]

    k = np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]])
    return ParentJoint(
        name=joint.name,
        kind=kind,
        parent_index=parent_index,
        origin_xyz=_vec3(origin[:3, 3]),
        origin_rotation=_mat3(rotation),
        axis=_vec3(axis),
        q_index=q_index,
        multiplier=multiplier,
        offset=offset,
        mimic_of=leader,
        rotation_terms=_mat3(rotation) + _mat3(rotation @ k) + _mat3(rotation @ k @ k),
        axis_in_parent=_vec3(rotation @ axis),
    )


def _unit_axis(joint) -> np.ndarray:
    axis = np.array([1.0, 0.0, 0.0]) if joint.axis is None else np.asarray(joint.axis, dtype=float)
    norm = float(np.linalg.norm(axis)) if axis.shape == (3,) else math.nan
    if not (math.isfinite(norm) and norm > 1e-12):
        raise ModelError(f"joint {joint.name!r} has an invalid axis {joint.axis!r}: give a nonzero 3-vector")
    return axis / norm


def _resolve_mimic(joint, joint_by_name, in_tree) -> tuple[str | None, float, float]:
    """Follow mimic links to an independent joint: q = multiplier * q_leader + offset."""
    if joint.mimic is None:
        return None, 1.0, 0.0
    multiplier, offset = 1.0, 0.0
    chain = [joint.name]
    current = joint
    while current.mimic is not None:
        mimic = current.mimic
        m = 1.0 if mimic.multiplier is None else float(mimic.multiplier)
        o = 0.0 if mimic.offset is None else float(mimic.offset)
        if not (math.isfinite(m) and math.isfinite(o)):
            raise ModelError(f"mimic joint {current.name!r} has a non-finite multiplier or offset")
        # current = m * leader + o, and the accumulated map applies on top of current.
        multiplier, offset = multiplier * m, multiplier * o + offset
        leader = joint_by_name.get(mimic.joint)
        if leader is None:
            raise ModelError(f"mimic joint {current.name!r} follows {mimic.joint!r}, which is not a joint")
        if leader.type not in _SUPPORTED_TYPES or _SUPPORTED_TYPES[leader.type] is JointKind.FIXED:
            raise ModelError(f"mimic joint {current.name!r} follows {leader.name!r}, which is {leader.type}")
        if leader.name not in in_tree:
            raise ModelError(f"mimic joint {current.name!r} follows {leader.name!r}, which is above root_link")
        if leader.name in chain:
            raise ModelError(f"mimic joints follow each other in a cycle: {' -> '.join([*chain, leader.name])}")
        chain.append(leader.name)
        current = leader
    return current.name, multiplier, offset


def _com(link) -> Vec3:
    inertial = link.inertial
    if inertial is None or inertial.origin is None:
        return (0.0, 0.0, 0.0)
    xyz = np.asarray(inertial.origin, dtype=float)[:3, 3]
    if not np.all(np.isfinite(xyz)):
        raise ModelError(f"link {link.name!r} has a non-finite <inertial><origin>")
    return _vec3(xyz)


INERTIA_TOLERANCE = 1e-9
"""Relative slack of the inertia checks (of the largest principal moment): rounding in a URDF's numbers."""


def _inertia(link) -> tuple[float, Mat3, str]:
    """(mass, inertia about the centre of mass along the link axes, a warning or ""), checked.

    Raises:
        ModelError: a mass that is negative or not a number, an inertia with a non-finite entry or
            a negative principal moment (not positive semi-definite), naming the link.
    """
    inertial = link.inertial
    if inertial is None:
        return 0.0, (0.0,) * 9, ""  # type: ignore[return-value]
    mass = 0.0 if inertial.mass is None else float(inertial.mass)
    if not (math.isfinite(mass) and mass >= 0.0):
        raise ModelError(f"link {link.name!r} has mass {mass!r}: a mass must be a number of at least 0")
    inertia = np.zeros((3, 3)) if inertial.inertia is None else np.asarray(inertial.inertia, dtype=float)
    if inertia.shape != (3, 3) or not np.all(np.isfinite(inertia)):
        raise ModelError(f"link {link.name!r} has a non-finite <inertia>")
    inertia = 0.5 * (inertia + inertia.T)
    if inertial.origin is not None:
        rotation = np.asarray(inertial.origin, dtype=float)[:3, :3]
        inertia = rotation @ inertia @ rotation.T
    moments = np.linalg.eigvalsh(inertia)
    slack = INERTIA_TOLERANCE * max(float(np.abs(moments).max()), 1e-300)
    if moments[0] < -slack:
        raise ModelError(
            f"link {link.name!r} has an inertia with a negative principal moment ({moments[0]:.6g} kg m^2): "
            "no body has one; check its <inertia> (ixx ixy ixz iyy iyz izz)"
        )
    warning = ""
    if moments[0] + moments[1] < moments[2] - slack:
        shortfall = (moments[2] - moments[0] - moments[1]) / moments[2]
        warning = (
            f"link {link.name!r}: the principal moments of its inertia ({', '.join(f'{m:.6g}' for m in moments)} "
            f"kg m^2) break the triangle inequality (the two smaller sum to {100 * shortfall:.3g} % less than the "
            "largest): no rigid body has this inertia; it is used as given"
        )
    return mass, _mat3(inertia), warning


def _vec3(values: np.ndarray) -> Vec3:
    x, y, z = (float(v) for v in values)
    return (x, y, z)


def _mat3(matrix: np.ndarray) -> Mat3:
    return tuple(float(v) for v in np.asarray(matrix).reshape(9))  # type: ignore[return-value]


def _contents(model: RobotModel) -> dict:
    """The model as JSON-able contents (floats round-trip exactly through JSON)."""
    return {
        "name": model.name,
        "link_names": list(model.link_names),
        "joint_names": list(model.joint_names),
        "com_in_link": [list(c) for c in model.com_in_link],
        "mass": list(model.mass),
        "inertia_in_link": [list(i) for i in model.inertia_in_link],
        "inertia_warnings": list(model.inertia_warnings),
        "floating_base": model.floating_base,
        "parent_joints": [
            None if j is None else {**{f: getattr(j, f) for f in ParentJoint.__slots__}, "kind": j.kind.value}
            for j in model.parent_joints
        ],
    }


def _from_contents(contents: dict) -> RobotModel:
    def joint(entry: dict | None) -> ParentJoint | None:
        if entry is None:
            return None
        fields = {f: entry[f] for f in ParentJoint.__slots__}
        for name, value in fields.items():
            if isinstance(value, list):
                fields[name] = tuple(value)
        fields["kind"] = JointKind(entry["kind"])
        return ParentJoint(**fields)

    link_names = tuple(contents["link_names"])
    joint_names = tuple(contents["joint_names"])
    return RobotModel(
        name=contents["name"],
        link_names=link_names,
        joint_names=joint_names,
        parent_joints=tuple(joint(entry) for entry in contents["parent_joints"]),
        com_in_link=tuple(tuple(c) for c in contents["com_in_link"]),
        link_index=MappingProxyType({name: i for i, name in enumerate(link_names)}),
        joint_index=MappingProxyType({name: i for i, name in enumerate(joint_names)}),
        mass=tuple(contents["mass"]),
        inertia_in_link=tuple(tuple(i) for i in contents["inertia_in_link"]),
        inertia_warnings=tuple(contents["inertia_warnings"]),
        floating_base=contents["floating_base"],
    )
