"""The BLAS thread limit around the estimator's step (vslam_gym.slam.threads)."""

from __future__ import annotations

import contextlib

import numpy as np
import pytest
from _raycast import cast
from test_filter import EDGES, PHI, SENSOR, circle_route, run
from threadpoolctl import ThreadpoolController

import vslam_gym.slam.filter as filter_module
from vslam_gym.slam.filter import SlamConfig, VertexSLAM
from vslam_gym.slam.threads import blas_threads, check_blas_threads


def blas_thread_counts() -> list[int]:
    libraries = ThreadpoolController().info()
    return [lib["num_threads"] for lib in libraries if lib["user_api"] == "blas"]


def test_limit_holds_inside_the_block_and_is_restored_after():
    before = blas_thread_counts()
    assert before, "no BLAS library found"
    with blas_threads(1):
        assert blas_thread_counts() == [1] * len(before)
    assert blas_thread_counts() == before
    with blas_threads(None):
        assert blas_thread_counts() == before


def test_step_runs_under_the_limit_and_leaves_the_caller_setting(monkeypatch):
    before = blas_thread_counts()
    slam = VertexSLAM(SENSOR, SlamConfig(), initial_pose=circle_route()[0])
    seen = []
    update = slam._update
    monkeypatch.setattr(slam, "_update", lambda *a: (seen.append(blas_thread_counts()), update(*a)))
    ranges = cast(circle_route()[0], EDGES, PHI, SENSOR.max_range, 0.0, 0.0)
    slam.step([0.0, 0.0, 0.0], ranges, PHI)
    assert seen == [[1] * len(before)]
    assert blas_thread_counts() == before
    # construction alone changes nothing either
    VertexSLAM(SENSOR, SlamConfig(), blas_threads=1)
    assert blas_thread_counts() == before


def test_same_belief_with_and_without_the_limit(monkeypatch):
    limited = run(SlamConfig(), steps=25)[1][-1]
    monkeypatch.setattr(filter_module, "blas_limit", lambda threads: contextlib.nullcontext())
    free = run(SlamConfig(), steps=25)[1][-1]
    np.testing.assert_array_equal(limited.pose, free.pose)
    np.testing.assert_array_equal(limited.pose_cov, free.pose_cov)
    assert len(limited.landmarks) == len(free.landmarks) > 0


@pytest.mark.parametrize("bad", [0, -1, True, 1.5, "1"])
def test_bad_thread_counts_are_refused(bad):
    with pytest.raises(ValueError, match="blas_threads"):
        check_blas_threads(bad)
    with pytest.raises(ValueError, match="blas_threads"):
        VertexSLAM(SENSOR, SlamConfig(), blas_threads=bad)
