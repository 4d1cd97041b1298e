"""The vertex-landmark SLAM filter (thesis chapter 4, SPEC section 10).

:class:`VertexSLAM` takes, per step, the odometry increments and one scan as arrays and
returns a :class:`Belief`. One step:

1. validate the inputs (nothing changes on bad input);
2. motion update of the pose block (:mod:`vslam_gym.slam.motion`);
3. segmentation into measurement sets (:mod:`vslam_gym.slam.segmentation`); sets with
   fewer than ``n_thres`` beams, or whose initial model (Algorithm 3) is one line, are not
   used;
4. correspondence per set: landmarks near the set, ICP to each
   (:func:`~vslam_gym.slam.icp.align`), the detection test at the aligned pose
   (:func:`~vslam_gym.slam.detection.detect`, all candidates of a set in one batch),
   maximum of the set likelihood plus the pose prior; an association updates only with
   two object lines of two beams each;
5. per association: the model update (:func:`~vslam_gym.slam.update.update_model`) gives
   ``Phi3``; the canonical state-space update
   (:func:`~vslam_gym.slam.state_update.state_space_update`) gives the new belief and
   the landmark's ``p(v | r)``;
6. new landmarks from unmatched sets that pass the detectability test;
7. every model's vertices recomputed from its reference.

Frames: the state pose is the LIDAR's pose ``[x, y, theta]`` in the world (map) frame,
which is the initial lidar pose's frame; odometry increments are the robot's and are
carried over to the lidar through the fixed ``SensorConfig.lidar_offset``.
"""

from __future__ import annotations

import math
import time
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from scipy.special import gammaincinv

from vslam_gym.config_utils import check_keys
from vslam_gym.slam import error_covariance
from vslam_gym.slam.config import FilterConfig, ModelConfig, SensorConfig
from vslam_gym.slam.creation import create_model, several_groups
from vslam_gym.slam.creation import point_covariances as _point_covariances
from vslam_gym.slam.detection import detect_many, model_parts
from vslam_gym.slam.gaussian import inflated_information, make_linearization, symmetrize
from vslam_gym.slam.geometry import stack_last, wrap_angle
from vslam_gym.slam.icp import (
    IcpConfig,
    IcpResult,
    LineGeometry,
    PoseBound,
    align,
    align_many,
    candidate_landmarks,
    line_geometry,
)
from vslam_gym.slam.landmark import LandmarkModel, prune_unknown_chains
from vslam_gym.slam.likelihood import exponential_rate
from vslam_gym.slam.loop_closure import LoopClosure
from vslam_gym.slam.motion import (
    check_increments,
    compose,
    frame_rotation,
    increment_to_relative,
    increments_between,
    inverse,
    motion_update,
    odometry_noise,
    predict_pose,
    relative_motion_update,
)
from vslam_gym.slam.pruning import (
    TranslationFit,
    covered_fraction,
    fit_translation,
    object_segments,
    sample_segments,
)
from vslam_gym.slam.scan import Scan
from vslam_gym.slam.scan_matching import (
    LocalMap,
    ScanMatcherConfig,
    ScanNormals,
    match_scan,
    scan_normals,
    scan_points,
)
from vslam_gym.slam.segmentation import segment_scan
from vslam_gym.slam.state_update import (
    POSE_DIM,
    POSE_REF_DIM,
    REF_DIM,
    LandmarkConditional,
    augment_landmark,
    pose_measurement_update,
    rotation_columns,
    state_space_update,
)
from vslam_gym.slam.threads import blas_threads as blas_limit
from vslam_gym.slam.threads import check_blas_threads
from vslam_gym.slam.update import update_model, update_unknown_lines, wrap_model

STEP_PARTS = ("motion", "loop_closure", "landmarks")
"""The parts of a step timed in ``Belief.step_ms_parts``."""
LOGS_OBSERVATION_INFORMATION_SCALE = 0.1
"""``FilterConfig.observation_information_scale`` of the ``logs`` preset. First 300
scans, synthetic seeds 0-1 and logged, with ``create_beside_candidates=False``
(position ATE [m], scale 1 -> 0.1): Intel 0.41 0.39 0.48 -> 0.38 0.36 0.49, ACES 1.38
1.96 2.04 -> 0.69 1.10 1.37."""
LOGS_MATCHER_NORMAL_AGREEMENT_DEG = 30.0
"""``ScanMatcherConfig.normal_agreement_deg`` of the ``logs`` preset [deg]. Full Radish
logs, position ATE [m], 0 -> 30 (session 39, docs/radish.md, "Normal agreement in the
matcher"): logged odometry, two round-off samples, Intel 0.679 / 0.681 -> 0.413 / 0.413,
ACES 1.027 / 0.953 -> 0.617 / 0.545; synthetic odometry, seeds 0-19 mean, Intel 0.485
-> 0.358 (paired t -3.8), ACES 1.229 -> 1.319 (paired t +0.9; seeds 0-4 1.007 ->
1.000)."""
DEFAULT_MATCHER_SIGMA_FLOOR = (0.002, 0.002, 0.0005)
"""``ScanMatcherConfig.sigma_floor`` of the default preset ``(x [m], y [m], theta [rad])``:
the matched motion of ``prealign="odometry"`` and the loop closure's revisit match. The
logs' floor ``(0.01, 0.01, 0.002)`` (the ``logs`` and ``fast`` presets) made the matched
motion's covariance ten to a hundred times its heading error's drift over fifty steps
(matched increments alternate in sign; docs/measurements.md, "Scan-matched motion on the
simulated worlds"). Seeds 0-9 (``house`` 0-19), two round-off samples, logs' -> this
floor with ``covariance_inflation`` below: position ATE single_landmark / small / curved
/ ``house`` 0.116 / 0.088 / 0.119 / 0.162 -> 0.119 / 0.091 / 0.075 / 0.161 m and 0.116 /
0.089 / 0.118 / 0.170 -> 0.119 / 0.090 / 0.075 / 0.158 m; the ``frontier`` explorer's
position ATE on worlds 1000-1039 0.126 -> 0.096 m."""
DEFAULT_MATCHER_COVARIANCE_INFLATION = 3.0
"""``ScanMatcherConfig.covariance_inflation`` of the default preset (see
:data:`DEFAULT_MATCHER_SIGMA_FLOOR`; the logs' 10 in the ``logs`` and ``fast`` presets)."""
DEFAULT_MATCHER_KEYFRAMES = 40
"""``ScanMatcherConfig.keyframes`` of the default preset: the matched motion's local map
holds the last 40 measured scans (about 6 m of travel under the motion filter) instead of
20, so a robot that drives back and forth matches against its earlier pass for longer
and its matched motion drifts less (docs/measurements.md, "Session 37"). The pose error
of the ``frontier`` explorer grows almost only through the matched motion (worlds
1000-1019: the landmark updates and revisit matches change it by a few centimetres
over all steps). 20 -> 40, the ``frontier`` explorer on the held-out worlds 1000-1059:
position ATE 0.0514 -> 0.0462 m (paired t -1.5, 39 worlds better, 21 worse), coverage
0.317 -> 0.328; the routes (seeds 0-9, position ATE m) single_landmark 0.094 -> 0.097,
``small`` 0.065 -> 0.043, ``curved`` 0.052 -> 0.054, ``house`` 0.128 -> 0.117 (seeds
0-19 0.123 / 0.112 -> 0.109 / 0.116 in two round-off samples: level); ``curved``'s
steps in the NEES band 95 -> 89.95 %. 80 keyframes: worlds 1000-1019 0.0466 m (40:
0.0412 m). The ``logs`` and ``fast`` presets keep 20."""

CORRECTION_RANK_TOLERANCE = 1e-6
"""Directions whose correction variance is below this times the largest are left out of
:meth:`VertexSLAM._plausible_correction` (the update hardly informs them; round-off there
would dominate the test)."""


@dataclass(frozen=True)
class SlamConfig:
    """Everything the estimator is configured with, in three typed parts.

    Attributes:
        model: landmark-model parameters (chapter 3).
        filter: filter parameters (chapter 4).
        icp: ICP parameters (4.3.4-4.3.16): point-to-line, with the association frozen
            once it cycles (``IcpConfig.freeze_on_cycle``; measured in
            docs/measurements.md, "ICP cycles": level accuracy, 15-34 % less filter time per step).
        matcher: whole-scan matcher parameters, used by ``filter.prealign`` and the
            loop closure (``filter.loop_closure``): by default a tighter matched
            covariance than the logs' (:data:`DEFAULT_MATCHER_SIGMA_FLOOR`,
            :data:`DEFAULT_MATCHER_COVARIANCE_INFLATION`) and a longer local map
            (:data:`DEFAULT_MATCHER_KEYFRAMES`).
    """

    model: ModelConfig = field(default_factory=ModelConfig)
    filter: FilterConfig = field(default_factory=FilterConfig)
    icp: IcpConfig = field(
        default_factory=lambda: IcpConfig(point_to_line=True, freeze_on_cycle=True)
    )
    matcher: ScanMatcherConfig = field(
        default_factory=lambda: ScanMatcherConfig(
            sigma_floor=DEFAULT_MATCHER_SIGMA_FLOOR,
            covariance_inflation=DEFAULT_MATCHER_COVARIANCE_INFLATION,
            keyframes=DEFAULT_MATCHER_KEYFRAMES,
        )
    )

    @classmethod
    def thesis(cls) -> SlamConfig:
        """The faithful thesis configuration.

        ``ModelConfig.thesis()``, ``FilterConfig.thesis()`` and the thesis's
        point-to-foot-point ICP (the default's point-to-line ICP reaches the same pose in
        about 4 iterations instead of about 35).
        """
        return cls(
            model=ModelConfig.thesis(),
            filter=FilterConfig.thesis(),
            icp=IcpConfig(point_to_line=False),
        )

    @classmethod
    def logs(cls) -> SlamConfig:
        """The default plus what real lidar logs need (README, "Replaying a Carmen log").

        ``filter.prealign="odometry"`` (scan-matched motion, :mod:`scan_matching`) and
        the ICP pose gate (``icp_max_pose_mahalanobis``, 3) with the reference's
        uncertainty (``icp_gate_includes_reference``) and no floor: per-landmark ICP
        poses tens of degrees off the (now good) prediction are not candidates. The
        default's floor (``icp_gate_sigma_floor``) measured much worse on the logs (see
        its docstring). The matcher resolves an ambiguous match with the prior instead
        of falling back to the odometry (``on_ambiguity="prior"``); it matches against
        its last keyframes only (no ``revisit_radius``: the filter's loop closure does
        what its revisits did, see below); the landmark
        layer creates no landmark beside a tested candidate
        (``create_beside_candidates=False``: 50-100 landmarks instead of 300-500 in the
        first 300 scans) and weighs its observations with
        ``observation_information_scale`` (the matched motion stays the main pose
        information). The default's loop closure by revisits (``loop_closure``) is on
        here too (ACES 1.38 -> 0.94 m with synthetic odometry), with its strong matches
        (``loop_strong_max_mahalanobis``: ACES logged odometry 1.30 -> 1.04 m); right
        after a fused revisit match the next starts from the predicted heading only
        (``loop_track_hypotheses=1``: 4-5 % less time per scan on Intel, accuracy
        level), and the update after a fused match tries none (``loop_cooldown=2``:
        2-5 % less time per scan, accuracy level); a per-landmark ICP stops once it
        leaves ten times the gate (``icp_stop_beyond_gate=10``: 6-9 % less time per
        scan, accuracy level) and one that alternates stops at its first return
        (``IcpConfig.cycle_returns=1``: the same results up to the tolerances, 3-8 % less
        time per scan). The matcher pairs a scan point with a map point only when their
        normals agree within 30 deg (:data:`LOGS_MATCHER_NORMAL_AGREEMENT_DEG`, since
        session 39: the logged odometry's position ATE Intel 0.68 -> 0.41 m, ACES 1.03
        -> 0.62 m). Figures in docs/radish.md.

        The matcher's revisits (older keyframes within 3 m of the prediction, an
        implicit loop closure in the matcher's own frame) were in this preset before the
        filter had its loop closure. With it they only turn a revisit into a jump of the
        matched motion, which the motion update cannot carry over to the landmarks.
        Without them (2026-11-26; full logs, position ATE [m], synthetic seeds 0-19 mean,
        logged odometry over six round-off samples): Intel 1.10 -> 0.48 (seed 7's
        quarter turn at a corridor junction, 12.8 m, is gone; the other seeds level),
        logged 0.67 -> 0.67; ACES 1.13 -> 1.25 (paired t +1.2; seeds 0-4 0.94 -> 1.05),
        logged 1.04-1.12 -> 0.96-0.97. A 1.5 m radius: Intel 0.63 (one seed 2.45), ACES
        1.13, logged 1.11. Before the loop closure, on the matcher alone (synthetic seeds
        0-4 / logged): off Intel 0.81 / 0.76, ACES 1.49 / 1.61; 3 m 0.59 / 0.67, 1.37 /
        1.61; 5 m 0.62 / 0.69, 1.53 / 1.55; 8 m (30 keyframes) 1.15 / 0.67, 1.72 / 1.74.
        """
        return cls(
            filter=FilterConfig(
                prealign="odometry",
                icp_gate_sigma_floor=(0.0, 0.0, 0.0),
                icp_gate_includes_reference=True,
                create_beside_candidates=False,
                observation_information_scale=LOGS_OBSERVATION_INFORMATION_SCALE,
                # Measured no better here (full logs, seeds 0-4, position ATE mean:
                # Intel 0.61 -> 0.59 m, ACES 1.36 -> 1.42 m, logged odometry level).
                verify_heading_sigma=0.0,
                # Model-error terms measured mixed here (full logs, synthetic seeds 0-4
                # mean / logged, position ATE: Intel 0.57 / 0.75 m, with the floor 0.05
                # m 0.60 / 0.70, with the 0.01 rad orientation term too 0.56 / 0.79;
                # ACES 1.43 / 1.31, 1.33 / 1.42, 1.39 / 1.45).
                observation_model_sigma=0.0,
                observation_model_heading_sigma=0.0,
                # Measured worse here (logged odometry, position ATE: 0.1 m, no sigma
                # term: Intel 0.68 -> 0.72 m, ACES 1.30 -> 1.44 m; 0.2 m: 0.65 / 1.25 m,
                # but 1.5-2 times the landmarks).
                candidate_max_near_distance=float("inf"),
                # Measured worse here (0 -> 0.3, full logs, synthetic seeds 0-4 mean /
                # logged, position ATE: Intel 0.58 / 0.68 -> 0.56 / 0.68 m, ACES 0.94 /
                # 1.30 -> 1.25 / 1.29 m, seed 0 0.39 -> 2.00 m).
                min_object_beam_fraction=0.0,
                # Right after a fused revisit match, the next one from the predicted
                # heading only (docs/radish.md, "Speed"): Intel 4-5 % less time per
                # scan, ACES unchanged; position ATE level (synthetic seeds 0-19 mean
                # Intel 0.478 -> 0.479 m, ACES 1.237 -> 1.244 m; logged over five
                # round-off samples Intel 0.672 -> 0.670-0.673 m, ACES 0.966 -> 0.963 m).
                loop_track_hypotheses=1,
                # After a fused revisit match the next measurement update tries none
                # (the tracking above then applies to the one after it): Intel fuses a
                # match on most updates. Measured (2026-11-26, docs/radish.md "Speed,
                # second round"; 0 -> 2, two round-off samples): synthetic seeds 0-19
                # Intel 0.480 / 0.480 -> 0.481 / 0.483 m, ACES 1.298 / 1.251 -> 1.290 /
                # 1.251 m; logged (five samples) Intel 0.670-0.673 -> 0.674-0.676 m,
                # ACES 0.951-0.963 -> 0.936-0.953 m; 2-5 % less time per scan.
                loop_cooldown=2,
                # The revisit match keeps its matcher's 20 points (the default's 10 was
                # measured on the simulated worlds only).
                loop_min_points=20,
                # A per-landmark ICP stops once its pose leaves 10 times the gate (30
                # Mahalanobis units): on the Intel log 30 % of the alignments wander
                # off, up to metres, until they lose their points, and those that go
                # that far do not come back into the gate. Measured (2026-11-26,
                # docs/radish.md "Speed, second round"; 0 -> 10, two round-off samples):
                # synthetic seeds 0-19 Intel 0.481 / 0.483 -> 0.483 / 0.485 m, ACES
                # 1.290 / 1.251 -> 1.281 / 1.252 m; logged (five samples) Intel
                # 0.674-0.676 -> 0.680 m, ACES 0.936-0.953 -> 0.952-0.953 m; 6-9 % less
                # time per scan. 3 (9 units) lost ACES: seeds 0-19 1.50 m, logged 1.04 m.
                icp_stop_beyond_gate=10.0,
                # Measured level or mixed here (2026-11-26, session 21, 0 -> 0.8): Intel
                # logged 0.680 -> 0.680 m, synthetic seeds 0-19 0.483 -> 0.492 m; ACES
                # logged 0.953 -> 0.949 m (final error 0.069 -> 0.435 m), synthetic
                # 1.281 -> 1.280 m.
                loop_prior_rival=0.0,
                # The default's limit until session 28 (the logs' figures were measured
                # with it; without the gate's floor here, 6 units are tens of
                # centimetres, not the default's metre).
                loop_max_mahalanobis=6.0,
                # The default's since session 36 (the revisit matches' noise floored);
                # the logs' figures were measured without it.
                loop_sigma_floor=(0.0, 0.0, 0.0),
                # Measured mixed here (session 21, 0 -> 10): Intel logged 0.680 ->
                # 0.660 m, synthetic seeds 0-19 0.483 -> 0.476 m; ACES logged 0.953 ->
                # 1.060 m (final error 2.0 m), synthetic 1.281 -> 1.272 m.
                single_line_min_beams=0,
                # Every scan is measured (the logs' figures were measured so; the
                # default's motion filter is not measured here).
                measurement_min_travel=0.0,
                measurement_min_turn=0.0,
            ),
            # No freeze_on_cycle: measured no better here (full logs, seeds 0-4, position
            # ATE mean: Intel 0.61 -> 0.59 m, ACES 1.36 -> 1.44 m; step time unchanged).
            # cycle_returns=1: an alignment whose association alternates stops at its
            # first return and reports the state it would have had at max_iterations
            # (389 of the 5 185 alignments of the Intel logged run ran to the limit, 44 %
            # of the ICP iterations). The same results up to the tolerances; measured
            # (2026-11-26, docs/radish.md "Speed, second round"): 3-8 % less time per
            # scan, ATE level.
            icp=IcpConfig(point_to_line=True, cycle_returns=1),
            matcher=ScanMatcherConfig(
                on_ambiguity="prior", normal_agreement_deg=LOGS_MATCHER_NORMAL_AGREEMENT_DEG
            ),
        )

    @classmethod
    def fast(cls) -> SlamConfig:
        """The default traded for throughput (reinforcement-learning training).

        ``association_pose="predicted_first"`` (per-landmark ICP only for candidates the
        detection test rejects at the predicted pose) and a motion filter of 0.2 m / 0.2 rad
        (``measurement_min_travel``, ``measurement_min_turn``), without the default's update
        verification (``verify_heading_sigma``). Measured (docs/measurements.md, "The `fast`
        preset"): 2.5-3.5 times less CPU time per step than the default of then (every scan
        measured; since session 26 the default measures after 0.15 m or 0.15 rad), at a
        larger position ATE. The default's loop closure by revisits (``loop_closure``) is on
        here too (seeds 0-9, off -> on, final error: small 0.181 -> 0.034 m, curved 0.083 ->
        0.047 m, ``house`` 0.681 -> 0.354 m; single_landmark unchanged). Its per-landmark
        ICP has a weak prior at the predicted pose (``icp_prior_point_sigma=0.03`` with the
        gate's floor): better or level on every world in two round-off samples
        (docs/measurements.md, "ICP pose prior").

        Without the default's scan-matched motion, for throughput. With it (``{"preset":
        "fast", "filter": {"prealign": "odometry"}, "matcher": {"sigma_floor": [0.002,
        0.002, 0.0005], "covariance_inflation": 3}}``; under the motion filter the match
        runs only on the steps that measure) it measured much more accurate but slower
        (session 25, docs/measurements.md, "Scan-matched motion in the `fast` preset";
        seeds 0-9, ``house`` 0-19): position ATE single_landmark / small / curved /
        ``house`` 0.232 / 0.147 / 0.117 / 0.368 -> 0.193 / 0.085 / 0.085 / 0.157-0.163
        m, ``house`` final error 0.331 -> 0.019-0.020 m; the ``frontier`` explorer on
        worlds 1000-1039 ATE 0.133 -> 0.082 m at level coverage; but 80-105 / 61-91
        instead of 101-105 / 79-95 steps/s on random worlds / ``house``
        (``bench_wrapper.py``, three alternating runs), this preset's own target.
        """
        return cls(
            filter=FilterConfig(
                association_pose="predicted_first",
                measurement_min_travel=0.2,
                measurement_min_turn=0.2,
                # Measured mixed here (seeds 0-9, 0 -> 3: house ATE 0.61 -> 0.49 m but
                # final error 0.90 -> 1.12 m, the other worlds level).
                verify_heading_sigma=0.0,
                # The default's model-error terms (observation_model_sigma 0.05 m and
                # observation_model_heading_sigma 0.01 rad) are kept: seeds 0-9, position
                # ATE single_landmark / small / curved / house 0.262 / 0.209 / 0.207 /
                # 0.639 -> 0.251 / 0.213 / 0.170 / 0.510 m, final error better on every
                # world (the floor alone: small 0.302 m, t +2.7).
                # Measured worse here (seeds 0-9, inf -> 0.1 m with 3 sigma: house ATE
                # 0.436 -> 0.550 m, final error 0.354 -> 0.829 m, the others level).
                candidate_max_near_distance=float("inf"),
                # Seeds 0-9 (house 0-19), two round-off samples, without -> with: ATE
                # 0.242 / 0.202 / 0.161 / 0.392 -> 0.232 / 0.147 / 0.121 / 0.372 m and
                # 0.240 / 0.202 / 0.163 / 0.413 -> 0.232 / 0.145 / 0.110 / 0.391 m,
                # final error and NEES level or better; the frontier agent on 20 held-out
                # random worlds level (coverage 0.274 -> 0.281, ATE 0.153 -> 0.140 m).
                icp_prior_point_sigma=0.03,
                icp_prior_sigma_floor=(0.2, 0.2, 0.1),
                # Measured no better here (session 21, 0 -> 0.8): the frontier agent on
                # worlds 1000-1019 coverage 0.281 -> 0.278, ATE 0.140 -> 0.153 m (t +0.8);
                # seeds 0-9 single_landmark final error 0.275 -> 0.210 m, the other
                # routes identical.
                loop_prior_rival=0.0,
                # The default's limit until session 28. Measured worse here with 2 (its
                # motion is odometry, so a loop's drift is larger): `house` seeds 0-19
                # final error 0.331 -> 0.492 m, 16 -> 12 runs within 0.2 m; the other
                # routes level; the frontier agent on worlds 1000-1019 coverage 0.279 ->
                # 0.274, ATE 0.133 -> 0.128 m.
                loop_max_mahalanobis=6.0,
                # The default's since session 36; not measured here (its motion is
                # odometry, so its revisit matches close a larger drift).
                loop_sigma_floor=(0.0, 0.0, 0.0),
                # Not measured here (the default's since session 22, with the rival test
                # that this preset keeps off).
                single_line_min_beams=0,
                # Measured more accurate but slower (see above).
                prealign="none",
                # The default's since session 33; not measured here.
                icp_stop_beyond_gate=0.0,
            ),
            # The loop closure's revisit match with the matcher's own covariance, as
            # measured before session 25 (the default's is tighter since then).
            matcher=ScanMatcherConfig(),
        )

    @classmethod
    def preset(cls, name: str) -> SlamConfig:
        """``"default"``, ``"thesis"``, ``"logs"`` or ``"fast"``."""
        presets = {"default": cls, "thesis": cls.thesis, "logs": cls.logs, "fast": cls.fast}
        check_keys([name], presets, "SlamConfig.preset")
        return presets[name]()

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> SlamConfig:
        """Nested mapping ``{"preset": ..., "model": {...}, "filter": {...}, "icp": {...}}``.

        Unknown keys at any level raise ``UnknownKeyError`` with a suggestion.
        """
        parts_names = ("model", "filter", "icp", "matcher")
        if not isinstance(data, Mapping):
            raise ValueError(f"SlamConfig: a mapping of sections is needed, got {data!r}")
        check_keys(data.keys(), ["preset", *parts_names], "SlamConfig")
        if not isinstance(data.get("preset", "default"), str):
            raise ValueError(f"SlamConfig.preset must be a name, got {data['preset']!r}")
        base = cls.preset(data.get("preset", "default"))
        parts = {}
        for name in parts_names:
            overrides = data.get(name, {})
            if not isinstance(overrides, Mapping):
                raise ValueError(
                    f"SlamConfig.{name} must be a mapping of its fields, got {overrides!r}"
                )
            current = getattr(base, name)
            names = [f for f in current.__dataclass_fields__]
            check_keys(overrides.keys(), names, f"SlamConfig.{name}")
            parts[name] = replace(current, **overrides)
        return cls(**parts)


@dataclass(frozen=True)
class LandmarkView:
    """One landmark of the belief (world frame).

    Attributes:
        id: stable landmark id (creation order).
        reference: ``(2,)`` reference point mean [m].
        reference_cov: ``(2, 2)`` its covariance [m^2] (as ``Belief.pose_cov``).
        model: the vertex model: means, covariance given the reference, ``u``, closed.
        object_vertices: ``(start, stop)``: ``model.mean[start:stop]`` are object
            vertices, the others end vertices of unknown lines.
    """

    id: int
    reference: np.ndarray
    reference_cov: np.ndarray
    model: LandmarkModel
    object_vertices: tuple[int, int]


@dataclass(frozen=True)
class SetDecision:
    """What one measurement set of the last scan did.

    Attributes:
        first: scan index of its first beam.
        last: scan index of its last beam (inclusive).
        outcome: ``"updated"`` (associated, map updated), ``"associated"`` (matched
            but too few object lines observed to update), ``"created"`` (new landmark),
            ``"unmatched"`` (no landmark, not detectable enough to create one, or
            beside a candidate, see ``FilterConfig.create_beside_candidates``),
            ``"overlapping"`` (no landmark accepted it, but its points lie on the object
            lines of the candidate ``landmark``, so no new landmark was made:
            ``FilterConfig.creation_overlap_distance``),
            ``"skipped"`` (too few beams or a single initial line), ``"failed"`` (a
            numerical failure; the state was left as before this set) or
            ``"rejected"`` (the update failed its verification,
            ``FilterConfig.verify_heading_sigma`` and ``verify_position_sigma``; the
            state was left as before it).
        landmark: the landmark id it was associated with or created as, else -1.
        candidates: per landmark tried: ``(id, icp_reason, mean_d2, var_d2, accepted)``
            (detection statistics at the ICP pose; NaN when not tested). ``icp_reason``
            is the ICP's stop reason, ``"far"`` when not aligned, or ``"gated"`` when the
            ICP pose failed the plausibility gate (``FilterConfig.icp_max_pose_mahalanobis``;
            with ``icp_gate_fallback`` the predicted pose was tested instead, else the
            statistics are NaN), or ``"retried"`` when it failed the gate and the
            retry with outlier rejection converged on enough points and passed it
            (``FilterConfig.icp_retry_correspondence_distance``).
    """

    first: int
    last: int
    outcome: str
    landmark: int = -1
    candidates: tuple[tuple[int, str, float, float, bool], ...] = ()


@dataclass(frozen=True)
class Belief:
    """The estimator's belief after a step.

    Attributes:
        step: number of steps taken.
        pose: ``(3,)`` lidar pose mean ``[x, y, theta]`` (world frame).
        pose_cov: ``(3, 3)`` its covariance (with ``FilterConfig.error_noise_scale`` the
            covariance of the estimation error, :mod:`vslam_gym.slam.error_covariance`).
        robot_pose: ``(3,)`` robot pose mean (through the lidar offset).
        landmarks: every landmark.
        decisions: one per measurement set of the last scan.
        state_dim: ``3 + dL`` (``d`` = 2, or 3 with ``FilterConfig.reference="pose"``).
        step_ms: wall time of the last step [ms].
        prealigned: the whole-scan matcher's result was used in the last step
            (``FilterConfig.prealign``).
        measured: the last step ran the landmark measurement update (False when the
            motion filter skipped it: ``FilterConfig.measurement_min_travel``; then
            ``decisions`` is empty).
        pruned: ids of the landmarks removed in the last step as covered duplicates
            (``FilterConfig.prune_covered_distance``).
        loop_closed: the last step fused a revisit match (``FilterConfig.loop_closure``).
        loop_match_pose: ``(3,)`` that match: the lidar pose ``[x, y, theta]`` (world
            frame) it measured; None when no match was fused.
        loop_match_cov: ``(3, 3)`` the noise covariance it was fused with (the match's,
            plus its keyframes' pose covariance and ``FilterConfig.loop_sigma_floor``);
            None when no match was fused.
        step_ms_parts: wall time [ms] of the last step's parts (:data:`STEP_PARTS`):
            ``"motion"`` (the motion update, with the whole-scan matcher when
            ``prealign`` is on), ``"loop_closure"`` (the revisit match and its update),
            ``"landmarks"`` (association, landmark updates and creation, pruning, the
            revisit keyframe); a part that did not run is 0. They add up to
            ``step_ms`` up to the bookkeeping between them.
        filter_pose_cov: ``(3, 3)`` the filter's own pose covariance, the one its gains
            and gates use (``pose_cov`` itself when ``error_noise_scale`` is 0); None
            when not given.
    """

    step: int
    pose: np.ndarray
    pose_cov: np.ndarray
    robot_pose: np.ndarray
    landmarks: tuple[LandmarkView, ...]
    decisions: tuple[SetDecision, ...]
    state_dim: int
    step_ms: float
    prealigned: bool = False
    measured: bool = False
    pruned: tuple[int, ...] = ()
    loop_closed: bool = False
    loop_match_pose: np.ndarray | None = None
    loop_match_cov: np.ndarray | None = None
    step_ms_parts: Mapping[str, float] = field(default_factory=dict)
    filter_pose_cov: np.ndarray | None = None


@dataclass
class _Landmark:
    id: int
    ref: int  # state index of r
    cond: LandmarkConditional
    u: np.ndarray
    closed: bool
    object_vertices: tuple[int, int]
    model: LandmarkModel | None = None
    radius: float = 0.0
    refreshed_at: np.ndarray | None = None  # reference at the last refresh
    # Derived data of ``model`` for the association (built on first use, dropped with it).
    geometry: LineGeometry | None = None  # icp.line_geometry
    parts: Any = None  # detection.model_parts of detection_model
    detection_model: LandmarkModel | None = None  # model with detection_model_sigma
    last_seen: int = 0  # measurement update that last created, associated or updated it
    idle_checked: bool = False  # covered-duplicate test done since it went idle
    heading_sigma: float = 0.0  # orientation model error [rad] of its observations
    updates: int = 0  # state-space updates it has had (creation not counted)


class _MapSnapshot:
    """Every landmark's object radius (the candidate gate) from the references, batched.

    ``p(v | r)`` of landmark ``l`` gives the vertex means ``v = A_l r_l + b_l``. The
    ``A_l`` and ``b_l`` are kept padded to ``(N, 2K, d)`` and ``(N, 2K)`` (a row is
    replaced when that landmark's conditional changes), so that all means and radii
    (:func:`~vslam_gym.slam.icp.object_radius`) follow from the references in a few
    vectorised operations instead of a loop over the map.
    """

    def __init__(self, ref_dim: int = REF_DIM) -> None:
        self.a = np.zeros((0, 0, ref_dim))
        self.b = np.zeros((0, 0))
        self.k = np.zeros(0, dtype=int)
        self.objects = np.zeros((0, 0), dtype=bool)  # vertices on an object line
        self.means = np.zeros((0, 0, 2))
        self.radii = np.zeros(0)

    def set(self, i: int, cond: LandmarkConditional, u: np.ndarray, closed: bool, thr: float):
        """Row ``i`` from a landmark's conditional and line probabilities."""
        n = max(i + 1, self.k.size)
        k = cond.b.size // 2
        width = max(k, self.objects.shape[1])
        if n > self.k.size or width > self.objects.shape[1]:
            a = np.zeros((n, 2 * width, self.a.shape[2]))
            b = np.zeros((n, 2 * width))
            objects = np.zeros((n, width), dtype=bool)
            kk = np.zeros(n, dtype=int)
            m, w = self.k.size, self.objects.shape[1]
            a[:m, : 2 * w], b[:m, : 2 * w], objects[:m, :w], kk[:m] = (
                self.a,
                self.b,
                self.objects,
                self.k,
            )
            self.a, self.b, self.objects, self.k = a, b, objects, kk
        self.a[i] = 0.0
        self.b[i] = 0.0
        self.objects[i] = False
        self.a[i, : 2 * k] = cond.A
        self.b[i, : 2 * k] = cond.b
        self.k[i] = k
        j = np.arange(k if closed else max(k - 1, 0))
        lines = np.stack([j, (j + 1) % k], axis=1)[u <= thr]
        if lines.size:
            self.objects[i, lines.ravel()] = True
        else:  # no object line: all vertices (icp.object_radius)
            self.objects[i, :k] = True

    def delete(self, rows: list[int]) -> None:
        """Drop the rows of removed landmarks (the rest keep their order)."""
        self.a = np.delete(self.a, rows, axis=0)
        self.b = np.delete(self.b, rows, axis=0)
        self.k = np.delete(self.k, rows)
        self.objects = np.delete(self.objects, rows, axis=0)
        self.means = np.delete(self.means, rows, axis=0)
        self.radii = np.delete(self.radii, rows)

    def refresh(self, refs: np.ndarray) -> None:
        """Means ``(N, K, 2)`` and object radii ``(N,)`` [m] at the references ``(N, d)``."""
        means = (self.a @ refs[:, :, None])[:, :, 0] + self.b
        self.means = means.reshape(means.shape[0], -1, 2)
        dist = np.hypot(
            self.means[:, :, 0] - refs[:, 0, None], self.means[:, :, 1] - refs[:, 1, None]
        )
        self.radii = np.max(np.where(self.objects, dist, -np.inf), axis=1)


@dataclass
class _SetWork:
    """A measurement set's candidate landmarks (association, first phase)."""

    first: int
    last: int
    points: np.ndarray  # (n, 2) at the predicted pose
    landmarks: list[_Landmark]
    geometry: list[LineGeometry]
    aligned: np.ndarray  # indices into landmarks that are aligned (not "far")


@dataclass(frozen=True)
class _Overlap:
    """The candidate landmark a set lies closest to (``_choose``)."""

    landmark: int
    distance: float  # median point-to-object-line distance [m]


@dataclass(frozen=True)
class _PoseGate:
    """What one scan's associations judge ICP poses by.

    The pose covariance's Cholesky factor and Gaussian log normaliser, and the ICP
    gate's covariance and its factor (None without a gate).
    """

    chol: np.ndarray
    log_norm: float
    gate_cov: np.ndarray | None
    chol_gate: np.ndarray | None


@dataclass
class _Gated:
    """A set's candidates after the ICP gate.

    ``tried``: per candidate its record (None while untested); ``tested``: ``(candidate,
    pose, reason)`` to test for detection; ``m2s``: their squared Mahalanobis distances
    from the predicted pose.
    """

    tried: list
    tested: list
    m2s: dict


@dataclass
class _Association:
    first: int
    last: int
    landmark: _Landmark
    pose: np.ndarray
    candidates: tuple
    enough: bool
    detection: Any = None


class VertexSLAM:
    """EKF-SLAM with probabilistic-polyline landmarks (thesis chapter 4).

    Args:
        sensor: the lidar as the estimator sees it (FOV, resolution, range, noise,
            lidar offset).
        config: estimator configuration; ``SlamConfig()`` (measured improvements) by
            default, ``SlamConfig.thesis()`` for the faithful thesis.
        initial_pose: the robot's initial pose ``[x, y, theta]``; the map frame.
        blas_threads: threads the BLAS library may use during :meth:`step` (restored
            afterwards; :mod:`vslam_gym.slam.threads`); 1 by default: more threads do
            not speed up the filter's small matrices and slow it down 1.5-fold when
            another process is busy. None leaves the BLAS library alone.

    Example:
        >>> slam = VertexSLAM(SensorConfig())
        >>> belief = slam.step([0.0, 0.0, 0.0], ranges, bearings)  # doctest: +SKIP
    """

    def __init__(
        self,
        sensor: SensorConfig | None = None,
        config: SlamConfig | None = None,
        initial_pose: np.ndarray | tuple[float, float, float] = (0.0, 0.0, 0.0),
        blas_threads: int | None = 1,
    ) -> None:
        if not isinstance(sensor, SensorConfig | None):
            raise TypeError(f"sensor must be a SensorConfig, got {sensor!r}")
        if not isinstance(config, SlamConfig | None):
            raise TypeError(
                "config must be a SlamConfig (SlamConfig.preset(name), "
                f"SlamConfig.from_dict(mapping)), got {config!r}"
            )
        self.sensor = sensor or SensorConfig()
        self.config = config or SlamConfig()
        self.blas_threads = check_blas_threads(blas_threads)
        self._lin = make_linearization(self.config.model)
        self._offset = np.asarray(self.sensor.lidar_offset, dtype=float)
        self._ref_dim = POSE_REF_DIM if self.config.filter.reference == "pose" else REF_DIM
        self.reset(initial_pose)

    # ------------------------------------------------------------------ public API

    def reset(self, initial_pose=(0.0, 0.0, 0.0)) -> Belief:
        """Forget the map; the lidar starts at ``initial_pose (+) lidar_offset``."""
        pose = np.asarray(initial_pose, dtype=float)
        if pose.shape != (3,) or not np.isfinite(pose).all():
            raise ValueError(f"initial_pose must be 3 finite numbers, got {initial_pose!r}")
        self._mu = compose(pose, self._offset)
        self._sigma = np.diag(np.asarray(self.config.filter.initial_pose_sigma) ** 2)
        # FilterConfig.error_noise_scale: the covariance of the estimation error (None: off)
        self._error = self._sigma.copy() if self.config.filter.error_noise_scale > 0 else None
        self._landmarks: list[_Landmark] = []
        self._snapshot = _MapSnapshot(self._ref_dim)
        self._next_id = 0
        self._measurements = 0  # measurement updates run
        self._pruned: tuple[int, ...] = ()
        self._step = 0
        self._decisions: tuple[SetDecision, ...] = ()
        self._step_ms = 0.0
        self._step_ms_parts: dict[str, float] = dict.fromkeys(STEP_PARTS, 0.0)
        self._local_map = LocalMap(self.config.matcher)
        self._matcher_pose = self._mu[:3].copy()  # "odometry": pose in the matcher's frame
        # "odometry" under a motion filter: the odometry since the last match (relative
        # pose, covariance) and the state's pose mean and pose rows then; None: no step
        # since the last match.
        self._pending: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None = None
        self._pending_error: np.ndarray | None = None  # the error covariance's pose rows then
        self._normals: ScanNormals | None = None  # the step's scan normals
        self._loop = self._make_loop_closure()
        self._loop_closed = False
        self._loop_match: tuple[np.ndarray, np.ndarray] | None = None  # fused: pose, cov
        self._prealigned = False
        self._measured = False
        self._measured_at: np.ndarray | None = None  # pose after the last measurement update
        # The landmark views of the belief and the state mean they were made from: every
        # change of the map replaces the mean array (a motion update too, which re-keys them).
        self._views: tuple[LandmarkView, ...] = ()
        self._views_of: np.ndarray | None = None
        return self.belief

    @property
    def belief(self) -> Belief:
        """The current belief.

        Its arrays are copies of the filter's state. The landmark views are made again only
        after a step that may have changed the map: the beliefs of the steps between share
        one ``landmarks`` tuple (the same objects), so treat its arrays as read-only.
        """
        if self._views_of is not self._mu:
            self._views = tuple(self._landmark_view(lm) for lm in self._landmarks)
            self._views_of = self._mu
        pose = self._mu[:3].copy()
        return Belief(
            step=self._step,
            pose=pose,
            pose_cov=self._reported[:3, :3].copy(),
            robot_pose=compose(pose, inverse(self._offset)),
            landmarks=self._views,
            decisions=self._decisions,
            state_dim=int(self._mu.size),
            step_ms=self._step_ms,
            prealigned=self._prealigned,
            measured=self._measured,
            pruned=self._pruned,
            loop_closed=self._loop_closed,
            loop_match_pose=None if self._loop_match is None else self._loop_match[0].copy(),
            loop_match_cov=None if self._loop_match is None else self._loop_match[1].copy(),
            step_ms_parts=dict(self._step_ms_parts),
            filter_pose_cov=self._sigma[:3, :3].copy(),
        )

    @property
    def _reported(self) -> np.ndarray:
        """The covariance the belief reports: the error covariance, else the filter's."""
        return self._sigma if self._error is None else self._error

    def _landmark_view(self, lm: _Landmark) -> LandmarkView:
        r = slice(lm.ref, lm.ref + REF_DIM)  # the point (a landmark frame's origin)
        return LandmarkView(
            id=lm.id,
            reference=self._mu[r].copy(),
            reference_cov=self._reported[r, r].copy(),
            model=_model_copy(self._model(lm)),
            object_vertices=lm.object_vertices,
        )

    def add_start_scan(self, ranges, bearings) -> bool:
        """Give the whole-scan matcher the scan taken at the initial pose, before the first step.

        The scan becomes the matcher's first keyframe, placed at the initial pose: the
        first step's scan is then aligned to it, so the map frame is the start pose's
        exactly. Without it the first keyframe is the first step's scan at the pose the
        odometry predicts, and its heading error (up to 1.4 degrees on the routes)
        rotates everything mapped after it (docs/measurements.md, "Session 33"). No
        landmark is made from it: the landmarks come from the first step on, at the
        matched pose (mapping it as a step of its own, ``step([0, 0, 0], ranges,
        bearings)``, measured worse on ``single_landmark``). Nothing happens without a
        whole-scan matcher (``FilterConfig.prealign="none"``, the ``thesis`` and
        ``fast`` presets).

        Args:
            ranges: ``(n,)`` ranges [m] of the scan taken at the initial pose.
            bearings: ``(n,)`` its bearings [rad] in the lidar frame, strictly descending.

        Returns:
            Whether the matcher keeps the scan (False without a matcher).

        Raises:
            ValueError: a malformed scan (``ScanError``), or the filter has stepped or
                already has a start scan; nothing changes.
        """
        scan = Scan.from_arrays(ranges, bearings, self.sensor)
        if self._step > 0 or len(self._local_map):
            raise ValueError("add_start_scan: only once, before the first step")
        if self.config.filter.prealign == "none":
            return False
        self._add_keyframe(scan_points(scan.ranges, scan.bearings, scan.max_range))
        return True

    def step(self, odometry, ranges, bearings) -> Belief:
        """One motion and measurement update.

        Args:
            odometry: ``(3,)`` robot odometry increments ``[rot1 [rad], trans [m],
                rot2 [rad]]`` since the last step.
            ranges: ``(n,)`` ranges [m]; ``max_range`` or more means no return.
            bearings: ``(n,)`` bearings [rad] in the lidar frame, strictly descending.

        Returns:
            The belief after the step.

        Raises:
            ValueError: malformed odometry (not 3 finite numbers, a rotation beyond a
                full turn, a translation beyond the lidar's ``max_range``) or scan
                (``ScanError``); the belief is left unchanged. The configuration is
                checked when it is built, so these are the step's only input errors. A
                failure inside an accepted step (a numerical one; none is known on the
                worlds or logs) leaves the filter's state undefined: :meth:`reset` it.
                (Keeping a copy to roll back costs about 10 ms per ``house`` step.)
        """
        u = check_increments(odometry, self.sensor.max_range)
        scan = Scan.from_arrays(ranges, bearings, self.sensor)
        start = time.perf_counter()
        with blas_limit(self.blas_threads):
            self._update(u, scan)
        self._step += 1
        self._step_ms = (time.perf_counter() - start) * 1e3
        return self.belief

    def _update(self, u: np.ndarray, scan: Scan) -> None:
        """The motion and measurement updates of :meth:`step` on validated inputs."""
        mode = self.config.filter.prealign
        points = None  # the scan's lidar-frame points, for the whole-scan matcher
        self._normals = None  # their normals, once computed (both keyframe maps use them)
        parts = dict.fromkeys(STEP_PARTS, 0.0)
        self._step_ms_parts = parts
        # A motion update changes the pose rows only: the landmark views stay valid then.
        views_valid = self._views_of is self._mu
        start = time.perf_counter()
        if mode != "none":
            points = scan_points(scan.ranges, scan.bearings, scan.max_range)
        measured = None
        if mode == "none":
            self._motion_update(u)
            self._prealigned = False
        elif mode == "odometry" and self._motion_filtered():
            measured = self._filtered_matched_motion_update(u, points)
        elif mode == "odometry":
            self._prealigned = self._matched_motion_update(u, points)
        else:
            self._motion_update(u)
            self._prealigned = self._fuse_match(points)
        self._measured = self._moved_enough() if measured is None else measured
        self._pruned = ()
        self._loop_closed = False
        self._loop_match = None
        parts["motion"] = (time.perf_counter() - start) * 1e3
        if self._measured:
            self._measurements += 1
            if self._loop is not None:
                start = time.perf_counter()
                if points is None:  # only steps that measure need them
                    points = scan_points(scan.ranges, scan.bearings, scan.max_range)
                self._loop_closed = self._close_loop(points)
                parts["loop_closure"] = (time.perf_counter() - start) * 1e3
            start = time.perf_counter()
            self._decisions = tuple(self._measurement_update(scan))
            self._refresh_models()
            if self.config.filter.prune_covered_distance > 0.0:
                self._pruned = self._prune_covered()
            self._measured_at = self._mu[:3].copy()
            if self._loop is not None:
                self._loop.add(
                    points, self._mu[:3], self._sigma[:3, :3], self._measurements, self._normals
                )
            parts["landmarks"] = (time.perf_counter() - start) * 1e3
        else:
            self._decisions = ()
        if mode == "fuse":
            start = time.perf_counter()
            self._local_map.add(points, self._mu[:3])
            parts["motion"] += (time.perf_counter() - start) * 1e3
        elif not self._measured and views_valid:
            self._views_of = self._mu

    def _motion_filtered(self) -> bool:
        """Whether a motion filter (``measurement_min_travel``/``_turn``) is on."""
        cfg = self.config.filter
        return cfg.measurement_min_travel > 0.0 or cfg.measurement_min_turn > 0.0

    def _moved_enough(self, pose: np.ndarray | None = None) -> bool:
        """Whether the motion filter lets this step run the measurement update.

        ``pose``: the pose mean to test (default: the state's). True on the first step,
        and once the pose mean has moved
        ``measurement_min_travel`` [m] or turned ``measurement_min_turn`` [rad] since the
        last measurement update (always, when both are 0).
        """
        cfg = self.config.filter
        if self._measured_at is None or (
            cfg.measurement_min_travel <= 0.0 and cfg.measurement_min_turn <= 0.0
        ):
            return True
        d = (self._mu[:3] if pose is None else pose) - self._measured_at
        travel = float(np.hypot(d[0], d[1]))
        turn = abs(float(wrap_angle(d[2])))
        return bool(
            (cfg.measurement_min_travel > 0.0 and travel >= cfg.measurement_min_travel)
            or (cfg.measurement_min_turn > 0.0 and turn >= cfg.measurement_min_turn)
        )

    # ------------------------------------------------------------------ motion

    def _lidar_increments(self, u: np.ndarray) -> np.ndarray:
        """Robot increments carried over to the lidar through the fixed offset."""
        if not np.any(self._offset):
            return u
        robot_delta = np.array([u[1] * np.cos(u[0]), u[1] * np.sin(u[0]), u[0] + u[2]])
        lidar_delta = compose(compose(inverse(self._offset), robot_delta), self._offset)
        return increments_between(np.zeros(3), lidar_delta)

    def _odometry_noise(self, u: np.ndarray) -> np.ndarray:
        cfg = self.config.filter
        return odometry_noise(u, cfg.odometry_alphas, np.asarray(cfg.odometry_sigma_floor))

    def _motion_update(self, u: np.ndarray) -> None:
        self._odometry_update(self._lidar_increments(u), self._odometry_noise(u))

    def _odometry_update(self, lidar_u: np.ndarray, noise: np.ndarray) -> None:
        """The motion update with lidar increments ``lidar_u`` and their ``noise``."""
        if self._error is not None:  # affine in the covariance: the same update
            self._error = motion_update(self._mu, self._error, lidar_u, noise)[1]
        self._mu, self._sigma = motion_update(self._mu, self._sigma, lidar_u, noise)

    # ------------------------------------------------------------------ prealignment

    def _matched_motion_update(self, u: np.ndarray, points: np.ndarray) -> bool:
        """``prealign="odometry"``: motion update with the scan-matched relative pose.

        The matcher keeps its own trajectory (``_matcher_pose``) and local map. The scan
        is aligned with the odometry's prediction as prior (maximum a posteriori, so the
        result already contains the odometry); the relative pose from the matcher's
        previous pose to the aligned one drives the filter's motion update. Without a
        match, the odometry. Returns whether the match was used.
        """
        delta, cov = increment_to_relative(self._lidar_increments(u), self._odometry_noise(u))
        return self._matched_relative_update(delta, cov, points)

    def _filtered_matched_motion_update(self, u: np.ndarray, points: np.ndarray) -> bool:
        """``prealign="odometry"`` under a motion filter; returns whether the step measures.

        The matcher runs only on the steps that measure (about half of the steps under
        the default's motion filter on the routes). Between them the belief follows
        the odometry, and the odometry is also composed into a relative pose since the
        last match. On a step that measures, the pose rows of the state go back to their
        values after the last measurement update (motion updates change nothing else)
        and one motion update with the matched relative pose since then, the composed
        odometry as its prior, replaces the odometry's. Without a match the result is
        the odometry's again (the same composition, to first order).
        """
        if self._pending is None:  # the first step since the last match
            rows = (self._mu[:3].copy(), self._sigma[:3].copy())
            self._pending = (np.zeros(3), np.zeros((3, 3)), *rows)
            self._pending_error = None if self._error is None else self._error[:3].copy()
        since, since_cov, pose, pose_rows = self._pending
        lidar_u, noise = self._lidar_increments(u), self._odometry_noise(u)
        delta, cov = increment_to_relative(lidar_u, noise)
        since, since_cov = relative_motion_update(since, since_cov, delta, cov)
        self._prealigned = False
        # the mean the odometry's motion update would give (motion_update's own)
        if not self._moved_enough(predict_pose(self._mu[:3], lidar_u)):
            self._pending = (since, since_cov, pose, pose_rows)
            self._odometry_update(lidar_u, noise)
            return False
        # a measuring step: its odometry update would be replaced at once, so the state
        # goes straight back to the pose rows after the last measurement update
        mu = self._mu.copy()
        mu[:3] = pose
        if self._error is not None:
            self._error = _with_pose_rows(self._error, self._pending_error)
        self._mu, self._sigma, self._pending = mu, _with_pose_rows(self._sigma, pose_rows), None
        self._prealigned = self._matched_relative_update(since, since_cov, points)
        return True

    def _matched_relative_update(
        self, delta: np.ndarray, cov: np.ndarray, points: np.ndarray
    ) -> bool:
        """Motion update with the scan matched from the odometry's ``delta`` (``cov``).

        ``delta``: the odometry's relative pose since the matcher's last pose, in that
        pose's frame; the match's prior. Returns whether the match was used.
        """
        to_map = frame_rotation(self._matcher_pose[2])
        result = None
        if len(self._local_map):
            if self.config.matcher.normal_agreement_deg > 0 and self._normals is None:
                self._normals = scan_normals(points, self.config.matcher)
            try:
                result = match_scan(
                    points,
                    self._local_map,
                    compose(self._matcher_pose, delta),
                    to_map @ cov @ to_map.T,
                    self.config.matcher,
                    normals=self._normals,
                )
            except (ValueError, np.linalg.LinAlgError):  # degenerate numbers: no match
                result = None
        if result is not None:
            delta = compose(inverse(self._matcher_pose), result.pose)
            cov = to_map.T @ result.cov @ to_map
        if self._error is not None:
            self._error = relative_motion_update(self._mu, self._error, delta, cov)[1]
        self._mu, self._sigma = relative_motion_update(self._mu, self._sigma, delta, cov)
        self._matcher_pose = compose(self._matcher_pose, delta)
        self._add_keyframe(points)
        return result is not None

    def _add_keyframe(self, points: np.ndarray) -> None:
        """Add the scan's lidar-frame ``points`` to the local map at the matcher's pose.

        Only when that pose makes a keyframe (``ScanMatcherConfig.keyframe_distance``).
        """
        if self._local_map.is_keyframe(self._matcher_pose):
            if self._normals is None:
                self._normals = scan_normals(points, self.config.matcher)
            self._local_map.add(points, self._matcher_pose, self._normals)

    def _fuse_match(self, points: np.ndarray) -> bool:
        """``prealign="fuse"``: the aligned pose as a direct measurement of the pose."""
        if not len(self._local_map):
            return False
        try:
            result = match_scan(
                points,
                self._local_map,
                self._mu[:3],
                self._sigma[:3, :3],
                self.config.matcher,
                use_prior=False,  # the filter's own prior: not counted twice
            )
            if result is None:
                return False
            mu, sigma = pose_measurement_update(self._mu, self._sigma, result.pose, result.cov)
            if self._error is not None:
                self._error = error_covariance.pose_update(self._error, self._sigma, result.cov)
            self._mu, self._sigma = mu, sigma
        except (ValueError, np.linalg.LinAlgError):  # degenerate numbers: not fused
            return False
        return True

    # ------------------------------------------------------------------ loop closure

    def _make_loop_closure(self) -> LoopClosure | None:
        """The revisit keyframes and tests of ``FilterConfig.loop_closure`` (None: off)."""
        cfg = self.config.filter
        if not cfg.loop_closure:
            return None
        return LoopClosure(
            self.config.matcher,
            radius=cfg.loop_radius,
            min_age=cfg.loop_min_age,
            keyframe_distance=cfg.loop_keyframe_distance,
            keyframe_heading_deg=cfg.loop_keyframe_heading_deg,
            min_inlier_fraction=cfg.loop_min_inlier_fraction,
            max_mahalanobis=cfg.loop_max_mahalanobis,
            strong_inlier_fraction=cfg.loop_strong_inlier_fraction,
            strong_max_mahalanobis=cfg.loop_strong_max_mahalanobis,
            sigma_floor=cfg.loop_sigma_floor,
            cooldown=cfg.loop_cooldown,
            track_hypotheses=cfg.loop_track_hypotheses,
            max_distance_start=cfg.loop_max_distance_start,
            max_distance_mid=cfg.loop_max_distance_mid,
            min_points=cfg.loop_min_points,
            prior_rival=cfg.loop_prior_rival,
        )

    def _close_loop(self, points: np.ndarray) -> bool:
        """Fuse the scan's revisit match as a pose measurement; whether one was fused."""
        assert self._loop is not None
        found = self._loop.match(
            points, self._mu[:3], self._gate_covariance(), self._measurements, self._normals
        )
        if found is None:
            return False
        cfg = self.config.filter
        if float(np.hypot(*(found.pose[:2] - self._mu[:2]))) > cfg.loop_max_correction:
            return False
        floor = cfg.loop_min_innovation
        if floor > 0.0:  # the match agrees with the belief: nothing to close
            d = found.pose - self._mu[:3]
            d[2] = wrap_angle(d[2])
            try:
                m2 = float(d @ np.linalg.solve(self._sigma[:3, :3] + found.cov, d))
            except np.linalg.LinAlgError:
                return False
            if m2 < floor**2:
                return False
        try:
            mu, sigma = pose_measurement_update(self._mu, self._sigma, found.pose, found.cov)
        except np.linalg.LinAlgError:  # degenerate numbers: not fused
            return False
        spread = self.config.filter.loop_correct_keyframes
        if spread != "none":  # the keyframes take a share of the pose's correction
            self._loop.correct_keyframes(self._mu[:3], mu[:3], spread, self._sigma[:3, :3])
        if self._error is not None:
            self._error = error_covariance.pose_update(self._error, self._sigma, found.cov)
        self._mu, self._sigma = mu, sigma
        self._loop.fused(self._measurements)
        self._loop_match = (found.pose.copy(), found.cov.copy())
        return True

    # ------------------------------------------------------------------ measurement

    def _informative(self, scan: Scan, first: int, last: int, pose: np.ndarray) -> bool:
        """Enough beams, and Algorithm 3 finds more than one line (4.3.3)."""
        if last - first + 1 < self.config.filter.min_set_beams:
            return False
        z = np.empty(2 * (last - first + 1))
        z[0::2] = scan.ranges[first : last + 1]
        z[1::2] = scan.bearings[first : last + 1]
        mu_c, cov_c = _point_covariances(z, pose, self.sensor, self._lin)
        return several_groups(mu_c, cov_c, self.config.model)

    def _set_points(self, scan: Scan, first: int, last: int, pose: np.ndarray) -> np.ndarray:
        r = scan.ranges[first : last + 1]
        a = pose[2] + scan.bearings[first : last + 1]
        return stack_last(pose[0] + r * np.cos(a), pose[1] + r * np.sin(a))

    def _refs(self) -> np.ndarray:
        """``(L, d)`` every landmark's reference mean (a copy; ``d`` = 2, or 3 for frames).

        Landmarks are appended to the state in creation order: landmark ``i``'s reference
        is at state index ``3 + d i``; its first two entries are the point [m].
        """
        n, d = len(self._landmarks), self._ref_dim
        return self._mu[POSE_DIM : POSE_DIM + d * n].reshape(n, d).copy()

    def _candidates(
        self,
        scan: Scan,
        first: int,
        last: int,
        refs: np.ndarray,
        radii: np.ndarray,
        pose_spread: tuple[float, float],
    ) -> _SetWork | None:
        """Candidate landmarks of a set and which of them are near enough to align.

        ``pose_spread``: :meth:`_pose_spread` of the predicted pose.
        """
        if not self._landmarks:
            return None
        pose = self._mu[:3]
        cfg = self.config.filter
        pts = self._set_points(scan, first, last, pose)
        centroid = pts.mean(axis=0)
        cand = candidate_landmarks(centroid, refs[:, :REF_DIM], radii, cfg.candidate_margin)
        if cand.size == 0:
            return None
        lms = [self._landmarks[i] for i in cand]
        geometry = [self._geometry(lm) for lm in lms]
        # the near distance grows with how far the pose's uncertainty may move the set
        reach = float(np.hypot(*(centroid - pose[:2])))
        max_near = cfg.candidate_max_near_distance + cfg.candidate_near_sigma * (
            pose_spread[0] + reach * pose_spread[1]
        )
        near = _near_candidates(
            pts, geometry, cfg.candidate_max_median_distance, max_near, cfg.candidate_near_quantile
        )
        return _SetWork(first, last, pts, lms, geometry, np.flatnonzero(near))

    def _pose_spread(self) -> tuple[float, float]:
        """``(position, heading)`` standard deviations of the pose [m, rad].

        The position's is along the major axis of its covariance.
        """
        position = float(np.sqrt(max(np.linalg.eigvalsh(self._sigma[:2, :2])[-1], 0.0)))
        return position, float(np.sqrt(max(self._sigma[2, 2], 0.0)))

    def _pose_gate(self) -> _PoseGate:
        """What the plausibility of every ICP pose of a scan is judged by (current state)."""
        cfg = self.config.filter
        chol = np.linalg.cholesky(self._sigma[:3, :3])
        log_norm = -0.5 * (3 * np.log(2 * np.pi)) - np.log(np.diag(chol)).sum()
        gate_cov = chol_gate = None
        if np.isfinite(cfg.icp_max_pose_mahalanobis):
            gate_cov = self._gate_covariance()
            # without a floor the gate covariance is the pose covariance: reuse its factor
            chol_gate = np.linalg.cholesky(gate_cov) if any(cfg.icp_gate_sigma_floor) else chol
        return _PoseGate(chol, log_norm, gate_cov, chol_gate)

    def _gate(self, work: _SetWork, results: list, gate: _PoseGate) -> _Gated:
        """Which aligned candidates of a set are tested for detection, and at which pose.

        ``results``: the ICP alignment of the set to each of ``work.aligned``. A result
        beyond ``icp_max_pose_mahalanobis`` of the predicted pose is retried
        (``icp_retry_correspondence_distance``), tested at the predicted pose
        (``icp_gate_fallback``) or not tested.
        """
        lms, pose = work.landmarks, self._mu[:3]
        gated_out = _Gated([None] * len(lms), [], {})
        far = np.ones(len(lms), dtype=bool)
        far[work.aligned] = False
        for c in far.nonzero()[0].tolist():
            gated_out.tried[c] = (lms[c].id, "far", np.nan, np.nan, False)
        cfg = self.config.filter
        finite = [k for k, res in enumerate(results) if np.isfinite(res.pose).all()]
        if not finite:
            return gated_out
        # Every finite result's pose offset and whitened offsets, one solve call each.
        offsets = np.array([results[k].pose for k in finite]) - pose
        offsets[:, 2] = wrap_angle(offsets[:, 2])
        whites = _solve_each(gate.chol, offsets)
        gate_whites = None  # the gate's, when its covariance is the same for every candidate
        if gate.gate_cov is not None and not cfg.icp_gate_includes_reference:
            gate_whites = _solve_each(gate.chol_gate, offsets)
        for row, k in enumerate(finite):
            c, res, d, white = work.aligned[k], results[k], offsets[row], whites[row]
            m2 = float(white @ white)
            test_pose, reason = res.pose, res.reason
            gated = False
            if gate_whites is not None:  # as _gate_distance
                gated = float(np.linalg.norm(gate_whites[row])) > cfg.icp_max_pose_mahalanobis
            elif gate.gate_cov is not None:
                distance = self._gate_distance(lms[c], d, gate.gate_cov, gate.chol_gate)
                gated = distance > cfg.icp_max_pose_mahalanobis
            if gated and cfg.icp_retry_correspondence_distance > 0.0:
                retry = self._robust_alignment(work, c)
                d_retry = retry.pose - pose
                d_retry[2] = wrap_angle(d_retry[2])
                if (
                    retry.converged
                    and retry.n_used >= cfg.icp_retry_min_fraction * work.points.shape[0]
                    and np.isfinite(d_retry).all()
                    and self._gate_distance(lms[c], d_retry, gate.gate_cov, gate.chol_gate)
                    <= cfg.icp_max_pose_mahalanobis
                ):
                    gated, d, test_pose, reason = False, d_retry, retry.pose, "retried"
                    white = np.linalg.solve(gate.chol, d)
                    m2 = float(white @ white)
            if gated:
                if not cfg.icp_gate_fallback:
                    gated_out.tried[c] = (lms[c].id, "gated", np.nan, np.nan, False)
                    continue
                test_pose, reason, m2 = pose, "gated", 0.0
            gated_out.tested.append((c, test_pose, reason))
            gated_out.m2s[c] = m2
        return gated_out

    def _detections(
        self, scan: Scan, requests: list[tuple[_SetWork, int, np.ndarray]], lam: float
    ) -> list[Any]:
        """The detection test of every (set, candidate, pose) request of a scan.

        One :func:`~vslam_gym.slam.detection.detect_many` call, each set its own beams.
        """
        if not requests:
            return []
        return detect_many(
            [self._detection_model(w.landmarks[c]) for w, c, _ in requests],
            scan,
            [w.first for w, _, _ in requests],
            [w.last for w, _, _ in requests],
            np.array([p for _, _, p in requests]),
            self.sensor,
            self.config.model,
            self._lin,
            lam,
            parts=[self._parts(w.landmarks[c]) for w, c, _ in requests],
        )

    def _choose(
        self,
        scan: Scan,
        work: _SetWork,
        gated: _Gated,
        detections: dict[int, Any],
        log_norm: float,
    ) -> tuple[_Association | None, tuple, _Overlap | None]:
        """Maximum-likelihood landmark for a set (4.3.4-4.3.18) and the candidates tried.

        ``detections``: the detection test of every tested candidate at its pose, by
        candidate. The third value is the candidate whose object lines the set lies
        closest to (:meth:`_overlap`; None when ``creation_overlap_distance`` is off or
        no candidate has object lines).
        """
        lms, tried = work.landmarks, gated.tried
        best, best_score = None, -np.inf
        for c, test_pose, reason in gated.tested:
            det = detections[c]
            lm, model = lms[c], self._model(lms[c])
            accepted = det.accepted and self._enough_object_beams(det)
            tried[c] = (lm.id, reason, det.mean_d2, det.var_d2, accepted)
            if not accepted:
                continue
            score = det.loglik + log_norm - 0.5 * gated.m2s[c]
            if score > best_score:
                line = det.association.line
                obj = model.u[line] <= self.config.model.unknown_threshold
                counts = np.bincount(line[obj], minlength=model.n_lines)
                cfg = self.config.filter
                enough = int(np.sum(counts >= cfg.min_beams_per_object_line))
                if 0 < cfg.single_line_min_beams <= counts.max(initial=0):
                    enough = max(enough, cfg.min_object_lines)
                best_score = score
                best = _Association(
                    work.first,
                    work.last,
                    lm,
                    test_pose.copy(),
                    (),
                    enough >= cfg.min_object_lines,
                    detection=det,
                )
        done = tuple(t for t in tried if t is not None)
        if best is not None:
            best.candidates = done
            return best, done, None
        overlap = None
        if self.config.filter.creation_overlap_distance > 0.0:
            poses = {c: p for c, p, reason in gated.tested if reason != "gated"}
            overlap = self._overlap(scan, work, poses)
        return best, done, overlap

    def _robust_alignment(self, work: _SetWork, c: int) -> IcpResult:
        """The set aligned to candidate ``c`` again, ignoring points far from the model.

        ``FilterConfig.icp_retry_correspondence_distance`` becomes the ICP's
        ``max_correspondence_distance``; the alignment starts at the predicted pose.
        """
        icp = replace(
            self.config.icp,
            max_correspondence_distance=self.config.filter.icp_retry_correspondence_distance,
        )
        return align(
            work.points,
            self._model(work.landmarks[c]),
            self._mu[:3],
            icp,
            self.sensor.max_range,
            self.sensor.half_fov,
        )

    def _overlap(self, scan: Scan, work: _SetWork, poses: dict) -> _Overlap | None:
        """The aligned candidate whose object lines the set's points lie closest to.

        Per candidate the median distance [m] of the set's points to the model's object
        lines (``u <= unknown_threshold``), at the candidate's ICP pose (``poses``, when
        it passed the gate) and at the predicted pose; the smaller counts.
        """
        best = None
        threshold = self.config.model.unknown_threshold
        for c in work.aligned.tolist():
            lm = work.landmarks[c]
            obj = self._model(lm).u <= threshold
            if not np.any(obj):
                continue
            lines = [work.geometry[c].subset(obj)]
            dist = float(_median_distances(work.points, lines)[0])
            if c in poses:
                pts = self._set_points(scan, work.first, work.last, poses[c])
                dist = min(dist, float(_median_distances(pts, lines)[0]))
            if best is None or dist < best.distance:
                best = _Overlap(lm.id, dist)
        return best

    def _enough_object_beams(self, det) -> bool:
        """At least ``min_object_beam_fraction`` of the set's beams on object lines."""
        fraction = self.config.filter.min_object_beam_fraction
        if fraction <= 0.0:
            return True
        on_object = det.association.u <= self.config.model.unknown_threshold
        return bool(np.mean(on_object) >= fraction)

    def _floored_pose_covariance(self, floor: tuple[float, float, float]) -> np.ndarray:
        """The pose covariance plus ``floor`` (x [m], y [m], theta [rad]) squared, diagonal."""
        return self._sigma[:3, :3] + np.diag(np.square(floor))

    def _gate_covariance(self) -> np.ndarray:
        """The pose covariance plus ``icp_gate_sigma_floor`` squared on the diagonal."""
        return self._floored_pose_covariance(self.config.filter.icp_gate_sigma_floor)

    def _icp_prior_weight(self) -> np.ndarray | None:
        """The ICP pose prior's weight (``FilterConfig.icp_prior_point_sigma``), or None."""
        cfg = self.config.filter
        if cfg.icp_prior_point_sigma <= 0.0:
            return None
        cov = self._floored_pose_covariance(cfg.icp_prior_sigma_floor)
        weight = cfg.icp_prior_point_sigma**2 * np.linalg.inv(cov)
        return 0.5 * (weight + weight.T)

    def _icp_bounds(self, landmarks: list[_Landmark]) -> list[PoseBound | None] | None:
        """Per alignment the ICP stop bound (``FilterConfig.icp_stop_beyond_gate``)."""
        cfg = self.config.filter
        factor = cfg.icp_stop_beyond_gate
        if factor <= 0.0 or not np.isfinite(cfg.icp_max_pose_mahalanobis):
            return None
        limit = factor * cfg.icp_max_pose_mahalanobis
        gate_cov = self._gate_covariance()
        if not cfg.icp_gate_includes_reference:
            bound = PoseBound(np.linalg.inv(np.linalg.cholesky(gate_cov)), limit)
            return [bound] * len(landmarks)
        bounds: list[PoseBound | None] = []
        for lm in landmarks:
            try:
                cov = self._gate_covariance_with_reference(lm, gate_cov)
                bounds.append(PoseBound(np.linalg.inv(np.linalg.cholesky(cov)), limit))
            except np.linalg.LinAlgError:
                bounds.append(None)
        return bounds

    def _gate_covariance_with_reference(self, lm: _Landmark, gate_cov: np.ndarray) -> np.ndarray:
        """``gate_cov`` plus the reference point's uncertainty relative to the pose."""
        r = slice(lm.ref, lm.ref + REF_DIM)
        cov = gate_cov.copy()
        cross = self._sigma[:2, r]
        cov[:2, :2] += self._sigma[r, r] - cross - cross.T
        return cov

    def _gate_distance(
        self, lm: _Landmark, d: np.ndarray, gate_cov: np.ndarray, chol_gate: np.ndarray
    ) -> float:
        """Mahalanobis distance of an ICP pose offset ``d`` in the plausibility gate.

        ``gate_cov``: the pose covariance plus ``icp_gate_sigma_floor`` squared on the
        diagonal, ``chol_gate`` its Cholesky factor. With ``icp_gate_includes_reference``
        the landmark reference's uncertainty relative to the pose is added to the
        position block.
        """
        if not self.config.filter.icp_gate_includes_reference:
            return float(np.linalg.norm(np.linalg.solve(chol_gate, d)))
        cov = self._gate_covariance_with_reference(lm, gate_cov)
        try:
            m2 = float(d @ np.linalg.solve(cov, d))
        except np.linalg.LinAlgError:
            return float("inf")
        return float(np.sqrt(m2)) if m2 >= 0 else float("inf")

    def _measurement_update(self, scan: Scan):
        cfg = self.config.filter
        sets = segment_scan(
            scan,
            cfg.segment_angle_gap * self.sensor.phi_res,
            cfg.segment_distance_gap,
            np.deg2rad(cfg.segment_breakpoint_angle_deg),
            self.sensor.sigma_range,
        )
        lam = exponential_rate(scan.ranges, scan.max_range)
        decisions: list[SetDecision] = []
        unmatched: list[tuple[int, int, tuple, _Overlap | None]] = []
        associations: list[_Association] = []
        # Every set is associated against the map as it was before this scan: first
        # each set's candidates, then all alignments, then each set's detection tests.
        works: list[tuple[int, int, _SetWork | None]] = []
        refs = self._refs()
        radii = np.array([lm.radius for lm in self._landmarks])
        spread = self._pose_spread()
        for first, last in sets:
            if not self._informative(scan, first, last, self._mu[:3]):
                decisions.append(SetDecision(first, last, "skipped"))
                continue
            works.append((first, last, self._candidates(scan, first, last, refs, radii, spread)))
        pairs = [(w, c) for _, _, w in works if w is not None for c in w.aligned]
        results, known = self._alignments(scan, works, pairs, lam)
        # The ICP gate of every set, then one detection call for all sets' candidates
        # (those not tested already at the predicted pose), then each set's choice.
        pose_gate = self._pose_gate() if any(w is not None for _, _, w in works) else None
        gates: list[_Gated | None] = []
        requests: list[tuple[_SetWork, int, np.ndarray]] = []
        at = 0
        for _, _, work in works:
            if work is None:
                gates.append(None)
                continue
            gates.append(self._gate(work, results[at : at + work.aligned.size], pose_gate))
            at += work.aligned.size
            done = known.get(id(work), {})
            requests += [(work, c, p) for c, p, _ in gates[-1].tested if c not in done]
        for (work, c, _), det in zip(requests, self._detections(scan, requests, lam), strict=True):
            known.setdefault(id(work), {})[c] = det
        for (first, last, work), gate in zip(works, gates, strict=True):
            if work is None:
                unmatched.append((first, last, (), None))
                continue
            assoc, tried, overlap = self._choose(
                scan, work, gate, known.get(id(work), {}), pose_gate.log_norm
            )
            if assoc is None:
                unmatched.append((first, last, tried, overlap))
            else:
                associations.append(assoc)
        for assoc in associations:
            assoc.landmark.last_seen, assoc.landmark.idle_checked = self._measurements, False
            outcome = "associated"
            if assoc.enough:
                outcome = self._update_landmark(scan, assoc)
            decisions.append(
                SetDecision(assoc.first, assoc.last, outcome, assoc.landmark.id, assoc.candidates)
            )
        limit = self.config.filter.creation_overlap_distance
        for first, last, tried, overlap in unmatched:
            if overlap is not None and overlap.distance <= limit:
                decisions.append(SetDecision(first, last, "overlapping", overlap.landmark, tried))
                continue
            created = None
            if self.config.filter.create_beside_candidates or all(t[1] == "far" for t in tried):
                created = self._create_landmark(scan, first, last)
            outcome = "created" if created is not None else "unmatched"
            decisions.append(
                SetDecision(first, last, outcome, -1 if created is None else created, tried)
            )
        decisions.sort(key=lambda d: d.first)
        return decisions

    def _alignments(
        self, scan: Scan, works: list, pairs: list, lam: float
    ) -> tuple[list[IcpResult], dict[int, dict[int, Any]]]:
        """The pose each (set, candidate) pair is tested at (``association_pose``).

        Returns the results in ``pairs`` order and, for ``"predicted_first"``, per set
        (keyed by ``id(work)``) the detections already computed at the predicted pose of
        the candidates that passed there.
        """
        pose = self._mu[:3]
        mode = self.config.filter.association_pose
        if mode == "predicted":
            return [_predicted_result(pose, w.points.shape[0]) for w, _ in pairs], {}
        results: list[IcpResult | None] = [None] * len(pairs)
        known: dict[int, dict[int, Any]] = {}
        if mode == "predicted_first":
            at = 0
            for first, last, work in works:
                if work is None or work.aligned.size == 0:
                    continue
                cands = work.aligned.tolist()
                dets = detect_many(
                    [self._detection_model(work.landmarks[c]) for c in cands],
                    scan,
                    first,
                    last,
                    np.tile(pose, (len(cands), 1)),
                    self.sensor,
                    self.config.model,
                    self._lin,
                    lam,
                    parts=[self._parts(work.landmarks[c]) for c in cands],
                )
                for k, (c, det) in enumerate(zip(cands, dets, strict=True)):
                    if det.accepted and self._enough_object_beams(det):
                        results[at + k] = _predicted_result(pose, work.points.shape[0])
                        known.setdefault(id(work), {})[c] = det
                at += len(cands)
        todo = [i for i, r in enumerate(results) if r is None]
        aligned = align_many(
            [pairs[i][0].points for i in todo],
            [self._model(pairs[i][0].landmarks[pairs[i][1]]) for i in todo],
            pose,
            self.config.icp,
            self.sensor.max_range,
            self.sensor.half_fov,
            lines=[pairs[i][0].geometry[pairs[i][1]] for i in todo],
            bounds=self._icp_bounds([pairs[i][0].landmarks[pairs[i][1]] for i in todo]),
            prior_weight=self._icp_prior_weight(),
        )
        for i, res in zip(todo, aligned, strict=True):
            results[i] = res
        return results, known  # type: ignore[return-value]

    # ------------------------------------------------------------------ map updates

    def _update_landmark(self, scan: Scan, assoc: _Association) -> str:
        """Model update + state-space update for one association.

        Returns the set's outcome: ``"updated"``, ``"failed"`` (numerical failure) or
        ``"rejected"`` (:meth:`_verified` failed); the state changes only when updated.
        """
        lm = assoc.landmark
        try:
            upd = update_model(
                self._model(lm),
                scan,
                assoc.first,
                assoc.last,
                assoc.pose,
                self.sensor,
                self.config.model,
                self._lin,
                association=assoc.detection,
                object_vertices=lm.object_vertices,
                finish=False,  # Algorithm 7 and wrapping: _finish_model, at the new pose
            )
            f = upd.F
            prior = lm.cond.relinearized(self._mu[lm.ref : lm.ref + self._ref_dim])
            a2, b2 = f.T @ prior.A, f.T @ prior.b
            k2 = f.T @ prior.K @ f
            k3 = self._repeat_discount(lm) * self._observation_information(
                self.config.filter.observation_information_scale * upd.K_obs,
                upd.A_vx,
                upd.b_vx,
                self._mu[lm.ref : lm.ref + REF_DIM],
                lm.heading_sigma,
            )
            mu, sigma, cond, lam = state_space_update(
                self._mu, self._sigma, lm.ref, a2, b2, k2, upd.A_vx, upd.b_vx, k3, with_factor=True
            )
        except (ValueError, np.linalg.LinAlgError):  # UpdateError, degenerate geometry, ...
            return "failed"
        try:
            cond.covariance()  # p(v | r) must be proper before anything is committed
        except np.linalg.LinAlgError:
            return "failed"
        if not self._verified(mu, assoc.pose) or not self._plausible_correction(mu, sigma):
            return "rejected"
        if self._error is not None:
            idx = np.r_[0:POSE_DIM, lm.ref : lm.ref + self._ref_dim]
            self._error = error_covariance.factor_update(
                self._error, self._sigma, idx, lam, self.config.filter.error_noise_scale
            )
        self._mu, self._sigma = mu, sigma
        lm.updates += 1
        lm.cond = cond
        lm.u = upd.posterior.u.copy()
        lm.closed = upd.posterior.closed
        lm.object_vertices = (
            (0, lm.u.size) if lm.closed else _object_span(lm.u, self.config.model.unknown_threshold)
        )
        self._finish_model(lm, upd, scan)
        self._set_model(lm, self._model_of(lm))
        self._snapshot.set(
            self._index(lm), lm.cond, lm.u, lm.closed, self.config.model.unknown_threshold
        )
        return "updated"

    def _observation_information(
        self,
        k_obs: np.ndarray,
        a_vx: np.ndarray,
        b_vx: np.ndarray,
        reference: np.ndarray,
        heading_sigma: float,
    ) -> np.ndarray:
        """``Phi3``'s information with the model errors of the config added.

        ``observation_model_sigma`` per vertex coordinate, and ``heading_sigma`` [rad]
        (the landmark's orientation model error, :meth:`_orientation_error`) as a
        rotation of all the observed vertices (at the current pose: ``A_vx x + b_vx``)
        about the landmark's ``reference`` point [m].
        """
        cfg = self.config.filter
        extra = None
        if heading_sigma > 0.0:
            vertices = a_vx @ self._mu[:3] + b_vx
            c = rotation_columns(vertices, reference)
            extra = heading_sigma**2 * np.outer(c, c)
        return inflated_information(k_obs, cfg.observation_model_sigma, extra)

    def _repeat_discount(self, lm: _Landmark) -> float:
        """Factor of a landmark update's observation information: ``1 / (1 + n / n0)``.

        ``n``: the landmark's earlier updates, ``n0``: ``FilterConfig.repeat_updates``
        (0: off, factor 1). The errors a landmark's model carries (the pose it was made
        at, its model error) are shared by all its updates, so repeated updates of it
        inform the pose less than independent ones would.
        """
        n0 = self.config.filter.repeat_updates
        return 1.0 if n0 <= 0.0 else 1.0 / (1.0 + lm.updates / n0)

    def _orientation_error(self) -> float:
        """The orientation model error [rad] of a landmark created now.

        ``observation_model_heading_sigma``, or ``creation_heading_model_error`` times
        the pose heading standard deviation when that is larger.
        """
        cfg = self.config.filter
        return max(
            cfg.observation_model_heading_sigma,
            cfg.creation_heading_model_error * float(np.sqrt(max(self._sigma[2, 2], 0.0))),
        )

    def _verified(self, mu: np.ndarray, icp_pose: np.ndarray) -> bool:
        """Whether an update's new pose agrees with its ICP pose (update verification).

        ``mu``: the state mean after the update; ``icp_pose``: the association's lidar
        pose ``[x, y, theta]``. The heading change must lie within the interval from 0
        to the ICP's heading offset (both relative to the current mean), widened on
        both sides by ``verify_heading_sigma`` prior heading standard deviations [rad];
        the position change within ``verify_position_sigma`` prior position standard
        deviations (larger axis) [m] of the segment from 0 to the ICP's position offset.
        A factor of 0 turns its test off.
        """
        cfg = self.config.filter
        prior = self._mu[:3]
        if cfg.verify_heading_sigma > 0.0:
            turn = float(wrap_angle(mu[2] - prior[2]))
            offset = float(wrap_angle(icp_pose[2] - prior[2]))
            slack = cfg.verify_heading_sigma * float(np.sqrt(self._sigma[2, 2]))
            if not min(0.0, offset) - slack <= turn <= max(0.0, offset) + slack:
                return False
        if cfg.verify_position_sigma > 0.0:
            move = mu[:2] - prior[:2]
            offset = np.asarray(icp_pose[:2], dtype=float) - prior[:2]
            length2 = float(offset @ offset)
            s = min(max(float(move @ offset) / length2, 0.0), 1.0) if length2 > 0.0 else 0.0
            sigma = float(np.sqrt(np.linalg.eigvalsh(self._sigma[:2, :2])[-1]))
            if float(np.hypot(*(move - s * offset))) > cfg.verify_position_sigma * sigma:
                return False
        return True

    def _plausible_correction(self, mu: np.ndarray, sigma: np.ndarray) -> bool:
        """Whether an update's pose correction is as large as its own covariance allows.

        A linear-Gaussian update moves the pose mean by a correction whose covariance is
        the prior pose covariance minus the posterior's; its squared Mahalanobis distance
        under that difference (over the directions the update informs: eigenvalues
        above ``CORRECTION_RANK_TOLERANCE`` times the largest) must be at most
        ``FilterConfig.update_max_correction_m2`` (0: not tested).
        """
        limit = self.config.filter.update_max_correction_m2
        if limit <= 0.0:
            return True
        d = mu[:3] - self._mu[:3]
        d[2] = wrap_angle(d[2])
        # the correction's covariance: how much the update shrank the pose's
        w, v = np.linalg.eigh(symmetrize(self._sigma[:3, :3] - sigma[:3, :3]))
        informed = w > CORRECTION_RANK_TOLERANCE * max(float(w[-1]), 0.0)
        if not informed.any():
            return True
        z = v[:, informed].T @ d
        return float(np.sum(z * z / w[informed])) <= limit

    def _finish_model(self, lm: _Landmark, upd, scan: Scan) -> None:
        """Algorithm 7 and wrapping, carried over to the landmark's ``p(v | r)``.

        The unknown lines are updated at the new pose mean. On a numerical failure the
        landmark keeps the posterior of the state-space update without them (still
        consistent).
        """
        r = self._mu[lm.ref : lm.ref + self._ref_dim]
        try:
            if upd.chains is not None and not lm.closed:
                post = LandmarkModel(lm.cond.mean(r), lm.cond.covariance(), lm.u, lm.closed)
                ul = update_unknown_lines(
                    post, upd.chains, scan, self._mu[:3], self.sensor, self.config.model, self._lin
                )
                covs = np.array([ul.model.vertex_cov(i) for i in range(ul.model.n_vertices)])
                source, u, span = ul.source, ul.model.u.copy(), ul.object_vertices
                cfg = self.config.filter
                if cfg.unknown_chain_max_vertices > 0:
                    keep = prune_unknown_chains(
                        ul.model, span, cfg.unknown_chain_tolerance, cfg.unknown_chain_max_vertices
                    )
                    if keep.size < source.size:
                        u = _pruned_u(u, keep, span, self.config.model.unknown_threshold)
                        span = (
                            int(np.searchsorted(keep, span[0])),
                            int(np.searchsorted(keep, span[1] - 1)) + 1,
                        )
                        source, covs = source[keep], covs[keep]
                        means = ul.model.mean[keep]
                    else:
                        means = ul.model.mean
                else:
                    means = ul.model.mean
                cond = lm.cond.select(source, means, covs, r)
                cond.covariance()  # raises unless positive definite: then nothing changes
                lm.cond, lm.u, lm.object_vertices = cond, u, span
            if not lm.closed:
                model = LandmarkModel(lm.cond.mean(r), lm.cond.covariance(), lm.u, lm.closed)
                w = wrap_model(model, lm.object_vertices, self.config.model)
                if w.wrapped:
                    cond = lm.cond.fold(w.keep, w.S)
                    cond.covariance()
                    lm.cond = cond
                    lm.u, lm.closed = w.model.u.copy(), True
                    lm.object_vertices = (0, w.model.n_vertices)
        except (ValueError, np.linalg.LinAlgError):
            return

    def _detectable(self, model: LandmarkModel, span: tuple[int, int]) -> bool:
        """New-landmark test (4.3.55-4.3.57): turn angle sum and two object lines."""
        obj = model.mean[span[0] : span[1]]
        if obj.shape[0] < 3:
            return False
        u = model.u[span[0] : span[1] - 1]
        if np.sum(u <= self.config.model.unknown_threshold) < self.config.filter.min_object_lines:
            return False
        d = np.diff(obj, axis=0)
        psi = np.arctan2(d[:, 1], d[:, 0])
        turn = np.abs(wrap_angle(np.diff(psi))).sum()
        return bool(turn > np.deg2rad(self.config.filter.psi_thres_deg))

    def _create_landmark(self, scan: Scan, first: int, last: int) -> int | None:
        """New landmark from an unmatched set (4.3.55-4.3.62), or None."""
        pose = self._mu[:3].copy()
        try:
            fit = create_model(scan, first, last, pose, self.sensor, self.config.model, self._lin)
        except (ValueError, np.linalg.LinAlgError):  # degenerate segment or geometry
            return None
        model = fit.model
        if not self._detectable(model, fit.object_vertices):
            return None
        start, stop = fit.object_vertices
        k, d = model.n_vertices, self._ref_dim
        select = np.zeros((d, 2 * k))
        for i in range(start, stop):  # r = mean of the object vertices (4.3.58)
            select[:REF_DIM, 2 * i : 2 * i + 2] = np.eye(2) / (stop - start)
        heading_sigma = self._orientation_error()
        scale = self.config.filter.error_noise_scale
        select_pose = None
        if d == POSE_REF_DIM:  # a landmark frame starts at the pose heading
            select_pose = np.zeros((d, POSE_DIM))
            select_pose[2, 2] = 1.0
        try:
            if self.config.filter.new_landmark in ("thesis", "halved"):
                mu_r = select @ model.mean.reshape(-1)
                k_v = symmetrize(np.linalg.inv(model.cov))
                if self.config.filter.new_landmark == "halved":
                    k_v = 0.5 * k_v
                a2 = np.zeros((2 * k, d))
                a2[:, :REF_DIM] = np.tile(np.eye(2), (k, 1))
                if select_pose is not None:
                    mu_r = mu_r + select_pose @ pose
                    a2[:, 2] = rotation_columns(model.mean, mu_r)
                b2 = model.mean.reshape(-1) - a2 @ mu_r
                k3 = self._observation_information(
                    k_v, fit.A_vx, fit.b_vx, mu_r[:REF_DIM], heading_sigma
                )
                mu, sigma, cond, lam = state_space_update(
                    self._mu,
                    self._sigma,
                    None,
                    a2,
                    b2,
                    k_v,
                    fit.A_vx,
                    fit.b_vx,
                    k3,
                    with_factor=True,
                )
                error = self._error
                if error is not None:
                    error = error_covariance.add_landmark(
                        error,
                        self._sigma,
                        lam,
                        scale,
                        self.config.filter.error_creation_pose_update,
                    )
            else:
                ref_sigma = self.config.filter.reference_heading_sigma
                mu, sigma, cond = augment_landmark(
                    self._mu,
                    self._sigma,
                    fit.A_vx,
                    fit.b_vx,
                    model.cov,
                    select,
                    self.config.filter.shape_sigma,
                    select_pose,
                    ref_sigma,
                )
                error = self._error
                if error is not None:  # affine in the covariance; the noise scaled
                    error = augment_landmark(
                        self._mu,
                        error,
                        fit.A_vx,
                        fit.b_vx,
                        scale * model.cov,
                        select,
                        self.config.filter.shape_sigma,
                        select_pose,
                        math.sqrt(scale) * ref_sigma,
                    )[1]
            cond.covariance()  # p(v | r) must be proper before anything is committed
        except (ValueError, np.linalg.LinAlgError):  # NotPositiveDefiniteError included
            return None
        self._mu, self._sigma, self._error = mu, sigma, error
        lm = _Landmark(
            id=self._next_id,
            ref=mu.size - d,
            cond=cond,
            u=model.u.copy(),
            closed=False,
            object_vertices=fit.object_vertices,
            last_seen=self._measurements,
            heading_sigma=heading_sigma,
        )
        self._next_id += 1
        self._set_model(lm, self._model_of(lm))
        self._landmarks.append(lm)
        self._snapshot.set(
            self._index(lm), lm.cond, lm.u, lm.closed, self.config.model.unknown_threshold
        )
        return lm.id

    def _index(self, lm: _Landmark) -> int:
        """Position of ``lm`` in the landmark list, the state and the snapshot."""
        return (lm.ref - POSE_DIM) // self._ref_dim

    # ------------------------------------------------------------------ covered duplicates

    def _prune_covered(self) -> tuple[int, ...]:
        """Remove idle landmarks whose object lines another landmark covers; their ids.

        ``FilterConfig.prune_covered_distance``: each landmark is tested once per idle
        period (the first measurement update it has been idle ``prune_idle_steps``
        for), against the landmarks near it (references within the sum of the object
        radii plus the distance, plus ``prune_merge_max_offset`` when merging). A
        covered landmark goes when its reference covariance trace is at least its
        coverer's; otherwise the better known one stays and the coverer goes instead,
        if it is idle and covered by it. With ``prune_merge`` the coverage is measured
        after the offset that aligns the two (:func:`fit_translation`), and a landmark
        goes only once that offset has been fused (:meth:`_merge_duplicate`).
        """
        cfg = self.config.filter
        distance, need = cfg.prune_covered_distance, cfg.prune_covered_fraction
        merge = cfg.prune_merge
        reach = distance + (cfg.prune_merge_max_offset if merge else 0.0)
        threshold = self.config.model.unknown_threshold
        idle = [
            lm
            for lm in self._landmarks
            if not lm.idle_checked and self._measurements - lm.last_seen >= cfg.prune_idle_steps
        ]
        if not idle:
            return ()
        refs = self._refs()[:, :REF_DIM]
        radii = np.array([lm.radius for lm in self._landmarks])
        samples: dict[int, tuple[np.ndarray, ...]] = {}  # id -> (points, weights, normals)
        fits: dict[tuple[int, int], TranslationFit] = {}  # (covered, coverer) ids -> fit

        def covered(a: _Landmark, b: _Landmark) -> bool:
            """Object lines of ``a`` covered by those of ``b``."""
            obj = self._model(b).u <= threshold
            if not np.any(obj):
                return False
            if a.id not in samples:
                model = self._model(a)
                points, weights, seg = sample_segments(
                    object_segments(model, threshold), 0.5 * distance
                )
                lines = self._geometry(a).subset(model.u <= threshold)  # same line order
                samples[a.id] = (points, weights, np.stack([lines.nx, lines.ny], 1)[seg])
            points, weights, normals = samples[a.id]
            if points.shape[0] == 0:
                return False
            lines_b = self._geometry(b).subset(obj)
            if merge:
                fit = fit_translation(points, weights, normals, lines_b, cfg.prune_merge_max_offset)
                fits[(a.id, b.id)] = fit
                near = fit.distances
            else:
                near = _segment_distances(points, [lines_b])[0]
            return covered_fraction(weights, near, distance) >= need

        def remove(victim: _Landmark, keeper: _Landmark) -> bool:
            """Mark ``victim`` (covered by ``keeper``) removed; False if the merge fails."""
            if merge:
                if not self._merge_duplicate(victim, keeper, fits[(victim.id, keeper.id)]):
                    return False
                self._refresh_models()  # every mean may have moved
                samples.clear()
            removed.add(victim.id)
            return True

        def uncertainty(lm: _Landmark) -> float:
            r = slice(lm.ref, lm.ref + REF_DIM)
            return float(np.trace(self._sigma[r, r]))

        removed: set[int] = set()
        for lm in idle:
            lm.idle_checked = True
            if lm.id in removed:
                continue
            i = self._index(lm)
            gap = np.hypot(*(refs - refs[i]).T) - radii - radii[i]
            for j in np.flatnonzero(gap <= reach).tolist():
                other = self._landmarks[j]
                if other is lm or other.id in removed or not covered(lm, other):
                    continue
                if uncertainty(lm) >= uncertainty(other):
                    if remove(lm, other):
                        break
                    continue
                # The covered landmark is the better anchored: keep it; the other goes
                # instead if it is covered too and idle.
                other_idle = self._measurements - other.last_seen >= cfg.prune_idle_steps
                if other_idle and covered(other, lm):
                    remove(other, lm)
        if removed:
            self._remove_landmarks(removed)
        return tuple(sorted(removed))

    def _merge_duplicate(self, victim: _Landmark, keeper: _Landmark, fit: TranslationFit) -> bool:
        """Fuse "``victim`` + offset lies on ``keeper``" into the state; False if gated out.

        A relative measurement of the two references along the offset's constrained
        directions ``D`` (:class:`~vslam_gym.slam.pruning.TranslationFit`):
        ``y = D^T (J_v r_v - J_k r_k)``, where ``J`` is the mean derivative of a
        landmark's object vertices by its reference (rows of ``A`` in ``p(v | r)``); the
        fit says ``y`` is ``D^T offset`` more than at the current means. Its noise is
        the mean conditional covariance of both landmarks' object vertices along ``D``
        plus ``prune_merge_sigma^2``. The update is an EKF update of the whole state
        (it moves the pose and every correlated landmark: a loop closure when the two
        were built before and after a drift), applied only when the innovation passes
        the chi-square gate of probability ``prune_merge_probability``.
        """
        cfg = self.config.filter
        u = fit.directions
        k = u.shape[1]
        if k == 0:
            return False
        d = self._ref_dim
        h = np.zeros((k, self._mu.size))
        noise = cfg.prune_merge_sigma**2 * np.eye(k)
        for lm, sign in ((victim, 1.0), (keeper, -1.0)):
            jac, cov = self._object_vertex_moments(lm)
            h[:, lm.ref : lm.ref + d] += sign * (u.T @ jac)
            noise += u.T @ cov @ u
        ph = self._sigma @ h.T
        s = symmetrize(h @ ph + noise)
        nu = u.T @ fit.offset
        try:
            white = np.linalg.solve(np.linalg.cholesky(s), nu)
        except np.linalg.LinAlgError:
            return False
        if not float(white @ white) <= 2.0 * gammaincinv(0.5 * k, cfg.prune_merge_probability):
            return False
        gain = np.linalg.solve(s, ph.T).T  # (n, k)
        if self._error is not None:
            self._error = error_covariance.direct_update(self._error, self._sigma, h, noise)
        self._mu = self._mu + gain @ nu
        self._sigma = symmetrize(self._sigma - gain @ s @ gain.T)
        return True

    def _object_vertex_moments(self, lm: _Landmark) -> tuple[np.ndarray, np.ndarray]:
        """Mean of ``dv / dr`` ``(2, d)`` and of ``Cov(v | r)`` ``(2, 2)`` over object vertices."""
        k = lm.cond.b.size // 2
        objects = self._snapshot.objects[self._index(lm), :k]
        jac = lm.cond.A.reshape(k, 2, -1)[objects].mean(axis=0)
        idx = np.flatnonzero(objects)
        blocks = lm.cond.covariance().reshape(k, 2, k, 2)[idx, :, idx, :]
        return jac, blocks.mean(axis=0)

    def _remove_landmarks(self, ids: set[int]) -> None:
        """Marginalise the landmarks ``ids`` out of the state (drop their rows/columns)."""
        d = self._ref_dim
        gone = [lm for lm in self._landmarks if lm.id in ids]
        rows = np.concatenate([np.arange(lm.ref, lm.ref + d) for lm in gone])
        positions = [self._index(lm) for lm in gone]
        keep = np.setdiff1d(np.arange(self._mu.size), rows)
        self._mu = self._mu[keep]
        self._sigma = self._sigma[np.ix_(keep, keep)]
        if self._error is not None:
            self._error = self._error[np.ix_(keep, keep)]
        self._snapshot.delete(positions)
        self._landmarks = [lm for lm in self._landmarks if lm.id not in ids]
        for k, lm in enumerate(self._landmarks):
            lm.ref = POSE_DIM + d * k

    def _model_of(self, lm: _Landmark) -> LandmarkModel:
        r = self._mu[lm.ref : lm.ref + self._ref_dim]
        return LandmarkModel(lm.cond.mean(r), lm.cond.covariance(), lm.u.copy(), lm.closed)

    def _refresh_models(self) -> None:
        """Vertex means from the (moved) references; object radius for gating.

        The radii in one batch (:class:`_MapSnapshot`); each landmark's
        :class:`LandmarkModel` (the conditional at the reference of this refresh) is
        built when first needed (:meth:`_model`), with its ICP and detection data.
        """
        if not self._landmarks:
            return
        refs = self._refs()
        self._snapshot.refresh(refs)
        for lm, r, radius in zip(self._landmarks, refs, self._snapshot.radii.tolist(), strict=True):
            self._set_model(lm, None)
            lm.refreshed_at, lm.radius = r, radius

    def _model(self, lm: _Landmark) -> LandmarkModel:
        """The landmark's model as of the last refresh (or its own last update)."""
        if lm.model is None:
            # The conditional and u as :meth:`_model_of` checked them, at another reference.
            mean = lm.cond.mean(lm.refreshed_at)
            lm.model = LandmarkModel._trusted(mean, lm.cond.covariance(), lm.u.copy(), lm.closed)
        return lm.model

    @staticmethod
    def _set_model(lm: _Landmark, model: LandmarkModel | None) -> None:
        lm.model, lm.geometry, lm.parts, lm.detection_model = model, None, None, None

    def _geometry(self, lm: _Landmark) -> LineGeometry:
        if lm.geometry is None:
            lm.geometry = line_geometry(self._model(lm))
        return lm.geometry

    def _detection_model(self, lm: _Landmark) -> LandmarkModel:
        """The model the detection test sees: ``detection_model_sigma`` added per vertex."""
        if lm.detection_model is None:
            model = self._model(lm)
            sigma = self.config.filter.detection_model_sigma
            if sigma > 0.0:
                cov = model.cov + sigma**2 * np.eye(model.cov.shape[0])
                model = LandmarkModel._trusted(model.mean, cov, model.u, model.closed)
            lm.detection_model = model
        return lm.detection_model

    def _parts(self, lm: _Landmark):
        if lm.parts is None:
            lm.parts = model_parts(self._detection_model(lm))
        return lm.parts


def _with_pose_rows(cov: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """A copy of the state covariance ``cov`` with its pose rows and columns ``rows`` (3, n)."""
    out = cov.copy()
    out[:3] = rows
    out[:, :3] = rows.T
    return out


def _model_copy(model: LandmarkModel) -> LandmarkModel:
    """:meth:`LandmarkModel.copy` of a model the filter built (no re-validation)."""
    return LandmarkModel._trusted(model.mean.copy(), model.cov.copy(), model.u.copy(), model.closed)


def _solve_each(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``np.linalg.solve(a, b[i])`` for every row of ``b`` ``(m, n)``, in one call ``(m, n)``.

    The stacked call solves each system with the same LAPACK routine on the same numbers
    as a single call (the same result to the last bit), without the per-call overhead.
    """
    return np.linalg.solve(np.broadcast_to(a, (b.shape[0], *a.shape)), b[:, :, None])[:, :, 0]


def _predicted_result(pose: np.ndarray, n_points: int) -> IcpResult:
    """The predicted pose standing in for a per-landmark ICP result."""
    return IcpResult(pose.copy(), np.zeros(3), 0, True, n_points, float("nan"), "predicted")


_MIN_LENGTH2 = 1e-12
"""Squared length [m^2] below which a line counts as a point (median distance)."""


def _near_candidates(
    points: np.ndarray,
    geometry: list[LineGeometry],
    max_median: float,
    max_near: float,
    near_quantile: float,
) -> np.ndarray:
    """``(len(geometry),)`` bool: which candidate models a set is aligned to (not "far").

    ``points``: ``(n, 2)`` the set at the predicted pose [m, world frame]. A model is
    near when the median of the points' distances [m] to its segments is at most
    ``max_median`` and their ``near_quantile`` quantile at most ``max_near`` (``inf``:
    no test).
    """
    near = np.ones(len(geometry), dtype=bool)
    if np.isfinite(max_median) or np.isfinite(max_near):
        dist = np.sort(_segment_distances(points, geometry), axis=1)
        if np.isfinite(max_median):
            near &= _sorted_median(dist) <= max_median
        if np.isfinite(max_near):
            near &= _sorted_quantile(dist, near_quantile) <= max_near
    return near


def _sorted_median(rows: np.ndarray) -> np.ndarray:
    """``np.median(rows, axis=1)`` of rows sorted ascending ``(m, n)``, ``n >= 1``, no NaN.

    The same value to the last bit (the middle one, or the mean of the middle two), without
    ``np.median``'s partition and checks, whose overhead dominates on a few short rows.
    """
    n = rows.shape[1]
    if n % 2:
        return rows[:, n // 2]
    return (rows[:, n // 2 - 1] + rows[:, n // 2]) / 2.0


def _sorted_quantile(rows: np.ndarray, q: float) -> np.ndarray:
    """``np.quantile(rows, q, axis=1)`` (method "linear") of sorted rows ``(m, n)``, no NaN.

    The same value to the last bit: numpy's virtual index ``(n - 1) q`` and its linear
    interpolation, from below for a weight under 0.5, from above otherwise.
    """
    n = rows.shape[1]
    virtual = (n - 1) * float(q)
    below = math.floor(virtual)
    above = min(below + 1, n - 1)
    weight = virtual - below
    low, high = rows[:, below], rows[:, above]
    diff = high - low
    if weight >= 0.5:
        return high - diff * (1.0 - weight)
    return low + diff * weight


def _median_distances(points: np.ndarray, geometry: list[LineGeometry]) -> np.ndarray:
    """Median distance [m] of ``points`` ``(n, 2)`` to each model's nearest line segment.

    ``geometry``: :func:`~vslam_gym.slam.icp.line_geometry` of each model. Returns
    ``(len(geometry),)``.
    """
    return _sorted_median(np.sort(_segment_distances(points, geometry), axis=1))


def _segment_distances(points: np.ndarray, geometry: list[LineGeometry]) -> np.ndarray:
    """``(len(geometry), n)`` distance [m] of each point to each model's nearest segment.

    ``geometry``: :func:`~vslam_gym.slam.icp.line_geometry` of each model (at least one
    line each), padded here into one ``(models, n, lines)`` batch.
    """
    n_lines = max(g.ax.size for g in geometry)
    padded = np.zeros((4, len(geometry), n_lines))
    valid = np.zeros((len(geometry), n_lines), dtype=bool)
    for i, g in enumerate(geometry):
        padded[:, i, : g.ax.size] = g.table[:4]  # ax, ay, abx, aby
        valid[i, : g.ax.size] = True
    ax, ay, abx, aby = (row[:, None, :] for row in padded[:4])  # (m, 1, L)
    length2 = np.maximum(abx * abx + aby * aby, _MIN_LENGTH2)
    apx = points[None, :, 0, None] - ax
    apy = points[None, :, 1, None] - ay
    t = np.clip((apx * abx + apy * aby) / length2, 0.0, 1.0)
    dx = apx - t * abx
    dy = apy - t * aby
    dist2 = np.where(valid[:, None, :], dx * dx + dy * dy, np.inf).min(axis=2)
    return np.sqrt(dist2)


def _pruned_u(
    u: np.ndarray, keep: np.ndarray, span: tuple[int, int], threshold: float
) -> np.ndarray:
    """Unknown probabilities of the lines between consecutive kept vertices.

    Object lines (between kept object vertices) keep their ``u``; a line that replaces
    part of an unknown chain is unknown (the largest ``u`` it spans).
    """
    out = []
    for a, b in zip(keep[:-1], keep[1:], strict=True):
        out.append(u[a] if b == a + 1 else max(float(u[a:b].max()), threshold + 1e-9))
    del span
    return np.array(out, dtype=float)


def _object_span(u: np.ndarray, threshold: float) -> tuple[int, int]:
    """Vertex range of the object part: from the first to the last object line."""
    obj = np.flatnonzero(u <= threshold)
    if obj.size == 0:
        return (0, 0)
    return int(obj[0]), int(obj[-1]) + 2


__all__ = [
    "Belief",
    "LandmarkView",
    "STEP_PARTS",
    "SetDecision",
    "SlamConfig",
    "VertexSLAM",
]
