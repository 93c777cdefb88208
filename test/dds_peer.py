"""Test helpers for end-to-end runs over real Cyclone DDS on loopback: the node as a separate
process (``neforward run``), and a test participant that publishes and receives ROS 2 messages."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
from cyclonedds.core import InstanceState, ReadCondition, SampleState, ViewState, WaitSet
from cyclonedds.domain import DomainParticipant
from cyclonedds.pub import DataWriter
from cyclonedds.qos import Policy, Qos
from cyclonedds.topic import Topic
from cyclonedds.util import duration

from neforward_ros.dds.qos import default_qos, latched_qos
from neforward_ros.dds.types import RawBytes, dds_type, raw_reader, raw_sample
from neforward_ros.demo.live import stopped_counts
from neforward_ros.stamps import time_message
from neforward_ros.wire import cdr

STARTUP_TIMEOUT = 60.0


class NodeProcess:
    """``neforward run`` in its own process; output goes to a log file the test can read."""

    def __init__(self, arguments: list[str], log_path: Path, environment: dict[str, str]) -> None:
        self.log_path = log_path
        self._log = open(log_path, "w")
        command = [sys.executable, "-m", "neforward_ros", "run", *arguments]
        # SIGINT at its default whatever the suite inherited: stop() sends it as Ctrl-C would
        self.process = subprocess.Popen(
            command, stdout=self._log, stderr=subprocess.STDOUT, env=environment,
            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
        )  # fmt: skip

    def log(self) -> str:
        return self.log_path.read_text()

    def alive(self) -> bool:
        return self.process.poll() is None

    def stop(self, signal_number: int = 2, timeout: float = 10.0) -> int:
        if self.process.poll() is None:
            self.process.send_signal(signal_number)
            try:
                self.process.wait(timeout=timeout)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait()
        self._log.close()
        return self.process.returncode


class Peer:
    """The test's own participant: writers and raw readers by ROS 2 topic name."""

    def __init__(self, domain_id: int) -> None:
        self.participant = DomainParticipant(domain_id)
        self.waitset = WaitSet(self.participant)
        self.writers: dict[str, tuple[str, DataWriter]] = {}
        self.readers: dict[str, tuple[str, object]] = {}

    def writer(self, topic: str, typename: str, latched: bool = False) -> DataWriter:
        qos = latched_qos(typename) if latched else default_qos(typename, depth=1000)
        writer = DataWriter(self.participant, Topic(self.participant, "rt" + topic, dds_type(typename)), qos=qos)
        self.writers[topic] = (typename, writer)
        return writer

    def reader(self, topic: str, typename: str) -> None:
        qos = Qos(
            Policy.Reliability.Reliable(max_blocking_time=100_000_000),
            Policy.History.KeepLast(100_000),
            Policy.Durability.Volatile,
            Policy.DataRepresentation(use_cdrv0_representation=True),
        )
        reader = raw_reader(self.participant, "rt" + topic, typename, qos)
        self.readers[topic] = (typename, reader)
        self.waitset.attach(ReadCondition(reader, SampleState.Any | ViewState.Any | InstanceState.Any))

    def write(self, topic: str, contents: dict) -> None:
        typename, writer = self.writers[topic]
        writer.write(raw_sample(typename, cdr.encode(typename, contents)))

    def take(self, topic: str) -> list[bytes]:
        _, reader = self.readers[topic]
        out = []
        while True:
            batch = reader.take(N=1000)
            out += [bytes(b) for b in batch if isinstance(b, RawBytes)]  # not the writer-gone notices
            if len(batch) < 1000:
                return out

    def wait(self, seconds: float) -> None:
        self.waitset.wait(duration(seconds=seconds))

    def wait_connected(self, node: NodeProcess, timeout: float = STARTUP_TIMEOUT) -> None:
        """Until every writer and reader of this peer has matched the node's endpoints."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            assert node.alive(), f"node exited early:\n{node.log()}"
            writers_ok = all(w.get_publication_matched_status().current_count for _, w in self.writers.values())
            readers_ok = all(r.get_subscription_matched_status().current_count for _, r in self.readers.values())
            if writers_ok and readers_ok:
                time.sleep(0.3)  # the node's side of the match
                return
            time.sleep(0.05)
        raise AssertionError(f"node did not connect in {timeout} s:\n{node.log()}")

    def wait_disconnected(self, timeout: float = 15.0) -> None:
        """Until no endpoint of this peer is matched any more (the node process has gone)."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            counts = [w.get_publication_matched_status().current_count for _, w in self.writers.values()]
            counts += [r.get_subscription_matched_status().current_count for _, r in self.readers.values()]
            if not any(counts):
                return
            time.sleep(0.05)
        raise AssertionError(f"still matched after {timeout} s")


def joint_state(stamp_ns: int, names, positions, velocities=()) -> dict:
    return {
        "header": {"stamp": time_message(stamp_ns)},
        "name": list(names),
        "position": list(positions),
        "velocity": list(velocities),
    }


def loopback_env(domain_id: int, config_uri: str) -> dict[str, str]:
    environment = dict(os.environ)
    environment.update({"CYCLONEDDS_URI": config_uri, "ROS_DOMAIN_ID": str(domain_id)})
    return environment


def stream_arm(peer: Peer, simulated, rate: float, settle: float = 0.5) -> tuple:
    """Write a simulated arm's joint states (``examples/arm_simulator.py``) on /joint_states at
    ``rate`` Hz in real time, collecting what arrives on /neforward/contact (with its arrival time)
    and /neforward/external_torques meanwhile and for ``settle`` s after, and on while they arrive; (send times (T,),
    [(arrival, state)], [external torques' bytes])."""
    contact: list[tuple[float, bool]] = []
    external: list[bytes] = []
    watched = "/neforward/external_torques" in peer.readers

    def collect() -> None:
        now = time.monotonic()
        nonlocal external
        contact.extend((now, cdr_bool(b)) for b in peer.take("/neforward/contact"))
        if watched:
            arrived = peer.take("/neforward/external_torques")
            external += arrived
            arrivals.extend((now, header_stamp(b)) for b in arrived)

    arrivals.clear()
    sent = np.zeros(len(simulated.stamps))
    start = time.monotonic()
    for k, stamp in enumerate(simulated.stamps.tolist()):
        delay = start + k / rate - time.monotonic()
        if delay > 0:
            time.sleep(delay)
        peer.write("/joint_states", {
            "header": {"stamp": time_message(stamp)}, "name": simulated.names, "position": simulated.q[k].tolist(),
            "velocity": simulated.qd[k].tolist(), "effort": simulated.effort[k].tolist(),
        })  # fmt: skip
        sent[k] = time.monotonic()
        collect()
    # at least ``settle`` s; then until nothing has arrived for a second (a busy node runs seconds behind
    # the stream, and answers every message it took), at most a minute
    deadline, cap = time.monotonic() + settle, time.monotonic() + settle + 60.0
    while time.monotonic() < min(deadline, cap):
        peer.wait(0.05)
        before = len(contact) + len(external)
        collect()
        if len(contact) + len(external) > before:
            deadline = max(deadline, time.monotonic() + 1.0)
    return sent, contact, external


arrivals: list[tuple[float, int]] = []
"""(arrival time, header stamp ns) of the external torques the last :func:`stream_arm` received."""


def header_stamp(data: bytes) -> int:
    """A stamped message's header stamp, ns (CDR: the encapsulation, then sec and nanosec)."""
    return int.from_bytes(data[4:8], "little", signed=True) * 10**9 + int.from_bytes(data[8:12], "little")


def processed_by(stamp: int) -> float:
    """When the node's external torque of the first sample at or after ``stamp`` arrived (how far
    behind the stream the node is then, on a loaded machine), from the last :func:`stream_arm`."""
    return min((t for t, s in arrivals if s >= stamp), default=float("inf"))


def cdr_bool(data: bytes) -> bool:
    """A std_msgs/Bool's value."""
    return bool(data[4])


def messages_in(log: str) -> int | None:
    """The joint states a stopped ``neforward run`` took, as its log says; None if it did not say."""
    counts = stopped_counts(log)
    return None if counts is None else counts[0]
