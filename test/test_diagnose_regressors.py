"""The residual tests' regressors must not share the residuals' noise.

An odometry residual is the poses' motion minus the wheels'. On a straight drive the
wheels' turn rate is their slip noise alone, so the residual's heading against the wheels'
own turn rate is strong "structure" on a recording with no effect at all. The graph's
poses weigh the laser's and the wheels' motion by their information, and a least-squares
fit leaves residuals uncorrelated with what it fitted: the poses' turn rate does not carry
the residuals' noise.
"""
import numpy as np

from sclam_ros.core import graph, kinematics, se2
from sclam_ros.diagnosis.config import StructureConfig
from sclam_ros.diagnosis.effects.base import EffectData
from sclam_ros.diagnosis.regressors import pose_motion, regressors
from sclam_ros.diagnosis.structure import residual_tests, significant

K = np.array([0.1, 0.1, 0.4])  # r_l, r_r, b (m)
EDGES = 300
DT = 0.5  # s
SPEED = 0.3  # m/s
WHEEL_NOISE = 0.01  # rad per wheel per edge: 2.5 mrad of heading, as slip noise gives
# rad of heading per edge from the scan matches: a tenth of the wheels' (2.5 mrad), as in
# the simulated corridors where the wheels' own turn rate showed as structure (laser
# 0.7 mrad per 0.3 s match, wheels 7 mrad per 0.5 s edge)
LASER_NOISE = 0.00025


def _straight_drive(seed=3):
    rng = np.random.default_rng(seed)
    stamps = DT * np.arange(EDGES + 1)
    dphi = np.full((EDGES, 2), SPEED * DT / K[0]) + WHEEL_NOISE * rng.standard_normal((EDGES, 2))
    wheel_turn = kinematics.forward(dphi, K)[:, 2]
    laser_turn = LASER_NOISE * rng.standard_normal(EDGES)
    wheel_variance = 2 * (K[0] * WHEEL_NOISE / K[2]) ** 2
    # each edge's turn as the graph weighs the two (information-weighted mean)
    turn = ((laser_turn / LASER_NOISE ** 2 + wheel_turn / wheel_variance)
            / (1 / LASER_NOISE ** 2 + 1 / wheel_variance))
    poses = np.zeros((EDGES + 1, 3))
    poses[:, 0] = SPEED * stamps
    poses[1:, 2] = np.cumsum(turn)
    inputs = graph.GraphInputs(stamps=stamps, odo_from=np.arange(EDGES), odo_dphi=dphi,
                               laser_from=np.zeros(0, int), laser_to=np.zeros(0, int),
                               laser_z=np.zeros((0, 3)), laser_info=np.zeros((0, 3, 3)))
    wheel_speeds = np.vstack([dphi[:1], 0.5 * (dphi[1:] + dphi[:-1]), dphi[-1:]]) / DT
    data = EffectData(stamps=stamps, wheel_speeds=wheel_speeds)
    residual = se2.wrap_angle(pose_motion(inputs, poses)[:, 2] - kinematics.forward(dphi, K)[:, 2])
    return inputs, data, poses, {"odometry.theta": residual / np.std(residual)}


def _structure(inputs, data, poses, residuals, motion):
    wheel_angles = np.vstack([np.zeros(2), np.cumsum(inputs.odo_dphi, axis=0)])
    regs = regressors(inputs, data, wheel_angles, K, poses, motion=motion)
    edge_of = {"odometry.theta": np.arange(EDGES)}
    found = significant(residual_tests(residuals, regs, edge_of, StructureConfig()), StructureConfig())
    return {t["regressor"] for t in found}


def test_the_wheels_own_turn_rate_shows_their_noise_as_structure():
    inputs, data, poses, residuals = _straight_drive()
    assert {"omega", "v_times_omega"} <= _structure(inputs, data, poses, residuals, motion=None)


def test_the_poses_turn_rate_shows_no_structure_on_a_straight_drive():
    inputs, data, poses, residuals = _straight_drive()
    assert _structure(inputs, data, poses, residuals, motion=pose_motion(inputs, poses)) == set()


def test_the_poses_arc_has_the_wheels_length_and_turn():
    """Without noise both motions agree: the regressors measure the same thing."""
    dphi = np.array([[3.0, 3.4], [2.0, 2.0], [-1.0, 1.0]])
    wheel = kinematics.forward(dphi, K)
    poses = np.vstack([np.zeros(3), se2.compose(np.zeros(3), wheel[0])])
    poses = np.vstack([poses, se2.compose(poses[-1], wheel[1])])
    poses = np.vstack([poses, se2.compose(poses[-1], wheel[2])])
    inputs = graph.GraphInputs(stamps=np.arange(4.0), odo_from=np.arange(3), odo_dphi=dphi,
                               laser_from=np.zeros(0, int), laser_to=np.zeros(0, int),
                               laser_z=np.zeros((0, 3)), laser_info=np.zeros((0, 3, 3)))
    data = EffectData(stamps=np.arange(4.0), wheel_speeds=np.zeros((4, 2)))
    angles = np.vstack([np.zeros(2), np.cumsum(dphi, axis=0)])
    from_wheels = regressors(inputs, data, angles, K, poses)
    from_poses = regressors(inputs, data, angles, K, poses, motion=pose_motion(inputs, poses))
    for name in ("v", "omega", "v_times_omega", "distance"):
        np.testing.assert_allclose(from_poses[name], from_wheels[name], atol=1e-9)
