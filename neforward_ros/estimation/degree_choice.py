"""The default fit's polynomial degree, chosen per joint by the recent estimates' errors.

The adaptive rule (:mod:`.adaptive`) chooses each estimate's window well for a given degree, but no
degree suits every motion: a slow sine through a 12-bit encoder wants degree 2 over the widest window
(degree 4's noise there is 2.5-3x larger), a 3 Hz sine degree 6 (degree 4's bias cuts its windows
short: 2-3x the error). Joining two degrees estimate by estimate (the lower one where the two agree
within the rule's intervals) let degree 4's bias through where degree 6 was right, and could not take
degree 2 without letting its bias through too: one estimate's difference between degrees is one
draw of the noise. Over a second of estimates it is not.

Each estimate runs the rule at every degree of :data:`DEGREES`. With the first (the highest, the
least biased) as the reference r, the mean squared error of degree k's estimate a is

    E[(a - r)^2] - var(r) + 2 cov(a, r),

and cov(a, r) = var(a) where a's fit is the best linear one on a window that holds r's (a linear
unbiased estimate cannot beat it, so r - a is uncorrelated with a), which is how the rule's windows
come out: a lower degree keeps a wider window. var(r) is the same for every k. So each degree scores,
per joint, the mean over the last :data:`MEMORY` of its estimates' (a - r)^2 + 2 s_a^2, s_a the rule's
stated deviation for a (its noise and its distance to the next smaller window, which reads what the
noise reading misses), and the least score wins. The reference's own score is 2 s_r^2, its bias
taken as zero.

The node (:class:`DegreePool`, one estimate at a time) and the whole-recording estimate
(:func:`choose`) pool the same estimates: those of the same stream (a restart forgets them) that were
made (the joint's samples covered their support). Once compiled, both run in C
(:func:`~.native_fit.choose_last`, :func:`~.native_fit.choose_degrees`: 300,000 estimates of 8 joints
in about 0.1 s where numpy took 0.8 s); these numpy functions serve until then and are their reference.
"""

from __future__ import annotations

import numpy as np

from neforward_ros.estimation import native_fit
from neforward_ros.estimation.adaptive import GAMMA, StampedRows, window_sums
from neforward_ros.stamps import NS

DEGREES = (6, 4, 2)
"""The degrees the default fit chooses among, the reference (the least biased) first."""
MEMORY = 1.0
"""s: the estimates a choice is made on (stamps in (s - MEMORY, s])."""
LEAST = 20
"""Estimates a joint's record must hold before a degree other than the reference is chosen: after a
start or a restart, the first few are a draw or two of the noise (on the reference signal at 500 Hz
the largest error in the first second was 6.8x the steady RMS error with a record of one estimate
on, 5.5x with 20; the degree with the least deviation among those agreeing with the reference's
estimate, as the two degrees' fusion chose, 6.8x too)."""


def terms(accelerations: np.ndarray, stated: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each estimate's contribution to each degree's score, (a - r)^2 + 2 s_a^2, and whether it
    counts (every degree's estimate and deviation finite), from the degrees' accelerations and stated
    deviations (D, ...), the reference first. Returns two (D, ...); 0 where not counted."""
    accelerations = np.asarray(accelerations, dtype=float)
    stated = np.asarray(stated, dtype=float)
    finite = np.all(np.isfinite(accelerations) & np.isfinite(stated), axis=0)
    apart = np.where(finite, accelerations - accelerations[0], 0.0)
    spread = np.where(finite, stated, 0.0)
    counted = np.broadcast_to(finite, accelerations.shape).astype(float)
    return apart * apart + 2.0 * spread * spread, counted


def _least(
    total: np.ndarray, count: np.ndarray, accelerations: np.ndarray, stated: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """The degree index (..., n) with the least mean score, the degree axis the second to last of
    ``total`` and ``count`` (..., D, n); the reference's where fewer than :data:`LEAST` counted, or
    where the degree's estimate leaves the reference's by more than :data:`~.adaptive.GAMMA` of their
    combined deviations (``accelerations``, ``stated``: (D, ..., n), this estimate's). And the chosen
    degree's mean squared error over the window as its scores tell it (its mean score less var(r),
    half the reference's; 0 where fewer counted)."""
    counted = count[..., 0, :] >= LEAST  # every degree's estimates count alike
    mean = total / np.maximum(count, 1.0)
    chosen = np.where(counted, np.argmin(mean, axis=-2), 0)
    estimate, spread = pick(accelerations, chosen), pick(stated, chosen)
    apart = np.abs(estimate - accelerations[0]) > GAMMA * np.hypot(spread, stated[0])
    chosen = np.where(apart, 0, chosen)
    least = np.take_along_axis(mean, chosen[..., None, :], axis=-2)[..., 0, :]
    return chosen, np.where(counted, np.maximum(least - 0.5 * mean[..., 0, :], 0.0), 0.0)


def choose(stamps_ns: np.ndarray, accelerations: np.ndarray, stated: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The degree index chosen at each estimate (M, n), from every degree's accelerations and stated
    deviations (D, M, n) at the estimates' stamps (M,), integer ns, increasing (NaN where a joint
    has no estimate: it does not count); and the chosen degree's mean squared error over the last
    second (M, n) (:func:`_least`)."""
    score, counted = terms(accelerations, stated)
    total, count = window_sums(stamps_ns, score.transpose(1, 0, 2), counted.transpose(1, 0, 2), round(MEMORY * NS))
    return _least(total, count, accelerations, stated)


def chosen_std(accelerations: np.ndarray, stated: np.ndarray, chosen: np.ndarray, error: np.ndarray) -> np.ndarray:
    """The standard deviation stated with the chosen degree's estimate (...): its own and its distance
    to the reference's beyond the reference's own deviation (an estimate of its bias over the
    reference's: (a - r)^2 - s_r^2) in quadrature, or where larger the root of its mean squared error
    over the last second as the scores tell it (``error``, from :func:`choose`). Where an acceleration
    jumps (a trapezoidal move's corners) every degree's estimate is off by more than its own
    deviation, the lower degrees' by more (RMS of error / sigma 3.0-3.1 for degree 4 on trapezoids at
    250 Hz with its own alone, 1.6-2.0 for degree 6); where the noise is coloured (a real arm's) the
    scores see what each estimate's own deviation misses."""
    estimate, spread = pick(accelerations, chosen), pick(stated, chosen)
    beyond = np.square(estimate - accelerations[0]) - np.square(stated[0])
    return np.sqrt(np.maximum(spread * spread + np.maximum(beyond, 0.0), error))


def pick(options: np.ndarray, chosen: np.ndarray) -> np.ndarray:
    """(D, ...) options' entries at the chosen degree index (...)."""
    if options.ndim == 2:  # one estimate's joints (the node's, every message): plain indexing is quicker
        return options[chosen, np.arange(options.shape[1])]
    out = np.array(options[0])  # a degree at a time where chosen: several times quicker than take_along_axis
    for k in range(1, len(options)):
        np.copyto(out, options[k], where=chosen == k)
    return out


class DegreePool:
    """:func:`choose` and :func:`chosen_std` one estimate at a time, in stamp order: the node's. An
    estimate's joints are chosen group by group (:meth:`choose`), after :meth:`start` at its stamp. The
    last second's score terms are kept and summed directly at each choice (in C once compiled,
    :func:`~.native_fit.choose_last`; the whole recording's sliding sums agree to about 1e-12)."""

    def __init__(self, joints: int) -> None:
        # the last second's estimates: each degree's score terms, then whether counted
        self._rows = StampedRows(round(MEMORY * NS), (len(DEGREES) + 1, joints))
        self._accelerations = np.zeros((len(DEGREES), joints))  # the estimate begun's
        self._stated = np.zeros((len(DEGREES), joints))
        self._counted = np.zeros(joints, dtype=np.uint8)

    def clear(self) -> None:
        """Forget every estimate (a new stream)."""
        self._rows.clear()

    def forget(self, joints: list[int]) -> None:
        """Forget these joints' estimates so far (their samples' times changed: see :mod:`.clock`)."""
        self._rows.window[:, :, joints] = 0.0

    def start(self, stamp_ns: int) -> None:
        """Begin the estimate at ``stamp_ns`` (after every earlier one); the estimates a second older
        are forgotten."""
        self._rows.append(stamp_ns)
        self._counted[:] = 0

    def choose(
        self, joints: np.ndarray, accelerations: np.ndarray, stated: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """The degree index (m,) for the ``joints`` (m,) of the estimate begun, from their degrees'
        accelerations and stated deviations (D, m), which are kept for the estimates to come; and the
        standard deviation to state with the chosen degree's estimate (m,) (:func:`chosen_std`)."""
        self._accelerations[:, joints], self._stated[:, joints] = accelerations, stated
        self._counted[joints] = 1
        window = self._rows.window
        library = native_fit.FIT.get()
        if library is not None:
            chosen, std = native_fit.choose_last(
                library, window, self._accelerations, self._stated, self._counted, LEAST, GAMMA
            )
            return chosen[joints], std[joints]
        score, counted = terms(accelerations, stated)
        window[-1, :-1, joints], window[-1, -1, joints] = score.T, counted[0]
        total = np.add.reduce(window[:, :, joints], axis=0)
        chosen, error = _least(total[:-1], total[-1:], accelerations, stated)
        return chosen, chosen_std(accelerations, stated, chosen, error)
