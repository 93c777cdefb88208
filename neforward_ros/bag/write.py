"""Writing the results as a rosbag2 recording (MCAP or sqlite3) with the node's topics, types and stamps."""

from __future__ import annotations

import os
import shutil
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from neforward_ros.bag.compute import Batch
from neforward_ros.bag.options import BagOptions
from neforward_ros.node import messages, topics
from neforward_ros.node.messages import per_link_messages
from neforward_ros.node.names import NodeNames
from neforward_ros.node.topics import COM_STATES, LINK_STATES, output_list
from neforward_ros.wire import cdr
from neforward_ros.wire.rostypes import typestore


def output_topics(options: BagOptions) -> list[tuple[str, str]]:
    """(topic, type) of every output: the node's, resolved in the root namespace."""
    names = NodeNames()
    return [(names.resolve(o.topic), o.type) for o in output_list(options.accel_links, options.imu_links, False)]


def write_bag(output: Path, batch: Batch, options: BagOptions, progress: Callable[[str, float], None]) -> list[str]:
    from rosbags.rosbag2 import StoragePlugin, Writer

    result = batch.result
    count = len(batch.log_times)
    first = result.sample(0)
    prefix = options.frame_prefix
    names = NodeNames()
    rows: dict[str, Any] = {}
    for topic, builder, blocks in (
        (LINK_STATES, messages.link_states, messages.link_states_blocks),
        (COM_STATES, messages.com_states, messages.com_states_blocks),
    ):
        template = cdr.encode(topics.LINK_STATES_TYPE, builder(first, prefix))
        rows[names.resolve(topic)] = cdr.MultiDofTemplate(template).encode_many(result.stamp_ns, *blocks(result))
    per_link = bool(options.accel_links or options.imu_links)
    storage = StoragePlugin.MCAP if options.storage == "mcap" else StoragePlugin.SQLITE3
    # Written inside a temporary folder under its final name (rosbag2 names the storage file after
    # the folder), then moved into place: no half-written recording under the output name.
    staging = output.with_name(f".{output.name}.partial-{os.getpid()}")
    if staging.exists():
        shutil.rmtree(staging)
    staging.mkdir(parents=True)
    partial = staging / output.name
    try:
        writer = Writer(partial, version=9, storage_plugin=storage)
        with writer:
            store = typestore()
            connections = {
                topic: writer.add_connection(topic, kind, typestore=store) for topic, kind in output_topics(options)
            }
            log_times = batch.log_times.tolist()
            streams = [(connections[topic], data) for topic, data in rows.items()]
            batched = not per_link and _FAST_MCAP and _write_rows_mcap(writer, streams, batch.log_times, progress)
            flat = [(connection, memoryview(data.reshape(-1)), data.shape[1]) for connection, data in streams]
            for i in range(0 if batched else count):
                for connection, view, size in flat:
                    writer.write(connection, log_times[i], view[i * size : (i + 1) * size])
                if per_link:
                    sample = result.sample(i)
                    for topic, contents in per_link_messages(sample, options.accel_links, options.imu_links, prefix):
                        connection = connections[names.resolve(topic)]
                        writer.write(connection, log_times[i], cdr.encode(connection.msgtype, contents))
                if i % 2048 == 0:
                    progress("writing", i / count)
        progress("writing", 1.0)
        partial.rename(output)
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    return [topic for topic, _ in output_topics(options)]


_FAST_MCAP = True  # tests turn it off to compare with rosbags' own per-message writing
_CHUNK_BYTES = 2**20  # as rosbags' MCAP writer


def _write_rows_mcap(
    writer: Any, streams: list[tuple[Any, np.ndarray]], log_times: np.ndarray, progress: Callable[[str, float], None]
) -> bool:
    """Write equal-length messages straight into rosbags' MCAP chunks, many at a time.

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
    for k, (_, data) in enumerate(streams):
        fields += [(f"op{k}", "u1"), (f"length{k}", "<u8"), (f"channel{k}", "<u2"), (f"sequence{k}", "<u4")]
        fields += [(f"log{k}", "<u8"), (f"publish{k}", "<u8"), (f"data{k}", "u1", (data.shape[1],))]
    record = np.dtype(fields)
    starts = [record.fields[f"op{k}"][1] for k in range(len(streams))]
    count = len(log_times)
    per_chunk = max(1, _CHUNK_BYTES // record.itemsize)
    for first in range(0, count, per_chunk):
        part = slice(first, min(count, first + per_chunk))
        times = np.asarray(log_times[part], dtype=np.int64)
        block = np.empty(len(times), dtype=record)
        for k, (connection, data) in enumerate(streams):
            block[f"op{k}"] = 0x05
            block[f"length{k}"] = 2 + 4 + 8 + 8 + data.shape[1]
            block[f"channel{k}"] = connection.id
            block[f"sequence{k}"] = 0
            block[f"log{k}"] = times
            block[f"publish{k}"] = times
            block[f"data{k}"] = data[part]
        chunk = storage.chunk
        base = chunk.bio.tell()
        chunk.bio.write(block.tobytes())
        offsets = base + np.arange(len(times), dtype=np.int64) * record.itemsize
        stamps = times.tolist()
        for k, (connection, _) in enumerate(streams):
            chunk.msgs[connection.id].extend(zip(stamps, (offsets + starts[k]).tolist(), strict=True))
            storage.channel_stats[connection.id] += len(stamps)
            writer.counts[connection.id] += len(stamps)
        low, high = int(times.min()), int(times.max())
        chunk.message_start_time = min(chunk.message_start_time, low)
        chunk.message_end_time = max(chunk.message_end_time, high)
        storage.message_start_time = min(storage.message_start_time, low)
        storage.message_end_time = max(storage.message_end_time, high)
        writer.min_timestamp = min(writer.min_timestamp, low)
        writer.max_timestamp = max(writer.max_timestamp, high)
        if chunk.bio.tell() > _CHUNK_BYTES:
            storage.close_chunk()
        progress("writing", part.stop / count)
    return True


def atomic(path: Path, write: Callable[[Path], None]) -> None:
    partial = path.with_name(f".{path.name}.partial-{os.getpid()}{path.suffix}")
    try:
        write(partial)
        partial.rename(path)
    except BaseException:
        partial.unlink(missing_ok=True)
        raise
