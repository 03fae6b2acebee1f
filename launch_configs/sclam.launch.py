"""Launch sclam_node with a parameters file.

    ros2 launch sclam_ros sclam.launch.py                                   # PowerBot preset
    ros2 launch sclam_ros sclam.launch.py params_file:=/path/to/robot.yaml use_sim_time:=true

The parameters file is a standard ROS 2 one (``sclam: ros__parameters: ...``); the presets
in this folder are commented templates. ``use_sim_time:=true`` when the data comes from
``sclam play BAG --clock`` or ``ros2 bag play --clock``.
"""
import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node


def generate_launch_description():
    default_params = os.path.join(
        get_package_share_directory("sclam_ros"), "launch_configs", "powerbot.yaml"
    )
    return LaunchDescription([
        DeclareLaunchArgument("params_file", default_value=default_params,
                              description="sclam_node parameters YAML"),
        DeclareLaunchArgument("use_sim_time", default_value="false",
                              description="use /clock (bag playback)"),
        DeclareLaunchArgument("calibration_file", default_value="sclam_calibration.yaml",
                              description="where ~/save_calibration writes the estimate"),
        Node(
            package="sclam_ros",
            executable="sclam_node",
            name="sclam",
            output="screen",
            parameters=[
                LaunchConfiguration("params_file"),
                {"use_sim_time": LaunchConfiguration("use_sim_time"),
                 "calibration_file": LaunchConfiguration("calibration_file")},
            ],
        ),
    ])
