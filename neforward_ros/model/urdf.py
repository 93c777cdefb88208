"""A URDF's element tree -> its links and joints: read by yourdfpy, by urdfdom's rules.

yourdfpy reads each ``<joint>`` (type, parent, child, origin, axis, limits, mimic) and each
``<inertial>`` (origin, mass, inertia). urdfdom (the parser of robot_state_publisher, KDL and
Pinocchio) decides what the robot is, and where the two differ the project follows urdfdom:

- urdfdom takes the ``<link>`` and ``<joint>`` children of ``<robot>`` and ignores every other
  element (``<gazebo>``, ``<transmission>``, ``<ros2_control>``, anything prefixed). A link's
  ``<visual>`` and ``<collision>`` are never read (urdfdom drops a link's visuals when one fails;
  yourdfpy refuses the whole file for a geometry it does not know, such as ``<capsule>``).
- A vector (``<origin xyz rpy>``, ``<axis xyz>``) is three numbers; urdfdom refuses four, which
  yourdfpy would cut to three. A number is finite (urdfdom's conversion refuses ``nan`` and
  ``inf``, which Python's accepts). Defaults are urdfdom's: a missing ``<origin>`` is the identity,
  ``<axis>`` 1 0 0, ``<mimic>`` multiplier 1 and offset 0. rpy is fixed-axis roll, pitch, yaw:
  R = Rz(yaw) Ry(pitch) Rx(roll). An origin may give URDF 1.1's ``quat_xyzw`` instead of ``rpy``.
- A link whose ``<inertial>`` fails to read is kept, as urdfdom keeps it (model.cpp ignores
  ``parseLink``'s failure): urdfdom reads the origin, then ``<mass value>``, then the six
  ``<inertia>`` attributes, stops at the first that is missing or not a number and keeps what it
  read before it. A link with a mass and no (or an incomplete) ``<inertia>`` keeps its mass and
  centre of mass with zero rotational inertia; one whose mass or origin fails is massless.
  yourdfpy would give a missing ``ixx``, ``iyy`` or ``izz`` the value 1 kg m^2. Each such link is
  said in :attr:`UrdfLink.problem`.
- A joint urdfdom cannot read refuses the file, as urdfdom refuses it; the error names the joint
  and its line.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from neforward_ros.errors import ModelError
from neforward_ros.model.document import children
from neforward_ros.rotations import rotation_matrix

JOINT_TYPES = ("revolute", "continuous", "prismatic", "fixed", "floating", "planar")
INERTIA_KEYS = ("ixx", "ixy", "ixz", "iyy", "iyz", "izz")


@dataclass(frozen=True)
class Inertial:
    """A link's ``<inertial>``: mass (kg), the frame of its centre of mass in the link frame
    (4x4: rotation and position), and the inertia about the centre of mass along that frame (3x3)."""

    mass: float
    origin: np.ndarray
    inertia: np.ndarray


@dataclass(frozen=True)
class UrdfLink:
    """A ``<link>``; ``problem`` says how its ``<inertial>`` failed and what was kept ("" if it read)."""

    name: str
    inertial: Inertial | None
    line: int
    problem: str = ""


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


def read_robot(root: Any) -> UrdfRobot:
    """The robot a URDF's root element (lxml) describes, read by yourdfpy with urdfdom's rules.

    Raises:
        ModelError: the root is not ``<robot>``, or a link or joint is one urdfdom refuses; the
            message names the element and its line.
    """
    if root.tag != "robot":
        raise ModelError(f"not a URDF: the root element is <{root.tag}>, expected <robot>")
    from neforward_ros.model.reader import yourdfpy_urdf

    reader = yourdfpy_urdf()
    elements = children(root)
    links = tuple(_link(element, reader) for element in elements if element.tag == "link")
    joints = tuple(_joint(element, reader) for element in elements if element.tag == "joint")
    # A <robot> without a name is refused by urdfdom and accepted by others (example-robot-data's ur3.urdf).
    return UrdfRobot(name=root.get("name") or "robot", links=links, joints=joints)


def _link(element: Any, reader: Any) -> UrdfLink:
    name = element.get("name")
    if not name:
        raise ModelError(f"a <link> without a name at line {element.sourceline}")
    inertial = element.find("inertial")
    if inertial is None:
        return UrdfLink(name, None, element.sourceline)
    read, problem = _inertial(inertial, reader)
    if problem:
        problem = f"link {name!r} (line {inertial.sourceline}): {problem}"
    return UrdfLink(name, read, element.sourceline, problem)


def _inertial(element: Any, reader: Any) -> tuple[Inertial, str]:
    """(what urdfdom keeps of an ``<inertial>``, how its reading failed or "")."""
    nothing = np.zeros((3, 3))
    origin_element = element.find("origin")
    problem = _pose_problem(origin_element)
    if problem:
        return Inertial(0.0, np.eye(4), nothing), f"{problem}: urdfdom reads nothing of its <inertial>; it is massless"
    origin = np.eye(4) if origin_element is None else oriented(reader._parse_origin(origin_element), origin_element)
    mass_element = element.find("mass")
    mass_text = None if mass_element is None else mass_element.get("value")
    if mass_text is None or _number_problem(mass_text):
        what = "no <mass value>" if mass_text is None else f"<mass value={mass_text!r}>, not a finite number"
        return Inertial(0.0, origin, nothing), f"{what}: urdfdom reads no mass; it is massless"
    mass = float(reader._parse_mass(mass_element))
    inertia_element = element.find("inertia")
    missing = INERTIA_KEYS if inertia_element is None else [k for k in INERTIA_KEYS if k not in inertia_element.attrib]
    bad = [] if missing else [k for k in INERTIA_KEYS if _number_problem(inertia_element.get(k))]
    if missing or bad:
        what = (
            "no <inertia>"
            if inertia_element is None
            else f"<inertia> without {' '.join(missing)}"
            if missing
            else f"<inertia {bad[0]}={inertia_element.get(bad[0])!r}>, not a finite number"
        )
        kept = Inertial(mass, origin, nothing)
        return kept, (
            f"{what}: urdfdom keeps its mass ({mass:.6g} kg) and centre of mass with zero rotational inertia, and so "
            "does this model; give all six of ixx ixy ixz iyy iyz izz"
        )
    inertia = np.asarray(reader._parse_inertia(inertia_element), dtype=float)
    return Inertial(mass, origin, inertia), ""


def _joint(element: Any, reader: Any) -> UrdfJoint:
    name = element.get("name")
    line = element.sourceline
    if not name:
        raise ModelError(f"a <joint> without a name at line {line}")
    where = f"joint {name!r} (line {line})"
    kind = element.get("type")
    if kind is None:
        raise ModelError(f"{where} has no type")
    if kind not in JOINT_TYPES:
        raise ModelError(f"{where} has unknown type {kind!r}; URDF joints are {', '.join(JOINT_TYPES)}")
    for role in ("parent", "child"):
        end = element.find(role)
        if end is None or not end.get("link"):
            raise ModelError(f"{where} names no {role} link (<{role} link=...>)")
    for problem in (_pose_problem(element.find("origin")), _vector_problem(element.find("axis"), "xyz")):
        if problem:
            raise ModelError(f"{where} {problem}")
    mimic_element = element.find("mimic")
    if mimic_element is not None:
        if not mimic_element.get("joint"):
            raise ModelError(f"{where}: <mimic> names no joint")
        for attribute in ("multiplier", "offset"):
            text = mimic_element.get(attribute)
            if text is not None and _number_problem(text):
                raise ModelError(f"{where} <mimic {attribute}>: {_number_problem(text)}")
    try:
        read = reader._parse_joint(element)
    except (ValueError, TypeError, AttributeError) as exc:  # what yourdfpy cannot convert, urdfdom refuses too
        raise ModelError(f"{where}: {exc} (urdfdom refuses it too)") from None
    origin = np.eye(4) if read.origin is None else oriented(read.origin, element.find("origin"))
    axis = np.asarray(read.axis, dtype=float)
    mimic = None
    if read.mimic is not None:
        mimic = Mimic(read.mimic.joint, float(read.mimic.multiplier), float(read.mimic.offset))
    return UrdfJoint(name, kind, read.parent, read.child, origin, axis, mimic, line)


def oriented(read: np.ndarray, element: Any) -> np.ndarray:
    """yourdfpy's 4x4 transform of an ``<origin xyz rpy>`` that passed :func:`_pose_problem`, with
    URDF 1.1's ``quat_xyzw`` for the rotation where the origin gives it (yourdfpy reads only rpy)."""
    transform = np.array(read, dtype=float)
    quaternion_text = element.get("quat_xyzw")
    if quaternion_text is not None:
        quaternion = np.array([float(part) for part in quaternion_text.split()])
        transform[:3, :3] = rotation_matrix(quaternion / np.linalg.norm(quaternion))
    return transform


def _pose_problem(element: Any) -> str:
    """Why urdfdom refuses an ``<origin>`` (None is fine), or ""."""
    if element is None:
        return ""
    if element.get("rpy") is not None and element.get("quat_xyzw") is not None:
        return "<origin> gives both rpy and quat_xyzw; give one"
    problem = _vector_problem(element, "xyz") or _vector_problem(element, "rpy")
    if problem or element.get("quat_xyzw") is None:
        return problem
    parts = element.get("quat_xyzw").split()
    values = [float(p) for p in parts if not _number_problem(p)]
    if len(parts) != 4 or len(values) != 4 or not math.hypot(*values) > 0.0:
        return f"<origin quat_xyzw>: {element.get('quat_xyzw')!r} is not a nonzero quaternion x y z w"
    return ""


def _vector_problem(element: Any, attribute: str) -> str:
    """Why urdfdom refuses ``element``'s vector ``attribute`` (absent is fine), or ""."""
    text = None if element is None else element.get(attribute)
    if text is None:
        return ""
    where = f"<{element.tag} {attribute}>"
    parts = text.split()
    for part in parts:
        if _number_problem(part):
            return f"{where}: {_number_problem(part)}"
    if len(parts) != 3:
        return f"{where}: {text!r} is not three numbers"
    return ""


def _number_problem(text: str) -> str:
    """Why urdfdom's conversion refuses a number, or ""."""
    try:
        value = float(text)
    except ValueError:
        return f"{text!r} is not a number"
    if not math.isfinite(value):
        return f"{text!r} is not a finite number"
    return ""
