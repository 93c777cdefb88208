"""Messages one at a time -> the inputs of :func:`~neforward_ros.computation.compute.compute` they
complete: the streaming estimator and, for a moving base, the base tracker and the aligner.

The node feeds it messages as they arrive; the bag tool replays a recording's messages through it
when the estimator is anything but its whole-recording default (causal, another lag, kalman), so
that the replay gives what the node gives.
"""

from __future__ import annotations

from collections.abc import Sequence

from neforward_ros.computation.base_motion import Aligner, BaseMessage, BaseTracker
from neforward_ros.computation.inputs import JointStates, LinkMotion
from neforward_ros.estimation.estimate import JointEstimate
from neforward_ros.estimation.stream import StreamingEstimator
from neforward_ros.logs import LogFunction
from neforward_ros.model import RobotModel
from neforward_ros.parameters.settings import NodeSettings

Inputs = tuple[JointStates, LinkMotion | None]


class LiveInputs:
    """See the module docstring.

    Args:
        model: the robot.
        settings: the node's settings (the estimator's, the base source's).
        log: ``log(level, message)``.
        keep_base: base estimates kept (the bag tool keeps all: None).
    """

    def __init__(
        self, model: RobotModel, settings: NodeSettings, log: LogFunction | None = None, keep_base: int | None = 4096
    ) -> None:
        self.settings = settings
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
        return self._released(estimates)

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
