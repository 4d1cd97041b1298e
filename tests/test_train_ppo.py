"""PPO smoke run on the SLAM-wrapped environment: train, save, load, act."""

from __future__ import annotations

import json

import gymnasium as gym
import numpy as np
import pytest

import vslam_gym
from agents.evaluate_agents import evaluate_agent
from agents.train_ppo import PpoSettings, main, train

pytest.importorskip("stable_baselines3")


def test_ppo_smoke_run_saves_a_model_that_acts(tmp_path):
    from stable_baselines3 import PPO

    settings = PpoSettings(n_steps=64, batch_size=32, n_epochs=1, net_arch=(16,), cnn_output_dim=16)
    path = train(
        "VSlam/ExploreSmall-v0",
        timesteps=128,
        out=tmp_path,
        n_envs=1,
        seed=0,
        settings=settings,
        checkpoint_every=64,
        progress_bar=False,
        subprocesses=False,
    )
    assert path.is_file()
    assert sorted(p.name for p in (tmp_path / "checkpoints").iterdir()) == [
        "ppo_128_steps.zip",
        "ppo_64_steps.zip",
    ]
    config = json.loads((tmp_path / "train_config.json").read_text())
    assert config["timesteps"] == 128 and config["steps_per_s"] > 0
    # one row of PPO statistics per rollout (2 rollouts of 64 steps), in the run's folder
    progress = (tmp_path / "logs" / "progress.csv").read_text().splitlines()
    assert len(progress) == 3 and "train/entropy_loss" in progress[0]
    model = PPO.load(path, device="cpu")
    env = gym.make("VSlam/ExploreSmall-v0")
    obs, _ = env.reset(seed=3)
    for _ in range(5):
        action, _ = model.predict(obs, deterministic=True)
        assert env.action_space.contains(action.astype(np.float32))
        obs, reward, terminated, truncated, info = env.step(action)
        assert np.isfinite(reward) and reward == pytest.approx(sum(info["rewards"].values()))
    env.close()
    summary = evaluate_agent(
        path, "VSlam/ExploreSmall-v0", episodes=1, seed=0, max_steps=8, progress=False,
        out_dir=tmp_path / "eval",
    )  # fmt: skip
    episode = summary["per_episode"][0]
    assert episode["steps"] == 8 and 0.0 <= episode["coverage"] <= 1.0
    assert (tmp_path / "eval" / "metrics.json").is_file()


def _stopped_at_once(out, reward: str) -> list[str]:
    """Command line of a tiny run with ``--reward reward`` that the wall clock stops at once."""
    return [
        "--env", "VSlam/ExploreSmall-v0", "--timesteps", "64", "--n-envs", "1",
        "--n-steps", "64", "--batch-size", "32", "--reward", reward,
        "--checkpoint-every", "0", "--no-progress", "--out", str(out), "--max-minutes", "0",
    ]  # fmt: skip


def test_command_line_with_another_reward_preset(tmp_path, capsys):
    code = main(_stopped_at_once(tmp_path, "d_opt"))
    assert code == 0
    assert "saved" in capsys.readouterr().out
    config = json.loads((tmp_path / "train_config.json").read_text())
    assert config["reward"] == "d_opt" and config["env_id"] == "VSlam/ExploreSmall-v0"
    assert config["trained_timesteps"] == 1  # the wall-clock limit stopped it at once
    assert (tmp_path / "final_model.zip").is_file()
    monitor = (tmp_path / "monitor" / "0.monitor.csv").read_text()
    assert monitor.startswith("#") and vslam_gym.__version__ == config["vslam_gym"]


def test_reward_weights_as_json(tmp_path):
    from agents.train_ppo import make_env_fn

    code = main(_stopped_at_once(tmp_path, '{"collision": 10}'))
    assert code == 0
    assert json.loads((tmp_path / "train_config.json").read_text())["reward"] == {"collision": 10}
    env = make_env_fn("VSlam/ExploreSmall-v0", 0, {"collision": 10})()
    try:
        config = env.get_wrapper_attr("reward_config")
        assert config.collision == 10 and config.new_boundary == 1.0  # others: the defaults
    finally:
        env.close()
    with pytest.raises(SystemExit):
        main(["--out", str(tmp_path / "bad"), "--reward", "{collision: 10}"])


def test_make_env_fn_applies_the_slam_preset():
    from agents.train_ppo import make_env_fn

    env = make_env_fn("VSlam/ExploreSmall-v0", 0, None, "fast")()
    env.reset(seed=0)
    try:
        slam = env.get_wrapper_attr("slam")
        assert slam.config.filter.association_pose == "predicted_first"
        assert slam.config.filter.measurement_min_travel == 0.2
    finally:
        env.close()
    plain = make_env_fn("VSlam/ExploreSmall-v0", 0, "coverage")()
    plain.reset(seed=0)
    try:
        assert plain.get_wrapper_attr("slam").config.filter.association_pose == "icp"  # default
    finally:
        plain.close()


def test_a_policy_trained_with_the_frontier_cue_is_evaluated_with_it(tmp_path):
    from stable_baselines3 import PPO

    settings = PpoSettings(n_steps=32, batch_size=32, n_epochs=1, net_arch=(16,), cnn_output_dim=16)
    path = train(
        "VSlam/ExploreSmall-v0", timesteps=32, out=tmp_path, n_envs=1, seed=0,
        settings=settings, checkpoint_every=0, progress_bar=False, subprocesses=False,
        frontier_cue=2,
    )  # fmt: skip
    assert json.loads((tmp_path / "train_config.json").read_text())["frontier_cue"] == 2
    assert PPO.load(path, device="cpu").observation_space["frontier"].shape == (8,)
    summary = evaluate_agent(
        path, "VSlam/ExploreSmall-v0", episodes=1, seed=0, max_steps=4, progress=False
    )
    assert summary["per_episode"][0]["steps"] == 4


def test_shield_flag_reaches_training_and_evaluation(tmp_path):
    from agents.evaluate_agents import main as evaluate_main
    from agents.train_ppo import make_env_fn

    code = main([*_stopped_at_once(tmp_path, "default"), "--shield"])
    assert code == 0
    assert json.loads((tmp_path / "train_config.json").read_text())["shield"] is True
    env = make_env_fn("VSlam/ExploreSmall-v0", 0, None, shield=True)()
    try:
        assert env.get_wrapper_attr("shield_config") is not None
    finally:
        env.close()
    out = tmp_path / "eval"
    args = ["--agent", "random", "--env", "VSlam/ExploreSmall-v0", "--episodes", "1"]
    args += ["--max-steps", "3", "--out", str(out), "--shield", "--no-progress"]
    assert evaluate_main(args) == 0
    summary = json.loads((out / "metrics.json").read_text())
    assert summary["shield"] is True and summary["per_episode"][0]["steps"] == 3
