"""sclam_node's zero configuration: the wheel geometry and the laser's mount that its
parameters leave out, read from the live /robot_description with io/zero_config.py's
functions, as `sclam calibrate BAG` reads them from a recording (no rclpy here: the node
feeds it the description's text and the scans' frame)."""
from __future__ import annotations

from sclam_ros.core.params import LASER_KEYS
from sclam_ros.io.tf_static import LaserMountError
from sclam_ros.io.urdf import frame_tree, load_robot
from sclam_ros.io.zero_config import (ROBOT_DESCRIPTION_TOPIC, WHEEL_KEYS, InferenceError,
                                      description_laser_mount, description_wheels)

INFERABLE_KEYS = WHEEL_KEYS + LASER_KEYS
SKID_STEER_KEYS = ("left_wheel_joints", "right_wheel_joints")


def left_out_keys(given: dict) -> frozenset:
    """The keys of INFERABLE_KEYS not among ``given`` ({name: value} the node's parameters
    set). A skid-steer's joint lists, when set, leave the two-wheel joint names unused rather
    than left out."""
    skid = any(given.get(key) for key in SKID_STEER_KEYS)
    unused = {"left_wheel_joint", "right_wheel_joint"} if skid else set()
    return frozenset(INFERABLE_KEYS) - set(given) - unused


class FromDescription:
    """The values of ``left_out`` (keys of INFERABLE_KEYS) from a URDF text, the wheels and
    the laser's mount on ``base_frame``. ``read(text)`` takes a description: False if it gives
    no wheels (``error`` says why, ``errors`` counts them). ``values(laser_frame)`` is then
    (values, line saying what was inferred, warning or None), or None while the laser's frame
    is still needed (no scan yet) or no description gave the wheels."""

    source = ROBOT_DESCRIPTION_TOPIC

    def __init__(self, left_out, base_frame: str):
        self.left_out = frozenset(left_out)
        self.base_frame = base_frame
        self.error = None
        self.errors = 0
        self._read = None  # (frame tree, wheel values, lines) of the last usable description

    @property
    def needs_laser(self) -> bool:
        return bool(self.left_out & set(LASER_KEYS))

    @property
    def read_one(self) -> bool:
        return self._read is not None

    def read(self, text) -> bool:
        try:
            robot = load_robot(text=str(text), source=self.source)
            tree = frame_tree(robot)
            values, lines = {}, [f"{self.source} ({robot.name}, {len(tree[2])} links)"]
            if self.left_out & set(WHEEL_KEYS):
                wheels, line = description_wheels(robot, tree, self.base_frame, self.source)
                values.update({k: v for k, v in wheels.items() if k in self.left_out})
                lines.append(line)
        except (InferenceError, LaserMountError) as exc:
            # Its fixes name the CLI's parameters file; the node's is the same file.
            self.refuse(str(exc).replace(" (--params)", ""))
            return False
        self.error, self._read = None, (tree, values, lines)
        return True

    def refuse(self, reason: str) -> None:
        """The description read cannot be used (``reason``): counted; wait for another."""
        self.error = " ".join(reason.split())
        self.errors += 1
        self._read = None

    def values(self, laser_frame):
        if self._read is None or (self.needs_laser and not laser_frame):
            return None
        tree, values, lines = self._read
        values, lines, warning = dict(values), list(lines), None
        if self.needs_laser:
            try:
                mount, line = description_laser_mount(self.source, self.base_frame,
                                                      laser_frame, tree)
                values.update({k: v for k, v in mount.items() if k in self.left_out})
                lines.append(line)
            except LaserMountError as exc:
                warning = (f"the laser's mount is not in {' '.join(str(exc).split())}: set "
                           "laser_x, laser_y and laser_yaw in the parameters file (the node "
                           "reads the mount from the description only, not /tf_static); "
                           "calibrating from the parameters' values")
        return values, "; ".join(lines), warning

