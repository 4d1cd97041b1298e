"""Planar obstacle geometry against hand-computed values and brute-force sampling."""

from __future__ import annotations

import math

import numpy as np
import pytest

from vslam_gym.sim import shapes
from vslam_gym.sim.world import CircleObstacle, PolygonObstacle, WallObstacle

SQUARE = PolygonObstacle(points=((0.0, 0.0), (2.0, 0.0), (2.0, 2.0), (0.0, 2.0)))
# A "U" opening north: non-convex, the notch is x in (1, 2), y in (1, 3).
U_SHAPE = PolygonObstacle(
    points=((0.0, 0.0), (3.0, 0.0), (3.0, 3.0), (2.0, 3.0), (2.0, 1.0), (1.0, 1.0), (1.0, 3.0),
            (0.0, 3.0))
)  # fmt: skip
DISC = CircleObstacle(center=(5.0, 5.0), radius=1.0)
WALL = WallObstacle(points=((0.0, 10.0), (4.0, 10.0), (4.0, 14.0)), thickness=0.2)


def test_point_segment_distance_values_and_degenerate_segments():
    d = shapes.point_segment_distance([[0.0, 1.0], [3.0, 0.0], [-1.0, 0.0]], [[0, 0]], [[2, 0]])
    assert d[:, 0] == pytest.approx([1.0, 1.0, 1.0])
    assert shapes.point_segment_distance([3.0, 4.0], [0.0, 0.0], [0.0, 0.0])[0, 0] == 5.0


def test_point_segment_distance_of_a_subset_is_bitwise_the_same():
    rng = np.random.default_rng(6)
    points = rng.uniform(-5.0, 5.0, (64, 2))
    a = rng.uniform(-5.0, 5.0, (30, 2))
    b = a + rng.uniform(-2.0, 2.0, (30, 2))
    b[::7] = a[::7]  # some points
    full = shapes.point_segment_distance(points, a, b)
    rows, cols = rng.permutation(64)[:9], np.array([0, 7, 13, 29])
    part = shapes.point_segment_distance(points[rows], a[cols], b[cols])
    assert np.array_equal(part, full[np.ix_(rows, cols)])
    # Against sampling the segments densely (at most 1.5 mm apart).
    t = np.linspace(0.0, 1.0, 2001)[:, None, None]
    dense = a[None] + t * (b - a)[None]  # (t, segment, 2)
    brute = np.linalg.norm(points[:16, None, None, :] - dense[None], axis=-1).min(axis=1)
    assert np.abs(full[:16] - brute).max() < 1e-3
    assert np.all(full[:16] <= brute + 1e-12)


@pytest.mark.parametrize(
    ("p0", "p1", "q0", "q1", "hit"),
    [
        ((0, 0), (2, 2), (0, 2), (2, 0), True),  # proper crossing
        ((0, 0), (2, 0), (1, 0), (1, 3), True),  # endpoint touches
        ((0, 0), (2, 0), (1, 0), (3, 0), True),  # collinear overlap
        ((0, 0), (1, 0), (2, 0), (3, 0), False),  # collinear, disjoint
        ((0, 0), (2, 0), (0, 1), (2, 1), False),  # parallel
        ((0, 0), (1, 1), (2, 0), (3, -5), False),
    ],
)
def test_segments_intersect_cases(p0, p1, q0, q1, hit):
    assert bool(shapes.segments_intersect(p0, p1, q0, q1)[0, 0]) is hit
    assert bool(shapes.segments_intersect(q0, q1, p0, p1)[0, 0]) is hit
    d = shapes.segment_segment_distance(p0, p1, q0, q1)[0, 0]
    assert bool(d == 0.0) is hit


def test_segment_segment_distance_value():
    assert shapes.segment_segment_distance((0, 0), (2, 0), (3, 1), (3, 5))[0, 0] == pytest.approx(
        math.sqrt(2.0)
    )


def test_point_in_polygon_handles_the_notch_of_a_non_convex_polygon():
    pts = [[0.5, 2.0], [1.5, 2.0], [2.5, 2.0], [1.5, 0.5], [4.0, 1.0]]
    assert shapes.point_in_polygon(pts, U_SHAPE.points).tolist() == [True, False, True, True, False]


def test_polygon_area_sign_follows_orientation():
    assert shapes.polygon_area(SQUARE.points) == pytest.approx(4.0)
    assert shapes.polygon_area(SQUARE.points[::-1]) == pytest.approx(-4.0)
    assert shapes.polygon_area(U_SHAPE.points) == pytest.approx(7.0)


@pytest.mark.parametrize(
    ("points", "simple"),
    [
        (SQUARE.points, True),
        (U_SHAPE.points, True),
        (((0, 0), (1, 1), (1, 0), (0, 1)), False),  # bow tie
        (((0, 0), (2, 0), (1, 0), (1, 1)), False),  # spike folding back on itself
        (((0, 0), (1, 0), (2, 0)), False),  # collinear
        (((0, 0), (2, 0), (2, 2), (1, 0), (0, 2)), False),  # vertex touching an edge
        (((0, 0), (1, 0), (1, 0), (0, 1)), False),  # repeated vertex
        (((0, 0), (1, 0)), False),
    ],
)
def test_simplicity(points, simple):
    assert shapes.is_simple_polygon(points) is simple


def test_self_intersection_reports_the_crossing_edges():
    assert shapes.polygon_self_intersection(((0, 0), (1, 1), (1, 0), (0, 1))) == (0, 2)
    assert shapes.polygon_self_intersection(U_SHAPE.points) is None


def _test_polygons(rng: np.random.Generator, count: int) -> list[np.ndarray]:
    """Star-shaped (simple), random (mostly crossing) and grid polygons (repeated and
    collinear vertices, touching edges), 3 to 11 vertices."""
    polygons = []
    for i in range(count):
        k = int(rng.integers(3, 12))
        if i % 3 == 0:
            angle = 2 * np.pi * (np.arange(k) + rng.uniform(0.0, 0.8, k)) / k
            radius = rng.uniform(0.3, 1.0, k)
            polygons.append(np.stack([radius * np.cos(angle), radius * np.sin(angle)], axis=1))
        elif i % 3 == 1:
            polygons.append(rng.uniform(-1.0, 1.0, (k, 2)))
        else:
            polygons.append(rng.integers(0, 4, (k, 2)).astype(float))
    return polygons


def test_short_and_long_polygon_paths_find_the_same_crossing(monkeypatch):
    polygons = _test_polygons(np.random.default_rng(4), 600)
    monkeypatch.setattr(shapes, "_SMALL_POLYGON", 10**6)  # plain Python loop
    loop = [shapes.polygon_self_intersection(p) for p in polygons]
    monkeypatch.setattr(shapes, "_SMALL_POLYGON", 0)  # numpy, vectorised
    vectorised = [shapes.polygon_self_intersection(p) for p in polygons]
    assert loop == vectorised
    assert 100 < sum(r is None for r in loop) < 500  # both simple and crossing cases


def test_shoelace_sum_is_twice_the_area_whatever_the_first_vertex():
    assert shapes.shoelace_sum(SQUARE.points) == 8.0
    assert shapes.shoelace_sum(SQUARE.points[::-1]) == -8.0
    assert shapes.shoelace_sum(U_SHAPE.points) == 14.0
    rng = np.random.default_rng(2)
    for polygon in _test_polygons(rng, 60):
        ring = (polygon * 1e3 + 1e6).tolist()  # far from the origin: terms cancel heavily
        sums = {shapes.shoelace_sum(ring[k:] + ring[:k]) for k in range(len(ring))}
        assert len(sums) == 1  # exactly rounded, so independent of the summation order
        assert sums.pop() == pytest.approx(2.0 * shapes.polygon_area(ring), rel=1e-6, abs=1e-3)


def test_signed_distances_of_each_kind():
    sq = shapes.signed_distance(SQUARE, [[1.0, 1.0], [1.0, 0.25], [3.0, 1.0], [3.0, 3.0]])
    assert sq == pytest.approx([-1.0, -0.25, 1.0, math.sqrt(2.0)])
    assert shapes.signed_distance(DISC, [[5.0, 5.0], [8.0, 5.0]]) == pytest.approx([-1.0, 2.0])
    wall = shapes.signed_distance(WALL, [[2.0, 10.0], [2.0, 11.0], [4.0, 15.0], [-1.0, 10.0]])
    assert wall == pytest.approx([-0.1, 0.9, 0.9, 0.9])  # round caps at the ends
    assert shapes.contains(U_SHAPE, [[1.5, 2.0], [0.5, 2.0]]).tolist() == [False, True]
    assert shapes.distance_to_obstacle(SQUARE, [[1.0, 1.0]])[0] == 0.0
    assert shapes.clearance([SQUARE, DISC], [[3.0, 3.0]])[0] == pytest.approx(math.sqrt(2.0))
    assert shapes.clearance([], [[0.0, 0.0]])[0] == math.inf


@pytest.mark.parametrize("obstacle", [SQUARE, U_SHAPE, DISC, WALL])
def test_signed_distance_matches_brute_force_boundary_sampling(obstacle):
    rng = np.random.default_rng(0)
    x0, y0, x1, y1 = shapes.obstacle_bounds(obstacle)
    pts = rng.uniform((x0 - 1, y0 - 1), (x1 + 1, y1 + 1), size=(200, 2))
    a, b, r = shapes.obstacle_capsules(obstacle)
    t = np.linspace(0.0, 1.0, 2001)
    dense = (a[:, None, :] + t[None, :, None] * (b - a)[:, None, :]).reshape(-1, 2)
    radius = np.repeat(r, len(t))
    brute = np.min(np.linalg.norm(pts[:, None] - dense[None], axis=-1) - radius, axis=1)
    got = shapes.signed_distance(obstacle, pts)
    assert np.abs(np.abs(got) - np.abs(brute)).max() < 2e-3
    if isinstance(obstacle, PolygonObstacle):
        assert np.array_equal(got < 0, shapes.point_in_polygon(pts, obstacle.points))


def test_segment_clearance_passing_crossing_and_inside():
    assert shapes.segment_clearance(SQUARE, (-1.0, 3.0), (3.0, 3.0)) == pytest.approx(1.0)
    assert shapes.segment_clearance(SQUARE, (-1.0, 1.0), (3.0, 1.0)) == 0.0
    assert shapes.segment_clearance(SQUARE, (0.5, 0.5), (1.5, 1.5)) == 0.0  # wholly inside
    assert shapes.segment_clearance(U_SHAPE, (1.5, 1.5), (1.5, 4.0)) == pytest.approx(0.5)
    assert shapes.segment_clearance(DISC, (0.0, 7.0), (10.0, 7.0)) == pytest.approx(1.0)
    assert shapes.segment_clearance(WALL, (2.0, 12.0), (3.0, 12.0)) == pytest.approx(0.9)
    many = shapes.segments_clearance(
        SQUARE, [[-1, 3], [-1, 1], [0.5, 0.5]], [[3, 3], [3, 1], [1, 1]]
    )
    assert many == pytest.approx([1.0, 0.0, 0.0])


def test_obstacle_distance_and_bounds():
    assert shapes.obstacle_distance(SQUARE, DISC) == pytest.approx(math.hypot(3, 3) - 1.0)
    inner = PolygonObstacle(points=((0.5, 0.5), (1.0, 0.5), (1.0, 1.0)))
    assert shapes.obstacle_distance(SQUARE, inner) == 0.0  # contained
    assert shapes.obstacle_distance(inner, SQUARE) == 0.0
    assert shapes.obstacle_bounds(WALL) == pytest.approx((-0.1, 9.9, 4.1, 14.1))
    assert shapes.obstacle_bounds(DISC) == pytest.approx((4.0, 4.0, 6.0, 6.0))


def test_bad_point_arrays_raise():
    with pytest.raises(ValueError, match="shape"):
        shapes.as_points([[1.0, 2.0, 3.0]])
