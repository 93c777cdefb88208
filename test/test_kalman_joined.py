"""The Kalman settings with the bank: its models join the local fits' candidates for the same delay,
each joint's estimate the candidate's whose q'' matched the centred fit best half a window later
(``estimation/causal_choice.py``), the bank's own estimate serving a joint without a record and, at a
fixed lag, checking the choice at every target.

Against hindsight (the best fixed-window polynomial for the same delay, chosen knowing the truth:
bench/hindsight.py) on motions, rates, encoders and seeds the estimator benchmark does not use, and
through a time reset in the middle of a move.
"""

from __future__ import annotations

import logging
import sys
from pathlib import Path

import pytest

from neforward_ros.estimation import stream as stream_module
from neforward_ros.estimation.motion import KalmanSettings
from neforward_ros.estimation.settings import StreamSettings
from neforward_ros.estimation.stream import StreamingEstimator

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "bench"))
import bench_transients
import numpy as np
from motion_family import make
from setting_ratio import setting_ratio

from conftest import EPOCH_NS

FIXED_LAG = StreamSettings(method="kalman")
CASES = [
    # (kind, rate, bits, seed): measured 1.01, 1.37, 1.28, 1.05, 0.45 (2026-11-26); the bank alone 1.76, 1.43,
    # 1.41, 1.12, 0.45
    ("sines0.5", 800.0, 20, 41),
    ("minjerk", 700.0, 18, 43),
    ("trapezoid", 900.0, 20, 50),
    ("sines3", 600.0, 16, 47),
    ("gait", 400.0, 14, 45),
]


@pytest.mark.parametrize("case", CASES, ids=[f"{c[0]}-{c[1]:g}Hz-{c[2]}bits" for c in CASES])
def test_the_kalman_20_ms_setting_is_within_1_5x_of_hindsight(case: tuple) -> None:
    assert setting_ratio(FIXED_LAG, *case) <= 1.5


def test_the_bank_alone_fails_the_same_check(monkeypatch) -> None:
    """The planted bug: the bank's models not among the candidates (the bank's own estimate, the setting
    before): a slow sine through a 20-bit encoder, where the likelihood's mixture lags the best fit."""
    made = StreamingEstimator.__init__

    def alone(self, *args, **kwargs) -> None:
        made(self, *args, **kwargs)
        self._joined, self._scores, self._models = False, None, 0

    monkeypatch.setattr(StreamingEstimator, "__init__", alone)
    assert setting_ratio(FIXED_LAG, *CASES[0]) > 1.5


FAST_GAITS = [
    # (kind, rate, bits, seed): a gait at 90 Hz with 5 % of the samples a driver's repeats, 4 s; measured 0.93 and
    # 0.99 (2026-12-02), with the centred reference the rule's degree 6 fused with 4 2.31 and 2.26
    ("gait", 90.0, 16, 402),
    ("gait", 90.0, 17, 402),
]


def fast_gait_ratios() -> list[float]:
    return [setting_ratio(FIXED_LAG, *case, seconds=4.0, repeats=0.05) for case in FAST_GAITS]


def test_fast_gaits_at_a_low_rate_are_scored_against_the_default_s_own_estimate() -> None:
    """The candidates (the bank's models among them) are scored against the default's centred estimate, its
    degree chosen by its own record: where the rule's degree 6 is biased alike with the short-delay fits, the
    bank's fastest model wins its record."""
    assert max(fast_gait_ratios()) <= 1.2


def test_scored_against_the_rule_s_degree_6_alone_they_fail(monkeypatch) -> None:
    """The planted bug: the reference the adaptive rule's degree 6 fused with 4 (the reference until 2026-12-02)."""
    monkeypatch.setattr(stream_module, "REFERENCE_CHOSEN", False)
    assert min(fast_gait_ratios()) > 1.8


@pytest.mark.parametrize("with_velocities", [False, True], ids=["positions", "velocities"])
def test_the_reference_is_the_default_setting_s_own_estimate(monkeypatch, with_velocities: bool) -> None:
    """The centred estimate the candidates are scored against is the default setting's estimate at that stamp,
    fitted on the messages' velocities where every sample has them (the Panda's): the default estimator run
    on the same messages is the oracle (at 100 Hz every stamp is scored, so both records hold the same
    estimates; from 1.2 s on, the finer fit's records are long enough for both)."""
    rng = np.random.default_rng(7)
    t = (np.arange(400) + rng.uniform(-0.05, 0.05, 400)) / 100.0
    phases = np.array([0.0, 1.0, 2.0])
    q = 0.6 * np.sin(2 * np.pi * 1.3 * t[:, None] + phases) + 0.2 * np.sin(2 * np.pi * 3.1 * t[:, None] - phases)
    qd = 0.6 * 2 * np.pi * 1.3 * np.cos(2 * np.pi * 1.3 * t[:, None] + phases)
    qd += 0.2 * 2 * np.pi * 3.1 * np.cos(2 * np.pi * 3.1 * t[:, None] - phases)
    q = np.round(q / 1e-4) * 1e-4
    qd = qd + rng.normal(0.0, 2e-3, qd.shape)
    names = ["a", "b", "c"]
    stamps = EPOCH_NS + np.round(t * 1e9).astype(np.int64)
    references: dict[int, np.ndarray] = {}
    made = StreamingEstimator._reference

    def kept(self, stamp, group):
        out = made(self, stamp, group)
        references.setdefault(stamp, np.full(3, np.nan))[group.joints] = out[0]
        return out

    monkeypatch.setattr(StreamingEstimator, "_reference", kept)
    joined = StreamingEstimator(names, settings=FIXED_LAG, log=lambda level, message: None)
    default = StreamingEstimator(names, log=lambda level, message: None)
    ours: dict[int, np.ndarray] = {}
    for k in range(len(t)):
        velocities = qd[k].tolist() if with_velocities else ()
        joined.update(int(stamps[k]), names, q[k].tolist(), velocities)
        for estimate in default.update(int(stamps[k]), names, q[k].tolist(), velocities):
            ours[estimate.stamp_ns] = estimate.accelerations
    compared = [s for s in references if s in ours and s >= EPOCH_NS + round(1.2e9)]
    assert len(compared) > 150
    got = np.array([references[s] for s in compared])
    expected = np.array([ours[s] for s in compared])
    np.testing.assert_allclose(got, expected, rtol=1e-9, atol=1e-9)


def transients() -> tuple[float, float]:
    """bench/bench_transients.py's first arm (7 joints, minimum-jerk moves with dwells, 500 Hz, 16 bits, a
    0.3 s gap, then the stamps 60 s back: a looped recording, in the middle of a move): the steady 99th
    percentile of |q'' error| (rad/s^2; the moves' q'' reach 20 rad/s^2), and the worst error in the
    second after each of the start, the gap and the reset over it."""
    p99, worst, lost = bench_transients.run(FIXED_LAG, "minjerk", 1)
    assert lost == 0
    return p99, max(worst) / p99


def test_moves_starts_and_a_time_reset_stay_within_the_steady_error() -> None:
    """Measured 1.34 rad/s^2, and 1.83x it after the reset (2026-11-26)."""
    p99, ratio = transients()
    assert p99 <= 2.0 and ratio <= 3.0, (p99, ratio)


def test_checked_only_where_the_candidates_are_kept_a_move_s_start_goes_through(monkeypatch) -> None:
    """The planted bug: the bank's estimate checks the chosen one only at the targets kept for scoring
    (as the causal fits' rule does): a move's start between two checks goes through, and the steady
    99th percentile is 6.4 rad/s^2."""
    monkeypatch.setattr(stream_module, "BANK_GUARDS_EVERY_TARGET", False)
    with pytest.raises(AssertionError):
        test_moves_starts_and_a_time_reset_stay_within_the_steady_error()


def said_lines(settings: StreamSettings) -> list[tuple[int, str]]:
    """What the estimator logs on trapezoidal moves at 250 Hz through a 16-bit encoder, 6 % of the
    samples repeated under a new stamp (bench/bench_estimator_unseen.py's case; the joined causal setting
    within 1.11x of hindsight there, 2026-11-26)."""
    t, q, _, _ = make("trapezoid", 250.0, 16, 7, 4.0, repeats=0.06)
    names = [f"j{k}" for k in range(q.shape[1])]
    lines: list[tuple[int, str]] = []
    estimator = StreamingEstimator(names, settings=settings, log=lambda *line: lines.append(line))
    stamps = EPOCH_NS + np.round(t * 1e9).astype(np.int64)
    for k in range(len(t)):
        estimator.update(int(stamps[k]), names, q[k].tolist())
    return lines


def test_a_motion_the_bank_lags_is_served_by_the_fits_without_a_warning() -> None:
    """Causal, the bank's fastest model (0.04 s) lags these moves (its innovations over 5x their
    expected size), and the local fits among the candidates serve instead. Nothing for the user to fix: one line
    of information per joint, no warning telling them to leave the setting (as before the models
    joined the fits)."""
    lines = said_lines(StreamSettings(method="kalman", mode="causal"))
    said = [message for level, message in lines if "lags this motion" in message]
    assert said and not [m for level, m in lines if level >= logging.WARNING and "lags" in m], lines
    assert len(said) == len(set(said)), said


def test_a_single_model_that_lags_is_still_a_warning() -> None:
    """An explicit length scale is one model and no fits among its candidates: its lag is the user's
    to fix, and the warning names the parameter."""
    lines = said_lines(StreamSettings(method="kalman", mode="causal", kalman=KalmanSettings(length_scale=1.0)))
    assert any(level == logging.WARNING and "estimator.kalman.length_scale" in m for level, m in lines), lines
