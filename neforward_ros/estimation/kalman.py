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

The prediction and the measurement move C_k together, C_k <- C_k A with A = F^T - F^T H^T S^-1 H Pp,
and the mean by C_k g with g = F^T H^T S^-1 e. An estimate at a step reads only its position,
velocity and acceleration, R x_k|N (R the read-out rows): only R C_k is kept and moved, three rows of
fifteen, and each step's A and g. Where a target lies between two steps, the earlier step's whole
smoothed state is worked out from them, x_k|N = x_k|k + P_k (g_k+1 + A_k+1 (g_k+2 + ...)), the same
sums. At 1 kHz with a 20 ms lag this took a third off a bank's cost per sample (0.65-0.69 ms to
0.45-0.48 ms, interleaved runs on a slow day; ``bench/bench_kalman.py``). Each sample moves at most
:data:`UNROLLED` steps, the newest: an older step, which only a caller that never forgets keeps,
stays as the samples up to then smoothed it.

Once the library of :mod:`.native_fit` is built, a step after the first is one C call
(:mod:`.native_kalman`: the same formulas; for the kept rows, with Z = R C_k F^T H^T, R C_k A =
R C_k F^T - Z S^-1 H Pp and R C_k g = Z S^-1 e, products of a few columns in place of two of fifteen),
which agrees with numpy's step to rounding (``test/test_native_kalman.py``, and both against the dense
posterior in ``test/test_estimators.py``). At 1 kHz with a 20 ms lag the bank took 0.53x polyfit's
update against 0.71x in numpy (``bench/bench_kalman.py``, the same run's peer); with the bank's
mixture and causal predictions in C too (:mod:`.native_kalman`), 0.41x (0.37x causal).

An estimate between two steps (a stamp whose sample was not filtered) carries the earlier step's
smoothed state forward to it with the model; its variance is interpolated linearly in time between
the two steps'.
"""

from __future__ import annotations

import ctypes
import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from neforward_ros.estimation import native_fit, native_kalman
from neforward_ros.estimation.motion import MotionModel, MotionModels, interval, off_the_clock

_LOG_2PI = float(np.log(2.0 * np.pi))
REACH = 0.01
"""s: the furthest the newest filtered velocity is carried at constant acceleration to move a sample to
the filter's clock (:meth:`KalmanTrack._on_the_clock`): a quarter of the bank's shortest length scale.
After a longer silence the velocity is carried that far only (half a microsecond times the error of an
extrapolation over a dropout could exceed a fine encoder's noise; over REACH it is far below)."""
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
    acceleration_variance: np.ndarray | None = None  # (models,): r P r^T, where the C step gave it


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
        self._found: tuple[tuple[int, int, int, int], int] | None = None  # see _index()
        self._stepper: native_kalman.Stepper | None = None  # the C step's arguments, once it serves
        lams = [model.lam for model in self.models.models]
        self._fastest = lams.index(max(lams))  # the model with the shortest length scale
        self._rates = np.ascontiguousarray(self.models.readout[self._fastest, 1:])  # its q', q'' rows (2, dim)
        first = self.models.models[0].settings
        self._noise = first.noise**2
        self._velocity_noise = first.velocity_noise**2
        self.nis = np.ones((len(self.models), 0))
        """Each model's and joint's normalised innovation squared at the last sample, per measured
        dimension (1 on average when the model fits the motion and the noise)."""
        self.read = np.zeros(0)
        """The newest sample's positions as the filters read them: at the filter's time for its stamp
        (:meth:`_on_the_clock`)."""

    def add(self, stamp: int, positions: np.ndarray, velocities: np.ndarray) -> np.ndarray:
        """One sample of every joint: positions (m,), velocities (m,), NaN where not measured.
        Velocities are used when every joint has one. Returns each model's and joint's log-likelihood
        of the sample under the prediction (models, m): 0 for the first sample."""
        models = self.models
        count = len(models)
        first = not self.steps
        if not first and (offset := off_the_clock(stamp)):
            positions, velocities = self._on_the_clock(offset, interval(stamp, self.steps[-1].stamp), positions,
                                                       velocities)  # fmt: skip
        self.read = positions
        smoothed = self._smoothed
        if first:
            state = np.zeros((count, models.dim, len(positions)))
            covariance = models.prior.copy()
        elif models.dim <= native_kalman.MAX_DIM and (library := native_fit.FIT.get()) is not None:
            return self._add_native(library, stamp, positions, velocities)
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
                self._smoothed = _Smoothed(models.readout, models.dim, len(positions))
            assert self._smoothed is not None
            self._smoothed.append(state, covariance)
        if first:
            self.nis = np.ones((count, len(positions)))
            return np.zeros((count, len(positions)))
        return likelihood

    def _on_the_clock(
        self, offset: float, dt: float, positions: np.ndarray, velocities: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """The sample moved from its stamp to the filter's time for it, ``offset`` s before the stamp
        (:func:`~.motion.off_the_clock`) and ``dt`` s after the newest step: each position less offset x
        the joint's velocity there, each velocity less offset x its acceleration, both as the fastest
        model carries its newest filtered state forward at constant acceleration, over at most
        :data:`REACH` (its lag on the fastest motion is the least; any model's error there, times half a
        microsecond, is far below an encoder's noise).

        Read at the rounded time unmoved, a 20-bit encoder's samples of a joint turning at 10 rad/s
        carry 2.9e-6 rad of error (0.29 us RMS times the speed), nearly twice the encoder's own 1.7e-6:
        the 20 ms estimate of 5 Hz sines through 20 bits was 1.85x hindsight's error at 500 Hz and 1.71x
        at 1 kHz; moved, 1.36x and 1.51x, as with a clock of 1 ns (``bench/bench_estimator_family.py``)."""
        rates = self._rates @ self.steps[-1].filtered[self._fastest]  # (2, m): q', q''
        velocity = rates[0] + min(dt, REACH) * rates[1]
        return positions - offset * velocity, velocities - offset * rates[1]

    def _add_native(
        self, library: ctypes.CDLL, stamp: int, positions: np.ndarray, velocities: np.ndarray
    ) -> np.ndarray:
        """:meth:`add` after the first sample, in one C call (:mod:`.native_kalman`)."""
        models = self.models
        last = self.steps[-1]
        stepper = self._stepper
        if stepper is None or not stepper.fits(len(positions)):
            stepper = self._stepper = native_kalman.Stepper(library, models.measured_rows, models.readout,
                                                            len(positions))  # fmt: skip
        if stepper.holds is not last:
            stepper.state[...] = last.filtered
            stepper.covariance[...] = last.covariance
        measured = 1
        stepper.samples[0] = positions
        stepper.variances[0] = self._noise
        if math.isfinite(np.add.reduce(velocities)):  # every one finite (a finite sum has no NaN or inf)
            measured = 2
            stepper.samples[1] = velocities
            stepper.variances[1] = self._velocity_noise
        smoothed = self._smoothed
        if smoothed is not None:
            smoothed.make_room()
        stepper.step(models.transition_addresses(interval(stamp, last.stamp)), measured, smoothed)
        step = _Step(stamp, stepper.state.copy(), stepper.covariance.copy(), stepper.acceleration_variance.copy())
        self.steps.append(step)
        stepper.holds = step
        if smoothed is not None:
            smoothed.end += 1
        self.nis = stepper.nis.copy()
        return stepper.likelihood.copy()

    def _index(self, target: int) -> int:
        """The newest kept step at or before the target (the oldest if none is); the last answer is
        kept until the steps change (an estimate asks it three times)."""
        steps = self.steps
        key = (target, len(steps), steps[0].stamp, steps[-1].stamp)
        if self._found is not None and self._found[0] == key:
            return self._found[1]
        index = len(steps) - 1
        while index > 0 and steps[index].stamp > target:
            index -= 1
        self._found = (key, index)
        return index

    def estimate(self, target: int) -> np.ndarray:
        """(models, 3, m) position, velocity and acceleration at the target stamp: smoothed over every
        step kept after it (filtered without smoothing), from the newest step <= target, carried forward
        to the target by the model."""
        steps = self.steps
        index = self._index(target)
        step = steps[index]
        smoothed = self._smoothed
        if target <= step.stamp:
            return self.models.readout @ step.filtered if smoothed is None else smoothed.mean(index)
        state = step.filtered if smoothed is None else smoothed.state(index, step.filtered, step.covariance)
        transition, _, _ = self.models.transition(interval(target, step.stamp))
        return self.models.readout @ (transition @ state)

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
        return self._smoothed.filtered(index)

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
        if target <= stamp and steps[index].acceleration_variance is not None:
            return steps[index].acceleration_variance.copy()
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


_PER_STEP = {"means": 3, "rows": 3, "variances": 1, "filtered_accelerations": 1, "filtered_variances": 1, "moves": 1,
             "pushes": 1}  # fmt: skip
"""The per-step buffers of :class:`_Smoothed`, each with its rows a step along its second axis."""


class _Smoothed:
    """For the steps kept (rows start .. end - 1, oldest first, in buffers that grow by doubling): the
    read-outs R x_k|N (models, rows * 3, m) of the smoothed states, R C_k (models, rows * 3, dim), and
    the acceleration's variance (models, rows); and each step's move of the older ones, A_j and g_j
    (the module docstring), from which :meth:`state` works out a step's whole smoothed state. The
    newest :data:`UNROLLED` steps are updated by each sample."""

    def __init__(self, readout: np.ndarray, dim: int, joints: int, capacity: int = 32) -> None:
        self.readout = readout  # R (models, 3, dim): position, velocity and acceleration
        models = len(readout)
        self.dim = dim
        self.means = np.zeros((models, capacity * 3, joints))
        self.rows = np.zeros((models, capacity * 3, dim))
        self.variances = np.zeros((models, capacity))
        self.filtered_accelerations = np.zeros((models, capacity, joints))  # r x_k|k
        self.filtered_variances = np.zeros((models, capacity))  # r P_k r^T
        self.moves = np.zeros((models, capacity, dim, dim))  # A_j, stored with step j
        self.pushes = np.zeros((models, capacity, dim, joints))  # g_j
        self.start = self.end = 0
        self._transposed: np.ndarray | None = None  # F^T of the prediction the next measurement completes
        self._move: tuple[np.ndarray, np.ndarray] | None = None  # (A, g) of the newest measurement

    def first_live(self) -> int:
        return max(self.start, self.end - UNROLLED)

    def predict(self, transposed: np.ndarray) -> None:
        """The newest state moves on by F ((models, dim, dim) F^T given): C_k becomes C_k F^T, applied
        with the measurement that follows (:meth:`measure`)."""
        self._transposed = transposed

    def measure(self, rows: np.ndarray, inverse: np.ndarray, projected: np.ndarray, innovation: np.ndarray) -> None:
        """The newest sample's measurement: rows H (models, p, dim), S^-1 (models, p, p), H Pp (models,
        p, dim) and the innovation (models, p, m) move every live step (the module docstring), after
        the prediction :meth:`predict` was given; its A and g are kept with the step that follows."""
        transposed = self._transposed
        assert transposed is not None, "a measurement follows a prediction"
        self._transposed = None
        measured = transposed @ rows.transpose(0, 2, 1)  # F^T H^T (models, dim, p)
        move = transposed - (measured @ inverse) @ projected  # A
        push = measured @ (inverse @ innovation)  # g (models, dim, m)
        self._move = (move, push)
        live = slice(3 * self.first_live(), 3 * self.end)
        read = self.rows[:, live]  # R C_k (models, kept * 3, dim)
        self.means[:, live] += read @ push
        told = read[:, 2::3] @ measured  # r C_k F^T H^T (models, kept, p)
        self.rows[:, live] = read @ move
        kept = told.shape[1]
        self.variances[:, self.end - kept : self.end] -= np.add.reduce(told * (told @ inverse), axis=2)

    def make_room(self) -> None:
        """Room for one more step at ``end`` in every buffer: the kept steps moved to the front, and the
        buffers doubled where they fill more than half of them."""
        capacity = self.variances.shape[1]
        if self.end == capacity:
            kept = self.end - self.start
            if 2 * kept > capacity:
                for name in _PER_STEP:
                    array = getattr(self, name)
                    setattr(self, name, np.concatenate([array, np.zeros_like(array)], axis=1))
            for name, per in _PER_STEP.items():
                array = getattr(self, name)
                array[:, : kept * per] = array[:, self.start * per : self.end * per]
            self.start, self.end = 0, kept

    def append(self, state: np.ndarray, covariance: np.ndarray) -> None:
        """A new newest step: its filtered state (models, dim, m) and covariance (models, dim, dim)."""
        self.make_room()
        readout = self.readout
        rows = slice(3 * self.end, 3 * self.end + 3)
        means = readout @ state
        self.means[:, rows] = means
        read = readout @ covariance
        self.rows[:, rows] = read
        variance = np.einsum("md,md->m", read[:, 2], readout[:, 2])
        self.variances[:, self.end] = variance
        self.filtered_accelerations[:, self.end] = means[:, 2]
        self.filtered_variances[:, self.end] = variance
        if self._move is not None:
            self.moves[:, self.end], self.pushes[:, self.end] = self._move
            self._move = None
        self.end += 1

    def mean(self, index: int) -> np.ndarray:
        """The smoothed read-outs R x_k|N (models, 3, m) of the step ``index`` among those kept."""
        first = 3 * (self.start + index)
        return self.means[:, first : first + 3]

    def filtered(self, index: int) -> tuple[np.ndarray, np.ndarray]:
        """The filtered acceleration (models, m) and its variance (models,) of the step ``index`` among
        those kept, as the step's own sample left them."""
        at = self.start + index
        return self.filtered_accelerations[:, at], self.filtered_variances[:, at]

    def state(self, index: int, filtered: np.ndarray, covariance: np.ndarray) -> np.ndarray:
        """The whole smoothed state (models, dim, m) of the step ``index`` among those kept, given its
        filtered state and covariance P_k: x_k|k + P_k (g_k+1 + A_k+1 (g_k+2 + A_k+2 (...))), over the
        samples that updated it (the module docstring)."""
        at = self.start + index
        last = min(self.end - 1, at + UNROLLED)
        if last <= at:
            return filtered
        total = self.pushes[:, last]
        for j in range(last - 1, at, -1):
            total = self.pushes[:, j] + self.moves[:, j] @ total
        return filtered + covariance @ total

    def variance(self, index: int) -> np.ndarray:
        """The smoothed acceleration variance (models,) of the step ``index``, at least 0 (sums of many
        terms: rounding can take a variance near 0, on noise-free samples, below it)."""
        return np.maximum(self.variances[:, self.start + index], 0.0)

    def forget(self, count: int) -> None:
        """The oldest ``count`` steps are dropped."""
        self.start += count

    def select(self, columns: list[int]) -> _Smoothed:
        smoothed = _Smoothed(self.readout, self.dim, len(columns), self.variances.shape[1])
        smoothed.means = np.ascontiguousarray(self.means[..., columns])  # (C-contiguous: native_kalman)
        smoothed.pushes = np.ascontiguousarray(self.pushes[..., columns])
        smoothed.rows = self.rows.copy()
        smoothed.variances = self.variances.copy()
        smoothed.moves = self.moves.copy()
        smoothed.filtered_accelerations = np.ascontiguousarray(self.filtered_accelerations[..., columns])
        smoothed.filtered_variances = self.filtered_variances.copy()
        smoothed.start, smoothed.end = self.start, self.end
        smoothed._transposed = self._transposed
        if self._move is not None:
            smoothed._move = (self._move[0], self._move[1][..., columns])
        return smoothed
