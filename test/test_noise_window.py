"""The adaptive fit's noise where its largest window holds few samples (adaptive.NOISE_SAMPLES): the white
noise is also read from the 64 samples up to the window's end, short of a hole (adaptive.NOISE_HOLE), and
the larger reading taken.

The oracle is the motions' exact q'' (bench/motion_family.py, on seeds the figures in the estimators guide
do not use). At 100 Hz the 0.2 s window's 20 samples read a 20-bit encoder's rounding up to 3 times too
small at times; the intervals broke on that noise and single estimates came out several times the steady
99th percentile of the errors, with no event. The compiled fit and numpy's must take the same samples
for the reading, and the node (its history) and the bag tool (the whole recording) the same numbers.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from neforward_ros.estimation import adaptive, native_fit
from neforward_ros.estimation import stream as stream_module
from neforward_ros.estimation.batch import estimate_derivatives
from neforward_ros.estimation.settings import StreamSettings
from neforward_ros.estimation.stream import StreamingEstimator

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "bench"))
import bench_transients
from motion_family import make

from conftest import EPOCH_NS

RATE = 100.0


def worst_second_over_p99(seed: int, bits: int, kind: str = "sines1.5") -> float:
    """The default whole-recording estimate of a 7-joint motion at 100 Hz: the worst joint's |q'' error|,
    its worst over each second (1-11 s) over its 99th percentile there."""
    t, q, _, qdd = make(kind, RATE, bits, seed, 12.0, joints=7)
    _, accelerations = estimate_derivatives(t, q)
    inside = (t >= 1.0) & (t < 11.0)
    errors = np.max(np.abs(accelerations - qdd), axis=1)[inside]
    p99 = float(np.percentile(errors, 99))
    seconds = np.floor(t[inside]).astype(int)
    return max(float(errors[seconds == s].max()) for s in np.unique(seconds)) / p99


CASES = [(11, 20), (12, 20), (13, 16)]


@pytest.mark.parametrize(("seed", "bits"), CASES)
def test_no_single_estimate_strays_far_beyond_the_steady_errors_at_100_hz(seed: int, bits: int) -> None:
    # 1.10-1.21 with the longer reading; 4.66-5.78 without (the mutation below)
    assert worst_second_over_p99(seed, bits) <= 2.5


def test_the_window_s_own_reading_alone_lets_estimates_stray(monkeypatch) -> None:
    """The planted bug: the noise read from the largest window alone (numpy's fits serving)."""
    monkeypatch.setattr(native_fit.FIT, "get", lambda wait=False: None)
    monkeypatch.setattr(adaptive, "NOISE_SAMPLES", 0)
    assert max(worst_second_over_p99(seed, bits) for seed, bits in CASES) > 2.5


def test_numpy_s_fits_read_the_same_noise_as_the_compiled_ones(monkeypatch) -> None:
    """The numpy fits (with no compiler) and the compiled ones give the same estimates where the
    reading reaches before the window (the rounding of the two computations apart)."""
    t, q, _, _ = make("gait", RATE, 16, 14, 6.0, joints=3)
    targets = t[(t > 1.0) & (t < 5.0)]
    compiled = adaptive.adaptive_fits(t, q, targets, 0.1, 6, 0.1)
    monkeypatch.setattr(native_fit.FIT, "get", lambda wait=False: None)
    plain = adaptive.adaptive_fits(t, q, targets, 0.1, 6, 0.1)
    scale = np.abs(plain[2]).max(axis=0)
    np.testing.assert_allclose(compiled[2], plain[2], rtol=0, atol=1e-7 * float(scale.max()))
    np.testing.assert_allclose(compiled[3], plain[3], rtol=1e-6)


@pytest.mark.parametrize("rate", [100.0, 200.0])
def test_c_and_numpy_read_the_noise_from_the_same_samples(rate: float) -> None:
    """One target at a time, with a random number of samples before its window: the same windows
    chosen and the same deviations (the windows' own readings and the longer ones)."""
    lib = native_fit.FIT.get(wait=True)
    assert lib is not None, "the C adaptive fit did not build"
    rng = np.random.default_rng(int(rate))
    for _ in range(200):
        before = int(rng.integers(0, 80))
        count = int(0.2 * rate) + 1 + before
        t = np.sort(np.arange(count) / rate + rng.uniform(-0.05, 0.05, count) / rate) + 3.0
        if before > 2 and rng.random() < 0.5:  # a hole before the window: the reading stops short of it
            t[: int(rng.integers(1, before))] -= rng.uniform(0.02, 0.3)
        n = int(rng.integers(1, 6))
        y = np.sin(2 * np.pi * t[:, None] * rng.uniform(0.1, 4.0, n) + rng.uniform(0, 6, n))
        step = 2 * np.pi / 2 ** int(rng.integers(12, 21))
        y = np.round(y / step) * step
        target, derivative = t[-1] - 0.1, np.full(n, 2)
        want = adaptive.python_adaptive_fit(t, y, target, 0.1, 6, 0.1, derivative)
        got = native_fit.fit(lib, t, y, target, *adaptive._ladder_and_leads(0.1, 0.1), 6, derivative,
                             adaptive.GAMMA, adaptive.ROUGHNESS, adaptive._GAIN, adaptive.FLOOR,
                             adaptive.GROWTH, adaptive.LATTICE)  # fmt: skip
        assert got is not None
        got = tuple(entry[0] for entry in got)
        np.testing.assert_array_equal(got[4], want[4])  # strained: the same windows
        assert np.all(np.abs(got[2] - want[2]) <= 5e-8 * (np.abs(want[2]) + want[3] + 1e-3))
        np.testing.assert_allclose(got[3], want[3], rtol=1e-6)


def node_and_bag_apart() -> float:
    """The largest difference between the node's estimates (its history) and the bag tool's (the whole
    recording) at 100 Hz with max_gap 0.05 s: the node's history spans window, lag and max_gap (0.35 s, 35
    samples), fewer than NOISE_SAMPLES. Relative to the largest q''; after 1.5 s (every record full)."""
    t, q, _, _ = make("gait", RATE, 16, 15, 6.0, joints=3)
    stamps = np.round(t * 1e9).astype(np.int64) + EPOCH_NS
    names = ["a", "b", "c"]
    estimator = StreamingEstimator(names, settings=StreamSettings(max_gap=0.05))
    out = [e for k in range(len(t)) for e in estimator.update(int(stamps[k]), names, q[k].tolist())]
    streamed = {e.stamp_ns: e.accelerations for e in out if e.ready.all()}
    _, whole = estimate_derivatives(stamps, q)
    index = {int(s): k for k, s in enumerate(stamps)}
    late = [s for s in streamed if t[index[s]] > 1.5]
    assert len(late) > 300
    got = np.array([streamed[s] for s in late])
    return float(np.abs(got - whole[[index[s] for s in late]]).max() / np.abs(whole).max())


def test_the_node_keeps_the_samples_the_reading_needs() -> None:
    assert node_and_bag_apart() <= 1e-9  # 3e-13


def test_a_history_kept_by_its_time_span_alone_reads_less_and_the_node_parts_from_the_bag(monkeypatch) -> None:
    """The planted bug: the history's samples kept by time alone (``drop_before`` keeping only
    degree + 2): 2 % of the estimates apart, by up to 0.5 % of the largest q''."""
    monkeypatch.setattr(stream_module, "NOISE_SAMPLES", 0)
    assert node_and_bag_apart() > 1e-4


HOLE_CASES = [("gait", 6), ("sines3", 5)]


def worst_after_the_gap(kind: str, seed: int) -> float:
    """kalman 20 ms on an arm at 100 Hz through 20 bits with a 0.3 s gap (shorter than max_gap: the
    history goes on across it; bench/bench_transients.py's run): the worst error in the second after the
    gap over the steady 99th percentile."""
    p99, worst, _ = bench_transients.run(StreamSettings(method="kalman"), kind, seed, RATE, 20)
    return worst[1] / p99


@pytest.mark.parametrize(("kind", "seed"), HOLE_CASES)
def test_the_reading_stops_short_of_a_gap(kind: str, seed: int) -> None:
    assert worst_after_the_gap(kind, seed) <= 2.0  # 1.13-1.23


def test_a_reading_across_the_gap_unsettles_the_estimates_after_it(monkeypatch) -> None:
    """The planted bug: the longer reading reaching across a hole (numpy's fits serving): 3.19-4.84."""
    monkeypatch.setattr(native_fit.FIT, "get", lambda wait=False: None)
    monkeypatch.setattr(adaptive, "NOISE_HOLE", float("inf"))
    assert max(worst_after_the_gap(kind, seed) for kind, seed in HOLE_CASES) > 3.0
