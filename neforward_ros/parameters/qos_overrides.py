"""ROS 2 QoS override parameters: ``qos_overrides.<topic>.<publisher|subscription>.<policy>``."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from neforward_ros.errors import InputError

QOS_OVERRIDES = "qos_overrides."
QOS_POLICIES = {"reliability": ("reliable", "best_effort", "system_default"), "history": ("keep_last", "keep_all")}
QOS_POLICIES_INT = ("depth",)
QOS_ENTITIES = ("publisher", "subscription")


@dataclass(frozen=True)
class QosOverride:
    """QoS policies a parameter file sets for one topic's publisher or subscription, ROS 2 style:
    ``qos_overrides./joint_states.subscription.reliability: best_effort``. None keeps the node's own."""

    reliability: str | None = None
    history: str | None = None
    depth: int | None = None


def qos_overrides(values: Mapping[str, Any]) -> dict[tuple[str, str], QosOverride]:
    """``qos_overrides.<topic>.<publisher|subscription>.<policy>`` values, checked, grouped per entity."""
    grouped: dict[tuple[str, str], dict[str, Any]] = {}
    for name, value in values.items():
        parts = name[len(QOS_OVERRIDES) :].rsplit(".", 2)
        if len(parts) != 3 or not parts[0].startswith("/") or parts[1] not in QOS_ENTITIES:
            raise InputError(
                f"parameter {name}: QoS overrides are named qos_overrides.<fully qualified topic>."
                "<publisher|subscription>.<policy>, e.g. qos_overrides./joint_states.subscription.reliability"
            )
        topic, entity, policy = parts
        if policy in QOS_POLICIES:
            if value not in QOS_POLICIES[policy]:
                raise InputError(f"parameter {name} must be one of {', '.join(QOS_POLICIES[policy])}, got {value!r}")
        elif policy in QOS_POLICIES_INT:
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise InputError(f"parameter {name} must be a positive integer, got {value!r}")
        else:
            known = ", ".join([*QOS_POLICIES, *QOS_POLICIES_INT])
            raise InputError(f"parameter {name}: this node lets a file override {known}, not {policy}")
        grouped.setdefault((topic, entity), {})[policy] = value
    return {key: QosOverride(**policies) for key, policies in grouped.items()}
