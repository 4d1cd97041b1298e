"""The README's Python examples run as written (a changed API must change the README too)."""

import re
from pathlib import Path

import numpy as np
import pytest

README = Path(__file__).resolve().parent.parent / "README.md"
FENCE = re.compile(r"^```python\n(.*?)^```", re.MULTILINE | re.DOTALL)


def _python_blocks() -> list[str]:
    return FENCE.findall(README.read_text(encoding="utf-8"))


def _block_with(text: str) -> str:
    blocks = [b for b in _python_blocks() if text in b]
    assert len(blocks) == 1, f"expected one README python block with {text!r}, got {len(blocks)}"
    return blocks[0]


def test_the_readme_has_the_examples_these_tests_run():
    assert len(_python_blocks()) >= 3


@pytest.mark.parametrize(
    "marker", ['"VSlam/LidarWorld-v0", world="house"', "VSlam/ExploreHouse-v0"]
)
def test_readme_environment_example_runs(marker):
    namespace: dict = {}
    exec(compile(_block_with(marker), "README.md", "exec"), namespace)
    frame = namespace["frame"]
    assert frame.dtype == np.uint8 and frame.ndim == 3 and frame.shape[2] == 3
    assert np.isfinite(namespace["reward"])
    assert not namespace["terminated"] and not namespace["truncated"]


def test_readme_estimator_example_runs_on_a_scan():
    from vslam_gym.slam.config import SensorConfig

    sensor = SensorConfig()
    bearings = np.linspace(sensor.half_fov, -sensor.half_fov, 181)  # left to right
    # the example's inputs: no motion, and a corner: walls 3 m ahead and 2 m to the left
    with np.errstate(divide="ignore"):
        ahead = np.where(np.cos(bearings) > 0, 3.0 / np.cos(bearings), np.inf)
        left = np.where(np.sin(bearings) > 0, 2.0 / np.sin(bearings), np.inf)
    ranges = np.minimum(np.minimum(ahead, left), sensor.max_range)
    namespace = {"odometry_increments": np.zeros(3), "ranges": ranges, "bearings": bearings}
    exec(compile(_block_with("VertexSLAM(SensorConfig()"), "README.md", "exec"), namespace)
    belief = namespace["belief"]
    assert belief.pose.shape == (3,) and belief.pose_cov.shape == (3, 3)
    assert len(belief.landmarks) >= 1
    assert belief.step_ms > 0.0
