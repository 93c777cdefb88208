"""Joint velocities and accelerations from joint-state messages, one message at a time.

:class:`StreamingEstimator` keeps each joint's recent samples and, for every message, returns the
estimates that message completes: in ``causal`` mode at the newest sample, in ``fixed_lag`` mode
``lag`` seconds back. Two estimators: ``polyfit``, a local polynomial fit (centred in fixed-lag mode
with the default lag, then equal to the whole-recording estimate; one-sided in causal mode), and
``kalman``, a Kalman filter (causal) or fixed-lag smoother on a Gaussian-process motion model
(:mod:`.motion`), accurate at low latency; with the bank of models (the default), each model is a
candidate beside the local fits for the same delay, chosen per joint by its errors
(:mod:`.causal_choice`). An estimate is given only where the samples cover what the estimator needs
(:mod:`.coverage`). Each message's fields are checked by :mod:`.joint_messages` and its stamp by
:mod:`.timeline`; bad input never raises, it is dropped and logged (throttled).
"""

from __future__ import annotations

import logging
import math
from collections import deque
from collections.abc import Iterable, Sequence
from functools import partial

import numpy as np

from neforward_ros.errors import InputError
from neforward_ros.estimation import degree_choice, native_fit
from neforward_ros.estimation.adaptive import (
    FLOOR,
    GAMMA,
    NOISE_SAMPLES,
    DeviationPool,
    adaptive_fit,
    degree_fit,
    noise_reach,
)
from neforward_ros.estimation.causal_choice import DEGREES, LEAST_RECORD, ErrorScores, candidates, half_widths, usable
from neforward_ros.estimation.clock import SampleClock
from neforward_ros.estimation.coverage import uncovered
from neforward_ros.estimation.estimate import JointEstimate
from neforward_ros.estimation.fit import degrees, fit_window, local_difference
from neforward_ros.estimation.history import JointHistory
from neforward_ros.estimation.joint_messages import JointMessageReader, Sample
from neforward_ros.estimation.kalman_bank import LENGTH_SCALES, KalmanBank
from neforward_ros.estimation.settings import StreamSettings
from neforward_ros.estimation.timeline import RESTART, Timeline
from neforward_ros.logs import LogFunction, ThrottledLog
from neforward_ros.stamps import NS

STRAIN_MEMORY = 0.02
"""The weight of each new estimate in the consistency checks' averages (about the last 50)."""
STRAIN_TIME = 1.0
"""s: polyfit's strain share is over at least about this long (:meth:`StreamingEstimator._watch_windows`)."""
STRAIN_LIMIT = 0.5
"""polyfit: the share of estimates at the smallest window above which a joint is said to strain."""
REST_SPREAD = 2.0
"""polyfit: a window whose samples spread (standard deviation) at most this many times their noise
(read from their second differences) holds no motion: a joint at rest there, whose estimate is not
counted as strained (its noise against a motion of zero, and nothing a higher rate would change)."""
INNOVATION_LIMIT = 5.0
"""kalman: how far the normalised innovations may average from 1 (above or below) before it is said."""
MEMORY_EVERY = 16
"""kalman: samples between two keepings of what a restart starts from (the noise read, the weights)."""

BANK_GUARDS_EVERY_TARGET = True
"""kalman at a fixed lag: the bank's own estimate checks the chosen candidate's at every target (it is
worked out at every target anyway), not only where the candidates are kept for scoring: a move's start
between two checks went through unchecked (an arm's moves at 500 Hz: the steady 99th percentile of the
q'' error 6.4 rad/s^2, against 1.34 checked at every target; ``test_kalman_joined.py``)."""

CHECK_LEAPS = True
"""The chosen candidate's estimate is checked against the rule at once where, between the targets kept for
scoring, it leaves the rule's estimate at the last check by more than that check allows (a move starting
after a dwell, whose record chose a short window: at 1 kHz through 12 bits, one encoder step read as hundreds
of rad/s^2 at four targets in five; ``test_transients.py``)."""
HOLD_UNTIL_RECORD = True
"""The settings that choose by their candidates' record (polyfit causal, kalman): from a start, a joint has
no estimate until its record holds (:data:`~.causal_choice.LEAST_RECORD` scores, each made half a window after
its estimate: about 0.2 s more warm-up at 100 Hz, 0.15-0.2 s at 250 Hz-1 kHz). Until 2026-11-29 the adaptive
rule's estimate, or the bank's own, served meanwhile: at 100-250 Hz the worst error in the second after the
start was up to 16x the steady 99th percentile on 20 ms, 9.1x kalman causal, 7.7x polyfit causal
(``bench/bench_transients.py``; the rule for a short delay, and the bank's models near their prior, err that
much at low rates)."""
CARRY_RECORDS = True
"""The candidates' records outlive a restart (stamps back in time, a joint's samples apart by more than max_gap):
they say which window, degree or model suits the joint's motion, which a restart does not change; the
estimates waiting for their scores are dropped. Forgotten until 2026-11-29, when the bank's own estimate or
the rule's served until a new record held: up to 7.5x the steady 99th percentile in the second after a time
reset at 100 Hz (``bench/bench_transients.py``). Where the stamps are found to be write times the records
made on them are still forgotten (they scored fits on the wrong times)."""
CARRY_STAMPS_VERDICT = True
"""A restart's clock starts with the verdict before it that the stamps are the samples' own times
(:attr:`~.clock.SampleClock.on_stamps`): a driver stamps the same way after a time reset or a gap, and the
causal fits would take the stamps' spread as timing noise again until a check tells
(:attr:`~.clock.SampleClock.timing`)."""
NO_RECORD_BY_DEVIATION = True
"""kalman: a joint without a record and not in a start's warm-up (:data:`HOLD_UNTIL_RECORD`; its record
forgotten, or unfair) gets the bank's own estimate or the rule's for the same delay, whichever states the
smaller deviation (the bank's own alone until 2026-11-28, when it served from a start: its models were near
their prior, 79x the steady 99th percentile of the error at 100 Hz through 12 bits; ``test_transients.py``).
After a restart the bank's own serves: its models start from the weights learnt before the restart."""
MODELS_UNRANKED_BY_DEVIATION = True
"""kalman: where a joint's record holds but cannot rank every model of the bank yet (one has not converged from
its prior, or has been scored too little for a fair record: the 0.6 s model the last, 1.8 s after a start and
1.65 s after a time reset), the bank's own estimate serves where it states a smaller deviation than the chosen fit's
record (its root mean square error). The fits alone served there until 2026-11-29: on sums of sines at 100 Hz
through 20 bits the best fit's error is about 3x the 0.25 s model's, which is chosen once its record is fair,
0.8 s after a start, and the worst error in the second after a start or a time reset was up to 3.5x the steady
99th percentile on 20 ms (``bench/bench_transients.py``)."""
REFERENCE_CHOSEN = True
"""The centred estimate the causal candidates (and the bank's models) are scored against is the default's own:
each degree's rule and the finer fit, the degree chosen per joint by the reference's last second
(:mod:`.degree_choice`; a joint fitted on its velocities by their first derivative). Until 2026-12-02 it was
the adaptive rule's degree 6 fused with 4, whose bias on fast gaits at low rates is like the short-delay
fits': kalman 20 ms chose those over the bank's fastest model, up to 3.1x hindsight at 90 Hz through 15-17
bits where that model alone is 0.6x; on 54 gaits at 90-140 Hz, 18 over 1.5x before, 10 since (see the
estimators guide, "The candidates scored against the default's own estimate")."""
REFERENCE_RECORD = 0.25
"""s: the least span of the reference's record for its finer fit (the default's :data:`~.degree_choice.RECORD`,
0.75 s, for its own estimates). From a start the candidates' records are made against the first second's
references: with 0.75 s, on a gait at 500 Hz through 12 bits, the rule's degree 6 served as the reference
for 0.85 s and kalman 20 ms's worst error in the second after the start was 18 rad/s^2, 3.96x its steady
99th percentile (4.6; the first estimates' error as before the reference was chosen, whose p99 was 12.2);
with 0.25 s, 1.21x (``bench/bench_transients.py``)."""
REFERENCE_ACROSS_HOLES = True
"""The reference's degree choice keeps its finer fit across a gap in the joint states: its estimates are made only
where the samples cover the whole window (none on a gap's lopsided edges, which the default's
:data:`~.degree_choice.HOLE` is for), so a gap leaves nothing in its record to misread. Until 2026-12-02 the
hole kept the finer fit out of the reference for a second after a gap, and the candidates' scores were made
against the rule's choice alone: after a 0.3 s gap, gaits through 20 bits, kalman 20 ms's worst error in the
second after was 5.07x its steady 99th percentile at 1 kHz and 3.48x at 500 Hz; since, 2.27x and 1.51x
(``bench/bench_transients.py``)."""
BANK_HOLDS_ITS_OVERRULING = True
"""kalman, fixed lag: where the bank's own estimate overruled a joint's chosen candidate at the last target,
the candidate returns only where it agrees with the bank's within the deviation the bank stated over the last
half window (root mean square), not within a larger one the bank states at this target alone. Until
2026-11-29 one such target let a stale choice back: after a start, minimum-jerk moves at 1 kHz through 12
bits, the longest window (the start's dwell had chosen it) served 6-15.7 rad/s^2 off for 36 ms, where the
bank's own was 1-3 off (4.18x the steady 99th percentile; 1.91x since; ``bench/bench_transients.py``)."""
RECORD_OF_REST = True
"""The settings that choose by their candidates' record (polyfit causal, kalman): until a joint's record holds
:data:`~.causal_choice.LEAST_RECORD` scores of estimates whose samples up to their stamp changed (counted since the
start; kept through a restart), the rule's estimate serves it, or at a fixed lag the Kalman bank's own. Where the
readings do not change every candidate is exact, and the record ranks them by their floors alone: the least
noisy, the longest window of degree 2, which lags the first move's start, and the first scores of that move
can rank a short window that an encoder's rounding then throws off. Until 2026-11-29 the record chose there: on
minimum-jerk moves after the start's dwell the worst error in the second after the start was up to 5.9x the
steady 99th percentile (500 Hz through 20 bits: 15.7 rad/s^2 off, where the rule was within 4) and 4.5x (250 Hz
through 12 bits: a short window of degree 3, 56 rad/s^2 off stating 2.7), 1.7x and 1.2x since
(``bench/bench_transients.py``). Later moves start from a record that remembers the earlier ones."""

_REPEATS = "repeats"

__all__ = ["RESTART", "JointEstimate", "StreamSettings", "StreamingEstimator"]


class StreamingEstimator:
    """Joint velocities and accelerations from joint-state messages, one message at a time.

    Each joint keeps its own history, so partial messages (arm and gripper from different
    drivers) are fine: joints that always arrive together share a buffer and one fit. Every call
    to :meth:`update` returns the estimates that became available with that message: in causal
    mode, one for the message's stamp (when it is newer than any before); in fixed-lag mode, one
    for every earlier message stamp that is now ``lag`` old.

    Bad input never raises out of :meth:`update`; it is dropped and logged (throttled), by the
    rules of :mod:`.joint_messages` (names, lengths, non-finite values) and :mod:`.timeline` (stamps
    out of line, zero stamps, time resets); a repeated stamp is skipped; a gap longer than max_gap
    restarts that joint's history.

    Args:
        joint_names: the joints to estimate, in output order.
        wrap: per joint, True for a continuous joint whose positions wrap at +-pi.
        ignored_names: names that may appear in messages and are not estimated, without a warning
            (mimic joints, which follow their leader).
        settings: the estimator's options.
        log: ``log(level, message)``; the Python logger ``neforward_ros`` by default.
    """

    def __init__(
        self,
        joint_names: Sequence[str],
        *,
        wrap: Sequence[bool] | None = None,
        ignored_names: Iterable[str] = (),
        settings: StreamSettings | None = None,
        log: LogFunction | None = None,
    ) -> None:
        self.settings = settings if settings is not None else StreamSettings()
        self.joint_names = tuple(joint_names)
        if len(set(self.joint_names)) != len(self.joint_names):
            raise InputError("joint names must be unique")
        self._wrap = tuple(bool(w) for w in wrap) if wrap is not None else (False,) * len(self.joint_names)
        if len(self._wrap) != len(self.joint_names):
            raise InputError(f"wrap has {len(self._wrap)} entries for {len(self.joint_names)} joints")
        self._log = ThrottledLog(log)
        use_velocities = self.settings.velocity_source != "differentiate"
        self._reader = JointMessageReader(self.joint_names, ignored_names, self._log, use_velocities)
        self._groups: list[JointHistory] = []
        self._group_of: list[JointHistory | None] = [None] * len(self.joint_names)
        self._targets = 0
        self._lag_ns = round(self.settings.effective_lag * NS)
        self._gap_ns = round(self.settings.max_gap * NS)
        self._timeline = Timeline(len(self.joint_names), self._gap_ns, self._log)
        self._window_ns = round(self.settings.window * NS)
        self._support = self.settings.support
        self._hole_ns = self._support.ns()[2]
        self._kalman = self.settings.method == "kalman"
        self._keep_ns = round((self.settings.window + self.settings.effective_lag) * NS) + self._gap_ns
        self._pending: deque[int] = deque()
        # polyfit's adaptive windows: each estimate's stated deviations pool the last half window's
        self._pool = None
        if self.settings.method == "polyfit" and self.settings.adaptive:
            self._pool = DeviationPool(self.settings.window, len(self.joint_names))
        # the default (adaptive, fixed lag, no explicit order): each joint's degree chosen by the last
        # second's estimates (.degree_choice)
        self._degrees: degree_choice.DegreePool | None = None
        if self._pool is not None and self.settings.lower_degree is not None:
            self._degrees = degree_choice.DegreePool(len(self.joint_names))
        # polyfit's causal adaptive fits: the candidate chosen by its errors half a window ago (.causal_choice)
        self._scores: ErrorScores | None = None
        self._reference_degrees: degree_choice.DegreePool | None = None
        # every candidate's estimates at the target being estimated and their floors (see ErrorScores.score),
        # where kept for scoring (else None)
        self._candidates: np.ndarray | None = None
        self._overruled = np.zeros(len(self.joint_names), dtype=bool)  # the rule's estimate taken at the last check
        # per joint, how many scores its record holds that were made where its readings changed (RECORD_OF_REST)
        self._record_moved = np.zeros(len(self.joint_names))
        # the rule's squared deviations at the checks, exponentially weighted over half a window: sum, weight,
        # and when last added to (s; NaN: never)
        self._rule_spread = np.zeros((2, len(self.joint_names)))
        self._rule_checked = np.full(len(self.joint_names), np.nan)
        # the rule's estimate at the last check (NaN: none): an estimate between checks that leaves it by more
        # than the check allows is checked at once (see _chosen_fit)
        self._rule_last = np.full(len(self.joint_names), np.nan)
        # per joint, whether it has had no record since the stream started (HOLD_UNTIL_RECORD)
        self._recordless = np.ones(len(self.joint_names), dtype=bool)
        # per joint, whether a clock of a group it left had let estimates through (clock.HOLD_FOR_CLOCK)
        self._clock_released = np.zeros(len(self.joint_names), dtype=bool)
        # per joint, whether that clock had found the stamps to be the samples' times (SampleClock.timing)
        self._clock_on_stamps = np.zeros(len(self.joint_names), dtype=bool)
        chosen = self.settings.method == "polyfit" and self.settings.adaptive and self.settings.order is None
        # kalman with the bank: its models join the fits' candidates for the same delay, chosen alike
        self._joined = self.settings.method == "kalman" and self.settings.kalman.length_scale == 0
        self._models = len(LENGTH_SCALES) if self._joined else 0
        if (chosen and self._lag_ns == 0) or self._joined:  # (an explicit order: that degree alone, the rule's)
            half = self.settings.window / 2.0
            self._half_widths = half_widths(half)
            count = len(DEGREES) * len(self._half_widths) + self._models
            self._scores = ErrorScores(len(self.joint_names), count, half, round(half * NS))
            self._reference_support = StreamSettings(window=self.settings.window).support
            # the reference's own degree choice, as the default's (REFERENCE_CHOSEN): its record of the
            # reference's estimates, in their stamps' order
            if REFERENCE_CHOSEN:
                self._reference_degrees = degree_choice.DegreePool(
                    len(self.joint_names), record=REFERENCE_RECORD, holes=not REFERENCE_ACROSS_HOLES
                )
        self._intervals: deque[int] = deque(maxlen=8)  # the last stamp intervals, ns
        # Per joint, how hard the estimator strains (see _watch_windows, _watch_innovations).
        self._strain = np.zeros(len(self.joint_names))
        self._innovations = np.ones(len(self.joint_names))
        self._watched = np.zeros(len(self.joint_names), dtype=int)
        # kalman, per joint: the position and velocity noise variances as read (n, 2), and its models' last
        # log-weights (models, n); NaN where not known
        self._noise_memory = np.full((len(self.joint_names), 2), np.nan)
        self._score_memory: np.ndarray | None = None
        self._clock: int | None = None
        self._origin = 0
        self.segment = 0
        self.accepted: list[tuple[int, list[Sample]] | str] = []
        """The messages the last :meth:`update` used, in order: (stamp, samples), and :data:`RESTART`
        where the stream restarted (the momentum observer's raw samples)."""
        if (self.settings.method == "polyfit" and self.settings.adaptive) or self._joined:
            native_fit.FIT.get()  # the adaptive fit's C, compiled in a thread meanwhile (numpy serves until then)

    # -- input ------------------------------------------------------------------------------

    def update(
        self,
        stamp_ns: int,
        names: Sequence[str],
        positions: Sequence[float],
        velocities: Sequence[float] = (),
        efforts: Sequence[float] = (),
        *,
        receive_ns: int | None = None,
    ) -> list[JointEstimate]:
        """Add one joint-state message; return the estimates it completes (possibly none).

        Args:
            stamp_ns: header stamp, integer nanoseconds; 0 means "not set".
            names, positions, velocities, efforts: the message's fields (velocities and efforts may
                be empty).
            receive_ns: receive time, used when stamp_ns is 0.
        """
        self.accepted = []
        try:
            return self._update(int(stamp_ns), names, positions, velocities, efforts, receive_ns)
        except Exception as exc:
            self._log.every("internal", logging.ERROR, f"joint state dropped: {type(exc).__name__}: {exc}")
            return []

    def flush(self) -> list[JointEstimate]:
        """The stamps still waiting for their lag (end of a stream, or time going backwards), with no
        estimates: nothing will come after them, so their supports are never covered."""
        n = len(self.joint_names)
        return [
            JointEstimate(
                stamp, self.segment, *(np.full(n, np.nan) for _ in range(3)), self.ages(stamp), np.zeros(n, bool)
            )
            for stamp in self._drain()
        ]

    def reset(self, keep_timeline: bool = False) -> None:
        """Forget every history (a new stream starts)."""
        if not keep_timeline:
            self._timeline.reset()
        for group in self._groups:
            self._remember_clock(group, group.joints)
        self._groups = []
        self._group_of = [None] * len(self.joint_names)
        self._pending.clear()
        if self._pool is not None:
            self._pool.clear()
        for pool in (self._degrees, self._reference_degrees):
            if pool is not None:
                pool.clear()
        self._forget_scores(None, keep_record=CARRY_RECORDS)
        self._intervals.clear()
        self._clock = None

    def _tolerance(self) -> int:
        """How much earlier than ``lag`` a fixed-lag estimate may leave: half the shortest of the last
        stamp intervals. Stamps jitter, so the sample nominally ``lag`` later often comes a little
        early; waiting for the one after would delay the estimate by a whole period, and then let
        two leave together. The next sample comes later than ``lag`` anyway (it is more than half an
        interval away), so the fit's window holds exactly the samples it would hold then."""
        return min(self._intervals) // 2 if self._lag_ns and self._intervals else 0

    def ages(self, now_ns: int | None = None) -> np.ndarray:
        """Seconds since each joint's newest sample (at ``now_ns``, default the newest stamp); inf if none."""
        now = self._clock if now_ns is None else now_ns
        return np.array(
            [(now - g.newest_stamp) / NS if g is not None and now is not None else np.inf for g in self._group_of]
        )

    def _update(
        self,
        stamp: int,
        names: Sequence[str],
        positions: Sequence[float],
        velocities: Sequence[float],
        efforts: Sequence[float],
        receive_ns: int | None,
    ) -> list[JointEstimate]:
        used = self._timeline.stamp(stamp, receive_ns)
        if used is None:
            return []
        samples = self._reader.read(names, positions, velocities, efforts)
        if not samples:
            return []
        out: list[JointEstimate] = []
        for step in self._timeline.offer(used, [j for j, _, _, _ in samples], samples):
            self.accepted.append(step)
            if step is RESTART:
                out.extend(self.flush())
                self.reset(keep_timeline=True)
                self.segment += 1
            else:
                out.extend(self._step(*step))
        return out

    def _step(self, stamp: int, samples: list[Sample]) -> list[JointEstimate]:
        """One message's samples, in line with the stream: added, and the estimates they complete."""
        if self._clock is None:
            self._clock = stamp
            self._origin = stamp
            new_target = True
        else:
            new_target = stamp > self._clock
        added = self._add(stamp, samples)
        if not added:
            return []
        if not new_target:
            return []
        if self._pending or self._targets:
            self._intervals.append(stamp - self._clock)
        self._clock = stamp
        self._pending.append(stamp)
        if added is _REPEATS:
            return []  # a repeated reading is a target, and tells nothing new about the ones before it
        until = stamp - self._lag_ns + self._tolerance()
        runs = [group.run[0][0] for group in self._groups if group.run]
        if runs:  # another group's run of repeats, not yet told from a stop: no estimate whose fit reaches it
            until = min(until, min(runs) - self._lag_ns - 1)
        out = [self._estimate(target) for target in self._drain(until)]
        self._targets += 1
        if self._targets % 32 == 0:  # forget old samples now and then
            for group in self._groups:
                group.drop_before(stamp - self._keep_ns, NOISE_SAMPLES + self.settings.degree + 2)
        return out

    def _add(self, stamp: int, samples: list[tuple[int, float, float, float]]) -> bool | str:
        """Append one message's samples to their groups; returns whether any was added (:data:`_REPEATS`
        when the message's samples were all repeated readings, left out of the fits).

        A repeated stamp is skipped. A joint whose previous sample is newer, or more than max_gap
        older, restarts its history. Joints of a group that arrive without the rest of it move,
        with their history, into a group of their own.
        """
        by_group: dict[int, tuple[JointHistory, dict[int, tuple[float, float, float]]]] = {}
        fresh: dict[int, tuple[float, float, float]] = {}
        restarted: list[str] = []
        for j, position, velocity, effort in samples:
            group = self._group_of[j]
            if self.settings.velocity_source == "message" and math.isnan(velocity):
                self._log.once(
                    ("no-velocity", j),
                    logging.WARNING,
                    f"velocity_source is 'message' but joint {self.joint_names[j]!r} has no velocity: differentiating",
                )
            if group is not None:
                newest = group.newest_stamp
                if stamp == newest:
                    continue
                if stamp < newest:
                    reason = "sample older than the previous one"
                elif stamp - newest > self._gap_ns:
                    reason = f"no sample for {(stamp - newest) / NS:.3f} s, more than max_gap {self.settings.max_gap} s"
                else:
                    if self._wrap[j]:
                        previous = group.newest_position(j)
                        position = previous + (position - previous + math.pi) % (2.0 * math.pi) - math.pi
                    by_group.setdefault(id(group), (group, {}))[1][j] = (position, velocity, effort)
                    continue
                restarted.append(f"{self.joint_names[j]!r} ({reason})")
                self._forget(group, [j])
            fresh[j] = (position, velocity, effort)
        repeats = 0
        if restarted:
            self._log.every("restart", logging.WARNING, f"history restarted for joint {', '.join(restarted)}")
        for group, values in by_group.values():
            if len(values) < len(group.joints):
                group = self._split(group, [j for j in group.joints if j in values])
            sample = [list(x) for x in zip(*(values[j] for j in group.joints), strict=True)]  # q, v, effort
            if group.repeats(stamp, *sample):
                repeats += 1  # a driver's repeated reading (:mod:`.repeats`): no sample; its stamp is a target
                continue
            written = group.written
            group.append(stamp, *sample, self._hole_ns)
            if group.written and not written:  # its samples now on the recovered clock: the records of the
                self._forget_scores(group.joints)  # causal candidates and of the default's degrees were made on
                for pool in (self._degrees, self._reference_degrees):  # the stamps'
                    if pool is not None:
                        pool.forget(group.joints)
                if group.clock.released_at == stamp:  # found as the start waited for the clock: the start
                    self._recordless[group.joints] = True  # waits for a record on the recovered clock too
            self._watch_innovations(group)
        if fresh:
            released = bool(self._clock_released[sorted(fresh)].all())  # (a restart: clock.HOLD_FOR_CLOCK)
            clock, track = SampleClock(released, bool(self._clock_on_stamps[sorted(fresh)].all())), None
            if self._kalman:  # what was read of the noise before a restart serves until it is read again
                known = self._noise_memory[sorted(fresh)]
                noise = tuple(float(known[:, i].max()) if np.isfinite(known[:, i]).all() else None for i in range(2))
                memory = self._score_memory
                seeded = None if memory is None else memory[:, sorted(fresh)]
                if seeded is not None and not np.isfinite(seeded).all():
                    seeded = None
                track = KalmanBank(self.settings.kalman, smooth=self._lag_ns > 0, known_noise=noise,
                                   known_scores=seeded, clock=clock)  # fmt: skip
                clock = None  # the fits' samples on the clock recovered from the stamps where those are write
                # times; the bank keeps its own
            group = JointHistory(sorted(fresh), self._origin, track=track, clock=clock)
            self._groups.append(group)
            for j in group.joints:
                self._group_of[j] = group
            columns = [fresh[j] for j in group.joints]
            group.append(stamp, *(list(x) for x in zip(*columns, strict=True)), self._hole_ns)
        if repeats and repeats == len(by_group) and not fresh:
            return _REPEATS
        return bool(by_group or fresh)

    def _forget_scores(self, joints: list[int] | None, keep_record: bool = False) -> None:
        """The causal candidates' scores and the rule's checks of these joints (all: None), forgotten; with
        ``keep_record``, the scores made are kept (a restart: :data:`CARRY_RECORDS`), those waiting dropped."""
        if self._scores is None:
            return
        self._scores.clear(joints, keep_record)
        columns = slice(None) if joints is None else joints
        self._overruled[columns] = False
        if not keep_record:
            self._rule_spread[:, columns] = 0.0
            self._record_moved[columns] = 0.0
        self._rule_checked[columns] = np.nan
        self._rule_last[columns] = np.nan

    def _remembered_spread(self, joints: np.ndarray) -> np.ndarray:
        """The rule's deviation at these joints' checks, root mean square over about the last half window
        (rad/s^2 or m/s^2; 0 where never checked)."""
        return np.sqrt(self._rule_spread[0, joints] / np.maximum(self._rule_spread[1, joints], 1e-300))

    def _forget(self, group: JointHistory, joints: list[int]) -> None:
        self._remember_clock(group, joints)
        group.remove(joints)
        self._forget_scores(joints, keep_record=CARRY_RECORDS)
        for j in joints:
            self._group_of[j] = None
        if not group.joints:
            self._groups.remove(group)

    def _remember_clock(self, group: JointHistory, joints: list[int]) -> None:
        """As these joints leave the group (a restart): whether its clock had let estimates through, which
        their next group's clock starts with (clock.HOLD_FOR_CLOCK), and whether it had found the stamps to be
        the samples' times (a driver stamps the same way after a time reset or a gap: SampleClock.timing)."""
        clock = group.sample_clock
        if clock is not None and clock.released_at is not None:
            self._clock_released[joints] = True
        if clock is not None and CARRY_STAMPS_VERDICT:
            self._clock_on_stamps[joints] = clock.on_stamps

    def _split(self, group: JointHistory, joints: list[int]) -> JointHistory:
        moved = group.split(joints)
        self._groups.append(moved)
        for j in joints:
            self._group_of[j] = moved
        return moved

    def _drain(self, until_ns: int | None = None) -> list[int]:
        targets = []
        while self._pending and (until_ns is None or self._pending[0] <= until_ns):
            targets.append(self._pending.popleft())
        return targets

    # -- estimation -------------------------------------------------------------------------

    def _estimate(self, target: int) -> JointEstimate:
        n = len(self.joint_names)
        state = np.full((n, 5), np.nan)  # position, velocity, acceleration, effort, acceleration's std
        ages = np.full(n, np.inf)
        if self._degrees is not None:
            self._degrees.start(target)
        if self._scores is not None:
            self._score(target)
            keeping = self._scores.wants(target)
            count = len(DEGREES) * len(self._half_widths) + self._models
            self._candidates = np.full((2, count, n), np.nan) if keeping else None
        for group in self._groups:
            self._estimate_group(target, group, state, ages)
            if group.track is not None:
                group.track.forget_before(target)
        if self._candidates is not None:
            self._scores.keep(target, *self._candidates)
        ready = np.isfinite(state[:, :3]).all(axis=1)
        if not ready.all():
            state[~ready, :3] = np.nan
            state[~ready, 4] = np.nan
        if self._pool is not None:
            state[:, 4] = self._pool.state(target, state[:, 4])
        return JointEstimate(
            target, self.segment, state[:, 0], state[:, 1], state[:, 2], ages, ready, state[:, 3], state[:, 4]
        )

    def _estimate_group(self, target: int, group: JointHistory, state: np.ndarray, ages: np.ndarray) -> None:
        """Fill state (n, 3) and ages (n,) at the target for one group's joints, if its samples cover
        the support there (else say once why, and leave them NaN).

        Only the samples of the fit's window are touched, however long the kept history is. polyfit:
        joints whose window has a velocity in every sample are fitted on velocities (the acceleration
        is their derivative); the others on positions. At a sample's own stamp the sample's position,
        and its velocity when the message gave one, are used as they are.
        """
        members = group.joints
        stamps = group.stamps
        k = int(stamps.searchsorted(target, side="right")) - 1
        if k < 0:
            return
        age_ns = target - int(stamps[k])
        ages[members] = age_ns / NS
        if age_ns > self._gap_ns:
            return  # stale: not ready
        if group.any_effort:
            state[members, 3] = group.effort_at(k, target)
        reason = uncovered(stamps, target, self._support, group.holes, group.end_slack(), group.left_out)
        if reason is not None:
            self._say_why(group, reason)
            return
        group.warming = False
        exact = age_ns == 0  # the target is a sample of this group: its own position is used as it is
        if group.track is not None and self._joined and not group.track.written:
            # the bank's models among the fits' candidates (not where the bank found the stamps to be write
            # times: it runs on the clock it recovered, and fits on the stamps would take their delays for noise)
            position, velocity, acceleration, spread = self._fit(target, group, exact)
            state[members, 4] = spread
        elif group.track is not None:
            position, velocity, acceleration, state[members, 4] = self._bank_own(group, target)
        else:
            position, velocity, acceleration, spread = self._fit(target, group, exact)
            state[members, 4] = spread
        if exact:
            position = group.positions[k]
            given = group.velocities[k]
            velocity = np.where(np.isfinite(given), given, velocity)  # a message velocity is kept as given
        if self._waits_for_clock(group, target):  # worked out all the same: the candidates' record is made meanwhile
            state[members, 4] = np.nan
            return
        state[members, 0], state[members, 1], state[members, 2] = position, velocity, acceleration

    def _waits_for_clock(self, group: JointHistory, target: int) -> bool:
        """Whether the group's joints wait for its clock at this target (:data:`~.clock.HOLD_FOR_CLOCK`: the
        targets before the sample at which the clock let estimates through, less half the lag; said once,
        throttled)."""
        clock = group.sample_clock
        if clock is None or not clock.holds_estimates(target + self._lag_ns // 2):
            return False
        self._log.every(
            ("clock", "warm-up"),
            logging.INFO,
            f"no estimate yet for joint(s) {', '.join(self.joint_names[j] for j in group.joints)}: their stamps "
            "are irregular, and from a start the estimator waits until it can tell whether they are the samples' "
            "times or the times the driver wrote them (40-128 samples)",
        )
        return True

    def _fit(
        self, target: int, group: JointHistory, exact: bool
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """polyfit or difference over the support's samples (covered), or, for the Kalman bank, the fits
        for the same delay with the bank's models among their candidates: position, velocity,
        acceleration, and the acceleration's standard deviation (NaN where not known)."""
        settings = self.settings
        lead_ns = self._lag_ns
        times, positions, velocities, by_velocity, before = self._samples(
            group, target + lead_ns - self._window_ns, target + lead_ns
        )
        fitted_velocities = bool(by_velocity.any())
        target_s = group.time_of(target)
        if fitted_velocities and exact:
            # One column per joint: its velocities where it has them all, else its positions.
            values = np.where(by_velocity, velocities, positions)
        elif fitted_velocities:  # positions are fitted too, to be estimated between samples
            values = np.concatenate([positions, velocities[:, by_velocity]], axis=1)
        else:
            values = positions
        m = len(group.joints)
        if settings.method == "difference":  # on the window's samples alone, as the fixed window below
            fitted, d1, d2 = local_difference(times[before:], values[before:], target_s, lead_ns / NS)
            return _per_joint((fitted, d1, d2, np.full(values.shape[1], np.nan)), m, by_velocity, exact)
        if not settings.adaptive and group.track is None:  # (polyfit's option: the joined bank's fits adapt)
            half = settings.window / 2.0  # on exactly the window's samples
            fitted, d1, d2 = fit_window(times[before:], values[before:], target_s, half, settings.degree)
            return _per_joint((fitted, d1, d2, np.full(values.shape[1], np.nan)), m, by_velocity, exact)
        derivative = np.full(values.shape[1], 2)
        if fitted_velocities and exact:
            derivative = np.where(by_velocity, 1, 2)
        elif fitted_velocities:
            derivative[m:] = 1
        half, lead = settings.window / 2.0, lead_ns / NS
        if group.track is not None and values.shape[1] != m:  # (joined, between its samples: the bank's own)
            return self._bank_own(group, target)
        if self._scores is not None and values.shape[1] == m:  # a column per joint: scored per joint
            models = bank = None
            if group.track is not None:  # the bank's models among the candidates; its own estimate until a record
                models, bank = self._model_candidates(group, target, values, derivative)
            chosen = self._chosen_fit(group, times, values, target_s, derivative, models, bank, lead)
            got = _per_joint(chosen, m, by_velocity, exact)
        elif self._degrees is not None:  # each degree's rule; the degree chosen per joint by the recent estimates
            got = self._chosen_degrees(self._degrees, group, times, values, target_s, lead, derivative, by_velocity,
                                       exact)  # fmt: skip
        else:
            fit = adaptive_fit(times, values, target_s, half, settings.degree, lead, derivative, settings.lower_degree,
                               _timing(group, lead))  # fmt: skip
            got = _per_joint(fit, m, by_velocity, exact)
        if group.track is None:  # (the bank's joints are watched by their innovations)
            strained = np.array(got[4], dtype=bool)
            if strained.any():  # (a joint at rest is not: looked at only where it counts)
                strained &= ~at_rest(values[:, :m])
            self._watch_windows(group, strained)
        return got[0], got[1], got[2], got[3]

    def _chosen_degrees(
        self,
        pool: degree_choice.DegreePool,
        group: JointHistory,
        times: np.ndarray,
        values: np.ndarray,
        target_s: float,
        lead: float,
        derivative: np.ndarray,
        by_velocity: np.ndarray,
        exact: bool,
    ) -> tuple[np.ndarray, ...]:
        """The default's fit (:mod:`.degree_choice`): each degree's rule and the finer fit over the window's
        samples, the degree chosen per joint by ``pool``'s record of the recent estimates. The group's joints'
        position, velocity, acceleration, the standard deviation to state with it, and whether its rule
        strained (each (m,); the columns as for :func:`_per_joint`)."""
        m = len(group.joints)
        fits = degree_fit(times, values, target_s, self.settings.window / 2.0, degree_choice.DEGREES, lead,
                          derivative, finer=degree_choice.FINER)  # fmt: skip
        options = _per_joint(fits, m, by_velocity, exact)  # each (D, m)
        chosen, std = pool.choose(np.asarray(group.joints), options[2], options[3], *options[5:])
        got = np.stack(options[:5])[:, chosen, np.arange(m)]  # each entry at each joint's chosen degree
        return (*got[:3], std, got[4] > 0.5)

    def _model_candidates(
        self, group: JointHistory, target: int, values: np.ndarray, derivative: np.ndarray
    ) -> tuple[tuple[np.ndarray, ...], tuple[np.ndarray, ...]]:
        """The bank's models as candidates at ``target``, in the columns of ``values`` (one per joint: its
        positions, or where ``derivative`` is 1 its velocities): each model's value, first and second
        derivative of the column, its estimate of q'' and that estimate's floor (models, m) each: the
        model's variance of q'' for the least noise (its variance scaled from the noise it reads to
        :data:`~.adaptive.FLOOR` of the position, as the fits' floors are). A model that has not yet
        converged from its prior (:meth:`~.kalman_bank.KalmanBank.converged`) gives no estimate: its
        start's errors would weigh on its record for a second after. Then the bank's own estimate (its
        models mixed as :meth:`~.kalman_bank.KalmanBank.estimate` mixes them) in the same columns: value,
        first and second derivative, q'' standard deviation (scaled up by the recent innovations) and
        False for "strained" (m,) each."""
        bank = group.track
        states, variances, mixture, spread = bank.estimates(target)  # (M, 3, m), (M,), (3, m), (m,)
        by_velocity = derivative == 1
        value, first, second = _columns(states, by_velocity)
        noise = np.where(by_velocity, bank.track._velocity_noise, bank.track._noise)
        least = FLOOR * np.maximum(np.abs(values[-1]), 1.0)
        floors = variances[:, None] * least * least / np.maximum(noise, 1e-300)
        estimates = np.where(bank.converged(target)[:, None], states[:, 2], np.nan)
        std = self._matched(group, spread)
        own = (*_columns(mixture, by_velocity), std, np.zeros(len(std), dtype=bool))
        return (value, first, second, estimates, floors), own

    def _bank_own(self, group: JointHistory, target: int) -> tuple[np.ndarray, ...]:
        """The bank's own estimate at the target: position, velocity, acceleration and the acceleration's
        standard deviation (m,) each (:meth:`_matched`)."""
        (position, velocity, acceleration), spread = group.track.estimate(target)
        return position, velocity, acceleration, self._matched(group, spread)

    def _matched(self, group: JointHistory, spread: np.ndarray) -> np.ndarray:
        """The bank's stated deviation: its models' variance, scaled up by how much larger than they expect
        the recent innovations are (covariance matching: a noise read too low, or a model that lags)."""
        return spread * np.sqrt(np.maximum(self._innovations[group.joints], 1.0))

    def _chosen_fit(
        self,
        group: JointHistory,
        times: np.ndarray,
        values: np.ndarray,
        target_s: float,
        derivative: np.ndarray,
        models: tuple[np.ndarray, ...] | None = None,
        bank: tuple[np.ndarray, ...] | None = None,
        lead: float = 0.0,
    ) -> tuple[np.ndarray, ...]:
        """The fit of each joint's candidate with the smallest recent error (:mod:`.causal_choice`; causal,
        or reaching ``lead`` past the target), the adaptive rule's where a joint has no record yet: value,
        first and second derivative, the
        estimate's standard deviation and whether it took the smallest window its degree allows (m,).
        ``models``: the Kalman bank's models as further candidates, after the fits (see
        :meth:`_model_candidates`); ``bank``: the bank's own estimate, which at a fixed lag (``lead``, s, the
        windows reach past the target; 0: causal) checks the chosen estimate at every target in the rule's
        place, and serves a joint without a record where it states a smaller deviation than the rule's for
        the same delay."""
        joints = np.asarray(group.joints)
        fits = len(DEGREES) * len(self._half_widths)
        if self._candidates is not None:  # every candidate, to be scored
            value, d1, d2, estimates, variance = candidates(times, values, target_s, self._half_widths, derivative,
                                                            lead=lead)  # fmt: skip
            least = FLOOR * np.maximum(np.abs(values[-1]), 1.0)  # the least noise: adaptive.accel_std's floor
            self._candidates[:, :fits, joints] = estimates, variance * least * least
            if models is not None:
                self._candidates[:, fits:, joints] = models[3], models[4]
            available = np.isfinite(self._candidates[0][:, joints])
            chosen, error = self._scores.choose(available, joints)
        else:  # only the chosen ones
            available = usable(times, target_s, self._half_widths, lead)[:, None]
            if models is not None:  # the fits' rows (the same for every joint), then the models'
                both = np.empty((fits + len(models[3]), len(joints)), dtype=bool)
                both[:fits] = available
                np.isfinite(models[3], out=both[fits:])
                available = both
            chosen, error = self._scores.choose(available, joints)
            only = np.array(sorted({c for c in chosen.tolist() if 0 <= c < fits}), dtype=np.intp)
            value, d1, d2, _, _ = candidates(times, values, target_s, self._half_widths, derivative, only, lead)
        if models is not None:  # the fits' rows, then the models'
            value, d1, d2 = (np.concatenate([a[:fits], b]) for a, b in zip((value, d1, d2), models[:3], strict=True))
        known = chosen >= 0
        columns = np.arange(len(joints))
        pick = np.maximum(chosen, 0)
        fitted, first, second = value[pick, columns], d1[pick, columns], d2[pick, columns]
        # strained: the smallest window of its degree that the samples allow (the next candidate is the next
        # degree's, or not usable)
        after = np.minimum(pick + 1, len(available) - 1)
        following = available[after, columns] if available.shape[1] > 1 else available[after, 0]
        levels = len(self._half_widths)
        smallest = ((pick % levels == levels - 1) | ~following) & (pick < fits)
        mine = (fitted, first, second, error, smallest)
        ours = np.where(derivative == 2, second, first)
        known &= np.isfinite(ours)  # (a candidate whose normal equations proved singular gives none)
        # The rule's where a joint has no record, or where the chosen candidate's estimate leaves the rule's
        # interval (the motion changed since the record was made: a move starts after a dwell). Checked at
        # the estimates kept for scoring (every one up to 200 Hz, every fifth at 1 kHz) and, once a joint's
        # check failed, at every estimate until it holds again; against the Kalman bank's own estimate at a
        # fixed lag, at every estimate (BANK_GUARDS_EVERY_TARGET).
        guarded = BANK_GUARDS_EVERY_TARGET and bank is not None and lead > 0.0
        if RECORD_OF_REST:  # a record made while the readings did not change cannot rank the candidates
            known &= self._record_moved[joints] >= LEAST_RECORD
        if self._candidates is None and known.all() and not self._overruled[joints].any() and not guarded:
            # between checks: unchecked unless the estimate left the last check's rule estimate by more than
            # that check would allow now (a move starting after a dwell, whose record chose a short window:
            # at 1 kHz through 12 bits, an encoder step read as hundreds of rad/s^2 four targets in five)
            remembered = self._remembered_spread(joints)
            leaps = CHECK_LEAPS and (np.abs(ours - self._rule_last[joints]) > GAMMA * np.hypot(remembered, error)).any()
            if not leaps:
                return mine
        if guarded:
            rule = bank
        else:
            rule = adaptive_fit(times, values, target_s, self.settings.window / 2.0, self.settings.degree, 0.0,
                                derivative, timing=_timing(group, 0.0))  # fmt: skip
        theirs = np.where(derivative == 2, rule[2], rule[1])
        self._rule_last[joints] = theirs
        # the rule's deviation, or where larger its root mean square over the last half window's checks (one
        # estimate's falls short of the rule's errors on a coarse encoder, where they come and go)
        since = target_s - self._rule_checked[joints]
        decay = np.where(np.isfinite(since), np.exp(-since / (0.5 * self.settings.window)), 1.0)
        remembered = decay * self._rule_spread[:, joints]
        remembered[0] += rule[3] ** 2
        remembered[1] += 1.0
        self._rule_spread[:, joints] = remembered
        self._rule_checked[joints] = target_s
        spread = self._remembered_spread(joints)
        # (the deviation the rule states at this target, where larger, but not for a return to a candidate
        # the bank overruled: BANK_HOLDS_ITS_OVERRULING)
        lenient = ~self._overruled[joints] if guarded and BANK_HOLDS_ITS_OVERRULING else True
        spread = np.where(lenient, np.fmax(rule[3], spread), spread)
        gap = ours - theirs
        agree = np.abs(gap) <= GAMMA * np.hypot(spread, error)
        self._overruled[joints] = known & ~agree
        known &= agree
        if guarded:  # the deviation stated with the chosen estimate is at least the part of its distance
            # from the bank's that the bank's own deviation does not explain (their errors independent):
            # the record is of targets where the samples came steadily, and after a gap (a writer's burst)
            # a model the record trusts can be 40 of its recorded deviations off, well within the check
            mine = (*mine[:3], np.fmax(error, np.sqrt(np.maximum(gap * gap - spread * spread, 0.0))), mine[4])
        if bank is not None and (chosen < 0).any():  # no record: from a start, the bank's own or the rule's
            # (for the same delay), whichever states the smaller deviation (the bank's models are still near
            # their prior: at 100 Hz through 12 bits, 1.5 Hz sines, its own was 264 rad/s^2 off for the
            # first 0.1 s, stating 70; the rule's about 4 off, stating 4); after a restart, the bank's own
            served = bank
            if NO_RECORD_BY_DEVIATION and group.track.known_scores is None:  # (known: a restart's)
                fallback = rule if lead == 0.0 else adaptive_fit(times, values, target_s, self.settings.window / 2.0,
                                                                 self.settings.degree, lead, derivative)  # fmt: skip
                own = ~(fallback[3] < bank[3])
                served = tuple(np.where(own, a, b) for a, b in zip(bank, fallback, strict=True))
            rule = tuple(np.where(chosen < 0, a, b) for a, b in zip(served, rule, strict=True))
        out = tuple(np.where(known, a, b) for a, b in zip(mine, rule, strict=True))
        if MODELS_UNRANKED_BY_DEVIATION and bank is not None:  # a record that cannot rank the bank's models yet
            unranked = (chosen >= 0) & ~self._scores.ranked(slice(fits, None), available, joints).all(axis=0)
            own = unranked & (bank[3] < error)  # the bank's own, where it states less than the chosen's record
            if own.any():
                out = tuple(np.where(own, a, b) for a, b in zip(bank, out, strict=True))
        held = self._recordless[joints] & (chosen < 0)  # a start's warm-up until the record holds
        self._recordless[joints] = held
        if HOLD_UNTIL_RECORD and held.any():
            self._log.every(
                ("record", "warm-up"),
                logging.INFO,
                f"no estimate yet for joint(s) {', '.join(self.joint_names[j] for j in joints[held])}: from a "
                "start, the estimator waits until its candidates' record holds (each estimate scored half a "
                "window later; about 0.2 s)",
            )
            out = (*(np.where(held, np.nan, a) for a in out[:4]), out[4])
        return out

    def _score(self, now: int) -> None:
        """Score the candidates' estimates that are now half a window old against the centred fit there."""
        for stamp, estimates, floors in self._scores.due(now):
            reference = np.full(len(self.joint_names), np.nan)
            if self._reference_degrees is not None:
                self._reference_degrees.start(stamp)
            for group in self._groups:
                reference[group.joints], changed = self._reference(stamp, group)
                self._record_moved[group.joints] += changed
            self._scores.score(stamp, estimates, floors, reference)

    def _reference(self, stamp: int, group: JointHistory) -> tuple[np.ndarray, np.ndarray]:
        """The default setting's centred estimate of q'' at ``stamp`` for the group's joints (NaN where its
        samples do not cover it), the reference the causal candidates are scored against; and whether each
        joint's readings changed within the window's half up to ``stamp`` (False where not covered)."""
        stamps = group.stamps
        support = self._reference_support
        if uncovered(stamps, stamp, support, group.holes, group.end_slack(), group.left_out) is not None:
            return np.full(len(group.joints), np.nan), np.zeros(len(group.joints), dtype=bool)
        half = self.settings.window / 2.0
        half_ns = round(half * NS)
        times, positions, velocities, by_velocity, before = self._samples(group, stamp - half_ns, stamp + half_ns)
        values = np.where(by_velocity, velocities, positions)
        derivative = np.where(by_velocity, 1, 2)
        at = group.time_of(stamp)
        if self._reference_degrees is not None:  # the default's own fit, its degrees chosen by their own record
            pool = self._reference_degrees
            acceleration = self._chosen_degrees(pool, group, times, values, at, half, derivative, by_velocity, True)[2]
        else:
            order, lower = degrees(None, True, False)
            _, d1, d2, _, _ = adaptive_fit(times, values, at, half, order, half, derivative, lower)
            acceleration = np.where(by_velocity, d1, d2)
        upto = before + int(times[before:].searchsorted(at, side="right"))  # the estimate's side
        changed = (values[before:upto] != values[before]).any(axis=0)
        return acceleration, changed

    @staticmethod
    def _samples(group: JointHistory, first_ns: int, last_ns: int) -> tuple[np.ndarray, ...]:
        """The group's samples stamped in [first_ns, last_ns], and before them those the adaptive fits
        also read the white noise from where there are fewer than :data:`~.adaptive.NOISE_SAMPLES`
        (:func:`~.adaptive.noise_reach`; none where a joint fitted on its velocities lacks one there):
        times (s from the segment's origin), positions and velocities, which joints are fitted on
        their velocities (those with a velocity in every sample of [first_ns, last_ns], when every
        sample since has them), and how many samples come before first_ns (only the adaptive fits,
        which choose their windows by time, take them)."""
        stamps = group.stamps
        lo = int(stamps.searchsorted(first_ns, side="left"))
        hi = int(stamps.searchsorted(last_ns, side="right"))
        by_velocity = np.zeros(len(group.joints), dtype=bool)
        if group.velocities_everywhere_after(lo):
            by_velocity = np.isfinite(group.velocities[lo:hi]).all(axis=0)
        first = noise_reach(lo, hi)
        if first < lo and by_velocity.any() and not np.isfinite(group.velocities[first:lo, by_velocity]).all():
            first = lo
        return group.seconds[first:hi], group.positions[first:hi], group.velocities[first:hi], by_velocity, lo - first

    # -- consistency --------------------------------------------------------------------------

    def _watch_windows(self, group: JointHistory, smallest: np.ndarray) -> None:
        """polyfit: the share of recent estimates (about the last 50, or the last :data:`STRAIN_TIME`
        where that holds more) that took the smallest window the samples allow; most of them means the
        motion changes as fast as the samples can show, and the estimate may be off by more than its
        stated uncertainty. Said per joint, throttled. (A move's start or end strains a few tens of
        milliseconds: at 800 Hz that is 50 estimates, and no reason to raise the rate.)"""
        joints = np.asarray(group.joints)
        weight = STRAIN_MEMORY
        if len(group) > 8:
            weight = min(weight, (int(group.stamps[-1]) - int(group.stamps[-9])) / (8 * NS * STRAIN_TIME))
        self._strain[joints] = (1.0 - weight) * self._strain[joints] + weight * smallest
        self._watched[joints] += 1
        for j in joints[(self._strain[joints] > STRAIN_LIMIT) & (self._watched[joints] > 2 / STRAIN_MEMORY)]:
            self._log.every(("estimate-fit", int(j)), logging.WARNING, partial(self._strained, group, int(j)))

    def _strained(self, group: JointHistory, j: int) -> str:
        interval = float(np.median(np.diff(group.stamps[-9:]))) / NS if len(group) > 8 else float("nan")
        return (
            f"joint {self.joint_names[j]!r}: {self._strain[j]:.0%} of its recent estimates strained (the smallest "
            f"window its samples allow, or samples that vary beyond a smooth motion; a sample every "
            f"{interval * 1e3:.3g} ms): its motion changes about as fast as the joint states can show it, or their "
            "noise is large, and its acceleration may be off by more than its stated uncertainty; raise the "
            "joint-state rate (or, for less delay, estimator.method kalman)"
        )

    def _watch_innovations(self, group: JointHistory) -> None:
        """kalman: each joint's normalised innovations (about the last 50 samples), 1 on average
        when the model fits the motion and the noise. Far above, the model lags the motion (its
        length scale too long, the noise set too low); far below, it smooths less than it could.
        Said per joint, throttled, with the parameter that would fit; where the bank's models join the
        local fits' candidates (``_joined``), a lagging bank needs no fix: said once, as information."""
        track = group.track
        if track is None:
            return
        nis = track.nis
        if len(nis) != len(group.joints):
            return
        joints = np.asarray(group.joints)
        # what a restart starts from (it changes slowly: kept every MEMORY_EVERY samples)
        if self._watched[joints[0]] % MEMORY_EVERY == 0:
            self._remember(track, joints)
        innovations = (1.0 - STRAIN_MEMORY) * self._innovations[joints] + STRAIN_MEMORY * nis
        self._innovations[joints] = innovations
        self._watched[joints] += 1
        settings = self.settings.kalman
        off = (innovations > INNOVATION_LIMIT) | ((innovations < 1.0 / INNOVATION_LIMIT) & bool(settings.noise))
        for j in joints[off & (self._watched[joints] > 2 / STRAIN_MEMORY)]:
            ratio = float(self._innovations[j])
            if ratio > INNOVATION_LIMIT and self._joined and not track.written and not settings.noise:
                # nothing to fix: the local fits among the candidates serve where the models lag
                self._log.once(
                    ("estimate-fit", int(j)),
                    logging.INFO,
                    f"joint {self.joint_names[j]!r}: the kalman bank's fastest model ({min(LENGTH_SCALES):g} s) "
                    "lags this motion; the local polynomial fits among its candidates, with the same delay, "
                    "serve where they follow it better",
                )
                continue
            if ratio > INNOVATION_LIMIT:
                scale = settings.length_scale or min(LENGTH_SCALES)
                fix = (
                    f"set estimator.kalman.length_scale below its {scale:g} s (about 0.65 / the motion's highest "
                    "frequency, Hz), or estimator.kalman.noise to the encoder's noise"
                    if settings.length_scale or settings.noise
                    else f"even its fastest model ({scale:g} s) lags this motion: use estimator.method polyfit"
                )
                what = f"{ratio:.3g} times their expected size: the model lags the motion"
            elif ratio < 1.0 / INNOVATION_LIMIT and settings.noise:
                fix = f"set estimator.kalman.noise below its {settings.noise:g} (or 0: read from the samples)"
                what = f"{ratio:.3g} times their expected size: the noise is set higher than it is"
            else:
                continue
            name = self.joint_names[j]
            self._log.every(
                ("estimate-fit", int(j)),
                logging.WARNING,
                lambda name=name, what=what, fix=fix: (
                    f"joint {name!r}: the kalman estimator's innovations are {what}; {fix}"
                ),
            )

    def _remember(self, track: KalmanBank, joints: np.ndarray) -> None:
        """Keep what a restart of these joints starts from: the noise read and the models' weights."""
        read = track.read_noise
        self._noise_memory[joints] = (read.get("positions", np.nan), read.get("velocities", np.nan))
        if track.scores is not None:
            weights = track.weights()
            if self._score_memory is None or len(self._score_memory) != len(weights):
                self._score_memory = np.full((len(weights), len(self.joint_names)), np.nan)
            self._score_memory[:, joints] = np.log(np.maximum(weights, 1e-12))

    def _say_why(self, group: JointHistory, reason: str) -> None:
        """Log once per warm-up (throttled) why a group's joints have no estimate; warn once per group
        when its samples are too sparse for the support ever to be covered."""
        support = self._support
        names = ", ".join(self.joint_names[j] for j in group.joints)
        where = f"[stamp - {support.before:g} s, stamp + {support.after:g} s]"
        recent = np.diff(group.stamps[-17:])
        interval = float(np.median(recent)) / NS if len(recent) >= 8 else 0.0
        needed = max(support.min_samples * interval, support.span * interval / support.max_hole) * 1.1
        if interval and needed > support.span:  # even a steady stream cannot cover the support
            if group.warming == "sparse":
                return
            group.warming = "sparse"
            self._log.every(
                ("coverage", "sparse", tuple(group.joints)),
                logging.WARNING,
                f"no estimate for joint(s) {names}: a sample every {interval * 1e3:.3g} ms is too sparse for the "
                f"estimator (at least {support.min_samples} samples in {where}, none more than "
                f"{support.max_hole:g} s apart); increase estimator.window to at least {needed:.2g} s",
            )
            return
        if group.warming:
            return
        group.warming = True
        self._log.every(
            ("coverage", "warm-up", tuple(group.joints)),
            logging.INFO,
            f"no estimate yet for joint(s) {names} ({reason}): estimates start where their samples cover "
            f"{where}, at least {support.min_samples} of them, none more than {support.max_hole:g} s apart "
            "(after a start, a restart, a gap or a model reload)",
        )


def _columns(states: np.ndarray, by_velocity: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Position, velocity and acceleration (..., 3, m) as a fit's columns: the value, first and second
    derivative of each joint's positions, or where ``by_velocity`` (m,) of its velocities (value the
    velocity, first the acceleration, second not known)."""
    value = np.where(by_velocity, states[..., 1, :], states[..., 0, :])
    first = np.where(by_velocity, states[..., 2, :], states[..., 1, :])
    second = np.where(by_velocity, np.nan, states[..., 2, :])
    return value, first, second


def _timing(group: JointHistory, lead: float) -> float:
    """s: how far a causal fit's samples' times may be off (:attr:`~.clock.SampleClock.timing`): 0 for a fit
    whose windows reach past the target. Those are centred where the motion's change shows on both sides,
    and held from a start on write times after a rest (the default within 1.8x of its steady 99th
    percentile, ``bench/bench_write_jitter.py --start``); the whole-recording fit (the bag tool's for the
    default) has no clock running as it fits."""
    clock = group.sample_clock
    return clock.timing if clock is not None and lead == 0.0 else 0.0


def _per_joint(fit: tuple[np.ndarray, ...], m: int, by_velocity: np.ndarray, exact: bool) -> tuple[np.ndarray, ...]:
    """A fit's columns (value, first and second derivative, the acceleration's standard deviation, and
    any more, such as whether it strained; each (..., columns)) as the group's m joints' position,
    velocity, acceleration and the rest (..., m). The columns are one per joint (its velocities where
    ``exact`` and it is fitted on them, else its positions), then, where not ``exact``, one per joint
    fitted on its velocities (``by_velocity``)."""
    value, first, second, *rest = fit
    if exact and by_velocity.any():
        return (value, np.where(by_velocity, value, first), np.where(by_velocity, first, second), *rest)
    position, velocity, acceleration = value[..., :m], first[..., :m].copy(), second[..., :m].copy()
    own = [entry[..., :m].copy() for entry in rest]
    if by_velocity.any():
        velocity[..., by_velocity], acceleration[..., by_velocity] = value[..., m:], first[..., m:]
        for entry, whole in zip(own, rest, strict=True):
            entry[..., by_velocity] = whole[..., m:]
    return (position, velocity, acceleration, *own)


def at_rest(values: np.ndarray) -> np.ndarray:
    """Per column of a window's samples (T, n), whether they hold no motion: their standard deviation
    at most :data:`REST_SPREAD` times their noise's, read from their second differences (a motion's are
    far smaller than its spread, white noise's are sqrt(6) times its own); constant samples are at rest."""
    if len(values) < 4:
        return np.zeros(values.shape[1], dtype=bool)
    noise = np.diff(values, 2, axis=0).std(axis=0) * (1.0 / math.sqrt(6.0))
    constant = (values == values[0]).all(axis=0)  # (whose standard deviation rounds above 0)
    return constant | (values.std(axis=0) <= REST_SPREAD * noise)
