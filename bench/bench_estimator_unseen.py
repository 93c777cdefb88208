"""The estimator settings on motions the family bench does not use: a check against over-fitting it.

``bench_estimator_family.py`` is the family the settings were measured on while they were built. The
same measurement here runs on 90 other cases: seeds 7 and 31 (the family uses 100), minimum-jerk
and trapezoidal moves, gaits, 0.5 Hz and 3 Hz sines, at 100, 250 and 800 Hz (the family: 100, 500
and 1000), through 12 bits, 16 bits with 6 % of the samples repeated under a new stamp, and 14 bits
with 10 % repeated. ``--cases fresh``: 90 more, seeds 53 and 97, 1.5 Hz and 5 Hz sines, trapezoidal and
minimum-jerk moves and gaits at 150, 400 and 2000 Hz, through 13 bits, 18 bits with 3 % repeated and 15 bits
with 8 % (first run on 2026-11-29: the relative rule in the estimators guide). ``--cases repeats``: 60
more, seeds 201 and 202, minimum-jerk and trapezoidal moves, gaits, 1.5 Hz and 3 Hz sines at 120, 300 and
600 Hz, through 14 bits with 5 % repeated and 17 bits with 10 % (first run on 2026-12-01, on the repeat rule
of that day). Per case and
setting: q-ddot's relative RMS error over the fresh samples (the repeats' stamps left out, as hindsight
knows them) and its ratio to hindsight for the setting's delay; then each setting's median and worst
ratio and its share of cases within the target (1.5).

Usage: python bench/bench_estimator_unseen.py [--only default,kalman 20ms,kalman causal,polyfit causal]
       [--cases unseen|fresh|repeats]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_estimator_family import SETTINGS, SHORT, TARGET, at_samples, refuse_unknown, run
from hindsight import best, relative_rms
from motion_family import make, repeated

SEEDS = (7, 31)
KINDS = ("minjerk", "trapezoid", "gait", "sines0.5", "sines3")
RATES = (100, 250, 800)
ENCODERS = ((12, 0.0), (16, 0.06), (14, 0.1))
"""(bits, share of repeated samples)."""
CASES = {
    "unseen": (SEEDS, KINDS, RATES, ENCODERS),
    "fresh": ((53, 97), ("sines1.5", "sines5", "trapezoid", "gait", "minjerk"), (150, 400, 2000),
              ((13, 0.0), (18, 0.03), (15, 0.08))),
    "repeats": ((201, 202), ("minjerk", "trapezoid", "gait", "sines1.5", "sines3"), (120, 300, 600),
                ((14, 0.05), (17, 0.1))),
}  # fmt: skip
"""Per set: seeds, motions, rates (Hz) and encoders."""


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    documented = ["default", "kalman 20ms", "kalman causal", "polyfit causal"]
    parser.add_argument("--only", default=",".join(documented), help=f"comma-separated among: {', '.join(SHORT)}")
    parser.add_argument("--cases", choices=sorted(CASES), default="unseen", help="which set of motions")
    args = parser.parse_args()
    seeds, kinds, rates, encoders = CASES[args.cases]
    wanted = args.only.split(",")
    refuse_unknown(parser, wanted)
    chosen = [(short, settings) for short, settings in zip(SHORT, SETTINGS.values(), strict=True) if short in wanted]
    print(f"{'motion':<10}{'rate':>5}{'bits':>5}{'rep':>5}{'seed':>5}  " + "".join(f"{s:>20}" for s, _ in chosen))
    ratios: dict[str, list[float]] = {short: [] for short, _ in chosen}
    for seed in seeds:
        for kind in kinds:
            for rate in rates:
                for bits, share in encoders:
                    t, q, _, qdd = make(kind, float(rate), bits, seed, 4.0, repeats=share)
                    fresh = np.flatnonzero(~repeated(seed, len(t), share))
                    inside = fresh[(t[fresh] > 1.0) & (t[fresh] < t[-1] - 0.5)]
                    row = ""
                    references: dict[float, float] = {}  # per delay: the causal settings share one
                    for short, settings in chosen:
                        delay = round(settings.effective_lag, 6)
                        if delay not in references:
                            in_fresh = np.searchsorted(fresh, inside)
                            references[delay] = best(t[fresh], q[fresh], qdd[fresh], in_fresh, delay)[0]
                        reference = references[delay]
                        index, estimates, _, _ = run(t, q, settings)
                        values, _ = at_samples(index, estimates, inside)
                        error = relative_rms(values, qdd[inside])
                        ratios[short].append(error / reference)
                        row += f"{100 * error:>11.2f}%{error / reference:>7.2f}x "
                    print(f"{kind:<10}{rate:>5}{bits:>5}{share:>5.2f}{seed:>5}  {row}", flush=True)
    print()
    for short, values in ratios.items():
        found = np.array(values)
        print(f"{short}: ratio to hindsight median {np.median(found):.2f}, worst {found.max():.2f}; "
              f"within {TARGET}: {np.mean(found <= TARGET):.0%} of {len(found)} cases")  # fmt: skip


if __name__ == "__main__":
    main()
