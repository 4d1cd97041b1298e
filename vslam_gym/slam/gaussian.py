"""Gaussian machinery of the estimator: SPD checks, linearisations and the canonical form.

Everything here is pure numpy/scipy and frame-agnostic: the arrays carry whatever units
the caller's state has (metres, radians). Moment-form Gaussians are ``(mu, Sigma)`` with
``mu`` of shape ``(..., n)`` and ``Sigma`` of shape ``(..., n, n)``; leading batch
dimensions are supported by the transforms and SPD helpers (SPEC.md sections 0-1).

Vectorised-function convention (shared by :func:`unscented_transform` and
:func:`first_order_transform`): ``f`` maps a stack of points of shape ``(..., m, n)``
(one point per row) to ``(..., m, p)``, evaluating every point in one call.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np
import scipy.linalg

from vslam_gym.slam.config import ModelConfig

VectorisedFunction = Callable[[np.ndarray], np.ndarray]
"""``f(points (..., m, n)) -> values (..., m, p)``."""

JacobianFunction = Callable[[np.ndarray], np.ndarray]
"""``jacobian(mu (..., n)) -> J (..., p, n)`` with ``J[..., i, j] = d f_i / d x_j``."""

# Numerical tolerances (not model thresholds): multiples of the machine epsilon.
_EPS = float(np.finfo(float).eps)
_PSD_EPS_MULTIPLE = 64.0
"""An input covariance whose smallest eigenvalue is above ``-n * this * eps * max|eig|``
counts as positive semi-definite (round-off), and is factored by eigen-decomposition."""
_RANGE_EPS_MULTIPLE = 1e4
"""Relative residual (in units of ``eps``) below which a vector counts as lying in the range
of a singular information block when marginalising (:meth:`Canonical.marginalize`)."""


class NotPositiveDefiniteError(np.linalg.LinAlgError):
    """A matrix that must be symmetric positive definite is not.

    Subclasses :class:`numpy.linalg.LinAlgError` (hence :class:`ValueError`).

    Attributes:
        quantity: name of the offending matrix (e.g. ``"unscented_transform output
            covariance"``).
        min_eigenvalue: its smallest eigenvalue (over the whole batch), ``nan`` if unknown.
        detail: optional extra explanation appended to the message.
    """

    def __init__(self, quantity: str, min_eigenvalue: float = float("nan"), detail: str = ""):
        self.quantity = quantity
        self.min_eigenvalue = float(min_eigenvalue)
        self.detail = detail
        message = f"{quantity} is not positive definite (smallest eigenvalue {min_eigenvalue:.6g})"
        if detail:
            message += f": {detail}"
        super().__init__(message)

    def __reduce__(self):  # keep the exception picklable despite the custom signature
        return (type(self), (self.quantity, self.min_eigenvalue, self.detail))


# ---------------------------------------------------------------------------------------
# SPD helpers
# ---------------------------------------------------------------------------------------


def _as_square(S: np.ndarray, name: str) -> np.ndarray:
    S = np.asarray(S, dtype=float)
    if S.ndim < 2 or S.shape[-1] != S.shape[-2]:
        raise ValueError(f"{name} must have shape (..., n, n), got {S.shape}")
    return S


def symmetrize(S: np.ndarray) -> np.ndarray:
    """Return ``(S + S^T) / 2`` over the last two axes (batched over leading dims)."""
    return _symmetrized(_as_square(S, "matrix"))


def _symmetrized(S: np.ndarray) -> np.ndarray:
    """:func:`symmetrize` of a float array already checked to be ``(..., n, n)``."""
    out = S + S.swapaxes(-1, -2)
    out *= 0.5
    return out


def inflated_information(
    K: np.ndarray, sigma: float, extra: np.ndarray | None = None
) -> np.ndarray:
    """Information of a Gaussian whose covariance ``K^-1`` gains ``Q = sigma^2 I + extra``.

    ``K' = (I + K Q)^-1 K = (K^-1 + Q)^-1``, defined for a singular positive
    semi-definite ``K`` too: a direction without information stays without, and with
    ``extra`` None every eigenvalue ``l`` becomes ``l / (1 + sigma^2 l) < 1 / sigma^2``.
    ``sigma`` in the units of the variables (m for vertex coordinates); ``extra`` a
    positive semi-definite ``(n, n)`` covariance in the same units. ``sigma`` 0 and no
    ``extra`` return ``K``.
    """
    K = _as_square(K, "information")
    if sigma == 0.0 and extra is None:
        return K
    q = sigma * sigma * np.eye(K.shape[-1])
    if extra is not None:
        q = q + extra
    return symmetrize(np.linalg.solve(np.eye(K.shape[-1]) + K @ q, K))


def _min_eigenvalue(S: np.ndarray) -> float:
    """Smallest eigenvalue of the symmetric part of ``S`` over the whole batch."""
    if S.shape[-1] == 0:
        return float("inf")
    if not np.isfinite(S).all():
        return float("nan")
    return float(np.min(np.linalg.eigvalsh(symmetrize(S))))


def _check_finite(S: np.ndarray, name: str) -> None:
    if not np.isfinite(S).all():
        raise ValueError(f"{name} contains non-finite values (nan or inf)")


def cholesky(S: np.ndarray, name: str = "covariance") -> np.ndarray:
    """Lower Cholesky factor ``L`` (``S = L L^T``) of the symmetric part of ``S``.

    Batched over leading dims. Raises :class:`NotPositiveDefiniteError` (naming ``name``
    and the smallest eigenvalue) when ``S`` is not positive definite, and
    :class:`ValueError` when it is not square or not finite.
    """
    S = _symmetrized(_as_square(S, name))
    _check_finite(S, name)
    try:
        return np.linalg.cholesky(S)
    except np.linalg.LinAlgError:
        raise NotPositiveDefiniteError(name, _min_eigenvalue(S)) from None


_POTRS = scipy.linalg.get_lapack_funcs("potrs", (np.empty((1, 1)),))
"""LAPACK's float64 Cholesky solve, the routine behind :func:`scipy.linalg.cho_solve`."""
_POTRF = scipy.linalg.get_lapack_funcs("potrf", (np.empty((1, 1)),))
"""LAPACK's float64 Cholesky factorisation, the routine behind :func:`scipy.linalg.cho_factor`."""


def cho_solve_finite(factor: np.ndarray, b: np.ndarray, *, lower: bool = True) -> np.ndarray:
    """``scipy.linalg.cho_solve((factor, lower), b)`` without its input checks (hot paths).

    The same LAPACK routine on the same arrays, so the same result to the last bit,
    without scipy's finiteness checks and batching wrapper, whose overhead dominates on
    the filter's small matrices. The caller guarantees what those checks would test:
    ``factor`` is a lower (``lower``) or upper Cholesky factor ``(n, n)`` and ``b``
    ``(n,)`` or ``(n, m)``, both finite float64 (e.g. the factor of a checked finite
    matrix and an identity).
    """
    if b.size == 0:
        return scipy.linalg.cho_solve((factor, lower), b)
    x, info = _POTRS(factor, b, lower=lower)
    if info != 0:
        raise ValueError(f"illegal value in {-info}th argument of internal potrs")
    return x


def cho_factor_finite(S: np.ndarray) -> np.ndarray:
    """``scipy.linalg.cho_factor(S)[0]`` without its input checks (hot paths).

    The upper Cholesky factor by the same LAPACK call (the strictly lower triangle holds
    whatever ``S`` had), for :func:`cho_solve_finite` with ``lower=False``. The caller
    guarantees that ``S`` is a finite float64 ``(n, n)`` matrix with ``n >= 1``.

    Raises:
        numpy.linalg.LinAlgError: ``S`` is not positive definite (scipy's error).
    """
    c, info = _POTRF(S, lower=False, clean=False)
    if info > 0:
        raise np.linalg.LinAlgError(
            f"{info}-th leading minor of the array is not positive definite"
        )
    if info < 0:
        raise ValueError(
            f'LAPACK reported an illegal value in {-info}-th argument on entry to "POTRF".'
        )
    return c


def is_spd(S: np.ndarray) -> bool:
    """Whether (the symmetric part of) every matrix in ``S`` is positive definite.

    Cholesky based; non-finite or non-square input gives ``False``.
    """
    S = np.asarray(S, dtype=float)
    if S.ndim < 2 or S.shape[-1] != S.shape[-2] or not np.isfinite(S).all():
        return False
    try:
        np.linalg.cholesky(symmetrize(S))
    except np.linalg.LinAlgError:
        return False
    return True


def ensure_spd(S: np.ndarray, name: str = "covariance") -> np.ndarray:
    """Symmetrise ``S`` and check that it is positive definite (batched).

    Returns:
        The symmetrised matrix (a new array).

    Raises:
        NotPositiveDefiniteError: some matrix of the batch is not positive definite.
        ValueError: ``S`` is not square over its last two axes or not finite.
    """
    S = symmetrize(_as_square(S, name))
    cholesky(S, name)
    return S


def _square_root(Sigma: np.ndarray, name: str) -> np.ndarray:
    """Return a square root ``S`` with ``S S^T = Sigma`` (columns are the sigma directions).

    Diagonal covariances take a fast path (``sqrt`` of the diagonal, zero variances
    allowed). Otherwise Cholesky; when that fails, a positive *semi*-definite matrix
    (smallest eigenvalue above ``-n * 64 eps * max|eig|``) is factored by its
    eigen-decomposition with the round-off negative eigenvalues clipped to zero, so that
    deterministic components are allowed. Anything else raises NotPositiveDefiniteError.
    """
    n = Sigma.shape[-1]
    diag = np.diagonal(Sigma, axis1=-2, axis2=-1)
    off_diagonal = Sigma - diag[..., :, None] * np.eye(n)
    if not np.any(off_diagonal):
        if np.any(diag < 0):
            raise NotPositiveDefiniteError(name, float(np.min(diag)))
        return np.sqrt(diag)[..., None, :] * np.eye(n)
    try:
        return np.linalg.cholesky(Sigma)
    except np.linalg.LinAlgError:
        pass
    eigenvalues, eigenvectors = np.linalg.eigh(Sigma)
    scale = np.max(np.abs(eigenvalues), axis=-1, keepdims=True)
    tolerance = n * _PSD_EPS_MULTIPLE * _EPS * scale
    if np.any(eigenvalues < -tolerance):
        raise NotPositiveDefiniteError(
            name, float(np.min(eigenvalues)), "not even positive semi-definite"
        )
    return eigenvectors * np.sqrt(np.clip(eigenvalues, 0.0, None))[..., None, :]


def _broadcast_moments(mu: np.ndarray, Sigma: np.ndarray, where: str) -> tuple[np.ndarray, ...]:
    mu = np.asarray(mu, dtype=float)
    Sigma = _as_square(Sigma, f"{where}: Sigma")
    if mu.ndim < 1 or mu.shape[-1] != Sigma.shape[-1]:
        raise ValueError(
            f"{where}: mu must have shape (..., n) matching Sigma (..., n, n); got mu "
            f"{mu.shape}, Sigma {Sigma.shape}"
        )
    if mu.shape[-1] == 0:
        raise ValueError(f"{where}: the input dimension n must be >= 1")
    _check_finite(mu, f"{where}: mu")
    _check_finite(Sigma, f"{where}: Sigma")
    batch = np.broadcast_shapes(mu.shape[:-1], Sigma.shape[:-2])
    n = mu.shape[-1]
    mu = np.broadcast_to(mu, (*batch, n))
    Sigma = np.broadcast_to(symmetrize(Sigma), (*batch, n, n))
    return mu, Sigma


def _evaluate(f: VectorisedFunction, points: np.ndarray, where: str) -> np.ndarray:
    """Call the vectorised ``f`` on ``points (..., m, n)`` and validate ``(..., m, p)``."""
    values = np.asarray(f(points), dtype=float)
    if values.ndim != points.ndim or values.shape[:-1] != points.shape[:-1]:
        raise ValueError(
            f"{where}: f must map points of shape (..., m, n) = {points.shape} to "
            f"(..., m, p) with the same leading shape; got {values.shape}"
        )
    _check_finite(values, f"{where}: f(points)")
    return values


# ---------------------------------------------------------------------------------------
# Unscented transform
# ---------------------------------------------------------------------------------------


@dataclass(frozen=True)
class UTWeights:
    """Sigma-point scale and weights of the unscented transform (SPEC section 1).

    Attributes:
        n: input dimension.
        lam: ``lambda = alpha^2 (n + kappa) - n``.
        alpha_squared: ``alpha^2``.
        scale: ``sqrt(n + lambda)``: sigma points are ``mu +/- scale * col_i(sqrt(Sigma))``.
        w_m0: mean weight of the centre point, ``lambda / (n + lambda)``.
        w_c0: covariance weight of the centre point, ``w_m0 + 1 - alpha^2 + beta``.
        w_i: weight of every other point (mean and covariance), ``1 / (2 (n + lambda))``.
    """

    n: int
    lam: float
    alpha_squared: float
    scale: float
    w_m0: float
    w_c0: float
    w_i: float


def ut_weights(
    n: int, *, beta: float = 2.0, kappa: float = 0.0, alpha_squared_times_n: float = 1.0
) -> UTWeights:
    """UT parameters for input dimension ``n`` with ``alpha^2 = alpha_squared_times_n / n``.

    The defaults are the thesis's: ``lambda = 1 - n``, ``n + lambda = 1`` (sigma points
    on the 1-sigma contour), ``w_m0 = 1 - n``, ``w_c0 = 4 - n - 1/n``, ``w_i = 1/2``.

    Raises:
        ValueError: ``n < 1`` or ``n + lambda <= 0``.
    """
    if n < 1:
        raise ValueError(f"ut_weights: the input dimension must be >= 1, got {n}")
    alpha_squared = alpha_squared_times_n / n
    n_plus_lambda = alpha_squared * (n + kappa)
    if not (np.isfinite(n_plus_lambda) and n_plus_lambda > 0):
        raise ValueError(
            "ut_weights: n + lambda = alpha^2 (n + kappa) must be > 0, got "
            f"{n_plus_lambda!r} (n={n}, kappa={kappa}, alpha^2 n={alpha_squared_times_n})"
        )
    lam = n_plus_lambda - n
    w_m0 = lam / n_plus_lambda
    return UTWeights(
        n=n,
        lam=lam,
        alpha_squared=alpha_squared,
        scale=float(np.sqrt(n_plus_lambda)),
        w_m0=w_m0,
        w_c0=w_m0 + 1.0 - alpha_squared + beta,
        w_i=0.5 / n_plus_lambda,
    )


def sigma_points(
    mu: np.ndarray, Sigma: np.ndarray, *, kappa: float = 0.0, alpha_squared_times_n: float = 1.0
) -> np.ndarray:
    """Return the ``2n + 1`` sigma points of ``N(mu, Sigma)`` as rows, ``(..., 2n+1, n)``.

    Row 0 is ``mu``, rows ``1..n`` are ``mu + scale * col_i(L)`` and rows ``n+1..2n`` are
    ``mu - scale * col_i(L)`` with ``L`` the Cholesky factor (see :func:`ut_weights`).
    """
    mu, Sigma = _broadcast_moments(mu, Sigma, "sigma_points")
    weights = ut_weights(mu.shape[-1], kappa=kappa, alpha_squared_times_n=alpha_squared_times_n)
    return _sigma_points(mu, _square_root(Sigma, "sigma_points input covariance"), weights.scale)


def _sigma_points(mu: np.ndarray, root: np.ndarray, scale: float) -> np.ndarray:
    offsets = scale * np.swapaxes(root, -1, -2)  # rows are the columns of the root
    centre = mu[..., None, :]
    return np.concatenate([centre, centre + offsets, centre - offsets], axis=-2)


def unscented_transform(
    f: VectorisedFunction,
    mu: np.ndarray,
    Sigma: np.ndarray,
    *,
    beta: float = 2.0,
    kappa: float = 0.0,
    alpha_squared_times_n: float = 1.0,
    check: bool = True,
) -> tuple[np.ndarray, np.ndarray]:
    """Map ``N(mu, Sigma)`` through ``y = f(x)`` with the unscented transform (SPEC 1).

    ``lambda = alpha^2 (n + kappa) - n`` with ``alpha^2 = alpha_squared_times_n / n``; the
    defaults give the thesis's ``lambda = 1 - n``. The matrix square root is the Cholesky
    factor (its columns span the sigma points); a diagonal ``Sigma`` skips the
    factorisation, and a singular positive semi-definite ``Sigma`` is factored by
    eigen-decomposition.

    Round-off: with ``lambda = 1 - n`` the centre weights are ``w_m0 = 1 - n`` and
    ``w_c0 = 4 - n - 1/n``, hugely negative for the ``2n``-dimensional measurement vectors
    of the landmark models. The textbook sums ``sum_i w_i Y_i`` and
    ``sum_i w_ci (Y_i - mu_y)(Y_i - mu_y)^T`` then cancel large terms and can return an
    asymmetric or indefinite covariance. Here the centre point is subtracted first
    (``D_i = Y_i - Y_0``), and the two sums are rewritten exactly as
    ``mu_y = Y_0 + w_i sum_{i>0} D_i`` and
    ``Sigma_y = w_i sum_{i>0} D_i D_i^T + (beta - alpha^2) delta delta^T`` with
    ``delta = mu_y - Y_0``: no large weight appears, and for ``beta >= alpha^2`` (the
    thesis's case) every term is positive semi-definite. The result is symmetrised and,
    with ``check=True``, Cholesky-checked; an output covariance that is rank deficient
    (e.g. ``p > 2n`` outputs or outputs that are exact linear combinations of each other)
    fails that check, so pass ``check=False`` when that is expected.

    Args:
        f: vectorised map ``(..., m, n) -> (..., m, p)`` with ``m = 2n + 1``.
        mu: input mean, shape ``(..., n)``.
        Sigma: input covariance, shape ``(..., n, n)``; batch dims broadcast with ``mu``.
        beta: prior-knowledge parameter (2 is optimal for Gaussians).
        kappa: secondary scaling parameter.
        alpha_squared_times_n: ``alpha^2 * n`` (1: sigma points on the 1-sigma contour).
        check: raise :class:`NotPositiveDefiniteError` if the output is not PD.

    Returns:
        ``(mu_y (..., p), Sigma_y (..., p, p))``.

    Raises:
        NotPositiveDefiniteError: ``Sigma`` is not positive semi-definite, or
            ``check`` and the output covariance is not positive definite.
        ValueError: inconsistent shapes or non-finite values.
    """
    mu, Sigma = _broadcast_moments(mu, Sigma, "unscented_transform")
    weights = ut_weights(
        mu.shape[-1], beta=beta, kappa=kappa, alpha_squared_times_n=alpha_squared_times_n
    )
    root = _square_root(Sigma, "unscented_transform input covariance")
    points = _sigma_points(mu, root, weights.scale)
    values = _evaluate(f, points, "unscented_transform")
    centre = values[..., 0, :]
    deviations = values[..., 1:, :] - centre[..., None, :]
    delta = weights.w_i * np.sum(deviations, axis=-2)
    mu_y = centre + delta
    Sigma_y = weights.w_i * (np.swapaxes(deviations, -1, -2) @ deviations)
    Sigma_y += (beta - weights.alpha_squared) * (delta[..., :, None] * delta[..., None, :])
    Sigma_y = symmetrize(Sigma_y)
    if check:
        cholesky(Sigma_y, "unscented_transform output covariance")
    return mu_y, Sigma_y


# ---------------------------------------------------------------------------------------
# First-order (Jacobian) transform
# ---------------------------------------------------------------------------------------


def numerical_jacobian(
    f: VectorisedFunction, mu: np.ndarray, steps: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """``f(mu)`` and the central-difference Jacobian of the vectorised ``f`` at ``mu``.

    One call of ``f`` on ``2n + 1`` stacked points (``mu``, ``mu + h_j e_j``,
    ``mu - h_j e_j``). A zero step ``h_j`` gives a zero Jacobian column.

    Args:
        f: vectorised map ``(..., m, n) -> (..., m, p)``.
        mu: expansion point, shape ``(..., n)``.
        steps: per-coordinate steps ``h``, shape broadcastable to ``(..., n)``, ``>= 0``.

    Returns:
        ``(f(mu) (..., p), J (..., p, n))``.
    """
    mu = np.asarray(mu, dtype=float)
    n = mu.shape[-1]
    steps = np.broadcast_to(np.asarray(steps, dtype=float), mu.shape)
    if np.any(~np.isfinite(steps)) or np.any(steps < 0):
        raise ValueError("numerical_jacobian: steps must be finite and >= 0")
    offsets = steps[..., None, :] * np.eye(n)  # (..., n, n), row j = h_j e_j
    centre = mu[..., None, :]
    points = np.concatenate([centre, centre + offsets, centre - offsets], axis=-2)
    values = _evaluate(f, points, "first_order_transform")
    difference = values[..., 1 : n + 1, :] - values[..., n + 1 :, :]  # (..., n, p)
    divisor = np.where(steps > 0, 2.0 * steps, 1.0)[..., :, None]
    jacobian = np.swapaxes(difference / divisor, -1, -2)
    return values[..., 0, :], jacobian


DEFAULT_STEP_SIGMAS = 1e-3
"""Default central-difference step of :func:`first_order_transform` in input standard
deviations: small enough to give the Jacobian at the mean (not an average over the
1-sigma region as the UT does), large enough for round-off not to matter."""


def first_order_transform(
    f: VectorisedFunction,
    mu: np.ndarray,
    Sigma: np.ndarray,
    *,
    jacobian: JacobianFunction | None = None,
    check: bool = True,
    step_sigmas: float = DEFAULT_STEP_SIGMAS,
) -> tuple[np.ndarray, np.ndarray]:
    """Map ``N(mu, Sigma)`` through ``y = f(x)`` by linearising at the mean.

    ``mu_y = f(mu)`` and ``Sigma_y = J Sigma J^T``. ``J`` comes from ``jacobian(mu)``
    when given (shape ``(..., p, n)``), otherwise from central differences with the
    per-coordinate step ``h_j = step_sigmas * sqrt(Sigma_jj)`` in a single vectorised
    call of ``f`` (a coordinate with zero variance gets a zero column, which does not
    change ``Sigma_y``).

    Args:
        f: vectorised map ``(..., m, n) -> (..., m, p)`` (same convention as the UT).
        mu: input mean, shape ``(..., n)``.
        Sigma: input covariance, shape ``(..., n, n)``; batch dims broadcast with ``mu``.
        jacobian: optional analytic Jacobian ``mu (..., n) -> (..., p, n)``.
        check: check that ``Sigma`` is positive semi-definite and raise
            :class:`NotPositiveDefiniteError` if the output is not positive definite.
        step_sigmas: finite-difference step in input standard deviations.

    Returns:
        ``(mu_y (..., p), Sigma_y (..., p, p))``.
    """
    mu, Sigma = _broadcast_moments(mu, Sigma, "first_order_transform")
    if check:
        _square_root(Sigma, "first_order_transform input covariance")
    variances = np.diagonal(Sigma, axis1=-2, axis2=-1)
    if jacobian is None:
        if not (np.isfinite(step_sigmas) and step_sigmas > 0):
            raise ValueError(f"first_order_transform: step_sigmas must be > 0, got {step_sigmas}")
        steps = step_sigmas * np.sqrt(np.clip(variances, 0.0, None))
        mu_y, J = numerical_jacobian(f, mu, steps)
    else:
        mu_y = _evaluate(f, mu[..., None, :], "first_order_transform")[..., 0, :]
        J = np.asarray(jacobian(mu), dtype=float)
        expected = (*mu.shape[:-1], mu_y.shape[-1], mu.shape[-1])
        if J.shape != expected:
            try:
                J = np.broadcast_to(J, expected)
            except ValueError:
                raise ValueError(
                    f"first_order_transform: jacobian(mu) must have shape (..., p, n) = "
                    f"{expected}, got {J.shape}"
                ) from None
        _check_finite(J, "first_order_transform: jacobian(mu)")
    Sigma_y = symmetrize(J @ Sigma @ np.swapaxes(J, -1, -2))
    if check:
        cholesky(Sigma_y, "first_order_transform output covariance")
    return mu_y, Sigma_y


# ---------------------------------------------------------------------------------------
# Pluggable linearisation
# ---------------------------------------------------------------------------------------


@runtime_checkable
class Linearization(Protocol):
    """How a Gaussian is mapped through a nonlinear vectorised function."""

    def propagate(
        self,
        f: VectorisedFunction,
        mu: np.ndarray,
        Sigma: np.ndarray,
        jacobian: JacobianFunction | None = None,
        *,
        check: bool = True,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Return ``(mu_y, Sigma_y)`` of ``y = f(x)``, ``x ~ N(mu, Sigma)`` (batched)."""
        ...


@dataclass(frozen=True)
class UnscentedLinearization:
    """The thesis's unscented transform (ignores any analytic Jacobian)."""

    beta: float = 2.0
    kappa: float = 0.0
    alpha_squared_times_n: float = 1.0

    def propagate(
        self,
        f: VectorisedFunction,
        mu: np.ndarray,
        Sigma: np.ndarray,
        jacobian: JacobianFunction | None = None,
        *,
        check: bool = True,
    ) -> tuple[np.ndarray, np.ndarray]:
        """See :func:`unscented_transform`; ``jacobian`` is ignored."""
        del jacobian
        return unscented_transform(
            f,
            mu,
            Sigma,
            beta=self.beta,
            kappa=self.kappa,
            alpha_squared_times_n=self.alpha_squared_times_n,
            check=check,
        )


@dataclass(frozen=True)
class FirstOrderLinearization:
    """First-order linearisation at the mean (analytic Jacobian if given, else numerical)."""

    step_sigmas: float = DEFAULT_STEP_SIGMAS

    def propagate(
        self,
        f: VectorisedFunction,
        mu: np.ndarray,
        Sigma: np.ndarray,
        jacobian: JacobianFunction | None = None,
        *,
        check: bool = True,
    ) -> tuple[np.ndarray, np.ndarray]:
        """See :func:`first_order_transform`."""
        return first_order_transform(
            f, mu, Sigma, jacobian=jacobian, check=check, step_sigmas=self.step_sigmas
        )


def make_linearization(config: ModelConfig) -> Linearization:
    """Build the linearisation named by ``config.linearization`` (``"ut"``/``"jacobian"``)."""
    if config.linearization == "ut":
        return UnscentedLinearization(
            beta=config.ut_beta,
            kappa=config.ut_kappa,
            alpha_squared_times_n=config.ut_alpha_squared_times_n,
        )
    if config.linearization == "jacobian":
        return FirstOrderLinearization()
    raise ValueError(
        f"make_linearization: unknown linearization {config.linearization!r} "
        "(expected 'ut' or 'jacobian')"
    )


# ---------------------------------------------------------------------------------------
# Canonical (information) form
# ---------------------------------------------------------------------------------------


def _index_mask(
    indices: Sequence[int] | np.ndarray, dim: int, where: str
) -> tuple[np.ndarray, np.ndarray]:
    """Validated ``indices`` into ``0..dim-1`` (negatives wrapped) and their ``(dim,)`` mask.

    Raises ``ValueError`` for indices that are not 1-D integers, out of range or repeated.
    """
    idx = np.asarray(indices)
    chosen = np.zeros(dim, dtype=bool)
    if idx.size == 0:
        return np.zeros(0, dtype=int), chosen
    if idx.ndim != 1 or not np.issubdtype(idx.dtype, np.integer):
        raise ValueError(f"{where}: indices must be a 1-D sequence of integers, got {indices!r}")
    low, high = idx.min(), idx.max()
    if low < -dim or high >= dim:
        raise ValueError(f"{where}: index out of range for dimension {dim}: {idx.tolist()}")
    if low < 0:
        idx = np.where(idx < 0, idx + dim, idx)
    chosen[idx] = True
    if np.count_nonzero(chosen) != idx.size:  # a repeated index marks one entry twice
        raise ValueError(f"{where}: repeated indices {idx.tolist()}")
    return idx, chosen


def _readonly(array: np.ndarray) -> np.ndarray:
    array.setflags(write=False)
    return array


@dataclass(frozen=True, eq=False)
class Canonical:
    """Gaussian in canonical (information) form ``C(K, h)``: ``K = Sigma^-1``, ``h = K mu``.

    ``K`` may be singular: a variable with no information has zero rows and columns
    (SPEC section 0). The arrays are stored as read-only float copies; every operation
    returns a new object.

    Attributes:
        K: information matrix, shape ``(n, n)``, symmetric positive semi-definite.
        h: information vector, shape ``(n,)``.
    """

    K: np.ndarray
    h: np.ndarray

    def __post_init__(self) -> None:
        K = np.asarray(self.K, dtype=float)  # copied by the symmetrisation below
        h = np.array(self.h, dtype=float)
        if K.ndim != 2 or K.shape[0] != K.shape[1] or h.shape != (K.shape[0],):
            raise ValueError(
                f"Canonical needs K of shape (n, n) and h of shape (n,), got K {K.shape}, "
                f"h {h.shape}"
            )
        if not (np.isfinite(K).all() and np.isfinite(h).all()):
            _check_finite(K, "Canonical.K")
            _check_finite(h, "Canonical.h")
        object.__setattr__(self, "K", _readonly(_symmetrized(K)))
        object.__setattr__(self, "h", _readonly(h))

    @classmethod
    def from_moments(cls, mu: np.ndarray, Sigma: np.ndarray) -> Canonical:
        """Canonical form of ``N(mu, Sigma)`` (Cholesky; ``Sigma`` must be PD)."""
        mu = np.asarray(mu, dtype=float)
        Sigma = _as_square(Sigma, "Canonical.from_moments: Sigma")
        if Sigma.ndim != 2 or mu.shape != (Sigma.shape[0],):
            raise ValueError(
                f"Canonical.from_moments needs mu (n,) and Sigma (n, n), got {mu.shape}, "
                f"{Sigma.shape}"
            )
        if mu.size == 0:
            return cls(np.zeros((0, 0)), np.zeros(0))
        lower = cholesky(Sigma, "Canonical.from_moments covariance")  # checked: finite
        K = cho_solve_finite(lower, np.eye(mu.size))
        if np.isfinite(mu).all():
            h = cho_solve_finite(lower, mu)
        else:  # scipy's finiteness check raises its error
            h = scipy.linalg.cho_solve((lower, True), mu)
        return cls(K, h)

    @classmethod
    def zeros(cls, dim: int) -> Canonical:
        """``dim`` variables without any information (``K = 0``, ``h = 0``)."""
        return cls(np.zeros((dim, dim)), np.zeros(dim))

    @property
    def dim(self) -> int:
        """Number of variables ``n``."""
        return int(self.h.shape[0])

    def to_moments(self) -> tuple[np.ndarray, np.ndarray]:
        """``(mu, Sigma)`` by Cholesky solves.

        Raises:
            NotPositiveDefiniteError: ``K`` is singular (some direction has no information).
        """
        if self.dim == 0:
            return np.zeros(0), np.zeros((0, 0))
        factor = cholesky(self.K, "Canonical information matrix K")
        Sigma = symmetrize(cho_solve_finite(factor, np.eye(self.dim)))
        mu = cho_solve_finite(factor, self.h)  # K and h are finite (checked on construction)
        return mu, Sigma

    def marginalize(self, keep: Sequence[int] | np.ndarray) -> Canonical:
        """Marginal over the variables ``keep`` (in the given order), by Schur complement.

        ``K' = K_kk - K_km K_mm^-1 K_mk``, ``h' = h_k - K_km K_mm^-1 h_m`` with ``m`` the
        marginalised rest. Keeping everything (in any order) is a permutation; keeping
        nothing gives a 0-dimensional Canonical. A singular ``K_mm`` is allowed when
        ``K_mk`` and ``h_m`` lie in its range (e.g. marginalising variables that carry no
        information); otherwise the integral diverges and NotPositiveDefiniteError is
        raised.
        """
        k, kept = _index_mask(keep, self.dim, "Canonical.marginalize")
        return self._marginal(k, np.flatnonzero(~kept))

    def _marginal(self, k: np.ndarray, m: np.ndarray) -> Canonical:
        """:meth:`marginalize` onto the valid indices ``k``; ``m``: the others, ascending."""
        K_kk = self.K[k[:, None], k]  # np.ix_(k, k) without its overhead
        h_k = self.h[k]
        if m.size == 0:
            return Canonical(K_kk, h_k)
        K_mm = self.K[m[:, None], m]
        rhs = np.empty((m.size, k.size + 1))  # [K_mk, h_m]
        rhs[:, :-1] = self.K[m[:, None], k]
        rhs[:, -1] = self.h[m]
        solution = _solve_psd(K_mm, rhs, "Canonical.marginalize block K_mm")
        K_km = self.K[k[:, None], m]
        correction = K_km @ solution
        return Canonical(K_kk - correction[:, :-1], h_k - correction[:, -1])

    def condition(self, idx: Sequence[int] | np.ndarray, values: np.ndarray) -> Canonical:
        """Conditional over the remaining variables (original order) given ``x[idx] = values``.

        ``K' = K_rr``, ``h' = h_r - K_ri values``.
        """
        i, given = _index_mask(idx, self.dim, "Canonical.condition")
        values = np.asarray(values, dtype=float).reshape(-1)
        if values.shape != i.shape:
            raise ValueError(
                f"Canonical.condition: {i.size} indices but {values.size} values given"
            )
        _check_finite(values, "Canonical.condition values")
        r = np.flatnonzero(~given)
        return Canonical(self.K[r[:, None], r], self.h[r] - self.K[r[:, None], i] @ values)

    def transform(self, F: np.ndarray, offset: np.ndarray | None = None) -> Canonical:
        """Express the density in a new state ``x_new`` with ``x_old = F x_new + offset``.

        ``K' = F^T K F`` and ``h' = F^T (h - K offset)``; ``F`` has shape
        ``(old_dim, new_dim)`` (e.g. a 0/1 placement matrix, SPEC section 9).
        """
        F = np.asarray(F, dtype=float)
        if F.ndim != 2 or F.shape[0] != self.dim:
            raise ValueError(
                f"Canonical.transform: F must have shape (old_dim={self.dim}, new_dim), got "
                f"{F.shape}"
            )
        h = self.h
        if offset is not None:
            offset = np.asarray(offset, dtype=float)
            if offset.shape != (self.dim,):
                raise ValueError(
                    f"Canonical.transform: offset must have shape ({self.dim},), got {offset.shape}"
                )
            h = h - self.K @ offset
        return Canonical(F.T @ self.K @ F, F.T @ h)

    def extend(self, n_new: int) -> Canonical:
        """Append ``n_new`` variables with zero information (zero rows/columns of ``K``)."""
        if int(n_new) != n_new or n_new < 0:
            raise ValueError(f"Canonical.extend: n_new must be an integer >= 0, got {n_new!r}")
        n_new = int(n_new)
        K = np.zeros((self.dim + n_new, self.dim + n_new))
        K[: self.dim, : self.dim] = self.K
        return Canonical(K, np.concatenate([self.h, np.zeros(n_new)]))

    def __add__(self, other: object) -> Canonical:
        """Product of two Gaussians over the same variables: add ``K`` and ``h``."""
        if not isinstance(other, Canonical):
            return NotImplemented
        if other.dim != self.dim:
            raise ValueError(f"Canonical.__add__: dimensions differ ({self.dim} vs {other.dim})")
        return Canonical(self.K + other.K, self.h + other.h)

    def __repr__(self) -> str:
        return f"Canonical(dim={self.dim}, K={self.K.tolist()}, h={self.h.tolist()})"


def _solve_psd(A: np.ndarray, B: np.ndarray, name: str) -> np.ndarray:
    """Solve ``A X = B`` for a symmetric PSD ``A`` (Cholesky, else a checked pseudo-inverse).

    The pseudo-inverse path requires the columns of ``B`` to lie in the range of ``A``
    (relative residual below ``1e4 eps``), otherwise raises NotPositiveDefiniteError.
    """
    try:
        return cho_solve_finite(np.linalg.cholesky(A), B)  # blocks of a finite Canonical
    except np.linalg.LinAlgError:
        pass
    eigenvalues, eigenvectors = np.linalg.eigh(A)
    scale = max(float(np.max(np.abs(eigenvalues))), 0.0)
    tolerance = A.shape[0] * _PSD_EPS_MULTIPLE * _EPS * scale
    if np.any(eigenvalues < -tolerance):
        raise NotPositiveDefiniteError(name, float(np.min(eigenvalues)), "indefinite")
    positive = eigenvalues > tolerance
    V = eigenvectors[:, positive]
    projected = V.T @ B
    residual = B - V @ projected
    b_scale = max(float(np.max(np.abs(B))), 1.0) if B.size else 1.0
    if np.any(np.abs(residual) > _RANGE_EPS_MULTIPLE * _EPS * b_scale):
        raise NotPositiveDefiniteError(
            name,
            float(np.min(eigenvalues)),
            "singular, and the marginalised variables are coupled to the kept ones (or "
            "have non-zero h) along a direction without information: the marginal is "
            "improper",
        )
    return V @ (projected / eigenvalues[positive][:, None])
