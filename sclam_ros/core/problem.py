"""A least-squares problem over named variable blocks, and its linear system.

A Problem is factors, initial Values, the rows held fixed and a robust kernel per factor
name. It never special-cases a factor: Problem.linear_system linearises every factor,
whitens with the factor's square-root information (scaled by the factor's variance
scale), applies the factor type's robust kernel as IRLS weights and stacks one Jacobian
(sparse; dense for small problems such as the online window). Values.retract applies a
step y ← y ⊕ Δ, additive with angles wrapped, matching factors.py's Jacobians. The
solvers (levenberg_marquardt, covariance, variance_components) all work on this System.

Gauge: scan matching and odometry only constrain relative motion, so the first pose is
held fixed (its columns are removed), which is the standard choice for a pose graph.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Optional

import numpy as np
import scipy.sparse as sp

from sclam_ros.core import se2
from sclam_ros.core.config import LinearConfig

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


@dataclass
class System:
    """The whitened, robustly weighted linear system at one linearisation point."""

    jacobian: "sp.csr_matrix | np.ndarray"  # dense up to LinearConfig.dense_max_columns columns
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
                 corrections=(), linear: LinearConfig = LinearConfig()):
        self.values = values
        self.linear = linear  # how its normal equations are stored and factorised
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
        if self.layout.size <= self.linear.dense_max_columns:
            # bincount sums entries that two blocks put in the same place (np.add.at does
            # too, more slowly).
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
