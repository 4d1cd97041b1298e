"""Tests of vslam_gym.slam.geometry: angles, polar maps, line fits and intersections."""

from __future__ import annotations

import numpy as np
import pytest

from vslam_gym.slam.geometry import (
    cartesian_to_polar,
    fit_line,
    fit_line_jacobian,
    intersect_lines,
    line_direction,
    line_normal,
    line_through,
    perpendicular_distance,
    polar_to_cartesian,
    polar_to_cartesian_jacobian,
    stack_last,
    wrap_angle,
)


def same_line_angle(psi: np.ndarray, expected: np.ndarray) -> np.ndarray:
    """Distance between line angles modulo pi."""
    return np.abs(wrap_angle(2.0 * (np.asarray(psi) - expected))) / 2.0


def test_wrap_angle_edges():
    assert wrap_angle(np.pi) == -np.pi
    assert wrap_angle(-np.pi) == -np.pi
    assert wrap_angle(0.0) == 0.0
    assert wrap_angle(3 * np.pi) == pytest.approx(-np.pi)
    assert wrap_angle(2 * np.pi + 0.25) == pytest.approx(0.25)
    assert wrap_angle(-2 * np.pi - 0.25) == pytest.approx(-0.25)
    tiny = wrap_angle(-np.pi - 1e-17)  # rounds to 2 pi inside np.mod
    assert -np.pi <= tiny < np.pi
    a = np.linspace(-20.0, 20.0, 1001)
    w = wrap_angle(a)
    assert w.shape == a.shape
    assert np.all(w >= -np.pi) and np.all(w < np.pi)
    np.testing.assert_allclose(np.cos(w), np.cos(a), atol=1e-12)
    np.testing.assert_allclose(np.sin(w), np.sin(a), atol=1e-12)


def test_polar_cartesian_round_trip_batched():
    rng = np.random.default_rng(0)
    r = rng.uniform(0.5, 30.0, size=(4, 50))
    phi = rng.uniform(-np.pi / 2, np.pi / 2, size=(4, 50))
    poses = np.column_stack([rng.normal(size=(4, 2)) * 5, rng.uniform(-np.pi, np.pi, 4)])
    pts = polar_to_cartesian(r, phi, poses)
    assert pts.shape == (4, 50, 2)
    # SPEC 3.2.1 for one beam.
    x, y, th = poses[2]
    expected = [x + r[2, 7] * np.cos(th + phi[2, 7]), y + r[2, 7] * np.sin(th + phi[2, 7])]
    np.testing.assert_allclose(pts[2, 7], expected, rtol=1e-14)
    r2, phi2 = cartesian_to_polar(pts, poses)
    np.testing.assert_allclose(r2, r, rtol=1e-12)
    np.testing.assert_allclose(phi2, phi, atol=1e-12)
    # Single pose broadcast against beams.
    one = polar_to_cartesian(r[0], phi[0], poses[0])
    np.testing.assert_allclose(one, pts[0])


def test_polar_to_cartesian_jacobian_matches_finite_differences():
    r, phi, pose = np.array([10.0, 3.0]), np.array([0.5, -1.2]), np.array([1.0, 2.0, 0.3])
    J = polar_to_cartesian_jacobian(r, phi, pose)
    h = 1e-6
    dr = (polar_to_cartesian(r + h, phi, pose) - polar_to_cartesian(r - h, phi, pose)) / (2 * h)
    dphi = (polar_to_cartesian(r, phi + h, pose) - polar_to_cartesian(r, phi - h, pose)) / (2 * h)
    np.testing.assert_allclose(J[..., 0], dr, atol=1e-8)
    np.testing.assert_allclose(J[..., 1], dphi, atol=1e-8)


def test_directions_and_normals():
    psi = np.array([0.0, np.pi / 2, 2.0])
    d, nrm = line_direction(psi), line_normal(psi)
    np.testing.assert_allclose(np.sum(d * nrm, axis=-1), 0.0, atol=1e-15)
    np.testing.assert_allclose(np.linalg.norm(d, axis=-1), 1.0)
    # The normal is the direction rotated +90 deg (counter-clockwise).
    np.testing.assert_allclose(nrm, line_direction(psi + np.pi / 2), atol=1e-15)


def test_fit_line_vertical_and_horizontal_are_exact():
    y = np.linspace(-3.0, 4.0, 9)
    vertical = np.column_stack([np.full_like(y, 0.1), y])
    p0, psi = fit_line(vertical)
    assert psi == np.pi / 2
    assert p0[0] == 0.1
    # cos(float(pi/2)) = 6e-17, so the distances are zero to round-off only.
    np.testing.assert_allclose(perpendicular_distance(vertical, p0, psi), 0.0, atol=1e-15)
    horizontal = np.column_stack([y, np.full_like(y, -7.3)])
    p0, psi = fit_line(horizontal)
    assert psi == 0.0
    assert p0[1] == -7.3
    np.testing.assert_array_equal(perpendicular_distance(horizontal, p0, psi), 0.0)


@pytest.mark.parametrize("angle", [0.3, 1.2, np.pi / 2 - 1e-7, 2.5, np.pi - 1e-6, 1e-7, -0.4])
def test_fit_line_recovers_noiseless_lines(angle):
    t = np.linspace(-2.0, 5.0, 12)
    base = np.array([3.0, -1.0])
    points = base + t[:, None] * np.array([np.cos(angle), np.sin(angle)])
    p0, psi = fit_line(points)
    assert 0.0 <= psi <= np.pi
    assert same_line_angle(psi, angle) < 1e-13
    np.testing.assert_allclose(p0, points.mean(axis=0), atol=1e-14)
    assert np.max(np.abs(perpendicular_distance(points, p0, psi))) < 1e-13


def test_fit_line_is_principal_axis_batched_and_degenerate():
    rng = np.random.default_rng(1)
    points = rng.normal(size=(6, 20, 2)) * np.array([3.0, 0.5])
    rot = rng.uniform(0, np.pi, 6)
    c, s = np.cos(rot), np.sin(rot)
    R = np.stack([np.stack([c, -s], -1), np.stack([s, c], -1)], -2)
    points = points @ np.swapaxes(R, -1, -2)
    p0, psi = fit_line(points)
    assert psi.shape == (6,)
    for k in range(6):
        w, V = np.linalg.eigh(np.cov(points[k].T))
        major = V[:, np.argmax(w)]
        assert abs(abs(np.dot(major, line_direction(psi[k]))) - 1.0) < 1e-12
    # Fully degenerate scatter (all points equal): c = 0 gives psi = 0.
    same = np.tile([[2.0, 3.0]], (4, 1))
    assert fit_line(same)[1] == 0.0
    with pytest.raises(ValueError, match="at least 2"):
        fit_line(np.zeros((1, 2)))


def test_line_through_and_perpendicular_distance_sign():
    p0, psi = line_through(np.array([0.0, 0.0]), np.array([2.0, 2.0]))
    assert psi == pytest.approx(np.pi / 4)
    np.testing.assert_array_equal(p0, [0.0, 0.0])
    d = perpendicular_distance(np.array([[0.0, 1.0], [1.0, 0.0]]), p0, psi)
    np.testing.assert_allclose(d, [np.sqrt(0.5), -np.sqrt(0.5)])
    with pytest.raises(ValueError, match="coincide"):
        line_through(np.ones(2), np.ones(2))


def test_intersections_of_l_shape_at_true_corner():
    corner = np.array([4.0, 2.0])
    t = np.linspace(0.2, 3.0, 10)[:, None]
    leg_a = corner + t * np.array([np.cos(0.4), np.sin(0.4)])
    leg_b = corner + t * np.array([np.cos(0.4 + np.pi / 2), np.sin(0.4 + np.pi / 2)])
    (pa, sa), (pb, sb) = fit_line(leg_a), fit_line(leg_b)
    point, ok = intersect_lines(pa, sa, pb, sb, parallel_sin_min=0.05)
    assert ok
    np.testing.assert_allclose(point, corner, atol=1e-12)
    # Symmetric in the two lines.
    point2, _ = intersect_lines(pb, sb, pa, sa)
    np.testing.assert_allclose(point2, corner, atol=1e-12)


def test_intersect_matches_spec_formula_batched():
    rng = np.random.default_rng(2)
    p0a, p0b = rng.normal(size=(2, 30, 2))
    psia, psib = rng.uniform(-np.pi, np.pi, size=(2, 30))
    point, ok = intersect_lines(p0a, psia, p0b, psib, 0.05)
    R = np.array([[0.0, 1.0], [-1.0, 0.0]])
    da, db = line_direction(psia), line_direction(psib)
    for k in np.flatnonzero(ok):
        factor = (p0b[k] - p0a[k]) @ R @ db[k] / (da[k] @ R @ db[k])
        np.testing.assert_allclose(point[k], factor * da[k] + p0a[k], rtol=1e-12, atol=1e-12)
    assert np.array_equal(ok, np.abs(np.sin(psib - psia)) > 0.05)


def test_parallel_lines_are_detected():
    p0a = np.array([[0.0, 0.0], [0.0, 0.0], [0.0, 0.0]])
    p0b = np.array([[0.0, 1.0], [0.0, 1.0], [0.0, 1.0]])
    psia = np.array([0.3, 0.3, 0.3])
    psib = np.array([0.3, 0.3 + np.pi, 0.3 + 0.01])
    point, ok = intersect_lines(p0a, psia, p0b, psib, parallel_sin_min=0.05)
    np.testing.assert_array_equal(ok, [False, False, False])
    assert np.all(np.isnan(point))
    point, ok = intersect_lines(p0a, psia, p0b, psib)
    np.testing.assert_array_equal(ok, [False, False, True])
    assert np.all(np.isfinite(point[2]))


@pytest.mark.parametrize("angle", [0.0, 0.7, np.pi / 2, 2.9])
def test_fit_line_jacobian_matches_finite_differences(angle):
    rng = np.random.default_rng(3)
    t = np.linspace(-1.5, 2.0, 8)
    points = np.array([1.0, 2.0]) + t[:, None] * np.array([np.cos(angle), np.sin(angle)])
    points = points + rng.normal(scale=0.05, size=points.shape)
    p0, psi = fit_line(points)
    J = fit_line_jacobian(points, p0, psi)
    assert J.shape == (3, 8, 2)
    h = 1e-6
    numeric = np.zeros_like(J)
    for k in range(8):
        for j in range(2):
            plus, minus = points.copy(), points.copy()
            plus[k, j] += h
            minus[k, j] -= h
            (pp, sp), (pm, sm) = fit_line(plus), fit_line(minus)
            numeric[:2, k, j] = (pp - pm) / (2 * h)
            numeric[2, k, j] = wrap_angle(2 * (sp - sm)) / 2 / (2 * h)
    np.testing.assert_allclose(J, numeric, atol=1e-7)


def test_fit_line_jacobian_batched_and_isotropic():
    rng = np.random.default_rng(4)
    points = rng.normal(size=(3, 6, 2)) * np.array([2.0, 0.3])
    p0, psi = fit_line(points)
    J = fit_line_jacobian(points, p0, psi)
    assert J.shape == (3, 3, 6, 2)
    np.testing.assert_allclose(J[1], fit_line_jacobian(points[1], p0[1], psi[1]))
    square = np.array([[1.0, 0.0], [0.0, 1.0], [-1.0, 0.0], [0.0, -1.0]])
    with pytest.raises(ValueError, match="equal eigenvalues"):
        fit_line_jacobian(square, *fit_line(square))


def test_wrap_angle_of_one_float_matches_the_array_path_bitwise():
    rng = np.random.default_rng(5)
    k = np.arange(-20, 21) * np.pi
    angles = np.concatenate(
        [
            rng.normal(0.0, 10.0, 2000),
            rng.normal(0.0, 1e-17, 200),
            np.nextafter(k, -np.inf),
            np.nextafter(k, np.inf),
            k,
            [0.0, -0.0, 1e300, -1e300],
        ]
    )
    for a in angles.tolist():
        scalar = wrap_angle(a)
        assert type(scalar) is np.float64
        reference = wrap_angle(np.array([a]))[0]
        assert scalar == reference and np.signbit(scalar) == np.signbit(reference)


@pytest.mark.parametrize("shape", [(5,), (0,), (1, 3), (4, 5), (3, 4, 2)])
@pytest.mark.parametrize("kind", ["contiguous", "strided", "transposed", "int"])
def test_stack_last_matches_np_stack_with_its_layout(shape, kind):
    rng = np.random.default_rng(11)
    if kind == "contiguous":
        arrays = [rng.random(shape) for _ in range(3)]
    elif kind == "strided":
        arrays = [rng.random(tuple(2 * n for n in shape))[(slice(None, None, 2),) * len(shape)]]
        arrays *= 3
    elif kind == "transposed":
        arrays = [rng.random(shape[::-1]).T for _ in range(3)]
    else:
        arrays = [rng.integers(0, 9, shape) for _ in range(3)]
    expected = np.stack(arrays, axis=-1)
    got = stack_last(*arrays)
    assert got.dtype == expected.dtype and got.strides == expected.strides
    np.testing.assert_array_equal(got, expected)
