"""ROS 2 Jazzy message types without ROS: message contents <-> rosbags objects and CDR bytes.

The definitions come from the ``rosbags`` type store for ROS 2 Jazzy (a maintained copy of the ROS 2
message definitions), so field names, types and layout are not hand-mirrored here. The message
contents are the nested dicts of :mod:`neforward_ros.messages`; fields left out take the message
defaults (zero, empty), as in rclpy.
"""

from __future__ import annotations

import importlib.util
import os
from collections.abc import Mapping
from functools import cache
from typing import Any

import numpy as np

from neforward_ros import disk_cache
from neforward_ros.errors import InputError

PRIMITIVES = {  # ROS 2 primitive type: struct code (little endian), size (= CDR alignment), default
    "bool": ("?", 1, False),
    "byte": ("B", 1, 0),
    "char": ("B", 1, 0),
    "uint8": ("B", 1, 0),
    "int8": ("b", 1, 0),
    "uint16": ("H", 2, 0),
    "int16": ("h", 2, 0),
    "uint32": ("I", 4, 0),
    "int32": ("i", 4, 0),
    "uint64": ("Q", 8, 0),
    "int64": ("q", 8, 0),
    "float32": ("f", 4, 0.0),
    "float64": ("d", 8, 0.0),
}
_DTYPES = {name: np.dtype("<" + code).type for name, (code, _, _) in PRIMITIVES.items()}


@cache
def typestore() -> Any:
    """The rosbags type store of ROS 2 Jazzy (all of it: 0.1 s to build; see :func:`facts`)."""
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS2_JAZZY)


@cache
def facts(typename: str) -> dict[str, Any]:
    """What the encoders, the DDS types and the rosbag2 writer need to know of a message type,
    without building the whole type store when it was known before (kept in
    :mod:`neforward_ros.disk_cache` per rosbags release):

    - ``fields``: the field definitions of the type and of every type nested in it, as rosbags
      gives them (``name -> [[field, [nodetype, description]], ...]``, nodetype 1 base, 2 named,
      3 array, 4 sequence);
    - ``msgdef``: the message definition text ROS 2 records; ``rihs01``: the ROS 2 type hash.

    Raises:
        InputError: an unknown message type.
    """
    release = _rosbags_release()
    stored = disk_cache.load("types", release, typename)
    if stored is not None:
        return stored
    store = typestore()
    if typename not in store.fielddefs:
        raise InputError(f"unknown ROS 2 message type {typename!r}")
    fields: dict[str, list] = {}
    pending = [typename]
    while pending:
        name = pending.pop()
        if name in fields:
            continue
        entries = []
        for field, (nodetype, description) in store.fielddefs[name][1]:
            entries.append([field, [int(nodetype), _plain(description)]])
            pending += _named(int(nodetype), description)
        fields[name] = entries
    value = {
        "fields": fields,
        "msgdef": store.generate_msgdef(typename, ros_version=2)[0],
        "rihs01": store.hash_rihs01(typename),
    }
    disk_cache.store("types", release, typename, value=value)
    return value


def fields(typename: str) -> list:
    """The field definitions of a message type: ``[[field, [nodetype, description]], ...]``."""
    return facts(typename)["fields"][typename]


def nested_fields(outer: str, typename: str) -> list:
    """The field definitions of a type nested in ``outer`` (from ``outer``'s facts)."""
    return facts(outer)["fields"][typename]


def _named(nodetype: int, description: Any) -> list[str]:
    if nodetype == 2:
        return [description]
    if nodetype in (3, 4):
        (element_type, element_description), _ = description
        return _named(int(element_type), element_description)
    return []


def _plain(description: Any) -> Any:
    """rosbags' nested tuples (and Nodetype enums) as JSON-able lists and ints."""
    if isinstance(description, tuple):
        return [_plain(x) for x in description]
    if hasattr(description, "value") and not isinstance(description, str):
        return int(description)
    return description


def _rosbags_release() -> str:
    """The identity of the installed rosbags type definitions: path, size and time of the file."""
    spec = importlib.util.find_spec("rosbags")  # a namespace package: no __init__, a search location
    if spec is None or not spec.submodule_search_locations:
        raise InputError("rosbags is not installed: pip install rosbags")
    path = os.path.join(next(iter(spec.submodule_search_locations)), "typesys", "stores", "ros2_jazzy.py")
    try:
        status = os.stat(path)
    except OSError:
        return "unknown"
    return f"{path}:{status.st_size}:{status.st_mtime_ns}"


def to_ros(typename: str, contents: Mapping[str, Any] | None = None) -> Any:
    """A rosbags message object of ``typename`` (``pkg/msg/Type``) from message contents.

    Raises:
        InputError: an unknown type or field, or a value that does not fit its field.
    """
    store = typestore()
    if typename not in store.fielddefs:
        raise InputError(f"unknown ROS 2 message type {typename!r}")
    contents = {} if contents is None else contents
    _, fields = store.fielddefs[typename]
    names = {name for name, _ in fields}
    unknown = sorted(set(contents) - names)
    if unknown:
        raise InputError(f"{typename} has no field(s) {', '.join(unknown)}")
    values = {}
    for name, (nodetype, description) in fields:
        try:
            values[name] = _convert(nodetype, description, contents.get(name))
        except (TypeError, ValueError) as exc:
            raise InputError(f"{typename}.{name}: {exc}") from exc
    return store.types[typename](**values)


def _convert(nodetype: Any, description: Any, value: Any) -> Any:
    kind = int(nodetype)  # rosbags Nodetype: BASE 1, NAME 2, ARRAY 3, SEQUENCE 4
    if kind == 2:
        return to_ros(description, value)
    if kind == 1:
        base = description[0]
        if base == "string":
            return "" if value is None else str(value)
        dtype = _DTYPES[base]
        if value is None:
            return dtype(0).item()
        return bool(value) if base == "bool" else dtype(value).item()
    (element_type, element_description), length = description
    items = [] if value is None else value
    if int(element_type) == 1 and element_description[0] != "string":
        array = np.asarray(items, dtype=_DTYPES[element_description[0]])
        if kind == 3 and value is None:
            array = np.zeros(length, dtype=array.dtype)
        if kind == 3 and array.shape != (length,):
            raise ValueError(f"expected {length} values, got {array.shape}")
        return array
    converted = [_convert(element_type, element_description, item) for item in items]
    if kind == 3 and value is None:
        converted = [_convert(element_type, element_description, None) for _ in range(length)]
    return converted


def to_contents(message: Any) -> Any:
    """Message contents (dicts, lists, numbers, strings) of a rosbags message object."""
    if hasattr(message, "__msgtype__"):
        return {
            name: to_contents(getattr(message, name))
            for name in message.__dataclass_fields__
            if not name.startswith("__")
        }
    if isinstance(message, np.ndarray):
        return message.tolist()
    if isinstance(message, list):
        return [to_contents(item) for item in message]
    return message


def serialize(typename: str, contents: Mapping[str, Any]) -> bytes:
    """CDR bytes (with the 4-byte encapsulation header, as ROS 2 puts on the wire and in bags)."""
    return bytes(typestore().serialize_cdr(to_ros(typename, contents), typename))


def deserialize(typename: str, data: bytes) -> dict[str, Any]:
    """Message contents from CDR bytes."""
    return to_contents(typestore().deserialize_cdr(data, typename))
