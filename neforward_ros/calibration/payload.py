"""A payload on a link, fitted with the joints' friction: its mass and centre of mass (a point mass).

A point mass m at c (in the link's frame) adds to each window's momentum equation
(:mod:`.fit`) m u(c), u(c) the equation's terms of a unit mass at c: the window's mean of
dp/dt + g - C^T qd of that mass alone, from the same kernels (the model with the mass minus the model
without). u is a quadratic polynomial in c, so ten evaluations (at the link origin and 10 cm along
and between its axes) give it everywhere. For a given c the joints' coefficients and m are linear:
one least-squares problem over every joint at once; c is searched (Nelder-Mead) for the least
residual. The joints are then fitted again on the equation less the payload's terms.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from neforward_ros.calibration.fit import JointFit, Windows
from neforward_ros.kinematics.effort_model import EffortModel
from neforward_ros.model import RobotModel, with_payload

STEP = 0.1
"""m: the spacing of the points the quadratic u(c) is taken from."""
MIN_MASS = 0.02
"""kg: a lighter payload is reported as none."""


@dataclass(frozen=True)
class Payload:
    """The fit: mass kg, centre of mass (link frame, m), and the residual RMS with and without it."""

    link: str
    mass: float
    com: tuple[float, float, float]
    residual: float
    residual_without: float


def basis_points() -> list[np.ndarray]:
    e = np.eye(3) * STEP
    return [np.zeros(3), *(sign * e[i] for i in range(3) for sign in (1.0, -1.0)),
            e[0] + e[1], e[0] + e[2], e[1] + e[2]]  # fmt: skip


def quadratic(values: Sequence[np.ndarray]) -> list[np.ndarray]:
    """The coefficients (a0, a_x, a_y, a_z, a_xx, a_yy, a_zz, a_xy, a_xz, a_yz) of the quadratic
    through the ten :func:`basis_points` values."""
    a0 = values[0]
    linear = [(values[1 + 2 * i] - values[2 + 2 * i]) / (2 * STEP) for i in range(3)]
    square = [(values[1 + 2 * i] + values[2 + 2 * i] - 2 * a0) / (2 * STEP**2) for i in range(3)]
    cross = []
    for k, (i, j) in enumerate(((0, 1), (0, 2), (1, 2))):
        cross.append((values[7 + k] - a0 - STEP * (linear[i] + linear[j])) / STEP**2 - square[i] - square[j])
    return [a0, *linear, *square, *cross]


def evaluate(coefficients: Sequence[np.ndarray], c: np.ndarray) -> np.ndarray:
    x, y, z = c
    weights = (1.0, x, y, z, x * x, y * y, z * z, x * y, x * z, y * z)
    return sum(w * a for w, a in zip(weights, coefficients, strict=True))


def payload_models(model: RobotModel, link: str) -> list[RobotModel]:
    """The model with a unit mass at each basis point."""
    return [with_payload(model, link, 1.0, tuple(point)) for point in basis_points()]


def fit_payload(
    data: Windows,
    unit_terms: Callable[[int], Windows],
    fits: list[JointFit],
    prior: EffortModel,
    link: str,
) -> tuple[Payload, np.ndarray]:
    """The payload and the equation's target less its terms ((W, n), for fitting the joints again).

    Args:
        data: the windows of the arm's own equation.
        unit_terms: k -> the windows of a unit mass at basis point k (its target only is used).
        fits: the joints' first fit (which coefficients are free, the velocity scales).
        prior: the values of the coefficients kept.
    """
    coefficients = quadratic([unit_terms(k).target for k in range(len(basis_points()))])
    n = len(fits)
    blocks, targets = [], []
    for j, fit in enumerate(fits):
        columns = [np.ones(len(data.target))]
        target = data.target[:, j].copy()
        for key, (column, factor) in data.terms(j, fit.velocity_scale).items():
            if key in fit.fitted:
                columns.append(factor * column)
            else:
                target -= factor * float(getattr(prior, key)[j]) * column
        blocks.append(np.stack(columns, axis=1))
        targets.append(target)
    widths = [b.shape[1] for b in blocks]
    rows = len(data.target)
    stacked_target = np.concatenate(targets)
    base = np.zeros((rows * n, sum(widths) + 1))
    at = 0
    for j, block in enumerate(blocks):
        base[j * rows : (j + 1) * rows, at : at + widths[j]] = block
        at += widths[j]

    def solve(c: np.ndarray) -> tuple[float, float]:
        u = evaluate(coefficients, c)  # (W, n)
        matrix = base.copy()
        matrix[:, -1] = -u.T.reshape(-1)  # the arm's motors also carry m u: target = X theta - m u
        solution, *_ = np.linalg.lstsq(matrix, stacked_target, rcond=None)
        residual = stacked_target - matrix @ solution
        return float(np.sqrt(np.mean(residual**2))), float(solution[-1])

    without = np.linalg.lstsq(base[:, :-1], stacked_target, rcond=None)[0]
    residual_without = float(np.sqrt(np.mean((stacked_target - base[:, :-1] @ without) ** 2)))
    best_c = _nelder_mead(lambda c: solve(c)[0], np.zeros(3), STEP)
    residual, mass = solve(best_c)
    if mass < MIN_MASS:
        return Payload(link, 0.0, (0.0, 0.0, 0.0), residual_without, residual_without), data.target
    payload = Payload(link, mass, tuple(float(x) for x in best_c), residual, residual_without)
    return payload, data.target + mass * evaluate(coefficients, best_c)


def _nelder_mead(f: Callable[[np.ndarray], float], start: np.ndarray, step: float, iterations: int = 300) -> np.ndarray:
    """The minimum of f near ``start`` by the Nelder-Mead simplex (the standard coefficients)."""
    simplex = [start] + [start + step * e for e in np.eye(len(start))]
    values = [f(x) for x in simplex]
    for _ in range(iterations):
        order = np.argsort(values)
        simplex = [simplex[k] for k in order]
        values = [values[k] for k in order]
        if abs(values[-1] - values[0]) <= 1e-10 * (abs(values[0]) + 1e-12) and np.ptp(simplex, axis=0).max() < 1e-5:
            break
        centroid = np.mean(simplex[:-1], axis=0)
        reflected = centroid + (centroid - simplex[-1])
        fr = f(reflected)
        if fr < values[0]:
            expanded = centroid + 2.0 * (centroid - simplex[-1])
            fe = f(expanded)
            simplex[-1], values[-1] = (expanded, fe) if fe < fr else (reflected, fr)
        elif fr < values[-2]:
            simplex[-1], values[-1] = reflected, fr
        else:
            contracted = centroid + 0.5 * (simplex[-1] - centroid)
            fc = f(contracted)
            if fc < values[-1]:
                simplex[-1], values[-1] = contracted, fc
            else:
                simplex = [simplex[0] + 0.5 * (x - simplex[0]) for x in simplex]
                values = [f(x) for x in simplex]
    return simplex[int(np.argmin(values))]
