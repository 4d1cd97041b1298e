import math

import numpy as np
import pytest

from vslam_gym.sim.odometry import OdometryModel, integrate_increments, wrap_angle

ALPHAS = (0.02, 0.01, 0.03, 0.004)


def test_wrap_angle_range():
    angles = np.array([-3 * math.pi, -math.pi, 0.0, math.pi, 2.5 * math.pi])
    wrapped = wrap_angle(angles)
    assert np.all(wrapped >= -math.pi) and np.all(wrapped < math.pi)
    np.testing.assert_allclose(np.cos(wrapped), np.cos(angles), atol=1e-12)
    assert wrap_angle(math.pi) == pytest.approx(-math.pi)
    assert isinstance(wrap_angle(1.0), float)


def test_forward_motion_increments():
    model = OdometryModel(alphas=ALPHAS)
    rot1, trans, rot2 = model.increments((1.0, 2.0, 0.0), (1.0 + math.sqrt(3), 3.0, 0.5))
    assert rot1 == pytest.approx(math.pi / 6)
    assert trans == pytest.approx(2.0)
    assert rot2 == pytest.approx(0.5 - math.pi / 6)


def test_backward_motion_gives_negative_translation_and_small_rotations():
    model = OdometryModel(alphas=ALPHAS)
    rot1, trans, rot2 = model.increments(
        (0.0, 0.0, 0.1), (-0.1 * math.cos(0.1), -0.1 * math.sin(0.1), 0.1)
    )
    assert trans == pytest.approx(-0.1)
    assert rot1 == pytest.approx(0.0, abs=1e-12)
    assert rot2 == pytest.approx(0.0, abs=1e-12)


def test_turn_on_the_spot_puts_the_rotation_into_rot2():
    model = OdometryModel(alphas=ALPHAS)
    rot1, trans, rot2 = model.increments((3.0, 4.0, 3.0), (3.0 + 1e-9, 4.0, -3.0))
    assert rot1 == 0.0
    assert trans == pytest.approx(1e-9)
    assert rot2 == pytest.approx(wrap_angle(-6.0))


def test_increments_and_integration_round_trip():
    model = OdometryModel(alphas=ALPHAS)
    rng = np.random.default_rng(0)
    for _ in range(200):
        start = np.array([*rng.uniform(-5, 5, 2), rng.uniform(-math.pi, math.pi)])
        end = np.array([*(start[:2] + rng.uniform(-0.3, 0.3, 2)), rng.uniform(-math.pi, math.pi)])
        increments = model.increments(start, end)
        assert abs(increments[0]) <= math.pi / 2 + 1e-12
        back = integrate_increments(start, increments)
        np.testing.assert_allclose(back[:2], end[:2], atol=1e-12)
        assert wrap_angle(back[2] - end[2]) == pytest.approx(0.0, abs=1e-12)


def test_noise_statistics_match_the_alphas():
    model = OdometryModel(alphas=ALPHAS)
    true = np.array([0.2, 0.5, -0.1])
    rng = np.random.default_rng(42)
    n = 40_000
    samples = np.array([model.sample(true, rng) for _ in range(n)])
    a1, a2, a3, a4 = ALPHAS
    rot1, trans, rot2 = true
    expected = np.array(
        [
            a1 * rot1**2 + a2 * trans**2,
            a3 * trans**2 + a4 * (rot1**2 + rot2**2),
            a1 * rot2**2 + a2 * trans**2,
        ]
    )
    errors = samples - true
    # Standard error of a sample variance is sqrt(2 / n) ~ 0.7 % here: allow 3 %.
    np.testing.assert_allclose(errors.var(axis=0), expected, rtol=0.03)
    np.testing.assert_array_less(np.abs(errors.mean(axis=0)), 4.0 * np.sqrt(expected / n))
    correlation = np.corrcoef(errors.T)
    assert np.all(np.abs(correlation[np.triu_indices(3, 1)]) < 4.0 / math.sqrt(n))
    np.testing.assert_allclose(model.standard_deviations(true), np.sqrt(expected))


def test_sample_draws_three_normals_even_without_motion():
    model = OdometryModel(alphas=ALPHAS)
    rng = np.random.default_rng(9)
    noisy = model.sample(np.zeros(3), rng)
    np.testing.assert_array_equal(noisy, np.zeros(3))
    twin = np.random.default_rng(9)
    twin.standard_normal(3)
    assert rng.standard_normal() == twin.standard_normal()


@pytest.mark.parametrize(
    "alphas", [(0.1, 0.1, 0.1), (-0.1, 0.0, 0.0, 0.0), (float("nan"), 0.0, 0.0, 0.0)]
)
def test_bad_alphas_raise(alphas):
    with pytest.raises(ValueError, match="alphas"):
        OdometryModel(alphas=alphas)


def test_bad_poses_raise():
    model = OdometryModel(alphas=ALPHAS)
    with pytest.raises(ValueError, match="pose_to"):
        model.increments((0.0, 0.0, 0.0), (1.0, float("inf"), 0.0))
    with pytest.raises(ValueError, match="shape"):
        model.increments((0.0, 0.0), (1.0, 0.0, 0.0))
