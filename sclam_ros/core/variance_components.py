"""Noise scales estimated from the residuals: variance component estimation.

Each factor type's stated covariance is only a model shape; solve_with_variance_components
estimates each group's overall scale from its χ² over its redundancy and re-solves until
the scales settle, keeping a group that runs away at its one-step estimate;
component_scales does the same per component of one factor. settle_corrections re-solves
where a cost correction (dilution) no longer holds at the size the residuals show.
"""
from __future__ import annotations

import numpy as np

from sclam_ros.core.config import SolverConfig
from sclam_ros.core.covariance import Influence, absorbed_trace, factorize_information, redundancy_by_factor
from sclam_ros.core.levenberg_marquardt import levenberg_marquardt
from sclam_ros.core.problem import Problem, SolverResult, Values


def solve_with_variance_components(problem: Problem, progress=None,
                                   config: SolverConfig = SolverConfig()):
    """LM, then iterated variance component estimation (Förstner / Helmert type).

    Each factor type's stated covariance is only a model shape; its overall scale is
    estimated from the data as σ̂²_g = χ²_g / r_g, with r_g the group's redundancy. The
    groups are re-weighted and the problem re-solved until the factors settle (a fixed
    point where every group's χ² matches its redundancy, within config.variance_tolerance,
    for at most config.variance_rounds). Returns the final result and the variance scales,
    which `problem.scales` also holds afterwards.
    """
    lm_options = config.lm_options()
    result = levenberg_marquardt(problem, progress=progress, **lm_options)
    first_round = None  # the scales after one round (the one-step estimate)
    first_redundancy = None  # the redundancies that round measured them with
    rounds_used_up = False
    step_low, step_high = config.variance_step_clip
    scale_low, scale_high = config.variance_scale_bounds
    for _ in range(config.variance_rounds):
        ratios, redundancy = _variance_ratios(problem, result.values, config)
        for name, ratio in ratios.items():
            # Clamp a round's step: far from the fixed point one group can absorb the
            # other's residuals, and an unclamped step overshoots.
            problem.scales[name] = float(np.clip(
                problem.scales.get(name, 1.0) * np.clip(ratio, step_low, step_high),
                scale_low, scale_high))
        if first_round is None:
            first_round = {name: problem.scales[name] for name in ratios}
            first_redundancy = redundancy
        if all(abs(ratio - 1.0) <= config.variance_tolerance for ratio in ratios.values()):
            break
        problem.values = result.values
        result = levenberg_marquardt(problem, progress=progress, **lm_options)
    else:
        rounds_used_up = True
        ratios, redundancy = _variance_ratios(problem, result.values, config)
    # A group still far from its fixed point when the rounds are used up is running away,
    # not settling. With an odometry model that misfits (1 Hz encoders), the scan matches'
    # scale falls round after round far below their true errors: the poses follow the
    # matches ever closer and the residuals left to them shrink with their scale. So is
    # one that runs so far that it pins the poses and loses the redundancy to measure its
    # own noise (no ratio left), or whose redundancy collapses on the way (a synthetic
    # street, test_solver: the odometry's scale then ends well below its true value).
    # Such a group keeps its one-step estimate, which errs on the safe side.
    def is_running_away(name):
        if name in ratios:
            return not config.unsettled_ratio[0] <= ratios[name] <= config.unsettled_ratio[1]
        return (rounds_used_up
                or redundancy[name] < config.collapsed_redundancy * first_redundancy[name])

    running_away = [name for name in first_round if is_running_away(name)]
    if running_away:
        problem.scales.update({name: first_round[name] for name in running_away})
        problem.values = result.values
        result = levenberg_marquardt(problem, progress=progress, **lm_options)
    problem.values = result.values
    result = settle_corrections(
        problem, result, lambda: levenberg_marquardt(problem, progress=progress, **lm_options))
    return result, dict(problem.scales)


def settle_corrections(problem: Problem, result: SolverResult, solve) -> SolverResult:
    """Each active correction, told the linear system at the solution (correction.observe:
    what the residuals say of its size), and its move of the solution, −H⁻¹ (½ its
    gradient) over its block, kept in `correction.shift`; those that do not hold at that
    size (correction.holds) are deactivated. Where any changed, the problem is solved
    again with `solve()`. Returns the final result."""
    if not any(c.active for c in problem.corrections):
        return result
    system, _, lu = factorize_information(problem, result.values, result.system)
    changed = False
    for correction in problem.corrections:
        if not correction.active:
            continue
        before = correction.term(result.values, problem.scales)[1]
        correction.observe(system, lu)
        _, gradient = correction.term(result.values, problem.scales)
        offset = problem.correction_offset(correction, gradient)
        if offset is None:  # its block is held: it moves nothing
            correction.shift = np.zeros(len(gradient))
            continue
        correction.shift = -lu.solve(offset)[problem.layout.columns(correction.block)]
        changed |= not np.allclose(gradient, before, rtol=1e-3, atol=0.0)
        if not correction.holds(correction.shift, result.values):
            correction.active, changed = False, True
    if not changed:
        return result
    problem.values = result.values
    result = solve()
    problem.values = result.values
    return result


def _variance_ratios(problem: Problem, values: Values, config: SolverConfig) -> tuple:
    """(χ²_g / r_g of each measurement group whose noise the data can reveal, r_g of every
    group). A group keeps its stated noise model where its redundancy is below
    config.min_redundancy_share of its size."""
    redundancy, _ = redundancy_by_factor(problem, values)
    measured = {f.name for f in problem.factors if f.measurement}
    ratios = {}
    for name, (r, chi2) in redundancy.items():
        # Priors are statements, not measurements; and a group that determines its
        # own variables (no redundancy) has no say on its noise. Where a group's
        # redundancy is a small share of its size, its residuals are mostly what the
        # poses it pins leave over, and another group's misfit moves them as much as its
        # own noise does. Among bare corridors, where a short-range laser fixes little
        # along them, the odometry keeps 6-15 % of its size and its scale still settles
        # near its true value (test_variance_components); held at the stated model
        # (scale 1) its σ would be 1.6 times too large.
        dim = sum(len(f) * f.edge_dim for f in problem.factors if f.name == name)
        if name in measured and r >= max(3.0, config.min_redundancy_share * dim):
            ratios[name] = float(chi2 / r)
    return ratios, {name: r for name, (r, _) in redundancy.items()}


def component_scales(influence: Influence, start: int, stop: int, d: int,
                     config: SolverConfig = SolverConfig()) -> np.ndarray:
    """Noise scale per component (d,) of a factor's whitened rows start:stop: each
    component's squared residuals over its redundancy, n − tr(J_c H⁻¹ J_cᵀ), where that is
    at least config.min_redundancy_share of its n rows; else 1.

    Variance components give a factor one scale; the shape of its covariance is the stated
    model's. The odometry's sideways part has its own parameter (lateral_noise), and the
    simulator's robots slip sideways less than the default states: at the truth their
    whitened sideways errors have a fraction of the mean square of the other components
    (docs/decisions/error_structure.md). The model's σ then overstates what
    rests on the sideways part: the laser yaw, taken from the direction the laser moves
    in while the odometry says the robot moves straight ahead. A component the other
    edges absorb (too little redundancy of its own) keeps the factor's scale."""
    jacobian = influence.system.jacobian[start:stop]
    residual = influence.system.residual[start:stop].reshape(-1, d)
    scales = np.ones(d)
    for c in range(d):
        rows = jacobian[c::d]
        n = rows.shape[0]
        redundancy = n - absorbed_trace(rows, influence.lu)
        if redundancy >= config.min_redundancy_share * n and redundancy > 0:
            scales[c] = float(np.sum(residual[:, c] ** 2)) / redundancy
    return scales
