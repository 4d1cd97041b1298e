"""The whole-scan matcher alone as odometry on a Carmen log: accuracy and CPU time.

Runs :func:`vslam_gym.slam.scan_matching.match_scan` exactly as
``FilterConfig.prealign="odometry"`` does inside the filter (prior: the odometry
increment and its Thrun covariance; the matched relative pose replaces the increment;
without a match, the increment), but without the landmark filter, so that the matcher's
share of the SLAM's error and time can be told apart. Prints per seed the position ATE
(no alignment, against the log's corrected poses), how often it declined and why, and
the matcher's median CPU time per scan (``time.process_time``: less sensitive to other
processes on a shared machine than wall time).

Usage::

    python benchmarks/bench_scan_matching.py LOG [--odometry synthetic|logged]
                                             [--seeds 0-4] [--max-scans N]
                                             [--preset logs|default] [--worst N]

``--worst N`` also prints, per run, the N steps whose matched relative pose is furthest
in heading from the corrected poses' (step, decision, heading and position error of
the step, the odometry's heading error, the true turn): where a run went wrong.

``--preset`` picks the matcher configuration (``SlamConfig.preset(name).matcher``):
``logs`` (default: ``on_ambiguity="prior"``, no keyframe revisits since 2026-11-26) or
``default`` (the matcher's defaults: ambiguous matches declined).
"""

from __future__ import annotations

import argparse
import collections
import time

import numpy as np

from vslam_gym.evaluation import machine_description, parse_seeds, position_ate_rmse
from vslam_gym.logs import (
    CarmenConfig,
    CarmenLog,
    logged_increments,
    read_carmen,
    synthetic_increments,
)
from vslam_gym.replay import DEFAULT_MAX_RANGE
from vslam_gym.slam.config import FilterConfig
from vslam_gym.slam.filter import SlamConfig
from vslam_gym.slam.geometry import wrap_angle
from vslam_gym.slam.motion import (
    compose,
    frame_rotation,
    increment_to_relative,
    inverse,
    odometry_noise,
)
from vslam_gym.slam.scan_matching import (
    LocalMap,
    ScanMatcherConfig,
    match_scan_why,
    scan_points,
)


def run(log: CarmenLog, increments: np.ndarray, n: int, config: ScanMatcherConfig) -> dict:
    """Scan-matching odometry over the first ``n`` scans; ATE, declines, CPU ms.

    Also ``steps``: per step ``(scan, decision, heading error [deg], position error [m],
    odometry heading error [deg], true turn [deg])`` of the relative pose used.
    """
    filt = FilterConfig()
    local = LocalMap(config)
    pose = log.poses[0].copy()
    local.add(scan_points(log.ranges[0], log.bearings, log.max_range), pose)  # scan 0
    poses, cpu_ms, reasons, steps = [pose], [], collections.Counter(), []
    for k in range(1, n):
        u = increments[k - 1]
        delta, cov = increment_to_relative(
            u, odometry_noise(u, filt.odometry_alphas, np.asarray(filt.odometry_sigma_floor))
        )
        to_map = frame_rotation(pose[2])
        points = scan_points(log.ranges[k], log.bearings, log.max_range)
        start = time.process_time()
        result, why = match_scan_why(
            points, local, compose(pose, delta), to_map @ cov @ to_map.T, config
        )
        cpu_ms.append((time.process_time() - start) * 1e3)
        reasons[why] += 1
        odometry_heading = delta[2]
        if result is not None:
            delta = compose(inverse(pose), result.pose)
        true = compose(inverse(log.poses[k - 1]), log.poses[k])
        steps.append(
            (
                k,
                why,
                float(np.degrees(wrap_angle(delta[2] - true[2]))),
                float(np.hypot(*(delta[:2] - true[:2]))),
                float(np.degrees(wrap_angle(odometry_heading - true[2]))),
                float(np.degrees(true[2])),
            )
        )
        pose = compose(pose, delta)
        poses.append(pose)
        local.add(points, pose)
    return {
        "ate_rmse_m": position_ate_rmse(np.array(poses), log.poses[:n]),
        "reasons": dict(reasons),
        "cpu_ms_median": float(np.median(cpu_ms)),
        "steps": steps,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("log")
    parser.add_argument("--odometry", choices=("synthetic", "logged"), default="synthetic")
    parser.add_argument("--seeds", default="0-4", help="synthetic odometry seeds, e.g. 0-4")
    parser.add_argument("--max-scans", type=int, default=None)
    parser.add_argument("--preset", choices=("logs", "default"), default="logs")
    parser.add_argument(
        "--worst", type=int, default=0, help="print the N steps with the largest heading error"
    )
    args = parser.parse_args()
    print(machine_description())
    log = read_carmen(args.log, CarmenConfig(max_range=DEFAULT_MAX_RANGE))
    n = log.num_scans if args.max_scans is None else min(log.num_scans, args.max_scans)
    seeds = parse_seeds(args.seeds) if args.odometry == "synthetic" else [0]
    ates = []
    for seed in seeds:
        inc = synthetic_increments(log, seed) if args.odometry == "synthetic" else None
        increments = inc if inc is not None else logged_increments(log)
        out = run(log, increments, n, SlamConfig.preset(args.preset).matcher)
        ates.append(out["ate_rmse_m"])
        print(
            f"{args.odometry} seed {seed}: ATE {out['ate_rmse_m']:.3f} m, "
            f"{out['reasons']}, matcher CPU median {out['cpu_ms_median']:.1f} ms"
        )
        for step in sorted(out["steps"], key=lambda s: -abs(s[2]))[: args.worst]:
            print(
                "  scan {}: {}, heading error {:+.1f} deg, position error {:.3f} m "
                "(odometry {:+.1f} deg, true turn {:+.1f} deg)".format(*step)
            )
    print(
        f"mean ATE {np.mean(ates):.3f} +- {np.std(ates):.3f} m over {len(ates)} run(s), {n} scans"
    )


if __name__ == "__main__":
    main()
