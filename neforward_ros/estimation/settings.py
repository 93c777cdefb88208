"""The joint estimator's settings: method, mode, window, lag, and what an estimate's support is."""

from __future__ import annotations

from dataclasses import dataclass, field

from neforward_ros.errors import InputError
from neforward_ros.estimation import fit
from neforward_ros.estimation.causal_choice import DEGREES
from neforward_ros.estimation.coverage import Support
from neforward_ros.estimation.fit import DEFAULT_WINDOW, degrees
from neforward_ros.estimation.motion import KalmanSettings

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
    """Options of the streaming estimator (:class:`~neforward_ros.estimation.stream.StreamingEstimator`).

    Attributes:
        method: ``"polyfit"`` (local polynomial fit), ``"kalman"`` (Kalman filter or fixed-lag smoother
            on the motion model of ``kalman``) or ``"difference"`` (numpy.gradient twice; a baseline).
        window: polyfit: full width of the local fit, s. kalman: the stretch of recent samples an
            estimate needs before its stamp (its warm-up), s.
        order: polynomial degree (polyfit); None: :attr:`degree`'s default, 6, 4 or 3 chosen per joint for adaptive
            windows reaching past the estimate (a fixed lag), 4 for a fixed window; an adaptive causal
            fit chooses among degrees 2-5 (:mod:`.causal_choice`).
        adaptive: polyfit: each joint's window chosen per estimate, up to ``window``, by the
            intersection-of-confidence-intervals rule (:mod:`.adaptive`); in causal mode with no
            ``order``, window and degree chosen by how each candidate fared half a window before
            (:mod:`.causal_choice`); False: always ``window``.
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
    order: int | None = None
    adaptive: bool = True
    mode: str = "fixed_lag"
    lag: float | None = None
    max_gap: float = DEFAULT_MAX_GAP
    velocity_source: str = "auto"
    kalman: KalmanSettings = field(default_factory=KalmanSettings)

    def __post_init__(self) -> None:
        if self.method not in METHODS:
            raise InputError(f"unknown method {self.method!r}; choose one of {', '.join(METHODS)}")
        fit.check_settings("polyfit", self.window, self.degree)
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
    def degree(self) -> int:
        """The polynomial degree of the polyfit: ``order``, or where None the default for the windows
        (:func:`~neforward_ros.estimation.fit.degrees`)."""
        return degrees(self.order, self.adaptive, self.effective_lag == 0.0)[0]

    @property
    def lower_degree(self) -> int | None:
        """The second degree the adaptive fit fuses with :attr:`degree` (the default at a fixed lag), or
        None (:func:`~neforward_ros.estimation.fit.degrees`)."""
        return degrees(self.order, self.adaptive, self.effective_lag == 0.0)[1]

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
            size = (
                f"windows up to {self.window:g} s, chosen per joint" if self.adaptive else f"window {self.window:g} s"
            )
            degree = "degrees 6, 4 or 3, chosen per joint" if self.lower_degree else f"degree {self.degree}"
            what = f"polyfit ({size}, {degree})"
            if self.adaptive and self.order is None and self.effective_lag == 0.0:
                what = (
                    f"polyfit (windows up to {self.window:g} s and degrees {DEGREES[0]}-{DEGREES[-1]}, chosen per "
                    "joint by their errors half a window before)"
                )
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

        polyfit: its window (ending ``lag`` after the stamp), with at least 2 (degree + 1) samples and
        no stretch longer than window / (degree + 1) without one (of two fused degrees, the lower).
        kalman: ``window`` before the stamp and ``lag`` after, at least :data:`KALMAN_MIN_SAMPLES`
        samples, no stretch longer than window / 5. difference: the same as kalman, with 5 samples.
        """
        lag = self.effective_lag
        if self.method == "polyfit":
            degree = self.lower_degree or self.degree  # the lower of two fused: the fit that needs fewest
            return Support(self.window - lag, lag, 2 * (degree + 1), self.window / (degree + 1))
        before = self.window if self.method == "kalman" or self.mode == "causal" else self.window / 2.0
        return Support(before, lag, KALMAN_MIN_SAMPLES if self.method == "kalman" else 5, self.window / 5.0)
