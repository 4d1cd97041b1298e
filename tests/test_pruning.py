"""Covered duplicates: the coverage geometry and the filter option that prunes them."""

from __future__ import annotations

import numpy as np
import pytest
from test_filter import run

from vslam_gym.slam.filter import SlamConfig, _segment_distances
from vslam_gym.slam.icp import line_geometry
from vslam_gym.slam.landmark import LandmarkModel
from vslam_gym.slam.pruning import (
    TranslationFit,
    covered_fraction,
    fit_translation,
    object_segments,
    sample_segments,
)


def _segments(*pairs):
    return np.array(pairs, dtype=float).reshape(-1, 2, 2)


def test_samples_span_each_segment_and_weigh_its_length():
    segs = _segments([(0, 0), (1, 0)], [(0, 1), (0, 1.25)])
    points, weights, seg = sample_segments(segs, 0.1)
    assert weights.sum() == pytest.approx(1.25)
    assert np.all(np.diff(points[: np.count_nonzero(points[:, 1] == 0), 0]) <= 0.1 + 1e-12)
    assert {tuple(p) for p in points} >= {(0.0, 0.0), (1.0, 0.0), (0.0, 1.0), (0.0, 1.25)}
    empty_points, empty_weights, _ = sample_segments(np.zeros((0, 2, 2)), 0.1)
    assert empty_points.shape == (0, 2) and empty_weights.size == 0


@pytest.mark.parametrize(
    ("other", "expected"),
    [
        (_segments([(0, 0), (2, 0)]), 1.0),  # itself
        (_segments([(-1, 0.05), (3, 0.05)]), 1.0),  # parallel, 5 cm off
        (_segments([(-1, 0.2), (3, 0.2)]), 0.0),  # parallel, 20 cm off
        (_segments([(1, 0), (3, 0)]), 0.55),  # from x = 0.9 on: within 0.1 m of its end
    ],
)
def test_covered_fraction(other, expected):
    points, weights, _ = sample_segments(_segments([(0, 0), (2, 0)]), 0.02)
    model = LandmarkModel(other[0], np.eye(4), np.zeros(1), False)
    distances = _segment_distances(points, [line_geometry(model)])[0]
    assert covered_fraction(weights, distances, 0.1) == pytest.approx(expected, abs=0.02)
    assert covered_fraction(np.zeros(0), np.zeros(0), 0.1) == 0.0  # nothing to cover


def test_object_segments_skip_unknown_lines_and_close_polygons():
    mean = np.array([(0, 0), (1, 0), (1, 1), (0, 1)], float)
    open_model = LandmarkModel(mean, np.eye(8), np.array([1.0, 0.0, 0.0]), False)
    np.testing.assert_array_equal(object_segments(open_model, 0.5), [mean[1:3], mean[2:4]])
    closed = LandmarkModel(mean, np.eye(8), np.array([0.0, 1.0, 1.0, 0.0]), True)
    np.testing.assert_array_equal(object_segments(closed, 0.5), [mean[0:2], mean[[3, 0]]])


SHORT_MATCHER = {"matcher": {"keyframes": 20}}
"""The matcher's local map before session 37: on the circle route the default's 40
keyframes make no covered duplicate to prune, 20 make several."""


def _prune_config(distance=0.1, idle=5):
    return SlamConfig.from_dict(
        {"filter": {"prune_covered_distance": distance, "prune_idle_steps": idle}, **SHORT_MATCHER}
    )


def test_pruning_removes_covered_duplicates_and_keeps_the_state_consistent():
    plain_slam, plain, _, _ = run(SlamConfig.from_dict(SHORT_MATCHER))
    slam, beliefs, _, true = run(_prune_config())
    pruned = [i for b in beliefs for i in b.pruned]
    assert pruned, "the circle route makes covered duplicates"
    assert len(set(pruned)) == len(pruned)
    assert len(beliefs[-1].landmarks) < len(plain[-1].landmarks)
    gone: set[int] = set()
    for belief in beliefs:
        ids = [lm.id for lm in belief.landmarks]
        gone |= set(belief.pruned)
        assert ids == sorted(ids) and not gone & set(ids), "ids stay; pruned ones never return"
        assert belief.state_dim == 3 + 2 * len(ids)
    # the state is consistent with the landmark list and positive definite
    assert [lm.ref for lm in slam._landmarks] == [3 + 2 * i for i in range(len(slam._landmarks))]
    sigma = slam._sigma
    np.testing.assert_allclose(sigma, sigma.T)
    assert np.linalg.eigvalsh(sigma).min() > 0.0
    # the loop still closes as well as without pruning (final position error, m)
    err = np.hypot(*(beliefs[-1].pose[:2] - true[-1, :2]))
    plain_err = np.hypot(*(plain[-1].pose[:2] - true[-1, :2]))
    assert err < max(0.2, 2.0 * plain_err)


def test_removal_is_a_marginalisation():
    slam, beliefs, _, _ = run(SlamConfig(), steps=40)
    before = {lm.id: lm for lm in slam.belief.landmarks}
    pose_cov = slam.belief.pose_cov
    victim = beliefs[-1].landmarks[1].id
    slam._remove_landmarks({victim})
    after = slam.belief
    assert victim not in {lm.id for lm in after.landmarks}
    assert len(after.landmarks) == len(before) - 1
    np.testing.assert_array_equal(after.pose_cov, pose_cov)
    for lm in after.landmarks:
        np.testing.assert_array_equal(lm.reference, before[lm.id].reference)
        np.testing.assert_array_equal(lm.reference_cov, before[lm.id].reference_cov)
        np.testing.assert_array_equal(lm.model.mean, before[lm.id].model.mean)
    np.testing.assert_array_equal(slam._refs(), [lm.reference for lm in after.landmarks])


def _polyline(vertices):
    """Open object polyline (every line an object line) and its line geometry."""
    return line_geometry(
        LandmarkModel(vertices, np.eye(2 * len(vertices)), np.zeros(len(vertices) - 1), False)
    )


def _fit(victim, keeper, max_distance=0.5):
    """fit_translation of the polyline ``victim`` onto ``keeper`` (vertex lists)."""
    segs = np.stack([victim[:-1], victim[1:]], axis=1)
    points, weights, seg = sample_segments(segs, 0.05)
    lines = _polyline(victim)
    normals = np.stack([lines.nx, lines.ny], axis=1)[seg]
    return fit_translation(points, weights, normals, _polyline(keeper), max_distance)


L_SHAPE = np.array([(0.0, 2.0), (0.0, 0.0), (2.0, 0.0)])  # right-hand free side: x < 0, y < 0


def test_fit_uses_the_icp_normals_which_point_to_the_free_side():
    lines = _polyline(L_SHAPE)
    np.testing.assert_allclose(np.stack([lines.nx, lines.ny], 1), [(-1, 0), (0, -1)])


def test_fit_recovers_the_offset_of_a_corner():
    fit = _fit(L_SHAPE + (-0.2, 0.1), L_SHAPE)
    np.testing.assert_allclose(fit.offset, (0.2, -0.1), atol=1e-9)
    assert fit.directions.shape == (2, 2)
    assert covered_fraction(np.ones(fit.distances.size), fit.distances, 0.01) > 0.9


def test_fit_of_a_straight_wall_moves_along_its_normal_only():
    wall = np.array([(0.0, 0.0), (3.0, 0.0)])  # free side y < 0
    fit = _fit(wall + (0.7, 0.15), wall)
    assert fit.directions.shape == (2, 1)
    np.testing.assert_allclose(np.abs(fit.directions[:, 0]), (0, 1), atol=1e-12)
    np.testing.assert_allclose(fit.offset, (0.0, -0.15), atol=1e-9)


def test_fit_never_matches_the_other_face_of_a_wall():
    wall = np.array([(0.0, 0.0), (3.0, 0.0)])
    fit = _fit(wall[::-1] + (0.0, 0.05), wall)  # 5 cm away, facing the other way
    assert np.all(np.isinf(fit.distances)) and fit.directions.shape == (2, 0)
    np.testing.assert_array_equal(fit.offset, (0.0, 0.0))


def _merge_setup():
    slam, beliefs, _, _ = run(SlamConfig(), steps=40)
    victim, keeper = slam._landmarks[0], slam._landmarks[1]
    d = np.eye(2)
    jv, cv = slam._object_vertex_moments(victim)
    jk, ck = slam._object_vertex_moments(keeper)
    h = np.zeros((2, slam._mu.size))
    h[:, victim.ref : victim.ref + 2], h[:, keeper.ref : keeper.ref + 2] = jv, -jk
    noise = slam.config.filter.prune_merge_sigma**2 * np.eye(2) + cv + ck
    return slam, victim, keeper, d, h, noise


def test_merge_is_a_gated_kalman_update_of_the_relative_position():
    slam, victim, keeper, d, h, noise = _merge_setup()
    mu, sigma = slam._mu.copy(), slam._sigma.copy()
    offset = np.array([0.03, -0.02])
    assert slam._merge_duplicate(victim, keeper, TranslationFit(offset, d, np.zeros(1)))
    moved = h @ (slam._mu - mu)
    # the relative position moves by the Kalman gain's share of the measured offset:
    # P (P + R)^-1 offset, toward it (positive along the whitened innovation), and the
    # rest of the offset is R (P + R)^-1 offset
    prior = h @ sigma @ h.T
    whitened = np.linalg.solve(prior + noise, offset)
    np.testing.assert_allclose(moved, prior @ whitened, rtol=1e-6, atol=1e-12)
    assert moved @ whitened > 0 and offset @ whitened > moved @ whitened
    assert np.all(np.diag(h @ slam._sigma @ h.T) < np.diag(h @ sigma @ h.T))
    np.testing.assert_array_equal(slam._sigma, slam._sigma.T)
    assert np.linalg.eigvalsh(slam._sigma).min() > 0.0
    # an offset far beyond the gate leaves the state exactly as it was
    mu, sigma = slam._mu.copy(), slam._sigma.copy()
    assert not slam._merge_duplicate(
        victim, keeper, TranslationFit(np.array([5.0, 0]), d, np.zeros(1))
    )
    assert not slam._merge_duplicate(
        victim, keeper, TranslationFit(offset, np.zeros((2, 0)), np.zeros(1))
    )
    np.testing.assert_array_equal(slam._mu, mu)
    np.testing.assert_array_equal(slam._sigma, sigma)


def test_merging_keeps_the_state_consistent_and_the_loop_closed():
    plain_slam, plain, _, true = run(SlamConfig())
    config = SlamConfig.from_dict(
        {"filter": {"prune_covered_distance": 0.1, "prune_idle_steps": 5, "prune_merge": True}}
    )
    slam, beliefs, _, _ = run(config)
    merged = [i for b in beliefs for i in b.pruned]
    assert merged and len(set(merged)) == len(merged)
    assert [lm.ref for lm in slam._landmarks] == [3 + 2 * i for i in range(len(slam._landmarks))]
    np.testing.assert_array_equal(slam._sigma, slam._sigma.T)
    assert np.linalg.eigvalsh(slam._sigma).min() > 0.0
    err = np.hypot(*(beliefs[-1].pose[:2] - true[-1, :2]))
    plain_err = np.hypot(*(plain[-1].pose[:2] - true[-1, :2]))
    assert err < max(0.2, 2.0 * plain_err)


def test_pruning_is_off_by_default_and_validated():
    assert SlamConfig().filter.prune_covered_distance == 0.0
    assert SlamConfig.thesis().filter.prune_covered_distance == 0.0
    for bad in (
        {"prune_covered_distance": -0.1},
        {"prune_covered_distance": float("nan")},
        {"prune_covered_fraction": 0.0},
        {"prune_covered_fraction": 1.5},
        {"prune_idle_steps": 0},
        {"prune_idle_steps": True},
        {"prune_merge_max_offset": 0.0},
        {"prune_merge_sigma": -1.0},
        {"prune_merge_probability": 1.0},
        {"prune_merge": "yes"},
    ):
        name = next(iter(bad))
        with pytest.raises(ValueError, match=name):
            SlamConfig.from_dict({"filter": bad})
