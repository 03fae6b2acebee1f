"""A calibration in the formats a robot and its tools load: the laser joint of a URDF, a
ros2_control diff_drive_controller parameter block, this node's parameters YAML, and
trajectories in TUM format for evo (`evo_ape tum ...`)."""
from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from sclam_ros.core.params import CALIBRATION_KEYS, ODOMETRY_KEYS, SclamParams, atomic_write_text

FORMATS = ("urdf", "diff-drive", "params")
DEFAULT_LASER_FRAME = "laser"
DEFAULT_CONTROLLER = "diff_drive_controller"


class ExportError(ValueError):
    """A calibration file that cannot be exported; the message says why."""


@dataclass
class Calibration:
    """The values to apply: estimates where the data observed them, nominal elsewhere."""

    values: dict  # the six parameters (m, rad)
    kept_nominal: tuple  # parameters the recording did not observe: their nominal value
    base_frame: str
    laser_frame: str
    wheels_per_side: int = 1  # a skid-steer's 2 or more
    wheel_separation: float = 0.0  # m, a skid-steer's geometric track (0: not given)


def load_calibration(path, params: SclamParams = None) -> Calibration:
    """Read `sclam calibrate --json` output. `params`: the parameters file the calibration
    started from, for the frames and nominal values an older JSON lacks."""
    try:
        doc = json.loads(Path(path).read_text())
        estimate = {k: float(doc[k]) for k in CALIBRATION_KEYS}
    except (KeyError, TypeError, ValueError, AttributeError) as exc:
        raise ExportError(f"{path}: not a calibration from `sclam calibrate --json` ({exc})") from None
    observable = doc.get("observable", {})
    nominal = doc.get("nominal") or (params.calibration() if params is not None else None)
    kept = tuple(k for k in CALIBRATION_KEYS if not observable.get(k, True))
    if kept and nominal is None:
        raise ExportError(f"{path}: {', '.join(kept)} not observable and the file has no "
                          "nominal values: give the parameters file with --params")
    # An unobserved parameter has no estimate worth applying: a robot gets what it had.
    values = {k: float(nominal[k]) if k in kept else estimate[k] for k in CALIBRATION_KEYS}
    frames = doc.get("frames", {})
    base = frames.get("base") or (params.base_frame if params is not None else "base_link")
    laser = frames.get("laser") or DEFAULT_LASER_FRAME
    per_side = doc.get("wheels_per_side") or (params.wheels_per_side if params is not None else 1)
    separation = doc.get("wheel_separation") or (params.wheel_separation if params is not None else 0.0)
    return Calibration(values, kept, base, laser, int(per_side), float(separation or 0.0))


def _comment_lines(cal: Calibration, source) -> list:
    lines = [f"Calibrated by sclam_ros (sclam export) from {source}."]
    if cal.kept_nominal:
        lines.append("NOT OBSERVABLE in the recording, left at their nominal value: "
                     + ", ".join(cal.kept_nominal) + ".")
    return lines


def urdf_joint(cal: Calibration, source, joint_name=None) -> str:
    """The fixed joint base frame -> laser frame. The calibration is planar: z, roll and
    pitch are not estimated and written as 0; keep your URDF's values for those."""
    x, y, yaw = (cal.values[k] for k in ("laser_x", "laser_y", "laser_yaw"))
    joint = joint_name or f"{cal.laser_frame}_joint"
    comment = " ".join(_comment_lines(cal, source)) + (
        f" Laser pose in {cal.base_frame}: x, y and yaw calibrated; z, roll and pitch are not"
        " (a planar calibration): keep your robot's.")
    return (f"<!-- {comment} -->\n"
            f'<joint name="{joint}" type="fixed">\n'
            f'  <parent link="{cal.base_frame}"/>\n'
            f'  <child link="{cal.laser_frame}"/>\n'
            f'  <origin xyz="{x:.6f} {y:.6f} 0" rpy="0 0 {yaw:.6f}"/>\n'
            f"</joint>\n")


def diff_drive_parameters(cal: Calibration) -> dict:
    """diff_drive_controller's wheel geometry. The controller uses
    wheel_radius × <side>_wheel_radius_multiplier per side and wheel_separation ×
    wheel_separation_multiplier; wheel_radius is the mean calibrated radius, so the
    multipliers carry the left/right difference. A skid-steer's wheel_separation is its
    geometric track (when given) and the multiplier widens it to the effective wheel base
    calibrated; it gets wheels_per_side too (an integer parameter of the controller)."""
    r_l, r_r, base = (cal.values[k] for k in ODOMETRY_KEYS)
    radius = 0.5 * (r_l + r_r)
    separation = cal.wheel_separation if cal.wheels_per_side > 1 and cal.wheel_separation else base
    skid = {"wheels_per_side": cal.wheels_per_side} if cal.wheels_per_side > 1 else {}
    return {"wheel_separation": separation, **skid, "wheel_separation_multiplier": base / separation,
            "wheel_radius": radius, "left_wheel_radius_multiplier": r_l / radius,
            "right_wheel_radius_multiplier": r_r / radius}


def _double(value) -> str:
    """A YAML float, never an integer: `1` would be an integer parameter, which a ROS 2
    node refuses for a parameter declared double."""
    text = f"{value:.9g}"
    return text if any(c in text for c in ".en") else text + ".0"


def diff_drive_yaml(cal: Calibration, source, controller=DEFAULT_CONTROLLER) -> str:
    lines = [f"# {line}" for line in _comment_lines(cal, source)]
    lines += ["# Merge into the controller's parameters (the controller manager's YAML).",
              f"{controller}:", "  ros__parameters:"]
    if cal.wheels_per_side > 1 and not cal.wheel_separation:
        lines.insert(-2, "# No geometric wheel_separation given: the effective wheel base is the "
                         "wheel_separation here.")
    lines += [f"    {k}: {v if isinstance(v, int) else _double(v)}"
              for k, v in diff_drive_parameters(cal).items()]
    return "\n".join(lines) + "\n"


def params_yaml(cal: Calibration, source, params: SclamParams) -> str:
    """The node's parameters with the calibrated values as the nominal ones."""
    header = "".join(f"# {line}\n" for line in _comment_lines(cal, source))
    return params.with_calibration(cal.values).yaml_text(header=header)


def export_text(cal: Calibration, fmt: str, source, params: SclamParams = None,
                controller=DEFAULT_CONTROLLER) -> str:
    if fmt == "urdf":
        return urdf_joint(cal, source)
    if fmt == "diff-drive":
        return diff_drive_yaml(cal, source, controller)
    if fmt == "params":
        if params is None:
            raise ExportError("--format params needs the parameters file the calibration "
                              "started from (--params)")
        return params_yaml(cal, source, params)
    raise ExportError(f"unknown format {fmt!r}; known: {', '.join(FORMATS)}")


# --- trajectories --------------------------------------------------------------------


def tum_text(stamps, poses) -> str:
    """TUM trajectory lines `timestamp x y z qx qy qz qw` of planar poses (x, y, θ)."""
    stamps, poses = np.asarray(stamps, float), np.asarray(poses, float)
    half = 0.5 * poses[:, 2]
    return "".join(f"{t:.9f} {x:.9g} {y:.9g} 0 0 0 {math.sin(h):.9g} {math.cos(h):.9g}\n"
                   for t, x, y, h in zip(stamps, poses[:, 0], poses[:, 1], half))


def trajectory_paths(out) -> dict:
    """OUT.tum -> the optimised poses at OUT.tum, the odometry beside it (OUT.nominal.tum,
    OUT.calibrated.tum) and, when the recording has it, the ground truth (OUT.truth.tum)."""
    out = Path(out)
    stem = out.with_suffix("") if out.suffix == ".tum" else out
    paths = {name: stem.with_name(f"{stem.name}.{name}.tum")
             for name in ("nominal", "calibrated", "truth")}
    return {"optimised": out, **paths}


def write_trajectories(out, result, bag_path=None) -> list:
    """Write the trajectories of a CalibrationResult in TUM format, all in the frame of the
    first scan's base pose: evo compares them as they are or aligned (`--align`)."""
    from sclam_ros.io.report import ground_truth_at, integrate_odometry

    inputs = result.inputs
    odometry = {name: integrate_odometry(inputs, np.array([values[k] for k in ODOMETRY_KEYS]))
                for name, values in (("nominal", result.nominal), ("calibrated", result.estimate))}
    trajectories = {"optimised": result.poses, **odometry}
    truth = ground_truth_at(bag_path, inputs.stamps) if bag_path is not None else None
    if truth is not None:
        trajectories["truth"] = truth
    paths = trajectory_paths(out)
    for name, poses in trajectories.items():
        atomic_write_text(paths[name], tum_text(inputs.stamps, poses))
    return [paths[name] for name in trajectories]
