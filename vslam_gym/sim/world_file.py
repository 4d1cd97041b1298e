"""World files: load and validate the TOML worlds of ``envs/`` into :class:`World`.

The schema is the README section "World files" (``/work/shared/WORLD_FORMAT.md``). A
shipped world is read by name from the package data of ``vslam_gym.worlds`` (the
top-level ``envs/`` folder); any other world is read from a path to a ``.toml`` file.

Every problem raises :class:`WorldFormatError` whose message starts with the file name
and the field, e.g. ``house.toml: obstacle[3].points: polygon is self-intersecting``.
Unknown keys are errors with a "did you mean" suggestion, never warnings.
"""

from __future__ import annotations

import difflib
import json
import math
import os
import sys
from collections.abc import Mapping, Sequence
from importlib import resources
from pathlib import Path
from typing import Any, NoReturn

import numpy as np

from vslam_gym.config_utils import UnknownKeyError, check_keys
from vslam_gym.sim import shapes
from vslam_gym.sim.lidar import resolution_problem
from vslam_gym.sim.world import (
    CircleObstacle,
    LidarSpec,
    Obstacle,
    OdometrySpec,
    PolygonObstacle,
    RobotSpec,
    Route,
    WallObstacle,
    World,
)

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - Python 3.10 only
    import tomli as tomllib

__all__ = [
    "WORLDS_PACKAGE",
    "UnknownWorldError",
    "WorldFormatError",
    "list_worlds",
    "load_world",
    "parse_world",
    "route_length",
    "world_to_toml",
]

WORLDS_PACKAGE = "vslam_gym.worlds"
"""Package whose data files are the shipped worlds (``envs/`` in the source tree)."""

WORLD_SUFFIX = ".toml"

_TOP_KEYS = ("name", "description", "robot", "lidar", "odometry", "obstacle", "route")
_ROBOT_KEYS = ("start", "radius", "max_speed", "max_turn_rate")
_LIDAR_KEYS = ("fov_deg", "resolution_deg", "max_range", "sigma_range", "sigma_bearing_deg")
_ODOMETRY_KEYS = ("alphas",)
_ROUTE_KEYS = ("waypoints", "loop")
_OBSTACLE_KEYS = {
    "polygon": ("kind", "points"),
    "circle": ("kind", "center", "radius"),
    "wall": ("kind", "points", "thickness"),
}
_MIN_POINTS = {"polygon": 3, "wall": 2}
_FULL_CIRCLE_DEG = 360.0
_N_ALPHAS = 4


class WorldFormatError(ValueError):
    """A world file is malformed or invalid; the message names the file and the field.

    Attributes:
        file: file name (or world name) the problem is in.
        field: dotted field path such as ``obstacle[3].points``; empty for the whole file.
        message: what is wrong.
    """

    def __init__(self, file: str, field: str, message: str) -> None:
        super().__init__(file, field, message)  # args kept for pickling across processes

    @property
    def file(self) -> str:
        """File (or world) name."""
        return self.args[0]

    @property
    def field(self) -> str:
        """Dotted field path, empty for the whole file."""
        return self.args[1]

    @property
    def message(self) -> str:
        """What is wrong."""
        return self.args[2]

    def __str__(self) -> str:
        if self.field:
            return f"{self.file}: {self.field}: {self.message}"
        return f"{self.file}: {self.message}"


class UnknownWorldError(WorldFormatError):
    """A world name that is not one of the shipped worlds (see :func:`list_worlds`)."""


def _type_name(value: object) -> str:
    return type(value).__name__


class _Parser:
    """Typed field readers that raise :class:`WorldFormatError` naming file and field."""

    def __init__(self, file: str) -> None:
        self.file = file

    def fail(self, field: str, message: str) -> NoReturn:
        raise WorldFormatError(self.file, field, message)

    def keys(self, table: Mapping[str, Any], allowed: Sequence[str], field: str) -> None:
        """Fail on the first key of ``table`` not in ``allowed``, suggesting the closest."""
        self.choice(list(table), allowed, field, key_field=True)

    def choice(
        self, values: Sequence[str], allowed: Sequence[str], field: str, key_field: bool = False
    ) -> None:
        """Fail on the first of ``values`` not in ``allowed`` ("did you mean ...?")."""
        where = f"{self.file}: {field}" if field else self.file
        try:
            check_keys(values, allowed, where)
        except UnknownKeyError as err:
            message = str(err)[len(where) + 2 :]
            if not key_field:
                message = message.replace("unknown key", "unknown value", 1)
                raise WorldFormatError(self.file, field, message) from err
            bad = next(str(v) for v in values if v not in allowed)
            raise WorldFormatError(self.file, f"{field}.{bad}" if field else bad, message) from err

    def table(self, value: object, field: str) -> Mapping[str, Any]:
        if not isinstance(value, Mapping):
            self.fail(field, f"must be a table ([{field}]), got {_type_name(value)}")
        return value

    def required(self, table: Mapping[str, Any], key: str, field: str) -> Any:
        if key not in table:
            self.fail(field, "required key is missing")
        return table[key]

    def string(self, value: object, field: str) -> str:
        if not isinstance(value, str):
            self.fail(field, f"must be a string, got {_type_name(value)} {value!r}")
        return value

    def boolean(self, value: object, field: str) -> bool:
        if not isinstance(value, bool):
            self.fail(field, f"must be true or false, got {_type_name(value)} {value!r}")
        return value

    def number(
        self, value: object, field: str, *, positive: bool = False, nonnegative: bool = False
    ) -> float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            self.fail(field, f"must be a number, got {_type_name(value)} {value!r}")
        x = float(value)
        if not math.isfinite(x):
            self.fail(field, f"must be finite, got {value!r}")
        if positive and not x > 0.0:
            self.fail(field, f"must be > 0, got {value!r}")
        if nonnegative and not x >= 0.0:
            self.fail(field, f"must be >= 0, got {value!r}")
        return x

    def numbers(self, value: object, field: str, count: int, what: str) -> tuple[float, ...]:
        if not isinstance(value, (list, tuple)) or len(value) != count:
            self.fail(field, f"must be {what} (an array of {count} numbers), got {value!r}")
        return tuple(self.number(v, f"{field}[{i}]") for i, v in enumerate(value))

    def point(self, value: object, field: str) -> tuple[float, float]:
        x, y = self.numbers(value, field, 2, "[x, y]")
        return (x, y)

    def points(self, value: object, field: str, min_count: int) -> tuple[tuple[float, float], ...]:
        if not isinstance(value, (list, tuple)):
            self.fail(field, f"must be an array of [x, y] points, got {_type_name(value)}")
        if len(value) < min_count:
            noun = "point" if min_count == 1 else "points"
            self.fail(field, f"needs at least {min_count} {noun}, got {len(value)}")
        pts = tuple(self.point(v, f"{field}[{i}]") for i, v in enumerate(value))
        for i in range(1, len(pts)):
            if pts[i] == pts[i - 1]:
                self.fail(f"{field}[{i}]", f"repeats the previous point {list(pts[i])}")
        return pts


def _parse_robot(p: _Parser, raw: object) -> RobotSpec:
    table = p.table(raw, "robot")
    p.keys(table, _ROBOT_KEYS, "robot")
    x, y, theta = p.numbers(
        p.required(table, "start", "robot.start"), "robot.start", 3, "[x, y, theta]"
    )
    kwargs: dict[str, float] = {}
    for key in ("radius", "max_speed", "max_turn_rate"):
        if key in table:
            kwargs[key] = p.number(table[key], f"robot.{key}", positive=True)
    return RobotSpec(start=(x, y, theta), **kwargs)


def _parse_lidar(p: _Parser, raw: object) -> LidarSpec:
    table = p.table(raw, "lidar")
    p.keys(table, _LIDAR_KEYS, "lidar")
    values: dict[str, float] = {}
    for key in ("fov_deg", "resolution_deg", "max_range"):
        if key in table:
            values[key] = p.number(table[key], f"lidar.{key}", positive=True)
    for key in ("sigma_range", "sigma_bearing_deg"):
        if key in table:
            values[key] = p.number(table[key], f"lidar.{key}", nonnegative=True)
    spec = LidarSpec(**values)
    if spec.fov_deg > _FULL_CIRCLE_DEG:
        p.fail("lidar.fov_deg", f"must be <= {_FULL_CIRCLE_DEG:g}, got {spec.fov_deg!r}")
    problem = resolution_problem(spec.fov_deg, spec.resolution_deg)
    if problem is not None:
        p.fail("lidar.resolution_deg", problem)
    return spec


def _parse_odometry(p: _Parser, raw: object) -> OdometrySpec:
    table = p.table(raw, "odometry")
    p.keys(table, _ODOMETRY_KEYS, "odometry")
    if "alphas" not in table:
        return OdometrySpec()
    raw_alphas = table["alphas"]
    p.numbers(raw_alphas, "odometry.alphas", _N_ALPHAS, "[a1, a2, a3, a4]")
    a1, a2, a3, a4 = (
        p.number(v, f"odometry.alphas[{i}]", nonnegative=True) for i, v in enumerate(raw_alphas)
    )
    return OdometrySpec(alphas=(a1, a2, a3, a4))


def _parse_obstacle(p: _Parser, raw: object, field: str) -> Obstacle:
    table = p.table(raw, field)
    kind = p.string(p.required(table, "kind", f"{field}.kind"), f"{field}.kind")
    p.choice([kind], tuple(_OBSTACLE_KEYS), f"{field}.kind")
    p.keys(table, _OBSTACLE_KEYS[kind], field)
    if kind == "circle":
        center = p.point(p.required(table, "center", f"{field}.center"), f"{field}.center")
        radius = p.number(
            p.required(table, "radius", f"{field}.radius"), f"{field}.radius", positive=True
        )
        return CircleObstacle(center=center, radius=radius)
    pts = p.points(
        p.required(table, "points", f"{field}.points"), f"{field}.points", _MIN_POINTS[kind]
    )
    if kind == "wall":
        if "thickness" in table:
            thickness = p.number(table["thickness"], f"{field}.thickness", positive=True)
            return WallObstacle(points=pts, thickness=thickness)
        return WallObstacle(points=pts)
    if pts[0] == pts[-1]:
        p.fail(
            f"{field}.points",
            "polygon repeats its first point at the end; polygons "
            "close themselves, drop the last point",
        )
    crossing = shapes.polygon_self_intersection(pts)
    if crossing is not None:
        i, j = crossing
        p.fail(f"{field}.points", f"polygon is self-intersecting (edges {i} and {j})")
    if shapes.polygon_area(pts) == 0.0:
        p.fail(f"{field}.points", "polygon has zero area")
    return PolygonObstacle(points=pts)


def _parse_route(p: _Parser, raw: object) -> Route:
    table = p.table(raw, "route")
    p.keys(table, _ROUTE_KEYS, "route")
    waypoints = p.points(p.required(table, "waypoints", "route.waypoints"), "route.waypoints", 1)
    loop = p.boolean(table.get("loop", False), "route.loop")
    return Route(waypoints=waypoints, loop=loop)


def _check_free(
    p: _Parser,
    fields: Sequence[str],
    points: Sequence[tuple[float, float]],
    radius: float,
    obstacles: Sequence[Obstacle],
) -> None:
    """Fail (naming the first offending field) if a robot disc at a point overlaps an obstacle."""
    if not obstacles or not points:
        return
    d = np.array([shapes.signed_distance(o, points) for o in obstacles])  # (obstacle, point)
    bad = d < radius
    if not np.any(bad):
        return
    i = int(np.flatnonzero(bad.any(axis=0))[0])
    k = int(np.flatnonzero(bad[:, i])[0])
    xy, dist, kind = points[i], float(d[k, i]), obstacles[k].kind
    where = f"({xy[0]:g}, {xy[1]:g})"
    if dist < 0.0:
        p.fail(fields[i], f"{where} is inside obstacle[{k}] ({kind})")
    p.fail(
        fields[i],
        f"robot disc (radius {radius:g} m) at {where} overlaps obstacle[{k}] ({kind}): "
        f"{dist:.3g} m away, closer than the robot radius",
    )


def parse_world(data: Mapping[str, Any], file: str) -> World:
    """Validate a parsed TOML document and build the :class:`World`.

    Args:
        data: the document as :func:`tomllib.loads` returns it.
        file: file name used in error messages; ``name`` must equal its stem.

    Raises:
        WorldFormatError: on any schema or geometry problem (see the module docstring).
    """
    p = _Parser(file)
    p.table(data, "")
    p.keys(data, _TOP_KEYS, "")
    name = p.string(p.required(data, "name", "name"), "name")
    stem = Path(file).stem
    if name != stem:
        p.fail("name", f"must match the file stem {stem!r}, got {name!r}")
    description = p.string(data.get("description", ""), "description")
    robot = _parse_robot(p, p.required(data, "robot", "robot"))
    lidar = _parse_lidar(p, data["lidar"]) if "lidar" in data else LidarSpec()
    odometry = _parse_odometry(p, data["odometry"]) if "odometry" in data else OdometrySpec()
    raw_obstacles = data.get("obstacle", [])
    if not isinstance(raw_obstacles, (list, tuple)):
        p.fail(
            "obstacle",
            f"must be an array of tables ([[obstacle]]), got {_type_name(raw_obstacles)}",
        )
    obstacles = tuple(
        _parse_obstacle(p, raw, f"obstacle[{k}]") for k, raw in enumerate(raw_obstacles)
    )
    route = _parse_route(p, data["route"]) if "route" in data else None

    fields = ["robot.start"]
    points = [robot.start[:2]]
    if route is not None:
        fields += [f"route.waypoints[{i}]" for i in range(len(route.waypoints))]
        points += list(route.waypoints)
    _check_free(p, fields, points, robot.radius, obstacles)
    return World(
        name=name,
        robot=robot,
        lidar=lidar,
        odometry=odometry,
        obstacles=obstacles,
        route=route,
        description=description,
    )


def _parse_text(text: str, file: str) -> World:
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as err:
        raise WorldFormatError(file, "", f"invalid TOML: {err}") from err
    return parse_world(data, file)


def list_worlds() -> list[str]:
    """Names of the shipped worlds (the ``.toml`` files of ``envs/``), sorted."""
    root = resources.files(WORLDS_PACKAGE)
    return sorted(
        entry.name[: -len(WORLD_SUFFIX)]
        for entry in root.iterdir()
        if entry.name.endswith(WORLD_SUFFIX) and entry.is_file()
    )


def _is_path(name_or_path: str | os.PathLike[str]) -> bool:
    if isinstance(name_or_path, os.PathLike):
        return True
    seps = {"/", os.sep} | ({os.altsep} if os.altsep else set())
    return name_or_path.endswith(WORLD_SUFFIX) or any(s in name_or_path for s in seps)


def load_world(name_or_path: str | os.PathLike[str]) -> World:
    """Load and validate a world.

    Args:
        name_or_path: a shipped world name such as ``"house"`` (see :func:`list_worlds`),
            or a path to a ``.toml`` file (a :class:`os.PathLike`, or a string that ends
            in ``.toml`` or contains a path separator).

    Returns:
        The validated world.

    Raises:
        UnknownWorldError: ``name_or_path`` is neither a path nor a shipped world name.
        FileNotFoundError: the path does not exist.
        WorldFormatError: the file is malformed or invalid.
    """
    if not isinstance(name_or_path, (str, os.PathLike)):
        raise TypeError(f"expected a world name or path, got {_type_name(name_or_path)}")
    if _is_path(name_or_path):
        path = Path(name_or_path)
        return _parse_text(path.read_text(encoding="utf-8"), path.name)
    name = str(name_or_path)
    shipped = list_worlds()
    if name not in shipped:
        close = difflib.get_close_matches(name, shipped, n=1)
        hint = f"did you mean {close[0]!r}? " if close else ""
        raise UnknownWorldError(
            name,
            "",
            f"unknown world; {hint}shipped worlds are {', '.join(shipped)} "
            f"(or pass a path to a {WORLD_SUFFIX} file)",
        )
    file = name + WORLD_SUFFIX
    text = resources.files(WORLDS_PACKAGE).joinpath(file).read_text(encoding="utf-8")
    return _parse_text(text, file)


def _toml_string(text: str) -> str:
    # JSON string escapes are valid TOML basic-string escapes; TOML also forbids raw DEL.
    return json.dumps(text, ensure_ascii=False).replace("\x7f", "\\u007f")


def _toml_float(x: float) -> str:
    return repr(float(x))  # shortest repr round-trips exactly


def _toml_array(values: Sequence[float]) -> str:
    return "[" + ", ".join(_toml_float(v) for v in values) + "]"


def _toml_points(points: Sequence[Sequence[float]]) -> str:
    return "[" + ", ".join(_toml_array(pt) for pt in points) + "]"


def world_to_toml(world: World) -> str:
    """Serialise a world to world-file TOML; ``load_world`` of the result gives it back.

    Save it as ``<world.name>.toml`` (the loader checks that name and stem agree).
    """
    r, lid, odo = world.robot, world.lidar, world.odometry
    lines = [f"name = {_toml_string(world.name)}"]
    if world.description:
        lines.append(f"description = {_toml_string(world.description)}")
    lines += [
        "",
        "[robot]",
        f"start = {_toml_array(r.start)}",
        f"radius = {_toml_float(r.radius)}",
        f"max_speed = {_toml_float(r.max_speed)}",
        f"max_turn_rate = {_toml_float(r.max_turn_rate)}",
        "",
        "[lidar]",
    ]
    lines += [f"{key} = {_toml_float(getattr(lid, key))}" for key in _LIDAR_KEYS]
    lines += ["", "[odometry]", f"alphas = {_toml_array(odo.alphas)}"]
    for obstacle in world.obstacles:
        lines += ["", "[[obstacle]]", f"kind = {_toml_string(obstacle.kind)}"]
        if isinstance(obstacle, CircleObstacle):
            lines += [
                f"center = {_toml_array(obstacle.center)}",
                f"radius = {_toml_float(obstacle.radius)}",
            ]
        else:
            lines.append(f"points = {_toml_points(obstacle.points)}")
            if isinstance(obstacle, WallObstacle):
                lines.append(f"thickness = {_toml_float(obstacle.thickness)}")
    if world.route is not None:
        lines += [
            "",
            "[route]",
            f"waypoints = {_toml_points(world.route.waypoints)}",
            f"loop = {'true' if world.route.loop else 'false'}",
        ]
    return "\n".join(lines) + "\n"


def route_length(world: World) -> float:
    """Length [m] of the world's route from its first waypoint (closing it if it loops).

    Zero when the world has no route.
    """
    if world.route is None:
        return 0.0
    pts = np.asarray(world.route.waypoints, dtype=float)
    if world.route.loop:
        pts = np.vstack([pts, pts[:1]])
    return float(np.sum(np.linalg.norm(np.diff(pts, axis=0), axis=1)))
