"""Reader for Carmen text logs of a 2-D lidar robot (``.log`` or ``.log.gz``).

The format and conventions are those of the Radish "corrected" logs (Intel Research
Lab, UT Austin ACES; see ``/work/shared/data/radish/README.md``)::

    FLASER n r_1 .. r_n x y theta odom_x odom_y odom_theta ipc_timestamp [host logger_timestamp]
    ODOM x y theta tv rv accel timestamp [host logger_timestamp]
    PARAM name value [host timestamp]

- Carmen lists the beams RIGHT to LEFT (beam 0 points to the robot's right, bearing
  ``-90 deg``, counter-clockwise); SPEC section 0 wants scans sorted by DEScending
  bearing (left to right), so :func:`read_carmen` reverses every scan and its bearings.
- No-return readings use a sentinel value (81.83 m in Intel, 50.00 m in ACES). They are
  detected with a per-log threshold (:class:`CarmenConfig`) and set to the log's
  maximum range, which the estimator treats as "no return".
- ``ODOM`` is re-anchored at every scan: the ``ODOM`` right after a ``FLASER`` equals
  that scan's corrected pose and the last ``ODOM`` before the next ``FLASER`` is the
  odometry pose at that next scan (:func:`logged_increments`).
- Comment lines (``#``) and blank lines are ignored; other message types (``NEFF``,
  ``RLASER``, ...) are skipped and counted in :attr:`CarmenLog.skipped`.

Frames and units: world frame of the log (x, y [m], theta [rad] counter-clockwise);
ranges [m]; bearings [rad] in the lidar frame, counter-clockwise from its x axis;
timestamps [s]. Odometry increments are ``[rot1 [rad], trans [m], rot2 [rad]]``
(Thrun's odometry model, as :func:`vslam_gym.slam.motion.predict_pose` consumes them).
"""

from __future__ import annotations

import gzip
import io
import math
import os
from collections import Counter
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from typing import IO

import numpy as np

from vslam_gym.config_utils import check_field_types
from vslam_gym.slam.geometry import wrap_angle
from vslam_gym.slam.motion import compose, increments_between, inverse, predict_pose

__all__ = [
    "CarmenConfig",
    "CarmenFormatError",
    "CarmenLog",
    "integrate_increments",
    "logged_increments",
    "read_carmen",
    "synthetic_increments",
]

GZIP_MAGIC = b"\x1f\x8b"
"""First two bytes of a gzip stream."""
FLASER_TRAILING_FIELDS = 7
"""Numeric fields after the ranges of a ``FLASER``: pose (3), odometry pose (3), timestamp."""
ODOM_FIELDS = 7
"""Numeric fields of an ``ODOM``: x, y, theta, tv, rv, accel, timestamp."""
PARAM_FIELDS = 2
"""Fields of a ``PARAM``: name, value (host and timestamp optional)."""
PARAM_RESOLUTION = "laser_front_laser_resolution"
"""``PARAM`` with the angle between adjacent front-laser beams [deg]."""
PARAM_FOV = "laser_front_laser_fov"
"""``PARAM`` with the front laser's field of view [deg]."""
PARAM_LASER_OFFSET = "robot_frontlaser_offset"
"""``PARAM`` with the forward offset [m] of the front laser from the robot origin."""
PARAM_MAX_RANGE = "laser_front_laser_max_range"
"""``PARAM`` with the range [m] the front laser reports for "no return" (written by
:func:`vslam_gym.logs.write_carmen`; the Radish logs have none)."""
DEFAULT_ALPHAS = (0.01, 0.005, 0.005, 0.001)
"""Thrun odometry-model coefficients ``(a1, a2, a3, a4)`` of the synthetic odometry."""


class CarmenFormatError(ValueError):
    """A Carmen log line that cannot be parsed; the message names its line number."""

    def __init__(self, message: str, line: int | None = None) -> None:
        self.line = line
        super().__init__(f"line {line}: {message}" if line is not None else message)


@dataclass(frozen=True)
class CarmenConfig:
    """How :func:`read_carmen` interprets a log.

    Attributes:
        no_return_fraction: readings ``>= no_return_fraction * max(all readings)`` are
            "no return" (the sentinel is the largest value in a log: 81.83 m Intel,
            50.00 m ACES). Used when ``no_return_threshold`` is ``None`` and the log
            has no ``laser_front_laser_max_range`` ``PARAM``.
        no_return_threshold: absolute threshold [m]: readings at or above it are "no
            return"; overrides the ``PARAM`` and ``no_return_fraction``. Without it, a
            log's ``laser_front_laser_max_range`` ``PARAM`` is the threshold (a log of
            a closed room may have no "no return" reading at all, so its largest
            reading would be taken for the sentinel).
        max_range: the range [m] no-return readings are set to, and beyond which any
            reading counts as no return (e.g. 30.0 to clip as the thesis did). ``None``:
            the no-return threshold itself.
        resolution_deg: angle between adjacent beams [deg] when the log has no
            ``laser_front_laser_resolution`` ``PARAM``.
        bearing_offset_deg: added to every beam's bearing [deg]: Carmen's convention
            (first beam at ``-fov/2``: ``-90 .. +89 deg`` for 180 beams at 1 deg) is not
            every logger's (``+0.5``: beams centred on ``-89.5 .. +89.5``; ``+1``: the
            first of 181 dropped), and a lidar mounted turned by a small angle shows
            the same way. :func:`vslam_gym.logs.bearing_check.bearing_offset_scores`
            tells it from the log's reference poses (the Radish logs: 0, docs/radish.md,
            "The bearing convention").
    """

    no_return_fraction: float = 0.999
    no_return_threshold: float | None = None
    max_range: float | None = None
    resolution_deg: float = 1.0
    bearing_offset_deg: float = 0.0

    def __post_init__(self) -> None:
        check_field_types(self)
        if not (math.isfinite(self.no_return_fraction) and 0 < self.no_return_fraction <= 1):
            raise ValueError(
                "CarmenConfig.no_return_fraction must be in (0, 1], "
                f"got {self.no_return_fraction!r}"
            )
        for name in ("no_return_threshold", "max_range", "resolution_deg"):
            value = getattr(self, name)
            if value is not None and not (math.isfinite(value) and value > 0):
                raise ValueError(f"CarmenConfig.{name} must be finite and > 0, got {value!r}")
        if not math.isfinite(self.bearing_offset_deg):
            raise ValueError(
                f"CarmenConfig.bearing_offset_deg must be finite, got {self.bearing_offset_deg!r}"
            )


@dataclass
class CarmenLog:
    """The scans, poses and odometry of one Carmen log (``N`` scans of ``n`` beams).

    Attributes:
        ranges: ``(N, n)`` ranges [m] sorted by descending bearing (left to right);
            no-return beams hold ``max_range``.
        bearings: ``(n,)`` beam bearings [rad], descending (e.g. ``+89 .. -90 deg``).
        no_return: ``(N, n)`` bool, the beam had no return (sentinel or beyond
            ``max_range``), in the same order as ``ranges``.
        poses: ``(N, 3)`` corrected poses ``(x [m], y [m], theta [rad])`` of the scans.
        scan_odometry: ``(N, 3)`` the odometry pose fields of the ``FLASER`` lines (the
            corrected pose again in the Radish corrected logs).
        times: ``(N,)`` ``FLASER`` timestamps [s] (as logged; not always increasing).
        scan_lines: ``(N,)`` 1-based line numbers of the ``FLASER`` lines.
        odometry: ``(M, 3)`` ``ODOM`` poses ``(x, y, theta)``.
        odometry_velocities: ``(M, 3)`` ``ODOM`` ``(tv [m/s], rv [rad/s], accel [m/s^2])``.
        odometry_times: ``(M,)`` ``ODOM`` timestamps [s].
        odometry_after_scan: ``(M,)`` index of the last scan before each ``ODOM`` (-1 if
            none).
        params: ``PARAM`` name to value (strings, the last occurrence wins).
        skipped: count of skipped lines per unknown message type.
        max_range: the range [m] no-return beams were set to.
        no_return_threshold: the threshold [m] the sentinel was detected with.
        source: the file name, or ``"<stream>"``.
    """

    ranges: np.ndarray
    bearings: np.ndarray
    no_return: np.ndarray
    poses: np.ndarray
    scan_odometry: np.ndarray
    times: np.ndarray
    scan_lines: np.ndarray
    odometry: np.ndarray
    odometry_velocities: np.ndarray
    odometry_times: np.ndarray
    odometry_after_scan: np.ndarray
    params: dict[str, str] = field(default_factory=dict)
    skipped: dict[str, int] = field(default_factory=dict)
    max_range: float = 0.0
    no_return_threshold: float = 0.0
    source: str = "<stream>"

    @property
    def num_scans(self) -> int:
        """Number of scans ``N``."""
        return int(self.ranges.shape[0])

    @property
    def num_beams(self) -> int:
        """Beams per scan ``n``."""
        return int(self.ranges.shape[1])

    @property
    def lidar_offset(self) -> tuple[float, float, float]:
        """Lidar pose in the robot frame ``(x [m], y [m], theta [rad])`` from ``PARAM``.

        Only the forward offset ``robot_frontlaser_offset`` is logged; zero if absent.
        """
        return (float(self.params.get(PARAM_LASER_OFFSET, 0.0)), 0.0, 0.0)


def _open_text(source: str | os.PathLike[str] | IO[str] | IO[bytes]) -> tuple[IO[str], str, bool]:
    """A text stream over ``source`` (gzip detected by its magic bytes), its name, owned."""
    if isinstance(source, (str, os.PathLike)):
        name = os.fspath(source)
        with open(name, "rb") as fh:
            magic = fh.read(len(GZIP_MAGIC))
        if magic == GZIP_MAGIC:
            return gzip.open(name, "rt", encoding="utf-8"), name, True
        return open(name, encoding="utf-8"), name, True
    name = str(getattr(source, "name", "<stream>"))
    if isinstance(source, io.TextIOBase):
        return source, name, False
    data = source.read()
    if isinstance(data, str):
        return io.StringIO(data), name, False
    if data[: len(GZIP_MAGIC)] == GZIP_MAGIC:
        data = gzip.decompress(data)
    return io.StringIO(data.decode("utf-8")), name, False


def _floats(tokens: Iterable[str], what: str, line: int) -> list[float]:
    """Parse finite floats or raise :class:`CarmenFormatError` naming ``line``."""
    out = []
    for tok in tokens:
        try:
            value = float(tok)
        except ValueError:
            raise CarmenFormatError(f"{what}: {tok!r} is not a number", line) from None
        if not math.isfinite(value):
            raise CarmenFormatError(f"{what}: {tok!r} is not finite", line)
        out.append(value)
    return out


def _lines(stream: IO[str]) -> Iterator[tuple[int, list[str]]]:
    """``(1-based line number, tokens)`` of every non-blank, non-comment line."""
    for number, text in enumerate(stream, start=1):
        tokens = text.split()
        if tokens and not tokens[0].startswith("#"):
            yield number, tokens


def _param_length(params: dict[str, str], name: str) -> float:
    """A ``PARAM`` that must be a positive finite number (a length [m], an angle [deg])."""
    try:
        value = float(params[name])
    except ValueError:
        raise CarmenFormatError(f"PARAM {name} must be a number, got {params[name]!r}") from None
    if not (math.isfinite(value) and value > 0.0):
        raise CarmenFormatError(f"PARAM {name} must be finite and > 0, got {params[name]!r}")
    return value


def _bearings(num_beams: int, params: dict[str, str], config: CarmenConfig) -> np.ndarray:
    """Descending ``(n,)`` bearings [rad]: Carmen's right-to-left order reversed.

    Carmen beam ``i`` has bearing ``-fov/2 + i * res`` with ``res`` from the
    ``laser_front_laser_resolution`` ``PARAM`` (else ``config.resolution_deg``) and
    ``fov`` from ``laser_front_laser_fov`` (else ``n * res``): 180 beams at 1 deg give
    ``-90 .. +89 deg``; ``config.bearing_offset_deg`` is added to every one.
    """
    res = config.resolution_deg
    if PARAM_RESOLUTION in params:
        res = _param_length(params, PARAM_RESOLUTION)
    fov = _param_length(params, PARAM_FOV) if PARAM_FOV in params else num_beams * res
    carmen = np.deg2rad(-fov / 2.0 + config.bearing_offset_deg + res * np.arange(num_beams))
    return carmen[::-1].copy()


def read_carmen(
    source: str | os.PathLike[str] | IO[str] | IO[bytes], config: CarmenConfig | None = None
) -> CarmenLog:
    """Read a Carmen log (plain or gzipped) into a :class:`CarmenLog`.

    Args:
        source: a path (``.log`` or ``.log.gz``; gzip is recognised by its content) or an
            open text or binary file.
        config: sentinel detection and beam geometry; defaults to :class:`CarmenConfig`.

    Returns:
        The log, scans in SPEC order (descending bearing) with no-return beams at
        ``max_range``.

    Raises:
        CarmenFormatError: a malformed ``FLASER``, ``ODOM`` or ``PARAM`` line (bad field
            count or value, scans with differing beam counts), or no ``FLASER`` at all.
    """
    cfg = config if config is not None else CarmenConfig()
    stream, name, owned = _open_text(source)
    scans: list[list[float]] = []
    scan_info: list[list[float]] = []
    scan_lines: list[int] = []
    odom: list[list[float]] = []
    odom_after: list[int] = []
    params: dict[str, str] = {}
    skipped: Counter[str] = Counter()
    try:
        for number, tokens in _lines(stream):
            kind, fields = tokens[0], tokens[1:]
            if kind == "FLASER":
                if not fields:
                    raise CarmenFormatError("FLASER without a beam count", number)
                try:
                    n = int(fields[0])
                except ValueError:
                    raise CarmenFormatError(
                        f"FLASER beam count {fields[0]!r} is not an integer", number
                    ) from None
                if n <= 0:
                    raise CarmenFormatError(f"FLASER beam count must be > 0, got {n}", number)
                if scans and n != len(scans[0]):
                    raise CarmenFormatError(
                        f"FLASER has {n} beams, earlier scans have {len(scans[0])}", number
                    )
                if len(fields) < 1 + n + FLASER_TRAILING_FIELDS:
                    raise CarmenFormatError(
                        f"FLASER with {n} beams needs at least {1 + n + FLASER_TRAILING_FIELDS}"
                        f" fields after the type, got {len(fields)}",
                        number,
                    )
                ranges = _floats(fields[1 : 1 + n], "FLASER range", number)
                if min(ranges) < 0:
                    raise CarmenFormatError(f"FLASER has a negative range {min(ranges)}", number)
                scans.append(ranges)
                scan_info.append(
                    _floats(fields[1 + n : 1 + n + FLASER_TRAILING_FIELDS], "FLASER pose", number)
                )
                scan_lines.append(number)
            elif kind == "ODOM":
                if len(fields) < ODOM_FIELDS:
                    raise CarmenFormatError(
                        f"ODOM needs at least {ODOM_FIELDS} fields, got {len(fields)}", number
                    )
                odom.append(_floats(fields[:ODOM_FIELDS], "ODOM", number))
                odom_after.append(len(scans) - 1)
            elif kind == "PARAM":
                if len(fields) < PARAM_FIELDS:
                    raise CarmenFormatError(
                        f"PARAM needs a name and a value, got {len(fields)} fields", number
                    )
                params[fields[0]] = fields[1]
            else:
                skipped[kind] += 1
    except UnicodeDecodeError as exc:  # a binary or differently encoded file
        raise CarmenFormatError(
            f"{name}: not UTF-8 text ({exc.reason} at byte {exc.start})"
        ) from None
    finally:
        if owned:
            stream.close()
    if not scans:
        raise CarmenFormatError(f"{name}: no FLASER scan in the log")

    raw = np.asarray(scans, dtype=float)[:, ::-1]  # Carmen right-to-left -> descending bearing
    if cfg.no_return_threshold is not None:
        threshold = cfg.no_return_threshold
    elif PARAM_MAX_RANGE in params:
        threshold = _param_length(params, PARAM_MAX_RANGE)
    else:
        threshold = cfg.no_return_fraction * float(raw.max())
    max_range = cfg.max_range if cfg.max_range is not None else threshold
    no_return = (raw >= threshold) | (raw >= max_range)
    ranges = np.where(no_return, max_range, raw)
    info = np.asarray(scan_info, dtype=float)
    odo = np.asarray(odom, dtype=float).reshape(-1, ODOM_FIELDS)
    return CarmenLog(
        ranges=ranges,
        bearings=_bearings(raw.shape[1], params, cfg),
        no_return=no_return,
        poses=info[:, 0:3].copy(),
        scan_odometry=info[:, 3:6].copy(),
        times=info[:, 6].copy(),
        scan_lines=np.asarray(scan_lines, dtype=int),
        odometry=odo[:, 0:3].copy(),
        odometry_velocities=odo[:, 3:6].copy(),
        odometry_times=odo[:, 6].copy(),
        odometry_after_scan=np.asarray(odom_after, dtype=int),
        params=params,
        skipped=dict(skipped),
        max_range=float(max_range),
        no_return_threshold=float(threshold),
        source=name,
    )


def logged_increments(log: CarmenLog) -> np.ndarray:
    """The real wheel-odometry increments between consecutive scans.

    Step ``k`` (scan ``k`` to ``k + 1``) is the relative pose
    ``inverse(P_k) (+) O``, with ``P_k`` scan ``k``'s corrected pose and ``O`` the last
    ``ODOM`` before scan ``k + 1`` (the logs re-anchor ODOM at every scan), expressed as
    increments ``[rot1 [rad], trans [m], rot2 [rad]]``. When that ``ODOM``'s
    translational velocity ``tv`` is negative (the robot drove backwards) and the
    motion points backwards, ``trans`` is negative and ``rot1`` within ``+-pi/2``, as the
    simulator's odometry reports a reverse (:mod:`vslam_gym.sim.odometry`; the same pose
    change, without the textbook form's ``rot1 ~ +-pi`` and its large rotation noise);
    the Radish logs log ``tv`` 0 throughout, so their increments keep the textbook form.

    Returns:
        ``(N - 1, 3)`` increments.

    Raises:
        CarmenFormatError: no ``ODOM`` between two consecutive scans (names the line of
            the later ``FLASER``).
    """
    out = np.zeros((max(log.num_scans - 1, 0), 3))
    # Index of the last ODOM whose preceding scan is k, for every k (-1 if none).
    last = np.full(log.num_scans, -1, dtype=int)
    after = log.odometry_after_scan
    valid = after >= 0
    last[after[valid]] = np.flatnonzero(valid)  # later indices overwrite earlier ones
    origin = np.zeros(3)
    for k in range(log.num_scans - 1):
        if last[k] < 0:
            raise CarmenFormatError(
                f"no ODOM between scans {k} and {k + 1}", int(log.scan_lines[k + 1])
            )
        relative = compose(inverse(log.poses[k]), log.odometry[last[k]])
        out[k] = increments_between(origin, relative)
        if log.odometry_velocities[last[k], 0] < 0.0 and abs(out[k, 0]) > math.pi / 2.0:
            rot1 = float(wrap_angle(out[k, 0] - math.pi))
            out[k] = (rot1, -out[k, 1], float(wrap_angle(relative[2] - rot1)))
    return out


def synthetic_increments(
    log: CarmenLog,
    seed: int | np.random.Generator,
    alphas: tuple[float, float, float, float] = DEFAULT_ALPHAS,
) -> np.ndarray:
    """Noisy odometry derived from the corrected poses with Thrun's odometry model.

    True increments ``[rot1, trans, rot2]`` between consecutive corrected poses
    (:func:`~vslam_gym.slam.motion.increments_between`) plus zero-mean normal noise with
    ``var(rot1) = a1 rot1^2 + a2 trans^2``, ``var(trans) = a3 trans^2 + a4 (rot1^2 +
    rot2^2)``, ``var(rot2) = a1 rot2^2 + a2 trans^2``; three standard-normal draws per
    step, in scan order and in the order rot1, trans, rot2.

    Args:
        log: the log.
        seed: seed of ``numpy.random.default_rng``, or a generator to draw from.
        alphas: ``(a1, a2, a3, a4)``, each ``>= 0``.

    Returns:
        ``(N - 1, 3)`` increments ``[rot1 [rad], trans [m], rot2 [rad]]``.
    """
    a = np.asarray(alphas, dtype=float)
    if a.shape != (4,) or not np.all(np.isfinite(a)) or np.any(a < 0):
        raise ValueError(f"alphas must be 4 finite numbers >= 0, got {alphas!r}")
    rng = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)
    a1, a2, a3, a4 = a
    out = np.zeros((max(log.num_scans - 1, 0), 3))
    for k in range(log.num_scans - 1):
        rot1, trans, rot2 = increments_between(log.poses[k], log.poses[k + 1])
        std = np.sqrt(
            [
                a1 * rot1**2 + a2 * trans**2,
                a3 * trans**2 + a4 * (rot1**2 + rot2**2),
                a1 * rot2**2 + a2 * trans**2,
            ]
        )
        out[k] = np.array([rot1, trans, rot2]) + std * rng.standard_normal(3)
    return out


def integrate_increments(start: np.ndarray, increments: np.ndarray) -> np.ndarray:
    """Dead reckoning: poses ``(T + 1, 3)`` from ``start`` ``(3,)`` and ``(T, 3)`` increments.

    Headings are wrapped to ``[-pi, pi)``; row 0 is ``start``.
    """
    inc = np.asarray(increments, dtype=float).reshape(-1, 3)
    poses = np.zeros((inc.shape[0] + 1, 3))
    poses[0] = np.asarray(start, dtype=float)
    for k, u in enumerate(inc):
        poses[k + 1] = predict_pose(poses[k], u)
    return poses
