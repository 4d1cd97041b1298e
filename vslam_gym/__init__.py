"""vslam-gym: 2-D lidar worlds as Gymnasium environments, with a vertex-landmark EKF-SLAM.

Importing the package registers the environments (idempotently). Gymnasium 1.x does not
load entry-point plugins, so write ``import vslam_gym; gym.register_envs(vslam_gym)`` or
``gym.make("vslam_gym:VSlam/LidarWorld-v0")``.
"""

from __future__ import annotations

from gymnasium.envs.registration import register, registry

__version__ = "0.1.0"

LIDAR_WORLD_ID = "VSlam/LidarWorld-v0"
"""Gymnasium id of :class:`vslam_gym.env.LidarWorldEnv`."""


def _register_envs() -> None:
    """Register the environments once (importing the package twice is harmless)."""
    if LIDAR_WORLD_ID not in registry:
        register(
            id=LIDAR_WORLD_ID,
            entry_point="vslam_gym.env:LidarWorldEnv",
            max_episode_steps=1000,
            kwargs={"world": "house"},
        )


_register_envs()
