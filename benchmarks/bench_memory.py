"""Memory of the estimator and of the SLAM-wrapped environment.

Each case runs in a fresh worker process (so that peaks do not carry over) and reports:

- ``traced MB``: the peak of the memory Python and numpy allocated during the case
  (``tracemalloc``; numpy reports its array buffers to it), the figure to compare
  between versions;
- ``RSS MB``: the process's peak resident set size, and ``base MB`` the resident size
  after the imports and a warm-up of two steps (Python, numpy, scipy, and for the
  environment gymnasium, pymunk and pygame), so ``RSS - base`` is what the case added;
- the final state dimension of the filter and its covariance size (``8 n^2`` bytes:
  the dense covariance is the part that grows with the map).

Cases:

- ``episode:WORLD``: ``vslam_gym.evaluation.run_episode`` along the world's route with
  the ``default`` preset (the filter plus the episode log that keeps every pose and
  covariance);
- ``replay:LOG``: ``vslam_gym.replay.replay`` of a Carmen log (logged odometry, ``logs``
  preset), when the log exists;
- ``env:ID``: ``gymnasium.make`` of an exploration id and ``--steps`` steps of random
  actions (the simulator, the filter, the belief raster).

Tracing slows the cases down: the times it prints are not step times (see
``bench_slam.py`` for those).

Usage::

    python benchmarks/bench_memory.py [--cases episode:house replay:intel.log.gz
                                       env:VSlam/Explore-v0] [--steps 300]
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import resource
import sys
import time
import tracemalloc
from pathlib import Path

MB = 1024.0 * 1024.0
DEFAULT_RADISH = Path(__file__).resolve().parents[2] / "shared" / "data" / "radish"
"""Where the Radish logs are looked for when a ``replay:`` case names a bare file."""


def _rss_mb() -> float:
    """Peak resident set size of this process [MB] (Linux reports kilobytes)."""
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return peak / 1024.0 if sys.platform != "darwin" else peak / MB


def _case(name: str, steps: int) -> dict[str, object]:
    """Run one case in this (fresh) process; return its figures."""
    kind, _, arg = name.partition(":")
    if kind == "episode":
        from vslam_gym.evaluation import run_episode

        run_episode(arg, 0, "default", max_steps=2)  # warm-up: lazy imports, caches
        base = _rss_mb()
        tracemalloc.start()
        start = time.perf_counter()
        log = run_episode(arg, 0, "default")
        n = 3 + 2 * int(log.landmark_counts[-1])
        detail = f"{log.steps} steps, {int(log.landmark_counts[-1])} landmarks"
    elif kind == "replay":
        from vslam_gym.replay import replay

        path = Path(arg)
        if not path.exists():
            path = DEFAULT_RADISH / arg
        if not path.exists():
            return {"case": name, "skipped": f"{arg} not found"}
        replay(path, "logged", 0, "logs", max_scans=2)  # warm-up: lazy imports, caches
        base = _rss_mb()
        tracemalloc.start()
        start = time.perf_counter()
        result = replay(path, "logged", 0, "logs")
        n = int(result["belief"].state_dim)
        detail = f"{result['metrics']['scans']} scans, {result['metrics']['landmarks']} landmarks"
    elif kind == "env":
        import gymnasium as gym

        import vslam_gym

        warm = gym.make(vslam_gym.explore_spec(arg))  # warm-up: lazy imports, caches
        warm.reset(seed=0)
        warm.step(warm.action_space.sample())
        warm.close()
        base = _rss_mb()
        tracemalloc.start()
        start = time.perf_counter()
        env = gym.make(vslam_gym.explore_spec(arg))
        env.reset(seed=0)
        env.action_space.seed(0)
        for _ in range(steps):
            _, _, terminated, truncated, _ = env.step(env.action_space.sample())
            if terminated or truncated:
                env.reset()
        belief = env.get_wrapper_attr("belief")
        n = int(belief.state_dim)
        detail = f"{steps} random steps, {len(belief.landmarks)} landmarks at the end"
        env.close()
    else:
        raise ValueError(f"unknown case {name!r}: use episode:WORLD, replay:LOG or env:ID")
    wall = time.perf_counter() - start
    _, traced_peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    return {
        "case": name,
        "detail": detail,
        "traced_mb": traced_peak / MB,
        "rss_mb": _rss_mb(),
        "base_mb": base,
        "state_dim": n,
        "cov_mb": 8.0 * n * n / MB,
        "wall_s": wall,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--cases",
        nargs="+",
        default=[
            "episode:house",
            "replay:intel.log.gz",
            "replay:aces.log.gz",
            "env:VSlam/Explore-v0",
        ],
    )
    parser.add_argument("--steps", type=int, default=300, help="steps of the env: cases")
    args = parser.parse_args()
    from vslam_gym.evaluation import machine_description

    print(f"machine: {machine_description()}")
    ctx = mp.get_context("spawn")  # a fresh interpreter per case: peaks do not carry over
    rows = []
    for name in args.cases:
        with ctx.Pool(1) as pool:
            row = pool.apply(_case, (name, args.steps))
        rows.append(row)
        if "skipped" in row:
            print(f"  {name}: skipped ({row['skipped']})", flush=True)
            continue
        print(
            f"  {name}: {row['detail']}; traced peak {row['traced_mb']:.1f} MB, peak RSS "
            f"{row['rss_mb']:.0f} MB (after imports {row['base_mb']:.0f} MB), state "
            f"{row['state_dim']} ({row['cov_mb']:.2f} MB covariance), {row['wall_s']:.0f} s",
            flush=True,
        )


if __name__ == "__main__":
    main()
