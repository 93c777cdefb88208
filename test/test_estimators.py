"""Live estimates you can trust: the accuracy targets of every estimator against the analytic reference
signal, no start-up or gap spikes, readiness by coverage, and the Kalman estimator against independent
oracles (matrix exponentials, the Matérn kernel's closed form, dense Gaussian-process regression)."""

from __future__ import annotations

import logging
import math

import numpy as np
import pytest

from neforward_ros.estimation import kalman, native_fit
from neforward_ros.estimation.coverage import Support, covered_mask, uncovered
from neforward_ros.estimation.kalman import KalmanTrack
from neforward_ros.estimation.motion import ORDER, TREND_JERK, KalmanSettings, MotionModel
from neforward_ros.estimation.settings import StreamSettings
from neforward_ros.estimation.stream import StreamingEstimator
from neforward_ros.kinematics import native

from conftest import EPOCH_NS, LogRecorder, reference

SHIFTS = (0.0, 0.8, 1.6, 2.4)  # four joints: the reference signal, phase-shifted

SETTINGS = {
    "polyfit fixed_lag": StreamSettings(),
    "polyfit causal": StreamSettings(mode="causal"),
    "kalman fixed_lag": StreamSettings(method="kalman"),
    "kalman causal": StreamSettings(method="kalman", mode="causal"),
}


def samples(seconds: float, rate: float = 500.0, noise: float = 1e-4, gap: float | None = None, seed: int = 0):
    """(t s, stamps ns, q (T, 4)) of the reference signal with +-10 % stamp jitter; a 0.3 s stretch
    with no samples from ``gap`` on."""
    rng = np.random.default_rng(seed)
    count = int(seconds * rate)
    t = (np.arange(count) + rng.uniform(-0.1, 0.1, count)) / rate
    if gap is not None:
        t = t[(t < gap) | (t >= gap + 0.3)]
    q = np.stack([reference(t, shift)[0] for shift in SHIFTS], axis=1)
    q = q + rng.normal(0.0, noise, q.shape)
    return t, EPOCH_NS + np.round(t * 1e9).astype(np.int64), q


def true_qdd(t: np.ndarray) -> np.ndarray:
    return np.stack([reference(t, shift)[2] for shift in SHIFTS], axis=1)


def run(settings: StreamSettings, stamps: np.ndarray, q: np.ndarray, log=None):
    """Every estimate, and the ready ones as (t s, qdd error (T, 4))."""
    names = [f"j{k}" for k in range(q.shape[1])]
    estimator = StreamingEstimator(names, settings=settings, log=log or (lambda level, message: None))
    out = []
    rows = q.tolist()
    for k in range(len(stamps)):
        out += estimator.update(int(stamps[k]), names, rows[k])
    ready = [e for e in out if e.all_ready]
    t_out = (np.array([e.stamp_ns for e in ready]) - EPOCH_NS) / 1e9
    error = np.array([e.accelerations for e in ready]) - true_qdd(t_out)
    return out, t_out, error


# -- accuracy targets (noisy 500 Hz reference; the README's table comes from bench/bench_estimators.py) --


@pytest.mark.parametrize(
    "name, bound, delay",
    [
        ("polyfit fixed_lag", 5e-3, 0.1),  # the default
        ("kalman fixed_lag", 3e-2, 0.02),  # the low-delay setting: 20 ms, 3 % (its target over the family)
        ("kalman causal", 7e-2, 0.0),  # zero delay: 7 % (self-tuned; its target over the family is 6 %)
        ("polyfit causal", 0.1, 0.0),
    ],
)
def test_accuracy_targets_on_the_noisy_reference_signal(name: str, bound: float, delay: float) -> None:
    settings = SETTINGS[name]
    _, stamps, q = samples(6.0)
    out, t_out, error = run(settings, stamps, q)
    assert settings.effective_lag == delay
    steady = t_out > t_out[0] + 1.0
    truth = true_qdd(t_out)
    relative = np.sqrt(np.mean(error[steady] ** 2) / np.mean(truth[steady] ** 2))
    assert relative <= bound, f"{name}: q-ddot relative RMS {relative:.2e} > {bound:.0e}"
    # each estimate refers to the sample `delay` before the newest input when it is emitted
    emitted_at = np.searchsorted(stamps, [e.stamp_ns for e in out]) + 0  # its own sample
    assert np.array_equal(stamps[emitted_at], [e.stamp_ns for e in out])


BOUND = {"polyfit fixed_lag": 6.0}
"""The default's first estimates after a start have no record of the last second to choose their degree
by (.degree_choice): its first 20 take the reference degree, 6, whose noise is larger than the degree the
record then chooses (here its steady RMS error is 0.026 rad/s^2, 0.071 with a per-estimate choice): the
largest error in its first second, 0.15 rad/s^2, is 5.5x the steady RMS, within 3x the steady 99th
percentile."""


@pytest.mark.parametrize("name", sorted(SETTINGS))
def test_no_spike_after_the_start_or_a_gap(name: str) -> None:
    """The old causal estimator gave q-ddot = 26, -91, 108 right after a start where the truth never
    exceeds 4.9, and 4x its usual worst error after a 0.3 s gap. Now the first second after the
    start and after a gap is as good as any other second: its largest error per joint is at most 5x
    that joint's steady RMS error (a steady second of noise-dominated error reaches about 3.3x; the
    default: :data:`BOUND`) and 3x its steady 99th percentile, and its RMS error at most 1.5x the
    steady one."""
    settings = SETTINGS[name]
    _, stamps, q = samples(7.0, gap=3.5)
    _, t_out, error = run(settings, stamps, q)
    first = t_out[0]
    steady = (t_out > first + 1.0) & ((t_out < 3.0) | (t_out > 5.3))
    steady_rms = np.sqrt(np.mean(error[steady] ** 2, axis=0))
    for label, stretch in (
        ("start", t_out <= first + 1.0),
        ("gap", (t_out >= 3.0) & (t_out <= 4.8)),
    ):
        assert stretch.sum() > 300, label
        worst = np.abs(error[stretch]).max(axis=0) / steady_rms
        rms = np.sqrt(np.mean(error[stretch] ** 2, axis=0)) / steady_rms
        assert worst.max() <= BOUND.get(name, 5.0), f"{name} {label}: largest error {worst.max():.1f}x the steady RMS"
        p99 = np.percentile(np.abs(error[steady]), 99, axis=0)  # issue 26's: at most 3x the steady 99th percentile
        assert np.all(np.abs(error[stretch]).max(axis=0) <= 3.0 * p99), f"{name} {label}"
        assert rms.max() <= 1.5, f"{name} {label}: RMS error {rms.max():.2f}x the steady RMS"


@pytest.mark.parametrize("name", ["polyfit causal", "kalman causal"])
def test_the_issues_own_cases_half_a_hertz_after_start_and_three_hertz_after_a_gap(name: str) -> None:
    settings = SETTINGS[name]
    rng = np.random.default_rng(5)
    for frequency, gap in ((0.5, None), (3.0, 2.0)):
        count = 2500
        t = (np.arange(count) + rng.uniform(-0.1, 0.1, count)) / 500.0
        if gap is not None:
            t = t[(t < gap) | (t >= gap + 0.3)]
        w = 2 * np.pi * frequency
        q = 0.5 * np.sin(w * t) + rng.normal(0.0, 1e-4, len(t))
        stamps = EPOCH_NS + np.round(t * 1e9).astype(np.int64)
        estimator = StreamingEstimator(["j"], settings=settings, log=lambda level, message: None)
        out = [e for k in range(len(t)) for e in estimator.update(int(stamps[k]), ["j"], [q[k]]) if e.all_ready]
        t_out = (np.array([e.stamp_ns for e in out]) - EPOCH_NS) / 1e9
        error = np.array([e.accelerations[0] for e in out]) + 0.5 * w * w * np.sin(w * t_out)
        first = t_out[0]
        if gap is None:
            stretch, steady = t_out <= first + 1.0, t_out > first + 1.0
        else:
            stretch = (t_out >= gap - 0.5) & (t_out <= gap + 1.3)
            steady = (t_out > first + 1.0) & ~stretch
        # issue 26's measure: the worst error after the start or the gap at most 3x the steady 99th percentile
        steady_p99 = np.percentile(np.abs(error[steady]), 99)
        assert np.abs(error[stretch]).max() <= 3.0 * steady_p99, (frequency, np.abs(error[stretch]).max(), steady_p99)


# -- readiness ------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "settings, before, record",
    [
        (StreamSettings(), 0.1, 0.0),  # polyfit, centred: 0.1 s of history
        (StreamSettings(mode="causal"), 0.2, 0.25),  # polyfit, one-sided: the whole window, and from a start the record
        (StreamSettings(method="kalman"), 0.2, 0.25),  # kalman: its warm-up window
        (StreamSettings(method="kalman", mode="causal"), 0.2, 0.25),
    ],
)
def test_no_estimate_until_the_samples_cover_the_support_after_a_start_a_gap_and_a_stamp_reset(
    settings: StreamSettings, before: float, record: float
) -> None:
    """Regular 500 Hz stamps: the first estimate after each (re)start is the first stamp with ``before``
    seconds of samples behind it, and from the start, for the settings that choose by their candidates'
    record, within ``record`` seconds after that (the record held: ``stream.HOLD_UNTIL_RECORD``; a restart
    keeps it); a 0.3 s gap (within max_gap) blanks every estimate whose support reaches into it."""
    step = 2_000_000
    stamps = EPOCH_NS + step * np.r_[0:500, 650:1000]  # 1 s, a 0.3 s gap, 0.7 s
    t = (stamps - EPOCH_NS) / 1e9
    q = np.stack([reference(t, shift)[0] for shift in SHIFTS], axis=1)
    log = LogRecorder()
    names = [f"j{k}" for k in range(4)]
    estimator = StreamingEstimator(names, settings=settings, log=log)
    out = []
    for k in range(len(stamps)):
        out += estimator.update(int(stamps[k]), names, q[k].tolist())
    # then the stamps go back (a bag played again): a new segment that warms up again
    for k in range(200):
        out += estimator.update(int(stamps[k]), names, q[k].tolist())
    support = settings.support
    for segment, origin, gap_end in ((0, stamps[0], stamps[500]), (1, stamps[0], None)):
        ready = [e.stamp_ns for e in out if e.segment == segment and e.all_ready]
        assert ready, segment
        first = origin + round(before * 1e9)
        if segment == 0 and record:
            assert first < ready[0] <= first + round(record * 1e9), (ready[0] - first) / 1e9
        else:
            assert ready[0] == first
        if gap_end is not None:  # nothing whose support reaches into the gap (1.0 s to 1.3 s)
            gap_start = stamps[499]
            before_gap = [s for s in ready if s <= gap_start]
            after_gap = [s for s in ready if s > gap_start]
            # up to the last sample before it, give or take 1.5 sample intervals (a jittered sample's)
            assert max(before_gap) + support.after * 1e9 <= gap_start + 1.5 * step
            assert max(before_gap) + support.after * 1e9 > gap_start - step  # and no earlier
            assert min(after_gap) - support.before * 1e9 >= gap_end
            resumed = min(s for s in ready if s > gap_start)
            assert resumed == gap_end + round(support.before * 1e9)
    assert log.count("no estimate yet for joint(s) j0, j1, j2, j3") >= 1
    assert all(level == logging.INFO for level, message in log.lines if "no estimate yet" in message)


def test_samples_too_sparse_for_the_window_say_so_and_never_estimate() -> None:
    log = LogRecorder()
    estimator = StreamingEstimator(["j"], settings=StreamSettings(mode="causal"), log=log)
    out = []
    for k in range(60):  # 20 Hz: 4 samples in a 0.2 s window, a degree-4 fit needs 10
        out += estimator.update(EPOCH_NS + k * 50_000_000, ["j"], [0.1 * k])
    assert out and not any(e.ready.any() for e in out)
    warnings = [m for level, m in log.lines if level == logging.WARNING and "too sparse" in m]
    assert len(warnings) == 1 and "estimator.window" in warnings[0]


@pytest.mark.parametrize("name", ["polyfit causal", "polyfit fixed_lag"])
def test_the_no_spike_test_fails_with_the_old_readiness_rule(monkeypatch, name: str) -> None:
    """A planted bug, kept as a test: the old rule (ready at three samples, the fit widened to the
    nearest samples and its degree lowered when its window is short) must fail the no-spike test."""
    from neforward_ros.estimation import fit, stream

    def old_rule(
        stamps: np.ndarray, target: int, support: Support, holes=None, end_slack=None, repeats=()
    ) -> str | None:
        return None if np.count_nonzero(stamps <= target) >= 3 else "fewer than 3 samples"

    monkeypatch.setattr(stream, "uncovered", old_rule)
    monkeypatch.setattr(
        stream,
        "fit_window",
        lambda times, values, target, half_width, order: (
            fit.fit_at(times, values, target, half_width, order, 0.0)
            if name == "polyfit causal"
            else fit.fit_at(times, values, target, half_width, order, half_width)
        ),
    )
    with pytest.raises(AssertionError, match="largest error"):
        test_no_spike_after_the_start_or_a_gap(name)


def test_coverage_rule_scalar_and_vectorised_agree() -> None:
    rng = np.random.default_rng(2)
    support = Support(before=0.1, after=0.05, min_samples=6, max_hole=0.03)
    for _ in range(30):
        times = np.sort(rng.uniform(0.0, 1.0, rng.integers(0, 60)))
        times = np.unique(np.round(times, 6))
        targets = rng.uniform(-0.1, 1.1, 40)
        mask = covered_mask(times, targets, support)
        stamps = np.round(times * 1e9).astype(np.int64)
        scalar = [uncovered(stamps, round(target * 1e9), support) is None for target in targets]
        assert mask.tolist() == scalar


def test_coverage_rule_cases() -> None:
    support = Support(before=0.1, after=0.0, min_samples=5, max_hole=0.03)
    ms = 1_000_000
    regular = np.arange(0, 300, 10) * ms
    assert uncovered(regular, 200 * ms, support) is None
    assert uncovered(regular, 50 * ms, support) == "too little history"
    assert uncovered(regular, 295 * ms, support) is None  # 5 ms after the newest: within max_hole
    assert uncovered(regular, 340 * ms, support) == "too few samples after the stamp yet"
    holed = np.r_[np.arange(0, 100, 10), np.arange(150, 300, 10)] * ms
    assert uncovered(holed, 180 * ms, support) == "a gap in the samples"
    assert uncovered(holed, 250 * ms, support) is None
    sparse = np.arange(0, 300, 30) * ms
    assert uncovered(sparse, 200 * ms, support) == "too few samples"


# -- the Kalman estimator against independent oracles ---------------------------------------------


def _generator(model: MotionModel) -> tuple[np.ndarray, np.ndarray]:
    """The continuous-time system of the model, written out from its definition: (A, Qc)."""
    n = ORDER
    dim = model.dim
    a = np.zeros((dim, dim))
    a[0, 1] = a[1, 2] = 1.0  # trend: c' = v, v' = acc, acc' = white jerk
    companion = np.zeros((n, n))
    companion[:-1, 1:] = np.eye(n - 1)
    companion[-1, :] = [-math.comb(n, k) for k in range(n)]
    a[3:, 3:] = model.lam * companion
    stationary = model.prior[3:, 3:]
    qc = np.zeros((dim, dim))
    qc[2, 2] = TREND_JERK
    qc[-1, -1] = -(a[3:, 3:] @ stationary + stationary @ a[3:, 3:].T)[-1, -1]
    return a, qc


def test_motion_model_transitions_equal_the_matrix_exponential_of_the_continuous_system() -> None:
    from scipy.linalg import expm, solve_continuous_lyapunov

    model = MotionModel(KalmanSettings(length_scale=0.3, magnitude=0.5))
    a, qc = _generator(model)
    n = model.dim
    stationary = solve_continuous_lyapunov(a[3:, 3:], -qc[3:, 3:])
    np.testing.assert_allclose(model.prior[3:, 3:], stationary, rtol=1e-8, atol=1e-10 * np.abs(stationary).max())
    for dt in (1e-4, 2e-3, 0.02, 0.2):
        van_loan = np.zeros((2 * n, 2 * n))
        van_loan[:n, :n], van_loan[:n, n:], van_loan[n:, n:] = -a, qc, a.T
        e = expm(van_loan * dt)
        transition, noise = model.transition(dt)
        np.testing.assert_allclose(transition, e[n:, n:].T, rtol=1e-10, atol=1e-12 * np.abs(e[n:, n:]).max())
        expected_noise = e[n:, n:].T @ e[:n, n:]
        np.testing.assert_allclose(noise, expected_noise, rtol=0, atol=1e-9 * np.abs(expected_noise).max())


def test_motion_model_covariance_is_the_matern_kernel() -> None:
    """Cov(g(t + tau), g(t)) for the stationary part is the Matérn kernel of smoothness p + 1/2
    (p = ORDER - 1), magnitude^2 exp(-r) p!/(2p)! sum_i (p+i)!/(i!(p-i)!) (2r)^(p-i), r = sqrt(2 nu) tau / l."""
    settings = KalmanSettings(length_scale=0.4, magnitude=0.3)
    model = MotionModel(settings)
    p = ORDER - 1
    nu = p + 0.5
    for tau in (0.0, 0.01, 0.1, 0.4, 1.0):
        transition, _ = model.transition(tau)
        ours = (transition[3:, 3:] @ model.prior[3:, 3:])[0, 0]
        r = math.sqrt(2 * nu) * tau / settings.length_scale
        series = sum(
            math.factorial(p + i) / (math.factorial(i) * math.factorial(p - i)) * (2 * r) ** (p - i)
            for i in range(p + 1)
        )
        matern = settings.magnitude**2 * math.exp(-r) * math.factorial(p) / math.factorial(2 * p) * series
        assert ours == pytest.approx(matern, rel=1e-9, abs=1e-15)


def _dense_posterior(model: MotionModel, times: np.ndarray, measured_at: np.ndarray, rows: int):
    """The prior covariance of the states at ``times`` (a chain of the model's transitions) and the
    measurement matrix of the nodes ``measured_at`` (position, and velocity with rows 2): dense."""
    dim, count = model.dim, len(times)
    covariance = np.zeros((count * dim, count * dim))
    marginal = model.prior
    transitions = [np.eye(dim)]
    marginals = [marginal]
    for k in range(1, count):
        f, q = model.transition(times[k] - times[k - 1])
        marginal = f @ marginal @ f.T + q
        transitions.append(f)
        marginals.append(marginal)
    for i in range(count):
        block = marginals[i]
        covariance[i * dim : (i + 1) * dim, i * dim : (i + 1) * dim] = block
        for j in range(i + 1, count):
            block = transitions[j] @ block  # Cov(x_j, x_i) = F_j ... F_{i+1} P_i
            covariance[j * dim : (j + 1) * dim, i * dim : (i + 1) * dim] = block
            covariance[i * dim : (i + 1) * dim, j * dim : (j + 1) * dim] = block.T
    h = np.zeros((len(measured_at) * rows, count * dim))
    for k, node in enumerate(measured_at):
        h[rows * k, node * dim : (node + 1) * dim] = model.position_row
        if rows == 2:
            h[rows * k + 1, node * dim : (node + 1) * dim] = model.velocity_row
    return covariance, h


def _refined_solve(matrix: np.ndarray, right: np.ndarray) -> np.ndarray:
    """matrix^-1 right, with two steps of iterative refinement on residuals in extended precision: the
    dense solve alone (condition about 5e9) rounds to about 1e-6 of the result, as much as the
    recursion it checks; refined, it agrees with a 40-digit solve to 1e-9."""
    solution = np.linalg.solve(matrix, right)
    wide = matrix.astype(np.longdouble)
    for _ in range(2):
        residual = (right.astype(np.longdouble) - wide @ solution.astype(np.longdouble)).astype(float)
        solution = solution + np.linalg.solve(matrix, residual)
    return solution


@pytest.mark.parametrize("length_scale", [0.04, 0.1, 0.6])
def test_the_smoother_on_nearly_noise_free_samples_drawn_from_its_own_model(length_scale: float) -> None:
    """Monte Carlo: 400 joints whose motions are drawn from one model of the bank (its Matern part
    stationary, the trend at rest) and measured at 1 kHz with 1e-6 rad of white noise (a 20-bit
    encoder's rounding is 1.7e-6); the fixed-lag smoother 20 ms back. Its q'' errors against the drawn
    truth have the variance it states (the posterior's, the least any estimate can have), within 20 %.
    The Rauch-Tung-Striebel form it replaced inverted the predicted covariance, too ill-conditioned here:
    its errors' variance was 12x (0.04 s), 277x (0.1 s) and 5x (0.6 s) this one, and its stated
    variance 13-900x its errors'."""
    model = MotionModel(KalmanSettings(noise=1e-6, length_scale=length_scale, magnitude=0.3))
    rng = np.random.default_rng(0)
    joints, count, lag = 400, 1500, 20
    stamps = EPOCH_NS + np.arange(count) * 1_000_000
    state = np.zeros((model.dim, joints))
    state[3:] = np.linalg.cholesky(model.prior[3:, 3:]) @ rng.normal(size=(model.dim - 3, joints))
    transition, noise = model.transition(1e-3)
    values, vectors = np.linalg.eigh(noise)  # the process noise is of rank 1 to rounding: no Cholesky
    draw = vectors * np.sqrt(np.maximum(values, 0.0))
    track = KalmanTrack([model], smooth=True)
    unmeasured = np.full(joints, np.nan)
    truth, errors, stated = [], [], []
    for k in range(count):
        if k:
            state = transition @ state + draw @ rng.normal(size=(model.dim, joints))
        truth.append((model.readout @ state)[2])
        track.add(int(stamps[k]), model.position_row @ state + rng.normal(0.0, 1e-6, joints), unmeasured)
        target = int(stamps[max(k - lag, 0)])
        if k > 500:  # the prior's start forgotten
            errors.append(track.estimate(target)[0, 2] - truth[k - lag])
            stated.append(track.acceleration_variance(target)[0])
        track.forget_before(target)
    ratio = float(np.mean(np.square(errors)) / np.mean(stated))
    assert 0.8 <= ratio <= 1.25, ratio


@pytest.mark.parametrize("step", ["numpy", "C"])
def test_stamps_between_the_filters_microseconds_cost_no_accuracy(step: str, monkeypatch) -> None:
    """The Kalman filter steps on stamps rounded to its clock's microsecond (motion.QUANTUM); a driver's
    stamps fall anywhere in between. A 20-bit encoder (1.7e-6 rad of rounding) on a joint swinging at up
    to 5 Hz (up to 11 rad/s), sampled at 1 kHz with +-5 % jitter: the fixed-lag estimates 20 ms back from
    stamps at arbitrary nanoseconds are as accurate against the true q'' as from the same motion sampled
    exactly on the microseconds. Read at the rounded time unmoved, each sample carries up to 0.5 us x
    11 rad/s of error, more than the encoder's: the error was 1.31-1.42x over five seeds (0.93-1.11x now)."""
    if step == "numpy":
        monkeypatch.setattr(native_fit.FIT, "get", lambda wait=False: None)
    elif native.compiler() is None or native_fit.FIT.get(wait=True) is None:
        pytest.skip("no C compiler (cc) here: numpy serves")
    rng = np.random.default_rng(11)
    count, lag = 2500, 20
    offsets = (np.arange(count) + rng.uniform(-0.05, 0.05, count)) * 1_000_000  # ns after the first sample
    freqs, amps, phases = np.array([0.7, 2.1, 5.0]), np.array([0.2, 0.15, 0.25]), rng.uniform(0, 2 * np.pi, 3)
    w = 2 * np.pi * freqs
    quantum = 2 * np.pi / 2**20

    def errors(stamps: np.ndarray) -> float:
        t = (stamps - stamps[0]) / 1e9
        q = np.round((amps * np.sin(t[:, None] * w + phases)).sum(axis=1) / quantum) * quantum
        qdd = (-amps * w**2 * np.sin(t[:, None] * w + phases)).sum(axis=1)
        model = MotionModel(KalmanSettings(noise=quantum / math.sqrt(12), length_scale=0.1, magnitude=0.3))
        track = KalmanTrack([model], smooth=True)
        unmeasured = np.full(1, np.nan)
        error = []
        for k in range(count):
            track.add(int(stamps[k]), q[k : k + 1], unmeasured)
            if k >= 1000:
                error.append(track.estimate(int(stamps[k - lag]))[0, 2, 0] - qdd[k - lag])
            track.forget_before(int(stamps[max(k - lag, 0)]))
        return float(np.sqrt(np.mean(np.square(error))))

    anywhere = EPOCH_NS + 123 + np.round(offsets).astype(np.int64)
    on_microseconds = EPOCH_NS + np.round(offsets / 1000).astype(np.int64) * 1000
    assert errors(anywhere) <= 1.2 * errors(on_microseconds)


@pytest.mark.parametrize("lag_samples", [0, 7])
@pytest.mark.parametrize("with_velocities", [False, True])
@pytest.mark.parametrize("unrolled", [None, 4])
@pytest.mark.parametrize("step", ["numpy", "C"])
def test_kalman_filter_and_smoother_equal_dense_gaussian_process_regression(
    lag_samples: int, with_velocities: bool, unrolled: int | None, step: str, monkeypatch
) -> None:
    """The recursive estimates (filter, fixed-lag smoother) of a bank of two models run as one batched
    filter, against each model's posterior mean computed in one dense solve over every sample (no
    recursion), from positions alone or with measured velocities; at the samples' stamps and at a
    stamp between two samples (carried forward from the step before it). The acceleration's variance
    stated with each (filtered, or smoothed over the lag) against the posterior's. With ``unrolled`` 4, the
    smoothed estimates 7 samples back are older than the steps the samples still update: each is the
    posterior given the samples up to the 4th after it. A third of the way the track is copied by
    ``select`` (its history with it). The filter's step in numpy, and in C (estimation/native_kalman.py)."""
    if unrolled is not None:
        monkeypatch.setattr(kalman, "UNROLLED", unrolled)
    if step == "numpy":
        monkeypatch.setattr(native_fit.FIT, "get", lambda wait=False: None)
    elif native.compiler() is None or native_fit.FIT.get(wait=True) is None:
        pytest.skip("no C compiler (cc) here: numpy serves")
    settings = [
        KalmanSettings(noise=1e-3, velocity_noise=1e-2, length_scale=scale, magnitude=0.4) for scale in (0.3, 0.08)
    ]
    models = [MotionModel(one) for one in settings]
    rng = np.random.default_rng(4)
    count = 60
    # on the filter's clock (motion.QUANTUM, 1 us), which the dense posterior's times then match exactly
    stamps = EPOCH_NS + np.cumsum(rng.integers(1_500_000, 2_500_000, count)) // 1000 * 1000
    t = (stamps - stamps[0]) / 1e9
    y = np.stack([np.sin(3 * t) + 0.2 * t, np.cos(2 * t)], axis=1) + rng.normal(0, 1e-3, (count, 2))
    v = np.stack([3 * np.cos(3 * t) + 0.2, -2 * np.sin(2 * t)], axis=1) + rng.normal(0, 1e-2, (count, 2))
    if not with_velocities:
        v[:] = np.nan
    track = KalmanTrack(models, smooth=lag_samples > 0)
    middle = count // 2  # an unmeasured node between samples middle and middle + 1
    between = (stamps[middle] + stamps[middle + 1]) // 2000 * 1000
    times = np.insert(t, middle + 1, (between - stamps[0]) / 1e9)
    nodes = np.arange(count) + (np.arange(count) > middle)
    rows = 2 if with_velocities else 1  # measurements per sample: position (and velocity)
    dense = [_dense_posterior(model, times, nodes, rows) for model in models]
    noise = np.zeros(count * rows)
    measured = np.zeros((count * rows, 2))
    for k in range(count):
        noise[rows * k], measured[rows * k] = settings[0].noise ** 2, y[k]
        if with_velocities:
            noise[rows * k + 1], measured[rows * k + 1] = settings[0].velocity_noise ** 2, v[k]
    checked_between = 0
    for k in range(count):
        track.add(int(stamps[k]), y[k], v[k])
        target = k - lag_samples
        if target < 0:
            continue
        wanted = [(int(stamps[target]), nodes[target], target)]
        if target <= middle <= k:
            wanted.append((int(between), middle + 1, middle))
            checked_between += 1
        for stamp, node, step in wanted:
            # the samples the estimate has seen: every one so far, or up to the UNROLLED-th after its step
            newest = k if unrolled is None else min(k, step + unrolled)
            seen = slice(0, rows * (newest + 1))
            got = track.estimate(stamp)  # (models, 3, joints)
            variances = track.acceleration_variance(stamp)  # (models,)
            for m, (model, (covariance, h)) in enumerate(zip(models, dense, strict=True)):
                dim, hs = model.dim, h[seen]
                gain = _refined_solve(hs @ covariance @ hs.T + np.diag(noise[seen]), measured[seen])
                posterior = (covariance @ hs.T @ gain)[node * dim : (node + 1) * dim]  # (dim, 2)
                expected = model.readout @ posterior
                scale = np.abs(expected).max(axis=1, keepdims=True)
                # the recursion's rounding over covariances of condition up to 1e13 (15 states): about 1e-6
                # of the acceleration at the samples, a few 1e-6 at the node between them
                tolerance = 1e-5 if node == middle + 1 else 2e-6
                assert np.all(np.abs(got[m] - expected) <= tolerance * scale), (k, m, stamp, got[m], expected)
                # the acceleration's posterior variance: the prior's less what the samples seen tell
                block = slice(node * dim, (node + 1) * dim)
                told = covariance[block] @ hs.T  # (dim, seen)
                settled = covariance[block, block] - told @ _refined_solve(
                    hs @ covariance @ hs.T + np.diag(noise[seen]), told.T
                )
                row = model.readout[2]
                # exact at the steps (the same rounding as the means'); between two, interpolated in time
                closeness = 0.15 if node == middle + 1 and lag_samples else 1e-5
                if node == middle + 1 and newest < k:
                    continue  # between a step no longer updated and one still updated: no one posterior
                assert variances[m] == pytest.approx(row @ settled @ row, rel=closeness), (k, m, stamp)
        track.forget_before(int(stamps[target]))
        if k == count // 3:
            track = track.select([0, 1])
    assert checked_between == lag_samples + 1
