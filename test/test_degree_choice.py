"""The default fit's degree, chosen per joint by the last second's estimates (estimation/degree_choice.py).

Against hindsight (the best fixed-window polynomial for the same 0.1 s delay, chosen knowing the truth:
bench/hindsight.py) on motions, rates, encoders and seeds the estimator benchmark does not use; the
choice's pooled scores against a direct loop over each estimate's window; the node's one estimate at a
time against the whole recording's.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from neforward_ros.estimation import batch, degree_choice, native_fit
from neforward_ros.estimation.batch import estimate_at
from neforward_ros.estimation.degree_choice import DEGREES, LEAST, MEMORY, DegreePool, choose
from neforward_ros.estimation.settings import StreamSettings

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "bench"))
from motion_family import make
from setting_ratio import setting_ratio

from conftest import EPOCH_NS


def default_ratio(kind: str, rate: float, bits: int, seed: int, seconds: float = 4.0) -> float:
    """The default setting's q'' relative RMS error over hindsight's for its 0.1 s delay."""
    return setting_ratio(StreamSettings(), kind, rate, bits, seed, seconds)


CASES = [
    ("sines0.5", 250.0, 12, 21),  # degree 2's quiet fit over the widest window
    ("sines0.5", 600.0, 13, 22),
    ("sines3", 400.0, 14, 23),  # degree 6's
    ("sines1.5", 1000.0, 16, 24),
    ("gait", 200.0, 14, 25),
    ("minjerk", 300.0, 18, 26),
]


@pytest.mark.parametrize("case", CASES, ids=[f"{c[0]}-{c[1]:g}Hz-{c[2]}bits" for c in CASES])
def test_the_default_is_within_1_5x_of_hindsight(case: tuple) -> None:
    ratio = default_ratio(*case)
    assert ratio <= 1.5, ratio


def test_an_encoder_read_at_about_a_step_a_sample_keeps_its_noise() -> None:
    """A slow sine through a 13-bit encoder at 800 Hz moves about one step a sample: the readings that
    repeat are taken for a driver's repeats and left out, and no two neighbours left are equal. With
    the step read only where some were, 29x hindsight (its rounding, correlated from sample to sample,
    read as a tiny white noise); with the step read on the samples' grid (test_noise_reading.py) and
    the fused degrees 6 and 4, 4.6x; with the degree chosen, 1.8x: still over 1.5x (the rounding's
    correlation is not in the noise model)."""
    assert default_ratio("sines0.5", 800.0, 13, 22) <= 2.5


def test_one_degree_alone_fails_the_same_check(monkeypatch) -> None:
    """The planted bug: the reference degree (6) always, the choice left out: the same check fails on the
    slow motions through coarse encoders."""

    def reference(self, joints: np.ndarray, accelerations: np.ndarray, stated: np.ndarray) -> tuple:
        return np.zeros(len(joints), dtype=int), stated[0]  # the reference's estimate and its own deviation

    monkeypatch.setattr(DegreePool, "choose", reference)
    ratios = [default_ratio(*case) for case in CASES]
    assert sum(ratio > 1.5 for ratio in ratios) >= 2, ratios


def test_the_choice_is_the_least_mean_score_over_the_last_second() -> None:
    """choose() against a direct loop: per joint, each degree's mean of (a - r)^2 + 2 s_a^2 over the
    counted estimates stamped in (s - 1 s, s], the least taken unless this estimate leaves the
    reference's by more than GAMMA of their combined deviations or fewer than LEAST counted; the
    node's DegreePool, fed one estimate at a time and one group of joints at a time, the same."""
    rng = np.random.default_rng(5)
    count, joints = 400, 3
    stamps = np.cumsum(rng.integers(2_000_000, 9_000_000, count)).astype(np.int64)
    truth = rng.normal(0.0, 1.0, (count, joints))
    # per joint (columns), each degree's bias (rows): degree 2 wins on the first, 4 on the second, 6 on the last
    bias = np.array([[0.0, 0.0, 0.0], [0.1, 0.3, 1.0], [0.2, 1.0, 1.0]])[:, None, :] * rng.normal(
        1.0, 0.2, (1, count, 1)
    )
    stated = np.array([0.5, 0.25, 0.1])[:, None, None] * np.ones((1, count, joints))
    accelerations = truth[None] + bias + stated * rng.normal(0.0, 1.0, (len(DEGREES), count, joints))
    accelerations[:, 50:60, 1] = np.nan  # no estimate: left out of the pool
    got, error = choose(stamps, accelerations, stated)
    for k in range(count):
        inside = (stamps > stamps[k] - MEMORY * 1e9) & (stamps <= stamps[k])
        for j in range(joints):
            rows = inside & np.all(np.isfinite(accelerations[:, :, j]), axis=0)
            if rows.sum() < LEAST:  # too short a record: the reference
                assert got[k, j] == 0 and error[k, j] == 0.0
                continue
            scores = [
                np.mean((accelerations[d, rows, j] - accelerations[0, rows, j]) ** 2 + 2 * stated[d, rows, j] ** 2)
                for d in range(len(DEGREES))
            ]
            best_degree = int(np.argmin(scores))
            apart = abs(accelerations[best_degree, k, j] - accelerations[0, k, j])
            expected = best_degree if not apart > 4.0 * np.hypot(stated[best_degree, k, j], stated[0, k, j]) else 0
            assert got[k, j] == expected, (k, j)
            # its mean squared error as the scores tell it: mean (a - r)^2 + 2 s_a^2 - s_r^2
            own = scores[expected] - np.mean(stated[0, rows, j] ** 2)
            assert error[k, j] == pytest.approx(max(own, 0.0), rel=1e-9, abs=1e-12)
    assert np.any(got == 0) and np.any(got == 1) and np.any(got == 2), "the case must exercise every degree"
    stated_with = degree_choice.chosen_std(accelerations, stated, got, error)
    for compiled in (True, False):  # the node's pool in C and in numpy
        with pytest.MonkeyPatch.context() as patch:
            if not compiled:
                patch.setattr(native_fit.FIT, "get", lambda wait=False: None)
            pool = DegreePool(joints)
            for k in range(count):
                pool.start(int(stamps[k]))
                first, first_std = pool.choose(np.array([0, 2]), accelerations[:, k, [0, 2]], stated[:, k, [0, 2]])
                second, second_std = pool.choose(np.array([1]), accelerations[:, k, [1]], stated[:, k, [1]])
                np.testing.assert_array_equal([first[0], second[0], first[1]], got[k])
                np.testing.assert_allclose([first_std[0], second_std[0], first_std[1]], stated_with[k], rtol=1e-9)
    pool.clear()
    pool.start(int(stamps[-1]) + 1)  # forgotten: this estimate alone
    alone, _ = pool.choose(np.arange(joints), accelerations[:, 0], stated[:, 0])
    np.testing.assert_array_equal(alone, choose(stamps[:1], accelerations[:, :1], stated[:, :1])[0][0])


def test_the_compiled_choice_is_the_node_s_over_a_fast_move_then_a_still_joint() -> None:
    """The bag tool's compiled choice (sliding sums, added up afresh where rounding would show) against
    the node's DegreePool (each window summed directly), estimate by estimate: the same degrees and the
    same stated deviations to 1e-9, across scores that fall a millionfold (a fast move, then a still
    joint) and estimates that do not count."""
    compiled_against_pool()


def test_sliding_sums_never_added_up_afresh_fail_the_comparison(monkeypatch) -> None:
    """The mutation: a sliding sum left alone keeps the fast move's rounding into the still joint's
    scores (the stated deviations off by about 1 %), which the comparison above catches."""
    monkeypatch.setattr(native_fit, "CHOICE_PRECISION", 1e300)
    monkeypatch.setattr(native_fit, "CHOICE_REFRESH", 10**9)
    with pytest.raises(AssertionError):
        compiled_against_pool()


def compiled_against_pool() -> None:
    """native_fit.choose_degrees against DegreePool on a fast move then a still joint (asserts)."""
    library = native_fit.FIT.get(wait=True)
    if library is None:
        pytest.skip("no C compiler: the numpy choice serves")
    rng = np.random.default_rng(9)
    count, joints = 3000, 3
    stamps = np.cumsum(rng.integers(1_000_000, 3_000_000, count)).astype(np.int64)
    scale = np.where(np.arange(count) < count // 2, 1e3, 1e-3)[None, :, None]
    bias = np.array([0.0, 0.3, 1.0])[:, None, None] * rng.normal(1.0, 0.2, (1, count, 1)) * [0.2, 1.0, 3.0]
    stated = np.array([0.5, 0.25, 0.1])[:, None, None] * np.ones((1, count, joints)) * scale
    accelerations = (rng.normal(0.0, 1.0, (1, count, joints)) + bias) * scale + stated * rng.normal(
        0.0, 1.0, (len(DEGREES), count, joints)
    )
    accelerations[1, 700:720, 2] = np.nan  # a degree without an estimate: the estimate does not count
    counted = np.ones((count, joints), dtype=bool)
    counted[900:950, 0] = False  # not made by the node: not pooled, still chosen for
    # the fit's layout: (targets, degrees, value / first / second / deviation / strain, joints)
    fits = np.zeros((count, len(DEGREES), 5, joints))
    fits[:, :, 2], fits[:, :, 3] = accelerations.transpose(1, 0, 2), stated.transpose(1, 0, 2)
    got, got_std = native_fit.choose_degrees(
        library, stamps, round(MEMORY * 1e9), fits[:, :, 2].transpose(1, 0, 2), fits[:, :, 3].transpose(1, 0, 2),
        counted, LEAST, degree_choice.GAMMA,
    )  # fmt: skip
    pool = DegreePool(joints)
    for k in range(count):
        pool.start(int(stamps[k]))
        made = np.flatnonzero(counted[k])  # the node makes only these
        chosen, want_std = pool.choose(made, accelerations[:, k, made], stated[:, k, made])
        np.testing.assert_array_equal(got[k, made], chosen, err_msg=f"estimate {k}")
        np.testing.assert_allclose(got_std[k, made], want_std, rtol=1e-9, err_msg=f"estimate {k}")
    assert set(np.unique(got[count // 2 + 600 :])) == {0, 1, 2}, "the still half must exercise every degree"


def test_the_stated_deviation_adds_the_distance_to_the_reference_beyond_its_own_or_takes_the_scores() -> None:
    accelerations = np.array([[1.0, 1.0], [1.2, 3.0], [0.0, 0.0]])
    stated = np.array([[0.5, 0.5], [0.1, 0.1], [0.1, 0.1]])
    got = degree_choice.chosen_std(accelerations, stated, np.array([1, 1]), np.array([0.0, 0.0]))
    np.testing.assert_allclose(got, [0.1, np.sqrt(0.01 + 4.0 - 0.25)])
    got = degree_choice.chosen_std(accelerations, stated, np.array([1, 1]), np.array([0.04, 0.04]))
    np.testing.assert_allclose(got, [0.2, np.sqrt(0.01 + 4.0 - 0.25)])  # the scores' error where larger


def test_a_whole_recording_in_blocks_chooses_as_in_one(monkeypatch) -> None:
    """The bag tool's fit chooses a block of targets at a time, each with the second of estimates
    before it: the same choices and estimates as the whole recording at once (blocks of 700 targets
    at 500 Hz, 1.4 s: every block's first second pooled across the edge)."""
    native_fit.FIT.get(wait=True)  # blocks under WORTH_WAITING targets would take numpy's fits meanwhile
    t, q, _, _ = make("sines0.5", 500.0, 12, 31, seconds=8.0)
    stamps = EPOCH_NS + np.round(t * 1e9).astype(np.int64)
    whole = estimate_at(t, q, t, stamps_ns=stamps, spread=True)
    monkeypatch.setattr(batch, "CHOICE_BLOCK", 700)
    blocks = estimate_at(t, q, t, stamps_ns=stamps, spread=True)
    for got, want in zip(blocks, whole, strict=True):
        np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-12)
