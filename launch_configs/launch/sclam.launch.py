"""Launch sclam_node with a parameters file.

    ros2 launch sclam_ros sclam.launch.py                                   # PowerBot preset
    ros2 launch sclam_ros sclam.launch.py params_file:=/path/to/robot.yaml use_sim_time:=true

The parameters file is a standard ROS 2 one (``sclam: ros__parameters: ...``); the presets
in ../config/ are commented templates. ``use_sim_time:=true`` when the data comes from
``sclam play BAG --clock`` or ``ros2 bag play --clock``.

``use_sim_time`` and ``calibration_file`` override the parameters file only when given on the
command line: left out, the file's values (or the node's defaults) apply.
"""
import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

# The arguments that, when given, override the parameters file. An empty default stands for
# "not given": a fixed default here would silently replace the user's value from the file.
OVERRIDES = {
    "use_sim_time": "use /clock (bag playback): true or false",
    "calibration_file": "where ~/save_calibration writes the estimate",
}


def _node(context):
    # Resolved at launch time, because which parameters to pass depends on what was given.
    overrides = {}
    for name in OVERRIDES:
        value = LaunchConfiguration(name).perform(context)
        if value != "":
            # use_sim_time is a bool parameter: pass a bool, not the string "true".
            if name == "use_sim_time":
                value = value.strip().lower() in ("true", "1", "yes", "on")
            overrides[name] = value
    parameters = [LaunchConfiguration("params_file").perform(context)]
    if overrides:
        parameters.append(overrides)
    return [Node(
        package="sclam_ros",
        executable="sclam_node",
        name="sclam",
        output="screen",
        parameters=parameters,
    )]


def generate_launch_description():
    default_params = os.path.join(
        get_package_share_directory("sclam_ros"), "launch_configs", "config", "powerbot.yaml"
    )
    return LaunchDescription([
        DeclareLaunchArgument("params_file", default_value=default_params,
                              description="sclam_node parameters YAML"),
        *[DeclareLaunchArgument(name, default_value="",
                                description=f"{text} (default: from the parameters file)")
          for name, text in OVERRIDES.items()],
        OpaqueFunction(function=_node),
    ])
