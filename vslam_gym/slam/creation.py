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

import functools
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np
from scipy.special import chdtri

from vslam_gym.slam.config import ModelConfig, SensorConfig
from vslam_gym.slam.gaussian import (
    FirstOrderLinearization,
    Linearization,
    make_linearization,
    symmetrize,
)
from vslam_gym.slam.geometry import stack_last
from vslam_gym.slam.landmark import LandmarkModel, ModelFit, conditional_on_pose
from vslam_gym.slam.likelihood import object_loglik, range_error_distribution
from vslam_gym.slam.scan import Scan

_GROUPING_BATCH = 16
"""Trial group ends tested together by :func:`initial_grouping` at first (a speed knob)."""


_PRECOMPUTED_JOINS_MAX_GROUPS = 12
"""With the closed-form first order, :func:`select_model` scores every line that joining
up to this many initial groups can produce in one batch (``g (g + 1) / 2`` lines) rather
than a few after each join (a speed knob; the result is the same)."""


class DegenerateSegmentError(ValueError):
    """A segment cannot be modelled (too few points, no-return beams, parallel lines)."""


# --------------------------------------------------------------------------- helpers


def stacked_measurements(scan: Scan, first: int, last: int, sensor: SensorConfig):
    """Interleaved polar measurements of beams ``first..last`` and their covariance.

    Returns:
        ``(z, Sigma)``: ``z`` ``(2n,)`` as ``[r_0, phi_0, ...]`` [m, rad] and the
        block-diagonal ``Sigma`` ``(2n, 2n)``.
    """
    z, var = _stacked(scan, first, last, sensor)
    return z, np.diag(var)


def _stacked(scan: Scan, first: int, last: int, sensor: SensorConfig):
    """:func:`stacked_measurements` with the diagonal of ``Sigma`` ``(2n,)`` only."""
    n = last - first + 1
    z = np.empty(2 * n)
    z[0::2] = scan.ranges[first : last + 1]
    z[1::2] = scan.bearings[first : last + 1]
    var = np.empty(2 * n)
    var[0::2], var[1::2] = sensor.polar_variances
    return z, var


def _points(x: np.ndarray, pose: np.ndarray) -> np.ndarray:
    """World-frame points ``(..., n, 2)`` of interleaved polar rows ``x`` ``(..., 2n)``."""
    r = x[..., 0::2]
    a = pose[2] + x[..., 1::2]
    return stack_last(pose[0] + r * np.cos(a), pose[1] + r * np.sin(a))


def _oriented_line(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Total-least-squares line ``(p0, d)`` of ``points`` ``(..., n, 2)``.

    ``d`` is the unit direction oriented from the first towards the last point, so that
    it varies continuously between sigma points (the raw angle ``psi`` of the fit lives
    in ``[0, pi]`` and flips for nearly horizontal lines).
    """
    p0, psi = _principal_axis(points)
    d = np.stack([np.cos(psi), np.sin(psi)], axis=-1)
    span = points[..., -1, :] - points[..., 0, :]
    sign = np.where(np.sum(d * span, axis=-1) < 0.0, -1.0, 1.0)
    return p0, d * sign[..., None]


def _segment_lengths(points: np.ndarray) -> np.ndarray:
    """``(n - 1,)`` lengths [m] of the segments between consecutive ``(n, 2)`` points.

    ``np.linalg.norm(np.diff(points, axis=0), axis=1)`` by its own arithmetic (the sum of
    the two squares, then the root) without its overhead.
    """
    d = points[1:] - points[:-1]
    return np.sqrt(d[:, 0] * d[:, 0] + d[:, 1] * d[:, 1])


def _intersect(pa, da, pb, db):
    """Intersection of lines ``pa + t da`` and ``pb + s db`` and the sine between them."""
    cross = da[..., 0] * db[..., 1] - da[..., 1] * db[..., 0]
    w = pb - pa
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (w[..., 0] * db[..., 1] - w[..., 1] * db[..., 0]) / cross
    norms = np.linalg.norm(da, axis=-1) * np.linalg.norm(db, axis=-1)
    return pa + t[..., None] * da, np.abs(cross) / norms


def _principal_axis(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unvalidated total-least-squares line ``(p0, psi)`` of ``(..., n, 2)`` points.

    The same line as :func:`~vslam_gym.slam.geometry.fit_line` (SPEC section 2: the
    principal axis of the scatter matrix) without its input checks, for the hot paths;
    ``psi`` lies in ``(-pi/2, pi/2]``.
    """
    p0 = points.sum(axis=-2) / points.shape[-2]  # np.mean's arithmetic
    e = points - p0[..., None, :]
    ex, ey = e[..., 0], e[..., 1]
    sxx, syy, sxy = (ex * ex).sum(-1), (ey * ey).sum(-1), (ex * ey).sum(-1)
    return p0, 0.5 * np.arctan2(2.0 * sxy, sxx - syy)


class _SpanFits:
    """Total-least-squares lines of many inclusive index spans of one point array, batched.

    The spans are padded to a common width: ``idx`` ``(m, W)`` indexes the points (padding
    repeats a valid index), ``w`` ``(m, W)`` is 1 on a span's own points and 0 on the
    padding. Per span: the centroid ``p0`` ``(m, 2)``, the masked deviations ``ex, ey``
    ``(m, W)`` from it, the scatter sums ``sxx, syy, sxy`` ``(m,)`` and the angle ``psi``
    ``(m,)`` of the principal axis in ``(-pi/2, pi/2]`` (:func:`_principal_axis`).
    """

    def __init__(self, points: np.ndarray, spans: list[tuple[int, int]]) -> None:
        spans_arr = np.asarray(spans, dtype=int).reshape(-1, 2)
        self.lengths = spans_arr[:, 1] - spans_arr[:, 0] + 1
        width = int(self.lengths.max())
        cols = np.arange(width)
        self.mask = cols < self.lengths[:, None]
        self.idx = np.minimum(spans_arr[:, :1] + cols, points.shape[0] - 1)
        self.w = self.mask.astype(float)
        self.cnt = self.lengths.astype(float)
        pts = points[self.idx]
        self.p0 = (self.w[..., None] * pts).sum(axis=1) / self.cnt[:, None]
        e = (pts - self.p0[:, None, :]) * self.w[..., None]
        self.ex, self.ey = e[..., 0], e[..., 1]
        ex, ey = self.ex, self.ey
        self.sxx, self.syy, self.sxy = (ex * ex).sum(1), (ey * ey).sum(1), (ex * ey).sum(1)
        self.psi = 0.5 * np.arctan2(2.0 * self.sxy, self.sxx - self.syy)


class _FirstOrderLines:
    """Closed-form first-order log-likelihoods of beams on fitted lines (hot path).

    Equivalent to the generic first-order path of :meth:`_SegmentModeller.evaluate_line`
    (line fitted by total least squares, its uncertainty propagated from the points'
    Cartesian covariances, the range error linearised in the beam's bearing and the
    line), but in closed form and batched over many candidate lines at once. The line
    is parameterised by its offset ``rho`` along the normal at ``p0`` and its angle
    ``psi``: ``d rho / d z_k = n^T / n_pts``, ``d psi / d z_k = ((d.e_k) n + (n.e_k) d)^T
    / (lambda_1 - lambda_2)``.
    """

    def __init__(self, modeller: _SegmentModeller, point_cov: np.ndarray) -> None:
        pose = modeller.pose
        self.pts = modeller.points
        self.cov = point_cov
        self.ranges = modeller.z[0::2]
        angle = pose[2] + modeller.z[1::2]
        self.u = stack_last(np.cos(angle), np.sin(angle))
        self.pos = pose[:2]
        self.var_r = modeller.sensor.sigma_range**2
        self.var_phi = modeller.sensor.sigma_bearing**2

    def loglik(self, spans: list[tuple[int, int]]) -> list[np.ndarray]:
        """Per-beam log-likelihoods for each inclusive local span ``(a, b)``."""
        fit = _SpanFits(self.pts, spans)
        lengths, idx, w, cnt, p0 = fit.lengths, fit.idx, fit.w, fit.cnt, fit.p0
        ex, ey, sxx, syy, sxy, psi = fit.ex, fit.ey, fit.sxx, fit.syy, fit.sxy, fit.psi
        gap = np.sqrt((sxx - syy) ** 2 + 4.0 * sxy**2)
        dx, dy = np.cos(psi)[:, None], np.sin(psi)[:, None]  # direction; normal (-dy, dx)
        de = ex * dx + ey * dy
        ne = ey * dx - ex * dy
        gx = (de * -dy + ne * dx) / gap[:, None]
        gy = (de * dx + ne * dy) / gap[:, None]
        cov = self.cov[idx]
        cxx, cxy, cyy = cov[..., 0, 0] * w, cov[..., 0, 1] * w, cov[..., 1, 1] * w
        # C n, with n = (-dy, dx)
        cnx, cny = -cxx * dy + cxy * dx, -cxy * dy + cyy * dx
        s_rr = (cnx * -dy + cny * dx).sum(1) / cnt**2
        s_rp = (cnx * gx + cny * gy).sum(1) / cnt
        s_pp = (gx * (cxx * gx + cxy * gy) + gy * (cxy * gx + cyy * gy)).sum(1)
        ux, uy = self.u[idx, 0], self.u[idx, 1]
        r = self.ranges[idx]
        den = -ux * dy + uy * dx  # n . u
        off = (p0[:, 0:1] - self.pos[0]) * -dy + (p0[:, 1:2] - self.pos[1]) * dx
        r_exp = off / den
        j_rho = 1.0 / den
        hx = self.pos[0] + r_exp * ux - p0[:, 0:1]
        hy = self.pos[1] + r_exp * uy - p0[:, 1:2]
        j_psi = (hx * dx + hy * dy) / den
        j_phi = -r_exp * (uy * dy + ux * dx) / den  # n . u_perp = u . d
        var = (
            self.var_r
            + j_phi**2 * self.var_phi
            + j_rho**2 * s_rr[:, None]
            + 2.0 * j_rho * j_psi * s_rp[:, None]
            + j_psi**2 * s_pp[:, None]
        )
        err = r - r_exp
        ll = -0.5 * (np.log(2.0 * np.pi * var) + err**2 / var)
        return [ll[i, : lengths[i]] for i in range(len(spans))]


# ------------------------------------------------------------------ Algorithm 3


def _polar_point_distribution(
    zp: np.ndarray, pose: np.ndarray, sensor: SensorConfig, lin: Linearization
) -> tuple[np.ndarray, np.ndarray]:
    """Cartesian Gaussians of independent polar measurements ``zp`` ``(q, 2)`` (3.2.2).

    First order in closed form (``J Q J^T``); otherwise through ``lin`` (the UT), batched.
    Zero-range points come out rank 1 (no bearing spread).
    """
    r, a = zp[:, 0], pose[2] + zp[:, 1]
    c, s_ = np.cos(a), np.sin(a)
    mu = stack_last(pose[0] + r * c, pose[1] + r * s_)
    jac = np.empty((*c.shape, 2, 2))  # [[c, -r s], [s, r c]]
    jac[..., 0, 0], jac[..., 0, 1], jac[..., 1, 0], jac[..., 1, 1] = c, -r * s_, s_, r * c
    cov = (jac * np.array(sensor.polar_variances)) @ np.swapaxes(jac, -1, -2)
    ut = ~(zp[:, 0] == 0.0) if not isinstance(lin, FirstOrderLinearization) else None
    if ut is not None and np.any(ut):
        q = np.broadcast_to(sensor.Q, (int(ut.sum()), 2, 2))
        mu[ut], cov[ut] = lin.propagate(lambda x: _points(x, pose)[..., 0, :], zp[ut], q)
    return mu, cov


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
    return _polar_point_distribution(z.reshape(-1, 2), pose, sensor, lin)


def initial_grouping(
    mu_c: np.ndarray, cov_c: np.ndarray, config: ModelConfig
) -> list[tuple[int, int]]:
    """Algorithm 3: initial groups of consecutive measurements.

    A group ``a..b`` grows while every point's perpendicular distance to the line fitted
    to ``a..b`` is within ``grouping_mahalanobis`` standard deviations; when point ``b``
    breaks that, the group ends at ``b - 1`` and the next starts there.

    Args:
        mu_c: ``(n, 2)`` Cartesian measurement means [m].
        cov_c: ``(n, 2, 2)`` their covariances [m^2].

    Returns:
        Groups ``(a, b)`` of local indices (inclusive); consecutive groups share ``b``.
    """
    return list(_groups(mu_c, cov_c, config))


def several_groups(mu_c: np.ndarray, cov_c: np.ndarray, config: ModelConfig) -> bool:
    """Whether :func:`initial_grouping` finds more than one group (4.3.3's test).

    Stops at the first group that ends before the last measurement instead of grouping
    them all.
    """
    first = next(_groups(mu_c, cov_c, config))
    return first[1] < mu_c.shape[0] - 1


def _groups(mu_c: np.ndarray, cov_c: np.ndarray, config: ModelConfig) -> Iterator[tuple[int, int]]:
    """:func:`initial_grouping`'s groups, in order, as they are found."""
    n = mu_c.shape[0]
    start = config.min_group_size - 1
    # Prefix sums make each trial line fit O(1). For one group start ``a`` the trial ends
    # ``b`` are tested in vectorised batches (each batch twice as long as the one before)
    # instead of one at a time.
    x, y = mu_c[:, 0], mu_c[:, 1]
    terms = np.empty((6, n))  # 1, x, y, x x, y y, x y per point
    terms[0] = 1.0
    terms[1:3] = mu_c.T
    np.multiply(terms[1:3], terms[1:3], out=terms[3:5])
    np.multiply(x, y, out=terms[5])
    cs = np.zeros((6, n + 1))
    np.cumsum(terms, axis=1, out=cs[:, 1:])
    cxx, cxy, cyy = cov_c[:, 0, 0], cov_c[:, 0, 1], cov_c[:, 1, 1]
    limit = config.grouping_mahalanobis**2
    a, b = 0, start
    batch = _GROUPING_BATCH
    while b < n:
        stop = min(b + batch, n)
        ends = np.arange(b, stop)
        cnt, sx, sy, sxx, syy, sxy = cs[:, b + 1 : stop + 1] - cs[:, a, None]  # sums a..ends
        mx, my = sx / cnt, sy / cnt
        psi = 0.5 * np.arctan2(2.0 * (sxy - sx * my), (sxx - sx * mx) - (syy - sy * my))
        nx, ny = -np.sin(psi)[:, None], np.cos(psi)[:, None]
        # rows: trial ends b; columns: points a..ends[-1] (only those <= b count)
        pts = slice(a, ends[-1] + 1)
        mu_d = (x[pts] - mx[:, None]) * nx + (y[pts] - my[:, None]) * ny
        var_d = nx * nx * cxx[pts] + 2.0 * nx * ny * cxy[pts] + ny * ny * cyy[pts]
        outside = (mu_d * mu_d > limit * var_d) & (np.arange(a, ends[-1] + 1) <= ends[:, None])
        failed = np.flatnonzero(outside.any(axis=1))
        if failed.size == 0:
            b = int(ends[-1]) + 1
            batch *= 2
            continue
        b = int(ends[failed[0]])
        yield a, b - 1
        a = b - 1
        b = a + start
        batch = _GROUPING_BATCH
    yield a, n - 1


# ------------------------------------------------------------- Algorithms 1-2


@dataclass
class _LineEval:
    """A line fitted to local measurements ``a..b`` and each measurement's log-likelihood."""

    a: int
    b: int
    loglik: np.ndarray  # (b - a + 1,)
    total: float = 0.0

    def __post_init__(self) -> None:
        self.total = float(self.loglik.sum())


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
        # z (2n,) and the variances var (2n,) of its independent entries
        self.z, self.var = _stacked(scan, first, last, sensor)
        self.points = _points(self.z, self.pose)  # (n, 2) world-frame points [m]
        self.n = last - first + 1
        self.point_cov = np.zeros((self.n, 2, 2))
        self.closed_form = False  # the closed-form first order (use_point_covariances)
        self._fast: _FirstOrderLines | None = None
        self._fits: tuple[tuple[tuple[int, int], ...], _SpanFits] | None = None

    def span_fits(self, spans: list[tuple[int, int]]) -> _SpanFits:
        """:class:`_SpanFits` of ``points`` over local ``spans`` (the last spans' kept)."""
        key = tuple(spans)
        if self._fits is None or self._fits[0] != key:
            self._fits = (key, _SpanFits(self.points, spans))
        return self._fits[1]

    @property
    def fast(self) -> _FirstOrderLines | None:
        """The closed-form first-order line scores (built on first use), None without."""
        if self._fast is None and self.closed_form:
            self._fast = _FirstOrderLines(self, self.point_cov)
        return self._fast

    def use_point_covariances(self, point_cov: np.ndarray) -> None:
        """Store the Cartesian point covariances; enable the closed-form first order."""
        self.point_cov = point_cov
        self._fast = None
        self.closed_form = isinstance(self.lin, FirstOrderLinearization)

    def line_distribution(self, a: int, b: int) -> tuple[np.ndarray, np.ndarray]:
        """Gaussian of ``(p0, p1)`` ``(4,)`` of the line fitted to local beams ``a..b``.

        ``p1 = p0 + d`` with a unit direction ``d`` (``beta = 1``), so the covariance has
        rank 3 by construction (``||p1 - p0|| = 1``); it is not checked for definiteness.
        """
        sl = slice(2 * a, 2 * b + 2)

        def f(x):
            p0, d = _oriented_line(_points(x, self.pose))
            return np.concatenate([p0, p0 + d], axis=-1)

        return self.lin.propagate(f, self.z[sl], np.diag(self.var[sl]), check=False)

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

    def evaluate_lines(self, spans: list[tuple[int, int]]) -> list[_LineEval]:
        """:meth:`evaluate_line` for many spans; closed form and batched for first order."""
        if not spans:
            return []
        if self.fast is None:
            return [self.evaluate_line(a, b) for a, b in spans]
        return [
            _LineEval(a, b, ll) for (a, b), ll in zip(spans, self.fast.loglik(spans), strict=True)
        ]

    def bic(self, lines: list[_LineEval]) -> float:
        """BIC score (3.2.26) of a model made of ``lines``, shared measurements once."""
        m = len(lines)
        k = m + 1
        dup = sum(min(lines[j].loglik[-1], lines[j + 1].loglik[0]) for j in range(m - 1))
        dup = float(dup)
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

    def evaluate(spans: list[tuple[int, int]]) -> None:
        new = [sp for sp in dict.fromkeys(spans) if sp not in cache]
        for line in modeller.evaluate_lines(new):
            cache[(line.a, line.b)] = line

    pairs = [(groups[j][0], groups[j + 1][1]) for j in range(len(groups) - 1)]
    if modeller.fast is not None and len(groups) <= _PRECOMPUTED_JOINS_MAX_GROUPS:
        # Closed form: every line the joins can produce, in one batch.
        g = len(groups)
        evaluate([(groups[i][0], groups[j][1]) for i in range(g) for j in range(i, g)])
    else:
        evaluate(list(groups) + pairs)
    lines = [cache[g] for g in groups]
    bic = np.full(len(lines), -np.inf)
    best_groups = {len(lines): [(ln.a, ln.b) for ln in lines]}
    bic[len(lines) - 1] = modeller.bic(lines)

    def loss(j: int) -> float:
        """Log-likelihood lost by joining lines ``j`` and ``j + 1`` (Algorithm 2)."""
        joined = cache[(lines[j].a, lines[j + 1].b)]
        dup = min(lines[j].loglik[-1], lines[j + 1].loglik[0])
        return lines[j].total + lines[j + 1].total - dup - joined.total

    losses = [loss(j) for j in range(len(lines) - 1)]
    while len(lines) > 1:
        j = int(np.argmin(losses))
        lines[j : j + 2] = [cache[(lines[j].a, lines[j + 1].b)]]
        del losses[j]
        touched = [i for i in (j - 1, j) if 0 <= i < len(lines) - 1]
        evaluate([(lines[i].a, lines[i + 1].b) for i in touched])
        for i in touched:
            losses[i] = loss(i)
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
    distances of the window's points to the two lines (each fitted without the window,
    to at least three points), and the lines are fitted to ``..k`` and ``k + 1..`` only.
    Shorter lines keep the shared measurement.
    """
    slices = [list(g) for g in groups]
    if not exclusive:
        return [tuple(s) for s in slices]
    for j in range(len(groups) - 1):
        left, right = slices[j], slices[j + 1]
        shared = groups[j][1]
        # Each side's reference line is fitted without the window and needs three points:
        # a line through two noisy points at a grazing angle can be far off.
        lo = max(shared - window, left[0] + 3)
        hi = min(shared + window, right[1] - 3)
        if lo > hi:
            continue
        residual = []
        for a, b in ((left[0], lo - 1), (hi + 1, right[1])):
            p0, psi = _principal_axis(points[a : b + 1])
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
    pts = modeller.points
    fit = modeller.span_fits(groups)
    d = np.empty((len(groups) + 2, 2))  # end line, the groups' lines, end line
    d[0], d[-1] = pts[0] - modeller.pose[:2], pts[-1] - modeller.pose[:2]
    lines = d[1:-1]
    lines[:, 0], lines[:, 1] = np.cos(fit.psi), np.sin(fit.psi)
    # Oriented from each group's first towards its last point (as _oriented_line).
    ends = np.asarray(groups, dtype=int).reshape(-1, 2)
    span = pts[ends[:, 1]] - pts[ends[:, 0]]
    lines *= np.where((lines * span).sum(-1) < 0.0, -1.0, 1.0)[:, None]
    cross = d[:-1, 0] * d[1:, 1] - d[:-1, 1] * d[1:, 0]
    norms = np.hypot(d[:-1, 0], d[:-1, 1]) * np.hypot(d[1:, 0], d[1:, 1])
    positive = norms > 0
    if positive.all():  # the usual case: no zero-length line
        return np.abs(cross) / norms
    with np.errstate(divide="ignore", invalid="ignore"):  # a zero-length line: sine 0
        return np.where(positive, np.abs(cross) / np.where(positive, norms, 1.0), 0.0)


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
    points = modeller.points
    slices = fit_slices(
        points, groups, modeller.config.exclusive_boundaries, modeller.config.boundary_window
    )
    offset_var = np.zeros(0)
    if modeller.config.coarseness > 0:
        var = coarseness_variances(
            points,
            modeller.point_cov,
            slices,
            modeller.config.coarseness_significance,
            modeller.span_fits(slices),
        )
        offset_var = modeller.config.coarseness**2 * var
    if modeller.closed_form:
        mu, sigma = _first_order_vertices(modeller, slices, offset_var)
        return groups, mu, sigma
    z = np.concatenate([modeller.z, np.zeros(offset_var.size)])
    cov = np.diag(np.concatenate([modeller.var, offset_var]))
    mu, sigma = modeller.lin.propagate(_vertex_function(slices, modeller.pose, modeller.n), z, cov)
    return groups, mu.reshape(-1, 2), sigma


def _first_order_vertices(
    modeller: _SegmentModeller, slices: list[tuple[int, int]], offset_var: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Closed-form first-order vertex distribution (hot path of :func:`vertex_distribution`).

    Every line is ``n . x = c`` with unit normal ``n``. An object line moves with its
    offset ``rho`` along ``n`` and its angle ``psi`` about its centroid ``p0`` (the
    derivatives of :class:`_FirstOrderLines`, plus the model-error offset of
    :func:`coarseness_variances`); an end line is the first or last beam's ray, so it
    turns with that beam's bearing only. A vertex solves ``M v = c`` for its two lines,
    so ``dv = M^-1 (dc - dM v)``: ``dv/drho_A = M^-1 e_A`` and
    ``dv/dpsi_A = M^-1 e_A * d_A . (v - p_A)`` for rotation about ``p_A``. Batched over
    the lines and the vertices.

    Returns:
        ``(m + 1, 2)`` vertex means [m] and their ``(2m + 2, 2m + 2)`` covariance.
    """
    pose, n = modeller.pose, modeller.n
    m = len(slices)
    n_in = 2 * n + offset_var.size
    fit = modeller.span_fits(slices)
    # Lines k = 0..m+1: k = 0 left end, 1..m object lines, m + 1 right end. Each line's
    # Jacobian rows: d rho (n_in,) and d psi (n_in,); a point p (2,) and direction d (2,).
    j_rho = np.zeros((m + 2, n_in))
    j_psi = np.zeros((m + 2, n_in))
    lines_p = np.empty((m + 2, 2))
    angles = np.empty(m + 2)  # of the lines' directions [rad]
    lines_p[0] = lines_p[-1] = pose[:2]
    angles[0], angles[-1] = pose[2] + modeller.z[1], pose[2] + modeller.z[-1]
    j_psi[0, 1] = 1.0  # the left end line turns with the first beam's bearing
    j_psi[-1, 2 * n - 1] = 1.0  # the right one with the last beam's

    # The line geometry per line as in _principal_axis (the vertex means then agree to the
    # last bit with a line-by-line evaluation; downstream ICP is sensitive to that).
    for k, (lo, hi) in enumerate(slices, start=1):
        lines_p[k], angles[k] = _principal_axis(modeller.points[lo : hi + 1])
    lines_d = stack_last(np.cos(angles), np.sin(angles))  # elementwise: as line by line
    dx, dy = lines_d[1:-1, 0, None], lines_d[1:-1, 1, None]  # normal (-dy, dx)
    gap = np.hypot(fit.sxx - fit.syy, 2.0 * fit.sxy)[:, None]
    de = fit.ex * dx + fit.ey * dy
    ne = fit.ey * dx - fit.ex * dy
    gx = (de * -dy + ne * dx) / gap  # d psi / d z_k, (m, W)
    gy = (de * dx + ne * dy) / gap
    # Chain through polar: d z_k / d (r_k, phi_k) = [[cos a, -r sin a], [sin a, r cos a]].
    r, angle = modeller.z[0::2][fit.idx], pose[2] + modeller.z[1::2][fit.idx]
    c, s_ = np.cos(angle), np.sin(angle)
    rho_r = (-dy * c + dx * s_) / fit.cnt[:, None]
    rho_phi = (dy * s_ + dx * c) * r / fit.cnt[:, None]
    psi_r = gx * c + gy * s_
    psi_phi = (-gx * s_ + gy * c) * r
    rows = np.repeat(np.arange(1, m + 1), fit.lengths)  # the mask's row of each entry
    cols = 2 * fit.idx[fit.mask]
    j_rho[rows, cols], j_rho[rows, cols + 1] = rho_r[fit.mask], rho_phi[fit.mask]
    j_psi[rows, cols], j_psi[rows, cols + 1] = psi_r[fit.mask], psi_phi[fit.mask]
    if offset_var.size:
        j_rho[np.arange(1, m + 1), 2 * n + np.arange(m)] = 1.0

    # Vertex i joins lines i (A) and i + 1 (B): solve [n_A; n_B] v = [n_A . p_A; n_B . p_B].
    pa, da, pb, db = lines_p[:-1], lines_d[:-1], lines_p[1:], lines_d[1:]
    normals = stack_last(-lines_d[:, 1], lines_d[:, 0])
    offsets = np.vecdot(normals, lines_p)  # row by row, as nrm @ p (the same dot kernel)
    mat = np.empty((m + 1, 2, 2))
    mat[:, 0], mat[:, 1] = normals[:-1], normals[1:]
    mu = np.linalg.solve(mat, stack_last(offsets[:-1], offsets[1:])[..., None])[..., 0]
    inv = np.linalg.inv(mat)
    row_a = j_rho[:-1] + (da * (mu - pa)).sum(1)[:, None] * j_psi[:-1]
    row_b = j_rho[1:] + (db * (mu - pb)).sum(1)[:, None] * j_psi[1:]
    jac = inv[:, :, 0, None] * row_a[:, None, :] + inv[:, :, 1, None] * row_b[:, None, :]
    jac = jac.reshape(2 * (m + 1), n_in)
    var_in = np.concatenate([modeller.var, offset_var])
    sigma = symmetrize((jac * var_in) @ jac.T)
    return mu, sigma


@functools.lru_cache(maxsize=1024)
def _chi2_limit(dof: int, significance: float) -> float:
    """Chi-square value exceeded with probability ``significance`` at ``dof`` degrees of freedom.

    ``scipy.special.chdtri(dof, 1 - significance)``, kept per argument pair: the hot
    paths ask for a few small ``dof`` over and over.
    """
    return float(chdtri(dof, 1.0 - significance))


def coarseness_variances(
    points: np.ndarray,
    point_cov: np.ndarray,
    slices: list[tuple[int, int]],
    significance: float,
    fit: _SpanFits | None = None,
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

    ``fit``: the lines' :class:`_SpanFits` of ``points`` over ``slices``, if already made.

    Returns:
        ``(m,)`` variances, one per line.
    """
    fit = _SpanFits(points, slices) if fit is None else fit
    nx, ny = -np.sin(fit.psi)[:, None], np.cos(fit.psi)[:, None]
    d2 = (fit.ex * nx + fit.ey * ny) ** 2  # 0 on the padding
    cov = point_cov[fit.idx]
    var = nx * nx * cov[..., 0, 0] + 2.0 * nx * ny * cov[..., 0, 1] + ny * ny * cov[..., 1, 1]
    var = np.where(fit.mask, var, 1.0)  # padding: any positive value (its d2 is 0)
    dof = np.maximum(fit.lengths - 2, 0)
    # A line through at most two points has no residual degrees of freedom: no evidence.
    has_dof = dof > 0
    excess = np.where(has_dof, d2.sum(1) - dof * (var * fit.w).sum(1) / fit.cnt, 0.0)
    stat = np.where(has_dof, (d2 / var).sum(1), 0.0)
    # Only residuals that the noise cannot explain (chi-square test) count as model error.
    limits = [_chi2_limit(d, significance) for d in np.maximum(dof, 1).tolist()]
    significant = stat > np.array(limits)
    per_line = np.where(significant, np.maximum(excess, 0.0) / np.maximum(dof, 1), 0.0)
    pooled_significant = stat.sum() > _chi2_limit(max(int(dof.sum()), 1), significance)
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

    left, right = side(first, first - 1, 1.0), side(last, last + 1, -1.0)
    zp = np.array(left + right, dtype=float)
    mu, blocks = _polar_point_distribution(zp, pose, sensor, lin)
    zero = zp[:, 0] == 0.0
    if np.any(zero):
        # A zero-range point spreads along its beam only (rank 1): add the floor.
        blocks[zero] += config.zero_range_vertex_sigma**2 * np.eye(2)
    result = []
    for sl in (slice(0, len(left)), slice(len(left), zp.shape[0])):
        q = sl.stop - sl.start
        big = np.zeros((2 * q, 2 * q))
        for i, blk in enumerate(blocks[sl]):
            big[2 * i : 2 * i + 2, 2 * i : 2 * i + 2] = blk
        result.append((mu[sl], big))
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
    d = _segment_lengths(mu_v) / np.maximum(gaps, 1.0)
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
    if not np.isfinite(pose).all():
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
    modeller.use_point_covariances(cov_c)
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
