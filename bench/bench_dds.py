"""End-to-end latency and sustained rate of ``neforward run`` over loopback Cyclone DDS.

For each robot (the bundled 13-link arm and the 34-link, 33-joint humanoid in test/urdf) and each
input rate, this script publishes JointState (positions only, stamped with the wall clock at
writing) for a few seconds to ``neforward run`` (causal mode, so the latency is processing, not the
estimator's lag) in a separate process, and receives ``/neforward/link_states``. Latency is
receive time minus input stamp. "Lost" counts inputs without an output (the first two inputs
never have one: too few samples for an estimate).

The floor is measured in the same run: a separate process that echoes each JointState straight
back on another topic, with no computation. Both use the same publisher and reader code here.

Prints p50/p99 latency, lost outputs, and the node's p50/p99 as a multiple of the floor's.
Usage: python bench/bench_dds.py [--seconds 3] [--rates 250,500,1000,2000]
"""

from __future__ import annotations

import argparse
import os
import signal
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

    from neforward_ros.dds.commands import domain_id
    from neforward_ros.dds.qos import default_qos
    from neforward_ros.dds.types import RawBytes, dds_type, raw_reader, raw_sample
    from neforward_ros.node import topics

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


def measure(
    peer_domain: int, output_topic: str, output_type: str, names: list[str], rate: float, seconds: float, process
):
    """Publish at ``rate`` for ``seconds``; return (latencies ms, sent, received)."""
    from cyclonedds.domain import DomainParticipant
    from cyclonedds.pub import DataWriter
    from cyclonedds.qos import Policy, Qos
    from cyclonedds.topic import Topic

    from neforward_ros.dds.qos import default_qos
    from neforward_ros.dds.types import RawBytes, dds_type, raw_reader, raw_sample
    from neforward_ros.node import topics
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
    latencies: list[float] = []
    received = 0
    done = threading.Event()

    def read() -> None:
        nonlocal received
        while True:
            batch = reader.take(N=512)
            now = time.time_ns()
            for data in batch:
                if not isinstance(data, RawBytes):
                    continue
                received += 1
                sec, nanosec = np.frombuffer(bytes(data), dtype="<i4", count=2, offset=4)
                latencies.append((now - (int(sec) * 1_000_000_000 + int(np.uint32(nanosec)))) / 1e6)
            if not batch:
                if done.is_set():
                    return
                time.sleep(0.0002)

    thread = threading.Thread(target=read, daemon=True)
    thread.start()
    count = int(rate * seconds)
    positions = np.zeros(len(names))
    start = time.monotonic()
    for k in range(count):
        delay = start + k / rate - time.monotonic()
        if delay > 0:
            time.sleep(delay)
        positions[:] = 0.3 * np.sin(k / rate * np.arange(1, len(names) + 1))
        stamp = time.time_ns()
        contents = {"header": {"stamp": time_message(stamp)}, "name": names, "position": positions.tolist()}
        writer.write(raw_sample(typename, cdr.encode(typename, contents)))
    time.sleep(1.0)
    done.set()
    thread.join(timeout=5)
    return latencies, count, received


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
    parser.add_argument("--rates", default="250,500,1000,2000")
    parser.add_argument("--echo-server", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.echo_server:
        echo_server()
        return
    from neforward_ros import load_model
    from neforward_ros.dds.loopback import use_loopback
    from neforward_ros.node import topics

    domain = use_loopback()
    rates = [float(r) for r in args.rates.split(",")]
    print(
        f"loopback Cyclone DDS, domain {domain}; {args.seconds:g} s per rate; latency = output received - input stamp"
    )
    print(
        f"{'robot':<32} {'rate Hz':>8} {'what':>6} {'p50 ms':>8} {'p99 ms':>8} {'lost':>6}"
        f" {'p50/floor':>10} {'p99/floor':>10}"
    )
    for label, path in ROBOTS.items():
        names = list(load_model(path).joint_names)
        for rate in rates:
            results = {}
            for what in ("floor", "node"):
                if what == "floor":
                    process = start([sys.executable, __file__, "--echo-server"])
                    topic, typename, expected_loss = "rt/echo", topics.JOINT_STATE_TYPE, 0
                else:
                    command = [sys.executable, "-m", "neforward_ros.cli", "run", "--urdf", str(path)]
                    process = start([*command, "--ros-args", "-p", "estimator.mode:=causal"])
                    topic, typename, expected_loss = "rt/neforward/link_states", topics.LINK_STATES_TYPE, 2
                try:
                    latencies, sent, received = measure(domain, topic, typename, names, rate, args.seconds, process)
                finally:
                    stop(process)
                p50, p99 = np.percentile(latencies, [50, 99]) if latencies else (float("nan"),) * 2
                results[what] = (p50, p99)
                lost = sent - expected_loss - received
                ratio = ""
                if what == "node":
                    ratio = f"{p50 / results['floor'][0]:>10.1f} {p99 / results['floor'][1]:>10.1f}"
                print(f"{label:<32} {rate:>8.0f} {what:>6} {p50:>8.2f} {p99:>8.2f} {lost:>6} {ratio}", flush=True)


if __name__ == "__main__":
    main()
