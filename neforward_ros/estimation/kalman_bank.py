"""A Kalman estimator that tunes itself: a bank of motion models mixed by how well each predicts
the joint's samples, with the measurement noise read from the samples.

One Gaussian-process motion model fits one kind of motion: its length scale says how fast the
motion may change (:mod:`.motion`). A model too slow for a 5 Hz motion lags it by tens of percent;
one too fast for a slow sweep lets the noise through. The bank runs a filter per length scale of
:data:`LENGTH_SCALES` side by side (the multiple-model approach of Magill 1965 and Bar-Shalom,
Li and Kirubarajan, *Estimation with Applications to Tracking and Navigation*, 2001, ch. 11, without
interaction between the models), as one batched filter (:class:`~.kalman.KalmanTrack`), and scores
each, per joint, by the log-likelihood of the samples under its predictions, forgotten with a time
constant of :data:`MEMORY`. A fixed-lag estimate is the models' smoothed estimates weighted by
exp(score), normalised: as the motion changes (a dwell, a fast move), the weights follow within a
fraction of a second. A causal estimate weights the models' filtered states by how their
predictions of the joint's position :data:`HORIZON` ahead erred (squared errors forgotten over
MEMORY; predictive least squares, Rissanen 1986: nearly the best model alone, :meth:`KalmanBank._shares`).
The likelihood of a sample under a one-step prediction ranks the models by how they foresee the next
sample, which on a fine encoder or at a low rate the fastest model does as well as any while its
acceleration is noisy: weighted so, the causal estimate of trapezoidal moves at 100 Hz through 16-20
bits was 4.2-8.2x hindsight's error (``bench/bench_estimator_family.py``). An explicit
``length_scale`` runs that model alone.

The position noise, unless given, is read from the samples as the polynomial fits read it
(:func:`neforward_ros.estimation.adaptive.noise_of`): white noise from the sixth divided differences
on the samples' stamps, an
encoder's step from the smallest non-zero change since the start (through dwells, where no sample
changes), white noise over the last :data:`NOISE_WINDOW` samples, read again every
:data:`NOISE_EVERY` samples; the velocity noise likewise from the velocities the messages carry.

Whether the driver stamps its messages when it writes them is told as the fits' sample histories tell
it (:class:`~.clock.SampleClock`: the position noise read on the stamps and on the clock recovered from
them, over checks that can tell); where it does, the filters run on the recovered clock from then on
(estimates and their stamps stay the messages'), the noise is read afresh on the samples kept, placed on
that clock, and the models are scored afresh (kept, the scores of predictions made on the stamps held the
20 ms setting's error on 1.5 Hz sines at 100 Hz at 9-10x its steady one for half a second after the
switch). A driver's write delays would otherwise read as noise that follows the velocity: 26 times the
error on 20 ms, 41 times causal (``bench/bench_write_jitter.py``).
Until 2026-11-28 the bank told it by itself, from one check over 64 samples: the Panda's recording, its
samples' own times, then read as write times 371 samples in, and the bank alone served it (its torque
error up to 2.08 times the zero-phase reference's, 1.05 now).
"""

from __future__ import annotations

import math
from collections import deque

import numpy as np

from neforward_ros.estimation import native_fit, native_kalman
from neforward_ros.estimation.adaptive import TIMING_STRIDE, noise_of
from neforward_ros.estimation.clock import SILENCE, SampleClock, median_of_few
from neforward_ros.estimation.kalman import KalmanTrack
from neforward_ros.estimation.motion import TICK_NS, KalmanSettings, MotionModel, MotionModels, interval
from neforward_ros.stamps import NS

LENGTH_SCALES = (0.04, 0.1, 0.25, 0.6)
"""s: the bank's models (each fits motion up to about 0.65 / length_scale Hz)."""
MEMORY = 0.2
"""s: the time constant with which the models' scores forget."""
SETTLE = 0.1
"""s after a start or a silence before the predictions are scored: the filters still converge from
their prior, or from where the silence left them, and errors thousands of times the usual ones would
rule the choice for seconds."""
HORIZON = 0.01
"""s: how far ahead of a sample each model's prediction of it is scored (a quarter of the fastest
model's length scale)."""
NOISE_WINDOW = 64
"""Samples the white noise is read from (the newest)."""
NOISE_EVERY = 32
"""Samples between two readings of the noise once the window is full (it changes slowly; reading it
costs several steps)."""
FALLBACK_NOISE = 1e-4
"""rad (m): the position noise before enough samples tell it."""
NOISE_FLOOR = 1e-2
"""The least noise read, relative to the fallback (1e-6 rad for positions, below a 20-bit encoder's
1.7e-6): a filter trusting noise-free samples further loses its covariance to rounding (the prior's
variances are 1e2, a noise of 1e-8 rad would be 1e-16) and diverges."""
FALLBACK_VELOCITY_NOISE = 1e-3
"""rad/s (m/s): likewise for the velocities."""
REPLAY_ON_CLOCK = True
"""Where the stamps are found to be write times, the filters start again from their prior on the samples
held since the start (:data:`UNCLOCKED`), each at its time on the recovered clock's line, the noise read
on them first. Until 2026-11-29 they went on from the state they had reached on the stamps, and their next
step's time went back by the stamps' mean delay to the line: from a start on write-time stamps (delays to
0.4 of a period, 16 bits, the estimates held until the clock told), the worst error in the first second was
20-121x the steady 99th percentile for kalman 20 ms at 100 Hz and 10-43x for kalman causal at 1 kHz on
sines and a gait, 0.86-1.47x and 1.05-1.20x replayed (``test/test_write_clock.py``)."""
BANK_TIMING_NOISE = True
"""Until the clock tells whether the stamps are the samples' times (:attr:`~.clock.SampleClock.timing` above 0),
the position noise is at least what the stamps' uncertainty makes at the joints' speed now
(:meth:`_timing_variance`), as the causal fits' is (:func:`~.adaptive.timing_noise`). Read from the samples, the
noise of a writer whose arm rested at the start is the rest's, and from the move's start until the clock finds
write times the filters took the write delays' motion for the joints' own: kalman 20 ms's worst error in the first
second up to 46 times its steady 99th percentile (minimum-jerk moves at 100 Hz through 16 bits), 9.6 and 6.7
times at 500 Hz; with it 13.7, 3.2 and 2.8 (``bench/bench_write_jitter.py --start``; 3.3 at 100 Hz with
:data:`~.clock.DECISIVE_LOOKS`). Tried on 2026-11-29 without the clock telling a swinging joint's stamps
(:func:`~.clock.path_speed`), it held the family's 5 Hz sines at 100 Hz through 12 bits, stamped at their
jittered samples, on the stamps' uncertainty for good: 0.52 -> 1.69 times hindsight's error."""
MIDWAY = True
"""Until the clock tells whether the stamps are the samples' times (while :attr:`~.clock.SampleClock.timing` is above
0), and while its newest check read less noise on its line than on the stamps (:attr:`~.clock.SampleClock.leaning`,
or before any could compare), the filters place each sample midway between its stamp and its time on the recovered
clock's line, less half the stamps' mean delay above the line (:meth:`~.clock.SampleClock.midway`: on average at the
stamps, so that going onto them or off them moves no sample by more than the noise it was taken to carry), and the
stamps' uncertainty (:data:`BANK_TIMING_NOISE`) is half their spread: whichever clock is right, a sample's time is
off by half the distance between them, where on the other it is off by all of it. From a start on write-time stamps
after a rest, kalman 20 ms's worst error in the first second was 3.34 and 3.22 times its steady 99th percentile on
the stamps (minimum-jerk moves at 100 and 500 Hz through 16 bits), 2.10 and 2.90 midway; 14.95 and 6.60 at 250 Hz
(seeds 306 and 308), 6.62 and 3.32 (``bench/bench_write_jitter.py --start``). Midway whatever the checks read, the
stamps of jittered samples that the clock never tells (12 bits at 100 Hz hide the jitter's motion) were off their
times by half the jitter for good: 1.29 -> 1.44 times hindsight's q'' error (``test_write_clock.py``)."""
UNCLOCKED = 256
"""Samples held for :data:`REPLAY_ON_CLOCK` until the clock tells (the newest; a stream kept on its stamps
holds none)."""
REVISION_MEMORY = 0.02
"""The weight of each new fixed-lag estimate in a joint's mean normalised revision (about the last 50)."""


class KalmanBank:
    """The filters of one group of joints (see the module docstring); the interface of
    :class:`~neforward_ros.estimation.kalman.KalmanTrack`.

    Args:
        settings: the Kalman settings; a zero noise, velocity noise or length scale means "from the
            data" (the bank's length scales for the latter).
        smooth: whether fixed-lag estimates are asked for.
        clock: the stream's sample clock (:class:`~.clock.SampleClock`; a new one where None).
    """

    def __init__(
        self,
        settings: KalmanSettings,
        smooth: bool,
        models: MotionModels | None = None,
        known_noise: tuple[float | None, float | None] = (None, None),
        known_scores: np.ndarray | None = None,
        clock: SampleClock | None = None,
    ) -> None:
        self.settings = settings
        self.smooth = smooth
        self.known_noise = dict(zip(("positions", "velocities"), known_noise, strict=True))
        """The variances read before a restart (the sensors are the same), used until the samples
        since tell them again."""
        if models is None:
            scales = LENGTH_SCALES if settings.length_scale == 0 else (settings.length_scale,)
            models = MotionModels([MotionModel(_concrete(settings, scale)) for scale in scales])
        self.models = models
        scales = np.array([model.settings.length_scale for model in models.models])
        self._converges_after = np.maximum(SETTLE, 2.0 * scales)  # s, per model: see converged()
        self.track = KalmanTrack(models, smooth)
        self.scores: np.ndarray | None = None
        """(models, joints): the log-likelihood of each joint's samples under each model's predictions,
        forgotten over :data:`MEMORY`."""
        self.errors: np.ndarray | None = None
        """Causal: (models, joints) the squared errors of each model's predictions :data:`HORIZON` ahead,
        forgotten over :data:`MEMORY`."""
        self._weights: np.ndarray | None = None
        self._mixer: native_kalman.Mixer | None = None  # the C mixture's workspace, once it serves
        self._origin: int | None = None  # ns: the first stamp
        self.known_scores = known_scores  # (models, joints): the weights before a restart, as log-weights
        # each model's predictions from the last samples, carried forward to the newest (models, dim, kept, m)
        self._predictions: np.ndarray | None = None
        self._ahead: native_kalman.Ahead | None = None  # the same in C, once it serves
        self._settled = 0  # the filter's time (ns) from which the predictions are scored
        self._recorded = 0  # the filter's time (ns) from which the record of their errors serves
        # (stamp, positions, velocities) of the samples since the start, until the clock tells whether the
        # stamps are write times (REPLAY_ON_CLOCK)
        self._unclocked: deque[tuple[int, np.ndarray, np.ndarray]] = deque(maxlen=UNCLOCKED)
        self._choosing = False  # causal: whether the estimate is by the errors' shares (:meth:`_shares`)
        self._last: int | None = None
        self._intervals: deque[float] = deque(maxlen=16)  # s: the last intervals between samples
        # (s, s on the recovered clock, values)
        self._positions: deque[tuple[float, float, np.ndarray]] = deque(maxlen=NOISE_WINDOW)
        self._velocities: deque[tuple[float, float, np.ndarray]] = deque(maxlen=NOISE_WINDOW)
        self.clock = clock or SampleClock()  # whether the stamps are write times, and the clock recovered from them
        self._models: deque[tuple[int, int]] = deque()  # (stamp, the filter's time) of the steps kept
        self.placing = "stamps"
        """Where the filters place the samples: on their stamps, "midway" between a stamp and its time on the
        recovered clock's line until the clock tells (:data:`MIDWAY`), or on the "line" once the stamps are found
        to be write times."""
        self._steps: dict[str, np.ndarray] = {}  # the smallest change seen so far, per joint: an encoder's step
        self.read_noise: dict[str, float] = {}  # the variances read from the samples so far
        self._unread = dict.fromkeys(("positions", "velocities"), 0)  # samples since the noise was read
        self.revisions: np.ndarray | None = None
        """Per joint, the mean normalised revision of the fixed-lag estimates (see :meth:`estimate`)."""

    @property
    def written(self) -> bool:
        """Whether the stamps were found to be write times: the filter then runs on the recovered clock."""
        return self.clock.written

    @property
    def steps(self):  # the filter's steps (one per sample; every model shares the stamps)
        return self.track.steps

    def add(self, stamp: int, positions: np.ndarray, velocities: np.ndarray) -> None:
        """One sample of every joint (see :meth:`KalmanTrack.add`)."""
        usual = median_of_few(self._intervals) if len(self._intervals) >= 4 else None
        silence = self._last is not None and usual is not None and (stamp - self._last) / NS > SILENCE * usual
        if silence:
            # A silence: differences across it are motion, not noise. Read the noise afresh after it,
            # with what was read before it meanwhile.
            self.known_noise = {kind: self.read_noise.get(kind, known) for kind, known in self.known_noise.items()}
            self._positions.clear()
            self._velocities.clear()
            # (the clock goes on: it counts the periods of a silence as of a dropped sample)
        written, placings = self.written, self.clock.placings
        recovered = self.clock.add(stamp, positions)
        going = self.written and not written
        if going or self.clock.placings != placings:  # (or the clock mended its count of periods)
            self._retime_noise_samples()
        self.placing = self._placement()
        self._tune_noise(stamp, recovered, positions, velocities)  # (on the line, where going on it)
        if going:
            self._go_on_clock()
        if REPLAY_ON_CLOCK and not (self.clock.written or self.clock.kept):  # until the clock is told
            self._unclocked.append((stamp, np.array(positions, dtype=float), np.array(velocities, dtype=float)))
        elif self._unclocked:
            self._unclocked.clear()
        placing = self.placing
        time = stamp if placing == "stamps" else recovered if placing == "line" else self.clock.midway(stamp, recovered)
        self._step(stamp, time, positions, velocities, silence, usual)

    def _placement(self) -> str:
        """Where the filters place the samples now (:attr:`placing`)."""
        if self.clock.written:
            return "line"
        if MIDWAY and self.clock.timing > 0.0 and self.clock.leaning:
            return "midway"
        return "stamps"

    def _step(
        self, stamp: int, time: int, positions: np.ndarray, velocities: np.ndarray, silence: bool, usual: float | None
    ) -> None:
        """The filters' step for the sample stamped ``stamp`` (ns) at ``time`` (ns: the stamp, or its time on
        the recovered clock), and the models' scores."""
        model = time
        models = self._models
        if models and (self.placing != "stamps" or models[-1][0] != models[-1][1]):
            # the time placed (or a stamp after a placed one), after the filter's newest
            model = max(time, models[-1][1] + TICK_NS)
        models.append((stamp, model))
        previous = self.track.steps[-1].stamp if self.track.steps else None
        likelihoods = self.track.add(model, positions, velocities)
        errors = None if self.smooth else self._prediction_errors(previous, model, self.track.read, silence, usual)
        if self.scores is None or self._last is None:
            self.scores = likelihoods if self.known_scores is None else likelihoods + self.known_scores
        else:
            step = (stamp - self._last) / NS
            decay = math.exp(-step / MEMORY)
            if not silence:
                self.scores = decay * self.scores + likelihoods
            # else: the first sample after a silence: how far each model drifted over it says little
            # about how well it follows the motion, and would hand the estimate to the fastest.
            if errors is not None:
                self.errors = errors if self.errors is None else decay * self.errors + errors
            self._intervals.append(step)
        # the record speaks once it spans MEMORY since the predictions first settled (after a silence, the
        # record from before it serves)
        self._choosing = self.errors is not None and model >= self._recorded
        self._last = stamp
        self._weights = None

    def _prediction_errors(
        self, previous: int | None, now: int, positions: np.ndarray, silence: bool, usual: float | None
    ) -> np.ndarray | None:
        """Each model's squared error (models, m) of the position it predicted for this sample from the
        samples :data:`HORIZON` before (as many sample intervals as come nearest, at least one), None
        where there is no such prediction yet (a start, a silence). ``previous`` and ``now``: the
        filter's times of the step before and of this one."""
        restart = silence or previous is None
        if restart:
            self._settled = now + round(SETTLE * NS)
            if previous is None:
                self._recorded = self._settled + round(MEMORY * NS)
        ahead = max(1, round(HORIZON / usual)) if usual else 1
        carrier = self._carrier()
        if carrier is not None:  # in C
            if restart:
                carrier.reset()
            scored, transition = False, None
            if carrier.kept and previous is not None:
                step = interval(now, previous)
                transition = self.models.transition(step)[0]
                if now >= self._settled:
                    address = self.models.transition_addresses(step)[0]
                    scored = carrier.predict(address, positions, ahead, self.track._noise)
            errors = carrier.errors.copy() if scored else None
            carrier.push(self.track.steps[-1].filtered, transition, ahead)
            return errors
        predictions = self._predictions  # (models, dim, kept, m), the oldest first
        if restart:
            predictions = None
        elif predictions is not None:
            transition, _, _ = self.models.transition(interval(now, previous))
            models, dim, kept, m = predictions.shape
            predictions = (transition @ predictions.reshape(models, dim, kept * m)).reshape(predictions.shape)
        errors = None
        if predictions is not None and predictions.shape[2] >= ahead and now >= self._settled:
            predicted = predictions[:, :, -ahead]
            # an error within the position noise says nothing of a model (at rest every one predicts the
            # unchanged reading to rounding, and the least rounding would choose)
            errors = np.maximum(np.square(positions - predicted[:, 0] - predicted[:, 3]), self.track._noise)
        newest = self.track.steps[-1].filtered[:, :, None]
        kept = newest if predictions is None else np.concatenate([predictions[:, :, 1 - ahead :], newest], axis=2)
        self._predictions = kept[:, :, -ahead:]
        return errors

    def _carrier(self) -> native_kalman.Ahead | None:
        """The predictions' rings in C (:class:`~.native_kalman.Ahead`) once the library is built, taking
        over what numpy kept before; None while numpy serves."""
        carrier = self._ahead
        if carrier is not None:  # (a bank's joints do not change: select() makes another)
            return carrier
        library = native_fit.FIT.get() if 4 <= self.models.dim <= native_kalman.MAX_DIM else None
        if library is None:
            return None
        shape = (len(self.models), self.models.dim, self.track.steps[-1].filtered.shape[2])
        carrier = self._ahead = native_kalman.Ahead(library, *shape, kept=self._predictions)
        self._predictions = None
        return carrier

    def weights(self) -> np.ndarray:
        """(models, joints): each model's weight per joint by the likelihood, exp(score) normalised
        (worked out once per sample)."""
        assert self.scores is not None
        if self._weights is None:
            weights = self.scores - np.maximum.reduce(self.scores, axis=0)
            np.exp(weights, out=weights)
            weights /= np.add.reduce(weights, axis=0)
            self._weights = weights
        return self._weights

    def _shares(self) -> np.ndarray:
        """Causal, once the predictions :data:`HORIZON` ahead have been scored for :data:`MEMORY` since the
        start (from :data:`SETTLE` after it, and after a silence; until then the likelihood's weights
        serve): each model's share of a joint's estimate (models, joints), the likelihood of its errors
        taken as Gaussian of its own mean square, MEMORY / HORIZON independent ones in the record,
        relative to the best's: (least / its) ** (MEMORY / HORIZON / 2), normalised. Nearly the best model alone
        (one twice the least weighs a thousandth), but as a move starts after a dwell and the slow
        model that the dwell chose lags, the weight goes over to a faster one as its errors show,
        where taking the least's alone jumps between the two (16.8 rad/s^2 off, against 5.9, on a
        simulated arm's move at 500 Hz: ``bench/bench_transients.py``)."""
        errors = self.errors
        assert errors is not None
        least = errors.min(axis=0, keepdims=True)
        ratio = np.where(errors > 0.0, least / np.where(errors > 0.0, errors, 1.0), 1.0)
        shares = ratio ** (0.5 * MEMORY / HORIZON)
        return shares / shares.sum(axis=0, keepdims=True)

    def estimate(self, target: int) -> tuple[np.ndarray, np.ndarray]:
        """(3, m) position, velocity and acceleration at the target: the models' mixture by their
        weights (fixed lag), or by the shares their predictions' errors give them (causal,
        :meth:`_shares`); and each joint's acceleration standard deviation (m,): each model's variance
        of its estimate there (smoothed for a fixed lag) and the spread of the models' estimates about
        the one given, by the weights, scaled up by the joint's mean normalised revision where it is
        above 1 (:meth:`_revised`)."""
        _, _, mixture, std = self.estimates(target)
        return mixture, std

    def estimates(self, target: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Each model's own position, velocity and acceleration at the target (models, 3, m), smoothed for
        a fixed lag, each model's variance of that acceleration (models,), and :meth:`estimate`'s mixture
        (3, m) and standard deviations (m,), from one reading of the filters (a joint's mean normalised
        revision moves once per target)."""
        at = self._model_of(target)
        estimates = self.track.estimate(at)  # (M, 3, m)
        own = self.track.acceleration_variance(at)  # (M,)
        mixer = self._mixer_for(*estimates.shape[::2])
        if mixer is not None:
            return (estimates, own, *self._mix_native(mixer, at, estimates, own))
        variances = own[:, None]  # (M, 1)
        if len(estimates) == 1:
            weights = np.ones((1, estimates.shape[2]))
        else:
            weights = self._shares() if self._choosing else self.weights()
        mixture = np.add.reduce(weights[:, None, :] * estimates, axis=0)
        spread = estimates[:, 2] - mixture[2]
        variance = np.add.reduce(weights * (variances + spread * spread), axis=0)
        std = np.sqrt(variance * np.maximum(self._revised(at, weights, mixture[2], variances), 1.0))
        return estimates, own, mixture, std

    def _mixer_for(self, count: int, joints: int) -> native_kalman.Mixer | None:
        """The C mixture's workspace for this many models and joints, once the library is built."""
        mixer = self._mixer
        if mixer is not None and mixer.fits(count, joints):
            return mixer
        library = native_fit.FIT.get()
        if library is None:
            return None
        self._mixer = native_kalman.Mixer(library, count, joints)
        return self._mixer

    def _mix_native(
        self, mixer: native_kalman.Mixer, at: int, estimates: np.ndarray, own: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`estimates`' mixture and standard deviations (with :meth:`_revised`'s update) in one C call."""
        mixer.estimates[...] = estimates
        mixer.own[...] = own
        weighting = 0  # (Mixer.mix)
        if len(estimates) == 1:
            mixer.weights[...] = 1.0
        elif self._choosing:  # _shares()
            assert self.errors is not None
            mixer.weights[...] = self.errors
            weighting = 2
        elif self._weights is not None:
            mixer.weights[...] = self._weights
        else:  # exp(score) normalised, as weights() has it
            assert self.scores is not None
            mixer.weights[...] = self.scores
            weighting = 1
        mixer.revisions[...] = self._revision_record(estimates.shape[2])
        filtered = self.track.filtered_at(at)
        if filtered is not None:
            mixer.filtered_accelerations[...], mixer.filtered_variances[...] = filtered
        mixer.mix(filtered is not None, weighting, REVISION_MEMORY, 0.5 * MEMORY / HORIZON)
        if weighting == 1:
            self._weights = mixer.weights.copy()
        self.revisions = mixer.revisions.copy()
        return mixer.mixture.copy(), mixer.std.copy()

    def converged(self, target: int) -> np.ndarray:
        """Which models (models,) have had the samples since the start to converge from their prior by the
        target: :data:`SETTLE`, or twice the model's length scale where longer (the 0.6 s model's q'' is
        still tens of times its later error after a second's samples)."""
        since = 0.0 if self._origin is None else (target - self._origin) / NS
        return since >= self._converges_after

    def _revised(self, at: int, weights: np.ndarray, smoothed: np.ndarray, variances: np.ndarray) -> np.ndarray:
        """Each joint's mean normalised revision (m,), updated with the fixed-lag estimate at ``at`` (the
        filter's time) where it is a step's: the revision, the smoothed acceleration less the one the
        step's filter gave, squared, over the variance the model expects of it (the filtered variance
        less the smoothed; the models' weighted). About 1 where the model fits the samples; noise that
        the model does not know (coloured: a real arm's positions carry more at 15-100 Hz than at the
        rate's Nyquist frequency) revises the estimates more, and the smoothed estimate's error grows
        with it, while the one-step innovations hardly see it. 1 where there is no revision to read."""
        filtered = self.track.filtered_at(at)
        count = len(smoothed)
        self._revision_record(count)
        if filtered is not None:
            accelerations, filtered_variances = filtered
            expected = np.add.reduce(weights * (filtered_variances[:, None] - variances), axis=0)
            revision = np.add.reduce(weights * accelerations, axis=0) - smoothed
            ratio = np.ones(count)
            np.divide(revision * revision, expected, out=ratio, where=expected > 0.0)
            self.revisions = (1.0 - REVISION_MEMORY) * self.revisions + REVISION_MEMORY * ratio
        return self.revisions

    def _revision_record(self, count: int) -> np.ndarray:
        """:attr:`revisions` for ``count`` joints, 1 each where there is none yet (or for other joints)."""
        if self.revisions is None or len(self.revisions) != count:
            self.revisions = np.ones(count)
        return self.revisions

    @property
    def nis(self) -> np.ndarray:
        """Each joint's normalised innovation squared at the last sample, of its best model (the best
        scored, or causal, where :meth:`_shares` serve, the best predicting ahead)."""
        if self._choosing:
            best = np.argmin(self.errors, axis=0)
        else:
            best = np.argmax(self.scores, axis=0) if self.scores is not None else np.zeros(0, dtype=int)
        stacked = self.track.nis
        return stacked[best, np.arange(len(best))] if len(best) else stacked[0]

    def forget_before(self, stamp: int) -> None:
        self.track.forget_before(self._model_of(stamp))
        models = self._models
        while len(models) > 1 and models[1][0] <= stamp:
            models.popleft()

    def _model_of(self, stamp: int) -> int:
        """The filter's time (ns) of a stamp: the recovered time of the newest sample at or before it,
        plus the time since (placed midway until the clock tells: :data:`MIDWAY`); the stamp itself where the
        samples are placed on their stamps."""
        if self.placing == "stamps":
            return stamp
        for sample, model in reversed(self._models):
            if sample <= stamp:
                return model + (stamp - sample)
        sample, model = self._models[0]
        return model + (stamp - sample)

    def select(self, columns: list[int]) -> KalmanBank:
        bank = KalmanBank(self.settings, self.smooth, self.models)
        bank.known_noise = dict(self.known_noise)
        bank.read_noise = dict(self.read_noise)
        bank.track = self.track.select(columns)
        bank.scores = None if self.scores is None else self.scores[:, columns]
        bank.known_scores = None if self.known_scores is None else self.known_scores[:, columns]
        bank._last = self._last
        bank._intervals = deque(self._intervals, maxlen=16)
        bank._origin = self._origin
        bank._positions = deque(((t, r, p[columns]) for t, r, p in self._positions), maxlen=NOISE_WINDOW)
        bank._velocities = deque(((t, r, v[columns]) for t, r, v in self._velocities), maxlen=NOISE_WINDOW)
        bank.clock = self.clock.select(columns)
        bank._unclocked = deque(((s, p[columns], v[columns]) for s, p, v in self._unclocked), maxlen=UNCLOCKED)
        bank._models = deque(self._models)
        bank.placing = self.placing
        bank._steps = {k: v[columns] for k, v in self._steps.items()}
        bank.revisions = None if self.revisions is None else self.revisions[columns]
        bank.errors = None if self.errors is None else self.errors[:, columns]
        predictions = self._predictions
        if self._ahead is not None:
            predictions = self._ahead.stacked() if self._ahead.kept else None
        bank._predictions = None if predictions is None else predictions[..., columns]
        bank._settled, bank._recorded, bank._choosing = self._settled, self._recorded, self._choosing
        return bank

    def _noise(self, kind: str, samples: deque[tuple[float, float, np.ndarray]], fallback: float) -> float:
        """A measurement variance for the whole group: the median of its joints' (white noise, or an
                encoder's step / sqrt(12)), from the samples kept; the fallback's until there are 32. The
                step is the smallest change seen since the start, kept through dwells (where no sample
                changes and the recent samples alone would say nothing). Joints that have not moved since
                the start say nothing of the noise and are left out of the median (with them, a group whose
                other joints still rest would take a noise of zero and trust every sample beyond measure). Once
        the window is full, read every :data:`NOISE_EVERY` samples; on the recovered clock once the stamps
        are found to be write times (:attr:`written`)."""
        if len(samples) < NOISE_WINDOW:
            known = self.known_noise.get(kind)
            if known is not None:
                return known
            if len(samples) < 32:
                return fallback**2
        elif kind in self.read_noise and self._unread[kind] < NOISE_EVERY - 1:
            self._unread[kind] += 1
            return self.read_noise[kind]
        self._unread[kind] = 0
        values = np.stack([v for _, _, v in samples])
        if self.placing == "midway":  # (less half the stamps' mean delay, a constant that says nothing of the noise)
            times = np.array([0.5 * (t + r) for t, r, _ in samples])
        else:
            times = np.array([r if self.placing == "line" else t for t, r, _ in samples])
        white, step = noise_of(times, values, coloured=False)
        seen = self._steps.get(kind)
        step = np.where(step > 0.0, step, np.inf)
        seen = step if seen is None else np.minimum(seen, step)
        self._steps[kind] = seen
        known = np.where(np.isfinite(seen), seen, 0.0)
        variance = np.maximum(white**2, known**2 / 12.0)
        # a joint at rest gives sixth differences of rounding size (its constant times the weights' sum,
        # about 1e-16 of it): no evidence of a noise below the floor. A joint that moves by more than the
        # floor, its sixth differences below it, is evidence of a noise at most the floor (a 24-bit encoder,
        # simulated samples): it was taken for a joint at rest, and the group kept the fallback, a hundred
        # times the floor (0.5 Hz sines at 500 Hz through 24 bits: 81x hindsight's q'' error, now 3.7x)
        moved = np.ptp(values, axis=0) > fallback * NOISE_FLOOR
        told = np.isfinite(seen) | (white > fallback * NOISE_FLOOR) | moved
        if not told.any():
            known = self.known_noise.get(kind)
            return known if known is not None else fallback**2
        found = float(max(_median_of(variance[told]), (fallback * NOISE_FLOOR) ** 2))
        self.read_noise[kind] = found
        return found

    def _go_on_clock(self) -> None:
        """As the stamps are found to be write times (the samples kept for the noise placed on the recovered
        clock's line and the noise read on them): the models scored afresh (their predictions so far were of
        samples at other times). With :data:`REPLAY_ON_CLOCK`, the filters start again from their prior
        on the samples held since the start, each at its time on the line, and score the models on them."""
        self.scores = None
        if not REPLAY_ON_CLOCK or not self._unclocked:
            return
        held = list(self._unclocked)
        self._unclocked.clear()
        track = KalmanTrack(self.models, self.smooth)
        track._noise, track._velocity_noise = self.track._noise, self.track._velocity_noise
        self.track = track
        self._models.clear()
        self._intervals.clear()
        self._predictions = None
        self.errors = self.revisions = None
        self._last = None
        self._choosing = False
        times = self.clock.retimed(np.array([stamp for stamp, _, _ in held], dtype=np.int64))
        for (stamp, positions, velocities), time in zip(held, np.round(times).astype(np.int64).tolist(), strict=True):
            usual = median_of_few(self._intervals) if len(self._intervals) >= 4 else None
            self._step(stamp, time, positions, velocities, False, usual)

    def _timing_variance(self, timing: float) -> float:
        """The position variance the stamps' uncertainty (``timing``, s) makes now: ``timing`` times each joint's
        speed over the newest :data:`~.adaptive.TIMING_STRIDE` samples, squared, the median over the joints that
        moved (the bank's noise is the group's; the causal fits take the fastest speed in their window:
        :func:`~.adaptive.timing_noise`)."""
        (before, _, then), (now, _, newest) = self._positions[-1 - TIMING_STRIDE], self._positions[-1]
        moved = np.abs(newest - then)
        moving = moved[moved > 0.0]
        if not len(moving) or now <= before:
            return 0.0
        moving *= timing / (now - before)
        return _median_of(moving * moving)

    def _retime_noise_samples(self) -> None:
        """The samples kept for the noise, placed on the recovered clock's line (:meth:`~.clock.SampleClock.retimed`);
        the noise is read afresh on them at the next sample."""
        for kind, samples in (("positions", self._positions), ("velocities", self._velocities)):
            if not samples:
                continue
            seconds = np.array([t for t, _, _ in samples])
            stamps = self._origin + np.round(seconds * NS).astype(np.int64)
            on_clock = (self.clock.retimed(stamps) - self._origin) / NS
            kept = [(t, float(r), v) for (t, _, v), r in zip(samples, on_clock, strict=True)]
            samples.clear()
            samples.extend(kept)
            self._unread[kind] = NOISE_EVERY - 1

    def _tune_noise(self, stamp: int, recovered: int, positions: np.ndarray, velocities: np.ndarray) -> None:
        settings = self.settings
        if self._origin is None:
            self._origin = stamp
        seconds = (stamp - self._origin) / NS  # the samples' times, for the noise's divided differences
        on_clock = (recovered - self._origin) / NS
        if settings.noise == 0:
            self._positions.append((seconds, on_clock, np.asarray(positions, dtype=float).copy()))
            noise = self._noise("positions", self._positions, FALLBACK_NOISE)
            timing = self.clock.timing * (0.5 if self.placing == "midway" else 1.0)
            if BANK_TIMING_NOISE and timing > 0.0 and len(self._positions) > TIMING_STRIDE:
                noise = max(noise, self._timing_variance(timing))
            self.track._noise = noise
        if settings.velocity_noise == 0 and math.isfinite(np.add.reduce(velocities)):
            self._velocities.append((seconds, on_clock, np.asarray(velocities, dtype=float).copy()))
            noise = self._noise("velocities", self._velocities, FALLBACK_VELOCITY_NOISE)
            self.track._velocity_noise = noise


def _median_of(values: np.ndarray) -> float:
    """numpy's median of a few numbers (NaN if any is), without its overhead."""
    listed = values.tolist()
    if any(value != value for value in listed):
        return math.nan
    return median_of_few(listed)


def _concrete(settings: KalmanSettings, length_scale: float) -> KalmanSettings:
    """The settings of one model: its length scale, and a placeholder noise where the bank reads it."""
    return KalmanSettings(
        noise=settings.noise or FALLBACK_NOISE,
        velocity_noise=settings.velocity_noise or FALLBACK_VELOCITY_NOISE,
        length_scale=length_scale,
        magnitude=settings.magnitude,
    )
