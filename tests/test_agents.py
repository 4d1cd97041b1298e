"""Scripted agents (agents/scripted.py) and evaluation rollouts (agents/evaluate_agents.py)."""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path
from types import SimpleNamespace

import gymnasium as gym
import numpy as np
import pytest

import vslam_gym
from agents.evaluate_agents import (
    TIMING_KEYS,
    PolicyAgent,
    build_parser,
    evaluate_agent,
    main,
    resolve_agent,
    run_agent_episode,
    training_differences,
)
from agents.scripted import (
    SCRIPTED_AGENTS,
    FrontierAgent,
    FrontierConfig,
    RandomAgent,
    RouteAgent,
    SafetyConfig,
    ScanNavigator,
    WallFollower,
    WallFollowerConfig,
    make_agent,
)
from vslam_gym.replay import replay
from vslam_gym.sim.world import LidarSpec, RobotSpec, World
from vslam_gym.slam.filter import LandmarkView
from vslam_gym.slam.landmark import LandmarkModel

gym.register_envs(vslam_gym)

SMALL = vslam_gym.EXPLORE_WORLD_IDS["small"]
LIDAR = LidarSpec()
BEARINGS = LIDAR.bearings
RADIUS = 0.2


def fake_env(belief=None, route=None) -> SimpleNamespace:
    """The few attributes the agents read: robot and lidar specs (and a belief)."""
    world = World(name="fake", robot=RobotSpec(start=(0.0, 0.0, 0.0), radius=RADIUS), route=route)
    return SimpleNamespace(
        unwrapped=SimpleNamespace(world=world, lidar_spec=LIDAR),
        get_wrapper_attr=lambda name: {"belief": belief}[name],
    )


def scan_of_lines(lines) -> np.ndarray:
    """Normalised scan of infinite lines ``n . p = c`` (robot frame), nearest return."""
    ranges = np.full(len(BEARINGS), LIDAR.max_range)
    u = np.stack([np.cos(BEARINGS), np.sin(BEARINGS)], axis=1)
    for normal, offset in lines:
        along = u @ np.asarray(normal, dtype=float)
        with np.errstate(divide="ignore"):
            r = np.where(along > 1e-9, offset / along, np.inf)
        ranges = np.minimum(ranges, np.where(r > 0, r, np.inf))
    return (np.minimum(ranges, LIDAR.max_range) / LIDAR.max_range).astype(np.float32)


INFO = {"bearings": BEARINGS}


# ---------------------------------------------------------------------------- scan geometry


def test_free_length_in_front_of_a_wall() -> None:
    nav = ScanNavigator(SafetyConfig(margin=0.1), RADIUS, LIDAR.max_range, BEARINGS)
    nav.update(scan_of_lines([((1.0, 0.0), 2.0)]))  # wall across, 2 m ahead
    free = nav.free_length(np.radians([0.0, 60.0]))
    assert free[0] == pytest.approx(2.0 - 0.3, abs=0.02)
    assert free[1] == pytest.approx(2.0 / math.cos(math.radians(60)) - 0.3 / 0.5, abs=0.1)
    nav.update(np.ones(len(BEARINGS), np.float32))  # nothing in range
    assert nav.free_length(np.zeros(1))[0] == LIDAR.max_range


def test_navigator_stops_before_an_obstacle_and_turns_to_a_gap() -> None:
    nav = ScanNavigator(SafetyConfig(), RADIUS, LIDAR.max_range, BEARINGS)
    nav.update(scan_of_lines([((1.0, 0.0), 0.35)]))  # wall 0.35 m ahead: blocked
    action = nav.steer(0.0)
    assert action[0] == 0.0 and abs(action[1]) > 0.0
    # wall ahead only on the left half: the free heading is to the right
    nav.update(scan_of_lines([((1.0, 0.0), 0.8)]) * (BEARINGS > 0) + (BEARINGS <= 0))
    action = nav.steer(0.0)
    assert action[1] < 0.0
    # a goal behind: turn on the spot towards it
    np.testing.assert_array_equal(nav.steer(math.radians(170)), [0.0, 1.0])


def test_a_turn_on_the_spot_keeps_its_direction_until_the_robot_drives() -> None:
    nav = ScanNavigator(SafetyConfig(turn_lock_steps=3), RADIUS, LIDAR.max_range, BEARINGS)
    nav.update(np.ones(len(BEARINGS), np.float32))
    assert nav.steer(math.radians(120))[1] == 1.0
    assert nav.steer(math.radians(-120))[1] == 1.0  # locked: no dithering
    assert nav.steer(math.radians(-120))[1] == 1.0
    assert nav.steer(math.radians(-120))[1] == -1.0  # the lock expires after 3 steps
    assert nav.steer(0.0)[0] > 0.0  # driving releases it
    assert nav.steer(math.radians(100))[1] == 1.0


# ---------------------------------------------------------------------------- agents


@pytest.mark.parametrize(
    ("offset", "turn_sign"),
    [(0.7, 0.0), (2.0, -1.0), (0.35, 1.0)],  # at the set distance, too far, too close
)
def test_wall_follower_keeps_the_wall_on_its_right(offset: float, turn_sign: float) -> None:
    agent = WallFollower(WallFollowerConfig(distance=0.5, lost_distance=2.5))
    agent.reset(fake_env(), {}, INFO)
    action = agent.act({"scan": scan_of_lines([((0.0, -1.0), offset)])}, INFO)  # y = -offset
    assert action.dtype == np.float32 and action.shape == (2,)
    assert action[0] > 0.3
    if turn_sign == 0.0:
        assert abs(action[1]) < 0.05
    else:
        assert np.sign(action[1]) == turn_sign and abs(action[1]) > 0.1


def test_wall_follower_turns_left_at_an_inner_corner_and_searches_when_lost() -> None:
    agent = WallFollower()
    agent.reset(fake_env(), {}, INFO)
    corner = scan_of_lines([((0.0, -1.0), 0.7), ((1.0, 0.0), 0.5)])
    assert agent.act({"scan": corner}, INFO)[1] > 0.5
    lost = agent.act({"scan": np.ones(len(BEARINGS), np.float32)}, INFO)
    assert lost[0] > 0.0 and lost[1] == pytest.approx(-agent.config.search_turn)
    left = WallFollower(WallFollowerConfig(side="left"))
    left.reset(fake_env(), {}, INFO)
    assert left.act({"scan": np.ones(len(BEARINGS), np.float32)}, INFO)[1] > 0.0
    with pytest.raises(ValueError, match="side"):
        WallFollowerConfig(side="up")


def test_random_agent_is_seeded_and_uniform() -> None:
    def actions(agent_seed: int, episode_seed: int) -> np.ndarray:
        agent = RandomAgent(agent_seed)
        agent.reset(fake_env(), {}, INFO, seed=episode_seed)
        return np.array([agent.act({}, INFO) for _ in range(2000)])

    first = actions(0, 5)
    np.testing.assert_array_equal(first, actions(0, 5))
    assert not np.array_equal(first, actions(0, 6))
    assert not np.array_equal(first, actions(1, 5))
    assert first.dtype == np.float32 and np.all(np.abs(first) <= 1.0)
    assert np.abs(first.mean(axis=0)).max() < 0.05
    assert first.std(axis=0) == pytest.approx(np.full(2, 1 / math.sqrt(3)), abs=0.03)


def _belief(polylines, unknown) -> SimpleNamespace:
    landmarks = []
    for i, (vertices, u) in enumerate(zip(polylines, unknown, strict=True)):
        mean = np.asarray(vertices, dtype=float)
        model = LandmarkModel(mean, 1e-6 * np.eye(2 * len(mean)), np.asarray(u, float), False)
        landmarks.append(LandmarkView(i, mean[0], 1e-6 * np.eye(2), model, (0, len(mean))))
    return SimpleNamespace(landmarks=tuple(landmarks))


def test_frontier_agent_heads_for_the_nearest_unknown_line() -> None:
    belief = _belief(
        [
            [(3.0, 2.0), (3.0, 4.0)],  # unknown, 3.6 m away, ahead-left
            [(-6.0, -1.0), (-6.0, 1.0)],  # unknown, 6 m away, behind
            [(1.0, -1.5), (1.0, -0.5)],  # object line: not a target
            [(0.5, 20.0), (0.5, 40.0)],  # unknown, long: target 3 m from its near end
        ],
        [[1.0], [1.0], [0.0], [1.0]],
    )
    agent = FrontierAgent(FrontierConfig(unknown_threshold=0.5))
    env = fake_env(belief)
    agent.reset(env, {}, INFO)
    points, distance = agent.candidates(belief, np.zeros(2))
    np.testing.assert_allclose(points, [[3.0, 3.0], [-6.0, 0.0], [0.5, 23.0]])
    np.testing.assert_allclose(distance, [math.hypot(3, 2), 6.0, math.hypot(0.5, 20.0)], rtol=0.01)
    scan = {"scan": np.ones(len(BEARINGS), np.float32)}
    action = agent.act(scan, {**INFO, "slam_pose": np.zeros(3)})
    np.testing.assert_allclose(agent.target, [3.0, 3.0])
    assert action[0] > 0.0 and action[1] > 0.0  # forward, turning left towards it
    # reached: the next nearest line becomes the target and the first is not chosen again
    agent.act(scan, {**INFO, "slam_pose": np.array([2.8, 2.6, 0.0])})
    agent.act(scan, {**INFO, "slam_pose": np.array([2.8, 2.6, 0.0])})
    assert agent.targets_reached == 1
    np.testing.assert_allclose(agent.target, [-6.0, 0.0])


def test_frontier_agent_gives_up_a_target_without_progress() -> None:
    belief = _belief([[(3.0, -1.0), (3.0, 1.0)]], [[1.0]])
    config = FrontierConfig(unknown_threshold=0.5, progress_steps=5)
    agent = FrontierAgent(config)
    agent.reset(fake_env(belief), {}, INFO)
    blocked = {"scan": scan_of_lines([((1.0, 0.0), 0.4)])}
    for _ in range(8):
        agent.act(blocked, {**INFO, "slam_pose": np.zeros(3)})
    assert agent.targets_abandoned == 1
    # with every line visited it falls back to wall following (a wall 0.4 m ahead: turn)
    action = agent.act(blocked, {**INFO, "slam_pose": np.zeros(3)})
    assert agent.target is None and action[0] == 0.0 and action[1] != 0.0


def test_factory_and_route_agent_errors() -> None:
    assert {type(make_agent(name)).__name__ for name in SCRIPTED_AGENTS} == {
        "RandomAgent",
        "RouteAgent",
        "WallFollower",
        "FrontierAgent",
    }
    with pytest.raises(ValueError, match="unknown agent"):
        make_agent("teleport")
    with pytest.raises(ValueError, match="no route"):
        RouteAgent().reset(fake_env(), {}, INFO)
    with pytest.raises(ValueError, match="neither"):
        resolve_agent("no/such/model.zip")


# ---------------------------------------------------------------------------- episodes


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(SCRIPTED_AGENTS))
def test_scripted_agent_drives_an_episode_on_small_without_collision(name: str) -> None:
    env = gym.make(SMALL)
    result = run_agent_episode(env, make_agent(name, seed=0), seed=0, max_steps=200)
    env.close()
    m = result.metrics
    assert m["steps"] == 200 and not m["terminated"]
    assert m["collisions"] == 0
    assert m["distance_m"] > (0.5 if name == "random" else 5.0)
    assert 0.0 < m["coverage"] <= 1.0


def test_short_rollouts_of_every_scripted_agent() -> None:
    env = gym.make(SMALL)
    for name in sorted(SCRIPTED_AGENTS):
        result = run_agent_episode(env, make_agent(name, seed=0), seed=1, max_steps=12)
        m = result.metrics
        assert m["steps"] == 12 and m["collisions"] == 0, name
        assert len(result.rows) == 13 and result.rows[0]["step"] == 0
        coverages = np.array([r["coverage"] for r in result.rows])
        assert coverages[0] == 0.0 and np.all(coverages <= 1.0)
        assert m["coverage"] == coverages[-1] > 0.0, name
    env.close()


def test_evaluate_writes_files_and_repeats_exactly(tmp_path: Path) -> None:
    args = ["--agent", "random", "--env", SMALL, "--episodes", "2", "--seed", "7"]
    args += ["--max-steps", "10", "--no-progress", "--video"]
    assert main([*args, "--out", str(tmp_path / "a")]) == 0
    first = json.loads((tmp_path / "a" / "metrics.json").read_text())
    for name in ("metrics.json", "steps.csv", "metrics.md", "episode.gif"):
        assert (tmp_path / "a" / name).stat().st_size > 0
    assert [m["seed"] for m in first["per_episode"]] == [7, 8]
    assert first["mean"]["steps"] == 10
    with open(tmp_path / "a" / "steps.csv") as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == 2 * 11
    assert {"true_x", "slam_theta", "reward", "r_time", "coverage", "collision"} <= set(rows[0])
    terms = [k for k in rows[5] if k.startswith("r_")]
    assert float(rows[5]["reward"]) == pytest.approx(sum(float(rows[5][k]) for k in terms))
    assert float(rows[10]["coverage"]) == first["per_episode"][0]["coverage"]

    second = evaluate_agent(
        "random", SMALL, episodes=2, seed=7, max_steps=10, out_dir=tmp_path / "b", progress=False
    )

    def strip(metrics: dict) -> list[dict]:
        return [{k: v for k, v in m.items() if k not in TIMING_KEYS} for m in metrics]

    assert strip(second["per_episode"]) == strip(first["per_episode"])
    csv_a = (tmp_path / "a" / "steps.csv").read_text()
    assert (tmp_path / "b" / "steps.csv").read_text() == csv_a
    assert first["start_scan"] == "registered"

    # --start-scan none: the same paths (random actions), another belief
    args_none = [*args[:-1], "--start-scan", "none", "--out", str(tmp_path / "c")]
    assert main(args_none) == 0
    ignored = json.loads((tmp_path / "c" / "metrics.json").read_text())
    assert ignored["start_scan"] == "none"
    with open(tmp_path / "c" / "steps.csv") as f:
        rows_none = list(csv.DictReader(f))
    assert [r["true_x"] for r in rows_none] == [r["true_x"] for r in rows]
    assert [r["slam_x"] for r in rows_none] != [r["slam_x"] for r in rows]


def test_a_model_with_predict_is_an_agent() -> None:
    class Model:
        def predict(self, obs, deterministic=False):
            assert deterministic
            return np.array([0.5, -0.25]), None

    agent = resolve_agent(Model())
    assert isinstance(agent, PolicyAgent)
    action = agent.act({"scan": np.ones(3)}, {})
    assert action.dtype == np.float32 and action.tolist() == [0.5, -0.25]


@pytest.mark.slow
def test_a_saved_ppo_model_evaluates(tmp_path: Path) -> None:
    sb3 = pytest.importorskip("stable_baselines3")
    env = gym.make(SMALL)
    model = sb3.PPO(
        "MultiInputPolicy", env, n_steps=8, batch_size=8, policy_kwargs={"net_arch": [8]}
    )
    path = tmp_path / "ppo.zip"
    model.save(path)
    env.close()
    result = evaluate_agent(str(path), SMALL, episodes=1, seed=0, max_steps=5, progress=False)
    assert result["per_episode"][0]["steps"] == 5
    assert isinstance(resolve_agent(str(path)), PolicyAgent)
    again = evaluate_agent(model, SMALL, episodes=1, seed=0, max_steps=5, progress=False)
    assert again["per_episode"][0]["ate_m"] == result["per_episode"][0]["ate_m"]


def test_carmen_logs_replay_the_closed_loop_run(tmp_path: Path) -> None:
    """An episode written with ``--carmen-logs`` and replayed follows the rollout's belief.

    The replay gets the same scans and, up to round-off, the same odometry increments,
    and uses the reset's scan as the wrapper does (``start_scan="matcher"``).
    """
    args = ["--agent", "frontier", "--env", vslam_gym.EXPLORE_ID, "--episodes", "1"]
    args += ["--seed", "1000", "--max-steps", "40", "--shield", "--no-progress"]
    assert main([*args, "--carmen-logs", "--out", str(tmp_path)]) == 0
    closed = json.loads((tmp_path / "metrics.json").read_text())
    assert closed["carmen_logs"] is True
    path = tmp_path / "logs" / "episode_1000.log.gz"
    result = replay(path, odometry="logged", start_scan="matcher")
    metrics = result["metrics"]
    assert metrics["completed"] and metrics["scans"] == 41
    with open(tmp_path / "steps.csv") as f:
        rows = list(csv.DictReader(f))
    loop = np.array([[float(r["slam_x"]), float(r["slam_y"])] for r in rows])
    assert np.abs(result["slam"][:, :2] - loop).max() < 1e-4  # round-off grows, slowly
    true = np.array([[float(r["true_x"]), float(r["true_y"])] for r in rows])
    np.testing.assert_allclose(result["true"][:, :2], true, atol=1e-12)
    episode = closed["per_episode"][0]
    assert metrics["ate_rmse_m"] == pytest.approx(episode["ate_m"], abs=1e-4)
    assert 0.0 < metrics["nees_mean"] < 100.0 and 0.0 <= metrics["nees_in_band_fraction"] <= 1.0
    with pytest.raises(ValueError, match="carmen_logs=True needs an out_dir"):
        evaluate_agent("random", vslam_gym.EXPLORE_ID, episodes=1, carmen_logs=True)


def test_evaluating_a_model_names_the_training_options_it_leaves_out(tmp_path):
    model = tmp_path / "final_model.zip"
    model.write_bytes(b"")
    trained = {"shield": True, "slam_preset": "fast", "reward": {"collision": 10}}
    (tmp_path / "train_config.json").write_text(json.dumps(trained))
    bare = build_parser().parse_args(["--agent", str(model), "--out", str(tmp_path / "o")])
    assert training_differences(str(model), bare) == [
        "--shield",
        "--slam-config fast",
        "--reward '{\"collision\": 10}'",
    ]
    same = build_parser().parse_args(
        ["--agent", str(model), "--out", "o", "--shield", "--slam-config", "fast"]
        + ["--reward", '{"collision": 10}']
    )
    assert same.reward == {"collision": 10}  # JSON weights, as train_ppo.py takes them
    assert training_differences(str(model), same) == []
    assert training_differences("frontier", bare) == []  # scripted agents: nothing to read


def test_an_env_without_the_slam_wrapper_is_named(tmp_path):
    with pytest.raises(ValueError, match="VSlam/LidarWorld-v0 has no SLAM wrapper"):
        evaluate_agent("random", env_id="VSlam/LidarWorld-v0", episodes=1, out_dir=tmp_path)


def test_scripted_agents_take_their_settings_by_name():
    agent = make_agent("frontier", config={"reach_distance": 0.5, "safety": {"margin": 0.2}})
    assert agent.config.reach_distance == 0.5 and agent.config.safety.margin == 0.2
    assert agent.config.wall == make_agent("frontier").config.wall  # the rest as default
    assert make_agent("wall", config={"safety": {"margin": 0.3}}).config.safety.margin == 0.3
    with pytest.raises(ValueError, match=r"frontier agent\.safety: unknown key 'marg'"):
        make_agent("frontier", config={"safety": {"marg": 0.2}})
    with pytest.raises(ValueError, match="random agent has no settings"):
        make_agent("random", config={"speed": 1})
    with pytest.raises(ValueError, match="reach_distance must be > 0"):
        make_agent("frontier", config={"reach_distance": -1.0})
    with pytest.raises(ValueError, match="scripted agents by name"):
        resolve_agent(RandomAgent(), agent_config={"reach_distance": 0.5})
