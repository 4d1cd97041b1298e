"""Detection (SPEC section 8): does a set of beams come from a landmark model?

Models are built with ``create_model`` from ray-cast scans of known polygons at a known
pose ``P0``; the sets to test are scans from another known pose. ``THESIS_THRESHOLDS``
keeps the thesis's gate (3 sigma) and variance bound (3), which reject too many scans of
the right object (see ``test_same_object_acceptance_with_thesis_thresholds_is_measured``);
the defaults (``PROPOSED``: 4 sigma, 6) were changed on that measurement.
"""

from __future__ import annotations

import numpy as np
import pytest
from _raycast import bearings_deg, cast, polygon_edges

from vslam_gym.slam.config import ModelConfig, SensorConfig
from vslam_gym.slam.creation import create_model
from vslam_gym.slam.detection import (
    beam_line_correspondence,
    beam_line_correspondences,
    detect,
    detect_many,
    model_parts,
)
from vslam_gym.slam.gaussian import FirstOrderLinearization, first_order_transform
from vslam_gym.slam.landmark import LandmarkModel
from vslam_gym.slam.likelihood import (
    expected_range,
    exponential_rate,
    generalized_mahalanobis_sq,
    line_loglik,
    unknown_loglik,
)
from vslam_gym.slam.scan import Scan

SENSOR = SensorConfig()
PHI = bearings_deg()
P0 = np.array([0.0, 0.0, np.pi / 2])
DEFAULT = ModelConfig()
THESIS_THRESHOLDS = ModelConfig(
    detection_gate_sigma=3.0, detection_var_max=3.0, detection_trim_fraction=0.0
)
PROPOSED = ModelConfig(detection_gate_sigma=4.0, detection_var_max=6.0)
TRIALS = 100

# A closed non-convex polygon about 3 m x 2 m: a zig-zag front (two notches) facing P0.
W = np.array([(-1.5, 5.0), (-0.5, 5.6), (0.3, 5.0), (1.5, 5.7), (1.4, 7.0), (-1.4, 7.0)])
# Different objects of similar size, placed where W is.
OTHERS = {
    "chevron": np.array([(-1.5, 5.6), (0.0, 5.0), (1.5, 5.6), (1.4, 7.0), (-1.4, 7.0)]),
    "mirrored": W * [-1.0, 1.0],
    "triangle": np.array([(-1.5, 5.0), (1.5, 5.5), (0.0, 7.0)]),
}


def scan_of(edges, pose, rng=None):
    r = cast(pose, edges, PHI, SENSOR.max_range, SENSOR.sigma_range, SENSOR.sigma_bearing, rng)
    return Scan.from_arrays(r, PHI, SENSOR)


def segment(scan):
    idx = np.flatnonzero(scan.returns)
    assert np.all(np.diff(idx) == 1), "test scenes must give one contiguous segment"
    return int(idx[0]), int(idx[-1])


def rotate(points, angle):
    c, s = np.cos(angle), np.sin(angle)
    return np.asarray(points) @ np.array([[c, s], [-s, c]])


@pytest.fixture(scope="module")
def trials():
    """Seeded trials: a model of W from a noisy scan at P0, then noisy scans of W and of
    the other objects from a pose 0.5 m away (random direction) and turned by 10 deg."""
    rng = np.random.default_rng(0)
    out = []
    for _ in range(TRIALS):
        s0 = scan_of(polygon_edges([W]), P0, rng)
        fit = create_model(s0, *segment(s0), P0, SENSOR, DEFAULT)
        heading = rng.uniform(0.0, 2.0 * np.pi)
        turn = rng.choice([-1.0, 1.0]) * np.deg2rad(10.0)
        pose = P0 + np.array([0.5 * np.cos(heading), 0.5 * np.sin(heading), turn])
        scans = {name: scan_of(polygon_edges([poly]), pose, rng) for name, poly in OTHERS.items()}
        scans["W"] = scan_of(polygon_edges([W]), pose, rng)
        out.append((fit.model, pose, scans))
    return out


def run(trials, name, config):
    return [
        detect(model, scans[name], *segment(scans[name]), pose, SENSOR, config)
        for model, pose, scans in trials
    ]


# ------------------------------------------------------------- acceptance / rejection


def test_same_object_acceptance_with_thesis_thresholds_is_measured(trials):
    """The thesis thresholds (mean and population variance of d_GM^2 both <= 3) accept
    only about 86 % of these scans (76-86 % over seeds 0-4), below the 95 % target.

    Two causes, both measured: (1) for a consistent set d_GM^2 ~ chi2(1) (mean 1,
    variance 2), and the sample variance of ~30 such values exceeds 3 in about 15 % of
    sets (one 3-sigma beam adds 81/30 to it); (2) an edge beam that hits the part of the
    object between the model's end vertex (on the last-hit ray) and the true corner
    falls outside the 3-sigma gate of the object line and is scored against an unknown
    line, far in front of it. The object-line beams themselves are calibrated: their
    mean d_GM^2 is close to 1 (below it: the coarseness term inflates variances).
    """
    detections = run(trials, "W", THESIS_THRESHOLDS)
    rate = np.mean([d.accepted for d in detections])
    assert 0.70 <= rate <= 0.92, rate
    d2 = np.concatenate([d.association.d2[d.association.u == 0] for d in detections])
    assert 0.7 <= d2.mean() <= 1.2, d2.mean()
    failed = [d for d in detections if not d.accepted]
    variance_only = [d for d in failed if d.mean_d2 <= THESIS_THRESHOLDS.detection_mean_max]
    assert len(variance_only) >= len(failed) / 2


def test_same_object_accepted_with_proposed_thresholds(trials):
    """Gate 4 sigma and variance <= 6 (the proposal): >= 95 % accepted (measured 100 %)."""
    rate = np.mean([d.accepted for d in run(trials, "W", PROPOSED)])
    assert rate >= 0.95, rate


@pytest.mark.parametrize("config", [THESIS_THRESHOLDS, PROPOSED], ids=["thesis", "proposed"])
@pytest.mark.parametrize("name", sorted(OTHERS))
def test_different_object_rejected(trials, name, config):
    detections = run(trials, name, config)
    rejected = np.mean([not d.accepted for d in detections])
    assert rejected >= 0.95, rejected
    # The true object is the more likely one (set log-likelihood per beam, as used for
    # maximum-likelihood correspondence between accepted models).
    same = run(trials[:10], "W", config)
    for s_w, o in zip(same, detections[:10], strict=True):
        assert s_w.loglik / s_w.association.n > o.loglik / o.association.n


# ---------------------------------------------------------------------- exact cases


@pytest.mark.parametrize("linearization", ["jacobian", "ut"])
def test_noiseless_scan_at_the_model_pose_matches(linearization):
    """Every d_GM^2 is far below 1 (measured: median 1e-27 with first order, 6e-4 with
    the UT; largest 0.07-0.09, on the first face, whose fit includes the corner beam
    that hits the next face and tilts it by a few millimetres)."""
    config = ModelConfig(linearization=linearization)
    scan = scan_of(polygon_edges([W]), P0)
    fit = create_model(scan, *segment(scan), P0, SENSOR, config)
    d = detect(fit.model, scan, *segment(scan), P0, SENSOR, config)
    a = d.association
    assert d.accepted
    assert np.all(a.gated)
    assert np.all(a.u == 0)  # every beam on an object line
    assert a.d2.max() <= 0.2
    assert np.median(a.d2) <= 1e-2
    assert d.mean_d2 <= 0.01
    assert d.loglik == pytest.approx(np.sum(line_loglik(a.mu_err, a.var_err, 0.0, 1.0)))


def test_noiseless_scan_from_another_pose_matches():
    scan0 = scan_of(polygon_edges([W]), P0)
    fit = create_model(scan0, *segment(scan0), P0, SENSOR, DEFAULT)
    pose = P0 + np.array([0.3, -0.4, np.deg2rad(10.0)])
    scan = scan_of(polygon_edges([W]), pose)
    d = detect(fit.model, scan, *segment(scan), pose, SENSOR, DEFAULT)
    assert d.accepted
    assert d.mean_d2 <= 0.1
    # Each beam took the line its return lies on: W's faces are lines 2, 3, 4 of the model.
    assert set(d.association.line) == {2, 3, 4}


# Occlusion scene: a wall with a corner, partly hidden from P0 by a short board in front.
WALL = np.array([[(-3.0, 6.0), (1.0, 6.0)], [(1.0, 6.0), (2.5, 4.5)]])
BOARD = np.array([[(-1.2, 2.5), (-0.6, 2.5)]])
OCCLUSION = np.concatenate([WALL, BOARD])
P_RIGHT = np.array([0.5, 0.0, np.pi / 2 + np.deg2rad(10.0)])


def wall_segment(scan):
    """The run of beams on the wall right of the board's shadow."""
    far = scan.returns & (scan.ranges > 4.0)
    last = int(np.flatnonzero(far)[-1])
    first = last
    while first > 0 and far[first - 1] and abs(scan.ranges[first - 1] - scan.ranges[first]) < 1:
        first -= 1
    return first, last


def occlusion_model():
    scan = scan_of(OCCLUSION, P0)
    fit = create_model(scan, *wall_segment(scan), P0, SENSOR, DEFAULT)
    # The left end is an occlusion: vertex 0 is the board's edge, line 0 the shadow's edge.
    np.testing.assert_allclose(fit.model.mean[0], (-0.6, 2.5), atol=0.05)
    assert fit.model.u[0] == 1.0
    return fit.model


def test_beams_behind_an_unknown_line_are_scored_with_the_unknown_density():
    """From a pose further right, the lidar sees part of the wall that was in the board's
    shadow: those beams cross the shadow line (an unknown line, u = 1) from its free
    side and hit the wall behind it. They are scored with the unknown-line density (an
    exponential behind the line) and barely raise d_GM^2."""
    model = occlusion_model()
    scan = scan_of(OCCLUSION, P_RIGHT)
    first, last = wall_segment(scan)
    lam = exponential_rate(scan.ranges, scan.max_range)
    d = detect(model, scan, first, last, P_RIGHT, SENSOR, DEFAULT, lam=lam)
    a = d.association
    shadow = a.line == 0
    assert shadow.sum() >= 4
    assert np.all(a.gated[shadow]) and np.all(a.u[shadow] == 1.0)
    assert np.all(a.mu_err[shadow] > 1.0)  # metres behind the shadow line
    np.testing.assert_allclose(
        a.loglik[shadow], unknown_loglik(a.mu_err[shadow], a.var_err[shadow], lam)
    )
    np.testing.assert_allclose(
        a.d2[shadow], generalized_mahalanobis_sq(a.mu_err[shadow], a.var_err[shadow], 1.0, lam)
    )
    assert np.all(a.d2[shadow] < 0.2)
    assert d.accepted and d.mean_d2 < 0.1


def test_returns_in_front_of_an_unknown_line_are_rejected():
    """The same beams, but returning 0.5 m in front of the shadow line, inside the free
    space observed from P0: the unknown density is a Gaussian tail there. (The shadow
    line runs nearly along these beams, so their range errors have a large variance.)"""
    model = occlusion_model()
    scan = scan_of(OCCLUSION, P_RIGHT)
    first, last = wall_segment(scan)
    before = detect(model, scan, first, last, P_RIGHT, SENSOR, DEFAULT).association
    shadow = first + np.flatnonzero(before.line == 0)
    assert shadow.size >= 4
    ranges = scan.ranges.copy()
    r_line = expected_range(scan.bearings[shadow], model.mean[0], model.mean[1], P_RIGHT)
    ranges[shadow] = r_line - 0.5
    moved = Scan.from_arrays(ranges, PHI, SENSOR)
    d = detect(model, moved, first, last, P_RIGHT, SENSOR, DEFAULT)
    a = d.association
    assert np.all(a.line[shadow - first] == 0)
    np.testing.assert_allclose(a.mu_err[shadow - first], -0.5, atol=1e-9)
    assert np.all(a.d2[shadow - first] > 9.0)
    assert not d.accepted


def test_beams_outside_the_model_go_to_its_end_lines():
    """A set that extends beyond the model (W plus a wall behind it on both sides):
    beams left of the model have no candidate and take line 0, beams right of it the
    last line; they are far in front of those (max-range) lines and the set is rejected."""
    scan0 = scan_of(polygon_edges([W]), P0)
    model = create_model(scan0, *segment(scan0), P0, SENSOR, DEFAULT).model
    back = np.array([[(-9.0, 9.0), (9.0, 9.0)]])
    scan = scan_of(np.concatenate([polygon_edges([W]), back]), P0)
    first, last = segment(scan)
    d = detect(model, scan, first, last, P0, SENSOR, DEFAULT)
    a = d.association
    bearing = scan.bearings[first : last + 1]
    v_bearing = np.arctan2(model.mean[:, 1], model.mean[:, 0]) - P0[2]
    margin = np.deg2rad(1.0)
    left = bearing > v_bearing[0] + margin
    right = bearing < v_bearing[-1] - margin
    assert left.sum() >= 10 and right.sum() >= 10
    assert not np.any(a.gated[left | right])
    assert np.all(a.line[left] == 0)
    assert np.all(a.line[right] == model.n_lines - 1)
    assert np.all(a.mu_err[left | right] < -15.0)  # the wall is far in front of r_max
    assert not d.accepted


def test_zero_range_vertex_at_the_fov_limit():
    """A landmark at the FOV edge has a vertex at the lidar position; seen from that pose
    its line is radial (no bearing of its own) and never a candidate."""
    pose = np.array([0.0, 0.0, 0.0])
    edges = np.array([[(-1.0, 6.0), (3.0, 4.0)], [(3.0, 4.0), (6.0, 9.0)]])
    wall = np.array([[(-5.0, -2.0), (-5.0, 8.0)]])
    scan = scan_of(np.concatenate([edges, wall]), pose)
    last = int(np.flatnonzero(np.abs(np.diff(scan.ranges)) > 1.0)[0])
    fit = create_model(scan, 0, last, pose, SENSOR, DEFAULT)
    np.testing.assert_allclose(fit.model.mean[0], pose[:2], atol=1e-12)
    d = detect(fit.model, scan, 0, last, pose, SENSOR, DEFAULT)
    assert d.accepted and np.all(d.association.gated)
    assert not np.any(d.association.line == 0)


def test_beam_parallel_to_its_line_has_no_range_error():
    """Beams right of a one-line model fall back to that line; those within
    arcsin(parallel_sin_min) of its direction never meet it: no range error, infinite
    d_GM^2, and the set is rejected."""
    model = LandmarkModel(np.array([(-1.0, 5.0), (1.0, 5.0)]), 0.01**2 * np.eye(4), [0.0])
    ranges = cast(P0, np.array([[(-1.0, 5.0), (1.0, 5.0)]]), PHI)
    first = int(np.flatnonzero(ranges < SENSOR.max_range)[0])
    ranges[first:] = np.minimum(ranges[first:], 3.0)  # returns all the way to -90 deg
    scan = Scan.from_arrays(ranges, PHI, SENSOR)
    d = detect(model, scan, first, scan.n - 1, P0, SENSOR, DEFAULT)
    a = d.association
    angle = np.abs(np.sin(scan.bearings[first:] + P0[2]))  # |sin| of beam vs. the line
    parallel = angle <= DEFAULT.parallel_sin_min
    assert parallel.sum() == 3  # bearings -88, -89, -90 deg
    assert np.all(np.isnan(a.mu_err[parallel])) and np.all(a.d2[parallel] == np.inf)
    assert np.all(a.loglik[parallel] == -np.inf) and np.all(a.line == 0)
    assert np.all(np.isfinite(a.d2[~parallel]))
    assert not d.accepted
    untrimmed = detect(model, scan, first, scan.n - 1, P0, SENSOR, THESIS_THRESHOLDS)
    assert untrimmed.mean_d2 == np.inf


# ------------------------------------------------------------------ closed polygons


def closed_box(closed=True):
    """A 2 m x 2 m box with outward-facing lines (free side on the right, i.e. the
    vertices counter-clockwise); line 3 (the closing line, vertex 3 -> 0) faces P0."""
    corners = np.array([(1.0, 4.0), (1.0, 6.0), (-1.0, 6.0), (-1.0, 4.0)])
    cov = 0.01**2 * np.eye(8)
    return LandmarkModel(corners, cov, np.zeros(4 if closed else 3), closed=closed), corners


def test_closed_polygon_uses_its_closing_line():
    model, corners = closed_box()
    pose = np.array([2.5, 0.0, np.pi / 2 + 0.3])
    scan = scan_of(polygon_edges([corners]), pose)
    first, last = segment(scan)
    d = detect(model, scan, first, last, pose, SENSOR, DEFAULT)
    a = d.association
    # Front face (y = 4) on the closing line 3, right face (x = 1) on line 0; the two
    # back-facing lines get no beam.
    assert set(a.line) == {0, 3}
    assert np.sum(a.line == 3) >= 10 and np.sum(a.line == 0) >= 3
    assert np.all(a.gated)
    assert d.accepted and d.mean_d2 < 0.5
    # Without the closing line the front-face beams have no candidate (but the one at
    # the corner, inside the gate of line 0) and the set fails.
    open_model, _ = closed_box(closed=False)
    d_open = detect(open_model, scan, first, last, pose, SENSOR, DEFAULT)
    assert d_open.association.gated[a.line == 3].sum() <= 1
    assert not d_open.accepted


@pytest.mark.parametrize("linearization", ["jacobian", "ut"])
def test_rigid_motion_of_the_world_changes_nothing(linearization):
    """Turning the whole scene (objects and poses) about the origin so that the heading
    and the vertex bearings cross +-pi gives the same association (angle wrapping)."""
    config = ModelConfig(linearization=linearization)
    rng = np.random.default_rng(7)
    pose = P0 + np.array([0.4, -0.3, np.deg2rad(-10.0)])
    scan0 = scan_of(polygon_edges([W]), P0, rng)
    scan = scan_of(polygon_edges([W]), pose, rng)
    fit = create_model(scan0, *segment(scan0), P0, SENSOR, config)
    angle = np.pi / 2 + 0.05  # the heading becomes pi + 0.05 -> -pi + 0.05
    turned = LandmarkModel(rotate(fit.model.mean, angle), fit.model.cov, fit.model.u)
    rot4 = np.kron(np.eye(fit.model.n_vertices), rotate(np.eye(2), angle).T)
    turned.cov = rot4 @ fit.model.cov @ rot4.T
    turned_pose = np.concatenate([rotate(pose[:2], angle), [pose[2] + angle]])
    turned_pose[2] = np.arctan2(np.sin(turned_pose[2]), np.cos(turned_pose[2]))
    d = detect(fit.model, scan, *segment(scan), pose, SENSOR, config)
    e = detect(turned, scan, *segment(scan), turned_pose, SENSOR, config)
    np.testing.assert_array_equal(d.association.line, e.association.line)
    # First order is exactly invariant; the UT's sigma points come from a Cholesky factor,
    # which does not turn with the covariance, so it agrees to its own accuracy only.
    rtol = 1e-6 if linearization == "jacobian" else 1e-3
    np.testing.assert_allclose(e.association.d2, d.association.d2, rtol=rtol, atol=1e-9)
    assert d.accepted == e.accepted


# ----------------------------------------------------------------- linearisations


class GenericFirstOrder:
    """First order through the generic ``propagate`` path (not the closed form)."""

    def propagate(self, f, mu, Sigma, jacobian=None, *, check=True):  # noqa: N803
        return first_order_transform(f, mu, Sigma, jacobian=jacobian, check=check)


def test_closed_form_first_order_matches_the_generic_path(trials):
    for model, pose, scans in trials[:5]:
        scan = scans["W"]
        lam = exponential_rate(scan.ranges, scan.max_range)
        args = (model, scan, *segment(scan), pose, SENSOR, DEFAULT)
        fast = beam_line_correspondence(*args, FirstOrderLinearization(), lam)
        slow = beam_line_correspondence(*args, GenericFirstOrder(), lam)
        np.testing.assert_array_equal(fast.line, slow.line)
        np.testing.assert_allclose(fast.mu_err, slow.mu_err, rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(fast.var_err, slow.var_err, rtol=1e-9)
        np.testing.assert_allclose(fast.d2, slow.d2, rtol=1e-6, atol=1e-9)


def test_scores_are_the_likelihood_modules(trials):
    """Per-beam log-likelihoods and distances are those of ``likelihood`` (3.2.43, SPEC 8)."""
    for model, pose, scans in trials[:10]:
        for scan in scans.values():
            lam = exponential_rate(scan.ranges, scan.max_range)
            d = detect(model, scan, *segment(scan), pose, SENSOR, DEFAULT)
            a = d.association
            ok = np.isfinite(a.mu_err)
            np.testing.assert_allclose(
                a.loglik[ok], line_loglik(a.mu_err[ok], a.var_err[ok], a.u[ok], lam)
            )
            np.testing.assert_allclose(
                a.d2[ok], generalized_mahalanobis_sq(a.mu_err[ok], a.var_err[ok], a.u[ok], lam)
            )
            assert np.all(a.d2[~ok] == np.inf) and np.all(a.loglik[~ok] == -np.inf)
            assert d.loglik == pytest.approx(np.sum(a.loglik))
            # the statistics leave out the largest floor(trim * n) values
            k = int(np.floor(DEFAULT.detection_trim_fraction * a.d2.size))
            kept = np.sort(a.d2)[: a.d2.size - k]
            if np.all(np.isfinite(kept)):
                assert d.mean_d2 == pytest.approx(np.mean(kept))
                assert d.var_d2 == pytest.approx(np.var(kept))
            else:
                assert d.mean_d2 == d.var_d2 == np.inf and not d.accepted


def test_unscented_and_first_order_agree(trials):
    ut = ModelConfig(linearization="ut")
    for model, pose, scans in trials[:5]:
        scan = scans["W"]
        a = detect(model, scan, *segment(scan), pose, SENSOR, DEFAULT)
        b = detect(model, scan, *segment(scan), pose, SENSOR, ut)
        np.testing.assert_array_equal(a.association.line, b.association.line)
        np.testing.assert_allclose(a.association.mu_err, b.association.mu_err, atol=2e-3)
        np.testing.assert_allclose(a.association.var_err, b.association.var_err, rtol=0.05)


# ---------------------------------------------------------------------- bad input


def test_bad_input_raises():
    scan = scan_of(polygon_edges([W]), P0)
    first, last = segment(scan)
    model = create_model(scan, first, last, P0, SENSOR, DEFAULT).model

    def call(**kw):
        args = dict(model=model, scan=scan, first=first, last=last, pose=P0)
        args.update(kw)
        return detect(sensor=SENSOR, config=DEFAULT, **args)

    cases = [
        (dict(first=-1), "first"),
        (dict(last=scan.n), "last"),
        (dict(first=last, last=first), "first <= last"),
        (dict(first=1.5), "first must be an integer"),
        (dict(first=first - 3), "no-return"),
        (dict(pose=P0[:2]), "pose must have shape"),
        (dict(pose=np.array([0.0, np.nan, 0.0])), "pose must be finite"),
        (dict(lam=0.0), "lam"),
        (dict(model=LandmarkModel(np.zeros((1, 2)), np.eye(2), np.zeros(0))), "at least one line"),
        (dict(scan=scan.ranges), "scan must be a Scan"),
    ]
    for kw, match in cases:
        with pytest.raises(ValueError, match=match):
            call(**kw)


# ------------------------------------------------------------- batched over models


def assert_same_detection(got, single):
    """``got`` equals ``single`` bit for bit: decision, statistics and every beam."""
    assert (got.accepted, got.mean_d2, got.var_d2, got.loglik) == (
        single.accepted,
        single.mean_d2,
        single.var_d2,
        single.loglik,
    )
    for name in ("line", "gated", "mu_err", "var_err", "loglik", "u", "d2"):
        np.testing.assert_array_equal(
            getattr(got.association, name), getattr(single.association, name)
        )


def _varied_models(trials):
    """Models of different sizes: W from several scans, a closed and an open box."""
    models = [trials[k][0] for k in range(4)]
    models += [closed_box()[0], closed_box(closed=False)[0]]
    return models


@pytest.mark.parametrize("linearization", ["jacobian", "ut"])
def test_detect_many_equals_one_model_at_a_time(trials, linearization):
    config = ModelConfig(linearization=linearization)
    rng = np.random.default_rng(7)
    models = _varied_models(trials)
    model0, pose0, scans = trials[0]
    scan = scans["W"]
    first, last = segment(scan)
    poses = pose0 + rng.normal(0.0, [0.05, 0.05, 0.02], (len(models), 3))
    many = detect_many(models, scan, first, last, poses, SENSOR, config)
    assert len(many) == len(models)
    cached = detect_many(
        models, scan, first, last, poses, SENSOR, config, parts=[model_parts(m) for m in models]
    )
    for model, pose, d, c in zip(models, poses, many, cached, strict=True):
        single = detect(model, scan, first, last, pose, SENSOR, config)
        for got in (d, c):
            assert_same_detection(got, single)
    # the same models seen from the right pose include accepted ones
    assert any(
        d.accepted for d in detect_many(models[:4], scan, first, last, [pose0] * 4, SENSOR, config)
    )


@pytest.mark.parametrize("linearization", ["jacobian", "ut"])
def test_detect_many_with_a_set_per_model_equals_one_set_at_a_time(trials, linearization):
    """Per-model beam spans (the filter tests all sets of a scan in one call): each
    result is that of the model's own set alone, bit for bit."""
    config = ModelConfig(linearization=linearization)
    rng = np.random.default_rng(8)
    models = _varied_models(trials)
    _, pose0, scans = trials[0]
    scan = scans["W"]
    first, last = segment(scan)
    # sets of different lengths: the whole segment, its halves, a few beams
    mid = (first + last) // 2
    spans = [(first, last), (first, mid), (mid + 1, last), (first + 2, first + 6)]
    spans = [spans[k % len(spans)] for k in range(len(models))]
    poses = pose0 + rng.normal(0.0, [0.05, 0.05, 0.02], (len(models), 3))
    firsts, lasts = [f for f, _ in spans], [la for _, la in spans]
    many = detect_many(models, scan, firsts, lasts, poses, SENSOR, config)
    for model, (f, la), pose, got in zip(models, spans, poses, many, strict=True):
        single = detect(model, scan, f, la, pose, SENSOR, config)
        assert got.association.n == la - f + 1
        assert_same_detection(got, single)
    assert any(d.accepted for d in many) and not all(d.accepted for d in many)
    with pytest.raises(ValueError, match="first <= last"):
        detect_many(models[:2], scan, [first, last], [last, first], poses[:2], SENSOR, config)


def test_beam_line_correspondences_checks_its_poses(trials):
    model, pose, scans = trials[0]
    scan = scans["W"]
    first, last = segment(scan)
    lin = FirstOrderLinearization()
    with pytest.raises(ValueError, match="poses must have shape"):
        beam_line_correspondences(
            [model, model], scan, first, last, pose, SENSOR, DEFAULT, lin, 0.1
        )
    with pytest.raises(ValueError, match="at least one"):
        beam_line_correspondences([], scan, first, last, pose[None], SENSOR, DEFAULT, lin, 0.1)
    quick = beam_line_correspondences(
        [model, model], scan, first, last, [pose, pose], SENSOR, DEFAULT, lin, 0.1, distances=False
    )
    assert all(np.all(np.isnan(q.d2)) for q in quick)
    np.testing.assert_array_equal(quick[0].line, quick[1].line)


def test_beam_offsets_equal_wrap_angle_bit_for_bit():
    """The gate's wrapped bearing offsets are wrap_angle's, without its float remainder."""
    from vslam_gym.slam.detection import _beam_offsets
    from vslam_gym.slam.geometry import wrap_angle

    rng = np.random.default_rng(3)
    edges = np.array([-np.pi, np.pi, 0.0, -0.0, np.nextafter(np.pi, 0.0), 1e-300, -1e-17])
    phi = np.asarray(wrap_angle(rng.uniform(-4.0, 4.0, (2, 3, 40))))
    phi[..., : edges.size] = wrap_angle(edges)
    for beams in (
        rng.uniform(-np.pi, np.pi, (3, 50)),
        np.tile(edges, (3, 1)),
        rng.uniform(-7.0, 7.0, (3, 50)),  # outside [-pi, pi]: wrap_angle itself
    ):
        got = _beam_offsets(phi, beams)
        want = np.asarray(wrap_angle(phi[..., None, :] - beams[:, :, None]))
        assert got.tobytes() == want.tobytes()
