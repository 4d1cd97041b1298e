"""Planar geometry of obstacles: distances, containment, polygon simplicity, clearance.

Pure numpy. All coordinates are metres in the world frame; point arrays are ``(n, 2)``.

Every obstacle is treated as a union of *capsules* (a segment swept by a disc of some
radius) plus, for polygons, the solid interior:

- a polygon is its closed boundary (capsules of radius 0) and its interior;
- a circle is one degenerate capsule (both ends at the centre) with the circle's radius;
- a wall is one capsule per polyline segment with radius ``thickness / 2`` (round ends,
  exactly what ``pymunk.Segment(body, a, b, radius=thickness / 2)`` models).

Signed distances are negative inside an obstacle, zero on its boundary and positive
outside; for walls and circles they are exact, for polygons the magnitude is the
distance to the boundary.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from vslam_gym.sim.world import CircleObstacle, Obstacle, PolygonObstacle, WallObstacle

__all__ = [
    "as_points",
    "clearance",
    "contains",
    "distance_to_obstacle",
    "is_simple_polygon",
    "obstacle_bounds",
    "obstacle_capsules",
    "obstacle_distance",
    "point_in_polygon",
    "point_segment_distance",
    "polygon_area",
    "polygon_self_intersection",
    "segment_clearance",
    "segments_clearance",
    "segment_segment_distance",
    "segments_intersect",
    "shoelace_sum",
    "signed_distance",
]

_SMALL_POLYGON = 32
"""Polygons with up to this many vertices are tested for simplicity in a plain Python loop,
which is faster than the vectorised test for the short rings of obstacles."""


def as_points(points: object) -> np.ndarray:
    """Return ``points`` as a float ``(n, 2)`` array (a single ``(2,)`` point gives ``n = 1``).

    Raises:
        ValueError: if the input cannot be read as ``(n, 2)`` coordinates.
    """
    arr = np.asarray(points, dtype=float)
    if arr.ndim == 1 and arr.shape[0] == 2:
        arr = arr[None, :]
    if arr.ndim != 2 or arr.shape[1] != 2:
        raise ValueError(f"expected points of shape (n, 2), got shape {arr.shape}")
    return arr


def _next(v: np.ndarray) -> np.ndarray:
    """``v`` shifted by one along the first axis (element ``i`` is ``v[i + 1]``, cyclic)."""
    return np.concatenate([v[1:], v[:1]])


def _cross(ax: np.ndarray, ay: np.ndarray, bx: np.ndarray, by: np.ndarray) -> np.ndarray:
    return ax * by - ay * bx


def point_segment_distance(points: object, a: object, b: object) -> np.ndarray:
    """Distances [m] from each point to each closed segment ``a[j]``-``b[j]``.

    Every entry is computed by the same elementwise operations, so it does not depend on
    which other points or segments are passed along (a subset gives the same values).

    Args:
        points: ``(n, 2)`` query points [m].
        a: ``(m, 2)`` segment starts [m].
        b: ``(m, 2)`` segment ends [m]; ``a[j] == b[j]`` is allowed (a point).

    Returns:
        ``(n, m)`` Euclidean distances [m].
    """
    p, a_, b_ = as_points(points), as_points(a), as_points(b)
    px, py = p[:, 0:1], p[:, 1:2]
    ax, ay = a_[:, 0], a_[:, 1]
    dx, dy = b_[:, 0] - ax, b_[:, 1] - ay
    length_sq = dx * dx + dy * dy
    proper = length_sq > 0.0  # else a point: the distance to `a`
    t = (px - ax) * dx
    t += (py - ay) * dy
    t /= np.where(proper, length_sq, 1.0)
    np.clip(t, 0.0, 1.0, out=t)
    t[:, ~proper] = 0.0
    ex = px - (ax + t * dx)  # the point minus the closest point of the segment
    ey = py - (ay + t * dy)
    ex *= ex
    ey *= ey
    ex += ey
    return np.sqrt(ex, out=ex)


def _orientation(*coords: np.ndarray) -> np.ndarray:
    """Sign of the turn o -> a -> b (+1 left, -1 right, 0 collinear) for ``ox, oy, ax, ...``."""
    ox, oy, ax, ay, bx, by = coords
    return np.sign(_cross(ax - ox, ay - oy, bx - ox, by - oy))


def segments_intersect(p0: object, p1: object, q0: object, q1: object) -> np.ndarray:
    """Whether closed segments ``p0[i]-p1[i]`` and ``q0[j]-q1[j]`` share a point.

    Touching (an endpoint on the other segment) and collinear overlap count as
    intersecting.

    Returns:
        ``(n, m)`` boolean array.
    """
    p0_, p1_ = as_points(p0)[:, None, :], as_points(p1)[:, None, :]
    q0_, q1_ = as_points(q0)[None, :, :], as_points(q1)[None, :, :]
    args_p = (p0_[..., 0], p0_[..., 1], p1_[..., 0], p1_[..., 1])
    o1 = _orientation(*args_p, q0_[..., 0], q0_[..., 1])
    o2 = _orientation(*args_p, q1_[..., 0], q1_[..., 1])
    args_q = (q0_[..., 0], q0_[..., 1], q1_[..., 0], q1_[..., 1])
    o3 = _orientation(*args_q, p0_[..., 0], p0_[..., 1])
    o4 = _orientation(*args_q, p1_[..., 0], p1_[..., 1])
    proper = (o1 * o2 < 0) & (o3 * o4 < 0)

    def on_segment(s0: np.ndarray, s1: np.ndarray, r: np.ndarray) -> np.ndarray:
        lo, hi = np.minimum(s0, s1), np.maximum(s0, s1)
        return np.all((r >= lo) & (r <= hi), axis=-1)

    touch = (
        ((o1 == 0) & on_segment(p0_, p1_, q0_))
        | ((o2 == 0) & on_segment(p0_, p1_, q1_))
        | ((o3 == 0) & on_segment(q0_, q1_, p0_))
        | ((o4 == 0) & on_segment(q0_, q1_, p1_))
    )
    return proper | touch


def segment_segment_distance(p0: object, p1: object, q0: object, q1: object) -> np.ndarray:
    """Distances [m] between closed segments ``p0[i]-p1[i]`` and ``q0[j]-q1[j]``.

    Returns:
        ``(n, m)`` distances [m]; zero where the segments intersect or touch.
    """
    p0_, p1_, q0_, q1_ = (as_points(x) for x in (p0, p1, q0, q1))
    d = np.minimum(
        np.minimum(point_segment_distance(p0_, q0_, q1_), point_segment_distance(p1_, q0_, q1_)),
        np.minimum(
            point_segment_distance(q0_, p0_, p1_).T, point_segment_distance(q1_, p0_, p1_).T
        ),
    )
    return np.where(segments_intersect(p0_, p1_, q0_, q1_), 0.0, d)


def point_in_polygon(points: object, polygon: object) -> np.ndarray:
    """Even-odd test of each point against a closed polygon.

    Args:
        points: ``(n, 2)`` query points [m].
        polygon: ``(k, 2)`` vertices [m] in order (either orientation, not repeated at
            the end).

    Returns:
        ``(n,)`` booleans; points exactly on the boundary may fall either way.
    """
    p = as_points(points)
    v = as_points(polygon)
    xi, yi = v[:, 0], v[:, 1]
    xj, yj = _next(xi), _next(yi)
    px, py = p[:, 0:1], p[:, 1:2]
    straddle = (yi > py) != (yj > py)
    dy = np.where(yj != yi, yj - yi, 1.0)
    x_cross = xi + (py - yi) * (xj - xi) / dy
    crossings = straddle & (px < x_cross)
    return (np.count_nonzero(crossings, axis=1) % 2) == 1


def shoelace_sum(ring: Sequence[Sequence[float]]) -> float:
    """Twice the signed area [m^2] of a vertex ring: positive if counter-clockwise.

    The shoelace terms ``x_i y_(i+1) - x_(i+1) y_i`` are added with :func:`math.fsum`
    (correctly rounded), so the sign is exact for the given terms and does not depend
    on the summation order. Plain Python, for the short rings of obstacles.

    Args:
        ring: ``(k, 2)`` vertices [m] in order, not repeated at the end.
    """
    return math.fsum(
        [ring[i - 1][0] * ring[i][1] - ring[i][0] * ring[i - 1][1] for i in range(len(ring))]
    )


def polygon_area(polygon: object) -> float:
    """Signed area [m^2] of a polygon (shoelace formula): positive if counter-clockwise."""
    v = as_points(polygon)
    x, y = v[:, 0], v[:, 1]
    return float(0.5 * np.sum(x * _next(y) - _next(x) * y))


def polygon_self_intersection(polygon: object) -> tuple[int, int] | None:
    """First pair of edges ``(i, j)`` that makes the polygon non-simple, else ``None``.

    Edge ``i`` joins vertex ``i`` to vertex ``i + 1`` (the last edge closes the polygon).
    Non-adjacent edges must not touch; adjacent edges must not fold back onto each
    other (a zero-angle spike) and must not have zero length.

    Args:
        polygon: ``(k, 2)`` vertices [m], ``k >= 3``.
    """
    v = as_points(polygon)
    if len(v) <= _SMALL_POLYGON:
        return _self_intersection_loop(v.tolist())
    return _self_intersection_vectorised(v)


def _self_intersection_vectorised(v: np.ndarray) -> tuple[int, int] | None:
    """:func:`polygon_self_intersection` of ``(k, 2)`` vertices, numpy-vectorised."""
    k = len(v)
    a, b = v, _next(v)
    length = np.linalg.norm(b - a, axis=1)
    for i in np.flatnonzero(length == 0.0):
        return int(i), int((i + 1) % k)
    # Adjacent edges i, i+1 overlap only if they are collinear and point back.
    e, e_next = b - a, _next(b - a)
    cross = _cross(e[:, 0], e[:, 1], e_next[:, 0], e_next[:, 1])
    dot = np.einsum("ij,ij->i", e, e_next)
    for i in np.flatnonzero((cross == 0.0) & (dot < 0.0)):
        return int(i), int((i + 1) % k)
    hits = segments_intersect(a, b, a, b)
    idx = np.arange(k)
    gap = np.abs(idx[:, None] - idx[None, :])
    adjacent = (gap <= 1) | (gap == k - 1)
    hits &= ~adjacent
    pairs = np.argwhere(np.triu(hits))
    if len(pairs):
        return int(pairs[0, 0]), int(pairs[0, 1])
    return None


def _in_box(s0: Sequence[float], s1: Sequence[float], r: Sequence[float]) -> bool:
    """Whether ``r`` lies in the bounding box of the segment ``s0``-``s1``."""
    return min(s0[0], s1[0]) <= r[0] <= max(s0[0], s1[0]) and min(s0[1], s1[1]) <= r[1] <= max(
        s0[1], s1[1]
    )


def _self_intersection_loop(v: list[list[float]]) -> tuple[int, int] | None:
    """:func:`polygon_self_intersection` of a vertex list, in plain Python.

    The same tests in the same order and with the same arithmetic as
    :func:`_self_intersection_vectorised` (and :func:`segments_intersect`), so both give
    the same answer.
    """
    k = len(v)
    nxt = v[1:] + v[:1]
    edges = [(b[0] - a[0], b[1] - a[1]) for a, b in zip(v, nxt, strict=True)]
    for i, (ex, ey) in enumerate(edges):
        if ex * ex + ey * ey == 0.0:
            return i, (i + 1) % k
    for i, (ex, ey) in enumerate(edges):
        fx, fy = edges[(i + 1) % k]
        if ex * fy - ey * fx == 0.0 and ex * fx + ey * fy < 0.0:
            return i, (i + 1) % k
    for i in range(k):
        p0, p1 = v[i], nxt[i]
        for j in range(i + 2, k - 1 if i == 0 else k):  # skip adjacent edges
            q0, q1 = v[j], nxt[j]
            # Turns p0 -> p1 -> q0, p0 -> p1 -> q1, q0 -> q1 -> p0, q0 -> q1 -> p1.
            o1 = (p1[0] - p0[0]) * (q0[1] - p0[1]) - (p1[1] - p0[1]) * (q0[0] - p0[0])
            o2 = (p1[0] - p0[0]) * (q1[1] - p0[1]) - (p1[1] - p0[1]) * (q1[0] - p0[0])
            o3 = (q1[0] - q0[0]) * (p0[1] - q0[1]) - (q1[1] - q0[1]) * (p0[0] - q0[0])
            o4 = (q1[0] - q0[0]) * (p1[1] - q0[1]) - (q1[1] - q0[1]) * (p1[0] - q0[0])
            if (((o1 > 0.0 > o2) or (o1 < 0.0 < o2)) and ((o3 > 0.0 > o4) or (o3 < 0.0 < o4))) or (
                (o1 == 0.0 and _in_box(p0, p1, q0))
                or (o2 == 0.0 and _in_box(p0, p1, q1))
                or (o3 == 0.0 and _in_box(q0, q1, p0))
                or (o4 == 0.0 and _in_box(q0, q1, p1))
            ):
                return i, j
    return None


def is_simple_polygon(polygon: object) -> bool:
    """Whether a polygon of ``>= 3`` vertices is simple.

    Simple: no self-intersection (:func:`polygon_self_intersection`) and a non-zero area
    (the exact sign of :func:`shoelace_sum`).
    """
    v = as_points(polygon)
    if len(v) < 3:
        return False
    return polygon_self_intersection(v) is None and shoelace_sum(v.tolist()) != 0.0


def obstacle_capsules(obstacle: Obstacle) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Return the capsules whose union is the boundary (polygon) or the body (circle, wall).

    Returns:
        ``(a, b, radius)``: ``(k, 2)`` segment starts [m], ``(k, 2)`` ends [m] and
        ``(k,)`` radii [m].
    """
    if isinstance(obstacle, PolygonObstacle):
        a = as_points(obstacle.points)
        return a, _next(a), np.zeros(len(a))
    if isinstance(obstacle, CircleObstacle):
        c = as_points(obstacle.center)
        return c, c.copy(), np.array([float(obstacle.radius)])
    if isinstance(obstacle, WallObstacle):
        p = as_points(obstacle.points)
        return p[:-1], p[1:], np.full(len(p) - 1, 0.5 * float(obstacle.thickness))
    raise TypeError(f"not an obstacle: {obstacle!r}")


def signed_distance(obstacle: Obstacle, points: object) -> np.ndarray:
    """Signed distance [m] from each point to the obstacle: < 0 inside, > 0 outside.

    Args:
        obstacle: a polygon, circle or wall obstacle.
        points: ``(n, 2)`` points [m] in the world frame.

    Returns:
        ``(n,)`` signed distances [m].
    """
    p = as_points(points)
    a, b, r = obstacle_capsules(obstacle)
    d = np.min(point_segment_distance(p, a, b) - r[None, :], axis=1)
    if isinstance(obstacle, PolygonObstacle):
        d = np.where(point_in_polygon(p, a), -d, d)
    return d


def distance_to_obstacle(obstacle: Obstacle, points: object) -> np.ndarray:
    """Distance [m] from each point to the obstacle; zero for points inside it."""
    return np.maximum(signed_distance(obstacle, points), 0.0)


def contains(obstacle: Obstacle, points: object) -> np.ndarray:
    """Whether each point lies strictly inside the obstacle (``(n,)`` booleans)."""
    return signed_distance(obstacle, points) < 0.0


def clearance(obstacles: object, points: object) -> np.ndarray:
    """Smallest signed distance [m] from each point to any of ``obstacles``.

    Returns:
        ``(n,)`` values; ``inf`` when there are no obstacles.
    """
    p = as_points(points)
    out = np.full(len(p), np.inf)
    for obstacle in obstacles:  # type: ignore[attr-defined]
        out = np.minimum(out, signed_distance(obstacle, p))
    return out


def segments_clearance(obstacle: Obstacle, a: object, b: object) -> np.ndarray:
    """Smallest distance [m] between each segment ``a[i]``-``b[i]`` and the obstacle.

    Zero where a segment touches or enters the obstacle. A robot disc of radius ``R``
    driving straight from ``a[i]`` to ``b[i]`` keeps ``clearance - R`` of free space.

    Args:
        obstacle: a polygon, circle or wall obstacle.
        a: ``(n, 2)`` segment starts [m].
        b: ``(n, 2)`` segment ends [m].

    Returns:
        ``(n,)`` clearances [m].
    """
    a_, b_ = as_points(a), as_points(b)
    ca, cb, r = obstacle_capsules(obstacle)
    d = np.min(segment_segment_distance(a_, b_, ca, cb) - r[None, :], axis=1)
    if isinstance(obstacle, PolygonObstacle):  # a segment wholly inside touches no edge
        d = np.where(point_in_polygon(a_, ca), 0.0, d)
    return np.maximum(d, 0.0)


def segment_clearance(obstacle: Obstacle, a: object, b: object) -> float:
    """Smallest distance [m] between the segment ``a``-``b`` and the obstacle (see above)."""
    return float(segments_clearance(obstacle, a, b)[0])


def obstacle_distance(first: Obstacle, second: Obstacle) -> float:
    """Smallest distance [m] between two obstacles; zero if they touch or overlap."""
    a1, b1, r1 = obstacle_capsules(first)
    a2, b2, r2 = obstacle_capsules(second)
    d = segment_segment_distance(a1, b1, a2, b2) - r1[:, None] - r2[None, :]
    if isinstance(first, PolygonObstacle) and bool(point_in_polygon(a2[:1], a1)[0]):
        return 0.0
    if isinstance(second, PolygonObstacle) and bool(point_in_polygon(a1[:1], a2)[0]):
        return 0.0
    return max(float(np.min(d)), 0.0)


def obstacle_bounds(obstacle: Obstacle) -> tuple[float, float, float, float]:
    """Axis-aligned bounding box ``(x_min, y_min, x_max, y_max)`` [m] of the obstacle."""
    a, b, r = obstacle_capsules(obstacle)
    lo = np.minimum(np.min(a - r[:, None], axis=0), np.min(b - r[:, None], axis=0))
    hi = np.maximum(np.max(a + r[:, None], axis=0), np.max(b + r[:, None], axis=0))
    return float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1])
