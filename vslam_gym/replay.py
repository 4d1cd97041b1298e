"""Run the estimator on a recorded Carmen lidar log and measure it (``vslam-gym replay``).

The log's corrected poses are the ground truth and only enter the metrics; the filter
sees the odometry increments (the log's own wheel odometry, ``logged``, or Thrun's
odometry model applied to the corrected poses with a seed, ``synthetic``) and the scans.

    vslam-gym replay intel.log.gz --odometry synthetic --seed 0 --preset default --out DIR
"""

from __future__ import annotations

import argparse
import json
import time
from collections.abc import Mapping, Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from vslam_gym.evaluation import (
    START_SCAN_MODES,
    add_jobs_argument,
    add_overrides_argument,
    add_range_perturbation_argument,
    check_range_perturbation,
    check_start_scan,
    final_position_error,
    heading_rmse,
    in_workers,
    json_safe,
    nees_summary,
    pose_nees,
    position_ate_rmse,
    progress_bar,
    seeds_argument,
    timing_summary,
    use_start_scan,
    write_tum,
)
from vslam_gym.logs import (
    CarmenConfig,
    CarmenLog,
    integrate_increments,
    logged_increments,
    read_carmen,
    synthetic_increments,
)
from vslam_gym.logs.carmen import PARAM_FOV, PARAM_RESOLUTION
from vslam_gym.slam.config import PREALIGN_MODES, SensorConfig
from vslam_gym.slam.filter import SlamConfig, VertexSLAM
from vslam_gym.slam.motion import compose

ODOMETRY_MODES = ("logged", "synthetic")
"""Where the odometry increments come from."""
DEFAULT_MAX_RANGE = 30.0
"""Readings beyond this [m] are treated as no return (the thesis clipped its data so)."""
DEFAULT_SIGMA_RANGE = 0.03
"""Range noise [m] assumed for the logs' lidar (the thesis's value)."""
DEFAULT_SIGMA_BEARING_DEG = 0.2
"""Bearing noise [deg] assumed for the logs' lidar (the thesis's value)."""


def sensor_for_log(log: CarmenLog, sigma_range: float, sigma_bearing_deg: float) -> SensorConfig:
    """The estimator's sensor model for a log: FOV and resolution from its bearings.

    The log's ``laser_front_laser_fov`` and ``laser_front_laser_resolution`` ``PARAM``
    lines, where it has them (a log written by :func:`vslam_gym.logs.write_carmen`), give
    them exactly.
    """
    if PARAM_FOV in log.params and PARAM_RESOLUTION in log.params:
        fov, res = float(log.params[PARAM_FOV]), float(log.params[PARAM_RESOLUTION])
    else:
        res = float(np.rad2deg(np.median(-np.diff(log.bearings))))
        ends = np.abs(np.rad2deg(log.bearings[[0, -1]]))
        fov = max(float(np.rad2deg(log.bearings[0] - log.bearings[-1])), 2.0 * float(ends.max()))
    return SensorConfig(
        fov_deg=fov,
        resolution_deg=res,
        max_range=float(log.max_range),
        sigma_range=sigma_range,
        sigma_bearing_deg=sigma_bearing_deg,
        lidar_offset=tuple(float(v) for v in log.lidar_offset),
    )


def replay(
    path: str | Path,
    odometry: str = "logged",
    seed: int = 0,
    preset: str = "default",
    max_scans: int | None = None,
    max_range: float = DEFAULT_MAX_RANGE,
    sigma_range: float = DEFAULT_SIGMA_RANGE,
    sigma_bearing_deg: float = DEFAULT_SIGMA_BEARING_DEG,
    progress: bool = False,
    prealign: str | None = None,
    config: SlamConfig | None = None,
    overrides: Mapping[str, Any] | None = None,
    range_perturbation: float = 0.0,
    bearing_offset_deg: float = 0.0,
    start_scan: str = "map",
) -> dict[str, Any]:
    """Feed a log to :class:`VertexSLAM` scan by scan; return the metrics and trajectories.

    Every scan after the first is a step. Scan 0, taken at the initial pose, is used as
    ``start_scan`` says (:func:`~vslam_gym.evaluation.use_start_scan`): ``"map"`` (the
    default) a step without motion, ``"matcher"`` the whole-scan matcher's first keyframe
    only (as the SLAM wrapper and ``vslam-gym evaluate`` use the scan of ``reset``: the
    replay of a log written by ``agents/evaluate_agents.py --carmen-logs`` then follows
    the closed-loop run), ``"none"`` unused.

    ``overrides`` (configuration sections, e.g. ``{"filter": {...}, "matcher": {...}}``,
    as ``vslam-gym replay --set``) apply over the preset; ``config`` replaces the preset's
    configuration (not both); ``prealign`` overrides ``FilterConfig.prealign`` last
    (None: keep it). ``range_perturbation``: every range the filter gets is multiplied
    by ``1 + this`` (at most ``MAX_RANGE_PERTURBATION``, as in ``vslam-gym evaluate``):
    ``1e-15`` changes the last bit of some ranges, so the run is another sample of the
    same filter's round-off (one run of a log is one draw of it).
    ``bearing_offset_deg`` is added to every bearing of the log
    (``CarmenConfig.bearing_offset_deg``; 0 for the Radish logs).

    Returns:
        A dict with ``metrics`` (``scans``, ``completed``, ``ate_rmse_m``,
        ``odom_ate_rmse_m``, ``final_error_m``, ``heading_rmse_rad``, ``nees_mean`` and
        ``nees_in_band_fraction`` (the pose NEES against the log's poses: meaningful where
        they are the truth, as in a simulated episode's log), ``landmarks``,
        ``step_ms_median``, ``step_ms_p95``, ``step_ms_parts`` (per part of a step,
        ``Belief.step_ms_parts``: its ``median`` and ``mean`` over the scans [ms]),
        ``prealign``, ``prealigned_fraction`` (steps that used the whole-scan match),
        ``range_perturbation``, ``bearing_offset_deg``, ``start_scan``, ``sensor`` (the
        lidar model: FOV and resolution from the log's bearings, maximum range, noise,
        offset),
        ``loop_closures`` (steps that fused a revisit match, ``FilterConfig.loop_closure``),
        ``error`` when not completed) and the ``true``, ``odometry`` and ``slam`` pose
        arrays ``(T, 3)``, ``times`` and the final ``belief``.

    Raises:
        ValueError: unknown odometry mode, malformed log (``CarmenFormatError``), unknown
            or invalid override, both ``config`` and ``overrides``, or a
            ``range_perturbation`` outside ``[0, MAX_RANGE_PERTURBATION]``.
    """
    if odometry not in ODOMETRY_MODES:
        raise ValueError(f"odometry must be one of {ODOMETRY_MODES}, got {odometry!r}")
    check_start_scan(start_scan)
    range_scale = 1.0 + check_range_perturbation(range_perturbation)
    if config is not None and overrides:
        raise ValueError("give either config or overrides, not both")
    if overrides:
        config = SlamConfig.from_dict({"preset": preset, **overrides})
    if max_scans is not None and not int(max_scans) >= 1:
        raise ValueError(f"max_scans must be at least 1, got {max_scans!r}")
    log = read_carmen(
        path, CarmenConfig(max_range=max_range, bearing_offset_deg=bearing_offset_deg)
    )
    n = log.num_scans if max_scans is None else min(log.num_scans, int(max_scans))
    if odometry == "logged":
        increments = logged_increments(log)[: n - 1]
    else:
        increments = synthetic_increments(log, seed)[: n - 1]
    config = config or SlamConfig.preset(preset)
    if prealign is not None:
        config = replace(config, filter=replace(config.filter, prealign=prealign))
    sensor = sensor_for_log(log, sigma_range, sigma_bearing_deg)
    slam = VertexSLAM(sensor, config, initial_pose=log.poses[0])
    slam_poses: list[np.ndarray] = []
    lidar_poses: list[np.ndarray] = []
    lidar_covs: list[np.ndarray] = []
    step_ms: list[float] = []
    parts: dict[str, list[float]] = {}
    prealigned = loop_closures = 0
    completed, error = True, ""
    bar = progress_bar(n, Path(path).name, progress, leave=True, unit="scan")
    belief = slam.belief
    for k in range(n):
        try:
            ranges = log.ranges[k] if range_scale == 1.0 else log.ranges[k] * range_scale
            if k == 0:  # taken at the initial pose
                belief = use_start_scan(slam, start_scan, ranges, log.bearings)
            else:
                belief = slam.step(increments[k - 1], ranges, log.bearings)
        except (ValueError, np.linalg.LinAlgError) as exc:  # report, do not hide
            completed, error = False, f"scan {k}: {type(exc).__name__}: {exc}"
            break
        slam_poses.append(belief.robot_pose)
        lidar_poses.append(belief.pose)
        lidar_covs.append(belief.pose_cov)
        step_ms.append(belief.step_ms)
        for name, ms in belief.step_ms_parts.items():
            parts.setdefault(name, []).append(ms)
        prealigned += int(belief.prealigned)
        loop_closures += int(belief.loop_closed)
        if bar is not None:
            bar.update(1)
    if bar is not None:
        bar.close()
    if not slam_poses:  # nothing to measure: the cause is the error itself
        raise ValueError(f"{path}: {error}")
    slam_arr = np.array(slam_poses).reshape(-1, 3)
    true = log.poses[: slam_arr.shape[0]]
    odo = integrate_increments(log.poses[0], increments)[: slam_arr.shape[0]]
    finite = bool(np.all(np.isfinite(slam_arr)))
    # the pose covariance is the lidar's: its NEES against the log's poses moved to the lidar
    offset = np.asarray(sensor.lidar_offset, dtype=float)
    true_lidar = np.array([compose(pose, offset) for pose in true]).reshape(-1, 3)
    nees = nees_summary(
        pose_nees(
            np.array(lidar_poses).reshape(-1, 3),
            np.array(lidar_covs).reshape(-1, 3, 3),
            true_lidar,
        )
    )
    median_ms, p95_ms = timing_summary(np.array(step_ms))
    metrics: dict[str, Any] = {
        "log": str(path),
        "odometry": odometry,
        "seed": seed,
        "preset": preset,
        "overrides": dict(overrides or {}),
        "scans": int(slam_arr.shape[0]),
        "completed": completed and finite and slam_arr.shape[0] == n,
        "ate_rmse_m": position_ate_rmse(slam_arr, true),
        "odom_ate_rmse_m": position_ate_rmse(odo, true),
        "final_error_m": final_position_error(slam_arr, true),
        "heading_rmse_rad": heading_rmse(slam_arr, true),
        "nees_mean": nees["nees_mean"],
        "nees_in_band_fraction": nees["nees_in_band_fraction"],
        "landmarks": len(belief.landmarks),
        "step_ms_median": median_ms,
        "step_ms_p95": p95_ms,
        "step_ms_parts": {
            name: {"median": float(np.median(ms)), "mean": float(np.mean(ms))}
            for name, ms in parts.items()
        },
        "prealign": config.filter.prealign,
        "prealigned_fraction": prealigned / max(len(step_ms), 1),
        "range_perturbation": float(range_perturbation),
        "bearing_offset_deg": float(bearing_offset_deg),
        "start_scan": start_scan,
        "sensor": {
            "fov_deg": sensor.fov_deg,
            "resolution_deg": sensor.resolution_deg,
            "max_range": sensor.max_range,
            "sigma_range": sensor.sigma_range,
            "sigma_bearing_deg": sensor.sigma_bearing_deg,
            "lidar_offset": list(sensor.lidar_offset),
        },
        "loop_closures": loop_closures,
    }
    if error:
        metrics["error"] = error
    return {
        "metrics": metrics,
        "true": true,
        "odometry": odo,
        "slam": slam_arr,
        "times": np.arange(slam_arr.shape[0], dtype=float),
        "belief": belief,
        "log": log,
    }


def plot_replay(result: dict[str, Any], out: Path) -> None:
    """Save the trajectories and the landmark map over all scans at the corrected poses."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from vslam_gym.slam.plotting import plot_models

    log: CarmenLog = result["log"]
    fig, ax = plt.subplots(figsize=(8, 8))
    ax.plot(*result["true"][:, :2].T, "k-", label="corrected (ground truth)")
    ax.plot(*result["odometry"][:, :2].T, "--", color="tab:orange", label="odometry")
    ax.plot(*result["slam"][:, :2].T, "-", color="tab:blue", label="SLAM")
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.legend(loc="best", fontsize="small")
    ax.set_title(f"{Path(str(result['metrics']['log'])).name}: trajectories")
    fig.savefig(out / "trajectories.png", dpi=120)
    plt.close(fig)

    fig, ax = plt.subplots(figsize=(8, 8))
    stride = max(1, log.num_scans // 300)
    for k in range(0, result["true"].shape[0], stride):
        hit = ~log.no_return[k]
        a = result["true"][k, 2] + log.bearings[hit]
        r = log.ranges[k, hit]
        ax.plot(
            result["true"][k, 0] + r * np.cos(a),
            result["true"][k, 1] + r * np.sin(a),
            ",",
            color="0.6",
        )
    plot_models([lm.model for lm in result["belief"].landmarks], ax=ax)
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title("landmark map over the scans at the corrected poses")
    fig.savefig(out / "map.png", dpi=120)
    plt.close(fig)


def add_replay_parser(subparsers: argparse._SubParsersAction) -> None:
    """Add ``vslam-gym replay`` to the command line."""
    parser = subparsers.add_parser(
        "replay",
        help="run the SLAM on a Carmen lidar log and measure it",
        description="Feed a Carmen log (.log or .log.gz) to the estimator scan by scan; write "
        "DIR/metrics.json, trajectories and a landmark map, and TUM trajectories.",
    )
    parser.add_argument("log", help="path to the log")
    parser.add_argument("--odometry", choices=ODOMETRY_MODES, default="logged")
    parser.add_argument(
        "--seed",
        "--seeds",
        dest="seeds",
        type=seeds_argument,
        default=[0],
        help="seed(s) of the synthetic odometry: one seed 3, a range 0-4 or a list 0,3,5 "
        "(several: each run in OUT/seedS/, and their summary in OUT/metrics.json)",
    )
    parser.add_argument(
        "--preset",
        choices=("default", "thesis", "logs", "fast"),
        default="default",
        help="configuration preset (default %(default)s); 'logs' is the one measured on "
        "real lidar logs: whole-scan prealignment, loop closure, README 'Replaying a "
        "Carmen log'",
    )
    parser.add_argument(
        "--prealign",
        choices=PREALIGN_MODES,
        default=None,
        help="whole-scan alignment before the landmark association (FilterConfig.prealign; "
        "default: the preset's)",
    )
    add_overrides_argument(parser, '{"filter": {"candidate_max_median_distance": 0.5}}')
    parser.add_argument("--out", required=True, help="output directory")
    parser.add_argument("--max-scans", type=int, default=None, help="replay only the first N")
    parser.add_argument(
        "--max-range",
        type=float,
        default=DEFAULT_MAX_RANGE,
        help="readings beyond this [m] are no return (default %(default)s)",
    )
    parser.add_argument(
        "--sigma-range",
        type=float,
        default=DEFAULT_SIGMA_RANGE,
        help="range noise standard deviation of the lidar [m] (default %(default)s)",
    )
    parser.add_argument(
        "--sigma-bearing-deg",
        type=float,
        default=DEFAULT_SIGMA_BEARING_DEG,
        help="bearing noise standard deviation of the lidar [deg] (default %(default)s)",
    )
    parser.add_argument(
        "--bearing-offset-deg",
        type=float,
        default=0.0,
        help="added to every beam's bearing [deg] (CarmenConfig.bearing_offset_deg): for a "
        "log whose lidar convention is not Carmen's; benchmarks/log_bearing_check.py tells "
        "it from the log's poses (default %(default)s, right for the Radish logs)",
    )
    parser.add_argument(
        "--start-scan",
        choices=START_SCAN_MODES,
        default="map",
        help="what the filter does with scan 0, taken at the initial pose: a step without "
        "motion ('map', default), the matcher's first keyframe ('matcher', as the SLAM "
        "wrapper and vslam-gym evaluate do) or nothing ('none')",
    )
    add_range_perturbation_argument(parser)
    add_jobs_argument(parser, "seeds")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    parser.set_defaults(handler=cmd_replay)


def write_replay(result: dict[str, Any], out: Path) -> None:
    """Write a replay's ``metrics.json``, TUM trajectories and figures to ``out``."""
    out.mkdir(parents=True, exist_ok=True)
    (out / "metrics.json").write_text(json.dumps(json_safe(result["metrics"]), indent=2))
    for name in ("true", "odometry", "slam"):
        write_tum(out / f"{name}.tum", result["times"], result[name])
    plot_replay(result, out)


def _replay_to(out: Path, kwargs: dict[str, Any]) -> dict[str, Any]:
    """Replay with ``kwargs``, write the result to ``out``; return its metrics."""
    result = replay(**kwargs)
    write_replay(result, out)
    return result["metrics"]


SUMMARY_KEYS = ("ate_rmse_m", "final_error_m", "heading_rmse_rad", "step_ms_median")
"""Metrics summarised over the seeds of a multi-seed replay."""


def summarize_seeds(per_seed: Sequence[Mapping[str, Any]]) -> dict[str, Any]:
    """Mean, median, maximum and standard error over seeds of :data:`SUMMARY_KEYS`.

    Also ``seeds``, ``completed`` (every run) and ``odom_ate_rmse_m`` (mean).
    """
    if not per_seed:
        raise ValueError("no seed to summarise")
    out: dict[str, Any] = {
        "seeds": [int(m["seed"]) for m in per_seed],
        "completed": all(bool(m["completed"]) for m in per_seed),
        "odom_ate_rmse_m": float(np.mean([m["odom_ate_rmse_m"] for m in per_seed])),
    }
    for key in SUMMARY_KEYS:
        v = np.array([float(m[key]) for m in per_seed])
        out[key] = {
            "mean": float(v.mean()),
            "median": float(np.median(v)),
            "max": float(v.max()),
            "sem": float(v.std(ddof=1) / np.sqrt(v.size)) if v.size > 1 else float("nan"),
        }
    return out


def _summary_line(metrics: Mapping[str, Any]) -> str:
    def shown(k: str, v: Any) -> str:
        if k == "step_ms_parts":  # the means [ms]
            return "step_ms_mean " + " / ".join(f"{p} {s['mean']:.1f}" for p, s in v.items())
        if k == "range_perturbation":  # 1e-15 and the like: no fixed decimals
            return f"{k} {v:g}"
        return f"{k} {v:.3f}" if isinstance(v, float) else f"{k} {v}"

    def kept(k: str, v: Any) -> bool:
        if k == "overrides":  # only when there are any
            return bool(v)
        if k == "seed":  # the synthetic odometry's; the logged odometry has none
            return metrics.get("odometry") != "logged"
        return k != "sensor"

    return ", ".join(shown(k, v) for k, v in metrics.items() if kept(k, v))


def cmd_replay(args: argparse.Namespace) -> int:
    """Handler of ``vslam-gym replay``."""
    start = time.perf_counter()
    seeds = list(args.seeds)
    if len(seeds) > 1 and args.odometry == "logged":
        raise ValueError(
            "the logged odometry has no seed: give one --seed (for other samples of the same "
            "run use --range-perturbation 1e-15, 3e-15, ...)"
        )
    kwargs = dict(
        path=args.log,
        odometry=args.odometry,
        preset=args.preset,
        max_scans=args.max_scans,
        max_range=args.max_range,
        sigma_range=args.sigma_range,
        sigma_bearing_deg=args.sigma_bearing_deg,
        prealign=args.prealign,
        overrides=args.overrides,
        range_perturbation=args.range_perturbation,
        bearing_offset_deg=args.bearing_offset_deg,
        start_scan=args.start_scan,
    )
    out = Path(args.out)
    if len(seeds) == 1:
        metrics = _replay_to(out, {**kwargs, "seed": seeds[0], "progress": not args.no_progress})
        print(_summary_line(metrics))
        print(f"wall time {time.perf_counter() - start:.1f} s; wrote {out}/metrics.json")
        return 0
    dirs = [out / f"seed{seed}" for seed in seeds]
    jobs = [{**kwargs, "seed": seed, "progress": not args.no_progress} for seed in seeds]
    if args.jobs > 1:
        calls = [(d, {**job, "progress": False}) for d, job in zip(dirs, jobs, strict=True)]
        bar = progress_bar(len(seeds), "seeds", not args.no_progress, unit="run")
        per_seed = list(in_workers(_replay_to, calls, args.jobs, bar))  # parallel bars clash
    else:
        per_seed = [_replay_to(d, job) for d, job in zip(dirs, jobs, strict=True)]
    for metrics in per_seed:
        print(_summary_line(metrics))
    summary = summarize_seeds(per_seed)
    first = per_seed[0]
    report = {
        **{k: first[k] for k in ("log", "odometry", "preset", "overrides", "range_perturbation")},
        "summary": summary,
        "per_seed": per_seed,
    }
    out.mkdir(parents=True, exist_ok=True)
    (out / "metrics.json").write_text(json.dumps(json_safe(report), indent=2))
    listed = ",".join(str(seed) for seed in seeds)
    for key in SUMMARY_KEYS:
        v = summary[key]
        print(
            f"{key} over seeds {listed}: mean {v['mean']:.3f} (sem {v['sem']:.3f}), "
            f"median {v['median']:.3f}, max {v['max']:.3f}"
        )
    print(f"completed {summary['completed']}; odometry ATE mean {summary['odom_ate_rmse_m']:.3f}")
    print(f"wall time {time.perf_counter() - start:.1f} s; wrote {out}/metrics.json")
    return 0
