"""Behaviour cloning of a scripted agent into a PPO policy (a warm start for PPO).

A scripted agent (e.g. the belief-driven ``frontier`` heuristic) drives the SLAM-wrapped
environment; its observations and actions are recorded (:func:`collect_demonstrations`,
in worker processes) and the PPO policy is fitted to them by maximum likelihood, its
value head to the discounted belief returns of the demonstrations
(:func:`behaviour_clone`). ``agents/train_ppo.py --imitate frontier`` runs both before
PPO; the policy then sees only what any policy sees (the observation), not the map the
heuristic reads.

    python agents/train_ppo.py --env VSlam/Explore-v0 --imitate frontier
                               --imitation-steps 12000 --max-minutes 28 --out runs/ppo_bc
"""

from __future__ import annotations

import math
import multiprocessing
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

if __package__ in (None, ""):  # run as a script: make the repository root importable
    sys.path.append(str(Path(__file__).resolve().parent.parent))

import gymnasium as gym  # noqa: E402

import vslam_gym  # noqa: E402
from agents.scripted import make_agent  # noqa: E402

DEMONSTRATION_SEED = 5000
"""First world seed of the demonstrations (clear of the held-out 1000-1019)."""


@dataclass
class Demonstrations:
    """Recorded steps of a scripted agent.

    Attributes:
        obs: the observation dict, each entry stacked to ``(N, ...)``.
        actions: ``(N, 2)`` the agent's actions, in ``[-1, 1]``.
        returns: ``(N,)`` discounted belief return from each step to its episode's end.
        episodes: number of (partial) episodes.
    """

    obs: dict[str, np.ndarray]
    actions: np.ndarray
    returns: np.ndarray
    episodes: int

    def __len__(self) -> int:
        return int(self.actions.shape[0])


def _discounted(rewards: list[float], gamma: float) -> np.ndarray:
    out = np.zeros(len(rewards))
    running = 0.0
    for i in range(len(rewards) - 1, -1, -1):
        running = rewards[i] + gamma * running
        out[i] = running
    return out


def _collect(
    env_id: str,
    agent_name: str,
    steps: int,
    seed: int,
    wrapper_kwargs: dict[str, Any],
    gamma: float,
) -> Demonstrations:
    """One worker: ``steps`` steps over episodes on worlds ``seed, seed + 1, ...``."""
    spec = vslam_gym.explore_spec(env_id, **wrapper_kwargs) if wrapper_kwargs else env_id
    env = gym.make(spec)
    agent = make_agent(agent_name, seed)
    obs_list: list[dict[str, np.ndarray]] = []
    actions: list[np.ndarray] = []
    returns: list[np.ndarray] = []
    episodes = 0
    while len(actions) < steps:
        obs, info = env.reset(seed=seed + episodes)
        agent.reset(env, obs, info, seed=seed + episodes)
        episodes += 1
        rewards: list[float] = []
        done = False
        while not done and len(actions) < steps:
            action = np.clip(np.asarray(agent.act(obs, info), dtype=np.float32), -1.0, 1.0)
            obs_list.append(obs)
            actions.append(action)
            obs, reward, terminated, truncated, info = env.step(action)
            rewards.append(float(reward))
            done = terminated or truncated
        returns.append(_discounted(rewards, gamma))
    env.close()
    stacked = {k: np.stack([o[k] for o in obs_list]) for k in obs_list[0]}
    return Demonstrations(stacked, np.stack(actions), np.concatenate(returns), episodes)


def collect_demonstrations(
    env_id: str,
    agent: str,
    steps: int,
    seed: int = DEMONSTRATION_SEED,
    workers: int = 2,
    wrapper_kwargs: dict[str, Any] | None = None,
    gamma: float = 0.99,
) -> Demonstrations:
    """Record ``steps`` steps of a scripted agent, split over ``workers`` processes.

    Worker ``i`` drives worlds ``seed + 1000 i, seed + 1000 i + 1, ...`` (a new world
    per episode on ``VSlam/Explore-v0``).

    Args:
        env_id: a registered exploration id.
        agent: a scripted agent name (``agents.scripted.SCRIPTED_AGENTS``).
        steps: total steps to record (>= 1).
        seed: first world seed.
        workers: processes (1: in this process).
        wrapper_kwargs: ``SlamWrapper`` arguments replacing the registration's
            (``slam_config``, ``reward``).
        gamma: discount of the recorded returns (PPO's).

    Returns:
        The demonstrations, workers concatenated.
    """
    if steps < 1 or workers < 1:
        raise ValueError(f"steps and workers must be >= 1, got {steps} and {workers}")
    kwargs = dict(wrapper_kwargs or {})
    shares = [steps // workers + (1 if i < steps % workers else 0) for i in range(workers)]
    jobs = [
        (env_id, agent, n, seed + 1000 * i, kwargs, gamma) for i, n in enumerate(shares) if n > 0
    ]
    if len(jobs) == 1:
        parts = [_collect(*jobs[0])]
    else:
        with multiprocessing.get_context("spawn").Pool(len(jobs)) as pool:
            parts = pool.starmap(_collect, jobs)
    return Demonstrations(
        {k: np.concatenate([p.obs[k] for p in parts]) for k in parts[0].obs},
        np.concatenate([p.actions for p in parts]),
        np.concatenate([p.returns for p in parts]),
        sum(p.episodes for p in parts),
    )


def behaviour_clone(
    model: Any,
    demos: Demonstrations,
    epochs: int = 10,
    batch_size: int = 256,
    learning_rate: float = 1e-3,
    value_weight: float = 0.5,
    seed: int = 0,
) -> list[float]:
    """Fit a stable-baselines3 actor-critic policy to demonstrations, in place.

    Loss per minibatch: ``-mean log pi(a | o) + value_weight * mean (V(o) - G)^2`` with
    ``G`` the demonstration's discounted return (the value head then starts near the
    demonstrator's values, so that PPO's first updates do not undo the cloning).

    Args:
        model: a PPO model (``model.policy.evaluate_actions``).
        demos: the recorded steps.
        epochs: passes over the data.
        batch_size: minibatch size.
        learning_rate: Adam step size.
        value_weight: weight of the value loss.
        seed: shuffling seed.

    Returns:
        The mean loss of each epoch.
    """
    import torch
    from stable_baselines3.common.utils import obs_as_tensor

    policy = model.policy
    policy.set_training_mode(True)
    optimizer = torch.optim.Adam(policy.parameters(), lr=learning_rate)
    rng = np.random.default_rng(seed)
    n = len(demos)
    history = []
    for _ in range(epochs):
        order = rng.permutation(n)
        total, batches = 0.0, 0
        for start in range(0, n, batch_size):
            idx = order[start : start + batch_size]
            obs = obs_as_tensor({k: v[idx] for k, v in demos.obs.items()}, policy.device)
            actions = torch.as_tensor(demos.actions[idx], device=policy.device)
            returns = torch.as_tensor(demos.returns[idx], dtype=torch.float32)
            values, log_prob, _ = policy.evaluate_actions(obs, actions)
            loss = -log_prob.mean() + value_weight * ((values.flatten() - returns) ** 2).mean()
            optimizer.zero_grad()
            loss.backward()
            torch.nn.utils.clip_grad_norm_(policy.parameters(), 0.5)
            optimizer.step()
            total += float(loss.detach())
            batches += 1
        history.append(total / max(batches, 1))
    policy.set_training_mode(False)
    if not all(math.isfinite(h) for h in history):
        raise FloatingPointError(f"behaviour cloning diverged: epoch losses {history}")
    return history
