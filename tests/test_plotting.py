"""Plotting helpers: covariance ellipses (numbers) and what plot_model draws."""

from __future__ import annotations

import subprocess
import sys

import matplotlib.pyplot as plt
import numpy as np
import pytest
from _raycast import bearings_deg, cast
from matplotlib.image import imread
from matplotlib.patches import Ellipse, Polygon

from vslam_gym.slam.config import SensorConfig
from vslam_gym.slam.creation import create_model
from vslam_gym.slam.landmark import LandmarkModel
from vslam_gym.slam.plotting import (
    PlotStyle,
    covariance_ellipse,
    plot_model,
    plot_models,
    scan_points,
)
from vslam_gym.slam.scan import Scan

SENSOR = SensorConfig()
PHI = bearings_deg()
POSE = np.array([0.0, 0.0, np.pi / 2])
ZIGZAG = np.array([(-3.0, 5.0), (-1.0, 6.5), (1.0, 5.5), (3.0, 7.0), (5.0, 6.0)])
ZIGZAG_EDGES = np.stack([ZIGZAG[:-1], ZIGZAG[1:]], axis=1)


@pytest.fixture(autouse=True)
def _close_figures():
    yield
    plt.close("all")


@pytest.fixture(scope="module")
def zigzag():
    """A noisy scan of the zig-zag, its segment and the fitted model."""
    rng = np.random.default_rng(7)
    r = cast(POSE, ZIGZAG_EDGES, PHI, SENSOR.max_range, SENSOR.sigma_range, 0.0, rng)
    scan = Scan.from_arrays(r, PHI, SENSOR)
    idx = np.flatnonzero(scan.returns)
    fit = create_model(scan, int(idx[0]), int(idx[-1]), POSE, SENSOR)
    return scan, fit


def rotation(deg: float) -> np.ndarray:
    a = np.deg2rad(deg)
    return np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])


def lines_by_style(ax):
    lines = ax.get_lines()
    solid = [ln for ln in lines if ln.get_linestyle() == "-"]
    dashed = [ln for ln in lines if ln.get_linestyle() == "--"]
    markers = [ln for ln in lines if ln.get_linestyle() == "None"]
    return solid, dashed, markers


# ------------------------------------------------------------------ covariance_ellipse


@pytest.mark.parametrize(
    "cov, n_sigma, expected",
    [
        (np.diag([4.0, 1.0]), 3.0, (12.0, 6.0, 0.0)),
        (np.diag([1.0, 4.0]), 3.0, (12.0, 6.0, 90.0)),
        (np.diag([0.25, 0.01]), 1.0, (1.0, 0.2, 0.0)),
    ],
)
def test_covariance_ellipse_axis_aligned(cov, n_sigma, expected):
    width, height, angle = covariance_ellipse(np.zeros(2), cov, n_sigma)
    np.testing.assert_allclose([width, height, angle], expected, atol=1e-9)


@pytest.mark.parametrize("deg", [30.0, -45.0, 60.0, 89.0, -89.0])
def test_covariance_ellipse_rotated(deg):
    """Major axis std 3, minor 1, rotated by ``deg``: 2-sigma ellipse is 12 x 4."""
    r = rotation(deg)
    cov = r @ np.diag([9.0, 1.0]) @ r.T
    width, height, angle = covariance_ellipse(np.array([5.0, -2.0]), cov, 2.0)
    assert width == pytest.approx(12.0)
    assert height == pytest.approx(4.0)
    assert angle == pytest.approx(deg)


def test_covariance_ellipse_contour_points_have_mahalanobis_n_sigma():
    """Points on the returned ellipse are exactly n_sigma from the mean."""
    cov = np.array([[0.5, 0.3], [0.3, 0.4]])
    mean = np.array([1.0, 2.0])
    width, height, angle = covariance_ellipse(mean, cov, 3.0)
    t = np.linspace(0.0, 2.0 * np.pi, 17)
    local = np.stack([0.5 * width * np.cos(t), 0.5 * height * np.sin(t)], axis=1)
    pts = mean + local @ rotation(angle).T
    d = pts - mean
    m2 = np.einsum("ni,ij,nj->n", d, np.linalg.inv(cov), d)
    np.testing.assert_allclose(m2, 9.0, rtol=1e-9)


def test_covariance_ellipse_singular_covariance_is_a_segment():
    width, height, angle = covariance_ellipse(np.zeros(2), np.array([[1.0, 1.0], [1.0, 1.0]]), 1)
    assert width == pytest.approx(2.0 * np.sqrt(2.0))
    assert height == pytest.approx(0.0, abs=1e-7)
    assert angle == pytest.approx(45.0)


@pytest.mark.parametrize(
    "mean, cov, n_sigma, match",
    [
        (np.zeros(3), np.eye(2), 3.0, "mean"),
        (np.zeros(2), np.eye(3), 3.0, "cov must have shape"),
        (np.zeros(2), np.array([[1.0, 0.5], [0.0, 1.0]]), 3.0, "symmetric"),
        (np.zeros(2), np.diag([1.0, -1.0]), 3.0, "positive semi-definite"),
        (np.zeros(2), np.array([[1.0, np.nan], [np.nan, 1.0]]), 3.0, "finite"),
        (np.zeros(2), np.eye(2), 0.0, "n_sigma"),
    ],
)
def test_covariance_ellipse_bad_input_raises(mean, cov, n_sigma, match):
    with pytest.raises(ValueError, match=match):
        covariance_ellipse(mean, cov, n_sigma)


# ------------------------------------------------------------------------- plot_model


def test_plot_model_draws_solid_object_and_dashed_unknown_lines(zigzag):
    _, fit = zigzag
    model = fit.model
    assert fit.n_object_lines == 4
    ax = plot_model(fit.model)
    solid, dashed, markers = lines_by_style(ax)
    # Object edge on both sides: two unknown lines per side, four object lines.
    assert len(solid) == 4 == int(np.sum(model.u <= 0.5))
    assert len(dashed) == 4 == int(np.sum(model.u > 0.5))
    assert len(markers) == 1
    np.testing.assert_allclose(markers[0].get_xydata(), model.mean)
    # The solid lines join consecutive object vertices.
    start, stop = fit.object_vertices
    obj = model.mean[start:stop]
    for j, line in enumerate(solid):
        np.testing.assert_allclose(line.get_xydata(), obj[j : j + 2])
    assert ax.get_aspect() == 1.0


def test_plot_model_ellipses_match_vertex_covariances(zigzag):
    _, fit = zigzag
    model = fit.model
    ax = plot_model(model, n_sigma=2.0)
    ellipses = [p for p in ax.patches if isinstance(p, Ellipse)]
    assert len(ellipses) == model.n_vertices == 9
    for i, e in enumerate(ellipses):
        width, height, angle = covariance_ellipse(model.mean[i], model.vertex_cov(i), 2.0)
        np.testing.assert_allclose(e.center, model.mean[i])
        assert (e.width, e.height, e.angle) == pytest.approx((width, height, angle))
        # 2-sigma along the major axis is twice the largest vertex standard deviation.
        assert e.width == pytest.approx(4.0 * np.sqrt(np.linalg.eigvalsh(model.vertex_cov(i))[-1]))


def test_plot_model_can_leave_out_unknown_vertex_ellipses_and_fade_unknown_lines(zigzag):
    _, fit = zigzag
    model = fit.model
    style = PlotStyle(unknown_alpha=0.25, unknown_ellipses=False)
    ax = plot_model(model, n_sigma=2.0, style=style)
    start, stop = fit.object_vertices  # the object lines join vertices start..stop-1
    ellipses = [p for p in ax.patches if isinstance(p, Ellipse)]
    assert len(ellipses) == stop - start == 5 < model.n_vertices
    np.testing.assert_allclose([e.center for e in ellipses], model.mean[start:stop])
    solid, dashed, _ = lines_by_style(ax)
    assert {ln.get_alpha() for ln in dashed} == {0.25}
    assert {ln.get_alpha() for ln in solid} == {1.0}


def test_plot_model_threshold_and_label(zigzag):
    _, fit = zigzag
    ax = plot_model(fit, unknown_threshold=1.0, label="zig-zag", color="r")
    solid, dashed, _ = lines_by_style(ax)
    assert len(solid) == fit.model.n_lines and not dashed
    labelled = [ln for ln in ax.get_lines() if ln.get_label() == "zig-zag"]
    assert len(labelled) == 1
    handles, labels = ax.get_legend_handles_labels()
    assert labels == ["zig-zag"]
    assert all(ln.get_color() == "r" for ln in ax.get_lines())


def test_plot_model_draws_measurements_and_pose(zigzag):
    scan, fit = zigzag
    ax = plot_model(fit.model, scan=scan, pose=POSE)
    _, _, markers = lines_by_style(ax)
    assert len(markers) == 2
    pts = markers[1].get_xydata()
    assert pts.shape == (int(scan.returns.sum()), 2)
    np.testing.assert_allclose(pts, scan_points(scan, POSE))
    # The noisy points lie on the zig-zag (range noise 3 cm).
    y_true = np.interp(pts[:, 0], ZIGZAG[:, 0], ZIGZAG[:, 1])
    assert np.max(np.abs(pts[:, 1] - y_true)) < 0.2
    triangles = [p for p in ax.patches if isinstance(p, Polygon)]
    assert len(triangles) == 1
    corners = triangles[0].get_xy()[:3]
    # The triangle's tip (first corner) points along the heading (+y here).
    assert corners[0, 1] > max(corners[1, 1], corners[2, 1])
    np.testing.assert_allclose(corners.mean(axis=0)[0], POSE[0], atol=1e-12)


def test_plot_model_closed_polygon_and_bad_input():
    mean = np.array([[0.0, 0.0], [2.0, 0.0], [1.0, 1.5]])
    model = LandmarkModel(mean, 0.01 * np.eye(6), np.array([0.0, 0.0, 1.0]), closed=True)
    _, ax = plt.subplots()
    assert plot_model(model, ax) is ax
    solid, dashed, _ = lines_by_style(ax)
    assert (len(solid), len(dashed)) == (2, 1)
    np.testing.assert_allclose(dashed[0].get_xydata(), mean[[2, 0]])
    with pytest.raises(ValueError, match="pose"):
        plot_model(model, ax, scan=Scan.from_arrays(np.ones(3), PHI[:3], SENSOR))
    with pytest.raises(ValueError, match="n_sigma"):
        plot_model(model, ax, n_sigma=-1.0)
    with pytest.raises(ValueError, match="unknown_threshold"):
        plot_model(model, ax, unknown_threshold=1.5)
    with pytest.raises(ValueError, match="LandmarkModel"):
        plot_model(mean, ax)


def test_plot_models_cycles_colors_and_draws_scan_once(zigzag):
    scan, fit = zigzag
    shifted = fit.model.copy()
    shifted.mean = shifted.mean + np.array([0.0, 3.0])
    ax = plot_models([fit.model, shifted], scan=scan, pose=POSE, label="models")
    solid, dashed, markers = lines_by_style(ax)
    assert len(solid) == 8 and len(dashed) == 8
    assert len(markers) == 3  # two vertex sets, one set of measurements
    assert {ln.get_color() for ln in solid} == {"C0", "C1"}
    assert sum(isinstance(p, Polygon) for p in ax.patches) == 1
    assert ax.get_legend_handles_labels()[1] == ["models"]


def test_saving_a_figure_to_png(zigzag, tmp_path):
    scan, fit = zigzag
    fig, ax = plt.subplots(figsize=(4, 3), dpi=50)
    plot_model(fit.model, ax, scan=scan, pose=POSE, label="landmark")
    ax.legend()
    path = tmp_path / "model.png"
    fig.savefig(path)
    image = imread(path)
    assert image.shape[:2] == (150, 200)
    assert image[..., :3].std() > 0  # something was drawn


def test_slam_package_imports_without_matplotlib():
    code = (
        "import sys; import vslam_gym.slam.plotting, vslam_gym.slam.creation; "
        "sys.exit('matplotlib' in sys.modules)"
    )
    assert subprocess.run([sys.executable, "-c", code], check=False).returncode == 0
