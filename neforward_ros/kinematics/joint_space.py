"""Joint-space dynamics: the inertia matrix M(q), the generalized momentum p = M(q) qd, the Coriolis
term C(q, qd)^T qd and the gravity torques g(q), as Pinocchio's ``crba``,
``computeCoriolisMatrix`` (transposed, times qd) and ``computeGeneralizedGravity`` give them.

What the momentum observer (:mod:`neforward_ros.computation.observer`) needs: with them, external
torques follow from q, qd and the motors' torques, with no joint acceleration (see
:mod:`.joint_space_kernel` for the equations). The arithmetic is generated per model; for one
sample ((n,) arrays) or T samples at once ((T, n)). Fixed base only: the root at rest.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from neforward_ros.kinematics.codegen import Kernel
from neforward_ros.kinematics.forward import DEFAULT_GRAVITY, check_finite, check_gravity, check_joint_arrays
from neforward_ros.kinematics.joint_space_kernel import mass_matrix_of, momentum_of
from neforward_ros.model import RobotModel

_CHUNK = 4096  # samples per vectorised pass of the Python kernel


@dataclass(frozen=True)
class MomentumTerms:
    """Per joint, in ``model.joint_names`` order; (n,) or (T, n).

    Attributes:
        momentum: p = M(q) qd, kg m^2/s (kg m/s for prismatic joints).
        coriolis: C(q, qd)^T qd, N m (N): the rate of the momentum that the motion itself gives.
        gravity: g(q), N m (N): the torques that hold the robot still against gravity.
    """

    momentum: np.ndarray
    coriolis: np.ndarray
    gravity: np.ndarray


def momentum_terms(model: RobotModel, q: Any, qd: Any, *, gravity: Sequence[float] = DEFAULT_GRAVITY) -> MomentumTerms:
    """p, C^T qd and g for joint positions q and velocities qd ((n,) or (T, n)), the root at rest
    under ``gravity`` (m/s^2, root frame).

    Raises:
        InputError: shapes that do not match the model, non-finite values.
    """
    q, qd, _ = check_joint_arrays(model, q, qd, qd)
    check_finite(model, q, qd, qd)
    g = check_gravity(gravity)
    values = momentum_values(model, q, qd, -np.asarray(g, dtype=float))
    return split_momentum(values)


def momentum_values(model: RobotModel, q: np.ndarray, qd: np.ndarray, gravity_force: np.ndarray) -> np.ndarray:
    """The ``momentum`` kernel's flat values ((3n,) or (T, 3n)): p, C^T qd, g; no checks.
    ``gravity_force``: minus gravity in the root frame, (3,) or (T, 3)."""
    return run_kernel(momentum_of(model), [q, qd, gravity_force], None if q.ndim == 1 else q.shape[0])


def split_momentum(values: np.ndarray) -> MomentumTerms:
    n = values.shape[-1] // 3
    return MomentumTerms(values[..., :n], values[..., n : 2 * n], values[..., 2 * n :])


def mass_matrix(model: RobotModel, q: Any) -> np.ndarray:
    """M(q), kg m^2 (kg for prismatic joints): (n, n), or (T, n, n) for (T, n) positions.

    Raises:
        InputError: shapes that do not match the model, non-finite values.
    """
    q, _, _ = check_joint_arrays(model, q, q, q)
    check_finite(model, q, q, q)
    n = len(model.joint_names)
    values = run_kernel(mass_matrix_of(model), [q], None if q.ndim == 1 else q.shape[0])
    return values.reshape((*q.shape[:-1], n, n))


def run_kernel(kernel: Kernel, arguments: list[np.ndarray], count: int | None) -> np.ndarray:
    """A generated kernel (with ``sin, cos`` after its array inputs) on one sample (``count`` None:
    every argument a row) or ``count`` samples (each argument (count, width), or a row for all):
    the compiled kernel when it is ready, else the Python one."""
    native = kernel.compiled()
    if native is not None:
        values = native([np.asarray(a, dtype=float) for a in arguments], 1 if count is None else count)
        return values[0] if count is None else values
    started = time.perf_counter()
    if count is None:
        values = np.array(kernel.python(*(np.asarray(a, dtype=float).tolist() for a in arguments), math.sin, math.cos))
    else:
        columns = [
            np.ascontiguousarray(np.asarray(a, dtype=float).T) if np.ndim(a) == 2 else list(a) for a in arguments
        ]
        parts = []
        for start in range(0, count, _CHUNK):
            part = slice(start, min(count, start + _CHUNK))
            chunk = [c[:, part] if isinstance(c, np.ndarray) else c for c in columns]
            out = kernel.python(*chunk, np.sin, np.cos)
            size = part.stop - part.start
            parts.append(np.stack([np.broadcast_to(np.asarray(v, dtype=float), (size,)) for v in out], axis=1))
        values = np.concatenate(parts) if parts else np.zeros((0, 0))
    kernel.spent(time.perf_counter() - started)
    return values
