"""Run the recordings that have no current result as one Dask task each; store as they finish."""
from __future__ import annotations

from dataclasses import dataclass, field

from sclam_ros.fleet.task import calibrate_recording


@dataclass
class FleetSummary:
    total: int = 0
    reused: int = 0  # results kept from an earlier run (inputs unchanged)
    calibrated: int = 0
    failed: list = field(default_factory=list)  # (bag, reason) of this run's failures
    failed_before: list = field(default_factory=list)  # (bag, reason) of reused failed results


def cluster_failure(recording, exc) -> dict:
    """A task the cluster could not run (e.g. its worker died on every attempt): failed,
    and marked for retry, because the input may be fine."""
    return {"robot": recording.robot, "bag": str(recording.bag), "key": recording.key,
            "params": str(recording.params) if recording.params else None,
            "status": "failed", "retry": True, "warnings": [], "start_time": None,
            "duration_s": None, "error": f"cluster: {type(exc).__name__}: {exc}"}


def run_fleet(client, recordings, store, progress=None) -> FleetSummary:
    """Calibrate `recordings` on `client`, skipping those `store` already holds."""
    from distributed import as_completed

    summary = FleetSummary(total=len(recordings))
    todo = [r for r in recordings if not store.is_done(r)]
    summary.reused = len(recordings) - len(todo)
    for recording in set(recordings) - set(todo):
        stored = store.load(recording.key)
        if stored["status"] != "ok":  # the same input fails the same way: still a failure
            summary.failed_before.append((stored["bag"], stored["error"]))
    # pure=False: a rerun after a change must run again even if Dask remembers the key.
    futures = {client.submit(calibrate_recording, r, pure=False): r for r in todo}
    for done, future in enumerate(as_completed(futures), 1):
        recording = futures[future]
        try:
            result = future.result()
        except Exception as exc:  # noqa: BLE001 - one recording's loss stops nothing else
            result = cluster_failure(recording, exc)
        store.save(result)
        if result["status"] == "ok":
            summary.calibrated += 1
        else:
            summary.failed.append((result["bag"], result["error"]))
        if progress is not None:
            progress(done, len(todo))
    store.write_csv()
    return summary
