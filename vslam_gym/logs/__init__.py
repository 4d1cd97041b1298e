"""Readers for recorded 2-D lidar robot logs, to run the estimator outside the simulator."""

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
    "integrate_increments",
    "logged_increments",
    "read_carmen",
    "synthetic_increments",
]
