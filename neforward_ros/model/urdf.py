"""A URDF's element tree -> its links and joints, by urdfdom's reading rules.

urdfdom (the parser of robot_state_publisher, KDL and Pinocchio) takes the ``<link>`` and
``<joint>`` children of ``<robot>`` and ignores every other element (``<gazebo>``,
``<transmission>``, ``<ros2_control>``, anything prefixed). It reads what this package uses the
same way: ``<origin xyz rpy>`` (each three numbers separated by blanks, missing = zeros; rpy as
fixed-axis roll, pitch, yaw: R = Rz(yaw) Ry(pitch) Rx(roll)), ``<axis xyz>`` (default 1 0 0),
``<mimic joint multiplier offset>`` (defaults 1 and 0), ``<inertial>`` with ``<origin>``,
``<mass value>`` and ``<inertia ixx ixy ixz iyy iyz izz>``.

Where urdfdom refuses a file for what no computation here uses (a revolute joint without
``<limit>``, a malformed ``<visual>``, a material or a safety controller), it is read anyway; where
it refuses one for what the computation needs (a joint without a type, parent or child, a number
that is not a number, an ``<inertial>`` without its mass or inertia), the error names the element
and its line.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from neforward_ros.errors import ModelError
from neforward_ros.model.xml_tree import Element
from neforward_ros.rotations import rotation_matrix

JOINT_TYPES = ("revolute", "continuous", "prismatic", "fixed", "floating", "planar")


@dataclass(frozen=True)
class Inertial:
    """A link's ``<inertial>``: mass (kg), the frame of its centre of mass in the link frame
    (4x4: rotation and position), and the inertia about the centre of mass along that frame (3x3)."""

    mass: float
    origin: np.ndarray
    inertia: np.ndarray


@dataclass(frozen=True)
class UrdfLink:
    name: str
    inertial: Inertial | None
    line: int


@dataclass(frozen=True)
class Mimic:
    """``q = multiplier * q_joint + offset``."""

    joint: str
    multiplier: float
    offset: float


@dataclass(frozen=True)
class UrdfJoint:
    """A ``<joint>``: its type, links, origin (4x4, child frame in the parent frame at q = 0), axis
    (in the child frame, as written: not normalised), mimic and line."""

    name: str
    type: str
    parent: str
    child: str
    origin: np.ndarray
    axis: np.ndarray
    mimic: Mimic | None
    line: int


@dataclass(frozen=True)
class UrdfRobot:
    name: str
    links: tuple[UrdfLink, ...]
    joints: tuple[UrdfJoint, ...]


def read_robot(root: Element) -> UrdfRobot:
    """The robot a URDF's root element describes.

    Raises:
        ModelError: the root is not ``<robot>``, or a link or joint lacks what the computation
            needs; the message names the element and its line.
    """
    if root.tag != "robot":
        raise ModelError(f"not a URDF: the root element is <{root.tag}>, expected <robot>")
    links = tuple(_link(element) for element in root.findall("link"))
    joints = tuple(_joint(element) for element in root.findall("joint"))
    # A <robot> without a name is refused by urdfdom and accepted by others (example-robot-data's ur3.urdf).
    return UrdfRobot(name=root.attrib.get("name") or "robot", links=links, joints=joints)


def _link(element: Element) -> UrdfLink:
    name = element.attrib.get("name")
    if not name:
        raise ModelError(f"a <link> without a name at line {element.line}")
    inertial = element.find("inertial")
    return UrdfLink(name, None if inertial is None else _inertial(inertial, name), element.line)


def _inertial(element: Element, link: str) -> Inertial:
    where = f"link {link!r} (line {element.line})"
    origin = pose(element.find("origin"), where)
    mass_element = element.find("mass")
    if mass_element is None or "value" not in mass_element.attrib:
        raise ModelError(f"{where}: <inertial> needs <mass value=...>")
    mass = number(mass_element.attrib["value"], f"{where} <mass value>")
    inertia_element = element.find("inertia")
    keys = ("ixx", "ixy", "ixz", "iyy", "iyz", "izz")
    if inertia_element is None or any(k not in inertia_element.attrib for k in keys):
        raise ModelError(f"{where}: <inertial> needs <inertia ixx ixy ixz iyy iyz izz>")
    ixx, ixy, ixz, iyy, iyz, izz = (number(inertia_element.attrib[k], f"{where} <inertia {k}>") for k in keys)
    inertia = np.array([[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]])
    return Inertial(mass, origin, inertia)


def _joint(element: Element) -> UrdfJoint:
    name = element.attrib.get("name")
    if not name:
        raise ModelError(f"a <joint> without a name at line {element.line}")
    where = f"joint {name!r} (line {element.line})"
    kind = element.attrib.get("type")
    if kind is None:
        raise ModelError(f"{where} has no type")
    if kind not in JOINT_TYPES:
        raise ModelError(f"{where} has unknown type {kind!r}; URDF joints are {', '.join(JOINT_TYPES)}")
    ends = []
    for role in ("parent", "child"):
        end = element.find(role)
        link = None if end is None else end.attrib.get("link")
        if not link:
            raise ModelError(f"{where} names no {role} link (<{role} link=...>)")
        ends.append(link)
    origin = pose(element.find("origin"), where)
    axis = np.array([1.0, 0.0, 0.0])
    axis_element = element.find("axis")
    if axis_element is not None and "xyz" in axis_element.attrib:
        axis = vector(axis_element.attrib["xyz"], f"{where} <axis xyz>")
    mimic = None
    mimic_element = element.find("mimic")
    if mimic_element is not None:
        leader = mimic_element.attrib.get("joint")
        if not leader:
            raise ModelError(f"{where}: <mimic> names no joint")
        multiplier = number(mimic_element.attrib.get("multiplier", "1"), f"{where} <mimic multiplier>")
        offset = number(mimic_element.attrib.get("offset", "0"), f"{where} <mimic offset>")
        mimic = Mimic(leader, multiplier, offset)
    return UrdfJoint(name, kind, ends[0], ends[1], origin, axis, mimic, element.line)


def number(text: str, where: str) -> float:
    """A finite number, or a ModelError naming where it was read."""
    try:
        value = float(text)
    except ValueError:
        raise ModelError(f"{where}: {text!r} is not a number") from None
    if not math.isfinite(value):
        raise ModelError(f"{where}: {text!r} is not a finite number")
    return value


def vector(text: str, where: str) -> np.ndarray:
    """Three numbers separated by blanks."""
    parts = text.split()
    if len(parts) != 3:
        raise ModelError(f"{where}: {text!r} is not three numbers")
    return np.array([number(part, where) for part in parts])


def pose(element: Element | None, where: str) -> np.ndarray:
    """An ``<origin xyz rpy>`` (or, URDF 1.1, ``quat_xyzw`` instead of ``rpy``) as a 4x4 transform
    (identity where absent)."""
    transform = np.eye(4)
    if element is None:
        return transform
    attributes = element.attrib
    if "xyz" in attributes:
        transform[:3, 3] = vector(attributes["xyz"], f"{where} <origin xyz>")
    if "rpy" in attributes and "quat_xyzw" in attributes:
        raise ModelError(f"{where}: <origin> gives both rpy and quat_xyzw; give one")
    if "rpy" in attributes:
        transform[:3, :3] = rpy_matrix(*vector(attributes["rpy"], f"{where} <origin rpy>"))
    elif "quat_xyzw" in attributes:
        parts = attributes["quat_xyzw"].split()
        quaternion = np.array([number(p, f"{where} <origin quat_xyzw>") for p in parts])
        norm = float(np.linalg.norm(quaternion)) if len(parts) == 4 else 0.0
        if not norm > 0.0:
            raise ModelError(
                f"{where} <origin quat_xyzw>: {attributes['quat_xyzw']!r} is not a nonzero quaternion x y z w"
            )
        transform[:3, :3] = rotation_matrix(quaternion / norm)
    return transform


def rpy_matrix(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """R = Rz(yaw) Ry(pitch) Rx(roll): URDF's fixed-axis roll, pitch, yaw."""
    cr, sr, cp, sp, cy, sy = (
        math.cos(roll),
        math.sin(roll),
        math.cos(pitch),
        math.sin(pitch),
        math.cos(yaw),
        math.sin(yaw),
    )
    return np.array(
        [
            [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
            [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
            [-sp, cp * sr, cp * cr],
        ]
    )
