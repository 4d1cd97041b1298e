"""Does the belief reward ``new_boundary`` track true coverage, or can duplicates inflate it?

For scripted agents on ``VSlam/Explore-v0`` (a new random world per seed), every step
records two belief-only measures of newly modelled boundary and the ground truth:

- ``cells``: the reward's ``new_boundary`` (object-line cells of a 0.25 m world grid
  crossed for the first time in the episode, times 0.25 m);
- ``length``: the previous definition, the growth of the total object-line length
  beyond its largest value so far (every duplicate landmark pays again);
- ``true``: the growth of the truly covered boundary [m] (coverage, the fraction of the
  true obstacle boundary within 0.1 m of an object line, times the boundary length).

Printed per agent: the sums over all episodes and the ratio of each measure to the true
gain (1 is ideal), and the Pearson correlation of the per-episode sums with the true gain.

Usage::

    python benchmarks/reward_vs_coverage.py [--episodes 10] [--steps 200] [--agents random wall]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import gymnasium as gym
import numpy as np

import vslam_gym
from vslam_gym.belief_observation import belief_segments, object_boundary_length
from vslam_gym.exploration import boundary_samples, coverage

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "agents"))
from scripted import make_agent  # noqa: E402

gym.register_envs(vslam_gym)

SAMPLE_SPACING = 0.05
"""Spacing [m] of the true boundary samples."""


def episode(agent_name: str, seed: int, steps: int) -> dict[str, float]:
    """One episode; the three boundary measures summed over it [m]."""
    env = gym.make("VSlam/Explore-v0")
    obs, info = env.reset(seed=seed)
    agent = make_agent(agent_name, seed=seed)
    agent.reset(env, obs, info, seed=seed)
    samples = boundary_samples(env.unwrapped.world, SAMPLE_SPACING)
    total_true = len(samples.index.points) * SAMPLE_SPACING
    best_length, cells, true = 0.0, 0.0, 0.0
    length_growth = 0.0
    cover = 0.0
    for _ in range(steps):
        obs, _, terminated, truncated, info = env.step(agent.act(obs, info))
        belief = env.get_wrapper_attr("belief")
        cells += info["rewards"].get("new_boundary", 0.0)
        length = object_boundary_length(belief, 0.5, belief_segments(belief, 0.5))
        length_growth += max(0.0, length - best_length)
        best_length = max(best_length, length)
        new_cover = coverage(samples, belief)
        true += max(0.0, new_cover - cover) * total_true
        cover = max(cover, new_cover)
        if terminated or truncated:
            break
    env.close()
    return {"cells": cells, "length": length_growth, "true": true}


def correlation(x: np.ndarray, y: np.ndarray) -> float:
    """Pearson correlation, NaN when either is constant."""
    return float(np.corrcoef(x, y)[0, 1]) if x.std() > 0 and y.std() > 0 else float("nan")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=10)
    parser.add_argument("--steps", type=int, default=200)
    parser.add_argument("--seed", type=int, default=1000)
    parser.add_argument("--agents", nargs="+", default=["random", "wall", "frontier"])
    args = parser.parse_args()
    print(
        f"VSlam/Explore-v0, seeds {args.seed}..{args.seed + args.episodes - 1}, "
        f"{args.steps} steps; sums over the episodes [m]"
    )
    print(
        f"{'agent':10s} {'true':>8s} {'cells':>8s} {'ratio':>6s} {'corr':>6s} "
        f"{'length':>8s} {'ratio':>6s} {'corr':>6s}"
    )
    for name in args.agents:
        rows = [episode(name, args.seed + i, args.steps) for i in range(args.episodes)]
        true, cells, length = (np.array([r[k] for r in rows]) for k in ("true", "cells", "length"))

        print(
            f"{name:10s} {true.sum():8.1f} {cells.sum():8.1f} {cells.sum() / true.sum():6.2f} "
            f"{correlation(cells, true):6.2f} {length.sum():8.1f} {length.sum() / true.sum():6.2f} "
            f"{correlation(length, true):6.2f}"
        )


if __name__ == "__main__":
    main()
