"""The online calibration: sliding window, change detection, solver thread, corrected odometry and
the status the node reports. No rclpy. May import: core, frontend."""
