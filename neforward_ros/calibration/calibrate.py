"""``neforward calibrate``: recordings of free motion in, the effort and friction model and contact
thresholds out, as a params file the node and the bag tool take as it is.

1. Each recording is read as the bag tool reads it (:mod:`neforward_ros.bag.read`: the model from
   its ``robot_description`` or ``--urdf``, the node's rules for stray messages), and its measured
   joint states are assembled as the node assembles them for the momentum observer
   (:func:`neforward_ros.bag.compute.raw_states`). A recording without velocities takes the
   whole-recording estimator's.
2. Each joint's effort scale and offset and its friction are fitted by least squares on the
   momentum equation, with no acceleration (:mod:`.fit`).
3. The external torques the node would then publish on that free motion (the shared computation,
   with the fitted parameters) give each joint's contact threshold from their distribution, per
   speed, robustly (:mod:`.thresholds`: 3 x the largest 99th percentile of the speed terciles), so
   that one outlier cannot blind detection; the stretches the thresholds leave above them are
   reported, and the debounce rides over them. A contact ends once every joint is under
   :data:`RELEASE` of its threshold (hysteresis). The contact debounce is at least the observer's
   time constant, 1 / gain (at least a millisecond): its output is already filtered; and at least
   :data:`DEBOUNCE_SAMPLES` sample intervals. Unless given,
   the observer's velocity cutoff is chosen among :data:`CUTOFFS` on the free motion: the highest
   (the least lag) whose external torques have a mean square within :data:`CUTOFF_SLACK` of the
   least, velocity noise against the lag of the momentum's rate measured on the robot itself.
   Unless given, a second, slower observer (:data:`SLOWER`) with a dead zone per joint, on the joints
   where it is :data:`QUIETER` in the free motion (:func:`_two_speeds`;
   :mod:`neforward_ros.computation.observer`): the published external torques'. The thresholds are
   measured on the fast observer's own estimate, on which the node decides contact.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from neforward_ros.bag.compute import prepare_inputs, raw_states, results
from neforward_ros.bag.options import BagOptions
from neforward_ros.bag.read import Recording, read
from neforward_ros.calibration.fit import JointFit, Windows, fit_joints, windows
from neforward_ros.calibration.inertial import Identified, identify
from neforward_ros.calibration.payload import Payload, fit_payload, payload_models
from neforward_ros.calibration.thresholds import (
    MIN_REST,
    Excursion,
    debounce_over,
    excursions,
    largest_accelerations,
    rest_thresholds,
    robust_thresholds,
)
from neforward_ros.computation.compute import ComputeState, observe_raw
from neforward_ros.computation.contact import REST_DWELL, ContactDetector
from neforward_ros.computation.observer import RawStates
from neforward_ros.errors import InputError
from neforward_ros.kinematics.joint_space import momentum_values
from neforward_ros.logs import ThrottledLog
from neforward_ros.parameters.settings import node_settings

RELEASE = 0.6
"""The contact's hysteresis: a contact ends once every joint is under this fraction of its threshold."""
DEBOUNCE_SAMPLES = 3
"""The contact debounce spans at least this many sample intervals: at a slow rate, what a model error
leaves for a sample or two (a drive ringing after an abrupt stop) raises no contact."""
CUTOFFS = (0.0, 2.0, 4.0, 8.0, 16.0, 32.0)
"""Hz: the observer's velocity cutoffs tried (0: no filter)."""
CUTOFF_SLACK = 2.5
"""The velocity cutoff taken: the highest whose free-motion mean square is within this factor of the least."""
SLOWER = 2.5
"""The slow observer's gain is the observer's over this (:mod:`neforward_ros.computation.observer`)."""
DEAD_ZONE = 3.0
"""Each joint's dead zone: this many times the 99th percentile of the two observers' difference in the
free motion."""
QUIETER = 2.0 / 3.0
"""The slow observer serves the joints whose free-motion mean square it brings to at most this fraction
of the observer's: where the velocities' noise, which it filters, is much of what the model leaves
(the Franka Panda's first four joints: 0.46-0.53), not where the model's own error is (the UR10e's
joints: 0.77-0.96, where a slower output only draws a drive's ringing out into a contact)."""


def _two_speeds(
    fitted: dict[str, Any], fast: np.ndarray, names: Sequence[str], external: Callable[[dict[str, Any]], np.ndarray]
) -> dict[str, Any]:
    """The slow observer's parameters: its gain (the observer's over :data:`SLOWER`) and each joint's
    dead zone, :data:`DEAD_ZONE` x the 99th percentile of |fast - slow| over this free motion, where
    the slow one is :data:`QUIETER` there, else 0 (the fast one's output); none where no joint is
    (``fast``: the observer's external torques (T, n); ``external``: those of given parameters)."""
    settings = node_settings(fitted)
    gains = [settings.observer_gains.get(n, settings.observer_gain) for n in names]
    slow_gain = settings.observer_gain / SLOWER
    slow = external({**fitted, "external_torques.gain": slow_gain, "external_torques.joint_names": [],
                     "external_torques.gains": [], "external_torques.dead_zones": []})  # fmt: skip
    zones = []
    for fast_j, slow_j in zip(fast.T, slow.T, strict=True):
        known = np.isfinite(fast_j) & np.isfinite(slow_j)
        quieter = known.any() and np.mean(slow_j[known] ** 2) <= QUIETER * np.mean(fast_j[known] ** 2)
        apart = np.abs(fast_j - slow_j)[known]
        zones.append(float(f"{DEAD_ZONE * np.percentile(apart, 99.0):.4g}") if quieter else 0.0)
    if not any(zones):
        return {}
    out: dict[str, Any] = {
        "external_torques.slow_gain": float(slow_gain),
        "external_torques.joint_names": list(names),
        "external_torques.dead_zones": zones,
    }
    if settings.observer_gains:  # the joints' own gains, for every joint now named
        out["external_torques.gains"] = [float(g) for g in gains]
    return out


@dataclass
class Calibration:
    """What ``neforward calibrate`` found.

    Attributes:
        joint_names: the model's joint columns.
        fits: each joint's fitted parameters and residuals.
        parameters: the node parameters to write (the given ones, with the fitted ones over them).
        before, after: each joint's external torque RMS in the free motion with the given parameters
            and with the fitted ones, N m (N).
        thresholds: each joint's contact threshold.
        accelerations: each joint's largest |acceleration| in the free motion, which its threshold
            holds for (:func:`.thresholds.largest_accelerations`).
        method: how the node will estimate the external torques (observer or difference).
        samples: joint states fitted on.
        notes: what could not be fitted, and why.
        payload: the payload fitted (``--payload``), or None.
        outliers: the stretches of the free motion over the thresholds (:mod:`.thresholds`).
        identified: the inertial parameters identified (:mod:`.inertial`), or None.
        rest_thresholds: each joint's rest threshold (:mod:`.thresholds`), or None where the
            recordings do not hold the arm still long enough.
    """

    joint_names: tuple[str, ...]
    fits: list[JointFit]
    parameters: dict[str, Any]
    before: np.ndarray
    after: np.ndarray
    thresholds: np.ndarray
    method: str
    samples: int
    notes: list[str] = field(default_factory=list)
    payload: Payload | None = None
    outliers: list[Excursion] = field(default_factory=list)
    identified: Identified | None = None
    rest_thresholds: np.ndarray | None = None
    accelerations: np.ndarray | None = None


def calibrate(
    inputs: Sequence[Path],
    values: Mapping[str, Any],
    *,
    urdf: str | None = None,
    joint_states_topic: str | None = None,
    stribeck: bool = False,
    payload: str | None = None,
    inertia: bool = True,
    progress: Callable[[str, float], None] = lambda what, fraction: None,
) -> Calibration:
    """Fit on the recordings (see the module docstring); ``values``: node parameters given (a params
    file, ``-p``), kept in the output and used as the prior of what the motion cannot tell;
    ``payload``: a link whose payload (mass, centre of mass) is fitted too (:mod:`.payload`);
    ``inertia``: identify the links' inertial parameters first (:mod:`.inertial`; not with a payload).

    Raises:
        InputError: an unreadable recording, recordings of different robots, no joint state with
            every joint's position and effort.
    """
    if payload is not None:  # the one fitted replaces any given
        values = {k: v for k, v in values.items() if not k.startswith("payload.")}
    options = BagOptions.from_parameters(values, urdf=urdf, joint_states_topic=joint_states_topic)
    # The recordings with the URDF's model: each computation below adds the payload its settings give.
    plain = _options({k: v for k, v in values.items() if not k.startswith("payload.")}, urdf, joint_states_topic)
    recordings: list[Recording] = []
    for k, path in enumerate(inputs):
        progress(f"reading {k + 1}/{len(inputs)}", 0.0)
        recording = read(Path(path), plain, progress)
        if recordings and recording.model.joint_names != recordings[0].model.joint_names:
            raise InputError(
                f"{path} is of robot {recording.model.name!r} with joints {list(recording.model.joint_names)}, "
                f"not those of {inputs[0]}"
            )
        recordings.append(recording)
    if payload is not None and payload not in recordings[0].model.link_index:
        raise InputError(f"--payload {payload}: robot {recordings[0].model.name!r} has no such link")
    model = options.settings.model_of(recordings[0].model)  # with the given payload, if any
    names = model.joint_names
    # Joints never in a recording (a gripper whose driver is separate) are held there (the bag tool's
    # rule): no effort of theirs is measured, so nothing of theirs is fitted; the others are.
    held = sorted({model.joint_index[name] for recording in recordings for name in recording.report.missing_joints})
    measured = np.ones(len(names), dtype=bool)
    measured[held] = False
    original = dict(values)  # "before": the parameters given, the URDF's inertias
    # The recordings' measured samples, assembled once: they do not depend on the model's inertias.
    raws: list[tuple[RawStates | None, bool | None]] = []
    samples: list[RawStates] = []
    for k, recording in enumerate(recordings):
        progress("preparing", k / len(recordings))
        assembled, _, velocities = raw_states(recording, options)
        raws.append((assembled, velocities))
        raw = _measured(recording, options, assembled, velocities)
        if raw is not None:
            samples.append(raw)
    progress("preparing", 1.0)
    here = _momentum_fit(samples, options, model, measured, held, stribeck, payload, progress)
    given_scales = set(values.get("effort.joint_names", ())) if values.get("effort.scale") else set()
    identified = None
    if inertia and payload is None and measured.any():
        # The inertial parameters, with the friction's shapes the momentum fit found; then that fit
        # again, with the model identified.
        progress("inertia", 0.0)
        shapes = np.array([fit.velocity_scale for fit in here.fits])
        identified = _identified(recordings, options, model, measured, shapes)
        if identified.links:
            values = {**values, **identified.values()}
            options = BagOptions.from_parameters(values, urdf=urdf, joint_states_topic=joint_states_topic)
            model = options.settings.model_of(recordings[0].model)
            # The parameters were identified in the units the given scales set: those scales stay.
            here = _momentum_fit(
                samples,
                options,
                model,
                measured,
                held,
                stribeck,
                payload,
                progress,
                [j for j, name in enumerate(names) if name in given_scales],
            )
        progress("inertia", 1.0)
    parts, data, fits, prior = here.parts, here.data, here.fits, here.prior
    stamps, efforts, qd, runs = here.stamps, here.efforts, here.qd, here.runs
    gravity_force = -np.asarray(options.settings.gravity, dtype=float)
    found_payload = None
    if payload is not None:
        progress("payload", 0.0)
        units = payload_models(model, payload)

        def unit_terms(k: int) -> Windows:
            moved = [
                _split(
                    momentum_values(units[k], raw.q, raw.qd, gravity_force)
                    - momentum_values(model, raw.q, raw.qd, gravity_force)
                )
                for raw, *_ in parts
            ]
            return windows(
                np.concatenate(stamps), np.concatenate([m[0] for m in moved]), np.concatenate([m[1] for m in moved]),
                np.concatenate(efforts), np.concatenate(qd), runs,
            )  # fmt: skip

        found_payload, corrected = fit_payload(data, unit_terms, fits, prior, payload)
        data = replace(data, target=corrected)
        fits = fit_joints(data, names, prior, stribeck=stribeck, scale=False, held=held)
        progress("payload", 1.0)
    progress("fitting", 1.0)
    fitted = dict(values)
    fitted.pop("effort.armature", None)  # the fit's (where any rotor is found) replace the given ones
    fitted.update(_fitted_parameters(names, fits, stribeck))
    if found_payload is not None:
        fitted["payload.link"] = found_payload.link
        fitted["payload.mass"] = float(f"{found_payload.mass:.5g}")
        fitted["payload.com"] = [float(f"{x:.4g}") for x in found_payload.com]
    fitted["publish_torques"] = True
    fitted.pop("contact.joint_names", None)
    fitted.pop("contact.thresholds", None)
    fitted.pop("contact.rest_thresholds", None)
    fitted.pop("contact.accelerations", None)
    progress("thresholds", 0.0)
    given = {**original, "publish_torques": True}
    before = _external(recordings, _options(given, urdf, joint_states_topic), raws).external
    free = _external(recordings, _options(fitted, urdf, joint_states_topic), raws)
    method = free.method
    if method == "observer" and "external_torques.velocity_cutoff" not in values:
        # The velocity cutoff for this robot and motion: velocity noise against the lag of the
        # momentum's rate. The highest cutoff (the least lag) whose external torques in this motion
        # have a mean square within CUTOFF_SLACK of the least.
        trials = {}
        for cutoff in CUTOFFS:
            trial = {**fitted, "external_torques.velocity_cutoff": cutoff}
            trial_motion = _external(recordings, _options(trial, urdf, joint_states_topic), raws)
            known = np.isfinite(trial_motion.external)
            power = float(np.mean(np.square(trial_motion.external[known]))) if known.any() else np.inf
            trials[cutoff] = (power, trial_motion)
        least = min(power for power, _ in trials.values())
        cutoff = max((c for c, (power, _) in trials.items() if c > 0 and power <= CUTOFF_SLACK * least), default=0.0)
        if trials[0.0][0] <= least:
            cutoff = 0.0
        fitted["external_torques.velocity_cutoff"] = cutoff
        free = trials[cutoff][1]
    after = free.external  # what ~/external_torques publishes in this free motion
    if method == "observer" and fitted.get("external_torques.slow_gain"):
        # given (a params file of an earlier calibration): contact is decided on the fast observer's
        # own estimate (see the observer's module), which the thresholds are measured on
        fast = {**fitted, "external_torques.slow_gain": 0.0}
        free = _external(recordings, _options(fast, urdf, joint_states_topic), raws)
    elif method == "observer" and "external_torques.slow_gain" not in values:
        speeds = _two_speeds(fitted, free.external, names, lambda trial: _external(
            recordings, _options(trial, urdf, joint_states_topic), raws).external)  # fmt: skip
        if speeds:
            fitted.update(speeds)
            after = _external(recordings, _options(fitted, urdf, joint_states_topic), raws).external
    fitted_options = _options(fitted, urdf, joint_states_topic)
    progress("thresholds", 1.0)
    thresholds = robust_thresholds(free.external, free.velocity, measured)
    fitted["contact.joint_names"] = [name for name, ok in zip(names, measured, strict=True) if ok]
    fitted["contact.thresholds"] = [float(f"{x:.4g}") for x, ok in zip(thresholds, measured, strict=True) if ok]
    accelerations = largest_accelerations(_accelerations(free, names), measured)
    fitted["contact.accelerations"] = [float(f"{x:.4g}") for x, ok in zip(accelerations, measured, strict=True) if ok]
    fitted["contact.release"] = RELEASE
    rest = _rest_thresholds(free, names, measured) if method == "observer" else None
    if rest is not None:
        fitted["contact.rest_thresholds"] = [float(f"{x:.4g}") for x, ok in zip(rest, measured, strict=True) if ok]
    least = 0.0
    if method == "observer":
        gains = np.array([fitted_options.settings.observer_gains.get(n, fitted_options.settings.observer_gain)
                          for n in names])  # fmt: skip
        least = max(0.001, float(np.ceil(1000.0 / float(np.min(gains)))) / 1000.0)
    outliers = excursions(free.external, free.stamps, free.recording, thresholds)
    steps = np.diff(free.stamps)[np.diff(free.recording) == 0]
    interval = float(np.median(steps[steps > 0])) / 1e9 if (steps > 0).any() else 0.0
    debounce = debounce_over(outliers, interval, max(least, DEBOUNCE_SAMPLES * interval))
    if debounce > 0.0:
        fitted["contact.debounce"] = float(np.ceil(debounce * 1000.0) / 1000.0)
    node_settings(fitted)  # what is written is what the node accepts
    notes = [note for fit in fits for note in fit.notes]
    unscaled = [
        name
        for name, fit, ok in zip(names, fits, measured, strict=True)
        if ok and "scale" not in fit.fitted and name not in given_scales
    ]
    if unscaled and payload is None:
        notes.append(
            f"the effort scale of {', '.join(unscaled)} is not in these recordings and none was given: their torques "
            "are in the units of their efforts (scale 1). Give it: "
            + " ".join(f"--effort-scale {name}=GAIN" for name in unscaled)
            + " (torque per effort unit, as a datasheet's drive gain), or effort.joint_names / effort.scale in "
            "--params; or calibrate again on a recording with a known payload (--payload)"
        )
    notes += [] if identified is None else identified.notes
    notes += _outlier_notes(outliers, names, [str(p) for p in inputs], fitted.get("contact.debounce"))
    if method == "observer" and rest is None:
        notes.append(
            f"these recordings do not hold the arm still (every joint slower than its friction's velocity scale for "
            f"{REST_DWELL:g} s, {MIN_REST} samples in all): no contact.rest_thresholds, so a push on a still arm must "
            "pass contact.thresholds and the static friction; record a few seconds at rest to measure them"
        )
    return Calibration(
        names,
        fits,
        fitted,
        _rms(before),
        _rms(after),
        thresholds,
        method,
        sum(len(p[0]) for p in parts),
        notes,
        found_payload,
        outliers,
        identified,
        rest,
        accelerations,
    )


def _identified(
    recordings: list[Recording], options: BagOptions, model: Any, measured: np.ndarray, shapes: np.ndarray
) -> Identified:
    """The inertial parameters, on every recording's stamps where each joint has an estimate (the
    whole-recording estimator's) and each measured joint an effort."""
    parts = []
    for recording in recordings:
        states = prepare_inputs(recording, options, lambda what, fraction: None).states
        usable = states.ready.all(axis=1) & np.isfinite(states.efforts[:, measured]).all(axis=1)
        parts.append((states.q[usable], states.qd[usable], states.qdd[usable], states.efforts[usable]))
    q, qd, qdd, efforts = (np.concatenate([p[k] for p in parts]) for k in range(4))
    settings = options.settings
    effort = ComputeState.new(model, settings).effort
    given = np.array([name in settings.effort_scale for name in model.joint_names])
    return identify(model, q, qd, qdd, efforts, measured, settings.gravity, effort.scale, shapes, given)


def _outlier_notes(found: list[Excursion], names: Sequence[str], inputs: list[str], debounce: Any) -> list[str]:
    """What the thresholds left above them in the free motion, said: a count, the largest, and the
    longest, and how the debounce deals with them."""
    if not found:
        return []
    largest = max(found, key=lambda e: e.ratio)
    longest = max(found, key=lambda e: e.seconds)

    def where(e: Excursion) -> str:
        return f"{names[e.joint]} {e.value:.3g} at {e.start_s:.2f} s of {inputs[e.recording]}"

    notes = [
        f"{len(found)} stretch(es) of the free motion over the thresholds left out of them as outliers "
        f"({sum(e.samples for e in found)} samples; the furthest over its threshold: {where(largest)}; the longest: "
        f"{longest.seconds * 1000:.0f} ms, {where(longest)}); contact.debounce {debounce:g} s rides over those "
        "shorter than it"
    ]
    long = [e for e in found if debounce is None or e.seconds >= debounce]
    if long:
        notes.append(
            f"{len(long)} stretch(es) over the thresholds last longer than the debounce (from {where(long[0])}): a "
            "contact during the calibration motion? The node would report them as contacts"
        )
    return notes


@dataclass
class _Momentum:
    """The momentum fit of every joint (:mod:`.fit`) and what it was made of."""

    parts: list[Any]
    stamps: list[np.ndarray]
    efforts: list[np.ndarray]
    qd: list[np.ndarray]
    runs: list[tuple[int, int]]
    data: Windows
    fits: list[JointFit]
    prior: Any


def _momentum_fit(
    samples: list[RawStates],
    options: BagOptions,
    model: Any,
    measured: np.ndarray,
    held: list[int],
    stribeck: bool,
    payload: str | None,
    progress: Callable[[str, float], None],
    kept_scales: Sequence[int] = (),
) -> _Momentum:
    """Each joint's scale, offset and friction on the momentum equation, with this model, on the
    recordings' measured ``samples``; ``kept_scales``: joints whose scale stays the given one."""
    names = model.joint_names
    prior_settings = options.settings
    prior = ComputeState.new(model, prior_settings).effort
    gravity_force = -np.asarray(prior_settings.gravity, dtype=float)
    parts = []
    for raw in samples:
        known = np.isfinite(raw.efforts[:, measured]).all(axis=1) if measured.any() else np.zeros(len(raw), bool)
        values_k = momentum_values(model, raw.q, raw.qd, gravity_force)
        parts.append((raw, *_split(values_k), known))
    if not any(known.any() for *_, known in parts):
        raise InputError("no joint state with every joint's position and effort: nothing to calibrate on")
    stamps, momentum, rest, efforts, qd, runs, offset = [], [], [], [], [], [], 0
    measured_qd = []
    for raw, p, r, known in parts:
        edges = [0, *np.flatnonzero(raw.restart[1:] | ~known[1:] | ~known[:-1]) + 1, len(raw)]
        runs += [(offset + a, offset + b) for a, b in itertools.pairwise(edges) if known[a]]
        stamps.append(raw.stamps)
        momentum.append(p)
        rest.append(r)
        efforts.append(raw.efforts)
        measured_qd.append(raw.qd)
        qd.append(_smoothed(raw.qd, raw.stamps, [(a - offset, b - offset) for a, b in runs if a >= offset]))
        offset += len(raw)
    progress("fitting", 0.0)
    data = windows(
        np.concatenate(stamps), np.concatenate(momentum), np.concatenate(rest), np.concatenate(efforts),
        np.concatenate(qd), runs, momentum_qd=np.concatenate(measured_qd),
    )  # fmt: skip
    # A payload's torques and the effort scales trade off: with --payload the scales are the given ones
    # (a calibration without the payload first, then this one with --params of it).
    fits = fit_joints(data, names, prior, stribeck=stribeck, scale=payload is None, held=held, kept_scales=kept_scales)
    return _Momentum(parts, stamps, efforts, qd, runs, data, fits, prior)


SMOOTHING = 0.02
"""s: the friction regressors take the velocities averaged over this span, centred, twice (no lag),
which keeps velocity noise out of the nonlinear friction shapes (the momentum keeps them as measured)."""


def _smoothed(qd: np.ndarray, stamps: np.ndarray, runs: list[tuple[int, int]]) -> np.ndarray:
    """Each run's velocities, centred moving average of :data:`SMOOTHING`, applied twice."""
    out = qd.copy()
    for start, stop in runs:
        if stop - start < 3:
            continue
        step = float(np.median(np.diff(stamps[start:stop]))) / 1e9
        width = max(1, round(SMOOTHING / step)) | 1
        kernel = np.ones(width)
        part = qd[start:stop]
        counts = np.convolve(np.ones(len(part)), kernel, mode="same")[:, None]
        for _ in range(2):
            part = (
                np.stack([np.convolve(part[:, j], kernel, mode="same") for j in range(part.shape[1])], axis=1) / counts
            )
        out[start:stop] = part
    return out


def _split(values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The momentum kernel's values as (p, g - C^T qd)."""
    n = values.shape[-1] // 3
    return values[..., :n], values[..., 2 * n :] - values[..., n : 2 * n]


def _options(values: Mapping[str, Any], urdf: str | None, topic: str | None) -> BagOptions:
    return BagOptions.from_parameters(values, urdf=urdf, joint_states_topic=topic)


def _measured(
    recording: Recording, options: BagOptions, raw: RawStates | None, velocities: bool | None
) -> RawStates | None:
    """The measured joint states at every stamp where each joint has a sample (the node's assembly,
    ``raw``); velocities from the whole-recording estimator where the recording has none."""
    if raw is not None and velocities:
        return raw
    inputs = prepare_inputs(recording, options, lambda what, fraction: None)
    states = inputs.states
    ready = states.ready.all(axis=1)
    if not ready.any():
        return None
    rows = np.flatnonzero(ready)
    restart = np.r_[True, (np.diff(rows) > 1) | (np.diff(inputs.segment[rows]) != 0)]
    return RawStates(states.stamps[rows], states.q[rows], states.qd[rows], states.efforts[rows], restart)


@dataclass
class FreeMotion:
    """The external torques the node publishes on the recordings, stacked, where they are known.

    Attributes:
        external: (T, n) N m (N), NaN where unknown.
        stamps: (T,) int ns; velocity: (T, n) the joint velocities there; recording: (T,) its index.
        method: how they are estimated (observer or difference).
        still: (T,) whether the arm is still there (the observer's; False with the difference).
    """

    external: np.ndarray
    stamps: np.ndarray
    velocity: np.ndarray
    recording: np.ndarray
    method: str
    still: np.ndarray


def _external(recordings: list[Recording], options: BagOptions, raws: list[tuple[Any, bool | None]]) -> FreeMotion:
    """The external torques the node publishes on the recordings with these options; ``raws``: each
    recording's :func:`raw_states` (states, velocities)."""
    parts: list[tuple[np.ndarray, np.ndarray, np.ndarray, int, np.ndarray]] = []
    method = "difference"
    for k, (recording, (raw, velocities)) in enumerate(zip(recordings, raws, strict=True)):
        model = options.settings.model_of(recording.model)
        state = ComputeState.new(model, options.settings)
        if state.observer is not None:
            state.decide(bool(velocities))
        if state.method == "observer":
            method = "observer"
            if raw is not None:
                observed = observe_raw(model, options.settings, raw, state)
                assert observed is not None
                stamps = np.asarray(observed.stamp_ns)
                parts.append((observed.external, stamps, raw.qd, k, np.asarray(observed.still, dtype=bool)))
            continue
        inputs = prepare_inputs(recording, options, lambda what, fraction: None)
        for result, _, _ in results(model, inputs, options, [], state):
            if result is not None and result.dynamics is not None:
                stamps = np.asarray(result.stamp_ns)
                dynamics = result.dynamics
                parts.append((dynamics.external, stamps, dynamics.velocities, k, np.zeros(len(stamps), bool)))
    n = len(recordings[0].model.joint_names)
    if not parts:
        empty = np.zeros(0, np.int64)
        return FreeMotion(np.zeros((0, n)), empty, np.zeros((0, n)), empty, method, np.zeros(0, bool))
    return FreeMotion(
        np.concatenate([p[0] for p in parts]),
        np.concatenate([p[1] for p in parts]).astype(np.int64),
        np.concatenate([p[2] for p in parts]),
        np.concatenate([np.full(len(p[1]), p[3], dtype=np.int64) for p in parts]),
        method,
        np.concatenate([p[4] for p in parts]),
    )


def _rest_thresholds(free: FreeMotion, names: Sequence[str], measured: np.ndarray) -> np.ndarray | None:
    """The rest thresholds of this free motion (:func:`.thresholds.rest_thresholds`): the departures
    from the rest baseline that the node's detector would watch, recording by recording."""
    departures = np.full(free.external.shape, np.nan)
    for k in np.unique(free.recording).tolist():
        rows = free.recording == k
        detector = ContactDetector(np.full(len(names), np.inf), 0.0, tuple(names), ThrottledLog(None))
        departures[rows] = detector.rest_departures(free.stamps[rows], free.external[rows], free.still[rows])
    return rest_thresholds(departures, measured)


def _accelerations(free: FreeMotion, names: Sequence[str]) -> np.ndarray:
    """(T, n) the |accelerations| the node's contact detector reads in this free motion, recording by
    recording (NaN where it reads none yet)."""
    out = np.full(free.velocity.shape, np.nan)
    for k in np.unique(free.recording).tolist():
        rows = free.recording == k
        detector = ContactDetector(np.full(len(names), np.inf), 0.0, tuple(names), ThrottledLog(None))
        out[rows] = detector.accelerations_of(free.stamps[rows], free.velocity[rows])
    return out


def _rms(external: np.ndarray) -> np.ndarray:
    """Per joint, the RMS of its known values; NaN for a joint with none (held, never measured)."""
    known = np.isfinite(external)
    count = known.sum(axis=0)
    total = np.where(known, np.square(external), 0.0).sum(axis=0)
    return np.where(count > 0, np.sqrt(total / np.maximum(count, 1)), np.nan)


def _fitted_parameters(names: Sequence[str], fits: list[JointFit], stribeck: bool) -> dict[str, Any]:
    def rounded(values: Sequence[float]) -> list[float]:
        return [float(f"{v:.6g}") for v in values]

    out: dict[str, Any] = {
        "effort.joint_names": list(names),
        "effort.scale": rounded([f.scale for f in fits]),
        "effort.offset": rounded([f.offset for f in fits]),
        "friction.joint_names": list(names),
        "friction.coulomb": rounded([f.coulomb for f in fits]),
        "friction.viscous": rounded([f.viscous for f in fits]),
        "friction.velocity_scale": rounded([f.velocity_scale for f in fits]),
    }
    if stribeck:
        out["friction.stribeck"] = rounded([f.stribeck for f in fits])
    if any(f.armature > 0.0 for f in fits):
        out["effort.armature"] = rounded([f.armature for f in fits])
    return out
