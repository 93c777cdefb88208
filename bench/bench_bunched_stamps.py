"""Bunched stamps: a writer that stamps each message as it writes it and, on a loaded machine, stalls
and catches up in bursts (every 15-30 ms, the messages due since written tens of microseconds apart),
each position taken at its own stamp: ``neforward demo`` on a machine with every core busy, whose node
printed peaks off by up to 1500x before the fits' conditioning was checked (``fit.LEAST_PIVOT``,
``fit.ROUNDING_PIVOT``) and an encoder's step was sought where the bursts hide its rounding
(``adaptive.DIVISORS``).

Sums of sines (to 0.5, 1 and 3 Hz) through 14-18-bit encoders at 500 Hz, six seeds, each fed to every
documented setting twice: at the bunched stamps (``motion_family.bunched_times``) and at as many steady
stamps over the same time. Printed per case and setting: q-ddot's relative RMS error (after the first
0.6 s) at steady -> bunched stamps and their ratio, and the worst single error relative to the largest
|q-ddot|; then per setting the ratios' median and worst.

Then a slower writer (``--slow`` alone: only that part): 100 Hz messages, the writer stalled 30 ms at a
time (three or four messages a burst), 14 and 16 bits, four seeds: per setting the worst single error
relative to the largest |q-ddot|, and the largest error over its stated deviation plus 1 % of the
largest |q-ddot| (how far an estimate can be from the truth without saying so). There a joint moves tens
to hundreds of steps between bursts (``adaptive.EXACT``).

Usage: python bench/bench_bunched_stamps.py [--slow]
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_transients import SETTINGS  # every documented setting
from bench_write_jitter import estimates
from motion_family import bunched_times, sines

CASES = ((1.0, 16, 0.015), (3.0, 14, 0.015), (0.5, 18, 0.03))
"""(fastest sine Hz, encoder bits, the writer's period s)."""
SEEDS = range(6)
SETTLED = 0.6


def errors(stamps: np.ndarray, fmax: float, bits: int, seed: int, settings) -> tuple[float, float]:
    """q-ddot's relative RMS error and worst error relative to the largest |q-ddot|, over the joints."""
    q, qdd = sines(stamps, fmax, np.random.default_rng(100 + seed), 3)
    step = 2 * np.pi / 2**bits
    index, values, _ = estimates(stamps, np.round(q / step) * step, settings)
    keep = stamps[index] > SETTLED
    error = values[keep] - qdd[index][keep]
    rms = np.sqrt(np.mean(error**2, axis=0) / np.mean(qdd**2, axis=0))
    return float(rms.max()), float(np.max(np.abs(error) / np.abs(qdd).max(axis=0)))


SLOW = ((16, 0.03), (14, 0.03))
"""The slow writer's (encoder bits, period s), at 100 Hz."""


def slow_writer() -> None:
    print("\na 100 Hz writer stalled 30 ms at a time: worst single error / max |q-ddot|, and the largest "
          "|error| / (stated sigma + 1 % of max |q-ddot|), per seed")  # fmt: skip
    for bits, period in SLOW:
        for name, settings in SETTINGS.items():
            worst, beyond = [], []
            for seed in range(4):
                stamps_s = bunched_times(seed, rate=100.0, seconds=3.0, period=period)
                q, qdd = sines(stamps_s, 1.0, np.random.default_rng(seed), 3)
                step = 2 * np.pi / 2**bits
                at, values, stds, _ = estimates(stamps_s, np.round(q / step) * step, settings, deviations=True)
                keep = stamps_s[at] > 0.5
                largest = np.abs(qdd).max(axis=0)
                error = np.abs(values[keep] - qdd[at[keep]])
                stated = stds[keep]
                worst.append(float(np.nanmax(error / largest)))
                beyond.append(float(np.nanmax(error / (stated + 0.01 * largest))))
            print(
                f"  {bits} bits {name:<28} worst {' '.join(f'{w:6.2f}' for w in worst)}   "
                f"error / (sigma + 1 %) {' '.join(f'{b:5.1f}' for b in beyond)}",
                flush=True,
            )


def main() -> None:
    if "--slow" in sys.argv[1:]:
        slow_writer()
        return
    print("q-ddot relative RMS error at steady -> bunched stamps (ratio), worst single error / max |q-ddot|")
    print(f"{'case':<28}" + "".join(f"{name:>42}" for name in SETTINGS))
    ratios: dict[str, list[float]] = {name: [] for name in SETTINGS}
    worst: dict[str, float] = {name: 0.0 for name in SETTINGS}
    for seed in SEEDS:
        for fmax, bits, period in CASES:
            bunched = bunched_times(seed, seconds=4.0, period=period)
            steady = np.round((np.arange(len(bunched)) + 0.5) * bunched[-1] / len(bunched) * 1e9) / 1e9
            row = []
            for name, settings in SETTINGS.items():
                steady_rms, _ = errors(steady, fmax, bits, seed, settings)
                bunched_rms, bunched_worst = errors(bunched, fmax, bits, seed, settings)
                ratios[name].append(bunched_rms / steady_rms)
                worst[name] = max(worst[name], bunched_worst)
                ratio = bunched_rms / steady_rms
                row.append(f"{steady_rms:7.2%} -> {bunched_rms:7.2%} ({ratio:4.1f}x) {bunched_worst:6.1%}")
            case = f"seed {seed} sines{fmax:g} {bits} bits /{period * 1e3:.0f} ms"
            print(f"{case:<28}" + "".join(f"{cell:>42}" for cell in row), flush=True)
    print()
    for name, values in ratios.items():
        print(f"{name}: bunched over steady stamps' error median {np.median(values):.2f}x, worst {max(values):.2f}x; "
              f"worst single error {worst[name]:.1%} of the largest |q-ddot|")  # fmt: skip
    slow_writer()


if __name__ == "__main__":
    main()
