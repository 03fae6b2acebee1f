"""Factors of the calibration graph: each knows its residual and its Jacobians.

A factor object holds *all* edges of one type, so residuals and Jacobians are evaluated
with a few vectorised numpy operations instead of a Python loop over thousands of edges.
The solver is generic: it only sees `Linearization`s (residuals, whitening, and Jacobian
blocks with the variable rows they touch) and never special-cases a factor.

Variables live in named blocks (see problem.Values): "poses" (n, 3), "odometry" (1, 3) =
(r_l, r_r, b), "laser" (1, 3) = (l_x, l_y, l_yaw); model extensions add their own blocks.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from sclam_ros.core import kinematics, se2


@dataclass
class JacobianBlock:
    """∂r/∂(one variable block): rows of the block each edge touches and the Jacobians."""

    block: str
    rows: np.ndarray  # (m,) row index into the block's values, one per edge
    jacobian: np.ndarray  # (m, d, block_dim)


@dataclass
class Linearization:
    residual: np.ndarray  # (m, d) raw residuals
    sqrt_information: np.ndarray  # (m, d, d) upper-triangular L with Ω = LᵀL
    blocks: list = field(default_factory=list)  # list[JacobianBlock]


def sqrt_information(information):
    """Upper-triangular L with Ω = LᵀL for a stack of information matrices (m, d, d)."""
    lower = np.linalg.cholesky(information)  # Ω = C Cᵀ with C lower
    return np.swapaxes(lower, -1, -2)  # L = Cᵀ: LᵀL = C Cᵀ = Ω


def information_from_covariance(covariance):
    return np.linalg.inv(covariance)


class Factor:
    """One type of edge. Subclasses set `name` and implement `linearize(values)`."""

    name = "factor"
    edge_dim = 3
    # Whether variance component estimation may rescale this factor's noise: true for
    # measurements, false for priors (their σ is a statement, not a measurement).
    measurement = True
    # Whether consecutive edges (one ending at the pose the next starts from) share a
    # measurement, so that their errors correlate
    # (correlated_covariance.chain_correlated_covariance).
    chained_errors = False

    def __len__(self) -> int:
        raise NotImplementedError

    def linearize(self, values) -> Linearization:
        raise NotImplementedError

    def residuals(self, values) -> np.ndarray:
        return self.linearize(values).residual


def motion_difference(pose_delta, motion):
    """(x_j ⊖ x_i) − K: two motions from the same start frame, compared in that frame
    (translation difference, wrapped rotation difference); ∂/∂pose_delta = I, ∂/∂K = −I.

    The same error as (x_j ⊖ x_i) ⊖ K to first order, but not expressed in K's end frame,
    which is turned by K's rotation: the wheel-noise covariance of K (kinematics.
    motion_covariance) is a thin ellipse along the arc's chord, in the start frame. Taken as
    the covariance of the ⊖ error it is misaligned by the edge's rotation: on the simulator's
    turns on the spot (0.6 rad per edge) the true odometry errors were 8σ across it.
    """
    residual = np.asarray(pose_delta, float) - np.asarray(motion, float)
    residual[..., 2] = se2.wrap_angle(residual[..., 2])
    return residual


class OdometryFactor(Factor):
    """e_i = (x_j ⊖ x_i) − K(u_i, k) (motion_difference): measured wheel motion against the
    pose difference, in the edge's start frame.

    The information is fixed (evaluated at the nominal k). Letting it follow k (the
    errors-in-variables form) removes regression dilution in simulation but, on real runs
    with a model misfit and weak excitation, pulls the estimate along the weakly
    determined direction (OptiOdom circular runs: b 0.09-0.13 m against 0.20 m from the
    square runs of the same robot): a k that inflates the edges' covariance lowers their
    cost. The dilution is kept small by long edges (graph.merge_keyframes) and corrected
    in the batch cost with the weights fixed (dilution.py).
    """

    name = "odometry"

    def __init__(self, pose_i, pose_j, dphi, information, parts=None):
        """dphi (m, 2): wheel increments of each edge; parts (m, n, 2), optional: the same
        split into consecutive sub-intervals (zero-padded), composed arc by arc."""
        self.pose_i = np.asarray(pose_i, int)
        self.pose_j = np.asarray(pose_j, int)
        self.dphi = np.asarray(dphi, float).reshape(-1, 2)
        self.parts = None if parts is None else np.asarray(parts, float).reshape(len(self.dphi), -1, 2)
        self.information = np.asarray(information, float).reshape(-1, 3, 3)
        self._sqrt_info = sqrt_information(self.information)

    def __len__(self):
        return len(self.pose_i)

    def predicted_motion(self, k):
        return self._motion_and_jacobian(k)[0]

    def _motion_and_jacobian(self, k):
        if self.parts is None:
            return kinematics.forward(self.dphi, k), kinematics.jacobian_k(self.dphi, k)
        return kinematics.forward_composed(self.parts, k)

    def linearize(self, values) -> Linearization:
        poses = values["poses"]
        k = values["odometry"][0]
        motion, d_motion_k = self._motion_and_jacobian(k)
        pose_delta, d_delta_j, d_delta_i = se2.between_with_jacobians(
            poses[self.pose_j], poses[self.pose_i]
        )
        residual = motion_difference(pose_delta, motion)
        zeros = np.zeros(len(self), int)
        return Linearization(
            residual,
            self._sqrt_info,
            [
                JacobianBlock("poses", self.pose_i, d_delta_i),
                JacobianBlock("poses", self.pose_j, d_delta_j),
                JacobianBlock("odometry", zeros, -d_motion_k),
            ],
        )


class LaserFactor(Factor):
    """e_ij = ((x_j ⊕ l) ⊖ (x_i ⊕ l)) ⊖ z_ij: the laser's own motion against scan matching."""

    name = "laser"
    # Consecutive matches share a scan: its registration error enters both.
    chained_errors = True

    def __init__(self, pose_i, pose_j, z, information):
        self.pose_i = np.asarray(pose_i, int)
        self.pose_j = np.asarray(pose_j, int)
        self.z = np.asarray(z, float).reshape(-1, 3)
        self.information = np.asarray(information, float).reshape(-1, 3, 3)
        self._sqrt_info = sqrt_information(self.information)

    def __len__(self):
        return len(self.pose_i)

    def linearize(self, values) -> Linearization:
        poses = values["poses"]
        laser = values["laser"][0]
        laser_i, d_li_xi, d_li_l = se2.compose_with_jacobians(poses[self.pose_i], laser)
        laser_j, d_lj_xj, d_lj_l = se2.compose_with_jacobians(poses[self.pose_j], laser)
        motion, d_motion_lj, d_motion_li = se2.between_with_jacobians(laser_j, laser_i)
        residual, d_res_motion, _ = se2.between_with_jacobians(motion, self.z)
        d_res_li = d_res_motion @ d_motion_li
        d_res_lj = d_res_motion @ d_motion_lj
        zeros = np.zeros(len(self), int)
        return Linearization(
            residual,
            self._sqrt_info,
            [
                JacobianBlock("poses", self.pose_i, d_res_li @ d_li_xi),
                JacobianBlock("poses", self.pose_j, d_res_lj @ d_lj_xj),
                JacobianBlock("laser", zeros, d_res_li @ d_li_l + d_res_lj @ d_lj_l),
            ],
        )


class PriorFactor(Factor):
    """A Gaussian prior on rows of one block: e = x − mean (angles wrapped where marked)."""

    name = "prior"
    measurement = False

    def __init__(self, block, rows, mean, information, angular=(False, False, True), name=None):
        self.block = block
        self.rows = np.atleast_1d(np.asarray(rows, int))
        self.mean = np.asarray(mean, float).reshape(len(self.rows), -1)
        dim = self.mean.shape[1]
        self.information = np.broadcast_to(
            np.asarray(information, float), (len(self.rows), dim, dim)
        ).copy()
        self._sqrt_info = sqrt_information(self.information)
        self.angular = np.asarray(angular[:dim], bool)
        if name:
            self.name = name

    def __len__(self):
        return len(self.rows)

    def linearize(self, values) -> Linearization:
        current = values[self.block][self.rows]
        residual = current - self.mean
        residual[:, self.angular] = se2.wrap_angle(residual[:, self.angular])
        dim = self.mean.shape[1]
        jac = np.broadcast_to(np.eye(dim), (len(self), dim, dim))
        return Linearization(residual, self._sqrt_info, [JacobianBlock(self.block, self.rows, jac)])
