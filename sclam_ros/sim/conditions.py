"""How a recording is made, apart from the robot and its drive: what real recordings vary
and a calibration or a diagnosis must not mistake for an effect.

- ``scan_phase``: when the first scan is taken after the first encoder sample (s); at a
  multiple of the encoder period every scan lands on a sample, otherwise the encoder
  angles are interpolated at every scan.
- ``scan_stamp_jitter``: 1σ (s) of the error of each scan's stamp against the time it
  was taken (a driver stamping on arrival, a busy computer); the scan itself is taken on
  the regular grid.
- ``sweep_stated``: whether a sweeping laser (the ``scan_motion`` effect) says so in
  ``time_increment``; a driver that writes 0 leaves the sweep unknown to the reader.
- ``no_return``: how a beam without a target is encoded: ``inf`` (REP-117), ``nan``,
  ``zero`` or ``above_max`` (range_max + 1 m), as drivers do.
- ``ticks_per_revolution``: the encoders' resolution (None: the robot preset's).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import numpy as np

NO_RETURN_ENCODINGS = ("inf", "nan", "zero", "above_max")


@dataclass(frozen=True)
class RecordingConditions:
    scan_phase: float = 0.013  # s
    scan_stamp_jitter: float = 0.0  # s, 1σ
    sweep_stated: bool = True
    no_return: str = "inf"
    ticks_per_revolution: Optional[float] = None

    def __post_init__(self):
        if self.no_return not in NO_RETURN_ENCODINGS:
            raise ValueError(f"no_return must be one of {', '.join(NO_RETURN_ENCODINGS)}, "
                             f"got {self.no_return!r}")
        if self.scan_phase < 0 or self.scan_stamp_jitter < 0:
            raise ValueError("scan_phase and scan_stamp_jitter must be >= 0")
        if self.ticks_per_revolution is not None and self.ticks_per_revolution <= 0:
            raise ValueError(f"ticks_per_revolution must be > 0, got {self.ticks_per_revolution}")

    def encode_no_return(self, ranges: np.ndarray, range_max: float) -> np.ndarray:
        """Ranges with the simulator's inf (no return) written as this driver would."""
        out = np.array(ranges, float)
        missing = np.isinf(out)
        out[missing] = {"inf": np.inf, "nan": np.nan, "zero": 0.0,
                        "above_max": range_max + 1.0}[self.no_return]
        return out

    def describe(self) -> dict:
        return {"scan_phase": self.scan_phase, "scan_stamp_jitter": self.scan_stamp_jitter,
                "sweep_stated": self.sweep_stated, "no_return": self.no_return,
                "ticks_per_revolution": self.ticks_per_revolution}
