"""Readers for recorded 2-D lidar robot logs, to run the estimator outside the simulator."""

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

__all__ = [
    "CarmenConfig",
    "CarmenFormatError",
    "CarmenLog",
    "bearing_offset_scores",
    "integrate_increments",
    "logged_increments",
    "read_carmen",
    "synthetic_increments",
]
