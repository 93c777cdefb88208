"""neforward_node on a real ROS 2 Jazzy: built with colcon, started with ``ros2 run``, fed and read by
a real rclpy client in its own process, inspected with the ros2 command-line tools."""

from __future__ import annotations

import re

import pytest
import yaml

from neforward_ros import load_model
from neforward_ros.dds.types import type_hash

from .ros_checks import Expected, marker_errors, moving_plan, multi_dof_errors, per_link_errors, stamp_ns
from .ros_harness import PANDA

MODEL = load_model(PANDA)
HAND = "panda_hand"
OUTPUTS = {
    "/neforward/link_states": "trajectory_msgs/msg/MultiDOFJointTrajectory",
    "/neforward/com_states": "trajectory_msgs/msg/MultiDOFJointTrajectory",
    f"/neforward/{HAND}/accel": "geometry_msgs/msg/AccelStamped",
    f"/neforward/{HAND}/twist": "geometry_msgs/msg/TwistStamped",
    f"/neforward/{HAND}/imu": "sensor_msgs/msg/Imu",
    "/neforward/markers": "visualization_msgs/msg/MarkerArray",
}
MARKER_SCALE = 0.05

# Relative errors (of the field's scale, see ros_checks.relative_error) allowed for link quantities
# estimated from joint positions at 200 Hz by the default fixed-lag estimator, on interior samples.
# Measured on this trajectory: accel 5.4e-5, alpha 8.1e-4, v 5.3e-5, omega 1.8e-4; the bounds leave 4x.
ESTIMATED = {"accel": 3e-3, "alpha": 3e-3, "linear_velocity": 1e-3, "omega": 1e-3}
EXACT = 1e-9  # what the message carries as given: positions, poses, and velocities when sent


def params_file(tmp_path, **parameters) -> str:
    path = tmp_path / "params.yaml"
    path.write_text(yaml.safe_dump({"/**/neforward": {"ros__parameters": parameters}}))
    return str(path)


def panda_parameters(**extra) -> dict:
    """The bundled arm with every output, and queues deep enough for the whole stream: the test's
    client may fall behind on a loaded machine, and nothing may be lost (reliable QoS)."""
    return {
        "robot_description": PANDA.read_text(),
        "accel_links": [HAND],
        "imu_links": [HAND],
        "publish_markers": True,
        "marker_scale": MARKER_SCALE,
        "qos_depth": 1000,
        "qos_overrides": {topic: {"publisher": {"depth": 1000}} for topic in OUTPUTS},
        **extra,
    }


def check_moving_robot(received: dict, plan: dict, velocities_given: bool) -> None:
    expected = Expected(PANDA, plan)
    for topic in OUTPUTS:
        assert received[topic], f"nothing on {topic}"
    links = expected.interior(received["/neforward/link_states"])
    assert len(links) >= 0.6 * plan["count"], len(links)
    assert all(m["joint_names"] == list(MODEL.link_names) for m in received["/neforward/link_states"])
    for com in (False, True):
        topic = "/neforward/com_states" if com else "/neforward/link_states"
        messages = expected.interior(received[topic])
        assert all(m["header"]["frame_id"] == MODEL.root_link for m in messages)
        errors = multi_dof_errors(messages, expected, com=com)
        for field, error in errors.items():
            bound = EXACT if field in ("translation", "rotation") else ESTIMATED[field]
            if velocities_given and field in ("linear_velocity", "omega"):
                bound = EXACT
            assert error <= bound, f"{topic} {field}: relative error {error:.2e} > {bound:.0e}"
    per_link = per_link_errors(
        *(expected.interior(received[f"/neforward/{HAND}/{kind}"]) for kind in ("accel", "twist", "imu")),
        expected,
        HAND,
    )
    bounds = {"linear": ESTIMATED["accel"], "angular": ESTIMATED["alpha"]}
    for field, error in per_link.items():
        if field.startswith("accel"):
            bound = bounds[field.split(".")[1]]
        elif field == "imu.linear_acceleration":
            bound = ESTIMATED["accel"]
        elif field == "imu.orientation":
            bound = EXACT
        else:
            bound = EXACT if velocities_given else ESTIMATED["omega"]
        assert error <= bound, f"{field}: relative error {error:.2e} > {bound:.0e}"
    frames = {
        m["header"]["frame_id"] for kind in ("accel", "twist", "imu") for m in received[f"/neforward/{HAND}/{kind}"]
    }
    assert frames == {HAND}
    markers = marker_errors(expected.interior(received["/neforward/markers"], 0.25), expected, MARKER_SCALE)
    assert markers["start"] <= EXACT and markers["end"] <= ESTIMATED["accel"], markers


@pytest.mark.parametrize("velocities", [False, True], ids=["positions", "positions+velocities"])
def test_ros2_run_with_a_params_file_gives_the_moving_robots_kinematics(graph, tmp_path, velocities) -> None:
    node = graph.start(
        "ros2", "run", "neforward_ros", "neforward_node", "--ros-args", "--params-file",
        params_file(tmp_path, **panda_parameters()),
    )  # fmt: skip
    node.wait_for("model 'panda'")
    # Fixed-lag (0.1 s, the default) answers every stamp whose fit window (0.1 s either side) is covered:
    # all but the first and the last 0.1 s of the stream (20 samples each).
    plan = moving_plan(MODEL, velocities=velocities, record=OUTPUTS, expect=360)
    received = graph.client(plan)
    check_moving_robot(received, plan, velocities)
    sent = [plan["epoch_ns"] + k * 5_000_000 for k in range(plan["count"])]
    for topic in OUTPUTS:  # nothing lost, and each output carries its input's stamp
        assert [stamp_ns(m) for m in received[topic]] == sent[20:380], topic
    assert "Traceback" not in node.log() and "ERROR" not in node.log()


def test_a_burst_of_joint_states_is_answered_whole_and_in_order(graph, tmp_path) -> None:
    # 400 messages stamped 5 ms apart, published at once: they queue while the node works, and its
    # callback takes them from the queue in runs (ros_node.TAKEN_PER_CALLBACK) between executor rounds.
    node = graph.start(
        "ros2", "run", "neforward_ros", "neforward_node", "--ros-args", "--params-file",
        params_file(tmp_path, **panda_parameters()),
    )  # fmt: skip
    node.wait_for("model 'panda'")
    plan = moving_plan(MODEL, record=OUTPUTS, expect=360, burst=True)
    received = graph.client(plan)
    check_moving_robot(received, plan, False)
    sent = [plan["epoch_ns"] + k * 5_000_000 for k in range(plan["count"])]
    for topic in OUTPUTS:
        assert [stamp_ns(m) for m in received[topic]] == sent[20:380], topic
    assert "Traceback" not in node.log() and "ERROR" not in node.log()


def test_model_from_the_robot_description_topic_of_another_process(graph) -> None:
    graph.latch(PANDA)  # a separate process, as robot_state_publisher publishes it: transient local
    node = graph.start("ros2", "run", "neforward_ros", "neforward_node")
    node.wait_for("model 'panda' from the robot_description topic")
    plan = moving_plan(MODEL, count=100, record={"/neforward/link_states": OUTPUTS["/neforward/link_states"]})
    received = graph.client({**plan, "expect": 60})
    expected = Expected(PANDA, plan)
    messages = expected.interior(received["/neforward/link_states"], 0.1)
    assert len(messages) >= 40
    errors = multi_dof_errors(messages, expected)
    assert errors["accel"] <= ESTIMATED["accel"] and errors["translation"] <= EXACT, errors


def test_a_joint_nobody_publishes_leaves_out_only_the_links_it_moves(graph, tmp_path) -> None:
    """robot_state_publisher publishes what it can: so does the node (publish_policy partial, the
    default). The gripper's driver is off: the fingers are left out, the arm is published."""
    node = graph.start(
        "ros2", "run", "neforward_ros", "neforward_node", "--ros-args", "--params-file",
        params_file(tmp_path, **panda_parameters()),
    )  # fmt: skip
    node.wait_for("model 'panda'")
    record = {topic: OUTPUTS[topic] for topic in ("/neforward/link_states", "/neforward/com_states")}
    record[f"/neforward/{HAND}/accel"] = OUTPUTS[f"/neforward/{HAND}/accel"]
    plan = moving_plan(MODEL, omit=["panda_finger_joint1"], record=record, expect=360)
    received = graph.client(plan)
    arm = [name for name in MODEL.link_names if "finger" not in name]
    expected = Expected(PANDA, plan)
    for topic in ("/neforward/link_states", "/neforward/com_states"):
        messages = received[topic]
        assert len(messages) == 360 and all(m["joint_names"] == arm for m in messages), topic
        errors = multi_dof_errors(expected.interior(messages), expected, com=topic.endswith("com_states"))
        for field, error in errors.items():
            bound = EXACT if field in ("translation", "rotation") else ESTIMATED[field]
            assert error <= bound, f"{topic} {field}: relative error {error:.2e} > {bound:.0e}"
    assert len(received[f"/neforward/{HAND}/accel"]) == 360  # the hand does not move with the fingers
    log = node.log()
    assert f"publishing {len(arm)} of {len(MODEL.link_names)} links" in log and "panda_finger_joint1" in log
    assert "no estimate yet for joint(s)" in log  # the warm-up at the start, said once


def test_joint_torques_external_torques_wrenches_and_contact(graph, tmp_path) -> None:
    """The backward pass on a real ROS 2: the drivers' efforts are the arm's torques with a 2 kg
    payload in the hand from 0.8 s to 1.4 s (Pinocchio's rnea of the URDF with the payload added)."""
    import numpy as np

    from neforward_ros import inverse_dynamics

    from .ros_checks import truth
    from conftest import require

    require("pinocchio")
    from test_torques import Loaded

    wrench = f"/neforward/{HAND}/wrench"
    record = {
        "/neforward/joint_torques": "sensor_msgs/msg/JointState",
        "/neforward/external_torques": "sensor_msgs/msg/JointState",
        wrench: "geometry_msgs/msg/WrenchStamped",
        "/neforward/contact": "std_msgs/msg/Bool",
        "/neforward/joint_estimates": "trajectory_msgs/msg/JointTrajectory",
    }
    names = list(MODEL.joint_names)
    node = graph.start(
        "ros2", "run", "neforward_ros", "neforward_node", "--ros-args", "--params-file",
        params_file(
            tmp_path,
            **panda_parameters(
                publish_torques=True,
                publish_joint_estimates=True,
                wrench_links=[HAND],
                **{"contact.joint_names": [names[1], names[3], names[5]], "contact.thresholds": [1.0, 1.0, 1.0]},
                qos_overrides={topic: {"publisher": {"depth": 1000}} for topic in record},
            ),
        ),
    )  # fmt: skip
    node.wait_for("model 'panda'")
    plan = moving_plan(MODEL, record=record, expect=360)
    t = np.arange(plan["count"]) / plan["rate"]
    q, qd, qdd = truth(MODEL, plan, t)
    loaded = Loaded()
    held = (t >= 0.8) & (t < 1.4)
    efforts = inverse_dynamics(MODEL, q, qd, qdd).joint_torque
    efforts[held] = [loaded.efforts(*x) for x in zip(q[held], qd[held], qdd[held], strict=True)]
    received = graph.client({**plan, "efforts": efforts.tolist()})
    torques = received["/neforward/joint_torques"]
    assert len(torques) == 360 and torques[0]["name"] == names
    k = np.array([round((stamp_ns(m) - plan["epoch_ns"]) * plan["rate"] / 1e9) for m in torques])
    expected = inverse_dynamics(MODEL, q[k], qd[k], qdd[k]).joint_torque
    got = np.array([m["effort"] for m in torques])
    assert np.abs(got - expected).max() <= 0.05 * np.abs(expected).max()  # estimated accelerations
    external = np.array([m["effort"] for m in received["/neforward/external_torques"]])
    payload = np.array([loaded.jacobian_transpose_wrench(q[i], qd[i], qdd[i]) for i in k])
    inside = held[k] & (t[k] > 0.85) & (t[k] < 1.35)
    assert np.abs(external[inside] - payload[inside]).max() <= 0.05 * np.abs(payload[inside]).max()
    assert np.abs(external[~held[k] & ((t[k] < 0.75) | (t[k] > 1.45))]).max() <= 0.3
    contact = np.array([m["data"] for m in received["/neforward/contact"]])
    assert contact[inside].all() and not contact[(t[k] < 0.75) | (t[k] > 1.45)].any()
    assert len(received[wrench]) == 360 and received[wrench][0]["header"]["frame_id"] == HAND
    assert "contact: joint(s)" in node.log()
    estimates = received["/neforward/joint_estimates"]  # the joint states used, and each q-ddot's deviation
    assert len(estimates) == 360 and estimates[0]["joint_names"] == names
    assert [stamp_ns(m) for m in estimates] == [stamp_ns(m) for m in torques]
    points = [m["points"][0] for m in estimates]
    accelerations = np.array([p["accelerations"] for p in points])
    assert np.abs(accelerations - qdd[k]).max() <= 0.05 * np.abs(qdd[k]).max()
    spread = np.array([p["effort"] for p in points])
    assert spread.shape == accelerations.shape and np.all(spread > 0)


def test_supplied_states_are_used_exactly(graph, tmp_path) -> None:
    node = graph.start(
        "ros2", "run", "neforward_ros", "neforward_node", "--ros-args", "--params-file",
        params_file(tmp_path, **panda_parameters(acceleration_source="supplied")),
    )  # fmt: skip
    node.wait_for("model 'panda'")
    plan = moving_plan(MODEL, supplied=True, topic="/joint_states_accel", count=50, record=OUTPUTS, expect=50)
    received = graph.client(plan)
    expected = Expected(PANDA, plan)
    assert len(received["/neforward/link_states"]) == 50  # every point, no warm-up: nothing is estimated
    for com in (False, True):
        topic = "/neforward/com_states" if com else "/neforward/link_states"
        errors = multi_dof_errors(received[topic], expected, com=com)
        assert max(errors.values()) <= EXACT, (topic, errors)
    errors = per_link_errors(*(received[f"/neforward/{HAND}/{k}"] for k in ("accel", "twist", "imu")), expected, HAND)
    assert max(errors.values()) <= EXACT, errors


def echo_once(graph, topic: str) -> dict:
    done = graph.ros2("topic", "echo", "--once", "--no-daemon", "--full-length", topic, OUTPUTS_ALL[topic], timeout=60)
    assert done.returncode == 0, done.stderr
    return yaml.safe_load(done.stdout.split("---")[0])


OUTPUTS_ALL = {**OUTPUTS, "/joint_states": "sensor_msgs/msg/JointState"}
HASH = re.compile(r"Topic type hash: (\S+)")


def test_the_ros2_command_line_tools_see_and_drive_the_node(graph, tmp_path) -> None:
    node = graph.start(
        "ros2", "run", "neforward_ros", "neforward_node", "--ros-args", "--params-file",
        params_file(tmp_path, **panda_parameters()),
    )  # fmt: skip
    node.wait_for("model 'panda'")
    graph.feeder(moving_plan(MODEL, count=100_000, rate=100.0))

    done = graph.ros2("node", "list", "--no-daemon")
    assert "/neforward" in done.stdout.split(), done.stdout
    message = echo_once(graph, "/neforward/link_states")
    assert message["header"]["frame_id"] == "panda_link0" and message["joint_names"] == list(MODEL.link_names)
    root_accel = message["points"][0]["accelerations"][0]["linear"]  # the root is at rest: -g
    assert (root_accel["x"], root_accel["y"], root_accel["z"]) == (0.0, 0.0, 9.81)

    for topic, typename in OUTPUTS.items():
        done = graph.ros2("topic", "info", "-v", "--no-daemon", topic)
        assert done.returncode == 0 and "Node name: neforward" in done.stdout, done.stdout
        assert HASH.findall(done.stdout) == [type_hash(typename)] * len(HASH.findall(done.stdout)) != [], done.stdout

    names = graph.ros2("param", "list", "--no-daemon", "/neforward").stdout.split()
    for name in ("robot_description", "gravity", "estimator.window", "accel_links", "use_sim_time"):
        assert name in names, names
    assert graph.ros2("param", "get", "--no-daemon", "/neforward", "max_gap").stdout.strip() == "Double value is: 0.5"
    described = graph.ros2("param", "describe", "--no-daemon", "/neforward", "max_gap", "gravity").stdout
    assert "restarts its history" in described and "Read only: true" in described.split("gravity")[0], described
    assert "Read only" not in described.split("Parameter name: gravity")[1], described

    def set_parameter(name: str, value: str) -> str:
        done = graph.ros2("param", "set", "--no-daemon", "/neforward", name, value)
        return done.stdout + done.stderr

    refused = set_parameter("max_gap", "1.0")
    assert "Setting parameter failed" in refused and "read-only" in refused, refused
    done = set_parameter("gravity", "[0.0, 0.0, 0.0]")
    assert "Set parameter successful" in done, done
    root_accel = echo_once(graph, "/neforward/link_states")["points"][0]["accelerations"][0]["linear"]
    assert (root_accel["x"], root_accel["y"], root_accel["z"]) == (0.0, 0.0, 0.0)  # the new gravity applies

    bad = set_parameter("robot_description", "<robot name='x'><link")
    assert "Setting parameter failed" in bad and "malformed URDF XML" in bad, bad
    assert echo_once(graph, "/neforward/link_states")["joint_names"] == list(MODEL.link_names)  # kept
    two = (
        '<robot name="two"><link name="a"/><link name="b"/><joint name="j" type="continuous">'
        '<parent link="a"/><child link="b"/><axis xyz="0 0 1"/></joint></robot>'
    )
    done = set_parameter("robot_description", two)
    assert "Set parameter successful" in done, done
    node.wait_for("model 'two' from the robot_description parameter")
    assert "Traceback" not in node.log()


def test_ctrl_c_ends_ros2_run_cleanly(graph, tmp_path) -> None:
    node = graph.start(
        "ros2", "run", "neforward_ros", "neforward_node", "--ros-args", "--params-file", params_file(tmp_path)
    )
    node.wait_for("waiting for the model")
    assert node.interrupt() == 0
    assert "Traceback" not in node.log() and "Error" not in node.log(), node.log()


def one_error_line(done) -> str:
    """The stderr of a start-up failure: exactly one line, and a non-zero exit code."""
    assert done.returncode != 0, done
    assert "Traceback" not in done.stderr and done.stderr.count("\n") == 1, done.stderr
    return done.stderr.strip()


def test_start_up_errors_are_one_line_and_the_same_in_both_runtimes(graph, tmp_path) -> None:
    whole_number = params_file(tmp_path, max_gap=1)  # a double written without a decimal point
    bad_urdf = tmp_path / "bad.yaml"
    bad_urdf.write_text(yaml.safe_dump({"neforward": {"ros__parameters": {"robot_description": "<robot><link"}}}))
    for arguments, text in (
        (["--params-file", whole_number], "parameter max_gap must be double, got the integer 1"),
        (["-p", "estimator.mode:=instant"], "estimator.mode must be one of causal, fixed_lag"),
        (["--params-file", str(bad_urdf)], "malformed URDF XML"),
        (["-p", "qos_overrides./joint_states.subscription.reliability:=sometimes"], "must be one of reliable"),
    ):
        ros = one_error_line(graph.ros2("run", "neforward_ros", "neforward_node", "--ros-args", *arguments))
        dds = one_error_line(graph.ros2("run", "neforward_ros", "neforward", "run", "--ros-args", *arguments))
        assert text in ros, ros
        assert ros.split("error: ", 1)[1] == dds.split("error: ", 1)[1], (ros, dds)


def test_a_message_that_fails_in_handling_is_logged_and_the_node_keeps_going(graph, tmp_path) -> None:
    """A supplied point whose stamp (header + time_from_start) leaves builtin_interfaces/Time's range
    cannot be published: logged (throttled), and the points after it are published as usual."""
    for command in (["neforward_node"], ["neforward", "run"]):
        node = graph.start(
            "ros2", "run", "neforward_ros", *command, "--ros-args", "--params-file",
            params_file(tmp_path, **panda_parameters(acceleration_source="supplied")),
        )  # fmt: skip
        node.wait_for("model 'panda'")
        # Points 5 ms apart, stamped 2^31 s - 20 ms + 5k ms: from the 5th on, int32 seconds overflow.
        plan = moving_plan(
            MODEL, supplied=True, topic="/joint_states_accel", count=10, record=OUTPUTS, expect=4, linger=2.0
        )
        plan.update(epoch_ns=(2**31 - 1) * 10**9, time_from_start_ns=10**9 - 20_000_000)
        received = graph.client(plan)
        assert len(received["/neforward/link_states"]) == 4, command
        node.wait_for("joint trajectory dropped: cannot build its messages: InputError: stamp")
        good = graph.client(
            {**moving_plan(MODEL, supplied=True, topic="/joint_states_accel", count=5), "record": OUTPUTS}
        )
        assert len(good["/neforward/link_states"]) == 5 and node.alive(), command
        assert "Traceback" not in node.log()
        assert node.interrupt() == 0


def test_best_effort_joint_states_connect_with_the_qos_override(graph, tmp_path) -> None:
    """Many drivers publish joint states best effort, which a reliable subscription cannot match."""
    link_states = {"/neforward/link_states": OUTPUTS["/neforward/link_states"]}
    plan = moving_plan(MODEL, count=100, record=link_states, best_effort=True)
    for command in (["neforward_node"], ["neforward", "run"]):
        default = graph.start(
            "ros2", "run", "neforward_ros", *command, "--ros-args", "--params-file",
            params_file(tmp_path, **panda_parameters()),
        )  # fmt: skip
        default.wait_for("model 'panda'")
        graph.client({**plan, "match_timeout": 3.0, "publish_unmatched": True, "linger": 0.5})
        default.wait_for("qos_overrides./joint_states.subscription.reliability: best_effort")
        assert default.interrupt() == 0
        override = {"/joint_states": {"subscription": {"reliability": "best_effort"}}}
        node = graph.start(
            "ros2", "run", "neforward_ros", *command, "--ros-args", "--params-file",
            params_file(tmp_path, **panda_parameters(qos_overrides=override)),
        )  # fmt: skip
        node.wait_for("model 'panda'")
        received = graph.client({**plan, "expect": 60})
        # connected: results come (best effort guarantees no count, and a busy machine drops some)
        assert len(received["/neforward/link_states"]) >= 1, (command, len(received["/neforward/link_states"]))
        assert node.interrupt() == 0


def test_a_missing_pip_dependency_is_one_line_at_start(graph, tmp_path) -> None:
    """A ROS user who forgot `pip install rosbags`: Debian's own python3, without it, runs the node."""
    probe = graph.run("/usr/bin/python3", "-c", "import rosbags")
    if probe.returncode == 0:
        pytest.skip("/usr/bin/python3 has rosbags installed, so it cannot show the missing package")
    executable = graph.workspace.root / "install" / "neforward_ros" / "lib" / "neforward_ros" / "neforward_node"
    done = graph.run("/usr/bin/python3", str(executable), "--ros-args", "--params-file", params_file(tmp_path))
    assert "rosbags (the ROS 2 message definitions the node encodes with) not installed" in one_error_line(done)
    assert "pip install rosbags" in one_error_line(done)
