"""``neforward bag`` on a fleet of recordings: one after another against ``--jobs`` at once, in one run.

Writes N recordings (default 6 of 60 s at 500 Hz, the bundled arm, MCAP), then times the fleet
processed by one worker (one after another) and by one worker per core, the same work through
:func:`neforward_ros.bag.fleet.process_fleet`, alternating, and prints the medians and their ratio
(the target on 2 cores: at most 0.6).

Usage: python bench/bench_fleet.py [--recordings 6] [--seconds 20] [--repeats 3] [--jobs N]
"""

from __future__ import annotations

import argparse
import os
import shutil
import statistics
import tempfile
import time
from pathlib import Path

from bench_bag import make_recording

from neforward_ros.bag import BagOptions
from neforward_ros.bag.fleet import plan, process_fleet, recordings


def timed(folder: Path, output: Path, workers: int) -> float:
    shutil.rmtree(output, ignore_errors=True)
    output.mkdir()
    jobs = plan(recordings([folder]), output)
    options = BagOptions.from_parameters({}, urdf=str(Path(__file__).resolve().parent.parent / "config" / "panda.urdf"))
    start = time.perf_counter()
    outcomes = process_fleet(jobs, options, workers)
    seconds = time.perf_counter() - start
    assert all(o.status == "done" for o in outcomes), [o.message for o in outcomes]
    return seconds


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--recordings", type=int, default=6)
    parser.add_argument("--seconds", type=float, default=60.0)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--jobs", type=int, default=os.cpu_count() or 1)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(
        prefix="bench-fleet-", dir="/dev/shm" if Path("/dev/shm").is_dir() else None
    ) as tmp:
        folder = Path(tmp) / "recordings"
        folder.mkdir()
        for k in range(args.recordings):
            make_recording(folder / f"run{k}", args.seconds)
        timed(folder, Path(tmp) / "out", 1)  # warm-up: imports, model cache
        serial, parallel = [], []
        for _ in range(args.repeats):
            serial.append(timed(folder, Path(tmp) / "out", 1))
            parallel.append(timed(folder, Path(tmp) / "out", args.jobs))
    s, p = statistics.median(serial), statistics.median(parallel)
    print(f"{args.recordings} recordings of {args.seconds:g} s at 500 Hz, {os.cpu_count()} cores")
    print(f"one after another: {s:.2f} s (median of {args.repeats})")
    print(f"--jobs {args.jobs}: {p:.2f} s")
    print(f"ratio: {p / s:.2f} (target at most 0.6 on 2 cores)")


if __name__ == "__main__":
    main()
