"""The contact detector's debounce counts a joint as over only while it stays over *the same way*
(neforward_ros.computation.contact): a contact presses one way, while a drive ringing after an abrupt
stop swings the model's error from one side to the other. Expected states derived by hand."""

from __future__ import annotations

import numpy as np

from neforward_ros.computation.contact import ContactDetector
from neforward_ros.logs import ThrottledLog

NS = 1_000_000_000
STEP = 10_000_000  # 100 Hz
DEBOUNCE = 0.03  # s: the fourth sample over is the first 30 ms after the first


def states(external: list[float], joints: int = 1) -> list[bool]:
    found = ContactDetector(np.full(joints, 10.0), DEBOUNCE, tuple(f"j{k}" for k in range(joints)),
                            ThrottledLog(lambda *_: None), 0.6)  # fmt: skip
    values = np.asarray(external, dtype=float).reshape(-1, joints)
    stamps = np.arange(len(values), dtype=np.int64) * STEP
    return [bool(x) for x in found.update_many(stamps, values, np.ones(len(values), bool))]


def test_a_torque_over_one_way_for_the_debounce_is_a_contact() -> None:
    got = states([0.0, 12.0, 12.0, 12.0, 12.0, 12.0, 0.0, 0.0, 0.0, 0.0, 0.0])
    # over from stamp 1: 30 ms later (stamp 4) in contact; under from stamp 6: out 30 ms later (stamp 9)
    assert got == [False, False, False, False, True, True, True, True, True, False, False]
    assert states([0.0, -12.0, -12.0, -12.0, -12.0])[-1] is True


def test_a_torque_swinging_across_both_thresholds_is_no_contact() -> None:
    """Over at every stamp for 200 ms, but never one way for 30 ms: no contact. The previous rule (any
    joint over, whichever way) would have reported one after 30 ms."""
    assert not any(states([0.0] + [12.0, -12.0] * 10))
    assert not any(states([0.0] + [12.0, 12.0, -12.0, -12.0] * 5))
    # once it settles on one side, the debounce counts from the first sample on that side
    got = states([0.0, 12.0, -12.0, 12.0, 12.0, 12.0, 12.0])
    assert got == [False] * 6 + [True]


def test_the_debounce_runs_per_joint() -> None:
    """Two joints over one way each, taking turns: neither holds for the debounce alone."""
    turns = [[12.0, 0.0], [12.0, 0.0], [0.0, 12.0], [0.0, 12.0]] * 3
    assert not any(states([0.0, 0.0, *[v for row in turns for v in row]], joints=2))
    # both over together from stamp 1: one joint's run is enough
    assert states([0.0, 0.0] + [12.0, 12.0] * 4, joints=2)[-1] is True
