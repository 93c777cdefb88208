"""``neforward demo``: the node live on loopback, fed by a synthetic joint-state publisher.

Starts ``neforward run`` as a separate process on the bundled robot (causal mode, so that the
latency shown is the processing latency), publishes JointState (positions only, a smooth
trajectory, 500 Hz, stamped with the wall clock at writing) and shows every link's |a|, |alpha| and
centre-of-mass |a| as they arrive, refreshed in place. After the given time it prints a summary:
messages in and out, latency p50/p99 (output received minus input stamp) and the peaks per link.
"""

from __future__ import annotations

import math
import os
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

from neforward_ros.errors import NeforwardError
from neforward_ros.model import RobotModel, load_model
from neforward_ros.node import topics
from neforward_ros.stamps import time_message
from neforward_ros.wire import cdr

STARTUP_TIMEOUT = 30.0


class _Publisher(threading.Thread):
    """Writes JointState at ``rate`` Hz on its own thread, stamped with the wall clock at writing."""

    def __init__(self, writer, model: RobotModel, seconds: float, rate: float) -> None:
        super().__init__(daemon=True)
        self.writer, self.model = writer, model
        self.count = int(seconds * rate)
        self.rate = rate
        self.sent = 0
        self.stop = threading.Event()

    def run(self) -> None:
        from neforward_ros.dds.types import raw_sample
        from neforward_ros.demo.robot import demo_trajectory

        names = list(self.model.joint_names)
        start = time.monotonic()
        first = time.time_ns()
        for k in range(self.count):
            if self.stop.is_set():
                return
            delay = start + k / self.rate - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            stamp = time.time_ns()
            # positions at the stamp itself: a late write must not pair old positions with a new stamp
            q, _, _ = demo_trajectory(self.model, np.array([(stamp - first) / 1e9]))
            contents = {"header": {"stamp": time_message(stamp)}, "name": names, "position": q[0].tolist()}
            self.writer.write(raw_sample(topics.JOINT_STATE_TYPE, cdr.encode(topics.JOINT_STATE_TYPE, contents)))
            self.sent += 1


def _wait_matched(entities, deadline: float, node: subprocess.Popen) -> None:
    while time.monotonic() < deadline:
        if node.poll() is not None:
            raise NeforwardError(f"the node exited with code {node.returncode} during start-up")
        if all(_matched(e) for e in entities):
            return
        time.sleep(0.05)
    raise NeforwardError(f"the node did not connect within {STARTUP_TIMEOUT:g} s")


def _matched(entity) -> bool:
    if hasattr(entity, "get_publication_matched_status"):
        return entity.get_publication_matched_status().current_count > 0
    return entity.get_subscription_matched_status().current_count > 0


def live_demo(seconds: float, urdf: str | None, rate: float = 500.0) -> int:
    from cyclonedds.core import InstanceState, ReadCondition, SampleState, ViewState, WaitSet
    from cyclonedds.domain import DomainParticipant
    from cyclonedds.pub import DataWriter
    from cyclonedds.topic import Topic
    from cyclonedds.util import duration

    from neforward_ros.dds.loopback import use_loopback
    from neforward_ros.dds.qos import default_qos
    from neforward_ros.dds.types import RawBytes, dds_type, raw_reader
    from neforward_ros.resources import DEFAULT_ROBOT, bundled_config_path

    path = Path(urdf) if urdf else bundled_config_path(DEFAULT_ROBOT)
    model = load_model(path)
    domain = use_loopback()
    node_log = tempfile.NamedTemporaryFile(prefix="neforward-demo-node-", suffix=".log", delete=False)
    command = [sys.executable, "-m", "neforward_ros.cli", "run", "--urdf", str(path)]
    command += ["--ros-args", "-p", "estimator.mode:=causal"]
    node = subprocess.Popen(command, env=os.environ.copy(), stdout=node_log, stderr=subprocess.STDOUT)
    participant = DomainParticipant(domain)
    joint_state = topics.JOINT_STATE_TYPE
    writer = DataWriter(
        participant, Topic(participant, "rt/joint_states", dds_type(joint_state)), qos=default_qos(joint_state)
    )
    link_type = topics.LINK_STATES_TYPE
    readers = {
        name: raw_reader(participant, f"rt/neforward/{name}", link_type, default_qos(link_type, depth=100))
        for name in ("link_states", "com_states")
    }
    waitset = WaitSet(participant)
    for reader in readers.values():
        waitset.attach(ReadCondition(reader, SampleState.Any | ViewState.Any | InstanceState.Any))
    publisher = _Publisher(writer, model, seconds, rate)
    view = _View(model, sys.stdout.isatty())
    try:
        _wait_matched([writer, *readers.values()], time.monotonic() + STARTUP_TIMEOUT, node)
        time.sleep(0.3)  # let the node's side of the matching settle too
        publisher.start()
        end = None
        while end is None or time.monotonic() < end:
            waitset.wait(duration(milliseconds=50))
            now = time.time_ns()
            for name, reader in readers.items():
                for data in reader.take(N=256):
                    if isinstance(data, RawBytes):
                        view.add(name, cdr.decode_multi_dof(bytes(data)), now)
            view.refresh()
            if end is None and not publisher.is_alive():
                end = time.monotonic() + 1.0  # stragglers
    except KeyboardInterrupt:
        publisher.stop.set()
    finally:
        publisher.stop.set()
        node.send_signal(signal.SIGINT)
        try:
            node.wait(timeout=10)
        except subprocess.TimeoutExpired:
            node.kill()
            node.wait()
        node_log.close()
    view.summary(publisher.sent, rate, node_log.name)
    os.unlink(node_log.name)
    return 0


class _View:
    """Peaks and latencies, and the table refreshed in place."""

    def __init__(self, model: RobotModel, live: bool) -> None:
        self.links = model.link_names
        n = len(self.links)
        self.live = live
        self.latest = {"a": np.zeros(n), "alpha": np.zeros(n), "com": np.zeros(n)}
        self.peak = {key: np.zeros(n) for key in self.latest}
        self.latencies: list[float] = []
        self.received = {"link_states": 0, "com_states": 0}
        self.gravity = np.array([0.0, 0.0, -9.81])
        self._lines = 0
        self._last = 0.0

    def add(self, topic: str, point: cdr.MultiDofPoint, now_ns: int) -> None:
        self.received[topic] += 1
        kinematic = point.accelerations[:, :3] + self.gravity  # specific force back to acceleration
        if topic == "link_states":
            self.latencies.append((now_ns - point.stamp_ns) / 1e6)
            self._update("a", np.linalg.norm(kinematic, axis=1))
            self._update("alpha", np.linalg.norm(point.accelerations[:, 3:], axis=1))
        else:
            self._update("com", np.linalg.norm(kinematic, axis=1))

    def _update(self, key: str, values: np.ndarray) -> None:
        self.latest[key] = values
        self.peak[key] = np.maximum(self.peak[key], values)

    def _table(self, source: dict[str, np.ndarray], title: str) -> list[str]:
        width = max(len(name) for name in self.links)
        lines = [title, f"{'link':<{width}}  {'|a| m/s^2':>10}  {'|alpha| rad/s^2':>15}  {'COM |a| m/s^2':>13}"]
        for k, name in enumerate(self.links):
            lines.append(
                f"{name:<{width}}  {source['a'][k]:>10.3f}  {source['alpha'][k]:>15.3f}  {source['com'][k]:>13.3f}"
            )
        return lines

    def refresh(self) -> None:
        now = time.monotonic()
        if now - self._last < (0.2 if self.live else 1.0):
            return
        self._last = now
        p50 = np.percentile(self.latencies, 50) if self.latencies else math.nan
        status = f"results {self.received['link_states']}, latency p50 {p50:.2f} ms"
        if not self.live:
            print(status, flush=True)
            return
        lines = self._table(self.latest, f"neforward demo (kinematic accelerations, gravity removed) - {status}")
        if self._lines:
            sys.stdout.write(f"\x1b[{self._lines}F")
        sys.stdout.write("\n".join(line + "\x1b[K" for line in lines) + "\n")
        sys.stdout.flush()
        self._lines = len(lines)

    def summary(self, sent: int, rate: float, node_log: str) -> None:
        received = self.received["link_states"]
        if received == 0:
            log = Path(node_log).read_text().strip().splitlines()
            detail = ("; node said: " + log[-1]) if log else ""
            raise NeforwardError(f"no results arrived from the node{detail}")
        p50, p99 = np.percentile(self.latencies, [50, 99])
        print()
        com = self.received["com_states"]
        print(f"joint states in: {sent} at {rate:g} Hz; link_states out: {received}; com_states out: {com}")
        worst = max(self.latencies)
        print(f"latency (input stamp -> link_states received): p50 {p50:.2f} ms, p99 {p99:.2f} ms, max {worst:.2f} ms")
        print("\n".join(self._table(self.peak, "peaks over the run")))
