"""Scripted rollouts: drive a world's route with the route follower, through Gymnasium.

Uses only the public API (``gymnasium.make`` and :class:`vslam_gym.control.RouteFollower`).

    python agents/route_rollout.py --world small --episodes 3
"""

from __future__ import annotations

import argparse

import gymnasium as gym
import numpy as np

import vslam_gym
from vslam_gym.control import RouteFollower


def rollout(world: str, seed: int, max_steps: int) -> dict[str, float]:
    """One episode; returns steps, distance driven [m], collisions and return."""
    env = gym.make(vslam_gym.LIDAR_WORLD_ID, world=world, max_episode_steps=max_steps)
    obs, info = env.reset(seed=seed)
    follower = RouteFollower(env.unwrapped.world.route)
    steps, distance, collisions, ret = 0, 0.0, 0, 0.0
    previous = np.asarray(info["pose"][:2])
    terminated = truncated = False
    while not (follower.done or terminated or truncated):
        obs, reward, terminated, truncated, info = env.step(follower(info["pose"]))
        position = np.asarray(info["pose"][:2])
        distance += float(np.hypot(*(position - previous)))
        previous = position
        collisions += int(info["collision"])
        ret += float(reward)
        steps += 1
    env.close()
    return {"steps": steps, "distance_m": distance, "collisions": collisions, "return": ret}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--world", default="house", help="shipped world name or TOML path")
    parser.add_argument("--episodes", type=int, default=1)
    parser.add_argument("--max-steps", type=int, default=3000)
    args = parser.parse_args()
    for seed in range(args.episodes):
        result = rollout(args.world, seed, args.max_steps)
        shown = (f"{k} {v}" if isinstance(v, int) else f"{k} {v:.1f}" for k, v in result.items())
        print(f"seed {seed}: " + ", ".join(shown))


if __name__ == "__main__":
    main()
