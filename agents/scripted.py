"""Scripted exploration agents for the SLAM-wrapped environments (``VSlam/Explore*-v0``).

Every agent has the same two methods:

- ``reset(env, obs, info, seed=None)``: start an episode (call after ``env.reset``);
- ``act(obs, info) -> np.ndarray``: the action ``(speed, turn)`` in ``[-1, 1]^2``, float32.

Agents, from blind to informed:

| Agent            | Uses                                                   |
|------------------|--------------------------------------------------------|
| `RandomAgent`    | its own random generator only                          |
| `WallFollower`   | the scan (``obs["scan"]``)                             |
| `FrontierAgent`  | the SLAM belief (``env.get_wrapper_attr("belief")``,  |
|                  | ``info["slam_pose"]``) and the scan                    |
| `RouteAgent`     | the world's route and the TRUE pose ``info["pose"]``:  |
|                  | an oracle baseline, not a fair exploration policy      |

Besides the observation, agents read the robot's own specification (radius, speed
limits: ``env.unwrapped.world.robot``) and the lidar's (``env.unwrapped.lidar_spec``),
never the obstacles. ``obs["scan"]`` holds ranges divided by the lidar's maximum range;
beam ``i`` points at ``info["bearings"][i]`` (descending: left to right).

Only the public API: ``gymnasium.make`` with the registered ids, ``env.unwrapped``,
``env.get_wrapper_attr``, :class:`vslam_gym.control.RouteFollower`,
:func:`vslam_gym.belief_observation.belief_segments` and
:func:`vslam_gym.shield.corridor_free_length`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, Protocol

import gymnasium as gym
import numpy as np

from vslam_gym.belief_observation import belief_segments, frontier_targets
from vslam_gym.config_utils import check_field_types, nested_dataclass_from_dict
from vslam_gym.control import RouteFollower, RouteFollowerConfig
from vslam_gym.shield import corridor_free_length

__all__ = [
    "AGENT_CONFIGS",
    "SCRIPTED_AGENTS",
    "Agent",
    "FrontierAgent",
    "FrontierConfig",
    "RandomAgent",
    "RouteAgent",
    "RouteAgentConfig",
    "SafetyConfig",
    "ScanNavigator",
    "WallFollower",
    "WallFollowerConfig",
    "make_agent",
]


class Agent(Protocol):
    """What :func:`agents.evaluate_agents.run_agent_episode` drives."""

    name: str

    def reset(
        self, env: gym.Env, obs: dict[str, np.ndarray], info: dict[str, Any], seed: int | None
    ) -> None:
        """Start an episode: ``obs, info`` as ``env.reset`` returned them."""

    def act(self, obs: dict[str, np.ndarray], info: dict[str, Any]) -> np.ndarray:
        """The action ``(speed, turn)`` in ``[-1, 1]^2`` (float32)."""


def _wrap(angle: np.ndarray | float) -> np.ndarray | float:
    """Wrap an angle [rad] to ``[-pi, pi)``."""
    return (np.asarray(angle) + math.pi) % (2.0 * math.pi) - math.pi


def _action(speed: float, turn: float) -> np.ndarray:
    return np.clip(np.array([speed, turn], dtype=np.float32), -1.0, 1.0)


def _check_positive(owner: object, *names: str) -> None:
    for name in names:
        value = getattr(owner, name)
        if not (math.isfinite(value) and value > 0.0):
            raise ValueError(f"{type(owner).__name__}.{name} must be > 0, got {value!r}")


# ---------------------------------------------------------------------------- random


class RandomAgent:
    """Uniform random actions in ``[-1, 1]^2`` from the agent's own generator.

    Args:
        seed: seed of the generator. ``reset(..., seed=s)`` reseeds it from
            ``(seed, s)``, so an episode's actions depend only on the two seeds.
    """

    name = "random"

    def __init__(self, seed: int | None = 0) -> None:
        self.seed = seed
        self.rng = np.random.default_rng(seed)

    def reset(
        self,
        env: gym.Env,
        obs: dict[str, np.ndarray],
        info: dict[str, Any],
        seed: int | None = None,
    ) -> None:
        """Reseed from ``(self.seed, seed)`` when an episode seed is given."""
        if seed is not None:
            entropy = [int(seed)] if self.seed is None else [int(self.seed), int(seed)]
            self.rng = np.random.default_rng(entropy)

    def act(self, obs: dict[str, np.ndarray], info: dict[str, Any]) -> np.ndarray:
        """A uniform random action."""
        return self.rng.uniform(-1.0, 1.0, size=2).astype(np.float32)


# ---------------------------------------------------------------------------- route


@dataclass(frozen=True)
class RouteAgentConfig:
    """Settings of :class:`RouteAgent`.

    Attributes:
        follower: gains of the :class:`~vslam_gym.control.RouteFollower`.
        repeat: drive the route again once it is done (else stop).
    """

    follower: RouteFollowerConfig = field(default_factory=RouteFollowerConfig)
    repeat: bool = True


class RouteAgent:
    """Drive the world's route with the route follower on the TRUE pose (an oracle).

    Not an exploration policy: it knows the route (laid out by the world's author or
    generator to pass every object) and steers on ground truth (``info["pose"]``). It
    bounds what a policy that sees the same places can map.

    Args:
        config: follower gains and whether to repeat the route.
    """

    name = "route"

    def __init__(self, config: RouteAgentConfig | None = None) -> None:
        self.config = config if config is not None else RouteAgentConfig()
        self.follower: RouteFollower | None = None

    def reset(
        self,
        env: gym.Env,
        obs: dict[str, np.ndarray],
        info: dict[str, Any],
        seed: int | None = None,
    ) -> None:
        """Take the route of the episode's world.

        Raises:
            ValueError: if the world has no route.
        """
        world = env.unwrapped.world
        if world.route is None:
            raise ValueError(f"world {world.name!r} has no route for the route agent")
        self.follower = RouteFollower(world.route, self.config.follower)

    def act(self, obs: dict[str, np.ndarray], info: dict[str, Any]) -> np.ndarray:
        """Follow the route from the true pose."""
        if self.follower is None:
            raise RuntimeError("call reset() first")
        if self.follower.done and self.config.repeat:
            self.follower.reset()
        return self.follower(info["pose"])


# ---------------------------------------------------------------------------- scan navigation


@dataclass(frozen=True)
class SafetyConfig:
    """Reactive obstacle avoidance from the scan (:class:`ScanNavigator`).

    The robot is a disc; turning on the spot never collides, so only forward motion is
    limited, by the free length of a corridor as wide as the robot plus ``margin`` on
    each side. The scan covers the front half-plane only, so the agents never reverse.

    Attributes:
        margin: clearance [m] kept beyond the robot radius on each side of the path.
        stop_distance: free length ahead [m] at or below which the robot only turns.
        slow_distance: free length ahead [m] below which the speed drops linearly to 0 at
            ``stop_distance``.
        candidate_step_deg: angle [deg] between the candidate headings of the gap search.
        lookahead: free length [m] a heading needs to be admissible (or the distance to
            the goal, if shorter).
        heading_gain: turn command per radian of heading error [1/rad].
        turn_in_place_angle: heading error [rad] beyond which the robot only turns.
        cruise_speed: speed command [-] on a clear path (1 is the robot's max speed).
        no_return: normalised range at or above which a beam counts as no return.
        turn_lock_steps: a turn on the spot keeps its direction until the robot drives
            again, for at most this many steps (45: a full turn at the default turn
            rate), so that it cannot dither between two headings on either side.
    """

    margin: float = 0.15
    stop_distance: float = 0.2
    slow_distance: float = 1.0
    candidate_step_deg: float = 5.0
    lookahead: float = 1.5
    heading_gain: float = 2.0
    turn_in_place_angle: float = math.radians(60.0)
    cruise_speed: float = 0.8
    no_return: float = 0.999
    turn_lock_steps: int = 45

    def __post_init__(self) -> None:
        check_field_types(self)
        _check_positive(
            self,
            "turn_lock_steps",
            "margin",
            "stop_distance",
            "candidate_step_deg",
            "lookahead",
            "heading_gain",
            "turn_in_place_angle",
            "cruise_speed",
            "no_return",
        )
        if not self.slow_distance > self.stop_distance:
            raise ValueError("SafetyConfig.slow_distance must exceed stop_distance")
        if self.cruise_speed > 1.0:
            raise ValueError(f"SafetyConfig.cruise_speed must be <= 1, got {self.cruise_speed}")


class ScanNavigator:
    """Steer towards a bearing around the obstacles a scan shows (robot frame).

    Args:
        config: margins, speeds and gains.
        robot_radius: the robot's radius [m].
        max_range: the lidar's maximum range [m].
        bearings: ``(n,)`` nominal beam bearings [rad], robot frame.
    """

    def __init__(
        self, config: SafetyConfig, robot_radius: float, max_range: float, bearings: np.ndarray
    ) -> None:
        self.config = config
        self.radius = float(robot_radius)
        self.max_range = float(max_range)
        self.bearings = np.asarray(bearings, dtype=float)
        half_fov = float(np.max(np.abs(self.bearings)))
        count = int(math.floor(math.degrees(half_fov) / config.candidate_step_deg))
        self.candidates = np.radians(config.candidate_step_deg) * np.arange(-count, count + 1)
        self.half_fov = half_fov
        self.points = np.zeros((0, 2))
        self.ranges = np.zeros(0)
        self._lock = 0.0
        self._lock_steps = 0

    def update(self, normalised_scan: np.ndarray) -> None:
        """Take a new scan (``obs["scan"]``: ranges / max range)."""
        scan = np.asarray(normalised_scan, dtype=float)
        hit = scan < self.config.no_return
        self.ranges = np.where(hit, scan * self.max_range, np.inf)
        b = self.bearings[hit]
        r = self.ranges[hit]
        self.points = np.stack([r * np.cos(b), r * np.sin(b)], axis=1)

    def free_length(self, directions: np.ndarray, margin: float | None = None) -> np.ndarray:
        """Distance [m] the robot can drive straight along each direction [rad] (robot frame).

        The corridor is ``radius + margin`` wide on each side; ``max_range`` when nothing
        of the scan is in it.
        """
        half_width = self.radius + (self.config.margin if margin is None else margin)
        return corridor_free_length(self.points, directions, half_width, self.max_range)

    def nearest(self, low: float, high: float) -> tuple[float, float] | None:
        """``(range [m], bearing [rad])`` of the closest return with bearing in ``[low, high]``."""
        inside = (self.bearings >= low) & (self.bearings <= high) & np.isfinite(self.ranges)
        if not inside.any():
            return None
        index = np.flatnonzero(inside)[np.argmin(self.ranges[inside])]
        return float(self.ranges[index]), float(self.bearings[index])

    def steer(self, desired: float, goal_distance: float = math.inf) -> np.ndarray:
        """Action heading as close to ``desired`` [rad, robot frame] as the scan allows.

        A desired bearing outside the field of view turns the robot on the spot towards
        it. Otherwise the admissible candidate heading (free for ``lookahead`` or up to the
        goal) closest to it is taken; with none admissible, the freest one. Speed drops
        with the free length ahead and with the heading error.
        """
        c = self.config
        desired = float(_wrap(desired))
        if abs(desired) > self.half_fov:
            return self.turn_in_place(math.copysign(1.0, desired))
        free = self.free_length(self.candidates)
        need = min(c.lookahead, max(goal_distance, c.stop_distance))
        admissible = free >= need
        if admissible.any():
            error = np.abs(self.candidates - desired)
            chosen = float(
                self.candidates[np.flatnonzero(admissible)[np.argmin(error[admissible])]]
            )
        else:
            best = np.flatnonzero(free == free.max())
            chosen = float(
                self.candidates[best[np.argmin(np.abs(self.candidates[best] - desired))]]
            )
        return self.drive(chosen)

    def drive(self, heading: float) -> np.ndarray:
        """Turn towards ``heading`` [rad, robot frame]; move forward as far as is safe."""
        c = self.config
        turn = float(np.clip(c.heading_gain * heading, -1.0, 1.0))
        if abs(heading) >= c.turn_in_place_angle:
            return self.turn_in_place(turn)
        self._lock = 0.0
        ahead = float(self.free_length(np.array([0.0, 0.5 * heading]), 0.0).min())
        room = (ahead - c.stop_distance) / (c.slow_distance - c.stop_distance)
        speed = c.cruise_speed * float(np.clip(room, 0.0, 1.0)) * max(0.0, math.cos(heading))
        return _action(speed, turn)

    def turn_in_place(self, turn: float) -> np.ndarray:
        """Turn on the spot by ``turn`` [-], in the locked direction if a turn is under way."""
        if self._lock == 0.0 or self._lock_steps >= self.config.turn_lock_steps:
            self._lock = math.copysign(1.0, turn)
            self._lock_steps = 0
        self._lock_steps += 1
        return _action(0.0, self._lock * abs(turn))


def _navigator(env: gym.Env, info: dict[str, Any], config: SafetyConfig) -> ScanNavigator:
    """A navigator for the episode's robot and lidar (specifications, not the map)."""
    base = env.unwrapped
    return ScanNavigator(
        config, base.world.robot.radius, base.lidar_spec.max_range, np.asarray(info["bearings"])
    )


# ---------------------------------------------------------------------------- wall follower


@dataclass(frozen=True)
class WallFollowerConfig:
    """Settings of :class:`WallFollower`.

    Attributes:
        side: ``"right"`` or ``"left"``: the side the wall is kept on.
        distance: distance [m] kept between the robot's body and the wall.
        distance_gain: heading correction per metre of distance error [rad/m].
        max_correction: largest heading correction towards or away from the wall [rad].
        lost_distance: beyond this body-to-wall distance [m] the wall is lost and the
            robot curves towards its side to find one.
        search_turn: turn command [-] while searching (towards the wall side).
        front_sector: the wall is looked for at bearings from the side (90 deg) round
            to this many radians past straight ahead.
        safety: obstacle avoidance.
    """

    side: str = "right"
    distance: float = 0.5
    distance_gain: float = 1.5
    max_correction: float = math.radians(45.0)
    lost_distance: float = 2.0
    search_turn: float = 0.4
    front_sector: float = math.radians(30.0)
    safety: SafetyConfig = field(default_factory=SafetyConfig)

    def __post_init__(self) -> None:
        check_field_types(self)
        if self.side not in ("right", "left"):
            raise ValueError(
                f"WallFollowerConfig.side must be 'right' or 'left', got {self.side!r}"
            )
        _check_positive(
            self, "distance", "distance_gain", "max_correction", "lost_distance", "search_turn"
        )
        if not self.lost_distance > self.distance:
            raise ValueError("WallFollowerConfig.lost_distance must exceed distance")


class WallFollower:
    """Keep a wall on one side at a set distance, from the scan alone.

    The nearest return on the wall side (from the side round to a little past straight
    ahead) is the wall; the desired heading is along the wall's tangent there (at right
    angles to the line of sight to it), corrected towards or away from the wall in
    proportion to the distance error. Obstacle avoidance (:class:`ScanNavigator`)
    takes the free heading closest to it, so an obstacle ahead turns the robot away from
    the wall side (it then follows the new obstacle). With no wall within
    ``lost_distance`` the robot curves towards the wall side.

    Args:
        config: side, distances and gains.
    """

    name = "wall"

    def __init__(self, config: WallFollowerConfig | None = None) -> None:
        self.config = config if config is not None else WallFollowerConfig()
        self.navigator: ScanNavigator | None = None

    def reset(
        self,
        env: gym.Env,
        obs: dict[str, np.ndarray],
        info: dict[str, Any],
        seed: int | None = None,
    ) -> None:
        """Set up the scan geometry of the episode's robot and lidar."""
        self.navigator = _navigator(env, info, self.config.safety)

    def act(self, obs: dict[str, np.ndarray], info: dict[str, Any]) -> np.ndarray:
        """Follow the wall seen in ``obs["scan"]``."""
        if self.navigator is None:
            raise RuntimeError("call reset() first")
        self.navigator.update(obs["scan"])
        return self.follow()

    def follow(self) -> np.ndarray:
        """The wall-following action for the navigator's current scan."""
        c = self.config
        nav = self.navigator
        s = -1.0 if c.side == "right" else 1.0
        low, high = sorted((s * 0.5 * math.pi, -s * c.front_sector))
        wall = nav.nearest(low, high)
        if wall is None or wall[0] - nav.radius > c.lost_distance:
            return self._search(s)
        distance, bearing = wall[0] - nav.radius, wall[1]
        correction = float(np.clip(c.distance_gain * (distance - c.distance), -1.0, 1.0))
        desired = bearing - s * 0.5 * math.pi + s * c.max_correction * correction
        return nav.steer(desired)

    def _search(self, s: float) -> np.ndarray:
        nav = self.navigator
        action = nav.drive(0.0)
        if action[0] <= 0.0:  # blocked ahead: turn away from the wall side
            return nav.turn_in_place(-s)
        action[1] = s * self.config.search_turn
        return action


# ---------------------------------------------------------------------------- frontier


@dataclass(frozen=True)
class FrontierConfig:
    """Settings of :class:`FrontierAgent`.

    Attributes:
        reach_distance: a target is reached within this distance [m] of the estimated
            robot position.
        visited_radius: unknown lines whose target point lies within this distance [m]
            of a reached or abandoned target are not chosen again.
        track_radius: the current target is kept while some unknown line's target
            point is within this distance [m] of it (the map moves it a little as the
            line is re-estimated); once none is, the line was mapped and the agent
            picks the next.
        min_line_length: shorter unknown lines [m] are ignored.
        max_target_offset: on an unknown line longer than twice this [m] (e.g. a shadow
            boundary running out to the lidar's maximum range) the target is this far
            along it from its end nearest the robot instead of its midpoint.
        timeout_steps: a target not reached after this many steps is abandoned.
        progress_steps: a target is abandoned when the distance to it has not shrunk by
            ``min_progress`` within this many steps.
        min_progress: see ``progress_steps`` [m].
        unknown_threshold: lines with ``u`` above this are unknown; ``None`` takes the
            running filter's ``model.unknown_threshold``.
        wall: the wall follower used while there is no unknown line to head for.
        safety: obstacle avoidance.
    """

    reach_distance: float = 0.75
    visited_radius: float = 1.0
    track_radius: float = 0.75
    min_line_length: float = 0.3
    max_target_offset: float = 3.0
    timeout_steps: int = 300
    progress_steps: int = 60
    min_progress: float = 0.3
    unknown_threshold: float | None = None
    wall: WallFollowerConfig = field(default_factory=WallFollowerConfig)
    safety: SafetyConfig = field(default_factory=SafetyConfig)

    def __post_init__(self) -> None:
        check_field_types(self)
        _check_positive(
            self,
            "reach_distance",
            "visited_radius",
            "track_radius",
            "min_line_length",
            "max_target_offset",
            "timeout_steps",
            "progress_steps",
            "min_progress",
        )


class FrontierAgent:
    """Head for the nearest unknown line of the SLAM map (a frontier), avoiding obstacles.

    Belief-driven: the map (``env.get_wrapper_attr("belief")``) and the estimated pose
    ``info["slam_pose"]`` (world frame = map frame) choose the target; the scan avoids
    obstacles on the way. Unknown lines separate observed free space from unobserved
    space, so driving to one looks behind it.

    Target choice: among unknown lines at least ``min_line_length`` long whose target
    point (the midpoint; see ``max_target_offset`` for long lines) is not within
    ``visited_radius`` of a reached or abandoned target, the line nearest the robot
    (point-to-segment distance). The target is dropped when reached, when its line is
    gone (mapped), after ``timeout_steps``, or when the distance to it stops shrinking
    (unreachable: inside an object, behind a wall). Without any unknown line to head
    for, the agent follows walls (:class:`WallFollower`), which brings new lines in.

    Args:
        config: distances, timeouts, the fallback wall follower and obstacle avoidance.
    """

    name = "frontier"

    def __init__(self, config: FrontierConfig | None = None) -> None:
        self.config = config if config is not None else FrontierConfig()
        self.navigator: ScanNavigator | None = None
        self.wall = WallFollower(self.config.wall)
        self.env: gym.Env | None = None
        self.target: np.ndarray | None = None
        self.visited: list[np.ndarray] = []
        self._threshold = 0.5
        self._target_steps = 0
        self._best_distance = math.inf
        self._best_step = 0
        self.targets_reached = 0
        """Targets reached in the episode (diagnostics)."""
        self.targets_abandoned = 0
        """Targets abandoned (timeout, no progress) in the episode."""

    def reset(
        self,
        env: gym.Env,
        obs: dict[str, np.ndarray],
        info: dict[str, Any],
        seed: int | None = None,
    ) -> None:
        """Forget targets; set up the scan geometry and the unknown-line threshold."""
        self.env = env
        self.navigator = _navigator(env, info, self.config.safety)
        self.wall.reset(env, obs, info, seed)
        self.wall.navigator = self.navigator  # one scan, one navigator
        threshold = self.config.unknown_threshold
        if threshold is None:
            threshold = env.get_wrapper_attr("slam").config.model.unknown_threshold
        self._threshold = float(threshold)
        self.target = None
        self.visited = []
        self.targets_reached = 0
        self.targets_abandoned = 0

    def candidates(self, belief: Any, position: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Target points ``(m, 2)`` [m] of the usable unvisited unknown lines, and distances [m].

        Sorted nearest first (distance from ``position`` to the line).
        """
        return self._unvisited(*self._lines(belief, position))

    def _lines(self, belief: Any, position: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Target points and distances of every unknown line long enough, nearest first."""
        c = self.config
        segments = belief_segments(belief, self._threshold)
        return frontier_targets(segments, position, c.min_line_length, c.max_target_offset)

    def _unvisited(self, points: np.ndarray, distance: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Drop the points within ``visited_radius`` of a reached or abandoned target."""
        if not self.visited or len(points) == 0:
            return points, distance
        visited = np.asarray(self.visited)
        gap = np.linalg.norm(points[:, None, :] - visited[None, :, :], axis=2)
        fresh = gap.min(axis=1) > self.config.visited_radius
        return points[fresh], distance[fresh]

    def act(self, obs: dict[str, np.ndarray], info: dict[str, Any]) -> np.ndarray:
        """Steer to the current target, choosing a new one when needed."""
        if self.navigator is None or self.env is None:
            raise RuntimeError("call reset() first")
        c = self.config
        self.navigator.update(obs["scan"])
        pose = np.asarray(info["slam_pose"], dtype=float)
        position = pose[:2]
        points, distances = self._lines(self.env.get_wrapper_attr("belief"), position)
        if self.target is not None:
            self._check_target(self._unvisited(points, distances)[0], position)
        if self.target is None:
            points, _ = self._unvisited(points, distances)
            # Targets already within reach are done: mark them, take the next.
            while len(points) and np.linalg.norm(points[0] - position) <= c.reach_distance:
                self.visited.append(points[0].copy())
                points = points[1:]
            if len(points) == 0:
                return self.wall.follow()
            self._set_target(points[0], position)
        offset = self.target - position
        distance = float(np.hypot(*offset))
        bearing = math.atan2(offset[1], offset[0]) - pose[2]
        return self.navigator.steer(bearing, distance)

    def _set_target(self, point: np.ndarray, position: np.ndarray) -> None:
        self.target = point.copy()
        self._target_steps = 0
        self._best_distance = float(np.linalg.norm(point - position))
        self._best_step = 0

    def _check_target(self, points: np.ndarray, position: np.ndarray) -> None:
        """Keep, follow (the line moved a little) or drop the current target."""
        c = self.config
        self._target_steps += 1
        distance = float(np.linalg.norm(self.target - position))
        if distance <= c.reach_distance:
            self.visited.append(self.target)
            self.targets_reached += 1
            self.target = None
            return
        if distance < self._best_distance - c.min_progress:
            self._best_distance, self._best_step = distance, self._target_steps
        stalled = self._target_steps - self._best_step > c.progress_steps
        if self._target_steps > c.timeout_steps or stalled:
            self.visited.append(self.target)
            self.targets_abandoned += 1
            self.target = None
            return
        if len(points):
            gap = np.linalg.norm(points - self.target, axis=1)
            if gap.min() <= c.track_radius:
                self.target = points[np.argmin(gap)].copy()
                return
        self.target = None  # its line is mapped (or merged away): choose again


# ---------------------------------------------------------------------------- factory


SCRIPTED_AGENTS = {
    "random": RandomAgent,
    "route": RouteAgent,
    "wall": WallFollower,
    "frontier": FrontierAgent,
}
"""Scripted agents by command-line name."""


AGENT_CONFIGS = {
    "route": RouteAgentConfig,
    "wall": WallFollowerConfig,
    "frontier": FrontierConfig,
}
"""The settings class of each configurable scripted agent."""


def make_agent(name: str, seed: int | None = 0, config: Mapping[str, Any] | None = None) -> Agent:
    """A scripted agent by name (``random``, ``route``, ``wall``, ``frontier``).

    Args:
        name: the agent's name.
        seed: seed of :class:`RandomAgent` (the others are deterministic).
        config: fields of the agent's settings (:data:`AGENT_CONFIGS`; nested ones as
            mappings, e.g. ``{"reach_distance": 0.5, "safety": {"margin": 0.2}}``);
            None or empty: the defaults.

    Raises:
        ValueError: an unknown name, an unknown or malformed setting, or settings for the
            random agent (it has none).
    """
    if name not in SCRIPTED_AGENTS:
        raise ValueError(f"unknown agent {name!r}; choose one of {sorted(SCRIPTED_AGENTS)}")
    if name == "random":
        if config:
            raise ValueError("the random agent has no settings (only its seed)")
        return RandomAgent(seed)
    if not config:
        return SCRIPTED_AGENTS[name]()
    settings = nested_dataclass_from_dict(AGENT_CONFIGS[name], config, f"{name} agent")
    return SCRIPTED_AGENTS[name](settings)
