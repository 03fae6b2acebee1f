"""LaserScan → points → KISS-ICP → z_ij, the laser's motion between scans, with its information.

Pipeline per scan (:meth:`ScanMatcher.add_scan`):

1. :func:`scan_to_points` keeps the beams that are real returns: finite, not 0 (many
   drivers write 0 for "no return"), inside [range_min, range_max] and inside the matcher's
   own [min_range, max_range]; points are (N, 3) with z = 0 in the laser frame.
2. Voxel downsampling as KISS-ICP does it: the frame at voxel/2 goes into the local map, the
   frame at 1.5·voxel is registered.
3. KISS-ICP's point-to-map registration (its public Python API: 6-DoF, but with
   every point at z = 0 the out-of-plane directions stay at exactly 0, so the result is
   planar) starts from the pose predicted by the wheel odometry (or, without it, by
   KISS-ICP's constant-velocity model).
4. The result is checked against that prediction with a generous gate (a registration that
   jumps by more than odometry can err is a divergence, not a measurement), the scan is
   added to the local map, and the match is

       z = laser_pose_j ⊖ laser_pose_i       (sclam_ros.core.se2.between)

   from the previous scan that has a pose to this one, with an information matrix from the
   measured noise model (see :class:`NoiseModel`).

Memory is bounded: the local map drops voxels farther than ``max_range`` from the laser, and
the matcher keeps only the previous scan's points.

Configuration choices are measured by ``bench/scan_matching_accuracy.py`` on the simulator;
the numbers that justify each default are quoted next to it in :class:`ScanMatcherConfig`.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Optional

import numpy as np
from kiss_icp.config import KISSConfig
from kiss_icp.mapping import VoxelHashMap
from kiss_icp.registration import Registration
from kiss_icp.threshold import AdaptiveThreshold
from kiss_icp.voxelization import voxel_down_sample
from scipy.spatial import cKDTree

from sclam_ros.core import se2
from sclam_ros.core.inputs import Rejections, Scan


# --- scan → points -----------------------------------------------------------------------


def range_limit(scan: Scan, max_range: float = np.inf) -> float:
    """The farthest return used: the scan's range_max (if it states one) or ours."""
    if np.isfinite(scan.range_max) and scan.range_max > 0:
        return min(float(scan.range_max), max_range)
    return max_range


def valid_beams(scan: Scan, min_range: float = 0.0, max_range: float = np.inf) -> np.ndarray:
    """Mask of the beams that are returns: finite, > 0, within the scan's and our limits."""
    r = np.asarray(scan.ranges, float)
    lo = max(float(scan.range_min), min_range, 0.0)
    hi = range_limit(scan, max_range)
    with np.errstate(invalid="ignore"):
        # NaN compares False everywhere, so it drops out with the comparisons; r > 0 drops the
        # "0 = no return" convention even when range_min is 0.
        return (r > 0.0) & (r >= lo) & (r <= hi) & np.isfinite(r)


def thinned(scan: Scan, max_beams: float) -> Scan:
    """Every k-th beam of `scan`, k the smallest that leaves at most `max_beams` (0: all)."""
    n = len(scan.ranges)
    if max_beams <= 0 or n <= max_beams:
        return scan
    k = math.ceil(n / max_beams)
    return dataclasses.replace(scan, ranges=scan.ranges[::k], angle_increment=scan.angle_increment * k,
                               time_increment=scan.time_increment * k)


def scan_to_points(scan: Scan, min_range: float = 0.0, max_range: float = np.inf) -> np.ndarray:
    """The valid returns of ``scan`` as (N, 3) points in the laser frame, z = 0.

    Angles come from ``angle_min + i·angle_increment`` so a negative increment (a scanner
    mounted upside down, or a clockwise driver) is geometrically right by construction.
    """
    keep = valid_beams(scan, min_range, max_range)
    r = np.asarray(scan.ranges, float)[keep]
    a = scan.angles()[keep]
    points = np.zeros((len(r), 3))
    points[:, 0] = r * np.cos(a)
    points[:, 1] = r * np.sin(a)
    return points


# --- noise model ---------------------------------------------------------------------------


@dataclass
class NoiseModel:
    """1σ of z_ij per component as an affine function of the motion size.

        σ_xy = xy_base + xy_per_m · |t| + xy_per_rad · |θ|     (m, each of x and y)
        σ_θ  = th_base + th_per_m · |t| + th_per_rad · |θ|     (rad)

    with t = (z_x, z_y) and θ = z_θ.

    It hardly grows with the motion: the refinement measures each scan against the previous
    one's wall lines, whose noise does not depend on how far the laser moved between them.
    Consecutive errors correlate negatively (part of each belongs to a scan's pose in the
    local map), which correlated_covariance.chain_correlated_covariance accounts for. Where
    a pair of scans fixes the motion less well, the refinement's own covariance is added
    (point_to_line.RefinedScanMatcher), and the calibration rescales the laser edges' noise
    per recording (variance components): the model's shape, not its level, is what matters
    for other lasers. The measurements: docs/decisions/scan_matching.md#match-noise-model.
    """

    xy_base: float = 0.00112
    xy_per_m: float = 0.00046
    xy_per_rad: float = 0.00136
    th_base: float = 0.00023
    th_per_m: float = 0.0006
    th_per_rad: float = 0.00045

    def sigmas(self, z) -> np.ndarray:
        z = np.asarray(z, float)
        t, th = float(np.hypot(z[0], z[1])), abs(float(z[2]))
        s_xy = self.xy_base + self.xy_per_m * t + self.xy_per_rad * th
        s_th = self.th_base + self.th_per_m * t + self.th_per_rad * th
        return np.array([s_xy, s_xy, s_th])

    def information(self, z) -> np.ndarray:
        return np.diag(1.0 / self.sigmas(z) ** 2)


# --- configuration -------------------------------------------------------------------------


@dataclass
class ScanMatcherConfig:
    """KISS-ICP set up for planar indoor scans (m, rad)."""

    voxel_size: float = 0.02
    # KISS-ICP finds correspondences only in the 27 voxels around a point, so a fine map
    # captures ~1 voxel of prediction error. A first registration on a coarse map pulls the
    # prediction in from ~coarse_voxel_size; None = single level.
    coarse_voxel_size: Optional[float] = None
    # The registered points are the frame downsampled at source_voxel_factor·voxel_size
    # (KISS-ICP: 1.5); the map keeps voxel_size/2.
    source_voxel_factor: float = 1.5
    min_range: float = 0.0
    max_range: float = 30.0
    # The final z is refined point-to-line (frontend → point_to_line.py), so KISS-ICP only
    # has to land close: fewer points per voxel cost less and change nothing after the
    # refinement (docs/decisions/scan_matching.md#kiss-icp-effort).
    max_points_per_voxel: int = 5
    # Correspondence kernel σ (m). None = KISS-ICP's adaptive threshold; a float fixes it.
    fixed_threshold: Optional[float] = 0.1
    initial_threshold: float = 0.3
    min_motion_threshold: float = 0.01
    max_iterations: int = 30
    # KISS-ICP stops when its update is below this (m, rad). The point-to-line refinement
    # moves z anyway, so KISS-ICP only has to land in its basin
    # (docs/decisions/scan_matching.md#kiss-icp-effort).
    convergence: float = 1e-3
    max_threads: int = 1  # one scan is too small to gain from threads; leave cores to the solver
    min_points: int = 30  # fewer returns than this cannot constrain 3 DoF reliably
    # Overlap check after registration: the fraction of registered points within
    # inlier_distance of a point of the previous scan must reach min_fitness.
    inlier_distance: float = 0.1
    min_fitness: float = 0.5
    # Gate against the odometry prediction: the registration may correct the prediction by
    # up to gate_translation + gate_fraction·|motion| (m) and gate_rotation + gate_fraction·|θ|.
    gate_translation: float = 0.3
    gate_rotation: float = 0.3
    gate_fraction: float = 0.5
    # Matches not reported while the local map holds fewer scans than this (they still
    # build it): the first matches on a young map err several times more
    # (docs/decisions/scan_matching.md#map-warm-up).
    warmup_scans: int = 3
    # rad: turns added to the constant-velocity prediction when the odometry's fails
    # (ScanMatcher._search): KISS-ICP converges from about 0.15 rad off on the office scans.
    search_turns: tuple = (0.0, -0.3, 0.3, -0.6, 0.6)
    # (m, rad): odometry and constant-velocity predictions further apart are both registered
    # (ScanMatcher.add_scan): 0.1 m in 0.3 s is a change of speed of 0.33 m/s, beyond a
    # driver's acceleration; reversed odometry at 0.5 m/s puts them 0.3 m apart.
    predictions_apart: tuple = (0.1, 0.1)
    # of the points: the overlap with the previous scan by which the constant-velocity
    # registration must beat the odometry's to replace it.
    fitness_margin: float = 0.05
    noise: NoiseModel = field(default_factory=NoiseModel)

    @classmethod
    def from_params(cls, params, **overrides) -> "ScanMatcherConfig":
        """The matcher configuration of a :class:`sclam_ros.core.params.SclamParams`."""
        return cls(voxel_size=params.scan_voxel_size, **overrides)


# --- matching ------------------------------------------------------------------------------


@dataclass
class Match:
    """z: the laser's motion from scan ``index_from`` to ``index_to`` in the laser frame of
    ``index_from`` (x, y, θ; m, rad), and its 3×3 information matrix."""

    index_from: int
    index_to: int
    stamp_from: float
    stamp_to: float
    z: np.ndarray
    information: np.ndarray
    num_points: int  # points registered (after downsampling)
    fitness: float  # fraction of registered points within inlier_distance of the previous scan
    rmse: float  # m, RMS distance of those inliers
    correction: np.ndarray  # registration result ⊖ prediction (how much ICP moved it)


class ScanMatcher:
    """Scan-to-local-map registration with KISS-ICP, one scan at a time.

    ``add_scan(scan, odometry_guess)`` takes the laser's motion since the *previous call* as
    predicted by the wheel odometry (nominal calibration, in the laser frame: see
    :func:`laser_motion_from_base_motion`), or None to use the constant-velocity model.
    It returns a :class:`Match` from the last scan that has a pose, or None (first scan, or a
    rejection counted in ``rejections``).
    """

    def __init__(self, config: Optional[ScanMatcherConfig] = None, rejections: Optional[Rejections] = None):
        self.config = config or ScanMatcherConfig()
        self.rejections = rejections if rejections is not None else Rejections()
        c = self.config
        self._registration = Registration(c.max_iterations, c.convergence, c.max_threads)
        # Coarse to fine: one local map per voxel size (see ScanMatcherConfig.coarse_voxel_size).
        self._voxel_sizes = [v for v in (c.coarse_voxel_size, c.voxel_size) if v]
        self._maps = [VoxelHashMap(v, c.max_range, c.max_points_per_voxel) for v in self._voxel_sizes]
        self._threshold = (
            None
            if c.fixed_threshold is not None
            else AdaptiveThreshold(KISSConfig(
                data={"max_range": c.max_range},
                adaptive_threshold={"initial_threshold": c.initial_threshold,
                                    "min_motion_th": c.min_motion_threshold}))
        )
        # Scans registered from the constant-velocity prediction after the odometry guess failed.
        self.odometry_guess_failures = 0
        # Scans whose odometry registration converged but the constant-velocity one, tried
        # because the two predictions disagreed, overlapped the previous scan better.
        self.odometry_guess_overruled = 0
        self.reset()

    def reset(self) -> None:
        """Forget the map; the next scan starts a new one (no match across a reset)."""
        for local_map in self._maps:
            local_map.clear()
        self._pose = None  # laser pose (x, y, θ) of the last scan with a pose, map frame
        self._index = None  # its index
        self._stamp = None
        self._prev_tree = None  # KD-tree of that scan's points (map frame), for fitness
        self._pending = np.zeros(3)  # odometry motion accumulated since that scan
        self._pending_complete = True  # False if a call without guess broke the chain
        self._velocity = np.zeros(3)  # last z per second, for the constant-velocity model
        self._count = 0
        self._map_scans = 0  # scans in the current local map

    @property
    def posed_index(self) -> Optional[int]:
        """The index of the last scan given a pose (matched, building a map, or starting one):
        the scan the next match will start from. None before the first."""
        return self._index

    @property
    def next_index(self) -> int:
        """The index the next scan given to add_scan will have."""
        return self._count

    # -- the one entry point ----------------------------------------------------------------
    def add_scan(self, scan: Scan, odometry_guess: Optional[np.ndarray] = None,
                 points: Optional[np.ndarray] = None) -> Optional[Match]:
        """`points`: scan_to_points(scan, min_range, max_range) if the caller has them."""
        index = self._count
        self._count += 1
        if odometry_guess is not None:
            self._pending = se2.compose(self._pending, odometry_guess)
        else:
            self._pending_complete = False

        c = self.config
        frame = scan_to_points(scan, c.min_range, c.max_range) if points is None else points
        if len(frame) < c.min_points:
            reason = "scan_empty" if len(frame) == 0 else "scan_too_few_points"
            self.rejections.add(reason)
            return None
        # Per level, as KISS-ICP does: the frame at voxel/2 feeds the map, at 1.5·voxel it is registered.
        frames_map = [_voxel(frame, 0.5 * v) for v in self._voxel_sizes]
        sources = [_voxel(f, c.source_voxel_factor * v) for f, v in zip(frames_map, self._voxel_sizes)]
        source = sources[-1]
        if len(source) < c.min_points:
            self.rejections.add("scan_too_few_points")
            return None

        if self._pose is None:  # first scan of a map: it defines the map frame
            self._start_map(index, scan.stamp, frames_map, source, np.zeros(3))
            return None

        have_guess = self._pending_complete
        dt = scan.stamp - self._stamp
        constant_velocity = se2.compose(self._pose, self._velocity * dt)
        prediction = se2.compose(self._pose, self._pending) if have_guess else constant_velocity

        new_pose, used, failure, fitness, rmse = self._register(sources, prediction)
        if have_guess and not failure and _apart(prediction, constant_velocity, c.predictions_apart):
            # The odometry and the laser's own last motion disagree by more than a driver's
            # change of speed in one match (encoders wired wrong, a laser yaw 180° off):
            # a registration from a wrong guess can still converge, in a corridor, to a
            # wrong place that overlaps well. The one the previous scan confirms better
            # wins; ties go to the odometry.
            other = self._register(sources, constant_velocity)
            if other[2] is None and other[3] > fitness + c.fitness_margin:
                new_pose, used, failure, fitness, rmse = other
                self.odometry_guess_overruled += 1
        if failure:
            # The odometry can be what is wrong (swapped or backwards encoders, a nominal
            # calibration far off): try again from the constant-velocity prediction, as
            # KISS-ICP does without odometry, turned by config.search_turns, so that the laser still
            # measures the motion the wheels contradict (core/wiring.py needs exactly those
            # motions). Without odometry, the turns are what is left to try.
            turns = c.search_turns if have_guess else c.search_turns[1:]
            retry = self._search(sources, constant_velocity, turns)
            if retry is not None:
                new_pose, used, failure, fitness, rmse = retry
                self.odometry_guess_failures += have_guess
        if failure:
            # registration_diverged: dropped, and the map restarts at this scan, placed where
            # odometry says it is, so the next scan is registered against clean geometry.
            # registration_poor_overlap: converged somewhere the previous scan does not
            # confirm (the robot was carried, the view changed completely).
            self.rejections.add(failure)
            self._start_map(index, scan.stamp, frames_map, source, prediction)
            return None
        correction = se2.between(new_pose, used)
        z = se2.between(new_pose, self._pose)
        if self._threshold is not None:
            self._threshold.update_model_deviation(se2.to_matrix4(correction))
        self._velocity = z / dt if dt > 0 else np.zeros(3)
        if self._map_scans <= c.warmup_scans:
            # Young map: one or a few scans with the same beam pattern, point-to-point ICP
            # locks onto the old samples and z stays near the prediction. Build the map,
            # do not report the motion.
            self.rejections.add("match_map_warmup")
            self._start_map(index, scan.stamp, frames_map, source, new_pose, keep_map=True)
            return None
        match = Match(
            index_from=self._index,
            index_to=index,
            stamp_from=self._stamp,
            stamp_to=scan.stamp,
            z=z,
            information=c.noise.information(z),
            num_points=len(source),
            fitness=fitness,
            rmse=rmse,
            correction=correction,
        )
        self._start_map(index, scan.stamp, frames_map, source, new_pose, keep_map=True)
        return match

    # -- internals --------------------------------------------------------------------------
    def _register(self, sources, prediction):
        """ICP of the scan from `prediction` (map frame), coarse to fine: (pose, prediction,
        failure reason or None, fitness, rmse)."""
        c = self.config
        sigma = c.fixed_threshold if self._threshold is None else self._threshold.get_threshold()
        pose_m = se2.to_matrix4(prediction)
        for level_source, local_map in zip(sources, self._maps):
            pose_m = self._registration.align_points_to_map(
                level_source, local_map, pose_m, 3.0 * sigma, sigma
            )
        new_pose = se2.from_matrix(pose_m)
        correction = se2.between(new_pose, prediction)
        if not np.all(np.isfinite(new_pose)) or not self._within_gate(correction, se2.between(prediction, self._pose)):
            return new_pose, prediction, "registration_diverged", 0.0, math.inf
        fitness, rmse = self._overlap(sources[-1], new_pose, c.inlier_distance)
        if fitness < c.min_fitness:
            return new_pose, prediction, "registration_poor_overlap", fitness, rmse
        return new_pose, prediction, None, fitness, rmse

    def _search(self, sources, prediction, turns):
        """The best registration (by overlap) from `prediction` and from it turned by each of
        `turns`, or None if none converges. Matches are 0.3 s apart
        (frontend/decimation.py): a spin of 1 rad/s turns 0.3 rad between them, beyond
        KISS-ICP's basin from a prediction that has the turn wrong (encoders wired wrong, the
        start of a spin under the constant-velocity model)."""
        best = None
        for turn in turns:
            result = self._register(sources, se2.compose(prediction, np.array([0.0, 0.0, turn])))
            if result[2] is None and (best is None or result[3] > best[3]):
                best = result
        return best

    def _start_map(self, index, stamp, frames_map, source, pose, keep_map=False):
        pose_m = se2.to_matrix4(pose)
        self._map_scans = self._map_scans + 1 if keep_map else 1
        for frame_map, local_map in zip(frames_map, self._maps):
            if not keep_map:
                local_map.clear()
            local_map.update(frame_map, pose_m)
        self._pose, self._index, self._stamp = pose, index, stamp
        self._prev_tree = cKDTree(se2.transform_points(pose, source[:, :2]))
        self._pending = np.zeros(3)
        self._pending_complete = True

    def _within_gate(self, correction, predicted_motion) -> bool:
        c = self.config
        t_limit = c.gate_translation + c.gate_fraction * float(np.hypot(*predicted_motion[:2]))
        r_limit = c.gate_rotation + c.gate_fraction * abs(float(predicted_motion[2]))
        return float(np.hypot(*correction[:2])) <= t_limit and abs(float(correction[2])) <= r_limit

    def _overlap(self, source, pose, max_distance):
        """Fraction of registered points with a neighbour in the previous scan, and their RMS."""
        d, _ = self._prev_tree.query(se2.transform_points(pose, source[:, :2]), distance_upper_bound=max_distance)
        inliers = np.isfinite(d)
        if not inliers.any():
            return 0.0, float("inf")
        return float(inliers.mean()), float(np.sqrt(np.mean(d[inliers] ** 2)))


def _apart(a, b, limits) -> bool:
    """Whether poses a and b are further apart than limits (m, rad)."""
    d = se2.between(a, b)
    return bool(np.hypot(d[0], d[1]) > limits[0] or abs(d[2]) > limits[1])


def _voxel(points: np.ndarray, size: float) -> np.ndarray:
    return voxel_down_sample(points, size)


def laser_motion_from_base_motion(base_motion, laser_mount) -> np.ndarray:
    """The laser's motion l⁻¹ ⊕ u ⊕ l for a base_link motion u and laser mount l (both (3,)
    or stacked): the odometry guess in the frame the scan matcher works in."""
    return se2.between(se2.compose(base_motion, laser_mount), laser_mount)
