"""What is published for a stamp at which some joints have no estimate: the publish policy.

Shared by the node (one stamp at a time) and the bag tool (every stamp of a recording at once):

- ``partial`` (default): the links every joint above which has an estimate, as robot_state_publisher
  publishes the transforms it can. Nothing when no joint has one (a start-up, say): a held joint
  does not count, so ``hold`` publishes nothing then either.
- ``wait``: nothing until every joint has an estimate.
- ``hold``: joints silent for longer than max_gap, or never heard, are held at a fixed position
  (``hold.positions``, 0 for joints not listed), at rest; joints that are only warming up (samples
  arrive, but not yet enough for an estimate) are treated as under ``partial``.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Published:
    """Joint states to run the recursion on, and which of them are estimates (or held).

    Attributes:
        q, qd, qdd: (..., n) with zeros where a joint has nothing (its links are left out).
        known: (..., n) whether the joint's state is an estimate or held.
        publish: (...) whether anything is published for the stamp.
    """

    q: np.ndarray
    qd: np.ndarray
    qdd: np.ndarray
    known: np.ndarray
    publish: np.ndarray


def hold_vector(joint_names: Sequence[str], hold_positions: Mapping[str, float]) -> np.ndarray:
    """The held position of every joint, in the model's order (0 where none is given)."""
    return np.array([float(hold_positions.get(name, 0.0)) for name in joint_names])


def apply_policy(
    policy: str,
    q: np.ndarray,
    qd: np.ndarray,
    qdd: np.ndarray,
    known: np.ndarray,
    silent: np.ndarray,
    hold: np.ndarray,
) -> Published:
    """The policy applied to joint states (..., n); ``known`` marks estimates, ``silent`` the joints
    with no sample within max_gap (or none at all); ``hold`` (n,) the held positions."""
    known = np.asarray(known, dtype=bool)
    estimated = known.any(axis=-1)
    if policy == "hold":
        held = ~known & silent
        q = np.where(held, hold, q)
        qd = np.where(held, 0.0, qd)
        qdd = np.where(held, 0.0, qdd)
        known = known | held
    publish = known.all(axis=-1) if policy == "wait" else estimated
    q, qd, qdd = (np.where(known, x, 0.0) for x in (q, qd, qdd))
    return Published(q, qd, qdd, known, np.asarray(publish))
