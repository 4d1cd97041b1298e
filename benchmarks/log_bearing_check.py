"""Which bearing offset a Carmen log's scans share with its reference poses.

Prints, per candidate offset [deg] added to the reader's bearings
(``CarmenConfig.bearing_offset_deg``), the median point-to-line distance between scans
``--lag`` apart moved into one frame by the log's corrected poses
(:func:`vslam_gym.logs.bearing_check.bearing_offset_scores`); the lowest marks the
convention the poses were made with. For a log of your own: if it is not 0, replay with
``vslam-gym replay LOG --bearing-offset-deg D``.

Usage::

    python benchmarks/log_bearing_check.py LOG [LOG ...] [--offsets -1 -0.5 0 0.5 1]
                                           [--lags 1 5]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from vslam_gym.evaluation import machine_description
from vslam_gym.logs import CarmenConfig, read_carmen
from vslam_gym.logs.bearing_check import DEFAULT_OFFSETS_DEG, bearing_offset_scores
from vslam_gym.replay import DEFAULT_MAX_RANGE

CM_PER_M = 100.0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("logs", nargs="+", help="Carmen logs (.log or .log.gz)")
    parser.add_argument("--offsets", type=float, nargs="+", default=list(DEFAULT_OFFSETS_DEG))
    parser.add_argument("--lags", type=int, nargs="+", default=[1, 5])
    args = parser.parse_args()
    print(f"machine: {machine_description()}")
    header = "log                 lag  " + "  ".join(f"{o:+6.2f}" for o in args.offsets)
    print("median point-to-line distance [cm] of scans at the reference poses, per bearing offset")
    print(header)
    print("-" * len(header))
    for path in args.logs:
        log = read_carmen(path, CarmenConfig(max_range=DEFAULT_MAX_RANGE))
        for lag in args.lags:
            start = time.perf_counter()
            scores = bearing_offset_scores(log, args.offsets, lag=lag)
            best = args.offsets[int(scores.argmin())]
            cells = "  ".join(f"{CM_PER_M * s:6.2f}" for s in scores)
            name = Path(log.source).name[:18]
            print(
                f"{name:<18}  {lag:3d}  {cells}   best {best:+.2f} deg"
                f" ({time.perf_counter() - start:.1f} s)"
            )


if __name__ == "__main__":
    main()
