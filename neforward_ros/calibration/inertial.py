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

from neforward_ros.kinematics.regressor import (
    UPPER,
    link_parameters,
    origin_inertia,
    split_parameters,
    torque_regressor,
)
from neforward_ros.model import RobotModel

MAX_SAMPLES = 3000
"""Stamps the fit takes at most (evenly spread over the recordings)."""
PRIOR = 0.5
"""The prior's standard deviation, relative to each link's magnitudes (mass, m r, m r^2)."""
TOLD = 0.5
"""A parameter is identified where the data bring its standard deviation below this fraction of the prior's."""
VELOCITY_SCALE = 0.01
"""rad/s: the friction's smooth sign, tanh(q̇ / this), where the prior gives none."""
MIN_SAMPLES = 100
"""The fewest samples the identification is made on."""
TRAIN = 0.7
"""The identification is first made on this fraction of the samples (the first) and judged on the rest."""
BETTER = 0.8
"""Identified parameters are kept only where they cut the held-out mean square to this fraction of the URDF's."""
UNITS = 2.0
"""Efforts whose scale (with the URDF's parameters) is beyond this factor of 1 are not torques."""
MAX_EVALUATIONS = 500
"""The fit's budget of evaluations: the data's part converges in far fewer; what is left is the prior
slowly pulling the directions the data do not see back towards the URDF (they change no torque)."""
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
        six = inertia[(slice(None), *UPPER)]

        def rounded(values: np.ndarray) -> list[float]:
            return [float(f"{v:.6g}") for v in np.ravel(values)]

        return {
            "inertial.link_names": list(self.links),
            "inertial.mass": rounded(mass),
            "inertial.com": rounded(com),
            "inertial.inertia": rounded(six),
        }


def _pseudo_inertia(p: np.ndarray) -> np.ndarray:
    """A link's parameters -> its 4x4 pseudo-inertia [[Sigma, h], [h^T, m]], Sigma = tr(I_o)/2 1 - I_o."""
    inertia_o = origin_inertia(p)
    sigma = 0.5 * np.trace(inertia_o) * np.eye(3) - inertia_o
    out = np.zeros((4, 4))
    out[:3, :3], out[:3, 3], out[3, :3], out[3, 3] = sigma, p[1:4], p[1:4], p[0]
    return out


def _from_pseudo(j: np.ndarray) -> np.ndarray:
    """(..., 4, 4) pseudo-inertias -> (..., 10) parameters."""
    sigma = j[..., :3, :3]
    inertia_o = np.trace(sigma, axis1=-2, axis2=-1)[..., None, None] * np.eye(3) - sigma
    out = np.empty((*j.shape[:-2], 10))
    out[..., 0] = j[..., 3, 3]
    out[..., 1:4] = j[..., :3, 3]
    out[..., 4:] = inertia_o[(..., *UPPER)]
    return out


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
    """The ten log-Cholesky numbers -> a link's parameters (physically consistent); (..., 10) -> (..., 10)."""
    theta = np.asarray(theta, dtype=float)
    alpha, d1, d2, d3, s12, s23, s13, t1, t2, t3 = np.moveaxis(theta, -1, 0)
    scale = np.exp(alpha)
    u = np.zeros((*theta.shape[:-1], 4, 4))
    u[..., 0, 0], u[..., 0, 1], u[..., 0, 2], u[..., 0, 3] = np.exp(d1), s12, s13, t1
    u[..., 1, 1], u[..., 1, 2], u[..., 1, 3] = np.exp(d2), s23, t2
    u[..., 2, 2], u[..., 2, 3] = np.exp(d3), t3
    u[..., 3, 3] = 1.0
    u *= scale[..., None, None]
    return _from_pseudo(u @ np.swapaxes(u, -1, -2))


def _derivatives(theta: np.ndarray) -> np.ndarray:
    """(P, 10) -> (P, 10, 10): d parameters / d theta of each link, by central differences."""
    step = 1e-6 * np.eye(10)
    ahead = from_cholesky(theta[:, None, :] + step)  # (P, 10 perturbed, 10 parameters)
    behind = from_cholesky(theta[:, None, :] - step)
    return np.swapaxes(ahead - behind, 1, 2) / 2e-6


def _consistent(p: np.ndarray) -> bool:
    """Whether a link's parameters are those of a body with a mass and a positive-definite inertia."""
    if not p[0] > 0.0:
        return False
    values = np.linalg.eigvalsh(_pseudo_inertia(p))
    return bool(values.min() > 1e-6 * values.max())


def _prior_scale(p: np.ndarray) -> np.ndarray:
    """Per parameter, the prior's standard deviation: half the link's mass, mass x length, mass x length^2."""
    m = max(float(p[0]), 1e-3)
    inertia_o = origin_inertia(p)
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
    scale_given: np.ndarray | None = None,
) -> Identified:
    """The inertial parameters (see the module docstring) from samples of free motion.

    Args:
        model: the model whose parameters are the prior (the URDF's, a payload's included).
        q, qd, qdd, efforts: (T, n) at the samples (evenly thinned to :data:`MAX_SAMPLES` here).
        measured: (n,) bool, the joints whose efforts are measured (others: no rows).
        gravity: in the root frame, m/s^2.
        effort_scale: (n,) torque (N m; N) per effort unit, per joint: the units of the parameters.
        velocity_scale: (n,) the friction's smooth-sign scale per joint.
        scale_given: (n,) bool, whether each joint's scale was given; where none was, the efforts
            must look like torques (a scale fitted with the URDF's parameters within
            :data:`UNITS` of 1): else nothing is identified, and the notes say what to give.
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
    if not len(links) or not len(rows) or len(q) < MIN_SAMPLES:
        why = "no moving link has a mass and an inertia in the URDF" if not len(links) else "too few samples"
        nothing = np.zeros((0, 10))
        count = len(rows)
        return Identified([], nothing, nothing.astype(bool), np.full(count, np.nan), np.full(count, np.nan), 0,
                          [f"inertial parameters not identified: {why}"])  # fmt: skip
    regressor = torque_regressor(model, q, qd, qdd, gravity)[:, rows]  # (T, r, L, 10)
    fixed = np.einsum("trlk,lk->tr", regressor[:, :, ~moving], prior[~moving])
    y_links = regressor[:, :, links]  # (T, r, P, 10)
    e = efforts[:, rows]
    v = qd[:, rows]
    sign = np.tanh(v / scale_v[rows])
    samples, count = e.shape
    # the joints' own unknowns, per row: offset, coulomb, viscous -> (T, r, r, 3); the efforts in
    # torque units by the given scales (the unit every term shares: see the module docstring)
    given = np.zeros(n, dtype=bool) if scale_given is None else np.asarray(scale_given, dtype=bool)
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

    # The efforts' units: with the URDF's parameters, each joint's scale (torque per effort unit).
    urdf_torque = (np.einsum("trlk,lk->tr", regressor, prior)).reshape(samples, count)
    foreign = []
    for k, j in enumerate(rows):
        if given[j]:
            continue
        # the effort as the URDF's torque over a gain, plus offset and friction: where the torque explains
        # most of the effort's spread, the gain tells the effort's unit
        basis = np.column_stack([urdf_torque[:, k], np.ones(samples), sign[:, k], v[:, k]])
        coefficients, *_ = np.linalg.lstsq(basis, e[:, k], rcond=None)
        explained = float(np.std(basis[:, 0] * coefficients[0])) / max(float(np.std(e[:, k])), 1e-12)
        gain = 1.0 / coefficients[0] if coefficients[0] != 0 else np.inf
        if explained > 0.5 and not 1 / UNITS <= gain <= UNITS:
            foreign.append((j, float(gain)))
    if foreign:
        names = [model.joint_names[j] for j in rows if not given[j]]
        note = (
            "inertial parameters not identified: the efforts of "
            + ", ".join(f"{model.joint_names[j]} (about {gain:.3g} N m per unit)" for j, gain in foreign)
            + " are not torques, and the effort scales set the parameters' units: give them ("
            + " ".join(f"--effort-scale {name}=GAIN" for name in names)
            + ", a datasheet's drive gains; or effort.scale in --params) and calibrate again"
        )
        nothing = np.zeros((0, 10))
        return Identified([], nothing, nothing.astype(bool), np.full(count, np.nan), np.full(count, np.nan), 0, [note])
    sigma_pi = np.stack([_prior_scale(p) for p in prior[links]])  # (P, 10)

    def fit(use: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(link parameters, each joint's noise, the weighted own and link columns) on samples ``use``."""
        chosen = np.repeat(use, count)
        own_u, y_u, target_u = own_flat[chosen], y_flat[chosen], target[chosen]
        used = int(np.count_nonzero(use))
        x_urdf, *_ = np.linalg.lstsq(own_u, target_u + y_u @ prior[links].reshape(-1), rcond=None)
        before_u = (own_u @ x_urdf - target_u - y_u @ prior[links].reshape(-1)).reshape(used, count)
        # Pass 1, linear (pi unconstrained, the prior as ridge) for each joint's noise level.
        noise = np.maximum(np.sqrt(np.mean(np.square(before_u), axis=0)), 1e-6)
        design = np.hstack([own_u, -y_u]) / np.tile(noise, used)[:, None]
        ridge = np.hstack([np.zeros((len(links) * 10, UNKNOWNS * count)), np.diag(1.0 / sigma_pi.reshape(-1))])
        rhs = np.concatenate([target_u / np.tile(noise, used), prior[links].reshape(-1) / sigma_pi.reshape(-1)])
        solution, *_ = np.linalg.lstsq(np.vstack([design, ridge]), rhs, rcond=None)
        first = (design @ solution - rhs[: len(design)]).reshape(used, count) * noise
        noise = np.maximum(np.sqrt(np.mean(np.square(first), axis=0)), 1e-6)
        weights = 1.0 / np.tile(noise, used)
        own_w, y_w, target_w = own_u * weights[:, None], y_u * weights[:, None], target_u * weights
        # The data rows are linear in (joint unknowns, link parameters): their sum of squares is that of
        # R z - Q^T t with [own, -y] = Q R, a few hundred rows in place of tens of thousands.
        basis, upper = np.linalg.qr(np.hstack([own_w, -y_w]))
        projected = basis.T @ target_w
        own_r, y_r = upper[:, : UNKNOWNS * count], -upper[:, UNKNOWNS * count :]
        # Pass 2: physically consistent links (log-Cholesky), every unknown at once.
        x0 = np.concatenate([solution[: UNKNOWNS * count], np.concatenate([to_cholesky(p) for p in prior[links]])])

        def residuals(x: np.ndarray) -> np.ndarray:
            with np.errstate(over="ignore", invalid="ignore"):  # a trial step far out: rejected below
                pi = from_cholesky(x[UNKNOWNS * count :].reshape(-1, 10))
                data = own_r @ x[: UNKNOWNS * count] - y_r @ pi.reshape(-1) - projected
                out = np.concatenate([data, ((pi - prior[links]) / sigma_pi).reshape(-1)])
            return out if np.all(np.isfinite(out)) else np.full(len(out), 1e8)

        def jacobian(x: np.ndarray) -> np.ndarray:
            with np.errstate(over="ignore", invalid="ignore"):
                blocks = np.nan_to_num(_derivatives(x[UNKNOWNS * count :].reshape(-1, 10)), posinf=0.0, neginf=0.0)
            d_pi = np.zeros((len(links) * 10, len(links) * 10))
            for k, block in enumerate(blocks):
                d_pi[10 * k : 10 * k + 10, 10 * k : 10 * k + 10] = block
            data = np.hstack([own_r, -y_r @ d_pi])
            prior_rows = np.hstack(
                [np.zeros((len(links) * 10, UNKNOWNS * count)), d_pi / sigma_pi.reshape(-1)[:, None]]
            )
            return np.vstack([data, prior_rows])

        found = least_squares(residuals, x0, jac=jacobian, method="lm", x_scale="jac", max_nfev=MAX_EVALUATIONS)
        return from_cholesky(found.x[UNKNOWNS * count :].reshape(-1, 10)), noise, own_w, y_w

    # Held out: fitted on the first part of the samples, the identified parameters must predict the
    # rest better than the URDF's (each with its own offsets and friction from the first part), or the
    # URDF's are kept: a model the data cannot improve is not changed by their noise.
    train = np.arange(samples) < int(TRAIN * samples)
    pi_train, noise, _, _ = fit(train)

    def held_out(pi: np.ndarray) -> float:
        chosen = np.repeat(train, count)
        rhs = target + y_flat @ pi.reshape(-1)
        x, *_ = np.linalg.lstsq(own_flat[chosen], rhs[chosen], rcond=None)
        rest = (own_flat[~chosen] @ x - rhs[~chosen]).reshape(-1, count) / noise
        return float(np.mean(np.square(rest)))

    urdf_score, identified_score = held_out(prior[links]), held_out(pi_train)
    _, before = linear_fit(prior[links])
    residual_before = np.sqrt(np.mean(np.square(before), axis=0))
    if not identified_score <= BETTER * urdf_score:
        note = (
            f"inertial parameters kept as the URDF's: identified on the first {TRAIN:.0%} of the samples, they "
            f"predict the rest no better ({identified_score:.3g} against {urdf_score:.3g}, the noise-weighted mean "
            "square of the torque equation's residual)"
        )
        nothing = np.zeros((0, 10))
        return Identified([], nothing, nothing.astype(bool), residual_before, residual_before, 0, [note])
    pi, noise, own_w, y_w = fit(np.ones(samples, dtype=bool))
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
