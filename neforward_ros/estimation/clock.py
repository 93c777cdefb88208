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
(0.7 of it, tested with dropped samples) never count one. Whether a stream's stamps are write times is for
the caller to tell: where the stamps are the sample times (a driver that stamps at sampling, jittered
or not), the line would move samples off their times. :class:`SampleClock` tells it for a stream by the
noise its positions read on both clocks (:func:`stamps_are_write_times`): the Kalman bank
(:mod:`.kalman_bank`) and the fits' sample histories (:mod:`.history`), each with a clock of its own, run
on the recovered clock once it reads far less.
"""

from __future__ import annotations

import copy
import itertools
from collections import deque
from collections.abc import Iterable

import numpy as np

from neforward_ros.estimation.adaptive import noise_of
from neforward_ros.stamps import NS

SPAN = 256
"""Periods of stamps the line is drawn over."""
REFIT = 32
"""Samples between two drawings of the line."""
SETTLE = 64
"""Periods over which the recovered clock leans towards a new line (it never jumps: a jump of a few
microseconds would read as a kink in every joint's motion)."""
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
two, 1 with 128 and three. Three checks find
a writer's stamps (``bench/bench_write_jitter.py``) after 190-770 samples: about 2 s at 100 Hz."""
CHECK_EVERY = 128
"""Samples between two of a :class:`SampleClock`'s checks once it has seen :data:`SPAN`."""
EARLY_CHECK_EVERY = 32
"""Samples between two checks before: the line drawn from the first samples may not tell yet (1.5 Hz
sines at 100 Hz, ``bench/bench_write_jitter.py``: the check at 64 samples reads 0.64 of the stamps'
noise, the one at 96 samples 0.06). With a check every 128 samples from the first, the default stayed
on the stamps there until 1.9 s, and its error was 12x that at the samples' stamps (1.1x now)."""
SILENCE = 3.0
"""An interval this many times the usual one is a silence: the samples before it are not compared with
those after it (the differences across it are motion, not noise)."""
KEEP_AFTER = 4
"""Checks (after the first :data:`SPAN` samples, each able to tell: :data:`TELLING`) that must find the
stamps to be the samples' times for a stream to keep them for good."""
TELLING = 2.0
"""A check tells the two clocks apart where, for some joint, its net speed over the check's samples
times the stamps' spread about the recovered clock is at least this many times the least of the noises
its positions read on the two clocks (whichever clock is wrong reads that spread as noise). A joint at
rest, or one creeping through its encoder's rounding, does not tell: a driver that stamps when it writes
is not kept on its stamps for having started at rest."""
LEAST_NOISE = 1e-6
"""rad (m): a joint whose positions read less noise than this on the stamps is not compared on the two
clocks (it rests, or its samples are exact)."""


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
        if len(self._marks) >= FIRST and (not fitted or self._unfitted >= REFIT):
            self._fit(usual)
        if self._line is None:
            self.recovered = stamp
            return stamp
        anchor, index, period = self._line
        envelope = anchor + (self._index - index) * period
        if not fitted:  # the first line: taken as it is, with the delays above it so far
            self._time, self._step = envelope, period
            self._delay = float(np.mean([s - (anchor + (i - index) * period) for s, i in self._marks]))
        else:  # carried on, its slope leaning towards the envelope over SETTLE periods: no jump
            self._time += periods * self._step
            if self._unfitted == 0:
                self._step = period + (envelope - self._time) / SETTLE
        self.recovered = round(self._time)
        self._delay += (stamp - self._time - self._delay) / SETTLE
        return self.recovered

    def _fit(self, usual: float | None) -> None:
        self._unfitted = 0
        stamps, indices = np.array(self._marks, dtype=np.int64).T
        span = indices[-1] - indices[0]
        if span <= 0:
            return
        period = (stamps[-1] - stamps[0]) / span  # a first slope; each pass leans the line on the lowest
        middle = len(stamps) // 2
        for _ in range(3):
            above = (stamps - stamps[0]) - period * (indices - indices[0])  # ns above the line
            a = int(np.argmin(above[:middle]))
            b = middle + int(np.argmin(above[middle:]))
            if indices[b] <= indices[a]:
                return
            period = (stamps[b] - stamps[a]) / (indices[b] - indices[a])
        if usual and abs(period / (usual * NS) - 1.0) < 0.2:  # else: not a steady clock here
            self._line = (int(stamps[b]), int(indices[b]), float(period))

    def copy(self) -> WriteClock:
        clock = copy.copy(self)
        clock._marks = deque(self._marks, maxlen=SPAN)
        return clock


def stamps_are_write_times(on_stamps: np.ndarray, on_clock: np.ndarray, moving: np.ndarray) -> bool:
    """Whether the position noise read on the recovered clock (per joint, ``on_clock``) is far less than
    that read on the stamps (``on_stamps``): the median over the ``moving`` joints, under :data:`WRITTEN`
    of it."""
    if not moving.any():
        return False
    return bool(np.median(on_clock[moving]) < WRITTEN * np.median(on_stamps[moving]))


class SampleClock:
    """The times one stream's samples are fitted at: their stamps, until the stamps are found to be write
    times, then the clock recovered from them (:class:`WriteClock`) for every sample, those before too.

    The clock is fed every sample the fits keep, in order. Once :data:`NOISE_SAMPLES` have come since the
    start or the last silence, and then every :data:`EARLY_CHECK_EVERY` samples (every :data:`CHECK_EVERY`
    once it has seen :data:`SPAN`), the newest ones' position noise is read on both clocks
    (:func:`~.adaptive.noise_of`, white). A check that can tell (:data:`TELLING`) and finds the recovered
    clock's less than :data:`WRITTEN` of the stamps' votes for write times: after :data:`WRITTEN_AFTER` such
    checks in a row, the stamps are write times, for the rest of the stream. Once :data:`KEEP_AFTER` checks
    that could tell, made after the first :data:`SPAN` samples, found them to be the samples' times, the
    stream keeps its stamps (:attr:`kept`) and the clock stops: a driver stamps the same way throughout,
    and the clock costs about 5 us a sample.
    """

    def __init__(self) -> None:
        self.clock = WriteClock()
        self.written = False
        """Whether the stamps were found to be write times."""
        self.kept = False
        """Whether the stamps were found to be the samples' times, for the rest of the stream."""
        self._last: int | None = None  # ns: the newest stamp
        self._intervals: deque[float] = deque(maxlen=16)  # s: the last intervals between samples
        self._window: deque[tuple[int, int, np.ndarray]] = deque(maxlen=NOISE_SAMPLES)  # (stamp, recovered, q)
        self._unchecked = CHECK_EVERY  # samples since the last check (the first: once the window is full)
        self._seen = 0  # samples fed
        self._kept_by = 0  # the checks that found the stamps to be the samples' times, after SPAN samples
        self._written_by = 0  # the consecutive checks that found them to be write times

    def add(self, stamp: int, positions: np.ndarray) -> int:
        """The recovered time (ns) of the sample stamped ``stamp`` (ns) with these positions (copied); the
        stamp itself once the stream keeps its stamps."""
        if self.kept:
            return stamp
        usual = median_of_few(self._intervals) if len(self._intervals) >= 4 else None
        if self._last is not None:
            interval = (stamp - self._last) / NS
            if usual is not None and interval > SILENCE * usual:
                self._window.clear()
            self._intervals.append(interval)
        self._last = stamp
        recovered = self.clock.update(stamp, usual)
        if not self.written:
            self._window.append((stamp, recovered, np.array(positions, dtype=float)))
            self._unchecked += 1
            every = EARLY_CHECK_EVERY if self._seen < SPAN else CHECK_EVERY
            self._seen += 1
            if len(self._window) == NOISE_SAMPLES and self._unchecked >= every:
                self._unchecked = 0
                self._check()
        return recovered

    def _check(self) -> None:
        stamps, recovered, values = zip(*self._window, strict=True)
        first = stamps[0]
        values = np.stack(values)
        on_stamps = (np.array(stamps) - first) / NS
        on_clock = (np.array(recovered) - first) / NS
        noise, _ = noise_of(on_stamps, values, coloured=False)
        clock_noise, _ = noise_of(on_clock, values, coloured=False)
        # Where the stamps' spread about the recovered clock, moved at the joint's speed, would stand out
        # of its noise on either clock, one of the two reads that spread as noise: the check tells.
        spread = float(np.std(on_stamps - on_clock))
        speed = np.abs(values[-1] - values[0]) / (on_stamps[-1] - on_stamps[0])
        if not (speed * spread > TELLING * np.minimum(noise, clock_noise)).any():
            return
        if stamps_are_write_times(noise, clock_noise, noise > LEAST_NOISE):
            self._written_by += 1
            self.written = self._written_by >= WRITTEN_AFTER
            return
        self._written_by = 0
        if self._seen >= SPAN:
            self._kept_by += 1
            self.kept = self._kept_by >= KEEP_AFTER

    def select(self, columns: list[int]) -> SampleClock:
        """A copy that goes on with these columns of the positions only (joints that left the stream)."""
        clock = copy.copy(self)
        clock.clock = self.clock.copy()
        clock._intervals = deque(self._intervals, maxlen=16)
        clock._window = deque(((s, r, q[columns]) for s, r, q in self._window), maxlen=NOISE_SAMPLES)
        return clock


def written_from(stamps: np.ndarray, positions: np.ndarray, starts: np.ndarray) -> int | None:
    """The first sample at which :class:`SampleClock`, fed these samples (stamps ns (T,), positions (T, n))
    in order and started anew where ``starts`` (T,) is set, finds the stamps to be write times; None
    where it never does. Where a clock keeps its stamps, the samples up to the next start are not fed."""
    edges = [0, *np.flatnonzero(starts).tolist(), len(stamps)]
    for first, stop in itertools.pairwise(edges):
        clock = SampleClock()
        for k in range(first, stop):
            clock.add(int(stamps[k]), positions[k])
            if clock.written:
                return k
            if clock.kept:
                break
    return None


def median_of_few(values: Iterable[float]) -> float:
    """The median of a few numbers, without numpy's overhead."""
    ordered = sorted(values)
    middle = len(ordered) // 2
    return ordered[middle] if len(ordered) % 2 else 0.5 * (ordered[middle - 1] + ordered[middle])
