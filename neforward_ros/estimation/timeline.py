"""What a joint-state stamp means: the next sample of the stream, a stray to drop, or a new stream.

A stream's stamps increase. One message that breaks that (a stale one from a buffered driver, a
stamp from another clock, a zero stamp among stamped ones) must cost no other estimate; a real
time reset (a looped recording, a simulation reset: the stream *continues* from the earlier time)
must restart the estimator. The two look alike on one message and differ on the next few, so a
message that breaks the stream is held, not used:

- a message is *in line* when none of its joints has a newer sample (a joint's own stamps
  increase; partial messages of several drivers interleave freely) and its stamp is not more than
  ``max_gap`` past the newest stamp (unless the stream's last step was that long already: a stream
  that slow, or one that just resumed, is taken as it comes);
- a message not in line is held. When :data:`CONFIRM` held messages follow one another (stamps
  increasing, no gap longer than ``max_gap``) while no message in line comes, the stream has moved
  to them: for a stamp that went back, the estimator restarts (a new segment); for a jump forward
  (a pause of the whole stream) nothing restarts here (each joint's gap restarts its history);
  the held messages are then used in order. A message in line drops the held ones, with one
  warning;
- a zero ``header.stamp`` in a stream that carries stamps is dropped, with a warning; a stream
  that carries none (a driver that does not stamp) is stamped with its receive times.

The node and the bag tool run the same rules on the same messages (:class:`Timeline`).
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from neforward_ros.logs import ThrottledLog
from neforward_ros.stamps import NS

CONFIRM = 3
"""Held messages that, following one another, show that the stream has moved to them."""

RESTART = "restart"


@dataclass
class _Held:
    stamps: list[int] = field(default_factory=list)
    joints: list[Sequence[int]] = field(default_factory=list)
    payloads: list[Any] = field(default_factory=list)
    backwards: bool = False


class Timeline:
    """The stamp rules of the module docstring, message by message.

    Args:
        joints: how many joints (indices in ``offer``).
        max_gap_ns: the estimator's max_gap.
        log: where dropped messages are said (throttled).
    """

    def __init__(self, joints: int, max_gap_ns: int, log: ThrottledLog) -> None:
        self._joints = joints
        self._max_gap = max_gap_ns
        self._log = log
        self._held = _Held()
        self.stamped = False
        self.reset()

    def reset(self) -> None:
        """Forget the stream (a new one starts; whether it carries stamps is kept)."""
        self._newest = [-1] * self._joints
        self.clock: int | None = None
        self._step = 0  # the newest stamp's step from the one before it, ns
        self._held = _Held()

    def stamp(self, stamp_ns: int, receive_ns: int | None) -> int | None:
        """The stamp to use for a message: its own; the receive time in a stream without stamps; None
        (dropped, said) for a zero stamp in a stream with stamps, or with no receive time."""
        if stamp_ns > 0:
            self.stamped = True
            return stamp_ns
        if self.stamped:
            self._log.every(
                "zero-stamp", logging.WARNING, "joint state with a zero header.stamp among stamped ones: dropped"
            )
            return None
        if receive_ns is None or receive_ns <= 0:
            self._log.every("stamp", logging.WARNING, "joint state with a zero stamp and no receive time: dropped")
            return None
        self._log.once(
            "zero-stamps", logging.WARNING, "joint states carry a zero header.stamp; using the receive time instead"
        )
        return int(receive_ns)

    def in_line(self, stamp_ns: int, joints: Sequence[int]) -> bool:
        newest = self._newest
        if any(newest[j] > stamp_ns for j in joints):
            return False
        return self.clock is None or stamp_ns - self.clock <= self._max_gap or self._step > self._max_gap

    def offer(self, stamp_ns: int, joints: Sequence[int], payload: Any) -> list[Any]:
        """What to do now with a message of these joints: a list of :data:`RESTART` markers and
        ``(stamp, payload)`` pairs to use, in order (empty while it is held)."""
        held = self._held
        if self.in_line(stamp_ns, joints):
            if held.stamps:
                self._drop_held()
            self._use(stamp_ns, joints)
            return [(stamp_ns, payload)]
        if held.stamps and stamp_ns > held.stamps[-1] and stamp_ns - held.stamps[-1] <= self._max_gap:
            held.stamps.append(stamp_ns)
            held.joints.append(joints)
            held.payloads.append(payload)
        else:
            if held.stamps:
                self._drop_held()
            backwards = self.clock is not None and stamp_ns < self.clock
            self._held = held = _Held([stamp_ns], [joints], [payload], backwards)
        if len(held.stamps) < CONFIRM:
            return []
        out: list[Any] = []
        if held.backwards:
            back = (self.clock - held.stamps[0]) / NS if self.clock is not None else 0.0
            self._log.every(
                "backwards",
                logging.WARNING,
                f"joint state stamps went back in time by {back:.6f} s and continue from there (bag loop or clock "
                "reset?): estimator histories restarted",
            )
            self.reset()
            out.append(RESTART)
        self._held = _Held()
        for stamp, message_joints, message in zip(held.stamps, held.joints, held.payloads, strict=True):
            self._use(stamp, message_joints)
            out.append((stamp, message))
        return out

    def _use(self, stamp_ns: int, joints: Sequence[int]) -> None:
        newest = self._newest
        for j in joints:
            if stamp_ns > newest[j]:
                newest[j] = stamp_ns
        if self.clock is None or stamp_ns > self.clock:
            self._step = 0 if self.clock is None else stamp_ns - self.clock
            self.clock = stamp_ns

    def _drop_held(self) -> None:
        held = self._held
        clock = self.clock if self.clock is not None else held.stamps[0]
        offset = (held.stamps[0] - clock) / NS
        where = f"{-offset:.6f} s before" if offset < 0 else f"{offset:.6f} s after"
        self._log.every(
            "stray",
            logging.WARNING,
            f"{len(held.stamps)} joint state(s) stamped {where} the stream's newest, which went on without them: "
            "dropped",
        )
        self._held = _Held()


def sort_out(
    stamps: np.ndarray,
    receive: np.ndarray,
    joints: Sequence[Sequence[int]],
    count: int,
    max_gap_ns: int,
    log: ThrottledLog,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A recording's messages, in recording order, through the same rules as the node's: whether each
    is used, the stamp it is used with (its own, or its recording time in a stream without stamps),
    and its segment (a new one after each time reset). ``joints[m]`` are message m's joint indices,
    of ``count`` joints; ``receive`` the recording times.

    A recording whose stamps break no rule (the usual case) is sorted out without a loop."""
    stamps = np.asarray(stamps, dtype=np.int64)
    zero = stamps <= 0
    used = np.where(zero, receive, stamps) if zero.all() else stamps
    if not (zero.any() and not zero.all()) and _in_order(used, joints, count, max_gap_ns):
        return np.ones(len(stamps), dtype=bool), used, np.zeros(len(stamps), dtype=np.int64)
    timeline = Timeline(count, max_gap_ns, log)
    kept = np.zeros(len(stamps), dtype=bool)
    segment = np.zeros(len(stamps), dtype=np.int64)
    current = 0
    for m, (stamp, joint_list) in enumerate(zip(stamps.tolist(), joints, strict=True)):
        at = timeline.stamp(stamp, int(receive[m]))
        if at is None:
            continue
        for step in timeline.offer(at, joint_list, m):
            if step is RESTART:
                current += 1
                continue
            message = step[1]
            kept[message], used[message], segment[message] = True, step[0], current
    return kept, used, segment


def _in_order(stamps: np.ndarray, joints: Sequence[Sequence[int]], count: int, max_gap_ns: int) -> bool:
    """Whether every message is in line (see the module docstring), tested at once."""
    by_list: dict[tuple[int, ...], list[int]] = {}
    for m, joint_list in enumerate(joints):
        by_list.setdefault(tuple(joint_list), []).append(m)
    by_joint: list[list[np.ndarray]] = [[] for _ in range(count)]
    for joint_list, messages in by_list.items():
        for j in joint_list:
            by_joint[j].append(np.asarray(messages))
    for parts in by_joint:
        messages = np.sort(np.concatenate(parts)) if len(parts) > 1 else (parts[0] if parts else None)
        if messages is not None and len(messages) > 1 and np.any(np.diff(stamps[messages]) < 0):
            return False
    if len(stamps) < 2:
        return True
    jumps = np.diff(np.maximum.accumulate(stamps)) > max_gap_ns
    # A jump after a step that was no jump holds the message; a stream that is slow anyway is taken as
    # it comes. (Conservative: where this says no, the loop decides.)
    return not np.any(jumps & ~np.r_[False, jumps[:-1]])
