"""Kalman filtering and fixed-lag smoothing of one group of joints sampled at the same stamps, for
several motion models at once.

Every joint of a group follows the same :class:`~neforward_ros.estimation.motion.MotionModel` and is
measured at the same stamps with the same noise, so the filter's covariance and gains are the same
for all of them: one covariance per group and model, one state column per joint. The models of a
bank (:mod:`.kalman_bank`) differ only in their length scale and run side by side as one batched
filter: every array carries a leading model axis, and a step costs a few batched products of small
matrices whatever the number of joints and models.

The causal estimate at a sample is the filtered state. The fixed-lag estimate at a sample ``lag``
old is the Rauch-Tung-Striebel smoothed state: going back one step is x_k = o_k + G_k x_(k+1), with
the smoother gain G_k and offset o_k (the filtered state less G_k times the next step's prediction)
known once the next sample is in. Unrolled from the newest sample N, the read-out (position,
velocity, acceleration) of x_k is R x_k = c_k + P_k xf_N, with c_k and P_k = R G_k ... G_(N-1) kept
for every step: when a sample N + 1 arrives, every c_k gains P_k o_N and every P_k becomes P_k G_N,
two batched products for all the steps kept (at most :data:`UNROLLED`: older steps, which only a
caller that never forgets keeps, go back step by step), and an estimate at a step is one product
more. An estimate between steps (a stamp whose sample was not filtered) goes back step by step and
carries the state forward to it.

The smoothed covariance goes back the same way: S_k = E_k + G_k S_(k+1) G_k^T, with E_k = P_k -
G_k Pp_(k+1) G_k^T (P_k filtered, Pp_(k+1) predicted; the Rauch-Tung-Striebel recursion) and S_N
= P_N. Unrolled, the read-out's variance at step k is d_k + P_k P_N P_k^T: when a sample N + 1
arrives, every d_k gains P_k E_N P_k^T (the acceleration's row only: one batched product more). The
variance stated with a fixed-lag estimate is the smoothed one at its step (several times smaller
than the newest sample's filtered variance at a 20 ms lag); between two steps it is interpolated
linearly in time between theirs.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np

from neforward_ros.estimation.motion import MotionModel, MotionModels, interval

_LOG_2PI = float(np.log(2.0 * np.pi))
try:  # numpy's batched inversion itself: np.linalg.inv adds 14 us of checks to its 22 us for 4 x 15 x 15
    # (a singular matrix gives NaN, with a RuntimeWarning, instead of an error: a predicted covariance
    # holds the process noise and is not singular)
    from numpy.linalg import _umath_linalg

    def _inverse(matrices: np.ndarray) -> np.ndarray:
        return _umath_linalg.inv(matrices, signature="d->d")

    _inverse(np.eye(2)[None])
except (ImportError, AttributeError, TypeError):  # pragma: no cover - a numpy without it
    _inverse = np.linalg.inv
UNROLLED = 1024
"""The most steps whose smoothed read-out is kept unrolled (a 20 ms lag at 1 kHz needs 21)."""


@dataclass
class _Step:
    """One sample's filter output, per model: the state after the measurement (models, dim, m), the
    prediction before it, the covariance after the measurement (models, dim, dim), and the smoother
    gain, offset and E_k (the module docstring's) towards the next step (set when the next sample
    arrives)."""

    stamp: int
    filtered: np.ndarray
    predicted: np.ndarray
    covariance: np.ndarray
    gain: np.ndarray | None = None
    offset: np.ndarray | None = None
    settled: np.ndarray | None = None


class KalmanTrack:
    """The filters of one group: joints measured together, one state column each, one filter per model.

    Args:
        models: the motion models (one or a bank's).
        smooth: whether fixed-lag estimates are asked for (then smoother gains are computed).
    """

    def __init__(self, models: list[MotionModel] | MotionModels, smooth: bool) -> None:
        self.models = models if isinstance(models, MotionModels) else MotionModels(models)
        self.smooth = smooth
        self.steps: deque[_Step] = deque()
        self._unrolled: _Unrolled | None = None  # c_k and P_k of the module docstring, per step kept
        first = self.models.models[0].settings
        self._noise = first.noise**2
        self._velocity_noise = first.velocity_noise**2
        self.nis = np.ones((len(self.models), 0))
        """Each model's and joint's normalised innovation squared at the last sample, per measured
        dimension (1 on average when the model fits the motion and the noise)."""

    def add(self, stamp: int, positions: np.ndarray, velocities: np.ndarray) -> np.ndarray:
        """One sample of every joint: positions (m,), velocities (m,), NaN where not measured.
        Velocities are used when every joint has one. Returns each model's and joint's log-likelihood
        of the sample under the prediction (models, m): 0 for the first sample."""
        models = self.models
        count = len(models)
        if not self.steps:
            state = np.zeros((count, models.dim, len(positions)))
            covariance = models.prior.copy()
        else:
            last = self.steps[-1]
            transition, noise, transposed = models.transition(interval(stamp, last.stamp))
            state = transition @ last.filtered
            carried = last.covariance @ transposed  # P_f F^T
            covariance = transition @ carried + noise
            if self.smooth:
                # G = P_f F^T P_pred^-1 (an explicit inverse: numpy's batched solve costs more at this size)
                gain = carried @ _inverse(covariance)
                last.gain, last.offset = gain, last.filtered - gain @ state
                last.settled = last.covariance - carried @ gain.transpose(0, 2, 1)  # P - G Pp G^T (G Pp = P F^T)
                if self._unrolled is not None:
                    self._unrolled.advance(gain, last.offset, last.settled)
        predicted = state
        first = not self.steps
        if np.isfinite(velocities).all():
            rows = models.measured_rows  # (models, 2, dim)
            projected = rows @ covariance  # (models, 2, dim)
            innovation_covariance = projected @ rows.transpose(0, 2, 1)
            innovation_covariance[:, 0, 0] += self._noise
            innovation_covariance[:, 1, 1] += self._velocity_noise
            gain = np.linalg.solve(innovation_covariance, projected).transpose(0, 2, 1)  # (models, dim, 2)
            innovation = np.stack([positions, velocities]) - rows @ state  # (models, 2, m)
            state = state + gain @ innovation
            covariance = covariance - gain @ projected
            weighted = np.linalg.solve(innovation_covariance, innovation)
            squared = np.sum(innovation * weighted, axis=1)  # (models, m)
            log_det = np.log(np.linalg.det(innovation_covariance))[:, None]
            likelihood = -0.5 * (squared + log_det + 2.0 * _LOG_2PI)
            self.nis = squared / 2.0
        else:  # the position (c + g, states 0 and 3) alone: scalar innovation
            projected = covariance[:, 0] + covariance[:, 3]  # (models, dim)
            # the prediction's own part is never negative (P is positive semi-definite): rounding can make
            # it so on noise-free samples, where the noise read is at its floor
            variance = (np.maximum(projected[:, 0] + projected[:, 3], 0.0) + self._noise)[:, None]  # (models, 1)
            gain = projected / variance
            innovation = positions - state[:, 0] - state[:, 3]  # (models, m)
            state = state + gain[:, :, None] * innovation[:, None, :]
            covariance = covariance - gain[:, :, None] * projected[:, None, :]
            self.nis = innovation**2 / variance
            likelihood = -0.5 * (self.nis + np.log(variance) + _LOG_2PI)
        covariance = 0.5 * (covariance + covariance.transpose(0, 2, 1))
        self.steps.append(_Step(stamp, state, predicted, covariance))
        if self.smooth:
            if first:
                self._unrolled = _Unrolled(models.readout, len(positions))
            assert self._unrolled is not None
            self._unrolled.append()
        if first:
            self.nis = np.ones((count, len(positions)))
            return np.zeros((count, len(positions)))
        return likelihood

    def _index(self, target: int) -> int:
        """The newest kept step at or before the target (the oldest if none is)."""
        steps = self.steps
        index = len(steps) - 1
        while index > 0 and steps[index].stamp > target:
            index -= 1
        return index

    def estimate(self, target: int) -> np.ndarray:
        """(models, 3, m) position, velocity and acceleration at the target stamp: smoothed over every
        step kept after it, from the newest step <= target, carried forward to the target by the model."""
        steps = self.steps
        index = self._index(target)
        state = steps[-1].filtered
        at_step = target == steps[index].stamp
        if index < len(steps) - 1:
            if not self.smooth:  # the filtered state
                state = steps[index].filtered
            elif at_step and self._unrolled is not None and index >= self._unrolled.skipped:
                offsets, products, _ = self._unrolled.at(index)
                return offsets + products @ state
            else:
                for k in range(len(steps) - 2, index - 1, -1):
                    state = steps[k].offset + steps[k].gain @ state
        if target > steps[index].stamp:  # (at_step is False)
            transition, _, _ = self.models.transition(interval(target, steps[index].stamp))
            state = transition @ state
        return self.models.readout @ state

    def acceleration_variance(self, target: int) -> np.ndarray:
        """Each model's variance of the acceleration :meth:`estimate` gives at the target (models,), the
        same for every joint of the group: the smoothed one (the module docstring) where the target
        has later steps and smoothing is on, interpolated in time between two steps; the filtered one
        at its step otherwise, carried forward by the model to a target after it."""
        steps = self.steps
        index = self._index(target)
        stamp = steps[index].stamp
        if self.smooth and index < len(steps) - 1:
            at = self._smoothed_variance(index)
            if target <= stamp:
                return at
            later = self._smoothed_variance(index + 1)
            return at + (target - stamp) / (steps[index + 1].stamp - stamp) * (later - at)
        covariance = steps[index].covariance
        if target > stamp:
            transition, noise, transposed = self.models.transition(interval(target, stamp))
            covariance = transition @ covariance @ transposed + noise
        return _row_variance(self.models.readout, covariance)

    def _smoothed_variance(self, index: int) -> np.ndarray:
        """Each model's smoothed acceleration variance at the step ``index`` (models,): unrolled where
        its row is kept, else going back step by step from the newest."""
        steps = self.steps
        newest = steps[-1].covariance
        unrolled = self._unrolled
        if unrolled is not None and index >= unrolled.skipped:
            _, products, variances = unrolled.at(index)
            variance = variances + _row_variance(products, newest)
        else:
            covariance = newest
            for k in range(len(steps) - 2, index - 1, -1):
                step = steps[k]
                assert step.gain is not None and step.settled is not None
                covariance = step.settled + step.gain @ covariance @ step.gain.transpose(0, 2, 1)
            variance = _row_variance(self.models.readout, covariance)
        # sums of many terms: rounding can take a variance near 0 (noise-free samples) below it
        return np.maximum(variance, 0.0)

    def forget_before(self, stamp: int) -> None:
        """Drop the steps no later estimate needs: all before the newest step at or before ``stamp``."""
        steps = self.steps
        dropped = 0
        while len(steps) > 1 and steps[1].stamp <= stamp:
            steps.popleft()
            dropped += 1
        if dropped and self._unrolled is not None:
            self._unrolled.forget(dropped)

    def select(self, columns: list[int]) -> KalmanTrack:
        """A track of these state columns only, with the same history."""
        track = KalmanTrack(self.models, self.smooth)
        track._noise, track._velocity_noise = self._noise, self._velocity_noise
        for step in self.steps:
            offset = None if step.offset is None else step.offset[:, :, columns]
            track.steps.append(
                _Step(step.stamp, step.filtered[:, :, columns], step.predicted[:, :, columns], step.covariance,
                      step.gain, offset, step.settled)
            )  # fmt: skip
        track._unrolled = None if self._unrolled is None else self._unrolled.select(columns)
        return track


def _row_variance(rows: np.ndarray, covariance: np.ndarray) -> np.ndarray:
    """Each model's variance (models,) of the acceleration read by ``rows`` (models, 3, dim), whose
    third row reads it, from a state of ``covariance`` (models, dim, dim)."""
    row = rows[:, 2:3]  # (models, 1, dim)
    return (row @ covariance @ row.transpose(0, 2, 1))[:, 0, 0]


class _Unrolled:
    """c_k (models, 3, m), P_k (models, 3, dim) and d_k (models,) of the module docstring for the steps
    kept, in buffers that grow by doubling: the steps are rows start .. end - 1, oldest first."""

    def __init__(self, readout: np.ndarray, joints: int, capacity: int = 32) -> None:
        self.readout = readout  # (models, 3, dim)
        models, _, dim = readout.shape
        self.offsets = np.zeros((models, capacity, 3, joints))
        self.products = np.zeros((models, capacity, 3, dim))
        self.variances = np.zeros((models, capacity))
        self.start = self.end = 0
        self.skipped = 0  # the oldest steps kept without a row (past UNROLLED)

    def append(self) -> None:
        """A new newest step: c = 0, P = R, d = 0."""
        if self.end - self.start >= UNROLLED:
            self.start += 1
            self.skipped += 1
        if self.end == self.offsets.shape[1]:
            kept = self.end - self.start
            if 2 * kept > self.offsets.shape[1]:
                self.offsets = np.concatenate([self.offsets, np.zeros_like(self.offsets)], axis=1)
                self.products = np.concatenate([self.products, np.zeros_like(self.products)], axis=1)
                self.variances = np.concatenate([self.variances, np.zeros_like(self.variances)], axis=1)
            self.offsets[:, :kept] = self.offsets[:, self.start : self.end]
            self.products[:, :kept] = self.products[:, self.start : self.end]
            self.variances[:, :kept] = self.variances[:, self.start : self.end]
            self.start, self.end = 0, kept
        self.offsets[:, self.end] = 0.0
        self.products[:, self.end] = self.readout
        self.variances[:, self.end] = 0.0
        self.end += 1

    def advance(self, gain: np.ndarray, offset: np.ndarray, settled: np.ndarray) -> None:
        """The newest step gets a successor: every c_k gains P_k o, every d_k the acceleration row's
        p_k E p_k^T (``settled`` E), every P_k becomes P_k G."""
        models, _, dim = self.readout.shape
        live = slice(self.start, self.end)
        accelerations = self.products[:, live, 2]  # (models, kept, dim)
        self.variances[:, live] += np.add.reduce((accelerations @ settled) * accelerations, axis=2)
        products = self.products[:, live].reshape(models, -1, dim)  # (models, kept * 3, dim)
        self.offsets[:, live] += (products @ offset).reshape(self.offsets[:, live].shape)
        self.products[:, live] = (products @ gain).reshape(models, -1, 3, dim)

    def at(self, index: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(c, P, d) of the step ``index`` among those kept (at least :attr:`skipped`)."""
        row = self.start + index - self.skipped
        return self.offsets[:, row], self.products[:, row], self.variances[:, row]

    def forget(self, count: int) -> None:
        """The oldest ``count`` steps are dropped."""
        unrolled = max(count - self.skipped, 0)
        self.skipped = max(self.skipped - count, 0)
        self.start += unrolled

    def select(self, columns: list[int]) -> _Unrolled:
        unrolled = _Unrolled(self.readout, len(columns), self.offsets.shape[1])
        unrolled.offsets = self.offsets[..., columns]
        unrolled.products = self.products.copy()
        unrolled.variances = self.variances.copy()
        unrolled.start, unrolled.end, unrolled.skipped = self.start, self.end, self.skipped
        return unrolled
