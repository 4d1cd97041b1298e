"""ICP alignments of a SLAM run: side by side (``align_many``) against one at a time.

One episode of a world's route (``vslam_gym.evaluation.run_episode``, default preset)
records every ``align_many`` call the filter makes: the sets, the candidate landmark
models, the predicted pose and the ICP parameters. Those calls are then replayed,
``--repeats`` times alternately, two ways: ``align_many`` (the alignments of a scan run
side by side, the last few one at a time) and the single-alignment loop per model
(``icp._align``, what ``align_many`` did before). Both get the same cached line
geometry. Printed: the median total time of each, their ratio, how many alignments
and iterations the run holds, and how many results differ in stop reason, iteration
count or used points (round-off: the sums are taken in another order; for scale, the
single loop on the same sets scaled by ``1 + 1e-15`` is counted too).

Usage::

    python benchmarks/bench_icp_batch.py [--world house] [--seed 0] [--repeats 5]
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np

import vslam_gym.slam.filter as slam_filter
from vslam_gym.evaluation import machine_description, run_episode
from vslam_gym.slam import icp


def record(world: str, seed: int) -> list[tuple]:
    """Every ``align_many`` call of one episode, with its arguments."""
    calls: list[tuple] = []
    original = slam_filter.align_many

    def recording(points, models, pose, config, max_range, half_fov, *, bounds=None, **kwargs):
        # kwargs: the filter's other keywords (its cached line geometry, an ICP pose prior)
        prior = kwargs.get("prior_weight")
        calls.append((points, models, np.array(pose), config, max_range, half_fov, bounds, prior))
        return original(points, models, pose, config, max_range, half_fov, bounds=bounds, **kwargs)

    slam_filter.align_many = recording
    try:
        run_episode(world, seed, "default")
    finally:
        slam_filter.align_many = original
    return [c for c in calls if c[1]]


def one_at_a_time(call, lines, scale: float = 1.0) -> list[icp.IcpResult]:
    points, models, pose, config, max_range, half_fov, bounds, prior = call
    sets = points if isinstance(points, list) else [points] * len(models)
    bounds = bounds or [None] * len(models)
    prior = icp._prior_weight(prior)
    return [
        icp._align(
            np.asarray(q, dtype=float) * scale,
            m.u > config.unknown_threshold,
            g,
            pose,
            config,
            max_range,
            half_fov,
            b,
            prior=prior,
        )
        for q, m, g, b in zip(sets, models, lines, bounds, strict=True)
    ]


def side_by_side(call, lines) -> list[icp.IcpResult]:
    points, models, pose, config, max_range, half_fov, bounds, prior = call
    return icp.align_many(
        points,
        models,
        pose,
        config,
        max_range,
        half_fov,
        lines=lines,
        bounds=bounds,
        prior_weight=prior,
    )


def differ(a: list[icp.IcpResult], b: list[icp.IcpResult]) -> int:
    return sum(
        (x.reason, x.iterations, x.n_used) != (y.reason, y.iterations, y.n_used)
        for x, y in zip(a, b, strict=True)
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--world", default="house")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    print(f"machine: {machine_description()}")
    print(f"load average before: {os.getloadavg()[0]:.2f}")
    calls = record(args.world, args.seed)
    lines = [[icp.line_geometry(m) for m in call[1]] for call in calls]
    times: dict[str, list[float]] = {"one at a time": [], "side by side": []}
    for _ in range(args.repeats):
        for name, run in (("one at a time", one_at_a_time), ("side by side", side_by_side)):
            start = time.perf_counter()
            for call, geometry in zip(calls, lines, strict=True):
                run(call, geometry)
            times[name].append(time.perf_counter() - start)
    single = [one_at_a_time(c, g) for c, g in zip(calls, lines, strict=True)]
    batch = [side_by_side(c, g) for c, g in zip(calls, lines, strict=True)]
    nudged = [one_at_a_time(c, g, 1 + 1e-15) for c, g in zip(calls, lines, strict=True)]
    n = sum(len(r) for r in single)
    iterations = sum(r.iterations for rs in single for r in rs)
    print(f"load average after: {os.getloadavg()[0]:.2f}")
    print(
        f"{args.world} seed {args.seed}: {len(calls)} scans with candidates, {n} alignments "
        f"({n / len(calls):.1f} per scan), {iterations / n:.1f} iterations each on average"
    )
    median = {k: float(np.median(v)) for k, v in times.items()}
    for name, value in median.items():
        print(f"  {name:>13}: median {value:.3f} s over {args.repeats} repeats")
    print(f"  ratio: side by side is {median['one at a time'] / median['side by side']:.2f}x")
    d_batch = sum(differ(a, b) for a, b in zip(single, batch, strict=True))
    d_nudge = sum(differ(a, b) for a, b in zip(single, nudged, strict=True))
    print(
        f"  results that differ in reason / iterations / used points: side by side "
        f"{d_batch} ({d_batch / n:.1%}); one at a time on points scaled by 1 + 1e-15 "
        f"{d_nudge} ({d_nudge / n:.1%})"
    )


if __name__ == "__main__":
    main()
