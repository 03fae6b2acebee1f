"""The front end's developer tuning: one tree of small frozen dataclasses (KISS-ICP's KISSConfig).

What a user sets for their robot is in core/params.py (SclamParams); these values are the
front end's own. Frontend and RefinedScanMatcher take a FrontendConfig and hand each part
the section it needs; a bench or test varies one by passing another, e.g.
``FrontendConfig(refinement=RefinementConfig(huber=0.2))``. Where a value was chosen by
measuring, docs/decisions/point_to_line.md keeps the measurement under the decision named.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field


@dataclass(frozen=True)
class LaserNoiseConfig:
    """How the laser's range noise is judged from its first scans (laser_noise.py;
    decision: "Which lasers are noisy", "Range noise that grows with range")."""

    # m: from this judged noise on, lines are whole wall segments (six beams' lines turn with it).
    noisy_range: float = 0.02
    # m: above this the returns are not on surfaces (poles, foliage): it says nothing of the laser.
    not_a_noise: float = 0.1
    # scans: the noise is judged on the first this many reference scans, then fixed.
    noise_scans: int = 30
    # bins: the returns on walls are split into this many by range to measure σ(r).
    growth_bins: int = 10
    # returns per bin at least: fewer tell no growth, and every return weighs alike.
    growth_samples: int = 100
    # sine of a beam's angle to its neighbours' chord, at least: nearer grazing, their noise rules.
    growth_min_sine: float = 0.5
    # of σ(0): the growth over the ranges seen, at the slope's lower 95 % bound, that is used.
    growth_significant: float = 0.3


@dataclass(frozen=True)
class ReferenceLinesConfig:
    """Which of the reference scan's returns get a line, and how (reference_lines.py;
    decisions: "A noisy laser's lines", "Returns on small objects", "The driver's cut at
    the range limit")."""

    # returns: a quiet laser's line at each return is fitted over this many nearest ones.
    normal_neighbours: int = 6
    # m RMS off such a line: beyond it the neighbourhood is a corner, not a wall.
    max_line_spread: float = 0.02
    # m: narrower objects get no six-beam line from small_object_noise on: their noise picks it.
    small_object: float = 1.0
    # m of judged range noise from which small objects get no line (a quieter laser's hold).
    small_object_noise: float = 0.005
    # × the judged noise: lines this near range_max are left out (its cut makes walls look near).
    clear_of_limit: float = 3.0


@dataclass(frozen=True)
class PairingConfig:
    """Which reference point a new point is paired with (reference_lines.py, point_to_line.py;
    decision: "Pairing along the line")."""

    # m across a reference point's line (around an anchor): KISS-ICP's answer is a few cm off.
    max_pair_distance: float = 0.15
    # × the beams' spacing on the surface: how far along its line a point may pair with a return.
    along_reach: float = 0.6
    # m: the most that reach along a line may be.
    along_cap: float = 1.0
    # cos of the incidence taken at least, for spacings on a surface and a wall's range at grazing.
    min_cos_incidence: float = 0.2


@dataclass(frozen=True)
class RefinementConfig:
    """The point-to-line Gauss-Newton refinement and when its answer is used (point_to_line.py;
    decision: "Corrections too large to be true")."""

    # m: the Huber weight's scale, ~2σ of the range noise of a typical 2D lidar.
    huber: float = 0.02
    # steps of Gauss-Newton at most, from KISS-ICP's answer (it stops at steps under 1 µm).
    iterations: int = 15
    # m: a refinement moving KISS-ICP's answer farther locks onto lines that are not there.
    max_correction: float = 0.05
    # rad: the same for the heading.
    max_correction_angle: float = 0.02


@dataclass(frozen=True)
class WallSegmentsConfig:
    """A noisy laser's scan cut into straight segments and their lines fitted on ranges
    (wall_segments.py; decision: "A noisy laser's lines"). First choices measured together,
    as the calibrations they give, not tuned one by one."""

    # rad: returns farther apart than a surface at this incidence allows are on two surfaces.
    breakpoint_incidence: float = math.radians(10.0)
    # × the range noise: the breakpoints' margin; one wall's returns differ by up to ~3·√2σ.
    break_noise: float = 4.0
    # × the range noise: a segment is straight when its returns' RMS off its line is within this...
    straight_spread: float = 1.3
    # × the range noise: ...and its farthest return's within this (of a few hundred draws ~3σ).
    split_deviation: float = 4.0
    # of a piece's returns: around its farthest return, where the two sides' lines are tried.
    split_reach: float = 0.1
    # returns: fewer make no line (a few returns' fit turns with their noise, ~σ·√(12/n)/L).
    min_segment_returns: int = 10
    # m: a shorter stretch of wall makes no line, for the same reason.
    min_segment_length: float = 0.3
    # cos of the incidence: a more glancing beam has no anchor (its meeting point moves by metres).
    min_cos_incidence: float = 0.1
    # × the range noise: returns this near a corner's other wall may be either wall's: not used.
    ambiguous: float = 3.0
    # rad: lines this far apart in direction or more meet at a corner (less: a wall split in two).
    corner: float = math.radians(10.0)
    # steps of Gauss-Newton at most in a segment's fit on ranges, from its least-squares line.
    range_fit_iterations: int = 5


@dataclass(frozen=True)
class DecimationConfig:
    """Which scans are matched (decimation.py; decision: docs/decisions/scan_matching.md,
    "Matching every n-th scan")."""

    # s between matched scans in batch: a match's error does not shrink with the motion between its scans.
    match_period: float = 0.3
    # s between matched scans in the online calibrator: its guess is its own running estimate.
    online_match_period: float = 0.1
    # scan periods the laser's rate is judged from (every scan is matched until then).
    rate_sample: int = 20


@dataclass(frozen=True)
class SyncConfig:
    """The encoder stream's conditioning and the scans' wait for it (encoder_stream.py,
    sync.py; decision: docs/decisions/slow_odometry.md)."""

    # s: longest interval between two encoder samples still interpolated across; a longer
    # silence starts a new segment (the counter may have wrapped more than once, the robot
    # may have been bumped, a driver restarted). 0.5 s is 10 periods at 20 Hz.
    max_gap: float = 0.5
    # periods: odometry slower than max_gap allows (1-2 Hz bases) has a gap at this many of its median period.
    gap_periods: float = 5.0
    # s: before the period is known (min_period_sample steps), a step up to this long is
    # judged against the steps seen so far, itself included, so that a 1-2 Hz base loses
    # none of its first seconds; a longer first step (a stale first message) is a gap.
    max_first_period: float = 2.0
    # s: a stamp earlier than the newest one by more than this is a clock jump (a bag played
    # in a loop, a clock set back): the history is dropped and a new segment starts. Smaller
    # steps back are single out-of-order samples and are rejected.
    clock_jump_backward: float = 1.0
    # rad/s: an increment larger than max_wheel_speed·dt + jump_margin is not physical (a
    # counter reset, a driver restart): a new segment starts there. 6 m/s on a 0.1 m wheel.
    max_wheel_speed: float = 60.0
    # rad: the margin of that test.
    jump_margin: float = 0.5
    # s of history kept behind the newest sample, so memory stays bounded online; the
    # synchroniser also trims what no pending scan can need.
    max_history: float = 10.0
    # s (scan time) a scan waits for the encoder stream to reach its stamp.
    max_scan_latency: float = 1.0
    # s: the shortest wheel-odometry arc between two synced scans. The odometry model
    # composes one arc per part, exact while the wheel speeds keep their ratio; one arc
    # over a 0.3 s match interval misses the sideways motion of a changing turn rate by
    # v·Δω·Δt²/12, as large as the laser's own sideways error, and shows as structure
    # against the angular acceleration (docs/diagnose.md). Parts end at encoder samples
    # at least this far apart: the sideways error falls as the square of the part's length
    # per part, as its cube per second of driving.
    min_arc: float = 0.05
    # s: samples further apart than this are interpolated on a curve (EncoderStream._curved:
    # the cubic through two samples before and two after the stamp, or the parabola through
    # the one before and the two around it where no second sample follows), not on the
    # line. Closer samples keep the line: there its error is below the slip noise, and the
    # second difference of ticks a few ms apart is mostly quantisation and stamp jitter.
    curved_interval: float = 0.3
    # steps: the stream's own period is the median of its last this many steps between samples...
    period_sample: int = 20
    # steps: ...known once it has seen at least this many (before, max_first_period rules).
    min_period_sample: int = 3
    # × the quadratic estimate (EncoderStream._off_line): the interpolation error's 1σ; the
    # estimate lags a change of acceleration, so the true error is somewhat larger.
    interpolation_sigma_scale: float = 1.2


@dataclass(frozen=True)
class OdometryInputConfig:
    """Wheel rotations implied from a nav_msgs/Odometry topic (odometry_wheels.py)."""

    # m: an increment moving sideways by more than this, across the arc through its ends, is
    # counted: a differential drive's own odometry never does (float rounding is ~1e-12 m),
    # odometry fused with an IMU, a mouse sensor or a localisation does.
    sideways_tolerance: float = 1e-4
    # fraction: the turning in the messages' twist (Σ|ω|·dt) and in their poses (Σ|dθ|) that
    # differ by more than this come from two sources (a fused heading beside wheel
    # velocities); a rolling mean of the wheel speeds, as diff_drive_controller applies,
    # shifts the twist in time but keeps its total.
    twist_mismatch: float = 0.05
    # rad: below this much turning in all, the comparison says nothing.
    min_turning: float = 3.0


@dataclass(frozen=True)
class WheelSidesConfig:
    """A skid-steer's wheels of one side compared (wheel_sides.py)."""

    # rad of the side's rotation over which the spread of its wheels is measured: long
    # enough for the slip noise to average (the simulator's default slip noise spreads two
    # wheels by 0.7 % RMS over 2π), short enough to catch a slipping stretch.
    stretch: float = 2.0 * math.pi
    # %: an RMS spread above this is warned about (4 to 5 times the simulator's default slip
    # noise; a joint of the other side named spreads a side by about 100 % in every turn).
    warn_percent: float = 3.0
    # rad: a step of a wheel between two messages beyond this is a gap or a counter reset,
    # not motion: the stretch restarts (EncoderStream cuts its segment there too).
    max_step: float = 2.0 * math.pi


@dataclass(frozen=True)
class FrontendConfig:
    """The front end's tuning, by part."""

    laser_noise: LaserNoiseConfig = field(default_factory=LaserNoiseConfig)
    reference_lines: ReferenceLinesConfig = field(default_factory=ReferenceLinesConfig)
    pairing: PairingConfig = field(default_factory=PairingConfig)
    refinement: RefinementConfig = field(default_factory=RefinementConfig)
    wall_segments: WallSegmentsConfig = field(default_factory=WallSegmentsConfig)
    decimation: DecimationConfig = field(default_factory=DecimationConfig)
    sync: SyncConfig = field(default_factory=SyncConfig)
    odometry_input: OdometryInputConfig = field(default_factory=OdometryInputConfig)
    wheel_sides: WheelSidesConfig = field(default_factory=WheelSidesConfig)
    # registrations remembered to resolve a match's reference scan to its keyframe (a match
    # refers to the last scan the matcher placed, at most a few empty scans back).
    remembered_registrations: int = 256
