"""Run-to-run and half-versus-half agreement on the real Mines rover (URG-04LX), in σ.

The two breezyslam-mines runs (../shared/data/breezyslam-mines, LGPL-3.0; converted with
`sclam convert breezyslam`, each scan stamped 160 ms before its log line as docs/real_data.md
establishes) are calibrated whole and in halves (the first and second half of the run's
scans, each calibrated alone). With no ground truth, agreement is the test of honesty: two
calibrations of one robot should differ by about their combined σ,
z = (a − b) / sqrt(σa² + σb²), |z| > 3 rarely.

Run: .venv/bin/python bench/mines_agreement.py [DATA_DIR]
"""
from __future__ import annotations

import itertools
import math
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import scratch_dir, table  # noqa: E402

from sclam_ros.core.estimator import calibrate_keyframes  # noqa: E402
from sclam_ros.core.params import CALIBRATION_KEYS, SclamParams  # noqa: E402
from sclam_ros.io.convert import convert_breezyslam  # noqa: E402
from sclam_ros.io.recording import read_recording  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
SCAN_DELAY = 0.16  # s, docs/real_data.md


def human(key, value):
    return math.degrees(value) if key == "laser_yaw" else 1e3 * value


def calibrations(src: Path, work: Path) -> dict:
    """{label: CalibrationResult} for the whole run and its two halves."""
    out = work / src.stem
    convert_breezyslam(src, out, scan_delay=SCAN_DELAY)
    params = SclamParams.from_yaml(out / "params.yaml")
    keyframes = read_recording(out / "bag", params).keyframes
    half = len(keyframes) // 2
    # The graph keeps only edges between the keyframes it is given: the second half's first
    # edges, which start in the first half, are left out.
    return {
        f"{src.stem} whole": calibrate_keyframes(keyframes, params),
        f"{src.stem} 1st half": calibrate_keyframes(keyframes[:half], params),
        f"{src.stem} 2nd half": calibrate_keyframes(keyframes[half:], params),
    }


def main(argv) -> int:
    data = Path(argv[1]) if len(argv) > 1 else ROOT.parent / "shared" / "data"
    sources = [data / "breezyslam-mines" / f"exp{n}.dat" for n in (1, 2)]
    if not all(s.exists() for s in sources):
        print(f"breezyslam-mines not found under {data}; nothing to do")
        return 0
    work = scratch_dir("mines_agreement_")
    results = {}
    for src in sources:
        results.update(calibrations(src, work))
    rows = [[label] + [f"{human(k, r.estimate[k]):.2f} ± {human(k, r.sigma[k]):.2f}"
                       + ("" if r.observable[k] else " (n/o)") for k in CALIBRATION_KEYS]
            for label, r in results.items()]
    print(f"Mines rover, scans stamped {SCAN_DELAY * 1e3:.0f} ms early; mm and degrees, ± 1σ")
    print(table(rows, ["calibration", *CALIBRATION_KEYS]))
    pairs = [("exp1 whole", "exp2 whole"), ("exp1 1st half", "exp1 2nd half"),
             ("exp2 1st half", "exp2 2nd half")]
    pairs += [(a, b) for a, b in itertools.product(["exp1 1st half", "exp1 2nd half"],
                                                     ["exp2 1st half", "exp2 2nd half"])]
    rows = []
    for a, b in pairs:
        ra, rb = results[a], results[b]
        cells = []
        for k in CALIBRATION_KEYS:
            if not (ra.observable[k] and rb.observable[k]):
                cells.append("n/o")
                continue
            z = (ra.estimate[k] - rb.estimate[k]) / math.hypot(ra.sigma[k], rb.sigma[k])
            cells.append(f"{z:+.1f}")
        rows.append([f"{a} − {b}", *cells])
    print("\ndifference / combined σ (n/o: not observable in one of them)")
    print(table(rows, ["pair", *CALIBRATION_KEYS]))
    zs = [abs(float(c)) for row in rows for c in row[1:] if c != "n/o"]
    print(f"\n|z| > 2: {sum(z > 2 for z in zs)} of {len(zs)}; |z| > 3: {sum(z > 3 for z in zs)} of {len(zs)}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
