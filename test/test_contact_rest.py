"""The contact detector's rest test (neforward_ros.computation.contact): on a still arm, a push is the
external torques' departure from their value at rest, far below the moving thresholds and the static
friction band. Expected states are derived by hand from the stream (a constant, a step, a ramp)."""

from __future__ import annotations

import numpy as np
import pytest

from neforward_ros.computation.contact import BASELINE_TIME, REST_DWELL, ContactDetector
from neforward_ros.logs import ThrottledLog

RATE = 100.0  # Hz
NS = 1_000_000_000


def detector(rest: float | None = 1.0) -> ContactDetector:
    return ContactDetector(
        np.array([10.0]), 0.02, ("j",), ThrottledLog(lambda *_: None), 0.6, None if rest is None else np.array([rest])
    )


def run(found: ContactDetector, external: np.ndarray, still: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    stamps = np.arange(len(external), dtype=np.int64) * round(NS / RATE)
    states = found.update_many(stamps, external[:, None], np.ones(len(external), bool), None, still)
    return stamps / NS, states


def episodes(t: np.ndarray, states: np.ndarray) -> list[tuple[float, float]]:
    on = np.r_[0, states.astype(int), 0]
    edges = np.flatnonzero(np.diff(on))
    return [(float(t[a]), float(t[min(b, len(t) - 1)])) for a, b in zip(edges[::2], edges[1::2], strict=True)]


def test_a_push_on_a_still_arm_is_its_departure_from_rest() -> None:
    """Held at 5 N m (inside the static friction, under the moving threshold 10), pushed by 3 N m for
    1 s: over the rest threshold 1 from the push's start (plus the debounce), over until it ends."""
    t = np.arange(0.0, 6.0, 1.0 / RATE)
    external = 5.0 + 3.0 * ((t >= 2.0) & (t < 3.0))
    still = np.ones(len(t), bool)
    found = episodes(*run(detector(), external, still))
    assert len(found) == 1
    start, end = found[0]
    assert 2.0 + 0.02 - 1e-9 <= start <= 2.0 + 0.02 + 1.0 / RATE
    assert 3.0 + 0.02 - 1e-9 <= end <= 3.0 + 0.02 + 1.0 / RATE
    # without rest thresholds, 8 N m stays under the moving threshold: the push is not seen
    assert not episodes(*run(detector(None), external, still))


def test_a_still_moment_shorter_than_the_dwell_is_not_rest() -> None:
    """A reversal: still for half the dwell while friction flips from -5 to +5 N m; no contact."""
    t = np.arange(0.0, 3.0, 1.0 / RATE)
    external = np.where(t < 1.05, -5.0, 5.0)
    still = np.abs(t - 1.05) < REST_DWELL / 4
    assert not episodes(*run(detector(), external, still))
    # the same flip on an arm still for longer than the dwell is a departure from rest
    assert episodes(*run(detector(), external, np.ones(len(t), bool)))


@pytest.mark.parametrize(("rate", "contact"), [(0.5, False), (2.0, True)])
def test_the_baseline_follows_a_slow_settling(rate: float, contact: bool) -> None:
    """A ramp of ``rate`` N m/s on a still arm: the baseline, a first-order follower of time constant
    BASELINE_TIME, lags it by rate x BASELINE_TIME: under the rest threshold 1 at 0.5 N m/s, over it
    at 2 N m/s."""
    assert 0.5 * BASELINE_TIME < 1.0 < 2.0 * BASELINE_TIME
    t = np.arange(0.0, 8.0, 1.0 / RATE)
    external = 5.0 + rate * np.clip(t - 1.0, 0.0, None)
    assert bool(episodes(*run(detector(), external, np.ones(len(t), bool)))) == contact


def test_motion_ends_the_rest_and_a_release_settles_anew() -> None:
    """Moving, the external torque itself is tested against the moving threshold; after a push the arm
    settles 0.5 N m higher (under the release level 0.6): one contact, not a second one later."""
    t = np.arange(0.0, 8.0, 1.0 / RATE)
    external = 5.0 + 3.0 * ((t >= 2.0) & (t < 3.0)) + 0.5 * (t >= 3.0)
    found = episodes(*run(detector(), external, np.ones(len(t), bool)))
    assert len(found) == 1 and found[0][0] < 2.1
    moving = np.ones(len(t), bool)
    moving[(t > 4.0) & (t < 5.0)] = False
    external = np.where(moving, 5.0, 9.0)  # moving at 9 N m: under the moving threshold 10
    assert not episodes(*run(detector(), external, moving))


def test_rest_departures_are_what_the_rest_test_watches() -> None:
    """The calibration's measure: NaN until the dwell has passed, then external - baseline."""
    t = np.arange(0.0, 2.0, 1.0 / RATE)
    external = np.full((len(t), 1), 4.0)
    external[150:, 0] = 4.5
    departures = detector().rest_departures(
        np.arange(len(t), dtype=np.int64) * round(NS / RATE), external, np.ones(len(t), bool)
    )
    dwell = round(REST_DWELL * RATE)
    assert np.isnan(departures[:dwell]).all() and np.allclose(departures[dwell:150], 0.0)
    assert departures[150, 0] == pytest.approx(0.5)
    assert 0.0 < departures[-1, 0] < 0.5  # the baseline follows


def test_a_stretch_without_estimates_starts_the_rest_over() -> None:
    """Still at 5 N m, then 0.5 s without external torques (a restart: the arm may move unseen), then
    still at 8 N m (stuck with another friction): a new rest with 8 as its baseline, no contact; with
    the estimates there all along, the same step is a departure of 3 over the rest threshold 1."""
    t = np.arange(0.0, 4.0, 1.0 / RATE)
    external = np.where(t < 1.5, 5.0, 8.0)
    gap = (t >= 1.5) & (t < 2.0)
    stamps = np.arange(len(t), dtype=np.int64) * round(NS / RATE)
    still = np.ones(len(t), bool)
    states = detector().update_many(stamps, np.where(gap, np.nan, external)[:, None], ~gap, None, still)
    assert not np.nansum(states)
    assert episodes(*run(detector(), external, still))
