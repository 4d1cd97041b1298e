"""The covariance of the filter's estimation error (``FilterConfig.error_noise_scale``).

The filter's own covariance ``Sigma`` ends up far smaller than its errors once landmarks
update the pose (session 29: the scan-matched motion alone is consistent, the landmark
updates are not). Their innovations are not the problem: whitened, they are within
their predicted spread and nearly uncorrelated from one update of a landmark to the
next (docs/measurements.md, "Session 30"). What the linearised updates inform
spuriously is what no update observes, the map's global position and heading, and no
single noise term of the filter's model is wrong by the needed factor. This module
keeps, beside ``Sigma`` (which the filter's gains and gates go on using), the covariance
``P`` of its estimation error: the same linear(ised) updates with the filter's own
gains, in Joseph form, with the noise of every landmark factor (update and creation)
multiplied by an empirical scale ``c`` (``FilterConfig.error_noise_scale``, measured:
10 brings the mean pose NEES of the routes from 8-132 to 2-22).

For a gain ``K`` and a measurement ``y = H s + n`` with noise ``R``,
``P' = (I - K H) P (I - K H)^T + c K R K^T``; with ``P = Sigma`` and ``c = 1`` this is the
filter's own update (tested). The motion updates (affine in the covariance: the
filter's own functions apply) and the revisit matches enter with their own noise. The
estimates never depend on ``P``: the means, gains and gates are the filter's, only what
the belief reports changes.

A landmark factor ``C(Lambda, eta)`` on the pose and reference ``s`` (``v`` marginalised;
``state_space_update(..., with_factor=True)`` returns ``Lambda``) is a measurement of ``s`` with
noise ``Lambda^-1`` (on its range): the filter's gain is ``K = Sigma_:s M`` with
``M = Lambda (I + Sigma_ss Lambda)^-1``, and ``K R K^T = Sigma_:s M^T (I - Sigma_ss M)
Sigma_s:`` needs no inverse of ``Lambda``.

The thesis's creation of a landmark is not such a measurement: it uses its scan twice,
as the new model's vertex prior and as the observation of it, so its pose factor leaves
the pose mean where it was (shifts below 1e-12) and the estimation error with it.
By default (``FilterConfig.error_creation_pose_update`` False) ``P``'s pose block stays as
it is at a creation, and only the new reference is appended with its error
(:func:`add_landmark`).

Frames and units: the filter's state ``[x; r_0; ...]`` (pose [m, m, rad], references
[m] or landmark frames [m, m, rad]). Pure numpy.
"""

from __future__ import annotations

import numpy as np

from vslam_gym.slam.gaussian import symmetrize
from vslam_gym.slam.state_update import POSE_DIM, append_reference, reference_given_pose

__all__ = ["add_landmark", "direct_update", "factor_update", "pose_update"]


def factor_update(
    p: np.ndarray, sigma: np.ndarray, idx: np.ndarray, lam: np.ndarray, scale: float
) -> np.ndarray:
    """``P`` after the filter multiplied ``Sigma`` by the factor ``C(lam, .)`` on ``idx``.

    With ``G = Sigma_:s``, ``K = G M``, ``B = P_s:`` and ``Q = M B``, the Joseph form is
    ``P + G X G^T - G Q - Q^T G^T`` with ``X = M P_ss M^T + c M^T (I - Sigma_ss M)``: one
    rank-``2s`` product ``[G, Q^T] [[X, -I], [-I, 0]] [G, Q^T]^T``, ``O(s n^2)``.

    Args:
        p: ``(n, n)`` the error covariance before the update.
        sigma: ``(n, n)`` the filter's covariance before the update (its gain).
        idx: ``(s,)`` the state indices the factor is on (pose, reference).
        lam: ``(s, s)`` the factor's information (positive semi-definite).
        scale: the factor's noise scale ``c`` (>= 0).
    """
    k = idx.size
    g = sigma[:, idx]
    s_ss = g[idx]
    eye = np.eye(k)
    m = lam @ np.linalg.inv(eye + s_ss @ lam)
    x = m @ p[idx[:, None], idx] @ m.T + scale * (m.T @ (eye - s_ss @ m))
    v = np.empty((p.shape[0], 2 * k))
    v[:, :k] = g
    v[:, k:] = (m @ p[idx]).T
    w = np.zeros((2 * k, 2 * k))
    w[:k, :k] = x
    w[:k, k:] = w[k:, :k] = -eye
    return symmetrize(p + v @ (w @ v.T))


def direct_update(
    p: np.ndarray, sigma: np.ndarray, h: np.ndarray, noise: np.ndarray, scale: float = 1.0
) -> np.ndarray:
    """``P`` after the filter's EKF update with ``y = H s + n``, ``n ~ N(0, noise)``.

    ``h`` ``(k, n)``, ``noise`` ``(k, k)`` positive definite; the gain is the filter's,
    ``K = Sigma H^T (H Sigma H^T + noise)^-1``, and
    ``P' = P - K H P - (K H P)^T + K (H P H^T + c noise) K^T``.
    """
    ph = sigma @ h.T
    gain = np.linalg.solve(h @ ph + noise, ph.T).T
    hp = h @ p
    khp = gain @ hp
    return symmetrize(p - khp - khp.T + gain @ (hp @ h.T + scale * noise) @ gain.T)


def pose_update(p: np.ndarray, sigma: np.ndarray, noise: np.ndarray) -> np.ndarray:
    """``P`` after a direct measurement of the pose (``H = [I_3, 0]``) with ``noise``.

    The factor ``noise^-1`` on the pose, at its own noise (:func:`factor_update`).
    """
    return factor_update(p, sigma, np.arange(POSE_DIM), np.linalg.inv(noise), 1.0)


def add_landmark(
    p: np.ndarray, sigma: np.ndarray, lam: np.ndarray, scale: float, pose_update: bool = True
) -> np.ndarray:
    """``P`` after the thesis's creation (a factor on the pose and a new reference).

    As :func:`~vslam_gym.slam.state_update.state_space_update` with no prior on the
    reference: the factor ``lam`` ``(3 + d, 3 + d)`` splits into a pose factor and
    ``r = C x + c + e`` (:func:`~vslam_gym.slam.state_update.reference_given_pose`); the
    pose is updated with the first (unless ``pose_update`` is False:
    ``FilterConfig.error_creation_pose_update``), and ``r`` is appended with its error
    ``C e_x + e`` (``e`` scaled too).
    """
    _, c_mat, e_cov, lam_x = reference_given_pose(lam)
    if pose_update:
        p = factor_update(p, sigma, np.arange(POSE_DIM), symmetrize(lam_x), scale)
    return append_reference(p, c_mat, scale * e_cov)
