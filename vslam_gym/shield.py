"""A speed shield: limit forward speed commands by the free space the scan shows.

The robot is a disc, so turning on the spot never collides; driving forward does when an
obstacle lies in the corridor the body sweeps. :class:`SpeedShield` caps the forward
speed command by the free length of that corridor in the latest scan, the way a
"shield" sits under a learned policy in safe reinforcement learning: the policy keeps its
action space, and the environment executes the shielded action. It uses the scan and
the robot's and lidar's specifications only (no map, no true pose), so a shielded
policy stays a belief-only policy. Every agent evaluated on a shielded environment gets
the same shield (the random baseline included).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from vslam_gym.config_utils import check_field_types, dataclass_from_dict

__all__ = ["ShieldConfig", "SpeedShield", "corridor_free_length"]


def corridor_free_length(
    points: np.ndarray, directions: np.ndarray, half_width: float, max_range: float
) -> np.ndarray:
    """Distance [m] a disc can drive straight along each direction before touching a point.

    Args:
        points: ``(n, 2)`` obstacle points [m], robot frame (x forward, y left).
        directions: ``(k,)`` driving directions [rad], robot frame.
        half_width: half the corridor's width [m] (the robot radius plus a margin).
        max_range: the length [m] returned when no point is in a corridor.

    Returns:
        ``(k,)`` free lengths [m], at least 0: how far the corridor's centre line can
        advance until a point lies within ``half_width`` of it (the robot's front arc).
    """
    directions = np.asarray(directions, dtype=float)
    if len(points) == 0:
        return np.full(directions.shape, float(max_range))
    u = np.stack([np.cos(directions), np.sin(directions)], axis=1)
    along = points @ u.T
    lateral = points @ np.stack([-u[:, 1], u[:, 0]], axis=1).T
    inside = (np.abs(lateral) < half_width) & (along > 0.0)
    reach = along - np.sqrt(np.maximum(half_width**2 - lateral**2, 0.0))
    reach = np.where(inside, reach, max_range)
    return np.maximum(np.min(reach, axis=0), 0.0)


@dataclasses.dataclass(frozen=True)
class ShieldConfig:
    """Settings of :class:`SpeedShield`.

    Attributes:
        margin: clearance [m] kept beyond the robot radius on each side of the swept
            corridor.
        stop_distance: free length ahead [m] at or below which forward commands become 0.
        slow_distance: free length ahead [m] from which full speed is allowed; between
            the two the allowed speed command rises linearly from 0 to 1. With the
            default robot (1 m/s, 0.1 s steps) the robot covers at most 0.1 m per step.
        no_return: range, as a fraction of the lidar's maximum range, at or above which a
            beam counts as no return.
    """

    margin: float = 0.05
    stop_distance: float = 0.1
    slow_distance: float = 0.5
    no_return: float = 0.999

    def __post_init__(self) -> None:
        check_field_types(self)
        for name in ("margin", "stop_distance", "no_return"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0.0):
                raise ValueError(f"ShieldConfig.{name} must be finite and >= 0, got {value}")
        if not (math.isfinite(self.slow_distance) and self.slow_distance > self.stop_distance):
            raise ValueError(
                f"ShieldConfig.slow_distance ({self.slow_distance}) must be finite and "
                f"exceed stop_distance ({self.stop_distance})"
            )
        if self.no_return > 1.0:
            raise ValueError(f"ShieldConfig.no_return must be <= 1, got {self.no_return}")

    @classmethod
    def from_any(cls, value: ShieldConfig | Mapping[str, Any] | bool | None) -> ShieldConfig | None:
        """None / False: no shield; True: the defaults; a mapping of fields; a config."""
        if value is None or value is False:
            return None
        if value is True:
            return cls()
        if isinstance(value, cls):
            return value
        if isinstance(value, Mapping):
            return dataclass_from_dict(cls, value, "shield")
        raise TypeError(
            f"shield must be None, a bool, a mapping or a ShieldConfig, got {type(value).__name__}"
        )


class SpeedShield:
    """Cap the forward speed command by the scan's free corridor (robot frame).

    The corridor is ``robot_radius + margin`` wide on each side, along the current
    heading and along the heading at the end of the step (``turn * max_turn_rate *
    control_period``); its free length ``f`` (the shorter) allows a forward command of
    at most ``clip((f - stop_distance) / (slow_distance - stop_distance), 0, 1)``. Turn
    commands and backward commands pass unchanged: the lidar sees only its field of
    view, so the shield cannot judge backward motion.

    Args:
        config: distances and margin.
        robot_radius: the robot's radius [m].
        max_range: the lidar's maximum range [m].
        bearings: ``(n,)`` nominal beam bearings [rad], robot frame.
        max_turn_rate: the turn rate [rad/s] of a turn command of 1.
        control_period: the step duration [s].
    """

    def __init__(
        self,
        config: ShieldConfig,
        robot_radius: float,
        max_range: float,
        bearings: np.ndarray,
        max_turn_rate: float,
        control_period: float,
    ) -> None:
        self.config = config
        self.half_width = float(robot_radius) + config.margin
        self.max_range = float(max_range)
        bearings = np.asarray(bearings, dtype=float)
        self._unit = np.stack([np.cos(bearings), np.sin(bearings)], axis=1)
        self.turn_per_step = float(max_turn_rate) * float(control_period)

    def allowed_speed(self, scan: np.ndarray, turn: float) -> float:
        """Largest forward speed command in ``[0, 1]`` for ``scan`` [m] and a turn command.

        Raises:
            ValueError: ``scan`` does not have one range per bearing.
        """
        scan = np.asarray(scan, dtype=float)
        if scan.shape != (len(self._unit),):
            raise ValueError(f"scan must have shape ({len(self._unit)},), got {scan.shape}")
        c = self.config
        hit = scan < c.no_return * self.max_range
        points = scan[hit, None] * self._unit[hit]
        directions = np.array([0.0, float(np.clip(turn, -1.0, 1.0)) * self.turn_per_step])
        free = corridor_free_length(points, directions, self.half_width, self.max_range)
        free = float(free.min())
        return float(np.clip((free - c.stop_distance) / (c.slow_distance - c.stop_distance), 0, 1))

    def apply(self, action: np.ndarray, scan: np.ndarray) -> tuple[np.ndarray, bool]:
        """``(executed action, changed)`` for a ``(speed, turn)`` command and ``scan`` [m].

        The action is returned as float32; ``changed`` is True when the speed was capped.
        A malformed action passes unchanged (the environment rejects it with its own
        error).
        """
        act = np.asarray(action, dtype=np.float32)
        if act.shape != (2,) or not np.all(np.isfinite(act)):
            return act, False
        speed, turn = float(act[0]), float(act[1])
        if speed <= 0.0:
            return act, False
        allowed = self.allowed_speed(scan, turn)
        if speed <= allowed:
            return act, False
        return np.array([allowed, turn], dtype=np.float32), True
