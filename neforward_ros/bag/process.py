"""``neforward bag``: a recording of joint states in, the node's outputs out."""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path

from neforward_ros.bag.compute import compute
from neforward_ros.bag.export import write_csv, write_plot
from neforward_ros.bag.options import BagOptions, check_options
from neforward_ros.bag.read import read
from neforward_ros.bag.report import BagReport, Progress
from neforward_ros.bag.write import atomic, write_bag
from neforward_ros.errors import InputError


def process_bag(
    input_path: str | Path,
    output_path: str | Path,
    options: BagOptions | None = None,
    *,
    csv_path: str | Path | None = None,
    plot_path: str | Path | None = None,
    progress: Callable[[str, float], None] | None = None,
) -> BagReport:
    """Compute the node's outputs for a whole recording and write them.

    Raises:
        InputError: no such file, not a rosbag2 recording, no joint-state topic (the message lists
            the topics), joints of the model missing from the recording, a corrupt recording, an
            output that exists already.
        ModelError: an invalid URDF.
    """
    started = time.monotonic()
    options = options if options is not None else BagOptions()
    check_options(options)
    progress = progress if progress is not None else Progress(False)
    source, output = Path(input_path), Path(output_path)
    if not source.exists():
        raise InputError(f"no such file or directory: {source}")
    for path in (output, csv_path, plot_path):
        if path is not None and Path(path).exists():
            raise InputError(f"{path} exists already; remove it or choose another name")
    if plot_path is not None:
        try:
            import matplotlib  # noqa: F401
        except ImportError as exc:
            raise InputError("--plot needs matplotlib: pip install 'neforward_ros[plot]' (or matplotlib)") from exc
    recording = read(source, options, progress)
    model = recording.model
    for link in (*options.accel_links, *options.imu_links):
        if link not in model.link_index:
            raise InputError(f"link {link!r} is not in robot {model.name!r}")
    batch = compute(recording, options, progress)
    report = recording.report
    report.samples_out = len(batch.log_times)
    if report.samples_out == 0:
        raise InputError("no output: no stretch of the recording has enough samples of every joint")
    report.topics = write_bag(output, batch, options, progress)
    if csv_path is not None:
        atomic(Path(csv_path), lambda path: write_csv(path, batch.result, model))
    if plot_path is not None:
        atomic(Path(plot_path), lambda path: write_plot(path, batch.result, model, options.gravity))
    report.seconds = time.monotonic() - started
    return report
