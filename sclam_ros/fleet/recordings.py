"""What ``sclam fleet`` is asked to calibrate: bags, folders searched for bags, manifest CSVs.

A recording is one bag of one robot with the parameters file that describes that robot. The
robot's name comes from the manifest, or else from the folder the bag sits in (a fleet's
recordings are usually stored as ROBOT/BAG); the parameters from the manifest, else
``--params``, else a ``params.yaml`` inside or beside the bag.
"""
from __future__ import annotations

import csv
import hashlib
from dataclasses import dataclass
from pathlib import Path
from typing import Optional

STORAGE_SUFFIXES = (".db3", ".mcap")
MANIFEST_COLUMNS = ("robot", "bag", "params")


class RecordingsError(ValueError):
    """The inputs do not name usable recordings; the message says which and why."""


@dataclass(frozen=True)
class Recording:
    robot: str
    bag: Path
    params: Optional[Path]

    @property
    def key(self) -> str:
        """A stable file-name-safe id: the robot, the bag's name and a hash of its full path."""
        digest = hashlib.sha1(str(self.bag.resolve()).encode()).hexdigest()[:10]
        safe = "".join(c if c.isalnum() or c in "-_." else "_" for c in f"{self.robot}__{self.bag.name}")
        return f"{safe}__{digest}"

    def fingerprint(self) -> dict:
        """Name, size and modification time of every file of the bag and of the parameters:
        a rerun recalibrates a recording only when one of them changed."""
        files = sorted(self.bag.rglob("*")) if self.bag.is_dir() else [self.bag]
        if self.params is not None:
            files.append(self.params)
        return {str(f): [f.stat().st_size, f.stat().st_mtime_ns] for f in files if f.is_file()}


def _is_bag_folder(path: Path) -> bool:
    return path.is_dir() and (path / "metadata.yaml").is_file()


def find_bags(folder: Path) -> list[Path]:
    """rosbag2 folders below `folder` (not descending into them), and lone storage files."""
    if _is_bag_folder(folder):
        return [folder]
    bags = []
    for child in sorted(folder.iterdir()):
        if child.is_dir():
            bags.extend(find_bags(child))
        elif child.suffix in STORAGE_SUFFIXES or child.suffix == ".bag":
            bags.append(child)
    return bags


def _params_beside(bag: Path) -> Optional[Path]:
    for candidate in (bag / "params.yaml", bag.parent / "params.yaml"):
        if candidate.is_file():
            return candidate
    return None


def read_manifest(path: Path) -> list[Recording]:
    """Rows ``robot, bag, params`` (a header row; relative paths are relative to the CSV)."""
    with path.open(newline="") as stream:
        reader = csv.DictReader(stream)
        missing = [c for c in MANIFEST_COLUMNS[:2] if c not in (reader.fieldnames or [])]
        if missing:
            raise RecordingsError(f"manifest {path} lacks column(s) {', '.join(missing)}; "
                                  f"expected a header row: {', '.join(MANIFEST_COLUMNS)}")
        recordings = []
        for line, row in enumerate(reader, 2):
            if not (row.get("bag") or "").strip():
                raise RecordingsError(f"manifest {path}, line {line}: no bag")
            bag = (path.parent / row["bag"].strip())
            params = (row.get("params") or "").strip()
            recordings.append(Recording((row.get("robot") or "").strip() or bag.parent.name,
                                        bag, path.parent / params if params else None))
    return recordings


def collect(inputs: list[str], default_params: Optional[str] = None) -> list[Recording]:
    """The recordings named by `inputs`, each once, in the order given."""
    params = Path(default_params) if default_params else None
    recordings = []
    for item in map(Path, inputs):
        if not item.exists():
            raise RecordingsError(f"input not found: {item}")
        if item.suffix == ".csv":
            found = read_manifest(item)
        else:
            bags = find_bags(item) if item.is_dir() else [item]
            if not bags:
                raise RecordingsError(f"no rosbag2 recording found in {item}")
            found = [Recording(b.parent.name, b, params or _params_beside(b)) for b in bags]
        recordings.extend(r if r.params else Recording(r.robot, r.bag, params or _params_beside(r.bag))
                          for r in found)
    unique = {r.bag.resolve(): r for r in reversed(recordings)}  # first mention wins
    return [r for r in recordings if unique.get(r.bag.resolve()) is r]
