"""neforward bag: recordings written with rosbags, processed, read back and compared with Pinocchio
on the analytic trajectory; every bad-input case gives one error line and no output."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from rosbags.rosbag2 import Reader, StoragePlugin, Writer

from neforward_ros.bag import BagOptions, process_bag
from neforward_ros.cli import main
from neforward_ros.interface import messages, topics
from neforward_ros.stamps import time_message
from neforward_ros.wire import cdr
from neforward_ros.wire.rostypes import typestore

from conftest import CONFIG_DIR, EPOCH_NS
from oracle import PinocchioOracle

PANDA = CONFIG_DIR / "panda.urdf"
FREQUENCIES = np.linspace(0.3, 1.2, 8)
AMPLITUDES = np.array([0.5, 0.4, 0.5, 0.4, 0.5, 0.4, 0.5, 0.01])  # the last is the finger (prismatic, m)
NAMES = [f"panda_joint{k}" for k in range(1, 8)] + ["panda_finger_joint1"]


def trajectory(t: np.ndarray):
    w = 2 * np.pi * FREQUENCIES
    arg = np.outer(t, w) + np.arange(8)
    return AMPLITUDES * np.sin(arg), AMPLITUDES * w * np.cos(arg), -AMPLITUDES * w**2 * np.sin(arg)


def record(path, *, seconds=4.0, velocities=False, storage=StoragePlugin.MCAP, description=True, runs=1, **extra):
    rng = np.random.default_rng(1)
    count = int(seconds * 500)
    t = (np.arange(count) + rng.uniform(-0.1, 0.1, count)) / 500.0
    if "gap" in extra:  # 0.3 s without samples from there on
        t = t[(t < extra["gap"]) | (t >= extra["gap"] + 0.3)]
        count = len(t)
    q, qd, _ = trajectory(t)
    if "finger" in extra:  # the finger still at this position
        q[:, -1], qd[:, -1] = extra["finger"], 0.0
    if extra.get("without_finger"):  # a driver that does not send the finger's joint
        q, qd = q[:, :-1], qd[:, :-1]
    store = typestore()
    with Writer(path, version=9, storage_plugin=storage) as writer:
        joint_states = writer.add_connection("/joint_states", topics.JOINT_STATE_TYPE, typestore=store)
        if description:
            connection = writer.add_connection("/robot_description", topics.STRING_TYPE, typestore=store)
            writer.write(connection, EPOCH_NS, cdr.encode(topics.STRING_TYPE, {"data": PANDA.read_text()}))
        for topic, kind in extra.get("other_topics", []):
            writer.add_connection(topic, kind, typestore=store)
        names = extra.get("names", NAMES[:-1] if extra.get("without_finger") else NAMES)
        strays = extra.get("strays", {})
        for run in range(runs):  # concatenated runs: stamps go back at each new run
            for k in range(count):
                stamp = EPOCH_NS + round(t[k] * 1e9)
                if k in strays:  # a malformed message first: (stamp, names, positions)
                    stray_stamp, stray_names, stray_positions = strays[k](stamp)
                    stray = {"header": {"stamp": time_message(stray_stamp)}, "name": stray_names,
                             "position": stray_positions}  # fmt: skip
                    writer.write(
                        joint_states, EPOCH_NS + round(t[k] * 1e9) - 1, cdr.encode(topics.JOINT_STATE_TYPE, stray)
                    )
                contents = {"header": {"stamp": time_message(stamp)}, "name": names, "position": q[k].tolist()}
                if velocities:
                    contents["velocity"] = qd[k].tolist()
                log_time = EPOCH_NS + run * 10**10 + round(t[k] * 1e9)
                writer.write(joint_states, log_time, cdr.encode(topics.JOINT_STATE_TYPE, contents))
    return t


def covered(t: np.ndarray) -> np.ndarray:
    """The samples with an estimate: their 0.2 s window (0.1 s either side) inside the recording, up to
    half a sample interval at the end (where the node emits a fixed-lag estimate)."""
    return (t - 0.1 >= t[0]) & (t + 0.1 <= t[-1] + 0.5 * np.median(np.diff(t)))


def read_output(path) -> dict[str, list]:
    out: dict[str, list] = {}
    with Reader(path) as reader:
        for connection, log_time, raw in reader.messages():
            out.setdefault(connection.topic, []).append((log_time, raw))
    return out


def relative_rms(estimate, truth) -> float:
    return float(np.sqrt(np.mean((estimate - truth) ** 2) / np.mean(truth**2)))


def check_against_pinocchio(link_states: list, com_states: list) -> None:
    oracle = PinocchioOracle(PANDA)
    from neforward_ros import load_model

    model = load_model(PANDA)
    got, want, got_com, want_com, got_alpha, want_alpha = [], [], [], [], [], []
    for (_, raw), (_, raw_com) in list(zip(link_states, com_states, strict=True))[::25]:
        point, com = cdr.decode_multi_dof(raw), cdr.decode_multi_dof(raw_com)
        tk = (point.stamp_ns - EPOCH_NS) / 1e9
        q, qd, qdd = (x[0] for x in trajectory(np.array([tk])))
        expected = oracle.kinematics(model.joint_names, model.link_names, q, qd, qdd)
        rotation = expected["rotation"]
        got.append(point.accelerations[:, :3])
        want.append(np.einsum("kij,kj->ki", rotation, expected["accel"]))
        got_alpha.append(point.accelerations[:, 3:])
        want_alpha.append(np.einsum("kij,kj->ki", rotation, expected["alpha"]))
        got_com.append(com.accelerations[:, :3])
        want_com.append(np.einsum("kij,kj->ki", rotation, expected["com_accel"]))
    gravity = np.array([0.0, 0.0, 9.81])  # compare kinematic parts: the specific force minus +g
    assert relative_rms(np.array(got) - gravity, np.array(want) - gravity) <= 1e-2
    assert relative_rms(np.array(got_com) - gravity, np.array(want_com) - gravity) <= 1e-2
    assert relative_rms(np.array(got_alpha), np.array(want_alpha)) <= 1e-2


@pytest.mark.parametrize(
    "storage, velocities", [(StoragePlugin.MCAP, False), (StoragePlugin.SQLITE3, True), (StoragePlugin.MCAP, True)]
)
def test_outputs_match_pinocchio_on_the_analytic_trajectory(tmp_path, storage, velocities) -> None:
    t = record(tmp_path / "in", storage=storage, velocities=velocities)
    assert main(["bag", str(tmp_path / "in"), "-o", str(tmp_path / "out"), "--imu-links", "panda_hand"]) == 0
    out = read_output(tmp_path / "out")
    assert set(out) == {"/neforward/link_states", "/neforward/com_states", "/neforward/panda_hand/imu"}
    stamps = [cdr.decode_multi_dof(raw).stamp_ns for _, raw in out["/neforward/link_states"]]
    assert stamps == (EPOCH_NS + np.round(t[covered(t)] * 1e9).astype(np.int64)).tolist()
    check_against_pinocchio(out["/neforward/link_states"], out["/neforward/com_states"])
    log_time, raw = out["/neforward/panda_hand/imu"][0]
    imu = typestore().deserialize_cdr(raw, topics.IMU_TYPE)
    assert imu.header.frame_id == "panda_hand" and log_time == out["/neforward/link_states"][0][0]


def test_batched_messages_equal_the_node_message_building(tmp_path) -> None:
    """The bag's vectorised encoding gives the same bytes as the node's per-message path."""
    from neforward_ros import load_model
    from neforward_ros.computation.result import make_result
    from neforward_ros.kinematics.forward import kinematics_table, root_state

    model = load_model(PANDA)
    t = np.linspace(0.0, 1.0, 7)
    q, qd, qdd = trajectory(t)
    stamps = EPOCH_NS + np.round(t * 1e9).astype(np.int64)
    batch = make_result(model, stamps, kinematics_table(model, q, qd, qdd, root_state()))
    _ = batch.blocks  # computed for the batch: its samples take their numbers from it
    for builder, blocks in (
        (messages.link_states, messages.link_states_blocks),
        (messages.com_states, messages.com_states_blocks),
    ):
        template = cdr.encode(topics.LINK_STATES_TYPE, builder(batch.sample(0), "p/"))
        rows = cdr.MultiDofTemplate(template).encode_many(stamps, *blocks(batch))
        for i in range(len(t)):
            # byte for byte what the per-message path encodes from the same numbers
            assert rows[i].tobytes() == cdr.encode(topics.LINK_STATES_TYPE, builder(batch.sample(i), "p/"))
            # and the same numbers as the node's single-sample computation, to rounding
            single = make_result(model, int(stamps[i]), kinematics_table(model, q[i], qd[i], qdd[i], root_state()))
            a = cdr.decode_multi_dof(rows[i].tobytes())
            b = cdr.decode_multi_dof(cdr.encode(topics.LINK_STATES_TYPE, builder(single, "p/")))
            assert a.stamp_ns == b.stamp_ns and a.joint_names == b.joint_names
            for x, y in zip(
                (a.transforms, a.velocities, a.accelerations),
                (b.transforms, b.velocities, b.accelerations),
                strict=True,
            ):
                np.testing.assert_allclose(x, y, rtol=0, atol=1e-12)


def test_concatenated_runs_are_segments_each_estimated_on_its_own(tmp_path, capsys) -> None:
    t = record(tmp_path / "in", runs=2, seconds=2.0)
    assert main(["bag", str(tmp_path / "in"), "-o", str(tmp_path / "out"), "--urdf", str(PANDA)]) == 0
    printed = capsys.readouterr().out
    assert "2 segments" in printed and "segment 2: 1000 messages" in printed
    out = read_output(tmp_path / "out")
    each = int(covered(t).sum())  # each run on its own: no estimate near either end of either
    assert len(out["/neforward/link_states"]) == 2 * each
    halves = out["/neforward/link_states"][:each], out["/neforward/link_states"][each:]
    for half, com in zip(
        halves, (out["/neforward/com_states"][:each], out["/neforward/com_states"][each:]), strict=True
    ):
        check_against_pinocchio(half, com)


def test_stray_messages_in_a_recording_cost_no_other_output(tmp_path, capsys) -> None:
    """The node's rules offline: the outputs of a recording with single malformed messages mixed in are
    those of the recording without them, byte for byte, for the whole-recording estimator and for the
    replayed one alike."""
    strays = {
        300: lambda stamp: (stamp - 1, [*NAMES, NAMES[0]], [0.1] * 9),  # a joint named twice
        400: lambda stamp: (stamp - 5 * 10**9, NAMES, [1.0] * 8),  # 5 s in the past
        500: lambda stamp: (0, NAMES, [2.0] * 8),  # a zero stamp among stamped ones
        600: lambda stamp: (stamp - 1, [f"x{i}" for i in range(20_000)], [0.0] * 20_000),  # huge, all unknown
        700: lambda stamp: (stamp + 60 * 10**9, NAMES, [3.0] * 8),  # a minute ahead
        800: lambda stamp: (stamp - 1, NAMES, [0.0] * 7),  # a length mismatch
    }
    record(tmp_path / "clean", seconds=2.0)
    record(tmp_path / "dirty", seconds=2.0, strays=strays)
    for flags in ([], ["-p", "estimator.mode:=causal"]):
        outputs = {}
        for name in ("clean", "dirty"):
            out = tmp_path / f"{name}_out{len(flags)}"
            assert main(["bag", str(tmp_path / name), "-o", str(out), "--urdf", str(PANDA), *flags]) == 0
            outputs[name] = [raw for _, raw in read_output(out)["/neforward/link_states"]]
        printed = capsys.readouterr()
        assert len(outputs["clean"]) > 800 and outputs["dirty"] == outputs["clean"], flags
        assert "name joint 'panda_joint1' more than once: dropped" in printed.out
        assert "ignored, not joints of the model: 20000 names: 'x0', 'x1', 'x2' and 19997 more" in printed.out
        assert "segments" not in printed.out  # one segment: nothing went back and on from there
        assert "6 joint state message(s) dropped by the node's rules" in printed.out
        assert "s before the stream's newest, which went on without them: dropped" in printed.out
        assert "zero header.stamp among stamped ones: dropped" in printed.out


def test_no_output_whose_window_reaches_into_a_gap(tmp_path) -> None:
    t = record(tmp_path / "in", seconds=3.0, gap=1.5)
    process_bag(tmp_path / "in", tmp_path / "out", BagOptions())
    stamps = np.array(
        [cdr.decode_multi_dof(raw).stamp_ns for _, raw in read_output(tmp_path / "out")["/neforward/link_states"]]
    )
    out = (stamps - EPOCH_NS) / 1e9
    last_before, first_after = t[t < 1.5].max(), t[t >= 1.5].min()
    before, after = out[out < 1.5], out[out >= 1.5]
    # the 0.1 s either side of each output lies within the samples, give or take 1.5 sample intervals
    assert before.max() + 0.1 <= last_before + 1.5 * 0.0022 and before.max() + 0.1 > last_before - 0.0022
    assert after.min() - 0.1 >= first_after - 1e-9
    check_against_pinocchio(
        *(read_output(tmp_path / "out")[topic] for topic in ("/neforward/link_states", "/neforward/com_states"))
    )


def test_csv_and_plot(tmp_path) -> None:
    t = record(tmp_path / "in", seconds=1.0)
    report = process_bag(
        tmp_path / "in", tmp_path / "out", BagOptions(), csv_path=tmp_path / "a.csv", plot_path=tmp_path / "a.png"
    )
    count = int(covered(t).sum())
    assert report.samples_out == count
    lines = (tmp_path / "a.csv").read_text().splitlines()
    header = lines[0].split(",")
    assert header[:2] == ["stamp_ns", "t[s]"]
    assert "panda_hand.accel_in_root.z[m/s^2]" in header and "panda_tcp.alpha_in_root.x[rad/s^2]" in header
    assert len(lines) == count + 1 and len(lines[1].split(",")) == len(header)
    base = lines[1].split(",")
    assert float(base[header.index("panda_link0.accel_in_root.z[m/s^2]")]) == pytest.approx(9.81)
    assert (tmp_path / "a.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert not [p for p in tmp_path.iterdir() if "partial" in p.name]


def bad_cases(tmp_path):
    (tmp_path / "text.txt").write_text("hello")
    record(tmp_path / "no_js", seconds=0.1, description=True, names=NAMES, other_topics=[])
    with Writer(tmp_path / "only_other", version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        connection = writer.add_connection("/odom_text", topics.STRING_TYPE, typestore=typestore())
        writer.write(connection, EPOCH_NS, cdr.encode(topics.STRING_TYPE, {"data": "x"}))
    record(tmp_path / "missing_joint", seconds=0.2, names=[*NAMES[:-1], "not_the_finger"])
    record(tmp_path / "corrupt", seconds=1.0)
    storage = next((tmp_path / "corrupt").glob("*.mcap"))
    data = storage.read_bytes()
    storage.write_bytes(data[: len(data) // 2])
    record(tmp_path / "ok", seconds=0.2)
    (tmp_path / "exists").mkdir()
    # issue 14: a plain recording (no robot_description) and no --urdf; an empty joint-state topic
    record(tmp_path / "plain", seconds=0.2, description=False)
    record(tmp_path / "empty", seconds=0.0)
    (tmp_path / "xacro.urdf.xacro").write_text(
        '<robot name="x" xmlns:xacro="http://www.ros.org/wiki/xacro"><xacro:property name="L" value="1"/>'
        '<link name="a"/><link name="b"/><joint name="j" type="revolute"><parent link="a"/><child link="b"/>'
        '<origin xyz="0 0 ${L}"/><axis xyz="0 0 1"/><limit lower="0" upper="1" effort="1" velocity="1"/>'
        "</joint><xacro:undefined_macro/></robot>"
    )
    ok = str(tmp_path / "ok")
    return [
        ([str(tmp_path / "plain"), "-o", str(tmp_path / "o9")], "give the URDF with --urdf FILE", tmp_path / "o9"),
        ([str(tmp_path / "empty"), "-o", str(tmp_path / "o10")], "/joint_states in", tmp_path / "o10"),
        ([ok, "-o", str(tmp_path / "o11"), "--csv", "/missing/x.csv"], "no such folder /missing", tmp_path / "o11"),
        ([ok, "-o", str(tmp_path / "missing" / "dir" / "out")], "no such folder", tmp_path / "missing"),
        ([ok, "-o", str(tmp_path / "o12"), "-p", "estimator.window:=fast"], "estimator.window", tmp_path / "o12"),
        ([ok, "-o", str(tmp_path / "o13"), "-p", "no_such_parameter:=1"], "no_such_parameter", tmp_path / "o13"),
        ([ok, "-o", str(tmp_path / "o14"), "--params", str(tmp_path / "nope.yaml")], "nope.yaml", tmp_path / "o14"),
        ([ok, "-o", str(tmp_path / "o15"), "--accel-links", "not_a_link"], "'not_a_link'", tmp_path / "o15"),
        (
            [ok, "-o", str(tmp_path / "o16"), "--urdf", str(tmp_path / "xacro.urdf.xacro")],
            "xacro",
            tmp_path / "o16",
        ),
        ([str(tmp_path / "nope"), "-o", str(tmp_path / "o1")], "no such file or directory", tmp_path / "o1"),
        (
            [str(tmp_path / "text.txt"), "-o", str(tmp_path / "o2")],
            "is not a readable rosbag2 recording",
            tmp_path / "o2",
        ),
        (
            [str(tmp_path / "only_other"), "-o", str(tmp_path / "o3")],
            "no sensor_msgs/msg/JointState topic",
            tmp_path / "o3",
        ),
        (
            [str(tmp_path / "ok"), "-o", str(tmp_path / "o8"), "--publish-policy", "hold", "--hold", "ghost=1"],
            "hold.joint_names (--hold) names joints that robot 'panda' does not have: ghost",
            tmp_path / "o8",
        ),
        ([str(tmp_path / "corrupt"), "-o", str(tmp_path / "o5")], "truncated or corrupt", tmp_path / "o5"),
        ([str(tmp_path / "ok"), "-o", str(tmp_path / "exists")], "exists already", None),
        (
            [str(tmp_path / "ok"), "-o", str(tmp_path / "o7"), "--urdf", str(tmp_path / "text.txt")],
            "URDF",
            tmp_path / "o7",
        ),
    ]


def test_bad_input_is_one_error_line_and_no_output(tmp_path, capsys) -> None:
    for arguments, text, output in bad_cases(tmp_path):
        assert main(["bag", *arguments]) == 1, arguments
        err = capsys.readouterr().err
        assert err.startswith("neforward: error: ") and err.count("\n") == 1, err
        assert text in err, err
        if output is not None:
            assert not output.exists()
        assert not [p for p in tmp_path.iterdir() if "partial" in p.name]
    # the topic listing names what is there
    assert main(["bag", str(tmp_path / "only_other"), "-o", str(tmp_path / "o8")]) == 1
    assert "/odom_text (std_msgs/msg/String)" in capsys.readouterr().err


def test_batched_mcap_writing_equals_rosbags_message_by_message(tmp_path, monkeypatch) -> None:
    from neforward_ros.bag import write as bag_write

    if not bag_write.fast_mcap_allowed():
        pytest.skip("the installed rosbags is not one the fast MCAP path is made for: it is not used")
    t = record(tmp_path / "in", seconds=3.0)
    calls = []
    fast_writer = bag_write._write_rows_mcap
    monkeypatch.setattr(bag_write, "_write_rows_mcap", lambda *a: calls.append(1) or fast_writer(*a))
    process_bag(tmp_path / "in", tmp_path / "fast", BagOptions())
    assert calls  # the fast path did write
    monkeypatch.setattr(bag_write, "_FAST_MCAP", False)
    process_bag(tmp_path / "in", tmp_path / "slow", BagOptions())
    fast, slow = read_output(tmp_path / "fast"), read_output(tmp_path / "slow")
    assert fast.keys() == slow.keys() and all(fast[topic] == slow[topic] for topic in fast)
    with Reader(tmp_path / "fast") as reader:
        counts = {c.topic: c.msgcount for c in reader.connections}
        count = int(covered(t).sum())
        assert counts == {"/neforward/link_states": count, "/neforward/com_states": count}
        assert reader.duration > 2.7e9
        # read back through the chunk indexes too (what players use), not only in file order
        window = list(reader.messages(start=reader.start_time + 10**9, stop=reader.start_time + 2 * 10**9))
    assert 990 <= len(window) <= 1010  # about 1 s of both topics at 500 Hz


def test_batched_and_single_messages_in_the_same_chunks_read_back_in_order_through_every_index(tmp_path) -> None:
    """The batched writing closes rosbags' chunks itself (message indexes from arrays): chunks that also
    hold messages rosbags wrote one by one, before and after batches, read back whole, by file order
    and through the chunk and message indexes."""
    from neforward_ros.bag import write as bag_write

    if not bag_write.fast_mcap_allowed():
        pytest.skip("the installed rosbags is not one the fast MCAP path is made for: it is not used")
    kind = "std_msgs/msg/Float64"
    sent: dict[str, list[tuple[int, bytes]]] = {"/single": [], "/a": [], "/b": []}
    with Writer(tmp_path / "mixed", version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        single = writer.add_connection("/single", kind, typestore=typestore())
        pair = [writer.add_connection(topic, kind, typestore=typestore()) for topic in ("/a", "/b")]
        stamp = 10**18
        for _ in range(40):  # 40 x 3000 batched messages of 28 bytes: about 6 chunks
            for _single in range(7):
                data = cdr.encode(kind, {"data": float(stamp)})
                writer.write(single, stamp, data)
                sent["/single"].append((stamp, bytes(data)))
                stamp += 1000
            times = stamp + 1000 * np.arange(3000, dtype=np.int64)
            streams = []
            for connection in pair:
                rows = np.stack(
                    [np.frombuffer(cdr.encode(kind, {"data": float(t + connection.id)}), np.uint8) for t in times]
                )
                streams.append(
                    (connection, rows.shape[1], lambda part, out, rows=rows: out.__setitem__(..., rows[part]))
                )
                sent[connection.topic] += [(int(t), bytes(r)) for t, r in zip(times, rows, strict=True)]
            assert bag_write._write_rows_mcap(writer, streams, times)
            stamp = int(times[-1]) + 1000
    with Reader(tmp_path / "mixed") as reader:
        assert {c.topic: c.msgcount for c in reader.connections} == {t: len(m) for t, m in sent.items()}
        got: dict[str, list[tuple[int, bytes]]] = {t: [] for t in sent}
        for connection, timestamp, raw in reader.messages():
            got[connection.topic].append((timestamp, bytes(raw)))
        assert got == sent
        middle = (reader.start_time + reader.end_time) // 2
        window = [(c.topic, t) for c, t, _ in reader.messages(start=middle, stop=middle + 5 * 10**6)]
    expected = sorted((t, topic) for topic, m in sent.items() for t, _ in m if middle <= t < middle + 5 * 10**6)
    assert sorted((t, topic) for topic, t in window) == expected and len(expected) > 5000
    assert message_indexes_point_at_their_messages(tmp_path / "mixed" / "mixed.mcap") == sum(map(len, sent.values()))


def message_indexes_point_at_their_messages(path: Path) -> int:
    """Checks, by the MCAP specification, that every message index record (opcode 0x07) after a chunk
    (0x06, uncompressed) lists each message of its channel in that chunk, by log time and offset into
    the chunk's records; returns how many messages the indexes list."""
    data = path.read_bytes()
    position, records, listed = 8, None, 0
    in_chunk: dict[int, list[tuple[int, int]]] = {}
    while position < len(data) - 8:
        opcode = data[position]
        length = int.from_bytes(data[position + 1 : position + 9], "little")
        body = data[position + 9 : position + 9 + length]
        position += 9 + length
        if opcode == 0x06:
            compression_length = int.from_bytes(body[28:32], "little")
            assert body[32 : 32 + compression_length] == b""
            records = body[32 + compression_length + 8 :]
            assert len(records) == int.from_bytes(body[16:24], "little")
            in_chunk = {}
            at = 0
            while at < len(records):
                size = int.from_bytes(records[at + 1 : at + 9], "little")
                if records[at] == 0x05:
                    channel = int.from_bytes(records[at + 9 : at + 11], "little")
                    log_time = int.from_bytes(records[at + 15 : at + 23], "little")
                    in_chunk.setdefault(channel, []).append((log_time, at))
                at += 9 + size
        elif opcode == 0x07:
            channel = int.from_bytes(body[0:2], "little")
            pairs = np.frombuffer(body[6:], dtype="<u8").reshape(-1, 2)
            assert int.from_bytes(body[2:6], "little") == pairs.nbytes
            assert [tuple(p) for p in pairs.tolist()] == in_chunk.pop(channel), channel
            listed += len(pairs)
    return listed


def test_the_fast_mcap_path_is_only_taken_with_the_rosbags_releases_it_was_checked_against(
    tmp_path, monkeypatch
) -> None:
    from neforward_ros.bag import write as bag_write

    record(tmp_path / "in", seconds=0.5)
    calls = []
    monkeypatch.setattr(bag_write, "_write_rows_mcap", lambda *a: calls.append(1) or False)
    monkeypatch.setattr(bag_write, "FAST_MCAP_ROSBAGS", frozenset({"0.0.0"}))
    bag_write.fast_mcap_allowed.cache_clear()
    try:
        process_bag(tmp_path / "in", tmp_path / "out", BagOptions())
    finally:
        bag_write.fast_mcap_allowed.cache_clear()
    assert calls == [] and len(read_output(tmp_path / "out")["/neforward/link_states"]) > 100


def test_chunks_of_samples_give_the_same_outputs_as_one_pass(tmp_path, monkeypatch) -> None:
    """The recursion, encoding, recording, CSV and plot data go chunk by chunk (bounded memory):
    the outputs must not depend on where the chunks end."""
    from neforward_ros.bag import compute

    record(tmp_path / "in", seconds=3.0)
    process_bag(tmp_path / "in", tmp_path / "whole", BagOptions(), csv_path=tmp_path / "whole.csv")
    monkeypatch.setattr(compute, "CHUNK", 333)
    process_bag(tmp_path / "in", tmp_path / "chunked", BagOptions(), csv_path=tmp_path / "chunked.csv")
    whole, chunked = read_output(tmp_path / "whole"), read_output(tmp_path / "chunked")
    assert whole.keys() == chunked.keys() and all(whole[topic] == chunked[topic] for topic in whole)
    assert (tmp_path / "whole.csv").read_text() == (tmp_path / "chunked.csv").read_text()


def test_a_block_of_stamps_without_output_at_any_edge_changes_nothing(tmp_path, monkeypatch) -> None:
    """Blocks made only of stamps the estimates do not cover (the start's warm-up, the end's last
    half window): for every block size putting a block edge at each of those stamps, the torques and
    the stamps with output are those of one pass; the whole command too, with the last block's edge
    at each stamp of the end (once a crash in the backward pass on an empty block, found on the
    last 40 % of the Panda recording)."""
    from neforward_ros.bag import compute
    from neforward_ros.bag.read import read
    from neforward_ros.bag.report import Progress
    from neforward_ros.computation.compute import ComputeState

    record(tmp_path / "in", seconds=0.5)
    options = BagOptions.from_parameters({"publish_torques": True})
    recording = read(tmp_path / "in", options, Progress(False))
    model = recording.model
    inputs = compute.prepare_inputs(recording, options, lambda what, fraction: None)

    def torques(size: int) -> tuple[np.ndarray, np.ndarray]:
        parts = list(compute.results(model, inputs, options, [], ComputeState.new(model, options.settings), size))
        done = [r for r, _, _ in parts if r is not None]
        return np.concatenate([r.stamp_ns for r in done]), np.concatenate([r.dynamics.torques for r in done])

    stamps, expected = torques(len(inputs))
    count = len(inputs)
    first = int(np.searchsorted(inputs.states.stamps, stamps[0]))
    last = int(np.searchsorted(inputs.states.stamps, stamps[-1]))
    assert first >= 2 and count - 1 - last >= 2  # stamps without output at both ends
    for size in sorted({*range(1, first + 2), *(count - j for j in range(1, count - last + 1))}):
        got_stamps, got = torques(size)
        assert np.array_equal(got_stamps, stamps) and np.array_equal(got, expected), size
    whole = process_bag(tmp_path / "in", tmp_path / "whole", options)
    expected_out = read_output(tmp_path / "whole")
    for size in (count - j for j in range(1, count - last + 1)):
        monkeypatch.setattr(compute, "CHUNK", size)
        report = process_bag(tmp_path / "in", tmp_path / f"c{size}", options)
        assert report.samples_out == whole.samples_out, size
        got_out = read_output(tmp_path / f"c{size}")
        assert got_out.keys() == expected_out.keys() and all(got_out[t] == expected_out[t] for t in got_out), size


@pytest.mark.parametrize("policy", ["partial", "wait", "hold"])
def test_a_joint_never_in_the_recording_is_held_and_everything_else_is_computed(tmp_path, policy, capsys) -> None:
    """A driver that does not send the gripper's joint: under every publish policy the finger is held
    at --hold's position (at rest), and the torques, link states and external torques are those of a
    recording where the finger is present and still at that position; the summary counts what each
    topic got and warns once."""
    record(tmp_path / "arm", seconds=1.0, without_finger=True)
    record(tmp_path / "still", seconds=1.0, finger=0.02)
    arguments = ["--torques", "--publish-policy", policy, "--hold", "panda_finger_joint1=0.02"]
    assert main(["bag", str(tmp_path / "arm"), "-o", str(tmp_path / "held"), *arguments]) == 0
    said = capsys.readouterr()
    assert main(["bag", str(tmp_path / "still"), "-o", str(tmp_path / "present"), *arguments]) == 0
    held, present = read_output(tmp_path / "held"), read_output(tmp_path / "present")
    assert held.keys() == present.keys() and "/neforward/joint_torques" in held
    store = typestore()
    for topic in held:
        assert [t for t, _ in held[topic]] == [t for t, _ in present[topic]], topic
        assert len(held[topic]) > 350, topic
    for topic, kind in (("/neforward/joint_torques", topics.JOINT_STATE_TYPE),):
        for (_, a), (_, b) in zip(held[topic], present[topic], strict=True):
            x, y = store.deserialize_cdr(a, kind), store.deserialize_cdr(b, kind)
            np.testing.assert_allclose(x.effort, y.effort, rtol=0, atol=1e-9)
    text = said.out + said.err
    assert text.count("never in the recording") == 1 and "panda_finger_joint1 at 0.02" in text, text
    count = len(held["/neforward/joint_torques"])
    assert f"/neforward/joint_torques {count}" in text, text


def test_the_summary_counts_what_each_topic_got(tmp_path, capsys) -> None:
    """The summary says how many messages each output topic got, as the recording holds them."""
    record(tmp_path / "in", seconds=1.0)
    assert main(["bag", str(tmp_path / "in"), "-o", str(tmp_path / "out"), "--torques"]) == 0
    text = capsys.readouterr()
    written = read_output(tmp_path / "out")
    for topic, got in written.items():
        assert f"{topic} {len(got)}" in text.out + text.err, (topic, text)


def test_the_payload_example_finds_the_payload_in_the_external_torques(tmp_path) -> None:
    """examples/payload_recording.py: a 2 kg payload from 2 s to 4 s that the URDF does not know. The
    bag tool's contact intervals and external torques against J^T w computed by Pinocchio."""
    import subprocess
    import sys

    from test_torques import Loaded

    root = Path(__file__).resolve().parent.parent
    example = root / "examples" / "payload_recording.py"
    subprocess.run([sys.executable, str(example), str(tmp_path / "run")], check=True, capture_output=True)
    options = BagOptions.from_parameters(
        {
            "publish_torques": True,
            "contact.joint_names": ["panda_joint2", "panda_joint4"],
            "contact.thresholds": [2.0, 2.0],
            "contact.debounce": 0.02,
        }
    )
    report = process_bag(tmp_path / "run", tmp_path / "out", options, csv_path=tmp_path / "out.csv")
    ((start, end),) = report.contacts
    assert 2.0 + 0.02 <= start <= 2.0 + 0.03 and 4.0 + 0.02 <= end <= 4.0 + 0.03
    out = read_output(tmp_path / "out")
    assert len(out["/neforward/joint_torques"]) == len(out["/neforward/link_states"]) == report.samples_out
    contact = [typestore().deserialize_cdr(raw, topics.BOOL_TYPE).data for _, raw in out["/neforward/contact"]]
    assert sum(contact) > 900  # about 2 s of 500 Hz
    # external torques in the CSV against Pinocchio's J^T w at the true states, while the payload is held
    import importlib.util

    spec = importlib.util.spec_from_file_location("payload_recording", example)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    header, *rows = (tmp_path / "out.csv").read_text().splitlines()
    names = header.split(",")
    table = np.array([[float(x) for x in row.split(",")] for row in rows])
    t = (table[:, 0] - module.EPOCH) / 1e9
    joint = "panda_joint2"
    column = table[:, names.index(f"{joint}.external_torque[N*m]")]
    loaded = Loaded()
    from neforward_ros import load_model

    model = load_model(PANDA)
    held = (t > 2.1) & (t < 3.9)
    q, qd, qdd = module.trajectory(t[held], len(model.joint_names))
    j = model.joint_index[joint]
    truth = np.array([loaded.jacobian_transpose_wrench(*x)[j] for x in zip(q, qd, qdd, strict=True)])
    assert np.sqrt(np.mean((column[held] - truth) ** 2)) <= 0.1  # N m: 0.05 N m effort noise, estimated qdd
    assert np.abs(column[(t > 0.5) & (t < 1.9)]).max() <= 0.3  # no payload: nothing but noise


def test_the_trotting_quadruped_example_with_its_base_imu(tmp_path) -> None:
    """examples/quadruped_trot.py: a floating-base URDF, a base IMU off the trunk's origin; every
    link's acceleration against the recursion at the true trunk motion and leg states."""
    import importlib.util
    import subprocess
    import sys

    from neforward_ros import forward_recursion, load_model

    root = Path(__file__).resolve().parent.parent
    example = root / "examples" / "quadruped_trot.py"
    subprocess.run([sys.executable, str(example), str(tmp_path / "trot")], check=True, capture_output=True)
    options = BagOptions.from_parameters({"base.source": "imu", "world_frame": "world"})
    report = process_bag(tmp_path / "trot", tmp_path / "out", options)
    assert report.samples_out > 1800
    spec = importlib.util.spec_from_file_location("quadruped_trot", example)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    model = load_model(root / "config" / "quadruped.urdf")
    out = read_output(tmp_path / "out")
    points = [cdr.decode_multi_dof(raw) for _, raw in out["/neforward/link_states"]]
    stamps = np.array([p.stamp_ns for p in points])
    t = (stamps - module.EPOCH) / 1e9
    truth = forward_recursion(model, *module.legs(t, model.joint_names), base=module.trunk_motion(t)).in_root()
    got = np.array([p.accelerations for p in points])
    for field, k in (("accel", slice(0, 3)), ("alpha", slice(3, 6))):
        error = relative_rms(got[:, :, k], getattr(truth, field))
        assert error <= 2e-2, (field, error)
    feet = [model.link_index[f"{leg}_foot"] for leg in ("lf", "rf", "lh", "rh")]
    assert relative_rms(got[:, feet, :3], truth.accel[:, feet]) <= 2e-2
    # world_link_states: the trunk's kinematic acceleration in the world is its position's second derivative
    world = [cdr.decode_multi_dof(raw) for _, raw in out["/neforward/world_link_states"]]
    assert world[0].frame_id == "world" and len(world) == len(points)
    h = 1e-4
    expected = (module.trunk_pose(t + h)[1] - 2 * module.trunk_pose(t)[1] + module.trunk_pose(t - h)[1]) / h**2
    trunk = np.array([w.accelerations[0, :3] for w in world])
    assert np.sqrt(np.mean((trunk - expected) ** 2)) <= 0.05  # m/s^2; the bounce is 0.015 m at 4 Hz: 9.5 m/s^2


def test_the_fast_mcap_reading_gives_what_rosbags_gives(tmp_path) -> None:
    """The joint states read straight from the MCAP chunks: the same data, times and order as rosbags'
    Reader.messages, over many chunks and with other topics interleaved (and only with the rosbags
    releases the fast path was checked against)."""
    from neforward_ros.bag import mcap_read
    from neforward_ros.bag.write import fast_mcap_allowed

    record(tmp_path / "rec", seconds=60.0, other_topics=[("/other", topics.STRING_TYPE)])
    with Reader(tmp_path / "rec") as reader:
        connections = [c for c in reader.connections if c.topic == "/joint_states"]
        expected = [(t, raw) for _, t, raw in reader.messages(connections=connections)]
        fast = mcap_read.messages(reader, connections)
        assert sum(len(getattr(f, "chunks", [])) for f in getattr(reader.storage, "storages", [reader.storage])) > 3
    if not fast_mcap_allowed():
        assert fast is None
        return
    raws, times = fast
    assert times.tolist() == [t for t, _ in expected] and raws == [raw for _, raw in expected]


def test_the_stated_deviations_are_the_nodes_through_a_gap_and_a_time_reset(tmp_path) -> None:
    """The default's stated sigma pools the last half window's estimates (adaptive.pooled_std in the
    bag tool, adaptive.DeviationPool in the node): through a 0.3 s gap (the joints' histories
    restart) and a second run whose stamps go back (a new segment, the pool starts afresh), the
    node fed the recording's messages in order and the bag tool state the same sigma stamp by stamp."""
    from neforward_ros.node.pipeline import Pipeline
    from neforward_ros.parameters.settings import node_settings
    from neforward_ros.wire.rostypes import deserialize

    record(tmp_path / "in", seconds=2.0, runs=2, gap=1.0)
    assert main(["bag", str(tmp_path / "in"), "-o", str(tmp_path / "out"), "--urdf", str(PANDA),
                 "--joint-estimates"]) == 0  # fmt: skip
    written = [deserialize(topics.JOINT_TRAJECTORY_TYPE, raw) for _, raw in read_output(tmp_path / "out")[
        "/neforward/joint_estimates"]]  # fmt: skip
    pipeline = Pipeline(node_settings({"robot_description": PANDA.read_text(), "publish_joint_estimates": True}))
    published = []
    with Reader(tmp_path / "in") as reader:
        for connection, _, raw in reader.messages():
            if connection.topic == "/joint_states":
                m = deserialize(topics.JOINT_STATE_TYPE, raw)
                stamp = m["header"]["stamp"]["sec"] * 10**9 + m["header"]["stamp"]["nanosec"]
                for result in pipeline.on_joint_state(stamp, m["name"], m["position"]):
                    published.append(dict(pipeline.messages(result))[topics.JOINT_ESTIMATES])
    assert len(written) == len(published) > 1000
    node = np.array([p["points"][0]["effort"] for p in published])
    bag = np.array([w["points"][0]["effort"] for w in written])
    assert [w["header"]["stamp"] for w in written] == [p["header"]["stamp"] for p in published]
    assert node.shape == bag.shape and np.all(node > 0)
    np.testing.assert_allclose(bag, node, rtol=1e-9)
