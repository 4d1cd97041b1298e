"""Motion update with the odometry motion model (SPEC section 10; thesis 4.2.1-4.2.13).

Odometry increments ``u = [d_theta0, d, d_theta1]`` (rotation [rad], translation [m],
rotation [rad]) move the pose ``x = [x, y, theta]`` (world frame):
``x_t = x + [d cos(theta + d_theta0), d sin(theta + d_theta0), d_theta0 + d_theta1]``.
The noise is Thrun's odometry model with coefficients ``alphas = (a1, a2, a3, a4)``.
Only the pose rows and columns of the state covariance change; they are updated in
place on a copy, never through dense ``(3 + 2L)^2`` products.
"""

from __future__ import annotations

import numpy as np

from vslam_gym.slam.geometry import wrap_angle

MAX_INCREMENT_ROTATION = 2.0 * np.pi
"""Largest ``|rot1|``, ``|rot2|`` [rad] of one step's odometry (:func:`check_increments`)."""


def check_increments(u: np.ndarray, max_translation: float = np.inf) -> np.ndarray:
    """``u`` as a finite ``(3,)`` float array, or a ``ValueError`` naming the problem.

    Besides shape and finiteness, a rotation beyond a full turn
    (:data:`MAX_INCREMENT_ROTATION`) or a translation beyond ``max_translation`` [m] (the
    filter passes its lidar's range: no scan can follow such a jump) is refused: such
    increments come from wrong units or a corrupt log, and their noise would overflow
    the covariance.
    """
    try:
        arr = np.asarray(u, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"odometry increments must be 3 numbers, got {u!r}") from exc
    if arr.shape != (3,):
        raise ValueError(
            f"odometry increments must have shape (3,) [rot1, trans, rot2], got {arr.shape}"
        )
    if not np.isfinite(arr).all():
        raise ValueError(f"odometry increments must be finite, got {arr}")
    if max(abs(arr[0]), abs(arr[2])) > MAX_INCREMENT_ROTATION:
        raise ValueError(
            f"odometry rotations rot1, rot2 must be at most 2 pi in magnitude, got {arr}"
        )
    if abs(arr[1]) > max_translation:
        raise ValueError(
            f"odometry translation must be at most {max_translation} m (the lidar's range) "
            f"in one step, got {arr[1]}"
        )
    return arr


def odometry_noise(
    u: np.ndarray, alphas: tuple[float, float, float, float], floor: np.ndarray
) -> np.ndarray:
    """Covariance ``Sigma_n`` ``(3, 3)`` of the increments (Thrun's odometry model).

    ``var(rot1) = a1 rot1^2 + a2 trans^2``, ``var(trans) = a3 trans^2 + a4 (rot1^2 + rot2^2)``,
    ``var(rot2) = a1 rot2^2 + a2 trans^2``, each at least ``floor**2`` (``(3,)``: [rad],
    [m], [rad]) so that a standing robot keeps a proper covariance.
    """
    a1, a2, a3, a4 = alphas
    rot1, trans, rot2 = u
    var = np.array(
        [
            a1 * rot1**2 + a2 * trans**2,
            a3 * trans**2 + a4 * (rot1**2 + rot2**2),
            a1 * rot2**2 + a2 * trans**2,
        ]
    )
    return np.diag(np.maximum(var, np.asarray(floor, dtype=float) ** 2))


def predict_pose(x: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Pose after the increments ``u`` (4.2.1); heading wrapped to ``[-pi, pi)``."""
    rot1, trans, rot2 = u
    a = x[2] + rot1
    return np.array(
        [x[0] + trans * np.cos(a), x[1] + trans * np.sin(a), wrap_angle(x[2] + rot1 + rot2)]
    )


def motion_jacobians(x: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Jacobians ``G = d x_t / d x`` and ``H = d x_t / d u``, both ``(3, 3)``."""
    rot1, trans, _ = u
    a = x[2] + rot1
    c, s = np.cos(a), np.sin(a)
    g = np.array([[1.0, 0.0, -trans * s], [0.0, 1.0, trans * c], [0.0, 0.0, 1.0]])
    h = np.array([[-trans * s, c, 0.0], [trans * c, s, 0.0], [1.0, 0.0, 1.0]])
    return g, h


def motion_update(
    mu: np.ndarray, sigma: np.ndarray, u: np.ndarray, sigma_n: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """EKF prediction of the full state; the pose is its first three entries.

    ``Sigma'_xx = G Sigma_xx G^T + H Sigma_n H^T``, ``Sigma'_xm = G Sigma_xm``; the
    landmark block is untouched.

    Returns:
        New ``(mu, Sigma)`` (copies).
    """
    g, h = motion_jacobians(mu[:3], u)
    return _propagate(mu, sigma, predict_pose(mu[:3], u), g, h @ sigma_n @ h.T)


def relative_motion_update(
    mu: np.ndarray, sigma: np.ndarray, delta: np.ndarray, delta_cov: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """EKF prediction with a relative pose ``delta = [dx, dy, dtheta]`` (previous frame).

    ``x_t = x (+) delta`` with ``delta ~ N(delta, delta_cov)`` (e.g. from scan matching);
    the same block update as :func:`motion_update`.

    Returns:
        New ``(mu, Sigma)`` (copies).
    """
    c, s = np.cos(mu[2]), np.sin(mu[2])
    dx, dy = delta[0], delta[1]
    g = np.array([[1.0, 0.0, -s * dx - c * dy], [0.0, 1.0, c * dx - s * dy], [0.0, 0.0, 1.0]])
    v = frame_rotation(mu[2])
    return _propagate(mu, sigma, compose(mu[:3], delta), g, v @ delta_cov @ v.T)


def frame_rotation(theta: float) -> np.ndarray:
    """``(3, 3)``: rotates the position part of a pose difference by ``theta`` [rad].

    Maps a relative pose's covariance from a frame at heading ``theta`` to the world:
    ``R C R^T``; its transpose maps back.
    """
    c, s = np.cos(theta), np.sin(theta)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def increment_to_relative(u: np.ndarray, sigma_n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Increments ``[rot1, trans, rot2]`` (covariance ``sigma_n``) as a relative pose.

    Returns:
        ``[dx, dy, dtheta]`` in the previous pose's frame and its first-order covariance.
    """
    _, h = motion_jacobians(np.zeros(3), u)
    return predict_pose(np.zeros(3), u), h @ sigma_n @ h.T


def _propagate(
    mu: np.ndarray, sigma: np.ndarray, pose: np.ndarray, g: np.ndarray, noise: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """New pose mean; ``Sigma'_xx = G Sigma_xx G^T + noise``, ``Sigma'_xm = G Sigma_xm``."""
    mu_new = mu.copy()
    mu_new[:3] = pose
    out = sigma.copy()
    out[:3, 3:] = g @ sigma[:3, 3:]
    out[3:, :3] = out[:3, 3:].T
    out[:3, :3] = g @ sigma[:3, :3] @ g.T + noise
    out[:3, :3] = 0.5 * (out[:3, :3] + out[:3, :3].T)
    return mu_new, out


def compose(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Pose composition ``a (+) b``: ``b`` expressed in ``a``'s frame, mapped to the world."""
    c, s = np.cos(a[2]), np.sin(a[2])
    return np.array(
        [a[0] + c * b[0] - s * b[1], a[1] + s * b[0] + c * b[1], wrap_angle(a[2] + b[2])]
    )


def inverse(a: np.ndarray) -> np.ndarray:
    """Pose inverse ``(-) a``."""
    c, s = np.cos(a[2]), np.sin(a[2])
    return np.array([-c * a[0] - s * a[1], s * a[0] - c * a[1], wrap_angle(-a[2])])


def increments_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Odometry increments ``[rot1, trans, rot2]`` taking pose ``a`` to pose ``b``."""
    dx, dy = b[0] - a[0], b[1] - a[1]
    trans = float(np.hypot(dx, dy))
    rot1 = float(wrap_angle(np.arctan2(dy, dx) - a[2])) if trans > 0 else 0.0
    return np.array([rot1, trans, float(wrap_angle(b[2] - a[2] - rot1))])
