"""One recording's calibration as a self-contained task: what a Dask worker runs.

Everything a recording can do wrong ends as a failed result with its reason, never as an
exception that would stop the other recordings: the task catches it and says what it was.
"""
from __future__ import annotations

import traceback

import numpy as np

from sclam_ros.core.params import CALIBRATION_KEYS

# Errors that say something about the input: their message is the reason, as is.
INPUT_ERRORS = ("ParamsError", "BagError", "CalibrationError", "RecordingsError")


def result_warnings(result) -> list[str]:
    """One-line warnings a fleet operator should see beside the numbers."""
    warnings = []
    unobserved = [k for k in CALIBRATION_KEYS if not result.observable[k]]
    if unobserved:
        warnings.append("not observable in this recording, kept nominal: " + ", ".join(unobserved))
    if not result.converged:
        warnings.append(f"solver stopped after {result.iterations} iterations without converging")
    if result.rejections.total():
        warnings.append(f"rejected input (counted, not used): {result.rejections}")
    return warnings


def result_fields(result) -> dict:
    """The calibration part of a fleet result (JSON-ready)."""
    return {
        "estimate": {k: float(result.estimate[k]) for k in CALIBRATION_KEYS},
        "sigma": {k: float(result.sigma[k]) for k in CALIBRATION_KEYS},
        "nominal": {k: float(result.nominal[k]) for k in CALIBRATION_KEYS},
        "observable": {k: bool(result.observable[k]) for k in CALIBRATION_KEYS},
        "scans_used": int(result.scans_used),
        "iterations": int(result.iterations),
        "converged": bool(result.converged),
        "warnings": result_warnings(result),
    }


def calibrate_recording(recording) -> dict:
    """Calibrate one recording end to end; a JSON-ready result, status "ok" or "failed"."""
    from sclam_ros.core.estimator import calibrate_keyframes
    from sclam_ros.core.params import SclamParams
    from sclam_ros.fleet.recordings import RecordingsError
    from sclam_ros.io import bag
    from sclam_ros.io.recording import read_recording

    out = {"robot": recording.robot, "bag": str(recording.bag),
           "params": str(recording.params) if recording.params else None,
           "key": recording.key, "status": "failed", "error": "", "warnings": [],
           "start_time": None, "duration_s": None}
    try:
        out["fingerprint"] = recording.fingerprint()
        if recording.params is None:
            raise RecordingsError("no parameters file: give --params, a manifest 'params' "
                                  "column, or put a params.yaml beside the bag")
        params = SclamParams.from_yaml(recording.params)
        first, last = bag.time_span(recording.bag)
        out["start_time"], out["duration_s"] = first, last - first
        data = read_recording(recording.bag, params)
        result = calibrate_keyframes(data.keyframes, params, data.rejections)
        if not all(np.isfinite(list(result.estimate.values()))):
            raise ValueError("non-finite estimate")
    except Exception as exc:  # noqa: BLE001 - a failed row with its reason, see the docstring
        name = type(exc).__name__
        out["error"] = str(exc) if name in INPUT_ERRORS else f"{name}: {exc}"
        if name not in INPUT_ERRORS:
            # An unexpected failure is a bug to report: keep where it happened.
            out["traceback"] = traceback.format_exc(limit=-3)
        return out
    out.update(result_fields(result), status="ok")
    return out
