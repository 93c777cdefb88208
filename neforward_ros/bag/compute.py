"""From a recording's messages to the node's results: the inputs of every segment, then the shared
computation (:func:`neforward_ros.computation.compute.compute`) a chunk of stamps at a time, so that
memory stays bounded for long recordings.

The inputs come from the whole-recording estimator for the node's default estimator (polyfit, fixed
lag window / 2, the same numbers), and otherwise from replaying the recording's messages through
the node's live inputs (:class:`~neforward_ros.computation.live_inputs.LiveInputs`: the streaming
estimator, and the base tracker for a moving base), so that each stamp gets what the node would
have published. A moving base's motion comes from the node's base tracker either way.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass, replace

import numpy as np

from neforward_ros.bag.options import BagOptions
from neforward_ros.bag.read import Recording
from neforward_ros.bag.report import Segment
from neforward_ros.computation.base_motion import BaseTracker
from neforward_ros.computation.compute import ComputeState, compute, observe_raw
from neforward_ros.computation.inputs import JointStates, LinkMotion
from neforward_ros.computation.live_inputs import Inputs, LiveInputs
from neforward_ros.computation.observer import RawStates
from neforward_ros.computation.raw_samples import RawAssembler
from neforward_ros.computation.result import Observation, Result
from neforward_ros.estimation.adaptive import pooled_std
from neforward_ros.estimation.batch import estimate_at
from neforward_ros.estimation.clock import held_targets, written_from
from neforward_ros.estimation.coverage import covered_mask
from neforward_ros.estimation.repeats import repeated
from neforward_ros.model import RobotModel
from neforward_ros.parameters.settings import NodeSettings
from neforward_ros.stamps import NS

CHUNK = 4096
"""Samples per batched computation: bounds the memory of every later stage at a few MB per link."""


@dataclass
class BagInputs:
    """The inputs of every output stamp of every segment, concatenated, in order.

    Attributes:
        states: (T, n) joint states at the stamps (the estimates, the efforts).
        log_times: (T,) the stamps' recording times.
        base: the base source's link motion at the stamps, for a moving base; None for a fixed one.
        segment: (T,) each stamp's segment (an index into the report's segments).
    """

    states: JointStates
    log_times: np.ndarray
    base: LinkMotion | None
    segment: np.ndarray

    def __len__(self) -> int:
        return len(self.log_times)


def _segments(recording: Recording) -> list[tuple[int, int]]:
    """Message index ranges [start, stop) of the segments: a new one after each time reset (the
    node's stamp rules, :mod:`neforward_ros.estimation.timeline`, sorted them out when reading)."""
    edges = [0, *(int(k) for k in recording.report.segment_starts), len(recording.stamps)]
    return [(a, b) for a, b in itertools.pairwise(edges) if b > a]


def prepare_inputs(recording: Recording, options: BagOptions, progress: Callable[[str, float], None]) -> BagInputs:
    """Each segment's inputs at every message stamp (see the module docstring); the report's
    segments are listed as it goes."""
    parts: list[tuple[JointStates, np.ndarray, LinkMotion | None]] = []
    ranges = _segments(recording)
    for number, (start, stop) in enumerate(ranges):
        progress("estimating", number / len(ranges))
        segment_stamps = recording.stamps[start:stop]
        segment = Segment(int(segment_stamps.min()), int(segment_stamps.max()), stop - start)
        recording.report.segments.append(segment)
        whole = None if options.streamed else _whole(recording, start, stop, options)
        if whole is None:
            states, log_times, base, absent = _replayed(recording, start, stop, options)
        else:
            states, log_times, absent = whole
            base = None
            if recording.base is not None:
                states, log_times, base = _with_base(recording, start, stop, states, log_times, options)
        if absent:
            segment.note = f"too few samples of {', '.join(absent)} for an estimate"
        segment.skipped = len(np.unique(segment_stamps)) - len(log_times)  # stamps with no input: no estimate, no base
        parts.append((states, log_times, base))
    progress("estimating", 1.0)
    n = len(recording.model.joint_names)
    parts = [p for p in parts if len(p[1])]
    if not parts:
        return BagInputs(JointStates.empty(n), np.zeros(0, dtype=np.int64), None, np.zeros(0, dtype=np.int64))
    numbers = [k for k, p in enumerate(parts) for _ in range(len(p[1]))]
    bases = [p[2] for p in parts]
    return BagInputs(
        JointStates.stack([p[0] for p in parts]),
        np.concatenate([p[1] for p in parts]),
        None if bases[0] is None else LinkMotion.stack(bases),
        np.array(numbers, dtype=np.int64),
    )


def raw_states(recording: Recording, options: BagOptions) -> tuple[RawStates | None, np.ndarray, bool | None]:
    """The measured joint states at the newest stamps, for the momentum observer, as the node
    assembles them (:mod:`neforward_ros.computation.raw_samples`, each segment from its start), with
    their recording times, and whether the joint states carry velocities (None: no stamp where
    every joint has a sample)."""
    model = recording.model
    n = len(model.joint_names)
    max_gap = round(options.settings.estimator.max_gap * NS)
    states: list[RawStates] = []
    times: list[int] = []
    velocities: bool | None = None
    for start, stop in _segments(recording):
        q, v, e, present = _message_rows(recording, start, stop)
        for j, position in held_joints(recording, options.settings).items():
            q[:, j], v[:, j], present[:, j] = position, 0.0, True  # efforts: NaN, none measured
        present &= np.isfinite(q)
        assembler = RawAssembler(n, max_gap)
        stamps = recording.stamps[start:stop].tolist()
        log_times = recording.log_times[start:stop].tolist()
        for m, stamp in enumerate(stamps):
            joints = np.flatnonzero(present[m])
            if not len(joints):
                continue
            found = assembler.add(stamp, joints, q[m, joints], v[m, joints], e[m, joints])
            if velocities is None and (found is not None or assembler.missing_velocity):
                velocities = found is not None
            if found is not None:
                states.append(found)
                times.append(log_times[m])
    if not states:
        return None, np.zeros(0, dtype=np.int64), velocities
    return RawStates.stack(states), np.array(times, dtype=np.int64), velocities


def observations(
    model: RobotModel, recording: Recording, options: BagOptions, state: ComputeState
) -> tuple[Observation, np.ndarray] | None:
    """The momentum observer over the recording's raw samples, in the shared computation: the
    observation (a batch) and its recording times; None when the observer does not give the external
    torques (``state.method`` is decided here for ``auto``)."""
    if state.observer is None:
        return None
    raw, log_times, velocities = raw_states(recording, options)
    state.decide(bool(velocities))
    if raw is None:
        return None
    observation = observe_raw(model, options.settings, raw, state)
    return None if observation is None else (observation, log_times)


def results(
    model: RobotModel,
    inputs: BagInputs,
    options: BagOptions,
    segments: list[Segment],
    state: ComputeState,
    chunk: int | None = None,
) -> Iterator[tuple[Result | None, np.ndarray, int]]:
    """(result, its recording times, the inputs done so far) of consecutive chunks of the inputs, each
    from one call of the shared computation (None: nothing published in the chunk); the segments'
    counts of stamps with output, without, and with only some links are added up as it goes."""
    chunk = CHUNK if chunk is None else chunk
    settings = options.settings
    for start in range(0, len(inputs), chunk):
        part = slice(start, start + chunk)
        base = None if inputs.base is None else inputs.base.part(part)
        computed = compute(model, settings, inputs.states.part(part), base, state)
        numbers = inputs.segment[part]
        published = np.zeros(len(numbers), dtype=bool)
        if computed.rows is not None:
            published[computed.rows] = True
        partial = published & ~computed.known.all(axis=1)
        for k, segment in enumerate(segments):
            mine = numbers == k
            if mine.any():
                segment.samples_out += int(np.count_nonzero(published & mine))
                segment.skipped += int(np.count_nonzero(~published & mine))
                segment.partial += int(np.count_nonzero(partial & mine))
        done = min(start + chunk, len(inputs))
        if computed.result is not None and len(computed.rows):
            yield computed.result, inputs.log_times[part][computed.rows], done
        else:
            yield None, inputs.log_times[:0], done


def _whole(
    recording: Recording, start: int, stop: int, options: BagOptions
) -> tuple[JointStates, np.ndarray, list[str]] | None:
    """One segment's joint states at every message stamp from the whole-recording estimator, their
    recording times, and the joints with too few samples; None where some joints' stamps are write
    times (:class:`~neforward_ros.estimation.clock.SampleClock`, fed their samples as the node feeds
    it): from there on the node fits them on the clock it recovers, and the segment is replayed
    through it (:func:`_replayed`).

    As in the node, a joint has an estimate at a stamp only where its samples cover the estimator's
    support there (:mod:`neforward_ros.estimation.coverage`, the fixed-lag fit's) and none is more
    than max_gap away."""
    model, settings = recording.model, options.settings
    n = len(model.joint_names)
    wrap = model.continuous_columns
    batch = options.batch_estimator
    support = batch.support
    targets, first = np.unique(recording.stamps[start:stop], return_index=True)
    origin = int(targets[0])
    target_s = (targets - origin) / NS
    state = np.full((3, len(targets), n), np.nan)
    efforts = np.full((len(targets), n), np.nan)
    spread = np.full((len(targets), n), np.nan)
    # As the node, which emits an estimate once a message about `after` later arrives (half an
    # interval early, for jitter) and has none for the last stretch of a stream.
    early = 0.5 * float(np.median(np.diff(target_s))) if len(target_s) > 1 else 0.0
    reached = target_s + support.after <= target_s[-1] + early
    silent = np.ones((len(targets), n), dtype=bool)
    # Each joint's own samples; joints with the same sample times and kind are estimated together.
    groups: dict[tuple[bytes, bool], list[tuple[int, np.ndarray, np.ndarray]]] = {}
    absent = []
    for j, (rows, qs, vs, es) in recording.columns.items():
        inside = (rows >= start) & (rows < stop) & np.isfinite(qs)
        t_ns, keep = np.unique(recording.stamps[rows[inside]], return_index=True)
        if len(t_ns) < support.min_samples:
            efforts[:, j] = _efforts_at(t_ns, es[inside][keep], targets)
            absent.append(model.joint_names[j])
            continue
        q = qs[inside][keep]
        if wrap[j]:
            q = np.unwrap(q)
        v = vs[inside][keep]
        use_velocity = settings.estimator.velocity_source != "differentiate" and bool(np.all(np.isfinite(v)))
        groups.setdefault((t_ns.tobytes(), use_velocity), []).append((j, q, v, es[inside][keep]))
    samples = []  # per group: members, fitted on velocities or not, stamps, positions, which are fresh, restarts
    for (t_bytes, use_velocity), members in groups.items():
        t_ns = np.frombuffer(t_bytes, dtype=np.int64)
        q = np.stack([q for _, q, _, _ in members], axis=1)
        gap = np.r_[False, np.diff(t_ns) > settings.estimator.max_gap * NS]  # where the node restarts
        fresh = ~repeated(q, gap)  # a driver's repeated reading is no sample: the node leaves it out too
        if written_from(t_ns[fresh], q[fresh], gap[fresh]) is not None:
            return None
        samples.append((members, use_velocity, t_ns, q, fresh, gap))
    lag = round(settings.estimator.effective_lag * NS)
    for members, use_velocity, t_ns, q, fresh, gap in samples:
        reach = (t_ns - origin) / NS  # every sample's time, repeated readings too: how far the samples go
        joints = [j for j, _, _, _ in members]
        v = np.stack([v for _, _, v, _ in members], axis=1)
        t_ns, q, v = t_ns[fresh], q[fresh], v[fresh]
        for j, _, _, e in members:
            efforts[:, j] = _efforts_at(t_ns, e[fresh], targets)
        t = (t_ns - origin) / NS
        stale = _gap_to_samples(t, target_s) > settings.estimator.max_gap
        silent[:, joints] = stale[:, None]
        unready = stale | ~covered_mask(t, target_s, support, _end_slack(reach), reach) | ~reached
        # as the node, whose start waits for the clock: the estimates made (a degree choice's record), not given
        held = held_targets(targets, lag, t_ns, q, gap[fresh])
        q_at, qd_at, qdd_at, std_at = estimate_at(
            t,
            q,
            target_s,
            velocity=v if use_velocity else None,
            stamps_ns=targets,
            counted=~unready,  # the estimates the node makes
            method=batch.method,
            window=batch.window,
            order=batch.order,
            adaptive=batch.adaptive,
            spread=True,
        )
        unready |= held
        for column, values in enumerate((q_at, qd_at, qdd_at)):
            values[unready] = np.nan
            state[column][:, joints] = values
        spread[:, joints] = np.where(unready[:, None], np.nan, std_at)
    ready = np.isfinite(state).all(axis=0)
    if batch.method == "polyfit" and batch.adaptive:  # as the node states them
        spread = pooled_std(targets, np.where(ready, spread, np.nan), batch.window)
    states = JointStates(targets, *np.where(ready, state, 0.0), ready, silent, efforts, spread)
    states = with_held(states, held_joints(recording, settings))
    return states, recording.log_times[start:stop][first], sorted(set(absent))


def _with_base(
    recording: Recording, start: int, stop: int, states: JointStates, log_times: np.ndarray, options: BagOptions
) -> tuple[JointStates, np.ndarray, LinkMotion]:
    """The stamps where the base's motion is known, with it: the recording's base messages through the
    node's base tracker (every estimate kept), its motion at the joint stamps as the node takes it."""
    settings = options.settings
    assert recording.base is not None
    tracker = BaseTracker(settings.base_source, settings.estimator, settings.gravity, keep=None)
    first, last = recording.log_times[start], recording.log_times[stop - 1]
    inside = (recording.base.log_times >= first) if start else np.ones(len(recording.base.messages), dtype=bool)
    if stop < len(recording.log_times):
        inside &= recording.base.log_times <= last
    for k in np.flatnonzero(inside):
        tracker.on_message(recording.base.messages[k])
    link = settings.base_link or tracker.frame_id
    motion, reasons = tracker.motion_at(states.stamps, link)
    ok = np.array([r is None for r in reasons], dtype=bool)
    rows = np.flatnonzero(ok)
    return states.part(rows), log_times[rows], motion.part(rows)


def _replayed(
    recording: Recording, start: int, stop: int, options: BagOptions
) -> tuple[JointStates, np.ndarray, LinkMotion | None, list[str]]:
    """As :func:`_whole`, by replaying the segment's messages (and its base messages, in recording
    order) through the node's live inputs: each stamp gets exactly what the node would have had."""
    model = recording.model
    n = len(model.joint_names)
    q, v, e, present = _message_rows(recording, start, stop)
    live = LiveInputs(model, options.settings, lambda level, message: None, keep_base=None)
    names = np.array(model.joint_names, dtype=object)
    stamps = recording.stamps[start:stop].tolist()
    log_times = recording.log_times[start:stop]
    base_times: list[int] = []
    base_messages = []
    if recording.base is not None:
        first, last = log_times[0], log_times[-1]
        inside = (recording.base.log_times >= first) if start else np.ones(len(recording.base.messages), bool)
        if stop < len(recording.log_times):
            inside &= recording.base.log_times <= last
        base_times = recording.base.log_times[inside].tolist()
        base_messages = [recording.base.messages[k] for k in np.flatnonzero(inside)]
    out: list[Inputs] = []
    b = 0
    for m, stamp in enumerate(stamps):
        while b < len(base_messages) and base_times[b] <= log_times[m]:  # in recording order
            out += live.base(base_messages[b])
            b += 1
        joints = np.flatnonzero(present[m])
        velocities, measured = v[m, joints], e[m, joints]
        out += live.joint_state(
            stamp,
            names[joints].tolist(),
            q[m, joints].tolist(),
            velocities.tolist() if np.isfinite(velocities).all() else (),
            measured.tolist() if np.isfinite(measured).all() else (),
        )
    while b < len(base_messages):
        out += live.base(base_messages[b])
        b += 1
    out += live.flush()
    index: dict[int, int] = {}  # a stamp's recording time: its first message's
    for k, stamp in enumerate(stamps):
        index.setdefault(stamp, k)
    held = held_joints(recording, options.settings)
    seen = present.any(axis=0)
    absent = [model.joint_names[j] for j in range(n) if not seen[j] and j not in held]
    if not out:
        return JointStates.empty(n), np.zeros(0, dtype=np.int64), None, absent
    states = with_held(JointStates.stack([states for states, _ in out]), held)
    times = np.array([log_times[index[s]] for s in states.stamps.tolist()], dtype=np.int64)
    motions = [motion for _, motion in out]
    base = None if motions[0] is None else LinkMotion.stack(motions)
    return states, times, base, absent


def held_joints(recording: Recording, settings: NodeSettings) -> dict[int, float]:
    """The joints of the model never in the recording (a gripper whose driver publishes elsewhere), by
    column, with the position each is held at: ``hold.positions`` (``--hold``), else 0. Held joints
    are at rest: their states are known at every stamp, whatever the publish policy, so that the
    links, torques and contact of the others are computed; they have no measured effort."""
    names = recording.model.joint_names
    return {
        j: float(settings.hold_positions.get(names[j], 0.0)) for j in range(len(names)) if j not in recording.columns
    }


def with_held(states: JointStates, held: Mapping[int, float]) -> JointStates:
    """The states with the held joints at their positions, at rest, known where another joint has an
    estimate (a held joint alone is no reason to publish; see :func:`held_joints`)."""
    if not held:
        return states
    columns = list(held)
    others = np.ones(states.q.shape[-1], dtype=bool)
    others[columns] = False
    q, qd, qdd, ready = states.q.copy(), states.qd.copy(), states.qdd.copy(), states.ready.copy()
    q[..., columns] = [held[j] for j in columns]
    qd[..., columns] = 0.0
    qdd[..., columns] = 0.0
    ready[..., columns] = ready[..., others].any(axis=-1, keepdims=True)
    spread = None if states.acceleration_std is None else states.acceleration_std.copy()
    if spread is not None:
        spread[..., columns] = 0.0
    return replace(states, q=q, qd=qd, qdd=qdd, ready=ready, acceleration_std=spread)


def _message_rows(recording: Recording, start: int, stop: int) -> tuple[np.ndarray, ...]:
    """Messages [start, stop) as rows of (q, v, e) by joint column, NaN where a message has none, and
    whether each message names each joint."""
    n = len(recording.model.joint_names)
    count = stop - start
    q, v, e = (np.full((count, n), np.nan) for _ in range(3))
    present = np.zeros((count, n), dtype=bool)
    for j, (rows, qs, vs, es) in recording.columns.items():
        inside = (rows >= start) & (rows < stop)
        at = rows[inside] - start
        present[at, j] = True
        q[at, j], v[at, j], e[at, j] = qs[inside], vs[inside], es[inside]
    return q, v, e, present


def _efforts_at(t_ns: np.ndarray, efforts: np.ndarray, targets: np.ndarray) -> np.ndarray:
    """A joint's recorded efforts at the target stamps: a sample's own at its stamp, else interpolated
    between the samples around; NaN outside them and next to samples without one."""
    if len(t_ns) == 0 or not np.isfinite(efforts).any():
        return np.full(len(targets), np.nan)
    out = np.interp(targets, t_ns, efforts)  # NaN samples make their neighbourhood NaN
    out[(targets < t_ns[0]) | (targets > t_ns[-1])] = np.nan
    return out


def _end_slack(t: np.ndarray) -> float:
    """How far, s, an estimate's support may reach past the joint's last sample: as in the node, one and
    a half of its longest sample interval among 8 (the node takes the last 8; here the median over the
    recording of the longest of every 8, so that one late sample does not widen it everywhere)."""
    intervals = np.diff(t)
    if len(intervals) < 8:
        return float("inf")
    longest = np.lib.stride_tricks.sliding_window_view(intervals, 8).max(axis=1)
    return 1.5 * float(np.median(longest))


def _gap_to_samples(t: np.ndarray, targets: np.ndarray) -> np.ndarray:
    """Seconds from each target to the nearest sample."""
    after = np.minimum(np.searchsorted(t, targets), len(t) - 1)
    before = np.maximum(after - 1, 0)
    return np.minimum(np.abs(t[after] - targets), np.abs(targets - t[before]))
