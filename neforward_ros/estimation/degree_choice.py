"""The default fit's polynomial degree, chosen per joint by the recent estimates' errors.

The adaptive rule (:mod:`.adaptive`) chooses each estimate's window well for a given degree, but no
degree suits every motion: a slow sine through a 12-bit encoder wants a low degree over the widest
window (degree 4's noise there is 2.5-3x larger), a 3 Hz sine degree 6 (degree 4's bias cuts its
windows short: 2-3x the error). Joining two degrees estimate by estimate (the lower one where the two
agree within the rule's intervals) let degree 4's bias through where degree 6 was right: one
estimate's difference between degrees is one draw of the noise. Over a second of estimates it is not.

Each estimate runs the rule at every degree of :data:`DEGREES`: 6, 4 and 3 (and takes degree 6 at one
window finer too: below). (3, not 2: in a window
symmetric about the estimate the two give the same q'', but jittered stamps and dropped repeats make
windows lopsided, and there degree 2 takes the motion's third derivative into q'': up to 2x hindsight
on slow sines at 100 Hz with repeats, where degree 3 gives 1.0-1.2x.) For two of them, a lower
degree's estimate a and a higher one's b, the difference of their mean squared errors is

    E[(a - b)^2] - 2 (var(b) - var(a)),

since cov(a, b) = var(a) where a's fit is the best linear one on a window that holds b's (a linear
unbiased estimate cannot beat it, so b - a is uncorrelated with a), which is how the rule's windows
come out: a lower degree keeps a wider window. From the first degree (the highest, the least biased:
the reference r) down, each degree's score adds its step from the one before: per joint, over the
estimates of the last :data:`MEMORY`, the mean of the squared steps down to degree k plus 2 c v_k^2
(the reference's own score 2 c v_r^2), and the least score wins. (Each step compares neighbours: the
reference's noise, the largest, does not enter the choice between 4 and 3, as it did when every degree
was scored by its distance to the reference; a second holds only about five of the widest window's
lengths, and with that noise in, degree 4 was taken at a third of the estimates of a slow sine where 3
alone gives 0.77x hindsight: 1.49x.) v_k is the rule's noise for degree k (its fit's own deviation,
from the noise read off the samples) and c the noise's *colour*, how much more than that the estimates
vary. The stated deviation (the noise and the distance to the next smaller window, in quadrature)
would not do for var: where the noise is white that distance is mostly the smaller window's noise,
about twice the estimate's own deviation, and scoring on it charged the noisier degrees 2-5x their
variance (degree 4 lost to degree 2's bias on slow sines through 16 bits: 1.6-2.1x hindsight). The
noise alone charges too little where the noise is coloured (a real arm's measured velocities: the
noise read off its samples is 2-3x below the estimates' spread), and then degree 6 wins everywhere.
c is read from the reference's same second: the sum of its squared distances to its next smaller
window (s_r^2 - v_r^2) over the sum of what the noise read would put there (w_r^2, the difference of
the two windows' noise variances: :func:`~.adaptive.between_std`), at least 1.

Degree 6 is also fitted at the next smaller window than its rule chose (:data:`FINER`;
:func:`~.adaptive.finer_level`): the rule's intervals, G = 4 deviations wide, keep windows whose bias
reaches several deviations, and where a motion's higher derivatives are large for its rate (a gait at
100-250 Hz) the next smaller window, with about an eighth of the bias and 2-3x the noise, is the better
estimate, which the rule does not take (on a 12-bit gait at 100 Hz the rule's degree 6 alone gives 2.0x
hindsight, the finer fit 0.84x). The degrees are chosen among themselves as above; then the finer fit takes
the place of the one chosen where the scores say it is the better: the chosen one's mean squared error over
degree 6's (its score less degree 6's) plus degree 6's over the finer's. The latter is their mean squared
step less twice the difference of their noise variances (the rule's window holds the finer's, at the same
degree: its fit is the better linear one there, and the step is uncorrelated with it), at the colour the
finer fit reads off its distance to its own next smaller window, also below 1: there the noise as read
overstates what reaches the estimates. A slow motion through a coarse encoder at a high rate rounds to a
staircase, whose error changes only as the reading does and reaches q'' far less than white noise of its
variance would: a minimum-jerk move at 2 kHz through 13 bits read 0.03, and with the reading taken no
lower than 1 the finer fit's variance was put at 10x its true error, it was never taken, and the estimate
came out 1.63x hindsight; taken at its reading, 1.26x. That colour must be white, at most
:data:`WHITE`: a coloured noise grows with the window (the Panda's measured velocities read 5 at the finer
window and 10 at the rule's), so the step to the rule's fit, at the finer's colour, reads the noise's growth
as the rule's bias; let in there, the finer fit was taken at 19-48 % of the Panda's estimates and its torque
error went to 1.11x the reference's (0.95x without it). White noise and encoders' rounding read 0.05-1.2 on
the benches' families.

Two readings are no colour of the finer fit's. Where the finer fit is the smallest window the samples allow,
its distance is to the rule's own window (the only neighbour it has), and that distance is the step the gain
weighs, mostly the rule's bias: read as the finer's colour, it charged the finer fit's variance with the
rule's bias and kept it out (:func:`~.adaptive.between_std` gives that fit nothing between, and :func:`terms`
no colour term for it; its strain is then checked on its noise, not on that distance). And where the
reference's colour (the rule's distance to the finer's) reads over :data:`GROWTH` times the finer's, the
distances grow with the window as a bias does: a degree 6 fit's bias in q'' grows as h^5, its squared
distance about 32-fold per rung of the ladder while the noise's variance between falls about 6-fold, and a
coloured noise's reading grows about 2-fold (the Panda's, above); the finer's reading is then taken for
the bias still left in its own window, and its noise as white. On gaits at 90-140 Hz through 13-18 bits
(114 cases, seeds 7, 11, 31, 53, 97 and 401-403, a driver's repeats on half), where both kept the finer fit
out, the default was over 1.5x hindsight on 9 (worst 1.78); with both, on 2 (1.66). :data:`GROWTH` at 4
left 1 over, but moved the Panda's torque error on its second joint from 1.01 to 1.03x the reference's;
at 8 the Panda's figures are the same to every digit.

The finer fit is also left out where its record is short (under :data:`LEAST` estimates, or spanning under
:data:`RECORD`: after a start or a restart its gain is read off a few steps' noise) or holds a gap
(:data:`HOLE`: its edges' estimates read as degree 6's bias), where its stated
deviation is over :data:`STRAIN` times its usual error (its window cut short now), as a degree's strain is,
and where it is the rule's own window (the rule chose its smallest, or the fit read its noise off fewer than
:data:`~.adaptive.NOISE_SAMPLES` samples: after a gap, the few since, which can read it 2.3x under an
encoder's rounding, and the finer fit's step to the rule's looked like bias).

The record tells each degree's usual error; one estimate can be far from usual. Where the chosen
degree's stated deviation is over :data:`STRAIN` (G) times the root of its mean squared error over the
second (its rule strained here: a window cut short on sparse or lopsided samples, after a gap, in a
writer's bursts), each degree is scored with its own noise now for one of its two c v^2 (its usual
bias from the record, its variance from this estimate). A 12-bit joint at 100 Hz after a 0.3 s gap
read its noise off the few samples since (2.3x under the encoder's rounding), degree 4's rule cut its
windows, and two estimates came out 4-5 rad/s^2 off (6.7x the steady 99th percentile); with the check,
1.0x.

The deviation stated with the chosen estimate is its coloured noise, c v_a^2, the distance to its
next smaller window beyond what that noise puts there (a bias the rule let through, a trapezoid's
corner), and its distance to the reference beyond the reference's coloured noise, added in
quadrature; or where larger, the root of its mean squared error over the last second as the scores
tell it (its score less c v_r^2, the reference's mean squared error).

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

DEGREES = (6, 4, 3)
"""The degrees the default fit chooses among, the highest (the least biased) first."""
FINER = True
"""Whether the highest degree's fit at the next smaller window than its rule chose is a candidate too,
before the degrees' own fits (see the module's docstring)."""
WHITE = 2.0
"""The most colour the finer fit may read (its squared distances to its neighbouring window over what the
noise read puts there, over the last second) for it to be a candidate (see the module's docstring)."""
GROWTH = 8.0
"""How many times the finer fit's colour reading the reference's (the rule's fit's, its distance to the
finer's) must be for the finer's to be taken for a bias and its noise as white (see the module's docstring)."""
RECORD = 0.75
"""s: the least span of the last second's estimates for the finer fit to be a candidate. After a start or a
restart, records of a tenth of a second (:data:`LEAST` estimates at 250 Hz-1 kHz) took it on their few
steps' noise: on the transients bench up to 3.4x the steady p99 in the second after a time reset, where
the degrees' choice alone gives 2.5x; with half a second, 2.26x at 100 Hz (1.23x without the finer fit)."""
HOLE = 0.05
"""s: an interval between estimates longer than this is a hole (a gap in the joint states), and the finer
fit is not a candidate while the record holds one. The estimates at a gap's edges, on lopsided windows,
step far from degree 6's, and the record read that as degree 6's bias: with the finer fit's colour read
below 1 too (see the module's docstring), a 0.3 s gap at 1 kHz (1.5 Hz sines through 20 bits) had it
taken at 85 % of the estimates in the 0.15 s after, and the worst error went to 3.04x the steady p99
(1.13x before; 2.07x with the check)."""
MEMORY = 1.0
"""s: the estimates a choice is made on (stamps in (s - MEMORY, s])."""
STRAIN = GAMMA
"""How many times the chosen degree's mean squared error over the second (in deviations) an estimate's
stated deviation may be before each degree is scored with its own noise now (see the module's
docstring: the estimate's rule strained)."""
LEAST = 20
"""Estimates a joint's record must hold before a degree other than the reference is chosen: after a
start or a restart, the first few are a draw or two of the noise (on the reference signal at 500 Hz
the largest error in the first second was 6.8x the steady RMS error with a record of one estimate
on, 5.5x with 20; the degree with the least deviation among those agreeing with the reference's
estimate, as the two degrees' fusion chose, 6.8x too)."""


def terms(
    accelerations: np.ndarray, stated: np.ndarray, noise: np.ndarray, between: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Each estimate's terms of the choice's sums and whether it counts (every degree's estimate and
    deviations finite), from the degrees' accelerations, stated deviations, noise's deviations and the
    noise's deviations between each estimate and its neighbouring window's (D, ...), the reference
    first: each degree's squared step from the one before, (a_k - a_(k-1))^2 (0 for the reference),
    then v_a^2 for each, then the reference's squared distance to its neighbour, s_r^2 - v_r^2 (at
    least 0), and what its noise alone puts there, w_r^2, then the same two of the second degree (the
    first's where there is only one); and 1 or 0 alike for each. Two (2 D + 4, ...), the terms 0 where not
    counted."""
    accelerations, stated, noise, between = (
        np.asarray(x, dtype=float) for x in (accelerations, stated, noise, between)
    )
    finite = np.all(
        np.isfinite(accelerations) & np.isfinite(stated) & np.isfinite(noise) & np.isfinite(between), axis=0
    )
    steps = np.concatenate([np.zeros_like(accelerations[:1]), np.diff(accelerations, axis=0)])
    apart = np.where(finite, steps, 0.0)
    own = np.where(finite, noise, 0.0)
    colours = []
    for k in (0, 1) if len(accelerations) > 1 else (0, 0):
        reference = np.where(finite, stated[k], 0.0)
        expected = np.where(finite, between[k], 0.0)
        beside = np.where(expected > 0.0, np.maximum(reference * reference - own[k] * own[k], 0.0), 0.0)
        colours += [beside, expected * expected]  # (nothing between: no smaller window, no colour read)
    rows = np.concatenate([apart * apart, own * own, np.stack(colours)])
    return rows, np.broadcast_to(finite, rows.shape).astype(float)


def _least(
    total: np.ndarray,
    count: np.ndarray,
    accelerations: np.ndarray,
    stated: np.ndarray,
    noise: np.ndarray,
    between: np.ndarray,
    finer: bool = False,
    held: np.ndarray | float = 0.0,
    record: float = RECORD,
) -> tuple[np.ndarray, np.ndarray]:
    """The degree index (..., n) with the least mean score and the standard deviation stated with its
    estimate (..., n), from the sums of :func:`terms` over the window (``total`` (..., 2 D + 4, n), the
    terms' axis the second to last) and the estimates counted (``count`` (..., K, n), its first entry
    along that axis the count), and this estimate's accelerations, stated deviations, noise's
    deviations and those between each and its neighbour (D, ..., n). The reference's where fewer than
    :data:`LEAST` counted, or where the degree's estimate leaves the reference's by more than
    :data:`~.adaptive.GAMMA` of their combined stated deviations.

    ``finer``: the first is the finer fit. The others are chosen among themselves as above, the second
    their reference and its colour read; the finer fit takes the place of the one chosen where its own
    colour reads at most :data:`WHITE` (1 where the reference's reads over :data:`GROWTH` times it), its
    record is long enough (``held``, the window's span in s (..., or one for all), at least ``record`` s,
    and :data:`LEAST` estimates), its stated deviation (its noise, where nothing is between it and a smaller
    window) is within :data:`STRAIN` of its usual error, and the scores say it is the better: the chosen
    one's mean squared error over the reference's (its score less the reference's) plus the reference's
    over the finer's (their mean squared step less twice the difference of their mean noise variances at
    the colour the finer's window reads, below 1 too) above 0."""
    degrees = len(accelerations)
    if not finer or degrees < 2:
        return _least_from(total, count, accelerations, stated, noise, between)[:2]
    zero = np.zeros_like(total[..., :1, :])  # the others' sums: the step to the second (from the first) left out
    theirs = np.concatenate([zero, total[..., 2:degrees, :], total[..., degrees + 1 : 2 * degrees, :],
                             total[..., 2 * degrees + 2 :, :]], axis=-2)  # fmt: skip
    chosen, std, score, colour = _least_from(theirs, count, accelerations[1:], stated[1:], noise[1:], between[1:])
    number = np.maximum(count[..., 0, :], 1.0)
    beside, expected = total[..., 2 * degrees, :], total[..., 2 * degrees + 1, :]
    reading = np.where(expected > 0.0, beside / np.where(expected > 0.0, expected, 1.0), 1.0)
    reading = np.where(colour > GROWTH * np.maximum(reading, 1.0), 1.0, reading)  # the distances grow as a bias
    tint = np.maximum(reading, 1.0)
    mine, rule = total[..., degrees, :] / number, total[..., degrees + 1, :] / number
    gain = score - 2.0 * colour * rule + total[..., 1, :] / number - 2.0 * reading * (mine - rule)
    finest, quiet, apart = stated[0], noise[0], between[0]
    other = (accelerations[0] != accelerations[1]) | (noise[0] != noise[1])  # (not the rule's smallest window)
    aged = np.asarray(held)[..., None] >= record
    take = (count[..., 0, :] >= LEAST) & aged & (reading <= WHITE) & (gain > 0.0) & other
    told = np.where(apart > 0.0, finest, quiet)  # (its stated deviation, where read against a smaller window)
    take &= told * told <= STRAIN**2 * tint * mine
    beyond = np.maximum(finest * finest - quiet * quiet - tint * apart * apart, 0.0)
    own = np.sqrt(np.maximum(tint * quiet * quiet + beyond, tint * mine))
    return np.where(take, 0, chosen + 1), np.where(take, own, std)


def _least_from(
    total: np.ndarray,
    count: np.ndarray,
    accelerations: np.ndarray,
    stated: np.ndarray,
    noise: np.ndarray,
    between: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """:func:`_least` with the first degree the reference, its colour read from ``total``'s rows 2 D and
    2 D + 1: the degree index and the deviation stated, then the chosen one's score and the colour."""
    degrees = len(accelerations)
    number = np.maximum(count[..., :1, :], 1.0)
    counted = count[..., 0, :] >= LEAST
    beside, expected = total[..., 2 * degrees, :], total[..., 2 * degrees + 1, :]
    colour = np.where(expected > 0.0, np.maximum(beside / np.where(expected > 0.0, expected, 1.0), 1.0), 1.0)
    steps = np.cumsum(total[..., :degrees, :], axis=-2)  # from the reference down to each degree
    usual = total[..., degrees : 2 * degrees, :] / number  # each degree's mean noise variance
    score = steps / number + 2.0 * colour[..., None, :] * usual
    chosen = np.where(counted, np.argmin(score, axis=-2), 0)
    # where this estimate's window was cut far below its usual, each degree's own variance now
    now = np.moveaxis(np.square(np.asarray(noise, dtype=float)), 0, -2)
    mean_error = np.take_along_axis(score, chosen[..., None, :], -2)[..., 0, :] - colour * usual[..., 0, :]
    cut = counted & (pick(stated, chosen) ** 2 > STRAIN**2 * np.maximum(mean_error, 0.0))
    mended = np.argmin(np.nan_to_num(steps / number + colour[..., None, :] * (usual + now), nan=np.inf), axis=-2)
    chosen = np.where(cut, mended, chosen)
    estimate, spread = pick(accelerations, chosen), pick(stated, chosen)
    apart = np.abs(estimate - accelerations[0]) > GAMMA * np.hypot(spread, stated[0])
    chosen = np.where(apart, 0, chosen)
    # the deviation stated: this estimate's coloured noise and the biases read beside it, or where larger
    # its mean squared error over the second as the scores tell it (they see what one estimate's terms
    # miss where an acceleration jumps, a trapezoidal move's corners)
    least = np.take_along_axis(score, chosen[..., None, :], axis=-2)[..., 0, :]
    error = np.where(counted, np.maximum(least - colour * usual[..., 0, :], 0.0), 0.0)
    estimate, own, spread = pick(accelerations, chosen), pick(noise, chosen), pick(stated, chosen)
    coloured, expected = colour * own * own, colour * np.square(pick(between, chosen))
    beyond_own = np.maximum(spread * spread - own * own - expected, 0.0)
    beyond_reference = np.maximum(np.square(estimate - accelerations[0]) - colour * np.square(noise[0]), 0.0)
    return chosen, np.sqrt(np.maximum(coloured + beyond_own + beyond_reference, error)), least, colour


def choose(
    stamps_ns: np.ndarray,
    accelerations: np.ndarray,
    stated: np.ndarray,
    noise: np.ndarray,
    between: np.ndarray,
    finer: bool = False,
) -> tuple[np.ndarray, np.ndarray]:
    """The degree index chosen at each estimate (M, n) and the standard deviation stated with it
    (M, n), from every degree's accelerations, stated deviations, noise's deviations and those between
    each and its neighbouring window (D, M, n) at the estimates' stamps (M,), integer ns, increasing
    (NaN where a joint has no estimate: it does not count) (:func:`_least`; ``finer``: the first is the
    finer fit)."""
    rows, counted = terms(accelerations, stated, noise, between)
    span = round(MEMORY * NS)
    total, count = window_sums(stamps_ns, rows.transpose(1, 0, 2), counted.transpose(1, 0, 2), span)
    stamps_ns = np.asarray(stamps_ns, dtype=np.int64)
    first = np.searchsorted(stamps_ns, stamps_ns - span, side="right")  # each window's oldest
    hole = np.flatnonzero(np.diff(stamps_ns) > round(HOLE * NS)) + 1
    after = np.zeros(len(stamps_ns), dtype=np.int64)  # the first estimate since the last hole
    after[hole] = hole
    after = np.maximum.accumulate(after)
    held = np.where(first >= after, (stamps_ns - stamps_ns[first]) / NS, 0.0)  # 0: a hole in the window
    return _least(total, count, accelerations, stated, noise, between, finer, held)


def pick(options: np.ndarray, chosen: np.ndarray) -> np.ndarray:
    """(D, ...) options' entries at the chosen degree index (...)."""
    if options.ndim == 2:  # one estimate's joints (the node's, every message): plain indexing is quicker
        return options[chosen, np.arange(options.shape[1])]
    out = np.array(options[0])  # a degree at a time where chosen: several times quicker than take_along_axis
    for k in range(1, len(options)):
        np.copyto(out, options[k], where=chosen == k)
    return out


class DegreePool:
    """:func:`choose` one estimate at a time, in stamp order: the node's. An
    estimate's joints are chosen group by group (:meth:`choose`), after :meth:`start` at its stamp. The
    last second's score terms are kept and summed directly at each choice (in C once compiled,
    :func:`~.native_fit.choose_last`; the whole recording's sliding sums agree to about 1e-12)."""

    def __init__(self, joints: int, candidates: int | None = None, record: float = RECORD, holes: bool = True) -> None:
        # the last second's estimates: their terms (terms), then whether counted
        self._finer = FINER
        self._holes = holes  # whether a hole in the record keeps the finer fit out (HOLE)
        self._record_ns = round(record * NS)  # the least span of a record for the finer fit (RECORD)
        options = len(DEGREES) + self._finer if candidates is None else candidates
        self._rows = StampedRows(round(MEMORY * NS), (2 * options + 5, joints))
        self._accelerations = np.zeros((options, joints))  # the estimate begun's
        self._stated = np.zeros((options, joints))
        self._noise = np.zeros((options, joints))
        self._between = np.zeros((options, joints))
        self._counted = np.zeros(joints, dtype=np.uint8)
        self._after_ns: int | None = None  # the first estimate's stamp since the last hole (HOLE)

    def clear(self) -> None:
        """Forget every estimate (a new stream)."""
        self._rows.clear()
        self._after_ns = None

    def forget(self, joints: list[int]) -> None:
        """Forget these joints' estimates so far (their samples' times changed: see :mod:`.clock`)."""
        self._rows.window[:, :, joints] = 0.0

    def start(self, stamp_ns: int) -> None:
        """Begin the estimate at ``stamp_ns`` (after every earlier one); the estimates a second older
        are forgotten."""
        kept = self._rows.stamps
        if self._holes and len(kept) and stamp_ns - kept[-1] > round(HOLE * NS):
            self._after_ns = stamp_ns
        self._rows.append(stamp_ns)
        self._counted[:] = 0

    def choose(
        self,
        joints: np.ndarray,
        accelerations: np.ndarray,
        stated: np.ndarray,
        noise: np.ndarray,
        between: np.ndarray,
    ) -> tuple[np.ndarray, np.ndarray]:
        """The degree index (m,) for the ``joints`` (m,) of the estimate begun, from their degrees'
        accelerations, stated deviations, noise's deviations and those between each and its neighbouring
        window (D, m), which are kept for the estimates to come; and the standard deviation to state
        with the chosen degree's estimate (m,) (:func:`_least`)."""
        self._accelerations[:, joints], self._stated[:, joints] = accelerations, stated
        self._noise[:, joints], self._between[:, joints] = noise, between
        self._counted[joints] = 1
        window = self._rows.window
        held_ns = self._rows.held_ns  # the window's span, 0 where it holds a hole
        if self._after_ns is not None and self._rows.stamps[0] < self._after_ns:
            held_ns = 0
        library = native_fit.FIT.get()
        if library is not None:
            chosen, std = native_fit.choose_last(
                library,
                window,
                self._accelerations,
                self._stated,
                self._noise,
                self._between,
                self._counted,
                LEAST,
                GAMMA,
                STRAIN,
                self._finer,
                WHITE,
                GROWTH,
                held_ns >= self._record_ns,
            )
            return chosen[joints], std[joints]
        rows, counted = terms(accelerations, stated, noise, between)
        window[-1, :-1, joints], window[-1, -1, joints] = rows.T, counted[0]
        total = np.add.reduce(window[:, :, joints], axis=0)
        return _least(total[:-1], total[-1:], accelerations, stated, noise, between, self._finer,
                      held_ns / NS, self._record_ns / NS)  # fmt: skip
