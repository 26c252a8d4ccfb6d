"""IMU grade presets: the shipped files hold the datasheet values; draw_errors has their sigmas."""
import math

import numpy as np
import pytest

from imu_calib_ros.core.errors import ConfigError
from imu_calib_ros.core.imu_grade import draw_errors, load_grade

DEG = math.pi / 180.0
G0 = 9.80665


def test_nav_grade_values() -> None:
    g = load_grade('nav_grade')
    assert g.gyro_noise_rad_s_rt_hz == pytest.approx(0.002 * DEG / 60.0, rel=1e-6)  # deg/rt(h)
    assert g.accel_noise_m_s2_rt_hz == pytest.approx(5e-6 * G0, rel=1e-6)
    assert g.sigma.gyro_bias_rad_s == pytest.approx(0.01 * DEG / 3600.0, rel=1e-6)
    assert g.sigma.gyro_g_sensitivity == 0.0  # optical gyros
    assert 5e-6 <= g.sigma.gyro_scale <= 50e-6
    assert 10e-6 <= g.sigma.gyro_misalignment_rad <= 50e-6
    assert 5e-3 <= g.sigma.size_effect_m <= 20e-3


def test_mems_grade_values() -> None:
    g = load_grade('mems_mti1')
    assert g.gyro_noise_rad_s_rt_hz == pytest.approx(0.007 * DEG, rel=1e-6)
    assert g.gyro_bias_instability_rad_s == pytest.approx(10 * DEG / 3600.0, rel=1e-6)
    assert g.accel_noise_m_s2_rt_hz == pytest.approx(120e-6 * G0, rel=1e-6)
    assert g.accel_bias_instability_m_s2 == pytest.approx(0.03e-3 * G0, rel=1e-6)
    assert g.sigma.gyro_bias_rad_s == pytest.approx(0.2 * DEG, rel=1e-6)
    assert g.sigma.gyro_g_sensitivity == pytest.approx(0.001 * DEG / G0, rel=1e-6)


def test_bad_grade_files(tmp_path) -> None:
    p = tmp_path / 'g.yaml'
    p.write_text('imu_grade: {name: x, gyro_noise_rad_s_rt_hz: -1.0}\n')
    with pytest.raises(ConfigError, match='gyro_noise_rad_s_rt_hz'):
        load_grade(p)
    p.write_text('imu_grade: {name: x, sigma: {gyro_bias: 1.0}}\n')
    with pytest.raises(ConfigError, match='sigma.gyro_bias'):
        load_grade(p)
    with pytest.raises(ConfigError, match='no_such_grade'):
        load_grade('no_such_grade')


def test_draw_errors_structure_and_sigmas() -> None:
    g = load_grade('mems_mti1')
    rng = np.random.default_rng(3)
    draws = [draw_errors(g, rng) for _ in range(2000)]
    for e in draws[:20]:
        np.testing.assert_array_equal(e.gyro_scale_misalignment, e.gyro_scale_misalignment.T)
        np.testing.assert_array_equal(np.diag(e.size_effect_m), 0.0)
    n = len(draws)

    def check(values: np.ndarray, sigma: float) -> None:
        # sample std of m normal values: relative standard error 1/sqrt(2m); allow 5 of them
        m = values.size
        assert np.std(values) == pytest.approx(sigma, rel=5.0 / math.sqrt(2 * m))

    s = g.sigma
    check(np.array([e.gyro_bias_rad_s for e in draws]), s.gyro_bias_rad_s)
    kg = np.array([e.gyro_scale_misalignment for e in draws])
    check(kg[:, [0, 1, 2], [0, 1, 2]], s.gyro_scale)
    check(kg[:, [0, 0, 1], [1, 2, 2]], s.gyro_misalignment_rad)
    ka = np.array([e.accel_scale_misalignment for e in draws])
    off = ~np.eye(3, dtype=bool)
    check(ka[:, off], s.accel_misalignment_rad)
    check(np.array([e.accel_bias_m_s2 for e in draws]), s.accel_bias_m_s2)
    check(np.array([e.size_effect_m[off] for e in draws]), s.size_effect_m)
    assert n == 2000
    # the same seed gives the same errors
    a = draw_errors(g, np.random.default_rng(11)).as_vector()
    b = draw_errors(g, np.random.default_rng(11)).as_vector()
    np.testing.assert_array_equal(a, b)
