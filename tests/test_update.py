"""Landmark model update at a known pose (SPEC section 9, thesis 3.2.62-3.2.95)."""

from __future__ import annotations

import numpy as np
import pytest
from _raycast import bearings_deg, cast, polygon_edges

import vslam_gym.slam.update as update_module
from vslam_gym.slam.config import ModelConfig, SensorConfig
from vslam_gym.slam.creation import create_model
from vslam_gym.slam.gaussian import is_spd
from vslam_gym.slam.landmark import LandmarkModel
from vslam_gym.slam.scan import Scan
from vslam_gym.slam.update import (
    InterleavedError,
    NewLine,
    ObservedLines,
    infer_object_vertices,
    observation_conditional,
    observed_vertices,
    placement_matrix,
    selection_matrix,
    update_model,
    wrap_model,
)

SENSOR = SensorConfig()
PHI = bearings_deg()
CFG = ModelConfig()
# The box of the worked example (notes 4.10), corners counter-clockwise.
BOX = np.array([(4.0, 1.0), (4.0, -1.0), (6.0, -1.0), (6.0, 1.0)])
BOX_EDGES = polygon_edges([BOX])
P1 = np.array([1.0, -4.0, np.deg2rad(45.0)])  # sees the west and south faces
P2 = np.array([10.0, -4.0, np.deg2rad(140.0)])  # sees the south and east faces


def star(n_points: int, r_out: float, r_in: float, centre=(5.0, 5.0)) -> np.ndarray:
    """A star polygon with ``n_points`` tips (counter-clockwise vertices)."""
    angle = np.arange(2 * n_points) * np.pi / n_points
    radius = np.where(np.arange(2 * n_points) % 2 == 0, r_out, r_in)
    return np.asarray(centre) + radius[:, None] * np.stack([np.cos(angle), np.sin(angle)], 1)


# Four tips, 2.6 m across, inner corners 0.22 m inside the hull: non-convex, 8 corners.
STAR = star(4, 1.3, 0.7)


def scan_at(pose, edges, rng=None) -> Scan:
    if rng is None:
        return Scan.from_arrays(cast(pose, edges, PHI, SENSOR.max_range), PHI, SENSOR)
    r = cast(pose, edges, PHI, SENSOR.max_range, SENSOR.sigma_range, SENSOR.sigma_bearing, rng)
    return Scan.from_arrays(r, PHI, SENSOR)


def segment(scan: Scan) -> tuple[int, int]:
    idx = np.flatnonzero(scan.returns)
    assert np.all(np.diff(idx) == 1), "test scenes must give one contiguous segment"
    return int(idx[0]), int(idx[-1])


def longest_segment(scan: Scan) -> tuple[int, int]:
    """The longest run of consecutive beams with returns (a grazing beam can miss)."""
    idx = np.flatnonzero(scan.returns)
    runs = np.split(idx, np.flatnonzero(np.diff(idx) > 1) + 1)
    best = max(runs, key=len)
    return int(best[0]), int(best[-1])


def look_at(position, target) -> np.ndarray:
    d = np.asarray(target, dtype=float) - np.asarray(position, dtype=float)
    return np.array([position[0], position[1], np.arctan2(d[1], d[0])])


def corner_mahalanobis(model: LandmarkModel, vertices, corners: np.ndarray) -> np.ndarray:
    """Mahalanobis distance of each vertex to its nearest true corner."""
    out = []
    for i in vertices:
        e = model.mean[i] - corners[np.argmin(np.linalg.norm(corners - model.mean[i], axis=1))]
        out.append(np.sqrt(e @ np.linalg.solve(model.vertex_cov(i), e)))
    return np.array(out)


def corrected_creation(scan: Scan, pose: np.ndarray, config: ModelConfig):
    """``create_model`` with the end-vertex correction applied to its two end vertices.

    Creation puts the end vertices on the rays of the segment's edge beams with
    measurement-level variance, biased by up to a beam spacing (notes R-5); this applies
    the update's correction to them, to test the update from a consistent prior.
    """
    first, last = segment(scan)
    fit = create_model(scan, first, last, pose, SENSOR, config)
    a, b = fit.object_vertices
    idx = np.arange(2 * a, 2 * b)
    mu, cov, _ = update_module._end_quantization(
        fit.model.mean[a:b].reshape(-1),
        fit.model.cov[np.ix_(idx, idx)],
        np.ones(b - a, dtype=bool),
        (False, False),
        [None, None],
        scan,
        first,
        last,
        pose,
        SENSOR,
    )
    mean, full = fit.model.mean.copy(), fit.model.cov.copy()
    mean[a:b] = mu.reshape(-1, 2)
    full[np.ix_(idx, idx)] = cov
    return LandmarkModel(mean, full, fit.model.u), fit.object_vertices


# ------------------------------------------------------------------ F, G, vartheta


def test_placement_and_selection_match_the_thesis_example():
    """Thesis 3.2.75-3.2.77: zeta = (0), (1), (1, 1), (1), (1), (0) over 7 old vertices."""
    zeta = ((0,), (1,), (1, 1), (1,), (1,), (0,))
    lines = []
    for i, z in enumerate(zeta):
        for j, flag in enumerate(z):
            beams = np.arange(2) if flag else np.zeros(0, dtype=int)
            lines.append(NewLine(i, j, bool(flag), beams, (0, 1) if flag else (-1, -1)))
    obs = ObservedLines(zeta, tuple(lines), np.array([len(z) == 1 and z[0] == 1 for z in zeta]))
    k_new = len(lines) + 1
    K_obs = np.zeros((2 * k_new, 2 * k_new))
    K_obs[2:14, 2:14] = np.eye(12)
    u = np.array([1.0, 0.0, 0.9, 0.1, 0.2, 1.0])
    vartheta, u_prime, old_of = observed_vertices(obs, K_obs, u)
    np.testing.assert_array_equal(vartheta, [0, 1, 1, 2, 1, 1, 1, 0])
    np.testing.assert_array_equal(old_of, [0, 1, 2, -1, 3, 4, 5, 6])
    # The replaced line 2 becomes two new lines with u' = 1; the others keep theirs.
    np.testing.assert_array_equal(u_prime, [1.0, 0.0, 1.0, 1.0, 0.1, 0.2, 1.0])
    F = placement_matrix(old_of, 7)
    assert F.shape == (14, 16)
    for old, new in [(0, 0), (1, 1), (2, 2), (3, 4), (4, 5), (5, 6), (6, 7)]:
        np.testing.assert_array_equal(F[2 * old : 2 * old + 2, 2 * new : 2 * new + 2], np.eye(2))
    assert F.sum() == 14 and not F[:, 6:8].any()  # the new vertex 3 has no prior
    G = selection_matrix(vartheta)
    assert G.shape == (12, 16)
    np.testing.assert_array_equal(G @ np.arange(16), np.arange(2, 14))


def test_observation_conditional_form_is_spec_corrected():
    """``A_vx = G^T A'``, ``b_vx = G^T (mu' - A' x)``: zero rows for unobserved vertices."""
    rng = np.random.default_rng(0)
    k = 4
    mu = rng.normal(size=2 * k)
    root = rng.normal(size=(2 * k, 2 * k))
    K = root @ root.T + np.eye(2 * k)
    K[:2, :] = 0.0
    K[:, :2] = 0.0  # vertex 0 unobserved
    h = K @ mu
    vartheta = np.array([0, 1, 1, 2])
    pose = np.array([0.5, -1.0, 0.3])
    A, b = observation_conditional(K, h, selection_matrix(vartheta), pose)
    assert A.shape == (2 * k, 3) and b.shape == (2 * k,)
    assert not A[:2].any() and not b[:2].any()
    np.testing.assert_allclose(A[2:] @ pose + b[2:], mu[2:], atol=1e-9)
    v = mu[4:6]
    np.testing.assert_allclose(A[4:6], [[1, 0, -(v[1] - pose[1])], [0, 1, v[0] - pose[0]]])


def test_wrap_folds_information_and_closes():
    """3.2.95: independent first/last object vertices fold into their information sum."""
    corners = np.array([(0.0, 0.0), (2.0, 0.0), (2.0, 2.0), (0.0, 2.0), (0.01, -0.01)])
    mean = np.vstack([[(-5.0, -5.0)], corners, [(5.0, -5.0)]])
    variances = [1.0, 0.01, 0.02, 0.02, 0.02, 0.03, 1.0]
    cov = np.diag(np.repeat(np.square(variances), 2))
    model = LandmarkModel(mean, cov, [1.0, 0.0, 0.1, 0.0, 0.2, 1.0])
    assert infer_object_vertices(model) == (1, 6)
    result = wrap_model(model, (1, 6), CFG)
    assert result.wrapped and result.model.closed
    assert result.model.n_vertices == 4 and result.model.n_lines == 4
    np.testing.assert_array_equal(result.model.u, [0.0, 0.1, 0.0, 0.2])
    w = 1 / np.array([0.01, 0.03]) ** 2
    expected = (w[0] * corners[0] + w[1] * corners[4]) / w.sum()
    np.testing.assert_allclose(result.model.mean[0], expected, atol=1e-12)
    np.testing.assert_allclose(result.model.vertex_cov(0), np.eye(2) / w.sum(), rtol=1e-9)
    assert is_spd(result.model.cov)
    # Far apart (in standard deviations): no wrap.
    moved = LandmarkModel(mean + np.where(np.arange(7)[:, None] == 5, 0.5, 0.0), cov, model.u)
    assert not wrap_model(moved, (1, 6), CFG).wrapped


# ------------------------------------------------------------------- update scenes


def test_worked_example_box_extended_by_a_third_side():
    """notes 4.10: the L-shaped model of a box is extended by its east face.

    Noiseless, thesis preset (first order): same encodings and vertices as worked out by
    hand, including Algorithm 7's crossing of the two unknown chains north of the box.
    """
    cfg = ModelConfig.thesis(linearization="jacobian")
    s1 = scan_at(P1, BOX_EDGES)
    fit = create_model(s1, *segment(s1), P1, SENSOR, cfg)
    np.testing.assert_array_equal(fit.model.u, [1, 1, 0, 0, 1, 1])
    s2 = scan_at(P2, BOX_EDGES)
    up = update_model(fit.model, s2, *segment(s2), P2, SENSOR, cfg)
    assert up.zeta == ((0,), (0,), (0,), (1,), (1, 0), (0,))
    np.testing.assert_array_equal(up.vartheta, [0, 0, 0, 1, 1, 2, 0, 0])
    np.testing.assert_array_equal(up.old_of, [0, 1, 2, 3, 4, -1, 5, 6])
    np.testing.assert_array_equal(up.posterior.u, [1, 1, 0, 0, 0, 1, 1])
    assert up.F.shape == (14, 16) and up.G.shape == (6, 16)
    np.testing.assert_allclose(up.posterior.mean[5], (6.0, 0.94), atol=0.01)  # D'
    # Final: [X_l, A, B, C, D', X_r], the chains ending where they cross.
    assert up.unknown.crossed and not up.wrapped
    assert up.model.n_vertices == 6 and up.object_vertices == (1, 5)
    np.testing.assert_array_equal(up.model.u, [1, 0, 0, 0, 1])
    np.testing.assert_allclose(up.model.mean[0], up.model.mean[-1])
    np.testing.assert_allclose(up.model.mean[0], (4.85, 2.48), atol=0.05)
    np.testing.assert_allclose(up.model.mean[1:5], [(4, 1), (4, -1), (6, -1), (6, 0.94)], atol=0.01)
    # The conditional form reproduces the observed vertices at the pose.
    rows = np.flatnonzero(np.repeat(up.vartheta > 0, 2))
    mu_obs = np.linalg.solve(up.G @ up.K_obs @ up.G.T, up.G @ up.h_obs)
    np.testing.assert_allclose((up.A_vx @ P2 + up.b_vx)[rows], mu_obs, atol=1e-9)


@pytest.mark.parametrize("linearization", ["jacobian", "ut"])
def test_new_side_is_added_at_the_right_place(linearization):
    """The east face extends the model: its far corner D within 3 sigma of (6, 1).

    The near corner C was created as an end vertex on a beam's ray, biased along the
    south face by up to a beam spacing with measurement-level variance (notes R-5): from
    the plain creation the east face fails the termination test at C in about 16 of 40
    scans and a second vertex is added next to C (1 of 40 from a creation with the
    end-vertex correction, below).
    """
    cfg = ModelConfig(linearization=linearization)
    hits, single, trials = 0, 0, 10
    for seed in range(trials):
        for corrected in (False, True):
            rng = np.random.default_rng(seed)
            s1 = scan_at(P1, BOX_EDGES, rng)
            if corrected:
                model, ov = corrected_creation(s1, P1, cfg)
            else:
                fit = create_model(s1, *segment(s1), P1, SENSOR, cfg)
                model, ov = fit.model, fit.object_vertices
            s2 = scan_at(P2, BOX_EDGES, rng)
            up = update_model(model, s2, *segment(s2), P2, SENSOR, cfg, object_vertices=ov)
            assert is_spd(up.model.cov) and is_spd(up.posterior.cov)
            new = np.flatnonzero(up.vartheta == 2)
            assert 1 <= new.size <= 2
            # D is the new vertex of the east face's far end; the chains cut at their
            # crossing north of the box.
            d = corner_mahalanobis(up.posterior, new[-1:], BOX[3:])
            assert np.linalg.norm(up.posterior.mean[new[-1]] - BOX[3]) < 0.1
            assert up.unknown.crossed and up.model.n_vertices == up.posterior.n_vertices - 2
            if corrected:
                hits += d[0] <= 3.0
                single += new.size == 1
    assert hits >= 0.9 * trials
    assert single == trials


def test_reobserving_shrinks_covariance_and_keeps_vertices_near_truth():
    """Re-observing the west and south faces from 0.5 m away (20 seeded scans).

    Every object vertex's covariance shrinks (determinant and trace). The corner seen as
    the intersection of two faces stays within 3 sigma. The two end vertices inherit the
    creation's beam-spacing bias: from a creation with the end-vertex correction applied
    they stay within 3 sigma too (measured: 0.98 and 0.95 of 40 seeds; from the plain
    creation 0.70 and 0.55, mean NEES 11 and 12 instead of 2).
    """
    p_near = np.array([1.4, -4.3, np.deg2rad(47.0)])
    shrink, corner, ends, n = 0, 0, 0, 20
    for seed in range(n):
        for corrected in (False, True):
            rng = np.random.default_rng(seed)
            s1 = scan_at(P1, BOX_EDGES, rng)
            if corrected:
                model, ov = corrected_creation(s1, P1, CFG)
            else:
                fit = create_model(s1, *segment(s1), P1, SENSOR, CFG)
                model, ov = fit.model, fit.object_vertices
            s2 = scan_at(p_near, BOX_EDGES, rng)
            up = update_model(model, s2, *segment(s2), p_near, SENSOR, CFG, object_vertices=ov)
            assert up.zeta == ((0,), (0,), (1,), (1,), (0,), (0,))
            assert up.model.n_vertices == model.n_vertices and is_spd(up.model.cov)
            new = [int(np.flatnonzero(up.old_of == i)[0]) for i in range(*ov)]
            for old, i in zip(range(*ov), new, strict=True):
                before, after = model.vertex_cov(old), up.posterior.vertex_cov(i)
                shrink += np.linalg.det(after) < np.linalg.det(before)
                shrink += np.trace(after) < np.trace(before)
            d = corner_mahalanobis(up.posterior, new, BOX[:3])
            if not corrected:
                corner += d[1] <= 3.0
            else:
                ends += int(np.sum(d[[0, 2]] <= 3.0))
    assert shrink == 2 * 3 * 2 * n
    assert corner >= 0.9 * n
    assert ends >= 0.85 * 2 * n


def circle_star(n_poses: int, seed: int, config: ModelConfig, turns: float = 1.25):
    """Create at the first of ``n_poses`` poses on a circle (radius 4 m) around the star,
    then update at every further pose, counter-clockwise, ``turns`` times around."""
    rng = np.random.default_rng(seed)
    edges = polygon_edges([STAR])
    centre = STAR.mean(axis=0)
    angles = -np.pi / 2 + np.arange(int(n_poses * turns) + 1) * 2 * np.pi / n_poses
    poses = [look_at(centre + 4.0 * np.array([np.cos(a), np.sin(a)]), centre) for a in angles]
    s0 = scan_at(poses[0], edges, rng)
    fit = create_model(s0, *longest_segment(s0), poses[0], SENSOR, config)
    model, ov = fit.model, fit.object_vertices
    wrapped_at = None
    for t, pose in enumerate(poses[1:], 1):
        scan = scan_at(pose, edges, rng)
        first, last = longest_segment(scan)
        up = update_model(model, scan, first, last, pose, SENSOR, config, object_vertices=ov)
        assert is_spd(up.model.cov) and is_spd(up.posterior.cov)
        assert np.allclose(up.model.cov, up.model.cov.T)
        # F places the input's vertices (in its own order, also when closed and rotated).
        placed = (up.F.T @ model.mean.reshape(-1)).reshape(-1, 2)
        kept = up.old_of >= 0
        np.testing.assert_array_equal(placed[kept], model.mean[up.old_of[kept]])
        assert not placed[~kept].any()
        if up.wrapped:
            assert wrapped_at is None
            wrapped_at = t
        model, ov = up.model, up.object_vertices
    return model, ov, wrapped_at


@pytest.mark.parametrize(
    "n_poses, min_closed, min_fraction, max_worst",
    [(24, 6, 0.7, 10.0), (30, 5, 0.7, 10.0), (36, 6, 0.9, 5.0)],
)
def test_circling_a_star_wraps_into_a_closed_polygon(n_poses, min_closed, min_fraction, max_worst):
    """Circle the 8-corner star 1.25 times (6 seeds), updating at every pose.

    The polygon wraps within the first turn and the closed model keeps updating. Measured
    (fraction of vertices within 3 sigma of the nearest true corner, worst Mahalanobis
    distance, runs closed): 24 poses per turn 0.77, 6.8, 6 of 6; 30 poses 0.78, 5.4,
    5 of 6; 36 poses 0.98, 3.2, 6 of 6. The run that stays open ends with two estimates
    of the first corner 5 sigma apart: the created one is biased by the creation's
    end-vertex bias (notes R-5); with the creation corrected all 6 close.
    """
    distances, closed = [], 0
    for seed in range(6):
        model, ov, wrapped_at = circle_star(n_poses, seed, CFG)
        assert 8 <= ov[1] - ov[0] <= 10
        if model.closed:
            closed += 1
            assert wrapped_at is not None and wrapped_at <= n_poses
            assert ov == (0, model.n_vertices)
        distances.append(corner_mahalanobis(model, range(*ov), STAR))
    d = np.concatenate(distances)
    assert closed >= min_closed
    assert np.mean(d <= 3.0) >= min_fraction
    assert d.max() <= max_worst


# ----------------------------------------------------------- failures and presets


def test_failed_update_leaves_the_model_unchanged(monkeypatch):
    s1 = scan_at(P1, BOX_EDGES, np.random.default_rng(1))
    fit = create_model(s1, *segment(s1), P1, SENSOR, CFG)
    model = fit.model
    saved = (model.mean.copy(), model.cov.copy(), model.u.copy(), model.closed)
    s2 = scan_at(P2, BOX_EDGES, np.random.default_rng(2))
    first, last = segment(s2)

    def fail(*args, **kwargs):
        raise RuntimeError("late failure")

    monkeypatch.setattr(update_module, "wrap_model", fail)
    with pytest.raises(RuntimeError, match="late failure"):
        update_model(model, s2, first, last, P2, SENSOR, CFG)
    monkeypatch.undo()
    with pytest.raises(ValueError, match="association has"):
        update_model(model, s2, first, last, P2, SENSOR, CFG, association=np.zeros(3, int))
    with pytest.raises(ValueError, match="line indices must lie"):
        update_model(
            model, s2, first, last, P2, SENSOR, CFG, association=np.full(last - first + 1, 9)
        )
    with pytest.raises(ValueError, match="no-return"):
        update_model(model, s2, first - 3, last, P2, SENSOR, CFG)
    np.testing.assert_array_equal(model.mean, saved[0])
    np.testing.assert_array_equal(model.cov, saved[1])
    np.testing.assert_array_equal(model.u, saved[2])
    assert model.closed == saved[3]
    up = update_model(model, s2, first, last, P2, SENSOR, CFG)
    assert up.model.n_vertices == 6


def test_interleaved_association_is_made_monotone():
    """Object lines 2 and 3 given interleaved beams (no split leaves both two beams): the
    plain pass fails, the retry with the association in line order drops line 2."""
    s1 = scan_at(P1, BOX_EDGES, np.random.default_rng(1))
    fit = create_model(s1, *segment(s1), P1, SENSOR, CFG)
    s2 = scan_at(P2, BOX_EDGES, np.random.default_rng(2))
    first, last = segment(s2)
    given = update_model(fit.model, s2, first, last, P2, SENSOR, CFG).association
    bad = given.copy()
    bad[:4] = [2, 3, 3, 2]
    with pytest.raises(InterleavedError):
        update_module.observed_parameters(
            update_module.observed_lines(
                fit.model, bad, first, s2, P2, SENSOR, CFG, update_module.make_linearization(CFG)
            ),
            s2,
            P2,
            SENSOR,
            CFG,
            update_module.make_linearization(CFG),
        )
    up = update_model(fit.model, s2, first, last, P2, SENSOR, CFG, association=bad)
    assert not up.observed_lines[2] and up.observed_lines[3]
    np.testing.assert_array_equal(up.association[:4], [2, 3, 3, 3])  # line 2: 1 beam
    assert is_spd(up.model.cov)


def test_thesis_preset_updates_with_the_unscented_transform():
    """``ModelConfig.thesis()`` (UT, no corrections) on the re-observation case."""
    cfg = ModelConfig.thesis()
    rng = np.random.default_rng(3)
    s1 = scan_at(P1, BOX_EDGES, rng)
    fit = create_model(s1, *segment(s1), P1, SENSOR, cfg)
    p_near = np.array([1.4, -4.3, np.deg2rad(47.0)])
    s2 = scan_at(p_near, BOX_EDGES, rng)
    up = update_model(fit.model, s2, *segment(s2), p_near, SENSOR, cfg)
    assert up.zeta == ((0,), (0,), (1,), (1,), (0,), (0,))
    assert is_spd(up.model.cov)
    for i in range(*fit.object_vertices):
        assert np.linalg.det(up.posterior.vertex_cov(i)) < np.linalg.det(fit.model.vertex_cov(i))
    d = corner_mahalanobis(up.posterior, [3], BOX[1:2])
    assert d[0] <= 3.0


def test_unfinished_update_gives_the_filter_the_same_factor():
    """``finish=False`` (the SLAM filter) skips Algorithm 7 and wrapping only."""
    cfg = ModelConfig.thesis(linearization="jacobian")
    s1 = scan_at(P1, BOX_EDGES)
    fit = create_model(s1, *segment(s1), P1, SENSOR, cfg)
    s2 = scan_at(P2, BOX_EDGES)
    full = update_model(fit.model, s2, *segment(s2), P2, SENSOR, cfg)
    quick = update_model(fit.model, s2, *segment(s2), P2, SENSOR, cfg, finish=False)
    for name in ("F", "K_obs", "h_obs", "G", "A_vx", "b_vx", "vartheta", "old_of"):
        np.testing.assert_array_equal(getattr(quick, name), getattr(full, name))
    np.testing.assert_array_equal(quick.posterior.mean, full.posterior.mean)
    np.testing.assert_array_equal(quick.posterior.u, full.posterior.u)
    assert quick.chains == full.chains
    assert quick.unknown is None and quick.wrap is None and quick.model is quick.posterior
    # the object part spans the posterior's object lines: [X_l, A, B, C, D', X_r] less
    # the chain vertices, here A..D' (u = [1, 1, 0, 0, 0, 1, 1])
    assert quick.object_vertices == (2, 6)


# ----------------------------------------------------------------- run ends that continue


def wall_scan(edges, heading: float = np.pi / 2) -> tuple[Scan, np.ndarray]:
    pose = np.array([0.0, 0.0, heading])
    return Scan.from_arrays(cast(pose, edges, PHI, SENSOR.max_range), PHI, SENSOR), pose


def run_vertices_on_wall(scan: Scan, pose: np.ndarray, s: int, e: int) -> np.ndarray:
    """The points of beams ``s`` and ``e`` (on the wall) as a run's end vertices."""
    a = pose[2] + scan.bearings[[s, e]]
    r = scan.ranges[[s, e]]
    return np.column_stack([r * np.cos(a), r * np.sin(a)])


def test_a_run_end_continued_by_the_next_beam_is_not_an_end():
    cfg = ModelConfig(continuation_gate=3.0, continuation_beams=2)
    long_wall = polygon_edges([np.array([(10.0, 5.0), (-10.0, 5.0), (-10.0, 6.0), (10.0, 6.0)])])
    scan, pose = wall_scan(long_wall)
    s, e = 80, 100  # the middle of the wall: the beams on both sides hit the wall too
    v = run_vertices_on_wall(scan, pose, s, e)
    assert update_module._continues(v, scan, s, e, pose, SENSOR, cfg) == (True, True)
    # the same beam 4 range sigmas off the extension (an edge of another surface): an end
    ranges = scan.ranges.copy()
    ranges[s - 1] += 4.0 * SENSOR.sigma_range
    moved = Scan.from_arrays(ranges, PHI, SENSOR)
    assert update_module._continues(v, moved, s, e, pose, SENSOR, cfg) == (False, True)
    # a shallow corner: the first beam out still near the extension, the second not
    ranges = scan.ranges.copy()
    ranges[e + 2] += 4.0 * SENSOR.sigma_range
    bent = Scan.from_arrays(ranges, PHI, SENSOR)
    assert update_module._continues(v, bent, s, e, pose, SENSOR, cfg) == (True, False)
    one = ModelConfig(continuation_gate=3.0, continuation_beams=1)
    assert update_module._continues(v, bent, s, e, pose, SENSOR, one) == (True, True)
    # at the field-of-view limit the beams that exist decide (turned so that beam 0,
    # the leftmost, hits the wall 9 m to the left)
    scan, pose = wall_scan(long_wall, np.pi / 2 - 0.5)
    assert scan.returns[0]
    v = run_vertices_on_wall(scan, pose, 1, 20)
    assert update_module._continues(v, scan, 1, 20, pose, SENSOR, cfg) == (True, True)
    # the wall's real ends: no return beyond either
    short = polygon_edges([np.array([(2.0, 5.0), (-2.0, 5.0), (-2.0, 6.0), (2.0, 6.0)])])
    scan, pose = wall_scan(short)
    hits = np.flatnonzero(scan.returns)
    s, e = int(hits[0]), int(hits[-1])
    v = run_vertices_on_wall(scan, pose, s, e)
    assert update_module._continues(v, scan, s, e, pose, SENSOR, cfg) == (False, False)
    with pytest.raises(ValueError, match="continuation_gate"):
        ModelConfig(continuation_gate=-1.0)
    with pytest.raises(ValueError, match="continuation_beams"):
        ModelConfig(continuation_beams=0)
