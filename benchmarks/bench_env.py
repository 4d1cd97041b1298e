"""Speed of the raw environment: median milliseconds per step and steps per second.

Cases (181-beam lidar, one process unless stated):

- ``house``: the shipped house world;
- ``random-100``: a random world with 100 obstacles;
- the lidar alone in ``random-100``: the numpy ray caster and pymunk's per-ray queries;
- the physics alone (one control period);
- ``gym.make_vec(..., vectorization_mode="async")`` with 2 worker processes (total
  environment steps per second over both workers);
- ``reset(seed=s)``, a new seed each time: ``house`` (a fixed world) and ``random`` (a
  new world per reset, default ``RandomWorldParams``, as ``VSlam/Explore-v0``), with the
  parts of a random reset (world generation, pymunk space, lidar geometry) timed apart
  on fresh worlds. Wall and CPU (process) time are both given: on a loaded machine the
  wall time includes waiting for a core.

Targets: at most 1.0 ms per step single-process; at most 5 ms per random-world reset
(the simulator's share of issue #5's 10 ms for the SLAM-wrapped reset). Anchor: IR-SIM
took 2.2 ms per step with a 181-beam lidar and 100 obstacles.

The load average is printed before and after: on a shared machine the times are only
comparable at a similar load.

Usage::

    python benchmarks/bench_env.py [--steps 1000] [--repeats 5] [--resets 200] [--reset-only]
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import time
from collections.abc import Callable

import gymnasium as gym
import numpy as np
import pymunk

import vslam_gym
from vslam_gym.env import LidarWorldEnv
from vslam_gym.sim.lidar import Lidar, NumpyRayCaster, PymunkRayCaster, RayGeometry
from vslam_gym.sim.physics import DiffDriveSim, PhysicsConfig
from vslam_gym.sim.random_world import generate_random_world

N_RANDOM_OBSTACLES = 100  # clutter; the generator adds the room walls
TARGET_MS = 1.0
ANCHOR_MS = 2.2  # IR-SIM, 181 beams, 100 obstacles
RESET_TARGET_MS = 5.0  # random-world reset, simulator only


def random_world_kwargs() -> dict:
    return {"world": "random", "world_params": {"n_obstacles": N_RANDOM_OBSTACLES}}


def time_per_call(call: Callable[[], object], calls: int, repeats: int) -> float:
    """Median over ``repeats`` of the mean time [ms] of one call (``calls`` per repeat)."""
    results = []
    for _ in range(repeats):
        start = time.perf_counter()
        for _ in range(calls):
            call()
        results.append((time.perf_counter() - start) / calls * 1e3)
    return statistics.median(results)


def bench_env(kwargs: dict, steps: int, repeats: int) -> tuple[float, LidarWorldEnv]:
    env = LidarWorldEnv(**kwargs)
    env.reset(seed=0)
    actions = np.random.default_rng(0).uniform(-1.0, 1.0, (steps, 2)).astype(np.float32)
    results = []
    for _ in range(repeats):
        env.reset(seed=0)
        start = time.perf_counter()
        for action in actions:
            env.step(action)
        results.append((time.perf_counter() - start) / steps * 1e3)
    return statistics.median(results), env


def bench_lidar(env: LidarWorldEnv, scans: int, repeats: int) -> tuple[float, float]:
    world = env.world
    sim = DiffDriveSim(world, PhysicsConfig())
    pose = sim.pose
    rng = np.random.default_rng(0)
    numpy_lidar = Lidar(env.lidar_spec, NumpyRayCaster(RayGeometry.from_world(world)))
    pymunk_lidar = Lidar(env.lidar_spec, PymunkRayCaster(sim.space))
    t_numpy = time_per_call(lambda: numpy_lidar.scan(pose, rng), scans, repeats)
    t_pymunk = time_per_call(lambda: pymunk_lidar.scan(pose, rng), max(scans // 5, 1), repeats)
    return t_numpy, t_pymunk


def bench_physics(env: LidarWorldEnv, steps: int, repeats: int) -> float:
    sim = DiffDriveSim(env.world, PhysicsConfig())
    return time_per_call(lambda: sim.step(0.3, 0.2), steps, repeats)


def median_ms(call: Callable[[int], object], n: int) -> tuple[float, float]:
    """Median wall and CPU time [ms] of ``call(i)`` for ``i = 0 .. n - 1``."""
    wall, cpu = [], []
    for i in range(n):
        start, start_cpu = time.perf_counter(), time.process_time()
        call(i)
        wall.append((time.perf_counter() - start) * 1e3)
        cpu.append((time.process_time() - start_cpu) * 1e3)
    return statistics.median(wall), statistics.median(cpu)


def bench_resets(resets: int) -> list[tuple[str, float, float]]:
    """Median wall and CPU [ms] of ``reset(seed=s)`` and of the parts of a random reset."""
    rows = []
    for label, kwargs in (("house", {"world": "house"}), ("random", {"world": "random"})):
        env = LidarWorldEnv(**kwargs)
        env.reset(seed=0)  # imports, caches
        wall, cpu = median_ms(lambda i, env=env: env.reset(seed=1 + i), resets)
        rows.append((f"env.reset  {label}", wall, cpu))
    # The parts of a random reset, on fresh worlds (polygon pieces not cached yet).
    first = 10**6  # seeds not used above
    worlds = [generate_random_world(seed) for seed in range(first, first + resets)]
    config = PhysicsConfig()
    parts = (
        ("world generation", lambda i: generate_random_world(first + resets + i)),
        ("pymunk space and robot", lambda i: DiffDriveSim(worlds[i], config)),
        ("lidar geometry", lambda i: Lidar.for_world(worlds[i])),
    )
    for label, call in parts:
        wall, cpu = median_ms(call, resets)
        rows.append((f"  {label} (random)", wall, cpu))
    return rows


def bench_async(kwargs: dict, steps: int, repeats: int, num_envs: int = 2) -> float:
    """Total environment steps per second over ``num_envs`` async workers."""
    envs = gym.make_vec(
        vslam_gym.LIDAR_WORLD_ID, num_envs=num_envs, vectorization_mode="async", **kwargs
    )
    try:
        envs.reset(seed=0)
        actions = np.random.default_rng(0).uniform(-1, 1, (steps, num_envs, 2)).astype(np.float32)
        rates = []
        for _ in range(repeats):
            start = time.perf_counter()
            for action in actions:
                envs.step(action)
            rates.append(steps * num_envs / (time.perf_counter() - start))
        return statistics.median(rates)
    finally:
        envs.close()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=1000, help="steps per repeat")
    parser.add_argument("--repeats", type=int, default=5, help="repeats (median reported)")
    parser.add_argument("--resets", type=int, default=200, help="resets timed (median)")
    parser.add_argument("--reset-only", action="store_true", help="time resets only")
    args = parser.parse_args()

    print(
        f"machine: {platform.platform()}, {platform.processor() or platform.machine()}, "
        f"os.cpu_count()={os.cpu_count()}; Python {platform.python_version()}, "
        f"numpy {np.__version__}, pymunk {pymunk.version}, gymnasium {gym.__version__}"
    )
    print(f"load average before: {os.getloadavg()[0]:.2f}")
    rows = bench_resets(args.resets)
    width = max(len(name) for name, _, _ in rows)
    print(f"\n{args.resets} resets, new seed each, median; 181 beams")
    print(f"{'case':{width}s}  {'wall ms':>8s}  {'CPU ms':>8s}")
    for name, wall, cpu in rows:
        print(f"{name:{width}s}  {wall:8.3f}  {cpu:8.3f}")
    print(f"target <= {RESET_TARGET_MS} ms per random-world reset")
    if args.reset_only:
        print(f"load average after: {os.getloadavg()[0]:.2f}")
        return
    print(f"\n{args.steps} steps x {args.repeats} repeats, median; 181 beams\n")
    rows = []
    for label, kwargs in (("house", {"world": "house"}), ("random-100", random_world_kwargs())):
        ms, env = bench_env(kwargs, args.steps, args.repeats)
        n_obstacles = len(env.world.obstacles)
        assert env.lidar_spec.n_beams == 181
        rows.append((f"env.step  {label} ({n_obstacles} obstacles)", ms))
        numpy_ms, pymunk_ms = bench_lidar(env, args.steps, args.repeats)
        rows.append((f"  lidar scan, numpy caster  ({label})", numpy_ms))
        rows.append((f"  lidar scan, pymunk queries ({label})", pymunk_ms))
        rows.append(
            (
                f"  physics, one control period ({label})",
                bench_physics(env, args.steps, args.repeats),
            )
        )
    width = max(len(name) for name, _ in rows)
    print(f"{'case':{width}s}  {'ms/step':>8s}  {'steps/s':>9s}")
    for name, ms in rows:
        print(f"{name:{width}s}  {ms:8.3f}  {1e3 / ms:9.0f}")
    for label, kwargs in (("house", {"world": "house"}), ("random-100", random_world_kwargs())):
        rate = bench_async(kwargs, max(args.steps // 2, 1), args.repeats)
        name = f"async make_vec, 2 workers, {label}"
        print(f"{name:{width}s}  {1e3 / rate:8.3f}  {rate:9.0f}   (total over both workers)")
    print(f"\ntarget <= {TARGET_MS} ms/step single-process; anchor IR-SIM {ANCHOR_MS} ms/step")
    print(f"load average after: {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
