"""The true motion: body twists held constant between control knots, integrated exactly.

The robot's controller updates its command at a fixed rate; between two updates the
body twist (vx, vy, ω) is constant, so the motion over an interval is the SE(2)
exponential of that twist and the wheel angles grow linearly. Poses and wheel angles
are therefore exact at any time (no integration step to choose, no discretisation
error for the encoders to disagree with).

``TrueKinematics`` is the pluggable wheel <-> motion mapping of the simulated robot:
the true radii and base plus the effects (see ``effects.py``) that bend it.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from sclam_ros.core import se2
from sclam_ros.sim.effects import EffectSet


def twist_increment(vx, vy, w, dt):
    """Motion (dx, dy, dθ), in the start frame, of a body holding twist (vx, vy, ω) for dt.

    The SE(2) exponential; series expansions near ω·dt = 0 keep it exact to rounding.
    Broadcasts over arrays.
    """
    vx, vy, w, dt = (np.asarray(a, float) for a in (vx, vy, w, dt))
    th = w * dt
    small = np.abs(th) < 1e-4
    th_safe = np.where(small, 1.0, th)
    # sin(θ)/θ and (1 − cos θ)/θ, with their Taylor series where θ is tiny.
    sinc = np.where(small, 1.0 - th**2 / 6.0, np.sin(th_safe) / th_safe)
    cosc = np.where(small, th / 2.0 - th**3 / 24.0, (1.0 - np.cos(th_safe)) / th_safe)
    dx = (vx * sinc - vy * cosc) * dt
    dy = (vx * cosc + vy * sinc) * dt
    return np.stack(np.broadcast_arrays(dx, dy, th), -1)


@dataclass
class Trajectory:
    """The true trajectory: knots every ``dt`` seconds from t = 0 (relative time).

    poses (K+1, 3) at knots, θ unwrapped (so turns can be counted); twists (K, 3) the
    true body twist (vx, vy, ω) held over each interval; commands (K, 2) the
    controller's (v, ω).
    """

    dt: float
    poses: np.ndarray
    twists: np.ndarray
    commands: np.ndarray

    @property
    def duration(self) -> float:
        return self.dt * len(self.twists)

    @property
    def knot_times(self) -> np.ndarray:
        return self.dt * np.arange(len(self.poses))

    def _interval(self, t):
        t = np.asarray(t, float)
        if np.any(t < -1e-9) or np.any(t > self.duration + 1e-9):
            raise ValueError(f"time outside the trajectory [0, {self.duration}] s")
        k = np.clip(np.floor(t / self.dt).astype(int), 0, len(self.twists) - 1)
        return k, t - k * self.dt

    def pose_at(self, t, unwrapped: bool = False) -> np.ndarray:
        """True pose(s) at time(s) t, exact."""
        k, tau = self._interval(t)
        tw = self.twists[k]
        step = twist_increment(tw[..., 0], tw[..., 1], tw[..., 2], tau)
        start = self.poses[k]
        pose = np.concatenate(
            [start[..., :2] + se2.rotate(start[..., 2], step[..., :2]), (start[..., 2] + step[..., 2])[..., None]],
            -1,
        )
        if not unwrapped:
            pose[..., 2] = se2.wrap_angle(pose[..., 2])
        return pose

    def twist_at(self, t) -> np.ndarray:
        """True body twist (vx, vy, ω) at time(s) t."""
        k, _ = self._interval(t)
        return self.twists[k]


@dataclass
class TrueKinematics:
    """The simulated robot's real wheels and how they move the body.

    A skid-steer (``track_widening`` χ > 1) follows the kinematic model of the instantaneous
    centres of rotation (ICR) of its tracks (Martínez et al. 2005, Mandow et al. 2007): its
    side contact lines are ``wheel_base`` (B) apart, but in a turn the wheels slip sideways
    and each side turns about its own ICR at ±χ·B/2 instead of ±B/2. With side speeds
    v_l, v_r (wheel rate × radius, all wheels of a side alike): v = (v_r + v_l)/2,
    ω = (v_r − v_l)/(χ·B), and no sideways body motion (the body's ICR on its y axis: mass
    centred over the wheels). That is a differential drive with the effective wheel base
    χ·B, which is what the calibration is compared with.
    """

    wheel_radius_left: float
    wheel_radius_right: float
    wheel_base: float
    effects: EffectSet = field(default_factory=EffectSet)
    track_widening: float = 1.0  # χ: the sides' ICRs at ±χ·wheel_base/2

    @property
    def effective_wheel_base(self) -> float:
        return self.track_widening * self.wheel_base

    def body_twist(self, t, v, w):
        """True body twist for the controller's (v, ω); effects such as slip enter here."""
        return self.effects.body_twist(t, v, w)

    def radii(self, t):
        return self.effects.radii(t, self.wheel_radius_left, self.wheel_radius_right)

    def wheel_angle_increments(self, trajectory: Trajectory) -> np.ndarray:
        """(K, 2) left/right wheel rotation over each interval, in radians.

        The wheels roll on their contact points: surface speeds vx ∓ ω·b/2 with b the
        effective wheel base (lateral slip vy is not seen by them). Radii are taken at the interval's midpoint, which
        is exact for steps aligned to knots and second-order for smooth drifts.
        """
        mid = trajectory.knot_times[:-1] + trajectory.dt / 2.0
        r_left, r_right = self.radii(mid)
        vx, w = trajectory.twists[:, 0], trajectory.twists[:, 2]
        half_base = self.effective_wheel_base / 2.0
        left = (vx - w * half_base) / r_left * trajectory.dt
        right = (vx + w * half_base) / r_right * trajectory.dt
        return self.effects.wheel_increments(mid, np.stack([left, right], -1), trajectory.twists)
