"""A collision-free, calibration-friendly drive through the world, deterministic per seed.

Two steps:

1. ``plan_route``: a random walk on the world's roadmap, turned into *runs*: dense
   polylines that the robot drives without stopping. A run ends where the robot stops
   and turns on the spot (sharp corners, dead ends, some corners at random, spins in
   open rooms). Open rooms also get loops (both directions) and figure-eights (an
   S-curve through the middle), long straight legs sometimes a sinusoidal weave. So
   both turn directions, tight and wide curvatures, straights and pure rotations all
   occur: every calibration parameter is excited.
2. ``drive``: a pure-pursuit controller at the control rate follows the runs with a
   speed profile (cruise 0.2-0.6 m/s, slower in curves, braking to each stop), turns
   on the spot between runs (|ω| ≤ 1 rad/s), and rate-limits v and ω so accelerations
   stay smooth. The true body twist of each interval comes from ``TrueKinematics``
   (effects such as lateral slip enter there), and the pose is integrated exactly.

The controller steers on the true pose: the simulated robot follows its plan, it does
not need to localise.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sclam_ros.core import se2
from sclam_ros.sim.motion import Trajectory, TrueKinematics, twist_increment
from sclam_ros.sim.world import World

PATH_SPACING = 0.05  # m between points of a run's polyline


@dataclass
class Limits:
    """Motion limits of the simulated controller (SI)."""

    cruise_min: float = 0.2  # m/s, slowest cruise speed of a leg
    cruise_max: float = 0.6  # m/s
    w_max: float = 1.0  # rad/s, on-the-spot turns
    w_curve: float = 0.8  # rad/s, budget for following curves while driving
    acc: float = 0.6  # m/s², hard limit of the rate limiter
    acc_plan: float = 0.35  # m/s², what the speed profile plans with (below the limit)
    ang_acc: float = 2.0  # rad/s²
    ang_acc_plan: float = 1.2  # rad/s²


@dataclass
class Run:
    """A stretch driven without stopping, preceded by an on-the-spot turn."""

    points: np.ndarray  # (N, 2) polyline
    cruise: np.ndarray  # (N,) m/s, cruise speed at each point
    extra_spin: float = 0.0  # rad, whole turns added to the initial on-the-spot turn


# --- route planning ------------------------------------------------------------------


def _segment_points(a, b) -> np.ndarray:
    n = max(int(np.ceil(np.linalg.norm(b - a) / PATH_SPACING)), 1)
    return a + np.linspace(0.0, 1.0, n + 1)[1:, None] * (b - a)


def _weave(a, b, rng) -> np.ndarray:
    """A sinusoid about the straight a→b, zero at both ends: S-curves on a straight."""
    length = np.linalg.norm(b - a)
    half_waves = max(int(round(length / rng.uniform(1.6, 2.6))), 1)
    amplitude = rng.uniform(0.2, 0.35) * rng.choice([-1.0, 1.0])
    points = _segment_points(a, b)
    s = np.linalg.norm(points - a, axis=1)
    normal = np.array([-(b - a)[1], (b - a)[0]]) / length
    return points + amplitude * np.sin(np.pi * half_waves * s / length)[:, None] * normal


def _loop(centre_on, heading, radius, direction) -> np.ndarray:
    """A full circle starting and ending at ``centre_on`` tangent to ``heading``;
    direction +1 turns left (counter-clockwise), −1 right."""
    normal = np.array([-np.sin(heading), np.cos(heading)]) * direction
    centre = centre_on + radius * normal
    start_angle = np.arctan2(*(centre_on - centre)[::-1])
    n = int(np.ceil(2 * np.pi * radius / PATH_SPACING))
    angles = start_angle + direction * np.linspace(0, 2 * np.pi, n + 1)[1:]
    return centre + radius * np.stack([np.cos(angles), np.sin(angles)], -1)


def _fits(world: World, points, margin: float) -> bool:
    return bool(world.clearance(points).min() >= margin)


def plan_route(world: World, rng: np.random.Generator, length: float, robot_radius: float,
               limits: Limits | None = None, start: str | None = None) -> list[Run]:
    """Runs covering at least ``length`` metres of path, starting at node ``start`` (default:
    the world's first node)."""
    limits = limits or Limits()
    start = start or next(iter(world.nodes))
    # Manoeuvres must keep a tracking margin on top of the robot's radius.
    margin = robot_radius + 0.3
    runs: list[Run] = []
    points = [np.array(world.nodes[start], float)[None]]
    cruise = [np.array([limits.cruise_min])]
    extra_spin = 0.0
    total = 0.0
    previous, current = None, start

    def finish_run(next_spin=0.0):
        """Close the run being built; the next one starts with ``next_spin`` extra turns."""
        nonlocal points, cruise, extra_spin
        pts, crs = np.concatenate(points), np.concatenate(cruise)
        if len(pts) > 1:
            runs.append(Run(pts, crs, extra_spin))
        points, cruise, extra_spin = [pts[-1:]], [crs[-1:]], next_spin

    heading = None
    while total < length:
        here = np.array(world.nodes[current], float)
        options = [n for n in world.neighbours(current) if n != previous] or world.neighbours(current)
        nxt = options[rng.integers(len(options))]
        there = np.array(world.nodes[nxt], float)
        out_heading = float(np.arctan2(*(there - here)[::-1]))

        if heading is not None:
            spin_here = 0.0
            if current in world.open_nodes:
                manoeuvre = rng.random()
                radius = rng.uniform(0.6, 1.0)
                direction = rng.choice([-1.0, 1.0])
                if manoeuvre < 0.3:
                    loop = _loop(here, heading, radius, direction)
                    if _fits(world, loop, margin):
                        points.append(loop)
                        cruise.append(np.full(len(loop), rng.uniform(limits.cruise_min, limits.cruise_max)))
                elif manoeuvre < 0.45:
                    eight = np.concatenate(
                        [_loop(here, heading, radius, direction), _loop(here, heading, radius, -direction)]
                    )
                    if _fits(world, eight, margin):
                        points.append(eight)
                        cruise.append(np.full(len(eight), rng.uniform(limits.cruise_min, limits.cruise_max)))
                elif manoeuvre < 0.6:
                    spin_here = 2 * np.pi * rng.choice([-1.0, 1.0])
            turn = float(se2.wrap_angle(out_heading - heading))
            if abs(turn) > 3.0 and rng.random() < 0.5:
                turn -= 2 * np.pi * np.sign(turn)  # U-turns both ways, not always left
            # Stop and turn on the spot at sharp corners and at some corners at random.
            if abs(turn) > 2.2 or spin_here or rng.random() < 0.35:
                finish_run(spin_here)

        speed = rng.uniform(limits.cruise_min, limits.cruise_max)
        leg = None
        if np.linalg.norm(there - here) > 4.0 and rng.random() < 0.4:
            leg = _weave(here, there, rng)
            if not _fits(world, leg, margin):
                leg = None
        if leg is None:
            leg = _segment_points(here, there)
        points.append(leg)
        cruise.append(np.full(len(leg), speed))
        total += np.linalg.norm(there - here)
        heading = out_heading
        previous, current = current, nxt
    finish_run()
    return runs


# --- driving -------------------------------------------------------------------------


def _curvature_speed_cap(points, w_curve, window=0.6) -> np.ndarray:
    """Speed at which following the polyline needs at most ``w_curve`` rad/s: heading
    change over a window about each point (a pure-pursuit lookahead's worth)."""
    seg = np.diff(points, axis=0)
    heading = np.unwrap(np.arctan2(seg[:, 1], seg[:, 0]))
    heading = np.concatenate([heading[:1], heading])
    half = max(int(window / PATH_SPACING / 2), 1)
    padded = np.concatenate([np.full(half, heading[0]), heading, np.full(half, heading[-1])])
    change = np.abs(padded[2 * half:] - padded[:-2 * half])
    curvature = change / window
    with np.errstate(divide="ignore"):
        return np.where(curvature > 0, w_curve / curvature, np.inf)


def speed_profile(run: Run, limits: Limits) -> np.ndarray:
    """Allowed speed at each point: cruise, capped in curves, braking to 0 at the end."""
    v = np.minimum(run.cruise, _curvature_speed_cap(run.points, limits.w_curve))
    ds = np.linalg.norm(np.diff(run.points, axis=0), axis=1)
    v[-1] = 0.0
    for i in range(len(v) - 2, -1, -1):  # backward pass: reachable braking
        v[i] = min(v[i], np.sqrt(v[i + 1] ** 2 + 2.0 * limits.acc_plan * ds[i]))
    return v


class _Controller:
    """Pure pursuit with on-the-spot turns and rate-limited (v, ω) commands."""

    def __init__(self, runs, limits: Limits, dt: float, start_pose):
        self.runs, self.limits, self.dt = runs, limits, dt
        self.pose = np.array(start_pose, float)  # θ unwrapped
        self.v = self.w = 0.0
        self.run_index = -1
        self._next_run()

    def _next_run(self):
        self.run_index += 1
        if self.run_index >= len(self.runs):
            self.mode = "idle"
            return
        run = self.runs[self.run_index]
        self.points = run.points
        self.arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(run.points, axis=0), axis=1))])
        self.profile = speed_profile(run, self.limits)
        self.progress = 0
        # Turn on the spot towards the run's first stretch (plus any whole spins).
        ahead = run.points[min(int(0.5 / PATH_SPACING), len(run.points) - 1)] - self.pose[:2]
        bearing = np.arctan2(ahead[1], ahead[0])
        self.turn_target = self.pose[2] + float(se2.wrap_angle(bearing - self.pose[2])) + run.extra_spin
        self.mode = "turn"

    def command(self):
        lim = self.limits
        v_des = w_des = 0.0
        if self.mode == "turn":
            error = self.turn_target - self.pose[2]
            w_des = np.sign(error) * min(lim.w_max, np.sqrt(2 * lim.ang_acc_plan * abs(error)), 3.0 * abs(error))
            if abs(error) < 0.01 and abs(self.w) < 0.03:
                self.mode = "follow"
        arrived = self.mode == "follow" and self._arrived()
        if self.mode == "follow" and not arrived:
            v_des, w_des = self._pursue()
        # Rate limits: bounded accelerations, hence smooth motion (also into each stop).
        self.v += np.clip(v_des - self.v, -lim.acc * self.dt, lim.acc * self.dt)
        self.w += np.clip(w_des - self.w, -lim.ang_acc * self.dt, lim.ang_acc * self.dt)
        if arrived and self.v == 0.0 and self.w == 0.0:
            self._next_run()
        return self.v, self.w

    def _pursue(self):
        lim = self.limits
        lo, hi = self.progress, min(self.progress + 60, len(self.points))
        nearest = lo + int(np.argmin(((self.points[lo:hi] - self.pose[:2]) ** 2).sum(1)))
        self.progress = nearest
        remaining = self.arc[-1] - self.arc[nearest]
        lookahead = float(np.clip(0.35 + 0.6 * abs(self.v), 0.35, 0.7))
        target_index = int(np.searchsorted(self.arc, self.arc[nearest] + lookahead))
        target = self.points[min(target_index, len(self.points) - 1)]
        local = se2.rotate_inverse(self.pose[2], target - self.pose[:2])
        distance = float(np.hypot(*local))
        if remaining < 0.02 or distance < 0.02:
            return 0.0, 0.0
        alpha = float(np.arctan2(local[1], local[0]))
        if abs(alpha) > 1.0:  # far off heading (after a stop): turn first
            return 0.0, float(np.sign(alpha) * min(lim.w_max, 2.0 * abs(alpha)))
        end_distance = float(np.hypot(*(self.points[-1] - self.pose[:2])))
        v_des = min(self.profile[nearest], max(np.sqrt(2 * lim.acc_plan * end_distance), 0.03))
        curvature = 2.0 * np.sin(alpha) / distance
        w_des = float(np.clip(curvature * max(self.v, 0.02), -lim.w_max, lim.w_max))
        return float(v_des), w_des

    def _arrived(self):
        end_distance = float(np.hypot(*(self.points[-1] - self.pose[:2])))
        at_last_point = self.progress >= len(self.points) - 2 and end_distance < 0.03
        near_end = self.arc[-1] - self.arc[self.progress] < 0.02 and end_distance < 0.05
        return at_last_point or near_end


def drive(runs: list[Run], kinematics: TrueKinematics, duration: float, control_rate: float = 50.0,
          limits: Limits | None = None, start_heading: float = 0.0, start_xy=None,
          hold: bool = False) -> Trajectory:
    """Follow ``runs`` for ``duration`` seconds; the exact true trajectory. ``hold``: stand
    still once the runs are done instead of failing (``start_xy`` then places a robot that
    has no run at all)."""
    limits = limits or Limits()
    dt = 1.0 / control_rate
    steps = int(round(duration * control_rate))
    start = np.array([*(runs[0].points[0] if start_xy is None else start_xy), start_heading])
    controller = _Controller(runs, limits, dt, start)
    poses = np.empty((steps + 1, 3))
    twists = np.empty((steps, 3))
    commands = np.empty((steps, 2))
    poses[0] = start
    for k in range(steps):
        v, w = controller.command()
        vx, vy, wt = kinematics.body_twist(k * dt, v, w)
        step = twist_increment(vx, vy, wt, dt)
        pose = controller.pose
        c, s = np.cos(pose[2]), np.sin(pose[2])
        controller.pose = np.array(
            [pose[0] + c * step[0] - s * step[1], pose[1] + s * step[0] + c * step[1], pose[2] + step[2]]
        )
        poses[k + 1] = controller.pose
        twists[k] = (vx, vy, wt)
        commands[k] = (v, w)
        if controller.mode == "idle" and not hold:
            raise RuntimeError("the route ran out before the duration; plan a longer route")
    return Trajectory(dt, poses, twists, commands)


def simulate_trajectory(world: World, kinematics: TrueKinematics, duration: float, seed: int,
                        robot_radius: float, control_rate: float = 50.0,
                        limits: Limits | None = None, motion: str = "route") -> Trajectory:
    """Plan and drive ``duration`` seconds for a seed; checks it stays clear. ``motion``:
    "route" (the random calibration-friendly drive) or a fixed pattern (see MOTIONS)."""
    limits = limits or Limits()
    if motion == "route":
        rng = np.random.default_rng(seed)
        # The robot cannot beat cruise_max on average, so this path is always long enough.
        runs = plan_route(world, rng, limits.cruise_max * duration + 20.0, robot_radius, limits)
        trajectory = drive(runs, kinematics, duration, control_rate, limits, start_heading=0.0)
    else:
        runs, start = motion_pattern(world, motion, robot_radius)
        trajectory = drive(runs, kinematics, duration, control_rate, limits,
                           start_heading=start[2], start_xy=start[:2], hold=True)
    clearance = world.clearance(trajectory.poses[:, :2])
    if clearance.min() < robot_radius:
        k = int(np.argmin(clearance))
        raise RuntimeError(
            f"simulated trajectory touches a wall at t = {k / control_rate:.2f} s "
            f"(clearance {clearance[k]:.3f} m < robot radius {robot_radius} m); seed {seed}"
        )
    return trajectory


# --- fixed motion patterns -------------------------------------------------------------
# Drives that leave some calibration parameters undetermined, on purpose (the degenerate-
# motion tests): each stands still once its runs are done, however long the recording.
#   straight             one straight leg along the world's longest straight road, 0.35 m/s:
#                        no rotation at all (≈ 68 s to the end of the office corridor)
#   straight_then_turns  the same leg, then at its end figure-eights (1 m loops both ways)
#                        and spins both ways: its first minute is ``straight``'s
#   spin                 turns on the spot at the leg's end, two turns each way in turn
#   still                no motion
MOTIONS = ("route", "straight", "straight_then_turns", "spin", "still")
PATTERN_CRUISE = 0.35  # m/s
LOOP_RADIUS = 1.0  # m
SPIN_TURNS = 2  # whole turns per on-the-spot spin, alternating direction
PATTERN_REPEATS = 6  # manoeuvres at the leg's end: plenty for a few minutes


def longest_straight(world: World):
    """End points of the longest chain of collinear roadmap edges."""
    best = (0.0, None, None)
    for a, b in world.edges + [(b, a) for a, b in world.edges]:
        start, previous, current = np.array(world.nodes[a], float), a, b
        direction = np.array(world.nodes[b], float) - start
        direction /= np.linalg.norm(direction)
        while True:
            onward = [n for n in world.neighbours(current) if n != previous
                      and _collinear(np.array(world.nodes[current], float),
                                     np.array(world.nodes[n], float), direction)]
            if not onward:
                break
            previous, current = current, onward[0]
        end = np.array(world.nodes[current], float)
        if np.linalg.norm(end - start) > best[0]:
            best = (float(np.linalg.norm(end - start)), start, end)
    return best[1], best[2]


def _collinear(here, there, direction) -> bool:
    step = there - here
    return bool(np.dot(step, direction) > 0.99 * np.linalg.norm(step))


def _spin(at, heading, turns) -> Run:
    """Turn on the spot by ``turns`` whole turns (sign: direction), then stay."""
    ahead = at + 0.01 * np.array([np.cos(heading), np.sin(heading)])
    return Run(np.stack([at, ahead]), np.full(2, 0.1), extra_spin=2 * np.pi * turns)


def motion_pattern(world: World, motion: str, robot_radius: float):
    """(runs, start pose) of a pattern of MOTIONS (not "route")."""
    if motion not in MOTIONS or motion == "route":
        raise ValueError(f"unknown motion {motion!r}; motions: {', '.join(MOTIONS)}")
    start, end = longest_straight(world)
    heading = float(np.arctan2(*(end - start)[::-1]))
    # The leg stops a metre short of the last node, where the manoeuvres have room.
    end = end - (end - start) / np.linalg.norm(end - start)
    leg = np.concatenate([start[None], _segment_points(start, end)])
    straight = Run(leg, np.full(len(leg), PATTERN_CRUISE))
    if motion == "still":
        return [], np.array([*start, heading])
    if motion == "spin":
        return ([_spin(start, heading, SPIN_TURNS * (-1) ** i) for i in range(PATTERN_REPEATS)],
                np.array([*start, heading]))
    if motion == "straight":
        return [straight], np.array([*start, heading])
    margin = robot_radius + 0.3
    eight = np.concatenate([_loop(end, heading, LOOP_RADIUS, 1.0), _loop(end, heading, LOOP_RADIUS, -1.0)])
    if not _fits(world, eight, margin):
        raise ValueError(f"no room for {motion!r} at the end of the longest straight road")
    runs = [straight]
    for i in range(PATTERN_REPEATS):
        points = np.concatenate([end[None], eight])
        runs.append(Run(points, np.full(len(points), PATTERN_CRUISE)))
        runs.append(_spin(end, heading, (-1) ** i))
    return runs, np.array([*start, heading])
