"""End to end over real Cyclone DDS on loopback: ``neforward run`` as a separate process, a test
participant publishing ROS 2 messages to it and checking what comes back against forward_recursion.

Every test bounds its own time and stops the processes it started. The DDS configuration binds
127.0.0.1 with multicast off, and each test has its own domain id.
"""

from __future__ import annotations

import itertools
import os
import random
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from neforward_ros import forward_recursion, load_model
from neforward_ros.dds.graph import DISCOVERY_TOPIC, DISCOVERY_TYPE
from neforward_ros.dds.loopback import write_config
from neforward_ros.dds.types import type_hash
from neforward_ros.interface import topics
from neforward_ros.stamps import time_message
from neforward_ros.wire import cdr, rostypes

from conftest import CONFIG_DIR, EPOCH_NS
from dds_peer import NodeProcess, Peer, joint_state, loopback_env

PANDA = CONFIG_DIR / "panda.urdf"
MODEL = load_model(PANDA)
NAMES = list(MODEL.joint_names)
STARTUP = 30.0
_DOMAINS = itertools.count(random.randint(100, 150))


@pytest.fixture(scope="module")
def config_uri(tmp_path_factory) -> str:
    uri = write_config(tmp_path_factory.mktemp("dds")).as_uri()
    os.environ["CYCLONEDDS_URI"] = uri  # this process's participants: loopback too
    return uri


@pytest.fixture
def domain(config_uri) -> int:
    return next(_DOMAINS)


@pytest.fixture
def start(config_uri, domain, tmp_path):
    nodes: list[NodeProcess] = []

    def start_node(*arguments: str) -> NodeProcess:
        node = NodeProcess(list(arguments), tmp_path / f"node{len(nodes)}.log", loopback_env(domain, config_uri))
        nodes.append(node)
        return node

    yield start_node
    for node in nodes:
        node.stop()


def stream(peer: Peer, states, rate: float, topics=()) -> dict[str, list[bytes]]:
    """Write joint states at ``rate`` Hz, collecting what arrives on ``topics`` meanwhile."""
    received: dict[str, list[bytes]] = {topic: [] for topic in topics}
    start = time.monotonic()
    for k, contents in enumerate(states):
        delay = start + k / rate - time.monotonic()
        if delay > 0:
            time.sleep(delay)
        peer.write("/joint_states", contents)
        for topic in topics:
            received[topic] += peer.take(topic)
    return received


def collect(peer: Peer, received: dict[str, list[bytes]], until, timeout: float = 60.0) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline and not until(received):
        peer.wait(0.05)
        for topic in received:
            received[topic] += peer.take(topic)


def still_states(q: np.ndarray, count: int, start_ns: int = EPOCH_NS, step_ns: int = 10_000_000) -> list[dict]:
    return [joint_state(start_ns + k * step_ns, NAMES, q.tolist()) for k in range(count)]


def check_still_outputs(link_states: bytes, accel: bytes | None, imu: bytes | None, q: np.ndarray) -> None:
    expected = forward_recursion(MODEL, q, np.zeros_like(q), np.zeros_like(q))
    root = expected.in_root()
    point = cdr.decode_multi_dof(link_states)
    assert point.frame_id == MODEL.root_link and point.joint_names == MODEL.link_names
    np.testing.assert_allclose(point.transforms[:, :3], root.position, atol=1e-9)
    np.testing.assert_allclose(point.accelerations[:, :3], root.accel, atol=1e-6)
    np.testing.assert_allclose(point.accelerations[:, 3:], 0.0, atol=1e-6)
    hand = MODEL.link_index["panda_hand"]
    if accel is not None:
        message = rostypes.deserialize(topics.ACCEL_TYPE, accel)
        assert message["header"]["frame_id"] == "panda_hand"
        linear = [message["accel"]["linear"][k] for k in "xyz"]
        np.testing.assert_allclose(linear, expected.accel[hand], atol=1e-6)
    if imu is not None:
        message = rostypes.deserialize(topics.IMU_TYPE, imu)
        linear = [message["linear_acceleration"][k] for k in "xyz"]
        np.testing.assert_allclose(linear, expected.accel[hand], atol=1e-6)  # specific force: +g at rest


PER_LINK = ("-p", "accel_links:=[panda_hand]", "-p", "imu_links:=[panda_hand]", "-p", "estimator.mode:=causal")
OUTPUTS = ("/neforward/link_states", "/neforward/panda_hand/accel", "/neforward/panda_hand/imu")


def peer_for_outputs(domain: int) -> Peer:
    peer = Peer(domain)
    peer.writer("/joint_states", topics.JOINT_STATE_TYPE)
    peer.reader("/neforward/link_states", topics.LINK_STATES_TYPE)
    peer.reader("/neforward/panda_hand/accel", topics.ACCEL_TYPE)
    peer.reader("/neforward/panda_hand/imu", topics.IMU_TYPE)
    return peer


def test_link_states_accel_and_imu_match_forward_recursion(start, domain) -> None:
    node = start("--urdf", str(PANDA), "--ros-args", *PER_LINK)
    peer = peer_for_outputs(domain)
    peer.wait_connected(node)
    q = np.linspace(-0.6, 0.6, len(NAMES))
    received = stream(peer, still_states(q, 60), rate=100.0, topics=OUTPUTS)
    collect(peer, received, lambda r: all(len(v) >= 20 for v in r.values()))
    # 60 in at 100 Hz; the causal fit's window is 0.2 s, and from a start its choice waits 0.2 s more for its
    # record (stream.HOLD_UNTIL_RECORD): the first 40 inputs give no output
    for topic in OUTPUTS:
        assert len(received[topic]) == 20, topic
    check_still_outputs(received[OUTPUTS[0]][-1], received[OUTPUTS[1]][-1], received[OUTPUTS[2]][-1], q)
    stamps = [cdr.decode_multi_dof(b).stamp_ns for b in received[OUTPUTS[0]]]
    assert stamps == [EPOCH_NS + k * 10_000_000 for k in range(40, 60)]  # each output has its input's stamp
    assert "no estimate yet for joint(s)" in node.log()  # the warm-up, said once


def test_a_joint_nobody_publishes_leaves_out_only_the_links_it_moves(start, domain) -> None:
    """The same publish policy as the rclpy node's (partial, by default): the finger's driver is off."""
    node = start("--urdf", str(PANDA), "--ros-args", *PER_LINK)
    peer = peer_for_outputs(domain)
    peer.wait_connected(node)
    names = [name for name in NAMES if name != "panda_finger_joint1"]
    q = np.linspace(-0.5, 0.5, len(names))
    states = [joint_state(EPOCH_NS + k * 10_000_000, names, q.tolist()) for k in range(60)]  # outputs from the 40th
    received = stream(peer, states, rate=100.0, topics=OUTPUTS)
    collect(peer, received, lambda r: len(r[OUTPUTS[0]]) >= 20 and len(r[OUTPUTS[1]]) >= 20)
    arm = tuple(name for name in MODEL.link_names if "finger" not in name)
    points = [cdr.decode_multi_dof(b) for b in received[OUTPUTS[0]]]
    assert len(points) == 20 and all(p.joint_names == arm for p in points)
    full = np.zeros(len(NAMES))
    full[[NAMES.index(n) for n in names]] = q
    expected = forward_recursion(MODEL, full, np.zeros_like(full), np.zeros_like(full)).in_root()
    rows = [MODEL.link_index[n] for n in arm]
    np.testing.assert_allclose(points[-1].transforms[:, :3], expected.position[rows], atol=1e-9)
    np.testing.assert_allclose(points[-1].accelerations[:, :3], expected.accel[rows], atol=1e-6)
    assert len(received[OUTPUTS[1]]) == 20  # the hand's accel: not moved by the finger
    assert "publishing 11 of 13 links" in node.log()


def test_supplied_states_give_exact_kinematics_over_the_wire(start, domain) -> None:
    node = start("--urdf", str(PANDA), "--ros-args", "-p", "acceleration_source:=supplied")
    peer = Peer(domain)
    peer.writer("/joint_states_accel", topics.JOINT_TRAJECTORY_TYPE)
    peer.reader("/neforward/link_states", topics.LINK_STATES_TYPE)
    peer.reader("/neforward/com_states", topics.LINK_STATES_TYPE)
    peer.wait_connected(node)
    rng = np.random.default_rng(11)
    q, qd, qdd = (rng.uniform(-2, 2, len(NAMES)) for _ in range(3))
    point = {"positions": q.tolist(), "velocities": qd.tolist(), "accelerations": qdd.tolist()}
    peer.write(
        "/joint_states_accel", {"header": {"stamp": time_message(EPOCH_NS)}, "joint_names": NAMES, "points": [point]}
    )
    received = {"/neforward/link_states": [], "/neforward/com_states": []}
    collect(peer, received, lambda r: all(r.values()))
    expected = forward_recursion(MODEL, q, qd, qdd).in_root()
    links = cdr.decode_multi_dof(received["/neforward/link_states"][0])
    coms = cdr.decode_multi_dof(received["/neforward/com_states"][0])
    assert links.stamp_ns == EPOCH_NS
    np.testing.assert_allclose(links.velocities[:, 3:], expected.omega, rtol=0, atol=1e-9)
    np.testing.assert_allclose(links.velocities[:, :3], expected.velocity, rtol=0, atol=1e-9)
    np.testing.assert_allclose(links.accelerations[:, :3], expected.accel, rtol=0, atol=1e-9)
    np.testing.assert_allclose(links.accelerations[:, 3:], expected.alpha, rtol=0, atol=1e-9)
    np.testing.assert_allclose(coms.accelerations[:, :3], expected.com_accel, rtol=0, atol=1e-9)


def test_model_from_the_transient_local_topic_after_the_node_started(start, domain) -> None:
    node = start("--ros-args", *PER_LINK)
    peer = peer_for_outputs(domain)
    peer.wait_connected(node)
    time.sleep(0.5)
    q = np.full(len(NAMES), 0.2)
    early = stream(peer, still_states(q, 5), rate=100.0, topics=OUTPUTS)  # before the model: dropped
    assert not any(early.values())
    description = peer.writer("/robot_description", topics.STRING_TYPE, latched=True)
    peer.write("/robot_description", {"data": PANDA.read_text()})
    deadline = time.monotonic() + 10
    while "model 'panda'" not in node.log() and time.monotonic() < deadline:
        time.sleep(0.05)
    assert description.get_publication_matched_status().current_count == 1
    received = stream(peer, still_states(q, 50, start_ns=EPOCH_NS + 10**9), rate=100.0, topics=OUTPUTS)
    collect(peer, received, lambda r: all(len(v) >= 8 for v in r.values()))
    check_still_outputs(received[OUTPUTS[0]][-1], received[OUTPUTS[1]][-1], received[OUTPUTS[2]][-1], q)
    log = node.log()
    assert log.count("waiting for the model on the robot_description topic") == 1
    assert "joint states dropped: no robot model yet" in log


def test_node_restart_mid_stream(start, domain) -> None:
    peer = peer_for_outputs(domain)
    first = start("--urdf", str(PANDA), "--ros-args", *PER_LINK)
    peer.wait_connected(first)
    q = np.full(len(NAMES), -0.3)
    before = stream(peer, still_states(q, 50), rate=100.0, topics=OUTPUTS)
    collect(peer, before, lambda r: all(len(v) >= 10 for v in r.values()))
    assert first.stop() == 0
    peer.wait_disconnected()
    second = start("--urdf", str(PANDA), "--ros-args", *PER_LINK)
    peer.wait_connected(second)
    after = stream(peer, still_states(q, 50, start_ns=EPOCH_NS + 10**9), rate=100.0, topics=OUTPUTS)
    collect(peer, after, lambda r: all(len(v) >= 10 for v in r.values()))
    assert len(after[OUTPUTS[0]]) == 10  # a new node warms up again: 0.2 s of samples and 0.2 s of record
    check_still_outputs(after[OUTPUTS[0]][-1], after[OUTPUTS[1]][-1], after[OUTPUTS[2]][-1], q)


def test_bad_input_over_the_wire_then_good_input_is_still_right(start, domain) -> None:
    node = start("--urdf", str(PANDA), "--ros-args", *PER_LINK)
    peer = peer_for_outputs(domain)
    peer.wait_connected(node)
    q = np.full(len(NAMES), 0.4)
    t = EPOCH_NS + 5 * 10**9
    bad = [
        joint_state(t, NAMES, [0.1, 0.2]),  # names and positions of different lengths
        joint_state(t + 10**7, NAMES, [float("nan")] * len(NAMES)),  # NaN
        joint_state(t + 2 * 10**7, ["ghost", *NAMES], [9.0, *q.tolist()]),  # an unknown joint (and a good sample)
        joint_state(t - 10**9, NAMES, q.tolist()),  # one stamp going backwards: a stray
    ]
    stream(peer, bad, rate=100.0)
    good = still_states(q, 50, start_ns=t + 10**9)  # (more than max_gap later: a start's warm-up, 0.4 s)
    received = stream(peer, good, rate=100.0, topics=OUTPUTS)
    collect(peer, received, lambda r: all(len(v) >= 8 for v in r.values()))
    assert node.alive()
    check_still_outputs(received[OUTPUTS[0]][-1], received[OUTPUTS[1]][-1], received[OUTPUTS[2]][-1], q)
    log = node.log()
    for text in (
        "names but 2 positions",
        "non-finite position",
        "joint states name 1 joint: 'ghost' that the model does not have",
        "s before the stream's newest, which went on without them: dropped",
    ):
        assert text in log, text
    assert "Traceback" not in log


def test_200_hz_for_5_s_loses_no_output(start, domain) -> None:
    """Reliable QoS with queues as deep as the whole burst (an input qos_depth and an output QoS
    override) loses nothing however loaded the machine is: a late node only answers later."""
    node = start(
        "--urdf", str(PANDA), "--ros-args", "-p", "estimator.mode:=causal", "-p", "qos_depth:=2000",
        "-p", "qos_overrides./neforward/link_states.publisher.depth:=2000",
    )  # fmt: skip
    peer = Peer(domain)
    peer.writer("/joint_states", topics.JOINT_STATE_TYPE)
    peer.reader("/neforward/link_states", topics.LINK_STATES_TYPE)
    peer.wait_connected(node)
    times = np.arange(1000) / 200.0
    q = 0.5 * np.sin(np.outer(times, np.linspace(1.0, 3.0, len(NAMES))))
    states = [joint_state(EPOCH_NS + round(t * 1e9), NAMES, row.tolist()) for t, row in zip(times, q, strict=True)]
    received = stream(peer, states, rate=200.0, topics=["/neforward/link_states"])
    collect(peer, received, lambda r: len(r["/neforward/link_states"]) >= 930, timeout=60.0)
    stamps = [cdr.decode_multi_dof(b).stamp_ns for b in received["/neforward/link_states"]]
    # every input from 0.35 s (the causal window, 0.2 s, and from a start the record, 0.15 s at 200 Hz) on
    assert stamps == [s["header"]["stamp"]["sec"] * 10**9 + s["header"]["stamp"]["nanosec"] for s in states[70:]]


def test_names_and_types_on_the_wire_are_ros2s(start, domain) -> None:
    from cyclonedds.builtin import BuiltinDataReader, BuiltinTopicDcpsPublication, BuiltinTopicDcpsSubscription
    from cyclonedds.qos import Policy

    from neforward_ros.dds.qos import latched_qos
    from neforward_ros.dds.types import raw_reader

    node = start(
        "--urdf", str(PANDA), "--ros-args", "-r", "__ns:=/robot1", "-r", "joint_states:=/arm/joint_states",
        "-p", "imu_links:=[panda_hand]",
    )  # fmt: skip
    peer = Peer(domain)
    peer.writer("/arm/joint_states", topics.JOINT_STATE_TYPE)
    peer.reader("/robot1/neforward/link_states", topics.LINK_STATES_TYPE)
    peer.wait_connected(node)
    publications, subscriptions = {}, {}
    for kind, store in ((BuiltinTopicDcpsPublication, publications), (BuiltinTopicDcpsSubscription, subscriptions)):
        reader = BuiltinDataReader(peer.participant, kind)
        deadline = time.monotonic() + 5
        while time.monotonic() < deadline and len(store) < 3:
            for endpoint in reader.take(N=200):
                if endpoint.participant_key != peer.participant.guid:
                    store[endpoint.topic_name] = endpoint
            time.sleep(0.05)
    expected_writers = {
        "rt/robot1/neforward/link_states": topics.LINK_STATES_TYPE,
        "rt/robot1/neforward/com_states": topics.LINK_STATES_TYPE,
        "rt/robot1/neforward/panda_hand/imu": topics.IMU_TYPE,
        DISCOVERY_TOPIC: DISCOVERY_TYPE,
    }
    for topic, typename in expected_writers.items():
        endpoint = publications[topic]
        package, kind, name = typename.split("/")
        assert endpoint.type_name == f"{package}::{kind}::dds_::{name}_"
        assert endpoint.qos[Policy.Userdata].data == f"typehash={type_hash(typename)};".encode()
    assert type_hash(topics.LINK_STATES_TYPE).startswith("RIHS01_")
    joint_states = subscriptions["rt/arm/joint_states"]  # remapped from the relative joint_states
    assert joint_states.type_name == "sensor_msgs::msg::dds_::JointState_"

    # The ROS 2 graph: ros_discovery_info names the node and lists its endpoints' GIDs (GUIDs).
    info_reader = raw_reader(peer.participant, DISCOVERY_TOPIC, DISCOVERY_TYPE, latched_qos(DISCOVERY_TYPE))
    deadline = time.monotonic() + 5
    infos = []
    while time.monotonic() < deadline and not infos:
        infos = [rostypes.deserialize(DISCOVERY_TYPE, bytes(b)) for b in info_reader.take(N=10)]
        time.sleep(0.05)
    assert infos, "no ros_discovery_info sample"
    (node_info,) = infos[-1]["node_entities_info_seq"]
    assert (node_info["node_namespace"], node_info["node_name"]) == ("/robot1", "neforward")
    writer_gids = {bytes(g["data"]) for g in node_info["writer_gid_seq"]}
    assert publications["rt/robot1/neforward/link_states"].key.bytes in writer_gids
    reader_gids = {bytes(g["data"]) for g in node_info["reader_gid_seq"]}
    assert joint_states.key.bytes in reader_gids
    assert bytes(infos[-1]["gid"]["data"]) == joint_states.participant_key.bytes


def test_ctrl_c_exits_cleanly_and_startup_errors_are_one_line(start, config_uri, domain, tmp_path) -> None:
    node = start("--urdf", str(PANDA))
    deadline = time.monotonic() + STARTUP
    while "publishing" not in node.log() and time.monotonic() < deadline:
        time.sleep(0.05)
    assert node.stop(signal.SIGINT) == 0
    assert "Traceback" not in node.log() and "stopped:" in node.log()
    environment = {**os.environ, "CYCLONEDDS_URI": config_uri, "ROS_DOMAIN_ID": str(domain)}
    for arguments, text in (
        (["--urdf", "/no/such.urdf"], "cannot read URDF file"),
        (["--urdf", str(tmp_path / "bad.urdf")], "malformed URDF XML"),
        (["--urdf", str(PANDA), "--ros-args", "-p", "estimator.mode:=instant"], "estimator.mode must be one of"),
        (["--urdf", str(PANDA), "--ros-args", "--enclave", "x"], "not supported"),
    ):
        (tmp_path / "bad.urdf").write_text("<robot name='x'><link name='a'>")
        result = subprocess.run(
            [sys.executable, "-m", "neforward_ros", "run", *arguments],
            capture_output=True, text=True, timeout=60, env=environment,
        )  # fmt: skip
        assert result.returncode == 1, result.stderr
        assert text in result.stderr and result.stderr.count("\n") == 1, result.stderr


def test_echo_prints_yaml_like_ros2_topic_echo(start, config_uri, domain) -> None:
    node = start("--urdf", str(PANDA), "--ros-args", *PER_LINK)
    peer = Peer(domain)
    peer.writer("/joint_states", topics.JOINT_STATE_TYPE)
    peer.wait_connected(node)
    environment = {**os.environ, "CYCLONEDDS_URI": config_uri, "ROS_DOMAIN_ID": str(domain)}
    echo = subprocess.Popen(
        [sys.executable, "-m", "neforward_ros", "echo", "/neforward/panda_hand/accel", "--count", "2"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=environment,
    )  # fmt: skip
    try:
        time.sleep(3.0)  # the echo process discovers the node
        q = np.zeros(len(NAMES))
        stream(peer, still_states(q, 300, start_ns=EPOCH_NS), rate=100.0)
        out, err = echo.communicate(timeout=60)
    finally:
        echo.kill()
    assert echo.returncode == 0, err
    documents = [d for d in out.split("---\n") if d.strip()]
    assert len(documents) == 2
    assert documents[0].startswith("header:\n  stamp:\n    sec: ")
    assert "frame_id: panda_hand" in documents[0] and "accel:\n  linear:\n    x: " in documents[0]


def test_use_sim_time_stamps_zero_stamped_input_with_the_clock_topic(start, domain) -> None:
    node = start("--urdf", str(PANDA), "--ros-args", "-p", "use_sim_time:=true", "-p", "estimator.mode:=causal")
    peer = Peer(domain)
    peer.writer("/joint_states", topics.JOINT_STATE_TYPE)
    peer.writer("/clock", "rosgraph_msgs/msg/Clock")
    peer.reader("/neforward/link_states", topics.LINK_STATES_TYPE)
    peer.wait_connected(node)
    q = np.zeros(len(NAMES)).tolist()
    received: dict[str, list[bytes]] = {"/neforward/link_states": []}
    sim = 42 * 10**9
    for k in range(60):  # the simulator's clock ticks, the driver leaves header.stamp empty
        peer.write("/clock", {"clock": time_message(sim + k * 10_000_000)})
        time.sleep(0.02)
        peer.write("/joint_states", joint_state(0, NAMES, q))
        time.sleep(0.02)
    collect(peer, received, lambda r: len(r["/neforward/link_states"]) >= 8)
    stamps = [cdr.decode_multi_dof(b).stamp_ns for b in received["/neforward/link_states"]]
    assert stamps and all(sim + 4 * 10**8 <= s < sim + 6 * 10**8 for s in stamps), stamps  # (after the warm-up)
    assert "zero header.stamp" in node.log()


def test_a_base_imu_moves_the_quadruped(start, domain) -> None:
    """base.source imu on the floating-base quadruped: sensor_msgs/Imu from its IMU link over the wire,
    joint states at their own stamps; the trunk's and the feet's accelerations against the truth."""
    import importlib.util

    root = Path(__file__).resolve().parent.parent
    spec = importlib.util.spec_from_file_location("quadruped_trot", root / "examples" / "quadruped_trot.py")
    example = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(example)
    urdf = root / "config" / "quadruped.urdf"
    model = load_model(urdf)
    node = start("--urdf", str(urdf), "--ros-args", "-p", "base.source:=imu", "-p", "qos_depth:=2000",
                 "-p", "qos_overrides./neforward/link_states.publisher.depth:=2000")  # fmt: skip
    peer = Peer(domain)
    peer.writer("/joint_states", topics.JOINT_STATE_TYPE)
    peer.writer("/imu", topics.IMU_TYPE)
    peer.reader("/neforward/link_states", topics.LINK_STATES_TYPE)
    peer.wait_connected(node)
    t = np.arange(300) / 200.0  # joint states and IMU messages alternate, 2.5 ms apart
    q, _, _ = example.legs(t, model.joint_names)
    t_imu = t + 0.0025
    kin = forward_recursion(model, *example.legs(t_imu, model.joint_names), base=example.trunk_motion(t_imu))
    k = model.link_index["imu_link"]
    received = {"/neforward/link_states": []}
    for i in range(len(t)):
        peer.write("/joint_states", joint_state(EPOCH_NS + round(t[i] * 1e9), list(model.joint_names), q[i].tolist()))
        imu = {
            "header": {"stamp": time_message(EPOCH_NS + round(t_imu[i] * 1e9)), "frame_id": "imu_link"},
            "orientation_covariance": [-1.0] + [0.0] * 8,  # no orientation
            "angular_velocity": dict(zip("xyz", kin.omega[i, k].tolist(), strict=True)),
            "linear_acceleration": dict(zip("xyz", kin.accel[i, k].tolist(), strict=True)),
        }
        peer.write("/imu", imu)
        time.sleep(0.004)
        received["/neforward/link_states"] += peer.take("/neforward/link_states")
    collect(peer, received, lambda r: len(r["/neforward/link_states"]) >= 200, timeout=60.0)
    points = [cdr.decode_multi_dof(b) for b in received["/neforward/link_states"]]
    assert len(points) >= 200
    stamps = (np.array([p.stamp_ns for p in points]) - EPOCH_NS) / 1e9
    truth = forward_recursion(
        model, *example.legs(stamps, model.joint_names), base=example.trunk_motion(stamps)
    ).in_root()
    got = np.array([p.accelerations[:, :3] for p in points])
    error = np.sqrt(np.mean((got - truth.accel) ** 2) / np.mean(truth.accel**2))
    assert error <= 2e-2, error
    assert "Traceback" not in node.log()


def test_malformed_messages_mixed_into_a_good_stream_cost_no_good_output(start, domain) -> None:
    """The node, over the wire, fed a moving robot's joint states at 200 Hz for 5 s with every kind of
    malformed message mixed in: it stays up, publishes only finite numbers, answers the good messages
    with right values (all but the estimator's first and last 0.1 s), and its log stays short."""
    from test_bag import trajectory

    node = start("--ros-args", "-p", "publish_torques:=true")  # the model from the topic
    peer = Peer(domain)
    peer.writer("/joint_states", topics.JOINT_STATE_TYPE)
    peer.writer("/robot_description", topics.STRING_TYPE, latched=True)
    peer.reader("/neforward/link_states", topics.LINK_STATES_TYPE)
    peer.wait_connected(node)
    peer.write("/robot_description", {"data": PANDA.read_text()})
    deadline = time.monotonic() + 30
    while "model 'panda'" not in node.log() and time.monotonic() < deadline:
        time.sleep(0.05)
    count, rate = 1000, 200.0
    t = (np.arange(count) + np.random.default_rng(5).uniform(-0.1, 0.1, count)) / rate
    q, qd, _ = trajectory(t)
    stamps = [EPOCH_NS + round(x * 1e9) for x in t]
    good = [joint_state(s, NAMES, q[k].tolist(), qd[k].tolist()) | {"effort": [0.5] * 8} for k, s in enumerate(stamps)]
    nan = float("nan")
    bad = {  # before good message k
        50: joint_state(stamps[50] - 1, NAMES, [nan] * 8),
        100: joint_state(stamps[100] - 1, NAMES, [float("inf")] * 8),
        150: joint_state(stamps[150] - 1, NAMES, [0.0] * 3),
        200: joint_state(stamps[200] - 1, ["ghost", "phantom"], [1.0, 2.0]),
        250: joint_state(stamps[250] - 1, [*NAMES, NAMES[2]], [0.0] * 9),
        300: joint_state(stamps[300] - 1, [], []),
        350: joint_state(stamps[350] - 1, NAMES, q[350].tolist(), [0.0] * 3),
        400: joint_state(stamps[400] - 1, NAMES, q[400].tolist()) | {"effort": [nan] * 8},
        450: joint_state(stamps[450] - 5 * 10**9, NAMES, [9.0] * 8),
        500: joint_state(stamps[500] - 1, [f"j{i}" for i in range(20_000)], [0.0] * 20_000),
        550: joint_state(0, NAMES, [7.0] * 8),
    }
    received: dict[str, list[bytes]] = {"/neforward/link_states": []}
    started = time.monotonic()
    for k, message in enumerate(good):
        delay = started + k / rate - time.monotonic()
        if delay > 0:
            time.sleep(delay)
        if k in bad:
            peer.write("/joint_states", bad[k])
        if k == 600:
            peer.write("/robot_description", {"data": "<robot name='broken'><link name='a'>"})
        peer.write("/joint_states", message)
        received["/neforward/link_states"] += peer.take("/neforward/link_states")
    answered = count - 40  # the first and last 0.1 s have no estimate
    collect(peer, received, lambda r: len(r["/neforward/link_states"]) >= answered)
    assert node.alive()
    points = [cdr.decode_multi_dof(raw) for raw in received["/neforward/link_states"]]
    assert all(np.isfinite(p.accelerations).all() and np.isfinite(p.transforms).all() for p in points)
    by_stamp = {p.stamp_ns: p for p in points}
    good_answered = [k for k, s in enumerate(stamps) if s in by_stamp]
    assert len(good_answered) >= 0.95 * count, len(good_answered)
    assert set(by_stamp) <= set(stamps) | {stamps[350] - 1, stamps[400] - 1}  # partial good samples
    index = np.array(good_answered)
    kin = forward_recursion(MODEL, *trajectory(t[index])).in_root()
    got = np.array([by_stamp[stamps[k]].accelerations[:, :3] for k in index])
    error = np.sqrt(np.mean((got - kin.accel) ** 2)) / np.sqrt(np.mean(kin.accel**2))
    assert error <= 1e-2, error
    lines = node.log().count("\n")
    assert lines < 60, node.log()
    assert "invalid robot description" in node.log() and "Traceback" not in node.log()
