"""sclam_node's ROS parameters: declared from SclamParams (with their units and docs, the
read-only ones marked), a parameters file's unknown names warned about, and read back into
SclamParams. The wheel geometry and laser mount the parameters leave out are declared
later, from /robot_description (ros/description.py)."""
from __future__ import annotations

from dataclasses import fields

from rcl_interfaces.msg import ParameterDescriptor

from sclam_ros.core.params import SclamParams, with_suggestion
from sclam_ros.ros.description import left_out_keys

DEFAULT_CALIBRATION_FILE = "sclam_calibration.yaml"
# Parameters whose new value the node can use without a restart.
RUNTIME_PARAMETERS = {
    "window_distance", "wheel_noise", "lateral_noise", "odom_frame", "base_frame",
    "calibration_file",
}


def declare_parameters(node) -> dict:
    """Declare the parameters, but for the wheel geometry and laser mount the parameters
    leave out: {name: descriptor} of those."""
    # (_parameter_overrides: the parameters files' and -p values; no public accessor.)
    left_out = left_out_keys({name: parameter.value
                              for name, parameter in node._parameter_overrides.items()})
    undeclared = {}
    for f in fields(SclamParams):
        unit = f.metadata.get("unit", "")
        description = f.metadata.get("doc", "") + (f" [{unit}]" if unit else "")
        read_only = f.name not in RUNTIME_PARAMETERS
        # Numbers accept integers too (``ticks_per_revolution: 0`` in a YAML); the type is
        # checked by hand so a bad value gets a reason, not an exception.
        descriptor = ParameterDescriptor(
            description=description + (" (read-only: restart the node to change)" if read_only else ""),
            read_only=read_only,
            dynamic_typing=not isinstance(f.default, str),
        )
        if f.name in left_out:
            undeclared[f.name] = descriptor
        else:
            node.declare_parameter(f.name, f.default, descriptor)
    node.declare_parameter(
        "calibration_file", DEFAULT_CALIBRATION_FILE,
        ParameterDescriptor(description="where ~/save_calibration writes the parameters "
                                        "YAML with the current estimate"),
    )
    node.declare_parameter(
        "publish_tf", False,
        ParameterDescriptor(description="broadcast odom → base_frame (/tf) and base_frame → "
                                        "the scan's frame (/tf_static) with the calibration; "
                                        "off when another node (a driver, "
                                        "robot_state_publisher) already does "
                                        "(read-only: restart the node to change)",
                            read_only=True),
    )
    return undeclared

def warn_unknown_parameters(node):
    # rclpy keeps a parameters file's values for this node until they are declared and
    # ignores the rest: a misspelt nominal value would silently stay at its default.
    # (_parameter_overrides: rclpy has no public accessor for them.)
    unknown = sorted(n for n in node._parameter_overrides if not node.has_parameter(n))
    if unknown:
        node.get_logger().warn(
            f"unknown parameter(s) ignored: {', '.join(map(with_suggestion, unknown))}")

def read_params(node) -> SclamParams:
    # None: an empty list in a parameters file, which rcl reads as NOT_SET: the default.
    raw = {f.name: node.get_parameter(f.name).value for f in fields(SclamParams)
           if node.has_parameter(f.name)}
    raw = {name: value for name, value in raw.items() if value is not None}
    return SclamParams.from_dict(raw, source=f"parameters of node {node.get_name()}")
