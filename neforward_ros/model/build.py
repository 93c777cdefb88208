"""A URDF's links and joints -> a checked :class:`RobotModel`: the tree, its root, the joint columns.

What is refused, and why (each a :class:`ModelError` naming the link or joint):

- what urdfdom refuses because the robot would not be one tree: no link, a link or joint defined
  twice, a joint naming a link that is not defined, a link with two parent joints, a cycle,
  several root links; an unknown ``root_link``;
- a movable joint whose axis is zero: no rotation or translation is defined (Pinocchio builds such a
  file, and its "rotation" is then a scaled identity, not a rotation).

What is read with a warning (:attr:`RobotModel.warnings`, logged once by the loader), as urdfdom,
KDL and Pinocchio read it:

- a mimic joint whose leader is unknown, not a movable joint of the tree, or part of a cycle of
  mimic joints: it is an independent joint (a column of q), as Pinocchio's default reads it;
- a floating or planar joint below the root: taken as fixed at its origin, as KDL (and so
  robot_state_publisher) takes it; a joint state cannot drive it. (A floating joint between the
  URDF's root, a world link, and the robot is the robot's floating base.)

A link whose ``<inertial>`` fails to read keeps what urdfdom keeps (:mod:`.urdf`), said in
:attr:`RobotModel.inertia_warnings`. Masses and inertias that no rigid body has (a negative mass, a
negative principal moment beyond rounding, principal moments breaking the triangle inequality) are
used as given, as Pinocchio uses them, and listed in :attr:`RobotModel.inertia_warnings`: only the
backward pass uses them.
"""

from __future__ import annotations

from types import MappingProxyType

import numpy as np

from neforward_ros.errors import ModelError
from neforward_ros.model.types import JointKind, Mat3, ParentJoint, RobotModel, Vec3
from neforward_ros.model.urdf import UrdfJoint, UrdfLink, UrdfRobot

_KINDS = {kind.value: kind for kind in JointKind}
_AS_FIXED = ("floating", "planar")

INERTIA_TOLERANCE = 1e-6
"""Relative slack of the inertia checks (of the link's largest principal moment, or the robot's where
larger): the rounding of a URDF's numbers, printed to six or more significant digits, stays within it."""


def build_model(robot: UrdfRobot, root_link: str | None = None) -> RobotModel:
    """The model of the tree below ``root_link`` (default: the URDF's root, or the link a floating
    joint holds when the root is a world link with only that joint).

    Raises:
        ModelError: see the module docstring.
    """
    link_by_name: dict[str, UrdfLink] = {}
    for link in robot.links:
        if link.name in link_by_name:
            raise ModelError(f"link {link.name!r} is defined twice (lines {link_by_name[link.name].line}, {link.line})")
        link_by_name[link.name] = link
    if not link_by_name:
        raise ModelError("the URDF has no links")
    joint_by_name: dict[str, UrdfJoint] = {}
    parent_joint_of: dict[str, UrdfJoint] = {}
    for joint in robot.joints:
        if joint.name in joint_by_name:
            raise ModelError(
                f"joint {joint.name!r} is defined twice (lines {joint_by_name[joint.name].line}, {joint.line})"
            )
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

    children: dict[str, list[UrdfJoint]] = {name: [] for name in link_by_name}
    for joint in robot.joints:  # URDF order, so children come in URDF order
        children[joint.parent].append(joint)
    link_names: list[str] = []
    tree_joints: list[UrdfJoint] = []
    stack: list[tuple[str, UrdfJoint | None]] = [(root_link, None)]
    while stack:
        link_name, joint = stack.pop()
        link_names.append(link_name)
        if joint is not None:
            tree_joints.append(joint)
        stack.extend((j.child, j) for j in reversed(children[link_name]))
    link_index = {name: i for i, name in enumerate(link_names)}

    warnings: list[str] = []
    for joint in tree_joints:
        if joint.type in _AS_FIXED:
            warnings.append(
                f"joint {joint.name!r} is {joint.type} and not between the URDF's root and the robot: it is taken as "
                f"fixed at its origin (as KDL and robot_state_publisher take it); choose root_link {joint.child!r} "
                "to treat what is below it as a moving base"
            )
    movable = {j.name: j for j in tree_joints if j.type in ("revolute", "continuous", "prismatic")}
    mimics = _resolve_mimics(movable, joint_by_name, warnings)
    independent = [j.name for j in robot.joints if j.name in movable and j.name not in mimics]
    joint_index = {name: i for i, name in enumerate(independent)}

    parent_joints: list[ParentJoint | None] = [None]
    for joint in tree_joints:
        parent_joints.append(_parent_joint(joint, link_index[joint.parent], joint_index, mimics))

    links = [link_by_name[name] for name in link_names]
    scale = max((_largest_moment(link) for link in links), default=0.0)
    inertias = [_inertia(link, scale) for link in links]
    return RobotModel(
        name=robot.name,
        link_names=tuple(link_names),
        joint_names=tuple(independent),
        parent_joints=tuple(parent_joints),
        com_in_link=tuple(com for _, com, _, _ in inertias),
        link_index=MappingProxyType(link_index),
        joint_index=MappingProxyType(joint_index),
        mass=tuple(mass for mass, _, _, _ in inertias),
        inertia_in_link=tuple(inertia for _, _, inertia, _ in inertias),
        inertia_warnings=tuple(warning for _, _, _, warning in inertias if warning),
        warnings=tuple(warnings),
        floating_base=floating_base,
    )


def _check_no_cycle(link_by_name: dict[str, UrdfLink], parent_joint_of: dict[str, UrdfJoint]) -> None:
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


def _resolve_mimics(
    movable: dict[str, UrdfJoint], joint_by_name: dict[str, UrdfJoint], warnings: list[str]
) -> dict[str, tuple[str, float, float]]:
    """Mimic joint -> (independent leader, multiplier, offset), chains composed: q = m q_leader + o.
    A mimic joint whose chain does not end at an independent movable joint of the tree is left out:
    it is independent itself (with a warning)."""
    resolved: dict[str, tuple[str, float, float] | None] = {}

    def resolve(name: str, chain: tuple[str, ...]) -> tuple[str, float, float] | None:
        if name in resolved:
            return resolved[name]
        mimic = movable[name].mimic
        if mimic is None:
            resolved[name] = None
            return None
        leader = joint_by_name.get(mimic.joint)
        problem = None
        if leader is None:
            problem = f"follows {mimic.joint!r}, which is not a joint of the URDF"
        elif mimic.joint in chain:
            problem = f"is part of a cycle of mimic joints ({' -> '.join([*chain, name, mimic.joint])})"
        elif mimic.joint not in movable:
            movable_type = leader.type in ("revolute", "continuous", "prismatic")
            where = "is not below root_link" if movable_type else f"is {leader.type}"
            problem = f"follows {mimic.joint!r}, which {where}"
        if problem is not None:
            warnings.append(
                f"mimic joint {name!r} {problem}: it is read as an independent joint (its own column of q, as "
                "Pinocchio reads it by default); fix or remove its <mimic>"
            )
            resolved[name] = None
            return None
        above = resolve(mimic.joint, (*chain, name))
        leader_name, multiplier, offset = above if above is not None else (mimic.joint, 1.0, 0.0)
        # q = m (multiplier q_leader + offset) + o
        result = (leader_name, mimic.multiplier * multiplier, mimic.multiplier * offset + mimic.offset)
        resolved[name] = result
        return result

    for name in movable:
        resolve(name, ())
    return {name: value for name, value in resolved.items() if value is not None}


def _parent_joint(
    joint: UrdfJoint, parent_index: int, joint_index: dict[str, int], mimics: dict[str, tuple[str, float, float]]
) -> ParentJoint:
    kind = _KINDS.get(joint.type, JointKind.FIXED)  # floating and planar below the root: fixed
    rotation = joint.origin[:3, :3]
    if kind is JointKind.FIXED:
        axis = np.zeros(3)
        q_index, multiplier, offset, leader = -1, 1.0, 0.0, None
    else:
        norm = float(np.linalg.norm(joint.axis))
        if not norm > 1e-12:
            raise ModelError(
                f"joint {joint.name!r} is {joint.type} with a zero axis ({' '.join(map(repr, joint.axis.tolist()))}): "
                "no motion is defined; give <axis xyz> a nonzero vector"
            )
        axis = joint.axis / norm
        leader, multiplier, offset = mimics.get(joint.name, (None, 1.0, 0.0))
        q_index = joint_index[leader if leader is not None else joint.name]
    k = np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]])
    return ParentJoint(
        name=joint.name,
        kind=kind,
        parent_index=parent_index,
        origin_xyz=_vec3(joint.origin[:3, 3]),
        origin_rotation=_mat3(rotation),
        axis=_vec3(axis),
        q_index=q_index,
        multiplier=float(multiplier),
        offset=float(offset),
        mimic_of=leader,
        rotation_terms=_mat3(rotation) + _mat3(rotation @ k) + _mat3(rotation @ k @ k),
        axis_in_parent=_vec3(rotation @ axis),
    )


def _inertia_along_link(link: UrdfLink) -> np.ndarray:
    """The link's inertia about its centre of mass along the link axes (3x3, symmetric), kg m^2."""
    assert link.inertial is not None
    rotation = link.inertial.origin[:3, :3]
    inertia = rotation @ link.inertial.inertia @ rotation.T
    return 0.5 * (inertia + inertia.T)


def _largest_moment(link: UrdfLink) -> float:
    """The link's largest principal moment in magnitude, kg m^2 (0 without an inertial)."""
    if link.inertial is None:
        return 0.0
    return float(np.abs(np.linalg.eigvalsh(_inertia_along_link(link))).max())


def _inertia(link: UrdfLink, robot_scale: float) -> tuple[float, Vec3, Mat3, str]:
    """(mass, centre of mass in the link frame, inertia about it along the link axes, a warning or "").

    The checks allow rounding: INERTIA_TOLERANCE of the link's largest principal moment or of the
    robot's, whichever is larger. Converters write a massive link's zero inertia as ``-5.42101e-20``
    (iCub's published models): nothing a torque can show, and no cause for a warning."""
    inertial = link.inertial
    if inertial is None:
        return 0.0, (0.0, 0.0, 0.0), (0.0,) * 9, ""  # type: ignore[return-value]
    inertia = _inertia_along_link(link)
    moments = np.linalg.eigvalsh(inertia)
    slack = INERTIA_TOLERANCE * max(float(np.abs(moments).max()), robot_scale, 1e-300)
    problems = []
    if inertial.mass < 0.0:
        problems.append(f"a negative mass ({inertial.mass:.6g} kg)")
    if moments[0] < -slack:
        problems.append(f"a negative principal moment ({moments[0]:.6g} kg m^2)")
    elif moments[0] + moments[1] < moments[2] - slack:
        shortfall = (moments[2] - moments[0] - moments[1]) / moments[2]
        problems.append(
            f"principal moments ({', '.join(f'{m:.6g}' for m in moments)} kg m^2) that break the triangle "
            f"inequality (the two smaller sum to {100 * shortfall:.3g} % less than the largest)"
        )
    warning = link.problem
    if problems:
        warning = (
            f"link {link.name!r} (line {link.line}) has {' and '.join(problems)}: no rigid body has this inertia; "
            "it is used as given, so joint torques and wrenches are off by what it misses; check its <inertial>"
        )
    return inertial.mass, _vec3(inertial.origin[:3, 3]), _mat3(inertia), warning


def _vec3(values: np.ndarray) -> Vec3:
    x, y, z = (float(v) for v in values)
    return (x, y, z)


def _mat3(matrix: np.ndarray) -> Mat3:
    return tuple(float(v) for v in np.asarray(matrix).reshape(9))  # type: ignore[return-value]
