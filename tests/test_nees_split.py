"""The NEES split diagnostic (benchmarks/nees_split.py): its heading drift and correlation."""

import importlib.util
from pathlib import Path

import numpy as np
import pytest

_PATH = Path(__file__).resolve().parents[1] / "benchmarks" / "nees_split.py"
_spec = importlib.util.spec_from_file_location("nees_split", _PATH)
nees_split = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(nees_split)


def test_heading_drift_is_the_heading_error_times_the_path_across_it():
    # straight east 10 x 0.1 m with a constant heading error of +0.02 rad: the map is
    # built rotated counter-clockwise, so the error points north, 0.02 rad x 1 m
    true = np.column_stack([np.arange(11) * 0.1, np.zeros(11), np.zeros(11)])
    error = np.zeros((11, 3))
    error[:, 2] = 0.02
    drift = nees_split.heading_drift(error, true)
    assert drift.shape == (11, 2)
    np.testing.assert_allclose(drift[0], [0.0, 0.0])
    np.testing.assert_allclose(drift[-1], [0.0, 0.02], atol=1e-12)
    np.testing.assert_allclose(drift[5], [0.0, 0.01], atol=1e-12)


def test_correlation_is_the_larger_absolute_position_heading_one():
    cov = np.diag([4.0, 1.0, 1.0])
    cov[0, 2] = cov[2, 0] = -1.0  # corr -0.5
    cov[1, 2] = cov[2, 1] = 0.25  # corr 0.25
    assert nees_split.correlation(cov[None])[0] == pytest.approx(0.5)
