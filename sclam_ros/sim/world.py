"""The simulated worlds: walls as line segments, ray casting, clearance.

The default floor plan is an office floor (30 m × 16 m): a corridor with five rooms on both
sides, doors between them, an open hall with pillars, and furniture along the walls so
that every scan has corners to match. The other scenes (SCENES) are open ground with
trees, poles and parked cars (outdoor_world) and a ring of bare corridors between four
lobbies (corridors_world). Beside the walls each carries a roadmap (nodes in
free space and straight, collision-free edges between them) that the trajectory
generator walks; ``test_sim`` checks every edge against the walls.

Everything is vectorised over rays × segments because the laser model casts a few
million rays for a 20-minute recording.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Optional

import numpy as np


def _polyline(*points) -> list[tuple[float, float, float, float]]:
    return [(*points[i], *points[i + 1]) for i in range(len(points) - 1)]


def _wall_with_doors(start, end, doors, width) -> list[tuple[float, float, float, float]]:
    """An axis-aligned wall from ``start`` to ``end`` with door gaps centred at ``doors``
    (coordinates along the wall's varying axis)."""
    (x0, y0), (x1, y1) = start, end
    horizontal = y0 == y1
    lo, hi = (x0, x1) if horizontal else (y0, y1)
    cuts = [lo]
    for centre in sorted(doors):
        cuts += [centre - width / 2, centre + width / 2]
    cuts.append(hi)
    segments = []
    for a, b in zip(cuts[0::2], cuts[1::2]):
        if b > a:
            segments.append((a, y0, b, y0) if horizontal else (x0, a, x0, b))
    return segments


def _box(cx, cy, w, h) -> list[tuple[float, float, float, float]]:
    """Closed rectangle (furniture, pillars) centred at (cx, cy)."""
    x0, x1, y0, y1 = cx - w / 2, cx + w / 2, cy - h / 2, cy + h / 2
    return _polyline((x0, y0), (x1, y0), (x1, y1), (x0, y1), (x0, y0))


@dataclass
class World:
    """Walls (S, 4) as x1, y1, x2, y2 and a roadmap through the free space."""

    segments: np.ndarray
    nodes: dict[str, tuple[float, float]] = field(default_factory=dict)
    edges: list[tuple[str, str]] = field(default_factory=list)
    # Nodes in open areas where loops, figure-eights and spins fit.
    open_nodes: tuple[str, ...] = ()
    bounds: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)  # xmin, ymin, xmax, ymax

    def neighbours(self, node: str) -> list[str]:
        out = [b for a, b in self.edges if a == node] + [a for a, b in self.edges if b == node]
        return sorted(out)

    def raycast(self, pose_xyth, angles, max_range: float) -> np.ndarray:
        """Ranges of beams at ``angles`` (in the frame of ``pose_xyth``) from that pose."""
        pose = np.asarray(pose_xyth, float)
        angles = np.asarray(angles, float)
        origins = np.broadcast_to(pose[:2], angles.shape + (2,))
        return cast_rays(self.segments, origins, pose[2] + angles, max_range)

    def clearance(self, points) -> np.ndarray:
        """Distance of each point (N, 2) to the nearest wall."""
        return distance_to_segments(self.segments, points)

    def inside_bounds(self, points) -> np.ndarray:
        p = np.atleast_2d(points)
        xmin, ymin, xmax, ymax = self.bounds
        return (p[:, 0] > xmin) & (p[:, 0] < xmax) & (p[:, 1] > ymin) & (p[:, 1] < ymax)


def cast_rays(segments, origins, directions, max_range: float, chunk: int = 4096) -> np.ndarray:
    """Range of each ray to the first wall it hits; ``inf`` beyond ``max_range`` or no hit.

    segments (S, 4); origins (R, 2); directions (R,) world angles. Solves
    p + t·d = a + u·(b − a) for every ray/segment pair at once: t is the range and
    0 ≤ u ≤ 1 says the hit lies on the segment.
    """
    segments = np.asarray(segments, float)
    origins = np.asarray(origins, float).reshape(-1, 2)
    directions = np.asarray(directions, float).reshape(-1)
    ax, ay = segments[:, 0], segments[:, 1]
    ex, ey = segments[:, 2] - ax, segments[:, 3] - ay
    out = np.empty(len(directions))
    for start in range(0, len(directions), chunk):
        stop = start + chunk
        dx = np.cos(directions[start:stop])[:, None]
        dy = np.sin(directions[start:stop])[:, None]
        apx = ax[None, :] - origins[start:stop, 0:1]
        apy = ay[None, :] - origins[start:stop, 1:2]
        denom = dx * ey - dy * ex
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (apx * ey - apy * ex) / denom
            u = (apx * dy - apy * dx) / denom
        # Parallel rays (denom 0) give inf/nan and fail these comparisons: no hit.
        hit = (t > 0.0) & (u >= 0.0) & (u <= 1.0)
        out[start:stop] = np.where(hit, t, np.inf).min(axis=1)
    out[out > max_range] = np.inf
    return out


def distance_to_segments(segments, points) -> np.ndarray:
    """Euclidean distance of each point (N, 2) to the nearest of the segments (S, 4)."""
    segments = np.asarray(segments, float)
    p = np.atleast_2d(np.asarray(points, float))
    a = segments[None, :, :2]
    e = segments[None, :, 2:] - segments[None, :, :2]
    ap = p[:, None, :] - a
    u = np.clip((ap * e).sum(-1) / (e * e).sum(-1), 0.0, 1.0)
    closest = a + u[..., None] * e
    return np.sqrt(((p[:, None, :] - closest) ** 2).sum(-1)).min(axis=1)


def office_world() -> World:
    """The default floor plan (see the module docstring); coordinates in metres."""
    door = 1.6  # m, wide enough for the largest preset robot with margin
    walls = []
    walls += _polyline((0, 0), (30, 0), (30, 16), (0, 16), (0, 0))
    # Corridor y ∈ [6.5, 9] from x = 0 to the hall at x = 22.
    walls += _wall_with_doors((0, 6.5), (22, 6.5), [3.5, 10.5, 18.0], door)
    walls += _wall_with_doors((0, 9.0), (22, 9.0), [5.0, 16.0], door)
    # Room dividers and the wall between the rooms and the hall.
    walls += _polyline((7, 0), (7, 6.5))
    walls += _polyline((14, 0), (14, 6.5))
    walls += _wall_with_doors((11, 9), (11, 16), [12.5], door)
    walls += _wall_with_doors((22, 0), (22, 6.5), [3.25], door)
    walls += _wall_with_doors((22, 9), (22, 16), [12.5], door)
    # Furniture along the walls (cabinets, desks) and pillars in the hall: corners for
    # the scan matcher, kept off the roadmap.
    walls += _box(0.9, 0.6, 1.2, 0.6)
    walls += _box(6.2, 5.4, 0.8, 1.6)
    walls += _box(8.0, 0.5, 1.6, 0.6)
    walls += _box(13.3, 4.8, 0.8, 1.2)
    walls += _box(15.0, 0.6, 1.2, 0.8)
    walls += _box(21.3, 5.6, 0.8, 1.0)
    walls += _box(1.0, 15.3, 1.4, 0.8)
    walls += _box(9.2, 15.4, 2.0, 0.6)
    walls += _box(12.2, 10.0, 1.0, 1.0)
    walls += _box(20.4, 15.3, 1.6, 0.8)
    walls += _box(28.5, 5.5, 0.5, 0.5)
    walls += _box(28.5, 10.0, 0.5, 0.5)
    walls += _box(24.0, 1.2, 0.5, 0.5)
    walls += _box(24.0, 14.8, 0.5, 0.5)
    walls += _box(29.2, 15.2, 1.0, 1.0)
    corridor_y, south_y, north_y, hall_x = 7.75, 3.25, 12.5, 26.0
    nodes = {
        "corridor_west": (1.5, corridor_y),
        "corridor_s1": (3.5, corridor_y),
        "corridor_n1": (5.0, corridor_y),
        "corridor_s2": (10.5, corridor_y),
        "corridor_n2": (16.0, corridor_y),
        "corridor_s3": (18.0, corridor_y),
        "corridor_east": (20.5, corridor_y),
        "room_s1": (3.5, south_y),
        "room_s2": (10.5, south_y),
        "room_s3": (18.0, south_y),
        "room_n1": (5.0, north_y),
        "room_n2": (16.0, north_y),
        "hall_south": (hall_x, south_y),
        "hall_centre": (hall_x, corridor_y),
        "hall_north": (hall_x, north_y),
    }
    edges = [
        ("corridor_west", "corridor_s1"),
        ("corridor_s1", "corridor_n1"),
        ("corridor_n1", "corridor_s2"),
        ("corridor_s2", "corridor_n2"),
        ("corridor_n2", "corridor_s3"),
        ("corridor_s3", "corridor_east"),
        ("corridor_east", "hall_centre"),
        ("corridor_s1", "room_s1"),
        ("corridor_s2", "room_s2"),
        ("corridor_s3", "room_s3"),
        ("corridor_n1", "room_n1"),
        ("corridor_n2", "room_n2"),
        ("room_n1", "room_n2"),
        ("room_n2", "hall_north"),
        ("room_s3", "hall_south"),
        ("hall_south", "hall_centre"),
        ("hall_centre", "hall_north"),
    ]
    open_nodes = (
        "room_s1",
        "room_s2",
        "room_s3",
        "room_n1",
        "room_n2",
        "hall_south",
        "hall_centre",
        "hall_north",
    )
    return World(np.array(walls, float), nodes, edges, open_nodes, (0.0, 0.0, 30.0, 16.0))


def _polygon(cx, cy, radius, sides, turn=0.0) -> list[tuple[float, float, float, float]]:
    """A round object (tree trunk, pole) as a closed polygon of `sides` corners."""
    angles = np.linspace(0.0, 2.0 * np.pi, sides + 1) + turn
    return _polyline(*[(cx + radius * np.cos(a), cy + radius * np.sin(a)) for a in angles])


@dataclass(frozen=True)
class OutdoorScene:
    """The outdoor scene's objects, as simulated or changed one factor at a time
    (bench/sensor_matrix.py --outdoor-variant). The layout is the same in every variant."""

    # a tree trunk drawn as: "octagon" (as simulated), "32-gon" (rounder), "box" (a square
    # of its width) or "none" (no trunks).
    trunks: str = "octagon"
    # whether the parked cars are there (the poles and the façade always are).
    parked_cars: bool = True

    def trunk(self, cx, cy, radius) -> list[tuple[float, float, float, float]]:
        if self.trunks == "octagon":
            return _polygon(cx, cy, radius, 8, np.pi / 8.0)
        if self.trunks == "32-gon":
            return _polygon(cx, cy, radius, 32)
        if self.trunks == "box":
            return _box(cx, cy, 2.0 * radius, 2.0 * radius)
        if self.trunks == "none":
            return []
        raise ValueError(f"unknown trunks {self.trunks!r}: octagon, 32-gon, box or none")


def outdoor_world(scene: OutdoorScene = OutdoorScene()) -> World:
    """Open ground (50 m × 30 m) with few long walls: a car park with two streets.

    What a planar laser sees outdoors: tree trunks and poles (small round objects), parked
    cars (boxes), and one building façade at the north-east. Most beams return nothing
    within a 20 m laser's range; there are few lines for a point-to-line matcher. The
    roadmap is a ladder of two streets (y = 8, y = 22) joined by three cross streets;
    objects keep at least 3 m from every street so that loops and spins fit beside them.
    ``scene``: the objects' variant (OutdoorScene).
    """
    rng = np.random.default_rng(2024)  # a fixed layout: the scene is part of the benchmark
    walls = []
    streets_y, cross_x = (8.0, 22.0), (5.0, 25.0, 45.0)
    # Tree rows along both streets, 3.5 m off, every ~6 m (jittered), trunks 0.2-0.4 m.
    for y in streets_y:
        for side in (-1.0, 1.0):
            for x in np.arange(8.0, 44.0, 6.0):
                if min(abs(x - c) for c in cross_x) < 3.5:
                    continue  # keep the crossings clear
                walls += scene.trunk(x + rng.uniform(-1.0, 1.0), y + side * rng.uniform(3.5, 4.5),
                                     rng.uniform(0.2, 0.4))
    # Parked cars (4.5 m × 1.8 m) south of the south street and north of the north street.
    for x in (11.0, 17.0, 31.0, 38.5) if scene.parked_cars else ():
        walls += _box(x, 8.0 - 5.6, 4.5, 1.8)
    for x in (12.5, 33.0) if scene.parked_cars else ():
        walls += _box(x, 22.0 + 5.6, 4.5, 1.8)
    # Poles along the middle cross street.
    for y in (11.0, 15.0, 19.0):
        walls += _box(25.0 + 3.2, y, 0.15, 0.15)
        walls += _box(25.0 - 3.2, y + 2.0, 0.15, 0.15)
    # One building façade with a recessed entrance: the only long lines in the scene.
    walls += _polyline((30.0, 30.0), (38.0, 30.0), (38.0, 31.0), (41.0, 31.0), (41.0, 30.0), (50.0, 30.0))
    nodes = {}
    edges = []
    for j, y in enumerate(streets_y):
        xs = (5.0, 15.0, 25.0, 35.0, 45.0)
        for i, x in enumerate(xs):
            nodes[f"street{j}_{i}"] = (x, y)
            if i:
                edges.append((f"street{j}_{i - 1}", f"street{j}_{i}"))
    for i, x in zip((0, 2, 4), cross_x):
        nodes[f"cross_{i}"] = (x, 15.0)
        edges += [(f"street0_{i}", f"cross_{i}"), (f"cross_{i}", f"street1_{i}")]
    open_nodes = ("street0_1", "street0_3", "street1_1", "street1_3", "cross_0", "cross_2", "cross_4")
    return World(np.array(walls, float), nodes, edges, open_nodes, (0.0, 0.0, 50.0, 30.0))


def corridors_world() -> World:
    """A ring of bare corridors (28 m × 18 m): four corridors 2.4 m wide, two 18 m and two
    8 m long, joining four 5 m × 5 m lobbies at the corners.

    What a laser sees in a building of long bare corridors: two parallel walls without
    doors or furniture, and the far end of a corridor only while it is in range, so a
    match made along a corridor fixes the motion along it poorly; the lobbies' walls and
    corners fix it. The roadmap runs along the corridors' centre lines through the
    lobbies' centres, where loops and spins fit.
    """
    walls = []
    # The outer boundary, then the inner block, each a closed polyline around the ring.
    walls += _polyline((0, 0), (5, 0), (5, 1.3), (23, 1.3), (23, 0), (28, 0), (28, 5), (26.7, 5),
                       (26.7, 13), (28, 13), (28, 18), (23, 18), (23, 16.7), (5, 16.7), (5, 18),
                       (0, 18), (0, 13), (1.3, 13), (1.3, 5), (0, 5), (0, 0))
    walls += _polyline((3.7, 5), (5, 5), (5, 3.7), (23, 3.7), (23, 5), (24.3, 5), (24.3, 13),
                       (23, 13), (23, 14.3), (5, 14.3), (5, 13), (3.7, 13), (3.7, 5))
    nodes = {"lobby_sw": (2.5, 2.5), "corridor_s": (14.0, 2.5), "lobby_se": (25.5, 2.5),
             "corridor_e": (25.5, 9.0), "lobby_ne": (25.5, 15.5), "corridor_n": (14.0, 15.5),
             "lobby_nw": (2.5, 15.5), "corridor_w": (2.5, 9.0)}
    ring = list(nodes)
    edges = [(ring[i], ring[(i + 1) % len(ring)]) for i in range(len(ring))]
    open_nodes = ("lobby_sw", "lobby_se", "lobby_ne", "lobby_nw")
    return World(np.array(walls, float), nodes, edges, open_nodes, (0.0, 0.0, 28.0, 18.0))


# Corridor bands of the scenes that have them, (x range, y range, axis: 0 along world x,
# 1 along y): where a match is "along a corridor" (docs/decisions/match_scale.md).
CORRIDORS = {
    "office": [((0.0, 22.0), (6.5, 9.0), 0)],
    "corridors": [((5.0, 23.0), (1.3, 3.7), 0), ((5.0, 23.0), (14.3, 16.7), 0),
                  ((1.3, 3.7), (5.0, 13.0), 1), ((24.3, 26.7), (5.0, 13.0), 1)],
}
SCENES = {"office": office_world, "outdoor": outdoor_world, "corridors": corridors_world}
MIRRORED = "-mirrored"  # a scene's name with this suffix: that scene reflected (mirrored())


def mirrored(world: World) -> World:
    """`world` reflected across its x axis (y -> -y): every drive through it turns right
    where it turned left. A bias that belongs to the drive's geometry changes sign with it;
    one that belongs to the processing (a preference for one turning direction) does not."""
    xmin, ymin, xmax, ymax = world.bounds
    return World(np.asarray(world.segments, float) * [1.0, -1.0, 1.0, -1.0],
                 {name: (x, -y) for name, (x, y) in world.nodes.items()}, list(world.edges),
                 tuple(world.open_nodes), (xmin, -ymax, xmax, -ymin))


def scene_world(name: str, outdoor: Optional[OutdoorScene] = None) -> World:
    """The scene `name`, or with the MIRRORED suffix that scene mirrored; `outdoor`: the
    outdoor scene's variant (other scenes ignore it)."""
    base = name[:-len(MIRRORED)] if name.endswith(MIRRORED) else name
    if base not in SCENES:
        raise ValueError(f"unknown scene {name!r}; scenes: {', '.join(sorted(SCENES))} "
                         f"(each also as NAME{MIRRORED})")
    world = outdoor_world(outdoor) if base == "outdoor" and outdoor is not None else SCENES[base]()
    return mirrored(world) if base != name else world
