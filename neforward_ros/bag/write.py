"""Writing the results as a rosbag2 recording (MCAP or sqlite3) with the node's topics, types and stamps."""

from __future__ import annotations

import functools
import os
import shutil
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from neforward_ros.bag.background_file import BackgroundFile
from neforward_ros.bag.options import BagOptions
from neforward_ros.computation.result import Observation, Result, make_result
from neforward_ros.interface import encoder
from neforward_ros.interface.messages import (
    dynamics_messages,
    observation_messages,
    per_link_messages,
    world_link_states,
)
from neforward_ros.interface.names import NodeNames
from neforward_ros.interface.topics import COM_STATES, LINK_STATES, WORLD_LINK_STATES, output_list
from neforward_ros.kinematics.forward_kernel import ROW
from neforward_ros.model import RobotModel
from neforward_ros.wire import cdr
from neforward_ros.wire.rostypes import facts


def output_topics(options: BagOptions) -> list[tuple[str, str]]:
    """(topic, type) of every output: the node's, resolved in the root namespace."""
    settings = options.settings
    names = NodeNames()
    outputs = output_list(
        settings.accel_links,
        settings.imu_links,
        False,
        settings.publish_torques,
        settings.wrench_links,
        bool(settings.contact_thresholds),
        settings.world_states,
        bool(settings.contact_link),
        settings.publish_joint_estimates,
    )
    return [(names.resolve(o.topic), o.type) for o in outputs]


def staging_folder(output: Path) -> Path:
    """Where a recording is written before it is moved to ``output``: a hidden name of this process."""
    return output.with_name(f".{output.name}.partial-{os.getpid()}")


class RecordingWriter:
    """A rosbag2 recording written chunk by chunk, inside a staging folder until :meth:`finish`.

    rosbag2 names the storage file after the recording's folder, so the recording is written in
    ``<staging>/<name>`` and moved to its place by the caller once everything else is written too.

    Args:
        output: the recording's final path (its parent must exist).
        options: topics and storage.
        model: the robot (per-link topics name its links).
    """

    def __init__(self, output: Path, options: BagOptions, model: RobotModel) -> None:
        from rosbags.rosbag2 import StoragePlugin, Writer

        settings = options.settings
        self.options = options
        self.names = NodeNames()
        self.staging = staging_folder(output)
        if self.staging.exists():
            shutil.rmtree(self.staging)
        self.staging.mkdir()
        self.path = self.staging / output.name
        storage = StoragePlugin.MCAP if options.storage == "mcap" else StoragePlugin.SQLITE3
        try:  # until the caller holds this writer, an error or a Ctrl-C here is this writer's to clean up
            self.writer = Writer(self.path, version=9, storage_plugin=storage)
            self.writer.open()
            if options.storage == "mcap" and fast_mcap_allowed():  # the file written by a thread of its own
                self.writer.storage.bio = BackgroundFile(self.writer.storage.bio)
            self.connections = {
                topic: self.writer.add_connection(
                    topic, kind, msgdef=facts(kind)["msgdef"], rihs01=facts(kind)["rihs01"]
                )
                for topic, kind in output_topics(options)
            }
        except BaseException:
            _close_quietly(self.writer if hasattr(self, "writer") else None)
            shutil.rmtree(self.staging, ignore_errors=True)
            raise
        self.topics = [topic for topic, _ in output_topics(options)]
        self.model = model
        self._templates = encoder.Templates(settings.frame_prefix)
        self._multi_dof = [self.connections[self.names.resolve(topic)] for topic in (LINK_STATES, COM_STATES)]

    def reserve(self, stamps: int) -> None:
        """Have the storage file allocated ahead for link_states and com_states at ``stamps`` stamps, while
        the estimates are computed (on a tmpfs the allocation is most of the writing); only a hint, for
        the MCAP file written by its own thread."""
        bio = getattr(getattr(self.writer, "storage", None), "bio", None)
        if not isinstance(bio, BackgroundFile):
            return
        model = self.model
        blank = make_result(model, 0, np.zeros((len(model.link_names), ROW)))
        # Per stamp and topic: the message's record (31 bytes and the message) and its index entry (16).
        bio.reserve(stamps * sum(31 + len(template.template) + 16 for template in self._templates(blank)))

    def write(self, result: Result, log_times: np.ndarray) -> None:
        """One chunk of results, each recorded at its joint state's recording time; samples where only
        some links are determined carry those links only (runs of samples alike are written together)."""
        for part, run in result.runs():
            self._write_run(run, log_times[part])

    def _write_run(self, result: Result, log_times: np.ndarray) -> None:
        options, names = self.options, self.names
        settings = options.settings
        prefix = settings.frame_prefix
        messages = list(zip(self._multi_dof, self._templates(result), result.blocks, strict=True))
        world = settings.world_states
        per_sample = bool(
            settings.accel_links or settings.imu_links or options.dynamics_needed or world
            or settings.publish_joint_estimates
        )  # fmt: skip
        if not per_sample and _FAST_MCAP and fast_mcap_allowed():
            stamps = result.stamp_ns
            rows = [
                (connection, len(template.template), _encoder(template, stamps, blocks))
                for connection, template, blocks in messages
            ]
            if _write_rows_mcap(self.writer, rows, log_times):
                return
        streams = [
            (connection, template.encode_many(result.stamp_ns, *blocks)) for connection, template, blocks in messages
        ]
        times = log_times.tolist()
        flat = [(connection, memoryview(data.reshape(-1)), data.shape[1]) for connection, data in streams]
        for i, log_time in enumerate(times):
            for connection, view, size in flat:
                self.writer.write(connection, log_time, view[i * size : (i + 1) * size])
            if per_sample:
                sample = result.sample(i)
                rest = []
                if world and sample.world is not None:
                    rest.append((WORLD_LINK_STATES, world_link_states(sample, settings.world_frame, settings.gravity)))
                rest += per_link_messages(sample, settings.accel_links, settings.imu_links, prefix)
                rest += dynamics_messages(sample, settings.publish_torques, settings.wrench_links, prefix)
                for topic, contents in rest:
                    connection = self.connections[names.resolve(topic)]
                    self.writer.write(connection, log_time, cdr.encode(connection.msgtype, contents))

    def write_observations(self, observation: Observation, log_times: np.ndarray, start: int, until: int | None) -> int:
        """The momentum observer's messages of samples ``start`` on, up to recording time ``until``
        (None: to the end); returns the index of the first sample not written."""
        stop = len(log_times) if until is None else int(np.searchsorted(log_times, until, side="right"))
        settings, names = self.options.settings, self.names
        times = log_times.tolist()
        for i in range(start, stop):
            for topic, contents in observation_messages(observation.sample(i), settings):
                connection = self.connections[names.resolve(topic)]
                self.writer.write(connection, times[i], cdr.encode(connection.msgtype, contents))
        return max(stop, start)

    def counts(self) -> dict[str, int]:
        """Messages written so far, per topic (every output topic, in :attr:`topics` order)."""
        return {topic: int(self.writer.counts.get(self.connections[topic].id, 0)) for topic in self.topics}

    def finish(self) -> Path:
        """Close the recording; returns where it is (inside the staging folder)."""
        self.writer.close()
        return self.path

    def discard(self) -> None:
        """Forget everything written (after an error or an interrupt)."""
        _close_quietly(self.writer)
        shutil.rmtree(self.staging, ignore_errors=True)


def _close_quietly(writer: Any) -> None:
    """Close a rosbags writer that may be half-written (it is deleted anyway), and its file's thread
    with it in any case."""
    if writer is None:
        return
    try:
        writer.close()
    except Exception:  # a half-written storage may not close cleanly
        pass
    bio = getattr(getattr(writer, "storage", None), "bio", None)
    if isinstance(bio, BackgroundFile) and not bio.closed:
        try:
            bio.close()
        except Exception:
            pass


_FAST_MCAP = True  # tests turn it off to compare with rosbags' own per-message writing
FAST_MCAP_ROSBAGS = frozenset({"0.11.9"})
"""rosbags releases whose MCAP writer internals the fast path was checked against (by the test that
compares its output with rosbags' own message-by-message writing). With any other release the bag
tool writes through ``Writer.write`` only: slower, never wrong."""


@functools.cache
def fast_mcap_allowed() -> bool:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("rosbags") in FAST_MCAP_ROSBAGS
    except PackageNotFoundError:
        return False


_CHUNK_BYTES = 2**20  # as rosbags' MCAP writer


Rows = Callable[[slice, np.ndarray], None]
"""Writes the messages of a slice of the stamps into the rows of bytes it is given (one per stamp)."""


def _encoder(template: cdr.MultiDofTemplate, stamps_ns: np.ndarray, blocks: tuple[np.ndarray, ...]) -> Rows:
    """The MultiDOF messages of ``template`` with these stamps and blocks (see ``encode_many``)."""

    def encode(part: slice, out: np.ndarray) -> None:
        template.encode_many(stamps_ns[part], *(b[part] for b in blocks), out=out)

    return encode


def _write_rows_mcap(writer: Any, messages: list[tuple[Any, int, Rows]], log_times: np.ndarray) -> bool:
    """Write messages of one size per topic, (connection, size in bytes, what writes them), one of each
    at every recording time, straight into rosbags' MCAP chunks, many at a time (only for the rosbags
    releases in :data:`FAST_MCAP_ROSBAGS`): each message is written into its record's bytes.

    Produces what rosbags' ``Writer.write`` produces message by message (message records of
    opcode 0x05 with channel id, sequence 0, log and publish time, data; the chunk's message
    index; the counts), at a fraction of the per-message cost. Returns False, writing nothing,
    when the writer is not the rosbags MCAP writer this was made for; the caller then writes one
    message at a time.
    """
    storage = getattr(writer, "storage", None)
    chunk = getattr(storage, "chunk", None)
    needed = (
        hasattr(storage, "close_chunk")
        and isinstance(getattr(storage, "channel_stats", None), dict)
        and all(hasattr(chunk, a) for a in ("bio", "msgs", "message_start_time", "message_end_time"))
        and isinstance(getattr(writer, "counts", None), dict)
        and hasattr(writer, "min_timestamp")
        and type(storage).__name__ == "McapWriter"
    )
    if not needed:
        return False
    fields = []
    for k, (_, size, _) in enumerate(messages):
        fields += [(f"op{k}", "u1"), (f"length{k}", "<u8"), (f"channel{k}", "<u2"), (f"sequence{k}", "<u4")]
        fields += [(f"log{k}", "<u8"), (f"publish{k}", "<u8"), (f"data{k}", "u1", (size,))]
    record = np.dtype(fields)
    starts = [record.fields[f"op{k}"][1] for k in range(len(messages))]
    count = len(log_times)
    per_chunk = max(1, _CHUNK_BYTES // record.itemsize)
    for first in range(0, count, per_chunk):
        part = slice(first, min(count, first + per_chunk))
        times = np.asarray(log_times[part], dtype=np.int64)
        block = np.empty(len(times), dtype=record)
        for k, (connection, size, write_rows) in enumerate(messages):
            block[f"op{k}"] = 0x05
            block[f"length{k}"] = 2 + 4 + 8 + 8 + size
            block[f"channel{k}"] = connection.id
            block[f"sequence{k}"] = 0
            block[f"log{k}"] = times
            block[f"publish{k}"] = times
            write_rows(part, block[f"data{k}"])
        chunk = storage.chunk
        base = chunk.bio.tell()
        chunk.bio.write(block.view(np.uint8))
        offsets = base + np.arange(len(times), dtype=np.int64) * record.itemsize
        for k, (connection, _, _) in enumerate(messages):
            index = chunk.msgs.get(connection.id)
            if not isinstance(index, _ArrayIndex):
                index = chunk.msgs[connection.id] = _ArrayIndex(index or ())
            index.add(times, offsets + starts[k])
            storage.channel_stats[connection.id] += len(times)
            writer.counts[connection.id] += len(times)
        low, high = int(times.min()), int(times.max())
        chunk.message_start_time = min(chunk.message_start_time, low)
        chunk.message_end_time = max(chunk.message_end_time, high)
        storage.message_start_time = min(storage.message_start_time, low)
        storage.message_end_time = max(storage.message_end_time, high)
        writer.min_timestamp = min(writer.min_timestamp, low)
        writer.max_timestamp = max(writer.max_timestamp, high)
        if chunk.bio.tell() > _CHUNK_BYTES:
            _close_chunk(storage)
    return True


class _ArrayIndex(list):
    """A chunk's message index of one channel, (log time, offset) pairs, kept as arrays for the
    batches written by :func:`_write_rows_mcap` after the pairs rosbags appended one by one (the list
    itself). Iterating yields every pair as Python ints, in writing order, as rosbags' own
    ``close_chunk`` expects; :func:`_close_chunk` takes the arrays as they are."""

    def __init__(self, pairs: Any = ()) -> None:
        super().__init__(pairs)
        self.batches: list[np.ndarray] = []

    def add(self, times: np.ndarray, offsets: np.ndarray) -> None:
        self.batches.append(np.stack([times, offsets], axis=1).astype("<u8"))

    def append(self, pair: Any) -> None:  # rosbags' message-by-message write, after batches
        self.batches.append(np.asarray([pair], dtype="<u8"))

    def pairs(self) -> np.ndarray:
        head = np.asarray(self[:], dtype="<u8").reshape(-1, 2)
        return np.concatenate([head, *self.batches]) if self.batches else head

    def __iter__(self) -> Any:
        return iter([tuple(pair) for pair in self.pairs().tolist()])

    def __len__(self) -> int:
        return list.__len__(self) + sum(len(b) for b in self.batches)

    def __bool__(self) -> bool:
        return len(self) > 0


def _close_chunk(storage: Any) -> None:
    """What rosbags' ``McapWriter.close_chunk`` writes (the chunk record, one message index record per
    channel, the chunk's index entry kept for the summary), with the message indexes written from
    arrays and the chunk's bytes written without intermediate copies. Uncompressed chunks only;
    compressed ones go through rosbags."""
    from io import BytesIO

    chunk = storage.chunk
    if storage.compression:
        storage.close_chunk()
        return
    data = chunk.bio.getbuffer()
    size = len(data)
    compression = storage.compression.encode()
    head = np.array([chunk.message_start_time, chunk.message_end_time, size], dtype="<u8").tobytes()
    body = head + (0).to_bytes(4, "little") + len(compression).to_bytes(4, "little") + compression
    body += size.to_bytes(8, "little")
    bio = storage.bio
    chunk_start = bio.tell()
    bio.write(b"\x06" + (len(body) + size).to_bytes(8, "little") + body)
    getattr(bio, "hand_over", bio.write)(data)  # the chunk's buffer, not written to again
    del data
    chunk_end = bio.tell()
    offsets: list[tuple[int, int]] = []
    for cid, index in chunk.msgs.items():
        pairs = index.pairs() if isinstance(index, _ArrayIndex) else np.asarray(index, dtype="<u8").reshape(-1, 2)
        offsets.append((cid, bio.tell()))
        payload = pairs.tobytes()
        record = cid.to_bytes(2, "little") + len(payload).to_bytes(4, "little")
        bio.write(b"\x07" + (len(record) + len(payload)).to_bytes(8, "little") + record)
        bio.write(payload)
    entry = BytesIO()
    entry.write(head[:16])
    entry.write(chunk_start.to_bytes(8, "little") + (chunk_end - chunk_start).to_bytes(8, "little"))
    entry.write((len(offsets) * 10).to_bytes(4, "little"))
    for cid, offset in offsets:
        entry.write(cid.to_bytes(2, "little") + offset.to_bytes(8, "little"))
    entry.write((bio.tell() - chunk_end).to_bytes(8, "little"))
    entry.write(len(compression).to_bytes(4, "little") + compression)
    entry.write(size.to_bytes(8, "little") + size.to_bytes(8, "little"))
    storage.chunks.append(entry)
    storage.chunk = type(chunk)(2**63 - 1, 0, BytesIO(), type(chunk.msgs)(list))
