"""Model extensions, one module per physical effect, estimated in the calibration graph.

    LIBRARY[name](EffectData[, DiagnoseConfig]) → an effect; model.build_problem /
    model.extend_problem put it in the graph (see base.ModelEffect for the hooks). Effects
    of kind "noise" change the noise model instead (see noise_fit).
"""
from sclam_ros.diagnosis.effects.base import EffectData, ModelEffect
from sclam_ros.diagnosis.effects.floor_noise import FloorNoise
from sclam_ros.diagnosis.effects.lateral_slip import LateralSlip
from sclam_ros.diagnosis.effects.noise_vs_motion import NoiseVsAcceleration, NoiseVsSpeed, NoiseVsTurnRate
from sclam_ros.diagnosis.effects.radius_drift import RadiusDrift
from sclam_ros.diagnosis.effects.scan_distortion import ScanDistortion
from sclam_ros.diagnosis.effects.time_offset import TimeOffset

LIBRARY = {cls.name: cls for cls in (TimeOffset, LateralSlip, RadiusDrift, ScanDistortion,
                                     FloorNoise, NoiseVsSpeed, NoiseVsTurnRate,
                                     NoiseVsAcceleration)}

__all__ = ["LIBRARY", "EffectData", "ModelEffect"]
