"""The state-space update against a brute-force dense Gaussian computation."""

from __future__ import annotations

import numpy as np
import pytest

from vslam_gym.slam.gaussian import Canonical
from vslam_gym.slam.state_update import _woodbury, state_space_update


def random_spd(rng, n, scale=1.0):
    a = rng.normal(size=(n, n))
    return scale * (a @ a.T + n * np.eye(n))


def factor(a, b, k):
    ka = k @ a
    return np.block([[a.T @ ka, -ka.T], [-ka, k]]), np.concatenate([-ka.T @ b, k @ b])


def dense_reference(mu, sigma, ref, a2, b2, k2, a3, b3, k3):
    """Joint over [x, m..., r, v] in canonical form, inverted densely."""
    d = a2.shape[1]
    n = mu.size + (d if ref is None else 0)
    nv = b2.size
    dim = n + nv
    kk, hh = np.zeros((dim, dim)), np.zeros(dim)
    prior = Canonical.from_moments(mu, sigma)
    kk[: mu.size, : mu.size] += prior.K
    hh[: mu.size] += prior.h
    r = np.arange(n - d, n) if ref is None else np.arange(ref, ref + d)
    v = np.arange(n, dim)
    for idx, (kf, hf) in (
        (np.r_[r, v], factor(a2, b2, k2)),
        (np.r_[np.arange(3), v], factor(a3, b3, k3)),
    ):
        kk[np.ix_(idx, idx)] += kf
        hh[idx] += hf
    cov = np.linalg.inv(kk)
    mean = cov @ hh
    s_rr = cov[np.ix_(r, r)]
    a8 = cov[np.ix_(v, r)] @ np.linalg.inv(s_rr)
    cond_cov = cov[np.ix_(v, v)] - a8 @ cov[np.ix_(r, v)]
    return mean[:n], cov[:n, :n], a8, mean[v] - a8 @ mean[r], np.linalg.inv(cond_cov)


def make_case(rng, k=3, new=False, d=2):
    """A random update; ``d = 3``: landmark-frame references (a heading column in A2)."""
    n_state = 3 + d * 3 + (0 if new else d)  # pose, three other references, [r]
    mu = rng.normal(size=n_state) * 3
    sigma = random_spd(rng, n_state, 0.01)
    nv = 2 * k
    a2 = np.tile(np.eye(2, d), (k, 1))
    if d == 3:
        a2[:, 2] = rng.normal(size=nv)
    b2 = rng.normal(size=nv)
    k2 = np.linalg.inv(random_spd(rng, nv, 0.001))
    a3 = np.tile(np.eye(2, 3), (k, 1))
    a3[0::2, 2] = rng.normal(size=k)
    a3[1::2, 2] = rng.normal(size=k)
    b3 = rng.normal(size=nv)
    k3 = np.linalg.inv(random_spd(rng, nv, 0.001))
    if not new:
        # an unobserved vertex: no information in the observation (singular K3)
        k3[:2, :] = 0.0
        k3[:, :2] = 0.0
    return mu, sigma, a2, b2, k2, a3, b3, k3


@pytest.mark.parametrize("seed, d", [(0, 2), (1, 2), (2, 2), (6, 3), (7, 3)])
def test_existing_landmark_matches_dense(seed, d):
    rng = np.random.default_rng(seed)
    mu, sigma, a2, b2, k2, a3, b3, k3 = make_case(rng, d=d)
    ref = mu.size - d
    got = state_space_update(mu, sigma, ref, a2, b2, k2, a3, b3, k3)
    want = dense_reference(mu, sigma, ref, a2, b2, k2, a3, b3, k3)
    np.testing.assert_allclose(got[0], want[0], rtol=1e-8, atol=1e-9)
    np.testing.assert_allclose(got[1], want[1], rtol=1e-7, atol=1e-12)
    np.testing.assert_allclose(got[2].A, want[2], rtol=1e-7, atol=1e-9)
    np.testing.assert_allclose(got[2].b, want[3], rtol=1e-7, atol=1e-8)
    np.testing.assert_allclose(got[2].K, want[4], rtol=1e-6)
    assert np.linalg.eigvalsh(got[1]).min() > 0
    # the observation adds information: no variance grows
    assert np.all(np.diag(got[1]) <= np.diag(sigma) + 1e-15)


@pytest.mark.parametrize("seed, d", [(3, 2), (4, 2), (8, 3)])
def test_new_landmark_matches_dense(seed, d):
    rng = np.random.default_rng(seed)
    mu, sigma, a2, b2, k2, a3, b3, k3 = make_case(rng, new=True, d=d)
    got = state_space_update(mu, sigma, None, a2, b2, k2, a3, b3, k3)
    want = dense_reference(mu, sigma, None, a2, b2, k2, a3, b3, k3)
    assert got[0].size == mu.size + d
    np.testing.assert_allclose(got[0], want[0], rtol=1e-8, atol=1e-9)
    np.testing.assert_allclose(got[1], want[1], rtol=1e-7, atol=1e-12)
    np.testing.assert_allclose(got[2].A, want[2], rtol=1e-7, atol=1e-9)
    np.testing.assert_allclose(got[2].K, want[4], rtol=1e-6)


def test_empty_other_references():
    """No other landmark (empty m) works too."""
    rng = np.random.default_rng(5)
    mu = rng.normal(size=5)
    sigma = random_spd(rng, 5, 0.01)
    _, _, a2, b2, k2, a3, b3, k3 = make_case(rng)
    got = state_space_update(mu, sigma, 3, a2, b2, k2, a3, b3, k3)
    want = dense_reference(mu, sigma, 3, a2, b2, k2, a3, b3, k3)
    np.testing.assert_allclose(got[1], want[1], rtol=1e-7, atol=1e-12)


def test_local_block_decides_positive_definiteness_of_the_update():
    # The update checks only the pose-and-reference block of the new covariance: for a
    # positive definite prior, Sigma - Sigma_:s M Sigma_s: is positive definite exactly
    # when its (s, s) block is. Random factors, many of them indefinite:
    rng = np.random.default_rng(5)
    agree, indefinite = 0, 0
    for _ in range(200):
        n = int(rng.integers(5, 12))
        sigma = random_spd(rng, n, 0.1)
        idx = np.sort(rng.choice(n, 5, replace=False))
        g = rng.normal(size=(5, 5))
        lam = g @ np.diag(rng.normal(0.0, 2.0, 5)) @ g.T  # symmetric, often indefinite
        mu_new, sigma_new = _woodbury(np.zeros(n), sigma, idx, lam, np.zeros(5))
        whole = np.linalg.eigvalsh(sigma_new).min() > 0
        local = np.linalg.eigvalsh(sigma_new[np.ix_(idx, idx)]).min() > 0
        agree += whole == local
        indefinite += not whole
    assert agree == 200
    assert indefinite > 20  # the check was exercised on both sides
