"""The nominal laser pose from the robot's frame tree: the chain from the base frame to the
scan's header.frame_id, composed in 3D and reduced to the planar (x, y, yaw) the calibration
estimates. The tree is the robot's URDF (`sclam calibrate --urdf`, read by io/urdf.py) or else
the recording's /tf_static (what robot_state_publisher latched from that URDF).

Precedence, per name: a parameters file that sets laser_x, laser_y or laser_yaw wins (the user
may know better than the URDF: a laser remounted since), then --urdf, then /tf_static, then
the defaults. A laser mounted upside down is refused (see planar_mount).
"""
from __future__ import annotations

import dataclasses
import logging
import math
from dataclasses import dataclass

import numpy as np

from sclam_ros.core.params import LASER_KEYS
from sclam_ros.io import bag
from sclam_ros.io.recording import check_topic_types, scan_frame_id

log = logging.getLogger("sclam")

TF_STATIC_TOPIC = "/tf_static"
TF_MESSAGE_TYPE = "tf2_msgs/msg/TFMessage"
# Beyond this roll or pitch the scan plane is not the floor's: its points, projected, are
# foreshortened, and no planar (x, y, yaw) describes the mount exactly.
MAX_TILT_RAD = math.radians(1.0)


class LaserMountError(ValueError):
    """A laser pose source (a URDF, /tf_static) that cannot be used; the message says why."""


@dataclass
class LaserMount:
    """The laser frame in the base frame, from a frame tree."""

    pose: np.ndarray  # (x, y, yaw): the planar part the calibration uses
    chain: list  # frame names from the base frame to the laser frame
    roll: float  # rad, of the laser frame in the base frame (ZYX Euler angles)
    pitch: float  # rad
    z: float  # m, height above the base frame (not used by the 2D calibration)
    source: str = TF_STATIC_TOPIC  # where the tree came from: the topic, or the URDF's path

    def describe(self) -> str:
        return f"{self.source} " + " → ".join(self.chain)


def frame_name(name) -> str:
    # ROS 1 recordings (and some ROS 2 drivers) write "/base_link"; tf2 itself strips it.
    return str(name).lstrip("/")


def _matrix(translation, rotation) -> np.ndarray:
    """4x4 homogeneous transform of a geometry_msgs Vector3 and Quaternion."""
    x, y, z, w = rotation.x, rotation.y, rotation.z, rotation.w
    norm = math.sqrt(x * x + y * y + z * z + w * w) or 1.0
    x, y, z, w = x / norm, y / norm, z / norm, w / norm
    out = np.eye(4)
    out[:3, :3] = [
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ]
    out[:3, 3] = (translation.x, translation.y, translation.z)
    return out


def read_static_transforms(path, topic=TF_STATIC_TOPIC) -> dict:
    """{child: (parent, 4x4 transform parent←child)} of every static transform in the bag;
    a later message replaces an earlier one for the same child (as tf2 does). Empty if the
    bag has no such topic."""
    info = bag.topic_info(path)
    if topic not in info:
        return {}
    if info[topic][0] != TF_MESSAGE_TYPE:
        log.warning("%s carries %s, not %s: not read", topic, info[topic][0], TF_MESSAGE_TYPE)
        return {}
    edges = {}
    for _, _, msg in bag.iter_messages(path, [topic]):
        for tf in msg.transforms:
            edges[frame_name(tf.child_frame_id)] = (
                frame_name(tf.header.frame_id),
                _matrix(tf.transform.translation, tf.transform.rotation),
            )
    return edges


def _ancestors(edges, frame) -> list:
    """[frame, its parent, ..., the root]; stops at a cycle (a broken tree)."""
    out = [frame]
    while frame in edges and edges[frame][0] not in out:
        frame = edges[frame][0]
        out.append(frame)
    return out


def _to_ancestor(edges, path) -> np.ndarray:
    """Transform ancestor←frame along ``path`` = [frame, parent, ..., ancestor]."""
    out = np.eye(4)
    for child in path[:-1]:
        out = edges[child][1] @ out
    return out


def chain_transform(edges, base, laser):
    """(4x4 transform base←laser, frame names from base to laser), or None if the two frames
    are not in one tree. Goes through their lowest common ancestor, so a laser hanging off a
    sibling of the base frame (base_footprint → base_link, base_footprint → laser) is found."""
    up_laser, up_base = _ancestors(edges, laser), _ancestors(edges, base)
    common = next((f for f in up_laser if f in up_base), None)
    if common is None or (base not in edges and laser not in edges):
        return None
    from_laser = up_laser[: up_laser.index(common) + 1]
    from_base = up_base[: up_base.index(common) + 1]
    transform = np.linalg.inv(_to_ancestor(edges, from_base)) @ _to_ancestor(edges, from_laser)
    return transform, from_base + from_laser[::-1][1:]


def planar_mount(transform, chain, source) -> LaserMount:
    """The LaserMount of a 4x4 transform base←laser found along ``chain`` in ``source``.
    Refuses a laser mounted upside down; warns if it is tilted."""
    rot = transform[:3, :3]
    # ZYX Euler angles: yaw about the base's z, then pitch, then roll.
    yaw = math.atan2(rot[1, 0], rot[0, 0])
    pitch = -math.asin(max(-1.0, min(1.0, rot[2, 0])))
    roll = math.atan2(rot[2, 1], rot[2, 2])
    mount = LaserMount(np.array([transform[0, 3], transform[1, 3], yaw]), chain, roll, pitch,
                       float(transform[2, 3]), source)
    tilt = f"roll {math.degrees(roll):.1f} deg, pitch {math.degrees(pitch):.1f} deg"
    if rot[2, 2] < 0:
        # Its z axis points down: a scan in that frame is the floor plane seen from below,
        # mirrored, and the planar model (points rotated by laser_yaw) cannot express that.
        raise LaserMountError(
            f"{mount.describe()}: the laser is mounted upside down ({tilt}): scans in its "
            "frame are mirrored, which the planar calibration does not model; publish the "
            "scans in an upright frame (z up, beams with a negative angle_increment if they "
            "then run clockwise) and name that frame in header.frame_id")
    if abs(roll) > MAX_TILT_RAD or abs(pitch) > MAX_TILT_RAD:
        log.warning("%s: the laser is tilted on %s (%s): its scans are not in the floor's "
                    "plane, and the calibration uses only the planar part (x, y, yaw)",
                    mount.describe(), chain[0], tilt)
    return mount


def laser_mount(path, base_frame, laser_frame, topic=TF_STATIC_TOPIC):
    """The LaserMount of ``laser_frame`` in ``base_frame`` from the bag's static transforms,
    or None if they hold no chain between the two."""
    if not laser_frame:
        return None
    found = chain_transform(read_static_transforms(path, topic), frame_name(base_frame),
                            frame_name(laser_frame))
    return None if found is None else planar_mount(*found, topic)


def _pose_text(values) -> str:
    x, y, yaw = values
    return f"x = {1000 * x:.1f} mm, y = {1000 * y:.1f} mm, yaw = {math.degrees(yaw):.2f} deg"


def with_nominal_laser_pose(path, params, urdf=None):
    """(params, description): ``params`` with laser_x, laser_y and laser_yaw taken, for each
    of them the parameters file did not set (params.explicit_keys), from the robot's URDF
    file ``urdf`` if given (LaserMountError if it does not place the scan's frame), else from
    the recording's /tf_static; and a line saying where the nominal laser pose came from."""
    info = bag.topic_info(path)
    # A wrong scan topic type fails here with the message the read would give, rather than
    # on a message without a header.
    check_topic_types(info, params)
    if urdf is not None:
        from sclam_ros.io.urdf import urdf_laser_mount

        # A missing scan topic fails here with the bag's list of topics.
        laser = scan_frame_id(path, params.scan_topic)
        if not laser:
            raise LaserMountError(f"the scans on {params.scan_topic} have no header.frame_id: "
                                  f"no laser frame to look up in {urdf}")
        mount = urdf_laser_mount(urdf, params.base_frame, laser)
    else:
        laser = scan_frame_id(path, params.scan_topic) if params.scan_topic in info else None
        mount = laser_mount(path, params.base_frame, laser)
    explicit = [k for k in LASER_KEYS if k in params.explicit_keys]
    from_file = _pose_text(params.calibration_vector()[3:])
    if mount is None:
        if explicit:
            return params, f"nominal laser pose from the parameters file: {from_file}"
        return params, (f"nominal laser pose: the defaults ({from_file}): neither the "
                        f"parameters file, --urdf nor {TF_STATIC_TOPIC} gives it")
    from_tree = dict(zip(LASER_KEYS, (float(v) for v in mount.pose)))
    taken = [k for k in LASER_KEYS if k not in explicit]
    if not taken:
        return params, (f"nominal laser pose from the parameters file: {from_file} "
                        f"({mount.describe()} says {_pose_text(mount.pose)})")
    updated = dataclasses.replace(params, **{k: from_tree[k] for k in taken}).validate()
    updated.explicit_keys = params.explicit_keys
    pose = _pose_text(updated.calibration_vector()[3:])
    if explicit:
        return updated, (f"nominal laser pose: {', '.join(taken)} from {mount.describe()}, "
                         f"{', '.join(explicit)} from the parameters file: {pose}")
    return updated, f"nominal laser pose from {mount.describe()}: {pose}"
