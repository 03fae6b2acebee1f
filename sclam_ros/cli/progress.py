"""A progress bar on stderr for long jobs; silent when stderr is not a terminal or CI."""
from __future__ import annotations

import os
import sys
import time


class ProgressBar:
    def __init__(self, label: str, enabled: bool = True, stream=None):
        self.label = label
        self.stream = stream if stream is not None else sys.stderr
        self.enabled = enabled
        self.interactive = enabled and self.stream.isatty() and not os.environ.get("CI")
        self.start = time.monotonic()
        self._last_line = 0.0

    def __call__(self, done: int, total: int) -> None:
        if not self.enabled:
            return
        now = time.monotonic()
        fraction = done / total if total else 1.0
        elapsed = now - self.start
        eta = elapsed / fraction - elapsed if fraction > 0 else float("nan")
        if self.interactive:
            filled = int(30 * fraction)
            self.stream.write(
                f"\r{self.label} [{'#' * filled}{'.' * (30 - filled)}] {100 * fraction:5.1f}% "
                f"{elapsed:5.1f} s, ~{eta:4.0f} s left"
            )
            if done >= total:
                self.stream.write("\n")
            self.stream.flush()
        elif now - self._last_line > 5.0 or done >= total:
            # Non-interactive logs get a line every few seconds, not a flood.
            self._last_line = now
            self.stream.write(f"{self.label}: {100 * fraction:.0f}% ({elapsed:.1f} s)\n")
            self.stream.flush()
