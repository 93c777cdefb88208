"""Start the neforward node on a URDF or xacro file.

    ros2 launch neforward_ros neforward.launch.py urdf:=/path/to/robot.urdf.xacro
    ros2 launch neforward_ros neforward.launch.py urdf:=robot.urdf namespace:=robot1 use_sim_time:=true
    ros2 launch neforward_ros neforward.launch.py urdf:=arm.xacro xacro_args:="prefix:=left_ tool:=gripper"

The file is given to the node as its robot_description parameter, the way robot_state_publisher is
usually launched (a whole URDF on the command line, -p robot_description:=..., is rejected by rcl's
argument parser for typical files). A ``.xacro`` file, or a file that uses xacro (the node's rule:
``neforward_ros.model.xacro``; declaring the namespace, as xacro's own output does, is not using it),
or one given ``xacro_args``, is expanded with xacro first: its warnings are shown and do not stop the
launch, and paths may contain spaces. A plain URDF is read as it is and needs no xacro.
"""

from __future__ import annotations

import os
import shlex
import shutil
import subprocess
import sys

from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.launch_context import LaunchContext
from launch.substitutions import LaunchConfiguration, PathJoinSubstitution
from launch_ros.actions import Node
from launch_ros.substitutions import FindPackageShare

from launch import LaunchDescription


def robot_description(path: str, xacro_args: str = "") -> str:
    """The URDF text of a URDF or xacro file."""
    if not os.path.isfile(path):
        raise RuntimeError(f"urdf:={path}: no such file")
    with open(path, encoding="utf-8") as stream:
        text = stream.read()
    if not (path.endswith(".xacro") or xacro_args.strip() or _uses_xacro(text)):
        return text
    arguments = [path, *shlex.split(xacro_args)]
    executable = shutil.which("xacro")
    if executable is None:
        try:
            import xacro  # noqa: F401  (ROS's xacro and PyPI's xacro both provide the module)
        except ImportError:
            raise RuntimeError(f"{path} is xacro: install xacro (ros-jazzy-xacro, or pip install xacro)") from None
        command = [sys.executable, "-c", "import sys, xacro; sys.argv[0] = 'xacro'; xacro.main()", *arguments]
    else:
        command = [executable, *arguments]
    done = subprocess.run(command, capture_output=True, text=True, check=False)
    if done.stderr.strip():
        print(done.stderr.rstrip(), file=sys.stderr)  # xacro's warnings: shown, not fatal
    if done.returncode != 0:
        raise RuntimeError(f"xacro failed on {path} (exit code {done.returncode})")
    return done.stdout


def _uses_xacro(text: str) -> bool:
    from neforward_ros.errors import ModelError

    try:
        from neforward_ros.model.document import parse_document
        from neforward_ros.model.xacro import xacro_use

        return xacro_use(parse_document(text)).needed is not None
    except ImportError:  # ros2 launch runs on the system's Python, which may lack lxml (a pip dependency)
        return any(mark in text for mark in ("<xacro:", "${", "$("))
    except ModelError:  # not XML: the node says what is wrong with it
        return False


def _node(context: LaunchContext) -> list[Node]:
    def value(name: str) -> str:
        return LaunchConfiguration(name).perform(context)

    return [
        Node(
            package="neforward_ros",
            executable="neforward_node",
            name="neforward",
            namespace=value("namespace"),
            output="screen",
            parameters=[
                value("params_file"),
                {
                    "robot_description": robot_description(value("urdf"), value("xacro_args")),
                    "use_sim_time": value("use_sim_time").lower() in ("true", "1", "yes"),
                },
            ],
        )
    ]


def generate_launch_description() -> LaunchDescription:
    share = FindPackageShare("neforward_ros")
    return LaunchDescription(
        [
            DeclareLaunchArgument(
                "urdf",
                default_value=PathJoinSubstitution([share, "config", "panda.urdf"]),
                description="URDF or xacro file of the robot",
            ),
            DeclareLaunchArgument("xacro_args", default_value="", description="xacro arguments: name:=value ..."),
            DeclareLaunchArgument(
                "params_file",
                default_value=PathJoinSubstitution([share, "config", "neforward.yaml"]),
                description="ROS 2 params file for the node (/**/neforward: ros__parameters: ...)",
            ),
            DeclareLaunchArgument("namespace", default_value="", description="namespace of the node"),
            DeclareLaunchArgument("use_sim_time", default_value="false", description="use the /clock topic"),
            OpaqueFunction(function=_node),
        ]
    )
