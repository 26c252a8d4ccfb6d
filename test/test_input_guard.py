"""core.input_guard: each reason counted, gaps flagged, units detected, single == batch."""
from __future__ import annotations

import numpy as np
import pytest

from imu_calib_ros.core.fixture import load_fixture
from imu_calib_ros.core.input_guard import IMU_REASONS, GuardConfig, InputGuard

FX = load_fixture('three_axis')
G = FX.site.gravity
DT = 5_000_000  # 200 Hz


def guard(**kw) -> InputGuard:
    return InputGuard(GuardConfig(**kw), G, FX.joint_names, FX.joint_axes_enu)


def clean(n: int = 400) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    t = 10**18 + np.arange(1, n + 1, dtype=np.int64) * DT
    w = np.tile([1e-5, 2e-5, 7e-5], (n, 1))
    f = np.tile([0.0, 0.0, G], (n, 1))
    return t, w, f


def test_clean_data_is_all_accepted_and_single_equals_batch() -> None:
    t, w, f = clean()
    a = guard()
    assert a.check_imu(t, w, f).keep.all() and a.rejected_total == 0
    b = guard()
    assert all(b.check_imu(t[i:i + 1], w[i:i + 1], f[i:i + 1]).keep[0] for i in range(len(t)))
    assert a.nominal_period_ns == b.nominal_period_ns == DT


@pytest.mark.parametrize('single', [False, True])
def test_each_reason_counted_once(single: bool) -> None:
    t, w, f = clean()
    w[10] = np.inf
    w[20], f[20] = 0.0, 0.0
    f[30, 0] = 200.0
    f[40] = [0.0, 0.0, 1.0]
    f[50] = [0.0, 0.0, 2.0]
    t[60] = t[59]
    t[70] = t[68] + 1
    t[80] = t[79] - 3 * 10**9
    g = guard(frame_id='imu_link')
    if single:
        keep = np.array([g.check_imu(t[i:i + 1], w[i:i + 1], f[i:i + 1], 'imu_link').keep[0]
                         for i in range(len(t))])
    else:
        keep = g.check_imu(t, w, f, 'imu_link').keep
    assert list(np.nonzero(~keep)[0]) == [10, 20, 30, 40, 50, 60, 70, 80]
    expect = {'non_finite': 1, 'all_zero': 1, 'saturated': 1, 'accel_units_g': 1,
              'accel_magnitude': 1, 'duplicate_stamp': 1, 'out_of_order': 1,
              'time_jump_backward': 1}
    assert {k: v for k, v in g.rejected.items() if v} == expect
    assert g.check_imu(t[-1:] + DT, w[:1], f[:1], 'other').keep.sum() == 0
    assert g.rejected['frame_id'] == 1


def test_gaps_flagged_by_the_one_and_a_half_period_rule() -> None:
    t, w, f = clean(100)
    t[50:] += int(0.4 * DT)  # 1.4 periods: not a gap
    t[70:] += int(0.6 * DT)  # 1.6 periods: a gap
    t[90:] += 2 * 10**9  # a long gap
    g = guard(max_gap_s=1.0)
    v = g.check_imu(t, w, f)
    assert v.keep.all()
    assert g.flagged == {'gap': 2, 'long_gap': 1} and list(v.long_gaps) == [90]


def spin(rate_rad_s: float, n_joint: int = 200) -> tuple[np.ndarray, np.ndarray]:
    """Outer (vertical) joint spinning at a constant rate, joints at 100 Hz."""
    tj = 10**18 + np.arange(n_joint, dtype=np.int64) * 10_000_000
    q = np.zeros((n_joint, 3))
    q[:, 0] = rate_rad_s * (tj - tj[0]) * 1e-9
    return tj, q


@pytest.mark.parametrize('deg', [False, True])
def test_gyro_units_from_encoder_rate(deg: bool) -> None:
    tj, q = spin(0.5)
    g = guard()
    for ti, qi in zip(tj, q):
        assert g.check_joint(int(ti), FX.joint_names, qi) is not None
    t = 10**18 + 50_000_000 + np.arange(200, dtype=np.int64) * DT
    w = np.tile(FX.joint_axes_enu(np.zeros(3))[0] * 0.5, (200, 1))  # |w| = 0.5 rad/s
    if deg:
        w = np.degrees(w)
    f = np.tile([0.0, 0.0, G], (200, 1))
    v = g.check_imu(t, w, f)
    if deg:
        assert g.units_error is not None and 'deg/s' in g.units_error
        assert g.rejected['gyro_units_deg'] == 200 and not v.keep.any()
    else:
        assert g.units_error is None and v.keep.all() and g._ok_votes == 200  # noqa: SLF001


def test_accel_in_g_latches() -> None:
    t, w, f = clean(50)
    g = guard(units_latch_count=20)
    assert not g.check_imu(t, w, f / G).keep.any()
    assert g.units_error is not None and 'not m/s^2' in g.units_error


def test_joint_reasons() -> None:
    g = guard()
    names = FX.joint_names
    assert g.check_joint(10, ('x', 'y'), np.zeros(2)) is None
    assert g.check_joint(10, names, np.array([0.0, np.nan, 0.0])) is None
    q = g.check_joint(10, tuple(reversed(names)) + ('extra',), np.array([3.0, 2.0, 1.0, 9.0]))
    np.testing.assert_array_equal(q, [1.0, 2.0, 3.0])  # reordered to the fixture's order
    assert g.check_joint(10, names, np.zeros(3)) is None
    assert g.check_joint(5, names, np.zeros(3)) is None
    assert {k: v for k, v in g.rejected.items() if v} == {
        'joint_missing_names': 1, 'joint_non_finite': 1, 'joint_duplicate_stamp': 1,
        'joint_out_of_order': 1}
    assert g.unknown_joint_names == ('x', 'y')


def test_reason_names_are_stable() -> None:
    assert len(set(IMU_REASONS)) == len(IMU_REASONS)


def _bad_joint_stream(m: int = 600) -> tuple[np.ndarray, np.ndarray]:
    """Joint samples (fixture order) with NaN, duplicate, older, much older stamps and
    wrapped encoders."""
    rng = np.random.default_rng(3)
    t = 10**18 + np.arange(m, dtype=np.int64) * 10_000_000
    q = np.cumsum(rng.normal(0.0, 0.3, (m, 3)), axis=0)
    q = (q + np.pi) % (2 * np.pi) - np.pi  # wrapped to [-pi, pi)
    q[10, 1] = np.nan
    t[20] = t[19]
    t[30] = t[28]
    t[31] = t[27] - 5
    q[40] = np.inf
    t[41] = t[40]  # duplicate of a rejected (non-finite) sample: accepted
    return t, q


def test_joint_batch_equals_single_checks() -> None:
    t, q = _bad_joint_stream()
    names = tuple(reversed(FX.joint_names))
    q_msg = q[:, ::-1]  # message order differs from the fixture order
    a, b = guard(), guard()
    kept = [(int(ti), qa) for ti, qi in zip(t, q_msg)
            if (qa := a.check_joint(int(ti), names, qi)) is not None]
    tb, qb = np.zeros(0, np.int64), np.zeros((0, 3))
    for k in range(0, len(t), 77):  # uneven batches
        tk, qk = b.check_joint_batch(t[k:k + 77], names, q_msg[k:k + 77])
        tb, qb = np.concatenate([tb, tk]), np.vstack([qb, qk])
    assert a.rejected == b.rejected
    assert {k: v for k, v in b.rejected.items() if v} == {
        'joint_non_finite': 2, 'joint_duplicate_stamp': 1, 'joint_out_of_order': 2}
    np.testing.assert_array_equal(tb, [k[0] for k in kept])
    np.testing.assert_array_equal(qb, np.array([k[1] for k in kept]))
    # the encoder rates derived from the pending samples are the same too
    a._update_rates()
    b._update_rates()
    np.testing.assert_array_equal(a._rate_t, b._rate_t)
    np.testing.assert_array_equal(a._rate_v, b._rate_v)
    c = guard()
    assert len(c.check_joint_batch(t[:5], ('x', 'y', 'z'), q[:5])[0]) == 0
    assert c.rejected['joint_missing_names'] == 5 and c.unknown_joint_names == ('x', 'y', 'z')


def _receipt(n: int, period_ns: int, jitter_ns: int, drop: float, seed: int) -> np.ndarray:
    """Stamps of a periodic sender taken on receipt: U(0, jitter) late, increasing, with
    messages dropped at random."""
    rng = np.random.default_rng(seed)
    true = 10**18 + np.arange(1, n + 1, dtype=np.int64) * period_ns
    late = true + (rng.integers(0, jitter_ns, n) if jitter_ns else 0)
    us = np.arange(n, dtype=np.int64) * 1000
    stamps = np.maximum.accumulate(late - us) + us
    return stamps[rng.random(n) >= drop]


def test_stamps_whose_scatter_makes_the_stream_gaps_are_refused() -> None:
    """A 1 kHz IMU stamped on receipt 0-3 ms late with 0.5 % of its messages dropped: the
    stamps cannot be counted (StampClock gives up) and a third of the intervals exceed 1.5
    periods: CONTRACT 1 makes each such sample the mean over its own period only, and
    bridging one gap after another took the estimator 15+ minutes on a 10-minute bag. The
    guard latches one line naming the stamps and rejects the rest ('stamp_scatter'). The
    same stream with its stamps on the sender's clock (2 % dropped: gaps, regular) and the
    receipt stamps without drops (counted one per message) are not refused."""
    n = 120_000
    stamps = _receipt(n, 1_000_000, 3_000_000, 0.005, 1)
    w = np.tile([1e-5, 2e-5, 7e-5], (len(stamps), 1))
    f = np.tile([0.0, 0.0, G], (len(stamps), 1))
    g = guard()
    keep = np.concatenate([g.check_imu(stamps[i:i + 500], w[i:i + 500], f[i:i + 500]).keep
                           for i in range(0, len(stamps), 500)])
    assert g.imu_clock.irregular
    assert g.stamps_error is not None and 'stamped on receipt' in g.stamps_error
    assert g.rejected['stamp_scatter'] > 0 and not keep[-1000:].any()
    for stamps_ok in (_receipt(n, 1_000_000, 0, 0.02, 2), _receipt(n, 1_000_000, 2_000_000,
                                                                     0.0, 3)):
        g = guard()
        for i in range(0, len(stamps_ok), 500):
            g.check_imu(stamps_ok[i:i + 500], w[:len(stamps_ok[i:i + 500])],
                        f[:len(stamps_ok[i:i + 500])])
        assert g.stamps_error is None and g.rejected['stamp_scatter'] == 0
