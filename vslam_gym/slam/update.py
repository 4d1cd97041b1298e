"""Updating a landmark model with a new scan segment at a known lidar pose (SPEC section 9).

Thesis section 3.2.3 (3.2.62-3.2.95, Algorithms 4-7), read as in
``notes/update_algorithms.md`` section 4 (register items R-13 to R-21, R-29). Pipeline for
one landmark and one segment ``first..last`` of a scan taken at the pose ``x``:

1. beam-to-line association (:func:`~vslam_gym.slam.detection.beam_line_correspondence`,
   SPEC 8) and :func:`observed_lines` (Algorithm 4): a line is observed with at least
   ``min_beams_per_line`` beams; an observed object line is refitted, an observed unknown
   line is replaced by a model selection on its beams, with an unobserved unknown line
   inserted at each end that does not terminate at the existing vertex (``zeta``);
2. :func:`observed_parameters` (Algorithm 5): the vertices of every run of adjacent
   observed lines, fitted together, in canonical form ``C(K_obs, h_obs)`` over the new
   vertices; existing run-end vertices that are occluded or at the field-of-view limit
   carry no information;
3. :func:`observed_vertices` (Algorithm 6), :func:`placement_matrix` (``F``, 3.2.73) and
   :func:`selection_matrix` (``G``, 3.2.83); :func:`combine` gives the posterior
   ``K_new = F^T K F + K_obs``, ``h_new = F^T h + h_obs`` (3.2.78-3.2.79),
   ``u_new = min(u', u_obs)`` (3.2.80); :func:`observation_conditional` the conditional
   form of the observation on the pose (3.2.81-3.2.90, with SPEC's two corrections);
4. :func:`update_unknown_lines` (Algorithm 7): the unknown chains at both ends are merged
   with the ones seen from the new pose, then cut where the left and right chains cross;
5. :func:`wrap_model` (3.2.91-3.2.95): the first and last object vertices are folded into
   one when they are statistically the same point, closing the polygon.

The SLAM filter of thesis chapter 4 uses steps 1-3 of :func:`update_model` (``F``,
``K_obs``, ``A_vx``, ``b_vx``: its factor ``Phi3``), runs its own state update, then calls
:func:`update_unknown_lines` and :func:`wrap_model` on its posterior means with the
bookkeeping in :attr:`ModelUpdate.chains`.

Frames and units: vertices, points and poses in the world frame ([m], [m], [rad]); the
pose is the lidar's and is known here; bearings relative to the lidar heading [rad];
ranges [m]. Vertex vectors are stacked ``[v0x, v0y, v1x, v1y, ...]``. The vertex order of
every model is left to right as first seen (observed free space on the right of each
line, notes section 0); every operation here keeps it.

Departures from the thesis (all documented where they happen):

- beams without a candidate line (SPEC 8 fallback) are not used to observe lines;
  object lines are fitted to their own beams, so lines of different existing lines have
  disjoint beams, and only lines of one model selection (sharing boundary beams) are
  re-split by ``exclusive_boundaries``; with ``exclusive_boundaries`` the beams where
  an unknown line meets another line are re-split by fit residuals
  (:func:`_refine_boundaries`); beams that interleave beyond repair are put in line
  order (:func:`_monotone_association`) before giving up;
- the two Mahalanobis gates compare distances (not the printed squared distances) with
  ``vertex_match_mahalanobis`` and ``wrap_mahalanobis``, as the configuration names them;
- adjacent lines of a run that are nearly parallel are fitted as one line (their shared
  vertex gets no information); a closed model is updated by rotating a line without
  beams to the closing position (notes 4.9 step 4);
- a new line terminates at an existing vertex only if this scan can see that vertex
  there (:func:`_terminates`): the thesis's own criterion for observed end vertices;
- the end-vertex correction (:func:`_end_correction`, on by default, off in
  :meth:`~vslam_gym.slam.config.ModelConfig.thesis`): run end vertices get the
  beam-spacing bias and variance of :func:`_end_quantization`, ends seen at a grazing
  angle carry no information, termination also needs the vertex where the line can end,
  and prior unknown vertices that become object vertices start afresh
  (:func:`_adopt_unknown_vertices`). Measured on a star circled with 24-36 poses a turn
  (tests): the fraction of corners within 3 sigma goes from about 0.2 (thesis preset)
  to about 0.85.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import scipy.linalg

from vslam_gym.slam.config import ModelConfig, SensorConfig
from vslam_gym.slam.creation import (
    DegenerateSegmentError,
    _first_order_vertices,
    _intersect,
    _parallel_pairs,
    _points,
    _segment_lengths,
    _SegmentModeller,
    _vertex_function,
    coarseness_variances,
    end_vertices,
    fit_slices,
    initial_grouping,
    point_covariances,
    select_model,
    unknown_probabilities,
)
from vslam_gym.slam.detection import BeamAssociation, Detection, beam_line_correspondence
from vslam_gym.slam.gaussian import (
    Canonical,
    Linearization,
    NotPositiveDefiniteError,
    cho_factor_finite,
    cho_solve_finite,
    ensure_spd,
    make_linearization,
    symmetrize,
)
from vslam_gym.slam.geometry import stack_last
from vslam_gym.slam.landmark import LandmarkModel, conditional_on_pose
from vslam_gym.slam.likelihood import exponential_rate
from vslam_gym.slam.scan import Scan

__all__ = [
    "ChainContext",
    "InterleavedError",
    "ModelUpdate",
    "NewLine",
    "ObservedLines",
    "ObservedParameters",
    "Run",
    "UnknownLineUpdate",
    "UpdateError",
    "Wrap",
    "combine",
    "infer_object_vertices",
    "observation_conditional",
    "observed_lines",
    "observed_parameters",
    "observed_vertices",
    "perpendicular_mahalanobis",
    "placement_matrix",
    "selection_matrix",
    "update_model",
    "update_unknown_lines",
    "wrap_model",
]

# Numerical tolerance (not a model threshold): segment parameters within this of an end
# count as touching that end, for the chain crossings of Algorithm 7.
_SEGMENT_EPS = 1e-9
_XY = np.arange(2)


class UpdateError(ValueError):
    """A landmark model cannot be updated with this segment (the model is left unchanged).

    Raised for an inconsistent association (lines whose beams overlap beyond repair), a
    new vertex without information, or a posterior that is not positive definite.
    """


class InterleavedError(UpdateError):
    """The beams of two adjacent lines of a run interleave so that one keeps < 2 beams."""


# ----------------------------------------------------------------------------- results


@dataclass(frozen=True)
class NewLine:
    """One line of the updated model, as produced by Algorithm 4.

    Attributes:
        old_line: index of the existing line it replaces or refits.
        j: its position in ``zeta[old_line]``; ``j == 0`` means its left vertex is the
            existing vertex ``old_line`` (otherwise a new vertex).
        observed: True when fitted to beams of this segment (``zeta`` entry 1).
        beams: scan indices of its beams (empty when unobserved).
        group: ``(first, last)`` scan indices of its beams, ``(-1, -1)`` when unobserved.
    """

    old_line: int
    j: int
    observed: bool
    beams: np.ndarray
    group: tuple[int, int]


@dataclass(frozen=True)
class ObservedLines:
    """Output of Algorithm 4 (:func:`observed_lines`).

    Attributes:
        zeta: per existing line, the tuple of 0/1 flags of the new lines replacing it.
        lines: the new lines in model order (``k_new - 1`` of them).
        observed: ``(m,)`` bool, existing lines with at least ``min_beams_per_line`` beams.
        matched: per existing unknown line observed, ``(left, right)``: whether the
            replacement lines terminate at its existing vertices (3.2.69-3.2.72).
    """

    zeta: tuple[tuple[int, ...], ...]
    lines: tuple[NewLine, ...]
    observed: np.ndarray
    matched: dict[int, tuple[bool, bool]] = field(default_factory=dict)

    @property
    def groups(self) -> np.ndarray:
        """``(k_new - 1, 2)`` the thesis's ``gamma``: scan beam range per new line (-1: none)."""
        return np.array([ln.group for ln in self.lines], dtype=int).reshape(-1, 2)


@dataclass(frozen=True)
class Run:
    """A run of adjacent observed new lines fitted together (Algorithm 5).

    Attributes:
        lines: ``(t0, t1)``: new lines ``t0..t1-1``; their vertices are ``t0..t1``.
        first_beam: scan index of the run's first (leftmost) beam.
        last_beam: scan index of its last (rightmost) beam.
        informed: new-vertex indices that received information from this run.
        dropped: existing end vertices left without information (occluded, at the field
            of view limit, on a ray nearly parallel to their line, or, with the
            end-vertex correction, seen at a grazing angle).
    """

    lines: tuple[int, int]
    first_beam: int
    last_beam: int
    informed: tuple[int, ...]
    dropped: tuple[int, ...]


@dataclass(frozen=True)
class ObservedParameters:
    """Output of Algorithm 5 (:func:`observed_parameters`).

    Attributes:
        K_obs: ``(2k_new, 2k_new)`` information matrix of the observation [1/m^2].
        h_obs: ``(2k_new,)`` information vector [1/m].
        u_obs: ``(k_new - 1,)`` unknown probability of each new line from the
            observation (1 for unobserved lines).
        runs: the runs of adjacent observed lines, left to right.
    """

    K_obs: np.ndarray  # noqa: N815 - the thesis's name
    h_obs: np.ndarray
    u_obs: np.ndarray
    runs: tuple[Run, ...]


@dataclass(frozen=True)
class ChainContext:
    """What Algorithm 7 needs to know about an update, in the new vertex space.

    Attributes:
        prior_left: new indices of the prior model's left unknown vertices, outer first;
            -1 for one that is not in the new space (it became an object vertex, see
            :func:`update_model`), whose prior Gaussian is then in ``prior_points``.
        prior_right: new indices of its right unknown vertices, inner first (-1 alike).
        attach_prior: ``(ip_left, ip_right)``: new indices of the prior model's first and
            last object vertices.
        attach_observed: ``(io_left, io_right)``: new indices of the first run's left end
            vertex and the last run's right end vertex (kept even if dropped, R-20).
        beams: ``(left, right)``: scan indices of the leftmost and rightmost beam used.
        prior_points: ``("left" | "right", position in the chain) -> (mean (2,), cov
            (2, 2))`` of the prior unknown vertices marked -1 (their old geometry still
            bounds the prior's unobserved region).
    """

    prior_left: tuple[int, ...]
    prior_right: tuple[int, ...]
    attach_prior: tuple[int, int]
    attach_observed: tuple[int, int]
    beams: tuple[int, int]
    prior_points: dict[tuple[str, int], tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)


@dataclass(frozen=True)
class UnknownLineUpdate:
    """Output of Algorithm 7 (:func:`update_unknown_lines`).

    Attributes:
        model: the model with its unknown chains replaced.
        source: ``(k,)`` for each vertex of ``model`` the index of the input vertex it is
            (its rows of the input mean and covariance, i.e. the others were
            marginalised out), or -1 for a new unknown vertex, independent of all others.
        object_vertices: ``(start, stop)``: ``model.mean[start:stop]`` are the object
            vertices (between the two unknown chains).
        crossed: True when the left and right chains were cut at their crossing.
    """

    model: LandmarkModel
    source: np.ndarray
    object_vertices: tuple[int, int]
    crossed: bool


@dataclass(frozen=True)
class Wrap:
    """Output of :func:`wrap_model` (3.2.91-3.2.95).

    Attributes:
        model: the closed model (or the input model when not wrapped).
        wrapped: True when the first and last object vertices were folded into one.
        distance: Mahalanobis distance of their difference (``nan`` if not tested).
        keep: input vertex indices kept before folding (the object vertices).
        S: ``(2 len(keep), 2 (len(keep) - 1))`` substitution ``v_keep = S v_new``
            (identity with the last vertex mapped onto the first), so that
            ``K_new = S^T K_keep S`` and ``h_new = S^T h_keep`` (3.2.95).
    """

    model: LandmarkModel
    wrapped: bool
    distance: float
    keep: np.ndarray
    S: np.ndarray  # noqa: N815 - the thesis's name


@dataclass(frozen=True)
class ModelUpdate:
    """Everything an update produced (SPEC section 9).

    The new vertex space (``k_new`` vertices) is that of Algorithms 4-6, before the
    unknown chains are merged and before wrapping.

    Attributes:
        model: the posterior landmark model (after Algorithm 7 and wrapping).
        F: ``(2k_old, 2k_new)`` placement of the old vertices in the new space (3.2.73).
        K_obs: ``(2k_new, 2k_new)`` observation information [1/m^2]; zero rows and
            columns for unobserved vertices (the filter's ``K3``).
        h_obs: ``(2k_new,)`` observation information vector [1/m].
        G: ``(2m_o, 2k_new)`` selection of the vertices with ``vartheta > 0`` (3.2.83).
        A_vx: ``(2k_new, 3)`` conditional form of the observation on the pose
            (``A3``), zero rows for unobserved vertices.
        b_vx: ``(2k_new,)`` its offset [m] (``b3``).
        vartheta: ``(k_new,)`` 0 unobserved, 1 existing and observed, 2 new.
        observed_lines: ``(m_old,)`` bool, existing lines observed by the segment.
        wrapped: True when this update closed the polygon.
        zeta: Algorithm 4's encoding per existing line (in rotated order if closed).
        old_of: ``(k_new,)`` old vertex index of each new vertex (input order), -1 for
            new vertices (including adopted unknown vertices, whose old vertex is
            marginalised out: see :func:`_adopt_unknown_vertices`).
        u_prior: the prior's unknown probability of each line in the new space (``u'``,
            1 for new lines): ``k_new - 1`` entries, ``k_new`` for a closed model.
        u_obs: the observation's, likewise.
        posterior: the posterior in the new vertex space (``u = min(u', u_obs)``),
            before Algorithm 7 and wrapping.
        chains: bookkeeping for :func:`update_unknown_lines` (``None`` for a closed
            model or when nothing was observed).
        unknown: result of Algorithm 7 (``None`` when skipped).
        wrap: result of :func:`wrap_model` (``None`` when not attempted).
        object_vertices: ``(start, stop)`` of the object vertices of ``model``.
        association: ``(n,)`` line of the input model each beam was used for (after
            the boundary refinement of :func:`_refine_boundaries`), -1 for beams not
            used (no candidate line, or on the closing line of a closed model).
        runs: the runs of Algorithm 5.
    """

    model: LandmarkModel
    F: np.ndarray  # noqa: N815 - the thesis's name
    K_obs: np.ndarray  # noqa: N815 - the thesis's name
    h_obs: np.ndarray
    G: np.ndarray  # noqa: N815 - the thesis's name
    A_vx: np.ndarray  # noqa: N815 - the thesis's name
    b_vx: np.ndarray
    vartheta: np.ndarray
    observed_lines: np.ndarray
    wrapped: bool
    zeta: tuple[tuple[int, ...], ...]
    old_of: np.ndarray
    u_prior: np.ndarray
    u_obs: np.ndarray
    posterior: LandmarkModel
    chains: ChainContext | None
    unknown: UnknownLineUpdate | None
    wrap: Wrap | None
    object_vertices: tuple[int, int]
    association: np.ndarray
    runs: tuple[Run, ...]


# ----------------------------------------------------------------------------- helpers


def _block_indices(vertices) -> np.ndarray:
    """Coordinate indices ``[2i, 2i + 1, ...]`` of vertex indices ``vertices``."""
    v = np.asarray(vertices, dtype=int).reshape(-1, 1)
    return (2 * v + _XY).reshape(-1)


def infer_object_vertices(model: LandmarkModel) -> tuple[int, int]:
    """Object vertex range ``(start, stop)`` of a model without bookkeeping.

    The thesis's proxy (Algorithm 7 line 2): the leading and trailing lines with
    ``u >= 1`` are the artificial unknown end lines. A closed model has no end lines.
    Pass the ``object_vertices`` of :class:`~vslam_gym.slam.landmark.ModelFit` or of the
    previous :class:`ModelUpdate` to :func:`update_model` instead where available: a
    sparse fitted line at an end can also reach ``u = 1`` (R-17).
    """
    k = model.n_vertices
    if model.closed:
        return 0, k
    artificial = model.u >= 1.0
    start = 0
    while start < model.n_lines and artificial[start]:
        start += 1
    stop = k
    while stop - 1 > start and artificial[stop - 2]:
        stop -= 1
    if stop - start < 2:
        raise UpdateError(
            f"cannot tell the object vertices of a model whose lines all have u = 1 (u = {model.u})"
        )
    return start, stop


def _check_inputs(
    model: LandmarkModel, scan: Scan, first: int, last: int, pose
) -> tuple[int, int, np.ndarray]:
    if not isinstance(model, LandmarkModel):
        raise ValueError(f"model must be a LandmarkModel, got {type(model).__name__}")
    if not isinstance(scan, Scan):
        raise ValueError(f"scan must be a Scan, got {type(scan).__name__}")
    if model.n_lines < 1:
        raise ValueError(f"model must have at least one line, got {model.n_vertices} vertices")
    if not (np.isfinite(model.mean).all() and np.isfinite(model.cov).all()):
        raise ValueError("model mean and covariance must be finite")
    for name, value in (("first", first), ("last", last)):
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
            raise ValueError(f"{name} must be an integer beam index, got {value!r}")
    first, last = int(first), int(last)
    if not (0 <= first <= last < scan.n):
        raise ValueError(f"segment {first}..{last} is not inside a scan of {scan.n} beams")
    if not np.all(scan.returns[first : last + 1]):
        raise ValueError(f"segment {first}..{last} includes no-return (max-range) beams")
    pose = np.array(pose, dtype=float).reshape(-1)
    if pose.shape != (3,) or not np.isfinite(pose).all():
        raise ValueError(f"pose must be 3 finite numbers [x, y, theta], got {pose}")
    return first, last, pose


def _association_lines(
    association, model, scan, first, last, pose, sensor, config, lin
) -> np.ndarray:
    """Per beam of ``first..last`` the model line it observes, -1 for none.

    Beams that had no candidate line (assigned to an end line only so that detection
    rejects partial fits, SPEC 8) are not used to observe lines.
    """
    n = last - first + 1
    if association is None:
        lam = exponential_rate(scan.ranges, scan.max_range)
        association = beam_line_correspondence(
            model, scan, first, last, pose, sensor, config, lin, lam, distances=False
        )
    if isinstance(association, Detection):
        association = association.association
    if isinstance(association, BeamAssociation):
        line = np.where(association.gated, association.line, -1)
    else:
        line = np.asarray(association)
        if not np.issubdtype(line.dtype, np.integer):
            raise ValueError(f"association must hold integer line indices, got {line.dtype}")
    line = np.array(line, dtype=int).reshape(-1)
    if line.size != n:
        raise ValueError(f"association has {line.size} entries for the {n} beams {first}..{last}")
    if np.any((line < -1) | (line >= model.n_lines)):
        raise ValueError(f"association line indices must lie in -1..{model.n_lines - 1}")
    return line


# ------------------------------------------------------------------------ Algorithm 4


def _monotone_association(line_of_beam: np.ndarray, config: ModelConfig) -> np.ndarray:
    """Make the observed lines' beams follow the line order (not in the thesis).

    Seen from outside, the visible parts of a polygon appear in the scan in the order of
    its boundary, so the observed lines' beams should not interleave; near a vertex the
    per-beam choice of the most likely line can make them. Used when the plain
    association fails (:class:`InterleavedError`): on the star of the tests, applying it
    always lowered the fraction of corners within 3 sigma (0.76 instead of 0.82), since
    beams behind crossing unknown chains legitimately go to either. Between consecutive
    observed lines (at least ``min_beams_per_line`` beams) whose beams interleave, the
    split that reassigns the fewest beams is applied if it moves at most
    ``boundary_window`` beams; otherwise the model disagrees with the scan there and the
    line with fewer beams is not used. A line left with too few beams is then simply not
    observed (Algorithm 4).

    Returns:
        A new ``(n,)`` array of line indices per beam (-1: not used).
    """
    line = line_of_beam.copy()
    counts = np.bincount(line[line >= 0])
    observed = np.flatnonzero(counts >= config.min_beams_per_line)
    for j, k in zip(observed[:-1], observed[1:], strict=True):
        left, right = np.flatnonzero(line == j), np.flatnonzero(line == k)
        if left.size == 0 or right.size == 0 or right[0] > left[-1]:
            continue
        splits = np.arange(right[0] - 1, left[-1] + 1)
        cost = (left[None, :] > splits[:, None]).sum(1) + (right[None, :] <= splits[:, None]).sum(1)
        best = int(np.argmin(cost))
        if cost[best] > config.boundary_window:
            # Not a boundary ambiguity: the model disagrees with the scan there. The line
            # with fewer beams is not observed this time.
            line[left if left.size < right.size else right] = -1
            continue
        split = splits[best]
        line[left[left > split]] = k
        line[right[right <= split]] = j
    return line


def _refine_boundaries(
    line_of_beam: np.ndarray,
    u: np.ndarray,
    scan: Scan,
    first: int,
    pose: np.ndarray,
    config: ModelConfig,
) -> np.ndarray:
    """Re-split the beams where two adjacent observed lines meet (not in the thesis).

    Next to an unknown line the most likely line of a beam is ambiguous near the vertex:
    the unknown line's broad density loses to an object line for beams a few
    centimetres behind it, so beams of the next face go to the object line, bias its fit
    and move the new line's end away from the vertex (a spurious vertex then follows).
    As creation's ``exclusive_boundaries`` (:func:`~vslam_gym.slam.creation.fit_slices`),
    the split between lines ``j`` and ``j + 1`` (one of them unknown) whose beams meet in
    the scan is moved by up to ``boundary_window`` beams to minimise the perpendicular
    residuals of the points to the two lines fitted to them (for the unknown line, to its
    beams next to the split only: they may cover several faces). Between two object
    lines the association is left alone (re-splitting there was measured to hurt: 0.71
    instead of 0.79 of the star's corners within 3 sigma; with unknown lines only, 0.81).

    Returns:
        A new ``(n,)`` array of line indices per beam.
    """
    line = line_of_beam.copy()
    beams = slice(first, first + line.size)
    points = _points(stack_last(scan.ranges[beams], scan.bearings[beams]).reshape(-1), pose)
    counts = np.bincount(line[line >= 0])  # beams per line, kept up to date
    for j in range(int(line.max(initial=-1))):
        if min(counts[j], counts[j + 1]) < config.min_beams_per_line:
            continue
        left, right = np.flatnonzero(line == j), np.flatnonzero(line == j + 1)
        if right[0] != left[-1] + 1:
            continue
        a, b = int(left[0]), int(right[-1])
        if np.any(line[a : b + 1] < j) or np.any(line[a : b + 1] > j + 1):
            continue  # other lines' beams in between: leave it to the association
        if max(u[j], u[j + 1]) <= config.unknown_threshold:
            continue  # two object lines: the association's choice is sharp there
        # The beams of an unknown line may cover several faces: fit only its few beams
        # next to the boundary (those just beyond the window).
        reach = 2 * config.boundary_window + config.min_group_size
        if u[j] > config.unknown_threshold:
            a = max(a, int(left[-1]) - reach)
        if u[j + 1] > config.unknown_threshold:
            b = min(b, int(right[0]) + reach)
        split = fit_slices(
            points[a : b + 1],
            [(0, int(left[-1]) - a), (int(right[0]) - a, b - a)],
            True,
            config.boundary_window,
        )[0][1]
        line[a : a + split + 1] = j
        line[a + split + 1 : b + 1] = j + 1
        counts = np.bincount(line[line >= 0], minlength=counts.size)
    return line


def perpendicular_mahalanobis(
    v_mean: np.ndarray,
    v_cov: np.ndarray,
    line_mean: np.ndarray,
    line_cov: np.ndarray,
    lin: Linearization,
) -> float:
    """Mahalanobis distance of a vertex's perpendicular error to a line (3.2.69-3.2.72).

    ``e = (v - p0) . n`` with ``n`` the unit normal of the line through ``p0`` and ``p1``;
    ``N(mu_e, s_e^2)`` by the linearisation over ``[v; p0; p1]`` with the vertex and the
    line independent (3.2.71, with the index typo ``Sigma_v,jj`` read as ``Sigma_v,ii``).

    Args:
        v_mean: ``(2,)`` vertex mean [m] (world frame).
        v_cov: ``(2, 2)`` its covariance [m^2].
        line_mean: ``(4,)`` mean of ``[p0, p1]`` [m] (two points of the line).
        line_cov: ``(4, 4)`` their covariance (may be singular).
        lin: the linearisation.

    Returns:
        ``|mu_e| / s_e`` (the thesis's ``e_mhl`` is its square).
    """
    mu = np.concatenate([v_mean, line_mean])
    cov = np.zeros((6, 6))
    cov[:2, :2] = v_cov
    cov[2:, 2:] = line_cov

    def f(x: np.ndarray) -> np.ndarray:
        d = x[..., 4:6] - x[..., 2:4]
        w = x[..., 0:2] - x[..., 2:4]
        cross = d[..., 0] * w[..., 1] - d[..., 1] * w[..., 0]
        return (cross / np.hypot(d[..., 0], d[..., 1]))[..., None]

    mu_e, var_e = lin.propagate(f, mu, cov, check=False)
    var = float(np.asarray(var_e).reshape(-1)[0])
    if not var > 0.0:
        raise NotPositiveDefiniteError("perpendicular error variance", var)
    return abs(float(np.asarray(mu_e).reshape(-1)[0])) / np.sqrt(var)


def _sub_model(
    scan: Scan,
    a: int,
    b: int,
    pose: np.ndarray,
    sensor: SensorConfig,
    config: ModelConfig,
    lin: Linearization,
) -> tuple[_SegmentModeller, list[tuple[int, int]]]:
    """Model selection (Algorithms 1-3) on beams ``a..b``; nearly parallel lines joined.

    Returns the modeller and the grouping in local indices (shared boundary beams).
    """
    modeller = _SegmentModeller(scan, a, b, pose, sensor, config, lin)
    mu_c, cov_c = point_covariances(modeller.z, pose, sensor, lin)
    modeller.use_point_covariances(cov_c)
    groups, _ = select_model(modeller, initial_grouping(mu_c, cov_c, config))
    # As creation.vertex_distribution: a vertex between nearly parallel lines is undefined.
    while len(groups) > 1:
        inner = _parallel_pairs(modeller, groups)[1:-1]
        j = int(np.argmin(inner))
        if inner[j] > config.parallel_sin_min:
            break
        groups[j : j + 2] = [(groups[j][0], groups[j + 1][1])]
    return modeller, groups


def observed_lines(
    model: LandmarkModel,
    line_of_beam: np.ndarray,
    first: int,
    scan: Scan,
    pose: np.ndarray,
    sensor: SensorConfig,
    config: ModelConfig,
    lin: Linearization,
) -> ObservedLines:
    """Algorithm 4 (ObservedLines), corrected as in notes 4.2 (R-13, R-14, R-27).

    Line ``i`` of the open chain ``model`` is observed with at least
    ``config.min_beams_per_line`` beams. An observed object line (``u <= unknown_threshold``)
    is refitted to its own beams (``zeta_i = (1,)``). An observed unknown line is replaced
    by the lines of a model selection on its contiguous beam range; an unobserved unknown
    line (0) is inserted at an end where the new lines do not terminate at the existing
    vertex (:func:`_terminates`; the printed condition is inverted, R-13). An unobserved
    line gets ``zeta_i = (0,)``.

    Args:
        model: the existing model as an open chain (``closed`` False).
        line_of_beam: ``(n,)`` line per beam of the segment starting at ``first``, -1 none.
        first: scan index of the segment's first beam.
        scan, pose, sensor, config, lin: as :func:`update_model`.

    Returns:
        The encoding ``zeta`` and the new lines.
    """
    m = model.n_lines
    zeta: list[tuple[int, ...]] = []
    lines: list[NewLine] = []
    counts = np.bincount(line_of_beam[line_of_beam >= 0], minlength=m)
    observed = counts >= config.min_beams_per_line
    matched: dict[int, tuple[bool, bool]] = {}
    none = np.zeros(0, dtype=int)
    for i in range(m):
        if not observed[i]:
            zeta.append((0,))
            lines.append(NewLine(i, 0, False, none, (-1, -1)))
            continue
        beams = np.flatnonzero(line_of_beam == i) + first
        a, b = int(beams[0]), int(beams[-1])
        if model.u[i] <= config.unknown_threshold:
            zeta.append((1,))
            lines.append(NewLine(i, 0, True, beams, (a, b)))
            continue
        modeller, groups = _sub_model(scan, a, b, pose, sensor, config, lin)
        ends = []
        for vertex, (ga, gb), beam, step, joined in (
            (i, groups[0], a, 1, i > 0 and observed[i - 1]),
            (i + 1, groups[-1], b, -1, i + 1 < m and observed[i + 1]),
        ):
            line_mu, line_cov = modeller.line_distribution(ga, gb)
            ends.append(
                _terminates(
                    model.mean[vertex],
                    model.vertex_cov(vertex),
                    line_mu,
                    line_cov,
                    bool(joined),
                    scan,
                    beam,
                    step,
                    pose,
                    sensor,
                    config,
                    lin,
                )
            )
        matched[i] = (ends[0], ends[1])
        flags = [1] * len(groups)
        new = [
            NewLine(i, 0, True, np.arange(a + ga, a + gb + 1), (a + ga, a + gb))
            for ga, gb in groups
        ]
        if not ends[0]:
            flags.insert(0, 0)
            new.insert(0, NewLine(i, 0, False, none, (-1, -1)))
        if not ends[1]:
            flags.append(0)
            new.append(NewLine(i, 0, False, none, (-1, -1)))
        zeta.append(tuple(flags))
        lines.extend(
            NewLine(ln.old_line, j, ln.observed, ln.beams, ln.group) for j, ln in enumerate(new)
        )
    return ObservedLines(tuple(zeta), tuple(lines), observed, matched)


# ------------------------------------------------------------------------ Algorithm 5


def _disjoint_groups(lines: list[NewLine]) -> list[tuple[int, int]]:
    """Beam ranges of a run's lines, made monotone where the association interleaves.

    Consecutive ranges may share one boundary beam (lines of one model selection) but
    must not overlap further; where they do, the split that misassigns fewest beams is
    used.

    Raises:
        UpdateError: a line would keep fewer than 2 beams.
    """
    groups = [list(ln.group) for ln in lines]
    for t in range(len(groups) - 1):
        left, right = groups[t], groups[t + 1]
        if right[0] >= left[1]:
            continue
        splits = np.arange(right[0] - 1, left[1] + 1)[:, None]
        cost = (lines[t].beams > splits).sum(1) + (lines[t + 1].beams <= splits).sum(1)
        split = int(splits[np.argmin(cost), 0])  # the first of the cheapest
        left[1], right[0] = split, split + 1
    for (a, b), ln in zip(groups, lines, strict=True):
        if b - a < 1:
            raise InterleavedError(
                f"line {ln.old_line}: interleaved beam associations leave it fewer than 2 beams"
            )
    return [tuple(g) for g in groups]


def _occluded(scan: Scan, beam: int, neighbour: int) -> bool:
    """Run end at ``beam`` occluded: at the FOV limit, or its neighbour returns closer."""
    if neighbour < 0 or neighbour >= scan.n:
        return True
    return bool(scan.returns[neighbour] and scan.ranges[neighbour] < scan.ranges[beam])


def _continues(
    v: np.ndarray,
    scan: Scan,
    s: int,
    e: int,
    pose: np.ndarray,
    sensor: SensorConfig,
    config: ModelConfig,
) -> tuple[bool, bool]:
    """Whether the beams beyond each end of a run return on that end line's extension.

    ``v`` ``(q, 2)`` are the run's vertices [m] (``v[0]`` and ``v[-1]`` on the rays of its
    first and last beams ``s`` and ``e``). An end continues when each of the next
    ``config.continuation_beams`` beams out (``s - 1, s - 2, ...``; ``e + 1, ...``) that
    lies in the field of view returns a point within ``config.continuation_gate``
    standard deviations of the range noise, measured along its ray, of the end line's
    extension (at least the first must). The line then goes on beyond the run: its beams
    were associated with another line (two model lines of one straight wall, or a line
    the association cut), and the end vertex only marks where this run stops. See
    ``ModelConfig.continuation_gate``.
    """
    gate = config.continuation_gate * sensor.sigma_range
    ends = []
    for end, inner, step, edge in ((0, 1, -1, s), (-1, -2, 1, e)):
        out = edge + step * np.arange(1, config.continuation_beams + 1)
        beams = [b for b in out.tolist() if 0 <= b < scan.n]
        on_line = bool(beams)
        for b in beams:
            angle = pose[2] + scan.bearings[b]
            ray_end = pose[:2] + np.array([np.cos(angle), np.sin(angle)])
            # the range at which the (unit) ray meets the end line's extension
            params = _segment_params(pose[:2], ray_end, v[end], v[inner])
            if not (
                scan.returns[b]
                and params is not None
                and params[0] > 0.0
                and abs(scan.ranges[b] - params[0]) <= gate
            ):
                on_line = False
                break
        ends.append(on_line)
    return ends[0], ends[1]


def _run_vertices(
    modeller: _SegmentModeller, groups: list[tuple[int, int]]
) -> tuple[np.ndarray, np.ndarray]:
    """Joint Gaussian ``(2m + 2,)``, ``(2m + 2, 2m + 2)`` of a run's vertices (3.2.14).

    As :func:`~vslam_gym.slam.creation.vertex_distribution` after its parallel-line
    checks (done by the caller): lines fitted to ``fit_slices`` of ``groups`` (local
    indices; only runs of groups sharing boundary beams are re-split), the
    model-error offsets of ``coarseness``, the closed-form first order
    when the linearisation is first order, else the configured one.
    """
    config, pose, n = modeller.config, modeller.pose, modeller.n
    _, point_cov = point_covariances(modeller.z, pose, modeller.sensor, modeller.lin)
    modeller.use_point_covariances(point_cov)
    points = modeller.points
    # Only lines that share a boundary beam (those of one model selection) are re-split;
    # the beams of lines observed through the association are already disjoint.
    slices: list[tuple[int, int]] = []
    chunk = [groups[0]]
    for g in [*groups[1:], None]:
        if g is not None and g[0] == chunk[-1][1]:
            chunk.append(g)
            continue
        slices += fit_slices(points, chunk, config.exclusive_boundaries, config.boundary_window)
        chunk = [g]
    offset_var = np.zeros(0)
    if config.coarseness > 0:
        var = coarseness_variances(
            points, point_cov, slices, config.coarseness_significance, modeller.span_fits(slices)
        )
        offset_var = config.coarseness**2 * var
    if modeller.closed_form:
        mu, sigma = _first_order_vertices(modeller, slices, offset_var)
        return mu.reshape(-1), sigma
    z = np.concatenate([modeller.z, np.zeros(offset_var.size)])
    cov = np.diag(np.concatenate([modeller.var, offset_var]))
    return modeller.lin.propagate(_vertex_function(slices, pose, n), z, cov, check=False)


def _fit_run(
    lines: tuple[NewLine, ...],
    t0: int,
    t1: int,
    scan: Scan,
    pose: np.ndarray,
    sensor: SensorConfig,
    config: ModelConfig,
    lin: Linearization,
    prior_mean: np.ndarray | None = None,
) -> tuple[list[int], np.ndarray, np.ndarray, list[int], list[tuple[int, int, float]], Run]:
    """Fit the new lines ``t0..t1-1`` together; Gaussian of their informed vertices.

    ``prior_mean`` ``(k_old, 2)`` are the existing vertices (for :func:`_end_quantization`).

    Returns ``(informed, mu, Sigma, dropped, u_lines, run)`` where ``informed`` are new
    vertex indices with ``mu`` ``(2q,)`` and ``Sigma`` ``(2q, 2q)`` over them (the
    dropped and merged vertices marginalised out), and ``u_lines`` holds
    ``(t_start, t_stop, u)`` for each fitted line (merged lines share a ``u``).
    """
    run_lines = list(lines[t0:t1])
    groups = _disjoint_groups(run_lines)
    s, e = groups[0][0], groups[-1][1]
    local = [(a - s, b - s) for a, b in groups]
    vertices = list(range(t0, t1 + 1))
    existing_left = lines[t0].j == 0
    existing_right = t1 == len(lines) or lines[t1].j == 0
    modeller = _SegmentModeller(scan, s, e, pose, sensor, config, lin)
    limit = config.parallel_sin_min

    # Nearly parallel adjacent lines: fit them as one; their shared (existing) vertex
    # gets no information from this run (it is undefined along the line).
    spans = [(t, t + 1) for t in range(t0, t1)]
    sines = _parallel_pairs(modeller, local)
    while len(local) > 1:
        q = int(np.argmin(sines[1:-1]))
        if sines[q + 1] > limit:
            break
        shared = vertices[q + 1]
        if lines[shared].j != 0:  # a new vertex of one model selection: never merged here
            raise DegenerateSegmentError(
                f"new vertex {shared} lies between nearly parallel lines (sine {sines[q + 1]:.3g})"
            )
        local[q : q + 2] = [(local[q][0], local[q + 1][1])]
        spans[q : q + 2] = [(spans[q][0], spans[q + 1][1])]
        del vertices[q + 1]
        sines = _parallel_pairs(modeller, local)

    keep = np.ones(len(vertices), dtype=bool)
    existing = (existing_left, existing_right)
    mu_all, sigma_all = _run_vertices(modeller, local)
    occluded = (_occluded(scan, s, s - 1), _occluded(scan, e, e + 1))
    if config.continuation_gate > 0.0:
        # The beams beyond an end lie on its line's extension: the line goes on there.
        continues = _continues(mu_all.reshape(-1, 2), scan, s, e, pose, sensor, config)
        occluded = (occluded[0] or continues[0], occluded[1] or continues[1])
    for end, sine in ((0, sines[0]), (-1, sines[-1])):
        if existing[end] and (sine <= limit or occluded[end]):
            keep[end] = False

    if _end_correction(config):
        # A new end vertex borders an inserted unobserved unknown line whose other end is
        # the existing vertex of the line it replaces.
        across = [None, None]
        if prior_mean is not None and not existing_left:
            across[0] = prior_mean[lines[t0].old_line]
        if prior_mean is not None and not existing_right:
            across[1] = prior_mean[lines[t1].old_line + 1]
        mu_all, sigma_all, unbounded = _end_quantization(
            mu_all, sigma_all, keep, occluded, across, scan, s, e, pose, sensor
        )
        for end in unbounded:  # the line's extent is not bounded by this scan
            if existing[end]:
                keep[end] = False
    dropped = [v for v, k in zip(vertices, keep, strict=True) if not k]
    mu_v = mu_all.reshape(-1, 2)
    u_fit = unknown_probabilities(mu_v, local, sensor, config)
    u_lines = [(a, b, float(u)) for (a, b), u in zip(spans, u_fit, strict=True)]

    idx = _block_indices(np.flatnonzero(keep))
    informed = [v for v, k in zip(vertices, keep, strict=True) if k]
    run = Run((t0, t1), s, e, tuple(informed), tuple(dropped))
    return informed, mu_all[idx], symmetrize(sigma_all[idx[:, None], idx]), dropped, u_lines, run


def _end_correction(config: ModelConfig) -> bool:
    """Whether the end-vertex corrections of this module are on (notes R-5; not in thesis).

    Vertices at the end of the observed part of a line: :func:`_end_quantization`
    (beam-spacing bias and variance of run end vertices), an existing run end whose next
    ray misses its line (grazing view) gets no information (:func:`observed_parameters`),
    the along-line condition of :func:`_terminates`, and
    :func:`_adopt_unknown_vertices`. ``config.end_vertex_correction`` (off in
    :meth:`ModelConfig.thesis`).
    """
    return bool(config.end_vertex_correction)


def _spacing_beyond(
    point: np.ndarray,
    along: np.ndarray,
    scan: Scan,
    beam: int,
    step: int,
    pose: np.ndarray,
    sensor: SensorConfig,
) -> float | None:
    """Distance [m] from ``point`` along the unit ``along`` to the next beam's ray.

    The next beam is one resolution step beyond ``beam`` (``step`` +1: to the left, -1:
    to the right). None when that ray does not meet the line beyond ``point``.
    """
    angle = pose[2] + scan.bearings[beam] + step * sensor.phi_res
    ray = np.array([np.cos(angle), np.sin(angle)])
    params = _segment_params(pose[:2], pose[:2] + ray, point, point + along)
    if params is None or params[0] <= 0.0 or params[1] <= 0.0:
        return None
    return params[1]


def _line_end(
    line_mu: np.ndarray,
    scan: Scan,
    beam: int,
    step: int,
    pose: np.ndarray,
    sensor: SensorConfig,
) -> tuple[np.ndarray, np.ndarray, float | None, float] | None:
    """Where a fitted line's observed part ends, at its edge ``beam``.

    Args:
        line_mu: ``(4,)`` two points ``[p0, p1]`` of the line, ``p1 - p0`` oriented from
            its first towards its last beam.
        beam: the line's first (``step`` +1) or last (``step`` -1) beam.

    Returns:
        ``(end, outward, ds, sigma_end)``: the end point on the beam's ray [m], the unit
        direction along the line away from the observed part, the spacing [m] to the next
        ray out (None if that ray does not meet the line: grazing view) and the end
        point's standard deviation along the line from the bearing noise [m]; None when
        the beam is parallel to the line.
    """
    p0, d = line_mu[:2], line_mu[2:] - line_mu[:2]
    d = d / np.hypot(*d)
    angle = pose[2] + scan.bearings[beam]
    ray = np.array([np.cos(angle), np.sin(angle)])
    params = _segment_params(pose[:2], pose[:2] + ray, p0, p0 + d)
    if params is None or params[0] <= 0.0:
        return None
    end = p0 + params[1] * d
    outward = -d if step > 0 else d
    sine = abs(ray[0] * d[1] - ray[1] * d[0])
    sigma_end = params[0] * sensor.sigma_bearing / sine
    return end, outward, _spacing_beyond(end, outward, scan, beam, step, pose, sensor), sigma_end


def _terminates(
    v_mean: np.ndarray,
    v_cov: np.ndarray,
    line_mu: np.ndarray,
    line_cov: np.ndarray,
    joined: bool,
    scan: Scan,
    beam: int,
    step: int,
    pose: np.ndarray,
    sensor: SensorConfig,
    config: ModelConfig,
    lin: Linearization,
) -> bool:
    """Whether a new line ends at the existing vertex ``v`` (Algorithm 4, 3.2.69-3.2.72).

    The thesis's test: the perpendicular Mahalanobis distance of the vertex to the line
    is at most ``vertex_match_mahalanobis``. The vertex must also be observable in this
    scan (the thesis's reason for inserting an unobserved unknown line, T:2735-2737):
    either it joins an observed neighbouring line (``joined``), or the line's edge
    ``beam`` is neither occluded nor at the field-of-view limit (Algorithm 5's test).
    With the end-vertex correction on (:func:`_end_correction`), two more conditions: a
    run end must be bounded (the next ray out meets the line), and the vertex must lie
    where the line can end, between the edge beam's ray and the next ray out, within
    ``vertex_match_mahalanobis`` standard deviations along the line (a far vertex, e.g. at
    ``r_max``, passes the perpendicular test on any short line).
    """
    gate = config.vertex_match_mahalanobis
    if perpendicular_mahalanobis(v_mean, v_cov, line_mu, line_cov, lin) > gate:
        return False
    if not joined and _occluded(scan, beam, beam - step):
        return False
    if not _end_correction(config):
        return True
    geometry = _line_end(line_mu, scan, beam, step, pose, sensor)
    if geometry is None:
        return False
    end, outward, ds, sigma_end = geometry
    if ds is None and not joined:
        return False
    t = float(outward @ (v_mean - end))
    sigma_t = np.sqrt(outward @ v_cov @ outward + sigma_end**2)
    upper = np.inf if ds is None else ds + gate * sigma_t
    return bool(-gate * sigma_t <= t <= upper)


def _end_quantization(
    mu: np.ndarray,
    sigma: np.ndarray,
    keep: np.ndarray,
    occluded: tuple[bool, bool],
    across: list[np.ndarray | None],
    scan: Scan,
    s: int,
    e: int,
    pose: np.ndarray,
    sensor: SensorConfig,
) -> tuple[np.ndarray, np.ndarray, list[int]]:
    """End-vertex correction of a run's kept end vertices (notes R-5; not in the thesis).

    An end vertex lies on the ray of the run's edge beam (3.2.7). Where the edge is a
    visible end of the line (not occluded), the line's true end lies anywhere between
    that ray and the next one out, where the line was not seen: a uniform error over
    the spacing ``ds`` along the line. The vertex is moved out by ``ds / 2`` and gets
    ``ds^2 / 12`` of extra variance along the line. A *new* end vertex that is occluded,
    or whose next ray misses the line, only marks where the observed part ends: the line
    goes on, up to the existing vertex ``across`` the inserted unobserved unknown line at
    the most, a distance ``l`` along the line; it keeps its place (the boundary of the
    observed part) and gets ``l^2 / 3`` of variance along the line (the mean square of a
    uniform error over ``[0, l]``). The extra variances are independent of everything
    else.

    Args:
        mu: ``(2q,)`` run vertex means [m]; ``sigma`` their ``(2q, 2q)`` covariance.
        keep: ``(q,)`` vertices that stay (dropped ends are not corrected).
        occluded: whether the left and right edge beams are occluded (or at the FOV limit).
        across: per end, the existing vertex across the inserted unknown line (new end
            vertices only), else None.
        s, e: the run's first and last beam.

    Returns:
        ``(mu, Sigma, unbounded)``: ``unbounded`` lists the ends (0 or -1) whose next ray
        does not meet the line beyond the vertex (grazing view).
    """
    mu = mu.copy()
    sigma = sigma.copy()
    v = mu.reshape(-1, 2)
    unbounded = []
    for side, (end, inner, beam, step) in enumerate(((0, 1, s, 1), (-1, v.shape[0] - 2, e, -1))):
        if not keep[end]:
            continue
        along = v[end] - v[inner]
        length = np.hypot(*along)
        if length == 0.0:
            continue
        along = along / length  # unit direction pointing out of the run at this end
        ds = _spacing_beyond(v[end], along, scan, beam, step, pose, sensor)
        if ds is None:
            unbounded.append(end)
        i = end % v.shape[0]
        block = slice(2 * i, 2 * i + 2)  # the vertex's coordinates
        if ds is not None and not occluded[side]:
            mu[block] += 0.5 * ds * along
            sigma[block, block] += (ds**2 / 12.0) * np.outer(along, along)
        elif across[side] is not None:
            reach = max(float(along @ (across[side] - v[end])), 0.0)
            sigma[block, block] += (reach**2 / 3.0) * np.outer(along, along)
    return mu, sigma, unbounded


def observed_parameters(
    obs: ObservedLines,
    scan: Scan,
    pose: np.ndarray,
    sensor: SensorConfig,
    config: ModelConfig,
    lin: Linearization,
    prior_mean: np.ndarray | None = None,
) -> ObservedParameters:
    """Algorithm 5 (ObservedParameters), corrected as in notes 4.3 (R-16, R-18).

    Each run of adjacent observed new lines is fitted together: one total-least-squares
    line per line's beams, vertices where adjacent lines meet (3.2.7-3.2.9) and the run's
    two end vertices on the rays of its first and last beam, all propagated from the
    beams by the linearisation (3.2.14). An end vertex that is an *existing* vertex is
    dropped (marginalised out: no information) when its beam is at the field-of-view
    limit, when the adjacent beam returns closer (occluded), or when the ray is nearly
    parallel to the line; a *new* end vertex is always kept. The kept vertices' Gaussian
    goes into ``C(K_obs, h_obs)``; runs are independent (disjoint beams). ``u_obs`` of
    each fitted line is eq. 3.2.36 over the run's fit (length per beam gap). With the
    end-vertex correction on, end vertices get :func:`_end_quantization` (which needs
    ``prior_mean``, the ``(k_old, 2)`` existing vertices) and an existing end vertex whose
    next ray misses its line (grazing view) is dropped too.

    Raises:
        DegenerateSegmentError: a new vertex cannot be fitted (nearly parallel lines).
        NotPositiveDefiniteError: a run's vertex covariance is singular.
    """
    n_lines = len(obs.lines)
    k_new = n_lines + 1
    K = np.zeros((2 * k_new, 2 * k_new))
    h = np.zeros(2 * k_new)
    u_obs = np.ones(n_lines)
    runs: list[Run] = []
    t = 0
    while t < n_lines:
        if not obs.lines[t].observed:
            t += 1
            continue
        t0 = t
        while t < n_lines and obs.lines[t].observed:
            t += 1
        informed, mu, sigma, _, u_lines, run = _fit_run(
            obs.lines, t0, t, scan, pose, sensor, config, lin, prior_mean
        )
        runs.append(run)
        for a, b, u in u_lines:
            u_obs[a:b] = u
        if informed:
            canon = Canonical.from_moments(mu, sigma)
            idx = _block_indices(informed)
            K[idx[:, None], idx] = canon.K
            h[idx] = canon.h
    return ObservedParameters(K, h, u_obs, tuple(runs))


# ------------------------------------------------------------------------ Algorithm 6


def observed_vertices(
    obs: ObservedLines, K_obs: np.ndarray, u: np.ndarray, u_closing: float | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Algorithm 6 (ObservedVertices), corrected as in notes 4.4 (R-19).

    Args:
        obs: Algorithm 4's new lines.
        K_obs: ``(2k_new, 2k_new)`` observation information.
        u: ``(m,)`` unknown probabilities of the existing open chain's lines.
        u_closing: for a closed model, the closing line's ``u`` (carried over).

    Returns:
        ``(vartheta, u_prime, old_of)``: per new vertex 0 (no information), 1 (existing,
        observed) or 2 (new); the prior's ``u`` in the new space (lines not replaced
        keep theirs, replaced or inserted lines get 1); per new vertex the existing
        vertex it is, -1 if new.
    """
    n_lines = len(obs.lines)
    k_new = n_lines + 1
    vartheta = np.zeros(k_new, dtype=int)
    old_of = np.full(k_new, -1, dtype=int)
    u_prime = np.ones(n_lines)
    for a, ln in enumerate(obs.lines):
        if ln.j == 0:
            old_of[a] = ln.old_line
        if len(obs.zeta[ln.old_line]) == 1:
            u_prime[a] = u[ln.old_line]
    old_of[-1] = len(obs.zeta)
    informed = np.any(K_obs.reshape(k_new, 2, k_new * 2) != 0.0, axis=(1, 2))
    vartheta[informed] = np.where(old_of[informed] >= 0, 1, 2)
    if u_closing is not None:
        u_prime = np.append(u_prime, u_closing)
    return vartheta, u_prime, old_of


def placement_matrix(old_of: np.ndarray, k_old: int) -> np.ndarray:
    """``F`` (3.2.73-3.2.74): ``(2k_old, 2k_new)`` with ``I_2`` at (old, new) pairs.

    Built from ``old_of`` rather than ``vartheta < 2`` (R-19): columns of new vertices
    are zero.
    """
    k_new = old_of.size
    F = np.zeros((2 * k_old, 2 * k_new))
    new = np.flatnonzero(old_of >= 0)
    rows = _block_indices(old_of[new])
    cols = _block_indices(new)
    F[rows, cols] = 1.0
    return F


def selection_matrix(vartheta: np.ndarray) -> np.ndarray:
    """``G`` (3.2.82-3.2.84): ``(2m_o, 2k_new)`` selecting the vertices with ``vartheta > 0``."""
    chosen = np.flatnonzero(np.asarray(vartheta) > 0)
    G = np.zeros((2 * chosen.size, 2 * np.size(vartheta)))
    G[np.arange(2 * chosen.size), _block_indices(chosen)] = 1.0
    return G


def combine(
    prior: LandmarkModel, F: np.ndarray, K_obs: np.ndarray, h_obs: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Posterior in the new space (3.2.78-3.2.79): ``K = F^T K_v F + K_obs``, ``h`` alike.

    Returns:
        ``(mean (k_new, 2), cov (2k_new, 2k_new))``.

    Raises:
        NotPositiveDefiniteError: the posterior information matrix is singular (some new
            vertex has no information) or the prior covariance is not positive definite.
    """
    canon = Canonical.from_moments(prior.mean.reshape(-1), prior.cov)
    post = canon.transform(F) + Canonical(K_obs, h_obs)
    mu, cov = post.to_moments()
    return mu.reshape(-1, 2), ensure_spd(cov, "posterior vertex covariance")


def observation_conditional(
    K_obs: np.ndarray, h_obs: np.ndarray, G: np.ndarray, pose: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Conditional form of the observation on the pose (3.2.81-3.2.90), SPEC-corrected.

    ``K'_obs = G K_obs G^T``, ``mu'_obs = K'_obs^-1 G h_obs``; ``A'_vx`` from
    :func:`~vslam_gym.slam.landmark.conditional_on_pose` at ``mu'_obs`` and the pose;
    ``b'_vx = mu'_obs - A'_vx x`` (the thesis prints the polar mean) and
    ``A_vx = G^T A'_vx``, ``b_vx = G^T b'_vx`` (the thesis prints ``G^T A' G``).

    Returns:
        ``(A_vx (2k_new, 3), b_vx (2k_new,))``; zero rows for unobserved vertices.
    """
    if G.shape[0] == 0:
        return np.zeros((G.shape[1], 3)), np.zeros(G.shape[1])
    K_sel = symmetrize(G @ K_obs @ G.T)
    upper = cho_factor_finite(ensure_spd(K_sel, "observed information G K_obs G^T"))  # finite
    h_sel = G @ h_obs
    if np.isfinite(h_sel).all():
        mu_sel = cho_solve_finite(upper, h_sel, lower=False)
    else:  # scipy's finiteness check raises its error
        mu_sel = scipy.linalg.cho_solve((upper, False), h_sel)
    a_sel, b_sel = conditional_on_pose(mu_sel.reshape(-1, 2), pose)
    return G.T @ a_sel, G.T @ b_sel


# ------------------------------------------------------------------------ Algorithm 7


@dataclass
class _Chain:
    """Chain vertices ``outer -> inner`` (last: the attach vertex) with their sources."""

    mean: np.ndarray  # (n, 2)
    cov: np.ndarray  # (n, 2, 2)
    source: np.ndarray  # (n,) input vertex index or -1

    def __len__(self) -> int:
        return int(self.source.size)

    def item(self, i: int) -> tuple[np.ndarray, np.ndarray, int]:
        return self.mean[i], self.cov[i], int(self.source[i])

    def reversed(self) -> _Chain:
        return _Chain(self.mean[::-1].copy(), self.cov[::-1].copy(), self.source[::-1].copy())

    @classmethod
    def of(cls, items: list[tuple[np.ndarray, np.ndarray, int]]) -> _Chain:
        if not items:
            return cls(np.zeros((0, 2)), np.zeros((0, 2, 2)), np.zeros(0, dtype=int))
        return cls(
            np.array([it[0] for it in items], dtype=float).reshape(-1, 2),
            np.array([it[1] for it in items], dtype=float).reshape(-1, 2, 2),
            np.array([it[2] for it in items], dtype=int),
        )


def _model_chain(model: LandmarkModel, vertices) -> _Chain:
    v = np.asarray(vertices, dtype=int)
    covs = np.array([model.vertex_cov(i) for i in v]).reshape(-1, 2, 2)
    return _Chain(model.mean[v].reshape(-1, 2).copy(), covs, v.copy())


def _prior_chain(model: LandmarkModel, chains: ChainContext, side: str) -> _Chain:
    """The prior unknown chain of one side with its attach vertex (left: outer first)."""
    indices = chains.prior_left if side == "left" else chains.prior_right
    items = []
    for pos, i in enumerate(indices):
        if i >= 0:
            items.append((model.mean[i], model.vertex_cov(i), int(i)))
        else:
            mean, cov = chains.prior_points[(side, pos)]
            items.append((mean, cov, -1))
    if side == "left":
        i = chains.attach_prior[0]
        return _Chain.of([*items, (model.mean[i], model.vertex_cov(i), int(i))])
    i = chains.attach_prior[1]
    return _Chain.of([(model.mean[i], model.vertex_cov(i), int(i)), *items])


def _segment_params(p, q, c, d) -> tuple[float, float] | None:
    """``(s, t)`` with ``p + s (q - p) = c + t (d - c)``; None when parallel.

    Points are any 2-sequences; the arithmetic is done on Python floats (the hot loops of
    Algorithm 7 call this on single segments).
    """
    px, py = float(p[0]), float(p[1])
    rx, ry = float(q[0]) - px, float(q[1]) - py
    cx, cy = float(c[0]), float(c[1])
    wx, wy = float(d[0]) - cx, float(d[1]) - cy
    den = rx * wy - ry * wx
    scale = math.hypot(rx, ry) * math.hypot(wx, wy)
    if scale == 0.0 or abs(den) <= _SEGMENT_EPS * scale:
        return None
    gx, gy = cx - px, cy - py
    return (gx * wy - gy * wx) / den, (gx * ry - gy * rx) / den


def _segments_params(
    p: np.ndarray, q: np.ndarray, c: np.ndarray, d: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`_segment_params` batched over ``(..., 2)`` arrays (same arithmetic).

    Returns:
        ``(ok, s, t)``: where the segments are not parallel, and their parameters there
        (``nan`` elsewhere).
    """
    r = q - p
    w = d - c
    den = r[..., 0] * w[..., 1] - r[..., 1] * w[..., 0]
    scale = np.hypot(r[..., 0], r[..., 1]) * np.hypot(w[..., 0], w[..., 1])
    ok = (scale != 0.0) & (np.abs(den) > _SEGMENT_EPS * scale)
    g = c - p
    with np.errstate(divide="ignore", invalid="ignore"):
        s = np.where(ok, (g[..., 0] * w[..., 1] - g[..., 1] * w[..., 0]) / den, np.nan)
        t = np.where(ok, (g[..., 0] * r[..., 1] - g[..., 1] * r[..., 0]) / den, np.nan)
    return ok, s, t


def _intersection(endpoints: list[tuple[np.ndarray, np.ndarray]], lin: Linearization):
    """Gaussian of the intersection of lines ``(e0, e1)`` and ``(e2, e3)`` (3.2.8).

    The four endpoints are taken as independent with their marginal covariances (unknown
    vertices are independent by convention, 3.2.35; notes 4.8).
    """
    mu = np.concatenate([m for m, _ in endpoints])
    cov = np.zeros((2 * len(endpoints), 2 * len(endpoints)))
    for i, (_, c) in enumerate(endpoints):
        cov[2 * i : 2 * i + 2, 2 * i : 2 * i + 2] = c

    def f(x: np.ndarray) -> np.ndarray:
        p, q, c, d = x[..., 0:2], x[..., 2:4], x[..., 4:6], x[..., 6:8]
        return _intersect(p, q - p, c, d - c)[0]

    mean, sigma = lin.propagate(f, mu, cov, check=False)
    return mean.reshape(2), ensure_spd(sigma.reshape(2, 2), "unknown-line intersection")


def _walk(chosen: _Chain, other: _Chain, lin: Linearization) -> _Chain:
    """Algorithm 7 lines 18-35 on two chains ordered outer -> inner (last: attach).

    Follows ``chosen`` outward from its attach vertex; at the first crossing (smallest
    parameter along the current segment, touching at the start excluded) with a segment
    of the other chain, continues along the other chain (swap with ``na := j``, R-21).
    Returns the merged chain, outer -> inner, ending with ``chosen``'s attach vertex.
    """
    a, b = chosen, other
    na, nb = len(a) - 1, len(b) - 1
    cur = a.mean[na]
    out = [a.item(na)]
    guard = 4 * (len(a) + len(b))
    while na > 0 and guard > 0:
        guard -= 1
        target = a.mean[na - 1]
        hit = None
        other = b.mean.tolist()
        for j in range(nb, 0, -1):
            params = _segment_params(cur, target, other[j], other[j - 1])
            if params is None:
                continue
            s, t = params
            if _SEGMENT_EPS < s <= 1.0 and -_SEGMENT_EPS <= t <= 1.0 + _SEGMENT_EPS:
                if hit is None or s < hit[0]:
                    hit = (s, j)
        if hit is None:
            out.insert(0, a.item(na - 1))
            cur = target
            na -= 1
            continue
        j = hit[1]
        mean, cov = _intersection(
            [
                (a.mean[na], a.cov[na]),
                (a.mean[na - 1], a.cov[na - 1]),
                (b.mean[j], b.cov[j]),
                (b.mean[j - 1], b.cov[j - 1]),
            ],
            lin,
        )
        out.insert(0, (mean, cov, -1))
        cur = mean
        a, b = b, a
        na, nb = j, na
    if na > 0:  # guard exhausted (cannot happen for finite chains): keep the rest
        out[0:0] = [a.item(i) for i in range(na)]
    return _Chain.of(out)


def _ccw(angle: float) -> float:
    return float(np.mod(angle, 2.0 * np.pi))


def _merge_side(
    observed: _Chain,
    prior: _Chain,
    io: int,
    ip: int,
    next_vertex: np.ndarray,
    lin: Linearization,
    mirror: bool = False,
) -> _Chain:
    """Algorithm 7 for one side (chains outer -> inner); returns the merged chain.

    The chain that starts farther out is followed first; when both attach at the same
    vertex, the one whose first line makes the smaller counter-clockwise angle from the
    first object line (clockwise on the right, ``mirror``): it claims more free space
    (notes 4.8). Ties go to the observed chain.
    """
    if io < ip:
        first = "obs"
    elif ip < io:
        first = "pre"
    else:
        v = observed.mean[-1]
        base = np.arctan2(*(next_vertex - v)[::-1])

        def angle(chain: _Chain) -> float:
            if len(chain) < 2:
                return np.inf
            d = chain.mean[-2] - v
            turn = np.arctan2(d[1], d[0]) - base
            return _ccw(-turn if mirror else turn)

        first = "obs" if angle(observed) <= angle(prior) else "pre"
    if first == "obs":
        return _walk(observed, prior, lin)
    return _walk(prior, observed, lin)


def _chain_crossing(left: _Chain, right: _Chain) -> tuple[int, int, float, float] | None:
    """Crossing of the left chain (outer -> attach) with the right (attach -> outer).

    Returns ``(i, j, s, t)`` for left segment ``i`` (``left[i] -> left[i+1]``) and right
    segment ``j`` (``right[j] -> right[j+1]``) minimising the summed arc length from the
    two attach vertices to the crossing, or None.
    """
    nl, nr = len(left), len(right)
    if nl < 2 or nr < 2:
        return None
    seg_l, seg_r = _segment_lengths(left.mean), _segment_lengths(right.mean)
    best = None
    # All segment pairs at once; the (few) crossings are then ranked in (i, j) order.
    ok, s_all, t_all = _segments_params(
        left.mean[:-1, None], left.mean[1:, None], right.mean[None, :-1], right.mean[None, 1:]
    )
    inside = (s_all > _SEGMENT_EPS) & (s_all < 1 - _SEGMENT_EPS)
    inside &= (t_all > _SEGMENT_EPS) & (t_all < 1 - _SEGMENT_EPS)
    for i, j in zip(*np.nonzero(ok & inside), strict=True):
        i, j = int(i), int(j)
        s, t = float(s_all[i, j]), float(t_all[i, j])
        arc = seg_l[i + 1 :].sum() + (1 - s) * seg_l[i] + seg_r[:j].sum() + t * seg_r[j]
        if best is None or arc < best[0]:
            best = (arc, i, j, s, t)
    return None if best is None else best[1:]


def update_unknown_lines(
    model: LandmarkModel,
    chains: ChainContext,
    scan: Scan,
    pose: np.ndarray,
    sensor: SensorConfig,
    config: ModelConfig,
    lin: Linearization,
) -> UnknownLineUpdate:
    """Algorithm 7 at both ends, then the left/right chain crossing (notes 4.8).

    Per side the prior chain (the prior model's unknown vertices at their posterior
    positions, attached at its first (last) object vertex) is merged with the chain seen
    from ``pose``: the creation rules (:func:`~vslam_gym.slam.creation.end_vertices`) at
    the beam beside the leftmost (rightmost) beam used, attached at the first run's left
    (last run's right) end vertex, even if that vertex got no information (R-20). The
    merged chain replaces every vertex before ``min(io, ip)`` (after ``max(io, ip)`` on
    the right). If the two chains then cross, both end at the crossing closest to the
    model (two independent copies of the point). Kept vertices keep their rows of the
    joint covariance (the others are marginalised out); new ones are independent.

    Args:
        model: posterior model in the new vertex space (open chain).
        chains: the bookkeeping of the update (:attr:`ModelUpdate.chains`).
        scan, pose, sensor, config, lin: the scan and the pose of the update.

    Returns:
        The model with merged chains and how its vertices map to the input's.
    """
    (ip_l, ip_r), (io_l, io_r) = chains.attach_prior, chains.attach_observed
    (obs_l_mu, obs_l_cov), (obs_r_mu, obs_r_cov) = end_vertices(
        scan, chains.beams[0], chains.beams[1], pose, sensor, config, lin
    )

    def observed_chain(mu, cov) -> _Chain:
        q = mu.shape[0]
        blocks = np.array([cov[2 * i : 2 * i + 2, 2 * i : 2 * i + 2] for i in range(q)])
        return _Chain(mu.copy(), blocks.reshape(-1, 2, 2), np.full(q, -1, dtype=int))

    def join(x: _Chain, y: _Chain) -> _Chain:
        return _Chain(
            np.concatenate([x.mean, y.mean]),
            np.concatenate([x.cov, y.cov]),
            np.concatenate([x.source, y.source]),
        )

    # Left: chains outer -> inner ending at their attach vertex.
    obs_left = join(observed_chain(obs_l_mu, obs_l_cov), _model_chain(model, [io_l]))
    pre_left = _prior_chain(model, chains, "left")
    lo = min(io_l, ip_l)
    left = _merge_side(obs_left, pre_left, io_l, ip_l, model.mean[lo + 1], lin)
    left = _Chain(left.mean[:-1], left.cov[:-1], left.source[:-1])

    # Right: mirror (reverse to outer -> inner, merge, reverse back).
    obs_right = join(_model_chain(model, [io_r]), observed_chain(obs_r_mu, obs_r_cov))
    pre_right = _prior_chain(model, chains, "right")
    hi = max(io_r, ip_r)
    # Mirrored indices: "farther out" on the right means a larger index.
    right = _merge_side(
        obs_right.reversed(), pre_right.reversed(), -io_r, -ip_r, model.mean[hi - 1], lin, True
    )
    right = right.reversed()
    right = _Chain(right.mean[1:], right.cov[1:], right.source[1:])

    core = _model_chain(model, np.arange(lo, hi + 1))
    # Left and right chains crossing: both end there (notes 4.8, T:3522-3528).
    crossed = False
    left_full = join(left, _model_chain(model, [lo]))
    right_full = join(_model_chain(model, [hi]), right)
    hit = _chain_crossing(left_full, right_full)
    if hit is not None:
        i, j, _, _ = hit
        mean, cov = _intersection(
            [
                (left_full.mean[i], left_full.cov[i]),
                (left_full.mean[i + 1], left_full.cov[i + 1]),
                (right_full.mean[j], right_full.cov[j]),
                (right_full.mean[j + 1], right_full.cov[j + 1]),
            ],
            lin,
        )
        x = _Chain.of([(mean, cov, -1)])
        inner_left = _Chain(
            left_full.mean[i + 1 : -1], left_full.cov[i + 1 : -1], left_full.source[i + 1 : -1]
        )
        inner_right = _Chain(
            right_full.mean[1 : j + 1], right_full.cov[1 : j + 1], right_full.source[1 : j + 1]
        )
        left = join(x, inner_left)
        right = join(inner_right, x)
        crossed = True

    full = join(join(left, core), right)
    k = len(full)
    # A vertex met twice (a prior unknown vertex that the observation also reached) is
    # kept once, in the core if there; other occurrences become independent copies.
    source = full.source.copy()
    order = [
        *range(len(left), len(left) + len(core)),
        *range(len(left)),
        *range(len(left) + len(core), k),
    ]
    seen: set[int] = set()
    for i in order:
        if source[i] >= 0:
            if source[i] in seen:
                source[i] = -1
            seen.add(int(full.source[i]))
    kept = np.flatnonzero(source >= 0)
    cov = np.zeros((2 * k, 2 * k))
    idx_new = _block_indices(kept)
    idx_old = _block_indices(source[kept])
    cov[idx_new[:, None], idx_new] = model.cov[idx_old[:, None], idx_old]
    for i in np.flatnonzero(source < 0):
        cov[2 * i : 2 * i + 2, 2 * i : 2 * i + 2] = full.cov[i]
    u = np.concatenate([np.ones(len(left)), model.u[lo:hi], np.ones(len(right))])
    new_model = LandmarkModel(full.mean.copy(), symmetrize(cov), u, closed=False)
    start = len(left)
    return UnknownLineUpdate(new_model, source.copy(), (start, start + len(core)), crossed)


# ------------------------------------------------------------------------------ wrapping


def wrap_model(model: LandmarkModel, object_vertices: tuple[int, int], config: ModelConfig) -> Wrap:
    """Close the polygon when its first and last object vertices coincide (3.2.91-3.2.95).

    ``mu_d = mu_l - mu_r``, ``Sigma_d = S_ll + S_rr - S_lr - S_rl``; wrap when the
    Mahalanobis distance ``sqrt(mu_d^T Sigma_d^-1 mu_d)`` is below
    ``config.wrap_mahalanobis``. Wrapping marginalises the unknown chains out (R-29),
    folds ``v_r`` into ``v_l`` in canonical form (``K' = S^T K S``, ``h' = S^T h``: 3.2.95
    with ``K_vc`` read as ``K_cc``), closes the polygon (the last object line now ends at
    ``v_l``) and keeps the object lines' ``u``.

    Args:
        model: an open model.
        object_vertices: ``(start, stop)`` of its object vertices.
        config: gives ``wrap_mahalanobis``.

    Returns:
        The wrap decision and the closed model (the input model when not wrapped).
    """
    start, stop = object_vertices
    keep = np.arange(start, stop)
    if model.closed or keep.size < 4:  # a closed polygon needs at least 3 vertices
        return Wrap(model, False, float("nan"), keep, np.zeros((0, 0)))
    lb, rb = slice(2 * start, 2 * start + 2), slice(2 * stop - 2, 2 * stop)  # v_l, v_r
    mu_d = model.mean[start] - model.mean[stop - 1]
    c = model.cov
    sigma_d = c[lb, lb] + c[rb, rb] - c[lb, rb] - c[rb, lb]
    distance = float(np.sqrt(mu_d @ np.linalg.solve(ensure_spd(sigma_d, "Sigma_delta"), mu_d)))
    if not distance < config.wrap_mahalanobis:
        return Wrap(model, False, distance, keep, np.zeros((0, 0)))
    q = keep.size
    S = np.zeros((2 * q, 2 * (q - 1)))
    S[: 2 * (q - 1), :] = np.eye(2 * (q - 1))
    S[2 * (q - 1) :, 0:2] = np.eye(2)
    idx = _block_indices(keep)
    canon = Canonical.from_moments(model.mean.reshape(-1)[idx], model.cov[np.ix_(idx, idx)])
    mu, cov = canon.transform(S).to_moments()
    u = model.u[start : stop - 1].copy()
    closed = LandmarkModel(mu.reshape(-1, 2), ensure_spd(cov, "wrapped vertex covariance"), u, True)
    return Wrap(closed, True, distance, keep, S)


# ---------------------------------------------------------------------------- entry point


def _adopt_unknown_vertices(
    chain: LandmarkModel, starts: tuple[int, int], old_of: np.ndarray, vartheta: np.ndarray
) -> None:
    """Observed unknown-chain vertices start afresh as object vertices (not in the thesis).

    A prior unknown vertex (outside ``starts``) that the observation now places at the
    end of an object line (Algorithm 4's termination test matched it) carries prior
    information about a different point: a return of a neighbouring beam, a point at
    ``r_max`` or a crossing of unknown chains, not the object's corner. Such a vertex is
    marginalised out and replaced by a new vertex (``old_of = -1``, ``vartheta = 2``) with
    the observation's information only. Done in place, and only for a vertex independent
    of all others (true of unknown vertices, 3.2.35), so that leaving it out of ``F``
    marginalises it.
    """
    k_old = chain.n_vertices
    for a in np.flatnonzero((old_of >= 0) & (vartheta > 0)):
        o = old_of[a]
        if starts[0] <= o < starts[1]:
            continue
        rows = _block_indices([o])
        others = np.setdiff1d(np.arange(2 * k_old), rows)
        if np.any(chain.cov[np.ix_(rows, others)] != 0.0):
            continue
        old_of[a] = -1
        vartheta[a] = 2


def _rotate_closed(model: LandmarkModel, line_of_beam: np.ndarray) -> tuple[np.ndarray, int]:
    """Vertex order putting a line without beams (else the fewest) at the closing position.

    Returns ``(perm, c)``: rotated vertex ``r`` is original vertex ``perm[r]``; original
    line ``c`` becomes the closing line (notes 4.9 step 4).
    """
    k = model.n_vertices
    counts = np.bincount(line_of_beam[line_of_beam >= 0], minlength=k)
    # Among the emptiest lines prefer the one farthest (in line order) from observed ones.
    empty = counts == counts.min()
    c = int(np.flatnonzero(empty)[0])
    if counts.max() > 0:
        observed = np.flatnonzero(counts > 0)
        gap = np.array(
            [
                np.min(np.minimum((j - observed) % k, (observed - j) % k)) if empty[j] else -1
                for j in range(k)
            ]
        )
        c = int(np.argmax(gap))
    perm = (c + 1 + np.arange(k)) % k
    return perm, c


def update_model(
    model: LandmarkModel,
    scan: Scan,
    first: int,
    last: int,
    pose,
    sensor: SensorConfig,
    config: ModelConfig,
    linearization: Linearization | None = None,
    association=None,
    *,
    object_vertices: tuple[int, int] | None = None,
    finish: bool = True,
) -> ModelUpdate:
    """Update ``model`` with beams ``first..last`` of ``scan`` taken at a known ``pose``.

    SPEC section 9, thesis 3.2.62-3.2.95: association, Algorithms 4-6, the posterior in
    canonical form, the conditional form of the observation, Algorithm 7 and wrapping
    (see the module docstring). The input model is never modified; on any exception
    nothing has changed.

    Args:
        model: the existing landmark model (world frame).
        scan: the scan (lidar frame).
        first: scan index of the segment's first (leftmost) beam.
        last: scan index of its last beam (inclusive); all beams between have returns.
        pose: ``(3,)`` lidar pose ``[x, y, theta]`` (world frame), taken as known.
        sensor: sensor parameters.
        config: model parameters (thresholds; the linearisation when ``linearization``
            is None).
        linearization: Gaussian map; ``make_linearization(config)`` when None.
        association: beam-to-line correspondences of the segment: a
            :class:`~vslam_gym.slam.detection.Detection` or
            :class:`~vslam_gym.slam.detection.BeamAssociation` (beams without a
            candidate are not used), or ``(n,)`` line indices with -1 for unused beams;
            computed at ``pose`` when None.
        object_vertices: ``(start, stop)`` of the model's object vertices
            (``ModelFit.object_vertices`` or the previous ``ModelUpdate``'s); inferred
            from ``u`` when None (:func:`infer_object_vertices`).
        finish: run Algorithm 7 and wrapping (:func:`update_unknown_lines`,
            :func:`wrap_model`) on the posterior. The SLAM filter passes False: it
            uses ``F``, ``K_obs``, ``A_vx``, ``b_vx``, ``posterior`` and ``chains`` and
            runs both steps itself on its own posterior at the updated pose. Then
            ``model`` is ``posterior``, ``unknown`` and ``wrap`` are None and
            ``object_vertices`` spans the posterior's first to last object line.

    Returns:
        The update (posterior model, ``F``, ``K_obs``, ``h_obs``, ``G``, ``A_vx``,
        ``b_vx``, ``vartheta`` and the intermediate results).

    Raises:
        ValueError: bad input (segment, pose, association, model).
        UpdateError: the association is inconsistent or a new vertex got no information.
        DegenerateSegmentError: a new vertex cannot be fitted.
        NotPositiveDefiniteError: a covariance that must be positive definite is not.
    """
    first, last, pose = _check_inputs(model, scan, first, last, pose)
    lin = linearization or make_linearization(config)
    prior = model.copy()
    k_old = prior.n_vertices
    line_of_beam = _association_lines(
        association, prior, scan, first, last, pose, sensor, config, lin
    )

    # A closed model is updated as the open chain that ends at a line without beams.
    if prior.closed:
        perm, c = _rotate_closed(prior, line_of_beam)
        idx = _block_indices(perm)
        chain = LandmarkModel(
            prior.mean[perm], prior.cov[np.ix_(idx, idx)], np.roll(prior.u, -(c + 1))[:-1]
        )
        u_closing = float(prior.u[c])
        lines_rot = np.where(line_of_beam >= 0, (line_of_beam - (c + 1)) % k_old, -1)
        lines_rot = np.where(lines_rot == k_old - 1, -1, lines_rot)  # beams on the closing line
        starts = (0, k_old)
    else:
        perm = np.arange(k_old)
        chain, u_closing, lines_rot = prior, None, line_of_beam
        starts = object_vertices or infer_object_vertices(prior)
        if not (0 <= starts[0] < starts[1] - 1 < k_old):
            raise ValueError(f"object_vertices {starts} do not fit a model of {k_old} vertices")

    if config.exclusive_boundaries:
        lines_rot = _refine_boundaries(lines_rot, chain.u, scan, first, pose, config)
    try:
        obs = observed_lines(chain, lines_rot, first, scan, pose, sensor, config, lin)
        params = observed_parameters(obs, scan, pose, sensor, config, lin, chain.mean)
    except InterleavedError:
        # Lines whose beams interleave beyond a boundary ambiguity: once more with the
        # association made to follow the line order.
        lines_rot = _monotone_association(lines_rot, config)
        obs = observed_lines(chain, lines_rot, first, scan, pose, sensor, config, lin)
        params = observed_parameters(obs, scan, pose, sensor, config, lin, chain.mean)
    if prior.closed:
        used = np.where(lines_rot >= 0, (lines_rot + c + 1) % k_old, -1)
    else:
        used = lines_rot
    vartheta, u_prime, old_of = observed_vertices(obs, params.K_obs, chain.u, u_closing)
    if not prior.closed and _end_correction(config):
        _adopt_unknown_vertices(chain, starts, old_of, vartheta)
    new_vertices = np.flatnonzero(old_of < 0)
    if np.any(vartheta[new_vertices] == 0):
        raise UpdateError(
            f"new vertices {new_vertices[vartheta[new_vertices] == 0]} got no information"
        )
    F_chain = placement_matrix(old_of, k_old)
    mean, cov = combine(chain, F_chain, params.K_obs, params.h_obs)
    u_obs = params.u_obs if u_closing is None else np.append(params.u_obs, 1.0)
    u_new = np.minimum(u_prime, u_obs)
    posterior = LandmarkModel(mean, cov, u_new, closed=prior.closed)
    G = selection_matrix(vartheta)
    A_vx, b_vx = observation_conditional(params.K_obs, params.h_obs, G, pose)
    # F in the input model's vertex order (rows of a closed model were rotated).
    F = np.zeros_like(F_chain)
    F[_block_indices(perm)] = F_chain

    chains = unknown = wrap = None
    final = posterior
    if prior.closed:
        object_range = (0, posterior.n_vertices)
    elif not params.runs:
        new_of_old = np.full(k_old, -1)
        new_of_old[old_of[old_of >= 0]] = np.flatnonzero(old_of >= 0)
        object_range = (int(new_of_old[starts[0]]), int(new_of_old[starts[1] - 1]) + 1)
    else:
        new_of_old = np.full(k_old, -1)
        new_of_old[old_of[old_of >= 0]] = np.flatnonzero(old_of >= 0)
        points = {}
        for side, olds in (("left", range(starts[0])), ("right", range(starts[1], k_old))):
            for pos, o in enumerate(olds):
                if new_of_old[o] < 0:
                    points[(side, pos)] = (chain.mean[o].copy(), chain.vertex_cov(o).copy())
        chains = ChainContext(
            prior_left=tuple(int(i) for i in new_of_old[: starts[0]]),
            prior_right=tuple(int(i) for i in new_of_old[starts[1] :]),
            attach_prior=(int(new_of_old[starts[0]]), int(new_of_old[starts[1] - 1])),
            attach_observed=(params.runs[0].lines[0], params.runs[-1].lines[1]),
            beams=(params.runs[0].first_beam, params.runs[-1].last_beam),
            prior_points=points,
        )
        if finish:
            unknown = update_unknown_lines(posterior, chains, scan, pose, sensor, config, lin)
            wrap = wrap_model(unknown.model, unknown.object_vertices, config)
            final = wrap.model
            if wrap.wrapped:
                object_range = (0, final.n_vertices)
            else:
                object_range = unknown.object_vertices
        else:
            obj = np.flatnonzero(posterior.u <= config.unknown_threshold)
            object_range = (int(obj[0]), int(obj[-1]) + 2) if obj.size else (0, 0)
    if finish:
        final = LandmarkModel(
            final.mean, ensure_spd(final.cov, "updated vertex covariance"), final.u, final.closed
        )
    observed = obs.observed
    if prior.closed:  # back to the input's line order; the closing line had no beams
        observed = np.roll(np.append(observed, False), c + 1)
    return ModelUpdate(
        model=final,
        F=F,
        K_obs=params.K_obs,
        h_obs=params.h_obs,
        G=G,
        A_vx=A_vx,
        b_vx=b_vx,
        vartheta=vartheta,
        observed_lines=observed,
        wrapped=bool(wrap is not None and wrap.wrapped),
        zeta=obs.zeta,
        old_of=np.where(old_of >= 0, perm[np.maximum(old_of, 0)], -1),
        u_prior=u_prime,
        u_obs=u_obs,
        posterior=posterior,
        chains=chains,
        unknown=unknown,
        wrap=wrap,
        object_vertices=object_range,
        association=used,
        runs=params.runs,
    )
