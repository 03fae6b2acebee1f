"""Reference check against Censi et al. (IEEE T-RO 2013) on their Khepera III tuples.

The tuples (github.com/AndreaCensi/calibration, ``reference-output/*.tuple``) are real
data already reduced to one interval each::

    {"T": s, "phi_l": rad/s, "phi_r": rad/s, "sm": [dx, dy, dθ]}

with constant wheel speeds over the interval and ``sm`` the scan-matched displacement of
the *laser* expressed in the laser frame at the interval's start: exactly our z_ij. Their
parameters are wheel *diameters* (``l_diam``, ``r_diam``) and ``axle`` (the wheel base
b); the kinematic model is the same as ours (v = (r_l ω_l + r_r ω_r)/2,
ω = (r_r ω_r − r_l ω_l)/b), so r = diam/2 and our dφ = phi·T.

Consecutive tuples do not share a pose (the intervals were cut by the synchroniser and
the scan matching restarts in every one), so each tuple becomes an independent pair of
poses (x_a, x_b) joined by one odometry and one laser factor, solved with the product's
graph (graph.build_problem: same factors, same robust kernel on the laser edges, same
priors and variance components). This is a check of our factors and solver, not of
our front end.

The data has no licence: it is read in place from /work/shared/data and never copied.
"""
from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from sclam_ros.core import graph as graph_mod
from sclam_ros.core import kinematics, se2
from sclam_ros.core.covariance import marginal_covariance
from sclam_ros.core.params import CALIBRATION_KEYS, SclamParams
from sclam_ros.core.variance_components import solve_with_variance_components

MOUNTINGS = ("lstraight", "l90", "lmov")

# Khepera III encoders as Censi's synchroniser states them: ticks_to_rad = 2π/(691.2·4).
KHEPERA_TICKS_PER_REVOLUTION = 691.2 * 4

# Starting values: physically plausible Khepera III numbers, *not* the published
# estimates (Censi's own code normalises the axle by 0.09 m for E_b).
NOMINAL_RADIUS = 0.021  # m
NOMINAL_BASE = 0.09  # m

# Scan-match noise shape for the laser edges (its scale is estimated by variance
# components): CSM on a short-range URG, a few mm and a few mrad per interval.
SM_SIGMA = np.array([0.002, 0.002, 0.004])  # m, m, rad

# A whitened squared laser residual beyond the Cauchy scale² counts as "down-weighted".
DOWNWEIGHT_WEIGHT = 0.5


@dataclass
class Tuples:
    T: np.ndarray  # (n,) s
    phi: np.ndarray  # (n, 2) wheel speeds (left, right), rad/s
    sm: np.ndarray  # (n, 3) laser displacement in the laser frame

    def __len__(self):
        return len(self.T)


def load_tuples(path) -> Tuples:
    # Mostly one object per line, but a few lines hold two: decode the stream.
    text, decoder, rows, pos = Path(path).read_text(), json.JSONDecoder(), [], 0
    while True:
        while pos < len(text) and text[pos].isspace():
            pos += 1
        if pos >= len(text):
            break
        row, pos = decoder.raw_decode(text, pos)
        rows.append(row)
    return Tuples(
        T=np.array([r["T"] for r in rows], float),
        phi=np.array([[r["phi_l"], r["phi_r"]] for r in rows], float),
        sm=np.array([r["sm"] for r in rows], float),
    )


def load_published(path):
    """Published estimate and covariance in OUR parameterisation (radii, not diameters).

    The covariance is in the order (l_diam, r_diam, axle, l_x, l_y, l_theta) of Censi's
    ``calib_result``; the diameter rows/columns are halved to get the radii's.
    """
    raw = json.loads(Path(path).read_text())
    estimate = np.array([raw["l_diam"] / 2, raw["r_diam"] / 2, raw["axle"],
                         raw["l_x"], raw["l_y"], raw["l_theta"]])
    scale = np.array([0.5, 0.5, 1.0, 1.0, 1.0, 1.0])
    cov = np.asarray(raw["covariance"], float) * np.outer(scale, scale)
    return estimate, cov


def initial_laser_yaw(tuples: Tuples, k) -> float:
    """Laser yaw from the directions of travel: the yaw that best rotates sm onto odometry.

    For short intervals the base's translation is ≈ R(yaw)·t_sm (the offset term is
    second order), so yaw = arg Σ t_odo · conj(t_sm) weighted by length: a closed form,
    valid for any mounting (the l90 and lmov yaws are near −π/2, far beyond the basin of
    a start at 0). Rotations alone carry no yaw information, which is fine: they are
    down-weighted by their small translation.
    """
    odo = kinematics.forward(tuples.phi * tuples.T[:, None], k)
    a = odo[:, 0] + 1j * odo[:, 1]
    z = tuples.sm[:, 0] + 1j * tuples.sm[:, 1]
    return float(np.angle(np.sum(a * np.conj(z))))


def graph_inputs(tuples: Tuples) -> graph_mod.GraphInputs:
    n = len(tuples)
    a = 2 * np.arange(n)
    info = np.broadcast_to(np.diag(SM_SIGMA**-2.0), (n, 3, 3)).copy()
    stamps = np.repeat(np.cumsum(tuples.T), 2)
    return graph_mod.GraphInputs(
        stamps=stamps,
        odo_from=a,
        odo_dphi=tuples.phi * tuples.T[:, None],
        laser_from=a,
        laser_to=a + 1,
        laser_z=tuples.sm,
        laser_info=info,
    )


def censi_params(nominal) -> SclamParams:
    return SclamParams(ticks_per_revolution=KHEPERA_TICKS_PER_REVOLUTION).with_calibration(
        dict(zip(CALIBRATION_KEYS, nominal))
    )


@dataclass
class CensiResult:
    estimate: np.ndarray  # (6,) r_l, r_r, b, l_x, l_y, l_yaw
    covariance: np.ndarray  # (6, 6)
    nominal: np.ndarray
    tuples: int
    downweighted: int  # laser edges with robust weight < DOWNWEIGHT_WEIGHT
    variance_scales: dict
    iterations: int

    @property
    def sigma(self):
        return np.sqrt(np.diag(self.covariance))


def calibrate_tuples(tuples: Tuples, nominal=None) -> CensiResult:
    if nominal is None:
        k = np.array([NOMINAL_RADIUS, NOMINAL_RADIUS, NOMINAL_BASE])
        nominal = np.concatenate([k, [0.0, 0.0, initial_laser_yaw(tuples, k)]])
    nominal = np.asarray(nominal, float)
    inputs = graph_inputs(tuples)
    params = censi_params(nominal)
    problem = graph_mod.build_problem(inputs, params, nominal)
    result, scales = solve_with_variance_components(problem)
    values = result.values
    cov = marginal_covariance(problem, values, ["odometry", "laser"])
    laser = next(f for f in problem.factors if f.name == "laser")
    lin = laser.linearize(values)
    whitened = np.einsum("mij,mj->mi", lin.sqrt_information, lin.residual)
    squared = np.einsum("mi,mi->m", whitened, whitened) / problem.scales.get("laser", 1.0)
    weights = problem.kernel(laser).weight(squared)
    return CensiResult(
        estimate=graph_mod.calibration_of(values),
        covariance=cov,
        nominal=nominal,
        tuples=len(tuples),
        downweighted=int(np.sum(weights < DOWNWEIGHT_WEIGHT)),
        variance_scales=dict(scales),
        iterations=result.iterations,
    )


def compare(ours: CensiResult, published, published_cov) -> np.ndarray:
    """|ours − published| in units of the published σ, per parameter (yaw wrapped)."""
    diff = ours.estimate - published
    diff[5] = se2.wrap_angle(diff[5])
    return np.abs(diff) / np.sqrt(np.diag(published_cov))
