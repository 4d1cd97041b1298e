"""Rigid-body simulation of a disc robot among static obstacles (pymunk).

The world frame is right-handed (x east, y north, theta counter-clockwise from x), units
metres, seconds and radians. pymunk uses the same frame and units here.

Static obstacles become pymunk shapes on the space's static body, each tagged with its
obstacle id (``shape.obstacle_id``, the index in ``World.obstacles``):

- a circle is a :class:`pymunk.Circle`;
- a wall (an open polyline with a thickness) is a chain of :class:`pymunk.Segment` with
  radius ``thickness / 2`` (capsules: rounded ends and joints);
- a polygon is one :class:`pymunk.Poly` when convex, otherwise the triangles of an
  ear-clipping triangulation (pymunk polygons must be convex). The union of the pieces
  is exactly the polygon.

The robot is a dynamic disc driven by differential-drive commands ``(v, omega)``: before
the contact solver runs in every substep, its velocity is set to ``v`` along its heading
and its angular velocity to ``omega`` (a pymunk velocity callback). The contact solver
then removes the velocity component that would push into an obstacle. All shapes are
frictionless and inelastic, so the robot stops when it drives straight into an obstacle
and slides along it otherwise, without spinning. A control period with contact at the
end of any of its substeps reports a collision, with the ids of the obstacles touched.

pymunk integrates positions before it calls the velocity callback, so a new command acts
one substep late (10 ms with the defaults): the first substep of a control period still
moves with the previous period's (contact-corrected) velocity, like a short actuator
delay. Setting the velocity directly before a step instead would bypass the contact
solver for that substep and push the robot into obstacles.

Tunnelling: a substep moves the robot by at most ``max_speed * dt``. As long as this is
less than the robot radius, the overlap with any obstacle (even one of zero thickness) is
detected before the centre can cross it, and the solver pushes the robot back out on the
side it came from. :class:`PhysicsConfig` raises the number of substeps automatically so
that a substep moves at most ``max_substep_travel`` robot radii.

A new space is built for every episode (cached contact impulses are hidden state).
"""

from __future__ import annotations

import math
import weakref
from dataclasses import dataclass

import numpy as np
import pymunk

from vslam_gym.sim import shapes
from vslam_gym.sim.world import (
    CircleObstacle,
    PolygonObstacle,
    RobotSpec,
    WallObstacle,
    World,
)

#: pymunk collision category of the static obstacles (lidar queries see only these).
OBSTACLE_CATEGORY = 0b01
#: pymunk collision category of the robot.
ROBOT_CATEGORY = 0b10
#: Query filter selecting obstacles only (for lidar ray queries against the space).
OBSTACLE_QUERY_FILTER = pymunk.ShapeFilter(mask=OBSTACLE_CATEGORY)


class PhysicsError(ValueError):
    """Invalid physics settings, commands or geometry."""


@dataclass(frozen=True)
class PhysicsConfig:
    """Settings of the rigid-body simulation.

    Attributes:
        control_period: duration [s] of one control step (one ``step(v, omega)`` call).
        substeps: minimum number of pymunk steps per control period.
        max_substep_travel: largest distance a substep may move the robot at full speed,
            as a fraction of the robot radius [-]; ``substeps`` is raised to respect it
            (must be < 1 to rule out tunnelling).
        collision_slop: overlap [m] the contact solver tolerates without correcting.
        overlap_kept_per_substep: fraction [-] of an overlap left after one substep of
            positional correction (pymunk's ``collision_bias`` is derived from it).
        solver_iterations: contact-solver iterations per pymunk step.
        robot_mass: mass [kg] of the robot disc (irrelevant against static obstacles,
            but pymunk needs one).
        geometry_tolerance: relative tolerance [-] for collinear and repeated polygon
            vertices when splitting polygons into convex pieces.
    """

    control_period: float = 0.1
    substeps: int = 10
    max_substep_travel: float = 0.25
    collision_slop: float = 1e-3
    overlap_kept_per_substep: float = 0.5
    solver_iterations: int = 10
    robot_mass: float = 1.0
    geometry_tolerance: float = 1e-12

    def __post_init__(self) -> None:
        if not (math.isfinite(self.control_period) and self.control_period > 0.0):
            raise PhysicsError(f"control_period must be > 0 s, got {self.control_period}")
        if int(self.substeps) != self.substeps or self.substeps < 1:
            raise PhysicsError(f"substeps must be an integer >= 1, got {self.substeps}")
        if not 0.0 < self.max_substep_travel < 1.0:
            raise PhysicsError(
                f"max_substep_travel must be in (0, 1) robot radii, got {self.max_substep_travel}"
            )
        if not self.collision_slop >= 0.0:
            raise PhysicsError(f"collision_slop must be >= 0 m, got {self.collision_slop}")
        if not 0.0 <= self.overlap_kept_per_substep < 1.0:
            raise PhysicsError(
                f"overlap_kept_per_substep must be in [0, 1), got {self.overlap_kept_per_substep}"
            )
        if int(self.solver_iterations) != self.solver_iterations or self.solver_iterations < 1:
            raise PhysicsError(
                f"solver_iterations must be an integer >= 1, got {self.solver_iterations}"
            )
        if not (math.isfinite(self.robot_mass) and self.robot_mass > 0.0):
            raise PhysicsError(f"robot_mass must be > 0 kg, got {self.robot_mass}")

    def substeps_for(self, robot: RobotSpec) -> int:
        """Return the pymunk steps per control period for ``robot`` (>= ``substeps``)."""
        travel = robot.max_speed * self.control_period
        needed = math.ceil(travel / (self.max_substep_travel * robot.radius))
        return max(int(self.substeps), needed)


@dataclass(frozen=True)
class StepOutcome:
    """What happened during one control period.

    Attributes:
        collision: the robot touched or overlapped an obstacle in some substep.
        contact_ids: sorted ids of the obstacles it touched.
        command: the ``(v [m/s], omega [rad/s])`` actually applied, after clipping to the
            robot's limits.
    """

    collision: bool
    contact_ids: tuple[int, ...]
    command: tuple[float, float]


class _DriveCommand:
    """pymunk velocity callback: the body moves at ``v`` along its heading, turns at ``omega``.

    A module-level class (not a closure) so that a space holding it can be pickled.
    """

    def __init__(self) -> None:
        self.v = 0.0
        self.omega = 0.0

    def __call__(self, body: pymunk.Body, gravity: object, damping: float, dt: float) -> None:
        angle = body.angle
        body.velocity = (self.v * math.cos(angle), self.v * math.sin(angle))
        body.angular_velocity = self.omega


_Point = tuple[float, float]  # (x [m], y [m])


def _cross(o: _Point, a: _Point, b: _Point) -> float:
    """z-component of ``(a - o) x (b - o)``."""
    return (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])


def _clean_ring(points: object, tolerance: float) -> list[_Point]:
    """Counter-clockwise vertex ring without repeated or collinear vertices.

    The orientation is the exact sign of :func:`shapes.shoelace_sum`. Vertex rings of
    obstacles are short, so plain Python floats are faster than numpy here.
    """
    if isinstance(points, tuple) and all(len(p) == 2 for p in points):  # a world's points
        ring = [(float(x), float(y)) for x, y in points]
    else:
        ring = [(x, y) for x, y in shapes.as_points(points).tolist()]
    if not ring:
        return ring
    if shapes.shoelace_sum(ring) < 0.0:
        ring.reverse()
    xs, ys = zip(*ring, strict=True)
    scale = max(max(xs) - min(xs), max(ys) - min(ys))
    limit = tolerance * scale * scale
    while len(ring) >= 3:  # drop the first flat vertex, until there is none
        n = len(ring)
        for i in range(n):
            if abs(_cross(ring[i - 1], ring[i], ring[(i + 1) % n])) <= limit:
                del ring[i]
                break
        else:
            break
    return ring


def _point_in_triangle(p: _Point, a: _Point, b: _Point, c: _Point) -> bool:
    """``p`` inside or on the boundary of the counter-clockwise triangle ``abc``."""
    return _cross(a, b, p) >= 0.0 and _cross(b, c, p) >= 0.0 and _cross(c, a, p) >= 0.0


def _is_convex(ring: list[_Point]) -> bool:
    """Whether a ring of ``>= 3`` vertices turns left at every vertex and goes around once.

    A ring that turns left everywhere turns by ``2 pi k`` in total, ``k`` the number of
    times it winds around; ``k = 1`` is a convex (so simple) polygon, ``k >= 2`` a star
    that crosses itself.
    """
    turning = 0.0
    (px, py), (cx, cy) = ring[-2], ring[-1]  # previous and current vertex
    for nx, ny in ring:
        cross = (cx - px) * (ny - py) - (cy - py) * (nx - px)  # _cross(prev, cur, next)
        if cross <= 0.0:
            return False
        turning += math.atan2(cross, (cx - px) * (nx - cx) + (cy - py) * (ny - cy))
        px, py, cx, cy = cx, cy, nx, ny
    return turning < 3.0 * math.pi  # 2 pi, not 4 pi or more


def _convex_rings(points: object, tolerance: float) -> list[list[_Point]]:
    """:func:`convex_pieces` as lists of vertex tuples."""
    ring = _clean_ring(points, tolerance)
    if len(ring) < 3:
        raise PhysicsError(f"polygon {np.asarray(points).tolist()} has zero area")
    if _is_convex(ring):
        return [ring]
    if not shapes.is_simple_polygon(ring):
        raise PhysicsError(f"polygon {np.asarray(points).tolist()} is not simple")
    remaining = list(range(len(ring)))
    pieces: list[list[_Point]] = []
    while len(remaining) > 3:
        m = len(remaining)
        for k in range(m):
            i0, i1, i2 = remaining[k - 1], remaining[k], remaining[(k + 1) % m]
            a, b, c = ring[i0], ring[i1], ring[i2]
            if _cross(a, b, c) <= 0.0:  # reflex or flat corner: not an ear
                continue
            if any(
                _point_in_triangle(ring[j], a, b, c) for j in remaining if j not in (i0, i1, i2)
            ):
                continue
            pieces.append([a, b, c])
            remaining.pop(k)
            break
        else:
            raise PhysicsError(f"polygon {np.asarray(points).tolist()} is not simple")
    pieces.append([ring[j] for j in remaining])
    return pieces


def convex_pieces(
    points: tuple[tuple[float, float], ...] | np.ndarray, tolerance: float = 1e-12
) -> list[np.ndarray]:
    """Split a simple polygon into convex pieces whose union is the polygon.

    A convex polygon is returned whole; otherwise the triangles of an ear-clipping
    triangulation are returned.

    Args:
        points: ``(n, 2)`` vertices [m] in either orientation, ``n >= 3``.
        tolerance: relative tolerance for collinear and repeated vertices.

    Returns:
        A list of ``(k, 2)`` counter-clockwise vertex arrays.

    Raises:
        PhysicsError: the polygon is degenerate or not simple.
    """
    return [np.array(piece) for piece in _convex_rings(points, tolerance)]


_PolygonPieces = list[list[_Point]] | None  # convex pieces of an obstacle (None: no polygon)
_PIECES_BY_WORLD: dict[tuple[int, float], tuple[weakref.ref[World], list[_PolygonPieces]]] = {}
"""Convex pieces of the polygons of each live world, by ``(id(world), tolerance)``: a
fixed world's space is rebuilt at every reset. Keyed by identity, not by value, so that
a stream of random worlds neither hashes every polygon nor keeps a cache of them; an
entry goes when its world does."""


def _world_pieces(world: World, tolerance: float) -> list[_PolygonPieces]:
    """The convex pieces of each obstacle of ``world`` (``None`` for non-polygons)."""
    key = (id(world), tolerance)
    entry = _PIECES_BY_WORLD.get(key)
    if entry is not None and entry[0]() is world:
        return entry[1]
    pieces = [
        _convex_rings(o.points, tolerance) if isinstance(o, PolygonObstacle) else None
        for o in world.obstacles
    ]

    def forget(ref: weakref.ref[World]) -> None:
        if _PIECES_BY_WORLD.get(key, (None,))[0] is ref:
            del _PIECES_BY_WORLD[key]

    try:
        _PIECES_BY_WORLD[key] = (weakref.ref(world, forget), pieces)
    except TypeError:  # not weakly referenceable: not cached
        pass
    return pieces


def _obstacle_shapes(
    obstacle: PolygonObstacle | CircleObstacle | WallObstacle,
    body: pymunk.Body,
    pieces: _PolygonPieces,
) -> list[pymunk.Shape]:
    """Make the pymunk shapes of one static obstacle (not yet tagged or added).

    ``pieces``: the convex pieces of a polygon (:func:`_convex_rings`).
    """
    if isinstance(obstacle, CircleObstacle):
        return [pymunk.Circle(body, float(obstacle.radius), tuple(map(float, obstacle.center)))]
    if isinstance(obstacle, WallObstacle):
        radius = float(obstacle.thickness) / 2.0
        points = [tuple(map(float, p)) for p in obstacle.points]
        return [
            pymunk.Segment(body, a, b, radius) for a, b in zip(points[:-1], points[1:], strict=True)
        ]
    if isinstance(obstacle, PolygonObstacle) and pieces is not None:
        return [pymunk.Poly(body, piece) for piece in pieces]
    raise PhysicsError(f"unknown obstacle type {type(obstacle).__name__}")


def build_space(world: World, config: PhysicsConfig) -> pymunk.Space:
    """Build a pymunk space holding the world's static obstacles (no robot).

    Every shape carries ``shape.obstacle_id`` (index in ``world.obstacles``), belongs to
    :data:`OBSTACLE_CATEGORY`, and is frictionless and inelastic.
    """
    space = pymunk.Space()
    space.iterations = int(config.solver_iterations)
    space.collision_slop = float(config.collision_slop)
    body = space.static_body
    obstacle_filter = pymunk.ShapeFilter(categories=OBSTACLE_CATEGORY)
    pieces = _world_pieces(world, config.geometry_tolerance)
    shapes: list[pymunk.Shape] = []
    for obstacle_id, obstacle in enumerate(world.obstacles):
        for shape in _obstacle_shapes(obstacle, body, pieces[obstacle_id]):
            # Friction and elasticity keep pymunk's defaults, 0 (frictionless, inelastic;
            # tests check it): setting them costs time at every reset.
            shape.obstacle_id = obstacle_id
            shape.filter = obstacle_filter
            shapes.append(shape)
    space.add(*shapes)
    return space


def _record_contact(arbiter: pymunk.Arbiter, robot_shape: pymunk.Shape, ids: set[int]) -> None:
    """``Body.each_arbiter`` callback: note the obstacle id of a robot contact."""
    first, second = arbiter.shapes
    other = second if first is robot_shape else first
    ids.add(int(other.obstacle_id))


class DiffDriveSim:
    """A disc robot with differential-drive commands in a world of static obstacles.

    Args:
        world: the world (robot start, radius and limits; obstacles).
        config: simulation settings.

    Attributes:
        world: the world simulated.
        config: the settings.
        substeps: pymunk steps per control period (see :meth:`PhysicsConfig.substeps_for`).
        space: the pymunk space (obstacles, robot).
        body: the robot's pymunk body.
        robot_shape: the robot's pymunk circle.
    """

    def __init__(self, world: World, config: PhysicsConfig | None = None) -> None:
        self.world = world
        self.config = config if config is not None else PhysicsConfig()
        robot = world.robot
        if not (robot.radius > 0.0 and robot.max_speed >= 0.0 and robot.max_turn_rate >= 0.0):
            raise PhysicsError(
                "robot radius must be > 0 m and its speed limits >= 0, got "
                f"radius={robot.radius}, max_speed={robot.max_speed}, "
                f"max_turn_rate={robot.max_turn_rate}"
            )
        self.substeps = self.config.substeps_for(robot)
        self._dt = self.config.control_period / self.substeps
        self.space = build_space(world, self.config)
        self.space.collision_bias = self.config.overlap_kept_per_substep ** (1.0 / self._dt)
        mass = self.config.robot_mass
        self.body = pymunk.Body(mass, pymunk.moment_for_circle(mass, 0.0, robot.radius))
        x, y, theta = (float(c) for c in robot.start)
        self.body.position = (x, y)
        self.body.angle = theta
        self._command = _DriveCommand()
        self.body.velocity_func = self._command
        self.robot_shape = pymunk.Circle(self.body, float(robot.radius))
        self.robot_shape.friction = 0.0
        self.robot_shape.elasticity = 0.0
        self.robot_shape.filter = pymunk.ShapeFilter(
            categories=ROBOT_CATEGORY, mask=OBSTACLE_CATEGORY
        )
        self.space.add(self.body, self.robot_shape)

    @property
    def pose(self) -> np.ndarray:
        """True pose ``(x [m], y [m], theta [rad])``, theta wrapped into ``[-pi, pi)``."""
        x, y = self.body.position
        theta = (self.body.angle + math.pi) % (2.0 * math.pi) - math.pi
        return np.array([x, y, theta])

    def clip_command(self, v: float, omega: float) -> tuple[float, float]:
        """Clip ``(v [m/s], omega [rad/s])`` to the robot's limits; non-finite raises."""
        if not (math.isfinite(v) and math.isfinite(omega)):
            raise PhysicsError(f"command (v, omega) must be finite, got ({v}, {omega})")
        robot = self.world.robot
        return (
            min(max(float(v), -robot.max_speed), robot.max_speed),
            min(max(float(omega), -robot.max_turn_rate), robot.max_turn_rate),
        )

    def step(self, v: float, omega: float) -> StepOutcome:
        """Drive with ``(v [m/s], omega [rad/s])`` (clipped) for one control period."""
        v, omega = self.clip_command(v, omega)
        self._command.v = v
        self._command.omega = omega
        contacts: set[int] = set()
        space, body, dt = self.space, self.body, self._dt
        for _ in range(self.substeps):
            space.step(dt)
            body.each_arbiter(_record_contact, self.robot_shape, contacts)
        return StepOutcome(
            collision=bool(contacts), contact_ids=tuple(sorted(contacts)), command=(v, omega)
        )
