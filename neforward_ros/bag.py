"""Offline: rosbag2 recordings of joint states in, the node's outputs out (rosbag2, CSV, plot).

``neforward bag INPUT -o OUTPUT`` reads a rosbag2 recording (sqlite3 or MCAP) with rosbags, no ROS
needed, estimates every joint's velocity and acceleration with the whole-recording (non-causal)
estimator, runs the batched recursion, and writes a new recording with the node's topics, types
and stamps. Stamps that go backwards split the recording into segments, each estimated on its own.
Nothing half-written is ever left under the output names: files are written under a temporary
name and renamed at the end.
"""

from __future__ import annotations

import itertools
import os
import shutil
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from neforward_ros import cdr, messages
from neforward_ros.dds.names import NodeNames
from neforward_ros.derivatives import (
    DEFAULT_MAX_GAP,
    DEFAULT_ORDER,
    DEFAULT_WINDOW,
    VELOCITY_SOURCES,
    estimate_at,
)
from neforward_ros.errors import InputError, ModelError
from neforward_ros.model import RobotModel, load_model
from neforward_ros.pipeline import COM_STATES, LINK_STATES, Result, make_result, output_list, per_link_messages
from neforward_ros.recursion import DEFAULT_GRAVITY, forward_recursion
from neforward_ros.rostypes import typestore

STORAGES = ("mcap", "sqlite3")
_NS = 1_000_000_000


@dataclass(frozen=True)
class BagOptions:
    """What to compute and write; the defaults are the node's.

    Attributes:
        urdf: URDF file; None takes the model from the recording's robot_description topic.
        joint_states_topic: None picks the recording's sensor_msgs/JointState topic.
        storage: output storage, ``mcap`` or ``sqlite3``.
        accel_links, imu_links: links that also get <link>/accel, <link>/twist and <link>/imu.
        gravity: m/s^2 in the root frame.
        method, window, order: the whole-recording estimator's.
        velocity_source: ``auto`` uses recorded velocities where every sample of a joint has one.
        max_gap: s; stamps further than this from a joint's samples get no output.
        frame_prefix: prepended to frame_ids.
    """

    urdf: str | None = None
    joint_states_topic: str | None = None
    storage: str = "mcap"
    accel_links: tuple[str, ...] = ()
    imu_links: tuple[str, ...] = ()
    gravity: tuple[float, float, float] = DEFAULT_GRAVITY
    method: str = "polyfit"
    window: float = DEFAULT_WINDOW
    order: int = DEFAULT_ORDER
    velocity_source: str = "auto"
    max_gap: float = DEFAULT_MAX_GAP
    frame_prefix: str = ""


@dataclass
class Segment:
    """A stretch of the recording whose stamps increase; estimated on its own."""

    first_ns: int
    last_ns: int
    messages: int
    samples_out: int = 0
    skipped: int = 0
    note: str = ""


@dataclass
class BagReport:
    """What a run did."""

    joint_states_topic: str
    messages: int
    samples_out: int = 0
    segments: list[Segment] = field(default_factory=list)
    zero_stamps: int = 0
    ignored_names: list[str] = field(default_factory=list)
    topics: list[str] = field(default_factory=list)
    seconds: float = 0.0


@dataclass
class _Batch:
    """All outputs of the recording, concatenated over segments."""

    result: Result
    log_times: np.ndarray


class Progress:
    """A progress bar on stderr, drawn only when stderr is a terminal."""

    def __init__(self, enabled: bool | None = None) -> None:
        self.enabled = sys.stderr.isatty() if enabled is None else enabled
        self._last = 0.0

    def __call__(self, what: str, fraction: float) -> None:
        if not self.enabled:
            return
        now = time.monotonic()
        if fraction < 1.0 and now - self._last < 0.1:
            return
        self._last = now
        filled = int(30 * min(max(fraction, 0.0), 1.0))
        sys.stderr.write(f"\r{what:<12} [{'#' * filled}{'.' * (30 - filled)}] {100 * fraction:5.1f}%")
        if fraction >= 1.0:
            sys.stderr.write("\n")
        sys.stderr.flush()


def process_bag(
    input_path: str | Path,
    output_path: str | Path,
    options: BagOptions | None = None,
    *,
    csv_path: str | Path | None = None,
    plot_path: str | Path | None = None,
    progress: Callable[[str, float], None] | None = None,
) -> BagReport:
    """Compute the node's outputs for a whole recording and write them.

    Raises:
        InputError: no such file, not a rosbag2 recording, no joint-state topic (the message lists
            the topics), joints of the model missing from the recording, a corrupt recording, an
            output that exists already.
        ModelError: an invalid URDF.
    """
    started = time.monotonic()
    options = options if options is not None else BagOptions()
    _check_options(options)
    progress = progress if progress is not None else Progress(False)
    source, output = Path(input_path), Path(output_path)
    if not source.exists():
        raise InputError(f"no such file or directory: {source}")
    for path in (output, csv_path, plot_path):
        if path is not None and Path(path).exists():
            raise InputError(f"{path} exists already; remove it or choose another name")
    if plot_path is not None:
        try:
            import matplotlib  # noqa: F401
        except ImportError as exc:
            raise InputError("--plot needs matplotlib: pip install 'neforward_ros[plot]' (or matplotlib)") from exc
    recording = _read(source, options, progress)
    model = recording.model
    for link in (*options.accel_links, *options.imu_links):
        if link not in model.link_index:
            raise InputError(f"link {link!r} is not in robot {model.name!r}")
    batch = _compute(recording, options, progress)
    report = recording.report
    report.samples_out = len(batch.log_times)
    if report.samples_out == 0:
        raise InputError("no output: no stretch of the recording has enough samples of every joint")
    report.topics = _write_bag(output, batch, options, progress)
    if csv_path is not None:
        _atomic(Path(csv_path), lambda path: write_csv(path, batch.result, model))
    if plot_path is not None:
        _atomic(Path(plot_path), lambda path: write_plot(path, batch.result, model, options.gravity))
    report.seconds = time.monotonic() - started
    return report


# -- reading ----------------------------------------------------------------------------------


@dataclass
class _Recording:
    model: RobotModel
    report: BagReport
    stamps: np.ndarray  # (M,) int64 ns, per message
    log_times: np.ndarray  # (M,) int64 ns
    columns: dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]]  # joint -> (message index, q, v)


def _read(source: Path, options: BagOptions, progress: Callable[[str, float], None]) -> _Recording:
    from rosbags.rosbag2 import Reader

    try:
        reader = Reader(source)
        reader.open()
    except Exception as exc:  # rosbags raises several kinds of exception for "not a bag"
        if (source / "metadata.yaml").exists() or source.suffix in (".mcap", ".db3"):
            raise InputError(f"{source} is truncated or corrupt: {exc}") from exc
        raise InputError(f"{source} is not a readable rosbag2 recording: {exc}") from exc
    try:
        topic = _joint_states_topic(reader, options.joint_states_topic, source)
        model = _model(reader, options.urdf)
        connections = [c for c in reader.connections if c.topic == topic]
        total = max(sum(c.msgcount for c in connections), 1)
        report = BagReport(joint_states_topic=topic, messages=0)
        stamps, log_times = [], []
        names_ids: list[int] = []  # per message: which names tuple
        positions_list: list[np.ndarray] = []
        velocities_list: list[np.ndarray] = []
        name_tuples: dict[tuple[str, ...], int] = {}
        try:
            for index, (_, log_time, raw) in enumerate(reader.messages(connections=connections)):
                stamp, names, positions, velocities = cdr.decode_joint_state(raw)
                if len(positions) != len(names):
                    continue  # a malformed message, as the node would drop it
                if stamp == 0:
                    stamp = log_time
                    report.zero_stamps += 1
                names_ids.append(name_tuples.setdefault(names, len(name_tuples)))
                positions_list.append(positions)
                velocities_list.append(velocities)
                stamps.append(stamp)
                log_times.append(log_time)
                if index % 2048 == 0:
                    progress("reading", index / total)
        except InputError as exc:
            raise InputError(f"{source}: corrupt joint state message: {exc}") from exc
        except Exception as exc:  # truncated or corrupt storage
            raise InputError(f"{source} is truncated or corrupt: {type(exc).__name__}: {exc}") from exc
        progress("reading", 1.0)
    finally:
        reader.close()
    report.messages = len(stamps)
    columns, unknown = _columns(model, name_tuples, np.asarray(names_ids), positions_list, velocities_list)
    report.ignored_names = sorted(unknown)
    missing = [model.joint_names[j] for j in range(len(model.joint_names)) if j not in columns]
    if missing:
        raise InputError(f"joints of robot {model.name!r} missing from {topic}: {', '.join(missing)}")
    return _Recording(model, report, np.asarray(stamps, dtype=np.int64), np.asarray(log_times, dtype=np.int64), columns)


def _columns(
    model: RobotModel,
    name_tuples: dict[tuple[str, ...], int],
    names_ids: np.ndarray,
    positions: list[np.ndarray],
    velocities: list[np.ndarray],
) -> tuple[dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]], set[str]]:
    """Per model joint: (message indices, positions, velocities or NaN), from messages grouped by names."""
    known = model.joint_index
    ignored = set(model.mimic_joint_names)
    parts: dict[int, list[tuple[np.ndarray, np.ndarray, np.ndarray]]] = {}
    unknown: set[str] = set()
    for names, group in name_tuples.items():
        rows = np.nonzero(names_ids == group)[0]
        block = np.stack([positions[i] for i in rows])
        width = len(names)
        speeds = np.full((len(rows), width), np.nan)
        with_velocity = [k for k, i in enumerate(rows) if len(velocities[i]) == width]
        if with_velocity:
            speeds[with_velocity] = np.stack([velocities[rows[k]] for k in with_velocity])
        for k, name in enumerate(names):
            j = known.get(name)
            if j is None:
                if name not in ignored:
                    unknown.add(name)
                continue
            parts.setdefault(j, []).append((rows, block[:, k], speeds[:, k]))
    columns = {}
    for j, pieces in parts.items():
        rows, qs, vs = (np.concatenate(x) for x in zip(*pieces, strict=True))
        order = np.argsort(rows, kind="stable")
        columns[j] = (rows[order], qs[order], vs[order])
    return columns, unknown


def _joint_states_topic(reader: Any, wanted: str | None, source: Path) -> str:
    topics = {c.topic: c.msgtype for c in reader.connections}
    listing = ", ".join(f"{name} ({kind})" for name, kind in sorted(topics.items())) or "none"
    if wanted is not None:
        if topics.get(wanted) != messages.JOINT_STATE_TYPE:
            raise InputError(f"{source} has no {messages.JOINT_STATE_TYPE} topic {wanted}; topics: {listing}")
        return wanted
    candidates = sorted(name for name, kind in topics.items() if kind == messages.JOINT_STATE_TYPE)
    if not candidates:
        raise InputError(f"{source} has no {messages.JOINT_STATE_TYPE} topic; topics: {listing}")
    if len(candidates) > 1:
        if "/joint_states" in candidates:
            return "/joint_states"
        raise InputError(
            f"{source} has several joint-state topics ({', '.join(candidates)}); choose one with --joint-states"
        )
    return candidates[0]


def _model(reader: Any, urdf: str | None) -> RobotModel:
    if urdf is not None:
        return load_model(urdf)
    connections = [
        c for c in reader.connections if c.msgtype == messages.STRING_TYPE and c.topic.endswith("robot_description")
    ]
    text = None
    for _, _, raw in reader.messages(connections=connections):
        text = typestore().deserialize_cdr(raw, messages.STRING_TYPE).data
    if text is None:
        raise InputError("no --urdf given and no robot_description topic in the recording")
    try:
        return load_model(text)
    except ModelError as exc:
        raise ModelError(f"the recording's robot_description: {exc}") from exc


# -- computing --------------------------------------------------------------------------------


def _segments(recording: _Recording) -> list[tuple[int, int]]:
    """Message index ranges [start, stop) within which every joint's stamps increase."""
    stamps = recording.stamps
    breaks = set()
    for rows, _, _ in recording.columns.values():
        joint_stamps = stamps[rows]
        backwards = np.nonzero(np.diff(joint_stamps) < 0)[0]
        breaks.update(int(rows[k + 1]) for k in backwards)
    edges = [0, *sorted(breaks), len(stamps)]
    return [(a, b) for a, b in itertools.pairwise(edges) if b > a]


def _compute(recording: _Recording, options: BagOptions, progress: Callable[[str, float], None]) -> _Batch:
    model = recording.model
    wrap = model.continuous_columns
    pieces: list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]] = []
    ranges = _segments(recording)
    for number, (start, stop) in enumerate(ranges):
        progress("estimating", number / len(ranges))
        segment_stamps = recording.stamps[start:stop]
        segment = Segment(int(segment_stamps.min()), int(segment_stamps.max()), stop - start)
        recording.report.segments.append(segment)
        targets, first = np.unique(segment_stamps, return_index=True)
        origin = int(targets[0])
        target_s = (targets - origin) / _NS
        state = np.full((3, len(targets), len(model.joint_names)), np.nan)
        # Each joint's own samples; joints with the same sample times and kind are estimated together.
        groups: dict[tuple[bytes, bool], list[tuple[int, np.ndarray, np.ndarray]]] = {}
        for j, (rows, qs, vs) in recording.columns.items():
            inside = (rows >= start) & (rows < stop) & np.isfinite(qs)
            t_ns, keep = np.unique(recording.stamps[rows[inside]], return_index=True)
            if len(t_ns) < 3:
                segment.note = f"fewer than 3 samples of {model.joint_names[j]}"
                break
            q = qs[inside][keep]
            if wrap[j]:
                q = np.unwrap(q)
            v = vs[inside][keep]
            use_velocity = options.velocity_source != "differentiate" and bool(np.all(np.isfinite(v)))
            groups.setdefault((t_ns.tobytes(), use_velocity), []).append((j, q, v))
        if segment.note:
            segment.skipped = len(targets)
            continue
        for (t_bytes, use_velocity), members in groups.items():
            t = (np.frombuffer(t_bytes, dtype=np.int64) - origin) / _NS
            joints = [j for j, _, _ in members]
            q_at, qd_at, qdd_at = estimate_at(
                t,
                np.stack([q for _, q, _ in members], axis=1),
                target_s,
                velocity=np.stack([v for _, _, v in members], axis=1) if use_velocity else None,
                method=options.method,
                window=options.window,
                order=options.order,
            )
            stale = _gap_to_samples(t, target_s) > options.max_gap
            for column, values in enumerate((q_at, qd_at, qdd_at)):
                values[stale] = np.nan
                state[column][:, joints] = values
        if segment.note:
            segment.skipped = len(targets)
            continue
        ok = np.all(np.isfinite(state), axis=(0, 2))
        segment.skipped = int(np.count_nonzero(~ok))
        segment.samples_out = int(np.count_nonzero(ok))
        log_times = recording.log_times[start:stop][first]
        pieces.append((targets[ok], log_times[ok], state[0][ok], state[1][ok], state[2][ok]))
    progress("estimating", 1.0)
    if not pieces:
        stamps = np.zeros(0, dtype=np.int64)
        zeros = np.zeros((0, len(model.joint_names)))
        pieces = [(stamps, stamps, zeros, zeros, zeros)]
    stamps, log_times, q, qd, qdd = (np.concatenate(parts) for parts in zip(*pieces, strict=True))
    kinematics = forward_recursion(model, q, qd, qdd, gravity=options.gravity)
    result = make_result(model, stamps, kinematics, {"positions": q, "velocities": qd, "accelerations": qdd})
    return _Batch(result, log_times)


def _gap_to_samples(t: np.ndarray, targets: np.ndarray) -> np.ndarray:
    """Seconds from each target to the nearest sample."""
    after = np.minimum(np.searchsorted(t, targets), len(t) - 1)
    before = np.maximum(after - 1, 0)
    return np.minimum(np.abs(t[after] - targets), np.abs(targets - t[before]))


# -- writing ----------------------------------------------------------------------------------


def output_topics(options: BagOptions) -> list[tuple[str, str]]:
    """(topic, type) of every output: the node's, resolved in the root namespace."""
    names = NodeNames()
    return [(names.resolve(o.topic), o.type) for o in output_list(options.accel_links, options.imu_links, False)]


def _write_bag(output: Path, batch: _Batch, options: BagOptions, progress: Callable[[str, float], None]) -> list[str]:
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
        template = cdr.encode(messages.LINK_STATES_TYPE, builder(first, prefix))
        rows[names.resolve(topic)] = cdr.patch_multi_dof(template, result.stamp_ns, *blocks(result))
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


def _atomic(path: Path, write: Callable[[Path], None]) -> None:
    partial = path.with_name(f".{path.name}.partial-{os.getpid()}{path.suffix}")
    try:
        write(partial)
        partial.rename(path)
    except BaseException:
        partial.unlink(missing_ok=True)
        raise


CSV_FIELDS = (
    ("omega", "rad/s", "root"),
    ("alpha", "rad/s^2", "root"),
    ("accel", "m/s^2", "root"),
    ("com_accel", "m/s^2", "root"),
)


def write_csv(path: Path, result: Result, model: RobotModel) -> None:
    """One row per sample: stamp, then per link omega, alpha, accel and com_accel (x, y, z).

    The header names each column's link, quantity, frame, component and unit, e.g.
    ``panda_hand.accel_in_root.z[m/s^2]``: vectors along the root frame's axes. accel and com_accel
    are specific forces (a - g), as in the node's messages.
    """
    root = result.in_root
    stamps = np.asarray(result.stamp_ns, dtype=np.int64)
    names = ["stamp_ns", "t[s]"]
    blocks = []
    for link_index, link in enumerate(model.link_names):
        for quantity, unit, frame in CSV_FIELDS:
            names += [f"{link}.{quantity}_in_{frame}.{axis}[{unit}]" for axis in "xyz"]
            blocks.append(getattr(root, quantity)[:, link_index, :])
    values = np.concatenate([((stamps - stamps[0]) / _NS)[:, None], *blocks], axis=1)
    with path.open("w") as stream:
        stream.write(",".join(names) + "\n")
        text = np.char.mod("%.9g", values)
        for stamp, row in zip(stamps.tolist(), text.tolist(), strict=True):
            stream.write(f"{stamp}," + ",".join(row) + "\n")


def write_plot(path: Path, result: Result, model: RobotModel, gravity: tuple[float, float, float]) -> None:
    """PNG: every link's |a| (kinematic, gravity removed) and |alpha| over time, peaks marked and labelled."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    root = result.in_root
    stamps = np.asarray(result.stamp_ns, dtype=np.int64)
    t = (stamps - stamps[0]) / _NS
    accel = np.linalg.norm(root.accel + np.asarray(gravity), axis=-1)
    alpha = np.linalg.norm(root.alpha, axis=-1)
    figure, axes = plt.subplots(2, 1, figsize=(13, 8), sharex=True)
    for axis, values, label in ((axes[0], accel, "|a| [m/s^2]"), (axes[1], alpha, "|alpha| [rad/s^2]")):
        axis.set_prop_cycle(color=plt.cm.tab20.colors)  # tens of links: more colours than the default 10
        for k, link in enumerate(model.link_names):
            if not np.any(values[:, k] > 0):
                continue
            line = axis.plot(t, values[:, k], linewidth=0.8, label=link)[0]
            peak = int(np.argmax(values[:, k]))
            axis.plot(t[peak], values[peak, k], "o", color=line.get_color(), markersize=4)
        # Label the three highest distinct peaks; links moving as one (rigidly attached) share one label.
        labelled: list[tuple[float, float]] = []
        for k in np.argsort(values.max(axis=0))[::-1]:
            peak = int(np.argmax(values[:, k]))
            value = float(values[peak, k])
            if value <= 0 or len(labelled) == 3:
                break
            if any(abs(value - v) <= 1e-9 * max(1.0, v) and t[peak] == at for v, at in labelled):
                continue
            same = sum(
                1 for other in range(values.shape[1]) if other != k and np.allclose(values[:, other], values[:, k])
            )
            extra = f" (and {same} more links)" if same else ""
            axis.annotate(
                f"{model.link_names[k]}{extra}: {value:.3g} at {t[peak]:.2f} s",
                (t[peak], value),
                textcoords="offset points",
                xytext=(5, 5 + 10 * len(labelled)),
                fontsize=8,
            )
            labelled.append((value, t[peak]))
        axis.set_ylabel(label)
        axis.grid(True, alpha=0.3)
    axes[0].set_title(f"{model.name}: link accelerations (peaks marked)")
    axes[1].set_xlabel("time since first sample [s]")
    axes[0].legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    figure.tight_layout()
    figure.savefig(path, format="png", dpi=100)
    plt.close(figure)


def _check_options(options: BagOptions) -> None:
    if options.storage not in STORAGES:
        raise InputError(f"unknown storage {options.storage!r}; choose {' or '.join(STORAGES)}")
    if options.velocity_source not in VELOCITY_SOURCES:
        raise InputError(f"unknown velocity_source {options.velocity_source!r}")


def describe(report: BagReport) -> str:
    """The report as a few lines for the terminal."""
    lines = [
        f"{report.messages} joint states from {report.joint_states_topic}; {report.samples_out} samples written "
        f"to {', '.join(report.topics)} in {report.seconds:.1f} s",
    ]
    if len(report.segments) > 1:
        lines.append(
            f"{len(report.segments)} segments (stamps went backwards between them), each estimated on its own:"
        )
    for number, segment in enumerate(report.segments, 1):
        span = (segment.last_ns - segment.first_ns) / _NS
        note = (
            f"; skipped: {segment.note}"
            if segment.note
            else (f"; {segment.skipped} stamps without output" if segment.skipped else "")
        )
        lines.append(f"  segment {number}: {segment.messages} messages over {span:.3f} s{note}")
    if report.zero_stamps:
        lines.append(f"{report.zero_stamps} messages had a zero header.stamp: their recording time was used")
    if report.ignored_names:
        lines.append(f"ignored joint names not in the model: {', '.join(report.ignored_names)}")
    return "\n".join(lines)
