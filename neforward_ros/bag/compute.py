"""From a recording's joint samples to the node's results: segments, whole-recording estimates, and
the batched recursion, a chunk of samples at a time (memory stays bounded for long recordings)."""

from __future__ import annotations

import itertools
from collections.abc import Callable, Iterator
from dataclasses import dataclass, replace

import numpy as np

from neforward_ros.bag.base import BaseAtStamps, base_at, root_states
from neforward_ros.bag.options import BagOptions
from neforward_ros.bag.read import Recording
from neforward_ros.bag.report import Segment
from neforward_ros.dynamics import split_values, wrenches_from_table
from neforward_ros.estimation.batch import estimate_at
from neforward_ros.estimation.coverage import covered_mask
from neforward_ros.estimation.settings import StreamSettings
from neforward_ros.estimation.stream import StreamingEstimator
from neforward_ros.logs import ThrottledLog
from neforward_ros.model import RobotModel
from neforward_ros.node.contact import ContactDetector
from neforward_ros.node.policy import apply_policy, hold_vector
from neforward_ros.node.result import Dynamics, Result, make_result
from neforward_ros.recursion import kinematics_table, root_state
from neforward_ros.stamps import NS

CHUNK = 8192
"""Samples per batched recursion: bounds the memory of every later stage at a few MB per link."""


@dataclass
class States:
    """The estimated joint states of every output sample, concatenated over segments.

    Attributes:
        stamps: (T,) the samples' stamps, integer ns; log_times: (T,) their recording times.
        q, qd, qdd: (T, n) in the model's joint order; zeros where a joint has nothing.
        known: (T, n) whether each joint's state is an estimate (or held, under ``hold``).
        efforts: (T, n) the recorded efforts at each stamp (interpolated between a joint's samples),
            NaN where there are none.
        root: (T, 12) the root's state for a moving base (see :mod:`neforward_ros.bag.base`); None
            for a fixed base.
        world_rotation, world_position: (T, 3, 3) root -> world and (T, 3), for a moving base.
    """

    stamps: np.ndarray
    log_times: np.ndarray
    q: np.ndarray
    qd: np.ndarray
    qdd: np.ndarray
    known: np.ndarray
    efforts: np.ndarray
    root: np.ndarray | None = None
    world_rotation: np.ndarray | None = None
    world_position: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.stamps)


def results(
    model: RobotModel, states: States, options: BagOptions, chunk: int | None = None
) -> Iterator[tuple[Result, np.ndarray]]:
    """(result, recording times) of consecutive chunks of the samples, each from one batched recursion
    (and, when the options ask for torques, wrenches or contact, one batched backward pass)."""
    settings = options.settings
    root = root_state(settings.gravity)
    chunk = CHUNK if chunk is None else chunk
    scale = np.array([settings.effort_scale.get(n, 1.0) for n in model.joint_names])
    offset = np.array([settings.effort_offset.get(n, 0.0) for n in model.joint_names])
    detector = None
    if settings.contact_thresholds:
        thresholds = np.array([settings.contact_thresholds.get(n, np.nan) for n in model.joint_names])
        detector = ContactDetector(thresholds, settings.contact_debounce, model.joint_names, ThrottledLog())
    for start in range(0, len(states), chunk):
        part = slice(start, start + chunk)
        q = states.q[part]
        chunk_root = root if states.root is None else list(states.root[part].T)
        table = kinematics_table(model, q, states.qd[part], states.qdd[part], chunk_root)
        known = states.known[part]
        result = make_result(model, states.stamps[part], table, model.determined_links(known))
        if states.world_rotation is not None and settings.world_frame:
            result = replace(result, world=(states.world_rotation[part], states.world_position[part]))
        if options.dynamics_needed:
            force, moment, torques = split_values(model, wrenches_from_table(model, q, table))
            complete = known.all(axis=1)
            torques = np.where(complete[:, None], torques, np.nan)  # no dynamics where a joint has no state
            measured = scale * states.efforts[part] + offset
            dynamics = Dynamics(model.joint_names, q, states.qd[part], torques, measured, force, moment)
            contact = None
            if detector is not None:
                external = dynamics.external
                contact = np.full(len(q), np.nan)
                for i in np.flatnonzero(complete):
                    state = detector.update(int(states.stamps[part][i]), external[i])
                    contact[i] = np.nan if state is None else float(state)
            result = replace(result, dynamics=dynamics, contact=contact)
        yield result, states.log_times[part]


def _segments(recording: Recording) -> list[tuple[int, int]]:
    """Message index ranges [start, stop) of the segments: a new one after each time reset (the
    node's stamp rules, :mod:`neforward_ros.estimation.timeline`, sorted them out when reading)."""
    edges = [0, *(int(k) for k in recording.report.segment_starts), len(recording.stamps)]
    return [(a, b) for a, b in itertools.pairwise(edges) if b > a]


def estimate_states(recording: Recording, options: BagOptions, progress: Callable[[str, float], None]) -> States:
    """Each segment's joint states at every message stamp, from the whole-recording estimator.

    As in the node, a joint has an estimate at a stamp only where its samples cover the estimator's
    support there (:mod:`neforward_ros.estimation.coverage`, the fixed-lag fit's) and none is more
    than max_gap away; the publish policy (:mod:`neforward_ros.node.policy`) then says what is
    written for stamps where some joints have none.
    """
    settings = options.settings
    model = recording.model
    hold = hold_vector(model.joint_names, settings.hold_positions)
    n = len(model.joint_names)
    pieces: list[tuple[np.ndarray, ...]] = []
    ranges = _segments(recording)
    for number, (start, stop) in enumerate(ranges):
        progress("estimating", number / len(ranges))
        segment_stamps = recording.stamps[start:stop]
        segment = Segment(int(segment_stamps.min()), int(segment_stamps.max()), stop - start)
        recording.report.segments.append(segment)
        targets, first = np.unique(segment_stamps, return_index=True)
        if options.streamed:
            state, efforts, silent, absent = _replayed(recording, start, stop, targets, settings.estimator)
        else:
            state, efforts, silent, absent = _whole(recording, start, stop, targets, options)
        if absent:
            segment.note = f"too few samples of {', '.join(absent)} for an estimate"
        known = np.all(np.isfinite(state), axis=0)
        published = apply_policy(settings.publish_policy, *state, known, silent, hold)
        ok = published.publish
        base = None
        if recording.base is not None:  # a moving base: its motion at these stamps, from the base topic
            at = base_at(recording.base, targets, options)
            link = settings.base_link or recording.base.frame_id
            ok &= at.ok & model.determined_links(published.known)[:, model.link_index[link]]
            rows = np.flatnonzero(ok)
            picked = BaseAtStamps(
                at.ok[rows],
                *(None if x is None else x[rows] for x in (at.omega, at.alpha, at.specific_force, at.velocity)),
                at.orientation[rows],
                at.position[rows],
            )
            base = root_states(model, link, published.q[rows], published.qd[rows], published.qdd[rows], picked)
        segment.skipped = int(np.count_nonzero(~ok))
        segment.samples_out = int(np.count_nonzero(ok))
        segment.partial = int(np.count_nonzero(ok & ~published.known.all(axis=1)))
        log_times = recording.log_times[start:stop][first]
        pieces.append(
            (
                targets[ok],
                log_times[ok],
                published.q[ok],
                published.qd[ok],
                published.qdd[ok],
                published.known[ok],
                efforts[ok],
                *(base if base is not None else (None, None, None)),
            )
        )
    progress("estimating", 1.0)
    if not pieces:
        stamps = np.zeros(0, dtype=np.int64)
        zeros = np.zeros((0, n))
        pieces = [(stamps, stamps, zeros, zeros, zeros, zeros.astype(bool), zeros, None, None, None)]
    return States(*(None if parts[0] is None else np.concatenate(parts) for parts in zip(*pieces, strict=True)))


def _whole(
    recording: Recording, start: int, stop: int, targets: np.ndarray, options: BagOptions
) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[str]]:
    """One segment's (q, qd, qdd) (3, T, n), efforts (T, n), silent (T, n) and the joints with too few
    samples, from the whole-recording estimator at the stamps ``targets``."""
    model, settings = recording.model, options.settings
    n = len(model.joint_names)
    wrap = model.continuous_columns
    batch = options.batch_estimator
    support = batch.support
    origin = int(targets[0])
    target_s = (targets - origin) / NS
    state = np.full((3, len(targets), n), np.nan)
    efforts = np.full((len(targets), n), np.nan)
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
        efforts[:, j] = _efforts_at(t_ns, es[inside][keep], targets)
        if len(t_ns) < support.min_samples:
            absent.append(model.joint_names[j])
            continue
        q = qs[inside][keep]
        if wrap[j]:
            q = np.unwrap(q)
        v = vs[inside][keep]
        use_velocity = settings.estimator.velocity_source != "differentiate" and bool(np.all(np.isfinite(v)))
        groups.setdefault((t_ns.tobytes(), use_velocity), []).append((j, q, v))
    absent += [model.joint_names[j] for j in range(n) if j not in recording.columns]
    for (t_bytes, use_velocity), members in groups.items():
        t = (np.frombuffer(t_bytes, dtype=np.int64) - origin) / NS
        joints = [j for j, _, _ in members]
        q_at, qd_at, qdd_at = estimate_at(
            t,
            np.stack([q for _, q, _ in members], axis=1),
            target_s,
            velocity=np.stack([v for _, _, v in members], axis=1) if use_velocity else None,
            method=batch.method,
            window=batch.window,
            order=batch.order,
        )
        stale = _gap_to_samples(t, target_s) > settings.estimator.max_gap
        silent[:, joints] = stale[:, None]
        unready = stale | ~covered_mask(t, target_s, support, _end_slack(t)) | ~reached
        for column, values in enumerate((q_at, qd_at, qdd_at)):
            values[unready] = np.nan
            state[column][:, joints] = values
    return state, efforts, silent, sorted(set(absent))


def _replayed(
    recording: Recording, start: int, stop: int, targets: np.ndarray, estimator: StreamSettings
) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[str]]:
    """As :func:`_whole`, by replaying the segment's messages through the node's streaming estimator
    (causal mode, another lag, kalman): each stamp gets exactly what the node would have published."""
    model = recording.model
    n = len(model.joint_names)
    count = stop - start
    q, v, e = (np.full((count, n), np.nan) for _ in range(3))
    present = np.zeros((count, n), dtype=bool)
    for j, (rows, qs, vs, es) in recording.columns.items():
        inside = (rows >= start) & (rows < stop)
        at = rows[inside] - start
        present[at, j] = True
        q[at, j], v[at, j], e[at, j] = qs[inside], vs[inside], es[inside]
    stream = StreamingEstimator(
        model.joint_names,
        wrap=model.continuous_columns,
        ignored_names=model.mimic_joint_names,
        settings=estimator,
        log=lambda level, message: None,  # the report says what the node would have logged
    )
    names = np.array(model.joint_names, dtype=object)
    state = np.full((3, len(targets), n), np.nan)
    efforts = np.full((len(targets), n), np.nan)
    silent = np.ones((len(targets), n), dtype=bool)
    seen = np.zeros(n, dtype=bool)
    stamps = recording.stamps[start:stop].tolist()
    estimates = []
    for m, stamp in enumerate(stamps):
        joints = np.flatnonzero(present[m])
        seen[joints] = True
        velocities = v[m, joints]
        measured = e[m, joints]
        estimates += stream.update(
            stamp,
            names[joints].tolist(),
            q[m, joints].tolist(),
            velocities.tolist() if np.isfinite(velocities).all() else (),
            measured.tolist() if np.isfinite(measured).all() else (),
        )
    estimates += stream.flush()
    index = {stamp: k for k, stamp in enumerate(targets.tolist())}
    for estimate in estimates:
        k = index.get(estimate.stamp_ns)
        if k is None:
            continue
        ready = estimate.ready
        for column, values in enumerate((estimate.positions, estimate.velocities, estimate.accelerations)):
            state[column, k] = np.where(ready, values, np.nan)
        if estimate.efforts is not None:
            efforts[k] = estimate.efforts
        silent[k] = ~(estimate.ages <= estimator.max_gap)
    absent = [model.joint_names[j] for j in range(n) if not seen[j]]
    return state, efforts, silent, absent


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
