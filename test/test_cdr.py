"""cdr.encode against rosbags' own CDR serializer (an independent implementation), byte for byte."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from neforward_ros import InputError
from neforward_ros.wire import cdr, rostypes

TYPES = [
    "sensor_msgs/msg/JointState",
    "sensor_msgs/msg/Imu",
    "std_msgs/msg/String",
    "std_msgs/msg/Empty",
    "geometry_msgs/msg/AccelStamped",
    "geometry_msgs/msg/TwistStamped",
    "trajectory_msgs/msg/JointTrajectory",
    "trajectory_msgs/msg/MultiDOFJointTrajectory",
    "visualization_msgs/msg/Marker",
    "visualization_msgs/msg/MarkerArray",
    "rmw_dds_common/msg/ParticipantEntitiesInfo",
]

floats = st.floats(allow_nan=False, width=64)
names = st.text(max_size=8)
stamps = st.fixed_dictionaries({"sec": st.integers(-(2**31), 2**31 - 1), "nanosec": st.integers(0, 10**9 - 1)})
header = st.fixed_dictionaries({"stamp": stamps, "frame_id": names})
vector = st.fixed_dictionaries({"x": floats, "y": floats, "z": floats})
gid = st.fixed_dictionaries({"data": st.lists(st.integers(0, 255), min_size=16, max_size=16)})

SAMPLES = {
    "sensor_msgs/msg/JointState": st.fixed_dictionaries(
        {"header": header, "name": st.lists(names, max_size=4), "position": st.lists(floats, max_size=4)},
        optional={"velocity": st.lists(floats, max_size=3), "effort": st.lists(floats, max_size=2)},
    ),
    "trajectory_msgs/msg/MultiDOFJointTrajectory": st.fixed_dictionaries(
        {
            "header": header,
            "joint_names": st.lists(names, max_size=3),
            "points": st.lists(
                st.fixed_dictionaries(
                    {
                        "transforms": st.lists(st.fixed_dictionaries({"translation": vector}), max_size=3),
                        "velocities": st.lists(st.fixed_dictionaries({"angular": vector}), max_size=2),
                        "time_from_start": stamps,
                    }
                ),
                max_size=2,
            ),
        }
    ),
    "rmw_dds_common/msg/ParticipantEntitiesInfo": st.fixed_dictionaries(
        {
            "gid": gid,
            "node_entities_info_seq": st.lists(
                st.fixed_dictionaries(
                    {"node_namespace": names, "node_name": names, "reader_gid_seq": st.lists(gid, max_size=2)}
                ),
                max_size=2,
            ),
        }
    ),
}


@pytest.mark.parametrize("typename", TYPES)
def test_defaults_encode_like_rosbags(typename: str) -> None:
    assert cdr.encode(typename, {}) == rostypes.serialize(typename, {})


@pytest.mark.parametrize("typename", sorted(SAMPLES))
@settings(max_examples=60, deadline=None)
@given(data=st.data())
def test_random_contents_encode_like_rosbags(typename: str, data) -> None:
    contents = data.draw(SAMPLES[typename])
    encoded = cdr.encode(typename, contents)
    assert encoded == rostypes.serialize(typename, contents)
    assert rostypes.deserialize(typename, encoded) == rostypes.deserialize(
        typename, rostypes.serialize(typename, contents)
    )


def test_bad_contents_are_input_errors() -> None:
    with pytest.raises(InputError, match="unknown ROS 2 message type"):
        cdr.encode("nope/msg/Nope", {})
    with pytest.raises(InputError, match="needs exactly 9 values"):
        cdr.encode("sensor_msgs/msg/Imu", {"orientation_covariance": [0.0] * 8})
    with pytest.raises(InputError, match="cannot encode"):
        cdr.encode("geometry_msgs/msg/Vector3", {"x": "fast"})


@settings(max_examples=60, deadline=None)
@given(contents=SAMPLES["trajectory_msgs/msg/MultiDOFJointTrajectory"])
def test_multi_dof_decoder_reads_what_rosbags_reads(contents) -> None:
    encoded = cdr.encode("trajectory_msgs/msg/MultiDOFJointTrajectory", contents)
    if not contents["points"]:
        with pytest.raises(InputError, match="without points"):
            cdr.decode_multi_dof(encoded)
        return
    decoded = cdr.decode_multi_dof(encoded)
    expected = rostypes.deserialize("trajectory_msgs/msg/MultiDOFJointTrajectory", encoded)
    stamp = expected["header"]["stamp"]
    assert decoded.stamp_ns == stamp["sec"] * 10**9 + stamp["nanosec"]
    assert decoded.frame_id == expected["header"]["frame_id"]
    assert list(decoded.joint_names) == expected["joint_names"]
    point = expected["points"][0]
    transforms = [[*t["translation"].values(), *t["rotation"].values()] for t in point["transforms"]]
    assert decoded.transforms.tolist() == transforms
    velocities = [[*v["linear"].values(), *v["angular"].values()] for v in point["velocities"]]
    assert decoded.velocities.tolist() == velocities
    assert decoded.accelerations.shape == (len(point["accelerations"]), 6)


@settings(max_examples=80, deadline=None)
@given(contents=SAMPLES["sensor_msgs/msg/JointState"])
def test_joint_state_decoder_reads_what_rosbags_reads(contents) -> None:
    encoded = cdr.encode("sensor_msgs/msg/JointState", contents)
    stamp, names, positions, velocities, efforts = cdr.decode_joint_state(encoded)
    expected = rostypes.deserialize("sensor_msgs/msg/JointState", encoded)
    assert stamp == expected["header"]["stamp"]["sec"] * 10**9 + expected["header"]["stamp"]["nanosec"]
    assert list(names) == expected["name"]
    assert positions.tolist() == expected["position"] and velocities.tolist() == expected["velocity"]
    assert efforts.tolist() == expected["effort"]
    with pytest.raises(InputError):
        cdr.decode_joint_state(encoded[: len(encoded) // 2] if len(encoded) > 40 else b"\x01\x00")


@settings(max_examples=40, deadline=None)
@given(
    names=st.lists(st.sampled_from(["a", "b", "elbow", "j_4"]), min_size=1, max_size=4, unique=True),
    others=st.lists(st.sampled_from(["a", "b", "elbow", "j_4"]), min_size=0, max_size=3, unique=True),
    plan=st.lists(st.tuples(st.booleans(), st.integers(0, 2), st.booleans()), min_size=1, max_size=30),
    frame=st.sampled_from(["", "base", "a_longer_frame"]),
)
def test_bulk_joint_state_decoding_reads_what_rosbags_reads(names, others, plan, frame) -> None:
    """Messages of one layout and of others, interleaved, some malformed (names and positions of
    different lengths), some with velocities or efforts: grouped by names, each message's numbers."""
    rng = np.random.default_rng(len(plan))
    encoded = []
    for k, (second, extra, malformed) in enumerate(plan):
        chosen = others if second and others else names
        n = len(chosen)
        contents = {
            "header": {"stamp": {"sec": 1_700_000_000 + k, "nanosec": 1000 * k}, "frame_id": frame},
            "name": chosen,
            "position": rng.uniform(-1, 1, n + (1 if malformed else 0)).tolist(),
            "velocity": rng.uniform(-1, 1, n).tolist() if extra >= 1 else [],
            "effort": rng.uniform(-1, 1, n).tolist() if extra >= 2 else [],
        }
        encoded.append(cdr.encode("sensor_msgs/msg/JointState", contents))
    batch = cdr.decode_joint_states(encoded)
    seen = set(batch.malformed)
    for message_names, (indices, positions, velocities, efforts) in batch.groups.items():
        for row, index in enumerate(indices.tolist()):
            expected = rostypes.deserialize("sensor_msgs/msg/JointState", encoded[index])
            assert tuple(expected["name"]) == message_names and index not in seen
            seen.add(index)
            assert positions[row].tolist() == expected["position"]
            for got, field in ((velocities, "velocity"), (efforts, "effort")):
                assert got[row].tolist() == expected[field] if expected[field] else np.all(np.isnan(got[row]))
    for index, data in enumerate(encoded):
        expected = rostypes.deserialize("sensor_msgs/msg/JointState", data)
        assert (
            batch.stamps[index] == expected["header"]["stamp"]["sec"] * 10**9 + expected["header"]["stamp"]["nanosec"]
        )
        assert (index in batch.malformed) == (len(expected["name"]) != len(expected["position"]))
    assert seen == set(range(len(encoded)))


def test_type_facts_kept_on_disk_read_back_and_spare_the_type_store(tmp_path) -> None:
    """The facts of a type come from rosbags' type store once, then from the disk cache: equal, and a
    new process encoding messages of types seen before does not build the type store at all."""
    import os
    import subprocess
    import sys

    code = (
        "import sys, json; from neforward_ros.wire import cdr, rostypes; "
        "cdr.encode('trajectory_msgs/msg/MultiDOFJointTrajectory', {}); "
        "cdr.encode('sensor_msgs/msg/Imu', {}); "
        "print(json.dumps([rostypes.facts('sensor_msgs/msg/Imu'), "
        "'rosbags.typesys.stores.ros2_jazzy' in sys.modules]))"
    )
    environment = {**os.environ, "NEFORWARD_CACHE": str(tmp_path)}
    runs = [
        subprocess.run([sys.executable, "-c", code], env=environment, capture_output=True, text=True, timeout=60)
        for _ in range(2)
    ]
    import json

    (first, built_first), (second, built_second) = (json.loads(run.stdout) for run in runs)
    assert (built_first, built_second) == (True, False)
    assert first == second
    store = rostypes.typestore()
    assert second["rihs01"] == store.hash_rihs01("sensor_msgs/msg/Imu")
    assert second["msgdef"] == store.generate_msgdef("sensor_msgs/msg/Imu", ros_version=2)[0]
