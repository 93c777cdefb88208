"""``neforward bag`` from its parsed command line: one recording, or a fleet of them."""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from neforward_ros import ctrl_c
from neforward_ros.bag.arguments import parameter_values
from neforward_ros.bag.fleet import is_recording, plan, process_fleet, recordings, summary
from neforward_ros.bag.options import BagOptions
from neforward_ros.bag.process import process_bag
from neforward_ros.bag.report import Progress, describe
from neforward_ros.errors import InputError


def run_bag(args: argparse.Namespace) -> int:
    """Process the inputs; 0 when every recording was done or skipped, 1 when one failed.

    Raises:
        InputError: bad options or paths (before anything is read), or the one recording's error.
    """
    options = BagOptions.from_parameters(
        parameter_values(args),
        urdf=args.urdf,
        joint_states_topic=args.joint_states,
        base_topic=args.base_topic,
        storage=args.format,
    )
    inputs = [Path(p) for p in args.inputs]
    fleet = len(inputs) > 1 or (inputs[0].is_dir() and not is_recording(inputs[0]))
    if not fleet:
        output = Path(args.output)
        csv = _beside(output, args.csv, ".csv")
        plot = _beside(output, args.plot, ".png")
        # Ctrl-C is held off from the moment every output is in place (on_done): the run is done; before,
        # one that a library swallowed stops it at its next step
        progress = ctrl_c.checking(Progress())
        report = process_bag(
            inputs[0], output, options, csv_path=csv, plot_path=plot, progress=progress, on_done=ctrl_c.hold
        )
        print(describe(report))
        return 0
    if args.csv or args.plot:
        raise InputError("with several recordings, --csv and --plot take no path: each output gets NAME.csv, NAME.png")
    if args.jobs is not None and args.jobs < 1:
        raise InputError(f"--jobs must be at least 1, got {args.jobs}")
    found = recordings(inputs)
    output_dir = Path(args.output)
    if output_dir.exists() and not output_dir.is_dir():
        raise InputError(f"-o {output_dir}: with several recordings, the output is a folder")
    if not output_dir.absolute().parent.is_dir():
        raise InputError(f"cannot write {output_dir}: no such folder {output_dir.absolute().parent}")
    jobs = plan(found, output_dir, csv=args.csv is not None, plot=args.plot is not None)
    output_dir.mkdir(exist_ok=True)
    started = time.monotonic()

    def said(k: int, outcome) -> None:
        ctrl_c.check()  # a Ctrl-C that a library swallowed in a job run here stops the fleet
        detail = {"done": f"{outcome.samples} samples in {outcome.seconds:.1f} s", "skipped": "outputs exist"}
        print(
            f"[{k + 1}/{len(jobs)}] {outcome.job.input}: {outcome.status}, "
            f"{detail.get(outcome.status, outcome.message)}",
            file=sys.stderr,
            flush=True,
        )

    # Ctrl-C is held off once every recording's outcome is known (on_done): the run is done
    outcomes = process_fleet(jobs, options, args.jobs, said, on_done=ctrl_c.hold)
    print(summary(outcomes, time.monotonic() - started))
    return 1 if any(o.status == "failed" for o in outcomes) else 0


def _beside(output: Path, given: str | None, suffix: str) -> Path | None:
    """--csv/--plot: None when absent, the given path, or (bare) OUTPUT.csv / OUTPUT.png."""
    if given is None:
        return None
    return Path(given) if given else output.with_name(output.name + suffix)
