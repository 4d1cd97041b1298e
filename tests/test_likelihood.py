"""Range-error likelihoods, the unknown-line density and the detection test."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import integrate, optimize, stats

from vslam_gym.slam.config import ModelConfig, SensorConfig
from vslam_gym.slam.gaussian import FirstOrderLinearization, UnscentedLinearization
from vslam_gym.slam.likelihood import (
    detection_accepts,
    detection_statistics,
    expected_range,
    exponential_rate,
    generalized_mahalanobis_sq,
    generalized_mahalanobis_sq_unchecked,
    line_loglik,
    object_loglik,
    range_error_distribution,
    range_error_jacobian,
    set_loglik,
    unknown_loglik,
)

SENSOR = SensorConfig()


# ------------------------------------------------------------------------ expected range


def test_expected_range_wall_ahead_from_origin() -> None:
    r = expected_range(0.3, [5.0, -1.0], [5.0, 1.0], [0.0, 0.0, 0.0])
    assert r == pytest.approx(5.0 / np.cos(0.3), rel=1e-14)


def test_expected_range_translated_rotated_pose_and_vertex_order() -> None:
    # Lidar at (1, 2) facing +y; wall y = 7 is 5 m ahead; bearing -0.2 (to the right).
    pose = np.array([1.0, 2.0, np.pi / 2])
    bearings = np.array([-0.2, 0.0, 0.4])
    v_a = np.array([[-3.0, 7.0]] * 3)
    v_b = np.array([[4.0, 7.0]] * 3)
    expected = 5.0 / np.cos(bearings)
    np.testing.assert_allclose(expected_range(bearings, v_a, v_b, pose), expected, rtol=1e-13)
    np.testing.assert_allclose(expected_range(bearings, v_b, v_a, pose), expected, rtol=1e-13)
    # A line behind the lidar gives a negative (signed) range.
    behind = expected_range(0.0, [-3.0, -1.0], [4.0, -1.0], pose)
    assert behind == pytest.approx(-3.0, rel=1e-13)


def test_expected_range_equals_thesis_beam_frame_formula() -> None:
    rng = np.random.default_rng(0)
    n = 50
    bearings = rng.uniform(-np.pi / 2, np.pi / 2, n)
    v_a = rng.uniform(-10, 10, (n, 2))
    v_b = rng.uniform(-10, 10, (n, 2))
    pose = rng.uniform(-3, 3, (n, 3))
    ang = pose[:, 2] + bearings
    c, s = np.cos(ang), np.sin(ang)
    rot = np.stack([np.stack([c, s], -1), np.stack([-s, c], -1)], -2)  # R_i
    vp = np.einsum("nij,nj->ni", rot, v_a - pose[:, :2])
    dvp = np.einsum("nij,nj->ni", rot, v_a - v_b)
    thesis = vp[:, 0] - vp[:, 1] * dvp[:, 0] / dvp[:, 1]
    np.testing.assert_allclose(
        expected_range(bearings, v_a, v_b, pose), thesis, rtol=1e-9, atol=1e-9
    )


def test_range_error_jacobian_matches_finite_differences() -> None:
    rng = np.random.default_rng(1)
    pose = np.array([0.5, -0.3, 0.2])
    inputs = np.array(
        [[5.1, 0.1, 5.0, -1.0, 5.5, 2.0], [3.0, -0.6, 2.0, -4.0, 4.0, 1.0]]
    ) + rng.normal(0, 0.01, (2, 6))
    jac = range_error_jacobian(inputs, pose)
    assert jac.shape == (2, 1, 6)
    h = 1e-6
    for k in range(6):
        step = np.zeros(6)
        step[k] = h

        def r_err(x: np.ndarray) -> np.ndarray:
            return x[:, 0] - expected_range(x[:, 1], x[:, 2:4], x[:, 4:6], pose)

        numeric = (r_err(inputs + step) - r_err(inputs - step)) / (2 * h)
        np.testing.assert_allclose(jac[:, 0, k], numeric, rtol=1e-6, atol=1e-7)


# --------------------------------------------------------------- range-error distribution


def _wall_case(rng: np.random.Generator, m: int = 7, vertex_sigma: float = 0.02):
    """A wall x = 5 (vertices (5, -2), (5, 3)) seen from a slightly rotated pose."""
    pose = np.array([0.0, 0.0, 0.05])
    bearings = np.linspace(0.4, -0.3, m)
    true_r = expected_range(bearings, [5.0, -2.0], [5.0, 3.0], pose)
    ranges = true_r + rng.normal(0.0, SENSOR.sigma_range, m)
    mu_vv = np.tile([5.0, -2.0, 5.0, 3.0], (m, 1))
    # Correlated vertex covariance (as from a fit): correlation 0.3 between the x's.
    base = vertex_sigma**2 * np.eye(4)
    base[0, 2] = base[2, 0] = 0.3 * vertex_sigma**2
    Sigma_vv = np.broadcast_to(base, (m, 4, 4)).copy()
    return ranges, bearings, pose, mu_vv, Sigma_vv


def test_range_error_ut_and_first_order_agree_on_a_wall() -> None:
    rng = np.random.default_rng(2)
    ranges, bearings, pose, mu_vv, Sigma_vv = _wall_case(rng)
    args = (ranges, bearings, SENSOR.Q, pose, mu_vv, Sigma_vv)
    mu_ut, var_ut = range_error_distribution(*args, UnscentedLinearization())
    mu_fo, var_fo = range_error_distribution(*args, FirstOrderLinearization())
    mu_num, var_num = range_error_distribution(*args, FirstOrderLinearization(), jacobian=False)
    assert mu_ut.shape == var_ut.shape == (7,)
    # Means agree to well below the range noise (the UT adds the curvature bias, here
    # below 1e-4 m), variances to 1 %.
    np.testing.assert_allclose(mu_ut, mu_fo, atol=1e-2 * SENSOR.sigma_range)
    np.testing.assert_allclose(var_ut, var_fo, rtol=1e-2)
    # Analytic and numerical Jacobians give the same first-order result.
    np.testing.assert_allclose(mu_num, mu_fo, rtol=0, atol=1e-12)
    np.testing.assert_allclose(var_num, var_fo, rtol=1e-6)
    # The variance includes at least the range noise and the wall's x uncertainty.
    assert np.all(var_fo > SENSOR.sigma_range**2)
    # And the mean is the observed range minus the noise-free expected range.
    np.testing.assert_allclose(
        mu_fo, ranges - expected_range(bearings, mu_vv[:, :2], mu_vv[:, 2:], pose), atol=1e-12
    )


def test_range_error_distribution_matches_monte_carlo() -> None:
    rng = np.random.default_rng(3)
    # A more nonlinear case than the wall: a line at an angle to the beams, 4 m away,
    # correlated vertex uncertainty of 5 cm, bearing noise 0.5 deg.
    pose = np.array([0.2, -0.1, 0.3])
    m = 3
    bearings = np.array([0.25, 0.1, -0.05])
    v = np.array([4.0, 2.0, 4.5, -1.5])
    ranges = expected_range(bearings, v[:2], v[2:], pose) + np.array([0.05, -0.02, 0.0])
    mu_vv = np.tile(v, (m, 1))
    corr = np.array(
        [[1.0, 0.2, 0.4, 0.0], [0.2, 1.0, 0.0, 0.3], [0.4, 0.0, 1.0, -0.2], [0.0, 0.3, -0.2, 1.0]]
    )
    Sigma_vv = np.broadcast_to(0.05**2 * corr, (m, 4, 4)).copy()
    Q = np.diag([0.03**2, np.deg2rad(0.5) ** 2])
    mu_ut, var_ut = range_error_distribution(
        ranges, bearings, Q, pose, mu_vv, Sigma_vv, UnscentedLinearization()
    )
    mu_fo, var_fo = range_error_distribution(
        ranges, bearings, Q, pose, mu_vv, Sigma_vv, FirstOrderLinearization()
    )
    n = 200_000
    for i in range(m):
        cov = np.zeros((6, 6))
        cov[:2, :2] = Q
        cov[2:, 2:] = Sigma_vv[i]
        x = rng.multivariate_normal(np.r_[ranges[i], bearings[i], mu_vv[i]], cov, n)
        err = x[:, 0] - expected_range(x[:, 1], x[:, 2:4], x[:, 4:6], pose)
        mc_mean, mc_var = err.mean(), err.var()
        se_mean = np.sqrt(mc_var / n)
        se_var = mc_var * np.sqrt(2.0 / n)
        assert abs(mu_ut[i] - mc_mean) < 4 * se_mean
        assert abs(var_ut[i] - mc_var) < 4 * se_var
        assert abs(mu_fo[i] - mc_mean) < 0.05 * np.sqrt(mc_var)
        assert abs(var_fo[i] - mc_var) < 0.02 * mc_var


def test_range_error_distribution_rejects_bad_input() -> None:
    rng = np.random.default_rng(4)
    ranges, bearings, pose, mu_vv, Sigma_vv = _wall_case(rng, m=3)
    ut = UnscentedLinearization()
    with pytest.raises(ValueError, match="bearings"):
        range_error_distribution(ranges, bearings[:2], SENSOR.Q, pose, mu_vv, Sigma_vv, ut)
    with pytest.raises(ValueError, match="mu_vv"):
        range_error_distribution(ranges, bearings, SENSOR.Q, pose, mu_vv[:, :2], Sigma_vv, ut)
    with pytest.raises(ValueError, match="Sigma_vv"):
        range_error_distribution(ranges, bearings, SENSOR.Q, pose, mu_vv, Sigma_vv[:2], ut)
    bad = ranges.copy()
    bad[1] = np.nan
    with pytest.raises(ValueError, match="ranges"):
        range_error_distribution(bad, bearings, SENSOR.Q, pose, mu_vv, Sigma_vv, ut)
    with pytest.raises(ValueError, match="Q"):
        range_error_distribution(ranges, bearings, np.diag([0.0, 1e-6]), pose, mu_vv, Sigma_vv, ut)
    asym = Sigma_vv.copy()
    asym[0, 0, 1] = 1e-3
    with pytest.raises(ValueError, match="Sigma_vv"):
        range_error_distribution(ranges, bearings, SENSOR.Q, pose, mu_vv, asym, ut)
    with pytest.raises(ValueError, match="pose"):
        range_error_distribution(ranges, bearings, SENSOR.Q, pose[:2], mu_vv, Sigma_vv, ut)


# ---------------------------------------------------------------------- log-likelihoods


def test_object_loglik_is_gaussian_density_at_zero() -> None:
    mu = np.array([0.0, 0.05, -0.1])
    var = np.array([0.03**2, 0.04**2, 0.05**2])
    np.testing.assert_allclose(
        object_loglik(mu, var), stats.norm.logpdf(0.0, loc=mu, scale=np.sqrt(var)), rtol=1e-13
    )
    with pytest.raises(ValueError, match="var_err"):
        object_loglik(mu, np.array([1.0, 0.0, 1.0]))
    with pytest.raises(ValueError, match="mu_err"):
        object_loglik(np.array([np.inf, 0.0, 0.0]), var)
    with pytest.raises(ValueError, match="broadcast"):
        object_loglik(mu, var[:2])


def test_exponential_rate_counts_returns_and_no_returns() -> None:
    ranges = np.array([2.0, 4.0, 30.0, 6.0, 35.0, np.inf])
    # n_z = 3 returns (mean 4), n_r = 3 no-returns at r_max = 30.
    assert exponential_rate(ranges, 30.0) == pytest.approx(3.0 / (3 * 4.0 + 3 * 30.0))
    # Without no-returns it is the inverse mean.
    assert exponential_rate(np.array([1.0, 3.0]), 30.0) == pytest.approx(0.5)
    # No return at all: one expected return over the free path.
    assert exponential_rate(np.full(4, 30.0), 30.0) == pytest.approx(1.0 / 120.0)
    with pytest.raises(ValueError, match="ranges"):
        exponential_rate(np.array([1.0, -1.0]), 30.0)
    with pytest.raises(ValueError, match="ranges"):
        exponential_rate(np.array([]), 30.0)
    with pytest.raises(ValueError, match="max_range"):
        exponential_rate(np.array([1.0]), 0.0)


def test_unknown_loglik_matches_numerical_convolution() -> None:
    lam, s = 0.4, 0.7
    for x in (-2.0, -0.3, 0.0, 0.5, 3.0):

        def integrand(tau: float, x: float = x) -> float:
            return stats.norm.pdf(x - tau, scale=s) * lam * np.exp(-lam * tau)

        direct, _ = integrate.quad(integrand, 0.0, np.inf, epsabs=1e-14)
        assert unknown_loglik(x, s**2, lam) == pytest.approx(np.log(direct), abs=1e-9)
    # Also against scipy's exponentially modified normal (K = 1 / (s lam)).
    xs = np.linspace(-4, 8, 25)
    np.testing.assert_allclose(
        unknown_loglik(xs, s**2, lam),
        stats.exponnorm.logpdf(xs, 1 / (s * lam), scale=s),
        rtol=1e-10,
        atol=1e-12,
    )


@pytest.mark.parametrize(("lam", "s"), [(0.4, 1.0), (0.05, 0.03), (3.0, 0.03), (0.1, 1e-9)])
def test_unknown_density_integrates_to_one(lam: float, s: float) -> None:
    def density(x: float) -> float:
        return float(np.exp(unknown_loglik(x, s**2, lam)))

    left, _ = integrate.quad(density, -60 * s, 0.0, points=[-s], epsabs=0, epsrel=1e-11)
    near, _ = integrate.quad(density, 0.0, 60 * s, points=[s, 10 * s], epsabs=0, epsrel=1e-11)
    far, _ = integrate.quad(density, 60 * s, np.inf, epsabs=0, epsrel=1e-11)
    assert left + near + far == pytest.approx(1.0, abs=1e-8)


def test_unknown_loglik_extreme_arguments_are_finite_and_accurate() -> None:
    lam, s = 0.2, 0.05
    # x = -50 s: Phi(z) in its far tail; compare with the asymptotic series.
    x = -50 * s
    z = (x - lam * s**2) / s
    asym = (
        np.log(lam)
        - lam * x
        + 0.5 * lam**2 * s**2
        - 0.5 * z**2
        - 0.5 * np.log(2 * np.pi)
        - np.log(-z)
        + np.log1p(-1 / z**2 + 3 / z**4 - 15 / z**6)
    )
    assert unknown_loglik(x, s**2, lam) == pytest.approx(asym, abs=1e-9)
    # x = 1e3 s: Phi -> 1, pure exponential tail.
    x = 1e3 * s
    assert unknown_loglik(x, s**2, lam) == pytest.approx(
        np.log(lam) - lam * x + 0.5 * lam**2 * s**2, abs=1e-12
    )
    # Tiny s: the density tends to the exponential itself (and lam / 2 at x = 0).
    tiny = 1e-150
    vals = unknown_loglik(np.array([-50 * tiny, 0.0, 1.0, 1e3 * tiny]), tiny**2, lam)
    assert np.all(np.isfinite(vals))
    assert vals[1] == pytest.approx(np.log(lam / 2), abs=1e-12)
    assert vals[2] == pytest.approx(np.log(lam) - lam, abs=1e-12)
    # Huge lam s (exponential much narrower than the Gaussian): continuous and finite.
    big = unknown_loglik(np.linspace(-5, 5, 11), 1.0, 1e6)
    assert np.all(np.isfinite(big))
    np.testing.assert_allclose(big, stats.norm.logpdf(np.linspace(-5, 5, 11)), atol=1e-4)
    # Continuity across the switch of evaluation branches at x = lam s^2.
    lam, s = 0.4, 1.0
    eps = 1e-9
    lo, hi = unknown_loglik(np.array([lam * s**2 - eps, lam * s**2 + eps]), s**2, lam)
    assert hi - lo == pytest.approx(0.0, abs=1e-8)


def test_unknown_loglik_rejects_bad_input() -> None:
    with pytest.raises(ValueError, match="lam"):
        unknown_loglik(0.0, 1.0, 0.0)
    with pytest.raises(ValueError, match="var"):
        unknown_loglik(0.0, -1.0, 0.4)
    with pytest.raises(ValueError, match="x"):
        unknown_loglik(np.nan, 1.0, 0.4)


def test_line_loglik_limits_and_mixture() -> None:
    rng = np.random.default_rng(5)
    mu = rng.normal(0.0, 0.1, 20)
    var = rng.uniform(0.02, 0.08, 20) ** 2
    lam = 0.15
    np.testing.assert_array_equal(line_loglik(mu, var, 0.0, lam), object_loglik(mu, var))
    np.testing.assert_allclose(
        line_loglik(mu, var, 1.0, lam), unknown_loglik(mu, var, lam), rtol=0, atol=1e-13
    )
    u = rng.uniform(0, 1, 20)
    direct = np.log(
        (1 - u) * stats.norm.pdf(mu, scale=np.sqrt(var)) + u * np.exp(unknown_loglik(mu, var, lam))
    )
    np.testing.assert_allclose(line_loglik(mu, var, u, lam), direct, rtol=1e-12)
    assert set_loglik(mu, var, u, lam) == pytest.approx(direct.sum(), rel=1e-12)
    with pytest.raises(ValueError, match="u"):
        line_loglik(mu, var, 1.5, lam)


# ---------------------------------------------------------------------------- detection


def test_gm_distance_reduces_to_mahalanobis_for_object_lines() -> None:
    rng = np.random.default_rng(6)
    mu = rng.normal(0.0, 0.1, 100)
    var = rng.uniform(0.01, 0.1, 100) ** 2
    np.testing.assert_array_equal(generalized_mahalanobis_sq(mu, var, 0.0, 0.2), mu**2 / var)


def test_gm_distance_zero_at_mode_positive_and_growing_for_unknown_lines() -> None:
    s, lam = 0.05, 0.2
    mode = optimize.minimize_scalar(
        lambda x: -line_loglik(x, s**2, 1.0, lam), bracket=(0.0, s), tol=1e-12
    ).x
    assert mode > 0.0
    assert generalized_mahalanobis_sq(mode, s**2, 1.0, lam) == pytest.approx(0.0, abs=1e-10)
    xs = np.linspace(mode - 6 * s, mode + 60 * s, 400)
    d2 = generalized_mahalanobis_sq(xs, s**2, 1.0, lam)
    # Equal to the definition with the numerically found mode.
    ref = 2 * (line_loglik(mode, s**2, 1.0, lam) - line_loglik(xs, s**2, 1.0, lam))
    np.testing.assert_allclose(d2, ref, rtol=1e-8, atol=1e-9)
    assert np.all(d2 >= 0.0)
    left, right = d2[xs < mode], d2[xs > mode]
    assert np.all(np.diff(left) < 0) and np.all(np.diff(right) > 0)
    # Far behind an unknown line the distance grows only linearly (exponential tail).
    assert d2[-1] < 2 * lam * (xs[-1] - mode) + 10


def test_gm_distance_mixture_and_bracket_doubling() -> None:
    rng = np.random.default_rng(7)
    mu = rng.normal(0.0, 0.2, 60)
    var = rng.uniform(0.01, 0.1, 60) ** 2
    u = rng.uniform(0.0, 1.0, 60)
    u[::4] = 0.0
    d2 = generalized_mahalanobis_sq(mu, var, u, 0.3)
    assert d2.shape == (60,) and np.all(np.isfinite(d2)) and np.all(d2 >= 0)
    # Same values for a 2-D batch with a broadcast u, and per beam.
    d2_2d = generalized_mahalanobis_sq(mu.reshape(6, 10), var.reshape(6, 10), u.reshape(6, 10), 0.3)
    np.testing.assert_array_equal(d2_2d, d2.reshape(6, 10))
    single = [generalized_mahalanobis_sq(mu[i], var[i], u[i], 0.3) for i in (0, 1, 17)]
    np.testing.assert_allclose(single, d2[[0, 1, 17]], rtol=1e-12)
    # Against a dense-grid maximum of the mixture density.
    for i in (1, 2, 3):
        s = np.sqrt(var[i])
        grid = np.linspace(0.0, 10 * s, 200_001)
        ref = 2 * (
            np.max(line_loglik(grid, var[i], u[i], 0.3)) - line_loglik(mu[i], var[i], u[i], 0.3)
        )
        assert d2[i] == pytest.approx(ref, rel=1e-6, abs=1e-9)
    # A very small lam s puts the mode of p_unk beyond 5 s: the bracket must grow.
    s, lam = 1.0, 1e-12
    mode = optimize.minimize_scalar(
        lambda x: -line_loglik(x, s**2, 1.0, lam),
        bounds=(0.0, 20.0),
        method="bounded",
        options={"xatol": 1e-10},
    ).x
    assert mode > 5 * s
    assert generalized_mahalanobis_sq(mode, s**2, 1.0, lam) == pytest.approx(0.0, abs=1e-9)
    d2_small_bracket = generalized_mahalanobis_sq(0.0, s**2, 1.0, lam, bracket_sigma=0.5)
    ref = 2 * (line_loglik(mode, s**2, 1.0, lam) - line_loglik(0.0, s**2, 1.0, lam))
    assert d2_small_bracket == pytest.approx(ref, rel=1e-9)
    with pytest.raises(ValueError, match="bracket_sigma"):
        generalized_mahalanobis_sq(0.0, 1.0, 1.0, 0.2, bracket_sigma=0.0)


def test_detection_statistics_and_acceptance() -> None:
    rng = np.random.default_rng(8)
    config = ModelConfig()
    good = rng.chisquare(1, 200)  # consistent beams: mean 1, variance 2
    mean, var = detection_statistics(good)
    assert mean == pytest.approx(np.mean(good)) and var == pytest.approx(np.var(good, ddof=0))
    assert detection_accepts(good, config)
    assert not detection_accepts(4.0 * good, config)  # mean ~4 > 3
    # Mean within bounds but variance too large: a few beams far off the model.
    spread = np.r_[np.zeros(90), np.full(10, 25.0)]  # mean 2.5, variance 56.25
    assert detection_statistics(spread) == pytest.approx((2.5, 56.25))
    assert not detection_accepts(spread, config)
    # Thresholds come from the config.
    assert detection_accepts(spread, ModelConfig(detection_var_max=60.0))
    assert not detection_accepts(np.r_[good, np.inf], config)
    with pytest.raises(ValueError, match="d2"):
        detection_statistics(np.array([1.0, -0.5]))
    with pytest.raises(ValueError, match="d2"):
        detection_statistics(np.array([]))


def test_detection_end_to_end_wall() -> None:
    """Beams really from a wall pass; the same beams against a shifted wall fail."""
    rng = np.random.default_rng(9)
    m = 40
    pose = np.array([0.0, 0.0, 0.0])
    bearings = np.linspace(0.6, -0.6, m)
    ranges = expected_range(bearings, [5.0, -4.0], [5.0, 4.0], pose)
    ranges = ranges + rng.normal(0.0, SENSOR.sigma_range, m)
    bearings_meas = bearings + rng.normal(0.0, SENSOR.sigma_bearing, m)
    Sigma_vv = np.broadcast_to(0.02**2 * np.eye(4), (m, 4, 4)).copy()
    lin = FirstOrderLinearization()
    config = ModelConfig()
    for x_wall, accept in ((5.0, True), (5.3, False)):
        mu_vv = np.tile([x_wall, -4.0, x_wall, 4.0], (m, 1))
        mu_err, var_err = range_error_distribution(
            ranges, bearings_meas, SENSOR.Q, pose, mu_vv, Sigma_vv, lin
        )
        d2 = generalized_mahalanobis_sq(mu_err, var_err, 0.0, 0.1)
        assert detection_accepts(d2, config) is accept


def test_gm_mode_search_in_groups_equals_one_group_at_a_time() -> None:
    # Batched searches (one group per model in detection) each stop on their own, so
    # every group gets exactly the result of a call with that group alone.
    rng = np.random.default_rng(11)
    sizes = [7, 1, 30, 12]
    groups = np.repeat(np.arange(len(sizes)), sizes)
    n = groups.size
    s = 10 ** rng.uniform(-2.5, -0.5, n)
    lam = np.full(n, 0.3)
    u = np.where(rng.random(n) < 0.6, 1.0, 10 ** rng.uniform(-3, 0, n))
    x = rng.normal(0.0, 3.0, n) * s
    together = generalized_mahalanobis_sq_unchecked(x, s**2, u, lam, 5.0, groups)
    for g in range(len(sizes)):
        sel = groups == g
        alone = generalized_mahalanobis_sq_unchecked(x[sel], s[sel] ** 2, u[sel], lam[sel], 5.0)
        np.testing.assert_array_equal(together[sel], alone)
    # and the grouped result is the ungrouped one up to the search tolerance
    np.testing.assert_allclose(
        together, generalized_mahalanobis_sq_unchecked(x, s**2, u, lam, 5.0), rtol=0, atol=1e-9
    )
