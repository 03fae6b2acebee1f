"""What only a developer tunes in the diagnosis: one tree of small frozen dataclasses.

`DiagnoseConfig()` holds the defaults `sclam diagnose` uses; benches and tests vary a copy
(`dataclasses.replace`) and pass it to `diagnose_keyframes`, never a module's attributes.
The measurements behind the values chosen by measuring: docs/decisions/diagnose.md.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True)
class SelectionConfig:
    """How candidate effects are judged on held-out time blocks (diagnosis/cross_validation.py)."""

    # count; mean effects' folds, one contiguous block each: their residuals drift, spread blocks leak it
    folds: int = 5
    # count; noise effects' folds: more train on more of a once-visited room, but score more quiet edges
    noise_folds: int = 5
    # blocks per noise fold, spread over the run: a room visited in one stretch is in every fold's training
    noise_fold_blocks: int = 4


@dataclass(frozen=True)
class StructureConfig:
    """When residuals count as structured (diagnosis/structure.py)."""

    # multiple correlation √R²; on hundreds of edges a weaker one is significant but too small to name
    min_strength: float = 0.2
    # family-wise significance level of one model's residual tests (Bonferroni over all of them)
    alpha: float = 0.01
    # edges; the Ljung-Box test's lags: the usual choice for a series without seasons
    ljung_box_lags: int = 10
    # first lag the whiteness test looks at: neighbouring edges share a pose, and
    # consecutive scan matches a scan, so their errors correlate at lag 1 by construction
    # (the model's, not an effect's; docs/decisions/diagnose.md); beyond it they do not
    ljung_box_first_lag: int = 2
    # whitened σ; residuals are clipped here so that an odd failed scan match cannot dominate
    residual_clip: float = 3.0


@dataclass(frozen=True)
class IdentifiabilityConfig:
    """Whether the recording tells an effect apart (diagnosis/identifiability.py)."""

    # posterior σ / prior σ at most, to be determined: at σ ≈ prior the data say nothing about it
    sigma_ratio: float = 0.5
    # |ρ| between two effects' parameters above which the recording cannot separate them
    max_correlation: float = 0.9
    # σ of the extended model; the calibration moved farther by the effects is a warning
    max_shift_sigma: float = 3.0


@dataclass(frozen=True)
class NoiseConfig:
    """Factors on the wheels' noise (noise_model.py, effects/noise_fit.py, effects/noise_vs_motion.py)."""

    # rounds of coordinate descent over several noise effects: they follow different regressors
    fit_rounds: int = 2
    # factor; searched within [1/max_factor, max_factor]: bounded, so a small wheel share cannot overflow
    max_factor: float = 100.0
    # |a| of log λ = b + a·z at most: a factor of e³ per standard deviation of the regressor
    max_slope: float = 3.0
    # the scans' stamp jitter fitted into the model every effect is tested against (stamp_jitter.py)
    stamp_jitter: bool = True

    @property
    def log_range(self) -> float:
        """The log factors searched lie within ±log_range."""
        return float(np.log(self.max_factor))


@dataclass(frozen=True)
class FloorNoiseConfig:
    """The noisier rectangle of floor_noise (effects/floor_noise.py)."""

    # edges inside and outside at least: a factor from fewer is too uncertain to tell floors apart
    min_edges: int = 40
    # m; grid of the rectangles' sides (the margins then move each side to halfway between edges)
    cell: float = 0.5
    # m; an edge farther from every fitted edge is on floor the fit has not seen: the overall factor
    coverage: float = 1.0
    # factor; scanned from 1/max_level to max_level, and the prior a fitted factor's σ is judged by
    max_level: float = 8.0
    # count; factors scanned, evenly in log (the best is then refined off the grid)
    level_count: int = 31
    # nats; gains this close to the best are not told apart (about one parameter's BIC penalty)
    within: float = 3.0
    # count; near-best rectangles the walls choose among: routes without a noisier floor have many
    max_candidates: int = 2000

    @property
    def levels(self) -> np.ndarray:
        """The log factors scanned."""
        return np.linspace(np.log(1 / self.max_level), np.log(self.max_level), self.level_count)


@dataclass(frozen=True)
class WallMapConfig:
    """The walls the laser saw, and when they bound a region (diagnosis/wall_map.py)."""

    # m; the map's grid, finer than the openings' lengths below that it measures
    cell: float = 0.1
    # returns per cell at least: a stray return or a person walking past is not a wall
    min_hits: int = 3
    # m; a wall through a region is at least this long within it (or half the region's width)
    split_wall: float = 2.0
    # m; an opening's walls are looked for from this far from the crossing ...
    opening_near: float = 0.2
    # m; ... to this far, beyond a door (doors are 0.8-1.2 m wide)
    opening_far: float = 1.5
    # m; wall at least this long on each side of the crossing
    opening_run: float = 0.5
    # m; off the boundary's line at most: it lies between the last edge inside and the first outside
    opening_band: float = 0.3
    # share of a region's edges beyond a wall through it at most, for the walls to bound it
    max_split: float = 0.1
    # share of the route's crossings of its boundary through doors at least, for the walls to bound it
    min_doorways: float = 0.5
    # m; consecutive edges farther apart are a gap in the data, not a crossing
    crossing_step: float = 1.0


@dataclass(frozen=True)
class DiagnoseConfig:
    """The diagnosis's tuning, one section per job."""

    selection: SelectionConfig = field(default_factory=SelectionConfig)
    structure: StructureConfig = field(default_factory=StructureConfig)
    identifiability: IdentifiabilityConfig = field(default_factory=IdentifiabilityConfig)
    noise: NoiseConfig = field(default_factory=NoiseConfig)
    floor: FloorNoiseConfig = field(default_factory=FloorNoiseConfig)
    walls: WallMapConfig = field(default_factory=WallMapConfig)
