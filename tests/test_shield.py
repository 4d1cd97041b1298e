"""The speed shield: free corridor length, speed caps, configuration, the wrapper option."""

from __future__ import annotations

import math

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env as gym_check_env

import vslam_gym
from vslam_gym.config_utils import UnknownKeyError
from vslam_gym.shield import ShieldConfig, SpeedShield, corridor_free_length

gym.register_envs(vslam_gym)

RADIUS, MAX_RANGE, TURN_RATE, PERIOD = 0.2, 8.0, 1.5, 0.1
BEARINGS = np.radians(np.linspace(90.0, -90.0, 181))


def _wall_scan(distance: float) -> np.ndarray:
    """Ranges [m] of a straight wall ``distance`` ahead, perpendicular to the heading."""
    with np.errstate(divide="ignore"):
        r = distance / np.cos(BEARINGS)
    return np.where((np.cos(BEARINGS) > 1e-9) & (r < MAX_RANGE), r, MAX_RANGE)


def _shield(**fields: float) -> SpeedShield:
    return SpeedShield(ShieldConfig(**fields), RADIUS, MAX_RANGE, BEARINGS, TURN_RATE, PERIOD)


def test_corridor_free_length_against_a_wall():
    y = np.linspace(-1.0, 1.0, 201)
    wall = np.stack([np.full_like(y, 2.0), y], axis=1)
    free = corridor_free_length(wall, np.radians([0.0, 30.0, 90.0]), 0.25, MAX_RANGE)
    assert free[0] == pytest.approx(2.0 - 0.25, abs=1e-9)  # the point (2, 0) meets the front
    # At 30 degrees the wall's end (2, 1) lies 0.13 m beside the centre line, 2.23 m along.
    lateral = -2.0 * math.sin(math.radians(30.0)) + 1.0 * math.cos(math.radians(30.0))
    along = 2.0 * math.cos(math.radians(30.0)) + 1.0 * math.sin(math.radians(30.0))
    assert free[1] <= along - math.sqrt(0.25**2 - lateral**2) + 1e-9
    assert free[2] == MAX_RANGE  # nothing beside the robot on the left
    assert corridor_free_length(np.zeros((0, 2)), np.zeros(2), 0.25, MAX_RANGE).tolist() == [
        MAX_RANGE,
        MAX_RANGE,
    ]


def test_allowed_speed_rises_linearly_between_stop_and_slow_distance():
    shield = _shield(margin=0.05, stop_distance=0.1, slow_distance=0.5)
    half_width = RADIUS + 0.05
    # Free length = distance - half width: 0.3 m is halfway from 0.1 to 0.5.
    assert shield.allowed_speed(_wall_scan(0.3 + half_width), 0.0) == pytest.approx(0.5, abs=1e-6)
    assert shield.allowed_speed(_wall_scan(0.05 + half_width), 0.0) == 0.0
    assert shield.allowed_speed(_wall_scan(3.0), 0.0) == 1.0
    assert shield.allowed_speed(np.full(181, MAX_RANGE), 1.0) == 1.0  # no returns


def test_apply_caps_only_forward_speed():
    shield = _shield()
    scan = _wall_scan(0.3 + RADIUS + 0.05)
    action, changed = shield.apply(np.array([1.0, 0.3], np.float32), scan)
    assert changed and action.dtype == np.float32
    assert action[0] == pytest.approx(shield.allowed_speed(scan, 0.3))
    assert action[1] == pytest.approx(0.3)
    assert 0.0 < action[0] < 1.0
    for free_action in ([0.1, 0.0], [-1.0, 0.5], [0.0, -1.0]):
        out, changed = shield.apply(np.array(free_action, np.float32), scan)
        assert not changed and out.tolist() == pytest.approx(free_action)
    bad = np.array([np.nan, 0.0], np.float32)  # left for the environment to reject
    out, changed = shield.apply(bad, scan)
    assert not changed and np.isnan(out[0])
    with pytest.raises(ValueError, match="scan must have shape"):
        shield.allowed_speed(np.ones(5), 0.0)


def test_config_validation_and_from_any():
    assert ShieldConfig.from_any(None) is None and ShieldConfig.from_any(False) is None
    assert ShieldConfig.from_any(True) == ShieldConfig()
    assert ShieldConfig.from_any({"margin": 0.1}).margin == 0.1
    with pytest.raises(UnknownKeyError, match="marign"):
        ShieldConfig.from_any({"marign": 0.1})
    with pytest.raises(ValueError, match="slow_distance"):
        ShieldConfig(stop_distance=0.5, slow_distance=0.5)
    with pytest.raises(ValueError, match="margin"):
        ShieldConfig(margin=-0.1)
    with pytest.raises(ValueError, match="no_return"):
        ShieldConfig(no_return=1.5)
    with pytest.raises(TypeError, match="shield must be"):
        ShieldConfig.from_any("on")


def _drive_straight(env: gym.Env, seed: int, steps: int) -> tuple[int, int, bool]:
    """Full speed ahead: ``(steps taken, steps shielded, collided)``."""
    env.reset(seed=seed)
    shielded, collided = 0, False
    for t in range(steps):
        _, _, terminated, truncated, info = env.step(np.array([1.0, 0.0], np.float32))
        shielded += int(info.get("shielded", False))
        collided |= bool(info["collision"])
        if terminated or truncated:
            return t + 1, shielded, collided
    return steps, shielded, collided


def test_wrapper_shield_stops_a_robot_driving_into_a_wall():
    plain = gym.make(vslam_gym.EXPLORE_ID, max_episode_steps=150)
    steps, _, collided = _drive_straight(plain, seed=3, steps=150)
    assert collided and steps < 150, "without the shield the robot hits the wall"
    shielded_env = gym.make(vslam_gym.explore_spec(shield=True), max_episode_steps=150)
    steps, shielded, collided = _drive_straight(shielded_env, seed=3, steps=150)
    assert not collided and steps == 150
    assert shielded > 50, "the shield capped the speed at the wall"
    _, _, _, _, info = shielded_env.step(np.array([1.0, 0.0], np.float32))
    assert info["executed_action"][0] == 0.0 and info["shielded"]
    plain.reset(seed=3)
    assert "shielded" not in plain.step(np.zeros(2, np.float32))[4]
    plain.close()
    shielded_env.close()


def test_shielded_env_passes_the_checker_and_keeps_the_spaces():
    env = gym.make(vslam_gym.explore_spec("VSlam/ExploreSmall-v0", shield={"margin": 0.1}))
    plain = gym.make("VSlam/ExploreSmall-v0")
    assert env.observation_space == plain.observation_space
    assert env.action_space == plain.action_space
    with pytest.warns(UserWarning, match="different from the unwrapped"):
        gym_check_env(env, skip_render_check=True)
    env.close()
    plain.close()
