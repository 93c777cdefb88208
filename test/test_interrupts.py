"""Ctrl-C: SIGINT sent to ``neforward bag`` and ``neforward run`` subprocesses at several moments, from
the interpreter's start-up to the last stage. Each stops promptly with one line and no traceback;
``bag`` leaves no output and no partial file behind, and running it again works."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from test_bag import record

from conftest import CONFIG_DIR, require

FRACTIONS = (0.05, 0.25, 0.45, 0.65, 0.8, 0.92)  # of an uninterrupted run: imports, reading, ..., CSV, plot


def command(*arguments: str) -> list[str]:
    return [sys.executable, "-m", "neforward_ros.cli", *arguments]


def interrupt_after(arguments: list[str], seconds: float, cwd: Path) -> tuple[int, str, float]:
    """Start, send SIGINT after ``seconds``; (exit code, stderr, seconds from the signal to the exit)."""
    process = subprocess.Popen(arguments, cwd=cwd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    time.sleep(seconds)
    sent = time.monotonic()
    if process.poll() is None:
        process.send_signal(signal.SIGINT)
    try:
        _, err = process.communicate(timeout=30)
    except subprocess.TimeoutExpired:
        process.kill()
        raise
    return process.returncode, err, time.monotonic() - sent


@pytest.fixture(scope="module")
def long_recording(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("interrupts") / "rec"
    record(path, seconds=16.0)
    return path


def test_ctrl_c_in_bag_leaves_nothing_and_a_rerun_works(long_recording, tmp_path) -> None:
    arguments = command("bag", str(long_recording), "-o", "out", "--csv", "--plot", "--torques")
    for attempt in range(2):  # the second, warm (compiled modules, cached model), is the shorter
        whole = tmp_path / f"whole{attempt}"
        whole.mkdir()
        started = time.monotonic()
        subprocess.run(arguments, cwd=whole, check=True, capture_output=True, timeout=300)
        duration = time.monotonic() - started
    outcomes = []
    interrupted = 0
    for number, fraction in enumerate(FRACTIONS):
        folder = tmp_path / f"run{number}"
        folder.mkdir()
        code, err, after = interrupt_after(arguments, fraction * duration, folder)
        assert "Traceback" not in err, (fraction, err)
        outcomes.append((round(fraction * duration, 2), code))
        if code == 0:  # finished before the signal: everything is there
            assert sorted(p.name for p in folder.iterdir()) == ["out", "out.csv", "out.png"]
            continue
        interrupted += 1
        assert code == 130 and err == "neforward: interrupted\n", (fraction, code, err)
        assert after < 5.0, (fraction, after)
        assert list(folder.iterdir()) == [], (fraction, list(folder.iterdir()))  # no output, no partial file
        # and running it again works
        done = subprocess.run(arguments, cwd=folder, capture_output=True, text=True, timeout=300)
        assert done.returncode == 0, done.stderr
        assert sorted(p.name for p in folder.iterdir()) == ["out", "out.csv", "out.png"]
    assert interrupted >= 4, outcomes  # most moments fall inside the run


def test_ctrl_c_in_run_stops_it_at_any_moment(tmp_path) -> None:
    require("cyclonedds")
    env = {**os.environ, "ROS_DOMAIN_ID": str(100 + os.getpid() % 100)}
    for moment in (0.1, 0.3, 0.8, 1.5, 2.5):
        arguments = command("run", "--urdf", str(CONFIG_DIR / "panda.urdf"))
        process = subprocess.Popen(arguments, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
        time.sleep(moment)
        sent = time.monotonic()
        process.send_signal(signal.SIGINT)
        try:
            _, err = process.communicate(timeout=15)
        except subprocess.TimeoutExpired:
            process.kill()
            pytest.fail(f"SIGINT {moment} s after start was swallowed: still running 15 s later")
        assert "Traceback" not in err, (moment, err)
        assert time.monotonic() - sent < 5.0
        # stopped before the node existed (130, one line), or the node stopped cleanly (0, its last log line)
        assert (process.returncode == 130 and err.endswith("neforward: interrupted\n")) or (
            process.returncode == 0 and "stopped:" in err.splitlines()[-1]
        ), (moment, process.returncode, err)
