"""Motion update (4.2.x) against a hand-computed case; segmentation of scans (4.3.1)."""

from __future__ import annotations

import numpy as np
import pytest

from vslam_gym.slam.config import SensorConfig
from vslam_gym.slam.filter import SlamConfig
from vslam_gym.slam.motion import (
    compose,
    increments_between,
    inverse,
    motion_update,
    odometry_noise,
    predict_pose,
)
from vslam_gym.slam.scan import Scan
from vslam_gym.slam.segmentation import segment_scan


def test_motion_update_hand_computed():
    mu = np.array([1.0, 2.0, np.pi / 2, 5.0, 6.0])
    sigma = np.diag([0.01, 0.02, 0.003, 0.5, 0.5])
    sigma[0, 3] = sigma[3, 0] = 0.001
    u = np.array([np.pi / 2, 2.0, 0.1])  # turn left 90 deg, drive 2 m, turn 0.1
    sigma_n = np.diag([1e-4, 4e-4, 1e-4])
    mu2, sigma2 = motion_update(mu, sigma, u, sigma_n)
    # heading pi: 2 m towards -x
    np.testing.assert_allclose(mu2[:3], [-1.0, 2.0, -np.pi + 0.1], atol=1e-12)
    np.testing.assert_array_equal(mu2[3:], mu[3:])
    # G = [[1,0,-d sin a],[0,1,d cos a],[0,0,1]] with a = pi: [[1,0,0],[0,1,-2],[0,0,1]]
    g = np.array([[1, 0, 0], [0, 1, -2.0], [0, 0, 1]])
    h = np.array([[0, -1.0, 0], [-2.0, 0, 0], [1, 0, 1]])
    want = g @ sigma[:3, :3] @ g.T + h @ sigma_n @ h.T
    np.testing.assert_allclose(sigma2[:3, :3], want, atol=1e-12)
    np.testing.assert_allclose(sigma2[:3, 3:], g @ sigma[:3, 3:], atol=1e-15)
    np.testing.assert_array_equal(sigma2[3:, 3:], sigma[3:, 3:])


def test_noise_model_and_pose_algebra():
    u = np.array([0.2, 1.0, -0.1])
    n = odometry_noise(u, (0.01, 0.005, 0.005, 0.001), np.zeros(3))
    np.testing.assert_allclose(
        np.diag(n), [0.01 * 0.04 + 0.005, 0.005 + 0.001 * 0.05, 0.01 * 0.01 + 0.005]
    )
    a, b = np.array([1.0, -2.0, 0.3]), np.array([4.0, 1.0, -2.0])
    np.testing.assert_allclose(predict_pose(a, increments_between(a, b)), b, atol=1e-12)
    np.testing.assert_allclose(compose(a, inverse(a)), 0.0, atol=1e-12)


SENSOR = SensorConfig()
PHI = np.linspace(np.pi / 2, -np.pi / 2, 181)


def test_segmentation_splits_at_gaps_and_no_returns():
    r = np.full(181, 30.0)
    r[10:30] = 5.0  # a wall
    r[30:40] = 7.0  # a jump of 2 m: new set
    r[50:60] = 4.0
    r[55] = 30.0  # a dropped beam splits
    scan = Scan.from_arrays(r, PHI, SENSOR)
    sets = segment_scan(scan, 2 * SENSOR.phi_res, 1.0)
    assert sets == [(10, 29), (30, 39), (50, 54), (56, 59)]


def test_segmentation_angular_threshold():
    """Beams further apart than the angular gap never link (a sparse scan)."""
    phi = np.linspace(np.pi / 2, -np.pi / 2, 19)  # 10 deg apart
    scan = Scan.from_arrays(np.full(19, 0.5), phi, SensorConfig(resolution_deg=10.0))
    assert len(segment_scan(scan, np.deg2rad(5.0), 1.0)) == 19
    assert segment_scan(scan, np.deg2rad(20.0), 1.0) == [(0, 18)]


def _ranges_to_line(point, normal):
    """Ranges along PHI to the infinite line through ``point`` with unit ``normal``."""
    d = np.stack([np.cos(PHI), np.sin(PHI)], axis=1)
    along = d @ np.asarray(normal)
    with np.errstate(divide="ignore"):
        r = (np.asarray(point) @ np.asarray(normal)) / along
    return np.where((along > 0) & (r > 0), r, np.inf)


def test_adaptive_breakpoint_splits_a_depth_jump_and_keeps_a_grazing_wall():
    # a box face 2 m ahead (beams 80-100) in front of a wall 2.6 m ahead: 0.6 m jumps
    r = np.minimum(_ranges_to_line((2.6, 0.0), (1.0, 0.0)), 30.0)
    r[80:101] = 2.0 / np.cos(PHI[80:101])
    scan = Scan.from_arrays(r, PHI, SENSOR)
    fixed = segment_scan(scan, 2 * SENSOR.phi_res, 1.0)
    adaptive = segment_scan(scan, 2 * SENSOR.phi_res, 1.0, np.deg2rad(10.0), 0.03)
    assert (80, 100) not in fixed and (80, 100) in adaptive
    assert len(adaptive) == len(fixed) + 2
    # a wall 1 m to the left, seen from 90 down to 12 degrees off the beams (beams 0-78,
    # points up to 0.4 m apart): one set either way
    wall = np.minimum(_ranges_to_line((0.0, 1.0), (0.0, 1.0)), 30.0)
    wall[wall > 1.0 / np.sin(np.deg2rad(12.0))] = 30.0
    scan = Scan.from_arrays(wall, PHI, SENSOR)
    assert segment_scan(scan, 2 * SENSOR.phi_res, 1.0, np.deg2rad(10.0), 0.03) == [(0, 78)]
    assert segment_scan(scan, 2 * SENSOR.phi_res, 1.0) == [(0, 78)]
    for bad in (90.0, -1.0, float("nan")):
        with pytest.raises(ValueError, match="segment_breakpoint_angle_deg"):
            SlamConfig.from_dict({"filter": {"segment_breakpoint_angle_deg": bad}})


def test_bad_increments():
    from vslam_gym.slam.motion import check_increments

    with pytest.raises(ValueError, match="shape"):
        check_increments([1.0, 2.0])
    with pytest.raises(ValueError, match="finite"):
        check_increments([np.nan, 0, 0])
