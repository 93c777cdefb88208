"""``neforward run`` and ``neforward echo``: the node and a topic printer over Cyclone DDS."""

from __future__ import annotations

import gc
import logging
import signal
import sys
import threading
import time
from collections.abc import Sequence
from typing import Any

import yaml

from neforward_ros.dds.domain import domain_id
from neforward_ros.dds.qos import default_qos, latched_qos
from neforward_ros.dds.types import RawBytes, raw_reader
from neforward_ros.errors import InputError
from neforward_ros.interface import topics
from neforward_ros.interface.names import NodeNames
from neforward_ros.model import description_text
from neforward_ros.parameters.files import command_line_parameters
from neforward_ros.parameters.settings import node_settings
from neforward_ros.parameters.table import NODE_NAME
from neforward_ros.wire.rostypes import deserialize

_LEVELS = {"DEBUG": logging.DEBUG, "INFO": logging.INFO, "WARN": logging.WARNING, "WARNING": logging.WARNING}
_LEVELS.update({"ERROR": logging.ERROR, "FATAL": logging.CRITICAL})


def run_node(urdf: str | None, params_file: str | None, ros_args: Sequence[str]) -> int:
    """``neforward run``: the node until Ctrl-C or SIGTERM. Start-up errors raise NeforwardError."""
    stop = threading.Event()

    def on_signal(signum: int, frame: Any) -> None:
        # Stop once, whenever it comes (during start-up too); a second Ctrl-C (a terminal signals
        # the whole process group, ros2 launch forwards one more) must not break the shutdown.
        stop.set()
        signal.signal(signal.SIGINT, signal.SIG_IGN)

    signal.signal(signal.SIGINT, on_signal)
    signal.signal(signal.SIGTERM, on_signal)
    from neforward_ros.dds.runtime import DdsNode  # imports cyclonedds

    parsed, values = command_line_parameters(ros_args, params_file=params_file)
    node_name = parsed.node_name or NODE_NAME
    if urdf is not None:
        values["robot_description"] = description_text(urdf)
    settings = node_settings(values)
    use_sim_time = bool(values.get("use_sim_time", False))
    names = NodeNames(node_name, parsed.namespace or "/", parsed.remaps)
    logging.basicConfig(
        level=_LEVELS.get(parsed.log_level or "INFO", logging.INFO),
        format=f"[%(levelname)s] [%(created).6f] [{node_name}]: %(message)s",
        stream=sys.stderr,
    )
    log = logging.getLogger("neforward_ros").log
    domain = domain_id()
    node = DdsNode(settings, names, domain_id=domain, use_sim_time=use_sim_time, log=log)
    outputs = ", ".join(names.resolve(o.topic) for o in node.pipeline.outputs())
    log(logging.INFO, f"node {names.fully_qualified_name} on DDS domain {domain}; publishing {outputs}")
    # Everything allocated so far lives as long as the node: keep it out of the collector's full
    # passes, which otherwise walk it every few hundred messages and show up as latency spikes.
    gc.freeze()
    node.spin(stop)
    log(logging.INFO, f"stopped: {node.messages_in} messages in, {node.messages_out} results out")
    return 0


KNOWN_TYPES = {
    "link_states": topics.LINK_STATES_TYPE,
    "com_states": topics.LINK_STATES_TYPE,
    "accel": topics.ACCEL_TYPE,
    "twist": topics.TWIST_TYPE,
    "imu": topics.IMU_TYPE,
    "markers": topics.MARKERS_TYPE,
    "joint_states": topics.JOINT_STATE_TYPE,
    "joint_states_accel": topics.JOINT_TRAJECTORY_TYPE,
    "robot_description": topics.STRING_TYPE,
}


def topic_type(topic: str, participant: Any, wait_s: float = 5.0) -> str:
    """The ROS 2 type of a topic: from its last name token for neforward's topics, else from discovery."""
    known = KNOWN_TYPES.get(topic.rstrip("/").rsplit("/", 1)[-1])
    if known:
        return known
    from cyclonedds.builtin import BuiltinDataReader, BuiltinTopicDcpsPublication

    reader = BuiltinDataReader(participant, BuiltinTopicDcpsPublication)
    deadline = time.monotonic() + wait_s
    while time.monotonic() < deadline:
        for endpoint in reader.take(N=100):
            if getattr(endpoint, "topic_name", None) == "rt" + topic:
                package, kind, _, name = endpoint.type_name.split("::")
                return f"{package}/{kind}/{name.rstrip('_')}"
        time.sleep(0.1)
    raise InputError(f"no publisher of {topic} found in {wait_s:g} s; give its type with --type pkg/msg/Type")


def echo(topic: str, typename: str | None, count: int | None) -> int:
    """``neforward echo``: print messages of a topic as YAML, like ``ros2 topic echo``."""
    from cyclonedds.core import InstanceState, ReadCondition, SampleState, ViewState, WaitSet
    from cyclonedds.domain import DomainParticipant
    from cyclonedds.util import duration

    name = NodeNames().resolve(topic)
    participant = DomainParticipant(domain_id())
    typename = typename or topic_type(name, participant)
    qos = latched_qos(typename) if name.endswith("/robot_description") else default_qos(typename)
    reader = raw_reader(participant, "rt" + name, typename, qos)
    waitset = WaitSet(participant)
    waitset.attach(ReadCondition(reader, SampleState.Any | ViewState.Any | InstanceState.Any))
    printed = 0
    try:
        while count is None or printed < count:
            waitset.wait(duration(seconds=0.2))
            for data in reader.take(N=64):
                if not isinstance(data, RawBytes):
                    continue  # a publisher went away: no data
                sys.stdout.write(yaml.safe_dump(deserialize(typename, bytes(data)), sort_keys=False) + "---\n")
                printed += 1
                if count is not None and printed >= count:
                    break
            sys.stdout.flush()
    except KeyboardInterrupt:
        pass
    return 0
