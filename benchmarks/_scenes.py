"""Known geometry for estimator benchmarks: a tiny exact ray caster and the zig-zag scene.

Benchmarks do not import from ``tests/``; this is their own small copy of the idea.
"""

from __future__ import annotations

import numpy as np

from vslam_gym.slam.config import SensorConfig
from vslam_gym.slam.scan import Scan

# An open zig-zag of four segments (like thesis figure 3.7), world frame [m].
ZIGZAG = np.array([(-3.0, 5.0), (-1.0, 6.5), (1.0, 5.5), (3.0, 7.0), (5.0, 6.0)])
ZIGZAG_EDGES = np.stack([ZIGZAG[:-1], ZIGZAG[1:]], axis=1)
# Lidar poses [x, y, theta] from which 60 (181-beam, 1 deg) beams hit the zig-zag: the
# model is built at the first, detected and updated at the second.
POSE_BUILD = np.array([1.0, -1.5, np.pi / 2])
POSE_UPDATE = np.array([1.3, -1.2, np.pi / 2 + 0.05])


def bearings(sensor: SensorConfig) -> np.ndarray:
    """Descending nominal bearings [rad] spanning the sensor's field of view."""
    n = int(round(sensor.fov_deg / sensor.resolution_deg)) + 1
    return np.linspace(sensor.half_fov, -sensor.half_fov, n)


def cast(pose: np.ndarray, edges: np.ndarray, phi: np.ndarray, max_range: float) -> np.ndarray:
    """Exact ranges [m] of beams at bearings ``phi`` [rad] from ``pose`` against segments
    ``edges`` ``(E, 2, 2)``; ``max_range`` where nothing is hit."""
    ang = pose[2] + phi
    d = np.stack([np.cos(ang), np.sin(ang)], axis=1)[:, None, :]  # (n, 1, 2)
    a, e = edges[None, :, 0], edges[None, :, 1] - edges[None, :, 0]  # (1, E, 2)
    w = a - pose[:2]

    def cross(p, q):
        return p[..., 0] * q[..., 1] - p[..., 1] * q[..., 0]

    den = cross(d, e)
    with np.errstate(divide="ignore", invalid="ignore"):
        t, s = cross(w, e) / den, cross(w, d) / den
    t = np.where((den != 0) & (t > 0) & (s >= 0) & (s <= 1), t, np.inf).min(axis=1)
    return np.minimum(t, max_range)


def noisy_scan(
    pose: np.ndarray, edges: np.ndarray, sensor: SensorConfig, rng: np.random.Generator
) -> Scan:
    """A scan with the sensor's range and bearing noise (the cast direction is perturbed,
    the reported bearing is nominal)."""
    phi = bearings(sensor)
    r = cast(pose, edges, phi + rng.normal(0.0, sensor.sigma_bearing, phi.shape), sensor.max_range)
    hit = r < sensor.max_range
    r = np.where(hit, r + rng.normal(0.0, sensor.sigma_range, r.shape), r)
    return Scan.from_arrays(np.clip(r, 0.0, sensor.max_range), phi, sensor)


def segment(scan: Scan) -> tuple[int, int]:
    """``(first, last)`` beam of the scan's one contiguous run of returns."""
    idx = np.flatnonzero(scan.returns)
    if idx.size == 0 or np.any(np.diff(idx) != 1):
        raise ValueError("the scene must give one contiguous segment of returns")
    return int(idx[0]), int(idx[-1])
