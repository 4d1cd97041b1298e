"""Range-error likelihoods of beams against landmark lines and the detection test.

SPEC.md sections 4, 6 and 8 (thesis 3.2.15-3.2.21, 3.2.38-3.2.43, 3.2.56-3.2.61).

Frames and units: vertices, positions and poses are in the world frame [m]; the pose is
that of the lidar, ``[x, y, theta]`` ([m], [m], [rad]), and is treated as known here.
Bearings ``phi`` [rad] are relative to the lidar heading; ranges [m]. A beam's *range
error* is ``r_err = r - r_exp``, the measured range minus the range at which the beam
meets the (infinite) line through the two vertices of its line; positive errors lie
behind the line as seen from the lidar.

Everything is vectorised over beams: one call handles all beams of a scan, and the
Gaussian propagation of the range error runs as one batched call (13 sigma points per
beam for the unscented transform).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING, NamedTuple

import numpy as np
from scipy import special

from vslam_gym.slam.config import ModelConfig
from vslam_gym.slam.geometry import stack_last

if TYPE_CHECKING:
    from vslam_gym.slam.gaussian import Linearization

__all__ = [
    "detection_accepts",
    "detection_statistics",
    "expected_range",
    "exponential_rate",
    "generalized_mahalanobis_sq",
    "line_loglik",
    "object_loglik",
    "range_error_distribution",
    "range_error_jacobian",
    "set_loglik",
    "trimmed",
    "unknown_loglik",
]

# Dimension of the per-beam input of the range error: [r, phi, v_a (2), v_b (2)].
_ERROR_INPUT_DIM = 6
# Bisection for the mode of the line density: halving the bracket this many times takes
# it from its initial width down to the float resolution of that width.
_BISECTION_ITERATIONS = np.finfo(float).nmant + 1
# The bisection stops once the mode is known to this many standard deviations of the
# range error (d_GM^2 then changes by about its square, 1e-12).
_MODE_TOLERANCE = 1e-6
# Doublings of the bracket allowed before giving up (the mode of an exponentially
# modified Gaussian lies within about sqrt(2 log(1 / (lam s))) s of 0, which stays
# below 40 s for every representable lam s; 64 doublings is far beyond that).
_MAX_BRACKET_DOUBLINGS = 64
# Relative tolerance of the symmetry check of the vertex covariances (relative to the
# largest diagonal element of each block).
_SYMMETRY_RTOL = 1e-9
_LOG_2PI = float(np.log(2.0 * np.pi))
_SQRT_2_OVER_PI = float(np.sqrt(2.0 / np.pi))
_SQRT_2 = float(np.sqrt(2.0))


# --------------------------------------------------------------------------- validation


def _finite(name: str, value: object) -> np.ndarray:
    """``value`` as a float array; raise ``ValueError`` naming ``name`` if not all finite."""
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name} must be numeric, got {value!r}") from exc
    if not np.isfinite(arr).all():
        raise ValueError(f"{name} must be finite, got non-finite values in {arr!r}")
    return arr


def _positive(name: str, value: object) -> np.ndarray:
    """``value`` as a finite float array with every element > 0."""
    arr = _finite(name, value)
    if np.any(arr <= 0.0):
        raise ValueError(f"{name} must be > 0, got {arr!r}")
    return arr


def _probability(name: str, value: object) -> np.ndarray:
    """``value`` as a finite float array with every element in ``[0, 1]``."""
    arr = _finite(name, value)
    if np.any((arr < 0.0) | (arr > 1.0)):
        raise ValueError(f"{name} must lie in [0, 1], got {arr!r}")
    return arr


def _broadcast(**arrays: np.ndarray) -> list[np.ndarray]:
    """Broadcast the arrays together; raise ``ValueError`` naming them if impossible."""
    try:
        return list(np.broadcast_arrays(*arrays.values()))
    except ValueError as exc:
        shapes = ", ".join(f"{k} {np.shape(v)}" for k, v in arrays.items())
        raise ValueError(f"shapes do not broadcast: {shapes}") from exc


def _check_last_dim(name: str, arr: np.ndarray, size: int) -> None:
    if arr.ndim == 0 or arr.shape[-1] != size:
        raise ValueError(f"{name} must have shape (..., {size}), got {arr.shape}")


def _check_symmetric_cov(name: str, cov: np.ndarray) -> None:
    """Covariance blocks (..., k, k): symmetric and with a non-negative diagonal."""
    diag = np.diagonal(cov, axis1=-2, axis2=-1)
    if np.any(diag < 0.0):
        raise ValueError(f"{name} has negative variances on its diagonal: {diag!r}")
    scale = np.max(np.abs(diag), axis=-1, keepdims=True)[..., None]
    if np.any(np.abs(cov - np.swapaxes(cov, -1, -2)) > _SYMMETRY_RTOL * scale):
        raise ValueError(f"{name} must be symmetric")


# ------------------------------------------------------------------------ expected range


def _cross(u_x: np.ndarray, u_y: np.ndarray, w_x: np.ndarray, w_y: np.ndarray) -> np.ndarray:
    return u_x * w_y - u_y * w_x


def _expected_range_parts(
    bearings: np.ndarray, v_a: np.ndarray, v_b: np.ndarray, pose: np.ndarray
) -> tuple[np.ndarray, ...]:
    """Numerator, denominator and the pieces the Jacobian needs.

    The thesis's beam-frame expression ``v'_ax - v'_ay dv'_x / dv'_y`` with
    ``v' = R_i (v_a - x_pos)``, ``dv' = R_i (v_a - v_b)`` equals, because the 2-D cross
    product is invariant under rotation, ``cross(v_a - x_pos, dv) / cross(e_i, dv)``
    with ``dv = v_a - v_b`` and ``e_i = [cos(theta + phi_i), sin(theta + phi_i)]``.
    """
    angle = pose[..., 2] + bearings
    cos_a, sin_a = np.cos(angle), np.sin(angle)
    ax, ay = v_a[..., 0] - pose[..., 0], v_a[..., 1] - pose[..., 1]
    dvx, dvy = v_a[..., 0] - v_b[..., 0], v_a[..., 1] - v_b[..., 1]
    numerator = _cross(ax, ay, dvx, dvy)
    denominator = _cross(cos_a, sin_a, dvx, dvy)
    return numerator, denominator, cos_a, sin_a, ax, ay, dvx, dvy


def _divide(numerator: np.ndarray, denominator: np.ndarray) -> np.ndarray:
    with np.errstate(divide="ignore", invalid="ignore"):
        return numerator / denominator


def expected_range(
    bearings: np.ndarray, v_a: np.ndarray, v_b: np.ndarray, pose: np.ndarray
) -> np.ndarray:
    """Range at which each beam meets the infinite line through ``v_a`` and ``v_b``.

    SPEC section 4 (thesis 3.2.15-3.2.17): in the frame of beam ``i`` (x-axis along the
    beam, rotation ``R_i`` by ``-(theta + phi_i)``),
    ``r_exp = v'_ax - v'_ay dv'_x / dv'_y``.

    Args:
        bearings: beam bearings ``phi`` [rad] relative to the lidar heading, shape (...).
        v_a: first vertex of the line, world frame [m], shape (..., 2).
        v_b: second vertex of the line, world frame [m], shape (..., 2).
        pose: lidar pose ``[x, y, theta]`` in the world frame ([m], [m], [rad]),
            shape (..., 3). All leading dimensions broadcast together.

    Returns:
        Expected ranges [m], the broadcast leading shape. Signed: negative when the
        line crosses the beam's backward extension. Where the beam is exactly parallel
        to the line there is no intersection and the result is ``+-inf`` (``nan`` if the
        line also passes through the lidar); no warning is issued.

    Raises:
        ValueError: non-finite input or wrong trailing dimensions.
    """
    bearings = _finite("bearings", bearings)
    v_a = _finite("v_a", v_a)
    v_b = _finite("v_b", v_b)
    pose = _finite("pose", pose)
    _check_last_dim("v_a", v_a, 2)
    _check_last_dim("v_b", v_b, 2)
    _check_last_dim("pose", pose, 3)
    _broadcast(bearings=bearings, v_a=v_a[..., 0], v_b=v_b[..., 0], pose=pose[..., 0])
    numerator, denominator, *_ = _expected_range_parts(bearings, v_a, v_b, pose)
    return _divide(numerator, denominator)


# --------------------------------------------------------------- range-error distribution


def _range_error(inputs: np.ndarray, pose: np.ndarray) -> np.ndarray:
    """``r_err`` of stacked inputs ``[r, phi, v_ax, v_ay, v_bx, v_by]`` (..., 6) -> (..., 1)."""
    numerator, denominator, *_ = _expected_range_parts(
        inputs[..., 1], inputs[..., 2:4], inputs[..., 4:6], pose
    )
    return (inputs[..., 0] - _divide(numerator, denominator))[..., None]


def range_error_jacobian(inputs: np.ndarray, pose: np.ndarray) -> np.ndarray:
    """Analytic Jacobian of ``r_err`` w.r.t. ``[r, phi, v_ax, v_ay, v_bx, v_by]``.

    With ``N = cross(v_a - x_pos, dv)``, ``D = cross(e, dv)``, ``dv = v_a - v_b`` and
    ``r_exp = N / D``: ``d r_exp / d phi = N (e . dv) / D^2`` and
    ``d r_exp / d v = (dN/dv - r_exp dD/dv) / D``; ``d r_err / d r = 1``.

    Args:
        inputs: stacked beam measurement and line vertices, shape (..., 6); ranges [m],
            bearings [rad], vertices in the world frame [m].
        pose: lidar pose ``[x, y, theta]`` (world frame), shape (..., 3) broadcasting
            with the leading dimensions of ``inputs``.

    Returns:
        Jacobian, shape (..., 1, 6) (one output row).
    """
    return range_error_jacobian_rows(inputs, pose)[0][..., None, :]


def range_error_jacobian_rows(
    inputs: np.ndarray, pose: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`range_error_jacobian` without its output axis, and the expected ranges.

    Returns:
        The Jacobian rows ``(..., 6)`` (C-contiguous) and ``r_exp`` [m] ``(...)``, the
        value :func:`expected_range` gives for the same beams and lines (computed on
        the way; unchecked: ``+-inf`` or ``nan`` where a beam is parallel to its line).
    """
    inputs = np.asarray(inputs, dtype=float)
    pose = np.asarray(pose, dtype=float)
    v_b = inputs[..., 4:6]
    numerator, denominator, cos_a, sin_a, ax, ay, dvx, dvy = _expected_range_parts(
        inputs[..., 1], inputs[..., 2:4], v_b, pose
    )
    r_exp = _divide(numerator, denominator)
    # dN/d[v_ax, v_ay, v_bx, v_by]: N = cross(v_b - x_pos, v_a - x_pos).
    bx, by = v_b[..., 0] - pose[..., 0], v_b[..., 1] - pose[..., 1]
    dn = stack_last(-by, bx, ay, -ax)
    # dD/d[v_ax, v_ay, v_bx, v_by]: D = cos(a) dv_y - sin(a) dv_x.
    dd = stack_last(-sin_a, cos_a, sin_a, -cos_a)
    jac = np.empty((*r_exp.shape, _ERROR_INPUT_DIM))
    jac[..., 0] = 1.0
    with np.errstate(divide="ignore", invalid="ignore"):
        d_phi = numerator * (cos_a * dvx + sin_a * dvy) / denominator**2
        np.negative(d_phi, out=jac[..., 1])
        np.negative((dn - r_exp[..., None] * dd) / denominator[..., None], out=jac[..., 2:])
    return jac, r_exp


def range_error_distribution(
    ranges: np.ndarray,
    bearings: np.ndarray,
    Q: np.ndarray,  # noqa: N803 - the thesis's name
    pose: np.ndarray,
    mu_vv: np.ndarray,
    Sigma_vv: np.ndarray,  # noqa: N803 - the thesis's name
    linearization: Linearization,
    *,
    jacobian: bool = True,
) -> tuple[np.ndarray, np.ndarray]:
    """Gaussian of the range error of each beam against its line (thesis 3.2.19).

    Per beam ``i``, ``N([r_i, phi_i, v_a, v_b], blockdiag(Q, Sigma_vv[i]))`` is mapped
    through ``r_err = r_i - r_exp(phi_i, v_a, v_b)`` by ``linearization`` in one batched
    call over the beams (the pose is fixed, not uncertain, here).

    Args:
        ranges: measured ranges ``r_i`` [m], shape (m,).
        bearings: beam bearings ``phi_i`` [rad] relative to the lidar heading, shape (m,).
        Q: measurement covariance of ``[r, phi]`` ([m^2], [rad^2]), shape (2, 2).
        pose: lidar pose ``[x, y, theta]`` in the world frame, shape (3,).
        mu_vv: the two vertices ``[v_ax, v_ay, v_bx, v_by]`` of beam ``i``'s line, world
            frame [m], shape (m, 4).
        Sigma_vv: their joint covariance [m^2], shape (m, 4, 4); symmetric positive
            semi-definite (an artificial vertex at the lidar may be degenerate).
        linearization: how to propagate the Gaussian (unscented or first order).
        jacobian: pass the analytic Jacobian :func:`range_error_jacobian` to the
            linearisation (used by first-order propagation, ignored by the unscented
            transform); ``False`` lets the linearisation find its own.

    Returns:
        ``(mu_err, var_err)``: mean [m] and variance [m^2] of each beam's range error,
        shapes (m,) and (m,).

    Raises:
        ValueError: mismatched shapes, non-finite input, a ``Q`` that is not symmetric
            with positive variances, or a ``Sigma_vv`` that is not symmetric with
            non-negative variances.
    """
    ranges = _finite("ranges", ranges)
    bearings = _finite("bearings", bearings)
    Q = _finite("Q", Q)  # noqa: N806
    pose = _finite("pose", pose)
    mu_vv = _finite("mu_vv", mu_vv)
    Sigma_vv = _finite("Sigma_vv", Sigma_vv)  # noqa: N806
    if ranges.ndim != 1:
        raise ValueError(f"ranges must have shape (m,), got {ranges.shape}")
    m = ranges.shape[0]
    if bearings.shape != (m,):
        raise ValueError(f"bearings must have shape ({m},) like ranges, got {bearings.shape}")
    if Q.shape != (2, 2):
        raise ValueError(f"Q must have shape (2, 2), got {Q.shape}")
    if np.any(np.diag(Q) <= 0.0):
        raise ValueError(f"Q must have positive variances on its diagonal, got {Q!r}")
    _check_symmetric_cov("Q", Q)
    if pose.shape != (3,):
        raise ValueError(f"pose must have shape (3,), got {pose.shape}")
    if mu_vv.shape != (m, 4):
        raise ValueError(f"mu_vv must have shape ({m}, 4), got {mu_vv.shape}")
    if Sigma_vv.shape != (m, 4, 4):
        raise ValueError(f"Sigma_vv must have shape ({m}, 4, 4), got {Sigma_vv.shape}")
    _check_symmetric_cov("Sigma_vv", Sigma_vv)

    mu = np.concatenate([ranges[:, None], bearings[:, None], mu_vv], axis=1)
    sigma = np.zeros((m, _ERROR_INPUT_DIM, _ERROR_INPUT_DIM))
    sigma[:, :2, :2] = Q
    sigma[:, 2:, 2:] = Sigma_vv

    def f(points: np.ndarray) -> np.ndarray:
        return _range_error(points, pose)

    jac: Callable[[np.ndarray], np.ndarray] | None = None
    if jacobian:

        def jac(points: np.ndarray) -> np.ndarray:
            return range_error_jacobian(points, pose)

    mu_y, sigma_y = linearization.propagate(f, mu, sigma, jacobian=jac)
    mu_err = np.asarray(mu_y, dtype=float).reshape(m)
    var_err = np.asarray(sigma_y, dtype=float).reshape(m)
    return mu_err, var_err


# ---------------------------------------------------------------------- log-likelihoods


def object_loglik(mu_err: np.ndarray, var_err: np.ndarray) -> np.ndarray:
    """Log-likelihood of beams on object lines (thesis 3.2.20).

    ``log p = -0.5 (log(2 pi s^2) + mu^2 / s^2)``: the density of the range error
    ``N(mu_err, s^2)`` at 0.

    Args:
        mu_err: mean range errors [m], any shape.
        var_err: their variances ``s^2`` [m^2], broadcasting with ``mu_err``; > 0.

    Returns:
        Log-likelihoods [log 1/m], the broadcast shape.

    Raises:
        ValueError: non-finite input, non-positive variance or shapes that do not
            broadcast.
    """
    mu, var = _broadcast(mu_err=_finite("mu_err", mu_err), var_err=_positive("var_err", var_err))
    return object_loglik_unchecked(mu, var)


def object_loglik_unchecked(mu_err: np.ndarray, var_err: np.ndarray) -> np.ndarray:
    """:func:`object_loglik` of validated arrays of one shape (hot path, nothing checked)."""
    return -0.5 * (np.log(2.0 * np.pi * var_err) + mu_err**2 / var_err)


def exponential_rate(ranges: np.ndarray, max_range: float) -> float:
    """Rate ``lambda`` [1/m] of the exponential prior over ranges (thesis 3.2.39).

    Maximum-likelihood estimate for an exponential cut off at ``r_max``:
    ``lambda = n_z / (n_z rbar + n_r r_max)`` with ``n_z`` returns of mean ``rbar`` and
    ``n_r`` no-return beams (readings ``>= max_range``, ``+inf`` included).

    With no return at all (``n_z = 0``) the maximum-likelihood rate is 0, which would
    make the unknown-line density vanish. We return ``1 / (n_r r_max)`` instead: the
    rate at which one return would have been expected over the free path observed
    (equivalently, the formula with ``n_z`` replaced by one return counted in the
    numerator only). It is positive and small, so unknown lines stay permissive.

    Args:
        ranges: the ranges [m] of one scan, any shape; no NaN, none negative.
        max_range: ``r_max`` [m], > 0.

    Returns:
        ``lambda`` [1/m], > 0.

    Raises:
        ValueError: empty scan, NaN or negative range, non-positive ``max_range``.
    """
    r_max = float(_positive("max_range", max_range))
    try:
        r = np.asarray(ranges, dtype=float).ravel()
    except (TypeError, ValueError) as exc:
        raise ValueError(f"ranges must be numeric, got {ranges!r}") from exc
    if r.size == 0:
        raise ValueError("ranges must hold at least one beam")
    if np.any(np.isnan(r)) or np.any(r < 0.0):
        raise ValueError(f"ranges must be >= 0 and not NaN, got {r!r}")
    returns = r[r < r_max]
    n_z = returns.size
    n_r = r.size - n_z
    if n_z == 0:
        return 1.0 / (n_r * r_max)
    return float(n_z / (returns.sum() + n_r * r_max))


def _log_emg(x: np.ndarray, var: np.ndarray, lam: np.ndarray) -> np.ndarray:
    """Log of ``lam exp(-lam x + lam^2 s^2 / 2) Phi((x - lam s^2) / s)`` (validated input).

    Two forms, each free of cancellation on its side of ``z = (x - lam s^2) / s = 0``:
    for ``z >= 0`` the direct form with ``log_ndtr(z)`` in ``[-log 2, 0]``; for
    ``z < 0``, ``Phi(z) = erfcx(-z / sqrt 2) exp(-z^2 / 2) / 2`` and the exponents
    combine exactly to ``-x^2 / (2 s^2)``. Both are evaluated everywhere and the one of
    each point's side kept (cheaper than masked assignments on these small arrays; the
    other may overflow, silently).
    """
    s = np.sqrt(var)
    z = (x - lam * var) / s
    with np.errstate(over="ignore", divide="ignore", invalid="ignore"):
        return np.where(
            z >= 0.0,
            np.log(lam) - lam * x + 0.5 * lam**2 * var + special.log_ndtr(z),
            np.log(lam) - 0.5 * x**2 / var + np.log(0.5 * special.erfcx(z / -_SQRT_2)),
        )


def _dlog_emg(x: np.ndarray, var: np.ndarray, lam: np.ndarray) -> np.ndarray:
    """Return ``d/dx`` of :func:`_log_emg`: ``-lam + phi(z) / (s Phi(z))``.

    Both forms of the tail evaluated everywhere, each point's kept (as there).
    """
    s = np.sqrt(var)
    z = (x - lam * var) / s
    with np.errstate(over="ignore", divide="ignore", invalid="ignore"):
        mills = np.where(
            z >= 0.0,
            np.exp(-0.5 * z**2 - 0.5 * _LOG_2PI - special.log_ndtr(z)),
            _SQRT_2_OVER_PI / special.erfcx(z / -_SQRT_2),
        )
    return -lam + mills / s


def unknown_loglik(x: np.ndarray, var: np.ndarray, lam: np.ndarray | float) -> np.ndarray:
    """Log-density of the range error on an unknown line (thesis 3.2.40-3.2.42).

    The exponentially modified Gaussian (exponential prior of rate ``lam`` behind the
    line convolved with the Gaussian range error)
    ``p_unk(x) = (lam / 2) exp(-lam x + lam^2 s^2 / 2) (1 - erf(-(x - lam s^2) / sqrt(2 s^2)))
    = lam exp(-lam x + lam^2 s^2 / 2) Phi((x - lam s^2) / s)``,
    evaluated in log space: finite for every finite input (e.g. ``x = -50 s`` gives
    about ``-1250``).

    Args:
        x: range error means ``mu_err`` [m], any shape.
        var: their variances ``s^2`` [m^2], > 0, broadcasting with ``x``.
        lam: exponential rate [1/m], > 0, broadcasting with ``x``.

    Returns:
        ``log p_unk(x)`` [log 1/m], the broadcast shape.

    Raises:
        ValueError: non-finite input, non-positive ``var`` or ``lam``, shapes that do
            not broadcast.
    """
    x, var, lam = _broadcast(
        x=_finite("x", x), var=_positive("var", var), lam=_positive("lam", lam)
    )
    return _log_emg(x, var, lam)


def _line_parts(mu_err: object, var_err: object, u: object, lam: object) -> tuple[np.ndarray, ...]:
    x, var, u_arr, lam_arr = _broadcast(
        mu_err=_finite("mu_err", mu_err),
        var_err=_positive("var_err", var_err),
        u=_probability("u", u),
        lam=_positive("lam", lam),
    )
    with np.errstate(divide="ignore"):
        log_u, log_1mu = np.log(u_arr), np.log1p(-u_arr)
    return x, var, u_arr, lam_arr, log_u, log_1mu


def _relative_mixture_log(
    x: np.ndarray, var: np.ndarray, lam: np.ndarray, log_u: np.ndarray, log_1mu: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``g = log p(x) + 0.5 log(2 pi s^2)`` and the two weighted component logs.

    The Gaussian normaliser is factored out so that with ``u = 0`` the result is exactly
    ``-0.5 x^2 / s^2`` (``logaddexp(a, -inf) == a``).
    """
    gauss = log_1mu - 0.5 * (x**2 / var)
    unk = log_u + _log_emg(x, var, lam) + 0.5 * np.log(2.0 * np.pi * var)
    return np.logaddexp(gauss, unk), gauss, unk


def line_loglik(
    mu_err: np.ndarray, var_err: np.ndarray, u: np.ndarray | float, lam: np.ndarray | float
) -> np.ndarray:
    """Log-likelihood of beams on general lines (thesis 3.2.43).

    ``log((1 - u) N(x; 0, s^2) + u p_unk(x))`` via ``logaddexp``: ``u = 0`` gives
    :func:`object_loglik` and ``u = 1`` gives :func:`unknown_loglik` exactly.

    Args:
        mu_err: mean range errors ``x`` [m], any shape.
        var_err: their variances ``s^2`` [m^2], > 0.
        u: unknown probability of each beam's line, in ``[0, 1]``.
        lam: exponential rate [1/m] of the unknown-line density, > 0.
            All four broadcast together.

    Returns:
        Log-likelihoods [log 1/m], the broadcast shape.

    Raises:
        ValueError: non-finite input, non-positive ``var_err`` or ``lam``, ``u`` outside
            ``[0, 1]``, shapes that do not broadcast.
    """
    x, var, u_arr, lam_arr, _, _ = _line_parts(mu_err, var_err, u, lam)
    return line_loglik_unchecked(x, var, u_arr, lam_arr)


def line_loglik_unchecked(
    mu_err: np.ndarray, var_err: np.ndarray, u: np.ndarray, lam: np.ndarray
) -> np.ndarray:
    """:func:`line_loglik` of validated arrays of one shape (hot path, nothing checked).

    The caller guarantees finite ``mu_err``, ``var_err > 0``, ``u`` in ``[0, 1]`` and
    ``lam > 0``, all of the same shape (``lam`` may be a broadcast view).
    """
    with np.errstate(divide="ignore"):
        log_u, log_1mu = np.log(u), np.log1p(-u)
    g, _, _ = _relative_mixture_log(mu_err, var_err, lam, log_u, log_1mu)
    return g - 0.5 * np.log(2.0 * np.pi * var_err)


def set_loglik(
    mu_err: np.ndarray, var_err: np.ndarray, u: np.ndarray | float, lam: np.ndarray | float
) -> float:
    """Log-likelihood of a set of beams (thesis 3.2.21): the sum of :func:`line_loglik`.

    Each beam's ``(mu_err, var_err)`` is already computed against its corresponding
    line; ``u`` is that line's unknown probability (0 for object lines).

    Returns:
        The summed log-likelihood (0.0 for an empty set).
    """
    return float(np.sum(line_loglik(mu_err, var_err, u, lam)))


# ---------------------------------------------------------------------------- detection


def _mixture_slope(
    x: np.ndarray, var: np.ndarray, lam: np.ndarray, log_u: np.ndarray, log_1mu: np.ndarray
) -> np.ndarray:
    """``d log p / dx`` of the line density (same sign as ``dp/dx``)."""
    g, gauss, unk = _relative_mixture_log(x, var, lam, log_u, log_1mu)
    w_gauss = np.exp(gauss - g)
    w_unk = np.exp(unk - g)
    return w_gauss * (-x / var) + w_unk * _dlog_emg(x, var, lam)


class _ModeTerms(NamedTuple):
    """The ``x``-free parts of :func:`_mixture_derivatives`, per point (1-D arrays).

    Computed once per mode search (:func:`_density_mode`) instead of once per Newton
    step; each is the same expression the step evaluated, so the steps are unchanged.
    """

    var: np.ndarray  # s^2 [m^2]
    neg_var: np.ndarray  # -s^2 [m^2]
    s: np.ndarray  # s [m]
    lam_var: np.ndarray  # lam s^2 [m]
    neg_lam: np.ndarray  # -lam [1/m]
    half_lam2_var: np.ndarray  # 0.5 lam^2 s^2
    neg_inv_var: np.ndarray  # -1 / s^2 [1/m^2]
    log_1mu: np.ndarray  # log(1 - u)
    log_u_lam: np.ndarray  # log(u) + log(lam)
    half_log_2pi_var: np.ndarray  # 0.5 log(2 pi s^2)


def _mode_terms(
    var: np.ndarray, lam: np.ndarray, log_u: np.ndarray, log_1mu: np.ndarray
) -> _ModeTerms:
    """:class:`_ModeTerms` of points with variances ``var``, rates ``lam`` and log weights."""
    with np.errstate(divide="ignore"):
        return _ModeTerms(
            var=var,
            neg_var=-var,
            s=np.sqrt(var),
            lam_var=lam * var,
            neg_lam=-lam,
            half_lam2_var=0.5 * lam**2 * var,
            neg_inv_var=-1.0 / var,
            log_1mu=log_1mu,
            log_u_lam=log_u + np.log(lam),
            half_log_2pi_var=0.5 * np.log(2.0 * np.pi * var),
        )


def _mixture_derivatives(x: np.ndarray, t: _ModeTerms) -> tuple[np.ndarray, np.ndarray]:
    """First and second ``x``-derivatives of ``log p`` of the line density (Newton steps).

    One evaluation of the standard normal tail per point serves both. With
    ``z = (x - lam s^2) / s`` and the inverse Mills ratio ``M = phi(z) / Phi(z)``, the
    unknown-line log-density ``U`` has ``U' = -lam + M / s`` and ``U'' = -M (z + M) / s^2``,
    the Gaussian ``G' = -x / s^2``, ``G'' = -1 / s^2``; the mixture
    ``g = logaddexp(G, U)`` has ``g' = w_G G' + w_U U'`` and
    ``g'' = w_G G'' + w_U U'' + w_G w_U (G' - U')^2`` with the posterior weights ``w``.
    Both tail forms are evaluated everywhere and the cancellation-free one kept (as in
    :func:`_log_emg`), which avoids masked assignments on these small arrays. The
    caller ignores floating-point warnings (overflow and division by zero in the
    discarded forms; :func:`_density_mode`).
    """
    var = t.var
    z = (x - t.lam_var) / t.s
    log_phi_tail = special.log_ndtr(z)  # accurate for z >= 0
    erfcx_neg = special.erfcx(z / -_SQRT_2)  # accurate for z < 0
    pos = z >= 0.0
    x2 = x**2
    log_tail_part = np.where(
        pos,
        t.neg_lam * x + t.half_lam2_var + log_phi_tail,
        -0.5 * x2 / var + np.log(0.5 * erfcx_neg),
    )
    mills = np.where(
        pos,
        np.exp(-0.5 * z**2 - 0.5 * _LOG_2PI - log_phi_tail),
        _SQRT_2_OVER_PI / erfcx_neg,
    )
    gauss = t.log_1mu - 0.5 * (x2 / var)
    unk = t.log_u_lam + log_tail_part + t.half_log_2pi_var
    g = np.logaddexp(gauss, unk)
    w_gauss = np.exp(gauss - g)
    w_unk = np.exp(unk - g)
    d_gauss = x / t.neg_var  # -x / s^2 (a negation is exact either side)
    d_unk = t.neg_lam + mills / t.s
    slope = w_gauss * d_gauss + w_unk * d_unk
    curvature = (
        w_gauss * t.neg_inv_var
        - w_unk * (mills * (z + mills) / var)
        + w_gauss * w_unk * (d_gauss - d_unk) ** 2
    )
    return slope, curvature


def _density_mode(
    var: np.ndarray,
    lam: np.ndarray,
    log_u: np.ndarray,
    log_1mu: np.ndarray,
    bracket: float,
    groups: np.ndarray | None = None,
) -> np.ndarray:
    """Mode of the line density of each beam, vectorised (1-D).

    The mode is bracketed on the sign of ``dp/dx`` (the bracket doubled while the
    density still rises at its upper end), then found by Newton's method on
    ``d log p / dx`` safeguarded by the bracket: a step that leaves the bracket, or a
    point where ``log p`` is not concave, bisects instead, and every evaluation shrinks
    the bracket. It stops when every step is below ``_MODE_TOLERANCE`` standard
    deviations (Newton converges quadratically there, so the mode is known far better
    than that; d_GM^2 is flat at the mode, so an error of ``t`` sigma changes it by
    about ``t^2``), or after as many iterations as a plain bisection to that tolerance
    would take twice, keeping the last point.

    ``groups`` (optional, ``(n,)`` ints from 0): independent searches batched together.
    Each group stops on its own (its points are frozen once all of its steps are below
    the tolerance), so that every result equals that of a call with its group alone.
    """

    def rising(at: np.ndarray) -> np.ndarray:
        return _mixture_slope(at, var, lam, log_u, log_1mu) > 0.0

    sigma = np.sqrt(var)
    lo = np.zeros_like(var)
    hi = bracket * sigma
    for _ in range(_MAX_BRACKET_DOUBLINGS):
        up = rising(hi)
        if not np.any(up):
            break
        lo = np.where(up, hi, lo)
        hi = np.where(up, 2.0 * hi, hi)
    else:
        raise RuntimeError("generalized_mahalanobis_sq: could not bracket the mode")
    tolerance = _MODE_TOLERANCE * sigma
    x = lo.copy()
    running = None if groups is None else np.ones(x.size, dtype=bool)
    n_groups = 0 if groups is None else int(groups.max()) + 1
    terms = _mode_terms(var, lam, log_u, log_1mu)
    with np.errstate(over="ignore", divide="ignore", invalid="ignore"):
        for _ in range(2 * _BISECTION_ITERATIONS):
            slope, curvature = _mixture_derivatives(x, terms)
            up = slope > 0.0
            lo = np.where(up, x, lo)
            hi = np.where(up, hi, x)
            newton = x - slope / curvature
            inside = (curvature < 0.0) & (newton >= lo) & (newton <= hi)
            x_new = np.where(inside, newton, 0.5 * (lo + hi))
            big = ~(np.abs(x_new - x) <= tolerance)
            if running is None:
                x = x_new
                if not big.any():
                    break
                continue
            x = np.where(running, x_new, x)
            # A group whose running points all took a small step is done.
            unfinished = np.bincount(groups[running & big], minlength=n_groups) > 0
            running &= unfinished[groups]
            if not running.any():
                break
    return x


def generalized_mahalanobis_sq(
    mu_err: np.ndarray,
    var_err: np.ndarray,
    u: np.ndarray | float,
    lam: np.ndarray | float,
    bracket_sigma: float = ModelConfig.gm_mode_bracket_sigma,
) -> np.ndarray:
    """Squared generalised Mahalanobis distance of each beam (SPEC section 8 item 3).

    ``d_GM^2 = 2 (log p(x_mode) - log p(x))`` for the line density ``p`` of
    :func:`line_loglik`, ``x = mu_err``. With ``u = 0`` this is exactly ``x^2 / s^2``.

    The mode is found by a vectorised bisection on the sign of ``dp/dx`` over
    ``[0, bracket_sigma s]``; while ``dp/dx`` is still positive at a beam's upper end,
    that bracket is doubled (and its lower end moved up). The bisection halves the
    brackets until they are below 1e-6 standard deviations; beams with ``u = 0``
    skip it (their mode is exactly 0). Like the thesis, this assumes the density has a
    single maximum, at ``x >= 0``: true for ``u = 0`` and ``u = 1`` (both densities are
    log-concave); for ``0 < u < 1`` a grid search over ``lam s`` in ``[1e-9, 0.1]`` and
    ``u`` in ``[0.01, 1)`` found no second maximum, but it is not proven (a mixture of
    log-concave densities need not be unimodal); were there two, the bisection would
    return one of them. The result is clipped at 0 where round-off near the mode would
    make it negative.

    Args:
        mu_err: mean range errors [m], any shape.
        var_err: their variances [m^2], > 0.
        u: unknown probabilities in ``[0, 1]``.
        lam: exponential rate [1/m], > 0. All four broadcast together.
        bracket_sigma: initial upper end of the mode bracket, in standard deviations.

    Returns:
        ``d_GM^2`` (dimensionless, >= 0), the broadcast shape.

    Raises:
        ValueError: bad input as for :func:`line_loglik`, non-positive ``bracket_sigma``.
        RuntimeError: the mode could not be bracketed (cannot happen for valid input).
    """
    bracket = float(_positive("bracket_sigma", bracket_sigma))
    x, var, u_arr, lam_arr, _, _ = _line_parts(mu_err, var_err, u, lam)
    shape = x.shape
    d2 = generalized_mahalanobis_sq_unchecked(
        *(np.array(a, dtype=float).reshape(-1) for a in (x, var, u_arr, lam_arr)), bracket
    )
    return d2.reshape(shape)


def generalized_mahalanobis_sq_unchecked(
    x: np.ndarray,
    var: np.ndarray,
    u: np.ndarray,
    lam: np.ndarray,
    bracket: float,
    groups: np.ndarray | None = None,
) -> np.ndarray:
    """:func:`generalized_mahalanobis_sq` of validated 1-D arrays of equal length (hot path).

    The caller guarantees finite ``x``, ``var > 0``, ``u`` in ``[0, 1]``, ``lam > 0`` and
    ``bracket > 0``; nothing is checked. ``groups``: see :func:`_density_mode` (each
    group's result is that of a call with the group alone).
    """
    with np.errstate(divide="ignore"):
        log_u, log_1mu = np.log(u), np.log1p(-u)
    # Beams on object lines (u = 0) have their mode at exactly 0; search the others only.
    x_mode = np.zeros_like(x)
    active = np.flatnonzero(u > 0.0)
    if active.size:
        x_mode[active] = _density_mode(
            var[active],
            lam[active],
            log_u[active],
            log_1mu[active],
            bracket,
            None if groups is None else groups[active],
        )
    # Both points in one evaluation: the relative log-density at the mode and at x.
    n = x.size
    both = np.concatenate([x_mode, x])
    rel = _relative_mixture_log(
        both, *(np.concatenate([a, a]) for a in (var, lam, log_u, log_1mu))
    )[0]
    return np.maximum(2.0 * (rel[:n] - rel[n:]), 0.0)


def detection_statistics(d2: np.ndarray) -> tuple[float, float]:
    """Mean and population variance (``ddof = 0``) of the ``d_GM^2`` of a set of beams.

    Args:
        d2: squared generalised Mahalanobis distances, any shape, at least one; >= 0,
            ``+inf`` allowed (then both statistics are ``inf``).

    Returns:
        ``(mean, variance)``.

    Raises:
        ValueError: empty input, NaN or negative values.
    """
    try:
        arr = np.asarray(d2, dtype=float).ravel()
    except (TypeError, ValueError) as exc:
        raise ValueError(f"d2 must be numeric, got {d2!r}") from exc
    if arr.size == 0:
        raise ValueError("d2 must hold at least one value")
    if np.any(np.isnan(arr)) or np.any(arr < 0.0):
        raise ValueError(f"d2 must be >= 0 and not NaN, got {arr!r}")
    if not np.isfinite(arr).all():
        return float("inf"), float("inf")
    return float(np.mean(arr)), float(np.var(arr))


def trimmed(d2: np.ndarray, fraction: float) -> np.ndarray:
    """``d2`` without its ``floor(fraction * n)`` largest values (robust detection).

    One beam just past a model's end vertex, or an outlier, can make the population
    variance of the whole set explode; trimming a small fraction keeps the test on the
    bulk of the beams.
    """
    arr = np.asarray(d2, dtype=float).ravel()
    k = int(np.floor(fraction * arr.size))
    if k <= 0:
        return arr
    return np.partition(arr, arr.size - k - 1)[: arr.size - k]


def detection_accepts(d2: np.ndarray, config: ModelConfig) -> bool:
    """Whether a set of beams comes from the model (SPEC section 8 item 4, thesis 3.2.61).

    Accepts when the mean of ``d_GM^2`` is at most ``config.detection_mean_max`` and its
    population variance (``ddof = 0``) at most ``config.detection_var_max``.

    Args:
        d2: squared generalised Mahalanobis distances of the set's beams.
        config: model configuration holding the two thresholds.

    Returns:
        ``True`` when both statistics are within their thresholds.
    """
    mean, var = detection_statistics(d2)
    return bool(mean <= config.detection_mean_max and var <= config.detection_var_max)
