"""A keyframe: one pose node of the graph and the measurements that tie it to earlier ones.

Made by the front end (frontend/pipeline.py), consumed by the graph builder and the online
window; a plain data type so that the core never imports the front end.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import numpy as np


@dataclass
class Keyframe:
    """One node of the graph and the measurements that tie it to earlier nodes."""

    index: int  # 0, 1, 2, ... in stamp order
    stamp: float  # s
    wheel_angles: np.ndarray  # (2,) rad, cumulative, at the scan stamp
    # (2,) rad²: variance of wheel_angles from interpolating the encoders at the stamp
    # (frontend/encoder_stream.py; None: the angles were sampled there)
    angle_variance: Optional[np.ndarray] = None
    # s from the last encoder sample at or before the stamp (0: sampled there; None: not
    # known, taken as sampled): graph.merge_keyframes ends edges just after samples
    since_sample: Optional[float] = None
    # rad⁴: sideways path variance of the odometry edge since keyframe index − 1, between
    # encoder samples (frontend/encoder_stream.py EncoderStream._path_variance; None: none known)
    path_variance: Optional[float] = None
    dphi: Optional[np.ndarray] = None  # (2,) increments since keyframe index − 1
    # (n, 2) the same split where the odometry composes one arc per part: at encoder
    # samples (frontend: SyncConfig.min_arc) and at the scans of a merged keyframe
    dphi_parts: Optional[np.ndarray] = None
    laser_from: Optional[int] = None  # keyframe index the scan match is relative to
    laser_motion: Optional[np.ndarray] = None  # z: laser_j ⊖ laser_from, in that frame
    laser_information: Optional[np.ndarray] = None  # (3, 3)
    # s from its scan's first beam to its last, as the scan states it (time_increment ·
    # (beams − 1)); 0: taken at once, or the driver does not say
    sweep: float = 0.0
    # (n, 2) m, the scan's points in the laser frame, float32: kept only on request
    # (Frontend keep_scan_points), for the diagnosis's map of walls
    scan_points: Optional[np.ndarray] = None
