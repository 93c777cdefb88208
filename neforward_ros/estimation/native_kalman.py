"""One step of the Kalman bank's batched filter (:meth:`~.kalman.KalmanTrack.add`) as machine code: the
prediction, the measurement, the likelihood and the fixed-lag smoother's update of the live steps and
its new step, for every model of a bank, in one C call (:class:`Stepper`). With it, the bank's mixture
of its models at a target, its deviations and the revisions (:class:`Mixer`: numpy's arithmetic in
numpy's order, the same numbers), and, causal, each model's prediction of a sample from the state a
horizon before (:class:`Ahead`: the same in exact arithmetic, worked out as a row times the
transitions since instead of carrying every kept state forward each step).

In numpy the step is some forty calls on arrays of a few hundred numbers (4 models, 15 states, 7
joints), each a few microseconds however small its arrays: most of a bank's cost per message. The
C function computes the same quantities (:mod:`.kalman`'s docstring), with the kept rows moved as
R C_k F^T less a product of one or two columns (Z = R C_k F^T H^T: R C_k A = R C_k F^T - Z S^-1 H Pp,
R C_k g = Z S^-1 e, equal in exact arithmetic to numpy's R C_k A and R C_k g), F^T's zeros skipped,
each product's terms added in index order where numpy's matrix products may pair them otherwise,
and a 2 x 2 innovation covariance inverted by its adjugate where numpy calls LAPACK: the two agree to
rounding (``test/test_native_kalman.py``; both against the dense posterior in
``test/test_estimators.py``).

It is compiled with the adaptive fit's C, in the same library (:mod:`.native_fit`): until that is
ready, and where there is no compiler or ``NEFORWARD_NATIVE=off``, numpy serves.
"""

from __future__ import annotations

import ctypes
import itertools
from typing import Protocol

import numpy as np

MAX_DIM = 32
"""The largest state the C function takes (the motion model's is 15); numpy serves above it."""

SOURCE = r"""
#define KALMAN_MAX_DIM 32
#define KALMAN_LOG_2PI 1.8378770664093453

/* out (rows, cols) = a (rows, inner) b (inner, cols), each output's terms added in index order (the loop
   over the output's columns innermost, where the compiler vectorises). sparse: a's zero entries skipped
   (for finite b only: 0 times infinity would be NaN). */
static void kalman_product(long rows, long inner, long cols, const double *a, const double *b, double *out,
                           int sparse) {
    for (long i = 0; i < rows; i++) {
        double *o = out + i * cols;
        for (long j = 0; j < cols; j++) o[j] = 0.0;
        for (long l = 0; l < inner; l++) {
            double f = a[i * inner + l];
            if (sparse && f == 0.0) continue;
            const double *row = b + l * cols;
            for (long j = 0; j < cols; j++) o[j] += f * row[j];
        }
    }
}

/* out (rows, cols) = a (rows, inner) b^T, b (cols, inner): dot products of rows, in index order. */
static void kalman_product_t(long rows, long inner, long cols, const double *a, const double *b, double *out) {
    for (long i = 0; i < rows; i++)
        for (long c = 0; c < cols; c++) {
            double s = 0.0;
            for (long l = 0; l < inner; l++) s += a[i * inner + l] * b[c * inner + l];
            out[i * cols + c] = s;
        }
}

/* out (rows, cols) = a (rows, inner) b (inner, cols) for a b whose row l is zero outside the columns
   lo[l] .. hi[l] - 1 (a transition's transpose), those zeros' terms skipped (for finite a only). */
static void kalman_banded(long rows, long inner, long cols, const double *a, const double *b, const long *lo,
                          const long *hi, double *out) {
    for (long i = 0; i < rows; i++) {
        double *o = out + i * cols;
        for (long j = 0; j < cols; j++) o[j] = 0.0;
        for (long l = 0; l < inner; l++) {
            double f = a[i * inner + l];
            const double *row = b + l * cols;
            for (long j = lo[l]; j < hi[l]; j++) o[j] += f * row[j];
        }
    }
}

/* One step of M filters of d states sharing m columns (joints), measured by p = 1 or 2 rows of H (the
   position's; the velocity's). F, Q, F^T (M, d, d); H (M, 2, d). The workspace holds the last filtered
   state (M, d, m) and covariance (M, d, d), replaced by the new ones; then each column's log-likelihood
   of the sample and its normalised innovation squared (M, m) each, written; the samples y (2, m) and the
   measurement variances r (2); last the new filtered acceleration's variance r P r^T (M), r the acceleration's
   row of the read-out rows R (M, 3, d). Where means is not NULL, the fixed-lag smoother (kalman.py's _Smoothed, buffers
   of cap steps): the live steps first .. end - 1 are moved (means += R C_k g, variances -= (r C_k F^T H^T)
   S^-1 (...)^T, R C_k <- R C_k A) and step end is written (the new step's read-outs, R P, r P r^T, and
   this measurement's A and g). Returns 0; 1 where d or p is out of range, 2 without memory. */
int kalman_step(long M, long d, long m, long p, const double *F, const double *Q, const double *Ft,
                const double *H, double *workspace, const double *R, double *means, double *rows,
                double *variances, double *filtered_acc, double *filtered_var, double *moves, double *pushes,
                long cap, long first, long end) {
    if (d > KALMAN_MAX_DIM || d < 1 || p < 1 || p > 2) return 1;
    double *xp = malloc(sizeof(double) * (size_t)((2 * d + 4) * m));
    if (xp == NULL) return 2;
    double *e = xp + d * m;  /* the innovations (p, m) */
    double *w = e + 2 * m;   /* S^-1 e (p, m) */
    double *g = w + 2 * m;   /* F^T H^T S^-1 e (d, m) */
    double *state = workspace, *cov = state + M * d * m, *likelihood = cov + M * d * d, *nis = likelihood + M * m;
    const double *y = nis + M * m, *r = y + 2 * m;
    double *acceleration_variance = (double *)r + 2;
    for (long k = 0; k < M; k++) {
        const double *Fk = F + k * d * d, *Qk = Q + k * d * d, *Ftk = Ft + k * d * d, *Hk = H + k * 2 * d;
        double *x = state + k * d * m, *P = cov + k * d * d;
        double T[KALMAN_MAX_DIM * KALMAN_MAX_DIM], HP[2 * KALMAN_MAX_DIM], S[4], inv[4], det;
        long lo[KALMAN_MAX_DIM], hi[KALMAN_MAX_DIM];  /* F^T's non-zero columns, row by row */
        for (long l = 0; l < d; l++) {
            lo[l] = d;
            hi[l] = 0;
            for (long j = 0; j < d; j++)
                if (Ftk[l * d + j] != 0.0) { if (j < lo[l]) lo[l] = j; hi[l] = j + 1; }
            if (hi[l] == 0) lo[l] = 0;
        }
        /* the prediction: x = F x, P = F (P F^T) + Q */
        kalman_product(d, d, m, Fk, x, xp, 0);
        kalman_banded(d, d, d, P, Ftk, lo, hi, T);
        kalman_product(d, d, d, Fk, T, P, 1);
        for (long i = 0; i < d * d; i++) P[i] += Qk[i];
        /* the measurement: H Pp, S = H Pp H^T + diag(r), its inverse */
        kalman_product(p, d, d, Hk, P, HP, 0);
        kalman_product_t(p, d, p, HP, Hk, S);
        if (p == 1) {
            /* the prediction's own part is never negative: rounding can make it so on noise-free samples */
            S[0] = (S[0] > 0.0 ? S[0] : 0.0) + r[0];
            det = S[0];
            inv[0] = 1.0 / S[0];
        } else {
            S[0] += r[0];
            S[3] += r[1];
            det = S[0] * S[3] - S[1] * S[2];
            inv[0] = S[3] / det; inv[1] = -S[1] / det; inv[2] = -S[2] / det; inv[3] = S[0] / det;
        }
        kalman_product(p, d, m, Hk, xp, e, 0);
        for (long i = 0; i < p * m; i++) e[i] = y[i] - e[i];
        kalman_product(p, p, m, inv, e, w, 0);
        double *like = likelihood + k * m, *nk = nis + k * m;
        for (long j = 0; j < m; j++) {
            double squared = 0.0;
            for (long a = 0; a < p; a++) squared += e[a * m + j] * w[a * m + j];
            nk[j] = squared / (double)p;
            like[j] = -0.5 * (squared + log(det) + (double)p * KALMAN_LOG_2PI);
        }
        /* the update: x = xp + K e, P = Pp - K H Pp, K = (S^-1 H Pp)^T; then P symmetrised */
        double K[2 * KALMAN_MAX_DIM];  /* K[i * p + a] */
        for (long i = 0; i < d; i++)
            for (long a = 0; a < p; a++) {
                double s = 0.0;
                for (long b = 0; b < p; b++) s += inv[a * p + b] * HP[b * d + i];
                K[i * p + a] = s;
            }
        kalman_product(d, p, m, K, e, x, 0);
        for (long i = 0; i < d * m; i++) x[i] += xp[i];
        kalman_product(d, p, d, K, HP, T, 0);
        for (long i = 0; i < d * d; i++) T[i] = P[i] - T[i];
        for (long i = 0; i < d; i++)
            for (long j = 0; j < d; j++) P[i * d + j] = 0.5 * (T[i * d + j] + T[j * d + i]);
        /* the filtered acceleration's variance, r P r^T (r: R's acceleration row) */
        const double *racc = R + (k * 3 + 2) * d;
        double rpr = 0.0;
        for (long l = 0; l < d; l++) {
            double s = 0.0;
            for (long i = 0; i < d; i++) s += racc[i] * P[i * d + l];
            rpr += s * racc[l];
        }
        acceleration_variance[k] = rpr;
        if (means == NULL) continue;
        /* the smoother: F^T H^T, A = F^T - (F^T H^T S^-1) H Pp, g = F^T H^T S^-1 e */
        const double *Rk = R + k * 3 * d;
        double MF[2 * KALMAN_MAX_DIM], MFI[2 * KALMAN_MAX_DIM];  /* [i * p + a] */
        double *A = moves + (k * cap + end) * d * d, *gk = pushes + (k * cap + end) * d * m;
        kalman_product_t(d, d, p, Ftk, Hk, MF);
        kalman_product(d, p, p, MF, inv, MFI, 0);
        kalman_product(d, p, d, MFI, HP, A, 0);
        for (long i = 0; i < d * d; i++) A[i] = Ftk[i] - A[i];
        kalman_product(d, p, m, MF, w, g, 0);
        for (long i = 0; i < d * m; i++) gk[i] = g[i];
        double *mk = means + k * cap * 3 * m, *rk = rows + k * cap * 3 * d, *vk = variances + k * cap;
        long live = 3 * (end - first);
        if (live > 0) {
            /* with Z = R C_k (F^T H^T) (live, p): means += Z (S^-1 e), variances -= z S^-1 z^T (z: Z's
               acceleration rows), R C_k <- R C_k A = (R C_k) F^T - (Z S^-1) H Pp; on the transposed rows
               (d, live), each product's terms in the same order, so that its loops run along the steps */
            double *read = malloc(sizeof(double) * (size_t)(live * (2 * d + 2 * p + m)));
            if (read == NULL) { free(xp); return 2; }
            double *moved = read + live * d, *Z = moved + live * d, *ZI = Z + live * p, *shift = ZI + live * p;
            double *block = rk + 3 * first * d;
            for (long i = 0; i < live; i++)
                for (long l = 0; l < d; l++) read[l * live + i] = block[i * d + l];
            for (long a = 0; a < p; a++) {  /* Z^T (p, live) */
                double *o = Z + a * live;
                for (long i = 0; i < live; i++) o[i] = 0.0;
                for (long l = 0; l < d; l++) {
                    double f = MF[l * p + a];
                    const double *row = read + l * live;
                    for (long i = 0; i < live; i++) o[i] += row[i] * f;
                }
            }
            for (long i = 0; i < live; i++)  /* Z S^-1 (live, p) */
                for (long a = 0; a < p; a++) {
                    double s = 0.0;
                    for (long b = 0; b < p; b++) s += Z[b * live + i] * inv[b * p + a];
                    ZI[i * p + a] = s;
                }
            for (long i = 0; i < live; i++)
                for (long j = 0; j < m; j++) {
                    double s = 0.0;
                    for (long a = 0; a < p; a++) s += Z[a * live + i] * w[a * m + j];
                    shift[i * m + j] = s;
                }
            for (long i = 0; i < live * m; i++) mk[3 * first * m + i] += shift[i];
            for (long step = 0; step < end - first; step++) {
                long i = 3 * step + 2;
                double quadratic = 0.0;
                for (long a = 0; a < p; a++) quadratic += Z[a * live + i] * ZI[i * p + a];
                vk[first + step] -= quadratic;
            }
            kalman_product(d, d, live, Fk, read, moved, 1);  /* (R C_k F^T)^T = F (R C_k)^T */
            for (long i = 0; i < live; i++)
                for (long j = 0; j < d; j++) {
                    double s = 0.0;
                    for (long a = 0; a < p; a++) s += ZI[i * p + a] * HP[a * d + j];
                    block[i * d + j] = moved[j * live + i] - s;
                }
            free(read);
        }
        /* the new step: R x, R P, r P r^T */
        kalman_product(3, d, m, Rk, x, mk + 3 * end * m, 0);
        kalman_product(3, d, d, Rk, P, rk + 3 * end * d, 0);
        vk[end] = rpr;  /* r P r^T, above (the same sums in the same order as R P's row, then times r) */
        filtered_var[k * cap + end] = rpr;
        for (long j = 0; j < m; j++) filtered_acc[(k * cap + end) * m + j] = mk[(3 * end + 2) * m + j];
    }
    free(xp);
    return 0;
}

/* The bank's prediction of a sample from the filtered state a horizon before (kalman_bank's
   _prediction_errors), from a workspace (see Ahead): states (cap, M, d, m) and transitions (cap, M, d, d)
   rings, slot s holding a step's filtered state and the transition F_s from the step before it to it;
   errors (M, m); y (m) the sample. The prediction from the state in slot scored: h F_now F_s+later ... F_s+1 x
   (the count - 1 slots after it, then F_now (M, d, d), this step's), h the position's row (c + g, states 0
   and 3), worked out right to left from h; errors = max((y - prediction)^2, noise), as numpy's. */
void kalman_ahead(long M, long d, long m, const double *F_now, double *work, long cap, long scored, long count,
                  double noise) {
    double *states = work, *transitions = states + cap * M * d * m, *errors = transitions + cap * M * d * d;
    const double *y = errors + M * m;
    double v[KALMAN_MAX_DIM], next[KALMAN_MAX_DIM];
    if (d > KALMAN_MAX_DIM || d < 4) return;
    for (long k = 0; k < M; k++) {
        for (long l = 0; l < d; l++) v[l] = l == 0 || l == 3 ? 1.0 : 0.0;
        for (long n = count; n >= 1; n--) {  /* F_now, then the later slots' back to the one after scored */
            const double *Fk = n == count ? F_now + k * d * d : transitions + (((scored + n) % cap) * M + k) * d * d;
            for (long l = 0; l < d; l++) next[l] = 0.0;
            for (long i = 0; i < d; i++) {
                double f = v[i];
                if (f == 0.0) continue;
                for (long l = 0; l < d; l++) next[l] += f * Fk[i * d + l];
            }
            for (long l = 0; l < d; l++) v[l] = next[l];
        }
        const double *x = states + (scored * M + k) * d * m;
        for (long j = 0; j < m; j++) {
            double prediction = 0.0;
            for (long l = 0; l < d; l++) prediction += v[l] * x[l * m + j];
            double off = y[j] - prediction, squared = off * off;
            errors[k * m + j] = squared > noise || squared != squared ? squared : noise;
        }
    }
}

/* The bank's mixture at one target (kalman_bank.KalmanBank.estimates), from a workspace (see Mixer):
   est (M, 3, m) each model's position, velocity and acceleration; own (M) each model's acceleration
   variance; facc (M, m) and fvar (M) the step's filtered accelerations and their variances (read where
   filtered is set); w (M, m) the weights, or what they are worked out from, replaced by them: with
   weighting 1, the scores (exp(score) normalised), with 2, the squared errors e of the predictions
   ahead ((least e / e) ** power normalised, 1 for an e of 0); rev (m) the mean normalised revisions,
   updated with memory where filtered is set; out: mix (3, m) and std (m). Sums over the models in
   their order, as numpy's reductions over the first axis; a NaN score or error propagates as in numpy. */
void kalman_mix(long M, long m, int filtered, int weighting, double memory, double power, double *work) {
    double *est = work, *own = est + M * 3 * m, *facc = own + M, *fvar = facc + M * m, *w = fvar + M;
    double *rev = w + M * m, *mix = rev + m, *std = mix + 3 * m;
    for (long j = 0; j < m; j++) {
        if (weighting) {
            double top = w[j]; /* the largest score, or the least error */
            for (long k = 1; k < M; k++) {
                double v = w[k * m + j];
                if (v != v || (weighting == 1 ? v > top : v < top)) top = v;
            }
            double total = 0.0;
            for (long k = 0; k < M; k++) {
                double v = w[k * m + j];
                w[k * m + j] = weighting == 1 ? exp(v - top) : pow(v > 0.0 ? top / v : 1.0, power);
                total = k ? total + w[k * m + j] : w[k * m + j];
            }
            for (long k = 0; k < M; k++) w[k * m + j] /= total;
        }
        for (long c = 0; c < 3; c++) {
            double s = 0.0;
            for (long k = 0; k < M; k++) {
                double term = w[k * m + j] * est[(k * 3 + c) * m + j];
                s = k ? s + term : term;
            }
            mix[c * m + j] = s;
        }
        double variance = 0.0, expected = 0.0, revised = 0.0, acc = mix[2 * m + j];
        for (long k = 0; k < M; k++) {
            double wk = w[k * m + j], spread = est[(k * 3 + 2) * m + j] - acc;
            double term = wk * (own[k] + spread * spread);
            variance = k ? variance + term : term;
            if (filtered) {
                double e = wk * (fvar[k] - own[k]), r = wk * facc[k * m + j];
                expected = k ? expected + e : e;
                revised = k ? revised + r : r;
            }
        }
        if (filtered) {
            double revision = revised - acc, ratio = expected > 0.0 ? revision * revision / expected : 1.0;
            rev[j] = (1.0 - memory) * rev[j] + memory * ratio;
        }
        double scale = rev[j] >= 1.0 || rev[j] != rev[j] ? rev[j] : 1.0;
        std[j] = sqrt(variance * scale);
    }
}
"""


def declare(library: ctypes.CDLL) -> None:
    """The argument types of :class:`Stepper`'s and :class:`Mixer`'s C functions."""
    pointer, long = ctypes.c_void_p, ctypes.c_long
    library.kalman_step.argtypes = [long, long, long, long] + [pointer] * 13 + [long, long, long]
    library.kalman_step.restype = ctypes.c_int
    library.kalman_mix.argtypes = [long, long, ctypes.c_int, ctypes.c_int, ctypes.c_double, ctypes.c_double,
                                   pointer]  # fmt: skip
    library.kalman_mix.restype = None
    library.kalman_ahead.argtypes = [long, long, long, pointer, pointer, long, long, long, ctypes.c_double]
    library.kalman_ahead.restype = None


SMOOTHED_BUFFERS = ("means", "rows", "variances", "filtered_accelerations", "filtered_variances", "moves", "pushes")
"""The buffers of :class:`~.kalman._Smoothed` the C function moves and writes, in its arguments' order."""


def _workspace(*sizes: int) -> tuple[np.ndarray, int, list[np.ndarray]]:
    """One zeroed float64 array of the sizes' sum, its address (taken once: reading a numpy array's address
    costs microseconds) and its consecutive parts of those sizes (views, flat)."""
    workspace = np.zeros(sum(sizes))
    bounds = np.cumsum((0, *sizes)).tolist()
    return workspace, workspace.ctypes.data, [workspace[a:b] for a, b in itertools.pairwise(bounds)]


class SmoothedBuffers(Protocol):
    """What the C function reads and writes of a fixed-lag smoother (:class:`~.kalman._Smoothed`): its
    buffers (:data:`SMOOTHED_BUFFERS`, C-contiguous float64, ``variances`` (models, capacity); replaced
    all together where they are, never one alone: :class:`Stepper` checks ``means``), its newest step's
    slot ``end`` and its first live step."""

    means: np.ndarray
    rows: np.ndarray
    variances: np.ndarray
    filtered_accelerations: np.ndarray
    filtered_variances: np.ndarray
    moves: np.ndarray
    pushes: np.ndarray
    end: int

    def first_live(self) -> int: ...


class Stepper:
    """The C function's arguments that outlive a step, for one track of ``count`` models, ``dim`` states
    and ``joints`` columns: a workspace (the newest filtered state and covariance, the outputs, the
    samples) whose address is taken once, and the addresses of the arrays that do not change (the
    read-out rows, the smoother's buffers until they are reallocated): a numpy
    array's address costs microseconds to read, as much as a third of the C function's work.

    Args:
        library: the compiled library (:data:`~.native_fit.FIT`).
        rows: the position's and velocity's read-out rows (models, 2, dim).
        readout: position, velocity and acceleration read-out rows (models, 3, dim).
    """

    def __init__(self, library: ctypes.CDLL, rows: np.ndarray, readout: np.ndarray, joints: int) -> None:
        self._function = library.kalman_step
        count, _, dim = rows.shape
        self._shape = (count, dim, joints)
        self._arrays = (np.ascontiguousarray(rows, dtype=float), np.ascontiguousarray(readout, dtype=float))
        self._rows, self._readout = (array.ctypes.data for array in self._arrays)
        self._workspace, self._address, parts = _workspace(
            count * dim * joints, count * dim * dim, count * joints, count * joints, 2 * joints, 2, count
        )
        state, covariance, likelihood, nis, samples, variances, acceleration_variance = parts
        self.state = state.reshape(count, dim, joints)
        self.covariance = covariance.reshape(count, dim, dim)
        self.likelihood = likelihood.reshape(count, joints)
        self.nis = nis.reshape(count, joints)
        self.samples = samples.reshape(2, joints)
        self.variances = variances
        self.acceleration_variance = acceleration_variance  # (models,): r P r^T of the new step
        self.holds: object | None = None
        """The step whose filtered state and covariance the workspace holds (the caller's to set)."""
        # the smoother whose buffers' addresses are kept, its means buffer (they are replaced all together) and
        # the addresses
        self._buffers: tuple[SmoothedBuffers, np.ndarray, list[int]] | None = None

    def fits(self, joints: int) -> bool:
        """Whether this stepper serves a track of that many joints."""
        return self._shape[2] == joints

    def step(self, transition: tuple[int, int, int], measured: int, smoothed: SmoothedBuffers | None) -> None:
        """One step from the state and covariance in the workspace, with the samples of its first
        ``measured`` rows (1: positions; 2: and velocities) and their variances, all set by the caller:
        the workspace then holds the new state, covariance, log-likelihoods and normalised innovations
        squared. ``transition``: the addresses of F, Q and F^T (models, dim, dim) each, C-contiguous
        (:meth:`~.motion.MotionModels.transition_addresses`). With ``smoothed`` (a
        :class:`~.kalman._Smoothed` with room for a step at its ``end``), its live steps are moved and its
        new step written (the caller counts it)."""
        count, dim, joints = self._shape
        if smoothed is None:
            buffers, capacity, first, end = [None] * len(SMOOTHED_BUFFERS), 0, 0, 0
        else:
            if self._buffers is None or self._buffers[0] is not smoothed or self._buffers[1] is not smoothed.means:
                arrays = tuple(getattr(smoothed, name) for name in SMOOTHED_BUFFERS)
                if not all(array.flags.c_contiguous and array.dtype == np.float64 for array in arrays):
                    raise ValueError("the smoother's buffers must be C-contiguous float64 arrays")
                self._buffers = (smoothed, smoothed.means, [a.ctypes.data for a in arrays])
            buffers = self._buffers[2]
            capacity, first, end = smoothed.variances.shape[1], smoothed.first_live(), smoothed.end
        status = self._function(count, dim, joints, measured, *transition, self._rows,
                                self._address, self._readout, *buffers, capacity,
                                first, end)  # fmt: skip
        if status != 0:
            raise MemoryError("the Kalman step's C function could not work (too large a state, or no memory)")


class Mixer:
    """The workspace of the C mixture of a bank's models at a target (:meth:`~.kalman_bank.KalmanBank.estimates`)
    for ``count`` models and ``joints`` columns, its address taken once: the caller writes the models'
    estimates, variances, weights (or scores) and, at a step, the step's filtered accelerations and
    their variances into its arrays, calls :meth:`mix`, and reads ``mixture``, ``std`` and the updated
    ``revisions``. numpy's arithmetic in the same order (``test/test_native_kalman.py``), without some
    twenty calls of a few microseconds each.

    Args:
        library: the compiled library (:data:`~.native_fit.FIT`).
    """

    def __init__(self, library: ctypes.CDLL, count: int, joints: int) -> None:
        self._function = library.kalman_mix
        self._shape = (count, joints)
        self._workspace, self._address, parts = _workspace(
            count * 3 * joints, count, count * joints, count, count * joints, joints, 3 * joints, joints
        )
        estimates, own, accelerations, variances, weights, revisions, mixture, std = parts
        self.estimates = estimates.reshape(count, 3, joints)
        self.own = own
        self.filtered_accelerations = accelerations.reshape(count, joints)
        self.filtered_variances = variances
        self.weights = weights.reshape(count, joints)
        self.revisions = revisions
        self.mixture = mixture.reshape(3, joints)
        self.std = std

    def fits(self, count: int, joints: int) -> bool:
        """Whether this mixer serves that many models and joints."""
        return self._shape == (count, joints)

    def mix(self, filtered: bool, weighting: int, memory: float, power: float = 1.0) -> None:
        """The mixture, its standard deviations and (``filtered``: the step's filtered accelerations and
        variances are set) the revisions moved with ``memory``. ``weighting``: 0, ``weights`` holds the
        weights; 1, the scores, replaced by exp(score) normalised over the models; 2, the squared errors
        e of the models' predictions, replaced by (least e / e) ** ``power`` normalised."""
        count, joints = self._shape
        self._function(count, joints, filtered, weighting, memory, power, self._address)


class Ahead:
    """The Kalman bank's predictions of each sample from the filtered state :data:`~.kalman_bank.HORIZON`
    before (:meth:`~.kalman_bank.KalmanBank._prediction_errors`) in C. numpy carries every kept state
    forward by each step's transition and reads the oldest's position, ``ahead`` products of (dim, dim)
    by (dim, kept x joints) a step; this keeps the states as filtered, with each step's transition, and
    works out the one prediction asked for as the position's row times the transitions since, right to
    left, times the state: ``ahead`` row-by-matrix products and one by the state. The same in exact
    arithmetic; the rings' address is taken once (grown, with what they keep, where more is asked for).

    Args:
        library: the compiled library (:data:`~.native_fit.FIT`).
        kept: numpy's kept predictions (models, dim, kept, joints), the oldest first, each carried to the
            newest step; none where None.
    """

    def __init__(self, library: ctypes.CDLL, count: int, dim: int, joints: int, kept: np.ndarray | None = None) -> None:
        self._function = library.kalman_ahead
        self._shape = (count, dim, joints)
        self._allocate(max(16, 0 if kept is None else kept.shape[2]))
        self.head = self.kept = 0
        if kept is not None:  # each already carried to the newest step: no transition between them
            self.kept = kept.shape[2]
            self.states[: self.kept] = kept.transpose(2, 0, 1, 3)
            self.transitions[: self.kept] = np.eye(dim)

    def _allocate(self, capacity: int) -> None:
        count, dim, joints = self._shape
        self._workspace, self._address, parts = _workspace(
            capacity * count * dim * joints, capacity * count * dim * dim, count * joints, joints
        )
        states, transitions, errors, sample = parts
        self.states = states.reshape(capacity, count, dim, joints)
        self.transitions = transitions.reshape(capacity, count, dim, dim)
        self.errors = errors.reshape(count, joints)
        self.sample = sample

    def _slots(self) -> list[int]:
        capacity = len(self.states)
        return [(self.head + n) % capacity for n in range(self.kept)]

    def stacked(self) -> np.ndarray:
        """numpy's kept predictions (models, dim, kept, joints), the oldest first: each kept state carried
        to the newest step by the transitions of the steps after it."""
        slots = self._slots()
        carried = []
        for n, slot in enumerate(slots):
            state = self.states[slot]
            for later in slots[n + 1 :]:
                state = self.transitions[later] @ state
            carried.append(state)
        return np.stack(carried, axis=2)

    def predict(self, transition: int, positions: np.ndarray, ahead: int, noise: float) -> bool:
        """Where ``ahead`` states are kept, ``errors`` set to each model's squared error of the position it
        predicted for ``positions`` from the state ``ahead`` steps back (at least ``noise``), through this
        step's transition (the address of F (models, dim, dim), C-contiguous): returns whether it was."""
        if self.kept < ahead:
            return False
        self.sample[...] = positions
        count, dim, joints = self._shape
        capacity = len(self.states)
        scored = (self.head + self.kept - ahead) % capacity
        self._function(count, dim, joints, transition, self._address, capacity, scored, ahead, noise)
        return True

    def push(self, newest: np.ndarray, transition: np.ndarray | None, ahead: int) -> None:
        """Keep the newest filtered state (models, dim, joints), reached by ``transition`` (F (models, dim,
        dim); None: the first after a start), with the last ``ahead`` - 1 kept before it."""
        keep = min(self.kept, ahead - 1)
        capacity = len(self.states)
        if keep + 1 > capacity:
            slots = self._slots()[self.kept - keep :]
            states, transitions = self.states[slots], self.transitions[slots]
            self._allocate(2 * (keep + 1))
            self.states[:keep], self.transitions[:keep] = states, transitions
            self.head, capacity = 0, len(self.states)
        else:
            self.head = (self.head + self.kept - keep) % capacity
        self.kept = keep + 1
        slot = (self.head + keep) % capacity
        self.states[slot] = newest
        self.transitions[slot] = np.eye(self._shape[1]) if transition is None else transition

    def reset(self) -> None:
        """Forget the kept states (a start, a silence)."""
        self.head = self.kept = 0
