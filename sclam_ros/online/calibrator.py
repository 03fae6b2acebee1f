"""Online calibration: a window of poses, marginalised priors with a change model for the radii.

OnlineCalibrator wires the parts and decides when each runs:
  - Arriving keyframes (one per scan) are merged into `params.keyframe_interval` chunks
    before they enter the window, exactly as the batch calibrator merges them
    (graph.merge_keyframes): the same long edges and arcs, and ~5× fewer poses.
  - The newest metres are kept as poses in the graph that is solved (pose_window.py); older
    keyframes are marginalised in chunks (marginalise.py) into Gaussians on the calibration,
    kept as a prior under the radii's change model (history.py, change.py).
  - After every solve the change test asks whether the radii changed, and a confirmed
    change cuts the history there (change_detector.py).
  - Every `solve_every` merged keyframes the window is re-solved by LM, warm-started from
    the previous solve's poses (window_solve.py). Inline by default; the node runs the
    solves on a thread of its own (solver_thread.py) via prepare_solve / run_solve /
    apply_solve, and the marginalisation via take_chunks_due / marginalise_chunks /
    add_chunks.
  - What is reported (Estimate, CalibratorStatus) has every parameter a direction the data
    does not determine moves at its nominal value, flagged, with its prior σ; the solution
    itself, which the next solve starts from, keeps the determined combinations.
"""
from __future__ import annotations

from typing import Optional

import numpy as np

from sclam_ros.core import graph as graph_mod
from sclam_ros.core.inputs import Rejections
from sclam_ros.core.marginal import Gaussian, gaussian_of_prior
from sclam_ros.core.params import CALIBRATION_KEYS
from sclam_ros.frontend.config import DecimationConfig
from sclam_ros.frontend.pipeline import Frontend
from sclam_ros.online.change_detector import ChangeDetector
from sclam_ros.online.config import OnlineConfig
from sclam_ros.online.estimate import CalibratorStatus, Estimate
from sclam_ros.online.history import MarginalisedHistory
from sclam_ros.online.marginalise import marginalise
from sclam_ros.online.pose_window import PoseWindow
from sclam_ros.online.window_graph import window_problem
from sclam_ros.online.window_solve import SolveJob, SolveOutcome, run_solve


class OnlineCalibrator:
    """Feeds on encoder samples and scans in arrival order; keeps an up-to-date Estimate."""

    def __init__(self, params, rejections: Optional[Rejections] = None, solve_every: int = 2,
                 inline_solve: bool = True, config: OnlineConfig = OnlineConfig()):
        self.params = params
        self.config = config
        self.inline_solve = inline_solve
        self.rejections = rejections if rejections is not None else Rejections()
        self.solve_every = solve_every
        self.nominal = np.array(params.calibration_vector())
        self.generation = 0  # counts window resets; solves and chunks from older ones are void
        self.frontend = Frontend(params, self.rejections, match_period=DecimationConfig().online_match_period)
        self.merger = graph_mod.KeyframeMerger(params.keyframe_interval)
        self.reset_calibration()

    # --- user actions -------------------------------------------------------------------
    def reset_window(self) -> None:
        """Forget the pose window, and what all marginalised data said about the
        radii (they restart from their current value); what it said about (b, l) is kept."""
        self.window = PoseWindow(self.config.window)
        self.forget_radii()  # the chunks' radii go, their (b, l) stays
        self._since_solve = 0
        self.solve_pending = False  # a solve is due (inline_solve False: the caller runs it)
        self.generation += 1

    def reset_calibration(self) -> None:
        """Back to the nominal values and no accumulated information at all."""
        self.calibration = self.nominal.copy()
        self.frontend.calibration = self.calibration.copy()
        self.history = MarginalisedHistory(self.params)
        self.change_detector = ChangeDetector(self.config.change)
        self.estimate: Optional[Estimate] = None
        self.solves = 0
        self.unconverged_in_a_row = 0  # solves at the iteration cap since the last below it
        self.reset_window()

    def set_window_distance(self, metres: float) -> None:
        self.params.window_distance = float(metres)
        self._trim()

    def forget_radii(self, before: Optional[int] = None) -> None:
        """The radii changed before the chunk numbered `before` (default: before the pose
        window): the data before it is one segment whose radii are integrated out jointly;
        its (b, l) is kept for good, the chunks after it stay a prior on the radii."""
        self.history.forget_radii(before)
        self.change_detector.restart()

    def fading_length(self) -> float:
        """Metres over which the radii information of old data fades by e (change.py)."""
        return self.history.fading_length()

    @property
    def radius_changes(self) -> int:
        """Times a change of the radii was detected."""
        return self.change_detector.radius_changes

    @property
    def change_statistic(self) -> float:
        """The change test's statistic of the last solve (nan where none was made)."""
        return self.change_detector.change_statistic

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
                self.window.append(kf, self.calibration)
                self._trim()
                self._since_solve += 1
                if (self._since_solve >= self.solve_every
                        and len(self.window) >= self.config.solve.min_keyframes):
                    if self.inline_solve:
                        updated = self.solve() or updated
                    else:
                        self.solve_pending = True
        return updated

    def pose_window_length(self) -> float:
        return self.window.length()

    def history_length(self) -> float:
        """Metres of travel of the marginalised chunks kept one by one (the history)."""
        return self.history.length()

    def window_length(self) -> float:
        """Metres of travel the radii are estimated from (poses + marginalised chunks)."""
        return self.pose_window_length() + self.history_length()

    def status(self) -> CalibratorStatus:
        estimate = self.estimate
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
            solves=self.solves, unconverged_in_a_row=self.unconverged_in_a_row,
            frontend=self.frontend.report(),
        )

    def _trim(self) -> None:
        if self.window.trim(self.params.window_distance) and self.inline_solve:
            self.marginalise_due()
        self.history.trim(self.pose_window_length())

    # --- marginalisation --------------------------------------------------------------------
    # Marginalising a chunk costs a few ms of dense algebra; the node does it on its solver
    # thread, outside its lock (take_chunks_due / marginalise_chunks / add_chunks), not in a
    # callback.
    def marginalise_due(self) -> None:
        self.add_chunks(self.generation,
                        self.marginalise_chunks(self.take_chunks_due(), self.calibration))

    def marginalise_chunks(self, due, calibration) -> list:
        """(Gaussian or None, metres) of each (keyframes, metres) taken from the due list."""
        return [(self.marginalise(keyframes, calibration), metres) for keyframes, metres in due]

    def marginalise(self, leaving, calibration) -> Optional[Gaussian]:
        """What the leaving keyframes knew about the calibration (marginalise.py)."""
        return marginalise(leaving, self.params, calibration, self.nominal)

    def take_chunks_due(self) -> list:
        return self.window.take_chunks_due()

    def add_chunks(self, generation, chunks) -> None:
        """(Gaussian or None, metres) from marginalise, taken at `generation`."""
        if generation != self.generation:
            return  # the window was reset meanwhile: these keyframes are forgotten
        for gaussian, metres in chunks:
            if gaussian is not None:
                self.history.add(gaussian, metres)
        self.history.trim(self.pose_window_length())

    def prior(self) -> Gaussian:
        """What the marginalised data says about the calibration (radii faded by age)."""
        return self.history.prior()

    # --- estimation -----------------------------------------------------------------------
    def solve(self) -> Optional[Estimate]:
        """Solve the window now, on this thread."""
        return self.apply_solve(run_solve(self.prepare_solve(), self.config.solve))

    # A solve in three steps, so that the node can run the expensive middle one on a
    # thread of its own while encoder and scan callbacks go on: prepare_solve and
    # apply_solve touch the calibrator's state (hold the node's lock around them),
    # run_solve touches nothing but its job.
    def prepare_solve(self) -> Optional[SolveJob]:
        self._since_solve = 0
        window = list(self.window)
        if len(window) < self.config.solve.min_keyframes:  # a reset came after the request
            return None
        inputs, problem = window_problem(window, self.params, self.calibration, self.nominal,
                                         prior=self.prior(),
                                         solved_poses=self.window.solved_poses)
        if len(inputs.odo_from) == 0 or len(inputs.laser_from) == 0:
            return None
        weak = gaussian_of_prior(self.nominal, graph_mod.prior_sigmas(self.nominal))
        prior = self.prior() + weak
        chunks = list(self.history.chunks)
        return SolveJob(self.generation, [kf.index for kf in window], float(inputs.stamps[-1]),
                        problem, len(window), self.window_length(), prior,
                        change_testable=self.change_detector.testable(self.history_length()),
                        nominal=self.nominal.copy(), reference=self.history.older + weak,
                        history=[c.gaussian for c in chunks],
                        history_numbers=[c.number for c in chunks],
                        next_chunk_number=self.history.chunks_made,
                        history_metres=[c.metres for c in chunks] + [self.pose_window_length()])

    def apply_solve(self, outcome: Optional[SolveOutcome]) -> Optional[Estimate]:
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
        # data has determined, the others at nominal. A first solve on a few keyframes can
        # put a parameter they do not determine far off, and a matcher seeded with it loses
        # scans (docs/decisions/online.md#scan-matcher-seed).
        self.frontend.calibration = reported.copy()
        self.window.solved_poses = dict(zip(job.keyframe_indices, outcome.poses))
        self.solves += 1
        self.unconverged_in_a_row = 0 if outcome.converged else self.unconverged_in_a_row + 1
        cov = observability.reported_covariance(outcome.variance_factor * outcome.covariance)
        found, before = self.change_detector.test(job, estimate, outcome.covariance,
                                                  observability.as_dict(), self.fading_length())
        if before is not None:
            self.forget_radii(before)
        if found is not None:
            # The published radii may be those of before a change being detected: their σ
            # weighs in the change model as far as the test believes in it.
            cov = self.change_detector.radii_covariance(cov, found, outcome.variance_factor)
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
