"""Whole-scan matcher (:mod:`vslam_gym.slam.scan_matching`) on ray-cast scans."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from _raycast import bearings_deg, cast, polygon_edges

from vslam_gym.slam.filter import SlamConfig
from vslam_gym.slam.geometry import wrap_angle
from vslam_gym.slam.motion import compose
from vslam_gym.slam.scan_matching import (
    LocalMap,
    ScanMatcherConfig,
    _hypotheses,
    _NormalAgreement,
    _residuals,
    match_scan,
    scan_normals,
    scan_points,
)

L_ROOM = polygon_edges(
    [np.array([[0.0, 0.0], [10.0, 0.0], [10.0, 4.0], [4.0, 4.0], [4.0, 10.0], [0.0, 10.0]])]
)
CORRIDOR = np.array(  # two long parallel walls, no end in range
    [[[-100.0, 1.5], [100.0, 1.5]], [[-100.0, -1.5], [100.0, -1.5]]]
)
BEARINGS = bearings_deg(180.0, 1.0)
MAX_RANGE = 30.0


def _points(pose, edges, seed):
    rng = np.random.default_rng(seed)
    r = cast(pose, edges, BEARINGS, MAX_RANGE, sigma_range=0.01, rng=rng)
    return scan_points(r, BEARINGS, MAX_RANGE)


def _cov(sigma_xy: float, sigma_theta_deg: float) -> np.ndarray:
    return np.diag([sigma_xy**2, sigma_xy**2, max(np.deg2rad(sigma_theta_deg), 1e-6) ** 2])


def _map(pose, edges, config=None) -> LocalMap:
    local = LocalMap(config or ScanMatcherConfig())
    local.add(_points(pose, edges, 0), np.asarray(pose))
    return local


def test_recovers_a_03_m_15_deg_offset_in_an_l_room_from_heading_hypotheses():
    ref_pose = np.array([2.0, 2.0, 0.6])
    true = np.array([2.25, 2.15, 0.6 + np.deg2rad(15.0)])  # 0.29 m and 15 deg away
    local = _map(ref_pose, L_ROOM)
    pts = _points(true, L_ROOM, 1)
    result = match_scan(pts, local, ref_pose, _cov(0.2, 8.0))
    assert result is not None
    assert result.hypotheses > 5
    assert np.hypot(*(result.pose[:2] - true[:2])) < 0.03
    assert abs(wrap_angle(result.pose[2] - true[2])) < np.deg2rad(0.5)
    assert np.allclose(result.cov, result.cov.T)
    assert np.all(np.linalg.eigvalsh(result.cov) > 0)
    err = result.pose - true
    err[2] = wrap_angle(err[2])
    assert err @ np.linalg.solve(result.cov, err) < 16.0  # within 4 sigma


def test_step_spacing_places_hypotheses_a_step_apart_and_one_for_a_narrow_span():
    step_config = ScanMatcherConfig(hypothesis_spacing="step")
    assert step_config.heading_step_deg == 5.0 and step_config.heading_sigmas == 4.0
    prior = np.array([1.0, 2.0, 0.3])
    # +- 4 sigma = +- 2.3 deg: one start (the span's default spreads three over it)
    narrow = _hypotheses(prior, np.deg2rad(0.575), step_config)
    assert narrow.tolist() == [prior.tolist()]
    assert _hypotheses(prior, np.deg2rad(0.575), ScanMatcherConfig()).shape[0] == 3
    # +- 4 sigma = +- 22 deg: -20 ... 20 deg in 5 deg steps, positions unchanged
    wide = _hypotheses(prior, np.deg2rad(5.5), step_config)
    assert np.allclose(np.rad2deg(wide[:, 2] - prior[2]), np.arange(-20.0, 21.0, 5.0))
    assert np.all(wide[:, :2] == prior[:2])
    capped = _hypotheses(prior, np.deg2rad(5.5), replace(step_config, max_hypotheses=4))
    assert np.allclose(np.rad2deg(capped[:, 2] - prior[2]), [-5.0, 0.0, 5.0])
    with pytest.raises(ValueError, match="hypothesis_spacing"):
        ScanMatcherConfig(hypothesis_spacing="even")


def test_step_spacing_still_recovers_a_15_deg_offset():
    ref_pose = np.array([2.0, 2.0, 0.6])
    true = np.array([2.25, 2.15, 0.6 + np.deg2rad(15.0)])
    local = _map(ref_pose, L_ROOM)
    config = ScanMatcherConfig(hypothesis_spacing="step")
    result = match_scan(_points(true, L_ROOM, 1), local, ref_pose, _cov(0.2, 8.0), config=config)
    assert result is not None and result.hypotheses == 13  # +- 32 deg in 5 deg steps
    assert np.hypot(*(result.pose[:2] - true[:2])) < 0.03
    assert abs(wrap_angle(result.pose[2] - true[2])) < np.deg2rad(0.5)


def test_a_single_hypothesis_at_the_prior_does_not_reach_the_truth():
    """Why hypotheses: from 15 deg off a local Gauss-Newton alone ends elsewhere."""
    ref_pose = np.array([2.0, 2.0, 0.6])
    true = np.array([2.25, 2.15, 0.6 + np.deg2rad(15.0)])
    local = _map(ref_pose, L_ROOM)
    pts = _points(true, L_ROOM, 1)
    config = ScanMatcherConfig(max_distance_start=0.3)
    result = match_scan(pts, local, ref_pose, _cov(0.2, 0.0), config=config, use_prior=False)
    assert result is None or abs(wrap_angle(result.pose[2] - true[2])) > np.deg2rad(2.0)


def test_declines_in_a_featureless_corridor_unless_the_prior_fixes_the_free_direction():
    local = _map(np.array([0.0, 0.0, 0.0]), CORRIDOR)
    true = np.array([0.5, 0.05, np.deg2rad(3.0)])
    pts = _points(true, CORRIDOR, 1)
    prior = np.array([0.45, 0.0, 0.0])
    assert match_scan(pts, local, prior, _cov(0.1, 8.0), use_prior=False) is None
    # with the prior (maximum a posteriori) the scan fixes heading and lateral position,
    # the prior the position along the corridor
    result = match_scan(pts, local, prior, _cov(0.1, 8.0))
    assert result is not None
    assert abs(result.pose[1] - true[1]) < 0.02
    assert abs(wrap_angle(result.pose[2] - true[2])) < np.deg2rad(0.5)
    assert abs(result.pose[0] - prior[0]) < 0.01
    assert np.sqrt(result.cov[0, 0]) > 0.07  # along the corridor: near the prior's 0.1 m
    assert np.sqrt(result.cov[1, 1]) < 0.03


def test_declines_with_an_empty_map_and_rejects_bad_input():
    local = LocalMap(ScanMatcherConfig())
    pts = _points(np.array([2.0, 2.0, 0.0]), L_ROOM, 0)
    assert match_scan(pts, local, np.array([2.0, 2.0, 0.0]), _cov(0.1, 5.0)) is None
    local = _map(np.array([2.0, 2.0, 0.0]), L_ROOM)
    with pytest.raises(ValueError, match="points"):
        match_scan(np.zeros((5, 3)), local, np.zeros(3), _cov(0.1, 5.0))
    with pytest.raises(ValueError, match="prior_cov"):
        match_scan(pts, local, np.zeros(3), -_cov(0.1, 5.0))
    with pytest.raises(ValueError, match="prior_cov"):
        match_scan(pts, local, np.zeros(3), np.eye(2))
    # a turn on the spot: the odometry's covariance is singular, which is accepted
    singular = np.diag([0.0, 0.0, np.deg2rad(5.0) ** 2])
    assert match_scan(pts, local, np.array([2.0, 2.0, 0.05]), singular) is not None
    with pytest.raises(ValueError, match="pose"):
        match_scan(pts, local, np.zeros(2), _cov(0.1, 5.0))
    with pytest.raises(ValueError, match="keyframes"):
        ScanMatcherConfig(keyframes=0)


def test_normals_are_perpendicular_to_a_wall_and_keyframes_are_bounded():
    pts = _points(np.array([0.0, 0.0, 0.0]), CORRIDOR, 0)
    normals, valid, _ = scan_normals(pts, ScanMatcherConfig())
    assert valid.mean() > 0.7  # far beams are more than normal_max_gap apart
    assert np.all(np.abs(normals[valid, 0]) < 0.1)  # walls along x: normals along y
    local = LocalMap(ScanMatcherConfig(keyframes=2))
    for k in range(4):
        local.add(pts, np.array([0.1 * k, 0.0, 0.0]))
    assert len(local) == 2


def _chained_error(keyframes: int, seed: int) -> tuple[float, float]:
    """Final position [m] and heading [rad] error of a chain of matches (matched motion).

    The robot drives 4.5 m forward along the L room and back, twice, 0.15 m per step; each
    scan (90 beams, 3 cm range noise) is matched from the last match composed with a
    noisy odometry increment and then added to the local map at the matched pose, as
    ``prealign="odometry"`` does.
    """
    rng = np.random.default_rng(seed)
    config = replace(SlamConfig().matcher, keyframes=keyframes)
    local = LocalMap(config)
    bearings = bearings_deg(180.0, 2.0)

    def scan(pose):
        return scan_points(
            cast(pose, L_ROOM, bearings, MAX_RANGE, 0.03, rng=rng), bearings, MAX_RANGE
        )

    true = np.array([1.5, 1.5, 0.2])
    estimate = true.copy()
    local.add(scan(true), estimate)
    noise = np.diag([0.02, 0.02, 0.02]) ** 2
    for k in range(120):
        step = np.array([0.15 if (k // 30) % 2 == 0 else -0.15, 0.0, 0.0])
        true = compose(true, step)
        odometry = step + rng.multivariate_normal(np.zeros(3), noise)
        points = scan(true)
        result = match_scan(points, local, compose(estimate, odometry), noise, config)
        estimate = compose(estimate, odometry) if result is None else result.pose
        local.add(points, estimate)
    position_error = float(np.hypot(*(estimate[:2] - true[:2])))
    return position_error, abs(float(wrap_angle(estimate[2] - true[2])))


def test_a_longer_local_map_drifts_less_when_driving_back_and_forth():
    """The default's 40 keyframes reach back into the last pass; 20 hardly do."""
    assert SlamConfig().matcher.keyframes == 40
    assert SlamConfig.logs().matcher.keyframes == SlamConfig.fast().matcher.keyframes == 20
    short = np.array([_chained_error(20, seed) for seed in range(3)])
    long = np.array([_chained_error(40, seed) for seed in range(3)])
    assert np.all(long[:, 0] < short[:, 0])
    assert long[:, 0].mean() < 0.7 * short[:, 0].mean()
    assert long[:, 1].mean() < 0.7 * short[:, 1].mean()


def test_normals_match_a_per_point_fit_and_can_be_passed_to_the_map():
    config = ScanMatcherConfig(fit_keyframe_points=True)  # with the offsets
    pts = _points(np.array([1.0, 0.5, 0.3]), L_ROOM, 3)
    fit = scan_normals(pts, config)
    normals, valid, offsets = fit
    assert 0.5 < valid.mean() < 1.0
    assert np.all(normals[~valid] == 0.0) and np.all(offsets[~valid] == 0.0)
    assert np.abs(offsets[valid]).max() > 0.0
    # the same normals without the option, and no offsets
    plain = scan_normals(pts, ScanMatcherConfig())
    assert np.array_equal(plain.normals, normals) and np.array_equal(plain.valid, valid)
    assert not plain.offsets.any()
    # each valid normal is the first window (of normal_half_windows) that qualifies
    for i in np.flatnonzero(valid)[::7]:
        for w in config.normal_half_windows:
            if i < w or i >= len(pts) - w:
                continue
            patch = pts[i - w : i + w + 1]
            spread = np.linalg.eigvalsh(np.cov(patch.T, bias=True))
            near = np.hypot(*(patch - pts[i]).T).max() <= config.normal_max_radius
            wide = spread[1] >= (0.5 * config.normal_min_extent) ** 2
            if near and wide and spread[0] <= config.normal_max_flatness * spread[1]:
                _, vectors = np.linalg.eigh(np.cov(patch.T, bias=True))
                assert abs(abs(vectors[:, 0] @ normals[i]) - 1.0) < 1e-9
                # the offset is the point's from the parabola fitted to the patch in
                # the patch's line frame (u along the line, v along the normal)
                tangent = np.array([normals[i, 1], -normals[i, 0]])
                frame = np.column_stack([tangent, normals[i]])
                u, v = ((patch - patch.mean(axis=0)) @ frame).T
                parabola = np.polyfit(u, v, 2)
                assert abs(offsets[i] - (v[w] - np.polyval(parabola, u[w]))) < 1e-9
                break
    # normals computed once and passed in build the same keyframe
    a, b = LocalMap(config), LocalMap(config)
    pose = np.array([0.2, -0.1, 0.4])
    assert a.add(pts, pose) and b.add(pts, pose, fit)
    for x, y in zip(a.reference()[1:], b.reference()[1:], strict=True):
        assert np.array_equal(x, y)


def test_offsets_vanish_on_a_noise_free_arc():
    """A round obstacle's returns lie on its parabola: no offset (a line would leave one)."""
    angles = np.linspace(np.pi - 0.6, np.pi + 0.6, 40)  # radius 1 m, centre 3 m ahead
    arc = np.column_stack([3.0 + np.cos(angles), np.sin(angles)])
    fit = scan_normals(arc, ScanMatcherConfig(fit_keyframe_points=True))
    assert fit.valid.sum() > 20
    assert np.abs(fit.offsets[fit.valid]).max() < 1e-4  # sagitta share of a line: ~1 cm


def test_fitted_keyframe_points_lie_closer_to_the_wall():
    """``fit_keyframe_points``: each kept point moves onto its patch's parabola, the
    noise across the wall shrinks, and nothing else of the keyframe changes."""
    rng = np.random.default_rng(7)
    r = cast(np.zeros(3), CORRIDOR, BEARINGS, MAX_RANGE, sigma_range=0.03, rng=rng)
    pts = scan_points(r, BEARINGS, MAX_RANGE)
    raw, fitted = (
        LocalMap(ScanMatcherConfig()),
        LocalMap(ScanMatcherConfig(fit_keyframe_points=True)),
    )
    pose = np.array([0.5, 0.0, 0.0])
    assert raw.add(pts, pose) and fitted.add(pts, pose)
    raw_ref, fitted_ref = raw.reference(), fitted.reference()
    assert np.array_equal(raw_ref.normals, fitted_ref.normals)
    # the walls are y = +-1.5: distance of each kept point from its wall
    across_raw = np.abs(np.abs(raw_ref.points[:, 1]) - 1.5)
    across_fitted = np.abs(np.abs(fitted_ref.points[:, 1]) - 1.5)
    assert raw_ref.points.shape == fitted_ref.points.shape
    assert np.sqrt(np.mean(across_fitted**2)) < 0.6 * np.sqrt(np.mean(across_raw**2))
    # moved only across the wall (along its normal)
    moved = fitted_ref.points - raw_ref.points
    assert np.allclose(
        moved[:, 0] * fitted_ref.normals[:, 1], moved[:, 1] * fitted_ref.normals[:, 0]
    )
    with pytest.raises(ValueError, match="fit_keyframe_points"):
        ScanMatcherConfig(fit_keyframe_points=1)
    # the filter's configuration takes it (off in every preset)
    on = SlamConfig.from_dict({"matcher": {"fit_keyframe_points": True}})
    assert on.matcher.fit_keyframe_points and not SlamConfig().matcher.fit_keyframe_points


def test_keyframes_by_motion_and_older_keyframes_near_the_prior():
    pts = _points(np.array([0.0, 0.0, 0.0]), CORRIDOR, 0)
    local = LocalMap(ScanMatcherConfig(keyframe_distance=0.5, keyframe_heading_deg=10.0))
    added = [local.add(pts, np.array([0.1 * k, 0.0, 0.0])) for k in range(11)]
    assert added == [k % 5 == 0 for k in range(11)]  # every 0.5 m
    assert local.add(pts, np.array([1.05, 0.0, np.deg2rad(12.0)]))  # turned enough
    # revisits: 2 recent keyframes, older ones only near the asked position
    local = LocalMap(ScanMatcherConfig(keyframes=2, revisit_radius=1.0))
    for x in (0.0, 5.0, 10.0, 15.0):
        local.add(pts, np.array([x, 0.0, 0.0]))
    assert len(local) == 2 and local.stored == 4
    recent = local.reference()[1].shape[0]
    near_start = local.reference(np.array([0.3, 0.0]))[1].shape[0]
    assert near_start == recent * 3 // 2  # the same scan three times instead of twice
    assert local.reference(np.array([7.0, 0.0]))[1].shape[0] == recent
    # without revisits old keyframes are dropped
    local = LocalMap(ScanMatcherConfig(keyframes=2))
    for x in (0.0, 5.0, 10.0):
        local.add(pts, np.array([x, 0.0, 0.0]))
    assert local.stored == 2


def test_an_ambiguous_match_is_declined_or_resolved_by_the_prior():
    """A square room seen from its centre looks the same every 90 deg."""
    square = polygon_edges([np.array([[-3.0, -3.0], [3.0, -3.0], [3.0, 3.0], [-3.0, 3.0]])])
    ref_pose = np.array([0.0, 0.0, 0.0])
    local = LocalMap(ScanMatcherConfig())
    for k in range(4):  # the whole room in the map
        pose = np.array([0.0, 0.0, k * np.pi / 2])
        local.add(_points(pose, square, k), pose)
    true = np.array([0.0, 0.0, np.deg2rad(10.0)])
    pts = _points(true, square, 1)
    wide = _cov(0.05, 30.0)  # hypotheses over +-120 deg: three quarter turns are rivals
    assert match_scan(pts, local, ref_pose, wide) is None
    config = ScanMatcherConfig(on_ambiguity="prior")
    result = match_scan(pts, local, ref_pose, wide, config=config)
    assert result is not None
    assert abs(wrap_angle(result.pose[2] - true[2])) < np.deg2rad(0.5)
    with pytest.raises(ValueError, match="on_ambiguity"):
        ScanMatcherConfig(on_ambiguity="guess")


def _box(centre, half: float) -> np.ndarray:
    cx, cy = centre
    return np.array(
        [
            [cx - half, cy - half],
            [cx + half, cy - half],
            [cx + half, cy + half],
            [cx - half, cy + half],
        ]
    )


def test_selection_points_weigh_the_prior_against_a_few_more_inliers():
    """A square room whose box moved: a quarter turn explains the box, the prior does not.

    The map holds the room with a box at (0, 2); the scan sees it at (2, 0). Turned by
    90 deg the scan fits the map a little better (the box and its shadow), so the largest
    inlier fraction picks the quarter turn; counting the inliers as ``selection_points``
    observations against the prior (heading sigma 30 deg) picks the true pose.
    """
    room = np.array([[-3.0, -3.0], [3.0, -3.0], [3.0, 3.0], [-3.0, 3.0]])
    before = polygon_edges([room, _box((0.0, 2.0), 0.15)])
    after = polygon_edges([room, _box((2.0, 0.0), 0.15)])
    config = ScanMatcherConfig(on_ambiguity="prior")
    local = LocalMap(config)
    for k in range(4):
        pose = np.array([0.0, 0.0, k * np.pi / 2])
        local.add(_points(pose, before, k), pose)
    true = np.array([0.0, 0.0, np.deg2rad(10.0)])
    pts = _points(true, after, 7)
    wide = _cov(0.05, 30.0)
    plain = match_scan(pts, local, true, wide, config=config)
    assert plain is not None  # the quarter turn, by a few more inliers
    assert abs(wrap_angle(plain.pose[2] - true[2] - np.pi / 2)) < np.deg2rad(2.0)
    chosen = match_scan(pts, local, true, wide, config=replace(config, selection_points=30.0))
    assert chosen is not None
    assert abs(wrap_angle(chosen.pose[2] - true[2])) < np.deg2rad(1.0)
    assert np.hypot(*(chosen.pose[:2] - true[:2])) < 0.05
    with pytest.raises(ValueError, match="selection_points"):
        ScanMatcherConfig(selection_points=-1.0)


def _counting_residuals(monkeypatch) -> list[int]:
    """Patch the matcher's residual function to record the poses it evaluates per call."""
    import vslam_gym.slam.scan_matching as sm

    rows: list[int] = []
    original = sm._residuals

    def counting(poses, *args, **kwargs):
        rows.append(poses.shape[0])
        return original(poses, *args, **kwargs)

    monkeypatch.setattr(sm, "_residuals", counting)
    return rows


def test_pruned_hypotheses_reach_the_same_pose_with_fewer_evaluations(monkeypatch):
    ref_pose = np.array([2.0, 2.0, 0.6])
    true = np.array([2.25, 2.15, 0.6 + np.deg2rad(15.0)])
    local = _map(ref_pose, L_ROOM)
    pts = _points(true, L_ROOM, 1)
    rows = _counting_residuals(monkeypatch)
    full = match_scan(pts, local, ref_pose, _cov(0.2, 8.0))
    full_rows = sum(rows)
    rows.clear()
    config = ScanMatcherConfig(coarse_keep_after=2, coarse_keep=3, refine_keep_after=2)
    pruned = match_scan(pts, local, ref_pose, _cov(0.2, 8.0), config=config)
    assert full is not None and pruned is not None
    assert full.hypotheses == pruned.hypotheses > 5
    assert np.hypot(*(pruned.pose[:2] - full.pose[:2])) < 1e-3
    assert abs(wrap_angle(pruned.pose[2] - full.pose[2])) < np.deg2rad(0.05)
    assert np.allclose(pruned.cov, full.cov, rtol=0.05)
    # two coarse steps with all, then ranked by the third's residuals: 3 go on
    assert rows[:4] == [full.hypotheses] * 3 + [3]
    assert sum(rows) < 0.6 * full_rows


def test_refinement_keeps_the_rivals_of_an_ambiguous_match():
    """Quarter turns of a square room have as many inliers: none is dropped early."""
    square = polygon_edges([np.array([[-3.0, -3.0], [3.0, -3.0], [3.0, 3.0], [-3.0, 3.0]])])
    local = LocalMap(ScanMatcherConfig())
    for k in range(4):
        pose = np.array([0.0, 0.0, k * np.pi / 2])
        local.add(_points(pose, square, k), pose)
    pts = _points(np.array([0.0, 0.0, np.deg2rad(10.0)]), square, 1)
    config = ScanMatcherConfig(coarse_keep_after=2, refine_keep_after=1, refine_keep_ratio=0.8)
    assert match_scan(pts, local, np.zeros(3), _cov(0.05, 30.0), config=config) is None


def test_the_reference_table_is_normals_points_and_a_zero_sentinel():
    local = _map(np.array([2.0, 2.0, 0.3]), L_ROOM)
    ref = local.reference()
    n = ref.tree.n
    assert n > 50 and ref.table.shape == (n + 1, 4)
    assert np.array_equal(ref.table[:n, 2:], ref.tree.data)  # the tree's points
    np.testing.assert_allclose(np.hypot(*ref.table[:n, :2].T), 1.0)  # unit normals
    assert np.array_equal(ref.points, ref.tree.data) and ref.normals.shape == (n, 2)
    assert not ref.table[n].any()


@pytest.mark.parametrize(
    ("name", "value"),
    [("coarse_keep_after", 1.5), ("coarse_keep_after", -1), ("refine_keep_after", True),
     ("coarse_keep", 0), ("refine_keep_ratio", 1.5)],
)  # fmt: skip
def test_pruning_options_are_validated(name, value):
    with pytest.raises(ValueError, match=name):
        ScanMatcherConfig(**{name: value})


THIN_WALL_ROOM = polygon_edges(  # a 10 m room across which runs a 3 cm thick wall
    [
        np.array([[0.0, 0.0], [10.0, 0.0], [10.0, 10.0], [0.0, 10.0]]),
        np.array([[2.0, 5.0], [8.0, 5.0], [8.0, 5.03], [2.0, 5.03]]),
    ]
)


def _both_faces(config: ScanMatcherConfig) -> LocalMap:
    """Keyframes of the thin wall from below (its face at y = 5) and from above (5.03)."""
    local = LocalMap(config)
    for pose, seed in (((5.0, 2.5, np.pi / 2), 0), ((5.0, 7.5, -np.pi / 2), 1)):
        local.add(_points(pose, THIN_WALL_ROOM, seed), np.asarray(pose))
    return local


def test_normals_face_the_lidar():
    """(Their offsets turn with them: see the fitted keyframe points' test.)"""
    pts = _points((2.0, 2.0, 0.6), L_ROOM, 3)
    fit = scan_normals(pts, ScanMatcherConfig(fit_keyframe_points=True))
    assert fit.valid.sum() > 150
    facing = np.einsum("ij,ij->i", pts[fit.valid], fit.normals[fit.valid])
    assert np.all(facing < 0.0)  # every normal points from its wall back to the lidar
    assert np.all(fit.normals[~fit.valid] == 0.0)


def test_normal_agreement_keeps_a_scan_off_the_far_face_of_a_thin_wall():
    """Seen from below, with the prior 2.5 cm toward the far face, the far face's points are
    the nearest neighbours of the wall's returns: only their normals tell them apart."""
    true = np.array([5.3, 2.7, np.pi / 2 + 0.05])
    prior = true + np.array([0.0, 0.025, 0.0])
    cov = np.diag([0.03**2, 0.03**2, 0.01**2])
    errors = {}
    for angle in (0.0, 30.0):
        config = ScanMatcherConfig(normal_agreement_deg=angle)
        local = _both_faces(config)
        # map normals face their keyframe's lidar: the far face's point up (+y)
        reference = local.reference()
        far = (np.abs(reference.points[:, 1] - 5.03) < 0.05) & (reference.normals[:, 1] > 0.9)
        assert far.sum() > 50
        points = _points(true, THIN_WALL_ROOM, 2)
        check = _NormalAgreement.of(points, None, config)
        res = _residuals(prior[None, :], points, reference, 0.3, check)
        c, s = np.cos(prior[2]), np.sin(prior[2])
        world_y = prior[1] + s * points[:, 0] + c * points[:, 1]
        on_wall = np.abs(world_y - 5.0) < 0.1  # the thin wall's returns
        on_far = on_wall & res.matched[0] & (res.normals[0][:, 1] > 0.9)
        if angle == 0.0:
            assert check is None and on_far.sum() > 20  # the wall's returns pair with it
        else:
            assert on_far.sum() == 0
            assert np.all(res.system[0][~res.matched[0]] == 0.0)  # dropped rows are zero
        err = []
        for seed in range(10, 20):
            result = match_scan(_points(true, THIN_WALL_ROOM, seed), local, prior, cov, config)
            assert result is not None
            err.append(result.pose - true)
        errors[angle] = np.abs(np.array(err)).mean(axis=0)
    # mean |error| over ten scans: y 21 -> 3.5 mm (without the test the scan settles
    # on the far face), heading 0.9 -> 0.4 mrad
    assert errors[0.0][1] > 0.015
    assert errors[30.0][1] < 0.25 * errors[0.0][1]
    assert errors[30.0][2] < 0.7 * errors[0.0][2]


@pytest.mark.parametrize("value", [-1.0, 91.0, float("nan")])
def test_normal_agreement_is_validated(value):
    with pytest.raises(ValueError, match="normal_agreement_deg"):
        ScanMatcherConfig(normal_agreement_deg=value)
