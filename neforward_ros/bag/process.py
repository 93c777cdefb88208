"""``neforward bag``: a recording of joint states in, the node's outputs out."""

from __future__ import annotations

import os
import shutil
import signal
import time
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

import numpy as np

from neforward_ros.bag.compute import observations, prepare_inputs, results
from neforward_ros.bag.export import CsvWriter
from neforward_ros.bag.options import BagOptions, check_options
from neforward_ros.bag.plot import PlotSeries, write_plot
from neforward_ros.bag.read import read
from neforward_ros.bag.report import BagReport, Progress
from neforward_ros.bag.write import RecordingWriter, staging_folder
from neforward_ros.computation.compute import ComputeState, observer_wanted
from neforward_ros.computation.result import Observation, Result
from neforward_ros.errors import InputError
from neforward_ros.estimation import native_fit
from neforward_ros.kinematics.backward_kernel import backward_of
from neforward_ros.kinematics.forward_kernel import kernel_of
from neforward_ros.kinematics.joint_space_kernel import momentum_of


def process_bag(
    input_path: str | Path,
    output_path: str | Path,
    options: BagOptions | None = None,
    *,
    csv_path: str | Path | None = None,
    plot_path: str | Path | None = None,
    progress: Callable[[str, float], None] | None = None,
    on_done: Callable[[], None] | None = None,
) -> BagReport:
    """Compute the node's outputs for a whole recording and write them.

    ``on_done`` is called once every output is in place, while SIGINT and SIGTERM are still held off
    (the executable ignores Ctrl-C from there: :func:`neforward_ros.ctrl_c.hold`).

    Raises:
        InputError: no such file, not a rosbag2 recording, no joint-state topic (the message lists
            the topics), joints of the model missing from the recording, a corrupt recording, an
            output that exists already.
        ModelError: an invalid URDF.
    """
    started = time.monotonic()
    options = options if options is not None else BagOptions()
    settings = options.settings
    check_options(options)
    progress = progress if progress is not None else Progress(False)
    source, output = Path(input_path), Path(output_path)
    if not source.exists():
        raise InputError(f"no such file or directory: {source}")
    for path in (output, csv_path, plot_path):
        if path is None:
            continue
        if Path(path).exists():
            raise InputError(f"{path} exists already; remove it or choose another name")
        folder = Path(path).absolute().parent
        if not folder.is_dir():
            raise InputError(f"cannot write {path}: no such folder {folder}")
        if not os.access(folder, os.W_OK | os.X_OK):
            raise InputError(f"cannot write {path}: folder {folder} is not writable")
    if plot_path is not None:
        try:
            import matplotlib  # noqa: F401
        except ImportError as exc:
            raise InputError("--plot needs matplotlib: pip install 'neforward_ros[plot]' (or matplotlib)") from exc
    if settings.estimator.method == "polyfit" and settings.estimator.adaptive:
        native_fit.FIT.get()  # the adaptive fit's C, compiled in a thread while the recording is read
    recording = read(source, options, progress)
    model = recording.model
    # Compile the recursions in a thread while the recording is estimated (a model seen before: the
    # disk cache's); the computation takes them once they are ready: the same numbers, faster.
    kernel_of(model).native.get(start=True)
    if settings.dynamics_needed:
        backward_of(model).native.get(start=True)
    if observer_wanted(settings):
        momentum_of(model).native.get(start=True)
    for link in settings.named_links:
        if link not in model.link_index:
            raise InputError(f"link {link!r} is not in robot {model.name!r}")
    for parameter, names in settings.named_joints:
        unknown = [name for name in names if name not in model.joint_index]
        if unknown:
            flag = parameter.split(".")[0]  # hold.joint_names (--hold)
            raise InputError(
                f"{parameter} (--{flag}) names joints that robot {model.name!r} does not have: {', '.join(unknown)}"
            )
    if recording.base is not None:
        link = settings.base_link or recording.base.frame_id
        if link not in model.link_index:
            raise InputError(
                f"the base topic {recording.base.topic} measures frame {link!r}, not a link of robot {model.name!r}; "
                "choose the link with --base-link"
            )
    elif model.floating_base:
        recording.report.notes.append(
            f"robot {model.name!r} has a floating base (joint {model.floating_base!r}) but no base source was "
            "given: its root link was taken to be at rest (--base imu or --base odometry for a moving base)"
        )
    report = recording.report
    # Every output is written under a temporary name and all are moved into place together at the
    # end: an error or an interrupt leaves none of them, and nothing half-written.
    partials: list[Path] = []
    recording_writer: RecordingWriter | None = None
    try:
        recording_writer = RecordingWriter(output, options, model)
        recording_writer.reserve(len(recording.stamps))  # allocated by the writing thread meanwhile
        inputs = prepare_inputs(recording, options, progress)
        csv = None
        if csv_path is not None:
            partials.append(_partial(Path(csv_path)))
            measured = bool(np.isfinite(inputs.states.efforts).any())
            csv = CsvWriter(partials[-1], model, settings.publish_torques, settings.publish_torques and measured)
        series = PlotSeries(settings.gravity, settings.publish_torques) if plot_path is not None else None
        origin = report.segments[0].first_ns
        state = ComputeState.new(model, settings, lambda level, message: None)  # the report says what matters
        observed = observations(model, recording, options, state)
        if observed is not None:
            report.notes.append("external torques and contact: the momentum observer, at every joint-state stamp")
            _contacts(report, observed[0].stamp_ns, observed[0].contact, origin)
        written = 0  # observations written so far (interleaved with the results, in recording order)
        for result, log_times, done in results(model, inputs, options, report.segments, state):
            progress("computing", done / len(inputs))
            if result is None:
                continue
            if observed is not None and len(log_times):
                written = recording_writer.write_observations(*observed, written, int(log_times[-1]))
            _contacts(report, result.stamp_ns, result.contact, origin)
            recording_writer.write(result, log_times)
            if observed is not None:
                result = with_observed(result, log_times, *observed)
            if csv is not None:
                csv.write(result)
            if series is not None:
                series.add(result)
        if observed is not None:
            recording_writer.write_observations(*observed, written, None)
        report.samples_out = sum(segment.samples_out for segment in report.segments)
        if report.samples_out == 0:
            raise InputError(
                "no output: no stamp of the recording has an estimate for every joint (publish policy wait) or "
                f"for any joint; an estimate needs samples covering {settings.estimator.window:g} s around its "
                "stamp (estimator.window)"
            )
        if csv is not None:
            csv.close()
        if series is not None and plot_path is not None:
            progress("plotting", 0.0)
            partials.append(_partial(Path(plot_path)))
            write_plot(partials[-1], series, model)
            progress("plotting", 1.0)
        progress("finishing", 0.0)
        written_counts = recording_writer.counts()
        written_recording = recording_writer.finish()
        finals = [Path(p) for p in (csv_path, plot_path) if p is not None]
        # All outputs appear together: an interrupt now waits until they are in place, and one that
        # came meanwhile changes nothing more (the run is done: taken, not acted on).
        stops = {signal.SIGINT, signal.SIGTERM}
        blocked = signal.pthread_sigmask(signal.SIG_BLOCK, stops)
        try:
            for partial, final in zip(partials, finals, strict=True):
                partial.rename(final)
            written_recording.rename(output)
            # the staging folder too, while Ctrl-C is held off: one taken after the outputs are in place
            # ends the run as done (exit 0), and must not leave the folder behind
            shutil.rmtree(recording_writer.staging, ignore_errors=True)
            if on_done is not None:
                on_done()
            for pending in signal.sigpending() & stops:
                signal.sigwait({pending})
        finally:
            signal.pthread_sigmask(signal.SIG_SETMASK, blocked)
        progress("finishing", 1.0)
    except BaseException:
        if recording_writer is not None:
            recording_writer.discard()
        else:  # interrupted as the writer was made: its staging folder, if it came to be
            shutil.rmtree(staging_folder(output), ignore_errors=True)
        for partial in partials:
            partial.unlink(missing_ok=True)
        raise
    assert recording_writer is not None
    report.topics = recording_writer.topics
    report.written = written_counts
    report.seconds = time.monotonic() - started
    return report


def _contacts(report: BagReport, stamps: np.ndarray, states: np.ndarray | None, origin: int) -> None:
    """The contact intervals, for the report: from a chunk's contact states (in order)."""
    if states is None:
        return
    current = bool(report.contacts) and report.contacts[-1][1] is None
    for stamp, state in zip(stamps.tolist(), states.tolist(), strict=True):
        if state == state and bool(state) != current:  # a known state that changed
            current = bool(state)
            seconds = (stamp - origin) / 1e9
            if current:
                report.contacts.append((seconds, None))
            else:
                report.contacts[-1] = (report.contacts[-1][0], seconds)


def with_observed(
    result: Result, log_times: np.ndarray, observation: Observation, observed_times: np.ndarray
) -> Result:
    """The result with the observer's external torques at its stamps (for the CSV and the plot), where
    the observer has a sample of the same stamp and recording time."""
    if result.dynamics is None:
        return result
    at = np.minimum(np.searchsorted(observed_times, log_times), max(len(observed_times) - 1, 0))
    if not len(observed_times):
        return result
    same = (observed_times[at] == log_times) & (observation.stamp_ns[at] == result.stamp_ns)
    external = np.where(same[:, None], observation.external[at], np.nan)
    return replace(result, dynamics=replace(result.dynamics, external=external))


def _partial(path: Path) -> Path:
    return path.with_name(f".{path.name}.partial-{os.getpid()}{path.suffix}")
