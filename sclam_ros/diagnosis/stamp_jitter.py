"""Error in the scans' stamps: part of the noise model every effect is tested against.

A scan stamped δ s off the time it was taken is paired with the wheels' pose δ s off too,
so its match disagrees with the odometry by the laser's velocity times δ: variance that
grows with speed and turn rate, at every speed and on every floor. Real drivers stamp
scans with a few ms of jitter (the host's clock at the USB or Ethernet read); with
encoders that barely slip this is most of the disagreement, and a model without it takes
it for wheel noise that grows with speed or turn rate. The jitter is a property of the
recording, not an effect to select: its 1σ is fitted once by maximum likelihood, on the
base model with the wheels' level profiled, and held in every model compared.

Per edge i → j with stamp errors δ_i, δ_j (independent, 1σ σ_t) and the laser's twists
η_i, η_j (its own frame), the odometry's laser motion zp is off by a right perturbation
η_j·δ_j − Ad(zp⁻¹)·η_i·δ_i, so the disagreement's covariance gains
σ_t²·D (a_i a_iᵀ + a_j a_jᵀ) Dᵀ, D = ∂d/∂zp and a the perturbations mapped to zp's (x, y, θ).
"""
from __future__ import annotations

import numpy as np
from scipy.optimize import minimize_scalar

from sclam_ros.core import kinematics, se2
from sclam_ros.diagnosis.effects.noise_fit import ml_factor

# s; the largest 1σ searched. Beyond it a scan is paired with the wrong encoder sample,
# which is a clock offset or a broken driver, not jitter.
MAX_JITTER_S = 0.05


def laser_twists(wheel_speeds, k, mount) -> np.ndarray:
    """(n, 3) the laser's velocity (vx, vy, ω) in its own frame at each pose, from the
    wheels' angular speeds (n, 2) (left, right) and k = (r_l, r_r, b)."""
    # K's arc length and rotation are linear in the wheel angles: per second, v and ω.
    v, w = kinematics.arc_length_and_rotation(wheel_speeds, k)
    # The laser's point on the body moves at v + ω × t_l (base frame), seen in its frame.
    moving = np.column_stack([v - w * mount[1], w * mount[0]])
    return np.column_stack([se2.rotate_inverse(mount[2], moving), w])


def _right_to_params(pose):
    """(m, 3, 3): a right perturbation of `pose` as a change of its (x, y, θ)."""
    out = np.zeros(pose.shape[:-1] + (3, 3))
    out[..., :2, :2] = se2.rotation(pose[..., 2])
    out[..., 2, 2] = 1.0
    return out


def _adjoint(pose, twist):
    """Ad(pose)·twist for SE(2) twists (vx, vy, ω), (m, 3)."""
    turned = se2.rotate(pose[..., 2], twist[..., :2])
    shift = np.column_stack([pose[..., 1], -pose[..., 0]]) * twist[..., 2:3]
    return np.column_stack([turned + shift, twist[..., 2]])


def stamp_covariance(zp, d_zp, twist_i, twist_j) -> np.ndarray:
    """(m, 3, 3) the disagreement's covariance per s² of each scan's stamp error (module doc)."""
    to_params = _right_to_params(zp)
    a_j = np.einsum("mij,mj->mi", to_params, twist_j)
    a_i = -np.einsum("mij,mj->mi", to_params, _adjoint(se2.inverse(zp), twist_i))
    d_a_i = np.einsum("mij,mj->mi", d_zp, a_i)
    d_a_j = np.einsum("mij,mj->mi", d_zp, a_j)
    return d_a_i[:, :, None] * d_a_i[:, None, :] + d_a_j[:, :, None] * d_a_j[:, None, :]


def fit_jitter(dis, log_range: float) -> float:
    """The ML 1σ (s) of the scans' stamp errors, in [0, MAX_JITTER_S], on the
    Disagreement `dis`, the wheels' overall level profiled within exp(±log_range)."""
    m = len(dis.d)

    def profiled(sigma):
        at = dis.with_stamp_sigma(sigma)
        level = ml_factor(at.nll, np.ones(m, bool), log_range)
        return float(np.sum(at.nll(np.full(m, level))))

    best = minimize_scalar(profiled, bounds=(0.0, MAX_JITTER_S), method="bounded",
                           options={"xatol": 1e-5})
    # The bounded search never evaluates the bound itself: no jitter at all is often best.
    return 0.0 if profiled(0.0) <= best.fun else float(best.x)


class StampJitter:
    """The scans' stamp error in the noise model: the wheels' angular speeds at the graph's
    poses (what the laser's twist is computed from) and the fitted 1σ (s)."""

    def __init__(self, wheel_speeds, sigma: float = 0.0):
        self.wheel_speeds = np.asarray(wheel_speeds, float)
        self.sigma = float(sigma)
