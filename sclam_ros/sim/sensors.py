"""Sensor models: wheel encoders and a 2D laser scanner, sampled on the true trajectory."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sclam_ros.core import se2
from sclam_ros.core.inputs import Scan
from sclam_ros.sim.motion import Trajectory, TrueKinematics
from sclam_ros.sim.world import World, cast_rays

# Default slip noise: a random walk on each wheel angle, σ = 0.5 % of one revolution
# after one revolution (σ grows with sqrt(angle turned)), in rad/sqrt(rad).
DEFAULT_SLIP_NOISE = 0.005 * np.sqrt(2.0 * np.pi)


@dataclass
class EncoderSamples:
    times: np.ndarray  # (J,) s, true sampling times (relative)
    ticks: np.ndarray  # (J, 2n) cumulative ticks (n left wheels, n right), integer-valued floats
    true_angles: np.ndarray  # (J, 2n) rad, wheel angles without slip noise or quantisation

    def side_ticks(self) -> np.ndarray:
        """(J, 2) ticks per side (left, right): the mean of its wheels'."""
        return self.ticks.reshape(len(self.ticks), 2, -1).mean(axis=2)


def encoder_samples(trajectory: Trajectory, kinematics: TrueKinematics, rate: float,
                    ticks_per_revolution: float, rng: np.random.Generator,
                    slip_noise: float = DEFAULT_SLIP_NOISE, wheels_per_side: int = 1) -> EncoderSamples:
    """Quantised cumulative ticks at ``rate`` Hz, from the true kinematics plus slip noise.

    Counters start at a random count, as a real robot's do after a while powered on.
    All wheels count up when driving forward. ``wheels_per_side``: the wheels of a side turn
    alike (a skid-steer's chained or equally driven wheels), each with its own slip noise,
    quantisation and counter.
    """
    increments = np.repeat(kinematics.wheel_angle_increments(trajectory), wheels_per_side, axis=1)
    # Slip: each interval's rotation gets noise with variance ∝ the angle turned.
    slip = rng.standard_normal(increments.shape) * slip_noise * np.sqrt(np.abs(increments))
    slip *= kinematics.effects.slip_noise_scale(trajectory.poses[:-1, :2])[:, None]
    wheels = increments.shape[1]
    true_knots = np.vstack([np.zeros(wheels), np.cumsum(increments, axis=0)])
    measured_knots = np.vstack([np.zeros(wheels), np.cumsum(increments + slip, axis=0)])
    times = np.arange(int(np.floor(trajectory.duration * rate + 1e-9)) + 1) / rate
    knot_times = trajectory.knot_times
    # Rotation is linear within an interval (constant twist), so interpolation is exact.
    true_angles = np.stack([np.interp(times, knot_times, true_knots[:, i]) for i in range(wheels)], -1)
    measured = np.stack([np.interp(times, knot_times, measured_knots[:, i]) for i in range(wheels)], -1)
    start_ticks = rng.integers(0, 100_000, size=wheels) + rng.random(wheels)
    ticks = np.floor(start_ticks + measured * ticks_per_revolution / (2.0 * np.pi))
    return EncoderSamples(times, ticks, true_angles)


@dataclass
class LaserModel:
    """A 2D laser scanner as robots carry them (the defaults: a 360° indoor laser).

    Beams cover ``fov`` centred on the laser's x axis: a full circle without a duplicated
    beam, or from −fov/2 to +fov/2 inclusive. Range noise is Gaussian with
    σ = ``range_noise`` + ``range_noise_per_m``·range (the second for lasers whose spec is a
    percentage of range). ``dropout``: probability that a beam with a target reports no
    return. ``mixed_pixels``: probability that a beam at a depth edge (neighbours more than
    MIXED_PIXEL_EDGE apart) returns a point between the two surfaces, as a real laser whose
    spot straddles the edge does.
    """

    beams: int = 360
    range_min: float = 0.05  # m
    range_max: float = 20.0  # m
    range_noise: float = 0.01  # m, 1σ Gaussian
    frame_id: str = "laser"
    fov: float = 2.0 * np.pi  # rad
    range_noise_per_m: float = 0.0  # 1σ per m of range
    dropout: float = 0.0  # probability per beam
    mixed_pixels: float = 0.0  # probability per beam at a depth edge
    # m: reported ranges are multiples of this (0: continuous). Real drivers round: a SICK
    # LMS in its cm mode to 1 cm, the Freiburg benchmark logs to about 2.5 cm.
    range_resolution: float = 0.0

    def __post_init__(self):
        if not 0.0 < self.fov <= 2.0 * np.pi + 1e-12:
            raise ValueError(f"field of view must be in (0, 360] deg, got {np.degrees(self.fov):g}")
        if self.beams < 2 or not 0.0 < self.range_min < self.range_max:
            raise ValueError(f"laser needs >= 2 beams and 0 < range_min < range_max, got "
                             f"{self.beams}, {self.range_min}, {self.range_max}")
        for name in ("dropout", "mixed_pixels"):
            if not 0.0 <= getattr(self, name) < 1.0:
                raise ValueError(f"{name} is a probability in [0, 1), got {getattr(self, name)}")
        if not 0.0 <= self.range_resolution < self.range_max:
            raise ValueError(f"range_resolution must be in [0, range_max), got {self.range_resolution}")

    @property
    def full_circle(self) -> bool:
        return self.fov >= 2.0 * np.pi - 1e-9

    @property
    def angle_min(self) -> float:
        return -np.pi if self.full_circle else -self.fov / 2.0

    @property
    def angle_increment(self) -> float:
        return self.fov / (self.beams if self.full_circle else self.beams - 1)

    def angles(self) -> np.ndarray:
        return self.angle_min + self.angle_increment * np.arange(self.beams)

    def measure(self, true_ranges: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """What the scanner reports for rows of true ranges (inf: nothing within range_max)."""
        ranges = np.array(true_ranges, float)
        if self.mixed_pixels > 0.0:
            _mix_edges(ranges, self.mixed_pixels, rng)
        hit = np.isfinite(ranges)
        sigma = self.range_noise + self.range_noise_per_m * ranges[hit]
        ranges[hit] += sigma * rng.standard_normal(int(hit.sum()))
        if self.range_resolution > 0.0:
            ranges[hit] = np.round(ranges[hit] / self.range_resolution) * self.range_resolution
        if self.dropout > 0.0:
            ranges[hit & (rng.random(ranges.shape) < self.dropout)] = np.inf
        # A noisy reading still inside the limits; a real driver reports nothing otherwise.
        ranges[np.isfinite(ranges) & ((ranges < self.range_min) | (ranges > self.range_max))] = np.inf
        return ranges


MIXED_PIXEL_EDGE = 0.3  # m: a jump between neighbouring beams larger than this is a depth edge


def _mix_edges(ranges: np.ndarray, probability: float, rng: np.random.Generator) -> None:
    """In place: at depth edges, a beam returns a point between its range and its
    neighbour's (uniformly), with ``probability`` per edge beam."""
    near, far = ranges[..., :-1], ranges[..., 1:]
    both = np.isfinite(near) & np.isfinite(far)
    with np.errstate(invalid="ignore"):
        edge = both & (np.abs(far - near) > MIXED_PIXEL_EDGE)
    mixed = edge & (rng.random(edge.shape) < probability)
    fraction = rng.random(int(mixed.sum()))
    near[mixed] = near[mixed] + fraction * (far[mixed] - near[mixed])


def laser_scans(world: World, trajectory: Trajectory, mount_xyth, times, model: LaserModel,
                rng: np.random.Generator, time_increment: float = 0.0, stamp_offset: float = 0.0,
                chunk: int = 200, progress=None) -> list[Scan]:
    """Scans at ``times`` (relative s) from the true laser pose = robot pose ⊕ mount.

    With ``time_increment`` > 0 beam j is taken at time + j·time_increment, each from
    where the laser is then (motion distortion); otherwise all at the stamp. The
    scans' stamps are ``times + stamp_offset`` (e.g. the recording's start epoch).
    """
    mount = np.asarray(mount_xyth, float)
    angles = model.angles()
    beam_offsets = time_increment * np.arange(model.beams)
    scans: list[Scan] = []
    times = np.asarray(times, float)
    for start in range(0, len(times), chunk):
        stamps = times[start:start + chunk]
        beam_times = stamps[:, None] + beam_offsets[None, :]  # (n, beams)
        if time_increment > 0.0:
            laser = se2.compose(trajectory.pose_at(beam_times), mount)  # (n, beams, 3)
        else:
            laser = np.broadcast_to(
                se2.compose(trajectory.pose_at(stamps), mount)[:, None, :], beam_times.shape + (3,)
            )
        ranges = cast_rays(
            world.segments, laser[..., :2].reshape(-1, 2), (laser[..., 2] + angles).reshape(-1),
            model.range_max,
        ).reshape(beam_times.shape)
        ranges = model.measure(ranges, rng)
        for stamp, row in zip(stamps, ranges):
            scans.append(Scan(float(stamp + stamp_offset), row, model.angle_min, model.angle_increment,
                              model.range_min, model.range_max, time_increment, model.frame_id))
        if progress is not None:
            progress(len(scans), len(times))
    return scans
