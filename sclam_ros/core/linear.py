"""The linear algebra of the normal equations H Δ = −g of a pose graph.

_normal_equations forms (H, g) = (JᵀJ, Jᵀr) of a Problem's System once; LinearSolver
factorises H (banded Cholesky with a Schur complement for the global columns, a sparse LU
when the band is wide, one dense Cholesky when small), solves with it and reads entries of
H⁻¹ within H's pattern without forming H⁻¹ (_banded_inverse). Levenberg-Marquardt and the
covariances share these, so each factorisation serves both.
"""
from __future__ import annotations

import functools

import numpy as np
import scipy.linalg
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from sclam_ros.core.config import LinearConfig
from sclam_ros.core.problem import System


class LinearSolver:
    """Solves H x = r for the SPD normal matrix of a pose graph.

    The pose block of H is banded (edges join poses a few keyframes apart) and the rest
    (calibration, effect parameters) is a handful of dense global columns. Banded
    Cholesky on the poses plus a dense Schur complement for the globals costs O(n·w²),
    linear in the length of the recording; a general sparse LU (the fallback, used when
    the band is wide, e.g. with loop closures) grows faster.
    """

    def __init__(self, hessian, banded_size: int, config: LinearConfig = LinearConfig()):
        self.n = banded_size
        self.config = config
        self._lu = None
        self._dense = None
        if not sp.issparse(hessian):
            # Up to LinearConfig.dense_max_columns, one dense Cholesky of the whole H: for the
            # online window, building the banded split and its sparse slices costs more
            # Python than the dense factorisation.
            self._dense = scipy.linalg.cho_factor(hessian)
            return
        hessian = hessian.tocsc()
        self._hessian = hessian
        coo = hessian[: self.n, : self.n].tocoo()
        upper = coo.col >= coo.row
        bandwidth = int(np.max(coo.col[upper] - coo.row[upper], initial=0))
        if self.n == 0 or bandwidth > config.max_bandwidth:
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

    def solve(self, rhs):
        if self._dense is not None:
            return scipy.linalg.cho_solve(self._dense, rhs)
        if self._lu is not None:
            return self._lu.solve(rhs)
        # The Schur complement C − BᵀA⁻¹B of well-determined calibration parameters is a
        # small difference of large numbers and loses digits; iterative refinement
        # against the exact H recovers them (each step costs one more cheap solve).
        x = self._solve_once(rhs)
        for _ in range(self.config.refinement_steps):
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
            step = self.config.trace_chunk
            for start in range(0, len(needed), step):
                chunk = needed[start:start + step]
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
