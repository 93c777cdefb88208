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
(0.7 of it, tested with dropped samples) never count one. Whether a stream's stamps are write times is told by
the noise read on both clocks (:func:`written`; :mod:`.kalman_bank` for the Kalman filters,
:class:`FitTimes` for the fits): where the stamps are the sample times (a driver that stamps at
sampling, jittered or not), the line would move samples off their times and the noise reads higher.
"""

from __future__ import annotations

import copy
from collections import deque

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
"""The most the position noise read on the recovered clock may be, relative to that read on the
stamps, for the stamps to be taken for write times. Where the stamps are the sample times, the
recovered clock moves samples off them and its noise reads higher; where they are write times,
several times lower (``bench/bench_write_jitter.py``)."""
STILL = 1e-6
"""rad (m): joints whose position noise reads below this on the stamps (at rest, or noise-free
samples) say nothing of the stamps and are left out of the comparison."""
JUDGED = 64
""":class:`FitTimes`: the newest samples whose noise is read on both clocks at each judgement."""
JUDGE_EVERY = 64
""":class:`FitTimes`: samples between two judgements."""
AGREEING = 2
""":class:`FitTimes`: consecutive judgements that must find write times (one alone can be chance: on
a real arm's recording stamped at its samples, one judgement in 16 read 0.46 and the others 0.8-2.2)."""
JUDGE_UNTIL = 2048
""":class:`FitTimes`: the samples of a history (from its start or restart) over which its stamps are
judged; a driver does not change how it stamps, and the bag tool judges a recording the same way
without replaying all of it."""


def written(on_stamps: np.ndarray, on_clock: np.ndarray, still: float = STILL) -> bool:
    """Whether stamps are write times: the position noise read per joint on the stamps (n,) and on the
    clock recovered from them (n,) (:func:`~neforward_ros.estimation.adaptive.noise_of`), compared
    (:data:`WRITTEN`) by their medians over the joints whose noise on the stamps is above ``still``."""
    moving = on_stamps > still
    return bool(moving.any() and np.median(on_clock[moving]) < WRITTEN * np.median(on_stamps[moving]))


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


class FitTimes:
    """The times a group's samples are fitted at: their stamps, or from the sample where the stamps are
    found to be write times, the clock recovered from them (:class:`WriteClock`), for every sample
    kept. Judged every :data:`JUDGE_EVERY` samples over the first :data:`JUDGE_UNTIL` (the position
    noise of the newest :data:`JUDGED` on both clocks, :func:`written`), taken for write times once
    :data:`AGREEING` judgements in a row find them; the clock stops with the judging when the stamps
    are the sample times."""

    __slots__ = ("_agreeing", "_count", "_intervals", "_judged", "_last", "clock", "written")

    def __init__(self) -> None:
        self.clock: WriteClock | None = WriteClock()
        self.written = False
        self._count = 0
        self._agreeing = 0  # consecutive judgements that found write times
        self._last: int | None = None
        self._intervals: deque[int] = deque(maxlen=16)  # ns, between the last samples
        self._judged: deque[tuple[int, int, np.ndarray]] = deque(maxlen=JUDGED)  # (stamp, recovered, positions)

    def add(self, stamp: int, positions: np.ndarray) -> int:
        """The recovered time (ns) of the next sample, stamped ``stamp`` (ns), of ``positions`` (n,);
        the stamp once the judging is over and the stamps are the sample times."""
        if self.clock is None:
            return stamp
        usual = sorted(self._intervals)[len(self._intervals) // 2] / NS if len(self._intervals) >= 4 else None
        if self._last is not None:
            self._intervals.append(stamp - self._last)
        self._last = stamp
        recovered = self.clock.update(stamp, usual)
        if not self.written:
            self._count += 1
            self._judged.append((stamp, recovered, np.array(positions, dtype=float)))
            if self._count >= JUDGED and (self._count - JUDGED) % JUDGE_EVERY == 0:
                self._agreeing = self._agreeing + 1 if self._judge() else 0
                self.written = self._agreeing >= AGREEING
            if not self.written and self._count >= JUDGE_UNTIL:
                self.clock = None  # the stamps are the sample times: nothing more to recover
        return recovered

    def _judge(self) -> bool:
        stamps, recovered, values = zip(*self._judged, strict=True)
        first = stamps[0]
        on_stamps, _ = noise_of((np.array(stamps) - first) / NS, np.stack(values), coloured=False)
        on_clock, _ = noise_of((np.array(recovered) - first) / NS, np.stack(values), coloured=False)
        return written(on_stamps, on_clock)

    def copy(self) -> FitTimes:
        times = copy.copy(self)
        times.clock = None if self.clock is None else self.clock.copy()
        times._intervals = deque(self._intervals, maxlen=16)
        times._judged = deque(self._judged, maxlen=JUDGED)
        return times


def judged_written(stamps: np.ndarray, positions: np.ndarray) -> bool:
    """Whether :class:`FitTimes` takes the stamps (T,) ns of a history's samples (T, n) for write
    times (within its first :data:`JUDGE_UNTIL` samples, as the node does)."""
    times = FitTimes()
    for k in range(min(len(stamps), JUDGE_UNTIL)):
        times.add(int(stamps[k]), positions[k])
        if times.written:
            return True
    return False
