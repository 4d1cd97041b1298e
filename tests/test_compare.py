"""``vslam-gym compare``: pairing runs of two evaluations and the paired statistics."""

from __future__ import annotations

import json
import math

import pytest

from vslam_gym.cli import main
from vslam_gym.compare import compare_runs, format_comparison, load_runs


def _write(path, data):
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(data))
    return path


def _per_seed(values, key="ate_rmse_m", runs="per_seed"):
    rows = [{"seed": s, key: v, "landmarks": 3, "world": "small"} for s, v in values.items()]
    return {runs: rows, "mean": {key: sum(values.values()) / len(values)}}


def test_paired_statistics_by_hand(tmp_path):
    base = load_runs(_write(tmp_path / "a" / "metrics.json", _per_seed({0: 1.0, 1: 2.0, 2: 3.0})))
    other = load_runs(_write(tmp_path / "b.json", _per_seed({0: 2.0, 1: 2.5, 2: 4.0, 7: 9.0})))
    assert sorted(base) == ["seed 0", "seed 1", "seed 2"]
    (ate, landmarks) = compare_runs(base, other)  # seed 7 has no pair: left out
    assert ate.metric == "ate_rmse_m" and ate.pairs == 3
    assert ate.base_mean == pytest.approx(2.0) and ate.other_mean == pytest.approx(17 / 6)
    # differences 1, 0.5, 1: mean 5/6, sd sqrt(1/12), t = (5/6) / (sqrt(1/12) / sqrt(3)) = 5
    assert ate.difference == pytest.approx(5 / 6)
    assert ate.paired_t == pytest.approx(5.0)
    assert (ate.lower, ate.higher, ate.equal) == (0, 3, 0)
    assert landmarks.paired_t == 0.0 and landmarks.equal == 3
    table = format_comparison([ate, landmarks]).splitlines()
    assert table[2].startswith("| ate_rmse_m | 3 | 2 | 2.833 | +0.8333 | +5.00 | 0 / 3 / 0 |")


def test_agent_episodes_nan_pairs_and_named_metrics(tmp_path):
    base = _per_seed({1000: 0.2, 1001: math.nan, 1002: 0.4}, key="coverage", runs="per_episode")
    other = _per_seed({1000: 0.1, 1001: 0.3, 1002: 0.4}, key="coverage", runs="per_episode")
    (cov,) = compare_runs(
        load_runs(_write(tmp_path / "a.json", base)),
        load_runs(_write(tmp_path / "b.json", other)),
        ["coverage"],
    )
    assert cov.pairs == 2  # the NaN pair is left out
    assert (cov.lower, cov.higher, cov.equal) == (1, 0, 1)
    assert cov.difference == pytest.approx(-0.05)
    assert cov.paired_t == pytest.approx(-1.0)  # differences -0.1, 0: mean -0.05, se 0.05


def test_tree_of_replays_keyed_by_directory(tmp_path):
    for side, ate in (("a", 0.5), ("b", 0.25)):
        _write(tmp_path / side / "intel" / "metrics.json", {"log": "intel", "ate_rmse_m": ate})
        _write(tmp_path / side / "aces" / "metrics.json", {"log": "aces", "ate_rmse_m": 2 * ate})
        # a multi-seed replay: its per-seed directories are not read again
        _write(tmp_path / side / "many" / "seed0" / "metrics.json", {"ate_rmse_m": 99.0})
        _write(tmp_path / side / "many" / "metrics.json", _per_seed({0: ate, 1: ate}))
    runs = load_runs(tmp_path / "a")
    assert sorted(runs) == ["aces", "intel", "many/seed 0", "many/seed 1"]
    (ate,) = compare_runs(runs, load_runs(tmp_path / "b"), ["ate_rmse_m"])
    assert ate.pairs == 4 and ate.lower == 4
    assert ate.base_mean == pytest.approx((0.5 + 1.0 + 0.5 + 0.5) / 4)
    # a single replay on each side is one run, paired with the other
    single = load_runs(tmp_path / "a" / "intel" / "metrics.json")
    assert list(single) == ["run"]


@pytest.mark.parametrize(
    ("content", "message"),
    [
        (None, "no such file"),
        ("{not json", "cannot read"),
        ("[1, 2]", "expected a JSON object"),
        ('{"per_seed": [1, 2]}', "must be a list of metrics objects"),
        ('{"per_seed": [{"seed": 1}, {"seed": 1}]}', "appears twice"),
    ],
)
def test_bad_inputs_are_named(tmp_path, content, message):
    path = tmp_path / "metrics.json"
    if content is not None:
        path.write_text(content)
    with pytest.raises(ValueError, match=message):
        load_runs(path)


def test_no_common_run_or_metric(tmp_path):
    (tmp_path / "empty").mkdir()
    with pytest.raises(ValueError, match="no metrics.json in it or below it"):
        load_runs(tmp_path / "empty")
    a = {"seed 0": {"ate_rmse_m": 1.0, "label": "x"}}
    with pytest.raises(ValueError, match="no run in common"):
        compare_runs(a, {"seed 1": {"ate_rmse_m": 1.0}})
    with pytest.raises(ValueError, match=r"not a number .*\['label'\]"):
        compare_runs(a, a, ["label"])
    # a key the runs lack (agents' outputs name their position ATE ``ate_m``)
    b = {"seed 0": {"ate_m": 1.0}}
    with pytest.raises(ValueError, match=r"no metric \['ate_rmse_m'\].*did you mean 'ate_m'"):
        compare_runs(b, b, ["ate_rmse_m"])
    with pytest.raises(ValueError, match="share no numeric metric"):
        compare_runs({"r": {"label": "x"}}, {"r": {"label": "y"}})


def test_compare_command_on_two_evaluations(tmp_path, capsys):
    """Two real ``vslam-gym evaluate`` outputs: one with itself, one with another filter."""
    common = ["--world", "single_landmark", "--seeds", "0-1", "--max-steps", "25", "--no-progress"]
    assert main(["evaluate", *common, "--out", str(tmp_path / "a")]) == 0
    other = '{"filter": {"measurement_min_travel": 0.5, "measurement_min_turn": 0.5}}'
    assert main(["evaluate", *common, "--out", str(tmp_path / "b"), "--set", other]) == 0
    capsys.readouterr()

    a = load_runs(tmp_path / "a")
    same = {c.metric: c for c in compare_runs(a, load_runs(tmp_path / "a" / "metrics.json"))}
    assert {"ate_rmse_m", "nees_mean", "landmarks", "step_ms_median"} <= same.keys()
    for metric in ("ate_rmse_m", "final_error_m", "nees_mean", "landmarks"):
        assert same[metric].pairs == 2 and same[metric].equal == 2, metric
        assert same[metric].paired_t == 0.0

    assert (
        main(
            [
                "compare",
                str(tmp_path / "a"),
                str(tmp_path / "b"),
                "--json",
                str(tmp_path / "c.json"),
            ]
        )
        == 0
    )
    printed = capsys.readouterr().out
    assert "2 runs paired by key" in printed and "| ate_rmse_m | 2 |" in printed
    rows = {r["metric"]: r for r in json.loads((tmp_path / "c.json").read_text())}
    assert rows["landmarks"]["pairs"] == 2
    # measuring less often changes the run: some metric differs
    assert any(r["equal"] < 2 for m, r in rows.items() if m != "step_ms_median")

    assert main(["compare", str(tmp_path / "a"), str(tmp_path / "missing")]) == 2
    assert "no such file or directory" in capsys.readouterr().err


def test_a_single_replay_pairs_with_its_seed_of_a_multi_seed_one():
    single = {"run": {"seed": 1, "ate_rmse_m": 0.5}}
    several = {"seed 0": {"seed": 0, "ate_rmse_m": 0.4}, "seed 1": {"seed": 1, "ate_rmse_m": 0.7}}
    (row,) = compare_runs(single, several, ["ate_rmse_m"])
    assert row.pairs == 1 and row.difference == pytest.approx(0.2)
    (row,) = compare_runs(several, single, ["ate_rmse_m"])
    assert row.pairs == 1 and row.difference == pytest.approx(-0.2)
    # two single runs still pair as "run", whatever their seeds
    (row,) = compare_runs(single, {"run": {"seed": 4, "ate_rmse_m": 0.6}}, ["ate_rmse_m"])
    assert row.pairs == 1
