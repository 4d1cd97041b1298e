"""Which bearing convention a log's scans share with its reference poses.

A uniform offset of every bearing (a logger's convention for where the first beam points,
or a lidar mounted turned by a small angle) cannot be seen in the scans alone: it turns
every scan alike. It shows against poses measured otherwise. Move scan ``k + lag`` into
scan ``k``'s frame by the log's reference poses: when the bearings are right the two
scans overlap; with an offset ``d`` the relative translation ``t`` between them seems
turned by ``d`` (turning both scans by ``d`` is, up to a rotation of the whole pair, the
same as turning ``t`` by ``-d``) and the scans are about ``d |t|`` apart across their
surfaces (measured point to line, as the whole-scan matcher does: point to point, the
beam spacing would hide it). :func:`bearing_offset_scores` measures that overlap for a
list of candidate offsets; the best is the offset the reference poses were made with (for
:class:`~vslam_gym.logs.carmen.CarmenConfig`'s ``bearing_offset_deg``). Measured on the
Radish logs in docs/radish.md ("The bearing convention").

Frames and units: the log's world frame; distances [m]; offsets [deg] added to the
log's bearings (counter-clockwise). numpy/scipy only.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from scipy.spatial import cKDTree

from vslam_gym.logs.carmen import CarmenLog
from vslam_gym.slam.geometry import polar_to_cartesian
from vslam_gym.slam.motion import compose, inverse
from vslam_gym.slam.scan_matching import ScanMatcherConfig, scan_normals

__all__ = ["DEFAULT_OFFSETS_DEG", "bearing_offset_scores"]

DEFAULT_OFFSETS_DEG = (-1.0, -0.5, 0.0, 0.5, 1.0)
"""Candidate offsets [deg]: Carmen's convention and half and whole beams either way."""


def bearing_offset_scores(
    log: CarmenLog,
    offsets_deg: Sequence[float] = DEFAULT_OFFSETS_DEG,
    lag: int = 5,
    stride: int = 2,
    max_range: float = 20.0,
    max_distance: float = 0.3,
    min_points: int = 20,
) -> np.ndarray:
    """Median distance [m] between scans ``lag`` apart at the reference poses, per offset.

    For every ``stride``-th scan ``k``, the returns of scan ``k + lag`` (within
    ``max_range``) are moved into scan ``k``'s frame by the lidar poses
    ``P (+) log.lidar_offset`` of ``log.poses`` and each is matched to its nearest return of
    scan ``k`` that has a surface normal (the whole-scan matcher's,
    :func:`~vslam_gym.slam.scan_matching.scan_normals`); the distance is taken along that
    normal. Matches beyond ``max_distance`` (the other scan did not see that surface) are
    left out. Pairs where either scan has fewer than ``min_points`` returns are skipped.
    The lowest median marks the offset the poses agree with; a few millimetres between
    neighbouring offsets are a clear difference (docs/radish.md, "The bearing
    convention").

    Args:
        log: the log (its ``bearings``, ``ranges``, ``no_return`` and ``poses``).
        offsets_deg: candidate offsets [deg] added to every bearing.
        lag: scans between the two of a pair (larger: longer baselines, less overlap).
        stride: every this-many-th scan starts a pair.
        max_range: returns beyond this [m] are not used (their spacing is coarse).
        max_distance: returns whose nearest return of the other scan lies farther [m]
            are not counted.
        min_points: least returns a scan of a pair needs.

    Returns:
        ``(len(offsets_deg),)`` median distances [m] (NaN when no pair qualifies).

    Raises:
        ValueError: ``lag`` or ``stride`` below 1, ``max_range``, ``max_distance`` not
            finite and > 0, ``min_points`` below 1, or a non-finite offset.
    """
    if lag < 1 or stride < 1 or min_points < 1:
        raise ValueError(
            f"lag, stride and min_points must be >= 1, got {lag}, {stride}, {min_points}"
        )
    for name, value in (("max_range", max_range), ("max_distance", max_distance)):
        if not (np.isfinite(value) and value > 0):
            raise ValueError(f"{name} must be finite and > 0, got {value!r}")
    offsets = np.asarray(offsets_deg, dtype=float).reshape(-1)
    if not np.all(np.isfinite(offsets)):
        raise ValueError(f"offsets_deg must be finite, got {list(offsets_deg)}")
    keep = ~log.no_return & (log.ranges <= max_range)
    pairs = [
        k
        for k in range(0, log.num_scans - lag, stride)
        if keep[k].sum() >= min_points and keep[k + lag].sum() >= min_points
    ]
    normal_config = ScanMatcherConfig()  # the matcher's normal fit, as it sees surfaces
    lidar = np.asarray(log.lidar_offset, dtype=float)
    turns = np.deg2rad(offsets)
    distances: list[list[np.ndarray]] = [[] for _ in offsets]
    for k in pairs:  # each pair's surfaces once; an offset only turns the translation
        earlier = polar_to_cartesian(log.ranges[k, keep[k]], log.bearings[keep[k]], np.zeros(3))
        fit = scan_normals(earlier, normal_config)
        if not fit.valid.any():
            continue
        surface, normals = earlier[fit.valid], fit.normals[fit.valid]
        tree = cKDTree(surface)
        relative = compose(
            inverse(compose(log.poses[k], lidar)), compose(log.poses[k + lag], lidar)
        )
        later = keep[k + lag]
        for i, turn in enumerate(turns):
            c, s = np.cos(turn), np.sin(turn)
            x, y = relative[0] * c + relative[1] * s, -relative[0] * s + relative[1] * c
            moved = polar_to_cartesian(
                log.ranges[k + lag, later], log.bearings[later], np.array([x, y, relative[2]])
            )
            d, j = tree.query(moved, distance_upper_bound=max_distance)
            near = np.isfinite(d)
            across = np.einsum("ij,ij->i", moved[near] - surface[j[near]], normals[j[near]])
            distances[i].append(np.abs(across))
    scores = np.full(offsets.size, np.nan)
    for i, found in enumerate(distances):
        if found:
            scores[i] = float(np.median(np.concatenate(found)))
    return scores
