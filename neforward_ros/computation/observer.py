"""External torques at the newest sample: a generalized-momentum observer (De Luca and Mattone 2005;
Haddadin, De Luca and Albu-Schaeffer, IEEE T-RO 2017).

The generalized momentum p = (M(q) + diag(armature)) qd changes at the rate

    dp/dt = tau_m - tau_f - g(q) + C(q, qd)^T qd - tau_x

with tau_m the motors' torques (``effort.*``), tau_f friction (``friction.*``), armature the rotors'
inertias (``effort.armature``; constant, so they add nothing to C) and tau_x the external
torque in this project's sign: measured - model, positive where the motors give more than the motion
needs (Jᵀw, w the wrench the robot exerts on what it touches). So tau_x needs q, qd and efforts, and
no joint acceleration: the observer follows it through a first-order filter of gain K per joint,

    r(t_k) = a r(t_{k-1}) + (1 - a) [ mean(tau_m - tau_f - g + C^T qd) - (p(t_k) - p(t_{k-1})) / dt ],
    a = exp(-K dt),

the mean over the step by the trapezoid rule. That is the continuous observer dr/dt = K (tau_x - r),
exact for a tau_x constant over each step, whatever the stamps' spacing: a step of tau_x shows
in r as 1 - exp(-K t).

Noise in the velocities would enter r about K |M| times over through the momentum's rate. The
momentum (and C^T qd) is therefore taken at the velocities low-passed at ``velocity_cutoff``
(first order); the torques are not filtered, so a push shows as fast as K lets it. What the filter
costs is the momentum's rate lagging by about 1 / (2 pi cutoff): an error of about
d^2p/dt^2 / (2 pi cutoff), small for smooth motion (``neforward calibrate`` picks the cutoff that
leaves the least external torque in a free motion).

**Two speeds** (``external_torques.slow_gain``, which ``neforward calibrate`` sets): a gain high
enough to show a push within milliseconds lets the velocities' noise through K |M| times over (a
real arm's, above 20 Hz, more than its model error: the Franka Panda's). A second observer with a
lower gain K_s runs on the same inputs, and each joint's output is the slow one's, r_s, while the two
agree within a dead zone z, and the fast one's, r, where they do not:

    output = r_s where |r - r_s| <= z, else r

In free motion the two differ by noise, under z (the calibration's 3 x the 99th percentile of their
difference), and the output is the slow one's, with its quiet. At a push's start or end the fast one
runs ahead of the slow one by more than z within a few of its time constants, and the output is the
fast one's. Contact is still decided on the fast observer's own estimate, whose speed it needs and
whose noise its thresholds absorb (:mod:`.contact`; ``neforward calibrate`` measures them on it):
where the dead zone is most of a threshold, a push's end might not take the two apart by more than
the dead zone, and the slow one's output would end the contact a time constant late.

It runs on the raw samples as they come (:class:`RawStates`, assembled by
:mod:`.raw_samples`), not on the estimator's lagged stamps: ~/external_torques and ~/contact leave
with the newest sample. It restarts (r = 0) at the start of a stream, after a gap longer than max_gap
and where time goes back, and gives nothing for :data:`WARM_UP` time constants of the velocity
filter after that: the filter starts from the first velocity, not from its lag behind a moving joint,
and the momentum's rate is wrong until that start is forgotten. The node steps it one sample at a time and the
bag tool a chunk at a time, through :func:`observe`, with the same numbers.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from neforward_ros.kinematics.effort_model import EffortModel
from neforward_ros.kinematics.joint_space import momentum_values
from neforward_ros.model import RobotModel
from neforward_ros.stamps import NS

WARM_UP = 3.0
"""Time constants of the velocity filter (1 / (2 pi cutoff)) after a restart with no output."""


@dataclass(frozen=True)
class RawStates:
    """Measured joint states, as the messages gave them, at one stamp ((n,) arrays) or T ((T, n)).

    Attributes:
        stamps: int ns, or (T,) int64, increasing.
        q, qd: rad (m), rad/s (m/s); every joint's (its newest sample at or before the stamp).
        efforts: as the messages gave them (before ``effort.*``); NaN where a joint has none.
        restart: whether the observer restarts at the stamp (a new stream or segment, a gap).
    """

    stamps: Any
    q: np.ndarray
    qd: np.ndarray
    efforts: np.ndarray
    restart: Any

    @property
    def single(self) -> bool:
        return self.q.ndim == 1

    def __len__(self) -> int:
        return 1 if self.single else len(self.stamps)

    def part(self, index: Any) -> RawStates:
        return RawStates(*(getattr(self, name)[index] for name in ("stamps", "q", "qd", "efforts", "restart")))

    @classmethod
    def stack(cls, parts: list[RawStates]) -> RawStates:
        def rows(name: str) -> np.ndarray:
            return np.stack([getattr(p, name) for p in parts])

        return cls(
            np.array([p.stamps for p in parts], dtype=np.int64),
            rows("q"),
            rows("qd"),
            rows("efforts"),
            np.array([bool(p.restart) for p in parts]),
        )


class ObserverState:
    """What the observer carries from one sample to the next, for one model and one stream.

    Args:
        gains: (n,) K per joint, 1/s.
        gravity: m/s^2 in the root frame (the root at rest).
        velocity_cutoff: Hz, the velocities' low-pass for the momentum; 0 for none.
        slow_gain: 1/s, the slow observer's gain (0: none; see the module docstring).
        dead_zones: (n,) z per joint, N m (N), with a slow observer; None: zeros.
    """

    def __init__(
        self,
        gains: np.ndarray,
        gravity: tuple[float, float, float],
        velocity_cutoff: float = 0.0,
        slow_gain: float = 0.0,
        dead_zones: np.ndarray | None = None,
    ) -> None:
        self.gains = np.asarray(gains, dtype=float)
        self.slow_gain = float(slow_gain)
        self.dead_zones = np.zeros(len(self.gains)) if dead_zones is None else np.asarray(dead_zones, dtype=float)
        self.gravity_force = -np.asarray(gravity, dtype=float)
        self.cutoff = 2.0 * math.pi * velocity_cutoff  # rad/s; 0: no filter
        self.velocity: np.ndarray | None = None  # the filtered velocities at the previous sample
        self.warm_ns = round(WARM_UP / self.cutoff * NS) if self.cutoff else 0
        self.quiet_until = 0  # no output before this stamp (after a restart)
        self.stamp: int | None = None
        self.momentum: np.ndarray | None = None
        self.rate: np.ndarray | None = None  # tau_m - tau_f - g + C^T qd at the previous sample
        self.external = np.zeros(len(self.gains))
        self.slow = np.zeros(len(self.gains))  # the slow observer's estimate

    def restart(self) -> None:
        """Forget the momentum and the estimates (the velocity filter restarts on its own rules)."""
        self.stamp = None
        self.momentum = None
        self.rate = None
        self.external = np.zeros(len(self.gains))
        self.slow = np.zeros(len(self.gains))


def observe(
    model: RobotModel, raw: RawStates, effort: EffortModel, state: ObserverState
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The external torques at the raw samples' stamps: (n,) or (T, n), N m (N); NaN at a restart and
    while the velocity filter warms up after it, and for joints without a measured effort. Also the
    velocities as filtered, and the fast observer's own estimates (the external torques themselves
    without a slow observer), of the same shape."""
    single = raw.single
    q, qd = (np.atleast_2d(x) for x in (raw.q, raw.qd))
    efforts = np.atleast_2d(raw.efforts)
    stamps = [int(raw.stamps)] if single else raw.stamps.tolist()
    restarts = [bool(raw.restart)] if single else raw.restart.tolist()
    filtered = _filtered(qd, stamps, restarts, state)
    values = momentum_values(model, q, filtered, state.gravity_force)
    n = q.shape[1]
    momentum, coriolis, gravity = values[:, :n], values[:, n : 2 * n], values[:, 2 * n :]
    momentum = momentum + effort.rotor_momentum(filtered)
    rate = effort.motor(efforts) - effort.friction(qd) - gravity + coriolis
    out = np.full((len(stamps), n), np.nan)
    fast = out.copy() if state.slow_gain else out
    gains = state.gains
    for k, stamp in enumerate(stamps):
        if restarts[k] or state.stamp is None or stamp <= state.stamp:
            state.restart()
            state.quiet_until = stamp + state.warm_ns
        else:
            dt = (stamp - state.stamp) / NS
            a = np.exp(-gains * dt) if len(gains) > 1 else math.exp(-gains[0] * dt)
            assert state.momentum is not None and state.rate is not None
            step = 0.5 * (rate[k] + state.rate) - (momentum[k] - state.momentum) / dt
            state.external = a * state.external + (1.0 - a) * step
            shown = state.external
            if state.slow_gain:
                b = math.exp(-state.slow_gain * dt)
                state.slow = b * state.slow + (1.0 - b) * step
                shown = np.where(np.abs(state.external - state.slow) > state.dead_zones, state.external, state.slow)
            if stamp >= state.quiet_until:
                out[k] = shown
                fast[k] = state.external
        state.stamp, state.momentum, state.rate = stamp, momentum[k], rate[k]
        if not np.isfinite(state.external).all():  # a joint without an effort: NaN there, the others go on
            state.external = np.where(np.isfinite(state.external), state.external, 0.0)
        if not np.isfinite(state.slow).all():
            state.slow = np.where(np.isfinite(state.slow), state.slow, 0.0)
    return (out[0], filtered[0], fast[0]) if single else (out, filtered, fast)


def _filtered(qd: np.ndarray, stamps: list[int], restarts: list[bool], state: ObserverState) -> np.ndarray:
    """The velocities low-passed (first order, ``state.cutoff``), sample by sample from the state's;
    as they are at a restart or without a cutoff."""
    if not state.cutoff:
        return qd
    out = np.empty_like(qd)
    previous, last = state.velocity, state.stamp
    for k, stamp in enumerate(stamps):
        if restarts[k] or previous is None or last is None or stamp <= last:
            previous = qd[k]
        else:
            a = math.exp(-state.cutoff * (stamp - last) / NS)
            previous = a * previous + (1.0 - a) * qd[k]
        out[k] = previous
        last = stamp
    state.velocity = previous
    return out
