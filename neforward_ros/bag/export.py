"""The results as a CSV table (the plot: :mod:`neforward_ros.bag.plot`)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from neforward_ros.computation.result import Result
from neforward_ros.model import JointKind, RobotModel
from neforward_ros.stamps import NS

CSV_FIELDS = (
    ("omega", "rad/s", "root"),
    ("alpha", "rad/s^2", "root"),
    ("accel", "m/s^2", "root"),
    ("com_accel", "m/s^2", "root"),
)


def torque_unit(model: RobotModel, joint: int) -> str:
    """N*m for a rotating joint, N for a prismatic one."""
    for parent in model.parent_joints:
        if parent is not None and parent.mimic_of is None and parent.q_index == joint:
            return "N" if parent.kind is JointKind.PRISMATIC else "N*m"
    return "N*m"


class CsvWriter:
    """One row per sample, written a chunk of results at a time: stamp, then per link omega, alpha,
    accel and com_accel (x, y, z); with ``torques``, per joint its torque (the model's) and, with
    ``external``, measured effort minus it (``<joint>.torque[N*m]``, ``<joint>.external_torque[N*m]``).

    The header names each column's link, quantity, frame, component and unit, e.g.
    ``panda_hand.accel_in_root.z[m/s^2]``: vectors along the root frame's axes. accel and com_accel
    are specific forces (a - g), as in the node's messages. ``t[s]`` counts from the first sample.
    A link that a joint without an estimate moves has empty cells (NaN) at that sample.
    """

    def __init__(self, path: Path, model: RobotModel, torques: bool = False, external: bool = False) -> None:
        self.model = model
        self.torques, self.external = torques, external
        self.stream = path.open("w")
        self.origin: int | None = None
        names = ["stamp_ns", "t[s]"]
        for link in model.link_names:
            for quantity, unit, frame in CSV_FIELDS:
                names += [f"{link}.{quantity}_in_{frame}.{axis}[{unit}]" for axis in "xyz"]
        units = [torque_unit(model, j) for j in range(len(model.joint_names))]
        if torques:
            names += [f"{joint}.torque[{unit}]" for joint, unit in zip(model.joint_names, units, strict=True)]
        if external:
            names += [f"{joint}.external_torque[{unit}]" for joint, unit in zip(model.joint_names, units, strict=True)]
        self.stream.write(",".join(names) + "\n")

    def write(self, result: Result) -> None:
        root = result.in_root
        stamps = np.asarray(result.stamp_ns, dtype=np.int64)
        if self.origin is None:
            self.origin = int(stamps[0])
        blocks = [
            getattr(root, quantity)[:, link_index, :]
            for link_index in range(len(self.model.link_names))
            for quantity, _, _ in CSV_FIELDS
        ]
        if result.determined is not None:  # links not determined at a sample: NaN
            blocks = [
                np.where(result.determined[:, link_index, None], block, np.nan)
                for link_index in range(len(self.model.link_names))
                for block in blocks[link_index * len(CSV_FIELDS) : (link_index + 1) * len(CSV_FIELDS)]
            ]
        if self.torques or self.external:
            dynamics = result.dynamics
            count = len(stamps)
            width = len(self.model.joint_names)
            nothing = np.full((count, width), np.nan)
            if self.torques:
                blocks.append(nothing if dynamics is None else dynamics.torques)
            if self.external:
                blocks.append(nothing if dynamics is None else dynamics.external)
        values = np.concatenate([((stamps - self.origin) / NS)[:, None], *blocks], axis=1)
        text = np.char.mod("%.9g", values)
        self.stream.writelines(
            f"{stamp}," + ",".join(row) + "\n" for stamp, row in zip(stamps.tolist(), text.tolist(), strict=True)
        )

    def close(self) -> None:
        self.stream.close()
