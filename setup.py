from glob import glob

from setuptools import find_packages, setup

package_name = "neforward_ros"

setup(
    name=package_name,
    version="0.1.0",
    packages=find_packages(exclude=["test", "test.*", "bench"]),
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        ("share/" + package_name, ["package.xml"]),
        ("share/" + package_name + "/config", glob("config/*")),
        ("share/" + package_name + "/launch", glob("launch/*.launch.py")),
    ],
    python_requires=">=3.11",
    install_requires=[
        "setuptools",
        "numpy>=1.24",
        "pyyaml>=6",
        # the URDF library: its element readers (URDF._parse_joint, _parse_inertial ...) are used
        "yourdfpy>=0.0.53,<0.1",
        "rosbags>=0.10",
        "cyclonedds>=0.10.5",
    ],
    extras_require={
        "plot": ["matplotlib>=3.6"],
        "docs": ["sphinx>=7", "myst-parser>=2"],
        "test": [
            "pytest>=7",
            "pin>=3.4",
            "hypothesis>=6",
            "scipy>=1.11",
            "matplotlib>=3.6",
            "ruff>=0.6",
            "catkin_pkg>=1.0",
            "distributed>=2024.1",
            "xacro>=2.0",
            "example-robot-data>=4",
            "pybullet>=3.2",
            "icub-models>=3",
        ],
    },
    zip_safe=True,
    maintainer="neforward_ros developers",
    maintainer_email="neforward-ros@example.com",
    description="Link angular velocities and linear/angular accelerations from joint states and a URDF "
    "(Newton-Euler forward recursion) for ROS 2.",
    license="Apache-2.0",
    tests_require=["pytest"],
    entry_points={
        "console_scripts": ["neforward = neforward_ros.command:entry", "neforward_node = neforward_ros.node_entry:main"]
    },
)
