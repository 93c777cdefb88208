"""The results as a CSV table and a PNG plot."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from neforward_ros.model import JointKind, RobotModel
from neforward_ros.node.result import Result
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


class PlotSeries:
    """What the plot shows, gathered chunk by chunk: every link's |a| (kinematic: gravity removed)
    and |alpha| at every sample, and with ``torques`` every joint's torque and external torque."""

    def __init__(self, gravity: tuple[float, float, float], torques: bool = False) -> None:
        self.gravity = np.asarray(gravity, dtype=float)
        self.with_torques = torques
        self.stamps: list[np.ndarray] = []
        self.accel: list[np.ndarray] = []
        self.alpha: list[np.ndarray] = []
        self.torques: list[np.ndarray] = []
        self.external: list[np.ndarray] = []

    def add(self, result: Result) -> None:
        root = result.in_root
        self.stamps.append(np.asarray(result.stamp_ns, dtype=np.int64))
        accel = np.linalg.norm(root.accel + self.gravity, axis=-1)
        alpha = np.linalg.norm(root.alpha, axis=-1)
        if result.determined is not None:  # links not determined at a sample: gaps in the lines
            accel, alpha = (np.where(result.determined, x, np.nan) for x in (accel, alpha))
        self.accel.append(accel)
        self.alpha.append(alpha)
        if self.with_torques and result.dynamics is not None:
            self.torques.append(result.dynamics.torques)
            self.external.append(result.dynamics.external)


def write_plot(path: Path, series: PlotSeries, model: RobotModel) -> None:
    """PNG: every link's |a| (kinematic, gravity removed) and |alpha| over time, peaks marked and
    labelled; with torques, every joint's torque and, where efforts were recorded, external torque."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    stamps = np.concatenate(series.stamps)
    t = (stamps - stamps[0]) / NS
    accel, alpha = np.concatenate(series.accel), np.concatenate(series.alpha)
    torque_panels = []
    if series.torques:
        torque_panels.append((np.concatenate(series.torques), "joint torque [N*m, N]"))
        external = np.concatenate(series.external)
        if np.isfinite(external).any():
            torque_panels.append((external, "external torque [N*m, N]\n(measured - model)"))
    rows = 2 + len(torque_panels)
    figure, axes = plt.subplots(rows, 1, figsize=(13, 4 * rows), sharex=True)
    for axis, values, label in ((axes[0], accel, "|a| [m/s^2]"), (axes[1], alpha, "|alpha| [rad/s^2]")):
        axis.set_prop_cycle(color=plt.cm.tab20.colors)  # tens of links: more colours than the default 10
        for k, link in enumerate(model.link_names):
            if not np.any(values[:, k] > 0):
                continue
            line = axis.plot(t, values[:, k], linewidth=0.8, label=link)[0]
            peak = int(np.nanargmax(values[:, k]))
            axis.plot(t[peak], values[peak, k], "o", color=line.get_color(), markersize=4)
        # Label the three highest distinct peaks; links moving as one (rigidly attached) share one label.
        labelled: list[tuple[float, float]] = []
        peaks = np.nanmax(np.where(np.isnan(values), -np.inf, values), axis=0)
        for k in np.argsort(peaks)[::-1]:
            if not np.any(values[:, k] > 0):
                break
            peak = int(np.nanargmax(values[:, k]))
            value = float(values[peak, k])
            if value <= 0 or len(labelled) == 3:
                break
            if any(abs(value - v) <= 1e-9 * max(1.0, v) and t[peak] == at for v, at in labelled):
                continue
            same = sum(
                1
                for other in range(values.shape[1])
                if other != k and np.allclose(values[:, other], values[:, k], equal_nan=True)
            )
            extra = f" (and {same} more links)" if same else ""
            axis.annotate(
                f"{model.link_names[k]}{extra}: {value:.3g} at {t[peak]:.2f} s",
                (t[peak], value),
                textcoords="offset points",
                xytext=(5, 5 + 10 * len(labelled)),
                fontsize=8,
            )
            labelled.append((value, t[peak]))
        axis.set_ylabel(label)
        axis.grid(True, alpha=0.3)
    for axis, (values, label) in zip(axes[2:], torque_panels, strict=True):
        axis.set_prop_cycle(color=plt.cm.tab20.colors)
        for j, joint in enumerate(model.joint_names):
            if np.isfinite(values[:, j]).any():
                axis.plot(t, values[:, j], linewidth=0.8, label=joint)
        axis.set_ylabel(label)
        axis.grid(True, alpha=0.3)
        axis.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    axes[0].set_title(f"{model.name}: link accelerations (peaks marked)")
    axes[-1].set_xlabel("time since the first output [s]")
    axes[0].legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    figure.tight_layout()
    figure.savefig(path, format="png", dpi=100)
    plt.close(figure)
