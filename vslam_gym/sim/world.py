"""World description: the typed, validated content of one world file.

A world is what `envs/*.toml` describes (see the README section "World files"): the
robot's start and limits, the lidar and odometry parameters, static obstacles and an
optional route. Units are metres and radians; the world frame is right-handed, x east,
y north, theta counter-clockwise from x.

This module holds the data types only; `vslam_gym.sim.world_file` parses and validates
TOML files into them and `vslam_gym.sim.random_world` generates them procedurally.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True)
class RobotSpec:
    """The robot: a disc driven by differential-drive commands.

    Attributes:
        start: initial pose ``(x [m], y [m], theta [rad])`` in the world frame.
        radius: body radius [m].
        max_speed: largest forward/backward speed [m/s] (action 1.0 maps to it).
        max_turn_rate: largest turn rate [rad/s] (action 1.0 maps to it).
    """

    start: tuple[float, float, float]
    radius: float = 0.2
    max_speed: float = 1.0
    max_turn_rate: float = 1.5


@dataclass(frozen=True)
class LidarSpec:
    """A planar scanning lidar at the robot centre; defaults are the thesis simulation.

    Attributes:
        fov_deg: full field of view [deg], centred on the robot heading.
        resolution_deg: angle between adjacent beams [deg].
        max_range: largest range [m]; a beam with no return reports exactly this.
        sigma_range: standard deviation of the additive range noise [m].
        sigma_bearing_deg: standard deviation of the bearing noise [deg].
    """

    fov_deg: float = 180.0
    resolution_deg: float = 1.0
    max_range: float = 30.0
    sigma_range: float = 0.03
    sigma_bearing_deg: float = 0.2

    @property
    def n_beams(self) -> int:
        """Number of beams, both FOV limits included (181 for 180 deg at 1 deg)."""
        return int(round(self.fov_deg / self.resolution_deg)) + 1

    @property
    def bearings(self) -> np.ndarray:
        """Nominal beam bearings [rad] in the lidar frame, DEScending (left to right)."""
        half = np.deg2rad(self.fov_deg) / 2.0
        return np.linspace(half, -half, self.n_beams)


@dataclass(frozen=True)
class OdometrySpec:
    """Thrun's odometry motion-model noise (Probabilistic Robotics, table 5.6).

    Attributes:
        alphas: ``(a1, a2, a3, a4)``: a1 rot<-rot, a2 rot<-trans, a3 trans<-trans,
            a4 trans<-rot. Variances are ``a1 rot^2 + a2 trans^2`` for the rotations
            and ``a3 trans^2 + a4 (rot1^2 + rot2^2)`` for the translation.
    """

    alphas: tuple[float, float, float, float] = (0.01, 0.005, 0.005, 0.001)


@dataclass(frozen=True)
class PolygonObstacle:
    """A closed solid simple polygon; ``points`` is an ``(n, 2)`` tuple of vertices [m]."""

    points: tuple[tuple[float, float], ...]
    kind: str = field(default="polygon", init=False)


@dataclass(frozen=True)
class CircleObstacle:
    """A solid disc with ``center`` [m] and ``radius`` [m]."""

    center: tuple[float, float]
    radius: float
    kind: str = field(default="circle", init=False)


@dataclass(frozen=True)
class WallObstacle:
    """An open polyline of ``points`` [m] with a ``thickness`` [m] (walls, partitions)."""

    points: tuple[tuple[float, float], ...]
    thickness: float = 0.1
    kind: str = field(default="wall", init=False)


Obstacle = PolygonObstacle | CircleObstacle | WallObstacle


@dataclass(frozen=True)
class Route:
    """Waypoints ``(x, y)`` [m] for scripted rollouts; ``loop`` returns to the first."""

    waypoints: tuple[tuple[float, float], ...]
    loop: bool = False


@dataclass(frozen=True)
class World:
    """One world. Obstacle ids are their indices in ``obstacles`` (file order)."""

    name: str
    robot: RobotSpec
    lidar: LidarSpec = field(default_factory=LidarSpec)
    odometry: OdometrySpec = field(default_factory=OdometrySpec)
    obstacles: tuple[Obstacle, ...] = ()
    route: Route | None = None
    description: str = ""
