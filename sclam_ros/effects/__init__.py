"""Model extensions, one module per physical effect, estimated in the calibration graph.

    LIBRARY[name](EffectData) → an effect; model.build_problem / model.extend_problem put
    it in the graph (see base.ModelEffect for the hooks).
"""
from .base import EffectData, ModelEffect
from .floor_noise import FloorNoise
from .lateral_slip import LateralSlip
from .radius_drift import RadiusDrift
from .scan_distortion import ScanDistortion
from .time_offset import TimeOffset

LIBRARY = {cls.name: cls for cls in (TimeOffset, LateralSlip, RadiusDrift, ScanDistortion,
                                     FloorNoise)}

__all__ = ["LIBRARY", "EffectData", "ModelEffect"]
