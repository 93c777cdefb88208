"""Stamps written after the sample: a driver that samples on a steady clock and stamps each message when
it writes it, a varying delay later (issue 26: such a stream must not read as noise).

The motions of ``motion_family.py`` (1.5 Hz sines, a gait, minimum-jerk moves) are sampled on an exact
grid at 100, 500 and 1000 Hz through a 16-bit encoder, and fed one message at a time to every
documented setting twice: stamped with the sample times, and stamped 0-40 % of a period after them
(uniform, independent). Printed per case and setting: q-ddot's relative RMS error against the true
acceleration at the sample (after the first second and before the last half second) with the true
stamps and with the written ones, and their ratio; the summary gives the ratios also from 3 s on. Taken
as the sample times, written stamps make the motion between a sample and its stamp (velocity x delay)
read as noise, of a size that changes with the velocity: every setting finds such stamps from the
noise they read (``neforward_ros/estimation/clock.py``) and runs on the clock it recovers from them,
by 0.63 s at 100 Hz (one check over half a second may decide), 0.5-0.67 s at 200-250 Hz, 0.19-1.3 s at
500 Hz-1 kHz (three checks in a row).

With --start, the start on the written stamps instead: per case and setting, the worst error in the
second after the first estimate over the steady 99th percentile (from 1.5 s after the first estimate to
the last half second; issue 26's target: at most 3), and the first estimate's sample time. From a start
on irregular stamps every setting waits until its clock can tell whether they are write times
(``clock.HOLD_FOR_CLOCK``).

Usage: python bench/bench_write_jitter.py [--rates 100,500,1000] [--delays 0.4] [--bits 16] [--seeds 300]
       [--kinds sines1.5,gait,minjerk] [--only polyfit,kalman] [--start]  (settings by their names' start)
"""

from __future__ import annotations

import argparse
import itertools
import sys
from collections.abc import Iterator
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_transients import add_only, chosen_settings  # every documented setting, or those chosen
from motion_family import EPOCH_NS, gait, min_jerk, sines

from neforward_ros.estimation.settings import StreamSettings
from neforward_ros.estimation.stream import StreamingEstimator

DELAY = 0.4
"""The longest write delay, in sample periods."""
SEED = 300
LATER = 3.0
"""s: the summary's second error is from here on (by then the fits have found a 100 Hz writer's stamps)."""


def motion(kind: str, t: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    if kind == "sines1.5":
        return sines(t, 1.5, rng, 3)
    if kind == "minjerk":
        return min_jerk(t, rng, 3)
    return gait(t, rng, 3)


def estimates(stamps_s: np.ndarray, q: np.ndarray, settings: StreamSettings, deviations: bool = False):
    """(sample index (k,), q-ddot (k, n), the estimator) of a setting fed (stamps s, q) one message at
    a time: the estimates every joint of which is ready; with ``deviations``, their stated standard
    deviations (k, n) before the estimator."""
    names = [f"j{k}" for k in range(q.shape[1])]
    estimator = StreamingEstimator(names, settings=settings, log=lambda level, message: None)
    stamps = (stamps_s * 1e9).astype(np.int64) + EPOCH_NS
    out: dict[int, tuple[np.ndarray, np.ndarray | None]] = {}
    for k in range(len(stamps)):
        for estimate in estimator.update(int(stamps[k]), names, q[k].tolist()):
            if estimate.ready.all():
                out[estimate.stamp_ns] = (estimate.accelerations, estimate.acceleration_std)
    keys = sorted(out)
    index = np.searchsorted(stamps, np.array(keys))
    values = np.array([out[s][0] for s in keys])
    if deviations:
        return index, values, np.array([out[s][1] for s in keys]), estimator
    return index, values, estimator


def error(
    stamps_s: np.ndarray, q: np.ndarray, qdd: np.ndarray, t: np.ndarray, settings: StreamSettings, settled: float = 1.0
) -> tuple[float, StreamingEstimator]:
    """q-ddot's relative RMS error of a setting fed (stamps, q), against qdd at the samples from ``settled``
    s on to the last half second; and the estimator."""
    relative, estimator = errors(stamps_s, q, qdd, t, settings, (settled,))
    return relative[0], estimator


def errors(
    stamps_s: np.ndarray, q: np.ndarray, qdd: np.ndarray, t: np.ndarray, settings: StreamSettings, settles: tuple
) -> tuple[list[float], StreamingEstimator]:
    """:func:`error` from each of ``settles`` (s) on, from one run of the estimator."""
    index, values, estimator = estimates(stamps_s, q, settings)
    out = []
    for settled in settles:
        keep = (t[index] > settled) & (t[index] < t[-1] - 0.5)
        truth = qdd[index][keep]
        out.append(float(np.sqrt(np.mean((values[keep] - truth) ** 2) / np.mean(truth**2))))
    return out, estimator


def case(
    kind: str, rate: float, delay: float, bits: int, seed: int, seconds: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(sample times s, positions through ``bits``, true q-ddot, stamps written 0 to ``delay`` periods after
    the samples, s) of ``seconds`` of a motion sampled on an exact grid at ``rate`` Hz."""
    rng = np.random.default_rng(seed)
    t = np.arange(int(seconds * rate)) / rate
    q, qdd = motion(kind, t, rng)
    step = 2 * np.pi / 2**bits
    return t, np.round(q / step) * step, qdd, t + rng.uniform(0.0, delay / rate, len(t))


HEADER = f"{'motion':<10}{'rate':>6}{'delay':>6}{'bits':>5}{'seed':>5}  "


def cases(
    args: argparse.Namespace, seconds: float
) -> Iterator[tuple[str, np.ndarray, np.ndarray, np.ndarray, np.ndarray]]:
    """Each case the arguments ask for: its row's label (under :data:`HEADER`) and :func:`case`'s arrays."""
    for kind, rate, delay, bits, seed in itertools.product(args.kinds, args.rates, args.delays, args.bits, args.seeds):
        yield f"{kind:<10}{rate:>6g}{delay:>6g}{bits:>5}{seed:>5}  ", *case(kind, rate, delay, bits, seed, seconds)


def start_over_steady(
    stamps_s: np.ndarray, q: np.ndarray, qdd: np.ndarray, t: np.ndarray, settings: StreamSettings
) -> tuple[float, float]:
    """(the worst joint's worst |q'' error| in the second after the first estimate over its steady 99th
    percentile, from 1.5 s after the first estimate to the last half second; the first estimate's sample
    time, s) of a setting fed (stamps s, q), against qdd at the sample times ``t``."""
    index, values, _ = estimates(stamps_s, q, settings)
    worst = np.abs(values - qdd[index]).max(axis=1)
    since = t[index] - t[index[0]]
    steady = np.percentile(worst[(since > 1.5) & (t[index] < t[-1] - 0.5)], 99)
    return float(worst[since < 1.0].max() / steady), float(t[index[0]])


def numbers(text: str, kind: type = float) -> list:
    return [kind(x) for x in text.split(",")]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rates", type=numbers, default=[100.0, 500.0, 1000.0])
    parser.add_argument("--delays", type=numbers, default=[DELAY], help="longest write delays, in periods")
    parser.add_argument("--bits", type=lambda text: numbers(text, int), default=[16])
    parser.add_argument("--seeds", type=lambda text: numbers(text, int), default=[SEED])
    parser.add_argument("--kinds", type=lambda text: text.split(","), default=["sines1.5", "gait", "minjerk"])
    parser.add_argument("--start", action="store_true", help="the start on the written stamps instead")
    add_only(parser)
    args = parser.parse_args()
    chosen = chosen_settings(args.only)
    if args.start:
        starts(args, chosen)
        return
    print("stamps written 0 to the longest delay (a share of the period) after the sample; q-ddot relative "
          "RMS error, true stamps -> written stamps (ratio)")  # fmt: skip
    print(HEADER + "".join(f"{n:>36}" for n in chosen))
    ratios: dict[str, list[float]] = {name: [] for name in chosen}
    later: dict[str, list[float]] = {name: [] for name in chosen}  # from LATER s on
    for label, t, measured, qdd, written in cases(args, 8.0):
        row = []
        for name, settings in chosen.items():
            (true_error, true_later), _ = errors(t, measured, qdd, t, settings, (1.0, LATER))
            (written_error, written_later), _ = errors(written, measured, qdd, t, settings, (1.0, LATER))
            ratios[name].append(written_error / true_error)
            later[name].append(written_later / true_later)
            row.append(f"{true_error:9.2%} -> {written_error:8.2%} ({written_error / true_error:6.1f}x)")
        print(label + "".join(f"{c:>36}" for c in row), flush=True)
    print()
    for name, values in ratios.items():
        print(f"{name}: written stamps' error over the true stamps' median {np.median(values):.1f}x, "
              f"worst {max(values):.1f}x; from {LATER:g} s on {np.median(later[name]):.1f}x, "
              f"{max(later[name]):.1f}x")  # fmt: skip


def starts(args: argparse.Namespace, chosen: dict[str, StreamSettings]) -> None:
    """--start: the start on the written stamps, per case and setting (see the module docstring)."""
    print("from a start on stamps written 0 to the longest delay after the sample: the worst q-ddot error in the "
          "first second over the steady 99th percentile (the first estimate's sample time)")  # fmt: skip
    print(HEADER + "".join(f"{n:>30}" for n in chosen))
    ratios: dict[str, list[float]] = {name: [] for name in chosen}
    for label, t, measured, qdd, written in cases(args, 6.0):
        row = []
        for name, settings in chosen.items():
            ratio, first = start_over_steady(written, measured, qdd, t, settings)
            ratios[name].append(ratio)
            row.append(f"{ratio:8.2f}x ({first:.2f} s)")
        print(label + "".join(f"{c:>30}" for c in row), flush=True)
    print()
    for name, values in ratios.items():
        over = sum(v > 3.0 for v in values)
        print(f"{name}: the start's worst error over the steady 99th percentile median {np.median(values):.2f}x, "
              f"worst {max(values):.2f}x, {over} of {len(values)} over 3")  # fmt: skip


if __name__ == "__main__":
    main()
