"""``neforward demo``: the node live on loopback, fed by a synthetic joint-state publisher.

Starts ``neforward run`` as a separate process on the bundled robot with the node's default
estimator (or the one asked for), publishes JointState (positions only, a smooth trajectory, 500 Hz,
stamped with the wall clock at writing) and shows every link's |a|, |alpha| and centre-of-mass |a|
as they arrive, refreshed in place. After the given time it prints a summary: the estimator and its
delay, messages in and out, latency p50/p99, and the peaks per link next to their exact values
(:func:`neforward_ros.forward_recursion` at the true joint states of the same stamps).
"""

from __future__ import annotations

import math
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

from neforward_ros.demo.robot import demo_trajectory
from neforward_ros.errors import NeforwardError
from neforward_ros.estimation.settings import StreamSettings
from neforward_ros.interface import topics
from neforward_ros.kinematics.forward import forward_recursion
from neforward_ros.model import RobotModel, load_model
from neforward_ros.stamps import time_message
from neforward_ros.wire import cdr

STARTUP_TIMEOUT = 30.0
QUIET = 1.0
"""s without a result after which, the stream sent, the node is taken to have answered all it took."""
STRAGGLERS = 60.0
"""s at most that the results of a stream are waited for once it is sent."""


def stopped_counts(log: str) -> tuple[int, int] | None:
    """(messages in, results out) as a stopped ``neforward run`` says in its log's last such line
    ("stopped: N messages in, M results out"); None if it did not say."""
    for line in reversed(log.splitlines()):
        if "stopped:" in line:
            words = line.split("stopped:")[1].split()
            return int(words[0]), int(words[3])
    return None


class _Publisher(threading.Thread):
    """Writes JointState at ``rate`` Hz on its own thread, stamped with the wall clock at writing."""

    def __init__(self, writer, model: RobotModel, seconds: float, rate: float) -> None:
        super().__init__(daemon=True)
        self.writer, self.model = writer, model
        self.count = int(seconds * rate)
        self.rate = rate
        self.sent = 0
        self.stop = threading.Event()
        self.first = time.time_ns()  # the trajectory's time 0, wall clock ns

    def run(self) -> None:
        from neforward_ros.dds.types import raw_sample

        names = list(self.model.joint_names)
        start = time.monotonic()
        self.first = first = time.time_ns()
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


def live_demo(
    seconds: float,
    urdf: str | None,
    rate: float = 500.0,
    estimator: StreamSettings | None = None,
    root_link: str | None = None,
) -> int:
    """Run the demo and print its summary; returns the exit code."""
    run = run_demo(seconds, urdf, rate, estimator, live=sys.stdout.isatty(), root_link=root_link)
    run.view.summary(run)
    return 0


class DemoRun:
    """What a demo run measured: the view's peaks and latencies, and what the publisher sent.

    Attributes:
        view: peaks (node) and latencies.
        sent: JointState messages published.
        first_ns: the trajectory's time 0 (wall clock ns).
        settings: the node's estimator settings.
    """

    def __init__(self, view: _View, sent: int, rate: float, first_ns: int, settings: StreamSettings) -> None:
        self.view, self.sent, self.rate, self.first_ns, self.settings = view, sent, rate, first_ns, settings

    @property
    def node_counts(self) -> tuple[int, int] | None:
        """(messages in, results out) as the node said when it stopped; None if it did not say."""
        return stopped_counts(self.view.node_log)

    def exact_peaks(self) -> dict[str, np.ndarray]:
        """Per link, the peaks of |a| (kinematic), |alpha| and COM |a| at the true joint states of the
        stamps the node answered, from the batched recursion."""
        stamps = np.array(self.view.stamps, dtype=np.int64)
        kin = forward_recursion(
            self.view.model,
            *demo_trajectory(self.view.model, (stamps - self.first_ns) / 1e9),
            gravity=(0.0, 0.0, 0.0),
        )
        return {
            "a": np.linalg.norm(kin.accel, axis=-1).max(axis=0),
            "alpha": np.linalg.norm(kin.alpha, axis=-1).max(axis=0),
            "com": np.linalg.norm(kin.com_accel, axis=-1).max(axis=0),
        }


def run_demo(
    seconds: float,
    urdf: str | None,
    rate: float = 500.0,
    estimator: StreamSettings | None = None,
    live: bool = False,
    root_link: str | None = None,
) -> DemoRun:
    """The node on loopback DDS, fed for ``seconds``; the outputs gathered (shown live if ``live``)."""
    from cyclonedds.core import InstanceState, ReadCondition, SampleState, ViewState, WaitSet
    from cyclonedds.domain import DomainParticipant
    from cyclonedds.pub import DataWriter
    from cyclonedds.topic import Topic
    from cyclonedds.util import duration

    from neforward_ros.dds.loopback import use_loopback
    from neforward_ros.dds.qos import default_qos
    from neforward_ros.dds.types import RawBytes, dds_type, raw_reader
    from neforward_ros.resources import DEFAULT_ROBOT, bundled_config_path

    settings = estimator if estimator is not None else StreamSettings()
    path = Path(urdf) if urdf else bundled_config_path(DEFAULT_ROBOT)
    model = load_model(path, root_link=root_link)
    domain = use_loopback()
    node_log = tempfile.NamedTemporaryFile(prefix="neforward-demo-node-", suffix=".log", delete=False)
    command = [sys.executable, "-m", "neforward_ros", "run", "--urdf", str(path)]
    command += ["--ros-args", "-p", f"estimator.method:={settings.method}", "-p", f"estimator.mode:={settings.mode}"]
    if settings.lag is not None:
        command += ["-p", f"estimator.lag:={float(settings.lag)!r}"]
    if root_link:
        command += ["-p", f"root_link:={root_link}"]
    # The demo stops its node with SIGINT: the node gets it at its default even where the demo itself
    # runs with it ignored (a background job).
    node = subprocess.Popen(
        command, env=os.environ.copy(), stdout=node_log, stderr=subprocess.STDOUT,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )  # fmt: skip
    participant = DomainParticipant(domain)
    joint_state = topics.JOINT_STATE_TYPE
    writer = DataWriter(
        participant, Topic(participant, "rt/joint_states", dds_type(joint_state)), qos=default_qos(joint_state)
    )
    link_type = topics.LINK_STATES_TYPE
    readers = {
        # deep enough for every result of the run: what the node sends, the view gets, however busy it is
        name: raw_reader(
            participant, f"rt/neforward/{name}", link_type, default_qos(link_type, depth=int(seconds * rate) + 100)
        )
        for name in ("link_states", "com_states")
    }
    waitset = WaitSet(participant)
    for reader in readers.values():
        waitset.attach(ReadCondition(reader, SampleState.Any | ViewState.Any | InstanceState.Any))
    publisher = _Publisher(writer, model, seconds, rate)
    view = _View(model, live, settings, node_log.name)
    try:
        _wait_matched([writer, *readers.values()], time.monotonic() + STARTUP_TIMEOUT, node)
        time.sleep(0.3)  # let the node's side of the matching settle too
        publisher.start()
        end = last = None  # after the publisher: when to stop waiting; when a result last arrived
        while end is None or time.monotonic() < min(end, last + QUIET):
            waitset.wait(duration(milliseconds=50))
            now = time.time_ns()
            for name, reader in readers.items():
                for data in reader.take(N=256):
                    if isinstance(data, RawBytes):
                        view.add(name, cdr.decode_multi_dof(bytes(data)), now)
                        last = time.monotonic()
            view.refresh()
            if end is None and not publisher.is_alive():
                # the stragglers: a busy node runs seconds behind its stream, and answers every message it
                # took; until it has been quiet for QUIET (at most STRAGGLERS)
                end, last = time.monotonic() + STRAGGLERS, time.monotonic()
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
    view.node_log = Path(node_log.name).read_text()
    os.unlink(node_log.name)
    return DemoRun(view, publisher.sent, rate, publisher.first, settings)


class _View:
    """Peaks and latencies, and the table refreshed in place."""

    def __init__(self, model: RobotModel, live: bool, settings: StreamSettings, node_log: str) -> None:
        self.model = model
        self.links = model.link_names
        n = len(self.links)
        self.live = live
        self.settings = settings
        self.node_log = node_log
        self.latest = {"a": np.zeros(n), "alpha": np.zeros(n), "com": np.zeros(n)}
        self.peak = {key: np.zeros(n) for key in self.latest}
        self.latencies: list[float] = []
        self.stamps: list[int] = []
        self.received = {"link_states": 0, "com_states": 0}
        self.gravity = np.array([0.0, 0.0, -9.81])
        self._lines = 0
        self._last = 0.0

    def add(self, topic: str, point: cdr.MultiDofPoint, now_ns: int) -> None:
        if point.joint_names != self.links:
            return  # only some links (not with this demo's publisher, which sends every joint)
        self.received[topic] += 1
        kinematic = point.accelerations[:, :3] + self.gravity  # specific force back to acceleration
        if topic == "link_states":
            self.latencies.append((now_ns - point.stamp_ns) / 1e6)
            self.stamps.append(point.stamp_ns)
            self._update("a", np.linalg.norm(kinematic, axis=1))
            self._update("alpha", np.linalg.norm(point.accelerations[:, 3:], axis=1))
        else:
            self._update("com", np.linalg.norm(kinematic, axis=1))

    def _update(self, key: str, values: np.ndarray) -> None:
        self.latest[key] = values
        self.peak[key] = np.maximum(self.peak[key], values)

    def _width(self) -> int:
        return max(len(name) for name in self.links)

    def _table(self, source: dict[str, np.ndarray], title: str, rows: int | None = None) -> list[str]:
        """The table; with ``rows``, at most that many lines: the links with the largest |a| first
        when they do not all fit, and a last line saying how many are not shown."""
        width = self._width()
        lines = [title, f"{'link':<{width}}  {'|a| m/s^2':>10}  {'|alpha| rad/s^2':>15}  {'COM |a| m/s^2':>13}"]
        shown = list(range(len(self.links)))
        if rows is not None and len(shown) > rows - len(lines):
            room = max(rows - len(lines) - 1, 1)
            shown = sorted(np.argsort(-source["a"], kind="stable")[:room].tolist())
        for k in shown:
            name = self.links[k]
            lines.append(
                f"{name:<{width}}  {source['a'][k]:>10.3f}  {source['alpha'][k]:>15.3f}  {source['com'][k]:>13.3f}"
            )
        if len(shown) < len(self.links):
            lines.append(f"... {len(self.links) - len(shown)} more links (the largest |a| are shown)")
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
        # Redrawn in place, so it must fit the terminal: a line for the cursor, at most the rows left.
        rows = shutil.get_terminal_size().lines - 1
        title = f"neforward demo (kinematic accelerations, gravity removed) - {status}"
        lines = self._table(self.latest, title, rows)
        if self._lines:
            sys.stdout.write(f"\x1b[{self._lines}F")
        sys.stdout.write("\n".join(line + "\x1b[K" for line in lines) + "\n")
        sys.stdout.flush()
        self._lines = len(lines)

    def summary(self, run: DemoRun) -> None:
        received = self.received["link_states"]
        if received == 0:
            log = self.node_log.strip().splitlines()
            detail = ("; node said: " + log[-1]) if log else ""
            raise NeforwardError(f"no results arrived from the node{detail}")
        lag_ms = self.settings.effective_lag * 1e3
        p50, p99 = np.percentile(self.latencies, [50, 99])
        print()
        print(f"estimator: {self.settings.describe()}")
        com = self.received["com_states"]
        print(f"joint states in: {run.sent} at {run.rate:g} Hz; link_states out: {received}; com_states out: {com}")
        print(
            f"latency (link_states received - the stamp it refers to): p50 {p50:.2f} ms, p99 {p99:.2f} ms, "
            f"max {max(self.latencies):.2f} ms" + (f"; the estimator's lag is {lag_ms:g} ms of that" if lag_ms else "")
        )
        exact = run.exact_peaks()
        width = self._width()
        print("peaks over the run: the node's, and exact (forward_recursion at the true joint states)")
        print(f"{'link':<{width}}  {'|a| m/s^2':>19}  {'|alpha| rad/s^2':>19}  {'COM |a| m/s^2':>19}")
        print(f"{'':<{width}}  " + "  ".join([f"{'node':>9} {'exact':>9}"] * 3))
        for k, name in enumerate(self.links):
            cells = [f"{self.peak[key][k]:>9.3f} {exact[key][k]:>9.3f}" for key in ("a", "alpha", "com")]
            print(f"{name:<{width}}  " + "  ".join(cells))
        worst, where = peak_difference(self.peak, exact, self.links)
        print(f"largest difference of a peak from its exact value: {100 * worst:.2f} % ({where})")


QUANTITIES = {"a": "|a|", "alpha": "|alpha|", "com": "COM |a|"}


def peak_difference(
    peaks: dict[str, np.ndarray], exact: dict[str, np.ndarray], links: tuple[str, ...]
) -> tuple[float, str]:
    """The largest relative difference of a peak from its exact value, and where; peaks below 1e-3 of
    the largest of their quantity (links that barely move) are compared to that instead."""
    worst, where = 0.0, ""
    for key, label in QUANTITIES.items():
        scale = np.maximum(exact[key], 1e-3 * exact[key].max())
        relative = np.abs(peaks[key] - exact[key]) / np.where(scale > 0, scale, 1.0)
        k = int(np.argmax(relative))
        if relative[k] > worst:
            worst, where = float(relative[k]), f"{label} of {links[k]}"
    return worst, where
