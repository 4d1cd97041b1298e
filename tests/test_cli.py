import pytest

from vslam_gym.cli import build_parser, main, run_route
from vslam_gym.sim.world_file import list_worlds

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def test_run_writes_a_png_and_prints_a_summary(tmp_path, capsys):
    out = tmp_path / "plots" / "run.png"
    status = main(
        ["run", "--world", "single_landmark", "--seed", "3", "--out", str(out), "--steps", "60"]
    )
    assert status == 0
    assert out.read_bytes()[:8] == PNG_MAGIC
    assert out.stat().st_size > 10_000
    summary = capsys.readouterr().out.strip()
    assert summary.startswith("single_landmark: 60 steps,")
    assert "0 collision steps" in summary
    assert "route NOT completed" in summary


def test_run_result_records_paths_and_hits():
    result = run_route("single_landmark", seed=0, steps=40, scan_every=10)
    assert result.steps == 40
    assert result.true_path.shape == result.odometry_path.shape == (41, 3)
    assert 3.0 < result.distance < 4.1  # at most 1 m/s for 4 s
    assert len(result.hits) > 50  # four scans of the landmark
    assert result.collision_steps == 0


def test_worlds_lists_the_shipped_worlds(capsys):
    assert main(["worlds"]) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    assert [line.split()[0] for line in lines] == list_worlds()


def test_bad_input(tmp_path, capsys):
    assert main(["run", "--world", "no_such_world", "--out", str(tmp_path / "x.png")]) == 2
    assert "unknown world" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["run", "--world", "single_landmark", "--out", str(tmp_path / "x.jpg")])
    with pytest.raises(SystemExit):
        build_parser().parse_args([])  # a subcommand is required
