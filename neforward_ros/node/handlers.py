"""The message handling both runtimes share: CDR bytes in, CDR bytes out.

The rclpy node (raw subscriptions, serialized publishing) and the no-ROS DDS node (raw readers and
writers) each hand the bytes of every incoming message to :class:`MessageHandlers` and give it a
``publish(topic, payload)`` function; everything between (decoding, the pipeline, message building,
encoding, publishing) happens here, once. No exception escapes a handler: whatever goes wrong with
one message is logged, throttled, and the next message is handled as if nothing happened.
"""

from __future__ import annotations

import logging
import struct
from collections.abc import Callable

from neforward_ros.computation.base_motion import base_message
from neforward_ros.computation.result import Observation, Result
from neforward_ros.interface import topics
from neforward_ros.logs import LogFunction, ThrottledLog
from neforward_ros.node.pipeline import Pipeline, TrajectoryPoint
from neforward_ros.stamps import stamp_ns
from neforward_ros.wire import cdr
from neforward_ros.wire.rostypes import deserialize

Publish = Callable[[str, bytes], None]
"""``publish(topic, payload)``: the runtime's publisher of the relative topic name, CDR bytes."""


class MessageHandlers:
    """Decode, compute, encode and publish, for every input topic of the node.

    Args:
        pipeline: the node's core.
        publish: sends CDR bytes on one of ``pipeline.outputs()`` (relative topic names).
        log: ``log(level, message)``.

    Attributes:
        messages_in: input messages handled (joint states or trajectories).
        results_out: results published (one per output stamp of the estimator; the momentum
            observer's observations are not counted).
    """

    def __init__(self, pipeline: Pipeline, publish: Publish, log: LogFunction | None = None) -> None:
        self.pipeline = pipeline
        self._publish = publish
        self._log = ThrottledLog(log)
        self._types = {output.topic: output.type for output in pipeline.outputs()}
        for typename in {*self._types.values(), topics.JOINT_STATE_TYPE}:
            cdr.warm_up(typename)  # generate the encoders now, not while the first message waits
        self.messages_in = 0
        self.results_out = 0

    def on_joint_state(self, data: bytes, receive_ns: int) -> None:
        """A sensor_msgs/JointState, as CDR bytes."""
        self.messages_in += 1
        try:
            stamp, names, positions, velocities, efforts = cdr.decode_joint_state(data)
            results = self.pipeline.on_joint_state(stamp, names, positions, velocities, efforts, receive_ns=receive_ns)
        except Exception as exc:
            self._dropped("joint state", exc)
            return
        self._publish_results(results, "joint state")

    def on_joint_trajectory(self, data: bytes, receive_ns: int) -> None:
        """A trajectory_msgs/JointTrajectory of supplied states, as CDR bytes."""
        self.messages_in += 1
        try:
            message = deserialize(topics.JOINT_TRAJECTORY_TYPE, data)
            points = [
                TrajectoryPoint(
                    p["positions"], p["velocities"], p["accelerations"], stamp_ns(p["time_from_start"]), p["effort"]
                )
                for p in message["points"]
            ]
            stamp = stamp_ns(message["header"]["stamp"])
            results = self.pipeline.on_joint_trajectory(stamp, message["joint_names"], points, receive_ns=receive_ns)
        except Exception as exc:
            self._dropped("joint trajectory", exc)
            return
        self._publish_results(results, "joint trajectory")

    def on_base(self, data: bytes, receive_ns: int) -> None:
        """A base sensor_msgs/Imu or nav_msgs/Odometry (by ``base.source``), as CDR bytes."""
        self.messages_in += 1
        source = self.pipeline.settings.base_source
        try:
            kind = topics.IMU_TYPE if source == "imu" else topics.ODOMETRY_TYPE
            message = base_message(source, deserialize(kind, data), receive_ns)
            results = self.pipeline.on_base(message)
        except Exception as exc:
            self._dropped(f"base {source} message", exc)
            return
        self._publish_results(results, f"base {source} message")

    def on_description(self, data: bytes) -> None:
        """A std_msgs/String robot description, as CDR bytes: replaces the model when valid."""
        try:
            self.pipeline.set_description(cdr.decode_string(data))
        except Exception as exc:
            self._dropped("robot description", exc)

    def _publish_results(self, results: list[Result | Observation], what: str) -> None:
        for result in results:
            try:
                payloads = self.pipeline.encode(result)
            except Exception as exc:
                self._dropped(what, exc, "cannot build its messages")
                continue
            for topic, payload in payloads:
                try:
                    self._publish(topic, payload)
                except Exception as exc:
                    self._log.every(
                        ("publish", topic), logging.ERROR, f"publishing on {topic} failed: {type(exc).__name__}: {exc}"
                    )
            if isinstance(result, Result):
                self.results_out += 1

    def _dropped(self, what: str, exc: Exception, why: str = "") -> None:
        detail = f"{why}: " if why else ""
        self._log.every(("dropped", what), logging.ERROR, f"{what} dropped: {detail}{type(exc).__name__}: {exc}")


def decode_clock_ns(data: bytes) -> int:
    """Nanoseconds of a rosgraph_msgs/Clock (or any message that starts with a builtin_interfaces/Time)."""
    sec, nanosec = struct.unpack_from("<iI", data, 4)
    return sec * 1_000_000_000 + nanosec
