"""ROS 2 message types as Cyclone DDS types, derived from the rosbags ROS 2 Jazzy definitions.

ROS 2 type ``pkg/msg/T`` is DDS type ``pkg::msg::dds_::T_`` with the same members in the same
order, serialized as plain CDR (XCDR1), as rmw_cyclonedds does. Nothing is hand-mirrored: each
struct is built from the rosbags type store's field definitions on first use.
"""

from __future__ import annotations

from functools import cache
from typing import Any

from cyclonedds.idl import IdlStruct, make_idl_struct
from cyclonedds.idl import types as idl

from neforward_ros.wire.rostypes import facts

_BASE = {
    "bool": bool,
    "byte": idl.uint8,
    "char": idl.uint8,
    "uint8": idl.uint8,
    "int8": idl.int8,
    "uint16": idl.uint16,
    "int16": idl.int16,
    "uint32": idl.uint32,
    "int32": idl.int32,
    "uint64": idl.uint64,
    "int64": idl.int64,
    "float32": idl.float32,
    "float64": idl.float64,
}


def dds_type_name(typename: str) -> str:
    """``pkg/msg/T`` -> ``pkg::msg::dds_::T_``."""
    package, kind, name = typename.split("/")
    return f"{package}::{kind}::dds_::{name}_"


def type_hash(typename: str) -> str:
    """The ROS 2 type hash (``RIHS01_<hex>``) of a message type, as ROS 2 Jazzy computes it."""
    return facts(typename)["rihs01"]


@cache
def dds_type(typename: str) -> type[IdlStruct]:
    """The Cyclone DDS struct class of a ROS 2 message type."""
    definitions = facts(typename)["fields"]
    members = {
        name: _member_type(nodetype, description, definitions)
        for name, (nodetype, description) in definitions[typename]
    }
    if not members:  # an empty ROS message has one uint8 placeholder member on the wire
        members = {"structure_needs_at_least_one_member": idl.uint8}
    class_name = typename.replace("/", "_")
    return make_idl_struct(class_name, dds_type_name(typename), members)


def _member_type(nodetype: Any, description: Any, definitions: Any) -> Any:
    kind = int(nodetype)  # rosbags Nodetype: BASE 1, NAME 2, ARRAY 3, SEQUENCE 4
    if kind == 2:
        return dds_type(description)
    if kind == 1:
        base, bound = description
        if base == "string":
            return idl.bounded_str[bound] if bound else str
        return _BASE[base]
    (element_type, element_description), length = description
    element = _member_type(element_type, element_description, definitions)
    if kind == 3:
        return idl.array[element, length]
    return idl.sequence[element, length] if length else idl.sequence[element]


def raw_sample(typename: str, payload: bytes) -> Any:
    """A sample of the DDS type of ``typename`` that writes the given CDR bytes as they are.

    cyclonedds' DataWriter.write calls ``sample.serialize()``; this sample answers with bytes
    already encoded by :mod:`neforward_ros.cdr` (the same layout, several times faster).
    """
    sample = object.__new__(dds_type(typename))
    sample.serialize = lambda use_version_2=None, endianness=None: payload
    return sample


class RawBytes(bytes):
    """A sample taken as its CDR bytes (with the encapsulation header); ``sample_info`` is set on it."""


class _RawDecoder:
    """Stands in for a DDS type on the Python side of a reader: hands samples over undecoded."""

    @staticmethod
    def deserialize(data: bytes) -> RawBytes:
        return RawBytes(data)

    @staticmethod
    def deserialize_key(data: bytes) -> RawBytes:
        return RawBytes(data)


def raw_reader(participant: Any, topic_name: str, typename: str, qos: Any, listener: Any = None) -> Any:
    """A DataReader of ``typename`` on DDS topic ``topic_name`` whose take() returns CDR bytes.

    The DDS type (name, key, type information) is the real one; only the Python-side decoding is
    skipped, so the caller can decode with a faster decoder or only the part it needs.
    """
    from cyclonedds.sub import DataReader
    from cyclonedds.topic import Topic

    topic = Topic(participant, topic_name, dds_type(typename))
    reader = DataReader(participant, topic, qos=qos, listener=listener)
    topic.data_type = _RawDecoder
    return reader
