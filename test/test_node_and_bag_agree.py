"""The node and the bag tool are one computation: on the same recording (a trotting quadruped with a
base IMU, efforts, torques, wrenches, contact and world-frame states), what the node publishes for the
recording's messages fed in their recording order and what ``neforward bag`` writes agree to 1e-9
relative, stamp by stamp, on every topic; with the node's default estimator (the bag's
whole-recording fit) and with a replayed one (causal); and with the default on stamps written after the
samples (the node's fits re-timed, the bag tool replaying)."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
from rosbags.rosbag2 import Reader, StoragePlugin, Writer

from neforward_ros import forward_recursion, load_model
from neforward_ros.cli import main
from neforward_ros.computation.base_motion import base_message
from neforward_ros.interface import topics
from neforward_ros.node.pipeline import Pipeline
from neforward_ros.parameters.settings import node_settings
from neforward_ros.rotations import quaternions
from neforward_ros.stamps import time_message
from neforward_ros.wire import cdr
from neforward_ros.wire.rostypes import deserialize, typestore

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "examples"))
from quadruped_trot import URDF, legs, trunk_motion, trunk_pose

from conftest import EPOCH_NS

PARAMETERS = {
    "base.source": "imu",
    "world_frame": "world",
    "publish_torques": True,
    "wrench_links": ["lf_foot"],
    "contact.joint_names": ["lf_hfe", "rh_kfe"],
    "contact.thresholds": [6.0, 6.0],
    "accel_links": ["rf_foot"],
    "imu_links": ["trunk"],
    "publish_joint_estimates": True,
}
FLAGS = [
    "--base", "imu", "--world-frame", "world", "--torques", "--wrench-links", "lf_foot",
    "--contact", "lf_hfe=6.0", "--contact", "rh_kfe=6.0", "--accel-links", "rf_foot", "--imu-links", "trunk",
    "--joint-estimates",
]  # fmt: skip


@pytest.fixture(scope="module")
def recording(tmp_path_factory) -> Path:
    """3 s of trotting: joint states at 500 Hz (jittered stamps, positions, velocities and efforts
    that swing over and under the contact thresholds; some messages repeat the one before under a new
    stamp) and the IMU at 400 Hz, in stamp order."""
    rng = np.random.default_rng(3)
    t = (np.arange(1500) + rng.uniform(-0.1, 0.1, 1500)) / 500.0
    return write_trot(tmp_path_factory.mktemp("agree") / "trot", t, t, rng)


@pytest.fixture(scope="module")
def written_recording(tmp_path_factory) -> Path:
    """The same motion sampled every 2 ms exactly and each message stamped when written, 0-0.8 ms later:
    the node finds the stamps to be write times and fits on the clock it recovers; the bag tool replays
    the recording through it."""
    rng = np.random.default_rng(5)
    sampled = np.arange(1500) / 500.0
    written = sampled + rng.uniform(0.0, 0.0008, len(sampled))
    return write_trot(tmp_path_factory.mktemp("agree") / "written", sampled, written, rng)


def write_trot(path: Path, t_sampled: np.ndarray, t: np.ndarray, rng: np.random.Generator) -> Path:
    """The recording: joint states sampled at ``t_sampled`` (s) and stamped ``t``; see :func:`recording`."""
    model = load_model(URDF)
    names = list(model.joint_names)
    count = len(t)
    q, qd, _ = legs(t_sampled, model.joint_names)
    efforts = 8.0 * np.sin(2 * np.pi * 0.7 * t[:, None] + np.arange(len(names))) + rng.normal(0, 0.05, q.shape)
    for first in range(40, count - 10, 41):  # a driver's repeated readings, runs of 1 to 3, under new stamps
        for i in range(first, first + 1 + first % 3):
            q[i], qd[i], efforts[i] = q[i - 1], qd[i - 1], efforts[i - 1]
    t_imu = np.arange(1200) / 400.0 + 0.0011
    kin = forward_recursion(model, *legs(t_imu, model.joint_names), base=trunk_motion(t_imu))
    k = model.link_index["imu_link"]
    orientation = quaternions(trunk_pose(t_imu)[0] @ kin.rotation[:, k])
    store = typestore()
    events = sorted([(x, 0, i) for i, x in enumerate(t)] + [(x, 1, i) for i, x in enumerate(t_imu)])
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        description = writer.add_connection("/robot_description", topics.STRING_TYPE, typestore=store)
        writer.write(description, EPOCH_NS, cdr.encode(topics.STRING_TYPE, {"data": URDF.read_text()}))
        joint_states = writer.add_connection("/joint_states", topics.JOINT_STATE_TYPE, typestore=store)
        imu = writer.add_connection("/imu", topics.IMU_TYPE, typestore=store)
        for x, kind, i in events:
            stamp = EPOCH_NS + round(x * 1e9)
            if kind == 0:
                contents = {"header": {"stamp": time_message(stamp)}, "name": names, "position": q[i].tolist(),
                            "velocity": qd[i].tolist(), "effort": efforts[i].tolist()}  # fmt: skip
                writer.write(joint_states, stamp, cdr.encode(topics.JOINT_STATE_TYPE, contents))
            else:
                contents = {
                    "header": {"stamp": time_message(stamp), "frame_id": "imu_link"},
                    "orientation": dict(zip("xyzw", orientation[i].tolist(), strict=True)),
                    "angular_velocity": dict(zip("xyz", kin.omega[i, k].tolist(), strict=True)),
                    "linear_acceleration": dict(zip("xyz", kin.accel[i, k].tolist(), strict=True)),
                }
                writer.write(imu, stamp, cdr.encode(topics.IMU_TYPE, contents))
    return path


def node_outputs(path: Path, parameters: dict) -> dict[str, dict[int, bytes]]:
    """What the node publishes, per topic and stamp, for the recording's messages in recording order."""
    pipeline = Pipeline(node_settings({"robot_description": URDF.read_text(), **PARAMETERS, **parameters}))
    out: dict[str, dict[int, bytes]] = {}
    with Reader(path) as reader:
        for connection, log_time, raw in reader.messages():
            if connection.topic == "/joint_states":
                m = deserialize(topics.JOINT_STATE_TYPE, raw)
                stamp = m["header"]["stamp"]["sec"] * 10**9 + m["header"]["stamp"]["nanosec"]
                results = pipeline.on_joint_state(stamp, m["name"], m["position"], m["velocity"], m["effort"])
            elif connection.topic == "/imu":
                results = pipeline.on_base(base_message("imu", deserialize(topics.IMU_TYPE, raw), log_time))
            else:
                continue
            for result in results:
                for topic, data in pipeline.encode(result):
                    out.setdefault("/neforward/" + topic.removeprefix("~/"), {})[result.stamp_ns] = data
    return out


def bag_outputs(path: Path, output: Path, flags: list[str]) -> dict[str, dict[int, bytes]]:
    assert main(["bag", str(path), "-o", str(output), *FLAGS, *flags]) == 0
    out: dict[str, dict[int, bytes]] = {}
    with Reader(output) as reader:
        for connection, _, raw in reader.messages():
            contents = deserialize(connection.msgtype, raw)
            header = contents.get("header") if isinstance(contents, dict) else None
            messages = out.setdefault(connection.topic, {})
            stamp = header["stamp"]["sec"] * 10**9 + header["stamp"]["nanosec"] if header else len(messages)
            messages[stamp] = raw
    return out


def numbers(contents) -> list[float]:
    """Every number of a message's contents, in order."""
    if isinstance(contents, dict):
        return [x for value in contents.values() for x in numbers(value)]
    if isinstance(contents, (list, tuple)):
        return [x for value in contents for x in numbers(value)]
    if isinstance(contents, bool):
        return [float(contents)]
    if isinstance(contents, (int, float)):
        return [float(contents)]
    return []


@pytest.mark.parametrize("flags", [[], ["-p", "estimator.mode:=causal"]], ids=["default", "causal"])
def test_the_node_and_the_bag_tool_agree_stamp_by_stamp(recording, tmp_path, flags) -> None:
    agree(recording, tmp_path, flags)


def test_the_node_and_the_bag_tool_agree_on_stamps_written_after_the_samples(written_recording, tmp_path) -> None:
    """The default setting on write stamps: the node re-times its fits (:mod:`~neforward_ros.estimation.clock`),
    the bag tool replays the recording through it (its whole-recording fit, on the stamps, would not agree)."""
    agree(written_recording, tmp_path, [])


def agree(recording: Path, tmp_path: Path, flags: list[str]) -> None:
    """The node's and the bag tool's outputs on ``recording`` with these bag flags, stamp by stamp."""
    parameters = {"estimator.mode": "causal"} if flags else {}
    node = node_outputs(recording, parameters)
    bag = bag_outputs(recording, tmp_path / "out", flags)
    contact = "/neforward/contact"
    types = {
        "/neforward/link_states": topics.LINK_STATES_TYPE, "/neforward/com_states": topics.LINK_STATES_TYPE,
        "/neforward/world_link_states": topics.LINK_STATES_TYPE, "/neforward/joint_torques": topics.JOINT_STATE_TYPE,
        "/neforward/external_torques": topics.JOINT_STATE_TYPE, "/neforward/lf_foot/wrench": topics.WRENCH_TYPE,
        "/neforward/rf_foot/accel": topics.ACCEL_TYPE, "/neforward/rf_foot/twist": topics.TWIST_TYPE,
        "/neforward/trunk/imu": topics.IMU_TYPE, "/neforward/joint_estimates": topics.JOINT_TRAJECTORY_TYPE,
    }  # fmt: skip
    assert set(types) | {contact} <= set(bag) and set(bag) <= set(node), (sorted(bag), sorted(node))
    for topic, kind in types.items():
        assert set(bag[topic]) == set(node[topic]) and len(bag[topic]) > 1000, topic
        for stamp, data in bag[topic].items():
            got, want = numbers(deserialize(kind, data)), numbers(deserialize(kind, node[topic][stamp]))
            assert len(got) == len(want), (topic, stamp)
            scale = max(1.0, max(abs(x) for x in want))
            assert max(abs(a - b) for a, b in zip(got, want, strict=True)) <= 1e-9 * scale, (topic, stamp)
    # contact (std_msgs/Bool has no stamp): the same sequence of states, and both changed state
    bag_states = [deserialize(topics.BOOL_TYPE, d)["data"] for d in bag[contact].values()]
    node_states = [deserialize(topics.BOOL_TYPE, node[contact][s])["data"] for s in sorted(node[contact])]
    assert len(bag_states) > 1000 and len(set(bag_states)) == 2 and bag_states == node_states
