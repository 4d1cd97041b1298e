"""Thrun's odometry motion model: increments between poses, noise, integration.

Probabilistic Robotics (Thrun, Burgard, Fox 2005), section 5.4, tables 5.5 and 5.6.
The motion between two poses ``(x, y, theta)`` [m, m, rad] in the world frame is
described by three increments ``(rot1, trans, rot2)``: turn by ``rot1``, drive ``trans``
straight ahead, turn by ``rot2``.

Two departures from the textbook, both for a differential-drive robot that may reverse:

- **Near-zero translation.** When the translation is below
  :attr:`OdometryModel.min_translation`, the direction of travel is undefined (a turn on
  the spot, or numerical jitter of the physics); then ``rot1 = 0`` and the whole heading
  change goes into ``rot2``.
- **Backward motion.** When the direction of travel points backwards (``|rot1| > pi/2``
  in the textbook decomposition), ``trans`` is reported NEGATIVE and ``rot1`` is turned by
  ``pi``, so ``rot1`` stays in ``[-pi/2, pi/2]``. The textbook form would report
  ``rot1 ~ +-pi`` and ``rot2 ~ -+pi`` for a short reverse, and its rotation noise
  (``a1 rot1^2``) would then be absurdly large. :func:`integrate_increments` accepts both
  forms: ``x' = x + trans cos(theta + rot1)`` gives the same position either way.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from vslam_gym.sim.world import OdometrySpec


def wrap_angle(angle: float | np.ndarray) -> float | np.ndarray:
    """Wrap an angle [rad] (scalar or array) into ``[-pi, pi)``."""
    if isinstance(angle, np.ndarray):
        return (angle + np.pi) % (2.0 * np.pi) - np.pi
    return (float(angle) + math.pi) % (2.0 * math.pi) - math.pi


def _floats(values: np.ndarray | tuple[float, float, float], name: str) -> tuple[float, ...]:
    """Three finite floats from a pose or increments; else a ValueError naming ``name``."""
    try:
        a, b, c = (float(v) for v in values)
    except (TypeError, ValueError) as err:
        raise ValueError(f"{name} must have shape (3,), got {values!r}") from err
    if not (math.isfinite(a) and math.isfinite(b) and math.isfinite(c)):
        raise ValueError(f"{name} must be finite, got {values!r}")
    return a, b, c


@dataclass(frozen=True)
class OdometryModel:
    """Thrun's odometry-model noise with the robot-specific thresholds.

    Attributes:
        alphas: ``(a1, a2, a3, a4)`` [-]: a1 rot<-rot, a2 rot<-trans, a3 trans<-trans,
            a4 trans<-rot. The noise VARIANCES are ``a1 rot1^2 + a2 trans^2`` for rot1,
            ``a3 trans^2 + a4 (rot1^2 + rot2^2)`` for trans and ``a1 rot2^2 + a2 trans^2``
            for rot2 (rotations in rad, translation in m).
        min_translation: translation [m] below which the direction of travel is treated as
            undefined (``rot1 = 0``, see the module docstring).
    """

    alphas: tuple[float, float, float, float] = OdometrySpec().alphas
    min_translation: float = 1e-6

    def __post_init__(self) -> None:
        alphas = tuple(float(a) for a in self.alphas)
        if len(alphas) != 4 or not all(math.isfinite(a) and a >= 0.0 for a in alphas):
            raise ValueError(
                f"odometry alphas must be four finite non-negative numbers, got {self.alphas}"
            )
        if not (math.isfinite(self.min_translation) and self.min_translation >= 0.0):
            raise ValueError(
                f"min_translation must be finite and >= 0 m, got {self.min_translation}"
            )
        object.__setattr__(self, "alphas", alphas)

    @classmethod
    def from_spec(cls, spec: OdometrySpec) -> OdometryModel:
        """Build the model from a world's :class:`OdometrySpec`."""
        return cls(alphas=tuple(spec.alphas))

    def increments(
        self,
        pose_from: np.ndarray | tuple[float, float, float],
        pose_to: np.ndarray | tuple[float, float, float],
    ) -> np.ndarray:
        """Exact increments ``(rot1 [rad], trans [m], rot2 [rad])`` from one pose to the next.

        Args:
            pose_from: pose ``(x, y, theta)`` at the start of the motion, world frame.
            pose_to: pose at the end of the motion, world frame.

        Returns:
            ``(3,)`` array; ``trans < 0`` for backward motion, rotations wrapped into
            ``[-pi, pi)``.
        """
        x0, y0, theta0 = _floats(pose_from, "pose_from")
        x1, y1, theta1 = _floats(pose_to, "pose_to")
        dx, dy = x1 - x0, y1 - y0
        trans = math.hypot(dx, dy)
        if trans < self.min_translation:
            rot1 = 0.0
        else:
            rot1 = wrap_angle(math.atan2(dy, dx) - theta0)
            if abs(rot1) > math.pi / 2.0:  # driving backwards
                rot1 = wrap_angle(rot1 + math.pi)
                trans = -trans
        rot2 = wrap_angle(theta1 - theta0 - rot1)
        return np.array([rot1, trans, rot2])

    def standard_deviations(self, increments: np.ndarray) -> np.ndarray:
        """Noise standard deviations ``(3,)`` [rad, m, rad] for the given increments."""
        return np.array(self._standard_deviations(*_floats(increments, "increments")))

    def _standard_deviations(
        self, rot1: float, trans: float, rot2: float
    ) -> tuple[float, float, float]:
        a1, a2, a3, a4 = self.alphas
        return (
            math.sqrt(a1 * rot1 * rot1 + a2 * trans * trans),
            math.sqrt(a3 * trans * trans + a4 * (rot1 * rot1 + rot2 * rot2)),
            math.sqrt(a1 * rot2 * rot2 + a2 * trans * trans),
        )

    def sample(self, increments: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """Noisy increments: each true increment plus zero-mean Gaussian noise.

        Always draws exactly three standard normals from ``rng`` (also when the noise is
        zero), so the random stream does not depend on the motion.

        Args:
            increments: true ``(rot1, trans, rot2)`` [rad, m, rad].
            rng: the one random generator of the simulation.

        Returns:
            ``(3,)`` noisy increments; the rotations are wrapped into ``[-pi, pi)``.
        """
        rot1, trans, rot2 = _floats(increments, "increments")
        s1, s2, s3 = self._standard_deviations(rot1, trans, rot2)
        e1, e2, e3 = rng.standard_normal(3)
        return np.array([wrap_angle(rot1 + s1 * e1), trans + s2 * e2, wrap_angle(rot2 + s3 * e3)])


def integrate_increments(
    pose: np.ndarray | tuple[float, float, float], increments: np.ndarray
) -> np.ndarray:
    """Apply increments ``(rot1, trans, rot2)`` to a pose; the inverse of ``increments``.

    ``x' = x + trans cos(theta + rot1)``, ``y' = y + trans sin(theta + rot1)``,
    ``theta' = theta + rot1 + rot2`` (wrapped into ``[-pi, pi)``). Works for negative
    ``trans`` (backward motion).
    """
    x, y, theta = _floats(pose, "pose")
    rot1, trans, rot2 = _floats(increments, "increments")
    heading = theta + rot1
    return np.array(
        [
            x + trans * math.cos(heading),
            y + trans * math.sin(heading),
            wrap_angle(heading + rot2),
        ]
    )
