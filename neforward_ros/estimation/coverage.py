"""When an estimate is an estimate: the samples around its stamp must cover what the estimator needs.

Every estimator here reads the samples of a support interval around the target stamp t:
[t - before, t + after]. A local polynomial fit of degree d over a window W fits the samples of its
window; a Kalman estimate rests on the samples of its recent past and, smoothed, of ``lag`` after.
An estimate is published only when that interval is covered: the samples reach back to its start
or before, the last one inside comes within ``end_slack`` of its end (about one sample interval of
that joint: its samples are there up to the end, not only up to a gap that comes before it),
between them no stretch is longer than ``max_hole`` without a sample, and at least
``min_samples`` of them lie inside. (When the
future end has been reached is the caller's to say: the streaming estimator emits a fixed-lag
estimate once a sample about ``lag`` later has arrived; the bag tool gives none for the last
``lag`` of a recording.) So there is no estimate from the first samples after a start, a restart or a gap, and
no fit that silently lowers its degree or reaches for samples outside its window: a fit that
extrapolates over an empty stretch amplifies the noise, and its numbers are not estimates.
"""

from __future__ import annotations

import bisect
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from neforward_ros.stamps import NS


@dataclass(frozen=True)
class Support:
    """The interval an estimate needs, relative to its stamp, and how densely it must be sampled.

    Attributes:
        before, after: s before and after the target stamp.
        min_samples: samples the interval must hold at least.
        max_hole: s; the longest stretch of the interval without a sample, its ends included.
    """

    before: float
    after: float
    min_samples: int
    max_hole: float

    @property
    def span(self) -> float:
        return self.before + self.after

    def ns(self) -> tuple[int, int, int]:
        """(before, after, max_hole) in integer nanoseconds."""
        return round(self.before * NS), round(self.after * NS), round(self.max_hole * NS)


def uncovered(
    stamps: np.ndarray,
    target: int,
    support: Support,
    holes: Sequence[int] | None = None,
    end_slack: int | None = None,
    repeats: Sequence[int] = (),
) -> str | None:
    """Why the samples (stamps, int ns, increasing) do not cover the target's support; None if they do.

    ``holes``: optionally, the increasing stamps of the samples that come more than max_hole after the
    one before them (a streaming caller keeps these as samples arrive, and the check costs no pass
    over the samples). ``end_slack``: ns; the last sample's greatest distance from the end (max_hole
    if None). ``repeats``: increasing stamps of repeated readings left out of the fits
    (:mod:`.repeats`): they show the joint's samples go on, and count as samples for the end only."""
    before, after, hole = support.ns()
    start, end = target - before, target + after
    first = int(stamps.searchsorted(start, side="right")) - 1  # the newest sample at or before start
    if first < 0:
        return "too little history"
    last = int(stamps.searchsorted(end, side="right")) - 1  # the newest at or before end
    reached = int(stamps[last])
    if repeats:
        k = bisect.bisect_right(repeats, end)
        if k and repeats[k - 1] > reached:
            reached = repeats[k - 1]
    if end - reached > (hole if end_slack is None else min(end_slack, hole)):
        return "too few samples after the stamp yet"
    if last > first:
        if holes is None:
            long = int(np.max(np.diff(stamps[first : last + 1]))) > hole
        else:  # a hole's sample in (stamps[first], stamps[last]]
            k = bisect.bisect_right(holes, int(stamps[first]))
            long = k < len(holes) and holes[k] <= int(stamps[last])
        if long:
            return "a gap in the samples"
    if last - int(stamps.searchsorted(start, side="left")) + 1 < support.min_samples:
        return "too few samples"
    return None


def covered_mask(
    times: np.ndarray,
    targets: np.ndarray,
    support: Support,
    end_slack: float | None = None,
    reach: np.ndarray | None = None,
) -> np.ndarray:
    """:func:`uncovered` is None, for many targets at once; times, targets and end_slack in s, times
    increasing. ``reach``: the samples' times with the repeated readings left out of them (increasing;
    None: ``times``), for the end's check."""
    if len(times) == 0:
        return np.zeros(len(targets), dtype=bool)
    start, end = targets - support.before, targets + support.after
    first = np.searchsorted(times, start, side="right") - 1
    last = np.searchsorted(times, end, side="right") - 1
    slack = support.max_hole if end_slack is None else min(end_slack, support.max_hole)
    reach = times if reach is None else reach
    reached = reach[np.maximum(np.searchsorted(reach, end, side="right") - 1, 0)]
    ok = (first >= 0) & (end - reached <= slack)
    ok &= last - np.searchsorted(times, start, side="left") + 1 >= support.min_samples
    # Long intervals (i, i + 1) with first <= i < last: a running count answers for each target.
    long = np.r_[0, np.cumsum(np.diff(times) > support.max_hole)]  # long intervals before sample i
    ok &= long[np.maximum(last, 0)] - long[np.maximum(first, 0)] == 0
    return ok
