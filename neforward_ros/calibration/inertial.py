"""The links' inertial parameters from recordings of free motion, physically consistent.

The joint torques are linear in the links' inertial parameters (:mod:`neforward_ros.kinematics.regressor`):
at the recording's stamps, with the whole-recording estimator's q, q̇, q̈ (the bag tool's),

    scale_j effort_j + offset_j - coulomb_j tanh(q̇_j / velocity_scale_j) - viscous_j q̇_j = Y_j(q, q̇, q̈) pi

for every joint j with a measured effort. Fitted by least squares, jointly with each joint's offset
and friction, over the moving links that have a mass and an inertia in the URDF. The scales are
given (``effort.scale``; 1: the efforts are torques): every term of the equation is linear, so a
common factor of the scales and the parameters is not in the data; the given scales set the units.
Then:

- **Physical consistency** by construction: each link's parameters are those of a pseudo-inertia
  ``J = [[Sigma, h], [h^T, m]]`` (Sigma = tr(I_o)/2 1 - I_o) written as U U^T with U upper triangular
  of positive diagonal, its ten numbers the fit's unknowns (the log-Cholesky parametrisation of
  Rucker and Wensing, 2022): any values give a positive mass and a positive-definite inertia that
  meets the triangle inequalities.
- **What the motion cannot tell stays the URDF's**: a prior (half of each link's own magnitudes, per
  parameter) keeps the directions the recording does not excite at the URDF's values; the data
  decide the rest. Each link's parameters are said to be identified where the
  data shrink their uncertainty below :data:`TOLD` of the prior's.
- Each joint's noise weighs its rows (the RMS residual of a first, linear fit), so that a wrist's
  N m count as much as a shoulder's tens.

The offsets and friction found here are a starting point only: ``neforward calibrate`` fits them
again, with the scales, joint by joint on the momentum equation (:mod:`.fit`), with the model
identified here.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from neforward_ros.kinematics.regressor import link_parameters, split_parameters, torque_regressor
from neforward_ros.model import RobotModel

MAX_SAMPLES = 3000
"""Stamps the fit takes at most (evenly spread over the recordings)."""
PRIOR = 0.5
"""The prior's standard deviation, relative to each link's magnitudes (mass, m r, m r^2)."""
TOLD = 0.5
"""A parameter is identified where the data bring its standard deviation below this fraction of the prior's."""
VELOCITY_SCALE = 0.01
"""rad/s: the friction's smooth sign, tanh(q̇ / this), where the prior gives none."""
UNKNOWNS = 3
"""Each joint's own unknowns in the fit: offset, Coulomb and viscous friction."""


@dataclass
class Identified:
    """What :func:`identify` found.

    Attributes:
        links: the links identified (moving links with a mass and an inertia in the URDF).
        parameters: (len(links), 10) their inertial parameters (regressor order).
        told: (len(links), 10) whether the data identified each (else it stays near the URDF's).
        residual_before, residual_after: per joint, the torque equation's RMS residual with the URDF's
            parameters (friction, scale and offset fitted) and with those found, in the efforts' units.
        rank: how many combinations of the parameters the motion excites (of 10 per link).
        notes: what the motion did not tell.
    """

    links: list[str]
    parameters: np.ndarray
    told: np.ndarray
    residual_before: np.ndarray
    residual_after: np.ndarray
    rank: int
    notes: list[str] = field(default_factory=list)

    def values(self) -> dict[str, list]:
        """The ``inertial.*`` parameters (rounded to 6 significant digits)."""
        mass, com, inertia = split_parameters(self.parameters)
        six = inertia[:, [0, 0, 0, 1, 1, 2], [0, 1, 2, 1, 2, 2]]

        def rounded(values: np.ndarray) -> list[float]:
            return [float(f"{v:.6g}") for v in np.ravel(values)]

        return {
            "inertial.link_names": list(self.links),
            "inertial.mass": rounded(mass),
            "inertial.com": rounded(com),
            "inertial.inertia": rounded(six),
        }


def _pseudo_inertia(p: np.ndarray) -> np.ndarray:
    inertia_o = np.array([[p[4], p[5], p[6]], [p[5], p[7], p[8]], [p[6], p[8], p[9]]])
    sigma = 0.5 * np.trace(inertia_o) * np.eye(3) - inertia_o
    out = np.zeros((4, 4))
    out[:3, :3], out[:3, 3], out[3, :3], out[3, 3] = sigma, p[1:4], p[1:4], p[0]
    return out


def _from_pseudo(j: np.ndarray) -> np.ndarray:
    sigma = j[:3, :3]
    inertia_o = np.trace(sigma) * np.eye(3) - sigma
    return np.array([j[3, 3], *j[:3, 3], *inertia_o[[0, 0, 0, 1, 1, 2], [0, 1, 2, 1, 2, 2]]])


def to_cholesky(p: np.ndarray) -> np.ndarray:
    """A link's parameters -> the ten log-Cholesky numbers (a pseudo-inertia that is not positive
    definite, as URDFs' rounding leaves some, is made so first)."""
    j = _pseudo_inertia(p)
    scale = max(float(np.abs(j).max()), 1e-12)
    low = np.linalg.eigvalsh(j).min()
    if low <= 1e-9 * scale:
        j = j + (1e-9 * scale - low) * np.eye(4)
    exchange = np.eye(4)[::-1]
    upper = exchange @ np.linalg.cholesky(exchange @ j @ exchange) @ exchange  # J = U U^T, U upper
    alpha = np.log(upper[3, 3])
    u = upper / np.exp(alpha)
    return np.array([alpha, *np.log(np.diag(u)[:3]), u[0, 1], u[1, 2], u[0, 2], u[0, 3], u[1, 3], u[2, 3]])


def from_cholesky(theta: np.ndarray) -> np.ndarray:
    """The ten log-Cholesky numbers -> a link's parameters (physically consistent)."""
    alpha, d1, d2, d3, s12, s23, s13, t1, t2, t3 = theta
    u = np.exp(alpha) * np.array(
        [[np.exp(d1), s12, s13, t1], [0.0, np.exp(d2), s23, t2], [0.0, 0.0, np.exp(d3), t3], [0.0, 0.0, 0.0, 1.0]]
    )
    return _from_pseudo(u @ u.T)


def _derivative(theta: np.ndarray) -> np.ndarray:
    """(10, 10) d parameters / d theta, by central differences."""
    out = np.zeros((10, 10))
    for k in range(10):
        step = np.zeros(10)
        step[k] = 1e-6
        out[:, k] = (from_cholesky(theta + step) - from_cholesky(theta - step)) / 2e-6
    return out


def _consistent(p: np.ndarray) -> bool:
    """Whether a link's parameters are those of a body with a mass and a positive-definite inertia."""
    if not p[0] > 0.0:
        return False
    values = np.linalg.eigvalsh(_pseudo_inertia(p))
    return bool(values.min() > 1e-6 * values.max())


def _prior_scale(p: np.ndarray) -> np.ndarray:
    """Per parameter, the prior's standard deviation: half the link's mass, mass x length, mass x length^2."""
    m = max(float(p[0]), 1e-3)
    inertia_o = np.array([[p[4], p[5], p[6]], [p[5], p[7], p[8]], [p[6], p[8], p[9]]])
    length = max(float(np.linalg.norm(p[1:4])) / m, float(np.sqrt(max(np.trace(inertia_o), 0.0) / (2 * m))), 0.02)
    return PRIOR * np.array([m, *(3 * [m * length]), *(6 * [m * length**2])])


def identify(
    model: RobotModel,
    q: np.ndarray,
    qd: np.ndarray,
    qdd: np.ndarray,
    efforts: np.ndarray,
    measured: np.ndarray,
    gravity: Sequence[float],
    effort_scale: np.ndarray,
    velocity_scale: np.ndarray | None = None,
) -> Identified:
    """The inertial parameters (see the module docstring) from samples of free motion.

    Args:
        model: the model whose parameters are the prior (the URDF's, a payload's included).
        q, qd, qdd, efforts: (T, n) at the samples (evenly thinned to :data:`MAX_SAMPLES` here).
        measured: (n,) bool, the joints whose efforts are measured (others: no rows).
        gravity: in the root frame, m/s^2.
        effort_scale: (n,) torque (N m; N) per effort unit, per joint: the units of the parameters.
        velocity_scale: (n,) the friction's smooth-sign scale per joint.
    """
    from scipy.optimize import least_squares

    stride = max(1, int(np.ceil(len(q) / MAX_SAMPLES)))
    q, qd, qdd, efforts = (np.asarray(x, dtype=float)[::stride] for x in (q, qd, qdd, efforts))
    n = q.shape[1]
    scale_v = np.full(n, VELOCITY_SCALE) if velocity_scale is None else np.asarray(velocity_scale, dtype=float)
    prior = link_parameters(model)
    # Links that move and have a mass and an inertia of their own in the URDF (a point mass, as
    # grippers' fingers often are, stays as it is: no inertia to start from).
    moving = model.driving_columns.any(axis=1) & np.array([_consistent(p) for p in prior])
    links = np.flatnonzero(moving)
    rows = np.flatnonzero(measured)
    regressor = torque_regressor(model, q, qd, qdd, gravity)[:, rows]  # (T, r, L, 10)
    fixed = np.einsum("trlk,lk->tr", regressor[:, :, ~moving], prior[~moving])
    y_links = regressor[:, :, links]  # (T, r, P, 10)
    e = efforts[:, rows]
    v = qd[:, rows]
    sign = np.tanh(v / scale_v[rows])
    samples, count = e.shape
    # the joints' own unknowns, per row: offset, coulomb, viscous -> (T, r, r, 3); the efforts in
    # torque units by the given scales (the unit every term shares: see the module docstring)
    own = np.zeros((samples, count, count, UNKNOWNS))
    index = np.arange(count)
    own[:, index, index, 0] = 1.0
    own[:, index, index, 1] = -sign
    own[:, index, index, 2] = -v
    own_flat = own.reshape(samples * count, UNKNOWNS * count)
    y_flat = y_links.reshape(samples * count, len(links) * 10)
    torque = e * np.asarray(effort_scale, dtype=float)[rows]
    target = (fixed - torque).reshape(-1)  # own @ x - y @ pi = fixed - scale * effort

    def linear_fit(pi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The joints' unknowns for these link parameters, and the residuals (T, r)."""
        rhs = target + y_flat @ pi.reshape(-1)
        x, *_ = np.linalg.lstsq(own_flat, rhs, rcond=None)
        return x, (own_flat @ x - rhs).reshape(samples, count)

    _, before = linear_fit(prior[links])
    residual_before = np.sqrt(np.mean(np.square(before), axis=0))
    # Pass 1, linear (pi unconstrained, the prior as ridge) for each joint's noise level.
    sigma_pi = np.stack([_prior_scale(p) for p in prior[links]])  # (P, 10)
    noise = np.maximum(residual_before, 1e-6)
    design = np.hstack([own_flat, -y_flat]) / np.repeat(noise[None, :], samples, axis=0).reshape(-1, 1)
    ridge = np.hstack([np.zeros((len(links) * 10, UNKNOWNS * count)), np.diag(1.0 / sigma_pi.reshape(-1))])
    stacked = np.vstack([design, ridge])
    rhs = np.concatenate([target / np.tile(noise, samples), prior[links].reshape(-1) / sigma_pi.reshape(-1)])
    solution, *_ = np.linalg.lstsq(stacked, rhs, rcond=None)
    first = (design @ solution - rhs[: len(design)]).reshape(samples, count) * noise
    noise = np.maximum(np.sqrt(np.mean(np.square(first), axis=0)), 1e-6)
    weights = 1.0 / np.tile(noise, samples)
    own_w, y_w, target_w = own_flat * weights[:, None], y_flat * weights[:, None], target * weights
    # Pass 2: physically consistent links (log-Cholesky), every unknown at once.
    theta0 = np.concatenate([to_cholesky(p) for p in prior[links]])
    x0 = np.concatenate([solution[: UNKNOWNS * count], theta0])

    def parameters(theta: np.ndarray) -> np.ndarray:
        return np.stack([from_cholesky(t) for t in theta.reshape(-1, 10)])

    def residuals(x: np.ndarray) -> np.ndarray:
        pi = parameters(x[UNKNOWNS * count :])
        data = own_w @ x[: UNKNOWNS * count] - y_w @ pi.reshape(-1) - target_w
        return np.concatenate([data, ((pi - prior[links]) / sigma_pi).reshape(-1)])

    def jacobian(x: np.ndarray) -> np.ndarray:
        blocks = [_derivative(t) for t in x[UNKNOWNS * count :].reshape(-1, 10)]
        d_pi = np.zeros((len(links) * 10, len(links) * 10))
        for k, block in enumerate(blocks):
            d_pi[10 * k : 10 * k + 10, 10 * k : 10 * k + 10] = block
        data = np.hstack([own_w, -y_w @ d_pi])
        prior_rows = np.hstack([np.zeros((len(links) * 10, UNKNOWNS * count)), d_pi / sigma_pi.reshape(-1)[:, None]])
        return np.vstack([data, prior_rows])

    found = least_squares(residuals, x0, jac=jacobian, method="trf", x_scale="jac", max_nfev=200)
    pi = parameters(found.x[UNKNOWNS * count :])
    _, after = linear_fit(pi)
    # What the data told: the posterior's standard deviation of each parameter against the prior's.
    information = y_w.T @ y_w - y_w.T @ own_w @ np.linalg.pinv(own_w.T @ own_w) @ own_w.T @ y_w
    whitened = information * np.outer(sigma_pi.reshape(-1), sigma_pi.reshape(-1))
    posterior = np.linalg.inv(whitened + np.eye(len(whitened)))
    told = (np.sqrt(np.clip(np.diag(posterior), 0.0, None)) < TOLD).reshape(-1, 10)
    singular = np.linalg.svd(whitened, compute_uv=False)
    rank = int(np.count_nonzero(singular > 1.0))  # combinations the data know better than the prior
    names = [model.link_names[k] for k in links]
    notes = []
    untold = [name for name, row in zip(names, told, strict=True) if not row.any()]
    if untold:
        notes.append(
            f"the motion does not tell the inertial parameters of {', '.join(untold)}: they stay near the URDF's"
        )
    return Identified(names, pi, told, residual_before, np.sqrt(np.mean(np.square(after), axis=0)), rank, notes)
