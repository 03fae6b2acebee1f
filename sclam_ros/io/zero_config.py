"""`sclam calibrate BAG` without a parameters file: the parameters inferred from the recording.

- the topics by type: a LaserScan; a JointState carrying the wheel joints, else the base's
  wheel odometry (nav_msgs/Odometry);
- the wheel joints from the robot description (--urdf, else the recording's
  /robot_description): the continuous joints whose child links are cylinders; their radius
  (the cylinders'), their separation (between the joints' origins across the robot) and which
  is left (the one on +y of the base frame);
- the laser's mount from --urdf, else /tf_static, else /robot_description.

What cannot be inferred is an InferenceError naming the missing piece and the fix.
sclam_node infers the wheels and the laser's mount it is not given from the live
/robot_description with the same functions (description_wheels, description_laser_mount).
"""
from __future__ import annotations

import dataclasses
import math

from sclam_ros.core.params import LASER_KEYS, SclamParams
from sclam_ros.io import bag
from sclam_ros.io.recording import (GROUND_TRUTH_TOPIC, JOINT_STATE_TYPE, LASER_SCAN_TYPE,
                                    ODOMETRY_TYPE, scan_frame_id)
from sclam_ros.io.tf_static import LaserMountError, chain_transform, with_nominal_laser_pose
from sclam_ros.io.urdf import frame_tree, load_robot, urdf_laser_mount

ROBOT_DESCRIPTION_TOPIC = "/robot_description"
STRING_TYPE = "std_msgs/msg/String"
FIX = "or give them in a parameters file (--params)"
# What a robot description gives of the wheels, in SclamParams' names.
WHEEL_KEYS = ("left_wheel_joint", "right_wheel_joint", "wheel_radius_left",
              "wheel_radius_right", "wheel_base")


class InferenceError(ValueError):
    """A parameter the recording and the robot description do not give; the message names it
    and the fix."""


def _topics_of_type(info, msgtype):
    return sorted(topic for topic, (kind, count) in info.items() if kind == msgtype and count)


def _scan_topic(info, path) -> str:
    scans = _topics_of_type(info, LASER_SCAN_TYPE)
    if not scans:
        raise InferenceError(f"no sensor_msgs/LaserScan topic in {path}: record the laser")
    if len(scans) > 1:
        raise InferenceError(f"{len(scans)} candidate LaserScan topics ({', '.join(scans)}): "
                             f"set scan_topic in a parameters file (--params) to the one to use")
    return scans[0]


def _description(path, info, urdf):
    """(yourdfpy Robot, where it came from)."""
    if urdf is not None:
        return load_robot(urdf), str(urdf)
    if info.get(ROBOT_DESCRIPTION_TOPIC, (None,))[0] != STRING_TYPE:
        raise InferenceError(
            f"no {ROBOT_DESCRIPTION_TOPIC} (std_msgs/String) in {path} to read the wheel joints, "
            f"their radius and separation from: pass --urdf ROBOT.urdf, {FIX}")
    text = None
    for _, _, msg in bag.iter_messages(path, [ROBOT_DESCRIPTION_TOPIC]):
        text = str(msg.data)  # the last one, as a late subscriber to the latched topic sees it
    return load_robot(text=text, source=ROBOT_DESCRIPTION_TOPIC), ROBOT_DESCRIPTION_TOPIC


def _cylinder_radius(link):
    for element in (*link.collisions, *link.visuals):
        cylinder = element.geometry.cylinder if element.geometry is not None else None
        if cylinder is not None:
            return float(cylinder.radius)
    return None


def _wheels(robot, tree, base, source):
    """(left joint, right joint, left radius, right radius, wheel base)."""
    edges = tree[0]
    links = {link.name: link for link in robot.links}
    continuous = [j for j in robot.joints if j.type == "continuous"]
    wheels = []
    for joint in continuous:
        radius = _cylinder_radius(links[joint.child]) if joint.child in links else None
        found = chain_transform(edges, base, joint.child)
        if radius is not None and found is not None:
            wheels.append((joint.name, radius, found[0][:3, 3]))
    if len(wheels) < 2:
        have = ", ".join(j.name for j in continuous) or "none"
        raise InferenceError(
            f"{source}: no two wheel joints (continuous joints whose child links are cylinders, "
            f"under {base}); continuous joints: {have}: set left_wheel_joint, right_wheel_joint, "
            f"wheel_radius_left, wheel_radius_right and wheel_base in a parameters file (--params)")
    if len(wheels) > 2:
        raise InferenceError(
            f"{source}: {len(wheels)} wheel joints ({', '.join(w[0] for w in wheels)}): zero "
            "configuration infers a differential drive's two; for a skid-steer name each side's "
            "(left_wheel_joints, right_wheel_joints), wheel_separation and a first wheel_base "
            "(1.5 x the track) in a parameters file (--params)")
    right, left = sorted(wheels, key=lambda w: w[2][1])
    if not left[2][1] > 0 > right[2][1]:
        raise InferenceError(
            f"{source}: the wheel joints {left[0]} and {right[0]} are not on either side of "
            f"{base} (y = {left[2][1]:.3f} m and {right[2][1]:.3f} m): {FIX}")
    return left[0], right[0], left[1], right[1], float(left[2][1] - right[2][1])


def description_base(tree) -> str:
    """The base frame of a frame_tree: base_link by REP-105, else the description's root link."""
    edges, _, links = tree
    roots = [name for name in links if name not in edges]
    return "base_link" if "base_link" in links else (roots[0] if roots else links[0])


def _wheels_line(wheels, source, base) -> str:
    left, right, r_left, r_right, wheel_base = (wheels[k] for k in WHEEL_KEYS)
    return (f"wheel joints {left} (left), {right} (right) in {source}: radius "
            f"{1e3 * r_left:.1f} mm and {1e3 * r_right:.1f} mm (their cylinders), "
            f"separation {1e3 * wheel_base:.1f} mm, on {base}")


def description_wheels(robot, tree, base, source) -> tuple:
    """({WHEEL_KEYS: value}, a line saying so) of a yourdfpy Robot and its frame_tree, the
    wheels placed on ``base``; InferenceError if it has not two wheel joints, one each side."""
    wheels = dict(zip(WHEEL_KEYS, _wheels(robot, tree, base, source)))
    return wheels, _wheels_line(wheels, source, base)


def description_laser_mount(source, base, laser, tree) -> tuple:
    """({LASER_KEYS: value}, a line saying so) of the chain from ``base`` to the scan's frame
    ``laser`` in the frame_tree of the description ``source``; LaserMountError if it holds none."""
    mount = urdf_laser_mount(source, base, laser, tree=tree)
    x, y, yaw = (float(v) for v in mount.pose)
    return dict(zip(LASER_KEYS, (x, y, yaw))), (
        f"nominal laser pose from {mount.describe()}: x = {1e3 * x:.1f} mm, "
        f"y = {1e3 * y:.1f} mm, yaw = {math.degrees(yaw):.2f} deg")


def _joint_state_topic(path, info, joints):
    """The JointState topic whose first message names both wheel joints, or None."""
    for topic in _topics_of_type(info, JOINT_STATE_TYPE):
        messages = bag.iter_messages(path, [topic])
        try:
            first = next(messages, None)
        finally:
            messages.close()
        if first is not None and set(joints) <= set(first[2].name):
            return topic
    return None


def _odometry_topic(path, info):
    """(topic, child frame) of the base's wheel odometry; the simulator's ground truth is not
    one. Of several, the one named odom."""
    topics = [t for t in _topics_of_type(info, ODOMETRY_TYPE) if t != GROUND_TRUTH_TOPIC]
    if len(topics) > 1:
        named = [t for t in topics if t.rsplit("/", 1)[-1] == "odom"]
        if len(named) != 1:
            raise InferenceError(f"{len(topics)} candidate Odometry topics ({', '.join(topics)}) "
                                 "and no JointState of the wheels: set odometry_topic in a "
                                 "parameters file (--params) to the wheels' own odometry")
        topics = named
    if not topics:
        return None, None
    messages = bag.iter_messages(path, topics)
    try:
        first = next(messages, None)
    finally:
        messages.close()
    child = str(first[2].child_frame_id).lstrip("/") if first is not None else ""
    return topics[0], child


def infer_params(path, urdf=None) -> tuple:
    """(SclamParams, lines saying what was inferred from where) for the recording ``path``."""
    info = bag.topic_info(path)
    scan_topic = _scan_topic(info, path)
    robot, source = _description(path, info, urdf)
    tree = frame_tree(robot)
    links = tree[2]
    lines = [f"robot description: {source} ({robot.name}, {len(links)} links)"]
    base = description_base(tree)
    left, right, r_left, r_right, wheel_base = _wheels(robot, tree, base, source)
    joint_states = _joint_state_topic(path, info, (left, right))
    odometry, child = (None, None) if joint_states else _odometry_topic(path, info)
    if joint_states is None and odometry is None:
        raise InferenceError(
            f"no wheel input in {path}: no JointState naming {left} and {right}, and no "
            "nav_msgs/Odometry: record /joint_states or the base's /odom")
    if odometry and child and child != base:
        if child not in links:
            raise InferenceError(
                f"{odometry} is the motion of {child}, which is not a link of {source}: "
                f"set odometry_topic and base_frame in a parameters file (--params)")
        base = child  # the laser and the wheels are then placed on the frame the odometry moves
        left, right, r_left, r_right, wheel_base = _wheels(robot, tree, base, source)
    params = SclamParams(
        scan_topic=scan_topic, base_frame=base, left_wheel_joint=left, right_wheel_joint=right,
        wheel_radius_left=r_left, wheel_radius_right=r_right, wheel_base=wheel_base,
        ticks_per_revolution=0.0,
        **({"joint_states_topic": joint_states} if joint_states else {"odometry_topic": odometry}),
    ).validate()
    lines.append(f"laser: {scan_topic}")
    if joint_states:
        lines.append(f"wheels: {joint_states} ({left}, {right}); positions taken as radians, the "
                     "JointState convention (a driver that publishes encoder ticks needs "
                     "ticks_per_revolution in the parameters file)")
    else:
        lines.append(f"wheels: {odometry} (nav_msgs/Odometry of {base}): no JointState of "
                     f"{left} and {right}, so the base's odometry, assumed computed with the "
                     "description's radii and wheel separation")
    lines.append(_wheels_line(dict(zip(WHEEL_KEYS, (left, right, r_left, r_right, wheel_base))),
                              source, base))
    params, laser_line = _laser_mount(path, info, params, urdf, robot, tree, source)
    lines.append(laser_line)
    return params, lines


def _laser_mount(path, info, params, urdf, robot, tree, source):
    """params with the laser pose from --urdf or /tf_static (with_nominal_laser_pose), else
    from the description in the recording; InferenceError where none places the laser."""
    updated, line = with_nominal_laser_pose(path, params, urdf)
    if updated is not params or urdf is not None:
        return updated, line
    laser = scan_frame_id(path, params.scan_topic)
    try:
        mount, line = description_laser_mount(source, params.base_frame, laser, tree)
    except LaserMountError as exc:
        raise InferenceError(f"the laser's mount: neither /tf_static nor {exc}: set laser_x, "
                             "laser_y and laser_yaw in a parameters file (--params)") from None
    return dataclasses.replace(params, **mount).validate(), line


def inferred_params_header(bag_path, lines) -> str:
    """The comment block at the top of the written parameters file."""
    said = "".join(f"#   {line}\n" for line in lines)
    return (f"# Parameters sclam calibrate inferred from {bag_path}:\n{said}"
            "# Edit what is wrong and pass this file next time: sclam calibrate BAG --params FILE\n")

