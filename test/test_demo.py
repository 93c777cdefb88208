"""``neforward demo`` tells the truth: its peak table against the batched recursion at the true joint
states, for the bundled arm and a 34-link humanoid, and it says which estimator it used."""

from __future__ import annotations

import numpy as np
import pytest

from neforward_ros import forward_recursion, load_model
from neforward_ros.cli import main
from neforward_ros.demo.live import run_demo
from neforward_ros.demo.robot import demo_trajectory

from conftest import TEST_ROBOTS


@pytest.mark.parametrize("robot", ["panda", "humanoid"])
def test_the_peak_table_is_within_two_percent_of_the_exact_peaks(robot: str) -> None:
    path = TEST_ROBOTS[robot]
    run = run_demo(3.0, str(path))
    view = run.view
    # what the design guarantees, however busy the machine: every result the node sent arrived
    # (reliable, a queue as deep as the run), and the node answered what it received
    received, answered = run.node_counts
    assert 0 < received <= run.sent and 0 < answered == len(view.stamps) == view.received["com_states"]
    model = load_model(path)
    t = (np.array(view.stamps, dtype=np.int64) - run.first_ns) / 1e9
    kin = forward_recursion(model, *demo_trajectory(model, t), gravity=(0.0, 0.0, 0.0))
    exact = {
        "a": np.linalg.norm(kin.accel, axis=-1).max(axis=0),
        "alpha": np.linalg.norm(kin.alpha, axis=-1).max(axis=0),
        "com": np.linalg.norm(kin.com_accel, axis=-1).max(axis=0),
    }
    for key, values in exact.items():
        scale = np.maximum(values, 1e-3 * values.max())  # links that barely move: against the largest
        worst = np.max(np.abs(view.peak[key] - values) / scale)
        assert worst <= 0.02, f"{robot} {key}: a peak {100 * worst:.2f} % off the exact one"


def test_the_demo_motion_spreads_its_frequencies_over_0_3_to_1_2_hz_whatever_the_joint_count() -> None:
    for robot in ("planar_2r", "panda", "humanoid"):
        model = load_model(TEST_ROBOTS[robot])
        t = np.arange(0, 20, 0.001)
        q, _, _ = demo_trajectory(model, t)
        spectrum = np.abs(np.fft.rfft(q - q.mean(axis=0), axis=0))
        frequencies = np.fft.rfftfreq(len(t), 0.001)[np.argmax(spectrum, axis=0)]
        assert frequencies.min() == pytest.approx(0.3, abs=0.06) and frequencies.max() == pytest.approx(1.2, abs=0.06)


def test_the_demo_says_which_estimator_it_used_and_how_far_its_peaks_are(capsys) -> None:
    assert main(["demo", "--seconds", "2", "--method", "kalman"]) == 0
    out = capsys.readouterr().out
    assert "estimator: kalman" in out and "20 ms before the newest" in out
    assert "largest difference of a peak from its exact value" in out
