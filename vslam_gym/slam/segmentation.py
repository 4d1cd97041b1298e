"""Segmentation of a scan into measurement sets (SPEC section 10; thesis 4.3.1-4.3.3).

Two beams with returns belong to one set when their bearings differ by at most
``angle_gap`` and their points are at most ``distance_gap`` apart (thesis: two angular
resolutions and 1 m). The landmark models need contiguous beams, so here a set is a run
of consecutive beams that all have returns, each linked to the next; a no-return beam or
a jump larger than ``distance_gap`` ends the set. (The thesis's two-resolution gap lets a
set bridge one faulty beam; that beam would then sit inside the set's model, so it is
not bridged here.)
"""

from __future__ import annotations

import numpy as np

from vslam_gym.slam.scan import Scan


def segment_scan(
    scan: Scan,
    angle_gap: float,
    distance_gap: float,
    breakpoint_angle: float = 0.0,
    sigma_range: float = 0.0,
) -> list[tuple[int, int]]:
    """Sets of beams as inclusive scan-index ranges ``(first, last)``, left to right.

    Args:
        scan: a validated scan.
        angle_gap: largest bearing difference [rad] of two linked beams.
        distance_gap: largest distance [m] between two linked points.
        breakpoint_angle: ``lambda`` [rad] of the adaptive breakpoint detector (Borges
            and Aldon 2004); 0: off. Two points are also split when they lie further
            apart than a surface seen at ``lambda`` from the beam would put them,
            ``r sin(d_phi) / sin(lambda - d_phi) + 3 sigma_range`` with ``r`` the
            nearer range and ``d_phi`` their bearing difference: a depth jump between
            two objects, which the fixed ``distance_gap`` joins at short range.
        sigma_range: range standard deviation [m] of that bound.

    Returns:
        ``(first, last)`` per set; every beam in a set has a return.
    """
    r, phi = scan.ranges, scan.bearings
    pts = np.stack([r * np.cos(phi), r * np.sin(phi)], axis=1)
    ret = scan.returns
    gap = np.linalg.norm(pts[1:] - pts[:-1], axis=1)
    d_phi = phi[:-1] - phi[1:]
    linked = ret[:-1] & ret[1:] & (d_phi <= angle_gap) & (gap <= distance_gap)
    if breakpoint_angle > 0.0:
        with np.errstate(divide="ignore", invalid="ignore"):
            bound = (
                np.minimum(r[:-1], r[1:]) * np.sin(d_phi) / np.sin(breakpoint_angle - d_phi)
                + 3.0 * sigma_range
            )
        # a bearing step at or beyond lambda itself: no surface bound, the fixed gap only
        linked &= (d_phi >= breakpoint_angle) | (gap <= bound)
    sets = []
    i, n = 0, scan.n
    while i < n:
        if not ret[i]:
            i += 1
            continue
        j = i
        while j < n - 1 and linked[j]:
            j += 1
        sets.append((i, j))
        i = j + 1
    return sets
