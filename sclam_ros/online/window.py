"""Online calibration: a window of poses, marginalised priors with a change model for the radii.

Scheme (issue: the online node):
  - Arriving keyframes (one per scan) are merged into `params.keyframe_interval` chunks
    before they enter the window, exactly as the batch calibrator merges them
    (graph.merge_keyframes): the same long edges and per-scan arcs, and ~5× fewer poses.
  - Only the newest POSE_WINDOW_DISTANCE metres travelled are kept as poses in the graph
    that is solved (and at most MAX_WINDOW_KEYFRAMES, so standing still cannot grow it):
    the cost of a solve is bounded whatever the robot does. Older keyframes are
    marginalised in chunks: their edges are linearised at the current estimate and their
    poses integrated out (a Schur complement of the information AND of the gradient),
    leaving a 6×6 Gaussian on the calibration per chunk (core/marginal.py).
  - The chunks are a prior of the solve under the radii's change model (change.py): as
    data ages, what it says about the radii fades (e-folding over `window_distance`
    metres) while what it says about (b, l) is kept for good: the wheel base and the
    laser do not drift, the radii may. The newest `window_distance` metres of chunks are
    kept one by one (`history`), the older ones summed (`older`).
  - A load changes the radii at once. After every solve a likelihood-ratio test
    (change.change_point) asks whether the radii changed at some chunk boundary of the
    history or at the start of the pose window; above CHANGE_STATISTIC on
    CHANGE_CONFIRMATIONS solves in a row, the data before that boundary becomes one
    segment whose radii are integrated out jointly (its (b, l) kept), the data after it
    stays a prior on the new radii. So a long memory (precise radii while nothing
    changes) neither makes the estimate slow to follow a change nor lets the old radii
    into the wheel base and laser.
  - Every `solve_every` merged keyframes the window is re-solved by LM, warm-started from
    the previous solve's poses. Inline by default; the node runs the solves on a thread
    of its own (solver_thread.py) via prepare_solve / run_solve / apply_solve.
  - Each solve first judges which directions of the calibration the window and its priors
    determine (core/observability.py, at the warm start) and locks the others at nominal.
    What is reported (Estimate, CalibratorStatus) has every parameter such a direction
    moves at its nominal value, flagged, with its prior σ; the solution itself, which the
    next solve starts from, keeps the determined combinations.
"""
from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field
from typing import Optional

import numpy as np

from sclam_ros.core import graph as graph_mod, kinematics, se2
from sclam_ros.frontend.pipeline import Frontend
from sclam_ros.frontend.decimation import ONLINE_MATCH_PERIOD
from sclam_ros.core.covariance import factorize_information, marginal_covariance
from sclam_ros.core.inputs import Rejections
from sclam_ros.core.levenberg_marquardt import levenberg_marquardt
from sclam_ros.core.marginal import RADII, CalibrationPriorFactor, Gaussian, gaussian_of_prior
from sclam_ros.core.observability import Observability, settle_poses
from sclam_ros.core.params import CALIBRATION_KEYS
from sclam_ros.online.change import (ChangePoint, change_point, change_weight, faded_sum,
                                     radii_covariance_with_change)

# Bound on the merged keyframes in the window (0.5 s each by default: 200 s). Reached only
# when the robot crawls or stands still; then the oldest keyframes leave by count.
MAX_WINDOW_KEYFRAMES = 400
# Leaving keyframes are marginalised in chunks: one dense Schur complement per chunk. A
# chunk boundary is where the change test can place a change (5 s at 0.5 s keyframes).
MARGINALISE_BATCH = 10
# Fewer keyframes than this in the window: no solve (too little to say anything).
MIN_WINDOW_KEYFRAMES = 6
# Metres kept as poses in the solved graph (the rest is marginalised). A change inside it
# can only be placed at its start, so it bounds how soon a change is located: 5 m
# (≈ 11 s at 0.45 m/s) detected a 1 % step on both radii after 17 s where 10 m took 62 s
# (bench/load_change.py, seed 1).
POSE_WINDOW_DISTANCE = 5.0
# A radius change is declared when the change point's likelihood ratio (change.py) exceeds
# CHANGE_STATISTIC on CHANGE_CONFIRMATIONS solves in a row. At one boundary fixed in advance
# the ratio would be a χ² with 2 dof; the test takes the largest over the ~45 boundaries of
# a 100 m history, and the window's noise model overstates the noise (the batch solve's
# variance factors are 0.25-0.46, bench/online_sigma.py), which shrinks the ratio by as
# much. Measured on clean 6-10 minute recordings (bench/load_change.py): no false alarm in
# 50 minutes; a 1 % step is detected 12-25 s after it.
CHANGE_STATISTIC = 6.0
CHANGE_CONFIRMATIONS = 3
# The test needs a reference: marginalised data of at least this many metres, and a change
# is placed no earlier than after the history's first this many metres. Chunks right after
# the start are linearised around radii still converging from nominal: against the first
# one alone the ratio sat at 3-6 for minutes of clean driving.
MIN_TESTED_HISTORY = 10.0
# A window solve stops when an LM step lowers the cost by less than this fraction, or after
# MAX_ITERATIONS steps: with a window cost of 50-500 (χ² ≈ dof), 1e-4 is a Δχ² of
# 0.005-0.05, a parameter step well below its σ, and the next solve, warm-started a second
# later, carries on from there. Measured (bench/load_change.py): capped at 2 steps the
# tracked radii matched those of 10 steps at 1e-6 to 0.001 %; at 3 steps 91 % of the
# solves end converged, and a solve takes ~8 ms instead of ~15 (bench/node_latency.py).
RELATIVE_TOLERANCE = 1e-4
MAX_ITERATIONS = 3
# The published σ is the window's H⁻¹ scaled by its a-posteriori variance factor
# (window_variance_factor); the change test keeps the stated model it is tuned on.
VARIANCE_FACTOR_LIMITS = (0.01, 100.0)


@dataclass
class Estimate:
    """The current calibration and its marginal uncertainty, as it may be published: a
    parameter the data did not determine is at its nominal value with its prior σ."""

    stamp: float
    values: dict  # the six CALIBRATION_KEYS
    sigma: dict
    covariance: np.ndarray  # (6, 6)
    keyframes_in_window: int
    window_distance: float  # m covered by the window
    converged: bool = True
    # edge type ("odometry", "laser") -> (3,) RMS of the raw residuals (m, m, rad)
    residual_rms: dict = field(default_factory=dict)
    # CALIBRATION_KEYS -> the data determines it (core/observability.py)
    observable: dict = field(default_factory=lambda: dict.fromkeys(CALIBRATION_KEYS, True))

    def vector(self):
        return np.array([self.values[k] for k in CALIBRATION_KEYS])


@dataclass(frozen=True)
class CalibratorStatus:
    """What is reported of an OnlineCalibrator, copied out of it: safe to hand to another
    thread or process while the calibrator goes on (see online/process.py)."""

    estimate: Optional[Estimate]
    calibration: np.ndarray  # (6,) the values in use: the estimate's (unobserved at nominal)
    nominal: np.ndarray  # (6,)
    observable: dict  # CALIBRATION_KEYS -> bool (all False before the first estimate)
    window_keyframes: int
    window_length: float  # m the radii are estimated from (poses + marginalised chunks)
    pose_window_length: float  # m of it still held as poses
    window_distance: float  # m, the configured radii memory (change.py)
    radius_changes: int
    change_statistic: float  # of the last solve (nan before the first test)
    solves: int
    skipped_scans: int
    unconverged_in_a_row: int
    scan_matches: int  # KISS-ICP's, used or not
    scan_matches_confirmed: int  # by the point-to-line refinement (used)
    sigma_may_be_small: bool  # point_to_line.RefinedScanMatcher.sigma_may_be_small


class OnlineCalibrator:
    """Feeds on encoder samples and scans in arrival order; keeps an up-to-date Estimate."""

    def __init__(self, params, rejections: Optional[Rejections] = None, solve_every: int = 2,
                 inline_solve: bool = True):
        self.params = params
        self.inline_solve = inline_solve
        self.rejections = rejections if rejections is not None else Rejections()
        self.solve_every = solve_every
        self.nominal = np.array([getattr(params, k) for k in CALIBRATION_KEYS])
        self.generation = 0  # counts window resets; solves and chunks from older ones are void
        self.frontend = Frontend(params, self.rejections, match_period=ONLINE_MATCH_PERIOD)
        self.merger = graph_mod.KeyframeMerger(params.keyframe_interval)
        self.reset_calibration()

    # --- user actions -------------------------------------------------------------------
    def reset_window(self) -> None:
        """Forget the pose window, and what all marginalised data said about the
        radii (they restart from their current value); what it said about (b, l) is kept."""
        self.window = deque()
        self._distance = deque()  # metres travelled by each keyframe's odometry edge
        self._leaving = []  # keyframes out of the window, not yet a full chunk
        self._leaving_metres = 0.0
        self._chunks_due = []  # (keyframes, metres) waiting to be marginalised
        self.forget_radii()  # the chunks' radii go, their (b, l) stays
        self._since_solve = 0
        self._solved_poses = {}  # keyframe index -> pose of the last solve (warm start)
        self.solve_pending = False  # a solve is due (inline_solve False: the caller runs it)
        self.generation += 1

    def reset_calibration(self) -> None:
        """Back to the nominal values and no accumulated information at all."""
        self.calibration = self.nominal.copy()
        self.frontend.calibration = self.calibration.copy()
        self.older = Gaussian()  # chunks older than the history, radii faded (change.py)
        self.history = deque()  # _Chunk, oldest first: the newest window_distance metres
        self._chunks_made = 0
        self.radius_changes = 0  # times a change of the radii was detected
        self.change_statistic = float("nan")  # of the last solve
        self.estimate: Optional[Estimate] = None
        self.solves = 0
        self.unconverged_in_a_row = 0  # solves that hit MAX_ITERATIONS, since the last that did not
        self.reset_window()

    def set_window_distance(self, metres: float) -> None:
        self.params.window_distance = float(metres)
        self._trim()

    def forget_radii(self, before: Optional[int] = None) -> None:
        """The radii changed before the chunk numbered `before` (default: before the pose
        window): the data before it is one segment whose radii are integrated out jointly;
        its (b, l) is kept for good, the chunks after it stay a prior on the radii."""
        segment = []
        while self.history and (before is None or self.history[0].number < before):
            segment.append(self.history.popleft())
        self.older = self._faded(segment, self.older).without_radii()
        self._over_threshold = 0

    def _retire_oldest_chunk(self) -> None:
        """The oldest chunk leaves the history: it joins the older data, radii fading."""
        chunk = self.history.popleft()
        self.older = self._faded([chunk], self.older)

    def fading_length(self) -> float:
        """Metres over which the radii information of old data fades by e (change.py)."""
        return self.params.window_distance

    def _faded(self, chunks, start: Gaussian) -> Gaussian:
        return faded_sum([c.gaussian for c in chunks], [c.metres for c in chunks],
                         self.fading_length(), start)

    # --- data -----------------------------------------------------------------------------
    def add_encoder(self, stamp, left_raw, right_raw) -> Optional[Estimate]:
        return self.add_keyframes(self.frontend.add_encoder(stamp, left_raw, right_raw))

    def add_scan(self, scan) -> Optional[Estimate]:
        # A fast laser's scans are thinned to ~10 Hz by the front end (frontend/decimation.py),
        # as in the batch calibration.
        return self.add_keyframes(self.frontend.add_scan(scan))

    def add_keyframes(self, keyframes) -> Optional[Estimate]:
        """Per-scan keyframes from `self.frontend` (e.g. via offline.iter_keyframes)."""
        updated = None
        for raw in keyframes:
            for kf in self.merger.add(raw):
                self._append(kf)
                if self._since_solve >= self.solve_every and len(self.window) >= MIN_WINDOW_KEYFRAMES:
                    if self.inline_solve:
                        updated = self.solve() or updated
                    else:
                        self.solve_pending = True
        return updated

    def _append(self, kf) -> None:
        self.window.append(kf)
        travelled = 0.0
        if kf.dphi is not None:
            s, _ = kinematics.arc_length_and_rotation(kf.dphi, self.calibration[:3])
            travelled = abs(float(s))
        self._distance.append(travelled)
        self._trim()
        self._since_solve += 1

    def pose_window_length(self) -> float:
        return float(sum(self._distance))

    def history_length(self) -> float:
        """Metres of travel of the marginalised chunks kept one by one (the history)."""
        return float(sum(c.metres for c in self.history))

    def window_length(self) -> float:
        """Metres of travel the radii are estimated from (poses + marginalised chunks)."""
        return self.pose_window_length() + self.history_length()

    def status(self) -> CalibratorStatus:
        estimate, refined = self.estimate, self.frontend.refined_matcher
        return CalibratorStatus(
            estimate=estimate,
            calibration=self.nominal.copy() if estimate is None else estimate.vector(),
            nominal=self.nominal.copy(),
            observable=(dict.fromkeys(CALIBRATION_KEYS, False) if estimate is None
                        else dict(estimate.observable)),
            window_keyframes=len(self.window),
            window_length=self.window_length(), pose_window_length=self.pose_window_length(),
            window_distance=float(self.params.window_distance),
            radius_changes=self.radius_changes, change_statistic=self.change_statistic,
            solves=self.solves, skipped_scans=self.frontend.skipped_scans,
            unconverged_in_a_row=self.unconverged_in_a_row,
            scan_matches=refined.matches, scan_matches_confirmed=refined.confirmed,
            sigma_may_be_small=refined.sigma_may_be_small,
        )

    def _trim(self) -> None:
        pose_limit = min(self.params.window_distance, POSE_WINDOW_DISTANCE)
        while len(self.window) > 2 and (
            self.pose_window_length() - self._distance[0] > pose_limit
            or len(self.window) > MAX_WINDOW_KEYFRAMES
        ):
            self._leaving.append(self.window.popleft())
            self._leaving_metres += self._distance.popleft()
        if len(self._leaving) >= MARGINALISE_BATCH:
            self._chunks_due.append((self._leaving, self._leaving_metres))
            # The last leaving keyframe stays as the start of the next chunk so the edges
            # between chunks are not lost (each edge is counted in exactly one chunk: the
            # edge into the window's first keyframe is not in the window's graph).
            self._leaving = [self._leaving[-1]]
            self._leaving_metres = 0.0
            if self.inline_solve:
                self.marginalise_due()
        self._trim_history()

    def _trim_history(self) -> None:
        while self.history and self.window_length() > self.params.window_distance:
            self._retire_oldest_chunk()

    # Marginalising a chunk costs a few ms of dense algebra; the node does it on its solver
    # thread, outside its lock (take_chunks_due / marginalise / add_chunks), not in a callback.
    def marginalise_due(self) -> None:
        self.add_chunks(self.generation,
                        self.marginalise_chunks(self.take_chunks_due(), self.calibration))

    def marginalise_chunks(self, due, calibration) -> list:
        """(Gaussian or None, metres) of each (keyframes, metres) taken from the due list."""
        return [(self.marginalise(keyframes, calibration), metres) for keyframes, metres in due]

    def take_chunks_due(self) -> list:
        due, self._chunks_due = self._chunks_due, []
        return due

    def add_chunks(self, generation, chunks) -> None:
        """(Gaussian or None, metres) from marginalise, taken at `generation`."""
        if generation != self.generation:
            return  # the window was reset meanwhile: these keyframes are forgotten
        for gaussian, metres in chunks:
            if gaussian is not None:
                self.history.append(_Chunk(gaussian, metres, self._chunks_made))
                self._chunks_made += 1
        self._trim_history()

    # --- estimation -----------------------------------------------------------------------
    def _problem(self, keyframes, with_prior=True, warm=False, calibration=None):
        """The graph of `keyframes` linearised around `calibration` (default: the current
        one); with_prior adds the marginalised data's Gaussian (reads the calibrator's
        state: hold the node's lock)."""
        keyframes = list(keyframes)
        inputs = graph_mod.GraphInputs.from_keyframes(keyframes)
        extra = []
        if with_prior and not (prior := self.prior()).is_empty():
            extra.append(CalibrationPriorFactor(prior))
        poses = self._warm_poses(keyframes, inputs) if warm else None
        return inputs, graph_mod.build_problem(
            inputs, self.params, self.calibration if calibration is None else calibration,
            poses=poses, nominal=self.nominal, extra_factors=extra,
            # Not corrected here: the marginalised history's information vector would have
            # to carry the correction, each chunk checked as
            # variance_components.settle_corrections does.
            correct_dilution=False,
        )

    def prior(self) -> Gaussian:
        """What the marginalised data says about the calibration (radii faded by age)."""
        return self._faded(self.history, self.older)

    def _warm_poses(self, keyframes, inputs):
        """Poses of the last solve where the window still holds them; the new keyframes
        chained on from there. The window moves by a keyframe or two between solves, so
        LM starts next to its optimum (measured: ~9 iterations from chained scan matches
        per solve, see bench/node_latency.py, against 2-3 warm)."""
        known = [n for n, kf in enumerate(keyframes) if kf.index in self._solved_poses]
        if not known or known != list(range(len(known))):
            return graph_mod.initial_poses(inputs, self.calibration)
        last = known[-1]
        poses = np.empty((len(keyframes), 3))
        poses[: last + 1] = [self._solved_poses[kf.index] for kf in keyframes[: last + 1]]
        if last + 1 < len(keyframes):
            # Only the new keyframes are chained, from the last solved one (chaining the
            # whole window was half the time of preparing a solve).
            tail = graph_mod.initial_poses(graph_mod.GraphInputs.from_keyframes(keyframes[last:]),
                                           self.calibration)
            poses[last + 1:] = se2.compose(np.broadcast_to(poses[last], tail[1:].shape), tail[1:])
        return poses

    def marginalise(self, leaving, calibration) -> Optional[Gaussian]:
        """What the leaving keyframes knew about the calibration: a Schur complement.

        H = JᵀJ and g = Jᵀr of the leaving edges alone, linearised at x₀ = (the
        current calibration, poses chained from the scan matches and settled on the chunk's
        edges with the calibration held: observability.settle_poses), over (poses, k, l); the poses are integrated out:
            Λ = H_cc − H_cp H_pp⁺ H_pc,   g' = g_c − H_cp H_pp⁺ g_p,
        a Gaussian with information Λ and information vector η = Λ c₀ − g' (its mean is
        the chunk's own Gauss-Newton optimum for c, not the current estimate: without g'
        the prior would only echo the estimate it was taken at). The pseudo-inverse keeps
        exactly the information that is there and no more.
        """
        inputs, problem = self._problem(leaving, with_prior=False, calibration=calibration)
        if len(inputs.odo_from) == 0 or len(inputs.laser_from) == 0:
            return None
        problem.factors = [f for f in problem.factors if f.measurement]
        # At chained scan matches a chunk of standing still "informs" the laser yaw through
        # the matches' jitter, and that would add up in the permanent prior for good.
        problem.values = settle_poses(problem)
        system = problem.linear_system(problem.values)
        jac = system.dense_jacobian()
        hessian = jac.T @ jac
        gradient = jac.T @ system.residual
        layout = problem.layout
        calib = np.concatenate([layout.columns("odometry"), layout.columns("laser")])
        poses = np.setdiff1d(np.arange(layout.size), calib)
        h_cp = hessian[np.ix_(calib, poses)]
        h_pp_pinv = np.linalg.pinv(hessian[np.ix_(poses, poses)], hermitian=True)
        info = hessian[np.ix_(calib, calib)] - h_cp @ h_pp_pinv @ h_cp.T
        info = 0.5 * (info + info.T)
        reduced_gradient = gradient[calib] - h_cp @ h_pp_pinv @ gradient[poses]
        return Gaussian(info, info @ calibration - reduced_gradient)

    def solve(self) -> Optional[Estimate]:
        """Solve the window now, on this thread."""
        return self.apply_solve(run_solve(self.prepare_solve()))

    # A solve in three steps, so that the node can run the expensive middle one on a
    # thread of its own while encoder and scan callbacks go on: prepare_solve and
    # apply_solve touch the calibrator's state (hold the node's lock around them),
    # run_solve touches nothing but its job.
    def prepare_solve(self) -> Optional["SolveJob"]:
        self._since_solve = 0
        window = list(self.window)
        if len(window) < MIN_WINDOW_KEYFRAMES:  # a reset came after the request
            return None
        inputs, problem = self._problem(window, warm=True)
        if len(inputs.odo_from) == 0 or len(inputs.laser_from) == 0:
            return None
        weak = gaussian_of_prior(self.nominal, graph_mod.prior_sigmas(self.nominal))
        prior = self.prior() + weak
        history = list(self.history)
        return SolveJob(self.generation, [kf.index for kf in window], float(inputs.stamps[-1]),
                        problem, len(window), self.window_length(), prior,
                        change_testable=self.history_length() >= MIN_TESTED_HISTORY,
                        nominal=self.nominal.copy(), reference=self.older + weak,
                        history=[c.gaussian for c in history],
                        history_numbers=[c.number for c in history],
                        next_chunk_number=self._chunks_made,
                        history_metres=[c.metres for c in history] + [self.pose_window_length()])

    def apply_solve(self, outcome: Optional["SolveOutcome"]) -> Optional[Estimate]:
        if outcome is None:
            return None
        job = outcome.job
        if job.generation != self.generation:
            return None  # a reset came while it ran: the result belongs to data now forgotten
        estimate = outcome.calibration
        if not np.all(np.isfinite(estimate)) or not np.all(np.isfinite(outcome.covariance)):
            self.rejections.add("online_solve_non_finite")
            return None
        self.calibration = estimate
        observability = outcome.observability
        reported = observability.reported(estimate, job.nominal)
        # The scan matcher's odometry guess uses what may be published: the parameters the
        # data has determined, the others at nominal. A first solve on a few keyframes had
        # put the wheel base 0.1 m off; seeded with it, the matcher lost 30 of 600 scans of
        # a live run (test_online_live).
        self.frontend.calibration = reported.copy()
        self._solved_poses = dict(zip(job.keyframe_indices, outcome.poses))
        self.solves += 1
        self.unconverged_in_a_row = 0 if outcome.converged else self.unconverged_in_a_row + 1
        cov = observability.reported_covariance(outcome.variance_factor * outcome.covariance)
        found = self._test_for_radius_change(job, estimate, outcome.covariance,
                                             observability.as_dict())
        if found is not None:
            # The published radii may be those of before a change being detected: their σ
            # weighs in the change model as far as the test believes in it.
            cov[np.ix_(RADII, RADII)] = radii_covariance_with_change(
                cov[np.ix_(RADII, RADII)], found,
                change_weight(found.statistic, CHANGE_STATISTIC), outcome.variance_factor)
        self.estimate = Estimate(
            stamp=job.stamp,
            values=graph_mod.as_dict(reported),
            sigma=graph_mod.as_dict(np.sqrt(np.clip(np.diag(cov), 0, None))),
            covariance=cov,
            keyframes_in_window=job.keyframes_in_window,
            window_distance=job.window_distance,
            converged=outcome.converged,
            residual_rms=outcome.residual_rms,
            observable=observability.as_dict(),
        )
        return self.estimate

    def _test_for_radius_change(self, job, mean, cov, observable) -> Optional[ChangePoint]:
        """The change test on this solve (None where it cannot be made); a change confirmed
        CHANGE_CONFIRMATIONS times in a row is acted on (forget_radii)."""
        # A parameter held at nominal carries a lock's information, not the data's.
        if not job.change_testable or not all(observable.values()):
            self.change_statistic = float("nan")
            return None
        # The pose window's own information: the solve's posterior less its priors.
        information = np.linalg.inv(cov)
        information = 0.5 * (information + information.T)
        window = Gaussian(information - job.prior.information, information @ mean - job.prior.eta)
        # A change is looked for after the first MIN_TESTED_HISTORY metres of the history:
        # its first chunks after a start or a change are linearised at radii still far
        # off, and against them alone the ratio sat at 3-6 for minutes of clean driving.
        first = int(np.searchsorted(np.cumsum(job.history_metres), MIN_TESTED_HISTORY)) + 1
        found = change_point([*job.history, window], job.history_metres,
                             self.fading_length(), job.reference,
                             graph_mod.prior_sigmas(job.nominal), first_boundary=first)
        self.change_statistic = found.statistic
        self._over_threshold = self._over_threshold + 1 if found.statistic > CHANGE_STATISTIC else 0
        if self._over_threshold >= CHANGE_CONFIRMATIONS:
            self.radius_changes += 1
            # Chunks may have joined the history since the job was prepared: the boundary
            # is the chunk's number (or the pose window's start as it was then).
            numbers = [*job.history_numbers, job.next_chunk_number]
            self.forget_radii(numbers[found.boundary])
        return found


@dataclass
class SolveJob:
    """A window problem to solve, and what it needs to be applied afterwards."""

    generation: int  # OnlineCalibrator.generation when it was prepared
    keyframe_indices: list
    stamp: float
    problem: object
    keyframes_in_window: int
    window_distance: float
    prior: Gaussian  # every prior of the problem, for the change test
    change_testable: bool  # enough marginalised radii information to test against
    nominal: np.ndarray  # (6,) where undetermined directions are locked
    reference: Gaussian  # the data older than the history (and the weak prior)
    history: list  # the history's Gaussians when the job was prepared, oldest first
    history_numbers: list  # their _Chunk.number
    next_chunk_number: int  # of the first chunk marginalised after the job was prepared
    history_metres: list  # their metres, and the pose window's


@dataclass
class SolveOutcome:
    job: SolveJob
    calibration: np.ndarray
    covariance: np.ndarray  # under the stated noise model (the change test's)
    poses: np.ndarray
    converged: bool
    residual_rms: dict
    observability: Observability
    variance_factor: float = 1.0  # σ̂₀² of the window (window_variance_factor)


def run_solve(job: Optional[SolveJob]) -> Optional[SolveOutcome]:
    """LM on a prepared window problem and the marginal covariance of the calibration."""
    from sclam_ros.core.estimator import residual_rms  # estimator imports nothing of the window

    if job is None:
        return None
    problem = job.problem
    # Judged at the warm start, before the lock is added (see Observability.of_problem).
    observability = Observability.of_problem(problem, graph_mod.prior_sigmas(job.nominal))
    problem.factors.extend(observability.lock(job.nominal))
    result = levenberg_marquardt(problem, max_iterations=MAX_ITERATIONS,
                                 relative_tolerance=RELATIVE_TOLERANCE)
    calibration = graph_mod.calibration_of(result.values)
    if not np.all(np.isfinite(calibration)):
        return SolveOutcome(job, calibration, np.full((6, 6), np.nan), result.values["poses"],
                            False, {}, observability)
    system, _, factorized = factorize_information(problem, result.values, result.system)
    cov = marginal_covariance(problem, result.values, ["odometry", "laser"], lu=factorized)
    return SolveOutcome(job, calibration, cov, result.values["poses"], result.converged,
                        residual_rms(problem, result.values, result.system), observability,
                        window_variance_factor(system, problem.layout.size))


def window_variance_factor(system, unknowns: int) -> float:
    """The a-posteriori variance factor σ̂₀² = χ² / (rows − unknowns) of a window solve:
    by how much the stated noise model over- (< 1) or understates (> 1) the window's
    residuals, all factors together (the history's priors were made under the same model).
    The published covariance is the solve's times it. VARIANCE_FACTOR_LIMITS bound it."""
    redundancy = len(system.residual) - unknowns
    if redundancy <= 0:
        return 1.0
    return float(np.clip(np.sum(system.residual ** 2) / redundancy, *VARIANCE_FACTOR_LIMITS))


@dataclass
class _Chunk:
    """Marginalised keyframes of the last window_distance metres (the history)."""

    gaussian: Gaussian
    metres: float
    number: int  # chunks are numbered in the order they were made
