"""Factors with effects plugged in, and the graph that estimates them with the calibration.

The extended odometry edge is
    e = (x_j ⊖ x_i) ⊖ m,   m = K(dφ', k_e) + Σ Δm,
with dφ' and k_e the increments and wheel parameters after the effects' hooks, Δm the
motion terms (see base.ModelEffect). An edge with ``parts`` (cut at encoder samples
and, merged by graph.merge_keyframes, at scans) composes their arcs as
factors.OdometryFactor does, and the effects act on the composed motion:
    m = K∘(parts, k_e) + [K(dφ', k_e) − K(dφ, k_e)] + Σ Δm,
i.e. per-edge wheel parameters (radius_drift) enter the composition exactly, an increment
correction (time_offset: δ·(ω_j − ω_i), which lives at the edge's two ends) perturbs the
composed motion by its first-order effect on the edge's arc, and the motion terms
(lateral_slip) read the edge's total arc length and rotation, which are sums over the
parts and so the same either way. With all effects at zero the bracket vanishes and
m = K∘(parts, k) exactly: the base factor. The extended laser edge compares the laser's
motion with the corrected scan match z'. With no effect both reduce to
factors.OdometryFactor / factors.LaserFactor exactly.
"""
from __future__ import annotations

import numpy as np

from sclam_ros.core import factors, kinematics, se2
from sclam_ros.core import graph as graph_mod
from sclam_ros.core.problem import Problem, Values


def _effect_params(values, effect):
    return values[effect.name][0]


class EffectOdometryFactor(factors.OdometryFactor):
    name = "odometry"

    def __init__(self, pose_i, pose_j, dphi, information, effects, parts=None):
        super().__init__(pose_i, pose_j, dphi, information, parts=parts)
        self.effects = [e for e in effects if e.bends("odometry")]

    def predicted_motion_with_jacobians(self, values):
        """m (m,3), ∂m/∂k (m,3,3) and {effect: ∂m/∂p}."""
        k = np.broadcast_to(values["odometry"][0], (len(self), 3))
        i, j = self.pose_i, self.pose_j
        dphi, d_dphi = self.dphi, {}
        for e in self.effects:
            p = _effect_params(values, e)
            dphi, j_prev, j_p = e.adjust_dphi(dphi, p, i, j)
            d_dphi = {key: j_prev @ val for key, val in d_dphi.items()}
            d_dphi[e.name] = j_p
        k_e, d_ke_k, d_ke = k, np.broadcast_to(np.eye(3), (len(self), 3, 3)), {}
        for e in self.effects:
            p = _effect_params(values, e)
            k_e, j_prev, j_p = e.adjust_k(k_e, p, i, j)
            d_ke = {key: j_prev @ val for key, val in d_ke.items()}
            d_ke[e.name] = j_p
            d_ke_k = j_prev @ d_ke_k
        d_m_u = kinematics.jacobian_u(dphi, k_e)
        if self.parts is None:
            motion = kinematics.forward(dphi, k_e)
            d_m_ke = kinematics.jacobian_k(dphi, k_e)
        else:
            motion, d_m_ke = kinematics.forward_composed(self.parts, k_e)
            if d_dphi:  # an increment correction: its first-order effect on the edge's arc
                motion = motion + kinematics.forward(dphi, k_e) - kinematics.forward(self.dphi, k_e)
                d_m_ke = (d_m_ke + kinematics.jacobian_k(dphi, k_e)
                          - kinematics.jacobian_k(self.dphi, k_e))
        own = {}
        for e in self.effects:
            term, t_u, t_k, t_p = e.motion_term(dphi, k_e, _effect_params(values, e), i, j)
            motion = motion + term
            d_m_u = d_m_u + t_u
            d_m_ke = d_m_ke + t_k
            own[e.name] = t_p
        d_p = {}
        for e in self.effects:
            jac = own[e.name].copy()
            if e.name in d_dphi:
                jac += d_m_u @ d_dphi[e.name]
            if e.name in d_ke:
                jac += d_m_ke @ d_ke[e.name]
            d_p[e.name] = jac
        return motion, d_m_ke @ d_ke_k, d_p

    def linearize(self, values) -> factors.Linearization:
        poses = values["poses"]
        motion, d_m_k, d_m_p = self.predicted_motion_with_jacobians(values)
        pose_delta, d_delta_j, d_delta_i = se2.between_with_jacobians(
            poses[self.pose_j], poses[self.pose_i])
        residual = factors.motion_difference(pose_delta, motion)
        zeros = np.zeros(len(self), int)
        blocks = [
            factors.JacobianBlock("poses", self.pose_i, d_delta_i),
            factors.JacobianBlock("poses", self.pose_j, d_delta_j),
            factors.JacobianBlock("odometry", zeros, -d_m_k),
        ]
        blocks += [factors.JacobianBlock(name, zeros, -jac) for name, jac in d_m_p.items()]
        return factors.Linearization(residual, self._sqrt_info, blocks)


class EffectLaserFactor(factors.LaserFactor):
    name = "laser"

    def __init__(self, pose_i, pose_j, z, information, effects):
        super().__init__(pose_i, pose_j, z, information)
        self.effects = [e for e in effects if e.bends("laser")]

    def corrected_z(self, values):
        z, d_p = self.z, {}
        for e in self.effects:
            z, d_p[e.name] = e.adjust_z(z, _effect_params(values, e), self.pose_i, self.pose_j)
        return z, d_p

    def linearize(self, values) -> factors.Linearization:
        poses = values["poses"]
        laser = values["laser"][0]
        z, d_z_p = self.corrected_z(values)
        laser_i, d_li_xi, d_li_l = se2.compose_with_jacobians(poses[self.pose_i], laser)
        laser_j, d_lj_xj, d_lj_l = se2.compose_with_jacobians(poses[self.pose_j], laser)
        motion, d_motion_lj, d_motion_li = se2.between_with_jacobians(laser_j, laser_i)
        residual, d_res_motion, d_res_z = se2.between_with_jacobians(motion, z)
        d_res_li = d_res_motion @ d_motion_li
        d_res_lj = d_res_motion @ d_motion_lj
        zeros = np.zeros(len(self), int)
        blocks = [
            factors.JacobianBlock("poses", self.pose_i, d_res_li @ d_li_xi),
            factors.JacobianBlock("poses", self.pose_j, d_res_lj @ d_lj_xj),
            factors.JacobianBlock("laser", zeros, d_res_li @ d_li_l + d_res_lj @ d_lj_l),
        ]
        blocks += [factors.JacobianBlock(name, zeros, d_res_z @ jac) for name, jac in d_z_p.items()]
        return factors.Linearization(residual, self._sqrt_info, blocks)


def extend_problem(problem: Problem, effects, initial=None) -> Problem:
    """The same graph (values, priors, gauge, kernels, scales) with the effects estimated:
    the odometry and laser factors replaced by their effect-aware versions, one block and
    a prior per effect (ModelEffect.prior: weak and zero-mean unless the data state a
    value). Noise effects (kind "noise") change no factor."""
    initial = initial or {}
    values = problem.values.copy()
    new_factors = []
    fitted = [e for e in effects if e.kind != "noise"]
    for f in problem.factors:
        if type(f) in (factors.OdometryFactor, EffectOdometryFactor):
            f = EffectOdometryFactor(f.pose_i, f.pose_j, f.dphi, f.information, fitted,
                                     parts=f.parts)
        elif type(f) in (factors.LaserFactor, EffectLaserFactor):
            f = EffectLaserFactor(f.pose_i, f.pose_j, f.z, f.information, fitted)
        new_factors.append(f)
    for e in fitted:
        if e.name not in values:
            values.add(e.name, [initial.get(e.name, e.initial())])
        mean, sigma = e.prior()
        new_factors.append(factors.PriorFactor(
            e.name, [0], [np.asarray(mean, float)], np.diag(np.asarray(sigma, float) ** -2.0),
            angular=(False,) * e.dim, name="effect_prior"))
    return Problem(values, new_factors, fixed=problem.fixed, kernels=problem.kernels,
                   scales=problem.scales, corrections=problem.corrections)


def build_problem(inputs, params, calibration, effects=(), poses=None, nominal=None) -> Problem:
    """graph.build_problem with the effects plugged in."""
    base = graph_mod.build_problem(inputs, params, calibration, poses=poses, nominal=nominal)
    return extend_problem(base, effects) if effects else base
