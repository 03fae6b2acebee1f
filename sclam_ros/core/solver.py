"""Re-exports of the modules solver.py is split into, until every importer uses them."""
from sclam_ros.core.correlated_covariance import (  # noqa: F401
    chain_correlated_covariance, chained_edges, lag1_correlation, sandwich_covariance)
from sclam_ros.core.covariance import (  # noqa: F401
    Influence, _inverse_columns, absorbed_trace, factorize_information, marginal_covariance,
    redundancy_by_factor, remaining_step)
from sclam_ros.core.levenberg_marquardt import (  # noqa: F401
    _predicted_decrease, _solve_damped, _system_or_none, levenberg_marquardt)
from sclam_ros.core.linear import TRACE_CHUNK, LinearSolver, _banded_inverse, _normal_equations  # noqa: F401
from sclam_ros.core.problem import (  # noqa: F401
    DENSE_MAX_COLUMNS, CauchyKernel, HuberKernel, Layout, Problem, SolverResult, System,
    TrivialKernel, Values)
from sclam_ros.core.variance_components import (  # noqa: F401
    COLLAPSED_REDUNDANCY, MIN_REDUNDANCY_SHARE, UNSETTLED_RATIO, _variance_ratios,
    component_scales, settle_corrections, solve_with_variance_components)
