"""The DDS domain of the no-ROS runtime: ``ROS_DOMAIN_ID``, as ROS 2 reads it (cyclonedds alone ignores it)."""

from __future__ import annotations

import os

from neforward_ros.errors import InputError


def domain_id() -> int:
    """ROS_DOMAIN_ID, 0 when unset, as ROS 2 does."""
    text = os.environ.get("ROS_DOMAIN_ID", "").strip()
    if not text:
        return 0
    if not text.isdigit() or int(text) > 232:
        raise InputError(f"ROS_DOMAIN_ID must be an integer from 0 to 232, got {text!r}")
    return int(text)
