"""Differential-drive forward kinematics K(u, k) and its Jacobians.

u = (dφ_l, dφ_r): wheel angle increments over one interval (rad). Using increments rather
than speeds makes the model independent of the interval length: with constant wheel speeds
over the interval, v·dt = (dφ_r r_r + dφ_l r_l)/2 and ω·dt = (dφ_r r_r − dφ_l r_l)/b.

k = (r_l, r_r, b): wheel radii and wheel base (m).

The motion is integrated exactly along the arc around the instantaneous centre of
curvature: for a travelled arc length s and heading change θ,

    K = (s·sin θ/θ,  s·(1 − cos θ)/θ,  θ),

with a Taylor series near θ = 0 so the straight-line limit is smooth and exact to
double precision.
"""
from __future__ import annotations

import math

import numpy as np

# Below this |θ| the closed forms lose digits to cancellation; the series are exact to
# ~1e-17 there (next terms are θ⁶/5040 and θ⁵/720).
_SMALL_ANGLE = 1e-3


def _series(theta, t2):
    """f1 = sin θ/θ, f2 = (1−cos θ)/θ, df1, df2 as series in θ (t2 = θ²): for |θ| < _SMALL_ANGLE."""
    return 1.0 - t2 / 6.0 + t2 * t2 / 120.0, theta / 2.0 - theta * t2 / 24.0, \
        -theta / 3.0 + theta * t2 / 30.0, 0.5 - t2 / 8.0


def _closed(t, s, c):
    """f1, f2, df1, df2 in closed form at θ = t, s = sin θ, c = cos θ."""
    return s / t, (1.0 - c) / t, (t * c - s) / (t * t), (t * s - (1.0 - c)) / (t * t)


def _arc_factors(theta):
    """f1 = sin θ/θ, f2 = (1−cos θ)/θ and their derivatives, stable near 0."""
    theta = np.asarray(theta, float)
    small = np.abs(theta) < _SMALL_ANGLE
    t = np.where(small, 1.0, theta)  # avoid 0/0 in the branch that is not used
    series = _series(theta, theta * theta)
    closed = _closed(t, np.sin(t), np.cos(t))
    return tuple(np.where(small, a, b) for a, b in zip(series, closed))


def arc_length_and_rotation(dphi, k):
    """Arc length s and heading change θ for increments dphi (..., 2) and k (3,) or (..., 3)."""
    dphi = np.asarray(dphi, float)
    k = np.asarray(k, float)
    left = dphi[..., 0] * k[..., 0]
    right = dphi[..., 1] * k[..., 1]
    return 0.5 * (right + left), (right - left) / k[..., 2]


def forward(dphi, k):
    """K(u, k): the motion (dx, dy, dθ) in the frame of the start pose, shape (..., 3)."""
    s, theta = arc_length_and_rotation(dphi, k)
    f1, f2, _, _ = _arc_factors(theta)
    return np.stack([s * f1, s * f2, theta], -1)


def inverse(motion, k):
    """The wheel increments that make each motion (dx, dy, dθ) (..., 3), in the frame of its
    start pose, along the arc through both ends: (dphi (..., 2), across (...)), where
    ``across`` (m) is the part of the motion perpendicular to that arc, which no pair of wheel
    rotations makes (0 for a differential drive's own odometry).

    An arc of heading change θ leaves along a chord leaning θ/2 from the start heading, of
    length c = 2·s·sin(θ/2)/θ, so s = c_along·(θ/2)/sin(θ/2); its sign is that of the
    forward part of the chord. Then dφ_l = (s − b·θ/2)/r_l, dφ_r = (s + b·θ/2)/r_r.
    """
    motion = np.asarray(motion, float)
    k = np.asarray(k, float)
    dx, dy, theta = motion[..., 0], motion[..., 1], motion[..., 2]
    half = theta / 2
    c, s = np.cos(half), np.sin(half)
    along, across = c * dx + s * dy, -s * dx + c * dy
    small = np.abs(half) < _SMALL_ANGLE
    safe = np.where(small, 1.0, half)
    # (θ/2)/sin(θ/2) = 1 + (θ/2)²/6 + 7(θ/2)⁴/360 near 0.
    h2 = half * half
    arc = along * np.where(small, 1.0 + h2 / 6.0 + 7.0 * h2 * h2 / 360.0, safe / np.sin(safe))
    dphi = np.stack([(arc - k[..., 2] * half) / k[..., 0], (arc + k[..., 2] * half) / k[..., 1]], -1)
    return dphi, across


def _jacobian_from_partials(s, theta, ds, dtheta):
    """Chain rule through the arc: ∂K/∂p given ∂s/∂p and ∂θ/∂p, each (..., m)."""
    f1, f2, df1, df2 = _arc_factors(theta)
    jx = ds * f1[..., None] + (s * df1)[..., None] * dtheta
    jy = ds * f2[..., None] + (s * df2)[..., None] * dtheta
    return np.stack([jx, jy, dtheta], -2)


def jacobian_k(dphi, k):
    """∂K/∂k, shape (..., 3, 3): rows (dx, dy, dθ), columns (r_l, r_r, b)."""
    dphi = np.asarray(dphi, float)
    k = np.asarray(k, float)
    s, theta = arc_length_and_rotation(dphi, k)
    zero = np.zeros_like(s)
    b = np.broadcast_to(k[..., 2], s.shape)
    ds = np.stack([0.5 * dphi[..., 0], 0.5 * dphi[..., 1], zero], -1)
    dtheta = np.stack([-dphi[..., 0] / b, dphi[..., 1] / b, -theta / b], -1)
    return _jacobian_from_partials(s, theta, ds, dtheta)


def jacobian_u(dphi, k):
    """∂K/∂u, shape (..., 3, 2): columns (dφ_l, dφ_r). Used to propagate wheel noise."""
    dphi = np.asarray(dphi, float)
    k = np.asarray(k, float)
    s, theta = arc_length_and_rotation(dphi, k)
    r_l = np.broadcast_to(k[..., 0], s.shape)
    r_r = np.broadcast_to(k[..., 1], s.shape)
    b = np.broadcast_to(k[..., 2], s.shape)
    ds = np.stack([0.5 * r_l, 0.5 * r_r], -1)
    dtheta = np.stack([-r_l / b, r_r / b], -1)
    return _jacobian_from_partials(s, theta, ds, dtheta)


def _steps_in_start_frame(parts, k):
    """Each part's arc (..., n, 3) and its translation turned into the edge's start frame
    (..., n, 2), R(θ̄ᵢ) tᵢ with θ̄ᵢ the heading before part i; and k per step."""
    parts = np.asarray(parts, float)
    k = np.asarray(k, float)
    k_steps = k[..., None, :] if k.ndim > 1 else k
    steps = forward(parts, k_steps)
    theta = steps[..., 2]
    before = np.cumsum(theta, axis=-1) - theta
    c, s = np.cos(before), np.sin(before)
    x, y = steps[..., 0], steps[..., 1]
    return steps, np.stack([c * x - s * y, s * x + c * y], -1), (c, s), k_steps


def forward_composed(parts, k):
    """K over consecutive sub-intervals composed, K(u₁) ⊕ K(u₂) ⊕ ..., and ∂/∂k.

    parts: (..., n, 2) wheel increments of the sub-intervals (zero rows are identity
    motions, so ragged edges can be padded); k: (3,) or one per edge (..., 3). One arc
    over a long edge assumes constant curvature; composing the arcs between encoder
    samples keeps the model exact to their length's cube when the curvature changes
    within the edge (S-curves, accelerations).

    In closed form rather than step by step (it is the hot loop of a window solve):
    with θ̄ᵢ the heading before step i (the sum of the earlier steps' rotations),
    translation = Σ R(θ̄ᵢ) tᵢ and rotation = Σ θᵢ, so
    ∂translation/∂k = Σ R(θ̄ᵢ) ∂tᵢ/∂k + R'(θ̄ᵢ) tᵢ ∂θ̄ᵢ/∂k.
    """
    from sclam_ros.core import se2  # local: se2 does not depend on kinematics, but keep the layering visible

    parts = np.asarray(parts, float)
    steps, turned, (c, s), k_steps = _steps_in_start_frame(parts, k)  # (..., n, 3), (..., n, 2)
    d_steps = jacobian_k(parts, k_steps)  # (..., n, 3, 3)
    d_before = np.cumsum(d_steps[..., 2, :], axis=-2) - d_steps[..., 2, :]  # (..., n, 3)
    dx, dy = d_steps[..., 0, :], d_steps[..., 1, :]
    rotation = se2.wrap_angle(np.sum(steps[..., 2], -1))
    motion = np.concatenate([np.sum(turned, -2), rotation[..., None]], -1)
    jac = np.stack([
        np.sum(c[..., None] * dx - s[..., None] * dy - turned[..., 1:2] * d_before, -2),
        np.sum(s[..., None] * dx + c[..., None] * dy + turned[..., 0:1] * d_before, -2),
        np.sum(d_steps[..., 2, :], -2),
    ], -2)
    return motion, jac


def jacobian_u_composed(parts, k):
    """∂(K(u₁) ⊕ K(u₂) ⊕ ...)/∂uₚ for every part p, shape (..., n, 3, 2).

    With T the composed translation, Cₚ the translation up to the end of part p and θ̄ₚ the
    heading before it: ∂T/∂uₚ = R(θ̄ₚ) ∂tₚ/∂uₚ + S (T − Cₚ) ∂θₚ/∂uₚ (the later parts swing
    about the end of part p), S the 90° rotation; ∂Θ/∂uₚ = ∂θₚ/∂uₚ.
    """
    parts = np.asarray(parts, float)
    _, turned, (c, s), k_steps = _steps_in_start_frame(parts, k)
    ju = jacobian_u(parts, k_steps)  # (..., n, 3, 2)
    cumulative = np.cumsum(turned, -2)
    later = cumulative[..., -1:, :] - cumulative  # (..., n, 2): T − Cₚ
    jx, jy, jth = ju[..., 0, :], ju[..., 1, :], ju[..., 2, :]
    return np.stack([
        c[..., None] * jx - s[..., None] * jy - later[..., 1:2] * jth,
        s[..., None] * jx + c[..., None] * jy + later[..., 0:1] * jth,
        jth,
    ], -2)


def motion_covariance(dphi, k, wheel_noise, floor=1e-12, lateral_noise=0.0,
                      increment_variance=None, path_variance=None, parts=None):
    """Covariance (..., 3, 3) of K(u, k): wheel-angle noise plus sideways slip.

    Each wheel's increment has variance wheel_noise² · |dφ| + floor (slip and backlash
    accumulate with the angle turned, a random walk; the floor is the encoder's
    quantisation), plus `increment_variance` (..., 2) where the increments themselves are
    uncertain (interpolated between slow encoder samples). Wheel noise alone is rank 2:
    the model cannot move sideways. Real tyres do slip sideways a little, so a lateral
    variance lateral_noise² · |s| (m² per m travelled) makes the edge full rank, and keeps
    a robot standing still positive definite. `path_variance` (...,) rad⁴ is where the
    path between slow encoder samples may run beside the constant-speed arcs
    (frontend/encoder_stream.py): times (r²/b)², sideways.

    `parts` (..., n, 2), the increments split into consecutive sub-intervals (zero-padded,
    as forward_composed takes them): the wheel noise then enters part by part, each along
    its own heading. The slip of a turn on the spot moves the robot along the arc's
    tangent as it turns, so its errors spread across the chord; one arc over the whole edge
    puts them all on the chord (measured at the simulator's truth on 0.6 rad turns on the
    spot: mean squared whitened error 2-3.5 across the chord with one arc, 0.1-0.2 part by
    part).
    """
    dphi = np.asarray(dphi, float)
    cov = wheel_angle_covariance(dphi, k, wheel_noise, floor, increment_variance, parts)
    s, _ = arc_length_and_rotation(dphi, k)
    k = np.asarray(k)
    _add_slip(cov, s, np.mean(k[..., :2], axis=-1), k[..., 2], np.mean(k[..., :2]), floor,
              lateral_noise, 0.0 if path_variance is None else np.asarray(path_variance, float))
    return cov


def _add_slip(cov, s, mean_radius, b, floor_radius, floor, lateral_noise, path_variance):
    """motion_covariance's sideways slip, path variance and quantisation floor, added to cov
    in place (`mean_radius` per edge for the path variance; `floor_radius` for the floor)."""
    cov[..., 1, 1] += (lateral_noise**2 * abs(s) + floor * floor_radius**2
                       + path_variance * (mean_radius**2 / b) ** 2)
    cov[..., 0, 0] += floor * floor_radius**2
    cov[..., 2, 2] += floor * (floor_radius / b) ** 2


def step(dphi, k, wheel_noise, lateral_noise=0.0, path_variance=0.0, floor=1e-12):
    """(K(u, k), ∂K/∂k, motion_covariance) of one increment dphi (2,) with k (3,): what
    forward, jacobian_k and motion_covariance give for it, in scalar arithmetic. ~/odom
    integrates one per encoder message, and the array functions spend ~0.2 ms a message
    in numpy's per-call overhead (online/odometry.py)."""
    d_left, d_right = float(dphi[0]), float(dphi[1])
    r_l, r_r, b = float(k[0]), float(k[1]), float(k[2])
    s = 0.5 * (d_right * r_r + d_left * r_l)
    theta = (d_right * r_r - d_left * r_l) / b
    if abs(theta) < _SMALL_ANGLE:
        f1, f2, df1, df2 = _series(theta, theta * theta)
    else:
        f1, f2, df1, df2 = _closed(theta, math.sin(theta), math.cos(theta))

    def partials(ds, dtheta):  # _jacobian_from_partials' chain rule through the arc
        ds, dtheta = np.array(ds), np.array(dtheta)
        return np.array([ds * f1 + s * df1 * dtheta, ds * f2 + s * df2 * dtheta, dtheta])

    j_k = partials([0.5 * d_left, 0.5 * d_right, 0.0], [-d_left / b, d_right / b, -theta / b])
    j_u = partials([0.5 * r_l, 0.5 * r_r], [-r_l / b, r_r / b])
    variance = floor + wheel_noise**2 * np.abs([d_left, d_right])
    cov = (j_u * variance) @ j_u.T
    mean_radius = 0.5 * (r_l + r_r)
    _add_slip(cov, s, mean_radius, b, mean_radius, floor, lateral_noise, path_variance)
    return np.array([s * f1, s * f2, theta]), j_k, cov


def wheel_angle_covariance(dphi, k, wheel_noise, floor=1e-12, increment_variance=None,
                           parts=None):
    """The part of motion_covariance that is noise in the wheel angles themselves (slip,
    quantisation, interpolation), propagated through K: the noise of the odometry's
    regressors, as opposed to the sideways slip the wheel model cannot express."""
    dphi = np.asarray(dphi, float)
    var = np.full(dphi.shape, floor)
    if increment_variance is not None:
        var = var + np.asarray(increment_variance, float)
    if parts is None:
        var = var + wheel_noise**2 * np.abs(dphi)
    ju = jacobian_u(dphi, k)
    cov = np.einsum("...ij,...j,...kj->...ik", ju, var, ju)
    if parts is not None:
        parts = np.asarray(parts, float)
        ju_parts = jacobian_u_composed(parts, k)
        cov = cov + np.einsum("...pij,...pj,...pkj->...ik", ju_parts,
                              wheel_noise**2 * np.abs(parts), ju_parts)
    return cov


def wheel_speeds_to_twist(v_l, v_r, k):
    """(v, ω) of the base from wheel angular speeds (rad/s): the continuous-time model."""
    k = np.asarray(k, float)
    return 0.5 * (v_r * k[1] + v_l * k[0]), (v_r * k[1] - v_l * k[0]) / k[2]
