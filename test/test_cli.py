"""The `neforward` command: demo output and error exits."""

from __future__ import annotations

import math
import os
import subprocess
import sys

import pytest

from neforward_ros.cli import main
from neforward_ros.resources import bundled_config_path

from conftest import CONFIG_DIR, TEST_ROBOTS, require


def test_table_prints_every_link_of_the_bundled_robot(capsys, monkeypatch) -> None:
    monkeypatch.setenv("COLUMNS", "160")  # wide enough for the four vectors on one line
    assert main(["table", "--samples", "2"]) == 0
    out = capsys.readouterr().out
    assert out.startswith("neforward table: robot 'panda'") and "13 links, 8 joints" in out
    for link in ("panda_link0", "panda_hand", "panda_leftfinger", "panda_rightfinger", "panda_tcp"):
        assert out.count(f"\n{link} ") == 2
    # The fixed base reads gravity alone: +9.81 m/s^2 along its z axis, origin and COM alike.
    assert "(   0.000,    0.000,    0.000)  (   0.000,    0.000,    0.000)  (   0.000,    0.000,    9.810)" in out


@pytest.mark.parametrize("columns", [100, 120])
def test_table_fits_the_terminal(capsys, monkeypatch, columns) -> None:
    monkeypatch.setenv("COLUMNS", str(columns))
    assert main(["table", "--samples", "2"]) == 0
    out = capsys.readouterr().out
    assert max(len(line) for line in out.splitlines()) <= columns
    for link in ("panda_link0", "panda_tcp"):  # in two blocks of two vectors
        assert out.count(f"\n{link} ") == 4
    assert "accel [m/s^2]" in out and "omega [rad/s]" in out


def test_help_version_and_defaults() -> None:
    def run(*arguments: str) -> str:
        done = subprocess.run(
            [sys.executable, "-m", "neforward_ros", *arguments], capture_output=True, text=True, check=True
        )
        return done.stdout

    assert "``" not in run("--help")
    assert run("--version").startswith("neforward ")
    demo = " ".join(run("demo", "--help").split())
    assert "(default: 500.0)" in demo and "(default: polyfit)" in demo
    bag = " ".join(run("bag", "--help").split())
    assert "-p NAME:=VALUE" in bag and "--params FILE" in bag
    # the bag flags that stand for node parameters show the node's defaults
    from neforward_ros.parameters.table import DEFAULTS

    assert f"(default: {' '.join(f'{g:g}' for g in DEFAULTS['gravity'])})" in bag
    for name in ("estimator.method", "estimator.mode", "publish_policy", "base.source", "contact.debounce"):
        assert f"{name}" in bag and f"(default: {DEFAULTS[name]})" in bag, name


def test_demo_on_planar_arm_matches_hand_computation(capsys) -> None:
    """At t = 0 the demo trajectory has q = 0, qd = A w, so link1 spins at 0.5 * 2 pi * 0.3 rad/s."""
    assert main(["table", "--urdf", str(TEST_ROBOTS["planar_2r"]), "--samples", "1"]) == 0
    line = next(row for row in capsys.readouterr().out.splitlines() if row.startswith("link1 "))
    assert f"{0.5 * 2 * math.pi * 0.3:8.3f}" in line


def test_demo_errors_exit_non_zero_with_one_line(capsys) -> None:
    assert main(["table", "--urdf", "/no/such.urdf"]) == 1
    err = capsys.readouterr().err
    assert err.startswith("neforward: error: cannot read URDF file") and err.count("\n") == 1
    assert main(["table", "--samples", "0"]) == 1


def test_bundled_robot_is_found() -> None:
    assert bundled_config_path("panda.urdf").is_file()


def test_neforward_node_without_ros_says_so_in_one_line() -> None:
    """The pip-installed entry point started where ROS 2 is not sourced (no rclpy on the path)."""
    environment = {k: v for k, v in os.environ.items() if not k.startswith(("ROS_", "AMENT_", "COLCON_"))}
    environment["PYTHONPATH"] = str(CONFIG_DIR.parent)  # the package's source, and nothing of ROS
    probe = subprocess.run([sys.executable, "-c", "import rclpy"], env=environment, capture_output=True, check=False)
    if probe.returncode == 0:
        pytest.skip("rclpy is importable here even without ROS 2 sourced")
    done = subprocess.run(
        [sys.executable, "-m", "neforward_ros.node_entry", "--ros-args", "-p", "max_gap:=1.0"],
        env=environment, capture_output=True, text=True, timeout=60, check=False,
    )  # fmt: skip
    assert done.returncode == 1
    assert done.stderr.count("\n") == 1 and "ROS 2 is not sourced" in done.stderr, done.stderr
    assert "source /opt/ros/jazzy/setup.bash" in done.stderr and "neforward run" in done.stderr


def test_package_xml_is_a_valid_ros_package_manifest() -> None:
    """catkin_pkg (what colcon uses to recognise a ROS package) parses it; an invalid manifest makes
    colcon build a plain Python package that `ros2 run` cannot find."""
    require("catkin_pkg")
    from catkin_pkg.package import parse_package

    package = parse_package(str(CONFIG_DIR.parent / "package.xml"))
    assert package.name == "neforward_ros" and package.get_build_type() == "ament_python"
    depends = {d.name for d in package.exec_depends}
    assert {"rclpy", "sensor_msgs", "trajectory_msgs", "geometry_msgs", "visualization_msgs"} <= depends


def test_the_public_api_is_importable_by_name() -> None:
    import neforward_ros

    for name in neforward_ros.__all__:
        assert getattr(neforward_ros, name) is not None, name
    assert sorted(neforward_ros.__all__) == sorted(neforward_ros._EXPORTS)


def test_the_demo_live_view_fits_a_short_terminal() -> None:
    """The table is redrawn in place, so it must not be taller than the terminal: with a humanoid's
    34 links in 20 rows, the links with the largest |a| are shown and the rest counted."""
    import numpy as np

    from neforward_ros.demo.live import _View
    from neforward_ros.estimation.settings import StreamSettings
    from neforward_ros.model import load_model

    model = load_model(TEST_ROBOTS["humanoid"])
    view = _View(model, True, StreamSettings(), "")
    n = len(model.link_names)
    values = {"a": np.arange(n, dtype=float), "alpha": np.zeros(n), "com": np.zeros(n)}
    lines = view._table(values, "title", rows=20)
    assert len(lines) == 20 and lines[-1].startswith(f"... {n - (20 - 3)} more links")
    shown = [line.split()[0] for line in lines[2:-1]]
    assert shown == [name for k, name in enumerate(model.link_names) if k >= n - len(shown)]  # the largest |a|
    assert len(view._table(values, "title")) == n + 2  # no limit: every link
