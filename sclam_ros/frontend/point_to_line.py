"""Point-to-line refinement of a scan match (2D), removing point-to-point ICP's scale bias.

KISS-ICP registers points to points. On walls sampled by a fixed beam pattern, a point of
the new scan is paired with the nearest *sample* of the old one, which sits where the old
beam hit, so the registration is pulled back toward zero motion: measured on the simulator
(PowerBot, 150 s, 1 cm range noise) scan-match translations were 0.8 % short, enough to
bias the wheel radii and base by 3σ. Measuring the distance to the wall's *line* instead
(normal · (q − p)) leaves the sliding along the wall free, and the bias goes away.

The refinement starts from KISS-ICP's answer (robust, already close) and runs a few
Gauss-Newton steps with a Huber weight against the previous scan's points and normals.
"""
from __future__ import annotations

import math
from collections import Counter

import numpy as np

from sclam_ros.core import se2
from sclam_ros.frontend.laser_noise import NOT_A_NOISE, LaserNoiseJudgement
from sclam_ros.frontend.reference_lines import (CLEAR_OF_LIMIT, MAX_PAIR_DISTANCE,
                                                MIN_COS_INCIDENCE, SMALL_OBJECT_NOISE,
                                                ReferenceScan)
from sclam_ros.frontend.scan_matching import range_limit

HUBER = 0.02  # m; ~2σ of the range noise of a typical 2D lidar
ITERATIONS = 15
# The refinement corrects KISS-ICP's answer by a fraction of a millimetre indoors (a 0.8 %
# scale bias on a few cm of motion). A correction beyond these is the refinement locking onto
# lines that are not there (outdoors: "lines" through points of two tree trunks; measured
# on the simulator's outdoor scene, p99 error 1.1 m refined against 0.13 m unrefined): the
# match is not used (RefinedScanMatcher).
MAX_CORRECTION = 0.05  # m
MAX_CORRECTION_ANGLE = 0.02  # rad


class RefinedScanMatcher:
    """A scan matcher (scan_matching.ScanMatcher) whose motions are refined point-to-line
    against the scan they start from.

    A match the refinement cannot confirm is not used. KISS-ICP's answer alone is biased
    where the refinement fails: on the simulator's outdoor scene (trees, poles, cars; 120 s,
    seeds 1 and 2, matches 0.3 s apart) the matches it had to keep unrefined came out
    10-14 % long, with median errors of 26-30 mm on 8 cm of motion, while the noise model
    gives them 1-2 mm; the refined ones were within 1 %. Kept, they pulled the wheel radii
    up to +3.5 %. They are counted as the matcher's rejection
    "match_unconfirmed", by reason in `unrefined` (reported by `sclam calibrate`); the
    keyframe keeps its odometry edge.
    """

    def __init__(self, matcher):
        self.matcher = matcher
        # The laser's noise, judged on the first reference scans, then fixed: it decides how
        # ReferenceScan.from_points fits the lines.
        self.laser_noise = LaserNoiseJudgement()
        self._segment_noise = None  # the judged noise while the laser is noisy, for from_points(noise=)
        self._clearance = 0.0  # m kept clear of the range limit (CLEAR_OF_LIMIT)
        self._small_objects = False  # the judged noise is SMALL_OBJECT_NOISE or more
        self._reference = None  # ReferenceScan of the last scan the matcher gave a pose
        self._reference_index = None  # its index in the matcher's numbering
        # Matches not used, by reason: "no_lines" (the reference scan has too few points on
        # lines: no walls in view, collapsed beams), "too_few_pairs" (fewer than 20 points of
        # the new scan near a line of the reference), "correction_too_large" (see
        # MAX_CORRECTION: the two registrations disagree, one of them is wrong).
        self.unrefined: Counter = Counter()
        self.matches = 0  # matches KISS-ICP gave, used or not

    @property
    def fits_segments(self) -> bool:
        """The laser is noisy (NOISY_RANGE): its lines are fitted to whole wall segments."""
        return self.laser_noise.noisy

    @property
    def range_noises(self) -> list:
        """range_noise() (m) of the scans the laser's noise is judged on."""
        return self.laser_noise.range_noises

    @property
    def growth(self) -> float:
        """How the laser's range noise grows with range (1/m; GROWTH), 0 where it does not."""
        return self.laser_noise.growth

    @property
    def confirmed(self) -> int:
        """Matches the refinement confirmed (used)."""
        return self.matches - sum(self.unrefined.values())

    @property
    def mostly_unconfirmed(self) -> bool:
        """More than half of the matches could not be confirmed (few straight surfaces)."""
        return 2 * self.confirmed < self.matches

    @property
    def sigma_may_be_small(self) -> bool:
        """A noisy laser with most matches unconfirmed: on the simulator's outdoor scene
        the errors were then up to 1.6 σ RMS for the wheels and 2.4 σ for the laser yaw
        (bench/sensor_matrix.py --factors outdoor; docs/accuracy.md)."""
        return self.fits_segments and self.mostly_unconfirmed

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
            z, covariance, reason = _confirmed(reference, points, np.asarray(match.z, float))
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
        """The scan just posed is the next match's reference; the first NOISE_SCANS judge
        the laser's noise, and with it how the reference's lines are fitted and how far
        from the range limit they must be (CLEAR_OF_LIMIT)."""
        if self.laser_noise.add(scan):  # the judgement changes only here, so it is used only here
            median = self.laser_noise.median
            self._segment_noise = median if self.laser_noise.noisy else None
            # Beyond NOT_A_NOISE the estimate says nothing about the laser: no clearance.
            self._clearance = CLEAR_OF_LIMIT * median if median <= NOT_A_NOISE else 0.0
            self._small_objects = median >= SMALL_OBJECT_NOISE
        usable = range_limit(scan, self.matcher.config.max_range) - self._clearance
        self._reference = ReferenceScan.from_points(points, self._segment_noise, usable,
                                                    self._small_objects,
                                                    abs(float(scan.angle_increment)),
                                                    growth=self.laser_noise.growth)


def _confirmed(reference, points, z_icp):
    """(refined z, its covariance, None), or (None, None, reason) where the refinement
    cannot confirm z_icp."""
    return verdict(reference, *refine_with_covariance(reference, points, z_icp), z_icp)


def verdict(reference, refined, used, covariance, against):
    """_confirmed's answer for a refinement (refine_with_covariance's result) of a match
    whose own answer was `against`."""
    if not used:
        return None, None, "no_lines" if reference is None else "too_few_pairs"
    if (math.hypot(*(refined[:2] - against[:2])) > MAX_CORRECTION
            or abs(se2.wrap_angle(refined[2] - against[2])) > MAX_CORRECTION_ANGLE):
        return None, None, "correction_too_large"
    return refined, covariance, None


def _with_covariance(information, covariance):
    """information⁻¹ + covariance, inverted (information itself if that is singular)."""
    try:
        return np.linalg.inv(np.linalg.inv(information) + covariance)
    except np.linalg.LinAlgError:
        return information


def pairs(reference: ReferenceScan, moved, origin):
    """(paired (n,) bool, index in `reference` of each one's point) of the new scan's points
    `moved` (n, 2), already moved by the motion being refined (the new scan's origin
    `origin` in the reference's frame): each is paired with its nearest reference point
    when it lies within MAX_PAIR_DISTANCE of it (in its ellipse, ALONG_LINE) and that point
    is within the usable range of both scans' origins."""
    reach = reference.reach
    bound = MAX_PAIR_DISTANCE if reach is None else float(reach.max())
    dist, idx = reference.tree.query(moved, distance_upper_bound=bound)
    ok = np.isfinite(dist)
    anchors = reference.anchors
    if reach is not None:
        found = idx[ok]
        offset = moved[ok] - reference.points[found]
        normal = reference.normals[found]
        across = normal[:, 0] * offset[:, 0] + normal[:, 1] * offset[:, 1]
        along = normal[:, 1] * offset[:, 0] - normal[:, 0] * offset[:, 1]
        ok[ok] = (along / reach[found]) ** 2 + (across / MAX_PAIR_DISTANCE) ** 2 <= 1.0
    if np.isfinite(reference.usable_range):  # the anchor as the new scan sees it
        found = idx[ok]
        ok[ok] = np.hypot(anchors[found, 0] - origin[0],
                          anchors[found, 1] - origin[1]) <= reference.usable_range
    return ok, idx


def _range_weights(reference, i, nx, ny, rx, ry, z):
    """GROWTH's weights 1/(1 + growth·r)² of new points paired with the reference's points
    i (their lines' normals nx, ny; the points rotated into the reference, R(θ)q = (rx, ry);
    the motion z): r where each point's beam meets its line, which does not depend on the
    point's own range noise (its measured range does, and so does which reference point it
    is paired with: weighed by either, the points the noise brought nearer would weigh
    more), or the reference's own_ranges."""
    anchors = reference.anchors[i]
    distance = np.abs(nx * (anchors[:, 0] - z[0]) + ny * (anchors[:, 1] - z[1]))
    cos_incidence = np.abs(nx * rx + ny * ry) / np.maximum(np.hypot(rx, ry), 1e-12)
    wall_range = distance / np.maximum(cos_incidence, MIN_COS_INCIDENCE)
    own = reference.own_ranges[i]
    wall_range = np.where(np.isnan(own), wall_range, own)
    return 1.0 / (1.0 + reference.growth * wall_range) ** 2


def refine(reference: ReferenceScan, points, z0):
    """(z, number of pairs used) of refine_with_covariance."""
    z, used, _ = refine_with_covariance(reference, points, z0)
    return z, used


def refine_with_covariance(reference: ReferenceScan, points, z0):
    """z = laser_j ⊖ laser_i refined so points of scan j lie on the lines of scan i.

    Returns (z, number of pairs used, covariance of z), or (z0, 0, None) if too few pairs
    were found or there is no reference (ReferenceScan.from_points gives None for a scan
    without lines). The covariance is the least-squares one, s²·(JᵀWJ)⁻¹ with s the robust
    scale of the point-to-line residuals: large along a direction the lines of this pair of
    scans do not fix (a corridor whose ends are out of range). Added to the noise model it
    made the simulated outdoor scene's radii and base unbiased (mean error +0.23 / +0.18 /
    +0.40 % → −0.03 / −0.04 / +0.05 %, 10 seeds) and the URG-04LX-like laser's RMS error
    0.29 → 0.24 %; twice or four times it was worse outdoors (bench/sensor_matrix.py).
    Runs once per scan: written on coordinate columns with scalar sin/cos (no per-call
    stacking of (N, 2) arrays), which makes it about a third faster than with se2's
    general helpers, with the same arithmetic.
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
    for _ in range(ITERATIONS):
        c, s = math.cos(z[2]), math.sin(z[2])
        rx, ry = c * qx - s * qy, s * qx + c * qy  # R(θ) q
        moved[:, 0] = rx + z[0]
        moved[:, 1] = ry + z[1]
        ok, idx = pairs(reference, moved, z[:2])
        used = int(np.count_nonzero(ok))
        if used < 20:
            return np.array(z0, float), 0, None
        i = idx[ok]
        nx, ny = normal_x[i], normal_y[i]
        rx, ry = rx[ok], ry[ok]
        residual = nx * (rx + z[0] - px[i]) + ny * (ry + z[1] - py[i])
        # ∂(R(θ) q + t)/∂θ = S R(θ) q: the rotated point turned by 90°.
        jac = np.stack((nx, ny, ny * rx - nx * ry))  # (3, n)
        weight = np.minimum(1.0, HUBER / np.maximum(np.abs(residual), 1e-12))
        if reference.growth:
            range_weight = _range_weights(reference, i, nx, ny, rx, ry, z)
            weight = weight * range_weight
        weighted = jac * weight
        hessian = weighted @ jac.T + 1e-9 * np.eye(3)
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
