"""The results folder of ``sclam fleet``: one JSON per recording, and results.csv over all.

    DIR/recordings/<key>.json   the result of one recording (written atomically)
    DIR/results.csv             one row per recording, rebuilt from the JSONs after every run

A result is reused on a rerun when its recording's files are unchanged (same fingerprint),
so a run that crashed or was stopped resumes where it was. A failure of the cluster rather
than of the input (a worker that kept dying) is stored as ``retry`` and is calibrated again.
"""
from __future__ import annotations

import csv
import io
import json
from datetime import datetime, timezone
from pathlib import Path

from sclam_ros.core.params import CALIBRATION_KEYS, atomic_write_text

CSV_COLUMNS = (
    "robot", "bag", "start_time", "duration_s", "status",
    *(c for k in CALIBRATION_KEYS for c in (k, f"sigma_{k}", f"observable_{k}")),
    "warnings", "error",
)


class ResultStore:
    def __init__(self, folder):
        self.folder = Path(folder)
        self.recordings = self.folder / "recordings"
        self.recordings.mkdir(parents=True, exist_ok=True)

    def path_of(self, key: str) -> Path:
        return self.recordings / f"{key}.json"

    def load(self, key: str):
        try:
            return json.loads(self.path_of(key).read_text())
        except (OSError, ValueError):
            return None

    def is_done(self, recording) -> bool:
        """A result exists for exactly these input files, and it is not marked for retry."""
        stored = self.load(recording.key)
        return (stored is not None and not stored.get("retry")
                and stored.get("fingerprint") == recording.fingerprint())

    def save(self, result: dict) -> None:
        atomic_write_text(self.path_of(result["key"]), json.dumps(result, indent=2) + "\n")

    def all_results(self) -> list[dict]:
        results = []
        for path in sorted(self.recordings.glob("*.json")):
            try:
                results.append(json.loads(path.read_text()))
            except ValueError:
                continue  # a file not written by us; atomic writes leave no half files
        return sorted(results, key=lambda r: (r["robot"], r.get("start_time") or 0.0, r["bag"]))

    def write_csv(self) -> Path:
        buffer = io.StringIO()
        writer = csv.writer(buffer)
        writer.writerow(CSV_COLUMNS)
        for result in self.all_results():
            writer.writerow(csv_row(result))
        path = self.folder / "results.csv"
        atomic_write_text(path, buffer.getvalue())
        return path


def iso_time(stamp) -> str:
    if stamp is None:
        return ""
    return datetime.fromtimestamp(stamp, timezone.utc).isoformat(timespec="seconds")


def csv_row(result: dict) -> list:
    row = [result["robot"], result["bag"], iso_time(result.get("start_time")),
           "" if result.get("duration_s") is None else f"{result['duration_s']:.1f}",
           result["status"]]
    for key in CALIBRATION_KEYS:
        if result["status"] == "ok":
            row += [f"{result['estimate'][key]:.9g}", f"{result['sigma'][key]:.3g}",
                    int(result["observable"][key])]
        else:
            row += ["", "", ""]
    return row + ["; ".join(result.get("warnings", [])), result.get("error", "")]
