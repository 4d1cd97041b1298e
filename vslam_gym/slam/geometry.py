"""Plane geometry of the estimator: angles, polar/Cartesian maps, line fits, intersections.

Frames and units: the world frame has x east and y north, in metres; angles are in
radians, counter-clockwise from the x axis. A pose is ``[x, y, theta]`` (the lidar's
position and heading in the world frame). A range-bearing pair ``[r, phi]`` is relative
to the lidar pose (``phi`` counter-clockwise from its heading). A line is a point ``p0``
(shape ``(..., 2)``) and a direction angle ``psi`` (direction ``[cos psi, sin psi]``,
unit normal ``[-sin psi, cos psi]``). Everything is vectorised over leading batch
dimensions (SPEC.md sections 0, 2 and 3).
"""

from __future__ import annotations

import math

import numpy as np

TWO_PI = 2.0 * np.pi
PARALLEL_SIN_FLOOR = 16.0 * float(np.finfo(float).eps)
"""``|sin|`` of the angle between two lines at or below which they are parallel whatever
the caller's threshold: angles that differ by a float-rounded ``pi`` leave ~1e-16."""


def _scalar_or_array(value: np.ndarray) -> np.ndarray:
    """0-d results come back as numpy scalars, everything else as arrays."""
    return value[()] if np.ndim(value) == 0 else value


def check_pose(pose: object) -> np.ndarray:
    """``pose`` as a finite ``(3,)`` float array ``[x, y, theta]``, or a ``ValueError``."""
    try:
        arr = np.array(pose, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"pose must be numeric [x, y, theta], got {pose!r}") from exc
    if arr.shape != (3,):
        raise ValueError(f"pose must have shape (3,) = [x, y, theta], got shape {arr.shape}")
    if not np.isfinite(arr).all():
        raise ValueError(f"pose must be finite, got {arr}")
    return arr


def stack_last(*arrays: np.ndarray) -> np.ndarray:
    """``np.stack(arrays, axis=-1)`` of arrays of one shape, without its per-call overhead.

    The same values, dtype and layout, filled column by column; for hot paths on small
    arrays, where ``np.stack`` costs several times more. ``np.stack`` lays its result
    out in the memory order of its inputs: only 1-D or C-contiguous inputs take the fast
    path (their stack is C-contiguous), others go to ``np.stack`` (the layout decides
    the summation order of later reductions, hence their last bits).
    """
    if not all(a.ndim <= 1 or a.flags.c_contiguous for a in arrays):
        return np.stack(arrays, axis=-1)
    out = np.empty((*arrays[0].shape, len(arrays)), dtype=np.result_type(*arrays))
    for i, a in enumerate(arrays):
        out[..., i] = a
    return out


def wrap_angle(a: np.ndarray | float) -> np.ndarray:
    """Wrap angles [rad] into ``[-pi, pi)`` (``pi`` maps to ``-pi``); any shape."""
    if isinstance(a, float) and math.isfinite(a):  # one angle: the same steps on floats
        # (Python's % is numpy's float remainder: fmod, then the divisor's sign.)
        wrapped = (a + math.pi) % TWO_PI - math.pi
        return np.float64(wrapped - TWO_PI if wrapped >= math.pi else wrapped)
    a = np.asarray(a, dtype=float)
    wrapped = np.mod(a + np.pi, TWO_PI) - np.pi
    # np.mod can round up to exactly 2 pi for tiny negative arguments.
    wrapped = np.where(wrapped >= np.pi, wrapped - TWO_PI, wrapped)
    return _scalar_or_array(wrapped)


def _pose_parts(pose: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    pose = np.asarray(pose, dtype=float)
    if pose.ndim < 1 or pose.shape[-1] != 3:
        raise ValueError(f"pose must have shape (..., 3) = [x, y, theta], got {pose.shape}")
    return pose[..., 0, None], pose[..., 1, None], pose[..., 2, None]


def polar_to_cartesian(ranges: np.ndarray, bearings: np.ndarray, pose: np.ndarray) -> np.ndarray:
    """World points of lidar beams (SPEC 3.2.1): ``x_pos + r [cos(theta+phi), sin(theta+phi)]``.

    Args:
        ranges: ranges ``r`` [m], shape ``(..., n)``.
        bearings: bearings ``phi`` [rad] relative to the lidar heading, shape ``(..., n)``.
        pose: lidar pose ``[x, y, theta]`` in the world frame, shape ``(3,)`` or
            ``(..., 3)``; its batch dims broadcast against those of the beams.

    Returns:
        Points in the world frame [m], shape ``(..., n, 2)``.
    """
    ranges = np.asarray(ranges, dtype=float)
    bearings = np.asarray(bearings, dtype=float)
    x, y, theta = _pose_parts(pose)
    angle = theta + bearings
    return np.stack(
        np.broadcast_arrays(x + ranges * np.cos(angle), y + ranges * np.sin(angle)), axis=-1
    )


def polar_to_cartesian_jacobian(
    ranges: np.ndarray, bearings: np.ndarray, pose: np.ndarray
) -> np.ndarray:
    """Jacobian of :func:`polar_to_cartesian` per beam with respect to ``[r, phi]``.

    Returns:
        Shape ``(..., n, 2, 2)``: ``[[cos a, -r sin a], [sin a, r cos a]]`` with
        ``a = theta + phi`` (rows: world ``x, y`` [m]; columns: ``r`` [m], ``phi`` [rad]).
    """
    ranges = np.asarray(ranges, dtype=float)
    bearings = np.asarray(bearings, dtype=float)
    _, _, theta = _pose_parts(pose)
    angle = theta + bearings
    ranges, angle = np.broadcast_arrays(ranges, angle)
    cos, sin = np.cos(angle), np.sin(angle)
    return np.stack(
        [np.stack([cos, -ranges * sin], axis=-1), np.stack([sin, ranges * cos], axis=-1)],
        axis=-2,
    )


def cartesian_to_polar(points: np.ndarray, pose: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Range and bearing of world points relative to a lidar pose.

    Args:
        points: world points [m], shape ``(..., n, 2)``.
        pose: lidar pose ``[x, y, theta]``, shape ``(3,)`` or ``(..., 3)`` (broadcasting
            against the batch dims of ``points``).

    Returns:
        ``(r (..., n) [m], phi (..., n) [rad] in [-pi, pi))``.
    """
    points = np.asarray(points, dtype=float)
    if points.ndim < 1 or points.shape[-1] != 2:
        raise ValueError(f"points must have shape (..., n, 2), got {points.shape}")
    x, y, theta = _pose_parts(pose)
    dx = points[..., 0] - x
    dy = points[..., 1] - y
    return np.hypot(dx, dy), np.asarray(wrap_angle(np.arctan2(dy, dx) - theta))


def line_direction(psi: np.ndarray | float) -> np.ndarray:
    """Return the unit direction ``[cos psi, sin psi]`` of lines at ``psi`` [rad]: ``(..., 2)``."""
    psi = np.asarray(psi, dtype=float)
    return np.stack([np.cos(psi), np.sin(psi)], axis=-1)


def line_normal(psi: np.ndarray | float) -> np.ndarray:
    """Return the unit normal ``[-sin psi, cos psi]`` (direction turned +90 deg): ``(..., 2)``."""
    psi = np.asarray(psi, dtype=float)
    return np.stack([-np.sin(psi), np.cos(psi)], axis=-1)


def _cross(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Return the 2-D cross product ``u_x v_y - u_y v_x`` (= ``u^T R v`` of SPEC section 3)."""
    return u[..., 0] * v[..., 1] - u[..., 1] * v[..., 0]


def _check_points(points: np.ndarray, minimum: int, where: str) -> np.ndarray:
    points = np.asarray(points, dtype=float)
    if points.ndim < 2 or points.shape[-1] != 2:
        raise ValueError(f"{where}: points must have shape (..., n, 2), got {points.shape}")
    if points.shape[-2] < minimum:
        raise ValueError(f"{where}: needs at least {minimum} points, got {points.shape[-2]}")
    return points


def _centre(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Mean ``p0`` and the centred points ``e = z - p0``.

    The mean is taken relative to the first point so that identical coordinates give an
    exact mean (a noiseless vertical line gets ``Sxx = Sxy = 0`` exactly).
    """
    reference = points[..., :1, :]
    shifted = points - reference
    mean_shift = np.mean(shifted, axis=-2, keepdims=True)
    return (reference + mean_shift)[..., 0, :], shifted - mean_shift


def fit_line(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Total-least-squares line through points (SPEC section 2, thesis Appendix A).

    ``p0 = mean(z)``; with the centred sums ``Sxx``, ``Syy``, ``Sxy``: ``a = Syy - Sxx``,
    ``b = 2 Sxy``, ``q = a + sqrt(a^2 + b^2)``, ``c = sqrt(b^2 + q^2)`` (equal to the
    printed ``sqrt(2 (a^2 + b^2 + a sqrt(a^2 + b^2)))``), ``cos psi = b / c``,
    ``sin psi = q / c``, and ``psi = 0`` when ``c = 0``. This is the principal axis of the
    scatter matrix. For ``a < 0`` the cancelling sum ``q`` is evaluated as the identical
    ``b^2 / (sqrt(a^2 + b^2) - a)``, so near-horizontal lines keep full precision; exactly
    vertical (horizontal) noiseless points give ``psi = pi/2`` (``0``) exactly.

    Args:
        points: world points [m], shape ``(..., n, 2)`` with ``n >= 2``.

    Returns:
        ``(p0 (..., 2) [m], psi (...,) [rad] in [0, pi])``.
    """
    points = _check_points(points, 2, "fit_line")
    p0, e = _centre(points)
    Sxx = np.sum(e[..., 0] ** 2, axis=-1)
    Syy = np.sum(e[..., 1] ** 2, axis=-1)
    Sxy = np.sum(e[..., 0] * e[..., 1], axis=-1)
    a = Syy - Sxx
    b = 2.0 * Sxy
    s = np.hypot(a, b)
    with np.errstate(divide="ignore", invalid="ignore"):
        q = np.where(a >= 0, a + s, b * b / (s - a))
    q = np.where(np.isfinite(q), q, 0.0)  # a < 0 and s - a = 0 cannot happen; 0/0 guard
    c = np.hypot(b, q)
    psi = np.where(c > 0, np.arctan2(q, b), 0.0)
    return p0, _scalar_or_array(psi)


def line_through(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Return the line through the points ``a`` and ``b``.

    Args:
        a: first point [m], shape ``(..., 2)``; becomes ``p0``.
        b: second point [m], shape ``(..., 2)``.

    Returns:
        ``(p0 = a, psi)`` with ``psi`` [rad] in ``(-pi, pi]`` pointing from ``a`` to ``b``.

    Raises:
        ValueError: ``a`` and ``b`` coincide (somewhere in the batch).
    """
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    if a.shape[-1:] != (2,) or b.shape[-1:] != (2,):
        raise ValueError(f"line_through: points must have shape (..., 2), got {a.shape}, {b.shape}")
    d = b - a
    if np.any(np.all(d == 0, axis=-1)):
        raise ValueError("line_through: the two points coincide, the line is undefined")
    p0 = np.broadcast_to(a, np.broadcast_shapes(a.shape, b.shape)).copy()
    return p0, _scalar_or_array(np.arctan2(d[..., 1], d[..., 0]))


def intersect_lines(
    p0a: np.ndarray,
    psia: np.ndarray,
    p0b: np.ndarray,
    psib: np.ndarray,
    parallel_sin_min: float = 0.0,
) -> tuple[np.ndarray, np.ndarray]:
    """Intersection of line a and line b (SPEC section 3, eq. 3.2.7-3.2.9).

    ``v = p0a + t d_a`` with ``t = cross(p0b - p0a, d_b) / cross(d_a, d_b)`` and
    ``cross(d_a, d_b) = sin(psib - psia)``: the SPEC formula with ``beta = 1``.

    Args:
        p0a: a point on line a [m], shape ``(..., 2)``.
        psia: angle of line a [rad], shape ``(...,)``.
        p0b: a point on line b [m], shape ``(..., 2)``.
        psib: angle of line b [rad], shape ``(...,)``.
        parallel_sin_min: lines with ``|sin(psib - psia)| <= parallel_sin_min`` count as
            parallel (``ModelConfig.parallel_sin_min``); exactly parallel lines (up to
            round-off, ``PARALLEL_SIN_FLOOR``) always do.

    Returns:
        ``(point (..., 2) [m], ok (...,) bool)``; ``point`` is NaN where ``ok`` is False.
    """
    p0a = np.asarray(p0a, dtype=float)
    p0b = np.asarray(p0b, dtype=float)
    da = line_direction(psia)
    db = line_direction(psib)
    sin_angle = _cross(da, db)
    numerator = _cross(p0b - p0a, db)
    ok = np.abs(sin_angle) > max(float(parallel_sin_min), PARALLEL_SIN_FLOOR)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(ok, numerator / np.where(ok, sin_angle, 1.0), np.nan)
    point = p0a + t[..., None] * da
    point = np.where(ok[..., None], point, np.nan)
    return point, _scalar_or_array(ok)


def perpendicular_distance(points: np.ndarray, p0: np.ndarray, psi: np.ndarray) -> np.ndarray:
    """Signed distance [m] of points from lines, positive on the normal side.

    Args:
        points: shape ``(..., n, 2)`` [m].
        p0: a point of each line, shape ``(..., 2)`` [m].
        psi: line angles, shape ``(...,)`` [rad].

    Returns:
        ``(points - p0) . [-sin psi, cos psi]``, shape ``(..., n)``.
    """
    points = _check_points(points, 0, "perpendicular_distance")
    p0 = np.asarray(p0, dtype=float)
    normal = line_normal(psi)
    return np.sum((points - p0[..., None, :]) * normal[..., None, :], axis=-1)


def fit_line_jacobian(points: np.ndarray, p0: np.ndarray, psi: np.ndarray) -> np.ndarray:
    """First-order derivative of :func:`fit_line`'s ``(p0x, p0y, psi)`` w.r.t. each point.

    ``dp0 / dz_k = I / n``; ``dpsi / dz_k = ((d . e_k) nrm + (nrm . e_k) d) / (l1 - l2)``
    with ``e_k = z_k - p0``, ``d``/``nrm`` the line direction/normal and ``l1 > l2`` the
    eigenvalues of the scatter matrix ``sum_k e_k e_k^T`` (eigenvector perturbation).

    Args:
        points: shape ``(..., n, 2)`` [m].
        p0: their mean [m], shape ``(..., 2)``, as returned by :func:`fit_line`.
        psi: their principal-axis angle [rad], shape ``(...,)``, from :func:`fit_line`.

    Returns:
        ``J`` of shape ``(..., 3, n, 2)``: ``J[..., i, k, j] = d out_i / d z_k[j]`` with
        ``out = (p0x [m], p0y [m], psi [rad])``. Reshape to ``(..., 3, 2n)`` for a
        Jacobian with respect to the flattened points ``[x_0, y_0, x_1, ...]``.

    Raises:
        ValueError: the scatter is isotropic (``l1 == l2``): the direction is undefined.
    """
    points = _check_points(points, 2, "fit_line_jacobian")
    p0 = np.asarray(p0, dtype=float)
    n = points.shape[-2]
    e = points - p0[..., None, :]
    d = line_direction(psi)[..., None, :]
    nrm = line_normal(psi)[..., None, :]
    along = np.sum(e * d, axis=-1)  # (..., n)
    across = np.sum(e * nrm, axis=-1)
    gap = np.sum(along**2, axis=-1) - np.sum(across**2, axis=-1)  # l1 - l2
    if np.any(~(gap > 0)):
        raise ValueError(
            "fit_line_jacobian: the scatter matrix has equal eigenvalues (or psi is not the "
            "principal axis of these points); the line direction is undefined"
        )
    dpsi = (along[..., None] * nrm + across[..., None] * d) / gap[..., None, None]
    batch = np.broadcast_shapes(points.shape[:-2], np.shape(psi), p0.shape[:-1])
    J = np.zeros((*batch, 3, n, 2))
    J[..., 0, :, 0] = 1.0 / n
    J[..., 1, :, 1] = 1.0 / n
    J[..., 2, :, :] = dpsi
    return J
