"""The Kalman bank's cost per message: 7 joints at 1 kHz (a 1.5 Hz motion, 16-bit encoder, +-5 %
jitter), the bank alone (add, estimate a lag back, spread) and the whole ``StreamingEstimator.update``,
with a 20 ms lag and causal; the default polyfit's update on the same stream, in the same run, as the
peer. Target (issue 26): at most 0.3 ms a message for the bank.

Usage: python bench/bench_kalman.py [--seconds 3]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from motion_family import make

from neforward_ros.estimation.kalman_bank import KalmanBank
from neforward_ros.estimation.motion import KalmanSettings
from neforward_ros.estimation.settings import StreamSettings
from neforward_ros.estimation.stream import StreamingEstimator


def bank_cost(t: np.ndarray, q: np.ndarray, stamps: np.ndarray, lag: int) -> float:
    bank = KalmanBank(KalmanSettings(), smooth=lag > 0)
    missing = np.full(q.shape[1], np.nan)
    started = time.perf_counter()
    for k in range(len(t)):
        bank.add(int(stamps[k]), q[k], missing)
        target = int(stamps[max(k - lag, 0)])
        bank.estimate(target)
        bank.acceleration_std()
        bank.forget_before(target)
    return (time.perf_counter() - started) / len(t)


def stream_cost(q: np.ndarray, stamps: np.ndarray, settings: StreamSettings) -> float:
    names = [f"j{k}" for k in range(q.shape[1])]
    estimator = StreamingEstimator(names, settings=settings, log=lambda level, message: None)
    rows = q.tolist()
    started = time.perf_counter()
    for k in range(len(stamps)):
        estimator.update(int(stamps[k]), names, rows[k])
    return (time.perf_counter() - started) / len(stamps)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=3.0)
    args = parser.parse_args()
    t, q, _, _ = make("sines1.5", 1000, 16, 3, args.seconds, joints=7)
    stamps = (t * 1e9).astype(np.int64) + 1_700_000_000 * 10**9
    peer = stream_cost(q, stamps, StreamSettings())
    print(f"7 joints at 1 kHz, {len(t)} messages; the peer, polyfit's update (default): {peer * 1e3:.3f} ms a message")
    for label, lag, settings in (
        ("kalman fixed_lag (20 ms)", 20, StreamSettings(method="kalman")),
        ("kalman causal", 0, StreamSettings(method="kalman", mode="causal")),
    ):
        bank = bank_cost(t, q, stamps, lag)
        whole = stream_cost(q, stamps, settings)
        verdict = "met" if bank <= 0.3e-3 else "NOT met"
        print(f"{label}: the bank {bank * 1e3:.3f} ms a message (target <= 0.3: {verdict}); the whole update "
              f"{whole * 1e3:.3f} ms, {whole / peer:.2f}x polyfit's")  # fmt: skip


if __name__ == "__main__":
    main()
