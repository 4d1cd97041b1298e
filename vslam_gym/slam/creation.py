"""Model creation: from one segment of a scan to a landmark model (SPEC sections 3, 5-7).

Pipeline (thesis section 3.2.1, Algorithms 1-3), all at a known lidar pose:

1. :func:`initial_grouping` (Algorithm 3): grow groups of consecutive measurements while
   every point's perpendicular distance to the group's line is within
   ``grouping_mahalanobis`` standard deviations.
2. :func:`select_model` (Algorithms 1-2): repeatedly join the adjacent pair of lines whose
   merge loses the least log-likelihood, scoring every model with the BIC; keep the best.
3. :func:`vertex_distribution` (3.2.7-3.2.14): the joint Gaussian of the vertices, where
   line ``i - 1`` meets line ``i`` and the two end lines run from the lidar through the
   first and the last measurement.
4. :func:`end_vertices` (3.2.32-3.2.35): unknown lines at both ends (object edge,
   occlusion, or field-of-view limit) and :func:`unknown_probabilities` (3.2.36-3.2.37).
5. :func:`~vslam_gym.slam.landmark.conditional_on_pose` (3.2.44-3.2.49).

Measurements of a segment are stacked interleaved, ``[r_0, phi_0, r_1, phi_1, ...]``, with
the block-diagonal covariance ``blockdiag(Q, ..., Q)``; every Gaussian map goes through a
pluggable :class:`~vslam_gym.slam.gaussian.Linearization` (the thesis's UT by default).

Departure from the thesis, documented: the per-line log-likelihoods of the model
selection (``Phi`` and ``Phi_dup``) are all evaluated against the fitted line's
``(p0, p1)`` distribution, as the thesis does for merged lines (Algorithm 2, line 8),
also for the initial model and the shared measurements. Vertices of the many short,
nearly collinear initial lines are ill-conditioned intersections and would make those
likelihoods meaningless; the line-based ones are not affected.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.stats import chi2

from vslam_gym.slam.config import ModelConfig, SensorConfig
from vslam_gym.slam.gaussian import Linearization, make_linearization, symmetrize
from vslam_gym.slam.geometry import fit_line
from vslam_gym.slam.landmark import LandmarkModel, ModelFit, conditional_on_pose
from vslam_gym.slam.likelihood import object_loglik, range_error_distribution
from vslam_gym.slam.scan import Scan


class DegenerateSegmentError(ValueError):
    """A segment cannot be modelled (too few points, no-return beams, parallel lines)."""


# --------------------------------------------------------------------------- helpers


def stacked_measurements(scan: Scan, first: int, last: int, sensor: SensorConfig):
    """Interleaved polar measurements of beams ``first..last`` and their covariance.

    Returns:
        ``(z, Sigma)``: ``z`` ``(2n,)`` as ``[r_0, phi_0, ...]`` [m, rad] and the
        block-diagonal ``Sigma`` ``(2n, 2n)``.
    """
    n = last - first + 1
    z = np.empty(2 * n)
    z[0::2] = scan.ranges[first : last + 1]
    z[1::2] = scan.bearings[first : last + 1]
    var = np.tile([sensor.sigma_range**2, sensor.sigma_bearing**2], n)
    return z, np.diag(var)


def _points(x: np.ndarray, pose: np.ndarray) -> np.ndarray:
    """World-frame points ``(..., n, 2)`` of interleaved polar rows ``x`` ``(..., 2n)``."""
    r = x[..., 0::2]
    a = pose[2] + x[..., 1::2]
    return np.stack([pose[0] + r * np.cos(a), pose[1] + r * np.sin(a)], axis=-1)


def _oriented_line(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Total-least-squares line ``(p0, d)`` of ``points`` ``(..., n, 2)``.

    ``d`` is the unit direction oriented from the first towards the last point, so that
    it varies continuously between sigma points (the raw angle ``psi`` of the fit lives
    in ``[0, pi]`` and flips for nearly horizontal lines).
    """
    p0, psi = fit_line(points)
    d = np.stack([np.cos(psi), np.sin(psi)], axis=-1)
    span = points[..., -1, :] - points[..., 0, :]
    sign = np.where(np.sum(d * span, axis=-1) < 0.0, -1.0, 1.0)
    return p0, d * sign[..., None]


def _intersect(pa, da, pb, db):
    """Intersection of lines ``pa + t da`` and ``pb + s db`` and the sine between them."""
    cross = da[..., 0] * db[..., 1] - da[..., 1] * db[..., 0]
    w = pb - pa
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (w[..., 0] * db[..., 1] - w[..., 1] * db[..., 0]) / cross
    norms = np.linalg.norm(da, axis=-1) * np.linalg.norm(db, axis=-1)
    return pa + t[..., None] * da, np.abs(cross) / norms


# ------------------------------------------------------------------ Algorithm 3


def point_covariances(
    z: np.ndarray, pose: np.ndarray, sensor: SensorConfig, lin: Linearization
) -> tuple[np.ndarray, np.ndarray]:
    """Cartesian distributions of each polar measurement (3.2.2), batched over beams.

    Args:
        z: ``(2n,)`` interleaved polar measurements.
        pose: ``(3,)`` lidar pose.

    Returns:
        ``(mu, Sigma)``: ``(n, 2)`` world-frame means [m] and ``(n, 2, 2)`` covariances.
    """
    zp = z.reshape(-1, 2)
    cov = np.broadcast_to(sensor.Q, (zp.shape[0], 2, 2))
    return lin.propagate(lambda x: _points(x, pose)[..., 0, :], zp, cov)


def initial_grouping(
    mu_c: np.ndarray, cov_c: np.ndarray, config: ModelConfig
) -> list[tuple[int, int]]:
    """Algorithm 3: initial groups of consecutive measurements.

    Args:
        mu_c: ``(n, 2)`` Cartesian measurement means [m].
        cov_c: ``(n, 2, 2)`` their covariances [m^2].

    Returns:
        Groups ``(a, b)`` of local indices (inclusive); consecutive groups share ``b``.
    """
    n = mu_c.shape[0]
    start = config.min_group_size - 1
    groups: list[tuple[int, int]] = []
    a, b = 0, start
    while b < n:
        p0, psi = fit_line(mu_c[a : b + 1])
        normal = np.array([-np.sin(psi), np.cos(psi)])
        mu_d = (mu_c[a : b + 1] - p0) @ normal
        var_d = np.einsum("i,nij,j->n", normal, cov_c[a : b + 1], normal)
        if np.all(mu_d**2 <= config.grouping_mahalanobis**2 * var_d):
            b += 1
        else:
            groups.append((a, b - 1))
            a = b - 1
            b = a + start
    groups.append((a, n - 1))
    return groups


# ------------------------------------------------------------- Algorithms 1-2


@dataclass
class _LineEval:
    """A line fitted to local measurements ``a..b`` and each measurement's log-likelihood."""

    a: int
    b: int
    loglik: np.ndarray  # (b - a + 1,)

    @property
    def total(self) -> float:
        return float(self.loglik.sum())


class _SegmentModeller:
    """Shared state for modelling one segment: measurements, pose, sensor, linearisation."""

    def __init__(
        self,
        scan: Scan,
        first: int,
        last: int,
        pose: np.ndarray,
        sensor: SensorConfig,
        config: ModelConfig,
        lin: Linearization,
    ) -> None:
        self.scan, self.first, self.last = scan, first, last
        self.pose = np.asarray(pose, dtype=float)
        self.sensor, self.config, self.lin = sensor, config, lin
        self.z, self.cov = stacked_measurements(scan, first, last, sensor)
        self.n = last - first + 1
        self.point_cov = np.zeros((self.n, 2, 2))

    def line_distribution(self, a: int, b: int) -> tuple[np.ndarray, np.ndarray]:
        """Gaussian of ``(p0, p1)`` ``(4,)`` of the line fitted to local beams ``a..b``.

        ``p1 = p0 + d`` with a unit direction ``d`` (``beta = 1``), so the covariance has
        rank 3 by construction (``||p1 - p0|| = 1``); it is not checked for definiteness.
        """
        sl = slice(2 * a, 2 * b + 2)

        def f(x):
            p0, d = _oriented_line(_points(x, self.pose))
            return np.concatenate([p0, p0 + d], axis=-1)

        return self.lin.propagate(f, self.z[sl], self.cov[sl, sl], check=False)

    def evaluate_line(self, a: int, b: int) -> _LineEval:
        """Fit a line to local beams ``a..b``; log-likelihood of each of them (3.2.20)."""
        mu, sigma = self.line_distribution(a, b)
        m = b - a + 1
        idx = np.arange(self.first + a, self.first + b + 1)
        mu_err, var_err = range_error_distribution(
            self.scan.ranges[idx],
            self.scan.bearings[idx],
            self.sensor.Q,
            self.pose,
            np.broadcast_to(mu, (m, 4)),
            np.broadcast_to(sigma, (m, 4, 4)),
            self.lin,
        )
        return _LineEval(a, b, object_loglik(mu_err, var_err))

    def bic(self, lines: list[_LineEval]) -> float:
        """BIC score (3.2.26) of a model made of ``lines``, shared measurements once."""
        m = len(lines)
        k = m + 1
        dup = sum(min(lines[j].loglik[-1], lines[j + 1].loglik[0]) for j in range(m - 1))
        n_params = 2 * k**2 + 3 * k
        penalty = self.config.alpha_bic * 0.5 * n_params * np.log(2 * self.n)
        return sum(line.total for line in lines) - dup - penalty


def select_model(
    modeller: _SegmentModeller, groups: list[tuple[int, int]]
) -> tuple[list[tuple[int, int]], np.ndarray]:
    """Algorithms 1-2: BIC model selection by greedy joining of adjacent lines.

    Returns:
        The best grouping and the BIC of every model, index ``m - 1`` for ``m`` lines.
    """
    cache: dict[tuple[int, int], _LineEval] = {}

    def evaluate(a: int, b: int) -> _LineEval:
        if (a, b) not in cache:
            cache[(a, b)] = modeller.evaluate_line(a, b)
        return cache[(a, b)]

    lines = [evaluate(a, b) for a, b in groups]
    bic = np.full(len(lines), -np.inf)
    best_groups = {len(lines): [(ln.a, ln.b) for ln in lines]}
    bic[len(lines) - 1] = modeller.bic(lines)
    while len(lines) > 1:
        losses = []
        for j in range(len(lines) - 1):
            joined = evaluate(lines[j].a, lines[j + 1].b)
            dup = min(lines[j].loglik[-1], lines[j + 1].loglik[0])
            losses.append(lines[j].total + lines[j + 1].total - dup - joined.total)
        j = int(np.argmin(losses))
        lines[j : j + 2] = [evaluate(lines[j].a, lines[j + 1].b)]
        best_groups[len(lines)] = [(ln.a, ln.b) for ln in lines]
        bic[len(lines) - 1] = modeller.bic(lines)
    return best_groups[int(np.argmax(bic)) + 1], bic


# ---------------------------------------------------------------- vertices


def _vertex_function(slices: list[tuple[int, int]], pose: np.ndarray, n: int):
    """Vectorised map from interleaved polar rows to stacked vertices (3.2.7-3.2.9).

    ``slices`` are the inclusive local beam ranges each object line is fitted to. Rows
    longer than ``2n`` carry one extra entry per object line: an offset [m] of that line
    along its normal (the model error of :func:`coarseness_variances`).
    """

    def f(x: np.ndarray) -> np.ndarray:
        pts = _points(x[..., : 2 * n], pose)
        offsets = x[..., 2 * n :]
        starts, dirs = [], []
        pos = np.broadcast_to(pose[:2], pts[..., 0, :].shape)
        starts.append(pos)
        dirs.append(pts[..., 0, :] - pos)
        for j, (a, b) in enumerate(slices):
            p0, d = _oriented_line(pts[..., a : b + 1, :])
            if offsets.shape[-1]:
                p0 = p0 + offsets[..., j, None] * np.stack([-d[..., 1], d[..., 0]], axis=-1)
            starts.append(p0)
            dirs.append(d)
        starts.append(pos)
        dirs.append(pts[..., -1, :] - pos)
        p = np.stack(starts, axis=-2)
        d = np.stack(dirs, axis=-2)
        v, _ = _intersect(p[..., :-1, :], d[..., :-1, :], p[..., 1:, :], d[..., 1:, :])
        return v.reshape(*v.shape[:-2], -1)

    return f


def fit_slices(
    points: np.ndarray, groups: list[tuple[int, int]], exclusive: bool, window: int = 0
) -> list[tuple[int, int]]:
    """The local beam range each object line is fitted to.

    The thesis fits consecutive lines to groups that share their boundary measurement.
    That measurement lies on one of the two object sides only, so it biases the other
    line and the vertex between them (by about 1 cm at 6 m with a 1 degree lidar). With
    ``exclusive`` each pair of adjacent lines is split at the beam ``k`` within
    ``window`` beams of the shared one that minimises the summed squared perpendicular
    distances of the window's points to the two lines (each fitted without the window),
    and the lines are fitted to ``..k`` and ``k + 1..`` only. Lines keep at least two
    points.
    """
    slices = [list(g) for g in groups]
    if not exclusive:
        return [tuple(s) for s in slices]
    for j in range(len(groups) - 1):
        left, right = slices[j], slices[j + 1]
        shared = groups[j][1]
        lo = max(shared - window, left[0] + 2)
        hi = min(shared + window, right[1] - 2)
        if lo > hi:
            continue
        residual = []
        for a, b in ((left[0], lo - 1), (hi + 1, right[1])):
            p0, psi = fit_line(points[a : b + 1])
            normal = np.array([-np.sin(psi), np.cos(psi)])
            residual.append(((points[lo - 1 : hi + 2] - p0) @ normal) ** 2)
        # split after local index k: points lo-1..k on the left, k+1..hi+1 on the right
        cost = [
            residual[0][: k - lo + 2].sum() + residual[1][k - lo + 2 :].sum()
            for k in range(lo - 1, hi + 1)
        ]
        k = lo - 1 + int(np.argmin(cost))
        left[1], right[0] = k, k + 1
    return [tuple(s) for s in slices]


def _parallel_pairs(modeller: _SegmentModeller, groups: list[tuple[int, int]]) -> np.ndarray:
    """Sine of the angle between each pair of adjacent lines (end lines included)."""
    pts = _points(modeller.z, modeller.pose)
    dirs = [pts[0] - modeller.pose[:2]]
    for a, b in groups:
        dirs.append(_oriented_line(pts[a : b + 1])[1])
    dirs.append(pts[-1] - modeller.pose[:2])
    d = np.array(dirs)
    cross = d[:-1, 0] * d[1:, 1] - d[:-1, 1] * d[1:, 0]
    return np.abs(cross) / (np.linalg.norm(d[:-1], axis=1) * np.linalg.norm(d[1:], axis=1))


def vertex_distribution(
    modeller: _SegmentModeller, groups: list[tuple[int, int]]
) -> tuple[list[tuple[int, int]], np.ndarray, np.ndarray]:
    """Joint Gaussian of the object vertices for a grouping (3.2.14).

    Adjacent object lines closer to parallel than ``parallel_sin_min`` are joined first
    (their intersection is meaningless). An end line parallel to its neighbour (a wall
    seen at a grazing angle) makes the segment degenerate.

    Returns:
        ``(groups, mu, Sigma)``: the grouping actually used, ``(m + 1, 2)`` vertex means
        [m] and their ``(2m + 2, 2m + 2)`` joint covariance.

    Raises:
        DegenerateSegmentError: an end line is parallel to the adjacent object line.
    """
    groups = list(groups)
    limit = modeller.config.parallel_sin_min
    while True:
        sines = _parallel_pairs(modeller, groups)
        if sines[0] <= limit or sines[-1] <= limit:
            raise DegenerateSegmentError(
                "an end line through the lidar is parallel to the adjacent object line "
                f"(sine {min(sines[0], sines[-1]):.3g} <= parallel_sin_min {limit})"
            )
        inner = sines[1:-1]
        if inner.size == 0 or inner.min() > limit:
            break
        j = int(np.argmin(inner))
        groups[j : j + 2] = [(groups[j][0], groups[j + 1][1])]
    points = _points(modeller.z, modeller.pose)
    slices = fit_slices(
        points, groups, modeller.config.exclusive_boundaries, modeller.config.boundary_window
    )
    z, cov = modeller.z, modeller.cov
    if modeller.config.coarseness > 0:
        var = coarseness_variances(
            points, modeller.point_cov, slices, modeller.config.coarseness_significance
        )
        z = np.concatenate([z, np.zeros(len(slices))])
        cov = np.diag(np.concatenate([np.diag(cov), modeller.config.coarseness**2 * var]))
    mu, sigma = modeller.lin.propagate(_vertex_function(slices, modeller.pose, modeller.n), z, cov)
    return groups, mu.reshape(-1, 2), sigma


def coarseness_variances(
    points: np.ndarray,
    point_cov: np.ndarray,
    slices: list[tuple[int, int]],
    significance: float,
) -> np.ndarray:
    """Model-error variance [m^2] of each object line (thesis future work, 6.2).

    A polyline only approximates a curved object: each line is off the object by about
    its sagitta, which the measurement noise does not explain, and the vertices inherit
    that error amplified by the angle between the lines. Per line, the excess
    perpendicular variance ``e_j = (sum d_k^2 - (n_j - 2) mean sigma_d,k^2) / (n_j - 2)``
    of its points counts when the residuals fail a chi-square test at ``significance``
    (else 0), and is never below the same estimate pooled over all lines (short lines
    estimate their own poorly). The caller models it as a random offset of the line
    along its normal, propagated to the vertices like the measurement noise.

    Returns:
        ``(m,)`` variances, one per line.
    """
    excess, dof, stat = [], [], []
    for a, b in slices:
        pts = points[a : b + 1]
        if pts.shape[0] <= 2:
            excess.append(0.0)
            dof.append(0)
            stat.append(0.0)
            continue
        p0, psi = fit_line(pts)
        normal = np.array([-np.sin(psi), np.cos(psi)])
        d2 = ((pts - p0) @ normal) ** 2
        var = np.einsum("i,nij,j->n", normal, point_cov[a : b + 1], normal)
        excess.append(d2.sum() - (pts.shape[0] - 2) * var.mean())
        dof.append(pts.shape[0] - 2)
        stat.append(float(np.sum(d2 / var)))
    excess, dof, stat = np.array(excess), np.array(dof), np.array(stat)
    # Only residuals that the noise cannot explain (chi-square test) count as model error.
    significant = stat > chi2.ppf(significance, np.maximum(dof, 1))
    per_line = np.where(significant, np.maximum(excess, 0.0) / np.maximum(dof, 1), 0.0)
    pooled_significant = stat.sum() > chi2.ppf(significance, max(dof.sum(), 1))
    pooled = max(0.0, excess.sum() / max(dof.sum(), 1)) if pooled_significant else 0.0
    # Short lines estimate their own error poorly: never below the pooled estimate.
    return np.maximum(per_line, pooled)


# ------------------------------------------------------------- unknown lines


def end_vertices(
    scan: Scan,
    first: int,
    last: int,
    pose: np.ndarray,
    sensor: SensorConfig,
    config: ModelConfig,
    lin: Linearization,
) -> tuple[tuple[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]:
    """Vertices of the unknown lines at both ends of a segment (3.2.32-3.2.35).

    Per side, from the beam beside the segment's edge beam:

    - it has a return (an object in front of or behind the landmark): one vertex at
      that measurement;
    - it has no return (the object's edge): two artificial vertices at ``r_max``, one
      beam and ``artificial_outer_offset`` beams beyond the edge, the outer first in
      the vertex order;
    - there is no such beam (the segment reaches the field-of-view limit): one vertex at
      the lidar position (an artificial zero-range measurement).

    Returns:
        ``((mu_left, cov_left), (mu_right, cov_right))``: per side ``(q, 2)`` means [m],
        world frame, in model vertex order (left to right), and ``(2q, 2q)``
        block-diagonal covariances (the vertices are independent of each other and of
        the object vertices).
    """
    res = sensor.phi_res
    outer = config.artificial_outer_offset

    def side(edge: int, neighbour: int, sign: float) -> list[tuple[float, float]]:
        phi_edge = scan.bearings[edge]
        if neighbour < 0 or neighbour >= scan.n:
            return [(0.0, phi_edge + sign * res)]
        if scan.returns[neighbour]:
            return [(scan.ranges[neighbour], scan.bearings[neighbour])]
        near = (scan.max_range, phi_edge + sign * res)
        far = (scan.max_range, phi_edge + sign * outer * res)
        return [far, near] if sign > 0 else [near, far]

    result = []
    for zs in (side(first, first - 1, 1.0), side(last, last + 1, -1.0)):
        zp = np.array(zs, dtype=float)
        cov = np.broadcast_to(sensor.Q, (zp.shape[0], 2, 2))
        zero = zp[:, 0] == 0.0
        mu = _points(zp.reshape(-1), pose).reshape(-1, 2)
        blocks = np.zeros((zp.shape[0], 2, 2))
        if np.any(~zero):
            _, blocks[~zero] = lin.propagate(
                lambda x: _points(x, pose)[..., 0, :], zp[~zero], cov[~zero]
            )
        if np.any(zero):
            # Analytic: only the range spreads a zero-range point, along the beam.
            a = pose[2] + zp[zero, 1]
            d = np.stack([np.cos(a), np.sin(a)], axis=-1)
            blocks[zero] = sensor.sigma_range**2 * d[:, :, None] * d[
                :, None, :
            ] + config.zero_range_vertex_sigma**2 * np.eye(2)
        big = np.zeros((2 * zp.shape[0], 2 * zp.shape[0]))
        for i, blk in enumerate(blocks):
            big[2 * i : 2 * i + 2, 2 * i : 2 * i + 2] = blk
        result.append((mu, big))
    return result[0], result[1]


def unknown_probabilities(
    mu_v: np.ndarray, groups: list[tuple[int, int]], sensor: SensorConfig, config: ModelConfig
) -> np.ndarray:
    """Unknown probability of each fitted line (3.2.36-3.2.37).

    ``d_j = ||mu_v,j+1 - mu_v,j|| / (gamma_j1 - gamma_j0)`` (length per measurement gap),
    ``u_j = clip((d_j - d_low) / (d_high - d_low), 0, 1)`` with the bounds scaled to the
    sensor's resolution.
    """
    lo, hi = config.unknown_bounds(sensor)
    gaps = np.array([b - a for a, b in groups], dtype=float)
    d = np.linalg.norm(np.diff(mu_v, axis=0), axis=1) / np.maximum(gaps, 1.0)
    return np.clip((d - lo) / (hi - lo), 0.0, 1.0)


def _block_diag(*blocks: np.ndarray) -> np.ndarray:
    size = sum(b.shape[0] for b in blocks)
    out = np.zeros((size, size))
    i = 0
    for b in blocks:
        out[i : i + b.shape[0], i : i + b.shape[0]] = b
        i += b.shape[0]
    return out


# -------------------------------------------------------------------- entry point


def create_model(
    scan: Scan,
    first: int,
    last: int,
    pose: np.ndarray,
    sensor: SensorConfig,
    config: ModelConfig | None = None,
    linearization: Linearization | None = None,
) -> ModelFit:
    """Build a landmark model from beams ``first..last`` (inclusive) of ``scan``.

    Args:
        scan: the validated scan (lidar frame).
        first: index of the segment's first (leftmost) beam.
        last: index of its last (rightmost) beam; all beams between must have returns.
        pose: ``(3,)`` lidar pose ``[x, y, theta]`` in the world frame, taken as known.
        sensor: sensor parameters (``Q``, resolution, maximum range).
        config: model parameters; thesis defaults when omitted.
        linearization: Gaussian map; built from ``config.linearization`` when omitted.

    Returns:
        The model with its grouping, conditional form and BIC scores.

    Raises:
        DegenerateSegmentError: fewer than 3 beams, no-return beams inside the segment,
            or degenerate geometry.
    """
    config = config or ModelConfig()
    lin = linearization or make_linearization(config)
    pose = np.asarray(pose, dtype=float).reshape(3)
    if not np.all(np.isfinite(pose)):
        raise ValueError(f"pose must be finite, got {pose}")
    if not (0 <= first and last < scan.n and last - first + 1 >= 3):
        raise DegenerateSegmentError(
            f"a segment needs at least 3 beams inside the scan, got beams {first}..{last} "
            f"of {scan.n}"
        )
    if not np.all(scan.returns[first : last + 1]):
        raise DegenerateSegmentError(f"beams {first}..{last} include no-return readings")

    modeller = _SegmentModeller(scan, first, last, pose, sensor, config, lin)
    mu_c, cov_c = point_covariances(modeller.z, pose, sensor, lin)
    modeller.point_cov = cov_c
    groups = initial_grouping(mu_c, cov_c, config)
    groups, bic = select_model(modeller, groups)
    groups, mu_obj, cov_obj = vertex_distribution(modeller, groups)
    u_obj = unknown_probabilities(mu_obj, groups, sensor, config)
    (mu_l, cov_l), (mu_r, cov_r) = end_vertices(scan, first, last, pose, sensor, config, lin)

    mean = np.vstack([mu_l, mu_obj, mu_r])
    cov = symmetrize(_block_diag(cov_l, cov_obj, cov_r))
    u = np.concatenate([np.ones(mu_l.shape[0]), u_obj, np.ones(mu_r.shape[0])])
    model = LandmarkModel(mean=mean, cov=cov, u=u, closed=False)
    a_vx, b_vx = conditional_on_pose(mean, pose)
    start = mu_l.shape[0]
    return ModelFit(
        model=model,
        pose=pose.copy(),
        first_beam=first,
        last_beam=last,
        groups=np.array(groups, dtype=int) + first,
        object_vertices=(start, start + mu_obj.shape[0]),
        A_vx=a_vx,
        b_vx=b_vx,
        bic=bic,
    )
