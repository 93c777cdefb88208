"""QoS profiles matching ROS 2's, with the type hash in USER_DATA as rmw_cyclonedds puts it."""

from __future__ import annotations

from cyclonedds.qos import Policy, Qos

from neforward_ros.dds.types import type_hash
from neforward_ros.parameters.qos_overrides import QosOverride

_MAX_BLOCKING_NS = 100_000_000  # rmw_qos_profile_default leaves it to the RMW; Cyclone's default


def _common(typename: str, best_effort: bool = False) -> list:
    reliability = Policy.Reliability.BestEffort if best_effort else Policy.Reliability.Reliable(_MAX_BLOCKING_NS)
    return [
        reliability,
        Policy.DataRepresentation(use_cdrv0_representation=True),  # plain CDR (XCDR1), as ROS 2 sends
        Policy.Userdata(f"typehash={type_hash(typename)};".encode()),
    ]


def default_qos(typename: str, depth: int = 10, override: QosOverride | None = None) -> Qos:
    """ROS 2's default: reliable, volatile, keep last ``depth`` (10); ``override`` changes the
    reliability, history and depth as the ``qos_overrides.*`` parameters say."""
    override = override if override is not None else QosOverride()
    depth = override.depth if override.depth is not None else depth
    history = Policy.History.KeepAll if override.history == "keep_all" else Policy.History.KeepLast(depth)
    return Qos(Policy.Durability.Volatile, history, *_common(typename, override.reliability == "best_effort"))


def latched_qos(typename: str, depth: int = 1) -> Qos:
    """Transient local, reliable, keep last ``depth``: robot_description, ros_discovery_info."""
    return Qos(Policy.Durability.TransientLocal, Policy.History.KeepLast(depth), *_common(typename))


def participant_qos() -> Qos:
    """USER_DATA ``enclave=/;`` as ROS 2 participants carry it (the default security enclave)."""
    return Qos(Policy.Userdata(b"enclave=/;"))
