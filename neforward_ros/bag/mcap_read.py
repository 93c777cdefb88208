"""A topic's messages from an MCAP recording, read straight from rosbags' chunk index: the joint states
of a long recording in a fraction of the time of ``Reader.messages`` (which yields one message at a
time through a merge of per-chunk generators).

It gives what ``Reader.messages(connections=...)`` gives, in the same order (by recording time, then
by chunk, then by position in the chunk; tested), and uses rosbags' chunk index, decompression and
checks, so it is taken only with the rosbags releases it was checked against (those of the fast
writing path, :data:`neforward_ros.bag.write.FAST_MCAP_ROSBAGS`); with any other, or any other
storage, the caller reads through ``Reader.messages``.
"""

from __future__ import annotations

import struct
from collections.abc import Collection
from typing import Any

import numpy as np

_RECORD = struct.Struct("<BQ")  # opcode, length
_MESSAGE = struct.Struct("<HIQQ")  # channel, sequence, log time, publish time


def messages(reader: Any, connections: Collection[Any]) -> tuple[list[bytes], np.ndarray] | None:
    """(data, recording times) of the connections' messages, or None where this cannot read them."""
    from neforward_ros.bag.write import fast_mcap_allowed

    storage = getattr(reader, "storage", None)
    if not fast_mcap_allowed() or storage is None:
        return None
    if type(storage).__name__ == "DirectoryReader":  # a rosbag2 folder: its files one after the other
        if storage.metadata.compression_mode == "message":
            return None
        files = [(file, _matching(file, connections)) for file in storage.storages]
    else:
        files = [(storage, {c.id for c in connections})]
    datas: list[bytes] = []
    times: list[np.ndarray] = []
    for file, wanted in files:
        if not wanted:
            continue
        if type(file).__name__ != "McapReader" or not getattr(file, "chunks", None):
            return None
        part = _file_messages(file, wanted)
        datas += part[0]
        times.append(part[1])
    return datas, (np.concatenate(times) if times else np.zeros(0, dtype=np.int64))


def _matching(file: Any, connections: Collection[Any]) -> set[int]:
    """The ids, in one file of a folder, of the folder's connections (as rosbags matches them)."""
    return {
        x.id
        for x in file.connections
        if any(
            y.topic == x.topic and y.msgtype == x.msgtype and y.ext == x.ext
            and (not x.digest or not y.digest or y.digest == x.digest)
            for y in connections
        )
    }  # fmt: skip


def _file_messages(storage: Any, wanted: set[int]) -> tuple[list[bytes], np.ndarray]:
    from rosbags.rosbag2 import storage_mcap

    bio = storage.bio
    found: list[tuple[int, int, int, bytes]] = []  # (log time, chunk offset, position, data)
    for chunk in storage.chunks:
        if not any(chunk.channel_count.get(cid, 0) for cid in wanted):
            continue
        bio.seek(chunk.chunk_start_offset + 9 + 24)
        crc = struct.unpack("<I", storage_mcap.read_exact(bio, 4))[0]
        bio.seek(chunk.chunk_start_offset + 9 + 40 + len(chunk.compression))
        data = storage_mcap.decompress(
            storage_mcap.read_exact(bio, chunk.compressed_size), chunk.compression, chunk.uncompressed_size, crc
        )
        view = memoryview(data)
        position, end = 0, chunk.uncompressed_size
        offset = chunk.chunk_start_offset
        while position < end:
            opcode, length = _RECORD.unpack_from(view, position)
            position += 9
            if opcode == 0x05:
                channel, _, log_time, _ = _MESSAGE.unpack_from(view, position)
                if channel in wanted:
                    found.append((log_time, offset, position, bytes(view[position + 22 : position + length])))
            position += length
    found.sort(key=lambda m: (m[0], m[1], m[2]))
    return [m[3] for m in found], np.array([m[0] for m in found], dtype=np.int64)
