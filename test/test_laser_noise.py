"""The laser's range noise judged from its first scans (frontend/laser_noise.py), as the
refined matcher judges it and as its decisions follow it."""
import numpy as np
import pytest

from sclam_ros.frontend import laser_noise, point_to_line
from sclam_ros.frontend.config import FrontendConfig, LaserNoiseConfig
from sclam_ros.sim.world import office_world

CONFIG = FrontendConfig()

ANGLES = -np.pi + 2 * np.pi / 360 * np.arange(360)


def _office_scans(noise, count=12, seed=3):
    """Scans (inputs.Scan, 360 beams) of the office along a short drive, Gaussian range noise."""
    from sclam_ros.core.inputs import Scan

    world, rng = office_world(), np.random.default_rng(seed)
    scans = []
    for i in range(count):
        ranges = world.raycast(np.array([4.0 + 0.05 * i, 2.5, 0.1 * i]), ANGLES, 20.0)
        scans.append(Scan(stamp=0.1 * i, ranges=ranges + rng.normal(0.0, noise, ranges.shape),
                          angle_min=float(ANGLES[0]), angle_increment=float(ANGLES[1] - ANGLES[0]),
                          range_min=0.05, range_max=20.0))
    return scans


@pytest.mark.parametrize("noise", [0.003, 0.01, 0.03, 0.05])
def test_range_noise_is_measured_from_the_scan(noise):
    """The second-difference estimate recovers the simulated range noise (within 25 %)."""
    estimates = [laser_noise.range_noise(scan) for scan in _office_scans(noise)]
    assert np.median(estimates) == pytest.approx(noise, rel=0.25)


def _office_scans_noise_growing(base, per_metre, count=30, seed=5):
    """As _office_scans, with range noise base + per_metre × range (m)."""
    scans = _office_scans(0.0, count, seed)
    rng = np.random.default_rng(seed)
    for scan in scans:
        ranges = np.asarray(scan.ranges, float)
        scan.ranges[:] = ranges + rng.normal(0.0, 1.0, ranges.shape) * (base + per_metre * ranges)
    return scans


@pytest.mark.parametrize("base, per_metre, growth, within", [
    (0.02, 0.01, 0.5, 0.3), (0.01, 0.01, 1.0, 0.5), (0.03, 0.0, 0.0, 0.0), (0.05, 0.0, 0.0, 0.0)])
def test_how_the_range_noise_grows_with_range_is_measured_from_the_scans(base, per_metre,
                                                                         growth, within):
    """σ(r) = base + per_metre·r: the judged growth (per_metre / base, 1/m) within 30 %
    (50 % where the noise at 0 m, an extrapolation from 1-8 m, is half the growth over
    1 m), and none on a laser whose noise does not grow (on the segments a matcher would
    fit)."""
    from sclam_ros.frontend.scan_matching import ScanMatcher, scan_to_points

    matcher = point_to_line.RefinedScanMatcher(ScanMatcher())
    scans = _office_scans_noise_growing(base, per_metre)
    for scan in scans:
        matcher._remember_reference(scan, scan_to_points(scan))
    assert matcher.fits_segments
    assert matcher.growth == pytest.approx(growth, rel=within)
    assert matcher._reference.growth == matcher.growth
    # The benches' judgement without a matcher is the matcher's.
    assert laser_noise.judged_laser(scans) == (np.median(matcher.range_noises), matcher.growth)


def test_refined_matcher_fits_wide_lines_on_a_noisy_laser_only():
    from sclam_ros.frontend.scan_matching import ScanMatcher, scan_to_points

    # 0.3 m: no laser is that noisy; returns that jump so are not on surfaces.
    for noise, wide in ((0.01, False), (0.04, True), (0.3, False)):
        matcher = point_to_line.RefinedScanMatcher(ScanMatcher())
        for scan in _office_scans(noise):
            matcher._remember_reference(scan, scan_to_points(scan))
        assert matcher.fits_segments == wide
        assert len(matcher.range_noises) == 12


def test_the_matcher_judges_the_laser_by_its_config():
    """The noise from which a laser is noisy is the matcher's config's, not a module's."""
    from sclam_ros.frontend.scan_matching import ScanMatcher, scan_to_points

    for noisy_range, wide in ((CONFIG.laser_noise.noisy_range, False), (0.005, True)):
        config = FrontendConfig(laser_noise=LaserNoiseConfig(noisy_range=noisy_range))
        matcher = point_to_line.RefinedScanMatcher(ScanMatcher(), config)
        for scan in _office_scans(0.01):
            matcher._remember_reference(scan, scan_to_points(scan))
        assert matcher.fits_segments == wide


def test_the_small_object_rule_follows_the_judged_noise():
    from sclam_ros.frontend.scan_matching import ScanMatcher, scan_to_points

    for noise, rule in ((0.003, False), (0.01, True)):
        matcher = point_to_line.RefinedScanMatcher(ScanMatcher())
        for scan in _office_scans(noise):
            matcher._remember_reference(scan, scan_to_points(scan))
        assert matcher._small_objects == rule
