"""The pose window: the newest merged keyframes, held as poses in the graph that is solved.

Only the newest POSE_WINDOW_DISTANCE metres travelled stay (and at most MAX_WINDOW_KEYFRAMES,
so standing still cannot grow it): the cost of a solve is bounded whatever the robot does.
The keyframes that leave are handed out in chunks of MARGINALISE_BATCH, to be marginalised
(marginalise.py) into the history (history.py).
"""
from __future__ import annotations

from collections import deque

from sclam_ros.core import kinematics

# Bound on the merged keyframes in the window (0.5 s each by default: 200 s). Reached only
# when the robot crawls or stands still; then the oldest keyframes leave by count.
MAX_WINDOW_KEYFRAMES = 400
# Leaving keyframes are marginalised in chunks: one dense Schur complement per chunk. A
# chunk boundary is where the change test can place a change (5 s at 0.5 s keyframes).
MARGINALISE_BATCH = 10
# Metres kept as poses in the solved graph (the rest is marginalised). A change inside it
# can only be placed at its start, so it bounds how soon a change is located: 5 m
# (≈ 11 s at 0.45 m/s) detected a 1 % step on both radii after 17 s where 10 m took 62 s
# (bench/load_change.py, seed 1).
POSE_WINDOW_DISTANCE = 5.0


class PoseWindow:
    """The keyframes held as poses, oldest first, with the metres each one's odometry edge
    travelled, and the chunks of those that left, due to be marginalised."""

    def __init__(self):
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
        """The oldest keyframes leave while the window is longer than POSE_WINDOW_DISTANCE
        (or `window_distance`, if shorter) or holds more than MAX_WINDOW_KEYFRAMES; True
        when the leaving keyframes made a chunk due."""
        limit = min(window_distance, POSE_WINDOW_DISTANCE)
        while len(self.keyframes) > 2 and (
            self.length() - self.distances[0] > limit
            or len(self.keyframes) > MAX_WINDOW_KEYFRAMES
        ):
            self._leaving.append(self.keyframes.popleft())
            self._leaving_metres += self.distances.popleft()
        if len(self._leaving) < MARGINALISE_BATCH:
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
