"""The recent samples of a group of joints that arrive together (one driver's), kept for the fits."""

from __future__ import annotations

from collections import deque

import numpy as np

from neforward_ros.estimation.clock import SampleClock
from neforward_ros.estimation.kalman_bank import KalmanBank
from neforward_ros.estimation.repeats import MOST_REPEATS, MOVING_STEPS, changing, stopped
from neforward_ros.stamps import NS


class JointHistory:
    """Joints that have received exactly the same stamps since their histories last restarted (one
    driver's joints): their samples share one buffer and are fitted together.

    Attributes:
        joints: the joints' indices in the estimator, in the order of the buffer's columns.
        origin: the segment's first stamp; ``seconds`` are counted from it.
        clock: where given, the times the samples are fitted at (:class:`~.clock.SampleClock`): the
            stamps, or once they are found to be write times the clock recovered from them (the Kalman
            bank, ``track``, keeps one of its own, for its filters).
    """

    __slots__ = (
        "_efforts",
        "_positions",
        "_recovered",
        "_seconds",
        "_stamps",
        "_velocities",
        "any_effort",
        "clock",
        "end",
        "holes",
        "intervals",
        "joints",
        "last_without_velocity",
        "left_out",
        "newest_received",
        "origin",
        "run",
        "slots",
        "start",
        "track",
        "warming",
    )

    def __init__(
        self,
        joints: list[int],
        origin: int,
        capacity: int = 256,
        track: KalmanBank | None = None,
        clock: SampleClock | None = None,
    ) -> None:
        self.joints = joints
        self.track = track
        self.clock = clock
        self.holes: list[int] = []  # stamps of samples more than the support's max_hole after the previous one
        self.intervals: deque[int] = deque(maxlen=8)  # the last intervals between samples, ns
        self.warming: bool | str = False  # whether the current warm-up has been logged ("sparse": warned)
        self.slots = {j: k for k, j in enumerate(joints)}
        self.origin = origin
        self._stamps = np.empty(capacity, dtype=np.int64)
        self._seconds = np.empty(capacity)
        self._recovered = np.empty(capacity)  # the samples' times on the recovered clock, s since origin
        self._positions = np.empty((capacity, len(joints)))
        self._velocities = np.empty((capacity, len(joints)))
        self._efforts = np.empty((capacity, len(joints)))
        self.any_effort = False  # whether a message ever gave an effort for these joints
        self.start = 0
        self.end = 0
        self.last_without_velocity = -1  # buffer index of the newest sample that had no velocity at all
        self.left_out: deque[int] = deque(maxlen=64)  # the stamps of the latest samples left out as repeats
        # The samples left out as repeats since the newest one kept, as given (stamp, positions,
        # velocities, efforts): taken back, in order, when the run turns out to be a stop.
        self.run: list[tuple[int, list[float], list[float], list[float]]] = []
        self.newest_received = 0  # the stamp of the newest sample, kept or left out

    def __len__(self) -> int:
        return self.end - self.start

    @property
    def stamps(self) -> np.ndarray:
        return self._stamps[self.start : self.end]

    @property
    def sample_clock(self) -> SampleClock | None:
        """The clock the group's samples are timed by: its own (:attr:`clock`), or the Kalman bank's."""
        return self.clock if self.track is None else self.track.clock

    @property
    def written(self) -> bool:
        """Whether the stamps were found to be write times (the samples' times are then the recovered clock's)."""
        return self.clock is not None and self.clock.written

    @property
    def seconds(self) -> np.ndarray:
        """The samples' times, s since the segment's first stamp: their stamps', or the recovered clock's
        where the stamps are write times."""
        times = self._recovered if self.written else self._seconds
        return times[self.start : self.end]

    def time_of(self, stamp_ns: int) -> float:
        """The time (s since the segment's first stamp) that a stamp stands for on the samples' clock (see
        :attr:`seconds`): the stamp's own, or where the stamps are write times that of the newest sample
        at or before it on the recovered clock, plus the time since (the oldest sample's, less the time
        to it, before every sample)."""
        if not self.written:
            return (stamp_ns - self.origin) / NS
        stamps = self.stamps
        k = max(int(stamps.searchsorted(stamp_ns, side="right")) - 1, 0)
        return float(self._recovered[self.start + k]) + (stamp_ns - int(stamps[k])) / NS

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

    def repeats(self, stamp_ns: int, positions: list[float], velocities: list[float], efforts: list[float]) -> bool:
        """Whether a sample (in the order of :attr:`joints`) at this stamp, newer than the newest,
        repeats it (:mod:`neforward_ros.estimation.repeats`); kept aside when it does."""
        if len(self) < MOVING_STEPS + 1 or len(self.run) >= MOST_REPEATS:
            return False
        newest = self._positions[self.end - 1]
        if any(p != newest[k] for k, p in enumerate(positions)):
            return False
        if not changing(self._positions[self.end - MOVING_STEPS - 1 : self.end]):
            return False
        self.intervals.append(stamp_ns - self.newest_received)
        self.newest_received = stamp_ns
        self.left_out.append(stamp_ns)
        self.run.append((stamp_ns, list(positions), list(velocities), list(efforts)))
        return True

    def append(
        self, stamp_ns: int, positions: list[float], velocities: list[float], efforts: list[float], max_hole_ns: int
    ) -> None:
        """A new sample, newest of all. After a run of left-out samples that was a stop, not a driver's
        repeats (:data:`MOST_REPEATS` of them, or a new sample that leaves a moving joint where it was
        or moves none onwards by more than one interval could:
        :func:`~neforward_ros.estimation.repeats.stopped`), those samples are taken back first, in
        order."""
        run, self.run = self.run, []
        if len(run) >= MOST_REPEATS or (
            run and stopped(self._positions[self.end - MOVING_STEPS - 1 : self.end], np.asarray(positions))
        ):
            for sample in run:
                self._store(*sample, max_hole_ns, received=False)
                self.left_out.pop()
        self._store(stamp_ns, positions, velocities, efforts, max_hole_ns, received=True)

    def _store(
        self,
        stamp_ns: int,
        positions: list[float],
        velocities: list[float],
        efforts: list[float],
        max_hole_ns: int,
        received: bool,
    ) -> None:
        """Store a sample; ``received``: it is the newest message's (not one taken back), whose interval
        from the message before is counted."""
        if self.end == len(self._stamps):
            count = len(self)
            arrays = ("_stamps", "_seconds", "_recovered", "_positions", "_velocities", "_efforts")
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
            elif received:
                self.intervals.append(stamp_ns - self.newest_received)  # from the last message, repeats too
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
        if received:
            self.newest_received = stamp_ns
        if self.clock is not None:
            placings = self.clock.placings
            self._recovered[end] = (self.clock.add(stamp_ns, self._positions[end]) - self.origin) / NS
            if self.clock.placings != placings:
                self._place_on_clock_line()
        if self.track is not None:
            self.track.add(stamp_ns, self._positions[end], self._velocities[end])

    def _place_on_clock_line(self) -> None:
        """Every sample held, placed on the recovered clock's line as the stamps are found to be write
        times (:meth:`~.clock.SampleClock.retimed`), and again where the clock jumps onto a line drawn on
        periods counted again: their times on the clock as it ran were still leaning towards it (polyfit
        causal on 1.5 Hz sines at 100 Hz, delays to 0.7 of a period: 1.7x the error on the samples'
        stamps from 1 s on, 1.0x placed)."""
        held = slice(self.start, self.end)
        self._recovered[held] = (self.clock.retimed(self._stamps[held]) - self.origin) / NS

    def drop_before(self, stamp_ns: int, keep: int) -> None:
        """Forget samples older than stamp_ns, keeping at least the newest ``keep``."""
        first = self.start + int(np.searchsorted(self.stamps, stamp_ns, side="left"))
        self.start = min(first, max(self.start, self.end - keep))
        oldest = int(self._stamps[self.start])
        if self.holes and self.holes[0] <= oldest:
            self.holes = [h for h in self.holes if h > oldest]

    def split(self, joints: list[int]) -> JointHistory:
        """Move these joints, with their history, into a group of their own; returns it."""
        columns = [self.slots[j] for j in joints]
        track = self.track.select(columns) if self.track is not None else None
        clock = self.clock.select(columns) if self.clock is not None else None
        moved = JointHistory(joints, self.origin, capacity=max(len(self._stamps), 16), track=track, clock=clock)
        count = len(self)
        moved._stamps[:count] = self.stamps
        moved._seconds[:count] = self._seconds[self.start : self.end]
        moved._recovered[:count] = self._recovered[self.start : self.end]
        moved._positions[:count] = self.positions[:, columns]
        moved._velocities[:count] = self.velocities[:, columns]
        moved._efforts[:count] = self.efforts[:, columns]
        moved.any_effort = self.any_effort
        moved.end = count
        moved.holes = list(self.holes)
        moved.intervals = self.intervals.copy()
        moved.left_out = self.left_out.copy()
        moved.newest_received = self.newest_received
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
        if self.clock is not None:
            self.clock = self.clock.select(columns)
        self._positions = self._positions[:, columns].copy()
        self._velocities = self._velocities[:, columns].copy()
        self._efforts = self._efforts[:, columns].copy()
        self.run = [(stamp, *([values[k] for k in columns] for values in sample)) for stamp, *sample in self.run]
        self.joints = keep
        self.slots = {j: k for k, j in enumerate(keep)}

    def effort_at(self, k: int, target: int) -> np.ndarray:
        """The efforts at the target: sample k's at its stamp, else interpolated between k and k + 1
        when there is a sample after (NaN otherwise, and where a message gave none)."""
        efforts = self.efforts
        stamps = self.stamps
        before = int(stamps[k])
        if target == before or k + 1 >= len(stamps):
            return efforts[k] if target == before else np.full(len(self.joints), np.nan)
        weight = (target - before) / (int(stamps[k + 1]) - before)
        return efforts[k] + weight * (efforts[k + 1] - efforts[k])
