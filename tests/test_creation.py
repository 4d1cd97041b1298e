"""Model creation (SPEC sections 3, 5-7): grouping, BIC selection, vertices, unknown lines."""

from __future__ import annotations

import numpy as np
import pytest
from _raycast import bearings_deg, cast, polygon_edges
from scipy import stats

from vslam_gym.slam.config import ModelConfig, SensorConfig
from vslam_gym.slam.creation import DegenerateSegmentError, create_model
from vslam_gym.slam.scan import Scan, ScanError

SENSOR = SensorConfig()
PHI = bearings_deg()
POSE = np.array([0.0, 0.0, np.pi / 2])
# An open zig-zag of four segments in front of the lidar (like thesis figure 3.7).
ZIGZAG = np.array([(-3.0, 5.0), (-1.0, 6.5), (1.0, 5.5), (3.0, 7.0), (5.0, 6.0)])
ZIGZAG_EDGES = np.stack([ZIGZAG[:-1], ZIGZAG[1:]], axis=1)


def noisy_scan(edges, rng, pose=POSE, sensor=SENSOR):
    r = cast(pose, edges, PHI, sensor.max_range, sensor.sigma_range, sensor.sigma_bearing, rng)
    return Scan.from_arrays(r, PHI, sensor)


def segment(scan):
    idx = np.flatnonzero(scan.returns)
    assert np.all(np.diff(idx) == 1), "test scenes must give one contiguous segment"
    return int(idx[0]), int(idx[-1])


@pytest.mark.parametrize("linearization, atol", [("jacobian", 1e-9), ("ut", 0.02)])
def test_noiseless_l_shape_vertex_at_true_corner(linearization, atol):
    """First order: exact. The UT mean adds the second-order (curvature) term, which is
    the expected value of the vertex estimator rather than its value at the data."""
    corner = np.array([1.0, 6.0])
    edges = np.array([[(-3.0, 5.0), corner], [corner, (4.0, 8.5)]])
    r = cast(POSE, edges, PHI)
    scan = Scan.from_arrays(r, PHI, SENSOR)
    first, last = segment(scan)
    fit = create_model(scan, first, last, POSE, SENSOR, ModelConfig(linearization=linearization))
    start, stop = fit.object_vertices
    assert fit.n_object_lines == 2
    np.testing.assert_allclose(fit.model.mean[start + 1], corner, atol=atol)
    # The end vertices lie on the first and last beams, on the true walls.
    for v, beam in ((fit.model.mean[start], first), (fit.model.mean[stop - 1], last)):
        np.testing.assert_allclose(np.hypot(*v), r[beam], atol=atol)


@pytest.mark.parametrize("linearization", ["ut", "jacobian"])
def test_four_segment_shape_gets_four_lines(linearization):
    cfg = ModelConfig(linearization=linearization)
    rng = np.random.default_rng(1)
    hits = 0
    trials = 100 if linearization == "jacobian" else 40
    for _ in range(trials):
        scan = noisy_scan(ZIGZAG_EDGES, rng)
        fit = create_model(scan, *segment(scan), POSE, SENSOR, cfg)
        hits += fit.n_object_lines == 4
    assert hits >= 0.95 * trials


def zigzag_vertex_nees(cfg, trials, seed=2):
    """NEES of the three true corners of the zig-zag (6 dof) over seeded noisy scans."""
    rng = np.random.default_rng(seed)
    nees = []
    for _ in range(trials):
        scan = noisy_scan(ZIGZAG_EDGES, rng)
        fit = create_model(scan, *segment(scan), POSE, SENSOR, cfg)
        if fit.n_object_lines != 4:
            continue
        start, _ = fit.object_vertices
        idx = np.arange(2 * (start + 1), 2 * (start + 4))
        err = fit.model.mean[start + 1 : start + 4].reshape(-1) - ZIGZAG[1:4].reshape(-1)
        nees.append(err @ np.linalg.solve(fit.model.cov[np.ix_(idx, idx)], err))
    return np.array(nees)


def test_vertex_nees_is_consistent():
    """Default model: mean NEES inside the 95% interval of its chi-square distribution."""
    nees = zigzag_vertex_nees(ModelConfig(), 200)
    n = nees.size
    assert n >= 190
    lo, hi = stats.chi2.ppf([0.025, 0.975], 6 * n) / n
    assert lo <= nees.mean() <= hi, (nees.mean(), lo, hi)


def test_thesis_vertex_nees_gap_is_measured():
    """The thesis model is overconfident: its corner NEES was measured at about 12
    (expected 6) over these 200 scans, because the boundary measurement shared by two
    lines biases their vertex. This test keeps that measurement (with a margin)."""
    nees = zigzag_vertex_nees(ModelConfig.thesis(linearization="jacobian"), 200)
    assert 9.0 <= nees.mean() <= 16.0


def circle_all_within_3_sigma(cfg, trials, seed=3):
    """Fraction of scans of a circle whose vertices all lie within 3 sigma of it."""
    centre, radius = np.array([0.0, 6.0]), 1.5
    ang = np.linspace(0, 2 * np.pi, 200, endpoint=False)
    circle = centre + radius * np.stack([np.cos(ang), np.sin(ang)], 1)
    rng = np.random.default_rng(seed)
    ok = []
    for _ in range(trials):
        scan = noisy_scan(polygon_edges([circle]), rng)
        fit = create_model(scan, *segment(scan), POSE, SENSOR, cfg)
        start, stop = fit.object_vertices
        assert fit.n_object_lines >= 2
        z = []
        for i in range(start, stop):
            v = fit.model.mean[i]
            radial = (v - centre) / np.linalg.norm(v - centre)
            sigma = np.sqrt(radial @ fit.model.vertex_cov(i) @ radial)
            z.append(abs(np.linalg.norm(v - centre) - radius) / sigma)
        ok.append(max(z) <= 3.0)
    return float(np.mean(ok))


def test_circle_vertices_lie_within_three_sigma():
    """A polyline cannot follow a circle: without a model-error term (the thesis) the
    vertices are outside 3 sigma in almost every scan; with coarseness in most.
    Measured over these 40 scans: thesis about 0.05, default about 0.8."""
    assert circle_all_within_3_sigma(ModelConfig(), 40) >= 0.7
    assert circle_all_within_3_sigma(ModelConfig.thesis(linearization="jacobian"), 40) <= 0.2


def test_unknown_lines_object_edge_case():
    """No return beside the landmark: two artificial vertices at max range per side."""
    scan = Scan.from_arrays(cast(POSE, ZIGZAG_EDGES, PHI), PHI, SENSOR)
    first, last = segment(scan)
    fit = create_model(scan, first, last, POSE, SENSOR)
    start, stop = fit.object_vertices
    assert start == 2 and fit.model.n_vertices - stop == 2
    res = SENSOR.phi_res
    expect = {
        0: PHI[first] + 5 * res,
        1: PHI[first] + res,
        stop: PHI[last] - res,
        stop + 1: PHI[last] - 5 * res,
    }
    for i, bearing in expect.items():
        v = fit.model.mean[i]
        assert np.hypot(*v) == pytest.approx(SENSOR.max_range)
        assert np.arctan2(v[1], v[0]) - POSE[2] == pytest.approx(bearing)
    np.testing.assert_array_equal(fit.model.u[:2], 1.0)
    np.testing.assert_array_equal(fit.model.u[-2:], 1.0)
    np.testing.assert_array_equal(fit.model.u[2:-2], 0.0)


def test_unknown_lines_occlusion_case():
    """A return beside the landmark (a wall behind it): one vertex at that measurement."""
    far_wall = np.array([[(-20.0, 15.0), (20.0, 15.0)]])
    edges = np.concatenate([ZIGZAG_EDGES, far_wall])
    r = cast(POSE, edges, PHI)
    scan = Scan.from_arrays(r, PHI, SENSOR)
    near = np.flatnonzero(r < 10)
    first, last = int(near[0]), int(near[-1])
    fit = create_model(scan, first, last, POSE, SENSOR)
    start, stop = fit.object_vertices
    assert start == 1 and fit.model.n_vertices - stop == 1
    for i, beam in ((0, first - 1), (stop, last + 1)):
        v = fit.model.mean[i]
        assert np.hypot(*v) == pytest.approx(r[beam])
        assert v[1] == pytest.approx(15.0)


def test_unknown_lines_fov_limit_case():
    """A landmark at the edge of the field of view: a vertex at the lidar position."""
    wall = np.array([[(-5.0, -2.0), (-5.0, 8.0)]])
    pose = np.array([0.0, 0.0, 0.0])  # facing +x: the wall x=-5 is only at the FOV edges
    edges = np.array([[(-1.0, 6.0), (3.0, 4.0)], [(3.0, 4.0), (6.0, 9.0)]])
    r = cast(pose, np.concatenate([edges, wall]), PHI)
    scan = Scan.from_arrays(r, PHI, SENSOR)
    assert r[0] < SENSOR.max_range  # the leftmost beam (bearing +90 deg) has a return
    last = int(np.flatnonzero(np.abs(np.diff(r)) > 1.0)[0])
    fit = create_model(scan, 0, last, pose, SENSOR)
    np.testing.assert_allclose(fit.model.mean[0], pose[:2], atol=1e-12)
    assert fit.object_vertices[0] == 1
    assert np.all(np.linalg.eigvalsh(fit.model.vertex_cov(0)) > 0)


def test_covariance_is_symmetric_positive_definite_and_conditional_form():
    rng = np.random.default_rng(4)
    scan = noisy_scan(ZIGZAG_EDGES, rng)
    fit = create_model(scan, *segment(scan), POSE, SENSOR)
    cov = fit.model.cov
    np.testing.assert_allclose(cov, cov.T, atol=0)
    assert np.linalg.eigvalsh(cov).min() > 0
    # v = A_vx x + b_vx reproduces the means at the build pose; A has the SPEC 7 form.
    np.testing.assert_allclose(fit.A_vx @ POSE + fit.b_vx, fit.model.mean.reshape(-1))
    v = fit.model.mean[3]
    np.testing.assert_allclose(fit.A_vx[6:8], [[1, 0, -(v[1] - POSE[1])], [0, 1, v[0] - POSE[0]]])


def test_ut_and_first_order_agree_on_vertices():
    scan = noisy_scan(ZIGZAG_EDGES, np.random.default_rng(5))
    fits = [
        create_model(scan, *segment(scan), POSE, SENSOR, ModelConfig(linearization=lin))
        for lin in ("ut", "jacobian")
    ]
    assert fits[0].n_object_lines == fits[1].n_object_lines == 4
    np.testing.assert_allclose(fits[0].model.mean, fits[1].model.mean, atol=2e-3)
    s0, s1 = (np.sqrt(np.diag(f.model.cov)) for f in fits)
    np.testing.assert_allclose(s0, s1, rtol=0.1)


@pytest.mark.parametrize(
    "ranges, bearings, match",
    [
        (np.array([1.0, np.nan, 1.0]), PHI[:3], "NaN"),
        (np.array([1.0, -1.0, 1.0]), PHI[:3], ">= 0"),
        (np.ones(3), PHI[:3][::-1], "descending"),
        (np.ones(2), PHI[:2], "at least 3"),
        (np.ones(4), PHI[:3], "bearings has 3"),
    ],
)
def test_bad_scans_raise(ranges, bearings, match):
    with pytest.raises(ScanError, match=match):
        Scan.from_arrays(ranges, bearings, SENSOR)


def test_degenerate_segments_raise():
    scan = Scan.from_arrays(cast(POSE, ZIGZAG_EDGES, PHI), PHI, SENSOR)
    first, last = segment(scan)
    with pytest.raises(DegenerateSegmentError, match="at least 3"):
        create_model(scan, first, first + 1, POSE, SENSOR)
    with pytest.raises(DegenerateSegmentError, match="no-return"):
        create_model(scan, first - 2, last, POSE, SENSOR)


def test_short_line_at_grazing_angle_keeps_its_vertices():
    """Regression: a 3-beam face seen at a grazing angle between two longer faces. The
    exclusive-boundary split must not refit it through two points (which put a vertex
    2.7 m off); its vertices agree with the thesis's shared-boundary fit."""
    poly = np.array([(-1.5, 7), (-1.5, 5), (-0.5, 5), (-0.5, 6), (1.5, 6), (1.5, 7)], float)
    c, s = np.cos(0.15), np.sin(0.15)
    poly = (poly - [0, 6]) @ np.array([[c, -s], [s, c]]).T + [0, 6]
    scan = noisy_scan(polygon_edges([poly]), np.random.default_rng(0))
    fits = [
        create_model(scan, 75, 103, POSE, SENSOR, ModelConfig(exclusive_boundaries=ex))
        for ex in (True, False)
    ]
    assert [f.n_object_lines for f in fits] == [3, 3]
    a, b = (f.model.mean[f.object_vertices[0] : f.object_vertices[1]] for f in fits)
    np.testing.assert_allclose(a, b, atol=0.05)


@pytest.mark.filterwarnings("error")
def test_parallel_pairs_sines_and_a_zero_length_end_line():
    from vslam_gym.slam.creation import _parallel_pairs, _SegmentModeller
    from vslam_gym.slam.gaussian import FirstOrderLinearization

    bearings = np.deg2rad(np.arange(20.0, -21.0, -1.0))
    ranges = 3.0 / np.cos(bearings)  # a wall at x = 3 [m] seen from the origin
    pose = np.zeros(3)
    groups = [(0, 20), (20, 40)]
    for zero_first in (False, True):
        r = ranges.copy()
        if zero_first:
            r[0] = 0.0  # the left end line has no length: its sine is 0
        scan = Scan.from_arrays(r, bearings, SENSOR)
        modeller = _SegmentModeller(
            scan, 0, 40, pose, SENSOR, ModelConfig(), FirstOrderLinearization()
        )
        sines = _parallel_pairs(modeller, groups)
        assert sines.shape == (3,) and np.isfinite(sines).all()
        assert (sines[0] == 0.0) == zero_first
        if not zero_first:
            np.testing.assert_allclose(sines[1], 0.0, atol=1e-12)  # two fits of one wall
            np.testing.assert_allclose(sines[[0, 2]], np.cos(bearings[[0, -1]]), rtol=1e-9)
