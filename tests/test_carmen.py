"""Carmen log reader: format, beam order, sentinels, odometry increments, the real logs."""

from __future__ import annotations

import gzip
import io
import os
from pathlib import Path

import numpy as np
import pytest

from vslam_gym.evaluation import heading_rmse, position_ate_rmse
from vslam_gym.logs import (
    CarmenConfig,
    CarmenFormatError,
    CarmenLog,
    CarmenRecorder,
    integrate_increments,
    logged_increments,
    read_carmen,
    synthetic_increments,
    write_carmen,
)
from vslam_gym.slam.geometry import wrap_angle
from vslam_gym.slam.motion import increments_between, predict_pose

# The logs live in the project's shared folder beside the repository (override with
# VSLAM_GYM_RADISH); tests that need them are skipped where they are absent.
RADISH = Path(
    os.environ.get("VSLAM_GYM_RADISH", Path(__file__).resolve().parents[2] / "shared/data/radish")
)
INTEL = RADISH / "intel.log.gz"
SENTINEL = 81.83

P0 = (1.0, 2.0, 0.3)
O1 = (1.8, 2.5, 0.9)
P1 = (1.75, 2.45, 0.85)

# 4 beams at 45 deg (PARAM), Carmen order right to left: -90, -45, 0, +45 deg.
SMALL_LOG = f"""# message formats defined: PARAM ODOM FLASER
PARAM laser_front_laser_resolution 45 nohost 0
ODOM 0 0 0 0 0 0 0.0 host 0.0
FLASER 4 1.0 2.0 {SENTINEL} 4.0 {P0[0]} {P0[1]} {P0[2]} {P0[0]} {P0[1]} {P0[2]} 1.0 host 1.0
ODOM {P0[0]} {P0[1]} {P0[2]} 0 0 0 1.0 host 1.0
NEFF 15

ODOM 1.5 2.2 0.5 0.3 0.1 0 1.5 host 1.5
ODOM {O1[0]} {O1[1]} {O1[2]} 0.3 0.1 0 1.9 host 1.9
RLASER 1 2.0 0 0 0 0 0 0 2.0 host 2.0
FLASER 4 5.0 6.0 7.0 8.0 {P1[0]} {P1[1]} {P1[2]} {P1[0]} {P1[1]} {P1[2]} 2.0 host 2.0
NEFF 14
"""


def write(tmp_path: Path, text: str, name: str = "small.log") -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


@pytest.fixture(scope="module")
def intel() -> CarmenLog:
    if not INTEL.exists():
        pytest.skip(f"the Intel log is not at {INTEL}")
    return read_carmen(INTEL)


def test_small_log_fields(tmp_path: Path) -> None:
    log = read_carmen(write(tmp_path, SMALL_LOG))
    assert log.num_scans == 2 and log.num_beams == 4
    np.testing.assert_allclose(np.rad2deg(log.bearings), [45.0, 0.0, -45.0, -90.0])
    # Reversed to descending bearing; the sentinel (the log's maximum) -> max range.
    assert log.no_return_threshold == pytest.approx(0.999 * SENTINEL)
    assert log.max_range == pytest.approx(0.999 * SENTINEL)
    np.testing.assert_array_equal(log.no_return[0], [False, True, False, False])
    np.testing.assert_allclose(log.ranges[0], [4.0, log.max_range, 2.0, 1.0])
    np.testing.assert_allclose(log.ranges[1], [8.0, 7.0, 6.0, 5.0])
    assert not log.no_return[1].any()
    np.testing.assert_allclose(log.poses, [P0, P1])
    np.testing.assert_allclose(log.times, [1.0, 2.0])
    np.testing.assert_array_equal(log.scan_lines, [4, 11])
    assert log.odometry.shape == (4, 3)
    np.testing.assert_array_equal(log.odometry_after_scan, [-1, 0, 0, 0])
    np.testing.assert_allclose(log.odometry[-1], O1)
    np.testing.assert_allclose(log.odometry_velocities[2], [0.3, 0.1, 0.0])
    assert log.skipped == {"NEFF": 2, "RLASER": 1}
    assert log.params == {"laser_front_laser_resolution": "45"}


def test_gzip_and_streams_read_the_same(tmp_path: Path) -> None:
    plain = read_carmen(write(tmp_path, SMALL_LOG))
    gz_path = tmp_path / "small.log.gz"
    gz_path.write_bytes(gzip.compress(SMALL_LOG.encode()))
    for source in (
        gz_path,
        str(gz_path),
        io.StringIO(SMALL_LOG),
        io.BytesIO(SMALL_LOG.encode()),
        io.BytesIO(gzip.compress(SMALL_LOG.encode())),
    ):
        log = read_carmen(source)
        np.testing.assert_array_equal(log.ranges, plain.ranges)
        np.testing.assert_array_equal(log.odometry, plain.odometry)
        assert log.skipped == plain.skipped


def test_explicit_threshold_and_max_range(tmp_path: Path) -> None:
    path = write(tmp_path, SMALL_LOG)
    log = read_carmen(path, CarmenConfig(no_return_threshold=80.0, max_range=6.5))
    # 81.83 is the sentinel; 7.0 and 8.0 lie beyond max_range: three no-return beams.
    assert log.no_return.sum() == 3
    np.testing.assert_array_equal(log.no_return[1], [True, True, False, False])
    assert log.ranges.max() == pytest.approx(6.5)
    with pytest.raises(ValueError, match="no_return_fraction"):
        CarmenConfig(no_return_fraction=1.5)


@pytest.mark.parametrize(
    ("bad", "match"),
    [
        ("FLASER 4 1.0 abc 3.0 4.0 0 0 0 0 0 0 1.0 h 1.0", "not a number"),
        ("FLASER 4 1.0 2.0 3.0 4.0 0 0 0", "needs at least"),
        ("FLASER four 1.0", "not an integer"),
        ("FLASER 3 1.0 2.0 3.0 0 0 0 0 0 0 1.0 h 1.0", "3 beams"),
        ("ODOM 1.0 2.0", "ODOM needs"),
        ("ODOM 1.0 2.0 nan 0 0 0 1.0 h 1.0", "not finite"),
        ("PARAM lonely", "PARAM needs"),
    ],
)
def test_malformed_line_names_its_number(tmp_path: Path, bad: str, match: str) -> None:
    lines = SMALL_LOG.splitlines()
    lines.insert(5, bad)  # becomes line 6
    with pytest.raises(CarmenFormatError, match=match) as err:
        read_carmen(write(tmp_path, "\n".join(lines)))
    assert err.value.line == 6
    assert "line 6" in str(err.value)
    assert isinstance(err.value, ValueError)


def test_log_without_scans_raises(tmp_path: Path) -> None:
    with pytest.raises(CarmenFormatError, match="no FLASER"):
        read_carmen(write(tmp_path, "PARAM a 1\nODOM 0 0 0 0 0 0 0\n"))


def test_wall_on_the_left_appears_at_positive_bearings(tmp_path: Path) -> None:
    """A wall parallel to the robot's heading, 1 m to its LEFT (robot frame y = +1)."""
    wall_y = 1.0
    carmen_bearings = np.deg2rad(-90.0 + np.arange(180))
    sin = np.sin(carmen_bearings)
    with np.errstate(divide="ignore"):
        ranges = np.where(sin > 0.05, wall_y / sin, SENTINEL)  # Carmen order: right to left
    pose = "0 0 0 0 0 0 1.0 host 1.0"
    text = "FLASER 180 " + " ".join(f"{r:.6f}" for r in ranges) + f" {pose}\n"
    log = read_carmen(write(tmp_path, text))
    assert np.rad2deg(log.bearings[0]) == pytest.approx(89.0)
    assert np.rad2deg(log.bearings[-1]) == pytest.approx(-90.0)
    assert np.all(np.diff(log.bearings) < 0)
    hits = ~log.no_return[0]
    assert hits.sum() == np.count_nonzero(sin > 0.05)
    assert np.all(log.bearings[hits] > 0)
    # Every return, placed at its converted bearing, lies on the wall y = +1.
    r, phi = log.ranges[0, hits], log.bearings[hits]
    np.testing.assert_allclose(r * np.sin(phi), wall_y, atol=1e-5)


def test_logged_increments_reach_last_odom_before_next_scan(tmp_path: Path) -> None:
    log = read_carmen(write(tmp_path, SMALL_LOG))
    inc = logged_increments(log)
    assert inc.shape == (1, 3)
    np.testing.assert_allclose(inc[0], increments_between(np.array(P0), np.array(O1)))
    np.testing.assert_allclose(predict_pose(np.array(P0), inc[0]), O1, atol=1e-12)
    # The dead-reckoned pose of scan 1 is the odometry pose O1, not the corrected P1.
    poses = integrate_increments(log.poses[0], inc)
    np.testing.assert_allclose(poses[1], O1, atol=1e-12)


def test_logged_increments_without_odom_between_scans_raise(tmp_path: Path) -> None:
    lines = [ln for ln in SMALL_LOG.splitlines() if not ln.startswith("ODOM")]
    log = read_carmen(write(tmp_path, "\n".join(lines)))
    with pytest.raises(CarmenFormatError, match="no ODOM between scans 0 and 1") as err:
        logged_increments(log)
    assert err.value.line == int(log.scan_lines[1])


def test_intel_log_parses(intel: CarmenLog) -> None:
    assert intel.num_scans == 910 and intel.num_beams == 180
    assert intel.skipped == {"NEFF": 910}
    assert intel.lidar_offset == (0.0, 0.0, 0.0)
    np.testing.assert_allclose(np.rad2deg(intel.bearings), np.arange(89.0, -91.0, -1.0))
    # First scan against its raw text: line 175, ranges reversed, pose at the end.
    with gzip.open(INTEL, "rt") as fh:
        first = next(line for line in fh if line.startswith("FLASER")).split()
    raw = np.array(first[2:182], dtype=float)
    assert intel.scan_lines[0] == 175
    np.testing.assert_allclose(intel.ranges[0], np.where(raw >= 81.0, intel.max_range, raw)[::-1])
    np.testing.assert_allclose(intel.poses[0], np.array(first[182:185], dtype=float))
    # README: sentinel 81.83, real readings 0.23 .. 25.4 m.
    assert intel.no_return_threshold == pytest.approx(0.999 * SENTINEL)
    np.testing.assert_array_equal(intel.no_return, intel.ranges >= 81.0)
    assert intel.ranges[~intel.no_return].max() == pytest.approx(25.38)
    assert intel.ranges.min() == pytest.approx(0.23)
    # README: duration 2651 s (the FLASER timestamps go back slightly at 4 scans).
    assert intel.times[-1] - intel.times[0] == pytest.approx(2651.0, abs=1.0)


def test_intel_logged_odometry_matches_readme(intel: CarmenLog) -> None:
    """README: per-step error about 0.07 m and 3.5 deg RMS; dead reckoning ATE 25.8 m."""
    inc = logged_increments(intel)
    assert inc.shape == (909, 3)
    predicted = np.array([predict_pose(intel.poses[k], inc[k]) for k in range(909)])
    step_pos = np.sqrt(np.mean(np.sum((predicted[:, :2] - intel.poses[1:, :2]) ** 2, axis=1)))
    step_heading = heading_rmse(predicted, intel.poses[1:])
    assert 0.06 < step_pos < 0.08
    assert 3.0 < np.rad2deg(step_heading) < 4.0
    dead = integrate_increments(intel.poses[0], inc)
    assert position_ate_rmse(dead[1:], intel.poses[1:]) == pytest.approx(25.8, abs=0.1)


def test_synthetic_increments_without_noise_reproduce_poses(intel: CarmenLog) -> None:
    inc = synthetic_increments(intel, seed=0, alphas=(0.0, 0.0, 0.0, 0.0))
    poses = integrate_increments(intel.poses[0], inc)
    np.testing.assert_allclose(poses[:, :2], intel.poses[:, :2], atol=1e-9)
    np.testing.assert_allclose(wrap_angle(poses[:, 2] - intel.poses[:, 2]), 0.0, atol=1e-9)


def test_synthetic_noise_follows_the_model(intel: CarmenLog) -> None:
    a1, a2, a3, a4 = alphas = (0.01, 0.005, 0.005, 0.001)
    true = synthetic_increments(intel, seed=0, alphas=(0.0, 0.0, 0.0, 0.0))
    noisy = synthetic_increments(intel, seed=7, alphas=alphas)
    np.testing.assert_array_equal(noisy, synthetic_increments(intel, seed=7))  # default alphas
    np.testing.assert_array_equal(
        noisy, synthetic_increments(intel, seed=np.random.default_rng(7), alphas=alphas)
    )
    assert not np.allclose(noisy, synthetic_increments(intel, seed=8))
    rot1, trans, rot2 = true.T
    var = np.stack(
        [
            a1 * rot1**2 + a2 * trans**2,
            a3 * trans**2 + a4 * (rot1**2 + rot2**2),
            a1 * rot2**2 + a2 * trans**2,
        ],
        axis=1,
    )
    z2 = (noisy - true) ** 2 / var
    # 3 x 909 unit chi-square draws: mean 1 with standard error ~0.027.
    assert abs(z2.mean() - 1.0) < 0.15
    # The first step's draws are the generator's first three normals, in order.
    expected = np.random.default_rng(7).standard_normal(3)
    np.testing.assert_allclose((noisy[0] - true[0]) / np.sqrt(var[0]), expected)
    with pytest.raises(ValueError, match="alphas"):
        synthetic_increments(intel, seed=0, alphas=(0.1, -0.1, 0.0, 0.0))


# ---------------------------------------------------------------------------- writing

BEAMS = np.linspace(np.pi / 2, -np.pi / 2, 181)  # the simulator's lidar: +90 .. -90 deg


def _episode(steps: int = 6) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Ranges of a closed room (no beam without return), true poses and odometry poses.

    Step 3 (from 4 scans on) drives backwards: its odometry increment has a negative
    translation.
    """
    rng = np.random.default_rng(4)
    increments = [np.array([0.05, 0.2, -0.02]) for _ in range(steps - 1)]
    if steps > 3:
        increments[2] = np.array([0.01, -0.15, 0.03])  # a reverse, as the simulator reports it
    odometry = [np.array([1.0, -2.0, 0.4])]
    for u in increments:
        odometry.append(predict_pose(odometry[-1], u))
    true = np.array(odometry) + rng.normal(0.0, 0.01, (steps, 3))
    ranges = rng.uniform(0.5, 9.0, (steps, BEAMS.size))
    return ranges, true, np.array(odometry), np.array(increments)


def test_a_written_log_reads_back_exactly(tmp_path: Path) -> None:
    """Ranges, poses and the odometry's increments, reverse included, survive the round trip."""
    ranges, true, odometry, increments = _episode()
    for name in ("episode.log", "episode.log.gz"):
        path = write_carmen(tmp_path / name, ranges, BEAMS, true, odometry, max_range=30.0)
        log = read_carmen(path)
        assert log.num_scans == 6 and log.num_beams == 181
        np.testing.assert_array_equal(log.ranges, ranges)
        np.testing.assert_array_equal(log.poses, true)
        np.testing.assert_array_equal(log.scan_odometry, odometry)
        np.testing.assert_allclose(log.bearings, BEAMS, atol=1e-12)
        # a closed room: no beam reaches the max range, and none is taken for "no return"
        assert log.max_range == 30.0 and log.no_return_threshold == 30.0
        assert not log.no_return.any()
        got = logged_increments(log)
        np.testing.assert_allclose(got, increments, atol=1e-12)
        assert got[2, 1] < 0.0 and abs(got[2, 0]) < np.pi / 2  # the reverse's own form


def test_a_beam_at_the_max_range_reads_as_no_return(tmp_path: Path) -> None:
    ranges, true, odometry, _ = _episode(2)
    ranges[1, 7] = 30.0
    log = read_carmen(write_carmen(tmp_path / "e.log", ranges, BEAMS, true, odometry, 30.0))
    assert np.flatnonzero(log.no_return[1]) == [7] and not log.no_return[0].any()
    # an explicit threshold still wins over the log's PARAM
    log = read_carmen(tmp_path / "e.log", CarmenConfig(no_return_threshold=8.0))
    assert log.no_return.sum() == (ranges >= 8.0).sum()


def test_the_recorder_writes_what_the_env_gave(tmp_path: Path) -> None:
    ranges, true, odometry, increments = _episode(4)
    recorder = CarmenRecorder(BEAMS, max_range=30.0, period=0.1)
    for k in range(4):
        recorder.add(ranges[k], true[k], odometry[k])
    assert len(recorder) == 4
    log = read_carmen(recorder.write(tmp_path / "r.log.gz"))
    np.testing.assert_array_equal(log.ranges, ranges)
    np.testing.assert_allclose(log.times, [0.0, 0.1, 0.2, 0.30000000000000004])
    np.testing.assert_allclose(logged_increments(log), increments[:3], atol=1e-12)


@pytest.mark.parametrize(
    ("change", "match"),
    [
        ({"ranges": np.full((2, 181), np.nan)}, "ranges must be finite"),
        ({"ranges": np.full((2, 181), 31.0)}, "within"),
        ({"ranges": np.ones(181)}, r"\(N, n\)"),
        ({"bearings": BEAMS[:-1]}, "bearings must have shape"),
        ({"bearings": BEAMS[::-1]}, "descending"),
        ({"bearings": BEAMS**3 / 3}, "evenly spaced"),
        ({"poses": np.full((2, 3), np.inf)}, "poses must be a finite"),
        ({"odometry_poses": np.zeros((3, 3))}, r"odometry_poses must be a finite \(2, 3\)"),
        ({"max_range": 0.0}, "max_range"),
        ({"period": -1.0}, "period"),
    ],
)
def test_writing_bad_input_raises_and_names_it(tmp_path: Path, change: dict, match: str) -> None:
    ranges, true, odometry, _ = _episode(2)
    args = {"ranges": ranges, "bearings": BEAMS, "poses": true, "odometry_poses": odometry}
    args |= {"max_range": 30.0, "period": 0.1} | change
    with pytest.raises(ValueError, match=match):
        write_carmen(tmp_path / "bad.log", **args)
    assert not (tmp_path / "bad.log").exists()


def test_the_recorder_refuses_bad_scans_and_an_empty_write(tmp_path: Path) -> None:
    recorder = CarmenRecorder(BEAMS, max_range=30.0)
    with pytest.raises(ValueError, match="nothing recorded"):
        recorder.write(tmp_path / "empty.log")
    with pytest.raises(ValueError, match="ranges must have shape"):
        recorder.add(np.ones(10), np.zeros(3), np.zeros(3))
    with pytest.raises(ValueError, match="odometry_pose must be a finite"):
        recorder.add(np.ones(181), np.zeros(3), np.array([0.0, np.nan, 0.0]))
    assert len(recorder) == 0  # nothing half-recorded


def test_a_bad_max_range_param_names_its_line(tmp_path: Path) -> None:
    text = SMALL_LOG.replace(
        "PARAM laser_front_laser_resolution", "PARAM laser_front_laser_max_range -3 x 0\nPARAM x"
    )
    with pytest.raises(CarmenFormatError, match="laser_front_laser_max_range must be finite"):
        read_carmen(write(tmp_path, text))


@pytest.mark.parametrize("name", ["laser_front_laser_resolution", "laser_front_laser_fov"])
def test_a_beam_geometry_param_that_is_no_number_is_named(tmp_path: Path, name: str) -> None:
    text = SMALL_LOG + f"\nPARAM {name} abc\n"  # the last occurrence counts
    with pytest.raises(CarmenFormatError, match=f"PARAM {name} must be a number, got 'abc'"):
        read_carmen(write(tmp_path, text))


def test_a_file_that_is_not_utf8_is_named(tmp_path: Path) -> None:
    path = tmp_path / "latin1.log"
    path.write_bytes(SMALL_LOG.encode("utf-8") + "PARAM robot caf\u00e9\n".encode("latin-1"))
    with pytest.raises(CarmenFormatError, match="latin1.log: not UTF-8 text"):
        read_carmen(path)
