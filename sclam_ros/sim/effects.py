"""Un-modelled effects the simulator can switch on, all listed in ``EFFECTS``.

Each effect overrides one or more hooks; an ``EffectSet`` chains them. The hooks are
the seams of the simulated truth:

- ``radii(t, r_left, r_right)``   true wheel radii over time (wear, load, a step change)
- ``body_twist(t, v, w)``         true body twist (vx, vy, ω) for a commanded (v, ω):
                                  how the ground answers to the wheels (lateral slip)
- ``encoder_stamp(t)``            header stamp of an encoder sample taken at true time t
- ``scan_time_increment(scan_rate, beams)``  seconds between two beams of one scan
                                  (0: the whole scan is taken at its stamp)
- ``wheel_increments(t, increments, twists)`` the wheel rotations (K, 2) the encoders see
                                  over each control interval, from those of round wheels
                                  rolling without slip (wheel eccentricity, speed-dependent
                                  slip)
- ``slip_noise_scale(positions)`` factor on the slip noise σ per control interval, from
                                  the body position (x, y) at its start (floor noise)

``wheel_eccentricity``, ``speed_dependent_slip`` and ``floor_noise_region`` are *outside*
the model library of sclam_ros.diagnosis.effects on purpose (floor_noise_region is close to the
library's floor_noise, the other two have no counterpart): they test that diagnose
reports what it cannot explain instead of attributing it to a wrong effect.

With no effect every hook is the identity and the encoders agree with the TRUE
kinematics up to the slip noise and the tick quantisation.

Adding an effect: subclass ``Effect``, set ``name``, ``params`` (ordered parameter
names with defaults and units) and ``doc``, override the hooks it needs, and add it to
``EFFECTS``. ``sclam simulate --effect NAME=V1[,V2...]`` (positional, in ``params``
order) or ``--effect NAME=key:value,key:value`` reaches it with no other change.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


class Effect:
    name = ""
    doc = ""
    # (parameter, default, unit); the first one is what ``NAME=VALUE`` sets.
    params: tuple[tuple[str, float, str], ...] = ()

    def __init__(self, **values):
        unknown = set(values) - {p for p, _, _ in self.params}
        if unknown:
            raise ValueError(
                f"effect {self.name}: unknown parameter(s) {sorted(unknown)}; "
                f"known: {[p for p, _, _ in self.params]}"
            )
        for param, default, _ in self.params:
            setattr(self, param, float(values.get(param, default)))

    def describe(self) -> dict:
        """Parameters as recorded in truth.json."""
        return {param: getattr(self, param) for param, _, _ in self.params}

    def for_duration(self, duration: float) -> None:
        """Resolve defaults that depend on the recording's length; reject impossible values."""

    # hooks: identity unless overridden ------------------------------------------------
    def radii(self, t, r_left, r_right):
        return r_left, r_right

    def body_twist(self, t, v, w):
        return v, 0.0 * v, w

    def encoder_stamp(self, t):
        return t

    def scan_time_increment(self, scan_rate: float, beams: int) -> float:
        return 0.0

    def wheel_increments(self, t, increments, twists):
        return increments

    def slip_noise_scale(self, positions):
        return np.ones(len(positions))


class TimeOffset(Effect):
    name = "time_offset"
    doc = "encoder header stamps = true sampling time + offset (laser stamps stay true)"
    params = (("offset", 0.02, "s"),)

    def encoder_stamp(self, t):
        return t + self.offset


class RadiusChangeAt(Effect):
    name = "radius_change_at"
    params = (("time", float("nan"), "s"), ("left", -0.01, "fraction"), ("right", -0.0033, "fraction"),
              ("then_after", float("nan"), "s"), ("then_left", 0.0, "fraction"),
              ("then_right", 0.0, "fraction"))
    doc = (
        "step change of both true wheel radii at a time since the start, as fractions "
        "(e.g. a tyre losing pressure, a load put on the robot); time defaults to mid-run; "
        "optionally a second step then_after s later (then_left, then_right, relative to the "
        "radii after the first)"
    )

    def for_duration(self, duration):
        if np.isnan(self.time):
            self.time = duration / 2.0
        if not 0.0 < self.time < duration:
            raise ValueError(f"radius_change_at: time {self.time} s is not inside the run (0, {duration}) s")

    def radii(self, t, r_left, r_right):
        t = np.asarray(t)
        after = t >= self.time
        second = t >= self.time + self.then_after if np.isfinite(self.then_after) else False
        return (
            r_left * np.where(after, 1.0 + self.left, 1.0) * np.where(second, 1.0 + self.then_left, 1.0),
            r_right * np.where(after, 1.0 + self.right, 1.0) * np.where(second, 1.0 + self.then_right, 1.0),
        )


class RadiusRamp(Effect):
    name = "radius_ramp"
    doc = ("the true wheel radii change linearly by the given fractions over `duration` s from "
           "`time` (default mid-run), then stay (a slowly deflating tyre)")
    params = (("time", float("nan"), "s"), ("duration", 300.0, "s"), ("left", -0.01, "fraction"),
              ("right", -0.01, "fraction"))

    def for_duration(self, duration):
        if np.isnan(self.time):
            self.time = duration / 2.0
        if not 0.0 <= self.time < duration or self.duration <= 0:
            raise ValueError(f"radius_ramp: time {self.time} s / duration {self.duration} s "
                             f"do not fit the run (0, {duration}) s")

    def radii(self, t, r_left, r_right):
        progress = np.clip((np.asarray(t) - self.time) / self.duration, 0.0, 1.0)
        return r_left * (1.0 + self.left * progress), r_right * (1.0 + self.right * progress)


class RadiusDrift(Effect):
    name = "radius_drift"
    doc = "linear drift of the true wheel radii over time (tyre wear, warming up)"
    params = (("left", -0.01, "fraction/hour"), ("right", 0.0, "fraction/hour"))

    def radii(self, t, r_left, r_right):
        hours = np.asarray(t) / 3600.0
        return r_left * (1.0 + self.left * hours), r_right * (1.0 + self.right * hours)


class LateralSlip(Effect):
    name = "lateral_slip"
    doc = (
        "the body skids outwards in turns: vy = -gain·v·ω, unseen by the wheels "
        "(gain in s; 0.05 gives 2.5 cm/s at 0.5 m/s and 1 rad/s)"
    )
    params = (("gain", 0.05, "s"),)

    def body_twist(self, t, v, w):
        return v, -self.gain * v * w, w


class ScanMotion(Effect):
    name = "scan_motion"
    doc = (
        "the laser sweeps its beams over the scan period instead of all at the stamp, "
        "so a moving robot sees a distorted scan; time_increment is written to the "
        "LaserScan as a real driver does"
    )
    params = (("fraction", 1.0, "of the scan period"),)

    def scan_time_increment(self, scan_rate, beams):
        return self.fraction / scan_rate / beams


class WheelEccentricity(Effect):
    name = "wheel_eccentricity"
    doc = (
        "out-of-round (eccentric) wheels: the rolling radius of each wheel is "
        "r·(1 + amplitude·sin(φ + phase)) at wheel angle φ, a periodic odometry error "
        "once per wheel revolution (amplitude as a fraction of r)"
    )
    params = (("amplitude", 0.02, "fraction"), ("phase_left", 0.0, "rad"),
              ("phase_right", 1.0, "rad"))

    def wheel_increments(self, t, increments, twists):
        # Ground distance r(φ)·dφ fixed: dφ = dφ₀ / (1 + a·sin(φ + phase)), integrated
        # interval by interval (φ from the start of the run: the encoders' zero is arbitrary).
        out = np.empty_like(increments)
        phi = np.zeros(2)
        phase = np.array([self.phase_left, self.phase_right])
        for k, d in enumerate(increments):
            out[k] = d / (1.0 + self.amplitude * np.sin(phi + phase))
            phi = phi + out[k]
        return out


class SpeedDependentSlip(Effect):
    name = "speed_dependent_slip"
    doc = (
        "longitudinal wheel slip growing with speed: each wheel turns (1 + gain·u²) times "
        "what rolling needs at surface speed u (gain in s²/m²; 0.1 gives 3.6 % at 0.6 m/s)"
    )
    params = (("gain", 0.1, "s²/m²"),)

    def wheel_increments(self, t, increments, twists):
        # Surface speed of each wheel from the rolling increments is not known here (the
        # radii are), so use the body speed: u = |vx| for both wheels.
        u = np.abs(np.asarray(twists)[:, 0])
        return increments * (1.0 + self.gain * u**2)[:, None]


class FloorNoiseRegion(Effect):
    name = "floor_noise_region"
    doc = (
        "a rough floor: the wheels' slip noise σ is multiplied by `factor` where x > x_min "
        "(map frame, m)"
    )
    params = (("factor", 4.0, "ratio of σ"), ("x_min", 0.0, "m"))

    def slip_noise_scale(self, positions):
        return np.where(np.asarray(positions)[:, 0] > self.x_min, self.factor, 1.0)


class FloorNoiseArea(Effect):
    name = "floor_noise_area"
    doc = (
        "a rough floor inside a rectangle of the map (one room's carpet): an extra, "
        "independent slip noise of σ `extra` (same unit as the recording's slip noise "
        "`base`: fraction of a revolution after one revolution) on both wheels while the "
        "robot is inside x_min..x_max, y_min..y_max (map frame, m)"
    )
    params = (("extra", 0.006, "fraction of a revolution after one revolution"),
              ("x_min", 0.0, "m"), ("x_max", 7.0, "m"), ("y_min", 0.0, "m"), ("y_max", 6.5, "m"),
              ("base", 0.005, "fraction of a revolution after one revolution"))

    def variance_ratio(self) -> float:
        """Slip-noise variance inside over outside: independent noises add variances."""
        return 1.0 + (self.extra / self.base) ** 2

    def inside(self, positions):
        p = np.asarray(positions, float)
        return ((p[..., 0] >= self.x_min) & (p[..., 0] <= self.x_max)
                & (p[..., 1] >= self.y_min) & (p[..., 1] <= self.y_max))

    def slip_noise_scale(self, positions):
        return np.where(self.inside(positions), np.sqrt(self.variance_ratio()), 1.0)


class SpeedDependentRadius(Effect):
    name = "speed_dependent_radius"
    doc = (
        "the wheels' rolling radius grows with the robot's speed v (tyres expanding when "
        "driven fast): r·(1 + gain·v²), the same factor on both wheels (gain in s²/m²; 0.1 "
        "gives 3.6 % at 0.6 m/s). Unlike speed_dependent_slip the wheels turn less, and the "
        "error scales the whole motion, turns included"
    )
    params = (("gain", 0.1, "s²/m²"),)

    def wheel_increments(self, t, increments, twists):
        # Ground distance fixed: a larger radius turns the wheel less.
        v = np.asarray(twists)[:, 0]
        return increments / (1.0 + self.gain * v**2)[:, None]

EFFECTS: dict[str, type[Effect]] = {
    cls.name: cls for cls in (TimeOffset, RadiusChangeAt, RadiusRamp, RadiusDrift, LateralSlip, ScanMotion,
                              WheelEccentricity, SpeedDependentSlip, FloorNoiseRegion,
                              FloorNoiseArea, SpeedDependentRadius)
}


def make_effect(name: str, value=None) -> Effect:
    """An effect from its name and a value: None (defaults), a number (the first
    parameter), a sequence (positional), a dict, or a CLI string ``V1,V2`` /
    ``key:value,key:value``."""
    if name not in EFFECTS:
        raise ValueError(f"unknown effect {name!r}; known: {', '.join(sorted(EFFECTS))}")
    cls = EFFECTS[name]
    names = [p for p, _, _ in cls.params]
    if value is None:
        return cls()
    if isinstance(value, dict):
        return cls(**value)
    if isinstance(value, str):
        items = [item.strip() for item in value.split(",") if item.strip()]
        if all(":" in item for item in items):
            return cls(**{k.strip(): float(v) for k, v in (item.split(":", 1) for item in items)})
        value = [float(item) for item in items]
    if np.ndim(value) == 0:
        value = [value]
    if len(value) > len(names):
        raise ValueError(f"effect {name} takes at most {len(names)} values ({', '.join(names)})")
    return cls(**dict(zip(names, (float(v) for v in value))))


@dataclass
class EffectSet:
    """The effects of one simulation, chained in the given order."""

    effects: tuple[Effect, ...] = ()

    @classmethod
    def from_spec(cls, spec) -> "EffectSet":
        """From None, a dict name -> value, or a list of names / (name, value) / Effect."""
        if spec is None:
            return cls()
        if isinstance(spec, EffectSet):
            return spec
        items = spec.items() if isinstance(spec, dict) else spec
        effects = []
        for item in items:
            if isinstance(item, Effect):
                effects.append(item)
            elif isinstance(item, str):
                effects.append(make_effect(item))
            else:
                effects.append(make_effect(*item))
        names = [e.name for e in effects]
        if len(set(names)) != len(names):
            raise ValueError(f"effect given twice: {names}")
        return cls(tuple(effects))

    def describe(self) -> dict:
        return {e.name: e.describe() for e in self.effects}

    def for_duration(self, duration: float) -> "EffectSet":
        for effect in self.effects:
            effect.for_duration(duration)
        return self

    def radii(self, t, r_left, r_right):
        for effect in self.effects:
            r_left, r_right = effect.radii(t, r_left, r_right)
        return r_left, r_right

    def body_twist(self, t, v, w):
        vy_total = 0.0
        for effect in self.effects:
            v, vy, w = effect.body_twist(t, v, w)
            vy_total = vy_total + vy
        return v, vy_total, w

    def encoder_stamp(self, t):
        for effect in self.effects:
            t = effect.encoder_stamp(t)
        return t

    def scan_time_increment(self, scan_rate, beams) -> float:
        return sum(e.scan_time_increment(scan_rate, beams) for e in self.effects)

    def wheel_increments(self, t, increments, twists):
        for effect in self.effects:
            increments = effect.wheel_increments(t, increments, twists)
        return increments

    def slip_noise_scale(self, positions):
        scale = np.ones(len(positions))
        for effect in self.effects:
            scale = scale * effect.slip_noise_scale(positions)
        return scale
