"""The fast paths of the landmark model agree with plain reference computations."""

from __future__ import annotations

import numpy as np
import pytest
from _raycast import bearings_deg, cast

from vslam_gym.slam.config import ModelConfig, SensorConfig
from vslam_gym.slam.creation import create_model, initial_grouping, several_groups
from vslam_gym.slam.detection import beam_line_correspondence
from vslam_gym.slam.gaussian import make_linearization
from vslam_gym.slam.likelihood import exponential_rate, generalized_mahalanobis_sq, line_loglik
from vslam_gym.slam.scan import Scan

SENSOR = SensorConfig()
PHI = bearings_deg(SENSOR.fov_deg, SENSOR.resolution_deg)
ZIGZAG = np.array([(-3.0, 5.0), (-1.0, 6.5), (1.0, 5.5), (3.0, 7.0), (5.0, 6.0)])
EDGES = np.stack([ZIGZAG[:-1], ZIGZAG[1:]], axis=1)
BUILD = np.array([1.0, -1.5, np.pi / 2])
OTHER = np.array([1.3, -1.2, np.pi / 2 + 0.05])


def grid_d2(x: float, var: float, u: float, lam: float) -> float:
    """d_GM^2 with the mode from a dense grid refined twice (reference)."""
    s = np.sqrt(var)
    lo, hi = 0.0, 40.0 * s
    for _ in range(3):
        grid = np.linspace(lo, hi, 4001)
        mode = grid[np.argmax(line_loglik(grid, var, u, lam))]
        step = grid[1] - grid[0]
        lo, hi = max(mode - step, 0.0), mode + step
    peak = line_loglik(mode, var, u, lam)
    return float(2.0 * (peak - line_loglik(x, var, u, lam)))


def test_generalized_mahalanobis_matches_grid_mode():
    rng = np.random.default_rng(3)
    n = 40
    s = 10 ** rng.uniform(-2.5, -0.5, n)
    lam = 10 ** rng.uniform(-2, 0.5, n)
    u = np.where(rng.random(n) < 0.3, 1.0, 10 ** rng.uniform(-3, 0, n))
    x = rng.normal(0.0, 3.0, n) * s
    d2 = generalized_mahalanobis_sq(x, s**2, u, lam)
    reference = np.array([grid_d2(*args) for args in zip(x, s**2, u, lam, strict=True)])
    # The grid mode is off by up to 1e-5 sigma: d_GM^2 by up to about 1e-10.
    np.testing.assert_allclose(d2, reference, rtol=0, atol=1e-8)
    assert np.all(d2 >= 0.0)


def reference_grouping(mu_c, cov_c, config):
    """Algorithm 3 one trial point at a time (no prefix sums, no batches)."""
    n, start = mu_c.shape[0], config.min_group_size - 1
    groups, a, b = [], 0, start
    while b < n:
        pts = mu_c[a : b + 1]
        p0 = pts.mean(axis=0)
        e = pts - p0
        psi = 0.5 * np.arctan2(2.0 * (e[:, 0] @ e[:, 1]), e[:, 0] @ e[:, 0] - e[:, 1] @ e[:, 1])
        normal = np.array([-np.sin(psi), np.cos(psi)])
        var = np.einsum("i,kij,j->k", normal, cov_c[a : b + 1], normal)
        if np.all((e @ normal) ** 2 <= config.grouping_mahalanobis**2 * var):
            b += 1
        else:
            groups.append((a, b - 1))
            a, b = b - 1, b - 1 + start
    groups.append((a, n - 1))
    return groups


@pytest.mark.parametrize("config", [ModelConfig(), ModelConfig.thesis()], ids=["default", "thesis"])
def test_initial_grouping_matches_one_at_a_time(config):
    rng = np.random.default_rng(5)
    for _ in range(40):
        n = int(rng.integers(3, 150))
        t = np.cumsum(rng.uniform(0.01, 0.1, n))
        curve = np.abs(np.sin(t * rng.uniform(0.5, 5.0))) * rng.uniform(0.0, 2.0)
        mu_c = np.stack([t, curve], axis=1) + rng.normal(0.0, 0.01, (n, 2))
        var = rng.uniform(1e-5, 3e-4)
        cov_c = np.tile(np.eye(2) * var, (n, 1, 1))
        groups = initial_grouping(mu_c, cov_c, config)
        assert groups == reference_grouping(mu_c, cov_c, config)
        assert groups[0][0] == 0 and groups[-1][1] == n - 1
        assert several_groups(mu_c, cov_c, config) == (len(groups) > 1)
        straight = np.stack([t, np.zeros(n)], axis=1)  # one line: a single group
        assert not several_groups(straight, cov_c, config)


def test_correspondence_without_distances_assigns_the_same_lines():
    rng = np.random.default_rng(0)
    config = ModelConfig()
    build = Scan.from_arrays(
        cast(BUILD, EDGES, PHI, SENSOR.max_range, SENSOR.sigma_range, SENSOR.sigma_bearing, rng),
        PHI,
        SENSOR,
    )
    idx = np.flatnonzero(build.returns)
    model = create_model(build, int(idx[0]), int(idx[-1]), BUILD, SENSOR, config).model
    scan = Scan.from_arrays(
        cast(OTHER, EDGES, PHI, SENSOR.max_range, SENSOR.sigma_range, SENSOR.sigma_bearing, rng),
        PHI,
        SENSOR,
    )
    idx = np.flatnonzero(scan.returns)
    args = (model, scan, int(idx[0]), int(idx[-1]), OTHER, SENSOR, config)
    lin = make_linearization(config)
    lam = exponential_rate(scan.ranges, scan.max_range)
    full = beam_line_correspondence(*args, lin, lam)
    quick = beam_line_correspondence(*args, lin, lam, distances=False)
    np.testing.assert_array_equal(quick.line, full.line)
    np.testing.assert_array_equal(quick.gated, full.gated)
    np.testing.assert_array_equal(quick.loglik, full.loglik)
    assert np.all(np.isnan(quick.d2)) and np.all(np.isfinite(full.d2))
