"""The pose window: the newest merged keyframes, held as poses in the graph that is solved.

Only the newest `config.distance` metres travelled stay (and at most `config.max_keyframes`,
so standing still cannot grow it): the cost of a solve is bounded whatever the robot does.
The keyframes that leave are handed out in chunks of `config.marginalise_batch`, to be
marginalised (marginalise.py) into the history (history.py).
"""
from __future__ import annotations

from collections import deque

from sclam_ros.core import kinematics
from sclam_ros.online.config import PoseWindowConfig


class PoseWindow:
    """The keyframes held as poses, oldest first, with the metres each one's odometry edge
    travelled, and the chunks of those that left, due to be marginalised."""

    def __init__(self, config: PoseWindowConfig):
        self.config = config
        self.keyframes = deque()
        self.distances = deque()  # metres travelled by each keyframe's odometry edge
        self.solved_poses = {}  # keyframe index -> pose of the last solve (warm start)
        self._leaving = []  # keyframes out of the window, not yet a full chunk
        self._leaving_metres = 0.0
        self._chunks_due = []  # (keyframes, metres) waiting to be marginalised

    def __len__(self) -> int:
        return len(self.keyframes)

    def __iter__(self):
        return iter(self.keyframes)

    def append(self, kf, calibration) -> None:
        """A new keyframe; its travel measured with `calibration` (6,)."""
        self.keyframes.append(kf)
        travelled = 0.0
        if kf.dphi is not None:
            s, _ = kinematics.arc_length_and_rotation(kf.dphi, calibration[:3])
            travelled = abs(float(s))
        self.distances.append(travelled)

    def length(self) -> float:
        """Metres travelled over the window."""
        return float(sum(self.distances))

    def trim(self, window_distance: float) -> bool:
        """The oldest keyframes leave while the window is longer than `config.distance`
        (or `window_distance`, if shorter) or holds more than `config.max_keyframes`; True
        when the leaving keyframes made a chunk due."""
        limit = min(window_distance, self.config.distance)
        while len(self.keyframes) > 2 and (
            self.length() - self.distances[0] > limit
            or len(self.keyframes) > self.config.max_keyframes
        ):
            self._leaving.append(self.keyframes.popleft())
            self._leaving_metres += self.distances.popleft()
        if len(self._leaving) < self.config.marginalise_batch:
            return False
        self._chunks_due.append((self._leaving, self._leaving_metres))
        # The last leaving keyframe stays as the start of the next chunk so the edges
        # between chunks are not lost (each edge is counted in exactly one chunk: the
        # edge into the window's first keyframe is not in the window's graph).
        self._leaving = [self._leaving[-1]]
        self._leaving_metres = 0.0
        return True

    def take_chunks_due(self) -> list:
        """The (keyframes, metres) chunks due to be marginalised; the list is emptied."""
        due, self._chunks_due = self._chunks_due, []
        return due
