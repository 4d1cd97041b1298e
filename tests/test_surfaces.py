"""Surface pieces of a world's obstacles (vslam_gym.surfaces), the duplicate metric's floor."""

import math

import numpy as np
import pytest

from vslam_gym.evaluation import duplicate_fraction
from vslam_gym.sim.world import CircleObstacle, PolygonObstacle, RobotSpec, WallObstacle, World
from vslam_gym.sim.world_file import load_world
from vslam_gym.surfaces import surface_pieces

ROOM = WallObstacle(((0.0, 0.0), (4.0, 0.0), (4.0, 2.0), (0.0, 2.0), (0.0, 0.0)), thickness=0.2)
"""A closed 4 m x 2 m room: one obstacle (id 0), as ``house``'s outer walls."""


def _world(*obstacles, start=(1.0, 1.0)) -> World:
    return World(name="rooms", robot=RobotSpec(start=(*start, 0.0)), obstacles=(ROOM, *obstacles))


def _owners(world: World, free_point=None) -> list[int]:
    return sorted(surface_pieces(world, free_point).owner.tolist())


def test_a_free_standing_wall_is_one_piece_around_its_ends():
    # the two faces of a wall join around its free (round) ends: one surface
    world = _world(WallObstacle(((2.0, 0.6), (2.0, 1.4)), thickness=0.1))
    assert _owners(world) == [0, 1]


def test_a_wall_from_wall_to_wall_splits_the_space_and_only_the_reachable_side_counts():
    world = _world(WallObstacle(((2.0, 0.0), (2.0, 2.0)), thickness=0.1))
    assert _owners(world) == [0, 1]  # the left room only: its outer walls and one face
    assert _owners(world, (3.0, 1.0)) == [0, 1]  # the right room
    pieces = surface_pieces(world)
    # the left room's boundary: three sides of about 2 m, 2 m and 2 m, and the partition
    lengths = dict(zip(pieces.owner.tolist(), (pieces.cells * pieces.cell).tolist(), strict=True))
    assert lengths[0] == pytest.approx(2 * 1.9 + 1.8, abs=0.25)
    assert lengths[1] == pytest.approx(1.8, abs=0.15)


def test_walls_that_abut_the_outer_wall_split_its_face_into_pieces():
    # a partition with a door in the middle, in two walls: one touches the floor side,
    # the other the ceiling side, so the room's face is two pieces (left and right)
    world = _world(
        WallObstacle(((2.0, 0.0), (2.0, 0.8)), thickness=0.1),
        WallObstacle(((2.0, 1.2), (2.0, 2.0)), thickness=0.1),
    )
    owners = _owners(world)
    assert owners == [0, 0, 1, 2]
    assert duplicate_fraction(owners) == pytest.approx(1.0 - 3 / 4)  # the metric's floor


def test_overlapping_solid_obstacles_are_one_piece_each_on_their_own_boundary():
    box = PolygonObstacle(((1.5, 0.5), (2.5, 0.5), (2.5, 1.5), (1.5, 1.5)))
    disc = CircleObstacle((2.5, 1.0), 0.3)  # overlaps the box's right side
    world = _world(box, disc, start=(0.5, 1.0))
    assert _owners(world) == [0, 1, 2]
    pieces = surface_pieces(world)
    hits = np.array([[1.49, 1.0], [2.81, 1.0], [2.0, 0.49]])  # box left, disc right, box bottom
    got = pieces.hit_pieces(hits, np.array([1, 2, 1]), 0.05)
    assert pieces.owner[got].tolist() == [1, 2, 1]
    # a hit on the disc's part inside the box is not on any boundary
    assert pieces.hit_pieces(np.array([[2.4, 1.0]]), np.array([2]), 0.05).tolist() == [-1]


def test_hit_pieces_assigns_hits_to_the_nearest_cell_of_the_obstacle_they_hit():
    world = _world(WallObstacle(((2.0, 0.0), (2.0, 2.0)), thickness=0.1))
    pieces = surface_pieces(world)
    partition = int(np.flatnonzero(pieces.owner == 1)[0])
    outer = int(np.flatnonzero(pieces.owner == 0)[0])
    points = np.array(
        [
            [1.96, 1.0],  # on the partition's left face, a little inside it
            [1.90, 1.0],  # 0.05 m in front of it
            [1.70, 1.0],  # 0.25 m in front: too far for a 0.1 m radius
            [1.96, 1.0],  # on the partition, but the beam says it hit obstacle 0
            [0.09, 1.0],  # on the outer wall's inner face
            [1.0, 1.0],  # no return
            [-5.0, 1.0],  # outside the raster
        ]
    )
    ids = np.array([1, 1, 1, 0, 0, -1, 0])
    got = pieces.hit_pieces(points, ids, 0.1)
    assert got.tolist() == [partition, partition, -1, -1, outer, -1, -1]
    with pytest.raises(ValueError, match="points"):
        pieces.hit_pieces(np.array([[np.nan, 0.0]]), np.array([0]), 0.1)
    with pytest.raises(ValueError, match="ids"):
        pieces.hit_pieces(points, ids[:2], 0.1)
    with pytest.raises(ValueError, match="radius"):
        pieces.hit_pieces(points, ids, 0.0)


def test_bad_arguments_are_rejected():
    world = _world()
    with pytest.raises(ValueError, match="cell"):
        surface_pieces(world, cell=0.0)
    with pytest.raises(ValueError, match="inside obstacle 0"):
        surface_pieces(world, (0.0, 1.0))  # on the outer wall


def test_the_floor_is_the_duplicate_fraction_of_the_pieces_obstacle_ids():
    # pieces stand for landmarks; no piece has the "no obstacle" id -1
    assert duplicate_fraction([3, 3, 5]) == pytest.approx(1.0 - 2 / 3)
    assert duplicate_fraction([0, 1, 2]) == 0.0
    assert math.isnan(duplicate_fraction([]))


def test_house_outer_wall_is_many_pieces_and_the_small_worlds_one_per_obstacle():
    house = surface_pieces(load_world("house"))
    per_obstacle = np.bincount(house.owner)
    assert per_obstacle[0] >= 10  # the outer walls, seen from every room
    assert duplicate_fraction(house.owner.tolist()) > 0.15
    for name in ("single_landmark", "small", "curved"):
        world = load_world(name)
        owners = surface_pieces(world).owner
        assert sorted(owners.tolist()) == list(range(len(world.obstacles))), name
