"""The error covariance of the filter's estimates (``FilterConfig.error_noise_scale``)."""

from __future__ import annotations

import numpy as np
import pytest
from test_state_update import make_case, random_spd

from vslam_gym.evaluation import episode_metrics, run_episode
from vslam_gym.slam import error_covariance as ec
from vslam_gym.slam.config import FilterConfig
from vslam_gym.slam.state_update import (
    pose_measurement_update,
    reference_given_pose,
    state_space_update,
)

FILTER_OWN = {"filter": {"error_noise_scale": 0}}
"""The belief reports the filter's own covariance (the ``thesis`` preset's way)."""


@pytest.mark.parametrize("seed, d", [(0, 2), (1, 2), (6, 3)])
def test_factor_update_at_scale_one_is_the_filters_landmark_update(seed, d):
    rng = np.random.default_rng(seed)
    mu, sigma, a2, b2, k2, a3, b3, k3 = make_case(rng, d=d)
    ref = mu.size - d
    _, want, _, lam = state_space_update(mu, sigma, ref, a2, b2, k2, a3, b3, k3, with_factor=True)
    idx = np.r_[0:3, ref : ref + d]
    got = ec.factor_update(sigma, sigma, idx, lam, 1.0)
    np.testing.assert_allclose(got, want, rtol=1e-7, atol=1e-12)


@pytest.mark.parametrize("seed, d", [(3, 2), (8, 3)])
def test_add_landmark_at_scale_one_is_the_filters_creation(seed, d):
    rng = np.random.default_rng(seed)
    mu, sigma, a2, b2, k2, a3, b3, k3 = make_case(rng, new=True, d=d)
    _, want, _, lam = state_space_update(mu, sigma, None, a2, b2, k2, a3, b3, k3, with_factor=True)
    got = ec.add_landmark(sigma, sigma, lam, 1.0)
    assert got.shape == want.shape == (mu.size + d,) * 2
    np.testing.assert_allclose(got, want, rtol=1e-7, atol=1e-12)


def test_pose_and_direct_updates_at_scale_one_are_the_kalman_updates():
    rng = np.random.default_rng(4)
    n = 9
    mu, sigma = rng.normal(size=n), random_spd(rng, n, 0.01)
    noise = random_spd(rng, 3, 0.001)
    _, want = pose_measurement_update(mu, sigma, mu[:3] + 0.01, noise)
    np.testing.assert_allclose(ec.pose_update(sigma, sigma, noise), want, rtol=1e-8, atol=1e-14)
    h = rng.normal(size=(2, n))
    r = random_spd(rng, 2, 0.001)
    gain = sigma @ h.T @ np.linalg.inv(h @ sigma @ h.T + r)
    want = sigma - gain @ h @ sigma
    np.testing.assert_allclose(ec.direct_update(sigma, sigma, h, r), want, rtol=1e-8, atol=1e-14)


def test_factor_update_is_the_joseph_form_with_the_noise_scaled():
    """One variable: gain ``k = s / (s + r)``, ``P' = (1 - k)^2 P + c k^2 r``."""
    s, r, p, c = 0.04, 0.01, 0.09, 7.0
    got = ec.factor_update(np.array([[p]]), np.array([[s]]), np.arange(1), np.array([[1 / r]]), c)
    k = s / (s + r)
    assert got[0, 0] == pytest.approx((1 - k) ** 2 * p + c * k**2 * r, rel=1e-12)


def test_error_noise_scale_keeps_the_estimates_and_widens_the_reported_covariance():
    """The option changes what the belief reports, never the estimates; with a scale
    above 1 the reported covariance is never smaller than the filter's (Loewner order),
    and it stays symmetric positive definite."""
    plain = run_episode("small", 0, max_steps=120, overrides=FILTER_OWN)
    wide = run_episode("small", 0, max_steps=120)  # the default: error_noise_scale 10
    np.testing.assert_array_equal(wide.slam_poses, plain.slam_poses)
    np.testing.assert_array_equal(wide.landmark_counts, plain.landmark_counts)
    assert plain.landmark_counts.max() > 0
    for cov, base in zip(wide.slam_covs, plain.slam_covs, strict=True):
        np.testing.assert_allclose(cov, cov.T, atol=1e-15)
        assert np.linalg.eigvalsh(cov)[0] > 0
        assert np.linalg.eigvalsh(cov - base)[0] > -1e-12 * np.abs(base).max()
    final_ratio = np.trace(wide.slam_covs[-1][:2, :2]) / np.trace(plain.slam_covs[-1][:2, :2])
    assert final_ratio > 2.0, final_ratio


def test_error_noise_scale_at_one_reports_the_filters_covariance():
    plain = run_episode("small", 1, max_steps=80, overrides=FILTER_OWN)
    joseph = {"error_noise_scale": 1, "error_creation_pose_update": True}
    same = run_episode("small", 1, max_steps=80, overrides={"filter": joseph})
    np.testing.assert_array_equal(same.slam_poses, plain.slam_poses)
    np.testing.assert_allclose(same.slam_covs, plain.slam_covs, rtol=1e-9, atol=1e-15)


@pytest.mark.parametrize("value", [-1.0, float("nan"), float("inf")])
def test_error_noise_scale_is_validated(value):
    with pytest.raises(ValueError, match="error_noise_scale"):
        FilterConfig(error_noise_scale=value)


def test_error_noise_scale_defaults():
    assert FilterConfig().error_noise_scale == 10.0
    assert FilterConfig().error_creation_pose_update is False
    assert FilterConfig.thesis().error_noise_scale == 0.0


def test_the_belief_and_the_metrics_keep_the_filters_own_covariance_too():
    own = run_episode("small", 2, max_steps=60, overrides=FILTER_OWN)
    default = run_episode("small", 2, max_steps=60)
    np.testing.assert_array_equal(default.filter_covs, own.slam_covs)
    np.testing.assert_array_equal(own.filter_covs, own.slam_covs)
    assert default.final_belief.filter_pose_cov.shape == (3, 3)
    m_own, m_default = episode_metrics(own), episode_metrics(default)
    assert m_default["filter_nees_mean"] == m_own["nees_mean"] == m_own["filter_nees_mean"]
    assert m_default["nees_mean"] < m_default["filter_nees_mean"]


def test_add_landmark_without_the_pose_update_keeps_the_pose_block():
    rng = np.random.default_rng(7)
    mu, sigma, a2, b2, k2, a3, b3, k3 = make_case(rng, new=True, d=2)
    _, _, _, lam = state_space_update(mu, sigma, None, a2, b2, k2, a3, b3, k3, with_factor=True)
    p = random_spd(rng, mu.size, 0.02)
    got = ec.add_landmark(p, sigma, lam, 4.0, pose_update=False)
    n = mu.size
    assert got.shape == (n + 2, n + 2)
    np.testing.assert_array_equal(got[:n, :n], p)
    _, c_mat, e_cov, _ = reference_given_pose(lam)
    np.testing.assert_allclose(got[n:, :n], c_mat @ p[:3], rtol=1e-12)
    np.testing.assert_allclose(got[n:, n:], c_mat @ p[:3, :3] @ c_mat.T + 4.0 * e_cov, rtol=1e-10)
    with_update = ec.add_landmark(p, sigma, lam, 4.0)
    assert np.trace(with_update[:3, :3]) < np.trace(p[:3, :3])


def test_a_landmark_creation_leaves_the_pose_mean_where_it_was(monkeypatch):
    """Why ``error_creation_pose_update`` may be off: the thesis's creation uses its scan
    twice, so its pose factor shrinks the filter's covariance without moving the mean."""
    from vslam_gym.slam.filter import VertexSLAM

    shifts, shrinks = [], []
    create = VertexSLAM._create_landmark

    def recorded(self, *args, **kwargs):
        mu, sd = self._mu[:3].copy(), np.sqrt(self._sigma[2, 2])
        out = create(self, *args, **kwargs)
        if out is not None:
            shifts.append(np.abs(self._mu[:3] - mu).max())
            shrinks.append(np.sqrt(self._sigma[2, 2]) / sd)
        return out

    monkeypatch.setattr(VertexSLAM, "_create_landmark", recorded)
    run_episode("small", 0, max_steps=120)
    assert len(shifts) >= 5
    assert max(shifts) < 1e-12, max(shifts)
    assert np.median(shrinks) < 0.99, np.median(shrinks)  # the heading sd shrinks anyway


def test_error_creation_pose_update_keeps_the_estimates():
    plain = run_episode("small", 0, max_steps=120)  # the default: no pose update
    on = {"filter": {"error_creation_pose_update": True}}
    kept = run_episode("small", 0, max_steps=120, overrides=on)
    np.testing.assert_array_equal(kept.slam_poses, plain.slam_poses)
    np.testing.assert_array_equal(kept.filter_covs, plain.filter_covs)
    assert not np.allclose(kept.slam_covs, plain.slam_covs)
    for cov in kept.slam_covs:
        np.testing.assert_allclose(cov, cov.T, atol=1e-15)
        assert np.linalg.eigvalsh(cov)[0] > 0
    # without the creations' spurious information the pose is reported less sure on the
    # whole (not at every step: the later Joseph updates use the filter's gains)
    wide, narrow = np.asarray(plain.slam_covs), np.asarray(kept.slam_covs)
    assert wide[:, 2, 2].mean() > 1.2 * narrow[:, 2, 2].mean()
    assert (
        np.trace(wide[:, :2, :2], axis1=1, axis2=2).mean()
        > 1.2 * np.trace(narrow[:, :2, :2], axis1=1, axis2=2).mean()
    )


def test_error_creation_pose_update_is_a_bool():
    with pytest.raises(ValueError, match="error_creation_pose_update"):
        FilterConfig(error_creation_pose_update=1)
