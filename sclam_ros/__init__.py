"""sclam_ros: simultaneous calibration, localization and mapping for differential-drive robots."""
__version__ = "0.1.0"
