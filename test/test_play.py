"""``neforward play`` feeding ``neforward run`` over real Cyclone DDS on loopback: a rosbag2 recording
(the model from its robot_description topic, transient local) and a CSV, with their timing."""

from __future__ import annotations

import itertools
import os
import random
import subprocess
import sys
import time

import numpy as np
import pytest
from test_bag import NAMES, covered, record, trajectory

from neforward_ros.dds.loopback import write_config
from neforward_ros.interface import topics
from neforward_ros.wire import cdr

from conftest import CONFIG_DIR, EPOCH_NS
from dds_peer import NodeProcess, Peer, loopback_env

_DOMAINS = itertools.count(random.randint(160, 200))


@pytest.fixture(scope="module")
def config_uri(tmp_path_factory) -> str:
    uri = write_config(tmp_path_factory.mktemp("dds")).as_uri()
    os.environ["CYCLONEDDS_URI"] = uri
    return uri


def play_into_node(
    config_uri, tmp_path, play_arguments: list[str], node_arguments=()
) -> tuple[list, float, str, tuple[int, int]]:
    """Start the node, then play; returns (link_states points received, play's duration, play's stderr,
    (joint states the node received, results it sent) as it says when it stops)."""
    domain = next(_DOMAINS)
    env = loopback_env(domain, config_uri)
    node = NodeProcess(list(node_arguments), tmp_path / "node.log", env)
    peer = Peer(domain)
    peer.reader("/neforward/link_states", topics.LINK_STATES_TYPE)
    try:
        peer.wait_connected(node)
        started = time.monotonic()
        played = subprocess.run(
            [sys.executable, "-m", "neforward_ros", "play", *play_arguments],
            env=env,
            capture_output=True,
            text=True,
            timeout=120,
        )
        duration = time.monotonic() - started
        assert played.returncode == 0, played.stderr
        received = []
        quiet_since = time.monotonic()
        while time.monotonic() - quiet_since < 3.0:  # until nothing more comes for 3 s
            peer.wait(0.2)
            taken = peer.take("/neforward/link_states")
            if taken:
                quiet_since = time.monotonic()
            received += [cdr.decode_multi_dof(raw) for raw in taken]
    finally:
        node.stop()
    summary = next(line for line in reversed(node.log().splitlines()) if "stopped:" in line).split("stopped:")[1]
    words = summary.split()
    return received, duration, played.stderr, (int(words[0]), int(words[3]))


def test_play_a_recording_into_the_node(config_uri, tmp_path) -> None:
    t = record(tmp_path / "rec", seconds=2.0, velocities=True)  # with its robot_description topic
    received, duration, err, (into, out) = play_into_node(
        config_uri, tmp_path, [str(tmp_path / "rec"), "--rate", "2", "--delay", "2"]
    )
    assert "/robot_description (std_msgs/msg/String)" in err
    assert f"{len(t) + 1} messages" in err.splitlines()[-1]  # the joint states and the description
    # The node got the model from the played robot_description, and every result it sent arrived
    # (reliable); when it received every joint state (its queue, 0.5 s deep at 1 kHz, may overflow on
    # a machine too busy to keep up), it answered exactly those the estimator covers: all but the
    # first and last 0.1 s.
    assert 0 < out == len(received) and 0 < into <= len(t), (into, out, len(received), err)
    if into == len(t):
        assert out == int(covered(t).sum()), (out, int(covered(t).sum()))
    # the recording's stamps, unchanged
    stamps = {p.stamp_ns for p in received}
    recorded = {EPOCH_NS + round(x * 1e9) for x in t}
    assert stamps <= recorded
    # played at twice the speed: about 1 s, after the 2 s delay (the only bound above: a generous one)
    assert 2.9 < duration < 120.0


def test_play_a_csv_into_the_node(config_uri, tmp_path) -> None:
    rate = 500.0
    t = np.arange(int(1.0 * rate)) / rate
    q, _, _ = trajectory(t)
    stamps = 1_800_000_000 * 10**9 + np.round(t * 1e9).astype(np.int64)
    lines = ["stamp_ns," + ",".join(NAMES)]
    lines += [f"{s}," + ",".join(f"{v:.12g}" for v in row) for s, row in zip(stamps, q, strict=True)]
    (tmp_path / "states.csv").write_text("\n".join(lines) + "\n")
    received, _, err, (into, out) = play_into_node(
        config_uri, tmp_path, [str(tmp_path / "states.csv")], ["--urdf", str(CONFIG_DIR / "panda.urdf")]
    )
    assert 0 < out == len(received) and 0 < into <= len(t), (into, out, len(received), err)
    if into == len(t):
        assert out == int(covered(t).sum()), (out, int(covered(t).sum()))
    assert {p.stamp_ns for p in received} <= set(stamps.tolist())


def test_play_errors_are_one_line(tmp_path) -> None:
    for arguments, text in (
        ([str(tmp_path / "nope")], "no such file or directory"),
        ([str(tmp_path), "--rate", "0"], "--rate must be a positive number"),
    ):
        done = subprocess.run(
            [sys.executable, "-m", "neforward_ros", "play", *arguments], capture_output=True, text=True
        )
        assert done.returncode == 1 and done.stderr.count("\n") == 1 and text in done.stderr, done.stderr
