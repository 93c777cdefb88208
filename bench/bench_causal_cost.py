"""The causal polyfit's cost per message against its strictest peer, in one run.

The causal setting (windows and degrees chosen by their errors, ``estimation/causal_choice.py``) and
its peer, the same causal fit with the adaptive rule's windows of degree 4 (``order 4``: the setting
before, the same outputs without the candidates, their scores and the rule's check), fed one message
at a time with 7 joints of the estimator benchmark's motions (``motion_family.py``: a gait at 500 Hz,
3 Hz sines at 1 kHz, minimum-jerk moves at 100 Hz; 16 bits, +-5 % jitter), interleaved over
``--repeats`` runs. Prints each one's median time per message and the ratio of the medians.

Usage: python bench/bench_causal_cost.py [--repeats 3] [--seconds 4]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_estimator_family import run
from motion_family import make

from neforward_ros.estimation.settings import StreamSettings

CASES = (("gait", 500), ("sines3", 1000), ("minjerk", 100))
CHOSEN = StreamSettings(mode="causal")
PEER = StreamSettings(mode="causal", order=4)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--seconds", type=float, default=4.0)
    args = parser.parse_args()
    print("us per message, 7 joints: median over the repeats (range)")
    for kind, rate in CASES:
        t, q, _, _ = make(kind, rate, 16, 100, args.seconds)
        joints = np.concatenate([q, q, q[:, :1]], axis=1)
        costs: dict[str, list[float]] = {"chosen": [], "peer": []}
        for _ in range(args.repeats):
            costs["chosen"].append(run(t, joints, CHOSEN)[3] * 1e6)
            costs["peer"].append(run(t, joints, PEER)[3] * 1e6)
        chosen, peer = (float(np.median(costs[name])) for name in ("chosen", "peer"))
        spans = {name: f"{min(v):.0f}-{max(v):.0f}" for name, v in costs.items()}
        print(f"{kind} at {rate} Hz: chosen {chosen:.0f} ({spans['chosen']}), the rule's windows {peer:.0f} "
              f"({spans['peer']}): {chosen / peer:.2f}x", flush=True)  # fmt: skip


if __name__ == "__main__":
    main()
