"""The streaming estimator's settings over a family of motions, rates and encoders, against targets.

Every documented setting, with its default parameters, is fed one message at a time
(``StreamingEstimator``) with each motion of ``motion_family.py`` (sums of sines up to 0.5, 1.5, 3
and 5 Hz; minimum-jerk and trapezoidal moves with dwells; a gait's joint profile), sampled at 100,
500 and 1000 Hz with +-5 % stamp jitter through 12-, 17- and 20-bit encoders (positions only, three
joints). Printed: q-ddot's relative RMS error (RMS of the error over RMS of q-ddot, after the first
second and before the last half second) per case and setting, each setting's median and worst over
the family against its target, and the cost per message. With --plot, the trade-off figure: each
setting's delay against its median and worst error over the family.

Targets (issue 19 of the estimators): the default setting <= 2 %; a setting of <= 20 ms delay <= 3 %;
the causal setting <= 6 %.

Usage: python bench/bench_estimator_family.py [--seconds 4] [--plot docs/estimators.png] [--quick]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from motion_family import KINDS, make

from neforward_ros.estimation.settings import StreamSettings
from neforward_ros.estimation.stream import StreamingEstimator

SETTINGS: dict[str, tuple[StreamSettings, float | None]] = {
    "polyfit fixed_lag (default, 100 ms)": (StreamSettings(), 0.02),
    "polyfit fixed_lag, fixed window (before)": (StreamSettings(adaptive=False), None),
    "kalman fixed_lag (20 ms)": (StreamSettings(method="kalman"), 0.03),
    "kalman causal": (StreamSettings(method="kalman", mode="causal"), 0.06),
    "polyfit causal": (StreamSettings(mode="causal"), None),
}
"""Setting -> (settings, target of its worst q-ddot relative RMS error over the family, or None)."""
RATES = (100, 500, 1000)
BITS = (12, 17, 20)
SEED = 100  # the tests use other seeds and other motions


def run(t: np.ndarray, q: np.ndarray, settings: StreamSettings) -> tuple[np.ndarray, np.ndarray, float]:
    names = [f"j{k}" for k in range(q.shape[1])]
    estimator = StreamingEstimator(names, settings=settings)
    stamps = (t * 1e9).astype(np.int64) + 1_700_000_000 * 10**9
    out: dict[int, np.ndarray] = {}
    started = time.perf_counter()
    for k in range(len(t)):
        for estimate in estimator.update(int(stamps[k]), names, q[k].tolist()):
            out[estimate.stamp_ns] = estimate.accelerations
    cost = (time.perf_counter() - started) / len(t)
    keys = sorted(out)
    return np.searchsorted(stamps, np.array(keys)), np.array([out[s] for s in keys]), cost


def error(index: np.ndarray, estimate: np.ndarray, t: np.ndarray, qdd: np.ndarray) -> float:
    keep = (t[index] > 1.0) & (t[index] < t[-1] - 0.5)
    truth = qdd[index][keep]
    return float(np.sqrt(np.nanmean((estimate[keep] - truth) ** 2)) / np.sqrt(np.mean(truth**2)))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=4.0)
    parser.add_argument("--plot", type=Path)
    parser.add_argument("--quick", action="store_true", help="500 Hz and 17 bits only")
    args = parser.parse_args()
    rates, bits_list = ((500,), (17,)) if args.quick else (RATES, BITS)
    errors: dict[str, list[float]] = {name: [] for name in SETTINGS}
    costs: dict[str, list[float]] = {name: [] for name in SETTINGS}
    worst: dict[str, tuple[float, str]] = {}
    short = ["default", "fixed", "kalman 20ms", "kalman causal", "polyfit causal"]
    print(f"{'motion':<10}{'rate':>6}{'bits':>5}  " + "".join(f"{s:>15}" for s in short))
    for kind in KINDS:
        for rate in rates:
            for bits in bits_list:
                t, q, _, qdd = make(kind, rate, bits, SEED, args.seconds)
                row = []
                for name, (settings, _) in SETTINGS.items():
                    index, estimate, cost = run(t, q, settings)
                    e = error(index, estimate, t, qdd)
                    errors[name].append(e)
                    costs[name].append(cost)
                    if e > worst.get(name, (-1.0, ""))[0]:
                        worst[name] = (e, f"{kind} {rate} Hz {bits} bits")
                    row.append(f"{e:>14.2%} ")
                print(f"{kind:<10}{rate:>6}{bits:>5}  " + "".join(row), flush=True)
    print()
    for name, (settings, target) in SETTINGS.items():
        values = np.array(errors[name])
        verdict = (
            ""
            if target is None
            else f"  target <= {target:.0%}: "
            + ("met" if values.max() <= target else f"NOT met ({np.mean(values > target):.0%} of the cases over)")
        )
        delay = settings.effective_lag * 1e3
        print(f"{name}: delay {delay:g} ms; median {np.median(values):.2%}, worst {values.max():.2%} "
              f"({worst[name][1]}); {np.median(costs[name]) * 1e6:.0f} us per message{verdict}")  # fmt: skip
    if args.plot is not None:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        figure, axis = plt.subplots(figsize=(8, 5))
        for name, (settings, _) in SETTINGS.items():
            delay = settings.effective_lag * 1e3
            values = np.array(errors[name])
            line = axis.plot([delay, delay], [np.median(values), values.max()], "-", lw=2)[0]
            axis.plot(delay, np.median(values), "o", color=line.get_color(), label=f"{name}: median (dot), worst (x)")
            axis.plot(delay, values.max(), "x", color=line.get_color(), ms=9)
        axis.set_yscale("log")
        axis.set_xlabel("delay of the estimate behind the newest sample [ms]")
        axis.set_ylabel("q-ddot relative RMS error over the family")
        axis.set_title(
            f"{len(errors[next(iter(errors))])} cases: {len(KINDS)} motions x {rates} Hz x {bits_list}-bit encoders"
        )
        axis.axhline(0.02, color="0.6", ls=":", lw=1)
        axis.legend(fontsize=7, loc="upper right")
        figure.tight_layout()
        figure.savefig(args.plot, dpi=100)
        print(f"wrote {args.plot}")


if __name__ == "__main__":
    main()
