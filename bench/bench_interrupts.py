"""How fast Ctrl-C takes effect in ``neforward bag``, stage by stage.

``neforward bag`` runs on a 20 s, 500 Hz recording of the bundled arm with its standard error on a
pseudo-terminal (so that it draws its progress, as in a terminal); SIGINT goes when a stage's
progress line appears, and the time until the process has exited is measured. Three runs per
stage; median and worst. The test suite (test/test_interrupts.py) checks the outcome (one line, no
output left behind); this measures the delay.

Usage: python bench/bench_interrupts.py
"""

from __future__ import annotations

import signal
import statistics
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "test"))

from test_bag import record  # noqa: E402
from test_interrupts import STAGES, Interrupted, command  # noqa: E402


def main() -> None:
    with tempfile.TemporaryDirectory() as folder:
        folder = Path(folder)
        recording = folder / "in"
        record(recording, seconds=20.0)
        print("Ctrl-C in `neforward bag` (20 s at 500 Hz): time from SIGINT to the process's exit")
        for stage in STAGES:
            delays = []
            for k in range(3):
                output = folder / f"out_{stage}_{k}"
                run = Interrupted(command("bag", str(recording), "-o", str(output), "--plot"), folder)
                if not run.wait_for(stage):
                    continue  # finished before the stage showed
                sent = time.monotonic()
                run.process.send_signal(signal.SIGINT)
                run.process.wait(timeout=120)
                delays.append(time.monotonic() - sent)
            if delays:
                median, worst = statistics.median(delays) * 1e3, max(delays) * 1e3
                print(f"  {stage:<11} median {median:6.0f} ms, worst {worst:6.0f} ms ({len(delays)} runs)")
            else:
                print(f"  {stage:<11} never seen before the end")


if __name__ == "__main__":
    main()
