"""Detection: does a set of measurements come from this landmark model? (SPEC section 8).

Thesis 3.2.50-3.2.61, read as in ``notes/update_algorithms.md`` section 3. At a given
(estimated) lidar pose:

1. every vertex of the model is seen in polar coordinates ``[range, bearing]`` from the
   pose, its Gaussian propagated by the configured linearisation plus ``Q``
   (3.2.51-3.2.53), one batched call over the vertices;
2. the candidate lines of beam ``i`` are the front-facing lines whose bearing interval,
   widened by ``detection_gate_sigma`` standard deviations of the end-vertex bearings,
   contains ``phi_i`` (3.2.54); of those, the one under which the beam is most likely
   (:func:`~vslam_gym.slam.likelihood.line_loglik`, the mixture 3.2.43) is chosen
   (3.2.55). A beam without candidates goes to the first or the last line, whichever
   side of the model it lies on, so that a set that extends beyond the model is rejected;
3. per beam the squared generalised Mahalanobis distance ``d_GM^2`` of its range error
   (3.2.56-3.2.59); the set is accepted when the mean of ``d_GM^2`` is at most
   ``detection_mean_max`` and its population variance at most ``detection_var_max``
   (3.2.60-3.2.61).

Frames and units: vertices and the pose are in the world frame ([m], [m], [rad]); the
pose is that of the lidar and is treated as known; bearings are relative to the lidar
heading [rad], ranges in [m]. Lines are oriented: line ``j`` runs from vertex ``a`` to
vertex ``b`` and its observed free side is on the right of ``a -> b`` (the vertices of
every model are ordered left to right as seen when it was built). A line is
*front-facing* from a position ``p`` when ``p`` is on that free side,
``cross(v_a - p, v_b - p) < 0``; only front-facing lines can be candidates.

Where the thesis is silent (notes section 3.2, register R-12):

- bearings are compared relative to the beam and wrapped, and a line is a candidate only
  if ``delta_a - delta_b < pi`` (it does not pass behind the lidar); the gate
  half-widths are clamped to ``pi/2``;
- a (beam, line) pair whose directions are within ``arcsin(parallel_sin_min)`` of each
  other is not a candidate: the range error (3.2.15) divides by that sine;
- a vertex within ``detection_gate_sigma`` standard deviations of the lidar has no
  bearing (the artificial zero-range vertex seen from its own pose): its lines are
  radial and are never candidates;
- a beam without candidates on a closed polygon, or in a gap of a chain seen from
  behind, takes the front-facing line with the nearest end in bearing.

Everything is vectorised over beams and lines: one propagation over the vertices, one
over all (beam, line) pairs that pass the gate, and dense ``(n, n_lines)`` arrays for the
choice. With :class:`~vslam_gym.slam.gaussian.FirstOrderLinearization` both
propagations are evaluated in closed form (same result as its generic path).
:func:`detect_many` tests one set against several models (each at its own pose) in one
pass over ``(models, n, n_lines)`` arrays, with the same result per model as
:func:`detect`; the filter uses it for all candidates of a set.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from vslam_gym.slam.config import ModelConfig, SensorConfig
from vslam_gym.slam.gaussian import (
    FirstOrderLinearization,
    Linearization,
    make_linearization,
)
from vslam_gym.slam.geometry import TWO_PI, check_pose, stack_last, wrap_angle
from vslam_gym.slam.landmark import LandmarkModel
from vslam_gym.slam.likelihood import (
    exponential_rate,
    generalized_mahalanobis_sq_unchecked,
    line_loglik_unchecked,
    object_loglik_unchecked,
    range_error_distribution,
    range_error_jacobian_rows,
)
from vslam_gym.slam.scan import Scan

__all__ = [
    "BeamAssociation",
    "Detection",
    "ModelParts",
    "VertexBearings",
    "beam_line_correspondence",
    "beam_line_correspondences",
    "detect",
    "detect_many",
    "model_parts",
    "vertex_polar_distribution",
]

_HALF_PI = 0.5 * np.pi


@dataclass(frozen=True)
class BeamAssociation:
    """Beam-to-line correspondences of beams ``first..last`` of a scan (SPEC 8 items 1-3).

    All arrays have one entry per beam, in scan order (left to right).

    Attributes:
        line: ``(n,)`` int, index of the model line each beam is assigned to.
        gated: ``(n,)`` bool, True where the beam had at least one candidate line; False
            where it was assigned to the first or last line (or the nearest one) because
            none passed the gate.
        mu_err: ``(n,)`` mean range error ``r_i - r_exp`` [m] against the assigned line
            (positive: the return lies behind the line). ``nan`` where the beam is
            (nearly) parallel to its assigned line, so that no range error exists.
        var_err: ``(n,)`` its variance [m^2] (``nan`` where ``mu_err`` is).
        loglik: ``(n,)`` log-likelihood of each beam under its line, the mixture of
            thesis 3.2.43 [log 1/m] (``-inf`` where ``mu_err`` is ``nan``).
        u: ``(n,)`` unknown probability of the assigned line.
        d2: ``(n,)`` squared generalised Mahalanobis distance ``d_GM^2`` (``inf`` where
            ``mu_err`` is ``nan``; all ``nan`` when computed with ``distances=False``).
    """

    line: np.ndarray
    gated: np.ndarray
    mu_err: np.ndarray
    var_err: np.ndarray
    loglik: np.ndarray
    u: np.ndarray
    d2: np.ndarray

    @property
    def n(self) -> int:
        """Number of beams."""
        return int(self.line.size)


@dataclass(frozen=True)
class Detection:
    """Outcome of the detection test of a set of beams against one model (SPEC 8 item 4).

    Attributes:
        accepted: True when ``mean_d2 <= detection_mean_max`` and
            ``var_d2 <= detection_var_max``.
        association: the per-beam correspondences and distances.
        mean_d2: mean of ``d_GM^2`` over the beams (``inf`` if any beam has no range
            error).
        var_d2: its population variance (``ddof = 0``).
        loglik: the set log-likelihood (thesis 3.2.21 with the unknown-line mixtures),
            the sum of ``association.loglik`` [log 1/m^n]; for maximum-likelihood
            correspondence between accepted models.
    """

    accepted: bool
    association: BeamAssociation
    mean_d2: float
    var_d2: float
    loglik: float


@dataclass(frozen=True)
class VertexBearings:
    """Polar view of the model's vertices from a pose (thesis 3.2.51-3.2.53).

    Attributes:
        mean: ``(k, 2)`` means ``[range [m], bearing [rad]]``, bearing relative to the lidar
            heading in ``[-pi, pi)``.
        cov: ``(k, 2, 2)`` covariances of the vertex's polar coordinates plus ``Q``.
        near: ``(k,)`` bool, vertices within ``detection_gate_sigma`` standard deviations
            of the lidar position: their bearing is undefined (e.g. the artificial
            zero-range vertex seen from the pose it was built at). Their ``mean`` holds
            the range and the raw bearing and ``cov`` is ``Q`` only.
    """

    mean: np.ndarray
    cov: np.ndarray
    near: np.ndarray


# ------------------------------------------------------------------------ validation


def _check_index(name: str, value: object) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise ValueError(f"{name} must be an integer beam index, got {value!r}")
    return int(value)


def _check_segment(
    scan: Scan, first: object, last: object, returns: np.ndarray | None = None
) -> tuple[int, int]:
    """``(first, last)`` as ints, or a ``ValueError``; ``returns``: ``scan.returns`` if known."""
    if not isinstance(scan, Scan):
        raise ValueError(f"scan must be a Scan, got {type(scan).__name__}")
    first = _check_index("first", first)
    last = _check_index("last", last)
    if not 0 <= first < scan.n:
        raise ValueError(f"first = {first} is out of range for a scan of {scan.n} beams")
    if not 0 <= last < scan.n:
        raise ValueError(f"last = {last} is out of range for a scan of {scan.n} beams")
    if last < first:
        raise ValueError(f"segment beams must satisfy first <= last, got {first}..{last}")
    returns = (scan.returns if returns is None else returns)[first : last + 1]
    if not returns.all():
        bad = first + np.flatnonzero(~returns)
        raise ValueError(
            f"segment {first}..{last} includes no-return (max-range) beams {bad[:5].tolist()}"
        )
    return first, last


def _check_spans(
    scan: Scan, first: object, last: object, n_models: int
) -> tuple[np.ndarray, np.ndarray]:
    """Per-model ``(first, last)`` beam indices: one pair for all, or one per model."""
    if np.ndim(first) == 0 and np.ndim(last) == 0:
        f, l_ = _check_segment(scan, first, last)
        return np.full(n_models, f), np.full(n_models, l_)
    firsts = np.broadcast_to(np.asarray(first), (n_models,))
    lasts = np.broadcast_to(np.asarray(last), (n_models,))
    spans = list(zip(firsts.tolist(), lasts.tolist(), strict=True))
    returns = scan.returns if isinstance(scan, Scan) else None
    for f, l_ in dict.fromkeys(spans):  # each distinct set once (they repeat per candidate)
        _check_segment(scan, f, l_, returns)
    return np.array([f for f, _ in spans]), np.array([l_ for _, l_ in spans])


def _check_model(model: LandmarkModel) -> None:
    if not isinstance(model, LandmarkModel):
        raise ValueError(f"model must be a LandmarkModel, got {type(model).__name__}")
    if model.n_lines < 1:
        raise ValueError(f"model must have at least one line, got {model.n_vertices} vertices")
    if not (np.isfinite(model.mean).all() and np.isfinite(model.cov).all()):
        raise ValueError("model mean and covariance must be finite")


def _check_models(models: Sequence[LandmarkModel]) -> None:
    """:func:`_check_model` of every model (in order: the first failure is reported).

    The finite checks of all models at once when the models pass the others (the usual
    case); else model by model.
    """
    if (
        all(isinstance(m, LandmarkModel) and m.n_lines >= 1 for m in models)
        and np.isfinite(np.concatenate([a.ravel() for m in models for a in (m.mean, m.cov)])).all()
    ):
        return
    for m in models:
        _check_model(m)


# -------------------------------------------------------------- vertex polar Gaussians


def _polar_function(pose: np.ndarray, reference: np.ndarray):
    """``v (k, m, 2) -> [range, bearing] (k, m, 2)``; bearings unwrapped around ``reference``.

    ``reference`` ``(k, 1)`` is each vertex's mean bearing: sigma points straddling
    ``+-pi`` stay next to each other instead of being averaged across the cut.
    """

    def f(points: np.ndarray) -> np.ndarray:
        dx = points[..., 0] - pose[0]
        dy = points[..., 1] - pose[1]
        bearing = np.arctan2(dy, dx) - pose[2]
        return np.stack([np.hypot(dx, dy), reference + wrap_angle(bearing - reference)], -1)

    return f


def _polar_jacobian(dx: np.ndarray, dy: np.ndarray) -> np.ndarray:
    """``(..., 2, 2)`` Jacobian of ``[range, bearing]`` w.r.t. the vertex, offsets ``dx, dy``."""
    r2 = dx**2 + dy**2
    r = np.sqrt(r2)
    jac = np.empty((*r.shape, 2, 2))
    np.divide(dx, r, out=jac[..., 0, 0])
    np.divide(dy, r, out=jac[..., 0, 1])
    np.divide(-dy, r2, out=jac[..., 1, 0])
    np.divide(dx, r2, out=jac[..., 1, 1])
    return jac


def vertex_polar_distribution(
    model: LandmarkModel,
    pose: np.ndarray,
    sensor: SensorConfig,
    config: ModelConfig,
    linearization: Linearization,
) -> VertexBearings:
    """Range and bearing of every vertex seen from ``pose``, plus ``Q`` (3.2.51-3.2.53).

    One batched propagation over the vertices (each vertex's own ``2 x 2`` block; the
    cross-covariances between vertices are not needed here). A
    :class:`~vslam_gym.slam.gaussian.FirstOrderLinearization` is evaluated in closed
    form (``J Sigma J^T`` with the analytic polar Jacobian); any other linearisation
    goes through its ``propagate``.

    Args:
        model: the landmark model (world frame).
        pose: ``(3,)`` lidar pose ``[x, y, theta]`` (world frame).
        sensor: gives ``Q``.
        config: gives ``detection_gate_sigma`` (the ``near`` test).
        linearization: how the Gaussians are propagated.

    Returns:
        The polar means and covariances, and which vertices are too close to the lidar
        for a bearing.

    Raises:
        ValueError: a pose that is not 3 finite numbers, a model without lines or with
            non-finite entries.
    """
    _check_model(model)
    return _vertex_polar(model, check_pose(pose), sensor, config, linearization)


def _vertex_polar(
    model: LandmarkModel,
    pose: np.ndarray,
    sensor: SensorConfig,
    config: ModelConfig,
    linearization: Linearization,
) -> VertexBearings:
    """:func:`vertex_polar_distribution` without the input checks (hot path)."""
    k = model.n_vertices
    mean = model.mean
    blocks = model.vertex_blocks()
    dx = mean[:, 0] - pose[0]
    dy = mean[:, 1] - pose[1]
    r = np.hypot(dx, dy)
    raw_bearing = np.asarray(wrap_angle(np.arctan2(dy, dx) - pose[2]))
    # Largest eigenvalue of each symmetric 2x2 block, in closed form.
    sxx, syy, sxy = blocks[:, 0, 0], blocks[:, 1, 1], blocks[:, 0, 1]
    lam_max = 0.5 * (sxx + syy) + np.hypot(0.5 * (sxx - syy), sxy)
    near = r <= config.detection_gate_sigma * np.sqrt(np.maximum(lam_max, 0.0))

    polar_mean = np.stack([r, raw_bearing], axis=1)
    if isinstance(linearization, FirstOrderLinearization) and not np.any(near):
        jac = _polar_jacobian(dx, dy)
        polar_cov = jac @ blocks @ np.swapaxes(jac, -1, -2) + sensor.Q
        return VertexBearings(mean=polar_mean, cov=polar_cov, near=near)
    polar_cov = np.zeros((k, 2, 2))
    far = np.flatnonzero(~near)
    if far.size:
        if isinstance(linearization, FirstOrderLinearization):
            jac = _polar_jacobian(dx[far], dy[far])
            polar_cov[far] = jac @ blocks[far] @ np.swapaxes(jac, -1, -2)
        else:
            f = _polar_function(pose, raw_bearing[far, None])
            mu_p, cov_p = linearization.propagate(f, mean[far], blocks[far], check=False)
            polar_mean[far, 0] = mu_p[:, 0]
            polar_mean[far, 1] = wrap_angle(mu_p[:, 1])
            polar_cov[far] = cov_p
    polar_cov += sensor.Q
    return VertexBearings(mean=polar_mean, cov=polar_cov, near=near)


def _range_errors(
    ranges: np.ndarray,
    bearings: np.ndarray,
    Q: np.ndarray,  # noqa: N803 - the thesis's name
    pose: np.ndarray,
    mu_vv: np.ndarray,
    Sigma_vv: np.ndarray,  # noqa: N803 - the thesis's name
    linearization: Linearization,
) -> tuple[np.ndarray, np.ndarray]:
    """Range-error Gaussians of (beam, line) pairs (thesis 3.2.19).

    :func:`~vslam_gym.slam.likelihood.range_error_distribution`; for a
    :class:`~vslam_gym.slam.gaussian.FirstOrderLinearization` the same first-order
    result in closed form, ``mu = r - r_exp`` and ``var = J blockdiag(Q, Sigma_vv) J^T``
    with the analytic :func:`~vslam_gym.slam.likelihood.range_error_jacobian` (the
    inputs were validated by the caller, and ``var >= sigma_r^2 > 0``).
    """
    if not isinstance(linearization, FirstOrderLinearization):
        return range_error_distribution(ranges, bearings, Q, pose, mu_vv, Sigma_vv, linearization)
    inputs = np.concatenate([ranges[:, None], bearings[:, None], mu_vv], axis=1)
    jac, r_exp = range_error_jacobian_rows(inputs, pose)
    j_z, j_v = jac[:, :2], jac[:, 2:]
    var = np.sum((j_z @ Q) * j_z, axis=1) + (j_v[:, None, :] @ Sigma_vv @ j_v[:, :, None])[:, 0, 0]
    return ranges - r_exp, var


# --------------------------------------------------------------------- correspondence


def _line_loglik(mu: np.ndarray, var: np.ndarray, u: np.ndarray, lam: float) -> np.ndarray:
    """:func:`~vslam_gym.slam.likelihood.line_loglik` of (beam, line) pairs.

    Evaluated as :func:`~vslam_gym.slam.likelihood.object_loglik` where ``u = 0``
    (identical there, without the unknown-line density the mixture would evaluate and
    discard). One check of the range errors here instead of the library's per-call
    input checks (``u`` and ``lam`` were validated with the models and by the caller).
    """
    if not (np.isfinite(mu).all() and np.isfinite(var).all() and (var > 0.0).all()):
        raise ValueError("range errors must be finite with variances > 0")
    out = np.empty_like(mu)
    obj = u == 0.0
    if obj.any():
        out[obj] = object_loglik_unchecked(mu[obj], var[obj])
    if not obj.all():
        mixed = ~obj
        lam_arr = np.full(int(np.count_nonzero(mixed)), lam)
        out[mixed] = line_loglik_unchecked(mu[mixed], var[mixed], u[mixed], lam_arr)
    return out


def _generalized_mahalanobis_sq(
    mu: np.ndarray,
    var: np.ndarray,
    u: np.ndarray,
    lam: float,
    bracket_sigma: float,
    groups: np.ndarray | None = None,
) -> np.ndarray:
    """:func:`~vslam_gym.slam.likelihood.generalized_mahalanobis_sq` per beam.

    ``inf`` where the beam has no range error (``mu`` is ``nan``); ``mu^2 / var`` where
    ``u = 0``, which is what the library returns there (the mode is 0 exactly), without
    its per-call overhead; the library's mode search for the others.
    """
    d2 = np.full(mu.shape, np.inf)
    ok = np.isfinite(mu)
    obj = ok & (u == 0.0)
    d2[obj] = mu[obj] ** 2 / var[obj]
    mixed = ok & ~obj
    if np.any(mixed):
        if not bracket_sigma > 0.0:
            raise ValueError(f"gm_mode_bracket_sigma must be > 0, got {bracket_sigma!r}")
        # The caller validated every input (finite errors of positive variance here).
        d2[mixed] = generalized_mahalanobis_sq_unchecked(
            mu[mixed],
            var[mixed],
            u[mixed],
            np.full(int(mixed.sum()), lam),
            bracket_sigma,
            None if groups is None else groups[mixed],
        )
    return d2


def beam_line_correspondence(
    model: LandmarkModel,
    scan: Scan,
    first: int,
    last: int,
    pose: np.ndarray,
    sensor: SensorConfig,
    config: ModelConfig,
    linearization: Linearization,
    lam: float,
    *,
    distances: bool = True,
) -> BeamAssociation:
    """Assign each beam of ``first..last`` to a model line and score it (SPEC 8 items 1-3).

    Candidates of beam ``i`` are the front-facing lines ``(a, b)`` with (bearings
    relative to the beam, wrapped) ``delta_b <= g s_b``, ``delta_a >= -g s_a`` and
    ``delta_a - delta_b < pi`` (the last rejects segments passing behind the lidar),
    ``g = config.detection_gate_sigma``, ``s`` the vertex bearing standard deviations
    (3.2.52, clamped so that ``g s <= pi/2``), and whose direction is not within
    ``arcsin(config.parallel_sin_min)`` of the beam's (no range error exists on a line
    parallel to the beam). Lines with a vertex at the lidar position (radial lines) are
    never candidates. Among the candidates the beam takes the line of highest
    :func:`~vslam_gym.slam.likelihood.line_loglik`; a beam without candidates takes the
    first line if it lies left of the model, the last if right of it, else (closed
    polygon, or a chain seen from behind) the line with the nearest end in bearing.

    Args:
        model: the landmark model (world frame); at least one line.
        scan: the scan holding the beams (lidar frame).
        first: scan index of the set's first (leftmost) beam.
        last: scan index of its last (rightmost) beam, inclusive; every beam of
            ``first..last`` must have a return.
        pose: ``(3,)`` lidar pose ``[x, y, theta]`` (world frame) at which to test.
        sensor: sensor parameters (``Q``).
        config: gives ``detection_gate_sigma``, ``parallel_sin_min`` and
            ``gm_mode_bracket_sigma``.
        linearization: how Gaussians are propagated (vertex bearings and range errors).
        lam: rate [1/m] of the unknown-line range density, > 0 (usually
            :func:`~vslam_gym.slam.likelihood.exponential_rate` of the scan).
        distances: compute ``d_GM^2`` (the mode search of the unknown-line densities);
            when False, ``d2`` is all ``nan`` (for callers that use the assignment only,
            e.g. a model update).

    Returns:
        The per-beam association (see :class:`BeamAssociation`).

    Raises:
        ValueError: segment indices out of range or not integers, no-return beams in the
            segment, a pose that is not 3 finite numbers, a model without lines or with
            non-finite entries, a non-positive ``lam``.
    """
    _check_model(model)
    first, last = _check_segment(scan, first, last)
    pose = check_pose(pose)
    return beam_line_correspondences(
        [model],
        scan,
        first,
        last,
        pose[None],
        sensor,
        config,
        linearization,
        lam,
        distances=distances,
    )[0]


def _check_lam(lam: object) -> float:
    lam = float(lam)
    if not (np.isfinite(lam) and lam > 0.0):
        raise ValueError(f"lam must be finite and > 0, got {lam!r}")
    return lam


def _check_poses(poses: object, n_models: int) -> np.ndarray:
    try:
        arr = np.array(poses, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"pose must be numeric [x, y, theta], got {poses!r}") from exc
    if arr.shape != (n_models, 3):
        raise ValueError(
            f"poses must have shape ({n_models}, 3) = one [x, y, theta] per model, got "
            f"shape {arr.shape}"
        )
    if not np.isfinite(arr).all():
        raise ValueError(f"pose must be finite, got {arr}")
    return arr


@dataclass(frozen=True)
class ModelParts:
    """Arrays of one model that the correspondence needs (see :func:`model_parts`).

    Attributes:
        blocks: ``(k, 2, 2)`` each vertex's own covariance [m^2].
        lines: ``(n_lines, 2)`` int, :meth:`LandmarkModel.line_vertices`.
        mu_vv: ``(n_lines, 4)`` and ``sigma_vv`` ``(n_lines, 4, 4)``:
            :meth:`LandmarkModel.line_blocks`.
    """

    blocks: np.ndarray
    lines: np.ndarray
    mu_vv: np.ndarray
    sigma_vv: np.ndarray


def model_parts(model: LandmarkModel) -> ModelParts:
    """The per-model arrays of :func:`beam_line_correspondences` (a cache for callers).

    They depend on the model's means and covariance only; a caller that tests the same
    model many times may compute them once and pass them in.
    """
    mu_vv, sigma_vv = model.line_blocks()
    return ModelParts(
        blocks=model.vertex_blocks(),
        lines=model.line_vertices(),
        mu_vv=mu_vv,
        sigma_vv=sigma_vv,
    )


class _PaddedModels:
    """Vertices and lines of ``C`` models padded to common sizes (batched correspondence).

    Vertex arrays are ``(C, K, ...)``, line arrays ``(C, L, ...)``; padding lines join
    padding vertices and are never candidates (``valid`` False).
    """

    def __init__(self, models: list[LandmarkModel], parts: list[ModelParts]) -> None:
        n_models = len(models)
        sizes = [(m.n_vertices, m.n_lines) for m in models]
        k = max(kc for kc, _ in sizes)
        self.n_lines = np.array([lc for _, lc in sizes])
        n_lines = int(self.n_lines.max())
        self.mean = np.zeros((n_models, k, 2))
        self.blocks = np.zeros((n_models, k, 2, 2))
        self.blocks[:, :, 0, 0] = self.blocks[:, :, 1, 1] = 1.0
        self.lines = np.zeros((n_models, n_lines, 2), dtype=int)
        self.valid = np.arange(n_lines) < self.n_lines[:, None]
        self.u = np.zeros((n_models, n_lines))
        self.mu_vv = np.zeros((n_models, n_lines, 4))
        self.sigma_vv = np.zeros((n_models, n_lines, 4, 4))
        self.closed = np.array([m.closed for m in models])
        for c, (m, p, (kc, lc)) in enumerate(zip(models, parts, sizes, strict=True)):
            self.mean[c, :kc] = m.mean
            self.blocks[c, :kc] = p.blocks
            self.lines[c, :lc] = p.lines
            self.u[c, :lc] = m.u
            self.mu_vv[c, :lc], self.sigma_vv[c, :lc] = p.mu_vv, p.sigma_vv


def _vertex_polar_many(
    padded: _PaddedModels,
    models: list[LandmarkModel],
    poses: np.ndarray,
    sensor: SensorConfig,
    config: ModelConfig,
    linearization: Linearization,
    q: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`_vertex_polar` of every model from its pose: means, covariances, ``near``.

    ``(C, K, 2)``, ``(C, K, 2, 2)``, ``(C, K)``; padding vertices are garbage. ``q``:
    ``sensor.Q`` (a property that builds the matrix; the caller has it).
    """
    if not isinstance(linearization, FirstOrderLinearization):
        k = padded.mean.shape[1]
        mean = np.zeros((len(models), k, 2))
        cov = np.tile(np.eye(2), (len(models), k, 1, 1))
        near = np.zeros((len(models), k), dtype=bool)
        for c, m in enumerate(models):
            vb = _vertex_polar(m, poses[c], sensor, config, linearization)
            kc = m.n_vertices
            mean[c, :kc], cov[c, :kc], near[c, :kc] = vb.mean, vb.cov, vb.near
        return mean, cov, near
    blocks = padded.blocks
    dx = padded.mean[:, :, 0] - poses[:, 0, None]
    dy = padded.mean[:, :, 1] - poses[:, 1, None]
    r = np.hypot(dx, dy)
    raw_bearing = np.asarray(wrap_angle(np.arctan2(dy, dx) - poses[:, 2, None]))
    # Largest eigenvalue of each symmetric 2x2 block, in closed form.
    sxx, syy, sxy = blocks[..., 0, 0], blocks[..., 1, 1], blocks[..., 0, 1]
    lam_max = 0.5 * (sxx + syy) + np.hypot(0.5 * (sxx - syy), sxy)
    near = r <= config.detection_gate_sigma * np.sqrt(np.maximum(lam_max, 0.0))
    polar_mean = stack_last(r, raw_bearing)
    with np.errstate(divide="ignore", invalid="ignore"):
        jac = _polar_jacobian(dx, dy)
        polar_cov = jac @ blocks @ np.swapaxes(jac, -1, -2)
    if near.any():  # no bearing: Q only (see _vertex_polar)
        polar_cov[near] = 0.0
    return polar_mean, polar_cov + q, near


def _range_errors_many(
    ranges: np.ndarray,
    bearings: np.ndarray,
    Q: np.ndarray,  # noqa: N803 - the thesis's name
    poses: np.ndarray,
    owner: np.ndarray,
    mu_vv: np.ndarray,
    Sigma_vv: np.ndarray,  # noqa: N803 - the thesis's name
    linearization: Linearization,
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`_range_errors` of (beam, line) pairs whose pose is ``poses[owner]``."""
    if not isinstance(linearization, FirstOrderLinearization):
        mu = np.empty(ranges.size)
        var = np.empty(ranges.size)
        for c in np.unique(owner):
            sel = owner == c
            mu[sel], var[sel] = _range_errors(
                ranges[sel], bearings[sel], Q, poses[c], mu_vv[sel], Sigma_vv[sel], linearization
            )
        return mu, var
    inputs = np.concatenate([ranges[:, None], bearings[:, None], mu_vv], axis=1)
    jac, r_exp = range_error_jacobian_rows(inputs, poses[owner])
    j_z, j_v = jac[:, :2], jac[:, 2:]
    var = np.sum((j_z @ Q) * j_z, axis=1) + (j_v[:, None, :] @ Sigma_vv @ j_v[:, :, None])[:, 0, 0]
    return ranges - r_exp, var


def _beam_offsets(phi: np.ndarray, beams: np.ndarray) -> np.ndarray:
    """``wrap_angle(phi[..., None, :] - beams[:, :, None])`` ``(..., C, n, L)`` [rad].

    ``phi`` ``(..., C, L)``: wrapped bearings (in ``[-pi, pi)``) of line ends per model;
    ``beams`` ``(C, n)``: beam bearings. With the beams in ``[-pi, pi]`` too (a scan's
    are), ``x = phi - beam + pi`` lies in ``[-pi, 3 pi]``, where wrap_angle's
    ``np.mod(x, 2 pi)`` is ``x``, ``x - 2 pi`` (exact, as is the remainder) or, for
    ``x < 0``, ``x + 2 pi`` (numpy's remainder adds the divisor): the same values without
    the float remainder, which is most of wrap_angle's time on these arrays.
    """
    x = phi[..., None, :] - beams[:, :, None]
    if not np.abs(beams).max() <= np.pi:
        return np.asarray(wrap_angle(x))
    x += np.pi
    below, above = x < 0.0, x >= TWO_PI
    np.add(x, TWO_PI, out=x, where=below)
    np.subtract(x, TWO_PI, out=x, where=above)
    x -= np.pi
    np.subtract(x, TWO_PI, out=x, where=x >= np.pi)  # as wrap_angle: pi maps to -pi
    return x


def beam_line_correspondences(
    models: list[LandmarkModel],
    scan: Scan,
    first: int | Sequence[int],
    last: int | Sequence[int],
    poses: np.ndarray,
    sensor: SensorConfig,
    config: ModelConfig,
    linearization: Linearization,
    lam: float,
    *,
    distances: bool = True,
    parts: list[ModelParts] | None = None,
) -> list[BeamAssociation]:
    """:func:`beam_line_correspondence` of one set of beams against several models.

    Model ``c`` is tested at ``poses[c]``. The models are padded to common sizes and
    processed together in ``(models, beams, lines)`` arrays (one propagation, one mode
    search for all), so that numpy's per-call overhead is paid once rather than once
    per model; each result equals that of :func:`beam_line_correspondence` for its
    model and pose.

    Args:
        models: the landmark models (world frame), at least one.
        first: the set's first beam, or per model the first beam of its set (then the
            sets are padded to the longest and each result has its own set's length) ...
        last: ... and its last beam (inclusive).
        poses: ``(len(models), 3)`` lidar poses ``[x, y, theta]`` (world frame).
        parts: optional :func:`model_parts` of each model (computed here when omitted);
            the caller must keep them in step with the models.
        (others): as :func:`beam_line_correspondence`.

    Returns:
        One :class:`BeamAssociation` per model, in order.

    Raises:
        ValueError: as :func:`beam_line_correspondence`, or ``poses`` of the wrong shape.
    """
    if len(models) == 0:
        raise ValueError("models must hold at least one LandmarkModel")
    _check_models(models)
    n_models = len(models)
    firsts, lasts = _check_spans(scan, first, last, n_models)
    poses = _check_poses(poses, n_models)
    lam = _check_lam(lam)

    # Beams as (models, n) arrays: one row for all models when they share the set,
    # else each model's set padded (with its last beam) to the longest; padded beams
    # are never candidates and get no range error.
    counts = lasts - firsts + 1
    n = int(counts.max())
    valid = None
    if np.all(firsts == firsts[0]) and np.all(lasts == lasts[0]):
        ranges = scan.ranges[firsts[0] : lasts[0] + 1][None, :]
        bearings = scan.bearings[firsts[0] : lasts[0] + 1][None, :]
    else:
        idx = firsts[:, None] + np.minimum(np.arange(n)[None, :], counts[:, None] - 1)
        ranges, bearings = scan.ranges[idx], scan.bearings[idx]
        valid = np.arange(n)[None, :] < counts[:, None]
    if parts is None:
        parts = [model_parts(m) for m in models]
    pm = _PaddedModels(models, parts)
    n_lines = pm.lines.shape[1]
    gate = config.detection_gate_sigma
    cm = np.arange(n_models)[:, None]

    # 1. Vertex bearings and each line's widened bearing interval, clamped to pi/2. A
    # near vertex (no bearing) takes the bearing of the line's other vertex: seen from
    # the pose, the line is radial and covers no bearing interval of its own.
    polar_q = sensor.Q
    polar_mean, polar_cov, near = _vertex_polar_many(
        pm, models, poses, sensor, config, linearization, polar_q
    )
    bearing = polar_mean[..., 1]
    margin = np.minimum(gate * np.sqrt(polar_cov[..., 1, 1]), _HALF_PI)
    a, b = pm.lines[..., 0], pm.lines[..., 1]
    near_a, near_b = near[cm, a], near[cm, b]
    bearing_a, bearing_b = bearing[cm, a], bearing[cm, b]
    margin_a, margin_b = margin[cm, a], margin[cm, b]
    phi_a = np.where(near_a, bearing_b, bearing_a)
    phi_b = np.where(near_b, bearing_a, bearing_b)
    m_a = np.where(near_a, margin_b, margin_a)
    m_b = np.where(near_b, margin_a, margin_b)
    va = pm.mean[cm, a]
    vbm = pm.mean[cm, b]
    rel_a = va - poses[:, None, :2]
    rel_b = vbm - poses[:, None, :2]
    front = (rel_a[..., 0] * rel_b[..., 1] - rel_a[..., 1] * rel_b[..., 0]) < 0.0
    usable = front & ~(near_a | near_b) & pm.valid  # front-facing, not radial

    # 2. Gate, per (model, beam, line).
    delta_a, delta_b = _beam_offsets(np.stack((phi_a, phi_b)), bearings)
    angle = poses[:, 2, None] + bearings
    dv = va - vbm
    length = np.hypot(dv[..., 0], dv[..., 1])
    sin_beam_line = (
        np.cos(angle)[:, :, None] * dv[:, None, :, 1]
        - np.sin(angle)[:, :, None] * dv[:, None, :, 0]
    )
    not_parallel = np.abs(sin_beam_line) > config.parallel_sin_min * length[:, None, :]
    candidate = (
        usable[:, None, :]
        & (delta_b <= m_b[:, None, :])
        & (delta_a >= -m_a[:, None, :])
        & (delta_a - delta_b < np.pi)
        & not_parallel
    )
    if valid is not None:
        candidate &= valid[:, :, None]
    gated = candidate.any(axis=2)

    # Beams without candidates: one fallback pair each (scored only if not parallel).
    # Open chain: a beam left of the first vertex goes to the first line, one right of
    # the last vertex to the last line; otherwise (closed polygon, or a gap of a chain
    # seen from behind) the line with the nearest end in bearing, among the usable
    # lines if there are any (thesis T:2363-2366, notes 3.2).
    evaluate = candidate.copy()
    fb_c, fb_beam = np.nonzero(~gated if valid is None else ~gated & valid)
    fb_line = np.zeros(0, dtype=int)
    if fb_c.size:
        da, db = delta_a[fb_c, fb_beam], delta_b[fb_c, fb_beam]  # (m, L)
        distance = np.minimum(np.abs(da), np.abs(db))
        restrict = usable[fb_c]
        restrict |= ~restrict.any(axis=1, keepdims=True)  # no usable line: any line
        distance = np.where(restrict & pm.valid[fb_c], distance, np.inf)
        fb_line = np.argmin(distance, axis=1)
        last_line = pm.n_lines[fb_c] - 1
        open_chain = ~pm.closed[fb_c]
        left = open_chain & (da[:, 0] < 0.0)
        right = open_chain & (db[np.arange(fb_c.size), last_line] > 0.0)
        fb_line = np.where(right, last_line, fb_line)
        fb_line = np.where(left, 0, fb_line)
        evaluate[fb_c, fb_beam, fb_line] = not_parallel[fb_c, fb_beam, fb_line]

    # 3. Range errors of every evaluated pair in one batched propagation.
    pair_c, beam_idx, line_idx = np.nonzero(evaluate)
    mu_err = np.full((n_models, n, n_lines), np.nan)
    var_err = np.full((n_models, n, n_lines), np.nan)
    loglik = np.full((n_models, n, n_lines), -np.inf)
    if beam_idx.size:
        row = pair_c if valid is not None else np.zeros_like(pair_c)
        mu_p, var_p = _range_errors_many(
            ranges[row, beam_idx],
            bearings[row, beam_idx],
            polar_q,
            poses,
            pair_c,
            pm.mu_vv[pair_c, line_idx],
            pm.sigma_vv[pair_c, line_idx],
            linearization,
        )
        mu_err[pair_c, beam_idx, line_idx] = mu_p
        var_err[pair_c, beam_idx, line_idx] = var_p
        loglik[pair_c, beam_idx, line_idx] = _line_loglik(mu_p, var_p, pm.u[pair_c, line_idx], lam)

    # 4. Choice: the most likely candidate, else the fallback line.
    line = np.argmax(np.where(candidate, loglik, -np.inf), axis=2)
    if fb_c.size:
        line[fb_c, fb_beam] = fb_line
    rows = np.arange(n)[None, :]
    chosen_mu = mu_err[cm, rows, line]
    chosen_var = var_err[cm, rows, line]
    chosen_ll = loglik[cm, rows, line]
    u = pm.u[cm, line]
    d2 = np.full((n_models, n), np.nan)
    if distances:
        keep = slice(None) if valid is None else valid.ravel()
        d2.ravel()[keep] = _generalized_mahalanobis_sq(
            chosen_mu.ravel()[keep],
            chosen_var.ravel()[keep],
            u.ravel()[keep],
            lam,
            config.gm_mode_bracket_sigma,
            # each model's mode search stops on its own
            np.repeat(np.arange(n_models), n)[keep],
        )
    return [
        BeamAssociation(
            line=line[c, :k],
            gated=gated[c, :k],
            mu_err=chosen_mu[c, :k],
            var_err=chosen_var[c, :k],
            loglik=chosen_ll[c, :k],
            u=u[c, :k],
            d2=d2[c, :k],
        )
        for c, k in enumerate(counts.tolist())
    ]


# ----------------------------------------------------------------------------- test


def detect(
    model: LandmarkModel,
    scan: Scan,
    first: int,
    last: int,
    pose: np.ndarray,
    sensor: SensorConfig,
    config: ModelConfig,
    linearization: Linearization | None = None,
    lam: float | None = None,
) -> Detection:
    """Test whether beams ``first..last`` of ``scan`` come from ``model`` (SPEC section 8).

    Runs :func:`beam_line_correspondence` and accepts when the mean of ``d_GM^2`` over
    the beams is at most ``config.detection_mean_max`` and its population variance at
    most ``config.detection_var_max`` (thesis 3.2.60-3.2.61).

    Args:
        model: the landmark model (world frame).
        scan: the scan (lidar frame).
        first: scan index of the set's first (leftmost) beam.
        last: scan index of its last beam, inclusive.
        pose: ``(3,)`` lidar pose ``[x, y, theta]`` (world frame), e.g. after ICP.
        sensor: sensor parameters.
        config: model parameters (gate, thresholds).
        linearization: defaults to ``make_linearization(config)``.
        lam: unknown-line rate [1/m]; defaults to
            ``exponential_rate(scan.ranges, scan.max_range)`` over the whole scan.

    Returns:
        The decision with its statistics, the per-beam association and the set
        log-likelihood.

    Raises:
        ValueError: as :func:`beam_line_correspondence`.
    """
    _check_model(model)
    _check_segment(scan, first, last)
    pose = check_pose(pose)
    return detect_many([model], scan, first, last, pose[None], sensor, config, linearization, lam)[
        0
    ]


def _trimmed_statistics(d2: np.ndarray, config: ModelConfig) -> tuple[list, list]:
    """Mean and population variance of each row of ``d2`` ``(models, n)``, trimmed.

    The ``floor(detection_trim_fraction * n)`` largest values of every row are left out
    (``inf`` for a row with a non-finite value): the statistics of
    :func:`~vslam_gym.slam.likelihood.detection_statistics` of ``trimmed(d2)`` per row.
    """
    k = int(np.floor(config.detection_trim_fraction * d2.shape[1]))
    if k > 0:
        d2 = np.partition(d2, d2.shape[1] - k - 1, axis=1)[:, : d2.shape[1] - k]
    finite = np.isfinite(d2).all(axis=1)
    count = d2.shape[1]
    with np.errstate(invalid="ignore"):
        # np.mean and np.var (ddof 0) by their own steps, without their overhead
        mean = d2.sum(axis=1, keepdims=True) / count
        var = np.square(d2 - mean).sum(axis=1) / count
        mean_d2 = np.where(finite, mean[:, 0], np.inf).tolist()
        var_d2 = np.where(finite, var, np.inf).tolist()
    return mean_d2, var_d2


def detect_many(
    models: list[LandmarkModel],
    scan: Scan,
    first: int | Sequence[int],
    last: int | Sequence[int],
    poses: np.ndarray,
    sensor: SensorConfig,
    config: ModelConfig,
    linearization: Linearization | None = None,
    lam: float | None = None,
    *,
    parts: list[ModelParts] | None = None,
) -> list[Detection]:
    """:func:`detect` of sets of beams against several models, model ``c`` at ``poses[c]``.

    One :func:`beam_line_correspondences` call for all models; each result equals that
    of :func:`detect` for its model, set and pose (up to round-off in the mean and
    variance when the sets differ in length).

    Args:
        models: the landmark models (world frame), at least one.
        first: the set's first beam, or per model the first beam of its set ...
        last: ... and its last beam (inclusive).
        poses: ``(len(models), 3)`` lidar poses ``[x, y, theta]`` (world frame).
        parts: optional :func:`model_parts` of each model.
        (others): as :func:`detect`.

    Returns:
        One :class:`Detection` per model, in order.

    Raises:
        ValueError: as :func:`beam_line_correspondences`.
    """
    lin = make_linearization(config) if linearization is None else linearization
    if lam is None:
        if not isinstance(scan, Scan):
            raise ValueError(f"scan must be a Scan, got {type(scan).__name__}")
        lam = exponential_rate(scan.ranges, scan.max_range)
    assocs = beam_line_correspondences(
        models, scan, first, last, poses, sensor, config, lin, lam, parts=parts
    )
    # The statistics of the sets of each length in one call (each row on its own).
    mean_d2, var_d2 = [0.0] * len(assocs), [0.0] * len(assocs)
    by_size: dict[int, list[int]] = {}
    for i, a in enumerate(assocs):
        by_size.setdefault(a.n, []).append(i)
    for rows in by_size.values():
        means, variances = _trimmed_statistics(np.stack([assocs[i].d2 for i in rows]), config)
        for i, mean, var in zip(rows, means, variances, strict=True):
            mean_d2[i], var_d2[i] = mean, var
    out = []
    for assoc, mean, var in zip(assocs, mean_d2, var_d2, strict=True):
        # The rule of likelihood.detection_accepts, on the statistics already computed.
        accepted = bool(mean <= config.detection_mean_max and var <= config.detection_var_max)
        out.append(
            Detection(
                accepted=accepted,
                association=assoc,
                mean_d2=mean,
                var_d2=var,
                loglik=float(assoc.loglik.sum()),
            )
        )
    return out
