import math

import numpy as np
import pytest

from vslam_gym.control import RouteFollower, RouteFollowerConfig
from vslam_gym.env import LidarWorldEnv
from vslam_gym.sim.world import Route
from vslam_gym.sim.world_file import route_length


def test_drives_the_single_landmark_loop_without_collisions():
    env = LidarWorldEnv(world="single_landmark")
    follower = RouteFollower(env.world.route)
    _, info = env.reset(seed=0)
    steps, collisions = 0, 0
    while not follower.done and steps < 600:
        _, _, _, _, info = env.step(follower(info["pose"]))
        steps += 1
        collisions += info["collision"]
    length = route_length(env.world)
    assert follower.done
    assert collisions == 0
    # At 1 m/s and 0.1 s per step the loop takes at least length / 0.1 steps.
    assert length / 0.1 <= steps <= 1.3 * length / 0.1
    start = np.asarray(env.world.route.waypoints[0])
    assert np.linalg.norm(info["pose"][:2] - start) <= follower.config.waypoint_tolerance


def test_actions_are_normalised_and_slow_for_turns():
    follower = RouteFollower([(10.0, 0.0), (10.0, 10.0)])
    straight = follower((0.0, 0.0, 0.0))
    assert straight.dtype == np.float32
    assert straight[0] == pytest.approx(1.0) and straight[1] == pytest.approx(0.0)
    near_corner = follower((9.5, 0.0, 0.0))
    assert 0.2 <= near_corner[0] < 0.9  # a 90 deg turn follows
    behind = follower((12.0, 0.0, 0.0))
    assert behind[0] == 0.0 and abs(behind[1]) == pytest.approx(1.0)  # turn on the spot
    left = follower((0.0, 0.0, -0.2))
    assert left[1] > 0.0  # target to the left: turn counter-clockwise


def test_progress_and_done():
    follower = RouteFollower(Route(waypoints=((1.0, 0.0), (2.0, 0.0)), loop=True))
    assert len(follower.targets) == 3 and follower.progress == 0.0
    follower((1.0, 0.0, 0.0))
    assert follower.index == 1
    follower((2.0, 0.1, 0.0))
    follower((1.1, 0.0, math.pi))
    assert follower.done and follower.progress == 1.0
    np.testing.assert_array_equal(follower((0.0, 0.0, 0.0)), np.zeros(2, dtype=np.float32))
    follower.reset()
    assert follower.index == 0


def test_bad_input_raises():
    with pytest.raises(ValueError, match="waypoint"):
        RouteFollower([])
    with pytest.raises(ValueError, match="finite"):
        RouteFollower([(0.0, 0.0)])((float("nan"), 0.0, 0.0))
    with pytest.raises(ValueError, match="min_speed"):
        RouteFollowerConfig(min_speed=2.0)
