"""The nearest reference point of each point of a new scan while the refinement moves it.

Gauss-Newton (point_to_line.refine_with_covariance) moves the new scan a little at each
step, and pairs each of its points with its nearest reference point again. A point's
nearest one cannot have changed while it has moved by less than half the gap between its
nearest and its second nearest (triangle inequality): only the other points are searched
again. The answers are those of ``tree.query(points, distance_upper_bound=bound)`` at every
step; after the first step or two most points move by micrometres, and the KD-tree
searches, most of the refinement's cost, drop to a few points a step.
"""
from __future__ import annotations

import numpy as np

# m searched beyond the bound at a full search: a point farther than bound + MARGIN from
# every reference point stays unpaired until it has moved by MARGIN.
MARGIN = 0.05
# m: distances within this of a decision are searched again (float rounding)
ROUNDING = 1e-9


class NearestReference:
    """``query(points)``: (distance, index) of each point's nearest reference point, as
    ``tree.query(points, distance_upper_bound=bound)`` gives them (inf and tree.n beyond
    the bound). Call it with the same points, moved, each time."""

    def __init__(self, tree, bound: float):
        self.tree, self.bound = tree, bound
        self.reference = np.asarray(tree.data)
        self._at = None  # the points where each one's neighbours were last searched
        self._nearest = self._first = self._second = None  # index, distance, 2nd distance

    def query(self, points):
        if self._at is None:
            self._search(points, np.arange(len(points)))
        else:
            moved = np.hypot(points[:, 0] - self._at[:, 0], points[:, 1] - self._at[:, 1])
            # Searched again: where another point may now be the nearest, or where no point
            # was within bound + MARGIN and one may now be within bound.
            stale = np.flatnonzero(2.0 * moved + ROUNDING >= self._second - self._first)
            if len(stale):
                self._search(points, stale)
        found = self._nearest < len(self.reference)
        distance = np.full(len(points), np.inf)
        offset = points[found] - self.reference[self._nearest[found]]
        squared = offset[:, 0] * offset[:, 0] + offset[:, 1] * offset[:, 1]
        distance[found] = np.where(squared < self.bound * self.bound, np.sqrt(squared), np.inf)
        index = np.where(np.isfinite(distance), self._nearest, len(self.reference))
        return distance, index

    def _search(self, points, which):
        """The two nearest reference points of points[which] within bound + MARGIN. A
        point with none there stays unpaired until it has moved by MARGIN; one with no
        second there keeps its nearest until it has moved by half the gap to bound +
        MARGIN; a tie is left to the one-neighbour search the answers must equal."""
        reach = self.bound + MARGIN
        subset = points[which]
        distances, indices = self.tree.query(subset, k=2, distance_upper_bound=reach)
        if self._at is None:
            self._at = points.copy()
            self._nearest = np.empty(len(points), int)
            self._first, self._second = np.empty(len(points)), np.empty(len(points))
        self._at[which] = subset
        nearest, first = indices[:, 0], distances[:, 0]
        second = np.minimum(distances[:, 1], reach)
        none = ~np.isfinite(first)
        first[none], second[none] = self.bound - MARGIN, reach
        tied = np.flatnonzero(~none & (first + ROUNDING >= second))
        if len(tied):
            _, nearest[tied] = self.tree.query(subset[tied], distance_upper_bound=self.bound)
            second[tied] = first[tied]  # searched again at every step
        self._nearest[which], self._first[which], self._second[which] = nearest, first, second
