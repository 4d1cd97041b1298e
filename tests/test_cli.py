import gzip

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


def test_unreadable_files_are_reported_not_raised(tmp_path, capsys):
    """A missing, truncated or empty log, or a missing world file: exit 2 with the cause."""
    assert main(["replay", str(tmp_path / "missing.log.gz"), "--out", str(tmp_path / "a")]) == 2
    assert "missing.log.gz: No such file or directory" in capsys.readouterr().err
    truncated = tmp_path / "truncated.log.gz"
    truncated.write_bytes(gzip.compress(b"FLASER 3 1.0 1.0 1.0 0 0 0 0 0 0 0 robot 0\n" * 50)[:40])
    assert main(["replay", str(truncated), "--out", str(tmp_path / "b")]) == 2
    assert "truncated file" in capsys.readouterr().err
    world = str(tmp_path / "missing.toml")
    assert main(["evaluate", "--world", world, "--seeds", "0", "--out", str(tmp_path / "c")]) == 2
    assert "missing.toml: No such file or directory" in capsys.readouterr().err
    # a replay that fails on its first scan names that failure (not the empty metrics)
    log = tmp_path / "two_beams.log"
    scan, odom = "FLASER 2 1.0 1.0 0 0 0 0 0 0 0 robot 0\n", "ODOM 0 0 0 0 0 0 0 robot 0\n"
    log.write_text((scan + odom) * 2 + scan)
    assert main(["replay", str(log), "--out", str(tmp_path / "d")]) == 2
    err = capsys.readouterr().err
    assert "scan 0" in err and "estimated must have shape" not in err, err
    assert main(["replay", str(log), "--out", str(tmp_path / "e"), "--max-scans", "0"]) == 2
    assert "max_scans must be at least 1" in capsys.readouterr().err
