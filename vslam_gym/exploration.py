"""Ground-truth exploration metrics: the true obstacle boundary and how much of it is mapped.

For evaluation only: nothing here may feed a policy's observation or reward (the
:class:`~vslam_gym.slam_wrapper.SlamWrapper` keeps ground truth out of both).

- :func:`boundary_samples` samples the true obstacle boundaries of a world every few
  centimetres, keeping only the parts the robot can face: points inside another
  obstacle (wall junctions, touching obstacles) and points facing space the robot cannot
  reach from its start (the outer face of enclosing walls) are dropped.
- :func:`coverage` is the fraction of those samples within a tolerance of a modelled
  object line of a SLAM belief (the belief's map frame is the world frame: the wrapper
  starts the filter at the world's start pose).

Compute the samples once per episode (a random world changes at every reset) and call
:func:`coverage` every step; it is vectorised (about a millisecond for a hundred lines
and a few thousand samples).

Example::

    samples = boundary_samples(env.unwrapped.world)
    ...
    fraction = coverage(samples, env.get_wrapper_attr("belief"))
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass
from functools import cached_property

import numpy as np
from scipy import ndimage

from vslam_gym.sim.shapes import (
    as_points,
    obstacle_bounds,
    obstacle_capsules,
    point_in_polygon,
    point_segment_distance,
    polygon_area,
    signed_distance,
)
from vslam_gym.sim.world import CircleObstacle, PolygonObstacle, WallObstacle, World
from vslam_gym.slam.filter import Belief

__all__ = [
    "BoundarySamples",
    "ExplorationMetricError",
    "ReachabilityConfig",
    "SampleIndex",
    "boundary_samples",
    "coverage",
    "covered_samples",
    "object_lines",
    "reachable_free_space",
]


class ExplorationMetricError(ValueError):
    """Bad input to an exploration metric (spacing, tolerance, a start inside an obstacle)."""


@dataclass(frozen=True)
class ReachabilityConfig:
    """Grid and tolerances of the reachability filter of :func:`boundary_samples`.

    Attributes:
        grid_cell: side [m] of the grid cells of the flood fill. Walls thinner than a
            cell may let the fill leak through them (the shipped and random worlds have
            walls of 0.1 m or more).
        normal_offset: distance [m] along a sample's outward normal to the point whose
            cell decides reachability; at least one cell, so that the point's cell centre
            lies outside the obstacle.
        inside_tolerance: a sample counts as inside an obstacle when its signed distance
            to it is below ``-inside_tolerance`` [m] (samples on a shared boundary are kept).
        margin: free border [m] added around the world's bounding box, so that the space
            outside an enclosure forms one region.
    """

    grid_cell: float = 0.05
    normal_offset: float = 0.05
    inside_tolerance: float = 1e-6
    margin: float = 1.0

    def __post_init__(self) -> None:
        for name in ("grid_cell", "normal_offset", "margin"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0.0):
                raise ExplorationMetricError(
                    f"ReachabilityConfig.{name} must be > 0, got {value!r}"
                )
        if not (math.isfinite(self.inside_tolerance) and self.inside_tolerance >= 0.0):
            raise ExplorationMetricError(
                f"ReachabilityConfig.inside_tolerance must be >= 0, got {self.inside_tolerance!r}"
            )


@dataclass(frozen=True, eq=False)
class BoundarySamples:
    """Points on the true obstacle boundaries (world frame), as :func:`boundary_samples` returns.

    Unpacks like a tuple: ``points, normals, obstacle_ids = boundary_samples(world)``.

    Attributes:
        points: ``(n, 2)`` sample positions [m].
        normals: ``(n, 2)`` unit outward normals (pointing into free space).
        obstacle_ids: ``(n,)`` index of each sample's obstacle in ``world.obstacles``.
    """

    points: np.ndarray
    normals: np.ndarray
    obstacle_ids: np.ndarray

    def __iter__(self) -> Iterator[np.ndarray]:
        return iter((self.points, self.normals, self.obstacle_ids))

    def __len__(self) -> int:
        return len(self.points)

    @cached_property
    def index(self) -> SampleIndex:
        """The grid index of the points used by :func:`coverage` (built on first use)."""
        return SampleIndex(self.points)


# ---------------------------------------------------------------------------- sampling


def _sample_segments(
    a: np.ndarray, b: np.ndarray, spacing: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Midpoints of ``ceil(length / spacing)`` equal pieces of each segment ``a[i]-b[i]``.

    Returns:
        ``(points (n, 2), unit directions (n, 2), segment index (n,))``; zero-length
        segments give no samples.
    """
    d = b - a
    length = np.linalg.norm(d, axis=1)
    counts = np.where(length > 0.0, np.ceil(length / spacing), 0).astype(int)
    seg = np.repeat(np.arange(len(a)), counts)
    first = np.repeat(np.cumsum(counts) - counts, counts)
    t = (np.arange(seg.size) - first + 0.5) / counts[seg]
    unit = d[seg] / length[seg, None]
    return a[seg] + t[:, None] * d[seg], unit, seg


def _sample_arcs(
    centers: np.ndarray, radii: np.ndarray, start: np.ndarray, sweep: float, spacing: float
) -> tuple[np.ndarray, np.ndarray]:
    """Points of arcs from angle ``start[i]`` over ``sweep`` [rad] (CCW), radial normals."""
    counts = np.maximum(np.ceil(radii * sweep / spacing), 1).astype(int)
    counts = np.where(radii > 0.0, counts, 0)
    arc = np.repeat(np.arange(len(centers)), counts)
    first = np.repeat(np.cumsum(counts) - counts, counts)
    angle = start[arc] + sweep * (np.arange(arc.size) - first + 0.5) / counts[arc]
    normal = np.stack([np.cos(angle), np.sin(angle)], axis=1)
    return centers[arc] + radii[arc, None] * normal, normal


def _obstacle_boundary(obstacle: object, spacing: float) -> tuple[np.ndarray, np.ndarray]:
    """Boundary points and outward normals of one obstacle (before any filtering)."""
    if isinstance(obstacle, PolygonObstacle):
        a, b, _ = obstacle_capsules(obstacle)
        points, unit, _ = _sample_segments(a, b, spacing)
        right = np.stack([unit[:, 1], -unit[:, 0]], axis=1)  # outward for CCW vertices
        sign = 1.0 if polygon_area(a) > 0.0 else -1.0
        return points, sign * right
    if isinstance(obstacle, CircleObstacle):
        center = as_points(obstacle.center)
        radius = np.array([float(obstacle.radius)])
        return _sample_arcs(center, radius, np.zeros(1), 2.0 * math.pi, spacing)
    if isinstance(obstacle, WallObstacle):
        # Every capsule's outline (both long sides, round caps); the parts inside a
        # neighbouring capsule (junctions) are dropped by the caller.
        a, b, r = obstacle_capsules(obstacle)
        d = b - a
        length = np.linalg.norm(d, axis=1)
        unit = np.where(length[:, None] > 0.0, d / np.maximum(length, 1e-300)[:, None], [1.0, 0])
        left = np.stack([-unit[:, 1], unit[:, 0]], axis=1)
        pieces_p, pieces_n = [], []
        for side in (1.0, -1.0):
            offset = side * r[:, None] * left
            points, _, seg = _sample_segments(a + offset, b + offset, spacing)
            pieces_p.append(points)
            pieces_n.append(side * left[seg])
        # Round caps: the forward cap at every segment end holds the outer arc of the
        # joint to the next segment (turns below 180 deg), so a start cap is only needed
        # at the free start of an open polyline (one arc sample set per joint).
        heading = np.arctan2(unit[:, 1], unit[:, 0])
        closed = np.array_equal(a[0], b[-1])
        first = slice(0, 0) if closed else slice(0, 1)
        caps = (
            (a[first], r[first], heading[first] + 0.5 * math.pi),
            (b, r, heading - 0.5 * math.pi),
        )
        for centers, radii, start in caps:
            points, normals = _sample_arcs(centers, radii, start, math.pi, spacing)
            pieces_p.append(points)
            pieces_n.append(normals)
        return np.concatenate(pieces_p), np.concatenate(pieces_n)
    raise TypeError(f"not an obstacle: {obstacle!r}")


# ---------------------------------------------------------------------------- reachability


def _inside_any(world: World, points: np.ndarray, tolerance: float) -> np.ndarray:
    """Whether each point is deeper than ``tolerance`` [m] inside any obstacle.

    Same result as ``clearance(world.obstacles, points) < -tolerance``, but each
    obstacle (each segment of a wall) only tests the points inside its bounding box.
    """
    inside = np.zeros(len(points), bool)
    for obstacle in world.obstacles:
        a, b, r = obstacle_capsules(obstacle)
        if isinstance(obstacle, PolygonObstacle):
            parts = [(a, b, r)]
        else:
            parts = [(a[k : k + 1], b[k : k + 1], r[k : k + 1]) for k in range(len(a))]
        for pa, pb, pr in parts:
            low = np.minimum(pa.min(axis=0), pb.min(axis=0)) - pr.max()
            high = np.maximum(pa.max(axis=0), pb.max(axis=0)) + pr.max()
            near = np.flatnonzero(np.all((points > low) & (points < high), axis=1))
            if near.size == 0:
                continue
            if isinstance(obstacle, PolygonObstacle):
                d = signed_distance(obstacle, points[near])
            else:
                d = point_segment_distance(points[near], pa, pb)[:, 0] - pr[0]
            inside[near[d < -tolerance]] = True
    return inside


def reachable_free_space(
    world: World, config: ReachabilityConfig | None = None
) -> tuple[np.ndarray, np.ndarray, float]:
    """Free space the robot can reach or see into from its start, on a grid.

    Two flood fills (:func:`scipy.ndimage.label`, 4-connected): the cells where the
    robot centre fits (clearance > robot radius) connected to the start cell, then every
    free cell (clearance > 0) connected to those. The second region also holds nooks too
    narrow for the robot body but open to its lidar.

    Args:
        world: the world (obstacles, robot start and radius).
        config: grid and margins.

    Returns:
        ``(mask, origin, cell)``: ``mask[i, j]`` is true for the reachable cell whose
        centre is ``origin + cell * (i + 0.5, j + 0.5)`` (``i`` along x, ``j`` along y).

    Raises:
        ExplorationMetricError: if the start pose is not free for the robot.
    """
    cfg = config if config is not None else ReachabilityConfig()
    radius = float(world.robot.radius)
    start = np.asarray(world.robot.start[:2], dtype=float)
    cell = float(cfg.grid_cell)
    boxes = np.array([obstacle_bounds(o) for o in world.obstacles]).reshape(-1, 4)
    lo = np.minimum(start, boxes[:, :2].min(axis=0) if len(boxes) else start) - cfg.margin
    hi = np.maximum(start, boxes[:, 2:].max(axis=0) if len(boxes) else start) + cfg.margin
    shape = np.ceil((hi - lo) / cell).astype(int)
    xs = lo[0] + cell * (np.arange(shape[0]) + 0.5)
    ys = lo[1] + cell * (np.arange(shape[1]) + 0.5)
    # Clearance only matters below the robot radius plus a cell: evaluate each capsule
    # (polygon edge, wall segment, circle) on the cells of its bounding box grown by
    # that reach, and mark polygon interiors as inside (negative).
    reach = radius + 2.0 * cell
    grid = np.full((shape[0], shape[1]), np.inf)

    def cells(low: np.ndarray, high: np.ndarray) -> tuple[slice, slice, np.ndarray] | None:
        i0, i1 = np.searchsorted(xs, [low[0], high[0]])
        j0, j1 = np.searchsorted(ys, [low[1], high[1]])
        if i1 <= i0 or j1 <= j0:
            return None
        gx, gy = np.meshgrid(xs[i0:i1], ys[j0:j1], indexing="ij")
        return slice(i0, i1), slice(j0, j1), np.stack([gx.ravel(), gy.ravel()], axis=1)

    for obstacle in world.obstacles:
        a, b, r = obstacle_capsules(obstacle)
        for k in range(len(a)):
            box = cells(
                np.minimum(a[k], b[k]) - r[k] - reach, np.maximum(a[k], b[k]) + r[k] + reach
            )
            if box is None:
                continue
            si_, sj_, points = box
            d = point_segment_distance(points, a[k : k + 1], b[k : k + 1])[:, 0] - r[k]
            block = grid[si_, sj_]
            np.minimum(block, d.reshape(block.shape), out=block)
        if isinstance(obstacle, PolygonObstacle):
            box = cells(a.min(axis=0), a.max(axis=0))
            if box is not None:
                si_, sj_, points = box
                block = grid[si_, sj_]
                inner = point_in_polygon(points, a).reshape(block.shape)
                block[inner] = -np.abs(block[inner])
    si, sj = np.floor((start - lo) / cell).astype(int)
    centre_free = grid > radius
    # The start cell's centre may miss the start by up to a cell: accept a neighbour.
    around = np.argwhere(centre_free[si - 1 : si + 2, sj - 1 : sj + 2]) - 1
    if len(around):
        nearest = around[np.argmin(np.abs(around).sum(axis=1))]
        si, sj = si + nearest[0], sj + nearest[1]
    else:
        raise ExplorationMetricError(
            f"the robot start {tuple(world.robot.start)} is not free for a robot of radius "
            f"{radius} m in world {world.name!r}"
        )
    labels, _ = ndimage.label(centre_free)
    robot_region = labels == labels[si, sj]
    free_labels, _ = ndimage.label(grid > 0.0)
    reached = np.zeros(int(free_labels.max()) + 1, bool)
    reached[free_labels[robot_region]] = True
    reached[0] = False  # label 0: not free
    mask = reached[free_labels]
    return mask, lo, cell


def boundary_samples(
    world: World, spacing: float = 0.05, config: ReachabilityConfig | None = None
) -> BoundarySamples:
    """Sample the true obstacle boundaries the robot can face, world frame.

    Polygons: every edge; circles: the circumference; walls: both long sides and the
    round end caps of every segment of the thick polyline. Each edge (side, arc) of
    length ``L`` gets ``ceil(L / spacing)`` samples at the centres of equal pieces.
    Dropped: samples inside another obstacle or another segment of the same wall (wall
    junctions, touching obstacles), and samples whose outward neighbour (``normal_offset``
    along the normal) lies outside :func:`reachable_free_space` (e.g. the outer face of
    an enclosing wall).

    Args:
        world: the world (``env.unwrapped.world``: ground truth).
        spacing: largest distance [m] between neighbouring samples along an edge.
        config: reachability grid and tolerances.

    Returns:
        :class:`BoundarySamples` ``(points (n, 2), normals (n, 2), obstacle_ids (n,))``.

    Raises:
        ExplorationMetricError: for a non-positive spacing or a start inside an obstacle.
    """
    if not (math.isfinite(spacing) and spacing > 0.0):
        raise ExplorationMetricError(f"spacing must be a positive length [m], got {spacing!r}")
    cfg = config if config is not None else ReachabilityConfig()
    points, normals, ids = [np.zeros((0, 2))], [np.zeros((0, 2))], [np.zeros(0, int)]
    for index, obstacle in enumerate(world.obstacles):
        p, n = _obstacle_boundary(obstacle, spacing)
        points.append(p)
        normals.append(n)
        ids.append(np.full(len(p), index))
    p, n, ids_ = np.concatenate(points), np.concatenate(normals), np.concatenate(ids)
    if len(p) == 0:
        return BoundarySamples(p, n, ids_)
    keep = ~_inside_any(world, p, cfg.inside_tolerance)
    mask, origin, cell = reachable_free_space(world, cfg)
    probe = np.floor((p + cfg.normal_offset * n - origin) / cell).astype(int)
    inside = (probe >= 0).all(axis=1) & (probe < np.array(mask.shape)).all(axis=1)
    reachable = np.zeros(len(p), bool)
    reachable[inside] = mask[probe[inside, 0], probe[inside, 1]]
    keep &= reachable
    return BoundarySamples(p[keep], n[keep], ids_[keep])


# ---------------------------------------------------------------------------- coverage


INDEX_CELL = 0.25
"""Cell side [m] of :class:`SampleIndex` (a few samples per cell at 0.05 m spacing)."""


class SampleIndex:
    """A uniform grid over fixed points for "which points lie near these segments" queries.

    Build once per set of points (:attr:`BoundarySamples.index` caches one); each query
    cuts the segments into pieces no longer than a cell, visits the cells of each piece's
    bounding box grown by the tolerance and tests only the points in them, exactly. All
    steps are vectorised (no Python loop over segments or cells).

    Args:
        points: ``(n, 2)`` points [m].
        cell: grid cell side [m].
    """

    def __init__(self, points: np.ndarray, cell: float = INDEX_CELL) -> None:
        if not (math.isfinite(cell) and cell > 0.0):
            raise ExplorationMetricError(f"cell must be > 0 [m], got {cell!r}")
        self.points = as_points(points) if len(points) else np.zeros((0, 2))
        if not np.all(np.isfinite(self.points)):
            raise ExplorationMetricError("points must be finite")
        self.cell = float(cell)
        if len(self.points) == 0:
            self.origin, self.shape = np.zeros(2), np.ones(2, dtype=np.int64)
        else:
            self.origin = self.points.min(axis=0) - self.cell
            self.shape = (
                np.floor((self.points.max(axis=0) - self.origin) / self.cell).astype(np.int64) + 2
            )
        ij = np.floor((self.points - self.origin) / self.cell).astype(np.int64)
        key = ij[:, 0] * self.shape[1] + ij[:, 1]
        self.order = np.argsort(key, kind="stable")
        self.count = np.bincount(key, minlength=int(self.shape[0] * self.shape[1]))
        self.first = np.cumsum(self.count) - self.count

    def covered(self, starts: np.ndarray, ends: np.ndarray, tolerance: float) -> np.ndarray:
        """Which points lie within ``tolerance`` [m] (inclusive) of any segment.

        Args:
            starts: ``(m, 2)`` segment starts [m].
            ends: ``(m, 2)`` segment ends [m].
            tolerance: distance [m].

        Returns:
            ``(n,)`` booleans.
        """
        if not (math.isfinite(tolerance) and tolerance >= 0.0):
            raise ExplorationMetricError(f"tolerance must be >= 0 [m], got {tolerance!r}")
        a = np.asarray(starts, dtype=float).reshape(-1, 2)
        b = np.asarray(ends, dtype=float).reshape(-1, 2)
        if a.shape != b.shape:
            raise ExplorationMetricError(f"starts {a.shape} and ends {b.shape} differ in shape")
        covered = np.zeros(len(self.points), bool)
        finite = np.all(np.isfinite(a), axis=1) & np.all(np.isfinite(b), axis=1)
        a, b = a[finite], b[finite]
        if len(self.points) == 0 or len(a) == 0:
            return covered
        cell = self.cell
        # Pieces of at most one cell.
        d = b - a
        pieces = np.maximum(np.ceil(np.linalg.norm(d, axis=1) / cell), 1).astype(np.int64)
        seg = np.repeat(np.arange(len(a)), pieces)
        k = np.arange(seg.size) - np.repeat(np.cumsum(pieces) - pieces, pieces)
        pa = a[seg] + (k / pieces[seg])[:, None] * d[seg]
        pb = a[seg] + ((k + 1) / pieces[seg])[:, None] * d[seg]
        # The cells of each piece's bounding box grown by the tolerance.
        top = self.shape - 1
        low = np.floor((np.minimum(pa, pb) - tolerance - self.origin) / cell)
        high = np.floor((np.maximum(pa, pb) + tolerance - self.origin) / cell)
        c0 = np.clip(low, 0, top).astype(np.int64)
        c1 = np.clip(high, 0, top).astype(np.int64)
        ny = c1[:, 1] - c0[:, 1] + 1
        n_cells = (c1[:, 0] - c0[:, 0] + 1) * ny
        piece = np.repeat(np.arange(len(pa)), n_cells)
        local = np.arange(piece.size) - np.repeat(np.cumsum(n_cells) - n_cells, n_cells)
        key = (c0[piece, 0] + local // ny[piece]) * self.shape[1] + c0[piece, 1] + local % ny[piece]
        counts = self.count[key]
        occupied = counts > 0
        key, piece, counts = key[occupied], piece[occupied], counts[occupied]
        # The points in those cells, against their piece.
        piece = np.repeat(piece, counts)
        local = np.arange(piece.size) - np.repeat(np.cumsum(counts) - counts, counts)
        sample = self.order[np.repeat(self.first[key], counts) + local]
        origin = pa[piece]
        direction = pb[piece] - origin
        rel = self.points[sample] - origin
        length_sq = np.einsum("ij,ij->i", direction, direction)
        t = np.einsum("ij,ij->i", rel, direction) / np.where(length_sq > 0.0, length_sq, 1.0)
        gap = rel - np.clip(t, 0.0, 1.0)[:, None] * direction
        near = np.einsum("ij,ij->i", gap, gap) <= tolerance * tolerance
        covered[sample[near]] = True
        return covered


def covered_samples(
    points: np.ndarray, starts: np.ndarray, ends: np.ndarray, tolerance: float = 0.1
) -> np.ndarray:
    """Which points lie within ``tolerance`` [m] of any segment ``starts[j]-ends[j]``.

    Builds a :class:`SampleIndex` for the call; reuse one (e.g. ``samples.index``) when
    the points stay the same.

    Args:
        points: ``(n, 2)`` points [m].
        starts: ``(m, 2)`` segment starts [m].
        ends: ``(m, 2)`` segment ends [m].
        tolerance: distance [m] (inclusive).

    Returns:
        ``(n,)`` booleans.
    """
    return SampleIndex(np.asarray(points, dtype=float).reshape(-1, 2)).covered(
        starts, ends, tolerance
    )


def coverage(
    samples: BoundarySamples | np.ndarray,
    belief: Belief,
    tolerance: float = 0.1,
    unknown_threshold: float = 0.5,
) -> float:
    """Fraction of the true boundary samples within ``tolerance`` of a modelled object line.

    Args:
        samples: :func:`boundary_samples` of the episode's world (its grid index is
            built on the first call and reused), or just ``(n, 2)`` points [m], world frame.
        belief: the SLAM belief (its lines are in the world frame).
        tolerance: distance [m] from a sample to the nearest object line (inclusive).
        unknown_threshold: a line with ``u > unknown_threshold`` is an unknown line and
            does not count.

    Returns:
        Coverage in ``[0, 1]``; 0 when there are no samples.
    """
    if isinstance(samples, BoundarySamples):
        index = samples.index
    else:
        index = SampleIndex(np.asarray(samples, dtype=float).reshape(-1, 2))
    if len(index.points) == 0:
        return 0.0
    starts, ends = object_lines(belief, unknown_threshold)
    hit = index.covered(starts, ends, tolerance)
    return float(np.count_nonzero(hit) / len(index.points))


def object_lines(belief: Belief, unknown_threshold: float = 0.5) -> tuple[np.ndarray, np.ndarray]:
    """The belief's modelled object lines (``u <= unknown_threshold``) as segments.

    The end points of :func:`~vslam_gym.belief_observation.belief_segments` without its
    vertex uncertainties (cheaper, for per-step metrics).

    Returns:
        ``(starts, ends)``: ``(m, 2)`` arrays [m], world frame.
    """
    starts, ends = [np.zeros((0, 2))], [np.zeros((0, 2))]
    for landmark in belief.landmarks:
        model = landmark.model
        if model.n_lines == 0:
            continue
        lines = model.line_vertices()[model.u <= unknown_threshold]
        starts.append(model.mean[lines[:, 0]])
        ends.append(model.mean[lines[:, 1]])
    return np.concatenate(starts), np.concatenate(ends)
