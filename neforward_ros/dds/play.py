"""``neforward play``: a rosbag2 recording's topics, or a CSV of joint states, published over Cyclone
DDS with the original timing, as ``ros2 bag play`` does: what feeds ``neforward run`` (or any ROS 2
node) without ROS.

Messages go out as recorded (the bytes of the recording, header stamps unchanged), each at its
recording time relative to the first, divided by ``rate``. ``robot_description`` (and any topic
whose name ends so) is published transient local, as robot_state_publisher does, so a node that
starts later still gets the model; its first message goes out before the others and before
``delay``, which gives a node time to load the model. The DDS domain is ROS_DOMAIN_ID's (cyclonedds alone ignores it).

A CSV has one row per joint state: a ``stamp_ns`` or ``t[s]`` column, then per joint a column named
after it (its position, rad or m), and optionally ``<joint>.velocity`` and ``<joint>.effort``
columns. With ``stamp_ns`` the messages carry those stamps; with ``t[s]`` they carry the time of
publication.
"""

from __future__ import annotations

import csv
import logging
import sys
import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from neforward_ros.errors import InputError
from neforward_ros.interface import topics as node_topics
from neforward_ros.stamps import NS, time_message
from neforward_ros.wire import cdr

DISCOVERY_WAIT = 2.0
"""s: at most this long for the first subscriber of each topic before the first message goes out."""


@dataclass(frozen=True)
class Recorded:
    """One message to play: its time (ns; only differences count), topic, type and CDR bytes; or,
    for a CSV row stamped when it is published, no bytes and the message's other fields (``row``)."""

    time_ns: int
    topic: str
    typename: str
    payload: bytes | None
    row: dict[str, Any] | None = None


def play(
    path: str | Path,
    rate: float = 1.0,
    loop: bool = False,
    topics: Sequence[str] | None = None,
    csv_topic: str = "/joint_states",
    delay: float = 0.0,
) -> int:
    """Publish until the end (or, with ``loop``, until Ctrl-C). Returns 0.

    Raises:
        InputError: no such file, not a recording or CSV, no topic to play, a bad rate.
    """
    import math

    if not (math.isfinite(rate) and rate > 0):
        raise InputError(f"--rate must be a positive number, got {rate}")
    if not (math.isfinite(delay) and delay >= 0):
        raise InputError(f"--delay must be a number of seconds, at least 0, got {delay}")
    source = Path(path)
    if not source.exists():
        raise InputError(f"no such file or directory: {source}")
    is_csv = source.suffix.lower() == ".csv"
    channels = _csv_channels(csv_topic) if is_csv else _recording_channels(source, topics)
    from cyclonedds.domain import DomainParticipant
    from cyclonedds.pub import DataWriter
    from cyclonedds.topic import Topic

    from neforward_ros.dds.domain import domain_id
    from neforward_ros.dds.qos import default_qos, latched_qos
    from neforward_ros.dds.types import dds_type, raw_sample

    domain = domain_id()
    participant = DomainParticipant(domain)
    writers = {}
    for topic, typename in channels.items():
        qos = latched_qos(typename) if _latched(topic) else default_qos(typename, depth=100)
        writers[topic] = DataWriter(participant, Topic(participant, "rt" + topic, dds_type(typename)), qos=qos)
    listing = ", ".join(f"{t} ({k})" for t, k in sorted(channels.items()))
    print(f"neforward play: {source} on DDS domain {domain}: {listing}", file=sys.stderr, flush=True)
    deadline = time.monotonic() + DISCOVERY_WAIT
    while time.monotonic() < deadline and not all(
        w.get_publication_matched_status().current_count for w in writers.values()
    ):
        time.sleep(0.05)
    played = 0
    started = time.monotonic()
    # The model first: a latched topic's first message goes out now, before the delay, so that a
    # node has it (and time to load it) before the first joint state.
    early = set()
    if not is_csv:
        for topic in channels:
            if _latched(topic):
                first = next(_recording_messages(source, {topic: channels[topic]}), None)
                if first is not None:
                    writers[topic].write(raw_sample(first.typename, first.payload))
                    early.add((first.time_ns, topic))
                    played += 1
    time.sleep(delay)
    while True:
        messages = _csv_messages(source, csv_topic) if is_csv else _recording_messages(source, channels)
        origin: int | None = None
        begin = time.monotonic()
        for message in messages:
            if (message.time_ns, message.topic) in early:
                early.discard((message.time_ns, message.topic))
                continue
            origin = message.time_ns if origin is None else origin
            due = begin + (message.time_ns - origin) / NS / rate
            pause = due - time.monotonic()
            if pause > 0:
                time.sleep(pause)
            payload = message.payload
            if payload is None:  # a CSV row stamped now
                row = dict(message.row or {})
                row["header"] = {"stamp": time_message(time.time_ns())}
                payload = cdr.encode(message.typename, row)
            writers[message.topic].write(raw_sample(message.typename, payload))
            played += 1
        if not loop or origin is None:
            break
    seconds = time.monotonic() - started
    print(f"neforward play: {played} messages in {seconds:.1f} s", file=sys.stderr, flush=True)
    time.sleep(0.2)  # let reliable writers hand over the last messages before the participant goes
    return 0


def _latched(topic: str) -> bool:
    return topic.rstrip("/").endswith("robot_description")


def _recording_channels(source: Path, wanted: Sequence[str] | None) -> dict[str, str]:
    from neforward_ros.dds.types import dds_type

    reader = _open(source)
    try:
        available = {c.topic: c.msgtype for c in reader.connections}
    finally:
        reader.close()
    if wanted:
        unknown = [t for t in wanted if t not in available]
        if unknown:
            listing = ", ".join(sorted(available)) or "none"
            raise InputError(f"{source} has no topic {', '.join(unknown)}; topics: {listing}")
        available = {t: available[t] for t in wanted}
    channels = {}
    for topic, typename in available.items():
        try:
            dds_type(typename)
        except Exception:  # a type that is not in ROS 2 Jazzy's common interfaces
            logging.getLogger("neforward_ros").warning(f"{topic}: type {typename} unknown here; not played")
            continue
        channels[topic] = typename
    if not channels:
        raise InputError(f"{source}: no topic of a known type to play")
    return channels


def _open(source: Path) -> Any:
    from rosbags.rosbag2 import Reader

    try:
        reader = Reader(source)
        reader.open()
    except Exception as exc:
        raise InputError(f"{source} is not a readable rosbag2 recording: {exc}") from exc
    return reader


def _recording_messages(source: Path, channels: dict[str, str]) -> Iterator[Recorded]:
    reader = _open(source)
    try:
        connections = [c for c in reader.connections if c.topic in channels]
        for connection, log_time, raw in reader.messages(connections=connections):
            yield Recorded(log_time, connection.topic, connection.msgtype, bytes(raw))
    finally:
        reader.close()


def _csv_channels(topic: str) -> dict[str, str]:
    return {topic: node_topics.JOINT_STATE_TYPE}


def _csv_messages(source: Path, topic: str) -> Iterator[Recorded]:
    with source.open(newline="") as stream:
        rows = csv.reader(stream)
        header = next(rows, None)
        if not header:
            raise InputError(f"{source} is empty")
        header = [h.strip() for h in header]
        if "stamp_ns" in header:
            clock = header.index("stamp_ns")
        elif "t[s]" in header:
            clock = header.index("t[s]")
        else:
            raise InputError(f"{source}: the CSV needs a stamp_ns or t[s] column; it has {', '.join(header)}")
        joints = [h for k, h in enumerate(header) if k != clock and "." not in h and h not in ("stamp_ns", "t[s]")]
        if not joints:
            raise InputError(f"{source}: no joint position columns")
        columns = {h: k for k, h in enumerate(header)}
        for number, row in enumerate(rows, start=2):
            if not row:
                continue
            try:
                values = {h: float(row[k]) for h, k in columns.items() if k < len(row) and row[k].strip()}
                clock_value = float(row[clock])
            except ValueError as exc:
                raise InputError(f"{source} line {number}: {exc}") from exc
            contents = {
                "name": joints,
                "position": [values.get(j, float("nan")) for j in joints],
                "velocity": [values[f"{j}.velocity"] for j in joints]
                if all(f"{j}.velocity" in values for j in joints)
                else [],
                "effort": [values[f"{j}.effort"] for j in joints]
                if all(f"{j}.effort" in values for j in joints)
                else [],
            }
            if header[clock] == "stamp_ns":
                stamp = int(row[clock])
                contents["header"] = {"stamp": time_message(stamp)}
                yield Recorded(
                    stamp, topic, node_topics.JOINT_STATE_TYPE, cdr.encode(node_topics.JOINT_STATE_TYPE, contents)
                )
            else:
                yield Recorded(round(clock_value * NS), topic, node_topics.JOINT_STATE_TYPE, None, contents)
