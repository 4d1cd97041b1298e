"""Recorded 2-D lidar robot logs: readers, and a writer for simulated episodes.

Read a log to run the estimator outside the simulator; write a simulated episode as a
log to replay it with any configuration (``vslam-gym replay``) or another SLAM package.
"""

from vslam_gym.logs.bearing_check import bearing_offset_scores
from vslam_gym.logs.carmen import (
    CarmenConfig,
    CarmenFormatError,
    CarmenLog,
    integrate_increments,
    logged_increments,
    read_carmen,
    synthetic_increments,
)
from vslam_gym.logs.carmen_writer import CarmenRecorder, write_carmen

__all__ = [
    "CarmenConfig",
    "CarmenFormatError",
    "CarmenLog",
    "CarmenRecorder",
    "bearing_offset_scores",
    "integrate_increments",
    "logged_increments",
    "read_carmen",
    "synthetic_increments",
    "write_carmen",
]
