"""Speed of forward_recursion against Pinocchio called from Python, side by side in one run.

Robot: the bundled Franka-Panda-size arm (7 revolute + 2 prismatic finger joints, one of them
mimic; 13 links). Outputs for every link, as ``LinkKinematics`` holds them: omega, alpha, velocity,
classical accel (with gravity) of the origin and of the centre of mass in the link frame, and the
pose in the root frame.

Peers:
- "pinocchio fill": forwardKinematics + updateFramePlacements, then per link getFrameVelocity and
  getFrameClassicalAcceleration (LOCAL) of the link frame and of a frame at its centre of mass and
  the placement, collected into arrays with gravity added: the same outputs.
- "pinocchio calls only": the same Pinocchio calls with nothing copied out or added: a floor
  that does not deliver the outputs, shown for reference.

Prints the time per sample of each, and the ratios (> 1 means neforward is faster). Timings are
the median of interleaved repeats, so a busy machine slows every contender alike.

Usage: python bench/bench_recursion.py [--samples 10000] [--repeats 7]
"""

from __future__ import annotations

import argparse
import statistics
import time
import xml.etree.ElementTree as ElementTree
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pinocchio as pin

from neforward_ros import forward_recursion, load_model

URDF = Path(__file__).resolve().parent.parent / "config" / "panda.urdf"
GRAVITY = np.array([0.0, 0.0, -9.81])


class PinocchioPeer:
    def __init__(self, path: Path, joint_names: tuple[str, ...], link_names: tuple[str, ...]) -> None:
        self.model = pin.buildModelFromXML(path.read_text(), mimic=True)
        coms = {}
        for link in ElementTree.parse(path).getroot().iter("link"):
            origin = link.find("inertial/origin")
            xyz = origin.get("xyz", "0 0 0") if origin is not None else "0 0 0"
            coms[link.get("name")] = np.array([float(v) for v in xyz.split()])
        self.frames = []
        for link in link_names:
            body = self.model.getFrameId(link, pin.FrameType.BODY)
            frame = self.model.frames[body]
            placement = frame.placement * pin.SE3(np.eye(3), coms[link])
            com = self.model.addFrame(
                pin.Frame(f"{link}__com", frame.parentJoint, body, placement, pin.FrameType.OP_FRAME)
            )
            self.frames.append((body, com))
        self.data = self.model.createData()
        self.q_index = [self.model.joints[self.model.getJointId(name)].idx_q for name in joint_names]

    def pin_vectors(self, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray):
        qp, vp, ap = np.zeros(self.model.nq), np.zeros(self.model.nv), np.zeros(self.model.nv)
        qp[self.q_index], vp[self.q_index], ap[self.q_index] = q, qd, qdd  # nq == nv for this robot
        return qp, vp, ap

    def fill(self, qp: np.ndarray, vp: np.ndarray, ap: np.ndarray) -> dict[str, np.ndarray]:
        """The same outputs, filled as an efficient Pinocchio user would: 6-vectors collected in
        lists, one array built per field, gravity added in one vectorised step."""
        model, data, local = self.model, self.data, pin.ReferenceFrame.LOCAL
        velocities, accels, com_accels, placements = [], [], [], []
        pin.forwardKinematics(model, data, qp, vp, ap)
        pin.updateFramePlacements(model, data)
        for body, com in self.frames:
            velocities.append(pin.getFrameVelocity(model, data, body, local).np)
            accels.append(pin.getFrameClassicalAcceleration(model, data, body, local).np)
            com_accels.append(pin.getFrameClassicalAcceleration(model, data, com, local).np)
            placements.append(data.oMf[body].homogeneous)
        velocity, accel, com_accel = np.array(velocities), np.array(accels), np.array(com_accels)
        pose = np.array(placements)
        rotation = pose[:, :3, :3]
        minus_g_in_link = -GRAVITY @ rotation  # row k: R_k^T (-g)
        return dict(omega=velocity[:, 3:], alpha=accel[:, 3:], velocity=velocity[:, :3],
                    accel=accel[:, :3] + minus_g_in_link, com_accel=com_accel[:, :3] + minus_g_in_link,
                    position=pose[:, :3, 3], rotation=rotation)  # fmt: skip

    def calls_only(self, qp: np.ndarray, vp: np.ndarray, ap: np.ndarray) -> None:
        model, data, local = self.model, self.data, pin.ReferenceFrame.LOCAL
        pin.forwardKinematics(model, data, qp, vp, ap)
        pin.updateFramePlacements(model, data)
        for body, com in self.frames:
            pin.getFrameVelocity(model, data, body, local)
            pin.getFrameClassicalAcceleration(model, data, body, local)
            pin.getFrameClassicalAcceleration(model, data, com, local)


def median_seconds(functions: dict[str, Callable[[], object]], repeats: int) -> dict[str, float]:
    """Median wall time of each function over interleaved repeats."""
    times: dict[str, list[float]] = {name: [] for name in functions}
    for _ in range(repeats):
        for name, function in functions.items():
            start = time.perf_counter()
            function()
            times[name].append(time.perf_counter() - start)
    return {name: statistics.median(values) for name, values in times.items()}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, default=10_000, help="batch size (default 10000)")
    parser.add_argument("--repeats", type=int, default=7, help="interleaved repeats (default 7)")
    args = parser.parse_args()

    model = load_model(URDF)
    peer = PinocchioPeer(URDF, model.joint_names, model.link_names)
    rng = np.random.default_rng(0)
    n = len(model.joint_names)
    q, qd, qdd = (rng.uniform(-1.0, 1.0, (args.samples, n)) for _ in range(3))
    pin_inputs = [peer.pin_vectors(q[t], qd[t], qdd[t]) for t in range(args.samples)]

    # Same numbers first: the comparison is meaningless otherwise.
    ours = forward_recursion(model, q[:50], qd[:50], qdd[:50], gravity=GRAVITY)
    worst = 0.0
    for t in range(50):
        theirs = peer.fill(*pin_inputs[t])
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
            "pinocchio fill": lambda: [peer.fill(*pin_inputs[t]) for t in range(singles)],
            "pinocchio calls only": lambda: [peer.calls_only(*pin_inputs[t]) for t in range(singles)],
        },
        args.repeats,
    )
    print(f"\none sample at a time ({singles} samples, median of {args.repeats}), per sample:")
    for name, seconds in single.items():
        print(f"  {name:<22} {seconds / singles * 1e6:8.1f} us")
    ratio_single = single["pinocchio fill"] / single["neforward"]
    ratio_floor = single["pinocchio calls only"] / single["neforward"]
    print(f"  ratio pinocchio fill / neforward:       {ratio_single:.2f}x  (target >= 1)")
    print(f"  ratio pinocchio calls only / neforward: {ratio_floor:.2f}x  (reference)")

    batch = median_seconds(
        {
            "neforward batched": lambda: forward_recursion(model, q, qd, qdd, gravity=GRAVITY),
            "pinocchio fill loop": lambda: [peer.fill(*x) for x in pin_inputs],
        },
        max(3, args.repeats // 2),
    )
    print(f"\n{args.samples} samples:")
    for name, seconds in batch.items():
        print(f"  {name:<22} {seconds * 1e3:8.1f} ms  ({seconds / args.samples * 1e6:.2f} us per sample)")
    ratio_batch = batch["pinocchio fill loop"] / batch["neforward batched"]
    print(f"  throughput ratio neforward batched / pinocchio loop: {ratio_batch:.1f}x  (target >= 10)")


if __name__ == "__main__":
    main()
