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
