"""Reading a rosbag2 recording (sqlite3 or MCAP) with rosbags: the model and every joint's samples."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from neforward_ros.bag import mcap_read
from neforward_ros.bag.options import BagOptions
from neforward_ros.bag.report import BagReport
from neforward_ros.computation.base_motion import BaseMessage, base_message
from neforward_ros.errors import InputError, ModelError
from neforward_ros.estimation.joint_messages import describe_names, name_map
from neforward_ros.estimation.timeline import sort_out
from neforward_ros.interface import topics
from neforward_ros.logs import ThrottledLog
from neforward_ros.model import RobotModel, load_model
from neforward_ros.stamps import NS
from neforward_ros.wire import cdr
from neforward_ros.wire.rostypes import deserialize


@dataclass
class BaseRecording:
    """A recording's base topic (sensor_msgs/Imu or nav_msgs/Odometry), decoded, in recording order.

    Attributes:
        topic: its name.
        messages: each message as the node's base tracker takes it (its recording time as the
            receive time).
        log_times: (N,) their recording times.
    """

    topic: str
    messages: list[BaseMessage]
    log_times: np.ndarray

    @property
    def frame_id(self) -> str:
        """The frame the messages measure (the first one that names one)."""
        return next((m.frame_id for m in self.messages if m.frame_id), "")


@dataclass
class Recording:
    model: RobotModel
    report: BagReport
    stamps: np.ndarray  # (M,) int64 ns, per message
    log_times: np.ndarray  # (M,) int64 ns
    columns: dict[int, tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]  # joint -> (message index, q, v, effort)
    base: BaseRecording | None = None  # the base topic (a moving base)


def read(source: Path, options: BagOptions, progress: Callable[[str, float], None]) -> Recording:
    settings = options.settings
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
        warnings: list[str] = []
        model = _model(reader, options.urdf, settings.root_link, settings.robot_description, warnings.append)
        connections = [c for c in reader.connections if c.topic == topic]
        total = max(sum(c.msgcount for c in connections), 1)
        report = BagReport(joint_states_topic=topic, messages=0, notes=warnings)
        raws: list[bytes] = []
        log_times: Any = []
        try:
            fast = mcap_read.messages(reader, connections)
            if fast is not None:
                raws, log_times = fast
            else:
                for index, (_, log_time, raw) in enumerate(reader.messages(connections=connections)):
                    raws.append(raw)
                    log_times.append(log_time)
                    if index % 2048 == 0:
                        progress("reading", index / total)
            decoded = cdr.decode_joint_states(raws)
        except InputError as exc:
            raise InputError(f"{source}: corrupt joint state message: {exc}") from exc
        except Exception as exc:  # truncated or corrupt storage
            raise InputError(f"{source} is truncated or corrupt: {type(exc).__name__}: {exc}") from exc
        base = read_base(reader, options)
        progress("reading", 1.0)
    finally:
        reader.close()
    # The node's rules for each message: malformed ones (names and positions of different lengths,
    # a name given twice) are dropped, and the stamps sorted out (strays dropped, time resets begin
    # segments, a zero stamp among stamped ones dropped; in a stream without stamps the recording
    # time stands in for them).
    keep = np.ones(len(raws), dtype=bool)
    keep[decoded.malformed] = False
    ignored = frozenset(model.mimic_joint_names)
    joints_of: list[tuple[int, ...]] = [()] * len(raws)
    unknown: dict[str, None] = {}
    pairs: dict[tuple[str, ...], tuple[tuple[int, int], ...]] = {}
    for names, (indices, *_) in decoded.groups.items():
        mapped = name_map(names, model.joint_index, ignored)
        if mapped.duplicate is not None:
            keep[indices] = False
            report.notes.append(f"{len(indices)} message(s) name joint {mapped.duplicate!r} more than once: dropped")
            continue
        unknown.update(dict.fromkeys(mapped.unknown))
        pairs[names] = mapped.pairs
        message_joints = tuple(j for _, j in mapped.pairs)
        for m in indices.tolist():
            joints_of[m] = message_joints
    times = np.asarray(log_times, dtype=np.int64)
    gap_ns = round(settings.estimator.max_gap * NS)
    usable = np.flatnonzero(keep & np.array([bool(j) for j in joints_of], dtype=bool))
    said: list[str] = []
    log = ThrottledLog(lambda level, message: said.append(message), period=float("inf"))
    kept, used, segment = sort_out(
        decoded.stamps[usable], times[usable], [joints_of[m] for m in usable], len(model.joint_names), gap_ns, log
    )
    chosen = usable[kept]
    if len(chosen) < len(raws):
        report.notes.append(
            f"{len(raws) - len(chosen)} joint state message(s) dropped by the node's rules (malformed, naming no "
            f"joint of the model, or out of line with the stream's stamps); the first of each kind:"
        )
    report.notes += said
    report.zero_stamps = int(np.count_nonzero(decoded.stamps[chosen] <= 0))
    renumber = np.full(len(raws), -1, dtype=np.int64)
    renumber[chosen] = np.arange(len(chosen))
    stamps, times = used[kept], times[chosen]
    report.messages = len(stamps)
    if not len(stamps):
        what = "no messages" if not raws else f"no usable messages ({len(raws)}: malformed, or naming no joint)"
        raise InputError(f"{topic} in {source} has {what}: nothing to compute")
    columns = _columns(decoded, renumber, pairs)
    report.ignored_names = describe_names(unknown, "names") if unknown else ""
    report.segment_starts = np.flatnonzero(np.diff(segment[kept]) != 0) + 1
    missing = [model.joint_names[j] for j in range(len(model.joint_names)) if j not in columns]
    report.missing_joints = missing
    report.held = {name: float(settings.hold_positions.get(name, 0.0)) for name in missing}
    return Recording(settings.model_of(model), report, stamps, times, columns, base)


def _columns(
    decoded: cdr.JointStateBatch, renumber: np.ndarray, pairs: dict[tuple[str, ...], tuple[tuple[int, int], ...]]
) -> dict[int, tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]:
    """Per model joint: (message indices among the kept ones, positions, velocities or NaN, efforts or
    NaN), from the messages grouped by names; ``renumber`` maps a message to its kept index (-1:
    dropped), ``pairs`` a list of names to its (position in the message, joint index) pairs."""
    parts: dict[int, list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]] = {}
    for names, (indices, positions, velocities, efforts) in decoded.groups.items():
        rows = renumber[indices]
        kept = rows >= 0
        if names not in pairs or not kept.any():
            continue
        for k, j in pairs[names]:
            parts.setdefault(j, []).append((rows[kept], positions[kept, k], velocities[kept, k], efforts[kept, k]))
    out = {}
    for j, pieces in parts.items():
        rows, qs, vs, es = (np.concatenate(x) for x in zip(*pieces, strict=True))
        order = np.argsort(rows, kind="stable")
        out[j] = (rows[order], qs[order], vs[order], es[order])
    return out


def _joint_states_topic(reader: Any, wanted: str | None, source: Path) -> str:
    available = {c.topic: c.msgtype for c in reader.connections}
    listing = ", ".join(f"{name} ({kind})" for name, kind in sorted(available.items())) or "none"
    if wanted is not None:
        if available.get(wanted) != topics.JOINT_STATE_TYPE:
            raise InputError(f"{source} has no {topics.JOINT_STATE_TYPE} topic {wanted}; topics: {listing}")
        return wanted
    candidates = sorted(name for name, kind in available.items() if kind == topics.JOINT_STATE_TYPE)
    if not candidates:
        raise InputError(f"{source} has no {topics.JOINT_STATE_TYPE} topic; topics: {listing}")
    if len(candidates) > 1:
        if "/joint_states" in candidates:
            return "/joint_states"
        raise InputError(
            f"{source} has several joint-state topics ({', '.join(candidates)}); choose one with --joint-states"
        )
    return candidates[0]


def _model(
    reader: Any, urdf: str | None, root_link: str | None, description: str, warn: Callable[[str], None]
) -> RobotModel:
    def log(level: int, message: str) -> None:
        warn(message)

    if urdf is not None:
        return load_model(urdf, root_link=root_link, log=log)
    if description:  # the robot_description parameter of a params file
        return load_model(description, root_link=root_link, log=log)
    connections = [
        c for c in reader.connections if c.msgtype == topics.STRING_TYPE and c.topic.endswith("robot_description")
    ]
    text = None
    if connections:  # (no connections would mean every message of the recording to rosbags)
        for _, _, raw in reader.messages(connections=connections):
            text = cdr.decode_string(raw)
    if text is None:
        raise InputError(
            "no --urdf given and no robot_description topic in the recording: give the URDF with --urdf FILE"
        )
    try:
        return load_model(text, root_link=root_link, log=log)
    except ModelError as exc:
        raise ModelError(f"the recording's robot_description: {exc}") from exc


def read_base(reader: Any, options: BagOptions) -> BaseRecording | None:
    """The base topic's messages (None for a fixed base).

    Raises:
        InputError: no such topic in the recording (the message lists what there is), or no usable message.
    """
    settings = options.settings
    source = settings.base_source
    if source == "fixed":
        return None
    kind = topics.IMU_TYPE if source == "imu" else topics.ODOMETRY_TYPE
    available = {c.topic: c.msgtype for c in reader.connections}
    topic = options.base_topic
    if topic is None:
        candidates = sorted(name for name, msgtype in available.items() if msgtype == kind)
        named = "/" + settings.base_topic.lstrip("/")  # the node's base.topic, in the root namespace
        if len(candidates) > 1 and named in candidates:
            candidates = [named]
        if len(candidates) != 1:
            listing = ", ".join(f"{n} ({t})" for n, t in sorted(available.items())) or "none"
            raise InputError(f"--base {source} needs one {kind} topic (--base-topic to choose); topics: {listing}")
        topic = candidates[0]
    if available.get(topic) != kind:
        raise InputError(f"the recording has no {kind} topic {topic}")
    messages, times = [], []
    for _, log_time, raw in reader.messages(connections=[c for c in reader.connections if c.topic == topic]):
        messages.append(base_message(source, deserialize(kind, raw), log_time))
        times.append(log_time)
    if len(messages) < 3:
        raise InputError(f"the base topic {topic} has fewer than 3 messages")
    return BaseRecording(topic, messages, np.asarray(times, dtype=np.int64))
