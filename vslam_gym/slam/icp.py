"""Correspondence by ICP: align a set of measurements to a landmark model (SPEC 10 item 2).

Thesis 4.3.4-4.3.16 (ICP adapted to a polyline landmark) and the candidate gate before
it (T:4318-4326), read as in ``notes/update_algorithms.md`` sections 5.1-5.2 (register
R-22 to R-24):

1. the lines *visible* from the current pose estimate are the front-facing ones
   (``cross(v_a - p, v_b - p) < 0``, the free side of every line is on the right of its
   direction ``v_a -> v_b``), optionally restricted to the field of view and the maximum
   range; they are recomputed every iteration; a closed polygon includes the line
   ``k - 1 -> 0``;
2. each point is matched to its nearest visible line *segment* (distance to the segment,
   not to the infinite line, R-22); its signed distance to that line's infinite extension,
   ``e = n . (q - v_a)`` with the free-side normal ``n = [sin psi, -cos psi]`` (4.3.12), is
   ``> 0`` in front and ``<= 0`` behind;
3. a point behind (or on) an unknown line (``u > unknown_threshold``) is ignored in this
   iteration; a point in front of one, and any point matched to an object line, pulls
   towards the foot point on the line: ``d = -e n`` (4.3.15, ``d = target - q``);
4. the increment ``t = H^-1 b`` with ``H = sum J^T J``, ``b = sum J^T d`` and
   ``J = [[1, 0, -q_y], [0, 1, q_x]]`` (4.3.9-4.3.10), by default written in coordinates
   centred on the used points' centroid; the points move by ``t`` (4.3.4), the total
   transform composes as ``t_f := t o t_f`` (4.3.11) and the pose estimate is ``t_f``
   applied to the prior pose with the heading ``theta + t_f,theta`` (4.3.16 corrected,
   R-23).

The thesis's form is point-to-point ICP against the foot points (each point's full
``2 x 2`` Hessian, so sliding along a line is regularised towards no motion);
``IcpConfig.point_to_line`` selects the point-to-plane variant (only the perpendicular
residual). Both have the same fixed points for a fixed association: ``sum_i e_i a_i = 0``
with ``a_i = n_i^T J_i``. The thesis form converges linearly, slowly where the lines give
a weak constraint along them (measured: 30-50 iterations from 0.3 m / 5 deg on an L or a
zig-zag, over 400 on an L with a 26 deg turn); point-to-line takes 3-7.

Frames and units: points, vertices and poses are in the world frame ([m], [m], [rad]);
bearings for the field-of-view test are relative to the lidar heading [rad]. Everything
is vectorised over points and lines: dense ``(n, n_lines)`` arrays per iteration, the
invisible lines masked out.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from vslam_gym.slam.geometry import check_pose, wrap_angle
from vslam_gym.slam.landmark import LandmarkModel

__all__ = [
    "IcpConfig",
    "IcpResult",
    "LineGeometry",
    "PoseBound",
    "align",
    "align_many",
    "candidate_landmarks",
    "line_geometry",
    "object_radius",
    "visible_lines",
]

TWO_PI = 2.0 * np.pi
_sum = np.add.reduce  # ndarray.sum without the Python wrapper (same summation)


@dataclass(frozen=True)
class IcpConfig:
    """Parameters of the ICP alignment (thesis 4.3.4-4.3.16; the thesis gives no numbers).

    Attributes:
        max_iterations: most least-squares steps per alignment.
        tol_translation: convergence when a step moves the centroid of the used points by
            less than this [m] ...
        tol_rotation: ... and rotates them by less than this [rad]. With the thesis
            form's slow linear convergence a small step does not guarantee a small
            error (measured: "converged" 1 cm from the fixed point on a shallow corner).
        min_points: fewer usable points in an iteration stop the alignment (not
            converged). At least 2; the point-to-line variant needs 3 on two
            non-parallel lines to fix all three degrees of freedom.
        unknown_threshold: a line with ``u > unknown_threshold`` is an unknown line
            (same meaning as ``ModelConfig.unknown_threshold``); points behind it are
            ignored.
        centre_on_centroid: solve each step in coordinates centred on the used points'
            centroid (rotation about the centroid). The linearised solution is the same
            as the thesis's rotation about the world origin, and the fixed point is
            identical, but ``H`` is well conditioned far from the origin and a step does
            not carry the second-order error of a rotation about a distant origin.
        point_to_line: False: the thesis's point-to-foot-point form (``H = sum J^T J``);
            True: the point-to-plane variant (``H = sum J^T n n^T J``), which converges
            in a few iterations but is singular when the used lines cannot fix all three
            degrees of freedom (all parallel, or every point on one line).
        max_condition: a step whose ``H`` has a condition number above this is treated
            as singular and stops the alignment (not converged). Not a thesis value.
        cycle_returns: stop the alignment (not converged, reason ``"cycle"``) the
            ``cycle_returns``-th time it returns to an earlier state: an iteration's
            association (nearest line of every point and which points are used) differs
            from the previous iteration's but equals an earlier one, at a pose within
            ``tol_translation`` and ``tol_rotation`` of the pose it had then. The nearest
            segments then alternate for good, and the alignment would run to
            ``max_iterations`` without converging: the state of the cycle it would have
            reached there is returned (the same pose within the tolerances), without
            the iterations. 0 (the thesis) never stops. Not a thesis value.
        freeze_on_cycle: when an iteration's association (nearest line of every point
            and which points are used) equals one of an earlier iteration other than the
            previous one, the nearest segments alternate: keep that association (and
            stop recomputing visibility) for the remaining steps, so the alignment
            converges to its fixed point in a few steps instead of alternating to
            ``max_iterations``; the result's ``reason`` reads ``"converged"`` or
            ``"max_iterations"`` as usual and ``frozen`` is True. False (the thesis)
            recomputes the association every step. Not a thesis value.
        max_correspondence_distance: a point farther than this [m] from its nearest
            visible segment is not used in that iteration (outlier rejection, as in most
            ICP variants; not in the thesis, ``inf``). A set that sees more than a
            partial model holds, e.g. a whole room against a landmark of one corner,
            otherwise pulls every point onto the model, and the alignment ends far from
            the overlap (measured on ``house``: headings 1.3 rad off at a revisit).
            Measured at 0.5 m (``vslam-gym evaluate``, seeds 0-9): position ATE 0.213 /
            0.129 / 0.102 / 0.249 -> 0.202 / 0.143 / 0.099 / 0.239 m (single_landmark /
            small / curved / house), ``house`` final error 0.315 -> 0.402 m; Radish
            logs: Intel 0.61 -> 0.56 m, ACES 1.36 -> 1.51 m. Not in any preset.
    """

    max_iterations: int = 50
    tol_translation: float = 1e-4
    tol_rotation: float = 1e-5
    min_points: int = 2
    unknown_threshold: float = 0.5
    centre_on_centroid: bool = True
    point_to_line: bool = False
    max_condition: float = 1e10
    cycle_returns: int = 0
    freeze_on_cycle: bool = False
    max_correspondence_distance: float = math.inf

    def __post_init__(self) -> None:
        if isinstance(self.max_iterations, bool) or int(self.max_iterations) < 1:
            raise ValueError(f"IcpConfig.max_iterations must be >= 1, got {self.max_iterations}")
        if isinstance(self.min_points, bool) or int(self.min_points) < 2:
            raise ValueError(f"IcpConfig.min_points must be >= 2, got {self.min_points}")
        for name in ("tol_translation", "tol_rotation"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value > 0):
                raise ValueError(f"IcpConfig.{name} must be finite and > 0, got {value!r}")
        if not 0.0 <= self.unknown_threshold <= 1.0:
            raise ValueError(
                f"IcpConfig.unknown_threshold must lie in [0, 1], got {self.unknown_threshold}"
            )
        if not (np.isfinite(self.max_condition) and self.max_condition > 1.0):
            raise ValueError(f"IcpConfig.max_condition must be > 1, got {self.max_condition}")
        if isinstance(self.cycle_returns, bool) or int(self.cycle_returns) < 0:
            raise ValueError(f"IcpConfig.cycle_returns must be >= 0, got {self.cycle_returns}")
        if not self.max_correspondence_distance > 0.0:  # inf allowed; NaN fails
            raise ValueError(
                "IcpConfig.max_correspondence_distance must be > 0 [m], got "
                f"{self.max_correspondence_distance!r}"
            )


@dataclass(frozen=True)
class IcpResult:
    """Outcome of :func:`align`.

    Attributes:
        pose: ``(3,)`` the aligned lidar pose ``x_icp = [x, y, theta]`` (world frame; the
            heading is the prior's plus ``transform[2]``, not wrapped, so that
            ``pose - prior`` is the correction).
        transform: ``(3,)`` the accumulated transform ``t_f = [t_x, t_y, t_theta]`` [m, m,
            rad]: the aligned points are ``R(t_theta) points + [t_x, t_y]`` (world frame,
            rotation about the world origin).
        iterations: least-squares steps taken (0 when the first iteration already had too
            few usable points).
        converged: True when the last step was below both tolerances.
        n_used: points that contributed to the last iteration.
        rms: root mean square of those points' perpendicular distances to their lines
            [m], at the start of the last iteration; ``inf`` when no point was used.
        reason: why the alignment stopped: ``"converged"``, ``"max_iterations"``,
            ``"too_few_points"``, ``"singular"``, ``"cycle"`` (``IcpConfig.cycle_returns``)
            or ``"out_of_bound"`` (the pose left the caller's bound, :func:`align_many`).
        frozen: the association was frozen after a cycle (``IcpConfig.freeze_on_cycle``).
    """

    pose: np.ndarray
    transform: np.ndarray
    iterations: int
    converged: bool
    n_used: int
    rms: float
    reason: str
    frozen: bool = False


@dataclass(frozen=True)
class PoseBound:
    """An ellipsoid around the prior pose: ``||W d|| <= limit`` for an offset ``d``.

    Attributes:
        whitening: ``(3, 3)`` ``W`` (e.g. the inverse Cholesky factor of a gate
            covariance), applied to ``d = [dx [m], dy [m], dtheta [rad]]``.
        limit: the largest allowed ``||W d||`` (a Mahalanobis distance).
    """

    whitening: np.ndarray
    limit: float

    def __post_init__(self) -> None:
        w = np.asarray(self.whitening, dtype=float)
        if w.shape != (3, 3) or not np.all(np.isfinite(w)):
            raise ValueError(f"PoseBound.whitening must be a finite (3, 3) matrix, got {w!r}")
        if not self.limit >= 0.0:
            raise ValueError(f"PoseBound.limit must be >= 0, got {self.limit!r}")
        object.__setattr__(self, "_rows", tuple(tuple(float(v) for v in row) for row in w))

    def outside(self, dx: float, dy: float, dtheta: float) -> bool:
        """True when the offset (heading wrapped to ``[-pi, pi)``) is beyond the bound."""
        dth = (dtheta + math.pi) % TWO_PI - math.pi
        m2 = 0.0
        for a, b, c in self._rows:  # type: ignore[attr-defined]
            v = a * dx + b * dy + c * dth
            m2 += v * v
        return m2 > self.limit * self.limit


# ------------------------------------------------------------------------ validation


def _check_points(points: object) -> np.ndarray:
    try:
        arr = np.array(points, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ValueError("points must be a numeric (n, 2) array") from exc
    if arr.ndim != 2 or arr.shape[1] != 2:
        raise ValueError(f"points must have shape (n, 2) [m], got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        bad = np.flatnonzero(~np.all(np.isfinite(arr), axis=1))
        raise ValueError(f"points contain NaN or inf at rows {bad[:5].tolist()}")
    return arr


def _check_model(model: object) -> LandmarkModel:
    if not isinstance(model, LandmarkModel):
        raise ValueError(f"model must be a LandmarkModel, got {type(model).__name__}")
    if model.n_lines < 1:
        raise ValueError(f"model must have at least one line, got {model.n_vertices} vertices")
    if not np.all(np.isfinite(model.mean)):
        raise ValueError("model vertex means must be finite")
    return model


def _check_limits(max_range: float | None, half_fov: float | None) -> None:
    if max_range is not None and not (np.isfinite(max_range) and max_range > 0):
        raise ValueError(f"max_range must be finite and > 0 [m], got {max_range!r}")
    if half_fov is not None and not (np.isfinite(half_fov) and 0 < half_fov <= np.pi):
        raise ValueError(f"half_fov must lie in (0, pi] [rad], got {half_fov!r}")


# ------------------------------------------------------------------------ visibility


def _unit_clip(s: np.ndarray) -> np.ndarray:
    """Clip to ``[0, 1]`` (``np.clip`` has a large per-call overhead on small arrays)."""
    return np.minimum(np.maximum(s, 0.0), 1.0)


class _Lines:
    """Per-line constants of a model, as separate coordinate arrays ``(L,)`` (fast paths).

    Built by :func:`line_geometry` (public name :data:`LineGeometry`).
    """

    index: np.ndarray | None = None

    def __init__(self, model: LandmarkModel) -> None:
        idx = model.line_vertices()
        a = model.mean[idx[:, 0]]
        ab = model.mean[idx[:, 1]] - a
        self.ax, self.ay = a[:, 0].copy(), a[:, 1].copy()
        self.abx, self.aby = ab[:, 0].copy(), ab[:, 1].copy()
        length2 = self.abx * self.abx + self.aby * self.aby
        ok = length2 > 0
        # Zero-length lines get zero normals and inverse lengths; they are never visible.
        self.inv_length2 = np.divide(1.0, length2, out=np.zeros_like(length2), where=ok)
        inv_length = np.sqrt(self.inv_length2)
        # Free-side (right-hand) unit normal n = [sin psi, -cos psi] (4.3.12).
        self.nx, self.ny = self.aby * inv_length, -self.abx * inv_length
        self._subsets: dict[bytes, _Lines] = {}

    def subset(self, mask: np.ndarray) -> _Lines:
        """The lines where ``mask`` ``(L,)`` is True, in order (cached per mask).

        ``index`` maps the subset's lines to this geometry's (None: all lines).
        """
        if mask.size == np.count_nonzero(mask):
            return self
        key = mask.tobytes()
        sub = self._subsets.get(key)
        if sub is None:
            sub = object.__new__(_Lines)
            sub.index = np.flatnonzero(mask)
            for name in ("ax", "ay", "abx", "aby", "inv_length2", "nx", "ny"):
                setattr(sub, name, getattr(self, name)[sub.index])
            self._subsets[key] = sub
        return sub

    def visible(
        self, pose: np.ndarray, max_range: float | None, half_fov: float | None
    ) -> np.ndarray:
        """Visibility mask ``(L,)`` bool from ``pose`` (see :func:`visible_lines`)."""
        return self.visible_from(*pose.tolist(), max_range, half_fov)

    def visible_from(
        self, px: float, py: float, theta: float, max_range: float | None, half_fov: float | None
    ) -> np.ndarray:
        """:meth:`visible` from a pose given as floats ``px, py`` [m], ``theta`` [rad]."""
        pax = self.ax - px
        pay = self.ay - py
        pbx = pax + self.abx
        pby = pay + self.aby
        # Front-facing: cross(v_a - p, v_b - p) < 0 (the position is on the free side).
        mask = pax * pby < pay * pbx
        if not np.count_nonzero(mask):  # nothing faces the lidar: the other tests cannot add a line
            return mask
        if max_range is not None:
            s = _unit_clip(-(pax * self.abx + pay * self.aby) * self.inv_length2)
            cx = pax + s * self.abx
            cy = pay + s * self.aby
            mask &= cx * cx + cy * cy <= max_range * max_range
        if half_fov is not None and half_fov < np.pi:
            # A front-facing line spans the bearings from phi_b up to phi_a (< pi apart);
            # two arcs of the circle overlap iff the start of one lies inside the other.
            phi_b = np.arctan2(pby, pbx) - theta
            span = np.mod(np.arctan2(pay, pax) - theta - phi_b, TWO_PI)
            start_in_fov = np.mod(phi_b + half_fov, TWO_PI) <= 2.0 * half_fov
            fov_start_in_line = np.mod(-half_fov - phi_b, TWO_PI) <= span
            mask &= start_in_fov | fov_start_in_line
        return mask


def visible_lines(
    model: LandmarkModel,
    pose: np.ndarray,
    max_range: float | None = None,
    half_fov: float | None = None,
) -> np.ndarray:
    """Lines of ``model`` visible from ``pose`` (R-24): ``(n_lines,)`` bool.

    A line is visible when it is front-facing (the lidar position lies on its free,
    right-hand side: ``cross(v_a - p, v_b - p) < 0``), when ``max_range`` is given its
    closest point is within ``max_range`` [m] of the lidar, and when ``half_fov`` [rad]
    is given its bearing interval overlaps ``[-half_fov, half_fov]`` around the heading.
    Occlusion by other lines is not tested. Line order as in
    :meth:`LandmarkModel.line_vertices` (a closed polygon includes ``k - 1 -> 0``).

    Raises:
        ValueError: malformed model, pose or limits.
    """
    model = _check_model(model)
    pose = check_pose(pose)
    _check_limits(max_range, half_fov)
    return _Lines(model).visible(pose, max_range, half_fov)


LineGeometry = _Lines
"""Per-line constants of a model (:func:`line_geometry`)."""


# ------------------------------------------------------------------------ ICP


def _condition_sym3(h00, h01, h02, h11, h12, h22) -> float:
    """Condition number ``l_max / l_min`` of a symmetric ``3 x 3`` matrix (closed form).

    Eigenvalues by the trigonometric method (O. K. Smith, 1961) on Python floats; ``inf``
    when the smallest eigenvalue is not positive.
    """
    p1 = h01 * h01 + h02 * h02 + h12 * h12
    m = (h00 + h11 + h22) / 3.0
    b00, b11, b22 = h00 - m, h11 - m, h22 - m
    p = math.sqrt((b00 * b00 + b11 * b11 + b22 * b22 + 2.0 * p1) / 6.0)
    if p == 0.0:
        return 1.0 if m > 0 else math.inf
    det_b = (
        b00 * (b11 * b22 - h12 * h12)
        - h01 * (h01 * b22 - h12 * h02)
        + h02 * (h01 * h12 - b11 * h02)
    )
    r = min(max(det_b / (2.0 * p * p * p), -1.0), 1.0)
    phi = math.acos(r) / 3.0
    l_max = m + 2.0 * p * math.cos(phi)
    l_min = m + 2.0 * p * math.cos(phi + 2.0 * math.pi / 3.0)
    return l_max / l_min if l_min > 0 else math.inf


def _solve_spd3(
    h: tuple[float, float, float, float, float, float],
    b: tuple[float, float, float],
    max_condition: float,
) -> tuple[float, float, float] | None:
    """``H^-1 b`` for ``H = [[h00, h01, h02], [., h11, h12], [., ., h22]]`` by Cholesky.

    Python floats: for a ``3 x 3`` system this is several times faster than a LAPACK
    call through numpy. Returns None when ``H`` is singular or its condition number
    exceeds ``max_condition``.
    """
    h00, h01, h02, h11, h12, h22 = h
    if not _condition_sym3(h00, h01, h02, h11, h12, h22) <= max_condition:
        return None
    l00 = math.sqrt(h00)
    l10 = h01 / l00
    l20 = h02 / l00
    d11 = h11 - l10 * l10
    if d11 <= 0.0:
        return None
    l11 = math.sqrt(d11)
    l21 = (h12 - l20 * l10) / l11
    d22 = h22 - l20 * l20 - l21 * l21
    if d22 <= 0.0:
        return None
    l22 = math.sqrt(d22)
    y0 = b[0] / l00
    y1 = (b[1] - l10 * y0) / l11
    y2 = (b[2] - l20 * y0 - l21 * y1) / l22
    t2 = y2 / l22
    t1 = (y1 - l21 * t2) / l11
    t0 = (y0 - l10 * t1 - l20 * t2) / l00
    t = (t0, t1, t2)
    return t if all(math.isfinite(v) for v in t) else None


_State = tuple[tuple[float, float, float], float, float, float, int, float]
"""An ICP state: pose estimate, transform ``t_f`` and the used points and rms there."""


class _CycleWatch:
    """Finds an ICP alignment's return to an earlier state (``IcpConfig.cycle_returns``).

    A return: an iteration's association (nearest line of every point, used points)
    differs from the previous iteration's but equals an earlier one, and the pose
    estimate is within the convergence tolerances (``tol_translation`` [m] in position,
    ``tol_rotation`` [rad] in heading) of the pose that association was last seen at.
    From there on the states repeat with that period.
    """

    def __init__(self, config: IcpConfig) -> None:
        self.limit, self.returns = config.cycle_returns, 0
        self.tol_xy, self.tol_theta = config.tol_translation, config.tol_rotation
        self.seen: dict[bytes, int] = {}  # association -> last iteration it was seen at
        self.states: list[_State] = []  # the state at the start of every iteration
        self.last = b""
        self.start = self.period = 0

    def cycled(self, nearest: np.ndarray, keep: np.ndarray, state: _State) -> bool:
        """Record an iteration's association and state; True once ``limit`` returns."""
        key = nearest.tobytes() + keep.tobytes()
        i = len(self.states)
        self.states.append(state)
        if key != self.last:
            m = self.seen.get(key)
            if m is not None:
                (x, y, th), (xm, ym, thm) = state[0], self.states[m][0]
                if math.hypot(x - xm, y - ym) < self.tol_xy and abs(th - thm) < self.tol_theta:
                    self.returns += 1
                    self.start, self.period = m, i - m
            self.last = key
        self.seen[key] = i
        return self.returns >= self.limit

    def state_at(self, iteration: int) -> _State:
        """The state the cycle is in at the start of ``iteration`` (0: the prior)."""
        if iteration < len(self.states):
            return self.states[iteration]
        return self.states[self.start + (iteration - self.start) % self.period]


def align(
    points: np.ndarray,
    model: LandmarkModel,
    pose: np.ndarray,
    config: IcpConfig | None = None,
    max_range: float | None = None,
    half_fov: float | None = None,
) -> IcpResult:
    """Align a measurement set to a landmark model by ICP and return ``x_icp`` (4.3.4-4.3.16).

    Only the model's vertex means, ``u`` and ``closed`` are used (T:4203-4205). Each
    iteration: visible lines at the current estimate (:func:`visible_lines`), nearest
    visible segment per point, the unknown-line rule (a point behind or on an unknown
    line is ignored, one in front is pulled onto it; object lines pull from either
    side; a point farther than ``max_correspondence_distance`` from its segment is
    ignored), one least-squares step, composition (4.3.11) and the new pose (4.3.16 with
    ``theta + t_f,theta``). Stops when a step is below both tolerances (converged),
    after ``max_iterations`` steps, or when an iteration has fewer than ``min_points``
    usable points or a singular system (both not converged; the pose of the last good
    step is returned).

    Args:
        points: ``(n, 2)`` the set's Cartesian points [m], world frame, computed at
            ``pose`` (3.2.1).
        model: the landmark model (world frame).
        pose: ``(3,)`` prior lidar pose ``[x, y, theta]`` the points were computed at.
        config: ICP parameters; defaults when omitted.
        max_range: if given, lines farther than this [m] from the current estimate are
            not visible.
        half_fov: if given, lines entirely outside ``[-half_fov, half_fov]`` [rad] around
            the current heading are not visible.

    Returns:
        The aligned pose, the accumulated transform and diagnostics.

    Raises:
        ValueError: malformed points, model, pose or limits.
    """
    config = config or IcpConfig()
    q = _check_points(points)
    model = _check_model(model)
    pose0 = check_pose(pose)
    _check_limits(max_range, half_fov)
    return _align(q, model, _Lines(model), pose0, config, max_range, half_fov)


def align_many(
    points: np.ndarray | list[np.ndarray],
    models: list[LandmarkModel],
    pose: np.ndarray,
    config: IcpConfig | None = None,
    max_range: float | None = None,
    half_fov: float | None = None,
    *,
    lines: list[LineGeometry] | None = None,
    bounds: list[PoseBound | None] | None = None,
) -> list[IcpResult]:
    """:func:`align` of one set (or one set per model) to each of several models.

    The alignments are independent; this is :func:`align` per model, with each model's
    line geometry optionally precomputed (:func:`line_geometry`). Measured: running the
    alignments side by side in padded ``(models, points, lines)`` arrays was slower
    than one at a time (an iteration of the batch does the padded work of every model
    and lasts until the slowest alignment stops).

    Args:
        points: ``(n, 2)``, the set aligned to every model, or a list with one set per
            model.
        models: the landmark models (world frame).
        lines: optional :func:`line_geometry` of each model; the caller must keep them
            in step with the models' means.
        bounds: optional per model a :class:`PoseBound`: the alignment stops (reason
            ``"out_of_bound"``, the pose where it left) after the first step that takes
            the pose out of it. A caller that rejects results beyond a gate saves the
            iterations of a diverging alignment.
        (others): as :func:`align`.

    Returns:
        One :class:`IcpResult` per model, in order.

    Raises:
        ValueError: malformed points, models, pose or limits.
    """
    config = config or IcpConfig()
    models = [_check_model(m) for m in models]
    if isinstance(points, list):
        if len(points) != len(models):
            raise ValueError(f"got {len(points)} point sets for {len(models)} models")
        sets = [_check_points(p) for p in points]
    else:
        sets = [_check_points(points)] * len(models)
    pose0 = check_pose(pose)
    _check_limits(max_range, half_fov)
    if lines is None:
        lines = [_Lines(m) for m in models]
    if bounds is None:
        bounds = [None] * len(models)
    elif len(bounds) != len(models):
        raise ValueError(f"got {len(bounds)} bounds for {len(models)} models")
    return [
        _align(q, m, g, pose0, config, max_range, half_fov, b)
        for q, m, g, b in zip(sets, models, lines, bounds, strict=True)
    ]


def line_geometry(model: LandmarkModel) -> LineGeometry:
    """Per-line constants of a model's vertex means, for :func:`align_many` (a cache).

    They depend on the vertex means only.

    Raises:
        ValueError: malformed model.
    """
    return _Lines(_check_model(model))


def _align(
    q: np.ndarray,
    model: LandmarkModel,
    lines: LineGeometry,
    pose0: np.ndarray,
    config: IcpConfig,
    max_range: float | None,
    half_fov: float | None,
    bound: PoseBound | None = None,
) -> IcpResult:
    """:func:`align` on validated inputs (the loop is inline: it is the hot path)."""
    unknown = model.u > config.unknown_threshold
    max_d2 = config.max_correspondence_distance**2  # inf: every point may be used
    qx, qy = q[:, 0].copy(), q[:, 1].copy()
    x0, y0, th0 = (float(v) for v in pose0)
    tfx = tfy = tfth = 0.0  # accumulated transform t_f (4.3.11)
    x = (x0, y0, th0)  # the pose estimate (4.3.16)
    iterations, n_used, rms = 0, 0, np.inf
    reason = "max_iterations"
    watch = _CycleWatch(config) if config.cycle_returns else None
    seen: dict[bytes, int] | None = {} if config.freeze_on_cycle else None
    frozen: tuple[np.ndarray, np.ndarray] | None = None  # (nearest line, used) once frozen
    for it in range(config.max_iterations):
        if frozen is None:
            vis = lines.visible_from(*x, max_range, half_fov)
            if q.shape[0] == 0 or not np.count_nonzero(vis):
                n_used, rms, reason = 0, np.inf, "too_few_points"
                break
            # Nearest visible segment of every point: dense (n, visible lines).
            sub = lines.subset(vis)
            aqx = qx[:, None] - sub.ax
            aqy = qy[:, None] - sub.ay
            s = _unit_clip((aqx * sub.abx + aqy * sub.aby) * sub.inv_length2)
            dx = aqx - s * sub.abx
            dy = aqy - s * sub.aby
            d2 = dx * dx + dy * dy
            j = np.argmin(d2, axis=1)  # into the visible lines
            near = d2[np.arange(j.size), j] <= max_d2 if max_d2 < math.inf else None
            # Signed distance to the chosen line (4.3.12): > 0 in front (free side).
            nx, ny = sub.nx[j], sub.ny[j]
            e = (qx - sub.ax[j]) * nx + (qy - sub.ay[j]) * ny  # = aq[i, j_i] . n
            if sub.index is not None:
                j = sub.index[j]
            keep = ~(unknown[j] & (e <= 0.0))
            if near is not None:
                keep &= near
            if seen is not None:
                key = j.tobytes() + keep.tobytes()
                earlier = seen.get(key)
                if earlier is not None and earlier < it - 1:
                    frozen = (j, keep)
                seen[key] = it
        else:  # the frozen association: same nearest lines and used points
            j, keep = frozen
            nx, ny = lines.nx[j], lines.ny[j]
            e = (qx - lines.ax[j]) * nx + (qy - lines.ay[j]) * ny
        n_used = int(np.count_nonzero(keep))
        if n_used < q.shape[0]:
            e, nx, ny, ux, uy = e[keep], nx[keep], ny[keep], qx[keep], qy[keep]
        else:
            ux, uy = qx, qy
        rms = math.sqrt(float(e @ e) / n_used) if n_used else np.inf
        if n_used < config.min_points:
            reason = "too_few_points"
            break
        if watch is not None and watch.cycled(j, keep, (x, tfx, tfy, tfth, n_used, rms)):
            # Where the endless alignment would stop: its pose after the last iteration,
            # and the used points and rms at the start of that iteration.
            reason = "cycle"
            x, tfx, tfy, tfth = watch.state_at(config.max_iterations)[:4]
            n_used, rms = watch.state_at(config.max_iterations - 1)[4:]
            break
        cx, cy = float(_sum(ux)) / n_used, float(_sum(uy)) / n_used
        ox, oy = (cx, cy) if config.centre_on_centroid else (0.0, 0.0)
        ux = ux - ox
        uy = uy - oy
        # Rows a_i = n_i^T J_i with J_i = [[1, 0, -y], [0, 1, x]] (4.3.9) in the solving
        # frame. With d_i = -e_i n_i (4.3.15), b = sum J^T d = -sum e_i a_i in both forms.
        a3 = ux * ny - uy * nx
        rhs = (-float(e @ nx), -float(e @ ny), -float(e @ a3))
        t = None
        if config.point_to_line:  # H = sum a_i^T a_i
            xx, xy, yy = float(nx @ nx), float(nx @ ny), float(ny @ ny)
            h = (xx, xy, float(nx @ a3), yy, float(ny @ a3), float(a3 @ a3))
            t = _solve_spd3(h, rhs, config.max_condition)
        if t is None:  # H = sum J_i^T J_i (4.3.10); also the point-to-line fallback
            sx, sy = float(_sum(ux)), float(_sum(uy))
            h = (n_used, 0.0, -sy, n_used, sx, float(ux @ ux + uy @ uy))
            t = _solve_spd3(h, rhs, config.max_condition)
        if t is None:
            reason = "singular"
            break
        iterations += 1
        tth = t[2]
        cos, sin = math.cos(tth), math.sin(tth)
        # Back to a rotation about the world origin: t_xy = t~_xy + o - R o.
        tx = t[0] + ox - (cos * ox - sin * oy)
        ty = t[1] + oy - (sin * ox + cos * oy)
        qx, qy = cos * qx - sin * qy + tx, sin * qx + cos * qy + ty  # (4.3.4)
        tfx, tfy = cos * tfx - sin * tfy + tx, sin * tfx + cos * tfy + ty  # (4.3.11)
        tfth += tth
        cf, sf = math.cos(tfth), math.sin(tfth)
        x = (cf * x0 - sf * y0 + tfx, sf * x0 + cf * y0 + tfy, th0 + tfth)  # (4.3.16), R-23
        # Convergence: how far the step moved the used points' centroid, and turned them.
        moved = math.hypot(cos * cx - sin * cy + tx - cx, sin * cx + cos * cy + ty - cy)
        if moved < config.tol_translation and abs(tth) < config.tol_rotation:
            reason = "converged"
            break
        if bound is not None and bound.outside(x[0] - x0, x[1] - y0, tfth):
            reason = "out_of_bound"
            break
    # Report the transform angle in [-pi, pi); the pose heading is th0 + t_f,theta,
    # continuous with the prior (pose - prior is the correction).
    tfth = float(wrap_angle(tfth))
    return IcpResult(
        pose=np.array([x[0], x[1], th0 + tfth]),
        transform=np.array([tfx, tfy, tfth]),
        iterations=iterations,
        converged=reason == "converged",
        n_used=n_used,
        rms=rms,
        reason=reason,
        frozen=frozen is not None,
    )


# ------------------------------------------------------------------------ candidates


def object_radius(model: LandmarkModel, reference: np.ndarray, unknown_threshold: float) -> float:
    """``R_lm = max ||mu_v,i - mu_r||`` over the object vertices [m] (notes 5.1).

    Object vertices are those on at least one object line (``u <= unknown_threshold``);
    a model without object lines falls back to all vertices.

    Raises:
        ValueError: malformed model or reference.
    """
    model = _check_model(model)
    ref = np.asarray(reference, dtype=float)
    if ref.shape != (2,) or not np.all(np.isfinite(ref)):
        raise ValueError(f"reference must be a finite (2,) point [m], got {ref!r}")
    idx = model.line_vertices()[model.u <= unknown_threshold]
    vertices = model.mean[np.unique(idx)] if idx.size else model.mean
    return float(np.max(np.hypot(*(vertices - ref).T)))


def candidate_landmarks(
    centroid: np.ndarray, references: np.ndarray, radii: np.ndarray, margin: float
) -> np.ndarray:
    """Indices of the landmarks a measurement set may belong to (T:4318-4326).

    A landmark is a candidate when its reference point lies within ``radius + margin``
    of the set's centroid: ``||centroid - r_l|| <= radii[l] + margin``.

    The thesis only says "a threshold" (no value). Recommendation (notes 5.1): use
    ``radii[l] = R_lm`` (:func:`object_radius`, the largest distance from the reference
    to an object vertex) and ``margin = d_margin = 2 m`` (config): a fixed radius fails
    for long walls, whose reference sits far from the centroid of a partial view. The
    thesis's second condition, that the landmark "falls in the field of view", is to be
    read as: at least one object vertex or line lies in the FOV sector within ``r_max``
    (not just the reference point); it is not tested here (see :func:`visible_lines`).

    Args:
        centroid: ``(2,)`` mean of the set's Cartesian points [m], world frame.
        references: ``(L, 2)`` landmark reference points ``mu_r`` [m], world frame.
        radii: ``(L,)`` per-landmark radii [m], >= 0.
        margin: extra distance [m], >= 0.

    Returns:
        ``(m,)`` int indices into ``references``, ascending.

    Raises:
        ValueError: shapes disagree, or values are non-finite or negative.
    """
    c = np.asarray(centroid, dtype=float)
    refs = np.asarray(references, dtype=float)
    r = np.asarray(radii, dtype=float)
    if c.shape != (2,):
        raise ValueError(f"centroid must have shape (2,), got {c.shape}")
    if refs.ndim != 2 or refs.shape[1] != 2:
        raise ValueError(f"references must have shape (L, 2), got {refs.shape}")
    if r.shape != (refs.shape[0],):
        raise ValueError(f"radii must have shape ({refs.shape[0]},), got {r.shape}")
    if not (np.all(np.isfinite(c)) and np.all(np.isfinite(refs)) and np.all(np.isfinite(r))):
        raise ValueError("centroid, references and radii must be finite")
    if np.any(r < 0):
        raise ValueError(f"radii must be >= 0, got {r[r < 0][:3]}")
    if not (np.isfinite(margin) and margin >= 0):
        raise ValueError(f"margin must be finite and >= 0 [m], got {margin!r}")
    dist = np.hypot(refs[:, 0] - c[0], refs[:, 1] - c[1])
    return np.flatnonzero(dist <= r + margin)
