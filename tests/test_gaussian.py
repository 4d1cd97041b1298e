"""Tests of vslam_gym.slam.gaussian: SPD helpers, UT, first-order transform, canonical form."""

from __future__ import annotations

import pickle

import numpy as np
import pytest

from vslam_gym.slam.config import ModelConfig
from vslam_gym.slam.gaussian import (
    Canonical,
    FirstOrderLinearization,
    Linearization,
    NotPositiveDefiniteError,
    UnscentedLinearization,
    cho_factor_finite,
    cho_solve_finite,
    ensure_spd,
    first_order_transform,
    inflated_information,
    is_spd,
    make_linearization,
    sigma_points,
    symmetrize,
    unscented_transform,
    ut_weights,
)
from vslam_gym.slam.geometry import (
    cartesian_to_polar,
    fit_line,
    intersect_lines,
    polar_to_cartesian,
    polar_to_cartesian_jacobian,
)


def random_spd(rng: np.random.Generator, n: int, batch: tuple[int, ...] = ()) -> np.ndarray:
    A = rng.normal(size=(*batch, n, n))
    return A @ np.swapaxes(A, -1, -2) + 0.5 * np.eye(n)


def linear_map(A: np.ndarray, b: np.ndarray):
    return lambda X: X @ A.T + b


# Thesis sensor noise and a beam at 10 m, bearing 0.5 rad (SPEC section 0).
POLAR_MU = np.array([10.0, 0.5])
POLAR_SIGMA = np.diag([0.03**2, 0.0035**2])
POSE = np.array([1.0, -2.0, 0.3])


def polar_map(X: np.ndarray) -> np.ndarray:
    return polar_to_cartesian(X[..., 0], X[..., 1], POSE)


def polar_jacobian(mu: np.ndarray) -> np.ndarray:
    return polar_to_cartesian_jacobian(mu[..., 0], mu[..., 1], POSE)


# ---------------------------------------------------------------------------------------
# SPD helpers
# ---------------------------------------------------------------------------------------


def test_symmetrize_batched():
    rng = np.random.default_rng(0)
    S = rng.normal(size=(4, 3, 3))
    out = symmetrize(S)
    np.testing.assert_array_equal(out, np.swapaxes(out, -1, -2))
    np.testing.assert_allclose(out[2], 0.5 * (S[2] + S[2].T))


def test_is_spd_and_ensure_spd():
    rng = np.random.default_rng(1)
    good = random_spd(rng, 4, (3,))
    assert is_spd(good)
    bad = good.copy()
    bad[1] = np.diag([1.0, 1.0, -0.5, 2.0])
    assert not is_spd(bad)
    assert not is_spd(np.ones((2, 3)))
    assert not is_spd(np.array([[np.nan, 0.0], [0.0, 1.0]]))
    asym = good + np.triu(np.full((4, 4), 1e-9), 1)
    out = ensure_spd(asym, "test matrix")
    np.testing.assert_array_equal(out, np.swapaxes(out, -1, -2))
    with pytest.raises(NotPositiveDefiniteError, match=r"my cov .*-0\.5") as info:
        ensure_spd(bad, "my cov")
    assert info.value.min_eigenvalue == pytest.approx(-0.5)
    assert isinstance(info.value, ValueError)
    copy = pickle.loads(pickle.dumps(info.value))
    assert str(copy) == str(info.value)
    with pytest.raises(ValueError, match="shape"):
        ensure_spd(np.ones((2, 3)))


# ---------------------------------------------------------------------------------------
# Unscented transform
# ---------------------------------------------------------------------------------------


def test_ut_weights_thesis_values():
    n = 6
    w = ut_weights(n)
    assert w.lam == pytest.approx(1 - n)
    assert w.scale == pytest.approx(1.0)
    assert w.w_m0 == pytest.approx(1 - n)
    assert w.w_c0 == pytest.approx(1 - n + 1 - 1 / n + 2)
    assert w.w_i == pytest.approx(0.5)
    assert w.w_m0 + 2 * n * w.w_i == pytest.approx(1.0)
    with pytest.raises(ValueError, match="n \\+ lambda"):
        ut_weights(3, kappa=-3.0)


def test_sigma_points_on_one_sigma_contour():
    rng = np.random.default_rng(2)
    mu = rng.normal(size=3)
    Sigma = random_spd(rng, 3)
    X = sigma_points(mu, Sigma)
    assert X.shape == (7, 3)
    np.testing.assert_array_equal(X[0], mu)
    # Thesis default: every non-centre point has Mahalanobis distance exactly 1.
    D = X[1:] - mu
    d2 = np.einsum("ij,jk,ik->i", D, np.linalg.inv(Sigma), D)
    np.testing.assert_allclose(d2, 1.0, rtol=1e-12)


@pytest.mark.parametrize("batch", [(), (4,), (2, 3)])
def test_ut_exact_for_linear_maps(batch):
    rng = np.random.default_rng(3)
    n, p = 5, 3
    mu = rng.normal(size=(*batch, n))
    Sigma = random_spd(rng, n, batch)
    A = rng.normal(size=(p, n))
    b = rng.normal(size=p)
    mu_y, Sigma_y = unscented_transform(linear_map(A, b), mu, Sigma)
    assert mu_y.shape == (*batch, p)
    assert Sigma_y.shape == (*batch, p, p)
    np.testing.assert_allclose(mu_y, mu @ A.T + b, rtol=0, atol=1e-10)
    np.testing.assert_allclose(Sigma_y, A @ Sigma @ A.T, rtol=0, atol=1e-10)
    np.testing.assert_array_equal(Sigma_y, np.swapaxes(Sigma_y, -1, -2))


def test_ut_batch_broadcasts_shared_covariance_and_diagonal_fast_path():
    rng = np.random.default_rng(4)
    mu = rng.normal(size=(5, 2))
    A = rng.normal(size=(2, 2))
    mu_y, Sigma_y = unscented_transform(linear_map(A, np.zeros(2)), mu, POLAR_SIGMA)
    assert Sigma_y.shape == (5, 2, 2)
    np.testing.assert_allclose(
        Sigma_y, np.broadcast_to(A @ POLAR_SIGMA @ A.T, (5, 2, 2)), rtol=1e-12
    )
    # A zero variance is allowed (deterministic component) on the diagonal path.
    mu_y, Sigma_y = unscented_transform(lambda X: X, np.zeros(2), np.diag([0.0, 4.0]), check=False)
    np.testing.assert_allclose(Sigma_y, np.diag([0.0, 4.0]), atol=1e-15)


def test_ut_high_dimension_linear_stays_exact_and_pd():
    # The 2n-dimensional measurement vectors of the thesis: centre weight 1 - n = -199.
    rng = np.random.default_rng(5)
    n = 200
    ranges = rng.uniform(5.0, 25.0, size=n // 2)
    mu = np.empty(n)
    mu[0::2] = ranges
    mu[1::2] = np.linspace(1.5, -1.5, n // 2)
    Sigma = np.diag(np.tile([0.03**2, np.deg2rad(0.2) ** 2], n // 2))
    A = rng.normal(size=(4, n)) * 50.0
    b = np.array([1e3, -1e3, 5e2, 0.0])
    mu_y, Sigma_y = unscented_transform(linear_map(A, b), mu, Sigma)
    expected = A @ Sigma @ A.T
    np.testing.assert_allclose(mu_y, A @ mu + b, rtol=1e-12)
    np.testing.assert_allclose(Sigma_y, expected, rtol=1e-10)
    assert is_spd(Sigma_y)


def test_ut_square_has_exact_moments_and_beta_matters():
    # x ~ N(0, 1), y = x^2: E[y] = 1, Var[y] = 2; with beta = 2 the UT is exact.
    mu_y, Sigma_y = unscented_transform(lambda X: X**2, np.zeros(1), np.eye(1))
    assert mu_y[0] == pytest.approx(1.0, abs=1e-14)
    assert Sigma_y[0, 0] == pytest.approx(2.0, abs=1e-14)
    # beta = -1 makes the output variance -1: indefinite, detected.
    with pytest.raises(NotPositiveDefiniteError, match="unscented_transform output"):
        unscented_transform(lambda X: X**2, np.zeros(1), np.eye(1), beta=-1.0)
    _, Sigma_unchecked = unscented_transform(
        lambda X: X**2, np.zeros(1), np.eye(1), beta=-1.0, check=False
    )
    assert Sigma_unchecked[0, 0] == pytest.approx(-1.0)


def test_ut_rejects_indefinite_input_and_rank_deficient_output():
    with pytest.raises(NotPositiveDefiniteError, match="input covariance"):
        unscented_transform(lambda X: X, np.zeros(2), np.array([[1.0, 2.0], [2.0, 1.0]]))
    # Two identical outputs: the output covariance is singular.
    with pytest.raises(NotPositiveDefiniteError, match="output covariance"):
        unscented_transform(lambda X: np.concatenate([X, X], axis=-1), np.zeros(1), np.eye(1))
    with pytest.raises(ValueError, match="same leading shape"):
        unscented_transform(lambda X: X[..., :1, :], np.zeros(2), np.eye(2))


def test_ut_singular_psd_input_uses_eigen_square_root():
    # Perfectly correlated pair: PSD, rank 1, Cholesky fails.
    Sigma = np.array([[1.0, 1.0], [1.0, 1.0]])
    A = np.array([[1.0, -1.0], [1.0, 2.0]])
    mu_y, Sigma_y = unscented_transform(linear_map(A, np.zeros(2)), np.ones(2), Sigma, check=False)
    np.testing.assert_allclose(Sigma_y, A @ Sigma @ A.T, atol=1e-12)
    np.testing.assert_allclose(mu_y, A @ np.ones(2), atol=1e-12)


def test_ut_polar_to_cartesian_matches_monte_carlo():
    rng = np.random.default_rng(6)
    n_samples = 200_000
    samples = rng.multivariate_normal(POLAR_MU, POLAR_SIGMA, size=n_samples)
    points = polar_map(samples)
    mc_mean = points.mean(axis=0)
    mc_cov = np.cov(points.T)
    mu_y, Sigma_y = unscented_transform(polar_map, POLAR_MU, POLAR_SIGMA)
    mean_se = np.sqrt(np.diag(Sigma_y) / n_samples)
    assert np.all(np.abs(mu_y - mc_mean) < 4 * mean_se)
    variances = np.diag(Sigma_y)
    cov_se = np.sqrt((np.outer(variances, variances) + Sigma_y**2) / n_samples)
    assert np.all(np.abs(Sigma_y - mc_cov) < 4 * cov_se)


def test_first_order_agrees_with_ut_on_polar_map():
    mu_ut, Sigma_ut = unscented_transform(polar_map, POLAR_MU, POLAR_SIGMA)
    mu_fo, Sigma_fo = first_order_transform(polar_map, POLAR_MU, POLAR_SIGMA)
    # Mildly nonlinear: the difference is the second-order term r sigma_phi^2 / 2 ~ 6e-5 m.
    np.testing.assert_allclose(mu_fo, polar_map(POLAR_MU[None])[0], atol=1e-12)
    assert np.max(np.abs(mu_fo - mu_ut)) < 1e-4
    np.testing.assert_allclose(Sigma_fo, Sigma_ut, rtol=0, atol=2e-5 * np.max(Sigma_ut))
    # Exact linear map through the analytic Jacobian: J Q J^T.
    J = polar_jacobian(POLAR_MU[None])[0]
    np.testing.assert_allclose(Sigma_fo, J @ POLAR_SIGMA @ J.T, rtol=1e-7)


def test_first_order_analytic_jacobian_equals_numerical_batched():
    rng = np.random.default_rng(7)
    mu = np.column_stack([rng.uniform(1.0, 20.0, 6), rng.uniform(-1.5, 1.5, 6)])
    Sigma = np.broadcast_to(POLAR_SIGMA, (6, 2, 2))
    mu_n, Sigma_n = first_order_transform(polar_map, mu, Sigma)
    mu_a, Sigma_a = first_order_transform(polar_map, mu, Sigma, jacobian=polar_jacobian)
    np.testing.assert_allclose(mu_a, mu_n, rtol=0, atol=1e-12)
    np.testing.assert_allclose(Sigma_a, Sigma_n, rtol=1e-7)
    np.testing.assert_array_equal(Sigma_a, np.swapaxes(Sigma_a, -1, -2))
    with pytest.raises(ValueError, match="jacobian"):
        first_order_transform(polar_map, mu, Sigma, jacobian=lambda m: np.zeros((3, 3)))
    with pytest.raises(NotPositiveDefiniteError):
        first_order_transform(polar_map, POLAR_MU, np.array([[1.0, 2.0], [2.0, 1.0]]))


def test_linearization_protocol_and_factory():
    ut = make_linearization(ModelConfig(linearization="ut", ut_beta=3.0))
    fo = make_linearization(ModelConfig(linearization="jacobian"))
    assert isinstance(ut, UnscentedLinearization) and ut.beta == 3.0
    assert isinstance(fo, FirstOrderLinearization)
    assert isinstance(ut, Linearization) and isinstance(fo, Linearization)
    results = [lin.propagate(polar_map, POLAR_MU, POLAR_SIGMA) for lin in (ut, fo)]
    np.testing.assert_allclose(results[0][0], results[1][0], atol=1e-4)
    np.testing.assert_allclose(results[0][1], results[1][1], atol=1e-4 * np.max(results[0][1]))


# ---------------------------------------------------------------------------------------
# Canonical form
# ---------------------------------------------------------------------------------------


@pytest.fixture
def gaussian5():
    rng = np.random.default_rng(8)
    return rng.normal(size=5), random_spd(rng, 5)


def test_canonical_round_trip(gaussian5):
    mu, Sigma = gaussian5
    c = Canonical.from_moments(mu, Sigma)
    assert c.dim == 5
    np.testing.assert_allclose(c.K @ Sigma, np.eye(5), atol=1e-10)
    mu2, Sigma2 = c.to_moments()
    np.testing.assert_allclose(mu2, mu, atol=1e-10)
    np.testing.assert_allclose(Sigma2, Sigma, atol=1e-10)
    with pytest.raises(ValueError):
        c.K[0, 0] = 1.0  # read-only


def test_canonical_singular_to_moments_raises(gaussian5):
    mu, Sigma = gaussian5
    extended = Canonical.from_moments(mu, Sigma).extend(2)
    with pytest.raises(NotPositiveDefiniteError, match="information matrix"):
        extended.to_moments()


def test_canonical_marginalize_equals_moment_subblock(gaussian5):
    mu, Sigma = gaussian5
    c = Canonical.from_moments(mu, Sigma)
    keep = [3, 0, 4]
    m_mu, m_Sigma = c.marginalize(keep).to_moments()
    np.testing.assert_allclose(m_mu, mu[keep], atol=1e-10)
    np.testing.assert_allclose(m_Sigma, Sigma[np.ix_(keep, keep)], atol=1e-10)
    # Keeping all is a permutation; keeping nothing is empty.
    perm = [4, 3, 2, 1, 0]
    p_mu, p_Sigma = c.marginalize(perm).to_moments()
    np.testing.assert_allclose(p_Sigma, Sigma[np.ix_(perm, perm)], atol=1e-10)
    np.testing.assert_allclose(p_mu, mu[perm], atol=1e-10)
    assert c.marginalize([]).dim == 0
    with pytest.raises(ValueError, match="repeated"):
        c.marginalize([1, 1])


def test_canonical_index_validation(gaussian5):
    mu, Sigma = gaussian5
    c = Canonical.from_moments(mu, Sigma)
    # negative indices wrap, in marginalize and condition alike
    np.testing.assert_array_equal(c.marginalize([-1, 0]).K, c.marginalize([4, 0]).K)
    np.testing.assert_array_equal(c.condition([-2], [0.5]).h, c.condition([3], [0.5]).h)
    for bad, match in (([1, -4], "repeated"), ([5], "out of range"), ([-6], "out of range")):
        with pytest.raises(ValueError, match=match):
            c.marginalize(bad)
        with pytest.raises(ValueError, match=match):
            c.condition(bad, np.zeros(len(bad)))
    with pytest.raises(ValueError, match="integers"):
        c.marginalize([0.5])
    with pytest.raises(ValueError, match="Canonical.K contains non-finite"):
        Canonical(np.full((2, 2), np.nan), np.zeros(2))
    with pytest.raises(ValueError, match="Canonical.h contains non-finite"):
        Canonical(np.eye(2), np.array([0.0, np.inf]))


def test_canonical_marginalize_uninformative_variables(gaussian5):
    mu, Sigma = gaussian5
    c = Canonical.from_moments(mu, Sigma).extend(2)
    m = c.marginalize(range(5))
    m_mu, m_Sigma = m.to_moments()
    np.testing.assert_allclose(m_Sigma, Sigma, atol=1e-10)
    np.testing.assert_allclose(m_mu, mu, atol=1e-10)
    # Information only on x5 + x6 with a link to x0 and no way to integrate out: improper.
    K = np.zeros((3, 3))
    K[0, 0] = 2.0
    K[0, 1] = K[1, 0] = 1.0
    with pytest.raises(NotPositiveDefiniteError, match="improper"):
        Canonical(K, np.zeros(3)).marginalize([0])


def test_canonical_condition_equals_gaussian_conditional(gaussian5):
    mu, Sigma = gaussian5
    c = Canonical.from_moments(mu, Sigma)
    idx = [1, 3]
    values = np.array([0.7, -1.2])
    rest = [0, 2, 4]
    S_ri = Sigma[np.ix_(rest, idx)]
    S_ii = Sigma[np.ix_(idx, idx)]
    expected_mu = mu[rest] + S_ri @ np.linalg.solve(S_ii, values - mu[idx])
    expected_Sigma = Sigma[np.ix_(rest, rest)] - S_ri @ np.linalg.solve(S_ii, S_ri.T)
    got_mu, got_Sigma = c.condition(idx, values).to_moments()
    np.testing.assert_allclose(got_mu, expected_mu, atol=1e-10)
    np.testing.assert_allclose(got_Sigma, expected_Sigma, atol=1e-10)


def test_canonical_transform_and_extend(gaussian5):
    mu, Sigma = gaussian5
    c = Canonical.from_moments(mu[:3], Sigma[:3, :3])
    # New state [w0, w1, w2, w3]: old x0 = w2, x1 = w0, x2 = w3; w1 is new.
    F = np.zeros((3, 4))
    F[0, 2] = F[1, 0] = F[2, 3] = 1.0
    t = c.transform(F)
    assert t.dim == 4
    np.testing.assert_array_equal(t.K[1], 0.0)
    assert t.h[1] == 0.0
    # Adding information on w1 alone makes it proper: x independent of w1.
    extra = Canonical.zeros(4)
    K = np.zeros((4, 4))
    K[1, 1] = 0.25
    got_mu, got_Sigma = (t + Canonical(K, np.zeros(4)) + extra).to_moments()
    order = [1, None, 0, 2]
    for new, old in enumerate(order):
        if old is None:
            assert got_Sigma[new, new] == pytest.approx(4.0)
            continue
        assert got_mu[new] == pytest.approx(mu[old])
    np.testing.assert_allclose(got_Sigma[np.ix_([2, 0, 3], [2, 0, 3])], Sigma[:3, :3], atol=1e-10)
    # Offset: x_old = w + b shifts the mean by -b.
    b = np.array([0.5, -1.0, 2.0])
    shifted_mu, _ = c.transform(np.eye(3), offset=b).to_moments()
    np.testing.assert_allclose(shifted_mu, mu[:3] - b, atol=1e-10)
    e = c.extend(2)
    assert e.dim == 5
    np.testing.assert_array_equal(e.K[:3, :3], c.K)
    np.testing.assert_array_equal(e.K[3:], 0.0)
    with pytest.raises(ValueError, match="F must have shape"):
        c.transform(np.eye(4))


def test_canonical_add_is_product_of_gaussians():
    rng = np.random.default_rng(9)
    mu1, mu2 = rng.normal(size=3), rng.normal(size=3)
    S1, S2 = random_spd(rng, 3), random_spd(rng, 3)
    got_mu, got_Sigma = (
        Canonical.from_moments(mu1, S1) + Canonical.from_moments(mu2, S2)
    ).to_moments()
    # Moment form of the product: Sigma = S1 (S1 + S2)^-1 S2, mu = S2 (S1+S2)^-1 mu1 + ...
    total = S1 + S2
    expected_Sigma = S1 @ np.linalg.solve(total, S2)
    expected_mu = S2 @ np.linalg.solve(total, mu1) + S1 @ np.linalg.solve(total, mu2)
    np.testing.assert_allclose(got_Sigma, expected_Sigma, atol=1e-10)
    np.testing.assert_allclose(got_mu, expected_mu, atol=1e-10)
    with pytest.raises(ValueError, match="dimensions differ"):
        Canonical.zeros(2) + Canonical.zeros(3)


def test_ut_and_first_order_agree_on_thesis_vertex():
    # A corner seen by 21 beams of the thesis lidar: the vertex of the two fitted lines as a
    # function of the 42-dimensional polar measurement vector (UT centre weight 1 - 42).
    pose = np.array([0.0, 0.0, 0.0])
    corner = np.array([6.0, 1.0])
    t = np.linspace(0.0, 2.0, 11)[:, None]
    left = corner + t[::-1] * np.array([-0.6, 0.8])
    right = corner + t[1:] * np.array([0.8, 0.6])
    r, phi = cartesian_to_polar(np.vstack([left, right]), pose)
    n_beams = r.size
    mu = np.column_stack([r, phi]).reshape(-1)
    Sigma = np.diag(np.tile([0.03**2, np.deg2rad(0.2) ** 2], n_beams))

    def vertex(X: np.ndarray) -> np.ndarray:
        pts = polar_to_cartesian(X[..., 0::2], X[..., 1::2], pose)
        pa, sa = fit_line(pts[..., :11, :])
        pb, sb = fit_line(pts[..., 10:, :])
        return intersect_lines(pa, sa, pb, sb, 0.05)[0]

    mu_ut, Sigma_ut = unscented_transform(vertex, mu, Sigma)
    mu_fo, Sigma_fo = first_order_transform(vertex, mu, Sigma)
    np.testing.assert_allclose(mu_fo, corner, atol=1e-9)
    assert np.max(np.abs(mu_ut - corner)) < 0.1 * np.sqrt(np.max(np.diag(Sigma_ut)))
    np.testing.assert_allclose(Sigma_ut, Sigma_fo, rtol=0, atol=0.005 * np.max(Sigma_ut))
    assert is_spd(Sigma_ut)


def test_inflated_information_adds_covariance_and_keeps_null_directions():
    rng = np.random.default_rng(3)
    a = rng.normal(size=(4, 4))
    k = a @ a.T + 0.1 * np.eye(4)
    sigma = 0.05
    inflated = inflated_information(k, sigma)
    np.testing.assert_allclose(np.linalg.inv(inflated), np.linalg.inv(k) + sigma**2 * np.eye(4))
    np.testing.assert_array_equal(inflated, inflated.T)
    np.testing.assert_array_equal(inflated_information(k, 0.0), k)
    # singular: two observed coordinates of four, with 1 mm precision
    singular = np.zeros((4, 4))
    singular[:2, :2] = np.diag([1e6, 4e6])
    capped = inflated_information(singular, sigma)
    np.testing.assert_array_equal(capped[2:], 0.0)
    np.testing.assert_allclose(np.diag(capped)[:2], 1.0 / (np.array([1e-6, 0.25e-6]) + sigma**2))
    assert np.linalg.eigvalsh(capped).max() < 1.0 / sigma**2


def test_inflated_information_with_an_extra_covariance():
    rng = np.random.default_rng(4)
    a = rng.normal(size=(4, 4))
    k = a @ a.T + 0.1 * np.eye(4)
    c = rng.normal(size=4)
    extra = 0.01 * np.outer(c, c)  # a rank-one term, like a rotation of all vertices
    inflated = inflated_information(k, 0.05, extra)
    expected = np.linalg.inv(np.linalg.inv(k) + 0.05**2 * np.eye(4) + extra)
    np.testing.assert_allclose(inflated, expected, rtol=1e-10)
    np.testing.assert_allclose(
        inflated_information(k, 0.0, extra), np.linalg.inv(np.linalg.inv(k) + extra), rtol=1e-10
    )


@pytest.mark.parametrize("columns", [None, 1, 4])
def test_cho_solve_finite_matches_scipy_bitwise(columns):
    import scipy.linalg

    rng = np.random.default_rng(7)
    a = rng.normal(size=(5, 5))
    lower = np.linalg.cholesky(a @ a.T + np.eye(5))
    b = rng.normal(size=5 if columns is None else (5, columns))
    np.testing.assert_array_equal(
        cho_solve_finite(lower, b), scipy.linalg.cho_solve((lower, True), b)
    )
    assert cho_solve_finite(lower, np.zeros((5, 0))).shape == (5, 0)


@pytest.mark.parametrize("columns", [None, 3])
def test_cho_factor_finite_matches_scipy_bitwise(columns):
    import scipy.linalg

    rng = np.random.default_rng(11)
    a = rng.normal(size=(6, 6))
    s = a @ a.T + np.eye(6)
    upper, lower = scipy.linalg.cho_factor(s)
    assert not lower
    np.testing.assert_array_equal(cho_factor_finite(s), upper)
    b = rng.normal(size=6 if columns is None else (6, columns))
    np.testing.assert_array_equal(
        cho_solve_finite(upper, b, lower=False), scipy.linalg.cho_solve((upper, False), b)
    )
    with pytest.raises(np.linalg.LinAlgError, match="not positive definite"):
        cho_factor_finite(-s)
