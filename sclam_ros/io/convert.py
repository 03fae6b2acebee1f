"""Converters from published real-robot logs to rosbag2 + params.yaml + attribution.

Each converter reads one source file, writes ``OUT/bag`` (rosbag2 via BagWriter),
``OUT/params.yaml`` (SclamParams with the documented nominal values, so
``sclam calibrate OUT/bag --params OUT/params.yaml`` runs as is) and ``OUT/ATTRIBUTION.md``
(source repository, commit and licence), plus a copy of the source's licence file when it
sits beside the data.

breezyslam (github.com/simondlevy/BreezySLAM ``examples/exp{1,2}.dat``, LGPL-3.0):
    one line per scan, space separated. col0 timestamp (µs), col2/col3 left/right
    cumulative encoder ticks (both increase driving forward), cols 24–705 the 682 ranges
    of a Hokuyo URG-04LX in mm over 240°, index 0 at −120° (the scanner's right), angles
    increasing counter-clockwise (REP-103, as the URG reports them); 0 = no return.
    Nominal: r = 77 mm, b = 330 mm, 2000 ticks/rev, laser 145 mm ahead of the axle.

optiodom (github.com/sousarbarb/optiodom ``data/diff/*/<id>_run-NN.csv``, MIT):
    ``t, x_gt, y_gt, th_gt, odoR, odoL`` at 20 Hz, ticks per 50 ms cycle (right before
    left). Pololu 43.7:1 gearmotor with a 64 counts/rev (both edges of both channels,
    already ×4) motor encoder: 43.7 · 64 = 2796.8 ticks per wheel revolution; the nominal
    odometry speed in the session file (60 ticks/cycle) then gives 0.11 m/s, matching
    the motion-capture path (checked in test_convert). Wheel base 0.2 m, diameters 0.084 m.
"""
from __future__ import annotations

import math
import shutil
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from sclam_ros.io import carmen
from sclam_ros.io.bag import BagWriter
from sclam_ros.core.inputs import Scan
from sclam_ros.core.params import SclamParams

JOINTS = ("left_wheel_joint", "right_wheel_joint")


class ConvertError(ValueError):
    """A source file that cannot be converted; the message says why."""


@dataclass(frozen=True)
class Source:
    name: str
    repository: str
    paths: str
    commit: str
    licence: str
    licence_file: str  # name of the licence file beside the data (copied when present)
    notes: str


BREEZYSLAM = Source(
    name="BreezySLAM / CoreSLAM Mines ParisTech rover logs",
    repository="https://github.com/simondlevy/BreezySLAM",
    paths="examples/exp1.dat, examples/exp2.dat",
    commit="1170285cd42a88300eddd275fc3df36e642e3a2e (files added in f9ae4fc0d0f66b2ed379e17f8707dd94fec2198f "
           "and 182f0006af4ccf666fe4953da0ba8a99a24f3c69, 2014-09-07)",
    licence="LGPL-3.0 (the repository's licence; no separate data licence is given)",
    licence_file="LICENSE.md",
    notes="Data by the CoreSLAM authors (Steux & El Hamzaoui, ICARCV 2010, Mines ParisTech). "
          "Nominal parameters from examples/mines.py and OpenSLAM-org/openslam_tinyslam "
          "test/test_lab_reverse.c.",
)

OPTIODOM = Source(
    name="OptiOdom differential-drive runs with OptiTrack ground truth",
    repository="https://github.com/sousarbarb/optiodom",
    paths="data/diff/circular/231220200134/, data/diff/square/231220200029/",
    commit="8e025fd7a30c7152132e0ae53ba23bbc909f5a81",
    licence="MIT",
    licence_file="LICENSE",
    notes="Session metadata: gear 43.7, encoder resolution 64, wheel base 0.2 m, wheel diameters "
          "0.084/0.084 m.",
)

# --- breezyslam ----------------------------------------------------------------------
MINES_TICKS_PER_REV = 2000.0
MINES_RADIUS = 0.077
MINES_BASE = 0.33
MINES_LASER_X = 0.145
URG_BEAMS = 682
URG_FOV = np.radians(240.0)
URG_RANGE_MIN = 0.02  # m
URG_RANGE_MAX = 5.6  # m
RANGE_COLUMNS = slice(24, 24 + URG_BEAMS)


def breezyslam_params() -> SclamParams:
    return SclamParams(
        ticks_per_revolution=MINES_TICKS_PER_REV,
        wheel_radius_left=MINES_RADIUS, wheel_radius_right=MINES_RADIUS, wheel_base=MINES_BASE,
        laser_x=MINES_LASER_X, laser_y=0.0, laser_yaw=0.0,
    ).validate()


def read_breezyslam(path):
    """(stamps s, ticks (n, 2) left/right cumulative, ranges (n, 682) m with 0 → inf)."""
    try:
        table = np.loadtxt(path, dtype=float)
    except (OSError, ValueError) as exc:
        raise ConvertError(f"{path}: cannot read as a BreezySLAM .dat log: {exc}") from None
    if table.ndim != 2 or table.shape[1] < RANGE_COLUMNS.stop:
        raise ConvertError(f"{path}: expected ≥ {RANGE_COLUMNS.stop} columns per line, "
                           f"got shape {table.shape}")
    stamps = table[:, 0] * 1e-6
    ticks = np.ascontiguousarray(table[:, [2, 3]])
    ranges = np.ascontiguousarray(table[:, RANGE_COLUMNS] * 1e-3)
    ranges[ranges <= 0] = np.inf  # 0 mm = no return
    return stamps, ticks, ranges


def convert_breezyslam(src, out, storage="sqlite3", scan_delay: float = 0.0) -> dict:
    """``scan_delay`` (s): each line's scan was taken this long before the line's stamp;
    the scan is stamped that much earlier (recorded at the line's time, as a late message
    would be), and the encoder ticks, interpolated at the scan stamps by the frontend, stay
    at their own stamps. The logs give no delay; `sclam diagnose` finds one (selects
    time_offset ≈ −0.12 to −0.14 s as logged, docs/real_data.md)."""
    stamps, ticks, ranges = read_breezyslam(src)
    out = _prepare(out)
    increment = URG_FOV / (URG_BEAMS - 1)
    with BagWriter(out / "bag", storage) as bag:
        for stamp, tick, row in zip(stamps, ticks, ranges):
            bag.write_joint_state("/joint_states", stamp, JOINTS, tick)
            # Scan stamp = the log line's stamp − scan_delay; the log does not say whether
            # it marks the first beam or the end of the sweep, so no per-beam time is
            # claimed (time_increment 0: no de-skewing).
            bag.write_scan("/scan", Scan(
                stamp=stamp - scan_delay, ranges=row, angle_min=-URG_FOV / 2,
                angle_increment=increment, range_min=URG_RANGE_MIN, range_max=URG_RANGE_MAX,
                time_increment=0.0, frame_id="laser"), record_time_s=stamp, scan_time=0.1)
    delayed = f"; scans stamped {scan_delay * 1e3:.0f} ms before their log line" if scan_delay else ""
    _finish(out, src, BREEZYSLAM, breezyslam_params(),
            f"{len(stamps)} scans and encoder readings, {stamps[-1] - stamps[0]:.1f} s{delayed}")
    return {"scans": len(stamps), "duration_s": float(stamps[-1] - stamps[0])}


# --- optiodom ------------------------------------------------------------------------
OPTIODOM_GEAR = 43.7
OPTIODOM_ENCODER_COUNTS = 64  # per motor revolution, quadrature (×4) included
OPTIODOM_TICKS_PER_REV = OPTIODOM_GEAR * OPTIODOM_ENCODER_COUNTS
OPTIODOM_RADIUS = 0.084 / 2
OPTIODOM_BASE = 0.2


def optiodom_params() -> SclamParams:
    return SclamParams(
        ticks_per_revolution=OPTIODOM_TICKS_PER_REV,
        wheel_radius_left=OPTIODOM_RADIUS, wheel_radius_right=OPTIODOM_RADIUS,
        wheel_base=OPTIODOM_BASE,
    ).validate()


def read_optiodom(path):
    """(stamps s, ground-truth poses (n, 3), cumulative ticks (n, 2) left/right)."""
    try:
        table = np.loadtxt(path, delimiter=",", dtype=float, ndmin=2)
    except (OSError, ValueError) as exc:
        raise ConvertError(f"{path}: cannot read as an OptiOdom run CSV: {exc}") from None
    if table.shape[1] != 6:
        raise ConvertError(f"{path}: expected 6 columns t,x,y,th,odoR,odoL, got {table.shape[1]}")
    stamps, truth = table[:, 0], table[:, 1:4]
    per_cycle = table[:, [5, 4]]  # odoL, odoR: the file lists right before left
    return stamps, np.ascontiguousarray(truth), np.ascontiguousarray(np.cumsum(per_cycle, axis=0))


def convert_optiodom(src, out, storage="sqlite3") -> dict:
    stamps, truth, ticks = read_optiodom(src)
    out = _prepare(out)
    with BagWriter(out / "bag", storage) as bag:
        for stamp, tick, pose in zip(stamps, ticks, truth):
            bag.write_joint_state("/joint_states", stamp, JOINTS, tick)
            bag.write_odometry("/mocap/odom", stamp, pose, frame_id="mocap",
                               child_frame_id="marker")
    _finish(out, src, OPTIODOM, optiodom_params(),
            f"{len(stamps)} encoder cycles with motion-capture poses (/mocap/odom, frame "
            f"'mocap', child 'marker'), {stamps[-1] - stamps[0]:.1f} s; no laser")
    return {"samples": len(stamps), "duration_s": float(stamps[-1] - stamps[0])}


# --- carmen -------------------------------------------------------------------------
CARMEN = Source(
    name="CARMEN log (Radish / Freiburg SLAM benchmark format)",
    repository="the log's own source (see the licence file beside it)",
    paths="a .clf / .log file, optionally .bz2 or .gz",
    commit="as distributed with the log",
    licence="as stated beside the log; the Freiburg benchmark logs are CC-BY-3.0: cite Kümmerle, "
            "Steder, Dornhege, Ruhnke, Grisetti, Stachniss, Kleiner, \"On measuring the accuracy "
            "of SLAM algorithms\", Autonomous Robots 27(4), 2009",
    licence_file="LICENSE",
    notes="Wheel rotations are implied from the logged odometry poses with the nominal radius "
          "and wheel base in params.yaml: the calibration is relative to them.",
)


def convert_carmen(src, out, storage="sqlite3", radius: float = carmen.NOMINAL_RADIUS,
                   base: float = carmen.NOMINAL_BASE, scan_delay: float = 0.0,
                   fov: float = carmen.FLASER_FOV) -> dict:
    """/joint_states (wheel angles in rad implied from the odometry poses), /scan, and the
    log's odometry as /odom (nav_msgs/Odometry, for comparison only). ``scan_delay`` (s):
    each scan was taken this long before its line's ipc_timestamp; it is stamped that much
    earlier and recorded at the line's time, as a late message is. ``fov`` (rad): the span
    of the FLASER lines' beams, which the log does not state."""
    try:
        log = carmen.read_carmen(src, flaser_fov=fov)
    except carmen.CarmenError as exc:
        raise ConvertError(str(exc)) from None
    stamps, poses, odometry_source = carmen.odometry_track(log)
    order = np.argsort(stamps, kind="stable")
    backwards = int(np.count_nonzero(np.diff(stamps) < 0))
    stamps, poses = stamps[order], poses[order]
    angles, sideways = carmen.implied_wheel_angles(poses, radius, base)
    mount = carmen.laser_mount(log)
    out = _prepare(out)
    with BagWriter(out / "bag", storage) as bag:
        messages = [(stamp, 0, i) for i, stamp in enumerate(stamps)]
        messages += [(laser.stamp, 1, i) for i, laser in enumerate(log.lasers)]
        for stamp, kind, i in sorted(messages):
            if kind == 0:
                bag.write_joint_state("/joint_states", stamp, JOINTS, angles[i])
                bag.write_odometry("/odom", stamp, poses[i])
            else:
                bag.write_scan("/scan", carmen.laser_scan(log.lasers[i], scan_delay),
                               record_time_s=stamp)
    params = carmen.carmen_params(mount, radius, base)
    notes = (f"{len(stamps)} odometry poses (from {odometry_source}) and {len(log.lasers)} scans, "
             f"{stamps[-1] - stamps[0]:.1f} s; nominal wheel radius {radius} m and wheel base "
             f"{base} m; laser mount ({mount[0]:.3f} m, {mount[1]:.3f} m, "
             f"{math.degrees(mount[2]):.2f}°); sideways odometry dropped: "
             f"{np.abs(sideways).sum():.3f} m in total")
    if backwards:
        notes += f"; {backwards} odometry stamps out of order, sorted"
    if scan_delay:
        notes += f"; scans stamped {scan_delay * 1e3:.0f} ms before their log line"
    if fov != carmen.FLASER_FOV:
        notes += f"; FLASER beams spread over {math.degrees(fov):.2f}°"
    if log.skipped:
        notes += "; lines not converted: " + ", ".join(
            f"{name} {count}" for name, count in sorted(log.skipped.items()))
    _finish(out, src, CARMEN, params, notes)
    return {"scans": len(log.lasers), "odometry": len(stamps),
            "duration_s": float(stamps[-1] - stamps[0]),
            "sideways_m": float(np.abs(sideways).sum())}


CONVERTERS = {"breezyslam": convert_breezyslam, "optiodom": convert_optiodom,
              "carmen": convert_carmen}


# --- shared --------------------------------------------------------------------------
def _prepare(out) -> Path:
    out = Path(out)
    if (out / "bag").exists():
        raise ConvertError(f"{out / 'bag'} already exists; choose another OUT")
    out.mkdir(parents=True, exist_ok=True)
    return out


def _finish(out: Path, src, source: Source, params: SclamParams, content: str) -> None:
    src = Path(src)
    params.write_yaml(out / "params.yaml",
                      header=f"# Nominal parameters of {source.name} ({source.repository}).\n")
    licence = src.parent / source.licence_file
    for folder in (src.parent, *src.parents):
        if (folder / source.licence_file).is_file():
            licence = folder / source.licence_file
            break
    copied = ""
    if licence.is_file():
        shutil.copy(licence, out / f"SOURCE_{source.licence_file}")
        copied = f"\nThe source's licence text is copied beside this file as `SOURCE_{source.licence_file}`.\n"
    (out / "ATTRIBUTION.md").write_text(
        f"# {source.name}\n\n"
        f"Converted by `sclam convert` from `{src.name}`.\n\n"
        f"- **Source:** {source.repository}, `{source.paths}`\n"
        f"- **Commit:** {source.commit}\n"
        f"- **Licence:** {source.licence}\n"
        f"- **Notes:** {source.notes}\n"
        f"- **Content:** {content}\n"
        f"{copied}\n"
        f"Calibrate with `sclam calibrate {out / 'bag'} --params {out / 'params.yaml'}`.\n"
    )
