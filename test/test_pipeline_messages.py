"""Pipeline and message building without ROS, against Pinocchio.

Each message is built by the pipeline, turned into the ROS 2 Jazzy message type from the rosbags
type store (unknown or misspelt fields fail there), serialized to CDR and read back, and its values
are compared with Pinocchio's frame quantities, re-expressed as the README documents: root axes for
link_states and com_states, link frame for accel/twist/imu, specific force for the IMU.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from neforward_ros.node.pipeline import Pipeline, TrajectoryPoint
from neforward_ros.parameters.settings import node_settings
from neforward_ros.wire import rostypes

from conftest import CONFIG_DIR, TEST_ROBOTS, assert_close
from oracle import GRAVITY, PinocchioOracle

PANDA = CONFIG_DIR / "panda.urdf"
STAMP = 1_700_000_123 * 10**9 + 456_789_012
REL = 1e-9


def roundtrip(pipeline: Pipeline, result) -> dict[str, dict]:
    types = {output.topic: output.type for output in pipeline.outputs()}
    out = {}
    for topic, contents in pipeline.messages(result):
        out[topic] = rostypes.deserialize(types[topic], rostypes.serialize(types[topic], contents))
    assert set(out) == set(types), "every declared output is published, and nothing else"
    return out


def vec(message: dict) -> np.ndarray:
    return np.array([message["x"], message["y"], message["z"]])


def rotation_of(quaternion: dict) -> np.ndarray:
    q = [quaternion[k] for k in ("x", "y", "z", "w")]
    assert abs(np.linalg.norm(q) - 1.0) < 1e-12
    return Rotation.from_quat(q).as_matrix()


@pytest.mark.parametrize("robot", ["panda", "tree", "arm_6r", "mimic"])
def test_every_message_field_matches_pinocchio(robot: str) -> None:
    path = TEST_ROBOTS[robot]
    probe = Pipeline(node_settings({"robot_description": path.read_text()}))
    model = probe.model
    links = list(model.link_names)
    last = links[-1]
    pipeline = Pipeline(
        node_settings(
            {
                "robot_description": path.read_text(),
                "accel_links": [links[1], last],
                "imu_links": [last],
                "publish_markers": True,
                "marker_scale": 0.05,
                "frame_prefix": "left/",
                "acceleration_source": "supplied",
            }
        )
    )
    rng = np.random.default_rng(3)
    n = len(model.joint_names)
    q, qd, qdd = rng.uniform(-2, 2, n), rng.uniform(-3, 3, n), rng.uniform(-10, 10, n)
    names = list(model.joint_names)
    order = rng.permutation(n)  # the message's joint order need not be the model's
    point = TrajectoryPoint(q[order].tolist(), qd[order].tolist(), qdd[order].tolist(), time_from_start_ns=5)
    (result,) = pipeline.on_joint_trajectory(STAMP, [names[i] for i in order], [point])
    got = roundtrip(pipeline, result)
    pin_kin = PinocchioOracle(path).kinematics(model.joint_names, model.link_names, q, qd, qdd)
    rotation = pin_kin["rotation"]

    def root(field: str) -> np.ndarray:
        return np.einsum("kij,kj->ki", rotation, pin_kin[field])

    stamp = {"sec": (STAMP + 5) // 10**9, "nanosec": (STAMP + 5) % 10**9}
    for topic, com in (("~/link_states", False), ("~/com_states", True)):
        message = got[topic]
        assert message["header"] == {"stamp": stamp, "frame_id": "left/" + model.root_link}
        assert message["joint_names"] == links
        (trajectory_point,) = message["points"]
        transforms = trajectory_point["transforms"]
        twists = trajectory_point["velocities"]
        accels = trajectory_point["accelerations"]
        for k in range(len(links)):
            position = pin_kin["com_position" if com else "position"][k]
            assert_close(vec(transforms[k]["translation"]), position, REL, f"{topic} {links[k]} translation")
            assert_close(rotation_of(transforms[k]["rotation"]), rotation[k], REL, f"{topic} rotation")
            assert_close(vec(twists[k]["angular"]), root("omega")[k], REL, f"{topic} omega")
            assert_close(vec(accels[k]["angular"]), root("alpha")[k], REL, f"{topic} alpha")
            linear_v = root("com_velocity" if com else "velocity")[k]
            linear_a = root("com_accel" if com else "accel")[k]
            assert_close(vec(twists[k]["linear"]), linear_v, REL, f"{topic} {links[k]} linear velocity")
            assert_close(vec(accels[k]["linear"]), linear_a, REL, f"{topic} {links[k]} linear acceleration")

    for k, link in ((1, links[1]), (len(links) - 1, last)):
        accel, twist = got[f"~/{link}/accel"], got[f"~/{link}/twist"]
        for message in (accel, twist):
            assert message["header"] == {"stamp": stamp, "frame_id": "left/" + link}
        assert_close(vec(accel["accel"]["linear"]), pin_kin["accel"][k], REL, "accel linear (link frame)")
        assert_close(vec(accel["accel"]["angular"]), pin_kin["alpha"][k], REL, "accel angular")
        assert_close(vec(twist["twist"]["linear"]), pin_kin["velocity"][k], REL, "twist linear")
        assert_close(vec(twist["twist"]["angular"]), pin_kin["omega"][k], REL, "twist angular")

    imu = got[f"~/{last}/imu"]
    k = len(links) - 1
    assert imu["header"]["frame_id"] == "left/" + last
    assert_close(rotation_of(imu["orientation"]), rotation[k], REL, "imu orientation")
    assert_close(vec(imu["angular_velocity"]), pin_kin["omega"][k], REL, "imu angular velocity")
    # Specific force: Pinocchio's classical acceleration minus gravity, in the IMU (link) frame.
    assert_close(vec(imu["linear_acceleration"]), pin_kin["accel"][k], REL, "imu linear acceleration")
    for field in ("orientation_covariance", "angular_velocity_covariance", "linear_acceleration_covariance"):
        assert imu[field] == [0.0] * 9  # sensor_msgs/Imu: all zeros = covariance unknown

    markers = got["~/markers"]["markers"]
    assert [m["id"] for m in markers] == list(range(len(links)))
    for k, marker in enumerate(markers):
        assert (
            marker["type"] == 0 and marker["action"] == 0 and marker["header"]["frame_id"] == "left/" + model.root_link
        )
        start, end = (vec(p) for p in marker["points"])
        assert_close(start, pin_kin["com_position"][k], REL, "marker start")
        assert_close((end - start) / 0.05, root("com_accel")[k], 1e-8, "marker arrow")


def test_imu_at_rest_reads_gravity_upward_and_zero_gravity_reads_nothing() -> None:
    xml = PANDA.read_text()
    for gravity, expected in (([0.0, 0.0, -9.81], 9.81), ([0.0, 0.0, 0.0], 0.0)):
        pipeline = Pipeline(
            node_settings(
                {"robot_description": xml, "imu_links": ["panda_link0"], "gravity": gravity, "estimator.mode": "causal"}
            )
        )
        n = len(pipeline.model.joint_names)
        out = []
        for k in range(250):  # a robot standing still, positions only, for more than the 0.2 s window and the record
            out += pipeline.on_joint_state(STAMP + k * 2_000_000, list(pipeline.model.joint_names), [0.3] * n)
        imu = dict(pipeline.messages(out[-1]))["~/panda_link0/imu"]
        assert imu["linear_acceleration"] == pytest.approx({"x": 0.0, "y": 0.0, "z": expected}, abs=1e-9)


def test_estimated_joint_states_give_the_link_accelerations_of_the_true_trajectory() -> None:
    """Positions only at 500 Hz with jitter -> link accelerations within 1e-2 of Pinocchio at the true state."""
    xml = PANDA.read_text()
    pipeline = Pipeline(node_settings({"robot_description": xml}))
    model = pipeline.model
    n = len(model.joint_names)
    rng = np.random.default_rng(5)
    t = (np.arange(600) + rng.uniform(-0.1, 0.1, 600)) / 500.0
    omega = 2 * np.pi * np.linspace(0.3, 1.2, n)
    amplitude = np.where(np.array(model.joint_names) == "panda_finger_joint1", 0.01, 0.5)

    def state(times: np.ndarray):
        arg = np.outer(times, omega)
        return amplitude * np.sin(arg), amplitude * omega * np.cos(arg), -amplitude * omega**2 * np.sin(arg)

    q, _, _ = state(t)
    stamps = STAMP + np.round(t * 1e9).astype(np.int64)
    results = []
    for k in range(len(t)):
        results += pipeline.on_joint_state(int(stamps[k]), list(model.joint_names), q[k].tolist())
    assert len(results) > 400
    oracle = PinocchioOracle(PANDA)
    errors, scale = [], []
    for result in results[::20]:
        tk = (result.stamp_ns - STAMP) / 1e9
        expected = oracle.kinematics(model.joint_names, model.link_names, *(x[0] for x in state(np.array([tk]))))
        errors.append(result.in_link.com_accel - expected["com_accel"])
        scale.append(expected["com_accel"] - expected["rotation"].transpose(0, 2, 1) @ -GRAVITY)
    relative = np.sqrt(np.mean(np.square(errors)) / np.mean(np.square(scale)))
    assert relative <= 1e-2


def test_joint_states_before_a_model_are_dropped_and_the_model_can_come_later() -> None:
    lines = []
    pipeline = Pipeline(node_settings({}), log=lambda level, message: lines.append(message))
    assert any("waiting for the model on the robot_description topic" in line for line in lines)
    for k in range(5):
        assert pipeline.on_joint_state(STAMP + k, ["panda_joint1"], [0.0]) == []
    assert sum("no robot model yet" in line for line in lines) == 1  # throttled
    assert not pipeline.set_description("<robot name='broken'><link name='a'/>")
    assert any("invalid robot description" in line and "still waiting" in line for line in lines)
    assert pipeline.set_description(PANDA.read_text())
    assert not pipeline.set_description("<robot name='x'><joint name='j' type='revolute'/></robot>")
    assert pipeline.model.name == "panda" and any("keeping the previous model" in line for line in lines)


def test_missing_joints_and_bad_supplied_points_are_logged_not_raised() -> None:
    lines = []
    pipeline = Pipeline(
        node_settings({"robot_description": PANDA.read_text(), "estimator.mode": "causal", "accel_links": ["nope"]}),
        log=lambda level, message: lines.append(message),
    )
    assert any("does not have: nope" in line for line in lines)
    assert not [o for o in pipeline.outputs() if "nope" in o.topic]  # not announced, not published
    names = list(pipeline.model.joint_names)
    out = []
    for k in range(10):  # the gripper driver never publishes
        out += pipeline.on_joint_state(STAMP + k * 2_000_000, names[:7], [0.1] * 7)
    assert out == [] and sum("panda_finger_joint1" in line for line in lines) == 1
    n = len(names)
    partial = TrajectoryPoint([0.0] * (n - 1), [0.0] * (n - 1), [0.0] * (n - 1))
    assert pipeline.on_joint_trajectory(STAMP, names[:-1], [partial]) == []
    assert any("no finite position, velocity and acceleration for panda_finger_joint1" in line for line in lines)
    bad_points = [
        TrajectoryPoint([0.0] * n, [0.0] * n, [0.0] * (n - 1)),
        TrajectoryPoint([0.0] * n, [0.0] * n, [float("nan")] * n),
    ]
    assert pipeline.on_joint_trajectory(STAMP, names, bad_points) == []  # logged, throttled
    assert any(f"{n} joint names but {n}/{n}/{n - 1} positions/velocities/accelerations" in line for line in lines)
    zeros = [0.0] * (n + 1)
    good = pipeline.on_joint_trajectory(STAMP, [*names, "ghost"], [TrajectoryPoint(zeros, zeros, zeros)])
    assert len(good) == 1 and any("'ghost'" in line for line in lines)


def test_link_names_that_cannot_be_topic_names_are_rejected_up_front() -> None:
    from neforward_ros import ModelError

    with pytest.raises(ModelError, match="cannot be part of a ROS 2 topic name"):
        Pipeline(node_settings({"accel_links": ["left-hand"]}))


@pytest.mark.parametrize("robot", ["panda", "tree", "mimic", "humanoid"])
@pytest.mark.parametrize("partial", [False, True])
def test_published_bytes_are_the_encoded_contents(robot: str, partial: bool) -> None:
    """The node publishes link_states and com_states patched into templates: the bytes must be those
    of the message contents (checked against Pinocchio above) encoded message by message, for the
    whole robot and for the links determined when a joint is never heard."""
    from neforward_ros.wire import cdr

    path = TEST_ROBOTS[robot]
    probe = Pipeline(node_settings({"robot_description": path.read_text()}))
    links = list(probe.model.link_names)
    pipeline = Pipeline(
        node_settings(
            {
                "robot_description": path.read_text(),
                "accel_links": [links[-1]],
                "imu_links": [links[1]],
                "publish_markers": True,
                "frame_prefix": "left/",
                "estimator.mode": "causal",
            }
        )
    )
    names = list(pipeline.model.joint_names)
    if partial:
        names = names[:-1]
    rng = np.random.default_rng(3)
    results = []
    for k in range(250):  # (causal: from 0.36 s on, the window and the record)
        results += pipeline.on_joint_state(STAMP + k * 2_000_000, names, rng.uniform(-1, 1, len(names)).tolist())
    types = {output.topic: output.type for output in pipeline.outputs()}
    assert len(results) > 10
    assert all((len(r.link_names) < len(links)) == partial for r in results)
    for result in results:
        published = pipeline.encode(result)
        expected = [(topic, cdr.encode(types[topic], contents)) for topic, contents in pipeline.messages(result)]
        assert published == expected
