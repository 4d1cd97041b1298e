"""Per-step time of the SLAM filter along a world's route, for both presets.

For each world and preset: one episode (``vslam_gym.evaluation.run_episode``) drives the
world's route with the route follower on the true pose and runs ``VertexSLAM`` every
step; the filter's own wall time per step (``Belief.step_ms``: motion update,
segmentation, association, map updates, new landmarks; not the simulation) is
summarised as median, mean, 95th percentile and maximum, with the median of the last
tenth of the steps (cost grows with the map) and the final landmark count. Under a motion
filter (the ``fast`` preset) most steps skip the measurement update: compare the means.

Targets: median <= 10 ms per step on ``house`` with the default preset. For reference,
the thesis reported 1.8 s per step (its Python, its curved-object world of 21 steps).

The machine (CPU, cores, Python, numpy) and the load average before and after are
printed: on a shared machine the times are only comparable at a similar load.

Usage::

    python benchmarks/bench_slam.py [--worlds house small] [--presets default thesis fast]
                                    [--seed 0] [--max-steps N]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from vslam_gym.evaluation import load_average, machine_description, run_episode, timing_summary

TARGET_MEDIAN_MS = {"house": 10.0}
"""Target median step time [ms] of the default preset, by world."""
THESIS_STEP_MS = 1800.0
"""The thesis's reported time per step [ms] (for reference)."""
TAIL_FRACTION = 0.1
"""The 'late' column is the median over this last fraction of the steps."""


def bench(world: str, preset: str, seed: int, max_steps: int | None) -> dict[str, object]:
    """Run one episode and summarise its per-step filter times [ms]."""
    start = time.perf_counter()
    log = run_episode(world, seed, preset, max_steps)
    wall = time.perf_counter() - start
    ms = log.step_ms
    median, p95 = timing_summary(ms)
    tail = ms[-max(1, int(round(TAIL_FRACTION * ms.size))) :]
    target = TARGET_MEDIAN_MS.get(world) if preset == "default" else None
    return {
        "world": world,
        "preset": preset,
        "steps": log.steps,
        "route": "done" if log.route_done else "cut",
        "median": median,
        "mean": float(ms.mean()),
        "p95": p95,
        "max": float(ms.max()),
        "late": float(np.median(tail)),
        "landmarks": int(log.landmark_counts[-1]),
        "filter_s": float(ms.sum()) / 1e3,
        "wall_s": wall,
        "target": target,
        "vs_thesis": THESIS_STEP_MS / float(ms.mean()),
    }


def format_rows(rows: list[dict[str, object]]) -> str:
    """The result table, fixed width."""
    header = (
        "world", "preset", "steps", "route", "med ms", "mean ms", "p95 ms", "max ms", "late ms",
        "LMs", "filter s", "wall s", "target", "met", "x thesis",
    )  # fmt: skip
    lines = []
    for r in rows:
        target = r["target"]
        met = "-" if target is None else ("yes" if r["median"] <= target else "NO")
        lines.append(
            (
                r["world"], r["preset"], str(r["steps"]), r["route"], f"{r['median']:.1f}",
                f"{r['mean']:.1f}", f"{r['p95']:.1f}", f"{r['max']:.1f}", f"{r['late']:.1f}",
                str(r["landmarks"]),
                f"{r['filter_s']:.1f}", f"{r['wall_s']:.1f}",
                "-" if target is None else f"<= {target:g}", met, f"{r['vs_thesis']:.0f}x",
            )
        )  # fmt: skip
    widths = [max(len(row[i]) for row in [header, *lines]) for i in range(len(header))]

    def fmt(cells: tuple[str, ...]) -> str:
        return "  ".join(c.rjust(w) for c, w in zip(cells, widths, strict=True))

    rule = "-" * len(fmt(header))
    return "\n".join([fmt(header), rule, *map(fmt, lines)])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--worlds", nargs="+", default=["house", "small"])
    parser.add_argument("--presets", nargs="+", default=["default", "thesis"])
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--max-steps", type=int, default=None, help="default: whole route")
    args = parser.parse_args()
    print(f"machine: {machine_description()}")
    print(f"load average before: {load_average()}")
    rows = []
    for world in args.worlds:
        for preset in args.presets:
            rows.append(bench(world, preset, args.seed, args.max_steps))
            r = rows[-1]
            print(
                f"  {world}/{preset}: {r['steps']} steps, median {r['median']:.1f} ms "
                f"(load {load_average()})",
                flush=True,
            )
    print(f"load average after: {load_average()}")
    print(
        f"SLAM step time [ms] per step, seed {args.seed}; 'late' = median of the last "
        f"{TAIL_FRACTION:.0%} of steps; 'x thesis' = {THESIS_STEP_MS / 1e3:g} s / mean"
    )
    print(format_rows(rows))


if __name__ == "__main__":
    main()
