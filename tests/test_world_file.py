"""World files: shipped worlds load and are drivable; every validation error names file+field."""

from __future__ import annotations

import copy
import math
import pickle
from importlib import resources
from pathlib import Path

import numpy as np
import pytest

from vslam_gym.sim import shapes
from vslam_gym.sim.world import (
    CircleObstacle,
    LidarSpec,
    OdometrySpec,
    PolygonObstacle,
    WallObstacle,
)
from vslam_gym.sim.world_file import (
    UnknownWorldError,
    WorldFormatError,
    list_worlds,
    load_world,
    parse_world,
    route_length,
    world_to_toml,
)

SHIPPED = ("curved", "house", "single_landmark", "small")
ROUTE_MARGIN = 0.3  # required free space [m] beyond the robot radius along every route segment


def _route_segments(world):
    pts = [world.robot.start[:2], *world.route.waypoints]
    if world.route.loop:
        pts.append(world.route.waypoints[0])
    return list(zip(pts[:-1], pts[1:], strict=True))


def test_list_worlds_names_the_shipped_files():
    assert list_worlds() == sorted(SHIPPED)


@pytest.mark.parametrize("name", SHIPPED)
def test_shipped_world_loads_with_thesis_sensor_and_a_looping_route(name):
    world = load_world(name)
    assert world.name == name
    assert len(world.description) > 40
    assert world.lidar == LidarSpec()
    assert (world.lidar.fov_deg, world.lidar.resolution_deg, world.lidar.max_range) == (
        180.0,
        1.0,
        30.0,
    )
    assert world.odometry == OdometrySpec()
    assert world.route is not None and world.route.loop
    assert len(world.route.waypoints) >= 4
    assert world.robot.start[:2] == world.route.waypoints[0]


@pytest.mark.parametrize("name", SHIPPED)
def test_every_route_segment_keeps_robot_radius_plus_margin_from_every_obstacle(name):
    world = load_world(name)
    need = world.robot.radius + ROUTE_MARGIN
    a, b = (np.array(end) for end in zip(*_route_segments(world), strict=True))
    worst = min(shapes.segments_clearance(obstacle, a, b).min() for obstacle in world.obstacles)
    assert worst >= need - 1e-9, f"{name}: route clearance {worst:.3f} m < {need:.3f} m"


@pytest.mark.parametrize("name", SHIPPED)
def test_path_and_name_give_the_same_world_and_toml_round_trips(name, tmp_path):
    by_name = load_world(name)
    with resources.as_file(resources.files("vslam_gym.worlds") / f"{name}.toml") as path:
        assert load_world(path) == by_name
        assert load_world(str(path)) == by_name
    copy_path = tmp_path / f"{name}.toml"
    copy_path.write_text(world_to_toml(by_name), encoding="utf-8")
    assert load_world(copy_path) == by_name


@pytest.mark.parametrize("name", SHIPPED)
def test_shipped_polygons_have_no_collinear_corners(name):
    # A straight-through vertex is invisible to the lidar and would make a false landmark
    # vertex in the ground truth.
    for k, obstacle in enumerate(load_world(name).obstacles):
        if isinstance(obstacle, PolygonObstacle):
            pts = np.asarray(obstacle.points)
            e = np.roll(pts, -1, axis=0) - pts
            n = np.roll(e, -1, axis=0)
            sin = (e[:, 0] * n[:, 1] - e[:, 1] * n[:, 0]) / (
                np.linalg.norm(e, axis=1) * np.linalg.norm(n, axis=1)
            )
            assert np.abs(sin).min() > 1e-3, f"{name}: obstacle[{k}]"


def test_single_landmark_is_one_non_convex_object_circled_at_three_to_four_metres():
    world = load_world("single_landmark")
    (star,) = world.obstacles
    assert isinstance(star, PolygonObstacle)
    pts = np.asarray(star.points)
    edges = np.roll(pts, -1, axis=0) - pts
    nxt = np.roll(edges, -1, axis=0)
    turns = edges[:, 0] * nxt[:, 1] - edges[:, 1] * nxt[:, 0]
    assert np.any(turns > 0) and np.any(turns < 0)  # reflex corners: non-convex
    extent = np.ptp(pts, axis=0)
    assert 2.0 <= extent.max() <= 3.0
    centre = pts.mean(axis=0)
    wps = np.asarray(world.route.waypoints)
    dist = np.linalg.norm(wps - centre, axis=1)
    assert np.all((dist >= 3.0) & (dist <= 4.0))
    angles = np.unwrap(np.arctan2(wps[:, 1] - centre[1], wps[:, 0] - centre[0]))
    closing = math.remainder(angles[0] - angles[-1], 2 * math.pi)
    assert abs(angles[-1] - angles[0] + closing) == pytest.approx(2 * math.pi)  # one full turn


def test_small_world_has_four_distinct_polygons_passed_in_turn():
    world = load_world("small")
    assert len(world.obstacles) == 4
    assert all(isinstance(o, PolygonObstacle) for o in world.obstacles)
    signatures = {
        (len(o.points), round(abs(shapes.polygon_area(o.points)), 3)) for o in world.obstacles
    }
    assert len(signatures) == 4
    # The route passes each object in turn: the waypoint nearest to each object differs.
    wps = np.asarray(world.route.waypoints)
    nearest = [int(np.argmin(shapes.signed_distance(o, wps))) for o in world.obstacles]
    assert len(set(nearest)) == 4


def test_curved_world_has_circles_and_many_vertex_polygons():
    world = load_world("curved")
    circles = [o for o in world.obstacles if isinstance(o, CircleObstacle)]
    curvy = [o for o in world.obstacles if isinstance(o, PolygonObstacle) and len(o.points) >= 16]
    assert len(circles) >= 2 and len(curvy) >= 5
    assert route_length(world) > route_length(load_world("small"))


def test_house_has_walls_right_angled_furniture_and_a_forty_to_fifty_metre_loop():
    world = load_world("house")
    walls = [o for o in world.obstacles if isinstance(o, WallObstacle)]
    furniture = [o for o in world.obstacles if isinstance(o, PolygonObstacle)]
    assert len(walls) >= 10 and len(furniture) >= 20
    for obstacle in furniture:
        pts = np.asarray(obstacle.points)
        edges = np.roll(pts, -1, axis=0) - pts
        cos = np.einsum("ij,ij->i", edges, np.roll(edges, -1, axis=0))
        assert np.allclose(cos, 0.0, atol=1e-9), obstacle
    small = [o for o in furniture if np.ptp(np.asarray(o.points), axis=0).max() <= 0.35]
    assert len(small) >= 3
    xs = np.asarray([p for w in walls for p in w.points])
    assert np.ptp(xs[:, 0]) == pytest.approx(20.0) and np.ptp(xs[:, 1]) == pytest.approx(15.0)
    assert 40.0 <= route_length(world) <= 50.0


def test_route_length_closes_loops():
    world = load_world("single_landmark")
    wps = np.asarray(world.route.waypoints)
    open_length = np.sum(np.linalg.norm(np.diff(wps, axis=0), axis=1))
    assert route_length(world) == pytest.approx(open_length + np.linalg.norm(wps[-1] - wps[0]))


# ---------------------------------------------------------------- validation errors

BASE = {
    "name": "x",
    "description": "test world",
    "robot": {"start": [0.0, 0.0, 0.0], "radius": 0.2, "max_speed": 1.0, "max_turn_rate": 1.5},
    "lidar": {"fov_deg": 180.0, "resolution_deg": 1.0, "max_range": 30.0},
    "odometry": {"alphas": [0.01, 0.005, 0.005, 0.001]},
    "obstacle": [
        {"kind": "polygon", "points": [[2.0, 2.0], [3.0, 2.0], [3.0, 3.0], [2.0, 3.0]]},
        {"kind": "circle", "center": [-3.0, 0.0], "radius": 0.5},
        {"kind": "wall", "points": [[-5.0, -5.0], [5.0, -5.0]], "thickness": 0.1},
    ],
    "route": {"waypoints": [[1.0, 0.0], [1.0, 1.0]], "loop": True},
}


def _with(path: str, value):
    """BASE with the value at a dotted path (``obstacle.0.points``) replaced or deleted."""
    data = copy.deepcopy(BASE)
    *parents, last = path.split(".")
    node = data
    for key in parents:
        node = node[int(key)] if isinstance(node, list) else node[key]
    if isinstance(node, list):
        node[int(last)] = value
    elif value is _DELETE:
        del node[last]
    else:
        node[last] = value
    return data


_DELETE = object()
NAN = float("nan")

CASES = [
    # (path, value, field named in the message, part of the message)
    ("name", _DELETE, "name", "required key is missing"),
    ("name", "y", "name", "must match the file stem 'x'"),
    ("name", 3, "name", "must be a string"),
    ("description", 3, "description", "must be a string"),
    ("robot", _DELETE, "robot", "required key is missing"),
    ("robot", [1, 2], "robot", "must be a table"),
    ("robot.start", _DELETE, "robot.start", "required key is missing"),
    ("robot.start", [0.0, 0.0], "robot.start", "[x, y, theta]"),
    ("robot.start", [0.0, "a", 0.0], "robot.start[1]", "must be a number"),
    ("robot.start", [0.0, math.inf, 0.0], "robot.start[1]", "must be finite"),
    ("robot.radius", -1, "robot.radius", "must be > 0, got -1"),
    ("robot.radius", 0.0, "robot.radius", "must be > 0"),
    ("robot.radius", NAN, "robot.radius", "must be finite"),
    ("robot.radius", True, "robot.radius", "must be a number"),
    ("robot.max_speed", -1.0, "robot.max_speed", "must be > 0"),
    ("robot.max_turn_rate", "fast", "robot.max_turn_rate", "must be a number"),
    ("lidar.max_range", -30.0, "lidar.max_range", "must be > 0"),
    ("lidar.fov_deg", 400.0, "lidar.fov_deg", "must be <= 360"),
    ("lidar.resolution_deg", 0.7, "lidar.resolution_deg", "whole number of steps"),
    ("lidar.sigma_range", -0.03, "lidar.sigma_range", "must be >= 0"),
    ("lidar.sigma_bearing_deg", NAN, "lidar.sigma_bearing_deg", "must be finite"),
    ("odometry.alphas", [0.1, 0.1, 0.1], "odometry.alphas", "[a1, a2, a3, a4]"),
    ("odometry.alphas", [0.1, 0.1, -0.1, 0.1], "odometry.alphas[2]", "must be >= 0"),
    ("obstacle", {"kind": "circle"}, "obstacle", "array of tables"),
    ("obstacle.0", "box", "obstacle[0]", "must be a table"),
    ("obstacle.0.kind", _DELETE, "obstacle[0].kind", "required key is missing"),
    ("obstacle.0.kind", "polgon", "obstacle[0].kind", "did you mean 'polygon'"),
    ("obstacle.0.points", [[2.0, 2.0], [3.0, 2.0]], "obstacle[0].points", "at least 3 points"),
    ("obstacle.0.points", [[2.0, 2.0], [3.0, 3.0], [3.0, 2.0], [2.0, 3.0]],
     "obstacle[0].points", "polygon is self-intersecting"),
    ("obstacle.0.points", [[2.0, 2.0], [3.0, 2.0], [4.0, 2.0]],
     "obstacle[0].points", "polygon is self-intersecting"),
    ("obstacle.0.points", [[2.0, 2.0], [3.0, 2.0], [3.0, 3.0], [2.0, 2.0]],
     "obstacle[0].points", "repeats its first point"),
    ("obstacle.0.points", [[2.0, 2.0], [3.0, 2.0], [3.0, 2.0], [2.0, 3.0]],
     "obstacle[0].points[2]", "repeats the previous point"),
    ("obstacle.0.points", [[2.0, 2.0], [3.0, NAN], [2.0, 3.0]],
     "obstacle[0].points[1][1]", "must be finite"),
    ("obstacle.0.points", [[2.0, 2.0], [3.0], [2.0, 3.0]], "obstacle[0].points[1]", "[x, y]"),
    ("obstacle.0.points", "square", "obstacle[0].points", "array of [x, y] points"),
    ("obstacle.1.radius", -0.5, "obstacle[1].radius", "must be > 0"),
    ("obstacle.1.radius", _DELETE, "obstacle[1].radius", "required key is missing"),
    ("obstacle.1.center", _DELETE, "obstacle[1].center", "required key is missing"),
    ("obstacle.2.thickness", 0.0, "obstacle[2].thickness", "must be > 0"),
    ("obstacle.2.points", [[-5.0, -5.0]], "obstacle[2].points", "at least 2 points"),
    ("route.waypoints", [], "route.waypoints", "at least 1 point,"),
    ("route.waypoints", _DELETE, "route.waypoints", "required key is missing"),
    ("route.loop", "yes", "route.loop", "must be true or false"),
    # geometry: the robot start and the waypoints must be free for the robot disc
    ("robot.start", [2.5, 2.5, 0.0], "robot.start", "is inside obstacle[0] (polygon)"),
    ("robot.start", [1.9, 2.5, 0.0], "robot.start", "overlaps obstacle[0] (polygon)"),
    ("robot.start", [0.0, -4.8, 0.0], "robot.start", "overlaps obstacle[2] (wall)"),
    ("route.waypoints", [[1.0, 0.0], [-3.0, 0.2]], "route.waypoints[1]",
     "is inside obstacle[1] (circle)"),
    ("route.waypoints", [[1.0, 0.0], [-2.4, 0.0]], "route.waypoints[1]",
     "closer than the robot radius"),
]  # fmt: skip


@pytest.mark.parametrize(("path", "value", "field", "message"), CASES)
def test_each_validation_error_names_file_and_field(path, value, field, message):
    with pytest.raises(WorldFormatError) as info:
        parse_world(_with(path, value), "x.toml")
    err = info.value
    assert str(err).startswith(f"x.toml: {field}: "), str(err)
    assert message in str(err)
    assert (err.file, err.field) == ("x.toml", field)


def test_base_document_is_valid():
    world = parse_world(copy.deepcopy(BASE), "x.toml")
    assert [o.kind for o in world.obstacles] == ["polygon", "circle", "wall"]
    assert world.robot.start == (0.0, 0.0, 0.0)


def test_optional_sections_take_defaults():
    data = {"name": "x", "robot": {"start": [0, 0, 0]}}
    world = parse_world(data, "dir/x.toml")
    assert world.lidar == LidarSpec() and world.odometry == OdometrySpec()
    assert world.robot.radius == 0.2 and world.obstacles == () and world.route is None
    assert isinstance(world.robot.start[0], float)


@pytest.mark.parametrize(
    ("path", "key", "field", "suggestion"),
    [
        ("", "robto", "robto", "'robot'"),
        ("robot", "radious", "robot.radious", "'radius'"),
        ("lidar", "max_rang", "lidar.max_rang", "'max_range'"),
        ("odometry", "alpha", "odometry.alpha", "'alphas'"),
        ("route", "loops", "route.loops", "'loop'"),
        ("obstacle.1", "radiuss", "obstacle[1].radiuss", "'radius'"),
        ("obstacle.0", "thickness", "obstacle[0].thickness", None),  # valid for walls only
    ],
)
def test_unknown_keys_raise_with_a_suggestion(path, key, field, suggestion):
    data = copy.deepcopy(BASE)
    node = data
    for part in filter(None, path.split(".")):
        node = node[int(part)] if isinstance(node, list) else node[part]
    node[key] = 1.0
    with pytest.raises(WorldFormatError) as info:
        parse_world(data, "x.toml")
    assert str(info.value).startswith(f"x.toml: {field}: unknown key {key!r}")
    if suggestion:
        assert f"did you mean {suggestion}?" in str(info.value)
    assert isinstance(info.value, ValueError)


def _write(tmp_path: Path, name: str, text: str) -> Path:
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    return path


def test_file_errors_name_the_file(tmp_path):
    good = 'name = "w"\n[robot]\nstart = [0.0, 0.0, 0.0]\n'
    assert load_world(_write(tmp_path, "w.toml", good)).name == "w"
    with pytest.raises(WorldFormatError, match=r"^other\.toml: name: must match the file stem"):
        load_world(_write(tmp_path, "other.toml", good))
    with pytest.raises(WorldFormatError, match=r"^bad\.toml: invalid TOML"):
        load_world(_write(tmp_path, "bad.toml", 'name = "bad"\n[robot\n'))
    nan_text = 'name = "n"\n[robot]\nstart = [0.0, 0.0, 0.0]\nradius = nan\n'
    with pytest.raises(WorldFormatError, match=r"^n\.toml: robot\.radius: must be finite"):
        load_world(_write(tmp_path, "n.toml", nan_text))
    with pytest.raises(FileNotFoundError):
        load_world(tmp_path / "missing.toml")


def test_unknown_world_name_lists_the_shipped_worlds():
    with pytest.raises(UnknownWorldError) as info:
        load_world("hose")
    message = str(info.value)
    assert message.startswith("hose: unknown world")
    assert "did you mean 'house'?" in message
    for name in SHIPPED:
        assert name in message
    assert isinstance(info.value, WorldFormatError)


def test_world_format_error_pickles_with_its_message():
    err = WorldFormatError("x.toml", "robot.radius", "must be > 0, got -1")
    back = pickle.loads(pickle.dumps(err))
    assert str(back) == str(err) == "x.toml: robot.radius: must be > 0, got -1"
    assert back.field == "robot.radius"


def test_load_world_rejects_non_strings():
    with pytest.raises(TypeError):
        load_world(3)  # type: ignore[arg-type]


def test_installed_package_ships_the_world_files(tmp_path, monkeypatch):
    """The world files are package data of ``vslam_gym.worlds``: CI installs the wheel
    (non-editable), so this loads them from site-packages, from any working directory."""
    import importlib.resources

    monkeypatch.chdir(tmp_path)
    files = {p.name for p in importlib.resources.files("vslam_gym.worlds").iterdir()}
    assert {"house.toml", "small.toml", "curved.toml", "single_landmark.toml"} <= files
    assert len(load_world("house").obstacles) > 20
