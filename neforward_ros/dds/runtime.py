"""The neforward node over Cyclone DDS: same pipeline, topics, types, QoS and parameters as the rclpy node.

Thin, like the rclpy adapter: raw readers hand CDR bytes to
:class:`neforward_ros.handlers.MessageHandlers`, which gives back CDR bytes for raw writers. The
handling of every message is the rclpy node's, line for line, since it is the same code.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from typing import Any

from cyclonedds.core import InstanceState, Listener, ReadCondition, SampleState, ViewState, WaitSet
from cyclonedds.domain import DomainParticipant
from cyclonedds.pub import DataWriter
from cyclonedds.qos import Policy, Qos
from cyclonedds.topic import Topic
from cyclonedds.util import duration

from neforward_ros.dds.graph import GraphAnnouncer
from neforward_ros.dds.qos import default_qos, latched_qos, participant_qos
from neforward_ros.dds.types import RawBytes, dds_type, raw_reader, raw_sample
from neforward_ros.interface import topics
from neforward_ros.interface.names import NodeNames
from neforward_ros.interface.topics import JOINT_STATES, JOINT_STATES_ACCEL, ROBOT_DESCRIPTION
from neforward_ros.logs import BoundedLog, LogFunction, ThrottledLog, python_log
from neforward_ros.node.handlers import MessageHandlers, decode_clock_ns
from neforward_ros.node.pipeline import Pipeline
from neforward_ros.parameters.settings import NodeSettings

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
        log = BoundedLog(log if log is not None else python_log())
        self._log = ThrottledLog(log)
        self.pipeline = Pipeline(settings, log=log)
        self.participant = DomainParticipant(domain_id, qos=participant_qos())
        self._writers: dict[str, tuple[str, DataWriter]] = {}
        for output in self.pipeline.outputs():
            override = settings.qos_override(self.names.resolve(output.topic), "publisher")
            self._writers[output.topic] = (
                output.type,
                self._writer(output.topic, output.type, default_qos(output.type, override=override)),
            )
        self.handlers = MessageHandlers(self.pipeline, self._publish, log=log)
        self._readers: list[tuple[Any, Callable[[bytes], None]]] = []
        if settings.acceleration_source == "supplied":
            self._input(JOINT_STATES_ACCEL, topics.JOINT_TRAJECTORY_TYPE, self.handlers.on_joint_trajectory)
        else:
            self._input(JOINT_STATES, topics.JOINT_STATE_TYPE, self.handlers.on_joint_state)
        if settings.base_source != "fixed":
            kind = topics.IMU_TYPE if settings.base_source == "imu" else topics.ODOMETRY_TYPE
            self._input(settings.base_topic, kind, self.handlers.on_base)
        if not settings.robot_description:
            string = topics.STRING_TYPE
            self._reader(ROBOT_DESCRIPTION, string, latched_qos(string), self.handlers.on_description)
        self._sim_time_ns: int | None = None
        if use_sim_time:
            best_effort = Qos(Policy.Reliability.BestEffort, Policy.History.KeepLast(1))
            self._reader("/clock", CLOCK_TYPE, best_effort, self._on_clock)
        self._waitset = WaitSet(self.participant)
        for reader, _ in self._readers:
            self._waitset.attach(ReadCondition(reader, _ANY))
        self._graph = GraphAnnouncer(self.participant)
        self._graph.announce(
            self.names.namespace,
            self.names.node_name,
            [reader for reader, _ in self._readers],
            [writer for _, writer in self._writers.values()],
        )

    @property
    def messages_in(self) -> int:
        return self.handlers.messages_in

    @property
    def messages_out(self) -> int:
        return self.handlers.results_out

    # -- entities ---------------------------------------------------------------------------

    def _writer(self, name: str, typename: str, qos: Qos) -> DataWriter:
        topic = Topic(self.participant, self.names.dds_topic(name), dds_type(typename))
        return DataWriter(self.participant, topic, qos=qos)

    def _input(self, name: str, typename: str, handler: Callable[[bytes, int], None]) -> None:
        """An input topic: ROS 2 default QoS with ``qos_depth``, then the ``qos_overrides``."""
        settings = self.pipeline.settings
        override = settings.qos_override(self.names.resolve(name), "subscription")
        self._reader(
            name,
            typename,
            default_qos(typename, settings.qos_depth, override),
            lambda data: handler(data, self._receive_ns()),
            listener=Listener(on_requested_incompatible_qos=lambda reader, status: self._incompatible(name, status)),
        )

    def _reader(
        self, name: str, typename: str, qos: Qos, handler: Callable[[bytes], None], listener: Any = None
    ) -> None:
        reader = raw_reader(self.participant, self.names.dds_topic(name), typename, qos, listener)
        self._readers.append((reader, handler))

    def _incompatible(self, name: str, status: Any) -> None:
        topic = self.names.resolve(name)
        self._log.every(
            ("incompatible", name),
            logging.WARNING,
            f"a publisher on {topic} offers QoS incompatible with this subscription (policy id "
            f"{status.last_policy_id}): its messages are not received. For a best-effort publisher, set the "
            f"parameter qos_overrides.{topic}.subscription.reliability: best_effort",
        )

    # -- loop -------------------------------------------------------------------------------

    def spin_once(self, timeout_s: float = 0.1) -> int:
        """Wait up to ``timeout_s`` for input, handle all of it; returns the number of samples."""
        self._waitset.wait(duration(seconds=timeout_s))
        count = 0
        for reader, handler in self._readers:
            while True:
                samples = reader.take(N=_BATCH)
                for sample in samples:
                    if isinstance(sample, RawBytes):  # not the notice of a writer gone away
                        handler(sample)
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

    def _on_clock(self, data: bytes) -> None:
        try:
            self._sim_time_ns = decode_clock_ns(data)
        except Exception as exc:
            self._log.every("clock", logging.ERROR, f"/clock message dropped: {type(exc).__name__}: {exc}")

    def _publish(self, topic: str, payload: bytes) -> None:
        typename, writer = self._writers[topic]
        writer.write(raw_sample(typename, payload))
