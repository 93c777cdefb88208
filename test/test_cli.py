"""The `neforward` command: demo output and error exits."""

from __future__ import annotations

import math

from neforward_ros.cli import bundled_config_path, main

from conftest import TEST_ROBOTS


def test_demo_prints_every_link_of_the_bundled_robot(capsys) -> None:
    assert main(["table", "--samples", "2"]) == 0
    out = capsys.readouterr().out
    assert "13 links, 8 joints" in out
    for link in ("panda_link0", "panda_hand", "panda_leftfinger", "panda_rightfinger", "panda_tcp"):
        assert out.count(f"\n{link} ") == 2
    # The fixed base reads gravity alone: +9.81 m/s^2 along its z axis, origin and COM alike.
    assert "(   0.000,    0.000,    0.000)  (   0.000,    0.000,    0.000)  (   0.000,    0.000,    9.810)" in out


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
