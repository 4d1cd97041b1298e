"""Behaviour cloning of a scripted agent into a PPO policy (a warm start for PPO).

A scripted agent (e.g. the belief-driven ``frontier`` heuristic) drives the SLAM-wrapped
environment; its observations and actions are recorded (:func:`collect_demonstrations`,
in worker processes) and the PPO policy is fitted to them by maximum likelihood, its
value head to the discounted belief returns of the demonstrations
(:func:`behaviour_clone`). ``agents/train_ppo.py --imitate frontier`` runs both before
PPO; the policy then sees only what any policy sees (the observation), not the map the
heuristic reads.

A clone drifts into states the demonstrator never visited (close to obstacles, where it
collides). Later rounds are DAgger (Ross et al. 2011): the cloned policy drives (the
agent with probability ``expert_fraction``), the agent labels every visited state with
its own action, and the policy is fitted to all rounds' data.

    python agents/train_ppo.py --env VSlam/Explore-v0 --imitate frontier
                               --imitation-steps 12000 --max-minutes 28 --out runs/ppo_bc
"""

from __future__ import annotations

import math
import multiprocessing
import sys
import time
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

    @staticmethod
    def concatenate(parts: list[Demonstrations]) -> Demonstrations:
        """All steps of ``parts``, in order."""
        return Demonstrations(
            {k: np.concatenate([p.obs[k] for p in parts]) for k in parts[0].obs},
            np.concatenate([p.actions for p in parts]),
            np.concatenate([p.returns for p in parts]),
            sum(p.episodes for p in parts),
        )


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
    policy_path: str | None = None,
    expert_fraction: float = 1.0,
    agent_config: dict[str, Any] | None = None,
) -> Demonstrations:
    """One worker: ``steps`` steps over episodes on worlds ``seed, seed + 1, ...``.

    With ``policy_path`` (a saved PPO model) the policy's deterministic action is executed
    except with probability ``expert_fraction``; the agent's action is recorded always.
    """
    env = gym.make(vslam_gym.explore_spec(env_id, **wrapper_kwargs))
    agent = make_agent(agent_name, seed, agent_config)
    policy = None
    if policy_path is not None:
        from stable_baselines3 import PPO

        policy = PPO.load(policy_path, device="cpu")
    rng = np.random.default_rng(seed)
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
            executed = action
            if policy is not None and rng.random() >= expert_fraction:
                executed = np.asarray(policy.predict(obs, deterministic=True)[0], np.float32)
            obs, reward, terminated, truncated, info = env.step(executed)
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
    policy_path: str | None = None,
    expert_fraction: float = 1.0,
    agent_config: dict[str, Any] | None = None,
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
        policy_path: a saved PPO model that drives instead of the agent (DAgger); the
            agent still labels every step.
        expert_fraction: with ``policy_path``, probability that the agent's own action
            is executed at a step.
        agent_config: the scripted agent's settings (``agents.scripted.make_agent``).

    Returns:
        The demonstrations, workers concatenated.
    """
    if steps < 1 or workers < 1:
        raise ValueError(f"steps and workers must be >= 1, got {steps} and {workers}")
    if not 0.0 <= expert_fraction <= 1.0:
        raise ValueError(f"expert_fraction must lie in [0, 1], got {expert_fraction}")
    kwargs = dict(wrapper_kwargs or {})
    make_agent(agent, seed, agent_config)  # bad settings fail here, not in a worker
    shares = [steps // workers + (1 if i < steps % workers else 0) for i in range(workers)]
    jobs = [
        (
            env_id,
            agent,
            n,
            seed + 1000 * i,
            kwargs,
            gamma,
            policy_path,
            expert_fraction,
            agent_config,
        )
        for i, n in enumerate(shares)
        if n > 0
    ]
    if len(jobs) == 1:
        parts = [_collect(*jobs[0])]
    else:
        with multiprocessing.get_context("spawn").Pool(len(jobs)) as pool:
            parts = pool.starmap(_collect, jobs)
    return Demonstrations.concatenate(parts)


def behaviour_clone(
    model: Any,
    demos: Demonstrations,
    epochs: int = 10,
    batch_size: int = 256,
    learning_rate: float = 1e-3,
    value_weight: float = 0.5,
    seed: int = 0,
    normalize_value: bool = False,
) -> list[float]:
    """Fit a stable-baselines3 actor-critic policy to demonstrations, in place.

    Loss per minibatch: ``-mean log pi(a | o) + value_weight * mean (V(o) - G)^2`` with
    ``G`` the demonstration's discounted return (the value head then starts near the
    demonstrator's values, so that PPO's first updates do not undo the cloning). With
    ``normalize_value`` the value term is divided by ``var(G)``, so that it cannot swamp
    the policy term whatever the reward scale. Off: the best PPO run (docs/status.md,
    "Exploration on random worlds"; coverage 0.183) cloned without it; the two runs with
    it, both with DAgger rounds, fell to 0.092 and 0.126 under PPO (a comparison
    confounded by DAgger and the reward).

    Args:
        model: a PPO model (``model.policy.evaluate_actions``).
        demos: the recorded steps.
        epochs: passes over the data.
        batch_size: minibatch size.
        learning_rate: Adam step size.
        value_weight: weight of the value loss.
        seed: shuffling seed.
        normalize_value: divide the value loss by the variance of the returns.

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
    value_scale = value_weight
    if normalize_value:
        value_scale /= max(float(np.var(demos.returns)), 1e-6)
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
            loss = -log_prob.mean() + value_scale * ((values.flatten() - returns) ** 2).mean()
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


def clone_agent(
    model: Any,
    env_id: str,
    agent: str,
    steps: int,
    rounds: int = 1,
    epochs: int = 10,
    workers: int = 2,
    wrapper_kwargs: dict[str, Any] | None = None,
    gamma: float = 0.99,
    expert_fraction: float = 0.5,
    work_dir: Path | None = None,
    seed: int = 0,
    agent_config: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """Fit ``model``'s policy to a scripted agent: behaviour cloning, then DAgger rounds.

    Round 0 records ``steps`` steps of the agent driving; each later round records
    ``steps`` steps driven by the current clone (the agent's action executed with
    probability ``expert_fraction``) and labelled by the agent, and refits the policy
    to all rounds' steps (:func:`behaviour_clone`, ``epochs`` passes). Round ``r`` drives
    worlds from ``DEMONSTRATION_SEED + 200 r`` (worker ``i``: plus ``1000 i``).

    Args:
        model: a PPO model, fitted in place.
        env_id, agent, workers, wrapper_kwargs, gamma, agent_config: see
            :func:`collect_demonstrations`.
        steps: steps recorded per round.
        rounds: 1 (behaviour cloning only) or more.
        epochs: cloning passes per round.
        expert_fraction: the agent's share of the driving in DAgger rounds.
        work_dir: where the clone of each round is saved for the workers (needed when
            ``rounds > 1``).
        seed: shuffling seed.

    Returns:
        A record per round: steps, episodes, losses, collection and fitting seconds.
    """
    if rounds < 1:
        raise ValueError(f"rounds must be >= 1, got {rounds}")
    if rounds > 1 and work_dir is None:
        raise ValueError("DAgger rounds need a work_dir for the intermediate policies")
    parts: list[Demonstrations] = []
    record: list[dict[str, Any]] = []
    for r in range(rounds):
        tick = time.perf_counter()
        policy_path = None
        if r > 0:
            assert work_dir is not None
            policy_path = str(work_dir / f"bc_round{r - 1}.zip")
            model.save(policy_path)
        parts.append(
            collect_demonstrations(
                env_id,
                agent,
                steps,
                seed=DEMONSTRATION_SEED + 200 * r,
                workers=workers,
                wrapper_kwargs=wrapper_kwargs,
                gamma=gamma,
                policy_path=policy_path,
                expert_fraction=expert_fraction if r > 0 else 1.0,
                agent_config=agent_config,
            )
        )
        collected = time.perf_counter()
        losses = behaviour_clone(model, Demonstrations.concatenate(parts), epochs, seed=seed + r)
        record.append(
            {
                "round": r,
                "steps": len(parts[-1]),
                "episodes": parts[-1].episodes,
                "expert_fraction": expert_fraction if r > 0 else 1.0,
                "losses": losses,
                "collect_s": collected - tick,
                "clone_s": time.perf_counter() - collected,
            }
        )
    return {"agent": agent, "agent_config": dict(agent_config or {}), "rounds": record}
