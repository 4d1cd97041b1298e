"""The Gymnasium environment ``VSlam/LidarWorld-v0``: a lidar robot in a 2-D world."""

from __future__ import annotations

import dataclasses
import math
import numbers
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from gymnasium.error import ResetNeeded

from vslam_gym.config_utils import check_keys
from vslam_gym.sim.lidar import Lidar, LidarScan, check_lidar_spec
from vslam_gym.sim.odometry import OdometryModel, integrate_increments
from vslam_gym.sim.physics import DiffDriveSim, PhysicsConfig, StepOutcome
from vslam_gym.sim.world import LidarSpec, World
from vslam_gym.sim.world_file import load_world

RANDOM_WORLD = "random"
"""The ``world`` argument that draws a new random world at every reset."""


class ActionError(ValueError):
    """An action the environment cannot apply (NaN, wrong shape or type)."""


class ScanObservation:
    """The ``scan`` observation: the noisy lidar ranges [m], descending bearing."""

    def __init__(self, env: LidarWorldEnv) -> None:
        self.env = env

    def space(self) -> spaces.Box:
        """``Box(0, max_range, (n_beams,), float32)``."""
        spec = self.env.lidar_spec
        return spaces.Box(0.0, spec.max_range, shape=(spec.n_beams,), dtype=np.float32)

    def observe(self) -> np.ndarray:
        """Return the ranges [m] of the latest scan as float32."""
        return self.env._scan.ranges.astype(np.float32)


class OdometryObservation:
    """The ``odometry`` observation: noisy ``(rot1 [rad], trans [m], rot2 [rad])``."""

    def __init__(self, env: LidarWorldEnv) -> None:
        self.env = env

    def space(self) -> spaces.Box:
        """``Box(-inf, inf, (3,), float32)``."""
        return spaces.Box(-np.inf, np.inf, shape=(3,), dtype=np.float32)

    def observe(self) -> np.ndarray:
        """Return the noisy increments of the last control period as float32."""
        return self.env._noisy_increments.astype(np.float32)


OBSERVATION_TYPES: dict[str, type[ScanObservation] | type[OdometryObservation]] = {
    "scan": ScanObservation,
    "odometry": OdometryObservation,
}
"""The observation kinds, by key of the ``Dict`` observation."""


class LidarWorldEnv(gym.Env[dict[str, np.ndarray], np.ndarray]):
    """A disc robot with a 2-D lidar and wheel odometry among static obstacles.

    ## Description

    The robot is a differential-drive disc in a planar world of static obstacles
    (polygons, circles, walls) described by a world file (see the README section "World
    files") or generated at random. Physics is pymunk: the robot stops or slides on
    contact and never passes through obstacles. Every control period (0.1 s by default)
    the robot receives a velocity command and returns a lidar scan and the odometry
    increments of the motion, both noisy. The environment is the simulator for SLAM in
    the loop: it has no task of its own, and the only reward is a collision penalty.

    World frame: right-handed, x east, y north, theta counter-clockwise from x; metres,
    seconds, radians.

    ## Action Space

    ``Box(-1, 1, (2,), float32)``, scaled linearly to the robot's limits:

    | Num | Action                  | Scaled to                                      |
    |-----|-------------------------|------------------------------------------------|
    | 0   | forward speed command   | ``v = a0 * max_speed`` [m/s] (negative: back)  |
    | 1   | turn-rate command       | ``omega = a1 * max_turn_rate`` [rad/s] (CCW +) |

    Actions outside the box are clipped to it (``inf`` included); actions containing
    NaN, or of the wrong shape, raise :class:`ActionError` (a ``ValueError``).

    ## Observation Space

    ``Dict`` of two float32 vectors:

    | Key        | Shape         | Bounds           | Content                                  |
    |------------|---------------|------------------|------------------------------------------|
    | `scan`     | `(n_beams,)`  | `[0, max_range]` | lidar ranges [m], beam ``i`` at bearing   |
    |            |               |                  | ``info["bearings"][i]`` (descending, left |
    |            |               |                  | to right); ``max_range`` means no return |
    | `odometry` | `(3,)`        | `(-inf, inf)`    | noisy ``(rot1 [rad], trans [m], rot2      |
    |            |               |                  | [rad])`` of the last control period       |

    ``n_beams = fov_deg / resolution_deg + 1`` (181 by default). Lidar noise: range
    ``N(0, sigma_range^2)``, bearing ``N(0, sigma_bearing^2)`` on the cast ray (the
    reported bearing is nominal). Odometry: Thrun's odometry motion model with
    ``alphas``; backward motion gives a negative ``trans`` (see
    :mod:`vslam_gym.sim.odometry`). After ``reset`` the odometry is zero.

    ## Rewards

    ``-collision_penalty`` for a control period in which the robot touched an obstacle,
    0 otherwise. The named terms are echoed in ``info["rewards"]``.

    ## Starting State

    The robot starts at the world's ``robot.start`` pose, at rest; with
    ``world="random"`` a new world (and start) is drawn at each reset from the
    environment's random generator. ``reset(seed=s)`` is deterministic: the same seed
    gives the same world, scans and odometry for the same actions.

    ## Episode End

    - Termination: a collision, if ``terminate_on_collision`` is true.
    - Truncation: ``max_episode_steps`` of the registration (1000 for
      ``VSlam/LidarWorld-v0``, i.e. 100 s at the default control period).

    ## Arguments

    ```python
    import gymnasium as gym
    import vslam_gym

    gym.register_envs(vslam_gym)
    env = gym.make("VSlam/LidarWorld-v0", world="house", render_mode="rgb_array")
    ```

    | Argument                 | Default   | Meaning                                              |
    |--------------------------|-----------|------------------------------------------------------|
    | `world`                  | `"house"` | shipped world name, path to a TOML file, or          |
    |                          |           | `"random"` (a new random world per reset)            |
    | `world_params`           | `None`    | keyword arguments of `generate_random_world`          |
    |                          |           | (only with `world="random"`)                         |
    | `lidar`                  | `None`    | overrides of the world's lidar: `fov_deg`,           |
    |                          |           | `resolution_deg`, `max_range`, `sigma_range`,        |
    |                          |           | `sigma_bearing_deg`                                  |
    | `odometry_alphas`        | `None`    | `(a1, a2, a3, a4)` overriding the world's            |
    | `control_period`         | `0.1`     | seconds per step                                     |
    | `physics_substeps`       | `10`      | minimum pymunk steps per control period              |
    | `collision_penalty`      | `1.0`     | penalty per step in contact (>= 0)                   |
    | `terminate_on_collision` | `False`   | end the episode at the first contact                 |
    | `render_mode`            | `None`    | `"rgb_array"` or `"human"`                           |

    ``info`` (after ``reset`` and every ``step``): ``pose`` true pose ``(x, y, theta)``;
    ``odom_pose`` the pose integrated from the noisy odometry (equal to the true pose at
    reset); ``hit_ids`` the obstacle id hit by each beam (-1: none; for evaluation only);
    ``bearings`` the nominal beam bearings [rad]; ``collision`` and ``contact_ids``;
    ``odometry_true`` and ``odometry_noisy`` increments; ``rewards``.

    ## Version History

    - v0: initial version.

    ## Notes

    - The robot centre is the lidar centre; there is no robot-to-lidar offset.
    - The physics applies a command one substep late (10 ms with the defaults): the first
      substep of a period still moves with the previous period's velocity.
    - A hit whose noisy range reaches ``max_range`` reads as no return (id -1).
    - The odometry is derived from the true motion over the period, including motion
      along an obstacle the robot slides on, not from the command.
    """

    metadata = {"render_modes": ["human", "rgb_array"], "render_fps": 10}

    screen_width = 640
    """Width [px] of rendered frames."""
    screen_height = 480
    """Height [px] of rendered frames."""
    render_margin = 0.5
    """Margin [m] around the world's bounding box in rendered frames."""
    max_rendered_path = 10_000
    """Most recent true positions kept for drawing the path."""

    def __init__(
        self,
        world: str = "house",
        world_params: Mapping[str, Any] | None = None,
        lidar: Mapping[str, float] | None = None,
        odometry_alphas: tuple[float, float, float, float] | None = None,
        control_period: float = 0.1,
        physics_substeps: int = 10,
        collision_penalty: float = 1.0,
        terminate_on_collision: bool = False,
        render_mode: str | None = None,
    ) -> None:
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(
                f"render_mode must be one of {self.metadata['render_modes']} or None, "
                f"got {render_mode!r}"
            )
        for name, value in (
            ("collision_penalty", collision_penalty),
            ("control_period", control_period),
        ):
            if not isinstance(value, numbers.Real) or isinstance(value, bool):
                raise ValueError(f"{name} must be a number, got {value!r}")
        if not (math.isfinite(collision_penalty) and collision_penalty >= 0.0):
            raise ValueError(f"collision_penalty must be finite and >= 0, got {collision_penalty}")
        if not isinstance(physics_substeps, numbers.Integral) or isinstance(physics_substeps, bool):
            raise ValueError(f"physics_substeps must be an integer, got {physics_substeps!r}")
        if not isinstance(terminate_on_collision, bool | np.bool_):
            raise ValueError(
                f"terminate_on_collision must be a bool, got {terminate_on_collision!r}"
            )
        self.render_mode = render_mode
        self.world_name = str(world)
        self.collision_penalty = float(collision_penalty)
        self.terminate_on_collision = bool(terminate_on_collision)
        self.physics_config = PhysicsConfig(
            control_period=float(control_period), substeps=int(physics_substeps)
        )
        lidar_overrides = dict(lidar or {})
        check_keys(
            lidar_overrides.keys(),
            [f.name for f in dataclasses.fields(LidarSpec)],
            "LidarWorldEnv(lidar=...)",
        )
        self._random = self.world_name == RANDOM_WORLD
        self.world_params = dict(world_params or {})
        if self.world_params and not self._random:
            raise ValueError(f'world_params only applies to world="random", not {world!r}')
        if self._random:
            self._fixed_world: World | None = None
            self.lidar_spec = check_lidar_spec(LidarSpec(**lidar_overrides))
        else:
            loaded = load_world(world)
            self.lidar_spec = check_lidar_spec(dataclasses.replace(loaded.lidar, **lidar_overrides))
            self._fixed_world = dataclasses.replace(loaded, lidar=self.lidar_spec)
        if odometry_alphas is not None and not isinstance(odometry_alphas, Sequence | np.ndarray):
            raise ValueError(f"odometry_alphas must be 4 numbers, got {odometry_alphas!r}")
        self._odometry_alphas = None if odometry_alphas is None else tuple(odometry_alphas)
        if self._odometry_alphas is not None:
            OdometryModel(alphas=self._odometry_alphas)  # validates

        self.action_space = spaces.Box(-1.0, 1.0, shape=(2,), dtype=np.float32)
        self._observers = {key: kind(self) for key, kind in OBSERVATION_TYPES.items()}
        self.observation_space = spaces.Dict(
            {key: observer.space() for key, observer in self._observers.items()}
        )

        # Episode state, set by reset().
        self.world: World | None = self._fixed_world
        self._lidar: Lidar | None = None
        self._sim: DiffDriveSim | None = None
        self._odometry: OdometryModel | None = None
        self._scan: LidarScan | None = None
        self._outcome: StepOutcome | None = None
        self._odom_pose = np.zeros(3)
        self._true_increments = np.zeros(3)
        self._noisy_increments = np.zeros(3)
        self._path: list[tuple[float, float]] = []
        self._screen: Any = None
        self._clock: Any = None

    # ------------------------------------------------------------------ episode

    def _make_world(self) -> World:
        """Return the world of a new episode (a fresh random one, or the fixed one)."""
        if self._fixed_world is not None:
            return self._fixed_world
        from vslam_gym.sim.random_world import generate_random_world  # only for "random"

        world = generate_random_world(self.np_random, **self.world_params)
        return dataclasses.replace(world, lidar=self.lidar_spec)

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        """Start an episode at the world's start pose; see the class docstring.

        ``options`` takes no keys (world, lidar and noise are constructor arguments); a
        non-empty mapping raises ``ValueError`` naming its keys rather than being ignored.
        """
        if options:
            raise ValueError(
                f"LidarWorldEnv.reset takes no options (set the world, lidar and noise when "
                f"making the env), got {sorted(options)}"
            )
        super().reset(seed=seed)
        world = self._make_world()
        if self._lidar is None or world is not self.world:
            self._lidar = Lidar.for_world(world, self.lidar_spec)
        self.world = world
        self._odometry = OdometryModel(alphas=self._odometry_alphas or tuple(world.odometry.alphas))
        self._sim = DiffDriveSim(world, self.physics_config)  # a new pymunk space
        pose = self._sim.pose
        self._odom_pose = pose.copy()
        self._true_increments = np.zeros(3)
        self._noisy_increments = np.zeros(3)
        self._outcome = StepOutcome(collision=False, contact_ids=(), command=(0.0, 0.0))
        self._scan = self._lidar.scan(pose, self.np_random)
        self._path = [(float(pose[0]), float(pose[1]))]
        if self.render_mode == "human":
            self.render()
        return self._observe(), self._info(self._rewards())

    def step(
        self, action: np.ndarray
    ) -> tuple[dict[str, np.ndarray], float, bool, bool, dict[str, Any]]:
        """Apply one action for one control period; see the class docstring."""
        if self._sim is None:
            raise ResetNeeded("call reset() before step()")
        v, omega = self._command(action)
        self._simulate(v, omega)
        observation = self._observe()
        rewards = self._rewards()
        reward = float(sum(rewards.values()))
        terminated = self._is_terminated()
        info = self._info(rewards)
        if self.render_mode == "human":
            self.render()
        return observation, reward, terminated, False, info

    def _command(self, action: np.ndarray) -> tuple[float, float]:
        """Check and clip an action, scale it to ``(v [m/s], omega [rad/s])``."""
        try:
            a = np.asarray(action, dtype=np.float64)
        except (TypeError, ValueError) as err:
            raise ActionError(
                f"action must be a numeric array of shape (2,), got {action!r}"
            ) from err
        if a.shape != (2,):
            raise ActionError(f"action must have shape (2,), got shape {a.shape}")
        if np.isnan(a).any():
            raise ActionError(f"action contains NaN: {action!r}")
        a0, a1 = np.clip(a, self.action_space.low, self.action_space.high)
        robot = self._sim.world.robot
        return float(a0) * robot.max_speed, float(a1) * robot.max_turn_rate

    def _simulate(self, v: float, omega: float) -> None:
        """Physics for one control period, then odometry and a new scan."""
        before = self._sim.pose
        self._outcome = self._sim.step(v, omega)
        after = self._sim.pose
        self._true_increments = self._odometry.increments(before, after)
        self._noisy_increments = self._odometry.sample(self._true_increments, self.np_random)
        self._odom_pose = integrate_increments(self._odom_pose, self._noisy_increments)
        self._scan = self._lidar.scan(after, self.np_random)
        self._path.append((float(after[0]), float(after[1])))
        if len(self._path) > self.max_rendered_path:
            del self._path[: len(self._path) - self.max_rendered_path]

    def _observe(self) -> dict[str, np.ndarray]:
        return {key: observer.observe() for key, observer in self._observers.items()}

    def _rewards(self) -> dict[str, float]:
        """Named reward terms of the last control period."""
        return {"collision": -self.collision_penalty if self._outcome.collision else 0.0}

    def _is_terminated(self) -> bool:
        return self.terminate_on_collision and self._outcome.collision

    def _info(self, rewards: dict[str, float]) -> dict[str, Any]:
        return {
            "pose": self._sim.pose,
            "odom_pose": self._odom_pose.copy(),
            "hit_ids": self._scan.hit_ids.copy(),
            "bearings": self._scan.bearings.copy(),
            "collision": self._outcome.collision,
            "contact_ids": self._outcome.contact_ids,
            "odometry_true": self._true_increments.copy(),
            "odometry_noisy": self._noisy_increments.copy(),
            "rewards": rewards,
        }

    @property
    def pose(self) -> np.ndarray:
        """True robot pose ``(x [m], y [m], theta [rad])`` (after ``reset``)."""
        if self._sim is None:
            raise ResetNeeded("call reset() first")
        return self._sim.pose

    @property
    def scan(self) -> LidarScan:
        """The latest noisy scan with bearings and hit ids (after ``reset``)."""
        if self._scan is None:
            raise ResetNeeded("call reset() first")
        return self._scan

    # ------------------------------------------------------------------ rendering

    def render(self) -> np.ndarray | None:
        """Draw obstacles, true path, lidar rays and hits, and the robot.

        Returns an ``(H, W, 3)`` uint8 array for ``render_mode="rgb_array"``; shows the
        frame in a pygame window for ``"human"``.
        """
        if self.render_mode is None:
            gym.logger.warn(
                "render() called without a render_mode; pass render_mode='rgb_array' or "
                "'human' to the constructor."
            )
            return None
        if self._sim is None:
            raise ResetNeeded("call reset() before render()")
        import pygame  # lazy: only rendering needs pygame

        size = (self.screen_width, self.screen_height)
        if self.render_mode == "human" and self._screen is None:
            pygame.display.init()
            pygame.display.set_caption(f"vslam-gym: {self.world.name}")
            self._screen = pygame.display.set_mode(size)
            self._clock = pygame.time.Clock()
        canvas = pygame.Surface(size)
        _draw_frame(pygame, canvas, self)
        if self.render_mode == "human":
            self._screen.blit(canvas, (0, 0))
            pygame.event.pump()
            pygame.display.flip()
            self._clock.tick(self.metadata["render_fps"])
            return None
        return np.transpose(np.array(pygame.surfarray.pixels3d(canvas)), (1, 0, 2)).copy()

    def close(self) -> None:
        """Close the pygame window, if any."""
        if self._screen is not None:
            import pygame

            pygame.display.quit()
            self._screen = None
            self._clock = None

    def __getstate__(self) -> dict[str, Any]:
        state = self.__dict__.copy()
        state["_screen"] = None  # pygame objects do not pickle; a copy opens its own window
        state["_clock"] = None
        return state


_COLORS = {
    "background": (255, 255, 255),
    "obstacle": (110, 110, 120),
    "path": (40, 90, 200),
    "ray": (255, 200, 200),
    "hit": (220, 30, 30),
    "robot": (30, 150, 60),
    "heading": (0, 0, 0),
}


def _draw_frame(
    pygame: Any, canvas: Any, env: LidarWorldEnv
) -> tuple[Callable[[float, float], tuple[int, int]], float]:
    """Draw one frame of ``env`` on the pygame surface ``canvas``.

    Returns:
        The world-to-pixel map ``px(x, y)`` of the frame and its scale [px/m], for
        overlays (the SLAM wrapper draws the belief with them).
    """
    from vslam_gym.sim.shapes import obstacle_bounds

    world = env.world
    pose = env._sim.pose
    boxes = [obstacle_bounds(o) for o in world.obstacles]
    xs = [pose[0]] + [b[0] for b in boxes] + [b[2] for b in boxes]
    ys = [pose[1]] + [b[1] for b in boxes] + [b[3] for b in boxes]
    x_low, x_high = min(xs) - env.render_margin, max(xs) + env.render_margin
    y_low, y_high = min(ys) - env.render_margin, max(ys) + env.render_margin
    width, height = canvas.get_size()
    scale = min(width / (x_high - x_low), height / (y_high - y_low))
    x_pad = (width - scale * (x_high - x_low)) / 2.0
    y_pad = (height - scale * (y_high - y_low)) / 2.0

    def px(x: float, y: float) -> tuple[int, int]:
        return (
            int(round(x_pad + (x - x_low) * scale)),
            int(round(height - y_pad - (y - y_low) * scale)),
        )

    canvas.fill(_COLORS["background"])
    scan = env._scan
    angles = pose[2] + scan.bearings
    for r, angle in zip(scan.ranges, angles, strict=True):
        end = (pose[0] + r * math.cos(angle), pose[1] + r * math.sin(angle))
        pygame.draw.line(canvas, _COLORS["ray"], px(pose[0], pose[1]), px(*end), 1)
    for obstacle in world.obstacles:
        if obstacle.kind == "circle":
            radius = max(1, int(round(obstacle.radius * scale)))
            pygame.draw.circle(canvas, _COLORS["obstacle"], px(*obstacle.center), radius)
        elif obstacle.kind == "polygon":
            pygame.draw.polygon(canvas, _COLORS["obstacle"], [px(*p) for p in obstacle.points])
        else:
            thickness = max(1, int(round(obstacle.thickness * scale)))
            points = [px(*p) for p in obstacle.points]
            pygame.draw.lines(canvas, _COLORS["obstacle"], False, points, thickness)
            for p in points:
                pygame.draw.circle(canvas, _COLORS["obstacle"], p, max(1, thickness // 2))
    if len(env._path) > 1:
        pygame.draw.lines(canvas, _COLORS["path"], False, [px(*p) for p in env._path], 2)
    for r, angle, hit_id in zip(scan.ranges, angles, scan.hit_ids, strict=True):
        if hit_id >= 0:
            end = (pose[0] + r * math.cos(angle), pose[1] + r * math.sin(angle))
            pygame.draw.circle(canvas, _COLORS["hit"], px(*end), 2)
    centre = px(pose[0], pose[1])
    radius = max(2, int(round(world.robot.radius * scale)))
    pygame.draw.circle(canvas, _COLORS["robot"], centre, radius)
    nose = (
        pose[0] + world.robot.radius * math.cos(pose[2]),
        pose[1] + world.robot.radius * math.sin(pose[2]),
    )
    pygame.draw.line(canvas, _COLORS["heading"], centre, px(*nose), 2)
    return px, scale
