"""The online calibrator in a process of its own, so that the node's odometry never waits.

The node's JointState → ~/odom path must answer at the encoder rate within a millisecond or
two. Scan registration (KISS-ICP, point-to-line refinement) and the window solve take
milliseconds each and are mostly Python: on a thread of the node's process they hold the
interpreter lock while an encoder callback waits, and ~/odom comes late
(docs/decisions/online.md#solver-thread-and-calibrator-process). Here they run in a child
process:

    node process                                child process (this module's _serve)
    JointState → integrate → ~/odom ─┐
                                     ├─ inbox ──> OnlineCalibrator (+ SolverThread) ─┐
    LaserScan → Scan ────────────────┘    (arrival order kept: one FIFO)             │
    publish ~/laser_pose, ~/wheel_parameters <── outbox: estimates, status ──────────┘

The child sees exactly the calls the node's callbacks made, in the same order, so it
estimates what an in-process calibrator would. The node reads the newest CalibratorStatus
(calibration for ~/odom, counts for /diagnostics) from a reference the reader thread
replaces: a read never waits for the child.

Commands (reset window, reset calibration, runtime parameters) go through the same inbox, so
they apply between the same two messages as they would in process. Each command starts a new
*epoch*; what the child sent before it had seen the command is ignored, so a status read right
after a reset never shows the old estimate. A child that dies is reported (``alive`` False,
its reason in ``failure``); the node keeps publishing odometry with the last calibration.
"""
from __future__ import annotations

import logging
import multiprocessing
import os
import queue
import threading
import time
from collections import Counter
from dataclasses import replace
from typing import Callable, Optional

from sclam_ros.core.inputs import Rejections
from sclam_ros.online.config import OnlineConfig

log = logging.getLogger("sclam")

STATUS_PERIOD_S = 0.5  # the child sends its status at least this often while data flows
STOP_TIMEOUT_S = 5.0


def _serve(params, config, inbox, outbox) -> None:
    """The child process: run the calibrator on what arrives, report what it learns."""
    from sclam_ros.online.solver_thread import SolverThread
    from sclam_ros.online.calibrator import OnlineCalibrator

    # A daemon child is ended by its parent's normal exit only; a node that is killed would
    # leave it running, waiting for input forever.
    parent = multiprocessing.parent_process()
    if config.process.niceness:
        os.nice(config.process.niceness)
    rejections = Rejections()
    calibrator = OnlineCalibrator(params, rejections, inline_solve=False, config=config)
    lock = threading.Lock()
    epoch = 0
    handled = 0  # messages and commands taken from the inbox
    reported = -1  # `handled` at the last report

    def report(kind, payload=None):
        nonlocal reported
        with lock:
            status = calibrator.status()
            counts = dict(rejections.counts)
            reported = handled
        outbox.put((kind, epoch, status, counts, handled, payload))

    solver = SolverThread(calibrator, lock, lambda estimate: report("estimate", estimate),
                          lambda exc: outbox.put(("error", epoch, None, None, handled,
                                                  f"window solve: {type(exc).__name__}: {exc}")))
    last_status = time.monotonic()
    try:
        while True:
            try:
                item = inbox.get(timeout=STATUS_PERIOD_S)
            except queue.Empty:  # idle: make sure the node has seen the last of it
                if not parent.is_alive():
                    return  # the node died without a "stop" (killed): end with it
                if reported != handled:
                    report("status")
                continue
            kind = item[0]
            if kind == "stop":
                return
            with lock:
                if kind == "encoder":
                    calibrator.add_encoder(*item[1:])
                elif kind == "scan":
                    calibrator.add_scan(item[1])
                else:  # a command: (name, epoch, *arguments)
                    epoch = item[1]
                    _command(calibrator, kind, *item[2:])
                handled += 1
                due = calibrator.solve_pending
                calibrator.solve_pending = False
            if due:
                solver.request()
            if kind not in ("encoder", "scan") or time.monotonic() - last_status > STATUS_PERIOD_S:
                last_status = time.monotonic()
                report("status")
    finally:
        solver.stop()


def _command(calibrator, name, *arguments) -> None:
    if name == "reset_window":
        calibrator.reset_window()
    elif name == "reset_calibration":
        calibrator.reset_calibration()
    elif name == "set_window_distance":
        calibrator.set_window_distance(*arguments)
    elif name == "set_param":
        key, value = arguments
        setattr(calibrator.params, key, value)  # the front end shares this object
    elif name != "status":
        raise ValueError(f"unknown command {name!r}")


class CalibratorProcess:
    """The node's handle on the calibrator child process.

    ``add_encoder`` / ``add_scan`` only enqueue (microseconds). ``status`` is the newest
    CalibratorStatus, ``estimate`` its Estimate; ``rejections`` the child's counts.
    ``on_estimate(estimate)`` is called on the reader thread for every new estimate.
    ``config`` tunes the child's calibrator.
    """

    def __init__(self, params, on_estimate: Optional[Callable] = None,
                 on_error: Optional[Callable[[str], None]] = None,
                 config: OnlineConfig = OnlineConfig()):
        from sclam_ros.online.calibrator import OnlineCalibrator

        self.params = params
        self.config = config
        self.on_estimate = on_estimate or (lambda estimate: None)
        self.on_error = on_error or (lambda message: log.error(message))
        # What a status says before the child has said anything: nominal, nothing known.
        self._initial = OnlineCalibrator(params, config=config).status()
        self.status = self._initial
        self.rejections = Rejections()
        self.failure: Optional[str] = None
        self.sent = 0  # messages and commands put in the inbox
        self.dropped = 0  # messages not handed over because the child had ended
        self._stopping = False
        self.handled = 0  # of them, taken by the child (as of its last report)
        self._epoch = 0
        # spawn, not fork: the node's process runs DDS threads a fork would copy mid-state.
        context = multiprocessing.get_context("spawn")
        self._inbox = context.Queue()
        self._outbox = context.Queue()
        self._process = context.Process(target=_serve,
                                        args=(params, config, self._inbox, self._outbox),
                                        name="sclam_calibrator", daemon=True)
        self._process.start()
        self._reader = threading.Thread(target=self._read, name="sclam_calibrator_reader",
                                        daemon=True)
        self._reader.start()

    # --- input (the node's callbacks) -----------------------------------------------------
    def add_encoder(self, stamp: float, left_raw: float, right_raw: float) -> None:
        self._put(("encoder", stamp, left_raw, right_raw))

    def add_scan(self, scan) -> None:
        self._put(("scan", scan))

    def _put(self, item) -> None:
        if self.failure is not None:  # nobody would read it: count it, do not pile it up
            self.dropped += 1
            return
        self.sent += 1
        self._inbox.put(item)

    @property
    def backlog(self) -> int:
        """Messages handed over that the child had not taken at its last report."""
        return self.sent - self.handled

    # --- commands ---------------------------------------------------------------------------
    def _command(self, name: str, *arguments) -> None:
        self._epoch += 1
        self._put((name, self._epoch, *arguments))

    def reset_window(self) -> None:
        self._command("reset_window")

    def reset_calibration(self) -> None:
        self.status = self._initial  # at once: nothing of the old estimate may be used
        self._command("reset_calibration")

    def set_window_distance(self, metres: float) -> None:
        self.params.window_distance = float(metres)
        self._command("set_window_distance", float(metres))

    def set_param(self, name: str, value) -> None:
        setattr(self.params, name, value)
        self._command("set_param", name, value)

    # --- output -----------------------------------------------------------------------------
    @property
    def estimate(self):
        return self.status.estimate

    @property
    def calibration(self):
        return self.status.calibration

    @property
    def alive(self) -> bool:
        return self._process.is_alive()

    def _read(self) -> None:
        while True:
            try:
                kind, epoch, status, counts, handled, payload = self._outbox.get(timeout=1.0)
            except queue.Empty:
                if not self._process.is_alive():
                    self._child_ended()
                    return
                continue
            except (EOFError, OSError):
                self._child_ended()
                return
            if kind == "stopped":
                return
            self.handled = max(self.handled, handled)
            if kind == "error":
                self.on_error(payload)
                continue
            if epoch < self._epoch:
                continue  # sent before the child saw the newest command
            if kind == "status" and status.solves == self.status.solves:
                # No solve since the last message: the estimate is the one already handed
                # out (an unpickled copy otherwise; callers may compare by identity).
                status = replace(status, estimate=self.status.estimate)
            self.status = status
            self.rejections = Rejections(Counter(counts))
            if kind == "estimate":
                self.on_estimate(payload)

    def _child_ended(self) -> None:
        self._process.join(STOP_TIMEOUT_S)
        if self.failure is None and not self._stopping:
            self.failure = f"calibrator process ended (exit code {self._process.exitcode})"
            self.on_error(self.failure)

    def stop(self) -> None:
        """Stop the child (after it has handled what was sent) and the reader."""
        self._stopping = True
        if self._process.is_alive():
            self._inbox.put(("stop",))
            self._process.join(STOP_TIMEOUT_S)
            if self._process.is_alive():
                self._process.terminate()
                self._process.join(STOP_TIMEOUT_S)
        self._outbox.put(("stopped", 0, None, None, 0, None))
        self._reader.join(STOP_TIMEOUT_S)
