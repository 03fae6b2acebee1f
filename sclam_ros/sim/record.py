"""``simulate()``: drive a simulated robot and record a rosbag2 with ground truth.

Output layout: ``out`` IS the rosbag2 folder (metadata.yaml + one .db3 or .mcap), with
two extra files beside them that rosbag2 readers ignore:

- ``params.yaml``: ROS 2 parameters for node ``sclam`` with the NOMINAL calibration,
  topics, joint names and ticks per revolution, so
  ``sclam calibrate OUT --params OUT/params.yaml`` runs as is;
- ``truth.json``: the TRUE calibration (same key names), robot, seed, duration, the
  effects applied with their parameters, and the recording's start time.

Topics: ``/joint_states`` (sensor_msgs/JointState, cumulative ticks) and/or ``/odom``
(nav_msgs/Odometry odom → base_link: the wheel odometry of the nominal values, see
``wheels``),
``/scan`` (sensor_msgs/LaserScan, frame "laser"), ``/ground_truth/odom``
(nav_msgs/Odometry odom → base_link at the encoder rate, or at the control rate when
the encoders are slower, true time stamps; the
odom frame is the robot's start pose, whose world pose truth.json gives as
``odom_origin_in_world``).
Record time = header stamp for every message.
"""
from __future__ import annotations

import dataclasses
import json
import shutil
from pathlib import Path

import numpy as np

from sclam_ros.core import kinematics, se2
from sclam_ros.io.bag import BagError, BagWriter
from sclam_ros.core.params import ODOMETRY_KEYS, SclamParams, atomic_write_text
from sclam_ros.sim.conditions import RecordingConditions
from sclam_ros.sim.description import laser_transform, robot_urdf
from sclam_ros.sim.effects import EffectSet
from sclam_ros.sim.motion import TrueKinematics
from sclam_ros.sim.robots import get_preset, true_calibration
from sclam_ros.sim.sensors import DEFAULT_SLIP_NOISE, LaserModel, encoder_samples, laser_scans
from sclam_ros.sim.trajectory import simulate_trajectory
from sclam_ros.sim.world import scene_world

START_TIME = 1_700_000_000.0  # s, epoch of t = 0: stamps look like a real recording's
JOINT_STATES_TOPIC = "/joint_states"
SCAN_TOPIC = "/scan"
GROUND_TRUTH_TOPIC = "/ground_truth/odom"
ODOMETRY_TOPIC = "/odom"
# What the simulated base publishes of its wheels: their JointState, its wheel odometry
# (nav_msgs/Odometry integrated from the encoders with the nominal values), or both.
WHEEL_OUTPUTS = ("joint_states", "odom", "both")
JOINT_UNITS = ("ticks", "rad")
ROBOT_DESCRIPTION_TOPIC = "/robot_description"
JOINT_NAMES = ("left_wheel_joint", "right_wheel_joint")
SKID_JOINT_NAMES = ("front_left_wheel_joint", "rear_left_wheel_joint",
                    "front_right_wheel_joint", "rear_right_wheel_joint")
CONTROL_RATE = 50.0  # Hz, the simulated controller's update rate
# Scans start a little after the encoders so the two streams never share stamps and the
# sync has to interpolate, as on a real robot.
SCAN_PHASE = 0.013  # s


def simulate(out, robot="powerbot", duration=300.0, seed=0, true_overrides=None, storage="sqlite3",
             scan_rate=10.0, beams=360, encoder_rate=50.0, range_noise=0.01, effects=None,
             progress=None, slip_noise=DEFAULT_SLIP_NOISE, overwrite=False, scene="office",
             laser=None, motion="route", outdoor=None, wheels="joint_states",
             description=False, joint_units="ticks", track_widening=None,
             conditions=None) -> dict:
    """Simulate ``duration`` s of ``robot`` driving through ``scene`` into ``out``.

    Deterministic for a seed. ``true_overrides``: dict of calibration keys -> true value.
    ``effects``: dict name -> value (see ``sclam_ros.sim.effects.EFFECTS``).
    ``scene``: "office" (walls, rooms, furniture), "outdoor" (trees, poles, parked cars) or
    "corridors" (a ring of bare corridors between four lobbies), each with the suffix
    "-mirrored" reflected left for right (world.mirrored).
    ``motion``: "route" (random, excites every parameter) or a fixed pattern that does not
    ("straight", "straight_then_turns", "spin", "still": sim.trajectory.MOTIONS).
    ``laser``: further LaserModel fields (fov in rad, range_max, range_noise_per_m,
    dropout, mixed_pixels) beside ``beams`` and ``range_noise``.
    ``outdoor``: the outdoor scene's objects changed (world.OutdoorScene; other scenes ignore it).
    ``wheels``: "joint_states" (/joint_states), "odom" (/odom only: the base's wheel odometry,
    integrated from the same encoder samples with the nominal values, as
    diff_drive_controller does) or "both"; params.yaml reads /odom only when it is alone.
    ``description``: also write /robot_description (the URDF) and /tf_static (the laser joint),
    with the nominal values, as robot_state_publisher latches them.
    ``joint_units``: the JointState's positions in encoder "ticks" or in "rad" (as
    ros2_control's joint_state_broadcaster publishes them: still quantised by the encoder).
    ``track_widening``: χ of a skid-steer (the preset's when None; motion.TrueKinematics):
    its sides turn about centres χ times as far apart as its geometric track. A preset with
    several wheels per side (``skid``) writes each wheel's joint (SKID_JOINT_NAMES) and
    params.yaml names them in left_wheel_joints / right_wheel_joints; its ``--true
    wheel_base`` is the geometric track, and truth.json's ``wheel_base`` the effective one
    (χ times it) beside ``wheel_separation`` (the geometric one) and ``track_widening``.
    ``conditions``: a sim.conditions.RecordingConditions (scan phase, stamp jitter, whether
    a sweep is stated, how no return is encoded, encoder resolution; default: scans 13 ms
    after the encoder samples, exact stamps, inf). ``progress``: callable taking a one-line
    message. Returns the truth (as truth.json).
    """
    report = progress or (lambda message: None)
    out = Path(out)
    if out.exists():
        if not overwrite:
            raise BagError(f"{out} exists already; remove it or choose another output folder")
        shutil.rmtree(out)
    if duration <= 0:
        raise ValueError(f"duration must be > 0 s, got {duration}")
    if joint_units not in JOINT_UNITS:
        raise ValueError(f"joint_units must be one of {', '.join(JOINT_UNITS)}, got {joint_units!r}")
    if wheels not in WHEEL_OUTPUTS:
        raise ValueError(f"wheels must be one of {', '.join(WHEEL_OUTPUTS)}, got {wheels!r}")
    preset = get_preset(robot)
    conditions = conditions or RecordingConditions(scan_phase=SCAN_PHASE)
    if conditions.ticks_per_revolution is not None:
        preset = dataclasses.replace(preset, ticks_per_revolution=conditions.ticks_per_revolution)
    widening = preset.track_widening if track_widening is None else float(track_widening)
    if not 1.0 <= widening <= 5.0:
        raise ValueError(f"track_widening must be in [1, 5], got {widening}")
    if description and preset.wheels_per_side > 1:
        raise ValueError("the robot description written is a two-wheel one: not for a skid-steer")
    truth = true_calibration(preset, true_overrides)
    effect_set = EffectSet.from_spec(effects).for_duration(duration)
    kinematics = TrueKinematics(
        truth["wheel_radius_left"], truth["wheel_radius_right"], truth["wheel_base"], effect_set,
        widening,
    )
    geometric_track = truth["wheel_base"]
    truth["wheel_base"] = kinematics.effective_wheel_base
    mount = np.array([truth["laser_x"], truth["laser_y"], truth["laser_yaw"]])
    world = scene_world(scene, outdoor)
    model = LaserModel(beams=beams, range_noise=range_noise, **(laser or {}))
    # Independent streams per purpose: changing the laser model does not change the route.
    route_seed, encoder_rng, laser_rng, stamp_rng = np.random.SeedSequence(seed).spawn(4)

    report(f"planning and driving {duration:.0f} s of trajectory ({preset.name}, seed {seed})")
    trajectory = simulate_trajectory(
        world, kinematics, duration, int(route_seed.generate_state(1)[0]), preset.footprint_radius,
        CONTROL_RATE, motion=motion,
    )
    encoders = encoder_samples(
        trajectory, kinematics, encoder_rate, preset.ticks_per_revolution,
        np.random.default_rng(encoder_rng), slip_noise, preset.wheels_per_side,
    )
    time_increment = effect_set.scan_time_increment(scan_rate, beams)
    phase = conditions.scan_phase
    scan_times = phase + np.arange(
        int(np.floor((duration - phase - time_increment * beams) * scan_rate)) + 1
    ) / scan_rate

    def scan_progress(done, total):
        if done == total or done % 2000 < 200:
            report(f"ray casting scans {done}/{total}")

    scans = laser_scans(
        world, trajectory, mount, scan_times, model, np.random.default_rng(laser_rng),
        time_increment, START_TIME, progress=scan_progress,
    )
    scans = _as_recorded(scans, conditions, np.random.default_rng(stamp_rng))

    report(f"writing {storage} bag {out}")
    odometry = wheel_odometry(encoders, preset) if wheels != "joint_states" else None
    latched = None
    if description:
        latched = (robot_urdf(preset.name, preset.nominal), laser_transform(preset.nominal))
    in_rad = joint_units == "rad"
    positions = encoders.ticks * (2.0 * np.pi / preset.ticks_per_revolution if in_rad else 1.0)
    names = joint_names(preset)
    _write_bag(out, storage, trajectory, encoders.times, positions, scans, effect_set,
               joint_states=wheels != "odom", odometry=odometry, latched=latched, names=names)

    params = SclamParams(
        joint_states_topic=JOINT_STATES_TOPIC,
        scan_topic=SCAN_TOPIC,
        left_wheel_joint=JOINT_NAMES[0],
        right_wheel_joint=JOINT_NAMES[1],
        ticks_per_revolution=float(preset.ticks_per_revolution),
        **preset.nominal,
    )
    if preset.wheels_per_side > 1:
        half = len(names) // 2
        params = dataclasses.replace(params, left_wheel_joints=names[:half],
                                     right_wheel_joints=names[half:],
                                     wheel_separation=preset.wheel_separation)
    if wheels == "odom" or in_rad:
        params = dataclasses.replace(params, ticks_per_revolution=0.0)
    if wheels == "odom":
        params = dataclasses.replace(params, odometry_topic=ODOMETRY_TOPIC)
    params.validate()
    params.write_yaml(
        out / "params.yaml",
        header=f"# Nominal parameters of the simulated {preset.name} (sclam simulate, seed {seed}).\n"
        "# The true values are in truth.json beside this file.\n",
    )
    truth_doc = {
        **truth,
        "robot": preset.name,
        "seed": int(seed),
        "duration": float(duration),
        "start_time": START_TIME,
        "effects": effect_set.describe(),
        "scene": scene,
        "motion": motion,
        "nominal": dict(preset.nominal),
        "ticks_per_revolution": float(preset.ticks_per_revolution),
        "wheels_per_side": preset.wheels_per_side,
        "wheel_separation": geometric_track,
        "track_widening": widening,
        "storage": storage,
        "sensors": {
            "encoder_rate": float(encoder_rate),
            "scan_rate": float(scan_rate),
            "beams": int(beams),
            "fov_deg": float(np.degrees(model.fov)),
            "range_noise": float(range_noise),
            "range_noise_per_m": float(model.range_noise_per_m),
            "range_max": model.range_max,
            "dropout": float(model.dropout),
            "mixed_pixels": float(model.mixed_pixels),
            "slip_noise": float(slip_noise),
            "control_rate": CONTROL_RATE,
        },
        "wheels": wheels,
        "joint_units": joint_units,
        "conditions": conditions.describe(),
        "topics": {
            **({"robot_description": ROBOT_DESCRIPTION_TOPIC, "tf_static": "/tf_static"}
               if description else {}),
            **({"joint_states": JOINT_STATES_TOPIC} if wheels != "odom" else {}),
            **({"odometry": ODOMETRY_TOPIC} if wheels != "joint_states" else {}),
            "scan": SCAN_TOPIC,
            "ground_truth": GROUND_TRUTH_TOPIC,
        },
        "odom_origin_in_world": [float(v) for v in trajectory.pose_at(0.0)],
        "path_length": float(np.abs(trajectory.twists[:, 0]).sum() * trajectory.dt),
        "rotation_total": float(np.abs(trajectory.twists[:, 2]).sum() * trajectory.dt),
    }
    atomic_write_text(out / "truth.json", json.dumps(truth_doc, indent=2) + "\n")
    report(f"done: {out}")
    return truth_doc


def _truth_times(encoder_times, duration):
    """When the ground truth is recorded: with the encoders, or at CONTROL_RATE when they are
    slower. Users of the truth interpolate it at scan stamps; on a 2 Hz grid that cuts the
    corners of every turn (measured: scan matches looked 0.2 % long against it).
    """
    if len(encoder_times) > 1 and np.median(np.diff(encoder_times)) <= 1.0 / CONTROL_RATE + 1e-9:
        return encoder_times
    return np.arange(int(np.floor(duration * CONTROL_RATE + 1e-9)) + 1) / CONTROL_RATE


def joint_names(preset) -> tuple:
    """The JointState names of the preset's wheels: the left side's, then the right's."""
    return SKID_JOINT_NAMES if preset.wheels_per_side > 1 else JOINT_NAMES


def wheel_odometry(encoders, preset):
    """(poses (J, 3), twists (J, 2) v, ω): the encoder samples integrated with the preset's
    nominal values, as a base driver or diff_drive_controller does (a side's wheels
    averaged); the twist of each sample is its last increment over its interval (0 at the
    first)."""
    k = np.array([preset.nominal[key] for key in ODOMETRY_KEYS])
    dphi = np.diff(encoders.side_ticks(), axis=0) * 2.0 * np.pi / preset.ticks_per_revolution
    motion = np.zeros((len(encoders.times), 3))
    motion[1:] = kinematics.forward(dphi, k)
    twists = np.zeros((len(encoders.times), 2))
    s, theta = kinematics.arc_length_and_rotation(dphi, k)
    dt = np.diff(encoders.times)
    twists[1:, 0], twists[1:, 1] = s / dt, theta / dt
    return se2.chain(motion), twists


def _write_bag(out, storage, trajectory, encoder_times, positions, scans, effect_set: EffectSet,
               joint_states=True, odometry=None, latched=None, names=JOINT_NAMES) -> None:
    """All messages in record-time order (= header stamp order). ``joint_states``: write the
    wheel ``positions`` (a column per joint of ``names``) sampled at ``encoder_times`` on
    /joint_states; ``odometry``: (poses,
    twists) written on /odom at the encoder stamps; ``latched``: (URDF text, laser transform)
    written first on /robot_description and /tf_static."""
    encoder_stamps = START_TIME + effect_set.encoder_stamp(encoder_times)
    truth_times = _truth_times(encoder_times, trajectory.duration)
    truth_stamps = START_TIME + truth_times
    # REP-105: the odom frame is where the robot started, so the truth starts at identity.
    truth_poses = se2.between(trajectory.pose_at(truth_times), trajectory.pose_at(0.0))
    truth_twists = trajectory.twist_at(truth_times)
    # (record time, kind, index); kind orders simultaneous messages deterministically.
    events = [(t, 0, i) for i, t in enumerate(encoder_stamps)] if joint_states else []
    if odometry is not None:
        events += [(t, 3, i) for i, t in enumerate(encoder_stamps)]
    events += [(t, 1, i) for i, t in enumerate(truth_stamps)]
    events += [(scan.stamp, 2, i) for i, scan in enumerate(scans)]
    events.sort()
    with BagWriter(out, storage) as bag:
        if latched is not None:
            bag.write_string(ROBOT_DESCRIPTION_TOPIC, latched[0], START_TIME)
            bag.write_tf_static(START_TIME, [latched[1]])
        for stamp, kind, i in events:
            if kind == 0:
                bag.write_joint_state(JOINT_STATES_TOPIC, stamp, names, positions[i])
            elif kind == 1:
                bag.write_odometry(GROUND_TRUTH_TOPIC, stamp, truth_poses[i], truth_twists[i])
            elif kind == 3:
                bag.write_odometry(ODOMETRY_TOPIC, stamp, odometry[0][i], odometry[1][i])
            else:
                bag.write_scan(SCAN_TOPIC, scans[i])


def _as_recorded(scans, conditions: RecordingConditions, rng):
    """The scans as the driver writes them: stamps off by the stamping jitter (kept in
    order: a jittered stamp is never before the previous one), no returns in its encoding,
    time_increment 0 where it does not state a sweep."""
    out = []
    last = -np.inf
    for scan in scans:
        stamp = scan.stamp
        if conditions.scan_stamp_jitter > 0.0:
            stamp = max(stamp + conditions.scan_stamp_jitter * rng.standard_normal(), last + 1e-4)
        last = stamp
        out.append(dataclasses.replace(
            scan, stamp=float(stamp),
            ranges=conditions.encode_no_return(scan.ranges, scan.range_max),
            time_increment=scan.time_increment if conditions.sweep_stated else 0.0))
    return out
