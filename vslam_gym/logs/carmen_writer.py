"""Write scans with their true and odometry poses as a Carmen log.

A simulated episode written this way is a log like the real ones: ``vslam-gym replay``
runs any estimator configuration on exactly the same scans and odometry (a paired
comparison, where closed-loop runs of an explorer drive different paths), and other 2-D
SLAM packages that read Carmen logs find the raw dead reckoning in the ``FLASER`` lines'
odometry fields (the ``ODOM`` lines are re-anchored at the true poses, below).

The log follows the conventions :func:`~vslam_gym.logs.read_carmen` reads (those of the
Radish "corrected" logs):

- ``PARAM`` lines: ``laser_front_laser_fov`` and ``laser_front_laser_resolution`` [deg]
  (the beam geometry), ``laser_front_laser_max_range`` [m] (the reading of a beam
  without return) and ``robot_frontlaser_offset`` [m] (0: the simulator's lidar sits at
  the robot centre);
- one ``FLASER`` per scan: its ranges right to left (Carmen's order; the scans given
  here are left to right, descending bearing, as the simulator and :class:`CarmenLog`
  hold them), the true pose (the "corrected" pose: ground truth, which the metrics
  read), the dead-reckoning odometry pose, and a timestamp;
- before every scan after the first one ``ODOM`` line: the odometry's motion since the
  previous scan, re-anchored at that scan's true pose (as the Radish logs re-anchor
  their ``ODOM`` at every scan), with its mean velocities ``tv`` (negative when the
  robot drove backwards) and ``rv``, so that :func:`~vslam_gym.logs.logged_increments`
  returns the odometry increments the filter got in the loop (reverses included).

Numbers are written in Python's shortest exact form: the log reads back to the same
floats (the increments to the last bits of the pose composition).

Frames and units: world frame (x, y [m], theta [rad] counter-clockwise); ranges [m];
bearings [rad] in the lidar frame, counter-clockwise from its x axis; timestamps [s].
"""

from __future__ import annotations

import gzip
import math
import os
from pathlib import Path

import numpy as np

from vslam_gym.logs.carmen import (
    PARAM_FOV,
    PARAM_LASER_OFFSET,
    PARAM_MAX_RANGE,
    PARAM_RESOLUTION,
)
from vslam_gym.slam.motion import compose, inverse

__all__ = ["CarmenRecorder", "write_carmen"]

BEARING_SPACING_TOLERANCE = 1e-9
"""Largest deviation [rad] of a beam from an even spacing that the writer accepts."""
BEAM_GEOMETRY_DIGITS = 12
"""Significant digits of the field of view and resolution [deg] in the ``PARAM`` lines
(round numbers such as 180 and 1 come out exact; the beams are checked against them)."""
HOST = "vslam-gym"
"""The host field of every written line."""


def _check_poses(name: str, poses: np.ndarray, count: int) -> np.ndarray:
    """``poses`` as a finite ``(count, 3)`` float array, else a ValueError naming ``name``."""
    arr = np.asarray(poses, dtype=float)
    if arr.shape != (count, 3) or not np.isfinite(arr).all():
        raise ValueError(f"{name} must be a finite ({count}, 3) array, got shape {arr.shape}")
    return arr


def _beam_geometry(bearings: np.ndarray) -> tuple[float, float]:
    """``(fov [deg], resolution [deg])`` of Carmen's convention for descending ``bearings``.

    Carmen's beam ``i`` (right to left) has bearing ``-fov / 2 + i * res``; the beams
    must therefore be evenly spaced with the rightmost at ``-fov / 2``. Both are rounded
    to :data:`BEAM_GEOMETRY_DIGITS` significant digits.
    """
    if bearings.ndim != 1 or bearings.size < 2 or not np.isfinite(bearings).all():
        raise ValueError(
            f"bearings must be a finite 1-D array of at least 2 beams, got shape {bearings.shape}"
        )
    carmen = bearings[::-1]
    res = float(f"{math.degrees(float(np.diff(carmen).mean())):.{BEAM_GEOMETRY_DIGITS}g}")
    fov = float(f"{math.degrees(-2.0 * float(carmen[0])):.{BEAM_GEOMETRY_DIGITS}g}")
    expected = np.deg2rad(-fov / 2.0 + res * np.arange(carmen.size))
    if res <= 0.0 or np.abs(carmen - expected).max() > BEARING_SPACING_TOLERANCE:
        raise ValueError(
            "bearings must be evenly spaced and descending (left to right), the rightmost "
            "at minus half the field of view"
        )
    return fov, res


def write_carmen(
    path: str | os.PathLike[str],
    ranges: np.ndarray,
    bearings: np.ndarray,
    poses: np.ndarray,
    odometry_poses: np.ndarray,
    max_range: float,
    period: float = 0.1,
) -> Path:
    """Write ``N`` scans as a Carmen log (gzipped when ``path`` ends in ``.gz``).

    Args:
        path: the file to write (its directory must exist).
        ranges: ``(N, n)`` ranges [m], descending bearing (left to right); a beam without
            return reads ``max_range``.
        bearings: ``(n,)`` the beams' bearings [rad], descending and evenly spaced, the
            rightmost at minus half the field of view (Carmen's convention; the
            simulator's lidar: ``+90 .. -90 deg``).
        poses: ``(N, 3)`` true poses of the scans (the log's ground truth).
        odometry_poses: ``(N, 3)`` the wheel odometry's dead-reckoning poses at the scans.
        max_range: the no-return reading [m] (``laser_front_laser_max_range``).
        period: seconds between scans (the timestamps are ``k * period``).

    Returns:
        The path written.

    Raises:
        ValueError: arrays of the wrong shape, non-finite or negative values, ranges above
            ``max_range``, bearings not in Carmen's convention, or a non-positive
            ``max_range`` or ``period``.
    """
    scans = np.asarray(ranges, dtype=float)
    if scans.ndim != 2 or scans.shape[0] < 1:
        raise ValueError(f"ranges must be an (N, n) array with N >= 1, got shape {scans.shape}")
    beams = np.asarray(bearings, dtype=float)
    if beams.shape != (scans.shape[1],):
        raise ValueError(f"bearings must have shape ({scans.shape[1]},), got {beams.shape}")
    if not (math.isfinite(max_range) and max_range > 0.0):
        raise ValueError(f"max_range must be finite and > 0, got {max_range!r}")
    if not (math.isfinite(period) and period > 0.0):
        raise ValueError(f"period must be finite and > 0, got {period!r}")
    if not np.isfinite(scans).all() or (scans < 0.0).any() or (scans > max_range).any():
        raise ValueError(f"ranges must be finite and within [0, max_range={max_range}] m")
    fov, res = _beam_geometry(beams)
    true = _check_poses("poses", poses, scans.shape[0])
    odometry = _check_poses("odometry_poses", odometry_poses, scans.shape[0])

    def num(values: np.ndarray | list[float]) -> str:
        return " ".join(repr(float(v)) for v in values)

    lines = [
        "# vslam-gym: scans with true poses (FLASER pose) and wheel odometry (FLASER odom, ODOM)",
        "# message formats defined: PARAM ODOM FLASER",
        f"PARAM {PARAM_FOV} {fov!r} {HOST} 0.0",
        f"PARAM {PARAM_RESOLUTION} {res!r} {HOST} 0.0",
        f"PARAM {PARAM_MAX_RANGE} {float(max_range)!r} {HOST} 0.0",
        f"PARAM {PARAM_LASER_OFFSET} 0.0 {HOST} 0.0",
    ]
    for k in range(scans.shape[0]):
        stamp = repr(k * float(period))
        if k > 0:  # the odometry's motion since scan k - 1, re-anchored at its true pose
            relative = compose(inverse(odometry[k - 1]), odometry[k])
            moved = compose(true[k - 1], relative)
            tv = math.copysign(math.hypot(relative[0], relative[1]), relative[0]) / period
            speeds = num([tv, relative[2] / period, 0.0])
            lines.append(f"ODOM {num(moved)} {speeds} {stamp} {HOST} {stamp}")
        flaser = f"{scans.shape[1]} {num(scans[k, ::-1])} {num(true[k])} {num(odometry[k])}"
        lines.append(f"FLASER {flaser} {stamp} {HOST} {stamp}")
    text = "\n".join(lines) + "\n"
    out = Path(path)
    if out.suffix == ".gz":
        with gzip.open(out, "wt", encoding="utf-8") as fh:
            fh.write(text)
    else:
        out.write_text(text, encoding="utf-8")
    return out


class CarmenRecorder:
    """Collect an episode's scans and poses step by step; write them as a Carmen log.

    Add the scan taken at ``reset`` and the one after every ``step``::

        recorder = CarmenRecorder(info["bearings"], env.unwrapped.lidar_spec.max_range)
        recorder.add(env.unwrapped.scan.ranges, info["pose"], info["odom_pose"])
        ...  # after every step, the same call
        recorder.write("episode.log.gz")

    Args:
        bearings: ``(n,)`` the beams' bearings [rad], descending (:func:`write_carmen`).
        max_range: the lidar's no-return reading [m].
        period: seconds between scans (the env's ``control_period``).
    """

    def __init__(self, bearings: np.ndarray, max_range: float, period: float = 0.1) -> None:
        self.bearings = np.asarray(bearings, dtype=float).copy()
        _beam_geometry(self.bearings)  # validates
        self.max_range = float(max_range)
        self.period = float(period)
        self._ranges: list[np.ndarray] = []
        self._poses: list[np.ndarray] = []
        self._odometry: list[np.ndarray] = []

    def __len__(self) -> int:
        """Scans recorded so far."""
        return len(self._ranges)

    def add(self, ranges: np.ndarray, pose: np.ndarray, odometry_pose: np.ndarray) -> None:
        """Record one scan ``(n,)`` [m], its true pose and its odometry pose ``(3,)``.

        Raises:
            ValueError: a scan of another length than the bearings, or a pose that is not
                three finite numbers (nothing is recorded then).
        """
        scan = np.asarray(ranges, dtype=float).copy()
        if scan.shape != self.bearings.shape:
            raise ValueError(f"ranges must have shape {self.bearings.shape}, got {scan.shape}")
        true, odo = (
            _check_poses(name, np.asarray(value, dtype=float).reshape(1, -1), 1)[0].copy()
            for name, value in (("pose", pose), ("odometry_pose", odometry_pose))
        )
        self._ranges.append(scan)
        self._poses.append(true)
        self._odometry.append(odo)

    def write(self, path: str | os.PathLike[str]) -> Path:
        """Write what was recorded (:func:`write_carmen`); returns the path.

        Raises:
            ValueError: nothing recorded yet, or invalid recorded values.
        """
        if not self._ranges:
            raise ValueError("nothing recorded: add at least one scan before writing")
        return write_carmen(
            path,
            np.array(self._ranges),
            self.bearings,
            np.array(self._poses),
            np.array(self._odometry),
            self.max_range,
            self.period,
        )
