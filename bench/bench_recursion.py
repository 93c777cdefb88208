"""Speed of forward_recursion against Pinocchio called from Python, side by side in one run.

Robot: the bundled Franka-Panda-size arm (7 revolute + 2 prismatic finger joints, one of them
mimic; 13 links). Outputs for every link, as ``LinkKinematics`` holds them: omega, alpha, velocity,
classical accel (with gravity) of the origin and of the centre of mass in the link frame, and the
pose in the root frame.

Peers:
- "pinocchio fill": forwardKinematics + updateFramePlacements, then per link getFrameVelocity and
  getFrameClassicalAcceleration (LOCAL) of the link frame and of a frame at its centre of mass and
  the placement, collected into arrays with gravity added: the same outputs (forward_recursion
  delivers more: each centre of mass's velocity and position, and each link's quaternion).
  This is test/oracle.py's Pinocchio adapter, the one the tests compare against.
- "pinocchio calls only": the same Pinocchio calls with nothing copied out or added: a floor
  that does not deliver the outputs, shown for reference.

Prints the time per sample of each, and the ratios (> 1 means neforward is faster); for the batch,
the throughput against its target (1 M samples/s per core), the bytes written per sample and the
rate they are written at (the distance to the machine's memory bandwidth), and the first call on
its own (with an empty kernel cache, it compiles the kernel: the cold figure). Timings are the median
of interleaved repeats, so a busy machine slows every contender alike.

Usage: python bench/bench_recursion.py [--samples 10000] [--repeats 7]
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from neforward_ros import forward_recursion, load_model

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "test"))
from oracle import GRAVITY, PinocchioOracle  # noqa: E402  (the tests' Pinocchio adapter)

URDF = ROOT / "config" / "panda.urdf"


def median_seconds(functions: dict[str, Callable[[], object]], repeats: int) -> dict[str, float]:
    """Median wall time of each function over interleaved repeats."""
    times: dict[str, list[float]] = {name: [] for name in functions}
    for _ in range(repeats):
        for name, function in functions.items():
            start = time.perf_counter()
            function()
            times[name].append(time.perf_counter() - start)
    return {name: statistics.median(values) for name, values in times.items()}


def compare_batches(
    ours: Callable[[], object],
    peers: dict[str, Callable[[], object]],
    samples: int,
    repeats: int,
    target_rate: float,
    bytes_per_sample: int,
) -> None:
    """Time a batched call of ours against loops of the peers (medians of interleaved repeats, after
    a first call of ours, timed on its own: with an empty kernel cache it compiles the kernel) and print
    the throughput against its target, the bytes written per sample and the rate they are written at,
    and the ratio to each peer."""
    started = time.perf_counter()
    ours()
    first = time.perf_counter() - started
    batch = median_seconds({"neforward batched": ours, **peers}, max(3, repeats // 2))
    seconds = batch["neforward batched"]
    print(
        f"\n{samples} samples at once (median of {max(3, repeats // 2)}, after a first call of {first * 1e3:.0f} ms):"
    )
    for name, took in batch.items():
        print(f"  {name:<28} {took * 1e3:8.1f} ms  ({took / samples * 1e6:.3f} us per sample)")
    rate = samples / seconds
    print(f"  neforward: {rate / 1e6:.2f} M samples/s per core (target >= {target_rate / 1e6:g} M); "
          f"{bytes_per_sample} bytes written per sample, {bytes_per_sample * rate / 1e9:.2f} GB/s")  # fmt: skip
    for name in peers:
        print(f"  throughput ratio neforward / {name}: {batch[name] / seconds:.1f}x")


def main() -> None:
    os.environ.setdefault("NEFORWARD_CACHE", tempfile.mkdtemp(prefix="neforward-bench-cache-"))  # cold first
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, default=10_000, help="batch size (default 10000)")
    parser.add_argument("--repeats", type=int, default=7, help="interleaved repeats (default 7)")
    args = parser.parse_args()

    model = load_model(URDF)
    peer = PinocchioOracle(URDF)
    links = model.link_names
    rng = np.random.default_rng(0)
    n = len(model.joint_names)
    q, qd, qdd = (rng.uniform(-1.0, 1.0, (args.samples, n)) for _ in range(3))
    pin_inputs = [peer.pin_vectors(model.joint_names, q[t], qd[t], qdd[t]) for t in range(args.samples)]

    # Same numbers first: the comparison is meaningless otherwise.
    ours = forward_recursion(model, q[:50], qd[:50], qdd[:50], gravity=GRAVITY)
    worst = 0.0
    for t in range(50):
        theirs = peer.fill(links, *pin_inputs[t])
        for field, expected in theirs.items():
            scale = max(1.0, float(np.abs(expected).max()))
            worst = max(worst, float(np.abs(getattr(ours, field)[t] - expected).max()) / scale)
    print(f"robot {model.name}: {len(model.link_names)} links, {n} joint columns; "
          f"max relative difference to Pinocchio over 50 samples: {worst:.1e}")  # fmt: skip

    singles = 2000
    single = median_seconds(
        {
            "neforward": lambda: [
                forward_recursion(model, q[t], qd[t], qdd[t], gravity=GRAVITY) for t in range(singles)
            ],
            "pinocchio fill": lambda: [peer.fill(links, *pin_inputs[t]) for t in range(singles)],
            "pinocchio calls only": lambda: [peer.calls_only(links, *pin_inputs[t]) for t in range(singles)],
        },
        args.repeats,
    )
    print(f"\none sample at a time ({singles} samples, median of {args.repeats}), per sample:")
    for name, seconds in single.items():
        print(f"  {name:<22} {seconds / singles * 1e6:8.1f} us")
    ratio_single = single["pinocchio fill"] / single["neforward"]
    ratio_floor = single["pinocchio calls only"] / single["neforward"]
    print(f"  ratio pinocchio fill / neforward:       {ratio_single:.2f}x  (target >= 1)")
    print(f"  ratio pinocchio calls only / neforward: {ratio_floor:.2f}x  (the floor: the calls, no outputs)")

    compare_batches(
        lambda: forward_recursion(model, q, qd, qdd, gravity=GRAVITY),
        {
            "pinocchio loop (arrays)": lambda: [peer.fill(links, *x) for x in pin_inputs],
            "pinocchio loop (bare calls)": lambda: [peer.calls_only(links, *x) for x in pin_inputs],
        },
        args.samples,
        args.repeats,
        1e6,
        forward_recursion(model, q[:2], qd[:2], qdd[:2]).omega.base.nbytes // 2,
    )


if __name__ == "__main__":
    main()
