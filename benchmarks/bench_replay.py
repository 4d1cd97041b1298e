"""Per-scan time of the SLAM on the Radish logs (issue #6: median at most 10 ms).

For each log and odometry mode the whole log is replayed ``--repeats`` times
(``vslam_gym.replay.replay``, preset ``logs`` unless ``--preset``), one run at a time;
each run's per-scan filter time (``Belief.step_ms``; not the log reading) gives a
median and a 95th percentile, and its parts (``Belief.step_ms_parts``: the motion update
with the whole-scan matcher, the loop closure, the landmark layer) a mean each. The
table prints the median over the repeats of each (and the range of the medians), with
the position ATE of the first run (the same every run: the replay is deterministic).
The published scan-matching baselines of the data README take 12-35 ms per scan.

Every run is a fresh Python process (``PYTHONPATH``: this checkout). ``--compare DIR``
alternates every run with the same run of another checkout of the package
(``PYTHONPATH=DIR``; its preset without ``--set``), so that two versions are timed in
the same minutes: these machines are noisy, compare ratios within one run.

The machine (CPU, cores, Python, numpy) and the load average before and after are
printed.

Usage::

    python benchmarks/bench_replay.py [--logs intel aces] [--odometry logged synthetic]
                                      [--repeats 3] [--seed 0] [--preset logs] [--set JSON]
                                      [--compare DIR] [--data DIR]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np

from vslam_gym.evaluation import load_average, machine_description

TARGET_MEDIAN_MS = 10.0
"""Issue #6's target: median filter time per scan [ms]."""
THIS_CHECKOUT = Path(__file__).resolve().parents[1]
"""The checkout this script belongs to (its package is the one timed)."""
DEFAULT_DATA = THIS_CHECKOUT.parent / "shared" / "data" / "radish"
"""Where the logs are in this project's layout (``--data`` to change it)."""
SYNTHETIC_SEED = 0
"""Default seed of the synthetic odometry timed (``--seed``)."""
_RUN = """
import json, sys
from vslam_gym.replay import replay
log, odometry, seed, preset, overrides = sys.argv[1:6]
m = replay(log, odometry, int(seed), preset, overrides=json.loads(overrides))["metrics"]
split = m.get("step_ms_parts", {})  # NaN for a checkout without it
names = ("motion", "loop_closure", "landmarks")
parts = [split.get(k, {}).get("mean", float("nan")) for k in names]
print(json.dumps([m[k] for k in ("step_ms_median", "step_ms_p95", "ate_rmse_m")] + parts))
"""
"""One replay in a fresh process; prints its median, p95 and ATE as JSON."""


def run(
    checkout: Path, log: Path, odometry: str, seed: int, preset: str, overrides: dict
) -> tuple[float, ...]:
    """``(median ms, p95 ms, ATE m, mean ms of the motion / loop closure / landmarks parts)``
    of one replay with the package of ``checkout``."""
    env = {**os.environ, "PYTHONPATH": str(checkout)}
    args = [str(log), odometry, str(seed), preset, json.dumps(overrides)]
    out = subprocess.run(  # cwd: ``-c`` puts it first on sys.path, before PYTHONPATH
        [sys.executable, "-c", _RUN, *args],
        env=env,
        cwd=checkout,
        capture_output=True,
        text=True,
        check=True,
    )
    return tuple(json.loads(out.stdout.strip().splitlines()[-1]))


def summary(runs: list[tuple[float, ...]]) -> dict[str, float]:
    """Median and range over the repeats of the per-run median and p95 [ms]."""
    a = np.array(runs, dtype=float)
    return {
        "median": float(np.median(a[:, 0])),
        "median_lo": float(a[:, 0].min()),
        "median_hi": float(a[:, 0].max()),
        "p95": float(np.median(a[:, 1])),
        "ate": float(a[0, 2]),
        "parts": [float(v) for v in np.median(a[:, 3:6], axis=0)],
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--logs", nargs="+", default=["intel", "aces"])
    parser.add_argument("--odometry", nargs="+", default=["logged", "synthetic"])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--seed", type=int, default=SYNTHETIC_SEED, help="synthetic odometry")
    parser.add_argument("--preset", default="logs")
    parser.add_argument("--set", default="{}", help="options over the preset (JSON)")
    parser.add_argument("--compare", type=Path, default=None, help="another checkout")
    parser.add_argument("--data", type=Path, default=DEFAULT_DATA, help="folder of the logs")
    args = parser.parse_args()
    if args.repeats < 1:
        parser.error(f"--repeats must be >= 1, got {args.repeats}")
    overrides = json.loads(args.set)
    print(f"machine: {machine_description()}")
    print(f"load average before: {load_average()}")
    rows = []
    for name in args.logs:
        log = args.data / f"{name}.log.gz"
        if not log.exists():
            parser.error(f"no log {log} (--data)")
        for odometry in args.odometry:
            here, other = [], []
            for _ in range(args.repeats):
                here.append(run(THIS_CHECKOUT, log, odometry, args.seed, args.preset, overrides))
                if args.compare is not None:
                    other.append(run(args.compare, log, odometry, args.seed, args.preset, {}))
            rows.append((name, odometry, "this", summary(here)))
            if other:
                rows.append((name, odometry, "compare", summary(other)))
            print(f"  {name}/{odometry} done (load {load_average()})", flush=True)
    print(f"load average after: {load_average()}")
    print(
        f"filter time per scan [ms], preset {args.preset}, {args.repeats} repeats "
        f"(median and range of the per-run medians)"
        + (f", synthetic odometry seed {args.seed}" if "synthetic" in args.odometry else "")
        + f"; target: median <= {TARGET_MEDIAN_MS:g} ms"
    )
    print(f"{'log':6s} {'odometry':9s} {'code':7s} {'median':>7s} {'range':>13s} "
          f"{'p95':>6s} {'motion':>7s} {'loop':>6s} {'landm.':>6s} {'ATE m':>6s} met")  # fmt: skip
    for name, odometry, code, s in rows:
        met = "yes" if s["median"] <= TARGET_MEDIAN_MS else "NO"
        span = f"{s['median_lo']:.1f}-{s['median_hi']:.1f}"
        motion, loop, landmarks = s["parts"]
        print(
            f"{name:6s} {odometry:9s} {code:7s} {s['median']:7.1f} {span:>13s} "
            f"{s['p95']:6.1f} {motion:7.1f} {loop:6.1f} {landmarks:6.1f} {s['ate']:6.3f} {met}"
        )
    print(
        "motion / loop / landm.: mean ms per scan of the step's parts (Belief.step_ms_parts: "
        "the motion update with the whole-scan matcher, the loop closure, the landmark layer)"
    )
    if args.compare is not None:
        for name, odometry, code, s in rows:
            if code == "compare":
                this = next(r[3] for r in rows if r[:3] == (name, odometry, "this"))
                print(f"{name}/{odometry}: this / compare = {this['median'] / s['median']:.3f}")


if __name__ == "__main__":
    main()
