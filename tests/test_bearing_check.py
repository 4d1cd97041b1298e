"""The bearing-convention check of a Carmen log, and the reader's bearing offset."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from _raycast import cast, polygon_edges

from vslam_gym.cli import main
from vslam_gym.logs import CarmenConfig, read_carmen
from vslam_gym.logs.bearing_check import bearing_offset_scores
from vslam_gym.replay import replay

# A 12 m x 8 m room with a pillar and an alcove: surfaces in several directions.
ROOM = [
    np.array(
        [
            [0.0, 0.0],
            [12.0, 0.0],
            [12.0, 8.0],
            [7.0, 8.0],
            [7.0, 6.5],
            [5.0, 6.5],
            [5.0, 8.0],
            [0.0, 8.0],
        ]
    )[::-1],
    np.array([[4.0, 3.0], [5.0, 3.0], [5.0, 4.0], [4.0, 4.0]]),
]
BEAMS = 180
TURNED_DEG = 1.0
"""The simulated lidar points this much counter-clockwise of Carmen's convention."""
SIGMA_RANGE = 0.005
"""Range noise [m] of the simulated returns."""


def room_log(
    tmp_path: Path, turned_deg: float, scans: int = 40, lidar_forward: float = 0.0
) -> Path:
    """A Carmen log driving a loop in the room; the lidar turned by ``turned_deg`` and
    ``lidar_forward`` [m] ahead of the robot origin (``robot_frontlaser_offset``)."""
    edges = polygon_edges(ROOM)
    carmen_deg = -90.0 + np.arange(BEAMS)  # right to left, as logged
    rng = np.random.default_rng(3)
    t = np.linspace(0.0, 2.0 * np.pi, scans, endpoint=False)
    lines = [
        "# message formats defined: PARAM ODOM FLASER",
        f"PARAM robot_frontlaser_offset {lidar_forward} nohost 0",
    ]
    for k, a in enumerate(t):
        pose = (6.0 + 3.5 * np.cos(a), 4.0 + 2.0 * np.sin(a), a + np.pi / 2)
        at = (pose[0] + lidar_forward * np.cos(pose[2]), pose[1] + lidar_forward * np.sin(pose[2]))
        ranges = cast(
            (*at, pose[2]), edges, np.deg2rad(carmen_deg + turned_deg), 30.0, SIGMA_RANGE, 0.0, rng
        )
        fields = " ".join(f"{r:.4f}" for r in ranges)
        p = f"{pose[0]:.6f} {pose[1]:.6f} {pose[2]:.6f}"
        lines.append(f"FLASER {BEAMS} {fields} {p} {p} {k}.0 host {k}.0")
        lines.append(f"ODOM {p} 0 0 0 {k}.0 host {k}.0")
    path = tmp_path / "room.log"
    path.write_text("\n".join(lines) + "\n")
    return path


def test_check_finds_the_lidar_turn(tmp_path: Path) -> None:
    log = read_carmen(room_log(tmp_path, TURNED_DEG))
    offsets = [-1.0, 0.0, 0.5, 1.0, 1.5, 2.0]
    scores = bearing_offset_scores(log, offsets, lag=2, stride=1)
    assert offsets[int(np.argmin(scores))] == TURNED_DEG
    # Off by a whole beam either way, the scans lie clearly further apart.
    assert scores[offsets.index(0.0)] > 1.5 * scores[offsets.index(1.0)]
    assert scores[offsets.index(2.0)] > 1.5 * scores[offsets.index(1.0)]


def test_check_moves_scans_by_the_lidar_poses(tmp_path: Path) -> None:
    log = read_carmen(room_log(tmp_path, TURNED_DEG, lidar_forward=0.5))
    assert log.lidar_offset == (0.5, 0.0, 0.0)
    offsets = [0.0, 1.0, 2.0]
    scores = bearing_offset_scores(log, offsets, lag=2, stride=1)
    assert offsets[int(np.argmin(scores))] == TURNED_DEG
    assert min(scores[0], scores[2]) > 1.5 * scores[1]


def test_reader_offset_turns_every_bearing(tmp_path: Path) -> None:
    path = room_log(tmp_path, TURNED_DEG, scans=6)
    plain = read_carmen(path)
    turned = read_carmen(path, CarmenConfig(bearing_offset_deg=TURNED_DEG))
    np.testing.assert_allclose(
        np.rad2deg(turned.bearings - plain.bearings), np.full(BEAMS, TURNED_DEG), atol=1e-12
    )
    np.testing.assert_array_equal(turned.ranges, plain.ranges)
    # Read with the offset, the poses agree with Carmen's convention again.
    scores = bearing_offset_scores(turned, [-1.0, 0.0, 1.0], lag=2, stride=1)
    assert int(np.argmin(scores)) == 1


def test_replay_takes_the_offset(tmp_path: Path) -> None:
    path = room_log(tmp_path, TURNED_DEG, scans=8)
    result = replay(path, preset="logs", bearing_offset_deg=TURNED_DEG)
    assert result["metrics"]["bearing_offset_deg"] == TURNED_DEG
    assert np.rad2deg(result["log"].bearings[0]) == pytest.approx(89.0 + TURNED_DEG)
    assert result["metrics"]["completed"]


def test_replay_command_takes_the_offset(tmp_path: Path) -> None:
    path = room_log(tmp_path, TURNED_DEG, scans=6)
    out = tmp_path / "out"
    argv = ["replay", str(path), "--bearing-offset-deg", str(TURNED_DEG), "--out", str(out)]
    assert main([*argv, "--preset", "logs", "--no-progress"]) == 0
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["bearing_offset_deg"] == TURNED_DEG and metrics["completed"]


@pytest.mark.parametrize("value", [float("nan"), float("inf")])
def test_reader_rejects_a_non_finite_offset(value: float) -> None:
    with pytest.raises(ValueError, match="bearing_offset_deg"):
        CarmenConfig(bearing_offset_deg=value)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"lag": 0}, "lag"),
        ({"stride": 0}, "stride"),
        ({"max_distance": 0.0}, "max_distance"),
        ({"max_range": float("nan")}, "max_range"),
        ({"offsets_deg": [0.0, float("nan")]}, "offsets_deg"),
    ],
)
def test_check_rejects_bad_arguments(tmp_path: Path, kwargs: dict, match: str) -> None:
    log = read_carmen(room_log(tmp_path, 0.0, scans=4))
    with pytest.raises(ValueError, match=match):
        bearing_offset_scores(log, **kwargs)


def test_check_without_pairs_is_nan(tmp_path: Path) -> None:
    log = read_carmen(room_log(tmp_path, 0.0, scans=4))
    assert np.isnan(bearing_offset_scores(log, [0.0], lag=10)).all()
