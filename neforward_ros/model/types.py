"""The immutable :class:`RobotModel` every computation shares, and its parts.

The model holds what the recursions need and nothing else: the link tree in an order where every
parent comes before its children, each link's parent joint with its constants, each link's mass,
centre of mass and inertia, and the column order of the joint vector q. Meshes are never loaded.

Frames: each link frame is the URDF link frame, which coincides with the child frame of the link's
parent joint. Rotations are stored row-major as 9-tuples and map child-frame coordinates to
parent-frame coordinates (``x_parent = R @ x_child``). Units are SI (m, rad, kg).
"""

from __future__ import annotations

import enum
from collections.abc import Mapping
from dataclasses import dataclass
from functools import cached_property

import numpy as np

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
    """An immutable kinematic tree built from a URDF by :func:`neforward_ros.load_model`.

    Attributes:
        name: the URDF robot name.
        link_names: every link of the tree, root first, each parent before its children
            (depth-first, children in URDF joint order). Indexes the outputs of the recursion.
        joint_names: the independent movable joints (revolute, continuous, prismatic; not mimic
            joints) in URDF order: the column order of q, qd and qdd. Empty for a model without
            movable joints (a sensor rig, a table, a floating body).
        parent_joints: for each link (indexed like ``link_names``) the joint to its parent;
            None for the root.
        com_in_link: for each link, its centre of mass in its own frame (m); the link origin
            when the URDF gives no ``<inertial>``.
        link_index, joint_index: name -> index in ``link_names`` / ``joint_names``.
        mass: for each link, kg (0 without ``<inertial>``: a massless link).
        inertia_in_link: for each link, its inertia tensor about its centre of mass, along the link
            frame's axes (the URDF's ``<inertia>`` rotated by the ``<inertial><origin>`` rpy), kg m^2,
            row-major.
        inertia_warnings: masses and inertias that no rigid body can have but that are used as given
            (a negative mass, a negative principal moment beyond rounding, principal moments that
            break the triangle inequality), one message per link naming it. They matter only to the
            backward pass, which logs them once.
        warnings: what else in the description was doubtful and how it was read (a mimic joint
            whose leader is missing, a floating or planar joint below the root taken as fixed, xacro
            markup left in a plain URDF and ignored), one message each, naming the joint or link
            and the fix. :func:`~neforward_ros.load_model` logs them once.
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
    warnings: tuple[str, ...] = ()
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
