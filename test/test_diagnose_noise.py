"""Noise effects (variance, not mean) and identifiability, against what was injected.

Synthetic disagreements (fast): the floor region is found from the residuals and its
variance ratio comes back; noise growing with speed comes back as a slope. Simulated
recordings (heavy): one room's carpet is selected with its room found, or named beside
a simpler effect that fits as well; a radius growing
with speed is reported unexplained with the speed named first; a clock offset and a
sweep delay, which a recording with no sweep cannot tell apart, are never selected
together.
"""
import json
from types import SimpleNamespace

import numpy as np
import pytest

from sclam_ros.cli import main as cli
from sclam_ros.core.params import SclamParams
from sclam_ros.diagnosis import identifiability
from sclam_ros.diagnosis.config import IdentifiabilityConfig
from sclam_ros.diagnosis.diagnose import diagnose_keyframes
from sclam_ros.diagnosis.disagreement import Disagreement, OdometryCovariance
from sclam_ros.diagnosis.effects import LIBRARY, EffectData
from sclam_ros.io.recording import read_ground_truth, read_recording
from sclam_ros.sim.effects import make_effect
from sclam_ros.sim.record import simulate

ODOMETRY_COV = np.diag([4e-6, 1e-6, 3e-5])
LASER_COV = np.diag([1e-6, 1e-6, 2e-6])


def _disagreements(rng, factor):
    """Disagreements with covariance factor·odometry + laser, and their NLL function."""
    m = len(factor)
    odometry = np.tile(ODOMETRY_COV, (m, 1, 1))
    laser = np.tile(LASER_COV, (m, 1, 1))
    cov = odometry * factor[:, None, None] + laser
    d = np.einsum("mij,mj->mi", np.linalg.cholesky(cov), rng.standard_normal((m, 3)))
    return Disagreement(d, odometry, laser)


def _route(rng, m):
    """(odometry-frame positions, map-frame positions) along three legs, (0,0) → (12,0) →
    (12,6) → (18,6), with the map's axes at 30° to the odometry frame (which starts at
    whatever heading the robot had)."""
    t = np.linspace(0, 3, m + 1)
    legs = [np.column_stack([12 * t, 0 * t]), np.column_stack([12 + 0 * t, 6 * (t - 1)]),
            np.column_stack([12 + 6 * (t - 2), 6 + 0 * t])]
    along = np.select([t[:, None] < 1, t[:, None] < 2, True], legs)
    along += rng.normal(0, 0.002, along.shape)
    c, s = np.cos(np.radians(30)), np.sin(np.radians(30))
    return along @ np.array([[c, s], [-s, c]]), along


def test_floor_region_and_ratio_from_synthetic_residuals():
    rng = np.random.default_rng(3)
    m = 3000
    positions, map_xy = _route(rng, m)
    room = map_xy[:m, 1] > 2  # the room: the second leg's upper part and the third
    effect = LIBRARY["floor_noise"](EffectData(np.arange(m + 1.0), np.zeros((m + 1, 2)), positions))
    pose = np.arange(m)
    effect.fit(pose, pose, _disagreements(rng, np.where(room, 2.44, 1.0)).nll)
    found = effect.inside(pose, pose)
    assert np.sum(found & room) / np.sum(found | room) > 0.9
    assert effect.value() == pytest.approx(2.44, rel=0.15)
    assert effect.describe()["region"]["angle_deg"] % 90 == pytest.approx(30, abs=2)


def test_floor_ratio_sigma_is_its_spread_over_seeds():
    """The reported σ of the variance ratio matches how far the ratio falls from the truth
    over independent synthetic runs of a recording's size (a room of 150 of 600 edges)."""
    z = []
    for seed in range(30):
        rng = np.random.default_rng(100 + seed)
        m = 600
        positions, map_xy = _route(rng, m)
        room = map_xy[:m, 1] > 4.5  # the third leg and the top of the second
        effect = LIBRARY["floor_noise"](EffectData(np.arange(m + 1.0), np.zeros((m + 1, 2)), positions))
        pose = np.arange(m)
        effect.fit(pose, pose, _disagreements(rng, np.where(room, 2.44, 1.0)).nll)
        z.append((effect.value() - 2.44) / effect.value_sigma())
    rms = float(np.sqrt(np.mean(np.square(z))))
    assert 0.7 < rms < 1.5, rms


def test_a_floor_ratio_the_recording_does_not_determine_does_not_join():
    """Identifiability of a noise effect: a region's variance ratio known only within a
    factor of e^2.4 (a few edges: the Mines exp1 log re-stamped gave 46 ± 110) is not
    determined; one found from a room of 150 of 600 edges is."""
    rng = np.random.default_rng(7)
    m = 600
    positions, map_xy = _route(rng, m)
    room = map_xy[:m, 1] > 4.5
    effect = LIBRARY["floor_noise"](EffectData(np.arange(m + 1.0), np.zeros((m + 1, 2)), positions))
    pose = np.arange(m)
    effect.fit(pose, pose, _disagreements(rng, np.where(room, 2.44, 1.0)).nll)
    edges = SimpleNamespace(pose_i=pose, pose_j=pose)
    config = IdentifiabilityConfig()
    assert identifiability.check(effect, [], None, [effect], edges, config)["determined"]
    effect.log_ratio_sigma = np.log(1 + 110 / 46)
    result = identifiability.check(effect, [], None, [effect], edges, config)
    assert not result["determined"] and not identifiability.separable(result, config)


def test_noise_vs_speed_from_synthetic_residuals():
    rng = np.random.default_rng(4)
    m = 3000
    stamps = np.arange(m + 1.0)
    speed = rng.uniform(0.1, 1.0, m + 1)
    positions = np.column_stack([np.cumsum(speed), np.zeros(m + 1)])  # 1 s per step
    effect = LIBRARY["noise_vs_speed"](EffectData(stamps, np.zeros((m + 1, 2)), positions))
    pose_i, pose_j = np.arange(m), np.arange(1, m + 1)
    v = effect._regressor(pose_i, pose_j)
    truth = np.exp(2.0 * v)  # variance e² times larger at 1 m/s than at 0 m/s
    effect.fit(pose_i, pose_j, _disagreements(rng, truth).nll)
    p10, p90 = np.percentile(v, [10, 90])
    assert effect.value() == pytest.approx(np.exp(2.0 * (p90 - p10)), rel=0.3)


# --- simulated recordings -----------------------------------------------------------------

ROOM = {"x_min": 0.0, "x_max": 11.0, "y_min": 9.0, "y_max": 16.0}  # room n1 of the office


def _diagnose(bag, names=None):
    params = SclamParams.from_yaml(bag / "params.yaml")
    keyframes = read_recording(bag, params, keep_scan_points=True).keyframes
    return diagnose_keyframes(keyframes, params, names).report


def _summary_line(text, start):
    """The line of `sclam diagnose`'s summary that starts (after indentation) with `start`."""
    return next((line for line in text.splitlines() if line.strip().startswith(start)), None)


def _selected(report):
    return [e["name"] for e in report["effects"] if e["selected"]]


@pytest.mark.heavy
@pytest.mark.parametrize("seed", [3, 5])
def test_carpet_in_one_room_is_found(tmp_path, seed, capsys):
    # Selected alone, the room found and its variance ratio within 30 % of what was
    # injected (bench/diagnose_effects.py: so on seeds 1-5). On seed 3 the room is
    # visited in the first half only, so contiguous time blocks alone could not have
    # judged it; on seed 5 the likelihood alone puts the corridor the run starts in with
    # the room (overlap 0.75, `--without-walls`), and the walls seen by the laser bound
    # it. Run as a user would, `sclam diagnose`, which keeps the scans for the walls.
    spec = {"extra": 0.006, **ROOM}
    bag = tmp_path / "carpet"
    truth = simulate(bag, duration=180.0, seed=seed, effects={"floor_noise_area": spec})
    assert cli.main(["diagnose", str(bag), "--params", str(bag / "params.yaml"),
                     "--json", str(tmp_path / "diagnosis.json"), "--quiet"]) == 0
    report = json.loads((tmp_path / "diagnosis.json").read_text())
    assert _selected(report) == ["floor_noise"]
    floor = next(e for e in report["effects"] if e["name"] == "floor_noise")
    # The room is left through its doors only: the walls bound the region found.
    assert _summary_line(capsys.readouterr().out, "region: corners")
    assert floor["region"]["wall_support"] >= 0.5
    assert floor["value"] == pytest.approx(make_effect("floor_noise_area", spec).variance_ratio(),
                                           rel=0.3)
    _, poses = read_ground_truth(tmp_path / "carpet")
    o = truth["odom_origin_in_world"]
    world = poses[:, :2] @ np.array([[np.cos(o[2]), np.sin(o[2])], [-np.sin(o[2]), np.cos(o[2])]]) + o[:2]
    in_room = ((world[:, 0] >= ROOM["x_min"]) & (world[:, 0] <= ROOM["x_max"])
               & (world[:, 1] >= ROOM["y_min"]) & (world[:, 1] <= ROOM["y_max"]))
    region = floor["region"]
    a = np.radians(region["angle_deg"])
    u = poses[:, 0] * np.cos(a) + poses[:, 1] * np.sin(a)
    w = -poses[:, 0] * np.sin(a) + poses[:, 1] * np.cos(a)
    found = ((u >= region["along"][0]) & (u <= region["along"][1])
             & (w >= region["across"][0]) & (w <= region["across"][1]))
    assert np.sum(found & in_room) / np.sum(found | in_room) >= 0.8


@pytest.mark.heavy
def test_a_carpet_where_the_robot_drives_slowly_is_selected_or_named(tmp_path):
    # On this drive the carpeted room is where the robot drives slowly (0.21 against
    # 0.35 m/s elsewhere), so noise that grows as the speed drops can fit the data about
    # as well as the room does, and the simpler of the two may be selected: then the
    # report names the room's effect as fitting about as well. (The benchmark selects the
    # room on it.)
    simulate(tmp_path / "carpet", duration=180.0, seed=7,
             effects={"floor_noise_area": {"extra": 0.006, **ROOM}})
    report = _diagnose(tmp_path / "carpet")
    named = {a for e in report["effects"] if e["selected"]
             for a in e["evidence"].get("alternatives", [])}
    assert "floor_noise" in set(_selected(report)) | named


@pytest.mark.heavy
def test_speed_dependent_radius_is_named_by_the_speed(tmp_path):
    simulate(tmp_path / "radius", duration=180.0, seed=2, effects={"speed_dependent_radius": 0.1})
    report = _diagnose(tmp_path / "radius")
    assert _selected(report) == []
    assert report["unexplained_cause"][0]["regressor"] in ("v", "abs_v", "v_squared")
    assert report["unexplained_cause"][0]["fraction_explained"] > 0.05


@pytest.mark.heavy
def test_clock_offset_and_sweep_delay_are_not_selected_together(tmp_path):
    """A 10 Hz sweep: its delay is a clock offset to first order. Only one of the two
    may be selected; if both had the evidence the pair is reported as not separable."""
    simulate(tmp_path / "sweep", duration=90.0, seed=1, effects={"scan_motion": 1.0})
    report = _diagnose(tmp_path / "sweep", ["time_offset", "scan_distortion"])
    assert _selected(report) == ["scan_distortion"]
    for pair in report["not_separable"]:
        assert pair["effects"] == ["scan_distortion", "time_offset"]
        assert pair["correlation"] > 0.9 and pair["selected"] == ["scan_distortion"]


def test_noise_effects_scale_the_wheels_noise_not_the_sideways_slip():
    # A floor or speed where the wheels slip more scales their noise; the sideways slip
    # (full rank for the edges), the encoders' quantisation and the interpolation stay.
    params = SclamParams()
    k = np.array([0.1, 0.1, 0.5])
    straight = np.array([[2.0, 2.0]])  # both wheels 2 rad: 0.2 m straight ahead
    inputs = SimpleNamespace(odo_dphi=straight, odo_parts=None, odo_variance=np.zeros((1, 2)),
                             odo_path_variance=np.zeros(1))
    cov = OdometryCovariance.of(inputs, params, k)
    wheels, rest = cov.wheels[0], cov.total[0] - cov.wheels[0]
    # Two wheels move the robot in two ways only (rank 2), ...
    assert np.linalg.eigvalsh(wheels)[0] < 1e-9 * np.linalg.eigvalsh(wheels)[-1]
    # ... along the motion by both wheels' noise, (r/2)²·σ²·|dφ| each, ...
    assert wheels[0, 0] == pytest.approx(2 * (0.1 / 2) ** 2 * params.wheel_noise**2 * 2.0, rel=1e-6)
    # ... and the sideways slip of 0.2 m is left out of them.
    assert rest[1, 1] == pytest.approx(params.lateral_noise**2 * 0.2, rel=0.01)
    assert np.all(np.linalg.eigvalsh(rest) >= -1e-15)
