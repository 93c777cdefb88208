"""Every streaming estimator setting on the reference signal: output delay against q-ddot error.

The reference signal (sum of sinusoids 0.2-1.6 Hz, amplitudes 0.05-0.8 rad) on 8 phase-shifted joints,
sampled with +-10 % stamp jitter, is fed one message at a time to StreamingEstimator. For each
variant (500 Hz noise-free, 500 Hz with 1e-4 rad Gaussian noise, 2 kHz and 100 Hz with that noise,
500 Hz quantised to 17 bits per turn, and a faster motion: 3 Hz sines of 0.5 rad with that noise)
and each method/setting, it prints:

- delay: how far behind the newest input an estimate's stamp is (the fixed lag; 0 for causal);
- qdd rel. RMS: RMS of the q-ddot error over RMS of q-ddot, after the first second;
- start / steady: per joint, the largest |q-ddot error| over the first second of output after the
  start, divided by that joint's steady-state RMS error; the worst joint. gap / steady: the same over
  the outputs from 0.5 s before a 0.3 s stretch with no samples to 1 s after it. 1 s / steady: the
  same over a second of steady output, for comparison (about 2-2.5 for errors like noise);
- outputs: how many inputs got an estimate; us/msg: the estimator's time per message.

With --plot PATH, writes the trade-off (delay against q-ddot error, one point per setting) for the
noisy 500 Hz variant as a PNG (the README's figure comes from bench_estimator_family.py).

Usage: python bench/bench_estimators.py [--seconds 8] [--plot docs/estimators.png] [--variants ...]
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from motion_family import EPOCH_NS

from neforward_ros.estimation.motion import KalmanSettings
from neforward_ros.estimation.settings import StreamSettings
from neforward_ros.estimation.stream import StreamingEstimator

AMPLITUDE = np.array([0.8, 0.3, 0.05])
FREQUENCY = np.array([0.2, 0.7, 1.6])
PHASE = np.array([0.3, 1.1, 2.0])
JOINTS = 8
GAP_START, GAP_LENGTH = 4.0, 0.3


@dataclass(frozen=True)
class Variant:
    name: str
    rate: float
    noise: float = 0.0
    quantum: float = 0.0  # quantisation step, rad
    fast: bool = False  # 3 Hz sines instead of the reference signal


VARIANTS = {
    "500Hz": Variant("500 Hz, no noise", 500.0),
    "500Hz-noisy": Variant("500 Hz, 1e-4 rad noise", 500.0, noise=1e-4),
    "2kHz-noisy": Variant("2 kHz, 1e-4 rad noise", 2000.0, noise=1e-4),
    "100Hz-noisy": Variant("100 Hz, 1e-4 rad noise", 100.0, noise=1e-4),
    "500Hz-17bit": Variant("500 Hz, 17-bit encoder", 500.0, quantum=2 * np.pi / 2**17),
    "3Hz-motion": Variant("3 Hz motion, 500 Hz, 1e-4 rad noise", 500.0, noise=1e-4, fast=True),
}

SETTINGS: dict[str, StreamSettings] = {
    "polyfit fixed_lag (default)": StreamSettings(),
    "polyfit fixed_lag lag 0.05": StreamSettings(lag=0.05),
    "polyfit fixed_lag lag 0.02, window 0.25, order 5": StreamSettings(lag=0.02, window=0.25, order=5),
    "polyfit causal": StreamSettings(mode="causal"),
    "polyfit causal, window 0.25, order 5": StreamSettings(mode="causal", window=0.25, order=5),
    "kalman causal": StreamSettings(method="kalman", mode="causal"),
    "kalman fixed_lag lag 0.01": StreamSettings(method="kalman", lag=0.01),
    "kalman fixed_lag (lag 0.02)": StreamSettings(method="kalman"),
    "kalman fixed_lag lag 0.05": StreamSettings(method="kalman", lag=0.05),
    "kalman causal, length_scale 0.2": StreamSettings(
        method="kalman", mode="causal", kalman=KalmanSettings(length_scale=0.2)
    ),
    "difference fixed_lag": StreamSettings(method="difference"),
}


def reference(t: np.ndarray, fast: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """q and q-ddot, (T, JOINTS), one phase shift per joint; ``fast``: 3 Hz sines of 0.5 rad instead."""
    if fast:
        w = 2 * np.pi * 3.0
        arg = t[:, None] * w + np.linspace(0.0, 2.0, JOINTS)
        return 0.5 * np.sin(arg), -0.5 * w * w * np.sin(arg)
    w = 2 * np.pi * FREQUENCY
    arg = t[:, None, None] * w + PHASE + np.linspace(0.0, 2.0, JOINTS)[None, :, None]
    return (AMPLITUDE * np.sin(arg)).sum(-1), (-AMPLITUDE * w**2 * np.sin(arg)).sum(-1)


def samples(variant: Variant, seconds: float, seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(sample times s, stamps ns, measured positions) with the gap cut out."""
    rng = np.random.default_rng(seed)
    count = int(seconds * variant.rate)
    t = (np.arange(count) + rng.uniform(-0.1, 0.1, count)) / variant.rate
    t = t[(t < GAP_START) | (t >= GAP_START + GAP_LENGTH)]
    q, _ = reference(t, variant.fast)
    q = q + rng.normal(0.0, variant.noise, q.shape) if variant.noise else q
    if variant.quantum:
        q = np.round(q / variant.quantum) * variant.quantum
    return t, EPOCH_NS + np.round(t * 1e9).astype(np.int64), q


@dataclass(frozen=True)
class Row:
    delay: float
    rms: float
    start: float
    gap: float
    calm: float
    outputs: int
    inputs: int
    us_per_message: float


def measure(settings: StreamSettings, variant: Variant, seconds: float) -> Row:
    _, stamps, q = samples(variant, seconds)
    names = [f"j{k}" for k in range(JOINTS)]
    estimator = StreamingEstimator(names, settings=settings, log=lambda level, message: None)
    out = []
    rows = q.tolist()
    begin = time.perf_counter()
    for k in range(len(stamps)):
        out += estimator.update(int(stamps[k]), names, rows[k])
    per_message = (time.perf_counter() - begin) / len(stamps)
    ready = [e for e in out if e.all_ready]
    out_t = (np.array([e.stamp_ns for e in ready]) - EPOCH_NS) / 1e9
    _, truth = reference(out_t, variant.fast)
    error = np.array([e.accelerations for e in ready]) - truth
    first = out_t[0]
    steady = (out_t > first + 1.0) & ((out_t < GAP_START - 0.5) | (out_t > GAP_START + GAP_LENGTH + 1.5))
    steady_rms = np.sqrt(np.mean(error[steady] ** 2, axis=0))  # per joint

    def worst(stretch: np.ndarray) -> float:
        return float(np.max(np.abs(error[stretch]).max(axis=0) / steady_rms)) if stretch.any() else float("nan")

    return Row(
        delay=settings.effective_lag,
        rms=float(np.sqrt(np.mean(error[steady] ** 2) / np.mean(truth[steady] ** 2))),
        start=worst(out_t <= first + 1.0),
        gap=worst((out_t >= GAP_START - 0.5) & (out_t <= GAP_START + GAP_LENGTH + 1.0)),
        calm=worst((out_t >= GAP_START - 1.5) & (out_t < GAP_START - 0.5)),
        outputs=len(ready),
        inputs=len(stamps),
        us_per_message=per_message * 1e6,
    )


def plot(path: str, rows: dict[str, Row], title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figure, axes = plt.subplots(figsize=(8, 5), dpi=110)
    markers = {"polyfit": "o", "kalman": "s", "difference": "^"}
    for name, row in rows.items():
        method = name.split()[0]
        axes.scatter(row.delay * 1e3, row.rms * 100, marker=markers[method], s=50, label=name, zorder=3)
    axes.set_yscale("log")
    axes.set_xlabel("output delay behind the newest input, ms")
    axes.set_ylabel("q-ddot relative RMS error, %")
    axes.set_title(title)
    axes.axhline(2.0, color="grey", lw=0.8, ls="--")
    axes.axhline(4.0, color="grey", lw=0.8, ls=":")
    axes.axvline(20.0, color="grey", lw=0.8, ls="--")
    axes.text(21, 2.1, "target: 2 % within 20 ms", fontsize=7, color="grey")
    axes.text(21, 4.2, "target: 4 % with no delay", fontsize=7, color="grey")
    axes.grid(True, which="both", alpha=0.3)
    axes.legend(fontsize=7, loc="upper center")
    figure.tight_layout()
    figure.savefig(path)
    print(f"plot written to {path}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=8.0)
    parser.add_argument("--variants", default=",".join(VARIANTS), help=f"comma-separated: {', '.join(VARIANTS)}")
    parser.add_argument("--settings", default="", help="only the settings whose name contains this")
    parser.add_argument("--plot", help="PNG path for the noisy 500 Hz trade-off plot")
    args = parser.parse_args()
    print(f"reference signal on {JOINTS} joints, {args.seconds:g} s, a {GAP_LENGTH} s gap at {GAP_START} s")
    print(f"kalman defaults: {KalmanSettings()}")
    for key in args.variants.split(","):
        variant = VARIANTS[key]
        print(f"\n{variant.name}")
        print(
            f"{'method / setting':<50} {'delay':>7} {'qdd rel. RMS':>13} {'start/steady':>13} {'gap/steady':>11}"
            f" {'1 s/steady':>11} {'outputs':>13} {'us/msg':>7}"
        )
        rows = {}
        for name, settings in SETTINGS.items():
            if args.settings not in name:
                continue
            row = measure(settings, variant, args.seconds)
            rows[name] = row
            print(
                f"{name:<50} {row.delay * 1e3:>4.0f} ms {row.rms:>13.2e} {row.start:>13.2f} {row.gap:>11.2f}"
                f" {row.calm:>11.2f} {f'{row.outputs}/{row.inputs}':>13} {row.us_per_message:>7.0f}",
                flush=True,
            )
        if args.plot and key == "500Hz-noisy":
            plot(args.plot, rows, f"Streaming estimators on the reference signal, {variant.name}")


if __name__ == "__main__":
    main()
