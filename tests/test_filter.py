"""The SLAM filter (SPEC section 10) on a synthetic loop around four objects."""

from __future__ import annotations

from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest
from _raycast import bearings_deg, cast, polygon_edges

from vslam_gym.config_utils import UnknownKeyError
from vslam_gym.slam.config import SensorConfig
from vslam_gym.slam.filter import (
    SlamConfig,
    VertexSLAM,
    _median_distances,
    _near_candidates,
    _sorted_median,
    _sorted_quantile,
)
from vslam_gym.slam.icp import line_geometry, object_radius
from vslam_gym.slam.landmark import LandmarkModel
from vslam_gym.slam.motion import increments_between, predict_pose
from vslam_gym.slam.scan import ScanError

SENSOR = SensorConfig()
PHI = bearings_deg()
OBJECTS = [
    np.array([(3, 3), (5, 3), (5, 4), (3, 4)], float),
    np.array([(8, -1), (9, -1), (9, 1.5), (8, 1.5)], float),
    np.array([(3, -5), (6, -5), (6, -4), (4, -4), (4, -3), (3, -3)], float),
    np.array([(-2, -3), (-1, -3), (-1, -1), (-2, -1)], float),
]
EDGES = polygon_edges(OBJECTS)
ALPHAS = (0.01, 0.005, 0.005, 0.001)


EVERY_SCAN = {"measurement_min_travel": 0.0, "measurement_min_turn": 0.0}
"""Filter options without the default's motion filter: every scan is measured. For the
tests that take their scans from (nearly) one pose, which the motion filter would skip."""


def every_scan(config: SlamConfig) -> SlamConfig:
    """``config`` with :data:`EVERY_SCAN`."""
    return replace(config, filter=replace(config.filter, **EVERY_SCAN))


def circle_route(n=120):
    t = np.linspace(0, 2 * np.pi, n)
    return np.column_stack([3.5 + 3.0 * np.sin(t), -3.0 * np.cos(t), t])


def run(config, seed=0, steps=None):
    rng = np.random.default_rng(seed)
    true = circle_route()
    slam = VertexSLAM(SENSOR, config, initial_pose=true[0])
    odo = true[0].copy()
    beliefs, odo_err = [], []
    for k in range(1, len(true) if steps is None else steps):
        u = increments_between(true[k - 1], true[k])
        a1, a2, a3, a4 = ALPHAS
        var = [
            a1 * u[0] ** 2 + a2 * u[1] ** 2,
            a3 * u[1] ** 2 + a4 * (u[0] ** 2 + u[2] ** 2),
            a1 * u[2] ** 2 + a2 * u[1] ** 2,
        ]
        noisy = u + rng.normal(0.0, np.sqrt(var))
        odo = predict_pose(odo, noisy)
        r = cast(
            true[k], EDGES, PHI, SENSOR.max_range, SENSOR.sigma_range, SENSOR.sigma_bearing, rng
        )
        beliefs.append(slam.step(noisy, r, PHI))
        odo_err.append(np.hypot(*(odo[:2] - true[k, :2])))
    return slam, beliefs, np.array(odo_err), true


def test_loop_closes_and_revisited_object_is_associated():
    slam, beliefs, odo_err, true = run(SlamConfig())
    final = beliefs[-1]
    err = np.hypot(*(final.pose[:2] - true[-1, :2]))
    assert err < 0.15 and err < 0.2 * odo_err[-1], (err, odo_err[-1])
    # every object is modelled, with few duplicates. The default ICP gate models an
    # object again where its alignment is implausible: seeds 0-2 give 9, 7, 6 landmarks
    # (final errors 0.002, 0.051, 0.018 m) against 7, 5, 6 without it (0.059, 0.046,
    # 0.018 m).
    assert 4 <= len(final.landmarks) <= 9
    # after most of the circle the first landmark is seen and updated again
    late = [d for b in beliefs[90:] for d in b.decisions if d.outcome == "updated"]
    assert any(d.landmark == 0 for d in late)
    # the state covariance stays symmetric positive definite
    assert np.linalg.eigvalsh(slam._sigma).min() > 0
    np.testing.assert_array_equal(slam._sigma, slam._sigma.T)


@pytest.mark.parametrize(
    "odometry, ranges, match",
    [
        ([0.0, np.nan, 0.0], np.ones(181), "finite"),
        ([0.0, 0.1], np.ones(181), "shape"),
        ([0.0, 0.1, 0.0], np.r_[np.ones(180), np.nan], "NaN"),
        ([0.0, 0.1, 0.0], np.ones(180), "bearings has 181"),
        ([0.0, 0.1, 0.0], -np.ones(181), ">= 0"),
        # absurd but finite increments (wrong units, a corrupt log) used to move the pose
        # and then fail inside the step, leaving every later step failing too
        ([0.0, 1e10, 0.0], np.ones(181), "translation must be at most 30.0 m"),
        ([1e155, 0.0, 0.0], np.ones(181), "rotations rot1, rot2"),
        (["a", 0.1, 0.0], np.ones(181), "3 numbers"),
        # ranges that numpy would cast: True as 1 m, a complex number as its real part
        ([0.0, 0.1, 0.0], np.ones(181, dtype=bool), "ranges must hold real numbers"),
        ([0.0, 0.1, 0.0], np.ones(181) + 1j, "ranges must hold real numbers"),
        ([0.0, 0.1, 0.0], np.array(["1"] * 181), "ranges must hold real numbers"),
    ],
)
def test_rejected_input_leaves_the_belief_unchanged(odometry, ranges, match):
    slam, _, _, _ = run(SlamConfig(), steps=15)
    before = slam.belief
    sigma = slam._sigma.copy()
    with pytest.raises(ValueError, match=match):
        slam.step(odometry, ranges, PHI if ranges.size == 181 else PHI)
    after = slam.belief
    assert after.step == before.step
    np.testing.assert_array_equal(after.pose, before.pose)
    np.testing.assert_array_equal(slam._sigma, sigma)
    assert len(after.landmarks) == len(before.landmarks)


def test_scan_error_type():
    slam = VertexSLAM(SENSOR)
    with pytest.raises(ScanError):
        slam.step([0, 0, 0], np.ones(181), PHI[::-1])


def test_config_from_dict_and_presets():
    cfg = SlamConfig.from_dict({"preset": "thesis", "filter": {"min_set_beams": 6}})
    assert cfg.filter.min_set_beams == 6 and cfg.model.linearization == "ut"
    assert cfg.filter.unknown_chain_max_vertices == 0
    with pytest.raises(UnknownKeyError, match="did you mean 'min_set_beams'"):
        SlamConfig.from_dict({"filter": {"min_set_beam": 6}})
    with pytest.raises(UnknownKeyError, match="preset"):
        SlamConfig.preset("thesys")
    fast = SlamConfig.preset("fast")
    assert fast.filter.association_pose == "predicted_first"
    assert fast.filter.measurement_min_travel == fast.filter.measurement_min_turn == 0.2
    # ... and a weak ICP pose prior (measured better there, worse in the default)
    assert fast.filter.icp_prior_point_sigma == 0.03
    assert fast.filter.icp_prior_sigma_floor == fast.filter.icp_gate_sigma_floor
    for name in ("default", "thesis", "logs"):
        assert SlamConfig.preset(name).filter.icp_prior_point_sigma == 0.0
    # otherwise the default
    assert fast.model == SlamConfig().model and fast.icp == SlamConfig().icp
    # the logs preset stops alternating ICP alignments at their first return
    assert SlamConfig.logs().icp.cycle_returns == 1 and SlamConfig().icp.cycle_returns == 0
    # ... and stops per-landmark alignments that leave ten times the gate
    assert SlamConfig.logs().filter.icp_stop_beyond_gate == 10.0
    assert SlamConfig().filter.icp_stop_beyond_gate == 3.0
    assert SlamConfig.thesis().filter.icp_stop_beyond_gate == 0.0
    assert SlamConfig.fast().filter.icp_stop_beyond_gate == 0.0
    for name in ("thesis", "logs"):  # every scan is measured
        assert SlamConfig.preset(name).filter.measurement_min_travel == 0.0
        assert SlamConfig.preset(name).filter.measurement_min_turn == 0.0
    # the default measures after 0.15 m or 0.15 rad of motion, fast after 0.2 m or 0.2 rad
    assert SlamConfig().filter.measurement_min_travel == SlamConfig().filter.measurement_min_turn
    assert SlamConfig().filter.measurement_min_travel == 0.15
    # update verification: on by default, off in the other presets (measured no better)
    assert SlamConfig().filter.verify_heading_sigma == 3.0
    for name in ("thesis", "logs", "fast"):
        assert SlamConfig.preset(name).filter.verify_heading_sigma == 0.0
    # the matcher's normal agreement: in the logs preset only (level on the worlds)
    assert SlamConfig.logs().matcher.normal_agreement_deg == 30.0
    for name in ("default", "thesis", "fast"):
        assert SlamConfig.preset(name).matcher.normal_agreement_deg == 0.0


# ----------------------------------------------------------------- cached map data


@pytest.mark.parametrize(
    "section, name",
    [
        ("filter", "min_set_beams"),
        ("filter", "min_object_lines"),
        ("filter", "min_beams_per_object_line"),
        ("filter", "unknown_chain_max_vertices"),
        ("model", "min_beams_per_line"),
        ("model", "artificial_outer_offset"),
        ("model", "boundary_window"),
        ("icp", "max_iterations"),
        ("icp", "cycle_returns"),
        ("matcher", "coarse_keep"),
        ("matcher", "max_hypotheses"),
    ],
)
@pytest.mark.parametrize("bad", [-1, 2.5, True, float("nan")])
def test_integer_settings_reject_non_integers_and_values_below_their_minimum(section, name, bad):
    with pytest.raises(ValueError, match=f"{name} must be an integer >= "):
        SlamConfig.from_dict({section: {name: bad}})


@pytest.mark.parametrize(
    "section, name, bad",
    [
        ("filter", "segment_distance_gap", 0.0),
        ("filter", "candidate_margin", -1.0),
        ("filter", "icp_max_pose_mahalanobis", float("nan")),
        ("filter", "observation_information_scale", 0.0),
        ("model", "unknown_threshold", 1.5),
        ("model", "detection_trim_fraction", 1.0),
        ("model", "coarseness", float("inf")),
        ("model", "coarseness_significance", True),
    ],
)
def test_real_settings_outside_their_interval_are_rejected(section, name, bad):
    # a bool is no number: the type check names it before the interval check
    with pytest.raises(ValueError, match=f"{name} must (lie in |be a number)"):
        SlamConfig.from_dict({section: {name: bad}})
    # the thesis's values at the ends of the intervals are accepted
    assert SlamConfig.thesis().filter.icp_max_pose_mahalanobis == float("inf")


def test_cached_models_radii_and_median_distances_match_plain_computations():
    slam, _, _, _ = run(SlamConfig(), steps=40)
    assert len(slam._landmarks) >= 3
    thr = slam.config.model.unknown_threshold
    rng = np.random.default_rng(2)
    for lm in slam._landmarks:
        r = slam._mu[lm.ref : lm.ref + 2]
        model = slam._model(lm)
        # the model as of the last refresh is the conditional at the current reference
        np.testing.assert_array_equal(model.mean, lm.cond.mean(r))
        np.testing.assert_allclose(lm.radius, object_radius(model, r, thr), rtol=0, atol=1e-12)
    # median distances of random point sets, batched over models, against one at a time
    models = [slam._model(lm) for lm in slam._landmarks]
    geometry = [line_geometry(m) for m in models]
    for _ in range(5):
        pts = rng.uniform(-3.0, 9.0, (int(rng.integers(1, 40)), 2))
        got = _median_distances(pts, geometry)
        want = [reference_median_distance(pts, m) for m in models]
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-12)


def test_sorted_median_and_quantile_equal_numpys_to_the_last_bit():
    rng = np.random.default_rng(4)
    for n in (1, 2, 3, 4, 7, 10, 11, 64, 101):
        rows = rng.exponential(0.3, (3, n)) * rng.choice([1e-3, 1.0, 30.0], (3, 1))
        rows = np.sort(rows, axis=1)
        np.testing.assert_array_equal(_sorted_median(rows), np.median(rows, axis=1))
        for q in (0.0, 0.05, 0.1, 0.25, 0.5, 0.7, 0.9, 1.0, rng.uniform()):
            np.testing.assert_array_equal(
                _sorted_quantile(rows, q), np.quantile(rows, q, axis=1), err_msg=f"{n} {q}"
            )


def test_near_candidates_keep_a_partly_overlapping_set_and_drop_a_parallel_one():
    wall = line_geometry(LandmarkModel(np.array([(0.0, 0.0), (2.0, 0.0)]), np.eye(4), np.zeros(1)))
    x = np.linspace(1.0, 4.0, 31)
    extending = np.column_stack([x, np.full_like(x, 0.02)])  # a third on the wall, then past it
    parallel = np.column_stack([x - 2.0, np.full_like(x, 0.3)])  # 0.3 m beside it
    thesis = SlamConfig.thesis().filter
    assert thesis.candidate_max_near_distance == thesis.candidate_max_median_distance == np.inf
    assert SlamConfig().filter.candidate_max_near_distance == 0.1

    def near(points, max_median=1.5, max_near=0.1):
        return _near_candidates(points, [wall], max_median, max_near, 0.1).tolist()

    assert near(extending) == [True] and near(parallel) == [False]
    assert near(parallel, max_near=0.35) == [True]  # a wider reach (pose uncertainty)
    assert near(parallel, max_near=np.inf) == [True]  # the thesis: no test
    # a median test as tight would drop the extending set too (its median point is 0.5 m off)
    assert near(extending, max_median=0.1, max_near=np.inf) == [False]
    for bad in (
        {"candidate_max_near_distance": -0.1},
        {"candidate_near_quantile": 1.5},
        {"candidate_near_sigma": float("inf")},
    ):
        with pytest.raises(ValueError, match=next(iter(bad))):
            SlamConfig.from_dict({"filter": bad})


def test_near_distance_widens_with_the_pose_uncertainty_to_close_the_loop():
    # Around the circle the pose drifts 0.15-0.2 m (about 3-4 of its sigmas) before the
    # first objects come back: at a fixed 0.1 m their sets are not candidates of their
    # landmarks any more and model them again, and the loop stays open. Odometry-driven
    # motion (the default's scan-matched motion drifts too little here to show it), and
    # alignments that run their course (with the default's stop at 3 times the gate the
    # fixed distance loses less: 0.037 against 0.024 m). Which seed drifts that far
    # depends on the machine's round-off (seed 0 on session 33's machine, seed 2 on
    # session 34's: there seeds 0 and 1 close the loop either way), so three seeds: the
    # widened distance closes every loop, the fixed one leaves at least one open.
    odometry = {"prealign": "none", "icp_stop_beyond_gate": 0.0}
    fixed = SlamConfig.from_dict({"filter": {**odometry, "candidate_near_sigma": 0.0}})
    opened = []
    for seed in range(3):
        _, beliefs_fixed, _, true = run(fixed, seed=seed)
        _, beliefs, _, _ = run(SlamConfig.from_dict({"filter": odometry}), seed=seed)
        err_fixed = np.hypot(*(beliefs_fixed[-1].pose[:2] - true[-1, :2]))
        err = np.hypot(*(beliefs[-1].pose[:2] - true[-1, :2]))
        assert err < 0.15, (seed, err)
        assert len(beliefs_fixed[-1].landmarks) >= len(beliefs[-1].landmarks), seed
        if err_fixed > 2.0 * err + 0.1:  # the loop left open, with landmarks made again
            opened.append(len(beliefs_fixed[-1].landmarks) > len(beliefs[-1].landmarks))
    assert opened and all(opened), opened


def reference_median_distance(points, model):
    """Median over points of the distance to the nearest line segment (plain loops)."""
    idx = model.line_vertices()
    out = []
    for p in points:
        best = np.inf
        for a, b in model.mean[idx]:
            ab = b - a
            t = np.clip(((p - a) @ ab) / max(ab @ ab, 1e-12), 0.0, 1.0)
            d = p - a - t * ab
            best = min(best, np.sqrt(d[0] * d[0] + d[1] * d[1]))
        out.append(best)
    return np.median(out)


def test_references_are_stored_in_creation_order():
    slam, _, _, _ = run(SlamConfig(), steps=30)
    assert [lm.ref for lm in slam._landmarks] == [3 + 2 * i for i in range(len(slam._landmarks))]
    np.testing.assert_array_equal(
        slam._refs(), [slam._mu[lm.ref : lm.ref + 2] for lm in slam._landmarks]
    )


# ----------------------------------------------------------------- association gates


def _kidnapped_update(config):
    """Map the first object from (0, 0, 0); then odometry says "no motion" but the robot
    was 0.4 m further on: the re-observation's ICP correction is 0.4 m."""
    slam = VertexSLAM(SENSOR, every_scan(config), initial_pose=(0.0, 0.0, 0.0))
    rng = np.random.default_rng(0)
    edges = polygon_edges(OBJECTS[:2])
    noise = (SENSOR.max_range, SENSOR.sigma_range, SENSOR.sigma_bearing, rng)
    first = slam.step([0.0, 0.0, 0.0], cast(np.zeros(3), edges, PHI, *noise), PHI)
    assert "created" in {d.outcome for d in first.decisions}
    moved = np.array([0.4, 0.0, 0.0])
    return slam.step([0.0, 0.0, 0.0], cast(moved, edges, PHI, *noise), PHI)


def test_icp_gate_floor_rejects_gross_corrections_and_keeps_plausible_ones():
    ungated = _kidnapped_update(
        SlamConfig.from_dict({"filter": {"icp_max_pose_mahalanobis": float("inf")}})
    )
    assert "updated" in {d.outcome for d in ungated.decisions}

    def gated(floor):
        cfg = SlamConfig.from_dict(
            {
                "filter": {
                    "icp_max_pose_mahalanobis": 3.0,
                    "icp_gate_sigma_floor": floor,
                    "icp_gate_fallback": False,
                }
            }
        )
        return _kidnapped_update(cfg)

    tight = gated([0.1, 0.1, 0.05])  # 0.4 m is 4 sigma: rejected, the map is kept apart
    assert "updated" not in {d.outcome for d in tight.decisions}
    assert any(c[1] == "gated" for d in tight.decisions for c in d.candidates)
    assert len(tight.landmarks) > len(ungated.landmarks)  # modelled again instead
    # With the fallback the gated candidates are tested at the predicted pose, where
    # the scan (taken 0.4 m further on) does not fit the map either.
    fallback = _kidnapped_update(
        SlamConfig.from_dict(
            {
                "filter": {
                    "icp_max_pose_mahalanobis": 3.0,
                    "icp_gate_sigma_floor": [0.1, 0.1, 0.05],
                    "icp_gate_fallback": True,
                }
            }
        )
    )
    tested = [c for d in fallback.decisions for c in d.candidates if c[1] == "gated"]
    assert tested and all(np.isfinite(c[2]) and not c[4] for c in tested)
    assert len(fallback.landmarks) == len(tight.landmarks)
    loose = gated([0.3, 0.3, 0.1])  # 0.4 m is 1.3 sigma: accepted
    assert "updated" in {d.outcome for d in loose.decisions}
    np.testing.assert_allclose(loose.pose, ungated.pose, atol=1e-9)
    with pytest.raises(ValueError, match="icp_gate_sigma_floor"):
        SlamConfig.from_dict({"filter": {"icp_gate_sigma_floor": [0.1, -0.1, 0.0]}})


def test_min_object_beam_fraction_is_validated_and_off_in_the_thesis():
    thesis = SlamConfig.thesis().filter
    assert thesis.min_object_beam_fraction == 0.0
    assert SlamConfig().filter.min_object_beam_fraction == 0.3
    logs = SlamConfig.logs().filter  # measured worse on ACES: both tests off there
    assert logs.min_object_beam_fraction == 0.0 and logs.candidate_max_near_distance == np.inf
    # a set with 2 of its 10 beams on object lines (u = 0) and 8 on unknown lines (u = 1)
    detection = SimpleNamespace(association=SimpleNamespace(u=np.r_[np.ones(8), np.zeros(2)]))
    assert not VertexSLAM(SENSOR, SlamConfig())._enough_object_beams(detection)
    assert VertexSLAM(SENSOR, SlamConfig.thesis())._enough_object_beams(detection)
    detection.association.u = np.r_[np.ones(7), np.zeros(3)]  # 3 of 10: enough
    assert VertexSLAM(SENSOR, SlamConfig())._enough_object_beams(detection)
    assert thesis.icp_max_pose_mahalanobis == float("inf") and not thesis.icp_gate_fallback
    with pytest.raises(ValueError, match="min_object_beam_fraction"):
        SlamConfig.from_dict({"filter": {"min_object_beam_fraction": 1.5}})


def _gated_config(**extra):
    return SlamConfig.from_dict(
        {
            "filter": {
                "icp_max_pose_mahalanobis": 3.0,
                "icp_gate_sigma_floor": [0.1, 0.1, 0.05],
                **extra,
            }
        }
    )


def test_icp_stop_beyond_gate_saves_iterations_without_changing_decisions(monkeypatch):
    import vslam_gym.slam.filter as filter_module

    results = []
    original = filter_module.align_many

    def recording(*args, **kwargs):
        out = original(*args, **kwargs)
        results.append(out)
        return out

    monkeypatch.setattr(filter_module, "align_many", recording)
    runs = {}
    for stop in (0.0, 1.0):
        results.clear()
        belief = _kidnapped_update(_gated_config(icp_stop_beyond_gate=stop))
        runs[stop] = (belief, [r for batch in results for r in batch])
    (full, full_icp), (stopped, stopped_icp) = runs[0.0], runs[1.0]
    # 0.4 m is 4 sigma of the gate: the same candidates are gated either way ...
    assert [(d.outcome, d.landmark) for d in stopped.decisions] == [
        (d.outcome, d.landmark) for d in full.decisions
    ]
    assert len(stopped.landmarks) == len(full.landmarks)
    np.testing.assert_array_equal(stopped.pose, full.pose)
    # ... but the alignments that left the gate stopped there
    assert any(r.reason == "out_of_bound" for r in stopped_icp)
    assert sum(r.iterations for r in stopped_icp) < sum(r.iterations for r in full_icp)
    # a 1.3 sigma correction (looser floor) stays inside the bound: nothing changes
    loose = {"icp_gate_sigma_floor": [0.3, 0.3, 0.1]}
    a = _kidnapped_update(_gated_config(**loose))
    b = _kidnapped_update(_gated_config(icp_stop_beyond_gate=1.0, **loose))
    assert "updated" in {d.outcome for d in b.decisions}
    np.testing.assert_array_equal(a.pose, b.pose)
    with pytest.raises(ValueError, match="icp_stop_beyond_gate"):
        SlamConfig.from_dict({"filter": {"icp_stop_beyond_gate": -1.0}})


def test_icp_prior_weight_is_the_pose_prior_in_point_units(monkeypatch):
    import vslam_gym.slam.filter as filter_module

    weights = []
    original = filter_module.align_many

    def recording(*args, **kwargs):
        weights.append(kwargs.get("prior_weight"))
        return original(*args, **kwargs)

    monkeypatch.setattr(filter_module, "align_many", recording)
    run(SlamConfig(), steps=6)
    assert weights and all(w is None for w in weights)  # the default: no prior
    floor = (0.05, 0.04, 0.02)
    cfg = SlamConfig.from_dict(
        {"filter": {"icp_prior_point_sigma": 0.03, "icp_prior_sigma_floor": list(floor)}}
    )
    weights.clear()
    slam, beliefs, _, true = run(cfg, steps=30)
    assert weights and all(w is not None for w in weights)
    assert len({w.tobytes() for w in weights}) > 1  # it follows the pose covariance
    # sigma_point^2 (Sigma_pose + floor^2)^-1 at the current pose covariance
    want = 0.03**2 * np.linalg.inv(slam._sigma[:3, :3] + np.diag(np.square(floor)))
    got = slam._icp_prior_weight()
    np.testing.assert_allclose(got, want, rtol=1e-9)
    np.testing.assert_array_equal(got, got.T)
    assert np.linalg.eigvalsh(got).min() > 0
    errors = [np.hypot(*(b.pose[:2] - t[:2])) for b, t in zip(beliefs, true[1:30], strict=True)]
    assert max(errors) < 0.1
    assert np.linalg.eigvalsh(slam._sigma).min() > 0
    for bad in ({"icp_prior_point_sigma": -0.1}, {"icp_prior_sigma_floor": [0.1, -0.1, 0.0]}):
        with pytest.raises(ValueError, match="icp_prior"):
            SlamConfig.from_dict({"filter": bad})


def test_icp_retry_rescues_an_alignment_pulled_off_beyond_the_gate(monkeypatch):
    import dataclasses

    import vslam_gym.slam.filter as filter_module

    def drive(config, pulled_off, steps=12, from_step=8):
        """The synthetic loop's first steps (exact odometry); from ``from_step`` on,
        optionally, every per-landmark ICP result ends 1 m off (as a set that sees far
        more than a partial model and is pulled onto it)."""
        original = filter_module.align_many
        active = [False]

        def pulled(*args, **kwargs):
            out = original(*args, **kwargs)
            if not active[0]:
                return out
            return [dataclasses.replace(r, pose=r.pose + np.array([1.0, 0.0, 0.0])) for r in out]

        monkeypatch.setattr(filter_module, "align_many", pulled if pulled_off else original)
        true = circle_route()
        slam = VertexSLAM(SENSOR, config, initial_pose=true[0])
        rng = np.random.default_rng(0)
        noise = (SENSOR.max_range, SENSOR.sigma_range, SENSOR.sigma_bearing, rng)
        outcomes, reasons = [], []
        for k in range(1, steps):
            active[0] = k >= from_step
            belief = slam.step(
                increments_between(true[k - 1], true[k]), cast(true[k], EDGES, PHI, *noise), PHI
            )
            if k >= from_step:
                outcomes += [d.outcome for d in belief.decisions]
                reasons += [c[1] for d in belief.decisions for c in d.candidates]
        return belief, outcomes, reasons

    clean, outcomes, _ = drive(_gated_config(), pulled_off=False)
    assert "updated" in outcomes
    off, outcomes, reasons = drive(_gated_config(), pulled_off=True)
    assert "updated" not in outcomes and "gated" in reasons
    retry = _gated_config(icp_retry_correspondence_distance=0.5)
    rescued, outcomes, reasons = drive(retry, pulled_off=True)
    assert "updated" in outcomes and "retried" in reasons and "gated" not in reasons
    # the retry (every point within 0.5 m of the model) finds the plain alignment again
    np.testing.assert_allclose(rescued.pose, clean.pose, atol=1e-6)
    assert len(rescued.landmarks) == len(clean.landmarks) < len(off.landmarks)
    # a retry that keeps no point stops at the predicted pose: that is no evidence
    starved = _gated_config(icp_retry_correspondence_distance=1e-4)
    _, outcomes, reasons = drive(starved, pulled_off=True)
    assert "updated" not in outcomes and "retried" not in reasons
    with pytest.raises(ValueError, match="icp_retry_min_fraction"):
        SlamConfig.from_dict({"filter": {"icp_retry_min_fraction": 1.5}})
    with pytest.raises(ValueError, match="icp_retry_correspondence_distance"):
        SlamConfig.from_dict({"filter": {"icp_retry_correspondence_distance": -1.0}})


def test_creation_overlap_distance_keeps_a_gated_reobservation_from_duplicating():
    plain = _kidnapped_update(_gated_config())
    assert "created" in {d.outcome for d in plain.decisions}
    # the re-observation lies 0.4 m from the mapped objects at the predicted pose
    guarded = _kidnapped_update(_gated_config(creation_overlap_distance=0.5))
    overlapping = [d for d in guarded.decisions if d.outcome == "overlapping"]
    assert overlapping and "created" not in {d.outcome for d in guarded.decisions}
    assert len(guarded.landmarks) < len(plain.landmarks)
    assert {d.landmark for d in overlapping} <= {lm.id for lm in guarded.landmarks}
    # too small a distance changes nothing
    tight = _kidnapped_update(_gated_config(creation_overlap_distance=0.05))
    assert len(tight.landmarks) == len(plain.landmarks)
    with pytest.raises(ValueError, match="creation_overlap_distance"):
        SlamConfig.from_dict({"filter": {"creation_overlap_distance": -0.1}})


def test_detection_model_sigma_loosens_the_detection_test_only():
    def first_landmark(sigma):
        slam = VertexSLAM(SENSOR, _gated_config(detection_model_sigma=sigma))
        rng = np.random.default_rng(1)
        noise = (SENSOR.max_range, SENSOR.sigma_range, SENSOR.sigma_bearing, rng)
        edges = polygon_edges(OBJECTS[:2])
        slam.step([0.0, 0.0, 0.0], cast(np.zeros(3), edges, PHI, *noise), PHI)
        lm = slam._landmarks[0]
        return slam._model(lm), slam._detection_model(lm), slam

    model, plain, _ = first_landmark(0.0)
    assert plain is model  # off: the detection test sees the state's own model
    state_model, inflated, slam = first_landmark(0.05)
    np.testing.assert_array_equal(state_model.cov, model.cov)  # the state is unchanged
    np.testing.assert_array_equal(inflated.mean, model.mean)
    np.testing.assert_allclose(inflated.cov - model.cov, 0.05**2 * np.eye(model.cov.shape[0]))
    assert np.linalg.eigvalsh(slam._sigma).min() > 0
    with pytest.raises(ValueError, match="detection_model_sigma"):
        SlamConfig.from_dict({"filter": {"detection_model_sigma": -0.01}})


def test_predicted_first_aligns_only_candidates_rejected_at_the_prediction(monkeypatch):
    import vslam_gym.slam.filter as filter_module

    aligned = []
    original = filter_module.align_many

    def counting(points, models, *args, **kwargs):
        aligned.append(len(models))
        return original(points, models, *args, **kwargs)

    monkeypatch.setattr(filter_module, "align_many", counting)

    def two_looks(mode, second_pose, floor=(0.3, 0.3, 0.1)):
        cfg = SlamConfig.from_dict(
            {"filter": {"association_pose": mode, "icp_gate_sigma_floor": list(floor)}}
        )
        slam = VertexSLAM(SENSOR, every_scan(cfg), initial_pose=(0.0, 0.0, 0.0))
        rng = np.random.default_rng(0)
        edges = polygon_edges(OBJECTS[:2])
        noise = (SENSOR.max_range, SENSOR.sigma_range, SENSOR.sigma_bearing, rng)
        slam.step([0.0, 0.0, 0.0], cast(np.zeros(3), edges, PHI, *noise), PHI)
        aligned.clear()
        return slam.step([0.0, 0.0, 0.0], cast(np.asarray(second_pose), edges, PHI, *noise), PHI)

    # looked at again from where it was mapped: every candidate passes at the prediction
    still = two_looks("predicted_first", [0.0, 0.0, 0.0])
    assert sum(aligned) == 0
    updated = [d for d in still.decisions if d.outcome == "updated"]
    assert updated and all(c[1] == "predicted" for d in updated for c in d.candidates)
    icp = two_looks("icp", [0.0, 0.0, 0.0])
    assert sum(aligned) > 0
    assert {d.landmark for d in icp.decisions if d.outcome == "updated"} == {
        d.landmark for d in updated
    }
    np.testing.assert_allclose(still.pose, icp.pose, atol=0.01)
    # 0.4 m on (the odometry says "no motion"): rejected at the prediction, aligned by ICP
    moved = two_looks("predicted_first", [0.4, 0.0, 0.0])
    assert sum(aligned) > 0
    reference = two_looks("icp", [0.4, 0.0, 0.0])
    np.testing.assert_array_equal(moved.pose, reference.pose)
    assert [d.outcome for d in moved.decisions] == [d.outcome for d in reference.decisions]
    with pytest.raises(ValueError, match="association_pose"):
        SlamConfig.from_dict({"filter": {"association_pose": "closest"}})


def test_motion_filter_measures_only_after_enough_motion():
    # the circle route moves 0.157 m and turns 0.053 rad per step
    cfg = SlamConfig.from_dict(
        {"filter": {"measurement_min_travel": 0.3, "measurement_min_turn": 1.0}}
    )
    slam, beliefs, odo_err, true = run(cfg)
    measured = np.array([b.measured for b in beliefs])
    assert measured[0]  # the first scan always builds the map
    assert 0.4 <= measured.mean() <= 0.6  # every second step
    for before, b in zip(beliefs[:-1], beliefs[1:], strict=True):
        if not b.measured:
            assert b.decisions == () and len(b.landmarks) == len(before.landmarks)
            # the motion update alone: the pose covariance grows
            assert np.trace(b.pose_cov) > np.trace(before.pose_cov)
    err = np.hypot(*(beliefs[-1].pose[:2] - true[-1, :2]))
    assert err < 0.5 * odo_err[-1], (err, odo_err[-1])
    assert np.linalg.eigvalsh(slam._sigma).min() > 0
    # turning in place: the turn threshold triggers a measurement
    turner = VertexSLAM(
        SENSOR,
        SlamConfig.from_dict(
            {"filter": {"measurement_min_travel": 1.0, "measurement_min_turn": 0.2}}
        ),
    )
    rng = np.random.default_rng(0)
    edges = polygon_edges(OBJECTS)
    noise = (SENSOR.max_range, SENSOR.sigma_range, SENSOR.sigma_bearing, rng)
    flags = []
    for k in range(1, 6):
        pose = np.array([0.0, 0.0, 0.12 * k])
        flags.append(turner.step([0.12, 0.0, 0.0], cast(pose, edges, PHI, *noise), PHI).measured)
    assert flags == [True, False, True, False, True]  # 0.24 rad after two steps
    for name in ("measurement_min_travel", "measurement_min_turn"):
        with pytest.raises(ValueError, match=name):
            SlamConfig.from_dict({"filter": {name: -0.1}})
    # the default's: after 0.15 m or 0.15 rad, here every third step of 0.06 m
    default = VertexSLAM(SENSOR)
    flags = []
    for k in range(1, 8):
        pose = np.array([0.06 * k, 0.0, 0.0])
        flags.append(default.step([0.0, 0.06, 0.0], cast(pose, edges, PHI, *noise), PHI).measured)
    assert flags == [True, False, False, True, False, False, True]


def _fresh_views(slam: VertexSLAM) -> list:
    """The landmark views built from the filter's state now (no cache)."""
    return [slam._landmark_view(lm) for lm in slam._landmarks]


def test_belief_views_are_made_again_only_after_the_map_changed():
    slam, beliefs, _, _ = run(
        SlamConfig.from_dict(
            {"filter": {"measurement_min_travel": 0.3, "measurement_min_turn": 1.0}}
        ),
        steps=30,
    )
    skipped = 0
    for before, b in zip(beliefs[:-1], beliefs[1:], strict=True):
        # a motion update leaves the map alone: the same views; a measurement makes new ones
        assert (b.landmarks is before.landmarks) == (not b.measured)
        skipped += not b.measured
    assert skipped >= 10
    # the views the last belief shares equal those made from the state now
    for view, fresh in zip(beliefs[-1].landmarks, _fresh_views(slam), strict=True):
        assert view.id == fresh.id and view.object_vertices == fresh.object_vertices
        np.testing.assert_array_equal(view.reference, fresh.reference)
        np.testing.assert_array_equal(view.reference_cov, fresh.reference_cov)
        np.testing.assert_array_equal(view.model.mean, fresh.model.mean)
        np.testing.assert_array_equal(view.model.cov, fresh.model.cov)
        np.testing.assert_array_equal(view.model.u, fresh.model.u)
    assert len(beliefs[-1].landmarks) == len(slam._landmarks) > 0
    # a reset forgets them
    assert slam.reset().landmarks == ()


def _turned_update(config, turn=0.05, moved=0.0):
    """Map the first objects from (0, 0, 0); then odometry says "no motion" but the robot
    turned by ``turn`` [rad] and moved ``moved`` [m] forward (odometry-driven motion: the
    scan-matched motion would find the turn before the landmark update)."""
    config = every_scan(replace(config, filter=replace(config.filter, prealign="none")))
    slam = VertexSLAM(SENSOR, config, initial_pose=(0.0, 0.0, 0.0))
    rng = np.random.default_rng(0)
    edges = polygon_edges(OBJECTS[:2])
    noise = (SENSOR.max_range, SENSOR.sigma_range, SENSOR.sigma_bearing, rng)
    slam.step([0.0, 0.0, 0.0], cast(np.zeros(3), edges, PHI, *noise), PHI)
    true = np.array([moved, 0.0, turn])
    return slam.step([0.0, 0.0, 0.0], cast(true, edges, PHI, *noise), PHI)


def test_verify_heading_sigma_rejects_turns_the_alignment_does_not_support():
    def config(verify, pose="icp"):
        # Without the model-error floor: with it the tight odometry prior keeps the
        # heading near 0.001 rad, and there is no turn to verify.
        return SlamConfig.from_dict(
            {
                "filter": {
                    "verify_heading_sigma": verify,
                    "association_pose": pose,
                    "observation_model_sigma": 0.0,
                }
            }
        )

    # The ICP pose says the robot turned by about 0.05 rad: the update turns the heading
    # within that interval and passes even a tight slack (0.1 prior sigma, 2e-4 rad),
    # and the result is that of no verification.
    plain = _turned_update(config(0.0))
    checked = _turned_update(config(0.1))
    assert "updated" in {d.outcome for d in checked.decisions}
    assert 0.003 < plain.pose[2] < 0.05
    np.testing.assert_array_equal(checked.pose, plain.pose)
    # Tested at the predicted pose (a 0.01 rad turn still passes the detection test
    # there), the association claims no turn at all: the update that turns the heading
    # anyway is rejected, and the pose stays the prediction.
    predicted = _turned_update(config(0.0, "predicted"), turn=0.01)
    assert "updated" in {d.outcome for d in predicted.decisions}
    assert predicted.pose[2] > 5e-4
    rejected = _turned_update(config(0.1, "predicted"), turn=0.01)
    outcomes = {d.outcome for d in rejected.decisions}
    assert "rejected" in outcomes and "updated" not in outcomes
    np.testing.assert_allclose(rejected.pose, np.zeros(3), atol=1e-12)
    assert len(rejected.landmarks) == len(predicted.landmarks)
    with pytest.raises(ValueError, match="verify_heading_sigma"):
        SlamConfig.from_dict({"filter": {"verify_heading_sigma": -1.0}})


def test_verify_position_sigma_rejects_moves_off_the_alignment_segment():
    def config(verify, pose):
        return SlamConfig.from_dict(
            {
                "filter": {
                    "verify_position_sigma": verify,
                    "verify_heading_sigma": 0.0,
                    "association_pose": pose,
                    "observation_model_sigma": 0.0,  # figures below measured without
                }
            }
        )

    # The robot moved 0.1 m forward. The update moves the position by 8.5e-5 m along x
    # (prior position sigma: 1.4e-3 m on the larger axis), 2e-5 m off the segment to the
    # ICP pose (an offset of 0.13 m, 0.22 rad off the x axis): a slack of 0.03 sigma
    # (4.3e-5 m) passes it ...
    plain = _turned_update(config(0.0, "icp"), turn=0.0, moved=0.1)
    checked = _turned_update(config(0.03, "icp"), turn=0.0, moved=0.1)
    assert plain.pose[0] > 5e-5
    assert "updated" in {d.outcome for d in checked.decisions}
    np.testing.assert_array_equal(checked.pose, plain.pose)
    # ... but at the predicted pose the segment is a point, and the same move is off it.
    rejected = _turned_update(config(0.03, "predicted"), turn=0.0, moved=0.1)
    outcomes = {d.outcome for d in rejected.decisions}
    assert "rejected" in outcomes and "updated" not in outcomes
    np.testing.assert_allclose(rejected.pose, np.zeros(3), atol=1e-12)
    with pytest.raises(ValueError, match="verify_position_sigma"):
        SlamConfig.from_dict({"filter": {"verify_position_sigma": float("nan")}})


@pytest.mark.parametrize("seed", [0, 1])
def test_observation_model_sigma_lowers_the_pose_nees_and_keeps_the_loop(seed):
    from vslam_gym.evaluation import pose_nees

    nees = {}
    for sigma in (0.0, 0.05):
        # Measured with odometry-driven motion; with the default's scan-matched motion the
        # term lowers this NEES on seed 0 only (56 -> 5.3; seed 1 9.5 -> 17.5).
        filter_ = {"observation_model_sigma": sigma, "observation_model_heading_sigma": 0.0}
        config = SlamConfig.from_dict({"filter": {**filter_, "prealign": "none"}})
        slam, beliefs, odo_err, true = run(config, seed=seed)
        est = np.array([b.pose for b in beliefs])
        nees[sigma] = pose_nees(est, np.array([b.pose_cov for b in beliefs]), true[1:]).mean()
        assert np.hypot(*(est[-1, :2] - true[-1, :2])) < 0.2 * odo_err[-1]
        assert np.linalg.eigvalsh(slam._sigma).min() > 0
    # measured: seed 0 55 -> 27, seed 1 93 -> 3.7 (3 for a consistent filter)
    assert nees[0.05] < 0.6 * nees[0.0], nees


def test_observation_model_heading_sigma_keeps_the_heading_less_certain():
    sd = {}
    for sigma in (0.0, 0.02):
        config = SlamConfig.from_dict({"filter": {"observation_model_heading_sigma": sigma}})
        slam, beliefs, odo_err, true = run(config, seed=0)
        sd[sigma] = np.median([np.sqrt(b.pose_cov[2, 2]) for b in beliefs])
        assert np.hypot(*(beliefs[-1].pose[:2] - true[-1, :2])) < 0.2 * odo_err[-1]
        assert np.linalg.eigvalsh(slam._sigma).min() > 0
    # measured: median heading sigma 0.0069 -> 0.0091 rad
    assert sd[0.02] > 1.2 * sd[0.0], sd
    with pytest.raises(ValueError, match="observation_model_heading_sigma"):
        SlamConfig.from_dict({"filter": {"observation_model_heading_sigma": -0.01}})


def test_creation_heading_model_error_keeps_a_creation_from_pinning_an_uncertain_heading():
    rng = np.random.default_rng(0)
    pose = circle_route()[0]
    scan = cast(pose, EDGES, PHI, SENSOR.max_range, SENSOR.sigma_range, SENSOR.sigma_bearing, rng)
    heading_sd, stored = {}, {}
    for factor in (0.0, 1.0):
        config = SlamConfig.from_dict(
            {
                "filter": {
                    "initial_pose_sigma": [1e-4, 1e-4, 0.05],
                    "creation_heading_model_error": factor,
                    "error_noise_scale": 0,  # the belief reports the filter's covariance
                }
            }
        )
        slam = VertexSLAM(SENSOR, config, initial_pose=pose)
        belief = slam.step(np.zeros(3), scan, PHI)
        assert len(belief.landmarks) >= 1
        assert np.linalg.eigvalsh(slam._sigma).min() > 0
        heading_sd[factor] = float(np.sqrt(belief.pose_cov[2, 2]))
        stored[factor] = [lm.heading_sigma for lm in slam._landmarks]
    # made at the predicted heading sigma: 0.05 rad plus the odometry floor's 1 mrad for
    # each of the two rotations of a standing robot
    assert stored[0.0] == pytest.approx([0.01] * len(stored[0.0]))
    assert stored[1.0][0] == pytest.approx(np.sqrt(0.05**2 + 2 * 0.001**2), rel=1e-9)
    assert all(0.01 <= s <= stored[1.0][0] for s in stored[1.0])
    # the thesis's creation pins the heading; with the model error it stays uncertain
    # (measured: 0.050 -> 0.010 rad without, 0.035 rad with)
    assert heading_sd[0.0] < 0.5 * heading_sd[1.0], heading_sd
    assert heading_sd[1.0] < stored[1.0][0]  # the scan still informs the heading
    with pytest.raises(ValueError, match="creation_heading_model_error"):
        SlamConfig.from_dict({"filter": {"creation_heading_model_error": -1.0}})


def test_step_time_parts_are_non_negative_and_within_the_step():
    from dataclasses import replace

    from vslam_gym.slam.filter import STEP_PARTS

    _, beliefs, _, _ = run(every_scan(SlamConfig()), steps=15)
    for b in beliefs:
        assert tuple(b.step_ms_parts) == STEP_PARTS
        assert all(v >= 0.0 for v in b.step_ms_parts.values())
        assert sum(b.step_ms_parts.values()) <= b.step_ms * 1.001 + 1e-3
        assert b.step_ms_parts["landmarks"] > 0.0  # every step measures here
    # a motion filter that skips the measurement update: only the motion part runs
    config = SlamConfig()
    config = replace(config, filter=replace(config.filter, measurement_min_travel=100.0))
    _, beliefs, _, _ = run(config, steps=5)
    skipped = [b for b in beliefs if not b.measured]
    assert skipped
    for b in skipped:
        assert b.step_ms_parts["landmarks"] == 0.0 == b.step_ms_parts["loop_closure"]
        assert b.step_ms_parts["motion"] > 0.0


def test_single_line_min_beams_updates_with_one_long_object_line():
    from collections import Counter

    from vslam_gym.evaluation import run_episode

    # On single_landmark seed 4 the set at the edge of the field of view covers one long
    # face of the landmark for about 20 steps: matched, but only "associated" (one
    # object line) by the thesis's rule.
    def outcomes(**extra):
        overrides = {"filter": {**EVERY_SCAN, **extra}}
        log = run_episode("single_landmark", 4, overrides=overrides, max_steps=110)
        return Counter(d.outcome for d in log.decisions), log

    plain, _ = outcomes(single_line_min_beams=0)  # the thesis's rule
    long_line, log = outcomes(single_line_min_beams=10)
    assert plain["associated"] >= 10
    assert long_line["associated"] < plain["associated"] / 4
    assert long_line["updated"] > plain["updated"] + plain["associated"] / 2
    for cov in log.slam_covs:
        assert np.linalg.eigvalsh(cov).min() > 0
    # a threshold no line reaches changes nothing
    never, _ = outcomes(single_line_min_beams=1000)
    assert never == plain
    with pytest.raises(ValueError, match="single_line_min_beams"):
        SlamConfig.from_dict({"filter": {"single_line_min_beams": -1}})
    # on by default; off in the thesis, logs and fast presets
    assert SlamConfig().filter.single_line_min_beams == 10
    for name in ("thesis", "logs", "fast"):
        assert SlamConfig.preset(name).filter.single_line_min_beams == 0


def test_update_max_correction_m2_rejects_corrections_beyond_their_covariance():
    def turned(limit, turn):
        config = SlamConfig.from_dict({"filter": {"update_max_correction_m2": limit}})
        return _turned_update(config, turn=turn)

    # Odometry says "no motion" (heading sigma about 1 mrad): a 0.01 rad turn moves the
    # heading as far as the update accounts for, a 0.05 rad one much further.
    for turn in (0.0, 0.01):
        plain, gated = turned(0.0, turn), turned(16.3, turn)
        assert {d.outcome for d in gated.decisions} >= {"updated"}
        np.testing.assert_array_equal(gated.pose, plain.pose)
    plain, gated = turned(0.0, 0.05), turned(16.3, 0.05)
    assert plain.pose[2] > 1e-3
    outcomes = {d.outcome for d in gated.decisions}
    assert "rejected" in outcomes and "updated" not in outcomes
    np.testing.assert_allclose(gated.pose, np.zeros(3), atol=1e-12)  # left as predicted
    assert np.linalg.eigvalsh(gated.pose_cov).min() > 0
    # a limit no correction reaches changes nothing
    np.testing.assert_array_equal(turned(1e9, 0.05).pose, plain.pose)
    assert SlamConfig().filter.update_max_correction_m2 == 0.0
    with pytest.raises(ValueError, match="update_max_correction_m2"):
        SlamConfig.from_dict({"filter": {"update_max_correction_m2": -1.0}})


def test_repeat_updates_discounts_a_landmarks_later_updates(monkeypatch):
    import vslam_gym.slam.filter as filter_module
    from vslam_gym.evaluation import run_episode

    seen: list[tuple[int, float]] = []  # (earlier updates, factor) of every update tried
    original = VertexSLAM._repeat_discount

    def recording(self, lm):
        factor = original(self, lm)
        seen.append((lm.updates, factor))
        return factor

    monkeypatch.setattr(filter_module.VertexSLAM, "_repeat_discount", recording)
    log = run_episode("small", 0, overrides={"filter": {"repeat_updates": 4}}, max_steps=80)
    updated = sum(d.outcome == "updated" for d in log.decisions)
    assert len(seen) >= updated > 0
    assert max(n for n, _ in seen) >= 4  # landmarks updated again and again
    for n, factor in seen:
        assert factor == pytest.approx(1.0 / (1.0 + n / 4))
    # weaker updates leave the pose less certain than the default's
    default = run_episode("small", 0, max_steps=80)
    trace = [np.trace(run.slam_covs[:, :2, :2], axis1=1, axis2=2).mean() for run in (default, log)]
    assert trace[1] > trace[0], trace
    assert SlamConfig().filter.repeat_updates == 0.0  # off by default
    with pytest.raises(ValueError, match="repeat_updates"):
        SlamConfig.from_dict({"filter": {"repeat_updates": -1.0}})
