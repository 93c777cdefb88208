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

The arithmetic is generated per model by :mod:`neforward_ros.kinematics.forward_kernel` as straight-line Python with
the model's constants folded in. Given Python floats it computes one sample with no numpy call at
all; given numpy arrays of shape (T,) it computes T samples at once, vectorised over the samples.
"""

from __future__ import annotations

import functools
import math
import struct
import time
from collections.abc import Sequence
from dataclasses import dataclass, fields, replace
from typing import Any, Literal

import numpy as np

from neforward_ros.errors import InputError
from neforward_ros.kinematics.forward_kernel import IN_ROOT, ROW, SLICES, kernel_of
from neforward_ros.model import RobotModel

DEFAULT_GRAVITY = (0.0, 0.0, -9.81)
"""Gravity in the root frame for a z-up world (REP-103), m/s^2."""

_CHUNK = 4096  # samples per vectorised pass: bounds the memory of the kernel's intermediates


@dataclass(frozen=True)
class BaseMotion:
    """The root link's motion, for a robot whose base moves (a legged robot, a mobile manipulator, a
    robot on a ship): every vector in the root link's frame, each of shape (3,) or (T, 3).

    Attributes:
        omega: angular velocity, rad/s.
        alpha: angular acceleration, rad/s^2.
        velocity: linear velocity of the root link's origin, m/s (only link velocities depend on it;
            accelerations do not: zeros give velocities relative to the root origin's motion).
        specific_force: classical linear acceleration of the root link's origin minus gravity,
            m/s^2: what an accelerometer there reads (a base IMU measures it directly, with no
            gravity model and no orientation needed).
    """

    omega: Any
    alpha: Any
    velocity: Any
    specific_force: Any

    def root(self, samples: int | None) -> tuple[Any, ...]:
        """The recursion's root state (12 values: floats, or (T,) arrays for T samples); checked.

        Raises:
            InputError: a shape that is neither (3,) nor (samples, 3), or a non-finite value.
        """
        values = []
        for name in ("omega", "alpha", "velocity", "specific_force"):
            try:
                array = np.asarray(getattr(self, name), dtype=float)
            except (TypeError, ValueError) as exc:
                raise InputError(f"base {name} is not an array of numbers: {exc}") from exc
            shapes = [(3,)] if samples is None else [(3,), (samples, 3)]
            if array.shape not in shapes:
                raise InputError(f"base {name} has shape {array.shape}; expected {' or '.join(map(str, shapes))}")
            if not np.all(np.isfinite(array)):
                raise InputError(f"base {name} has a non-finite value")
            if array.ndim == 1:
                values.extend(float(v) for v in array)
            else:
                values.extend(np.ascontiguousarray(array[:, k]) for k in range(3))
        return tuple(values)


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
        com_velocity: linear velocity of each link's centre of mass (m/s).
        position: each link-frame origin in the root frame (m), shape (..., n_links, 3).
        rotation: rotation link -> root of each link frame (``x_root = rotation @ x_link``),
            shape (..., n_links, 3, 3).
        com_position: each link's centre of mass in the root frame (m).
        orientation: ``rotation`` as a unit quaternion (x, y, z, w) with w >= 0, (..., n_links, 4).
        frame: ``"link"``: omega ... com_velocity are expressed in each link's own frame
            (Pinocchio's LOCAL); ``"root"``: the same vectors re-expressed in the root frame's axes
            (Pinocchio's LOCAL_WORLD_ALIGNED); see :meth:`in_root`. ``position``, ``rotation``,
            ``com_position`` and ``orientation`` are always in the root frame.
    """

    link_names: tuple[str, ...]
    omega: np.ndarray
    alpha: np.ndarray
    velocity: np.ndarray
    accel: np.ndarray
    com_accel: np.ndarray
    com_velocity: np.ndarray
    position: np.ndarray
    rotation: np.ndarray
    com_position: np.ndarray
    orientation: np.ndarray
    frame: Literal["link", "root"] = "link"

    @classmethod
    def from_table(
        cls, link_names: tuple[str, ...], table: np.ndarray, frame: Literal["link", "root"] = "link"
    ) -> LinkKinematics:
        """Views into a table of the kernel's rows, (..., n_links, ROW); with ``frame="root"`` the
        vectors are the rows' own along the root axes (``<name>_in_root``: what :meth:`in_root`
        computes, without computing it again)."""
        own = {field.name for field in fields(cls)}
        views = {name: table[..., part] for name, part in SLICES.items() if name in own}
        views["rotation"] = views["rotation"].reshape((*table.shape[:-1], 3, 3))
        if frame == "root":
            views.update({name: table[..., SLICES[f"{name}_in_root"]] for name in IN_ROOT})
        return cls(link_names=link_names, frame=frame, **views)  # the kernel gives orientations with w >= 0

    def in_root(self) -> LinkKinematics:
        """The same kinematics with omega, alpha, velocity, accel, com_accel and com_velocity in root axes.

        Each vector v_link becomes ``rotation @ v_link``: same physical vector, same point,
        coordinates along the root frame's axes.
        """
        if self.frame == "root":
            return self
        names = ("omega", "alpha", "velocity", "accel", "com_accel", "com_velocity")
        stacked = np.stack([getattr(self, name) for name in names], axis=-1)
        rotated = np.matmul(self.rotation, stacked)
        return replace(self, frame="root", **{name: rotated[..., k] for k, name in enumerate(names)})


def forward_recursion(
    model: RobotModel,
    q: Any,
    qd: Any,
    qdd: Any,
    *,
    gravity: Sequence[float] = DEFAULT_GRAVITY,
    base: BaseMotion | None = None,
) -> LinkKinematics:
    """Velocities and accelerations of every link from joint positions, rates and accelerations.

    Args:
        model: the robot.
        q, qd, qdd: joint positions (rad or m), velocities and accelerations, in the column order
            of ``model.joint_names``; shape (n,) for one sample or (T, n) for T samples computed
            in one vectorised pass. Mimic joints are not columns: they follow their leader.
        gravity: gravity in the root frame (m/s^2); (0, 0, -9.81) for a z-up world. Zeros give
            pure kinematic accelerations. Used for a fixed base only.
        base: the root link's motion, for a moving base; None: the root is fixed, at rest, and its
            specific force is -gravity.

    Returns:
        :class:`LinkKinematics` in link frames, with a leading axis of length T for (T, n) inputs;
        ``position`` and ``rotation`` relative to the root link.

    Raises:
        InputError: shapes that do not match the model or each other, or NaN/inf values.
    """
    q, qd, qdd = check_joint_arrays(model, q, qd, qdd)
    gx, gy, gz = check_gravity(gravity)
    if q.ndim == 1:
        columns = q.tolist(), qd.tolist(), qdd.tolist()
        if not np.isfinite(sum(columns[0]) + sum(columns[1]) + sum(columns[2])):
            check_finite(model, q, qd, qdd)  # names the culprit; a sum can also overflow
    else:
        check_finite(model, q, qd, qdd)
    root = root_state(gravity=(gx, gy, gz)) if base is None else base.root(None if q.ndim == 1 else q.shape[0])
    table = kinematics_table(model, q, qd, qdd, root)
    return LinkKinematics.from_table(model.link_names, table)


def root_state(gravity: Sequence[float] = DEFAULT_GRAVITY) -> tuple[float, ...]:
    """The root's (omega, alpha, v, a) for a fixed base: at rest, with a_0 = -g, the specific force
    an accelerometer on the base reads."""
    if isinstance(gravity, tuple):
        return _root_state(gravity)
    gx, gy, gz = gravity
    return (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, -gx, -gy, -gz)


@functools.lru_cache(maxsize=8)
def _root_state(gravity: tuple[float, ...]) -> tuple[float, ...]:
    gx, gy, gz = gravity
    return (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, -gx, -gy, -gz)


def root_rows(root: Sequence[Any], count: int, single: bool) -> np.ndarray:
    """The root's state as the compiled kernels take it: one row of 12 (one sample, or the same for
    every sample), else (count, 12)."""
    if single or not isinstance(root[0], np.ndarray):
        return np.array(root, dtype=float)
    return np.stack([np.broadcast_to(r, (count,)) for r in root], axis=1)


def kinematics_table(
    model: RobotModel, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray, root: Sequence[Any]
) -> np.ndarray:
    """The kernel's rows for one sample, (n_links, ROW), or for T, (T, n_links, ROW); no checks.

    ``q``, ``qd``, ``qdd`` are (n,) or (T, n) float arrays; ``root`` the root's state (12 values,
    floats or (T,) arrays) in the root frame: omega, alpha, velocity, specific force.
    """
    kernel = kernel_of(model)
    n_links = len(model.link_names)
    single = q.ndim == 1
    native = kernel.compiled()
    if native is not None:  # the same arithmetic, compiled: the same numbers, faster
        count = 1 if single else q.shape[0]
        table = native([q, qd, qdd, root_rows(root, count, single)], count)
        return table.reshape(n_links, ROW) if single else table.reshape(count, n_links, ROW)
    started = time.perf_counter()
    if single:
        values = kernel.python(q.tolist(), qd.tolist(), qdd.tolist(), root, math.sin, math.cos, math.copysign)
        kernel.spent(time.perf_counter() - started)
        # struct packs a tuple of floats several times faster than np.array converts it.
        packer = packer_of(len(values))
        buffer = bytearray(packer.size)
        packer.pack_into(buffer, 0, *values)
        return np.frombuffer(buffer, dtype=float).reshape(n_links, ROW)
    # Batches are computed field by field: each of the kernel's values is one contiguous row of T
    # numbers, and the (T, n_links, ROW) table is a transposed view of those rows (no copy).
    count = q.shape[0]
    rows = np.empty((n_links * ROW, count))
    columns = [np.ascontiguousarray(x.T) for x in (q, qd, qdd)]
    for start in range(0, count, _CHUNK):
        part = slice(start, min(count, start + _CHUNK))
        chunk_root = [r[part] if isinstance(r, np.ndarray) else r for r in root]
        values = kernel.python(*(c[:, part] for c in columns), chunk_root, np.sin, np.cos, np.copysign)
        for row, value in enumerate(values):
            rows[row, part] = value
    kernel.spent(time.perf_counter() - started)
    return rows.reshape(n_links, ROW, count).transpose(2, 0, 1)


@functools.lru_cache(maxsize=16)
def packer_of(count: int) -> struct.Struct:
    """A struct packing ``count`` doubles (kept for the last few counts)."""
    return struct.Struct(f"{count}d")


def check_joint_arrays(model: RobotModel, q: Any, qd: Any, qdd: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """q, qd, qdd as float arrays of the model's width and one shape; InputError otherwise."""
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


def check_finite(model: RobotModel, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray) -> None:
    """InputError naming the first non-finite value's array, sample and joint."""
    for name, values in (("q", q), ("qd", qd), ("qdd", qdd)):
        bad = ~np.isfinite(values)
        if bad.any():
            index = tuple(int(i) for i in np.argwhere(bad)[0])
            where = f"sample {index[0]}, " if values.ndim == 2 else ""
            joint = model.joint_names[index[-1]]
            raise InputError(f"{name} has a non-finite value ({values[index]}) at {where}joint {joint!r}")


def check_gravity(gravity: Sequence[float]) -> tuple[float, float, float]:
    """gravity as three finite floats; InputError otherwise."""

    # Plain Python: this runs for every single sample, where numpy calls would dominate.
    def problem() -> InputError:  # built only on error: repr of an array costs tens of microseconds
        return InputError(f"gravity must be a finite 3-vector in the root frame (m/s^2), got {gravity!r}")

    if gravity is DEFAULT_GRAVITY:
        return DEFAULT_GRAVITY
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
