"""The walls the laser saw, on the fitted map: where one floor may end and the next begin.

A floor the wheels slip more on (a room's carpet) ends at walls and doors. A region found
from the residuals alone can spill through a door into the corridor or the next room
where the robot drove a few metres slowly: the likelihood hardly tells those edges' floor
apart (effects/floor_noise.py). The walls can. This map scores how well a region's
boundary follows them.

The map: each graph pose's scan, placed with the fitted poses and laser mount, binned
into WallMapConfig.cell cells; a cell with at least min_hits points is occupied (a stray return, a
person walking past, is not a wall). A region (its inside edges' mid-points, in the map's
axes) scores doorways × (1 − split) if the walls bound it, 0 if they do not:
- split: the share of its inside edges beyond a wall that runs through it (a rectangle
  holding a room and a strip of the corridor on the other side of its wall);
- doorways: the share of the route's crossings of its boundary that pass through an
  opening in a wall running along that boundary (a door), not across open floor.
A region the route never leaves or enters scores 1 on doorways. The walls bound a
region with at most max_split of its edges beyond a wall through it and at least
min_doorways of its crossings through doors; for any other region they say nothing
(a floor that changes along a line across the rooms of half an office: the rectangles
the likelihood cannot tell apart there all have walls through them, and without these
limits the one that scores highest runs metres further past the floor's edge than the
likelihood's best; docs/decisions/diagnose.md).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from sclam_ros.core import se2
from sclam_ros.diagnosis.config import WallMapConfig


@dataclass
class WallMap:
    """Occupied cells of the map (their centres in the odometry frame, (k, 2) m)."""

    occupied: np.ndarray
    config: WallMapConfig = field(default_factory=WallMapConfig)

    @classmethod
    def from_scans(cls, poses, mount, scans, config: WallMapConfig = WallMapConfig()) -> "WallMap | None":
        """poses (n, 3) fitted base poses; mount (3,) the laser on the base; scans: n
        arrays (m_i, 2) of the laser's points in its own frame (None where none).
        None if there are no points at all."""
        placed = [se2.transform_points(se2.compose(pose, mount), points)
                  for pose, points in zip(np.asarray(poses, float), scans)
                  if points is not None and len(points)]
        if not placed:
            return None
        cells, hits = np.unique(np.floor(np.vstack(placed) / config.cell).astype(np.int64), axis=0,
                                return_counts=True)
        return cls((cells[hits >= config.min_hits] + 0.5) * config.cell, config)

    @classmethod
    def from_keyframes(cls, raw_keyframes, stamps, poses, mount,
                       config: WallMapConfig = WallMapConfig()) -> "WallMap | None":
        """The map of the scans the raw keyframes carry (Keyframe.scan_points) at the
        graph's pose `stamps` (a merged keyframe's stamp is its last raw keyframe's),
        placed with the fitted `poses` (n, 3) and laser `mount` (3,). None without scans."""
        points_at = {kf.stamp: kf.scan_points for kf in raw_keyframes
                     if kf.scan_points is not None}
        if not points_at:
            return None
        return cls.from_scans(poses, mount, [points_at.get(t) for t in stamps], config)

    def in_axes(self, angle: float) -> "AxisWalls":
        """The map in axes rotated by `angle` (rad) from the odometry frame's."""
        return AxisWalls(se2.rotate_inverse(angle, self.occupied), self.config)


class AxisWalls:
    """The occupied cells on a grid in the map's axes, with what the scores look up."""

    def __init__(self, points, config: WallMapConfig):
        self.config = config
        cells = np.floor(np.asarray(points, float).reshape(-1, 2) / config.cell).astype(int)
        self.origin = (cells.min(axis=0) - 2) if len(cells) else np.zeros(2, int)
        cells -= self.origin
        shape = (cells.max(axis=0) + 3) if len(cells) else np.ones(2, int)
        grid = np.zeros(shape, bool)
        grid[cells[:, 0], cells[:, 1]] = True
        # Per axis k: rows are cells along k, columns along the other axis. For the
        # split, a wall parallel to the other axis that falls across two rows (not
        # exactly on the axes) counts in both: each row is or-ed with its neighbours.
        self.rows = []
        self.prefix = []
        for k in (0, 1):
            g = grid if k == 0 else grid.T
            wide = g.copy()
            wide[1:] |= g[:-1]
            wide[:-1] |= g[1:]
            self.rows.append(g)
            self.prefix.append(np.concatenate([np.zeros((len(wide), 1), int), wide.cumsum(axis=1)],
                                              axis=1))

    def _row(self, k, x):
        return int(np.floor(x / self.config.cell)) - self.origin[k]

    def _column(self, k, x):
        return int(np.floor(x / self.config.cell)) - self.origin[1 - k]

    def score(self, u, inside) -> float:
        """doorways × (1 − split) of the region `inside` (m,) bool of the edge mid-points
        u (m, 2) in the map's axes, in time order, if the walls bound it; else 0."""
        doorways = self.doorways(u, inside)
        if doorways < self.config.min_doorways:
            return 0.0
        split = self.split(u, inside)
        return 0.0 if split > self.config.max_split else doorways * (1.0 - split)

    def split(self, u, inside) -> float:
        """Share of the inside edges on the smaller side of the wall through the region
        that divides them most (0: no wall runs through it)."""
        ins = u[inside]
        lo, hi = ins.min(axis=0), ins.max(axis=0)
        cell = self.config.cell
        worst = 0
        for k in (0, 1):
            o = 1 - k
            prefix = self.prefix[k]
            need = min(self.config.split_wall, 0.5 * (hi[o] - lo[o])) / cell
            rows = np.arange(max(self._row(k, lo[k]) + 1, 0),
                             min(self._row(k, hi[k]), len(prefix)))
            if not len(rows):
                continue
            c0 = int(np.clip(self._column(k, lo[o]), 0, prefix.shape[1] - 1))
            c1 = int(np.clip(self._column(k, hi[o]) + 1, 0, prefix.shape[1] - 1))
            rows = rows[prefix[rows, c1] - prefix[rows, c0] >= need]
            if not len(rows):
                continue
            line = (rows + self.origin[k] + 0.5) * cell
            along = np.sort(ins[:, k])
            # Edges within a cell of the line are on neither side.
            below = np.searchsorted(along, line - cell)
            above = len(along) - np.searchsorted(along, line + cell)
            worst = max(worst, int(np.max(np.minimum(below, above))))
        return worst / len(ins)

    def doorways(self, u, inside) -> float:
        """Share of the route's crossings of the region's boundary through an opening in
        a wall along it (1 if the route never crosses it)."""
        lo, hi = u[inside].min(axis=0), u[inside].max(axis=0)
        crossings = np.nonzero(inside[1:] != inside[:-1])[0]
        through = total = 0
        for n in crossings:
            a, b = u[n], u[n + 1]
            if np.hypot(*(b - a)) > self.config.crossing_step:
                continue
            outer = b if inside[n] else a
            # The boundary crossed: across axis k (a side where u_k is constant).
            k = 0 if (outer[0] < lo[0] or outer[0] > hi[0]) else 1
            total += 1
            through += self._in_opening(k, 0.5 * (a + b))
        return through / total if total else 1.0

    def _in_opening(self, k, crossing) -> bool:
        """Wall along the line u_k = crossing_k on both sides of the crossing: at least
        opening_run of it between opening_near and opening_far from the crossing, within
        opening_band of the line (which lies halfway between the last edge inside and the
        first outside, so a few cm to a few dm off the wall)."""
        c = self.config
        rows = self.rows[k]
        r0 = max(self._row(k, crossing[k] - c.opening_band), 0)
        r1 = min(self._row(k, crossing[k] + c.opening_band) + 1, len(rows))
        if r1 <= r0:
            return False
        band = rows[r0:r1].any(axis=0)
        for sign in (-1.0, 1.0):
            ends = sorted(self._column(k, crossing[1 - k] + sign * d)
                          for d in (c.opening_near, c.opening_far))
            c0, c1 = max(ends[0], 0), min(ends[1] + 1, len(band))
            if c1 <= c0 or band[c0:c1].sum() * c.cell < c.opening_run:
                return False
        return True
