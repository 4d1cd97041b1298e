"""Covered duplicates: how much of one landmark's object boundary another one models.

A light form of the thesis's future work "merging landmarks of one object" (SPEC
section 11): a landmark whose object lines lie (almost) entirely on another landmark's
object lines adds nothing to the map that the other does not hold, and the filter may
remove it (``FilterConfig.prune_covered_distance``). This module holds the sampling and
the coverage measure (vertex means only, world frame, metres); the point-to-line
distances and the state surgery are the filter's.
"""

from __future__ import annotations

import numpy as np

from vslam_gym.slam.landmark import LandmarkModel

__all__ = ["covered_fraction", "object_segments", "sample_segments"]


def object_segments(model: LandmarkModel, unknown_threshold: float) -> np.ndarray:
    """``(m, 2, 2)`` start and end vertex means [m] of the model's object lines.

    Object lines are those with ``u <= unknown_threshold``; ``m`` may be 0.
    """
    lines = model.line_vertices()[model.u <= unknown_threshold]
    return model.mean[lines] if lines.size else np.zeros((0, 2, 2))


def sample_segments(segments: np.ndarray, spacing: float) -> tuple[np.ndarray, np.ndarray]:
    """Points along segments, at most ``spacing`` [m] apart, and the length each stands for.

    Args:
        segments: ``(m, 2, 2)`` start and end points [m].
        spacing: the largest distance [m] between neighbouring samples of a segment, > 0.

    Returns:
        ``(points (p, 2), weights (p,))``: each segment's samples include both ends and
        share its length equally, so ``weights.sum()`` is the total length [m].
    """
    if segments.shape[0] == 0:
        return np.zeros((0, 2)), np.zeros(0)
    start, end = segments[:, 0], segments[:, 1]
    length = np.hypot(*(end - start).T)
    counts = np.maximum(np.ceil(length / spacing).astype(int), 1) + 1
    seg = np.repeat(np.arange(segments.shape[0]), counts)
    first = np.repeat(np.cumsum(counts) - counts, counts)
    t = (np.arange(seg.size) - first) / (counts[seg] - 1)
    points = start[seg] + t[:, None] * (end - start)[seg]
    return points, (length / counts)[seg]


def covered_fraction(weights: np.ndarray, distances: np.ndarray, distance: float) -> float:
    """Length-weighted fraction of sampled object lines within ``distance`` [m] of another's.

    Args:
        weights: ``(p,)`` the length [m] each sample of one landmark's object lines stands
            for (:func:`sample_segments`).
        distances: ``(p,)`` each sample's distance [m] to the other landmark's nearest
            object line.
        distance: largest distance [m] that counts as covered.

    Returns:
        A fraction in ``[0, 1]``; 0 when there is nothing to cover.
    """
    total = float(weights.sum())
    if total <= 0.0:
        return 0.0
    return float(weights[distances <= distance].sum()) / total
