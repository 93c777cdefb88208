"""Samples that repeat the previous one under a new stamp: a driver's stale reading, not a stop.

Drivers that publish on a timer re-send their last reading when no new one has come (the Franka
Panda's logs repeat about 6 % of their samples, in runs of one to four, while the arm moves at
1 rad/s). Fitted as samples, each one reads as the joint standing still for a millisecond and
jumping after: high-frequency noise in q'' of about v / dt^2 at that stamp, and a noise level read
from the samples that no longer says what the rest of them carry.

A sample is taken as a repeat, and left out of the fits (its stamp still gets an estimate, from the
samples around it), when all of these hold:

- every position it carries equals the previous sample's exactly, and some joint changed at some of
  the :data:`MOVING_STEPS` steps between the samples kept before it (:func:`changing`: an equal
  sample after samples that all agree, a joint at rest, is no repeat that can be told);
- it does not make a run of more than :data:`MOST_REPEATS` equal samples: a longer run is a stop,
  and the samples of the run are taken back into the fits, in order, as soon as the sample after
  :data:`MOST_REPEATS` of them is equal too;
- the run is no stop (:func:`stopped`), which the sample that ends it tells. Where some joint changed
  at each of those steps (a joint that moves that steadily cannot stand still for exactly one
  interval, even at an encoder's resolution), or at each of the last two of them, by half again as
  much at the second (a joint speeding up, as at a move's start, whose readings cannot stand still
  either: on the estimator family's minimum-jerk moves at 100 Hz with driver repeats, such a repeat
  read as a stop made the Kalman 20 ms setting's error 6.0-7.2x hindsight's) (:func:`moving_joints`),
  the run is a stop only if the sample that ends it leaves every such joint where it was, and moves
  no joint onwards by more than one interval could: joints that moved at every step and then keep
  their positions over the run and the sample after it, the others moving on as before, have
  stopped (a minimum-jerk move's end through 12 bits at 100 Hz: the joint creeps one encoder step a
  sample into its target; taken as repeats, the run left a hole in every joint's samples, and the
  default setting gave no estimate for 0.2 s at each such stop). Where no joint moved that steadily
  (a joint slower than a step a sample, whose readings often repeat; a move's first change after a
  rest), the run is a repeat only where the sample that ends it moves some joint onwards, in the
  direction of its last change, by more than :data:`SPEEDING_UP` times its largest change between
  the kept samples: the joint moved through the run's intervals, the run held its reading. On the
  unseen estimator bench's fresh minimum-jerk moves at 150 Hz through 15 bits with 8 % repeats, a
  repeat after a move's first two changes of two steps each, followed by one of 13, was fitted as a
  stop, and the Kalman 20 ms setting's error was 1.77x hindsight's (1.16x once left out). A run that
  is a stop is taken back, as above.

No estimate of a stamp among a run is made before it is told from a stop (a repeat's stamp waits for
the next sample kept, in every mode; another joint group's messages meanwhile release no estimate
whose fit reaches the run), so none is made without its samples.

The rule looks only at the samples before it and at most :data:`MOST_REPEATS` + 1 after, so the node
(one message at a time) and the bag tool (a whole recording, :func:`repeated`) leave out the same
samples and make each estimate from the same ones.
"""

from __future__ import annotations

import numpy as np

MOVING_STEPS = 3
"""Steps between the kept samples before a candidate: a joint that changed at each of them is moving
(:func:`moving_joints`); one that changed at some of them makes the candidate (:func:`changing`)."""
SPEEDING_UP = 1.5
"""How many times its change at the step before a joint's last change must be for the joint to be
speeding up: clear of one encoder step against one step (the two differences of positions on a grid
differ in their last bits)."""
MOST_REPEATS = 8
"""Consecutive samples left out as repeats at most; after them, equal samples are a stop."""


def moving_joints(kept: np.ndarray) -> np.ndarray:
    """(joints,) bool: the joints that changed at every step of ``kept`` (the last ``MOVING_STEPS + 1``
    kept samples' positions, (MOVING_STEPS + 1, joints), in order), or at each of its last two steps,
    by :data:`SPEEDING_UP` times more at the second; none where ``kept`` is shorter."""
    if len(kept) < MOVING_STEPS + 1:
        return np.zeros(kept.shape[1], dtype=bool)
    changes = np.abs(np.diff(kept, axis=0))
    steady = np.all(changes > 0.0, axis=0)
    speeding_up = (changes[-2] > 0.0) & (changes[-1] > SPEEDING_UP * changes[-2])
    return steady | speeding_up


def changing(kept: np.ndarray) -> bool:
    """Whether some joint of ``kept`` (as :func:`moving_joints` takes it) changed at some step: an equal
    sample after it may be a driver's repeat, which the sample that ends its run tells
    (:func:`stopped`); none where ``kept`` is shorter."""
    return len(kept) >= MOVING_STEPS + 1 and bool(np.any(kept[1:] != kept[:-1]))


def stopped(kept: np.ndarray, following: np.ndarray) -> bool:
    """Whether a run of equal samples after ``kept`` (as :func:`moving_joints` takes it) was a stop:
    every joint that made ``kept`` moving is unchanged in ``following`` (joints,), the sample that ends
    the run, and no joint moves there onwards (in the direction of its last change between the
    ``kept`` samples) by more than :data:`SPEEDING_UP` times its largest change between them (one that
    does moved for more than one interval: the run held its reading).

    One moving joint that changes there, after none did over the run, shows the run was a driver's
    too: with 'some moving joint unchanged' a driver's repeat was fitted wherever a slow joint did not
    change over two intervals (3.9x hindsight on trapezoidal moves at 800 Hz with 6 % repeats); and
    without the last clause wherever the moving joint stopped as another sped up (4.2x on
    minimum-jerk moves at 100 Hz with 10 % repeats), or where no joint moved at every step, as after a
    move's first changes (1.77x on minimum-jerk moves at 150 Hz with 8 % repeats). A joint that turns
    back there does not tell: a slow joint's turning point holds its reading for a while."""
    change = np.asarray(following) - kept[-1]
    if np.any(change[moving_joints(kept)] != 0.0):
        return False
    changes = np.diff(kept, axis=0)
    largest = np.max(np.abs(changes), axis=0, initial=0.0)
    newest = len(changes) - 1 - np.argmax(changes[::-1] != 0.0, axis=0)  # per joint: its last change's step
    direction = np.sign(changes[newest, np.arange(changes.shape[1])])  # 0 where it never changed
    onward = change * direction  # > 0: in the direction of its last change
    return not np.any((largest > 0.0) & (onward > SPEEDING_UP * largest))


def repeated(positions: np.ndarray, starts: np.ndarray | None = None) -> np.ndarray:
    """(T,) bool: the samples of ``positions`` (T, joints), in stamp order, that are repeats.

    ``starts``: (T,) bool, the samples where a history starts anew (after a gap longer than max_gap,
    as the node restarts it): the samples before one are not looked at from it on."""
    count = len(positions)
    out = np.zeros(count, dtype=bool)
    if count < MOVING_STEPS + 2:
        return out
    first = np.zeros(count, dtype=np.int64)  # where each sample's history starts
    if starts is not None:
        first = np.maximum.accumulate(np.where(starts, np.arange(count), 0))
    same = np.flatnonzero(np.all(positions[1:] == positions[:-1], axis=1)) + 1
    run: tuple[int, int] | None = None  # the open run of repeats: its first sample, its last
    for k in [*same.tolist(), count]:
        if run is not None and run[1] < k - 1:  # the run ended at the sample after its last
            first_out, end = run[0], run[1] + 1
            run = None
            if end < count and not (starts is not None and starts[end]):
                if stopped(positions[_kept_before(out, first_out, first[first_out])], positions[end]):
                    out[first_out:end] = False
        if k == count:
            break
        if starts is not None and starts[k]:
            continue
        streak = 0
        while k - 1 - streak >= first[k] and out[k - 1 - streak]:
            streak += 1
        if streak >= MOST_REPEATS:  # a stop: the run before it was no driver's repeats
            out[k - streak : k] = False
            run = None
            continue
        out[k] = changing(positions[_kept_before(out, k, first[k])])
        if out[k]:
            run = (run[0] if run is not None else k, k)
    return out


def _kept_before(out: np.ndarray, k: int, first: int) -> list[int]:
    """The indices of the last ``MOVING_STEPS + 1`` samples kept (not in ``out``) before ``k`` and from
    ``first`` on, in order."""
    kept: list[int] = []  # newest first
    i = k - 1
    while i >= first and len(kept) <= MOVING_STEPS:
        if not out[i]:
            kept.append(i)
        i -= 1
    return kept[::-1]
