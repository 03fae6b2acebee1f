"""Robot presets: the three robots of Kümmerle et al. (IROS 2011), and a four-wheel
skid-steer.

``nominal`` is what a user would write into params.yaml before calibrating (datasheet
values); ``true`` is what the simulated robot really has, by default the paper's first
calibrated row for that robot. ``footprint_radius`` keeps the planned path clear of
walls.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from sclam_ros.core.params import CALIBRATION_KEYS


@dataclass(frozen=True)
class RobotPreset:
    name: str
    nominal: dict  # CALIBRATION_KEYS -> value (m, rad)
    true: dict  # CALIBRATION_KEYS -> value (m, rad)
    ticks_per_revolution: float
    footprint_radius: float  # m
    # A skid-steer's: wheels on each side (their JointState names: record.joint_names), the
    # track widening χ of its sides' instantaneous centres of rotation (motion.py) and its
    # nominal geometric track (m). Its ``true`` wheel_base is the geometric track (the
    # effective one is χ times it), its ``nominal`` one a first guess of the effective one.
    wheels_per_side: int = 1
    track_widening: float = 1.0
    wheel_separation: float = 0.0


def _calibration(r_left, r_right, base, laser_x, laser_y, laser_yaw_deg) -> dict:
    values = (r_left, r_right, base, laser_x, laser_y, math.radians(laser_yaw_deg))
    return dict(zip(CALIBRATION_KEYS, (float(v) for v in values)))


PRESETS: dict[str, RobotPreset] = {
    "powerbot": RobotPreset(
        "powerbot",
        nominal=_calibration(0.125, 0.125, 0.56, 0.22, 0.0, 0.0),
        true=_calibration(0.1263, 0.1275, 0.5825, 0.2258, 0.0026, 0.099),
        ticks_per_revolution=22835,
        footprint_radius=0.45,
    ),
    "custom": RobotPreset(
        "custom",
        nominal=_calibration(0.16, 0.16, 0.70, 0.3, 0.0, 0.0),
        true=_calibration(0.1603, 0.1605, 0.6969, 0.3067, -0.0051, -0.357),
        ticks_per_revolution=20000,
        footprint_radius=0.45,
    ),
    "pioneer": RobotPreset(
        "pioneer",
        nominal=_calibration(0.065, 0.065, 0.35, 0.1, 0.0, 0.0),
        true=_calibration(0.0656, 0.065, 0.3519, 0.1045, 0.009, -0.178),
        ticks_per_revolution=1970,
        footprint_radius=0.3,
    ),
    # A Husky-sized four-wheel skid-steer (geometric track 0.555 m, wheels 0.165 m), whose
    # sides turn about centres 1.5 times as far apart as the tracks. Nominal wheel_base: 1.5
    # times the track measured with a tape (started from the track itself, 2× off, the scan
    # matcher's odometry guesses fail in turns and the wheel base is left undetermined:
    # docs/robot_inputs.md#skid-steer).
    "skid": RobotPreset(
        "skid",
        nominal=_calibration(0.165, 0.165, 1.5 * 0.555, 0.30, 0.0, 0.0),
        true=_calibration(0.1656, 0.1643, 0.555, 0.3064, 0.0071, 0.45),
        ticks_per_revolution=10000,
        footprint_radius=0.45,
        wheels_per_side=2,
        track_widening=1.5,
        wheel_separation=0.555,
    ),
}


def get_preset(name: str) -> RobotPreset:
    try:
        return PRESETS[name.lower()]
    except KeyError:
        raise ValueError(f"unknown robot {name!r}; presets: {', '.join(PRESETS)}") from None


def true_calibration(preset: RobotPreset, overrides: dict | None = None) -> dict:
    """The preset's true values with ``overrides`` (same key names, SI, radians) applied."""
    values = dict(preset.true)
    for key, value in (overrides or {}).items():
        if key not in values:
            raise ValueError(f"unknown true value {key!r}; keys: {', '.join(CALIBRATION_KEYS)}")
        value = float(value)
        if not math.isfinite(value) or (key in CALIBRATION_KEYS[:3] and value <= 0):
            raise ValueError(f"true {key} must be finite{' and > 0' if key in CALIBRATION_KEYS[:3] else ''}, got {value}")
        values[key] = value
    return values
