"""forward_recursion against answers that share no formula with it: a planar 2R arm worked out by
hand, finite differences of the recursion's own poses along a smooth trajectory, and a robot at
rest reading +9.81 m/s^2 upward."""

from __future__ import annotations

import math

import numpy as np
import pytest

from neforward_ros import forward_recursion, load_model

from conftest import TEST_ROBOTS, assert_close

G = 9.81


def rot_z(angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


@pytest.mark.parametrize("q1, q2, qd1, qd2, qdd1, qdd2", [
    (0.3, -0.7, 1.2, -0.4, 2.0, 3.0),
    (-2.0, 1.4, -0.5, 2.5, -4.0, 0.5),
    (0.0, 0.0, 0.0, 0.0, 0.0, 0.0),
])  # fmt: skip
def test_planar_2r_by_hand(q1: float, q2: float, qd1: float, qd2: float, qdd1: float, qdd2: float) -> None:
    """Links 0.5 m and 0.3 m, both axes z, COM at mid-link; gravity -z, normal to the plane."""
    l1, l2 = 0.5, 0.3
    model = load_model(TEST_ROBOTS["planar_2r"])
    kin = forward_recursion(model, [q1, q2], [qd1, qd2], [qdd1, qdd2])
    th1, th2 = q1, q1 + q2
    w1, w2, dw1, dw2 = qd1, qd1 + qd2, qdd1, qdd1 + qdd2

    def radial(angle: float) -> np.ndarray:
        return np.array([math.cos(angle), math.sin(angle), 0.0])

    def tangential(angle: float) -> np.ndarray:
        return np.array([-math.sin(angle), math.cos(angle), 0.0])

    up = np.array([0.0, 0.0, G])  # specific force of gravity alone
    # World-frame expectations for each link origin and centre of mass.
    p_link2 = l1 * radial(th1)
    v_link2 = l1 * w1 * tangential(th1)
    a_link2 = l1 * dw1 * tangential(th1) - l1 * w1**2 * radial(th1)
    expected_world = {
        "base": dict(angle=0.0, w=0.0, dw=0.0, p=np.zeros(3), v=np.zeros(3), a=np.zeros(3), ac=np.zeros(3)),
        "link1": dict(
            angle=th1, w=w1, dw=dw1, p=np.zeros(3), v=np.zeros(3), a=np.zeros(3),
            ac=0.25 * (dw1 * tangential(th1) - w1**2 * radial(th1)),
        ),
        "link2": dict(
            angle=th2, w=w2, dw=dw2, p=p_link2, v=v_link2, a=a_link2,
            ac=a_link2 + 0.15 * (dw2 * tangential(th2) - w2**2 * radial(th2)),
        ),
        "tip": dict(
            angle=th2, w=w2, dw=dw2, p=p_link2 + l2 * radial(th2),
            v=v_link2 + l2 * w2 * tangential(th2),
            a=a_link2 + l2 * (dw2 * tangential(th2) - w2**2 * radial(th2)),
            ac=a_link2 + l2 * (dw2 * tangential(th2) - w2**2 * radial(th2)),
        ),
    }  # fmt: skip
    for name, e in expected_world.items():
        k = model.link_index[name]
        to_link = rot_z(e["angle"]).T
        assert_close(kin.rotation[k], rot_z(e["angle"]), 1e-12, f"{name} rotation")
        assert_close(kin.position[k], e["p"], 1e-12, f"{name} position")
        assert_close(kin.omega[k], [0.0, 0.0, e["w"]], 1e-12, f"{name} omega")
        assert_close(kin.alpha[k], [0.0, 0.0, e["dw"]], 1e-12, f"{name} alpha")
        assert_close(kin.velocity[k], to_link @ e["v"], 1e-12, f"{name} velocity")
        assert_close(kin.accel[k], to_link @ (e["a"] + up), 1e-12, f"{name} accel")
        assert_close(kin.com_accel[k], to_link @ (e["ac"] + up), 1e-12, f"{name} com_accel")


def test_robot_at_rest_reads_plus_g_upward(robot_path) -> None:
    model = load_model(robot_path)
    n = len(model.joint_names)
    q = np.linspace(-1.0, 1.0, n)
    kin = forward_recursion(model, q, np.zeros(n), np.zeros(n)).in_root()
    expected = np.tile([0.0, 0.0, G], (len(model.link_names), 1))
    assert_close(kin.accel, expected, 1e-12, "accel at rest")
    assert_close(kin.com_accel, expected, 1e-12, "com_accel at rest")
    assert_close(kin.omega, np.zeros_like(kin.omega), 1e-12, "omega at rest")


def test_zero_gravity_gives_pure_kinematic_acceleration() -> None:
    model = load_model(TEST_ROBOTS["planar_2r"])
    kin = forward_recursion(model, [0.4, 0.2], [0.0, 0.0], [0.0, 0.0], gravity=(0.0, 0.0, 0.0))
    assert_close(kin.accel, np.zeros_like(kin.accel), 1e-15, "accel")


def smooth_trajectory(n_joints: int, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """q(t) = a sin(w t + phi) per joint, with its exact first and second derivatives."""
    k = np.arange(1, n_joints + 1)
    amp, w, phi = 0.4 + 0.1 * k, 0.7 + 0.35 * k, 0.3 * k
    arg = np.outer(t, w) + phi
    return amp * np.sin(arg), amp * w * np.cos(arg), -amp * w**2 * np.sin(arg)


def vee(skew: np.ndarray) -> np.ndarray:
    """The vector of the antisymmetric part of a 3x3 matrix (batched on leading axes)."""
    a = 0.5 * (skew - np.swapaxes(skew, -1, -2))
    return np.stack([a[..., 2, 1], a[..., 0, 2], a[..., 1, 0]], axis=-1)


def test_finite_differences_of_poses_reproduce_rates(robot_path) -> None:
    """Velocities and accelerations from differencing the recursion's own positions and rotations
    (4th-order central differences), which share no formula with the velocity propagation."""
    model = load_model(robot_path)
    n = len(model.joint_names)
    gravity = np.array([0.0, 0.0, -G])
    h = 2.5e-4  # truncation ~h^4 stays below 1e-7 even on the 33-joint humanoid; round-off ~eps/h^2
    t0 = np.array([0.37, 1.91])
    offsets = np.arange(-4, 5) * h  # t0 + k h for k = -4..4
    times = (t0[:, None] + offsets[None, :]).reshape(-1)
    q, qd, qdd = smooth_trajectory(n, times)
    kin = forward_recursion(model, q, qd, qdd, gravity=gravity)
    shape = (len(t0), len(offsets))
    position = kin.position.reshape(shape + kin.position.shape[1:])
    rotation = kin.rotation.reshape(shape + kin.rotation.shape[1:])
    com = np.array(model.com_in_link)
    com_position = position + np.einsum("stlij,lj->stli", rotation, com)
    centre = 4

    def d1(x: np.ndarray, at: int) -> np.ndarray:
        return (x[:, at - 2] - 8 * x[:, at - 1] + 8 * x[:, at + 1] - x[:, at + 2]) / (12 * h)

    def d2(x: np.ndarray, at: int) -> np.ndarray:
        return (-x[:, at - 2] + 16 * x[:, at - 1] - 30 * x[:, at] + 16 * x[:, at + 1] - x[:, at + 2]) / (12 * h**2)

    def omega_fd(at: int) -> np.ndarray:
        return vee(d1(rotation, at) @ np.swapaxes(rotation[:, at], -1, -2))

    alpha_fd = (omega_fd(centre - 2) - 8 * omega_fd(centre - 1) + 8 * omega_fd(centre + 1) - omega_fd(centre + 2)) / (
        12 * h
    )
    at_centre = forward_recursion(model, *smooth_trajectory(n, t0), gravity=gravity).in_root()
    assert_close(at_centre.velocity, d1(position, centre), 1e-7, "velocity")
    assert_close(at_centre.omega, omega_fd(centre), 1e-7, "omega")
    assert_close(at_centre.alpha, alpha_fd, 1e-5, "alpha")
    assert_close(at_centre.accel, d2(position, centre) - gravity, 1e-5, "accel")
    assert_close(at_centre.com_accel, d2(com_position, centre) - gravity, 1e-5, "com_accel")


def test_batch_of_one_and_of_none() -> None:
    model = load_model(TEST_ROBOTS["tree"])
    n = len(model.joint_names)
    one = forward_recursion(model, np.ones((1, n)), np.ones((1, n)), np.ones((1, n)))
    assert one.accel.shape == (1, len(model.link_names), 3)
    empty = forward_recursion(model, np.zeros((0, n)), np.zeros((0, n)), np.zeros((0, n)))
    assert empty.accel.shape == (0, len(model.link_names), 3)
    assert empty.rotation.shape == (0, len(model.link_names), 3, 3)
