"""CONTRACT 1's gap rule in :func:`sample_intervals_ns`."""
import numpy as np
import pytest

from imu_calib_ros.core.types import sample_intervals_ns

T0 = 1_700_000_000_000_000_000  # absolute stamps: float64 would resolve only 256 ns


def test_gap_interval_becomes_the_nominal_one():
    d = np.array([0, 10, 20, 30, 45, 59, 100, 110]) * 1_000_000  # 10 ms nominal
    iv, gap = sample_intervals_ns(T0 + d)
    # 15 and 14 ms are <= 1.5 periods (kept as is); 41 ms follows a gap -> 10 ms
    np.testing.assert_array_equal(iv, np.array([10, 10, 10, 10, 15, 14, 10, 10]) * 1e6)
    np.testing.assert_array_equal(gap, [False] * 6 + [True, False])


def test_given_nominal_and_threshold():
    d = np.array([0, 1003, 2009, 5000], np.int64)
    iv, gap = sample_intervals_ns(T0 + d, nominal_ns=1000.0)
    np.testing.assert_array_equal(iv, [1000.0, 1003.0, 1006.0, 1000.0])  # exact ns
    np.testing.assert_array_equal(gap, [False, False, False, True])
    iv, gap = sample_intervals_ns(T0 + d, nominal_ns=1000.0, gap_periods=4.0)
    np.testing.assert_array_equal(iv, [1000.0, 1003.0, 1006.0, 2991.0])
    assert not gap.any()


def test_degenerate_lengths():
    iv, gap = sample_intervals_ns(np.zeros(0, np.int64))
    assert iv.shape == gap.shape == (0,)
    iv, gap = sample_intervals_ns(np.array([T0]), nominal_ns=5e6)
    np.testing.assert_array_equal(iv, [5e6])
    with pytest.raises(ValueError):
        sample_intervals_ns(np.array([T0]))
