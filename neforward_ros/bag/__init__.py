"""``neforward bag``, offline: rosbag2 recordings of joint states in, the node's outputs out (rosbag2, CSV, plot).

``neforward bag INPUT -o OUTPUT`` reads a rosbag2 recording (sqlite3 or MCAP) with rosbags, no ROS
needed, estimates every joint's velocity and acceleration as the node does (by default with the
whole-recording fixed-lag fit; any other estimator setting replays the node's streaming estimator),
runs the batched recursion, and writes a new recording with the node's topics, types and stamps.
Stamps that go backwards split the recording into segments, each estimated on its own. Nothing
half-written is ever left under the output names: files are written under a temporary name and
renamed at the end. Many recordings at once: :mod:`neforward_ros.bag.fleet`.

The names below are imported on first use, so that the command line starts quickly.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

_EXPORTS = {
    "BagOptions": "neforward_ros.bag.options",
    "BagReport": "neforward_ros.bag.report",
    "Progress": "neforward_ros.bag.report",
    "describe": "neforward_ros.bag.report",
    "process_bag": "neforward_ros.bag.process",
}

__all__ = ["BagOptions", "BagReport", "Progress", "describe", "process_bag"]

if TYPE_CHECKING:
    from neforward_ros.bag.options import BagOptions
    from neforward_ros.bag.process import process_bag
    from neforward_ros.bag.report import BagReport, Progress, describe


def __getattr__(name: str) -> Any:
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'neforward_ros.bag' has no attribute {name!r}")
    return getattr(importlib.import_module(module), name)
