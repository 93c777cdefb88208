"""Kalman filtering and fixed-lag smoothing of one group of joints sampled at the same stamps, for
several motion models at once.

Every joint of a group follows the same :class:`~neforward_ros.estimation.motion.MotionModel` and is
measured at the same stamps with the same noise, so the filter's covariance and gains are the same
for all of them: one covariance per group and model, one state column per joint. The models of a
bank (:mod:`.kalman_bank`) differ only in their length scale and run side by side as one batched
filter: every array carries a leading model axis, and a step costs a few batched products of small
matrices whatever the number of joints and models.

The causal estimate at a sample is the filtered state. The fixed-lag estimate at a sample ``lag``
old is its smoothed state given every sample up to the newest, kept for each step as the
augmented-state fixed-lag smoother keeps it (Anderson and Moore, *Optimal Filtering*, 1979, ch. 7):
the step's mean x_k|N (dim, m) and its covariance with the newest state, C_k = Cov(x_k, x_N) (dim,
dim). When a sample N + 1 arrives, C_k becomes C_k F^T (the prediction); the sample's measurement
(rows H, innovation e, innovation covariance S, predicted covariance Pp) then moves every step as it
moves the newest state: x_k += C_k H^T S^-1 e, C_k -= C_k H^T S^-1 H Pp, and the acceleration's
variance at step k loses (r C_k H^T) S^-1 (r C_k H^T)^T, r the acceleration's read-out row. A new
step starts as the filtered state, its covariance and that covariance's acceleration variance.

This is the Rauch-Tung-Striebel smoother's result without its gain P_f F^T Pp^-1 (the form used
before): on nearly noise-free samples (a 20-bit encoder) Pp is too ill-conditioned (15 states) for
that inverse, whose rounding took the 20 ms estimate's error on 0.5 Hz sines at 1 kHz through 20
bits from 0.17 % to 0.58 % with the slowest model of the bank (to 8.5 % with a ``magnitude`` of 1).
Each sample costs two batched products over the steps kept, of which at most :data:`UNROLLED`, the
newest, are updated: an older step, which only a caller that never forgets keeps, stays as the
samples up to then smoothed it.

An estimate between two steps (a stamp whose sample was not filtered) carries the earlier step's
smoothed state forward to it with the model; its variance is interpolated linearly in time between
the two steps'.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np

from neforward_ros.estimation.motion import MotionModel, MotionModels, interval

_LOG_2PI = float(np.log(2.0 * np.pi))
UNROLLED = 1024
"""The most steps kept whose smoothed state the newest samples still update (a 20 ms lag at 1 kHz
needs 21)."""


@dataclass
class _Step:
    """One sample's filter output, per model: the state after the measurement (models, dim, m) and its
    covariance (models, dim, dim)."""

    stamp: int
    filtered: np.ndarray
    covariance: np.ndarray


class KalmanTrack:
    """The filters of one group: joints measured together, one state column each, one filter per model.

    Args:
        models: the motion models (one or a bank's).
        smooth: whether fixed-lag estimates are asked for (then every step's smoothed state is kept).
    """

    def __init__(self, models: list[MotionModel] | MotionModels, smooth: bool) -> None:
        self.models = models if isinstance(models, MotionModels) else MotionModels(models)
        self.smooth = smooth
        self.steps: deque[_Step] = deque()
        self._smoothed: _Smoothed | None = None  # x_k|N, C_k and the variances of the module docstring
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
        first = not self.steps
        smoothed = self._smoothed
        if first:
            state = np.zeros((count, models.dim, len(positions)))
            covariance = models.prior.copy()
        else:
            last = self.steps[-1]
            transition, noise, transposed = models.transition(interval(stamp, last.stamp))
            state = transition @ last.filtered
            covariance = transition @ (last.covariance @ transposed) + noise
            if smoothed is not None:
                smoothed.predict(transposed)
        if np.isfinite(velocities).all():
            rows = models.measured_rows  # (models, 2, dim)
            projected = rows @ covariance  # H Pp (models, 2, dim)
            innovation_covariance = projected @ rows.transpose(0, 2, 1)
            innovation_covariance[:, 0, 0] += self._noise
            innovation_covariance[:, 1, 1] += self._velocity_noise
            inverse = np.linalg.inv(innovation_covariance)  # (models, 2, 2)
            gain = (inverse @ projected).transpose(0, 2, 1)  # (models, dim, 2)
            innovation = np.stack([positions, velocities]) - rows @ state  # (models, 2, m)
            if smoothed is not None:
                smoothed.measure(rows, inverse, projected, innovation)
            state = state + gain @ innovation
            covariance = covariance - gain @ projected
            weighted = inverse @ innovation
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
            if smoothed is not None:
                rows = models.measured_rows[:, :1]
                smoothed.measure(rows, 1.0 / variance[:, :, None], projected[:, None, :], innovation[:, None, :])
            state = state + gain[:, :, None] * innovation[:, None, :]
            covariance = covariance - gain[:, :, None] * projected[:, None, :]
            self.nis = innovation**2 / variance
            likelihood = -0.5 * (self.nis + np.log(variance) + _LOG_2PI)
        covariance = 0.5 * (covariance + covariance.transpose(0, 2, 1))
        self.steps.append(_Step(stamp, state, covariance))
        if self.smooth:
            if first:
                self._smoothed = _Smoothed(models.readout[:, 2], models.dim, len(positions))
            assert self._smoothed is not None
            self._smoothed.append(state, covariance)
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
        step kept after it (filtered without smoothing), from the newest step <= target, carried forward
        to the target by the model."""
        steps = self.steps
        index = self._index(target)
        if self._smoothed is not None:
            state = self._smoothed.mean(index)
        else:
            state = steps[index].filtered
        if target > steps[index].stamp:
            transition, _, _ = self.models.transition(interval(target, steps[index].stamp))
            state = transition @ state
        return self.models.readout @ state

    def filtered_at(self, target: int) -> tuple[np.ndarray, np.ndarray] | None:
        """Where the target is the stamp of a step older than the newest and smoothing is on: each
        model's filtered acceleration there (models, m) and its variance (models,), what the step said
        before the later samples revised it; else None."""
        if self._smoothed is None:
            return None
        steps = self.steps
        index = self._index(target)
        if index == len(steps) - 1 or steps[index].stamp != target:
            return None
        row = self.models.readout[:, 2]  # (models, dim)
        step = steps[index]
        return np.einsum("md,mdj->mj", row, step.filtered), _acceleration_variance(row, step.covariance)

    def acceleration_variance(self, target: int) -> np.ndarray:
        """Each model's variance of the acceleration :meth:`estimate` gives at the target (models,), the
        same for every joint of the group: the smoothed one (the module docstring) where the target
        has later steps and smoothing is on, interpolated in time between two steps; the filtered one
        at its step otherwise, carried forward by the model to a target after it."""
        steps = self.steps
        index = self._index(target)
        stamp = steps[index].stamp
        smoothed = self._smoothed
        if smoothed is not None and index < len(steps) - 1:
            at = smoothed.variance(index)
            if target <= stamp:
                return at
            later = smoothed.variance(index + 1)
            return at + (target - stamp) / (steps[index + 1].stamp - stamp) * (later - at)
        covariance = steps[index].covariance
        if target > stamp:
            transition, noise, transposed = self.models.transition(interval(target, stamp))
            covariance = transition @ covariance @ transposed + noise
        return _acceleration_variance(self.models.readout[:, 2], covariance)

    def forget_before(self, stamp: int) -> None:
        """Drop the steps no later estimate needs: all before the newest step at or before ``stamp``."""
        steps = self.steps
        dropped = 0
        while len(steps) > 1 and steps[1].stamp <= stamp:
            steps.popleft()
            dropped += 1
        if dropped and self._smoothed is not None:
            self._smoothed.forget(dropped)

    def select(self, columns: list[int]) -> KalmanTrack:
        """A track of these state columns only, with the same history."""
        track = KalmanTrack(self.models, self.smooth)
        track._noise, track._velocity_noise = self._noise, self._velocity_noise
        for step in self.steps:
            track.steps.append(_Step(step.stamp, step.filtered[:, :, columns], step.covariance))
        track._smoothed = None if self._smoothed is None else self._smoothed.select(columns)
        return track


def _acceleration_variance(row: np.ndarray, covariance: np.ndarray) -> np.ndarray:
    """Each model's variance (models,) of the acceleration read by ``row`` (models, dim) from a state of
    ``covariance`` (models, dim, dim)."""
    return np.einsum("md,mde,me->m", row, covariance, row)


class _Smoothed:
    """x_k|N (models, dim, m), C_k (models, dim, dim) and the acceleration's variance (models,) of the
    module docstring for the steps kept, in buffers that grow by doubling: the steps are rows start ..
    end - 1, oldest first; the newest :data:`UNROLLED` of them are updated by each sample."""

    def __init__(self, acceleration_row: np.ndarray, dim: int, joints: int, capacity: int = 32) -> None:
        self.row = acceleration_row  # (models, dim)
        models = len(acceleration_row)
        self.means = np.zeros((models, capacity, dim, joints))
        self.cross = np.zeros((models, capacity, dim, dim))
        self.variances = np.zeros((models, capacity))
        self.start = self.end = 0

    def _live(self) -> slice:
        return slice(max(self.start, self.end - UNROLLED), self.end)

    def predict(self, transposed: np.ndarray) -> None:
        """The newest state moves on by F ((models, dim, dim) F^T given): C_k becomes C_k F^T."""
        live = self._live()
        models, _, dim, _ = self.cross.shape
        cross = self.cross[:, live].reshape(models, -1, dim)
        self.cross[:, live] = (cross @ transposed).reshape(models, -1, dim, dim)

    def measure(self, rows: np.ndarray, inverse: np.ndarray, projected: np.ndarray, innovation: np.ndarray) -> None:
        """The newest sample's measurement: rows H (models, p, dim), S^-1 (models, p, p), H Pp (models,
        p, dim) and the innovation (models, p, m) move every live step (the module docstring)."""
        live = self._live()
        models, _, dim, joints = self.means.shape
        cross = self.cross[:, live].reshape(models, -1, dim)  # (models, kept * dim, dim)
        told = cross @ rows.transpose(0, 2, 1)  # C_k H^T (models, kept * dim, p)
        weights = told @ inverse  # C_k H^T S^-1
        self.means[:, live] += (weights @ innovation).reshape(models, -1, dim, joints)
        self.cross[:, live] -= (weights @ projected).reshape(models, -1, dim, dim)
        kept = self.end - live.start
        told = told.reshape(models, kept, dim, -1)
        acceleration = np.einsum("md,mkdp->mkp", self.row, told)  # r C_k H^T (models, kept, p)
        self.variances[:, live] -= np.add.reduce(acceleration * (acceleration @ inverse), axis=2)

    def append(self, state: np.ndarray, covariance: np.ndarray) -> None:
        """A new newest step: its filtered state and covariance."""
        if self.end == self.means.shape[1]:
            kept = self.end - self.start
            if 2 * kept > self.means.shape[1]:
                self.means = np.concatenate([self.means, np.zeros_like(self.means)], axis=1)
                self.cross = np.concatenate([self.cross, np.zeros_like(self.cross)], axis=1)
                self.variances = np.concatenate([self.variances, np.zeros_like(self.variances)], axis=1)
            self.means[:, :kept] = self.means[:, self.start : self.end]
            self.cross[:, :kept] = self.cross[:, self.start : self.end]
            self.variances[:, :kept] = self.variances[:, self.start : self.end]
            self.start, self.end = 0, kept
        self.means[:, self.end] = state
        self.cross[:, self.end] = covariance
        self.variances[:, self.end] = _acceleration_variance(self.row, covariance)
        self.end += 1

    def mean(self, index: int) -> np.ndarray:
        """The smoothed state (models, dim, m) of the step ``index`` among those kept."""
        return self.means[:, self.start + index]

    def variance(self, index: int) -> np.ndarray:
        """The smoothed acceleration variance (models,) of the step ``index``, at least 0 (sums of many
        terms: rounding can take a variance near 0, on noise-free samples, below it)."""
        return np.maximum(self.variances[:, self.start + index], 0.0)

    def forget(self, count: int) -> None:
        """The oldest ``count`` steps are dropped."""
        self.start += count

    def select(self, columns: list[int]) -> _Smoothed:
        smoothed = _Smoothed(self.row, self.cross.shape[2], len(columns), self.means.shape[1])
        smoothed.means = self.means[..., columns]
        smoothed.cross = self.cross.copy()
        smoothed.variances = self.variances.copy()
        smoothed.start, smoothed.end = self.start, self.end
        return smoothed
