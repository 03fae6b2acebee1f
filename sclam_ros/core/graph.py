"""Build the calibration graph of a run of keyframes: variables, factors, gauge, priors.

Shared by the batch calibrator and the online window, so both estimate exactly the same
model.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from sclam_ros.core import dilution, factors, kinematics, se2
from sclam_ros.core.config import GraphConfig, LinearConfig
from sclam_ros.core.keyframe import Keyframe
from sclam_ros.core.params import CALIBRATION_KEYS
from sclam_ros.core.problem import CauchyKernel, Problem, Values

def prior_sigmas(calibration, config: GraphConfig = GraphConfig()) -> np.ndarray:
    """σ of the weak priors on the calibration at its nominal value. They carry no
    information a real run would notice (σ far beyond any plausible mounting error), but
    they keep the system well-posed when the motion cannot excite a parameter (driving
    straight only: no base, no laser offset), and they are the unit the data's information
    is measured in: a direction with too little information beside them is undetermined,
    locked at nominal and its parameters flagged "not observable" (core/observability.py)."""
    calibration = np.asarray(calibration, float)
    return np.concatenate(
        [
            config.prior_sigma_relative_odometry * np.abs(calibration[:3]),
            [config.prior_sigma_laser_xy, config.prior_sigma_laser_xy,
             config.prior_sigma_laser_yaw],
        ]
    )


def encoder_variance_floor(params) -> float:
    """Per-wheel variance of an angle increment from tick quantisation alone (rad²).

    An increment is the difference of two readings each uniformly off by up to one tick:
    variance 2 · (tick²/12). Radian encoders get a 1e-4 rad floor.
    """
    tick = 2 * np.pi / params.ticks_per_revolution if params.ticks_per_revolution > 0 else 1e-4
    return tick**2 / 6.0


@dataclass
class GraphInputs:
    """Keyframes flattened into edge arrays."""

    stamps: np.ndarray  # (n,)
    odo_from: np.ndarray  # (m_o,)
    odo_dphi: np.ndarray  # (m_o, 2)
    laser_from: np.ndarray  # (m_l,)
    laser_to: np.ndarray
    laser_z: np.ndarray  # (m_l, 3)
    laser_info: np.ndarray  # (m_l, 3, 3)
    odo_parts: Optional[np.ndarray] = None  # (m_o, n, 2) per-scan increments, zero-padded
    # (m_o, 2) rad²: variance of each increment from interpolating the encoders at its two
    # ends (Keyframe.angle_variance); None: the increments were sampled, not interpolated
    odo_variance: Optional[np.ndarray] = None
    # (m_o,) rad⁴: each edge's sideways path variance between encoder samples
    # (Keyframe.path_variance); None: none known
    odo_path_variance: Optional[np.ndarray] = None

    @classmethod
    def from_keyframes(cls, keyframes, first_index=None):
        first = keyframes[0].index if first_index is None else first_index
        n = len(keyframes)
        odo = [(kf.index - first - 1, kf.dphi) for kf in keyframes
               if kf.dphi is not None and kf.index - first - 1 >= 0]
        las = [(kf.laser_from - first, kf.index - first, kf.laser_motion, kf.laser_information)
               for kf in keyframes
               if kf.laser_motion is not None and kf.laser_from - first >= 0]
        parts = None
        if any(getattr(kf, "dphi_parts", None) is not None for kf in keyframes):
            chunks = [kf.dphi_parts if getattr(kf, "dphi_parts", None) is not None else kf.dphi[None]
                      for kf in keyframes if kf.dphi is not None and kf.index - first - 1 >= 0]
            parts = np.zeros((len(chunks), max((len(c) for c in chunks), default=1), 2))
            for row, chunk in enumerate(chunks):
                parts[row, : len(chunk)] = chunk
        return cls(
            odo_parts=parts,
            odo_variance=_increment_variance(keyframes, first),
            odo_path_variance=_path_variance(keyframes, first),
            stamps=np.array([kf.stamp for kf in keyframes]),
            odo_from=np.array([o[0] for o in odo], int),
            odo_dphi=np.array([o[1] for o in odo], float).reshape(-1, 2),
            laser_from=np.array([e[0] for e in las], int),
            laser_to=np.array([e[1] for e in las], int),
            laser_z=np.array([e[2] for e in las], float).reshape(-1, 3),
            laser_info=np.array([e[3] for e in las], float).reshape(-1, 3, 3),
        )

    @property
    def size(self) -> int:
        return len(self.stamps)


def _increment_variance(keyframes, first):
    """(m_o, 2) interpolation variance of each odometry edge's increments, in the order of
    GraphInputs.odo_dphi, or None when no keyframe's angles were interpolated. An increment
    is the difference of the angles at its two ends: their variances add (the ends of the
    parts of a merged edge cancel, so only its own two ends count)."""
    if all(getattr(kf, "angle_variance", None) is None for kf in keyframes):
        return None
    of_index = {kf.index: kf.angle_variance for kf in keyframes}

    def at(index):
        v = of_index.get(index)
        return np.zeros(2) if v is None else np.asarray(v, float)

    rows = [at(kf.index - 1) + at(kf.index) for kf in keyframes
            if kf.dphi is not None and kf.index - first - 1 >= 0]
    return np.array(rows, float).reshape(-1, 2)


def _path_variance(keyframes, first):
    """(m_o,) sideways path variance of each odometry edge (Keyframe.path_variance), in the
    order of GraphInputs.odo_dphi; None when no keyframe has one."""
    if all(getattr(kf, "path_variance", None) is None for kf in keyframes):
        return None
    return np.array([kf.path_variance or 0.0 for kf in keyframes
                     if kf.dphi is not None and kf.index - first - 1 >= 0], float)


def odometry_covariance(inputs: GraphInputs, params, k,
                        config: GraphConfig = GraphConfig()) -> np.ndarray:
    """(m_o, 3, 3) covariance of the odometry edges' motions K(u, k): the wheels' noise
    model (params.wheel_noise, lateral_noise, the encoder's quantisation) plus the
    interpolation variance of the increments (GraphInputs.odo_variance) and the path
    between encoder samples (GraphInputs.odo_path_variance, scaled by
    config.composed_path_sigma_scale where an edge is composed of several arcs: those
    follow most of the path's accelerations; encoder_stream.EncoderStream._path_variance gives the
    constant-speed arc's)."""
    path = inputs.odo_path_variance
    if path is not None and inputs.odo_parts is not None:
        arcs = np.count_nonzero(np.any(np.asarray(inputs.odo_parts) != 0.0, axis=-1), axis=-1)
        path = np.where(arcs > 1, config.composed_path_sigma_scale**2, 1.0) * path
    return kinematics.motion_covariance(inputs.odo_dphi, k, params.wheel_noise,
                                        encoder_variance_floor(params), params.lateral_noise,
                                        inputs.odo_variance, path, parts=inputs.odo_parts)


def _node(kf, index):
    """A keyframe at kf's stamp and wheel angles (with what is known of them), numbered
    `index`, without edges."""
    return Keyframe(index, kf.stamp, kf.wheel_angles, angle_variance=kf.angle_variance,
                    since_sample=kf.since_sample)


def merged_keyframe(segment, index, config: GraphConfig = GraphConfig()):
    """One keyframe standing for a run of consecutive ones (see merge_keyframes): wheel
    increments kept per part (the odometry factor composes their arcs) and summed, chained
    scan matches composed with their covariances added. The edge starts at keyframe
    ``index − 1``."""
    kf = _node(segment[-1], index)
    if all(s.dphi is not None for s in segment):
        kf.dphi_parts = np.concatenate([s.dphi[None] if s.dphi_parts is None else s.dphi_parts
                                        for s in segment])
        kf.dphi = np.sum([s.dphi for s in segment], axis=0)
        if any(s.path_variance is not None for s in segment):
            kf.path_variance = float(sum(s.path_variance or 0.0 for s in segment))
    if all(_chained(s) for s in segment):
        z = np.zeros(3)
        for s in segment:
            z = se2.compose(z, s.laser_motion)
        parts = [np.linalg.inv(s.laser_information) for s in segment]
        kf.laser_from, kf.laser_motion = index - 1, z
        kf.laser_information = np.linalg.inv(chained_scan_match_covariance(parts, config))
    return kf


def chained_scan_match_covariance(parts, config: GraphConfig = GraphConfig()) -> np.ndarray:
    """Covariance of a chain of consecutive scan matches: Σ Cᵢ + ρ Σ (Cᵢ + Cᵢ₊₁), with ρ
    config.scan_match_lag1_correlation.

    Summing the parts as if independent overstates it: five 0.1 s matches composed into
    one 0.5 s edge have 1.8 C, not 5 C, at ρ = −0.4 (the cross-covariance of neighbours
    taken as ρ times their mean covariance; the rotation between their frames over one
    edge is neglected); an overstated covariance makes the online window's radii σ larger
    than their scatter and its change test too weak (docs/decisions/graph.md).
    """
    rho = config.scan_match_lag1_correlation
    total = np.sum(parts, axis=0)
    for before, after in zip(parts[:-1], parts[1:]):
        total = total + rho * (before + after)
    return total


def merge_keyframes(keyframes, interval: float, config: GraphConfig = GraphConfig()) -> list:
    """Fewer, longer edges: consecutive keyframes merged into one per `interval` seconds.

    Wheel increments add exactly and chained scan matches compose, so no measurement is
    lost. Why: the wheel base is learned from rotation against wheel angles measured with
    noise, and least squares with a noisy regressor is biased (regression dilution) by
    ≈ Σ noise² / Σ signal² over the edges. Over an edge of length T the rotation signal
    grows as T² and the wheel noise as T, so the bias falls as 1/T
    (docs/decisions/graph.md#merged-edges). The merged scan-match covariance
    is the sum of the parts (their shared-scan errors cancel partly, which the sandwich σ
    accounts for). A merged keyframe ends early where an edge is missing, so gaps stay gaps.

    Edges end just after encoder samples (Keyframe.since_sample): once `interval` has
    passed, at the first keyframe after a sample. With encoders at 20 Hz and more that is
    every keyframe; with 1-2 Hz odometry it puts the ends of the edges where the wheel
    angles are nearly exact, and the straight line between samples, wrong wherever the
    robot turned in part of an encoder interval, cancels inside the edge. For the same
    reason a missing scan match between samples does not end the edge there: the edge
    goes on to the next sample without a laser part (the few matches of that stretch are
    not used; at 1 Hz a few per cent, where failed matches cluster in fast turns;
    docs/decisions/slow_odometry.md#edge-ends).
    """
    if interval <= 0 or len(keyframes) < 2:
        return list(keyframes)
    merger = KeyframeMerger(interval, config)
    merged = [m for kf in keyframes for m in merger.add(kf)]
    return merged + merger.flush()


class KeyframeMerger:
    """merge_keyframes one keyframe at a time, with running indices (the online window
    merges as keyframes arrive, the batch over a list: the same edges).

    Feed per-scan keyframes in order; get back merged keyframes as each chunk closes, and
    the open one from flush() at the end of the data.
    """

    def __init__(self, interval: float, config: GraphConfig = GraphConfig()):
        self.interval = float(interval)
        self.config = config
        self.reset()

    def reset(self):
        self._last = None  # the last merged keyframe
        self._previous_stamp = None  # of the last keyframe fed
        self._previous_after_sample = True  # ... and whether it came just after a sample
        self._segment = []  # keyframes since the last merged one
        self._count = 0

    def add(self, kf) -> list:
        previous = self._previous_stamp
        self._previous_stamp = kf.stamp
        if self._last is None:
            self._last = _node(kf, self._count)
            self._count += 1
            return [self._last]
        out = []
        after_sample = _after_sample(kf, previous)
        # Close the run before a broken edge if it can end there: always where the wheels
        # broke, and where the scan match is missing if the run's last keyframe is just
        # after a sample (otherwise the run goes on to the next sample without its laser).
        if self._segment and (kf.dphi is None
                              or (not _chained(kf) and self._previous_after_sample)):
            out.append(self._close())
        self._previous_after_sample = after_sample
        self._segment.append(kf)
        laser_broken = not all(_chained(s) for s in self._segment)
        if kf.dphi is None or (after_sample and (
                laser_broken or kf.stamp - self._last.stamp >= self.interval - 1e-9)):
            out.append(self._close())
        return out

    def flush(self) -> list:
        """The open chunk, merged (end of data), or nothing."""
        return [self._close()] if self._segment else []

    def _close(self):
        kf = merged_keyframe(self._segment, self._count, self.config)
        self._count += 1
        self._last = kf
        self._segment = []
        return kf


def _chained(kf) -> bool:
    """The keyframe's scan match is from the keyframe before it."""
    return kf.laser_motion is not None and kf.laser_from == kf.index - 1


def _after_sample(kf, previous_stamp) -> bool:
    """An encoder sample lies after the previous keyframe, up to this one's stamp."""
    return kf.since_sample is None or kf.stamp - kf.since_sample > previous_stamp


def initial_poses(inputs: GraphInputs, calibration,
                  config: GraphConfig = GraphConfig()) -> np.ndarray:
    """Initial poses: chained scan matches where they exist, wheel odometry elsewhere.

    Scan matches do not depend on the wheel calibration, so a chain of them starts the
    poses close to the optimum, where the problem is nearly linear; dead reckoning with
    a wrong nominal wheel base accumulates heading error along the whole run, and the
    first Gauss-Newton step from there overshoots (measured: cost ×45 on a 2000-pose
    chain) and Levenberg-Marquardt then crawls.

    A scan match that disagrees grossly with the wheels (an ICP failure the robust kernel
    will later discount; config.init_gate_*) is not trusted for the start; odometry is used
    there instead.
    """
    calibration = np.asarray(calibration, float)
    k, mount = calibration[:3], calibration[3:]
    motion = np.zeros((inputs.size, 3))
    known = np.zeros(inputs.size, bool)
    motion[inputs.odo_from + 1] = (kinematics.forward(inputs.odo_dphi, k) if inputs.odo_parts is None
                                   else kinematics.forward_composed(inputs.odo_parts, k)[0])
    known[inputs.odo_from + 1] = True
    chained = inputs.laser_from == inputs.laser_to - 1
    to = inputs.laser_to[chained]
    # The base's motion from the laser's: l ∘ z ∘ l⁻¹.
    from_laser = se2.compose(se2.compose(mount, inputs.laser_z[chained]), se2.inverse(mount))
    disagreement = se2.between(from_laser, motion[to])
    step = np.linalg.norm(motion[to, :2], axis=1)
    plausible = ~known[to] | (
        (np.linalg.norm(disagreement[:, :2], axis=1)
         < config.init_gate_m + config.init_gate_relative * step)
        & (np.abs(disagreement[:, 2])
           < config.init_gate_rad + config.init_gate_relative * np.abs(motion[to, 2]))
    )
    motion[to[plausible]] = from_laser[plausible]
    known[to] = True
    return se2.chain(np.where(known[:, None], motion, 0.0))


def gauge_anchors(inputs: GraphInputs) -> np.ndarray:
    """First pose of every connected piece of the graph: those are held fixed.

    Relative edges fix nothing absolute, so each piece (separated by a stretch with no
    encoder and no scan match) needs one anchored pose.
    """
    linked = np.zeros(max(inputs.size - 1, 0), bool)  # pose i joined to pose i + 1
    linked[inputs.odo_from] = True
    linked[inputs.laser_from[inputs.laser_to == inputs.laser_from + 1]] = True
    if linked.all():  # one unbroken chain, the usual case: no graph search needed
        return np.zeros(1, int)
    src = np.concatenate([inputs.odo_from, inputs.laser_from])
    dst = np.concatenate([inputs.odo_from + 1, inputs.laser_to])
    adjacency = coo_matrix((np.ones(len(src)), (src, dst)), shape=(inputs.size, inputs.size))
    _, labels = connected_components(adjacency, directed=False)
    _, first = np.unique(labels, return_index=True)
    return np.sort(first)


def build_problem(inputs: GraphInputs, params, calibration, poses=None,
                  nominal=None, extra_factors=(), correct_dilution=True,
                  config: GraphConfig = GraphConfig(),
                  linear: LinearConfig = LinearConfig()) -> Problem:
    """The SCLAM least-squares problem over poses, k = (r_l, r_r, b) and l = (x, y, yaw);
    with correct_dilution, the wheel base's regression dilution taken out of the cost
    (dilution.py). `linear`: how the problem's normal equations are factorised."""
    calibration = np.asarray(calibration, float)
    nominal = calibration if nominal is None else np.asarray(nominal, float)
    if poses is None:
        poses = initial_poses(inputs, calibration, config)
    values = Values(
        {"poses": poses, "odometry": [calibration[:3]], "laser": [calibration[3:]]},
        angular={"poses": [False, False, True], "laser": [False, False, True]},
        # Radii and wheel base are physical lengths: the solver never steps through zero.
        lower={"odometry": config.min_odometry_fraction * calibration[:3]},
    )
    odometry_cov = odometry_covariance(inputs, params, nominal[:3], config)
    corrections = [dilution.wheel_noise_correction(
        inputs, params, calibration[:3], odometry_cov, encoder_variance_floor(params),
        config.max_dilution_shift)
    ] if correct_dilution and len(inputs.odo_from) else []
    sigma = prior_sigmas(nominal, config)
    factor_list = [
        factors.OdometryFactor(inputs.odo_from, inputs.odo_from + 1, inputs.odo_dphi,
                               np.linalg.inv(odometry_cov), parts=inputs.odo_parts),
        factors.LaserFactor(inputs.laser_from, inputs.laser_to, inputs.laser_z, inputs.laser_info),
        factors.PriorFactor("odometry", [0], [nominal[:3]], np.diag(sigma[:3] ** -2.0),
                            angular=(False, False, False), name="calibration_prior"),
        factors.PriorFactor("laser", [0], [nominal[3:]], np.diag(sigma[3:] ** -2.0),
                            name="calibration_prior"),
        *extra_factors,
    ]
    return Problem(values, factor_list, fixed={"poses": gauge_anchors(inputs)},
                   kernels={"laser": laser_kernel(config)}, corrections=corrections,
                   linear=linear)


def laser_kernel(config: GraphConfig = GraphConfig()) -> CauchyKernel:
    """The scan matches' robust kernel: an ICP that slid along a corridor is a gross outlier
    and must not drag the calibration; Cauchy's influence decays far outside. The diagnosis
    scores edges with the same kernel."""
    return CauchyKernel(config.laser_kernel_scale)


def calibration_of(values: Values) -> np.ndarray:
    return np.concatenate([values["odometry"][0], values["laser"][0]])


def as_dict(vector) -> dict:
    return {k: float(v) for k, v in zip(CALIBRATION_KEYS, vector)}
