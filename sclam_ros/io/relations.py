"""Ground-truth relations of the Freiburg SLAM benchmark and their error metric.

A relations file (Kümmerle et al., "On measuring the accuracy of SLAM algorithms",
Autonomous Robots 27(4), 2009) holds one line per relation, ``t1 t2 x y z roll pitch yaw``:
the robot's true motion from its pose at time t1 to its pose at t2, in the frame at t1.
The metric compares a trajectory's own relative pose over each relation with the true one,
δ_ij ⊖ δ*_ij, and averages the translation (m) and the rotation (rad) of that error.
Spans of 10 s or more show drift, shorter ones local accuracy.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from sclam_ros.core import kinematics, se2

LONG_SPAN = 10.0  # s: the split between drift and local accuracy used in the reports


class RelationsError(ValueError):
    """A relations file that cannot be read; the message names the line."""


def read_relations(path) -> np.ndarray:
    """(n, 5) array of t1, t2, x, y, yaw (s, s, m, m, rad)."""
    try:
        table = np.loadtxt(Path(path), dtype=float, ndmin=2, comments="#")
    except (OSError, ValueError) as exc:
        raise RelationsError(f"{path}: cannot read as benchmark relations: {exc}") from None
    if table.shape[1] != 8:
        raise RelationsError(f"{path}: expected 8 columns t1 t2 x y z roll pitch yaw, "
                             f"got {table.shape[1]}")
    return table[:, [0, 1, 2, 3, 7]]


def interpolate_poses(stamps, poses, at) -> np.ndarray:
    """Poses at the times ``at``, linear in x, y and the unwrapped heading; NaN outside.
    Rows of ``poses`` with a NaN are left out (one would spread through the unwrapping)."""
    stamps, poses, at = np.asarray(stamps, float), np.asarray(poses, float), np.asarray(at, float)
    known = np.isfinite(poses).all(1)
    stamps, poses = stamps[known], poses[known]
    heading = np.unwrap(poses[:, 2])
    out = np.stack([np.interp(at, stamps, poses[:, 0]), np.interp(at, stamps, poses[:, 1]),
                    se2.wrap_angle(np.interp(at, stamps, heading))], -1)
    out[(at < stamps[0]) | (at > stamps[-1])] = np.nan
    return out


@dataclass(frozen=True)
class RelationErrors:
    span: np.ndarray  # (n,) s
    translation: np.ndarray  # (n,) m
    rotation: np.ndarray  # (n,) rad, absolute

    def summary(self, long: bool) -> dict:
        """Mean and standard deviation of the errors over the long (≥ LONG_SPAN) or the short
        spans: translation in m, rotation in degrees, and the number of relations."""
        pick = self.span >= LONG_SPAN if long else self.span < LONG_SPAN
        t, r = self.translation[pick], np.degrees(self.rotation[pick])
        return {"relations": int(pick.sum()),
                "translation_m": float(t.mean()) if t.size else float("nan"),
                "translation_sd_m": float(t.std()) if t.size else float("nan"),
                "rotation_deg": float(r.mean()) if r.size else float("nan"),
                "rotation_sd_deg": float(r.std()) if r.size else float("nan")}


def relation_errors(stamps, poses, relations) -> RelationErrors:
    """The metric's per-relation errors of the trajectory (stamps, poses); relations outside
    the trajectory's time span are left out."""
    relations = np.asarray(relations, float)
    start = interpolate_poses(stamps, poses, relations[:, 0])
    end = interpolate_poses(stamps, poses, relations[:, 1])
    inside = np.isfinite(start).all(1) & np.isfinite(end).all(1)
    relations, start, end = relations[inside], start[inside], end[inside]
    estimated = se2.between(end, start)
    error = se2.between(estimated, relations[:, 2:5])
    return RelationErrors(span=relations[:, 1] - relations[:, 0],
                          translation=np.hypot(error[:, 0], error[:, 1]),
                          rotation=np.abs(error[:, 2]))


def wheel_odometry(wheel_angles, k) -> np.ndarray:
    """Dead-reckoned poses from cumulative wheel angles (n, 2) with k = (r_l, r_r, b)."""
    increments = np.diff(np.asarray(wheel_angles, float), axis=0, prepend=np.nan)
    motion = kinematics.forward(np.nan_to_num(increments), np.asarray(k, float))
    return se2.chain(motion)


def anchored_odometry(anchor_stamps, anchor_poses, stamps, odometry) -> np.ndarray:
    """Poses at ``stamps`` from poses known at ``anchor_stamps`` (an optimised trajectory's
    keyframes) and dead reckoning between them: the latest anchor at or before each stamp,
    composed with the odometry's motion since it. ``odometry``: poses at ``stamps``."""
    anchor_stamps = np.asarray(anchor_stamps, float)
    stamps = np.asarray(stamps, float)
    odometry_at_anchor = interpolate_poses(stamps, odometry, anchor_stamps)
    which = np.clip(np.searchsorted(anchor_stamps, stamps, side="right") - 1, 0, None)
    since = se2.between(np.asarray(odometry, float), odometry_at_anchor[which])
    poses = se2.compose(np.asarray(anchor_poses, float)[which], since)
    poses[stamps < anchor_stamps[0]] = np.nan
    return poses
