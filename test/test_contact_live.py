"""Contact live: ``neforward run --params`` (the calibration's file) over loopback Cyclone DDS, fed a
simulated arm's joint states at 500 Hz in real time, with a 15 N push on its tool.

~/contact turns true once during the push and false again after it, and never before it;
~/external_torques carries every joint-state stamp, published as the sample arrives (the momentum
observer runs at the newest sample, not at the estimator's lag). The wall-clock delay from sending
the push's first sample to receiving ~/contact is printed; it is bounded here only loosely, since a
loaded machine delays any process (bench/bench_contact.py --live measures it).
"""

from __future__ import annotations

import itertools
import os
import random
import sys
import time
from pathlib import Path

import numpy as np

from neforward_ros.dds.loopback import write_config
from neforward_ros.interface import topics

from dds_peer import NodeProcess, Peer, loopback_env, messages_in, processed_by, stream_arm
from test_contact import SEED, arm, arm_urdf, neforward

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "examples"))
import arm_simulator as sim

_DOMAINS = itertools.count(random.randint(160, 200))


def test_contact_live_over_dds(tmp_path) -> None:
    free_arm = arm(SEED + 10)
    sim.write(sim.simulate(free_arm, 30.0), free_arm.urdf.read_text(), tmp_path / "free")
    done = neforward("calibrate", str(tmp_path / "free"), "-o", str(tmp_path / "params.yaml"))
    assert done.returncode == 0, done.stderr
    pushed_arm = arm(SEED + 10, pushes=(sim.Push(3.0, 1.0, (0.0, 0.0, -15.0)),))
    pushed_arm.seed = SEED + 11
    pushed = sim.simulate(pushed_arm, 5.0)
    uri = write_config(tmp_path).as_uri()
    os.environ["CYCLONEDDS_URI"] = uri
    domain = next(_DOMAINS)
    node = NodeProcess(["--urdf", str(arm_urdf()), "--params", str(tmp_path / "params.yaml")],
                       tmp_path / "node.log", loopback_env(domain, uri))  # fmt: skip
    try:
        peer = Peer(domain)
        peer.writer("/joint_states", topics.JOINT_STATE_TYPE)
        peer.reader("/neforward/contact", topics.BOOL_TYPE)
        peer.reader("/neforward/external_torques", topics.JOINT_STATE_TYPE)
        peer.wait_connected(node)
        time.sleep(1.0)  # the node compiles its kernels meanwhile
        sent, contact, external = stream_arm(peer, pushed, 500.0, settle=3.0)
    finally:
        node.stop()
    push_start = int(np.searchsorted(pushed.stamps, pushed.intervals[0][0]))
    push_end = int(np.searchsorted(pushed.stamps, pushed.intervals[0][1]))
    rises = [t for (t, state), (_, before) in zip(contact[1:], contact[:-1], strict=True) if state and not before]
    falls = [t for (t, state), (_, before) in zip(contact[1:], contact[:-1], strict=True) if not state and before]
    assert not contact[0][1], "contact at the start"
    assert len(rises) == 1 and len(falls) == 1, (rises, falls, node.log())
    rise, fall = rises[0] - sent[push_start], falls[0] - sent[push_end]
    print(f"live: contact {rise * 1e3:.1f} ms after the push's first sample was sent, released "
          f"{fall * 1e3:.1f} ms after its last")  # fmt: skip
    # loose, and counted from when the node had processed those samples (their external torques
    # arrived): with every core busy, the node may run 0.3-0.7 s behind the stream it is sent
    behind_start = max(0.0, processed_by(int(pushed.stamps[push_start])) - sent[push_start])
    behind_end = max(0.0, processed_by(int(pushed.stamps[push_end])) - sent[push_end])
    assert 0 < rise < 0.5 + behind_start and 0 < fall < 0.5 + behind_end, (rise, fall, behind_start, behind_end)
    # every stamp the node took, after the observer's warm-up (all of them on an idle machine; one that
    # runs the node over a second behind its stream drops the oldest, as its queue's depth says)
    taken = messages_in(node.log())
    assert taken is not None and taken > 0 and len(external) >= taken - 200, (taken, len(external), node.log())
