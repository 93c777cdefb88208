"""Latency and sustained rate of ``neforward run`` over loopback Cyclone DDS, every mode and input kind.

For each robot (the bundled 13-link arm and the 34-link, 33-joint humanoid in test/urdf), each
estimator mode (default fixed_lag, and causal), each input kind (positions only, and positions with
velocities, as most drivers send them) and each rate, this script publishes JointState (stamped
with the wall clock at writing) for a few seconds to ``neforward run`` in a separate process, with
the node's default settings otherwise, and receives ``/neforward/link_states``.

Latency is receive time minus the stamp of the input that completed the output: the output's own
input in causal mode; in fixed-lag mode the first input ``lag`` (0.1 s) or more after it, since the
estimate waits for it. So "latency" is the node's processing and transport, and the configured lag
comes on top of it. "lost" counts inputs without an output from the node's first output on (the inputs
before it are its warm-up, printed in ms: the support, and for polyfit causal and kalman their wait for
the candidates' record; the last ``lag`` of the stream in fixed-lag mode never has one and is not counted).

The floor is measured in the same run: a separate process that echoes each JointState straight
back on another topic, with no computation. Both use the same publisher and reader code here.
Prints p50/p99 latency, the node's p50 above the floor's, lost outputs and the node's warm-up.

Usage: python bench/bench_dds.py [--seconds 3] [--rates 500,1000,2000] [--modes fixed_lag,causal]
"""

from __future__ import annotations

import argparse
import os
import signal
import struct
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
ROBOTS = {
    "arm (13 links, 8 joints)": ROOT / "config" / "panda.urdf",
    "humanoid (34 links, 33 joints)": ROOT / "test" / "urdf" / "humanoid.urdf",
}


def echo_server() -> None:
    """The floor: take JointState bytes on rt/joint_states and write them back on rt/echo."""
    from cyclonedds.core import InstanceState, ReadCondition, SampleState, ViewState, WaitSet
    from cyclonedds.domain import DomainParticipant
    from cyclonedds.pub import DataWriter
    from cyclonedds.topic import Topic
    from cyclonedds.util import duration

    from neforward_ros.dds.domain import domain_id
    from neforward_ros.dds.qos import default_qos
    from neforward_ros.dds.types import RawBytes, dds_type, raw_reader, raw_sample
    from neforward_ros.interface import topics

    typename = topics.JOINT_STATE_TYPE
    participant = DomainParticipant(domain_id())
    reader = raw_reader(participant, "rt/joint_states", typename, default_qos(typename))
    writer = DataWriter(participant, Topic(participant, "rt/echo", dds_type(typename)), qos=default_qos(typename))
    waitset = WaitSet(participant)
    waitset.attach(ReadCondition(reader, SampleState.Any | ViewState.Any | InstanceState.Any))
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    try:
        while not stop.is_set():
            waitset.wait(duration(milliseconds=100))
            for data in reader.take(N=256):
                if isinstance(data, RawBytes):
                    writer.write(raw_sample(typename, bytes(data)))
    except KeyboardInterrupt:
        pass


def measure(peer_domain: int, output_topic: str, output_type: str, names: list[str], rate: float, seconds: float,
            velocities: bool, process):  # fmt: skip
    """Publish at ``rate`` for ``seconds``; return (input stamps, [(receive ns, output stamp)])."""
    from cyclonedds.core import InstanceState, ReadCondition, SampleState, ViewState, WaitSet
    from cyclonedds.domain import DomainParticipant
    from cyclonedds.pub import DataWriter
    from cyclonedds.qos import Policy, Qos
    from cyclonedds.topic import Topic
    from cyclonedds.util import duration

    from neforward_ros.dds.qos import default_qos
    from neforward_ros.dds.types import RawBytes, dds_type, raw_reader, raw_sample
    from neforward_ros.interface import topics
    from neforward_ros.stamps import time_message
    from neforward_ros.wire import cdr

    typename = topics.JOINT_STATE_TYPE
    participant = DomainParticipant(peer_domain)
    writer = DataWriter(
        participant, Topic(participant, "rt/joint_states", dds_type(typename)), qos=default_qos(typename)
    )
    deep = Qos(
        Policy.Reliability.Reliable(max_blocking_time=100_000_000),
        Policy.History.KeepLast(100_000),
        Policy.DataRepresentation(use_cdrv0_representation=True),
    )
    reader = raw_reader(participant, output_topic, output_type, deep)
    deadline = time.monotonic() + 30
    while not (
        writer.get_publication_matched_status().current_count and reader.get_subscription_matched_status().current_count
    ):
        if time.monotonic() > deadline or process.poll() is not None:
            raise RuntimeError("the process under test did not connect")
        time.sleep(0.05)
    time.sleep(0.5)
    received: list[tuple[int, int]] = []
    done = threading.Event()

    waitset = WaitSet(participant)  # blocks without spinning: the measurement must not steal the CPU it measures
    waitset.attach(ReadCondition(reader, SampleState.Any | ViewState.Any | InstanceState.Any))

    def read() -> None:
        while True:
            waitset.wait(duration(milliseconds=20))
            batch = reader.take(N=512)
            now = time.time_ns()
            for data in batch:
                if isinstance(data, RawBytes):
                    sec, nanosec = struct.unpack_from("<iI", data, 4)
                    received.append((now, sec * 1_000_000_000 + nanosec))
            if not batch and done.is_set():
                return

    thread = threading.Thread(target=read, daemon=True)
    thread.start()
    count = int(rate * seconds)
    frequencies = np.arange(1, len(names) + 1)
    stamps = []
    start = time.monotonic()
    for k in range(count):
        delay = start + k / rate - time.monotonic()
        if delay > 0:
            time.sleep(delay)
        t = k / rate
        stamp = time.time_ns()
        contents = {
            "header": {"stamp": time_message(stamp)},
            "name": names,
            "position": (0.3 * np.sin(t * frequencies)).tolist(),
        }
        if velocities:
            contents["velocity"] = (0.3 * frequencies * np.cos(t * frequencies)).tolist()
        writer.write(raw_sample(typename, cdr.encode(typename, contents)))
        stamps.append(stamp)
    time.sleep(1.0)
    done.set()
    thread.join(timeout=5)
    return np.array(stamps, dtype=np.int64), received


def reach(stamps: np.ndarray, lag_ns: int) -> np.ndarray:
    """How far each input's arrival lets the node's estimates go: its stamp, plus, with a lag, half the
    shortest of the last 8 stamp intervals (the node's rule, ``StreamingEstimator._tolerance``)."""
    out = stamps.copy()
    if lag_ns:
        intervals = np.diff(stamps, prepend=stamps[0])
        windows = np.lib.stride_tricks.sliding_window_view(np.r_[np.full(7, intervals[1]), intervals[1:]], 8)
        out[1:] += windows.min(axis=1) // 2
    return np.maximum.accumulate(out)


def latencies(stamps: np.ndarray, received: list[tuple[int, int]], lag_ns: int) -> np.ndarray:
    """ms from the input that completed each output: the first whose reach is the output's stamp plus the lag."""
    if not received:
        return np.array([np.nan])
    arrival, output = (np.array(x, dtype=np.int64) for x in zip(*received, strict=True))
    trigger = stamps[np.minimum(np.searchsorted(reach(stamps, lag_ns), output + lag_ns), len(stamps) - 1)]
    return (arrival - trigger) / 1e6


def expected_outputs(stamps: np.ndarray, lag_ns: int) -> int:
    """Outputs the node gives for these inputs (a fixed lag holds back the last lag's worth)."""
    return int(np.sum(stamps + lag_ns <= reach(stamps, lag_ns)[-1]))


def summary(stamps: np.ndarray, received: list[tuple[int, int]], lag_ns: int, warms_up: bool) -> tuple:
    """(p50 ms, p99 ms, outputs lost, outputs expected, warm-up ms). ``warms_up`` (the node): outputs are
    expected from the first one it gave, and the warm-up is that output's stamp after the first input's:
    the estimator waits for its support, and polyfit causal and kalman for their candidates' record too
    (0.36 s at 1 kHz; counted from the support alone, until 2026-11-29, that wait read as 160 outputs lost)."""
    first = min(output for _, output in received) if warms_up and received else int(stamps[0])
    expected = expected_outputs(stamps, lag_ns) - int(np.count_nonzero(stamps < first))
    p50, p99 = np.percentile(latencies(stamps, received, lag_ns), [50, 99])
    return p50, p99, expected - len(received), expected, (first - int(stamps[0])) / 1e6


def print_row(labels: list[str], floor: tuple, node: tuple) -> None:
    """One table row: the labels, the floor's and the node's p50 / p99, the node above the floor, losses."""
    (f50, f99, _, _, _), (n50, n99, lost, expected, warm_up) = floor, node
    print(
        " ".join(labels) + f" {f50:>10.2f} {f99:>6.2f} {n50:>9.2f} {n99:>6.2f} {n50 - f50:>12.2f}"
        f" {f'{lost} of {expected}':>12} {warm_up:>10.0f}",
        flush=True,
    )


def start(command: list[str]) -> subprocess.Popen:
    return subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=os.environ.copy())


def stop(process: subprocess.Popen) -> None:
    process.send_signal(signal.SIGINT)
    try:
        process.wait(timeout=10)
    except subprocess.TimeoutExpired:
        process.kill()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=3.0)
    parser.add_argument("--rates", default="500,1000,2000")
    parser.add_argument("--modes", default="fixed_lag,causal")
    parser.add_argument("--inputs", default="positions,velocities")
    parser.add_argument("--robots", default="arm,humanoid")
    parser.add_argument(
        "-p", dest="parameters", action="append", default=[], metavar="NAME:=VALUE", help="more node parameters"
    )
    parser.add_argument("--echo-server", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.echo_server:
        echo_server()
        return
    from neforward_ros import load_model
    from neforward_ros.dds.loopback import use_loopback
    from neforward_ros.estimation.settings import StreamSettings
    from neforward_ros.interface import topics

    domain = use_loopback()
    rates = [float(r) for r in args.rates.split(",")]
    print(f"loopback Cyclone DDS, domain {domain}; {args.seconds:g} s per run; latency from the completing input")
    print(
        f"{'robot':<10} {'mode':<10} {'input':<11} {'rate':>6} {'floor p50':>10} {'p99':>6} "
        f"{'node p50':>9} {'p99':>6} {'above floor':>12} {'lost':>12} {'warm-up ms':>10}"
    )
    for label, path in ROBOTS.items():
        if not any(wanted in label for wanted in args.robots.split(",")):
            continue
        names = list(load_model(path).joint_names)
        for mode in args.modes.split(","):
            lag_s = StreamSettings(mode=mode).effective_lag
            for kind in args.inputs.split(","):
                for rate in rates:
                    results = {}
                    for what in ("floor", "node"):
                        if what == "floor":
                            process = start([sys.executable, __file__, "--echo-server"])
                            topic, typename = "rt/echo", topics.JOINT_STATE_TYPE
                        else:
                            command = [sys.executable, "-m", "neforward_ros", "run", "--urdf", str(path)]
                            extra = [token for rule in args.parameters for token in ("-p", rule)]
                            process = start([*command, "--ros-args", "-p", f"estimator.mode:={mode}", *extra])
                            topic, typename = "rt/neforward/link_states", topics.LINK_STATES_TYPE
                        try:
                            stamps, received = measure(
                                domain, topic, typename, names, rate, args.seconds, kind == "velocities", process
                            )
                        finally:
                            stop(process)
                        lag_ns = round(lag_s * 1e9) if what == "node" else 0
                        results[what] = summary(stamps, received, lag_ns, what == "node")
                    labels = [f"{label.split()[0]:<10}", f"{mode:<10}", f"{kind:<11}", f"{rate:>6.0f}"]
                    print_row(labels, results["floor"], results["node"])


if __name__ == "__main__":
    main()
