"""A waypoint-following controller that drives a world's route.

The controller works on any pose (the true pose from ``info["pose"]``, or an estimate
such as a SLAM belief's mean) and returns actions of ``VSlam/LidarWorld-v0``: normalised
``(speed, turn rate)`` commands in ``[-1, 1]^2``.

Steering: the turn command is proportional to the heading error towards the current
waypoint. Speed: scaled by ``cos(heading error)`` (zero when the waypoint is behind), and
reduced when approaching a waypoint with a sharp turn after it, and when approaching the
final waypoint, so that the robot takes corners without circling and stops at the end.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from vslam_gym.sim.odometry import wrap_angle
from vslam_gym.sim.world import Route


@dataclass(frozen=True)
class RouteFollowerConfig:
    """Gains and tolerances of :class:`RouteFollower`.

    Attributes:
        waypoint_tolerance: a waypoint is reached within this distance [m].
        cruise_speed: speed command on straight stretches, in action units [-] (1.0 is the
            robot's ``max_speed``).
        min_speed: lowest speed command while slowing down for a turn or the final
            waypoint [-] (turning on the spot is governed by ``turn_in_place_angle``).
        heading_gain: turn command per radian of heading error [1/rad], clipped to +-1.
        turn_in_place_angle: heading error [rad] beyond which the robot only turns.
        slow_down_distance: distance [m] before a waypoint where slowing for the turn after
            it (or for the final stop) starts.
    """

    waypoint_tolerance: float = 0.3
    cruise_speed: float = 1.0
    min_speed: float = 0.2
    heading_gain: float = 2.0
    turn_in_place_angle: float = math.radians(75.0)
    slow_down_distance: float = 1.0

    def __post_init__(self) -> None:
        checks = {
            "waypoint_tolerance": self.waypoint_tolerance > 0.0,
            "cruise_speed": 0.0 < self.cruise_speed <= 1.0,
            "min_speed": 0.0 < self.min_speed <= self.cruise_speed,
            "heading_gain": self.heading_gain > 0.0,
            "turn_in_place_angle": 0.0 < self.turn_in_place_angle <= math.pi,
            "slow_down_distance": self.slow_down_distance >= 0.0,
        }
        for name, ok in checks.items():
            if not (ok and math.isfinite(getattr(self, name))):
                raise ValueError(
                    f"RouteFollowerConfig.{name} is out of range: {getattr(self, name)}"
                )


class RouteFollower:
    """Follow waypoints in order; for a looping route, return to the first at the end.

    Args:
        route: a :class:`Route` or a sequence of ``(x, y)`` waypoints [m], world frame.
        config: gains and tolerances.
        loop: for a plain sequence, whether to return to the first waypoint (a
            :class:`Route` brings its own ``loop``).

    Example::

        follower = RouteFollower(env.unwrapped.world.route)
        obs, info = env.reset(seed=0)
        while not follower.done:
            obs, reward, terminated, truncated, info = env.step(follower(info["pose"]))
    """

    def __init__(
        self,
        route: Route | Sequence[Sequence[float]],
        config: RouteFollowerConfig | None = None,
        loop: bool = False,
    ) -> None:
        if isinstance(route, Route):
            waypoints, loop = route.waypoints, route.loop
        else:
            waypoints = route
        points = np.asarray(waypoints, dtype=float)
        if points.ndim != 2 or points.shape[1] != 2 or len(points) == 0:
            raise ValueError(f"route needs at least one (x, y) waypoint, got shape {points.shape}")
        if not np.all(np.isfinite(points)):
            raise ValueError("route waypoints must be finite")
        if loop:
            points = np.vstack([points, points[:1]])
        self.config = config if config is not None else RouteFollowerConfig()
        self.targets = points
        """``(m, 2)`` targets in order (a looping route ends with its first waypoint)."""
        self.index = 0
        """Index of the current target in :attr:`targets`."""

    def reset(self) -> None:
        """Start the route again from its first waypoint."""
        self.index = 0

    @property
    def done(self) -> bool:
        """All targets reached."""
        return self.index >= len(self.targets)

    @property
    def progress(self) -> float:
        """Fraction [0, 1] of targets reached."""
        return self.index / len(self.targets)

    def _turn_after(self, position: np.ndarray) -> float | None:
        """Turn angle [rad] at the current target, arriving from ``position`` (None: last)."""
        if self.index + 1 >= len(self.targets):
            return None
        target = self.targets[self.index]
        incoming = target - position
        outgoing = self.targets[self.index + 1] - target
        angle_in = math.atan2(incoming[1], incoming[0])
        angle_out = math.atan2(outgoing[1], outgoing[0])
        return abs(float(wrap_angle(angle_out - angle_in)))

    def __call__(self, pose: np.ndarray | Sequence[float]) -> np.ndarray:
        """Return the action ``(speed, turn) in [-1, 1]^2`` (float32) for the pose.

        Args:
            pose: ``(x [m], y [m], theta [rad])`` in the world frame.

        Returns:
            Zeros once :attr:`done`.
        """
        x, y, theta = (float(c) for c in pose)
        if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(theta)):
            raise ValueError(f"pose must be finite, got {pose!r}")
        cfg = self.config
        while not self.done:
            tx, ty = self.targets[self.index]
            distance = math.hypot(tx - x, ty - y)
            if distance > cfg.waypoint_tolerance:
                break
            self.index += 1
        if self.done:
            return np.zeros(2, dtype=np.float32)
        error = float(wrap_angle(math.atan2(ty - y, tx - x) - theta))
        turn = max(-1.0, min(1.0, cfg.heading_gain * error))
        if abs(error) >= cfg.turn_in_place_angle:
            return np.array([0.0, turn], dtype=np.float32)
        # Slow down before a sharp turn, and before the final target.
        turn_after = self._turn_after(np.array([x, y]))
        corner_speed = (
            cfg.min_speed
            if turn_after is None
            else max(cfg.min_speed, cfg.cruise_speed * math.cos(turn_after / 2.0))
        )
        if cfg.slow_down_distance > 0.0 and distance < cfg.slow_down_distance:
            closeness = distance / cfg.slow_down_distance
            limit = corner_speed + (cfg.cruise_speed - corner_speed) * closeness
        else:
            limit = cfg.cruise_speed
        speed = limit * max(0.0, math.cos(error))
        return np.array([speed, turn], dtype=np.float32)
