"""The laser's range noise, judged from its first scans: how large it is and how it grows with range.

The reference scan's lines (frontend/reference_lines.py) are fitted as this judgement says:
over a few beams on a quiet laser, to whole straight wall segments on a noisy one, and with
each return weighed by 1/σ(r)² where the noise grows with range.
"""
from __future__ import annotations

import math

import numpy as np
from scipy.stats import theilslopes

from sclam_ros.frontend.scan_matching import valid_beams
from sclam_ros.frontend.wall_segments import MIN_SEGMENT_RETURNS, straight_segments

# +0.039 / +0.015 % (0.26 / 0.25 / 0.31 → 0.16 / 0.14 / 0.24 %), URG-04LX-like RMS 0.14 /
# 0.13 / 0.20 → 0.13 / 0.10 / 0.17 %, 5 cm 0.21 / 0.21 / 0.27 → 0.18 / 0.17 / 0.25 %.
# Which lasers are noisy is measured, not configured (a datasheet's range accuracy includes
# bias and says little about the beam-to-beam noise that matters here): range_noise() of
# each of the first NOISE_SCANS reference scans of a recording, their median against
# NOISY_RANGE. Median over the first 30 scans on the simulator's lasers (bench/sensor_matrix.py):
# 1 cm indoors 10-12 mm, outdoors (trees, poles, cars: surfaces end often) 15-19 mm; 3 cm
# (URG-04LX-like) 28-31 mm; 5 cm 54 mm; 2 cm + 1 % of range 61 mm. The real Mines
# URG-04LX: 3 mm (its datasheet's ±3 cm is accuracy, not beam-to-beam noise).
# Above NOT_A_NOISE consecutive returns do not lie on surfaces (isolated poles, foliage, a
# scene of small objects) and the estimate says nothing about the laser: six beams.
NOISY_RANGE = 0.02  # m
NOT_A_NOISE = 0.1  # m
NOISE_SCANS = 30
# GROWTH: some lasers' range noise grows with range (a low-cost triangulation or
# time-of-flight laser: 2 cm + 1 % of range, 12 cm at 10 m). Least squares that weigh every
# return alike lean on the far, noisy returns, and the matches came out long: on pairs
# along the simulator's office corridor (`python bench/refinement_bias.py --rows 17 25`,
# the refinement from the true motion) +0.45 ± 0.09 % as the graph weighs them. Each return
# is weighed by 1/σ(r)² instead, in the wall lines' fit (wall_segments) and in the
# refinement, with r the range of its wall (where its beam meets its line), not its own
# measured range: weighed by that, the returns the noise brought nearer weigh more
# (_range_weights). In
# the calibrations (`python bench/sensor_matrix.py --rows 4 11 --seeds 80 --duration
# 120`, paired seeds, weighed alike → by σ(r)): office, radii and base +0.061 / +0.039 /
# +0.002 → +0.045 / +0.029 / −0.007 % (± 0.016 / 0.014 / 0.026), RMS 0.174 / 0.146 /
# 0.233 → 0.152 / 0.125 / 0.231 %, match scale 1.0007 → 1.0004; bare corridors, RMS 0.228
# / 0.236 / 0.363 → 0.194 / 0.193 / 0.333 %. (Weighed by the range of the reference
# point a new point is paired with, which the new point's noise chooses, the office radii
# came out +0.029 / +0.013 %.) How the noise grows is measured, not configured (range_errors of
# the first NOISE_SCANS reference scans, pooled: judged_growth; `python
# bench/noise_growth.py`): 2 cm + 1 % of range (a growth of 0.5/m) is judged 0.24-0.84/m
# on 80 of 80 short drives in the two indoor scenes (outdoors, with few straight surfaces,
# on 5 of 40), constant 3 cm and 5 cm noise as not growing on all 240. It is used on a laser that fits segments where σ grows by
# GROWTH_SIGNIFICANT or more of its value at 0 m over the ranges seen (to the median range
# of the farthest of GROWTH_BINS), judged by the slope's lower 95 % bound; else every
# return weighs alike.
GROWTH_BINS = 10
GROWTH_SAMPLES = 100  # returns per bin at least
GROWTH_MIN_SINE = 0.5
GROWTH_SIGNIFICANT = 0.3


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


def range_errors(scan, noise):
    """(ranges, errors) (m) of the scan's returns on its straight segments (wall_segments,
    judged with range noise `noise`), each return's error measured against the chord
    between its two neighbours along its own beam: on a flat wall at any incidence the
    noise-free return lies on that chord (the second difference of ranges does not: at
    grazing incidence it holds centimetres of the wall's geometry). Only where the beam
    meets the chord at GROWTH_MIN_SINE or more: nearer grazing the neighbours' noise moves
    the meeting point by many times their own. The error's spread is √1.5 times the
    return's range noise (its neighbours' share)."""
    valid = valid_beams(scan)
    r = np.where(valid, np.asarray(scan.ranges, float), 0.0)
    angle = float(scan.angle_min) + float(scan.angle_increment) * np.arange(len(r))
    u = np.column_stack([np.cos(angle), np.sin(angle)])
    p = u * r[:, None]
    returns = np.flatnonzero(valid)
    on_wall = np.zeros(len(r), bool)
    if len(returns) >= MIN_SEGMENT_RETURNS:
        for segment in straight_segments(p[returns], noise):
            on_wall[returns[segment]] = True
    triple = on_wall[:-2] & on_wall[1:-1] & on_wall[2:]
    first, beam, last = p[:-2][triple], u[1:-1][triple], p[2:][triple]
    chord = last - first
    across = beam[:, 0] * chord[:, 1] - beam[:, 1] * chord[:, 0]
    steep = np.abs(across) >= GROWTH_MIN_SINE * np.maximum(np.hypot(*chord.T), 1e-12)
    reach = (first[:, 0] * chord[:, 1] - first[:, 1] * chord[:, 0])[steep] / across[steep]
    ranges = r[1:-1][triple][steep]
    return ranges, ranges - reach


def judged_growth(samples):
    """growth (1/m) of ReferenceScan from range_errors' answers for several scans, pooled:
    split into GROWTH_BINS by range, the robust spread in each (1.4826 × the median
    absolute error / √1.5) against its median range gives σ(r) = a + b·r (robust line
    through the bins), and growth = b/a where σ grows by GROWTH_SIGNIFICANT or more of a
    over the ranges seen (to the farthest bin's median range) at the lower 95 % bound of
    b; else, or with fewer than GROWTH_SAMPLES per bin, 0."""
    if not samples:
        return 0.0
    ranges = np.concatenate([r for r, _ in samples])
    errors = np.abs(np.concatenate([e for _, e in samples]))
    if len(ranges) < GROWTH_SAMPLES * GROWTH_BINS:
        return 0.0
    bins = np.array_split(np.argsort(ranges), GROWTH_BINS)
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
    return float(b / a) if b_low / a * middle[-1] >= GROWTH_SIGNIFICANT else 0.0


class LaserNoiseJudgement:
    """The laser's range noise as judged from range_noise() of the first NOISE_SCANS scans
    that give one, then fixed: their median, whether the laser is noisy (NOISY_RANGE: its
    lines are fitted to whole wall segments) and how its noise grows with range (GROWTH,
    from range_errors() of the same scans while it is noisy)."""

    def __init__(self):
        self.range_noises = []
        self.range_errors = []
        self.noisy = False
        self.growth = 0.0  # 1/m

    @property
    def judging(self) -> bool:
        """More scans are still to be judged."""
        return len(self.range_noises) < NOISE_SCANS

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
        median = self.median
        self.noisy = NOISY_RANGE <= median <= NOT_A_NOISE
        if self.noisy:
            self.range_errors.append(range_errors(scan, median))
        self.growth = judged_growth(self.range_errors) if self.noisy else 0.0
        return True


def judged_laser(scans):
    """(median range noise (m), growth (1/m)) of a laser as RefinedScanMatcher judges them
    from the first NOISE_SCANS of `scans` that give a range_noise (for benches that build
    ReferenceScans without a matcher); NaN and 0 without any (a quiet laser's lines, no
    clearance)."""
    judgement = LaserNoiseJudgement()
    for scan in scans:
        if not judgement.judging:
            break
        judgement.add(scan)
    return judgement.median, judgement.growth
