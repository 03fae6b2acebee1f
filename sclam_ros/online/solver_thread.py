"""The online window solve on a thread of its own.

A window solve takes milliseconds (a few warm-started LM steps over tens of poses in
numpy). Run in a subscription callback it holds up every message queued behind it: ~/odom
and the next keyframes wait for it (docs/decisions/online.md#solver-thread-and-calibrator-process).
Here the callbacks only append keyframes and ask for a solve; this thread marginalises the keyframes that left the pose
window and solves the window with the shared lock released, taking it only to read and
write the calibrator's state (prepare_solve, apply_solve, take_chunks_due, add_chunks).
Requests that arrive while a solve runs are merged into the next one: the solver always
works on the newest window and never builds a backlog.

The numpy and LAPACK parts of the solve release the GIL, so on a machine with two cores
the callbacks keep running beside it; the pure-Python parts share the interpreter with
them in switch-interval slices.
"""
from __future__ import annotations

import threading
from typing import Callable, Optional

from sclam_ros.online.calibrator import OnlineCalibrator
from sclam_ros.online.estimate import Estimate
from sclam_ros.online.window_solve import run_solve


class SolverThread:
    def __init__(self, calibrator: OnlineCalibrator, lock: threading.Lock,
                 on_estimate: Callable[[Estimate], None],
                 on_error: Callable[[BaseException], None]):
        self.calibrator = calibrator
        self.lock = lock
        self.on_estimate = on_estimate
        self.on_error = on_error
        self.requests = 0
        self._wake = threading.Event()
        self._stopping = False
        self._thread = threading.Thread(target=self._run, name="sclam_window_solver", daemon=True)
        self._thread.start()

    def request(self) -> None:
        """Ask for a solve of the newest window (call with or without the lock held)."""
        self.requests += 1
        self._wake.set()

    def stop(self, timeout: float = 5.0) -> None:
        self._stopping = True
        self._wake.set()
        self._thread.join(timeout)

    def _run(self) -> None:
        while True:
            self._wake.wait()
            self._wake.clear()
            if self._stopping:
                return
            try:
                estimate = self._solve_once()
                if estimate is not None:
                    self.on_estimate(estimate)
                # After the solve, not before: the estimate someone waits for comes first.
                # The keyframes that left the pose window then join the prior, and a solve
                # follows at once so that no estimate lacks them for long (at the end of a
                # bag, the last estimate would otherwise be short of the last chunk).
                if self._marginalise_due():
                    self._wake.set()
            except Exception as exc:  # noqa: BLE001 - one bad solve must not end the thread
                self.on_error(exc)

    def _solve_once(self) -> Optional[Estimate]:
        with self.lock:
            job = self.calibrator.prepare_solve()
        if job is None:
            return None
        outcome = run_solve(job, self.calibrator.config.solve)
        with self.lock:
            return self.calibrator.apply_solve(outcome)

    def _marginalise_due(self) -> bool:
        """Marginalise the chunks that are due; True if there were any."""
        calibrator = self.calibrator
        with self.lock:
            generation, calibration = calibrator.generation, calibrator.calibration.copy()
            due = calibrator.take_chunks_due()
        if not due:
            return False
        # Dense algebra on keyframes no one else touches any more: outside the lock.
        chunks = calibrator.marginalise_chunks(due, calibration)
        with self.lock:
            calibrator.add_chunks(generation, chunks)
        return True
