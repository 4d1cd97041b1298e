"""Per-step time of the SLAM filter along a world's route, for each preset asked for.

For each world and preset: an episode (``vslam_gym.evaluation.run_episode``) drives the
world's route with the route follower on the true pose and runs ``VertexSLAM`` every
step; the filter's own wall time per step (``Belief.step_ms``: motion update,
segmentation, association, map updates, new landmarks; not the simulation) is
summarised as median, mean, 95th percentile and maximum, with the median of the last
tenth of the steps (cost grows with the map) and the final landmark count. Under a motion
filter (the default measures after 0.15 m or 0.15 rad, ``fast`` after 0.2 m or 0.2 rad)
the steps that skip the measurement update are cheap: the mean is the CPU time per step,
and ``meas ms`` the median over the steps that ran the measurement update.

The episode runs ``--repeats`` times (the same results each time, the filter is
deterministic), every world and preset once per round, so that a slow minute of a
shared machine touches all of them alike; each figure is the median over the runs, and
``range`` the lowest and highest per-run median.

Targets: median <= 10 ms per step on ``house`` with the default preset. For reference,
the thesis reported 1.8 s per step (its Python, its curved-object world of 21 steps).

The machine (CPU, cores, Python, numpy) and the load average before and after are
printed: on a shared machine the times are only comparable at a similar load.

Usage::

    python benchmarks/bench_slam.py [--worlds house small] [--presets default thesis fast]
                                    [--seed 0] [--max-steps N] [--repeats 3]
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
        "measured": timing_summary(ms[log.measured])[0],
        "p95": p95,
        "max": float(ms.max()),
        "late": float(np.median(tail)),
        "landmarks": int(log.landmark_counts[-1]),
        "filter_s": float(ms.sum()) / 1e3,
        "wall_s": wall,
        "target": target,
        "vs_thesis": THESIS_STEP_MS / float(ms.mean()),
    }


def summarise_runs(runs: list[dict[str, object]]) -> dict[str, object]:
    """One row from repeated runs of a world and preset: each number the median over them.

    ``range`` holds the lowest and highest per-run median step time [ms].
    """
    row = dict(runs[0])
    for key, value in runs[0].items():
        if isinstance(value, float):
            row[key] = float(np.median([r[key] for r in runs]))
    medians = [float(r["median"]) for r in runs]
    row["range"] = (min(medians), max(medians))
    return row


def format_rows(rows: list[dict[str, object]]) -> str:
    """The result table, fixed width."""
    header = (
        "world", "preset", "steps", "route", "med ms", "range", "mean ms", "meas ms", "p95 ms",
        "max ms", "late ms", "LMs", "filter s", "wall s", "target", "met", "x thesis",
    )  # fmt: skip
    lines = []
    for r in rows:
        target = r["target"]
        met = "-" if target is None else ("yes" if r["median"] <= target else "NO")
        lines.append(
            (
                r["world"], r["preset"], str(r["steps"]), r["route"], f"{r['median']:.1f}",
                "{:.1f}-{:.1f}".format(*r["range"]), f"{r['mean']:.1f}",
                f"{r['measured']:.1f}", f"{r['p95']:.1f}",
                f"{r['max']:.1f}", f"{r['late']:.1f}",
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
    parser.add_argument("--repeats", type=int, default=3, help="runs of each episode, >= 1")
    args = parser.parse_args()
    if args.repeats < 1:
        parser.error(f"--repeats must be >= 1, got {args.repeats}")
    print(f"machine: {machine_description()}")
    print(f"load average before: {load_average()}")
    cases = [(world, preset) for world in args.worlds for preset in args.presets]
    runs: dict[tuple[str, str], list[dict[str, object]]] = {case: [] for case in cases}
    for round_ in range(args.repeats):
        for world, preset in cases:
            r = bench(world, preset, args.seed, args.max_steps)
            runs[(world, preset)].append(r)
            print(
                f"  run {round_ + 1}/{args.repeats} {world}/{preset}: {r['steps']} steps, "
                f"median {r['median']:.1f} ms (load {load_average()})",
                flush=True,
            )
    print(f"load average after: {load_average()}")
    print(
        f"SLAM step time [ms] per step, seed {args.seed}, median over {args.repeats} run(s) "
        f"('range': lowest-highest per-run median); 'late' = median of the last "
        f"{TAIL_FRACTION:.0%} of steps; 'x thesis' = {THESIS_STEP_MS / 1e3:g} s / mean"
    )
    print(format_rows([summarise_runs(runs[case]) for case in cases]))


if __name__ == "__main__":
    main()
