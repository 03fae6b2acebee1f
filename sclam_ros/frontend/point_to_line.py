"""Point-to-line refinement of a scan match (2D), removing point-to-point ICP's scale bias.

KISS-ICP registers points to points. On walls sampled by a fixed beam pattern, a point of
the new scan is paired with the nearest *sample* of the old one, which sits where the old
beam hit, so the registration is pulled back toward zero motion and the matches come out
short. Measuring the distance to the wall's *line* instead (normal · (q − p)) leaves the
sliding along the wall free, and the bias goes away. Measured: docs/decisions/
point_to_line.md, "Point-to-line, not point-to-point".

The refinement starts from KISS-ICP's answer (robust, already close) and runs a few
Gauss-Newton steps with a Huber weight against the reference scan's lines
(reference_lines.py), fitted as the laser's judged noise says (laser_noise.py). Its tuning
is RefinementConfig and PairingConfig (config.py).
"""
from __future__ import annotations

import math
from collections import Counter

import numpy as np

from sclam_ros.core import se2
from sclam_ros.frontend.config import FrontendConfig, PairingConfig, RefinementConfig
from sclam_ros.frontend.laser_noise import LaserNoiseJudgement
from sclam_ros.frontend.nearest import NearestReference
from sclam_ros.frontend.reference_lines import ReferenceScan
from sclam_ros.frontend.scan_matching import range_limit


class RefinedScanMatcher:
    """A scan matcher (scan_matching.ScanMatcher) whose motions are refined point-to-line
    against the scan they start from.

    A match the refinement cannot confirm is not used: KISS-ICP's answer alone is biased
    where the refinement fails (outdoors, few straight surfaces), far beyond what the
    noise model gives it. Measured: docs/decisions/point_to_line.md, "Unconfirmed matches
    are not used". They are counted as the matcher's rejection "match_unconfirmed", by
    reason in `unrefined` (reported through frontend/report.py); the keyframe keeps its
    odometry edge.
    """

    def __init__(self, matcher, config: FrontendConfig = FrontendConfig()):
        self.matcher = matcher
        self.config = config
        # The laser's noise, judged on the first reference scans, then fixed: it decides how
        # ReferenceScan.from_points fits the lines.
        self.laser_noise = LaserNoiseJudgement(config)
        self._segment_noise = None  # the judged noise while the laser is noisy (from_points)
        self._clearance = 0.0  # m kept clear of the range limit
        self._small_objects = False  # the judged noise is small_object_noise or more
        self._reference = None  # ReferenceScan of the last scan the matcher gave a pose
        self._reference_index = None  # its index in the matcher's numbering
        # Matches not used, by reason: "no_lines" (the reference scan has too few points on
        # lines: no walls in view, collapsed beams), "too_few_pairs" (fewer than 20 points of
        # the new scan near a line of the reference), "correction_too_large" (see
        # RefinementConfig.max_correction: the two registrations disagree, one is wrong).
        self.unrefined: Counter = Counter()
        self.matches = 0  # matches KISS-ICP gave, used or not

    @property
    def fits_segments(self) -> bool:
        """The laser is noisy (laser_noise.py): its lines are fitted to whole wall segments."""
        return self.laser_noise.noisy

    @property
    def range_noises(self) -> list:
        """range_noise() (m) of the scans the laser's noise is judged on."""
        return self.laser_noise.range_noises

    @property
    def growth(self) -> float:
        """How the laser's range noise grows with range (1/m), 0 where it does not."""
        return self.laser_noise.growth

    def add_scan(self, scan, guess, points):
        """(Match or None, z or None, information of z or None): the matcher's answer and
        its refined motion; z is None when there is no match or the refinement could not
        confirm it (counted). The information is that of the matcher's noise model
        (match.information, measured on the simulator) with the refinement's own covariance
        added (refine_with_covariance): the model knows how match errors grow with the
        motion, the refinement where this pair of scans does not fix the motion.
        `points`: scan_matching.scan_to_points of `scan` with the matcher's range limits."""
        index = self.matcher.next_index
        match = self.matcher.add_scan(scan, guess, points)
        z = information = None
        if match is not None:
            self.matches += 1
            # A match starts from the last posed scan, which is the reference.
            reference = self._reference if match.index_from == self._reference_index else None
            z, covariance, reason = _confirmed(reference, points, np.asarray(match.z, float),
                                               self.config)
            if reason:
                self.unrefined[reason] += 1
                self.matcher.rejections.add("match_unconfirmed")
            else:
                information = _with_covariance(np.asarray(match.information, float), covariance)
        if self.matcher.posed_index == index:
            self._remember_reference(scan, points)
            self._reference_index = index
        return match, z, information

    def _remember_reference(self, scan, points):
        """The scan just posed is the next match's reference; the first few judge the
        laser's noise, and with it how the reference's lines are fitted and how far from
        the range limit they must be (reference_lines.py)."""
        if self.laser_noise.add(scan):  # the judgement changes only here, so it is used only here
            median, lines = self.laser_noise.median, self.config.reference_lines
            self._segment_noise = median if self.laser_noise.noisy else None
            # Beyond not_a_noise the estimate says nothing about the laser: no clearance.
            says_something = median <= self.config.laser_noise.not_a_noise
            self._clearance = lines.clear_of_limit * median if says_something else 0.0
            self._small_objects = median >= lines.small_object_noise
        usable = range_limit(scan, self.matcher.config.max_range) - self._clearance
        self._reference = ReferenceScan.from_points(points, self._segment_noise, usable,
                                                    self._small_objects,
                                                    abs(float(scan.angle_increment)),
                                                    growth=self.laser_noise.growth,
                                                    config=self.config)


def _confirmed(reference, points, z_icp, config: FrontendConfig):
    """(refined z, its covariance, None), or (None, None, reason) where the refinement
    cannot confirm z_icp."""
    refined = refine_with_covariance(reference, points, z_icp, config)
    return verdict(reference, *refined, z_icp, config.refinement)


def verdict(reference, refined, used, covariance, against,
            config: RefinementConfig = RefinementConfig()):
    """_confirmed's answer for a refinement (refine_with_covariance's result) of a match
    whose own answer was `against`. A refinement that moves it by more than
    config.max_correction (or config.max_correction_angle) is locking onto lines that are
    not there (outdoors: "lines" through the points of two tree trunks), and the match is
    not used. Measured: docs/decisions/point_to_line.md, "Corrections too large to be
    true"."""
    if not used:
        return None, None, "no_lines" if reference is None else "too_few_pairs"
    if (math.hypot(*(refined[:2] - against[:2])) > config.max_correction
            or abs(se2.wrap_angle(refined[2] - against[2])) > config.max_correction_angle):
        return None, None, "correction_too_large"
    return refined, covariance, None


def _with_covariance(information, covariance):
    """information⁻¹ + covariance, inverted (information itself if that is singular)."""
    try:
        return np.linalg.inv(np.linalg.inv(information) + covariance)
    except np.linalg.LinAlgError:
        return information


def pairs(reference: ReferenceScan, moved, origin, config: PairingConfig = PairingConfig(),
          nearest=None):
    """(paired (n,) bool, index in `reference` of each one's point) of the new scan's points
    `moved` (n, 2), already moved by the motion being refined (the new scan's origin
    `origin` in the reference's frame): each is paired with its nearest reference point
    when it lies within config.max_pair_distance of it (in its ellipse along the line where
    the reference has a reach) and that point is within the usable range of both scans'
    origins. `nearest`: the nearest.NearestReference that follows these points, where
    the caller moves them step by step."""
    reach = reference.reach
    max_distance = config.max_pair_distance
    nearest = nearest or NearestReference(reference.tree, search_bound(reference, config))
    dist, idx = nearest.query(moved)
    ok = np.isfinite(dist)
    anchors = reference.anchors
    if reach is not None:
        found = idx[ok]
        offset = moved[ok] - reference.points[found]
        normal = reference.normals[found]
        across = normal[:, 0] * offset[:, 0] + normal[:, 1] * offset[:, 1]
        along = normal[:, 1] * offset[:, 0] - normal[:, 0] * offset[:, 1]
        ok[ok] = (along / reach[found]) ** 2 + (across / max_distance) ** 2 <= 1.0
    if np.isfinite(reference.usable_range):  # the anchor as the new scan sees it
        found = idx[ok]
        ok[ok] = np.hypot(anchors[found, 0] - origin[0],
                          anchors[found, 1] - origin[1]) <= reference.usable_range
    return ok, idx


def search_bound(reference: ReferenceScan, config: PairingConfig = PairingConfig()) -> float:
    """m: how far from a new point pairs() looks for its nearest reference point."""
    return config.max_pair_distance if reference.reach is None else float(reference.reach.max())


def _range_weights(reference, i, nx, ny, rx, ry, z, min_cos_incidence):
    """The weights 1/(1 + growth·r)² of new points paired with the reference's points i
    (their lines' normals nx, ny; the points rotated into the reference, R(θ)q = (rx, ry);
    the motion z) where the range noise grows with range (laser_noise.py): r where each
    point's beam meets its line (its cos of the incidence taken as min_cos_incidence at
    least), which does not depend on the point's own range noise (its measured range does,
    and so does which reference point it is paired with: weighed by either, the points the
    noise brought nearer would weigh more), or the reference's own_ranges."""
    anchors = reference.anchors[i]
    distance = np.abs(nx * (anchors[:, 0] - z[0]) + ny * (anchors[:, 1] - z[1]))
    cos_incidence = np.abs(nx * rx + ny * ry) / np.maximum(np.hypot(rx, ry), 1e-12)
    wall_range = distance / np.maximum(cos_incidence, min_cos_incidence)
    own = reference.own_ranges[i]
    wall_range = np.where(np.isnan(own), wall_range, own)
    return 1.0 / (1.0 + reference.growth * wall_range) ** 2


_DAMPING = 1e-9 * np.eye(3)  # keeps the 3×3 normal equations solvable


def refine(reference: ReferenceScan, points, z0, config: FrontendConfig = FrontendConfig()):
    """(z, number of pairs used) of refine_with_covariance."""
    z, used, _ = refine_with_covariance(reference, points, z0, config)
    return z, used


def refine_with_covariance(reference: ReferenceScan, points, z0,
                           config: FrontendConfig = FrontendConfig()):
    """z = laser_j ⊖ laser_i refined so points of scan j lie on the lines of scan i.

    Returns (z, number of pairs used, covariance of z), or (z0, 0, None) if too few pairs
    were found or there is no reference (ReferenceScan.from_points gives None for a scan
    without lines). The covariance is the least-squares one, s²·(JᵀWJ)⁻¹ with s the robust
    scale of the point-to-line residuals: large along a direction the lines of this pair of
    scans do not fix (a corridor whose ends are out of range); RefinedScanMatcher adds it
    to the noise model's. Measured: docs/decisions/point_to_line.md, "The refinement's
    covariance in the match's information".
    Runs once per scan: written on coordinate columns with scalar sin/cos (no per-call
    stacking of (N, 2) arrays), faster than with se2's general helpers, with the same
    arithmetic.
    """
    if reference is None:
        return np.array(z0, float), 0, None
    q = np.asarray(points, float)
    qx, qy = np.ascontiguousarray(q[:, 0]), np.ascontiguousarray(q[:, 1])
    px, py = reference.anchors[:, 0], reference.anchors[:, 1]
    normal_x, normal_y = reference.normals[:, 0], reference.normals[:, 1]
    z = np.array(z0, float)
    used = 0
    moved = np.empty((len(qx), 2))
    huber, pairing = config.refinement.huber, config.pairing
    nearest = NearestReference(reference.tree, search_bound(reference, pairing))
    for _ in range(config.refinement.iterations):
        c, s = math.cos(z[2]), math.sin(z[2])
        rx, ry = c * qx - s * qy, s * qx + c * qy  # R(θ) q
        moved[:, 0] = rx + z[0]
        moved[:, 1] = ry + z[1]
        ok, idx = pairs(reference, moved, z[:2], pairing, nearest)
        used = int(np.count_nonzero(ok))
        if used < 20:
            return np.array(z0, float), 0, None
        i = idx[ok]
        nx, ny = normal_x[i], normal_y[i]
        rx, ry = rx[ok], ry[ok]
        residual = nx * (rx + z[0] - px[i]) + ny * (ry + z[1] - py[i])
        # ∂(R(θ) q + t)/∂θ = S R(θ) q: the rotated point turned by 90°.
        jac = np.empty((3, used))
        jac[0], jac[1] = nx, ny
        np.subtract(ny * rx, nx * ry, out=jac[2])
        weight = np.minimum(1.0, huber / np.maximum(np.abs(residual), 1e-12))
        if reference.growth:
            range_weight = _range_weights(reference, i, nx, ny, rx, ry, z,
                                          pairing.min_cos_incidence)
            weight = weight * range_weight
        weighted = jac * weight
        hessian = weighted @ jac.T + _DAMPING
        try:
            step = -np.linalg.solve(hessian, weighted @ residual)
        except np.linalg.LinAlgError:
            return np.array(z0, float), 0, None
        z = z + step
        if math.hypot(step[0], step[1]) < 1e-6 and abs(step[2]) < 1e-7:
            break
    z[2] = se2.wrap_angle(z[2])
    # The scale of the residuals as weighed (of σ at 0 m where the noise grows with range).
    whitened = residual * np.sqrt(range_weight) if reference.growth else residual
    scale = 1.4826 * float(np.median(np.abs(whitened)))
    return z, used, scale ** 2 * np.linalg.inv(hessian)
