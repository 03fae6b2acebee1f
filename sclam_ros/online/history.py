"""The marginalised data: what the keyframes that left the pose window say about the calibration.

Each marginalised chunk (marginalise.py) is a Gaussian on the calibration. They are a prior
of the window solve under the radii's change model (change.py): as data ages, what it says
about the radii fades (e-folding over `window_distance` metres) while what it says about
(b, l) is kept for good: the wheel base and the laser do not drift, the radii may. The
newest `window_distance` metres of chunks are kept one by one (the history, where the change
test can place a change), the older ones summed (`older`). A change found before a chunk
makes everything before it one segment whose radii are integrated out (forget_radii).
"""
from __future__ import annotations

from collections import deque
from dataclasses import dataclass
from typing import Optional

from sclam_ros.core.marginal import Gaussian
from sclam_ros.online.change import faded_sum


@dataclass
class Chunk:
    """Marginalised keyframes of the last window_distance metres (the history)."""

    gaussian: Gaussian
    metres: float
    number: int  # chunks are numbered in the order they were made


class MarginalisedHistory:
    """The chunks of the newest `params.window_distance` metres, oldest first, and the sum
    of the older ones (radii faded by age); `params` is shared with the calibrator, so a
    runtime change of window_distance applies at once."""

    def __init__(self, params):
        self.params = params
        self.older = Gaussian()  # chunks older than the history, radii faded (change.py)
        self.chunks = deque()  # Chunk, oldest first: the newest window_distance metres
        self.chunks_made = 0

    def fading_length(self) -> float:
        """Metres over which the radii information of old data fades by e (change.py)."""
        return self.params.window_distance

    def length(self) -> float:
        """Metres of travel of the chunks kept one by one."""
        return float(sum(c.metres for c in self.chunks))

    def add(self, gaussian: Gaussian, metres: float) -> None:
        self.chunks.append(Chunk(gaussian, metres, self.chunks_made))
        self.chunks_made += 1

    def trim(self, pose_window_length: float) -> None:
        """The oldest chunks join the older data while, with the pose window's metres,
        the history is longer than window_distance."""
        while self.chunks and pose_window_length + self.length() > self.params.window_distance:
            self.older = self._faded([self.chunks.popleft()], self.older)

    def forget_radii(self, before: Optional[int] = None) -> None:
        """The radii changed before the chunk numbered `before` (default: after all the
        chunks): the data before it is one segment whose radii are integrated out jointly;
        its (b, l) is kept for good, the chunks after it stay a prior on the radii."""
        segment = []
        while self.chunks and (before is None or self.chunks[0].number < before):
            segment.append(self.chunks.popleft())
        self.older = self._faded(segment, self.older).without_radii()

    def prior(self) -> Gaussian:
        """What the marginalised data says about the calibration (radii faded by age)."""
        return self._faded(self.chunks, self.older)

    def _faded(self, chunks, start: Gaussian) -> Gaussian:
        return faded_sum([c.gaussian for c in chunks], [c.metres for c in chunks],
                         self.fading_length(), start)
