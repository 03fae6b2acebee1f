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
    ticks: np.ndarray  # (J, 2) cumulative ticks (left, right), integer-valued floats
    true_angles: np.ndarray  # (J, 2) rad, wheel angles without slip noise or quantisation


def encoder_samples(trajectory: Trajectory, kinematics: TrueKinematics, rate: float,
                    ticks_per_revolution: float, rng: np.random.Generator,
                    slip_noise: float = DEFAULT_SLIP_NOISE) -> EncoderSamples:
    """Quantised cumulative ticks at ``rate`` Hz, from the true kinematics plus slip noise.

    Counters start at a random count, as a real robot's do after a while powered on.
    Both wheels count up when driving forward.
    """
    increments = kinematics.wheel_angle_increments(trajectory)
    # Slip: each interval's rotation gets noise with variance ∝ the angle turned.
    slip = rng.standard_normal(increments.shape) * slip_noise * np.sqrt(np.abs(increments))
    slip *= kinematics.effects.slip_noise_scale(trajectory.poses[:-1, :2])[:, None]
    true_knots = np.vstack([np.zeros(2), np.cumsum(increments, axis=0)])
    measured_knots = np.vstack([np.zeros(2), np.cumsum(increments + slip, axis=0)])
    times = np.arange(int(np.floor(trajectory.duration * rate + 1e-9)) + 1) / rate
    knot_times = trajectory.knot_times
    # Rotation is linear within an interval (constant twist), so interpolation is exact.
    true_angles = np.stack([np.interp(times, knot_times, true_knots[:, i]) for i in range(2)], -1)
    measured = np.stack([np.interp(times, knot_times, measured_knots[:, i]) for i in range(2)], -1)
    start_ticks = rng.integers(0, 100_000, size=2) + rng.random(2)
    ticks = np.floor(start_ticks + measured * ticks_per_revolution / (2.0 * np.pi))
    return EncoderSamples(times, ticks, true_angles)


@dataclass
class LaserModel:
    beams: int = 360
    range_min: float = 0.05  # m
    range_max: float = 20.0  # m
    range_noise: float = 0.01  # m, 1σ Gaussian
    frame_id: str = "laser"

    @property
    def angle_min(self) -> float:
        return -np.pi

    @property
    def angle_increment(self) -> float:
        return 2.0 * np.pi / self.beams

    def angles(self) -> np.ndarray:
        return self.angle_min + self.angle_increment * np.arange(self.beams)


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
        hit = np.isfinite(ranges)
        ranges[hit] += model.range_noise * rng.standard_normal(int(hit.sum()))
        # A noisy reading still inside the limits; a real driver reports nothing otherwise.
        ranges[hit & ((ranges < model.range_min) | (ranges > model.range_max))] = np.inf
        for stamp, row in zip(stamps, ranges):
            scans.append(Scan(float(stamp + stamp_offset), row, model.angle_min, model.angle_increment,
                              model.range_min, model.range_max, time_increment, model.frame_id))
        if progress is not None:
            progress(len(scans), len(times))
    return scans
