"""Fitting the models the diagnosis compares: the base graph on a run or part of it (without
the dilution correction, as diagnose fits the whole run), the same graph with effects
plugged in, and the edges whose laser-vs-odometry disagreement is scored.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sclam_ros.core import graph as graph_mod
from sclam_ros.core.levenberg_marquardt import levenberg_marquardt
from sclam_ros.core.variance_components import solve_with_variance_components
from sclam_ros.diagnosis.effects.model import extend_problem


@dataclass
class Fit:
    problem: object
    values: object
    scales: dict
    cost: float


@dataclass
class Edges:
    """Edges with both an odometry and a chained laser measurement (the scored ones)."""

    odo_index: np.ndarray  # into inputs.odo_*
    laser_index: np.ndarray  # into inputs.laser_*
    pose_i: np.ndarray
    pose_j: np.ndarray

    def where(self, keep) -> "Edges":
        """The edges selected by the mask `keep`."""
        return Edges(self.odo_index[keep], self.laser_index[keep], self.pose_i[keep],
                     self.pose_j[keep])


def paired_edges(inputs) -> Edges:
    laser_of = {(int(a), int(b)): n for n, (a, b) in enumerate(zip(inputs.laser_from, inputs.laser_to))}
    odo, las = [], []
    for n, a in enumerate(inputs.odo_from):
        m = laser_of.get((int(a), int(a) + 1))
        if m is not None:
            odo.append(n)
            las.append(m)
    odo, las = np.array(odo, int), np.array(las, int)
    return Edges(odo, las, inputs.odo_from[odo], inputs.odo_from[odo] + 1)


def component_residuals(problem, values, edges: Edges):
    """Whitened residual components (the stated noise grows with the wheel angle turned,
    so raw residuals would correlate with speed through their spread alone) of the scored edges, name -> (m,), all indexed like edges."""
    out = {}
    for f in problem.factors:
        if f.name in ("odometry", "laser") and len(f):
            lin = f.linearize(values)
            r = np.einsum("mij,mj->mi", lin.sqrt_information, lin.residual)
            pick = edges.odo_index if f.name == "odometry" else edges.laser_index
            for c, axis in enumerate(("x", "y", "theta")):
                out[f"{f.name}.{axis}"] = r[pick, c]
    return out


def subset(inputs, keep_pose_edges):
    """GraphInputs with only the edges whose both poses satisfy the mask."""
    o = keep_pose_edges[inputs.odo_from] & keep_pose_edges[inputs.odo_from + 1]
    la = keep_pose_edges[inputs.laser_from] & keep_pose_edges[inputs.laser_to]
    return graph_mod.GraphInputs(inputs.stamps, inputs.odo_from[o], inputs.odo_dphi[o],
                                 inputs.laser_from[la], inputs.laser_to[la], inputs.laser_z[la],
                                 inputs.laser_info[la],
                                 odo_parts=None if inputs.odo_parts is None else inputs.odo_parts[o],
                                 odo_variance=(None if inputs.odo_variance is None
                                               else inputs.odo_variance[o]),
                                 odo_path_variance=(None if inputs.odo_path_variance is None
                                                    else inputs.odo_path_variance[o]))


def fit_base(inputs, params, nominal, observability, poses=None) -> Fit:
    """The base model on `inputs`, with the full run's undetermined directions locked."""
    problem = graph_mod.build_problem(inputs, params, nominal, poses=poses,
                                      correct_dilution=False)
    problem.factors.extend(observability.lock(nominal))
    result, scales = solve_with_variance_components(problem)
    return Fit(problem, result.values, scales, result.final_cost)


def fit_effects(base: Fit, effects, variance_components=False) -> Fit:
    problem = extend_problem(base.problem, effects)
    problem.values = problem.values.copy()
    for name in base.values:
        problem.values[name] = base.values[name].copy()
    problem.scales = dict(base.scales)
    if variance_components:
        result, scales = solve_with_variance_components(problem)
    else:
        result, scales = levenberg_marquardt(problem), dict(base.scales)
    return Fit(problem, result.values, scales, result.final_cost)
