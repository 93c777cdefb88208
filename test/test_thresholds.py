"""Contact thresholds from a free motion's external torques (neforward_ros.calibration.thresholds):
one outlier does not move them; the outliers are found and reported; the debounce rides over them."""

from __future__ import annotations

import numpy as np

from neforward_ros.calibration.thresholds import (
    MARGIN,
    MAX_DEBOUNCE,
    debounce_over,
    excursions,
    robust_thresholds,
)


def free_motion(seed: int, samples: int = 6000):
    rng = np.random.default_rng(seed)
    velocity = np.sin(np.linspace(0, 40, samples))[:, None] * np.array([1.0, 2.0])
    noise = np.array([1.0, 0.1])
    external = rng.normal(size=(samples, 2)) * noise * (1.0 + np.abs(velocity))  # speed-dependent spread
    stamps = np.arange(samples, dtype=np.int64) * 10_000_000  # 100 Hz
    return external, velocity, stamps


def test_a_spike_does_not_move_the_thresholds_and_is_reported() -> None:
    external, velocity, stamps = free_motion(1)
    watched = np.array([True, True])
    clean = robust_thresholds(external, velocity, watched)
    spiked = external.copy()
    spiked[3000:3002, 0] = 100.0  # two samples, 50x the usual: a model miss at a sudden stop
    assert np.allclose(robust_thresholds(spiked, velocity, watched), clean, rtol=0.03)  # a quantile step
    # against the largest value: 3 x the 99th percentile stays far below it; and above the bulk
    assert clean[0] < 0.2 * 100.0 and (np.abs(external) < clean).mean() > 0.999
    found = excursions(spiked, stamps, np.zeros(len(stamps), dtype=np.int64), clean)
    assert any(e.samples == 2 and e.joint == 0 and e.value == 100.0 and abs(e.start_s - 30.0) < 1e-9 for e in found)
    debounce = debounce_over(found, 0.01, 0.004)
    assert max(e.seconds for e in found) < debounce <= MAX_DEBOUNCE


def test_the_speed_where_the_residual_is_largest_sets_the_threshold() -> None:
    """The residual grows with speed: the threshold covers the fastest third, which a single quantile
    over all samples would not."""
    external, velocity, _ = free_motion(2)
    threshold = robust_thresholds(external, velocity, np.array([True, True]))
    fast = np.abs(velocity[:, 0]) >= np.quantile(np.abs(velocity[:, 0]), 2 / 3)
    assert threshold[0] >= MARGIN * np.quantile(np.abs(external[fast, 0]), 0.99) - 1e-12
    assert threshold[0] > MARGIN * np.quantile(np.abs(external[:, 0]), 0.99)


def test_joints_not_watched_get_no_threshold_and_stretches_split_by_recording() -> None:
    external, velocity, stamps = free_motion(3, 400)
    threshold = robust_thresholds(external, velocity, np.array([True, False]))
    assert np.isfinite(threshold[0]) and np.isnan(threshold[1])
    external[199:201, 0] = 50.0  # over the boundary between two recordings
    recording = (np.arange(400) >= 200).astype(np.int64)
    found = excursions(external, stamps, recording, threshold)
    assert [(e.recording, e.samples, e.start_s) for e in found if e.value == 50.0] == [(0, 1, 1.99), (1, 1, 0.0)]
