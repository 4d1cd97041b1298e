import importlib.util
import math
import pickle
import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env, data_equivalence
from stable_baselines3.common.env_checker import check_env as sb3_check_env

import vslam_gym
from vslam_gym.env import ActionError, LidarWorldEnv
from vslam_gym.sim.world import RobotSpec, WallObstacle, World
from vslam_gym.sim.world_file import world_to_toml

gym.register_envs(vslam_gym)

ENV_IDS = sorted(  # the simulator ids; the SLAM-wrapped ones are tested in test_slam_wrapper
    env_id
    for env_id, spec in gym.registry.items()
    if env_id.startswith("VSlam/") and not spec.additional_wrappers
)
HAS_RANDOM_WORLDS = importlib.util.find_spec("vslam_gym.sim.random_world") is not None
CASES = [pytest.param(env_id, {}, id=env_id) for env_id in ENV_IDS] + [
    pytest.param(
        vslam_gym.LIDAR_WORLD_ID,
        {"world": "random"},
        id="random-world",
        marks=pytest.mark.skipif(not HAS_RANDOM_WORLDS, reason="no random world generator"),
    )
]


def rollout(env: gym.Env, seed: int, steps: int) -> list:
    """Reset with ``seed`` and take ``steps`` seeded random actions; return everything."""
    actions = np.random.default_rng(seed).uniform(-1.0, 1.0, (steps, 2)).astype(np.float32)
    record = [env.reset(seed=seed)]
    record += [env.step(action) for action in actions]
    return record


def test_registration_is_idempotent():
    assert vslam_gym.LIDAR_WORLD_ID in ENV_IDS
    spec = gym.spec(vslam_gym.LIDAR_WORLD_ID)
    vslam_gym._register_envs()
    assert gym.spec(vslam_gym.LIDAR_WORLD_ID) is spec
    assert spec.max_episode_steps == 1000
    assert spec.kwargs == {"world": "house"}


@pytest.mark.parametrize(("env_id", "kwargs"), CASES)
def test_gymnasium_check_env(env_id, kwargs):
    env = gym.make(env_id, render_mode="rgb_array", disable_env_checker=True, **kwargs)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        check_env(env.unwrapped)
    # The only warnings allowed: the odometry Box is unbounded by design.
    unexpected = [str(w.message) for w in caught if "infinity" not in str(w.message)]
    assert unexpected == []
    env.close()


@pytest.mark.parametrize(("env_id", "kwargs"), CASES)
def test_stable_baselines3_check_env(env_id, kwargs):
    env = gym.make(env_id, disable_env_checker=True, **kwargs)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        sb3_check_env(env.unwrapped, warn=True)
    assert [str(w.message) for w in caught] == []
    env.close()


@pytest.mark.parametrize(("env_id", "kwargs"), CASES)
def test_same_seed_same_rollout(env_id, kwargs):
    first = rollout(gym.make(env_id, **kwargs), seed=123, steps=60)
    second = rollout(gym.make(env_id, **kwargs), seed=123, steps=60)
    assert data_equivalence(first, second, exact=True)
    other = rollout(gym.make(env_id, **kwargs), seed=124, steps=60)
    assert not np.array_equal(first[0][0]["scan"], other[0][0]["scan"])


@pytest.mark.parametrize(("env_id", "kwargs"), CASES)
def test_reset_with_a_seed_replays_the_episode(env_id, kwargs):
    env = gym.make(env_id, **kwargs)
    first = rollout(env, seed=7, steps=30)
    second = rollout(env, seed=7, steps=30)  # same env object, physics rebuilt
    assert data_equivalence(first, second, exact=True)


@pytest.mark.parametrize(("env_id", "kwargs"), CASES)
def test_pickled_env_continues_identically(env_id, kwargs):
    env = gym.make(env_id, **kwargs)
    rollout(env, seed=3, steps=25)
    copy = pickle.loads(pickle.dumps(env))
    for action in np.random.default_rng(0).uniform(-1, 1, (20, 2)).astype(np.float32):
        assert data_equivalence(env.step(action), copy.step(action), exact=True)


@pytest.mark.parametrize(("env_id", "kwargs"), CASES)
def test_async_vector_env_steps(env_id, kwargs):
    envs = gym.make_vec(env_id, num_envs=2, vectorization_mode="async", **kwargs)
    try:
        observations, infos = envs.reset(seed=11)
        n_beams = envs.single_observation_space["scan"].shape[0]
        assert observations["scan"].shape == (2, n_beams)
        assert observations["odometry"].shape == (2, 3)
        for _ in range(5):
            observations, rewards, terminated, truncated, infos = envs.step(
                np.full((2, 2), 0.5, dtype=np.float32)
            )
        assert np.all(observations["odometry"][:, 1] > 0.0)  # both drove forward
        assert infos["pose"].shape == (2, 3)
        assert not np.array_equal(observations["scan"][0], observations["scan"][1])
    finally:
        envs.close()


@pytest.mark.parametrize(("env_id", "kwargs"), CASES)
def test_render_rgb_array(env_id, kwargs):
    env = gym.make(env_id, render_mode="rgb_array", **kwargs)
    env.reset(seed=0)
    for _ in range(5):
        env.step(np.array([1.0, 0.2], dtype=np.float32))
    frame = env.render()
    assert frame.dtype == np.uint8
    assert frame.shape == (LidarWorldEnv.screen_height, LidarWorldEnv.screen_width, 3)
    assert len(np.unique(frame.reshape(-1, 3), axis=0)) >= 4  # background, obstacles, robot...
    env.close()


def test_render_human_headless():
    env = LidarWorldEnv(world="single_landmark", render_mode="human")
    env.reset(seed=0)
    env.step(np.array([0.5, 0.0], dtype=np.float32))
    assert env.render() is None
    env.close()


def test_nan_action_raises_a_clear_error():
    env = LidarWorldEnv(world="single_landmark")
    env.reset(seed=0)
    with pytest.raises(ActionError, match="NaN"):
        env.step(np.array([np.nan, 0.0], dtype=np.float32))
    with pytest.raises(ValueError, match=r"shape \(2,\)"):
        env.step(np.zeros(3, dtype=np.float32))


def test_actions_outside_the_box_are_clipped():
    clipped, limit = LidarWorldEnv(world="single_landmark"), LidarWorldEnv(world="single_landmark")
    clipped.reset(seed=1)
    limit.reset(seed=1)
    for _ in range(10):
        a = clipped.step(np.array([3.0, -np.inf], dtype=np.float32))
        b = limit.step(np.array([1.0, -1.0], dtype=np.float32))
        assert data_equivalence(a, b, exact=True)


def test_step_before_reset_raises():
    with pytest.raises(gym.error.ResetNeeded):
        LidarWorldEnv(world="single_landmark").step(np.zeros(2, dtype=np.float32))


def test_info_contents():
    env = LidarWorldEnv(world="single_landmark")
    obs, info = env.reset(seed=0)
    assert set(info) == {
        "pose",
        "odom_pose",
        "hit_ids",
        "bearings",
        "collision",
        "contact_ids",
        "odometry_true",
        "odometry_noisy",
        "rewards",
    }
    np.testing.assert_array_equal(info["pose"], info["odom_pose"])
    np.testing.assert_array_equal(obs["odometry"], np.zeros(3))
    obs, reward, terminated, truncated, info = env.step(np.array([1.0, 0.5], dtype=np.float32))
    assert info["hit_ids"].shape == info["bearings"].shape == obs["scan"].shape
    np.testing.assert_array_equal(info["hit_ids"] == -1, obs["scan"] == env.lidar_spec.max_range)
    np.testing.assert_array_equal(obs["odometry"], info["odometry_noisy"].astype(np.float32))
    assert info["odometry_true"][1] == pytest.approx(0.09, abs=0.01)  # about v * dt
    assert np.all(np.diff(info["bearings"]) < 0)
    assert reward == 0.0 and info["rewards"] == {"collision": 0.0}


def test_noise_free_odometry_integrates_to_the_true_pose():
    env = LidarWorldEnv(world="single_landmark", odometry_alphas=(0.0, 0.0, 0.0, 0.0))
    env.reset(seed=0)
    for action in np.random.default_rng(0).uniform(-1, 1, (100, 2)).astype(np.float32):
        _, _, _, _, info = env.step(action)
    np.testing.assert_allclose(info["odom_pose"][:2], info["pose"][:2], atol=1e-9)
    assert math.remainder(info["odom_pose"][2] - info["pose"][2], 2 * math.pi) == pytest.approx(
        0.0, abs=1e-9
    )


@pytest.fixture
def bump_world(tmp_path):
    """A world file: the robot 0.5 m in front of a wall."""
    world = World(
        name="bump",
        robot=RobotSpec(start=(0.0, 0.0, 0.0)),
        obstacles=(WallObstacle(points=((0.8, -3.0), (0.8, 3.0)), thickness=0.1),),
    )
    path = tmp_path / "bump.toml"
    path.write_text(world_to_toml(world))
    return str(path)


@pytest.mark.parametrize("terminate", [False, True])
def test_collision_penalty_and_termination(bump_world, terminate):
    env = LidarWorldEnv(world=bump_world, collision_penalty=2.5, terminate_on_collision=terminate)
    env.reset(seed=0)
    forward = np.array([1.0, 0.0], dtype=np.float32)
    steps = 0
    while steps < 20:
        _, reward, terminated, _, info = env.step(forward)
        steps += 1
        if info["collision"]:
            break
        assert reward == 0.0 and not terminated
    assert info["collision"] and steps >= 4  # 0.5 m minus radius and half thickness at 1 m/s
    assert info["contact_ids"] == (0,)
    assert reward == -2.5 and info["rewards"] == {"collision": -2.5}
    assert terminated is terminate
    assert info["pose"][0] <= 0.8 - 0.05 - 0.2 + 1e-2


def test_lidar_overrides_fix_the_observation_space():
    env = LidarWorldEnv(world="single_landmark", lidar={"fov_deg": 90.0, "resolution_deg": 0.5})
    assert env.observation_space["scan"].shape == (181,)
    obs, info = env.reset(seed=0)
    assert obs["scan"].shape == (181,)
    assert info["bearings"][0] == pytest.approx(math.radians(45.0))
    with pytest.raises(ValueError, match="did you mean 'fov_deg'"):
        LidarWorldEnv(world="single_landmark", lidar={"fov": 90.0})
    with pytest.raises(ValueError, match="world_params"):
        LidarWorldEnv(world="single_landmark", world_params={"n_obstacles": 3})
    with pytest.raises(ValueError, match="render_mode"):
        LidarWorldEnv(world="single_landmark", render_mode="ascii")


@pytest.mark.skipif(not HAS_RANDOM_WORLDS, reason="no random world generator")
def test_random_worlds_follow_the_seed():
    env = LidarWorldEnv(world="random")
    env.reset(seed=1)
    first = env.world
    env.reset(seed=2)
    second = env.world
    env.reset(seed=1)
    assert env.world == first
    assert second != first
    assert env.observation_space["scan"].shape == (181,)


@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({"collision_penalty": "1"}, "collision_penalty must be a number"),
        ({"control_period": None}, "control_period must be a number"),
        ({"physics_substeps": 2.7}, "physics_substeps must be an integer"),  # was truncated
        ({"terminate_on_collision": "no"}, "terminate_on_collision must be a bool"),  # was True
        ({"odometry_alphas": 0.1}, "odometry_alphas must be 4 numbers"),
    ],
)
def test_constructor_arguments_of_the_wrong_type_are_named(kwargs, message):
    with pytest.raises(ValueError, match=message):
        LidarWorldEnv(world="small", **kwargs)


def test_reset_options_are_not_silently_ignored():
    env = gym.make("VSlam/LidarWorld-v0", world="small")
    env.reset(seed=0, options={})  # empty: as no options
    with pytest.raises(ValueError, match=r"takes no options .* got \['world'\]"):
        env.reset(seed=0, options={"world": "house"})
