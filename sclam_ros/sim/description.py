"""What robot_state_publisher puts in a recording of a simulated robot: its URDF on
/robot_description and the fixed laser joint on /tf_static, both with the NOMINAL values (what
the robot's description says, not what the robot is)."""
from __future__ import annotations

import math

LASER_FRAME = "laser"
BASE_FRAME = "base_link"
LASER_HEIGHT = 0.3  # m above base_link: a 2D calibration does not see it
WHEEL_WIDTH = 0.04  # m, the wheels' cylinders' length
CASTER_RADIUS = 0.03  # m


def _wheel(side, sign, radius, base):
    # The cylinder's axis is its link's z: rolled by -90° about x, it lies along base_link's y,
    # the axle, about which the wheel turns (axis z of the wheel link).
    return f"""
  <link name="{side}_wheel">
    <visual><geometry><cylinder radius="{radius:.6g}" length="{WHEEL_WIDTH}"/></geometry></visual>
    <collision><geometry><cylinder radius="{radius:.6g}" length="{WHEEL_WIDTH}"/></geometry></collision>
  </link>
  <joint name="{side}_wheel_joint" type="continuous">
    <parent link="{BASE_FRAME}"/>
    <child link="{side}_wheel"/>
    <origin xyz="0 {sign * base / 2:.6g} {radius:.6g}" rpy="{-math.pi / 2:.9f} 0 0"/>
    <axis xyz="0 0 1"/>
  </joint>"""


def robot_urdf(name, nominal) -> str:
    """The URDF of a differential drive with the nominal calibration ``nominal`` (CALIBRATION_KEYS
    → value): two wheel joints named as the simulator's JointState names them, a caster, and
    the laser on a fixed joint."""
    r_left, r_right = nominal["wheel_radius_left"], nominal["wheel_radius_right"]
    base = nominal["wheel_base"]
    x, y, yaw = nominal["laser_x"], nominal["laser_y"], nominal["laser_yaw"]
    return f"""<?xml version="1.0"?>
<robot name="{name}">
  <link name="{BASE_FRAME}"/>{_wheel("left", 1, r_left, base)}{_wheel("right", -1, r_right, base)}
  <link name="caster"><collision><geometry><sphere radius="{CASTER_RADIUS}"/></geometry></collision></link>
  <joint name="caster_joint" type="fixed">
    <parent link="{BASE_FRAME}"/><child link="caster"/>
    <origin xyz="{-base / 2:.6g} 0 {CASTER_RADIUS}" rpy="0 0 0"/>
  </joint>
  <link name="{LASER_FRAME}"/>
  <joint name="laser_joint" type="fixed">
    <parent link="{BASE_FRAME}"/><child link="{LASER_FRAME}"/>
    <origin xyz="{x:.6g} {y:.6g} {LASER_HEIGHT}" rpy="0 0 {yaw:.9g}"/>
  </joint>
</robot>
"""


def laser_transform(nominal) -> tuple:
    """(parent, child, xyz, quaternion xyzw) of the laser joint, as /tf_static carries it."""
    yaw = nominal["laser_yaw"]
    return (BASE_FRAME, LASER_FRAME, (nominal["laser_x"], nominal["laser_y"], LASER_HEIGHT),
            (0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2)))
