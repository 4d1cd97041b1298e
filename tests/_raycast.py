"""A tiny exact ray caster against polygons, for estimator tests that need no simulator."""

from __future__ import annotations

import numpy as np


def polygon_edges(polygons: list[np.ndarray]) -> np.ndarray:
    """``(E, 2, 2)`` edges of closed polygons given as ``(k, 2)`` vertex arrays."""
    edges = [np.stack([p, np.roll(p, -1, axis=0)], axis=1) for p in map(np.asarray, polygons)]
    return np.concatenate(edges, axis=0).astype(float)


def cast(
    pose,
    edges: np.ndarray,
    bearings: np.ndarray,
    max_range: float = 30.0,
    sigma_range: float = 0.0,
    sigma_bearing: float = 0.0,
    rng: np.random.Generator | None = None,
) -> np.ndarray:
    """Ranges [m] of beams at ``bearings`` [rad] from ``pose``; no hit gives ``max_range``.

    Noise: the cast direction is perturbed by N(0, sigma_bearing^2) (the reported bearing
    stays nominal) and hits get N(0, sigma_range^2) added.
    """
    x, y, th = pose
    phi = np.asarray(bearings, dtype=float)
    if rng is not None and sigma_bearing > 0:
        phi = phi + rng.normal(0.0, sigma_bearing, phi.shape)
    d = np.stack([np.cos(th + phi), np.sin(th + phi)], axis=1)  # (n, 2)
    a = edges[:, 0]  # (E, 2)
    e = edges[:, 1] - a
    w = a - np.array([x, y])
    den = d[:, None, 0] * e[None, :, 1] - d[:, None, 1] * e[None, :, 0]
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (w[None, :, 0] * e[None, :, 1] - w[None, :, 1] * e[None, :, 0]) / den
        s = (w[None, :, 0] * d[:, None, 1] - w[None, :, 1] * d[:, None, 0]) / den
    ok = (np.abs(den) > 1e-12) & (t > 1e-9) & (s >= 0) & (s <= 1)
    t = np.where(ok, t, np.inf).min(axis=1)
    hit = t < max_range
    r = np.where(hit, t, max_range)
    if rng is not None and sigma_range > 0:
        r = np.where(hit, r + rng.normal(0.0, sigma_range, r.shape), r)
        r = np.clip(r, 0.0, max_range)
    return r


def bearings_deg(fov_deg: float = 180.0, res_deg: float = 1.0) -> np.ndarray:
    """Descending nominal bearings [rad] spanning the FOV, both limits included."""
    half = np.deg2rad(fov_deg) / 2
    return np.linspace(half, -half, int(round(fov_deg / res_deg)) + 1)
