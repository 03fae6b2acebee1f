"""``sclam simulate OUT``: record a simulated rosbag2 with ground truth.

OUT becomes the rosbag2 folder, with params.yaml (nominal values) and truth.json
(true values) beside the storage file, so ``sclam calibrate OUT --params OUT/params.yaml``
works right away.
"""
from __future__ import annotations

import argparse
import math
import sys
import time

from sclam_ros.core.params import CALIBRATION_KEYS
from sclam_ros.sim.conditions import NO_RETURN_ENCODINGS


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from sclam_ros.sim.effects import EFFECTS
    from sclam_ros.sim.robots import PRESETS
    from sclam_ros.sim.trajectory import MOTIONS
    from sclam_ros.sim.world import SCENES

    parser.add_argument("out", help="output folder (becomes the rosbag2; must not exist)")
    parser.add_argument("--robot", choices=sorted(PRESETS), default="powerbot",
                        help="robot preset (default: %(default)s)")
    parser.add_argument("--duration", type=float, default=300.0, help="seconds (default: %(default)s)")
    parser.add_argument("--seed", type=int, default=0, help="random seed (default: %(default)s)")
    parser.add_argument("--true", action="append", default=[], metavar="KEY=VALUE",
                        help=f"override a true value (SI, radians); keys: {', '.join(CALIBRATION_KEYS)} "
                             "(a skid-steer's wheel_base: its geometric track)")
    parser.add_argument("--track-widening", type=float, metavar="CHI",
                        help="skid-steer (--robot skid): its sides turn about centres CHI times as "
                             "far apart as its geometric track, the effective wheel base CHI times "
                             "the track (default: the preset's, 1.5 for skid, 1 for the others)")
    parser.add_argument("--storage", choices=("sqlite3", "mcap"), default="sqlite3",
                        help="rosbag2 storage (default: %(default)s)")
    effects_help = "; ".join(
        f"{cls.name} ({', '.join(f'{p} [{u}] = {d}' for p, d, u in cls.params)}): {cls.doc}"
        for cls in EFFECTS.values()
    )
    parser.add_argument("--effect", action="append", default=[], metavar="NAME[=VALUE]",
                        help="switch on an un-modelled effect; VALUE is V1[,V2...] in parameter "
                        "order or key:value,... . Effects: "
                        + effects_help.replace("%", "%%"))  # argparse %-formats help text
    parser.add_argument("--scan-rate", type=float, default=10.0, help="Hz (default: %(default)s)")
    parser.add_argument("--beams", type=int, default=360, help="beams per scan (default: %(default)s)")
    parser.add_argument("--encoder-rate", type=float, default=50.0, help="Hz (default: %(default)s)")
    parser.add_argument("--range-noise", type=float, default=0.01, help="m, 1σ (default: %(default)s)")
    parser.add_argument("--range-noise-per-m", type=float, default=0.0,
                        help="range noise growing with range, 1σ per m (default: %(default)s)")
    parser.add_argument("--fov", type=float, default=360.0, help="laser field of view, deg (default: %(default)s)")
    parser.add_argument("--range-max", type=float, default=20.0, help="laser range, m (default: %(default)s)")
    parser.add_argument("--dropout", type=float, default=0.0,
                        help="probability that a beam with a target returns nothing (default: %(default)s)")
    parser.add_argument("--mixed-pixels", type=float, default=0.0,
                        help="probability of a point between the surfaces at a depth edge (default: %(default)s)")
    parser.add_argument("--range-resolution", type=float, default=0.0,
                        help="m: ranges reported as multiples of this, 0 for continuous "
                             "(default: %(default)s)")
    parser.add_argument("--scene", choices=tuple(SCENES), default="office",
                        help="office: walls and furniture; outdoor: trees, poles, parked cars; "
                             "corridors: a ring of bare corridors between four lobbies (default: %(default)s)")
    parser.add_argument("--motion", choices=MOTIONS, default="route",
                        help="route: a random drive that excites every parameter; straight, "
                             "straight_then_turns, spin, still: fixed patterns that leave some "
                             "undetermined (default: %(default)s)")
    parser.add_argument("--wheels", choices=("joint_states", "odom", "both"), default="joint_states",
                        help="what the base publishes of its wheels: /joint_states (encoder ticks), "
                             "/odom (wheel odometry integrated from them with the nominal values, "
                             "as diff_drive_controller does; params.yaml then reads it), or both "
                             "(default: %(default)s)")
    parser.add_argument("--robot-description", action="store_true",
                        help="also write /robot_description (URDF) and /tf_static (laser joint) "
                             "with the nominal values, as robot_state_publisher latches them, so "
                             "that `sclam calibrate OUT` runs without a parameters file")
    parser.add_argument("--joint-units", choices=("ticks", "rad"), default="ticks",
                        help="JointState positions in encoder ticks, or in rad as ros2_control "
                             "publishes them (default: %(default)s)")
    conditions = parser.add_argument_group(
        "recording conditions", "how the recording is made, apart from the robot and its drive "
        "(sclam_ros/sim/conditions.py): what real recordings vary")
    conditions.add_argument("--slip-noise", type=float, metavar="SIGMA",
                            help="the wheels' slip noise, 1σ per wheel per step "
                                 "(default: the simulator's; 0: exact encoders)")
    conditions.add_argument("--ticks-per-revolution", type=float, metavar="N",
                            help="encoder resolution (default: the robot preset's)")
    conditions.add_argument("--scan-phase", type=float, metavar="S",
                            help="s from the first encoder sample to the first scan; a multiple "
                                 "of the encoder period puts every scan on a sample "
                                 "(default: the simulator's)")
    conditions.add_argument("--scan-stamp-jitter", type=float, default=0.0, metavar="S",
                            help="1σ of each scan stamp's error, s (default: %(default)s)")
    conditions.add_argument("--no-return", choices=NO_RETURN_ENCODINGS, default="inf",
                            help="how a beam without a target is written (default: %(default)s)")
    conditions.add_argument("--sweep-unstated", action="store_true",
                            help="a sweeping laser (--effect scan_motion) writes time_increment 0")
    parser.add_argument("--overwrite", action="store_true", help="replace OUT if it exists")
    parser.add_argument("--quiet", action="store_true", help="no progress on stderr")


def _key_values(items, what):
    out = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not key:
            raise ValueError(f"--{what} expects KEY=VALUE, got {item!r}")
        out[key.strip()] = value.strip() if sep else None
    return out


def run(args) -> int:
    from sclam_ros.io.bag import BagError
    from sclam_ros.sim import simulate
    from sclam_ros.sim.conditions import RecordingConditions
    from sclam_ros.sim.record import SCAN_PHASE

    start = time.monotonic()

    def progress(message):
        if not args.quiet:
            print(f"[sclam simulate {time.monotonic() - start:6.1f} s] {message}", file=sys.stderr, flush=True)

    try:
        overrides = _key_values(args.true, "true")
        for key, value in overrides.items():
            if value is None:
                raise ValueError(f"--true {key} needs a value: --true {key}=VALUE")
            overrides[key] = float(value)
        effects = _key_values(args.effect, "effect")
        conditions = RecordingConditions(
            scan_phase=SCAN_PHASE if args.scan_phase is None else args.scan_phase,
            scan_stamp_jitter=args.scan_stamp_jitter,
            sweep_stated=not args.sweep_unstated, no_return=args.no_return,
            ticks_per_revolution=args.ticks_per_revolution)
        slip = {} if args.slip_noise is None else {"slip_noise": args.slip_noise}
        truth = simulate(
            args.out, robot=args.robot, duration=args.duration, seed=args.seed,
            true_overrides=overrides, storage=args.storage, scan_rate=args.scan_rate,
            beams=args.beams, encoder_rate=args.encoder_rate, range_noise=args.range_noise,
            effects=effects, progress=progress, overwrite=args.overwrite, scene=args.scene,
            motion=args.motion, wheels=args.wheels, description=args.robot_description,
            joint_units=args.joint_units, track_widening=args.track_widening,
            laser=dict(fov=math.radians(args.fov), range_max=args.range_max,
                       range_noise_per_m=args.range_noise_per_m, dropout=args.dropout,
                       mixed_pixels=args.mixed_pixels,
                       range_resolution=args.range_resolution),
            conditions=conditions, **slip,
        )
    except (ValueError, BagError) as exc:
        print(f"sclam simulate: error: {exc}", file=sys.stderr)
        return 2
    print(
        f"wrote {args.out}: {truth['robot']}, {truth['duration']:.0f} s, "
        f"{truth['path_length']:.0f} m driven, effects: {', '.join(truth['effects']) or 'none'}"
    )
    return 0


def main(argv=None) -> int:
    """Stand-alone entry point (the ``sclam`` CLI calls add_arguments/run itself)."""
    parser = argparse.ArgumentParser(prog="sclam simulate", description=__doc__.splitlines()[0])
    add_arguments(parser)
    return run(parser.parse_args(argv))


if __name__ == "__main__":
    sys.exit(main())
