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
the caller to tell (:mod:`.kalman_bank` compares the noise read on both clocks): where the stamps are
the sample times (a driver that stamps at sampling, jittered or not), the line would move samples off
their times.
"""

from __future__ import annotations

import copy
from collections import deque

import numpy as np

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
