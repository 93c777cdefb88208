"""Joint velocities and accelerations from joint-state messages, one message at a time.

:class:`StreamingEstimator` keeps each joint's recent samples and, for every message, returns the
estimates that message completes: in ``causal`` mode at the newest sample, in ``fixed_lag`` mode
``lag`` seconds back. Two estimators: ``polyfit``, a local polynomial fit (centred in fixed-lag mode
with the default lag, then equal to the whole-recording estimate; one-sided in causal mode), and
``kalman``, a Kalman filter (causal) or fixed-lag smoother on a Gaussian-process motion model
(:mod:`.motion`), accurate at low latency. An estimate is given only where the samples cover what
the estimator needs (:mod:`.coverage`). Bad input never raises; it is dropped and logged (throttled).
"""

from __future__ import annotations

import logging
import math
from collections import deque
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field

import numpy as np

from neforward_ros.errors import InputError
from neforward_ros.estimation import fit
from neforward_ros.estimation.coverage import Support, uncovered
from neforward_ros.estimation.fit import DEFAULT_ORDER, DEFAULT_WINDOW, fit_window, local_difference
from neforward_ros.estimation.kalman import KalmanTrack
from neforward_ros.estimation.motion import KalmanSettings, MotionModel
from neforward_ros.logs import LogFunction, ThrottledLog
from neforward_ros.stamps import NS

METHODS = ("polyfit", "kalman", "difference")
MODES = ("causal", "fixed_lag")
VELOCITY_SOURCES = ("auto", "message", "differentiate")
DEFAULT_MAX_GAP = 0.5
"""Seconds without a sample after which a joint's history restarts."""
DEFAULT_KALMAN_LAG = 0.02
"""The Kalman smoother's default lag, s."""
KALMAN_MIN_SAMPLES = 10
"""Samples a Kalman estimate's support must hold at least (as a degree-4 fit's)."""


@dataclass(frozen=True)
class StreamSettings:
    """Options of :class:`StreamingEstimator`.

    Attributes:
        method: ``"polyfit"`` (local polynomial fit), ``"kalman"`` (Kalman filter or fixed-lag smoother
            on the motion model of ``kalman``) or ``"difference"`` (numpy.gradient twice; a baseline).
        window: polyfit: full width of the local fit, s. kalman: the stretch of recent samples an
            estimate needs before its stamp (its warm-up), s.
        order: polynomial degree (polyfit).
        mode: ``"causal"``: each estimate refers to the newest sample (lowest latency).
            ``"fixed_lag"``: each estimate refers to the sample ``lag`` seconds before the newest and
            is stamped with that sample's stamp.
        lag: fixed-lag delay, s, between 0 and window; None means the method's default: window / 2
            for polyfit and difference (a centred fit, as in the whole-recording estimator),
            :data:`DEFAULT_KALMAN_LAG` for kalman.
        max_gap: a joint whose samples are further apart than this, s, restarts its history.
        velocity_source: ``"auto"`` uses the message's velocities where they are present and
            differentiates positions elsewhere; ``"message"`` expects them (and warns once per
            joint that lacks them); ``"differentiate"`` ignores them. Accelerations are the
            derivative of whichever velocity is used.
        kalman: the Kalman estimator's noise levels and motion model.
    """

    method: str = "polyfit"
    window: float = DEFAULT_WINDOW
    order: int = DEFAULT_ORDER
    mode: str = "fixed_lag"
    lag: float | None = None
    max_gap: float = DEFAULT_MAX_GAP
    velocity_source: str = "auto"
    kalman: KalmanSettings = field(default_factory=KalmanSettings)

    def __post_init__(self) -> None:
        if self.method not in METHODS:
            raise InputError(f"unknown method {self.method!r}; choose one of {', '.join(METHODS)}")
        fit.check_settings("polyfit", self.window, self.order)
        if self.mode not in MODES:
            raise InputError(f"unknown mode {self.mode!r}; choose one of {', '.join(MODES)}")
        if self.velocity_source not in VELOCITY_SOURCES:
            raise InputError(
                f"unknown velocity_source {self.velocity_source!r}; choose one of {', '.join(VELOCITY_SOURCES)}"
            )
        if self.lag is not None and not (isinstance(self.lag, (int, float)) and 0.0 <= self.lag <= self.window):
            raise InputError(f"lag must be between 0 and window ({self.window} s), got {self.lag!r}")
        if not (isinstance(self.max_gap, (int, float)) and self.max_gap > 0.0):
            raise InputError(f"max_gap must be a positive number of seconds, got {self.max_gap!r}")
        if not isinstance(self.kalman, KalmanSettings):
            raise InputError(f"kalman must be KalmanSettings, got {self.kalman!r}")

    @property
    def effective_lag(self) -> float:
        """Seconds between the newest stamp and the stamp an estimate refers to."""
        if self.mode == "causal":
            return 0.0
        if self.lag is not None:
            return float(self.lag)
        return min(DEFAULT_KALMAN_LAG, self.window) if self.method == "kalman" else self.window / 2.0

    def describe(self) -> str:
        """One line: the method, its settings and what an output's stamp refers to."""
        if self.method == "kalman":
            k = self.kalman
            what = (
                f"kalman (noise {k.noise:g}, length_scale {k.length_scale:g} s, magnitude {k.magnitude:g}, "
                f"warm-up {self.window:g} s)"
            )
        elif self.method == "polyfit":
            what = f"polyfit (window {self.window:g} s, degree {self.order})"
        else:
            what = f"difference (window {self.window:g} s)"
        lag = self.effective_lag
        when = (
            "each output at the newest sample, no delay"
            if lag == 0
            else f"each output refers to the sample {lag * 1e3:g} ms before the newest"
        )
        return f"{what}, {self.mode}: {when}"

    @property
    def support(self) -> Support:
        """The samples an estimate needs around its stamp (see :mod:`.coverage`).

        polyfit: its window (ending ``lag`` after the stamp), with at least 2 (order + 1) samples and
        no stretch longer than window / (order + 1) without one. kalman: ``window`` before the stamp
        and ``lag`` after, at least :data:`KALMAN_MIN_SAMPLES` samples, no stretch longer than
        window / 5. difference: the same as kalman, with 5 samples.
        """
        lag = self.effective_lag
        if self.method == "polyfit":
            return Support(self.window - lag, lag, 2 * (self.order + 1), self.window / (self.order + 1))
        before = self.window if self.method == "kalman" or self.mode == "causal" else self.window / 2.0
        return Support(before, lag, KALMAN_MIN_SAMPLES if self.method == "kalman" else 5, self.window / 5.0)


@dataclass(frozen=True)
class JointEstimate:
    """The state of every joint at one stamp.

    Arrays are in the estimator's joint order. A joint that is not ``ready`` has NaN entries: no
    sample yet, none for longer than max_gap, or samples that do not yet cover the estimator's
    support around the stamp (after a start, a restart, a gap or a model reload).

    Attributes:
        stamp_ns: the stamp the estimate refers to, integer nanoseconds (the input's clock).
        segment: counts history restarts caused by time going backwards; stamps increase strictly
            within a segment.
        positions: rad or m.
        velocities: rad/s or m/s.
        accelerations: rad/s^2 or m/s^2.
        ages: seconds from each joint's newest sample at or before the stamp to the stamp.
        ready: per joint, whether the entries are estimates.
        efforts: the efforts the messages carried (N m or N), at the stamp: a sample's own at its
            stamp, else interpolated between the samples around it; NaN where there are none. None
            when not known at all (supplied states without efforts).
    """

    stamp_ns: int
    segment: int
    positions: np.ndarray
    velocities: np.ndarray
    accelerations: np.ndarray
    ages: np.ndarray
    ready: np.ndarray
    efforts: np.ndarray | None = None

    @property
    def all_ready(self) -> bool:
        return bool(np.all(self.ready))


class _Group:
    """Joints that have received exactly the same stamps since their histories last restarted (one
    driver's joints): their samples share one buffer and are fitted together.

    Attributes:
        joints: the joints' indices in the estimator, in the order of the buffer's columns.
        origin: the segment's first stamp; ``seconds`` are counted from it.
    """

    __slots__ = (
        "_efforts",
        "_positions",
        "_seconds",
        "_stamps",
        "_velocities",
        "any_effort",
        "end",
        "holes",
        "intervals",
        "joints",
        "last_without_velocity",
        "origin",
        "slots",
        "start",
        "track",
        "warming",
    )

    def __init__(self, joints: list[int], origin: int, capacity: int = 256, track: KalmanTrack | None = None) -> None:
        self.joints = joints
        self.track = track
        self.holes: list[int] = []  # stamps of samples more than the support's max_hole after the previous one
        self.intervals: deque[int] = deque(maxlen=8)  # the last intervals between samples, ns
        self.warming: bool | str = False  # whether the current warm-up has been logged ("sparse": warned)
        self.slots = {j: k for k, j in enumerate(joints)}
        self.origin = origin
        self._stamps = np.empty(capacity, dtype=np.int64)
        self._seconds = np.empty(capacity)
        self._positions = np.empty((capacity, len(joints)))
        self._velocities = np.empty((capacity, len(joints)))
        self._efforts = np.empty((capacity, len(joints)))
        self.any_effort = False  # whether a message ever gave an effort for these joints
        self.start = 0
        self.end = 0
        self.last_without_velocity = -1  # buffer index of the newest sample that had no velocity at all

    def __len__(self) -> int:
        return self.end - self.start

    @property
    def stamps(self) -> np.ndarray:
        return self._stamps[self.start : self.end]

    @property
    def seconds(self) -> np.ndarray:
        """The stamps as seconds since the segment's first stamp."""
        return self._seconds[self.start : self.end]

    @property
    def positions(self) -> np.ndarray:
        """(count, joints)."""
        return self._positions[self.start : self.end]

    @property
    def velocities(self) -> np.ndarray:
        """(count, joints), NaN where a message gave none."""
        return self._velocities[self.start : self.end]

    @property
    def efforts(self) -> np.ndarray:
        """(count, joints), NaN where a message gave none."""
        return self._efforts[self.start : self.end]

    def end_slack(self) -> int | None:
        """How far, ns, an estimate's support may reach past this group's newest sample: one and a half
        of its longest recent sample intervals (a jittered sample comes a little late)."""
        return 3 * max(self.intervals) // 2 if self.intervals else None

    def velocities_everywhere_after(self, index: int) -> bool:
        """Whether every sample from ``index`` (in the views above) on has some velocity."""
        return self.last_without_velocity < self.start + index

    @property
    def newest_stamp(self) -> int:
        return int(self._stamps[self.end - 1])

    def newest_position(self, joint: int) -> float:
        return float(self._positions[self.end - 1, self.slots[joint]])

    def append(
        self, stamp_ns: int, positions: list[float], velocities: list[float], efforts: list[float], max_hole_ns: int
    ) -> None:
        if self.end == len(self._stamps):
            count = len(self)
            arrays = ("_stamps", "_seconds", "_positions", "_velocities", "_efforts")
            if count > len(self._stamps) // 2:
                for name in arrays:
                    old = getattr(self, name)
                    setattr(self, name, np.concatenate([old, np.empty_like(old)]))
            for name in arrays:
                array = getattr(self, name)
                array[:count] = array[self.start : self.end]
            self.last_without_velocity -= self.start
            self.start, self.end = 0, count
        end = self.end
        if end > self.start:
            interval = stamp_ns - int(self._stamps[end - 1])
            if interval > max_hole_ns:
                self.holes.append(stamp_ns)
            else:
                self.intervals.append(interval)
        self._stamps[end] = stamp_ns
        self._seconds[end] = (stamp_ns - self.origin) / NS
        self._positions[end] = positions
        self._velocities[end] = velocities
        self._efforts[end] = efforts
        if not self.any_effort and any(e == e for e in efforts):  # not all NaN
            self.any_effort = True
        if all(v != v for v in velocities):  # all NaN
            self.last_without_velocity = end
        self.end = end + 1
        if self.track is not None:
            self.track.add(stamp_ns, self._positions[end], self._velocities[end])

    def drop_before(self, stamp_ns: int, keep: int) -> None:
        """Forget samples older than stamp_ns, keeping at least the newest ``keep``."""
        first = self.start + int(np.searchsorted(self.stamps, stamp_ns, side="left"))
        self.start = min(first, max(self.start, self.end - keep))
        oldest = int(self._stamps[self.start])
        if self.holes and self.holes[0] <= oldest:
            self.holes = [h for h in self.holes if h > oldest]

    def split(self, joints: list[int]) -> _Group:
        """Move these joints, with their history, into a group of their own; returns it."""
        columns = [self.slots[j] for j in joints]
        track = self.track.select(columns) if self.track is not None else None
        moved = _Group(joints, self.origin, capacity=max(len(self._stamps), 16), track=track)
        count = len(self)
        moved._stamps[:count] = self.stamps
        moved._seconds[:count] = self.seconds
        moved._positions[:count] = self.positions[:, columns]
        moved._velocities[:count] = self.velocities[:, columns]
        moved._efforts[:count] = self.efforts[:, columns]
        moved.any_effort = self.any_effort
        moved.end = count
        moved.holes = list(self.holes)
        moved.intervals = self.intervals.copy()
        # -1 claims nothing: the velocities of its first windows are checked sample by sample
        moved.last_without_velocity = -1
        self.remove(joints)
        return moved

    def remove(self, joints: list[int]) -> None:
        """Forget these joints."""
        keep = [j for j in self.joints if j not in joints]
        columns = [self.slots[j] for j in keep]
        if self.track is not None:
            self.track = self.track.select(columns)
        self._positions = self._positions[:, columns].copy()
        self._velocities = self._velocities[:, columns].copy()
        self._efforts = self._efforts[:, columns].copy()
        self.joints = keep
        self.slots = {j: k for k, j in enumerate(keep)}


def _effort_at(group: _Group, k: int, target: int) -> np.ndarray:
    """The group's efforts at the target: sample k's at its stamp, else interpolated between k and
    k + 1 when there is a sample after (NaN otherwise, and where a message gave none)."""
    efforts = group.efforts
    stamps = group.stamps
    before = int(stamps[k])
    if target == before or k + 1 >= len(stamps):
        return efforts[k] if target == before else np.full(len(group.joints), np.nan)
    weight = (target - before) / (int(stamps[k + 1]) - before)
    return efforts[k] + weight * (efforts[k + 1] - efforts[k])


class StreamingEstimator:
    """Joint velocities and accelerations from joint-state messages, one message at a time.

    Each joint keeps its own history, so partial messages (arm and gripper from different
    drivers) are fine: joints that always arrive together share a buffer and one fit. Every call
    to :meth:`update` returns the estimates that became available with that message: in causal
    mode, one for the message's stamp (when it is newer than any before); in fixed-lag mode, one
    for every earlier message stamp that is now ``lag`` old.

    Bad input never raises out of :meth:`update`; it is dropped and logged (throttled):
    names/positions of different lengths reject the message; velocities of the wrong length, or
    NaN/inf entries, drop that field; a NaN/inf position drops that joint's sample; unknown names
    are ignored with one warning per name; a repeated stamp is skipped; a stamp going backwards
    restarts the histories (one log line) and starts a new segment; a gap longer than max_gap
    restarts that joint's history; a zero stamp is replaced by the receive time given by the caller
    (logged once).

    Args:
        joint_names: the joints to estimate, in output order.
        wrap: per joint, True for a continuous joint whose positions wrap at +-pi.
        ignored_names: names that may appear in messages and are not estimated, without a warning
            (mimic joints, which follow their leader).
        settings: the estimator's options.
        log: ``log(level, message)``; the Python logger ``neforward_ros`` by default.
    """

    def __init__(
        self,
        joint_names: Sequence[str],
        *,
        wrap: Sequence[bool] | None = None,
        ignored_names: Iterable[str] = (),
        settings: StreamSettings | None = None,
        log: LogFunction | None = None,
    ) -> None:
        self.settings = settings if settings is not None else StreamSettings()
        self.joint_names = tuple(joint_names)
        if len(set(self.joint_names)) != len(self.joint_names):
            raise InputError("joint names must be unique")
        self._index = {name: i for i, name in enumerate(self.joint_names)}
        self._wrap = tuple(bool(w) for w in wrap) if wrap is not None else (False,) * len(self.joint_names)
        if len(self._wrap) != len(self.joint_names):
            raise InputError(f"wrap has {len(self._wrap)} entries for {len(self.joint_names)} joints")
        self._ignored = frozenset(ignored_names)
        self._log = ThrottledLog(log)
        self._last_names: tuple[str, ...] | None = None
        self._last_indices: list[tuple[int, int]] = []
        self._groups: list[_Group] = []
        self._group_of: list[_Group | None] = [None] * len(self.joint_names)
        self._targets = 0
        self._lag_ns = round(self.settings.effective_lag * NS)
        self._gap_ns = round(self.settings.max_gap * NS)
        self._window_ns = round(self.settings.window * NS)
        self._support = self.settings.support
        self._hole_ns = self._support.ns()[2]
        self._motion = MotionModel(self.settings.kalman) if self.settings.method == "kalman" else None
        self._keep_ns = round((self.settings.window + self.settings.effective_lag) * NS) + self._gap_ns
        self._pending: deque[int] = deque()
        self._intervals: deque[int] = deque(maxlen=8)  # the last stamp intervals, ns
        self._clock: int | None = None
        self._origin = 0
        self.segment = 0

    # -- input ------------------------------------------------------------------------------

    def update(
        self,
        stamp_ns: int,
        names: Sequence[str],
        positions: Sequence[float],
        velocities: Sequence[float] = (),
        efforts: Sequence[float] = (),
        *,
        receive_ns: int | None = None,
    ) -> list[JointEstimate]:
        """Add one joint-state message; return the estimates it completes (possibly none).

        Args:
            stamp_ns: header stamp, integer nanoseconds; 0 means "not set".
            names, positions, velocities, efforts: the message's fields (velocities and efforts may
                be empty).
            receive_ns: receive time, used when stamp_ns is 0.
        """
        try:
            return self._update(int(stamp_ns), names, positions, velocities, efforts, receive_ns)
        except Exception as exc:
            self._log.every("internal", logging.ERROR, f"joint state dropped: {type(exc).__name__}: {exc}")
            return []

    def flush(self) -> list[JointEstimate]:
        """The stamps still waiting for their lag (end of a stream, or time going backwards), with no
        estimates: nothing will come after them, so their supports are never covered."""
        n = len(self.joint_names)
        return [
            JointEstimate(
                stamp, self.segment, *(np.full(n, np.nan) for _ in range(3)), self.ages(stamp), np.zeros(n, bool)
            )
            for stamp in self._drain()
        ]

    def reset(self) -> None:
        """Forget every history (a new stream starts)."""
        self._groups = []
        self._group_of = [None] * len(self.joint_names)
        self._pending.clear()
        self._intervals.clear()
        self._clock = None

    def _tolerance(self) -> int:
        """How much earlier than ``lag`` a fixed-lag estimate may leave: half the shortest of the last
        stamp intervals. Stamps jitter, so the sample nominally ``lag`` later often comes a little
        early; waiting for the one after would delay the estimate by a whole period, and then let
        two leave together. The next sample comes later than ``lag`` anyway (it is more than half an
        interval away), so the fit's window holds exactly the samples it would hold then."""
        return min(self._intervals) // 2 if self._lag_ns and self._intervals else 0

    def ages(self, now_ns: int | None = None) -> np.ndarray:
        """Seconds since each joint's newest sample (at ``now_ns``, default the newest stamp); inf if none."""
        now = self._clock if now_ns is None else now_ns
        return np.array(
            [(now - g.newest_stamp) / NS if g is not None and now is not None else np.inf for g in self._group_of]
        )

    def _update(
        self,
        stamp: int,
        names: Sequence[str],
        positions: Sequence[float],
        velocities: Sequence[float],
        efforts: Sequence[float],
        receive_ns: int | None,
    ) -> list[JointEstimate]:
        if stamp <= 0:
            if receive_ns is None or receive_ns <= 0:
                self._log.every("stamp", logging.WARNING, "joint state with a zero stamp and no receive time: dropped")
                return []
            self._log.once(
                "zero-stamp", logging.WARNING, "joint states carry a zero header.stamp; using the receive time instead"
            )
            stamp = int(receive_ns)
        samples = self._read_message(names, positions, velocities, efforts)
        if samples is None:
            return []
        out: list[JointEstimate] = []
        if (
            self._clock is not None
            and stamp < self._clock
            and any(self._group_of[j] is not None and stamp < self._group_of[j].newest_stamp for j, _, _, _ in samples)
        ):
            self._log.every(
                "backwards",
                logging.WARNING,
                f"joint state stamps went back in time by {(self._clock - stamp) / NS:.6f} s "
                "(bag loop or clock reset?): estimator histories restarted",
            )
            out.extend(self.flush())
            self.reset()
            self.segment += 1
        if self._clock is None:
            self._clock = stamp
            self._origin = stamp
            new_target = True
        else:
            new_target = stamp > self._clock
        if not self._add(stamp, samples):
            return out
        if new_target:
            if self._pending or self._targets:
                self._intervals.append(stamp - self._clock)
            self._clock = stamp
            self._pending.append(stamp)
            out.extend(self._estimate(target) for target in self._drain(stamp - self._lag_ns + self._tolerance()))
            self._targets += 1
            if self._targets % 32 == 0:  # forget old samples now and then
                for group in self._groups:
                    group.drop_before(stamp - self._keep_ns, self.settings.order + 2)
        return out

    def _read_message(
        self, names: Sequence[str], positions: Sequence[float], velocities: Sequence[float], efforts: Sequence[float]
    ) -> list[tuple[int, float, float, float]] | None:
        """The message's usable samples as (joint index, position, velocity or NaN, effort or NaN);
        None rejects it."""
        count = len(names)
        if len(positions) != count:
            self._log.every(
                "length", logging.WARNING, f"joint state rejected: {count} names but {len(positions)} positions"
            )
            return None
        position = self._floats(positions, "positions", count)
        if position is None:
            return None
        velocity = self._floats(velocities, "velocities", count)
        if velocity is None or self.settings.velocity_source == "differentiate":
            velocity = [math.nan] * count
        elif not all(math.isfinite(v) for v in velocity):
            self._log.every(("nan", "velocities"), logging.WARNING, "joint state with non-finite velocities: dropped")
            velocity = [v if math.isfinite(v) else math.nan for v in velocity]
        effort = self._floats(efforts, "efforts", count) if len(efforts) else None
        if effort is None:
            effort = [math.nan] * count
        elif not math.isfinite(sum(effort)):
            self._log.every(("nan", "efforts"), logging.WARNING, "joint state with non-finite efforts: dropped")
            effort = [e if math.isfinite(e) else math.nan for e in effort]
        indices = self._indices(names)
        if math.isfinite(sum(position)):  # the usual case: every position is a number (inf - inf is NaN)
            return [(j, position[k], velocity[k], effort[k]) for k, j in indices]
        samples = []
        for k, j in indices:
            if not math.isfinite(position[k]):
                name = self.joint_names[j]
                self._log.every(("nan", name), logging.WARNING, f"joint {name!r}: non-finite position, sample dropped")
                continue
            samples.append((j, position[k], velocity[k], effort[k]))
        return samples

    def _indices(self, names: Sequence[str]) -> list[tuple[int, int]]:
        """(position in the message, joint index) of the names this estimator knows; unknown names
        warned about once each. Kept for the last names seen: a driver sends the same ones."""
        key = tuple(names)
        if key != self._last_names:
            indices = []
            for k, name in enumerate(key):
                j = self._index.get(name)
                if j is not None:
                    indices.append((k, j))
                elif name not in self._ignored:
                    self._log.once(
                        ("unknown", name), logging.WARNING, f"joint state names unknown joint {name!r}, ignored"
                    )
            self._last_names, self._last_indices = key, indices
        return self._last_indices

    def _floats(self, values: Sequence[float], what: str, count: int) -> list[float] | None:
        """A message field as floats; None (logged) when it is empty, of the wrong length or not numbers."""
        if len(values) == 0:
            return None
        if len(values) != count:
            self._log.every(
                ("length", what), logging.WARNING, f"joint state {what} ignored: {len(values)} values for {count} names"
            )
            return None
        try:
            if isinstance(values, np.ndarray) and values.dtype.kind == "f":
                return values.tolist()
            return [float(v) for v in values]
        except (TypeError, ValueError):
            self._log.every(("type", what), logging.WARNING, f"joint state {what} are not numbers: ignored")
            return None

    def _add(self, stamp: int, samples: list[tuple[int, float, float, float]]) -> bool:
        """Append one message's samples to their groups; returns whether any was added.

        A repeated stamp is skipped. A joint whose previous sample is newer, or more than max_gap
        older, restarts its history. Joints of a group that arrive without the rest of it move,
        with their history, into a group of their own.
        """
        by_group: dict[int, tuple[_Group, dict[int, tuple[float, float, float]]]] = {}
        fresh: dict[int, tuple[float, float, float]] = {}
        restarted: list[str] = []
        for j, position, velocity, effort in samples:
            group = self._group_of[j]
            if self.settings.velocity_source == "message" and math.isnan(velocity):
                self._log.once(
                    ("no-velocity", j),
                    logging.WARNING,
                    f"velocity_source is 'message' but joint {self.joint_names[j]!r} has no velocity: differentiating",
                )
            if group is not None:
                newest = group.newest_stamp
                if stamp == newest:
                    continue
                if stamp < newest:
                    reason = "sample older than the previous one"
                elif stamp - newest > self._gap_ns:
                    reason = f"no sample for {(stamp - newest) / NS:.3f} s, more than max_gap {self.settings.max_gap} s"
                else:
                    if self._wrap[j]:
                        previous = group.newest_position(j)
                        position = previous + (position - previous + math.pi) % (2.0 * math.pi) - math.pi
                    by_group.setdefault(id(group), (group, {}))[1][j] = (position, velocity, effort)
                    continue
                restarted.append(f"{self.joint_names[j]!r} ({reason})")
                self._forget(group, [j])
            fresh[j] = (position, velocity, effort)
        if restarted:
            self._log.every("restart", logging.WARNING, f"history restarted for joint {', '.join(restarted)}")
        for group, values in by_group.values():
            if len(values) < len(group.joints):
                group = self._split(group, [j for j in group.joints if j in values])
            columns = [values[j] for j in group.joints]
            group.append(stamp, *(list(x) for x in zip(*columns, strict=True)), self._hole_ns)
        if fresh:
            track = KalmanTrack(self._motion, smooth=self._lag_ns > 0) if self._motion is not None else None
            group = _Group(sorted(fresh), self._origin, track=track)
            self._groups.append(group)
            for j in group.joints:
                self._group_of[j] = group
            columns = [fresh[j] for j in group.joints]
            group.append(stamp, *(list(x) for x in zip(*columns, strict=True)), self._hole_ns)
        return bool(by_group or fresh)

    def _forget(self, group: _Group, joints: list[int]) -> None:
        group.remove(joints)
        for j in joints:
            self._group_of[j] = None
        if not group.joints:
            self._groups.remove(group)

    def _split(self, group: _Group, joints: list[int]) -> _Group:
        moved = group.split(joints)
        self._groups.append(moved)
        for j in joints:
            self._group_of[j] = moved
        return moved

    def _drain(self, until_ns: int | None = None) -> list[int]:
        targets = []
        while self._pending and (until_ns is None or self._pending[0] <= until_ns):
            targets.append(self._pending.popleft())
        return targets

    # -- estimation -------------------------------------------------------------------------

    def _estimate(self, target: int) -> JointEstimate:
        n = len(self.joint_names)
        state = np.full((n, 4), np.nan)  # position, velocity, acceleration, effort
        ages = np.full(n, np.inf)
        for group in self._groups:
            self._estimate_group(target, group, state, ages)
            if group.track is not None:
                group.track.forget_before(target)
        ready = np.isfinite(state[:, :3]).all(axis=1)
        if not ready.all():
            state[~ready, :3] = np.nan
        return JointEstimate(target, self.segment, state[:, 0], state[:, 1], state[:, 2], ages, ready, state[:, 3])

    def _estimate_group(self, target: int, group: _Group, state: np.ndarray, ages: np.ndarray) -> None:
        """Fill state (n, 3) and ages (n,) at the target for one group's joints, if its samples cover
        the support there (else say once why, and leave them NaN).

        Only the samples of the fit's window are touched, however long the kept history is. polyfit:
        joints whose window has a velocity in every sample are fitted on velocities (the acceleration
        is their derivative); the others on positions. At a sample's own stamp the sample's position,
        and its velocity when the message gave one, are used as they are.
        """
        members = group.joints
        stamps = group.stamps
        k = int(stamps.searchsorted(target, side="right")) - 1
        if k < 0:
            return
        age_ns = target - int(stamps[k])
        ages[members] = age_ns / NS
        if age_ns > self._gap_ns:
            return  # stale: not ready
        if group.any_effort:
            state[members, 3] = _effort_at(group, k, target)
        reason = uncovered(stamps, target, self._support, group.holes, group.end_slack())
        if reason is not None:
            self._say_why(group, reason)
            return
        group.warming = False
        exact = age_ns == 0  # the target is a sample of this group: its own position is used as it is
        if group.track is not None:
            position, velocity, acceleration = group.track.estimate(target)
        else:
            position, velocity, acceleration = self._fit(target, group, exact)
        if exact:
            position = group.positions[k]
            given = group.velocities[k]
            velocity = np.where(np.isfinite(given), given, velocity)  # a message velocity is kept as given
        state[members, 0], state[members, 1], state[members, 2] = position, velocity, acceleration

    def _fit(self, target: int, group: _Group, exact: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """polyfit or difference over the support's samples (covered): position, velocity, acceleration."""
        settings = self.settings
        stamps = group.stamps
        lead_ns = self._lag_ns
        lo = int(stamps.searchsorted(target + lead_ns - self._window_ns, side="left"))
        hi = int(stamps.searchsorted(target + lead_ns, side="right"))
        positions, velocities = group.positions[lo:hi], group.velocities[lo:hi]
        by_velocity = np.zeros(len(group.joints), dtype=bool)
        if group.velocities_everywhere_after(lo):
            by_velocity = np.isfinite(velocities).all(axis=0)
        fitted_velocities = bool(by_velocity.any())
        times = group.seconds[lo:hi]
        target_s = (target - self._origin) / NS
        if fitted_velocities and exact:
            # One column per joint: its velocities where it has them all, else its positions.
            values = np.where(by_velocity, velocities, positions)
        elif fitted_velocities:  # positions are fitted too, to be estimated between samples
            values = np.concatenate([positions, velocities[:, by_velocity]], axis=1)
        else:
            values = positions
        if settings.method == "difference":
            fitted, d1, d2 = local_difference(times, values, target_s, lead_ns / NS)
        else:
            fitted, d1, d2 = fit_window(times, values, target_s, settings.window / 2.0, settings.order)
        m = len(group.joints)
        if fitted_velocities and exact:
            return fitted, np.where(by_velocity, fitted, d1), np.where(by_velocity, d1, d2)
        velocity, acceleration = d1[:m], d2[:m]
        if fitted_velocities:
            velocity, acceleration = velocity.copy(), acceleration.copy()
            velocity[by_velocity], acceleration[by_velocity] = fitted[m:], d1[m:]
        return fitted[:m], velocity, acceleration

    def _say_why(self, group: _Group, reason: str) -> None:
        """Log once per warm-up (throttled) why a group's joints have no estimate; warn once per group
        when its samples are too sparse for the support ever to be covered."""
        support = self._support
        names = ", ".join(self.joint_names[j] for j in group.joints)
        where = f"[stamp - {support.before:g} s, stamp + {support.after:g} s]"
        recent = np.diff(group.stamps[-17:])
        interval = float(np.median(recent)) / NS if len(recent) >= 8 else 0.0
        needed = max(support.min_samples * interval, support.span * interval / support.max_hole) * 1.1
        if interval and needed > support.span:  # even a steady stream cannot cover the support
            if group.warming == "sparse":
                return
            group.warming = "sparse"
            self._log.every(
                ("coverage", "sparse", tuple(group.joints)),
                logging.WARNING,
                f"no estimate for joint(s) {names}: a sample every {interval * 1e3:.3g} ms is too sparse for the "
                f"estimator (at least {support.min_samples} samples in {where}, none more than "
                f"{support.max_hole:g} s apart); increase estimator.window to at least {needed:.2g} s",
            )
            return
        if group.warming:
            return
        group.warming = True
        self._log.every(
            ("coverage", "warm-up", tuple(group.joints)),
            logging.INFO,
            f"no estimate yet for joint(s) {names} ({reason}): estimates start where their samples cover "
            f"{where}, at least {support.min_samples} of them, none more than {support.max_hole:g} s apart "
            "(after a start, a restart, a gap or a model reload)",
        )
