"""The no-ROS runtime: the node over Eclipse Cyclone DDS, speaking ROS 2's names, types and QoS.

A plain DDS participant that uses ROS 2's topic names (``rt/...``), type names
(``pkg::msg::dds_::T_``), CDR layout and QoS is a peer of ROS 2 nodes running on rmw_cyclonedds.
Message types come from the rosbags ROS 2 Jazzy type store (:mod:`neforward_ros.dds.types`).
"""
