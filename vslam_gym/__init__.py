"""vslam-gym: 2-D lidar worlds as Gymnasium environments, with a vertex-landmark EKF-SLAM.

Importing the package registers the environments (idempotently). Gymnasium 1.x does not
load entry-point plugins, so write ``import vslam_gym; gym.register_envs(vslam_gym)`` or
``gym.make("vslam_gym:VSlam/LidarWorld-v0")``.

Registered ids:

- ``VSlam/LidarWorld-v0``: :class:`vslam_gym.env.LidarWorldEnv`, ground-truth simulator
  (observations: scan and odometry).
- ``VSlam/Explore-v0``: a new random world per reset, wrapped in
  :class:`vslam_gym.slam_wrapper.SlamWrapper` (belief observations and rewards).
- ``VSlam/ExploreSingleLandmark-v0``, ``VSlam/ExploreSmall-v0``,
  ``VSlam/ExploreCurved-v0``, ``VSlam/ExploreHouse-v0``: the shipped worlds, wrapped.
"""

from __future__ import annotations

import dataclasses
from typing import Any

from gymnasium.envs.registration import EnvSpec, WrapperSpec, register, registry

from vslam_gym.config_utils import check_keys

__version__ = "0.1.0"

LIDAR_WORLD_ID = "VSlam/LidarWorld-v0"
"""Gymnasium id of :class:`vslam_gym.env.LidarWorldEnv`."""
EXPLORE_ID = "VSlam/Explore-v0"
"""Gymnasium id of the SLAM-wrapped environment on random worlds (new world per reset)."""
EXPLORE_WORLD_IDS = {
    "single_landmark": "VSlam/ExploreSingleLandmark-v0",
    "small": "VSlam/ExploreSmall-v0",
    "curved": "VSlam/ExploreCurved-v0",
    "house": "VSlam/ExploreHouse-v0",
}
"""Gymnasium ids of the SLAM-wrapped environment on each shipped world."""
EXPLORE_MAX_STEPS = {
    "random": 500,
    "single_landmark": 500,
    "small": 500,
    "curved": 800,
    "house": 1000,
}
"""``max_episode_steps`` of the exploration ids (0.1 s per step)."""

SLAM_WRAPPER_SPEC = WrapperSpec(
    name="SlamWrapper",
    entry_point="vslam_gym.slam_wrapper:SlamWrapper",
    kwargs={
        "slam_config": "default",
        "reward": "default",
        "observation": None,
        "start_scan": "matcher",
        "shield": None,
    },
)
"""The wrapper every exploration id applies (so ``Monitor`` records the belief reward)."""


def _register_envs() -> None:
    """Register the environments once (importing the package twice is harmless)."""
    if LIDAR_WORLD_ID not in registry:
        register(
            id=LIDAR_WORLD_ID,
            entry_point="vslam_gym.env:LidarWorldEnv",
            max_episode_steps=1000,
            kwargs={"world": "house"},
        )
    worlds = {env_id: world for world, env_id in EXPLORE_WORLD_IDS.items()}
    worlds[EXPLORE_ID] = "random"
    for env_id, world in worlds.items():
        if env_id not in registry:
            register(
                id=env_id,
                entry_point="vslam_gym.env:LidarWorldEnv",
                max_episode_steps=EXPLORE_MAX_STEPS[world],
                kwargs={"world": world, "terminate_on_collision": True},
                additional_wrappers=(SLAM_WRAPPER_SPEC,),
            )


def explore_spec(env_id: str = EXPLORE_ID, **wrapper_kwargs: Any) -> EnvSpec:
    """The spec of an exploration id with other :class:`SlamWrapper` arguments.

    ``gym.make(explore_spec(reward="d_opt"))`` is ``VSlam/Explore-v0`` with the
    ``d_opt`` reward; environment arguments still go to ``gym.make``, e.g.
    ``gym.make(explore_spec("VSlam/ExploreHouse-v0", reward="coverage"), render_mode="rgb_array")``.

    Args:
        env_id: a registered exploration id.
        **wrapper_kwargs: ``slam_config``, ``reward``, ``observation``,
            ``start_scan``, ``shield`` (JSON-able values: preset names, mappings or
            booleans).

    Raises:
        ValueError: ``env_id`` is not an exploration id, or an unknown wrapper argument.
    """
    spec = registry.get(env_id)
    if spec is None or SLAM_WRAPPER_SPEC not in spec.additional_wrappers:
        raise ValueError(f"{env_id!r} is not an exploration id: {sorted(_explore_ids())}")
    check_keys(wrapper_kwargs, SLAM_WRAPPER_SPEC.kwargs, "explore_spec")
    wrapper = dataclasses.replace(
        SLAM_WRAPPER_SPEC, kwargs={**SLAM_WRAPPER_SPEC.kwargs, **wrapper_kwargs}
    )
    return dataclasses.replace(spec, additional_wrappers=(wrapper,))


def _explore_ids() -> list[str]:
    return [EXPLORE_ID, *EXPLORE_WORLD_IDS.values()]


def __getattr__(name: str):  # lazy: importing the package stays light
    if name == "SlamWrapper":
        from vslam_gym.slam_wrapper import SlamWrapper

        return SlamWrapper
    raise AttributeError(f"module 'vslam_gym' has no attribute {name!r}")


_register_envs()
