import argparse
import dataclasses
import json
import math

import numpy as np
import pytest

from vslam_gym.evaluation import (
    NEES_PARTS,
    START_SCAN_MODES,
    TIMING_KEYS,
    DecisionRecord,
    SeedsError,
    add_evaluate_parser,
    association_precision,
    check_range_perturbation,
    chi2_interval,
    cmd_evaluate,
    compound_precision,
    creation_causes,
    duplicate_fraction,
    episode_metrics,
    evaluate,
    final_position_error,
    format_table,
    heading_rmse,
    landmark_majority_ids,
    loop_match_nees,
    loop_match_summary,
    majority_id,
    mean_metrics,
    mean_nees_interval,
    name_or_mapping,
    nees_summary,
    odometry_covariances,
    parse_seeds,
    pose_nees,
    position_ate_rmse,
    run_episode,
    sem_metrics,
    set_obstacles,
    write_tum,
    yaw_quaternion,
)
from vslam_gym.sim.world_file import load_world, world_to_toml
from vslam_gym.slam.filter import Belief, SlamConfig

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
REQUIRED_KEYS = {
    "ate_rmse_m",
    "odom_ate_rmse_m",
    "heading_rmse_rad",
    "final_error_m",
    "nees_mean",
    "nees_in_band_fraction",
    "association_precision",
    "duplicate_fraction",
    "landmarks",
    "step_ms_median",
    "step_ms_p95",
    "steps",
    "world",
    "preset",
}


# ---------------------------------------------------------------------- trajectory errors


def test_ate_of_a_constant_offset_is_the_offset_length():
    rng = np.random.default_rng(0)
    true = np.column_stack([rng.uniform(-5, 5, (50, 2)), rng.uniform(-3, 3, 50)])
    est = true + np.array([0.3, -0.4, 0.0])
    assert position_ate_rmse(est, true) == pytest.approx(0.5, abs=1e-12)
    assert final_position_error(est, true) == pytest.approx(0.5, abs=1e-12)
    assert heading_rmse(est, true) == pytest.approx(0.0, abs=1e-12)


def test_ate_is_a_root_mean_square_not_a_mean():
    true = np.zeros((2, 3))
    est = np.array([[0.0, 0.0, 0.0], [2.0, 0.0, 0.0]])
    assert position_ate_rmse(est, true) == pytest.approx(math.sqrt(2.0))
    assert final_position_error(est, true) == pytest.approx(2.0)


def test_heading_rmse_wraps_across_pi():
    true = np.array([[0.0, 0.0, math.pi - 0.05], [0.0, 0.0, 0.0]])
    est = np.array([[0.0, 0.0, -math.pi + 0.05], [0.0, 0.0, 0.2 + 4 * math.pi]])
    assert heading_rmse(est, true) == pytest.approx(math.sqrt((0.1**2 + 0.2**2) / 2))


def test_trajectory_errors_reject_mismatched_shapes():
    with pytest.raises(ValueError, match="poses"):
        position_ate_rmse(np.zeros((3, 3)), np.zeros((4, 3)))
    with pytest.raises(ValueError, match="shape"):
        heading_rmse(np.zeros((3, 2)), np.zeros((3, 2)))


# ---------------------------------------------------------------------- NEES


def test_nees_of_a_known_case_with_a_wrapped_heading():
    cov = np.diag([4.0, 1.0, 0.01])
    true = np.array([[2.0, 1.0, math.pi - 0.05]])
    est = np.array([[0.0, 0.0, -math.pi + 0.05]])  # heading error -0.1 across pi
    # (2^2/4) + (1^2/1) + (0.1^2/0.01) = 3
    assert pose_nees(est, cov[None], true) == pytest.approx([3.0])


def test_nees_uses_the_correlations():
    cov = np.array([[1.0, 0.9, 0.0], [0.9, 1.0, 0.0], [0.0, 0.0, 1.0]])
    e = np.array([1.0, -1.0, 0.0])  # along the small-variance direction (1 - 0.9)
    nees = pose_nees(np.zeros((1, 3)), cov[None], e[None])
    assert nees[0] == pytest.approx(e @ np.linalg.solve(cov, e))
    assert nees[0] == pytest.approx(20.0)


def test_nees_parts_use_their_block_of_the_covariance():
    rng = np.random.default_rng(0)
    a = rng.normal(size=(4, 3, 3))
    covs = a @ a.transpose(0, 2, 1) + 0.1 * np.eye(3)
    true = rng.normal(size=(4, 3))
    est = np.zeros((4, 3))
    position = pose_nees(est, covs, true, NEES_PARTS["position"])
    heading = pose_nees(est, covs, true, NEES_PARTS["heading"])
    for t in range(4):
        e = true[t, :2]
        assert position[t] == pytest.approx(e @ np.linalg.solve(covs[t][:2, :2], e))
        assert heading[t] == pytest.approx(true[t, 2] ** 2 / covs[t][2, 2])
    # a marginal's NEES is never above the whole pose's
    assert np.all(pose_nees(est, covs, true) >= position - 1e-12)
    for bad in ((), (0, 0), (3,), (-1,)):
        with pytest.raises(ValueError, match="components"):
            pose_nees(est, covs, true, bad)


def test_nees_is_nan_for_a_covariance_that_is_not_positive_definite():
    covs = np.stack([np.eye(3), np.diag([1.0, -1.0, 1.0])])
    nees = pose_nees(np.zeros((2, 3)), covs, np.ones((2, 3)))
    assert nees[0] == pytest.approx(3.0)
    assert np.isnan(nees[1])


def test_loop_match_nees_of_a_known_case_and_none_without_a_match():
    pose = np.array([1.0, 2.0, 0.1])
    plain = Belief(0, pose, np.eye(3), pose, (), (), 3, 0.0)
    assert loop_match_nees(plain, pose) is None
    fused = dataclasses.replace(
        plain,
        loop_match_pose=np.array([1.3, 1.6, 0.1 + 0.05]),
        loop_match_cov=np.diag([0.09, 0.04, 0.01]),
    )
    # (0.3 / 0.3)^2 + (0.4 / 0.2)^2 + (0.05 / 0.1)^2 = 1 + 4 + 0.25
    assert loop_match_nees(fused, pose) == pytest.approx(5.25)


def test_loop_match_summary_is_nan_without_matches_and_skips_nan():
    empty = loop_match_summary(np.array([]))
    assert math.isnan(empty["loop_match_nees_mean"]) and math.isnan(empty["loop_match_nees_median"])
    assert math.isnan(loop_match_summary(None)["loop_match_nees_median"])
    summary = loop_match_summary(np.array([1.0, 2.0, 9.0, np.nan]))
    assert summary == {"loop_match_nees_mean": 4.0, "loop_match_nees_median": 2.0}


def test_chi2_intervals():
    low, high = chi2_interval(3)
    assert (low, high) == pytest.approx((0.2158, 9.3484), abs=1e-4)
    lows, highs = zip(*(mean_nees_interval(n) for n in (1, 10, 100, 1000)), strict=True)
    assert (lows[0], highs[0]) == pytest.approx((low, high))
    assert all(a < b for a, b in zip(lows, lows[1:], strict=False))  # narrows around 3
    assert all(a > b for a, b in zip(highs, highs[1:], strict=False))
    assert lows[-1] < 3.0 < highs[-1]
    assert highs[-1] - lows[-1] < 0.4


def test_band_fraction_and_mean_test_on_hand_made_values():
    summary = nees_summary(np.array([0.1, 1.0, 3.0, 9.0, 10.0, np.nan]))
    assert summary["nees_in_band_fraction"] == pytest.approx(3 / 5)  # NaN ignored
    assert summary["nees_mean"] == pytest.approx(23.1 / 5)
    low, high = summary["nees_mean_interval"]
    assert low < 23.1 / 5 < high
    assert summary["nees_mean_consistent"] is True
    overconfident = nees_summary(np.full(100, 30.0))
    assert overconfident["nees_in_band_fraction"] == 0.0
    assert overconfident["nees_mean_consistent"] is False


def test_consistent_gaussian_errors_give_nees_3_and_95_percent_in_band():
    rng = np.random.default_rng(1)
    n = 4000
    a = rng.normal(size=(n, 3, 3)) * np.array([0.3, 0.3, 0.05])[:, None]
    covs = a @ a.transpose(0, 2, 1) + 1e-3 * np.eye(3)
    errors = np.einsum("nij,nj->ni", np.linalg.cholesky(covs), rng.normal(size=(n, 3)))
    est = np.column_stack([rng.uniform(-5, 5, (n, 2)), rng.uniform(-3, 3, n)])
    summary = nees_summary(pose_nees(est, covs, est + errors))
    assert summary["nees_mean"] == pytest.approx(3.0, abs=0.15)
    assert summary["nees_in_band_fraction"] == pytest.approx(0.95, abs=0.015)
    assert summary["nees_mean_consistent"] is True


# ---------------------------------------------------------------------- associations


def test_majority_id_ignores_no_returns_and_breaks_ties_low():
    assert majority_id([-1, -1, -1, 2, 2, 3]) == 2
    assert majority_id([5, 4, 5, 4]) == 4
    assert majority_id([-1, -1]) == -1
    assert majority_id(np.array([], dtype=int)) == -1


def _decision_log():
    d = DecisionRecord
    return [
        d(1, 0, 9, "created", 0, 1),  # landmark 0 from obstacle 1
        d(1, 20, 29, "created", 1, 2),  # landmark 1 from obstacle 2
        d(2, 0, 9, "updated", 0, 1),  # correct
        d(2, 20, 29, "associated", 1, 2),  # correct (no update; does not vote)
        d(3, 0, 9, "updated", 0, 2),  # wrong: obstacle 2 on landmark 0
        d(3, 20, 29, "created", 2, 1),  # landmark 2: a duplicate of obstacle 1
        d(4, 0, 9, "updated", 0, 1),  # correct
        d(4, 30, 35, "skipped", -1, 3),
        d(4, 40, 45, "unmatched", -1, 3),
        d(5, 0, 9, "associated", 2, 3),  # wrong
    ]


def test_landmark_majority_ids_vote_over_created_and_updated_sets():
    ids = landmark_majority_ids(_decision_log())
    assert ids == {0: 1, 1: 2, 2: 1}


def test_association_precision_on_a_tiny_decision_log():
    log = _decision_log()
    precision, associations = association_precision(log, landmark_majority_ids(log))
    assert associations == 5
    assert precision == pytest.approx(3 / 5)
    # only the associations that updated the map: two of three correct
    precision, updates = association_precision(log, landmark_majority_ids(log), ("updated",))
    assert updates == 3
    assert precision == pytest.approx(2 / 3)


def test_association_precision_without_associations_is_nan():
    precision, associations = association_precision([DecisionRecord(1, 0, 5, "created", 0, 0)], {})
    assert associations == 0
    assert math.isnan(precision)


def test_set_obstacles_keeps_the_ids_of_a_tenth_of_the_hits_most_hit_first():
    # 20 hitting beams: 12 on obstacle 3, 6 on 1, 2 on 7 (a tenth: kept), 0 on others
    hits = [3] * 12 + [-1] * 5 + [1] * 6 + [7] * 2
    assert set_obstacles(hits) == (3, 1, 7)
    assert set_obstacles(hits + [9]) == (3, 1)  # 2 and 1 of 21 hits: below a tenth
    assert set_obstacles([5, 4, 5, 4]) == (4, 5)  # ties: the smaller id first
    assert set_obstacles([-1, -1]) == ()
    assert set_obstacles(hits, share=0.5) == (3,)


def test_compound_precision_accepts_the_obstacles_the_landmark_was_created_from():
    d = DecisionRecord
    log = [
        d(1, 0, 9, "created", 0, 1, (1, 2)),  # landmark 0: a corner of obstacles 1 and 2
        d(1, 20, 29, "created", 1, 3, (3,)),
        d(2, 0, 9, "updated", 0, 1, (1,)),  # correct either way
        d(2, 20, 29, "updated", 0, 2, (2,)),  # obstacle 2: on the corner's other wall
        d(3, 0, 9, "updated", 1, 4, (4, 3)),  # obstacle 4 was not in landmark 1's set
        d(4, 0, 9, "associated", 1, 4, (4,)),  # a wrong update does not make 4 a member
        d(5, 0, 9, "associated", 1, -1, ()),  # no return: never correct
    ]
    ids = landmark_majority_ids(log)
    assert ids == {0: 1, 1: 3}  # votes: landmark 1 gets 3 and 4 once each, tie to 3
    strict, n = association_precision(log, ids)
    assert (strict, n) == (pytest.approx(1 / 5), 5)
    compound, n = compound_precision(log, ids)
    assert (compound, n) == (pytest.approx(2 / 5), 5)
    # without recorded obstacles it is the strict metric
    bare = [
        DecisionRecord(r.step, r.first, r.last, r.outcome, r.landmark, r.majority_id) for r in log
    ]
    assert compound_precision(bare, ids) == association_precision(bare, ids)
    assert compound_precision(_decision_log(), landmark_majority_ids(_decision_log()))[0] == (
        pytest.approx(3 / 5)
    )


def test_creation_causes_name_what_became_of_the_same_obstacle_candidates():
    d, nan = DecisionRecord, float("nan")
    far, gated = (0, "far", nan, nan, False), (0, "gated", nan, nan, False)
    log = [
        d(1, 0, 9, "created", 0, 1),  # obstacle 1's first landmark
        d(1, 10, 19, "created", 1, 2),  # obstacle 2's
        d(2, 0, 9, "created", 2, 1, (1,), (far,)),  # beside landmark 0, not aligned
        d(3, 0, 9, "created", 3, 1, (1,), (far, gated)),  # aligned and gated
        # the furthest candidate of the obstacle counts: the detection test failed
        d(4, 0, 9, "created", 4, 1, (1,), (gated, (2, "converged", 4.0, 9.0, False))),
        d(5, 0, 9, "created", 5, 1, (1,), ((3, "converged", 1.0, 2.0, True),)),
        # a candidate of another obstacle does not make a duplicate
        d(6, 10, 19, "created", 6, 3, (3,), ((0, "converged", 9.0, 99.0, False),)),
        d(7, 0, 9, "created", 7, -1, (), (far,)),  # no majority obstacle
        d(8, 0, 9, "updated", 0, 1, (1,), (far,)),  # not a creation
    ]
    ids = landmark_majority_ids(log)
    assert creation_causes(log, ids) == {
        "new": 4,
        "far": 1,
        "gated": 1,
        "rejected": 1,
        "accepted": 1,
    }
    # a detection that found a beam without range error (inf) is a rejection too
    inf = d(9, 0, 9, "created", 9, 1, (1,), ((0, "converged", float("inf"), nan, False),))
    assert creation_causes([*log, inf], ids)["rejected"] == 2


def test_duplicate_fraction():
    assert duplicate_fraction(landmark_majority_ids(_decision_log())) == pytest.approx(1 - 2 / 3)
    assert duplicate_fraction([0, 1, 2, 3]) == 0.0
    assert duplicate_fraction([4, 4, 4, 4]) == pytest.approx(0.75)
    assert duplicate_fraction([0, -1]) == pytest.approx(0.5)  # a landmark of nothing
    assert math.isnan(duplicate_fraction([]))


# ---------------------------------------------------------------------- TUM export


def test_yaw_quaternion_of_known_yaws():
    assert yaw_quaternion(0.0) == pytest.approx([0.0, 0.0, 0.0, 1.0])
    half = math.sqrt(0.5)
    assert yaw_quaternion(math.pi / 2) == pytest.approx([0.0, 0.0, half, half])
    q = yaw_quaternion(np.array([0.3, -2.0]))
    assert q.shape == (2, 4)
    assert np.linalg.norm(q, axis=1) == pytest.approx([1.0, 1.0])
    assert 2 * np.arctan2(q[:, 2], q[:, 3]) == pytest.approx([0.3, -2.0])


def test_write_tum_line_format(tmp_path):
    path = tmp_path / "traj.tum"
    poses = np.array([[1.0, 2.0, 0.0], [1.5, 2.25, math.pi / 2], [2.0, 2.5, -3.0]])
    write_tum(path, np.array([0.0, 0.1, 0.2]), poses)
    lines = path.read_text().splitlines()
    assert lines[0].startswith("#")
    rows = lines[1:]
    assert len(rows) == 3
    assert all(len(r.split(" ")) == 8 and not r.endswith(" ") for r in rows)
    assert rows[1].split(" ")[:4] == ["0.100000", "1.500000", "2.250000", "0.000000"]
    data = np.loadtxt(path)  # '#' lines are comments, as in evo
    half = math.sqrt(0.5)
    assert data[1, 4:] == pytest.approx([0.0, 0.0, half, half], abs=1e-9)
    assert 2 * np.arctan2(data[:, 6], data[:, 7]) == pytest.approx(poses[:, 2], abs=1e-8)


def test_write_tum_rejects_bad_input(tmp_path):
    with pytest.raises(ValueError, match="increasing"):
        write_tum(tmp_path / "a.tum", np.array([0.0, 0.0]), np.zeros((2, 3)))
    with pytest.raises(ValueError, match="entries"):
        write_tum(tmp_path / "a.tum", np.array([0.0]), np.zeros((2, 3)))


# ---------------------------------------------------------------------- command line


@pytest.mark.parametrize(
    ("text", "seeds"),
    [("0-9", list(range(10))), ("0,3,5", [0, 3, 5]), ("7", [7]), ("0-2, 5", [0, 1, 2, 5])],
)
def test_parse_seeds(text, seeds):
    assert parse_seeds(text) == seeds


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("", "not a seed"),
        ("a", "not a seed"),
        ("5-3", "reversed"),
        ("1,1", "twice"),
        ("0-", "not a seed"),
    ],
)
def test_parse_seeds_rejects(text, message):
    with pytest.raises(SeedsError, match=message):
        parse_seeds(text)


def _parser():
    parser = argparse.ArgumentParser(prog="vslam-gym")
    add_evaluate_parser(parser.add_subparsers(dest="command", required=True))
    return parser


def test_evaluate_parser():
    args = _parser().parse_args(
        ["evaluate", "--world", "house", "--seeds", "0-3", "--preset", "thesis", "--out", "d"]
    )
    assert (args.world, args.seeds, args.preset, args.out) == ("house", [0, 1, 2, 3], "thesis", "d")
    assert args.max_steps is None and args.no_progress is False
    assert args.handler is cmd_evaluate and args.overrides is None
    args = _parser().parse_args(
        ["evaluate", "--world", "small", "--out", "d", "--set", '{"filter": {"prealign": "fuse"}}']
    )
    assert args.overrides == {"filter": {"prealign": "fuse"}}


@pytest.mark.parametrize(
    "bad, message",
    [
        (["--seeds", "3-1"], "seeds"),
        (["--preset", "quick"], "preset"),
        (["--set", "{not json"], "JSON object"),
        (["--set", "[1, 2]"], "JSON object"),
        (["--set", '{"filter": {"icp_gate": 3}}'], "icp_gate"),
        (["--set", '{"preset": "thesis"}'], "--preset"),
        (["--set", '{"filter": {"measurement_min_travel": -1}}'], "measurement_min_travel"),
        (["--jobs", "0"], "--jobs"),
    ],
)
def test_evaluate_parser_rejects(bad, message, capsys):
    with pytest.raises(SystemExit):
        _parser().parse_args(["evaluate", "--world", "house", "--out", "d", *bad])
    err = capsys.readouterr().err
    assert "error" in err and message in err


def test_run_episode_rejects_a_world_without_route(tmp_path):
    world = dataclasses.replace(load_world("single_landmark"), route=None)
    path = tmp_path / "no_route.toml"
    path.write_text(world_to_toml(world))
    with pytest.raises(ValueError, match="route"):
        run_episode(str(path), seed=0, max_steps=5)
    with pytest.raises(ValueError, match="max_steps"):
        run_episode("single_landmark", seed=0, max_steps=0)


# ---------------------------------------------------------------------- end to end

E2E_STEPS = 60


@pytest.fixture(scope="module")
def episode():
    return run_episode("single_landmark", seed=0, max_steps=E2E_STEPS)


def test_episode_log_is_consistent(episode):
    n = E2E_STEPS + 1
    assert episode.steps == E2E_STEPS
    assert episode.true_poses.shape == episode.slam_poses.shape == (n, 3)
    assert episode.odometry_poses.shape == (n, 3)
    assert episode.slam_covs.shape == (n, 3, 3)
    assert np.allclose(episode.slam_covs, episode.slam_covs.transpose(0, 2, 1))
    assert np.all(np.linalg.eigvalsh(episode.slam_covs) > 0)
    assert episode.times[1] == pytest.approx(0.1)
    # all three start at the true initial pose
    assert np.allclose(episode.slam_poses[0], episode.true_poses[0])
    assert np.allclose(episode.odometry_poses[0], episode.true_poses[0])
    assert episode.landmark_counts[-1] == len(episode.final_belief.landmarks) >= 1
    assert not episode.route_done
    # the only obstacle is id 0: every set is on it
    assert {d.majority_id for d in episode.decisions} == {0}
    assert {d.obstacles for d in episode.decisions} == {(0,)}
    assert {d.step for d in episode.decisions} <= set(range(1, E2E_STEPS + 1))
    timing = episode_metrics(episode)
    assert timing["step_ms_mean"] == pytest.approx(np.mean(episode.step_ms))
    assert timing["step_ms_median"] == pytest.approx(np.median(episode.step_ms))
    # the default's motion filter: some steps measure (the first always), some do not
    assert episode.measured.shape == (E2E_STEPS,) and episode.measured[0]
    assert 0.0 < timing["measured_fraction"] == np.mean(episode.measured) < 1.0
    assert timing["measured_step_ms_median"] == np.median(episode.step_ms[episode.measured])
    assert {d.step for d in episode.decisions} <= set(np.flatnonzero(episode.measured) + 1)
    rejected = [d for d in episode.decisions if d.outcome == "rejected"]
    assert timing["rejected_updates"] == len(rejected)
    assert timing["updates"] == sum(d.outcome == "updated" for d in episode.decisions) > 0
    # no revisit match this early (60 updates old at least): the match NEES is NaN
    assert episode.loop_match_nees.size == timing["loop_closures"] == 0
    assert math.isnan(timing["loop_match_nees_mean"])


def _same(a, b):
    """Equal metric values; NaN on one side is null (None) on the other (strict JSON)."""
    if isinstance(a, float) and math.isnan(a):
        return b is None
    if isinstance(a, tuple | list):
        return list(a) == list(b)
    return a == b


def test_evaluate_end_to_end_is_deterministic(episode, tmp_path, capsys):
    out = tmp_path / "eval"
    args = _parser().parse_args(
        ["evaluate", "--world", "single_landmark", "--seeds", "0", "--out", str(out)]
        + ["--max-steps", str(E2E_STEPS), "--no-progress"]
    )
    assert cmd_evaluate(args) == 0
    printed = capsys.readouterr().out
    assert printed.startswith("single_landmark / preset default / 1 seed(s)")
    assert "ATE m" in printed and "metrics.json" in printed

    metrics = json.loads((out / "metrics.json").read_text())
    seed = metrics["per_seed"][0]
    assert REQUIRED_KEYS | {"seed"} <= seed.keys()
    assert REQUIRED_KEYS <= metrics["mean"].keys()
    assert seed["steps"] == E2E_STEPS and seed["seed"] == 0
    assert seed["world"] == "single_landmark" and seed["preset"] == "default"
    assert seed["landmarks"] >= 1
    assert 0.0 < seed["odom_ate_rmse_m"] < 0.5
    assert 0.0 <= seed["nees_in_band_fraction"] <= 1.0
    assert 0.0 <= seed["duplicate_fraction"] < 1.0
    # the one star-shaped obstacle is one surface: a perfect map has no duplicate
    assert seed["surface_pieces"] == 1 and seed["duplicate_floor"] == 0.0
    assert seed["landmarks_per_piece"] == seed["landmarks"]
    assert "floor" in printed and "pieces" in printed
    assert seed["association_precision"] <= seed["compound_precision"] <= 1.0
    assert "cmp P" in printed
    # every new landmark has one cause, and the first one of an obstacle is new
    causes = [seed[f"created_{c}"] for c in ("new", "far", "gated", "rejected", "accepted")]
    assert sum(causes) >= seed["landmarks"] >= 1 and seed["created_new"] >= 1
    assert seed["step_ms_median"] <= seed["step_ms_p95"]
    for key in REQUIRED_KEYS - {"world", "preset"}:
        assert metrics["mean"][key] == pytest.approx(seed[key]), key  # one seed
    assert format_table(metrics).splitlines()[-1].split()[0] == "mean"

    for name in ("trajectories", "map", "nees"):
        png = out / f"{name}_seed0.png"
        assert png.read_bytes()[:8] == PNG_MAGIC
    for name in ("true", "odometry", "slam"):
        tum = np.loadtxt(out / f"{name}_seed0.tum")
        assert tum.shape == (E2E_STEPS + 1, 8)
    slam_tum = np.loadtxt(out / "slam_seed0.tum")
    true_tum = np.loadtxt(out / "true_seed0.tum")
    ate = np.sqrt(np.mean(np.sum((slam_tum[1:, 1:3] - true_tum[1:, 1:3]) ** 2, axis=1)))
    assert ate == pytest.approx(seed["ate_rmse_m"], abs=1e-5)

    # the same seed in a second, independent run (the fixture) gives the same numbers
    again = episode_metrics(episode)
    assert again.keys() == seed.keys()
    for key in again.keys() - set(TIMING_KEYS):
        assert _same(again[key], seed[key]), key


def test_evaluate_in_worker_processes_gives_the_same_metrics(tmp_path):
    """``jobs=2`` runs the seeds in two processes: same metrics and files, seed order."""
    kwargs = dict(max_steps=15, progress=False, print_table=False)
    alone = evaluate("small", [1, 0], out_dir=tmp_path / "one", **kwargs)
    pooled = evaluate("small", [1, 0], out_dir=tmp_path / "two", jobs=2, **kwargs)
    assert [m["seed"] for m in pooled["per_seed"]] == [1, 0]
    for a, b in zip(alone["per_seed"], pooled["per_seed"], strict=True):
        assert a.keys() == b.keys()
        for key in a.keys() - set(TIMING_KEYS):
            assert a[key] == b[key] or (math.isnan(a[key]) and math.isnan(b[key])), key
    assert (tmp_path / "two" / "map_seed0.png").read_bytes()[:8] == PNG_MAGIC
    assert np.array_equal(
        np.loadtxt(tmp_path / "one" / "slam_seed1.tum"),
        np.loadtxt(tmp_path / "two" / "slam_seed1.tum"),
    )
    with pytest.raises(ValueError, match="jobs"):
        evaluate("small", [0], out_dir=tmp_path / "bad", jobs=0, **kwargs)


def test_sem_metrics_and_the_table_row():
    per_seed = [
        {"seed": 0, "world": "w", "preset": "default", "ate_rmse_m": 0.1, "route_done": True},
        {"seed": 1, "world": "w", "preset": "default", "ate_rmse_m": 0.3, "route_done": False},
        {"seed": 2, "world": "w", "preset": "default", "ate_rmse_m": math.nan, "route_done": True},
    ]
    sem = sem_metrics(per_seed)
    # over the finite values 0.1 and 0.3: sd 0.1414, / sqrt(2)
    assert sem["ate_rmse_m"] == pytest.approx(0.1)
    assert sem["route_done"] == pytest.approx(np.std([1, 0, 1], ddof=1) / math.sqrt(3))
    assert "world" not in sem and "seed" not in sem
    assert math.isnan(sem_metrics(per_seed[:1])["ate_rmse_m"])
    with pytest.raises(ValueError, match="no seed"):
        sem_metrics([])
    metrics = {
        "world": "w",
        "preset": "default",
        "per_seed": per_seed[:2],
        "mean": mean_metrics(per_seed[:2]),
        "sem": sem_metrics(per_seed[:2]),
    }
    last = format_table(metrics).splitlines()
    assert last[-2].split()[0] == "mean" and last[-1].split()[:2] == ["+-", "sem"]
    assert "0.100" in last[-1] and "0.200" in last[-2]


def test_range_perturbation_is_a_round_off_probe(tmp_path):
    """1 + 1e-15 on the ranges: the simulation is the same, the SLAM moves by round-off
    only (at first), and the figures say which perturbation they were run with."""
    plain = run_episode("small", 0, max_steps=20)
    probed = run_episode("small", 0, max_steps=20, range_perturbation=1e-15)
    np.testing.assert_array_equal(probed.true_poses, plain.true_poses)
    np.testing.assert_array_equal(probed.odometry_poses, plain.odometry_poses)
    difference = np.abs(probed.slam_poses - plain.slam_poses).max()
    assert 0.0 < difference < 1e-9
    metrics = evaluate(
        "small", [0], "default", tmp_path, progress=False, max_steps=3, print_table=False,
        range_perturbation=1e-15,
    )  # fmt: skip
    assert metrics["range_perturbation"] == 1e-15
    assert "--range-perturbation 1e-15" in format_table(metrics).splitlines()[0]
    assert check_range_perturbation(0.0) == 0.0
    for bad in (0.1, -1e-15, math.nan, "1e-15"):
        with pytest.raises(ValueError, match="range_perturbation"):
            check_range_perturbation(bad)
    with pytest.raises(ValueError, match="range_perturbation"):
        run_episode("small", 0, max_steps=1, range_perturbation=1e-3)


def test_start_scan_modes_give_the_scan_of_reset_to_the_matcher_the_map_or_nobody(tmp_path):
    """The scan of ``reset``: the matcher's first keyframe (default; the first step is
    aligned to it), a step that makes landmarks (``"map"``), or unused (``"none"``)."""
    first: dict[str, bool] = {}

    def on_first_step(mode):
        def progress(step, belief):
            if step == 1:
                first[mode] = belief.prealigned

        return progress

    logs = {
        mode: run_episode("small", 0, max_steps=3, progress=on_first_step(mode), start_scan=mode)
        for mode in START_SCAN_MODES
    }
    # "map" measured the start scan: step 1 has not moved far enough to measure again
    assert first == {"matcher": True, "map": False, "none": False}
    assert logs["map"].landmark_counts[0] > 0
    assert logs["matcher"].landmark_counts[0] == logs["none"].landmark_counts[0] == 0
    np.testing.assert_array_equal(logs["matcher"].true_poses, logs["none"].true_poses)
    metrics = evaluate(
        "small", [0], "default", tmp_path, progress=False, max_steps=3, print_table=False,
        start_scan="none",
    )  # fmt: skip
    assert metrics["start_scan"] == "none"
    assert "--start-scan none" in format_table(metrics).splitlines()[0]
    for bad in ("keyframe", True, None):
        with pytest.raises(ValueError, match="start_scan"):
            run_episode("small", 0, max_steps=1, start_scan=bad)


def test_evaluate_applies_overrides_over_the_preset(tmp_path):
    # a motion filter no route step reaches: only the first scan is used
    overrides = {"filter": {"measurement_min_travel": 100.0, "measurement_min_turn": 100.0}}
    metrics = evaluate(
        "single_landmark",
        [0],
        "default",
        tmp_path,
        progress=False,
        max_steps=8,
        print_table=False,
        overrides=overrides,
    )
    assert metrics["overrides"] == overrides and metrics["preset"] == "default"
    assert metrics["per_seed"][0]["preset"] == "default"
    first_scan_only = run_episode("single_landmark", seed=0, max_steps=1)
    assert metrics["per_seed"][0]["landmarks"] == len(first_scan_only.final_belief.landmarks)
    assert metrics["per_seed"][0]["measured_fraction"] == 1 / 8
    assert "--set" in format_table(metrics).splitlines()[0]
    with pytest.raises(ValueError, match="measurement_min_travel"):
        evaluate(
            "single_landmark",
            [0],
            "default",
            tmp_path,
            overrides={"filter": {"measurement_min_travel": -1}},
        )


def test_odometry_covariance_matches_monte_carlo_dead_reckoning():
    """The motion model alone is consistent: its propagated covariance is the spread of
    sampled dead reckoning along the same path (so odom NEES near 3)."""
    from vslam_gym.slam.motion import odometry_noise, predict_pose

    config = SlamConfig()
    u = np.array([0.02, 0.1, 0.02])
    true = [np.zeros(3)]
    for _ in range(60):
        true.append(predict_pose(true[-1], u))
    true = np.array(true)
    covs = odometry_covariances(true, config)
    assert covs.shape == (61, 3, 3)
    assert np.all(np.linalg.eigvalsh(covs) > 0)
    sd = np.sqrt(
        np.diag(
            odometry_noise(u, config.filter.odometry_alphas, config.filter.odometry_sigma_floor)
        )
    )
    rng = np.random.default_rng(0)
    finals = []
    for _ in range(3000):
        pose = np.zeros(3)
        for _ in range(60):
            pose = predict_pose(pose, u + rng.normal(0.0, sd))
        finals.append(pose)
    finals = np.array(finals)
    empirical = np.cov(finals.T)
    np.testing.assert_allclose(np.diag(empirical), np.diag(covs[-1]), rtol=0.15)
    nees = pose_nees(
        finals, np.repeat(covs[-1][None], len(finals), axis=0), np.tile(true[-1], (len(finals), 1))
    )
    assert 2.7 < nees.mean() < 3.4


def test_name_or_mapping_parses_json_objects_and_keeps_names():
    assert name_or_mapping("fast") == "fast"
    assert name_or_mapping(' {"filter": {"loop_closure": false}}') == {
        "filter": {"loop_closure": False}
    }
    with pytest.raises(argparse.ArgumentTypeError, match="valid JSON"):
        name_or_mapping('{"filter": ')


def test_evaluate_keeps_odometry_alphas_set_in_the_overrides():
    mine = [0.1, 0.05, 0.05, 0.01]
    common = dict(world="single_landmark", seed=0, preset="default", max_steps=3)
    result = run_episode(**common, overrides={"filter": {"odometry_alphas": mine}})
    assert result.config.filter.odometry_alphas == tuple(mine)
    world = run_episode(**common)
    assert world.config.filter.odometry_alphas != tuple(mine)
