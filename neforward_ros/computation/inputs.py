"""What :func:`~neforward_ros.computation.compute.compute` takes: the joint states of one stamp or of
many, and, for a moving base, the motion of the link the base source measures at those stamps.

Every array has the stamps on its leading axis for a batch (the bag tool's chunks, a replay) and no
such axis for one stamp (the node, message by message, on Python floats where it counts).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from neforward_ros.estimation.estimate import JointEstimate


@dataclass(frozen=True)
class JointStates:
    """Joint states at one stamp ((n,) arrays) or at T stamps ((T, n) arrays), in the model's column order.

    Attributes:
        stamps: int ns, or (T,) int64.
        q, qd, qdd: rad (m), rad/s (m/s), rad/s^2 (m/s^2); anything where ``ready`` is False.
        ready: whether each joint's state is an estimate (or supplied).
        silent: whether each joint has had no sample within max_gap (or none at all): what
            ``publish_policy: hold`` holds.
        efforts: the measured efforts at the stamp as the input gave them (before ``effort.*``), NaN
            where there are none.
        acceleration_std: the estimator's standard deviation of each acceleration, NaN where it gives
            none (supplied states, a fixed-window estimator).
    """

    stamps: Any
    q: np.ndarray
    qd: np.ndarray
    qdd: np.ndarray
    ready: np.ndarray
    silent: np.ndarray
    efforts: np.ndarray
    acceleration_std: np.ndarray | None = None

    @property
    def single(self) -> bool:
        """Whether this is one stamp (no leading axis)."""
        return self.q.ndim == 1

    def __len__(self) -> int:
        return 1 if self.single else len(self.stamps)

    @classmethod
    def of_estimate(cls, estimate: JointEstimate, max_gap: float) -> JointStates:
        """One estimate of the streaming estimator."""
        n = len(estimate.positions)
        efforts = estimate.efforts if estimate.efforts is not None else np.full(n, np.nan)
        silent = ~(estimate.ages <= max_gap)
        spread = estimate.acceleration_std if estimate.acceleration_std is not None else np.full(n, np.nan)
        return cls(
            estimate.stamp_ns,
            estimate.positions,
            estimate.velocities,
            estimate.accelerations,
            estimate.ready,
            silent,
            efforts,
            spread,
        )

    @classmethod
    def empty(cls, joints: int) -> JointStates:
        """A batch of no stamps."""
        nothing = np.zeros((0, joints))
        flags = nothing.astype(bool)
        return cls(np.zeros(0, dtype=np.int64), nothing, nothing, nothing, flags, flags, nothing, nothing)

    @classmethod
    def stack(cls, parts: list[JointStates]) -> JointStates:
        """Single stamps (or batches) into one batch, in order."""
        if not parts:
            raise ValueError("nothing to stack")

        def rows(name: str) -> np.ndarray:
            values = [getattr(p, name) for p in parts]
            return np.stack(values) if parts[0].single else np.concatenate(values)

        spreads = [p.acceleration_std if p.acceleration_std is not None else np.full(p.q.shape, np.nan) for p in parts]
        spread = np.stack(spreads) if parts[0].single else np.concatenate(spreads)
        stamps = np.array([p.stamps for p in parts], dtype=np.int64) if parts[0].single else rows("stamps")
        return cls(stamps, *(rows(name) for name in ("q", "qd", "qdd", "ready", "silent", "efforts")), spread)

    def part(self, index: Any) -> JointStates:
        """Rows ``index`` (a slice, mask or index array) of a batch."""
        spread = self.acceleration_std if self.acceleration_std is not None else np.full(self.q.shape, np.nan)
        return JointStates(*(getattr(self, name)[index] for name in _FIELDS), spread[index])


_FIELDS = ("stamps", "q", "qd", "qdd", "ready", "silent", "efforts")


@dataclass(frozen=True)
class LinkMotion:
    """The motion of the link a base source measures, at the same stamps as the joint states, in that
    link's frame: (3,) vectors for one stamp, (T, 3) for T.

    Attributes:
        link: the link (an IMU's frame, an odometry's child frame).
        omega, alpha: rad/s, rad/s^2.
        specific_force: at the link origin, m/s^2.
        velocity: of the link origin, m/s; None when the source does not give it (an IMU).
        orientation: (x, y, z, w) of the link frame in the world frame; NaN where unknown.
        position: of the link origin in the world frame, m; NaN where unknown (an IMU).
    """

    link: str
    omega: np.ndarray
    alpha: np.ndarray
    specific_force: np.ndarray
    velocity: np.ndarray | None
    orientation: np.ndarray
    position: np.ndarray

    def part(self, index: Any) -> LinkMotion:
        """Rows ``index`` of a batch."""
        return LinkMotion(
            self.link,
            self.omega[index],
            self.alpha[index],
            self.specific_force[index],
            None if self.velocity is None else self.velocity[index],
            self.orientation[index],
            self.position[index],
        )

    @classmethod
    def stack(cls, parts: list[LinkMotion]) -> LinkMotion:
        """Single stamps (or batches) into one batch, in order (every part of the same link)."""
        first = parts[0]
        join = np.stack if first.omega.ndim == 1 else np.concatenate

        def rows(name: str) -> np.ndarray:
            return join([getattr(p, name) for p in parts])

        velocity = None if first.velocity is None else rows("velocity")
        return cls(first.link, rows("omega"), rows("alpha"), rows("specific_force"), velocity,
                   rows("orientation"), rows("position"))  # fmt: skip
