"""Speed of inverse_dynamics against Pinocchio called from Python, side by side in one run.

Robot: the bundled Franka-Panda-size arm (13 links, 8 joint columns, a mimic finger). Outputs: the
joint torques and, for every link, the force and moment it receives through its parent joint.

Peer, "pinocchio rnea + fill": pin.rnea, then the wrench through each link's joint (data.f) collected
into arrays, as an efficient Pinocchio user would (test/oracle.py's rnea_fill), on Pinocchio's model of
the URDF with its fixed joints made joints (else Pinocchio merges those links into their parents and
has no wrench for them). Pinocchio's inputs are converted beforehand, outside the timing.

Prints the time per sample of each and the ratios (> 1 means neforward is faster): one sample at a
time (inverse_dynamics from joint states, and from a forward_recursion result already at hand), and
a batch of 10,000 samples against Pinocchio in a Python loop. Medians of interleaved repeats.

Usage: python bench/bench_dynamics.py [--samples 10000] [--repeats 7]
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
from pathlib import Path

import numpy as np

from neforward_ros import forward_recursion, inverse_dynamics, load_model

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "test"))
sys.path.insert(0, str(ROOT / "bench"))
from bench_recursion import compare_batches, median_seconds  # noqa: E402

from oracle import GRAVITY, PinocchioOracle  # noqa: E402

URDF = ROOT / "config" / "panda.urdf"


def main() -> None:
    os.environ.setdefault("NEFORWARD_CACHE", tempfile.mkdtemp(prefix="neforward-bench-cache-"))  # cold first
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, default=10_000)
    parser.add_argument("--repeats", type=int, default=7)
    args = parser.parse_args()
    model = load_model(URDF)
    peer = PinocchioOracle(URDF, unfix=True)
    ids = peer.link_joints([None if j is None else j.name for j in model.parent_joints])
    columns = [iv for _, _, iv in peer.joint_layout(model.joint_names)]
    n = len(model.joint_names)
    rng = np.random.default_rng(0)
    q, qd, qdd = (rng.uniform(-1.0, 1.0, (args.samples, n)) for _ in range(3))
    pin_inputs = [peer.pin_vectors(model.joint_names, q[t], qd[t], qdd[t]) for t in range(args.samples)]

    ours = inverse_dynamics(model, q[:50], qd[:50], qdd[:50], gravity=GRAVITY)
    worst = 0.0
    for t in range(50):
        tau, force, moment = peer.rnea_fill(ids, *pin_inputs[t])
        for got, want in (
            (ours.joint_torque[t], tau[columns]),
            (ours.force[t, 1:], force[1:]),
            (ours.moment[t, 1:], moment[1:]),
        ):
            worst = max(worst, float(np.abs(got - want).max()) / max(1.0, float(np.abs(want).max())))
    print(f"robot {model.name}: {len(model.link_names)} links, {n} joint columns; "
          f"max relative difference to Pinocchio over 50 samples: {worst:.1e}")  # fmt: skip

    singles = 2000
    kinematics = [forward_recursion(model, q[t], qd[t], qdd[t], gravity=GRAVITY) for t in range(singles)]
    single = median_seconds(
        {
            "neforward": lambda: [
                inverse_dynamics(model, q[t], qd[t], qdd[t], gravity=GRAVITY) for t in range(singles)
            ],
            "neforward, kinematics given": lambda: [
                inverse_dynamics(model, q[t], qd[t], qdd[t], kinematics=kinematics[t]) for t in range(singles)
            ],
            "pinocchio rnea + fill": lambda: [peer.rnea_fill(ids, *pin_inputs[t]) for t in range(singles)],
            "pinocchio bare rnea": lambda: [peer.rnea_only(*pin_inputs[t]) for t in range(singles)],
        },
        args.repeats,
    )
    print(f"\none sample at a time ({singles} samples, median of {args.repeats}), per sample:")
    for name, seconds in single.items():
        print(f"  {name:<30} {seconds / singles * 1e6:8.1f} us")
    ratio = single["pinocchio rnea + fill"] / single["neforward"]
    print(f"  ratio pinocchio / neforward:                   {ratio:.2f}x  (target >= 1)")
    print(f"  ratio pinocchio / neforward, kinematics given: "
          f"{single['pinocchio rnea + fill'] / single['neforward, kinematics given']:.2f}x")  # fmt: skip
    print(
        f"  ratio pinocchio bare rnea / neforward:         "
        f"{single['pinocchio bare rnea'] / single['neforward']:.2f}x  (the floor: the call, no wrenches copied)"
    )

    compare_batches(
        lambda: inverse_dynamics(model, q, qd, qdd, gravity=GRAVITY),
        {
            "pinocchio loop (arrays)": lambda: [peer.rnea_fill(ids, *x) for x in pin_inputs],
            "pinocchio loop (bare rnea)": lambda: [peer.rnea_only(*x) for x in pin_inputs],
        },
        args.samples,
        args.repeats,
        1.5e6,
        inverse_dynamics(model, q[:2], qd[:2], qdd[:2]).force.base.nbytes // 2,
    )


if __name__ == "__main__":
    main()
