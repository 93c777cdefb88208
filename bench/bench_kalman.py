"""The Kalman bank's cost per message: 7 joints at 1 kHz (a 1.5 Hz motion, 16-bit encoder, +-5 %
jitter), the bank alone (add, estimate a lag back, spread) and the whole ``StreamingEstimator.update``,
with a 20 ms lag and causal; the default polyfit's update on the same stream as the peer.

The three advance side by side, message by message, each message's calls in a rotating order and
timed one by one: a shared machine's speed drifts within seconds (the same code read 0.30 and 0.45 ms
a message in back-to-back runs), and so each ratio to the peer is of the same moments. Each setting
is run --repeats times; printed: the median and the range of the costs, and of the ratios. Target
(issue 26): at most 0.3 ms a message for the bank.

Usage: python bench/bench_kalman.py [--seconds 3] [--repeats 5]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from motion_family import EPOCH_NS, make

from neforward_ros.estimation.kalman_bank import KalmanBank
from neforward_ros.estimation.motion import KalmanSettings
from neforward_ros.estimation.settings import StreamSettings
from neforward_ros.estimation.stream import StreamingEstimator


def side_by_side(q: np.ndarray, stamps: np.ndarray, lag: int) -> dict[str, float]:
    """ms a message of the bank alone (KalmanBank: add, estimate ``lag`` samples back, forget before it),
    of the whole kalman update and of the peer's (polyfit, the default) on the same messages, fed in
    turn, the order rotating from message to message."""
    names = [f"j{k}" for k in range(q.shape[1])]
    mode = "fixed_lag" if lag else "causal"
    bank = KalmanBank(KalmanSettings(), smooth=lag > 0)
    whole = StreamingEstimator(names, settings=StreamSettings(method="kalman", mode=mode), log=lambda *_: None)
    peer = StreamingEstimator(names, settings=StreamSettings(), log=lambda *_: None)
    missing = np.full(q.shape[1], np.nan)
    rows = q.tolist()

    def run_bank(k: int) -> None:
        bank.add(int(stamps[k]), q[k], missing)
        target = int(stamps[max(k - lag, 0)])
        bank.estimate(target)  # and its spread
        bank.forget_before(target)

    calls = {
        "bank": run_bank,
        "whole": lambda k: whole.update(int(stamps[k]), names, rows[k]),
        "peer": lambda k: peer.update(int(stamps[k]), names, rows[k]),
    }
    order = list(calls)
    spent = dict.fromkeys(calls, 0.0)
    clock = time.perf_counter
    for k in range(len(stamps)):
        turn = k % len(order)
        for name in order[turn:] + order[:turn]:
            started = clock()
            calls[name](k)
            spent[name] += clock() - started
    return {name: seconds / len(stamps) * 1e3 for name, seconds in spent.items()}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=3.0)
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    t, q, _, _ = make("sines1.5", 1000, 16, 3, args.seconds, joints=7)
    stamps = (t * 1e9).astype(np.int64) + EPOCH_NS
    print(f"7 joints at 1 kHz, {len(t)} messages, {args.repeats} repeats, the bank, the whole update and the "
          "peer (polyfit's update, the default) side by side")  # fmt: skip

    def said(values: list[float], unit: str) -> str:
        return f"{np.median(values):.3f}{unit} (repeats {min(values):.3f}-{max(values):.3f})"

    for label, lag in (("kalman fixed_lag (20 ms)", 20), ("kalman causal", 0)):
        runs = [side_by_side(q, stamps, lag) for _ in range(args.repeats)]
        bank = [run["bank"] for run in runs]
        verdict = (
            "met in every repeat" if max(bank) <= 0.3 else ("met (median)" if np.median(bank) <= 0.3 else "NOT met")
        )
        print(f"{label}: the bank {said(bank, ' ms a message')} (target <= 0.3: {verdict}), "
              f"{said([run['bank'] / run['peer'] for run in runs], 'x')} the peer's; the whole update "
              f"{said([run['whole'] for run in runs], ' ms')}, "
              f"{said([run['whole'] / run['peer'] for run in runs], 'x')} the peer's; the peer "
              f"{said([run['peer'] for run in runs], ' ms')}")  # fmt: skip


if __name__ == "__main__":
    main()
