"""Contact detection: thresholds on the external torques, with a debounce.

Out of contact, a joint is over its threshold when |external torque| exceeds it, plus, with the
momentum observer, the friction the model cannot place: a joint moving slower than its friction's
velocity scale may be held by any friction up to its Coulomb (and Stribeck) level, which the
measured velocity cannot sign, so that much is added to its threshold (in proportion to
1 - |tanh(v / velocity_scale)|, v the filtered velocity). In contact, a joint stays over while
|external torque| exceeds ``release`` times its threshold (hysteresis: a push whose torques wane on
one joint and grow on another, or pass through the friction band, is one contact, not several).
``~/contact`` turns true when some watched joint has been over its threshold for ``debounce``
seconds, and false again when none has been for ``debounce`` seconds: a spike shorter than that
(noise, a stick-slip) changes nothing. The detector is the computation's state that runs on from
one stamp to the next (the node holds one for its run, the bag tool one per recording), fed in
stamp order.
"""

from __future__ import annotations

import logging

import numpy as np

from neforward_ros.logs import ThrottledLog
from neforward_ros.stamps import NS


class ContactDetector:
    """The debounced contact state of a stream of external torques.

    Args:
        thresholds: (n,) per joint column, N m (N); NaN for joints not watched.
        debounce: s.
        joint_names: for the log.
        log: where transitions and missing efforts are said.
        release: in contact, the fraction of its threshold a joint must stay over (1: no hysteresis).
    """

    def __init__(
        self,
        thresholds: np.ndarray,
        debounce: float,
        joint_names: tuple[str, ...],
        log: ThrottledLog,
        release: float = 1.0,
    ) -> None:
        self.thresholds = np.asarray(thresholds, dtype=float)
        self.release = float(release)
        self.watched = np.isfinite(self.thresholds)
        self.debounce_ns = round(debounce * NS)
        self.joint_names = joint_names
        self.state = False
        self._since: int | None = None  # stamp from which the other state has held
        self._log = log

    def update(self, stamp_ns: int, external: np.ndarray, slack: np.ndarray | None = None) -> bool | None:
        """The state at this stamp, or None when no watched joint has a measured effort; ``slack``
        (n,): added to the thresholds at this stamp, out of contact."""
        measured = self.watched & np.isfinite(external)
        if not measured.any():
            self._log.once(
                "contact-no-effort",
                logging.WARNING,
                "contact detection needs the efforts of joint(s) "
                f"{', '.join(n for n, w in zip(self.joint_names, self.watched, strict=True) if w)}: "
                "their joint states carry none",
            )
            return None
        if self.state:
            thresholds = self.release * self.thresholds
        else:
            thresholds = self.thresholds if slack is None else self.thresholds + slack
        over = measured & (np.abs(np.where(measured, external, 0.0)) > np.where(measured, thresholds, 0.0))
        now = bool(over.any())
        if now == self.state:
            self._since = None
        elif self._since is None:
            self._since = stamp_ns
        if now != self.state and stamp_ns - self._since >= self.debounce_ns:
            self.state = now
            self._since = None
            joints = ", ".join(n for n, o in zip(self.joint_names, over, strict=True) if o)
            self._log.log(logging.INFO, f"contact: {'joint(s) ' + joints + ' over threshold' if now else 'none'}")
        return self.state

    def update_many(
        self, stamps: np.ndarray, external: np.ndarray, usable: np.ndarray, slack: np.ndarray | None = None
    ) -> np.ndarray:
        """The states at T stamps, in order: (T,) 1.0 or 0.0, NaN where not ``usable`` (a stamp without
        every joint's state) or no watched joint has a measured effort; ``slack`` (T, n) as for
        :meth:`update`."""
        out = np.full(len(stamps), np.nan)
        for i in np.flatnonzero(usable):
            state = self.update(int(stamps[i]), external[i], None if slack is None else slack[i])
            out[i] = np.nan if state is None else float(state)
        return out
