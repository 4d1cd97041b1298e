"""Speed of the landmark-model operations, and UT versus first order on the same scan.

Scene (``benchmarks/_scenes.py``): a four-line zig-zag seen by the default 181-beam lidar
(1 deg, sigma_r 3 cm, sigma_phi 0.2 deg) from a pose where 60 beams hit it; one seeded
noisy scan. Cases, each the median over ``--repeats`` single calls after a warm-up:

- model creation (``create_model``) for ``ModelConfig()`` (first order) and
  ``ModelConfig.thesis()`` (UT);
- detection (``detect``) of a second scan, from a nearby pose, against that model;
- one model update (``update_model``) with that second scan, computing its own
  association, and again given the detection's association (as a filter would).

Detection and update are skipped ("not available") when their modules do not import.
Targets: creation <= 2 ms, detection <= 1 ms, update <= 2 ms.

UT versus first order: both linearisations on the same scan, all else equal (for each
preset), as the largest vertex-mean difference [m] and the largest relative difference
of the vertex coordinate standard deviations.

Usage::

    python benchmarks/bench_model.py [--repeats 50] [--seed 0]
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import platform
import statistics
import time
from collections.abc import Callable

import numpy as np
import scipy
from _scenes import POSE_BUILD, POSE_UPDATE, ZIGZAG_EDGES, noisy_scan, segment

from vslam_gym.slam.config import ModelConfig, SensorConfig
from vslam_gym.slam.creation import create_model

TARGET_MS = {"creation": 2.0, "detection": 1.0, "update": 2.0}
WARMUP_CALLS = 3


def time_calls(call: Callable[[], object], repeats: int) -> tuple[float, float]:
    """Median and minimum time [ms] of one call over ``repeats`` timed calls."""
    for _ in range(WARMUP_CALLS):
        call()
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        call()
        times.append((time.perf_counter() - start) * 1e3)
    return statistics.median(times), min(times)


def compare_linearizations(scan, first, last, sensor, config: ModelConfig) -> str:
    """UT versus first order with everything else of ``config`` equal, as one line."""
    fits = {
        lin: create_model(
            scan, first, last, POSE_BUILD, sensor, dataclasses.replace(config, linearization=lin)
        )
        for lin in ("ut", "jacobian")
    }
    ut, fo = fits["ut"], fits["jacobian"]
    if ut.n_object_lines != fo.n_object_lines or ut.model.n_vertices != fo.model.n_vertices:
        return (
            f"different models: UT {ut.n_object_lines} lines, first order {fo.n_object_lines} lines"
        )
    d_mean = np.linalg.norm(ut.model.mean - fo.model.mean, axis=1)
    s_ut, s_fo = (np.sqrt(np.diag(f.model.cov)) for f in (ut, fo))
    rel = np.abs(s_ut - s_fo) / s_fo
    start, stop = fo.object_vertices
    obj = slice(2 * start, 2 * stop)
    return (
        f"{fo.n_object_lines} lines; max |mean diff| {d_mean.max() * 1e3:.2f} mm "
        f"(object vertices {d_mean[start:stop].max() * 1e3:.2f} mm); "
        f"max rel. std diff {rel.max():.3%} (object vertices {rel[obj].max():.3%})"
    )


def row(name: str, median: float, best: float, target: float | None, note: str = "") -> str:
    target_txt = f"<= {target:.1f}" if target is not None else ""
    ok = "" if target is None else ("ok" if median <= target else "OVER")
    return f"{name:44s} {median:8.3f} {best:8.3f}  {target_txt:>7s} {ok:4s}  {note}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=50, help="timed calls (median reported)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the noisy scans")
    args = parser.parse_args()

    print(
        f"machine: {platform.platform()}, {platform.processor() or platform.machine()}, "
        f"os.cpu_count()={os.cpu_count()}; Python {platform.python_version()}, "
        f"numpy {np.__version__}, scipy {scipy.__version__}; "
        f"load average {os.getloadavg()[0]:.2f}"
    )
    sensor = SensorConfig()
    rng = np.random.default_rng(args.seed)
    scan = noisy_scan(POSE_BUILD, ZIGZAG_EDGES, sensor, rng)
    scan_b = noisy_scan(POSE_UPDATE, ZIGZAG_EDGES, sensor, rng)
    first, last = segment(scan)
    first_b, last_b = segment(scan_b)
    print(
        f"zig-zag of 4 lines, {last - first + 1} beams in the segment "
        f"({last_b - first_b + 1} in the update scan); {args.repeats} calls, "
        f"median after {WARMUP_CALLS} warm-up calls\n"
    )
    print(f"{'case':44s} {'median':>8s} {'min':>8s}  {'target':>7s}       [ms]")

    presets = {
        "ModelConfig() (first order)": ModelConfig(),
        "ModelConfig.thesis() (UT)": ModelConfig.thesis(),
    }
    fits = {}
    for name, config in presets.items():
        fits[name] = fit = create_model(scan, first, last, POSE_BUILD, sensor, config)
        median, best = time_calls(
            lambda config=config: create_model(scan, first, last, POSE_BUILD, sensor, config),
            args.repeats,
        )
        note = f"{fit.n_object_lines} object lines, {fit.model.n_vertices} vertices"
        print(row(f"creation  {name}", median, best, TARGET_MS["creation"], note))

    detections = {}
    try:
        from vslam_gym.slam.detection import detect
    except ImportError as err:
        print(f"{'detection':44s} not available ({err})")
    else:
        for name, config in presets.items():
            model = fits[name].model

            def call(model=model, config=config):
                return detect(model, scan_b, first_b, last_b, POSE_UPDATE, sensor, config)

            try:
                result = call()
                median, best = time_calls(call, args.repeats)
            except Exception as err:  # noqa: BLE001 - report and go on
                print(f"{'detection  ' + name:44s} failed: {type(err).__name__}: {err}")
                continue
            detections[name] = result
            note = f"accepted={result.accepted}, mean d2 {result.mean_d2:.2f}"
            print(row(f"detection {name}", median, best, TARGET_MS["detection"], note))

    try:
        from vslam_gym.slam.update import update_model
    except ImportError as err:
        print(f"{'update':44s} not available ({err})")
    else:
        for name, config in presets.items():
            fit = fits[name]

            def call(fit=fit, config=config, association=None):
                return update_model(
                    fit.model,
                    scan_b,
                    first_b,
                    last_b,
                    POSE_UPDATE,
                    sensor,
                    config,
                    association=association,
                    object_vertices=fit.object_vertices,
                )

            try:
                result = call()
                median, best = time_calls(call, args.repeats)
            except Exception as err:  # noqa: BLE001 - report and go on
                print(f"{'update     ' + name:44s} failed: {type(err).__name__}: {err}")
                continue
            start, stop = result.object_vertices
            note = (
                f"{fit.model.n_vertices} -> {result.model.n_vertices} vertices, "
                f"{stop - start - 1} object lines"
            )
            print(row(f"update    {name}", median, best, TARGET_MS["update"], note))
            if detections.get(name) is not None:
                given = detections[name]
                median, best = time_calls(
                    lambda call=call, d=given: call(association=d), args.repeats
                )
                note = "association passed in (the detection's)"
                print(row("  update, association given", median, best, TARGET_MS["update"], note))

    print("\nUT versus first order on the same scan (all else equal):")
    for name, config in presets.items():
        base = name.split(" (")[0]
        print(f"  {base:22s} {compare_linearizations(scan, first, last, sensor, config)}")
    print(
        "\ntargets: creation <= {creation} ms, detection <= {detection} ms, "
        "update <= {update} ms".format(**TARGET_MS)
    )


if __name__ == "__main__":
    main()
