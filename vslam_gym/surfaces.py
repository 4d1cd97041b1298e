"""Contiguous surface pieces of a world's obstacles: the fewest landmarks a map can hold.

The duplicate metric (:func:`vslam_gym.evaluation.duplicate_fraction`) counts landmarks
per obstacle id. Some obstacles cannot be modelled by one landmark however good the
estimator: ``house``'s outer wall (one obstacle, 20 m x 15 m) is seen from inside six
rooms, and each face of an inner wall is a surface of its own. A *surface piece* is a
maximal contiguous part of one obstacle's boundary that faces the free space the robot
moves in: the two faces of a wall are one piece when they join around a free end, and
two when both ends abut other walls. A map with exactly one landmark per piece the
robot saw has the duplicate fraction ``1 - obstacles / pieces`` (the metric of the
pieces' obstacle ids), the floor of the metric on that route.

The pieces are found on a raster (:func:`surface_pieces`): the cells inside an obstacle
get its id, the free cells connected to a point of the free space (the robot's start)
are the reachable space, the obstacle cells next to it are the boundary, and each
obstacle's boundary cells fall into 8-connected pieces. A scan's beam hit then belongs
to the piece of its nearest boundary cell when that cell is near and of the obstacle
the beam hit (:meth:`SurfacePieces.hit_pieces`). Ground truth only: a metric, never an
input of the estimator.

Units and frames: metres, world frame; rasters are indexed ``[row, column]`` = ``[y, x]``.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from scipy import ndimage

from vslam_gym.sim.shapes import obstacle_bounds, signed_distance
from vslam_gym.sim.world import World

__all__ = ["DEFAULT_CELL", "SurfacePieces", "surface_pieces"]

DEFAULT_CELL = 0.02
"""Raster cell size [m]: five cells across the thinnest shipped walls (0.1 m), so that
the two faces of a wall never touch on the raster."""

_MARGIN_CELLS = 2
"""Free cells around the obstacles' bounding box (the raster's border is free space)."""


@dataclass(frozen=True)
class SurfacePieces:
    """The surface pieces of a world on a raster (:func:`surface_pieces`).

    Attributes:
        origin: ``(x, y)`` [m] of the raster's lower-left corner.
        cell: cell size [m].
        nearest: ``(rows, columns)`` for every cell the piece of the nearest boundary
            cell (int32; meaningless without pieces).
        distance: ``(rows, columns)`` the distance to that cell [cells] (float32).
        owner: ``(pieces,)`` obstacle id of every piece.
        cells: ``(pieces,)`` boundary cells of every piece (its length is about
            ``cells * cell`` metres).
    """

    origin: tuple[float, float]
    cell: float
    nearest: np.ndarray
    distance: np.ndarray
    owner: np.ndarray
    cells: np.ndarray

    @property
    def count(self) -> int:
        """Number of pieces."""
        return int(self.owner.size)

    def hit_pieces(self, points: np.ndarray, ids: np.ndarray, radius: float) -> np.ndarray:
        """The piece each beam hit lies on, -1 for none.

        A hit belongs to the boundary cell nearest to it when that cell is within
        ``radius`` [m] (a noisy range ends a little in front of or behind the surface)
        and belongs to the obstacle the beam hit; otherwise (a hit near where two
        obstacles meet, whose nearest cell is the other's) to none.

        Args:
            points: ``(n, 2)`` hit points [m], world frame.
            ids: ``(n,)`` obstacle id of every hit, -1 for a beam that hit nothing.
            radius: largest distance [m] from a hit to its cell, > 0.

        Returns:
            ``(n,)`` piece indices (int).

        Raises:
            ValueError: malformed points or ids, or ``radius <= 0``.
        """
        points = np.asarray(points, dtype=float)
        ids = np.asarray(ids)
        if points.ndim != 2 or points.shape[1] != 2 or not np.isfinite(points).all():
            raise ValueError(f"points must be a finite (n, 2) array [m], got shape {points.shape}")
        if ids.shape != (points.shape[0],):
            raise ValueError(f"ids must have shape ({points.shape[0]},), got {ids.shape}")
        if not (np.isfinite(radius) and radius > 0):
            raise ValueError(f"radius must be finite and > 0 [m], got {radius!r}")
        out = np.full(points.shape[0], -1, dtype=np.intp)
        if self.count == 0:
            return out
        rows, cols = self.nearest.shape
        idx = np.floor((points - np.asarray(self.origin)) / self.cell).astype(np.intp)
        ok = (ids >= 0) & (idx[:, 0] >= 0) & (idx[:, 0] < cols) & (idx[:, 1] >= 0)
        ok &= idx[:, 1] < rows
        r, c = idx[ok, 1], idx[ok, 0]
        piece = self.nearest[r, c].astype(np.intp)
        good = (self.distance[r, c] * self.cell <= radius) & (self.owner[piece] == ids[ok])
        out[np.flatnonzero(ok)[good]] = piece[good]
        return out


def surface_pieces(
    world: World, free_point: tuple[float, float] | None = None, cell: float = DEFAULT_CELL
) -> SurfacePieces:
    """The surface pieces of ``world``'s obstacles that face the free space.

    Args:
        world: the world (obstacle ids are their indices).
        free_point: ``(x, y)`` [m] of a point in the free space the robot moves in; None:
            the robot's start.
        cell: raster cell size [m], > 0. Thin walls need several cells across.

    Returns:
        The pieces (cached per world, point and cell: worlds are immutable).

    Raises:
        ValueError: ``cell <= 0``, or ``free_point`` inside an obstacle.
    """
    if not (np.isfinite(cell) and cell > 0):
        raise ValueError(f"cell must be finite and > 0 [m], got {cell!r}")
    point = tuple(world.robot.start[:2]) if free_point is None else tuple(free_point)
    return _surface_pieces(world, (float(point[0]), float(point[1])), float(cell))


@lru_cache(maxsize=16)
def _surface_pieces(world: World, point: tuple[float, float], cell: float) -> SurfacePieces:
    boxes = np.array([obstacle_bounds(o) for o in world.obstacles]).reshape(-1, 4)
    lo = np.minimum(boxes[:, :2].min(axis=0, initial=np.inf), point) - _MARGIN_CELLS * cell
    hi = np.maximum(boxes[:, 2:].max(axis=0, initial=-np.inf), point) + _MARGIN_CELLS * cell
    cols, rows = (int(v) + 1 for v in np.ceil((hi - lo) / cell))
    owner = np.full((rows, cols), -1, dtype=np.intp)
    depth = np.zeros((rows, cols))  # signed distance of the owning obstacle (< 0)
    blocks = []  # per obstacle the raster block of its bounding box: all its cells
    for k, (obstacle, box) in enumerate(zip(world.obstacles, boxes, strict=True)):
        c0, r0 = np.floor((box[:2] - lo) / cell).astype(int)
        c1, r1 = np.ceil((box[2:] - lo) / cell).astype(int) + 1
        c0, r0, c1, r1 = max(c0, 0), max(r0, 0), min(c1, cols), min(r1, rows)
        xs = lo[0] + (np.arange(c0, c1) + 0.5) * cell
        ys = lo[1] + (np.arange(r0, r1) + 0.5) * cell
        gx, gy = np.meshgrid(xs, ys)
        d = signed_distance(obstacle, np.column_stack([gx.ravel(), gy.ravel()]))
        d = d.reshape(gx.shape)
        block = (slice(r0, r1), slice(c0, c1))
        blocks.append(block)
        take = (d < 0.0) & (d < depth[block])  # the deepest obstacle owns a shared cell
        owner[block] = np.where(take, k, owner[block])
        depth[block] = np.where(take, d, depth[block])
    occupied = owner >= 0
    free, _ = ndimage.label(~occupied)  # 4-connected: no leak through diagonal gaps
    pc, pr = (int(v) for v in np.floor((np.asarray(point) - lo) / cell))
    if occupied[pr, pc]:
        raise ValueError(f"free_point {point} lies inside obstacle {owner[pr, pc]}")
    reachable = free == free[pr, pc]
    boundary = occupied & ndimage.binary_dilation(reachable)
    piece = np.full((rows, cols), -1, dtype=np.intp)
    owners: list[int] = []
    sizes: list[int] = []
    for k, block in enumerate(blocks):
        labels, n = ndimage.label(boundary[block] & (owner[block] == k), structure=np.ones((3, 3)))
        piece[block] = np.where(labels > 0, labels - 1 + len(owners), piece[block])
        sizes += np.bincount(labels.ravel(), minlength=n + 1)[1:].tolist()
        owners += [k] * n
    # Every cell's nearest boundary cell (Euclidean distance transform of the rest).
    distance, (near_r, near_c) = ndimage.distance_transform_edt(piece < 0, return_indices=True)
    return SurfacePieces(
        (float(lo[0]), float(lo[1])),
        cell,
        piece[near_r, near_c].astype(np.int32),
        distance.astype(np.float32),
        np.array(owners, dtype=np.intp),
        np.array(sizes, dtype=np.intp),
    )
