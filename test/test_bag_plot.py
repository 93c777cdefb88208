"""The bag tool's plot, read back from the figure object: one colour per link in every panel and in
the legend, a legend that fits beside the axes from 6 to 130 links, peak labels that do not overlap."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("matplotlib")
import matplotlib.colors as mcolors
import matplotlib.pyplot as plt
from matplotlib.text import Text

from neforward_ros.bag.plot import LEGEND_LINKS, OTHERS_COLOUR, PlotSeries, plot_figure
from neforward_ros.computation.result import Dynamics, make_result
from neforward_ros.kinematics.forward import kinematics_table, root_state
from neforward_ros.kinematics.inverse_dynamics import split_values, wrenches_from_table
from neforward_ros.model import load_model

from conftest import CONFIG_DIR, TEST_DIR


def chain(links: int) -> str:
    """A serial chain of ``links`` links, alternating joint axes, with masses."""
    parts = ['<robot name="chain">']
    for k in range(links):
        parts.append(
            f'<link name="l{k}"><inertial><mass value="1"/><inertia ixx="0.01" iyy="0.01" izz="0.01" '
            'ixy="0" ixz="0" iyz="0"/></inertial></link>'
        )
        if k:
            axis = ("1 0 0", "0 1 0", "0 0 1")[k % 3]
            parts.append(
                f'<joint name="j{k}" type="revolute"><parent link="l{k - 1}"/><child link="l{k}"/>'
                f'<origin xyz="0 0 0.05"/><axis xyz="{axis}"/>'
                '<limit lower="-3" upper="3" effort="1" velocity="1"/></joint>'
            )
    return "".join(parts) + "</robot>"


def figure_for(model, torques: bool = True):
    rng = np.random.default_rng(3)
    n = len(model.joint_names)
    t = np.linspace(0.0, 2.0, 400)
    w = rng.uniform(0.5, 2.0, n) * 2 * np.pi
    amplitude = rng.uniform(0.05, 0.3, n)
    phase = rng.uniform(0, 2 * np.pi, n)
    arg = np.outer(t, w) + phase
    q, qd, qdd = amplitude * np.sin(arg), amplitude * w * np.cos(arg), -amplitude * w**2 * np.sin(arg)
    stamps = (1_000_000_000 + t * 1e9).astype(np.int64)
    table = kinematics_table(model, q, qd, qdd, root_state())
    result = make_result(model, stamps, table)
    series = PlotSeries((0.0, 0.0, -9.81), torques=torques)
    if torques:
        force, moment, tau = split_values(model, wrenches_from_table(model, q, table))
        measured = tau + rng.normal(0, 0.1, tau.shape)
        from dataclasses import replace

        result = replace(result, dynamics=Dynamics(model.joint_names, q, qd, tau, measured, force, moment))
    series.add(result)
    return plot_figure(series, model)


MODELS = {
    "panda (13 links)": lambda: load_model(CONFIG_DIR / "panda.urdf"),
    "humanoid (34 links)": lambda: load_model(TEST_DIR / "urdf" / "humanoid.urdf"),
    "chain (6 links)": lambda: load_model(chain(6)),
    "chain (130 links)": lambda: load_model(chain(130)),
}


@pytest.mark.parametrize("name", sorted(MODELS))
def test_colours_legend_and_labels(name) -> None:
    model = MODELS[name]()
    figure = figure_for(model)
    try:
        figure.canvas.draw()
        renderer = figure.canvas.get_renderer()
        frame = figure.bbox
        legends = {legend.get_gid(): legend for legend in figure.legends}
        assert set(legends) == {"legend-links", "legend-joints"}
        link_axes, joint_axes = figure.axes[:2], figure.axes[2:]
        for legend, axes, names in (
            (legends["legend-links"], link_axes, model.link_names),
            (legends["legend-joints"], joint_axes, model.joint_names),
        ):
            # the legend fits in the figure, beside (not over) the axes
            box = legend.get_window_extent(renderer)
            assert frame.x0 <= box.x0 and box.x1 <= frame.x1 + 1 and frame.y0 <= box.y0 and box.y1 <= frame.y1 + 1
            assert all(box.x0 >= axis.get_window_extent(renderer).x1 for axis in figure.axes)
            entries = [
                (text.get_text(), handle.get_color())
                for text, handle in zip(legend.texts, legend.legend_handles, strict=True)
            ]
            coloured = [e for e in entries if "other" not in e[0]]
            assert 1 <= len(coloured) <= LEGEND_LINKS
            assert len({mcolors.to_hex(c) for _, c in coloured}) == len(coloured)  # distinct colours
            for label, colour in coloured:
                link = label.split(" (+")[0]
                assert link in names
                for axis in axes:  # the legend's colour is the colour of that link's line in every panel
                    lines = [line for line in axis.get_lines() if line.get_gid() == link]
                    assert lines, (link, axis.get_ylabel())
                    assert all(mcolors.to_hex(line.get_color()) == mcolors.to_hex(colour) for line in lines)
            # links without an entry of their own are grey in every panel, and counted in the legend
            others = [text for text, _ in entries if "other" in text]
            for axis in axes:
                unnamed = [
                    line for line in axis.get_lines() if line.get_gid() is None and line.get_linestyle() != "None"
                ]
                assert all(mcolors.to_hex(line.get_color()) == OTHERS_COLOUR for line in unnamed)
                if unnamed:
                    assert others == [f"{len(unnamed)} other {'links' if axes is link_axes else 'joints'}"]
            if len(names) > 40:  # many links: most are grey
                assert others
        # the axes keep their height whatever the number of links
        for axis in figure.axes:
            assert axis.get_position().height >= 0.15
        # peak labels do not overlap one another
        for axis in figure.axes:
            boxes = [Text.get_window_extent(text, renderer) for text in axis.texts]  # the text, not its arrow
            assert 1 <= len(boxes) <= 3
            for a in range(len(boxes)):
                for b in range(a + 1, len(boxes)):
                    assert not boxes[a].overlaps(boxes[b]), (axis.get_ylabel(), axis.texts[a], axis.texts[b])
    finally:
        plt.close(figure)
