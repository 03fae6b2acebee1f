"""Where the outdoor row's bias comes from (or another sensor-matrix row's): the range noise.

The range noise is what moves the sensor matrix's outdoor row away from the truth: without
it the radii and base are right (`bench/sensor_matrix.py --factors outdoor`). Here each
seed is simulated twice with the same drive, the same random draws and the same scene:
once as the matrix does (1 cm range noise) and once without range noise. The noisy
recording is calibrated with its scan-match refinement (frontend/point_to_line.py) handed
the noise-free returns of the same scan in one role at a time:

  - as recorded: nothing replaced;
  - new scan noise-free: the refined scan's own points (KISS-ICP still gets the noisy scan);
  - reference noise-free: the scan the match starts from (its lines: points kept, normals,
    anchors);
  - reference anchors noise-free: only the points the residuals are measured from;
  - pairing at the true motion: each new point paired once, by its noise-free position at
    the true motion, and kept with that line (the residuals noisy as recorded);
  - matches = the true motion: every used match replaced by the truth (its information
    kept): what the rest of the pipeline (odometry, graph) makes of perfect matches;
  - matches mirrored about the truth: z' = 2·z_true − z, the same errors with their sign
    turned: a bias of the matches flips, one made by the graph would not;
  - pairs within 15 cm (a circle): a new point is paired with its nearest reference
    return when it lies within MAX_PAIR_DISTANCE of it, instead of in the ellipse along
    the return's line the product uses (point_to_line.ALONG_LINE): where the beams are
    sparse on the surface, whether a point between two returns reaches one then depends
    on that return's own range noise. On references whose returns are their own anchors
    (lines fitted over 6 beams), as the outdoor laser's;
  - matches and wheel increments = the truth: as "matches = the true motion", and each
    odometry edge's wheel increments replaced by those that drive the true motion between
    its two stamps (one arc): what the graph makes of odometry without slip noise;
  - reference anchors with fresh noise: the anchors noise-free, then moved along their
    beams by a new draw of the laser's range noise (the same σ), independent of the noise
    that chose the pairs, fitted the lines and passed the straightness tests: noise as
    such against noise that took part in those choices;
  - reference anchors with their noise mirrored: the anchors' recorded noise with its sign
    turned (noise-free return − recorded noise): a bias even in the noise stays, one made
    by the choices the noise took part in turns;
  - reference lines fitted to the noise-free returns: each kept return's normal from its
    noise-free neighbourhood (returns, anchors and which are kept as recorded);
  - reference returns kept by the noise-free returns' tests: which returns get a line
    decided on the noise-free scan (their returns, anchors and normals as recorded);
  - new scan with fresh noise: the refined scan's points noise-free, then moved along
    their beams by a new draw of the range noise (KISS-ICP gets the recorded scan, and the
    scan is the next match's reference as recorded): whether the bias needs the same
    scan's noise on both sides, as the new scan of one match and the reference of the
    next;
  - refinement started at the true motion: from the truth instead of KISS-ICP's answer
    (still confirmed against KISS-ICP's answer), which KISS-ICP found with the same
    reference returns in its map;
  - refinement confirmed against the true motion: a refinement (from KISS-ICP's answer)
    is used where it lies within MAX_CORRECTION of the truth instead of KISS-ICP's answer:
    which matches are used no longer depends on whether two answers sharing the
    reference's noise agree;
  - reference noise-free but its anchors as recorded: which returns are kept, their
    lines and the pairing all from the noise-free returns, the residuals measured from
    the recorded returns: the anchors' noise with none of the reference's choices made
    by it;
  - both: the last two at once;
  - refinement confirmed against the odometry's prediction: as "confirmed against the
    true motion", but against the matcher's guess from the wheels (with the calibration
    in use: nominal in a batch calibration), which no laser noise entered.

Mean error of r_l r_r b (%, ± standard error over the seeds), of the laser yaw, and of the
laser x with the RMS of its error over its reported σ (where the turns see the mount).

The front end is patched for the run only (functions of point_to_line and scan_matching
wrapped in each worker process; the last variant also rewrites the keyframes' increments
before the calibration); the product code is not changed.

--row N takes another row of bench/sensor_matrix.py instead of the outdoor one (its twin
without range noise: neither the constant part nor the part proportional to the range).
Variants 3, 9-12, 16 and 17 take the reference's returns as its anchors or fit its lines
over 6 beams, as the product does on a low-noise laser, and variant 7 applies only there:
on a laser judged noisy (wall-segment lines, anchors where the beams meet them) they
change more than they say, or nothing. Variants 0-2, 4-6, 8, 13-15 and 18 apply to any row.

Run: .venv/bin/python bench/outdoor_noise_roles.py [--seeds 20] [--duration 120] [--jobs 2]
     [--variants N ...]   (their numbers in the list above, from 0; default all)
     [--row N]            (bench/sensor_matrix.py's row, from 0; default the outdoor one)
"""
from __future__ import annotations

import dataclasses
import functools
import math
import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import scratch_dir, seeds_arguments, table  # noqa: E402
from sensor_matrix import ROWS  # noqa: E402

OUTDOOR_NAME = "outdoor, default laser"
VARIANTS = ("as recorded", "new scan noise-free", "reference noise-free",
            "reference anchors noise-free", "pairing at the true motion",
            "matches = the true motion", "matches mirrored about the truth",
            "pairs within 15 cm (a circle)", "matches and wheel increments = the truth",
            "reference anchors with fresh noise", "reference anchors with their noise mirrored",
            "reference lines fitted to the noise-free returns",
            "reference returns kept by the noise-free returns' tests",
            "new scan with fresh noise", "refinement started at the true motion",
            "refinement confirmed against the true motion",
            "reference noise-free but its anchors as recorded",
            "both: reference noise-free but its anchors, confirmed against the truth",
            "refinement confirmed against the odometry's prediction")
TRUE_MATCHES = (VARIANTS[5], VARIANTS[8])


class _Twin:
    """The noise-free ranges of every scan of the twin recording (by stamp), the truth of
    the noisy one, and what the patches need to know of the scan being matched."""

    def __init__(self, noisy, clean, truth, params):
        from sclam_ros.frontend import point_to_line
        from sclam_ros.io.recording import read_ground_truth, read_recording

        self.ranges = {}
        original = point_to_line.RefinedScanMatcher.add_scan

        def record(matcher, scan, guess, points):
            self.ranges[round(scan.stamp, 6)] = np.array(scan.ranges, float)
            return original(matcher, scan, guess, points)

        point_to_line.RefinedScanMatcher.add_scan = record
        read_recording(clean, params)
        point_to_line.RefinedScanMatcher.add_scan = original
        self.stamps, self.poses = read_ground_truth(noisy)
        self.heading = np.unwrap(self.poses[:, 2])
        self.mount = np.array([truth["laser_x"], truth["laser_y"], truth["laser_yaw"]])
        self.clean_points = None  # of the scan being added, aligned with its noisy points
        self.beam_spacing = None  # rad, of the scan being added (as thinned for the matcher)
        self.match_stamps = None  # (from, to) of the match being refined
        self.guess = None  # the wheels' prediction of the match being refined
        self.rng = np.random.default_rng(int(truth["seed"]))  # fresh range noise
        self.range_noise = float(truth["sensors"]["range_noise"])  # m, 1σ
        self.range_noise_per_m = float(truth["sensors"]["range_noise_per_m"])  # its part ∝ range

    def with_fresh_noise(self, points):
        """`points` (noise-free, laser frame) moved along their beams by a new draw of the
        recording's range noise."""
        ranges = np.linalg.norm(points, axis=1, keepdims=True)
        sigma = self.range_noise + self.range_noise_per_m * ranges
        return points + points / ranges * self.rng.normal(0.0, 1.0, (len(points), 1)) * sigma

    def points_of(self, scan, min_range, max_range):
        """The noise-free twin of scan_to_points(scan, min_range, max_range)."""
        from sclam_ros.frontend.scan_matching import valid_beams

        keep = valid_beams(scan, min_range, max_range)  # the noisy scan's returns
        r = self.ranges[round(scan.stamp, 6)][keep]
        a = scan.angles()[keep]
        return np.column_stack([r * np.cos(a), r * np.sin(a), np.zeros(len(r))])

    def base_pose(self, t):
        """The true base pose at stamp t (heading unwrapped)."""
        return np.array([np.interp(t, self.stamps, self.poses[:, 0]),
                         np.interp(t, self.stamps, self.poses[:, 1]),
                         np.interp(t, self.stamps, self.heading)])

    def true_motion(self, stamp_from, stamp_to):
        """The laser's true motion between the two stamps, in its frame at stamp_from."""
        from sclam_ros.core import se2

        return se2.between(se2.compose(self.base_pose(stamp_to), self.mount),
                           se2.compose(self.base_pose(stamp_from), self.mount))

    def true_increments(self, stamp_from, stamp_to, truth):
        """(left, right) wheel angles (rad) that drive the true base motion between the two
        stamps along one arc, with the true radii and base."""
        from sclam_ros.core import se2

        motion = se2.between(self.base_pose(stamp_to), self.base_pose(stamp_from))
        turn = motion[2]
        chord = math.copysign(math.hypot(motion[0], motion[1]), motion[0])
        arc = chord * (0.5 * turn / math.sin(0.5 * turn)) if abs(turn) > 1e-9 else chord
        half_turn = 0.5 * turn * truth["wheel_base"]
        return np.array([(arc - half_turn) / truth["wheel_radius_left"],
                         (arc + half_turn) / truth["wheel_radius_right"]])


def _refined(q, z0, pairs, reference):
    """(z, pairs used, covariance) of point_to_line.refine_with_covariance's Gauss-Newton
    iterations on the points q (n, 2), with the pairing of each iteration given by
    `pairs(z, q turned by z) -> (used (n,) bool, index of each one's line in reference)`;
    (z0, 0, None) where fewer than 20 are used."""
    from sclam_ros.core import se2
    from sclam_ros.frontend import point_to_line as ptl

    z = np.array(z0, float)
    for _ in range(ptl.ITERATIONS):
        c, s = math.cos(z[2]), math.sin(z[2])
        turned = q @ np.array([[c, s], [-s, c]])
        used, line = pairs(z, turned)
        if np.count_nonzero(used) < 20:
            return np.array(z0, float), 0, None
        normal, anchor = reference.normals[line[used]], reference.anchors[line[used]]
        turned = turned[used]
        residual = np.sum(normal * (turned + z[:2] - anchor), axis=1)
        jac = np.stack((normal[:, 0], normal[:, 1],
                        normal[:, 1] * turned[:, 0] - normal[:, 0] * turned[:, 1]))
        weight = np.minimum(1.0, ptl.HUBER / np.maximum(np.abs(residual), 1e-12))
        hessian = (jac * weight) @ jac.T + 1e-9 * np.eye(3)
        step = -np.linalg.solve(hessian, (jac * weight) @ residual)
        z = z + step
        if math.hypot(step[0], step[1]) < 1e-6 and abs(step[2]) < 1e-7:
            break
    z[2] = se2.wrap_angle(z[2])
    scale = 1.4826 * float(np.median(np.abs(residual)))
    return z, int(np.count_nonzero(used)), scale**2 * np.linalg.inv(hessian)


def _line_normals(points):
    """(N, 2) each return's normal as ReferenceScan.from_points fits it on a low-noise laser
    (the line through its NORMAL_NEIGHBOURS nearest returns)."""
    from scipy.spatial import cKDTree

    from sclam_ros.frontend import point_to_line as ptl

    neighbours = cKDTree(points).query(points, min(ptl.NORMAL_NEIGHBOURS, len(points)))[1]
    return ptl._line_fit(points, neighbours)[0]


def _kept_as(clean_reference, clean, noisy, usable_range, beam_spacing):
    """A reference of the recorded returns `noisy` (their own anchors, their lines fitted
    over NORMAL_NEIGHBOURS of them, paired along them where `clean_reference` is) keeping
    the returns `clean_reference` (made from the noise-free twin `clean` of the same beams)
    keeps; None where that is None."""
    from scipy.spatial import cKDTree

    from sclam_ros.frontend import point_to_line as ptl

    if clean_reference is None:
        return None
    kept = cKDTree(clean).query(clean_reference.points)[1]
    points, normals = noisy[kept], _line_normals(noisy)[kept]
    reach = None if clean_reference.reach is None else ptl._along_reach(points, normals,
                                                                         beam_spacing)
    return ptl.ReferenceScan(points, normals, cKDTree(points), points, usable_range, reach)


def _patch(variant, twin):
    """Wrap the front end's functions for `variant` (this worker process only)."""
    from scipy.spatial import cKDTree

    from sclam_ros.core import se2
    from sclam_ros.frontend import point_to_line as ptl
    from sclam_ros.frontend import scan_matching

    add_scan, confirmed = ptl.RefinedScanMatcher.add_scan, ptl._confirmed
    original_from_points = ptl.ReferenceScan.from_points.__func__
    refine = ptl.refine_with_covariance
    match = scan_matching.ScanMatcher.add_scan

    def matcher_add_scan(matcher, scan, odometry_guess=None, points=None):
        m = match(matcher, scan, odometry_guess, points)
        if m is not None:
            twin.match_stamps = (m.stamp_from, m.stamp_to)
        return m

    def refined_add_scan(matcher, scan, guess, points):
        config = matcher.matcher.config
        twin.clean_points = twin.points_of(scan, config.min_range, config.max_range)
        twin.beam_spacing = abs(scan.angle_increment)
        twin.guess = guess  # the wheels' prediction of this match (None: none)
        out = add_scan(matcher, scan, guess, points)
        if out[1] is not None and variant in TRUE_MATCHES + (VARIANTS[6],):
            z_true = twin.true_motion(out[0].stamp_from, out[0].stamp_to)
            z = z_true.copy() if variant in TRUE_MATCHES else 2.0 * z_true - out[1]
            z[2] = se2.wrap_angle(z[2])
            out = (out[0], z, out[2])
        return out

    def reference_from_points(cls, points, noise=None, usable_range=np.inf, small_objects=False,
                              beam_spacing=None):
        clean = twin.clean_points[:, :2]
        from_points = functools.partial(original_from_points, beam_spacing=beam_spacing)
        if variant == VARIANTS[2]:
            return from_points(cls, clean, noise, usable_range, small_objects)
        if variant in (VARIANTS[16], VARIANTS[17]):
            reference = from_points(cls, clean, noise, usable_range, small_objects)
            if reference is not None:
                kept = cKDTree(clean).query(reference.points)[1]
                reference.anchors = np.asarray(points, float)[kept, :2]
            return reference
        if variant == VARIANTS[12]:
            return _kept_as(from_points(cls, clean, noise, usable_range, small_objects),
                            clean, np.asarray(points, float)[:, :2], usable_range, beam_spacing)
        reference = from_points(cls, points, noise, usable_range, small_objects)
        if reference is None or variant not in (VARIANTS[3], VARIANTS[9], VARIANTS[10],
                                                VARIANTS[11]):
            return reference
        kept = cKDTree(np.asarray(points, float)[:, :2]).query(reference.points)[1]
        if variant == VARIANTS[11]:
            reference.normals = _line_normals(clean)[kept]
        elif variant == VARIANTS[9]:
            reference.anchors = twin.with_fresh_noise(clean[kept])
        elif variant == VARIANTS[10]:
            reference.anchors = 2.0 * clean[kept] - reference.points
        else:
            reference.anchors = clean[kept]
        return reference

    def confirmed_with(reference, points, z_icp):
        # Where the refinement starts and what its answer is judged against (_confirmed:
        # both KISS-ICP's answer).
        start = against = z_icp
        if variant == VARIANTS[14]:
            start = twin.true_motion(*twin.match_stamps)
        elif variant in (VARIANTS[15], VARIANTS[17]):
            against = twin.true_motion(*twin.match_stamps)
        elif variant == VARIANTS[18] and twin.guess is not None:
            against = np.asarray(twin.guess, float)
        elif variant == VARIANTS[1]:
            points = twin.clean_points
        elif variant == VARIANTS[13]:
            points = twin.with_fresh_noise(twin.clean_points)
        if start is z_icp and against is z_icp:
            return confirmed(reference, points, z_icp)
        return ptl.verdict(reference, *refine(reference, points, start), against)

    def refine_paired_at_truth(reference, points, z0):
        """refine_with_covariance with each point's line chosen once, at the true motion."""
        if reference is None:
            return refine(reference, points, z0)
        z_true = twin.true_motion(*twin.match_stamps)
        c, s = math.cos(z_true[2]), math.sin(z_true[2])
        # the noise-free twin of `points`: the scan being matched is the one just added
        at_truth = twin.clean_points[:, :2] @ np.array([[c, s], [-s, c]]) + z_true[:2]
        ok, line = ptl.pairs(reference, at_truth, z_true[:2])
        if np.count_nonzero(ok) < 20:
            return np.array(z0, float), 0, None
        q, line = np.asarray(points, float)[ok, :2], line[ok]
        return _refined(q, z0, lambda z, turned: (np.ones(len(q), bool), line), reference)

    def refine_within_circle(reference, points, z0):
        """refine_with_covariance pairing within MAX_PAIR_DISTANCE of each return."""
        if reference is not None:
            reference = dataclasses.replace(reference, reach=None)
        return refine(reference, points, z0)

    scan_matching.ScanMatcher.add_scan = matcher_add_scan
    ptl.RefinedScanMatcher.add_scan = refined_add_scan
    ptl.ReferenceScan.from_points = classmethod(reference_from_points)
    ptl._confirmed = confirmed_with
    if variant == VARIANTS[4]:
        ptl.refine_with_covariance = refine_paired_at_truth
    if variant == VARIANTS[7]:
        ptl.refine_with_covariance = refine_within_circle


def run_one(job):
    """One seed, one variant, in its own worker process (the patches do not leak)."""
    variant, seed, duration, workdir, row = job
    from sclam_ros.core.estimator import calibrate_keyframes
    from sclam_ros.core.params import CALIBRATION_KEYS, SclamParams
    from sclam_ros.io.recording import read_recording
    from sclam_ros.sim import simulate

    noisy, clean = Path(workdir) / f"noisy_{seed}", Path(workdir) / f"clean_{seed}"
    truth = simulate(noisy, duration=duration, seed=seed, overwrite=True, **row)
    # No range noise, the same draws: the noise is drawn for every return either way.
    simulate(clean, duration=duration, seed=seed, overwrite=True, **noise_free(row))
    params = SclamParams.from_yaml(noisy / "params.yaml")
    twin = _Twin(noisy, clean, truth, params)
    _patch(variant, twin)
    recording = read_recording(noisy, params)
    if variant == VARIANTS[8]:
        previous = None
        for keyframe in recording.keyframes:
            if keyframe.dphi is not None and previous is not None:
                keyframe.dphi = twin.true_increments(previous.stamp, keyframe.stamp, truth)
                keyframe.dphi_parts = None
            previous = keyframe
    result = calibrate_keyframes(recording.keyframes, params, recording.rejections)
    error = {k: result.estimate[k] - truth[k] for k in CALIBRATION_KEYS}
    return variant, seed, [100.0 * error[k] / truth[k] for k in
                           ("wheel_radius_left", "wheel_radius_right", "wheel_base")], \
        math.degrees(error["laser_yaw"]), (error["laser_x"], result.sigma["laser_x"])


def noise_free(row):
    """The simulate() keywords of `row` without range noise (constant or ∝ range)."""
    laser = dict(row.get("laser", {}))
    if "range_noise_per_m" in laser:
        laser["range_noise_per_m"] = 0.0
    return dict(row, range_noise=1e-9, laser=laser)


def main():
    ap = seeds_arguments(__doc__, seeds=20, duration=120.0)
    ap.add_argument("--variants", type=int, nargs="+", default=list(range(len(VARIANTS))))
    ap.add_argument("--row", type=int, default=list(ROWS).index(OUTDOOR_NAME),
                    help="bench/sensor_matrix.py's row (its number, from 0; default outdoor)")
    args = ap.parse_args()
    variants = [VARIANTS[i] for i in args.variants]
    name = list(ROWS)[args.row]
    workdir = scratch_dir("sclam_outdoor_roles_")
    jobs = [(v, s, args.duration, workdir, ROWS[name]) for v in variants
            for s in range(1, args.seeds + 1)]
    # One job per process: the patches are process-wide.
    with ProcessPoolExecutor(args.jobs, max_tasks_per_child=1) as pool:
        results = list(pool.map(run_one, jobs))
    rows = []
    for variant in variants:
        relative = np.array([r[2] for r in results if r[0] == variant])
        yaw = np.array([r[3] for r in results if r[0] == variant])
        x_error, x_sigma = np.array([r[4] for r in results if r[0] == variant]).T
        se = relative.std(axis=0, ddof=1) / math.sqrt(len(relative))
        rows.append([variant, " ".join(f"{m:+.3f}" for m in relative.mean(axis=0)),
                     " ".join(f"{v:.3f}" for v in se),
                     f"{yaw.mean():+.3f} ± {yaw.std(ddof=1) / math.sqrt(len(yaw)):.3f}",
                     f"{1e3 * x_error.mean():+.2f} ± {1e3 * x_error.std(ddof=1) / math.sqrt(len(x_error)):.2f}",
                     f"{np.sqrt(np.mean((x_error / x_sigma) ** 2)):.2f}"])
    print(f"{name}, {args.seeds} seeds × {args.duration:.0f} s; errors "
          "against the simulator's truth")
    print(table(rows, ["refinement given", "mean error r_l r_r b %", "its standard error %",
                       "laser yaw error °", "laser x error mm", "laser x RMS err/σ"]))


if __name__ == "__main__":
    main()
