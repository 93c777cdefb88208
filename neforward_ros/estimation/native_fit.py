"""The node's adaptive polynomial fit (:func:`neforward_ros.estimation.adaptive.adaptive_fit`) as
machine code: the same windows, noise, fits and ICI rule, written in C and compiled once per machine.

The Python function makes some sixty numpy calls per estimate, each a few microseconds however small
its arrays: about 0.2 ms a message, which at 2 kHz is most of the node's budget. Here one C call
does the same. Its arithmetic differs from numpy's only in the order of additions: the windows are
nested, so each sample's powers are added once, ring by ring from the smallest window outwards (in
the largest window's unit, rescaled per level: inner sums never come from differences of larger
ones), where the Python function fits each level on its own; and the normal equations are inverted
by a Cholesky factorisation where numpy calls LAPACK. The two agree to rounding (tested, with the
same window chosen). Two degrees fused (the default's 6 and 4) come from one call: the lower degree's
normal equations are the leading rows and columns of the higher's, so both share the power sums and
the noise reading. A whole recording's targets (``adaptive_fits``) take each block's sixth differences
from one pass, the same numbers added in the same order as for one target: the node and the bag tool
give bitwise the same estimates (tested).

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

from neforward_ros.kinematics import native

WORTH_WAITING = 5000
"""Targets from which a batch waits for the build rather than fitting in numpy meanwhile."""
MAX_ORDER = 15
"""The highest polynomial degree the C function takes (the Python function serves above it)."""
FLAGS = ("-O3", "-fPIC", "-shared", "-ffp-contract=off", "-fno-fast-math")
"""-O3 vectorises the loops over joints (each joint's sums still added in order: no reassociation
without fast-math): a third faster than -O1 for a humanoid's 33 joints, built in 0.3 s."""

SOURCE = r"""
#include <math.h>
#include <stdlib.h>

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

/* Inverse of the symmetric positive definite d x d matrix a (row-major) into inv; 0 if a is not
   positive definite to rounding. */
static int spd_inverse(const double *a, long d, double *inv) {
    double low[16 * 16], x[16 * 16];
    for (long i = 0; i < d * d; i++) { low[i] = 0.0; x[i] = 0.0; }
    for (long j = 0; j < d; j++) {
        double pivot = a[j * d + j];
        for (long k = 0; k < j; k++) pivot -= low[j * d + k] * low[j * d + k];
        if (!(pivot > 0.0)) return 0;
        low[j * d + j] = sqrt(pivot);
        for (long i = j + 1; i < d; i++) {
            double s = a[i * d + j];
            for (long k = 0; k < j; k++) s -= low[i * d + k] * low[j * d + k];
            low[i * d + j] = s / low[j * d + j];
        }
    }
    for (long i = 0; i < d; i++) {  /* x = low^-1, lower triangular */
        x[i * d + i] = 1.0 / low[i * d + i];
        for (long j = 0; j < i; j++) {
            double s = 0.0;
            for (long k = j; k < i; k++) s += low[i * d + k] * x[k * d + j];
            x[i * d + j] = -s * x[i * d + i];
        }
    }
    for (long i = 0; i < d; i++)
        for (long j = 0; j <= i; j++) {
            double s = 0.0;
            for (long k = i; k < d; k++) s += x[k * d + i] * x[k * d + j];
            inv[i * d + j] = s;
            inv[j * d + i] = s;
        }
    return 1;
}

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

/* One level's fit of degree `order` from the power sums (sums[k] = sum of u^k, moments[k n + j] = sum
   of u^k y_j, u in the largest window's unit h0) into fit (n, 5): value, first and second derivative,
   and the chosen derivative's variance factor for unit noise. 0 if the normal equations are singular. */
static int level_fit(const double *sums, const double *moments, long n, long order, double h, double h0,
                     const long *derivative, double *fit) {
    long d = order + 1;
    double gram[16 * 16], inv[16 * 16], r = h0 / h, scale[33];
    scale[0] = 1.0;
    for (long k = 1; k <= 2 * order; k++) scale[k] = scale[k - 1] * r;
    for (long a = 0; a < d; a++)
        for (long b = 0; b < d; b++) gram[a * d + b] = sums[a + b] * scale[a + b];
    if (!spd_inverse(gram, d, inv)) return 0;
    for (long j = 0; j < n; j++) {
        double c[3] = {0.0, 0.0, 0.0};
        for (long q = 0; q < 3; q++)
            for (long k = 0; k < d; k++) c[q] += inv[q * d + k] * (moments[k * n + j] * scale[k]);
        double *f = fit + j * 5;
        f[0] = c[0];
        f[1] = c[1] / h;
        f[2] = 2.0 * c[2] / (h * h);
        f[3] = derivative[j] == 2 ? 4.0 * inv[2 * d + 2] / (h * h * h * h) : inv[1 * d + 1] / (h * h);
    }
    return 1;
}

/* The ICI rule over the `valid` levels' fits (valid, n, 5) of one degree, into out (5, n): value,
   first and second derivative, stated standard deviation (see stated_std in adaptive.py), strained;
   and into noise (n,) the chosen level's noise's standard deviation. changes (levels, n): how many
   times each column's samples change within each level's window. */
static void choose(double *fits, long valid, long n, const long *lo, const long *hi, const double *changes,
                   const long *derivative, const double *white, const double *step, const double *spread,
                   double gamma, double roughness, double floor_, double *out, double *noise) {
    for (long j = 0; j < n; j++) {
        double low_run = -INFINITY, high_run = INFINITY;
        long chosen = -1;
        int meets[64];
        for (long l = valid - 1; l >= 0; l--) {
            double *fit = fits + (l * n + j) * 5, cnt = (double)(hi[l] - lo[l]);
            double quantisation = step[j] * step[j] / 12.0;
            double crossings = step[j] > 0.0 ? changes[l * n + j] + 1.0 : cnt;
            double independent = nmin(nmax(crossings, 1.0), nmax(cnt, 1.0));
            double least = floor_ * fits[j * 5];  /* level 0's value */
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
        double *fit = fits + (chosen * n + j) * 5;
        long smallest_level = valid - 1;
        int strained = (chosen == smallest_level && smallest_level > 0) || white[j] > roughness * spread[j];
        for (long k = 0; k < 4; k++) out[k * n + j] = fit[k];
        noise[j] = fit[3];
        /* the distance to the next smaller window's estimate, in quadrature; where the smallest was
           chosen, to the next larger one's */
        long other = chosen + 1 < valid ? chosen + 1 : chosen - 1;
        if (other >= 0) {
            const double *neighbour = fits + (other * n + j) * 5;
            long k = derivative[j] == 2 ? 2 : 1;
            double apart = fit[k] - neighbour[k];
            out[3 * n + j] = sqrt(fit[3] * fit[3] + apart * apart);
        }
        out[4 * n + j] = strained ? 1.0 : 0.0;
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

/* adaptive_fit below, with pre (pre_strides, pre_count, n) the sixths of samples [pre_lo, pre_lo +
   pre_count), covering this target's largest window, or NULL: computed here. */
static int fit_target(long count, const double *times, const double *values, long n, double target,
                      long nlevels, const double *levels, const double *leads, long order, long lower,
                      const long *derivative, double gamma, double roughness, double sixth_gain,
                      double floor_, double growth, double lattice, const double *pre, long pre_lo, long pre_count,
                      long pre_strides, double *out) {
    long d = order + 1, lo[64], hi[64], valid = 0, valid_low = 0;
    if (nlevels > 64 || d > 16 || n < 1 || lower < 0 || lower >= order) return 1;
    for (long l = 0; l < nlevels; l++) {
        lo[l] = lower_bound(times, count, (target + leads[l]) - 2.0 * levels[l]);
        hi[l] = upper_bound(times, count, target + leads[l]);
        if (hi[l] - lo[l] >= order + 3 && valid == l) valid = l + 1;
        if (hi[l] - lo[l] >= lower + 3 && valid_low == l) valid_low = l + 1;
    }
    if (valid == 0) return 1;
    if (lower == 0) valid_low = 0;
    long width = hi[0] - lo[0], rings = valid > valid_low ? valid : valid_low;
    double *scratch = malloc(sizeof(double) * (d * n + 5 * (size_t)(valid + valid_low + 1) * n + 6 * n
                                               + (size_t)rings * n + 2 * (size_t)n + (size_t)width));
    if (scratch == NULL) return 2;
    double *moments = scratch, *fits = moments + d * n, *fits_low = fits + 5 * (size_t)valid * n;
    double *out_low = fits_low + 5 * (size_t)valid_low * n;
    double *white = out_low + 5 * (size_t)n, *step = white + n, *spread = step + n;
    double *changes = spread + 4 * n;  /* after previous, candidate, alive: (rings, n) */
    double *noise = changes + (size_t)rings * n, *noise_low = noise + n, *changed = noise_low + n;
    for (long j = 0; j < n; j++) {  /* each level's changes between consecutive samples (changes_within) */
        changed[0] = 0.0;  /* the changes up to each sample of the largest window, which holds the others */
        for (long i = 1; i < width; i++)
            changed[i] = changed[i - 1] + (values[(lo[0] + i) * n + j] != values[(lo[0] + i - 1) * n + j]);
        for (long l = 0; l < rings; l++)
            changes[l * n + j] = hi[l] - 1 > lo[l] ? changed[hi[l] - 1 - lo[0]] - changed[lo[l] - lo[0]] : 0.0;
    }
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
        const double *wt = times + lo[0];
        for (long i = 0; i + 1 < width; i++)  /* the smallest change: an encoder's step, if on its grid */
            for (long j = 0; j < n; j++) {
                double a = fabs(window[(i + 1) * n + j] - window[i * n + j]);
                if (a > 0.0 && a < step[j]) step[j] = a;
            }
        for (long j = 0; j < n; j++) {  /* an encoder's grid: each sample a whole number of steps from
                                            the first, and the changes not all one number of steps */
            if (!isfinite(step[j])) continue;
            double position = 0.0, first = 0.0;
            int varied = 0;
            for (long i = 0; i + 1 < width; i++) {
                double ratio = (window[(i + 1) * n + j] - window[i * n + j]) * (1.0 / step[j]);
                position += ratio;
                if (fabs(position - nearbyint(position)) > lattice) { step[j] = INFINITY; break; }
                if (i == 0) first = nearbyint(ratio);
                else if (nearbyint(ratio) != first) varied = 1;
            }
            if (!varied) step[j] = INFINITY;
        }
        /* noise from the normalised sixth divided differences of samples 1, 2, 4, 8 ... apart (see
           sixth_differences and noise_of): stride 1 is the white noise; a coloured stride counts
           while they grow at most `growth` times per doubling, once the next one agrees */
        double *previous = spread + n, *candidate = previous + n, *alive = candidate + n, weights[7];
        for (long s = 1, b = 0; s == 1 || 6 * s + 8 <= width; s *= 2, b++) {
            long terms = width - 6 * s;
            for (long j = 0; j < n; j++) candidate[j] = 0.0;
            const double *stored = pre != NULL && b < pre_strides
                ? pre + ((size_t)b * pre_count + (lo[0] - pre_lo)) * n : NULL;
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
        }
    }
    for (long j = 0; j < n; j++) if (isinf(step[j]) || width < 8) step[j] = 0.0;
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
        if (l < valid && !level_fit(sums, moments, n, order, levels[l], h0, derivative, fits + l * n * 5)) {
            status = 1;
            break;
        }
        if (l < valid_low && !level_fit(sums, moments, n, lower, levels[l], h0, derivative, fits_low + l * n * 5)) {
            status = 1;
            break;
        }
    }
    if (status == 0) {
        choose(fits, valid, n, lo, hi, changes, derivative, white, step, spread, gamma, roughness, floor_, out,
               noise);
        if (valid_low > 0) {
            choose(fits_low, valid_low, n, lo, hi, changes, derivative, white, step, spread, gamma, roughness,
                   floor_, out_low, noise_low);
            for (long j = 0; j < n; j++) {  /* fused: the lower degree where it agrees and is the quieter */
                long k = derivative[j] == 2 ? 2 : 1;
                double apart = fabs(out_low[k * n + j] - out[k * n + j]);
                double std_low = noise_low[j], std_high = noise[j];
                if (apart <= gamma * hypot(std_low, std_high) && std_low <= std_high)
                    for (long q = 0; q < 5; q++) out[q * n + j] = out_low[q * n + j];
            }
        }
    }
    free(scratch);
    return status;
}

/* See adaptive_fit in neforward_ros/estimation/adaptive.py. times (count,), values (count, n)
   row-major; levels, leads (nlevels,) the half-widths (largest first) and their leads; order the
   polynomial degree and lower a second, lower degree fused with it (see fused in adaptive.py; 0: none),
   both fitted from the same power sums and noise reading; derivative (n,) 2 or 1. out (5, n): value,
   first and second derivative, the chosen derivative's standard deviation, strained (1 or 0). Returns
   0 when done, 1 when the largest window is too small (the caller's function serves), 2 when memory
   runs out. */
int adaptive_fit(long count, const double *times, const double *values, long n, double target,
                 long nlevels, const double *levels, const double *leads, long order, long lower,
                 const long *derivative, double gamma, double roughness, double sixth_gain,
                 double floor_, double growth, double lattice, double *out) {
    return fit_target(count, times, values, n, target, nlevels, levels, leads, order, lower, derivative, gamma,
                      roughness, sixth_gain, floor_, growth, lattice, NULL, 0, 0, 0, out);
}

/* adaptive_fit at each of ntargets targets over the whole of times, values; derivative (n,); out
   (ntargets, 5, n); status (ntargets,) each target's return value. Neighbouring targets' windows
   overlap: a block of them takes its sixth differences from one pass (sixths), which is most of
   each target's work otherwise; the numbers are the same as adaptive_fit's one target at a time. */
void adaptive_fits(long count, const double *times, const double *values, long n, long ntargets,
                   const double *targets, long nlevels, const double *levels, const double *leads,
                   long order, long lower, const long *derivative, double gamma, double roughness,
                   double sixth_gain, double floor_, double growth, double lattice, double *out, int *status) {
    const long block = 256;
    for (long first = 0; first < ntargets; first += block) {
        long last = first + block < ntargets ? first + block : ntargets, lo = count, hi = 0, widest = 0;
        for (long m = first; m < last; m++) {
            long a = lower_bound(times, count, (targets[m] + leads[0]) - 2.0 * levels[0]);
            long z = upper_bound(times, count, targets[m] + leads[0]);
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
                                   derivative, gamma, roughness, sixth_gain, floor_, growth, lattice, pre, lo,
                                   hi - lo,
                                   pre == NULL ? 0 : strides, out + m * 5 * n);
        free(pre);
    }
}

/* The causal candidates (estimation/causal_choice.py) at `target`, at or after the newest sample: level
   l's window [target - 2 h_l, target] (levels largest first: nested, added ring by ring from the
   smallest outwards, as fit_target does), degree degrees[k]; candidate c = k levels + l is fitted where
   wanted is NULL or wanted[c], and its window holds at least degree + extra samples: value, first and
   second derivative, and the derivative's variance factor for unit noise into out (C, n, 4); NaN
   elsewhere. The samples' powers are in the largest window's unit, rescaled per level (level_fit). */
void causal_candidates(long count, const double *times, const double *values, long n, double target,
                       long nlevels, const double *levels, long ndeg, const long *degrees, long extra,
                       const long *derivative, const unsigned char *wanted, double *out) {
    long top = 0;
    for (long k = 0; k < ndeg; k++) if (degrees[k] > top) top = degrees[k];
    long hi = upper_bound(times, count, target), width = 2 * top + 1, rows = top + 1;
    double h0 = levels[0];
    double *sums = calloc((size_t)width, sizeof(double)), *moments = calloc((size_t)rows * n, sizeof(double));
    double *fit = malloc((size_t)n * 5 * sizeof(double));
    long next = hi;  /* the samples [next, hi) are in the running sums */
    for (long c = 0; c < ndeg * nlevels * n * 4; c++) out[c] = NAN;
    for (long l = nlevels - 1; l >= 0; l--) {
        long lo = lower_bound(times, count, target - 2.0 * levels[l]);
        for (long i = next - 1; i >= lo; i--) {
            double u = (times[i] - target) / h0, power = 1.0;
            for (long k = 0; k < width; k++) {
                sums[k] += power;
                if (k < rows) for (long j = 0; j < n; j++) moments[k * n + j] += power * values[i * n + j];
                power *= u;
            }
        }
        if (lo < next) next = lo;
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
"""


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
                                     pointer, double, double, double, double, double, double, pointer]  # fmt: skip
    library.adaptive_fit.restype = ctypes.c_int
    library.adaptive_fits.argtypes = [long, pointer, pointer, long, long, pointer, long, pointer, pointer,
                                      long, long, pointer, double, double, double, double, double, double,
                                      pointer, pointer]  # fmt: skip
    library.adaptive_fits.restype = None
    library.causal_candidates.argtypes = [long, pointer, pointer, long, double, long, pointer, long, pointer, long,
                                          pointer, pointer, pointer]  # fmt: skip
    library.causal_candidates.restype = None
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
) -> tuple[np.ndarray, ...] | None:
    """The C function's value, first and second derivative, standard deviation and strain (n,) each;
    None where the Python function must serve (too few samples, an order above MAX_ORDER). ``lower``:
    a second degree fused with ``order`` (:func:`neforward_ros.estimation.adaptive.fused`), in the same
    call."""
    got = fits(library, times, values, np.array([target], dtype=float), half_widths, leads, order, derivative,
               gamma, roughness, sixth_gain, floor, growth, lattice, lower)  # fmt: skip
    if got is None or not got[1][0]:
        return None
    out = got[0][0]
    return out[0], out[1], out[2], out[3], out[4] > 0.5


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
) -> tuple[np.ndarray, np.ndarray] | None:
    """The C function at every target over the whole of ``times, values``: value, first and second
    derivative, standard deviation and strain (M, 5, n), and whether each target was done (M,)
    (where not, the Python function must serve); None above MAX_ORDER. ``lower``: as for :func:`fit`."""
    if order > MAX_ORDER or (lower is not None and not 0 < lower < order):
        return None
    times = np.ascontiguousarray(times, dtype=float)
    values = np.ascontiguousarray(values, dtype=float)
    targets = np.ascontiguousarray(targets, dtype=float)
    n = values.shape[1]
    out = np.empty((len(targets), 5, n))
    status = np.empty(len(targets), dtype=np.intc)
    half_widths = np.ascontiguousarray(half_widths, dtype=float)
    leads = np.ascontiguousarray(leads, dtype=float)
    derivative = _longs(derivative)

    def run(part: slice) -> None:
        count = part.stop - part.start
        library.adaptive_fits(len(times), times.ctypes.data, values.ctypes.data, n, count,
                              targets[part].ctypes.data, len(half_widths), half_widths.ctypes.data,
                              leads.ctypes.data, order, lower or 0, derivative.ctypes.data, gamma, roughness,
                              sixth_gain, floor, growth, lattice, out[part].ctypes.data,
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
    return out, status == 0


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
    library.causal_candidates(len(times), times.ctypes.data, values.ctypes.data, n, float(target), len(half_widths),
                              half_widths.ctypes.data, len(degrees), each.ctypes.data, extra, columns.ctypes.data,
                              None if chosen is None else chosen.ctypes.data, out.ctypes.data)  # fmt: skip
    return out


PARALLEL_TARGETS = 20_000
"""From this many targets on (a whole recording, not a message), :func:`fits` uses every core."""


def _longs(values: np.ndarray) -> np.ndarray:
    """As C longs, contiguous."""
    kind = np.int64 if ctypes.sizeof(ctypes.c_long) == 8 else np.int32
    return np.ascontiguousarray(values, dtype=kind)
