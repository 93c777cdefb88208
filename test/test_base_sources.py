"""A moving base in the node: base IMU and odometry sources against the recursion at the true base
motion, a virtual IMU fed back as the base IMU, and bad base input."""

from __future__ import annotations

import logging

import numpy as np
import pytest

from neforward_ros import BaseMotion, forward_recursion, load_model
from neforward_ros.computation.base_motion import BaseMessage
from neforward_ros.node.pipeline import Pipeline
from neforward_ros.parameters.settings import node_settings
from neforward_ros.rotations import quaternions

from conftest import EPOCH_NS, TEST_ROBOTS, LogRecorder

GRAVITY = np.array([0.0, 0.0, -9.81])
PATH = TEST_ROBOTS["humanoid"]
MODEL = load_model(PATH)


def _rotation(t: np.ndarray) -> np.ndarray:
    """The base's orientation (base -> world) at times t: a rolling, pitching, turning body."""
    a, b, c = 0.3 * np.sin(2.1 * t), 0.2 * np.sin(1.3 * t + 0.5), 0.8 * t

    def axis(angle, i):
        out = np.zeros((len(t), 3, 3))
        j, k = (i + 1) % 3, (i + 2) % 3
        out[:, i, i] = 1.0
        out[:, j, j] = out[:, k, k] = np.cos(angle)
        out[:, j, k], out[:, k, j] = -np.sin(angle), np.sin(angle)
        return out

    return axis(c, 2) @ axis(b, 1) @ axis(a, 0)


def _position(t: np.ndarray) -> np.ndarray:
    return np.stack([0.3 * t, 0.05 * np.sin(3.0 * t), 0.9 + 0.04 * np.sin(6.0 * t)], axis=1)


def base_truth(t: np.ndarray, h: float = 1e-4):
    """(rotation, position, omega, alpha, velocity, specific force), body-frame vectors, by 4th-order
    differences of the analytic pose."""

    def d(f, x):
        return (-f(x + 2 * h) + 8 * f(x + h) - 8 * f(x - h) + f(x - 2 * h)) / (12 * h)

    def omega_body(x):
        r, dr = _rotation(x), d(_rotation, x)
        skew = np.einsum("tji,tjk->tik", r, dr)
        return np.stack([skew[:, 2, 1], skew[:, 0, 2], skew[:, 1, 0]], axis=1)

    r = _rotation(t)
    velocity_world = d(_position, t)
    accel_world = d(lambda x: d(_position, x), t)
    return (
        r,
        _position(t),
        omega_body(t),
        d(omega_body, t),
        np.einsum("tji,tj->ti", r, velocity_world),
        np.einsum("tji,tj->ti", r, accel_world - GRAVITY),
    )


def joints(t: np.ndarray):
    k = np.arange(len(MODEL.joint_names))
    w = 2 * np.pi * (0.3 + 0.9 * k / (len(k) - 1))
    arg = np.outer(t, w) + k
    return 0.4 * np.sin(arg), 0.4 * w * np.cos(arg), -0.4 * w**2 * np.sin(arg)


def run(pipeline: Pipeline, seconds: float = 2.0, source: str = "imu", skip=None, link: str | None = None):
    """Joint states at 500 Hz and base messages at 400 Hz (their own stamps), in stamp order; the
    base source on the root link, or (an IMU) on ``link``."""
    t_joint = np.arange(int(seconds * 500)) / 500.0
    t_base = np.arange(int(seconds * 400)) / 400.0 + 0.0007
    q, _, _ = joints(t_joint)
    r, p, w, al, v, f = base_truth(t_base)
    orientation = quaternions(r)
    frame = MODEL.root_link
    if link is not None:  # what an IMU on that link reads, and its orientation in the world
        kin = forward_recursion(
            MODEL, *joints(t_base), base=BaseMotion(omega=w, alpha=al, velocity=v, specific_force=f)
        )
        k = MODEL.link_index[link]
        w, f, frame = kin.omega[:, k], kin.accel[:, k], link
        orientation = quaternions(r @ kin.rotation[:, k])
    events = [(t, 0, k) for k, t in enumerate(t_joint)] + [(t, 1, k) for k, t in enumerate(t_base)]
    results = []
    names = list(MODEL.joint_names)
    for t, kind, k in sorted(events):
        stamp = EPOCH_NS + round(t * 1e9)
        if kind == 0:
            results += pipeline.on_joint_state(stamp, names, q[k].tolist())
        elif skip is None or not skip(t):
            if source == "imu":
                results += pipeline.on_base(BaseMessage(stamp, frame, w[k], f[k], orientation[k]))
            else:
                results += pipeline.on_base(BaseMessage(stamp, MODEL.root_link, w[k], v[k], orientation[k], p[k]))
    return results


def truth_at(stamps_ns: np.ndarray):
    t = (stamps_ns - EPOCH_NS) / 1e9
    r, p, w, al, v, f = base_truth(t)
    base = BaseMotion(omega=w, alpha=al, specific_force=f, velocity=v)
    return forward_recursion(MODEL, *joints(t), base=base), r, p


def relative(got: np.ndarray, want: np.ndarray) -> float:
    return float(np.sqrt(np.mean((got - want) ** 2) / np.mean(want**2)))


@pytest.mark.parametrize("source, link", [("imu", None), ("imu", "torso_3"), ("odometry", None)])
def test_a_base_source_gives_every_link_the_true_motion(source: str, link: str | None) -> None:
    pipeline = Pipeline(
        node_settings({"robot_description": PATH.read_text(), "base.source": source, "world_frame": "odom"})
    )
    results = run(pipeline, source=source, link=link)
    assert len(results) > 700
    stamps = np.array([r.stamp_ns for r in results])
    kin, rotation, position = truth_at(stamps)
    got = [r.in_link for r in results]
    for field, bound in (("accel", 1e-2), ("alpha", 1e-2), ("omega", 1e-3), ("com_accel", 1e-2)):
        value = np.array([getattr(g, field) for g in got])
        assert relative(value, getattr(kin, field)) <= bound, field
    if source == "odometry":  # the odometry gives the base's velocity too
        assert relative(np.array([g.velocity for g in got]), kin.velocity) <= 1e-3
    # the world pose of the root, and the world link states
    world_rotation = np.array([r.world[0] for r in results])
    # interpolated between 400 Hz orientations (of a link that turns with its joints): within 1e-5
    np.testing.assert_allclose(world_rotation, rotation, atol=1e-5)
    if source == "odometry":
        # linear interpolation between 400 Hz poses: within 1e-5 m
        np.testing.assert_allclose(np.array([r.world[1] for r in results]), position, atol=1e-5)
    message = dict(pipeline.messages(results[300]))["~/world_link_states"]
    assert message["header"]["frame_id"] == "odom"
    k = MODEL.link_index["left_leg_6"]
    accel = message["points"][0]["accelerations"][k]["linear"]
    kinematic = rotation[300] @ kin.in_root().accel[300, k] + GRAVITY  # gravity removed, world axes
    np.testing.assert_allclose(
        [accel["x"], accel["y"], accel["z"]], kinematic, rtol=0, atol=0.05 * np.abs(kinematic).max()
    )


def test_a_virtual_imu_fed_back_as_the_base_imu_gives_the_same_outputs() -> None:
    """Node 1: base IMU on the root; it publishes a virtual IMU on the head. Node 2: that virtual IMU
    is its base IMU, on the head: every link's outputs agree with node 1's."""
    head = "head_2"
    first = Pipeline(node_settings({"robot_description": PATH.read_text(), "base.source": "imu", "imu_links": [head]}))
    results = run(first)
    second = Pipeline(node_settings({"robot_description": PATH.read_text(), "base.source": "imu", "base.link": head}))
    names = list(MODEL.joint_names)
    t_joint = np.arange(1000) / 500.0
    q_all, _, _ = joints(t_joint)
    imu = {r.stamp_ns: dict(first.messages(r))[f"~/{head}/imu"] for r in results}
    again = []
    for k, t in enumerate(t_joint):
        stamp = EPOCH_NS + round(t * 1e9)
        again += second.on_joint_state(stamp, names, q_all[k].tolist())
        if stamp in imu:
            m = imu[stamp]
            vector = lambda d: [d["x"], d["y"], d["z"]]  # noqa: E731
            message = BaseMessage(stamp, head, vector(m["angular_velocity"]), vector(m["linear_acceleration"]), None)
            again += second.on_base(message)
    ours = {r.stamp_ns: r for r in again}
    common = [r for r in results if r.stamp_ns in ours]
    assert len(common) > 500
    for field in ("accel", "alpha", "omega", "com_accel"):
        a = np.array([getattr(r.in_link, field) for r in common])
        b = np.array([getattr(ours[r.stamp_ns].in_link, field) for r in common])
        assert relative(b, a) <= 1e-2, field


def test_missing_late_nan_and_out_of_order_base_messages() -> None:
    log = LogRecorder()
    settings = {"robot_description": PATH.read_text(), "base.source": "imu", "base.max_delay": 0.3}
    # no base message at all: nothing, and a warning
    pipeline = Pipeline(node_settings(settings), log=log)
    names = list(MODEL.joint_names)
    q, _, _ = joints(np.arange(500) / 500.0)
    out = []
    for k in range(500):
        out += pipeline.on_joint_state(EPOCH_NS + k * 2_000_000, names, q[k].tolist())
    assert out == [] and log.count("no base motion at its stamp") >= 1
    # a 0.4 s stretch without base messages: the stamps it covers are dropped, the rest published
    pipeline = Pipeline(node_settings(settings), log=log)
    results = run(pipeline, seconds=3.0, skip=lambda t: 1.0 <= t < 1.4)
    t = (np.array([r.stamp_ns for r in results]) - EPOCH_NS) / 1e9
    assert ((t > 0.3) & (t < 0.9)).sum() > 250 and ((t > 1.7) & (t < 2.8)).sum() > 500
    assert not ((t > 1.05) & (t < 1.35)).any()
    kin, _, _ = truth_at(np.array([r.stamp_ns for r in results]))
    assert relative(np.array([r.in_link.accel for r in results]), kin.accel) <= 1e-2
    # NaN and stamps going back: dropped or restarted, logged, never raised
    pipeline = Pipeline(node_settings(settings), log=log)
    assert pipeline.on_base(BaseMessage(EPOCH_NS, MODEL.root_link, [np.nan, 0, 0], [0, 0, 9.81], None)) == []
    assert log.count("non-finite") >= 1
    for k in range(3):  # a stream in line
        pipeline.on_base(BaseMessage(EPOCH_NS + 10**9 + k * 10**7, MODEL.root_link, [0, 0, 0], [0, 0, 9.81], None))
    pipeline.on_base(BaseMessage(EPOCH_NS, MODEL.root_link, [0, 0, 0], [0, 0, 9.81], None))  # one stray
    pipeline.on_base(BaseMessage(EPOCH_NS + 10**9 + 3 * 10**7, MODEL.root_link, [0, 0, 0], [0, 0, 9.81], None))
    assert log.count("which went on without them: dropped") == 1 and log.count("went back in time") == 0
    for k in range(3):  # the stream goes on from an earlier time: a reset
        pipeline.on_base(BaseMessage(EPOCH_NS + k * 10**7, MODEL.root_link, [0, 0, 0], [0, 0, 9.81], None))
    assert log.count("went back in time") == 1


def test_a_floating_urdf_with_a_fixed_base_source_says_so() -> None:
    log = LogRecorder()
    urdf = (
        '<robot name="q"><link name="world"/><link name="trunk"/><link name="leg"/>'
        '<joint name="root_joint" type="floating"><parent link="world"/><child link="trunk"/></joint>'
        '<joint name="hip" type="revolute"><parent link="trunk"/><child link="leg"/><axis xyz="0 1 0"/>'
        '<limit lower="-1" upper="1" effort="1" velocity="1"/></joint></robot>'
    )
    Pipeline(node_settings({"robot_description": urdf}), log=log)
    warnings = [m for level, m in log.lines if level == logging.WARNING and "floating base" in m]
    assert len(warnings) == 1 and "base.source" in warnings[0]
