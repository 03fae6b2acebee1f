"""How far a skid-steer's wheels of one side disagree.

A side's position is the mean of its wheels' (io/messages.side_position): the calibration
sees one wheel per side. Its wheels turn alike when they are chained or driven alike and
grip; they drift apart when one slips more than the others, and at once when a joint of the
wrong side (or of another wheel altogether) is named. The spread is measured over stretches
of the side's rotation (WheelSidesConfig.stretch): the largest minus the smallest of the
wheels' rotations over the stretch, as a fraction of the side's. Its RMS over the stretches
is reported per side, and warned about above WheelSidesConfig.warn_percent.
"""
from __future__ import annotations

import math
from typing import Optional

import numpy as np

from sclam_ros.frontend.config import WheelSidesConfig

SIDES = ("left", "right")


class SideDisagreement:
    """Raw wheel positions per side in (io/messages.joint_state_wheels), spread statistics out."""

    def __init__(self, params, config: Optional[WheelSidesConfig] = None):
        self.config = config or WheelSidesConfig()
        self.joints = params.wheel_joints()
        self.wrap = float(params.encoder_wrap)
        ticks = float(params.ticks_per_revolution)
        self.rad_per_unit = 2.0 * math.pi / ticks if ticks > 0 else 1.0
        self._last = None  # (left, right) raw positions of the previous message
        self._rotation = [np.zeros(len(j)) for j in self.joints]  # rad per wheel, this stretch
        self.spreads = ([], [])  # per side: spread / rotation of each completed stretch

    @property
    def compared(self) -> bool:
        """The sides have several wheels to compare (one wheel a side has nothing to spread)."""
        return len(self.joints[0]) >= 2

    def add(self, left, right) -> None:
        if not self.compared:
            return
        now = (np.asarray(left, float), np.asarray(right, float))
        if self._last is not None:
            for side, (position, before) in enumerate(zip(now, self._last)):
                self._add_step(side, position - before)
        self._last = now

    def _add_step(self, side: int, step) -> None:
        if self.wrap > 0:
            step = (step + 0.5 * self.wrap) % self.wrap - 0.5 * self.wrap
        step = step * self.rad_per_unit
        if np.max(np.abs(step)) > self.config.max_step:
            self._rotation[side][:] = 0.0  # a gap or a reset: this stretch says nothing
            return
        self._rotation[side] += step
        turned = abs(float(self._rotation[side].mean()))
        if turned >= self.config.stretch:
            rotation = self._rotation[side]
            self.spreads[side].append(float(rotation.max() - rotation.min()) / turned)
            self._rotation[side] = np.zeros_like(rotation)

    def summary(self) -> Optional[dict]:
        """{side: {joints, rms_percent, stretches, over}} for a skid-steer (None for one wheel
        a side): ``rms_percent`` the RMS spread over ``stretches`` stretches (None if none
        was completed), ``over`` how many of them spread more than warn_percent."""
        if not self.compared:
            return None
        out = {}
        for name, joints, spreads in zip(SIDES, self.joints, self.spreads):
            percent = 100.0 * np.asarray(spreads)
            out[name] = {
                "joints": list(joints),
                "rms_percent": float(np.sqrt(np.mean(percent**2))) if len(percent) else None,
                "stretches": len(percent),
                "over": int(np.sum(percent > self.config.warn_percent)),
            }
        return out

    def warnings(self) -> list:
        """One line per side whose wheels disagree by more than warn_percent RMS."""
        lines = []
        for name, side in (self.summary() or {}).items():
            if side["rms_percent"] is not None and side["rms_percent"] > self.config.warn_percent:
                lines.append(
                    f"the {name} wheels ({', '.join(side['joints'])}) disagree by "
                    f"{side['rms_percent']:.1f} % RMS of their rotation over "
                    f"{self.config.stretch:.2g} rad stretches ({side['over']} of "
                    f"{side['stretches']} over {self.config.warn_percent:g} %): a wheel "
                    f"slipping, or a joint in {name}_wheel_joints that is not a {name} wheel; "
                    "the side's mean is calibrated")
        return lines
