"""Local polynomial fits whose window each joint's data choose: the intersection of confidence
intervals (ICI) rule, with the noise read from the samples themselves.

A local polynomial fit of half-width h estimates q'' with a bias that grows with h (the motion's
higher derivatives) and a variance that shrinks with it (more samples, longer lever arm). No window
suits every motion: 0.2 s fits slow sweeps to 0.1 % and 5 Hz sines or the corners of a trapezoidal
move to tens of percent. For each estimate, fits are made on a geometric ladder of half-widths,
from the largest (``window / 2``) down by factors of sqrt(2) while a window still holds
``order + 3`` samples; each gives q'' and its standard deviation s_h from the fit's own normal
equations and the noise. Going from the smallest window up, the intervals [q''_h - G s_h,
q''_h + G s_h] are intersected; the largest window whose interval still meets all the smaller ones'
is taken (Goldenshluger and Nemirovski 1997; Katkovnik 1999, the ICI rule for adaptive-window
derivative estimation). Where the motion is smooth every window agrees and the largest (the least
noisy) wins; where it is not (a fast sine, a move's start), the larger windows' bias breaks the
intersection and a smaller one is kept.

The noise is read from each joint's own samples in the largest window (and, where it holds fewer than
:data:`NOISE_SAMPLES`, from that many up to its end too, the larger taken): white noise from the mean
absolute sixth difference (the motion's contribution to a sixth difference is small at the rates joints
are sampled, and where it is not it makes the estimate cautious, not wrong), and an encoder's step from
the smallest non-zero difference between consecutive samples, or (where the differences are blind to
the rounding) the largest whole fraction of it up to 1 / :data:`DIVISORS` that fits (:func:`grid_step`;
sigma = step / sqrt(12)), where the window's samples lie on a grid of that step (:func:`on_grid`: each
a whole number of steps from the first, within :data:`LATTICE`, and the changes not all the same number
of steps). (It used to be read
only where some consecutive samples were equal: a joint moving about a step a sample, whose equal
readings are left out as a driver's repeats, rounds with errors correlated from sample to sample that
the differences do not show, and read as a tiny white noise, 29x hindsight on a slow sine through 13
bits at 800 Hz. Where a joint moves many steps a sample its rounding is white, and the differences read
the same.) A fast joint's two samples that happen to round alike at a turning point
(a 5 Hz sine at 100 Hz) are no encoder step: its smallest other difference is tens of steps, the
differences are no multiples of it, and taking it as the step would state a noise hundreds of times the
real one, the largest window's bias hidden under it. The larger of the two is taken. A quantisation
error is not white: it changes only when the reading changes, so a window of N samples holds only
(changes of the reading + 1) independent errors, and its variance is scaled up by N over that number
(counted in each window: at a turning point the reading rests on a step for a few samples and changes at
every sample around them; counting from the speed at the estimate, zero there, took the whole window for
one error). Nor is it drawn afresh where the reading changes by the same number of steps at every
sample (a joint at about one step a sample drifts through its rounding): the count is also at most
:data:`TURNS` times the window's changes of that number (:func:`turns_within`).

G, :data:`GAMMA`, is 4: the intervals must not break on noise alone over the thousands of estimates
a second of a robot's joints gives, and quantisation makes the noise heavier-tailed than a Gaussian.

The standard deviation stated with each estimate (:func:`stated_std`) is the chosen fit's noise and
the distance between its estimate and the next smaller window's, added in quadrature. The rule lets
the chosen window's bias reach a few of its noise's deviations (a larger one breaks the intersection),
and noise that the reading underrates (a real arm's coloured noise) breaks it early: the noise alone
stated an error 5x too small on a family of motions (median RMS of error / sigma 5.3) and 5-7x on the
Panda's recording. The next smaller window's estimate has a fraction of the bias (a polynomial's
bias grows as a power of the half-width: 2^(p/2) times smaller for p the bias's order) and its own
noise, so the distance between the two reads the bias and the noise that the intervals did not;
where neither is there it adds about the smaller window's noise (about 1.7x the chosen one's). The
family's median RMS of error / sigma became 1.43 (77 % of its motions between 0.5 and 2, the
trapezoidal moves' corners up to 35: ``bench/bench_estimator_family.py``) and the Panda's 2.4-3.5:
that distance is one draw, and where it happens to be small the error is not. The deviation stated
is therefore pooled (:func:`pooled_std`): the root mean square of the same joint's deviations over
the last half window's estimates, where larger than the estimate's own (the Panda's RMS of error /
sigma 1.13-1.59; the family's median 0.80, 76 % of its motions within 0.5-2). The
windows chosen and the two degrees' fusion stay on the noise alone: the estimates are the same.

The default fit runs the rule at degrees 6, 4 and 3 and chooses each joint's degree by the last second's
estimates (:mod:`.degree_choice`). Two degrees can also be fused (``lower``: the centred fit the causal
setting is scored against): the degree-4 choice where the two agree within G of their combined
deviations and it is the less noisy, the degree-6 one elsewhere: a slow, noisy motion keeps the quieter
degree 4 over the largest window, and a fast one (a 5 Hz sine, a move's corner) the degree 6, whose bias
lets the rule keep windows about twice as wide as degree 4's for the same error.

The node (one target at a time, :func:`adaptive_fit`) and the bag tool (every target at once,
:func:`adaptive_fits`) take the same windows, noise and rule: the same estimates.
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np

from neforward_ros.estimation import native_fit
from neforward_ros.estimation.fit import LEAST_PIVOT, ROUNDING_PIVOT, block_fits, polynomial_fits
from neforward_ros.stamps import NS

GAMMA = 4.0
"""Half-width of each confidence interval, in standard deviations."""
RATIO = math.sqrt(2.0)
"""Between consecutive half-widths of the ladder."""
LEVELS = 10
"""Half-widths tried at most."""
GROWTH = 4.0
"""The most a coloured noise's sixth differences grow from one stride to twice it (a smooth motion's
grow 64-fold): see :func:`noise_of`."""
FLOOR = 1e-9
"""The least noise, relative to the position: a still joint's samples, all alike, give fits that differ
only by rounding, which must not break the intervals."""
BLOCK = 2048
"""Targets fitted together by :func:`adaptive_fits`."""
GRID_CHUNK = 1 << 20
"""Differences checked against their windows' steps at once by the numpy fits (memory: 8 MB each)."""
LATTICE = 0.05
"""How far from a whole number of steps a difference between consecutive samples may be, in steps,
for the samples to be taken as on an encoder's grid (rounding of the driver's float conversion, to
float32 even, stays within 0.01 of a step down to 20-bit encoders)."""
ROUGHNESS = 0.01
"""The noise, relative to the samples' spread in the largest window, above which an estimate strains."""
_GAIN = math.sqrt(2.0 / math.pi)  # mean |N(0, 1)|
DIVISORS = native_fit.DIVISORS
"""An encoder's step is sought as the smallest change between consecutive samples of a window divided by
1, then by the base divisor (:data:`EXACT`) times 1, 2 ... this (:func:`grid_step`): a joint that moves
a few steps between its readings may change by two steps or more at every one of them. A driver that
stamps at writing and writes in bursts (ten samples 20 us apart every 15 ms) shows it most: its samples
repeat within a burst, and a joint's smallest change is what it moved between bursts; its sixth
differences, mostly within bursts, read almost no noise, and a window of three bursts was fitted as if
exact (q'' 259 rad/s^2 for 3). A fraction of the smallest change is taken only where the sixth
differences are thus blind to the rounding (:data:`HIDDEN`): a joint creeping two or three steps a
sample into a move's end, whose differences show its rounding, keeps the noise they read (taking the
step there, its rounding counted as drawn afresh only at the window's few turns, cost the default
1.24x -> 1.63x hindsight on a minimum-jerk move at 100 Hz)."""
EXACT = native_fit.EXACT
"""The base divisor of :func:`grid_step`: the least common multiple, for two changes (the smallest one
above the smallest change, and the largest), of the smallest denominator q among the continued
fraction's convergents of the change over the smallest change (r) that makes q r a whole number within
this; 1 where none at most :data:`LARGEST_DIVISOR` does. An encoder's counts in float64 give r to about
1e-12, and two fractions with denominators q, q' <= LARGEST_DIVISOR lie at least 1 / (q q') apart, so
no smaller denominator than the reduced fraction's comes within this: the base is the step's own divisor
or a divisor of it (a third change may lack a factor the two share: hence its multiples, up to
:data:`DIVISORS`). A float32 conversion's rounding (up to 0.01 of a step) is not within it: there the
base is 1, and the divisors 1, 2 ... DIVISORS. A 100 Hz writer stalled 30 ms at a time, 16 bits, shows
why: a joint moving 14-145 steps between bursts, its step 1/14 of its smallest change; with eight
divisors it was not found, the noise read nothing, and the causal settings' one-sided fits took a step
crossed within a burst for a slope (q'' 220 rad/s^2 for 0.86, 25 stated deviations off)."""
LARGEST_DIVISOR = native_fit.LARGEST_DIVISOR
"""The largest divisor of the smallest change :func:`grid_step` tries (:data:`EXACT`)."""
HIDDEN = native_fit.HIDDEN
"""The fraction of a grid's rounding (step / sqrt(12)) below which the noise read from the sixth
differences is taken as blind to it (:data:`DIVISORS`); bunched stamps read a millionth of it."""
_ROUNDING = 1.0 / math.sqrt(12.0)
NOISE_SAMPLES = native_fit.NOISE_SAMPLES
"""Where the largest window holds fewer samples than this, the white noise is also read from this many
up to its end (as many as there are, and short of a hole: :func:`noise_start`), and the larger of the two
readings is taken.
At 100 Hz the largest window (0.2 s) holds 20 samples, whose 14 sixth differences overlap (each spans 7
samples): their mean is a few independent draws, and read the noise 2-3 times too small at times (a
20-bit encoder's white rounding, 1.9e-6 rad, read as 6.6e-7). The intervals then broke on noise and a
small window was taken, its error 6-7 times the deviation stated: single estimates 3.7-6.5 times the
steady 99th percentile of the errors with no event at all (1.5 Hz sines and a gait at 100 Hz through
12-20 bits, degree 6 alone). Read from the longer stretch alone, a move's dwell (its readings still)
lowered the noise read for the move after it (the default 1.18x -> 1.60x hindsight on minimum-jerk
moves at 100 Hz through 12 bits): a reading from more samples guards against one too small, and the
window's own stays where it is the larger. From 320 Hz on the largest window holds as many."""
NOISE_HOLE = native_fit.NOISE_HOLE
"""The longer reading reaches back to no interval between samples longer than this many times the
largest window's longest (:func:`noise_start`): across a hole (a gap shorter than ``max_gap``, which
does not restart the history) a sixth difference spans the motion of the whole gap, and read as a
noise hundreds of times the encoder's, the intervals of the estimates after the gap held windows far
too wide (kalman 20 ms on a gait at 100 Hz through 20 bits: 1.01 -> 5.06 times the steady 99th
percentile in the second after a 0.3 s gap). A repeated reading left out is an interval of two periods,
within this of a window holding one."""
TURNS = 2.0
"""A window on an encoder's grid holds at most this many times its turns independent rounding errors
(:func:`turns_within`; the compiled fit writes the same number)."""
TIMING_STRIDE = native_fit.TIMING_STRIDE
"""Samples apart over which a joint's speed is read for the noise its stamps' uncertainty makes
(:func:`timing_noise`): across a few samples a write delay's share of the interval is a fraction of it."""


def timing_noise(times: np.ndarray, values: np.ndarray, timing: float) -> np.ndarray:
    """The position noise (n,) that samples (k, n) at ``times`` (k,) carry where their times may be off by
    about ``timing`` (s, a standard deviation): that times the fastest speed over :data:`TIMING_STRIDE`
    samples, zeros where too few. Until a stream's clock can tell whether its stamps are the samples' times
    or the times a driver wrote them, each may be off by their spread about the other
    (:attr:`~.clock.SampleClock.timing`), and a joint's motion over that time is noise that follows its speed:
    read from sixth differences over a window where the joint starts to move after a rest, it is read mostly
    where the joint was slower, and a causal fit's intervals broke on it (from a start on write times after
    a rest, the causal settings' worst error in the first second over 100 times the steady 99th percentile:
    ``bench/bench_write_jitter.py --start``)."""
    if len(times) <= TIMING_STRIDE:
        return np.zeros(values.shape[1])
    apart = times[TIMING_STRIDE:] - times[:-TIMING_STRIDE]
    moved = np.abs(values[TIMING_STRIDE:] - values[:-TIMING_STRIDE])
    least = timing * moved / np.where(apart > 0.0, apart, 1.0)[:, None]  # (the compiled fit's order)
    return np.max(np.where((apart > 0.0)[:, None], least, 0.0), axis=0)


def ladder(h_max: float) -> np.ndarray:
    """The half-widths tried, largest first."""
    return h_max / RATIO ** np.arange(LEVELS)


@lru_cache(maxsize=64)
def _ladder_and_leads(h_max: float, lead: float) -> tuple[np.ndarray, np.ndarray]:
    """The half-widths (largest first) and each one's reach past the target, as the C function
    takes them."""
    half_widths = np.ascontiguousarray(ladder(float(h_max)))
    return half_widths, np.ascontiguousarray(np.minimum(float(lead), half_widths))


def sixth_differences(times: np.ndarray, values: np.ndarray, stride: int = 1) -> np.ndarray:
    """The normalised sixth divided differences of samples ``stride`` apart: for every 7 samples
    i, i + stride, ..., i + 6 stride (count - 6 stride, n), the combination of their values that
    vanishes on every polynomial of degree 5 through their stamps (weights 1 / prod_(j != k)
    (t_k - t_j)), scaled to unit norm: white noise of deviation sigma gives N(0, sigma^2) whatever
    the stamps' spacing, so irregular stamps (a driver's jitter) do not read as noise. On evenly
    spaced stamps it is the sixth difference over sqrt(924)."""
    count = len(times) - 6 * stride
    if count <= 0:
        return np.zeros((0, values.shape[1]))
    stamps = np.stack([times[k * stride : k * stride + count] for k in range(7)], axis=1)  # (count, 7)
    spans = stamps[:, 6] - stamps[:, 0]
    x = (stamps - stamps[:, :1]) / np.where(spans > 0.0, spans, 1.0)[:, None]
    differences = x[:, :, None] - x[:, None, :]
    differences[:, np.arange(7), np.arange(7)] = 1.0
    weights = 1.0 / np.prod(differences, axis=2)
    weights *= 1.0 / np.sqrt(np.einsum("ik,ik->i", weights, weights))[:, None]
    total = weights[:, :1] * values[:count]
    for k in range(1, 7):
        total = total + weights[:, k : k + 1] * values[k * stride : k * stride + count]
    return total


def noise_of(times: np.ndarray, values: np.ndarray, coloured: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """(noise sigma, quantisation step) per column of consecutive samples (k, n) at ``times`` (k,);
    zeros when there are too few samples to tell.

    The noise is read from the mean absolute sixth divided difference (:func:`sixth_differences`) of
    consecutive samples, and, with
    ``coloured``, also of samples 2, 4, 8 ... apart while at least 8 such differences fit: a real
    arm's logged positions carry several times more noise at 15-100 Hz than at the sampling rate's
    Nyquist frequency (the Panda's, about 5x), which consecutive samples do not see, and which the
    larger windows' fits do. A stride's figure is taken (the largest of them) while it grows at most
    :data:`GROWTH` times from the stride before, at every stride up to it and at the next one: a smooth
    motion's sixth differences grow 64-fold per doubling, and where the motion shows, the strides stop
    (the next stride's check keeps the motion's share of a stride taken under GROWTH / 64)."""
    n = values.shape[1]
    if len(values) < 8:
        return np.zeros(n), np.zeros(n)
    first = values[1:] - values[:-1]
    sixth = sixth_differences(times, values)
    white = np.add.reduce(np.abs(sixth), axis=0) * (1.0 / (len(sixth) * _GAIN))
    if coloured:
        white = _coloured(times, values, np.array([0]), np.array([len(values)]), white[None])[0]
    steps = np.abs(first)
    steps[steps == 0.0] = np.inf
    step = np.minimum.reduce(steps, axis=0)
    step = np.where(np.isfinite(step), step, 0.0)
    return white, grid_step(first, step, white)


def grid_step(
    differences: np.ndarray, smallest: np.ndarray, white: np.ndarray, inside: np.ndarray | None = None
) -> np.ndarray:
    """The step of the encoder's grid that the samples whose consecutive differences are ``differences``
    (..., k, n) lie on (:func:`on_grid`), (..., n): their ``smallest`` non-zero change (..., n) where
    they lie on its grid; else the largest of it divided by the :func:`base_divisor` times 1, 2 ...
    :data:`DIVISORS` (at most :data:`LARGEST_DIVISOR`) that they lie on, where the noise read from their
    sixth differences, ``white`` (..., n), is below :data:`HIDDEN` of that step's rounding (step /
    sqrt(12)); 0 elsewhere. ``inside``: as for :func:`on_grid`."""
    step = np.where(on_grid(differences, smallest, inside), smallest, 0.0)
    # a smaller fraction's rounding is smaller still: where even a half's is not hidden, none is
    hidden = (step == 0.0) & (white < HIDDEN * (smallest / 2) * _ROUNDING)
    if not hidden.any():
        return step
    base = base_divisor(differences, smallest, inside)
    for multiple in range(DIVISORS, 0, -1):  # the largest step last: it stands where several fit
        divisor = base * multiple
        tried = hidden & (divisor >= 2.0) & (divisor <= LARGEST_DIVISOR)
        if not tried.any():
            continue
        candidate = smallest / np.where(tried, divisor, 1.0)  # (a base of 0, none found: not tried)
        fits = tried & on_grid(differences, candidate, inside) & (white < HIDDEN * candidate * _ROUNDING)
        step = np.where(fits, candidate, step)
    return step


def base_divisor(differences: np.ndarray, smallest: np.ndarray, inside: np.ndarray | None = None) -> np.ndarray:
    """(..., n): the least common multiple of :func:`exact_denominator` of two changes over the smallest,
    ``smallest`` (..., n), among ``differences`` (..., k, n) (``inside`` as for :func:`on_grid`): the
    smallest change above it by more than :data:`EXACT` of it, and the largest (:data:`EXACT`); 1 where
    neither gives one, 0 where it exceeds :data:`LARGEST_DIVISOR`."""
    size = np.abs(differences)
    if inside is not None:
        size = np.where(inside[..., None], size, 0.0)
    ratio = size / np.where(smallest > 0.0, smallest, 1.0)[..., None, :]
    two = np.stack([np.min(np.where(ratio - 1.0 > EXACT, ratio, np.inf), axis=-2), np.max(ratio, axis=-2)])
    denominators = exact_denominator(np.where(np.isfinite(two) & (two >= 1.0), two, 1.0))
    base = np.lcm(*np.maximum(denominators, 1.0).astype(np.int64))
    return np.where(base <= LARGEST_DIVISOR, base, 0).astype(float)


_ONE_BY_ONE = 128


def _denominator(ratio: float) -> float:
    """:func:`exact_denominator` of one ratio (the compiled reading's arithmetic)."""
    if abs(ratio - round(ratio)) <= EXACT:
        return 1.0
    before, now, rest = 0.0, 1.0, ratio - math.floor(ratio)
    for _ in range(native_fit.CONVERGENTS):
        if not (rest > 0.0 and now <= LARGEST_DIVISOR):
            return 0.0
        inverse = 1.0 / rest
        if inverse == math.inf:  # rest below 1e-308: as numpy and C go on, no denominator
            return 0.0
        term = float(math.floor(inverse))
        rest = inverse - term
        before, now = now, term * now + before
        product = now * ratio
        if now <= LARGEST_DIVISOR and abs(product - round(product)) <= EXACT:
            return now
    return 0.0


def exact_denominator(ratio: np.ndarray) -> np.ndarray:
    """The smallest denominator q of the continued fraction's convergents of ``ratio`` (at least 1)
    with q ratio a whole number within :data:`EXACT`, up to :data:`LARGEST_DIVISOR`; 0 where none.
    A few ratios (one window's) are expanded one by one, with the same arithmetic: numpy's calls on
    small arrays cost more than the sums."""
    if ratio.size <= _ONE_BY_ONE:
        return np.array([_denominator(x) for x in ratio.reshape(-1).tolist()]).reshape(ratio.shape)
    found = np.where(np.abs(ratio - np.round(ratio)) <= EXACT, 1.0, 0.0)
    open_ = np.flatnonzero(found == 0.0)  # the ratios still being expanded, and their terms so far
    x = ratio.reshape(-1)[open_]
    rest = x - np.floor(x)
    before, now = np.zeros_like(x), np.ones_like(x)  # the convergents' denominators
    flat = found.reshape(-1)
    for _ in range(native_fit.CONVERGENTS):
        going = (rest > 0.0) & (now <= LARGEST_DIVISOR)
        if not going.all():
            open_, x, rest, before, now = open_[going], x[going], rest[going], before[going], now[going]
        if not len(x):
            break
        with np.errstate(over="ignore", invalid="ignore"):  # a rest below 1e-308: inf, then NaN (dropped)
            inverse = 1.0 / rest
            term = np.floor(inverse)
            rest = inverse - term
            before, now = now, term * now + before
        product = now * x
        exact = (now <= LARGEST_DIVISOR) & (np.abs(product - np.round(product)) <= EXACT)
        if exact.any():
            flat[open_[exact]] = now[exact]
            rest[exact] = 0.0  # done
    return found


def on_grid(differences: np.ndarray, step: np.ndarray, inside: np.ndarray | None = None) -> np.ndarray:
    """Whether the samples whose consecutive differences are ``differences`` (..., k, n) lie on a grid
    of their column's ``step`` (..., n): every sample's distance from the first a whole number of steps
    within :data:`LATTICE`, and the changes not all the same number of steps (False where the step is
    0). ``inside`` (..., k): which differences are the window's (all where None).

    A smooth motion at a nearly steady speed, sampled without noise, changes by about the same amount
    every sample: every change is within a few percent of one smallest change, but its samples drift
    off any grid within a few samples, and one multiple alone is no grid (it stated the whole change,
    about v dt / sqrt(12), as noise: 0.36 rad/s^2 on a simulated Panda's q'' exact to 1e-7)."""
    ratio = differences * (1.0 / np.where(step > 0.0, step, 1.0))[..., None, :]
    if inside is not None:
        ratio = np.where(inside[..., None], ratio, 0.0)
    position = np.cumsum(ratio, axis=-2)
    off = np.max(np.abs(position - np.round(position)), axis=-2, initial=0.0)
    steps = np.round(ratio)
    first = steps[..., :1, :]
    if inside is None:
        varied = np.any(steps != first, axis=-2)
    else:
        varied = np.any((steps != first) & inside[..., None], axis=-2)
    return (step > 0.0) & (off <= LATTICE) & varied


def changes_up_to(y: np.ndarray) -> np.ndarray:
    """(T, n): how many times each column of y (T, n) changes between consecutive samples up to each
    sample (:func:`changes_within` counts a window's from it)."""
    return np.concatenate([np.zeros((1, y.shape[1])), np.cumsum(y[1:] != y[:-1], axis=0)])


def turns(y: np.ndarray) -> np.ndarray:
    """(T - 2, n): how much each column's change between consecutive samples changes at each sample
    from the third (an encoder's rounding error is drawn afresh where it does: see
    :func:`turns_within`)."""
    return np.abs((y[2:] - y[1:-1]) - (y[1:-1] - y[:-2]))


def turns_within(turned: np.ndarray, lo: np.ndarray, hi: np.ndarray, step: np.ndarray) -> np.ndarray:
    """(M, n): how many times the change between consecutive samples changes by half of ``step``
    (M, n) or more within each window [lo, hi) (M,) of the samples whose :func:`turns` is ``turned``;
    0 where the step is 0.

    On an encoder's grid, a joint that moves a steady number of steps a sample (a slow sine at about
    one step a sample, through 12 bits at 800 Hz) keeps its rounding error but for a slow drift: the
    error is drawn afresh only where the number of steps a sample changes. Counted as a change of
    the reading, each of those samples was an independent error, and a small window's stated noise
    was a third of its fits' actual spread; its estimate left the larger windows' intervals and the
    rule took it (degree 2 on such a sine: 2.3x the error of its largest window alone). A slow
    drift's wrap shows as two turns; but where the speed sweeps through many steps a sample across
    the window (a turning point's parabola at 1 kHz through 16 bits) its errors are nearly independent
    between turns too, and the turns alone overstated the noise there (RMS of error / sigma 0.53 with
    the changes, 0.46 with the turns): :data:`TURNS` times the turns leaves the parabola's at 0.53 and
    the slow sine's error at its largest window's (1.3 % and 1.4 % against 3.0 % and 3.1 %, two seeds)."""
    out = np.zeros(step.shape)
    longest = int(np.max(hi - lo - 2, initial=0))
    if longest <= 0 or not len(turned):
        return out
    chunk = max(1, GRID_CHUNK // max(longest * step.shape[1], 1))
    for start in range(0, len(lo), chunk):
        part = slice(start, start + chunk)
        index = lo[part, None] + np.arange(longest)
        inside = index < (hi[part] - 2)[:, None]
        taken = turned[np.minimum(index, len(turned) - 1)]  # (m, longest, n)
        counted = inside[..., None] & (taken >= 0.5 * step[part, None, :]) & (step[part, None, :] > 0.0)
        out[part] = np.count_nonzero(counted, axis=1)
    return out


def changes_within(changed: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(changes (M, n), pairs of consecutive samples (M,)) within the windows [lo, hi) (M,) of the
    samples whose :func:`changes_up_to` is ``changed``."""
    last = np.clip(hi - 1, 0, len(changed) - 1)
    first = np.minimum(lo, last)
    return changed[last] - changed[first], last - first


def _coloured(t: np.ndarray, y: np.ndarray, lo: np.ndarray, hi: np.ndarray, white: np.ndarray) -> np.ndarray:
    """The noise of :func:`noise_of` with strides 2, 4, 8 ..., for the windows [lo, hi) of y (T, n)
    at t (T,) whose stride-1 noise is ``white`` (M, n)."""
    best = white.copy()
    previous = white
    alive = np.ones(white.shape, dtype=bool)
    s = 2
    while 6 * s + 8 <= int(np.max(hi - lo, initial=0)):
        count = len(y) - 6 * s
        sixth = sixth_differences(t, y, s)
        total = np.concatenate([np.zeros((1, y.shape[1])), np.cumsum(np.abs(sixth), axis=0)])
        last = np.clip(hi - 6 * s, 0, count)  # differences wholly inside: [lo, hi - 6 s)
        number = np.maximum(last - lo, 0)
        noise = (total[last] - total[np.minimum(lo, last)]) / (np.maximum(number, 1)[:, None] * _GAIN)
        alive = alive & (number >= 8)[:, None] & (noise <= GROWTH * previous)
        best = np.where(alive & (previous > best), previous, best)  # a stride counts once the next one agrees
        previous = noise
        s *= 2
    return best


def select(
    estimates: np.ndarray, stds: np.ndarray, valid: np.ndarray, gamma: float = GAMMA
) -> tuple[np.ndarray, np.ndarray]:
    """The ICI choice among (L, ...) estimates, largest window first: (index of the chosen level (...),
    whether any level was valid). ``valid`` (L, ...): windows with enough samples (the others are
    skipped). Going from the smallest window up, the intervals' intersection only shrinks, so the
    choice is the largest window at which the running intersection is still non-empty: running
    maxima of the lower ends and minima of the upper ends, from the smallest window."""
    low = np.where(valid, estimates - gamma * stds, -np.inf)
    high = np.where(valid, estimates + gamma * stds, np.inf)
    low = np.maximum.accumulate(low[::-1], axis=0)[::-1]
    high = np.minimum.accumulate(high[::-1], axis=0)[::-1]
    meets = valid & (low <= high)
    return np.argmax(meets, axis=0), meets.any(axis=0)


def stated_std(estimates: np.ndarray, valid: np.ndarray, chosen: np.ndarray, std: np.ndarray) -> np.ndarray:
    """The standard deviation stated with the ICI choice ``chosen`` (...) among the levels' (L, ...)
    ``estimates``, ``std`` (...) the chosen level's noise: that noise and the chosen estimate's distance
    to the next smaller valid level's, added in quadrature; where the smallest valid level was chosen
    (the rule strained: even that window's bias broke the intersection, or nothing smaller fits), to
    the next larger level's instead (whose bias is larger: a bound, not an estimate); the noise alone
    where only one level is valid."""
    other, found = _neighbour(valid, chosen)
    apart = np.take_along_axis(estimates, chosen[None], 0)[0] - np.take_along_axis(estimates, other, 0)[0]
    return np.where(found, np.sqrt(std * std + apart * apart), std)


def between_std(
    valid: np.ndarray, chosen: np.ndarray, stds: np.ndarray, smaller: bool | np.ndarray = False
) -> np.ndarray:
    """The deviation that the noise alone puts between the chosen level's estimate and the level
    :func:`stated_std` measures its distance to (...): the root of the difference of their noise's
    variances (``stds`` (L, ...), each level's; the chosen fit is the best one on the samples both
    windows hold, so the other differs from it by the rest); 0 where only one level is valid. What of
    that distance lies beyond it is the noise's colour or a bias (:mod:`.degree_choice`). ``smaller``
    (one for all, or per target (M,) for (L, M, n)): 0 also where the chosen level is the smallest (the
    finer fit's: its distance to a larger window reads that window's bias, not the finer's colour)."""
    other, found = _neighbour(valid, chosen)
    if np.any(smaller):
        below = np.reshape(smaller, np.shape(smaller) + (1,) * (np.ndim(chosen) - np.ndim(smaller)))
        found = found & (~below | (other[0] > chosen))
    own, theirs = np.take_along_axis(stds, chosen[None], 0)[0], np.take_along_axis(stds, other, 0)[0]
    return np.where(found, np.sqrt(np.abs(theirs * theirs - own * own)), 0.0)


def finer_level(valid: np.ndarray, chosen: np.ndarray) -> np.ndarray:
    """The next smaller valid level than ``chosen`` (...) among ``valid`` (L, ...), or ``chosen`` where
    it is the smallest valid one."""
    below = np.minimum(chosen + 1, len(valid) - 1)
    return np.where((below > chosen) & np.take_along_axis(valid, below[None], 0)[0], below, chosen)


def _neighbour(valid: np.ndarray, chosen: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The level (1, ...) whose estimate :func:`stated_std` measures the chosen one's distance to: the
    next smaller valid one, else the next larger; and whether there is one (...)."""
    below = finer_level(valid, chosen)
    smaller = below > chosen
    above = np.maximum(chosen - 1, 0)[None]
    larger = ~smaller & (above[0] < chosen) & np.take_along_axis(valid, above, 0)[0]
    return np.where(smaller, below, above[0])[None], smaller | larger


PRECISION = 1e4
"""How much larger than a window's sum of squared deviations the running sum (from its chunk's start)
up to it may be for the window's to be taken as a difference of running sums (:func:`pooled_std`)."""
POOL_CHUNK = 8192
"""Estimates pooled at once by :func:`pooled_std` (each chunk's running sums start afresh)."""


def pooled_std(stamps_ns: np.ndarray, std: np.ndarray, window: float) -> np.ndarray:
    """The standard deviation stated with each estimate: its own (:func:`stated_std`, NaN where none),
    or where larger the root mean square of the finite ones of the same joint at the estimates of
    the last half ``window`` (stamps in (s - window / 2, s]), whose fits share most of their samples.

    One estimate's distance between two levels reads the bias and the coloured noise by a single
    draw: where it happens to be small the error is not (on the Panda's recording the RMS of error /
    sigma was 2.4-3.5 with the stated deviations' RMS about the errors' RMS). Pooled over its
    neighbours it reads their mean square, which a single draw's luck does not shrink; the estimate's
    own stays the floor, so a move's corner is not diluted by the calm before it. Only past
    estimates are pooled: the node has them when it states one (:class:`DeviationPool`, the same
    windows). 300,000 estimates of 7 joints take about 0.1 s.

    Args:
        stamps_ns: the estimates' stamps (M,), integer ns, increasing.
        std: (M, n) their own standard deviations.
        window: the estimator's window, s.

    Returns:
        (M, n).
    """
    squares, counted = _squares(np.asarray(std, dtype=float))
    total, count = window_sums(stamps_ns, squares, counted, _half_window_ns(window))
    return _pooled(squares, counted, total, count)


def window_sums(
    stamps_ns: np.ndarray, values: np.ndarray, counted: np.ndarray, span_ns: int
) -> tuple[np.ndarray, np.ndarray]:
    """Each row's window sums over the rows stamped in (s - span_ns, s]: of ``values`` (M, ...) (0
    where not counted) and of ``counted`` (M, ...) (1 where counted, 0 elsewhere), as differences of
    running sums; where a difference would lose the window's sum to rounding (a still joint's tiny
    values after a fast move's), summed directly, as the node sums every window (:class:`StampedRows`).

    Args:
        stamps_ns: (M,), integer ns, increasing.
        values, counted: (M, ...).
        span_ns: the window's length, ns.

    Returns:
        two (M, ...).
    """
    stamps_ns = np.asarray(stamps_ns, dtype=np.int64)
    total, count = np.empty(values.shape), np.empty(values.shape)
    first = np.searchsorted(stamps_ns, stamps_ns - span_ns, side="right")
    for start in range(0, len(stamps_ns), POOL_CHUNK):  # a chunk's rows, and the rows their windows reach
        stop = min(start + POOL_CHUNK, len(stamps_ns))
        reach = int(first[start])
        part, weight = values[reach:stop], counted[reach:stop]
        padding = np.zeros((1, *values.shape[1:]))
        running = np.concatenate([padding, np.cumsum(part, axis=0)])
        number = np.concatenate([padding, np.cumsum(weight, axis=0)])
        lo, hi = first[start:stop] - reach, np.arange(start, stop) + 1 - reach  # windows [lo, hi)
        sums = running[hi] - running[lo]
        # the difference of two running sums keeps the window's sum to about eps * the larger: where that
        # is not about 1e-12 of it, the window is summed directly
        loose = np.flatnonzero(np.any((running[hi] > PRECISION * sums).reshape(len(sums), -1), axis=1))
        if len(loose):
            bounds = np.stack([lo[loose], hi[loose]], axis=1).reshape(-1)
            sums[loose] = np.add.reduceat(np.concatenate([part, padding]), bounds, axis=0)[::2]
        total[start:stop], count[start:stop] = sums, number[hi] - number[lo]
    return total, count


class StampedRows:
    """The rows stamped within the last ``span_ns``, in stamp order, kept as one contiguous array of
    rows of ``shape`` (:attr:`window`): the node's pools (:class:`DeviationPool`, the default's
    :class:`~.degree_choice.DegreePool`), whose sums over it the whole-recording functions make from
    differences of running sums (:func:`window_sums`) or sliding ones."""

    def __init__(self, span_ns: int, shape: tuple[int, ...]) -> None:
        self._span_ns = span_ns
        self._stamps = np.zeros(64, dtype=np.int64)
        self._rows = np.zeros((64, *shape))
        self._first = self._end = 0

    def clear(self) -> None:
        """Forget every row (a new stream)."""
        self._first = self._end = 0

    def append(self, stamp_ns: int) -> None:
        """A row of zeros at ``stamp_ns`` (after every earlier row), the rows stamped at or before
        ``stamp_ns - span_ns`` forgotten."""
        if self._end == len(self._stamps):  # full: the window's rows moved to the front, room doubled
            kept = self._end - self._first
            size = max(len(self._stamps), 2 * kept)
            for name in ("_stamps", "_rows"):
                old = getattr(self, name)
                new = np.zeros((size, *old.shape[1:]), dtype=old.dtype)
                new[:kept] = old[self._first : self._end]
                setattr(self, name, new)
            self._first, self._end = 0, kept
        self._first += int(np.searchsorted(self._stamps[self._first : self._end], stamp_ns - self._span_ns, "right"))
        self._stamps[self._end] = stamp_ns
        self._rows[self._end] = 0.0
        self._end += 1

    @property
    def window(self) -> np.ndarray:
        """The rows kept (rows, *shape), the newest last: a view, to be written in place."""
        return self._rows[self._first : self._end]

    @property
    def stamps(self) -> np.ndarray:
        """The stamps of the rows kept (rows,), ns, the newest last: a view."""
        return self._stamps[self._first : self._end]

    @property
    def held_ns(self) -> int:
        """The span of the rows kept, ns: from the oldest's stamp to the newest's (0 with none)."""
        return int(self._stamps[self._end - 1] - self._stamps[self._first]) if self._end > self._first else 0


class DeviationPool:
    """:func:`pooled_std` one estimate at a time, in stamp order: the node's (each window summed
    directly; the whole-recording function's differences of running sums agree to about 1e-12)."""

    def __init__(self, window: float, joints: int) -> None:
        self._rows = StampedRows(_half_window_ns(window), (2, joints))  # squares, whether counted

    def clear(self) -> None:
        """Forget every estimate (a new stream)."""
        self._rows.clear()

    def state(self, stamp_ns: int, std: np.ndarray) -> np.ndarray:
        """The deviations (n,) to state with the estimate at ``stamp_ns`` (after every earlier one)
        whose own are ``std`` (n,)."""
        squares, counted = _squares(np.asarray(std, dtype=float))
        self._rows.append(stamp_ns)
        window = self._rows.window
        window[-1, 0], window[-1, 1] = squares, counted
        total, count = np.add.reduce(window, axis=0)
        return _pooled(squares, counted, total, count)


def _half_window_ns(window: float) -> int:
    return round(window / 2.0 * NS)


def _squares(std: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(squares of the finite deviations, 0 elsewhere; 1 where finite, 0 elsewhere)."""
    finite = np.isfinite(std)
    return np.where(finite, np.square(np.where(finite, std, 0.0)), 0.0), finite.astype(float)


def _pooled(squares: np.ndarray, counted: np.ndarray, total: np.ndarray, count: np.ndarray) -> np.ndarray:
    """The larger of each own deviation and its window's root mean square; NaN where it had none."""
    return np.where(counted > 0.0, np.sqrt(np.maximum(squares, total / np.maximum(count, 1.0))), np.nan)


def posed(enough: np.ndarray, pivots: np.ndarray) -> np.ndarray:
    """The levels (L, ...) that may be chosen: those of the leading run (from the largest window) that
    hold ``enough`` samples and whose fit is well posed (its normal equations' least relative pivot,
    ``pivots``, at least :data:`~neforward_ros.estimation.fit.LEAST_PIVOT`). Windows are nested: a
    smaller one than an ill-posed window holds fewer of the same samples."""
    return np.logical_and.accumulate(enough & (pivots >= LEAST_PIVOT), axis=0)


def rounding(pivots: np.ndarray) -> np.ndarray:
    """How much the least noise (:data:`FLOOR` of the position) is raised for fits whose normal
    equations' least relative pivots are ``pivots``: ``ROUNDING_PIVOT / pivot`` where that exceeds 1
    (:data:`~neforward_ros.estimation.fit.ROUNDING_PIVOT`), else 1."""
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.maximum(ROUNDING_PIVOT / pivots, 1.0)


def accel_std(
    variance: np.ndarray,
    white: np.ndarray,
    step: np.ndarray,
    count: np.ndarray,
    changes: np.ndarray,
    position: np.ndarray,
) -> np.ndarray:
    """The standard deviation of q'' from a fit: ``variance`` its factor for unit white noise,
    ``count`` samples in the window, ``changes`` how many times the samples change across it (an
    encoder's rounding is drawn afresh only when the reading changes: the window holds changes + 1
    independent rounding errors; the callers pass the fewer of those and :data:`TURNS` times its
    :func:`turns_within`), ``position`` the joint's position, times the fit's :func:`rounding` (the
    noise is at least :data:`FLOOR` of it: samples without any noise are still rounded, and the fits
    with them)."""
    quantisation = step**2 / 12.0
    crossings = np.where(step > 0.0, changes + 1.0, count)
    independent = np.minimum(np.maximum(crossings, 1.0), np.maximum(count, 1.0))
    effective = np.maximum(np.maximum(white**2, quantisation * count / independent), (FLOOR * position) ** 2)
    return np.sqrt(np.maximum(variance, 0.0) * effective)


def noise_reach(lo: np.ndarray | int, hi: np.ndarray | int) -> np.ndarray | int:
    """The furthest back the white noise is also read from for the largest windows [lo, hi): the
    :data:`NOISE_SAMPLES` up to hi (from 0 where there are fewer), or lo where a window holds as many
    (the compiled fit's ``noise_reach``)."""
    if isinstance(lo, int) and isinstance(hi, int):  # the node's one window: no arrays
        return max(min(lo, hi - NOISE_SAMPLES), 0)
    return np.maximum(np.minimum(lo, np.asarray(hi) - NOISE_SAMPLES), 0)


def noise_start(t: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Where that reading starts for the windows [lo, hi) of the samples at t: back from lo towards
    :func:`noise_reach`, short of any interval longer than :data:`NOISE_HOLE` times the window's longest
    (the compiled fit's ``noise_start``). One window at a time: only where the reach passes lo."""
    lo, hi = np.asarray(lo), np.asarray(hi)
    reach = noise_reach(lo, hi)
    start = np.array(lo, copy=True)
    for k in np.flatnonzero(reach < lo):
        longest = float(np.max(np.diff(t[lo[k] : hi[k]]), initial=0.0))
        holes = np.flatnonzero(np.diff(t[reach[k] : lo[k] + 1]) > NOISE_HOLE * longest)
        start[k] = reach[k] + (holes[-1] + 1 if len(holes) else 0)
    return start


def _window_noise(t: np.ndarray, y: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`noise_of` of the samples [lo, hi) of y (T, n) at t (T,), for many windows at once: two
    (M, n)."""
    sixth = np.abs(sixth_differences(t, y))
    total = np.concatenate([np.zeros((1, y.shape[1])), np.cumsum(sixth, axis=0)])
    last = np.clip(hi - 6, 0, len(sixth))  # sixth differences wholly inside: [lo, hi - 6)
    number = np.maximum(last - lo, 0)
    white = np.where(number[:, None] > 0, (total[last] - total[np.minimum(lo, last)]) / np.maximum(number, 1)[:, None],
                     0.0) / _GAIN  # fmt: skip
    white[hi - lo < 8] = 0.0
    white = _coloured(t, y, lo, hi, white)
    differences = np.diff(y, axis=0)
    steps = np.abs(differences)
    steps = np.where(steps > 0.0, steps, np.inf)
    pairs = np.stack([lo, np.maximum(hi - 1, lo + 1)], axis=1).reshape(-1)
    padded = np.concatenate([steps, np.full((1, y.shape[1]), np.inf)])
    step = np.minimum.reduceat(padded, np.minimum(pairs, len(steps)), axis=0)[::2]
    step = np.where(np.isfinite(step) & (hi - lo >= 8)[:, None], step, 0.0)
    ends = np.maximum(hi - 1, lo)
    longest = int(np.max(ends - lo, initial=0))
    chunk = max(1, GRID_CHUNK // max(longest * y.shape[1], 1))
    for start in range(0, len(lo), chunk):  # each window's differences on its own step's grid
        part = slice(start, start + chunk)
        index = lo[part, None] + np.arange(longest)
        inside = index < ends[part, None]
        taken = differences[np.minimum(index, len(differences) - 1)]
        step[part] = grid_step(taken, step[part], white[part], inside)
    return white, step


def _lead(level_half_width: float, lead: float) -> float:
    """How far a level's window reaches past the target: centred while the lag allows it."""
    return min(lead, level_half_width)


def fused(high: tuple[np.ndarray, ...], low: tuple[np.ndarray, ...], derivative: np.ndarray | int) -> tuple:
    """Two degrees' choices, each (value, first, second derivative, noise's standard deviation, ...)
    of one fit, joined column by column: the lower degree's where its estimate of the ``derivative``-th
    derivative (2 or 1, per column or for all) agrees with the higher's within :data:`GAMMA` of
    their noise's combined deviations and its noise is the smaller, the higher degree's elsewhere
    (every element of the tuples taken alike)."""
    second = np.asarray(derivative) == 2
    estimate_high, estimate_low = np.where(second, high[2], high[1]), np.where(second, low[2], low[1])
    agree = np.abs(estimate_low - estimate_high) <= GAMMA * np.hypot(low[3], high[3])
    take_low = agree & (low[3] <= high[3])
    return tuple(np.where(take_low, b, a) for a, b in zip(high, low, strict=True))


def adaptive_fits(
    t: np.ndarray,
    y: np.ndarray,
    targets: np.ndarray,
    h_max: float,
    order: int,
    lead: float,
    derivative: int = 2,
    lower: int | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Value, first and second derivative at each target (M, n), each column's window chosen by the
    ICI rule on its ``derivative``-th derivative (2 for positions; 1 for measured velocities, whose
    derivative is the acceleration); and that derivative's standard deviation (M, n).

    Args:
        t, y: samples (T,), (T, n), t strictly increasing, s.
        targets: (M,), s.
        h_max: the largest half-width, s.
        order: polynomial degree.
        lead: the largest reach past the target, s (h_max for a centred fit, 0 for a causal one).
        lower: a second, lower degree whose choice is :func:`fused` with ``order``'s; None: ``order`` alone.
    """
    value, first, second, std, *_ = degree_fits(t, y, targets, h_max, (order,), lead, derivative, lower)
    return (np.ascontiguousarray(value[0]), np.ascontiguousarray(first[0]), np.ascontiguousarray(second[0]),
            np.ascontiguousarray(std[0]))  # fmt: skip


def degree_fits(
    t: np.ndarray,
    y: np.ndarray,
    targets: np.ndarray,
    h_max: float,
    degrees: tuple[int, ...],
    lead: float,
    derivative: int = 2,
    lower: int | None = None,
    finer: bool = False,
) -> tuple[np.ndarray, ...]:
    """:func:`adaptive_fits` at each degree of ``degrees`` (the first the highest; ``lower`` fused with
    it alone), each with its own windows chosen, in one C call: the power sums and the noise reading
    shared, the numbers those of one call per degree to rounding. Value, first and second derivative,
    the derivative's stated standard deviation, its noise's (the chosen window's fit's own, without the
    distance to the neighbouring window's) and the noise's between the two (:func:`between_std`); the
    last two are the degree choice's (:mod:`.degree_choice`). Each (D, M, n); where ``finer``, the first
    degree's fit at the next smaller window than its rule's comes first (D = 1 + len(degrees))."""
    library = native_fit.FIT.get(wait=len(targets) >= native_fit.WORTH_WAITING)
    columns = np.full(y.shape[1], derivative)
    got = None if library is None else native_fit.fits(library, t, y, targets, *_ladder_and_leads(h_max, lead),
                                                       degrees[0], columns, GAMMA, ROUGHNESS, _GAIN, FLOOR, GROWTH,
                                                       LATTICE, lower, tuple(degrees[1:]), finer=finer)  # fmt: skip
    candidates = _candidates(degrees, lower, finer)
    if got is None:
        fits = [_numpy_fits(t, y, targets, h_max, degree, lead, derivative, fused, shifted)
                for degree, fused, shifted in candidates]  # fmt: skip
        value, first, second, noise, stated, between = (np.stack(entries) for entries in zip(*fits, strict=True))
        return value, first, second, stated, noise, between
    out, done = got
    value, first, second, stated, noise, between = (out[:, :, q].transpose(1, 0, 2) for q in (0, 1, 2, 3, 5, 6))
    rest = np.flatnonzero(~done)  # too few samples in a target's largest window: numpy's fits serve there
    for k, (degree, fused, shifted) in enumerate(candidates):
        if len(rest):
            numpy_fits = _numpy_fits(t, y, targets[rest], h_max, degree, lead, derivative, fused, shifted)
            for whole, part in zip((value, first, second, noise, stated, between), numpy_fits, strict=True):
                whole[k, rest] = part
    return value, first, second, stated, noise, between


def _candidates(degrees: tuple[int, ...], lower: int | None, finer: bool) -> list[tuple[int, int | None, bool]]:
    """:func:`degree_fits`' fits in its order: (degree, the lower degree fused with it, whether at the next
    smaller window than the rule's)."""
    fused_with = [lower] + [None] * (len(degrees) - 1)
    ours = [(degree, fused, False) for degree, fused in zip(degrees, fused_with, strict=True)]
    return [(degrees[0], None, True), *ours] if finer else ours


def python_adaptive_fits(
    t: np.ndarray,
    y: np.ndarray,
    targets: np.ndarray,
    h_max: float,
    order: int,
    lead: float,
    derivative: int = 2,
    lower: int | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """:func:`adaptive_fits` in numpy (two degrees fused: each fitted on its own)."""
    value, first, second, _, stated, _ = _numpy_fits(t, y, targets, h_max, order, lead, derivative, lower)
    return value, first, second, stated


def _numpy_fits(
    t: np.ndarray,
    y: np.ndarray,
    targets: np.ndarray,
    h_max: float,
    order: int,
    lead: float,
    derivative: int,
    lower: int | None,
    finer: bool = False,
) -> tuple[np.ndarray, ...]:
    """:func:`python_adaptive_fits` with the noise's standard deviation before the stated one: value,
    first and second derivative, noise's and stated standard deviation, and the noise's between the
    estimate and its neighbouring level's (:func:`between_std`) (M, n); ``finer`` (not with ``lower``): at
    the next smaller window than the rule's (:func:`finer_level`), where the noise was read off
    :data:`NOISE_SAMPLES` samples at least (else the rule's own)."""
    if lower is not None:
        high = _numpy_fits(t, y, targets, h_max, order, lead, derivative, None)
        return fused(high, _numpy_fits(t, y, targets, h_max, lower, lead, derivative, None), derivative)
    levels = ladder(h_max)
    first_lead = _lead(levels[0], lead)
    lo = np.searchsorted(t, targets + first_lead - 2.0 * levels[0], side="left")
    hi = np.searchsorted(t, targets + first_lead, side="right")
    changed, turned = changes_up_to(y), turns(y)
    white, step = _window_noise(t, y, lo, hi)
    first = noise_start(t, lo, hi)
    more = np.flatnonzero((first < lo) & (hi - first >= 8))
    if len(more):  # the white noise read from more samples too: the larger
        white[more] = np.maximum(white[more], _window_noise(t, y, first[more], hi[more])[0])
    out = [np.empty((len(targets), y.shape[1])) for _ in range(6)]
    for start in range(0, len(targets), BLOCK):  # a block of targets at a time: its levels stay in cache
        part = slice(start, start + BLOCK)
        chosen = _block_fits(t, y, targets[part], levels, order, lead, derivative, white[part], step[part], changed,
                             turned, finer and hi[part] - first[part] >= NOISE_SAMPLES)  # fmt: skip
        for whole, level in zip(out, chosen, strict=True):
            whole[part] = level
    return tuple(out)


def _block_fits(
    t: np.ndarray,
    y: np.ndarray,
    targets: np.ndarray,
    levels: np.ndarray,
    order: int,
    lead: float,
    derivative: int,
    white: np.ndarray,
    step: np.ndarray,
    changed: np.ndarray,
    turned: np.ndarray,
    finer: bool | np.ndarray = False,
) -> list[np.ndarray]:
    """:func:`adaptive_fits` for a block of targets, with their windows' noise: value, first and
    second derivative, the chosen derivative's noise's and stated standard deviation (:func:`stated_std`)
    and the noise's between it and its neighbouring level's (:func:`between_std`) (M, n). Levels whose
    window is too small at every target of the block are not fitted. ``changed``, ``turned``: y's
    :func:`changes_up_to` and :func:`turns`; a window's rounding errors are counted as the fewer of its
    changes and its turns. ``finer`` (M,) or one for all: at the next smaller window than the rule's
    (:func:`finer_level`) at those targets (where the noise was read off :data:`NOISE_SAMPLES` at least)."""
    needed = order + 3
    fits = []
    changes = []
    for h in levels:
        level_lead = _lead(h, lead)
        hi = np.searchsorted(t, targets + level_lead, side="right")
        lo = np.searchsorted(t, targets + level_lead - 2.0 * h, side="left")
        if fits and not np.any(hi - lo >= needed):
            break  # smaller windows hold fewer samples still
        fits.append(polynomial_fits(t, y, targets, h, order, level_lead, variance=True))
        changes.append(np.minimum(changes_within(changed, lo, hi)[0], TURNS * turns_within(turned, lo, hi, step)))
    pivots = np.stack([f[6] for f in fits])
    valid = posed(np.stack([f[5] >= needed for f in fits]), pivots)[:, :, None]
    estimates = np.stack([f[derivative] for f in fits])
    stds = np.stack([
        accel_std(f[2 + derivative][:, None], white, step, f[5][:, None], c, fits[0][0] * rounding(f[6])[:, None])
        for f, c in zip(fits, changes, strict=True)
    ])  # fmt: skip
    valid = np.broadcast_to(valid, estimates.shape)
    chosen, _ = select(estimates, stds, valid)
    chosen = np.where(np.reshape(finer, (-1, 1)), finer_level(valid, chosen), chosen)
    pick = chosen[None]
    picked = [np.take_along_axis(np.stack([f[i] for f in fits]), pick, 0)[0] for i in range(3)]
    noise = np.take_along_axis(stds, pick, 0)[0]
    between = between_std(valid, chosen, stds, smaller=finer)
    return [*picked, noise, stated_std(estimates, valid, chosen, noise), between]


def adaptive_fit(
    times: np.ndarray,
    values: np.ndarray,
    target: float,
    h_max: float,
    order: int,
    lead: float,
    derivative: np.ndarray,
    lower: int | None = None,
    timing: float = 0.0,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """:func:`adaptive_fits` at one target (the stream's): ``times, values`` the samples of the
    largest window ([target + lead - 2 h_max, target + lead]), which the noise is read from too;
    ``derivative`` (n,) 2 or 1 per column. Returns value, first and second derivative (n,), the
    chosen derivative's standard deviation (n,), and whether the estimate strains (n,): the smallest
    usable window was chosen (the motion changes as fast as the samples can show), or the samples
    vary beyond a smooth motion by more than :data:`ROUGHNESS` of their spread in the window (noise,
    or a motion too fast for the rate: the two look alike to differences). Every level's fit in one
    vectorised pass, with the arithmetic of :func:`neforward_ros.estimation.fit.polynomial_fits`; or,
    once compiled, the same in one C call (:mod:`neforward_ros.estimation.native_fit`). ``lower``: as
    for :func:`adaptive_fits`. ``timing``: s, how far the samples' times may be off (the noise read is at
    least :func:`timing_noise`'s; 0: none)."""
    value, first, second, std, strained, *_ = degree_fit(
        times, values, target, h_max, (order,), lead, derivative, lower, timing
    )
    return value[0], first[0], second[0], std[0], strained[0]


def degree_fit(
    times: np.ndarray,
    values: np.ndarray,
    target: float,
    h_max: float,
    degrees: tuple[int, ...],
    lead: float,
    derivative: np.ndarray,
    lower: int | None = None,
    timing: float = 0.0,
    finer: bool = False,
) -> tuple[np.ndarray, ...]:
    """:func:`adaptive_fit` at each degree of ``degrees`` (the first the highest; ``lower`` fused with
    it alone), in one C call (:func:`degree_fits`): its five, then the noise's standard deviation and
    the noise's between the estimate and its neighbouring level's (:func:`degree_fits`), each (D, n);
    ``finer``: as for :func:`degree_fits`."""
    library = native_fit.FIT.get()
    if library is not None:
        got = native_fit.fit(
            library, times, values, target, *_ladder_and_leads(h_max, lead), degrees[0], derivative, GAMMA,
            ROUGHNESS, _GAIN, FLOOR, GROWTH, LATTICE, lower, tuple(degrees[1:]), timing, finer,
        )  # fmt: skip
        if got is not None:
            return got
    fits = [_numpy_fit(times, values, target, h_max, degree, lead, derivative, fused, timing, shifted)
            for degree, fused, shifted in _candidates(degrees, lower, finer)]  # fmt: skip
    value, first, second, noise, strained, stated, between = (np.stack(entries) for entries in zip(*fits, strict=True))
    return value, first, second, stated, strained, noise, between


def python_adaptive_fit(
    times: np.ndarray,
    values: np.ndarray,
    target: float,
    h_max: float,
    order: int,
    lead: float,
    derivative: np.ndarray,
    lower: int | None = None,
    timing: float = 0.0,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """:func:`adaptive_fit` in numpy (two degrees fused: each fitted on its own)."""
    value, first, second, _, strained, stated, _ = _numpy_fit(times, values, target, h_max, order, lead, derivative,
                                                              lower, timing)  # fmt: skip
    return value, first, second, stated, strained


def _numpy_fit(
    times: np.ndarray,
    values: np.ndarray,
    target: float,
    h_max: float,
    order: int,
    lead: float,
    derivative: np.ndarray,
    lower: int | None,
    timing: float = 0.0,
    finer: bool = False,
) -> tuple[np.ndarray, ...]:
    """:func:`python_adaptive_fit`'s value, first and second derivative, noise's standard deviation,
    strain, stated standard deviation and the noise's between the estimate and its neighbouring level's
    (:func:`between_std`) (n,); ``finer`` (not with ``lower``): at the next smaller window than the rule's
    (:func:`finer_level`), the strain the rule's, where the noise was read off :data:`NOISE_SAMPLES` samples
    at least (else the rule's own window)."""
    if lower is not None:
        high = _numpy_fit(times, values, target, h_max, order, lead, derivative, None, timing)
        low = _numpy_fit(times, values, target, h_max, lower, lead, derivative, None, timing)
        return fused(high, low, derivative)
    levels = ladder(h_max)
    leads = np.minimum(lead, levels)
    lo = times.searchsorted(target + leads - 2.0 * levels, side="left")
    hi = times.searchsorted(target + leads, side="right")
    white, step = noise_of(times[lo[0] : hi[0]], values[lo[0] : hi[0]])
    first = int(noise_start(times, lo[:1], hi[:1])[0])
    if first < lo[0] and hi[0] - first >= 8:  # the white noise read from more samples too: the larger
        white = np.maximum(white, noise_of(times[first : hi[0]], values[first : hi[0]])[0])
    if timing > 0.0:
        white = np.maximum(white, timing_noise(times[lo[0] : hi[0]], values[lo[0] : hi[0]], timing))
    counts = (hi - lo).astype(float)
    valid = counts >= order + 3
    window = values[lo[0] : hi[0]]  # the largest window holds every other level's
    offsets = np.arange(hi[0] - lo[0])
    # A level with too few samples is fitted like the largest (the caller's support guarantees that
    # one enough) and never chosen.
    scale = np.where(valid, levels, levels[0])
    start, end = np.where(valid, lo, lo[0]) - lo[0], np.where(valid, hi, hi[0]) - lo[0]
    inside = (offsets >= start[:, None]) & (offsets < end[:, None])
    tau = (times[lo[0] : hi[0]] - target) / scale[:, None]
    value, d1, d2, var1, var2, pivots = block_fits(tau, inside, window, scale, order)
    valid = posed(valid, pivots)
    if not valid[0]:  # the largest window's samples do not determine the polynomial: no estimate
        nothing = np.full(values.shape[1], np.nan)
        return nothing, nothing, nothing, nothing, np.zeros(values.shape[1], dtype=bool), nothing, nothing
    second = derivative == 2
    estimates = np.where(second, d2, d1)
    variance = np.where(second, var2[:, None], var1[:, None])
    changes, _ = changes_within(changes_up_to(window), start, end)  # (levels, n) within each level's window
    changes = np.minimum(changes, TURNS * turns_within(turns(window), start, end, np.broadcast_to(step, changes.shape)))
    stds = accel_std(variance, white, step, counts[:, None], changes, value[0] * rounding(pivots)[:, None])
    usable = np.broadcast_to(valid[:, None], estimates.shape)
    chosen, _ = select(estimates, stds, usable)
    columns = np.arange(values.shape[1])
    smallest = max(int(np.count_nonzero(valid)) - 1, 0)  # the windows are nested: valid ones come first
    centred = window - np.add.reduce(window, axis=0) * (1.0 / len(window))
    spread = np.sqrt(np.einsum("ij,ij->j", centred, centred) * (1.0 / len(window)))  # the samples' deviation
    strained = ((chosen == smallest) & (smallest > 0)) | (white > ROUGHNESS * spread)
    if finer and hi[0] - first >= NOISE_SAMPLES:  # (a noise read off fewer samples: the rule's own window)
        chosen = finer_level(usable, chosen)
    noise = stds[chosen, columns]
    return (
        value[chosen, columns],
        d1[chosen, columns],
        d2[chosen, columns],
        noise,
        strained,
        stated_std(estimates, usable, chosen, noise),
        between_std(usable, chosen, stds, smaller=finer),
    )
