"""Joint velocities and accelerations from joint-state messages, one message at a time.

:class:`StreamingEstimator` keeps each joint's recent samples and, for every message, returns the
estimates that message completes: in ``causal`` mode at the newest sample (a one-sided fit), in
``fixed_lag`` mode ``lag`` seconds back (a centred fit, equal to the whole-recording estimate).
Bad input never raises; it is dropped and logged (throttled).
"""

from __future__ import annotations

import logging
import math
from collections import deque
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import numpy as np

from neforward_ros.errors import InputError
from neforward_ros.estimation.fit import (
    DEFAULT_ORDER,
    DEFAULT_WINDOW,
    check_settings,
    fit_at,
    local_difference,
)
from neforward_ros.logs import LogFunction, ThrottledLog
from neforward_ros.stamps import NS

MODES = ("causal", "fixed_lag")
VELOCITY_SOURCES = ("auto", "message", "differentiate")
DEFAULT_MAX_GAP = 0.5
"""Seconds without a sample after which a joint's history restarts."""


@dataclass(frozen=True)
class StreamSettings:
    """Options of :class:`StreamingEstimator`.

    Attributes:
        method: ``"polyfit"`` or ``"difference"``, as for :func:`estimate_derivatives`.
        window: full width of the local fit, s.
        order: polynomial degree (polyfit).
        mode: ``"causal"``: each estimate refers to the newest sample, fitted on the ``window``
            seconds before it (lowest latency). ``"fixed_lag"``: each estimate refers to the sample
            ``lag`` seconds before the newest and is stamped with that sample's stamp; with the
            default lag of window / 2 the fit is centred, as in the whole-recording estimator.
        lag: fixed-lag delay, s, between 0 and window; None means window / 2.
        max_gap: a joint whose samples are further apart than this, s, restarts its history.
        velocity_source: ``"auto"`` uses the message's velocities where they are present and
            differentiates positions elsewhere; ``"message"`` expects them (and warns once per
            joint that lacks them); ``"differentiate"`` ignores them. Accelerations are the
            derivative of whichever velocity is used. Supplied accelerations bypass estimation.
    """

    method: str = "polyfit"
    window: float = DEFAULT_WINDOW
    order: int = DEFAULT_ORDER
    mode: str = "fixed_lag"
    lag: float | None = None
    max_gap: float = DEFAULT_MAX_GAP
    velocity_source: str = "auto"

    def __post_init__(self) -> None:
        check_settings(self.method, self.window, self.order)
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

    @property
    def effective_lag(self) -> float:
        """Seconds between the newest stamp and the stamp an estimate refers to."""
        if self.mode == "causal":
            return 0.0
        return self.window / 2.0 if self.lag is None else float(self.lag)


@dataclass(frozen=True)
class JointEstimate:
    """The state of every joint at one stamp.

    Arrays are in the estimator's joint order. A joint that is not ``ready`` (no sample yet, too
    few samples since its history restarted, or none for longer than max_gap) has NaN entries.

    Attributes:
        stamp_ns: the stamp the estimate refers to, integer nanoseconds (the input's clock).
        segment: counts history restarts caused by time going backwards; stamps increase strictly
            within a segment.
        positions: rad or m.
        velocities: rad/s or m/s.
        accelerations: rad/s^2 or m/s^2.
        ages: seconds from each joint's newest sample at or before the stamp to the stamp.
        ready: per joint, whether the entries are estimates.
    """

    stamp_ns: int
    segment: int
    positions: np.ndarray
    velocities: np.ndarray
    accelerations: np.ndarray
    ages: np.ndarray
    ready: np.ndarray

    @property
    def all_ready(self) -> bool:
        return bool(np.all(self.ready))


class _History:
    """One joint's samples since its last restart: stamps (ns), positions, velocities, accelerations."""

    __slots__ = ("_data", "_stamps", "end", "start")

    def __init__(self, capacity: int = 256) -> None:
        self._stamps = np.empty(capacity, dtype=np.int64)
        self._data = np.empty((capacity, 3))
        self.start = 0
        self.end = 0

    def __len__(self) -> int:
        return self.end - self.start

    @property
    def stamps(self) -> np.ndarray:
        return self._stamps[self.start : self.end]

    @property
    def data(self) -> np.ndarray:
        """(count, 3): position, velocity (NaN if not given), acceleration (NaN if not given)."""
        return self._data[self.start : self.end]

    @property
    def newest_stamp(self) -> int:
        return int(self._stamps[self.end - 1])

    @property
    def newest_position(self) -> float:
        return float(self._data[self.end - 1, 0])

    def clear(self) -> None:
        self.start = self.end = 0

    def append(self, stamp_ns: int, position: float, velocity: float, acceleration: float) -> None:
        if self.end == len(self._stamps):
            count = len(self)
            if count > len(self._stamps) // 2:
                self._stamps = np.concatenate([self._stamps, np.empty_like(self._stamps)])
                self._data = np.concatenate([self._data, np.empty_like(self._data)])
            self._stamps[:count] = self._stamps[self.start : self.end]
            self._data[:count] = self._data[self.start : self.end]
            self.start, self.end = 0, count
        self._stamps[self.end] = stamp_ns
        self._data[self.end] = (position, velocity, acceleration)
        self.end += 1

    def drop_before(self, stamp_ns: int, keep: int) -> None:
        """Forget samples older than stamp_ns, keeping at least the newest ``keep``."""
        first = self.start + int(np.searchsorted(self.stamps, stamp_ns, side="left"))
        self.start = min(first, max(self.start, self.end - keep))


class StreamingEstimator:
    """Joint velocities and accelerations from joint-state messages, one message at a time.

    Each joint keeps its own history, so partial messages (arm and gripper from different
    drivers) are fine. Every call to :meth:`update` returns the estimates that became available
    with that message: in causal mode, one for the message's stamp (when it is newer than any
    before); in fixed-lag mode, one for every earlier message stamp that is now ``lag`` old.

    Bad input never raises out of :meth:`update`; it is dropped and logged (throttled):
    names/positions of different lengths reject the message; velocities or accelerations of the
    wrong length, or NaN/inf entries, drop that field; a NaN/inf position drops that joint's sample;
    unknown names are ignored with one warning per name; a repeated stamp is skipped; a stamp going
    backwards restarts the histories (one log line) and starts a new segment; a gap longer than
    max_gap restarts that joint's history; a zero stamp is replaced by the receive time given by the
    caller (logged once).

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
        self._histories = [_History() for _ in self.joint_names]
        # Joints with the same lineage have received exactly the same stamps since their histories
        # last restarted (one driver's joints), so they are fitted together. 0: empty history.
        self._lineage = [0] * len(self.joint_names)
        self._lineages = 0
        self._targets = 0
        self._lag_ns = round(self.settings.effective_lag * NS)
        self._gap_ns = round(self.settings.max_gap * NS)
        self._keep_ns = round((self.settings.window + self.settings.effective_lag) * NS) + self._gap_ns
        self._pending: deque[int] = deque()
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
        accelerations: Sequence[float] = (),
        *,
        receive_ns: int | None = None,
    ) -> list[JointEstimate]:
        """Add one joint-state message; return the estimates it completes (possibly none).

        Args:
            stamp_ns: header stamp, integer nanoseconds; 0 means "not set".
            names, positions, velocities, accelerations: the message's fields (the last two may
                be empty).
            receive_ns: receive time, used when stamp_ns is 0.
        """
        try:
            return self._update(int(stamp_ns), names, positions, velocities, accelerations, receive_ns)
        except Exception as exc:
            self._log.every("internal", logging.ERROR, f"joint state dropped: {type(exc).__name__}: {exc}")
            return []

    def flush(self) -> list[JointEstimate]:
        """Estimates for the stamps still waiting for their lag (end of a stream), from what is there."""
        return [self._estimate(stamp) for stamp in self._drain()]

    def reset(self) -> None:
        """Forget every history (a new stream starts)."""
        for history in self._histories:
            history.clear()
        self._lineage = [0] * len(self.joint_names)
        self._pending.clear()
        self._clock = None

    def ages(self, now_ns: int | None = None) -> np.ndarray:
        """Seconds since each joint's newest sample (at ``now_ns``, default the newest stamp); inf if none."""
        now = self._clock if now_ns is None else now_ns
        return np.array(
            [(now - h.newest_stamp) / NS if len(h) and now is not None else np.inf for h in self._histories]
        )

    def _update(
        self,
        stamp: int,
        names: Sequence[str],
        positions: Sequence[float],
        velocities: Sequence[float],
        accelerations: Sequence[float],
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
        samples = self._read_message(names, positions, velocities, accelerations)
        if samples is None:
            return []
        out: list[JointEstimate] = []
        if (
            self._clock is not None
            and stamp < self._clock
            and any(len(self._histories[j]) and stamp < self._histories[j].newest_stamp for j, *_ in samples)
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
        added = False
        restarted: list[str] = []
        successors: dict[int, int] = {}
        for j, position, velocity, acceleration in samples:
            result = self._add(j, stamp, position, velocity, acceleration)
            if result is None:
                continue
            added = True
            if result:
                restarted.append(f"{self.joint_names[j]!r} ({result})")
            before = -1 if result else self._lineage[j]  # -1: restarted in this message
            if before not in successors:
                self._lineages += 1
                successors[before] = self._lineages
            self._lineage[j] = successors[before]
        if restarted:
            self._log.every("restart", logging.WARNING, f"history restarted for joint {', '.join(restarted)}")
        if not added:
            return out
        if new_target:
            self._clock = stamp
            self._pending.append(stamp)
            out.extend(self._estimate(target) for target in self._drain(stamp - self._lag_ns))
            self._targets += 1
            if self._targets % 32 == 0:  # forget old samples now and then; joints of one lineage alike
                for history in self._histories:
                    history.drop_before(stamp - self._keep_ns, self.settings.order + 2)
        return out

    def _read_message(
        self,
        names: Sequence[str],
        positions: Sequence[float],
        velocities: Sequence[float],
        accelerations: Sequence[float],
    ) -> list[tuple[int, float, float, float]] | None:
        """The message's usable samples as (joint index, position, velocity, acceleration); None rejects it."""
        count = len(names)
        if len(positions) != count:
            self._log.every(
                "length", logging.WARNING, f"joint state rejected: {count} names but {len(positions)} positions"
            )
            return None
        position = self._floats(positions, "positions", count)
        if position is None:
            return None
        given = np.full((count, 2), np.nan)
        for column, (values, what) in enumerate(((velocities, "velocities"), (accelerations, "accelerations"))):
            field = self._floats(values, what, count)
            if field is None:
                continue
            if not np.all(np.isfinite(field)):
                self._log.every(("nan", what), logging.WARNING, f"joint state with non-finite {what}: those dropped")
            given[:, column] = field
        given[~np.isfinite(given)] = np.nan
        if self.settings.velocity_source == "differentiate":
            given[:, 0] = np.nan
        velocity, acceleration = given.T.tolist()
        position = position.tolist()
        samples = []
        for k, name in enumerate(names):
            j = self._index.get(name)
            if j is None:
                if name not in self._ignored:
                    self._log.once(
                        ("unknown", name), logging.WARNING, f"joint state names unknown joint {name!r}, ignored"
                    )
                continue
            if not math.isfinite(position[k]):
                self._log.every(("nan", name), logging.WARNING, f"joint {name!r}: non-finite position, sample dropped")
                continue
            samples.append((j, position[k], velocity[k], acceleration[k]))
        return samples

    def _floats(self, values: Sequence[float], what: str, count: int) -> np.ndarray | None:
        """A message field as floats; None (logged) when it is empty, of the wrong length or not numbers."""
        if len(values) == 0:
            return None
        if len(values) != count:
            self._log.every(
                ("length", what), logging.WARNING, f"joint state {what} ignored: {len(values)} values for {count} names"
            )
            return None
        try:
            return np.asarray(values, dtype=float).reshape(count)
        except (TypeError, ValueError):
            self._log.every(("type", what), logging.WARNING, f"joint state {what} are not numbers: ignored")
            return None

    def _add(self, j: int, stamp: int, position: float, velocity: float, acceleration: float) -> str | None:
        """Append one sample. Returns None for a duplicate (skipped), else why the history restarted, or ''."""
        history = self._histories[j]
        restarted = ""
        if len(history):
            newest = history.newest_stamp
            if stamp == newest:
                return None
            if stamp < newest:
                restarted = "sample older than the previous one"
                history.clear()
            elif stamp - newest > self._gap_ns:
                restarted = f"no sample for {(stamp - newest) / NS:.3f} s, more than max_gap {self.settings.max_gap} s"
                history.clear()
            elif self._wrap[j]:
                previous = history.newest_position
                position = previous + (position - previous + np.pi) % (2.0 * np.pi) - np.pi
        if self.settings.velocity_source == "message" and np.isnan(velocity) and np.isnan(acceleration):
            self._log.once(
                ("no-velocity", j),
                logging.WARNING,
                f"velocity_source is 'message' but joint {self.joint_names[j]!r} has no velocity: differentiating",
            )
        history.append(stamp, position, velocity, acceleration)
        return restarted

    def _drain(self, until_ns: int | None = None) -> list[int]:
        targets = []
        while self._pending and (until_ns is None or self._pending[0] <= until_ns):
            targets.append(self._pending.popleft())
        return targets

    # -- estimation -------------------------------------------------------------------------

    def _estimate(self, target: int) -> JointEstimate:
        n = len(self.joint_names)
        state = np.full((n, 3), np.nan)
        ages = np.full(n, np.inf)
        for members in self._same_stamp_groups():
            self._estimate_group(target, members, state, ages)
        ready = np.all(np.isfinite(state), axis=1)
        state[~ready] = np.nan
        return JointEstimate(
            stamp_ns=target,
            segment=self.segment,
            positions=state[:, 0],
            velocities=state[:, 1],
            accelerations=state[:, 2],
            ages=ages,
            ready=ready,
        )

    def _same_stamp_groups(self) -> list[list[int]]:
        """Joints whose histories hold exactly the same stamps (one driver's joints): fitted together."""
        groups: dict[int, list[int]] = {}
        for j, lineage in enumerate(self._lineage):
            if lineage:
                groups.setdefault(lineage, []).append(j)
        return list(groups.values())

    def _estimate_group(self, target: int, members: list[int], state: np.ndarray, ages: np.ndarray) -> None:
        """Fill state (n, 3) and ages (n,) at the target for joints sharing the same sample stamps."""
        settings = self.settings
        stamps = self._histories[members[0]].stamps
        k = int(np.searchsorted(stamps, target, side="right")) - 1
        if k < 0:
            return
        age_ns = target - int(stamps[k])
        ages[members] = age_ns / NS
        if age_ns > self._gap_ns:
            return  # stale: not ready
        data = np.stack([self._histories[j].data for j in members])  # (m, count, 3)
        exact = age_ns == 0
        if exact:  # the sample itself rather than a fit, for what the message gave
            state[members] = data[:, k]  # supplied accelerations (finite) bypass the estimate below
        lead_ns = self._lag_ns if settings.mode == "fixed_lag" else 0
        lo = int(np.searchsorted(stamps, target + lead_ns - round(settings.window * NS), side="left"))
        hi = int(np.searchsorted(stamps, target + lead_ns, side="right"))
        from_velocity = np.all(np.isfinite(data[:, lo:hi, 1]), axis=1) & (hi - lo >= 2)
        needs = ~np.isfinite(state[members, 2])
        if len(stamps) < 3:
            needs &= from_velocity
        if not np.any(needs):
            return
        estimated = [j for j, need in zip(members, needs, strict=True) if need]
        by_velocity = from_velocity[needs]
        values = np.concatenate([data[needs, :, 0], data[needs][by_velocity, :, 1]]).T  # (count, columns)
        times = (stamps - self._origin) / NS
        target_s = (target - self._origin) / NS
        if settings.method == "difference":
            fitted, d1, d2 = local_difference(times, values, target_s, lead_ns / NS)
        else:
            fitted, d1, d2 = fit_at(times, values, target_s, settings.window / 2.0, settings.order, lead_ns / NS)
        m = len(estimated)
        velocity_column = m + np.cumsum(by_velocity) - 1
        for column, j in enumerate(estimated):
            if by_velocity[column]:
                fitted_velocity, acceleration = fitted[velocity_column[column]], d1[velocity_column[column]]
            else:
                fitted_velocity, acceleration = d1[column], d2[column]
            if not exact:
                state[j, 0] = fitted[column]
            if not (exact and np.isfinite(state[j, 1])):  # a message velocity is kept as given
                state[j, 1] = fitted_velocity
            state[j, 2] = acceleration
