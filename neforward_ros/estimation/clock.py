"""The sample times of a driver that stamps its messages when it writes them.

Many drivers sample on a steady clock and stamp each message when they publish it, a varying delay
later (a thread's wake-up, a bus transfer): the stamp is the sample time plus a delay of 0 to some
fraction of a period. Taken as sample times, such stamps make the motion between sample and stamp
(velocity x delay) read as noise whose size follows the velocity (``bench/bench_write_jitter.py``).

Since the delays are never negative, the sample times lie on the lower envelope of the stamps:
numbering the samples by whole periods since the first (a dropped or repeated sample counts two), the
stamps lie on or above a line, index x period + offset, and the samples written soonest lie just
above it. Over the last :data:`SPAN` periods the line is drawn through the earliest-written sample
of the older half and that of the newer half (each above the line by the least of a hundred delays;
three passes, each leaning the line on the lowest samples of the one before), drawn again every
:data:`REFIT` samples. The recovered clock follows the line without ever jumping (its step per period
leans towards the line over :data:`SETTLE` periods); the periods since the sample before are counted
from the recovered time and the stamps' mean delay after it, so that delays up to most of a period
(0.7 of it, tested with dropped samples) never count one. Before the first line they are counted from
the intervals, where delays over half a period make some read as a dropped sample (or hide one): a line
is drawn only where every stamp lies less than :data:`SPREAD` of a period above it, and where it does
not the periods are counted again from the stamps' phases (:meth:`WriteClock._recount`). Whether a
stream's stamps are write times is for the caller to tell: where the stamps are the sample times (a
driver that stamps at sampling, jittered or not), the line would move samples off their times.
:class:`SampleClock` tells it for a stream by the noise its positions read on the stamps and on the
newest line (:func:`stamps_are_write_times`): the Kalman bank (:mod:`.kalman_bank`) and the fits'
sample histories (:mod:`.history`), each with a clock of its own, run on the recovered clock once it
reads far less, every sample they hold placed on that line (:meth:`SampleClock.retimed`).
"""

from __future__ import annotations

import copy
import itertools
from collections import deque
from collections.abc import Callable, Iterable

import numpy as np

from neforward_ros.estimation.adaptive import noise_of
from neforward_ros.stamps import NS

SPAN = 256
"""Periods of stamps the line is drawn over."""
REFIT = 32
"""Samples between two drawings of the line; a quarter of the stamps kept where fewer (the first lines,
drawn over few stamps, are the least sure of their period: delays to 0.7 of a period at 100 Hz, the line
over the first 64 stamps 0.7 % off, which miscounted a period 10 samples on)."""
SPREAD = 0.75
"""The most of a period the stamps kept may lie above a line for it to be drawn: a writer's delays spread
over up to 0.7 of a period are recovered (``test/test_write_clock.py``). Lines whose stamps spread over
more are a stream stamped at its samples, irregularly: the Panda's recording (fed from 250 starts, see
:data:`WRITTEN_AFTER`) was taken for write times from 8 starts with lines up to a whole period, from
none with this."""
PERIOD_SEARCH = 0.15
"""The share of the usual interval either side of it over which the period is searched where the stamps'
periods are counted again (:meth:`WriteClock._recount`)."""
SETTLE = 64
"""Periods over which the recovered clock leans towards a new line (a jump of a few microseconds would
read as a kink in every joint's motion). It jumps only onto a line drawn on periods counted again (the
periods it counted were wrong) and where the stamps are found to be write times (its holder places every
sample it holds on the line then: :meth:`SampleClock.retimed`)."""
FIRST = 32
"""Samples before a line is drawn (until then the stamps are taken as they are)."""
WRITTEN = 0.5
"""The most the position noise read on the recovered clock may be, relative to that read on the stamps,
for the stamps to be taken for write times. Where the stamps are the sample times, the recovered clock
moves samples off them and its noise reads higher; where they are write times, several times lower
(``bench/bench_write_jitter.py``)."""
NOISE_SAMPLES = 128
"""The newest samples a :class:`SampleClock` reads the noise from."""
WRITTEN_AFTER = 3
"""Consecutive checks that must find the stamps to be write times for them to be taken for such. The
Panda's recording (``../shared/realdata``), whose positions read a median 1.9 times more noise on the
recovered clock than on the stamps, reads under :data:`WRITTEN` over a few stretches: fed from 250
starts 16 samples apart, the clock took its stamps for write times from 133 of them with windows of 64
samples and one check (the Kalman bank's rule until 2026-11-28), 40 with 128 and one, 10 with 128 and
two, 1 with 128 and three (none since the check reads the newest line, drawn where it holds the stamps:
:data:`SPREAD`). Three checks found a writer's stamps (``bench/bench_write_jitter.py``) after 190-770
samples, about 2 s at 100 Hz, before one check over half a second could decide (:data:`DECISIVE`)."""
DECISIVE = 0.2
"""A check whose samples span at least :data:`DECISIVE_SPAN` and read on the recovered clock's line less
than this share of the noise read on the stamps finds write times alone, without :data:`WRITTEN_AFTER`
in a row. Over half a second or more, a stream stamped at its samples reads about as much noise on the
line or more: the Panda's recording (its repeats left out) thinned to 100 Hz read at least 0.72 of it
over 64 samples, thinned to 200 Hz 0.55 over 128; the UR10e recordings (about 94 Hz) 0.88 over 64,
jittered samples (+-5 %, 100 Hz) 4.4-19 times more; writers (delays to 0.4 of a period) 0.01-0.04.
Over shorter spans real stamps can read far less (the Panda at 1 kHz down to 0.006 over 64 samples,
0.05 over 128, fed from 250 starts): there only checks in a row tell."""
DECISIVE_SPAN = 0.5
"""s: the least span of samples over which one check may find write times alone (:data:`DECISIVE`)."""
DECISIVE_LOOKS = True
"""A look (over fewer samples than a check reads: :data:`SOON`, :data:`LOOK_SAMPLES`) that spans
:data:`DECISIVE_SPAN` and reads under :data:`DECISIVE` of the stamps' noise on the line finds write times as such
a check does; until 2026-11-30 a look never voted for them. At 50-125 Hz a writer whose arm rests at the start
is looked at every :data:`SOON` samples once it moves, before a check can be made: 50 Hz writers (minimum-jerk
moves, 16 bits) were found 0.32-0.56 s after the move started instead of 0.80-1.04 s
(``test_write_clock.py``); at 100 Hz, kalman 20 ms's worst error in the first second of one such start was 3.3
times its steady 99th percentile instead of 13.7 (``bench/bench_write_jitter.py --start``). No stamps of the
samples' own times were taken for write times by it: the Panda's recording from 250 starts at 1 kHz, and
thinned to 100 and 50 Hz, 470 starts spread over the UR10e recordings, and 432 simulated streams stamped at
their jittered samples (50-125 Hz, jitter 5-20 % of a period, 12-20 bits, sines, gaits, minimum-jerk moves)."""
EARLY_SAMPLES = 64
"""Samples the first check may read, before :data:`NOISE_SAMPLES` have come, where they span
:data:`DECISIVE_SPAN` (128 Hz or less): a 100 Hz writer is then found by about 0.6-1 s, not 2 s."""
CHECK_EVERY = 128
"""Samples between two of a :class:`SampleClock`'s checks once it has seen :data:`SPAN`."""
EARLY_CHECK_EVERY = 32
"""Samples between two checks before, and on irregular stamps (:data:`JITTER`) until :data:`SPAN` samples have
come since the first check that could tell (:data:`TELLING`): the first checks may not tell yet (1.5 Hz sines at 100 Hz,
``bench/bench_write_jitter.py``, on the recovered clock as it ran, before the checks read the newest
line: 0.64 of the stamps' noise at 64 samples, 0.06 at 96; on the line 0.009 at 64). With a check every
128 samples from the first, the default stayed on the stamps there until 1.9 s, and its error was 12x
that at the samples' stamps (1.1x from 1 s on since the checks read the newest line). Counted from the start
alone, a writer whose arm rested over its first 256 samples was checked every 128 once it moved: found 0.82 s
after a 500 Hz arm started to move, 0.21 s since (``test/test_write_clock.py``)."""
SOON = 8
"""Samples after a check that could not tell (the arm at rest) from which the next is made as soon as some
joint's speed would tell, on irregular stamps (:meth:`SampleClock._moves_to_tell`; a look where the window
holds too few samples for a check, :data:`LOOK_SAMPLES` or more): the causal fits of a start on jittered
stamps take their spread as timing noise until a check or look tells (:attr:`SampleClock.timing`)."""
SILENCE = 3.0
"""An interval this many times the usual one is a silence: the samples before it are not compared with
those after it (the differences across it are motion, not noise)."""
KEEP_AFTER = 4
"""Checks (after the first :data:`SPAN` samples, each able to tell: :data:`TELLING`) that must find the
stamps to be the samples' times for a stream to keep them for good."""
TELLING = 2.0
"""A check tells the two clocks apart where, for some joint, its mean speed over the check's samples
(:func:`path_speed`) times the stamps' spread about the recovered clock is at least this many times the least of
the noises its positions read on the two clocks (whichever clock is wrong reads that spread as noise). A joint at
rest, or one creeping through its encoder's rounding, does not tell: a driver that stamps when it writes
is not kept on its stamps for having started at rest."""
HOLD_FOR_CLOCK = True
"""From a start on irregular stamps, a stream has no estimate until its clock can tell whether the stamps are
the samples' times or the times a driver wrote them (:meth:`SampleClock.holds_estimates`: a first look at 40
samples, else the first check, 64-128 samples; at 100 Hz the default's first estimate 0.34 s after the first
sample instead of 0.11 s on jittered sample stamps). The verdict outlives a restart, which then does not
wait; the bag tool's whole-recording fit holds the same targets (:func:`held_targets`). Until 2026-11-29 the
estimates ran on the stamps meanwhile: from a start on write-time stamps (delays to 0.4 of a period, 16 bits,
100 Hz-1 kHz), the worst error in the first second was up to 122x the steady 99th percentile for the default,
135x kalman 20 ms (1.83x, 59x since), the cases over 3x 8 and 17 of 18 (0 and 3 since; what is left is a
writer resting at the start that moves later, where the look at rest cannot tell: ``bench/bench_write_jitter.py
--start``). There the causal settings' 262x and 258x are 2.6x and 2.3x since their fits take the stamps'
uncertainty into account until the clock tells (:attr:`SampleClock.timing`, :data:`SOON`); kalman 20 ms's 46x
is 3.3x since the Kalman bank's does too (:data:`~.kalman_bank.BANK_TIMING_NOISE`, :data:`DECISIVE_LOOKS`)."""
JITTER = 0.03
"""The most an interval between stamps may leave a whole number of usual intervals, as a share of one,
for the stamps to be regular: a stream whose stamps are irregular from the start (samples stamped with
jitter, or written a varying delay after them) has its first estimates wait until a check tells which
they are (:meth:`SampleClock.holds_estimates`). Where the stamps are regular the two clocks agree and
nothing waits."""
LOOK_SAMPLES = 40
"""Samples at which a stream waiting for its clock (:meth:`SampleClock.holds_estimates`) has a first look,
whatever their span, before a check can decide: the recovered clock's line is drawn by then
(:data:`FIRST`), and a stream stamped at its jittered samples reads several times more noise on it than on
its stamps, a writer a few hundredths of it (``test/test_write_clock.py``). A clock that lets estimates through
from the start (a restart's) has it too: it may find the stamps to be the samples' own (:attr:`SampleClock.timing`)."""
REGULAR_AFTER = 8
"""Intervals between stamps seen (the first four tell the usual one) before stamps none of which was off by
:data:`JITTER` are taken to be regular."""
LEAST_NOISE = 1e-6
"""rad (m): a joint whose positions read less noise than this on the clock a comparison is made against (the
stamps, or the line where the question is whether the stamps are the samples' own) is not compared on the two
clocks (it rests, or its samples are exact: :func:`stamps_are_write_times`)."""


class WriteClock:
    """Recovered sample times of one stream, sample by sample (see the module docstring)."""

    def __init__(self) -> None:
        self.recovered: int | None = None  # ns: the newest sample's recovered time
        self._last: int | None = None  # ns: the newest stamp
        self._index = 0  # whole periods since the clock started
        self._marks: deque[tuple[int, int]] = deque(maxlen=SPAN)  # (stamp, period index)
        self._line: tuple[int, int, float] | None = None  # (stamp, index, period ns) of the envelope
        self._unfitted = 0
        self._time = 0.0  # ns: the newest recovered time, unrounded
        self._step = 0.0  # ns: its advance per period
        self._delay = 0.0  # ns: the stamps' mean delay after the recovered times (over about SETTLE samples)
        self._recounted: tuple[int, int] | None = None  # (period index, stamps kept) at the last _recount
        self.holds = False
        """Whether the newest drawing found a line that holds the stamps kept (else the line is an older
        one, and the periods counted on it may be wrong: a check does not decide on it)."""
        self.spread = 0.0
        """s: the standard deviation of the stamps kept about the newest line that holds them (0 before one)."""
        self.jumps = 0
        """How many times the recovered clock jumped onto a line drawn on periods counted again (a holder
        that placed its samples on the line places them again: :attr:`SampleClock.placings`)."""

    def update(self, stamp: int, usual: float | None) -> int:
        """The recovered time (ns) of the sample stamped ``stamp`` (ns), given the usual interval
        between samples (s; None before it is known: the stamp is taken as it is)."""
        if self._line is not None:  # the periods since the newest recovered time, less the usual delay
            periods = max(1, round((stamp - self._time - self._delay) / self._step))
        elif self._last is not None and usual:
            periods = max(1, round((stamp - self._last) / (usual * NS)))
        else:  # the clock starts once the usual interval is known
            self._last = self.recovered = stamp
            return stamp
        self._index += periods
        self._last = stamp
        self._marks.append((stamp, self._index))
        self._unfitted += 1
        fitted = self._line is not None
        recounted = False
        if len(self._marks) >= FIRST and (not fitted or self._unfitted >= min(REFIT, len(self._marks) // 4)):
            recounted = self._fit(usual)
        if self._line is None:
            self.recovered = stamp
            return stamp
        anchor, index, period = self._line
        envelope = anchor + (self._index - index) * period
        if not fitted or recounted:  # the first line, or one on periods counted again: taken as it is
            self._time, self._step = envelope, period
            self._delay = self._delay_above_line()
            self.jumps += recounted
        else:  # carried on, its slope leaning towards the envelope over SETTLE periods: no jump
            self._time += periods * self._step
            if self._unfitted == 0:
                self._step = period + (envelope - self._time) / SETTLE
        self.recovered = round(self._time)
        self._delay += (stamp - self._time - self._delay) / SETTLE
        return self.recovered

    @property
    def delay(self) -> float:
        """ns: the stamps' mean delay after the recovered times (over about :data:`SETTLE` samples; 0 before a line)."""
        return self._delay if self._line is not None else 0.0

    def _delay_above_line(self) -> float:
        """ns: the mean of the stamps kept above the newest line."""
        return float(np.mean(self._above(self._line)))

    def _above(self, line: tuple[int, int, float]) -> np.ndarray:
        """ns: how far each stamp kept lies above ``line`` (stamp, index, period ns)."""
        anchor, index, period = line
        stamps, indices = np.array(self._marks, dtype=np.int64).T
        return stamps - (anchor + (indices - index) * period)

    def line_times(self, stamps: np.ndarray) -> np.ndarray | None:
        """The times (ns, float) on the newest line of the samples stamped ``stamps`` (ns; samples this
        clock was fed, in order), or None before a line is drawn: the line is straight over them all
        where the recovered clock, still leaning towards it, is not. A sample among the last
        :data:`SPAN` is placed at the period it was counted in; an older one (or one from before the
        clock started) at whole periods before the next, at least one."""
        if self._line is None:
            return None
        anchor, index, period = self._line
        counted = dict(self._marks)
        stamps = np.asarray(stamps, dtype=np.int64)
        periods = np.array([counted.get(int(s), -1) for s in stamps], dtype=np.int64)
        known = np.flatnonzero(periods >= 0)
        if len(known) == 0:  # none among the last SPAN: placed from the newest line's own count
            periods[-1] = self._index - round((self._last - int(stamps[-1])) / period)
            known = np.array([len(stamps) - 1])
        for k in range(int(known[0]) - 1, -1, -1):  # the older ones are a prefix
            periods[k] = periods[k + 1] - max(1, round((int(stamps[k + 1]) - int(stamps[k])) / period))
        return anchor + (periods - index) * period

    def settle(self) -> None:
        """Put the recovered clock on the newest line at once: a jump, for a caller that places every
        sample it holds on that line (:meth:`line_times`) at the same time."""
        if self._line is None:
            return
        anchor, index, period = self._line
        self._time, self._step = anchor + (self._index - index) * period, period
        self._delay = self._delay_above_line()
        self.recovered = round(self._time)

    def _fit(self, usual: float | None) -> bool:
        """Draw the line through the stamps kept (see the module docstring) where it holds them (every one
        above it by less than :data:`SPREAD` of its period). Where it does not, the periods were miscounted (delays over
        half a period make intervals that read as a dropped sample, or hide one): they are counted again
        (:meth:`_recount`) and the line drawn on them if it holds them; else the line drawn before stays.
        Kept, a line drawn on miscounted periods has its slope off, and the periods counted on it go on
        being miscounted (delays to 0.7 of a period at 200 Hz: a line 0.82 periods a sample, a drop
        counted every 6-15 samples). Returns whether the line was drawn on periods counted again (the
        recovered clock, counted on the periods before, goes onto it at once)."""
        self._unfitted = 0
        self.holds = False
        if not usual:
            return False
        line = self._drawn(usual)
        if line is not None and self._holds(line):
            self._take(line)
            return False
        if not self._recount(usual):
            return False
        line = self._drawn(usual)
        if line is None or not self._holds(line):
            return False
        self._take(line)
        return True

    def _take(self, line: tuple[int, int, float]) -> None:
        """Go on with ``line``, which holds the stamps kept."""
        self._line, self.holds = line, True
        self.spread = float(np.std(self._above(line))) / NS

    def _drawn(self, usual: float) -> tuple[int, int, float] | None:
        """(stamp, index, period ns) of the line through the stamps kept, None where it cannot be drawn or its
        period is not within a fifth of the usual interval (not a steady clock here)."""
        stamps, indices = np.array(self._marks, dtype=np.int64).T
        span = indices[-1] - indices[0]
        if span <= 0:
            return None
        period = (stamps[-1] - stamps[0]) / span  # a first slope; each pass leans the line on the lowest
        middle = len(stamps) // 2
        for _ in range(3):
            above = (stamps - stamps[0]) - period * (indices - indices[0])  # ns above the line
            a = int(np.argmin(above[:middle]))
            b = middle + int(np.argmin(above[middle:]))
            if indices[b] <= indices[a]:
                return None
            period = (stamps[b] - stamps[a]) / (indices[b] - indices[a])
        if abs(period / (usual * NS) - 1.0) >= 0.2:
            return None
        return int(stamps[b]), int(indices[b]), float(period)

    def _holds(self, line: tuple[int, int, float]) -> bool:
        """Whether every stamp kept lies above the line by less than :data:`SPREAD` of its period."""
        above, period = self._above(line), line[2]
        return bool(np.all((above > -0.05 * period) & (above < SPREAD * period)))

    def _recount(self, usual: float) -> bool:
        """Count the kept stamps' periods again, without their intervals: the period is the one, within
        :data:`PERIOD_SEARCH` of the usual interval, on which the stamps' phases lie in the shortest arc
        (delays under a period put them in an arc of that part of it; a period off by one part in the
        stamps' count spreads them over all of it), searched on the newest 32 stamps, then on all near
        the one found, finely enough that its error drifts by a tenth of a period over the stamps at most.
        Each stamp counts the whole periods since the first, less the arc's middle. The newest keeps its
        index (the running clock counts on); where two stamps would share a period, the count stays as
        it was. Tried again once the stamps kept since have doubled, or :data:`SPAN` have come (it costs
        about 1 ms). Returns whether the periods were counted otherwise than they were."""
        if self._recounted is not None and self._index - self._recounted[0] < min(SPAN, self._recounted[1]):
            return False
        self._recounted = (self._index, len(self._marks))
        stamps = np.array([s for s, _ in self._marks], dtype=np.int64)
        since = (stamps - stamps[0]).astype(float)
        period, width = usual * NS, PERIOD_SEARCH
        for count in dict.fromkeys((min(32, len(stamps)), len(stamps))):
            periods = period * (1.0 + np.arange(-width, width, 0.2 / count))
            arcs, _ = _shortest_arcs(since[-count:][None, :] / periods[:, None])
            period, width = float(periods[int(np.argmin(arcs))]), 2.0 / count
        _, middle = _shortest_arcs(since[None, :] / period)
        counted = np.round(since / period - middle[0]).astype(np.int64)
        if np.any(np.diff(counted) < 1):
            return False
        indices = self._index - (counted[-1] - counted)
        if np.array_equal(indices, [i for _, i in self._marks]):
            return False  # counted as they were
        self._marks = deque(zip(stamps.tolist(), indices.tolist(), strict=True), maxlen=SPAN)
        return True

    def copy(self) -> WriteClock:
        clock = copy.copy(self)
        clock._marks = deque(self._marks, maxlen=SPAN)
        return clock


def _shortest_arcs(cycles: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per row of ``cycles`` (..., n; in periods), the shortest arc (a share of the period) holding every
    phase (their fractional parts), and the arc's middle (in periods, within [0, 1.5))."""
    phases = np.sort(cycles % 1.0, axis=-1)
    gaps = np.diff(phases, axis=-1, append=phases[..., :1] + 1.0)  # the last: around from the last to the first
    widest = np.argmax(gaps, axis=-1)
    start = np.take_along_axis(phases, (widest[..., None] + 1) % phases.shape[-1], axis=-1)[..., 0]
    arcs = 1.0 - np.take_along_axis(gaps, widest[..., None], axis=-1)[..., 0]
    return arcs, start + 0.5 * arcs


def path_speed(times: np.ndarray, values: np.ndarray) -> np.ndarray:
    """Each joint's mean speed (n,) over samples (k, n) at ``times`` (k,; s): the length of its path over their span.
    Its net speed (first to last sample) was used until 2026-11-30: a joint that swings back and forth over a
    check's samples (5 Hz sines at 100 Hz) nets little, its checks never told, and a stream stamped at its
    jittered samples stayed undecided for good, its fits and filters hedging against write times (their
    :attr:`SampleClock.timing`). An encoder's flicker at rest, or its rounding's steps at about one a sample,
    makes a path of at most about 1.2 of its noise a sample: times a writer's spread (under 0.35 of a period),
    well under :data:`TELLING` of the noise."""
    return np.add.reduce(np.abs(np.diff(values, axis=0)), axis=0) / (times[-1] - times[0])


def stamps_are_write_times(on_stamps: np.ndarray, on_clock: np.ndarray, share: float = WRITTEN) -> bool:
    """Whether the position noise read on the recovered clock (per joint, ``on_clock``) is far less than
    that read on the stamps (``on_stamps``): the median over the joints that read more than
    :data:`LEAST_NOISE` on the stamps, under ``share`` (:data:`WRITTEN` unless told) of it. With the two
    swapped: whether the stamps read far less than the line (compared on the joints that read noise on the
    line: exact samples read none on their stamps)."""
    moving = on_stamps > LEAST_NOISE
    if not moving.any():
        return False
    return bool(np.median(on_clock[moving]) < share * np.median(on_stamps[moving]))


class SampleClock:
    """The times one stream's samples are fitted at: their stamps, until the stamps are found to be write
    times, then the clock recovered from them (:class:`WriteClock`) for every sample, those before too.

    The clock is fed every sample the fits keep, in order. Once :data:`NOISE_SAMPLES` have come since the
    start or the last silence (:data:`EARLY_SAMPLES` where they span :data:`DECISIVE_SPAN`), and then every
    :data:`EARLY_CHECK_EVERY` samples (every :data:`CHECK_EVERY` once it has seen :data:`SPAN`, and where the
    stamps are irregular, :data:`SPAN` since the first check that could tell), the newest
    ones' position noise is read on both clocks (:func:`~.adaptive.noise_of`, white). A check that can tell
    (the clock's newest drawing holds the stamps, :attr:`WriteClock.holds`; :data:`TELLING`) and finds the
    recovered clock's less than :data:`WRITTEN` of the stamps' votes for write times: after
    :data:`WRITTEN_AFTER` such checks in a row, or one over :data:`DECISIVE_SPAN` that finds it less than
    :data:`DECISIVE`, the stamps are write times, for the rest of the stream. Once :data:`KEEP_AFTER`
    checks that could tell, made after the first :data:`SPAN` samples, found them to be the samples'
    times, the stream keeps its stamps (:attr:`kept`) and the clock stops: a driver stamps the
    same way throughout, and the clock costs about 5 us a sample. From a start on irregular stamps, the
    stream's first estimates wait until it can tell (:meth:`holds_estimates`).
    """

    def __init__(self, released: bool = False, on_stamps: bool = False) -> None:
        self.clock = WriteClock()
        self.written = False
        """Whether the stamps were found to be write times."""
        self.kept = False
        """Whether the stamps were found to be the samples' times, for the rest of the stream."""
        self._last: int | None = None  # ns: the newest stamp
        self._intervals: deque[float] = deque(maxlen=16)  # s: the last intervals between samples
        self._window: deque[tuple[int, np.ndarray]] = deque(maxlen=NOISE_SAMPLES)  # (stamp, q)
        self._unchecked = CHECK_EVERY  # samples since the last check (the first: once the window is full)
        self._seen = 0  # samples fed
        self._telling_from: int | None = None  # samples fed at the first check that could tell
        self._kept_by = 0  # the checks that found the stamps to be the samples' times, after SPAN samples
        self._written_by = 0  # the consecutive checks that found them to be write times
        self._told = False  # whether a check (or the first look) told the stamps to be the samples' times for now
        self._on_stamps = on_stamps  # whether a check (or look) read far less noise on them, none voting since
        self._untold: np.ndarray | None = None  # per joint, the least noise the last check read, where it told nothing
        self._unlooked = 0  # samples since the last check or look
        self._jittered = False  # whether an interval left whole usual intervals by more than JITTER of one
        self.leaning = True
        """Whether the newest check or look that could compare the two clocks (some joint reading noise on either) read
        less position noise on the recovered clock's line than on the stamps, the median ratio over those joints (a
        writer's moving arm reads far less, stamps of jittered samples more); True before any could (at rest, either
        clock places the samples as well: :data:`~.kalman_bank.MIDWAY`)."""
        self.released_at: int | None = 0 if released else None
        """ns: the stamp of the sample from which the stream's estimates no longer wait for this clock (0: from
        the start, a restart's clock where the one before let them through; None: not yet). See
        :meth:`holds_estimates`."""
        self.placings = 0
        """How many times the samples held must be placed on the recovered clock's line (:meth:`retimed`):
        once as the stamps are found to be write times, again each time the clock then jumps onto a line
        drawn on periods counted again."""

    def add(self, stamp: int, positions: np.ndarray) -> int:
        """The recovered time (ns) of the sample stamped ``stamp`` (ns) with these positions (copied); the
        stamp itself once the stream keeps its stamps."""
        if self.kept:
            return stamp
        usual = median_of_few(self._intervals) if len(self._intervals) >= 4 else None
        if self._last is not None:
            interval = (stamp - self._last) / NS
            silence = usual is not None and interval > SILENCE * usual
            if silence:
                self._window.clear()
                self._told = True  # (a stream that pauses or comes in bursts lets its estimates through)
            self._intervals.append(interval)
            if usual is not None and self.released_at is None and not self._jittered:
                self._jittered = abs(interval - max(1, round(interval / usual)) * usual) > JITTER * usual
        self._last = stamp
        jumps = self.clock.jumps
        recovered = self.clock.update(stamp, usual)
        if self.written and self.clock.jumps != jumps:
            self.placings += 1
        if not self.written:
            self._window.append((stamp, np.array(positions, dtype=float)))
            self._unchecked += 1
            # (irregular stamps whose checks could not tell yet, the arm at rest: as from a start)
            untold = self._jittered and (self._telling_from is None or self._seen - self._telling_from < SPAN)
            every = EARLY_CHECK_EVERY if self._seen < SPAN or untold else CHECK_EVERY
            self._seen += 1
            self._unlooked += 1
            soon = self._unlooked >= SOON and self._moves_to_tell()
            if (self._unchecked >= every or soon) and self._readable():
                self._unchecked = 0
                self._check()
            elif soon and len(self._window) >= LOOK_SAMPLES:  # too few for a check: a look (see SOON)
                self._check(look=True)
            elif not self._told and len(self._window) == LOOK_SAMPLES:
                # (the first look, released or not: it may find the samples' own times, and write times only
                # where it is decisive: DECISIVE_LOOKS)
                self._check(look=True)
            if self.written:  # found now: from now on the samples lie on the newest line (see retimed)
                self.clock.settle()
                recovered = self.clock.recovered
                self.placings += 1
        if self.released_at is None:
            regular = not self._jittered and len(self._intervals) >= REGULAR_AFTER
            if self.written or self._told or regular:
                self.released_at = stamp
        return recovered

    @property
    def on_stamps(self) -> bool:
        """Whether the stamps were found to be the samples' times: for the rest of the stream (:attr:`kept`), or
        by a check or look that read far less noise on them than on the line, no check since voting for write
        times (a restart's clock starts with it: its :attr:`timing` 0)."""
        return not self.written and (self.kept or self._on_stamps)

    @property
    def timing(self) -> float:
        """s: how far the samples' times may be from their stamps, as far as this clock can tell yet: the
        stamps' spread about the newest line that holds them until they are found to be write times
        (:attr:`written`) or the samples' own (:attr:`on_stamps`); 0 once they are, or where no line holds
        them. Either the stamps or the line is right, and the other off by about that much: the fits that
        extrapolate to the newest sample take the noise it makes into account (:func:`~.adaptive.timing_noise`)."""
        if self.written or self.on_stamps or not self.clock.holds:
            return 0.0
        return self.clock.spread

    def midway(self, stamp: int, recovered: int) -> int:
        """ns: the time midway between a sample's stamp (ns) and its ``recovered`` time (ns, :meth:`add`'s), less
        half the stamps' mean delay above the recovered clock: on average the stamp, off it by half the stamp's
        own delay's deviation from the mean. Whichever of the two clocks is right, the sample is off it by half
        the distance between them (:data:`~.kalman_bank.MIDWAY`)."""
        return stamp - (stamp - recovered - round(self.clock.delay)) // 2

    def retimed(self, stamps: np.ndarray) -> np.ndarray:
        """The times (ns, float) of the samples stamped ``stamps`` (ns; samples fed, in order) on the
        recovered clock once the stamps are found to be write times: on the line the clock settled on
        then (:meth:`WriteClock.line_times`), with which the recovered times go on. The holder of a
        stream's samples re-times them so at the sample that finds write times."""
        times = self.clock.line_times(stamps)
        return np.asarray(stamps, dtype=float) if times is None else times

    def holds_estimates(self, target: int) -> bool:
        """Whether the estimate at ``target`` (ns) waits for this clock (:attr:`released_at`): from a
        start, the estimates wait until the stamps are regular (:data:`REGULAR_AFTER` intervals, none
        off whole usual intervals by more than :data:`JITTER` of one); on irregular ones, until the
        stamps are found to be write times, or a check (or the first look at :data:`LOOK_SAMPLES`,
        whatever their span) finds them the samples' times or cannot tell (the joints at rest, where the
        two clocks make no difference), or a silence comes first (a stream that pauses or comes in
        bursts, whose checks start afresh after each silence). Held are the targets before the sample
        at which that happened: once estimates flow, none is held again (a hold is a start's warm-up,
        never a gap), and a target's fate does not depend on when it is asked (the bag tool, which
        holds the same targets without replaying the stream, :func:`held_targets`)."""
        return HOLD_FOR_CLOCK and (self.released_at is None or target < self.released_at)

    def _moves_to_tell(self) -> bool:
        """Whether, since the last check could not tell or found neither clock's noise far less, some joint's
        speed over the newest :data:`SOON` samples, times the stamps' spread about the newest line, stands out
        of the least of the noises that check read (:data:`TELLING`): an arm that rested starts to move."""
        if self._untold is None or len(self._window) <= SOON:
            return False
        (first, before), (last, now) = self._window[-1 - SOON], self._window[-1]
        speed = np.abs(now - before) * (NS / max(last - first, 1))
        return bool((speed * self.clock.spread > TELLING * self._untold).any())

    def _readable(self) -> bool:
        """Whether the window holds enough samples for a check: :data:`NOISE_SAMPLES`, or
        :data:`EARLY_SAMPLES` spanning :data:`DECISIVE_SPAN`."""
        held = len(self._window)
        if held == NOISE_SAMPLES:
            return True
        return held >= EARLY_SAMPLES and self._window[-1][0] - self._window[0][0] >= DECISIVE_SPAN * NS

    def _check(self, look: bool = False) -> None:
        """A check of the window (see the class docstring). With ``look``, a look over fewer samples (the
        first, or one made :data:`SOON`): it may find the stamps to be the samples' times, or find that it cannot
        tell (the first estimates wait no longer), and it votes for write times only where it decides alone
        (:data:`DECISIVE_LOOKS`)."""
        self._told = False
        self._untold = None
        self._unlooked = 0
        if not self.clock.holds:  # stamps spread beyond a writer's, or periods miscounted: see _unheld
            self._told = True
            if not look:
                self._unheld()
            return
        stamps, values = zip(*self._window, strict=True)
        first = stamps[0]
        values = np.stack(values)
        on_stamps = (np.array(stamps) - first) / NS
        on_clock = (self.retimed(np.array(stamps)) - first) / NS  # on the newest line
        noise, _ = noise_of(on_stamps, values, coloured=False)
        clock_noise, _ = noise_of(on_clock, values, coloured=False)
        compared = np.maximum(noise, clock_noise) > LEAST_NOISE
        if compared.any():  # (see leaning)
            self.leaning = float(np.median(clock_noise[compared] / np.maximum(noise[compared], LEAST_NOISE))) < 1.0
        # Where the stamps' spread about the recovered clock, moved at the joint's speed, would stand out
        # of its noise on either clock, one of the two reads that spread as noise: the check tells.
        spread = float(np.std(on_stamps - on_clock))
        speed = path_speed(on_stamps, values)
        least = np.minimum(noise, clock_noise)
        if not (speed * spread > TELLING * least).any():
            self._told = True  # (the two clocks make no difference yet)
            self._untold = least if self._jittered else None
            return
        if self._telling_from is None and not look:
            self._telling_from = self._seen
        written = stamps_are_write_times(noise, clock_noise)
        # (the stamps read under WRITTEN of the line's noise, as the line under WRITTEN of theirs for a vote;
        # where neither stands out, the verdict before stands)
        own = stamps_are_write_times(clock_noise, noise)
        self._on_stamps = not written and (self._on_stamps or own)
        if self._jittered and not (written or self._on_stamps):  # neither clock stands out yet: soon again
            self._untold = least
        decisive = written and on_stamps[-1] >= DECISIVE_SPAN and stamps_are_write_times(noise, clock_noise, DECISIVE)
        if look and not (DECISIVE_LOOKS and decisive):
            self._told = not written
            return
        if written:
            self._written_by += 1
            self.written = decisive or self._written_by >= WRITTEN_AFTER
            return
        self._written_by = 0
        self._told = True
        if self._seen >= SPAN:
            self._kept_by += 1
            self.kept = self._kept_by >= KEEP_AFTER

    def _unheld(self) -> None:
        """A check where the clock's newest drawing found no line that holds the stamps: no vote for write
        times; after the first :data:`SPAN` samples, one for the samples' own times (a writer's stamps,
        its delays within :data:`SPREAD` of a period, are held once their periods are counted again,
        which is tried each time the stamps kept have doubled). Without, the Panda's recording was never
        kept on its stamps (its lines seldom hold them) and the clock ran throughout."""
        self._written_by = 0
        if self._seen >= SPAN:
            self._kept_by += 1
            self.kept = self._kept_by >= KEEP_AFTER

    def select(self, columns: list[int]) -> SampleClock:
        """A copy that goes on with these columns of the positions only (joints that left the stream)."""
        clock = copy.copy(self)
        clock.clock = self.clock.copy()
        clock._intervals = deque(self._intervals, maxlen=16)
        clock._window = deque(((s, q[columns]) for s, q in self._window), maxlen=NOISE_SAMPLES)
        return clock


def written_from(stamps: np.ndarray, positions: np.ndarray, starts: np.ndarray) -> int | None:
    """The first sample at which :class:`SampleClock`, fed these samples (stamps ns (T,), positions (T, n))
    in order and started anew where ``starts`` (T,) is set, finds the stamps to be write times; None
    where it never does. Where a clock keeps its stamps, the samples up to the next start are not fed."""
    found = _first(stamps, positions, starts, lambda clock: clock.written)
    return None if found is None else found[0]


def held_targets(
    targets: np.ndarray, lag: int, stamps: np.ndarray, positions: np.ndarray, starts: np.ndarray
) -> np.ndarray:
    """Which of ``targets`` (ns (K,)) a stream's estimates at a lag of ``lag`` (ns) wait for its clock at
    (:meth:`SampleClock.holds_estimates`, as the streaming estimator asks it: at the target plus half the
    lag), its samples fed as :func:`written_from` feeds them (a restart's clock letting them through from
    its start once one did)."""
    targets = np.asarray(targets, dtype=np.int64)
    if not HOLD_FOR_CLOCK:
        return np.zeros(len(targets), dtype=bool)
    found = _first(stamps, positions, starts, lambda clock: clock.released_at is not None)
    if found is None:
        return np.ones(len(targets), dtype=bool)
    released_at = found[1].released_at
    assert released_at is not None
    return targets + lag // 2 < released_at


def _first(
    stamps: np.ndarray, positions: np.ndarray, starts: np.ndarray, found: Callable[[SampleClock], bool]
) -> tuple[int, SampleClock] | None:
    """(the first sample after which ``found`` holds of the :class:`SampleClock` fed these samples (stamps ns
    (T,), positions (T, n)) in order, started anew where ``starts`` (T,) is set, and that clock); None where
    it never does. Where a clock keeps its stamps, the samples up to the next start are not fed."""
    edges = [0, *np.flatnonzero(starts).tolist(), len(stamps)]
    for first, stop in itertools.pairwise(edges):
        clock = SampleClock()
        for k in range(first, stop):
            clock.add(int(stamps[k]), positions[k])
            if found(clock):
                return k, clock
            if clock.kept:
                break
    return None


def median_of_few(values: Iterable[float]) -> float:
    """The median of a few numbers, without numpy's overhead."""
    ordered = sorted(values)
    middle = len(ordered) // 2
    return ordered[middle] if len(ordered) % 2 else 0.5 * (ordered[middle - 1] + ordered[middle])
