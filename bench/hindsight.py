"""The hindsight reference of the estimator benchmarks: the best fixed-window local polynomial for a
given delay, window and degree picked per motion knowing the true accelerations.

For a delay d, a candidate is a window of N consecutive samples and a degree p; the estimate at
sample i is the second derivative at t_i of the least-squares polynomial of degree p through the N
samples ending min(d, half the window) after t_i (centred while the delay allows it, as the
estimators' own windows are). Every N of a geometric ladder (ratio 1.25, from p + 2 samples to 0.8 s)
and every p in 2..5 is tried; the candidate with the smallest relative RMS error against the truth
at the evaluated samples is the reference. Written here, with numpy's least squares, independently
of the package's fits.
"""

from __future__ import annotations

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

DEGREES = (2, 3, 4, 5)
RATIO = 1.25
LONGEST = 0.2  # s: the settings' window


def relative_rms(estimate: np.ndarray, truth: np.ndarray) -> float:
    """RMS of the error over RMS of the truth, every column pooled."""
    return float(np.sqrt(np.nanmean((estimate - truth) ** 2)) / np.sqrt(np.mean(truth**2)))


def fixed_window(
    t: np.ndarray, q: np.ndarray, targets: np.ndarray, count: int, degree: int, delay: float
) -> np.ndarray:
    """q'' (len(targets), n) at the sample indices ``targets`` from the fit of ``count`` samples and
    ``degree``, its window ending ``min(delay, window / 2)`` after each target; NaN where the window
    leaves the samples."""
    step = float(np.median(np.diff(t)))
    lead = round(min(delay, 0.5 * (count - 1) * step) / step)
    first = targets + lead - count + 1
    ok = (first >= 0) & (targets + lead < len(t))
    out = np.full((len(targets), q.shape[1]), np.nan)
    rows = np.flatnonzero(ok)
    if not len(rows):
        return out
    windows_t = sliding_window_view(t, count)[first[rows]]  # (M, N)
    windows_q = sliding_window_view(q, count, axis=0)[first[rows]]  # (M, n, N)
    scale = (windows_t[:, -1] - windows_t[:, 0])[:, None]  # per window: well conditioned across gaps
    tau = (windows_t - t[targets[rows]][:, None]) / scale
    vander = tau[:, :, None] ** np.arange(degree + 1)  # (M, N, p + 1)
    transposed = vander.transpose(0, 2, 1)
    normal = transposed @ vander
    right = transposed @ windows_q.transpose(0, 2, 1)
    coefficients = np.linalg.solve(normal, right)  # (M, p + 1, n)
    out[rows] = 2.0 * coefficients[:, 2, :] / scale**2
    return out


def best(t: np.ndarray, q: np.ndarray, qdd: np.ndarray, targets: np.ndarray, delay: float) -> tuple[float, str]:
    """(the smallest relative RMS error of q'' at ``targets`` over the candidates, which one)."""
    step = float(np.median(np.diff(t)))
    truth = qdd[targets]
    found = (np.inf, "")
    for degree in DEGREES:
        count = degree + 2
        while count * step <= LONGEST and count <= len(t):
            estimate = fixed_window(t, q, targets, count, degree, delay)
            if not np.isnan(estimate).any():
                error = relative_rms(estimate, truth)
                if error < found[0]:
                    found = (error, f"{count} samples, degree {degree}")
            count = max(count + 1, round(count * RATIO))
    return found
