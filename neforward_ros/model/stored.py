"""A built :class:`RobotModel` kept in the disk cache, so that a URDF seen before is not read again.

Reading a URDF imports yourdfpy, and yourdfpy imports trimesh: about a second of a run's start. The
model built from a description depends only on the description's bytes, the root link asked for and
the code of :mod:`neforward_ros.model`; it is kept as JSON (:mod:`neforward_ros.disk_cache`,
``models/``) under a hash of all three, so a node start or a ``neforward bag`` run on a URDF seen
before reads that file instead. Descriptions that need xacro are not kept (their expansion depends on
other files).
"""

from __future__ import annotations

import functools
import hashlib
from pathlib import Path
from types import MappingProxyType
from typing import Any

from neforward_ros import disk_cache
from neforward_ros.model.types import JointKind, ParentJoint, RobotModel


@functools.cache
def _code_digest() -> str:
    """A hash of this package's sources: a change in how models are built invalidates what was kept."""
    digest = hashlib.sha256()
    for path in sorted(Path(__file__).parent.glob("*.py")):
        digest.update(path.name.encode())
        digest.update(path.read_bytes())
    return digest.hexdigest()


def stored_model(description: bytes | str, root_link: str | None) -> RobotModel | None:
    """The model kept for this description and root link, or None."""
    value = disk_cache.load("models", _code_digest(), description, root_link or "")
    if not isinstance(value, dict):
        return None
    try:
        return _from_json(value)
    except (KeyError, TypeError, ValueError):
        return None


def store_model(description: bytes | str, root_link: str | None, model: RobotModel) -> None:
    """Keep the model built from this description (best effort)."""
    disk_cache.store("models", _code_digest(), description, root_link or "", value=_to_json(model))


def _to_json(model: RobotModel) -> dict[str, Any]:
    joints = [
        None
        if joint is None
        else {
            "name": joint.name,
            "kind": joint.kind.value,
            "parent_index": joint.parent_index,
            "origin_xyz": joint.origin_xyz,
            "origin_rotation": joint.origin_rotation,
            "axis": joint.axis,
            "q_index": joint.q_index,
            "multiplier": joint.multiplier,
            "offset": joint.offset,
            "mimic_of": joint.mimic_of,
            "rotation_terms": joint.rotation_terms,
            "axis_in_parent": joint.axis_in_parent,
        }
        for joint in model.parent_joints
    ]
    return {
        "name": model.name,
        "link_names": model.link_names,
        "joint_names": model.joint_names,
        "parent_joints": joints,
        "com_in_link": model.com_in_link,
        "link_index": dict(model.link_index),
        "joint_index": dict(model.joint_index),
        "mass": model.mass,
        "inertia_in_link": model.inertia_in_link,
        "inertia_warnings": model.inertia_warnings,
        "warnings": model.warnings,
        "floating_base": model.floating_base,
    }


def _floats(values: Any) -> tuple[Any, ...]:
    return tuple(float(v) for v in values)


def _from_json(value: dict[str, Any]) -> RobotModel:
    joints = tuple(
        None
        if joint is None
        else ParentJoint(
            name=str(joint["name"]),
            kind=JointKind(joint["kind"]),
            parent_index=int(joint["parent_index"]),
            origin_xyz=_floats(joint["origin_xyz"]),
            origin_rotation=_floats(joint["origin_rotation"]),
            axis=_floats(joint["axis"]),
            q_index=int(joint["q_index"]),
            multiplier=float(joint["multiplier"]),
            offset=float(joint["offset"]),
            mimic_of=None if joint["mimic_of"] is None else str(joint["mimic_of"]),
            rotation_terms=_floats(joint["rotation_terms"]),
            axis_in_parent=_floats(joint["axis_in_parent"]),
        )
        for joint in value["parent_joints"]
    )
    return RobotModel(
        name=str(value["name"]),
        link_names=tuple(value["link_names"]),
        joint_names=tuple(value["joint_names"]),
        parent_joints=joints,
        com_in_link=tuple(_floats(c) for c in value["com_in_link"]),
        link_index=MappingProxyType({str(k): int(v) for k, v in value["link_index"].items()}),
        joint_index=MappingProxyType({str(k): int(v) for k, v in value["joint_index"].items()}),
        mass=_floats(value["mass"]),
        inertia_in_link=tuple(_floats(i) for i in value["inertia_in_link"]),
        inertia_warnings=tuple(value["inertia_warnings"]),
        warnings=tuple(value["warnings"]),
        floating_base=value["floating_base"],
    )
