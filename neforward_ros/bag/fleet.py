"""``neforward bag`` on many recordings: one job per recording, on every core, resumable.

:func:`run_job` is the whole work for one recording and a plain picklable function of picklable
arguments, so any engine can run it as a task: :func:`process_fleet` runs it on a local process
pool (``--jobs``); on a cluster, hand the same jobs to ``dask.distributed`` (``client.map(run_job,
jobs, options=options)``, see the README's recipe). Outputs are moved into place only when a
recording is complete, so a job whose outputs all exist is done and is skipped on the next run.
"""

from __future__ import annotations

import multiprocessing
import os
import signal
import sys
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from neforward_ros.bag.options import BagOptions
from neforward_ros.errors import InputError, NeforwardError

RECORDING_SUFFIXES = (".mcap", ".db3")


@dataclass(frozen=True)
class Job:
    """One recording and where its outputs go (csv and plot: None for none)."""

    input: Path
    output: Path
    csv: Path | None = None
    plot: Path | None = None

    @property
    def outputs(self) -> list[Path]:
        return [p for p in (self.output, self.csv, self.plot) if p is not None]


@dataclass(frozen=True)
class Outcome:
    """What became of a job: ``status`` is ``done``, ``skipped`` (its outputs existed) or ``failed``."""

    job: Job
    status: str
    message: str = ""
    samples: int = 0
    seconds: float = 0.0


def is_recording(path: Path) -> bool:
    """A rosbag2 recording: a folder with metadata.yaml, or an .mcap or .db3 file."""
    return (path / "metadata.yaml").is_file() if path.is_dir() else path.suffix in RECORDING_SUFFIXES


def recordings(inputs: Iterable[str | Path]) -> list[Path]:
    """The recordings the inputs name: each recording itself; a folder that is not one, the
    recordings directly inside it (sorted by name).

    Raises:
        InputError: an input that does not exist, or a folder with no recording in it.
    """
    found: list[Path] = []
    for item in map(Path, inputs):
        if not item.exists():
            raise InputError(f"no such file or directory: {item}")
        if is_recording(item) or not item.is_dir():
            found.append(item)
            continue
        inside = sorted(p for p in item.iterdir() if not p.name.startswith(".") and is_recording(p))
        if not inside:
            raise InputError(f"{item} is neither a rosbag2 recording nor a folder of recordings")
        found += inside
    return found


def plan(inputs: Sequence[Path], output_dir: Path, csv: bool = False, plot: bool = False) -> list[Job]:
    """One job per recording: its outputs are ``output_dir/<name>`` (and ``<name>.csv``, ``<name>.png``),
    named after the recording's folder or file stem.

    Raises:
        InputError: two recordings with the same name.
    """
    jobs, seen = [], {}
    for source in inputs:
        name = source.stem if source.suffix in RECORDING_SUFFIXES else source.name
        if name in seen:
            raise InputError(f"{seen[name]} and {source} would both write {output_dir / name}; rename one")
        seen[name] = source
        output = output_dir / name
        jobs.append(
            Job(
                source,
                output,
                output.with_name(name + ".csv") if csv else None,
                output.with_name(name + ".png") if plot else None,
            )
        )
    return jobs


def run_job(job: Job, options: BagOptions, on_done: Callable[[], None] | None = None) -> Outcome:
    """Process one recording; never raises for a bad recording (the outcome says what went wrong).

    A job whose outputs all exist is skipped; one with only some of them fails and names them, as
    they were not written by this job (every run moves all of a job's outputs into place together).
    ``on_done``: as for :func:`~neforward_ros.bag.process.process_bag`, called once the job's outputs
    are in place (not for a job skipped or failed).
    """
    from neforward_ros.bag.process import process_bag

    present = [p for p in job.outputs if p.exists()]
    if present and len(present) == len(job.outputs):
        return Outcome(job, "skipped", "outputs exist")
    if present:
        names = ", ".join(str(p) for p in present)
        return Outcome(job, "failed", f"{names} exist(s) but not every output asked for; remove them to redo it")
    started = time.monotonic()
    try:
        report = process_bag(job.input, job.output, options, csv_path=job.csv, plot_path=job.plot, on_done=on_done)
    except NeforwardError as exc:
        return Outcome(job, "failed", str(exc), seconds=time.monotonic() - started)
    except Exception as exc:  # a recording the readers choke on must not stop the fleet
        return Outcome(job, "failed", f"{type(exc).__name__}: {exc}", seconds=time.monotonic() - started)
    return Outcome(job, "done", samples=report.samples_out, seconds=time.monotonic() - started)


def process_fleet(
    jobs: Sequence[Job],
    options: BagOptions,
    workers: int | None = None,
    on_outcome: Callable[[int, Outcome], None] | None = None,
    on_done: Callable[[], None] | None = None,
) -> list[Outcome]:
    """Every job, ``workers`` at once in a process pool (default: one per core), in the jobs' order.

    An interrupt (Ctrl-C, SIGTERM) stops the workers, which remove what they had half written, and
    is raised again as KeyboardInterrupt: the jobs finished so far stay done. ``on_done`` is called
    once every job's outcome is known, before the last is handed to ``on_outcome`` (the executable
    ignores Ctrl-C from there: :func:`neforward_ros.ctrl_c.hold`); in one process, where the last job
    moves its outputs into place (as :func:`~neforward_ros.bag.process.process_bag` calls it), or
    after it where it was skipped or failed.
    """
    workers = max(1, min(workers or os.cpu_count() or 1, len(jobs)))
    outcomes: list[Outcome | None] = [None] * len(jobs)
    done = on_done if on_done is not None else _nothing
    if workers == 1:
        for k, job in enumerate(jobs):
            last = k == len(jobs) - 1
            outcomes[k] = run_job(job, options, on_done=done if last else None)
            if last:
                done()  # (again, where the job moved its outputs: holding twice holds)
            if on_outcome is not None:
                on_outcome(k, outcomes[k])  # type: ignore[arg-type]
        return outcomes  # type: ignore[return-value]
    pool = multiprocessing.get_context("fork" if sys.platform == "linux" else "spawn").Pool(
        workers, initializer=_worker_started
    )
    try:
        received = 0
        for k, outcome in pool.imap_unordered(_run_numbered, [(k, job, options) for k, job in enumerate(jobs)]):
            outcomes[k] = outcome
            received += 1
            if received == len(jobs):
                done()
            if on_outcome is not None:
                on_outcome(k, outcome)
        pool.close()
    except BaseException:
        pool.terminate()  # SIGTERM: each worker cleans up (see _worker_started)
        raise
    finally:
        pool.join()
    return outcomes  # type: ignore[return-value]


def _nothing() -> None:
    pass


def _run_numbered(item: tuple[int, Job, BagOptions]) -> tuple[int, Outcome]:
    k, job, options = item
    try:
        _in_job.append(k)
        try:
            return k, run_job(job, options)
        finally:
            _in_job.clear()
    except KeyboardInterrupt:  # terminated (the job removed what it had half written): leave quietly
        raise SystemExit(1) from None  # (multiprocessing prints any other exception's traceback)


_in_job: list[int] = []  # in a worker: the job it is running, if any


def _worker_started() -> None:
    # The parent decides when to stop: a terminal's Ctrl-C reaches the whole process group, and the
    # parent then terminates the pool. SIGTERM interrupts a job like Ctrl-C, so that it removes its
    # partial outputs before the worker exits; between jobs the worker just exits.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, _interrupt)


def _interrupt(signum: int, frame: Any) -> None:
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    if _in_job:
        raise KeyboardInterrupt
    raise SystemExit(1)


def summary(outcomes: Sequence[Outcome], seconds: float) -> str:
    """One line for the whole fleet, then one per failed recording."""
    counts = {status: sum(o.status == status for o in outcomes) for status in ("done", "skipped", "failed")}
    samples = sum(o.samples for o in outcomes)
    lines = [
        f"{len(outcomes)} recordings in {seconds:.1f} s: {counts['done']} done ({samples} samples), "
        f"{counts['skipped']} skipped (outputs exist), {counts['failed']} failed"
    ]
    lines += [f"  failed: {o.job.input}: {o.message}" for o in outcomes if o.status == "failed"]
    return "\n".join(lines)
