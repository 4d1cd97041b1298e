"""``FilterConfig.prealign``: the whole-scan match inside :class:`VertexSLAM`."""

from __future__ import annotations

import numpy as np
import pytest
from _raycast import cast
from test_filter import EDGES, PHI, SENSOR, circle_route, run

from vslam_gym.slam.config import FilterConfig
from vslam_gym.slam.filter import SlamConfig, VertexSLAM
from vslam_gym.slam.motion import increment_to_relative, motion_update, relative_motion_update
from vslam_gym.slam.state_update import pose_measurement_update

STEPS = 40


def _config(mode: str) -> SlamConfig:
    return SlamConfig.from_dict({"preset": "logs", "filter": {"prealign": mode}})


@pytest.mark.parametrize("mode", ["odometry", "fuse"])
def test_prealigned_filter_tracks_and_keeps_the_covariance_spd(mode):
    slam, beliefs, odo_err, true = run(_config(mode), steps=STEPS)
    assert np.mean([b.prealigned for b in beliefs]) > 0.5
    err = np.hypot(*(beliefs[-1].pose[:2] - true[STEPS - 1, :2]))
    assert err < 0.15, (err, odo_err[-1])
    np.testing.assert_array_equal(slam._sigma, slam._sigma.T)
    assert np.linalg.eigvalsh(slam._sigma).min() > 0


@pytest.mark.parametrize("mode", ["odometry", "fuse"])
def test_rejected_input_leaves_belief_and_matcher_unchanged(mode):
    slam, _, _, _ = run(_config(mode), steps=10)
    before, sigma = slam.belief, slam._sigma.copy()
    keyframes, matcher_pose = len(slam._local_map), slam._matcher_pose.copy()
    with pytest.raises(ValueError, match="NaN"):
        slam.step([0.0, 0.1, 0.0], np.r_[np.ones(180), np.nan], PHI)
    np.testing.assert_array_equal(slam.belief.pose, before.pose)
    np.testing.assert_array_equal(slam._sigma, sigma)
    assert len(slam._local_map) == keyframes
    np.testing.assert_array_equal(slam._matcher_pose, matcher_pose)


def test_unknown_prealign_mode_raises():
    with pytest.raises(ValueError, match="prealign"):
        FilterConfig(prealign="joint")


def test_relative_motion_update_equals_the_odometry_motion_update():
    rng = np.random.default_rng(0)
    a = rng.normal(size=(7, 7))
    sigma = a @ a.T + np.eye(7)
    mu = rng.normal(size=7)
    u, sigma_n = np.array([0.3, 0.8, -0.2]), np.diag([1e-3, 4e-3, 2e-3])
    expected = motion_update(mu, sigma, u, sigma_n)
    got = relative_motion_update(mu, sigma, *increment_to_relative(u, sigma_n))
    np.testing.assert_allclose(got[0], expected[0], atol=1e-12)
    np.testing.assert_allclose(got[1], expected[1], atol=1e-12)


def test_pose_measurement_update_is_the_dense_kalman_update():
    rng = np.random.default_rng(1)
    a = rng.normal(size=(7, 7))
    sigma = a @ a.T + np.eye(7)
    mu = rng.normal(size=7)
    z, r = mu[:3] + np.array([0.1, -0.2, 0.05]), np.diag([0.01, 0.02, 0.001])
    h = np.hstack([np.eye(3), np.zeros((3, 4))])
    gain = sigma @ h.T @ np.linalg.inv(h @ sigma @ h.T + r)
    mu_new, sigma_new = pose_measurement_update(mu, sigma, z, r)
    expected = mu + gain @ (z - mu[:3])
    np.testing.assert_allclose(mu_new[:2], expected[:2], atol=1e-12)
    np.testing.assert_allclose(mu_new[3:], expected[3:], atol=1e-12)
    np.testing.assert_allclose(sigma_new, (np.eye(7) - gain @ h) @ sigma, atol=1e-12)
    np.testing.assert_array_equal(sigma_new, sigma_new.T)


def _filtered(prealign: str, **matcher) -> SlamConfig:
    """The default with a 0.2 m / 0.2 rad motion filter (as in the ``fast`` preset)."""
    motion_filter = {"measurement_min_travel": 0.2, "measurement_min_turn": 0.2}
    return SlamConfig.from_dict(
        {"filter": {**motion_filter, "prealign": prealign}, "matcher": matcher}
    )


def test_motion_filter_matches_only_on_the_steps_that_measure(monkeypatch):
    import vslam_gym.slam.filter as filter_module

    calls = []
    real = filter_module.match_scan

    def counting(*args, **kwargs):
        calls.append(1)
        return real(*args, **kwargs)

    monkeypatch.setattr(filter_module, "match_scan", counting)
    slam, beliefs, odo_err, true = run(_filtered("odometry"), steps=STEPS)
    measured = sum(b.measured for b in beliefs)
    assert 3 <= measured <= STEPS // 2  # the filter skips every other step here
    # one match per measuring step but the first (empty local map); the loop closure's
    # matcher is another module's import
    assert len(calls) == measured - 1
    assert sum(b.prealigned for b in beliefs) >= measured - 2
    assert not any(b.prealigned and not b.measured for b in beliefs)
    err = np.hypot(*(beliefs[-1].pose[:2] - true[STEPS - 1, :2]))
    assert err < 0.15, (err, odo_err[-1])
    np.testing.assert_array_equal(slam._sigma, slam._sigma.T)
    assert np.linalg.eigvalsh(slam._sigma).min() > 0


def test_motion_filter_without_matches_equals_the_odometry():
    # Every match declined (too few points): the composed odometry since the last
    # measuring step replaces the odometry's steps, the same to first order.
    _, declined, _, _ = run(_filtered("odometry", min_points=10**6), steps=STEPS)
    _, odometry, _, _ = run(_filtered("none"), steps=STEPS)
    assert not any(b.prealigned for b in declined)
    assert [b.measured for b in declined] == [b.measured for b in odometry]
    for a, b in zip(declined, odometry, strict=True):
        np.testing.assert_allclose(a.pose, b.pose, atol=1e-9)
        np.testing.assert_allclose(a.pose_cov, b.pose_cov, rtol=1e-6, atol=1e-12)


def _start_scan(rng: np.random.Generator) -> np.ndarray:
    """A scan from the start of :func:`test_filter.circle_route`."""
    return cast(circle_route()[0], EDGES, PHI, SENSOR.max_range, 0.0, 0.0, rng)


def test_start_scan_is_the_matchers_first_keyframe_at_the_initial_pose():
    start = circle_route()[0]
    slam = VertexSLAM(SENSOR, SlamConfig(), initial_pose=start)
    ranges = _start_scan(np.random.default_rng(0))
    assert slam.add_start_scan(ranges, PHI)
    assert len(slam._local_map) == 1 and slam.belief.landmarks == ()
    # the keyframe's points lie where the scan saw them from the initial pose
    reference = slam._local_map.reference(start)
    hits = np.isfinite(ranges) & (ranges < SENSOR.max_range)
    angles = start[2] + PHI[hits]
    seen = start[:2] + ranges[hits, None] * np.column_stack([np.cos(angles), np.sin(angles)])
    gaps = np.linalg.norm(reference.points[:, None, :] - seen[None, :, :], axis=2).min(axis=1)
    assert len(reference.points) > 20 and gaps.max() < 1e-9  # the points with a normal
    # the first step is aligned to it (without it the matcher has nothing yet)
    increments = [0.0, 0.2, 0.0]
    moved = np.array([start[0] + 0.2 * np.cos(start[2]), start[1] + 0.2 * np.sin(start[2])])
    pose = np.r_[moved, start[2]]
    scan = cast(pose, EDGES, PHI, SENSOR.max_range, 0.0, 0.0, np.random.default_rng(1))
    assert slam.step(increments, scan, PHI).prealigned
    plain = VertexSLAM(SENSOR, SlamConfig(), initial_pose=start)
    assert not plain.step(increments, scan, PHI).prealigned


def test_start_scan_is_refused_after_a_step_or_twice_and_bad_input_changes_nothing():
    ranges = _start_scan(np.random.default_rng(0))
    slam = VertexSLAM(SENSOR, SlamConfig())
    with pytest.raises(ValueError, match="NaN"):
        slam.add_start_scan(np.r_[ranges[:-1], np.nan], PHI)
    with pytest.raises(ValueError):
        slam.add_start_scan(ranges[:-1], PHI)
    assert len(slam._local_map) == 0
    assert slam.add_start_scan(ranges, PHI)
    with pytest.raises(ValueError, match="once, before the first step"):
        slam.add_start_scan(ranges, PHI)
    stepped = VertexSLAM(SENSOR, SlamConfig())
    stepped.step([0.0, 0.0, 0.0], ranges, PHI)
    with pytest.raises(ValueError, match="before the first step"):
        stepped.add_start_scan(ranges, PHI)
    # without a whole-scan matcher (the thesis, ``fast``) there is nothing to give it to
    thesis = VertexSLAM(SENSOR, SlamConfig.thesis())
    assert not thesis.add_start_scan(ranges, PHI)
    assert len(thesis._local_map) == 0
