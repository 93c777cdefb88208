"""Fast CDR encoding of message contents, generated from the ROS 2 Jazzy definitions.

:func:`encode` turns the message contents built by :mod:`neforward_ros.messages` (nested dicts and
lists, missing fields meaning their defaults) into the bytes ROS 2 puts on the wire and in bags:
the 4-byte encapsulation header (CDR, little endian) and the XCDR1 body. For each type, a
specialised Python encoder is generated once from the rosbags type store's field definitions: it
inlines nested structs and packs runs of equal primitives with one ``struct.pack``, which makes it
several times faster than building message objects and serializing them. The tests check its
bytes against rosbags' own serializer.
"""

from __future__ import annotations

import struct
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from functools import cache
from typing import Any

import numpy as np

from neforward_ros.errors import InputError
from neforward_ros.stamps import split_stamp
from neforward_ros.wire.rostypes import PRIMITIVES as _PRIMITIVES
from neforward_ros.wire.rostypes import facts

HEADER = b"\x00\x01\x00\x00"  # CDR_LE encapsulation, options 0
_STAMP = struct.Struct("<iI")
_F8 = np.dtype("<f8")  # builtin_interfaces/Time right after the encapsulation header

_ZEROS = tuple(b"\0" * n for n in range(8))
_EMPTY: Mapping[str, Any] = {}


def encode(typename: str, contents: Mapping[str, Any]) -> bytes:
    """CDR bytes (with the encapsulation header) of a message of ``typename`` (``pkg/msg/T``).

    Raises:
        InputError: an unknown type, or contents that do not fit it (wrong array length, a value
            of the wrong kind).
    """
    encoder = _encoder(typename)
    buffer = bytearray(HEADER)
    try:
        encoder(buffer, contents)
    except (struct.error, TypeError, AttributeError, UnicodeEncodeError) as exc:
        raise InputError(f"cannot encode {typename}: {exc}") from exc
    return bytes(buffer)


def warm_up(typename: str) -> None:
    """Generate the encoder of ``typename`` now (it is generated on first use otherwise)."""
    _encoder(typename)


@cache
def _encoder(typename: str) -> Callable[[bytearray, Mapping[str, Any]], None]:
    generator = _Generator(facts(typename)["fields"])
    generator.struct(typename, "v", 1)
    source = "def encode(buf, v):\n" + "\n".join(generator.lines) + "\n    return None\n"
    namespace: dict[str, Any] = {"_ZEROS": _ZEROS, "_EMPTY": _EMPTY, "_check_length": _check_length}
    namespace.update(generator.constants)
    exec(compile(source, f"<cdr encoder {typename}>", "exec"), namespace)
    return namespace["encode"]


def _check_length(values: Any, length: int, where: str) -> Any:
    if len(values) != length:
        raise InputError(f"{where} needs exactly {length} values, got {len(values)}")
    return values


class _Generator:
    """Emits the body of an encoder as Python source lines."""

    def __init__(self, definitions: Mapping[str, list]) -> None:
        self.definitions = definitions  # type name -> field definitions (rostypes.facts)
        self.lines: list[str] = []
        self.constants: dict[str, Any] = {}
        self._names = 0

    def _name(self, stem: str) -> str:
        self._names += 1
        return f"{stem}{self._names}"

    def _emit(self, depth: int, line: str) -> None:
        self.lines.append("    " * depth + line)

    def _align(self, depth: int, size: int) -> None:
        if size > 1:
            self._emit(depth, f"pad = (4 - len(buf)) & {size - 1}")
            self._emit(depth, "if pad: buf += _ZEROS[pad]")

    def _packer(self, code: str) -> str:
        name = f"_pack_{code}".replace("?", "bool")
        if name not in self.constants:
            self.constants[name] = struct.Struct("<" + code).pack
        return name

    def struct(self, typename: str, var: str, depth: int) -> None:
        """Code that appends the members of ``typename`` held in the dict named ``var``."""
        fields = self.definitions[typename]
        if not fields:
            self._emit(depth, "buf += b'\\x00'")
            return
        index = 0
        while index < len(fields):
            name, (nodetype, description) = fields[index]
            if int(nodetype) == 1 and description[0] in _PRIMITIVES:
                # a run of members of the same primitive type: one alignment, one pack
                run = [name]
                while (
                    index + len(run) < len(fields)
                    and int(fields[index + len(run)][1][0]) == 1
                    and fields[index + len(run)][1][1][0] == description[0]
                ):
                    run.append(fields[index + len(run)][0])
                code, size, default = _PRIMITIVES[description[0]]
                self._align(depth, size)
                packer = self._packer(str(len(run)) + code)
                args = ", ".join(f"{var}.get({member!r}, {default!r})" for member in run)
                self._emit(depth, f"buf += {packer}({args})")
                index += len(run)
                continue
            self.member(nodetype, description, f"{var}.get({name!r})", f"{typename}.{name}", depth)
            index += 1

    def member(self, nodetype: Any, description: Any, expression: str, where: str, depth: int) -> None:
        kind = int(nodetype)  # rosbags Nodetype: BASE 1, NAME 2, ARRAY 3, SEQUENCE 4
        if kind == 2:
            sub = self._name("s")
            self._emit(depth, f"{sub} = {expression}")
            self._emit(depth, f"if {sub} is None: {sub} = _EMPTY")
            self.struct(description, sub, depth)
            return
        if kind == 1:
            value = self._name("x")
            self._emit(depth, f"{value} = {expression}")
            self.primitive(description[0], value, depth)
            return
        (element_type, element_description), length = description
        items = self._name("items")
        if kind == 3:
            self._emit(depth, f"{items} = {expression}")
            self._emit(depth, f"if {items} is None: {items} = (None,) * {length}")
            self._emit(depth, f"_check_length({items}, {length}, {where!r})")
        else:
            self._emit(depth, f"{items} = {expression} or ()")
            self._align(depth, 4)
            self._emit(depth, f"buf += {self._packer('I')}(len({items}))")
        if int(element_type) == 1 and element_description[0] in _PRIMITIVES:
            code, size, default = _PRIMITIVES[element_description[0]]
            self._emit(depth, f"if {items}:")
            self._align(depth + 1, size)
            self._emit(
                depth + 1,
                f"buf += struct_pack('<%d{code}' % len({items}), *[{default!r} if e is None else e for e in {items}])",
            )
            self.constants["struct_pack"] = struct.pack
            return
        element = self._name("e")
        self._emit(depth, f"for {element} in {items}:")
        self.member(element_type, element_description, element, where, depth + 1)

    def primitive(self, base: str, value: str, depth: int) -> None:
        if base == "string":
            encoded = self._name("b")
            self._emit(depth, f"{encoded} = ({value} or '').encode()")
            self._align(depth, 4)
            self._emit(depth, f"buf += {self._packer('I')}(len({encoded}) + 1)")
            self._emit(depth, f"buf += {encoded}")
            self._emit(depth, "buf += b'\\x00'")
            return
        if base not in _PRIMITIVES:
            raise InputError(f"cannot encode {base!r} members (wstring is not used by these messages)")
        code, size, default = _PRIMITIVES[base]
        self._align(depth, size)
        self._emit(depth, f"buf += {self._packer('1' + code)}({default!r} if {value} is None else {value})")


@dataclass(frozen=True)
class MultiDofPoint:
    """The first point of a trajectory_msgs/MultiDOFJointTrajectory, as arrays.

    Attributes:
        stamp_ns: header stamp, integer nanoseconds.
        frame_id: header frame.
        joint_names: the names (link names for neforward's link_states / com_states).
        transforms: (n, 7): translation x, y, z, rotation x, y, z, w.
        velocities: (n, 6): linear x, y, z, angular x, y, z.
        accelerations: (n, 6): linear x, y, z, angular x, y, z.
        offsets: byte offsets of the three blocks in the encoded message.
    """

    stamp_ns: int
    frame_id: str
    joint_names: tuple[str, ...]
    transforms: np.ndarray
    velocities: np.ndarray
    accelerations: np.ndarray
    offsets: tuple[int, int, int]


def decode_multi_dof(data: bytes) -> MultiDofPoint:
    """Decode link_states / com_states CDR bytes into arrays, without building message objects.

    For readers that take thousands of these a second (the demo, the benchmarks, the tests).

    Raises:
        InputError: not a little-endian CDR MultiDOFJointTrajectory with at least one point.
    """
    if data[:2] != HEADER[:2]:
        raise InputError("not little-endian CDR (encapsulation 0x0001)")
    try:
        sec, nanosec = struct.unpack_from("<iI", data, 4)
        position = 12
        frame_id, position = _string(data, position)
        position += -(position - 4) & 3
        (count,) = struct.unpack_from("<I", data, position)
        position += 4
        names = []
        for _ in range(count):
            position += -(position - 4) & 3
            name, position = _string(data, position)
            names.append(name)
        position += -(position - 4) & 3
        (points,) = struct.unpack_from("<I", data, position)
        if points < 1:
            raise InputError("MultiDOFJointTrajectory without points")
        position += 4
        blocks, offsets = [], []
        for width in (7, 6, 6):
            position += -(position - 4) & 3
            (n,) = struct.unpack_from("<I", data, position)
            position += 4
            if n:
                position += -(position - 4) & 7
            block = np.frombuffer(data, dtype="<f8", count=n * width, offset=position).reshape(n, width)
            blocks.append(block)
            offsets.append(position)
            position += 8 * n * width
    except (struct.error, ValueError) as exc:
        raise InputError(f"truncated MultiDOFJointTrajectory: {exc}") from exc
    return MultiDofPoint(sec * 1_000_000_000 + nanosec, frame_id, tuple(names), *blocks, tuple(offsets))


_last_names: tuple[bytes, tuple[str, ...]] = (b"", ())


def _joint_state_layout(data: bytes) -> tuple[int, tuple[str, ...], list[tuple[int, int]]]:
    """(stamp ns, names, [(offset, count) of position, velocity, effort]) of JointState CDR bytes.

    When the names are byte for byte those of the previous message (the usual case), they are not
    decoded again.

    Raises:
        InputError: not little-endian CDR, truncated or malformed.
    """
    global _last_names
    if data[:2] != HEADER[:2]:
        raise InputError("not little-endian CDR (encapsulation 0x0001)")
    try:
        sec, nanosec = struct.unpack_from("<iI", data, 4)
        _, position = _string(data, 12)
        start = position + (-(position - 4) & 3)
        region, names = _last_names
        # the same names at the same alignment: reuse them
        if region and data.startswith(region, start):
            position = start + len(region)
        else:
            position = start
            (count,) = struct.unpack_from("<I", data, position)
            position += 4
            decoded = []
            for _ in range(count):
                name, position = _string(data, position)
                decoded.append(name)
            names = tuple(decoded)
            _last_names = (bytes(data[start:position]), names)
        fields = []
        for _ in range(3):
            position += -(position - 4) & 3
            (n,) = struct.unpack_from("<I", data, position)
            position += 4
            if n:
                position += -(position - 4) & 7
            if position + 8 * n > len(data):
                raise InputError(f"truncated JointState: {n} values at offset {position} of {len(data)} bytes")
            fields.append((position, n))
            position += 8 * n
    except (struct.error, ValueError, UnicodeDecodeError) as exc:
        raise InputError(f"truncated or malformed JointState: {exc}") from exc
    return sec * 1_000_000_000 + nanosec, names, fields


def decode_joint_state(data: bytes) -> tuple[int, tuple[str, ...], np.ndarray, np.ndarray, np.ndarray]:
    """(stamp ns, names, positions, velocities, efforts) of sensor_msgs/JointState CDR bytes, without
    message objects. Fields the message leaves empty are empty arrays.

    Raises:
        InputError: not little-endian CDR, truncated or malformed.
    """
    stamp, names, fields = _joint_state_layout(data)
    positions, velocities, efforts = (np.frombuffer(data, dtype="<f8", count=n, offset=o) for o, n in fields)
    return stamp, names, positions, velocities, efforts


@dataclass
class JointStateBatch:
    """Many JointState messages decoded at once: per list of names, the messages that carry it.

    Attributes:
        stamps: (M,) header stamps, integer nanoseconds, of every message (malformed ones too).
        groups: names -> (message indices, positions (k, n), velocities (k, n) with NaN where a
            message has none, efforts likewise).
        malformed: indices of messages whose names and positions differ in length (dropped, as the
            node drops them).
    """

    stamps: np.ndarray
    groups: dict[tuple[str, ...], tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]
    malformed: list[int]


def decode_joint_states(messages: Sequence[bytes]) -> JointStateBatch:
    """Decode a recording's JointState messages in bulk.

    Messages laid out byte for byte like the one before them up to their numbers (same frame_id,
    names and lengths: the usual case) are decoded together, as one numpy array of rows; the others
    one by one.

    Raises:
        InputError: a message that is not little-endian CDR, or truncated.
    """
    stamps = np.zeros(len(messages), dtype=np.int64)
    layouts: dict[tuple[int, bytes], tuple[tuple[str, ...], list[tuple[int, int]], list[int]]] = {}
    malformed: list[int] = []
    key: tuple[int, bytes] | None = None
    prefix_end = 0
    for index, data in enumerate(messages):
        if key is not None and len(data) == key[0] and data[12:prefix_end] == key[1]:
            layouts[key][2].append(index)
            continue
        _, names, fields = _joint_state_layout(data)
        if fields[0][1] != len(names):
            malformed.append(index)
            key = None
            continue
        prefix_end = fields[0][0]
        key = (len(data), bytes(data[12:prefix_end]))
        layouts.setdefault(key, (names, fields, []))[2].append(index)
    parts: dict[tuple[str, ...], list[tuple[np.ndarray, ...]]] = {}
    for (size, _), (names, fields, indices) in layouts.items():
        rows = np.frombuffer(b"".join(messages[i] for i in indices), dtype=np.uint8).reshape(len(indices), size)
        index = np.asarray(indices, dtype=np.int64)
        sec = rows[:, 4:8].copy().view("<i4")[:, 0].astype(np.int64)
        nanosec = rows[:, 8:12].copy().view("<u4")[:, 0].astype(np.int64)
        stamps[index] = sec * 1_000_000_000 + nanosec
        width = len(names)
        values = []
        for offset, n in fields:
            if n == width:
                values.append(rows[:, offset : offset + 8 * n].copy().view("<f8"))
            else:  # empty (or of another length: ignored, as the node ignores it)
                values.append(np.full((len(indices), width), np.nan))
        parts.setdefault(names, []).append((index, *values))
    groups = {}
    for names, pieces in parts.items():
        index, *values = (np.concatenate(x) for x in zip(*pieces, strict=True))
        order = np.argsort(index, kind="stable")
        groups[names] = (index[order], *(v[order] for v in values))
    for index in malformed:
        stamps[index] = _joint_state_layout(messages[index])[0]
    return JointStateBatch(stamps, groups, malformed)


def decode_string(data: bytes) -> str:
    """The text of a std_msgs/String, from its CDR bytes.

    Raises:
        InputError: not little-endian CDR, or truncated.
    """
    if data[:2] != HEADER[:2]:
        raise InputError("not little-endian CDR (encapsulation 0x0001)")
    try:
        return _string(data, 4)[0]
    except (struct.error, UnicodeDecodeError) as exc:
        raise InputError(f"truncated or malformed String: {exc}") from exc


def _string(data: bytes, position: int) -> tuple[str, int]:
    position += -(position - 4) & 3
    (length,) = struct.unpack_from("<I", data, position)
    start = position + 4
    if length < 1 or start + length > len(data):
        raise struct.error(f"string of {length} bytes at offset {position} runs past the end ({len(data)} bytes)")
    return data[start : start + length - 1].decode(), start + length


class MultiDofTemplate:
    """MultiDOFJointTrajectory messages that differ from one encoded message only in the header stamp
    and the numbers of the first point's transforms, velocities and accelerations.

    Made once per model and frame (the names, frame_id and counts are the template's); each message
    is then a copy of the template with the stamp and three blocks of numbers written in place,
    byte for byte what :func:`encode` gives for the same contents (tested).

    Args:
        template: one encoded message (one point, n transforms, velocities and accelerations).
    """

    def __init__(self, template: bytes) -> None:
        layout = decode_multi_dof(template)
        self.template = bytes(template)
        self.offsets = layout.offsets
        self.shapes = (layout.transforms.shape, layout.velocities.shape, layout.accelerations.shape)

    def encode(self, stamp_ns: int, transforms: np.ndarray, velocities: np.ndarray, accelerations: np.ndarray) -> bytes:
        """One message: stamp (ns) and blocks (n, 7), (n, 6), (n, 6)."""
        buffer = bytearray(self.template)
        _STAMP.pack_into(buffer, 4, *split_stamp(stamp_ns))
        for offset, shape, values in zip(
            self.offsets, self.shapes, (transforms, velocities, accelerations), strict=True
        ):
            if values.shape != shape or values.dtype != _F8:
                raise InputError(f"MultiDOFJointTrajectory block {values.shape} {values.dtype}, expected {shape} <f8")
            buffer[offset : offset + 8 * values.size] = values.tobytes()  # C order, whatever the strides
        return bytes(buffer)

    def encode_many(
        self,
        stamps_ns: np.ndarray,
        transforms: np.ndarray,
        velocities: np.ndarray,
        accelerations: np.ndarray,
        out: np.ndarray | None = None,
    ) -> np.ndarray:
        """Many messages at once: one row of bytes per stamp, (T,), (T, n, 7), (T, n, 6), (T, n, 6);
        written into ``out`` when given ((T, size) uint8 whose rows may lie apart, as the data of
        records), else into a new array."""
        count = len(stamps_ns)
        size = len(self.template)
        if out is None:
            out = np.empty((count, size), dtype=np.uint8)
        elif out.shape != (count, size) or out.dtype != np.uint8 or out.strides[-1] != 1:
            raise ValueError(f"out {out.shape} {out.dtype}: expected ({count}, {size}) uint8 rows")
        out[:] = np.frombuffer(self.template, dtype=np.uint8)
        stamps = np.asarray(stamps_ns, dtype=np.int64)
        sec, nanosec = np.divmod(stamps, 1_000_000_000)
        if count and (sec.min() < -(2**31) or sec.max() >= 2**31):
            raise InputError("a stamp is outside the range of builtin_interfaces/Time (int32 seconds)")
        out[:, 4:8].view("<i4")[:, 0] = sec
        out[:, 8:12].view("<u4")[:, 0] = nanosec
        for offset, shape, values in zip(
            self.offsets, self.shapes, (transforms, velocities, accelerations), strict=True
        ):
            if values.shape != (count, *shape):
                raise InputError(f"MultiDOFJointTrajectory blocks of shape {values.shape}, expected {(count, *shape)}")
            size = 8 * shape[0] * shape[1]
            # The numbers straight into each row's bytes (an unaligned view of them as doubles, rows apart).
            numbers = out[:, offset : offset + size].view("<f8")
            numbers = np.lib.stride_tricks.as_strided(numbers, (count, *shape), (numbers.strides[0], 8 * shape[1], 8))
            numbers[...] = values
        return out
