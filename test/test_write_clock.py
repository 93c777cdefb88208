"""Stamps written after the sample (:mod:`neforward_ros.estimation.clock`): the recovered clock against
the true sample times, and the Kalman bank and the polyfit settings (whose sample histories re-time
their fits) on such a stream against the same stream stamped at the samples; a stream stamped at its
(jittered) samples keeps its stamps. The bag tool on such a recording: ``test_node_and_bag_agree.py``."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from neforward_ros.estimation.clock import WriteClock
from neforward_ros.estimation.settings import StreamSettings

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "bench"))
from bench_write_jitter import error
from motion_family import gait, min_jerk, sines

from conftest import EPOCH_NS


@pytest.mark.parametrize("delay", [0.1, 0.4, 0.7])
@pytest.mark.parametrize("period_ns", [1_000_000, 10_000_000])
def test_the_clock_recovers_the_sample_times_under_write_delays_and_drops(delay: float, period_ns: int) -> None:
    rng = np.random.default_rng(int(delay * 10) + period_ns // 1_000_000)
    count = 6000
    grid = EPOCH_NS + np.arange(count, dtype=np.int64) * period_ns
    stamps = grid + rng.integers(0, int(delay * period_ns), count)
    kept = rng.random(count) > 0.05  # dropped samples: the clock counts their periods
    grid, stamps = grid[kept], stamps[kept]
    clock = WriteClock()
    recovered = np.array([clock.update(int(s), period_ns / 1e9 if k else None) for k, s in enumerate(stamps)])
    settled = slice(300, None)
    error = (recovered - grid)[settled]
    jitter = (stamps - grid)[settled]
    assert np.std(error) <= 0.1 * np.std(jitter), (np.std(error) / period_ns, np.std(jitter) / period_ns)
    assert np.max(np.abs(error - np.mean(error))) <= 0.05 * period_ns
    assert np.all(np.diff(recovered) > 0)


def _recovered_error(delay: float, rate: float, seed: int) -> np.ndarray:
    """Periods: the recovered clock's error over the last 600 of 1000 samples (its mean left out) of a
    stream stamped 0 to ``delay`` periods after its samples, the usual interval read from the stamps."""
    from neforward_ros.estimation.clock import SampleClock

    rng = np.random.default_rng(seed)
    grid = np.arange(1000) / rate
    stamps = EPOCH_NS + np.round((grid + rng.uniform(0.0, delay / rate, len(grid))) * 1e9).astype(np.int64)
    clock = SampleClock()
    recovered = np.array([clock.add(int(s), np.zeros(1)) for s in stamps])
    error = (recovered - EPOCH_NS - grid * 1e9)[400:] * rate / 1e9
    return error - np.mean(error)


@pytest.mark.parametrize("seed", range(1, 7))
def test_delays_over_half_a_period_are_not_counted_as_drops(seed: int) -> None:
    """Delays spread over 0.7 of a period, no sample dropped: intervals from 0.3 to 1.7 periods, which
    rounded count a drop now and then before the line is drawn. A line drawn on those counts had its
    slope off, and the periods counted on it went on miscounting (200 Hz, seed 1 of
    ``bench/bench_write_jitter.py --delays 0.7``: 0.82 periods a sample, the default's error 167x that on
    the samples' stamps). The line is drawn only where it holds the stamps, the periods counted again
    where it does not."""
    assert np.max(np.abs(_recovered_error(0.7, 200.0, seed))) < 0.1


def test_the_miscounted_line_is_what_the_clock_mends(monkeypatch) -> None:
    """The mutation of the test above (any line drawn, the periods never counted again): some seed's
    recovered clock is off by periods."""
    from neforward_ros.estimation.clock import WriteClock

    monkeypatch.setattr(WriteClock, "_holds", lambda self, line: True)
    monkeypatch.setattr(WriteClock, "_recount", lambda self, usual: None)
    errors = [np.max(np.abs(_recovered_error(0.7, 200.0, seed))) for seed in range(1, 7)]
    assert max(errors) > 0.3, errors


def _error(stamps_s: np.ndarray, q: np.ndarray, qdd: np.ndarray, t: np.ndarray, settings: StreamSettings):
    """q-ddot's relative RMS error against the truth at the samples, and whether the bank took the
    stamps for write times."""
    relative, estimator = error(stamps_s, q, qdd, t, settings, settled=1.5)
    return relative, estimator._groups[0].track.written


@pytest.mark.parametrize("mode", ["fixed_lag", "causal"])
@pytest.mark.parametrize("kind, rate", [("sines", 500.0), ("gait", 1000.0)])
def test_the_kalman_bank_on_write_stamps_is_as_accurate_as_on_sample_stamps(kind: str, rate: float, mode: str):
    rng = np.random.default_rng(41)
    t = np.arange(int(6 * rate)) / rate
    q, qdd = sines(t, 2.0, rng, 3) if kind == "sines" else gait(t, rng, 3)
    step = 2 * np.pi / 2**16
    measured = np.round(q / step) * step
    written = t + rng.uniform(0.0, 0.5 / rate, len(t))
    settings = StreamSettings(method="kalman", mode=mode)
    on_samples, taken_for_written = _error(t, measured, qdd, t, settings)
    on_writes, found = _error(written, measured, qdd, t, settings)
    assert not taken_for_written and found
    assert on_writes <= 1.5 * on_samples, (on_writes, on_samples)


@pytest.mark.parametrize("mode", ["fixed_lag", "causal"])
@pytest.mark.parametrize("kind, rate", [("sines", 100.0), ("gait", 500.0), ("minjerk", 1000.0)])
def test_polyfit_on_write_stamps_is_as_accurate_as_on_sample_stamps(kind: str, rate: float, mode: str):
    """The default and polyfit causal: the history's clock finds the stamps to be write times and the
    fits run on the clock it recovers (on the stamps the write delays read as noise: 5-49x the error
    at the samples' stamps in ``bench/bench_write_jitter.py`` before). The error from 300 samples on
    (3 s at 100 Hz; from 1 s on there: the test below)."""
    rng = np.random.default_rng(47)
    t = np.arange(int(6 * rate)) / rate
    q, qdd = {
        "sines": lambda: sines(t, 1.5, rng, 3),
        "gait": lambda: gait(t, rng, 3),
        "minjerk": lambda: min_jerk(t, rng, 3),
    }[kind]()
    step = 2 * np.pi / 2**16
    measured = np.round(q / step) * step
    written = t + rng.uniform(0.0, 0.4 / rate, len(t))
    settings = StreamSettings(mode=mode)
    settled = max(1.5, 300 / rate)
    on_samples, sampled = error(t, measured, qdd, t, settings, settled=settled)
    on_writes, writes = error(written, measured, qdd, t, settings, settled=settled)
    assert not sampled._groups[0].written and writes._groups[0].written
    assert on_writes <= 1.5 * on_samples, (on_writes, on_samples)


@pytest.mark.parametrize("method", ["kalman", "polyfit"])
def test_stamps_of_jittered_samples_are_kept(method: str) -> None:
    """A driver that samples with jitter and stamps each sample with its own time: the recovered
    clock would move the samples off their times; the bank and the polyfit history keep the stamps."""
    rng = np.random.default_rng(43)
    rate = 500.0
    t = (np.arange(int(5 * rate)) + rng.uniform(-0.1, 0.1, int(5 * rate))) / rate
    q, qdd = sines(t, 1.5, rng, 3)
    step = 2 * np.pi / 2**20
    _, estimator = error(t, np.round(q / step) * step, qdd, t, StreamSettings(method=method), settled=1.5)
    group = estimator._groups[0]
    assert not (group.track.written if method == "kalman" else group.written)


def test_a_writer_whose_robot_starts_at_rest_is_found_once_it_moves() -> None:
    """Write stamps from a driver whose arm rests for 3 s (its 16-bit encoders flickering between two
    readings) before it moves: the rest tells nothing of the clock, so the stream is not kept on its
    stamps for it; once the arm moves its stamps are found to be write times, and the default's error
    after the move is within 1.5x that on the samples' stamps."""
    rate = 500.0
    rng = np.random.default_rng(53)
    t = np.arange(int(8 * rate)) / rate
    phases = rng.uniform(0, 2 * np.pi, 3)

    def motion(x: np.ndarray) -> np.ndarray:
        ramp = np.clip((x - 3.0) / 0.5, 0.0, 1.0)
        weight = ramp * ramp * (3.0 - 2.0 * ramp)  # 0 at rest, 1 from 3.5 s
        return weight[:, None] * 0.4 * np.sin(2 * np.pi * 1.2 * x[:, None] + phases)

    h = 1e-4  # the true acceleration by central differences of the exact motion
    qdd = (motion(t + h) - 2.0 * motion(t) + motion(t - h)) / (h * h)
    step = 2 * np.pi / 2**16
    measured = np.round((motion(t) + rng.normal(0.0, 0.3 * step, (len(t), 3))) / step) * step
    written = t + rng.uniform(0.0, 0.4 / rate, len(t))
    on_samples, sampled = error(t, measured, qdd, t, StreamSettings(), settled=4.0)
    on_writes, writes = error(written, measured, qdd, t, StreamSettings(), settled=4.0)
    assert not sampled._groups[0].written and writes._groups[0].written
    assert on_writes <= 1.5 * on_samples, (on_writes, on_samples)


def _writer(kind: str, rate: float, bits: int, longest: float, seed: int):
    """(sample times s, written stamps s, measured positions, true q-ddot) of 6 s of a motion sampled
    on an exact grid and stamped 0 to ``longest`` periods later."""
    rng = np.random.default_rng(seed)
    t = np.arange(int(6 * rate)) / rate
    q, qdd = sines(t, 2.0, rng, 3) if kind == "sines" else gait(t, rng, 3)
    step = 2 * np.pi / 2**bits
    return t, t + rng.uniform(0.0, longest / rate, len(t)), np.round(q / step) * step, qdd


@pytest.mark.parametrize("kind, longest, seed", [("sines", 0.25, 71), ("gait", 0.6, 72)])
def test_a_100_hz_writer_is_found_within_a_second(kind: str, longest: float, seed: int, monkeypatch) -> None:
    """At 100 Hz the check needed 128 samples and three checks in a row (about 2 s: 14-28x the error at
    the samples' stamps from 1 s on, ``bench/bench_write_jitter.py``); one check over 64 samples (0.64 s)
    that reads the recovered clock's line at a fifth of the stamps' noise now finds a writer. Without
    that (the mutation: clock.DECISIVE = 0), not within the first second."""
    from neforward_ros.estimation import clock

    _, written, measured, _ = _writer(kind, 100.0, 16, longest, seed)
    stamps = EPOCH_NS + np.round(written * 1e9).astype(np.int64)
    starts = np.zeros(len(stamps), dtype=bool)
    found = clock.written_from(stamps, measured, starts)
    assert found is not None and found < 100, found
    monkeypatch.setattr(clock, "DECISIVE", 0.0)
    assert (clock.written_from(stamps, measured, starts) or 10**6) >= 100


@pytest.mark.parametrize("method", ["polyfit", "kalman"])
@pytest.mark.parametrize("kind, bits, longest, seed", [("sines", 16, 0.3, 73), ("gait", 16, 0.4, 76)])
def test_from_the_first_second_a_100_hz_writer_reads_as_its_samples(kind, bits, longest, seed, method) -> None:
    """The default and kalman 20 ms on a 100 Hz writer through 16 bits, from 1 s on (the fits' warm-up):
    within 1.6x the error at the samples' stamps (9-31x before the clock re-timed them; the default's gait
    1.478x until 2026-11-29, 1.505x since that day's degree choice: the same error at the samples' stamps,
    1.8 % more on the written ones, some estimates better, some worse); the default's gait within 1.8x since
    2026-12-02, 1.754x: at the samples' stamps the degree choice takes the finer fit more (0.701 -> 0.592 %),
    on the written ones, re-timed to the line, about as before (1.055 -> 1.038 %). Found at about 0.64 s, the
    samples held (the history's, the bank's noise window) are placed on the recovered clock's line then, and the
    bank's models scored afresh. Through 20 bits the line drawn from a second of stamps is not yet fine
    enough (sines, delays to 0.2 of a period: 3.5x and 3.0x from 1 s on, about 1x from 4 s on)."""
    t, written, measured, qdd = _writer(kind, 100.0, bits, longest, seed)
    settings = StreamSettings(method=method)
    on_samples, _ = error(t, measured, qdd, t, settings, settled=1.0)
    on_writes, _ = error(written, measured, qdd, t, settings, settled=1.0)
    bound = 1.8 if (kind, method) == ("gait", "polyfit") else 1.6
    assert on_writes <= bound * on_samples, (on_writes, on_samples)


@pytest.mark.parametrize("jitter, bits", [(0.05, 16), (0.1, 12), (0.2, 20)])
def test_a_100_hz_stream_of_jittered_samples_keeps_its_stamps(jitter: float, bits: int) -> None:
    """Stamps that are the samples' own jittered times, at 100 Hz, where one check over 0.64 s may find
    write times: none does (the recovered clock reads several times the stamps' noise there)."""
    from neforward_ros.estimation.clock import written_from

    rng = np.random.default_rng(75 + bits)
    rate = 100.0
    t = (np.arange(int(6 * rate)) + rng.uniform(-jitter, jitter, int(6 * rate))) / rate
    q, _ = gait(t, rng, 3)
    step = 2 * np.pi / 2**bits
    stamps = EPOCH_NS + np.round(t * 1e9).astype(np.int64)
    assert written_from(stamps, np.round(q / step) * step, np.zeros(len(t), dtype=bool)) is None


def _placed_case(seed: int, delay: float, settings: StreamSettings) -> tuple[float, float]:
    """(error on the written stamps over that on the samples' stamps, from 1 s on; the same with the
    samples held not placed on the clock's line at the switch, the mutation) for 8 s of 1.5 Hz sines at
    100 Hz through 16 bits, written 0 to ``delay`` periods after the samples."""
    from neforward_ros.estimation.history import JointHistory
    from neforward_ros.estimation.kalman_bank import KalmanBank

    rng = np.random.default_rng(seed)
    t = np.arange(800) / 100.0
    q, qdd = sines(t, 1.5, rng, 3)
    step = 2 * np.pi / 2**16
    measured = np.round(q / step) * step
    written = t + rng.uniform(0.0, delay / 100.0, len(t))
    on_samples, _ = error(t, measured, qdd, t, settings, settled=1.0)
    on_writes, _ = error(written, measured, qdd, t, settings, settled=1.0)
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(JointHistory, "_place_on_clock_line", lambda self: None)
        patch.setattr(KalmanBank, "_go_on_clock", lambda self: None)
        unplaced, _ = error(written, measured, qdd, t, settings, settled=1.0)
    return on_writes / on_samples, unplaced / on_samples


@pytest.mark.parametrize(
    "method, mode, delay, seed",
    [("polyfit", "causal", 0.7, 90), ("polyfit", "causal", 0.7, 94), ("kalman", "fixed_lag", 0.4, 82),
     ("kalman", "fixed_lag", 0.4, 85)],
)  # fmt: skip
def test_the_samples_held_go_on_the_clock_line_when_write_times_are_found(method, mode, delay, seed) -> None:
    """Found at 0.63 s, the samples held were timed by the recovered clock as it ran, still leaning
    towards the line: the history places them on it (and again where the clock mends its count), the
    Kalman bank its noise window, and the bank scores its models afresh. Within 1.3x the error on the
    samples' stamps from 1 s on; without (the mutation), 1.6-3.2x for polyfit causal, 2.0-2.5x for
    kalman 20 ms on these seeds."""
    placed, unplaced = _placed_case(seed, delay, StreamSettings(method=method, mode=mode))
    assert placed <= 1.3, placed
    assert unplaced > 1.5, unplaced


def _start_over_steady(settings: StreamSettings, rate: float, kind: str, seed: int) -> tuple[float, float]:
    """``bench_write_jitter.start_over_steady`` on 4 s of a motion through 16 bits, from a start on stamps
    written 0 to 0.4 of a period after the samples."""
    from bench_write_jitter import case, start_over_steady

    t, measured, qdd, written = case(kind, rate, 0.4, 16, seed, 4.0)
    return start_over_steady(written, measured, qdd, t, settings)


START_CASES = [(StreamSettings(), "sines1.5", 101), (StreamSettings(method="kalman"), "gait", 101)]


@pytest.mark.parametrize("settings, kind, seed", START_CASES)
def test_a_start_on_write_stamps_waits_for_the_clock(settings: StreamSettings, kind: str, seed: int) -> None:
    """From a start on a 100 Hz writer's stamps, the first estimates wait until the clock is told (found
    at 0.63 s): the worst error in the first second within 3x the steady 99th percentile (1.21x the
    default, 0.93x kalman 20 ms here)."""
    ratio, first = _start_over_steady(settings, 100.0, kind, seed)
    assert ratio <= 3.0, ratio
    assert 0.5 <= first <= 0.7, first


@pytest.mark.parametrize("settings, kind, seed", START_CASES)
def test_a_start_on_write_stamps_without_the_wait_fails(settings, kind, seed, monkeypatch) -> None:
    """The planted bug: the estimates run on the stamps until the clock is told (clock.HOLD_FOR_CLOCK
    off; 208x the default's steady 99th percentile here). For kalman 20 ms, the wait kept but the bank
    going on the clock's line from the state it reached on the stamps (kalman_bank.REPLAY_ON_CLOCK off:
    41x): its next step's time went back by the stamps' mean delay."""
    from neforward_ros.estimation import clock, kalman_bank

    if settings.method == "kalman":
        monkeypatch.setattr(kalman_bank, "REPLAY_ON_CLOCK", False)
    else:
        monkeypatch.setattr(clock, "HOLD_FOR_CLOCK", False)
    ratio, _ = _start_over_steady(settings, 100.0, kind, seed)
    assert ratio > 10.0, ratio


def _clock_waits(stamps: np.ndarray, positions: np.ndarray, released: bool = False) -> np.ndarray:
    """Per sample, whether a :class:`SampleClock` fed these samples holds the estimate at its stamp back."""
    from neforward_ros.estimation.clock import SampleClock

    clock = SampleClock(released)
    waits = []
    for stamp, q in zip(stamps.tolist(), positions, strict=True):
        clock.add(int(stamp), q)
        waits.append(clock.holds_estimates(int(stamp)))
    return np.array(waits)


def test_only_irregular_stamps_wait_and_only_from_a_start() -> None:
    """Regular stamps do not wait once a few intervals tell them regular (the two clocks agree); a 500 Hz
    stream stamped at its jittered samples waits for the first look at 40 samples, which finds its stamps
    the samples' times; a 1 kHz writer waits until its stamps are found to be write times (three checks,
    192 samples); a restarted stream whose clock let estimates through before does not wait again; and
    once a clock lets them through it never holds them again."""
    from neforward_ros.estimation.clock import LOOK_SAMPLES, REGULAR_AFTER

    step = 2 * np.pi / 2**16
    rng = np.random.default_rng(5)
    t = np.arange(1500) / 500.0
    q, _ = sines(t, 1.5, rng, 3)
    regular = EPOCH_NS + np.round(t * 1e9).astype(np.int64)
    assert not _clock_waits(regular, np.round(q / step) * step)[REGULAR_AFTER + 1 :].any()
    t = (np.arange(1500) + rng.uniform(-0.1, 0.1, 1500)) / 500.0  # the samples' own times, jittered
    q, _ = sines(t, 1.5, rng, 3)
    jittered = EPOCH_NS + np.round(t * 1e9).astype(np.int64)
    waits = _clock_waits(jittered, np.round(q / step) * step)
    assert waits[REGULAR_AFTER + 1] and not waits[LOOK_SAMPLES - 1 :].any(), np.flatnonzero(waits)[-1]
    assert not _clock_waits(jittered, np.round(q / step) * step, released=True).any()
    t = np.arange(1500) / 1000.0
    written = EPOCH_NS + np.round((t + rng.uniform(0.0, 0.4e-3, len(t))) * 1e9).astype(np.int64)
    q, _ = sines(t, 1.5, rng, 3)
    waits = _clock_waits(written, np.round(q / step) * step)
    last = int(np.flatnonzero(waits)[-1])
    assert 150 <= last <= 200 and not waits[last + 1 :].any(), last


@pytest.mark.parametrize("rate, seed", [(500.0, 300), (1000.0, 300), (500.0, 302)])
def test_a_writer_at_rest_at_the_start_is_found_soon_after_it_moves(rate: float, seed: int) -> None:
    """A writer whose arm rests at the start (the first minimum-jerk move after 0.3-0.5 s): the checks at
    rest cannot tell, and the checks stay a few periods apart until one can (they went every 128 samples
    once the first 256 had come, rest or not: found 0.82, 0.44 and 0.37 s after the move started, now 0.21,
    0.17 and 0.18 s)."""
    from bench_write_jitter import case

    from neforward_ros.estimation import clock

    t, measured, _, written = case("minjerk", rate, 0.4, 16, seed, 3.0)
    moved = int(np.flatnonzero(np.any(measured != measured[0], axis=1))[0])
    stamps = EPOCH_NS + np.round(written * 1e9).astype(np.int64)
    found = clock.written_from(stamps, measured, np.zeros(len(stamps), dtype=bool))
    assert found is not None and t[found] - t[moved] <= 0.3, (t[moved], found and t[found])


CAUSAL = [StreamSettings(mode="causal"), StreamSettings(method="kalman", mode="causal")]


@pytest.mark.parametrize("settings", CAUSAL, ids=["polyfit", "kalman"])
def test_a_causal_start_on_write_stamps_after_a_rest(settings: StreamSettings) -> None:
    """From a start on a 500 Hz writer's stamps, its arm at rest until 0.46 s: until the clock can tell, the
    causal fits take the noise that the stamps' spread about the clock's line makes at the joint's speed
    (:func:`~neforward_ros.estimation.adaptive.timing_noise`): the worst error in the first second within 3x
    the steady 99th percentile (2.2x polyfit, 2.4x kalman; 203x and 221x before)."""
    ratio, _ = _start_over_steady(settings, 500.0, "minjerk", 300)
    assert ratio <= 3.0, ratio


@pytest.mark.parametrize("settings", CAUSAL, ids=["polyfit", "kalman"])
def test_a_causal_start_on_write_stamps_after_a_rest_without_the_timing_noise_fails(settings, monkeypatch) -> None:
    """The planted bug: the causal fits read the noise on the stamps alone while the clock cannot tell
    (``stream._timing`` 0): the noise read over a window where the joint starts to move after a rest is
    read mostly where it was slower, and the intervals break on it."""
    from neforward_ros.estimation import stream

    monkeypatch.setattr(stream, "_timing", lambda group, lead: 0.0)
    ratio, _ = _start_over_steady(settings, 500.0, "minjerk", 300)
    assert ratio > 10.0, ratio


@pytest.mark.parametrize("bits", [16, None], ids=["16 bits", "exact"])
def test_the_timing_uncertainty_is_the_writers_spread_until_the_clock_can_tell(bits: int | None) -> None:
    """:attr:`SampleClock.timing`: for a 500 Hz writer (delays uniform over 0.4 of a period: a standard
    deviation of 0.4 / sqrt(12) periods, 0.231 ms) the stamps' spread about the line, until its stamps are
    found to be write times, 0 after; for a stream stamped at its jittered samples, 0 from the first look,
    which reads far less noise on the stamps than on the line. Exact positions too (a simulator's): there the
    stamps read less noise than ``clock.LEAST_NOISE``, and the look compares the joints that read noise on the
    line (it compared those that read it on the stamps: none, and the timing noise stayed until the check that
    keeps the stamps for good, the causal fits 0.41 of a move's largest q'' off at its dead stop,
    ``test_repeats.py``)."""
    from neforward_ros.estimation.clock import SampleClock

    rng = np.random.default_rng(5)
    step = 2 * np.pi / 2**bits if bits else 0.0
    sampled = np.arange(600) / 500.0
    jittered = (np.arange(600) + rng.uniform(-0.1, 0.1, 600)) / 500.0
    for t, stamps in ((sampled, sampled + rng.uniform(0.0, 0.4 / 500.0, 600)), (jittered, jittered)):
        q, _ = sines(t, 1.5, rng, 3)
        clock = SampleClock()
        seen = []
        for stamp, positions in zip(stamps.tolist(), np.round(q / step) * step if step else q, strict=True):
            clock.add(EPOCH_NS + round(stamp * 1e9), positions)
            seen.append((clock.timing, clock.written))
        timing, written = np.array(seen).T
        if t is sampled:
            before = timing[50 : int(np.argmax(written))]
            assert len(before) > 100 and np.all(np.abs(before / 0.231e-3 - 1.0) < 0.15), (before.min(), before.max())
            assert written[-1] and not timing[written > 0].any()
        else:
            assert not written.any() and not timing[40:].any()


@pytest.mark.parametrize("net", [False, True], ids=["path", "net speed (planted)"])
def test_a_joint_swinging_back_and_forth_tells_the_stamps_apart(net: bool, monkeypatch) -> None:
    """5 Hz sines at 100 Hz through 12 bits, stamped at their samples (+-5 % jitter: the estimator family's):
    the joints move 5-11 rad/s, their samples' motion over the stamps' spread about the line (0.27 ms) several
    times their noise, and the first look finds the stamps to be the samples' times (timing 0 from 0.4 s on).
    The planted bug: the checks weigh the joints' net speed over their samples (``clock.path_speed`` as it was
    until 2026-11-30), which nets little over a swing; the clock never told, and the timing uncertainty stayed
    for good."""
    from motion_family import make

    from neforward_ros.estimation import clock

    if net:
        monkeypatch.setattr(clock, "path_speed", lambda t, q: np.abs(q[-1] - q[0]) / (t[-1] - t[0]))
    t, q, _, _ = make("sines5", 100.0, 12, 100, 4.0)
    sample_clock = clock.SampleClock()
    timing = []
    for stamp, positions in zip(t.tolist(), q, strict=True):
        sample_clock.add(EPOCH_NS + round(stamp * 1e9), positions)
        timing.append(sample_clock.timing)
    told = not np.any(np.array(timing)[t >= 0.5])
    assert told != net, max(timing)


@pytest.mark.parametrize("noise", [True, False], ids=["timing noise", "without (planted)"])
def test_a_kalman_20_ms_start_on_write_stamps_after_a_rest(noise: bool, monkeypatch) -> None:
    """From a start on a 500 Hz writer's stamps, its arm at rest at first (minimum-jerk moves): until the clock
    can tell, the Kalman bank's position noise is at least what the stamps' spread about the clock's line makes
    at the joints' speed (``kalman_bank.BANK_TIMING_NOISE``), the samples placed midway (``kalman_bank.MIDWAY``):
    the worst error in the first second 2.95x kalman 20 ms's steady 99th percentile. The planted bug: the noise read
    alone, mostly over the rest (10.6x; on seed 302, 5.9x until the bank placed its samples midway, 2.6x since)."""
    from neforward_ros.estimation import kalman_bank

    monkeypatch.setattr(kalman_bank, "BANK_TIMING_NOISE", noise)
    ratio, _ = _start_over_steady(StreamSettings(method="kalman"), 500.0, "minjerk", 309)
    assert (ratio <= 3.0) if noise else (ratio > 4.0), ratio


@pytest.mark.parametrize("midway", [True, False], ids=["midway", "on the stamps (planted)"])
@pytest.mark.parametrize("rate, seed", [(100.0, 308), (500.0, 303)])
def test_a_kalman_20_ms_start_on_write_stamps_places_the_samples_midway(midway, rate, seed, monkeypatch) -> None:
    """From a start on a writer's stamps, its arm at rest at first (minimum-jerk moves): until the clock can tell,
    the Kalman bank places each sample midway between its stamp and the clock's line, its timing noise half the
    spread (``kalman_bank.MIDWAY``): the worst error in the first second 2.47x and 2.67x kalman 20 ms's steady 99th
    percentile here. The planted bug: the samples on their stamps until the clock tells, as until 2026-12-01
    (4.26x and 5.66x)."""
    from neforward_ros.estimation import kalman_bank

    monkeypatch.setattr(kalman_bank, "MIDWAY", midway)
    ratio, _ = _start_over_steady(StreamSettings(method="kalman"), rate, "minjerk", seed)
    assert (ratio <= 3.0) if midway else (ratio > 3.5), ratio


@pytest.mark.parametrize("lean", [True, False], ids=["as the clock leans", "midway regardless (planted)"])
def test_stamps_of_jittered_samples_that_the_clock_cannot_tell_stay_the_banks_times(lean: bool, monkeypatch) -> None:
    """Samples stamped at their own (jittered) times through 12 bits at 100 Hz, minimum-jerk moves: the clock never
    tells (the encoder's steps hide the jitter's motion), but its checks read more noise on the line than on the
    stamps, and the bank keeps the samples on their stamps (``SampleClock.leaning``): kalman 20 ms 1.29x hindsight's
    q'' error (1.29x with the samples on their stamps until the clock tells). The planted bug: midway until the
    clock tells, whatever it reads (1.44x)."""
    from hindsight import best
    from motion_family import make

    from neforward_ros.estimation.kalman_bank import KalmanBank

    if not lean:

        def regardless(self: KalmanBank) -> str:
            return "line" if self.clock.written else "midway" if self.clock.timing > 0.0 else "stamps"

        monkeypatch.setattr(KalmanBank, "_placement", regardless)
    t, measured, _, qdd = make("minjerk", 100.0, 12, 31, 4.0)
    inside = np.flatnonzero((t > 1.0) & (t < t[-1] - 0.5))
    reference, _ = best(t, measured, qdd, inside, 0.02)
    ratio = _kalman_error(t, measured, qdd, inside) / reference
    assert (ratio <= 1.35) if lean else (ratio > 1.4), ratio


def _kalman_error(t: np.ndarray, measured: np.ndarray, qdd: np.ndarray, inside: np.ndarray) -> float:
    """kalman 20 ms's q'' relative RMS error at the samples ``inside``, fed (t s, measured) one message at a time,
    stamped at t."""
    from bench_write_jitter import estimates
    from hindsight import relative_rms

    index, values, _ = estimates(t, measured, StreamSettings(method="kalman"))
    at = np.searchsorted(index, inside)
    assert (index[at] == inside).all()
    return relative_rms(values[at], qdd[inside])


def test_the_bank_holds_every_sample_until_the_clock_tells_across_its_placings() -> None:
    """The samples a bank holds for a replay (``kalman_bank.UNCLOCKED``) are every one since the start until the
    clock tells, also after the bank placed them midway (a replay that let them go left the next replay, onto the
    line, without the samples before: kalman 20 ms's start on a 1 kHz gait 1.78x its steady 99th percentile
    instead of 1.13x). Once the clock finds write times the bank is on the line and holds none."""
    from bench_write_jitter import case

    from neforward_ros.estimation import kalman_bank
    from neforward_ros.estimation.motion import KalmanSettings

    _, measured, _, written = case("gait", 1000.0, 0.4, 16, 300, 0.4)
    stamps = EPOCH_NS + np.round(written * 1e9).astype(np.int64)
    bank = kalman_bank.KalmanBank(KalmanSettings(), smooth=True)
    placings = []
    for k, (stamp, positions) in enumerate(zip(stamps.tolist(), measured, strict=True)):
        bank.add(stamp, positions, np.full(3, np.nan))
        placings.append(bank.placing)
        if bank.placing != "line":
            assert len(bank._unclocked) == min(k + 1, kalman_bank.UNCLOCKED), k
        else:
            assert not bank._unclocked
    assert placings[0] == "stamps" and "midway" in placings and placings[-1] == "line", sorted(set(placings))


@pytest.mark.parametrize("looks", [True, False], ids=["decisive looks", "without (planted)"])
@pytest.mark.parametrize("seed", [300, 302])
def test_a_50_hz_writer_at_rest_at_the_start_is_found_by_a_look(looks: bool, seed: int, monkeypatch) -> None:
    """A 50 Hz writer whose arm rests at the start: once it moves, a look (the window still too small for a check,
    40-63 samples, here over 0.8 s) that reads under a fifth of the stamps' noise on the line finds write times
    alone, as a check over half a second does (``clock.DECISIVE_LOOKS``): found 0.32 and 0.38 s after the move
    started. The planted bug: only checks decide (0.80 and 0.86 s; a look voted for nothing until 2026-11-30)."""
    from bench_write_jitter import case

    from neforward_ros.estimation import clock

    monkeypatch.setattr(clock, "DECISIVE_LOOKS", looks)
    t, measured, _, written = case("minjerk", 50.0, 0.4, 16, seed, 3.0)
    moved = int(np.flatnonzero(np.any(measured != measured[0], axis=1))[0])
    stamps = EPOCH_NS + np.round(written * 1e9).astype(np.int64)
    found = clock.written_from(stamps, measured, np.zeros(len(stamps), dtype=bool))
    assert found is not None
    after = t[found] - t[moved]
    assert (after <= 0.5) if looks else (after > 0.7), after
    # found by a look as by a check, the clock goes onto the line at that sample (its holders place their samples)
    sample_clock = clock.SampleClock()
    for stamp, positions in zip(stamps[: found + 1].tolist(), measured, strict=False):
        recovered = sample_clock.add(stamp, positions)
    assert sample_clock.written and sample_clock.placings == 1
    assert abs(recovered - sample_clock.retimed(np.array([stamp]))[0]) < 1e3, recovered - stamp
