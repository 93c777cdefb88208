"""Forward Newton-Euler recursion: link velocities and classical accelerations, O(n) in links.

For link i with parent p, parent joint rotation R_i (child -> parent) and child origin p_i in the
parent frame (both recomputed from q), joint axis z_i in the link frame and sigma_i = 1 for a
prismatic joint, 0 otherwise, every vector expressed in the frame of the link it belongs to:

    omega_i = R_i^T omega_p + (1 - sigma_i) qd_i z_i
    alpha_i = R_i^T alpha_p + (1 - sigma_i) (qdd_i z_i + omega_i x (qd_i z_i))
    v_i     = R_i^T (v_p + omega_p x p_i) + sigma_i qd_i z_i
    a_i     = R_i^T (a_p + alpha_p x p_i + omega_p x (omega_p x p_i))
              + sigma_i (qdd_i z_i + 2 omega_i x (qd_i z_i))
    a_ci    = a_i + alpha_i x r_ci + omega_i x (omega_i x r_ci)

The root starts at rest with a_0 = -g, so ``accel`` is the specific force at each link origin (what
an ideal accelerometer there reads: +9.81 m/s^2 upward at rest for g = (0, 0, -9.81)). The linear
accelerations are classical (second derivatives of point positions), not the linear part of the
spatial acceleration: they match Pinocchio's ``getFrameClassicalAcceleration(..., LOCAL)`` plus
``-R^T g``.

The kernel :func:`_recurse` is written once over scalar components. Given Python floats it
computes one sample with no numpy call per link (the fast single-sample path); given numpy arrays
of shape (T,) it computes T samples at once, vectorised over the samples.
"""

from __future__ import annotations

import functools
import math
import struct
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import Any, Literal

import numpy as np

from neforward_ros.errors import InputError
from neforward_ros.model import JointKind, RobotModel

DEFAULT_GRAVITY = (0.0, 0.0, -9.81)
"""Gravity in the root frame for a z-up world (REP-103), m/s^2."""

# Layout of one link's row in the kernel's output table: the kernel's per-link state, then com_accel.
_OMEGA, _ALPHA, _VELOCITY, _ACCEL = (slice(3 * k, 3 * k + 3) for k in range(4))
_ROTATION, _POSITION, _COM_ACCEL = slice(12, 21), slice(21, 24), slice(24, 27)
_ROW = 27


@dataclass(frozen=True)
class LinkKinematics:
    """Kinematics of every link, indexed like ``RobotModel.link_names`` on axis -2.

    All arrays have a leading sample axis when the recursion was given (T, n) inputs.

    Attributes:
        link_names: the model's link names.
        omega: angular velocity of each link (rad/s), shape (..., n_links, 3).
        alpha: angular acceleration of each link (rad/s^2).
        velocity: linear velocity of each link-frame origin (m/s).
        accel: classical linear acceleration of each link-frame origin minus gravity, i.e. the
            specific force an accelerometer at the origin reads (m/s^2).
        com_accel: the same for each link's centre of mass (m/s^2).
        position: each link-frame origin in the root frame (m), shape (..., n_links, 3).
        rotation: rotation link -> root of each link frame (``x_root = rotation @ x_link``),
            shape (..., n_links, 3, 3).
        frame: ``"link"``: omega ... com_accel are expressed in each link's own frame (Pinocchio's
            LOCAL); ``"root"``: the same vectors re-expressed in the root frame's axes
            (Pinocchio's LOCAL_WORLD_ALIGNED); see :meth:`in_root`. ``position`` and
            ``rotation`` are always in the root frame.
    """

    link_names: tuple[str, ...]
    omega: np.ndarray
    alpha: np.ndarray
    velocity: np.ndarray
    accel: np.ndarray
    com_accel: np.ndarray
    position: np.ndarray
    rotation: np.ndarray
    frame: Literal["link", "root"] = "link"

    def in_root(self) -> LinkKinematics:
        """The same kinematics with omega, alpha, velocity, accel and com_accel in root axes.

        Each vector v_link becomes ``rotation @ v_link``: same physical vector, same point,
        coordinates along the root frame's axes.
        """
        if self.frame == "root":
            return self
        stacked = np.stack([self.omega, self.alpha, self.velocity, self.accel, self.com_accel], axis=-1)
        rotated = np.matmul(self.rotation, stacked)
        omega, alpha, velocity, accel, com_accel = (rotated[..., k] for k in range(5))
        return replace(
            self, omega=omega, alpha=alpha, velocity=velocity, accel=accel, com_accel=com_accel, frame="root"
        )


def forward_recursion(
    model: RobotModel,
    q: Any,
    qd: Any,
    qdd: Any,
    *,
    gravity: Sequence[float] = DEFAULT_GRAVITY,
) -> LinkKinematics:
    """Velocities and accelerations of every link from joint positions, rates and accelerations.

    Args:
        model: the robot.
        q, qd, qdd: joint positions (rad or m), velocities and accelerations, in the column order
            of ``model.joint_names``; shape (n,) for one sample or (T, n) for T samples computed
            in one vectorised pass. Mimic joints are not columns: they follow their leader.
        gravity: gravity in the root frame (m/s^2); (0, 0, -9.81) for a z-up world. Zeros give
            pure kinematic accelerations.

    Returns:
        :class:`LinkKinematics` in link frames, with a leading axis of length T for (T, n) inputs.

    Raises:
        InputError: shapes that do not match the model or each other, or NaN/inf values.
    """
    q, qd, qdd = _check_joint_arrays(model, q, qd, qdd)
    gx, gy, gz = _check_gravity(gravity)
    root_accel = (-gx, -gy, -gz)  # a_0 = -g: the root is at rest, so it reads the specific force -g
    n_links = len(model.link_names)
    if q.ndim == 1:
        columns = q.tolist(), qd.tolist(), qdd.tolist()
        if not math.isfinite(sum(columns[0]) + sum(columns[1]) + sum(columns[2])):
            _check_finite(model, q, qd, qdd)  # names the culprit; a sum can also overflow
        flat = _recurse(model, *columns, root_accel, float, math.sin, math.cos)
        # struct packs a list of floats several times faster than np.array converts it.
        packer = _packer(len(flat))
        buffer = bytearray(packer.size)
        packer.pack_into(buffer, 0, *flat)
        table = np.frombuffer(buffer, dtype=float).reshape(n_links, _ROW)
    else:
        _check_finite(model, q, qd, qdd)
        n_samples = q.shape[0]

        def constant(value: float) -> np.ndarray:
            return np.full(n_samples, value)

        columns = (list(np.ascontiguousarray(x.T)) for x in (q, qd, qdd))
        flat = _recurse(model, *columns, root_accel, constant, np.sin, np.cos)
        # (n_links * _ROW, T) -> (T, n_links, _ROW), made contiguous so every field is a plain view.
        table = np.ascontiguousarray(np.stack(flat).reshape(n_links, _ROW, n_samples).transpose(2, 0, 1))
    return LinkKinematics(
        link_names=model.link_names,
        omega=table[..., _OMEGA],
        alpha=table[..., _ALPHA],
        velocity=table[..., _VELOCITY],
        accel=table[..., _ACCEL],
        com_accel=table[..., _COM_ACCEL],
        position=table[..., _POSITION],
        rotation=table[..., _ROTATION].reshape((*table.shape[:-1], 3, 3)),
    )


@functools.lru_cache(maxsize=16)
def _packer(count: int) -> struct.Struct:
    return struct.Struct(f"{count}d")


_FIXED, _PRISMATIC = JointKind.FIXED, JointKind.PRISMATIC


def _recurse(
    model: RobotModel,
    q: Sequence[Any],
    qd: Sequence[Any],
    qdd: Sequence[Any],
    root_accel: tuple[float, float, float],
    constant: Callable[[float], Any],
    sin: Callable[[Any], Any],
    cos: Callable[[Any], Any],
) -> list[Any]:
    """The recursion over scalar components; returns a flat list, ``_ROW`` entries per link.

    ``q``, ``qd``, ``qdd`` hold one scalar per joint column: Python floats, or numpy arrays of
    shape (T,) with ``constant`` making such an array from a float. The arithmetic is written out
    component by component because, for floats, one numpy call per 3-vector would cost more than
    the whole computation. Per-link state: w = omega, al = alpha, v = velocity, a = accel (all in
    the link frame), R = rotation link -> root (row-major), p = origin in root.
    """
    zero, one = constant(0.0), constant(1.0)
    a0x, a0y, a0z = (constant(c) for c in root_accel)
    states: list[tuple[Any, ...]] = [
        (zero, zero, zero, zero, zero, zero, zero, zero, zero, a0x, a0y, a0z,
         one, zero, zero, zero, one, zero, zero, zero, one, zero, zero, zero)
    ]  # fmt: skip
    # The root is at rest: its centre of mass has the root's acceleration wherever it is.
    out: list[Any] = [*states[0], a0x, a0y, a0z]

    for link in range(1, len(model.link_names)):
        joint = model.parent_joints[link]
        assert joint is not None
        (wx, wy, wz, alx, aly, alz, vx, vy, vz, ax, ay, az,
         R00, R01, R02, R10, R11, R12, R20, R21, R22, px0, py0, pz0) = states[joint.parent_index]  # fmt: skip

        # Joint transform child -> parent at this q: rotation r.. and child origin (px, py, pz).
        kind = joint.kind
        if kind is _FIXED:
            r00, r01, r02, r10, r11, r12, r20, r21, r22 = joint.origin_rotation
            px, py, pz = joint.origin_xyz
        else:
            k = joint.q_index
            if joint.mimic_of is None:
                qj, qdj, qddj = q[k], qd[k], qdd[k]
            else:
                m = joint.multiplier
                qj, qdj, qddj = m * q[k] + joint.offset, m * qd[k], m * qdd[k]
            if kind is _PRISMATIC:
                r00, r01, r02, r10, r11, r12, r20, r21, r22 = joint.origin_rotation
                ox, oy, oz = joint.origin_xyz
                dx, dy, dz = joint.axis_in_parent
                px, py, pz = ox + qj * dx, oy + qj * dy, oz + qj * dz
            else:
                # Rodrigues: origin_rotation + sin(qj) origin_rotation K + (1 - cos(qj)) origin_rotation K^2.
                (o00, o01, o02, o10, o11, o12, o20, o21, o22,
                 k00, k01, k02, k10, k11, k12, k20, k21, k22,
                 m00, m01, m02, m10, m11, m12, m20, m21, m22) = joint.rotation_terms  # fmt: skip
                s = sin(qj)
                u = 1.0 - cos(qj)
                r00, r01, r02 = o00 + s * k00 + u * m00, o01 + s * k01 + u * m01, o02 + s * k02 + u * m02
                r10, r11, r12 = o10 + s * k10 + u * m10, o11 + s * k11 + u * m11, o12 + s * k12 + u * m12
                r20, r21, r22 = o20 + s * k20 + u * m20, o21 + s * k21 + u * m21, o22 + s * k22 + u * m22
                px, py, pz = joint.origin_xyz

        # In parent axes: omega_p x p, then v_p + omega_p x p and
        # a_p + alpha_p x p + omega_p x (omega_p x p).
        cx = wy * pz - wz * py
        cy = wz * px - wx * pz
        cz = wx * py - wy * px
        vx, vy, vz = vx + cx, vy + cy, vz + cz
        ax = ax + (aly * pz - alz * py) + (wy * cz - wz * cy)
        ay = ay + (alz * px - alx * pz) + (wz * cx - wx * cz)
        az = az + (alx * py - aly * px) + (wx * cy - wy * cx)

        # Into the child frame: x_child = R^T x_parent.
        wx, wy, wz = (r00 * wx + r10 * wy + r20 * wz, r01 * wx + r11 * wy + r21 * wz, r02 * wx + r12 * wy + r22 * wz)
        alx, aly, alz = (
            r00 * alx + r10 * aly + r20 * alz, r01 * alx + r11 * aly + r21 * alz, r02 * alx + r12 * aly + r22 * alz
        )  # fmt: skip
        vx, vy, vz = (r00 * vx + r10 * vy + r20 * vz, r01 * vx + r11 * vy + r21 * vz, r02 * vx + r12 * vy + r22 * vz)
        ax, ay, az = (r00 * ax + r10 * ay + r20 * az, r01 * ax + r11 * ay + r21 * az, r02 * ax + r12 * ay + r22 * az)

        # The joint's own motion along its axis e (child frame).
        if kind is not _FIXED:
            ex, ey, ez = joint.axis
            jx, jy, jz = qdj * ex, qdj * ey, qdj * ez  # qd z
            kx, ky, kz = qddj * ex, qddj * ey, qddj * ez  # qdd z
            if kind is _PRISMATIC:
                vx, vy, vz = vx + jx, vy + jy, vz + jz
                ax = ax + kx + 2.0 * (wy * jz - wz * jy)
                ay = ay + ky + 2.0 * (wz * jx - wx * jz)
                az = az + kz + 2.0 * (wx * jy - wy * jx)
            else:
                wx, wy, wz = wx + jx, wy + jy, wz + jz
                alx = alx + kx + (wy * jz - wz * jy)
                aly = aly + ky + (wz * jx - wx * jz)
                alz = alz + kz + (wx * jy - wy * jx)

        # Centre of mass: a_c = a + alpha x r + omega x (omega x r).
        rx, ry, rz = model.com_in_link[link]
        if rx == 0.0 and ry == 0.0 and rz == 0.0:
            acx, acy, acz = ax, ay, az
        else:
            wrx = wy * rz - wz * ry  # omega x r
            wry = wz * rx - wx * rz
            wrz = wx * ry - wy * rx
            acx = ax + (aly * rz - alz * ry) + (wy * wrz - wz * wry)
            acy = ay + (alz * rx - alx * rz) + (wz * wrx - wx * wrz)
            acz = az + (alx * ry - aly * rx) + (wx * wry - wy * wrx)

        # Pose in the root frame: R_root = R_root_parent @ R, p_root = p_root_parent + R_root_parent @ p.
        state = (
            wx, wy, wz, alx, aly, alz, vx, vy, vz, ax, ay, az,
            R00 * r00 + R01 * r10 + R02 * r20, R00 * r01 + R01 * r11 + R02 * r21, R00 * r02 + R01 * r12 + R02 * r22,
            R10 * r00 + R11 * r10 + R12 * r20, R10 * r01 + R11 * r11 + R12 * r21, R10 * r02 + R11 * r12 + R12 * r22,
            R20 * r00 + R21 * r10 + R22 * r20, R20 * r01 + R21 * r11 + R22 * r21, R20 * r02 + R21 * r12 + R22 * r22,
            px0 + R00 * px + R01 * py + R02 * pz, py0 + R10 * px + R11 * py + R12 * pz,
            pz0 + R20 * px + R21 * py + R22 * pz,
        )  # fmt: skip
        states.append(state)
        out += state
        out += (acx, acy, acz)
    return out


def _check_joint_arrays(model: RobotModel, q: Any, qd: Any, qdd: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    n = len(model.joint_names)
    arrays = []
    for name, values in (("q", q), ("qd", qd), ("qdd", qdd)):
        try:
            array = np.asarray(values, dtype=float)
        except (TypeError, ValueError) as exc:
            raise InputError(f"{name} is not an array of numbers: {exc}") from exc
        if array.ndim not in (1, 2) or array.shape[-1] != n:
            raise InputError(
                f"{name} has shape {array.shape}; expected ({n},) or (T, {n}) for joints {list(model.joint_names)}"
            )
        arrays.append(array)
    if not arrays[0].shape == arrays[1].shape == arrays[2].shape:
        raise InputError(
            f"q, qd and qdd must have the same shape; got {arrays[0].shape}, {arrays[1].shape}, {arrays[2].shape}"
        )
    return arrays[0], arrays[1], arrays[2]


def _check_finite(model: RobotModel, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray) -> None:
    for name, values in (("q", q), ("qd", qd), ("qdd", qdd)):
        bad = ~np.isfinite(values)
        if bad.any():
            index = tuple(int(i) for i in np.argwhere(bad)[0])
            where = f"sample {index[0]}, " if values.ndim == 2 else ""
            joint = model.joint_names[index[-1]]
            raise InputError(f"{name} has a non-finite value ({values[index]}) at {where}joint {joint!r}")


def _check_gravity(gravity: Sequence[float]) -> tuple[float, float, float]:
    # Plain Python: this runs for every single sample, where numpy calls would dominate.
    def problem() -> InputError:  # built only on error: repr of an array costs tens of microseconds
        return InputError(f"gravity must be a finite 3-vector in the root frame (m/s^2), got {gravity!r}")

    if isinstance(gravity, (str, bytes)) or (isinstance(gravity, np.ndarray) and gravity.shape != (3,)):
        raise problem()
    try:
        gx, gy, gz = gravity
        g = (float(gx), float(gy), float(gz))
    except (TypeError, ValueError) as exc:
        raise problem() from exc
    if not all(math.isfinite(v) for v in g):
        raise problem()
    return g
