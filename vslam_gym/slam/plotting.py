"""Matplotlib drawings of landmark models, in the style of the thesis figures.

Object lines (``u <= unknown_threshold``) are solid, unknown lines dashed; each vertex
gets a marker and its ``n_sigma`` covariance ellipse. Optionally the measurements of a
scan (as world-frame points) and the lidar pose (a small triangle pointing along the
heading) are drawn too. Everything is in the world frame, in metres, on equal axes.

Matplotlib is imported inside the drawing functions only, so that ``vslam_gym.slam``
imports without it; :func:`covariance_ellipse` is pure numpy.

Example::

    fit = create_model(scan, first, last, pose, sensor)
    ax = plot_model(fit.model, scan=scan, pose=fit.pose, label="landmark")
    ax.figure.savefig("landmark.png")
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from vslam_gym.slam.geometry import check_pose
from vslam_gym.slam.landmark import LandmarkModel, ModelFit
from vslam_gym.slam.scan import Scan

if TYPE_CHECKING:
    from matplotlib.axes import Axes

__all__ = ["PlotStyle", "covariance_ellipse", "plot_model", "plot_models", "scan_points"]

# Relative tolerances of the covariance checks in covariance_ellipse.
_SYMMETRY_RTOL = 1e-9
_PSD_RTOL = 1e-12
# Default colours of plot_models cycle through matplotlib's "C0".."C9".
_N_CYCLE_COLORS = 10


@dataclass(frozen=True)
class PlotStyle:
    """Appearance of :func:`plot_model` drawings.

    Attributes:
        line_width: width of object and unknown lines [points].
        unknown_linestyle: matplotlib line style of unknown lines.
        vertex_marker: marker of the vertex means.
        vertex_marker_size: its size [points].
        ellipse_line_width: edge width of the vertex ellipses [points].
        ellipse_alpha: opacity of the vertex ellipses, in [0, 1].
        unknown_alpha: opacity of unknown lines, in [0, 1].
        unknown_ellipses: draw the ellipses of vertices on no object line too (an
            unknown line's far end is a ray's maximum range, with an ellipse metres
            long); False draws only the object vertices' ellipses.
        measurement_marker: marker of the scan's world-frame points.
        measurement_marker_size: its size [points].
        measurement_color: colour of the scan's points.
        pose_length: length of the lidar-pose triangle along the heading [m].
        pose_color: colour of the lidar-pose triangle.
    """

    line_width: float = 1.5
    unknown_linestyle: str = "--"
    vertex_marker: str = "o"
    vertex_marker_size: float = 3.0
    ellipse_line_width: float = 0.8
    ellipse_alpha: float = 0.8
    unknown_alpha: float = 1.0
    unknown_ellipses: bool = True
    measurement_marker: str = "."
    measurement_marker_size: float = 3.0
    measurement_color: str = "k"
    pose_length: float = 0.4
    pose_color: str = "k"


def covariance_ellipse(
    mean: np.ndarray, cov: np.ndarray, n_sigma: float = 3.0
) -> tuple[float, float, float]:
    """Size and orientation of the ``n_sigma`` contour of a 2-D Gaussian.

    The contour ``(x - mean)^T cov^-1 (x - mean) = n_sigma^2`` is an ellipse centred at
    ``mean`` whose axes are ``n_sigma`` standard deviations along the eigenvectors of
    ``cov``; the result matches ``matplotlib.patches.Ellipse(mean, width, height,
    angle=angle_deg)``.

    Args:
        mean: ``(2,)`` centre [m] (checked for shape and finiteness; it does not change
            the size or orientation).
        cov: ``(2, 2)`` symmetric positive semi-definite covariance [m^2].
        n_sigma: number of standard deviations of the contour, > 0.

    Returns:
        ``(width, height, angle_deg)``: the full length [m] of the major axis, of the
        minor axis, and the angle of the major axis from the +x axis [deg], in
        ``(-90, 90]`` (counter-clockwise positive). For an isotropic covariance the
        angle is arbitrary.

    Raises:
        ValueError: wrong shapes, non-finite values, ``n_sigma <= 0``, or a covariance
            that is not symmetric positive semi-definite.
    """
    mean = np.asarray(mean, dtype=float)
    cov = np.asarray(cov, dtype=float)
    if mean.shape != (2,):
        raise ValueError(f"mean must have shape (2,), got {mean.shape}")
    if cov.shape != (2, 2):
        raise ValueError(f"cov must have shape (2, 2), got {cov.shape}")
    if not (np.isfinite(mean).all() and np.isfinite(cov).all()):
        raise ValueError(f"mean and cov must be finite, got mean={mean}, cov={cov.tolist()}")
    if not (np.isfinite(n_sigma) and n_sigma > 0):
        raise ValueError(f"n_sigma must be finite and > 0, got {n_sigma!r}")
    scale = float(np.abs(cov).max())
    if abs(cov[0, 1] - cov[1, 0]) > _SYMMETRY_RTOL * scale:
        raise ValueError(f"cov must be symmetric, got {cov.tolist()}")
    eigval, eigvec = np.linalg.eigh(0.5 * (cov + cov.T))  # ascending eigenvalues
    if eigval[0] < -_PSD_RTOL * scale:
        raise ValueError(f"cov must be positive semi-definite, got eigenvalues {eigval.tolist()}")
    minor, major = np.sqrt(np.maximum(eigval, 0.0))
    angle = float(np.degrees(np.arctan2(eigvec[1, 1], eigvec[0, 1])))
    if angle <= -90.0:
        angle += 180.0
    elif angle > 90.0:
        angle -= 180.0
    return 2.0 * n_sigma * float(major), 2.0 * n_sigma * float(minor), angle


def _as_model(model: LandmarkModel | ModelFit) -> LandmarkModel:
    if isinstance(model, ModelFit):
        return model.model
    if not isinstance(model, LandmarkModel):
        raise ValueError(f"model must be a LandmarkModel or ModelFit, got {type(model).__name__}")
    return model


def scan_points(scan: Scan, pose: np.ndarray) -> np.ndarray:
    """World-frame points ``(m, 2)`` [m] of the beams of ``scan`` that have a return.

    Args:
        scan: the scan (lidar frame).
        pose: ``(3,)`` lidar pose ``[x, y, theta]`` in the world frame.
    """
    if not isinstance(scan, Scan):
        raise ValueError(f"scan must be a Scan, got {type(scan).__name__}")
    pose = check_pose(pose)
    hit = scan.returns
    r = scan.ranges[hit]
    a = pose[2] + scan.bearings[hit]
    return np.stack([pose[0] + r * np.cos(a), pose[1] + r * np.sin(a)], axis=1)


def _pose_triangle(pose: np.ndarray, length: float) -> np.ndarray:
    """``(3, 2)`` world-frame corners of a triangle pointing along the pose's heading."""
    local = length * np.array([[0.5, 0.0], [-0.5, 0.3], [-0.5, -0.3]])
    c, s = np.cos(pose[2]), np.sin(pose[2])
    return pose[:2] + local @ np.array([[c, s], [-s, c]])


def plot_model(
    model: LandmarkModel | ModelFit,
    ax: Axes | None = None,
    *,
    scan: Scan | None = None,
    pose: np.ndarray | None = None,
    n_sigma: float = 3.0,
    unknown_threshold: float = 0.5,
    color: Any = None,
    label: str | None = None,
    style: PlotStyle | None = None,
) -> Axes:
    """Draw a landmark model (world frame, metres) like the thesis figures.

    Draws one ``Line2D`` per model line (solid for object lines,
    ``u <= unknown_threshold``; dashed for unknown lines), one ``Line2D`` of vertex
    markers and one ``Ellipse`` patch per vertex (its ``n_sigma`` contour; with
    ``style.unknown_ellipses`` False only per vertex of an object line). With
    ``scan`` and ``pose`` the scan's returns are drawn as world-frame points (one
    ``Line2D``); with ``pose`` the lidar pose is drawn as a triangle (a ``Polygon``
    patch) pointing along the heading. The axes get an equal aspect ratio.

    Args:
        model: the landmark model, or a ``ModelFit`` (its model is drawn).
        ax: axes to draw into; the current axes (``plt.gca()``) when omitted.
        scan: optional scan whose returns are drawn; needs ``pose``.
        pose: ``(3,)`` lidar pose ``[x, y, theta]`` (world frame) of ``scan``; drawn as a
            triangle when given.
        n_sigma: standard deviations of the vertex ellipses.
        unknown_threshold: lines with ``u`` above it are drawn dashed.
        color: any matplotlib colour of lines, vertices and ellipses; ``"C0"`` when
            omitted.
        label: legend label, attached to the first object line (or the first line when
            there is none) so that the model appears once in a legend.
        style: widths, markers and sizes; :class:`PlotStyle` defaults when omitted.

    Returns:
        The axes drawn into.

    Raises:
        ValueError: bad model, scan or pose, ``scan`` without ``pose``, ``n_sigma <= 0``
            or ``unknown_threshold`` outside ``[0, 1]``.
    """
    from matplotlib.patches import Ellipse, Polygon

    model = _as_model(model)
    style = style or PlotStyle()
    if not (np.isfinite(n_sigma) and n_sigma > 0):
        raise ValueError(f"n_sigma must be finite and > 0, got {n_sigma!r}")
    if not 0.0 <= unknown_threshold <= 1.0:
        raise ValueError(f"unknown_threshold must lie in [0, 1], got {unknown_threshold!r}")
    if scan is not None and pose is None:
        raise ValueError("drawing a scan needs the lidar pose it was taken from (pose=...)")
    points = scan_points(scan, pose) if scan is not None else None
    pose_arr = check_pose(pose) if pose is not None else None
    unknown = model.is_unknown(unknown_threshold)
    ends = model.line_vertices()
    drawn = np.ones(model.n_vertices, dtype=bool)
    if not style.unknown_ellipses:
        drawn[:] = False
        drawn[ends[~unknown].ravel()] = True
    ellipses = [
        (model.mean[i], covariance_ellipse(model.mean[i], model.vertex_cov(i), n_sigma))
        for i in np.flatnonzero(drawn)
    ]
    if ax is None:
        import matplotlib.pyplot as plt

        ax = plt.gca()
    color = "C0" if color is None else color

    label_line = int(np.argmin(unknown)) if model.n_lines else -1
    for j, (a, b) in enumerate(ends):
        xy = model.mean[[a, b]]
        ax.plot(
            xy[:, 0],
            xy[:, 1],
            linestyle=style.unknown_linestyle if unknown[j] else "-",
            linewidth=style.line_width,
            color=color,
            alpha=style.unknown_alpha if unknown[j] else 1.0,
            label=label if j == label_line else None,
        )
    ax.plot(
        model.mean[:, 0],
        model.mean[:, 1],
        linestyle="None",
        marker=style.vertex_marker,
        markersize=style.vertex_marker_size,
        color=color,
    )
    for centre, (width, height, angle) in ellipses:
        ax.add_patch(
            Ellipse(
                tuple(centre),
                width,
                height,
                angle=angle,
                fill=False,
                edgecolor=color,
                linewidth=style.ellipse_line_width,
                alpha=style.ellipse_alpha,
            )
        )
    if points is not None:
        ax.plot(
            points[:, 0],
            points[:, 1],
            linestyle="None",
            marker=style.measurement_marker,
            markersize=style.measurement_marker_size,
            color=style.measurement_color,
        )
    if pose_arr is not None:
        ax.add_patch(
            Polygon(
                _pose_triangle(pose_arr, style.pose_length), closed=True, color=style.pose_color
            )
        )
    ax.set_aspect("equal")
    ax.autoscale_view()
    return ax


def plot_models(
    models: Iterable[LandmarkModel | ModelFit], ax: Axes | None = None, **kwargs: Any
) -> Axes:
    """Draw several landmark models into one axes with :func:`plot_model`.

    Args:
        models: the models (or ``ModelFit`` objects).
        ax: axes to draw into; the current axes when omitted.
        **kwargs: keyword arguments of :func:`plot_model`. ``scan`` and the pose are
            drawn once (with the first model). Without ``color`` model ``i`` gets
            ``"C{i mod 10}"``; with it all models share it. ``label`` goes to the first
            model only.

    Returns:
        The axes drawn into.
    """
    if ax is None:
        import matplotlib.pyplot as plt

        ax = plt.gca()
    color = kwargs.pop("color", None)
    for i, model in enumerate(models):
        if i > 0:
            kwargs.pop("scan", None)
            kwargs.pop("pose", None)
            kwargs.pop("label", None)
        model_color = f"C{i % _N_CYCLE_COLORS}" if color is None else color
        plot_model(model, ax, color=model_color, **kwargs)
    ax.set_aspect("equal")
    return ax
