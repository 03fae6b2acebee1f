"""Variance component estimation on a real (simulated) recording: the scales it settles on
are those of the measurements' true errors, not a runaway.

With 1 Hz encoders the odometry model misfits (the path between samples), and on this
10-minute drive the scan matches' scale had fallen round after round (0.2 → 0.006) while
their true errors measure ~0.1 of the stated variance: the poses followed the matches ever
closer and the residuals left to them shrank with their scale, so the laser y came out
4.8σ off. A group that has not settled when the rounds are used up keeps its one-step
estimate (variance_components.solve_with_variance_components).
"""
import numpy as np

from sclam_ros.core.covariance import Influence
from sclam_ros.core.estimator import calibrate_keyframes
from sclam_ros.core.params import CALIBRATION_KEYS, SclamParams
from sclam_ros.core.variance_components import component_scales
from sclam_ros.io.recording import read_ground_truth, read_recording
from sclam_ros.sim import simulate


def _true_mean_squared_whitened(result, bag, truth, name, axis=None):
    """Mean squared error of a factor group's edges at the true poses and calibration,
    whitened by the stated model (scale 1): the variance scale the data should give
    (per component of the edge with axis=0)."""
    problem = result.problem
    stamps, poses = read_ground_truth(bag)
    heading = np.unwrap(poses[:, 2])
    values = problem.values.copy()
    values["poses"] = np.column_stack([np.interp(result.stamps, stamps, poses[:, 0]),
                                       np.interp(result.stamps, stamps, poses[:, 1]),
                                       np.interp(result.stamps, stamps, heading)])
    values["odometry"] = np.array([[truth[k] for k in CALIBRATION_KEYS[:3]]])
    values["laser"] = np.array([[truth[k] for k in CALIBRATION_KEYS[3:]]])
    factors = [f for f in problem.factors if f.name == name]
    lin = factors[0].linearize(values)
    whitened = np.einsum("mij,mj->mi", lin.sqrt_information, lin.residual)
    return np.mean(whitened ** 2, axis=axis)


def test_scan_match_scale_does_not_run_away_with_slow_odometry(tmp_path):
    bag = tmp_path / "bag"
    truth = simulate(bag, duration=600.0, seed=3, encoder_rate=1.0)
    params = SclamParams.from_yaml(bag / "params.yaml")
    recording = read_recording(bag, params)
    result = calibrate_keyframes(recording.keyframes, params, recording.rejections)
    true_scale = _true_mean_squared_whitened(result, bag, truth, "laser")
    # The stated model overstates the merged edges' noise: a keyframe edge sums its
    # matches' covariances, and their errors correlate negatively (−0.4 at lag 1).
    assert 0.05 < true_scale < 0.8
    assert true_scale / 3 < result.variance_scales["laser"] < 3 * true_scale
    for key in CALIBRATION_KEYS:
        assert abs(result.estimate[key] - truth[key]) < 3 * result.sigma[key], key


def test_odometry_scale_is_estimated_where_the_laser_sees_little_along_corridors(tmp_path):
    """Among bare corridors a 5.6 m laser fixes little of the motion along them: the
    odometry keeps only 6-15 % of its size as redundancy. That is still 80-150 redundant
    components, enough to measure its noise: its scale is estimated and lies near its true
    errors' (the simulator's slip is smaller than the stated model: about 0.27), not at
    the stated model, which makes the radii's σ 1.6 times too large."""
    bag = tmp_path / "bag"
    truth = simulate(bag, duration=120.0, seed=1, scene="corridors", beams=683, range_noise=0.03,
                     laser=dict(fov=np.radians(240.0), range_max=5.6))
    params = SclamParams.from_yaml(bag / "params.yaml")
    recording = read_recording(bag, params)
    result = calibrate_keyframes(recording.keyframes, params, recording.rejections)
    true_scale = _true_mean_squared_whitened(result, bag, truth, "odometry")
    assert true_scale < 0.5
    assert "odometry" in result.variance_scales
    assert 0.7 * true_scale < result.variance_scales["odometry"] < 2.0 * true_scale


def test_the_odometry_noise_scale_per_component_follows_its_true_errors(tmp_path):
    """The default parameters state more sideways slip than the simulated robot has: at the
    truth the odometry's whitened sideways errors have a fraction of the mean square of its
    other components, which one variance scale for the edge type cannot show. The scale
    per component that the reported covariance uses (variance_components.component_scales)
    shows it; the laser yaw's σ rests on the sideways part."""
    bag = tmp_path / "bag"
    truth = simulate(bag, duration=120.0, seed=1, scene="corridors")
    params = SclamParams.from_yaml(bag / "params.yaml")
    recording = read_recording(bag, params)
    result = calibrate_keyframes(recording.keyframes, params, recording.rejections)
    true_square = _true_mean_squared_whitened(result, bag, truth, "odometry", axis=0)
    true_square = true_square / result.variance_scales["odometry"]
    problem = result.problem
    influence = Influence.of(problem, problem.values, ["odometry", "laser"])
    (_, start, stop), = [r for r in influence.system.row_ranges if r[0] == "odometry"]
    scales = component_scales(influence, start, stop, 3)
    assert true_square[1] < 0.6 * min(true_square[0], true_square[2]), true_square  # the premise
    # Between its truth and the one scale: the residuals carry the scan matches' sideways
    # errors too, so the estimate leans to the conservative side.
    assert 0.8 * true_square[1] < scales[1] < 0.6 * min(scales[0], scales[2]), (scales, true_square)
