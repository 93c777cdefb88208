"""Messages one at a time -> the inputs of :func:`~neforward_ros.computation.compute.compute` they
complete: the streaming estimator and, for a moving base, the base tracker and the aligner; and,
for the momentum observer, the measured joint states at the newest stamps
(:mod:`~neforward_ros.computation.raw_samples`).

The node feeds it messages as they arrive; the bag tool replays a recording's messages through it
when the estimator is anything but its whole-recording default (causal, another lag, kalman), so
that the replay gives what the node gives.
"""

from __future__ import annotations

from collections.abc import Sequence

from neforward_ros.computation.base_motion import Aligner, BaseMessage, BaseTracker
from neforward_ros.computation.inputs import JointStates, LinkMotion
from neforward_ros.computation.observer import RawStates
from neforward_ros.computation.raw_samples import RawAssembler
from neforward_ros.estimation.estimate import JointEstimate
from neforward_ros.estimation.stream import RESTART, StreamingEstimator
from neforward_ros.logs import LogFunction
from neforward_ros.model import RobotModel
from neforward_ros.parameters.settings import NodeSettings
from neforward_ros.stamps import NS

Inputs = tuple[JointStates, LinkMotion | None]


class LiveInputs:
    """See the module docstring.

    Args:
        model: the robot.
        settings: the node's settings (the estimator's, the base source's).
        log: ``log(level, message)``.
        keep_base: base estimates kept (the bag tool keeps all: None).
        raw: whether to assemble the measured joint states for the momentum observer.

    Attributes:
        raw: the measured joint states at the newest stamps since the last :meth:`take_raw`.
        velocities: whether the joint states carry every joint's velocity, once every joint has
            had a sample (None before).
    """

    def __init__(
        self,
        model: RobotModel,
        settings: NodeSettings,
        log: LogFunction | None = None,
        keep_base: int | None = 4096,
        raw: bool = False,
    ) -> None:
        self.settings = settings
        self.assembler = RawAssembler(len(model.joint_names), round(settings.estimator.max_gap * NS)) if raw else None
        self.raw: list[RawStates] = []
        self.velocities: bool | None = None
        self.estimator = StreamingEstimator(
            model.joint_names,
            wrap=model.continuous_columns,
            ignored_names=model.mimic_joint_names,
            settings=settings.estimator,
            log=log,
        )
        self.aligner = None
        if settings.base_source != "fixed":
            tracker = BaseTracker(settings.base_source, settings.estimator, settings.gravity, log, keep_base)
            self.aligner = Aligner(tracker, settings.base_max_delay, settings.base_link, log)

    def joint_state(
        self,
        stamp_ns: int,
        names: Sequence[str],
        positions: Sequence[float],
        velocities: Sequence[float] = (),
        efforts: Sequence[float] = (),
        receive_ns: int | None = None,
    ) -> list[Inputs]:
        """A sensor_msgs/JointState's fields; the inputs it completes (see the estimator's modes)."""
        estimates = self.estimator.update(stamp_ns, names, positions, velocities, efforts, receive_ns=receive_ns)
        if self.assembler is not None:
            self._assemble()
        return self._released(estimates)

    def take_raw(self) -> list[RawStates]:
        """The measured joint states at the newest stamps since the last call, in order."""
        out, self.raw = self.raw, []
        return out

    def _assemble(self) -> None:
        assembler = self.assembler
        assert assembler is not None
        for step in self.estimator.accepted:
            if step is RESTART:
                assembler.restart()
                continue
            stamp, samples = step
            joints, q, qd, efforts = zip(*samples, strict=True)
            states = assembler.add(stamp, joints, q, qd, efforts)
            if self.velocities is None and (states is not None or assembler.missing_velocity):
                self.velocities = states is not None
            if states is not None:
                self.raw.append(states)

    def base(self, message: BaseMessage) -> list[Inputs]:
        """A base sensor_msgs/Imu or nav_msgs/Odometry; the inputs of the joint states it lets out."""
        if self.aligner is None:
            return []
        self.aligner.tracker.on_message(message)
        return self._released([])

    def flush(self) -> list[Inputs]:
        """The end of the messages: the stamps still waiting for their lag, without estimates."""
        return self._released(self.estimator.flush())

    def _released(self, estimates: list[JointEstimate]) -> list[Inputs]:
        max_gap = self.settings.estimator.max_gap
        if self.aligner is None:
            return [(JointStates.of_estimate(e, max_gap), None) for e in estimates]
        self.aligner.add(estimates)
        return [(JointStates.of_estimate(e, max_gap), motion) for e, motion in self.aligner.ready()]
