"""``SlamWrapper``: the vertex SLAM in the loop; the policy sees and is rewarded by the belief."""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from gymnasium.error import ResetNeeded

from vslam_gym.belief_observation import (
    BeliefObservationConfig,
    BeliefRaster,
    FrontierCue,
    PoseUncertainty,
    SlamStatus,
    belief_segments,
    boundary_cells,
)
from vslam_gym.belief_reward import BeliefReward, BeliefRewardConfig
from vslam_gym.config_utils import dataclass_from_dict
from vslam_gym.env import LidarWorldEnv
from vslam_gym.evaluation import (
    check_start_scan,
    sensor_from_lidar,
    sets_odometry_alphas,
    slam_config,
    use_start_scan,
)
from vslam_gym.shield import ShieldConfig, SpeedShield
from vslam_gym.slam.filter import Belief, SlamConfig, VertexSLAM

ASSOCIATED_OUTCOMES = ("updated", "associated")
"""Set outcomes that count as an association (reset ``steps since association``)."""


def _slam_config(value: str | SlamConfig | Mapping[str, Any]) -> SlamConfig:
    if isinstance(value, SlamConfig):
        return value
    if isinstance(value, str):
        return SlamConfig.preset(value)
    if isinstance(value, Mapping):
        return SlamConfig.from_dict(value)
    raise TypeError(
        f"slam_config must be a preset name, a mapping or a SlamConfig, got {type(value).__name__}"
    )


class SlamWrapper(gym.Wrapper, gym.utils.RecordConstructorArgs):
    """Run :class:`~vslam_gym.slam.filter.VertexSLAM` on every step; observe the belief.

    ## Description

    Wraps a :class:`~vslam_gym.env.LidarWorldEnv` (``VSlam/LidarWorld-v0``, possibly
    inside other wrappers). Every step the wrapper feeds the step's noisy odometry and
    scan (with the nominal bearings) to the SLAM filter and returns an observation and
    a reward computed from the resulting belief and the scan only: an exploration or
    active-SLAM policy sees what the robot believes, never the true pose or map. The
    map frame is the world frame: the filter starts at the world's start pose, which only
    fixes the frame (observations are egocentric). The scan and raster are those of the
    lidar frame (at the robot centre in simulation).

    ## Action Space

    The wrapped environment's: ``Box(-1, 1, (2,), float32)``, forward speed and turn
    rate commands. With ``shield=`` a :class:`~vslam_gym.shield.SpeedShield` caps the
    forward speed command by the free corridor ahead in the latest scan before the
    wrapped environment executes it (turns and backward commands pass unchanged); the
    executed action is ``info["executed_action"]``, ``info["shielded"]`` says whether
    it was capped. Every agent on a shielded environment gets the same shield.

    ## Observation Space

    ``Dict`` (fixed shapes, stable-baselines3's ``MultiInputPolicy`` accepts it):

    | Key                | Shape         | dtype   | Content                                 |
    |--------------------|---------------|---------|-----------------------------------------|
    | `scan`             | `(n_beams,)`  | float32 | ranges / max_range in [0, 1] (1: none)   |
    | `pose_uncertainty` | `(7,)`        | float32 | :class:`PoseUncertainty`: log-eigen-     |
    |                    |               |         | values and axis of the position         |
    |                    |               |         | covariance, log heading variance,       |
    |                    |               |         | heading-position correlations (robot    |
    |                    |               |         | frame)                                  |
    | `belief_map`       | `(3, H, W)`   | uint8   | :class:`BeliefRaster`, egocentric,      |
    |                    |               |         | heading up, ``H = W = 64`` cells of     |
    |                    |               |         | 0.25 m; channels `object_lines`,        |
    |                    |               |         | `unknown_lines`, `vertex_uncertainty`   |
    | `status`           | `(2,)`        | float32 | :class:`SlamStatus`: ``log1p`` of the   |
    |                    |               |         | landmark count and of the steps since   |
    |                    |               |         | the last association (steps that the    |
    |                    |               |         | motion filter skips count:              |
    |                    |               |         | ``measurement_min_travel``, ``_turn``)  |
    | `frontier`         | `(4 K,)`      | float32 | optional, :class:`FrontierCue`: the K   |
    |                    |               |         | nearest unknown lines of the map, each  |
    |                    |               |         | as present flag, cos / sin of the       |
    |                    |               |         | bearing to its target point, distance / |
    |                    |               |         | 16 m; only with ``observation=``        |
    |                    |               |         | ``{"frontier_count": K}``, ``K > 0``    |

    ## Rewards

    The sum of named terms (:class:`~vslam_gym.belief_reward.BeliefRewardConfig`),
    each echoed in ``info["rewards"]``; ``S`` is the 3x3 pose covariance:

    | Term               | Formula (weight ``w``)                                     |
    |--------------------|------------------------------------------------------------|
    | `pose_information` | ``w * 0.5 (log det S_prev - log det S)`` (entropy decrease) |
    | `new_boundary`     | ``w * c * (cells newly crossed by object lines)``: a world- |
    |                    | frame grid of side ``c`` (0.25 m), each cell paid once per |
    |                    | episode, so duplicate landmarks earn nothing               |
    | `collision`        | ``-w`` if the robot touched an obstacle this step          |
    | `time`             | ``-w`` per step                                            |
    | `d_opt`            | ``w * tanh(eta / D_opt)``, ``D_opt = exp(mean log eig S)``   |

    Presets (``reward=``): ``"default"`` (pose_information 1, new_boundary 1, collision
    1, time 0.01), ``"d_opt"`` (d_opt 1, collision 100: Placed and Castellanos 2020),
    ``"coverage"`` (new_boundary 1). The wrapped environment's own reward (its
    collision penalty) is replaced; it stays in ``info["env_reward"]``.

    ## Starting State

    ``reset`` resets the wrapped environment (a new world for ``world="random"``) and
    starts a fresh filter, with an empty map, at the world's start pose (this defines
    the map frame). The scan returned by ``reset`` is in the observation and, by
    default (``start_scan="matcher"``), the whole-scan matcher's first keyframe, so the
    first step is aligned to the start pose (no landmark is made from it; the map
    stays empty until the first step). ``"map"`` runs the filter on it as a step
    without motion (landmarks too; one SLAM step more in ``reset``), ``"none"`` ignores
    it (the behaviour before session 33). Measured in docs/measurements.md, "Session
    33": ``"matcher"`` maps the held-out random worlds with a third less position error.

    ## Episode End

    As the wrapped environment (collision termination if configured; truncation by the
    registration's ``max_episode_steps``).

    ## Arguments

    | Argument      | Default     | Meaning                                              |
    |---------------|-------------|------------------------------------------------------|
    | `env`         |             | a ``LidarWorldEnv``, possibly wrapped                 |
    | `slam_config` | `"default"` | preset name, ``SlamConfig.from_dict`` mapping or      |
    |               |             | ``SlamConfig``; odometry alphas come from the world   |
    |               |             | unless a mapping sets ``filter.odometry_alphas``;     |
    |               |             | ``"fast"`` trades accuracy for 2-3x the throughput    |
    | `reward`      | `"default"` | preset name, mapping of weights or config             |
    | `observation` | `None`      | mapping of ``BeliefObservationConfig`` fields         |
    | `start_scan`  | `"matcher"` | the scan of ``reset``: ``"matcher"``, ``"map"`` or    |
    |               |             | ``"none"`` (see Starting State)                      |
    | `shield`      | `None`      | ``None``/``False``: off; ``True``, a mapping of       |
    |               |             | ``ShieldConfig`` fields or a ``ShieldConfig``: cap    |
    |               |             | forward speed by the scan's free corridor             |

    ``info`` adds ``slam_pose`` and ``slam_pose_cov`` (the robot pose belief, world
    frame), ``landmarks``, ``loop_closed`` (the filter fused a revisit match this step,
    ``FilterConfig.loop_closure``), ``rewards``, ``env_reward`` and, with a shield,
    ``executed_action`` and ``shielded`` to the
    wrapped environment's keys, which hold ground truth (``pose``, ``hit_ids``):
    for metrics only, never part of the observation or the reward. The filter's wall
    time per step is ``belief.step_ms`` (``env.get_wrapper_attr("belief")``), not in
    ``info``, which stays deterministic.

    ## Version History

    - v0: initial version (the optional ``frontier`` key and ``shield`` were added
      before the first release, 2026-11-25; ``start_scan`` replaced the boolean
      ``map_reset_scan``, whose ``True`` is ``"map"`` and ``False`` ``"none"``, in
      session 33).
    """

    def __init__(
        self,
        env: gym.Env,
        slam_config: str | SlamConfig | Mapping[str, Any] = "default",
        reward: str | BeliefRewardConfig | Mapping[str, Any] = "default",
        observation: BeliefObservationConfig | Mapping[str, Any] | None = None,
        start_scan: str = "matcher",
        shield: ShieldConfig | Mapping[str, Any] | bool | None = None,
    ) -> None:
        gym.utils.RecordConstructorArgs.__init__(
            self,
            slam_config=slam_config,
            reward=reward,
            observation=observation,
            start_scan=start_scan,
            shield=shield,
        )
        gym.Wrapper.__init__(self, env)
        base = env.unwrapped
        if not isinstance(base, LidarWorldEnv):
            raise TypeError(
                f"SlamWrapper needs a LidarWorldEnv underneath, got {type(base).__name__}"
            )
        self._base: LidarWorldEnv = base
        self.start_scan = check_start_scan(start_scan)
        self._slam_base = _slam_config(slam_config)
        self._own_alphas = sets_odometry_alphas(slam_config)  # else the world's
        self._configs: dict[tuple[float, ...], SlamConfig] = {}  # by the world's alphas
        self.reward_config = BeliefRewardConfig.from_any(reward)
        if observation is None:
            observation = BeliefObservationConfig()
        elif isinstance(observation, Mapping):
            observation = dataclass_from_dict(BeliefObservationConfig, observation, "observation")
        self.observation_config: BeliefObservationConfig = observation
        self.sensor = sensor_from_lidar(base.lidar_spec)
        threshold = self._slam_base.model.unknown_threshold
        self._unknown_threshold = threshold
        self._pose_features = PoseUncertainty(observation)
        self._raster = BeliefRaster(observation, threshold)
        self._status = SlamStatus(observation)
        self._frontier = FrontierCue(observation)
        n_beams = base.lidar_spec.n_beams
        keys = {
            "scan": spaces.Box(0.0, 1.0, shape=(n_beams,), dtype=np.float32),
            "pose_uncertainty": self._pose_features.space(),
            "belief_map": self._raster.space(),
            "status": self._status.space(),
        }
        if self._frontier.size:
            keys["frontier"] = self._frontier.space()
        self.observation_space = spaces.Dict(keys)
        self._reward = BeliefReward(self.reward_config)
        self.shield_config = ShieldConfig.from_any(shield)
        self._shield: SpeedShield | None = None  # built at reset (the robot may change)
        self._scan_m = np.zeros(n_beams, dtype=np.float32)  # the latest scan [m], for the shield
        self._slam: VertexSLAM | None = None
        self._belief: Belief | None = None
        self._segments: dict[str, np.ndarray] = {}  # belief_segments of the latest belief
        self._cells = np.zeros(0, dtype=np.int64)  # their boundary cells (boundary_cells)
        self._mapped: tuple | None = None  # the belief landmarks they were computed from
        self._steps_since_association = 0

    # ------------------------------------------------------------------ API

    @property
    def slam(self) -> VertexSLAM:
        """The running filter (after ``reset``)."""
        if self._slam is None:
            raise ResetNeeded("call reset() first")
        return self._slam

    @property
    def belief(self) -> Belief:
        """The latest belief (after ``reset``)."""
        if self._belief is None:
            raise ResetNeeded("call reset() first")
        return self._belief

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        """Reset the world and start a fresh filter; see the class docstring."""
        obs, info = self.env.reset(seed=seed, options=options)
        base = self._base
        alphas = base._odometry_alphas or tuple(base.world.odometry.alphas)
        config = self._slam_base if self._own_alphas else self._configs.get(alphas)
        if config is None:  # built once per odometry noise (a config takes ~0.3 ms)
            config = self._configs[alphas] = slam_config(self._slam_base, alphas)
        self._slam = VertexSLAM(self.sensor, config, initial_pose=base.world.robot.start)
        self._belief = use_start_scan(self._slam, self.start_scan, obs["scan"], info["bearings"])
        self._steps_since_association = 0
        if self.shield_config is not None:
            robot = base.world.robot
            self._shield = SpeedShield(
                self.shield_config,
                robot.radius,
                self.sensor.max_range,
                info["bearings"],
                robot.max_turn_rate,
                base.physics_config.control_period,
            )
        self._scan_m = obs["scan"]
        self._mapped = None
        self._refresh_segments()
        self._reward.reset(self._belief.pose_cov, self._cells)
        info = self._info(info, {}, 0.0)
        return self._observe(obs), info

    def step(
        self, action: np.ndarray
    ) -> tuple[dict[str, np.ndarray], float, bool, bool, dict[str, Any]]:
        """Step the world, run the filter, observe and reward the belief."""
        if self._slam is None:
            raise ResetNeeded("call reset() before step()")
        shielded = False
        if self._shield is not None:
            action, shielded = self._shield.apply(action, self._scan_m)
        obs, env_reward, terminated, truncated, info = self.env.step(action)
        self._scan_m = obs["scan"]
        self._belief = self._slam.step(obs["odometry"], obs["scan"], info["bearings"])
        if any(d.outcome in ASSOCIATED_OUTCOMES for d in self._belief.decisions):
            self._steps_since_association = 0
        else:
            self._steps_since_association += 1
        self._refresh_segments()
        rewards = self._reward.step(self._belief.pose_cov, self._cells, bool(info["collision"]))
        info = self._info(info, rewards, float(env_reward))
        if self._shield is not None:
            info["executed_action"] = np.asarray(action, dtype=np.float32).copy()
            info["shielded"] = shielded
        return self._observe(obs), float(sum(rewards.values())), terminated, truncated, info

    # ------------------------------------------------------------------ pieces

    def _refresh_segments(self) -> None:
        """``_segments`` and ``_cells``: the latest belief's lines and boundary cells.

        Computed again only when the belief's landmarks changed: the filter keeps one
        ``landmarks`` tuple over the steps that leave the map alone (motion only).
        """
        if self._mapped is not self._belief.landmarks:
            self._segments = belief_segments(self._belief, self._unknown_threshold)
            self._cells = boundary_cells(self._segments, self.reward_config.boundary_cell)
            self._mapped = self._belief.landmarks

    def _observe(self, obs: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        belief = self._belief
        scan = np.clip(obs["scan"] / self.sensor.max_range, 0.0, 1.0).astype(np.float32)
        out = {
            "scan": scan,
            "pose_uncertainty": self._pose_features.observe(belief.pose, belief.pose_cov),
            "belief_map": self._raster.observe(belief, self._segments),
            "status": self._status.observe(len(belief.landmarks), self._steps_since_association),
        }
        if self._frontier.size:
            out["frontier"] = self._frontier.observe(self._segments, belief.pose)
        return out

    def _info(
        self, info: dict[str, Any], rewards: dict[str, float], env_reward: float
    ) -> dict[str, Any]:
        belief = self._belief
        info = dict(info)
        info["slam_pose"] = belief.robot_pose.copy()
        info["slam_pose_cov"] = belief.pose_cov.copy()
        info["landmarks"] = len(belief.landmarks)
        info["loop_closed"] = bool(belief.loop_closed)
        info["rewards"] = rewards
        info["env_reward"] = env_reward
        return info

    # ------------------------------------------------------------------ rendering

    def render(self) -> np.ndarray | None:
        """The wrapped environment's frame with the belief drawn over it.

        Object lines dark blue, unknown lines orange, the estimated pose as a magenta
        triangle with its 3-sigma position ellipse. ``(H, W, 3)`` uint8 for
        ``render_mode="rgb_array"``; drawn in the window for ``"human"``.
        """
        base = self._base
        if base.render_mode is None or self._belief is None:
            return self.env.render()
        import pygame  # lazy: only rendering needs pygame

        from vslam_gym.env import _draw_frame

        canvas = pygame.Surface((base.screen_width, base.screen_height))
        px, scale = _draw_frame(pygame, canvas, base)
        _draw_belief(pygame, canvas, px, scale, self._belief, self._unknown_threshold)
        if base.render_mode == "human":
            if base._screen is None:
                base.render()  # opens the window
            base._screen.blit(canvas, (0, 0))
            pygame.event.pump()
            pygame.display.flip()
            return None
        return np.transpose(np.array(pygame.surfarray.pixels3d(canvas)), (1, 0, 2)).copy()


_BELIEF_COLORS = {
    "object": (20, 40, 160),
    "unknown": (250, 150, 20),
    "pose": (200, 0, 200),
}

ELLIPSE_SIGMA = 3.0
"""The drawn pose ellipse is this many standard deviations."""


def _draw_belief(
    pygame: Any, canvas: Any, px: Any, scale: float, belief: Belief, unknown_threshold: float
) -> None:
    """Draw the belief's lines and pose on ``canvas`` with the world-to-pixel map ``px``."""
    seg = belief_segments(belief, unknown_threshold)
    for a, b, unknown in zip(seg["start"], seg["end"], seg["unknown"], strict=True):
        color = _BELIEF_COLORS["unknown" if unknown else "object"]
        pygame.draw.line(canvas, color, px(*a), px(*b), 1 if unknown else 3)
    x, y, theta = belief.robot_pose
    eigvals, eigvecs = np.linalg.eigh(belief.pose_cov[:2, :2])
    t = np.linspace(0.0, 2.0 * math.pi, 40)
    radii = ELLIPSE_SIGMA * np.sqrt(np.maximum(eigvals, 0.0))
    ring = (eigvecs @ (radii[:, None] * np.stack([np.cos(t), np.sin(t)]))).T + [x, y]
    pygame.draw.lines(canvas, _BELIEF_COLORS["pose"], True, [px(*p) for p in ring], 1)
    size = 0.3
    tip = (x + size * math.cos(theta), y + size * math.sin(theta))
    left = (x + 0.5 * size * math.cos(theta + 2.4), y + 0.5 * size * math.sin(theta + 2.4))
    right = (x + 0.5 * size * math.cos(theta - 2.4), y + 0.5 * size * math.sin(theta - 2.4))
    pygame.draw.polygon(canvas, _BELIEF_COLORS["pose"], [px(*tip), px(*left), px(*right)], 2)
