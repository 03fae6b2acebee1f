"""Do the wheel encoders and the laser agree on which way the robot moves?

Swapped wheel joints, or an encoder counting backwards, is no calibration error: the
calibration would absorb it into absurd values (radii −22 %, laser yaw −180°) with small σ.
The scan matcher measures the motion independently of the wheels, so the recording itself
says which wiring is right: each of the eight signed permutations of the two wheels (as
read from JointState) maps the laser's left and right wheel travel onto what the encoders
report, and the one that explains the data best is the wiring.

The comparison is made on two axes, forward travel v and turning d = θ·b/2, each by an
uncentred correlation over the whole recording, so that a recording with few turns still
decides the turning axis as clearly as the forward one. In the (v, d) axes a swap of the
wheels reverses d; both encoders backwards reverse v and d; one encoder backwards exchanges
v and d (the wheels report turning while the laser sees straight travel). The forward
direction of the laser is taken from the nominal laser yaw, which must be within 90° of the
truth; the turning direction needs no calibration at all. The thresholds (WiringConfig) and
the measurements behind them: docs/decisions/wiring.md.
"""
from __future__ import annotations

import math
from itertools import permutations, product

import numpy as np

from sclam_ros.core import se2
from sclam_ros.core.config import WiringConfig
from sclam_ros.core.params import CALIBRATION_KEYS

# (v, d) = (forward travel, turning θ·b/2) of the (left, right) wheel travel.
_TO_AXES = np.array([[0.5, 0.5], [-0.5, 0.5]])


def _wirings():
    """Every signed permutation P of two wheels: encoder slots = P @ true wheel travel."""
    for order, signs in product(permutations(range(2)), product((1.0, -1.0), repeat=2)):
        wiring = np.zeros((2, 2))
        wiring[[0, 1], order] = signs
        yield wiring


def paired_travel(keyframes, calibration):
    """(wheels, laser), each (n, 2): the left and right wheel travel (m) between consecutive
    keyframes as the encoders report it under the nominal radii, and as the laser's motion
    implies it under the nominal wheel base and laser pose."""
    k, mount = np.asarray(calibration[:3], float), np.asarray(calibration[3:], float)
    pairs = [(kf.dphi, kf.laser_motion) for kf in keyframes
             if kf.dphi is not None and kf.laser_motion is not None
             and kf.laser_from == kf.index - 1]
    if not pairs:
        return np.zeros((0, 2)), np.zeros((0, 2))
    dphi = np.array([p[0] for p in pairs], float)
    laser_motion = np.array([p[1] for p in pairs], float)
    wheels = dphi * k[:2]
    # The base's motion u = l ∘ z ∘ l⁻¹ for a laser motion z (the inverse of
    # scan_matching.laser_motion_from_base_motion).
    base = se2.compose(se2.compose(np.broadcast_to(mount, laser_motion.shape), laser_motion),
                       np.broadcast_to(se2.inverse(mount), laser_motion.shape))
    turn = 0.5 * k[2] * base[:, 2]
    laser = np.column_stack([base[:, 0] - turn, base[:, 0] + turn])
    return wheels, laser


def axis_agreement(wheels, laser) -> np.ndarray:
    """M[a, b]: partial correlation of the encoders' axis a with the laser's axis b (a, b ∈
    v, d), both with the part proportional to the laser's other axis taken out: 1 where they
    agree, −1 where one is the other reversed. Taken out because a wrong nominal value makes
    each axis pick up a share of the other (wheel radii that differ turn straight travel into
    turning; a laser offset turns a spin into forward travel) with either sign."""
    w, s = wheels @ _TO_AXES.T, laser @ _TO_AXES.T
    agreement = np.zeros((2, 2))
    for b in range(2):
        other = s[:, 1 - b]
        scale = float(other @ other)

        def without_other(x):
            return x - other * float(x @ other) / scale if scale > 0 else x

        laser_b = without_other(s[:, b])
        for a in range(2):
            wheel_a = without_other(w[:, a])
            norm = math.sqrt(float(wheel_a @ wheel_a) * float(laser_b @ laser_b))
            agreement[a, b] = float(wheel_a @ laser_b) / norm if norm > 0 else 0.0
    return agreement


def _fix(wiring, params) -> dict:
    """The parameters that make the encoders read the wheels the data says they are."""
    joints = (params.left_wheel_joint, params.right_wheel_joint)
    signs = (params.left_encoder_sign, params.right_encoder_sign)
    fix = {}
    for wheel, side in enumerate(("left", "right")):
        slot = int(np.flatnonzero(wiring[:, wheel])[0])
        joint, sign = joints[slot], wiring[slot, wheel] * signs[slot]
        if joint != joints[wheel]:
            fix[f"{side}_wheel_joint"] = joint
        if sign != signs[wheel]:
            fix[f"{side}_encoder_sign"] = int(sign)
    return fix


def _explanation(wiring, params) -> str:
    joints = (params.left_wheel_joint, params.right_wheel_joint)
    parts = []
    if wiring[0, 0] == 0:
        parts.append("the left and right wheel joints are swapped")
    for wheel, side in enumerate(("left", "right")):
        slot = int(np.flatnonzero(wiring[:, wheel])[0])
        if wiring[slot, wheel] < 0:
            parts.append(f"the {side} wheel's encoder ({joints[slot]}) counts backwards")
    fix = _fix(wiring, params)
    return " and ".join(parts) + ": set " + ", ".join(f"{k}: {v}" for k, v in fix.items())


def wiring_problem(keyframes, params, config: WiringConfig = WiringConfig()):
    """None if the encoders move the way the laser sees the robot move; else the reason, one
    line, naming the parameters that fix it. An axis the laser saw the robot move little
    along decides no sign (its correlation is noise)."""
    calibration = [getattr(params, key) for key in CALIBRATION_KEYS]
    wheels, laser = paired_travel(keyframes, calibration)
    if len(wheels) < config.min_pairs:
        return None
    agreement = axis_agreement(wheels, laser)
    travel = np.abs(laser @ _TO_AXES.T).sum(0)
    agreement[:, travel < np.maximum(config.min_axis_share * travel.max(),
                                     config.min_axis_travel)] = 0.0
    scored = []
    for wiring in _wirings():
        on_axes = _TO_AXES @ wiring @ np.linalg.inv(_TO_AXES)  # entries 0 or ±1
        scored.append((float(np.sum(on_axes * agreement)), wiring, on_axes))
    configured = scored[0][0]  # _wirings() starts with the identity
    best = max(score for score, _, _ in scored)
    if best - configured <= config.min_score_gap:
        return None
    candidates = [(wiring, on_axes) for score, wiring, on_axes in scored
                  if score >= best - config.tie]
    on_axes = max(scored, key=lambda item: item[0])[2]
    if on_axes[0, 0]:
        seen = [f"{axis} reversed (correlation {agreement[i, i]:+.2f})"
                for i, axis in enumerate(("forward travel", "turning")) if on_axes[i, i] < 0]
    else:
        seen = [f"forward travel and turning exchanged (correlations {agreement[0, 1]:+.2f}, "
                f"{agreement[1, 0]:+.2f})"]
    checks = []
    if any(on_axes[0, 0] < 0 for _, on_axes in candidates):
        checks.append("laser_yaw 180° off reverses forward travel")
    if any(on_axes[1, 1] < 0 for _, on_axes in candidates):
        checks.append("a laser mounted upside down reverses turning")
    return (
        f"the wheel encoders contradict the laser's motion, {' and '.join(seen)}: "
        + "; or ".join(_explanation(wiring, params) for wiring, _ in candidates)
        + (f" (if the encoders are right, check the laser: {'; '.join(checks)})" if checks else "")
    )
