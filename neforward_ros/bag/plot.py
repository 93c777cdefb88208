"""The results as a PNG: every link's |a| and |alpha| over time (and joint torques), peaks marked.

Readable from 6 to 130 links: the links that move most (largest peaks) get a colour each, the same
in every panel, and the one legend, at the figure's right in a margin of fixed width; every other
link is drawn thin and grey under them, as one legend entry. Links that move as one (rigidly
attached) share their entry. The three highest peaks of each panel are labelled in a column of
text slots at the panel's top left, each with an arrow to its peak, so labels never overlap.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from neforward_ros.computation.result import Result
from neforward_ros.model import RobotModel
from neforward_ros.stamps import NS

LEGEND_LINKS = 12
"""Links (and joints) with a colour and a legend entry of their own."""
OTHERS_COLOUR = "#b0b0b0"
PEAK_LABELS = 3


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


@dataclass(frozen=True)
class Entry:
    """One legend entry: the series it stands for (a link or joint and those moving as one with it)."""

    label: str
    members: tuple[int, ...]
    colour: Any


def legend_entries(
    panels: list[np.ndarray], names: list[str], count: int = LEGEND_LINKS
) -> tuple[list[Entry], list[int]]:
    """The ``count`` most active series over all panels (largest peak relative to the panel's
    largest, summed over panels) as entries with distinct colours, series equal in every panel
    sharing one; and the indices of the others (grey)."""
    import matplotlib.pyplot as plt

    width = len(names)
    score = np.zeros(width)
    for values in panels:
        peaks = np.nanmax(np.where(np.isfinite(values), np.abs(values), 0.0), axis=0, initial=0.0)
        score += peaks / max(float(peaks.max(initial=0.0)), 1e-300)
    moving = [k for k in np.argsort(-score, kind="stable").tolist() if score[k] > 0]
    entries: list[list[int]] = []
    for k in moving:
        for group in entries:
            if all(np.allclose(v[:, group[0]], v[:, k], rtol=1e-9, atol=1e-12, equal_nan=True) for v in panels):
                group.append(k)
                break
        else:
            if len(entries) == count:
                continue
            entries.append([k])
    palette = (*plt.cm.tab10.colors, "#000000", "#6a3d9a", "#b15928")  # strong colours only: no pale ones
    legend = []
    for number, group in enumerate(entries):
        label = names[group[0]] + (f" (+{len(group) - 1} moving with it)" if len(group) > 1 else "")
        legend.append(Entry(label, tuple(group), palette[number % len(palette)]))
    chosen = {k for group in entries for k in group}
    others = [k for k in range(width) if k not in chosen and score[k] > 0]
    return legend, others


def plot_figure(series: PlotSeries, model: RobotModel) -> Any:
    """The matplotlib figure (see the module docstring)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.lines import Line2D

    stamps = np.concatenate(series.stamps)
    t = (stamps - stamps[0]) / NS
    link_panels = [
        (np.concatenate(series.accel), "|a| [m/s^2]"),
        (np.concatenate(series.alpha), "|alpha| [rad/s^2]"),
    ]
    joint_panels = []
    if series.torques:
        joint_panels.append((np.concatenate(series.torques), "joint torque [N*m, N]"))
        external = np.concatenate(series.external)
        if np.isfinite(external).any():
            joint_panels.append((external, "external torque [N*m, N]\n(measured - model)"))
    rows = len(link_panels) + len(joint_panels)
    figure, axes = plt.subplots(rows, 1, figsize=(14, 3.6 * rows), sharex=True, squeeze=False)
    axes = axes[:, 0]
    figure.subplots_adjust(left=0.07, right=0.76, top=0.95, bottom=0.06, hspace=0.12)
    groups = [(link_panels, list(model.link_names), "links"), (joint_panels, list(model.joint_names), "joints")]
    axis_iter = iter(axes)
    legend_y = 0.95
    for panels, names, what in groups:
        if not panels:
            continue
        entries, others = legend_entries([values for values, _ in panels], names)
        for values, label in panels:
            axis = next(axis_iter)
            for k in others:
                axis.plot(t, values[:, k], color=OTHERS_COLOUR, linewidth=0.5, zorder=1)
            for entry in entries:
                for k in entry.members:
                    axis.plot(t, values[:, k], color=entry.colour, linewidth=0.9, zorder=2, gid=names[k])
            _label_peaks(axis, t, values, names, entries)
            axis.set_ylabel(label)
            axis.grid(True, alpha=0.3)
        handles = [Line2D([], [], color=e.colour, linewidth=2, label=e.label) for e in entries]
        if others:
            handles.append(Line2D([], [], color=OTHERS_COLOUR, linewidth=2, label=f"{len(others)} other {what}"))
        legend = figure.legend(
            handles=handles, loc="upper left", bbox_to_anchor=(0.775, legend_y), fontsize=8, title=what.capitalize()
        )
        legend.set_gid(f"legend-{what}")
        legend_y -= 0.5 if joint_panels else 0.0
    axes[0].set_title(f"{model.name}: link accelerations (the {PEAK_LABELS} highest peaks labelled)")
    axes[-1].set_xlabel("time since the first output [s]")
    return figure


def _label_peaks(axis: Any, t: np.ndarray, values: np.ndarray, names: list[str], entries: list[Entry]) -> None:
    """Mark each coloured series' peak; label the highest distinct ones in stacked slots (axes
    fraction coordinates) with an arrow each, so that no two labels overlap."""
    peaks = []
    for entry in entries:
        k = entry.members[0]
        column = np.where(np.isfinite(values[:, k]), np.abs(values[:, k]), -np.inf)
        if not np.isfinite(column).any() or column.max() <= 0:
            continue
        i = int(np.argmax(column))
        axis.plot(t[i], values[i, k], "o", color=entry.colour, markersize=4, zorder=3)
        peaks.append((float(column[i]), i, entry))
    peaks.sort(key=lambda p: -p[0])
    # Series that peak together (links rigidly attached, differing in another panel) share a label.
    distinct: list[tuple[float, int, Entry, int]] = []
    for value, i, entry in peaks:
        same = [d for d in distinct if d[1] == i and abs(d[0] - value) <= 1e-9 * max(1.0, value)]
        if same:
            index = distinct.index(same[0])
            distinct[index] = (*same[0][:3], same[0][3] + 1)
        else:
            distinct.append((value, i, entry, 0))
    for slot, (_, i, entry, more) in enumerate(distinct[:PEAK_LABELS]):
        k = entry.members[0]
        name = names[k] + (f" (and {more} more)" if more else "")
        axis.annotate(
            f"{name}: {values[i, k]:.3g} at {t[i]:.2f} s",
            xy=(t[i], values[i, k]),
            xycoords="data",
            xytext=(0.01, 0.93 - 0.13 * slot),
            textcoords="axes fraction",
            fontsize=8,
            va="top",
            color=entry.colour,
            bbox={"boxstyle": "round,pad=0.2", "facecolor": "white", "alpha": 0.85, "edgecolor": "none"},
            arrowprops={"arrowstyle": "-", "color": entry.colour, "linewidth": 0.6, "alpha": 0.8},
            zorder=4,
        )


def write_plot(path: Path, series: PlotSeries, model: RobotModel) -> None:
    """Write the figure as a PNG."""
    import matplotlib.pyplot as plt

    figure = plot_figure(series, model)
    try:
        figure.savefig(path, format="png", dpi=100)
    finally:
        plt.close(figure)
