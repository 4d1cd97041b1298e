"""Ground-truth exploration metrics: boundary samples, reachability, coverage."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

from vslam_gym.exploration import (
    BoundarySamples,
    ExplorationMetricError,
    ReachabilityConfig,
    SampleIndex,
    boundary_samples,
    coverage,
    covered_samples,
    reachable_free_space,
)
from vslam_gym.sim.shapes import clearance, point_in_polygon, point_segment_distance
from vslam_gym.sim.world import (
    CircleObstacle,
    PolygonObstacle,
    RobotSpec,
    WallObstacle,
    World,
)
from vslam_gym.sim.world_file import load_world
from vslam_gym.slam.filter import LandmarkView
from vslam_gym.slam.landmark import LandmarkModel

BOX = ((2.0, 1.0), (4.0, 1.0), (4.0, 2.0), (2.0, 2.0))  # 2 m x 1 m, counter-clockwise
CENTER, RADIUS = (6.0, 5.0), 0.5
ROOM = ((0.0, 0.0), (10.0, 0.0), (10.0, 8.0), (0.0, 8.0), (0.0, 0.0))
THICKNESS = 0.2


def world_of(*obstacles, start=(5.0, 4.0, 0.0)) -> World:
    return World(name="test", robot=RobotSpec(start=start), obstacles=tuple(obstacles))


def belief_of(polylines, u=None, closed=None) -> SimpleNamespace:
    """A belief-like object: one landmark per polyline (vertices in the world frame)."""
    landmarks = []
    for i, vertices in enumerate(polylines):
        mean = np.asarray(vertices, dtype=float)
        k = len(mean)
        is_closed = True if closed is None else closed[i]
        n_lines = k if is_closed else k - 1
        model = LandmarkModel(
            mean,
            1e-6 * np.eye(2 * k),
            np.zeros(n_lines) if u is None else np.asarray(u[i], dtype=float),
            is_closed,
        )
        landmarks.append(
            LandmarkView(
                id=i,
                reference=mean.mean(axis=0),
                reference_cov=1e-6 * np.eye(2),
                model=model,
                object_vertices=(0, k),
            )
        )
    return SimpleNamespace(landmarks=tuple(landmarks))


# ---------------------------------------------------------------------------- samples


def test_box_samples_count_positions_and_outward_normals() -> None:
    samples = boundary_samples(world_of(PolygonObstacle(points=BOX)), spacing=0.05)
    points, normals, ids = samples  # unpacks like a tuple
    assert len(samples) == 2 * (40 + 20)  # 2 m and 1 m edges at 0.05 m
    assert np.all(ids == 0)
    a = np.array(BOX)
    dist = point_segment_distance(points, a, np.roll(a, -1, axis=0)).min(axis=1)
    assert np.max(dist) < 1e-12
    assert not point_in_polygon(points + 0.01 * normals, a).any()
    assert point_in_polygon(points - 0.01 * normals, a).all()
    np.testing.assert_allclose(np.linalg.norm(normals, axis=1), 1.0)


def test_clockwise_polygon_normals_still_point_out() -> None:
    samples = boundary_samples(world_of(PolygonObstacle(points=BOX[::-1])), spacing=0.05)
    assert len(samples) == 120
    assert not point_in_polygon(samples.points + 0.01 * samples.normals, np.array(BOX)).any()


def test_circle_samples_lie_on_the_circumference() -> None:
    samples = boundary_samples(world_of(CircleObstacle(center=CENTER, radius=RADIUS)), 0.05)
    assert len(samples) == math.ceil(2 * math.pi * RADIUS / 0.05)
    radial = samples.points - np.array(CENTER)
    np.testing.assert_allclose(np.linalg.norm(radial, axis=1), RADIUS)
    np.testing.assert_allclose(samples.normals, radial / RADIUS, atol=1e-12)


def test_spacing_sets_the_count() -> None:
    world = world_of(PolygonObstacle(points=BOX), CircleObstacle(center=CENTER, radius=RADIUS))
    coarse = boundary_samples(world, spacing=0.1)
    fine = boundary_samples(world, spacing=0.02)
    assert len(coarse) == 60 + math.ceil(2 * math.pi * RADIUS / 0.1)
    assert len(fine) == 300 + math.ceil(2 * math.pi * RADIUS / 0.02)
    assert np.bincount(fine.obstacle_ids).tolist() == [300, math.ceil(math.pi / 0.02)]


def test_enclosing_wall_keeps_only_its_inner_face() -> None:
    room = WallObstacle(points=ROOM, thickness=THICKNESS)
    samples = boundary_samples(world_of(room), spacing=0.05)
    half = THICKNESS / 2
    inner_perimeter = 2 * ((10 - 2 * half) + (8 - 2 * half))
    # inner faces only: every sample on the inside lines x = 0.1, 9.9, y = 0.1, 7.9
    x, y = samples.points.T
    on_inner = (
        np.isclose(x, half)
        | np.isclose(x, 10 - half)
        | np.isclose(y, half)
        | np.isclose(y, 8 - half)
    )
    assert on_inner.all()
    assert abs(len(samples) * 0.05 - inner_perimeter) < 0.5
    # normals point into the room
    inward = (samples.points + 0.3 * samples.normals - [5.0, 4.0]) @ np.eye(2)
    assert np.all(np.abs(inward[:, 0]) < 5 - half) and np.all(np.abs(inward[:, 1]) < 4 - half)


def test_robot_outside_the_enclosure_sees_the_outer_face() -> None:
    room = WallObstacle(points=ROOM, thickness=THICKNESS)
    samples = boundary_samples(world_of(room, start=(-2.0, -2.0, 0.0)), spacing=0.05)
    half = THICKNESS / 2
    x, y = samples.points.T
    outside = (x < 0.0) | (x > 10.0) | (y < 0.0) | (y > 8.0)  # beyond the centre line
    assert outside.all()
    # straight outer faces plus four quarter-circle corners
    outer = 2 * (10 + 8) + 2 * math.pi * half
    assert abs(len(samples) * 0.05 - outer) < 0.5


def test_junctions_and_touching_obstacles_drop_inside_points() -> None:
    room = WallObstacle(points=ROOM, thickness=THICKNESS)
    partition = WallObstacle(points=((5.0, 0.0), (5.0, 3.0)), thickness=0.1)  # T junction
    post = CircleObstacle(center=(8.0, 0.4), radius=0.3)  # overlaps the south wall
    world = world_of(room, partition, post, start=(3.0, 4.0, 0.0))
    samples = boundary_samples(world, spacing=0.05)
    assert np.all(clearance(world.obstacles, samples.points) >= -1e-6)
    # the partition's end cap inside the outer wall is gone, its free end cap is kept
    cap = samples.points[samples.obstacle_ids == 1]
    assert cap[:, 1].min() >= THICKNESS / 2 - 1e-9
    assert cap[:, 1].max() == pytest.approx(3.05, abs=0.005)
    # both faces of the partition are reachable (the room connects round its free end)
    assert np.count_nonzero(cap[:, 0] < 5.0) == pytest.approx(np.count_nonzero(cap[:, 0] > 5.0))


def test_reachable_free_space_is_the_robots_room() -> None:
    room = WallObstacle(points=ROOM, thickness=THICKNESS)
    mask, origin, cell = reachable_free_space(world_of(room))
    centres = origin + cell * (np.argwhere(mask) + 0.5)
    assert centres.min(axis=0) == pytest.approx([0.1, 0.1], abs=cell)
    assert centres.max(axis=0) == pytest.approx([9.9, 7.9], abs=cell)
    assert mask.sum() * cell**2 == pytest.approx(9.8 * 7.8, rel=0.03)


def test_start_inside_an_obstacle_raises() -> None:
    with pytest.raises(ExplorationMetricError, match="start"):
        boundary_samples(world_of(PolygonObstacle(points=BOX), start=(3.0, 1.5, 0.0)))
    with pytest.raises(ExplorationMetricError, match="spacing"):
        boundary_samples(world_of(PolygonObstacle(points=BOX)), spacing=0.0)
    with pytest.raises(ExplorationMetricError, match="grid_cell"):
        ReachabilityConfig(grid_cell=-1.0)


def test_shipped_house_drops_outer_faces_and_has_no_inside_points() -> None:
    world = load_world("house")
    samples = boundary_samples(world)
    x, y = samples.points.T
    assert np.all((x > 0.0) & (x < 20.0) & (y > 0.0) & (y < 15.0))  # no outer face
    assert np.all(clearance(world.obstacles, samples.points) >= -1e-6)
    assert set(np.unique(samples.obstacle_ids)) == set(range(len(world.obstacles)))


# ---------------------------------------------------------------------------- coverage


def test_coverage_of_true_lines_is_one_and_of_an_empty_map_zero() -> None:
    world = world_of(PolygonObstacle(points=BOX), CircleObstacle(center=CENTER, radius=RADIUS))
    samples = boundary_samples(world)
    circle = [
        (CENTER[0] + RADIUS * math.cos(t), CENTER[1] + RADIUS * math.sin(t))
        for t in np.linspace(0, 2 * math.pi, 64, endpoint=False)
    ]  # chord sagitta 0.6 mm
    assert coverage(samples, belief_of([BOX, circle])) == 1.0
    assert coverage(samples, belief_of([])) == 0.0
    assert coverage(samples, belief_of([BOX])) == pytest.approx(120 / len(samples))


def test_coverage_ignores_unknown_lines_and_respects_the_tolerance() -> None:
    samples = boundary_samples(world_of(PolygonObstacle(points=BOX)))
    # only the south edge is an object line: its 40 samples and the two nearest the
    # corner on each adjacent edge (0.025 m and 0.075 m from it) are within 0.1 m
    belief = belief_of([BOX], u=[[0.0, 1.0, 1.0, 1.0]])
    assert coverage(samples, belief) == pytest.approx(44 / 120)
    assert coverage(samples, belief, tolerance=0.05) == pytest.approx(42 / 120)
    assert coverage(samples, belief, unknown_threshold=1.0) == 1.0
    shifted = np.array(BOX) - [0.0, 0.15]
    a, b = shifted, np.roll(shifted, -1, axis=0)
    expected = np.mean(point_segment_distance(samples.points, a, b).min(axis=1) <= 0.1)
    assert 0.0 < expected < 0.5
    assert coverage(samples, belief_of([shifted]), tolerance=0.1) == pytest.approx(expected)
    assert coverage(samples, belief_of([shifted]), tolerance=0.16) == 1.0
    assert coverage(samples.points, belief_of([shifted]), tolerance=0.16) == 1.0


def test_covered_samples_matches_brute_force() -> None:
    rng = np.random.default_rng(0)
    points = rng.uniform(0, 10, size=(3000, 2))
    starts = rng.uniform(0, 10, size=(80, 2))
    ends = starts + rng.normal(0, 1.5, size=(80, 2))
    ends[0] = starts[0]  # a degenerate segment
    for tolerance in (0.0, 0.05, 0.1, 0.4):
        expected = point_segment_distance(points, starts, ends).min(axis=1) <= tolerance
        got = covered_samples(points, starts, ends, tolerance)
        np.testing.assert_array_equal(got, expected)
        assert SampleIndex(points, cell=0.7).covered(starts, ends, tolerance).tolist() == (
            expected.tolist()
        )
    assert covered_samples(points, np.zeros((0, 2)), np.zeros((0, 2))).sum() == 0
    with pytest.raises(ExplorationMetricError, match="tolerance"):
        covered_samples(points, starts, ends, -0.1)


def test_segments_outside_the_sample_grid_cover_nothing() -> None:
    index = SampleIndex(np.array([[0.0, 0.0], [1.0, 0.0]]))
    far = index.covered(np.array([[50.0, 50.0]]), np.array([[60.0, -40.0]]), 0.1)
    assert far.sum() == 0
    across = index.covered(np.array([[-30.0, 0.05]]), np.array([[30.0, 0.05]]), 0.1)
    assert across.all()


def test_boundary_samples_index_is_cached() -> None:
    samples = boundary_samples(world_of(PolygonObstacle(points=BOX)))
    assert isinstance(samples, BoundarySamples)
    assert samples.index is samples.index


def test_open_wall_has_two_sides_and_two_round_caps() -> None:
    wall = WallObstacle(points=((2.0, 1.0), (5.0, 1.0)), thickness=0.1)
    samples = boundary_samples(world_of(wall), spacing=0.05)
    cap = math.ceil(math.pi * 0.05 / 0.05)
    assert len(samples) == 2 * 60 + 2 * cap
    distance = point_segment_distance(samples.points, [[2.0, 1.0]], [[5.0, 1.0]])[:, 0]
    np.testing.assert_allclose(distance, 0.05)
    ahead = samples.points + 0.01 * samples.normals
    assert np.all(point_segment_distance(ahead, [[2.0, 1.0]], [[5.0, 1.0]])[:, 0] > 0.05)


def test_object_lines_are_the_known_belief_segments() -> None:
    from vslam_gym.belief_observation import belief_segments
    from vslam_gym.exploration import object_lines

    belief = belief_of(
        [BOX, [(0.0, 0.0), (1.0, 0.0), (1.0, 1.0)]],
        u=[[0.0, 0.9, 0.5, 0.2], [1.0, 0.0]],
        closed=[True, False],
    )
    seg = belief_segments(belief, 0.5)
    starts, ends = object_lines(belief, 0.5)
    np.testing.assert_array_equal(starts, seg["start"][~seg["unknown"]])
    np.testing.assert_array_equal(ends, seg["end"][~seg["unknown"]])
    assert len(starts) == 4
