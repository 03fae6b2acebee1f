"""Shared by the benchmark scripts: simulate a recording, calibrate it, time it."""
from __future__ import annotations

import atexit
import os
import resource
import shutil
import tempfile
import time
from pathlib import Path

from sclam_ros.core.estimator import calibrate_keyframes
from sclam_ros.io.recording import read_recording
from sclam_ros.core.params import CALIBRATION_KEYS, SclamParams
from sclam_ros.sim import simulate


def scratch_dir(prefix: str) -> Path:
    """A new directory under the system's temporary folder for a bench's recordings,
    removed when the bench exits (the matrix's 180 bags are 1-2 GB, and runs add up) unless
    SCLAM_BENCH_KEEP=1, which keeps it and says where. Only the process that made it
    removes it: the worker processes a bench forks end without running it."""
    path = Path(tempfile.mkdtemp(prefix=prefix))
    owner = os.getpid()

    def remove():
        if os.getpid() != owner:
            return
        if os.environ.get("SCLAM_BENCH_KEEP") == "1":
            print(f"(bench recordings kept in {path})", flush=True)
        else:
            shutil.rmtree(path, ignore_errors=True)

    atexit.register(remove)
    return path


def simulate_and_calibrate(robot, duration, seed, true_overrides=None, nominal_overrides=None,
                           workdir=None, **sim_options):
    """(truth, result, seconds spent calibrating) for one simulated recording."""
    workdir = Path(workdir or scratch_dir("sclam_bench_"))
    out = workdir / f"{robot}_{seed}_{int(duration)}"
    truth = simulate(out, robot=robot, duration=duration, seed=seed,
                     true_overrides=true_overrides, overwrite=True, **sim_options)
    params = SclamParams.from_yaml(out / "params.yaml")
    if nominal_overrides:
        params = params.with_calibration({**params.calibration(), **nominal_overrides})
    start = time.perf_counter()
    recording = read_recording(out, params)
    result = calibrate_keyframes(recording.keyframes, params, recording.rejections)
    return truth, result, time.perf_counter() - start, out


def errors(truth, result):
    return {k: result.estimate[k] - truth[k] for k in CALIBRATION_KEYS}


def peak_rss_mb():
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def table(rows, header):
    widths = [max(len(str(h)), *(len(str(r[i])) for r in rows)) for i, h in enumerate(header)]
    line = "| " + " | ".join(str(h).ljust(w) for h, w in zip(header, widths)) + " |"
    sep = "|" + "|".join("-" * (w + 2) for w in widths) + "|"
    body = ["| " + " | ".join(str(c).ljust(w) for c, w in zip(r, widths)) + " |" for r in rows]
    return "\n".join([line, sep, *body])


def seeds_arguments(doc, seeds, duration):
    """An argument parser with a bench's usual --seeds, --duration (s) and --jobs (one
    process per core), its description the bench's docstring."""
    import argparse

    ap = argparse.ArgumentParser(description=doc, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, default=seeds)
    ap.add_argument("--duration", type=float, default=duration)
    ap.add_argument("--jobs", type=int, default=2)
    return ap


def configured(config, settings=()):
    """`config` (a configuration tree of frozen dataclasses: DiagnoseConfig, OnlineConfig,
    ...) with `settings` ("section.field=value", e.g. "selection.noise_folds=10"; a tuple
    field takes comma-separated values) changed: how a bench tries another value without
    touching the code."""
    import dataclasses

    for setting in settings:
        path, _, text = setting.partition("=")
        section_name, _, name = path.strip().partition(".")
        section = getattr(config, section_name)
        old = getattr(section, name)
        value = (tuple(float(v) for v in text.split(",")) if isinstance(old, tuple)
                 else type(old)(text))
        config = dataclasses.replace(
            config, **{section_name: dataclasses.replace(section, **{name: value})})
    return config
