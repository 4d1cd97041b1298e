"""Config values of the wrong type are refused when the config is built, naming the field.

Before these checks a JSON ``"false"`` counted as true, a string in a float field failed
deep inside numpy, and a malformed odometry tuple first failed inside a filter step
(after the motion update had moved the pose).
"""

import re

import numpy as np
import pytest

from vslam_gym.belief_reward import BeliefRewardConfig
from vslam_gym.config_utils import ConfigTypeError, check_field_types
from vslam_gym.shield import ShieldConfig
from vslam_gym.slam.config import SensorConfig
from vslam_gym.slam.filter import SlamConfig, VertexSLAM


@pytest.mark.parametrize(
    "section, name, bad, expected",
    [
        ("icp", "point_to_line", "false", "a bool"),
        ("filter", "create_beside_candidates", 0, "a bool"),
        ("model", "exclusive_boundaries", "no", "a bool"),
        ("matcher", "robust_scale", "0.05", "a number"),
        ("icp", "tol_translation", [1e-3], "a number"),
        ("model", "unknown_threshold", None, "a number"),
        ("filter", "prealign", 3, "a string"),
        ("filter", "loop_closure", "false", "a bool"),
        ("matcher", "fit_keyframe_points", 1, "a bool"),
    ],
)
def test_wrong_types_are_named(section, name, bad, expected):
    with pytest.raises(ConfigTypeError, match=re.escape(f"{name} must be {expected}, got {bad!r}")):
        SlamConfig.from_dict({section: {name: bad}})


@pytest.mark.parametrize(
    "name, bad",
    [
        ("odometry_alphas", "abc"),
        ("odometry_alphas", [0.01, 0.005, 0.005]),
        ("odometry_alphas", [float("nan")] * 4),
        ("odometry_sigma_floor", None),
        ("odometry_sigma_floor", [1e-3, -1e-3, 1e-3]),
        ("initial_pose_sigma", [-1e-4, 1e-4, 1e-5]),
    ],
)
def test_malformed_noise_tuples_are_refused_before_any_step(name, bad):
    size = 4 if name == "odometry_alphas" else 3
    with pytest.raises(ValueError, match=f"FilterConfig.{name} must be {size} finite numbers"):
        SlamConfig.from_dict({"filter": {name: bad}})


def test_json_lists_become_tuples_and_the_defaults_pass():
    config = SlamConfig.from_dict({"filter": {"odometry_alphas": [0.02, 0.01, 0.01, 0.002]}})
    assert config.filter.odometry_alphas == (0.02, 0.01, 0.01, 0.002)
    for preset in ("default", "thesis", "fast", "logs"):
        SlamConfig.preset(preset)  # every preset passes its own checks


@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({"fov_deg": 400.0}, "fov_deg must be at most 360"),
        ({"fov_deg": 90.0, "resolution_deg": 100.0}, "resolution_deg must be at most fov_deg"),
        ({"lidar_offset": ("a", 0, 0)}, "lidar_offset must be 3 finite numbers"),
        ({"max_range": "30"}, "max_range must be a number"),
    ],
)
def test_sensor_limits(kwargs, message):
    with pytest.raises(ValueError, match=message):
        SensorConfig(**kwargs)
    assert SensorConfig(fov_deg=360.0, resolution_deg=1.0).half_fov == pytest.approx(np.pi)


def test_other_configs_and_numpy_scalars():
    with pytest.raises(ConfigTypeError, match="BeliefRewardConfig.collision must be a number"):
        BeliefRewardConfig(collision="10")
    with pytest.raises(ConfigTypeError, match="ShieldConfig.margin must be a number"):
        ShieldConfig(margin="0.05")
    # numpy scalars are numbers and bools
    assert ShieldConfig(margin=np.float64(0.05)).margin == 0.05
    check_field_types(SlamConfig.from_dict({"icp": {"point_to_line": np.bool_(True)}}).icp)


def test_a_refused_config_never_reaches_a_filter():
    """The NaN alphas that used to fail at the first step (pose already moved) fail here."""
    with pytest.raises(ValueError, match="odometry_alphas"):
        VertexSLAM(SensorConfig(), SlamConfig.from_dict({"filter": {"odometry_alphas": [1] * 3}}))


@pytest.mark.parametrize(
    "data, message",
    [
        ({"filter": None}, "SlamConfig.filter must be a mapping of its fields, got None"),
        ({"model": "thesis"}, "SlamConfig.model must be a mapping"),
        ({"preset": ["thesis"]}, "SlamConfig.preset must be a name"),
        (["filter"], "a mapping of sections is needed"),
    ],
)
def test_sections_that_are_not_mappings(data, message):
    with pytest.raises(ValueError, match=re.escape(message)):
        SlamConfig.from_dict(data)


def test_filter_refuses_a_config_that_is_not_one():
    with pytest.raises(TypeError, match="config must be a SlamConfig"):
        VertexSLAM(SensorConfig(), "default")
    with pytest.raises(TypeError, match="sensor must be a SensorConfig"):
        VertexSLAM({"fov_deg": 180.0})
