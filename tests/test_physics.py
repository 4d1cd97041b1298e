import dataclasses
import gc
import math
import pickle

import numpy as np
import pytest

from vslam_gym.sim.physics import (
    DiffDriveSim,
    PhysicsConfig,
    PhysicsError,
    build_space,
    convex_pieces,
)
from vslam_gym.sim.world import CircleObstacle, PolygonObstacle, RobotSpec, WallObstacle, World

RADIUS = 0.2


def wall_world(thickness: float, heading: float = 0.0, max_speed: float = 1.0) -> World:
    """A wall along x = 2 (from y = -200 to 200), the robot at the origin."""
    wall = WallObstacle(points=((2.0, -200.0), (2.0, 200.0)), thickness=thickness)
    robot = RobotSpec(start=(0.0, 0.0, heading), radius=RADIUS, max_speed=max_speed)
    return World(name="wall", robot=robot, obstacles=(wall,))


def test_free_motion_follows_the_commands():
    sim = DiffDriveSim(World(name="empty", robot=RobotSpec(start=(0.0, 0.0, 0.0))))
    for _ in range(10):
        outcome = sim.step(0.5, 0.0)
        assert not outcome.collision
    # The first substep of the first period still moves with the initial (zero) velocity.
    dt = sim.config.control_period / sim.substeps
    assert sim.pose[0] == pytest.approx(0.5 * (1.0 - dt), abs=1e-9)
    assert sim.pose[1] == pytest.approx(0.0, abs=1e-12)
    # A constant (v, omega) drives on a circle of radius v / omega.
    v, omega = 0.8, 1.0
    sim = DiffDriveSim(World(name="empty", robot=RobotSpec(start=(0.0, 0.0, 0.0))))
    positions = []
    for _ in range(60):
        sim.step(v, omega)
        positions.append(sim.pose[:2].copy())
    # The path is the circle through the start, centre v / omega to the left.
    distances = np.linalg.norm(np.array(positions) - [0.0, v / omega], axis=1)
    np.testing.assert_allclose(distances, v / omega, atol=5e-3)


def test_commands_are_clipped_to_the_robot_limits():
    sim = DiffDriveSim(World(name="empty", robot=RobotSpec(start=(0.0, 0.0, 0.0), max_speed=0.5)))
    outcome = sim.step(3.0, -10.0)
    assert outcome.command == (0.5, -sim.world.robot.max_turn_rate)
    with pytest.raises(PhysicsError, match="finite"):
        sim.step(float("nan"), 0.0)


def test_collision_with_a_wall_stops_the_robot():
    sim = DiffDriveSim(wall_world(thickness=0.1))
    contact_x = 2.0 - 0.05 - RADIUS  # wall face minus robot radius
    collided = []
    for _ in range(40):
        outcome = sim.step(1.0, 0.0)
        collided.append(outcome.collision)
        if outcome.collision:
            assert outcome.contact_ids == (0,)
    assert not collided[0] and collided[-1]
    first = collided.index(True)
    assert all(collided[first:])  # stays in contact while pushing
    assert sim.pose[0] == pytest.approx(contact_x, abs=2 * sim.config.collision_slop)
    assert sim.pose[1] == pytest.approx(0.0, abs=1e-9)
    stopped = sim.pose.copy()
    sim.step(1.0, 0.0)
    assert np.linalg.norm(sim.pose - stopped) < 1e-6
    # Backing off ends the contact.
    outcome = sim.step(-1.0, 0.0)
    outcome = sim.step(-1.0, 0.0)
    assert not outcome.collision
    assert sim.pose[0] < contact_x - 0.05


def test_oblique_contact_slides_along_the_wall():
    sim = DiffDriveSim(wall_world(thickness=0.1, heading=math.pi / 4))
    for _ in range(60):
        sim.step(1.0, 0.0)
    x, y, theta = sim.pose
    assert x == pytest.approx(2.0 - 0.05 - RADIUS, abs=2 * sim.config.collision_slop)
    # Sliding keeps the tangential speed cos(45 deg) * 1 m/s and the heading.
    before = y
    sim.step(1.0, 0.0)
    assert sim.pose[1] - before == pytest.approx(math.cos(math.pi / 4) * 0.1, rel=1e-3)
    assert theta == pytest.approx(math.pi / 4, abs=1e-9)


@pytest.mark.parametrize("thickness", [0.0, 0.01])
@pytest.mark.parametrize("max_speed", [1.0, 5.0])
@pytest.mark.parametrize("heading", [0.0, 0.3])
def test_no_tunnelling_through_a_thin_wall_at_full_speed(thickness, max_speed, heading):
    sim = DiffDriveSim(wall_world(thickness, heading, max_speed))
    assert max_speed * sim.config.control_period / sim.substeps < RADIUS
    deepest = -np.inf
    for _ in range(300):
        sim.step(max_speed, 0.0)
        deepest = max(deepest, sim.pose[0])
    # The centre never comes closer to the wall than the radius, minus a small overlap.
    assert (
        deepest
        <= 2.0 - thickness / 2 - RADIUS + max_speed * sim.config.control_period / sim.substeps
    )


def test_space_holds_tagged_static_shapes():
    nonconvex = PolygonObstacle(points=((0.0, 0.0), (4.0, 0.0), (4.0, 4.0), (2.0, 1.0), (0.0, 4.0)))
    world = World(
        name="shapes",
        robot=RobotSpec(start=(10.0, 10.0, 0.0)),
        obstacles=(
            CircleObstacle(center=(-3.0, 0.0), radius=1.0),
            nonconvex,
            WallObstacle(points=((6.0, 0.0), (7.0, 0.0), (7.0, 1.0)), thickness=0.1),
        ),
    )
    space = build_space(world, PhysicsConfig())
    ids = sorted(shape.obstacle_id for shape in space.shapes)
    assert ids == [0, 1, 1, 1, 2, 2]  # the non-convex pentagon is three triangles
    assert all(shape.body is space.static_body for shape in space.shapes)
    # The notch of the non-convex polygon is free space, its arms are solid.
    from vslam_gym.sim.physics import OBSTACLE_QUERY_FILTER

    assert space.point_query_nearest((2.0, 2.0), 0.0, OBSTACLE_QUERY_FILTER) is None
    assert space.point_query_nearest((0.5, 3.0), 0.0, OBSTACLE_QUERY_FILTER).shape.obstacle_id == 1
    # Frictionless and inelastic (pymunk's defaults, relied upon by build_space).
    assert all(shape.friction == 0.0 and shape.elasticity == 0.0 for shape in space.shapes)
    # Points given as lists give the same shapes.
    as_lists = PolygonObstacle(points=[list(p) for p in nonconvex.points])
    again = build_space(dataclasses.replace(world, obstacles=(as_lists,)), PhysicsConfig())
    vertices = [[tuple(v) for v in shape.get_vertices()] for shape in again.shapes]
    assert vertices == [
        [tuple(v) for v in shape.get_vertices()] for shape in space.shapes if shape.obstacle_id == 1
    ]


def test_polygon_pieces_are_reused_for_a_world_and_forgotten_with_it():
    from vslam_gym.sim import physics

    l_shape = PolygonObstacle(
        points=((0.0, 0.0), (2.0, 0.0), (2.0, 1.0), (1.0, 1.0), (1.0, 2.0), (0.0, 2.0))
    )
    world = World(name="l", robot=RobotSpec(start=(5.0, 5.0, 0.0)), obstacles=(l_shape,))
    spaces = [build_space(world, PhysicsConfig()) for _ in range(2)]
    spaces.append(build_space(dataclasses.replace(world), PhysicsConfig()))  # an equal copy
    vertices = [[[tuple(v) for v in s.get_vertices()] for s in space.shapes] for space in spaces]
    assert len(vertices[0]) == 4  # the L-shape is four triangles
    assert vertices[0] == vertices[1] == vertices[2]
    key = (id(world), PhysicsConfig().geometry_tolerance)
    assert key in physics._PIECES_BY_WORLD
    del world
    gc.collect()
    assert key not in physics._PIECES_BY_WORLD


def _area(points: np.ndarray) -> float:
    x, y = points[:, 0], points[:, 1]
    return 0.5 * float(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y))


def test_convex_pieces_cover_the_polygon_exactly():
    rng = np.random.default_rng(0)
    for _ in range(50):
        k = int(rng.integers(3, 12))
        angles = 2 * np.pi * (np.arange(k) + rng.uniform(0.0, 0.8, k)) / k
        radii = rng.uniform(0.3, 1.0, k)
        polygon = np.stack([radii * np.cos(angles), radii * np.sin(angles)], axis=1)
        pieces = convex_pieces(polygon[::-1] if rng.random() < 0.5 else polygon)
        assert sum(_area(p) for p in pieces) == pytest.approx(_area(polygon), rel=1e-12)
        for piece in pieces:
            assert _area(piece) > 0.0
            n = len(piece)
            for i in range(n):
                a, b, c = piece[i - 1], piece[i], piece[(i + 1) % n]
                assert (b[0] - a[0]) * (c[1] - b[1]) - (b[1] - a[1]) * (c[0] - b[0]) > 0.0


def test_bad_polygons_and_settings_raise():
    with pytest.raises(PhysicsError, match="not simple"):
        convex_pieces(((0.0, 0.0), (1.0, 1.0), (1.0, 0.0), (0.0, 1.0)))
    # A pentagram turns left at every vertex but winds around twice.
    angles = 2 * np.pi * np.arange(0, 10, 2) / 5
    with pytest.raises(PhysicsError, match="not simple"):
        convex_pieces(np.stack([np.cos(angles), np.sin(angles)], axis=1))
    with pytest.raises(PhysicsError, match="zero area"):
        convex_pieces(((0.0, 0.0), (1.0, 0.0), (2.0, 0.0)))
    with pytest.raises(PhysicsError, match="control_period"):
        PhysicsConfig(control_period=0.0)
    with pytest.raises(PhysicsError, match="max_substep_travel"):
        PhysicsConfig(max_substep_travel=1.5)


def test_substeps_rise_with_speed():
    config = PhysicsConfig(control_period=0.1, substeps=2, max_substep_travel=0.25)
    assert config.substeps_for(RobotSpec(start=(0, 0, 0), radius=0.2, max_speed=1.0)) == 2
    assert config.substeps_for(RobotSpec(start=(0, 0, 0), radius=0.2, max_speed=5.0)) == 10


def test_pickled_simulation_continues_identically():
    sim = DiffDriveSim(wall_world(thickness=0.1, heading=0.2))
    for _ in range(20):
        sim.step(1.0, 0.1)  # in contact by now
    copy = pickle.loads(pickle.dumps(sim))
    for _ in range(10):
        a, b = sim.step(1.0, -0.3), copy.step(1.0, -0.3)
        assert a == b
        np.testing.assert_array_equal(sim.pose, copy.pose)
