"""Validated lidar scans (SPEC section 0).

A scan is ``n`` range-bearing pairs sorted by DEScending bearing (left to right as seen
from the lidar). Readings at or beyond the maximum range mean "no return". Every entry
point of the estimator validates its scan here, before touching any state, so that a
rejected scan never leaves a half-updated estimate.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from vslam_gym.slam.config import SensorConfig


class ScanError(ValueError):
    """A scan is malformed (shape, NaN, negative range, bearing order, too few beams)."""


@dataclass(frozen=True)
class Scan:
    """A validated scan in the lidar frame.

    Attributes:
        ranges: ``(n,)`` ranges [m], clipped to ``max_range``; ``max_range`` means no return.
        bearings: ``(n,)`` bearings [rad], strictly descending.
        max_range: the sensor's maximum range [m].
    """

    ranges: np.ndarray
    bearings: np.ndarray
    max_range: float

    @classmethod
    def from_arrays(
        cls, ranges: np.ndarray, bearings: np.ndarray, sensor: SensorConfig, *, min_beams: int = 3
    ) -> Scan:
        """Validate and copy ``ranges`` [m] and ``bearings`` [rad] into a scan.

        Raises:
            ScanError: wrong shapes or lengths, fewer than ``min_beams`` beams, non-finite
                values, negative ranges, bearings not strictly descending or outside the
                field of view.
        """
        r, phi = _real_array(ranges, "ranges"), _real_array(bearings, "bearings")
        if r.ndim != 1 or phi.ndim != 1:
            raise ScanError(
                f"ranges and bearings must be 1-D arrays, got shapes {r.shape} and {phi.shape}"
            )
        if r.shape != phi.shape:
            raise ScanError(f"ranges has {r.size} beams but bearings has {phi.size}")
        if r.size < min_beams:
            raise ScanError(f"a scan needs at least {min_beams} beams, got {r.size}")
        if not np.isfinite(r).all():
            raise ScanError(
                f"ranges contain NaN or inf at beams {np.flatnonzero(~np.isfinite(r))[:5]}"
            )
        if not np.isfinite(phi).all():
            raise ScanError(
                f"bearings contain NaN or inf at beams {np.flatnonzero(~np.isfinite(phi))[:5]}"
            )
        if np.any(r < 0):
            raise ScanError(
                f"ranges must be >= 0, got {r[r < 0][:3]} at beams {np.flatnonzero(r < 0)[:3]}"
            )
        if np.any(np.diff(phi) >= 0):
            bad = np.flatnonzero(np.diff(phi) >= 0)[0]
            raise ScanError(
                "bearings must be strictly descending (left to right), but bearing "
                f"{bad + 1} ({phi[bad + 1]:.4f} rad) >= bearing {bad} ({phi[bad]:.4f} rad)"
            )
        tol = 0.5 * sensor.phi_res
        if phi[0] > sensor.half_fov + tol or phi[-1] < -sensor.half_fov - tol:
            raise ScanError(
                f"bearings span [{phi[-1]:.4f}, {phi[0]:.4f}] rad, outside the field of view "
                f"+-{sensor.half_fov:.4f} rad"
            )
        np.minimum(r, sensor.max_range, out=r)
        r.setflags(write=False)
        phi.setflags(write=False)
        return cls(ranges=r, bearings=phi, max_range=float(sensor.max_range))

    @property
    def n(self) -> int:
        """Number of beams."""
        return int(self.ranges.size)

    @property
    def returns(self) -> np.ndarray:
        """``(n,)`` bool: True where the beam hit something (range below max range)."""
        return self.ranges < self.max_range


def _real_array(values: Any, name: str) -> np.ndarray:
    """A float copy of ``values``, or a :class:`ScanError` naming ``name``.

    Numbers only: booleans, complex numbers and strings are refused rather than cast
    (``True`` as 1 m, ``1 + 2j`` as its real part).
    """
    try:
        raw = np.asarray(values)
    except (TypeError, ValueError) as exc:  # ragged nested sequences
        raise ScanError(f"{name} must be an array of numbers: {exc}") from None
    if raw.dtype.kind not in "iuf":
        raise ScanError(f"{name} must hold real numbers, got dtype {raw.dtype}")
    return np.array(raw, dtype=float, copy=True)
