"""Typed configuration of the estimator; every threshold of the thesis lives here.

Defaults are the thesis values (SPEC.md, thesis chapters 3-4) except for the measured
improvements listed in :meth:`ModelConfig.thesis`, which returns the faithful thesis
configuration. Build from a plain mapping with :meth:`SensorConfig.from_dict` /
:meth:`ModelConfig.from_dict`; unknown keys raise with a "did you mean" suggestion.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from vslam_gym.config_utils import (
    check_field_types,
    check_integers,
    check_intervals,
    dataclass_from_dict,
)

LINEARIZATIONS = ("ut", "jacobian")
PREALIGN_MODES = ("none", "odometry", "fuse")
"""``FilterConfig.prealign``: whole-scan alignment before the landmark association."""
KEYFRAME_CORRECTIONS = ("none", "time", "variance")
"""``FilterConfig.loop_correct_keyframes``: how a loop closure's correction is spread."""
ASSOCIATION_POSES = ("icp", "predicted", "predicted_first")
"""``FilterConfig.association_pose``: where a set is tested against a candidate."""
REFERENCES = ("point", "pose")
"""``FilterConfig.reference``: what a landmark's reference in the state is."""
NEW_LANDMARKS = ("thesis", "augment", "halved")
"""``FilterConfig.new_landmark``: how a new landmark enters the state."""


@dataclass(frozen=True)
class SensorConfig:
    """The lidar as the estimator sees it (SPEC section 0).

    Attributes:
        fov_deg: full field of view [deg]; beams span ``[-fov/2, +fov/2]``.
        resolution_deg: angle between adjacent beams ``phi_res`` [deg].
        max_range: ``r_max`` [m]; readings at or beyond it are "no return".
        sigma_range: range noise standard deviation ``sigma_r`` [m].
        sigma_bearing_deg: bearing noise standard deviation ``sigma_phi`` [deg].
        lidar_offset: pose of the lidar in the robot frame ``(x [m], y [m], theta [rad])``;
            zero in simulation (lidar at the robot centre).
    """

    fov_deg: float = 180.0
    resolution_deg: float = 1.0
    max_range: float = 30.0
    sigma_range: float = 0.03
    sigma_bearing_deg: float = 0.2
    lidar_offset: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def __post_init__(self) -> None:
        check_field_types(self)
        for name in ("fov_deg", "resolution_deg", "max_range", "sigma_range", "sigma_bearing_deg"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value > 0):
                raise ValueError(f"SensorConfig.{name} must be finite and > 0, got {value!r}")
        if self.fov_deg > 360.0:
            raise ValueError(f"SensorConfig.fov_deg must be at most 360, got {self.fov_deg!r}")
        if self.resolution_deg > self.fov_deg:
            raise ValueError(
                f"SensorConfig.resolution_deg must be at most fov_deg ({self.fov_deg!r}), "
                f"got {self.resolution_deg!r}"
            )
        try:
            offset = np.asarray(self.lidar_offset, dtype=float)
        except (TypeError, ValueError):
            offset = np.zeros(0)
        if offset.shape != (3,) or not np.isfinite(offset).all():
            raise ValueError(
                f"SensorConfig.lidar_offset must be 3 finite numbers, got {self.lidar_offset!r}"
            )

    @property
    def phi_res(self) -> float:
        """Angular resolution [rad]."""
        return float(np.deg2rad(self.resolution_deg))

    @property
    def half_fov(self) -> float:
        """``phi_FOV`` [rad]: bearings lie in ``[-half_fov, +half_fov]``."""
        return float(np.deg2rad(self.fov_deg) / 2.0)

    @property
    def sigma_bearing(self) -> float:
        """Bearing noise standard deviation [rad]."""
        return float(np.deg2rad(self.sigma_bearing_deg))

    @property
    def polar_variances(self) -> tuple[float, float]:
        """``(sigma_r^2 [m^2], sigma_phi^2 [rad^2])``: the diagonal of :attr:`Q`."""
        return (self.sigma_range**2, self.sigma_bearing**2)

    @property
    def Q(self) -> np.ndarray:  # noqa: N802 - the thesis's name
        """Per-beam measurement covariance ``diag(sigma_r^2, sigma_phi^2)`` for ``[r, phi]``."""
        return np.diag(self.polar_variances)

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> SensorConfig:
        """Build from a mapping; unknown keys raise ``UnknownKeyError``."""
        return dataclass_from_dict(cls, data)


@dataclass(frozen=True)
class ModelConfig:
    """Landmark-model parameters (thesis chapter 3, SPEC sections 1-9).

    Attributes:
        linearization: how Gaussians are mapped through nonlinear functions: ``"ut"``
            (the thesis's unscented transform) or ``"jacobian"`` (first order; default).
        ut_beta: UT ``beta`` (2: optimal for Gaussians).
        ut_kappa: UT ``kappa`` (0 in the thesis).
        ut_alpha_squared_times_n: ``alpha^2 * n``; 1 gives the thesis's
            ``lambda = 1 - n`` (sigma points on the 1-sigma contour).
        alpha_bic: scale of the BIC complexity penalty (SPEC section 5). The thesis
            shows 1, 0.5, 0.15 and 0 and argues for a weak penalty (too many lines
            still describe the landmark, too few do not); 0.5 is our default.
        grouping_mahalanobis: Algorithm 3: largest Mahalanobis distance of a point's
            perpendicular error to the group line for the point to join the group
            (1 in the thesis).
        min_group_size: Algorithm 3: measurements a group starts with.
        unknown_d_low: fitted-line length per measurement gap [m] below which the line
            is an object line (``u = 0``), at ``unknown_reference_resolution_deg``.
        unknown_d_high: length per gap [m] above which the line is unknown (``u = 1``).
        unknown_reference_resolution_deg: resolution [deg] at which ``unknown_d_low`` and
            ``unknown_d_high`` hold; they scale linearly with the sensor resolution.
        unknown_threshold: a line with ``u > unknown_threshold`` counts as unknown.
        artificial_outer_offset: at an object edge (no return beside the landmark), the
            outer artificial vertex lies this many beams beyond the edge beam.
        detection_gate_sigma: angular gate of beam-to-line candidates, in standard
            deviations of the vertex bearings (3 in the thesis).
        detection_mean_max: detection accepts when the mean ``d_GM^2`` is at most this.
        detection_var_max: ... and its variance is at most this (3 in the thesis: for a
            consistent set ``d_GM^2`` is chi-square with one degree of freedom, variance
            2, and its sample variance is heavy-tailed: its 95th percentile is 4.4 for
            30 beams).
        detection_trim_fraction: the largest ``floor(this * n)`` of a set's ``n`` values
            of ``d_GM^2`` are left out of the mean and variance (0 in the thesis): one
            beam just past a model's end vertex makes the variance explode and the
            landmark is modelled again.
        vertex_match_mahalanobis: an existing end vertex stays when its perpendicular
            Mahalanobis distance to the newly observed end line is at most this.
        wrap_mahalanobis: first and last object vertices are folded into one (closing
            the polygon) when the Mahalanobis distance of their difference is below this.
        min_beams_per_line: a line counts as observed with at least this many beams.
        parallel_sin_min: adjacent lines whose directions differ by less than
            ``arcsin(parallel_sin_min)`` are treated as parallel (no vertex is
            computed from them). Not a thesis value: the thesis does not guard this.
        gm_mode_bracket_sigma: initial bracket ``[0, this * s]`` of the bisection for the
            mode of the unknown-line density.
        zero_range_vertex_sigma: standard deviation [m] added isotropically to the
            artificial zero-range vertex at the lidar position (landmark at the FOV
            limit). Its transformed covariance is singular (a zero range has no
            bearing spread), which no information form can hold. Not a thesis value.
        exclusive_boundaries: fit each object line's vertices without the boundary
            measurement it shares with its neighbour when that measurement lies on the
            neighbour's side (see ``creation.fit_slices``). False in the thesis, whose
            shared boundary measurement biases corner vertices.
        boundary_window: with ``exclusive_boundaries``, how many beams on each side of
            the shared measurement the split between two lines may move.
        coarseness: scale (in standard deviations) of each object line's model error,
            a random offset along its normal propagated to the vertices
            (``creation.coarseness_variances``): the thesis's future-work
            "coarseness"; 0 (off) in the thesis.
        coarseness_significance: a line's residuals count as model error only when their
            chi-square statistic exceeds this quantile.
        end_vertex_correction: in a model update, an object line's end vertex on the
            edge beam's ray is shifted by half a beam spacing along the line with that
            spread as variance, and end vertices seen at a grazing angle carry no
            information (``update._end_quantization``). The thesis keeps the edge ray's
            intersection with measurement-level variance, which biases it by up to a
            beam spacing (vertex NEES about 11 instead of 2 on re-observation).
        continuation_gate: in a model update, an end of a run of observed lines is not
            an observed end when the next beam out returns within this many range
            standard deviations (along its ray) of the end line's extension: the line
            goes on there, its beams associated with another line, and the end vertex
            only marks where the run stops (an existing end vertex then gets no
            information, like an occluded one). 0 (the thesis) takes every unoccluded
            run end as the line's end. Found in ``house`` (seed 0, step 406): a model
            folded into two overlapping lines of one wall split the wall's beams at
            beam 1, and the false end vertex pulled the pose heading by 0.09 rad at a
            heading standard deviation of 0.01 rad. Measured at 3 (``vslam-gym
            evaluate --set``, seeds 0-9, position ATE single_landmark / small / curved /
            house, default 0.243 / 0.129 / 0.099 / 0.274 m, house final error 0.474 m):
            with ``continuation_beams=1`` 0.286 / 0.145 / 0.103 / 0.201 m, house final
            error 0.329 m; with 2: 0.218 / 0.130 / 0.107 / 0.288 m, 0.445 m. Each
            helps somewhere and neither everywhere: not the default.
        continuation_beams: with ``continuation_gate``, this many beams beyond the end
            (those inside the field of view) must all lie on the extension; more spare
            the corners whose first beam round them lies close to the extension.
    """

    linearization: str = "jacobian"
    ut_beta: float = 2.0
    ut_kappa: float = 0.0
    ut_alpha_squared_times_n: float = 1.0
    alpha_bic: float = 0.5
    grouping_mahalanobis: float = 3.0
    min_group_size: int = 3
    unknown_d_low: float = 0.2
    unknown_d_high: float = 0.8
    unknown_reference_resolution_deg: float = 1.0
    unknown_threshold: float = 0.5
    artificial_outer_offset: int = 5
    detection_gate_sigma: float = 4.0
    detection_mean_max: float = 3.0
    detection_var_max: float = 6.0
    detection_trim_fraction: float = 0.05
    vertex_match_mahalanobis: float = 3.0
    wrap_mahalanobis: float = 3.0
    min_beams_per_line: int = 2
    parallel_sin_min: float = 0.05
    gm_mode_bracket_sigma: float = 5.0
    zero_range_vertex_sigma: float = 0.03
    exclusive_boundaries: bool = True
    boundary_window: int = 2
    coarseness: float = 2.0
    coarseness_significance: float = 0.9
    end_vertex_correction: bool = True
    continuation_gate: float = 0.0
    continuation_beams: int = 1

    def __post_init__(self) -> None:
        check_field_types(self)
        if self.linearization not in LINEARIZATIONS:
            raise ValueError(
                f"ModelConfig.linearization must be one of {LINEARIZATIONS}, "
                f"got {self.linearization!r}"
            )
        check_intervals(
            self,
            {
                "ut_beta": "(-inf, inf)",
                "ut_kappa": "(-inf, inf)",
                "ut_alpha_squared_times_n": "(0, inf)",
                "alpha_bic": "[0, inf)",
                "grouping_mahalanobis": "(0, inf)",
                "unknown_reference_resolution_deg": "(0, inf)",
                "unknown_threshold": "[0, 1]",
                "detection_gate_sigma": "(0, inf]",
                "detection_mean_max": "(0, inf]",
                "detection_var_max": "(0, inf]",
                "detection_trim_fraction": "[0, 1)",
                "vertex_match_mahalanobis": "(0, inf]",
                "wrap_mahalanobis": "(0, inf]",
                "parallel_sin_min": "[0, 1]",
                "gm_mode_bracket_sigma": "(0, inf)",
                "zero_range_vertex_sigma": "(0, inf)",
                "coarseness": "[0, inf)",
                "coarseness_significance": "(0, 1)",
            },
        )
        check_integers(
            self,
            {
                "min_group_size": 2,
                "artificial_outer_offset": 1,
                "min_beams_per_line": 1,
                "boundary_window": 0,
                "continuation_beams": 1,
            },
        )
        if not 0.0 <= self.unknown_d_low < self.unknown_d_high:
            raise ValueError("ModelConfig needs 0 <= unknown_d_low < unknown_d_high")
        if not (np.isfinite(self.continuation_gate) and self.continuation_gate >= 0.0):
            raise ValueError(
                f"ModelConfig.continuation_gate must be finite and >= 0, "
                f"got {self.continuation_gate!r}"
            )

    @classmethod
    def thesis(cls, **overrides: Any) -> ModelConfig:
        """The faithful thesis configuration.

        The defaults differ from it where an evaluation measured an improvement
        (``tests/test_creation.py``; figures in the README, "Presets"):

        - ``linearization="jacobian"``: first order agrees with the UT on every model
          (vertex means to 2 mm, standard deviations to 10 %) and is cheaper;
        - ``exclusive_boundaries=True``: the shared boundary measurement biases corner
          vertices; vertex NEES of a four-segment object falls from about 12 (2x
          overconfident, 6 expected) to about 6;
        - ``coarseness=2``: curved objects' vertices fall within 3 sigma of the object
          in most scans instead of almost none;
        - ``grouping_mahalanobis=3``: Algorithm 3 starts from a few lines instead of one
          per 2-3 beams; the same models come out of the selection (four lines in 100
          of 100 zig-zag scans, same NEES) at about half the cost;
        - ``detection_gate_sigma=4``, ``detection_var_max=6``: the same object seen from
          0.5 m and 10 degrees away is accepted in 97-100 % of trials instead of 76-86 %,
          different objects are still rejected in 100 % (``tests/test_detection.py``).
        """
        base = dict(
            linearization="ut",
            grouping_mahalanobis=1.0,
            exclusive_boundaries=False,
            coarseness=0.0,
            detection_gate_sigma=3.0,
            detection_var_max=3.0,
            detection_trim_fraction=0.0,
            end_vertex_correction=False,
        )
        base.update(overrides)
        return dataclass_from_dict(cls, base)

    def unknown_bounds(self, sensor: SensorConfig) -> tuple[float, float]:
        """``(d_low, d_high)`` [m per gap] scaled to the sensor's angular resolution."""
        scale = sensor.resolution_deg / self.unknown_reference_resolution_deg
        return self.unknown_d_low * scale, self.unknown_d_high * scale

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> ModelConfig:
        """Build from a mapping; unknown keys raise ``UnknownKeyError``."""
        return dataclass_from_dict(cls, data)


@dataclass(frozen=True)
class FilterConfig:
    """SLAM-filter parameters (thesis chapter 4, SPEC section 10).

    Attributes:
        odometry_alphas: Thrun's odometry-noise coefficients ``(a1, a2, a3, a4)`` of the
            motion update (match the robot; the simulator's default).
        odometry_sigma_floor: smallest standard deviation of each increment
            ``(rot1 [rad], trans [m], rot2 [rad])``, so a standing robot keeps a proper
            covariance. Not a thesis value.
        initial_pose_sigma: standard deviation of the initial pose ``(x [m], y [m],
            theta [rad])``; the map is anchored at the initial pose, so it is tiny.
        segment_angle_gap: largest bearing difference of two linked beams, in angular
            resolutions (thesis: 2).
        segment_distance_gap: largest distance [m] of two linked points (thesis: 1).
        segment_breakpoint_angle_deg: ``lambda`` [deg] of an adaptive breakpoint
            detector on top (:func:`~vslam_gym.slam.segmentation.segment_scan`): two
            points nearer than ``segment_distance_gap`` are still split when a surface
            seen at ``lambda`` degrees from the beam could not join them; 0 (the thesis)
            is off. In [0, 90). A third of the ``house`` sets hit two obstacles (a
            table before a wall joins at 1 m); 10 degrees makes that a fifth (15: a
            seventh). Measured at 10 (``vslam-gym evaluate --world house --seeds 0-19``,
            2026-11-26): association precision 0.866 -> 0.889 and duplicates 0.76 ->
            0.70, but position ATE 0.208 -> 0.350 m and final error 0.068 -> 0.347 m
            (three seeds end 1.6-2.1 m off): not the default.
        min_set_beams: ``n_thres``: sets with fewer beams are not used (thesis: 4).
        candidate_margin: a landmark is a correspondence candidate of a set when its
            reference is within its radius plus this margin [m] of the set centroid (the
            thesis gives no value).
        psi_thres_deg: a new landmark needs a summed absolute turn between consecutive
            fitted lines above this [deg] (the thesis gives no value).
        min_object_lines: an association updates the map only when at least this many
            object lines each get ``min_beams_per_object_line`` beams (thesis: 2 and 2).
        min_beams_per_object_line: see ``min_object_lines``.
        single_line_min_beams: when > 0, an association with fewer than
            ``min_object_lines`` such lines still updates the map when one object line
            gets at least this many beams: a long line fixes the heading and the
            distance to it, though not the position along it. On ``single_landmark``
            the set at the edge of the field of view often covers one long face of the
            object for 20-30 steps, "associated" but not updated, while the heading
            drifts with the odometry. 0 (the thesis): off. Measured (session 21,
            ``vslam-gym evaluate --seeds 0-9``, ``house`` 0-19, paired t; 6 / 10 / 15
            / 20 beams): at 10 the position ATE single_landmark / small / curved /
            house 0.176 / 0.095 / 0.103 / 0.208 -> 0.132 / 0.092 / 0.089 / 0.211 m
            (t -2.1 / -1.2 / -2.2 / +0.2), in a second round-off sample 0.176 / 0.096 /
            0.108 / 0.209 -> 0.132 / 0.095 / 0.097 / 0.184 m, with a higher mean pose
            NEES on ``house`` (384 -> 490, 333 -> 409); but the ``frontier`` agent on
            the 20 held-out random worlds mapped worse (coverage 0.327 -> 0.308,
            position ATE 0.109 -> 0.231 m, one world diverging to 2.1 m; 0.132 m
            without it), and the ``logs`` preset measured mixed (Intel better, the
            logged ACES run worse). The explorer's divergences were false revisit
            matches, which ``loop_prior_rival`` at 0.7 declines: together (session 22,
            10 and 0.7 against the default of 0 and 0.8, two round-off samples; paired
            t) the routes' position ATE went 0.173 / 0.098 / 0.101 / 0.229 -> 0.125 /
            0.093 / 0.103 / 0.191 m and 0.173 / 0.099 / 0.110 / 0.260 -> 0.125 / 0.096
            / 0.098 / 0.189 m (``house`` t -1.8 / -2.7), and the ``frontier`` agent's
            position ATE on the 40 held-out worlds 1000-1039 0.099 -> 0.091 m at the
            same coverage (0.312 -> 0.310). 10 by default; 0 in the ``thesis``,
            ``logs`` and ``fast`` presets (docs/measurements.md, "Updates from one long
            object line").
        update_max_correction_m2: a landmark update is rejected (outcome
            ``"rejected"``, the state left as before it) when it moves the pose mean
            further than the update itself accounts for: the squared Mahalanobis
            distance of the pose correction under its covariance (the prior pose
            covariance minus the posterior's) above this. A consistent update's
            correction has about 3 (chi-square, 3 dof; 16.3 is its 99.9 % point), but
            the filter is overconfident, and on ``house`` 2 % of the default's updates
            exceed 16.3. 0 (the thesis): not tested; 0 by default. Measured (session
            23; routes ``vslam-gym evaluate --seeds 0-9``, ``house`` 0-19, two round-off
            samples; the ``frontier`` agent on the 40 held-out worlds 1000-1039): at 50
            the routes are level (position ATE single_landmark / small / curved / house
            0.125 / 0.093 / 0.103 / 0.191 and 0.125 / 0.096 / 0.098 / 0.189 m ->
            0.125 / 0.094 / 0.103 / 0.166 and 0.125 / 0.095 / 0.101 / 0.198 m; ``house``
            final error 0.064 / 0.063 -> 0.062 / 0.083 m, 19 and 18 of 20 runs within
            0.2 m instead of all; a third sample 0.201 -> 0.193 m, 19 of 20 both); the
            explorer mapped more on worlds 1000-1039 (coverage 0.310 -> 0.332, paired t
            +2.0; ATE 0.091 -> 0.084 m) but not on 1040-1059 (0.306 -> 0.304, ATE 0.088
            -> 0.123 m); at 16.3 ``small`` is worse in both samples (0.093 / 0.096 ->
            0.126 / 0.123 m) and the explorer's ATE 0.091 -> 0.083 m at level coverage
            (docs/measurements.md, "Pose corrections beyond their own covariance").
        icp_max_pose_mahalanobis: an ICP result whose pose is further than this from the
            predicted pose (Mahalanobis distance, 3 dof, with ``icp_gate_sigma_floor``
            added to the covariance) fails the plausibility gate. Not a thesis value
            (the thesis: ``inf``, no gate). Without a floor the overconfident pose
            covariance rejects correct associations (synthetic loop of
            ``tests/test_filter.py``: 28 landmarks for 4 objects instead of 7).
        icp_prior_point_sigma: the per-landmark ICP minimises its points' squared
            residuals plus a prior on the aligned pose: the predicted pose with the
            pose covariance plus ``icp_prior_sigma_floor`` squared on the diagonal,
            weighted as if each point's residual had this standard deviation [m]
            (the ``prior_weight`` of :func:`~vslam_gym.slam.icp.align_many`). The
            thesis's ICP has no prior: a set that sees a wall
            slides along it, and one that sees more than a partial model holds is
            pulled off it (``house`` seed 0: more than half of the alignments end
            beyond the plausibility gate, many metres and up to 1.5 rad from a
            prediction good to 2 cm, and 60 of 169 new landmarks are made beside a
            gated landmark of the same obstacle). 0 (the thesis): no prior. Measured at
            0.03 m with floors of 0, (0.05, 0.05, 0.02) and the gate's (0.2, 0.2,
            0.1) (``vslam-gym evaluate``, seeds 0-9, ``house`` 0-19, 2026-11-26):
            fewer landmarks (``house`` 165 -> 128-141, ``curved`` 111 -> 53), half the
            ICP iterations, ``small`` and (with the gate's floor)
            ``curved`` better, but position ATE worse on ``single_landmark`` (0.176 ->
            0.227-0.316 m) and ``house`` (0.208 -> 0.267-0.275 m): not the default. In
            the ``fast`` preset at 0.03 m with the gate's floor (docs/measurements.md,
            "ICP pose prior").
        icp_prior_sigma_floor: standard deviations ``(x [m], y [m], theta [rad])`` added in
            quadrature to the pose covariance in the ICP prior (``icp_prior_point_sigma``).
        icp_gate_sigma_floor: standard deviations ``(x [m], y [m], theta [rad])`` added in
            quadrature to the pose covariance in the gate only (not in the association
            score), so that the gate catches gross ICP failures without depending on the
            overconfident covariance: in ``house`` (seed 0, step 119) a 3.7 m / 175 deg
            "correction" at a pose standard deviation of 1 cm / 0.7 deg flipped the map;
            in ``single_landmark`` (seed 3) the six-spiked object matched itself turned
            by 64 deg. With the default 3 sigma the gate passes corrections up to about
            0.6 m / 17 deg. Measured (``vslam-gym evaluate`` seeds 0-4, position ATE
            mean, gate off -> floor (0.1, 0.1, 0.05) -> (0.2, 0.2, 0.1), the default):
            ``single_landmark`` 0.54 -> 0.29 -> 0.32 m, ``small`` 0.18 -> 0.19 -> 0.14,
            ``curved`` 0.16 -> 0.09 -> 0.10, ``house`` 10.6 -> 0.32 -> 0.22 m (odometry
            1.31 m), final error in ``house`` 10.4 -> 0.71 -> 0.18 m. Not for the real
            logs: there (``logs`` preset, whole-scan prealignment, first 300 scans,
            synthetic odometry seeds 0-1) the floor let wrong associations through, Intel
            0.71 / 0.49 -> 15.2 / 15.5 m (ACES 1.36 / 2.05 -> 1.31 / 2.94 m), so the
            ``logs`` preset keeps the plain gate.
        icp_gate_fallback: a candidate whose ICP result fails the gate is tested (and,
            if chosen, updated) at the predicted pose instead of being dropped (its
            decision's ICP reason reads ``"gated"``). ICP diverges where a landmark
            gives it no hold (a disc, a symmetric shape); the prediction is then the
            better pose, and dropping the candidate models the object again. Off by
            default: measured with the default gate (position ATE mean, without -> with
            the fallback; seeds 0-4): ``single_landmark`` 0.32 -> 0.23 m, ``small``
            0.14 -> 0.11, ``curved`` 0.10 -> 0.08 (landmarks 103 -> 76, precision 0.97
            -> 0.99), but ``house`` (seeds 0-9) 0.22 -> 0.41 m, final error 0.23 ->
            0.70 m (landmarks 160 -> 117).
        icp_gate_includes_reference: the gate's covariance adds the landmark reference's
            uncertainty relative to the pose (``S_rr - S_xr - S_rx`` on the position
            block): an ICP pose is offset by the reference's error as much as by the
            pose's. False (the pose covariance alone) by default; True in the ``logs``
            preset.
        association_pose: the pose at which a set is tested against a candidate landmark
            and, when associated, converted for the model update: ``"icp"`` (the
            thesis: the set aligned to the landmark by ICP) or ``"predicted"`` (the
            predicted pose mean, no per-landmark ICP; sensible only when the prediction
            is already good, e.g. with ``prealign``: a segment of a few beams often does
            not constrain the ICP, which then ends tens of degrees off);
            ``"predicted_first"``: every candidate is tested at the predicted pose first,
            and only those the detection test rejects there are aligned by ICP (a speed
            measure: a well-tracked pose needs no per-landmark alignment). Measured
            (protocol of ``creation_overlap_distance``): alignments per ``house`` step
            25 -> 11, CPU
            time per step 58 -> 45 ms (``small`` 22 -> 18 ms), ``house`` landmarks 157 ->
            103; ATE 0.32 / 0.14 / 0.10 / 0.22 -> 0.25 / 0.18 / 0.13 / 0.25 m, ``house``
            final error 0.18 -> 0.38 m. Not the default.
        candidate_max_median_distance: a candidate landmark is aligned (ICP) and tested
            only when the median distance [m] of the set's points, at the predicted
            pose, to its nearest model lines is at most this; ``inf`` (the thesis)
            tries every landmark near the reference. A speed measure: most candidates
            of a cluttered scene are far from the set.
        candidate_max_near_distance: ... and only when the set's nearest points lie
            on it: the ``candidate_near_quantile`` quantile of the points' distances
            [m] to the model's segments, at the predicted pose, is at most this (a set
            that overlaps the model only partly still has its nearest points on it).
            ``inf`` (the thesis) does not test. On ``house`` (default, seeds 0-2) nine
            in ten associations of a set whose nearest tenth lay 0.1 m or more from the
            landmark joined two different obstacles. Measured at 0.1 m with
            ``candidate_near_sigma`` 3 (``vslam-gym evaluate``, seeds 0-9, ``house``
            0-19 in three round-off samples; docs/measurements.md, "Candidates a set lies on"):
            association precision ``house`` 0.757 -> 0.803, curved 0.975 -> 0.994;
            position ATE and final error level (``single_landmark`` final error 0.285
            -> 0.175 m); 12 % more ``house`` landmarks. 0.1 m by default; off in the
            ``logs`` and ``fast`` presets (measured worse there).
        candidate_near_quantile: the quantile of ``candidate_max_near_distance``, in
            [0, 1].
        candidate_near_sigma: ``candidate_max_near_distance`` grows by this many pose
            standard deviations: the position's (major axis) plus the heading's times the
            set centroid's distance from the lidar, so that a pose the filter knows to be
            uncertain still finds its landmarks. >= 0; 3 by default (0 does not
            close the synthetic circle of ``tests/test_filter.py``).
        new_landmark: how a new landmark enters the state: ``"thesis"`` (4.3.59-4.3.62:
            ``Phi2`` and ``Phi3`` both with ``K_v = Sigma_v^-1``, which counts the scan
            twice and informs the heading) or ``"augment"`` (exact augmentation of the
            reference, no pose information; see ``state_update.augment_landmark``).
            ``"augment"`` is the principled one but measured worse (synthetic loop of
            ``tests/test_filter.py``, seeds 0-2: position ATE 0.07-0.19 m against
            0.03-0.06 m, mean pose NEES 55-680 against 19-60): the state keeps only the
            reference point, so a landmark's orientation uncertainty, which equals the
            creating pose's heading error, becomes independent of the pose.
            ``"halved"``: the thesis form with ``K_v / 2`` in both factors, so the scan is
            counted once. Measured (default otherwise, ``vslam-gym evaluate``):
            ``small`` seeds 0-5 median position ATE 0.13 m against 0.18 m but one
            divergence (3.1 m); ``single_landmark`` seeds 0-2 0.18 m against 0.24 m;
            ``house`` seed 0 1.5 m against 3.1 m. With the model-error terms of the
            default (2026-11-26, ``house`` seeds 0-19, three round-off samples):
            position ATE 0.264 +- 0.007 m against 0.238 +- 0.030 m, final error
            0.341 +- 0.008 m against 0.411 +- 0.096 m: not better on both, so the thesis
            form stays the default.
        shape_sigma: with ``"augment"``, isotropic spread [m] added to the singular
            ``p(v | r)`` so that it has an information form.
        reference: a landmark's reference in the state: ``"point"`` (the thesis: the 2-D
            mean of its object vertices) or ``"pose"`` (a landmark frame: that point
            plus a heading [rad], started at the creating pose's heading, with the
            vertices linearised about it and re-linearised at every update). A point
            cannot hold a landmark's orientation uncertainty, which after creation is
            the creating pose's heading uncertainty and is correlated with it; so the
            thesis's creation (``new_landmark="thesis"``) turns it into pose heading
            information the filter does not have (the pose heading sigma drops about
            20-fold when a landmark is created), and ``"augment"`` treats the
            orientation as known. With ``"pose"`` neither creation form informs the
            pose. Measured (``vslam-gym evaluate --set``, seeds 0-4, position ATE
            single_landmark / small / curved / house, mean pose NEES; default 0.32 /
            0.14 / 0.10 / 0.22 m, NEES 117 / 612 / 279 / 4764): with the thesis
            creation 0.35 / 0.18 / 0.17 / 0.65 m, NEES 38 / 276 / 590 / 14560; with
            ``"augment"`` 0.42 / 0.15 / 0.11 / 0.31 m, NEES 94 / 1320 / 300 / 4882;
            with ``"halved"`` 0.40 / 0.06 / 0.14 / 0.56 m, NEES 42 / 101 / 489 / 13927.
            The heading collapse at creation is gone (``small`` seed 0: NEES 652 -> 135
            with the thesis creation, 16 with ``"augment"``), but the later landmark
            updates stay overconfident and ``house`` is worse: not the default.
        reference_heading_sigma: with ``reference="pose"`` and ``new_landmark="augment"``,
            standard deviation [rad] of a new landmark frame's heading about the pose
            heading (it keeps the state covariance positive definite).
        unknown_chain_max_vertices: each unknown chain keeps at most this many vertices
            after Douglas-Peucker simplification at ``unknown_chain_tolerance`` [m]
            (``landmark.prune_unknown_chains``); 0 keeps every vertex (the thesis,
            whose chains grow with every update).
        unknown_chain_tolerance: see ``unknown_chain_max_vertices``.
        observation_information_scale: the observation's information ``K_obs`` (``K3``)
            is multiplied by this in the state-space update (1 in the thesis); below 1
            it discounts the model errors the vertex covariances do not describe. 0.1
            in the ``logs`` preset (``filter.LOGS_OBSERVATION_INFORMATION_SCALE``: the
            scan-matched motion stays the main pose information; full ACES log,
            synthetic seeds 0-4 mean / logged odometry: 0.3 -> 1.41 / 1.68 m, 0.1 ->
            1.33 / 1.28 m, 0.03 -> 1.32 / 1.50 m).
        observation_model_sigma: model error [m] of an observation's vertices: the
            observation factor ``Phi3`` of the state-space update (landmark updates, and
            the thesis's landmark creation, whose ``Phi3`` carries the creating scan)
            keeps its mean but its covariance gains this squared times the identity
            (``gaussian.inflated_information``), so no vertex coordinate is observed
            more precisely than this. A scan pins a well-seen wall to millimetres, but
            the polyline model of a partial view is not that right (ends, corners, the
            reference a later view moves): without the floor the filter keeps
            millimetres per landmark handoff where the true error per handoff is
            centimetres, and the pose NEES grows into the thousands. 0 (the thesis):
            off. Default 0.05, measured (``vslam-gym evaluate --seeds 0-9``, 0 -> 0.05,
            2026-11-25, paired t): mean pose NEES single_landmark / small / curved /
            house 37 / 531 / 327 / 7717 -> 22 / 107 / 145 / 417 (t -2.0 / -4.6 / -2.3 /
            -2.8; house seeds 10-19 8101 -> 748), association precision curved 0.959 ->
            0.974, house 0.734 -> 0.757 (t +4.2), duplicates and landmarks fewer (house
            162 -> 139), position ATE level within the seed spread: 0.213 / 0.131 /
            0.102 / 0.293 -> 0.227 / 0.136 / 0.112 / 0.232 m (t +0.3 / +0.3 / +0.8 /
            -1.1; house seeds 10-19 0.331 -> 0.274), final error 0.212 / 0.110 / 0.049
            / 0.462 -> 0.259 / 0.125 / 0.055 / 0.396 m (house seeds 10-19 0.331 ->
            0.527, t +1.4). 0.1 measured NEES lower still (house 244) but ATE mixed
            (small 0.097, t -3.0; single_landmark 0.272 and curved 0.144, t +1.4).
        observation_model_heading_sigma: model error [rad] of a landmark's orientation:
            ``Phi3``'s covariance (as for ``observation_model_sigma``) also gains a
            rotation of all the observed vertices about the landmark's reference point
            by this standard deviation. A point reference keeps no orientation in the
            state: a landmark's orientation is fixed in ``p(v | r)`` at the heading it
            was made at, and every later observation uses it as an independent compass
            although its error is the creating pose's heading error; the pose heading
            then grows overconfident (on ``house`` 10-20 standard deviations off). 0
            (the thesis): off. Default 0.01, measured on top of ``observation_model_sigma``
            0.05 (``vslam-gym evaluate --seeds 0-9``, 0 -> 0.01, 2026-11-25, paired t):
            position ATE single_landmark / small / curved / house 0.227 / 0.136 / 0.112
            / 0.232 -> 0.209 / 0.102 / 0.101 / 0.159 m (t -0.7 / -1.9 / -1.5 / -2.5;
            house seeds 10-19 0.274 -> 0.258, t -0.4), final error 0.259 / 0.125 /
            0.055 / 0.396 -> 0.285 / 0.058 / 0.035 / 0.189 m (house t -2.6; seeds 10-19
            0.527 -> 0.447), mean pose NEES 22 / 107 / 145 / 417 -> 13 / 47 / 95 / 155.
            0.02 measured between the two (house 0.211 m, final 0.353 m); 0.005 worse
            (house seeds 0-5 0.134 -> 0.205 m, t +2.6).
        creation_heading_model_error: a landmark's orientation model error is at least
            this times the pose heading standard deviation [rad] just before the
            landmark was created (``observation_model_heading_sigma`` is the floor), in
            its creation's ``Phi3`` and in every later update. A landmark made while the
            heading was uncertain is then no better a compass than that heading was; the
            thesis's creation otherwise turns the creating scan into heading information
            (on ``single_landmark`` seed 4 the heading standard deviation drops from
            0.056 to 0.011 rad at one creation while its error grows to 0.046 rad). 0:
            off (the default). Measured (``vslam-gym evaluate --seeds 0-9``, ``house``
            0-19, 0 -> 1, 2026-11-26, paired t), position ATE single_landmark / small /
            curved / house 0.184 / 0.097 / 0.103 / 0.208 -> 0.206 / 0.072 / 0.100 /
            0.224 m (t +1.1 / -1.5 / -1.5 / +0.9), mean pose NEES 14 / 44 / 103 / 384
            -> 12 / 23 / 98 / 413; with 2 on the three small worlds 0.224 / 0.082 /
            0.109 m (t +1.6 / -0.8 / +0.5). No |t| reaches 2 and ``single_landmark``
            is worse with both, so it is not the default. (On ``single_landmark`` the
            heading error comes from the odometry while no set updates the map, and a
            less certain creation does not undo it.)
        min_object_beam_fraction: a candidate landmark that passes the detection test is
            still rejected when fewer than this fraction of the set's beams are assigned
            to its object lines (``u <= unknown_threshold``); 0 in the thesis. A set that
            fits a model only through its unknown lines (free-space boundaries, whose
            likelihood is broad) says little about the landmark: in ``house`` most wrong
            associations had no beam on an object line. Measured with 0.3 on top of the
            default (``vslam-gym evaluate`` seeds 0-4): association precision ``house``
            0.74 -> 0.87, ``curved`` 0.97 -> 1.00, ATE ``single_landmark`` 0.32 -> 0.28
            m, ``small`` and ``curved`` unchanged, but ``house`` ATE 0.22 -> 0.39 m and
            final error 0.18 -> 0.55 m: then not the default. With 0.01 (one object beam
            suffices; seeds 0-4): precision ``curved`` 0.97 -> 1.00, ``house`` 0.74 ->
            0.88, ATE 0.32 / 0.14 / 0.10 / 0.22 -> 0.28 / 0.14 / 0.10 / 0.45 m: the
            rejected sets become new landmarks (``house`` 157 -> 190). With the loop
            closure by revisits and the near-candidate test (2026-11-26, seeds 0-9,
            ``house`` 0-19 in three round-off samples; docs/measurements.md, "Candidates a set lies
            on"), 0.3 measured better on ``house`` (position ATE 0.221-0.236 ->
            0.208-0.217 m, final error 0.063-0.154 -> 0.053-0.069 m, precision 0.80 ->
            0.87) and on the ``curved`` precision (0.994 -> 1.000), level elsewhere:
            0.3 by default; 0 in the ``logs`` preset (ACES measured worse).
        prealign: whole-scan alignment before the landmark association
            (:mod:`vslam_gym.slam.scan_matching`; not in the thesis, its future work):
            ``"none"`` (the thesis); ``"odometry"`` (the default): the scan is aligned
            to the last scans in the matcher's own frame with the odometry as prior, and
            the matched relative pose replaces the odometry in the motion update
            (scan-matching odometry under the landmark filter); ``"fuse"``: the scan is
            aligned to the last scans placed at the filter's pose estimates, and the
            aligned pose is fused as a direct pose measurement (``H = [I, 0]``) after
            the motion update. Measured in docs/radish.md (the ``logs`` preset) and on
            the simulated worlds (sessions 24-25, docs/measurements.md, "Scan-matched
            motion on the simulated worlds"): with the default's tighter matched
            covariance (``SlamConfig.matcher``: ``sigma_floor`` ``(0.002, 0.002,
            0.0005)``, ``covariance_inflation`` 3) ``"odometry"`` closes the ``house``
            loop better (position ATE 0.189-0.201 -> 0.158-0.164 m, final error
            0.063-0.076 -> 0.023-0.025 m, three round-off samples), ``curved`` better
            (0.098-0.103 -> 0.075 m), the other routes level or better, the mean pose
            NEES lower on ``curved`` and ``house``, and the ``frontier`` explorer level
            on 60 held-out random worlds (coverage 0.309 -> 0.318, position ATE 0.090
            -> 0.095 m); the matcher costs about 4 ms per step (``bench_wrapper``: 8-16 %
            fewer steps per second). With the logs' covariance (floor ``(0.01, 0.01,
            0.002)``, inflation 10) the explorer's ATE measured worse (0.091 -> 0.126
            m). ``"none"`` in the ``thesis`` and ``fast`` presets. Under a motion
            filter (``measurement_min_travel``, ``measurement_min_turn``) the match runs
            only on the steps that measure, from the last of them with the odometry
            since then as prior (the default's motion filter since session 26).
        creation_overlap_distance: an unmatched set is not made a new landmark when the
            median distance [m] of its points to the object lines of an aligned candidate
            landmark (at that candidate's ICP pose if it passed the gate, or at the
            predicted pose) is at most this; its decision reads ``"overlapping"``. 0
            (the thesis) creates a landmark from every unmatched detectable set, so an
            object whose re-observation fails the detection test (a coarsely modelled
            corner) is modelled again: a duplicate landmark. Measured at 0.1 m (seeds
            0-4, means for ``single_landmark`` / ``small`` / ``curved`` / ``house``, with
            ``vslam-gym evaluate --set``): landmarks 7.8 / 19 / 103 / 157 -> 4.6 / 8.6 /
            36 / 67, duplicate fraction 0.87 / 0.79 / 0.91 / 0.78 -> 0.78 / 0.49 / 0.75
            / 0.49, but position ATE 0.32 / 0.14 / 0.10 / 0.22 -> 0.33 / 0.19 / 0.24 /
            0.39 m: the duplicates carry updates that the failed re-association does
            not. Not the default (``create_beside_candidates=False``, in the ``logs``
            preset, blocks creation beside any tested candidate, whatever the distance).
        detection_model_sigma: isotropic standard deviation [m] added to every vertex's
            covariance in the detection test only (not in the state): the model's shape
            error (a corner cut by the model selection), which does not average out over
            updates the way the vertex covariances do. 0 in the thesis. Measured at
            0.02 m (protocol of ``creation_overlap_distance``): ATE 0.32 / 0.14 / 0.10
            / 0.22 -> 0.23 / 0.13 / 0.12 / 0.32 m, better on two worlds, worse on
            ``curved`` and ``house``. Not the default.
        icp_retry_correspondence_distance: a candidate whose ICP result fails the
            plausibility gate is aligned once more from the predicted pose with
            ``IcpConfig.max_correspondence_distance`` set to this [m] (points farther
            from the model are not used), and that result is gated instead. Aimed at
            revisits: a set that sees far more than an old, partial model is pulled
            off by the points the model does not hold (``house`` seed 7: every
            alignment to the start's landmarks at the loop's end was gated, headings
            1.3 rad off). Results that pass the gate are unchanged. 0 (the default):
            no retry. Only a retry that converged with at least
            ``icp_retry_min_fraction`` of the set's points counts.
        icp_retry_min_fraction: see ``icp_retry_correspondence_distance``. A retry that
            keeps few points is weak evidence: on ``house`` seeds 10-19 (0.5 m), of the
            associations through a retry that kept under 30 % of the points 37 %
            were correct, 30-50 %: 47 %, 50-70 %: 67 %, over 70 %: 89 %; a retry left
            without points stops at the predicted pose, which must not count. Measured
            at 0.5 m and 0.5 (``house``): seeds 0-9 ATE 0.249 -> 0.225 m, final error
            0.315 -> 0.252 m, but seeds 10-19 0.328 -> 0.337 m and 0.350 -> 0.438 m;
            at 0.7 seeds 0-9 0.339 m and 0.558 m. Not the default.
        icp_stop_beyond_gate: a per-landmark ICP stops (reason ``"out_of_bound"``) after
            the first step that takes its pose beyond this many times the plausibility
            gate (``icp_max_pose_mahalanobis``, same covariance); such a result fails
            the gate unless the alignment would have come back. 0 (the thesis) lets
            every alignment run to convergence. A speed measure: diverging alignments
            cost about a quarter of the ICP iterations in ``house``. Measured at 1
            (protocol of ``creation_overlap_distance``): ICP iterations per ``house`` step 283 ->
            115 and CPU time per step 58 -> 44 ms, but alignments that would have come
            back inside the gate are lost (``house`` landmarks 157 -> 175): ATE 0.32 /
            0.14 / 0.10 / 0.22 -> 0.26 / 0.15 / 0.09 / 0.25 m, ``house`` final error
            0.18 -> 0.57 m. Not the default. At 3 (seeds 0-9, 2026-11-25): median step
            13-36 % shorter on every world, but ``house`` final error 0.315 -> 0.471
            m and ``small`` ATE 0.129 -> 0.163 m. Again at 3 with the side-by-side ICP
            (2026-11-26): ``house`` median step 17.5 -> 14.9 ms, ``small`` ATE 0.098
            -> 0.148 m (its round-off spread is 0.096-0.098 m), ``house`` 20-seed ATE
            0.262 / 0.293 m in two samples (default 0.21-0.28 m). 10 in the ``logs``
            preset (Radish logs: accuracy level, 6-9 % less time per scan; 3 was
            worse on ACES). At 3 on session 26's default (docs/measurements.md,
            "Stopping diverging alignments, re-measured"): routes level, about 5 % less
            filter time, the ``house`` median step unchanged, one explorer world
            diverged. 3 is the default since session 33 (docs/measurements.md, "Session
            33"): on session 32's default and again with the start keyframe, routes
            within the round-off spread and the ``frontier`` explorer level on 60
            held-out worlds in both (no world above 0.2 m; the divergence did not
            recur), 4-8 % less CPU time per ``house`` step. 0 in the ``thesis`` and
            ``fast`` presets (not measured there), 10 in ``logs``.
        measurement_min_travel: a motion filter: the landmark measurement update (step 3
            on) runs only once the pose mean has moved at least this far [m] ...
        measurement_min_turn: ... or turned at least this much [rad] since the last
            measurement update; other steps do the motion update only (the scan is not
            used). 0 and 0 (the thesis, ``logs``) measure every scan. Scan-matching SLAM
            front ends commonly process a scan only after such motion; it saves the work
            of re-observing the same scene from almost the same pose, and counts the
            scene's correlated model errors fewer times. With the scan-matched motion
            (``prealign="odometry"``) the match too runs only on the steps that measure.
            0.15 m and 0.15 rad by default (session 26, docs/measurements.md, "A motion
            filter on the default"; seeds 0-9, ``house`` 0-19, three round-off samples,
            against every scan): position ATE single_landmark / small / curved / house
            0.119 / 0.090-0.091 / 0.075 / 0.158-0.161 -> 0.111 / 0.079-0.084 /
            0.077-0.081 / 0.138-0.156 m, mean pose NEES 14 / 39-41 / 48 / 319-326 -> 11
            / 19-21 / 32-35 / 132-161, mean filter step about half (``house`` 37.5 ->
            16.2-18.2 ms side by side); the ``frontier`` explorer on 60 held-out worlds:
            coverage 0.318 -> 0.316, position ATE 0.095 -> 0.084 m, mean NEES 378 -> 113.
            0.2 m / 0.2 rad (the ``fast`` preset's) lost explorer coverage (0.326 / 0.322
            -> 0.299 / 0.299 on worlds 1000-1019 / 1020-1039), 0.1 m / 0.1 rad too (0.312
            / 0.277). Before the scan-matched motion, 0.1 m and 0.1 rad had measured
            worse on ``house`` (seeds 0-4, ATE 0.22 -> 0.36 m).
        create_beside_candidates: an unmatched set becomes a new landmark even when a
            landmark near it was aligned and tested (and failed the gate or the
            detection test); True in the thesis. False: only a set whose candidates
            were all too far (``candidate_max_median_distance``) or that had none
            creates one; a re-observation that fails its test is then not modelled
            again as a duplicate (compare ``creation_overlap_distance``, which tests the
            set's distance to the candidates' lines). False in the ``logs`` preset.
            Measured there (first 300 scans, synthetic seeds 0-1 and logged odometry;
            True -> False): Intel 330-360 -> 50 landmarks, median step 50-95 -> 23-25
            ms, position ATE 0.44 0.35 0.58 -> 0.41 0.39 0.48 m; ACES 480-510 -> 100
            landmarks, ATE 1.52 1.46 2.46 -> 1.38 1.96 2.04 m (with
            ``observation_information_scale`` 0.1 as well: 0.69 1.10 1.37 m).
        verify_heading_sigma: verification of an update before it is committed (the
            thesis's future work, SPEC section 11): the update is rejected (the set's
            decision reads ``"rejected"``, the state is left as before it) when it turns
            the heading outside the interval between the current heading and the heading
            of the association's ICP pose by more than this many prior heading standard
            deviations. The ICP pose is what the set's alignment to the landmark says;
            an update that turns the robot beyond it, or against it, draws on model
            structure the alignment did not use (in ``house``, false end vertices of a
            folded model observed with centimetre uncertainty). 0 (the thesis): no
            verification. With ``association_pose="predicted"`` the interval is the
            current heading alone. Default 3, measured (``vslam-gym evaluate --seeds
            0-9``, 0 -> 3, paired t): position ATE single_landmark / small / curved /
            house 0.243 / 0.129 / 0.099 / 0.274 -> 0.213 / 0.129 / 0.102 / 0.249 m
            (-1.4 / -0.3 / +0.6 / -0.6), ``house`` final error 0.474 -> 0.315 m (-1.4);
            ``house`` seeds 0-19: ATE 0.329 -> 0.288 m (-1.1), final error 0.493 ->
            0.332 m (-1.7), heading RMSE 0.036 -> 0.028 rad (-2.4). At 2 and 5 ``house``
            measured 0.307 / 0.426 m and 0.257 / 0.401 m (ATE / final error, seeds 0-9).
            0 in the ``logs`` preset (measured no better there).
        verify_position_sigma: the same verification for the position: the update is
            rejected when it moves the position farther than this many prior position
            standard deviations (the larger axis of the ``2 x 2`` covariance) from the
            segment between the current position and the ICP pose's position. 0 (the
            default): no verification. With 3 on top of ``verify_heading_sigma`` 3,
            ``house`` seeds 0-9 measured ATE 0.249 -> 0.256 m, final error 0.315 ->
            0.358 m.
        prune_covered_distance: pruning of covered duplicates (a light form of the
            thesis's future work "merging landmarks of one object", SPEC section 11):
            when a landmark has not been associated, updated or created for
            ``prune_idle_steps`` measurement updates, and at least
            ``prune_covered_fraction`` of its object-line length lies within this
            distance [m] of another landmark's object lines (vertex means), it is
            removed from the state by marginalisation (its reference's rows and
            columns are dropped: exact for a Gaussian, so the rest of the belief is
            unchanged). A covered landmark whose reference is better known (smaller
            covariance trace) than its coverer's stays; the coverer is removed instead
            if it is idle and covered by it. The
            removed ids are in ``Belief.pruned``; the other ids do not change. 0 (the
            thesis): off. Measured at 0.1 m (``vslam-gym evaluate --seeds 0-9``, paired
            against the default, 2026-11-25): position ATE single_landmark / small /
            curved / house 0.213 / 0.131 / 0.102 / 0.293 -> 0.181 / 0.159 / 0.104 /
            0.225 m, ``house`` final error 0.462 -> 0.290 m, half the landmarks; but
            ``house`` seeds 10-19 ATE 0.331 -> 0.391 m and ``small`` worse: not the
            default (docs/measurements.md, "Covered duplicates").
        prune_covered_fraction: see ``prune_covered_distance``; in ``(0, 1]``.
        prune_idle_steps: see ``prune_covered_distance``; >= 1.
        prune_merge: merge instead of only removing (the thesis's "merging landmarks of
            one object"): the coverage is measured after the translation that moves the
            covered landmark's object lines onto the coverer's (point to line, matches
            within ``prune_merge_max_offset`` between lines facing the same way), and
            before the covered landmark is removed that offset is fused into the state
            as a relative measurement of the two references (EKF update of the whole
            state, gated at chi-square probability ``prune_merge_probability``, noise
            the landmarks' vertex covariances plus ``prune_merge_sigma^2``): a duplicate
            built after a drift then closes the loop. False: remove without fusing.
            Measured worse (``house`` seeds 0-5, 2026-11-25, position ATE / final error
            [m]): default 0.310 / 0.493, pruning at 0.1 m 0.276 / 0.314, merging 0.380 /
            0.590 (with ``prune_merge_sigma`` 0.05: 0.382 / 0.699). The merges hardly
            move the pose (the merged pairs were built close in time), and with the
            update made negligible (``prune_merge_sigma`` 1000) the ATE is 0.415 m:
            removing the landmarks only an offset fit covers is what costs accuracy.
        prune_merge_max_offset: largest distance [m] between matched lines of the offset
            fit; > 0.
        prune_merge_sigma: standard deviation [m] added to the merge measurement's
            noise per direction; >= 0.
        prune_merge_probability: chi-square gate probability of the merge measurement's
            innovation; in ``(0, 1)``.
        loop_closure: loop closure by revisits (:mod:`vslam_gym.slam.loop_closure`; not
            in the thesis): every measurement update keeps its scan as a keyframe at the
            updated pose (``loop_keyframe_distance`` / ``loop_keyframe_heading_deg``
            apart); before a measurement update the whole scan is aligned (the
            ``matcher`` parameters, without the prior, ambiguous matches declined) to
            the keyframes made at least ``loop_min_age`` measurement updates earlier
            within ``loop_radius`` of the predicted position, and a match with at least
            ``loop_min_inlier_fraction`` inliers within ``loop_max_mahalanobis`` of the
            predicted pose (pose covariance plus the ICP gate's floor plus the match's)
            updates the whole state as a measurement of the pose. The drift of a long
            loop exceeds the per-landmark ICP gate, so without it the first landmarks
            are not re-associated on the return. On by default, off in the thesis.
            Measured (``vslam-gym evaluate`` seeds 0-9, off -> on, position ATE /
            final error [m]): single_landmark 0.209 / 0.285 -> the same (no match
            passes), small 0.098 / 0.059 -> 0.097 / 0.019, curved 0.100 / 0.033 ->
            0.099 / 0.019, ``house`` 0.242 / 0.480 -> 0.214 / 0.051 (seeds 10-19: 0.273
            / 0.439 -> 0.264 / 0.231; 18-19 of 20 seeds within 0.2 m in each of three
            round-off samples, 7-8 without); full Radish logs (``logs`` preset,
            synthetic seeds 0-4 / logged odometry): Intel 0.61 / 0.73 -> 0.58 / 0.68,
            ACES 1.38 / 1.28 -> 0.94 / 1.30 (docs/measurements.md, "Loop closure by revisits").
        loop_radius: see ``loop_closure`` [m]; > 0.
        loop_min_age: see ``loop_closure`` (measurement updates); >= 1.
        loop_keyframe_distance: see ``loop_closure`` [m]; >= 0.
        loop_keyframe_heading_deg: see ``loop_closure`` [deg]; >= 0.
        loop_min_inlier_fraction: see ``loop_closure``; in ``[0, 1]``.
        loop_max_mahalanobis: see ``loop_closure``; > 0. 2 by default since session 28
            (6 before, and in the ``logs`` and ``fast`` presets): since the default's
            motion is scan-matched (session 25) its pose is seldom more than a few
            centimetres off, and on the random worlds the fused matches beyond 2
            (0.3-1.05 m from a pose 2-10 cm off, 42-60 % inliers) were aliases that moved
            the pose away from the truth, but for a few that undid an earlier alias; on
            ``house`` (seeds 0-5) every fused match lies within 1.6. Measured 6 -> 2
            (docs/measurements.md, "Revisit matches within 2 sigma"): ``small``,
            ``curved`` and ``house`` identical to the last digit, single_landmark
            position ATE 0.111 -> 0.103 m and final error 0.163 -> 0.102 m in two
            round-off samples; the ``frontier`` explorer on the 60 worlds 1000-1059
            position ATE 0.084 -> 0.078 m (paired t -1.1; world 1029 0.386 -> 0.075 m),
            coverage 0.316 -> 0.317, mean NEES 113 -> 89. Strong matches keep their own
            limit (``loop_strong_max_mahalanobis``).
        loop_max_distance_start: the whole-scan matcher's first correspondence
            distance [m] in the revisit match (``ScanMatcherConfig.max_distance_start``
            for this match only) ...
        loop_max_distance_mid: ... and its distance [m] at the end of the coarse phase
            (``max_distance_mid``); both > 0. ``house``, three round-off samples of
            seeds 0-19, final error [m]: with the matcher's own 1 m / 0.5 m, 0.140 /
            0.127 / 0.152 (one seed of 20 at 1.5-1.85 m in each: more than a metre of
            drift is not pulled in); with 2 m / 1 m (the default) 0.141 / 0.126 /
            0.079. With 2 m / 1 m and ``loop_max_mahalanobis`` 10: 0.097 / 0.060 /
            0.079, but false closures elsewhere (a wall matched 1.5 m along itself at
            7.7 sigma in one of 20 random worlds, ``frontier`` ATE 0.115 -> 0.194 m;
            ACES synthetic seed 0 2.75 m and logged 2.16 m): 6 then (2 by default
            since session 28, see ``loop_max_mahalanobis``).
        loop_sigma_floor: standard deviations ``(x [m], y [m], theta [rad])`` added in
            quadrature to a revisit match's noise; each >= 0. (0.02, 0.02, 0.005) by
            default since session 36 (0 in the ``logs`` and ``fast`` presets): on the
            random worlds a revisit match is fused on most measuring steps, and its
            error is correlated with the prediction's (the keyframes were placed by
            the same drifting estimate; correlation 0.77 in position), which the fusion
            treats as independent. Over the 1 638 matches the ``frontier`` explorer
            fused on worlds 1000-1019 (``loop_match_nees_*`` in its metrics), the
            match's NEES against the true pose had median 6.8 and mean 34 (2.37 and 3
            for a consistent match); the same matches with this floor 2.5 and 10.7
            (the explorer's own matches under it: per world, mean 9.2 and median 5.3,
            averaged over the 20 worlds, against 34 and 6.8). Measured 0 -> this
            floor (docs/measurements.md, "Session 36"): the explorer's mean pose NEES
            25 -> 8.2 and 20 -> 9.5 on worlds 1000-1019 / 1020-1039, position ATE
            0.056 -> 0.051 m (paired t -1.9) and 0.055 -> 0.053 m (t -0.6), coverage
            level; the routes' position ATE level (seeds 0-9, within 1 mm), but the
            ``house`` loop closes less tightly by the route's end (final error 0.023 ->
            0.042 m, seeds 10-19 0.022 -> 0.039 m, all within 0.11 m) and ``curved``
            0.022 -> 0.027 m. Before session 25 (odometry motion, the first version of
            the loop closure) (0.05, 0.05, 0.01) had left the ``house`` loop open
            (final error 0.182 m instead of 0.050 m).
        loop_min_points: fewest scan points, and inliers, of a revisit match
            (``ScanMatcherConfig.min_points`` for this match only); >= 3. A scan of one
            small object has fewer than the matcher's 20: on ``single_landmark`` every
            revisit failed for it and the loop around the object stayed open. Measured
            (session 19, ``vslam-gym evaluate --seeds 0-9``, 20 -> 10, paired t), position
            ATE single_landmark / small / curved 0.184 / 0.097 / 0.103 -> 0.176 / 0.095 /
            0.103 m (t -1.7 / -2.9 / -0.3), final error 0.234 / 0.019 / 0.028 -> 0.185 /
            0.017 / 0.027 m, mean pose NEES 14 / 44 / 103 -> 17 / 43 / 103; a second
            round-off sample (``--range-perturbation 1e-15``) the same; ``house`` seeds
            0-19 and the ``frontier`` agent on 20 random worlds unchanged to the last
            digit (their scans have more points). 6 admits false matches
            (``single_landmark`` ATE 0.233 m, final error 0.513 m), 14 is between (0.185
            / 0.205 m). 10 by default; 20 in the ``logs`` preset (as its matcher).
        loop_cooldown: after a fused revisit match the next is tried this many
            measurement updates later at the earliest (2: the next update tries none);
            0 and 1 try every one; >= 0. 10 measured NEES 198 on the random worlds and
            ``house`` final error 0.199 m: 0 by default; 2 in the ``logs`` preset.
        loop_track_hypotheses: the first revisit match tried after a fused one (the
            next measurement update's; with ``loop_cooldown`` >= 2 the first after the
            cooldown) starts from at most this many heading hypotheses (1: the
            predicted heading only) instead of the spread over the pose's heading
            uncertainty: the belief already agrees with the earlier visit (speed: on
            the Intel log a match is fused on most updates); 0: off; >= 0.
        loop_min_innovation: a revisit match is fused only when it lies at least this
            far (Mahalanobis distance, pose covariance plus the match's) from the
            predicted pose: one that agrees with the belief closes nothing and would
            only shrink the covariance again. 0 fuses every match; >= 0. Measured at 1
            and 2: ``house`` seeds 0-9 unchanged (final error 0.050 / 0.051 m), but on
            the random worlds (``frontier``, 20 worlds) no better: mean NEES 621 / 434,
            ATE 0.136 / 0.133 m against 528 and 0.115 m. 0 by default.
        loop_max_correction: a revisit match is fused only when its position lies at
            most this far [m] from the predicted position (``inf``: no limit); > 0. Of
            the explorer's fused matches that moved the pose more than 0.15 m (session
            28, worlds 1000-1019 and 1040-1059), 33 of 47 added error. Measured at 0.15
            (session 29, docs/measurements.md): the ``frontier`` explorer's position ATE
            on worlds 1000-1059 0.078 -> 0.075 m, coverage 0.317 -> 0.315, but the
            ``house`` loop stays open in 3 of 20 runs (final error up to 0.29 m), whose
            closing matches move the pose further. ``inf`` by default.
        repeat_updates: a landmark's update after ``n`` earlier ones observes with its
            information times ``1 / (1 + n / repeat_updates)`` (0: off, every update at
            full weight; >= 0): the errors of a landmark's model (the pose it was made
            at, its model error) are shared by all its updates, which the filter
            otherwise counts as independent. Measured at 20 (session 29,
            docs/measurements.md, two round-off samples): position ATE single_landmark
            / small / curved / house 0.103 / 0.079 / 0.081 / 0.138 -> 0.101 / 0.080 /
            0.081 / 0.135 m and 0.103 / 0.084 / 0.079 / 0.150 -> 0.101 / 0.079 / 0.083
            / 0.134 m, mean pose NEES ``house`` 132 / 148 -> 100 / 96, final error level
            or better; but the ``frontier`` explorer on worlds 1000-1059 maps less
            (coverage 0.317 -> 0.304, lower on 42 of 60 worlds; ATE 0.078 -> 0.076 m).
            At 5 the ``house`` NEES is 65 but single_landmark's ATE 0.115 m; at 50 the
            explorer maps less too (0.307) and the routes are a little worse. 0 by
            default.
        error_noise_scale: when > 0, the belief reports the covariance of the filter's
            estimation error instead of the filter's own (``Belief.pose_cov``,
            ``LandmarkView.reference_cov``): the same updates with the filter's gains,
            in Joseph form, with the noise of every landmark update and creation times
            this scale (:mod:`vslam_gym.slam.error_covariance`). The estimates, gains
            and gates do not change; 0: the filter's own covariance (the ``thesis``
            preset). An empirical scale: the landmark updates' innovations are within
            their predicted spread, the overconfidence is in the directions they cannot
            observe. Measured (session 30, docs/measurements.md; seeds 0-9, ``house``
            0-19), mean pose NEES single_landmark / small / curved / ``house`` and the
            fraction of steps in the 95 % band: 0: 8 / 19 / 35 / 132, 0.72 / 0.58 /
            0.29 / 0.19; 5: 3 / 6 / 11 / 40, 0.95 / 0.85 / 0.59 / 0.37; 10: 2 / 4 / 6 /
            22, 0.94 / 0.86 / 0.76 / 0.49; 20: 1 / 2 / 3 / 12, 0.87 / 0.81 / 0.86 /
            0.61; the ``frontier`` explorer on worlds 1000-1059 at 10: 89 -> 33 (these
            figures with ``error_creation_pose_update`` True, the default until session
            32). About 2 % more CPU time per step on ``house``. 10 by default.
        error_creation_pose_update: with ``error_noise_scale`` > 0, whether the error
            covariance takes the pose information of a landmark creation
            (``new_landmark`` ``"thesis"`` or ``"halved"``). That creation uses its scan
            twice, as the new model's vertex prior and as the observation of it, so its
            pose factor leaves the pose mean where it was (shifts below 1e-12) and
            only shrinks the filter's covariance: the estimation error does not change.
            False (default since session 32): the error covariance's pose block stays
            as it is and the new reference enters with its error ``C e_x + e``
            (:func:`~vslam_gym.slam.error_covariance.add_landmark`). The estimates do
            not change either way. Measured (docs/measurements.md, "Session 32";
            seeds 0-9, ``house`` 0-19; single_landmark / small / curved / ``house``):
            True -> False, mean pose NEES 1.8 / 3.8 / 6.0 / 22.0 -> 1.4 / 2.4 / 5.7 /
            21.5, steps in the 95 % band 0.94 / 0.86 / 0.76 / 0.49 -> 0.91 / 0.90 /
            0.78 / 0.51; the ``frontier`` explorer's mean NEES on worlds 1000-1019 27.1
            -> 27.0.
        loop_prior_rival: when > 0, a revisit match is declined as ambiguous when the scan,
            fitted locally at the predicted pose
            (:func:`~vslam_gym.slam.scan_matching.local_fit`), ends at a distinct pose (the
            matcher's ``ambiguity_translation`` or ``ambiguity_heading_deg``) with at least
            this fraction of the match's inliers: an alias along a corridor or a long wall,
            where the earlier visit fits where the belief already is. On the random worlds
            70 of the 81 revisit matches that moved the ``frontier`` agent's position by
            more than 0.3 m were such aliases (reported with 2 cm standard deviations). A
            true drift correction has no such rival: the local fit at the drifted prediction
            converges to the match or fits badly. Only a match that moves the pose by more
            than those steps is checked (a few in a hundred on the random worlds: no
            measurable time). 0: off (as before session 21; the ``logs`` and ``fast``
            presets, where it measured level or mixed). Measured (session 21, 0 -> 0.8): the
            ``frontier`` agent on held-out worlds 1000-1019 / 1020-1039, coverage 0.327 ->
            0.318 / 0.304 -> 0.332, position ATE 0.109 -> 0.104 / 0.151 -> 0.088 m (paired t
            -0.7 / -1.9), mean NEES 359 -> 439 / 807 -> 282; ``vslam-gym evaluate`` (seeds
            0-9, ``house`` 0-19) small, curved and ``house`` identical to the last digit,
            single_landmark final error 0.185 -> 0.139 m (t -1.8), ATE 0.176 -> 0.173 m. 0.8
            by default then; 0.7 since session 22 (a rival with 0.72 of the match's inliers
            let an alias 1.8 m along a wall through on a random world), together with
            ``single_line_min_beams`` (measured there).
        loop_strong_inlier_fraction: a revisit match with at least this fraction of
            the scan's points as inliers passes the Mahalanobis test up to
            ``loop_strong_max_mahalanobis`` instead of ``loop_max_mahalanobis``; in
            ``[0, 1]``.
        loop_strong_max_mahalanobis: see ``loop_strong_inlier_fraction``; >= 0, used
            only when larger than ``loop_max_mahalanobis`` (0: off). The pose
            covariance is overconfident after a long loop, and the true closure then
            fails the test (ACES, logged odometry: back at the start 2 m and 3 degrees
            off at a heading standard deviation of 0.5 degrees, a match with 94 % of the
            scan's points as inliers lay 7.2 standard deviations away). Measured 0 ->
            12 (0.8 inliers; docs/measurements.md, "Strong revisit matches"): ACES logged odometry
            position ATE 1.30 -> 1.04 m (final error 0.89 -> 0.28 m), synthetic seeds
            0-9 1.03 -> 1.02 m; Intel synthetic seeds 0-4 0.58 -> 0.54 m, logged 0.68
            -> 0.68 m; the simulated worlds and the 20 random worlds of ``frontier``
            unchanged (no such match). The false match that a gate of 10 admitted (a
            wall 1.5 m along itself) had 42 % inliers. 12 by default.
        loop_correct_keyframes: after a fused revisit match, move the keyframes made since
            those it was matched against by a growing fraction of the correction
            (:meth:`~vslam_gym.slam.loop_closure.RevisitKeyframes.correct_since`), so
            that a later revisit of the places mapped during the drift does not pull the
            pose back into the drifted frame: ``"time"`` (a keyframe made halfway
            between them and now by half of it), ``"variance"`` (by the share of the
            position variance grown by then) or ``"none"`` (keyframes keep the poses they
            were made at). Measured (``logs`` preset, position ATE [m], seeds 0-4 mean /
            logged; docs/measurements.md, "Keyframe correction after a closure"): Intel
            0.54 / 0.68 -> 0.46 / 0.63
            (``"time"``; ten seeds, median 0.53 -> 0.43) and 0.50 / 0.65
            (``"variance"``), ACES 0.94 / 1.04 -> 0.95 / 1.12 and 0.91 / 1.09; ``house``
            seeds 0-19 level; but on the random worlds, where a match is fused on most
            steps, the keyframes are dragged along by every correction (``frontier``, 20
            worlds: coverage 0.324 -> 0.286 / 0.269, ATE 0.112 -> 0.235 / 0.320 m).
            ``"none"`` by default.
    """

    odometry_alphas: tuple[float, float, float, float] = (0.01, 0.005, 0.005, 0.001)
    odometry_sigma_floor: tuple[float, float, float] = (1e-3, 1e-3, 1e-3)
    initial_pose_sigma: tuple[float, float, float] = (1e-4, 1e-4, 1e-5)
    segment_angle_gap: float = 2.0
    segment_distance_gap: float = 1.0
    segment_breakpoint_angle_deg: float = 0.0
    min_set_beams: int = 4
    candidate_margin: float = 2.0
    psi_thres_deg: float = 30.0
    min_object_lines: int = 2
    min_beams_per_object_line: int = 2
    single_line_min_beams: int = 10
    update_max_correction_m2: float = 0.0
    icp_max_pose_mahalanobis: float = 3.0
    icp_gate_sigma_floor: tuple[float, float, float] = (0.2, 0.2, 0.1)
    icp_gate_fallback: bool = False
    icp_gate_includes_reference: bool = False
    icp_prior_point_sigma: float = 0.0
    icp_prior_sigma_floor: tuple[float, float, float] = (0.0, 0.0, 0.0)
    association_pose: str = "icp"
    candidate_max_median_distance: float = 1.5
    candidate_max_near_distance: float = 0.1
    candidate_near_quantile: float = 0.1
    candidate_near_sigma: float = 3.0
    new_landmark: str = "thesis"
    shape_sigma: float = 1e-3
    reference: str = "point"
    reference_heading_sigma: float = 1e-3
    unknown_chain_max_vertices: int = 4
    unknown_chain_tolerance: float = 0.3
    observation_information_scale: float = 1.0
    observation_model_sigma: float = 0.05
    observation_model_heading_sigma: float = 0.01
    creation_heading_model_error: float = 0.0
    min_object_beam_fraction: float = 0.3
    prealign: str = "odometry"
    creation_overlap_distance: float = 0.0
    detection_model_sigma: float = 0.0
    icp_stop_beyond_gate: float = 3.0
    icp_retry_correspondence_distance: float = 0.0
    icp_retry_min_fraction: float = 0.5
    measurement_min_travel: float = 0.15
    measurement_min_turn: float = 0.15
    create_beside_candidates: bool = True
    verify_heading_sigma: float = 3.0
    verify_position_sigma: float = 0.0
    prune_covered_distance: float = 0.0
    prune_covered_fraction: float = 0.8
    prune_idle_steps: int = 20
    prune_merge: bool = False
    prune_merge_max_offset: float = 0.5
    prune_merge_sigma: float = 0.02
    prune_merge_probability: float = 0.99
    loop_closure: bool = True
    loop_radius: float = 3.0
    loop_min_age: int = 60
    loop_keyframe_distance: float = 0.5
    loop_keyframe_heading_deg: float = 15.0
    loop_min_inlier_fraction: float = 0.4
    loop_max_mahalanobis: float = 2.0
    loop_sigma_floor: tuple[float, float, float] = (0.02, 0.02, 0.005)
    loop_cooldown: int = 0
    loop_track_hypotheses: int = 0
    loop_min_innovation: float = 0.0
    loop_max_correction: float = math.inf
    repeat_updates: float = 0.0
    error_noise_scale: float = 10.0
    error_creation_pose_update: bool = False
    loop_strong_inlier_fraction: float = 0.8
    loop_strong_max_mahalanobis: float = 12.0
    loop_prior_rival: float = 0.7
    loop_correct_keyframes: str = "none"
    loop_max_distance_start: float = 2.0
    loop_max_distance_mid: float = 1.0
    loop_min_points: int = 10

    def __post_init__(self) -> None:
        check_field_types(self)
        for name in (
            "icp_gate_sigma_floor",
            "loop_sigma_floor",
            "icp_prior_sigma_floor",
            "odometry_sigma_floor",
            "initial_pose_sigma",
        ):
            self._nonnegative_numbers(name)
        self._nonnegative_numbers("odometry_alphas", 4)
        check_intervals(
            self,
            {
                "icp_retry_min_fraction": "[0, 1]",
                "min_object_beam_fraction": "[0, 1]",
                "loop_min_inlier_fraction": "[0, 1]",
                "loop_strong_inlier_fraction": "[0, 1]",
                "candidate_near_quantile": "[0, 1]",
                "measurement_min_travel": "[0, inf)",
                "measurement_min_turn": "[0, inf)",
                "loop_keyframe_distance": "[0, inf)",
                "loop_keyframe_heading_deg": "[0, inf)",
                "candidate_near_sigma": "[0, inf)",
                "icp_stop_beyond_gate": "[0, inf]",
                "icp_retry_correspondence_distance": "[0, inf]",
                "icp_prior_point_sigma": "[0, inf]",
                "detection_model_sigma": "[0, inf]",
                "creation_overlap_distance": "[0, inf]",
                "verify_heading_sigma": "[0, inf]",
                "update_max_correction_m2": "[0, inf]",
                "verify_position_sigma": "[0, inf]",
                "prune_covered_distance": "[0, inf]",
                "prune_merge_sigma": "[0, inf]",
                "observation_model_sigma": "[0, inf]",
                "observation_model_heading_sigma": "[0, inf]",
                "creation_heading_model_error": "[0, inf]",
                "loop_min_innovation": "[0, inf]",
                "loop_max_correction": "(0, inf]",
                "repeat_updates": "[0, inf)",
                "error_noise_scale": "[0, inf)",
                "loop_strong_max_mahalanobis": "[0, inf]",
                "candidate_max_near_distance": "[0, inf]",
                "prune_merge_max_offset": "(0, inf)",
                "reference_heading_sigma": "(0, inf)",
                "loop_radius": "(0, inf)",
                "loop_max_mahalanobis": "(0, inf)",
                "loop_max_distance_start": "(0, inf)",
                "loop_max_distance_mid": "(0, inf)",
                "segment_breakpoint_angle_deg": "[0, 90)",
                "prune_covered_fraction": "(0, 1]",
                "prune_merge_probability": "(0, 1)",
                "segment_angle_gap": "(0, inf)",
                "segment_distance_gap": "(0, inf)",
                "candidate_margin": "[0, inf]",
                "psi_thres_deg": "[0, inf)",
                "icp_max_pose_mahalanobis": "(0, inf]",
                "candidate_max_median_distance": "(0, inf]",
                "shape_sigma": "(0, inf)",
                "unknown_chain_tolerance": "[0, inf)",
                "observation_information_scale": "(0, inf)",
                "loop_prior_rival": "[0, 1]",
            },
        )
        check_integers(
            self,
            {
                "min_set_beams": 1,
                "min_object_lines": 1,
                "min_beams_per_object_line": 1,
                "single_line_min_beams": 0,
                "unknown_chain_max_vertices": 0,
                "prune_idle_steps": 1,
                "loop_min_age": 1,
                "loop_cooldown": 0,
                "loop_track_hypotheses": 0,
                "loop_min_points": 3,
            },
        )
        if self.new_landmark not in NEW_LANDMARKS:
            raise ValueError(
                f"FilterConfig.new_landmark must be one of {NEW_LANDMARKS}, got "
                f"{self.new_landmark!r}"
            )
        if self.reference not in REFERENCES:
            raise ValueError(
                f"FilterConfig.reference must be one of {REFERENCES}, got {self.reference!r}"
            )
        if self.association_pose not in ASSOCIATION_POSES:
            raise ValueError(
                f"FilterConfig.association_pose must be one of {ASSOCIATION_POSES}, got "
                f"{self.association_pose!r}"
            )
        if self.loop_correct_keyframes not in KEYFRAME_CORRECTIONS:
            raise ValueError(
                f"FilterConfig.loop_correct_keyframes must be one of {KEYFRAME_CORRECTIONS}, "
                f"got {self.loop_correct_keyframes!r}"
            )
        if self.prealign not in PREALIGN_MODES:
            raise ValueError(
                f"FilterConfig.prealign must be one of {PREALIGN_MODES}, got {self.prealign!r}"
            )

    def _nonnegative_numbers(self, name: str, size: int = 3) -> None:
        """Check ``size`` finite numbers >= 0 and store them as a tuple (hashable)."""
        value = getattr(self, name)
        try:
            floor = np.asarray(value, dtype=float)
        except (TypeError, ValueError):
            floor = np.zeros(0)
        if floor.shape != (size,) or not np.isfinite(floor).all() or np.any(floor < 0):
            raise ValueError(
                f"FilterConfig.{name} must be {size} finite numbers >= 0, got {value!r}"
            )
        # A frozen config stays hashable when built from JSON lists.
        object.__setattr__(self, name, tuple(float(v) for v in floor))

    @classmethod
    def thesis(cls, **overrides: Any) -> FilterConfig:
        """The thesis's filter.

        No chain pruning, ICP plausibility gate (so no stop beyond it), update
        verification, model-error terms, loop closure, near-candidate or object-beam
        test, update from one long line, whole-scan prealignment, or motion filter (every
        scan is measured); the belief reports the filter's own covariance (no
        ``error_noise_scale``).
        """
        base: dict[str, Any] = dict(
            single_line_min_beams=0,
            unknown_chain_max_vertices=0,
            candidate_max_median_distance=float("inf"),
            candidate_max_near_distance=float("inf"),
            min_object_beam_fraction=0.0,
            icp_max_pose_mahalanobis=float("inf"),
            icp_gate_sigma_floor=(0.0, 0.0, 0.0),
            icp_gate_fallback=False,
            verify_heading_sigma=0.0,
            observation_model_sigma=0.0,
            observation_model_heading_sigma=0.0,
            loop_closure=False,
            prealign="none",
            measurement_min_travel=0.0,
            measurement_min_turn=0.0,
            error_noise_scale=0.0,
            icp_stop_beyond_gate=0.0,
        )
        base.update(overrides)
        return dataclass_from_dict(cls, base)

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> FilterConfig:
        """Build from a mapping; unknown keys raise ``UnknownKeyError``."""
        return dataclass_from_dict(cls, data)
