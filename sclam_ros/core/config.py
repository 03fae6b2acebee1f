"""What only a developer tunes in the core: one tree of small frozen dataclasses.

A user's robot lives in params.SclamParams; these are the model's and the solver's choices,
passed down by the functions that use them (each takes its section as a keyword argument
whose default is the value below). `CoreConfig` groups the sections, as KISS-ICP's
KISSConfig does; calibrate_keyframes takes one and hands each function its part. The
measurements behind a value are in docs/decisions/<topic>.md, linked beside it.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field


@dataclass(frozen=True)
class GraphConfig:
    """The calibration graph (graph.build_problem): priors, robust kernel, merged edges.
    Why each value: docs/decisions/graph.md."""

    # × nominal radius / base: the weak prior keeps the system well-posed where the motion
    # excites nothing, and is the unit observability measures the data's information in
    prior_sigma_relative_odometry: float = 0.25
    # m: far beyond any plausible mounting error, so no real run notices it
    prior_sigma_laser_xy: float = 2.0
    # rad: far beyond any plausible mounting error, so no real run notices it
    prior_sigma_laser_yaw: float = math.pi / 2
    # whitened σ: scale c of the scan matches' Cauchy kernel (problem.CauchyKernel); a match
    # that slid along a corridor is a gross outlier, and Cauchy's influence decays far
    # outside, so it does not drag the calibration
    laser_kernel_scale: float = 3.0
    # × nominal: radii and base are physical lengths; a step below this is rejected
    min_odometry_fraction: float = 0.1
    # m: a scan match farther than this (+ init_gate_relative × the step) from the wheels is
    # an ICP failure, not trusted for the initial poses; a nominal calibration a few % off is not
    init_gate_m: float = 0.05
    # rad: the same gate on the rotation
    init_gate_rad: float = 0.05
    # × the wheels' step: the gate grows with the motion a calibration error scales
    init_gate_relative: float = 0.2
    # × the constant-speed arc's σ: the sideways path σ of an edge composed of several
    # arcs (one per stretch between encoder samples), which follow the path's accelerations
    composed_path_sigma_scale: float = 0.5
    # lag-1 correlation of consecutive scan-match errors (a shared scan enters both with
    # opposite signs); the smaller measured magnitude, so merged covariances err large
    scan_match_lag1_correlation: float = -0.4
    # × each of k: the wheel noise correction is first order in noise²/signal²; where it
    # would move a parameter further its assumption fails and it is not applied
    # (dilution.WheelNoiseCorrection)
    max_dilution_shift: float = 0.01


@dataclass(frozen=True)
class ObservabilityConfig:
    """Which parameters the data determines (observability.Observability).
    Why each value: docs/decisions/observability.md."""

    # × the prior's information: a direction the data informs less (its σ would shrink less
    # than tenfold) is undetermined and locked
    min_information_gain: float = 100.0
    # × the prior's information per measured edge: noise of the estimated poses alone
    # informs every direction a little per edge, so a long run needs more
    min_information_gain_per_edge: float = 1.0
    # × the (whitened) prior σ: how far a locked direction may move
    lock_sigma_ratio: float = 1e-6
    # LM iterations settling the poses before judging (settle_poses): their spurious motion
    # would otherwise inform directions the robot did not excite
    settle_iterations: int = 10
    # relative cost decrease at which the settling stops
    settle_tolerance: float = 1e-6

    @property
    def unobserved_sigma_ratio(self) -> float:
        """× a parameter's prior σ: the undetermined directions leaving it this uncertain
        make it unobserved; the same tenfold as min_information_gain, per parameter."""
        return self.min_information_gain ** -0.5


@dataclass(frozen=True)
class SolverConfig:
    """Levenberg-Marquardt and the variance components around it
    (levenberg_marquardt, variance_components). Why each value: docs/decisions/solver.md."""

    # LM iterations per solve: a cap; estimator.converged_step_sigma judges the answer
    max_iterations: int = 50
    # relative cost decrease below which LM stops
    relative_tolerance: float = 1e-10
    # LM's starting damping λ: small, the start (chained scan matches) is near the optimum
    initial_lambda: float = 1e-5
    # smallest λ after accepted steps: λ·diag(H) must fall below H's smallest curvature
    # along the calibration, or a long chain of poses without loop closure (condition
    # numbers of 1e15) is damped along its flattest direction and LM creeps
    min_lambda: float = 1e-20
    # re-weighting rounds of variance component estimation
    variance_rounds: int = 6
    # |χ²/r − 1| of every group below which the scales have settled
    variance_tolerance: float = 0.02
    # (low, high) factor one round may change a scale by: far from the fixed point one
    # group can absorb another's residuals, and an unclamped step overshoots
    variance_step_clip: tuple = (0.2, 5.0)
    # (low, high) bounds of any variance scale
    variance_scale_bounds: tuple = (1e-4, 1e4)
    # × a group's rows: below this redundancy its residuals are mostly what the poses it
    # pins leave over, and it keeps its stated noise model
    min_redundancy_share: float = 0.05
    # (low, high) χ²/r of a group once the rounds are used up: outside, it is running away
    # and keeps its one-step estimate
    unsettled_ratio: tuple = (0.7, 1.4)
    # × its redundancy at the stated model: a group whose redundancy falls below this at
    # its estimated scale has come to pin the poses its residuals are measured against
    collapsed_redundancy: float = 0.5

    def lm_options(self) -> dict:
        """levenberg_marquardt's keyword arguments."""
        return {"max_iterations": self.max_iterations,
                "relative_tolerance": self.relative_tolerance,
                "initial_lambda": self.initial_lambda, "min_lambda": self.min_lambda}


@dataclass(frozen=True)
class WiringConfig:
    """Do the encoders and the laser agree on the motion (wiring.wiring_problem).
    Why each value: docs/decisions/wiring.md."""

    # score gap (a sum of two correlations, 2 = perfect) by which another wiring must beat
    # the configured one: one reversed axis at −0.5 already counts 1, noise ~0.1
    min_score_gap: float = 0.8
    # score: wirings within this of the best cannot be told apart by the motion
    tie: float = 0.2
    # scan pairs: fewer decide nothing
    min_pairs: int = 20
    # × the other axis' travel: an axis the robot moved less along decides no sign
    min_axis_share: float = 0.02
    # m (turning counted as θ·b/2): an axis with less travel in all decides no sign
    min_axis_travel: float = 0.2


@dataclass(frozen=True)
class EstimatorConfig:
    """The batch calibration around the solve (estimator.calibrate_keyframes).
    Why each value: docs/decisions/solver.md."""

    # scans paired with encoder data: fewer cannot support a calibration
    min_keyframes: int = 10
    # × each parameter's σ: converged when a further Gauss-Newton step moves none by more,
    # whatever the iteration count (long recordings reach LM's cap while settled)
    converged_step_sigma: float = 0.1


@dataclass(frozen=True)
class MocapConfig:
    """Calibration against motion capture (mocap.py)."""

    # (m, m, rad): noise shape of one mocap relative motion; variance components estimate
    # its scale
    motion_sigma: tuple = (0.001, 0.001, 0.005)


@dataclass(frozen=True)
class LinearConfig:
    """How the normal equations are stored and factorised (problem.Problem,
    linear.LinearSolver). Why each value: docs/decisions/solver.md."""

    # columns: up to this many the linear system is dense, where scipy.sparse's
    # constructors cost more than the dense BLAS work (the online window's size)
    dense_max_columns: int = 400
    # scalar columns (30 poses): a wider pose band is factorised by sparse LU, not banded
    # Cholesky
    max_bandwidth: int = 90
    # iterative-refinement solves after the banded Schur solve, recovering the digits the
    # Schur complement of well-determined parameters loses
    refinement_steps: int = 3
    # unit columns per block of solves on inverse_at's sparse-LU path: bounds each block's
    # memory
    trace_chunk: int = 256


@dataclass(frozen=True)
class CoreConfig:
    """All of the core's developer tuning, one section per job."""

    graph: GraphConfig = field(default_factory=GraphConfig)
    observability: ObservabilityConfig = field(default_factory=ObservabilityConfig)
    solver: SolverConfig = field(default_factory=SolverConfig)
    wiring: WiringConfig = field(default_factory=WiringConfig)
    estimator: EstimatorConfig = field(default_factory=EstimatorConfig)
    linear: LinearConfig = field(default_factory=LinearConfig)
    mocap: MocapConfig = field(default_factory=MocapConfig)
