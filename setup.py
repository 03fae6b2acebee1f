from glob import glob

from setuptools import find_packages, setup

package_name = "sclam_ros"

setup(
    name=package_name,
    version="0.1.0",
    packages=find_packages(exclude=["test", "test.*", "bench", "bench.*"]),
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        ("share/" + package_name, ["package.xml"]),
        # Launch files and parameter files in separate folders, so that a glob over one never
        # picks up the other (`ros2 launch sclam_ros sclam.launch.py` finds the launch file).
        ("share/" + package_name + "/launch_configs/launch",
         glob("launch_configs/launch/*.launch.py")),
        ("share/" + package_name + "/launch_configs/config",
         glob("launch_configs/config/*.yaml")),
    ],
    # The runtime dependencies of requirements.txt (which pins the tested versions); the
    # lower bounds are the APIs the code uses. On a ROS install rosdep provides the same
    # through package.xml.
    install_requires=[
        "setuptools",
        "ros-jazzy-rclpy[fastrtps]",
        "ros-jazzy-common-interfaces",
        "numpy>=1.24",
        "scipy>=1.10",
        "kiss-icp>=1.0",
        "rosbags>=0.10",
        "matplotlib>=3.6",
        "PyYAML>=6.0",
        "threadpoolctl>=3.1",
        "yourdfpy>=0.0.60",
    ],
    extras_require={
        # `sclam fleet` and `sclam calibrate --scheduler` (a recording's chunks on local processes need none)
        "fleet": ["dask[distributed]>=2024.1", "bokeh>=3.1"],
    },
    python_requires=">=3.10",
    zip_safe=True,
    maintainer="sclam_ros developers",
    maintainer_email="sclam-ros@example.com",
    description="Simultaneous calibration, localization and mapping for differential-drive robots",
    license="LGPL-3.0-or-later",
    entry_points={
        "console_scripts": [
            "sclam = sclam_ros.cli.main:main",
            "sclam_node = sclam_ros.ros.main:main",
        ],
    },
)
