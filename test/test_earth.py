"""earth.py: WGS-84 normal gravity against published values, earth rate, Site validation."""
import math

import numpy as np
import pytest

from imu_calib_ros.core import earth
from imu_calib_ros.core.earth import EARTH_RATE_RAD_S, Site, normal_gravity_m_s2
from imu_calib_ros.core.errors import ConfigError


def test_normal_gravity_equator_and_poles() -> None:
    # TR8350.2 Table 3.3: gamma_e = 9.7803253359, gamma_p = 9.8321849378 m/s^2
    assert normal_gravity_m_s2(0.0, 0.0) == pytest.approx(9.7803253359, abs=1e-10)
    assert normal_gravity_m_s2(math.pi / 2, 0.0) == pytest.approx(9.8321849378, abs=1e-9)
    assert normal_gravity_m_s2(-math.pi / 2, 0.0) == pytest.approx(9.8321849378, abs=1e-9)
    # 45 deg, sea level: GRS80 gives 9.806199203 m/s^2; WGS-84's gamma_e is 1.4e-6 lower
    assert normal_gravity_m_s2(math.radians(45.0), 0.0) == pytest.approx(9.806199203, abs=2e-6)
    assert normal_gravity_m_s2(math.radians(45.0), 0.0) < 9.806199203


def test_free_air_gradient_and_second_order_term() -> None:
    lat = math.radians(55.7)
    h = np.array([-1.0, 0.0, 1.0]) * 1000.0
    g = normal_gravity_m_s2(lat, h)
    slope = (g[2] - g[0]) / 2000.0
    # normal free-air gradient ~ -0.3086 mGal/m = -3.086e-6 1/s^2 (varies ~0.1 % with latitude)
    assert slope == pytest.approx(-3.086e-6, rel=2e-3)
    # second order: g0 * 3 h^2 / a^2 -> second difference 6 g0 / a^2 per m^2
    second = (g[2] - 2 * g[1] + g[0]) / 1000.0 ** 2
    assert second == pytest.approx(6 * g[1] / earth.WGS84_A_M ** 2, rel=1e-3)


def test_site_properties() -> None:
    s = Site(55.7, 200.0)
    lat = math.radians(55.7)
    assert s.gravity == pytest.approx(normal_gravity_m_s2(lat, 200.0), abs=0)
    assert 9.81 < s.gravity < 9.82
    np.testing.assert_array_equal(s.g_enu, [0.0, 0.0, -s.gravity])
    np.testing.assert_allclose(np.linalg.norm(s.omega_ie_enu), EARTH_RATE_RAD_S, rtol=1e-15)
    assert s.omega_ie_enu[0] == 0.0
    assert s.omega_ie_enu[2] == pytest.approx(EARTH_RATE_RAD_S * math.sin(lat), rel=1e-15)
    assert s.omega_ie_enu[1] > 0  # the earth rate points north (and up in the north)
    measured = Site(55.7, 200.0, 9.8155)
    assert measured.gravity == 9.8155
    assert measured.normal_gravity == s.gravity


def test_site_from_dict_and_round_trip() -> None:
    s = Site.from_dict({'latitude_deg': -33.9, 'height_m': 15, 'gravity_m_s2': 9.796})
    assert (s.latitude_deg, s.height_m, s.gravity_m_s2) == (-33.9, 15.0, 9.796)
    assert Site.from_dict(s.to_dict()) == s
    assert Site.from_dict({'latitude_deg': 10, 'height_m': 0}).gravity_m_s2 is None


@pytest.mark.parametrize('d, key', [
    ({'latitude_deg': 91.0, 'height_m': 0.0}, 'site.latitude_deg'),
    ({'latitude_deg': -90.5, 'height_m': 0.0}, 'site.latitude_deg'),
    ({'latitude_deg': 10.0}, 'site.height_m'),
    ({'latitude_deg': 10.0, 'height_m': 0.0, 'gravity_m_s2': 9.5}, 'site.gravity_m_s2'),
    ({'latitude_deg': 10.0, 'height_m': 0.0, 'gravity_m_s2': 9.95}, 'site.gravity_m_s2'),
    ({'latitude_deg': 10.0, 'height_m': 0.0, 'longitude_deg': 3.0}, 'site.longitude_deg'),
    ({'latitude_deg': 'north', 'height_m': 0.0}, 'site.latitude_deg'),
    ({'latitude_deg': float('nan'), 'height_m': 0.0}, 'site.latitude_deg'),
    ({'latitude_deg': 10.0, 'height_m': 1e6}, 'site.height_m'),
])
def test_site_from_dict_refuses(d: dict, key: str) -> None:
    with pytest.raises(ConfigError) as ei:
        Site.from_dict(d, 'f.yaml')
    assert ei.value.key == key and ei.value.source == 'f.yaml'
    assert str(ei.value).startswith(f'f.yaml: {key}: ')
