"""Local polynomial fits on irregular stamps: the numerics of every estimator in this package.

Savitzky-Golay smoothing generalised to non-uniform sampling: for a target time t*, a polynomial
of degree ``order`` in tau = (t - t*) / half_width is fitted by least squares to the samples of a
window around (or ending at) t*, and its value, first and second derivatives at t* are the
estimates. ``difference`` is the plain baseline (numpy.gradient twice).
"""

from __future__ import annotations

import numpy as np

from neforward_ros.errors import InputError

METHODS = ("polyfit", "difference")
DEFAULT_WINDOW = 0.2
"""Full width of the local fit, s."""
DEFAULT_ORDER = 4
"""Degree of the local polynomial of a fixed window or of a causal fit (one-sided windows: a higher
degree's noise grows fastest where they extrapolate, at the newest sample)."""
ADAPTIVE_ORDER = 6
"""Degree of the adaptive fit's polynomials where the windows reach past the estimate (fixed lag, whole
recordings): the reference of the default's degree choice (:mod:`~neforward_ros.estimation.degree_choice`,
among 6, 4 and 3; the support is :data:`DEFAULT_ORDER`'s), and, fused with :data:`DEFAULT_ORDER`'s
(:func:`~neforward_ros.estimation.adaptive.fused`), the centred fit the causal setting is scored against:
the intersection-of-confidence-intervals rule shrinks a window whose bias shows, and degree 6 lets it
keep windows about twice as wide on fast motions as degree 4 does for the same bias, while slow, noisy
motions keep degree 4's quieter fit over the largest window."""


def degrees(order: int | None, adaptive: bool, causal: bool) -> tuple[int, int | None]:
    """The polynomial degree a polyfit setting fits, and the second, lower degree fused with it (or
    None). ``order`` given: that degree alone. None: :data:`ADAPTIVE_ORDER` fused with
    :data:`DEFAULT_ORDER` for adaptive windows that reach past the estimate; :data:`DEFAULT_ORDER`
    alone for a fixed window or a causal fit."""
    if order is not None:
        return order, None
    if adaptive and not causal:
        return ADAPTIVE_ORDER, DEFAULT_ORDER
    return DEFAULT_ORDER, None


_CHUNK = 2048  # targets per vectorised block: bounds memory (about 2 order + 1 + n numbers per target and
# window sample) and keeps a block in cache
LEAST_PIVOT = 1e-10
"""The least pivot of the Cholesky factor of a fit's normal equations, relative to its diagonal entry, for
the fit to be made. Samples bunched at a few instants of a window (a driver that stamps at writing and
writes in bursts: ten samples 20 us apart every 15 ms) leave a polynomial of the fit's degree nearly
undetermined, and the normal equations, whose condition is the square of the samples' design's, lose
every digit: a 9-sample window of two bursts had a condition of 1e16-1e20 and gave q'' 1e3-1e5 times off
from exact positions, with a variance factor of either sign. On random designs (degrees 2, 4 and 6,
centred and one-sided, 1-11 bursts of 1-11 samples, ``test/test_fit_conditioning.py``) the variance
factor is wrong by up to a factor 7 (or negative) below a relative pivot of 1e-12 and within 1 % above
1e-10. A window less well posed than this gives no fit (the adaptive rule: neither does any smaller one).
A uniform window's least pivot is about 2e-3 (degree 6, centred) to 7e-7 (degree 6, one-sided)."""
ROUNDING_PIVOT = 1e-8
"""Below this least relative pivot (and above :data:`LEAST_PIVOT`) a fit's rounding can exceed the least
noise the adaptive rule takes (:data:`~neforward_ros.estimation.adaptive.FLOOR` of the position: a fit
of exact samples): it grows as about 1e-17 / pivot of the window's largest position times the fit's
noise gain (at most 1.2e-8 / pivot floors' deviations on 18,000 random designs), so the rule raises
that floor by ``ROUNDING_PIVOT / pivot`` there, and a fit's rounding stays within about one of its
stated deviations (8.5 without, between pivots of 1e-10 and 1e-9). Windows this poorly posed are rare
outside bursts (a one-sided degree-6 window with a dropout of a third of it); at a real encoder's noise
the raise is hidden under the noise."""
_ELEMENTWISE = 256  # matrices from which spd_inverse beats LAPACK's calls (lapack_inverse)


def local_polynomial(
    t: np.ndarray,
    y: np.ndarray,
    targets: np.ndarray,
    half_width: float,
    order: int,
    lead: float | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Value, first and second derivative at each target time of a local polynomial fit.

    For each target t*, fits y over the samples with t* + lead - 2 half_width <= t <= t* + lead
    (centred, |t - t*| <= half_width, when lead is half_width, the default; lead 0 is a causal,
    one-sided window ending at t*). A window holding fewer than ``order + 1`` samples is widened to
    the ``order + 1`` samples nearest its centre, and fewer samples in all lower the degree. The fit
    is least squares in tau = (t - t*) / half_width, vectorised over blocks of targets.

    Args:
        t: sample times (T,), s, strictly increasing.
        y: samples (T, n).
        targets: evaluation times (M,), s.
        half_width: half the window width, s.
        order: polynomial degree.
        lead: how far the window reaches past the target, s, between 0 and 2 half_width.

    Returns:
        three arrays of shape (M, n).
    """
    fits = polynomial_fits(t, y, targets, half_width, order, lead)
    return fits[0], fits[1], fits[2]


def polynomial_fits(
    t: np.ndarray,
    y: np.ndarray,
    targets: np.ndarray,
    half_width: float,
    order: int,
    lead: float | None = None,
    variance: bool = False,
) -> tuple[np.ndarray, ...]:
    """:func:`local_polynomial`'s value, first and second derivative; with ``variance``, also each
    target's variance factors of the first and second derivative for unit white noise (M,), its
    window's sample count (M,) and its normal equations' least relative pivot (M,) (:func:`spd_inverse`;
    NaN estimates where it is below :data:`LEAST_PIVOT`)."""
    lead = half_width if lead is None else lead
    count = len(t)
    degree = min(order, count - 1)
    needed = degree + 1
    lo = np.searchsorted(t, targets - (2.0 * half_width - lead), side="left")
    hi = np.searchsorted(t, targets + lead, side="right")
    short = hi - lo < needed
    if np.any(short):  # too few samples in the window: take the `needed` nearest its centre instead
        centre = np.searchsorted(t, targets[short] + (lead - half_width))
        lo[short] = np.clip(centre - needed // 2, 0, count - needed)
        hi[short] = lo[short] + needed
    width = int(np.max(hi - lo))
    value, d1, d2 = (np.empty((len(targets), y.shape[1])) for _ in range(3))
    var1, var2, pivots = np.empty(len(targets)), np.empty(len(targets)), np.empty(len(targets))
    for start in range(0, len(targets), _CHUNK):
        block = slice(start, start + _CHUNK)
        index = lo[block, None] + np.arange(width)
        inside = index < hi[block, None]
        index = np.minimum(index, count - 1)
        tau = (t[index] - targets[block, None]) / half_width
        fit = block_fits(tau, inside, y[index], half_width, degree)
        value[block], d1[block], d2[block], var1[block], var2[block], pivots[block] = fit
    if not variance:
        return value, d1, d2
    return value, d1, d2, var1, var2, (hi - lo).astype(float), pivots


def block_fits(
    tau: np.ndarray, inside: np.ndarray, values: np.ndarray, half_width: np.ndarray | float, degree: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Least-squares fits of a polynomial of ``degree`` in tau, one per row of tau (B, W): the
    samples where ``inside`` (B, W) is false count for nothing. ``values`` (B, W, n), or (W, n)
    shared by every row; ``half_width`` (B,) or a float, s, the unit of tau. Returns the value, first
    and second derivative at tau = 0 (B, n) and the variance factors of the first and second
    derivative for unit white noise (B,) (the second's is inf below degree 2).

    The normal equations' matrix is a Hankel matrix of the sums of tau^0 .. tau^(2 degree), formed
    from those sums; only the inverse's first three rows are applied to the moments."""
    powers = np.empty((2 * degree + 1, *tau.shape))  # tau^k per sample, 0 outside the window
    powers[0] = inside
    for power in range(1, 2 * degree + 1):
        np.multiply(powers[power - 1], tau, out=powers[power])
    sums = powers @ np.ones(tau.shape[-1])  # (2 degree + 1, B): a matrix-vector product sums fastest
    k = np.arange(degree + 1)
    gram = sums[k[:, None] + k[None, :]].transpose(2, 0, 1)  # (B, degree + 1, degree + 1)
    moments = powers[: degree + 1].transpose(1, 0, 2) @ values  # (B, degree + 1, n)
    inverse, pivots = spd_inverse(gram) if len(gram) >= _ELEMENTWISE else lapack_inverse(gram)
    rows = min(degree, 2) + 1
    coefficients = inverse[:, :rows] @ moments
    scale = np.asarray(half_width, dtype=float)
    column = scale[:, None] if scale.ndim else scale
    d1 = coefficients[:, 1] / column
    if degree >= 2:
        d2 = 2.0 * coefficients[:, 2] / column**2
        var2 = 4.0 * inverse[:, 2, 2] / scale**4
    else:
        d2, var2 = np.zeros_like(d1), np.full(len(tau), np.inf)
    return coefficients[:, 0], d1, d2, inverse[:, 1, 1] / scale**2, var2, pivots


def lapack_inverse(matrices: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`spd_inverse` by LAPACK's batched Cholesky factor L and L's inverse (the inverse is
    L^-T L^-1, as there): for a few matrices, several times faster than the elementwise factorisation,
    which serves where LAPACK finds a matrix not positive definite (it raises)."""
    try:
        low = np.linalg.cholesky(matrices)
        inverse_low = np.linalg.inv(low)
    except np.linalg.LinAlgError:
        return spd_inverse(matrices)
    least = np.min(np.einsum("bii->bi", low) ** 2 / np.einsum("bii->bi", matrices), axis=1)
    inverse = np.swapaxes(inverse_low, 1, 2) @ inverse_low
    inverse[least < LEAST_PIVOT] = np.nan
    return inverse, least


def spd_inverse(matrices: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The inverse of each symmetric positive definite matrix of (B, d, d), by a Cholesky factorisation
    written out elementwise over B (for many small matrices, several times faster than LAPACK's one call
    per matrix), and each factorisation's least pivot relative to its diagonal entry (B,): the least
    ratio of the factor's squared diagonal entry to the matrix's (0 where one is not positive). A matrix
    whose least relative pivot is below :data:`LEAST_PIVOT` (not positive definite, or too ill-conditioned
    for its inverse to mean anything) gets NaN."""
    d = matrices.shape[-1]
    entries = np.moveaxis(matrices, 0, -1)  # (d, d, B)
    low = np.zeros(entries.shape)
    least = np.full(entries.shape[-1], np.inf)
    with np.errstate(invalid="ignore", divide="ignore"):
        for j in range(d):
            pivot = entries[j, j] - np.einsum("kb,kb->b", low[j, :j], low[j, :j])
            relative = pivot / entries[j, j]
            np.fmin(least, np.where(relative > 0.0, relative, 0.0), out=least)
            pivot = np.where(least >= LEAST_PIVOT, pivot, np.nan)
            np.sqrt(pivot, out=low[j, j])
            below = entries[j + 1 :, j] - np.einsum("ikb,kb->ib", low[j + 1 :, :j], low[j, :j])
            low[j + 1 :, j] = below / low[j, j]
        inverse_low = np.zeros(entries.shape)  # the lower factor's inverse, row by row
        for i in range(d):
            inverse_low[i, i] = 1.0 / low[i, i]
            if i:
                inverse_low[i, :i] = -np.einsum("kb,kjb->jb", low[i, :i], inverse_low[:i, :i]) * inverse_low[i, i]
    return np.einsum("kib,kjb->bij", inverse_low, inverse_low), least


def check_settings(method: str, window: float, order: int) -> None:
    if method not in METHODS:
        raise InputError(f"unknown method {method!r}; choose one of {', '.join(METHODS)}")
    if not (isinstance(window, (int, float)) and np.isfinite(window) and window > 0.0):
        raise InputError(f"window must be a positive number of seconds, got {window!r}")
    if not (isinstance(order, (int, np.integer)) and order >= 2):
        raise InputError(f"order must be an integer of at least 2, got {order!r}")


def fit_at(
    times: np.ndarray, values: np.ndarray, target_s: float, half_width: float, order: int, lead: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`local_polynomial` at one target: value, first and second derivative per column.

    The common case (a full window) is solved directly, with the same window and normal equations
    as :func:`local_polynomial`, at a fraction of its overhead; sparse windows go through it.
    """
    lo = int(times.searchsorted(target_s - (2.0 * half_width - lead), side="left"))
    hi = int(times.searchsorted(target_s + lead, side="right"))
    if hi - lo < order + 1 or len(times) < order + 1:
        fit = local_polynomial(times, values, np.array([target_s]), half_width, order, lead)
        return fit[0][0], fit[1][0], fit[2][0]
    if hi - lo < len(times):
        times, values = times[lo:hi], values[lo:hi]
    return fit_window(times, values, target_s, half_width, order)


def fit_window(
    times: np.ndarray, values: np.ndarray, target_s: float, half_width: float, order: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The fit of :func:`fit_at` on exactly the samples given (at least order + 1 of them)."""
    tau = (times - target_s) / half_width
    basis = np.vander(tau, order + 1, increasing=True)  # powers by repeated products, as local_polynomial
    transposed = basis.T
    gram = transposed @ basis
    coefficients = np.linalg.solve(gram, transposed @ values)
    return coefficients[0], coefficients[1] / half_width, 2.0 * coefficients[2] / half_width**2


def local_difference(
    times: np.ndarray, values: np.ndarray, target_s: float, lead: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """numpy.gradient applied twice around the sample at or before target_s, on the samples available.

    With two samples on either side this equals the whole-recording ``"difference"`` estimate there.
    """
    k = int(np.searchsorted(times, target_s, side="right")) - 1
    hi = min(len(times), int(np.searchsorted(times, target_s + lead, side="right")), k + 3)
    lo = max(0, min(k - 2, hi - 5))
    t, y = times[lo:hi], values[lo:hi]
    if len(t) < 3:
        if len(t) < 2:  # one sample: nothing to differentiate
            return y[k - lo], np.full_like(y[0], np.nan), np.full_like(y[0], np.nan)
        d1 = (y[-1] - y[0]) / (t[-1] - t[0])
        return y[k - lo], d1, np.full_like(d1, np.nan)
    first = np.gradient(y, t, axis=0, edge_order=2)
    second = np.gradient(first, t, axis=0, edge_order=2)
    return y[k - lo], first[k - lo], second[k - lo]
