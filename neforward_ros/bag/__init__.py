"""``neforward bag``, offline: rosbag2 recordings of joint states in, the node's outputs out (rosbag2, CSV, plot).

``neforward bag INPUT -o OUTPUT`` reads a rosbag2 recording (sqlite3 or MCAP) with rosbags, no ROS
needed, estimates every joint's velocity and acceleration with the whole-recording (non-causal)
estimator, runs the batched recursion, and writes a new recording with the node's topics, types
and stamps. Stamps that go backwards split the recording into segments, each estimated on its own.
Nothing half-written is ever left under the output names: files are written under a temporary
name and renamed at the end.
"""

from neforward_ros.bag.process import BagOptions, process_bag
from neforward_ros.bag.report import BagReport, Progress, describe

__all__ = ["BagOptions", "BagReport", "Progress", "describe", "process_bag"]
