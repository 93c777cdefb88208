"""The whole-recording adaptive fit's cost per target, in one run: one degree (4), two degrees fused
(6 and 4, the default before 2026-11-25) and the default's three degrees each with its windows chosen
(6, 4 and 3, among which estimation/degree_choice.py chooses), each one C call. The batch takes each
block of targets' sixth differences from one pass (see neforward_ros/estimation/native_fit.py).

A synthetic recording: 8 joints at 500 Hz with ±2 % stamp jitter, sines with 1e-5 rad noise rounded
to 1e-5 rad.

Usage: python bench/bench_fit.py [--targets 60000] [--repeats 3]
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np

from neforward_ros.estimation import adaptive, native_fit


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--targets", type=int, default=60_000)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    if native_fit.FIT.get(wait=True) is None:
        raise SystemExit("no C compiler: the compiled fit is not built, nothing to time")
    rng = np.random.default_rng(1)
    count, n = args.targets, 8
    t = (np.arange(count) + rng.uniform(-0.02, 0.02, count)) / 500.0
    y = np.sin(t[:, None] * rng.uniform(0.5, 5.0, n)) + np.round(rng.normal(0.0, 1e-5, (count, n)) / 1e-5) * 1e-5
    runs = {
        "degree 4": lambda: adaptive.adaptive_fits(t, y, t, 0.1, 4, 0.1),
        "degrees 6 and 4 fused": lambda: adaptive.adaptive_fits(t, y, t, 0.1, 6, 0.1, lower=4),
        "degrees 6, 4, 3 (default)": lambda: adaptive.degree_fits(t, y, t, 0.1, (6, 4, 3), 0.1),
    }
    times: dict[str, list[float]] = {name: [] for name in runs}
    for _ in range(args.repeats):
        for name, run in runs.items():
            start = time.perf_counter()
            run()
            times[name].append((time.perf_counter() - start) / count)
    median = {name: statistics.median(values) * 1e6 for name, values in times.items()}
    print(f"{count} targets, {n} joints, 500 Hz; median of {args.repeats} runs, µs a target (all cores)")
    for name, value in median.items():
        print(f"  {name:<30} {value:7.2f}")
    print(f"fused over degree 4: {median['degrees 6 and 4 fused'] / median['degree 4']:.2f}x")
    three = median["degrees 6, 4, 3 (default)"] / median["degrees 6 and 4 fused"]
    print(f"the default's three over the two fused: {three:.2f}x")


if __name__ == "__main__":
    main()
