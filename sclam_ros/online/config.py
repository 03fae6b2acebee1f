"""The online calibrator's developer tuning: one frozen tree, passed to constructors.

What a user sets for their robot (window_distance, noise, keyframe_interval...) is in
core.params.SclamParams; these are the values only a developer tunes. Benches and tests vary
them by passing a config (dataclasses.replace), never by assigning to a module. The
measurements behind the chosen values: docs/decisions/online.md.
"""
from __future__ import annotations

from dataclasses import dataclass, field


@dataclass(frozen=True)
class PoseWindowConfig:
    """The keyframes held as poses in the solved graph (pose_window.py)."""

    # m driven kept as poses: a change inside can only be placed at the window's start, so
    # this bounds how soon a change is located (docs/decisions/online.md#pose-window).
    distance: float = 5.0
    # merged keyframes (200 s at 0.5 s): bounds a solve's cost when crawling or standing still.
    max_keyframes: int = 400
    # keyframes per marginalised chunk: one dense Schur complement each; its boundaries are
    # where the change test can place a change (5 s at 0.5 s keyframes).
    marginalise_batch: int = 10


@dataclass(frozen=True)
class ChangeTestConfig:
    """When the change test declares a change of the radii (change_detector.py)."""

    # likelihood ratio (dimensionless) a solve exceeds to count toward a change: the largest
    # over the history's boundaries, under a model that overstates the noise
    # (docs/decisions/online.md#change-threshold).
    statistic: float = 6.0
    # solves in a row above `statistic` to declare a change: one noisy solve cuts nothing.
    confirmations: int = 3
    # m of marginalised history before the test runs, and before its first boundary: the
    # chunks right after a start are linearised at radii still converging from nominal
    # (docs/decisions/online.md#tested-history).
    min_tested_history: float = 10.0


@dataclass(frozen=True)
class WindowSolveConfig:
    """A window solve (window_solve.py, calibrator.py)."""

    # keyframes in the window below which no solve is made: too little to say anything.
    min_keyframes: int = 6
    # fraction of the cost an LM step must remove to go on: well below a σ of the
    # parameters, and the next solve, warm-started, carries on (docs/decisions/online.md#lm-cap).
    relative_tolerance: float = 1e-4
    # LM steps per solve: bounds a solve's time; the next, warm-started, carries on.
    max_iterations: int = 3
    # bounds of the window's a-posteriori variance factor (dimensionless): a window with
    # few redundant rows neither inflates nor collapses the published σ.
    variance_factor_limits: tuple = (0.01, 100.0)


@dataclass(frozen=True)
class StatusConfig:
    """When the node's status warns (status.py)."""

    # solves in a row at their iteration cap before a warning: one is normal, the next
    # solve carries on; a run of them means the window's optimum keeps moving away.
    unconverged_warning: int = 3
    # change model's weight in the radii σ (0-1) above which a change is reported as
    # suspected: past even odds the test is a solve or two from declaring it.
    change_suspected: float = 0.5


@dataclass(frozen=True)
class ProcessConfig:
    """How the calibrator's child process runs beside the node (process.py)."""

    # added to the child's nice value (0: the node's priority): ~/odom answers every
    # encoder message, an estimate comes once a second, so where the CPU is contended
    # the node's callbacks go first (docs/decisions/runtime.md).
    niceness: int = 5


@dataclass(frozen=True)
class OnlineConfig:
    window: PoseWindowConfig = field(default_factory=PoseWindowConfig)
    change: ChangeTestConfig = field(default_factory=ChangeTestConfig)
    solve: WindowSolveConfig = field(default_factory=WindowSolveConfig)
    status: StatusConfig = field(default_factory=StatusConfig)
    process: ProcessConfig = field(default_factory=ProcessConfig)
