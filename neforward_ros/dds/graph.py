"""Announce the node in the ROS 2 graph, as ROS 2 nodes do.

ROS 2 (rmw_dds_common) keeps a graph of nodes from the ``ros_discovery_info`` topic: each
participant publishes a ParticipantEntitiesInfo with its GID and, per node, the node's namespace,
name and the GIDs of its readers and writers. With rmw_cyclonedds a GID is the entity's 16-byte DDS
GUID. This is what makes ``ros2 node list`` show ``/neforward`` and ``ros2 topic info -v`` name it.
"""

from __future__ import annotations

from typing import Any

from cyclonedds.domain import DomainParticipant
from cyclonedds.pub import DataWriter
from cyclonedds.topic import Topic

from neforward_ros.dds.qos import latched_qos
from neforward_ros.dds.types import dds_type, raw_sample
from neforward_ros.wire import cdr

DISCOVERY_TOPIC = "ros_discovery_info"  # no rt/ prefix: an RMW-internal topic
DISCOVERY_TYPE = "rmw_dds_common/msg/ParticipantEntitiesInfo"


def gid(entity: Any) -> dict[str, list[int]]:
    """rmw_dds_common/Gid of a DDS entity: its GUID's 16 bytes."""
    return {"data": list(entity.guid.bytes)}


def entities_info(participant: Any, namespace: str, node_name: str, readers: list, writers: list) -> dict:
    """ParticipantEntitiesInfo contents for one node."""
    return {
        "gid": gid(participant),
        "node_entities_info_seq": [
            {
                "node_namespace": namespace,
                "node_name": node_name,
                "reader_gid_seq": [gid(r) for r in readers],
                "writer_gid_seq": [gid(w) for w in writers],
            }
        ],
    }


class GraphAnnouncer:
    """Publishes the node's entities on ``ros_discovery_info`` (transient local, keep last 1)."""

    def __init__(self, participant: DomainParticipant) -> None:
        self.participant = participant
        topic = Topic(participant, DISCOVERY_TOPIC, dds_type(DISCOVERY_TYPE))
        self.writer = DataWriter(participant, topic, qos=latched_qos(DISCOVERY_TYPE))

    def announce(self, namespace: str, node_name: str, readers: list, writers: list) -> None:
        contents = entities_info(self.participant, namespace, node_name, readers, writers)
        self.writer.write(raw_sample(DISCOVERY_TYPE, cdr.encode(DISCOVERY_TYPE, contents)))
