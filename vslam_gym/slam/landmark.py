"""The landmark model: a probabilistic polyline of Gaussian vertices (SPEC sections 3, 6, 7).

A landmark is ``k`` vertices in the world frame with a joint Gaussian over their
coordinates, ordered ``[left unknown..., object vertices..., right unknown...]`` as seen
when the model was built (left to right). Line ``j`` joins vertex ``j`` and ``j + 1``; a
closed (wrapped) polygon has one more line, from the last vertex back to vertex 0.
``u[j]`` is the probability that line ``j`` is an unknown line (a boundary between free
and unobserved space) rather than an object boundary.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from vslam_gym.slam.geometry import stack_last


@dataclass
class LandmarkModel:
    """Gaussian vertices of one landmark.

    Attributes:
        mean: ``(k, 2)`` vertex means [m], world frame.
        cov: ``(2k, 2k)`` joint covariance [m^2], ordered ``[v0x, v0y, v1x, v1y, ...]``.
        u: ``(n_lines,)`` unknown probability of each line, in [0, 1].
        closed: True when the polyline is a closed polygon (wrapped).
    """

    mean: np.ndarray
    cov: np.ndarray
    u: np.ndarray
    closed: bool = False

    def __post_init__(self) -> None:
        self.mean = np.asarray(self.mean, dtype=float).reshape(-1, 2)
        self.cov = np.asarray(self.cov, dtype=float)
        self.u = np.asarray(self.u, dtype=float).reshape(-1)
        k = self.mean.shape[0]
        if self.cov.shape != (2 * k, 2 * k):
            raise ValueError(
                f"cov must be ({2 * k}, {2 * k}) for {k} vertices, got {self.cov.shape}"
            )
        if self.u.size != self.n_lines:
            raise ValueError(f"u must have {self.n_lines} entries, got {self.u.size}")

    @classmethod
    def _trusted(
        cls, mean: np.ndarray, cov: np.ndarray, u: np.ndarray, closed: bool
    ) -> LandmarkModel:
        """A model of arrays already in form, stored as given (no conversion, no checks).

        For internal hot paths rebuilding a model from data that a checked construction
        accepted before: float ``(k, 2)`` means, ``(2k, 2k)`` covariance and
        ``(n_lines,)`` ``u``.
        """
        model = object.__new__(cls)
        model.mean, model.cov, model.u, model.closed = mean, cov, u, closed
        return model

    @property
    def n_vertices(self) -> int:
        """Number of vertices ``k``."""
        return int(self.mean.shape[0])

    @property
    def n_lines(self) -> int:
        """Number of lines: ``k - 1`` for an open polyline, ``k`` for a closed polygon."""
        k = self.n_vertices
        return k if self.closed else max(k - 1, 0)

    def line_vertices(self) -> np.ndarray:
        """``(n_lines, 2)`` int: the vertex indices ``(a, b)`` of each line."""
        j = np.arange(self.n_lines)
        return stack_last(j, (j + 1) % self.n_vertices)

    def vertex_cov(self, i: int) -> np.ndarray:
        """``(2, 2)`` covariance of vertex ``i`` [m^2]."""
        return self.cov[2 * i : 2 * i + 2, 2 * i : 2 * i + 2]

    def vertex_blocks(self) -> np.ndarray:
        """``(k, 2, 2)`` covariance of every vertex [m^2] (the diagonal blocks of ``cov``)."""
        k = self.n_vertices
        diag = np.arange(k)
        return self.cov.reshape(k, 2, k, 2)[diag, :, diag, :]

    def line_blocks(self) -> tuple[np.ndarray, np.ndarray]:
        """Joint Gaussian of each line's two vertices.

        Returns:
            ``(mu, Sigma)`` with shapes ``(n_lines, 4)`` and ``(n_lines, 4, 4)``, ordered
            ``[a_x, a_y, b_x, b_y]`` for line ``(a, b)``.
        """
        idx = self.line_vertices()
        coords = np.stack([2 * idx[:, 0], 2 * idx[:, 0] + 1, 2 * idx[:, 1], 2 * idx[:, 1] + 1], 1)
        mu = self.mean.reshape(-1)[coords]
        sigma = self.cov[coords[:, :, None], coords[:, None, :]]
        return mu, sigma

    def is_unknown(self, threshold: float) -> np.ndarray:
        """``(n_lines,)`` bool: lines whose unknown probability exceeds ``threshold``."""
        return self.u > threshold

    def copy(self) -> LandmarkModel:
        """A deep copy."""
        return LandmarkModel(self.mean.copy(), self.cov.copy(), self.u.copy(), self.closed)


def conditional_on_pose(mean: np.ndarray, pose: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Linear dependence of vertices on the lidar pose they were built from (SPEC 7).

    ``v = A_vx x + b_vx + n``: per vertex with polar coordinates ``(v_r, v_phi)`` seen from
    ``pose = [x, y, theta]``, ``A_vx,i = [[1, 0, -v_r sin(theta + v_phi)],
    [0, 1, v_r cos(theta + v_phi)]]`` (i.e. ``[[1, 0, -(v_y - y)], [0, 1, v_x - x]]``).

    Args:
        mean: ``(k, 2)`` vertex means [m], world frame.
        pose: ``(3,)`` lidar pose ``[x, y, theta]``.

    Returns:
        ``A_vx`` ``(2k, 3)`` and ``b_vx = mu_v - A_vx pose`` ``(2k,)``.
    """
    mean = np.asarray(mean, dtype=float).reshape(-1, 2)
    pose = np.asarray(pose, dtype=float)
    k = mean.shape[0]
    a = np.zeros((k, 2, 3))
    a[:, 0, 0] = 1.0
    a[:, 1, 1] = 1.0
    a[:, 0, 2] = -(mean[:, 1] - pose[1])
    a[:, 1, 2] = mean[:, 0] - pose[0]
    a = a.reshape(2 * k, 3)
    return a, mean.reshape(-1) - a @ pose


@dataclass
class ModelFit:
    """A landmark model built from one segment of one scan, with its bookkeeping.

    Attributes:
        model: the landmark model (object lines plus unknown end lines).
        pose: ``(3,)`` lidar pose the model was built from (world frame).
        first_beam: scan index of the segment's first (leftmost) beam.
        last_beam: scan index of the segment's last (rightmost) beam.
        groups: ``(m, 2)`` scan indices ``(first, last)`` of the beams of each object
            line; consecutive lines share their boundary beam.
        object_vertices: ``(start, stop)``: the object vertices are
            ``model.mean[start:stop]``; the others are unknown-line end vertices.
        A_vx: ``(2k, 3)`` conditional form (SPEC 7).
        b_vx: ``(2k,)`` conditional form.
        bic: BIC score of each candidate model, index ``m - 1`` for ``m`` object lines
            (``-inf`` where not evaluated).
    """

    model: LandmarkModel
    pose: np.ndarray
    first_beam: int
    last_beam: int
    groups: np.ndarray
    object_vertices: tuple[int, int]
    A_vx: np.ndarray  # noqa: N815 - the thesis's name
    b_vx: np.ndarray
    bic: np.ndarray = field(default_factory=lambda: np.zeros(0))

    @property
    def n_object_lines(self) -> int:
        """Number of fitted object lines ``m``."""
        return int(self.groups.shape[0])


def prune_unknown_chains(
    model: LandmarkModel, object_vertices: tuple[int, int], tolerance: float, max_vertices: int
) -> np.ndarray:
    """Vertices to keep when the unknown chains at the ends grow long.

    Every update merges the unknown chain seen from the new pose into the old one
    (Algorithm 7), so the chains only grow. Per side, the chain from its outer end to the
    first (last) object vertex is simplified with Douglas-Peucker at ``tolerance`` [m]
    and then cut to its ``max_vertices`` vertices nearest the object. Object vertices
    are always kept; a closed model is returned whole.

    Returns:
        Ascending indices of the vertices to keep.
    """
    k = model.n_vertices
    start, stop = object_vertices
    if model.closed or k == 0:
        return np.arange(k)

    def simplify(idx: np.ndarray) -> list[int]:
        """Douglas-Peucker over model.mean[idx] (first and last always kept)."""
        if idx.size <= 2:
            return list(idx)
        pts = model.mean[idx]
        a, b = pts[0], pts[-1]
        ab = b - a
        norm = np.hypot(*ab)
        rel = pts - a
        if norm > 0:
            dist = np.abs(rel[:, 0] * ab[1] - rel[:, 1] * ab[0]) / norm
        else:
            dist = np.hypot(rel[:, 0], rel[:, 1])
        i = int(np.argmax(dist))
        if dist[i] <= tolerance:
            return [int(idx[0]), int(idx[-1])]
        return simplify(idx[: i + 1])[:-1] + simplify(idx[i:])

    left = simplify(np.arange(0, start + 1))[:-1][-max_vertices:] if start > 0 else []
    right = simplify(np.arange(stop - 1, k))[1:][:max_vertices] if stop < k else []
    return np.array(sorted(set(left) | set(range(start, stop)) | set(right)), dtype=int)
