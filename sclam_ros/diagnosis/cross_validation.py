"""Time-block cross-validation: sets of effects fitted on the whole run and on each fold's
training blocks, each fit done once, and the held-out error of every fold.

Mean effects are judged on contiguous folds (SelectionConfig.folds), noise effects on folds
of blocks spread over the run (SelectionConfig.noise_folds, noise_fold_blocks): a region's
noise can only be learnt from training data that drove there, and one room is visited in
one or two stretches of a run, so a contiguous fold holding it out has no floor to learn
from. The disagreements' noise is independent from one block to the next, so spread folds
do not leak it; a mean effect's residuals drift slowly along the run, and spread folds
would leak those (docs/decisions/diagnose.md).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from sclam_ros.diagnosis.config import DiagnoseConfig
from sclam_ros.diagnosis.disagreement import OdometryCovariance, edge_nll, fit_noise_effects
from sclam_ros.diagnosis.effects import LIBRARY, EffectData
from sclam_ros.diagnosis.fitting import Edges, Fit, component_residuals, fit_base, fit_effects, subset
from sclam_ros.diagnosis.regressors import pose_motion
from sclam_ros.diagnosis.structure import regressor_shares, residual_tests, significant


@dataclass
class Fold:
    test: Edges  # the held-out block's edges
    train_edges: Edges
    train: Fit  # the base model fitted without the held-out block


@dataclass
class Models:
    """Fits of effect sets, each done once: on the whole run (values, σ, likelihood ratio)
    and per held-out fold (the held-out error)."""

    data: EffectData
    inputs: object
    edges: Edges
    odo_cov: OdometryCovariance
    base: Fit
    folds: list  # contiguous time blocks: mean effects
    spread_folds: list  # blocks spread over the run: noise effects
    regs: dict = field(default_factory=dict)
    edge_reg: np.ndarray = None
    config: DiagnoseConfig = field(default_factory=DiagnoseConfig)
    # the scans' stamp error, in every model compared (stamp_jitter.py; None: not modelled)
    jitter: object = None
    whole: dict = field(default_factory=dict)
    heldout: dict = field(default_factory=dict)

    def effects(self, names):
        return [LIBRARY[n](self.data, self.config) for n in names]

    def split_effects(self, names):
        """(mechanical effects, noise effects), fresh instances of `names`."""
        effects = self.effects(names)
        return ([e for e in effects if e.kind != "noise"], [e for e in effects if e.kind == "noise"])

    def _fit_noise(self, noise, fit, mech, edges):
        return fit_noise_effects(noise, fit, mech, self.inputs, edges, self.odo_cov,
                                 self.config.noise.fit_rounds, self.config.noise.log_range,
                                 self.jitter)

    def fit_whole(self, names):
        """(Fit of the mechanical effects, fitted noise effects, whole-run cost)."""
        key = tuple(names)
        if key not in self.whole:
            mech, noise = self.split_effects(names)
            fit = fit_effects(self.base, mech) if mech else self.base
            cost = fit.cost
            # 2·ΔNLL: the same scale as the graph's χ²-type cost; both NLLs with the
            # wheels' level fitted (disagreement.fit_noise_effects), so the difference is
            # the noise effects' shape, not the base's stated level of the wheels' noise.
            if noise:
                before, after = self._fit_noise(noise, fit, mech, self.edges)
                cost -= 2.0 * float(np.sum(before - after))
            self.whole[key] = (fit, noise, cost)
        return self.whole[key]

    def odometry_residuals(self, names):
        """(Fit, {odometry component: whitened residuals}) of the mechanical effects of
        `names` fitted on the whole run."""
        fit = self.fit_whole(names)[0]
        residuals = component_residuals(fit.problem, fit.values, self.edges)
        return fit, {c: r for c, r in residuals.items() if c.startswith("odometry.")}

    def shares(self, names) -> dict:
        """regressor -> fraction of the odometry residuals' structure it explains, left by
        the mechanical effects of `names` fitted on the whole run ({} if none is left)."""
        fit, residuals = self.odometry_residuals(names)
        motion = pose_motion(self.inputs, fit.values["poses"])  # as the regressors take it
        return regressor_shares(residuals, self.regs, self.edge_reg, motion,
                                self.config.structure)[0]

    def mean_structure(self, names) -> list:
        """Significant dependence of the odometry residuals' mean on a regressor
        (autocorrelation aside) left by the mechanical effects of `names`, fitted on the
        whole run. Only the odometry's: the noise effects scale the odometry's covariance,
        and the laser residuals depend on the change of wheel speed / the angular
        acceleration on some routes with no effect at all (the scan matcher's, not the
        wheels'; docs/decisions/diagnose.md)."""
        residuals = self.odometry_residuals(names)[1]
        tests = residual_tests(residuals, self.regs, {c: self.edge_reg for c in residuals},
                               self.config.structure)
        return [t for t in significant(tests, self.config.structure) if t["regressor"] != "lag"]

    def heldout_nll(self, names, spread=False):
        """Per-edge NLL of every held-out block, concatenated in fold order, on the
        contiguous folds or (spread) the spread ones."""
        key = (tuple(names), spread)
        if key not in self.heldout:
            per_fold = []
            for fold in self.spread_folds if spread else self.folds:
                mech, noise = self.split_effects(names)  # noise effects are fitted per fold
                fit = fit_effects(fold.train, mech) if mech else fold.train
                if noise:
                    self._fit_noise(noise, fit, mech, fold.train_edges)
                per_fold.append(edge_nll(fit, mech, self.inputs, fold.test, self.odo_cov, noise,
                                         self.jitter))
            self.heldout[key] = np.concatenate(per_fold)
        return self.heldout[key]


def time_block_folds(inputs, edges, base, params, nominal, observability, folds,
                     blocks_per_fold=1) -> list:
    """Folds of `blocks_per_fold` time blocks each, spread over the run (fold k holds
    blocks k, k + folds, ...; one block: contiguous folds)."""
    blocks = np.array_split(np.arange(inputs.size), folds * blocks_per_fold)
    out = []
    for k in range(folds):
        held = np.zeros(inputs.size, bool)
        held[np.concatenate(blocks[k::folds])] = True
        test = held[edges.pose_j] & held[edges.pose_i]
        if not test.any():
            continue
        train = fit_base(subset(inputs, ~held), params, nominal, observability,
                         poses=base.values["poses"])
        out.append(Fold(edges.where(test), edges.where(~held[edges.pose_j] & ~held[edges.pose_i]),
                        train))
    return out
