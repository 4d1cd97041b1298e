"""Rewards computed from the SLAM belief alone (for :class:`vslam_gym.SlamWrapper`).

Each reward is a weighted sum of named terms; :class:`BeliefRewardConfig` holds the
weights, with the presets ``default``, ``d_opt`` and ``coverage``
(:meth:`BeliefRewardConfig.preset`). A term with weight 0 is not computed and not
reported.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from vslam_gym.config_utils import check_field_types, dataclass_from_dict

REWARD_PRESETS = ("default", "d_opt", "coverage")
"""Names accepted by :meth:`BeliefRewardConfig.preset`."""


@dataclass(frozen=True)
class BeliefRewardConfig:
    """Weights of the belief reward terms.

    Attributes:
        pose_information: weight of ``pose_information``, the decrease of the pose
            entropy over the step, ``0.5 (log det S_prev - log det S)`` [nat], ``S`` the
            3x3 pose covariance (x [m], y [m], theta [rad]).
        new_boundary: weight of ``new_boundary`` [per m], the object boundary modelled
            for the first time in the episode: the number of cells of a world-frame grid
            (side ``boundary_cell``) that an object line passes through for the first
            time, times the cell side (about the length of newly modelled boundary; up to
            1.4 times it for a diagonal line). A duplicate landmark of a boundary that is
            already modelled earns nothing (in earlier versions the growth of the total
            object-line length paid for every duplicate again: a PPO policy earned 200
            in 20 steps from spurious landmarks).
        collision: penalty of ``collision`` for a step in which the robot touched an
            obstacle (the robot feels its bumper; that is not map ground truth).
        time: cost of ``time`` per step.
        d_opt: weight of ``d_opt``, ``tanh(d_opt_eta / D_opt)`` with
            ``D_opt = exp(mean(log eig(S)))`` (Placed and Castellanos, 2020).
        d_opt_eta: the scale ``eta`` of the ``d_opt`` term.
        boundary_cell: grid cell side [m] of ``new_boundary``.
    """

    pose_information: float = 1.0
    new_boundary: float = 1.0
    collision: float = 1.0
    time: float = 0.01
    d_opt: float = 0.0
    d_opt_eta: float = 0.01
    boundary_cell: float = 0.25

    def __post_init__(self) -> None:
        check_field_types(self)
        for field in dataclasses.fields(self):
            value = getattr(self, field.name)
            if not np.isfinite(value):
                raise ValueError(f"BeliefRewardConfig.{field.name} must be finite, got {value!r}")
        for name in ("collision", "time", "d_opt_eta"):
            if getattr(self, name) < 0:
                raise ValueError(f"BeliefRewardConfig.{name} must be >= 0")
        if self.boundary_cell <= 0:
            raise ValueError(
                f"BeliefRewardConfig.boundary_cell must be > 0 [m], got {self.boundary_cell!r}"
            )

    @classmethod
    def preset(cls, name: str) -> BeliefRewardConfig:
        """A named preset.

        - ``default``: pose information + new boundary length - collision - time.
        - ``d_opt``: ``tanh(0.01 / D_opt)`` per step and -100 on collision (Placed and
          Castellanos 2020).
        - ``coverage``: new boundary length only.
        """
        presets = {
            "default": cls(),
            "d_opt": cls(
                pose_information=0.0, new_boundary=0.0, collision=100.0, time=0.0, d_opt=1.0
            ),
            "coverage": cls(pose_information=0.0, new_boundary=1.0, collision=0.0, time=0.0),
        }
        if name not in presets:
            raise ValueError(f"unknown reward preset {name!r}; choose one of {REWARD_PRESETS}")
        return presets[name]

    @classmethod
    def from_any(cls, reward: str | BeliefRewardConfig | Mapping[str, Any]) -> BeliefRewardConfig:
        """A preset name, a config, or a mapping of weights (unknown keys raise)."""
        if isinstance(reward, BeliefRewardConfig):
            return reward
        if isinstance(reward, str):
            return cls.preset(reward)
        if isinstance(reward, Mapping):
            return dataclass_from_dict(cls, reward, "reward")
        raise TypeError(
            f"reward must be a preset name, a mapping or a BeliefRewardConfig, "
            f"got {type(reward).__name__}"
        )


def pose_entropy(pose_cov: np.ndarray) -> float:
    """Differential entropy [nat] of a 3-D Gaussian with covariance ``pose_cov``."""
    sign, logdet = np.linalg.slogdet(pose_cov)
    if sign <= 0:
        raise ValueError("pose covariance is not positive definite")
    return float(0.5 * logdet + 1.5 * (1.0 + np.log(2.0 * np.pi)))


def d_optimality(pose_cov: np.ndarray) -> float:
    """``D_opt = exp(mean(log eig(pose_cov)))``, the geometric mean of the eigenvalues."""
    eig = np.linalg.eigvalsh(0.5 * (pose_cov + pose_cov.T))
    return float(np.exp(np.mean(np.log(np.maximum(eig, np.finfo(float).tiny)))))


class BeliefReward:
    """Stateful reward over one episode: call :meth:`reset` then :meth:`step`.

    Args:
        config: the term weights.
    """

    def __init__(self, config: BeliefRewardConfig) -> None:
        self.config = config
        self._entropy = 0.0
        self._cells = np.zeros(0, dtype=np.int64)

    def reset(self, pose_cov: np.ndarray, boundary_cells: np.ndarray) -> None:
        """Start an episode from the belief after ``reset``.

        ``boundary_cells``: the belief's object-line cells at ``config.boundary_cell``
        (:func:`vslam_gym.belief_observation.boundary_cells`).
        """
        self._entropy = pose_entropy(pose_cov)
        self._cells = np.asarray(boundary_cells, dtype=np.int64)

    def step(
        self, pose_cov: np.ndarray, boundary_cells: np.ndarray, collision: bool
    ) -> dict[str, float]:
        """Named, weighted reward terms of one step (their sum is the reward)."""
        c = self.config
        terms: dict[str, float] = {}
        entropy = pose_entropy(pose_cov)
        if c.pose_information:
            terms["pose_information"] = c.pose_information * (self._entropy - entropy)
        self._entropy = entropy
        new = np.setdiff1d(boundary_cells, self._cells, assume_unique=True)
        if c.new_boundary:
            terms["new_boundary"] = c.new_boundary * c.boundary_cell * new.size
        if new.size:
            self._cells = np.union1d(self._cells, new)
        if c.collision:
            terms["collision"] = -c.collision if collision else 0.0
        if c.time:
            terms["time"] = -c.time
        if c.d_opt:
            terms["d_opt"] = c.d_opt * float(np.tanh(c.d_opt_eta / d_optimality(pose_cov)))
        return terms
