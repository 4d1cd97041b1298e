"""Covered duplicates: how much of one landmark's object boundary another one models.

A light form of the thesis's future work "merging landmarks of one object" (SPEC
section 11): a landmark whose object lines lie (almost) entirely on another landmark's
object lines adds nothing to the map that the other does not hold, and the filter may
remove it (``FilterConfig.prune_covered_distance``); with ``prune_merge`` the offset
between the two (:func:`fit_translation`) is first fused into the state as a relative
measurement of their references. This module holds the sampling, the coverage measure
and the offset fit (vertex means only, world frame, metres); the state surgery is the
filter's.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vslam_gym.slam.icp import LineGeometry, segment_offsets
from vslam_gym.slam.landmark import LandmarkModel

__all__ = [
    "TranslationFit",
    "covered_fraction",
    "fit_translation",
    "object_segments",
    "sample_segments",
]

MIN_NORMAL_COS = float(np.cos(np.deg2rad(30.0)))
"""A sample is matched only to lines whose free-side normal is within 30 degrees of its
own line's: the two faces of a thin wall are never matched."""
MIN_CONSTRAINT = 0.05
"""An offset direction is constrained when at least this fraction of the matched length
has its normal along it (eigenvalue of the normalised normal scatter): a straight wall
constrains only its normal direction."""
FIT_ITERATIONS = 10
"""Match-and-solve rounds of :func:`fit_translation`."""
FIT_TOLERANCE = 1e-4
"""A round that moves the offset less than this [m] ends the fit."""


def object_segments(model: LandmarkModel, unknown_threshold: float) -> np.ndarray:
    """``(m, 2, 2)`` start and end vertex means [m] of the model's object lines.

    Object lines are those with ``u <= unknown_threshold``; ``m`` may be 0.
    """
    lines = model.line_vertices()[model.u <= unknown_threshold]
    return model.mean[lines] if lines.size else np.zeros((0, 2, 2))


def sample_segments(
    segments: np.ndarray, spacing: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Points along segments, at most ``spacing`` [m] apart, and the length each stands for.

    Args:
        segments: ``(m, 2, 2)`` start and end points [m].
        spacing: the largest distance [m] between neighbouring samples of a segment, > 0.

    Returns:
        ``(points (p, 2), weights (p,), segment (p,))``: each segment's samples include
        both ends and share its length equally, so ``weights.sum()`` is the total length
        [m]; ``segment`` is the index of the segment each sample lies on.
    """
    if segments.shape[0] == 0:
        return np.zeros((0, 2)), np.zeros(0), np.zeros(0, dtype=int)
    start, end = segments[:, 0], segments[:, 1]
    length = np.hypot(*(end - start).T)
    counts = np.maximum(np.ceil(length / spacing).astype(int), 1) + 1
    seg = np.repeat(np.arange(segments.shape[0]), counts)
    first = np.repeat(np.cumsum(counts) - counts, counts)
    t = (np.arange(seg.size) - first) / (counts[seg] - 1)
    points = start[seg] + t[:, None] * (end - start)[seg]
    return points, (length / counts)[seg], seg


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


@dataclass(frozen=True)
class TranslationFit:
    """The offset that moves one landmark's object lines onto another's (:func:`fit_translation`).

    Attributes:
        offset: ``(2,)`` [m], world frame: sampled points ``+ offset`` lie on the other
            landmark's lines. Zero along unconstrained directions.
        directions: ``(2, k)`` orthonormal directions the matched lines constrain
            (``k`` in 0..2): the offset is measured along these only.
        distances: ``(p,)`` each sample's distance [m] after the offset to the nearest
            other line facing the same way (``inf`` when none does).
    """

    offset: np.ndarray
    directions: np.ndarray
    distances: np.ndarray


def _nearest_facing(
    points: np.ndarray, normals: np.ndarray, lines: LineGeometry
) -> tuple[np.ndarray, np.ndarray]:
    """Index and distance of each point's nearest line facing its way (inf: none)."""
    dx, dy = segment_offsets(
        points[:, 0, None], points[:, 1, None],
        lines.ax, lines.ay, lines.abx, lines.aby, lines.inv_length2,
    )  # fmt: skip
    facing = normals[:, 0, None] * lines.nx + normals[:, 1, None] * lines.ny >= MIN_NORMAL_COS
    d2 = np.where(facing, dx * dx + dy * dy, np.inf)
    j = np.argmin(d2, axis=1)
    return j, np.sqrt(d2[np.arange(j.size), j])


def fit_translation(
    points: np.ndarray,
    weights: np.ndarray,
    normals: np.ndarray,
    lines: LineGeometry,
    max_distance: float,
) -> TranslationFit:
    """Least-squares translation of samples onto lines, point to line (translation-only ICP).

    Each round matches every sample to the nearest line segment whose normal is within 30
    degrees of the sample's (:data:`MIN_NORMAL_COS`), uses the matches within
    ``max_distance`` [m], and solves ``min sum w (n . (p + t - a))^2`` for ``t`` in the
    directions the matched normals constrain (:data:`MIN_CONSTRAINT`); a straight wall
    fixes only its normal offset.

    Args:
        points: ``(p, 2)`` samples of one landmark's object lines [m] (world frame).
        weights: ``(p,)`` the length each sample stands for [m].
        normals: ``(p, 2)`` free-side normal of each sample's line (the ICP's
            convention, :data:`~vslam_gym.slam.icp.LineGeometry` ``nx, ny``).
        lines: the other landmark's object lines (``LineGeometry``, at least one).
        max_distance: matches farther than this [m] are not used.

    Returns:
        The offset, its constrained directions and the distances after it.
    """
    line_normals = np.stack([lines.nx, lines.ny], axis=1)
    t = np.zeros(2)
    directions = np.zeros((2, 0))
    for _ in range(FIT_ITERATIONS):
        p = points + t
        j, dist = _nearest_facing(p, normals, lines)
        use = dist <= max_distance
        if not np.any(use):
            return TranslationFit(np.zeros(2), np.zeros((2, 0)), dist)
        n, w, k = line_normals[j[use]], weights[use], j[use]
        e = (p[use, 0] - lines.ax[k]) * n[:, 0] + (p[use, 1] - lines.ay[k]) * n[:, 1]  # > 0 free
        scatter = (n * w[:, None]).T @ n
        vals, vecs = np.linalg.eigh(scatter / w.sum())
        directions = vecs[:, vals >= MIN_CONSTRAINT]
        if directions.shape[1] == 0:
            break
        # t in span(directions): (D^T M D) c = -D^T sum w e n
        rhs = -directions.T @ (n.T @ (w * e))
        c = np.linalg.solve(directions.T @ scatter @ directions, rhs)
        step = directions @ c
        t = t + step
        if np.hypot(*step) < FIT_TOLERANCE:
            break
    _, dist = _nearest_facing(points + t, normals, lines)
    return TranslationFit(t, directions, dist)
