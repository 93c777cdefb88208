"""``neforward_node``: the entry point of the rclpy node, light enough to fail with one line.

It imports nothing heavy before it knows ROS 2 is there: started without a sourced ROS 2 (or with
a dependency missing) it prints one line saying what to do, not a traceback.
"""

from __future__ import annotations

import importlib.util
import sys

PROGRAM = "neforward_node"
PIP_PACKAGES = {"rosbags": "the ROS 2 message definitions the node encodes with"}
"""Packages the node needs that ROS 2 does not bring (no rosdep keys yet): pip installs them."""


def main() -> int:
    if importlib.util.find_spec("rclpy") is None:
        print(
            f"{PROGRAM}: error: ROS 2 is not sourced (rclpy cannot be imported): run "
            "`source /opt/ros/jazzy/setup.bash` first, or use `neforward run`, the same node without ROS",
            file=sys.stderr,
        )
        return 1
    missing = [name for name in PIP_PACKAGES if importlib.util.find_spec(name) is None]
    if missing:
        what = "; ".join(f"{name} ({PIP_PACKAGES[name]})" for name in missing)
        install = f"pip install {' '.join(missing)}"
        print(f"{PROGRAM}: error: cannot start: {what} not installed in {sys.executable}: {install}", file=sys.stderr)
        return 1
    try:
        from neforward_ros import ros_node
    except ImportError as exc:
        print(f"{PROGRAM}: error: cannot start: {exc}", file=sys.stderr)
        return 1
    return ros_node.main()


if __name__ == "__main__":
    sys.exit(main())
