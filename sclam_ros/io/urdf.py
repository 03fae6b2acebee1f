"""The nominal laser pose from a robot's URDF (`sclam calibrate --urdf`): its joints, parsed
with yourdfpy, make the frame tree that io/tf_static.py walks from the base frame to the scan's
frame_id, as robot_state_publisher would latch it on /tf_static. Every joint on that chain
must be fixed: a laser on a moving joint has no one nominal pose.
"""
from __future__ import annotations

import io
import logging
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

from sclam_ros.io.tf_static import (LaserMount, LaserMountError, chain_transform, frame_name,
                                     planar_mount)

XACRO_NAMESPACE = "http://www.ros.org/wiki/xacro"


def _check_is_urdf(root, source) -> None:
    """LaserMountError unless the XML element ``root`` is a <robot> without xacro macros:
    yourdfpy itself reads any XML (and garbage, with a recovering parser) into an empty
    robot, logging the parse errors."""
    if root.tag != "robot":
        raise LaserMountError(f"{source}: not a URDF (its root element is <{root.tag}>, not <robot>)")
    if any(str(element.tag).startswith(f"{{{XACRO_NAMESPACE}}}") for element in root.iter()):
        raise LaserMountError(f"{source}: a xacro file, not a URDF: expand it first "
                              f"(xacro {Path(source).name} > robot.urdf)")


def load_robot(path=None, text=None, source=None):
    """The yourdfpy Robot of the URDF file ``path``, or of the URDF ``text`` (a recording's
    /robot_description) named ``source`` in errors; LaserMountError if it is not a URDF."""
    import yourdfpy

    source = str(source or path)
    try:
        if text is None:
            if not Path(path).is_file():
                raise LaserMountError(f"URDF not found: {path}")
            root = ET.parse(path).getroot()
        else:
            root = ET.fromstring(text)
    except ET.ParseError as exc:
        raise LaserMountError(f"{source}: not a URDF (not XML: {exc})") from None
    _check_is_urdf(root, source)
    quiet = logging.getLogger("yourdfpy")
    level = quiet.level
    quiet.setLevel(logging.CRITICAL)  # what it logs on a bad file: our error says it once
    try:
        robot = yourdfpy.URDF.load(str(path) if text is None else io.StringIO(text),
                                   build_scene_graph=False, load_meshes=False).robot
    except (KeyError, AttributeError, ValueError, TypeError) as exc:  # a <robot> without name, ...
        raise LaserMountError(f"{source}: not a URDF yourdfpy can read "
                              f"({type(exc).__name__}: {exc})") from None
    finally:
        quiet.setLevel(level)
    if not robot.links:
        raise LaserMountError(f"{source}: not a URDF (no <link>)")
    return robot


def frame_tree(robot) -> tuple:
    """(edges, joints, links) of a yourdfpy Robot: edges {child: (parent, 4x4 transform
    parent←child)}, each joint at its zero position (its <origin>); joints {child: (joint
    name, joint type)}; the names of the links."""
    edges = {j.child: (j.parent, np.eye(4) if j.origin is None else np.asarray(j.origin, float))
             for j in robot.joints}
    joints = {j.child: (j.name, j.type) for j in robot.joints}
    return edges, joints, [link.name for link in robot.links]


def read_joints(path) -> tuple:
    """frame_tree of the URDF file ``path``."""
    return frame_tree(load_robot(path))


def urdf_laser_mount(path, base_frame, laser_frame, tree=None) -> LaserMount:
    """The LaserMount of ``laser_frame`` in ``base_frame`` from the URDF file ``path`` (or its
    frame_tree ``tree``, ``path`` then naming it); LaserMountError if the file is not a URDF,
    holds no chain between the two frames, or the chain has a joint that is not fixed."""
    edges, joints, links = tree if tree is not None else read_joints(path)
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
