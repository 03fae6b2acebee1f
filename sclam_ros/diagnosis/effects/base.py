"""What every model extension shares: per-pose data, hooks into the odometry/laser models.

An effect is a small parameter block (named after the effect, shape (1, dim)) estimated
in the same graph as the poses and the calibration. It bends the model through hooks,
each returning its value and its Jacobians so the factors can chain them:

- ``adjust_dphi(dphi, p, i, j)``  → dφ', ∂dφ'/∂dφ (m,2,2), ∂dφ'/∂p (m,2,d): the wheel
  increments the model should use (clock offset);
- ``adjust_k(k, p, i, j)``        → k_e (m,3), ∂k_e/∂k (m,3,3), ∂k_e/∂p (m,3,d): per-edge
  wheel parameters (radius drift);
- ``motion_term(dphi, k_e, p, i, j)`` → Δm (m,3), ∂Δm/∂dφ (m,3,2), ∂Δm/∂k_e (m,3,3),
  ∂Δm/∂p (m,3,d): motion the wheels do not see, added to K (lateral slip);
- ``adjust_z(z, p, i, j)``        → z', ∂z'/∂p (m,3,d): the scan match corrected
  (scan distortion).

A hook an effect does not override is the identity. ``i``/``j`` are the edges' pose
indices, through which an effect reads its per-pose data (stamps, wheel speeds, ...).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sclam_ros.diagnosis.config import DiagnoseConfig


@dataclass
class EffectData:
    """Per-pose quantities the effects may read (all indexed by graph pose)."""

    stamps: np.ndarray  # (n,) s
    wheel_speeds: np.ndarray  # (n, 2) rad/s, wheel angular speeds at the pose's stamp
    positions: np.ndarray = None  # (n, 2) m, fitted positions (noise regions)
    # (n,) rad/s, the turn rate from the scan matches alone (the laser turns with the
    # body), so effects on the laser side do not depend on the wheel calibration.
    turn_rates: np.ndarray = None
    # The walls the laser saw on the fitted map (diagnosis/wall_map.WallMap; None: no
    # scans kept): where a noise region's boundary may lie.
    walls: object = None
    # s: when the scans' mean beam was taken after their stamps, from what they state of
    # their sweep (half of it; median over the scans; 0: taken at once or not stated);
    # None: not known (EffectData made without keyframes)
    sweep_delay: float = None

    @property
    def reference_time(self) -> float:
        """Mid-run: drift parameters are centred here, so the radii are the run's mean."""
        return 0.5 * (self.stamps[0] + self.stamps[-1])

    @classmethod
    def from_keyframes(cls, raw_keyframes, stamps, positions=None):
        """Wheel speeds at the graph's stamps by central differences of the raw keyframes'
        cumulative wheel angles (one keyframe per scan, so ±1 scan period); turn rates
        and turn rates from the raw keyframes' scan matches."""
        raw_t = np.array([kf.stamp for kf in raw_keyframes], float)
        raw_phi = np.array([kf.wheel_angles for kf in raw_keyframes], float).reshape(-1, 2)
        if len(raw_t) >= 2:
            speeds = np.gradient(raw_phi, raw_t, axis=0)
        else:
            speeds = np.zeros_like(raw_phi)
        stamps = np.asarray(stamps, float)
        omega = np.column_stack([np.interp(stamps, raw_t, speeds[:, c]) for c in range(2)])
        sweep = float(np.median([0.5 * kf.sweep for kf in raw_keyframes])) if raw_keyframes else None
        return cls(stamps, omega, None if positions is None else np.asarray(positions, float),
                   laser_turn_rates(raw_keyframes, stamps), sweep_delay=sweep)


def laser_turn_rates(raw_keyframes, stamps):
    """Turn rate (rad/s) at `stamps`: each scan match's heading change over its interval,
    placed at the interval's middle, interpolated (across failed matches too)."""
    by_index = {kf.index: kf for kf in raw_keyframes}
    mid, rate = [], []
    for kf in raw_keyframes:
        before = by_index.get(kf.laser_from) if kf.laser_motion is not None else None
        if before is not None and kf.stamp > before.stamp:
            mid.append(0.5 * (kf.stamp + before.stamp))
            rate.append(kf.laser_motion[2] / (kf.stamp - before.stamp))
    if not mid:
        return np.zeros(len(stamps))
    return np.interp(stamps, mid, rate)


def largest_signed(p) -> float:
    """The parameter of the largest magnitude, with its sign (the one number reported for
    a per-wheel or per-axis effect)."""
    p = np.asarray(p, float).ravel()
    return float(p[np.argmax(np.abs(p))])


class ModelEffect:
    """Base class: identity hooks. Subclasses set the class attributes and override hooks."""

    name = ""
    dim = 1
    units = ""  # of the parameter(s), for the report
    doc = ""
    # Which edge model the effect bends: "odometry", "laser", both ("odometry+laser") or
    # "noise" (a noise model, estimated from residuals rather than by least squares).
    kind = "odometry"
    # 1σ of the weak zero-mean prior that keeps an unexcited effect well-posed.
    prior_sigma = 1.0
    # Whether part of the effect is found by a search over the data (a region's place):
    # its held-out likelihood ratio must then clear a penalty too, not only its in-sample
    # one (which the search overfits).
    searched = False
    # NLL (nats) by which the place a search chose fits worse than the search's best (a
    # region moved by the walls: FloorNoise); evidence.evaluate adds it back, so that the
    # selection tests the statistic its penalty was set on. 0 for every other effect.
    search_deficit = 0.0
    # The regressors (diagnosis/regressors.py) that describe this effect's footprint in the
    # odometry residuals. When another regressor explains more of the structure than these
    # do, the effect would only stand in for that cause and is not selected (evidence.py).
    # Empty: not checked.
    signature: tuple = ()

    def __init__(self, data: EffectData, config: DiagnoseConfig = DiagnoseConfig()):
        self.data = data
        self.config = config  # what a noise effect's search reads (the others ignore it)

    def bends(self, model: str) -> bool:
        """Whether the effect's hooks act on `model` ("odometry" or "laser") edges."""
        return model in self.kind.split("+")

    def initial(self) -> np.ndarray:
        return self.prior()[0]

    def prior(self) -> tuple:
        """(mean, σ) per parameter of the prior that keeps an unexcited effect well-posed:
        zero-mean and weak (prior_sigma) unless the data state a value."""
        return np.zeros(self.dim), np.full(self.dim, float(self.prior_sigma))

    def adjust_dphi(self, dphi, p, i, j):
        m = len(dphi)
        return dphi, np.broadcast_to(np.eye(2), (m, 2, 2)), np.zeros((m, 2, self.dim))

    def adjust_k(self, k, p, i, j):
        m = len(k)
        return k, np.broadcast_to(np.eye(3), (m, 3, 3)), np.zeros((m, 3, self.dim))

    def motion_term(self, dphi, k, p, i, j):
        m = len(dphi)
        return (np.zeros((m, 3)), np.zeros((m, 3, 2)), np.zeros((m, 3, 3)),
                np.zeros((m, 3, self.dim)))

    def adjust_z(self, z, p, i, j):
        return z, np.zeros((len(z), 3, self.dim))

    def value(self, p) -> float:
        """The one number reported for the effect (its first parameter by default)."""
        return float(np.asarray(p).ravel()[0])

    def value_sigma(self):
        """1σ of a fitted noise effect's value(), or None where it has none (a least-
        squares effect's σ comes from the fit's covariance instead)."""
        return None

    def describe(self) -> dict:
        """Further fields for the report (a noise region's place), none by default."""
        return {}
