"""Partial robots: what the node and the bag tool publish when some joints have no estimate, under each
publish policy, checked against forward_recursion at the true joint states."""

from __future__ import annotations

import re

import numpy as np
import pytest

from neforward_ros import forward_recursion, load_model
from neforward_ros.node.pipeline import Pipeline
from neforward_ros.parameters.settings import node_settings

from conftest import CONFIG_DIR, EPOCH_NS, TEST_DIR, assert_close

PANDA = CONFIG_DIR / "panda.urdf"
MODEL = load_model(PANDA)
FINGER = "panda_finger_joint1"
ARM = [name for name in MODEL.link_names if "finger" not in name]  # the links the finger joint does not move


def trajectory(t: np.ndarray):
    k = np.arange(len(MODEL.joint_names))
    w = 2 * np.pi * (0.3 + 0.1 * k)
    amplitude = np.where(np.array(MODEL.joint_names) == FINGER, 0.01, 0.5)
    arg = np.outer(t, w) + k
    return amplitude * np.sin(arg), amplitude * w * np.cos(arg), -amplitude * w**2 * np.sin(arg)


def feed(pipeline: Pipeline, seconds: float, names=None, start: float = 0.0, rate: float = 500.0):
    names = list(MODEL.joint_names) if names is None else names
    columns = [MODEL.joint_index[name] for name in names]
    t = start + np.arange(int(seconds * rate)) / rate
    q, _, _ = trajectory(t)
    results = []
    for k in range(len(t)):
        stamp = EPOCH_NS + round(t[k] * 1e9)
        results += pipeline.on_joint_state(stamp, names, q[k, columns].tolist())
    return results


def pipeline_with(**parameters) -> Pipeline:
    return Pipeline(
        node_settings(
            {
                "robot_description": PANDA.read_text(),
                "accel_links": ["panda_hand", "panda_leftfinger"],
                "imu_links": ["panda_leftfinger"],
                "publish_markers": True,
                **parameters,
            }
        )
    )


def check_links(result, q_override=None) -> None:
    """The result's links against the recursion at the true state (the finger at q_override if given,
    at rest)."""
    t = np.array([(result.stamp_ns - EPOCH_NS) / 1e9])
    q, qd, qdd = (x[0] for x in trajectory(t))
    if q_override is not None:
        j = MODEL.joint_index[FINGER]
        q[j], qd[j], qdd[j] = q_override, 0.0, 0.0
    truth = forward_recursion(MODEL, q, qd, qdd).in_root()
    rows = [MODEL.link_index[name] for name in result.link_names]
    got = result.in_root
    assert_close(got.accel, truth.accel[rows], 1e-3, "accel")
    assert_close(got.alpha, truth.alpha[rows], 1e-3, "alpha")
    assert_close(got.position, truth.position[rows], 1e-9, "position")


def test_partial_publishes_the_links_every_joint_above_which_has_an_estimate() -> None:
    pipeline = pipeline_with()
    names = [name for name in MODEL.joint_names if name != FINGER]  # the gripper's driver is off
    results = feed(pipeline, 1.0, names)
    assert len(results) > 300
    for result in results:
        assert list(result.link_names) == ARM  # in the model's order
    check_links(results[len(results) // 2])
    contents = dict(pipeline.messages(results[-1]))
    assert contents["~/link_states"]["joint_names"] == ARM
    assert contents["~/com_states"]["joint_names"] == ARM
    points = contents["~/link_states"]["points"][0]
    assert len(points["transforms"]) == len(points["velocities"]) == len(points["accelerations"]) == len(ARM)
    # per-link topics: the hand's, not the finger's; markers keep the model's link indices as ids
    assert "~/panda_hand/accel" in contents and "~/panda_leftfinger/accel" not in contents
    assert "~/panda_leftfinger/imu" not in contents
    ids = [marker["id"] for marker in contents["~/markers"]["markers"]]
    assert ids == [MODEL.link_index[name] for name in ARM]


def test_wait_publishes_nothing_until_every_joint_has_an_estimate() -> None:
    pipeline = pipeline_with(publish_policy="wait")
    names = [name for name in MODEL.joint_names if name != FINGER]
    assert feed(pipeline, 1.0, names) == []
    results = feed(pipeline, 1.0, start=1.0)  # the finger arrives: after its warm-up, the whole robot
    assert results and all(r.link_names == MODEL.link_names for r in results)


def test_hold_holds_silent_joints_at_their_hold_position() -> None:
    pipeline = pipeline_with(publish_policy="hold", **{"hold.joint_names": [FINGER], "hold.positions": [0.02]})
    names = [name for name in MODEL.joint_names if name != FINGER]
    results = feed(pipeline, 1.0, names)
    assert len(results) > 300 and all(r.link_names == MODEL.link_names for r in results)
    check_links(results[len(results) // 2], q_override=0.02)


def test_a_joint_falling_silent_and_coming_back() -> None:
    """The finger stops after 1 s: its links go once max_gap (0.5 s) has passed with no sample, and
    come back once it has been heard again for its warm-up."""
    pipeline = pipeline_with()
    results = feed(pipeline, 1.0)
    names = [name for name in MODEL.joint_names if name != FINGER]
    results += feed(pipeline, 1.0, names, start=1.0)
    results += feed(pipeline, 1.0, start=2.0)
    t = np.array([(r.stamp_ns - EPOCH_NS) / 1e9 for r in results])
    full = np.array([r.link_names == MODEL.link_names for r in results])
    arm_only = np.array([list(r.link_names) == ARM for r in results])
    assert np.all(full | arm_only)
    assert full[(t > 0.2) & (t < 0.9)].all()  # until the finger's fit window reaches past its last sample
    assert arm_only[(t > 0.95) & (t < 2.0)].all()
    assert full[t > 2.3].all()  # heard again, and warmed up
    for result in results[::50]:
        check_links(result)


def test_a_model_reload_warms_up_again() -> None:
    pipeline = pipeline_with(**{"estimator.mode": "causal"})
    before = feed(pipeline, 0.5)
    assert before
    assert pipeline.set_description(PANDA.read_text())
    after = feed(pipeline, 0.5, start=0.5)
    t = np.array([(r.stamp_ns - EPOCH_NS) / 1e9 for r in after])
    assert t.min() >= 0.5 + 0.2 - 1e-9  # nothing until the new estimator's 0.2 s window is covered


def test_the_node_guide_says_what_the_arrays_hold_in_the_partial_case() -> None:
    guide = (TEST_DIR.parent / "docs" / "guides" / "node.md").read_text()
    section = guide[guide.index("## Partial robots") :]
    for phrase in ("joint_names", "model's order", "publish_policy", "hold.positions", "max_gap", "neforward bag"):
        assert phrase in section, phrase
    assert re.search(r"`partial`.*default", section)


@pytest.mark.parametrize("policy", ["partial", "hold"])
def test_the_bag_tool_applies_the_same_policy(tmp_path, policy) -> None:
    pytest.importorskip("rosbags")
    from test_bag import read_output, record

    from neforward_ros.cli import main
    from neforward_ros.wire import cdr

    names = [name for name in MODEL.joint_names if name != FINGER]
    record(tmp_path / "in", seconds=1.0, names=[*names, "not_the_finger"])
    arguments = ["bag", str(tmp_path / "in"), "-o", str(tmp_path / "out"), "--csv", str(tmp_path / "out.csv")]
    arguments += ["--publish-policy", policy, "--hold", f"{FINGER}=0.02"]
    assert main(arguments) == 0
    out = read_output(tmp_path / "out")
    points = [cdr.decode_multi_dof(raw) for _, raw in out["/neforward/link_states"]]
    assert len(points) > 300
    # a joint never in the recording is held under every policy (a driver that does not send it)
    assert all(list(p.joint_names) == list(MODEL.link_names) for p in points)
    assert points[0].stamp_ns >= EPOCH_NS + 100_000_000  # no estimate before the window is covered
    header, *rows = (tmp_path / "out.csv").read_text().splitlines()
    column = header.split(",").index("panda_leftfinger.accel_in_root.z[m/s^2]")
    cells = {row.split(",")[column] for row in rows}
    assert "nan" not in cells
