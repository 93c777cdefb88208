"""Each joint's effort scale and offset and its friction, by least squares on free motion.

With no contact, the generalized momentum p = M(q) qd of the arm changes at the rate

    dp/dt = scale * effort + offset - tau_f(qd) - armature * qdd - g(q) + C(q, qd)^T qd

(:mod:`neforward_ros.kinematics.joint_space`; armature * qdd the torque the motor spends on its own
rotor). Averaged over a window [a, b], with no acceleration estimated anywhere (the rotor's term
averages to the change of velocity over the window):

    (p(b) - p(a)) / (b - a) + mean(g - C^T qd) = scale * mean(effort) + offset
                                                 - coulomb * mean(tanh(qd / velocity_scale))
                                                 - viscous * mean(qd) - stribeck * mean(...)
                                                 - armature * (qd(b) - qd(a)) / (b - a)

which is linear in each joint's scale, offset, friction coefficients and armature, given the
velocity scales (chosen from a few candidates, the one with the least residual). Every window gives
one equation per joint, and each joint's coefficients are fitted on its own. A parameter the motion
does not excite is kept at its prior and said: Coulomb friction on a joint that never reversed,
viscous friction on a joint that moved at one speed, the scale where its uncertainty is large. The
armature is fitted last, where the data tell it (:data:`ARMATURE_UNCERTAINTY`); elsewhere it keeps
its prior (0 unless given) silently, as a rotor too light to matter would.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from neforward_ros.kinematics.effort_model import DEFAULT_STRIBECK_VELOCITY, EffortModel, friction_shapes

WINDOW = 0.05
"""s: the windows the momentum equation is averaged over."""
VELOCITY_SCALES = tuple(float(v) for v in np.geomspace(0.001, 0.1, 21))
"""rad/s (m/s): the smooth sign's candidate velocity scales (then refined between neighbours)."""
REVERSALS = 0.05
"""The least fraction of the windows each way (faster than :data:`REVERSAL_SPEED`) for Coulomb friction."""
REVERSAL_SPEED = 0.01
"""rad/s (m/s): a window's mean speed that counts as moving one way."""
SCALE_SIGNAL = 0.1
"""The scale is fitted only where the model torque varies, beyond what friction and a constant
explain, by at least this fraction of the friction torque (RMS): elsewhere the scale trades off
against the friction coefficients, and the fit would pick among them by noise."""
SCALE_FLOOR = 0.1
"""N m (N): nor where the model torque varies by less than this beyond friction and a constant."""
SPEED_RANGE = 0.05
"""rad/s (m/s): the least spread of the windows' mean speeds for viscous friction."""
SCALE_UNCERTAINTY = 0.05
"""The largest relative standard error of a fitted effort scale; above it the scale is kept."""
ARMATURE_UNCERTAINTY = 0.2
"""The largest relative standard error of a fitted armature; above it the armature is kept."""
FRICTION = ("coulomb", "viscous", "stribeck")
"""The coefficients that cannot be negative, besides the armature."""


@dataclass
class _Run:
    """One contiguous run of samples, cut into windows [a, b)."""

    t: np.ndarray  # (T,) s
    a: np.ndarray
    b: np.ndarray
    qd: np.ndarray  # (T, n)

    def mean(self, x: np.ndarray) -> np.ndarray:
        """Each window's mean of x ((T,) or (T, n)), trapezoid rule."""
        dt = np.diff(self.t)
        steps = 0.5 * (x[1:] + x[:-1]) * (dt if x.ndim == 1 else dt[:, None])
        integral = np.concatenate([np.zeros((1, *x.shape[1:])), np.cumsum(steps, axis=0)])
        span = self.t[self.b] - self.t[self.a]
        return (integral[self.b] - integral[self.a]) / (span if x.ndim == 1 else span[:, None])


@dataclass
class Windows:
    """The momentum equation averaged over windows: per window and joint (W, n).

    Attributes:
        target: (p(b) - p(a)) / (b - a) + mean(g - C^T qd).
        effort: mean(effort).
        velocity: mean(qd).
        acceleration: (qd(b) - qd(a)) / (b - a), of the velocities the momentum was taken at.
        instrument: the same, each end's velocity the mean of its neighbours' (:func:`_neighbours`).
    """

    target: np.ndarray
    effort: np.ndarray
    velocity: np.ndarray
    runs: list[_Run]
    stribeck_velocity: float
    acceleration: np.ndarray
    instrument: np.ndarray

    def terms(self, j: int, velocity_scale: float) -> dict[str, tuple[np.ndarray, float]]:
        """Joint j's columns of the equation by coefficient, with their signs (the offset's aside):
        scale * effort - coulomb * sign - viscous * velocity - stribeck * decay - armature * acceleration."""
        sign, decay = self.shapes(j, velocity_scale)
        return {
            "scale": (self.effort[:, j], 1.0),
            "coulomb": (sign, -1.0),
            "viscous": (self.velocity[:, j], -1.0),
            "stribeck": (decay, -1.0),
            "armature": (self.acceleration[:, j], -1.0),
        }

    def shapes(self, j: int, velocity_scale: float) -> tuple[np.ndarray, np.ndarray]:
        """Joint j's window means of tanh(qd / velocity_scale) and of the Stribeck shape times it."""
        signs, decays = [], []
        for run in self.runs:
            sign, decay = friction_shapes(run.qd[:, j], velocity_scale, self.stribeck_velocity)
            signs.append(run.mean(sign))
            decays.append(run.mean(sign * decay))
        return np.concatenate(signs), np.concatenate(decays)


def windows(
    stamps_ns: np.ndarray,
    momentum: np.ndarray,
    rest: np.ndarray,
    efforts: np.ndarray,
    qd: np.ndarray,
    runs: Sequence[tuple[int, int]],
    window: float = WINDOW,
    stribeck_velocity: float = DEFAULT_STRIBECK_VELOCITY,
    momentum_qd: np.ndarray | None = None,
) -> Windows:
    """The windows of contiguous runs of samples ([start, stop) index pairs, no restart inside).

    Args:
        stamps_ns: (T,) int ns.
        momentum: (T, n) p.
        rest: (T, n) g - C^T qd.
        efforts, qd: (T, n) measured efforts and velocities (for friction's shapes).
        momentum_qd: (T, n) the velocities the momentum was taken at (for the rotors' term); None: qd.
    """
    momentum_qd = qd if momentum_qd is None else momentum_qd
    parts: dict[str, list[np.ndarray]] = {
        "target": [], "effort": [], "velocity": [], "acceleration": [], "instrument": []
    }  # fmt: skip
    kept: list[_Run] = []
    for start, stop in runs:
        t = (stamps_ns[start:stop] - stamps_ns[start]) / 1e9
        if len(t) < 3:
            continue
        step = max(1, round(window / float(np.median(np.diff(t)))))
        edges = np.arange(0, len(t), step)
        if len(edges) < 2:
            continue
        run = _Run(t, edges[:-1], edges[1:], qd[start:stop])
        kept.append(run)
        p = momentum[start:stop]
        span = (t[run.b] - t[run.a])[:, None]
        parts["target"].append((p[run.b] - p[run.a]) / span + run.mean(rest[start:stop]))
        parts["effort"].append(run.mean(efforts[start:stop]))
        parts["velocity"].append(run.mean(run.qd))
        v = momentum_qd[start:stop]
        parts["acceleration"].append((v[run.b] - v[run.a]) / span)
        around = _neighbours(v)
        parts["instrument"].append((around[run.b] - around[run.a]) / span)
    if not parts["target"]:
        raise ValueError("no window: the recordings are too short")
    return Windows(
        np.concatenate(parts["target"]),
        np.concatenate(parts["effort"]),
        np.concatenate(parts["velocity"]),
        kept,
        stribeck_velocity,
        np.concatenate(parts["acceleration"]),
        np.concatenate(parts["instrument"]),
    )


def _neighbours(v: np.ndarray) -> np.ndarray:
    """Each sample's velocities as the mean of its two neighbours on each side (one side at a run's
    ends), without the sample itself: free of its own noise, which the momentum at that sample carries."""
    padded = np.concatenate([np.full((2, v.shape[1]), np.nan), v, np.full((2, v.shape[1]), np.nan)])
    around = np.stack([padded[k : k + len(v)] for k in (0, 1, 3, 4)])
    known = np.isfinite(around)
    return np.where(known, around, 0.0).sum(axis=0) / np.maximum(known.sum(axis=0), 1)


@dataclass
class JointFit:
    """One joint's fitted parameters, how well they fit, and what could not be fitted."""

    scale: float = 1.0
    offset: float = 0.0
    coulomb: float = 0.0
    viscous: float = 0.0
    velocity_scale: float = 0.01
    stribeck: float = 0.0
    armature: float = 0.0
    residual_before: float = float("nan")
    residual_after: float = float("nan")
    notes: list[str] = field(default_factory=list)
    # which of scale, coulomb, viscous, stribeck, armature were fitted (the offset always is)
    fitted: tuple[str, ...] = ()


def fit_joints(
    data: Windows,
    names: Sequence[str],
    prior: EffortModel,
    stribeck: bool = False,
    scale: bool = True,
    held: Sequence[int] = (),
    kept_scales: Sequence[int] = (),
) -> list[JointFit]:
    """Each joint's parameters (see the module docstring); ``prior``: the values kept where the motion
    does not tell (and the residual before); ``scale`` False keeps every scale at the prior's, and
    ``kept_scales`` those of these joints; ``held``: joints never in the recordings (no effort
    measured), which keep the prior's values."""
    fits = []
    for j, name in enumerate(names):
        if j in held:
            kept = JointFit(
                scale=float(prior.scale[j]),
                offset=float(prior.offset[j]),
                coulomb=float(prior.coulomb[j]),
                viscous=float(prior.viscous[j]),
                velocity_scale=float(prior.velocity_scale[j]),
                stribeck=float(prior.stribeck[j]),
                armature=float(prior.armature[j]),
            )
            kept.notes.append(f"joint {name} is in none of the recordings (held at rest): nothing of it was fitted")
            fits.append(kept)
            continue
        fits.append(_fit_joint(data, j, name, prior, stribeck, scale and j not in kept_scales))
    return fits


def _fit_joint(data: Windows, j: int, name: str, prior: EffortModel, stribeck: bool, scale: bool) -> JointFit:
    y = data.target[:, j]
    velocity = data.velocity[:, j]
    fit = JointFit()
    before = prior.offset[j] + sum(
        sign_of * float(getattr(prior, key)[j]) * column
        for key, (column, sign_of) in data.terms(j, float(prior.velocity_scale[j])).items()
    )
    fit.residual_before = float(np.sqrt(np.mean(np.square(y - before))))
    free = {"scale": scale, "coulomb": True, "viscous": True, "stribeck": stribeck, "armature": False}
    # the windows' means, not the noisy samples, tell whether a joint moved
    threshold = REVERSAL_SPEED
    forwards, backwards = float(np.mean(velocity > threshold)), float(np.mean(velocity < -threshold))
    if min(forwards, backwards) < REVERSALS:
        free["coulomb"] = free["stribeck"] = False
        fit.notes.append(
            f"joint {name} hardly reversed ({forwards:.0%} of the samples one way, {backwards:.0%} the other): its "
            "Coulomb friction cannot be told from its offset; kept at "
            f"{prior.coulomb[j]:g} (move it both ways for longer)"
        )
    if float(np.std(velocity)) < SPEED_RANGE:
        free["viscous"] = False
        fit.notes.append(
            f"joint {name} moved within too narrow a range of speeds (spread {float(np.std(velocity)):.3g}): its "
            f"viscous friction is kept at {prior.viscous[j]:g} (move it at several speeds)"
        )

    instruments = {"armature": data.instrument[:, j]}

    def attempt(velocity_scale: float, free=free, prior=prior) -> tuple[float, dict[str, float]] | None:
        return _solve(y, data.terms(j, velocity_scale), free, prior, j, instruments)

    def best_fit() -> tuple[float, float, dict[str, float]] | None:
        found = _best_scale(attempt) if free["coulomb"] else None
        if found is None:
            solved = attempt(float(prior.velocity_scale[j]))
            found = None if solved is None else (solved[0], float(prior.velocity_scale[j]), solved[1])
        return found

    if free["scale"]:
        # Whether the scale can be told from friction: judged with the scale at its prior, since a free
        # scale could take the friction over where it cannot.
        free["scale"] = False
        held = best_fit()
        free["scale"] = True
        if held is not None:
            _, velocity_scale, values = held
            sign, _ = data.shapes(j, velocity_scale)
            basis = np.stack([np.ones_like(y), sign, velocity], axis=1)
            unexplained = y - basis @ np.linalg.lstsq(basis, y, rcond=None)[0]
            friction = values["coulomb"] * sign + values["viscous"] * velocity
            signal, friction_rms = float(np.sqrt(np.mean(unexplained**2))), float(np.sqrt(np.mean(friction**2)))
            if signal < max(SCALE_SIGNAL * friction_rms, SCALE_FLOOR):
                free["scale"] = False
                fit.notes.append(
                    f"joint {name}: its effort scale cannot be told from its friction and offset (its model torque "
                    f"varied by {signal:.3g} beyond what they explain, against {friction_rms:.3g} of friction): kept "
                    f"at {prior.scale[j]:g}"
                )
    best = best_fit()
    if best is None:
        fit.notes.append(f"joint {name}: nothing could be fitted; the prior is kept")
        fit.scale, fit.offset = float(prior.scale[j]), float(prior.offset[j])
        fit.coulomb, fit.viscous = float(prior.coulomb[j]), float(prior.viscous[j])
        fit.armature = float(prior.armature[j])
        fit.residual_after = fit.residual_before
        return fit
    residual, velocity_scale, values = best
    if free["scale"] and values.get("scale_error", 0.0) > SCALE_UNCERTAINTY * abs(values["scale"]):
        free["scale"] = False
        fit.notes.append(
            f"joint {name}: its effort scale is uncertain by {values['scale_error'] / abs(values['scale']):.1%} "
            f"(its torque varied too little against its noise and friction): kept at {prior.scale[j]:g}"
        )
        solved = attempt(velocity_scale)
        assert solved is not None
        residual, values = solved
    # The armature last: with the scale as free as it was, else at the value just found (a joint whose
    # torque is mostly its own inertia cannot tell the two apart: the scale found without a rotor stands).
    trials = [(dict(free, armature=True), prior)]
    if free["scale"]:
        trials.append((dict(free, armature=True, scale=False), _with(prior, "scale", j, values["scale"])))
    for trial_free, trial_prior in trials:
        solved = attempt(velocity_scale, trial_free, trial_prior)
        if solved is None or "armature_error" not in solved[1]:
            continue
        found = solved[1]
        told = found["armature_error"] <= ARMATURE_UNCERTAINTY * found["armature"]
        if trial_free["scale"]:
            told = told and found["scale_error"] <= SCALE_UNCERTAINTY * abs(found["scale"])
        if told:
            residual, values, free = solved[0], found, trial_free
            break
    fit.fitted = tuple(k for k in ("scale", "coulomb", "viscous", "stribeck", "armature") if free[k])
    fit.scale, fit.offset = values["scale"], values["offset"]
    fit.coulomb, fit.viscous, fit.stribeck = values["coulomb"], values["viscous"], values["stribeck"]
    fit.armature = values["armature"]
    fit.velocity_scale = velocity_scale
    fit.residual_after = residual
    return fit


def _best_scale(attempt) -> tuple[float, float, dict[str, float]] | None:
    """The velocity scale with the least residual: the best of the candidates, then golden-section
    search between its neighbours (on the logarithm of the scale)."""
    tried = [(scale, attempt(scale)) for scale in VELOCITY_SCALES]
    scored = [(solved[0], scale, solved[1]) for scale, solved in tried if solved is not None]
    if not scored:
        return None
    best = min(scored)
    k = VELOCITY_SCALES.index(best[1])
    low = np.log(VELOCITY_SCALES[max(k - 1, 0)])
    high = np.log(VELOCITY_SCALES[min(k + 1, len(VELOCITY_SCALES) - 1)])
    ratio = (np.sqrt(5.0) - 1.0) / 2.0
    for _ in range(12):
        x1, x2 = high - ratio * (high - low), low + ratio * (high - low)
        f1, f2 = attempt(float(np.exp(x1))), attempt(float(np.exp(x2)))
        r1 = f1[0] if f1 is not None else np.inf
        r2 = f2[0] if f2 is not None else np.inf
        if r1 < r2:
            high = x2
        else:
            low = x1
    middle = float(np.exp(0.5 * (low + high)))
    refined = attempt(middle)
    if refined is not None and refined[0] < best[0]:
        return refined[0], middle, refined[1]
    return best


def _solve(
    y: np.ndarray,
    terms: dict[str, tuple[np.ndarray, float]],
    free: dict[str, bool],
    prior: EffortModel,
    j: int,
    instruments: dict[str, np.ndarray] | None = None,
) -> tuple[float, dict[str, float]] | None:
    """Least squares of one joint with the free coefficients (``terms``: :meth:`Windows.terms`); the
    fixed ones at the prior. Friction coefficients or an armature that come out negative are fixed at
    0 and the rest fitted again. The values, and each free coefficient's standard error as
    ``<name>_error``.

    ``instruments``: a column whose noise is in the target too (the velocities' change, which the
    momentum's change carries M times over) is fitted by instrumental variables, with this stand-in
    free of that noise: plain least squares would pull its coefficient towards -M."""
    instruments = instruments or {}
    free = dict(free)
    for _ in range(len(terms) + 1):
        columns = {"offset": np.ones_like(y)}
        fixed = np.zeros_like(y)
        for key, (column, sign_of) in terms.items():
            if free[key]:
                columns[key] = sign_of * column
            else:
                fixed += sign_of * float(getattr(prior, key)[j]) * column
        names = list(columns)
        matrix = np.stack([columns[k] for k in names], axis=1)
        target = y - fixed
        stand_in = np.stack([terms[k][1] * instruments[k] if k in instruments else columns[k] for k in names], axis=1)
        normal = stand_in.T @ matrix
        if any(k in instruments for k in names):
            solution, *_ = np.linalg.lstsq(normal, stand_in.T @ target, rcond=None)
        else:  # plain least squares, on the columns themselves (not their squared condition number)
            solution, *_ = np.linalg.lstsq(matrix, target, rcond=None)
        values = dict(zip(names, solution.tolist(), strict=True))
        negative = [k for k in (*FRICTION, "armature") if k in values and values[k] < 0]
        if negative:
            for k in negative:
                free[k] = False
                prior = _with(prior, k, j, 0.0)
            continue
        if "scale" in values and not values["scale"] > 0:
            free["scale"] = False
            continue
        residual_vector = target - matrix @ solution
        residual = float(np.sqrt(np.mean(np.square(residual_vector))))
        out = {key: float(values.get(key, getattr(prior, key)[j])) for key in terms}
        out["offset"] = float(values["offset"])
        dof = max(len(y) - len(names), 1)
        variance = float(residual_vector @ residual_vector) / dof
        try:
            inverse = np.linalg.inv(normal)
            covariance = variance * inverse @ (stand_in.T @ stand_in) @ inverse.T
            errors = np.sqrt(np.clip(np.diag(covariance), 0.0, None))
        except np.linalg.LinAlgError:
            errors = np.full(len(names), np.inf)
        for key in ("scale", "armature"):
            if key in values:
                out[f"{key}_error"] = float(errors[names.index(key)])
        return residual, out
    return None


def _with(prior: EffortModel, key: str, j: int, value: float) -> EffortModel:
    from dataclasses import replace

    array = getattr(prior, key).copy()
    array[j] = value
    return replace(prior, **{key: array})
