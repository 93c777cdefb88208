"""The node, independent of its transport: settings, names, topics, the pipeline from joint states to
results, the messages built from results, and the per-message handling both runtimes share.

The rclpy adapter (:mod:`neforward_ros.ros_node`) and the Cyclone DDS runtime (:mod:`neforward_ros.dds`)
only move bytes between their middleware and :class:`.handlers.MessageHandlers`.
"""
