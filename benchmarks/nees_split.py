"""Where a route's pose NEES comes from: position against heading, and over the route.

For each seed of a world's route (``vslam_gym.evaluation.run_episode``, the SLAM in the
loop, as ``vslam-gym evaluate`` drives it) prints

- the mean pose NEES (3 degrees of freedom) and its position-only (2) and heading-only
  (1) parts, each with the reported covariance's own block;
- per fifth of the route: the mean position error ``|e_xy|`` [m] and the reported
  position standard deviation ``sqrt(P_xx + P_yy)`` [m], the mean heading error
  ``|e_theta|`` and standard deviation [rad], and the largest position-heading
  correlation ``|P_x,theta| / sqrt(P_xx P_theta,theta)`` (or ``y``) in the stretch;
- the position error predicted from the heading error alone: ``sum_t e_theta(t) J d_t``
  with ``d_t`` the true displacement [m] of step ``t`` and ``J`` the 90 degree rotation
  (a map built rotated by the heading error of the moment, with the robot keeping to
  it), beside the actual position error at the same steps.

Usage::

    python benchmarks/nees_split.py [--world house] [--seeds 0 1] [--preset default]
                                    [--set '{"filter": {"reference": "pose"}}'] [--points 5]
"""

from __future__ import annotations

import argparse
import json

import numpy as np

from vslam_gym.evaluation import NEES_PARTS, pose_nees, position_ate_rmse, run_episode
from vslam_gym.slam.geometry import wrap_angle

FIFTHS = 5
"""The route is summarised in this many equal stretches of steps."""


def correlation(covariances: np.ndarray) -> np.ndarray:
    """``(N,)`` the larger of the x-heading and y-heading correlations, absolute."""
    sd = np.sqrt(np.maximum(np.diagonal(covariances, axis1=1, axis2=2), np.finfo(float).tiny))
    return (np.abs(covariances[:, :2, 2]) / (sd[:, :2] * sd[:, 2:])).max(axis=1)


def heading_drift(error: np.ndarray, true_poses: np.ndarray) -> np.ndarray:
    """``(N, 2)`` position error [m] the heading error alone builds up along the true path."""
    displacement = np.diff(true_poses[:, :2], axis=0)
    theta = error[:-1, 2]
    step = np.column_stack([-theta * displacement[:, 1], theta * displacement[:, 0]])
    return np.vstack([np.zeros(2), np.cumsum(step, axis=0)])


def report(world: str, seed: int, preset: str, overrides: dict | None, points: int) -> None:
    """Print one seed's split (see the module docstring)."""
    log = run_episode(world, seed, preset, overrides=overrides)
    error = log.slam_poses - log.true_poses
    error[:, 2] = wrap_angle(error[:, 2])
    covs = log.slam_covs[1:]  # row 0 is the known start (zero covariance)
    full = pose_nees(log.slam_poses[1:], covs, log.true_poses[1:])
    parts = {
        name: pose_nees(log.slam_poses[1:], covs, log.true_poses[1:], rows)
        for name, rows in NEES_PARTS.items()
    }
    ate = position_ate_rmse(log.slam_poses, log.true_poses)
    print(
        f"{world} seed {seed}: {log.steps} steps, position ATE {ate:.3f} m; mean NEES "
        f"{np.nanmean(full):.1f} (3 dof), position {np.nanmean(parts['position']):.1f} (2), "
        f"heading {np.nanmean(parts['heading']):.1f} (1)"
    )
    steps = len(full)
    print(
        f"  {'stretch':>9s} {'NEES':>6s} {'|e_xy| m':>9s} {'sd_xy m':>8s} {'|e_th| rad':>10s} "
        f"{'sd_th rad':>9s} {'corr':>5s}"
    )
    for k in range(FIFTHS):
        rows = slice(k * steps // FIFTHS, (k + 1) * steps // FIFTHS)
        e, p = error[1:][rows], covs[rows]
        print(
            f"  {k + 1:>4d} of {FIFTHS} {np.nanmean(full[rows]):6.1f} "
            f"{np.hypot(e[:, 0], e[:, 1]).mean():9.3f} "
            f"{np.sqrt(p[:, 0, 0] + p[:, 1, 1]).mean():8.3f} "
            f"{np.abs(e[:, 2]).mean():10.4f} {np.sqrt(p[:, 2, 2]).mean():9.4f} "
            f"{correlation(p).max():5.2f}"
        )
    drift = heading_drift(error, log.true_poses)
    for t in np.linspace(0, len(error) - 1, points + 1).astype(int)[1:]:
        print(
            f"  step {t:4d}: position error ({error[t, 0]:+.3f}, {error[t, 1]:+.3f}) m, "
            f"from the heading error alone ({drift[t, 0]:+.3f}, {drift[t, 1]:+.3f}) m"
        )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--world", default="house")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1])
    parser.add_argument("--preset", default="default")
    parser.add_argument(
        "--set",
        dest="overrides",
        type=json.loads,
        default=None,
        help="JSON configuration sections over the preset",
    )
    parser.add_argument(
        "--points", type=int, default=5, help="steps at which the heading-built error is printed"
    )
    args = parser.parse_args()
    for seed in args.seeds:
        report(args.world, seed, args.preset, args.overrides, args.points)


if __name__ == "__main__":
    main()
