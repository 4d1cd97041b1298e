"""Landmark-frame references (``FilterConfig.reference="pose"``): a heading per landmark."""

from __future__ import annotations

import numpy as np
import pytest
from _raycast import bearings_deg, cast, polygon_edges
from test_filter import OBJECTS, SENSOR, run

from vslam_gym.slam.config import FilterConfig
from vslam_gym.slam.filter import SlamConfig, VertexSLAM
from vslam_gym.slam.motion import motion_update
from vslam_gym.slam.state_update import (
    LandmarkConditional,
    augment_landmark,
    rotation_columns,
)

PHI = bearings_deg()


def random_spd(rng, n, scale):
    a = rng.normal(size=(n, n))
    return scale * (a @ a.T + n * np.eye(n))


def test_augment_with_a_landmark_frame_matches_the_dense_joint():
    """``r = (S v, x_theta + e)``: exact moments, pose untouched, exact ``p(v | r)``."""
    rng = np.random.default_rng(0)
    n, k = 7, 3  # pose and two other landmark frames... then v of three vertices
    mu = rng.normal(size=n)
    sigma = random_spd(rng, n, 0.01)
    a3 = np.tile(np.eye(2, 3), (k, 1))
    a3[:, 2] = rng.normal(size=2 * k)
    b3 = rng.normal(size=2 * k)
    cov3 = random_spd(rng, 2 * k, 1e-4)
    select = np.zeros((3, 2 * k))
    select[:2] = np.tile(np.eye(2), k) / k
    select_pose = np.zeros((3, 3))
    select_pose[2, 2] = 1.0
    heading_sigma, shape_sigma = 1e-3, 1e-3
    mu_new, sigma_new, cond = augment_landmark(
        mu, sigma, a3, b3, cov3, select, shape_sigma, select_pose, heading_sigma
    )
    # dense: z = [s, v, e] jointly Gaussian, r = S v + S_x x + e
    m = n + 2 * k + 3
    t = np.zeros((m, m))  # z = t @ [s, n_v, e] + c
    t[:n, :n] = np.eye(n)
    t[n : n + 2 * k, :3] = a3
    t[n : n + 2 * k, n : n + 2 * k] = np.eye(2 * k)
    t[n + 2 * k :, n + 2 * k :] = np.eye(3)
    base = np.zeros((m, m))
    base[:n, :n] = sigma
    base[n : n + 2 * k, n : n + 2 * k] = cov3
    base[n + 2 * k :, n + 2 * k :] = np.diag([0.0, 0.0, heading_sigma**2])
    joint = t @ base @ t.T
    mean = np.concatenate([mu, a3 @ mu[:3] + b3, np.zeros(3)])
    to_r = np.zeros((3, m))
    to_r[:, :3] = select_pose
    to_r[:, n : n + 2 * k] = select
    to_r[:, n + 2 * k :] = np.eye(3)
    keep = np.zeros((n + 3, m))  # [s, r]
    keep[:n, :n] = np.eye(n)
    keep[n:] = to_r
    np.testing.assert_allclose(mu_new, keep @ mean, atol=1e-12)
    np.testing.assert_allclose(sigma_new, keep @ joint @ keep.T, atol=1e-12)
    np.testing.assert_array_equal(sigma_new[:n, :n], sigma)  # no information about the pose
    v = np.arange(n, n + 2 * k)
    s_vr = joint[v] @ to_r.T
    s_rr = to_r @ joint @ to_r.T
    gain = s_vr @ np.linalg.inv(s_rr)
    np.testing.assert_allclose(cond.A, gain, atol=1e-9)
    cond_cov = joint[np.ix_(v, v)] - gain @ s_vr.T + shape_sigma**2 * np.eye(2 * k)
    np.testing.assert_allclose(cond.covariance(), cond_cov, atol=1e-12)
    assert np.linalg.eigvalsh(sigma_new).min() > 0


def _frame_conditional(vertices, r):
    """A rigid landmark: ``v = r_xy + rotation column * (phi - r_phi) + offsets``."""
    k = vertices.shape[0]
    a = np.zeros((2 * k, 3))
    a[:, :2] = np.tile(np.eye(2), (k, 1))
    a[:, 2] = rotation_columns(vertices, r)
    return LandmarkConditional(A=a, b=vertices.reshape(-1) - a @ r, K=np.eye(2 * k) * 1e4)


def test_relinearized_keeps_the_means_and_follows_a_rotation():
    vertices = np.array([[2.0, 1.0], [4.0, 1.0], [4.0, 3.0]])
    r = np.array([3.0, 1.5, 0.2])
    cond = _frame_conditional(vertices, r)
    # the frame turns by 0.3 rad in small steps, re-linearised each time
    turned = r.copy()
    for _ in range(30):
        turned = turned + np.array([0.0, 0.0, 0.01])
        cond = cond.relinearized(turned)
        np.testing.assert_allclose(cond.mean(turned), cond.relinearized(turned).mean(turned))
    c, s = np.cos(0.3), np.sin(0.3)
    rigid = (vertices - r[:2]) @ np.array([[c, s], [-s, c]]) + r[:2]
    got = cond.mean(turned)
    # one linear step of 0.3 rad would stretch a 1.8 m landmark by about 8 cm
    one_step = _frame_conditional(vertices, r).mean(turned)
    assert np.abs(one_step - rigid).max() > 0.05
    assert np.abs(got - rigid).max() < 0.01
    # side lengths stay as they were (rigid), to within a few millimetres
    np.testing.assert_allclose(
        np.linalg.norm(np.diff(got, axis=0), axis=1),
        np.linalg.norm(np.diff(vertices, axis=0), axis=1),
        atol=5e-3,
    )
    # a point reference is left alone
    point = LandmarkConditional(A=np.tile(np.eye(2), (3, 1)), b=np.zeros(6), K=np.eye(6))
    assert point.relinearized(np.zeros(2)) is point


def test_select_attaches_new_vertices_to_the_frame():
    vertices = np.array([[2.0, 1.0], [4.0, 1.0]])
    r = np.array([3.0, 1.0, 0.0])
    cond = _frame_conditional(vertices, r)
    new = np.array([[4.0, 2.0]])
    out = cond.select(np.array([0, 1, -1]), np.r_[vertices, new], np.tile(np.eye(2), (3, 1, 1)), r)
    np.testing.assert_allclose(out.mean(r), np.r_[vertices, new])
    np.testing.assert_allclose(out.A[4:, 2], rotation_columns(new, r))
    np.testing.assert_allclose(out.A[4:, :2], np.eye(2))


@pytest.mark.parametrize("new_landmark", ["thesis", "augment"])
def test_creating_a_landmark_frame_gives_the_pose_no_information(new_landmark):
    sigma0 = (0.05, 0.05, 0.05)

    def first_step(reference):
        cfg = SlamConfig(
            filter=FilterConfig(
                reference=reference,
                new_landmark=new_landmark,
                initial_pose_sigma=sigma0,
                error_noise_scale=0.0,  # the belief reports the filter's own covariance
            )
        )
        slam = VertexSLAM(SENSOR, cfg)
        rng = np.random.default_rng(1)
        ranges = cast(
            np.zeros(3),
            polygon_edges(OBJECTS),
            PHI,
            SENSOR.max_range,
            SENSOR.sigma_range,
            SENSOR.sigma_bearing,
            rng,
        )
        return slam, slam.step([0.0, 0.0, 0.0], ranges, PHI)

    slam, belief = first_step("pose")
    assert sum(d.outcome == "created" for d in belief.decisions) >= 2
    assert belief.state_dim == 3 + 3 * len(belief.landmarks)
    # only the standing robot's odometry floor (1 mm, 1 mrad per rotation) was added
    _, expected = motion_update(
        np.zeros(3), np.diag(np.square(sigma0)), np.zeros(3), np.diag([1e-6, 1e-6, 1e-6])
    )
    np.testing.assert_allclose(belief.pose_cov, expected, rtol=1e-6, atol=1e-12)
    assert np.linalg.eigvalsh(slam._sigma).min() > 0
    np.testing.assert_allclose(
        slam._refs()[:, 2], belief.pose[2], atol=1e-9
    )  # frames start at the pose heading
    if new_landmark == "thesis":
        # the thesis's point reference turns the same scan into heading information
        _, point = first_step("point")
        assert np.sqrt(point.pose_cov[2, 2]) < 0.2 * np.sqrt(belief.pose_cov[2, 2])


def test_loop_with_landmark_frames_closes_and_stays_positive_definite():
    cfg = SlamConfig(filter=FilterConfig(reference="pose", new_landmark="augment"))
    slam, beliefs, odo_err, true = run(cfg)
    final = beliefs[-1]
    err = np.hypot(*(final.pose[:2] - true[-1, :2]))
    assert err < 0.15 and err < 0.2 * odo_err[-1], (err, odo_err[-1])
    assert [lm.ref for lm in slam._landmarks] == [3 + 3 * i for i in range(len(slam._landmarks))]
    assert np.linalg.eigvalsh(slam._sigma).min() > 0
    np.testing.assert_array_equal(slam._sigma, slam._sigma.T)
    late = [d for b in beliefs[90:] for d in b.decisions if d.outcome == "updated"]
    assert any(d.landmark == 0 for d in late)
    # the belief's reference is the frame's origin, a point
    assert final.landmarks[0].reference.shape == (2,)
    assert final.landmarks[0].reference_cov.shape == (2, 2)
