"""Behaviour cloning of a scripted agent as PPO's warm start (agents/imitation.py)."""

from __future__ import annotations

import json

import gymnasium as gym
import numpy as np
import pytest

from agents.imitation import (
    Demonstrations,
    _discounted,
    behaviour_clone,
    clone_agent,
    collect_demonstrations,
)
from agents.train_ppo import PpoSettings, train

pytest.importorskip("stable_baselines3")

ENV = "VSlam/ExploreSmall-v0"


def small_ppo(env, hidden, features):
    """A small PPO model on ``env`` (one hidden layer, a small CNN)."""
    from stable_baselines3 import PPO

    return PPO(
        "MultiInputPolicy",
        env,
        n_steps=32,
        batch_size=32,
        policy_kwargs={
            "net_arch": [hidden],
            "features_extractor_kwargs": {"cnn_output_dim": features},
        },
        seed=0,
        device="cpu",
    )


def test_discounted_returns():
    np.testing.assert_allclose(_discounted([1.0, 0.0, 2.0], 0.5), [1.5, 1.0, 2.0])
    assert _discounted([], 0.9).size == 0


def test_demonstrations_have_the_observation_space_and_agent_actions():
    demos = collect_demonstrations(ENV, "wall", steps=40, seed=3, workers=1)
    space = gym.make(ENV).observation_space
    assert len(demos) == 40 and demos.episodes == 1
    assert set(demos.obs) == set(space.spaces)
    for key, sub in space.spaces.items():
        assert demos.obs[key].shape == (40, *sub.shape)
        assert demos.obs[key].dtype == sub.dtype
        assert all(sub.contains(o) for o in demos.obs[key][:5])
    assert demos.actions.shape == (40, 2)
    assert np.all(np.abs(demos.actions) <= 1.0)
    assert np.all(np.isfinite(demos.returns))
    # the wall follower drives forward for most steps
    assert np.mean(demos.actions[:, 0] > 0.0) > 0.5
    with pytest.raises(ValueError, match="steps and workers"):
        collect_demonstrations(ENV, "wall", steps=0)


def test_behaviour_cloning_fits_the_demonstrated_actions():
    demos = collect_demonstrations(ENV, "wall", steps=64, seed=1, workers=1)
    env = gym.make(ENV)
    model = small_ppo(env, hidden=32, features=16)

    def action_error() -> float:
        obs = {k: v for k, v in demos.obs.items()}
        actions, _ = model.predict(obs, deterministic=True)
        return float(np.abs(actions - demos.actions).mean())

    before = action_error()
    losses = behaviour_clone(model, demos, epochs=40, batch_size=32, seed=0)
    after = action_error()
    assert len(losses) == 40 and losses[-1] < losses[0]
    assert after < 0.5 * before, (before, after)
    # with the value term divided by the variance of the returns: finite, and smaller
    normalised = behaviour_clone(model, demos, epochs=1, batch_size=32, normalize_value=True)
    assert np.isfinite(normalised[0]) and normalised[0] < losses[0]
    env.close()


def test_train_with_imitation_saves_the_cloned_policy(tmp_path):
    settings = PpoSettings(n_steps=32, batch_size=16, n_epochs=1, net_arch=(16,), cnn_output_dim=16)
    path = train(
        ENV,
        timesteps=32,
        out=tmp_path,
        n_envs=1,
        settings=settings,
        checkpoint_every=0,
        progress_bar=False,
        subprocesses=False,
        imitate="wall",
        imitation_steps=24,
        imitation_epochs=2,
        imitation_rounds=2,
    )
    assert path.is_file() and (tmp_path / "bc_model.zip").is_file()
    config = json.loads((tmp_path / "train_config.json").read_text())
    assert config["imitation"]["agent"] == "wall"
    rounds = config["imitation"]["rounds"]
    assert [r["steps"] for r in rounds] == [24, 24]
    assert [r["expert_fraction"] for r in rounds] == [1.0, 0.5]
    assert all(len(r["losses"]) == 2 for r in rounds)
    assert (tmp_path / "bc_round0.zip").is_file()  # the clone that drove round 1
    with pytest.raises(ValueError, match="--imitate must be one of"):
        train(ENV, 32, tmp_path / "x", n_envs=1, settings=settings, imitate="nobody")


def test_demonstrations_concatenate_workers():
    demos = collect_demonstrations(ENV, "random", steps=7, seed=2, workers=2)
    assert isinstance(demos, Demonstrations)
    assert len(demos) == 7 and demos.episodes == 2
    assert demos.obs["scan"].shape[0] == 7


def test_dagger_round_is_driven_by_the_policy_and_labelled_by_the_agent(tmp_path):
    """With the clone driving (expert_fraction 0) the recorded labels are still the
    agent's actions, which the policy would not have taken."""
    env = gym.make(ENV)
    model = small_ppo(env, hidden=8, features=8)
    path = str(tmp_path / "policy.zip")
    model.save(path)
    demos = collect_demonstrations(
        ENV, "wall", steps=30, seed=4, workers=1, policy_path=path, expert_fraction=0.0
    )
    policy_actions, _ = model.predict(demos.obs, deterministic=True)
    assert np.abs(policy_actions - demos.actions).mean() > 0.1
    # the agent labels: its forward command is positive on most steps
    assert np.mean(demos.actions[:, 0] > 0.0) > 0.5
    with pytest.raises(ValueError, match="expert_fraction"):
        collect_demonstrations(ENV, "wall", steps=3, expert_fraction=1.5)
    with pytest.raises(ValueError, match="work_dir"):
        clone_agent(model, ENV, "wall", steps=3, rounds=2)
    env.close()


def test_demonstrations_of_a_configured_agent_and_bad_settings(tmp_path):
    """The imitated agent's settings reach the workers; bad ones fail before any work."""
    slow = {"safety": {"cruise_speed": 0.2}}
    fast = collect_demonstrations(ENV, "wall", steps=30, seed=3, workers=1)
    tuned = collect_demonstrations(ENV, "wall", steps=30, seed=3, workers=1, agent_config=slow)
    assert len(tuned) == 30
    # the wall follower drives at its cruise speed: a slower one commands less forward
    assert tuned.actions[:, 0].max() < fast.actions[:, 0].max()
    with pytest.raises(ValueError, match="unknown key 'cruise'"):
        collect_demonstrations(ENV, "wall", steps=30, workers=2, agent_config={"cruise": 1})
    with pytest.raises(ValueError, match="needs an agent to imitate"):
        train(ENV, 10, tmp_path / "a", imitate_config={"reach_distance": 1.0})
    with pytest.raises(ValueError, match="unknown key 'reach'"):
        train(ENV, 10, tmp_path / "b", imitate="frontier", imitate_config={"reach": 1.0})
