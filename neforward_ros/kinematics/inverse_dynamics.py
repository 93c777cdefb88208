"""Inverse dynamics: joint torques and the wrenches the joints transmit, by the backward recursion.

:func:`inverse_dynamics` completes the forward recursion of :mod:`neforward_ros.kinematics.forward` with its
backward pass (Luh, Walker and Paul): from each link's omega, alpha and centre-of-mass specific
force, Newton's and Euler's equations give, leaves to root, the force and moment each link receives
from its parent through its parent joint, and the torque (or force) each joint must produce. The
arithmetic is generated per model (:mod:`neforward_ros.kinematics.backward_kernel`), for one sample on floats
or for T samples at once on numpy arrays.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from neforward_ros.errors import InputError
from neforward_ros.kinematics.backward_kernel import KIN_FIELDS, backward_of, dynamics_of
from neforward_ros.kinematics.forward import (
    DEFAULT_GRAVITY,
    BaseMotion,
    LinkKinematics,
    check_finite,
    check_gravity,
    check_joint_arrays,
    packer_of,
    root_rows,
    root_state,
)
from neforward_ros.kinematics.forward_kernel import SLICES
from neforward_ros.model import RobotModel

_CHUNK = 4096  # samples per vectorised pass
_WARNED: set[int] = set()


@dataclass(frozen=True)
class InverseDynamics:
    """Joint torques and transmitted wrenches; a leading sample axis when computed for (T, n) inputs.

    Attributes:
        joint_names, link_names: the model's.
        joint_torque: (..., n_joints) the torque (N m, revolute and continuous joints) or force (N,
            prismatic) each joint produces along its axis, in ``joint_names`` order. A mimic joint's
            torque is added to its leader's, times the multiplier (the leader's motor drives both).
        force: (..., n_links, 3) N, the force each link receives from its parent through its parent
            joint, in the link frame. For the root link: the force the world applies to the base.
        moment: (..., n_links, 3) N m, the moment that goes with it, about the link origin, in the
            link frame.
    """

    joint_names: tuple[str, ...]
    link_names: tuple[str, ...]
    joint_torque: np.ndarray
    force: np.ndarray
    moment: np.ndarray

    @property
    def wrench(self) -> np.ndarray:
        """(..., n_links, 6): force, then moment."""
        return np.concatenate([self.force, self.moment], axis=-1)


def inverse_dynamics(
    model: RobotModel,
    q: Any,
    qd: Any,
    qdd: Any,
    *,
    gravity: Sequence[float] = DEFAULT_GRAVITY,
    kinematics: LinkKinematics | None = None,
    external_wrenches: Any = None,
    base: BaseMotion | None = None,
) -> InverseDynamics:
    """Joint torques and transmitted wrenches of the robot moving with q, qd, qdd.

    Args:
        model: the robot, with the masses and inertias of its URDF (``model.mass``,
            ``model.inertia_in_link``; a link without ``<inertial>`` is massless).
        q, qd, qdd: as for :func:`~neforward_ros.forward_recursion`: (n,) or (T, n).
        gravity: in the root frame, m/s^2.
        kinematics: the :func:`~neforward_ros.forward_recursion` result for the same q, qd, qdd and
            gravity, in link frames; given, its omega, alpha and com_accel are used and no second
            forward pass is made (``gravity`` is then already in them).
        external_wrenches: (n_links, 6) or (T, n_links, 6): the wrench the environment applies to
            each link (force N, then moment N m about the link origin), in the link frame; None for
            none.
        base: the root link's motion for a moving base (see :class:`~neforward_ros.BaseMotion`);
            the root's wrench is then what must act on the base for that motion.

    Returns:
        :class:`InverseDynamics`.

    Raises:
        InputError: shapes that do not match the model, or non-finite values.
    """
    q, qd, qdd = check_joint_arrays(model, q, qd, qdd)
    if q.ndim == 1:  # Python sums of lists are cheaper than numpy checks; the checks name the culprit
        lists = q.tolist(), qd.tolist(), qdd.tolist()
        if not math.isfinite(sum(lists[0]) + sum(lists[1]) + sum(lists[2])):
            check_finite(model, q, qd, qdd)
    else:
        check_finite(model, q, qd, qdd)
    g = check_gravity(gravity)
    _warn_inertias(model)
    external = _check_wrenches(model, external_wrenches, q.shape[:-1])
    if kinematics is not None:
        if kinematics.frame != "link" or kinematics.omega.shape[:-2] != q.shape[:-1]:
            raise InputError(
                "kinematics must be forward_recursion's result for the same samples, in link frames (not in_root())"
            )
        kin = np.concatenate([getattr(kinematics, field) for field in KIN_FIELDS], axis=-1)  # (..., n_links, 9)
        values = _run_backward(model, q, kin, external)
    else:
        root = root_state(g) if base is None else base.root(None if q.ndim == 1 else q.shape[0])
        values = _run_dynamics(model, lists if q.ndim == 1 else (q, qd, qdd), root, external)
    return _result(model, values)


def wrenches_from_table(model: RobotModel, q: np.ndarray, table: np.ndarray, external: Any = None) -> np.ndarray:
    """The backward pass on the forward kernel's rows ((n_links, ROW) or (T, n_links, ROW)): the flat
    values per sample, per link f (3) and n (3), then the joint torques; no checks."""
    columns = np.concatenate([table[..., SLICES[field]] for field in KIN_FIELDS], axis=-1)
    return _run_backward(model, q, columns, external)


def split_values(model: RobotModel, values: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(force (..., n_links, 3), moment (..., n_links, 3), torque (..., n)) of the flat values."""
    n_links = len(model.link_names)
    wrench = values[..., : 6 * n_links].reshape((*values.shape[:-1], n_links, 6))
    return wrench[..., :3], wrench[..., 3:], values[..., 6 * n_links :]


def _result(model: RobotModel, values: np.ndarray) -> InverseDynamics:
    force, moment, torque = split_values(model, values)
    return InverseDynamics(model.joint_names, model.link_names, torque, force, moment)


def _run_dynamics(model, states, root, external) -> np.ndarray:
    """``states``: (q, qd, qdd) as lists (one sample) or (T, n) arrays."""
    kernel = dynamics_of(model, external=external is not None)
    q, qd, qdd = states
    single = isinstance(q, list)
    native = kernel.compiled()
    if native is not None:  # the same arithmetic, compiled: the same numbers, faster
        count = 1 if single else q.shape[0]
        fext = None if external is None else external.reshape(count, -1)
        values = native([np.asarray(q, dtype=float), np.asarray(qd, dtype=float), np.asarray(qdd, dtype=float),
                         root_rows(root, count, single), fext], count)  # fmt: skip
        return values[0] if single else values
    started = time.perf_counter()
    if single:
        fext = None if external is None else external.reshape(-1).tolist()
        values = _array(kernel.python(q, qd, qdd, root, math.sin, math.cos, fext))
    else:
        values = _batched(
            lambda part, fext: kernel.python(*(x[:, part] for x in (q.T, qd.T, qdd.T)), root, np.sin, np.cos, fext),
            model,
            q.shape[0],
            external,
        )
    kernel.spent(time.perf_counter() - started)
    return values


def _run_backward(model, q, kin, external) -> np.ndarray:
    kernel = backward_of(model, external=external is not None)
    single = q.ndim == 1
    native = kernel.compiled()
    if native is not None:  # the same arithmetic, compiled: the same numbers, faster
        count = 1 if single else q.shape[0]
        fext = None if external is None else external.reshape(count, -1)
        values = native([q, kin.reshape(count, -1), fext], count)
        return values[0] if single else values
    started = time.perf_counter()
    if single:
        fext = None if external is None else external.reshape(-1).tolist()
        values = _array(kernel.python(q.tolist(), kin.reshape(-1).tolist(), math.sin, math.cos, fext))
    else:
        flat_kin = np.ascontiguousarray(kin.reshape(kin.shape[0], -1).T)  # (n_links * 9, T)
        q_columns = np.ascontiguousarray(q.T)
        values = _batched(
            lambda part, fext: kernel.python(q_columns[:, part], flat_kin[:, part], np.sin, np.cos, fext),
            model,
            q.shape[0],
            external,
        )
    kernel.spent(time.perf_counter() - started)
    return values


def _array(values: tuple[float, ...]) -> np.ndarray:
    """A tuple of floats as an array: struct packs it several times faster than np.array converts it."""
    packer = packer_of(len(values))
    buffer = bytearray(packer.size)
    packer.pack_into(buffer, 0, *values)
    return np.frombuffer(buffer, dtype=float)


def _batched(call, model: RobotModel, count: int, external) -> np.ndarray:
    width = 6 * len(model.link_names) + len(model.joint_names)
    out = np.empty((width, count))
    flat_external = None if external is None else np.ascontiguousarray(external.reshape(count, -1).T)
    for start in range(0, count, _CHUNK):
        part = slice(start, min(count, start + _CHUNK))
        values = call(part, None if flat_external is None else flat_external[:, part])
        for row, value in enumerate(values):
            out[row, part] = value
    return out.T


def _check_wrenches(model: RobotModel, wrenches: Any, samples: tuple[int, ...]) -> np.ndarray | None:
    if wrenches is None:
        return None
    try:
        array = np.asarray(wrenches, dtype=float)
    except (TypeError, ValueError) as exc:
        raise InputError(f"external_wrenches is not an array of numbers: {exc}") from exc
    expected = (*samples, len(model.link_names), 6)
    if array.shape != expected:
        raise InputError(f"external_wrenches has shape {array.shape}; expected {expected} (force, moment per link)")
    if not np.all(np.isfinite(array)):
        raise InputError("external_wrenches has a non-finite value")
    return array


def _warn_inertias(model: RobotModel) -> None:
    if model.inertia_warnings and id(model) not in _WARNED:
        _WARNED.add(id(model))
        for warning in model.inertia_warnings:
            logging.getLogger("neforward_ros").warning(warning)
