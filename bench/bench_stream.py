"""Streaming estimator: accuracy and delay of each mode, and its cost per message next to the recursion's.

Input: the issue's reference signal (sum of sinusoids 0.2-1.6 Hz, amplitudes 0.05-0.8 rad) on each of
the bundled arm's 8 independent joints (phase-shifted), sampled at 500 Hz with +-10 % stamp jitter,
noise-free and with 1e-4 rad Gaussian position noise, fed one JointState-like message at a time.

Prints per mode: q-ddot relative RMS error against the exact derivative at the output stamps, the
effective delay (the time shift of the exact q-ddot that best matches the estimate), the delay from
input to output stamp, and the time per message as a ratio to one forward_recursion call measured
in the same run.

Usage: python bench/bench_stream.py [--seconds 10]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from motion_family import EPOCH_NS

from neforward_ros import forward_recursion, load_model
from neforward_ros.estimation import native_fit
from neforward_ros.estimation.settings import StreamSettings
from neforward_ros.estimation.stream import StreamingEstimator

URDF = Path(__file__).resolve().parent.parent / "config" / "panda.urdf"
AMPLITUDE = np.array([0.8, 0.3, 0.05])
FREQUENCY = np.array([0.2, 0.7, 1.6])
PHASE = np.array([0.3, 1.1, 2.0])


def reference(t: np.ndarray, shifts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """q and q-ddot, shape (T, n), of the reference signal with one phase shift per joint."""
    w = 2 * np.pi * FREQUENCY
    arg = t[:, None, None] * w + PHASE + shifts[None, :, None]
    return (AMPLITUDE * np.sin(arg)).sum(-1), (-AMPLITUDE * w**2 * np.sin(arg)).sum(-1)


def relative_rms(estimate: np.ndarray, truth: np.ndarray) -> float:
    return float(np.sqrt(np.mean((estimate - truth) ** 2) / np.mean(truth**2)))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=10.0)
    args = parser.parse_args()
    model = load_model(URDF)
    native_fit.FIT.get(wait=True)  # the steady state: the adaptive fit compiled (the first run builds it)
    names = list(model.joint_names)
    shifts = np.linspace(0.0, 2.0, len(names))
    count = int(args.seconds * 500)
    rng = np.random.default_rng(0)
    t = (np.arange(count) + rng.uniform(-0.1, 0.1, count)) / 500.0
    stamps = EPOCH_NS + np.round(t * 1e9).astype(np.int64)
    q, _ = reference(t, shifts)

    zeros = np.zeros(len(names))
    start = time.perf_counter()
    for k in range(2000):
        forward_recursion(model, q[k % count], zeros, zeros)
    recursion_s = (time.perf_counter() - start) / 2000

    print(f"{len(names)} joints, {count} messages at 500 Hz; one forward_recursion call: {recursion_s * 1e6:.0f} us")
    print(
        f"{'mode':>10} {'noise':>7} {'qdd rel. RMS':>13} {'eff. delay':>11} {'stamp lag':>10}"
        f" {'per msg':>9} {'/ recursion':>12}"
    )
    for mode in ("fixed_lag", "causal"):
        for noise in (0.0, 1e-4):
            positions = q + rng.normal(0.0, noise, q.shape)
            estimator = StreamingEstimator(names, settings=StreamSettings(mode=mode))
            out = []
            start = time.perf_counter()
            for k in range(count):
                out += estimator.update(int(stamps[k]), names, positions[k].tolist())
            per_message = (time.perf_counter() - start) / count
            out = [e for e in out if e.all_ready]  # none until the fit's window is covered
            out_stamps = np.array([e.stamp_ns for e in out])
            qdd = np.array([e.accelerations for e in out])
            steady = slice(100, None)
            t_out = (out_stamps - stamps[0]) / 1e9
            error = relative_rms(qdd[steady], reference(t_out, shifts)[1][steady])
            delays = np.arange(-0.03, 0.1001, 0.001)
            fits = [relative_rms(qdd[steady], reference(t_out - d, shifts)[1][steady]) for d in delays]
            delay = delays[int(np.argmin(fits))]
            lag = estimator.settings.effective_lag
            print(
                f"{mode:>10} {noise:>7.0e} {error:>13.2e} {delay * 1e3:>8.0f} ms {lag * 1e3:>7.0f} ms"
                f" {per_message * 1e6:>6.0f} us {per_message / recursion_s:>11.2f}x"
            )


if __name__ == "__main__":
    main()
