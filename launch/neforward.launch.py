"""Start the neforward node on a URDF or xacro file.

    ros2 launch neforward_ros neforward.launch.py urdf:=/path/to/robot.urdf.xacro
    ros2 launch neforward_ros neforward.launch.py urdf:=robot.urdf params_file:=my_params.yaml use_sim_time:=true

The file is expanded with xacro (a plain URDF passes through unchanged) and given to the node as its
robot_description parameter, the way robot_state_publisher is usually launched: a whole URDF on
the command line (-p robot_description:=...) is rejected by rcl's argument parser for typical files.
"""

from launch.actions import DeclareLaunchArgument
from launch.substitutions import Command, FindExecutable, LaunchConfiguration, PathJoinSubstitution
from launch_ros.actions import Node
from launch_ros.parameter_descriptions import ParameterValue
from launch_ros.substitutions import FindPackageShare

from launch import LaunchDescription


def generate_launch_description() -> LaunchDescription:
    share = FindPackageShare("neforward_ros")
    robot_description = ParameterValue(
        Command([FindExecutable(name="xacro"), " ", LaunchConfiguration("urdf")]), value_type=str
    )
    return LaunchDescription(
        [
            DeclareLaunchArgument(
                "urdf",
                default_value=PathJoinSubstitution([share, "config", "panda.urdf"]),
                description="URDF or xacro file of the robot",
            ),
            DeclareLaunchArgument(
                "params_file",
                default_value=PathJoinSubstitution([share, "config", "neforward.yaml"]),
                description="ROS 2 params file for the node (neforward: ros__parameters: ...)",
            ),
            DeclareLaunchArgument("use_sim_time", default_value="false", description="use the /clock topic"),
            Node(
                package="neforward_ros",
                executable="neforward_node",
                name="neforward",
                output="screen",
                parameters=[
                    LaunchConfiguration("params_file"),
                    {"robot_description": robot_description, "use_sim_time": LaunchConfiguration("use_sim_time")},
                ],
            ),
        ]
    )
