"""Our factors + solver against Censi et al.'s published Khepera III calibration.

Reads the tuples in place from ../shared/data (no licence: never copied into the repo);
skips when the folder is absent.
"""
from pathlib import Path

import numpy as np
import pytest

from sclam_ros.io import censi

DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "censi-khepera-tuples"

pytestmark = pytest.mark.skipif(not DATA.is_dir(), reason=f"{DATA} not present")


def test_load_tuples_reads_every_object():
    tuples = censi.load_tuples(DATA / "l90.tuple")
    # README: 3295 tuples (a few lines hold two objects).
    assert len(tuples) == 3295
    assert np.all(tuples.T > 0) and np.all(np.isfinite(tuples.sm))


def test_initial_yaw_closed_form_lands_near_the_mounting():
    # l90 is mounted ~−90°: a start at 0 would be far outside the basin.
    tuples = censi.load_tuples(DATA / "l90.tuple")
    yaw = censi.initial_laser_yaw(tuples, [censi.NOMINAL_RADIUS, censi.NOMINAL_RADIUS,
                                           censi.NOMINAL_BASE])
    assert abs(yaw - (-1.56)) < 0.2


@pytest.mark.parametrize("mounting", censi.MOUNTINGS)
def test_matches_published_calibration_within_two_sigma(mounting):
    tuples = censi.load_tuples(DATA / f"{mounting}.tuple")
    published, published_cov = censi.load_published(DATA / f"{mounting}_results.json")
    ours = censi.calibrate_tuples(tuples)
    z = censi.compare(ours, published, published_cov)
    assert np.all(z < 2.0), dict(zip(["r_l", "r_r", "b", "l_x", "l_y", "l_yaw"], z.round(2)))
    # Our own σ is of the same order as theirs (neither collapsed nor unconstrained).
    ratio = ours.sigma / np.sqrt(np.diag(published_cov))
    assert np.all((ratio > 0.02) & (ratio < 10)), ratio
    # Heavy-tailed scan matching: the robust kernel down-weights some, not most.
    assert 0 < ours.downweighted < 0.3 * len(tuples)
