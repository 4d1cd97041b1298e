"""Procedural rooms-and-clutter worlds for reinforcement-learning training.

:func:`generate_random_world` builds a :class:`World` from one random generator:

1. **Rooms.** The enclosing rectangle is split binary-space-partition style into
   ``n_rooms`` rectangular rooms; each split adds a straight partition wall with one
   doorway, so every room is reachable (the rooms and doorways form a tree). Splits keep
   away from existing doorways so that no partition blocks one.
2. **Route.** A depth-first tour of the room tree from a random start room: a few random
   points per room, and for each doorway a point on either side of it on the doorway's
   axis, so the route crosses doorways square-on. Every point is at least
   ``waypoint_wall_distance`` from the walls of its (convex) room, which keeps every
   route segment clear of the walls. The robot starts on the first waypoint, facing the
   second; the route loops.
3. **Clutter.** ``n_obstacles`` boxes, L-shapes, discs and small posts by rejection
   sampling, drawn and tested in vectorised batches: each keeps a gap of at least
   ``min_gap`` to every other obstacle (walls included) and ``robot_radius +
   min_clearance`` to the route, measured from its bounding circle (so real gaps are
   often larger). Since ``min_gap`` is at least the robot diameter, the robot fits
   between any two obstacles, and the route is drivable by a disc of ``robot_radius``
   with ``min_clearance`` to spare.

The same seed gives an identical :class:`World`. Units are metres and radians in the
world frame (origin at the south-west outer corner, x east, y north).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, fields
from typing import Any, NoReturn

import numpy as np

from vslam_gym.config_utils import dataclass_from_dict
from vslam_gym.sim import shapes
from vslam_gym.sim.world import (
    CircleObstacle,
    Obstacle,
    PolygonObstacle,
    RobotSpec,
    Route,
    WallObstacle,
    World,
)

__all__ = ["RandomWorldError", "RandomWorldParams", "generate_random_world"]

_QUOTA_PHASE = 25
"""The kind quotas hold for the first ``1 / _QUOTA_PHASE`` of the placement attempts."""
CLUTTER_KINDS = ("box", "l_shape", "disc", "post")
"""Clutter kinds, in the order of :attr:`RandomWorldParams.kind_weights`."""


class RandomWorldError(ValueError):
    """The parameters cannot be realised (rooms or clutter do not fit)."""


@dataclass(frozen=True)
class RandomWorldParams:
    """Parameters of :func:`generate_random_world`; build with keyword arguments.

    Attributes:
        width: outer size along x [m] (wall centre lines).
        height: outer size along y [m].
        wall_thickness: thickness of the outer and partition walls [m].
        n_rooms: number of rooms (1 = one open hall).
        min_room_size: smallest side of a room [m] between wall centre lines.
        door_width: doorway width [m] between the partition ends (centre lines).
        n_obstacles: number of clutter objects (walls not counted).
        clutter_size: ``(min, max)`` side [m] of boxes and L-shapes and diameter of discs.
        post_radius: ``(min, max)`` half side [m] of the small square posts.
        kind_weights: relative frequency of box, L-shape, disc and post clutter.
        l_arm_fraction: ``(min, max)`` arm width of an L-shape as a fraction of its
            shorter side.
        rotate_clutter: rotate boxes and L-shapes by a random angle (else axis-aligned).
        robot_radius: robot disc radius [m] written into the world.
        min_clearance: free space [m] beyond the robot radius kept around the start,
            the waypoints and every route segment.
        min_gap: smallest gap [m] between a clutter object and any other obstacle; at
            least the robot diameter, so the robot fits between any two obstacles.
        waypoint_wall_distance: distance [m] of room waypoints and doorway approach points
            from the walls of their room (and of doorways from partition ends).
        waypoints_per_room: random route points per room visit.
        max_attempts: rejection-sampling attempts per clutter object before giving up.
    """

    width: float = 20.0
    height: float = 15.0
    wall_thickness: float = 0.15
    n_rooms: int = 4
    min_room_size: float = 4.0
    door_width: float = 1.2
    n_obstacles: int = 30
    clutter_size: tuple[float, float] = (0.4, 1.2)
    post_radius: tuple[float, float] = (0.05, 0.12)
    kind_weights: tuple[float, float, float, float] = (0.35, 0.2, 0.2, 0.25)
    l_arm_fraction: tuple[float, float] = (0.3, 0.6)
    rotate_clutter: bool = True
    robot_radius: float = 0.2
    min_clearance: float = 0.3
    min_gap: float = 0.5
    waypoint_wall_distance: float = 1.0
    waypoints_per_room: int = 1
    max_attempts: int = 1000

    def __post_init__(self) -> None:
        for name in ("clutter_size", "post_radius", "kind_weights", "l_arm_fraction"):
            value = getattr(self, name)
            try:
                if isinstance(value, str):
                    raise TypeError(name)
                value = tuple(float(v) for v in value)
            except (TypeError, ValueError) as err:
                raise ValueError(
                    f"RandomWorldParams.{name}: must be numbers, got {value!r}"
                ) from err
            object.__setattr__(self, name, value)
        for f in fields(self):
            value = getattr(self, f.name)
            if f.name == "rotate_clutter":
                if not isinstance(value, bool):
                    self._fail(f.name, f"must be a bool, got {value!r}")
                continue
            values = value if isinstance(value, tuple) else (value,)
            for v in values:
                if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                    self._fail(f.name, f"must be finite numbers, got {value!r}")
        for f in fields(self):
            value = getattr(self, f.name)
            if f.type == "int" and not isinstance(value, int):
                self._fail(f.name, f"must be an int, got {value!r}")
            if f.type == "float":
                object.__setattr__(self, f.name, float(value))
        positive = (
            "width",
            "height",
            "wall_thickness",
            "min_room_size",
            "door_width",
            "robot_radius",
            "waypoint_wall_distance",
            "n_rooms",
            "waypoints_per_room",
            "max_attempts",
        )
        for name in positive:
            if not getattr(self, name) > 0:
                self._fail(name, f"must be > 0, got {getattr(self, name)!r}")
        for name in ("n_obstacles", "min_clearance"):
            if not getattr(self, name) >= 0:
                self._fail(name, f"must be >= 0, got {getattr(self, name)!r}")
        for name in ("clutter_size", "post_radius", "l_arm_fraction"):
            lo_hi = getattr(self, name)
            if len(lo_hi) != 2 or not 0 < lo_hi[0] <= lo_hi[1]:
                self._fail(name, f"must be (min, max) with 0 < min <= max, got {lo_hi!r}")
        if self.l_arm_fraction[1] >= 1.0:
            self._fail("l_arm_fraction", f"max must be < 1, got {self.l_arm_fraction!r}")
        w = self.kind_weights
        if len(w) != len(CLUTTER_KINDS) or min(w) < 0 or sum(w) <= 0:
            self._fail(
                "kind_weights",
                f"must be {len(CLUTTER_KINDS)} weights >= 0 with a "
                f"positive sum ({', '.join(CLUTTER_KINDS)}), got {w!r}",
            )
        if self.min_gap < 2 * self.robot_radius:
            self._fail(
                "min_gap",
                f"must be >= the robot diameter {2 * self.robot_radius:g} m, got {self.min_gap!r}",
            )
        route_clear = self.robot_radius + self.min_clearance
        if self.waypoint_wall_distance < route_clear + self.wall_thickness / 2:
            self._fail(
                "waypoint_wall_distance",
                f"must be >= robot_radius + min_clearance + "
                f"wall_thickness / 2 = {route_clear + self.wall_thickness / 2:g} m, got "
                f"{self.waypoint_wall_distance!r}",
            )
        if self.door_width - self.wall_thickness < 2 * route_clear:
            self._fail(
                "door_width",
                f"must leave 2 * (robot_radius + min_clearance) = "
                f"{2 * route_clear:g} m between the wall faces, got {self.door_width!r}",
            )
        min_side = max(2 * self.waypoint_wall_distance, self.door_width + 2 * self._door_margin)
        if self.min_room_size < min_side:
            self._fail(
                "min_room_size",
                f"must be >= {min_side:g} m (room waypoints and a "
                f"doorway must fit), got {self.min_room_size!r}",
            )
        if min(self.width, self.height) < self.min_room_size:
            self._fail(
                "width",
                f"width and height must be >= min_room_size "
                f"({self.min_room_size:g} m), got {self.width!r} x {self.height!r}",
            )

    @property
    def _door_margin(self) -> float:
        """Distance [m] kept between a doorway edge and a partition end or a T-junction."""
        return self.waypoint_wall_distance

    @staticmethod
    def _fail(name: str, message: str) -> NoReturn:
        raise ValueError(f"RandomWorldParams.{name}: {message}")

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> RandomWorldParams:
        """Build from a mapping; unknown keys raise ``UnknownKeyError`` ("did you mean")."""
        return dataclass_from_dict(cls, data)


@dataclass
class _Door:
    """A doorway in a partition; the partition runs along ``axis`` over ``span`` at ``fixed``."""

    axis: int  # 0: the partition runs along x (a horizontal wall), 1: along y
    fixed: float  # the partition's constant coordinate (y if axis == 0, x if axis == 1)
    span: tuple[float, float]  # the partition's extent along `axis`
    at: float  # the doorway centre along `axis`

    @property
    def center(self) -> np.ndarray:
        """Doorway centre ``(x, y)`` [m]."""
        return np.array([self.at, self.fixed] if self.axis == 0 else [self.fixed, self.at])


Rect = tuple[float, float, float, float]  # x0, y0, x1, y1


def _subtract(lo: float, hi: float, holes: list[tuple[float, float]]) -> list[tuple[float, float]]:
    """Intervals of ``[lo, hi]`` outside every open hole ``(a, b)``."""
    segments = [(lo, hi)] if hi > lo else []
    for a, b in holes:
        nxt = []
        for s, e in segments:
            if b <= s or a >= e:
                nxt.append((s, e))
                continue
            if a > s:
                nxt.append((s, a))
            if b < e:
                nxt.append((b, e))
        segments = nxt
    return segments


def _uniform_in_box(
    rng: np.random.Generator, low: tuple[float, float], high: tuple[float, float], size: object
) -> np.ndarray:
    """``rng.uniform(low, high, size)`` for per-coordinate bounds, without its overhead.

    ``Generator.uniform`` with array bounds computes ``low + (high - low) * u`` from the
    next ``rng.random`` draws; so does this, drawing the same numbers (tests check it)
    several times faster for small sizes.
    """
    lo = np.asarray(low, dtype=float)
    return lo + (np.asarray(high, dtype=float) - lo) * rng.random(size)


def _kind_cdf(p: RandomWorldParams) -> np.ndarray:
    """Cumulative distribution of the clutter kinds, built as ``Generator.choice`` does."""
    cdf = (np.asarray(p.kind_weights) / sum(p.kind_weights)).cumsum()
    cdf /= cdf[-1]
    return cdf


def _draw_kinds(rng: np.random.Generator, cdf: np.ndarray, n: int) -> np.ndarray:
    """``n`` clutter kinds (indices into :data:`CLUTTER_KINDS`) drawn from ``cdf``.

    The same draws as ``rng.choice(len(cdf), size=n, p=weights)`` (one ``rng.random``
    per kind, inverted through the cumulative weights; tests check it), without the
    argument checks that make it slow for small sizes.
    """
    return cdf.searchsorted(rng.random(n), side="right")


def _pick(rng: np.random.Generator, intervals: list[tuple[float, float]]) -> float:
    """Uniform sample from a union of disjoint intervals."""
    lengths = np.array([e - s for s, e in intervals])
    u = float(rng.uniform(0.0, float(lengths.sum())))
    for (s, _e), length in zip(intervals, lengths, strict=True):
        if u <= length:
            return s + u
        u -= length
    return intervals[-1][1]


def _split_rooms(p: RandomWorldParams, rng: np.random.Generator) -> tuple[list[Rect], list[_Door]]:
    """Split the outer rectangle into ``p.n_rooms`` rooms, one doorway per partition."""
    rooms: list[Rect] = [(0.0, 0.0, p.width, p.height)]
    doors: list[_Door] = []
    keep = p.door_width / 2 + p._door_margin  # doorway centre to partition end or junction
    for _ in range(p.n_rooms - 1):
        split = None
        for k in sorted(range(len(rooms)), key=lambda j: -_area(rooms[j])):
            x0, y0, x1, y1 = rooms[k]
            # A split at coordinate `pos` on axis `cut` makes a partition along the other
            # axis; cut the longer side first.
            for cut in (0, 1) if (x1 - x0) >= (y1 - y0) else (1, 0):
                lo, hi = (x0, x1) if cut == 0 else (y0, y1)
                o_lo, o_hi = (y0, y1) if cut == 0 else (x0, x1)
                # Doorways in the room's walls across the cut line must stay clear of it.
                holes = [
                    (d.at - keep, d.at + keep)
                    for d in doors
                    if d.axis == cut and d.fixed in (o_lo, o_hi) and lo < d.at < hi
                ]
                free = _subtract(lo + p.min_room_size, hi - p.min_room_size, holes)
                if free and o_hi - o_lo >= 2 * keep:
                    split = (k, cut, free, o_lo, o_hi)
                    break
            if split is not None:
                break
        if split is None:
            raise RandomWorldError(
                f"cannot split a {p.width:g} m x {p.height:g} m area into {p.n_rooms} rooms "
                f"of at least {p.min_room_size:g} m; lower n_rooms or min_room_size"
            )
        k, cut, free, o_lo, o_hi = split
        pos = _pick(rng, free)
        at = float(rng.uniform(o_lo + keep, o_hi - keep))
        doors.append(_Door(axis=1 - cut, fixed=pos, span=(o_lo, o_hi), at=at))
        x0, y0, x1, y1 = rooms[k]
        if cut == 0:
            rooms[k], new = (x0, y0, pos, y1), (pos, y0, x1, y1)
        else:
            rooms[k], new = (x0, y0, x1, pos), (x0, pos, x1, y1)
        rooms.append(new)
    return rooms, doors


def _area(r: Rect) -> float:
    return (r[2] - r[0]) * (r[3] - r[1])


def _room_of(rooms: list[Rect], pt: np.ndarray) -> int:
    for k, (x0, y0, x1, y1) in enumerate(rooms):
        if x0 < pt[0] < x1 and y0 < pt[1] < y1:
            return k
    raise AssertionError(f"point {pt} is in no room")  # unreachable by construction


def _walls(p: RandomWorldParams, doors: list[_Door]) -> list[WallObstacle]:
    """The outer wall and the partitions, each partition cut open at its doorway."""
    t = p.wall_thickness
    w, h = p.width, p.height
    walls = [WallObstacle(points=((0.0, 0.0), (w, 0.0), (w, h), (0.0, h), (0.0, 0.0)), thickness=t)]
    half = p.door_width / 2
    for d in doors:
        for s, e in ((d.span[0], d.at - half), (d.at + half, d.span[1])):
            ends = ((s, d.fixed), (e, d.fixed)) if d.axis == 0 else ((d.fixed, s), (d.fixed, e))
            walls.append(WallObstacle(points=ends, thickness=t))
    return walls


def _route(
    p: RandomWorldParams, rng: np.random.Generator, rooms: list[Rect], doors: list[_Door]
) -> np.ndarray:
    """Depth-first tour of the room tree from a random room; ``(n, 2)`` waypoints [m]."""
    m = p.waypoint_wall_distance
    neighbours: list[list[tuple[int, np.ndarray, np.ndarray]]] = [[] for _ in rooms]
    for d in doors:
        normal = np.zeros(2)
        normal[1 - d.axis] = m
        low, high = d.center - normal, d.center + normal
        r_low, r_high = _room_of(rooms, low), _room_of(rooms, high)
        neighbours[r_low].append((r_high, low, high))
        neighbours[r_high].append((r_low, high, low))
    out: list[np.ndarray] = []

    def visit(room: int, parent: int) -> None:
        x0, y0, x1, y1 = rooms[room]
        for _ in range(p.waypoints_per_room):
            out.append(_uniform_in_box(rng, (x0 + m, y0 + m), (x1 - m, y1 - m), 2))
        for j in rng.permutation(len(neighbours[room])):
            other, here, there = neighbours[room][int(j)]
            if other == parent:
                continue
            out.extend((here, there))
            visit(other, room)
            out.extend((there, here))

    visit(int(rng.integers(len(rooms))), -1)
    return np.array(out)


_BATCH = 64  # clutter candidates drawn (and tested vectorised) at a time


def _distances(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """``(n, m)`` distances [m] between points ``u`` ``(n, 2)`` and ``v`` ``(m, 2)``.

    The arithmetic of ``np.linalg.norm(u[:, None] - v[None], axis=-1)``, without its
    slow reduction over an axis of length 2.
    """
    dx = u[:, 0:1] - v[:, 0]
    dy = u[:, 1:2] - v[:, 1]
    dx *= dx
    dy *= dy
    dx += dy
    return np.sqrt(dx, out=dx)


@dataclass(frozen=True)
class _Candidates:
    """A batch of random clutter objects as parameter arrays (one entry per candidate)."""

    kind: np.ndarray  # index into CLUTTER_KINDS
    center: np.ndarray  # (n, 2) centre of the bounding box [m]
    size: np.ndarray  # (n, 2) bounding-box sides before rotation [m]; disc diameter in [:, 0]
    arm: np.ndarray  # L-shape arm width as a fraction of the shorter side
    angle: np.ndarray  # rotation [rad]
    post_radius: np.ndarray  # [m]

    @classmethod
    def draw(
        cls, p: RandomWorldParams, rng: np.random.Generator, n: int, kind_cdf: np.ndarray
    ) -> _Candidates:
        """Draw ``n`` candidates; ``kind_cdf`` from :func:`_kind_cdf`.

        The numbers and arithmetic of one ``rng.choice`` (kinds) and one ``rng.uniform``
        call per field, in the order kinds, centres, sizes, arms, angles (only if rotated)
        and post radii (tests check it), but from a single ``rng.random`` call: each field
        is ``low + (high - low) * u``, kinds are ``u`` inverted through ``kind_cdf``.
        """
        u = rng.random((8 if p.rotate_clutter else 7) * n)
        inset = p.wall_thickness / 2
        low = np.array([inset, inset])
        high = np.array([p.width - inset, p.height - inset])
        (size_low, size_high), (arm_low, arm_high) = p.clutter_size, p.l_arm_fraction
        post_low, post_high = p.post_radius
        return cls(
            kind=kind_cdf.searchsorted(u[:n], side="right"),
            center=low + (high - low) * u[n : 3 * n].reshape(n, 2),
            size=size_low + (size_high - size_low) * u[3 * n : 5 * n].reshape(n, 2),
            arm=arm_low + (arm_high - arm_low) * u[5 * n : 6 * n],
            angle=2 * math.pi * u[6 * n : 7 * n] if p.rotate_clutter else np.zeros(n),
            post_radius=post_low + (post_high - post_low) * u[-n:],
        )

    @property
    def bounding_radius(self) -> np.ndarray:
        """Radius [m] of a circle about ``center`` that holds each candidate."""
        kind, width, height = self.kind, self.size[:, 0], self.size[:, 1]
        radius = np.where(
            kind == CLUTTER_KINDS.index("disc"), width / 2, np.hypot(width, height) / 2
        )
        return np.where(
            kind == CLUTTER_KINDS.index("post"), self.post_radius * math.sqrt(2.0), radius
        )

    def rows(self, js: np.ndarray) -> list[list[float]]:
        """Candidates ``js`` as rows ``[kind, x, y, width, height, arm, angle, post_radius]``."""
        columns = (self.kind, self.center, self.size, self.arm, self.angle, self.post_radius)
        return np.column_stack(columns)[js].tolist()


def _clutter_obstacles(rows: list[list[float]]) -> list[Obstacle]:
    """Clutter objects from candidate rows (:meth:`_Candidates.rows`), in that order.

    A polygon's corners are rotated by ``angle`` about the bounding-box centre and moved
    there: ``corners @ [[c, s], [-s, c]] + center``, one stacked product per vertex count
    (numpy multiplies each stacked pair exactly as it would alone).
    """
    out: dict[int, Obstacle] = {}  # by position in `rows`
    # Polygons by vertex count: positions in `rows`, centres, corners, rotation matrices.
    groups: dict[int, tuple[list[int], list[object], list[object], list[object]]] = {}
    for i, (kind_index, x, y, w, h, arm, angle, post_radius) in enumerate(rows):
        kind = CLUTTER_KINDS[int(kind_index)]
        if kind == "disc":
            out[i] = CircleObstacle(center=(x, y), radius=w / 2)
            continue
        if kind == "post":  # a small square post (corners for the line landmarks)
            r = post_radius
            corners = [(-r, -r), (r, -r), (r, r), (-r, r)]
        else:  # corners relative to the centre of the bounding box
            if kind == "box":
                corners = [(0.0, 0.0), (w, 0.0), (w, h), (0.0, h)]
            else:
                a = arm * min(w, h)
                corners = [(0.0, 0.0), (w, 0.0), (w, a), (a, a), (a, h), (0.0, h)]
            half_w, half_h = w / 2, h / 2
            corners = [(cx - half_w, cy - half_h) for cx, cy in corners]
        c, s = math.cos(angle), math.sin(angle)
        group = groups.setdefault(len(corners), ([], [], [], []))
        group[0].append(i)
        group[1].append([x, y])
        group[2].append(corners)
        group[3].append([[c, s], [-s, c]])
    for positions, center, corners, rotation in groups.values():
        points = np.matmul(np.array(corners), np.array(rotation)) + np.array(center)[:, None, :]
        for i, polygon in zip(positions, points.tolist(), strict=True):
            out[i] = PolygonObstacle(points=tuple(map(tuple, polygon)))
    return [out[i] for i in range(len(rows))]


def _place_clutter(
    p: RandomWorldParams,
    rng: np.random.Generator,
    walls: list[WallObstacle],
    waypoints: np.ndarray,
) -> list[Obstacle]:
    """Rejection-sample ``p.n_obstacles`` clutter objects (see the module docstring).

    Gaps are measured conservatively from each candidate's bounding circle, so actual
    gaps are at least the demanded ones.
    """
    caps = [shapes.obstacle_capsules(w) for w in walls]
    closed = np.vstack([waypoints, waypoints[:1]])
    route_gap = p.robot_radius + p.min_clearance
    fixed_a = np.vstack([c[0] for c in caps] + [closed[:-1]])
    fixed_b = np.vstack([c[1] for c in caps] + [closed[1:]])
    fixed_need = np.concatenate(  # capsule radius + demanded gap
        [np.concatenate([c[2] for c in caps]) + p.min_gap, np.full(len(closed) - 1, route_gap)]
    )
    # The clutter placed so far: candidate rows, and bounding circles (first n_placed).
    placed: list[list[float]] = []
    placed_center = np.empty((p.n_obstacles, 2))
    placed_radius = np.empty(p.n_obstacles)
    # The mix of kinds is drawn once; candidates of a kind whose quota is full are
    # skipped (otherwise small kinds, easier to place, would crowd out the others) for
    # the first 1/_QUOTA_PHASE of the attempt budget, after which a crowded floor takes
    # any kind.
    kind_cdf = _kind_cdf(p)
    quota = np.bincount(
        _draw_kinds(rng, kind_cdf, p.n_obstacles), minlength=len(CLUTTER_KINDS)
    ).tolist()
    count = [0] * len(CLUTTER_KINDS)
    budget = p.max_attempts * p.n_obstacles
    drawn = 0
    while len(placed) < p.n_obstacles:
        if drawn >= budget:
            raise RandomWorldError(
                f"placed only {len(placed)} of {p.n_obstacles} clutter objects after {drawn} "
                f"attempts; lower n_obstacles, clutter_size or min_gap, or enlarge the world"
            )
        cand = _Candidates.draw(p, rng, _BATCH, kind_cdf)
        drawn += _BATCH
        quotas_hold = drawn < budget // _QUOTA_PHASE
        # Narrow the batch down, cheapest test first, to the candidates of a kind with
        # room in its quota (while quotas hold) that keep their gaps to the placed and
        # the fixed obstacles. Each test is elementwise, so it gives the same verdict on
        # any subset of the batch.
        if quotas_hold:
            index = np.flatnonzero(np.less(count, quota)[cand.kind])
        else:
            index = np.arange(_BATCH)
        center, reach = cand.center[index], cand.bounding_radius[index]
        if placed:
            d = _distances(center, placed_center[: len(placed)])
            ok = np.all(d - placed_radius[: len(placed)] - p.min_gap >= reach[:, None], axis=1)
            index, center, reach = index[ok], center[ok], reach[ok]
        d_fixed = shapes.point_segment_distance(center, fixed_a, fixed_b)
        ok = np.all(d_fixed - fixed_need[None, :] >= reach[:, None], axis=1)
        index, center, reach = index[ok], center[ok], reach[ok]
        # The survivors in batch order, each kept unless it clashes with one kept before
        # it in this batch (clash[i][j]: candidate j is too close to candidate i).
        d = _distances(center, center)
        clash = (d - reach[:, None] - p.min_gap < reach[None, :]).tolist()
        kept: list[int] = []
        room = p.n_obstacles - len(placed)
        for j, kind in enumerate(cand.kind[index].tolist()):
            if quotas_hold and count[kind] >= quota[kind]:
                continue
            if any(clash[i][j] for i in kept):
                continue
            kept.append(j)
            count[kind] += 1
            if len(kept) == room:
                break
        n_before = len(placed)
        placed.extend(cand.rows(index[kept]))
        placed_center[n_before : len(placed)] = center[kept]
        placed_radius[n_before : len(placed)] = reach[kept]
    return _clutter_obstacles(placed)


def generate_random_world(rng: np.random.Generator | int | None = None, **params: Any) -> World:
    """Generate a rooms-and-clutter world (see the module docstring for the construction).

    Args:
        rng: the random generator (used as is), or a seed for a new one; ``None`` seeds
            from the operating system.
        **params: fields of :class:`RandomWorldParams` (unknown names raise
            ``UnknownKeyError`` with a "did you mean" suggestion).

    Returns:
        A world named ``"random"``: the outer wall, the partition walls, then
        ``n_obstacles`` clutter objects (in that order), a looping route, the robot on the
        route's first waypoint facing the second, and the thesis lidar/odometry defaults.

    Raises:
        ValueError: bad parameters.
        RandomWorldError: the rooms or the clutter do not fit (too dense).
    """
    p = RandomWorldParams.from_dict(params)
    gen = np.random.default_rng(rng)
    rooms, doors = _split_rooms(p, gen)
    walls = _walls(p, doors)
    waypoints = _route(p, gen, rooms, doors)
    if len(waypoints) > 1:
        heading = waypoints[1] - waypoints[0]
        theta = math.atan2(heading[1], heading[0])
    else:
        theta = float(gen.uniform(-math.pi, math.pi))

    clutter = _place_clutter(p, gen, walls, waypoints)
    return World(
        name="random",
        robot=RobotSpec(
            start=(float(waypoints[0][0]), float(waypoints[0][1]), theta), radius=p.robot_radius
        ),
        obstacles=(*walls, *clutter),
        route=Route(waypoints=tuple(map(tuple, waypoints.tolist())), loop=len(waypoints) > 1),
        description=(
            f"Procedurally generated {p.width:g} m x {p.height:g} m world: {p.n_rooms} rooms, "
            f"{p.n_obstacles} clutter objects"
        ),
    )
