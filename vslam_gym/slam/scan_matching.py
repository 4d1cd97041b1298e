"""Whole-scan alignment to a local map of recent scans (issue #6; thesis future work).

The per-landmark ICP of the filter (:mod:`vslam_gym.slam.icp`) starts from the predicted
pose and converges only within a few degrees of it. On real logs consecutive scans are
10-36 degrees apart and synthetic odometry is off by 6-10 degrees per step, so it locks
onto wrong poses. This module aligns ALL points of a scan jointly to a local map:

1. the local map (:class:`LocalMap`) keeps the points of the last ``keyframes`` scans,
   each with a unit normal fitted to its neighbouring beams (:func:`scan_normals`),
   placed at the pose the caller gives; one ``scipy.spatial.cKDTree`` per map state;
2. :func:`match_scan` starts a robust (Cauchy) point-to-line Gauss-Newton from several
   heading hypotheses spread over ``+- heading_sigmas`` standard deviations of the
   predicted heading, all hypotheses in one batch;
3. the hypothesis with the largest inlier fraction wins; the match is declined (None)
   when too few points agree, when a clearly different pose agrees almost as well
   (ambiguous), or when the normals cannot fix the translation (a corridor);
4. the covariance is the Gauss-Newton one, ``sigma^2 H^-1`` with the robust residual
   variance, inflated (neighbouring residuals are correlated and the map has errors)
   and floored.

By default the predicted pose is also a Gaussian term of the cost (maximum a
posteriori): in a corridor the scan fixes the heading and the cross-corridor position,
the prior the position along it.

Frames and units: poses ``[x, y, theta]`` ([m], [m], [rad]) of the lidar in the frame
of the map; scan points in the lidar frame [m]. Pure numpy/scipy.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from scipy.spatial import cKDTree

from vslam_gym.config_utils import check_field_types, check_integers, dataclass_from_dict
from vslam_gym.slam.geometry import check_pose, polar_to_cartesian, stack_last, wrap_angle

__all__ = [
    "LocalMap",
    "MatchResult",
    "Reference",
    "ScanMatcherConfig",
    "ScanNormals",
    "distinct_poses",
    "local_fit",
    "match_scan",
    "match_scan_why",
    "scan_normals",
    "scan_points",
]


AMBIGUITY_MODES = ("decline", "prior")
"""``ScanMatcherConfig.on_ambiguity``."""
HYPOTHESIS_SPACINGS = ("span", "step")
"""``ScanMatcherConfig.hypothesis_spacing``."""
PSD_TOLERANCE = 1e-9
"""Relative negative eigenvalue of ``prior_cov`` still accepted as round-off."""


@dataclass(frozen=True)
class ScanMatcherConfig:
    """Parameters of the whole-scan matcher (not thesis values; measured on the logs).

    Attributes:
        keyframes: keyframes kept in the local map (the last ones); the default preset
            keeps 40 (``vslam_gym.slam.filter.DEFAULT_MATCHER_KEYFRAMES``: a longer
            memory drifts less when the robot drives back and forth), the ``logs`` and
            ``fast`` presets 20.
        keyframe_distance: a scan becomes a keyframe only when its pose is at least this
            far [m] from the last keyframe's ...
        keyframe_heading_deg: ... or turned at least this much [deg] from it; with both
            0 every scan is a keyframe (the local map is the last ``keyframes`` scans).
            Measured no better on the Radish logs (1 m / 15 deg, ``on_ambiguity=
            "prior"``, ACES synthetic seeds 0-4 mean 1.81 m against 1.49 m, logged 1.10
            against 1.61 m): both 0 in every preset.
        revisit_radius: besides the last ``keyframes``, the local map holds the older
            keyframes whose pose lies within this distance [m] of the predicted pose
            (an implicit loop closure when the drift is small on a revisit); 0: off.
            Measured (matcher alone, full Radish logs, ``on_ambiguity="prior"``,
            synthetic seeds 0-4 mean / logged odometry, position ATE [m]): off: Intel
            0.81 / 0.76, ACES 1.49 / 1.61; 3 m (the ``logs`` preset): 0.59 / 0.67, 1.37 /
            1.61; 5 m: 0.62 / 0.69, 1.53 / 1.55. With ``on_ambiguity="decline"`` it
            measured much worse (5 m: Intel 6.8 m, a declined step falls back to
            odometry several degrees off and the map then disagrees with itself).
        revisit_max_keyframes: at most this many older keyframes (the nearest ones).
        coarse_stride: in the coarse phase (every hypothesis) every this-many-th return
            of the current scan is aligned (speed); the refinement uses every return and
            the local map keeps every return.
        normal_half_windows: a point's normal is fitted to the returns up to ``w``
            beams on each side of it, for the first ``w`` of these whose patch is ...
        normal_min_extent: ... at least this long [m] (about: twice the standard
            deviation of the points along the patch),
        normal_max_radius: ... has every point within this distance [m] of the centre
            point,
        normal_max_flatness: ... and whose scatter's smaller eigenvalue is at most this
            fraction of the larger (straight); else the point has no normal.
        fit_keyframe_points: each point a keyframe keeps is moved onto the parabola
            fitted to its normal's patch (its noise across the surface mostly removed),
            so that a scan point's residual to its nearest map point holds less of that
            point's noise; False: the raw returns (every preset). Measured in session
            34 (docs/measurements.md, "Session 34"): the ``frontier`` explorer's mean
            pose NEES on 60 held-out worlds 29.4 -> 15.2 at level coverage and ATE,
            but the routes no better (single_landmark position ATE 0.096 -> 0.110 m).
        normal_agreement_deg: a scan point and its nearest map point correspond only
            when their normals, each turned toward the lidar that saw it, are at most
            this far apart [deg] (a thin wall's other face, or a neighbour across a
            corner, is no correspondence); a point without a normal keeps its
            correspondence. 30 in the ``logs`` preset (Radish logs, logged odometry:
            position ATE Intel 0.68 -> 0.41 m, ACES 1.03 -> 0.62 m), 0 (off) in the
            others: on the simulated worlds it measured level (docs/measurements.md,
            "Session 39").
        heading_sigmas: heading hypotheses span ``+- heading_sigmas * sigma_theta`` of
            the predicted heading.
        heading_step_deg: spacing [deg] of the hypotheses (well inside the convergence
            basin of the Gauss-Newton, about 5-10 deg indoors).
        max_hypotheses: at most this many hypotheses (the span is covered evenly).
        hypothesis_spacing: ``"span"``: ``2 ceil(span / step) + 1`` hypotheses spread
            evenly over the span, so at least three whenever the heading is uncertain
            (1 deg apart for a heading sigma of 0.25 deg: the same basin three times);
            ``"step"``: hypotheses exactly ``heading_step_deg`` apart within the span,
            one (the prediction) when the span is narrower than a step. Measured on the
            default (docs/measurements.md, "Heading hypotheses a step apart"): 5-8 %
            less filter time, single_landmark ATE 0.111 -> 0.090 m, the other routes
            level, but the ``frontier`` explorer's ATE 0.077 -> 0.113 m: not adopted.
        coarse_iterations: Gauss-Newton steps of the coarse phase, with the
            correspondence gate shrinking linearly from ``max_distance_start`` to
            ``max_distance_mid`` [m].
        coarse_keep: with ``coarse_keep_after`` > 0, after that many coarse steps only
            this many hypotheses (those with the most inliers at that step; ties: the
            first) go on ...
        coarse_keep_after: ... to the remaining coarse steps (speed: far-off headings
            are dropped early); 0: every hypothesis takes every step.
        refine_candidates: the coarse poses are merged (same pose within
            ``merge_translation`` [m] and ``merge_heading_deg`` [deg]) and this many with
            the largest inlier fractions are refined with every point ...
        refine_iterations: ... in this many steps, the gate shrinking from
            ``max_distance_mid`` to ``max_distance_end`` [m].
        refine_keep_after: with this > 0, after that many refinement steps only the
            candidates with at least ``refine_keep_ratio`` times the most inliers at that
            step go on (speed: a candidate that far behind is neither the winner nor an
            ambiguous rival, ``ambiguity_ratio``); 0: every candidate takes every step.
        refine_keep_ratio: see ``refine_keep_after``; in ``[0, 1]``.
        merge_translation: see ``refine_candidates``.
        merge_heading_deg: see ``refine_candidates``.
        converged_translation: a phase stops early when every pose's step is below this
            [m] ...
        converged_rotation: ... and this [rad].
        max_distance_start: see ``coarse_iterations``.
        max_distance_mid: see ``coarse_iterations``.
        max_distance_end: see ``refine_iterations``.
        robust_scale: Cauchy scale [m] of the point-to-line residuals.
        inlier_distance: a point within this distance [m] of its neighbour's line (and
            within ``max_distance_end``) is an inlier.
        min_points: fewer aligned points (or inliers) decline the match.
        min_inlier_fraction: the winning pose needs at least this fraction of the
            scan's aligned points as inliers.
        ambiguity_ratio: a hypothesis whose pose differs from the winner by more than
            ``ambiguity_translation`` or ``ambiguity_heading_deg`` and whose inlier
            fraction is at least this times the winner's makes the match ambiguous.
        ambiguity_translation: see ``ambiguity_ratio`` [m].
        on_ambiguity: what an ambiguous match returns: ``"decline"`` (None; the caller
            falls back to its prior) or ``"prior"`` (of the poses within
            ``ambiguity_ratio`` of the best inlier fraction, the one nearest the prior,
            Mahalanobis distance; reason ``"ambiguous_prior"``). Measured (matcher
            alone, full Radish logs, no revisits, synthetic seeds 0-4 mean / logged,
            position ATE [m]; decline -> prior): Intel 0.78 / 1.68 -> 0.81 / 0.76, ACES
            1.44 / 1.62 -> 1.49 / 1.61. ``"prior"`` in the ``logs`` preset.
        ambiguity_heading_deg: see ``ambiguity_ratio`` [deg].
        selection_points: 0 (every preset): the refined pose with the largest inlier
            fraction wins. Above 0 (with the prior): the pose with the largest
            ``selection_points * fraction - 0.5 * m2`` wins, ``m2`` its squared
            Mahalanobis distance from the prior: a maximum a posteriori choice with the
            scan's inliers counted as ``selection_points`` independent observations
            (neighbouring returns are correlated); the same score picks the coarse poses
            that are refined. Meant for a symmetric place (an orthogonal corridor
            junction) under a broad prior: on the Intel log, synthetic seed 7, scan 534 (a
            backward step, prior heading sigma 24 deg) a pose 90 deg off won by inliers
            0.861 to 0.828 against one 2 deg off, and the matcher alone ended at an ATE of
            13 m. Measured (full logs, synthetic seeds 0-9 mean / logged odometry,
            position ATE [m]; 0 -> 100): matcher alone Intel 1.81 / 0.67 -> 0.57 / 0.72
            (seed 7 13.3 -> 0.61, seed 2 0.45 -> 1.41), ACES 1.44 / 1.61 -> 1.45 / 2.01
            (150: Intel 0.57 / 0.72, ACES 1.61); the ``logs`` SLAM Intel 1.82 / 0.69 ->
            0.63 / 0.74, ACES 1.49 / 1.28 -> 1.53 / 2.42. It removes the Intel failure
            but is worse on ACES, above all with the real odometry: not in a preset.
        min_constraint: smallest eigenvalue of the inliers' normal scatter
            ``sum w n n^T / sum w``; a corridor (all normals parallel) has about 0 and
            is declined.
        covariance_inflation: the scan's information (``H / sigma^2``, sigma from the
            residuals) is divided by this: neighbouring residuals are correlated and
            the map has errors. The iterations weigh the scan with ``1 / robust_scale^2``
            (no inflation): measured on the logs, an inflated scan term lets the
            odometry prior pull the heading (ACES, 300 scans, seeds 0-2: scan-matching
            odometry ATE 1.2-1.7 m instead of 1.3-4.2 m).
        sigma_floor: the covariance gets at least these standard deviations ``(x [m],
            y [m], theta [rad])`` added on its diagonal; so does the prior (a turn on
            the spot has a singular odometry covariance).

    The defaults are the logs' (the ``logs`` and ``fast`` presets); the ``default``
    preset's ``SlamConfig.matcher`` has a tighter covariance (``sigma_floor``,
    ``covariance_inflation``: ``filter.DEFAULT_MATCHER_SIGMA_FLOOR``), measured on the
    simulated worlds.
    """

    keyframes: int = 20
    keyframe_distance: float = 0.0
    keyframe_heading_deg: float = 0.0
    revisit_radius: float = 0.0
    revisit_max_keyframes: int = 20
    coarse_stride: int = 3
    normal_half_windows: tuple[int, ...] = (2, 4, 8)
    normal_min_extent: float = 0.2
    normal_max_radius: float = 3.0
    normal_max_flatness: float = 0.02
    fit_keyframe_points: bool = False
    normal_agreement_deg: float = 0.0
    heading_sigmas: float = 4.0
    heading_step_deg: float = 5.0
    max_hypotheses: int = 25
    hypothesis_spacing: str = "span"
    coarse_iterations: int = 8
    coarse_keep: int = 6
    coarse_keep_after: int = 0
    refine_candidates: int = 3
    refine_iterations: int = 8
    refine_keep_after: int = 0
    refine_keep_ratio: float = 0.8
    merge_translation: float = 0.05
    merge_heading_deg: float = 1.0
    converged_translation: float = 1e-3
    converged_rotation: float = 1e-4
    max_distance_start: float = 1.0
    max_distance_mid: float = 0.5
    max_distance_end: float = 0.3
    robust_scale: float = 0.05
    inlier_distance: float = 0.1
    min_points: int = 20
    min_inlier_fraction: float = 0.15
    ambiguity_ratio: float = 0.97
    ambiguity_translation: float = 0.3
    ambiguity_heading_deg: float = 3.0
    on_ambiguity: str = "decline"
    selection_points: float = 0.0
    min_constraint: float = 0.05
    covariance_inflation: float = 10.0
    sigma_floor: tuple[float, float, float] = (0.01, 0.01, 0.002)

    def __post_init__(self) -> None:
        check_field_types(self)
        check_integers(
            self,
            {
                "keyframes": 1,
                "coarse_stride": 1,
                "coarse_iterations": 1,
                "coarse_keep": 1,
                "refine_candidates": 1,
                "refine_iterations": 1,
                "revisit_max_keyframes": 1,
                "coarse_keep_after": 0,
                "refine_keep_after": 0,
                "max_hypotheses": 1,
                "min_points": 3,
            },
        )
        for name in (
            "normal_min_extent",
            "normal_max_radius",
            "normal_max_flatness",
            "heading_sigmas",
            "heading_step_deg",
            "max_distance_start",
            "max_distance_mid",
            "max_distance_end",
            "robust_scale",
            "inlier_distance",
            "ambiguity_translation",
            "ambiguity_heading_deg",
            "covariance_inflation",
            "merge_translation",
            "merge_heading_deg",
            "converged_translation",
            "converged_rotation",
        ):
            value = getattr(self, name)
            if not (np.isfinite(value) and value > 0):
                raise ValueError(f"ScanMatcherConfig.{name} must be finite and > 0, got {value}")
        for name in (
            "keyframe_distance",
            "keyframe_heading_deg",
            "revisit_radius",
            "selection_points",
        ):
            value = getattr(self, name)
            if not (np.isfinite(value) and value >= 0):
                raise ValueError(f"ScanMatcherConfig.{name} must be finite and >= 0, got {value}")
        for name in (
            "min_inlier_fraction",
            "ambiguity_ratio",
            "min_constraint",
            "refine_keep_ratio",
        ):
            value = getattr(self, name)
            if not 0.0 <= value <= 1.0:
                raise ValueError(f"ScanMatcherConfig.{name} must lie in [0, 1], got {value}")
        if self.hypothesis_spacing not in HYPOTHESIS_SPACINGS:
            raise ValueError(
                f"ScanMatcherConfig.hypothesis_spacing must be one of {HYPOTHESIS_SPACINGS}, "
                f"got {self.hypothesis_spacing!r}"
            )
        if not (np.isfinite(self.normal_agreement_deg) and 0 <= self.normal_agreement_deg <= 90):
            raise ValueError(
                "ScanMatcherConfig.normal_agreement_deg must lie in [0, 90] (0: off), got "
                f"{self.normal_agreement_deg}"
            )
        if self.on_ambiguity not in AMBIGUITY_MODES:
            raise ValueError(
                f"ScanMatcherConfig.on_ambiguity must be one of {AMBIGUITY_MODES}, "
                f"got {self.on_ambiguity!r}"
            )
        if not self.normal_half_windows or any(int(w) < 1 for w in self.normal_half_windows):
            raise ValueError(
                "ScanMatcherConfig.normal_half_windows must be integers >= 1, got "
                f"{self.normal_half_windows}"
            )
        if len(self.sigma_floor) != 3 or not all(
            np.isfinite(v) and v >= 0 for v in self.sigma_floor
        ):
            raise ValueError(
                f"ScanMatcherConfig.sigma_floor must be 3 numbers >= 0, got {self.sigma_floor}"
            )

    @classmethod
    def from_dict(cls, data) -> ScanMatcherConfig:
        """Build from a mapping; unknown keys raise ``UnknownKeyError``."""
        return dataclass_from_dict(cls, data)


@dataclass(frozen=True)
class MatchResult:
    """A successful whole-scan alignment.

    Attributes:
        pose: ``(3,)`` aligned lidar pose in the map frame (heading wrapped).
        cov: ``(3, 3)`` its covariance (symmetric positive definite).
        inlier_fraction: fraction of the aligned points within ``inlier_distance``.
        n_points: points aligned.
        hypotheses: heading hypotheses tried.
    """

    pose: np.ndarray
    cov: np.ndarray
    inlier_fraction: float
    n_points: int
    hypotheses: int


def scan_points(ranges: np.ndarray, bearings: np.ndarray, max_range: float) -> np.ndarray:
    """``(m, 2)`` lidar-frame points [m] of the returns (``range < max_range``), beam order."""
    ranges = np.asarray(ranges, dtype=float)
    bearings = np.asarray(bearings, dtype=float)
    if ranges.shape != bearings.shape or ranges.ndim != 1:
        raise ValueError(
            f"ranges and bearings must be 1-D of equal length, got {ranges.shape}, {bearings.shape}"
        )
    hit = ranges < max_range
    return polar_to_cartesian(ranges[hit], bearings[hit], np.zeros(3))


class ScanNormals(NamedTuple):
    """A scan's surface normals and each point's offset from the curve fitted to its patch.

    Attributes:
        normals: ``(m, 2)`` unit normals, lidar frame, each facing the lidar (``n . p
            <= 0``); zero where not ``valid``.
        valid: ``(m,)`` bool, the point has a normal.
        offsets: ``(m,)`` signed distance [m] of each point, along its normal, from
            the parabola fitted to its patch in the patch's line frame (0 where not
            ``valid``): ``point - offset * normal`` lies on that curve. Computed only
            with ``ScanMatcherConfig.fit_keyframe_points`` (it doubles the time of
            :func:`scan_normals`); all zero otherwise.
    """

    normals: np.ndarray
    valid: np.ndarray
    offsets: np.ndarray


def scan_normals(points: np.ndarray, config: ScanMatcherConfig) -> ScanNormals:
    """Unit normals of a scan's points from their neighbouring beams.

    Each point tries the half-windows of ``normal_half_windows`` in order and keeps the
    first patch that is wide enough (``normal_min_extent``: dense beams near the lidar
    need more of them, or the range noise tilts the normal), close enough
    (``normal_max_radius``) and straight enough (``normal_max_flatness``). With
    ``fit_keyframe_points`` a parabola fitted to that patch in its line frame also gives
    the point's offset across the surface.

    Args:
        points: ``(m, 2)`` points [m] in beam order.
        config: the ``normal_*`` parameters and ``fit_keyframe_points``.

    Returns:
        :class:`ScanNormals` ``(normals (m, 2), valid (m,), offsets (m,))``, the normals
        facing the lidar (the offsets along them); invalid rows have zero normals and
        offsets.
    """
    points = np.asarray(points, dtype=float)
    m = points.shape[0]
    normals = np.zeros((m, 2))
    valid = np.zeros(m, dtype=bool)
    offsets = np.zeros(m)
    for w in config.normal_half_windows:
        rows = np.flatnonzero(~valid)  # still without a normal, the whole window inside
        rows = rows[(rows >= w) & (rows < m - w)]
        if rows.size == 0:
            break
        size = 2 * w + 1
        # (2w+1, r, 2), window-major: the patch mean is a fast sum over the first axis, in
        # the same order (neighbour by neighbour) as over the middle axis of (r, 2w+1, 2).
        nb = np.take(points, np.arange(-w, w + 1)[:, None] + rows[None, :], axis=0)
        offset = nb - points[rows]
        close = (np.hypot(offset[..., 0], offset[..., 1]) <= config.normal_max_radius).all(axis=0)
        d = nb - nb.sum(axis=0) / size  # means as sum / size: np.mean's steps
        dx, dy = d[..., 0].T, d[..., 1].T  # (r, 2w+1)
        # The moments sum each row of a C-ordered (r, 2w+1) array (numpy's pairwise sum).
        cxx = np.square(dx, order="C").sum(axis=1) / size
        cyy = np.square(dy, order="C").sum(axis=1) / size
        cxy = np.multiply(dx, dy, order="C").sum(axis=1) / size
        half_trace = 0.5 * (cxx + cyy)
        root = np.hypot(0.5 * (cxx - cyy), cxy)
        large, small = half_trace + root, half_trace - root
        wide = large >= (0.5 * config.normal_min_extent) ** 2  # std of a uniform patch
        flat = small <= config.normal_max_flatness * large
        ok = close & wide & flat
        direction = 0.5 * np.arctan2(2.0 * cxy[ok], cxx[ok] - cyy[ok])  # principal axis
        found = rows[ok]
        normals[found] = stack_last(-np.sin(direction), np.cos(direction))
        valid[found] = True
        if config.fit_keyframe_points:
            offsets[found] = _offsets_from_patch_curves(d[:, ok], normals[found], w)
    # Each normal faces the lidar (the sign is free for the point-to-line residual, whose
    # rows it only negates exactly; the normal agreement test needs it), and its offset,
    # measured along it, turns with it.
    away = np.einsum("ij,ij->i", points, normals) > 0.0
    normals[away] *= -1.0
    offsets[away] *= -1.0
    return ScanNormals(normals, valid, offsets)


def _offsets_from_patch_curves(d: np.ndarray, normals: np.ndarray, centre: int) -> np.ndarray:
    """Offset [m] of each patch's centre point from a parabola fitted to the patch.

    In each patch's own frame (``u`` along its line, ``v`` along its normal) the
    least-squares ``v = a + b u + c u^2``; the offset is the centre point's ``v`` minus
    the parabola's value there. A straight line would leave a point on a curved
    surface (a round obstacle) offset by a share of the patch's sagitta (about 1 cm
    for a 1 m radius seen from 3 m), the parabola does not.

    Args:
        d: ``(2w + 1, r, 2)`` the patches' points minus their means [m].
        normals: ``(r, 2)`` their unit normals.
        centre: the centre point's row in each patch (``w``).
    """
    tangents = stack_last(normals[:, 1], -normals[:, 0])
    u = np.einsum("prk,rk->rp", d, tangents)  # (r, 2w + 1)
    v = np.einsum("prk,rk->rp", d, normals)
    u = u / np.maximum(np.abs(u).max(axis=1, keepdims=True), np.finfo(float).tiny)  # scale
    design = np.stack([np.ones_like(u), u, u * u], axis=2)  # (r, 2w + 1, 3)
    normal_matrix = design.transpose(0, 2, 1) @ design
    rhs = design.transpose(0, 2, 1) @ v[..., None]
    coef = np.linalg.solve(normal_matrix, rhs)[..., 0]  # (r, 3): a, b, c
    uc = u[:, centre]
    return v[:, centre] - (coef[:, 0] + coef[:, 1] * uc + coef[:, 2] * uc * uc)


class Reference(NamedTuple):
    """A local map's reference: the selected keyframes' points and normals.

    ``table`` is ``(N + 1, 4)``: each point's normal and position ``[n_x, n_y, x, y]``
    and a last all-zero row, the sentinel a k-d tree query returns (index ``N``, the
    tree's ``n``) when no point lies within its distance bound; one gather then gives
    normal and point.
    """

    tree: cKDTree  # over the points
    table: np.ndarray  # (N + 1, 4)

    @property
    def points(self) -> np.ndarray:
        """``(N, 2)`` the points, map frame [m] (a view of the table)."""
        return self.table[:-1, 2:]

    @property
    def normals(self) -> np.ndarray:
        """``(N, 2)`` their unit normals, map frame (a view of the table)."""
        return self.table[:-1, :2]


_BALANCED_TREE = False
"""``cKDTree(balanced_tree=...)`` of a reference. Sliding-midpoint splits (False) build
a 4 000-point map of wall points in 0.30 ms instead of 0.52 ms (median splits), and
queries take as long (scipy 1.17); nearest neighbours are exact either way. The Intel
log builds 1.5 references per scan."""


def _transform(pose: np.ndarray, points: np.ndarray) -> np.ndarray:
    c, s = np.cos(pose[2]), np.sin(pose[2])
    return points @ np.array([[c, s], [-s, c]]) + pose[:2]


class LocalMap:
    """Keyframes (points and normals in the map frame) and the reference built from them.

    The reference is the last ``config.keyframes`` keyframes plus, with
    ``config.revisit_radius``, the older keyframes near the position the caller asks
    about (:meth:`reference`). A scan becomes a keyframe when it moved or turned enough
    from the last one (``keyframe_distance``, ``keyframe_heading_deg``).
    """

    def __init__(self, config: ScanMatcherConfig) -> None:
        self.config = config
        self._points: list[np.ndarray] = []  # per keyframe, (m, 2) map frame [m]
        self._normals: list[np.ndarray] = []
        self._poses: list[np.ndarray] = []
        self._reference: Reference | None = None
        self._selection: tuple[int, ...] = ()

    def __len__(self) -> int:
        """Keyframes in the reference without revisits (at most ``config.keyframes``)."""
        return min(len(self._points), int(self.config.keyframes))

    @property
    def stored(self) -> int:
        """Every keyframe kept (older ones only with ``revisit_radius``)."""
        return len(self._points)

    def clear(self) -> None:
        """Forget every keyframe."""
        self._points.clear()
        self._normals.clear()
        self._poses.clear()
        self._reference = None
        self._selection = ()

    def is_keyframe(self, pose: np.ndarray) -> bool:
        """Whether a scan at ``pose`` (map frame) would become a keyframe."""
        if not self._poses:
            return True
        cfg = self.config
        last = self._poses[-1]
        moved = float(np.hypot(pose[0] - last[0], pose[1] - last[1]))
        turned = abs(float(wrap_angle(pose[2] - last[2])))
        return moved >= cfg.keyframe_distance or turned >= np.deg2rad(cfg.keyframe_heading_deg)

    def add(
        self,
        points: np.ndarray,
        pose: np.ndarray,
        normals: ScanNormals | None = None,
    ) -> bool:
        """Add a scan's lidar-frame points ``(m, 2)`` [m] seen from ``pose`` (map frame).

        Only the points with a normal are kept; with ``config.fit_keyframe_points`` each
        is moved onto the parabola fitted to its patch (:class:`ScanNormals`).

        Args:
            points: ``(m, 2)`` the scan's returns in the lidar frame [m], beam order.
            pose: ``(3,)`` the lidar pose in the map frame.
            normals: ``scan_normals(points, config)`` when the caller has it already
                (same ``normal_*`` and ``fit_keyframe_points`` as this map's config);
                None: computed here, only when the scan becomes a keyframe.

        Returns whether it became a keyframe.
        """
        pose = check_pose(pose)
        if not self.is_keyframe(pose):
            return False
        fit = normals if normals is not None else scan_normals(points, self.config)
        valid = fit.valid
        if not np.any(valid):
            return False
        kept = points[valid]
        if self.config.fit_keyframe_points:
            kept = kept - fit.offsets[valid, None] * fit.normals[valid]
        c, s = np.cos(pose[2]), np.sin(pose[2])
        rot = np.array([[c, s], [-s, c]])
        self._points.append(_transform(pose, kept))
        self._normals.append(fit.normals[valid] @ rot)
        self._poses.append(pose.copy())
        if self.config.revisit_radius <= 0 and len(self._points) > self.config.keyframes:
            del self._points[0], self._normals[0], self._poses[0]  # never needed again
            self._selection = ()
        return True

    def _select(self, near: np.ndarray | None) -> tuple[int, ...]:
        count = len(self._points)
        recent = list(range(max(0, count - int(self.config.keyframes)), count))
        older = count - len(recent)
        if near is None or self.config.revisit_radius <= 0 or older == 0:
            return tuple(recent)
        poses = np.array(self._poses[:older])
        dist = np.hypot(poses[:, 0] - near[0], poses[:, 1] - near[1])
        close = np.flatnonzero(dist <= self.config.revisit_radius)
        close = close[np.argsort(dist[close], kind="stable")][: self.config.revisit_max_keyframes]
        return tuple(sorted(int(i) for i in close)) + tuple(recent)

    def reference(self, near: np.ndarray | None = None) -> Reference | None:
        """The :class:`Reference` of the selected keyframes, or None.

        None when no keyframe is selected (an empty map, or a subclass's selection).

        Args:
            near: ``(>=2,)`` map position [m] around which older keyframes are selected
                (``revisit_radius``); None: the last ``keyframes`` only.
        """
        selection = self._select(near)
        if not selection:
            return None
        if self._reference is None or selection != self._selection:
            pts = np.concatenate([self._points[i] for i in selection])
            nrm = np.concatenate([self._normals[i] for i in selection])
            table = np.zeros((pts.shape[0] + 1, 4))
            table[:-1, :2], table[:-1, 2:] = nrm, pts
            self._reference = Reference(cKDTree(pts, balanced_tree=_BALANCED_TREE), table)
            self._selection = selection
        return self._reference


def _hypotheses(prior: np.ndarray, sigma_theta: float, config: ScanMatcherConfig) -> np.ndarray:
    """``(h, 3)`` start poses: the prior with headings over ``+- heading_sigmas`` sigma."""
    half = config.heading_sigmas * max(float(sigma_theta), 0.0)
    step = np.deg2rad(config.heading_step_deg)
    if config.hypothesis_spacing == "step":
        k = min(int(np.floor(half / step)), (int(config.max_hypotheses) - 1) // 2)
        starts = np.repeat(prior[None, :], 2 * k + 1, axis=0)
        starts[:, 2] = prior[2] + np.arange(-k, k + 1) * step
        return starts
    count = min(int(config.max_hypotheses), 2 * int(np.ceil(half / step)) + 1)
    offsets = np.linspace(-half, half, count) if count > 1 else np.zeros(1)
    starts = np.repeat(prior[None, :], offsets.size, axis=0)
    starts[:, 2] = prior[2] + offsets
    return starts


@dataclass(frozen=True)
class _Prior:
    """The predicted pose as a Gaussian term of the cost (``info`` zero: not used)."""

    mean: np.ndarray  # (3,)
    info: np.ndarray  # (3, 3) inverse covariance, or zeros
    used: bool  # the term is in the cost (``info`` not all zero)

    def offset(self, poses: np.ndarray) -> np.ndarray:
        d = poses - self.mean
        d[:, 2] = wrap_angle(d[:, 2])
        return d

    def mahalanobis2(self, poses: np.ndarray) -> np.ndarray:
        """Squared Mahalanobis distances ``(h,)`` of ``poses`` ``(h, 3)`` from the mean."""
        d = self.offset(poses)
        return np.einsum("hi,ij,hj->h", d, self.info, d)


@dataclass
class _Residuals:
    system: np.ndarray  # (h, n, 4): d r / d [x, y, theta] and r, one row per point
    matched: np.ndarray  # (h, n) bool: a neighbour within the gate

    @property
    def r(self) -> np.ndarray:
        """``(h, n)`` signed point-to-line distances [m] (0 when unmatched)."""
        return self.system[..., 3]

    @property
    def normals(self) -> np.ndarray:
        """``(h, n, 2)`` the neighbours' normals: ``d r / d [x, y]`` (0 when unmatched)."""
        return self.system[..., :2]

    @property
    def jac(self) -> np.ndarray:
        """``(h, n, 3)`` their derivatives by ``[x, y, theta]`` (0 when unmatched)."""
        return self.system[..., :3]

    def inliers(self, distance: float) -> np.ndarray:
        """``(h, n)`` bool: matched and within ``distance`` [m] of the neighbour's line."""
        return self.matched & (np.abs(self.r) <= distance)

    def take(self, rows: np.ndarray) -> _Residuals:
        """The residuals of the poses ``rows`` only."""
        return _Residuals(self.system[rows], self.matched[rows])


def _residuals(
    poses: np.ndarray,
    points: np.ndarray,
    reference: Reference,
    gate: float,
    agreement: _NormalAgreement | None = None,
) -> _Residuals:
    """Point-to-line residuals of ``points`` (lidar frame) at each pose to the map.

    A point without a neighbour within ``gate`` [m] gets the reference's sentinel row
    (zero point and normal): its residual and Jacobian row are zero. So does a point
    whose normal disagrees with its neighbour's (``agreement``, None: no test).
    """
    c, s = np.cos(poses[:, 2])[:, None], np.sin(poses[:, 2])[:, None]
    rx = c * points[:, 0] - s * points[:, 1]  # rotated, (h, n)
    ry = s * points[:, 0] + c * points[:, 1]
    world = np.empty((*rx.shape, 2))
    wx, wy = world[..., 0], world[..., 1]
    np.add(rx, poses[:, 0, None], out=wx)
    np.add(ry, poses[:, 1, None], out=wy)
    _, idx = reference.tree.query(world.reshape(-1, 2), distance_upper_bound=gate)
    idx = idx.reshape(rx.shape)
    # (h, n, 4): normal and point, the sentinel when unmatched; it becomes the system:
    # the normal stays (d r / d [x, y]), the point is overwritten once r is computed.
    # (np.take: the same gather as ``table[idx]``, with less overhead.)
    system = np.take(reference.table, idx, axis=0)
    nx, ny = system[..., 0], system[..., 1]
    # r = n_x (w_x - p_x) + n_y (w_y - p_y), both coordinates per operation
    along = system[..., :2] * (world - system[..., 2:])
    np.subtract(ny * rx, nx * ry, out=system[..., 2])
    np.add(along[..., 0], along[..., 1], out=system[..., 3])
    matched = idx < reference.tree.n
    if agreement is not None:
        sx, sy = agreement.normals[:, 0], agreement.normals[:, 1]
        cosine = (c * sx - s * sy) * nx + (s * sx + c * sy) * ny  # scan normal rotated
        disagree = (cosine < agreement.min_cos) & agreement.valid & matched
        if disagree.any():
            system[disagree] = 0.0
            matched &= ~disagree
    return _Residuals(system, matched)


class _NormalAgreement(NamedTuple):
    """The scan's normals for the test of ``ScanMatcherConfig.normal_agreement_deg``."""

    normals: np.ndarray  # (n, 2) lidar frame, facing the lidar; zero where not valid
    valid: np.ndarray  # (n,) bool: the point has a normal
    min_cos: float  # cosine of the largest angle between a scan and a map normal

    @classmethod
    def of(
        cls, points: np.ndarray, normals: ScanNormals | None, config: ScanMatcherConfig
    ) -> _NormalAgreement | None:
        """The test for ``points``, or None when ``config`` has it off.

        ``normals``: their :func:`scan_normals` (computed here when None).
        """
        if config.normal_agreement_deg <= 0:
            return None
        fit = normals if normals is not None else scan_normals(points, config)
        return cls(fit.normals, fit.valid, float(np.cos(np.deg2rad(config.normal_agreement_deg))))

    def every(self, stride: int) -> _NormalAgreement:
        """The test for every ``stride``-th point (the coarse phase's points)."""
        return _NormalAgreement(self.normals[::stride], self.valid[::stride], self.min_cos)


def _normal_equations(
    res: _Residuals, weights: np.ndarray, factor: float
) -> tuple[np.ndarray, np.ndarray]:
    """``H = f sum w J^T J`` ``(h, 3, 3)`` and ``g = f sum w J r`` ``(h, 3)``, ``f = factor``.

    One batched product ``[J r]^T W [J r]`` (a matrix product: several times faster
    than ``einsum`` at these sizes), scaled in place.
    """
    m = (weights[:, None, :] * res.system.transpose(0, 2, 1)) @ res.system
    m *= factor
    return m[:, :3, :3], m[:, :3, 3]


def _cauchy_any(res: _Residuals, scale: float) -> np.ndarray:
    """Cauchy weights ``(h, n)`` of the residuals, 1 where unmatched (``r = 0``).

    Enough for :func:`_normal_equations`: an unmatched row of the system is zero, and
    so is its product with any weight.
    """
    return 1.0 / (1.0 + (res.r / scale) ** 2)


def _cauchy(res: _Residuals, scale: float) -> np.ndarray:
    """Cauchy weights ``(h, n)`` of the residuals, 0 where unmatched."""
    return np.where(res.matched, _cauchy_any(res, scale), 0.0)


def _gauss_newton(
    starts: np.ndarray,
    points: np.ndarray,
    reference: Reference,
    prior: _Prior,
    gates: np.ndarray,
    config: ScanMatcherConfig,
    keep_after: int = 0,
    keep: int | None = None,
    keep_ratio: float = 0.0,
    agreement: _NormalAgreement | None = None,
) -> np.ndarray:
    """Robust point-to-line Gauss-Newton (plus the prior term) from every start at once.

    One step per correspondence gate [m] in ``gates``. With ``keep_after`` > 0, at that
    step only the poses ranked by their inliers (``config.inlier_distance``) at it among
    the first ``keep`` (None: all) with at least ``keep_ratio`` times the most go on.
    Returns ``(h, 3)``, fewer poses than ``starts`` when some were dropped.
    """
    poses = starts.copy()
    scan_info = 1.0 / config.robust_scale**2  # the prior only breaks ties (corridors)
    for k, gate in enumerate(gates):
        res = _residuals(poses, points, reference, float(gate), agreement)
        if 0 < keep_after == k and poses.shape[0] > 1:
            kept = _kept(res, keep, keep_ratio, config)
            if kept.size < poses.shape[0]:
                poses = poses[kept]
                res = res.take(kept)
        hess, grad = _normal_equations(res, _cauchy_any(res, config.robust_scale), scan_info)
        if prior.used:  # adding a zero term changes nothing: skipped
            hess = hess + prior.info
            grad = grad + prior.offset(poses) @ prior.info
        ok = res.matched.sum(axis=1) >= config.min_points
        if ok.all():  # the usual case: no copies
            step = _damped_step(hess, grad)
            poses += step
        elif ok.any():
            step = _damped_step(hess[ok], grad[ok])
            poses[ok] += step
        else:
            break
        if (np.abs(step[:, 2]) < config.converged_rotation).all() and (
            np.hypot(step[:, 0], step[:, 1]) < config.converged_translation
        ).all():
            break
    poses[:, 2] = wrap_angle(poses[:, 2])
    return poses


_DAMPING = np.eye(3) * np.finfo(float).eps ** 0.5
"""Relative Levenberg damping of :func:`_gauss_newton`'s steps (times the trace of H)."""


def _damped_step(hess: np.ndarray, grad: np.ndarray) -> np.ndarray:
    """``-(H + damping tr(H) I)^-1 g`` per pose: ``hess`` ``(h, 3, 3)``, ``grad`` ``(h, 3)``."""
    scale = np.maximum(hess.trace(axis1=1, axis2=2), 1.0)[:, None, None]
    return -np.linalg.solve(hess + _DAMPING * scale, grad[..., None])[..., 0]


def _kept(res: _Residuals, keep: int | None, ratio: float, config: ScanMatcherConfig) -> np.ndarray:
    """Indices (ascending) of the poses :func:`_gauss_newton` keeps (``keep_after``)."""
    inliers = res.inliers(config.inlier_distance).sum(axis=1)
    order = np.argsort(-inliers, kind="stable")[:keep]
    order = order[inliers[order] >= ratio * inliers[order[0]]]
    return np.sort(order)


def _inliers(
    poses: np.ndarray,
    points: np.ndarray,
    reference: Reference,
    gate: float,
    config: ScanMatcherConfig,
    agreement: _NormalAgreement | None = None,
) -> tuple[_Residuals, np.ndarray]:
    """Residuals at ``poses`` and each pose's inlier fraction ``(h,)``."""
    res = _residuals(poses, points, reference, gate, agreement)
    return res, res.inliers(config.inlier_distance).sum(axis=1) / points.shape[0]


def _merge(poses: np.ndarray, config: ScanMatcherConfig) -> np.ndarray:
    """One pose per cell of a ``merge_translation`` x ``merge_heading_deg`` grid."""
    cell = np.array([config.merge_translation] * 2 + [np.deg2rad(config.merge_heading_deg)])
    keys = np.round(np.column_stack([poses[:, :2], wrap_angle(poses[:, 2])]) / cell)
    seen: set[tuple[float, ...]] = set()
    first = []
    for i, key in enumerate(map(tuple, keys.tolist())):  # a few rows: faster than np.unique
        if key not in seen:
            seen.add(key)
            first.append(i)
    return poses[first]


def _scores(
    poses: np.ndarray, fraction: np.ndarray, prior: _Prior | None, config: ScanMatcherConfig
) -> np.ndarray:
    """What ranks candidate poses ``(h, 3)`` (``ScanMatcherConfig.selection_points``).

    Their inlier fractions ``(h,)``, or with ``selection_points > 0`` and a prior
    ``selection_points * fraction - 0.5 * m2`` (``m2``: squared Mahalanobis distance of
    each pose from the prior).
    """
    if config.selection_points <= 0.0 or prior is None:
        return fraction
    return config.selection_points * fraction - 0.5 * prior.mahalanobis2(poses)


def match_scan(
    points: np.ndarray,
    local_map: LocalMap,
    prior: np.ndarray,
    prior_cov: np.ndarray,
    config: ScanMatcherConfig | None = None,
    use_prior: bool = True,
    normals: ScanNormals | None = None,
) -> MatchResult | None:
    """Align a scan to the local map from heading hypotheses around ``prior``.

    Args:
        points: ``(m, 2)`` the scan's returns in the lidar frame [m], beam order
            (:func:`scan_points`).
        local_map: the reference.
        prior: ``(3,)`` predicted lidar pose in the map frame.
        prior_cov: ``(3, 3)`` its covariance (positive semi-definite); the hypotheses
            span its heading variance.
        config: defaults to ``local_map.config``.
        use_prior: True: maximum a posteriori, the prior is a term of the cost (a
            corridor's free direction comes from it) and of the returned covariance;
            False: the scan alone (declined when the normals cannot fix the translation;
            use this when the result is fused with the same prior later).
        normals: ``scan_normals(points, config)`` when the caller has it (for
            ``config.normal_agreement_deg``; computed here when needed and None).

    Returns:
        The aligned pose and covariance, or None when the map is empty, too few points
        match, the match is ambiguous or (without the prior) degenerate.

    Raises:
        ValueError: malformed ``points``, ``prior`` or ``prior_cov``.
    """
    return match_scan_why(points, local_map, prior, prior_cov, config, use_prior, normals)[0]


def distinct_poses(poses: np.ndarray, pose: np.ndarray, config: ScanMatcherConfig) -> np.ndarray:
    """Which of ``poses`` ``(..., 3)`` differ from ``pose`` ``(3,)`` beyond the ambiguity steps.

    More than ``config.ambiguity_translation`` [m] apart, or headings more than
    ``config.ambiguity_heading_deg`` apart: the matcher's test of a rival match.
    """
    d_trans = np.hypot(poses[..., 0] - pose[0], poses[..., 1] - pose[1])
    d_head = np.abs(wrap_angle(poses[..., 2] - pose[2]))
    return (d_trans > config.ambiguity_translation) | (
        d_head > np.deg2rad(config.ambiguity_heading_deg)
    )


def local_fit(
    points: np.ndarray,
    local_map: LocalMap,
    pose: np.ndarray,
    config: ScanMatcherConfig | None = None,
) -> tuple[np.ndarray, float] | None:
    """The scan aligned to the local map near ``pose`` only, and its inlier fraction.

    The refinement of :func:`match_scan` alone (correspondences within
    ``max_distance_mid`` shrinking to ``max_distance_end``, no heading hypotheses, no
    prior): where the scan fits around the given pose, to compare a match found
    elsewhere with. ``points``: ``(m, 2)`` lidar frame [m]; ``pose``: ``(3,)`` lidar pose
    in the map frame. None when the map is empty. Without the normal agreement test of
    ``config.normal_agreement_deg`` (as measured in session 39).
    """
    config = config or local_map.config
    pose = check_pose(pose)
    reference = local_map.reference(pose)
    if reference is None:
        return None
    points = np.asarray(points, dtype=float)
    gates = np.linspace(config.max_distance_mid, config.max_distance_end, config.refine_iterations)
    term = _Prior(pose, np.zeros((3, 3)), False)
    fitted = _gauss_newton(pose[None, :], points, reference, term, gates, config)
    _, fraction = _inliers(fitted, points, reference, config.max_distance_end, config)
    return fitted[0].copy(), float(fraction[0])


def match_scan_why(
    points: np.ndarray,
    local_map: LocalMap,
    prior: np.ndarray,
    prior_cov: np.ndarray,
    config: ScanMatcherConfig | None = None,
    use_prior: bool = True,
    normals: ScanNormals | None = None,
) -> tuple[MatchResult | None, str]:
    """:func:`match_scan` and why it declined (for diagnostics).

    The reason is ``"matched"``, ``"ambiguous_prior"`` (matched, see
    ``ScanMatcherConfig.on_ambiguity``), ``"empty"``, ``"few_points"``, ``"few_inliers"``,
    ``"ambiguous"`` or ``"degenerate"``.
    """
    config = config or local_map.config
    prior = check_pose(prior)
    points = np.asarray(points, dtype=float)
    if points.ndim != 2 or points.shape[1] != 2 or not np.isfinite(points).all():
        raise ValueError(f"points must be a finite (m, 2) array [m], got shape {points.shape}")
    prior_cov = np.asarray(prior_cov, dtype=float)
    if prior_cov.shape != (3, 3) or not np.isfinite(prior_cov).all():
        raise ValueError(f"prior_cov must be a finite (3, 3) array, got shape {prior_cov.shape}")
    prior_cov = 0.5 * (prior_cov + prior_cov.T)
    if np.linalg.eigvalsh(prior_cov)[0] < -PSD_TOLERANCE * max(np.abs(prior_cov).max(), 1.0):
        raise ValueError("prior_cov must be symmetric positive semi-definite")
    # A turn on the spot has a singular odometry covariance: floor it.
    floor = np.diag(np.asarray(config.sigma_floor, dtype=float) ** 2)
    info = np.linalg.inv(prior_cov + floor) if use_prior else np.zeros((3, 3))
    reference = local_map.reference(prior)
    if reference is None:
        return None, "empty"
    if points.shape[0] < config.min_points:
        return None, "few_points"
    term = _Prior(prior, info, bool(info.any()))
    starts = _hypotheses(prior, float(np.sqrt(max(prior_cov[2, 2], 0.0))), config)
    coarse = points[:: config.coarse_stride]
    agreement = _NormalAgreement.of(points, normals, config)
    coarse_agreement = None if agreement is None else agreement.every(config.coarse_stride)
    poses = _gauss_newton(
        starts,
        coarse,
        reference,
        term,
        np.linspace(config.max_distance_start, config.max_distance_mid, config.coarse_iterations),
        config,
        keep_after=int(config.coarse_keep_after),
        keep=int(config.coarse_keep),
        agreement=coarse_agreement,
    )
    poses = _merge(poses, config)
    _, fraction = _inliers(
        poses, coarse, reference, config.max_distance_mid, config, coarse_agreement
    )
    rank = _scores(poses, fraction, term if use_prior else None, config)
    poses = poses[np.argsort(-rank, kind="stable")[: config.refine_candidates]]
    poses = _gauss_newton(
        poses,
        points,
        reference,
        term,
        np.linspace(config.max_distance_mid, config.max_distance_end, config.refine_iterations),
        config,
        keep_after=int(config.refine_keep_after),
        keep_ratio=float(config.refine_keep_ratio),
        agreement=agreement,
    )
    res, fraction = _inliers(poses, points, reference, config.max_distance_end, config, agreement)
    best = int(np.argmax(_scores(poses, fraction, term if use_prior else None, config)))
    if (
        fraction[best] < config.min_inlier_fraction
        or fraction[best] * points.shape[0] < config.min_points
    ):
        return None, "few_inliers"
    distinct = distinct_poses(poses, poses[best], config)
    reason = "matched"
    rivals = fraction >= config.ambiguity_ratio * fraction[best]
    if np.any(distinct & rivals):
        if config.on_ambiguity == "decline":
            return None, "ambiguous"
        # The rival nearest the prior (without a prior term: the best inlier fraction).
        if use_prior:
            mahalanobis = term.mahalanobis2(poses)
            mahalanobis[~rivals] = np.inf
            best = int(np.argmin(mahalanobis))
        reason = "ambiguous_prior"
    cov = _covariance(res, best, term, config, check_constraint=not use_prior)
    if cov is None:
        return None, "degenerate"
    result = MatchResult(
        poses[best].copy(), cov, float(fraction[best]), int(points.shape[0]), starts.shape[0]
    )
    return result, reason


def _covariance(
    res: _Residuals, best: int, prior: _Prior, config: ScanMatcherConfig, check_constraint: bool
) -> np.ndarray | None:
    """Inflated Gauss-Newton covariance at the winning pose, or None when degenerate."""
    weights = _cauchy(res, config.robust_scale)[best]
    total = weights.sum()
    if check_constraint:
        n = res.normals[best]
        scatter = (weights[:, None, None] * n[:, :, None] * n[:, None, :]).sum(axis=0) / total
        if np.linalg.eigvalsh(scatter)[0] < config.min_constraint:
            return None
    jac = res.jac[best]
    hess = (weights[:, None] * jac).T @ jac
    variance = max(float(np.sum(weights * res.r[best] ** 2) / max(total - 3.0, 1.0)), 1e-12)
    try:
        cov = np.linalg.inv(hess / (config.covariance_inflation * variance) + prior.info)
    except np.linalg.LinAlgError:
        return None
    cov = 0.5 * (cov + cov.T) + np.diag(np.asarray(config.sigma_floor, dtype=float) ** 2)
    if not np.isfinite(cov).all() or np.linalg.eigvalsh(cov)[0] <= 0:
        return None
    return cov
