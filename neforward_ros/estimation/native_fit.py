"""The node's adaptive polynomial fit (:func:`neforward_ros.estimation.adaptive.adaptive_fit`) as
machine code: the same windows, noise, fits and ICI rule, written in C and compiled once per machine.

The Python function makes some sixty numpy calls per estimate, each a few microseconds however small
its arrays: about 0.2 ms a message, which at 2 kHz is most of the node's budget. Here one C call
does the same. Its arithmetic differs from numpy's only in the order of additions: the windows are
nested, so each sample's powers are added once, ring by ring from the smallest window outwards (in
the largest window's unit, rescaled per level: inner sums never come from differences of larger
ones), where the Python function fits each level on its own; and the normal equations are solved
through a Cholesky factor where numpy calls LAPACK. The two agree to rounding (tested, with the same
window chosen). Several degrees come from one call: a lower degree's normal equations are the leading
rows and columns of the higher's, so they share the power sums, the noise reading and, per level, one
Cholesky factor L, the first three columns of L^-1 and L^-1 b, from which each degree's coefficients and
variance factors are partial sums (two degrees fused, ``lower``; or further degrees each with its own
windows chosen, ``also``: the default's 4 and 2 besides its 6, the same numbers as one call per degree).
A whole recording's targets (``adaptive_fits``) take each block's sixth differences from one pass, the
same numbers added in the same order as for one target: the node and the bag tool give bitwise the
same estimates (tested). The default's degree choice (:mod:`.degree_choice`) is here too: the node's
(``choose_last``, the last second's score terms summed directly) and the whole recording's
(``choose_degrees``, sliding sums added up afresh where their rounding could show: the two agree to
about 1e-12, tested).

Compiled with the system's C compiler (``cc``, ``$CC``) on first use, in a thread, and kept in the
disk cache (:mod:`neforward_ros.disk_cache`, ``kernels/``); until it is ready, and where there is no
compiler or ``NEFORWARD_NATIVE=off``, the Python function serves.
"""

from __future__ import annotations

import ctypes
import itertools
import os
import subprocess
import threading

import numpy as np

from neforward_ros.estimation import native_kalman
from neforward_ros.estimation.fit import LEAST_PIVOT, ROUNDING_PIVOT
from neforward_ros.kinematics import native

DIVISORS = 8
"""The multiples of the base divisor tried for an encoder's step (:data:`~.adaptive.DIVISORS`)."""
EXACT = 1e-6
"""How close to a whole number of a step two changes must be for their ratio to give it
(:data:`~.adaptive.EXACT`)."""
LARGEST_DIVISOR = 4096
"""The largest divisor of the smallest change tried for an encoder's step (:data:`~.adaptive.EXACT`)."""
CONVERGENTS = 24
"""The continued fraction's terms taken for a ratio's denominator (the 24th convergent's is at least
Fibonacci's F(25) = 75025, beyond :data:`LARGEST_DIVISOR`)."""
HIDDEN = 0.1
"""Below this fraction of a fractional step's rounding, the noise read is blind to it
(:data:`~.adaptive.HIDDEN`)."""
NOISE_SAMPLES = 64
"""Samples the white noise is also read from where the largest window holds fewer
(:data:`~.adaptive.NOISE_SAMPLES`)."""
NOISE_HOLE = 2.5
"""The reading reaches back to no interval longer than this many times the window's longest
(:data:`~.adaptive.NOISE_HOLE`)."""
TIMING_STRIDE = 4
"""Samples apart over which a joint's speed is read for the noise its stamps' uncertainty makes
(:data:`~.adaptive.TIMING_STRIDE`)."""

WORTH_WAITING = 5000
"""Targets from which a batch waits for the build rather than fitting in numpy meanwhile."""
MAX_ORDER = 15
"""The highest polynomial degree the C function takes (the Python function serves above it)."""
MAX_ALSO = 4
"""The further degrees one call fits besides its own (``MAX_ALSO`` in the C source)."""
FLAGS = ("-O3", "-fPIC", "-shared", "-ffp-contract=off", "-fno-fast-math")
"""-O3 vectorises the loops over joints (each joint's sums still added in order: no reassociation
without fast-math): a third faster than -O1 for a humanoid's 33 joints, built in 0.3 s."""

SOURCE = f"""
#define LEAST_PIVOT {LEAST_PIVOT!r}  /* fit.LEAST_PIVOT */
#define ROUNDING_PIVOT {ROUNDING_PIVOT!r}  /* fit.ROUNDING_PIVOT */
#define DIVISORS {DIVISORS}  /* adaptive.DIVISORS */
#define EXACT {EXACT!r}  /* adaptive.EXACT */
#define LARGEST_DIVISOR {LARGEST_DIVISOR}.0  /* adaptive.LARGEST_DIVISOR */
#define CONVERGENTS {CONVERGENTS}
#define HIDDEN {HIDDEN!r}  /* adaptive.HIDDEN */
#define NOISE_SAMPLES {NOISE_SAMPLES}  /* adaptive.NOISE_SAMPLES */
#define NOISE_HOLE {NOISE_HOLE!r}  /* adaptive.NOISE_HOLE */
#define TIMING_STRIDE {TIMING_STRIDE}  /* adaptive.TIMING_STRIDE */
"""
SOURCE += r"""
#include <math.h>
#include <stdlib.h>

#define MAX_ALSO 4  /* further degrees one call fits besides its own */

static double exact_denominator(double ratio) {  /* adaptive.exact_denominator, for one ratio */
    if (fabs(ratio - nearbyint(ratio)) <= EXACT) return 1.0;
    double before = 0.0, now = 1.0, rest = ratio - floor(ratio);
    for (int term = 0; term < CONVERGENTS; term++) {
        if (!(rest > 0.0 && now <= LARGEST_DIVISOR)) return 0.0;
        double inverse = 1.0 / rest, whole = floor(inverse), next = whole * now + before;
        rest = inverse - whole;
        before = now;
        now = next;
        double product = now * ratio;
        if (now <= LARGEST_DIVISOR && fabs(product - nearbyint(product)) <= EXACT) return now;
    }
    return 0.0;
}

static long common_multiple(long a, long b) {
    long x = a, y = b;
    while (y != 0) { long r = x % y; x = y; y = r; }
    return a / x * b;
}

/* adaptive.base_divisor, for one column (its samples `stride` apart) of `width` samples */
static double base_divisor(const double *column, long width, long stride, double smallest) {
    double above = INFINITY, largest = 0.0;
    for (long i = 0; i + 1 < width; i++) {
        double ratio = fabs(column[(i + 1) * stride] - column[i * stride]) / smallest;
        if (ratio - 1.0 > EXACT && ratio < above) above = ratio;
        if (ratio > largest) largest = ratio;
    }
    double ratios[2] = {above, largest};
    long base = 1;
    for (int k = 0; k < 2; k++) {
        double ratio = isfinite(ratios[k]) && ratios[k] >= 1.0 ? ratios[k] : 1.0;
        double denominator = exact_denominator(ratio);
        base = common_multiple(base, denominator > 1.0 ? (long)denominator : 1);
    }
    return base <= (long)LARGEST_DIVISOR ? (double)base : 0.0;
}

static long lower_bound(const double *t, long count, double x) {  /* first index with t >= x */
    long lo = 0, hi = count;
    while (lo < hi) { long mid = (lo + hi) / 2; if (t[mid] < x) lo = mid + 1; else hi = mid; }
    return lo;
}

static long upper_bound(const double *t, long count, double x) {  /* first index with t > x */
    long lo = 0, hi = count;
    while (lo < hi) { long mid = (lo + hi) / 2; if (t[mid] <= x) lo = mid + 1; else hi = mid; }
    return lo;
}

/* numpy's maximum and minimum: NaN if either is */
static double nmax(double a, double b) { return isnan(a) || isnan(b) ? NAN : (a > b ? a : b); }
static double nmin(double a, double b) { return isnan(a) || isnan(b) ? NAN : (a < b ? a : b); }

/* the weights of the sixth divided difference of t[0], t[s], ..., t[6 s], scaled to unit norm: the
   combination of seven samples that vanishes on every polynomial of degree 5 through their stamps */
static void divided_weights(const double *t, long s, double *w) {
    double span = t[6 * s] - t[0], x[7], norm = 0.0;
    if (!(span > 0.0)) span = 1.0;
    for (long k = 0; k < 7; k++) x[k] = (t[k * s] - t[0]) / span;
    for (long k = 0; k < 7; k++) {
        double p = 1.0;
        for (long j = 0; j < 7; j++) p *= j == k ? 1.0 : x[k] - x[j];
        w[k] = 1.0 / p;
        norm += w[k] * w[k];
    }
    norm = 1.0 / sqrt(norm);
    for (long k = 0; k < 7; k++) w[k] *= norm;
}

/* One level's fits of several degrees from the same power sums (sums[k] = sum of u^k, moments[k n + j]
   = sum of u^k y_j, u in the largest window's unit h0), into fit[g] (n, 5) for each g with wanted[g]:
   value, first and second derivative, and the chosen derivative's variance factor for unit noise.
   A degree's normal equations are the leading rows and columns of a higher one's, so one Cholesky
   factor L of the highest's serves every degree (its leading block), as do the first three columns of
   X = L^-1 and y = X b (b the scaled moments): the coefficients (A^-1 b)_q = sum_{i=q}^{e} X[i][q] y[i]
   and the variance factors (A^-1)_qq = sum_{i=q}^{e} X[i][q]^2, each sum up to the degree e.
   Returns the number of leading columns factored (the equations too ill-posed beyond: a pivot below
   LEAST_PIVOT of its diagonal entry, see fit.py): degree e's fit is made where e + 1 is at most that.
   fit[g]'s fifth entry is the factor by which the least noise is raised for its rounding (ROUNDING_PIVOT
   over the least relative pivot of its columns, at least 1). */
static long level_fits(const double *sums, const double *moments, long n, long ndeg, const long *degree,
                       const int *wanted, double *const *fit, double h, double h0, const long *derivative) {
    long d = 0;
    for (long g = 0; g < ndeg; g++) if (wanted[g] && degree[g] + 1 > d) d = degree[g] + 1;
    double low[16 * 16], inverse_diagonal[16], x[3 * 16], scale[33], r = h0 / h;
    scale[0] = 1.0;
    for (long k = 1; k <= 2 * (d - 1); k++) scale[k] = scale[k - 1] * r;
    long ok = d;
    double least[16];  /* the least relative pivot of columns 0 .. j */
    for (long j = 0; j < d && ok == d; j++) {
        double diagonal = sums[2 * j] * scale[2 * j], pivot = diagonal;
        for (long k = 0; k < j; k++) pivot -= low[j * 16 + k] * low[j * 16 + k];
        double relative = pivot / diagonal;
        if (!(pivot > 0.0) || !(relative >= LEAST_PIVOT)) { ok = j; break; }
        least[j] = j > 0 && least[j - 1] < relative ? least[j - 1] : relative;
        low[j * 16 + j] = sqrt(pivot);
        inverse_diagonal[j] = 1.0 / low[j * 16 + j];
        for (long i = j + 1; i < d; i++) {
            double s = sums[i + j] * scale[i + j];
            for (long k = 0; k < j; k++) s -= low[i * 16 + k] * low[j * 16 + k];
            low[i * 16 + j] = s * inverse_diagonal[j];
        }
    }
    long columns = ok < 3 ? ok : 3;
    for (long q = 0; q < columns; q++) {  /* column q of X = L^-1: X[i][q], i >= q */
        x[q * 16 + q] = inverse_diagonal[q];
        for (long i = q + 1; i < ok; i++) {
            double s = 0.0;
            for (long k = q; k < i; k++) s += low[i * 16 + k] * x[q * 16 + k];
            x[q * 16 + i] = -s * inverse_diagonal[i];
        }
    }
    double y[(ok > 0 ? ok : 1) * n], c[3 * n];  /* y = X b, row by row, every joint at once */
    for (long i = 0; i < ok; i++) {
        double *row = y + i * n;
        for (long j = 0; j < n; j++) row[j] = moments[i * n + j] * scale[i];
        for (long k = 0; k < i; k++) {
            double factor = low[i * 16 + k];
            const double *earlier = y + k * n;
            for (long j = 0; j < n; j++) row[j] -= factor * earlier[j];
        }
        for (long j = 0; j < n; j++) row[j] *= inverse_diagonal[i];
    }
    /* the coefficients summed over i = q, q + 1, ... and each degree's taken as the sums reach it */
    for (long k = 0; k < 3 * n; k++) c[k] = 0.0;
    double per_h = 1.0 / h, per_h2 = 2.0 / (h * h);
    for (long i = 0; i < ok; i++) {
        for (long q = 0; q < columns && q <= i; q++) {
            double factor = x[q * 16 + i];
            const double *row = y + i * n;
            for (long j = 0; j < n; j++) c[q * n + j] += factor * row[j];
        }
        for (long g = 0; g < ndeg; g++) {
            if (!wanted[g] || degree[g] != i) continue;
            double first = 0.0, second = 0.0;
            for (long k = 1; k <= i && columns > 1; k++) first += x[16 + k] * x[16 + k];
            for (long k = 2; k <= i && columns > 2; k++) second += x[32 + k] * x[32 + k];
            first *= per_h * per_h;
            second *= per_h2 * per_h2;
            double raised = ROUNDING_PIVOT / least[i] > 1.0 ? ROUNDING_PIVOT / least[i] : 1.0;
            double *f = fit[g];
            for (long j = 0; j < n; j++) {
                f[j * 5] = c[j];
                f[j * 5 + 1] = c[n + j] * per_h;
                f[j * 5 + 2] = c[2 * n + j] * per_h2;
                f[j * 5 + 3] = derivative[j] == 2 ? second : first;
                f[j * 5 + 4] = raised;
            }
        }
    }
    return ok;
}

/* level_fits of one degree: 0 if its normal equations are too ill-posed (LEAST_PIVOT). */
static int level_fit(const double *sums, const double *moments, long n, long order, double h, double h0,
                     const long *derivative, double *fit) {
    int wanted = 1;
    return level_fits(sums, moments, n, 1, &order, &wanted, &fit, h, h0, derivative) >= order + 1;
}

/* Column j of level `level`'s fit among the `valid` levels' fits (valid, n, 5) into out (7, n): value, first
   and second derivative, stated standard deviation (its noise and the distance to the next smaller valid
   level's estimate in quadrature; where it is the smallest, to the next larger one's), `strained`, its noise's
   standard deviation and the deviation that noise alone puts between the two estimates (0 where `below`
   and there is no smaller level: the finer fit's, see between_std in adaptive.py). */
static void emit(const double *fits, long valid, long n, long j, long level, long derivative, int strained,
                 int below, double *out) {
    const double *fit = fits + (level * n + j) * 5;
    for (long k = 0; k < 4; k++) out[k * n + j] = fit[k];
    out[6 * n + j] = 0.0;
    long other = level + 1 < valid ? level + 1 : level - 1;
    if (other >= 0) {
        const double *neighbour = fits + (other * n + j) * 5;
        long k = derivative == 2 ? 2 : 1;
        double apart = fit[k] - neighbour[k];
        out[3 * n + j] = sqrt(fit[3] * fit[3] + apart * apart);
        if (!below || other > level) out[6 * n + j] = sqrt(fabs(neighbour[3] * neighbour[3] - fit[3] * fit[3]));
    }
    out[4 * n + j] = strained ? 1.0 : 0.0;
    out[5 * n + j] = fit[3];
}

/* The ICI rule over the `valid` levels' fits (valid, n, 5) of one degree, into out (7, n): value,
   first and second derivative, stated standard deviation (see stated_std in adaptive.py), strained,
   the chosen level's noise's standard deviation (also into noise (n,)), and the deviation that noise
   alone puts between its estimate and the other level's that the stated one measures the distance to
   (the root of the difference of their variances; 0 where there is none: see between_std in
   adaptive.py). changes (levels, n): how many times each column's samples change within each level's
   window. finer (7, n) or NULL: the same for the next smaller valid level than the chosen one (the
   chosen where it is the smallest, or where not shift: the noise read off too few samples), its strain the
   rule's. */
static void choose(double *fits, long valid, long n, const long *lo, const long *hi, const double *changes,
                   const long *derivative, const double *white, const double *step, const double *spread,
                   double gamma, double roughness, double floor_, double *out, double *noise, double *finer,
                   int shift) {
    for (long j = 0; j < n; j++) {
        double low_run = -INFINITY, high_run = INFINITY;
        long chosen = -1;
        int meets[64];
        for (long l = valid - 1; l >= 0; l--) {
            double *fit = fits + (l * n + j) * 5, cnt = (double)(hi[l] - lo[l]);
            double quantisation = step[j] * step[j] / 12.0;
            double crossings = step[j] > 0.0 ? changes[l * n + j] + 1.0 : cnt;
            double independent = nmin(nmax(crossings, 1.0), nmax(cnt, 1.0));
            double least = floor_ * (fits[j * 5] * fit[4]);  /* level 0's value, raised for rounding */
            double effective = nmax(nmax(white[j] * white[j], quantisation * cnt / independent), least * least);
            double std = sqrt(nmax(fit[3], 0.0) * effective);
            fit[3] = std;
            double estimate = derivative[j] == 2 ? fit[2] : fit[1];
            double low = estimate - gamma * std, high = estimate + gamma * std;
            low_run = nmax(low_run, low);
            high_run = nmin(high_run, high);
            meets[l] = low_run <= high_run;
        }
        for (long l = 0; l < valid && chosen < 0; l++) if (meets[l]) chosen = l;
        if (chosen < 0) chosen = 0;
        long smallest_level = valid - 1;
        int strained = (chosen == smallest_level && smallest_level > 0) || white[j] > roughness * spread[j];
        emit(fits, valid, n, j, chosen, derivative[j], strained, 0, out);
        noise[j] = out[5 * n + j];
        /* the next smaller window's (the rule's strain is this one's too) */
        if (finer != NULL)
            emit(fits, valid, n, j, shift && chosen + 1 < valid ? chosen + 1 : chosen, derivative[j], strained, 1,
                 finer);
    }
}

/* |the combination of y[0], y[s n], ..., y[6 s n] with the weights w|: one column's normalised sixth
   divided difference (the single expression both callers use, so that they add the very same numbers) */
static double sixth(const double *y, const double *w, long s, long n) {
    double x = w[0] * y[0];
    for (long k = 1; k < 7; k++) x = x + w[k] * y[k * s * n];
    return fabs(x);
}

/* |normalised sixth divided difference| of samples s = 1, 2, 4 ... (strides of them) apart, starting
   at each sample i of [lo, hi) whose seventh sample is before hi, into pre (strides, hi - lo, n): the
   very numbers fit_target adds for a window inside [lo, hi), computed once for many targets. */
static void sixths(const double *times, const double *values, long n, long lo, long hi, long strides,
                   double *pre) {
    double weights[7];
    for (long b = 0, s = 1; b < strides; b++, s *= 2)
        for (long i = lo; i + 6 * s < hi; i++) {
            divided_weights(times + i, s, weights);
            double *row = pre + ((size_t)b * (hi - lo) + (i - lo)) * n;
            for (long j = 0; j < n; j++) row[j] = sixth(values + i * n + j, weights, s, n);
        }
}

/* The furthest back the white noise is also read from for a largest window [lo, hi): the NOISE_SAMPLES
   up to hi (as many as there are), or lo where the window holds as many (adaptive.noise_reach). */
static long noise_reach(long lo, long hi) {
    long first = hi > NOISE_SAMPLES ? hi - NOISE_SAMPLES : 0;
    return first < lo ? first : lo;
}

/* Where that reading starts: back from lo towards noise_reach, short of any interval between samples
   longer than NOISE_HOLE times the window's longest (a hole: adaptive.noise_start). */
static long noise_start(const double *times, long lo, long hi) {
    long first = noise_reach(lo, hi);
    if (first >= lo) return lo;
    double longest = 0.0;
    for (long i = lo + 1; i < hi; i++) if (times[i] - times[i - 1] > longest) longest = times[i] - times[i - 1];
    long start = lo;
    while (start > first && times[start] - times[start - 1] <= NOISE_HOLE * longest) start--;
    return start;
}

/* The noise of `width` samples (window, width x n row-major, at times wt) into white (n), from their
   normalised sixth divided differences of samples 1, 2, 4, 8 ... apart (see sixth_differences and
   noise_of): stride 1 is the white noise; a coloured stride counts while they grow at most `growth`
   times per doubling, once the next one agrees. pre: the sixths of the samples from `offset` before
   the first on (see sixths), or NULL: computed here. scratch: 3 n. */
static void read_white(const double *wt, const double *window, long width, long n, const double *pre, long pre_count,
                       long pre_strides, long offset, double sixth_gain, double growth, double *white,
                       double *scratch) {
    double *previous = scratch, *candidate = previous + n, *alive = candidate + n, weights[7];
    for (long s = 1, b = 0; s == 1 || 6 * s + 8 <= width; s *= 2, b++) {
        long terms = width - 6 * s;
        for (long j = 0; j < n; j++) candidate[j] = 0.0;
        const double *stored = pre != NULL && b < pre_strides ? pre + ((size_t)b * pre_count + offset) * n : NULL;
        if (stored != NULL)  /* the same numbers, added in the same order */
            for (long i = 0; i < terms; i++) for (long j = 0; j < n; j++) candidate[j] += stored[i * n + j];
        else for (long i = 0; i < terms; i++) {
            divided_weights(wt + i, s, weights);
            for (long j = 0; j < n; j++) candidate[j] += sixth(window + i * n + j, weights, s, n);
        }
        for (long j = 0; j < n; j++) {
            double noise = candidate[j] / ((double)terms * sixth_gain);
            if (s == 1) { white[j] = noise; alive[j] = 1.0; }
            else {
                alive[j] = alive[j] > 0.0 && noise <= growth * previous[j] ? 1.0 : 0.0;
                if (alive[j] > 0.0 && previous[j] > white[j]) white[j] = previous[j];  /* confirmed by s */
            }
            previous[j] = noise;
        }
        int any = 0;  /* no column's noise can grow past its stride: the larger ones change nothing */
        for (long j = 0; j < n; j++) any |= alive[j] > 0.0;
        if (!any) break;
    }
}

/* adaptive_fit below, with pre (pre_strides, pre_count, n) the sixths of samples [pre_lo, pre_lo +
   pre_count), covering this target's largest window and its noise_reach, or NULL: computed here. */
static int fit_target(long count, const double *times, const double *values, long n, double target,
                      long nlevels, const double *levels, const double *leads, long order, long lower,
                      long nalso, const long *also, long finer, const long *derivative, double gamma,
                      double roughness, double sixth_gain, double floor_, double growth, double lattice,
                      double timing, const double *pre, long pre_lo, long pre_count, long pre_strides, double *out) {
    long d = order + 1, lo[64], hi[64], valid = 0, valid_low = 0, valid_also[MAX_ALSO], also_at[MAX_ALSO + 1];
    if (nlevels > 64 || d > 16 || n < 1 || lower < 0 || lower >= order || nalso < 0 || nalso > MAX_ALSO) return 1;
    if (finer < 0 || finer > 1) return 1;
    for (long a = 0; a < nalso; a++) {
        if (also[a] < 1 || also[a] >= order) return 1;
        valid_also[a] = 0;
    }
    for (long l = 0; l < nlevels; l++) {
        double start = (target + leads[l]) - 2.0 * levels[l], end = target + leads[l];
        if (l > 0 && start >= (target + leads[0]) - 2.0 * levels[0] && end <= target + leads[0]) {
            /* inside the largest window: its samples are searched alone */
            lo[l] = lo[0] + lower_bound(times + lo[0], hi[0] - lo[0], start);
            hi[l] = lo[0] + upper_bound(times + lo[0], hi[0] - lo[0], end);
        } else {
            lo[l] = lower_bound(times, count, start);
            hi[l] = upper_bound(times, count, end);
        }
        if (hi[l] - lo[l] >= order + 3 && valid == l) valid = l + 1;
        if (hi[l] - lo[l] >= lower + 3 && valid_low == l) valid_low = l + 1;
        for (long a = 0; a < nalso; a++)
            if (hi[l] - lo[l] >= also[a] + 3 && valid_also[a] == l) valid_also[a] = l + 1;
    }
    if (valid == 0) return 1;
    if (lower == 0) valid_low = 0;
    long width = hi[0] - lo[0], rings = valid > valid_low ? valid : valid_low;
    also_at[0] = 0;  /* where each further degree's level fits start in fits_also */
    for (long a = 0; a < nalso; a++) {
        if (valid_also[a] > rings) rings = valid_also[a];
        also_at[a + 1] = also_at[a] + valid_also[a];
    }
    double *scratch = malloc(sizeof(double) * (d * n + 5 * (size_t)(valid + valid_low) * n + 7 * n + 6 * n
                                               + (size_t)rings * n + 2 * (size_t)n + (size_t)width * n
                                               + 5 * (size_t)also_at[nalso] * n + (size_t)n));
    if (scratch == NULL) return 2;
    double *moments = scratch, *fits = moments + d * n, *fits_low = fits + 5 * (size_t)valid * n;
    double *out_low = fits_low + 5 * (size_t)valid_low * n;
    double *white = out_low + 7 * (size_t)n, *step = white + n, *spread = step + n;
    double *changes = spread + 4 * n;  /* after previous, candidate, alive: (rings, n) */
    double *noise = changes + (size_t)rings * n, *noise_low = noise + n, *changed = noise_low + n;
    double *fits_also = changed + (size_t)width * n;  /* each further degree's level fits, one after another */
    double *more = fits_also + 5 * (size_t)also_at[nalso] * n;  /* (n,) the white noise over NOISE_SAMPLES */
    /* each level's changes between consecutive samples (changes_within), from the changes up to each
       sample of the largest window, which holds the others (width, n), every column at once */
    for (long j = 0; j < n; j++) changed[j] = 0.0;
    for (long i = 1; i < width; i++) {
        const double *now = values + (lo[0] + i) * n, *before = now - n;
        double *count = changed + i * n;
        for (long j = 0; j < n; j++) count[j] = count[j - n] + (now[j] != before[j] ? 1.0 : 0.0);
    }
    for (long l = 0; l < rings; l++)
        for (long j = 0; j < n; j++)
            changes[l * n + j] = hi[l] - 1 > lo[l]
                ? changed[(hi[l] - 1 - lo[0]) * n + j] - changed[(lo[l] - lo[0]) * n + j] : 0.0;
    /* the noise, from the largest window, every column at once (rows are contiguous): the samples'
       deviation, the mean |sixth difference|, the smallest non-zero step */
    const double *window = values + lo[0] * n;
    for (long j = 0; j < n; j++) { white[j] = 0.0; spread[j] = 0.0; step[j] = INFINITY; }
    for (long i = 0; i < width; i++) for (long j = 0; j < n; j++) white[j] += window[i * n + j];
    for (long j = 0; j < n; j++) white[j] *= 1.0 / width;  /* the mean, for now */
    for (long i = 0; i < width; i++)
        for (long j = 0; j < n; j++) { double c = window[i * n + j] - white[j]; spread[j] += c * c; }
    for (long j = 0; j < n; j++) { spread[j] = sqrt(spread[j] * (1.0 / width)); white[j] = 0.0; }
    if (width >= 8) {
        int fraction[n];  /* per column: its step a fraction of its smallest change (grid_step) */
        for (long i = 0; i + 1 < width; i++)  /* the smallest change: an encoder's step, if on its grid */
            for (long j = 0; j < n; j++) {
                double a = fabs(window[(i + 1) * n + j] - window[i * n + j]);
                if (a > 0.0 && a < step[j]) step[j] = a;
            }
        for (long j = 0; j < n; j++) {  /* an encoder's grid: each sample a whole number of steps from
                                            the first, and the changes not all one number of steps; the
                                            step the smallest change over 1, then over the base divisor
                                            times 1, 2 ... DIVISORS, the largest that fits (grid_step) */
            fraction[j] = 0;
            if (!isfinite(step[j])) continue;
            double smallest = step[j], base = 1.0;
            step[j] = INFINITY;
            for (long multiple = 0; multiple <= DIVISORS && isinf(step[j]); multiple++) {
                if (multiple == 1) base = base_divisor(window + j, width, n, smallest);
                double divisor = multiple == 0 ? 1.0 : base * (double)multiple;
                if (multiple > 0 && !(divisor >= 2.0 && divisor <= LARGEST_DIVISOR)) continue;
                fraction[j] = multiple > 0;
                double candidate = smallest / divisor, position = 0.0, first = 0.0;
                int varied = 0, off = 0;
                for (long i = 0; i + 1 < width; i++) {
                    double ratio = (window[(i + 1) * n + j] - window[i * n + j]) * (1.0 / candidate);
                    position += ratio;
                    if (fabs(position - nearbyint(position)) > lattice) { off = 1; break; }
                    if (i == 0) first = nearbyint(ratio);
                    else if (nearbyint(ratio) != first) varied = 1;
                }
                if (!off && varied) step[j] = candidate;
            }
            if (isinf(step[j])) fraction[j] = 0;
        }
        read_white(times + lo[0], window, width, n, pre, pre_count, pre_strides, lo[0] - pre_lo, sixth_gain, growth,
                   white, spread + n);
        for (long j = 0; j < n; j++)  /* a fraction of the smallest change: only where the noise read is
                                         blind to its rounding (grid_step) */
            if (fraction[j] && !(white[j] < HIDDEN * step[j] * (1.0 / sqrt(12.0)))) step[j] = INFINITY;
    }
    for (long j = 0; j < n; j++) if (isinf(step[j]) || width < 8) step[j] = 0.0;
    long noise_lo = noise_start(times, lo[0], hi[0]);
    if (noise_lo < lo[0] && hi[0] - noise_lo >= 8) {  /* the white noise read from more samples too: the larger */
        read_white(times + noise_lo, values + noise_lo * n, hi[0] - noise_lo, n, pre, pre_count, pre_strides,
                   noise_lo - pre_lo, sixth_gain, growth, more, spread + n);
        for (long j = 0; j < n; j++) if (more[j] > white[j]) white[j] = more[j];
    }
    if (timing > 0.0)  /* the stamps' uncertainty at the joint's fastest speed in the window (timing_noise) */
        for (long i = 0; i + TIMING_STRIDE < width; i++) {
            const double *a = window + i * n, *b = a + TIMING_STRIDE * n;
            double apart = times[lo[0] + i + TIMING_STRIDE] - times[lo[0] + i];
            if (!(apart > 0.0)) continue;
            for (long j = 0; j < n; j++) {
                double least = timing * fabs(b[j] - a[j]) / apart;
                if (least > white[j]) white[j] = least;
            }
        }
    /* on a grid, each level's rounding errors are drawn afresh at most where the change between
       consecutive samples changes by half a step or more, TURNS (2) times those (turns_within):
       `changed` now counts the turns up to each sample of the largest window */
    int gridded = 0;  /* no column on a grid: its counts are not used (accel_std), nothing to count */
    for (long j = 0; j < n; j++) gridded |= step[j] > 0.0;
    for (long j = 0; j < n; j++) { changed[j] = 0.0; if (width > 1) changed[n + j] = 0.0; }
    for (long i = 2; i < width && gridded; i++) {
        const double *now = values + (lo[0] + i) * n, *before = now - n, *earlier = before - n;
        double *count = changed + i * n;
        for (long j = 0; j < n; j++) {
            double turn = fabs((now[j] - before[j]) - (before[j] - earlier[j]));
            count[j] = count[j - n] + (step[j] > 0.0 && turn >= 0.5 * step[j] ? 1.0 : 0.0);
        }
    }
    for (long l = 0; l < rings && gridded; l++)
        for (long j = 0; j < n; j++) {
            double turns = hi[l] - 1 > lo[l] + 1
                ? changed[(hi[l] - 1 - lo[0]) * n + j] - changed[(lo[l] + 1 - lo[0]) * n + j] : 0.0;
            if (2.0 * turns < changes[l * n + j]) changes[l * n + j] = 2.0 * turns;  /* TURNS */
        }
    /* every valid level's fit, the sums gathered ring by ring from the smallest window outwards; the
       lower degree's from the same sums (its normal equations are their leading rows and columns) */
    double sums[33], h0 = levels[0];
    for (long k = 0; k <= 2 * order; k++) sums[k] = 0.0;
    for (long k = 0; k < d * n; k++) moments[k] = 0.0;
    long inner_lo = 0, inner_hi = 0;
    int status = 0;
    for (long l = rings - 1; l >= 0; l--) {
        long ring[2][2] = {{lo[l], l == rings - 1 ? hi[l] : inner_lo}, {l == rings - 1 ? hi[l] : inner_hi, hi[l]}};
        for (long side = 0; side < 2; side++)
            for (long i = ring[side][0]; i < ring[side][1]; i++) {
                double u = (times[i] - target) / h0, p = 1.0;
                const double *row = values + i * n;
                for (long k = 0; k <= 2 * order; k++) {
                    sums[k] += p;
                    if (k < d) for (long j = 0; j < n; j++) moments[k * n + j] += p * row[j];
                    p *= u;
                }
            }
        inner_lo = lo[l]; inner_hi = hi[l];
        long degree[2 + MAX_ALSO] = {order, lower};
        int wanted[2 + MAX_ALSO] = {l < valid, l < valid_low};
        double *fit[2 + MAX_ALSO] = {fits + l * n * 5, fits_low + l * n * 5};
        for (long a = 0; a < nalso; a++) {
            degree[2 + a] = also[a];
            wanted[2 + a] = l < valid_also[a];
            fit[2 + a] = fits_also + (also_at[a] + l) * n * 5;
        }
        long factored = level_fits(sums, moments, n, 2 + nalso, degree, wanted, fit, levels[l], h0, derivative);
        /* an ill-posed level: no fit there, nor at any smaller one (each degree's valid levels lead) */
        if (wanted[0] && order + 1 > factored) valid = l;
        if (wanted[1] && lower + 1 > factored) valid_low = l;
        for (long a = 0; a < nalso; a++)
            if (wanted[2 + a] && also[a] + 1 > factored) valid_also[a] = l;
    }
    if (valid == 0) status = 1;  /* the largest window ill-posed: the caller's function serves (NaN) */
    for (long a = 0; a < nalso; a++) if (valid_also[a] == 0) status = 1;
    if (status == 0) {
        choose(fits, valid, n, lo, hi, changes, derivative, white, step, spread, gamma, roughness, floor_, out,
               noise, finer ? out + (1 + nalso) * 7 * n : NULL, hi[0] - noise_lo >= NOISE_SAMPLES);
        if (valid_low > 0) {
            choose(fits_low, valid_low, n, lo, hi, changes, derivative, white, step, spread, gamma, roughness,
                   floor_, out_low, noise_low, NULL, 0);
            for (long j = 0; j < n; j++) {  /* fused: the lower degree where it agrees and is the quieter */
                long k = derivative[j] == 2 ? 2 : 1;
                double apart = fabs(out_low[k * n + j] - out[k * n + j]);
                double std_low = noise_low[j], std_high = noise[j];
                if (apart <= gamma * hypot(std_low, std_high) && std_low <= std_high)
                    for (long q = 0; q < 7; q++) out[q * n + j] = out_low[q * n + j];
            }
        }
        for (long a = 0; a < nalso; a++)  /* each further degree's own choice, not fused */
            choose(fits_also + also_at[a] * n * 5, valid_also[a], n, lo, hi, changes, derivative, white, step, spread,
                   gamma, roughness, floor_, out + (a + 1) * 7 * n, noise_low, NULL, 0);
    }
    free(scratch);
    return status;
}

/* See adaptive_fit in neforward_ros/estimation/adaptive.py. times (count,), values (count, n)
   row-major; levels, leads (nlevels,) the half-widths (largest first) and their leads; order the
   polynomial degree and lower a second, lower degree fused with it (see fused in adaptive.py; 0: none),
   both fitted from the same power sums and noise reading; derivative (n,) 2 or 1. out (1 + nalso + finer, 7,
   n), for order, then each degree of also, then (finer 1) order's fit at the next smaller window than its
   rule's: value, first and second derivative, the chosen derivative's stated standard deviation, strained
   (1 or 0), its noise's standard deviation and the deviation that noise puts between it and the level the
   stated one is measured against (see choose). Returns
   0 when done, 1 when the largest window is too small (the caller's function serves), 2 when memory
   runs out. */
int adaptive_fit(long count, const double *times, const double *values, long n, double target,
                 long nlevels, const double *levels, const double *leads, long order, long lower,
                 long nalso, const long *also, long finer, const long *derivative, double gamma,
                 double roughness, double sixth_gain, double floor_, double growth, double lattice, double timing,
                 double *out) {
    return fit_target(count, times, values, n, target, nlevels, levels, leads, order, lower, nalso, also, finer,
                      derivative, gamma, roughness, sixth_gain, floor_, growth, lattice, timing, NULL, 0, 0, 0,
                      out);
}

/* adaptive_fit at each of ntargets targets over the whole of times, values; derivative (n,); out
   (ntargets, 1 + nalso + finer, 7, n); status (ntargets,) each target's return value. Neighbouring targets'
   windows overlap: a block of them takes its sixth differences from one pass (sixths), which is most of
   each target's work otherwise; the numbers are the same as adaptive_fit's one target at a time. */
void adaptive_fits(long count, const double *times, const double *values, long n, long ntargets,
                   const double *targets, long nlevels, const double *levels, const double *leads,
                   long order, long lower, long nalso, const long *also, long finer, const long *derivative,
                   double gamma, double roughness, double sixth_gain, double floor_, double growth, double lattice,
                   double timing, double *out, int *status) {
    const long block = 256;
    for (long first = 0; first < ntargets; first += block) {
        long last = first + block < ntargets ? first + block : ntargets, lo = count, hi = 0, widest = 0;
        for (long m = first; m < last; m++) {
            long z = upper_bound(times, count, targets[m] + leads[0]);
            long a = noise_reach(lower_bound(times, count, (targets[m] + leads[0]) - 2.0 * levels[0]), z);
            if (a < lo) lo = a;
            if (z > hi) hi = z;
            if (z - a > widest) widest = z - a;
        }
        long strides = 0;
        if (widest >= 8) for (long s = 1; s == 1 || 6 * s + 8 <= widest; s *= 2) strides++;
        double *pre = NULL;
        /* targets in order share most of their samples; scattered ones are fitted one at a time */
        if (strides > 0 && hi - lo <= 4 * (widest + block))
            pre = malloc(sizeof(double) * (size_t)strides * (size_t)(hi - lo) * (size_t)n);
        if (pre != NULL) sixths(times, values, n, lo, hi, strides, pre);
        for (long m = first; m < last; m++)
            status[m] = fit_target(count, times, values, n, targets[m], nlevels, levels, leads, order, lower,
                                   nalso, also, finer, derivative, gamma, roughness, sixth_gain, floor_, growth,
                                   lattice, timing, pre, lo, hi - lo, pre == NULL ? 0 : strides,
                                   out + m * (1 + nalso + finer) * 7 * n);
        free(pre);
    }
}

/* The causal candidates (estimation/causal_choice.py) at `target`, at or after the newest sample: level
   l's window [target - 2 h_l, target] (levels largest first: nested, added ring by ring from the
   smallest outwards, as fit_target does), degree degrees[k]; candidate c = k levels + l is fitted where
   wanted is NULL or wanted[c], and its window holds at least degree + extra samples: value, first and
   second derivative, and the derivative's variance factor for unit noise into out (C, n, 4); NaN
   elsewhere. The samples' powers are in the largest window's unit, rescaled per level (level_fit). */
static void add_samples(long from, long to, const double *times, const double *values, long n, double target,
                        double h0, long width, long rows, double *sums, double *moments) {
    for (long i = to - 1; i >= from; i--) {
        double u = (times[i] - target) / h0, power = 1.0;
        for (long k = 0; k < width; k++) {
            sums[k] += power;
            if (k < rows) for (long j = 0; j < n; j++) moments[k * n + j] += power * values[i * n + j];
            power *= u;
        }
    }
}

/* Each level's window reaches min(lead, h) past the target ([target + min(lead, h) - 2 h, target + min(lead,
   h)]: one-sided for lead 0, centred while h <= lead); from the smallest level up the windows are nested,
   so the running sums take each level's new samples on either side. */
void causal_candidates(long count, const double *times, const double *values, long n, double target,
                       double lead, long nlevels, const double *levels, long ndeg, const long *degrees,
                       long extra, const long *derivative, const unsigned char *wanted, double *out) {
    long top = 0;
    for (long k = 0; k < ndeg; k++) if (degrees[k] > top) top = degrees[k];
    long width = 2 * top + 1, rows = top + 1;
    double h0 = levels[0];
    double *sums = calloc((size_t)width, sizeof(double)), *moments = calloc((size_t)rows * n, sizeof(double));
    double *fit = malloc((size_t)n * 5 * sizeof(double));
    long next = upper_bound(times, count, target), last = next;  /* the samples [next, last) are in the sums */
    for (long c = 0; c < ndeg * nlevels * n * 4; c++) out[c] = NAN;
    long widest = 0;  /* the largest window wanted (the smallest level index): no samples added beyond it */
    if (wanted != NULL) {
        widest = nlevels;
        for (long k = 0; k < ndeg; k++)
            for (long l = 0; l < nlevels; l++)
                if (wanted[k * nlevels + l] && l < widest) widest = l;
    }
    for (long l = nlevels - 1; l >= widest; l--) {
        double reach = lead < levels[l] ? lead : levels[l];
        long lo = lower_bound(times, count, target + reach - 2.0 * levels[l]);
        long hi = upper_bound(times, count, target + reach);
        if (lo < next) add_samples(lo, next, times, values, n, target, h0, width, rows, sums, moments);
        if (hi > last) add_samples(last, hi, times, values, n, target, h0, width, rows, sums, moments);
        if (lo < next) next = lo;
        if (hi > last) last = hi;
        for (long k = 0; k < ndeg; k++) {
            long c = k * nlevels + l;
            if ((wanted != NULL && !wanted[c]) || hi - lo < degrees[k] + extra) continue;
            if (!level_fit(sums, moments, n, degrees[k], levels[l], h0, derivative, fit)) continue;
            for (long j = 0; j < n; j++)
                for (long q = 0; q < 4; q++) out[(c * n + j) * 4 + q] = fit[j * 5 + q];
        }
    }
    free(sums);
    free(moments);
    free(fit);
}

/* One estimate's terms of the degree choice's sums into score (2 ndeg + 5): (a_g - a_(g-1))^2 at [g] (0 at [0]),
   v_g^2 at [ndeg + g], the reference's squared distance to its neighbouring window, s_0^2 - v_0^2 (at
   least 0), at [2 ndeg] and what its noise alone puts there, w_0^2, at [2 ndeg + 1], the same two of
   degree 1 (of degree 0 where there is one degree) at [2 ndeg + 2] and [2 ndeg + 3]; and 1 at
   [2 ndeg + 4] where it counts (counted, and every degree's estimate and deviations finite), else 0
   throughout. a, s, v, w: degree g's acceleration, stated deviation, noise's deviation and the noise's
   deviation between it and its neighbour at a[g * acc_g], s[g * std_g], v[g * noise_g], w[g * between_g]
   (see degree_choice.terms). */
static void degree_scores(long ndeg, const double *a, long acc_g, const double *s, long std_g, const double *v,
                          long noise_g, const double *w, long between_g, int counted, double *score) {
    int finite = counted;
    for (long g = 0; g < ndeg && finite; g++)
        finite = isfinite(a[g * acc_g]) && isfinite(s[g * std_g]) && isfinite(v[g * noise_g])
                 && isfinite(w[g * between_g]);
    for (long g = 0; g < ndeg; g++) {
        double apart = g > 0 ? a[g * acc_g] - a[(g - 1) * acc_g] : 0.0, noise = v[g * noise_g];
        score[g] = finite ? apart * apart : 0.0;
        score[ndeg + g] = finite ? noise * noise : 0.0;
    }
    for (long r = 0; r < 2; r++) {
        long g = r < ndeg ? r : 0;
        double own = s[g * std_g], noise = v[g * noise_g], between = w[g * between_g];
        score[2 * ndeg + 2 * r] = finite && between > 0.0 ? nmax(own * own - noise * noise, 0.0) : 0.0;
        score[2 * ndeg + 2 * r + 1] = finite ? between * between : 0.0;
    }
    score[2 * ndeg + 4] = finite ? 1.0 : 0.0;
}

/* One estimate's degree and the deviation stated with it (degree_choice._least), from its window's sums
   total[k * n] of degree_scores' terms k and count of estimates counted. finer: degree 0 is the finer
   fit, which the others' choice leaves out (degree 1 their reference, its colour read) and which then takes
   the place of the degree chosen where its colour reads at most `white`, the record is `aged` (spans
   degree_choice.RECORD with no hole, degree_choice.HOLE) and its scores say it is the better
   (degree_choice._least). */
static void decide(long ndeg, long n, const double *total, double count, const double *a, long acc_g,
                   const double *s, long std_g, const double *v, long noise_g, const double *w, long between_g,
                   int counted, long least, double gamma, double strain, int finer, double white, double growth,
                   int aged, long *chosen, double *stated) {
    long first = finer && ndeg > 1 ? 1 : 0;  /* the reference */
    double number = count > 1.0 ? count : 1.0, expected = total[(2 * ndeg + 1 + 2 * first) * n];
    double colour = expected > 0.0 ? nmax(total[(2 * ndeg + 2 * first) * n] / expected, 1.0) : 1.0;
    int enough = count >= (double)least;
    long best = first;
    double best_score = 0.0, steps = 0.0;
    for (long g = first; g < ndeg; g++) {
        if (g > first) steps += total[g * n];  /* the squared steps from the reference down to degree g */
        double score = (steps + 2.0 * colour * total[(ndeg + g) * n]) / number;
        if (g == first || (enough && score < best_score)) { best = g; best_score = score; }
    }
    double usual = nmax(best_score - colour * total[(ndeg + first) * n] / number, 0.0), told = s[best * std_g];
    if (enough && counted && told * told > strain * strain * usual) {
        /* this estimate's stated deviation far beyond the degree's usual error (its rule strained here):
           each degree's own variance now for one of its two, not its usual */
        steps = 0.0;
        double least = INFINITY;
        for (long g = first; g < ndeg; g++) {
            if (g > first) steps += total[g * n];
            double now = v[g * noise_g];
            double score = (steps + colour * total[(ndeg + g) * n]) / number + colour * now * now;
            if (score < least) { least = score; best = g; }
        }
        steps = 0.0;
        for (long g = first + 1; g <= best; g++) steps += total[g * n];
        best_score = (steps + 2.0 * colour * total[(ndeg + best) * n]) / number;
    }
    const double *reference = a + first * acc_g;
    if (counted && fabs(a[best * acc_g] - *reference) > gamma * hypot(s[best * std_g], s[first * std_g])) {
        best = first;
        best_score = 2.0 * colour * total[(ndeg + first) * n] / number;
    }
    double error = enough ? nmax(best_score - colour * total[(ndeg + first) * n] / number, 0.0) : 0.0;
    double noise = v[best * noise_g], own = s[best * std_g], apart = a[best * acc_g] - *reference;
    double between = w[best * between_g], theirs = v[first * noise_g];
    double beside = nmax(own * own - noise * noise - colour * between * between, 0.0);
    double beyond = nmax(apart * apart - colour * theirs * theirs, 0.0);
    *chosen = best;
    *stated = sqrt(nmax(colour * noise * noise + beside + beyond, error));
    expected = total[(2 * ndeg + 1) * n];
    double reading = expected > 0.0 ? total[2 * ndeg * n] / expected : 1.0;
    if (colour > growth * nmax(reading, 1.0)) reading = 1.0;  /* the distances grow as a bias does */
    /* (the same fit as degree 1's where its rule chose its smallest window: no candidate) */
    if (!first || !enough || !aged || !counted || reading > white || (a[0] == a[acc_g] && v[0] == v[noise_g]))
        return;
    /* the finer fit: the degree chosen's mean squared error over the reference's (its score less the
       reference's), then the reference's over the finer's (their squared step less twice the difference
       of their coloured variances, at the colour the finer's window reads, below 1 too) */
    double tint = nmax(reading, 1.0), mine = total[ndeg * n] / number, rule = total[(ndeg + 1) * n] / number;
    double gain = best_score - 2.0 * colour * rule + total[n] / number - 2.0 * reading * (mine - rule);
    double finest = s[0], quiet = v[0], apart_f = w[0], read = apart_f > 0.0 ? finest : quiet;
    if (gain <= 0.0 || read * read > strain * strain * tint * mine) return;
    *chosen = 0;
    *stated = sqrt(nmax(tint * quiet * quiet + nmax(finest * finest - quiet * quiet - tint * apart_f * apart_f, 0.0),
                        tint * mine));
}

/* degree_choice.choose over m estimates in stamp order (stamps, ns): per joint, degree_scores' terms
   over the estimates stamped in (s - span, s] that count, as sliding sums; where a sum has taken in more
   than `precision` times itself since it was last added up (or `refresh` estimates have passed), added
   up afresh over its window, so that it stays within about 1e-14 of the direct sums the node adds
   (choose_last). acc, std, noise, between: degree g's acceleration, stated deviation, noise's deviation
   and the noise's deviation between it and its neighbour (degree_scores) of estimate t, joint j at
   [g * _g + t * _t + j]; counted (m, n); record and hole: ns, the least span of a window's estimates for
   the finer fit and the longest interval between them (decide's aged). Into chosen (m, n) the degree
   index and into stated (m, n) the standard deviation stated with it. */
void choose_degrees(long m, long ndeg, long n, const long long *stamps, long long span, const double *acc,
                    long acc_g, long acc_t, const double *std, long std_g, long std_t, const double *noise,
                    long noise_g, long noise_t, const double *between, long between_g, long between_t,
                    const unsigned char *counted, long least, double gamma, double strain, int finer, double white,
                    double growth, long long record, long long hole, double precision, long refresh, long *chosen,
                    double *stated) {
    long sums = 2 * ndeg + 4, row = sums + 1;  /* each estimate's terms (m, n, row), whether it counts last */
    double *scores = malloc(sizeof(double) * ((size_t)m * n * row + (size_t)(2 * sums + 1) * n));
    if (scores == NULL) {
        for (long k = 0; k < m * n; k++) { chosen[k] = 0; stated[k] = NAN; }
        return;
    }
    double *total = scores + (size_t)m * n * row, *passed = total + sums * n, *count = passed + sums * n;
    for (long k = 0; k < (2 * sums + 1) * n; k++) total[k] = 0.0;
    for (long t = 0; t < m; t++)
        for (long j = 0; j < n; j++)
            degree_scores(ndeg, acc + t * acc_t + j, acc_g, std + t * std_t + j, std_g, noise + t * noise_t + j,
                          noise_g, between + t * between_t + j, between_g, counted[t * n + j],
                          scores + (t * n + j) * row);
    long first = 0, since = 0, after = 0;  /* after: the first estimate since the last hole */
    for (long t = 0; t < m; t++) {
        if (t > 0 && stamps[t] - stamps[t - 1] > hole) after = t;
        for (long j = 0; j < n; j++) {  /* this estimate joins its window */
            const double *score = scores + (t * n + j) * row;
            count[j] += score[sums];
            for (long g = 0; g < sums; g++) { total[g * n + j] += score[g]; passed[g * n + j] += score[g]; }
        }
        for (; stamps[first] <= stamps[t] - span; first++)  /* the estimates a second old leave it */
            for (long j = 0; j < n; j++) {
                const double *score = scores + (first * n + j) * row;
                count[j] -= score[sums];
                for (long g = 0; g < sums; g++) total[g * n + j] -= score[g];
            }
        int all = ++since >= refresh;
        if (all) since = 0;
        for (long j = 0; j < n; j++) {
            int loose = all;
            for (long g = 0; g < sums; g++) loose |= passed[g * n + j] > precision * total[g * n + j];
            if (!loose) continue;
            for (long g = 0; g < sums; g++) total[g * n + j] = 0.0;
            for (long i = first; i <= t; i++)
                for (long g = 0; g < sums; g++) total[g * n + j] += scores[(i * n + j) * row + g];
            for (long g = 0; g < sums; g++) passed[g * n + j] = total[g * n + j];
        }
        for (long j = 0; j < n; j++)
            decide(ndeg, n, total + j, count[j], acc + t * acc_t + j, acc_g, std + t * std_t + j, std_g,
                   noise + t * noise_t + j, noise_g, between + t * between_t + j, between_g, counted[t * n + j],
                   least, gamma, strain, finer, white, growth, first >= after && stamps[t] - stamps[first] >= record,
                   chosen + t * n + j, stated + t * n + j);
    }
    free(scores);
}

/* The node's choice (degree_choice.DegreePool): the last of m estimates' degrees and deviations (n).
   scores (m, 2 ndeg + 5, n): each estimate's terms and whether it counts (degree_scores' row, joint by
   joint); the last's are made here from acc, std, noise, between (ndeg, n) and counted (n). Their sums
   over all m (the window) are added up directly, estimate by estimate; aged: whether they span
   degree_choice.RECORD with no hole (see decide). */
void choose_last(long m, long ndeg, long n, double *scores, const double *acc, const double *std,
                 const double *noise, const double *between, const unsigned char *counted, long least,
                 double gamma, double strain, int finer, double white, double growth, int aged, long *chosen,
                 double *stated) {
    long width = 2 * ndeg + 5, row = width * n;
    double total[(9 + 2 * MAX_ALSO) * n], score[9 + 2 * MAX_ALSO];
    if (ndeg > 2 + MAX_ALSO || m < 1) return;
    double *last = scores + (m - 1) * row;
    for (long j = 0; j < n; j++) {
        degree_scores(ndeg, acc + j, n, std + j, n, noise + j, n, between + j, n, counted[j], score);
        for (long g = 0; g < width; g++) last[g * n + j] = score[g];
    }
    for (long k = 0; k < row; k++) total[k] = 0.0;
    for (long t = 0; t < m; t++) {
        const double *each = scores + t * row;
        for (long k = 0; k < row; k++) total[k] += each[k];
    }
    for (long j = 0; j < n; j++)
        decide(ndeg, n, total + j, total[(width - 1) * n + j], acc + j, n, std + j, n, noise + j, n, between + j,
               n, counted[j], least, gamma, strain, finer, white, growth, aged, chosen + j, stated + j);
}
"""


SOURCE += native_kalman.SOURCE  # one library: the Kalman bank's step is ready when the fits are


class NativeAdaptiveFit:
    """The compiled library, built on first use in a thread (see the module docstring); ``get``
    gives it once ready, else None."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._library: ctypes.CDLL | None = None
        self._started = False
        self._thread: threading.Thread | None = None

    def get(self, wait: bool = False) -> ctypes.CDLL | None:
        """The library if it is ready; with ``wait``, built now if it is not (a whole recording's
        estimates are worth the build's fraction of a second)."""
        if self._library is not None or (self._started and not wait):
            return self._library
        with self._lock:
            if not self._started:
                self._started = True
                if not self._load():
                    self._thread = threading.Thread(target=self._build, name="neforward-compile-fit", daemon=True)
                    self._thread.start()
            thread = self._thread
        if wait and thread is not None:
            thread.join()
        return self._library

    def _load(self) -> bool:
        """Take the library built before; True when there is nothing to build (it was there, or
        there is no compiler and the Python function serves)."""
        cc = native.compiler()
        if cc is None:
            return True
        path = native.cache_path("adaptive_fit", SOURCE, cc, FLAGS)
        library = native.load_cached(path)
        if library is None:
            return False
        try:
            self._library = _declare(library)
        except AttributeError:
            if path is not None:
                path.unlink(missing_ok=True)
            return False
        return True

    def _build(self) -> None:
        cc = native.compiler()
        if cc is None:
            return
        try:
            library = native.build_library(cc, SOURCE, FLAGS, native.cache_path("adaptive_fit", SOURCE, cc, FLAGS))
            self._library = _declare(library)
        except (OSError, subprocess.SubprocessError, ValueError, AttributeError):
            return  # the Python function serves


def _declare(library: ctypes.CDLL) -> ctypes.CDLL:
    double, pointer, long = ctypes.c_double, ctypes.c_void_p, ctypes.c_long
    library.adaptive_fit.argtypes = [long, pointer, pointer, long, double, long, pointer, pointer, long, long,
                                     long, pointer, long, pointer, double, double, double, double, double, double,
                                     double, pointer]  # fmt: skip
    library.adaptive_fit.restype = ctypes.c_int
    library.adaptive_fits.argtypes = [long, pointer, pointer, long, long, pointer, long, pointer, pointer,
                                      long, long, long, pointer, long, pointer, double, double, double, double, double,
                                      double, double, pointer, pointer]  # fmt: skip
    library.adaptive_fits.restype = None
    library.causal_candidates.argtypes = [long, pointer, pointer, long, double, double, long, pointer, long, pointer,
                                          long, pointer, pointer, pointer]  # fmt: skip
    library.causal_candidates.restype = None
    library.choose_degrees.argtypes = [long, long, long, pointer, ctypes.c_longlong, pointer, long, long, pointer,
                                       long, long, pointer, long, long, pointer, long, long, pointer, long, double,
                                       double, ctypes.c_int, double, double, ctypes.c_longlong, ctypes.c_longlong,
                                       double, long, pointer, pointer]  # fmt: skip
    library.choose_degrees.restype = None
    library.choose_last.argtypes = [long, long, long, pointer, pointer, pointer, pointer, pointer, pointer, long,
                                    double, double, ctypes.c_int, double, double, ctypes.c_int, pointer,
                                    pointer]  # fmt: skip
    library.choose_last.restype = None
    native_kalman.declare(library)
    return library


FIT = NativeAdaptiveFit()
"""The one compiled function of this process."""


def fit(
    library: ctypes.CDLL,
    times: np.ndarray,
    values: np.ndarray,
    target: float,
    half_widths: np.ndarray,
    leads: np.ndarray,
    order: int,
    derivative: np.ndarray,
    gamma: float,
    roughness: float,
    sixth_gain: float,
    floor: float,
    growth: float,
    lattice: float,
    lower: int | None = None,
    also: tuple[int, ...] = (),
    timing: float = 0.0,
    finer: bool = False,
) -> tuple[np.ndarray, ...] | None:
    """The C function's value, first and second derivative, stated standard deviation, strain, the
    noise's standard deviation and the deviation the noise puts between the estimate and the level its
    stated deviation is measured against (D, n) each, for ``order``'s next smaller window where ``finer``,
    then ``order`` and each degree of ``also`` (D = finer + 1 + len(also)); None where the Python function
    must serve (too few samples, an order above MAX_ORDER). ``lower``: a second degree fused with ``order``
    (:func:`neforward_ros.estimation.adaptive.fused`), in the same call; ``also``, ``timing``, ``finer``: as
    for :func:`fits`."""
    got = fits(library, times, values, np.array([target], dtype=float), half_widths, leads, order, derivative,
               gamma, roughness, sixth_gain, floor, growth, lattice, lower, also, timing, finer)  # fmt: skip
    if got is None or not got[1][0]:
        return None
    out = got[0][0]
    return out[:, 0], out[:, 1], out[:, 2], out[:, 3], out[:, 4] > 0.5, out[:, 5], out[:, 6]


def fits(
    library: ctypes.CDLL,
    times: np.ndarray,
    values: np.ndarray,
    targets: np.ndarray,
    half_widths: np.ndarray,
    leads: np.ndarray,
    order: int,
    derivative: np.ndarray,
    gamma: float,
    roughness: float,
    sixth_gain: float,
    floor: float,
    growth: float,
    lattice: float,
    lower: int | None = None,
    also: tuple[int, ...] = (),
    timing: float = 0.0,
    finer: bool = False,
) -> tuple[np.ndarray, np.ndarray] | None:
    """The C function at every target over the whole of ``times, values``: value, first and second
    derivative, stated standard deviation, strain, the noise's standard deviation and the deviation it
    puts between the estimate and the level the stated one is measured against (M, finer + 1 + len(also), 7,
    n) for ``order``'s next smaller window where ``finer`` (below), ``order`` and each further degree of
    ``also`` (each below ``order``, with its own windows chosen: the numbers of a call at that degree alone),
    and whether each target was done (M,) (where not, the Python function must serve); None above MAX_ORDER.
    ``lower``: as for :func:`fit`. ``timing``: s, how far the samples' times may be from their stamps
    (:func:`~.adaptive.timing_noise`; 0: none). ``finer``: first, ``order``'s fit at the next smaller window
    than its rule chose (the smallest where it chose that; its strain the rule's): a candidate whose bias the
    degree choice weighs against its noise (:mod:`~.degree_choice`)."""
    if order > MAX_ORDER or (lower is not None and not 0 < lower < order):
        return None
    if len(also) > MAX_ALSO or any(not 0 < degree < order for degree in also):
        return None
    degrees = _longs(np.array(also, dtype=int))
    times = np.ascontiguousarray(times, dtype=float)
    values = np.ascontiguousarray(values, dtype=float)
    targets = np.ascontiguousarray(targets, dtype=float)
    n = values.shape[1]
    out = np.empty((len(targets), 1 + len(also) + finer, 7, n))
    status = np.empty(len(targets), dtype=np.intc)
    half_widths = np.ascontiguousarray(half_widths, dtype=float)
    leads = np.ascontiguousarray(leads, dtype=float)
    derivative = _longs(derivative)

    def run(part: slice) -> None:
        count = part.stop - part.start
        library.adaptive_fits(len(times), times.ctypes.data, values.ctypes.data, n, count,
                              targets[part].ctypes.data, len(half_widths), half_widths.ctypes.data,
                              leads.ctypes.data, order, lower or 0, len(also), degrees.ctypes.data, int(finer),
                              derivative.ctypes.data, gamma, roughness,
                              sixth_gain, floor, growth, lattice, timing, out[part].ctypes.data,
                              status[part].ctypes.data)  # fmt: skip

    # Each target is fitted on its own (the C function keeps nothing from one to the next), and a
    # ctypes call releases the GIL: a whole recording's targets are shared among the cores.
    workers = min(os.cpu_count() or 1, 8) if len(targets) >= PARALLEL_TARGETS else 1
    if workers == 1:  # the node's one target: no parts to share out
        run(slice(0, len(targets)))
    else:
        bounds = np.linspace(0, len(targets), workers + 1).astype(int)
        parts = [slice(int(a), int(b)) for a, b in itertools.pairwise(bounds.tolist())]
        threads = [threading.Thread(target=run, args=(part,), name="neforward-fit") for part in parts[1:]]
        for thread in threads:
            thread.start()
        try:
            run(parts[0])
        finally:
            for thread in threads:
                thread.join()
    return (np.roll(out, 1, axis=1) if finer else out), status == 0  # the finer fit first


def causal_candidates(
    library: ctypes.CDLL,
    times: np.ndarray,
    values: np.ndarray,
    target: float,
    half_widths: np.ndarray,
    degrees: tuple[int, ...],
    extra: int,
    derivative: np.ndarray,
    wanted: np.ndarray | None = None,
    lead: float = 0.0,
) -> np.ndarray | None:
    """The C function's causal candidates (:func:`neforward_ros.estimation.causal_choice.candidates`):
    value, first and second derivative and the derivative's variance factor (C, n, 4), NaN where a
    candidate is not fitted; None above MAX_ORDER (numpy serves)."""
    if max(degrees) > MAX_ORDER:
        return None
    times = np.ascontiguousarray(times, dtype=float)
    values = np.ascontiguousarray(values, dtype=float)
    n = values.shape[1]
    out = np.empty((len(degrees) * len(half_widths), n, 4))
    half_widths = np.ascontiguousarray(half_widths, dtype=float)
    chosen = None if wanted is None else np.ascontiguousarray(wanted, dtype=np.uint8)
    each, columns = _longs(np.array(degrees)), _longs(derivative)  # kept alive across the call
    library.causal_candidates(len(times), times.ctypes.data, values.ctypes.data, n, float(target), float(lead),
                              len(half_widths), half_widths.ctypes.data, len(degrees), each.ctypes.data, extra,
                              columns.ctypes.data, None if chosen is None else chosen.ctypes.data,
                              out.ctypes.data)  # fmt: skip
    return out


def choose_degrees(
    library: ctypes.CDLL,
    stamps_ns: np.ndarray,
    span_ns: int,
    accelerations: np.ndarray,
    stated: np.ndarray,
    noise: np.ndarray,
    between: np.ndarray,
    counted: np.ndarray,
    least: int,
    gamma: float,
    strain: float,
    finer: bool,
    white: float,
    growth: float,
    record_ns: int,
    hole_ns: int,
) -> tuple[np.ndarray, np.ndarray]:
    """The C function's :func:`neforward_ros.estimation.degree_choice.choose`: the degree index chosen
    at each estimate (M, n) and the standard deviation stated with it (M, n), from every degree's
    accelerations, stated deviations, noise's deviations and the noise's deviations between each and
    its neighbouring window (D, M, n) (any strides, a joint's entries adjacent), which of them count
    (M, n), at the stamps (M,), integer ns, increasing; ``finer``, ``white``, ``growth``: whether the first is
    the finer fit, the most colour it may read (:data:`~.degree_choice.WHITE`), how much more the colour its
    reference reads must be for the finer's reading to count as a bias (:data:`~.degree_choice.GROWTH`), and
    the least span of a window's estimates for it and the longest interval between them
    (:data:`~.degree_choice.RECORD`, :data:`~.degree_choice.HOLE`, ns)."""
    item = accelerations.itemsize
    for array in (accelerations, stated, noise, between):
        if array.dtype != np.float64 or array.strides[2] != item or any(x % item for x in array.strides):
            raise ValueError("choose_degrees takes float64 arrays whose joints are adjacent")
    stamps = np.ascontiguousarray(stamps_ns, dtype=np.int64)
    mask = np.ascontiguousarray(counted, dtype=np.uint8)
    degrees, m, n = accelerations.shape
    chosen = np.empty((m, n), dtype=C_LONG)
    out = np.empty((m, n))
    library.choose_degrees(m, degrees, n, stamps.ctypes.data, int(span_ns), accelerations.ctypes.data,
                           accelerations.strides[0] // item, accelerations.strides[1] // item, stated.ctypes.data,
                           stated.strides[0] // item, stated.strides[1] // item, noise.ctypes.data,
                           noise.strides[0] // item, noise.strides[1] // item, between.ctypes.data,
                           between.strides[0] // item, between.strides[1] // item, mask.ctypes.data, least, gamma,
                           strain, int(finer), white, growth, int(record_ns), int(hole_ns), CHOICE_PRECISION,
                           CHOICE_REFRESH, chosen.ctypes.data, out.ctypes.data)  # fmt: skip
    return chosen, out


def choose_last(
    library: ctypes.CDLL,
    scores: np.ndarray,
    accelerations: np.ndarray,
    stated: np.ndarray,
    noise: np.ndarray,
    between: np.ndarray,
    counted: np.ndarray,
    least: int,
    gamma: float,
    strain: float,
    finer: bool,
    white: float,
    growth: float,
    aged: bool,
) -> tuple[np.ndarray, np.ndarray]:
    """The C function's choice for the node (:class:`neforward_ros.estimation.degree_choice.DegreePool`):
    the last estimate's degree index (n,) and the standard deviation stated with it (n,). ``scores``
    (W, 2 D + 5, n), contiguous: the window's estimates' terms (:func:`~.degree_choice.terms`) and
    whether each counts (the last row is written here, from the last estimate's accelerations, stated
    deviations, noise's deviations and those between each and its neighbour (D, n) and which count
    (n,), uint8); their sums added up directly. ``finer``, ``white``, ``growth``: as for :func:`choose_degrees`;
    ``aged``: whether the window's estimates span :data:`~.degree_choice.RECORD` with no hole
    (:data:`~.degree_choice.HOLE`)."""
    rows, degrees, n = scores.shape[0], (scores.shape[1] - 5) // 2, scores.shape[2]
    accelerations = np.ascontiguousarray(accelerations, dtype=float)
    stated = np.ascontiguousarray(stated, dtype=float)
    noise = np.ascontiguousarray(noise, dtype=float)
    between = np.ascontiguousarray(between, dtype=float)
    chosen = np.zeros(n, dtype=C_LONG)
    out = np.full(n, np.nan)  # an empty window (none begun) states nothing
    library.choose_last(rows, degrees, n, scores.ctypes.data, accelerations.ctypes.data, stated.ctypes.data,
                        noise.ctypes.data, between.ctypes.data, counted.ctypes.data, least, gamma, strain,
                        int(finer), white, growth, int(aged), chosen.ctypes.data, out.ctypes.data)  # fmt: skip
    return chosen, out


CHOICE_PRECISION = 64.0
"""How much the values a sliding sum of :func:`choose_degrees` has taken in since it was last added up
may exceed the sum before it is added up afresh (its rounding stays about 1e-14 of it)."""
CHOICE_REFRESH = 4096
"""Estimates after which every sliding sum of :func:`choose_degrees` is added up afresh."""

PARALLEL_TARGETS = 20_000
"""From this many targets on (a whole recording, not a message), :func:`fits` uses every core."""


C_LONG = np.int64 if ctypes.sizeof(ctypes.c_long) == 8 else np.int32
"""numpy's type of a C long."""


def _longs(values: np.ndarray) -> np.ndarray:
    """As C longs, contiguous."""
    return np.ascontiguousarray(values, dtype=C_LONG)
