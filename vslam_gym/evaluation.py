"""Evaluation of the vertex-landmark SLAM on simulated worlds.

One episode (:func:`run_episode`) drives a world's route in :class:`LidarWorldEnv` with
the :class:`~vslam_gym.control.RouteFollower` on the TRUE pose and runs
:class:`~vslam_gym.slam.filter.VertexSLAM` on every step with the noisy odometry and scan
(and the nominal beam bearings). The ground truth (true pose, obstacle id of every beam)
is logged next to the belief and used only by the metrics; the filter never sees it.

Metrics (pure functions over arrays, below) are computed over the ``T`` filter steps
(the initial pose, given to the filter, is not counted). No trajectory alignment: the
filter's map frame is the world frame, both start at the true initial pose.

:func:`evaluate` runs several seeds and writes, into one directory:

- ``metrics.json``: per seed and the mean over seeds (see :func:`episode_metrics`);
- per seed ``N``: ``trajectories_seed{N}.png``, ``map_seed{N}.png``, ``nees_seed{N}.png``;
  TUM trajectories ``true_seed{N}.tum``, ``odometry_seed{N}.tum``, ``slam_seed{N}.tum``
  (readable by ``evo``, e.g. ``evo_ape tum true_seed0.tum slam_seed0.tum``); and
  ``episode_seed{N}.npz`` with the per-step arrays.

Command line (wired into ``vslam-gym`` by :func:`add_evaluate_parser`)::

    vslam-gym evaluate --world house --seeds 0-9 --preset default --out results/house

Frames and units: world frame (right-handed, x east, y north, theta counter-clockwise
from x); metres, radians, seconds; step times in milliseconds.
"""

from __future__ import annotations

import argparse
import collections
import dataclasses
import json
import math
import os
import platform
import sys
import time
from collections import Counter
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from scipy.special import gammaincinv

from vslam_gym.slam.config import SensorConfig
from vslam_gym.slam.filter import Belief, SlamConfig, VertexSLAM
from vslam_gym.slam.geometry import polar_to_cartesian, wrap_angle
from vslam_gym.slam.motion import increments_between, motion_update, odometry_noise
from vslam_gym.surfaces import SurfacePieces, surface_pieces

__all__ = [
    "ASSOCIATION_OUTCOMES",
    "CREATION_CAUSES",
    "NEES_PARTS",
    "START_SCAN_MODES",
    "DecisionRecord",
    "EpisodeLog",
    "SeedsError",
    "add_evaluate_parser",
    "add_jobs_argument",
    "add_range_perturbation_argument",
    "association_precision",
    "check_range_perturbation",
    "check_start_scan",
    "chi2_interval",
    "cmd_evaluate",
    "compound_precision",
    "creation_causes",
    "duplicate_fraction",
    "episode_metrics",
    "evaluate",
    "final_position_error",
    "format_table",
    "heading_rmse",
    "in_workers",
    "json_safe",
    "landmark_majority_ids",
    "machine_description",
    "majority_id",
    "name_or_mapping",
    "mean_nees_interval",
    "nees_part_means",
    "nees_summary",
    "parse_seeds",
    "pose_nees",
    "position_ate_rmse",
    "progress_bar",
    "run_episode",
    "seeds_argument",
    "sem_metrics",
    "sensor_from_lidar",
    "set_obstacles",
    "slam_config",
    "timing_summary",
    "use_start_scan",
    "write_tum",
    "yaw_quaternion",
]

POSE_DOF = 3
"""Degrees of freedom of the pose NEES ``(x, y, theta)``."""
NEES_PARTS = {"position": (0, 1), "heading": (2,)}
"""The pose components of the NEES parts ``nees_position_mean`` / ``nees_heading_mean``."""
CONFIDENCE = 0.95
"""Probability mass of the two-sided chi-square intervals (per-step band, mean NEES)."""
TIMING_PERCENTILE = 95.0
"""Upper percentile [%] of the step times reported next to the median."""
ELLIPSE_N_SIGMA = 3.0
"""Standard deviations of the pose and landmark ellipses drawn in the figures."""
ELLIPSE_EVERY = 20
"""The trajectory figure draws a pose ellipse every this many steps."""
MAP_MARGIN = 1.5
"""Margin [m] around the true obstacles and path in the map figure (unknown lines that
run to the maximum range are clipped)."""
MAP_LABELS_AT_MOST = 40
"""The map figure labels each landmark (``L<id>:o<obstacle>``) only up to this many."""
MAP_UNKNOWN_ALPHA = 0.3
"""Opacity of the unknown lines in the map figure (object lines are opaque)."""
DEFAULT_STEP_LIMIT = 5000
"""Step budget of an episode when ``max_steps`` is not given (a robot that cannot finish
its route, e.g. stuck on an obstacle, must not run forever): 500 s of simulated time at
the default control period, ten times the longest shipped route."""
NO_HIT = -1
"""``info["hit_ids"]`` of a beam with no return."""
SURFACE_HIT_RADIUS = 0.1
"""A beam hit counts for the surface piece (:mod:`vslam_gym.surfaces`) whose boundary is
within this distance [m]: over three standard deviations of the simulated range noise."""
ASSOCIATION_OUTCOMES = ("updated", "associated")
"""Decision outcomes that are a set-to-landmark association."""
MAP_OUTCOMES = ("created", "updated")
"""Decision outcomes whose set votes for the landmark's obstacle id."""
OBSTACLE_SHARE = 0.1
"""An obstacle hit by at least this fraction of a set's hitting beams is one of the set's
obstacles (:attr:`DecisionRecord.obstacles`, :func:`compound_precision`)."""
CREATION_CAUSES = ("new", "far", "gated", "rejected", "accepted")
"""Why a set made a new landmark (:func:`creation_causes`), by what became of the
candidates that model the set's own obstacle: none was a candidate (``"new"``), or the
one that came closest to an association was not aligned (``"far"``), had its ICP result
gated, had its detection test (or the object-beam test) fail, or was accepted."""
TIMING_KEYS = (
    "step_ms_median",
    "step_ms_p95",
    "step_ms_mean",
    "measured_step_ms_median",
    "wall_s",
)
"""Metrics that measure time (they differ between identical runs)."""

ProgressCallback = Callable[[int, Belief], None]
"""Called after every step with the step number (1-based) and the belief."""


class SeedsError(ValueError):
    """A ``--seeds`` specification that is not ``A-B``, ``a,b,c`` or ``n``."""


# ---------------------------------------------------------------------------- logging


@dataclass(frozen=True)
class DecisionRecord:
    """One measurement set's decision at one step, with its ground-truth obstacle.

    Attributes:
        step: the filter step (1-based) of the scan.
        first: scan index of the set's first beam.
        last: scan index of its last beam (inclusive).
        outcome: the filter's outcome (``SetDecision.outcome``).
        landmark: the landmark id it was associated with or created as, else -1.
        majority_id: the obstacle id hit by most of the set's beams (:func:`majority_id`).
        obstacles: the ids hit by at least :data:`OBSTACLE_SHARE` of the set's hitting
            beams, most hit first (:func:`set_obstacles`); empty when not recorded.
        candidates: the landmarks tried (``SetDecision.candidates``: ``(id, icp_reason,
            mean_d2, var_d2, accepted)``); empty when not recorded.
    """

    step: int
    first: int
    last: int
    outcome: str
    landmark: int
    majority_id: int
    obstacles: tuple[int, ...] = ()
    candidates: tuple[tuple[int, str, float, float, bool], ...] = ()


@dataclass
class EpisodeLog:
    """Everything one episode recorded; arrays have one row per pose (``T + 1``).

    Row 0 is the initial pose (given to the filter), row ``t`` the pose after step ``t``.

    Attributes:
        world_name: the world's name.
        world: the :class:`~vslam_gym.sim.world.World` driven in (true obstacles).
        preset: the :class:`SlamConfig` preset name.
        seed: the ``reset`` seed.
        config: the filter's configuration (preset with the world's odometry alphas).
        times: ``(T + 1,)`` simulated time [s].
        true_poses: ``(T + 1, 3)`` true robot poses ``(x [m], y [m], theta [rad])``.
        odometry_poses: ``(T + 1, 3)`` poses integrated from the noisy odometry.
        slam_poses: ``(T + 1, 3)`` SLAM robot pose means.
        slam_covs: ``(T + 1, 3, 3)`` SLAM pose covariances [m^2, m rad, rad^2] (the lidar
            sits at the robot centre in simulation, so lidar and robot pose coincide):
            ``Belief.pose_cov``.
        filter_covs: ``(T + 1, 3, 3)`` the filter's own pose covariances
            (``Belief.filter_pose_cov``; the same as ``slam_covs`` when
            ``FilterConfig.error_noise_scale`` is 0), or None.
        step_ms: ``(T,)`` filter wall time per step [ms] (``Belief.step_ms``).
        measured: ``(T,)`` bool, the step ran the measurement update (``Belief.measured``;
            a motion filter skips it on the others).
        landmark_counts: ``(T + 1,)`` landmarks in the belief.
        collisions: ``(T,)`` bool, the robot touched an obstacle during the step.
        decisions: every set decision of every step, in order.
        final_belief: the belief after the last step.
        route_done: the route follower reached its last waypoint.
        wall_s: wall time [s] of the episode (simulation, filter and logging).
        loop_closures: steps that fused a revisit match (``Belief.loop_closed``).
        loop_match_nees: ``(loop_closures,)`` each fused revisit match's NEES against the
            true pose (:func:`loop_match_nees`), or None when not recorded.
        surface_hits: per surface piece of the world (:func:`vslam_gym.surfaces.surface_pieces`)
            the most beams of one scan that hit it (computed from the true pose); None
            when not recorded.
    """

    world_name: str
    world: Any
    preset: str
    seed: int
    config: SlamConfig
    times: np.ndarray
    true_poses: np.ndarray
    odometry_poses: np.ndarray
    slam_poses: np.ndarray
    slam_covs: np.ndarray
    step_ms: np.ndarray
    measured: np.ndarray
    landmark_counts: np.ndarray
    collisions: np.ndarray
    decisions: list[DecisionRecord] = field(default_factory=list)
    final_belief: Belief | None = None
    route_done: bool = False
    wall_s: float = 0.0
    loop_closures: int = 0
    surface_hits: np.ndarray | None = None
    filter_covs: np.ndarray | None = None
    loop_match_nees: np.ndarray | None = None

    @property
    def steps(self) -> int:
        """Number of filter steps ``T``."""
        return int(self.step_ms.size)


def sensor_from_lidar(lidar: Any) -> SensorConfig:
    """The estimator's :class:`SensorConfig` of a simulated ``LidarSpec`` (no offset).

    Raises:
        ValueError: the lidar cannot be filtered, e.g. a noise-free lidar (``[lidar]
            sigma_range = 0`` in a world file: the simulator takes it, the filter's
            likelihoods need noise); the message names the lidar setting.
    """
    try:
        return SensorConfig(
            fov_deg=lidar.fov_deg,
            resolution_deg=lidar.resolution_deg,
            max_range=lidar.max_range,
            sigma_range=lidar.sigma_range,
            sigma_bearing_deg=lidar.sigma_bearing_deg,
        )
    except ValueError as exc:
        raise ValueError(
            f"the world's lidar cannot be given to the SLAM filter ([lidar] of the world "
            f"file or the env's lidar overrides): {exc}"
        ) from exc


def sets_odometry_alphas(overrides: Any) -> bool:
    """Whether a ``SlamConfig.from_dict`` mapping sets ``filter.odometry_alphas`` itself.

    Callers that give the filter the world's odometry noise keep such a choice (a
    deliberately wrong noise model, say) instead of overwriting it.
    """
    if not isinstance(overrides, Mapping):
        return False
    section = overrides.get("filter")
    return isinstance(section, Mapping) and "odometry_alphas" in section


def slam_config(preset: str | SlamConfig, odometry_alphas: Sequence[float]) -> SlamConfig:
    """A preset name (:meth:`SlamConfig.preset`) or config, with odometry ``alphas``."""
    base = preset if isinstance(preset, SlamConfig) else SlamConfig.preset(preset)
    alphas = tuple(float(a) for a in odometry_alphas)
    return dataclasses.replace(
        base, filter=dataclasses.replace(base.filter, odometry_alphas=alphas)
    )


MAX_RANGE_PERTURBATION = 1e-9
"""Largest ``range_perturbation`` of :func:`run_episode`: a round-off probe, not noise."""


def check_range_perturbation(value: float) -> float:
    """``value`` if it is a valid ``range_perturbation``, else ValueError naming it."""
    if not (isinstance(value, int | float) and 0.0 <= value <= MAX_RANGE_PERTURBATION):
        raise ValueError(
            f"range_perturbation must lie in [0, {MAX_RANGE_PERTURBATION:g}] (a round-off "
            f"probe such as 1e-15), got {value!r}"
        )
    return float(value)


START_SCAN_MODES = ("matcher", "map", "none")
"""What a fresh filter does with the scan taken at its initial pose (:func:`use_start_scan`)."""


def check_start_scan(mode: object) -> str:
    """``mode`` if it is one of :data:`START_SCAN_MODES`, else ValueError naming it."""
    if mode not in START_SCAN_MODES:
        raise ValueError(f"start_scan must be one of {START_SCAN_MODES}, got {mode!r}")
    return str(mode)


def use_start_scan(slam: VertexSLAM, mode: str, ranges, bearings) -> Belief:
    """Give a fresh filter the scan taken at its initial pose; the belief after it.

    ``mode`` (:data:`START_SCAN_MODES`):

    - ``"matcher"`` (the default of :func:`run_episode` and the SLAM wrapper): the
      whole-scan matcher's first keyframe (:meth:`VertexSLAM.add_start_scan`), so the
      first step is aligned to the start pose; no landmark is made from it;
    - ``"map"``: a step without motion, which makes landmarks from it too;
    - ``"none"``: not used; the first scan the filter sees is the first step's (the
      behaviour before session 33).

    Measured (docs/measurements.md, "Session 33"): ``"matcher"`` better than ``"none"``
    on every route and on the explorer; ``"map"`` as good on the explorer and ``curved``
    but worse on ``single_landmark``.

    Raises:
        ValueError: an unknown ``mode``, or a malformed scan (nothing changes).
    """
    check_start_scan(mode)
    if mode == "map":
        return slam.step(np.zeros(3), ranges, bearings)
    if mode == "matcher":
        slam.add_start_scan(ranges, bearings)
    return slam.belief


def run_episode(
    world: str,
    seed: int,
    preset: str = "default",
    max_steps: int | None = None,
    progress: ProgressCallback | None = None,
    overrides: Mapping[str, Any] | None = None,
    range_perturbation: float = 0.0,
    start_scan: str = "matcher",
) -> EpisodeLog:
    """Drive a world's route with SLAM in the loop and log truth and belief per step.

    The route follower steers on the true pose; the filter gets only
    ``obs["odometry"]``, ``obs["scan"]`` and the nominal bearings ``info["bearings"]``.
    The episode ends when the route is done or after ``max_steps`` steps
    (:data:`DEFAULT_STEP_LIMIT` when None).

    Args:
        world: shipped world name or path to a TOML world file (it needs a route).
        seed: seed of ``env.reset``.
        preset: a :meth:`SlamConfig.preset` name (or a ``SlamConfig``).
        max_steps: largest number of steps, >= 1.
        progress: optional callback after every step (step number, belief).
        overrides: optional configuration sections applied over the preset
            (:meth:`SlamConfig.from_dict`); the log keeps the preset's name.
        range_perturbation: every range the filter gets is multiplied by ``1 + this``
            (at most :data:`MAX_RANGE_PERTURBATION`; the simulation is unchanged). A
            value like ``1e-15`` changes the last bit of some ranges: the run is then
            another sample of the same filter's round-off, which is how the spread of
            a configuration's figures is measured ("Accuracy and loop closing" in
            docs/status.md).
        start_scan: what the filter does with the scan of ``reset``, taken at the start
            pose (:func:`use_start_scan`: ``"matcher"``, ``"map"`` or ``"none"``); it is
            not a step of the log.

    Returns:
        The episode log.

    Raises:
        ValueError: an unknown world, preset or ``start_scan``, a world without a route,
            ``max_steps < 1``.
    """
    from vslam_gym.control import RouteFollower
    from vslam_gym.env import LidarWorldEnv

    if max_steps is not None and max_steps < 1:
        raise ValueError(f"max_steps must be >= 1, got {max_steps}")
    check_range_perturbation(range_perturbation)
    check_start_scan(start_scan)
    range_scale = 1.0 + float(range_perturbation)
    limit = DEFAULT_STEP_LIMIT if max_steps is None else int(max_steps)
    env = LidarWorldEnv(world=world)
    if env.world is None or env.world.route is None:
        raise ValueError(f"world {world!r} has no [route] to drive")
    base = SlamConfig.from_dict({"preset": preset, **overrides}) if overrides else preset
    if sets_odometry_alphas(overrides):  # the caller's noise model, not the world's
        config = base
    else:
        config = slam_config(base, env.world.odometry.alphas)
    sensor = sensor_from_lidar(env.lidar_spec)
    period = env.physics_config.control_period
    pieces = surface_pieces(env.world)  # cached per world; not part of the episode's time
    surface_hits = np.zeros(pieces.count, dtype=np.intp)
    start = time.perf_counter()
    obs, info = env.reset(seed=seed)
    slam = VertexSLAM(sensor, config, initial_pose=info["pose"])

    def filter_ranges(scan: np.ndarray) -> np.ndarray:
        """The ranges the filter gets (``range_perturbation``)."""
        return scan if range_scale == 1.0 else np.asarray(scan, dtype=float) * range_scale

    belief = use_start_scan(slam, start_scan, filter_ranges(obs["scan"]), info["bearings"])
    follower = RouteFollower(env.world.route)
    true_poses, odom_poses = [info["pose"]], [info["odom_pose"]]
    slam_poses, slam_covs = [belief.robot_pose], [belief.pose_cov]
    filter_covs = [belief.filter_pose_cov]
    step_ms, measured, counts, collisions = [], [], [len(belief.landmarks)], []
    decisions: list[DecisionRecord] = []
    loop_closures, match_nees = 0, []
    try:
        for step in range(1, limit + 1):
            action = follower(info["pose"])
            if follower.done:
                break
            obs, _, terminated, _, info = env.step(action)
            belief = slam.step(obs["odometry"], filter_ranges(obs["scan"]), info["bearings"])
            true_poses.append(info["pose"])
            odom_poses.append(info["odom_pose"])
            slam_poses.append(belief.robot_pose)
            slam_covs.append(belief.pose_cov)
            filter_covs.append(belief.filter_pose_cov)
            step_ms.append(belief.step_ms)
            measured.append(belief.measured)
            counts.append(len(belief.landmarks))
            collisions.append(bool(info["collision"]))
            loop_closures += int(belief.loop_closed)
            if (fused := loop_match_nees(belief, info["pose"])) is not None:
                match_nees.append(fused)
            hit_ids = info["hit_ids"]
            _count_surface_hits(
                surface_hits, pieces, info["pose"], obs["scan"], info["bearings"], hit_ids
            )
            decisions.extend(
                DecisionRecord(
                    step,
                    d.first,
                    d.last,
                    d.outcome,
                    d.landmark,
                    majority_id(hit_ids[d.first : d.last + 1]),
                    set_obstacles(hit_ids[d.first : d.last + 1]),
                    d.candidates,
                )
                for d in belief.decisions
            )
            if progress is not None:
                progress(step, belief)
            if terminated:
                break
        else:
            follower(info["pose"])  # a last check: the final step may reach the end
    finally:
        env.close()
    n = len(true_poses)
    return EpisodeLog(
        world_name=env.world.name,
        world=env.world,
        preset=preset,
        seed=int(seed),
        config=config,
        times=np.arange(n) * period,
        true_poses=np.array(true_poses, dtype=float),
        odometry_poses=np.array(odom_poses, dtype=float),
        slam_poses=np.array(slam_poses, dtype=float),
        slam_covs=np.array(slam_covs, dtype=float),
        filter_covs=np.array(filter_covs, dtype=float),
        step_ms=np.array(step_ms, dtype=float),
        measured=np.array(measured, dtype=bool),
        landmark_counts=np.array(counts, dtype=int),
        collisions=np.array(collisions, dtype=bool),
        decisions=decisions,
        final_belief=belief,
        route_done=follower.done,
        wall_s=time.perf_counter() - start,
        loop_closures=loop_closures,
        surface_hits=surface_hits,
        loop_match_nees=np.array(match_nees, dtype=float),
    )


def _count_surface_hits(
    counts: np.ndarray,
    pieces: SurfacePieces,
    pose: np.ndarray,
    ranges: np.ndarray,
    bearings: np.ndarray,
    hit_ids: np.ndarray,
) -> None:
    """Raise ``counts`` (per surface piece) to this scan's beams on each piece, in place.

    The hit points are computed from the TRUE pose (the lidar sits at the robot centre
    in simulation), the measured ranges and the nominal bearings: ground truth only.
    """
    on = pieces.hit_pieces(polar_to_cartesian(ranges, bearings, pose), hit_ids, SURFACE_HIT_RADIUS)
    on = on[on >= 0]
    if on.size:
        np.maximum(counts, np.bincount(on, minlength=counts.size), out=counts)


# ---------------------------------------------------------------------------- metrics


def _poses(name: str, poses: np.ndarray, columns: int) -> np.ndarray:
    arr = np.asarray(poses, dtype=float)
    if arr.ndim != 2 or arr.shape[1] < columns or arr.shape[0] == 0:
        raise ValueError(f"{name} must have shape (N, >={columns}) with N >= 1, got {arr.shape}")
    return arr


def _same_length(a: np.ndarray, b: np.ndarray) -> None:
    if a.shape[0] != b.shape[0]:
        raise ValueError(f"estimate has {a.shape[0]} poses but the truth has {b.shape[0]}")


def position_ate_rmse(estimated: np.ndarray, true: np.ndarray) -> float:
    """Absolute trajectory error of the position: RMSE [m] over poses, no alignment.

    Args:
        estimated: ``(N, >=2)`` estimated poses; columns 0-1 are ``(x, y)`` [m].
        true: ``(N, >=2)`` true poses at the same times.

    Returns:
        ``sqrt(mean_t |p_est,t - p_true,t|^2)`` [m].
    """
    est, ref = _poses("estimated", estimated, 2), _poses("true", true, 2)
    _same_length(est, ref)
    d = est[:, :2] - ref[:, :2]
    return float(np.sqrt(np.mean(np.sum(d * d, axis=1))))


def heading_rmse(estimated: np.ndarray, true: np.ndarray) -> float:
    """RMSE [rad] of the heading error, each error wrapped to ``[-pi, pi)``.

    Args:
        estimated: ``(N, 3)`` estimated poses ``(x, y, theta [rad])``.
        true: ``(N, 3)`` true poses.
    """
    est, ref = _poses("estimated", estimated, 3), _poses("true", true, 3)
    _same_length(est, ref)
    e = wrap_angle(est[:, 2] - ref[:, 2])
    return float(np.sqrt(np.mean(e * e)))


def final_position_error(estimated: np.ndarray, true: np.ndarray) -> float:
    """Distance [m] between the last estimated and the last true position."""
    est, ref = _poses("estimated", estimated, 2), _poses("true", true, 2)
    _same_length(est, ref)
    return float(np.hypot(*(est[-1, :2] - ref[-1, :2])))


def pose_nees(
    estimated: np.ndarray,
    covariances: np.ndarray,
    true: np.ndarray,
    components: Sequence[int] = (0, 1, 2),
) -> np.ndarray:
    """Normalised estimation error squared of the pose, per step (no unit).

    ``e^T P^-1 e`` with ``e = true - estimated`` (heading wrapped to ``[-pi, pi)``) and
    ``P`` the ``(3, 3)`` pose covariance [m^2, m rad, rad^2], or of their rows and
    columns ``components`` only (:data:`NEES_PARTS`: the position ``(0, 1)``, the
    heading ``(2,)``). For a consistent filter it is chi-square distributed with as many
    degrees of freedom as components (mean 3 for the whole pose).

    Args:
        estimated: ``(N, 3)`` pose means ``(x [m], y [m], theta [rad])``.
        covariances: ``(N, 3, 3)`` their covariances.
        true: ``(N, 3)`` true poses.
        components: distinct indices into ``(x, y, theta)``, at least one.

    Returns:
        ``(N,)`` NEES values; NaN where a covariance block is not positive definite.
    """
    est, ref = _poses("estimated", estimated, 3), _poses("true", true, 3)
    _same_length(est, ref)
    cov = np.asarray(covariances, dtype=float)
    if cov.shape != (est.shape[0], POSE_DOF, POSE_DOF):
        raise ValueError(f"covariances must have shape ({est.shape[0]}, 3, 3), got {cov.shape}")
    rows = list(components)
    if not rows or len(set(rows)) != len(rows) or not set(rows) <= set(range(POSE_DOF)):
        raise ValueError(f"components must be distinct indices into (x, y, theta), got {rows}")
    e = ref[:, :3] - est[:, :3]
    e[:, 2] = wrap_angle(e[:, 2])
    e, cov = e[:, rows], cov[:, rows][:, :, rows]
    out = np.full(est.shape[0], np.nan)
    for t in range(est.shape[0]):
        try:
            chol = np.linalg.cholesky(0.5 * (cov[t] + cov[t].T))
        except np.linalg.LinAlgError:
            continue
        white = np.linalg.solve(chol, e[t])
        out[t] = float(white @ white)
    return out


def odometry_covariances(odometry_poses: np.ndarray, config: SlamConfig) -> np.ndarray:
    """``(N, 3, 3)`` covariance of dead reckoning along ``odometry_poses`` ``(N, 3)``.

    The filter's own motion model (``FilterConfig.odometry_alphas``, the standard
    deviation floor, the initial pose sigma) applied to the increments between
    successive odometry poses, without any measurement: the NEES of the odometry-only
    trajectory against it tells whether the motion model alone is consistent, so that
    an overconfident SLAM covariance can be put down to the measurement updates.
    """
    poses = _poses("odometry_poses", odometry_poses, 3)
    cfg = config.filter
    floor = np.asarray(cfg.odometry_sigma_floor, dtype=float)
    sigma = np.diag(np.asarray(cfg.initial_pose_sigma, dtype=float) ** 2)
    out = np.empty((poses.shape[0], 3, 3))
    out[0] = sigma
    for t in range(1, poses.shape[0]):
        u = increments_between(poses[t - 1], poses[t])
        _, sigma = motion_update(
            poses[t - 1], sigma, u, odometry_noise(u, cfg.odometry_alphas, floor)
        )
        out[t] = sigma
    return out


def chi2_interval(dof: float, confidence: float = CONFIDENCE) -> tuple[float, float]:
    """Two-sided interval of a chi-square variable holding ``confidence`` of its mass.

    Returns ``(ppf((1 - c) / 2), ppf((1 + c) / 2))``; for 3 dof at 95 %: (0.216, 9.348).
    """
    if not (dof > 0 and 0.0 < confidence < 1.0):
        raise ValueError(f"need dof > 0 and 0 < confidence < 1, got {dof}, {confidence}")
    tail = (1.0 - confidence) / 2.0
    # chi2.ppf(q, dof) as scipy.stats computes it (2 P^-1(dof / 2, q)), without importing
    # scipy.stats (about a second at every start of a process that makes an env)
    half = dof / 2.0
    return 2.0 * float(gammaincinv(half, tail)), 2.0 * float(gammaincinv(half, 1.0 - tail))


def mean_nees_interval(
    n: int, dof: int = POSE_DOF, confidence: float = CONFIDENCE
) -> tuple[float, float]:
    """Interval of the mean of ``n`` independent chi-square(``dof``) NEES values.

    ``n * mean`` is chi-square with ``dof * n`` degrees of freedom, so the interval is
    that of ``chi2(dof n) / n``. Successive filter steps are correlated, so this test is
    stricter than its nominal level on a trajectory (Bar-Shalom's test assumes
    independent runs).
    """
    if n < 1:
        raise ValueError(f"n must be >= 1, got {n}")
    low, high = chi2_interval(dof * n, confidence)
    return low / n, high / n


def nees_part_means(
    estimated: np.ndarray, covariances: np.ndarray, true: np.ndarray
) -> dict[str, float]:
    """The mean NEES of each block of :data:`NEES_PARTS`, keyed ``nees_<part>_mean``.

    :func:`pose_nees` with the block's components, NaN-safe means by
    :func:`nees_summary`; arguments as :func:`pose_nees`.
    """
    return {
        f"nees_{part}_mean": nees_summary(
            pose_nees(estimated, covariances, true, components), len(components)
        )["nees_mean"]
        for part, components in NEES_PARTS.items()
    }


def loop_match_nees(belief: Belief, true_pose: np.ndarray) -> float | None:
    """The NEES of the revisit match a step fused (None when it fused none).

    ``e^T C^-1 e`` with ``e`` the true pose minus the match's pose
    (``Belief.loop_match_pose``) and ``C`` the noise it was fused with
    (``Belief.loop_match_cov``): chi-square with 3 degrees of freedom for a consistent
    match. ``true_pose``: ``(3,)`` the true lidar pose ``(x [m], y [m], theta [rad])``
    (the robot pose in simulation, where the lidar sits at the robot centre).
    """
    if belief.loop_match_pose is None or belief.loop_match_cov is None:
        return None
    value = pose_nees(belief.loop_match_pose[None], belief.loop_match_cov[None], true_pose[None])
    return float(value[0])


def loop_match_summary(values: np.ndarray | None) -> dict[str, float]:
    """``loop_match_nees_mean`` and ``_median`` of per-match NEES values (NaN when none)."""
    arr = np.asarray([] if values is None else values, dtype=float)
    arr = arr[np.isfinite(arr)]
    if arr.size == 0:
        return {"loop_match_nees_mean": math.nan, "loop_match_nees_median": math.nan}
    return {
        "loop_match_nees_mean": float(arr.mean()),
        "loop_match_nees_median": float(np.median(arr)),
    }


def nees_summary(
    nees: np.ndarray, dof: int = POSE_DOF, confidence: float = CONFIDENCE
) -> dict[str, Any]:
    """Mean NEES, fraction of steps inside the per-step band, and the mean test.

    Args:
        nees: ``(N,)`` NEES values (NaN entries are ignored).
        dof: degrees of freedom of each value.
        confidence: mass of the two-sided intervals.

    Returns:
        ``nees_mean``; ``nees_in_band_fraction`` (steps with NEES inside the per-step
        ``chi2(dof)`` interval, over finite steps); ``nees_band`` ``[low, high]``;
        ``nees_mean_interval`` (:func:`mean_nees_interval`) and ``nees_mean_consistent``
        (the mean lies inside it). NaN / False when no value is finite.
    """
    values = np.asarray(nees, dtype=float).ravel()
    finite = values[np.isfinite(values)]
    band = chi2_interval(dof, confidence)
    if finite.size == 0:
        return {
            "nees_mean": math.nan,
            "nees_in_band_fraction": math.nan,
            "nees_band": list(band),
            "nees_mean_interval": [math.nan, math.nan],
            "nees_mean_consistent": False,
        }
    mean = float(finite.mean())
    interval = mean_nees_interval(finite.size, dof, confidence)
    inside = (finite >= band[0]) & (finite <= band[1])
    return {
        "nees_mean": mean,
        "nees_in_band_fraction": float(inside.mean()),
        "nees_band": list(band),
        "nees_mean_interval": list(interval),
        "nees_mean_consistent": bool(interval[0] <= mean <= interval[1]),
    }


def majority_id(hit_ids: Iterable[int]) -> int:
    """The most frequent obstacle id among beams, ignoring ``-1`` (no return).

    Ties go to the smallest id; ``-1`` when no beam hit anything.
    """
    ranked = _ranked_hits(hit_ids)
    return ranked[0][0] if ranked else NO_HIT


def set_obstacles(hit_ids: Iterable[int], share: float = OBSTACLE_SHARE) -> tuple[int, ...]:
    """The obstacle ids hit by at least ``share`` of the beams that hit something.

    Most hit first, ties to the smaller id; ``-1`` (no return) is ignored; empty when no
    beam hit anything.
    """
    ranked = _ranked_hits(hit_ids)
    total = sum(c for _, c in ranked)
    return tuple(i for i, c in ranked if c >= share * total)


def _ranked_hits(hit_ids: Iterable[int]) -> list[tuple[int, int]]:
    """``(obstacle id, beams)`` of the ids hit, most hit first, ties to the smaller id."""
    counts = Counter(int(i) for i in np.asarray(hit_ids).ravel() if int(i) != NO_HIT)
    return sorted(counts.items(), key=lambda item: (-item[1], item[0]))


def landmark_majority_ids(decisions: Iterable[DecisionRecord]) -> dict[int, int]:
    """Each landmark's obstacle id: the majority over the sets that created or updated it.

    Every set with outcome ``"created"`` or ``"updated"`` votes its own majority id for
    its landmark (sets whose majority is ``-1`` do not vote); ties go to the smallest id.
    Landmarks with no vote map to ``-1``.

    Returns:
        ``{landmark id: obstacle id}`` for every landmark that appears in ``decisions``.
    """
    votes: dict[int, list[int]] = {}
    for d in decisions:
        if d.landmark < 0:
            continue
        ballot = votes.setdefault(d.landmark, [])
        if d.outcome in MAP_OUTCOMES and d.majority_id != NO_HIT:
            ballot.append(d.majority_id)
    return {lm: majority_id(ids) for lm, ids in votes.items()}


def association_precision(
    decisions: Iterable[DecisionRecord],
    landmark_ids: Mapping[int, int],
    outcomes: Sequence[str] = ASSOCIATION_OUTCOMES,
    also: Mapping[int, Sequence[int]] | None = None,
) -> tuple[float, int]:
    """Fraction of set-to-landmark associations that are correct.

    An association is a decision with outcome ``"updated"`` or ``"associated"`` (or
    those in ``outcomes``: ``("updated",)`` counts only the associations that changed the
    map); it is correct when the set's majority obstacle id equals the landmark's
    (:func:`landmark_majority_ids`), or is one of ``also[landmark]`` when given.

    Returns:
        ``(precision, associations)``; precision is NaN when there is no association.
    """
    also = also or {}
    total = correct = 0
    for d in decisions:
        if d.outcome not in outcomes:
            continue
        total += 1
        ok = d.majority_id == landmark_ids.get(d.landmark, NO_HIT)
        correct += int(
            d.majority_id != NO_HIT and (ok or d.majority_id in also.get(d.landmark, ()))
        )
    return (correct / total if total else math.nan), total


def compound_precision(
    decisions: Iterable[DecisionRecord], landmark_ids: Mapping[int, int]
) -> tuple[float, int]:
    """:func:`association_precision` that also accepts the obstacles a landmark was made of.

    A diagnostic beside the issue's metric, not a replacement for it. A landmark is a
    polyline, and the set that creates it often spans two obstacles that meet (a wall
    and the wall it abuts, a cupboard against a wall): the landmark models both, but
    its majority id names one, so a later set on the other counts as a wrong
    association. Here an association is also correct when the set's majority obstacle
    is one of the obstacles of the set that created the landmark
    (:attr:`DecisionRecord.obstacles`, at least :data:`OBSTACLE_SHARE` of its beams).
    Only the creating set counts, so a wrong update cannot make its own obstacle a
    member. Decisions recorded without ``obstacles`` count as in
    :func:`association_precision`.

    Returns:
        ``(precision, associations)``; precision is NaN when there is no association.
    """
    decisions = list(decisions)
    made_of: dict[int, tuple[int, ...]] = {}
    for d in decisions:
        if d.outcome == "created" and d.landmark >= 0:
            made_of.setdefault(d.landmark, d.obstacles)
    return association_precision(decisions, landmark_ids, also=made_of)


def creation_causes(
    decisions: Iterable[DecisionRecord], landmark_ids: Mapping[int, int]
) -> dict[str, int]:
    """Why each new landmark was made: counts by :data:`CREATION_CAUSES` (a diagnostic).

    For every ``"created"`` decision, the candidates whose landmark models the set's own
    majority obstacle (``landmark_ids``, :func:`landmark_majority_ids`) are those the
    new landmark duplicates. ``"new"``: none (or the set has no majority obstacle);
    otherwise the furthest any of them got: ``"accepted"`` (the detection test passed;
    another rule made the landmark), ``"rejected"`` (aligned and tested, the detection
    or object-beam test failed), ``"gated"`` (the ICP result failed the plausibility
    gate) or ``"far"`` (near the set's centroid but not aligned). Decisions recorded
    without candidates count as ``"new"``.
    """
    rank = {cause: i for i, cause in enumerate(CREATION_CAUSES)}  # how far it got
    counts = dict.fromkeys(CREATION_CAUSES, 0)
    for d in decisions:
        if d.outcome != "created":
            continue
        best = "new"
        for lm, reason, mean_d2, _, accepted in d.candidates:
            if d.majority_id == NO_HIT or landmark_ids.get(lm, NO_HIT) != d.majority_id:
                continue
            if accepted:
                cause = "accepted"
            elif reason in ("far", "gated"):
                cause = reason
            else:
                cause = "gated" if math.isnan(mean_d2) else "rejected"
            if rank[cause] > rank[best]:
                best = cause
        counts[best] += 1
    return counts


def duplicate_fraction(landmark_ids: Mapping[int, int] | Sequence[int]) -> float:
    """``1 - (distinct obstacles among the landmarks' ids) / landmarks``.

    0 when every landmark models a different obstacle; ``1 - 1/k`` for ``k`` landmarks of
    one obstacle. Landmarks with id ``-1`` (no obstacle) count as landmarks only. NaN
    for no landmark.

    Args:
        landmark_ids: per landmark its obstacle id (a mapping's values, or a sequence).
    """
    ids = list(landmark_ids.values()) if isinstance(landmark_ids, Mapping) else list(landmark_ids)
    if not ids:
        return math.nan
    distinct = {i for i in ids if i != NO_HIT}
    return 1.0 - len(distinct) / len(ids)


def timing_summary(
    step_ms: np.ndarray, percentile: float = TIMING_PERCENTILE
) -> tuple[float, float]:
    """Median and ``percentile``-th percentile [ms] of per-step times [ms] (NaN if empty)."""
    ms = np.asarray(step_ms, dtype=float).ravel()
    if ms.size == 0:
        return math.nan, math.nan
    return float(np.median(ms)), float(np.percentile(ms, percentile))


def episode_metrics(log: EpisodeLog) -> dict[str, Any]:
    """Every metric of one episode, over its ``T`` filter steps (rows ``1..T``).

    Keys (units): ``world``, ``preset``, ``seed``, ``steps``, ``route_done``,
    ``collision_steps``; ``ate_rmse_m`` / ``odom_ate_rmse_m`` (position ATE RMSE [m] of
    SLAM / odometry only); ``heading_rmse_rad`` / ``odom_heading_rmse_rad`` [rad];
    ``final_error_m`` / ``odom_final_error_m`` [m]; ``nees_*`` (:func:`nees_summary`);
    ``odom_nees_mean`` and ``odom_nees_in_band_fraction`` (the same for dead reckoning
    with the filter's motion model, :func:`odometry_covariances`);
    ``filter_nees_mean`` and ``filter_nees_in_band_fraction`` (the same with the
    filter's own covariance, ``EpisodeLog.filter_covs``; NaN when not recorded);
    ``nees_position_mean`` and ``nees_heading_mean`` (the mean NEES of the position
    alone, 2 degrees of freedom, and of the heading alone, 1: which part of the pose is
    over- or underconfident; :data:`NEES_PARTS`);
    ``association_precision`` and ``associations``; ``update_precision`` and
    ``updates`` (the same over the associations that updated the map: an
    ``"associated"`` set, matched with too few beams on object lines to update, often
    lies on another landmark's unknown lines); ``rejected_updates`` and
    ``rejected_precision`` (the associations whose update failed its verification,
    ``FilterConfig.verify_heading_sigma``, and the fraction of them that were correct);
    ``compound_precision`` (:func:`compound_precision`, a diagnostic: also correct when
    the set is on an obstacle the landmark was created from);
    ``landmarks`` (final count),
    ``obstacles_mapped`` (distinct true obstacles among them), ``obstacles``,
    ``landmarks_per_obstacle`` (landmarks / obstacles mapped), ``duplicate_fraction``;
    ``created_new``, ``created_far``, ``created_gated``, ``created_rejected``,
    ``created_accepted`` (the new landmarks by :func:`creation_causes`, a diagnostic of
    the duplicates); ``surface_pieces`` (the contiguous surface pieces of the obstacles,
    :mod:`vslam_gym.surfaces`, that some scan hit with at least
    ``FilterConfig.min_set_beams`` beams: the fewest landmarks that model everything
    seen), ``landmarks_per_piece`` and ``duplicate_floor`` (the duplicate fraction of a
    map with one landmark per piece, :func:`duplicate_fraction` of the pieces' obstacle
    ids: the lowest the ``duplicate_fraction`` of any per-surface map can be on the route; NaN
    when the log has no ``surface_hits``);
    ``loop_closures`` (steps that fused a revisit match, ``FilterConfig.loop_closure``);
    ``loop_match_nees_mean`` and ``loop_match_nees_median`` (over those matches, each
    one's NEES against the true pose with the noise it was fused with,
    :func:`loop_match_nees`: a consistent match has mean 3 and median 2.37; NaN when
    none was fused or the log has no record);
    ``step_ms_median``, ``step_ms_p95``, ``step_ms_mean`` [ms] (the mean is what a
    throughput sees when a motion filter makes most steps cheap);
    ``measured_fraction`` (steps that ran the measurement update) and
    ``measured_step_ms_median`` [ms] (the median over them; NaN when none did);
    ``wall_s`` [s].
    """
    if log.steps == 0:
        raise ValueError("the episode has no step to evaluate")
    true, odom, est = log.true_poses[1:], log.odometry_poses[1:], log.slam_poses[1:]
    nees = pose_nees(est, log.slam_covs[1:], true)
    final = log.final_belief
    ids = landmark_majority_ids(log.decisions)
    final_ids = {lm.id: ids.get(lm.id, NO_HIT) for lm in final.landmarks}
    mapped = len({i for i in final_ids.values() if i != NO_HIT})
    precision, associations = association_precision(log.decisions, ids)
    update_precision, updates = association_precision(log.decisions, ids, ("updated",))
    rejected_precision, rejected = association_precision(log.decisions, ids, ("rejected",))
    compound, _ = compound_precision(log.decisions, ids)
    causes = creation_causes(log.decisions, ids)
    median, p95 = timing_summary(log.step_ms)
    if log.surface_hits is None:
        n_pieces, floor = math.nan, math.nan
    else:
        seen = log.surface_hits >= log.config.filter.min_set_beams
        owners = surface_pieces(log.world).owner[seen]
        n_pieces, floor = int(owners.size), duplicate_fraction(owners.tolist())
    out: dict[str, Any] = {
        "world": log.world_name,
        "preset": log.preset,
        "seed": log.seed,
        "steps": log.steps,
        "route_done": log.route_done,
        "collision_steps": int(log.collisions.sum()),
        "ate_rmse_m": position_ate_rmse(est, true),
        "odom_ate_rmse_m": position_ate_rmse(odom, true),
        "heading_rmse_rad": heading_rmse(est, true),
        "odom_heading_rmse_rad": heading_rmse(odom, true),
        "final_error_m": final_position_error(est, true),
        "odom_final_error_m": final_position_error(odom, true),
    }
    out.update(nees_summary(nees))
    odom_nees = nees_summary(
        pose_nees(odom, odometry_covariances(log.odometry_poses, log.config)[1:], true)
    )
    out["odom_nees_mean"] = odom_nees["nees_mean"]
    out["odom_nees_in_band_fraction"] = odom_nees["nees_in_band_fraction"]
    own = nees_summary(
        pose_nees(est, log.filter_covs[1:], true)
        if log.filter_covs is not None
        else np.full(len(est), np.nan)
    )
    out["filter_nees_mean"] = own["nees_mean"]
    out["filter_nees_in_band_fraction"] = own["nees_in_band_fraction"]
    out.update(nees_part_means(est, log.slam_covs[1:], true))
    out.update(
        {
            "association_precision": precision,
            "associations": associations,
            "update_precision": update_precision,
            "updates": updates,
            "rejected_updates": rejected,
            "rejected_precision": rejected_precision,
            "compound_precision": compound,
            "landmarks": len(final.landmarks),
            "obstacles_mapped": mapped,
            "obstacles": len(log.world.obstacles),
            "landmarks_per_obstacle": len(final.landmarks) / mapped if mapped else math.nan,
            "duplicate_fraction": duplicate_fraction(final_ids),
            "surface_pieces": n_pieces,
            "landmarks_per_piece": len(final.landmarks) / n_pieces if n_pieces else math.nan,
            "duplicate_floor": floor,
            **{f"created_{cause}": count for cause, count in causes.items()},
            "loop_closures": log.loop_closures,
            **loop_match_summary(log.loop_match_nees),
            "step_ms_median": median,
            "step_ms_p95": p95,
            "step_ms_mean": float(np.mean(log.step_ms)) if len(log.step_ms) else math.nan,
            "measured_fraction": float(np.mean(log.measured)),
            "measured_step_ms_median": timing_summary(log.step_ms[log.measured])[0],
            "wall_s": log.wall_s,
        }
    )
    return out


def mean_metrics(per_seed: Sequence[Mapping[str, Any]]) -> dict[str, Any]:
    """Mean over seeds of every numeric metric (NaNs ignored; booleans as fractions).

    Non-numeric keys (``world``, ``preset``) are copied from the first seed; ``seed``
    becomes the list ``seeds``.
    """
    if not per_seed:
        raise ValueError("no seed to average")
    out: dict[str, Any] = {}
    for key, value in per_seed[0].items():
        if key == "seed":
            out["seeds"] = [m["seed"] for m in per_seed]
        elif isinstance(value, bool | int | float | np.floating | np.integer):
            values = np.array([float(m[key]) for m in per_seed])
            finite = values[np.isfinite(values)]
            out[key] = float(finite.mean()) if finite.size else math.nan
        elif isinstance(value, list):
            out[key] = value  # the chi-square band is the same for every seed
        else:
            out[key] = value
    out["nees_mean_interval"] = None  # depends on each seed's step count
    return out


def sem_metrics(per_seed: Sequence[Mapping[str, Any]]) -> dict[str, float]:
    """Standard error of :func:`mean_metrics` over seeds, per numeric metric.

    ``std(ddof=1) / sqrt(n)`` over the seeds with a finite value (NaN with fewer than
    two). The per-seed spread includes the filter's sensitivity to round-off, which
    pairing seeds between two configurations does not remove (:mod:`vslam_gym.compare`
    pairs them and reports the paired t statistic, whose spread includes it).
    """
    if not per_seed:
        raise ValueError("no seed to average")
    out: dict[str, float] = {}
    for key, value in per_seed[0].items():
        if key == "seed" or not isinstance(value, bool | int | float | np.floating | np.integer):
            continue
        values = np.array([float(m[key]) for m in per_seed])
        finite = values[np.isfinite(values)]
        out[key] = (
            float(finite.std(ddof=1) / math.sqrt(finite.size)) if finite.size > 1 else math.nan
        )
    return out


# ---------------------------------------------------------------------------- TUM export


def yaw_quaternion(yaw: np.ndarray | float) -> np.ndarray:
    """Unit quaternion ``(qx, qy, qz, qw)`` of a rotation by ``yaw`` [rad] about +z.

    Returns shape ``(4,)`` for a scalar, ``(N, 4)`` for ``(N,)`` yaws.
    """
    half = 0.5 * np.asarray(yaw, dtype=float)
    zeros = np.zeros_like(half)
    return np.stack([zeros, zeros, np.sin(half), np.cos(half)], axis=-1)


def write_tum(path: str | os.PathLike[str], times: np.ndarray, poses: np.ndarray) -> None:
    """Write a planar trajectory in the TUM format (``evo`` reads it).

    One line per pose, ``timestamp tx ty tz qx qy qz qw`` separated by single spaces,
    with ``tz = 0`` and the yaw quaternion of :func:`yaw_quaternion`; a leading ``#``
    comment line names the columns.

    Args:
        path: output file.
        times: ``(N,)`` timestamps [s], strictly increasing.
        poses: ``(N, 3)`` poses ``(x [m], y [m], theta [rad])``, world frame.
    """
    t = np.asarray(times, dtype=float).ravel()
    p = _poses("poses", poses, 3)
    if t.size != p.shape[0]:
        raise ValueError(f"times has {t.size} entries but poses has {p.shape[0]}")
    if not (np.all(np.isfinite(t)) and np.all(np.isfinite(p[:, :3]))):
        raise ValueError("times and poses must be finite")
    if np.any(np.diff(t) <= 0):
        raise ValueError("times must be strictly increasing")
    q = yaw_quaternion(p[:, 2])
    lines = ["# timestamp tx ty tz qx qy qz qw"]
    lines.extend(
        f"{ti:.6f} {x:.6f} {y:.6f} 0.000000 {qx:.9f} {qy:.9f} {qz:.9f} {qw:.9f}"
        for ti, x, y, (qx, qy, qz, qw) in zip(t, p[:, 0], p[:, 1], q, strict=True)
    )
    Path(path).write_text("\n".join(lines) + "\n")


# ---------------------------------------------------------------------------- figures


def _draw_obstacles(ax: Any, world: Any, **style: Any) -> None:
    """Draw the true obstacles of ``world`` as filled patches."""
    from matplotlib.patches import Circle, Polygon

    for obstacle in world.obstacles:
        if obstacle.kind == "polygon":
            ax.add_patch(Polygon(np.asarray(obstacle.points), closed=True, **style))
        elif obstacle.kind == "circle":
            ax.add_patch(Circle(obstacle.center, obstacle.radius, **style))
        else:  # a wall: one rectangle per segment, discs at the joints
            points = np.asarray(obstacle.points, dtype=float)
            half = obstacle.thickness / 2.0
            for a, b in zip(points[:-1], points[1:], strict=True):
                d = b - a
                length = float(np.hypot(*d))
                if length == 0.0:
                    continue
                n = np.array([-d[1], d[0]]) / length * half
                ax.add_patch(Polygon(np.array([a + n, b + n, b - n, a - n]), **style))
            for p in points:
                ax.add_patch(Circle(tuple(p), half, **style))


def _world_box(log: EpisodeLog) -> tuple[np.ndarray, np.ndarray]:
    """Lower-left and upper-right corners [m] of the obstacles and the true path."""
    from vslam_gym.sim.shapes import obstacle_bounds

    boxes = np.array([obstacle_bounds(o) for o in log.world.obstacles]).reshape(-1, 4)
    xy = log.true_poses[:, :2]
    low = np.min(np.vstack([boxes[:, :2], xy]), axis=0)
    high = np.max(np.vstack([boxes[:, 2:], xy]), axis=0)
    return low, high


def _new_figure(size: tuple[float, float]) -> tuple[Any, Any]:
    from matplotlib.figure import Figure

    fig = Figure(figsize=size, dpi=110, layout="constrained")
    return fig, fig.subplots()


def plot_trajectories(log: EpisodeLog, path: str | os.PathLike[str]) -> None:
    """Save true / odometry-only / SLAM paths with 3-sigma SLAM pose ellipses."""
    from matplotlib.patches import Ellipse

    from vslam_gym.slam.plotting import covariance_ellipse

    fig, ax = _new_figure((9, 7))
    _draw_obstacles(ax, log.world, facecolor="0.75", edgecolor="0.45", linewidth=0.5)
    ax.plot(*log.true_poses[:, :2].T, "-", color="k", linewidth=1.5, label="true")
    ax.plot(*log.odometry_poses[:, :2].T, "--", color="tab:orange", label="odometry only")
    ax.plot(*log.slam_poses[:, :2].T, "-", color="tab:blue", linewidth=1.2, label="SLAM")
    for t in range(ELLIPSE_EVERY, log.slam_poses.shape[0], ELLIPSE_EVERY):
        width, height, angle = covariance_ellipse(
            log.slam_poses[t, :2], log.slam_covs[t, :2, :2], ELLIPSE_N_SIGMA
        )
        ax.add_patch(
            Ellipse(
                tuple(log.slam_poses[t, :2]),
                width,
                height,
                angle=angle,
                fill=False,
                edgecolor="tab:blue",
                linewidth=0.8,
            )
        )
    ax.plot(*log.true_poses[0, :2], "o", color="tab:green", label="start")
    ax.plot([], [], color="tab:blue", linewidth=0.8, label=f"SLAM {ELLIPSE_N_SIGMA:g}-sigma")
    ax.set_aspect("equal")
    ax.autoscale_view()
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title(f"{log.world_name}, seed {log.seed}, {log.preset}: {log.steps} steps")
    ax.legend(loc="best", fontsize="small")
    fig.savefig(path)


def plot_map(log: EpisodeLog, path: str | os.PathLike[str]) -> None:
    """Save the final landmark map over the true obstacles.

    Object lines solid, unknown lines dashed and faint, the 3-sigma ellipses of the
    object vertices (an unknown line's far end, at a ray's maximum range, has an ellipse
    metres long and is left out); each landmark labelled ``L<id>:o<majority obstacle>``
    when there are at most :data:`MAP_LABELS_AT_MOST`.
    """
    from vslam_gym.slam.plotting import PlotStyle, plot_models

    fig, ax = _new_figure((9, 7))
    _draw_obstacles(ax, log.world, facecolor="0.9", edgecolor="0.7", linewidth=0.5)
    landmarks = log.final_belief.landmarks
    labelled = len(landmarks) <= MAP_LABELS_AT_MOST
    if landmarks:
        plot_models(
            [lm.model for lm in landmarks],
            ax,
            n_sigma=ELLIPSE_N_SIGMA,
            unknown_threshold=log.config.model.unknown_threshold,
            style=PlotStyle(unknown_alpha=MAP_UNKNOWN_ALPHA, unknown_ellipses=False),
        )
        ids = landmark_majority_ids(log.decisions)
        for lm in landmarks if labelled else ():
            ax.annotate(
                f"L{lm.id}:o{ids.get(lm.id, NO_HIT)}",
                tuple(lm.reference),
                fontsize="x-small",
                ha="center",
            )
    ax.plot(*log.true_poses[:, :2].T, ":", color="0.5", linewidth=0.8, label="true path")
    ax.set_aspect("equal")
    low, high = _world_box(log)
    ax.set_xlim(low[0] - MAP_MARGIN, high[0] + MAP_MARGIN)
    ax.set_ylim(low[1] - MAP_MARGIN, high[1] + MAP_MARGIN)
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    key = " (L<landmark>:o<majority obstacle>)" if labelled and landmarks else ""
    ax.set_title(
        f"{log.world_name}, seed {log.seed}: {len(landmarks)} landmarks{key}, "
        f"{len(log.world.obstacles)} obstacles"
    )
    ax.legend(loc="best", fontsize="small")
    fig.savefig(path)


def plot_nees(log: EpisodeLog, path: str | os.PathLike[str]) -> None:
    """Save the pose NEES over time (log scale) with its 95 % chi-square(3) band."""
    nees = pose_nees(log.slam_poses[1:], log.slam_covs[1:], log.true_poses[1:])
    summary = nees_summary(nees)
    low, high = summary["nees_band"]
    t = log.times[1:]
    floor = np.finfo(float).tiny
    fig, ax = _new_figure((9, 4.5))
    ax.axhspan(low, high, color="tab:green", alpha=0.15, label=f"{CONFIDENCE:.0%} band")
    ax.axhline(POSE_DOF, color="tab:green", linewidth=0.8, label=f"expected ({POSE_DOF})")
    ax.semilogy(t, np.maximum(nees, floor), color="tab:blue", linewidth=1.0, label="pose NEES")
    ax.axhline(summary["nees_mean"], color="tab:red", linestyle="--", linewidth=0.8, label="mean")
    ax.set_xlabel("time [s]")
    ax.set_ylabel("NEES (3 dof)")
    ax.set_title(
        f"{log.world_name}, seed {log.seed}: mean {summary['nees_mean']:.3g}, "
        f"{summary['nees_in_band_fraction']:.0%} of steps in band"
    )
    ax.legend(loc="best", fontsize="small")
    fig.savefig(path)


# ---------------------------------------------------------------------------- evaluate


def json_safe(value: Any) -> Any:
    """Replace NaN/inf by None (strict JSON), numpy scalars by Python ones, keys by str."""
    if isinstance(value, Mapping):
        return {str(k): json_safe(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [json_safe(v) for v in value]
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def progress_bar(
    total: int | None, desc: str, enabled: bool, leave: bool = False, unit: str = "step"
) -> Any:
    """A tqdm bar (on stderr, counting ``unit``) when tqdm is installed and ``enabled``."""
    if not enabled:
        return None
    try:
        from tqdm import tqdm
    except ImportError:
        return None
    return tqdm(total=total, desc=desc, unit=unit, leave=leave, file=sys.stderr)


def save_episode(log: EpisodeLog, out_dir: Path) -> list[Path]:
    """Write one episode's figures, TUM trajectories and arrays; return the paths."""
    suffix = f"_seed{log.seed}"
    paths = {
        "trajectories": out_dir / f"trajectories{suffix}.png",
        "map": out_dir / f"map{suffix}.png",
        "nees": out_dir / f"nees{suffix}.png",
        "true": out_dir / f"true{suffix}.tum",
        "odometry": out_dir / f"odometry{suffix}.tum",
        "slam": out_dir / f"slam{suffix}.tum",
        "arrays": out_dir / f"episode{suffix}.npz",
    }
    plot_trajectories(log, paths["trajectories"])
    plot_map(log, paths["map"])
    plot_nees(log, paths["nees"])
    write_tum(paths["true"], log.times, log.true_poses)
    write_tum(paths["odometry"], log.times, log.odometry_poses)
    write_tum(paths["slam"], log.times, log.slam_poses)
    np.savez_compressed(
        paths["arrays"],
        times=log.times,
        true_poses=log.true_poses,
        odometry_poses=log.odometry_poses,
        slam_poses=log.slam_poses,
        slam_covs=log.slam_covs,
        step_ms=log.step_ms,
        landmark_counts=log.landmark_counts,
        collisions=log.collisions,
    )
    return list(paths.values())


def evaluate(
    world: str,
    seeds: Sequence[int],
    preset: str = "default",
    out_dir: str | os.PathLike[str] = "evaluation",
    progress: bool = True,
    max_steps: int | None = None,
    print_table: bool = True,
    overrides: Mapping[str, Any] | None = None,
    range_perturbation: float = 0.0,
    jobs: int = 1,
    start_scan: str = "matcher",
) -> dict[str, Any]:
    """Run one episode per seed and write metrics, figures and trajectories.

    Args:
        world: shipped world name or path to a TOML world file (with a route).
        seeds: ``reset`` seeds, at least one.
        preset: a :meth:`SlamConfig.preset` name (``"default"``, ``"thesis"``, ``"fast"``).
        out_dir: output directory (created if needed).
        progress: show a tqdm progress bar per seed (silently none without tqdm).
        max_steps: step budget per episode (None: until the route is done).
        print_table: print :func:`format_table` of the result to standard output.
        overrides: optional ``{"model": {...}, "filter": {...}, "icp": {...}}`` applied
            over the preset (:meth:`SlamConfig.from_dict`), e.g. a measured option.
        range_perturbation: a round-off probe (:func:`run_episode`), 0 by default.
        jobs: episodes run at once, each in its own worker process (1: one after the
            other in this process). The metrics are the same for any ``jobs`` except
            the step times, which then include the episodes' competition for cores.
        start_scan: what the filter does with the scan of ``reset``
            (:func:`use_start_scan`).

    Returns:
        The content of ``out_dir/metrics.json``: ``world``, ``preset``, ``overrides``,
        ``range_perturbation``, ``start_scan``, ``seeds``, ``machine``, ``per_seed`` (one
        :func:`episode_metrics` dict per seed), ``mean`` (:func:`mean_metrics`) and
        ``sem`` (its standard error over the seeds, :func:`sem_metrics`). NaN metrics are
        written as ``null``.
    """
    seeds = [int(s) for s in seeds]
    if not seeds:
        raise ValueError("evaluate needs at least one seed")
    if not (isinstance(jobs, int) and jobs >= 1):
        raise ValueError(f"jobs must be an integer >= 1, got {jobs!r}")
    SlamConfig.from_dict({"preset": preset, **(overrides or {})})  # fail early
    range_perturbation = check_range_perturbation(range_perturbation)
    start_scan = check_start_scan(start_scan)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    if jobs > 1:
        calls = [
            (
                world,
                s,
                preset,
                max_steps,
                None,
                dict(overrides or {}),
                range_perturbation,
                start_scan,
            )
            for s in seeds
        ]
        bar = progress_bar(len(seeds), f"{world} seeds", progress, unit="episode")
        logs = in_workers(run_episode, calls, jobs, bar)
    else:
        logs = (
            _episode_with_bar(
                world, s, preset, max_steps, overrides, range_perturbation, start_scan, progress
            )
            for s in seeds
        )
    per_seed = []
    for log in logs:  # in seed order; figures as each episode arrives
        per_seed.append(episode_metrics(log))
        save_episode(log, out)
    result = {
        "world": per_seed[0]["world"],
        "preset": preset,
        "overrides": dict(overrides or {}),
        "range_perturbation": range_perturbation,
        "start_scan": start_scan,
        "seeds": seeds,
        "machine": machine_description(),
        "per_seed": per_seed,
        "mean": mean_metrics(per_seed),
        "sem": sem_metrics(per_seed),
    }
    result = json_safe(result)
    (out / "metrics.json").write_text(json.dumps(result, indent=2) + "\n")
    if print_table:
        print(format_table(result))
    return result


def _episode_with_bar(
    world: str,
    seed: int,
    preset: str,
    max_steps: int | None,
    overrides: Mapping[str, Any] | None,
    range_perturbation: float,
    start_scan: str,
    progress: bool,
) -> EpisodeLog:
    """:func:`run_episode` with a per-step progress bar (when ``progress``)."""
    bar = progress_bar(max_steps, f"{world} seed {seed}", progress)

    def tick(step: int, belief: Belief) -> None:
        bar.update(1)
        bar.set_postfix(landmarks=len(belief.landmarks), refresh=False)

    try:
        return run_episode(
            world,
            seed,
            preset,
            max_steps,
            tick if bar is not None else None,
            overrides,
            range_perturbation,
            start_scan,
        )
    finally:
        if bar is not None:
            bar.close()


def in_workers(
    function: Callable[..., Any],
    calls: Sequence[tuple[Any, ...]],
    jobs: int,
    bar: Any = None,
) -> Iterator[Any]:
    """``function(*call)`` for each call in ``jobs`` worker processes, yielded in order.

    ``bar`` (a :func:`progress_bar` or None) advances as each call finishes and is closed
    at the end. ``function`` and the arguments must be picklable (module-level).
    """
    try:
        with ProcessPoolExecutor(max_workers=max(1, min(jobs, len(calls)))) as pool:
            futures = [pool.submit(function, *call) for call in calls]
            if bar is not None:
                for future in futures:
                    future.add_done_callback(lambda _: bar.update(1))
            for future in futures:
                yield future.result()
    finally:
        if bar is not None:
            bar.close()


def load_average() -> str:
    """The 1-minute load average for timing figures, or "n/a" where there is none."""
    try:
        return f"{os.getloadavg()[0]:.2f}"
    except OSError:
        return "n/a"


def machine_description() -> str:
    """CPU, core count, Python and numpy versions, for timing figures."""
    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    cpu = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    return (
        f"{cpu}, {os.cpu_count()} cores, Python {platform.python_version()}, numpy {np.__version__}"
    )


_TABLE_COLUMNS = (
    ("steps", "steps", "{:.0f}"),
    ("ATE m", "ate_rmse_m", "{:.3f}"),
    ("odo ATE m", "odom_ate_rmse_m", "{:.3f}"),
    ("hdg rad", "heading_rmse_rad", "{:.4f}"),
    ("odo hdg", "odom_heading_rmse_rad", "{:.4f}"),
    ("final m", "final_error_m", "{:.3f}"),
    ("NEES", "nees_mean", "{:.3g}"),
    ("in band", "nees_in_band_fraction", "{:.2f}"),
    ("odo NEES", "odom_nees_mean", "{:.3g}"),
    ("assoc P", "association_precision", "{:.3f}"),
    ("upd P", "update_precision", "{:.3f}"),
    ("cmp P", "compound_precision", "{:.3f}"),
    ("dup", "duplicate_fraction", "{:.2f}"),
    ("floor", "duplicate_floor", "{:.2f}"),
    ("LMs", "landmarks", "{:.1f}"),
    ("pieces", "surface_pieces", "{:.1f}"),
    ("ms med", "step_ms_median", "{:.1f}"),
    ("ms p95", "step_ms_p95", "{:.1f}"),
    ("ms mean", "step_ms_mean", "{:.1f}"),
    ("ms meas", "measured_step_ms_median", "{:.1f}"),
)


def format_table(metrics: Mapping[str, Any]) -> str:
    """A fixed-width summary table: one row per seed and the mean.

    Args:
        metrics: the result of :func:`evaluate` (or ``metrics.json`` loaded).
    """

    def cell(value: Any, fmt: str) -> str:
        if value is None or (isinstance(value, float) and not math.isfinite(value)):
            return "-"
        return fmt.format(value)

    header = ["seed"] + [name for name, _, _ in _TABLE_COLUMNS]
    rows = [
        [str(m["seed"])] + [cell(m.get(key), fmt) for _, key, fmt in _TABLE_COLUMNS]
        for m in metrics["per_seed"]
    ]
    mean = metrics["mean"]
    rows.append(["mean"] + [cell(mean.get(key), fmt) for _, key, fmt in _TABLE_COLUMNS])
    sem = metrics.get("sem") if len(metrics["per_seed"]) > 1 else None
    if sem:
        rows.append(["+- sem"] + [cell(sem.get(key), fmt) for _, key, fmt in _TABLE_COLUMNS])
    widths = [max(len(r[i]) for r in [header, *rows]) for i in range(len(header))]

    def line(cells: Sequence[str]) -> str:
        return "  ".join(c.rjust(w) for c, w in zip(cells, widths, strict=True))

    title = f"{metrics['world']} / preset {metrics['preset']} / {len(metrics['per_seed'])} seed(s)"
    if metrics.get("overrides"):
        title += f" / --set {json.dumps(metrics['overrides'], separators=(',', ':'))}"
    if metrics.get("range_perturbation"):
        title += f" / --range-perturbation {metrics['range_perturbation']:g}"
    if metrics.get("start_scan", "matcher") != "matcher":
        title += f" / --start-scan {metrics['start_scan']}"
    rule = "-" * len(line(header))
    n_summary = 2 if sem else 1
    body, summary = rows[:-n_summary], rows[-n_summary:]
    return "\n".join([title, line(header), rule, *map(line, body), rule, *map(line, summary)])


# ---------------------------------------------------------------------------- command line


def parse_seeds(text: str) -> list[int]:
    """Seeds from ``"0-9"`` (inclusive range), ``"0,3,5"``, ``"7"`` or combinations.

    Raises:
        SeedsError: empty parts, negative or non-integer seeds, a reversed range, or a
            seed listed twice.
    """
    seeds: list[int] = []
    for part in str(text).split(","):
        part = part.strip()
        try:
            if "-" in part:
                low_text, high_text = part.split("-", 1)
                low, high = int(low_text), int(high_text)
                if low > high:
                    raise SeedsError(f"seed range {part!r} is reversed")
                seeds.extend(range(low, high + 1))
            else:
                seeds.append(int(part))
        except ValueError as err:
            if isinstance(err, SeedsError):
                raise
            raise SeedsError(
                f"bad seeds {text!r}: {part!r} is not a seed or range (use 0-9, 0,3,5 or 7)"
            ) from err
    if any(s < 0 for s in seeds):
        raise SeedsError(f"seeds must be >= 0, got {text!r}")
    duplicates = sorted(s for s, n in collections.Counter(seeds).items() if n > 1)
    if duplicates:
        raise SeedsError(f"seeds listed twice in {text!r}: {duplicates}")
    return seeds


def seeds_argument(text: str) -> list[int]:
    """An argparse type: :func:`parse_seeds`, its errors as argparse errors."""
    try:
        return parse_seeds(text)
    except SeedsError as err:
        raise argparse.ArgumentTypeError(str(err)) from err


def name_or_mapping(text: str) -> str | dict[str, Any]:
    """An argparse type for an option that takes a preset name or a JSON object.

    ``"fast"`` stays a name; text starting with ``{`` is parsed as a JSON object (e.g.
    ``'{"filter": {"loop_closure": false}}'`` for a wrapper's ``slam_config``, or
    reward weights). Malformed JSON raises ``argparse.ArgumentTypeError`` (a usage
    error naming it).
    """
    if not text.lstrip().startswith("{"):
        return text
    try:
        return json.loads(text)
    except json.JSONDecodeError as exc:
        raise argparse.ArgumentTypeError(f"neither a preset name nor valid JSON: {exc}") from None


def json_object(text: str, option: str) -> dict[str, Any]:
    """The JSON object ``text`` of a command-line ``option``, else a usage error naming it.

    Raises ``argparse.ArgumentTypeError`` for malformed JSON or JSON that is not an object.
    """
    try:
        value = json.loads(text)
    except json.JSONDecodeError as exc:
        raise argparse.ArgumentTypeError(f"{option} must be a JSON object: {exc}") from None
    if not isinstance(value, dict):
        raise argparse.ArgumentTypeError(f"{option} must be a JSON object, got {text!r}")
    return value


def _overrides_argument(text: str) -> dict[str, Any]:
    """``--set`` (``evaluate``, ``replay``): a JSON object of configuration sections.

    Checked by :meth:`SlamConfig.from_dict`; unknown sections or keys raise
    ``argparse.ArgumentTypeError`` (a usage error) naming them.
    """
    value = json_object(text, "--set")
    if "preset" in value:
        raise argparse.ArgumentTypeError("--set takes configuration sections; use --preset")
    try:
        SlamConfig.from_dict(value)
    except (TypeError, ValueError) as exc:  # UnknownKeyError is a ValueError
        raise argparse.ArgumentTypeError(str(exc)) from None
    return value


def add_overrides_argument(parser: argparse.ArgumentParser, example: str) -> None:
    """Add ``--set JSON`` (:func:`_overrides_argument`, stored as ``overrides``) to a parser."""
    parser.add_argument(
        "--set",
        dest="overrides",
        type=_overrides_argument,
        default=None,
        metavar="JSON",
        help=f"options over the preset, e.g. '{example}'",
    )


def add_range_perturbation_argument(parser: argparse.ArgumentParser) -> None:
    """Add ``--range-perturbation EPS`` (a round-off probe, :func:`run_episode`)."""
    parser.add_argument(
        "--range-perturbation",
        type=float,
        default=0.0,
        metavar="EPS",
        help="multiply every range the filter gets by 1 + EPS (at most "
        f"{MAX_RANGE_PERTURBATION:g}); EPS = 1e-15 gives another sample of the same "
        "filter's round-off, to measure how much of a difference is round-off",
    )


def _jobs_argument(text: str) -> int:
    try:
        jobs = int(text)
    except ValueError:
        jobs = 0
    if jobs < 1:
        raise argparse.ArgumentTypeError(f"must be an integer >= 1, got {text!r}")
    return jobs


def add_jobs_argument(parser: argparse.ArgumentParser, runs: str) -> None:
    """Add ``--jobs N``: ``runs`` (e.g. "episodes") at once in worker processes."""
    parser.add_argument(
        "--jobs",
        type=_jobs_argument,
        default=1,
        metavar="N",
        help=f"{runs} run at once in worker processes (default 1); the metrics do not "
        "change, the step times then include the competition for cores",
    )


def add_evaluate_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Add the ``evaluate`` subcommand (its handler is :func:`cmd_evaluate`)."""
    parser = subparsers.add_parser(
        "evaluate",
        help="run the SLAM on a world's route and write metrics and figures",
        description="Drive the world's route in the simulator with the SLAM filter in the "
        "loop, for each seed; write DIR/metrics.json, figures (trajectories, landmark map, "
        "pose NEES) and TUM trajectories, and print a summary table.",
    )
    parser.add_argument("--world", required=True, help="shipped world name or path to a .toml")
    parser.add_argument(
        "--seeds",
        type=seeds_argument,
        default=[0],
        help="seeds: a range 0-9, a list 0,3,5 or one seed 7 (default 0)",
    )
    parser.add_argument(
        "--preset",
        choices=("default", "thesis", "fast", "logs"),
        default="default",
        help="estimator configuration (default %(default)s; 'logs' is the one measured on "
        "the real lidar logs)",
    )
    add_overrides_argument(parser, '{"filter": {"measurement_min_travel": 0.1}}')
    parser.add_argument("--out", required=True, help="output directory")
    parser.add_argument(
        "--max-steps", type=int, default=None, help="step budget per seed (default: whole route)"
    )
    add_range_perturbation_argument(parser)
    parser.add_argument(
        "--start-scan",
        choices=START_SCAN_MODES,
        default="matcher",
        help="what the filter does with the scan taken at the start pose: the whole-scan "
        "matcher's first keyframe (default), a step of its own that makes landmarks "
        "('map'), or nothing ('none', before session 33)",
    )
    add_jobs_argument(parser, "episodes")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    parser.set_defaults(handler=cmd_evaluate)
    return parser


def cmd_evaluate(args: argparse.Namespace) -> int:
    """Run ``vslam-gym evaluate``; print the summary table; return the exit status."""
    start = time.perf_counter()
    metrics = evaluate(
        args.world,
        args.seeds,
        args.preset,
        args.out,
        progress=not args.no_progress,
        max_steps=args.max_steps,
        print_table=False,
        overrides=args.overrides,
        range_perturbation=args.range_perturbation,
        jobs=args.jobs,
        start_scan=args.start_scan,
    )
    print(format_table(metrics))
    print(
        f"wall time {time.perf_counter() - start:.1f} s on {metrics['machine']}; "
        f"wrote {Path(args.out) / 'metrics.json'} and figures"
    )
    return 0
