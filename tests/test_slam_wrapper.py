"""SlamWrapper: spaces, belief observations, belief rewards, no ground-truth leak."""

from __future__ import annotations

import dataclasses
import math
import pickle

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env as gym_check_env

import vslam_gym
from vslam_gym.belief_observation import (
    BeliefObservationConfig,
    BeliefRaster,
    FrontierCue,
    PoseUncertainty,
    belief_segments,
    boundary_cells,
    frontier_targets,
)
from vslam_gym.belief_reward import (
    BeliefReward,
    BeliefRewardConfig,
    d_optimality,
    pose_entropy,
)
from vslam_gym.env import LidarWorldEnv
from vslam_gym.sim.world import CircleObstacle
from vslam_gym.sim.world_file import load_world, world_to_toml
from vslam_gym.slam.filter import Belief, LandmarkView
from vslam_gym.slam.landmark import LandmarkModel
from vslam_gym.slam_wrapper import SlamWrapper

gym.register_envs(vslam_gym)

EXPLORE_IDS = [vslam_gym.EXPLORE_ID, *vslam_gym.EXPLORE_WORLD_IDS.values()]


def _actions(n: int, seed: int = 0) -> np.ndarray:
    """A fixed, smooth action sequence (forward with a slow weave)."""
    t = np.arange(n)
    return np.stack([np.full(n, 0.6), 0.5 * np.sin(t / 7.0 + seed)], axis=1).astype(np.float32)


def _rollout(env: gym.Env, seed: int, n: int) -> tuple[list[dict], list[float], list[dict]]:
    obs, info = env.reset(seed=seed)
    observations, rewards, infos = [obs], [], [info]
    for action in _actions(n):
        obs, reward, terminated, truncated, info = env.step(action)
        observations.append(obs)
        rewards.append(reward)
        infos.append(info)
        if terminated or truncated:
            break
    return observations, rewards, infos


def _same_observations(a: list[dict], b: list[dict]) -> None:
    assert len(a) == len(b)
    for oa, ob in zip(a, b, strict=True):
        assert oa.keys() == ob.keys()
        for key in oa:
            np.testing.assert_array_equal(oa[key], ob[key], err_msg=key)


def test_registered_ids_wrap_the_world_env():
    for env_id in EXPLORE_IDS:
        env = gym.make(env_id)
        assert isinstance(env, SlamWrapper), env_id
        assert isinstance(env.unwrapped, LidarWorldEnv)
        assert env.spec.max_episode_steps == vslam_gym.EXPLORE_MAX_STEPS[env.unwrapped.world_name]
        env.close()


@pytest.mark.parametrize("env_id", ["VSlam/ExploreSmall-v0", vslam_gym.EXPLORE_ID])
def test_gymnasium_and_sb3_checkers_pass(env_id):
    from stable_baselines3.common.env_checker import check_env as sb3_check_env

    env = gym.make(env_id)
    with pytest.warns(UserWarning, match="different from the unwrapped"):
        gym_check_env(env, skip_render_check=True)
    sb3_check_env(env, warn=True)
    env.close()


def test_observations_keep_shape_dtype_and_stay_in_space():
    env = gym.make("VSlam/ExploreSmall-v0")
    observations, _, _ = _rollout(env, seed=3, n=40)
    space = env.observation_space
    for obs in observations:
        assert space.contains(obs)
        for key, box in space.spaces.items():
            assert obs[key].shape == box.shape and obs[key].dtype == box.dtype
    assert observations[-1]["belief_map"][0].any(), "object lines are drawn after 40 steps"
    assert observations[-1]["status"][0] > 0.0, "landmarks were created"
    env.close()


def test_reward_terms_add_up_and_match_the_formulas():
    env = gym.make("VSlam/ExploreSmall-v0")
    _, rewards, infos = _rollout(env, seed=1, n=30)
    previous_cov = infos[0]["slam_pose_cov"]
    for reward, info in zip(rewards, infos[1:], strict=True):
        terms = info["rewards"]
        assert set(terms) == {"pose_information", "new_boundary", "collision", "time"}
        assert reward == pytest.approx(sum(terms.values()), abs=1e-12)
        expected_info = pose_entropy(previous_cov) - pose_entropy(info["slam_pose_cov"])
        assert terms["pose_information"] == pytest.approx(expected_info, rel=1e-9, abs=1e-12)
        assert terms["new_boundary"] >= 0.0
        assert terms["time"] == -0.01
        assert terms["collision"] == (-1.0 if info["collision"] else 0.0)
        previous_cov = info["slam_pose_cov"]
    assert sum(i["rewards"]["new_boundary"] for i in infos[1:]) > 1.0, "walls were modelled"
    env.close()


def test_segments_and_cells_follow_the_belief_and_are_reused_between_measurements():
    env = gym.make("VSlam/ExploreSmall-v0")
    wrapper = env
    while not isinstance(wrapper, SlamWrapper):
        wrapper = wrapper.env
    env.reset(seed=2)
    reused = 0
    for action in _actions(40):
        before = wrapper._mapped
        env.step(action)
        belief = wrapper.belief
        reused += wrapper._mapped is before
        assert (wrapper._mapped is before) == (not belief.measured)
        fresh = belief_segments(belief, wrapper._unknown_threshold)
        for key, value in fresh.items():
            np.testing.assert_array_equal(wrapper._segments[key], value, err_msg=key)
        cells = boundary_cells(fresh, wrapper.reward_config.boundary_cell)
        np.testing.assert_array_equal(wrapper._cells, cells)
    assert 5 <= reused < 40  # the motion filter skipped some scans, not all
    env.close()


def test_d_opt_and_coverage_presets():
    base = gym.make("VSlam/LidarWorld-v0", world="small")
    env = SlamWrapper(base, reward="d_opt")
    _, rewards, infos = _rollout(env, seed=0, n=15)
    for reward, info in zip(rewards, infos[1:], strict=True):
        assert set(info["rewards"]) == {"collision", "d_opt"}
        d_opt = d_optimality(info["slam_pose_cov"])
        expected = math.tanh(0.01 / d_opt) - (100.0 if info["collision"] else 0.0)
        assert reward == pytest.approx(expected, rel=1e-9)
        assert 0.0 < info["rewards"]["d_opt"] <= 1.0
    env = SlamWrapper(gym.make("VSlam/LidarWorld-v0", world="small"), reward="coverage")
    env.reset(seed=0)
    covered: set[int] = set()
    total = 0.0
    for action in _actions(15):
        _, reward, _, _, info = env.step(action)
        assert set(info["rewards"]) == {"new_boundary"}
        cells = set(boundary_cells(belief_segments(env.belief, 0.5), 0.25).tolist())
        assert reward == pytest.approx(0.25 * len(cells - covered), abs=1e-12)
        covered |= cells
        total += reward
    assert total > 1.0, "walls were modelled"
    assert total == pytest.approx(0.25 * len(covered), abs=1e-9)


def _segments(*lines: tuple[tuple[float, float], tuple[float, float]], unknown=None) -> dict:
    start = np.array([a for a, _ in lines], dtype=float)
    end = np.array([b for _, b in lines], dtype=float)
    flags = np.zeros(len(lines), bool) if unknown is None else np.array(unknown, dtype=bool)
    return {"start": start, "end": end, "unknown": flags}


def test_new_boundary_pays_each_cell_once_so_duplicates_earn_nothing():
    reward = BeliefReward(BeliefRewardConfig.preset("coverage"))
    reward.reset(np.eye(3), boundary_cells(_segments(), 0.25))
    wall = ((0.1, 0.1), (10.1, 0.1))
    first = reward.step(np.eye(3), boundary_cells(_segments(wall), 0.25), False)
    assert first["new_boundary"] == pytest.approx(10.25)  # 41 cells of 0.25 m along 10 m
    # A duplicate landmark of the same wall, 5 cm off, and the wall's unknown
    # continuation: nothing new.
    duplicate = ((0.1, 0.15), (10.1, 0.15))
    unknown = ((10.1, 0.1), (20.1, 0.1))
    cells = boundary_cells(_segments(wall, duplicate, unknown, unknown=[0, 0, 1]), 0.25)
    assert reward.step(np.eye(3), cells, False)["new_boundary"] == 0.0
    # The wall seen 5 m further: about 5 m of new boundary.
    longer = boundary_cells(_segments(((0.1, 0.1), (15.1, 0.1))), 0.25)
    assert reward.step(np.eye(3), longer, False)["new_boundary"] == pytest.approx(5.0)
    # A wall that disappears from the map and comes back is not paid twice.
    reward.step(np.eye(3), boundary_cells(_segments(), 0.25), False)
    assert reward.step(np.eye(3), longer, False)["new_boundary"] == 0.0
    with pytest.raises(ValueError, match="boundary_cell"):
        BeliefRewardConfig(boundary_cell=0.0)


def test_custom_weights_and_bad_configuration():
    env = SlamWrapper(
        gym.make("VSlam/LidarWorld-v0", world="small"),
        reward={"time": 0.5, "pose_information": 0.0},
    )
    _, _, infos = _rollout(env, seed=0, n=3)
    assert infos[-1]["rewards"]["time"] == -0.5
    assert "pose_information" not in infos[-1]["rewards"]
    base = gym.make("VSlam/LidarWorld-v0", world="small")
    with pytest.raises(ValueError, match="did you mean 'time'"):
        SlamWrapper(base, reward={"tme": 1.0})
    with pytest.raises(ValueError, match="unknown reward preset"):
        SlamWrapper(base, reward="entropy")
    with pytest.raises(ValueError, match="raster_cel"):
        SlamWrapper(base, observation={"raster_cel": 0.1})
    with pytest.raises(ValueError, match="preset"):
        SlamWrapper(base, slam_config="fastest")
    with pytest.raises(TypeError, match="LidarWorldEnv"):
        SlamWrapper(gym.make("CartPole-v1"))


def test_same_seed_same_episode_and_pickling():
    a = gym.make("VSlam/ExploreSmall-v0")
    b = gym.make("VSlam/ExploreSmall-v0")
    obs_a, rew_a, _ = _rollout(a, seed=7, n=25)
    obs_b, rew_b, _ = _rollout(b, seed=7, n=25)
    _same_observations(obs_a, obs_b)
    assert rew_a == rew_b
    clone = pickle.loads(pickle.dumps(a))
    action = np.array([0.5, -0.2], np.float32)
    out_a, r_a, *_ = a.step(action)
    out_c, r_c, *_ = clone.step(action)
    _same_observations([out_a], [out_c])
    assert r_a == r_c


def _world_with_far_obstacle(tmp_path) -> str:
    """The `small` world plus a disc 200 m away, beyond every beam's range."""
    world = load_world("small")
    far = CircleObstacle(center=(200.0, 200.0), radius=1.0)
    path = tmp_path / "small.toml"
    path.write_text(world_to_toml(dataclasses.replace(world, obstacles=(*world.obstacles, far))))
    return str(path)


class _CorruptTruth(gym.Wrapper):
    """Replaces every ground-truth entry of ``info`` by garbage."""

    def _corrupt(self, info):
        info = dict(info)
        info["pose"] = np.array([123.0, -45.0, 2.0])
        info["odom_pose"] = np.array([-7.0, 8.0, 1.0])
        info["hit_ids"] = np.full_like(info["hit_ids"], 99)
        info["odometry_true"] = np.array([1.0, 2.0, 3.0])
        info["contact_ids"] = (42,)
        return info

    def reset(self, **kwargs):
        obs, info = self.env.reset(**kwargs)
        return obs, self._corrupt(info)

    def step(self, action):
        obs, reward, terminated, truncated, info = self.env.step(action)
        return obs, reward, terminated, truncated, self._corrupt(info)


def test_ground_truth_does_not_reach_observation_or_reward(tmp_path):
    reference = SlamWrapper(LidarWorldEnv(world="small"))
    obs_ref, rew_ref, info_ref = _rollout(reference, seed=5, n=30)

    far_world = SlamWrapper(LidarWorldEnv(world=_world_with_far_obstacle(tmp_path)))
    obs_far, rew_far, info_far = _rollout(far_world, seed=5, n=30)
    for a, b in zip(info_ref, info_far, strict=True):  # same scans and odometry ...
        np.testing.assert_array_equal(a["odometry_noisy"], b["odometry_noisy"])
    _same_observations(obs_ref, obs_far)  # ... so the same observations and rewards
    assert rew_ref == rew_far

    corrupted = SlamWrapper(_CorruptTruth(LidarWorldEnv(world="small")))
    obs_bad, rew_bad, info_bad = _rollout(corrupted, seed=5, n=30)
    assert info_bad[-1]["pose"][0] == 123.0
    _same_observations(obs_ref, obs_bad)
    assert rew_ref == rew_bad


def test_reset_starts_a_fresh_map_and_start_scan_option():
    env = gym.make("VSlam/ExploreSmall-v0")
    obs, info = env.reset(seed=0)
    assert info["landmarks"] == 0 and not obs["belief_map"].any()
    _rollout(env, seed=0, n=20)
    obs, info = env.reset(seed=1)
    assert info["landmarks"] == 0 and env.get_wrapper_attr("belief").step == 0
    # the default ("matcher"): the first step is aligned to the scan of reset ...
    env.step(np.array([0.5, 0.0], dtype=np.float32))
    assert env.get_wrapper_attr("belief").prealigned
    # ... which "none" ignores: the matcher has nothing to align the first step to
    ignored = SlamWrapper(LidarWorldEnv(world="small"), start_scan="none")
    ignored.reset(seed=1)
    ignored.step(np.array([0.5, 0.0], dtype=np.float32))
    assert not ignored.belief.prealigned
    mapped = SlamWrapper(LidarWorldEnv(world="small"), start_scan="map")
    obs, info = mapped.reset(seed=0)
    assert info["landmarks"] > 0 and obs["belief_map"][0].any()
    with pytest.raises(ValueError, match="start_scan"):
        SlamWrapper(LidarWorldEnv(world="small"), start_scan=True)


def test_info_reports_the_filters_loop_closures():
    env = SlamWrapper(LidarWorldEnv(world="small"), slam_config={"filter": {"loop_min_age": 5}})
    obs, info = env.reset(seed=0)
    assert info["loop_closed"] is False
    rng = np.random.default_rng(0)
    closed = []
    for _ in range(40):
        action = np.array([0.3, rng.uniform(-1.0, 1.0)], dtype=np.float32)
        obs, reward, terminated, truncated, info = env.step(action)
        assert info["loop_closed"] == env.belief.loop_closed
        closed.append(info["loop_closed"])
        if terminated or truncated:
            break
    assert any(closed)  # keyframes 5 updates old are revisited at once
    _, off = SlamWrapper(
        LidarWorldEnv(world="small"), slam_config={"filter": {"loop_closure": False}}
    ).reset(seed=0)
    assert off["loop_closed"] is False


def test_async_vector_env_of_a_registered_id():
    envs = gym.make_vec("VSlam/ExploreSmall-v0", num_envs=2, vectorization_mode="async")
    obs, _ = envs.reset(seed=[0, 1])
    assert obs["belief_map"].shape == (2, 3, 64, 64)
    for action in _actions(5):
        obs, reward, *_ = envs.step(np.stack([action, action]))
    assert reward.shape == (2,) and np.all(np.isfinite(reward))
    envs.close()


def test_render_draws_the_belief_over_the_world():
    env = gym.make("VSlam/ExploreSmall-v0", render_mode="rgb_array")
    _rollout(env, seed=0, n=20)
    frame = env.render()
    plain = env.unwrapped.render()
    assert frame.shape == plain.shape and frame.dtype == np.uint8
    object_blue = np.all(frame == (20, 40, 160), axis=-1)
    assert object_blue.sum() > 50 and not np.all(plain == (20, 40, 160), axis=-1).any()


# ---------------------------------------------------------------- belief observation pieces


def _belief_with_line(start, end, pose, u=0.0, ref_cov=None) -> Belief:
    cov = np.diag([0.01, 0.01, 0.04, 0.04])
    model = LandmarkModel(mean=np.array([start, end], float), cov=cov, u=np.array([u]))
    view = LandmarkView(
        id=0,
        reference=np.array(start, float),
        reference_cov=np.zeros((2, 2)) if ref_cov is None else ref_cov,
        model=model,
        object_vertices=(0, 2),
    )
    pose = np.asarray(pose, float)
    return Belief(0, pose, np.eye(3) * 1e-4, pose, (view,), (), 5, 0.0)


def test_belief_segments_of_open_closed_and_line_less_landmarks():
    # an open chain of 3 vertices, a landmark without lines, a closed triangle
    open_cov = np.diag([0.01, 0.04, 0.09, 0.01, 0.16, 0.25])
    open_cov[0, 2] = open_cov[2, 0] = 0.005  # a cross term: not in the per-vertex sigma
    chain = LandmarkModel(
        mean=np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0]]), cov=open_cov, u=np.array([0.0, 0.9])
    )
    point = LandmarkModel(mean=np.array([[5.0, 5.0]]), cov=np.eye(2), u=np.zeros(0))
    triangle = LandmarkModel(
        mean=np.array([[3.0, 0.0], [4.0, 0.0], [3.0, 1.0]]),
        cov=np.diag([0.04, 0.01, 0.01, 0.01, 0.0, 0.0]),
        u=np.array([0.0, 0.2, 0.7]),
        closed=True,
    )
    ref_covs = [np.diag([0.01, 0.0]), np.eye(2), np.zeros((2, 2))]
    views = tuple(
        LandmarkView(i, m.mean.mean(axis=0), c, m, (0, m.n_vertices))
        for i, (m, c) in enumerate(zip([chain, point, triangle], ref_covs, strict=True))
    )
    belief = Belief(0, np.zeros(3), np.eye(3), np.zeros(3), views, (), 9, 0.0)
    seg = belief_segments(belief, 0.5)
    np.testing.assert_array_equal(seg["start"], [[0, 0], [1, 0], [3, 0], [4, 0], [3, 1]])
    np.testing.assert_array_equal(seg["end"], [[1, 0], [1, 1], [4, 0], [3, 1], [3, 0]])
    np.testing.assert_array_equal(seg["unknown"], [False, True, False, False, True])
    # largest standard deviation of each vertex: its block plus the reference's
    chain_sigma = np.sqrt([0.04, 0.09 + 0.01, 0.25])  # the y variances 0.04, 0.25 are larger
    triangle_sigma = np.sqrt([0.04, 0.01, 0.0])
    np.testing.assert_allclose(seg["sigma_start"], [*chain_sigma[:2], *triangle_sigma])
    np.testing.assert_allclose(
        seg["sigma_end"], [*chain_sigma[1:], *triangle_sigma[1:], triangle_sigma[0]]
    )
    empty = belief_segments(Belief(0, np.zeros(3), np.eye(3), np.zeros(3), (), (), 3, 0.0), 0.5)
    assert empty["start"].shape == empty["end"].shape == (0, 2)
    assert empty["unknown"].dtype == bool and empty["sigma_start"].shape == (0,)


def test_raster_is_egocentric_heading_up():
    config = BeliefObservationConfig(raster_size=64, raster_cell=0.25)
    raster = BeliefRaster(config, unknown_threshold=0.5)
    # a wall 2 m ahead, from 1 m left to 1 m right, robot at the origin heading +x
    image = raster.observe(_belief_with_line((2.0, 1.0), (2.0, -1.0), (0.0, 0.0, 0.0)))
    rows, cols = np.nonzero(image[0])
    assert set(rows) == {32 - 8}  # 2 m ahead = 8 cells above the centre row
    assert cols.min() == 28 and cols.max() == 36  # +-1 m = +-4 cells
    assert not image[1].any()
    # the same wall seen by a robot at (5, 5) heading +y (the wall is now on its right)
    image = raster.observe(_belief_with_line((7.0, 6.0), (7.0, 4.0), (5.0, 5.0, math.pi / 2)))
    rows, cols = np.nonzero(image[0])
    assert set(cols) == {32 + 8}  # 2 m to the right
    assert rows.min() == 28 and rows.max() == 36
    # unknown lines go to channel 1; uncertainty rises from the first vertex to the second
    image = raster.observe(_belief_with_line((2.0, 1.0), (2.0, -1.0), (0, 0, 0), u=0.9))
    assert not image[0].any() and image[1].sum() == image[2][image[1] > 0].size * 255
    levels = image[2][24, 28:37]
    assert 0 < levels[0] < levels[-1]  # vertex 0 at the left (sd 0.1 m) ... vertex 1 (0.2 m)
    assert levels[0] == pytest.approx(1 + 254 * 0.1, abs=3)
    assert levels[-1] == pytest.approx(1 + 254 * 0.2, abs=3)


def test_frontier_targets_nearest_first_with_offset_on_long_lines():
    seg = _segments(
        ((3, -1), (3, 1)),
        ((0, 5), (0, 25)),
        ((1, 1), (1, 1.2)),
        ((-2, 0), (-2, 2)),
        unknown=[1, 1, 1, 0],
    )
    points, distances = frontier_targets(seg, np.zeros(2), min_length=0.3, max_offset=3.0)
    # the 0.2 m line is too short, the object line is no frontier
    assert points.shape == (2, 2)
    np.testing.assert_allclose(distances, [3.0, 5.0])
    np.testing.assert_allclose(points[0], [3.0, 0.0])  # a short line: its midpoint
    np.testing.assert_allclose(points[1], [0.0, 8.0])  # 3 m along from the nearer end
    empty, none = frontier_targets(seg, np.zeros(2), min_length=50.0, max_offset=3.0)
    assert empty.shape == (0, 2) and none.shape == (0,)


def test_frontier_cue_in_the_robot_frame():
    config = BeliefObservationConfig(frontier_count=3, frontier_range=10.0)
    cue = FrontierCue(config)
    seg = _segments(((3, -1), (3, 1)), ((-1, 4), (1, 4)), unknown=[1, 1])
    ahead = cue.observe(seg, np.array([0.0, 0.0, 0.0])).reshape(3, 4)
    np.testing.assert_allclose(ahead[0], [1, 1, 0, 0.3], atol=1e-6)  # 3 m straight ahead
    np.testing.assert_allclose(ahead[1], [1, 0, 1, 0.4], atol=1e-6)  # 4 m to the left
    assert not ahead[2].any()  # no third frontier
    # heading +y: the first line is now to the right, the second straight ahead
    turned = cue.observe(seg, np.array([0.0, 0.0, math.pi / 2])).reshape(3, 4)
    np.testing.assert_allclose(turned[0], [1, 0, -1, 0.3], atol=1e-6)
    np.testing.assert_allclose(turned[1], [1, 1, 0, 0.4], atol=1e-6)
    far = cue.observe(seg, np.array([-50.0, 0.0, 0.0])).reshape(3, 4)
    assert far[0, 3] == 1.0  # clipped
    assert cue.space().contains(far.ravel())
    assert FrontierCue(BeliefObservationConfig(frontier_count=0)).size == 0
    with pytest.raises(ValueError, match="frontier_count"):
        BeliefObservationConfig(frontier_count=-1)
    with pytest.raises(ValueError, match="frontier_range"):
        BeliefObservationConfig(frontier_range=0.0)


def test_frontier_key_is_an_option():
    env = gym.make("VSlam/ExploreSmall-v0")
    assert "frontier" not in env.observation_space.spaces
    env.close()
    env = gym.make(
        vslam_gym.explore_spec("VSlam/ExploreSmall-v0", observation={"frontier_count": 2})
    )
    assert env.observation_space["frontier"].shape == (8,)
    observations, _, _ = _rollout(env, seed=3, n=40)
    assert all(env.observation_space.contains(obs) for obs in observations)
    assert observations[-1]["frontier"][0] == 1.0, "the map has unknown lines after 40 steps"
    env.close()


def test_pose_uncertainty_features_in_the_robot_frame():
    features = PoseUncertainty(BeliefObservationConfig())
    cov = np.diag([0.04, 0.01, 0.0025])  # long axis along world x
    ahead = features.observe(np.array([0.0, 0.0, 0.0]), cov)
    across = features.observe(np.array([0.0, 0.0, math.pi / 2]), cov)
    assert ahead[0] == pytest.approx(math.log(0.04)) and ahead[1] == pytest.approx(math.log(0.01))
    assert ahead[2] == pytest.approx(1.0) and across[2] == pytest.approx(-1.0)  # cos 2a
    assert ahead[4] == pytest.approx(math.log(0.0025))
    assert ahead[5] == ahead[6] == 0.0
    corr = np.array([[0.04, 0.0, 0.006], [0.0, 0.01, 0.0], [0.006, 0.0, 0.0025]])
    out = features.observe(np.zeros(3), corr)
    assert out[5] == pytest.approx(0.006 / math.sqrt(0.04 * 0.0025), rel=1e-6)


def test_reward_config_validation():
    with pytest.raises(ValueError, match="time"):
        BeliefRewardConfig(time=-1.0)
    with pytest.raises(ValueError, match="finite"):
        BeliefRewardConfig(new_boundary=float("nan"))
    assert BeliefRewardConfig.preset("d_opt").collision == 100.0
    assert d_optimality(np.diag([1.0, 4.0, 16.0])) == pytest.approx(4.0)


def test_odometry_alphas_come_from_the_world_unless_the_config_sets_them():
    world_alphas = tuple(load_world("small").odometry.alphas)
    env = SlamWrapper(LidarWorldEnv(world="small"), slam_config={"filter": {"min_set_beams": 6}})
    env.reset(seed=0)
    assert env.slam.config.filter.odometry_alphas == world_alphas
    mine = (0.1, 0.05, 0.05, 0.01)  # a deliberately wrong noise model is kept
    env = SlamWrapper(
        LidarWorldEnv(world="small"), slam_config={"filter": {"odometry_alphas": mine}}
    )
    env.reset(seed=0)
    assert env.slam.config.filter.odometry_alphas == mine != world_alphas


def test_a_noise_free_lidar_is_named_for_the_filter():
    """The simulator takes sigma_range 0; the filter needs noise and says where to set it."""
    env = LidarWorldEnv(world="small", lidar={"sigma_range": 0.0})
    with pytest.raises(ValueError, match=r"\[lidar\] of the world file.*sigma_range"):
        SlamWrapper(env)
