"""Scan → points geometry, and KISS-ICP motion recovery against an analytic ray cast."""
import math

import numpy as np
import pytest

from sclam_ros.core import se2
from sclam_ros.core.inputs import Rejections, Scan
from sclam_ros.frontend.point_to_line import RefinedScanMatcher
from sclam_ros.frontend.scan_matching import (
    NoiseModel,
    ScanMatcher,
    ScanMatcherConfig,
    laser_motion_from_base_motion,
    scan_to_points,
)

# --- a small analytic world: a 10 m × 7 m room with an alcove and two boxes --------------
_ROOM = [(0, 0), (10, 0), (10, 7), (6, 7), (6, 5.5), (4, 5.5), (4, 7), (0, 7)]
_BOXES = [(2.5, 2.0, 0.6, 0.4), (7.5, 4.5, 0.5, 0.8)]


def _segments():
    segs = [(*_ROOM[i], *_ROOM[(i + 1) % len(_ROOM)]) for i in range(len(_ROOM))]
    for cx, cy, w, h in _BOXES:
        c = [(cx - w / 2, cy - h / 2), (cx + w / 2, cy - h / 2), (cx + w / 2, cy + h / 2), (cx - w / 2, cy + h / 2)]
        segs += [(*c[i], *c[(i + 1) % 4]) for i in range(4)]
    return np.array(segs, float)


SEGMENTS = _segments()


def ray_cast(pose, angles, max_range=12.0):
    """Exact range along each beam to the nearest wall (inf if none within max_range)."""
    d = np.stack([np.cos(pose[2] + angles), np.sin(pose[2] + angles)], -1)[:, None, :]
    a, e = SEGMENTS[None, :, :2], (SEGMENTS[:, 2:] - SEGMENTS[:, :2])[None]
    ap = a - pose[:2]
    den = d[..., 0] * e[..., 1] - d[..., 1] * e[..., 0]
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (ap[..., 0] * e[..., 1] - ap[..., 1] * e[..., 0]) / den
        u = (ap[..., 0] * d[..., 1] - ap[..., 1] * d[..., 0]) / den
    r = np.where((t > 0) & (u >= 0) & (u <= 1), t, np.inf).min(1)
    r[r > max_range] = np.inf
    return r


def make_scan(pose, stamp, rng=None, noise=0.0, beams=360, increment_sign=1.0):
    angle_min = -math.pi if increment_sign > 0 else math.pi - 2 * math.pi / beams
    inc = increment_sign * 2 * math.pi / beams
    ranges = ray_cast(np.asarray(pose, float), angle_min + inc * np.arange(beams))
    if noise:
        ranges = ranges + rng.normal(0.0, noise, beams)
    return Scan(stamp, ranges, angle_min, inc, 0.05, 12.0)


# --- scan → points ---------------------------------------------------------------------------


def test_points_geometry_with_negative_increment_and_invalid_beams():
    # Beams at +90°, +45°, 0°, -45°, -90° (clockwise driver), with every kind of non-return.
    ranges = np.array([2.0, 0.0, 3.0, np.nan, 1.0, np.inf, 0.01, 50.0, 4.0])
    inc = -math.pi / 8
    scan = Scan(0.0, ranges, math.pi / 2, inc, 0.05, 30.0)
    points = scan_to_points(scan)
    angles = math.pi / 2 + inc * np.array([0, 2, 4, 8])
    expected = np.stack([[2.0, 3.0, 1.0, 4.0] * np.cos(angles), [2.0, 3.0, 1.0, 4.0] * np.sin(angles)], -1)
    assert points.shape == (4, 3)
    np.testing.assert_allclose(points[:, :2], expected, atol=1e-12)
    np.testing.assert_array_equal(points[:, 2], 0.0)
    # 50 m is beyond range_max = 30 m; a tighter matcher limit cuts 4 m too.
    assert len(scan_to_points(scan, max_range=3.5)) == 3


def test_zero_means_no_return_even_when_range_min_is_zero():
    scan = Scan(0.0, np.array([0.0, 1.0, -1.0]), 0.0, 0.1, 0.0, 10.0)
    np.testing.assert_allclose(scan_to_points(scan)[:, 0], [np.cos(0.1)])


def test_points_land_on_the_walls_they_were_cast_from():
    pose = np.array([3.0, 3.5, 0.4])
    for sign in (1.0, -1.0):
        scan = make_scan(pose, 0.0, increment_sign=sign)
        world = se2.transform_points(pose, scan_to_points(scan)[:, :2])
        assert len(world) == 360
        assert np.all(_distance_to_walls(world) < 1e-9)


def _distance_to_walls(p):
    a, e = SEGMENTS[None, :, :2], (SEGMENTS[:, 2:] - SEGMENTS[:, :2])[None]
    u = np.clip(((p[:, None] - a) * e).sum(-1) / (e * e).sum(-1), 0, 1)
    return np.linalg.norm(p[:, None] - (a + u[..., None] * e), axis=-1).min(1)


# --- matching -------------------------------------------------------------------------------


def drive(n=25, step=(0.05, 0.0, 0.03), start=(2.0, 3.5, 0.1)):
    """Laser poses along an arc: 5 cm and 1.7° per scan (0.5 m/s, 0.3 rad/s at 10 Hz)."""
    poses = [np.array(start, float)]
    for _ in range(n - 1):
        poses.append(se2.compose(poses[-1], step))
    return np.array(poses)


def test_recovers_known_motion_within_the_measured_noise():
    """Every z the graph gets (KISS-ICP, then the point-to-line refinement) within 4σ of
    the documented noise model, and the mean error (bias) within 4σ/√n: the model must not
    be optimistic, and the matcher must be unbiased."""
    rng = np.random.default_rng(7)
    poses = drive()
    matcher = ScanMatcher()
    refined = RefinedScanMatcher(matcher)
    errors, sigmas = [], []
    for i, pose in enumerate(poses):
        guess = None if i == 0 else se2.between(poses[i], poses[i - 1]) * [1.03, 1.03, 0.97]
        scan = make_scan(pose, 0.1 * i, rng, noise=0.01)
        match, z, _ = refined.add_scan(scan, guess, scan_to_points(scan))
        if i <= matcher.config.warmup_scans:
            assert match is None  # the first scans build the map
            continue
        assert (match.index_from, match.index_to) == (i - 1, i)
        assert z is not None  # the refinement confirmed it
        z_true = se2.between(poses[i], poses[i - 1])
        errors.append(se2.between(z, z_true))
        sigmas.append(np.sqrt(1.0 / np.diag(match.information)))
        assert match.fitness > 0.8 and match.num_points > 100
    errors, sigmas = np.array(errors), np.array(sigmas)
    assert np.all(np.abs(errors) < 4 * sigmas), np.abs(errors / sigmas).max(0)
    assert np.all(np.abs(errors.mean(0)) < 4 * sigmas.mean(0) / math.sqrt(len(errors)))
    assert matcher.rejections.counts == {"match_map_warmup": matcher.config.warmup_scans}


NO_WARMUP = ScanMatcherConfig(warmup_scans=0)


def test_empty_and_all_invalid_scans_are_counted_and_matching_resumes():
    poses = drive(n=6)
    matcher = ScanMatcher(NO_WARMUP)
    step = se2.between(poses[1], poses[0])
    scans = [make_scan(p, 0.1 * i) for i, p in enumerate(poses)]
    empty = Scan(0.25, np.zeros(0), -math.pi, 0.0175, 0.05, 12.0)
    all_inf = Scan(0.35, np.full(360, np.inf), -math.pi, 2 * math.pi / 360, 0.05, 12.0)
    assert matcher.add_scan(scans[0]) is None
    assert matcher.add_scan(scans[1], step) is not None
    assert matcher.add_scan(empty, np.zeros(3)) is None
    assert matcher.add_scan(all_inf, np.zeros(3)) is None
    assert matcher.rejections.counts == {"scan_empty": 2}
    # The next good scan is matched from the last scan that had a pose (index 1).
    match = matcher.add_scan(scans[2], step)
    assert (match.index_from, match.index_to) == (1, 4)
    np.testing.assert_allclose(match.z, step, atol=2e-3)


def test_a_scan_from_elsewhere_is_rejected_and_the_map_restarts():
    """The robot was spun 143° by hand (odometry saw nothing): the registration finds no
    overlap with the previous scan, the match is refused and a new map starts there."""
    rng = np.random.default_rng(5)
    poses = drive(n=6)
    step = se2.between(poses[1], poses[0])
    matcher = ScanMatcher()
    for i in range(6):
        matcher.add_scan(make_scan(poses[i], 0.1 * i, rng, noise=0.01), None if i == 0 else step)
    assert matcher.rejections.counts == {"match_map_warmup": 3}
    elsewhere = se2.compose(poses[5], [0.0, 0.0, 2.5])
    assert matcher.add_scan(make_scan(elsewhere, 0.6, rng, noise=0.01), step) is None
    assert matcher.rejections.counts["registration_poor_overlap"] == 1
    # The map restarted at the refused scan (index 6): after the warm-up, matches resume.
    pose, matches = elsewhere, []
    for i in range(7, 12):
        pose = se2.compose(pose, step)
        matches.append(matcher.add_scan(make_scan(pose, 0.1 * i, rng, noise=0.01), step))
    assert matches[:3] == [None] * 3 and matcher.rejections.counts["match_map_warmup"] == 6
    assert (matches[3].index_from, matches[3].index_to) == (9, 10)
    sigma = np.sqrt(1.0 / np.diag(matches[3].information))
    assert np.all(np.abs(se2.between(matches[3].z, step)) < 4 * sigma)


def test_without_odometry_the_constant_velocity_prediction_is_used_and_locks_at_rest():
    """No odometry: KISS-ICP's constant-velocity model predicts. Starting from rest it stays
    at rest: point-to-point ICP on a young 2D map locks onto the previous beam pattern
    (the reason the odometry guess is the default). Pinned here so a change is noticed."""
    rng = np.random.default_rng(11)
    poses = drive(n=8, step=(0.01, 0.0, 0.004))
    matcher = ScanMatcher()
    matches = [matcher.add_scan(make_scan(p, 0.1 * i, rng, noise=0.01)) for i, p in enumerate(poses)]
    reported = [m for m in matches if m is not None]
    assert len(reported) == len(poses) - 1 - matcher.config.warmup_scans
    assert matcher.rejections.counts == {"match_map_warmup": matcher.config.warmup_scans}
    travelled = sum(m.z[0] for m in reported)
    assert travelled < 0.5 * 0.01 * len(reported)  # most of the motion is missed


def test_laser_motion_from_base_motion_matches_composed_poses():
    rng = np.random.default_rng(3)
    mount = np.array([0.3, -0.1, 0.7])
    for _ in range(20):
        x_i = rng.normal(size=3)
        u = rng.normal(scale=0.3, size=3)
        x_j = se2.compose(x_i, u)
        expected = se2.between(se2.compose(x_j, mount), se2.compose(x_i, mount))
        np.testing.assert_allclose(laser_motion_from_base_motion(u, mount), expected, atol=1e-12)


def test_noise_model_information_is_inverse_variance_and_grows_with_motion():
    model = NoiseModel()
    small, large = np.array([0.01, 0.0, 0.0]), np.array([0.1, 0.0, 0.3])
    np.testing.assert_allclose(model.information(small), np.diag(1 / model.sigmas(small) ** 2))
    assert np.all(model.sigmas(large) > model.sigmas(small))


def test_kiss_icp_public_api_is_the_one_the_matcher_calls():
    """ScanMatcher calls only KISS-ICP's public Python wrappers (kiss-icp==1.3.0 in
    requirements.txt); another version that renames or reorders them fails here, by name."""
    import inspect

    from kiss_icp.mapping import VoxelHashMap
    from kiss_icp.registration import Registration
    from kiss_icp.threshold import AdaptiveThreshold
    from kiss_icp.voxelization import voxel_down_sample

    def parameters(function):
        return [p for p in inspect.signature(function).parameters if p != "self"]

    assert parameters(Registration.__init__) == ["max_num_iterations", "convergence_criterion",
                                                 "max_num_threads"]
    assert parameters(Registration.align_points_to_map) == [
        "points", "voxel_map", "initial_guess", "max_correspondance_distance", "kernel"]
    assert parameters(VoxelHashMap.__init__) == ["voxel_size", "max_distance", "max_points_per_voxel"]
    assert parameters(VoxelHashMap.update) == ["points", "pose"]
    assert parameters(VoxelHashMap.clear) == []
    assert parameters(voxel_down_sample) == ["points", "voxel_size"]
    assert parameters(AdaptiveThreshold.__init__) == ["config"]
    assert parameters(AdaptiveThreshold.get_threshold) == []
    assert parameters(AdaptiveThreshold.update_model_deviation) == ["model_deviation"]


def test_adaptive_threshold_matches_as_fixed_threshold_none_asks():
    """The adaptive threshold (fixed_threshold=None) runs through KISS-ICP's KISSConfig."""
    matcher = ScanMatcher(ScanMatcherConfig(fixed_threshold=None, warmup_scans=0))
    assert matcher._threshold.get_threshold() == pytest.approx(0.3)  # initial_threshold
