"""The graph of a run of merged keyframes, as the window solve and the marginaliser build it."""
from __future__ import annotations

from typing import Optional

import numpy as np

from sclam_ros.core import graph as graph_mod, se2
from sclam_ros.core.marginal import CalibrationPriorFactor, Gaussian


def window_problem(keyframes, params, calibration, nominal, prior: Optional[Gaussian] = None,
                   solved_poses: Optional[dict] = None):
    """(inputs, problem): the graph of `keyframes` linearised around `calibration` (6,);
    `prior` (the marginalised data's Gaussian) added as a factor unless empty; with
    `solved_poses` (keyframe index -> pose), warm-started from them (warm_poses)."""
    keyframes = list(keyframes)
    inputs = graph_mod.GraphInputs.from_keyframes(keyframes)
    extra = []
    if prior is not None and not prior.is_empty():
        extra.append(CalibrationPriorFactor(prior))
    poses = (None if solved_poses is None
             else warm_poses(keyframes, inputs, solved_poses, calibration))
    return inputs, graph_mod.build_problem(
        inputs, params, calibration, poses=poses, nominal=nominal, extra_factors=extra,
        # Not corrected here: the marginalised history's information vector would have
        # to carry the correction, each chunk checked as
        # variance_components.settle_corrections does.
        correct_dilution=False,
    )


def warm_poses(keyframes, inputs, solved_poses: dict, calibration):
    """Poses of the last solve where the window still holds them; the new keyframes
    chained on from there. The window moves by a keyframe or two between solves, so
    LM starts next to its optimum and needs a few steps where chained scan matches need
    several times more (docs/decisions/online.md#warm-start)."""
    known = [n for n, kf in enumerate(keyframes) if kf.index in solved_poses]
    if not known or known != list(range(len(known))):
        return graph_mod.initial_poses(inputs, calibration)
    last = known[-1]
    poses = np.empty((len(keyframes), 3))
    poses[: last + 1] = [solved_poses[kf.index] for kf in keyframes[: last + 1]]
    if last + 1 < len(keyframes):
        # Only the new keyframes are chained, from the last solved one: chaining the
        # whole window costs as much as the rest of preparing a solve.
        tail = graph_mod.initial_poses(graph_mod.GraphInputs.from_keyframes(keyframes[last:]),
                                       calibration)
        poses[last + 1:] = se2.compose(np.broadcast_to(poses[last], tail[1:].shape), tail[1:])
    return poses
