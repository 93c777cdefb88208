"""Contact detection: thresholds on the external torques, with a debounce.

Out of contact, a joint is over its threshold when |external torque| exceeds it, plus, with the
momentum observer, the friction the model cannot place: a joint moving slower than its friction's
velocity scale may be held by any friction up to its Coulomb (and Stribeck) level, which the
measured velocity cannot sign, so that much is added to its threshold (in proportion to
1 - |tanh(v / velocity_scale)|, v the filtered velocity). In contact, a joint stays over while
|external torque| exceeds ``release`` times its threshold (hysteresis: a push whose torques wane on
one joint and grow on another, or pass through the friction band, is one contact, not several).
``~/contact`` turns true when some watched joint has been over its threshold *the same way* (one
sign) for ``debounce`` seconds, and false again when none has been over for ``debounce`` seconds: a
spike shorter than that (noise, a stick-slip) changes nothing, nor does a torque swinging from one
side to the other (a contact presses one way; a drive ringing after an abrupt stop, which the
rigid model cannot follow, swings both). The detector is the computation's state that runs on from
one stamp to the next (the node holds one for its run, the bag tool one per recording), fed in
stamp order.

**Beyond the calibrated accelerations**, with ``accelerations`` (``contact.accelerations``, which
``neforward calibrate`` measures: each joint's largest |acceleration| in its free motion, as the
detector reads it): a model identified on a motion is not trusted beyond it. Where a joint
accelerates faster than that (a hard stop the excitation never made), the rigid model's errors grow
in proportion (its inertias, the effort scale that came with them), on every joint the inertia
matrix couples to it: every moving threshold grows by the largest |acceleration| / calibrated
largest among the joints (at least 1). The detector reads each joint's acceleration as
the change of the velocities it is given over the last :data:`ACCELERATION_SPAN` (from the newest
stamp at least that old: at 1 kHz, a one-sample difference would be the velocities' noise times a
thousand), and the calibration reads its free motion the same way (:meth:`ContactDetector.accelerations_of`).

**At rest**, with ``rest_thresholds`` (``contact.rest_thresholds``, which ``neforward calibrate``
measures where its recordings hold still): once every joint has been slower than its friction's
velocity scale for :data:`REST_DWELL`, the arm is still, and what the model cannot tell there is
constant: the static friction each joint is stuck with, the gravity model's error in this pose. Each
joint's external torque when the arm came to rest is its *baseline*, and a joint is over when its
external torque departs from that baseline by more than its rest threshold (a push on a held arm,
far smaller than the moving thresholds and the static-friction band). Out of contact the baseline
follows the external torque with the time constant :data:`BASELINE_TIME` (a controller's slow
settling is not a push); in contact it stays, so that the contact ends when the torques come back.
The first motion ends the rest: the moving thresholds apply again.
"""

from __future__ import annotations

import logging
from collections import deque

import numpy as np

from neforward_ros.logs import ThrottledLog
from neforward_ros.stamps import NS

REST_DWELL = 0.2
"""s every joint must have been slower than its friction's velocity scale before the rest test applies
(a reversal passes through rest far quicker)."""
ACCELERATION_SPAN = 0.02
"""s over which the detector reads each joint's acceleration from the velocities' change."""
BASELINE_TIME = 1.0
"""s: the time constant with which a still arm's baseline follows its external torques out of contact."""


class ContactDetector:
    """The debounced contact state of a stream of external torques.

    Args:
        thresholds: (n,) per joint column, N m (N); NaN for joints not watched.
        debounce: s.
        joint_names: for the log.
        log: where transitions and missing efforts are said.
        release: in contact, the fraction of its threshold a joint must stay over (1: no hysteresis).
        rest_thresholds: (n,) the thresholds of the departure from the baseline while the arm is
            still, N m (N); None (or NaN for a watched joint): no rest test.
        accelerations: (n,) the largest |acceleration| each joint's thresholds hold for, rad/s^2
            (m/s^2); None (or NaN for a joint): at every acceleration.
    """

    def __init__(
        self,
        thresholds: np.ndarray,
        debounce: float,
        joint_names: tuple[str, ...],
        log: ThrottledLog,
        release: float = 1.0,
        rest_thresholds: np.ndarray | None = None,
        accelerations: np.ndarray | None = None,
    ) -> None:
        self.thresholds = np.asarray(thresholds, dtype=float)
        self.accelerations = None
        if accelerations is not None:
            given = np.asarray(accelerations, dtype=float)
            self.accelerations = np.where(np.isfinite(given) & (given > 0.0), given, np.inf)
        self._velocities: deque[tuple[int, np.ndarray]] = deque()  # the last span's (stamp, velocities)
        self.release = float(release)
        self.watched = np.isfinite(self.thresholds)
        self.debounce_ns = round(debounce * NS)
        self.joint_names = joint_names
        self.state = False
        self._since: int | None = None  # in contact: stamp from which no joint has been over
        self._sign = np.zeros(len(self.thresholds))  # out of contact: each joint's side of its threshold
        self._over_since = np.zeros(len(self.thresholds), dtype=np.int64)  # from which stamp it has held
        self._log = log
        rest = None if rest_thresholds is None else np.asarray(rest_thresholds, dtype=float)
        self.rest_thresholds = rest if rest is not None and np.isfinite(rest[self.watched]).all() else None
        self._still_since: int | None = None  # stamp from which the arm has been still
        self._baseline: np.ndarray | None = None  # the still arm's external torques
        self._stamp: int | None = None

    def _departure(self, stamp_ns: int, external: np.ndarray, still: bool) -> np.ndarray | None:
        """The external torques' departure from the rest baseline at this stamp; None while the arm is
        not (yet) at rest."""
        if not still:
            self._still_since = self._baseline = None
            return None
        if self._still_since is None:
            self._still_since = stamp_ns
        if stamp_ns - self._still_since < REST_DWELL * NS:
            return None
        if self._baseline is None:
            self._baseline = external.copy()
        self._baseline = np.where(np.isfinite(self._baseline), self._baseline, external)
        return external - self._baseline

    def unseen(self) -> None:
        """A stamp without external torques (a restart, the observer warming up): the arm may have
        moved unseen, so the rest test starts over."""
        self._still_since = self._baseline = None
        self._velocities.clear()

    def _acceleration(self, stamp_ns: int, velocity: np.ndarray) -> np.ndarray | None:
        """Each joint's |acceleration| at this stamp, rad/s^2 (m/s^2): its velocity's change since the
        newest stamp at least :data:`ACCELERATION_SPAN` before (see the module docstring); None until
        the velocities given span that long."""
        kept = self._velocities
        if kept and stamp_ns <= kept[-1][0]:
            kept.clear()  # (stamps back in time: a new stream)
        kept.append((stamp_ns, np.asarray(velocity, dtype=float)))
        span = round(ACCELERATION_SPAN * NS)
        while len(kept) > 1 and stamp_ns - kept[1][0] >= span:
            kept.popleft()
        first, then = kept[0]
        if stamp_ns - first < span:
            return None
        return np.abs(kept[-1][1] - then) * (NS / (stamp_ns - first))

    def accelerations_of(self, stamps: np.ndarray, velocity: np.ndarray) -> np.ndarray:
        """(T, n) the |accelerations| the detector reads from a stream of velocities (T, n) at stamps
        (T,), NaN where it reads none yet: what ``contact.accelerations`` is measured on."""
        out = np.full(velocity.shape, np.nan)
        for i, stamp in enumerate(stamps.tolist()):
            found = self._acceleration(int(stamp), velocity[i])
            if found is not None:
                out[i] = found
        return out

    def growth(self, stamp_ns: int, velocity: np.ndarray | None) -> float:
        """The factor the moving thresholds grow by at this stamp: the largest of the joints'
        |acceleration| over its calibrated largest, at least 1 (the inertia matrix couples the joints: a
        hard stop of one leaves its error on the others too); 1 without ``accelerations``, a velocity, or
        a span of them yet."""
        if self.accelerations is None or velocity is None:
            return 1.0
        acceleration = self._acceleration(stamp_ns, velocity)
        if acceleration is None:
            return 1.0
        ratio = acceleration / self.accelerations
        return max(1.0, float(np.max(ratio, initial=1.0, where=np.isfinite(ratio))))

    def _follow(self, stamp_ns: int, external: np.ndarray) -> None:
        """The baseline follows the external torques (out of contact, nothing over)."""
        assert self._baseline is not None
        if self._stamp is not None and stamp_ns > self._stamp:
            a = min(1.0, (stamp_ns - self._stamp) / (BASELINE_TIME * NS))
            moved = self._baseline + a * (external - self._baseline)
            self._baseline = np.where(np.isfinite(external), moved, self._baseline)

    def rest_departures(self, stamps: np.ndarray, external: np.ndarray, still: np.ndarray) -> np.ndarray:
        """(T, n) the departures from the rest baseline a contact-free stream of external torques
        (T, n) would have, NaN where the arm is not at rest: what the rest thresholds must stay above
        (the calibration's measure). The detector's rest state runs on."""
        out = np.full(external.shape, np.nan)
        for i, stamp in enumerate(stamps.tolist()):
            departure = self._departure(int(stamp), external[i], bool(still[i]))
            if departure is not None:
                out[i] = departure
                self._follow(int(stamp), external[i])
            self._stamp = int(stamp)
        return out

    def update(
        self,
        stamp_ns: int,
        external: np.ndarray,
        slack: np.ndarray | None = None,
        still: bool | None = None,
        velocity: np.ndarray | None = None,
    ) -> bool | None:
        """The state at this stamp, or None when no watched joint has a measured effort; ``slack``
        (n,): added to the thresholds at this stamp, out of contact; ``still``: whether every joint is
        slower than its friction's velocity scale (None: unknown, no rest test); ``velocity`` (n,): the
        joint velocities, whose change grows the thresholds beyond the calibrated accelerations."""
        grown = self.thresholds * self.growth(stamp_ns, velocity)
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
        departure = None
        if self.rest_thresholds is not None and still is not None:
            departure = self._departure(stamp_ns, external, still)
        if departure is not None:
            assert self.rest_thresholds is not None
            values = departure
            thresholds = self.release * self.rest_thresholds if self.state else self.rest_thresholds
        else:
            values = external
            if self.state:
                thresholds = self.release * grown
            else:
                thresholds = grown if slack is None else grown + slack
        signed = np.where(measured, values, 0.0)
        over = measured & (np.abs(signed) > np.where(measured, thresholds, 0.0))
        now = bool(over.any())
        if departure is not None and not now and not self.state:
            self._follow(stamp_ns, external)
        self._stamp = stamp_ns
        if self.state:
            if now:
                self._since = None
            elif self._since is None:
                self._since = stamp_ns
            change = self._since is not None and stamp_ns - self._since >= self.debounce_ns
        else:
            sign = np.where(over, np.sign(signed), 0.0)
            self._over_since = np.where(sign != self._sign, stamp_ns, self._over_since)
            self._sign = sign
            change = bool(np.any(over & (stamp_ns - self._over_since >= self.debounce_ns)))
        if change:
            self.state = not self.state
            self._since = None
            self._sign = np.zeros_like(self._sign)
            if not self.state:
                self._still_since = self._baseline = None  # a released arm settles anew: a new rest
            joints = ", ".join(n for n, o in zip(self.joint_names, over, strict=True) if o)
            self._log.log(
                logging.INFO, f"contact: {'joint(s) ' + joints + ' over threshold' if self.state else 'none'}"
            )
        return self.state

    def update_many(
        self,
        stamps: np.ndarray,
        external: np.ndarray,
        usable: np.ndarray,
        slack: np.ndarray | None = None,
        still: np.ndarray | None = None,
        velocity: np.ndarray | None = None,
    ) -> np.ndarray:
        """The states at T stamps, in order: (T,) 1.0 or 0.0, NaN where not ``usable`` (a stamp without
        every joint's state) or no watched joint has a measured effort; ``slack`` (T, n), ``still``
        (T,) and ``velocity`` (T, n) as for :meth:`update` (with ``still``, a stamp not ``usable`` is
        :meth:`unseen`)."""
        out = np.full(len(stamps), np.nan)
        for i in range(len(stamps)):
            if not usable[i]:
                if still is not None:
                    self.unseen()
                continue
            state = self.update(
                int(stamps[i]),
                external[i],
                None if slack is None else slack[i],
                None if still is None else bool(still[i]),
                None if velocity is None else velocity[i],
            )
            out[i] = np.nan if state is None else float(state)
        return out
