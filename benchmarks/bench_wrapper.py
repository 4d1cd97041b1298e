"""Reset time and throughput of the SLAM-wrapped environment (issue #5 targets).

For each exploration id: the median wall time of ``reset(seed=s)`` over repeats (a new
world for ``VSlam/Explore-v0``, always a fresh SLAM), and the steps per second of
``step()`` in one process, driven by a simple reactive policy (forward, turning away
from the nearest return ahead) so that the robot keeps mapping new walls. The step time
includes the simulation, the SLAM filter, the belief raster and the reward.

Targets: reset < 10 ms; >= 100 steps/s on ``house`` and random worlds.

    python benchmarks/bench_wrapper.py [--ids VSlam/Explore-v0 VSlam/ExploreHouse-v0]
                                       [--steps 300] [--resets 20] [--seed 0]
                                       [--slam-config PRESET_OR_JSON]

``--slam-config`` is the wrapper's ``slam_config`` (a preset name or a JSON mapping for
``SlamConfig.from_dict``, e.g. ``'{"filter": {"measurement_min_travel": 0.2}}'``).
Report ``mean/s`` (steps / total time) as the throughput when a motion filter makes
most steps cheap: ``steps/s`` (one over the median step) then counts the cheap ones;
``measured`` is the fraction of steps that ran the measurement update and ``travel m``
the distance the robot drove.
"""

from __future__ import annotations

import argparse
import os
import time

import gymnasium as gym
import numpy as np

import vslam_gym
from vslam_gym.evaluation import machine_description, name_or_mapping

RESET_TARGET_MS = 10.0
"""Target median reset time [ms]."""
STEPS_PER_S_TARGET = 100.0
"""Target throughput [steps/s] in one process."""
FRONT_HALF_WIDTH = 20
"""Beams either side of straight ahead the reactive policy watches."""
TURN_DISTANCE = 0.03
"""Normalised range (of max range: 0.9 m of 30 m) below which the policy turns in place."""


class ReactiveDriver:
    """Forward, or turn in place (always to the same side until the way is clear) when
    something is close ahead. Keeping the side stops it from dithering left and right on
    the spot, which would flatter a motion filter (no motion, no measurement update)."""

    def __init__(self) -> None:
        self.turn = 0.0

    def __call__(self, scan: np.ndarray) -> np.ndarray:
        mid = scan.size // 2
        ahead = scan[mid - FRONT_HALF_WIDTH : mid + FRONT_HALF_WIDTH + 1]
        if ahead.min() > TURN_DISTANCE:
            self.turn = 0.0
            return np.array([0.8, 0.0], np.float32)
        if self.turn == 0.0:
            left, right = scan[:mid].mean(), scan[mid + 1 :].mean()  # descending bearings
            self.turn = 1.0 if left > right else -1.0
        return np.array([0.0, self.turn], np.float32)


def bench(
    env_id: str, steps: int, resets: int, seed: int, slam_config: str | dict = "default"
) -> dict[str, float]:
    """Median reset [ms] and steps/s of one id."""
    env = gym.make(vslam_gym.explore_spec(env_id, slam_config=slam_config))
    env.reset(seed=seed)  # imports, caches
    reset_ms = []
    for i in range(resets):
        start = time.perf_counter()
        env.reset(seed=seed + i)
        reset_ms.append((time.perf_counter() - start) * 1e3)
    obs, info = env.reset(seed=seed)
    driver = ReactiveDriver()
    step_s, slam_ms, measured, travel = [], [], [], 0.0
    for _ in range(steps):
        start = time.perf_counter()
        pose = info["pose"]
        obs, _, terminated, truncated, info = env.step(driver(obs["scan"]))
        step_s.append(time.perf_counter() - start)
        belief = env.get_wrapper_attr("belief")
        slam_ms.append(belief.step_ms)
        measured.append(belief.measured)
        travel += float(np.hypot(*(info["pose"][:2] - pose[:2])))
        if terminated or truncated:
            obs, info = env.reset()
            driver = ReactiveDriver()
    env.close()
    step_s = np.array(step_s)
    return {
        "reset_ms": float(np.median(reset_ms)),
        "steps_per_s": float(1.0 / np.median(step_s)),
        "mean_steps_per_s": float(steps / step_s.sum()),
        "slam_ms": float(np.median(slam_ms)),
        "step_p95_ms": float(np.percentile(step_s, 95) * 1e3),
        "measured": float(np.mean(measured)),
        "travel_m": travel,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--ids", nargs="+", default=[vslam_gym.EXPLORE_ID, vslam_gym.EXPLORE_WORLD_IDS["house"]]
    )
    parser.add_argument("--steps", type=int, default=300)
    parser.add_argument("--resets", type=int, default=20)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument(
        "--slam-config", default="default", type=name_or_mapping, help="preset name or JSON mapping"
    )
    args = parser.parse_args()
    slam_config = args.slam_config
    print(f"machine: {machine_description()}; load average {os.getloadavg()[0]:.2f}")
    print(f"slam_config: {args.slam_config}")
    header = (
        f"{'id':32s} {'reset ms':>9s} {'steps/s':>8s} {'mean/s':>7s} {'SLAM ms':>8s} "
        f"{'p95 ms':>7s} {'measured':>8s} {'travel m':>8s}"
    )
    print(header)
    print("-" * len(header))
    for env_id in args.ids:
        r = bench(env_id, args.steps, args.resets, args.seed, slam_config)
        print(
            f"{env_id:32s} {r['reset_ms']:9.2f} {r['steps_per_s']:8.1f} "
            f"{r['mean_steps_per_s']:7.1f} {r['slam_ms']:8.1f} {r['step_p95_ms']:7.1f} "
            f"{r['measured']:8.2f} {r['travel_m']:8.1f}"
        )
    print(
        f"targets: reset < {RESET_TARGET_MS:g} ms, >= {STEPS_PER_S_TARGET:g} steps/s "
        f"(steps/s = 1 / median step; mean/s = steps / total time); "
        f"load average after {os.getloadavg()[0]:.2f}"
    )


if __name__ == "__main__":
    main()
