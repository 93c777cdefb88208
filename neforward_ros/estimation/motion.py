"""The Kalman estimator's model of one joint's motion, as a linear stochastic system on irregular stamps.

A joint position is modelled as the sum of two independent parts, each a Gaussian process written as
a linear stochastic differential equation (the state-space form of Gaussian-process regression,
Hartikainen and Särkkä 2010), so that filtering and smoothing cost O(1) per sample:

- a trend: constant acceleration driven by white jerk of intensity :data:`TREND_JERK`
  (states c, c', c''), which carries offsets, ramps (a turning wheel) and slow accelerations;
- the motion itself: a stationary Matérn process of smoothness nu = ORDER - 1/2, standard deviation
  ``magnitude`` and length scale ``length_scale``. For large nu it approaches the squared-exponential
  kernel: its spectrum falls off steeply above about 1 / (2 length_scale) Hz, which is what lets a
  causal estimate of the second derivative stay accurate where a polynomial model (constant jerk)
  cannot. Its state is g, g' / lam, ..., g^(ORDER-1) / lam^(ORDER-1) with lam = sqrt(2 nu) / length_scale,
  scaled so that every entry has the same order of magnitude.

Positions are measured with white noise of standard deviation ``noise`` and, when the message
carries them, velocities with ``velocity_noise``.

The transition over dt is exact for any dt: the Matérn generator is lam (C - I) with C - I nilpotent
((C - I)^ORDER = 0), so exp(A dt) is a short polynomial, and the process noise integral is a sum of
incomplete gamma functions, evaluated by a series with positive terms only.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from neforward_ros.errors import InputError

ORDER = 12
"""States of the Matérn part (smoothness nu = ORDER - 1/2)."""
TREND_JERK = 1e-2
"""Intensity of the white jerk that drives the trend, rad^2/s^5 (m^2/s^5 for prismatic joints)."""
TREND_PRIOR = (10.0, 10.0, 100.0)
"""Standard deviations of the trend's position, velocity and acceleration before the first sample."""
QUANTUM = 1e-6
"""s: the resolution of the Kalman estimator's clock. The filter steps on every stamp rounded to it
(:func:`interval`), at most half a microsecond off (a two-thousandth of a 1 kHz interval) and never
drifting: the intervals of a jittering stream then share a few hundred transitions instead of one
worked out per sample. Each sample's readings are moved along the joint's motion to the rounded time
(:func:`off_the_clock`, ``KalmanTrack._on_the_clock``): half a microsecond at 10 rad/s is 5e-6 rad,
more than a 20-bit encoder's rounding."""
TICK_NS = round(QUANTUM * 1e9)
"""ns: :data:`QUANTUM`, the least interval between two of the filter's steps."""


def _ticks(stamp: int) -> int:
    """The filter's time for a stamp (ns): the stamp rounded to :data:`QUANTUM`, in its ticks."""
    return (stamp + TICK_NS // 2) // TICK_NS


def interval(later: int, earlier: int) -> float:
    """s between two stamps (ns), each rounded to :data:`QUANTUM`: the filter's intervals."""
    return (_ticks(later) - _ticks(earlier)) * QUANTUM


def off_the_clock(stamp: int) -> float:
    """s: how far a stamp (ns) lies after the filter's time for it, the stamp rounded to
    :data:`QUANTUM` (at most half of it either way)."""
    return (stamp - _ticks(stamp) * TICK_NS) * 1e-9


@dataclass(frozen=True)
class KalmanSettings:
    """The Kalman estimator's noise levels and motion model (see the module docstring).

    Attributes:
        noise: standard deviation of the position measurements, rad (m for prismatic joints):
            encoder noise, or quantisation step / sqrt(12); 0 (the default): read from the samples
            (:mod:`.kalman_bank`).
        velocity_noise: standard deviation of the velocities a message carries, rad/s (m/s); 0 (the
            default): read from them.
        length_scale: s; the motion's spectrum falls off above about 1 / (2 length_scale) Hz: about
            0.65 / (the highest frequency of the joints' motion, Hz); 0 (the default): a bank of
            models, mixed by how well each predicts each joint (:mod:`.kalman_bank`).
        magnitude: typical excursion of the motion around its trend, rad (m).
    """

    noise: float = 0.0
    velocity_noise: float = 0.0
    length_scale: float = 0.0
    magnitude: float = 0.3

    def __post_init__(self) -> None:
        for name in ("noise", "velocity_noise", "length_scale", "magnitude"):
            value = getattr(self, name)
            automatic = name != "magnitude" and value == 0
            if (
                isinstance(value, bool)
                or not isinstance(value, (int, float))
                or not (0.0 < value < math.inf or automatic)
            ):
                alternative = " or 0 (from the data)" if name != "magnitude" else ""
                raise InputError(f"kalman {name} must be a positive number{alternative}, got {value!r}")


class MotionModel:
    """The linear system of :class:`KalmanSettings`: transitions, noise and read-outs.

    State layout: [c, c', c'', g, g'/lam, ..., g^(ORDER-1)/lam^(ORDER-1)]; position = c + g.

    Attributes:
        dim: the state's size.
        position_row, velocity_row: read-out rows (dim,) of the position and the velocity.
        readout: (3, dim): position, velocity and acceleration from a state.
        prior: (dim, dim) covariance of a state before any sample (the Matérn part stationary).
    """

    def __init__(self, settings: KalmanSettings) -> None:
        self.settings = settings
        n = ORDER
        nu = n - 0.5
        lam = math.sqrt(2.0 * nu) / settings.length_scale
        self.lam = lam
        self.dim = 3 + n
        # Generator of the Matern part: lam * (S - e_n b^T) with b_k = binomial(n, k); its
        # characteristic polynomial is (s + lam)^n, so N = A + lam I is nilpotent.
        companion = np.zeros((n, n))
        companion[:-1, 1:] = np.eye(n - 1)
        companion[-1, :] = [-math.comb(n, k) for k in range(n)]
        nilpotent = lam * (companion + np.eye(n))
        powers = [np.eye(n)]
        for _ in range(1, n):
            powers.append(powers[-1] @ nilpotent)
        self._powers = np.stack([p / math.factorial(k) for k, p in enumerate(powers)])  # N^k / k!
        self._powers_flat = np.ascontiguousarray(self._powers.reshape(n, n * n).T)  # (n*n, n)
        # Stationary covariance for unit white-noise intensity, scaled to the magnitude.
        unit = _stationary_covariance(lam * companion)
        intensity = settings.magnitude**2 / unit[0, 0]
        self._stationary = unit * intensity
        # Q(dt) = sum_m M_m int_0^dt tau^m exp(-2 lam tau) dtau, M_m = sum_{j+k=m} N^j/j! Qc (N^k/k!)^T,
        # and int_0^dt tau^m exp(-2 lam tau) dtau = m! / (2 lam)^(m+1) * P(m + 1, 2 lam dt).
        last = self._powers[:, :, -1] * math.sqrt(intensity)  # N^j/j! Qc^(1/2): Qc = intensity e_n e_n^T
        terms = np.zeros((2 * n - 1, n, n))
        for j in range(n):
            for k in range(n):
                terms[j + k] += np.outer(last[j], last[k])
        scale = np.array([math.factorial(m) / (2.0 * lam) ** (m + 1) for m in range(2 * n - 1)])
        self._noise_terms = np.ascontiguousarray((terms * scale[:, None, None]).reshape(2 * n - 1, n * n).T)
        self._exponents = np.arange(n, dtype=float)
        self.position_row = np.zeros(self.dim)
        self.position_row[[0, 3]] = 1.0
        self.velocity_row = np.zeros(self.dim)
        self.velocity_row[[1, 4]] = (1.0, lam)
        self.readout = np.zeros((3, self.dim))
        self.readout[0] = self.position_row
        self.readout[1] = self.velocity_row
        self.readout[2, [2, 5]] = (1.0, lam * lam)
        self.prior = np.zeros((self.dim, self.dim))
        self.prior[:3, :3] = np.diag(np.square(TREND_PRIOR))
        self.prior[3:, 3:] = self._stationary
        self._as_bank = MotionModels([self])  # see transition()

    def transition(self, dt: float) -> tuple[np.ndarray, np.ndarray]:
        """(F, Q) over dt seconds: x(t + dt) = F x(t) + w, w ~ N(0, Q). Kept for the intervals seen
        last (a steady rate has one or two): read-only arrays. Worked out as a bank of one model
        (:class:`MotionModels`), the arithmetic the filter runs."""
        transition, noise, _ = self._as_bank.transition(dt)
        return transition[0], noise[0]


class MotionModels:
    """Models that differ only in their length scale (a bank's), as one batched system: every array
    carries a leading model axis.

    Attributes:
        models: the models.
        dim: the state's size (every model's).
        measured_rows: (models, 2, dim): the position's and the velocity's read-out rows.
        readout: (models, 3, dim): position, velocity and acceleration from a state.
        prior: (models, dim, dim): each model's covariance before any sample.
    """

    def __init__(self, models: list[MotionModel]) -> None:
        self.models = list(models)
        first = self.models[0]
        self.dim = first.dim
        self._lam = np.array([model.lam for model in self.models])
        self._powers_flat = np.stack([model._powers_flat for model in self.models])  # (M, n*n, n)
        self._noise_terms = np.stack([model._noise_terms for model in self.models])  # (M, n*n, 2n - 1)
        self._exponents = first._exponents
        self.measured_rows = np.stack([np.stack([model.position_row, model.velocity_row]) for model in self.models])
        self.readout = np.stack([model.readout for model in self.models])
        self.prior = np.stack([model.prior for model in self.models])
        self._transitions: dict[float, tuple[np.ndarray, np.ndarray]] = {}
        self._addresses: dict[int, tuple[int, int, int]] = {}  # the cached transitions' memory, for C

    def __len__(self) -> int:
        return len(self.models)

    def transition(self, dt: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(F, Q, F transposed) of every model over dt seconds, (models, dim, dim) each (see
        :meth:`MotionModel.transition`), dt rounded to :data:`QUANTUM` (see :func:`interval`); kept for
        the intervals seen last (with stamp jitter, a few hundred): read-only arrays."""
        key = round(dt / QUANTUM)
        cache = self._transitions
        found = cache.get(key)
        if found is None:
            if len(cache) >= 256:
                cache.clear()
                self._addresses.clear()
            transition, noise = self._transition(key * QUANTUM)
            found = cache[key] = (transition, noise, np.ascontiguousarray(transition.transpose(0, 2, 1)))
            for array in found:
                array.flags.writeable = False
        return found

    def transition_addresses(self, dt: float) -> tuple[int, int, int]:
        """The memory addresses of :meth:`transition`'s three arrays (C-contiguous float64), valid while
        they are cached: taken once per interval (a numpy array's address costs microseconds to read)."""
        key = round(dt / QUANTUM)
        found = self._addresses.get(key)
        if found is None:
            arrays = self.transition(dt)
            found = self._addresses[key] = (arrays[0].ctypes.data, arrays[1].ctypes.data, arrays[2].ctypes.data)
        return found

    def _transition(self, dt: float) -> tuple[np.ndarray, np.ndarray]:
        n = ORDER
        count = len(self.models)
        transition = np.zeros((count, self.dim, self.dim))
        noise = np.zeros((count, self.dim, self.dim))
        transition[:, :3, :3], noise[:, :3, :3] = _trend(dt)
        powers = dt**self._exponents * np.exp(-self._lam * dt)[:, None]  # (M, n): dt^k exp(-lam dt)
        transition[:, 3:, 3:] = (self._powers_flat @ powers[:, :, None]).reshape(count, n, n)
        x = 2.0 * self._lam * dt
        gamma = _small_lower_gamma(x) if x.max() <= SMALL else _lower_gamma_regularized(2 * n - 1, x)  # (M, 2n - 1)
        noise[:, 3:, 3:] = (self._noise_terms @ gamma[:, :, None]).reshape(count, n, n)
        return transition, noise


SMALL = 4.0
"""2 lam dt up to which :func:`_small_lower_gamma` serves (a sample interval: 0.24 at 1 kHz for the
shortest length scale)."""
_TERMS = np.arange(1, 2 * ORDER - 1 + 31)  # j = 1 .. 2n - 1 + 30: x^j / j! < 1e-17 past them for x <= 4
_INVERSE_FACTORIALS = np.array([1.0 / math.factorial(int(j)) for j in _TERMS])
_TAILS = (_TERMS[:, None] > np.arange(2 * ORDER - 1)[None, :]).astype(float)  # [j > m]


def _small_lower_gamma(x: np.ndarray) -> np.ndarray:
    """P(m + 1, x) for m = 0 .. 2 ORDER - 2, each x (M,) at most :data:`SMALL`: exp(-x) sum_(j > m)
    x^j / j!, every tail at once as one product (the terms past the last are below rounding)."""
    terms = x[:, None] ** _TERMS * _INVERSE_FACTORIALS  # (M, J)
    return np.exp(-x)[:, None] * (terms @ _TAILS)


def _trend(dt: float) -> tuple[np.ndarray, np.ndarray]:
    """The trend's (F, Q) over dt: constant acceleration driven by white jerk of :data:`TREND_JERK`."""
    dt2 = dt * dt
    transition = np.array([[1.0, dt, 0.5 * dt2], [0.0, 1.0, dt], [0.0, 0.0, 1.0]])
    j = TREND_JERK
    noise = j * np.array([
        [dt2 * dt2 * dt / 20.0, dt2 * dt2 / 8.0, dt2 * dt / 6.0],
        [dt2 * dt2 / 8.0, dt2 * dt / 3.0, dt2 / 2.0],
        [dt2 * dt / 6.0, dt2 / 2.0, dt],
    ])  # fmt: skip
    return transition, noise


_RECIPROCALS = 1.0 / np.arange(1, 4097)


def _lower_gamma_regularized(count: int, x: np.ndarray) -> np.ndarray:
    """P(m + 1, x) for m = 0 .. count - 1 and each x (M,): exp(-x) sum_{j > m} x^j / j!, (M, count),
    summed from the tail up (all terms positive, so accurate for small and large x alike)."""
    largest = float(x.max())
    terms = min(count + int(largest + 10.0 * math.sqrt(largest) + 25.0), len(_RECIPROCALS))
    series = np.cumprod(x[:, None] * _RECIPROCALS[:terms], axis=1)  # x^j / j!, j = 1 .. terms
    tails = np.cumsum(series[:, ::-1], axis=1)[:, ::-1]  # sum_{i >= j} x^i / i!
    return np.exp(-x)[:, None] * tails[:, :count]


def _stationary_covariance(generator: np.ndarray) -> np.ndarray:
    """P with A P + P A^T + e_n e_n^T = 0 (unit white noise into the last state), by vectorisation."""
    n = len(generator)
    identity = np.eye(n)
    system = np.kron(identity, generator) + np.kron(generator, identity)
    source = np.zeros((n, n))
    source[-1, -1] = 1.0
    solution = np.linalg.solve(system, -source.reshape(-1))
    covariance = solution.reshape(n, n)
    return 0.5 * (covariance + covariance.T)
