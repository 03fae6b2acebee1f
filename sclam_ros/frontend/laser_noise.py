"""The laser's range noise, judged from its first scans: how large, and how it grows with range.

The reference scan's lines (reference_lines.py) are fitted as this judgement says. Which
lasers are noisy is measured, not configured: a datasheet's range accuracy includes bias
and says little about the beam-to-beam noise that matters here. A laser whose judged noise
is LaserNoiseConfig.noisy_range or more has its lines fitted to whole wall segments;
above not_a_noise consecutive returns do not lie on surfaces (isolated poles, foliage, a
scene of small objects), the estimate says nothing about the laser, and it keeps the
six-beam lines. Decision: docs/decisions/point_to_line.md, "Which lasers are noisy".

Some lasers' range noise grows with range (a low-cost triangulation or time-of-flight
laser: 2 cm + 1 % of range, 12 cm at 10 m). Least squares that weigh every return alike
lean on the far, noisy returns, and the matches come out long. Where the judgement finds
the noise growing, each return is weighed by 1/σ(r)² instead, in the wall lines' fit
(wall_segments.py) and in the refinement, with r the range of its wall where its beam
meets its line, not its own measured range: weighed by that, the returns the noise
brought nearer would weigh more. Decision: docs/decisions/point_to_line.md, "Range noise
that grows with range".
"""
from __future__ import annotations

import math

import numpy as np

from sclam_ros.frontend.config import FrontendConfig, LaserNoiseConfig
from sclam_ros.frontend.scan_matching import valid_beams
from sclam_ros.frontend.wall_segments import straight_segments


def range_noise(scan):
    """1σ range noise of a scan (m) from the second differences of consecutive returns, or
    None with fewer than 20 triples. On a smooth surface r[i−1] − 2r[i] + r[i+1] is the
    noise times √6 (the surface's own curvature adds ~1 mm at 1° between beams); the median
    keeps the jumps between surfaces out."""
    valid = valid_beams(scan)
    r = np.where(valid, np.asarray(scan.ranges, float), 0.0)  # no inf − inf below
    triple = valid[:-2] & valid[1:-1] & valid[2:]
    if np.count_nonzero(triple) < 20:
        return None
    second = (r[:-2] - 2.0 * r[1:-1] + r[2:])[triple]
    return float(1.4826 * np.median(np.abs(second)) / math.sqrt(6.0))


def range_errors(scan, noise, config: FrontendConfig = FrontendConfig()):
    """(ranges, errors) (m) of the scan's returns on its straight segments (wall_segments,
    judged with range noise `noise`), each return's error measured against the chord
    between its two neighbours along its own beam: on a flat wall at any incidence the
    noise-free return lies on that chord (the second difference of ranges does not: at
    grazing incidence it holds centimetres of the wall's geometry). Only where the beam
    meets the chord at a sine of config.laser_noise.growth_min_sine or more: nearer grazing
    the neighbours' noise moves the meeting point by many times their own. The error's
    spread is √1.5 times the return's range noise (its neighbours' share)."""
    valid = valid_beams(scan)
    r = np.where(valid, np.asarray(scan.ranges, float), 0.0)
    angle = float(scan.angle_min) + float(scan.angle_increment) * np.arange(len(r))
    u = np.column_stack([np.cos(angle), np.sin(angle)])
    p = u * r[:, None]
    returns = np.flatnonzero(valid)
    on_wall = np.zeros(len(r), bool)
    if len(returns) >= config.wall_segments.min_segment_returns:
        for segment in straight_segments(p[returns], noise, config.wall_segments):
            on_wall[returns[segment]] = True
    triple = on_wall[:-2] & on_wall[1:-1] & on_wall[2:]
    first, beam, last = p[:-2][triple], u[1:-1][triple], p[2:][triple]
    chord = last - first
    across = beam[:, 0] * chord[:, 1] - beam[:, 1] * chord[:, 0]
    min_sine = config.laser_noise.growth_min_sine
    steep = np.abs(across) >= min_sine * np.maximum(np.hypot(*chord.T), 1e-12)
    reach = (first[:, 0] * chord[:, 1] - first[:, 1] * chord[:, 0])[steep] / across[steep]
    ranges = r[1:-1][triple][steep]
    return ranges, ranges - reach


def judged_growth(samples, config: LaserNoiseConfig = LaserNoiseConfig()):
    """growth (1/m) of ReferenceScan from range_errors' answers for several scans, pooled:
    split into config.growth_bins by range, the robust spread in each (1.4826 × the median
    absolute error / √1.5) against its median range gives σ(r) = a + b·r (robust line
    through the bins), and growth = b/a where σ grows by config.growth_significant or more
    of a over the ranges seen (to the farthest bin's median range) at the lower 95 % bound
    of b; else, or with fewer than config.growth_samples per bin, 0."""
    if not samples:
        return 0.0
    ranges = np.concatenate([r for r, _ in samples])
    errors = np.abs(np.concatenate([e for _, e in samples]))
    if len(ranges) < config.growth_samples * config.growth_bins:
        return 0.0
    # Here, not at the top: scipy.stats takes 0.4 s to import, a tenth of calibrating a
    # 5-minute recording, and only a noisy laser's judgement needs it.
    from scipy.stats import theilslopes

    bins = np.array_split(np.argsort(ranges), config.growth_bins)
    spread = np.array([1.4826 * np.median(errors[b]) / math.sqrt(1.5) for b in bins])
    middle = np.array([np.median(ranges[b]) for b in bins])
    # The median of the slopes between bins (Theil-Sen): the farthest bin's spread comes out
    # low (of the far returns, the straight segments keep the quieter ones).
    b, a, b_low, _ = theilslopes(spread, middle)
    # σ(0) is an extrapolation, and a small one makes the nearest returns weigh many times
    # more than the next: it is taken as at least half the nearest bin's spread.
    a = max(a, 0.5 * spread[0])
    # Judged by the slope's lower 95 % bound: a laser whose noise does not grow can show a
    # slope of a few mm per metre over the few metres a corridor's steep returns span.
    return float(b / a) if b_low / a * middle[-1] >= config.growth_significant else 0.0


class LaserNoiseJudgement:
    """The laser's range noise as judged from range_noise() of the first
    config.laser_noise.noise_scans scans that give one, then fixed: their median, whether
    the laser is noisy (its lines are fitted to whole wall segments) and how its noise
    grows with range (from range_errors() of the same scans while it is noisy)."""

    def __init__(self, config: FrontendConfig = FrontendConfig()):
        self.config = config
        self.range_noises = []
        self.range_errors = []
        self.noisy = False
        self.growth = 0.0  # 1/m

    @property
    def judging(self) -> bool:
        """More scans are still to be judged."""
        return len(self.range_noises) < self.config.laser_noise.noise_scans

    @property
    def median(self) -> float:
        """The median of the range noises judged so far (m); NaN before the first."""
        return float(np.median(self.range_noises)) if self.range_noises else math.nan

    def add(self, scan) -> bool:
        """Judge `scan` too while judging; whether the judgement changed (only then)."""
        noise = range_noise(scan) if self.judging else None
        if noise is None:
            return False
        self.range_noises.append(noise)
        median, config = self.median, self.config.laser_noise
        self.noisy = config.noisy_range <= median <= config.not_a_noise
        if self.noisy:
            self.range_errors.append(range_errors(scan, median, self.config))
        self.growth = judged_growth(self.range_errors, config) if self.noisy else 0.0
        return True


def judged_laser(scans, config: FrontendConfig = FrontendConfig()):
    """(median range noise (m), growth (1/m)) of a laser as RefinedScanMatcher judges them
    from the first of `scans` (for benches that build ReferenceScans without a matcher);
    NaN and 0 without any that gives a range_noise (a quiet laser's lines, no clearance)."""
    judgement = LaserNoiseJudgement(config)
    for scan in scans:
        if not judgement.judging:
            break
        judgement.add(scan)
    return judgement.median, judgement.growth
