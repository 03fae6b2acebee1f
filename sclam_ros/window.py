"""Online calibration: a sliding window for the wheel radii, accumulated priors for the rest.

Scheme (issue: the online node):
  - Arriving keyframes (one per scan) are merged into `params.keyframe_interval` chunks
    before they enter the window, exactly as the batch calibrator merges them
    (graph.merge_keyframes): the same long edges, so the same small regression-dilution
    bias of the wheel base, and ~5× fewer poses to solve for.
  - The window holds the merged keyframes of the last `window_distance` metres travelled,
    and at most MAX_WINDOW_KEYFRAMES of them, so standing still cannot grow it: the cost
    of a solve is bounded whatever the robot does. The wheel radii are estimated from this
    window only: when a load compresses the tyres, the old data leaves the window and stops
    pulling.
  - The wheel base and the laser pose do not drift; the information the leaving keyframes
    held about them is kept. Leaving keyframes are marginalised in chunks: their edges are
    linearised at the current estimate and everything but (b, l) — their poses and the
    radii they were driven with — is integrated out (a Schur complement of the information
    AND of the gradient), giving a 4×4 Gaussian that is added to the prior on (b, l).
    Information adds up; the cost of the window stays constant.
  - Every `solve_every` merged keyframes the window is re-solved by LM, warm-started from
    the previous solve's poses. Inline by default; the node runs the solves on a thread
    of its own (solver_thread.py) via prepare_solve / run_solve / apply_solve.
"""
from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field
from typing import Optional

import numpy as np

from . import factors, graph as graph_mod, kinematics, se2
from .frontend import Frontend, Keyframe
from .inputs import Rejections
from .params import CALIBRATION_KEYS
from .solver import levenberg_marquardt, marginal_covariance

# Bound on the merged keyframes in the window (0.5 s each by default: 200 s). Reached only
# when the robot crawls or stands still; then the oldest keyframes leave by count.
MAX_WINDOW_KEYFRAMES = 400
# Leaving keyframes are marginalised in chunks: one dense Schur complement per chunk.
MARGINALISE_BATCH = 20
# Fewer keyframes than this in the window: no solve (too little to say anything).
MIN_WINDOW_KEYFRAMES = 6
SLOW_KEYS = ("wheel_base", "laser_x", "laser_y", "laser_yaw")
# Scans closer than this to the last one used are skipped: the window merges scans into
# keyframe_interval edges anyway, and a 40 Hz / 1080-beam laser matched scan by scan needs
# a whole core (measured: bench/node_latency.py). A chain of fewer, longer scan matches
# composes to the same edge with no more noise (the errors of consecutive matches are
# negatively correlated, so they do not average out by matching more often).
MIN_SCAN_INTERVAL = 0.09  # s: at most ~10 Hz of scans are matched
# A window solve stops when an LM step lowers the cost by less than this fraction: with a
# window cost of a few hundred (χ² ≈ dof), 1e-6 is a parameter step of a few % of its σ,
# and the next solve, warm-started, carries on from there anyway.
RELATIVE_TOLERANCE = 1e-6
MAX_ITERATIONS = 10


@dataclass
class Estimate:
    """The current calibration and its marginal uncertainty."""

    stamp: float
    values: dict  # the six CALIBRATION_KEYS
    sigma: dict
    covariance: np.ndarray  # (6, 6)
    keyframes_in_window: int
    window_distance: float  # m covered by the window
    converged: bool = True
    # edge type ("odometry", "laser") -> (3,) RMS of the raw residuals (m, m, rad)
    residual_rms: dict = field(default_factory=dict)

    def vector(self):
        return np.array([self.values[k] for k in CALIBRATION_KEYS])


@dataclass
class _Slow:
    """Accumulated Gaussian on (b, l_x, l_y, l_yaw) from marginalised keyframes."""

    information: np.ndarray = field(default_factory=lambda: np.zeros((4, 4)))
    eta: np.ndarray = field(default_factory=lambda: np.zeros(4))  # information vector

    def add(self, info, eta):
        self.information = self.information + info
        self.eta = self.eta + eta

    def mean(self, fallback):
        if np.linalg.matrix_rank(self.information) < 4:
            return fallback
        return np.linalg.solve(self.information, self.eta)


class KeyframeMerger:
    """graph.merge_keyframes, one keyframe at a time, with running indices.

    Feed per-scan keyframes in order; get back merged keyframes as each chunk of
    `interval` seconds closes (or early, at a broken edge, so gaps stay gaps).
    """

    def __init__(self, interval: float):
        self.interval = float(interval)
        self.reset()

    def reset(self):
        self._last = None  # the last merged keyframe
        self._segment = []
        self._count = 0

    def add(self, kf) -> list:
        if self._last is None:
            self._last = Keyframe(self._count, kf.stamp, kf.wheel_angles)
            self._count += 1
            return [self._last]
        out = []
        complete = (kf.dphi is not None and kf.laser_motion is not None
                    and kf.laser_from == kf.index - 1)
        if self._segment and not complete:
            out.append(self._flush())
        self._segment.append(kf)
        if not complete or kf.stamp - self._last.stamp >= self.interval - 1e-9:
            out.append(self._flush())
        return out

    def _flush(self):
        kf = graph_mod.merged_keyframe(self._segment, self._count)
        self._count += 1
        self._last = kf
        self._segment = []
        return kf


class OnlineCalibrator:
    """Feeds on encoder samples and scans in arrival order; keeps an up-to-date Estimate."""

    def __init__(self, params, rejections: Optional[Rejections] = None, solve_every: int = 2,
                 inline_solve: bool = True):
        self.params = params
        self.inline_solve = inline_solve
        self.rejections = rejections if rejections is not None else Rejections()
        self.solve_every = solve_every
        self.nominal = np.array([getattr(params, k) for k in CALIBRATION_KEYS])
        self.frontend = Frontend(params, self.rejections)
        self.merger = KeyframeMerger(params.keyframe_interval)
        self.reset_calibration()

    # --- user actions -------------------------------------------------------------------
    def reset_window(self) -> None:
        """Forget the keyframes of the window (the radii restart from their current value)."""
        self.window = deque()
        self._distance = deque()  # metres travelled by each keyframe's odometry edge
        self._leaving = []  # keyframes out of the window, waiting to be marginalised
        self._since_solve = 0
        self._last_scan_stamp = None
        self._solved_poses = {}  # keyframe index -> pose of the last solve (warm start)
        self.solve_pending = False  # a solve is due (inline_solve False: the caller runs it)
        self._generation = getattr(self, "_generation", 0) + 1

    def reset_calibration(self) -> None:
        """Back to the nominal values and no accumulated information at all."""
        self.calibration = self.nominal.copy()
        self.frontend.calibration = self.calibration.copy()
        self.slow = _Slow()
        self.estimate: Optional[Estimate] = None
        self.solves = 0
        self.skipped_scans = 0  # scans not matched, see MIN_SCAN_INTERVAL
        self.reset_window()

    def set_window_distance(self, metres: float) -> None:
        self.params.window_distance = float(metres)
        self._trim()

    # --- data -----------------------------------------------------------------------------
    def add_encoder(self, stamp, left_raw, right_raw) -> Optional[Estimate]:
        return self.add_keyframes(self.frontend.add_encoder(stamp, left_raw, right_raw))

    def add_scan(self, scan) -> Optional[Estimate]:
        last = self._last_scan_stamp
        if last is not None and 0.0 <= scan.stamp - last < MIN_SCAN_INTERVAL:
            self.skipped_scans += 1
            return None
        self._last_scan_stamp = scan.stamp
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

    def window_length(self) -> float:
        return float(sum(self._distance))

    def _trim(self) -> None:
        leaving = []
        while len(self.window) > 2 and (
            self.window_length() - self._distance[0] > self.params.window_distance
            or len(self.window) > MAX_WINDOW_KEYFRAMES
        ):
            leaving.append(self.window.popleft())
            self._distance.popleft()
        self._leaving.extend(leaving)
        if len(self._leaving) >= MARGINALISE_BATCH:
            self._marginalise(self._leaving)
            # The last leaving keyframe stays as the start of the next chunk so the edges
            # between chunks are not lost (each edge is counted in exactly one chunk: the
            # edge into the window's first keyframe is not in the window's graph).
            self._leaving = [self._leaving[-1]]

    # --- estimation -----------------------------------------------------------------------
    def _problem(self, keyframes, prior_slow=True, warm=False):
        keyframes = list(keyframes)
        inputs = graph_mod.GraphInputs.from_keyframes(keyframes)
        extra = []
        if prior_slow and np.linalg.matrix_rank(self.slow.information) == 4:
            extra.append(_SlowPrior(self.slow))
        poses = self._warm_poses(keyframes, inputs) if warm else None
        return inputs, graph_mod.build_problem(
            inputs, self.params, self.calibration, poses=poses, nominal=self.nominal,
            extra_factors=extra,
        )

    def _warm_poses(self, keyframes, inputs):
        """Poses of the last solve where the window still holds them; the new keyframes
        chained on from there. The window moves by a keyframe or two between solves, so
        LM starts next to its optimum (measured: ~9 iterations from chained scan matches
        per solve, see bench/node_latency.py, against 2-3 warm)."""
        chained = graph_mod.initial_poses(inputs, self.calibration)
        known = [n for n, kf in enumerate(keyframes) if kf.index in self._solved_poses]
        if not known or known != list(range(len(known))):
            return chained
        last = known[-1]
        poses = chained.copy()
        poses[: last + 1] = [self._solved_poses[kf.index] for kf in keyframes[: last + 1]]
        # The rigid motion taking the chain onto the solved poses at the last known one.
        align = se2.compose(poses[last], se2.inverse(chained[last]))
        poses[last + 1:] = se2.compose(np.broadcast_to(align, chained[last + 1:].shape),
                                       chained[last + 1:])
        return poses

    def _marginalise(self, leaving) -> None:
        """Keep what the leaving keyframes knew about (b, l): a Schur complement.

        H = JᵀJ and g = Jᵀr of the leaving edges alone, linearised at x₀ = (the
        current calibration, poses chained from the scan matches, which are close to their
        optimum), over (poses, k, l); everything but s = (b, l) is integrated out:
            Λ = H_ss − H_sr H_rr⁺ H_rs,   g' = g_s − H_sr H_rr⁺ g_r,
        a Gaussian with information Λ and information vector η = Λ s₀ − g' (its mean is
        the chunk's own Gauss-Newton optimum for s, not the current estimate: without g'
        the prior would only echo the estimate it was taken at). A short chunk alone
        cannot determine its radii, so H_rr may be singular: the pseudo-inverse keeps
        exactly the information that is there and no more.
        """
        inputs, problem = self._problem(leaving, prior_slow=False)
        if len(inputs.odo_from) == 0 or len(inputs.laser_from) == 0:
            return
        problem.factors = [f for f in problem.factors if f.measurement]
        system = problem.linear_system(problem.values)
        jac = system.jacobian.toarray()
        hessian = jac.T @ jac
        gradient = jac.T @ system.residual
        layout = problem.layout
        odo_cols = layout.columns("odometry")
        slow = np.concatenate([odo_cols[2:], layout.columns("laser")])
        rest = np.setdiff1d(np.arange(layout.size), slow)
        h_sr = hessian[np.ix_(slow, rest)]
        h_rr_pinv = np.linalg.pinv(hessian[np.ix_(rest, rest)], hermitian=True)
        info = hessian[np.ix_(slow, slow)] - h_sr @ h_rr_pinv @ h_sr.T
        info = 0.5 * (info + info.T)
        reduced_gradient = gradient[slow] - h_sr @ h_rr_pinv @ gradient[rest]
        self.slow.add(info, info @ self.calibration[2:] - reduced_gradient)

    def solve(self) -> Optional[Estimate]:
        """Solve the window now, on this thread."""
        return self.apply_solve(run_solve(self.prepare_solve()))

    # A solve in three steps, so that the node can run the expensive middle one on a
    # thread of its own while encoder and scan callbacks go on: prepare_solve and
    # apply_solve touch the calibrator's state (hold the node's lock around them),
    # run_solve touches nothing but its job.
    def prepare_solve(self) -> Optional["SolveJob"]:
        self._since_solve = 0
        self.solve_pending = False
        window = list(self.window)
        if len(window) < MIN_WINDOW_KEYFRAMES:  # a reset came after the request
            return None
        inputs, problem = self._problem(window, warm=True)
        if len(inputs.odo_from) == 0 or len(inputs.laser_from) == 0:
            return None
        return SolveJob(self._generation, [kf.index for kf in window], float(inputs.stamps[-1]),
                        problem, len(window), self.window_length())

    def apply_solve(self, outcome: Optional["SolveOutcome"]) -> Optional[Estimate]:
        if outcome is None:
            return None
        job = outcome.job
        if job.generation != self._generation:
            return None  # a reset came while it ran: the result belongs to data now forgotten
        estimate = outcome.calibration
        if not np.all(np.isfinite(estimate)) or not np.all(np.isfinite(outcome.covariance)):
            self.rejections.add("online_solve_non_finite")
            return None
        self.calibration = estimate
        self.frontend.calibration = estimate.copy()
        self._solved_poses = dict(zip(job.keyframe_indices, outcome.poses))
        self.solves += 1
        cov = outcome.covariance
        self.estimate = Estimate(
            stamp=job.stamp,
            values=graph_mod.as_dict(estimate),
            sigma=graph_mod.as_dict(np.sqrt(np.clip(np.diag(cov), 0, None))),
            covariance=cov,
            keyframes_in_window=job.keyframes_in_window,
            window_distance=job.window_distance,
            converged=outcome.converged,
            residual_rms=outcome.residual_rms,
        )
        return self.estimate


@dataclass
class SolveJob:
    """A window problem to solve, and what it needs to be applied afterwards."""

    generation: int  # OnlineCalibrator._generation when it was prepared
    keyframe_indices: list
    stamp: float
    problem: object
    keyframes_in_window: int
    window_distance: float


@dataclass
class SolveOutcome:
    job: SolveJob
    calibration: np.ndarray
    covariance: np.ndarray
    poses: np.ndarray
    converged: bool
    residual_rms: dict


def run_solve(job: Optional[SolveJob]) -> Optional[SolveOutcome]:
    """LM on a prepared window problem and the marginal covariance of the calibration."""
    from .estimator import residual_rms  # estimator imports nothing of the window

    if job is None:
        return None
    problem = job.problem
    result = levenberg_marquardt(problem, max_iterations=MAX_ITERATIONS,
                                 relative_tolerance=RELATIVE_TOLERANCE)
    calibration = graph_mod.calibration_of(result.values)
    if not np.all(np.isfinite(calibration)):
        return SolveOutcome(job, calibration, np.full((6, 6), np.nan), result.values["poses"],
                            False, {})
    cov = marginal_covariance(problem, result.values, ["odometry", "laser"])
    return SolveOutcome(job, calibration, cov, result.values["poses"], result.converged,
                        residual_rms(problem, result.values))


class _SlowPrior(factors.Factor):
    """The accumulated Gaussian on (b, l) as a factor over the odometry and laser blocks."""

    name = "marginal_prior"
    measurement = False

    def __init__(self, slow: _Slow):
        self.mean = slow.mean(None)
        self._sqrt_info = factors.sqrt_information(
            (slow.information + 1e-12 * np.eye(4))[None]
        )

    def __len__(self):
        return 1

    def linearize(self, values):
        current = np.concatenate([values["odometry"][0][2:], values["laser"][0]])
        residual = current - self.mean
        residual[3] = (residual[3] + np.pi) % (2 * np.pi) - np.pi
        j_odo = np.zeros((1, 4, 3))
        j_odo[0, 0, 2] = 1.0
        j_laser = np.zeros((1, 4, 3))
        j_laser[0, 1:, :] = np.eye(3)
        zeros = np.zeros(1, int)
        return factors.Linearization(
            residual[None], self._sqrt_info,
            [factors.JacobianBlock("odometry", zeros, j_odo),
             factors.JacobianBlock("laser", zeros, j_laser)],
        )
