"""The ``vslam-gym`` console command.

Subcommands:

- ``vslam-gym worlds``: list the shipped worlds.
- ``vslam-gym run --world NAME_OR_TOML --seed S --out PATH.png [--steps N]``: drive the
  world's route with :class:`vslam_gym.control.RouteFollower` on the true pose and save a
  PNG of the world, the true path, the odometry path and the lidar hits.

Further subcommands register themselves in :data:`SUBCOMMANDS` (a name mapped to a
function that adds its parser).
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from vslam_gym.sim.world import CircleObstacle, PolygonObstacle, WallObstacle, World

DEFAULT_RUN_STEPS = 1000
"""Step budget of ``vslam-gym run`` (the registered ``max_episode_steps``)."""
DEFAULT_SCAN_EVERY = 10
"""``vslam-gym run`` plots the lidar hits of every this many scans."""


@dataclass
class RunResult:
    """What ``vslam-gym run`` recorded.

    Attributes:
        world: the world driven in.
        steps: control steps taken.
        distance: length [m] of the true path.
        collision_steps: steps in which the robot touched an obstacle.
        route_done: the route follower reached every waypoint.
        true_path: ``(steps + 1, 3)`` true poses.
        odometry_path: ``(steps + 1, 3)`` poses integrated from the noisy odometry.
        hits: ``(k, 2)`` world positions [m] of the plotted lidar returns.
    """

    world: World
    steps: int = 0
    distance: float = 0.0
    collision_steps: int = 0
    route_done: bool = False
    true_path: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    odometry_path: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    hits: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))


def _progress(total: int, enabled: bool) -> object | None:
    """Return a tqdm progress bar if tqdm is installed and wanted, else None."""
    if not enabled:
        return None
    try:
        from tqdm import tqdm
    except ImportError:
        return None
    return tqdm(total=total, unit="step", leave=False)


def run_route(
    world: str, seed: int, steps: int, scan_every: int = DEFAULT_SCAN_EVERY, progress: bool = False
) -> RunResult:
    """Drive a world's route with the route follower on the true pose.

    Args:
        world: shipped world name or path to a TOML world file (it must have a route).
        seed: seed of ``reset``.
        steps: largest number of control steps.
        scan_every: keep the lidar hits of every ``scan_every``-th scan.
        progress: show a tqdm progress bar (if tqdm is installed).

    Raises:
        ValueError: the world has no route, or a bad argument.
    """
    from vslam_gym.control import RouteFollower
    from vslam_gym.env import LidarWorldEnv

    if steps < 1 or scan_every < 1:
        raise ValueError(f"steps and scan_every must be >= 1, got {steps} and {scan_every}")
    env = LidarWorldEnv(world=world)
    if env.world is None or env.world.route is None:
        raise ValueError(f"world {world!r} has no [route] to drive")
    follower = RouteFollower(env.world.route)
    _, info = env.reset(seed=seed)
    result = RunResult(world=env.world)
    true_path, odometry_path, hits = [info["pose"]], [info["odom_pose"]], []
    bar = _progress(steps, progress)
    try:
        for step in range(steps):
            if follower.done:
                break
            _, _, terminated, _, info = env.step(follower(info["pose"]))
            true_path.append(info["pose"])
            odometry_path.append(info["odom_pose"])
            result.collision_steps += int(info["collision"])
            if step % scan_every == 0:
                pose, scan = info["pose"], env.scan
                ok = scan.hit_ids >= 0
                angles = pose[2] + scan.bearings[ok]
                ranges = scan.ranges[ok]
                hits.append(
                    np.stack(
                        [pose[0] + ranges * np.cos(angles), pose[1] + ranges * np.sin(angles)],
                        axis=1,
                    )
                )
            if bar is not None:
                bar.update(1)
            if terminated:
                break
    finally:
        if bar is not None:
            bar.close()
        env.close()
    result.steps = len(true_path) - 1
    result.true_path = np.array(true_path)
    result.odometry_path = np.array(odometry_path)
    result.hits = np.concatenate(hits) if hits else np.zeros((0, 2))
    result.distance = float(np.sum(np.hypot(*np.diff(result.true_path[:, :2], axis=0).T)))
    result.route_done = follower.done
    return result


def _wall_outline(a: np.ndarray, b: np.ndarray, radius: float) -> np.ndarray:
    """Rectangle [m] of a wall segment of half-thickness ``radius``."""
    direction = b - a
    length = float(np.hypot(*direction))
    if length == 0.0:
        return np.array([a, a, a, a])
    normal = np.array([-direction[1], direction[0]]) / length * radius
    return np.array([a + normal, b + normal, b - normal, a - normal])


def plot_run(result: RunResult, out: Path) -> None:
    """Save a PNG of the true world, true and odometry paths, and lidar hits."""
    from matplotlib.figure import Figure
    from matplotlib.patches import Circle, Polygon

    fig = Figure(figsize=(9, 7), dpi=100)
    ax = fig.subplots()
    style = {"facecolor": "0.6", "edgecolor": "0.3", "linewidth": 0.5}
    for obstacle in result.world.obstacles:
        if isinstance(obstacle, PolygonObstacle):
            ax.add_patch(Polygon(np.asarray(obstacle.points), closed=True, **style))
        elif isinstance(obstacle, CircleObstacle):
            ax.add_patch(Circle(obstacle.center, obstacle.radius, **style))
        elif isinstance(obstacle, WallObstacle):
            points = np.asarray(obstacle.points, dtype=float)
            radius = obstacle.thickness / 2.0
            for a, b in zip(points[:-1], points[1:], strict=True):
                ax.add_patch(Polygon(_wall_outline(a, b, radius), closed=True, **style))
            for p in points:
                ax.add_patch(Circle(p, radius, **style))
    if result.world.route is not None:
        waypoints = np.asarray(result.world.route.waypoints)
        ax.plot(*waypoints.T, "x", color="0.4", markersize=5, label="route waypoints")
    if len(result.hits):
        ax.plot(*result.hits.T, ".", color="tab:red", markersize=1.5, label="lidar hits")
    ax.plot(*result.odometry_path[:, :2].T, "--", color="tab:orange", label="odometry path")
    ax.plot(*result.true_path[:, :2].T, "-", color="tab:blue", label="true path")
    ax.plot(*result.true_path[0, :2], "o", color="tab:green", label="start")
    ax.set_aspect("equal")
    ax.autoscale_view()
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title(
        f"{result.world.name}: {result.steps} steps, {result.distance:.1f} m, "
        f"{result.collision_steps} collision steps"
    )
    ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize="small")
    fig.savefig(out, bbox_inches="tight")


def _cmd_run(args: argparse.Namespace) -> int:
    out = Path(args.out)
    if out.suffix.lower() != ".png":
        raise SystemExit(f"vslam-gym run: --out must end in .png, got {str(out)!r}")
    if not out.parent.exists():
        out.parent.mkdir(parents=True)
    result = run_route(
        args.world, args.seed, args.steps, args.scan_every, progress=sys.stderr.isatty()
    )
    plot_run(result, out)
    status = "route completed" if result.route_done else "route NOT completed"
    print(
        f"{result.world.name}: {result.steps} steps, {result.distance:.1f} m, "
        f"{result.collision_steps} collision steps, {status}; saved {out}"
    )
    return 0


def _cmd_worlds(args: argparse.Namespace) -> int:
    from vslam_gym.sim.world_file import list_worlds, load_world, route_length

    for name in list_worlds():
        world = load_world(name)
        route = f"route {route_length(world):.1f} m" if world.route is not None else "no route"
        print(f"{name:20s} {len(world.obstacles):4d} obstacles, {route}")
    return 0


def _add_run(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "run",
        help="drive a world's route and save a PNG",
        description="Drive the world's route with the route follower on the true pose; save a "
        "PNG of the world, the true and odometry paths and the lidar hits; print a summary.",
    )
    parser.add_argument("--world", required=True, help="shipped world name or path to a .toml")
    parser.add_argument("--seed", type=int, default=0, help="reset seed (default 0)")
    parser.add_argument("--out", required=True, help="output PNG path")
    parser.add_argument(
        "--steps", type=int, default=DEFAULT_RUN_STEPS, help="step budget (default %(default)s)"
    )
    parser.add_argument(
        "--scan-every",
        type=int,
        default=DEFAULT_SCAN_EVERY,
        help="plot the hits of every k-th scan (default %(default)s)",
    )
    parser.set_defaults(handler=_cmd_run)


def _add_worlds(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser("worlds", help="list the shipped worlds")
    parser.set_defaults(handler=_cmd_worlds)


def _add_evaluate(subparsers: argparse._SubParsersAction) -> None:
    from vslam_gym.evaluation import add_evaluate_parser

    add_evaluate_parser(subparsers)


def _add_replay(subparsers: argparse._SubParsersAction) -> None:
    from vslam_gym.replay import add_replay_parser

    add_replay_parser(subparsers)


def _add_compare(subparsers: argparse._SubParsersAction) -> None:
    from vslam_gym.compare import add_compare_parser

    add_compare_parser(subparsers)


SUBCOMMANDS: dict[str, Callable[[argparse._SubParsersAction], None]] = {
    "run": _add_run,
    "worlds": _add_worlds,
    "evaluate": _add_evaluate,
    "replay": _add_replay,
    "compare": _add_compare,
}
"""Subcommand name -> function adding its parser (which sets ``handler``)."""


def build_parser() -> argparse.ArgumentParser:
    """Build the argument parser with every subcommand of :data:`SUBCOMMANDS`."""
    parser = argparse.ArgumentParser(
        prog="vslam-gym", description="2-D lidar worlds for SLAM in the loop."
    )
    subparsers = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for add in SUBCOMMANDS.values():
        add(subparsers)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run the ``vslam-gym`` command; returns the exit status."""
    args = build_parser().parse_args(argv)
    try:
        return int(args.handler(args))
    except ValueError as err:  # bad world file, unknown world, bad arguments
        print(f"vslam-gym {args.command}: error: {err}", file=sys.stderr)
        return 2
    except (OSError, EOFError) as err:  # a missing, unreadable or truncated (gzip) file
        where = f" {err.filename}" if getattr(err, "filename", None) else ""
        reason = err.strerror if isinstance(err, OSError) and err.strerror else err
        kind = "truncated file" if isinstance(err, EOFError) else "cannot read or write"
        print(f"vslam-gym {args.command}: error: {kind}{where}: {reason}", file=sys.stderr)
        return 2


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
