"""How many processes register one recording: `sclam calibrate --workers auto|N`.

Cut into time chunks (chunked.py), a recording registers in parallel; each chunk costs a
few seconds of data read twice (its lead) and a local map started anew, and the processes
cost their start. Parallel pays from a length on, measured by bench/speed.py, and a short
recording cut in two can move by a fraction of σ (docs/decisions/parallel.md): shorter
recordings register sequentially. The length comes from the bag's metadata, before
anything is read.
"""
from __future__ import annotations

from dataclasses import dataclass

from sclam_ros.fleet.chunked import MIN_CHUNK_S
from sclam_ros.fleet.engine import default_workers


@dataclass(frozen=True)
class WorkersConfig:
    # s of recording from which `--workers auto` registers in parallel chunks: parallel paid
    # from 60 s but saved a fifth only from 2 minutes, and the real one-minute logs cut in
    # two moved by up to 1.5 σ (docs/decisions/parallel.md)
    parallel_from_s: float = 120.0


@dataclass(frozen=True)
class WorkersChoice:
    workers: int  # processes registering the recording (1: sequential, in this process)
    reason: str  # one line for the log: what was chosen and why


def choose_workers(requested, duration_s: float, cores: int | None = None,
                   config: WorkersConfig = WorkersConfig()) -> WorkersChoice:
    """`requested`: "auto" or a number of workers (1: sequential; N forces N chunks, as
    many as the recording has room for: chunked.MIN_CHUNK_S each). `cores`: those this
    process may run on (default: engine.default_workers)."""
    room = max(1, int(duration_s // MIN_CHUNK_S))
    if requested != "auto":
        workers = max(1, min(int(requested), room))
        how = "sequentially" if workers == 1 else f"in {workers} parallel chunks"
        return WorkersChoice(workers, f"registering {how} (--workers {requested})")
    cores = cores or default_workers()
    if cores < 2:
        return WorkersChoice(1, "registering sequentially: one core")
    if duration_s < config.parallel_from_s:
        return WorkersChoice(1, f"registering sequentially: the recording is {duration_s:.0f} s, "
                                f"parallel chunks pay from {config.parallel_from_s:.0f} s "
                                "(--workers N forces N)")
    workers = min(cores, room)
    return WorkersChoice(workers, f"registering in {workers} parallel chunks on {cores} cores: "
                                  f"the recording is {duration_s:.0f} s, parallel chunks pay "
                                  f"from {config.parallel_from_s:.0f} s (--workers 1 forces "
                                  "sequential)")
