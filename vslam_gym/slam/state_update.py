"""The state-space update of the vertex SLAM filter (SPEC section 10 item 3; thesis 4.3.3).

The state is ``s = [x; r_0; ...; r_{L-1}]`` (lidar pose and one reference per landmark)
with a Gaussian belief in moment form. A reference is the thesis's 2-D point ``(x, y)``
[m] (:data:`REF_DIM`) or, with ``FilterConfig.reference="pose"``, a landmark frame
``(x [m], y [m], phi [rad])`` (:data:`POSE_REF_DIM`) whose heading carries the
landmark's orientation uncertainty and its correlation with the robot heading. A
landmark's vertices ``v`` hang off its reference through the linear(ised) conditional
``v = A_vr r + b_vr + n``, ``n ~ C(K_v, 0)``; every function here takes the reference
size from the shapes of its arguments.

Updating with one associated landmark multiplies three factors over ``[x; m; r; v]``
(``m``: every other reference): ``Phi1`` the current belief, ``Phi2 = p(v | r)`` in the
new vertex space (``A2 = F^T A_vr``, ``b2 = F^T b_vr``, ``K2 = F^T K_v F``) and
``Phi3 = p(v | x, z)`` from the model update (``A3 = A_vx``, ``b3 = b_vx``,
``K3 = K_obs``). The result is factorised again as ``p(x, m, r) p(v | r)``:

- ``Phi5 = p(x, m, r)``: ``v`` marginalised out. ``Phi2 Phi3`` with ``v`` marginalised is
  a factor ``C(Lambda, eta)`` on ``(x, r)`` only, so the belief is updated in moment form
  by a rank-5 Woodbury correction (rank 6 with a landmark frame), ``O((3 + 2L)^2)``,
  never inverting the full state.
- ``Phi8 = p(v | r)`` (``K8``, ``A8``, ``b8``): from the local joint over ``(x, r, v)`` of
  the prior marginal ``p(x, r)`` (``m`` marginalised) times ``Phi2 Phi3``, with ``x``
  marginalised. This equals the thesis's closed forms (4.3.39-4.3.53, SPEC section 10).

A new landmark's reference has no prior information (4.3.62): its factor ``C(Lambda, eta)``
splits into a pose factor and ``p(r | x)``, which appends ``r`` to the state.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.linalg

from vslam_gym.slam.gaussian import Canonical, cho_solve_finite, cholesky, symmetrize
from vslam_gym.slam.geometry import stack_last, wrap_angle

POSE_DIM = 3
REF_DIM = 2
"""Size of the thesis's reference point ``(x, y)``."""
POSE_REF_DIM = 3
"""Size of a landmark-frame reference ``(x, y, phi)``."""


def rotation_columns(vertices: np.ndarray, centre: np.ndarray) -> np.ndarray:
    """``(2k,)``: derivative of the vertices ``(k, 2)`` [m] under a rotation about ``centre``.

    ``d v_i / d phi = perp(v_i - centre) = (-(y_i - c_y), x_i - c_x)`` [m/rad]: the column of
    ``A_vr`` that belongs to a landmark frame's heading.
    """
    d = np.asarray(vertices, dtype=float).reshape(-1, 2) - np.asarray(centre, dtype=float)[:2]
    return stack_last(-d[:, 1], d[:, 0]).reshape(-1)


def pose_measurement_update(
    mu: np.ndarray, sigma: np.ndarray, z: np.ndarray, cov_z: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Kalman update of the whole state with a direct measurement ``z ~ N(x, cov_z)``.

    ``H = [I_3, 0]``: the landmark references move with the pose through their
    correlations. Heading innovation wrapped; ``O((3 + 2L)^2)``.

    Returns:
        New ``(mu, Sigma)`` (copies).

    Raises:
        numpy.linalg.LinAlgError: the innovation covariance is not positive definite.
    """
    innovation = np.asarray(z, dtype=float) - mu[:POSE_DIM]
    innovation[2] = wrap_angle(innovation[2])
    s_cho = scipy.linalg.cho_factor(sigma[:POSE_DIM, :POSE_DIM] + cov_z)
    gain_t = scipy.linalg.cho_solve(s_cho, sigma[:POSE_DIM, :])  # (3, n) = S^-1 Sigma_x.
    mu_new = mu + gain_t.T @ innovation
    mu_new[2] = wrap_angle(mu_new[2])
    sigma_new = symmetrize(sigma - sigma[:, :POSE_DIM] @ gain_t)
    return mu_new, sigma_new


@dataclass
class LandmarkConditional:
    """``p(v | r) = N(A r + b, K^-1)``: vertices [m] given the reference, world frame.

    Attributes:
        A: ``(2k, d)``, ``d`` the reference size (2: a point; 3: a landmark frame, whose
            last column is linearised at the last :meth:`relinearized`).
        b: ``(2k,)``.
        K: ``(2k, 2k)`` information matrix (positive definite).
    """

    A: np.ndarray  # noqa: N815
    b: np.ndarray
    K: np.ndarray  # noqa: N815
    _cov: np.ndarray | None = field(default=None, repr=False, compare=False)

    def mean(self, r: np.ndarray) -> np.ndarray:
        """Vertex means ``(k, 2)`` for reference ``r``."""
        return (self.A @ r + self.b).reshape(-1, 2)

    def relinearized(self, r: np.ndarray) -> LandmarkConditional:
        """The conditional re-linearised at the reference ``r`` (landmark frames only).

        The heading column of ``A`` becomes the exact rotation derivative at the current
        vertex means (:func:`rotation_columns`) and ``b`` keeps the means at ``r``, so the
        linear model stays a rigid rotation near ``r`` however far the heading has moved
        since the column was last set. A point reference is returned unchanged.
        """
        if self.A.shape[1] != POSE_REF_DIM:
            return self
        r = np.asarray(r, dtype=float)
        mean = self.A @ r + self.b
        a = self.A.copy()
        a[:, 2] = rotation_columns(mean, r)
        return LandmarkConditional(A=a, b=mean - a @ r, K=self.K, _cov=self._cov)

    def covariance(self) -> np.ndarray:
        """``Sigma_v = K^-1`` ``(2k, 2k)`` (computed once; treat it as read-only)."""
        if self._cov is None:
            lower = np.linalg.cholesky(self.K)
            eye = np.eye(self.K.shape[0])
            if np.isfinite(lower).all():
                self._cov = symmetrize(cho_solve_finite(lower, eye))
            else:  # scipy's finiteness check raises its error
                self._cov = symmetrize(scipy.linalg.cho_solve((lower, True), eye))
        return self._cov

    def select(
        self, source: np.ndarray, means: np.ndarray, covs: np.ndarray, r: np.ndarray
    ) -> LandmarkConditional:
        """The conditional over a new vertex set (unknown-line update, Algorithm 7).

        Vertex ``i`` is old vertex ``source[i]`` (the others are marginalised out) or,
        where ``source[i] == -1``, a new vertex independent of all others, with mean
        ``means[i]`` [m] and covariance ``covs[i]`` ``(2, 2)``, rigidly attached to the
        reference (``A = I`` for a point; ``[I, rotation column]`` for a landmark frame;
        ``b = mean - A r``).
        """
        source = np.asarray(source, dtype=int)
        cov = self.covariance()
        k = source.size
        a = np.zeros((2 * k, self.A.shape[1]))
        b = np.zeros(2 * k)
        big = np.zeros((2 * k, 2 * k))
        old = np.flatnonzero(source >= 0)
        if old.size:
            rows_new = stack_last(2 * old, 2 * old + 1).reshape(-1)
            rows_old = stack_last(2 * source[old], 2 * source[old] + 1).reshape(-1)
            a[rows_new] = self.A[rows_old]
            b[rows_new] = self.b[rows_old]
            big[rows_new[:, None], rows_new] = cov[rows_old[:, None], rows_old]
        for i in np.flatnonzero(source < 0):
            sl = slice(2 * i, 2 * i + 2)
            a[sl, :2] = np.eye(2)
            if a.shape[1] == POSE_REF_DIM:
                a[sl, 2] = rotation_columns(means[i], r)
            b[sl] = means[i] - a[sl] @ r
            big[sl, sl] = covs[i]
        return LandmarkConditional(A=a, b=b, K=symmetrize(np.linalg.inv(symmetrize(big))))

    def fold(self, keep: np.ndarray, subst: np.ndarray) -> LandmarkConditional:
        """The conditional after wrapping (3.2.95).

        Keeps the vertices ``keep`` (marginalising the others), then substitutes
        ``v_keep = subst v_new`` in canonical form: ``K' = S^T K_keep S`` and mean
        ``K'^-1 S^T K_keep (A_keep r + b_keep)``.
        """
        keep = np.asarray(keep, dtype=int)
        rows = stack_last(2 * keep, 2 * keep + 1).reshape(-1)
        k_keep = symmetrize(np.linalg.inv(self.covariance()[np.ix_(rows, rows)]))
        k_new = symmetrize(subst.T @ k_keep @ subst)
        proj = np.linalg.solve(k_new, subst.T @ k_keep)
        return LandmarkConditional(A=proj @ self.A[rows], b=proj @ self.b[rows], K=k_new)


def _add_linear_factor(
    kk: np.ndarray,
    hh: np.ndarray,
    y: slice,
    v: slice,
    a: np.ndarray,
    b: np.ndarray,
    k: np.ndarray,
) -> None:
    """Add the canonical form of ``v = a y + b + n``, ``n ~ C(k, 0)``, to ``(kk, hh)``.

    ``y`` and ``v`` are the slices of the two variables in ``kk`` ``(dim, dim)`` and
    ``hh`` ``(dim,)``, added to in place block by block: ``[[a^T k a, -(k a)^T],
    [-k a, k]]`` and ``[-(k a)^T b, k b]``.
    """
    ka = k @ a
    neg_t = -ka.T
    kk[y, y] += a.T @ ka
    kk[y, v] += neg_t
    kk[v, y] += -ka
    kk[v, v] += k
    hh[y] += neg_t @ b
    hh[v] += k @ b


def observation_factor(
    a2: np.ndarray,
    b2: np.ndarray,
    k2: np.ndarray,
    a3: np.ndarray,
    b3: np.ndarray,
    k3: np.ndarray,
) -> Canonical:
    """``Phi2 Phi3`` in canonical form over ``z = (x (3), r (d), v (2k))``."""
    nv, d = b2.size, a2.shape[1]
    dim = POSE_DIM + d + nv
    kk, hh = np.zeros((dim, dim)), np.zeros(dim)
    x, r, v = slice(0, POSE_DIM), slice(POSE_DIM, POSE_DIM + d), slice(POSE_DIM + d, dim)
    _add_linear_factor(kk, hh, r, v, a2, b2, k2)
    _add_linear_factor(kk, hh, x, v, a3, b3, k3)
    return Canonical(kk, hh)


def augment_landmark(
    mu: np.ndarray,
    sigma: np.ndarray,
    a3: np.ndarray,
    b3: np.ndarray,
    cov3: np.ndarray,
    select: np.ndarray,
    shape_sigma: float,
    select_pose: np.ndarray | None = None,
    heading_sigma: float = 0.0,
) -> tuple[np.ndarray, np.ndarray, LandmarkConditional]:
    """Add a new landmark by augmentation: no information about the pose is created.

    The vertices seen from the pose, ``v = A3 x + b3 + n``, ``n ~ N(0, cov3)``, define the
    reference ``r = S v + S_x x + e`` (``S = select``, e.g. the mean of the object vertices;
    ``S_x = select_pose``, e.g. the pose heading as a landmark frame's heading, with
    ``e ~ N(0, heading_sigma^2)`` [rad] on that row so that the state stays positive
    definite). The state gains ``r`` with its exact moments (``r`` correlates with the pose
    and, through it, with the map), and the landmark keeps ``p(v | r)`` with ``x`` and
    ``m`` marginalised. That conditional is singular along ``S v = r`` (an identity, not a
    measurement); ``shape_sigma`` [m] of isotropic spread is added to hold it in
    information form.

    The thesis instead multiplies ``Phi2`` (``A_vr = [I; ...; I]``, ``K2 = Sigma_v^-1``)
    with ``Phi3`` (``K3 = Sigma_v^-1``) in :func:`state_space_update`, which uses the same
    scan twice and, with a point reference, gives the pose heading information it does
    not have.

    Returns:
        ``(mu', Sigma', p(v | r))`` with ``r`` appended to the state.
    """
    n, d = mu.size, select.shape[0]
    s_x = np.zeros((d, POSE_DIM)) if select_pose is None else np.asarray(select_pose, float)
    extra = np.diag(np.where(np.any(s_x != 0.0, axis=1), heading_sigma**2, 0.0))
    s_xx = sigma[:3, :3]
    t = select @ a3 + s_x  # r = T x + S b3 + S n + e
    mu_v = a3 @ mu[:3] + b3
    mu_r = select @ mu_v + s_x @ mu[:3]
    cross = t @ sigma[:3, :]  # cov(r, state)
    noise_rr = select @ cov3 @ select.T + extra
    s_rr = t @ s_xx @ t.T + noise_rr
    mu_new = np.concatenate([mu, mu_r])
    sigma_new = np.zeros((n + d, n + d))
    sigma_new[:n, :n] = sigma
    sigma_new[n:, :n] = cross
    sigma_new[:n, n:] = cross.T
    sigma_new[n:, n:] = symmetrize(s_rr)
    sigma_vv = a3 @ s_xx @ a3.T + cov3
    s_vr = a3 @ s_xx @ t.T + cov3 @ select.T
    gain = np.linalg.solve(s_rr, s_vr.T).T
    cond_cov = symmetrize(sigma_vv - gain @ s_vr.T) + shape_sigma**2 * np.eye(b3.size)
    k = symmetrize(np.linalg.inv(cond_cov))
    conditional = LandmarkConditional(A=gain, b=mu_v - gain @ mu_r, K=k)
    # [Sigma, cross^T; cross, s_rr] is positive definite when Sigma is and the Schur
    # complement s_rr - cross Sigma^-1 cross^T = S cov3 S^T + e is (no O(n^3) check).
    cholesky(noise_rr, "state covariance after adding a landmark")
    return mu_new, sigma_new, conditional


def _times_leading(joint: Canonical, prior: Canonical) -> Canonical:
    """``joint`` times ``prior`` over its leading ``prior.dim`` variables.

    ``joint + prior.extend(joint.dim - prior.dim)`` without the zero-padded copy: the
    sum of two symmetric information matrices is symmetric as it stands.
    """
    lead = slice(0, prior.dim)
    K, h = joint.K.copy(), joint.h.copy()
    K[lead, lead] += prior.K
    h[lead] += prior.h
    return Canonical(K, h)


def _conditional_v_given_r(local: Canonical, d: int) -> LandmarkConditional:
    """``p(v | r)`` from a canonical form over ``(x, r (d), v)`` (``x`` marginalised)."""
    m = local._marginal(np.arange(POSE_DIM, local.dim), np.arange(POSE_DIM))
    k8 = m.K[d:, d:]
    chol = np.linalg.cholesky(k8)  # of a finite Canonical's block: finite
    a8 = -cho_solve_finite(chol, m.K[d:, :d])
    b8 = cho_solve_finite(chol, m.h[d:])
    return LandmarkConditional(A=a8, b=b8, K=symmetrize(k8))


def _woodbury(
    mu: np.ndarray, sigma: np.ndarray, idx: np.ndarray, lam: np.ndarray, eta: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Belief times the factor ``C(lam, eta)`` on the variables ``idx`` (moment form).

    ``Sigma' = Sigma - Sigma_:s lam (I + Sigma_ss lam)^-1 Sigma_s:`` and
    ``mu' = mu + Sigma'_:s (eta - lam mu_s)``; ``lam`` may be singular.
    """
    s_cols = sigma[:, idx]
    s_ss = s_cols[idx]
    gain = np.linalg.solve((np.eye(idx.size) + s_ss @ lam).T, (s_cols @ lam).T).T
    change = gain @ s_cols.T
    sigma_new = symmetrize(np.subtract(sigma, change, out=change))
    mu_new = mu + sigma_new[:, idx] @ (eta - lam @ mu[idx])
    return mu_new, sigma_new


def reference_given_pose(
    lam: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A new landmark's factor ``C(lam, .)`` on ``(x, r)`` split as ``p(r | x) f(x)``.

    ``r = C x + c + e``, ``e ~ N(0, lam_rr^-1)``; ``f`` has the information ``lam_x =
    lam_xx + lam_xr C`` on the pose. Returns ``(chol(lam_rr), C, lam_rr^-1, lam_x)``
    (``c`` needs the factor's ``eta``: ``cho_solve(chol, eta_r)``).
    """
    chol = np.linalg.cholesky(lam[3:, 3:])  # lam: a finite Canonical's
    c_mat = -cho_solve_finite(chol, lam[3:, :3])
    e_cov = cho_solve_finite(chol, np.eye(lam.shape[0] - 3))
    return chol, c_mat, e_cov, lam[:3, :3] + lam[:3, 3:] @ c_mat


def append_reference(cov: np.ndarray, c_mat: np.ndarray, e_cov: np.ndarray) -> np.ndarray:
    """The state covariance ``cov`` ``(n, n)`` with ``r = C x + e`` appended (``e`` apart).

    ``C`` ``(d, 3)`` maps the pose, ``e_cov`` ``(d, d)`` is the covariance of ``e``,
    independent of the state.
    """
    n, d = cov.shape[0], e_cov.shape[0]
    out = np.zeros((n + d, n + d))
    out[:n, :n] = cov
    cross = c_mat @ cov[:3, :]
    out[n:, :n] = cross
    out[:n, n:] = cross.T
    out[n:, n:] = symmetrize(c_mat @ cov[:3, :3] @ c_mat.T + e_cov)
    return out


def state_space_update(
    mu: np.ndarray,
    sigma: np.ndarray,
    ref: int | None,
    a2: np.ndarray,
    b2: np.ndarray,
    k2: np.ndarray,
    a3: np.ndarray,
    b3: np.ndarray,
    k3: np.ndarray,
    *,
    with_factor: bool = False,
) -> (
    tuple[np.ndarray, np.ndarray, LandmarkConditional]
    | tuple[np.ndarray, np.ndarray, LandmarkConditional, np.ndarray]
):
    """Update the belief with one landmark's observation (SPEC section 10 item 3).

    Args:
        mu: ``(n,)`` state mean; the pose is ``mu[:3]``.
        sigma: ``(n, n)`` state covariance.
        ref: index of the landmark's reference ``r`` in the state, or ``None`` for a new
            landmark (``r`` has no prior information and is appended to the state).
        a2, b2, k2: ``Phi2 = p(v | r)`` in the new vertex space (``(2k, d)``, ``(2k,)``,
            ``(2k, 2k)``; ``d`` the reference size, 2 or 3).
        a3, b3, k3: ``Phi3 = p(v | x, z)`` (``(2k, 3)``, ``(2k,)``, ``(2k, 2k)``); ``k3``
            may be singular (unobserved vertices carry no information).
        with_factor: also return ``Lambda`` ``(3 + d, 3 + d)``, the information of the
            factor ``Phi2 Phi3`` with ``v`` marginalised, on ``(x, r)``
            (:mod:`vslam_gym.slam.error_covariance` applies its gain).

    Returns:
        ``(mu', Sigma', p(v | r))``, and ``Lambda`` with ``with_factor``; the state grows
        by ``d`` for a new landmark.

    Raises:
        NotPositiveDefiniteError: ``k2 + k3`` or the result is not positive definite.

    The result is checked on its pose and reference block only (a ``5 x 5``, or ``6 x 6``, Cholesky
    instead of one of the whole state, which costs ``O(n^3)`` and runs multi-threaded
    BLAS on large maps): for a positive definite prior ``Sigma`` and the positive
    semi-definite factor ``C(Lambda, eta)`` on the variables ``s``, the Woodbury result
    ``Sigma - Sigma_:s M Sigma_s:`` (``M = Lambda (I + Sigma_ss Lambda)^-1``) is positive
    definite exactly when its block ``Sigma'_ss = Sigma_ss - Sigma_ss M Sigma_ss`` is
    (both reduce to the eigenvalues of ``Sigma_ss M`` lying below 1). A new landmark
    appends ``r = C x + c + e`` with ``e ~ N(0, Lambda_rr^-1)``, which is positive
    definite when the updated pose block is.
    """
    d = a2.shape[1]
    phi23 = observation_factor(a2, b2, k2, a3, b3, k3)
    xr = np.arange(POSE_DIM + d)
    factor = phi23._marginal(xr, np.arange(POSE_DIM + d, phi23.dim))  # v out: on (x, r)
    pose = np.arange(POSE_DIM)
    if ref is None:
        prior_k = np.zeros((POSE_DIM + d,) * 2)
        prior_h = np.zeros(POSE_DIM + d)
        prior_k[:3, :3] = np.linalg.inv(sigma[:3, :3])
        prior_h[:3] = prior_k[:3, :3] @ mu[:3]
        prior = Canonical(prior_k, prior_h)
    else:
        local_idx = np.array([*range(POSE_DIM), *range(ref, ref + d)])
        prior = Canonical.from_moments(mu[local_idx], sigma[local_idx[:, None], local_idx])
    conditional = _conditional_v_given_r(_times_leading(phi23, prior), d)

    lam, eta = factor.K, factor.h
    if ref is not None:
        mu_new, sigma_new = _woodbury(mu, sigma, local_idx, lam, eta)
        cholesky(
            sigma_new[local_idx[:, None], local_idx], "state covariance after the landmark update"
        )
    else:
        chol, c_mat, e_cov, lam_x = reference_given_pose(lam)
        c_vec = cho_solve_finite(chol, eta[3:])
        eta_x = eta[:3] - lam[:3, 3:] @ c_vec
        mu_x, sigma_x = _woodbury(mu, sigma, pose, symmetrize(lam_x), eta_x)
        mu_new = np.concatenate([mu_x, c_mat @ mu_x[:3] + c_vec])
        sigma_new = append_reference(sigma_x, c_mat, e_cov)
        cholesky(sigma_x[:3, :3], "state covariance after the landmark update")
    if with_factor:
        return mu_new, sigma_new, conditional, lam
    return mu_new, sigma_new, conditional
