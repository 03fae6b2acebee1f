"""A chunk of keyframes leaving the pose window, marginalised into a Gaussian on the calibration."""
from __future__ import annotations

from typing import Optional

import numpy as np

from sclam_ros.core.marginal import Gaussian
from sclam_ros.core.observability import settle_poses
from sclam_ros.online.window_graph import window_problem


def marginalise(leaving, params, calibration, nominal) -> Optional[Gaussian]:
    """What the leaving keyframes knew about the calibration: a Schur complement (None
    when they hold no odometry or no laser edge).

    H = JᵀJ and g = Jᵀr of the leaving edges alone, linearised at x₀ = (the
    current calibration, poses chained from the scan matches and settled on the chunk's
    edges with the calibration held: observability.settle_poses), over (poses, k, l); the poses are integrated out:
        Λ = H_cc − H_cp H_pp⁺ H_pc,   g' = g_c − H_cp H_pp⁺ g_p,
    a Gaussian with information Λ and information vector η = Λ c₀ − g' (its mean is
    the chunk's own Gauss-Newton optimum for c, not the current estimate: without g'
    the prior would only echo the estimate it was taken at). The pseudo-inverse keeps
    exactly the information that is there and no more.
    """
    inputs, problem = window_problem(leaving, params, calibration, nominal)
    if len(inputs.odo_from) == 0 or len(inputs.laser_from) == 0:
        return None
    problem.factors = [f for f in problem.factors if f.measurement]
    # At chained scan matches a chunk of standing still "informs" the laser yaw through
    # the matches' jitter, and that would add up in the permanent prior for good.
    problem.values = settle_poses(problem)
    system = problem.linear_system(problem.values)
    jac = system.dense_jacobian()
    hessian = jac.T @ jac
    gradient = jac.T @ system.residual
    layout = problem.layout
    calib = np.concatenate([layout.columns("odometry"), layout.columns("laser")])
    poses = np.setdiff1d(np.arange(layout.size), calib)
    h_cp = hessian[np.ix_(calib, poses)]
    h_pp_pinv = np.linalg.pinv(hessian[np.ix_(poses, poses)], hermitian=True)
    info = hessian[np.ix_(calib, calib)] - h_cp @ h_pp_pinv @ h_cp.T
    info = 0.5 * (info + info.T)
    reduced_gradient = gradient[calib] - h_cp @ h_pp_pinv @ gradient[poses]
    return Gaussian(info, info @ calibration - reduced_gradient)
