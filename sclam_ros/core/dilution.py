"""The wheel base's regression dilution, taken out of the cost (a corrected score).

The wheel base is learned from the heading change against the wheel angles: θ = (r_r u_r −
r_l u_l)/b. The angles are measured with noise C_u (slip, quantisation, interpolation), so
at the true k an odometry edge's expected squared rotation residual is its value at the true
angles plus D(k) = (K_θu C_u(k) K_θuᵀ)/σ²_θ, and D falls as b grows (K_θu = (−r_l, r_r)/b).
Least squares follows D to a wheel base too large by ≈ Σ noise² / Σ signal² (the regression
dilution graph.merge_keyframes describes); docs/decisions/wheel_base_dilution.md records
it and what the correction leaves on graphs drawn from the model itself, and an investigation on the
simulator outdoors (the scan matches, then also the wheel increments, replaced by the
truth; docs/decisions/match_scale.md).

The correction subtracts D's slope from the cost, −s·(k − k₀) (Nakamura 1990, corrected
score). Four choices, each measured:

- Only the rotation row. The translation's dilution is the same effect on the radii, but
  there the signal is large (noise²/signal² ≈ q²/|u| ≈ 10⁻⁴ per edge): with the matches
  replaced by the true motion the radii came out within 0.03 % without it, and a correction
  over all three rows moved them by +0.06 % (outdoors, 40 seeds, ad hoc).
- Per edge, the share of its noise the poses do not absorb. The expected residual is D only
  where something else fixes the poses' rotation: an edge whose poses are joined by a scan
  match keeps σ²_O / (σ²_O + σ²_L) of it (σ²_O, σ²_L the odometry and laser edges' rotation
  variances, each times its variance scale); an edge no scan match spans keeps none (the
  poses follow the wheels). Without this share the correction overshot outdoors, where
  matches fail in stretches (ad hoc: the solution's rotation residuals were 0.17-0.21 of the
  noise model where the simulator's slip is 0.37 of it).
- Linear in k, slope evaluated once at the start: D changes by its own O(σ²) share over the
  few per cent k moves. And with the weights fixed there is no way to lower the cost by
  inflating a covariance, which is why letting the information follow k was rejected
  (factors.OdometryFactor).
- The noise level from the data. The term is tr(Ω/scale · C_actual), with the wheel noise
  C_actual = scale · C_u when the odometry's variance scale
  (variance_components.solve_with_variance_components) is right; then the scale cancels. The scale is estimated from all three
  residual rows and can stop short of a small noise (a clamped round: the simulator without
  slip left it at 0.2 where its rotation residuals were 10⁻⁴ of the model, and the
  correction moved b by −0.16 %). So the rotation rows are asked too: their own variance
  factor (χ² over redundancy, at the solution, under the scale) is the level the correction
  is taken at where it is below 1.
"""
from __future__ import annotations

import numpy as np

from sclam_ros.core import kinematics
from sclam_ros.core.config import GraphConfig
from sclam_ros.core.covariance import absorbed_trace
from sclam_ros.core.params import CALIBRATION_KEYS



class WheelNoiseCorrection:
    """−Σᵢ wᵢ ∂Dᵢ/∂k · (k − k₀) over the "odometry" block, wᵢ the unabsorbed share.

    `active` is cleared (variance_components.settle_corrections) where the correction would
    move a parameter by more than `max_relative_shift` of its value
    (GraphConfig.max_dilution_shift: the correction is first order in noise²/signal²;
    docs/decisions/wheel_base_dilution.md); `shift` holds the move it makes or would make
    (m), so that a result can say how much dilution it left in."""

    block = "odometry"
    active = True
    shift = None
    # The share of the stated wheel noise (under the odometry's variance scale) that the
    # rotation residuals show: observe() sets it.
    level = 1.0

    def __init__(self, k0, edge_slopes, odometry_variance, laser_variance,
                 max_relative_shift: float = GraphConfig.max_dilution_shift):
        """edge_slopes (m, 3): ∂Dᵢ/∂k at k₀; odometry_variance (m,), laser_variance (m,): the
        rotation variances of each odometry edge and of the scan match joining the same two
        poses (inf where none does)."""
        self.max_relative_shift = float(max_relative_shift)
        self.k0 = np.asarray(k0, float)
        self.edge_slopes = np.asarray(edge_slopes, float).reshape(-1, 3)
        self.odometry_variance = np.asarray(odometry_variance, float)
        self.laser_variance = np.asarray(laser_variance, float)

    def holds(self, shift, values) -> bool:
        limit = self.max_relative_shift * np.abs(values[self.block][0])
        return bool(np.all(np.abs(shift) <= limit))

    def observe(self, system, lu) -> None:
        """`level` from the odometry edges' rotation rows of the linear system at the
        solution (`system`, its factorisation `lu`): their whitened χ² over their
        redundancy (the rows less the share the poses absorb, tr(J H⁻¹ Jᵀ) over those
        rows, covariance.absorbed_trace), at most 1."""
        ranges = [(start, stop) for name, start, stop in system.row_ranges if name == "odometry"]
        if len(ranges) != 1 or (ranges[0][1] - ranges[0][0]) != 3 * len(self.edge_slopes):
            return
        rows = np.arange(ranges[0][0] + 2, ranges[0][1], 3)  # the rotation component
        absorbed = absorbed_trace(system.jacobian[rows], lu)
        redundancy = len(rows) - absorbed
        if redundancy > 0:
            chi2 = float(system.residual[rows] @ system.residual[rows])
            self.level = min(1.0, chi2 / redundancy)

    def _share(self, scales) -> np.ndarray:
        """Per edge, the share of its rotation noise the poses do not absorb."""
        odometry = scales.get("odometry", 1.0) * self.odometry_variance
        laser = scales.get("laser", 1.0) * self.laser_variance
        with np.errstate(invalid="ignore"):
            return np.where(np.isfinite(laser), odometry / (odometry + laser), 0.0)

    def slope(self, scales) -> np.ndarray:
        return self.level * (self._share(scales) @ self.edge_slopes)

    def term(self, values, scales):
        """(cost, ∂cost/∂k): the correction at `values` under the variance `scales`."""
        slope = self.slope(scales)
        return -float(slope @ (values[self.block][0] - self.k0)), -slope


def wheel_noise_correction(inputs, params, k, odometry_covariance, encoder_floor,
                           max_relative_shift: float = GraphConfig.max_dilution_shift):
    """The correction for a graph's edges (graph.GraphInputs) at calibration k, with the
    odometry edges' covariance `odometry_covariance` (m, 3, 3) the factor uses; applied
    where it moves no parameter by more than `max_relative_shift` of its value."""
    k = np.asarray(k, float)
    odometry_variance = odometry_covariance[:, 2, 2]

    def rotation_noise(k_at):
        cov = kinematics.wheel_angle_covariance(inputs.odo_dphi, k_at, params.wheel_noise,
                                                encoder_floor, inputs.odo_variance,
                                                parts=inputs.odo_parts)
        return cov[:, 2, 2] / odometry_variance

    slopes = np.zeros((len(odometry_variance), 3))
    for j in range(3):
        step = np.zeros(3)
        step[j] = 1e-6 * k[j]
        slopes[:, j] = (rotation_noise(k + step) - rotation_noise(k - step)) / (2.0 * step[j])
    consecutive = inputs.laser_to == inputs.laser_from + 1
    laser_rotation = np.linalg.inv(inputs.laser_info[consecutive])[:, 2, 2]
    by_start = dict(zip(inputs.laser_from[consecutive].tolist(), laser_rotation.tolist()))
    laser_variance = np.array([by_start.get(i, np.inf) for i in inputs.odo_from.tolist()])
    return WheelNoiseCorrection(k, slopes, odometry_variance, laser_variance, max_relative_shift)


def summary(problem, values, observable):
    """{"applied": bool, "shift_percent": {r_l, r_r, b}} of a solved problem's correction
    (how far it moved k, or would have where it was not applied), or None without one.
    Parameters not `observable` ({key: bool}) kept their nominal value: no shift of theirs
    is reported, and with none observable there is no summary."""
    found = [c for c in problem.corrections if isinstance(c, WheelNoiseCorrection)]
    if not found or found[0].shift is None:
        return None
    shift = 100.0 * found[0].shift / values["odometry"][0]
    shift_percent = {k: float(s) for k, s in zip(CALIBRATION_KEYS[:3], shift) if observable[k]}
    return {"applied": bool(found[0].active), "shift_percent": shift_percent} if shift_percent else None
