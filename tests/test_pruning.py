"""Covered duplicates: the coverage geometry and the filter option that prunes them."""

from __future__ import annotations

import numpy as np
import pytest
from test_filter import run

from vslam_gym.slam.filter import SlamConfig, _segment_distances
from vslam_gym.slam.icp import line_geometry
from vslam_gym.slam.landmark import LandmarkModel
from vslam_gym.slam.pruning import covered_fraction, object_segments, sample_segments


def _segments(*pairs):
    return np.array(pairs, dtype=float).reshape(-1, 2, 2)


def test_samples_span_each_segment_and_weigh_its_length():
    segs = _segments([(0, 0), (1, 0)], [(0, 1), (0, 1.25)])
    points, weights = sample_segments(segs, 0.1)
    assert weights.sum() == pytest.approx(1.25)
    assert np.all(np.diff(points[: np.count_nonzero(points[:, 1] == 0), 0]) <= 0.1 + 1e-12)
    assert {tuple(p) for p in points} >= {(0.0, 0.0), (1.0, 0.0), (0.0, 1.0), (0.0, 1.25)}
    empty_points, empty_weights = sample_segments(np.zeros((0, 2, 2)), 0.1)
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
    points, weights = sample_segments(_segments([(0, 0), (2, 0)]), 0.02)
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


def _prune_config(distance=0.1, idle=5):
    return SlamConfig.from_dict(
        {"filter": {"prune_covered_distance": distance, "prune_idle_steps": idle}}
    )


def test_pruning_removes_covered_duplicates_and_keeps_the_state_consistent():
    plain_slam, plain, _, _ = run(SlamConfig())
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
    ):
        name = next(iter(bad))
        with pytest.raises(ValueError, match=name):
            SlamConfig.from_dict({"filter": bad})
