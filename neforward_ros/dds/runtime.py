"""The neforward node over Cyclone DDS: same pipeline, topics, types, QoS and parameters as the rclpy node.

Thin, like the rclpy adapter: readers in, :class:`neforward_ros.pipeline.Pipeline` in the middle,
writers out. Messages are encoded by :mod:`neforward_ros.cdr` from the contents that
:mod:`neforward_ros.messages` builds, so the bytes equal what an rclpy node would send.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from typing import Any

from cyclonedds.core import InstanceState, ReadCondition, SampleState, ViewState, WaitSet
from cyclonedds.domain import DomainParticipant
from cyclonedds.pub import DataWriter
from cyclonedds.qos import Policy, Qos
from cyclonedds.sub import DataReader, InvalidSample
from cyclonedds.topic import Topic
from cyclonedds.util import duration

from neforward_ros import cdr, messages
from neforward_ros.dds.graph import GraphAnnouncer
from neforward_ros.dds.names import NodeNames
from neforward_ros.dds.qos import default_qos, latched_qos, participant_qos
from neforward_ros.dds.types import dds_type, raw_sample
from neforward_ros.logs import LogFunction, ThrottledLog
from neforward_ros.parameters import NodeSettings
from neforward_ros.pipeline import JOINT_STATES, JOINT_STATES_ACCEL, ROBOT_DESCRIPTION, Pipeline, TrajectoryPoint

CLOCK_TYPE = "rosgraph_msgs/msg/Clock"
_ANY = SampleState.Any | ViewState.Any | InstanceState.Any
_BATCH = 256


class DdsNode:
    """The node on a DDS domain.

    Args:
        settings: validated parameters.
        names: node name, namespace and remap rules.
        domain_id: DDS domain (ROS_DOMAIN_ID).
        use_sim_time: take the receive time for zero stamps from ``/clock``.
        log: ``log(level, message)``.

    Raises:
        ModelError, InputError: an invalid robot_description parameter or settings.
    """

    def __init__(
        self,
        settings: NodeSettings,
        names: NodeNames | None = None,
        *,
        domain_id: int = 0,
        use_sim_time: bool = False,
        log: LogFunction | None = None,
    ) -> None:
        self.names = names if names is not None else NodeNames()
        self._log = ThrottledLog(log)
        self.pipeline = Pipeline(settings, log=log)
        self.participant = DomainParticipant(domain_id, qos=participant_qos())
        self.messages_in = 0
        self.messages_out = 0
        self._writers: dict[str, tuple[str, DataWriter]] = {}
        for output in self.pipeline.outputs():
            self._writers[output.topic] = (
                output.type,
                self._writer(output.topic, output.type, default_qos(output.type)),
            )
        self._handlers: list[tuple[DataReader, Callable[[Any], None]]] = []
        depth = settings.qos_depth
        if settings.acceleration_source == "supplied":
            trajectory = messages.JOINT_TRAJECTORY_TYPE
            self._reader(JOINT_STATES_ACCEL, trajectory, default_qos(trajectory, depth), self._on_joint_trajectory)
        else:
            joint_state = messages.JOINT_STATE_TYPE
            self._reader(JOINT_STATES, joint_state, default_qos(joint_state, depth), self._on_joint_state)
        if not settings.robot_description:
            string = messages.STRING_TYPE
            self._reader(ROBOT_DESCRIPTION, string, latched_qos(string), self._on_description)
        self._sim_time_ns: int | None = None
        if use_sim_time:
            best_effort = Qos(Policy.Reliability.BestEffort, Policy.History.KeepLast(1))
            self._reader("/clock", CLOCK_TYPE, best_effort, self._on_clock)
        self._waitset = WaitSet(self.participant)
        for reader, _ in self._handlers:
            self._waitset.attach(ReadCondition(reader, _ANY))
        self._graph = GraphAnnouncer(self.participant)
        self._graph.announce(
            self.names.namespace,
            self.names.node_name,
            [reader for reader, _ in self._handlers],
            [writer for _, writer in self._writers.values()],
        )

    # -- entities ---------------------------------------------------------------------------

    def _writer(self, name: str, typename: str, qos: Qos) -> DataWriter:
        topic = Topic(self.participant, self.names.dds_topic(name), dds_type(typename))
        return DataWriter(self.participant, topic, qos=qos)

    def _reader(self, name: str, typename: str, qos: Qos, handler: Callable[[Any], None]) -> None:
        topic = Topic(self.participant, self.names.dds_topic(name), dds_type(typename))
        self._handlers.append((DataReader(self.participant, topic, qos=qos), handler))

    # -- loop -------------------------------------------------------------------------------

    def spin_once(self, timeout_s: float = 0.1) -> int:
        """Wait up to ``timeout_s`` for input, handle all of it; returns the number of samples."""
        self._waitset.wait(duration(seconds=timeout_s))
        count = 0
        for reader, handler in self._handlers:
            while True:
                samples = reader.take(N=_BATCH)
                for sample in samples:
                    if isinstance(sample, InvalidSample):  # a writer went away: state, not data
                        continue
                    try:
                        handler(sample)
                    except Exception as exc:
                        self._log.every("handler", logging.ERROR, f"message dropped: {type(exc).__name__}: {exc}")
                count += len(samples)
                if len(samples) < _BATCH:
                    break
        return count

    def spin(self, stop: threading.Event | None = None, until: float | None = None) -> None:
        """Handle input until ``stop`` is set or the monotonic time ``until`` passes."""
        while not (stop is not None and stop.is_set()) and not (until is not None and time.monotonic() >= until):
            self.spin_once(0.1)

    # -- handlers ---------------------------------------------------------------------------

    def _receive_ns(self) -> int:
        if self._sim_time_ns is not None:
            return self._sim_time_ns
        return time.time_ns()

    def _on_clock(self, sample: Any) -> None:
        self._sim_time_ns = messages.stamp_ns(sample.clock)

    def _on_description(self, sample: Any) -> None:
        self.pipeline.set_description(sample.data)

    def _on_joint_state(self, sample: Any) -> None:
        self.messages_in += 1
        results = self.pipeline.on_joint_state(
            messages.stamp_ns(sample.header.stamp),
            sample.name,
            sample.position,
            sample.velocity,
            receive_ns=self._receive_ns(),
        )
        self._publish(results)

    def _on_joint_trajectory(self, sample: Any) -> None:
        self.messages_in += 1
        points = [
            TrajectoryPoint(p.positions, p.velocities, p.accelerations, messages.stamp_ns(p.time_from_start))
            for p in sample.points
        ]
        stamp = messages.stamp_ns(sample.header.stamp)
        self._publish(
            self.pipeline.on_joint_trajectory(stamp, sample.joint_names, points, receive_ns=self._receive_ns())
        )

    def _publish(self, results: list) -> None:
        for result in results:
            for topic, contents in self.pipeline.messages(result):
                typename, writer = self._writers[topic]
                writer.write(raw_sample(typename, cdr.encode(typename, contents)))
            self.messages_out += 1
