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
invisible lines masked out. :func:`align_many` runs several alignments side by side:
every iteration advances all those still running on their concatenated points, and the
last few finish one at a time.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from vslam_gym.config_utils import check_field_types, check_integers
from vslam_gym.slam.geometry import check_pose, stack_last, wrap_angle
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
    "segment_offsets",
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
        check_field_types(self)
        check_integers(self, {"max_iterations": 1, "min_points": 2, "cycle_returns": 0})
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
        if w.shape != (3, 3) or not np.isfinite(w).all():
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
    if not np.isfinite(arr).all():
        bad = np.flatnonzero(~np.all(np.isfinite(arr), axis=1))
        raise ValueError(f"points contain NaN or inf at rows {bad[:5].tolist()}")
    return arr


def _check_model(model: object) -> LandmarkModel:
    if not isinstance(model, LandmarkModel):
        raise ValueError(f"model must be a LandmarkModel, got {type(model).__name__}")
    if model.n_lines < 1:
        raise ValueError(f"model must have at least one line, got {model.n_vertices} vertices")
    if not np.isfinite(model.mean).all():
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


def segment_offsets(qx, qy, ax, ay, abx, aby, inv_length2) -> tuple[np.ndarray, np.ndarray]:
    """Offsets ``(dx, dy)`` [m] from segments ``a -> a + ab`` to points ``(qx, qy)``.

    The point minus its foot on the segment (not the infinite line, R-22); every
    argument broadcasts (e.g. points ``(n, 1)`` against lines ``(L,)``, the constants of
    :data:`LineGeometry`; ``inv_length2`` is ``1 / |ab|^2``, 0 for a zero-length line).
    """
    aqx = qx - ax
    aqy = qy - ay
    s = _unit_clip((aqx * abx + aqy * aby) * inv_length2)
    return aqx - s * abx, aqy - s * aby


def _segment_distance2(qx, qy, ax, ay, abx, aby, inv_length2) -> np.ndarray:
    """Squared length ``dx^2 + dy^2`` [m^2] of :func:`segment_offsets`, for the hot paths.

    The same operations in the same order (bit-identical), but in place in two
    temporaries: ``qx - ax`` must already have the shape of the result (points ``(n, 1)``
    against lines ``(L,)`` or ``(n, L)``).
    """
    dx = qx - ax
    dy = qy - ay
    s = dx * abx
    tmp = dy * aby
    s += tmp
    s *= inv_length2
    np.maximum(s, 0.0, out=s)  # _unit_clip
    np.minimum(s, 1.0, out=s)
    dx -= np.multiply(s, abx, out=tmp)
    dy -= np.multiply(s, aby, out=tmp)
    dx *= dx
    dy *= dy
    dx += dy
    return dx


class _Lines:
    """Per-line constants of a model, as separate coordinate arrays ``(L,)`` (fast paths).

    The arrays are the rows of ``table`` ``(7, L)``, in the order of :attr:`FIELDS`. Built
    by :func:`line_geometry` (public name :data:`LineGeometry`).
    """

    FIELDS = ("ax", "ay", "abx", "aby", "inv_length2", "nx", "ny")
    index: np.ndarray | None = None

    def __init__(self, model: LandmarkModel) -> None:
        # Line j joins vertices j and j + 1 (a closed polygon's last one: k - 1 and 0), as
        # model.line_vertices(): its ends by slicing instead of fancy indexing.
        mean, n = model.mean.T, model.n_lines  # coordinates as rows (2, k)
        a = mean[:, :n]
        b = np.concatenate([mean[:, 1:], mean[:, :1]], axis=1) if model.closed else mean[:, 1:]
        self._set_table(np.empty((len(self.FIELDS), n)))
        self.table[:2] = a
        np.subtract(b[:, :n], a, out=self.table[2:4])
        length2 = self.abx * self.abx + self.aby * self.aby
        if np.count_nonzero(length2 > 0) == n:
            np.divide(1.0, length2, out=self.inv_length2)
        else:  # zero-length lines get zero normals and inverse lengths: never visible
            self.inv_length2[:] = 0.0
            np.divide(1.0, length2, out=self.inv_length2, where=length2 > 0)
        inv_length = np.sqrt(self.inv_length2)
        # Free-side (right-hand) unit normal n = [sin psi, -cos psi] (4.3.12).
        np.multiply(self.aby, inv_length, out=self.nx)
        np.multiply(-self.abx, inv_length, out=self.ny)
        self._subsets: dict[bytes, _Lines] = {}
        # A circle around every line (centre of the vertices' bounding box), for the
        # shortcuts of visible_from.
        (lo_x, hi_x), (lo_y, hi_y) = ((min(v), max(v)) for v in mean.tolist())
        self._centre = (0.5 * (lo_x + hi_x), 0.5 * (lo_y + hi_y))
        self._radius = 0.5 * math.hypot(hi_x - lo_x, hi_y - lo_y)

    def _set_table(self, table: np.ndarray) -> None:
        """Take ``table`` ``(7, L)`` as the constants: its rows become the named arrays."""
        self.table = table
        self.ax, self.ay, self.abx, self.aby, self.inv_length2, self.nx, self.ny = table

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
            (sub.index,) = mask.nonzero()
            sub._set_table(self.table.take(sub.index, axis=1))
            sub._centre, sub._radius = self._centre, self._radius  # around these lines too
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
        """:meth:`visible` from a pose given as floats ``px, py`` [m], ``theta`` [rad].

        The range and field-of-view tests are skipped (same mask, less time) when the
        circle around every line lies inside the range, or inside the field of view, by
        a margin far above round-off.
        """
        dx, dy = self._centre[0] - px, self._centre[1] - py
        d = math.hypot(dx, dy)
        if max_range is not None and d + self._radius <= max_range * (1.0 - _INSIDE_MARGIN):
            max_range = None
        if half_fov is not None and half_fov < math.pi and d > self._radius:
            off = abs(float(wrap_angle(math.atan2(dy, dx) - theta)))
            if off + math.asin(self._radius / d) <= half_fov - _INSIDE_MARGIN:
                half_fov = None
        return _visible(
            self.ax,
            self.ay,
            self.abx,
            self.aby,
            self.inv_length2,
            px,
            py,
            theta,
            max_range,
            half_fov,
        )


_INSIDE_MARGIN = 1e-9
"""Relative margin of range [-] and absolute margin of bearing [rad] by which
:meth:`_Lines.visible_from` must find its circle inside the range or the field of view
to skip a test (round-off in the tests themselves is about 1e-15)."""


def _visible(ax, ay, abx, aby, inv_length2, px, py, theta, max_range, half_fov) -> np.ndarray:
    """Visibility of lines ``a -> a + ab`` (arrays) from poses ``px, py, theta``.

    The pose may be floats (lines ``(L,)``) or ``(A, 1)`` columns (lines ``(A, L)``);
    see :func:`visible_lines`.
    """
    pax = ax - px
    pay = ay - py
    pbx = pax + abx
    pby = pay + aby
    # Front-facing: cross(v_a - p, v_b - p) < 0 (the position is on the free side).
    mask = pax * pby < pay * pbx
    if not np.count_nonzero(mask):  # nothing faces the lidar: the other tests cannot add a line
        return mask
    if max_range is not None:
        s = _unit_clip(-(pax * abx + pay * aby) * inv_length2)
        cx = pax + s * abx
        cy = pay + s * aby
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
    if math.isfinite(t0) and math.isfinite(t1) and math.isfinite(t2):
        return t0, t1, t2
    return None


def _prior_terms(w, a, b, d0, d1, d2):
    """The pose prior's terms of one ICP step's normal equations (``prior_weight``).

    The step moves the pose as it moves the points, ``x' ~ x + J t`` with
    ``J = [[1, 0, a], [0, 1, b], [0, 0, 1]]`` (``a = -(y - o_y)``, ``b = x - o_x`` for the
    rotation about ``o``), and the prior adds ``(x' - x_0)^T W (x' - x_0)`` to the sum of
    squared point residuals. Returns ``J^T W J`` as ``(h00, h01, h02, h11, h12, h22)``
    and ``J^T W d`` for the current offset ``d = (d0, d1, d2) = x - x_0``. ``w`` is
    ``W``'s upper triangle ``(w00, w01, w02, w11, w12, w22)``; every other argument may be
    a float or an array (element-wise).
    """
    w00, w01, w02, w11, w12, w22 = w
    c0 = a * w00 + b * w01 + w02
    c1 = a * w01 + b * w11 + w12
    c2 = a * w02 + b * w12 + w22
    g0 = w00 * d0 + w01 * d1 + w02 * d2
    g1 = w01 * d0 + w11 * d1 + w12 * d2
    g2 = w02 * d0 + w12 * d1 + w22 * d2
    h = (w00, w01, c0, w11, c1, a * c0 + b * c1 + c2)
    return h, (g0, g1, a * g0 + b * g1 + g2)


def _add6(h, k):
    """Element-wise sum of two 6-tuples (upper triangles of symmetric ``3 x 3`` matrices)."""
    return tuple(a + b for a, b in zip(h, k, strict=True))


def _prior_weight(weight: np.ndarray | None) -> tuple[float, ...] | None:
    """``prior_weight`` checked: a symmetric positive semi-definite ``(3, 3)`` matrix.

    Returns its upper triangle ``(w00, w01, w02, w11, w12, w22)``, None for None.

    Raises:
        ValueError: not a finite symmetric positive semi-definite ``(3, 3)`` matrix.
    """
    if weight is None:
        return None
    w = np.asarray(weight, dtype=float)
    if w.shape != (3, 3) or not np.isfinite(w).all():
        raise ValueError(f"prior_weight must be a finite (3, 3) matrix, got {w!r}")
    if not np.allclose(w, w.T) or np.linalg.eigvalsh(w)[0] < -1e-12 * max(1.0, abs(w).max()):
        raise ValueError(f"prior_weight must be symmetric positive semi-definite, got {w!r}")
    return tuple(float(w[i, j]) for i, j in ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2)))


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
        self.seen: dict[object, int] = {}  # association -> last iteration it was seen at
        self.states: list[_State] = []  # the state at the start of every iteration
        self.last: object = None
        self.start = self.period = 0

    def cycled(self, key: object, state: _State) -> bool:
        """Record an iteration's association (hash) and state; True once ``limit`` returns."""
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
    *,
    prior_weight: np.ndarray | None = None,
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
        prior_weight: optional ``(3, 3)`` symmetric positive semi-definite ``W``: every
            step minimises the squared point residuals plus ``(x - pose)^T W (x - pose)``
            (heading wrapped), a prior on the aligned pose in units of one point's
            squared residual (``W = sigma_point^2 Sigma_prior^-1``). It holds the
            directions the points leave free (a set on one wall slides along it without
            it) and keeps a set that sees more than the model holds near the prior. None
            (the thesis): no prior.

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
    return _align(
        q,
        model.u > config.unknown_threshold,
        _Lines(model),
        pose0,
        config,
        max_range,
        half_fov,
        prior=_prior_weight(prior_weight),
    )


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
    prior_weight: np.ndarray | None = None,
) -> list[IcpResult]:
    """:func:`align` of one set (or one set per model) to each of several models.

    The alignments are independent: each result is that of :func:`align` for its set
    and model, up to round-off (sums are taken in another order, so an alignment may
    stop one iteration apart, or differently where a point is equidistant from two
    segments). With more than ``_SEQUENTIAL_AT_MOST`` models they run side by side:
    every iteration is one pass of numpy calls over the points of all running
    alignments (concatenated, each against its model's lines padded to the largest
    line count), and when only ``_SEQUENTIAL_AT_MOST`` are left they finish one at a
    time. Measured on the alignments of a ``house`` run (23 per scan, 7 iterations on
    average but 23 until the slowest stops): 1.6 times faster than one at a time
    (``python benchmarks/bench_icp_batch.py``).

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
        prior_weight: optional ``(3, 3)`` pose prior of every alignment (see
            :func:`align`).
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
        # A caller passes the same set once per candidate: each object is checked (and
        # copied) once; the copies are only read. ``points`` keeps every object alive,
        # so their ids are distinct.
        distinct = {id(p): p for p in points}
        checked = {key: _check_points(p) for key, p in distinct.items()}
        sets = [checked[id(p)] for p in points]
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
    unknowns = [m.u > config.unknown_threshold for m in models]
    prior = _prior_weight(prior_weight)
    return _align_batch(sets, lines, unknowns, pose0, config, max_range, half_fov, bounds, prior)


def line_geometry(model: LandmarkModel) -> LineGeometry:
    """Per-line constants of a model's vertex means, for :func:`align_many` (a cache).

    They depend on the vertex means only.

    Raises:
        ValueError: malformed model.
    """
    return _Lines(_check_model(model))


@dataclass
class _Progress:
    """Where an alignment stands before iteration ``it``: :func:`_align` resumes from it.

    Attributes: the moved points ``qx, qy`` [m], the pose estimate ``x`` (4.3.16), the
    transform ``t_f`` so far (4.3.11), the steps taken, the used points and rms of the
    last iteration, and the cycle bookkeeping (``seen``, ``frozen``, ``watch``).
    """

    it: int
    qx: np.ndarray
    qy: np.ndarray
    x: tuple[float, float, float]
    tf: tuple[float, float, float]
    iterations: int
    n_used: int
    rms: float
    seen: dict[int, int] | None
    frozen: tuple[np.ndarray, np.ndarray] | None
    watch: _CycleWatch | None


_HASH_SEED = 20261126
"""Seed of the per-point-position 64-bit keys that hash an ICP association."""


def _association_keys(n: int) -> np.ndarray:
    """``(n,)`` odd uint64 keys, one per point position (cached).

    The table only grows, by appending: key ``i`` never changes, so hashes taken before
    and after a growth agree.
    """
    global _KEYS
    keys = _KEYS
    while keys.size < n:
        rng = np.random.default_rng([_HASH_SEED, keys.size])
        more = rng.integers(0, 2**63, size=max(keys.size, 1024), dtype=np.uint64)
        keys = np.concatenate([keys, more * np.uint64(2) + np.uint64(1)])
    _KEYS = keys
    return keys[:n]


_KEYS = np.zeros(0, dtype=np.uint64)


def _association_hash(j: np.ndarray, keep: np.ndarray, keys: np.ndarray | None = None):
    """The 64-bit hash codes of an association, one per point (sum them mod 2**64).

    ``j``: every point's line, ``keep``: whether it is used, ``keys``: every point's key
    :func:`_association_keys` at its index in its set (default: the points are one set,
    ``0..n-1``). Integer sums do not depend on the order of addition, so the hash of a
    set is the same however its points are summed.
    """
    code = j.astype(np.uint64)  # 2 j + 1 + keep, in place (modulo 2**64)
    code *= 2
    code += keep
    code += 1
    code *= _association_keys(j.size) if keys is None else keys
    return code


def _align(
    q: np.ndarray,
    unknown: np.ndarray,
    lines: LineGeometry,
    pose0: np.ndarray,
    config: IcpConfig,
    max_range: float | None,
    half_fov: float | None,
    bound: PoseBound | None = None,
    resume: _Progress | None = None,
    prior: tuple[float, ...] | None = None,
) -> IcpResult:
    """:func:`align` on validated inputs (the loop is inline: it is the hot path).

    ``resume``: continue an alignment that ran its first ``resume.it`` iterations
    elsewhere (:func:`_align_batch`). ``unknown``: ``(lines,)`` bool, the unknown lines.
    ``prior``: the upper triangle of ``prior_weight`` (:func:`_prior_weight`) or None.
    """
    max_d2 = config.max_correspondence_distance**2  # inf: every point may be used
    x0, y0, th0 = (float(v) for v in pose0)
    reason = "max_iterations"
    if resume is None:
        qx, qy = q[:, 0].copy(), q[:, 1].copy()
        tfx = tfy = tfth = 0.0  # accumulated transform t_f (4.3.11)
        x = (x0, y0, th0)  # the pose estimate (4.3.16)
        start, iterations, n_used, rms = 0, 0, 0, np.inf
        watch = _CycleWatch(config) if config.cycle_returns else None
        seen: dict[int, int] | None = {} if config.freeze_on_cycle else None
        frozen: tuple[np.ndarray, np.ndarray] | None = None  # (nearest line, used) once frozen
    else:
        qx, qy, x, (tfx, tfy, tfth) = resume.qx, resume.qy, resume.x, resume.tf
        start, iterations, n_used, rms = resume.it, resume.iterations, resume.n_used, resume.rms
        watch, seen, frozen = resume.watch, resume.seen, resume.frozen
    for it in range(start, config.max_iterations):
        if frozen is None:
            vis = lines.visible_from(*x, max_range, half_fov)
            if q.shape[0] == 0 or not np.count_nonzero(vis):
                n_used, rms, reason = 0, np.inf, "too_few_points"
                break
            # Nearest visible segment of every point: dense (n, visible lines).
            sub = lines.subset(vis)
            d2 = _segment_distance2(
                qx[:, None], qy[:, None], sub.ax, sub.ay, sub.abx, sub.aby, sub.inv_length2
            )
            j = d2.argmin(axis=1)  # into the visible lines
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
                key = int(_sum(_association_hash(j, keep)))
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
            (at,) = keep.nonzero()
            e, nx, ny, ux, uy = e.take(at), nx.take(at), ny.take(at), qx.take(at), qy.take(at)
        else:
            ux, uy = qx, qy
        rms = math.sqrt(float(e @ e) / n_used) if n_used else np.inf
        if n_used < config.min_points:
            reason = "too_few_points"
            break
        if watch is not None and watch.cycled(
            int(_sum(_association_hash(j, keep))), (x, tfx, tfy, tfth, n_used, rms)
        ):
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
        hp = None
        if prior is not None:
            dth = (tfth + math.pi) % TWO_PI - math.pi
            hp, g = _prior_terms(prior, oy - x[1], x[0] - ox, x[0] - x0, x[1] - y0, dth)
            rhs = (rhs[0] - g[0], rhs[1] - g[1], rhs[2] - g[2])
        t = None
        if config.point_to_line:  # H = sum a_i^T a_i
            xx, xy, yy = float(nx @ nx), float(nx @ ny), float(ny @ ny)
            h = (xx, xy, float(nx @ a3), yy, float(ny @ a3), float(a3 @ a3))
            t = _solve_spd3(h if hp is None else _add6(h, hp), rhs, config.max_condition)
        if t is None:  # H = sum J_i^T J_i (4.3.10); also the point-to-line fallback
            sx, sy = float(_sum(ux)), float(_sum(uy))
            h = (n_used, 0.0, -sy, n_used, sx, float(ux @ ux + uy @ uy))
            t = _solve_spd3(h if hp is None else _add6(h, hp), rhs, config.max_condition)
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


# ------------------------------------------------------------------------ batched ICP


def _solve_spd3_many(m: np.ndarray, b: np.ndarray, config: IcpConfig):
    """:func:`_solve_spd3` of ``(A, 3, 3)`` symmetric systems ``m`` with ``(A, 3)`` right sides.

    Returns ``(t, ok)``: ``(A, 3)`` solutions and ``(A,)`` bool, False where ``H`` is not
    positive definite or its condition number exceeds ``config.max_condition`` (``t`` is
    then zero). A singular ``H`` divides by zero: the caller ignores it (``np.errstate``).
    """
    eig = np.linalg.eigvalsh(m)  # ascending
    ok = (eig[:, 0] > 0.0) & (eig[:, 2] / eig[:, 0] <= config.max_condition)
    (good,) = ok.nonzero()
    if good.size == ok.size:
        t = np.linalg.solve(m, b[:, :, None])[:, :, 0]
    else:
        t = np.zeros_like(b)
        if not good.size:
            return t, ok
        t[good] = np.linalg.solve(m.take(good, axis=0), b.take(good, axis=0)[:, :, None])[:, :, 0]
    ok &= np.isfinite(t).all(axis=1)
    return t, ok


_SYM3 = np.array([[0, 1, 2], [1, 3, 4], [2, 4, 5]])
"""Indices of ``[h00, h01, h02, h11, h12, h22]`` that make the symmetric ``3 x 3`` matrix."""


def _take_lines(table: np.ndarray, index: np.ndarray, n_lines: int) -> np.ndarray:
    """``table[:, index, :n_lines]`` of a ``(fields, A, L)`` table, C-contiguous.

    (``take`` then slice: numpy's fancy indexing of a middle axis is several times slower.)
    """
    out = table.take(index, axis=1)
    return out if n_lines == out.shape[2] else np.ascontiguousarray(out[:, :, :n_lines])


def _offsets(counts: np.ndarray) -> np.ndarray:
    """``(n,)`` where each of consecutive runs of ``counts`` ``(n,)`` starts (0 first)."""
    starts = np.zeros(counts.size, dtype=np.intp)
    counts[:-1].cumsum(out=starts[1:])
    return starts


class _Batch:
    """Several alignments side by side: their points in one ragged list.

    The points of all running alignments are concatenated (alignment by alignment) in
    ``(T,)`` arrays; every point carries its alignment's line constants padded to the
    largest line count of the running alignments ``(T, L)`` (a padded line has a zero
    direction and is never visible). Per-alignment sums are ``np.add.reduceat`` over
    the contiguous runs. :meth:`keep` drops the points of alignments that stopped.
    """

    _PAIR_ROWS = 5  # ax, ay, abx, aby, inv_length2: the first rows of _Lines.table
    _POINT_ROWS = [0, 1, 5, 6, 7]  # ax, ay, nx, ny and the unknown flag (row 7 below)

    def __init__(self, sets, lines, unknowns, rows: np.ndarray) -> None:
        sizes = np.array([g.ax.size for g in lines], dtype=np.intp)
        l_max = int(sizes.max())
        p = len(sets)
        # Every model's line constants and unknown flag (1.0 / 0.0) in the (p * l_max)
        # slots of the padded rows (zero: a padded line).
        slots = np.arange(sizes.sum()) + np.repeat(np.arange(p) * l_max - _offsets(sizes), sizes)
        padded = np.zeros((len(_Lines.FIELDS) + 1, p * l_max))
        padded[:-1, slots] = np.concatenate([g.table for g in lines], axis=1)
        padded[-1, slots] = np.concatenate(unknowns)
        # What a point needs of its nearest line, one row per (alignment, line): the
        # line's start [m], free-side normal and unknown flag.
        self.per_line = np.ascontiguousarray(padded[self._POINT_ROWS].T)
        self.rows = rows  # the running alignments
        self.line_counts = sizes[rows]
        # (5, A, L): the line constants of _PAIR_ROWS per running alignment, and
        # (5, T, L) the same per point, padded to the largest running line count.
        pair = padded[: self._PAIR_ROWS].reshape(self._PAIR_ROWS, p, l_max)
        self.pair = pair.take(rows, axis=1)
        self.counts = np.array([sets[r].shape[0] for r in rows.tolist()], dtype=np.intp)
        # (3, A): the circle around every running alignment's lines (_Lines.visible_from).
        self.circles = np.array([(*lines[r]._centre, lines[r]._radius) for r in rows.tolist()]).T
        self.owner = np.repeat(np.arange(rows.size), self.counts)  # (T,) into rows
        self.base = rows[self.owner] * l_max  # (T,) every point's first row of per_line
        # Every point's association key at its index in its set (_association_hash).
        position = np.arange(self.owner.size) - np.repeat(_offsets(self.counts), self.counts)
        self.keys = _association_keys(int(self.counts.max()))[position]
        q = np.concatenate([sets[r] for r in rows.tolist()])
        self.qx, self.qy = q[:, 0].copy(), q[:, 1].copy()
        self.point = self.pair.take(self.owner, axis=1)
        self.frozen_j = np.zeros(self.qx.size, dtype=np.intp)
        self.frozen_keep = np.zeros(self.qx.size, dtype=bool)
        self.starts = _offsets(self.counts)

    def terms(self, n: int) -> np.ndarray:
        """An empty ``(n, T)`` array, to fill row by row with per-point terms for :meth:`sums`."""
        return np.empty((n, self.qx.size))

    def sums(self, terms: np.ndarray) -> np.ndarray:
        """``(n, A)``: each row of ``(n, T)`` :meth:`terms` summed over every alignment's points.

        ``np.add.reduceat`` sums every run by itself (pairwise): the sum of a run does not
        depend on the other rows or on the memory layout.
        """
        return np.add.reduceat(terms, self.starts, axis=1)

    def keep(self, running: np.ndarray) -> None:
        """Keep only the alignments where ``running`` ``(A,)`` is True."""
        (kept,) = running.nonzero()
        (pts,) = running[self.owner].nonzero()
        self.rows, self.counts = self.rows.take(kept), self.counts.take(kept)
        self.line_counts = self.line_counts.take(kept)
        self.circles = self.circles.take(kept, axis=1)
        self.owner = np.repeat(np.arange(kept.size), self.counts)
        self.base, self.keys = self.base.take(pts), self.keys.take(pts)
        self.qx, self.qy = self.qx.take(pts), self.qy.take(pts)
        self.frozen_j, self.frozen_keep = self.frozen_j.take(pts), self.frozen_keep.take(pts)
        n_lines = int(self.line_counts.max())  # the padding the running ones need
        self.pair = _take_lines(self.pair, kept, n_lines)
        self.point = self.pair.take(self.owner, axis=1)
        self.starts = _offsets(self.counts)

    def visible(self, px, py, theta, max_range, half_fov) -> np.ndarray:
        """:meth:`_Lines.visible_from` of every alignment at its pose ``(A,)``: ``(A, L)``.

        The range test is skipped (same mask) when every alignment's circle around its
        lines lies inside the range, as in :meth:`_Lines.visible_from`.
        """
        if max_range is not None:
            cx, cy, radius = self.circles
            far = np.hypot(cx - px, cy - py) + radius > max_range * (1.0 - _INSIDE_MARGIN)
            if not np.count_nonzero(far):
                max_range = None
        return _visible(*self.pair, px[:, None], py[:, None], theta[:, None], max_range, half_fov)

    def nearest(self, vis: np.ndarray, distance: bool) -> tuple[np.ndarray, np.ndarray | None]:
        """Every point's nearest visible segment (R-22): index ``(T,)`` and squared distance.

        The distance ``(T,)`` [m^2] only when ``distance`` is True (None otherwise).
        """
        d2 = _segment_distance2(self.qx[:, None], self.qy[:, None], *self.point)
        np.putmask(d2, (~vis).take(self.owner, axis=0), np.inf)
        j = d2.argmin(axis=1)
        return j, d2[np.arange(j.size), j] if distance else None

    def line_of(self, j: np.ndarray) -> np.ndarray:
        """``(T, 5)``: ``[ax, ay, nx, ny, unknown]`` of every point's line ``j``."""
        return self.per_line.take(self.base + j, axis=0)

    def association_hash(self, j: np.ndarray, keep: np.ndarray) -> list[int]:
        """Per alignment the 64-bit hash of its association (:func:`_association_hash`)."""
        return np.add.reduceat(_association_hash(j, keep, self.keys), self.starts).tolist()


def _align_batch(
    sets: list[np.ndarray],
    lines: list[LineGeometry],
    unknowns: list[np.ndarray],
    pose0: np.ndarray,
    config: IcpConfig,
    max_range: float | None,
    half_fov: float | None,
    bounds: list[PoseBound | None],
    prior: tuple[float, ...] | None = None,
) -> list[IcpResult]:
    """:func:`align` of set ``k`` to the model of ``lines[k]``, all from ``pose0``, side by side.

    The loop of :func:`align` (see there), run for all alignments at once: every
    iteration advances each alignment that has not stopped by one step, on the
    concatenated points of the running alignments (:class:`_Batch`), so the overhead of
    a numpy call is paid once per iteration for all of them. ``unknowns[k]``:
    ``(lines,)`` bool, the unknown lines of model ``k``. An association (every point's
    line and whether it is used), for ``freeze_on_cycle`` and ``cycle_returns``, is
    compared by a 64-bit hash. Validated inputs (the hot path).
    """
    p = len(sets)
    x0, y0, th0 = (float(v) for v in pose0)
    px, py, pth = np.full(p, x0), np.full(p, y0), np.full(p, th0)  # pose estimates (4.3.16)
    tfx, tfy, tfth = np.zeros(p), np.zeros(p), np.zeros(p)  # accumulated t_f (4.3.11)
    iterations = np.zeros(p, dtype=np.intp)
    n_used, rms = np.zeros(p, dtype=np.intp), np.full(p, np.inf)
    reasons = ["too_few_points" if q.shape[0] == 0 else "max_iterations" for q in sets]
    frozen = np.zeros(p, dtype=bool)  # the association is frozen (same lines, same points)
    rows = np.array([k for k in range(p) if sets[k].shape[0] > 0], dtype=np.intp)
    finished: dict[int, IcpResult] = {}
    inputs = (sets, lines, unknowns, bounds, prior)
    if 0 < rows.size <= _SEQUENTIAL_AT_MOST:
        finished = {
            r: _align_one(r, inputs, pose0, config, max_range, half_fov) for r in rows.tolist()
        }
    elif rows.size:
        finished = _iterate(
            _Batch(sets, lines, unknowns, rows),
            (px, py, pth, tfx, tfy, tfth, iterations, n_used, rms, frozen),
            reasons,
            pose0,
            config,
            max_range,
            half_fov,
            inputs,
        )
    # Report the transform angle in [-pi, pi); the pose heading is th0 + t_f,theta,
    # continuous with the prior (pose - prior is the correction).
    tf_theta = np.atleast_1d(wrap_angle(tfth))
    return [
        finished[k]
        if k in finished
        else IcpResult(
            pose=np.array([px[k], py[k], th0 + tf_theta[k]]),
            transform=np.array([tfx[k], tfy[k], tf_theta[k]]),
            iterations=int(iterations[k]),
            converged=reasons[k] == "converged",
            n_used=int(n_used[k]),
            rms=float(rms[k]),
            reason=reasons[k],
            frozen=bool(frozen[k]),
        )
        for k in range(p)
    ]


def _align_one(r, inputs, pose0, config, max_range, half_fov, resume=None) -> IcpResult:
    """:func:`_align` of alignment ``r`` of a batch, from the start or from ``resume``.

    ``inputs``: the batch's ``(sets, lines, unknowns, bounds, prior)``.
    """
    sets, lines, unknowns, bounds, prior = inputs
    return _align(
        sets[r], unknowns[r], lines[r], pose0, config, max_range, half_fov, bounds[r], resume, prior
    )


class _Stopper:
    """Stops alignments of a batch round: ``stop(local, reason)`` for indices into ``act``."""

    def __init__(self, act: np.ndarray, running: np.ndarray, reasons: list[str]) -> None:
        self.act, self.running, self.reasons = act, running, reasons

    def __call__(self, local: np.ndarray, reason: str) -> None:
        if local.size:
            self.running[local] = False
            for r in self.act[local].tolist():
                self.reasons[r] = reason


_SEQUENTIAL_AT_MOST = 3
"""When this few alignments of a batch are still running, :func:`_align` finishes them one
by one: an iteration of the batch costs about as much numpy overhead as three single ones."""


def _iterate(batch, state, reasons, pose0, config, max_range, half_fov, inputs):
    """The iterations of :func:`_align_batch`: updates ``state`` and ``reasons`` in place.

    Returns the results of the alignments finished by :func:`_align`, by index.
    """
    px, py, pth, tfx, tfy, tfth, iterations, n_used, rms, frozen = state
    bounds, prior = inputs[3:]
    x0, y0, th0 = (float(v) for v in pose0)
    p = px.size
    max_d2 = config.max_correspondence_distance**2  # inf: every point may be used
    watches = [_CycleWatch(config) for _ in range(p)] if config.cycle_returns else None
    seen: list[dict[int, int]] | None = [{} for _ in range(p)] if config.freeze_on_cycle else None
    bounded = np.array([b is not None for b in bounds])
    if bounded.any():
        whitening = np.stack([np.eye(3) if b is None else b.whitening for b in bounds])
        limit2 = np.array([0.0 if b is None else b.limit * b.limit for b in bounds])
    # An alignment without used points (or lines) divides by zero: its rms, its centroid
    # and its condition number are masked below (the one-by-one finish has its own checks).
    with np.errstate(divide="ignore", invalid="ignore"):
        for it in range(config.max_iterations):
            act = batch.rows
            if act.size <= _SEQUENTIAL_AT_MOST:
                break
            running = np.ones(act.size, dtype=bool)
            stop = _Stopper(act, running, reasons)
            vis = batch.visible(px[act], py[act], pth[act], max_range, half_fov)
            j, d2 = batch.nearest(vis, max_d2 < math.inf)
            fro = frozen[act]
            fro_pts = fro[batch.owner] if np.count_nonzero(fro) else None
            if fro_pts is not None:
                j = np.where(fro_pts, batch.frozen_j, j)
            line = batch.line_of(j)
            nx, ny = line[:, 2], line[:, 3]
            # Signed distance to the chosen line (4.3.12): > 0 in front (free side).
            e = (batch.qx - line[:, 0]) * nx + (batch.qy - line[:, 1]) * ny
            keep = ~((line[:, 4] > 0.0) & (e <= 0.0))
            if max_d2 < math.inf:
                keep &= d2 <= max_d2
            if fro_pts is not None:
                keep = np.where(fro_pts, batch.frozen_keep, keep)
            blind = ~fro & ~vis.any(axis=1)
            keys = batch.association_hash(j, keep) if seen is not None or watches else None
            if seen is not None:
                rows = act.tolist()
                for k in (~(fro | blind)).nonzero()[0].tolist():
                    r = rows[k]
                    earlier = seen[r].get(keys[k])
                    if earlier is not None and earlier < it - 1:
                        frozen[r] = True
                        pts = batch.owner == k
                        batch.frozen_j[pts], batch.frozen_keep[pts] = j[pts], keep[pts]
                    seen[r][keys[k]] = it
            terms = batch.terms(4)
            kf = terms[0]
            np.copyto(kf, keep)  # 1.0 / 0.0
            e *= kf
            np.multiply(e, e, out=terms[1])
            np.multiply(batch.qx, kf, out=terms[2])
            np.multiply(batch.qy, kf, out=terms[3])
            sums = batch.sums(terms)
            used = sums[0]
            rms_it = np.where(used > 0, np.sqrt(sums[1] / used), np.inf)
            n_used[act] = np.where(blind, 0, used.astype(np.intp))
            rms[act] = np.where(blind, np.inf, rms_it)
            go = ~blind & (used >= config.min_points)
            stop((~go).nonzero()[0], "too_few_points")
            if watches is not None:
                for k, r in enumerate(act.tolist()):
                    state_r = ((px[r], py[r], pth[r]), tfx[r], tfy[r], tfth[r], n_used[r], rms[r])
                    if go[k] and watches[r].cycled(keys[k], state_r):
                        # Where the endless alignment would stop: its pose after the last
                        # iteration, and the used points and rms at the start of that one.
                        (px[r], py[r], pth[r]), tfx[r], tfy[r], tfth[r] = watches[r].state_at(
                            config.max_iterations
                        )[:4]
                        n_used[r], rms[r] = watches[r].state_at(config.max_iterations - 1)[4:]
                        go[k] = False
                        stop(np.array([k]), "cycle")
            if np.count_nonzero(go):
                point_terms = (nx, ny, e, kf)
                _step(batch, act, go, running, stop, sums, point_terms, state, pose0, config, prior)
                if bounded.any():
                    upd = act[running]  # stepped and not converged
                    check = upd[bounded[upd]]
                    dth = np.mod(tfth[check] + math.pi, TWO_PI) - math.pi
                    d = np.stack([px[check] - x0, py[check] - y0, dth], axis=1)
                    w = np.einsum("kij,kj->ki", whitening[check], d)
                    out = np.einsum("ki,ki->k", w, w) > limit2[check]
                    stop(np.searchsorted(act, check[out]), "out_of_bound")
            n_running = np.count_nonzero(running)
            if n_running < running.size:
                if not n_running:
                    return {}
                batch.keep(running)
        else:  # the iteration limit: every alignment has stopped
            return {}
    return _finish_one_by_one(
        batch, it, state, seen, watches, inputs, pose0, config, max_range, half_fov
    )


def _finish_one_by_one(
    batch, it, state, seen, watches, inputs, pose0, config, max_range, half_fov
) -> dict[int, IcpResult]:
    """:func:`_align` of each alignment still running in ``batch``, from iteration ``it``.

    Returns their results by index.
    """
    px, py, pth, tfx, tfy, tfth, iterations, n_used, rms, frozen = state
    finished: dict[int, IcpResult] = {}
    for k, r in enumerate(batch.rows.tolist()):
        pts = batch.owner == k
        progress = _Progress(
            it,
            batch.qx[pts],
            batch.qy[pts],
            (float(px[r]), float(py[r]), float(pth[r])),
            (float(tfx[r]), float(tfy[r]), float(tfth[r])),
            int(iterations[r]),
            int(n_used[r]),
            float(rms[r]),
            None if seen is None else seen[r],
            (batch.frozen_j[pts], batch.frozen_keep[pts]) if frozen[r] else None,
            None if watches is None else watches[r],
        )
        finished[r] = _align_one(r, inputs, pose0, config, max_range, half_fov, progress)
    return finished


_TERM_ROWS = 8
"""Rows of :func:`_step`'s per-point terms ``(8 or 17, T)`` (``e`` the signed distance,
``w = [n_x, n_y, a_3]`` the row ``a_i`` and ``u`` the point in the solving frame, all
zero for the unused points): ``e w`` (3 rows), ``0``, ``1``, ``u_x``, ``-u_y``,
``|u|^2``, and for the point-to-line form ``w w^T`` (9 rows, row-major)."""

_SYSTEM_ROWS = np.array(
    [
        [*range(_TERM_ROWS, _TERM_ROWS + 9), 0, 1, 2],  # H = sum a_i^T a_i
        [4, 3, 6, 3, 4, 5, 6, 5, 7, 0, 1, 2],  # H = sum J_i^T J_i (4.3.10)
    ]
)
"""Per form, the rows of the summed terms that make ``H`` (3 x 3, row-major) and ``-b``."""


def _step(batch, act, go, running, stop, sums, terms, state, pose0, config, prior) -> None:
    """One least-squares step of the alignments ``act[go]``; stops the singular and converged.

    ``sums``: the per-alignment sums of :func:`_iterate` (used points, squared distances,
    ``x``, ``y``); ``terms``: every point's line normal, signed distance and use ``(nx,
    ny, e, kf)``; ``prior``: the upper triangle of ``prior_weight`` or None. Divisions
    by zero (an alignment without used points) must be ignored by the caller
    (``np.errstate``).
    """
    nx, ny, e, kf = terms
    px, py, pth, tfx, tfy, tfth, iterations = state[:7]
    x0, y0, th0 = pose0
    used = sums[0]
    cx, cy = sums[2] / used, sums[3] / used
    if config.centre_on_centroid:
        ox, oy = np.where(go, cx, 0.0), np.where(go, cy, 0.0)
    else:
        ox, oy = np.zeros_like(cx), np.zeros_like(cy)
    owner = batch.owner
    per_point = batch.terms(_TERM_ROWS + 9 if config.point_to_line else _TERM_ROWS)
    ux = np.multiply(batch.qx - ox[owner], kf, out=per_point[5])
    uy = (batch.qy - oy[owner]) * kf
    np.negative(uy, out=per_point[6])
    w = np.empty((3, ux.size))
    nx, ny = np.multiply(nx, kf, out=w[0]), np.multiply(ny, kf, out=w[1])
    # Rows a_i = n_i^T J_i with J_i = [[1, 0, -y], [0, 1, x]] (4.3.9) in the solving
    # frame. With d_i = -e_i n_i (4.3.15), b = sum J^T d = -sum e_i a_i in both forms.
    np.subtract(ux * ny, uy * nx, out=w[2])
    np.multiply(e, w, out=per_point[:3])
    per_point[3], per_point[4] = 0.0, kf
    np.add(ux * ux, uy * uy, out=per_point[7])
    if config.point_to_line:  # H = sum a_i^T a_i
        np.multiply(w[:, None], w[None], out=per_point[_TERM_ROWS:].reshape(3, 3, -1))
    # (forms, G, 12): the systems of the alignments that step, the point-to-line form
    # first (when used), then H = sum J_i^T J_i (4.3.10), the thesis form and the fallback.
    (stepping,) = go.nonzero()
    n = stepping.size
    forms = _SYSTEM_ROWS if config.point_to_line else _SYSTEM_ROWS[1:]
    system = batch.sums(per_point).take(stepping, axis=1)[forms].transpose(0, 2, 1).copy()
    if prior is not None:
        rows = act[stepping]
        x, y, o_x, o_y = px[rows], py[rows], ox[stepping], oy[stepping]
        dth = np.mod(tfth[rows] + math.pi, TWO_PI) - math.pi
        hp, gp = _prior_terms(prior, o_y - y, x - o_x, x - x0, y - y0, dth)
        hp = stack_last(*(np.broadcast_to(v, x.shape) for v in hp))
        system[..., :9] += hp[:, _SYM3].reshape(n, 9)
        system[..., 9:] += stack_last(*gp)  # b = -(sum e_i a_i + g)
    t, ok = _solve_spd3_many(
        system[..., :9].reshape(-1, 3, 3), -system[..., 9:].reshape(-1, 3), config
    )
    if config.point_to_line:  # its solution where it exists
        t = np.where(ok[:n, None], t[:n], t[n:])
        ok = ok[:n] | ok[n:]
    stop(stepping[~ok], "singular")
    (solved,) = ok.nonzero()
    if solved.size == 0:
        return
    g, t = stepping.take(solved), t.take(solved, axis=0)
    rows = act.take(g)
    iterations[rows] += 1
    tth = t[:, 2]
    cos, sin = np.cos(tth), np.sin(tth)
    cgx, cgy = cx.take(g), cy.take(g)
    og_x, og_y = (cgx, cgy) if config.centre_on_centroid else (ox.take(g), oy.take(g))
    # Back to a rotation about the world origin: t_xy = t~_xy + o - R o.
    tx = t[:, 0] + og_x - (cos * og_x - sin * og_y)
    ty = t[:, 1] + og_y - (sin * og_x + cos * og_y)
    # Move the points of the stepped alignments (4.3.4); the others keep theirs.
    move = np.zeros((4, go.size))  # per alignment [cos, sin, t_x, t_y]: no move
    move[0] = 1.0
    move[:, g] = cos, sin, tx, ty
    c_p, s_p, tx_p, ty_p = move.take(owner, axis=1)
    batch.qx, batch.qy = (
        c_p * batch.qx - s_p * batch.qy + tx_p,
        s_p * batch.qx + c_p * batch.qy + ty_p,
    )
    fx, fy, fth = tfx[rows], tfy[rows], tfth[rows] + tth
    fx, fy = cos * fx - sin * fy + tx, sin * fx + cos * fy + ty  # (4.3.11)
    tfx[rows], tfy[rows], tfth[rows] = fx, fy, fth
    cf, sf = np.cos(fth), np.sin(fth)
    px[rows] = cf * x0 - sf * y0 + fx  # (4.3.16), R-23
    py[rows] = sf * x0 + cf * y0 + fy
    pth[rows] = th0 + fth
    # Convergence: how far the step moved the used points' centroid, and turned them.
    moved = np.hypot(cos * cgx - sin * cgy + tx - cgx, sin * cgx + cos * cgy + ty - cgy)
    stop(g[(moved < config.tol_translation) & (np.abs(tth) < config.tol_rotation)], "converged")


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
    if ref.shape != (2,) or not np.isfinite(ref).all():
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
    if not (np.isfinite(c).all() and np.isfinite(refs).all() and np.isfinite(r).all()):
        raise ValueError("centroid, references and radii must be finite")
    if np.any(r < 0):
        raise ValueError(f"radii must be >= 0, got {r[r < 0][:3]}")
    if not (np.isfinite(margin) and margin >= 0):
        raise ValueError(f"margin must be finite and >= 0 [m], got {margin!r}")
    dist = np.hypot(refs[:, 0] - c[0], refs[:, 1] - c[1])
    return np.flatnonzero(dist <= r + margin)
