"""Generic sparse Levenberg-Marquardt over named variable blocks.

The solver never special-cases a factor: it linearises every factor, whitens with the
factor's square-root information, applies the factor type's robust kernel as IRLS weights,
stacks one Jacobian (sparse; dense for small problems such as the online window), and
solves (H + λ·diag(H)) Δ = −g (LinearSolver: banded Cholesky with a Schur complement for
the global columns, a sparse LU when the band is wide, one dense Cholesky when small). The
update y ← y ⊕ Δ is additive with angles wrapped, matching factors.py's Jacobians.

Gauge: scan matching and odometry only constrain relative motion, so the first pose is
held fixed (its columns are removed), which is the standard choice for a pose graph.
"""
from __future__ import annotations

import functools
import math
import time
from dataclasses import dataclass, field
from typing import Optional

import numpy as np
import scipy.linalg
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from sclam_ros.core import se2

# --- robust kernels ----------------------------------------------------------------------
# ρ(s) of the squared whitened residual norm s; the IRLS weight is ρ'(s).


@dataclass(frozen=True)
class TrivialKernel:
    def rho(self, s):
        return s

    def weight(self, s):
        return np.ones_like(s)


@dataclass(frozen=True)
class HuberKernel:
    """Quadratic within `delta` whitened σ, linear beyond: outlier scan matches lose pull."""

    delta: float = 3.0

    def rho(self, s):
        d2 = self.delta**2
        return np.where(s <= d2, s, 2.0 * self.delta * np.sqrt(s) - d2)

    def weight(self, s):
        return np.where(s <= self.delta**2, 1.0, self.delta / np.sqrt(np.maximum(s, 1e-300)))


@dataclass(frozen=True)
class CauchyKernel:
    c: float = 3.0

    def rho(self, s):
        return self.c**2 * np.log1p(s / self.c**2)

    def weight(self, s):
        return 1.0 / (1.0 + s / self.c**2)


# --- values -------------------------------------------------------------------------------


class Values(dict):
    """Named blocks of variables, each an array (count, dim), plus which columns are angles."""

    def __init__(self, blocks=None, angular=None, lower=None):
        super().__init__()
        self.angular = {}
        self.lower = {}
        for name, value in (blocks or {}).items():
            self.add(name, value, (angular or {}).get(name), (lower or {}).get(name))

    def add(self, name, value, angular=None, lower=None):
        """A block; `lower` bounds its columns from below (a step crossing it is rejected)."""
        value = np.array(value, float, ndmin=2)
        self[name] = value
        if angular is None:
            angular = np.zeros(value.shape[1], bool)
        self.angular[name] = np.asarray(angular, bool)
        self.lower[name] = None if lower is None else np.asarray(lower, float)

    def within_bounds(self) -> bool:
        return all(low is None or np.all(self[name] > low) for name, low in self.lower.items())

    def copy(self):
        out = Values()
        for name, value in self.items():
            out.add(name, value.copy(), self.angular[name], self.lower[name])
        return out

    def retract(self, layout, delta):
        """y ⊕ Δ for the free rows described by `layout`."""
        out = self.copy()
        for name, (rows, offset) in layout.blocks.items():
            dim = self[name].shape[1]
            out[name][rows] += delta[offset : offset + len(rows) * dim].reshape(-1, dim)
            ang = self.angular[name]
            if ang.any():
                out[name][:, ang] = se2.wrap_angle(out[name][:, ang])
        return out


@dataclass
class Layout:
    """Where each free variable row lives in the column vector of the linear system."""

    blocks: dict  # name -> (free row indices, column offset)
    column_of_row: dict  # name -> (count,) first column of each row, -1 when fixed
    dims: dict  # name -> variables per row
    size: int

    @classmethod
    def build(cls, values: Values, fixed: dict):
        blocks, column_of_row, dims, offset = {}, {}, {}, 0
        for name, value in values.items():
            count, dim = value.shape
            mask = np.ones(count, bool)
            mask[np.asarray(fixed.get(name, []), int)] = False
            rows = np.flatnonzero(mask)
            cols = np.full(count, -1, int)
            cols[rows] = offset + dim * np.arange(len(rows))
            blocks[name] = (rows, offset)
            column_of_row[name] = cols
            dims[name] = dim
            offset += dim * len(rows)
        return cls(blocks, column_of_row, dims, offset)

    def columns(self, name):
        """All column indices of a block's free rows, in row-major order."""
        rows, offset = self.blocks[name]
        return offset + np.arange(len(rows) * self.dims[name])


# Up to this many columns the linear system is dense: built as sparse matrices, the online
# window (~45-75 poses, 141-231 columns) spent ~3 ms of its ~10 ms solve in scipy.sparse's
# constructors and conversions (cProfile), more than the dense BLAS work costs.
DENSE_MAX_COLUMNS = 400


@dataclass
class System:
    """The whitened, robustly weighted linear system at one linearisation point."""

    jacobian: "sp.csr_matrix | np.ndarray"  # dense up to DENSE_MAX_COLUMNS columns
    residual: np.ndarray  # whitened and weighted
    cost: float  # Σ ρ(s) over all edges (the robust cost)
    per_factor: dict  # factor name -> dict(cost, chi2, count, dim, weights, squared_residual_sum)
    row_ranges: list  # (factor name, first row, end row) in stacking order
    normal: Optional[tuple] = None  # (H, g) once _normal_equations has formed them
    # ½ ∂/∂y of the cost corrections (Problem.corrections), added to g = Jᵀr
    gradient_offset: Optional[np.ndarray] = None

    def dense_jacobian(self) -> np.ndarray:
        return self.jacobian.toarray() if sp.issparse(self.jacobian) else self.jacobian


@dataclass
class SolverResult:
    values: Values
    iterations: int
    converged: bool
    initial_cost: float
    final_cost: float
    history: list = field(default_factory=list)
    seconds: float = 0.0
    system: Optional[System] = None  # the linear system at `values` (for covariances)


class Problem:
    """Factors + initial values + which rows are fixed + a robust kernel per factor name."""

    def __init__(self, values: Values, factors, fixed=None, kernels=None, scales=None,
                 corrections=()):
        self.values = values
        self.factors = list(factors)
        # Terms of the cost that are not squared residuals, linear in one block's first
        # row: `block`, term(values, scales) -> (cost, gradient); e.g.
        # dilution.WheelNoiseCorrection. They move the minimum, not the curvature H.
        self.corrections = list(corrections)
        self.fixed = fixed or {}
        self.kernels = kernels or {}
        # Variance scale per factor name: the factor's covariance is multiplied by it
        # (estimated from the residuals by variance component estimation).
        self.scales = dict(scales or {})
        self.layout = Layout.build(values, self.fixed)
        # Columns of the first block (the poses) form the banded part of H.
        first = next(iter(values))
        self.banded_size = len(self.layout.blocks[first][0]) * self.layout.dims[first]

    def kernel(self, factor):
        return self.kernels.get(factor.name, TrivialKernel())

    def linear_system(self, values: Values) -> System:
        rows_all, cols_all, data_all, residuals = [], [], [], []
        total_cost, per_factor, row_ranges, row0 = 0.0, {}, [], 0
        for factor in self.factors:
            if len(factor) == 0:
                continue
            lin = factor.linearize(values)
            scale = self.scales.get(factor.name, 1.0)
            whitened = np.einsum("mij,mj->mi", lin.sqrt_information, lin.residual) / math.sqrt(scale)
            squared = np.einsum("mi,mi->m", whitened, whitened)
            kernel = self.kernel(factor)
            weight = kernel.weight(squared)
            sqrt_w = np.sqrt(weight)
            cost = float(np.sum(kernel.rho(squared)))
            total_cost += cost
            stats = per_factor.setdefault(
                factor.name, {"cost": 0.0, "chi2": 0.0, "count": 0, "dim": 0, "weights": [],
                              "squared_residual_sum": 0.0}
            )
            stats["cost"] += cost
            stats["chi2"] += float(np.sum(weight * squared))
            stats["count"] += len(factor)
            stats["dim"] += len(factor) * lin.residual.shape[1]
            stats["weights"].append(weight)
            if factor.measurement:  # per component, raw: for estimator.residual_rms
                stats["squared_residual_sum"] = (stats["squared_residual_sum"]
                                                 + np.sum(lin.residual**2, axis=0))
            m, d = lin.residual.shape
            residuals.append((whitened * sqrt_w[:, None]).ravel())
            edge_rows = row0 + np.arange(m * d).reshape(m, d)
            for jb in lin.blocks:
                cols0 = self.layout.column_of_row[jb.block][jb.rows]  # (m,)
                keep = cols0 >= 0
                if not keep.any():
                    continue
                jac = np.einsum("mij,mjk->mik", lin.sqrt_information, jb.jacobian)
                jac = jac * (sqrt_w / math.sqrt(scale))[:, None, None]
                dim = jac.shape[2]
                r = np.broadcast_to(edge_rows[:, :, None], (m, d, dim))[keep]
                c = (cols0[:, None, None] + np.arange(dim)[None, None, :])
                c = np.broadcast_to(c, (m, d, dim))[keep]
                rows_all.append(r.ravel())
                cols_all.append(c.ravel())
                data_all.append(jac[keep].ravel())
            row_ranges.append((factor.name, row0, row0 + m * d))
            row0 += m * d
        rows, cols, data = (np.concatenate(rows_all), np.concatenate(cols_all),
                            np.concatenate(data_all))
        if self.layout.size <= DENSE_MAX_COLUMNS:
            # bincount sums entries that two blocks put in the same place (np.add.at does
            # too, at 0.7 ms a call for this size).
            jacobian = np.bincount(rows * self.layout.size + cols, data,
                                   row0 * self.layout.size).reshape(row0, self.layout.size)
        else:
            jacobian = sp.csr_matrix((data, (rows, cols)), shape=(row0, self.layout.size))
        correction, offset = self.cost_correction(values)
        return System(jacobian, np.concatenate(residuals), total_cost + correction, per_factor,
                      row_ranges, gradient_offset=offset)

    def cost_correction(self, values: Values):
        """Σ of the corrections' costs and ½ their gradient over the columns (the solver's
        g is ½ ∂cost/∂y), or (0, None) when there is none."""
        total, offset = 0.0, None
        for correction in self.corrections:
            if not correction.active:
                continue
            cost, gradient = correction.term(values, self.scales)
            total += cost
            part = self.correction_offset(correction, gradient)
            if part is not None:
                offset = part if offset is None else offset + part
        return total, offset

    def correction_offset(self, correction, gradient) -> Optional[np.ndarray]:
        """½ `gradient` at the columns of the correction's block (its first row), zero
        elsewhere; None where that row is held."""
        first = self.layout.column_of_row[correction.block][0]
        if first < 0:
            return None
        offset = np.zeros(self.layout.size)
        offset[first:first + len(gradient)] = 0.5 * np.asarray(gradient)
        return offset

    def cost(self, values: Values) -> float:
        total = 0.0
        for factor in self.factors:
            if len(factor) == 0:
                continue
            lin = factor.linearize(values)
            scale = self.scales.get(factor.name, 1.0)
            whitened = np.einsum("mij,mj->mi", lin.sqrt_information, lin.residual)
            squared = np.einsum("mi,mi->m", whitened, whitened) / scale
            total += float(np.sum(self.kernel(factor).rho(squared)))
        return total + self.cost_correction(values)[0]


# Unit columns per block of solves on LinearSolver.inverse_at's sparse-LU path (bounds the
# memory of each block).
TRACE_CHUNK = 256


class LinearSolver:
    """Solves H x = r for the SPD normal matrix of a pose graph.

    The pose block of H is banded (edges join poses a few keyframes apart) and the rest
    (calibration, effect parameters) is a handful of dense global columns. Banded
    Cholesky on the poses plus a dense Schur complement for the globals costs O(n·w²),
    linear in the length of the recording; a general sparse LU (the fallback, used when
    the band is wide, e.g. with loop closures) grows faster.
    """

    MAX_BANDWIDTH = 90  # scalar columns; 30 poses

    def __init__(self, hessian, banded_size: int):
        self.n = banded_size
        self._lu = None
        self._dense = None
        if not sp.issparse(hessian):
            # Up to DENSE_MAX_COLUMNS, one dense Cholesky of the whole H: the online
            # window factors in ~0.1 ms, where building the banded split and its sparse
            # slices cost ~1 ms of Python per factorisation.
            self._dense = scipy.linalg.cho_factor(hessian)
            return
        hessian = hessian.tocsc()
        self._hessian = hessian
        coo = hessian[: self.n, : self.n].tocoo()
        upper = coo.col >= coo.row
        bandwidth = int(np.max(coo.col[upper] - coo.row[upper], initial=0))
        if self.n == 0 or bandwidth > self.MAX_BANDWIDTH:
            self._lu = spla.splu(hessian)
            return
        bands = np.zeros((bandwidth + 1, self.n))
        bands[bandwidth + coo.row[upper] - coo.col[upper], coo.col[upper]] = coo.data[upper]
        self._chol = scipy.linalg.cholesky_banded(bands, lower=False)
        coupling = hessian[: self.n, self.n :].toarray()
        self._a_inv_b = self._solve_banded(coupling)
        schur = hessian[self.n :, self.n :].toarray() - coupling.T @ self._a_inv_b
        self._coupling = coupling
        self._schur = scipy.linalg.cho_factor(schur) if schur.size else None

    def _solve_banded(self, rhs):
        return scipy.linalg.cho_solve_banded((self._chol, False), rhs)

    REFINEMENT_STEPS = 3

    def solve(self, rhs):
        if self._dense is not None:
            return scipy.linalg.cho_solve(self._dense, rhs)
        if self._lu is not None:
            return self._lu.solve(rhs)
        # The Schur complement C − BᵀA⁻¹B of well-determined calibration parameters is a
        # small difference of large numbers and loses digits; iterative refinement
        # against the exact H recovers them (each step costs one more cheap solve).
        x = self._solve_once(rhs)
        for _ in range(self.REFINEMENT_STEPS):
            x = x + self._solve_once(rhs - self._hessian @ x)
        return x

    def inverse_at(self, rows, cols) -> np.ndarray:
        """(H⁻¹)[rows[k], cols[k]] for index pairs within H's own pattern (the band of the
        poses, the global columns): exact, and linear in the recording's length on the
        banded path, where H⁻¹ itself would be dense. The dense path (the online window)
        inverts H; the sparse LU (wide bands) solves for the unit columns needed."""
        rows, cols = np.asarray(rows, int), np.asarray(cols, int)
        if self._dense is not None:
            return self._dense_inverse[rows, cols]
        if self._lu is not None:
            out = np.empty(len(rows))
            needed = np.unique(cols)
            for start in range(0, len(needed), TRACE_CHUNK):
                chunk = needed[start:start + TRACE_CHUNK]
                unit = np.zeros((self._hessian.shape[0], len(chunk)))
                unit[chunk, np.arange(len(chunk))] = 1.0
                solved = self.solve(unit)
                take = np.isin(cols, chunk)
                out[take] = solved[rows[take], np.searchsorted(chunk, cols[take])]
            return out
        band, w_s, schur_inv = self._banded_inverse_parts
        n = self.n
        lo, hi = np.minimum(rows, cols), np.maximum(rows, cols)
        out = np.zeros(len(rows))
        poses = hi < n
        out[poses] = band[hi[poses] - lo[poses], lo[poses]]
        if schur_inv is None:
            return out
        out[poses] += np.einsum("kg,kg->k", w_s[lo[poses]], self._a_inv_b[hi[poses]])
        mixed = (lo < n) & (hi >= n)
        out[mixed] = -w_s[lo[mixed], hi[mixed] - n]
        both = lo >= n
        out[both] = schur_inv[lo[both] - n, hi[both] - n]
        return out

    # Computed once per factorisation: redundancy_by_factor asks inverse_at once per
    # factor group, every variance-component round.
    @functools.cached_property
    def _dense_inverse(self) -> np.ndarray:
        return scipy.linalg.cho_solve(self._dense, np.eye(len(self._dense[0])))

    @functools.cached_property
    def _banded_inverse_parts(self):
        """(band of A⁻¹, W S⁻¹, S⁻¹) of H = [[A, B], [Bᵀ, C]], A banded, W = A⁻¹B,
        S = C − BᵀW (the last two None without globals), from which
        H⁻¹ = [[A⁻¹ + W S⁻¹ Wᵀ, −W S⁻¹], [−S⁻¹ Wᵀ, S⁻¹]]."""
        band = _banded_inverse(self._chol)  # band[d, i] = (A⁻¹)[i, i + d]
        if self._schur is None:
            return band, None, None
        schur_inv = scipy.linalg.cho_solve(self._schur, np.eye(len(self._schur[0])))
        return band, self._a_inv_b @ schur_inv, schur_inv

    def _solve_once(self, rhs):
        top, bottom = rhs[: self.n], rhs[self.n :]
        y = self._solve_banded(top)
        if self._schur is None:
            return y
        x_global = scipy.linalg.cho_solve(self._schur, bottom - self._coupling.T @ y)
        return np.concatenate([y - self._a_inv_b @ x_global, x_global])


def _banded_inverse(upper) -> np.ndarray:
    """The band of A⁻¹ from A's banded Cholesky factor U (A = UᵀU, scipy's upper banded
    storage: upper[w + i − j, j] = U[i, j]), as band[d, i] = (A⁻¹)[i, i + d], d = 0..w.

    Takahashi's recurrence: U Z = U⁻ᵀ is lower triangular with diagonal 1/U_ii, so for
    j ≥ i, Z_ij = (δ_ij / U_ii − Σ_{k=i+1..i+w} U_ik Z_kj) / U_ii, which needs only entries
    of Z within the band below and right of i: one pass from the last row up, O(n·w²)."""
    w, n = upper.shape[0] - 1, upper.shape[1]
    band = np.zeros((w + 1, n))
    window = np.zeros((w + 1, w + 1))  # Z[i .. i+w, i .. i+w], entries past n left 0
    for i in range(n - 1, -1, -1):
        m = min(w, n - 1 - i)
        diagonal = upper[w, i]
        u = upper[w - np.arange(1, m + 1), i + np.arange(1, m + 1)]  # U[i, i+1 .. i+m]
        window[1:, 1:] = window[:-1, :-1]
        row = -(u @ window[1:m + 1, 1:m + 1]) / diagonal
        window[0, 1:m + 1] = window[1:m + 1, 0] = row
        window[0, 0] = (1.0 / diagonal - u @ row) / diagonal
        band[: m + 1, i] = window[0, : m + 1]
    return band


def _solve_damped(problem, hessian, gradient, damping):
    """Δ of (H + diag(damping)) Δ = −g, or None when the damped matrix is still not
    positive definite."""
    damped = hessian + (sp.diags(damping) if sp.issparse(hessian) else np.diag(damping))
    try:
        delta = LinearSolver(damped, problem.banded_size).solve(-gradient)
    except (np.linalg.LinAlgError, RuntimeError, ValueError):
        return None
    return delta if np.all(np.isfinite(delta)) else None


def _system_or_none(problem, values):
    """The linear system at `values`, or None where the model is not defined (a step so
    long that a noise model turned singular, e.g. a wheel base through zero): such a step
    is simply rejected. Evaluating a candidate step by its whole linear system, not its
    cost alone, costs a little more for a rejected step and saves the re-linearisation of
    every accepted one."""
    if not values.within_bounds():
        return None
    try:
        system = problem.linear_system(values)
    except (np.linalg.LinAlgError, FloatingPointError, ValueError):
        return None
    return system if math.isfinite(system.cost) else None


def _normal_equations(system: System):
    """(H, g) = (JᵀJ, Jᵀr), formed once per system (LM's last one is the covariance's)."""
    if system.normal is None:
        jac = system.jacobian
        hessian = jac.T @ jac
        hessian = hessian.tocsc() if sp.issparse(hessian) else hessian
        gradient = jac.T @ system.residual
        if system.gradient_offset is not None:
            gradient = gradient + system.gradient_offset
        system.normal = hessian, gradient
    return system.normal


def _predicted_decrease(hessian, gradient, delta) -> float:
    """Cost decrease the linearised model promises for Δ: ‖r‖² − ‖r + JΔ‖²."""
    return float(-(2.0 * gradient @ delta + delta @ (hessian @ delta)))


def levenberg_marquardt(
    problem: Problem,
    max_iterations: int = 50,
    relative_tolerance: float = 1e-10,
    initial_lambda: float = 1e-5,
    progress=None,
) -> SolverResult:
    """Minimise Σ ρ(‖L e‖²) with Marquardt's diagonal damping and an adaptive λ."""
    start = time.perf_counter()
    values = problem.values
    system = problem.linear_system(values)
    initial_cost = cost = system.cost
    lam, history, converged = initial_lambda, [cost], False
    iteration = 0
    for iteration in range(1, max_iterations + 1):
        hessian, gradient = _normal_equations(system)
        diag = np.maximum(hessian.diagonal(), 1e-9)

        def damped_step(lam):
            return _solve_damped(problem, hessian, gradient, lam * diag)

        accepted = False
        delta = damped_step(lam)
        # Even the model's own step gains less than the tolerance: at a minimum. Without
        # this stop a solve started at its optimum (a warm start) raised λ to 1e10 in 15
        # rejected steps, each a solve and a cost evaluation.
        at_minimum = delta is not None and (
            _predicted_decrease(hessian, gradient, delta) < relative_tolerance * cost)
        while not at_minimum and lam < 1e10:
            if delta is not None:
                candidate = values.retract(problem.layout, delta)
                candidate_system = _system_or_none(problem, candidate)
                if candidate_system is not None and candidate_system.cost < cost:
                    accepted = True
                    break
            lam *= 10.0
            delta = damped_step(lam) if lam < 1e10 else None
        if not accepted:
            converged = True  # at a minimum: no step gains enough, or none descends at all
            break
        new_cost = candidate_system.cost
        improvement = (cost - new_cost) / max(cost, 1e-300)
        values, system, cost = candidate, candidate_system, new_cost
        lam = max(lam / 10.0, 1e-12)
        history.append(cost)
        if progress is not None:
            progress(iteration, cost)
        if improvement < relative_tolerance:
            converged = True
            break
    return SolverResult(
        values, iteration, converged, initial_cost, cost, history, time.perf_counter() - start,
        system,
    )


def factorize_information(problem: Problem, values: Values, system: Optional[System] = None):
    """Factorisation of the (robustly weighted) information matrix H = JᵀJ at `values`
    (`system`: the linear system at `values` if already at hand, e.g. SolverResult.system)."""
    if system is None:
        system = problem.linear_system(values)
    hessian, _ = _normal_equations(system)
    return system, hessian, LinearSolver(hessian, problem.banded_size)


def remaining_step(problem: Problem, values: Values, blocks):
    """The Gauss-Newton step Δ = −H⁻¹g still ahead at `values`, for the named blocks' free
    variables, and the factorisation of H (for marginal_covariance's `lu`). How far a
    continued solve would move the parameters, whatever stopped the iterations."""
    system, _, lu = factorize_information(problem, values)
    _, gradient = _normal_equations(system)
    cols = np.concatenate([problem.layout.columns(name) for name in blocks])
    return -lu.solve(gradient)[cols], lu


def marginal_covariance(problem: Problem, values: Values, blocks, lu=None):
    """Joint marginal covariance of the named blocks' free variables, (p, p).

    The marginal of a Gaussian is the corresponding block of H⁻¹: solve H X = E for the p
    unit columns E of those variables with one factorisation.
    """
    if lu is None:
        _, _, lu = factorize_information(problem, values)
    cols, solved = _inverse_columns(problem, blocks, lu)
    cov = solved[cols]
    return 0.5 * (cov + cov.T)


def _inverse_columns(problem: Problem, blocks, lu):
    """(columns of the named blocks' free variables, H⁻¹ E: those columns of H⁻¹), one
    solve with the factorisation `lu` for all of them."""
    cols = np.concatenate([problem.layout.columns(name) for name in blocks])
    unit = np.zeros((problem.layout.size, len(cols)))
    unit[cols, np.arange(len(cols))] = 1.0
    return cols, lu.solve(unit)


def absorbed_trace(rows, lu) -> float:
    """tr(J H⁻¹ Jᵀ) of whitened Jacobian rows J (sparse or dense), `lu` H's LinearSolver:
    the part of their expected χ² the variables absorb. Exact: Σ (JᵀJ)_ij (H⁻¹)_ij over
    JᵀJ's pattern, within H's (LinearSolver.inverse_at). Hutchinson's stochastic estimate
    with 40 probes is within 1 % indoors but scattered from −326 to +703 against exact
    values of 151-227 on an outdoor drive: there the poses along a street are a long
    random walk of the odometry, H⁻¹ couples them all, and the probes' cross terms swamp
    the trace."""
    rows = rows if sp.issparse(rows) else sp.csr_matrix(np.asarray(rows))
    gram = (rows.T @ rows).tocoo()
    return float(gram.data @ lu.inverse_at(gram.row, gram.col))


def redundancy_by_factor(problem: Problem, values: Values):
    """Redundancy (observations minus the share of parameters each factor type determines).

    For variance component estimation: the expected χ² of factor group g at the optimum
    is r_g = n_g − tr(J_g H⁻¹ J_gᵀ) (absorbed_trace).
    """
    system, _, lu = factorize_information(problem, values)
    traces = {}
    for name, start, stop in system.row_ranges:
        traces[name] = traces.get(name, 0.0) + absorbed_trace(system.jacobian[start:stop], lu)
    out = {
        name: (stats["dim"] - traces[name], stats["chi2"])
        for name, stats in system.per_factor.items()
    }
    return out, lu


# A group keeps its stated noise model where its redundancy is below this share of its size
# (_variance_ratios).
MIN_REDUNDANCY_SHARE = 0.05
# A group whose χ²/r is outside this band once the rounds are used up has not settled
# (solve_with_variance_components). Groups that converge slowly end within 0.9-1.1.
UNSETTLED_RATIO = (0.7, 1.4)
# A group whose redundancy at its estimated scale is below this fraction of its redundancy
# at the stated model has come to pin the poses its residuals are measured against.
COLLAPSED_REDUNDANCY = 0.5


def solve_with_variance_components(problem: Problem, rounds: int = 6, tolerance: float = 0.02,
                                   progress=None, **lm_options):
    """LM, then iterated variance component estimation (Förstner / Helmert type).

    Each factor type's stated covariance is only a model shape; its overall scale is
    estimated from the data as σ̂²_g = χ²_g / r_g, with r_g the group's redundancy. The
    groups are re-weighted and the problem re-solved until the factors settle (a fixed
    point where every group's χ² matches its redundancy). Returns the final result and the
    variance scales, which `problem.scales` also holds afterwards.
    """
    result = levenberg_marquardt(problem, progress=progress, **lm_options)
    first_round = None  # the scales after one round (the one-step estimate)
    first_redundancy = None  # the redundancies that round measured them with
    rounds_used_up = False
    for _ in range(rounds):
        ratios, redundancy = _variance_ratios(problem, result.values)
        for name, ratio in ratios.items():
            # Clamp a round's step: far from the fixed point one group can absorb the
            # other's residuals, and an unclamped step overshoots.
            problem.scales[name] = float(np.clip(
                problem.scales.get(name, 1.0) * np.clip(ratio, 0.2, 5.0), 1e-4, 1e4))
        if first_round is None:
            first_round = {name: problem.scales[name] for name in ratios}
            first_redundancy = redundancy
        if all(abs(ratio - 1.0) <= tolerance for ratio in ratios.values()):
            break
        problem.values = result.values
        result = levenberg_marquardt(problem, progress=progress, **lm_options)
    else:
        rounds_used_up = True
        ratios, redundancy = _variance_ratios(problem, result.values)
    # A group still far from its fixed point when the rounds are used up is running away,
    # not settling. With an odometry model that misfits (1 Hz encoders), the scan matches'
    # scale fell round after round (0.2, 0.08, 0.04, 0.03, 0.014, 0.006 on a simulated
    # 10-minute drive, seed 3) while their true errors measure 0.11: the poses follow the
    # matches ever closer and the residuals left to them shrink with their scale. So is
    # one that ran so far that it pins the poses and has lost the redundancy to measure
    # its own noise (the same drive with the odometry edges of factors.motion_difference:
    # laser scale 0.0056, no ratio left), or whose redundancy collapsed on the way (a
    # synthetic street, test_solver: the odometry's fell from 24 % of its size to 2-4 %
    # and its scale to 0.09-0.17 against a true 0.25). Such a group keeps its one-step
    # estimate (0.43-0.47 on that street: on the safe side).
    def is_running_away(name):
        if name in ratios:
            return not UNSETTLED_RATIO[0] <= ratios[name] <= UNSETTLED_RATIO[1]
        return rounds_used_up or redundancy[name] < COLLAPSED_REDUNDANCY * first_redundancy[name]

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


def _variance_ratios(problem: Problem, values: Values) -> tuple:
    """(χ²_g / r_g of each measurement group whose noise the data can reveal, r_g of every
    group)."""
    redundancy, _ = redundancy_by_factor(problem, values)
    measured = {f.name for f in problem.factors if f.measurement}
    ratios = {}
    for name, (r, chi2) in redundancy.items():
        # Priors are statements, not measurements; and a group that determines its
        # own variables (no redundancy) has no say on its noise. Where a group's
        # redundancy is a small share of its size, its residuals are mostly what the
        # poses it pins leave over, and another group's misfit moves them as much as its
        # own noise does. Among bare corridors, where a short-range laser fixes little
        # along them, the odometry keeps 6-15 % of its size and its scale settles at
        # 0.24-0.46 against a true 0.25-0.29 (test_variance_components); held at the
        # stated model (scale 1) its σ would be 1.6 times too large.
        dim = sum(len(f) * f.edge_dim for f in problem.factors if f.name == name)
        if name in measured and r >= max(3.0, MIN_REDUNDANCY_SHARE * dim):
            ratios[name] = float(chi2 / r)
    return ratios, {name: r for name, (r, _) in redundancy.items()}


@dataclass
class Influence:
    """How the whitened residuals move the named blocks at `values` (for the covariances
    below, which share it): the linear system there, the blocks' marginal H⁻¹ (p, p), and
    J H⁻¹ E (rows × p)."""

    system: System
    marginal: np.ndarray
    rows: np.ndarray
    lu: "LinearSolver"

    @classmethod
    def of(cls, problem: Problem, values: Values, blocks, lu=None) -> "Influence":
        system = problem.linear_system(values)
        if lu is None:
            hessian, _ = _normal_equations(system)
            lu = LinearSolver(hessian, problem.banded_size)
        cols, solved = _inverse_columns(problem, blocks, lu)
        marginal = solved[cols]
        return cls(system, 0.5 * (marginal + marginal.T), system.jacobian @ solved, lu)


def component_scales(influence: Influence, start: int, stop: int, d: int) -> np.ndarray:
    """Noise scale per component (d,) of a factor's whitened rows start:stop: each
    component's squared residuals over its redundancy, n − tr(J_c H⁻¹ J_cᵀ), where that is
    at least MIN_REDUNDANCY_SHARE of its n rows; else 1.

    Variance components give a factor one scale; the shape of its covariance is the stated
    model's. The odometry's sideways part has its own parameter (lateral_noise), and the
    simulator's robots slip sideways less than the default states: at the truth their
    whitened sideways errors have a mean square of about a third of the factor's scale,
    the others' about 1 (bench/error_structure.py). The model's σ then overstates what
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
        if redundancy >= MIN_REDUNDANCY_SHARE * n and redundancy > 0:
            scales[c] = float(np.sum(residual[:, c] ** 2)) / redundancy
    return scales


def chained_edges(factor):
    """Index pairs (t, u) of a factor's edges where edge u starts at the pose edge t ends at."""
    start = {int(i): n for n, i in enumerate(factor.pose_i)}
    t = np.array([n for n, j in enumerate(factor.pose_j) if int(j) in start], int)
    u = np.array([start[int(factor.pose_j[n])] for n in t], int)
    return t, u


def lag1_correlation(whitened, t, u) -> np.ndarray:
    """Pooled lag-1 correlation per component of whitened residuals (m, d) over pairs (t, u)."""
    if len(t) == 0:
        return np.zeros(whitened.shape[1])
    cross = np.mean(whitened[t] * whitened[u], axis=0)
    return cross / np.maximum(np.mean(whitened**2, axis=0), 1e-300)


def chain_correlated_covariance(problem: Problem, values: Values, blocks, lu=None,
                                influence: Optional[Influence] = None, per_component=True):
    """H⁻¹ (Jᵀ C J) H⁻¹ of the named blocks, with C the errors' covariance when consecutive
    edges of a factor with `chained_errors` are correlated; and those correlations.

    H⁻¹ assumes every edge independent. Consecutive scan matches share a scan, whose own
    registration error enters them with opposite signs, so their errors correlate
    negatively and cancel where a parameter averages over many edges (the laser pose):
    H⁻¹ overstates its σ (RMS err/σ 0.4-0.7 over 20 seeds on most simulated lasers). In
    whitened units C has the identity on its diagonal and diag(ρ) between chained edges,
    ρ per component pooled over the recording from the residuals, one number each, so it
    is not noisy as the sandwich's per-edge products are. The residuals' correlation
    understates the errors' (the poses absorb part of each): the errors' own at the
    simulator's truth are −0.31 to −0.43 on the default and URG-like lasers, in the office
    and among corridors (bench/error_structure.py), so the correction errs toward H⁻¹.
    Only cancellation is taken from it (ρ clipped to [−0.5, 0]: −0.5 is a scan's error
    alone, and C stays positive semidefinite); a positive correlation is the sandwich's to
    report. The other measurement edges (the odometry) enter with their noise scale per
    component (component_scales) where `per_component`: in the sandwich H⁻¹ Jᵀ C J H⁻¹
    their block of C is diag(scales), so that a part of the stated model too large for
    these data (the sideways slip) does not widen the σ of what rests on it, while the
    estimate keeps the variance components' weights. `influence`: Influence.of(problem,
    values, blocks, lu) if already at hand.
    """
    influence = influence or Influence.of(problem, values, blocks, lu)
    system, cov = influence.system, influence.marginal
    correlations = {}
    factor_rows = iter(system.row_ranges)
    for factor in problem.factors:
        if len(factor) == 0:
            continue
        name, start, stop = next(factor_rows)
        d = factor.edge_dim
        if per_component and factor.measurement and not getattr(factor, "chained_errors", False):
            scales = component_scales(influence, start, stop, d)
            rows = influence.rows[start:stop].reshape(-1, d, influence.rows.shape[1])
            cov = cov + np.einsum("tip,i,tiq->pq", rows, scales - 1.0, rows)
            continue
        if not getattr(factor, "chained_errors", False):
            continue
        t, u = chained_edges(factor)
        rho = np.clip(lag1_correlation(system.residual[start:stop].reshape(-1, d), t, u), -0.5, 0.0)
        correlations[name] = rho
        rows = influence.rows[start:stop].reshape(-1, d, influence.rows.shape[1])
        cross = np.einsum("tip,i,tiq->pq", rows[t], rho, rows[u])
        cov = cov + cross + cross.T
    return 0.5 * (cov + cov.T), correlations


def sandwich_covariance(problem: Problem, values: Values, blocks, lags: int = 1, lu=None,
                        influence: Optional[Influence] = None):
    """Heteroscedasticity- and autocorrelation-consistent covariance of the named blocks.

    The model covariance H⁻¹ is right only if every edge's noise is independent with the
    stated covariance. Scan matches are not: consecutive matches share a scan, so their
    errors are correlated (measured lag-1 correlation ≈ −0.25 to −0.5), and H⁻¹
    overstates the uncertainty of what averages over many edges. The sandwich estimator
    H⁻¹ (Σ_t Σ_t' s_t s_t'ᵀ) H⁻¹, with s_t the summed scores J_eᵀ r_e of the measurement
    edges ending at pose t, over pairs up to `lags` apart, measures the spread from the
    residuals themselves. Pairwise scan matching makes the errors MA(1) (measured lag-1
    correlation −0.41 to −0.47, lags ≥ 2 below 0.05), for which the truncated (uniform)
    kernel at lag 1 is exact, where Newey-West's Bartlett weights would keep a third of
    the variance that cancels. The truncated estimate need not be positive semidefinite:
    negative eigenvalues are clipped to zero. `influence`: Influence.of(problem, values,
    blocks, lu) if already at hand.
    """
    influence = influence or Influence.of(problem, values, blocks, lu)
    system = influence.system
    cols = influence.rows.shape[1]
    # Scores of all measurement edges that end at the same pose are one time step's
    # contribution: the odometry and the laser edge of an interval are fitted to the same
    # pose difference, so their residuals are correlated and must be summed, not counted
    # as independent.
    n_time = max((int(f.pose_j.max()) + 1 for f in problem.factors
                  if f.measurement and len(f) and hasattr(f, "pose_j")), default=0)
    per_time = np.zeros((n_time, cols))
    meat = np.zeros((cols, cols))
    factor_rows = iter(system.row_ranges)
    for factor in problem.factors:
        if len(factor) == 0:
            continue
        name, start, stop = next(factor_rows)
        if not factor.measurement:
            continue
        d = factor.edge_dim
        scores = (influence.rows[start:stop] * system.residual[start:stop, None]).reshape(-1, d, cols).sum(1)
        if hasattr(factor, "pose_j"):
            np.add.at(per_time, factor.pose_j, scores)
        else:  # no time order known: independent edges
            meat += scores.T @ scores
    meat += per_time.T @ per_time
    for lag in range(1, lags + 1):
        cross = per_time[:-lag].T @ per_time[lag:]
        meat += cross + cross.T
    meat = 0.5 * (meat + meat.T)
    eigval, eigvec = np.linalg.eigh(meat)
    meat = (eigvec * np.clip(eigval, 0.0, None)) @ eigvec.T
    return 0.5 * (meat + meat.T)
