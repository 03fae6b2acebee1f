"""nearest.NearestReference answers as the KD-tree does at every step, searching less."""
import numpy as np
from scipy.spatial import cKDTree

from sclam_ros.frontend.nearest import NearestReference


def _steps(rng, points, sizes):
    for size in sizes:
        turn = rng.normal(0.0, size)
        c, s = np.cos(turn), np.sin(turn)
        points = points @ np.array([[c, s], [-s, c]]) + rng.normal(0.0, size, 2)
        yield points


def test_same_pairs_as_the_tree_at_every_step():
    rng = np.random.default_rng(0)
    for trial in range(30):
        reference = rng.uniform(-5.0, 5.0, (300, 2))
        reference[:20] = reference[20:40]  # duplicates: ties
        tree = cKDTree(reference)
        bound = rng.uniform(0.05, 1.0)
        points = reference[rng.choice(300, 250)] + rng.normal(0.0, 0.2, (250, 2))
        points[:10] = rng.uniform(20.0, 30.0, (10, 2))  # far from every reference point
        nearest = NearestReference(tree, bound)
        for moved in _steps(rng, points, [0.05, 0.01, 0.001, 1e-5, 1e-7, 0.1, 1e-6]):
            distance, index = nearest.query(moved)
            want_distance, want_index = tree.query(moved, distance_upper_bound=bound)
            found = np.isfinite(want_distance)
            assert np.array_equal(np.isfinite(distance), found), trial
            assert np.array_equal(index[found], want_index[found]), trial
            assert np.allclose(distance[found], want_distance[found], rtol=0, atol=1e-12)
