"""ROS 2 messages on the wire without ROS: the Jazzy type definitions (via rosbags) and fast CDR."""
