"""The held-out metric: each scored edge's laser-vs-odometry disagreement and its negative
log-likelihood under a fit, with the wheels' share of the covariance scaled by the noise
effects.

    d = (l⁻¹ ∘ K(u; k, effects) ∘ l) ⊖ z',   NLL = 0.5·(ρ(dᵀΣ⁻¹d) + ln det Σ)

Σ the fitted odometry + scan-match covariance in the laser frame plus the scans' stamp
jitter (stamp_jitter.py), ρ the graph's Cauchy kernel (the one that weighs the scan matches
in the fit).
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from sclam_ros.core import graph as graph_mod
from sclam_ros.core import kinematics, se2
from sclam_ros.diagnosis.effects.model import EffectLaserFactor, EffectOdometryFactor
from sclam_ros.diagnosis.fitting import Edges, Fit
from sclam_ros.diagnosis.noise_model import combined_scale, fit_noise, level_profiled_nll
from sclam_ros.diagnosis.stamp_jitter import StampJitter, fit_jitter, laser_twists, stamp_covariance


@dataclass
class Disagreement:
    """Per-edge laser-vs-odometry disagreement d and its covariance in two parts, so a
    noise model can rescale the wheels' share without recomputing anything else."""

    d: np.ndarray  # (m, 3) laser frame
    wheel_cov: np.ndarray  # (m, 3, 3) J Σ_w Jᵀ, the wheels' slip (what noise effects scale)
    fixed_cov: np.ndarray  # (m, 3, 3) the scan match's share and the odometry's other parts
    stamp_cov: np.ndarray = None  # (m, 3, 3) per s² of the scans' stamp error (None: not modelled)
    stamp_sigma: float = 0.0  # s, 1σ of the scans' stamp error

    def with_stamp_sigma(self, sigma: float) -> "Disagreement":
        return dataclasses.replace(self, stamp_sigma=float(sigma))

    def nll(self, wheel_scale=1.0):
        """Per-edge NLL with the wheels' share multiplied by wheel_scale ((m,) or a
        number)."""
        scale = np.reshape(np.asarray(wheel_scale, float), (-1, 1, 1))
        cov = self.wheel_cov * scale + self.fixed_cov
        if self.stamp_cov is not None and self.stamp_sigma > 0.0:
            cov = cov + self.stamp_cov * self.stamp_sigma**2
        sq = np.einsum("mi,mij,mj->m", self.d, np.linalg.inv(cov), self.d)
        return 0.5 * (graph_mod.laser_kernel().rho(sq) + np.linalg.slogdet(cov)[1])


@dataclass
class OdometryCovariance:
    """The odometry edges' covariance and the part of it a noise effect rescales.

    A noise effect is a floor or a speed at which the wheels slip more: it scales the
    wheel noise (params.wheel_noise), not the sideways slip that keeps the edges full rank,
    the encoders' quantisation or the interpolation between slow samples. Scaling the
    whole covariance diluted the effect into those parts (docs/decisions/diagnose.md)."""

    total: np.ndarray  # (m_o, 3, 3) graph.odometry_covariance
    wheels: np.ndarray  # (m_o, 3, 3) its wheel-noise part

    @classmethod
    def of(cls, inputs, params, k):
        return cls(graph_mod.odometry_covariance(inputs, params, k),
                   kinematics.motion_covariance(inputs.odo_dphi, k, params.wheel_noise,
                                                floor=0.0, parts=inputs.odo_parts))


def disagreement(fit: Fit, effects, inputs, edges: Edges, odo_cov: OdometryCovariance,
                 jitter=None) -> Disagreement:
    """d = (l⁻¹ ∘ K(u; k, effects) ∘ l) ⊖ z' of the edges, with its covariance split;
    `jitter` (stamp_jitter.StampJitter or None) the scans' stamp error."""
    values = fit.values
    mech = [e for e in effects if e.kind != "noise"]
    oi, li = edges.odo_index, edges.laser_index
    odo = EffectOdometryFactor(edges.pose_i, edges.pose_j, inputs.odo_dphi[oi],
                               np.tile(np.eye(3), (len(oi), 1, 1)), mech,
                               parts=None if inputs.odo_parts is None else inputs.odo_parts[oi])
    las = EffectLaserFactor(edges.pose_i, edges.pose_j, inputs.laser_z[li],
                            inputs.laser_info[li], mech)
    motion, _, _ = odo.predicted_motion_with_jacobians(values)
    z, _ = las.corrected_z(values)
    mount = values["laser"][0]
    a, a_m = se2.compose_with_jacobians(motion, mount)[:2]
    zp, _, zp_a = se2.compose_with_jacobians(np.broadcast_to(se2.inverse(mount), a.shape), a)
    d, d_zp, d_z = se2.between_with_jacobians(zp, z)
    j_m = d_zp @ zp_a @ a_m
    odometry_scale = fit.scales.get("odometry", 1.0)
    cov_w = odo_cov.wheels[oi] * odometry_scale
    cov_rest = (odo_cov.total[oi] - odo_cov.wheels[oi]) * odometry_scale
    cov_z = np.linalg.inv(inputs.laser_info[li]) * fit.scales.get("laser", 1.0)
    stamp_cov, sigma = None, 0.0
    if jitter is not None:
        twists = laser_twists(jitter.wheel_speeds, values["odometry"][0], mount)
        stamp_cov = stamp_covariance(zp, d_zp, twists[edges.pose_i], twists[edges.pose_j])
        sigma = jitter.sigma
    return Disagreement(d, j_m @ cov_w @ np.swapaxes(j_m, 1, 2),
                        j_m @ cov_rest @ np.swapaxes(j_m, 1, 2)
                        + d_z @ cov_z @ np.swapaxes(d_z, 1, 2), stamp_cov, sigma)


def fitted_stamp_jitter(fit: Fit, inputs, edges: Edges, odo_cov, wheel_speeds,
                       log_range: float) -> StampJitter:
    """The scans' stamp jitter fitted to the disagreement of `edges` under `fit` without
    effects (stamp_jitter.fit_jitter); wheel_speeds (n, 2) at the graph's poses."""
    unfitted = StampJitter(wheel_speeds)
    sigma = fit_jitter(disagreement(fit, [], inputs, edges, odo_cov, unfitted), log_range)
    return StampJitter(wheel_speeds, sigma)


def edge_nll(fit: Fit, effects, inputs, edges: Edges, odo_cov, noise=(), jitter=None):
    """Per-edge negative log-likelihood of the laser-vs-odometry disagreement, the
    wheels' noise scaled by the fitted noise effects `noise`."""
    dis = disagreement(fit, effects, inputs, edges, odo_cov, jitter)
    return dis.nll(combined_scale(noise, edges.pose_i, edges.pose_j))


def fit_noise_effects(noise, fit: Fit, mech, inputs, edges: Edges, odo_cov, rounds: int,
                      log_range: float, jitter=None):
    """Fit the noise effects to the disagreement of `edges` under `fit` (`rounds` of
    coordinate descent, noise_model.fit_noise); the NLL before and after (per edge), each
    with the wheels' overall level fitted (noise_model.level_profiled_nll), so that their
    difference is the effects' shape alone: zero when they change nothing."""
    dis = disagreement(fit, mech, inputs, edges, odo_cov, jitter)
    fit_noise(noise, edges.pose_i, edges.pose_j, dis.nll, rounds)
    return (level_profiled_nll(dis.nll, np.ones(len(edges.pose_i)), log_range),
            level_profiled_nll(dis.nll, combined_scale(noise, edges.pose_i, edges.pose_j),
                               log_range))
