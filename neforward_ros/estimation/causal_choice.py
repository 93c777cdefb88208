"""The causal polyfit's window and degree, chosen per joint by how each candidate fared half a window ago;
and the Kalman settings' choice among the bank's models and the same fits, reaching their lag past the
target (the stream's ``_chosen_fit``).

A causal estimate refers to the newest sample: its fit is one-sided, and extrapolates to the end of
its window. The intersection-of-confidence-intervals rule (:mod:`.adaptive`), which serves the
centred fits well, chooses such windows poorly: a one-sided fit's bias grows fast with its window
and its variance with its degree, the intervals' test tells them apart late, and over a family of
motions the causal setting's q'' error was a median 2.3x (up to 8.8x) that of the best fixed
window and degree chosen knowing the truth (``bench/bench_estimator_family.py``).

A causal estimate's error can be told afterwards, though. Half a window after a sample, the centred
fit of the default setting (its window reaching half a window each way, the adaptive rule choosing
it) estimates q'' there several times more accurately than any one-sided fit: it serves as the
truth. So every estimate fits a fixed set of candidates, degrees :data:`DEGREES` on each of
:data:`LEVELS` half-widths (:func:`half_widths`) whose window holds at least degree + :data:`EXTRA`
samples, and keeps their estimates (at most :data:`SCORED_PER_MEMORY` per half window; the estimates
between fit only the chosen candidates); once an estimate is half a window old, each candidate's is
scored against the centred fit there. Per joint, each candidate keeps two exponentially weighted
means of its squared errors (:class:`ErrorScores`): over a short memory, half a window, which
follows the motion as it changes (a slow sine at a fine encoder's 1 kHz wants the longest window
away from its turning points, not at them), and over a long one, :data:`LONG_MEMORY`, which
remembers what the last moves needed through a dwell, where every candidate is right; each squared
error is floored at the candidate's variance for the least noise, so that at rest the candidates
rank by their noise. The candidate whose two means sum to the least gives the estimate; its root
mean square error over the short memory is the stated standard deviation.

From a start, the streaming estimator gives a joint no estimate until its record holds (:data:`LEAST_RECORD`
scores: about 0.15-0.2 s after the first estimate's samples); a restart keeps the record. It keeps the
adaptive rule's estimate where the chosen candidate's leaves the rule's by more than G of their combined
deviations: the motion changed since the record was made (a move starts after a dwell, whose record chose a
long window).

Over the benchmark's family (``python bench/bench_estimator_family.py``), the causal setting's ratio to
hindsight went from a median 2.34 (worst 8.81, 85 % of the cases over 1.5) to 0.99 (worst 1.95, 4 %
over); per message it costs 1.4x the rule alone at 1 kHz and 3x at 100 Hz, where every estimate is
scored (the estimators guide has the figures and how they were measured).
"""

from __future__ import annotations

from collections import deque
from functools import lru_cache

import numpy as np

from neforward_ros.estimation import native_fit
from neforward_ros.estimation.fit import lapack_inverse

DEGREES = (2, 3, 4, 5)
"""The candidates' polynomial degrees."""
RATIO = 2.0**0.25
"""Between the candidates' consecutive half-widths (the adaptive rule's ladder, :data:`~.adaptive.RATIO`,
with a level between each two: at 100 Hz its windows hold 21, 15, 11, 8 and 6 samples, and a 5 Hz
motion's best, 7 samples of degree 5, falls between)."""
LEVELS = 20
"""Half-widths of the candidates, the largest half the estimator's window."""
EXTRA = 1
"""Samples a candidate's window holds at least, beyond its degree: 1, the interpolating polynomial
(at a fine encoder's 100 Hz, a 5 Hz motion's best is degree 5 through 6 or 7 samples)."""
SCORED_PER_MEMORY = 20
"""Estimates scored per memory time constant at most (an estimate is kept for scoring only once that
share of the memory has passed since the last one kept: at 1 kHz about every fifth, at 100 Hz each)."""
LONG_MEMORY = 1.0
"""The long memory's time constant, s: what the last moves needed is remembered through a dwell (where
every candidate is right and the short memory forgets them)."""
_EYE = np.eye(DEGREES[-1] + 1)
LEAST_RECORD = SCORED_PER_MEMORY / 2
"""The scores (each weighted by its age over the long memory) a joint's record must hold before its
choice is trusted: one estimate's errors are no record (right after a start, a candidate that happened
to hit the first reference took it and its noise)."""
LEAST_WEIGHT = 0.5
"""A candidate is chosen only where its scores weigh at least this share of the joint's most scored
candidate's (a window that was too short for most of the recent samples has no fair record)."""


def half_widths(largest: float) -> np.ndarray:
    """The candidates' half-widths (LEVELS,), s, largest first."""
    return largest / RATIO ** np.arange(LEVELS)


@lru_cache(maxsize=16)
def _layout(half_widths: tuple[float, ...]) -> tuple[np.ndarray, ...]:
    """Per candidate (degree by degree, then level): its level (C,), the coefficients its degree uses
    (C, top + 1, 1) and their square (C, top + 1, top + 1); the Hankel matrix's indices into the
    power sums, and each candidate's half-width (C, 1)."""
    levels = len(half_widths)
    index = np.arange(DEGREES[-1] + 1)
    used = index[None, :] <= np.repeat(np.array(DEGREES), levels)[:, None]
    level = np.tile(np.arange(levels), len(DEGREES))
    scale = np.array(half_widths)[level][:, None]
    return level, used[:, :, None], used[:, :, None] & used[:, None, :], index[:, None] + index[None, :], scale


def _bounds(times: np.ndarray, target: float, half_widths: np.ndarray, lead: float) -> tuple[np.ndarray, np.ndarray]:
    """Each level's window [lo, hi) among the samples: [target + min(lead, h) - 2 h, target + min(lead, h)]
    (one-sided for lead 0, centred while h <= lead, as hindsight's are)."""
    reach = np.minimum(lead, half_widths)
    lo = times.searchsorted(target + reach - 2.0 * half_widths, side="left")
    hi = times.searchsorted(target + reach, side="right")
    return lo, hi


def usable(times: np.ndarray, target: float, half_widths: np.ndarray, lead: float = 0.0) -> np.ndarray:
    """Which candidates' windows hold enough samples (C,): at least degree + :data:`EXTRA`."""
    lo, hi = _bounds(times, target, half_widths, lead)
    return (hi - lo)[_layout(tuple(half_widths))[0]] >= _least_samples(len(half_widths))


@lru_cache(maxsize=16)
def _least_samples(levels: int) -> np.ndarray:
    """Each candidate's least number of samples (C,), degree by degree, ``levels`` windows each (kept:
    read-only)."""
    least = np.repeat(np.array(DEGREES), levels) + EXTRA
    least.flags.writeable = False
    return least


def _wanted(only: np.ndarray | None, count: int) -> np.ndarray | None:
    """The candidates of the indices ``only`` as a mask (count,), or None for every one."""
    if only is None:
        return None
    wanted = np.zeros(count, dtype=bool)
    wanted[only] = True
    return wanted


def candidates(
    times: np.ndarray,
    values: np.ndarray,
    target: float,
    half_widths: np.ndarray,
    derivative: np.ndarray,
    only: np.ndarray | None = None,
    lead: float = 0.0,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Every candidate's fit at ``target`` (or only those of the indices ``only``, the others NaN): its
    window reaching ``lead`` past the target, or half its width where that is less (a causal fit, lead
    0: one-sided, the target the newest of the samples or after it).

    Args:
        times: the samples' times (W,), s, increasing, the largest window's ([target + lead - 2 h,
            target + lead]).
        values: the samples (W, n).
        target: s.
        half_widths: the ladder (L,), s, largest first.
        derivative: (n,) 2 for a column of positions, 1 for one of velocities.
        lead: s.

    Returns:
        value, first and second derivative at ``target``, the estimate of q'' (the
        ``derivative``-th), and that estimate's variance for samples of unit white noise, each (C, n)
        for C = len(DEGREES) * L candidates, degree by degree and largest window first; NaN where a
        window holds fewer than degree + :data:`EXTRA` samples.

    In one C call once compiled (:func:`~neforward_ros.estimation.native_fit.causal_candidates`: the
    windows' power sums added ring by ring, each system solved by Cholesky), else in numpy
    (:func:`python_candidates`); the two agree to rounding.
    """
    library = native_fit.FIT.get()
    if library is not None:
        wanted = _wanted(only, len(DEGREES) * len(half_widths))
        got = native_fit.causal_candidates(library, times, values, target, half_widths, DEGREES, EXTRA, derivative,
                                           wanted, lead)  # fmt: skip
        if got is not None:
            value, first, second, variance = (got[:, :, q] for q in range(4))
            return value, first, second, np.where(derivative == 2, second, first), variance
    return python_candidates(times, values, target, half_widths, derivative, only, lead)


def python_candidates(
    times: np.ndarray,
    values: np.ndarray,
    target: float,
    half_widths: np.ndarray,
    derivative: np.ndarray,
    only: np.ndarray | None = None,
    lead: float = 0.0,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """:func:`candidates` in numpy: one batch of normal equations for every candidate fitted."""
    lo, hi = _bounds(times, target, half_widths, lead)
    level, used, square, hankel, scale = _layout(tuple(half_widths))
    fitted = usable(times, target, half_widths, lead)
    if only is not None:
        fitted &= _wanted(only, len(level))
    rows = np.flatnonzero(fitted)
    out = np.full((5, len(level), values.shape[1]), np.nan)
    if not len(rows):
        return out[0], out[1], out[2], out[3], out[4]
    needed = np.unique(level[rows])  # the levels fitted
    at = np.searchsorted(needed, level[rows])  # each fitted candidate's among them
    tau = (times[None, :] - target) / half_widths[needed, None]  # (L', W)
    # Every degree's normal equations from one set of sums: the moments sum_i tau_i^k (a Hankel matrix's
    # entries) and sum_i tau_i^k y_i, 0 outside each level's window.
    top = DEGREES[-1]
    powers = np.empty((2 * top + 1, *tau.shape))
    index = np.arange(len(times))[None, :]
    powers[0] = (index >= lo[needed, None]) & (index < hi[needed, None])
    for power in range(1, 2 * top + 1):
        np.multiply(powers[power - 1], tau, out=powers[power])
    sums = powers @ np.ones(len(times))  # (2 top + 1, L')
    moments = (powers[: top + 1] @ values).transpose(1, 0, 2)  # (L', top + 1, n)
    # One batch of (top + 1)-square systems, candidate by candidate (degree by degree, then level): a lower
    # degree's Gram matrix padded with the identity, its moments with zeros, gives the same coefficients.
    gram = np.where(square[rows], sums[hankel][:, :, at].transpose(2, 0, 1), _EYE)
    inverse = lapack_inverse(gram)[0][:, :3]  # value, first and second derivative's rows (every degree >= 2)
    coefficients = np.einsum("cij,cjn->cin", inverse, moments[at] * used[rows])  # (C', 3, n)
    h = scale[rows]
    first, second = inverse[:, 1, 1, None] / (h * h), 4.0 * inverse[:, 2, 2, None] / (h * h) ** 2
    out[0, rows] = coefficients[:, 0]
    out[1, rows] = coefficients[:, 1] / h
    out[2, rows] = 2.0 * coefficients[:, 2] / (h * h)
    out[3] = np.where(derivative == 2, out[2], out[1])
    out[4, rows] = np.where(derivative == 2, second, first)
    return out[0], out[1], out[2], out[3], out[4]


class ErrorScores:
    """Per joint and candidate, exponentially weighted means of the squared error of its estimates
    against a later, more accurate reference, over a short and a long memory; and the candidates'
    estimates still waiting for theirs.

    Args:
        joints: how many joints.
        count: how many candidates.
        memory: the short memory's time constant, s; the long one's is :data:`LONG_MEMORY`.
        delay_ns: how long after its stamp an estimate's reference can be made.
    """

    def __init__(self, joints: int, count: int, memory: float, delay_ns: int) -> None:
        self._memory_ns = np.array([memory, max(memory, LONG_MEMORY)])[:, None] * 1e9  # (2, 1)
        self._spacing_ns = memory * 1e9 / SCORED_PER_MEMORY
        self.delay_ns = delay_ns
        self._total = np.zeros((2, count, joints))
        self._weight = np.zeros((2, count, joints))
        self._last = np.full(joints, -1, dtype=np.int64)  # the stamp last scored per joint; -1: none
        self.waiting: deque[tuple[int, np.ndarray, np.ndarray]] = deque()
        self._kept: int | None = None  # the stamp of the last estimates kept
        self._ranking: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None  # see _rank; None: to be worked out

    def clear(self, joints: list[int] | None = None, keep_record: bool = False) -> None:
        """Forget the scores and waiting estimates of these joints (all: None), whose history restarted; with
        ``keep_record``, only the waiting estimates (the scores made go on, from the next one scored)."""
        columns = slice(None) if joints is None else joints
        if not keep_record:
            self._total[:, :, columns] = 0.0
            self._weight[:, :, columns] = 0.0
        self._last[columns] = -1
        self._ranking = None
        if joints is None:
            self.waiting.clear()
            self._kept = None
        else:
            for _, estimates, _ in self.waiting:
                estimates[:, joints] = np.nan

    def wants(self, stamp_ns: int) -> bool:
        """Whether estimates made at ``stamp_ns`` are to be kept for scoring: the first, and then those
        made at least :data:`SCORED_PER_MEMORY`'s spacing after the last kept."""
        return self._kept is None or stamp_ns - self._kept >= self._spacing_ns

    def keep(self, stamp_ns: int, estimates: np.ndarray, floors: np.ndarray) -> None:
        """Keep the candidates' estimates (C, joints) made at ``stamp_ns`` (NaN where none) until scored,
        with the least squared error each is scored with (C, joints): see :meth:`score`."""
        self.waiting.append((stamp_ns, estimates, floors))
        self._kept = stamp_ns

    def due(self, now_ns: int) -> list[tuple[int, np.ndarray, np.ndarray]]:
        """The waiting estimates whose reference can be made at ``now_ns`` (taken off the queue)."""
        out = []
        while self.waiting and self.waiting[0][0] <= now_ns - self.delay_ns:
            out.append(self.waiting.popleft())
        return out

    def score(self, stamp_ns: int, estimates: np.ndarray, floors: np.ndarray, reference: np.ndarray) -> None:
        """Score the candidates' ``estimates`` (C, joints) made at ``stamp_ns`` against ``reference``
        (joints,), NaN where a joint has none: each squared error plus its ``floors`` (C, joints), the
        candidate's variance for the least noise (that of :data:`~.adaptive.FLOOR`): a joint at rest
        whose readings do not change gives every candidate an error of rounding size, and a record of
        those alone would rank them at random; the floors rank them by their noise (the next move's
        first samples then meet the least noisy, not a short window of degree 5)."""
        joints = np.flatnonzero(np.isfinite(reference))
        if not len(joints):
            return
        last = self._last[joints]
        decay = np.where(last >= 0, np.exp(-(stamp_ns - last) / self._memory_ns), 1.0)[:, None, :]  # (2, 1, m)
        error = estimates[:, joints] - reference[joints]
        scored = np.isfinite(error)
        squared = np.where(scored, error * error + floors[:, joints], 0.0)
        self._total[:, :, joints] = decay * self._total[:, :, joints] + squared
        self._weight[:, :, joints] = decay * self._weight[:, :, joints] + scored
        self._last[joints] = stamp_ns
        self._ranking = None

    def choose(self, available: np.ndarray, joints: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """For these joints (m,), the candidates ``available`` now ((C, m) or (C, 1), bool): (the chosen
        candidate, the one whose short and long memories' mean squared errors sum to the least (m,); its
        root mean square error over the short memory (m,)); -1 and NaN where a joint has no fair record
        (its most scored candidate's weigh less than :data:`LEAST_RECORD`), and a candidate whose scores weigh
        less than :data:`LEAST_WEIGHT` of those is not chosen."""
        order, rms, _ = self._ranked_now()  # (C, joints) each: candidates best first, and their short RMS errors
        columns = np.arange(len(joints))
        ranked, errors = order[:, joints], rms[:, joints]
        now = available[ranked, columns] if available.shape[1] > 1 else available[ranked, 0]
        ok = np.isfinite(errors) & now
        first = np.argmax(ok, axis=0)
        known = ok[first, columns]
        return np.where(known, ranked[first, columns], -1), np.where(known, errors[first, columns], np.nan)

    def ranked(self, rows: slice, available: np.ndarray, joints: np.ndarray) -> np.ndarray:
        """For these joints (m,), which candidates among ``rows`` the record can rank now (rows' count, m), bool:
        those ``available`` ((C, m) or (C, 1), as for :meth:`choose`) whose record is fair (:meth:`_rank`)."""
        return self._ranked_now()[2][rows][:, joints] & available[rows]

    def _ranked_now(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """:meth:`_rank`'s result for the scores so far, worked out once after each change of them."""
        if self._ranking is None:
            self._ranking = self._rank()
        return self._ranking

    def _rank(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Per joint, the candidates in order of their two means' sum (those without a fair record last),
        in that order their short memory's root mean square error (inf: no fair record), and whose record
        is fair (in the candidates' own order), each (C, joints)."""
        weight = self._weight
        most = weight[1].max(axis=0)
        fair = (weight > 0.0).all(axis=0) & (weight[1] >= LEAST_WEIGHT * most) & (most >= LEAST_RECORD)
        mean = np.where(fair, self._total / np.where(fair, weight, 1.0), np.inf)
        order = np.argsort(mean[0] + mean[1], axis=0, kind="stable")
        return order, np.sqrt(np.take_along_axis(mean[0], order, axis=0)), fair
