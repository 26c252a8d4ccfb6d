"""The turntable driver's conversion of trajectory times to builtin_interfaces/Duration."""
import pytest

from imu_calib_ros.nodes.turntable_driver import duration_from_seconds


@pytest.mark.parametrize('t_s, sec, nanosec', [
    (2.9999999999, 3, 0),          # rounds up to a whole second: carries into sec
    (2.9999999994, 2, 999_999_999),
    (0.0, 0, 0),
    (1.5, 1, 500_000_000),
    (7.000000001, 7, 1),
    (12345.25, 12345, 250_000_000),
])
def test_duration_from_seconds(t_s, sec, nanosec):
    d = duration_from_seconds(t_s)
    assert (d.sec, d.nanosec) == (sec, nanosec)
