"""Kalman filtering and fixed-lag smoothing of one group of joints sampled at the same stamps.

Every joint of a group follows the same :class:`~neforward_ros.estimation.motion.MotionModel` and is
measured at the same stamps with the same noise, so the filter's covariance and gains are the same
for all of them: one covariance per group, one state column per joint. A step costs a few small
matrix products whatever the number of joints.

The causal estimate at a sample is the filtered state. The fixed-lag estimate at a sample ``lag``
old is the Rauch-Tung-Striebel smoothed state, computed backwards from the newest sample over the
steps kept since; the smoother gains are computed once per step, when the next sample arrives.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np

from neforward_ros.estimation.motion import MotionModel
from neforward_ros.stamps import NS

_LOG_2PI = float(np.log(2.0 * np.pi))


@dataclass
class _Step:
    """One sample's filter output: the state after the measurement, the prediction before it, and the
    smoother gain towards the next step (set when the next sample arrives)."""

    stamp: int
    filtered: np.ndarray  # (dim, m)
    predicted: np.ndarray  # (dim, m)
    covariance: np.ndarray  # (dim, dim), after the measurement
    gain: np.ndarray | None = None


class KalmanTrack:
    """The filter of one group: joints measured together, one state column each.

    Args:
        model: the motion model.
        smooth: whether fixed-lag estimates are asked for (then smoother gains are computed).
    """

    def __init__(self, model: MotionModel, smooth: bool) -> None:
        self.model = model
        self.smooth = smooth
        self.steps: deque[_Step] = deque()
        self._noise = model.settings.noise**2
        self._velocity_noise = model.settings.velocity_noise**2
        self.nis = np.ones(0)
        """Each joint's normalised innovation squared at the last sample, per measured dimension
        (1 on average when the model fits the motion and the noise)."""

    def add(self, stamp: int, positions: np.ndarray, velocities: np.ndarray) -> np.ndarray:
        """One sample of every joint: positions (m,), velocities (m,), NaN where not measured.
        Velocities are used when every joint has one. Returns each joint's log-likelihood of the
        sample under the prediction (m,): 0 for the first sample."""
        model = self.model
        if not self.steps:
            state = np.zeros((model.dim, len(positions)))
            covariance = model.prior.copy()
            # The first position goes to the trend, whose prior is wide; the update below splits it.
            predicted = state
        else:
            last = self.steps[-1]
            transition, noise = model.transition((stamp - last.stamp) / NS)
            state = transition @ last.filtered
            covariance = transition @ last.covariance @ transition.T + noise
            if self.smooth:
                last.gain = np.linalg.solve(covariance, transition @ last.covariance).T
            predicted = state
        first = not self.steps
        if np.isfinite(velocities).all():
            rows = np.stack([model.position_row, model.velocity_row])
            projected = rows @ covariance  # (2, dim)
            innovation_covariance = projected @ rows.T + np.diag([self._noise, self._velocity_noise])
            gain = np.linalg.solve(innovation_covariance, projected).T  # (dim, 2)
            innovation = np.stack([positions, velocities]) - rows @ state
            state = state + gain @ innovation
            covariance = covariance - gain @ projected
            weighted = np.linalg.solve(innovation_covariance, innovation)
            squared = np.sum(innovation * weighted, axis=0)
            log_det = float(np.log(np.linalg.det(innovation_covariance)))
            likelihood = -0.5 * (squared + log_det + 2.0 * _LOG_2PI)
            self.nis = squared / 2.0
        else:  # the position (c + g, states 0 and 3) alone: scalar innovation
            projected = covariance[0] + covariance[3]
            variance = projected[0] + projected[3] + self._noise
            gain = projected / variance
            innovation = positions - state[0] - state[3]
            state = state + np.outer(gain, innovation)
            covariance = covariance - np.outer(gain, projected)
            likelihood = -0.5 * (innovation**2 / variance + np.log(variance) + _LOG_2PI)
            self.nis = innovation**2 / variance
        covariance = 0.5 * (covariance + covariance.T)
        self.steps.append(_Step(stamp, state, predicted, covariance))
        if first:
            self.nis = np.ones(len(positions))
            return np.zeros(len(positions))
        return likelihood

    def estimate(self, target: int) -> np.ndarray:
        """(3, m) position, velocity and acceleration at the target stamp: smoothed over every step kept
        after it, from the newest step ≤ target, carried forward to the target by the model."""
        steps = self.steps
        index = len(steps) - 1
        while index > 0 and steps[index].stamp > target:
            index -= 1
        state = steps[-1].filtered
        for k in range(len(steps) - 2, index - 1, -1):
            step = steps[k]
            if step.gain is None:  # not smoothing: the filtered state
                state = steps[index].filtered
                break
            state = step.filtered + step.gain @ (state - steps[k + 1].predicted)
        if target > steps[index].stamp:
            transition, _ = self.model.transition((target - steps[index].stamp) / NS)
            state = transition @ state
        return self.model.readout @ state

    def acceleration_variance(self) -> float:
        """The acceleration's variance at the newest sample (the filter's; the same for every joint
        of the group)."""
        row = self.model.readout[2]
        return float(row @ self.steps[-1].covariance @ row)

    def forget_before(self, stamp: int) -> None:
        """Drop the steps no later estimate needs: all before the newest step at or before ``stamp``."""
        steps = self.steps
        while len(steps) > 1 and steps[1].stamp <= stamp:
            steps.popleft()

    def select(self, columns: list[int]) -> KalmanTrack:
        """A track of these state columns only, with the same history."""
        track = KalmanTrack(self.model, self.smooth)
        track._noise, track._velocity_noise = self._noise, self._velocity_noise
        for step in self.steps:
            track.steps.append(
                _Step(step.stamp, step.filtered[:, columns], step.predicted[:, columns], step.covariance, step.gain)
            )
        return track
