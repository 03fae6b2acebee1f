"""Candidate explanations of residual structure, per odometry edge.

Each regressor is a group of one or more columns: a cause that needs two numbers to be
written linearly (a position on the map, a heading, a wheel's angle with unknown phase)
is one group, so that it competes with the one-column causes as one explanation.
"""
from __future__ import annotations

import numpy as np

from sclam_ros.core import kinematics, se2


def _gradient(values, times):
    out = np.zeros_like(values)
    if len(values) > 2:
        order = np.argsort(times)
        out[order] = np.gradient(values[order], times[order])
    return out


def pose_motion(inputs, poses) -> np.ndarray:
    """(m_o, 3) each odometry edge's motion (x, y, θ in the frame of its first pose) as the
    graph's poses have it."""
    return se2.between(poses[inputs.odo_from + 1], poses[inputs.odo_from])


def arc_length(motion) -> np.ndarray:
    """(m,) signed length of the arc through each motion's chord (x, y, θ)."""
    chord = np.hypot(motion[:, 0], motion[:, 1]) * np.sign(motion[:, 0])
    return chord / np.sinc(motion[:, 2] / (2 * np.pi))  # chord = arc · sin(θ/2) / (θ/2)


def regressors(inputs, data, wheel_angles, k, poses, motion=None) -> dict:
    """name -> (m_o, c) array over the odometry edges (c columns of one explanation).

    motion: (m_o, 3) the edges' motion the speeds and turn rates are taken from (default:
    the wheels'). A residual tested against a regressor must not share its noise: the
    odometry residual is the poses' motion minus the wheels', so against the wheels' own
    turn rate it correlates on a straight drive, where that turn rate is the wheels' noise
    alone. The structure tests take the poses' motion (pose_motion), which the laser
    determines several times more precisely than the wheels."""
    i, j = inputs.odo_from, inputs.odo_from + 1
    t = data.stamps
    dt = np.maximum(t[j] - t[i], 1e-3)
    mid = 0.5 * (t[i] + t[j])
    if motion is None:
        s, theta = kinematics.arc_length_and_rotation(inputs.odo_dphi, k)
        body_w = kinematics.arc_length_and_rotation(data.wheel_speeds, k)[1]  # at each pose
    else:
        s, theta = arc_length(motion), motion[:, 2]
        body_w = np.interp(t, mid, theta / dt)  # the same motion's turn rate at each pose
    v, w = s / dt, theta / dt
    pos = 0.5 * (poses[i, :2] + poses[j, :2])
    heading = poses[i, 2] + 0.5 * theta
    groups = {
        "v": v,
        "abs_v": np.abs(v),
        # Signed square: a forward error growing with speed keeps the sign of travel.
        "v_squared": v * np.abs(v),
        "omega": w,
        "abs_omega": np.abs(w),
        "v_times_omega": v * w,
        "acceleration": _gradient(v, mid),
        "angular_acceleration": _gradient(w, mid),
        "wheel_speed_change": body_w[j] - body_w[i],  # what an encoder/laser clock offset scales
        "time": mid - t[0],
        "distance": np.cumsum(np.abs(s)),
        "heading": np.column_stack([np.cos(heading), np.sin(heading)]),
        "position": pos,
    }
    # A radius varying once per wheel revolution, r·(1 + a·sin(φ + c)), changes an edge's
    # wheel rotation by ≈ a·(cos(φ_j + c) − cos(φ_i + c)): a combination of the sine and
    # cosine differences, whatever the (unknown) phase c.
    for side, c in (("left", 0), ("right", 1)):
        groups[f"wheel_angle_{side}"] = np.column_stack([
            np.sin(wheel_angles[j, c]) - np.sin(wheel_angles[i, c]),
            np.cos(wheel_angles[j, c]) - np.cos(wheel_angles[i, c])])
    return {name: np.asarray(x, float).reshape(len(v), -1) for name, x in groups.items()}

