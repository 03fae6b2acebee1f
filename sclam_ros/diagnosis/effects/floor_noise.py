"""Odometry noise that depends on where the robot drives (one room's carpet, a rough hall).

One region of the map, a rectangle found from the residuals, whose odometry noise
is higher than the rest's. Only the noisier side is searched: the effect is a floor
the wheels slip more on, and a quieter rectangle is the complement of a noisy region
that a rectangle fits worse (searching both sides can find a quieter rectangle elsewhere
on a run with one noisy room). The rectangle is searched over a grid (FloorNoiseConfig.cell)
laid along the map's own axes (the headings of straight
driving, modulo 90°: walls, and so rooms and their floors, run along them; the odometry
frame starts at an arbitrary heading). For every rectangle holding at least min_edges
edges, and leaving as many outside, the maximum-likelihood factor on the odometry
covariance is taken inside and outside; of the rectangles whose inside factor is the
larger, the one with the largest likelihood gain wins, unless the recording's scans
give a map of walls (EffectData.walls): then, of the rectangles within `within` of the
largest gain, the one whose boundary the walls support best (diagnosis/wall_map.py: it
is left through doors, and no wall runs through it). Its sides are then placed halfway
between its outermost edges and the nearest edges left out, so a held-out pass through
the same room falls inside.

The factors are relative to the one factor of all edges together, so the effect models
how the region differs, never a misfit of the overall wheel noise. They are fitted to
the laser-vs-odometry disagreements, whose covariance is λ·(wheels' part) + (scan match
and the odometry's other parts), not to the χ²/dof of the odometry residuals of a
joint fit: the poses hand part of every disagreement to the scan matches, more of it
the noisier the odometry, which pulls that ratio towards 1.

(Not fixed cells, e.g. four split at the route's medians: a room whose edges fall
across two cells dilutes into both, and its likelihood ratio with it.) The measurements
behind these choices: docs/decisions/diagnose.md.
"""
from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from sclam_ros.core import se2
from sclam_ros.diagnosis.config import DiagnoseConfig
from sclam_ros.diagnosis.effects.base import ModelEffect
from sclam_ros.diagnosis.effects.noise_fit import ml_factor, ml_factor_with_sigma, nll_profile


def principal_angle(positions, min_step=1e-3) -> float:
    """The map's axes: the dominant direction of travel modulo 90° (rad), each step
    weighted by its length (turns on the spot hardly count)."""
    step = np.diff(np.asarray(positions, float), axis=0)
    length = np.hypot(step[:, 0], step[:, 1])
    keep = length > min_step
    if not keep.any():
        return 0.0
    ang = 4.0 * np.arctan2(step[keep, 1], step[keep, 0])
    return float(0.25 * np.arctan2(np.sum(length[keep] * np.sin(ang)),
                                   np.sum(length[keep] * np.cos(ang))))


class FloorNoise(ModelEffect):
    name = "floor_noise"
    kind = "noise"
    units = "variance ratio (inside the region / outside)"
    doc = "odometry noise of one rectangular region of the map, found from the residuals"
    # For the BIC: the region's factor and its place, the search over places counted as
    # one parameter: it keeps the best noisier rectangle of runs without a floor effect
    # below its penalty (docs/decisions/diagnose.md). Because the place is searched, its
    # held-out likelihood ratio must clear a penalty too (searched = True).
    dim = 2
    searched = True

    def __init__(self, data, config=DiagnoseConfig()):
        super().__init__(data, config)
        self.angle = 0.0
        self.lo = np.full(2, np.inf)  # empty region until fitted
        self.hi = np.full(2, -np.inf)
        self.inside_scale = self.outside_scale = 1.0
        self.log_ratio_sigma = None  # 1σ of ln(inside / outside), given the region
        self.edges_inside = 0
        self.seen = None  # KD-tree of the fitted edges' mid-points (map axes)
        self.wall_support = None  # wall_map score of the region (None: no walls)
        # NLL (nats) by which the region the walls chose fits the edges worse than the
        # likelihood's best rectangle (0: the same). The selection tests the search's
        # best (evidence.evaluate): its likelihood ratio on runs without a floor effect is
        # what the penalty was set on; the walls choose the place, not whether there is one.
        self.search_deficit = 0.0

    @property
    def levels(self) -> np.ndarray:
        """The log factors the search scans: the range a fitted factor's σ is judged
        against (identifiability)."""
        return self.config.floor.levels

    def _aligned(self, pose_i, pose_j):
        """Edge mid-points in the map's axes."""
        mid = 0.5 * (self.data.positions[pose_i] + self.data.positions[pose_j])
        return se2.rotate_inverse(self.angle, mid)

    def inside(self, pose_i, pose_j):
        u = self._aligned(pose_i, pose_j)
        return np.all((u >= self.lo) & (u <= self.hi), axis=1)

    def fit(self, pose_i, pose_j, nll):
        """Find the region and its factor from the edges (pose_i, pose_j) and nll
        (per-edge factors (m,) → per-edge NLL (m,))."""
        floor, log_range = self.config.floor, self.config.noise.log_range
        self.angle = principal_angle(self.data.positions)
        u = self._aligned(pose_i, pose_j)
        walls = self.data.walls
        candidates = _near_best_rectangles(u, nll_profile(nll, len(u), floor.levels), floor.cell,
                                           floor.min_edges, 0.0 if walls is None else floor.within,
                                           floor.max_candidates)
        if not candidates:
            return
        chosen = candidates[0][1]
        if walls is not None:
            # Time order, so that consecutive edges are the route's steps.
            order = np.argsort(pose_i, kind="stable")
            axis_walls = walls.in_axes(self.angle)
            scores = [round(axis_walls.score(u[order], inside[order]), 3)
                      for _, inside in candidates]
            pick = int(np.argmax(scores))  # the first (best gain) of ties
            chosen, self.wall_support = candidates[pick][1], scores[pick]
        self.lo, self.hi = _with_margins(u, chosen, floor.cell)
        self.seen = cKDTree(u)
        inside = self.inside(pose_i, pose_j)
        overall = ml_factor(nll, np.ones(len(u), bool), log_range)
        inside_factor, inside_sigma = ml_factor_with_sigma(nll, inside, log_range)
        outside_factor, outside_sigma = ml_factor_with_sigma(nll, ~inside, log_range)
        self.inside_scale = inside_factor / overall
        self.outside_scale = outside_factor / overall
        # The two factors come from disjoint edges: their logs' variances add. The
        # region's place is taken as given (its search makes the ratio err high).
        self.log_ratio_sigma = float(np.hypot(inside_sigma, outside_sigma))
        self.edges_inside = int(inside.sum())
        if chosen is not candidates[0][1]:
            # Both as the model uses them: their sides moved out by the margins.
            lo, hi = _with_margins(u, candidates[0][1], floor.cell)
            best = np.all((u >= lo) & (u <= hi), axis=1)
            self.search_deficit = max(_region_nll(nll, inside, overall, log_range)
                                      - _region_nll(nll, best, overall, log_range), 0.0)

    def scale_of(self, pose_i, pose_j):
        if self.seen is None:
            return np.ones(len(pose_i))
        u = self._aligned(pose_i, pose_j)
        inside = np.all((u >= self.lo) & (u <= self.hi), axis=1)
        coverage = self.config.floor.coverage
        unseen = self.seen.query(u, distance_upper_bound=coverage)[0] > coverage
        return np.where(unseen, 1.0, np.where(inside, self.inside_scale, self.outside_scale))

    def value(self, p=None):
        return float(self.inside_scale / self.outside_scale)

    def value_sigma(self):
        """1σ of value() (delta method on its logarithm), None before a region is fitted."""
        return None if self.log_ratio_sigma is None else self.value() * self.log_ratio_sigma

    def describe(self) -> dict:
        """The region in the fitted map frame (the odometry frame: the first pose at the
        origin): its sides along the map's axes, rotated by `angle_deg`, and its corners."""
        if not np.all(np.isfinite(self.lo)):
            return {}
        c, s = np.cos(self.angle), np.sin(self.angle)
        corners = [(a, b) for a, b in ((self.lo[0], self.lo[1]), (self.hi[0], self.lo[1]),
                                       (self.hi[0], self.hi[1]), (self.lo[0], self.hi[1]))]
        return {"region": {
            "angle_deg": float(np.degrees(self.angle)),
            "along": [float(self.lo[0]), float(self.hi[0])],
            "across": [float(self.lo[1]), float(self.hi[1])],
            "corners": [[float(c * a - s * b), float(s * a + c * b)] for a, b in corners],
            "edges_inside": self.edges_inside,
            # How well walls bound it (diagnosis/wall_map.py: 1 = left only through
            # doors, no wall through it; null: the scans were not kept)
            "wall_support": self.wall_support,
        }}


def _region_nll(nll, inside, overall, log_range) -> float:
    """Summed NLL of the edges with the ML factors inside and outside `inside`, relative
    to the `overall` one (as scale_of gives them)."""
    scale = np.where(inside, ml_factor(nll, inside, log_range),
                     ml_factor(nll, ~inside, log_range)) / overall
    return float(np.sum(nll(scale)))


def _near_best_rectangles(u, profile, cell, min_edges, within, max_candidates):
    """[(gain, edges inside (m,) bool)] of the grid rectangles, noisier inside than
    outside, whose likelihood gain is within `within` of the largest: best first,
    distinct edge sets, at most `max_candidates` ([] if there is none).

    profile (m, G): each edge's NLL at G common factors. With prefix sums over the grid
    cells, a rectangle's NLL at every factor is four look-ups, so all rectangles of the
    grid are scored (one x-side at a time, vectorised over the rest)."""
    origin = u.min(axis=0)
    cells = np.floor((u - origin) / cell).astype(int)
    nx, ny = cells.max(axis=0) + 1
    levels = profile.shape[1]
    sums = np.zeros((nx + 1, ny + 1, levels))
    counts = np.zeros((nx + 1, ny + 1))
    np.add.at(sums, (cells[:, 0] + 1, cells[:, 1] + 1), profile)
    np.add.at(counts, (cells[:, 0] + 1, cells[:, 1] + 1), 1.0)
    sums = sums.cumsum(0).cumsum(1)
    counts = counts.cumsum(0).cumsum(1)
    total = sums[-1, -1]
    m = len(u)
    y_lo, y_hi = np.triu_indices(ny + 1, 1)
    gains, sides = [], []
    for a in range(nx):
        strip = sums[a + 1:] - sums[a]  # (nx − a, ny + 1, G): columns a..b, rows 0..y
        strip_n = counts[a + 1:] - counts[a]
        inside = strip[:, y_hi] - strip[:, y_lo]
        n_in = strip_n[:, y_hi] - strip_n[:, y_lo]
        ok = (n_in >= min_edges) & (m - n_in >= min_edges)
        if not ok.any():
            continue
        outside = total - inside
        gain = total.min() - inside.min(axis=2) - outside.min(axis=2)
        ok &= (inside.argmin(axis=2) > outside.argmin(axis=2)) & (gain > 0)
        b, k = np.nonzero(ok)
        gains.append(gain[b, k])
        sides.append(np.column_stack([np.full(len(b), a), a + 1 + b, y_lo[k], y_hi[k]]))
    gains, sides = np.concatenate(gains or [[]]), np.concatenate(sides or [np.zeros((0, 4), int)])
    if not len(gains):
        return []
    near = np.nonzero(gains >= gains.max() - within)[0]
    order = near[np.argsort(-gains[near], kind="stable")]  # ties: the first in scan order
    found, seen = [], set()
    for start in range(0, len(order), 4096):  # many rectangles hold the same edges
        chunk = order[start:start + 4096]
        a, b, c, d = (sides[chunk, i, None] for i in range(4))
        inside = ((cells[:, 0] >= a) & (cells[:, 0] < b) & (cells[:, 1] >= c)
                  & (cells[:, 1] < d))
        for n, row, key in zip(chunk, inside, np.packbits(inside, axis=1)):
            key = key.tobytes()
            if key not in seen:
                seen.add(key)
                found.append((float(gains[n]), row))
                if len(found) == max_candidates:
                    return found
    return found


def _with_margins(u, inside, cell):
    """The rectangle around the inside edges, each side halfway to the nearest edge left
    out beyond it (one `cell` beyond if there is none)."""
    lo, hi = u[inside].min(axis=0), u[inside].max(axis=0)
    new_lo, new_hi = lo.copy(), hi.copy()
    for axis in (0, 1):
        other = 1 - axis
        beside = ~inside & (u[:, other] >= lo[other]) & (u[:, other] <= hi[other])
        below = u[beside & (u[:, axis] < lo[axis]), axis]
        above = u[beside & (u[:, axis] > hi[axis]), axis]
        new_lo[axis] = 0.5 * (lo[axis] + below.max()) if len(below) else lo[axis] - cell
        new_hi[axis] = 0.5 * (hi[axis] + above.min()) if len(above) else hi[axis] + cell
    return new_lo, new_hi
