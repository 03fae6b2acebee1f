"""True calibration values to print beside an estimate (`sclam calibrate --truth FILE`).

Two layouts are read: the one `sclam simulate` writes (truth.json: the six parameter names
at the top level, beside the simulation's other facts), and a table of the values alone
under ``true`` (or ``truth``), with either the parameter names or the short names that
papers and other tools use (r_l, r_r, b, l_x, l_y, l_yaw).
"""
from __future__ import annotations

import json
import math
from pathlib import Path

from sclam_ros.core.params import CALIBRATION_KEYS

# Short names → parameter names; laser_theta and l_theta as CARMEN and g2o call the yaw.
ALIASES = {
    "r_l": "wheel_radius_left", "r_r": "wheel_radius_right", "b": "wheel_base",
    "l_x": "laser_x", "l_y": "laser_y", "l_yaw": "laser_yaw", "l_theta": "laser_yaw",
    "laser_theta": "laser_yaw",
}
NESTED_KEYS = ("true", "truth")


class TruthError(ValueError):
    """A truth file that cannot be read as the six true values; the message says why."""


def _table(doc, path):
    """The mapping that holds the values: the document itself, or its ``true``/``truth``."""
    if not isinstance(doc, dict):
        raise TruthError(f"{path}: expected a JSON object of true values, got a "
                         f"{type(doc).__name__}")
    for key in NESTED_KEYS:
        if isinstance(doc.get(key), dict) and not any(k in doc for k in CALIBRATION_KEYS):
            return doc[key]
    return doc


def read_truth(path) -> dict:
    """{parameter: true value (m, rad)} of the six calibration parameters in ``path``;
    TruthError (one line) naming what is missing or not a number."""
    path = Path(path)
    try:
        doc = json.loads(path.read_text())
    except json.JSONDecodeError as exc:
        raise TruthError(f"{path}: not JSON ({exc})") from None
    except UnicodeDecodeError:
        raise TruthError(f"{path}: not a text file, so not a JSON truth file") from None
    table = _table(doc, path)
    values = {ALIASES.get(k, k): v for k, v in table.items()}
    missing = [k for k in CALIBRATION_KEYS if k not in values]
    if missing:
        raise TruthError(
            f"{path}: no true value for {', '.join(missing)}; expected the keys "
            f"{', '.join(CALIBRATION_KEYS)} (or {', '.join(list(ALIASES)[:6])}) at the top "
            f"level or under 'true'; found {', '.join(sorted(map(str, table))) or 'none'}")
    truth = {}
    for key in CALIBRATION_KEYS:
        value = values[key]
        if isinstance(value, bool) or not isinstance(value, (int, float)) \
                or not math.isfinite(value):
            raise TruthError(f"{path}: the true {key} must be a finite number, got {value!r}")
        truth[key] = float(value)
    return truth
