"""The nominal laser pose from a robot's URDF (`sclam calibrate --urdf`): its joints, parsed
with yourdfpy, make the frame tree that io/tf_static.py walks from the base frame to the scan's
frame_id, as robot_state_publisher would latch it on /tf_static. Every joint on that chain
must be fixed: a laser on a moving joint has no one nominal pose.
"""
from __future__ import annotations

import logging
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

from sclam_ros.io.tf_static import (LaserMount, LaserMountError, chain_transform, frame_name,
                                     planar_mount)

XACRO_NAMESPACE = "http://www.ros.org/wiki/xacro"


def _check_is_urdf(path: Path) -> None:
    """LaserMountError unless ``path`` is an XML file whose root is <robot> without xacro
    macros: yourdfpy itself reads any XML (and garbage, with a recovering parser) into an
    empty robot, logging the parse errors."""
    if not path.is_file():
        raise LaserMountError(f"URDF not found: {path}")
    try:
        root = ET.parse(path).getroot()
    except ET.ParseError as exc:
        raise LaserMountError(f"{path}: not a URDF (not XML: {exc})") from None
    if root.tag != "robot":
        raise LaserMountError(f"{path}: not a URDF (its root element is <{root.tag}>, not <robot>)")
    if any(str(element.tag).startswith(f"{{{XACRO_NAMESPACE}}}") for element in root.iter()):
        raise LaserMountError(f"{path}: a xacro file, not a URDF: expand it first "
                              f"(xacro {path.name} > robot.urdf)")


def read_joints(path) -> tuple:
    """(edges, joints, links): edges {child: (parent, 4x4 transform parent←child)}, each
    joint at its zero position (its <origin>); joints {child: (joint name, joint type)}; the
    names of the links."""
    import yourdfpy

    path = Path(path)
    _check_is_urdf(path)
    quiet = logging.getLogger("yourdfpy")
    level = quiet.level
    quiet.setLevel(logging.CRITICAL)  # what it logs on a bad file: our error says it once
    try:
        robot = yourdfpy.URDF.load(str(path), build_scene_graph=False, load_meshes=False).robot
    except (KeyError, AttributeError, ValueError, TypeError) as exc:  # a <robot> without name, ...
        raise LaserMountError(f"{path}: not a URDF yourdfpy can read "
                              f"({type(exc).__name__}: {exc})") from None
    finally:
        quiet.setLevel(level)
    if not robot.links:
        raise LaserMountError(f"{path}: not a URDF (no <link>)")
    edges = {j.child: (j.parent, np.eye(4) if j.origin is None else np.asarray(j.origin, float))
             for j in robot.joints}
    joints = {j.child: (j.name, j.type) for j in robot.joints}
    return edges, joints, [link.name for link in robot.links]


def urdf_laser_mount(path, base_frame, laser_frame) -> LaserMount:
    """The LaserMount of ``laser_frame`` in ``base_frame`` from the URDF file ``path``;
    LaserMountError if the file is not a URDF, holds no chain between the two frames, or
    the chain has a joint that is not fixed."""
    edges, joints, links = read_joints(path)
    base, laser = frame_name(base_frame), frame_name(laser_frame)
    found = chain_transform(edges, base, laser)
    if found is None:
        raise LaserMountError(f"{path}: no chain of joints from {base} to the scan's frame "
                              f"{laser}; its links: {', '.join(links)}")
    chain = found[1]
    # In a tree, a link on the chain whose parent is on it too hangs from a joint of the chain.
    moving = [f"{joints[f][0]} ({joints[f][1]})" for f in chain
              if f in edges and edges[f][0] in chain and joints[f][1] != "fixed"]
    if moving:
        raise LaserMountError(f"{path}: the chain {' → '.join(chain)} has joints that are not "
                              f"fixed: {', '.join(moving)}; a laser that moves on the robot has "
                              "no one nominal pose: set laser_x, laser_y and laser_yaw in the "
                              "parameters file instead of --urdf")
    return planar_mount(*found, str(path))
