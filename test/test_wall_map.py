"""The map of walls and the floor region it bounds (diagnosis/wall_map.py,
effects/floor_noise.py), on a drawn floor plan: a corridor (y −2..0) below two rooms
(A: x 0-6, B: x 6-12, y 0-5), a door from the corridor into A at x 2.5-3.5 and one from
A into B at y 2-3. The route: along the corridor, up through its door, across A and
through the second door into B."""
import numpy as np
import pytest

from sclam_ros.core import se2
from sclam_ros.diagnosis.effects import LIBRARY, EffectData
from sclam_ros.diagnosis.config import FloorNoiseConfig, WallMapConfig
from sclam_ros.diagnosis.wall_map import WallMap
from test_diagnose_noise import _disagreements

WALLS = [  # (x0, y0, x1, y1) m
    (0, -2, 12, -2), (0, 5, 12, 5), (0, -2, 0, 5), (12, -2, 12, 5),  # outline
    (0, 0, 2.5, 0), (3.5, 0, 12, 0),  # corridor | rooms, door into A
    (6, 0, 6, 2), (6, 3, 6, 5),  # A | B, door at y 2-3
]
POSES = np.array([[1.0, -1.0, 0.3], [3.0, 2.5, -1.2], [9.0, 2.5, 2.0], [5.0, 4.0, 0.0]])


def _wall_points(spacing=0.02):
    out = []
    for x0, y0, x1, y1 in WALLS:
        t = np.linspace(0, 1, int(np.hypot(x1 - x0, y1 - y0) / spacing) + 1)[:, None]
        out.append(np.column_stack([x0 + t[:, 0] * (x1 - x0), y0 + t[:, 0] * (y1 - y0)]))
    return np.vstack(out)


def _wall_map(mount=np.array([0.2, -0.05, 0.1])):
    """Every pose's laser sees every wall point (no occlusion needed here)."""
    world = _wall_points()
    scans = [se2.transform_points(se2.inverse(se2.compose(pose, mount)), world) for pose in POSES]
    return WallMap.from_scans(POSES, mount, scans)


def _route(step=0.25):
    """Edge mid-points along the route, in time order."""
    legs = [((1, -1), (3, -1)), ((3, -1), (3, 2.5)), ((3, 2.5), (10, 2.5))]
    points = [np.linspace(a, b, int(np.hypot(b[0] - a[0], b[1] - a[1]) / step) + 1)[:-1]
              for a, b in legs]
    return np.vstack(points)


def test_the_scans_are_placed_on_the_walls():
    occupied = _wall_map().occupied
    world = _wall_points()
    nearest = np.min(np.hypot(*(occupied[:, None, :] - world[None, :, :]).transpose(2, 0, 1)),
                     axis=1)
    cell = WallMapConfig().cell
    assert len(occupied) > 0.8 * sum(np.hypot(x1 - x0, y1 - y0) for x0, y0, x1, y1 in WALLS) / cell
    assert nearest.max() <= cell / np.sqrt(2) + 0.01  # a cell's centre, a wall through it


def test_a_room_bounded_at_its_doors_scores_one_and_a_region_spilling_past_a_door_less():
    walls = _wall_map().in_axes(0.0)
    u = _route()
    room_a = (u[:, 1] > 0) & (u[:, 0] < 6)
    assert walls.doorways(u, room_a) == 1.0 and walls.split(u, room_a) == 0.0
    assert walls.score(u, room_a) == 1.0
    spilled = (u[:, 1] > 0) & (u[:, 0] < 7.5)  # 1.5 m into room B
    # In through the corridor's door, out across room B's open floor; A's wall with B
    # runs through it.
    assert walls.doorways(u, spilled) == 0.5
    beyond = np.sum(spilled & (u[:, 0] > 6))
    assert walls.split(u, spilled) == pytest.approx(beyond / spilled.sum())
    assert walls.score(u, spilled) == 0.0  # a wall through it: they do not bound it


def test_a_region_holding_the_corridor_beyond_the_rooms_wall_is_split():
    walls = _wall_map().in_axes(0.0)
    u = _route()
    with_corridor = u[:, 0] < 6  # the corridor stretch, then room A: the wall y = 0 between
    corridor = u[:, 1] < 0
    assert walls.split(u, with_corridor) == pytest.approx(corridor.sum() / with_corridor.sum(),
                                                          abs=1 / with_corridor.sum())
    assert walls.score(u, with_corridor) == 0.0


def test_the_walls_take_the_room_of_rectangles_the_likelihood_cannot_tell_apart():
    # Room A's floor is noisier (variance ratio 3), edges every 5 cm. On some draws the
    # likelihood's best rectangle runs a few dm past a door or stops short of one; the
    # walls take the room on every draw.
    u = _route(step=0.05)
    m = len(u)
    positions = np.vstack([u, u[-1:]])
    room_a = (u[:, 1] >= 0) & (u[:, 0] < 6)  # the edge in the corridor's doorway counted in
    pose = np.arange(m)
    wrong = {None: 0, "walls": 0}
    wall_map = _wall_map()
    for seed in range(30):
        nll = _disagreements(np.random.default_rng(seed), np.where(room_a, 3.0, 1.0)).nll
        found = {}
        for key, walls in ((None, None), ("walls", wall_map)):
            effect = LIBRARY["floor_noise"](EffectData(np.arange(m + 1.0), np.zeros((m + 1, 2)),
                                                       positions, walls=walls))
            effect.fit(pose, pose, nll)
            found[key] = effect.inside(pose, pose)
            wrong[key] += not np.array_equal(found[key], room_a)
        # The walls' choice fits worse than the likelihood's best by less than `within`
        # (plus what refining the factors off the search's grid of levels moves), and
        # the selection is told by how much.
        if np.array_equal(found[None], found["walls"]):
            assert effect.search_deficit == 0.0
        else:
            assert 0.0 < effect.search_deficit <= FloorNoiseConfig().within + 0.5
    assert wrong["walls"] == 0, wrong
    assert wrong[None] >= 3, wrong  # without the walls: 5 of these 30 draws


def test_scans_with_too_few_returns_per_cell_make_no_walls_and_bound_nothing():
    # One return per cell is a stray (WallMapConfig.min_hits): an empty map, which bounds no region.
    walls = WallMap.from_scans(POSES[:1], np.zeros(3), [np.array([[1.0, 0.0], [3.0, 2.0]])])
    assert walls.occupied.shape == (0, 2)
    u = _route()
    assert walls.in_axes(0.4).score(u, u[:, 0] < 6) == 0.0
    assert WallMap.from_scans(POSES[:1], np.zeros(3), [None]) is None


def test_a_floor_factor_the_data_does_not_depend_on_finds_no_region():
    # Every edge's NLL the same at every factor (so on every edge of some fits of the
    # Mines exp1 log with its scans re-stamped by 200 ms): no rectangle is noisier than
    # the rest; sums taken in different orders differ only by rounding.
    rng = np.random.default_rng(0)
    m = 300
    positions = rng.uniform(0, 10, (m + 1, 2))
    per_edge = rng.normal(-10, 3, m)
    pose = np.arange(m)
    for walls in (None, _wall_map()):
        effect = LIBRARY["floor_noise"](EffectData(np.arange(m + 1.0), np.zeros((m + 1, 2)),
                                                   positions, walls=walls))
        effect.fit(pose, pose, lambda factors: per_edge + 0.0 * factors)
        assert effect.value() == 1.0 and effect.describe() == {}
