"""Effect factors: Jacobians against central differences, identity at zero, the graph
recovers an injected effect from synthetic edges."""
import numpy as np
import pytest
from numdiff import check_factor_jacobians

from sclam_ros.core import kinematics, se2
from sclam_ros.diagnosis.effects import LIBRARY, EffectData
from sclam_ros.diagnosis.effects.model import EffectLaserFactor, EffectOdometryFactor
from sclam_ros.core.factors import LaserFactor, OdometryFactor
from sclam_ros.core.problem import Values

rng = np.random.default_rng(7)
N = 6


def data():
    stamps = np.cumsum(rng.uniform(0.3, 0.6, N))
    return EffectData(stamps, rng.normal(0, 3, (N, 2)), rng.normal(0, 5, (N, 2)),
                      rng.normal(0, 1, N))


def values_with(effects, p=None):
    poses = np.column_stack([rng.normal(0, 3, (N, 2)), rng.uniform(-3, 3, N)])
    v = Values({"poses": poses, "odometry": [[0.12, 0.13, 0.55]], "laser": [[0.22, -0.05, 0.4]]},
               angular={"poses": [False, False, True], "laser": [False, False, True]})
    for e in effects:
        v.add(e.name, [rng.normal(0, 0.1, e.dim) if p is None else p[e.name]])
    return v


def merged_parts():
    """Per-scan increments of merged edges: ragged (zero-padded), curvature changing."""
    parts = rng.normal(0, 0.6, (N - 1, 4, 2))
    parts[1, 3] = 0.0
    parts[3, 2:] = 0.0
    return parts


@pytest.mark.parametrize("merged", [False, True])
@pytest.mark.parametrize("names", [["time_offset"], ["lateral_slip"], ["radius_drift"],
                                   ["scan_distortion"],
                                   ["time_offset", "lateral_slip", "radius_drift", "scan_distortion"]])
def test_odometry_effect_jacobians(names, merged):
    d = data()
    effects = [LIBRARY[n](d) for n in names]
    values = values_with(effects)
    parts = merged_parts() if merged else None
    dphi = parts.sum(1) if merged else rng.normal(0, 2, (N - 1, 2))
    f = EffectOdometryFactor(np.arange(N - 1), np.arange(1, N), dphi,
                             np.tile(np.eye(3), (N - 1, 1, 1)), effects, parts=parts)
    check_factor_jacobians(f, values)


def test_scan_distortion_jacobians():
    d = data()
    effects = [LIBRARY["scan_distortion"](d)]
    values = values_with(effects)
    z = np.column_stack([rng.normal(0, 1, (N - 1, 2)), rng.uniform(-1, 1, N - 1)])
    f = EffectLaserFactor(np.arange(N - 1), np.arange(1, N), z, np.tile(np.eye(3), (N - 1, 1, 1)),
                          effects)
    check_factor_jacobians(f, values)


@pytest.mark.parametrize("merged", [False, True])
def test_zero_effects_reduce_to_base_factors(merged):
    d = data()
    effects = [LIBRARY[n](d) for n in ("time_offset", "lateral_slip", "radius_drift",
                                       "scan_distortion")]
    values = values_with(effects, {e.name: np.zeros(e.dim) for e in effects})
    parts = merged_parts() if merged else None
    dphi = parts.sum(1) if merged else rng.normal(0, 2, (N - 1, 2))
    info = np.tile(np.eye(3), (N - 1, 1, 1))
    ext = EffectOdometryFactor(np.arange(N - 1), np.arange(1, N), dphi, info, effects, parts=parts)
    base = OdometryFactor(np.arange(N - 1), np.arange(1, N), dphi, info, parts=parts)
    assert np.allclose(ext.residuals(values), base.residuals(values), rtol=0, atol=1e-14)
    lin_e, lin_b = ext.linearize(values), base.linearize(values)
    for jb in lin_b.blocks:
        je = next(b for b in lin_e.blocks if b.block == jb.block and np.array_equal(b.rows, jb.rows))
        assert np.allclose(je.jacobian, jb.jacobian, atol=1e-14)
    if merged:  # the composed arcs differ from one arc over the edge: the test has teeth
        single = OdometryFactor(np.arange(N - 1), np.arange(1, N), dphi, info)
        assert not np.allclose(single.residuals(values), base.residuals(values), atol=1e-6)
    z = rng.normal(0, 1, (N - 1, 3))
    assert np.allclose(EffectLaserFactor(np.arange(N - 1), np.arange(1, N), z, info, effects)
                       .residuals(values),
                       LaserFactor(np.arange(N - 1), np.arange(1, N), z, info).residuals(values))


def test_extend_problem_keeps_the_parts():
    from sclam_ros.diagnosis.effects.model import extend_problem
    from sclam_ros.core.problem import Problem

    d = data()
    effects = [LIBRARY["time_offset"](d)]
    values = values_with([])
    parts = merged_parts()
    info = np.tile(np.eye(3), (N - 1, 1, 1))
    base = OdometryFactor(np.arange(N - 1), np.arange(1, N), parts.sum(1), info, parts=parts)
    ext = extend_problem(Problem(values, [base]), effects)
    odo = next(f for f in ext.factors if f.name == "odometry")
    assert isinstance(odo, EffectOdometryFactor) and np.array_equal(odo.parts, base.parts)
    assert np.allclose(odo.residuals(ext.values), base.residuals(values), rtol=0, atol=1e-14)


def test_scan_distortion_delay_is_a_clock_offset():
    """The sweep delay τ shifts the odometry window exactly as a clock offset δ = τ does."""
    d = data()
    to, sd = LIBRARY["time_offset"](d), LIBRARY["scan_distortion"](d)
    dphi = rng.normal(0, 2, (N - 1, 2))
    i, j = np.arange(N - 1), np.arange(1, N)
    assert np.allclose(to.adjust_dphi(dphi, [0.05], i, j)[0],
                       sd.adjust_dphi(dphi, [0.05, 0.3, -0.2], i, j)[0])


def test_scan_distortion_corrects_a_turn_rate_change():
    """A match shifted by −g·(ω_j − ω_i) comes back; at a constant turn rate (an
    on-the-spot turn) nothing changes."""
    turn = np.array([0.0, 0.8, 0.8, -0.5, -0.5, 0.0])
    d = EffectData(np.arange(N) * 0.5, np.zeros((N, 2)), None, turn)
    g = np.array([0.04, -0.01])
    i, j = np.arange(N - 1), np.arange(1, N)
    truth = np.column_stack([rng.normal(0, 0.3, (N - 1, 2)), rng.uniform(-0.4, 0.4, N - 1)])
    measured = truth.copy()
    measured[:, :2] -= np.outer(turn[j] - turn[i], g)
    effect = LIBRARY["scan_distortion"](d)
    assert np.allclose(effect.adjust_z(measured, np.r_[0.0, g], i, j)[0], truth)
    constant = [1, 3]  # edges 1→2 and 3→4 turn at a constant rate
    assert np.allclose(effect.adjust_z(truth, np.r_[0.0, g], i, j)[0][constant], truth[constant])


def test_turn_rates_from_scan_matches():
    from sclam_ros.frontend.pipeline import Keyframe

    t = np.arange(0, 2, 0.1)
    kfs = [Keyframe(i, s, np.zeros(2)) for i, s in enumerate(t)]
    for kf in kfs[1:]:
        if kf.index != 7:  # a failed match: bridged by interpolation
            kf.laser_from, kf.laser_motion = kf.index - 1, np.array([0.05, 0.0, 0.1 * kf.stamp])
    d = EffectData.from_keyframes(kfs, t[2:-2])
    # Heading change 0.1·t_k over 0.1 s: rate t_k, placed at t_k − 0.05.
    assert np.allclose(d.turn_rates, t[2:-2] + 0.05)


def test_wheel_speeds_from_keyframes():
    from sclam_ros.frontend.pipeline import Keyframe

    t = np.arange(0, 2, 0.1)
    kfs = [Keyframe(i, s, np.array([3.0 * s, -2.0 * s])) for i, s in enumerate(t)]
    d = EffectData.from_keyframes(kfs, t[::5])
    assert np.allclose(d.wheel_speeds, [[3.0, -2.0]] * 4)
