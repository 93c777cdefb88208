"""The noise the estimators read from the samples: sixth divided differences on the samples' own
stamps, against closed forms (polynomials, even spacing, white noise of a known deviation)."""

from __future__ import annotations

import numpy as np
import pytest

from neforward_ros.estimation.adaptive import noise_of, sixth_differences


def test_divided_differences_vanish_on_quintics_and_are_the_sixth_difference_on_even_stamps() -> None:
    rng = np.random.default_rng(3)
    t = np.sort(rng.uniform(0.0, 1.0, 40))
    quintic = np.polyval(rng.normal(size=6), t)[:, None]
    for stride in (1, 2, 4):
        combination = sixth_differences(t, quintic, stride)
        assert combination.shape == (40 - 6 * stride, 1)
        assert np.abs(combination).max() <= 1e-9 * np.abs(quintic).max()
    even = np.arange(30) * 0.002
    y = rng.normal(size=(30, 2))
    np.testing.assert_allclose(sixth_differences(even, y), np.diff(y, 6, axis=0) / np.sqrt(924.0), atol=1e-12)


@pytest.mark.parametrize("rate", [100.0, 500.0, 1000.0])
def test_jittered_stamps_do_not_read_as_noise(rate: float) -> None:
    """A 1.5 Hz motion sampled with +-5 % stamp jitter and white noise of 1e-5 rad: the noise read is
    the white noise's (a reading on even spacing takes velocity x jitter for noise: 1e-4 and more)."""
    rng = np.random.default_rng(int(rate))
    count = int(0.2 * rate) + 1
    t = (np.arange(count) + rng.uniform(-0.05, 0.05, count)) / rate
    motion = 0.4 * np.sin(2 * np.pi * 1.5 * t) + 0.1 * np.sin(2 * np.pi * 0.7 * t + 1.0)
    y = (motion + rng.normal(0.0, 1e-5, count))[:, None]
    white, step = noise_of(t, y, coloured=False)
    assert 0.6e-5 <= white[0] <= 1.6e-5
    assert step[0] == 0.0  # every sample moves: no encoder step to read
    even_reading = np.mean(np.abs(np.diff(y, 6, axis=0))) / (np.sqrt(2 / np.pi) * np.sqrt(924.0))
    assert even_reading > 3 * white[0]  # what the reading was before, on the same samples


def test_a_slow_quantised_joint_reads_its_step() -> None:
    rate, step = 500.0, 2 * np.pi / 2**16
    t = np.arange(200) / rate
    y = (np.round(0.01 * np.sin(2 * np.pi * 0.3 * t) / step) * step)[:, None]  # less than a step a sample
    _, read = noise_of(t, y)
    assert read[0] == pytest.approx(step)
