"""Procedural worlds: seeded determinism, counts, free start and route, parameter checks."""

from __future__ import annotations

import numpy as np
import pytest

from vslam_gym.config_utils import UnknownKeyError
from vslam_gym.sim import shapes
from vslam_gym.sim.random_world import (
    CLUTTER_KINDS,
    RandomWorldError,
    RandomWorldParams,
    _Candidates,
    _draw_kinds,
    _kind_cdf,
    _uniform_in_box,
    generate_random_world,
)
from vslam_gym.sim.world import PolygonObstacle, WallObstacle
from vslam_gym.sim.world_file import parse_world, world_to_toml

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10
    import tomli as tomllib

SEEDS = range(6)


def _clutter(world):
    return [o for o in world.obstacles if not isinstance(o, WallObstacle)]


def _segments(world):
    pts = list(world.route.waypoints)
    if world.route.loop:
        pts.append(pts[0])
    return list(zip(pts[:-1], pts[1:], strict=True))


def test_same_seed_gives_an_identical_world():
    assert generate_random_world(7) == generate_random_world(7)
    assert generate_random_world(np.random.default_rng(7)) == generate_random_world(7)
    kwargs = {"n_obstacles": 12, "n_rooms": 3}
    assert generate_random_world(3, **kwargs) == generate_random_world(3, **kwargs)


def test_different_seeds_give_different_worlds():
    worlds = [generate_random_world(seed) for seed in SEEDS]
    starts = {w.robot.start for w in worlds}
    obstacles = {w.obstacles for w in worlds}
    assert len(starts) == len(worlds) and len(obstacles) == len(worlds)


def test_passed_generator_is_advanced_not_copied():
    rng = np.random.default_rng(5)
    first, second = generate_random_world(rng), generate_random_world(rng)
    assert first != second


@pytest.mark.parametrize("weights", [(0.35, 0.2, 0.2, 0.25), (0.0, 1.0, 0.0, 3.0), (1, 1, 1, 1)])
def test_fast_draws_are_the_generator_draws_they_replace(weights):
    # The generator's stream (and so every world) is what rng.choice and rng.uniform with
    # per-coordinate bounds would give; the next draw shows both used the same numbers.
    params = RandomWorldParams(kind_weights=weights)
    p = np.asarray(params.kind_weights) / sum(params.kind_weights)
    fast, reference = np.random.default_rng(11), np.random.default_rng(11)
    for n in (1, 64, 500):
        kinds = _draw_kinds(fast, _kind_cdf(params), n)
        assert np.array_equal(kinds, reference.choice(len(CLUTTER_KINDS), size=n, p=p))
        low, high = (0.075, 1.0), (19.925, 14.5)
        for size in (2, (n, 2)):
            box = _uniform_in_box(fast, low, high, size)
            assert np.array_equal(box, reference.uniform(low, high, size=size))
        assert fast.random() == reference.random()
    assert set(np.unique(kinds)) == {k for k, w in enumerate(weights) if w > 0}


@pytest.mark.parametrize("rotate", [True, False])
def test_candidates_are_drawn_as_one_generator_call_per_field(rotate):
    params = RandomWorldParams(rotate_clutter=rotate)
    fast, reference = np.random.default_rng(2), np.random.default_rng(2)
    p = np.asarray(params.kind_weights) / sum(params.kind_weights)
    inset = params.wall_thickness / 2
    for _ in range(3):
        cand = _Candidates.draw(params, fast, 64, _kind_cdf(params))
        kind = reference.choice(len(CLUTTER_KINDS), size=64, p=p)
        box = (params.width - inset, params.height - inset)
        center = reference.uniform((inset, inset), box, size=(64, 2))
        size = reference.uniform(*params.clutter_size, size=(64, 2))
        arm = reference.uniform(*params.l_arm_fraction, size=64)
        angle = reference.uniform(0.0, 2 * np.pi, size=64) if rotate else np.zeros(64)
        post_radius = reference.uniform(*params.post_radius, size=64)
        for got, want in zip(
            (cand.kind, cand.center, cand.size, cand.arm, cand.angle, cand.post_radius),
            (kind, center, size, arm, angle, post_radius),
            strict=True,
        ):
            assert np.array_equal(got, want)
    assert fast.random() == reference.random()


@pytest.mark.parametrize(("n_obstacles", "n_rooms"), [(0, 1), (10, 2), (30, 4), (100, 4)])
def test_obstacle_count_and_rooms(n_obstacles, n_rooms):
    world = generate_random_world(1, n_obstacles=n_obstacles, n_rooms=n_rooms)
    assert len(_clutter(world)) == n_obstacles
    walls = [o for o in world.obstacles if isinstance(o, WallObstacle)]
    # The outer wall, then each of the n_rooms - 1 partitions in at most two pieces.
    assert n_rooms <= len(walls) <= 1 + 2 * (n_rooms - 1)
    assert walls[0].points[0] == walls[0].points[-1] == (0.0, 0.0)
    # Walls come first, then clutter (obstacle ids are stable by kind).
    assert all(isinstance(o, WallObstacle) for o in world.obstacles[: len(walls)])


@pytest.mark.parametrize("seed", SEEDS)
def test_start_waypoints_and_route_segments_keep_the_clearance(seed):
    params = RandomWorldParams()
    world = generate_random_world(seed, n_obstacles=60)
    need = params.robot_radius + params.min_clearance
    assert world.robot.radius == params.robot_radius
    assert world.robot.start[:2] == world.route.waypoints[0]
    points = np.asarray([world.robot.start[:2], *world.route.waypoints])
    assert np.all(shapes.clearance(world.obstacles, points) >= need - 1e-9)
    a, b = (np.array(end) for end in zip(*_segments(world), strict=True))
    worst = min(shapes.segments_clearance(o, a, b).min() for o in world.obstacles)
    assert worst >= need - 1e-9
    # Everything lies inside the outer walls.
    assert np.all((points > 0) & (points < [params.width, params.height]))


@pytest.mark.parametrize("seed", SEEDS)
def test_clutter_keeps_min_gap_and_world_passes_the_file_validation(seed):
    params = RandomWorldParams()
    world = generate_random_world(seed, n_obstacles=40)
    clutter = _clutter(world)
    boxes = np.array([shapes.obstacle_bounds(o) for o in world.obstacles])
    checked = 0
    for first in clutter:
        lo, hi = np.array(shapes.obstacle_bounds(first)).reshape(2, 2)
        near = np.all(
            (boxes[:, :2] < hi + params.min_gap) & (boxes[:, 2:] > lo - params.min_gap), 1
        )
        for k in np.flatnonzero(near):  # bounding boxes further apart than min_gap pass anyway
            second = world.obstacles[k]
            if second is not first:
                assert shapes.obstacle_distance(first, second) >= params.min_gap - 1e-9
                checked += 1
    assert checked >= len(clutter)  # the outer wall's box holds every object
    polygons = [o for o in clutter if isinstance(o, PolygonObstacle)]
    assert all(shapes.is_simple_polygon(o.points) for o in polygons)
    back = parse_world(tomllib.loads(world_to_toml(world)), "random.toml")
    assert back == world


def _partitions(world):
    """Full partition lines (doorways closed): pieces grouped by axis and fixed coordinate."""
    groups = {}
    for wall in world.obstacles[1:]:
        if not isinstance(wall, WallObstacle):
            break
        (x0, y0), (x1, y1) = wall.points
        key = ("h", y0) if y0 == y1 else ("v", x0)
        groups.setdefault(key, []).extend([(x0, y0), (x1, y1)])
    return [(min(pts), max(pts)) for pts in groups.values()]


@pytest.mark.parametrize("seed", SEEDS)
def test_route_visits_every_room(seed):
    n_rooms = 5
    world = generate_random_world(seed, n_rooms=n_rooms, n_obstacles=0)
    lines = _partitions(world)
    assert len(lines) == n_rooms - 1
    a = np.array([line[0] for line in lines])
    b = np.array([line[1] for line in lines])
    # Rooms are convex, so two waypoints share a room iff no partition separates them.
    rooms = []
    for wp in world.route.waypoints:
        for members in rooms:
            if not np.any(shapes.segments_intersect(wp, members[0], a, b)):
                members.append(wp)
                break
        else:
            rooms.append([wp])
    assert len(rooms) == n_rooms


@pytest.mark.parametrize(
    ("params", "field"),
    [
        ({"width": -1.0}, "width"),
        ({"height": float("nan")}, "height"),
        ({"n_rooms": 0}, "n_rooms"),
        ({"n_rooms": 2.5}, "n_rooms"),
        ({"n_obstacles": -1}, "n_obstacles"),
        ({"clutter_size": (1.0, 0.5)}, "clutter_size"),
        ({"clutter_size": "big"}, "clutter_size"),
        ({"post_radius": (0.0, 0.1)}, "post_radius"),
        ({"kind_weights": (0, 0, 0, 0)}, "kind_weights"),
        ({"kind_weights": (1, 1, 1)}, "kind_weights"),
        ({"l_arm_fraction": (0.5, 1.0)}, "l_arm_fraction"),
        ({"rotate_clutter": 1}, "rotate_clutter"),
        ({"min_gap": 0.3}, "min_gap"),
        ({"door_width": 0.9}, "door_width"),
        ({"waypoint_wall_distance": 0.5}, "waypoint_wall_distance"),
        ({"min_room_size": 2.0}, "min_room_size"),
        ({"width": 3.0}, "width"),
    ],
)
def test_bad_params_raise_naming_the_field(params, field):
    with pytest.raises(ValueError, match=rf"RandomWorldParams\.{field}: "):
        generate_random_world(0, **params)


def test_unknown_param_raises_with_suggestion():
    with pytest.raises(UnknownKeyError, match="did you mean 'n_obstacles'"):
        generate_random_world(0, n_obstacle=5)


def test_infeasible_requests_raise_clearly():
    with pytest.raises(RandomWorldError, match="rooms"):
        generate_random_world(0, n_rooms=40)
    with pytest.raises(RandomWorldError, match="clutter objects"):
        generate_random_world(0, width=8.0, height=8.0, n_rooms=1, n_obstacles=200, max_attempts=5)
