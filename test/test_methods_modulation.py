"""Rotation modulation (MEMS paper, seed 004): de-rotation removes constant X/Y biases."""
import numpy as np
import pytest

from imu_calib_ros.core.fixture import Fixture
from imu_calib_ros.core.methods import modulation
from imu_calib_ros.core.rotation import rot_axis_angle
from imu_calib_ros.core.types import ImuBatch, JointBatch

RATE_HZ = 100.0
SPIN_RAD_S = np.radians(150.0)
G = 9.81


def _fixture(axis):
    return Fixture.from_dict({'site': {'latitude_deg': 45.0, 'height_m': 0.0},
                              'joints': [{'name': 'spin', 'axis': list(axis)}],
                              'imu': {'rpy_deg': [0, 0, 0], 'xyz_m': [0, 0, 0]}})


def _data(axis, f_b, w_b, bias_f_s, bias_w_s, duration_s=30.0, sub=16):
    """Mean-over-interval IMU data of a body-fixed (f_b, w_b) seen by an IMU spinning about
    ``axis`` (IMU frame = body frame at angle 0), by oversampling (independent of the code's
    closed form)."""
    n = int(duration_s * RATE_HZ)
    t_sub = (np.arange(n * sub) + 0.5) / (RATE_HZ * sub)
    R_s_b = np.swapaxes(rot_axis_angle(np.asarray(axis, float), SPIN_RAD_S * t_sub), -1, -2)
    f_s = np.einsum('nij,j->ni', R_s_b, f_b).reshape(n, sub, 3).mean(axis=1) + bias_f_s
    w_s = (np.einsum('nij,j->ni', R_s_b, w_b).reshape(n, sub, 3).mean(axis=1)
           + SPIN_RAD_S * np.asarray(axis, float) + bias_w_s)
    stamps = (np.arange(1, n + 1) * 1e9 / RATE_HZ).astype(np.int64)
    js = np.arange(0, n + 1, 2)  # joint states at 50 Hz, wrapped to (-pi, pi]
    q = np.angle(np.exp(1j * SPIN_RAD_S * js / RATE_HZ))
    joints = JointBatch((js * 1e9 / RATE_HZ).astype(np.int64), ('spin',), q[:, None])
    return ImuBatch(stamps, w_s, f_s, 'imu'), joints


@pytest.mark.parametrize('axis', [(0, 0, 1), (1, 0, 0)])
def test_continuous_removes_perpendicular_bias(axis):
    axis = np.asarray(axis, float)
    f_b = np.array([0.3, -0.2, G])  # body-fixed specific force
    w_b = np.array([1e-3, -2e-3, 5e-4])
    bf = np.array([0.05, -0.08, 0.02])  # 5-8 mg biases in the sensor frame
    bw = np.array([3e-3, -2e-3, 1e-3])
    imu, joints = _data(axis, f_b, w_b, bf, bw)
    out = modulation.demodulate_continuous(imu, joints, _fixture(axis))
    assert len(out) == len(imu)
    P = np.eye(3) - np.outer(axis, axis)
    # perpendicular bias removed; axial bias stays (not modulated: paper eq. 9)
    exp_f = f_b + axis * (axis @ bf)
    exp_w = w_b + axis * (axis @ bw)
    # residual: the revolution mean sees the body signal only through the end clamps;
    # noise-free data, so the bound is the 1e-9 interpolation/rounding level
    np.testing.assert_allclose(out.accel_m_s2[50:-50], np.broadcast_to(exp_f, (len(out) - 100, 3)),
                               atol=1e-6)
    np.testing.assert_allclose(out.gyro_rad_s[50:-50], np.broadcast_to(exp_w, (len(out) - 100, 3)),
                               atol=1e-6)
    # without de-biasing the perpendicular bias would be a 1/1 sinusoid of |P bf|
    assert np.linalg.norm(P @ bf) > 1e4 * 1e-6


@pytest.mark.parametrize('mode,n', [('one', 1), ('two', 2), ('four', 4)])
def test_points_rate_and_bias(mode, n):
    axis = np.array([0.0, 0.0, 1.0])
    f_b = np.array([0.0, 0.0, G])
    bf = np.array([0.05, -0.08, 0.02])
    bw = np.array([3e-3, -2e-3, 1e-3])
    imu, joints = _data(axis, f_b, np.zeros(3), bf, bw)
    out = modulation.demodulate_points(imu, joints, _fixture(axis), mode)
    f_rot = SPIN_RAD_S / (2 * np.pi)
    dt = np.diff(out.stamps_ns) * 1e-9
    np.testing.assert_allclose(np.median(dt), 1 / (n * f_rot), rtol=0.02)
    # Body X/Y accel: bias removed; the residual is the specific force seen at the raw
    # sample's mid angle instead of the control point (half a sample, 0.75 deg): 0 here
    # because f_b is along the axis.
    np.testing.assert_allclose(out.accel_m_s2[:, :2], 0.0, atol=1e-6)
    np.testing.assert_allclose(out.accel_m_s2[:, 2], G + bf[2], atol=1e-9)
    np.testing.assert_allclose(out.gyro_rad_s[:, :2], 0.0, atol=1e-6)
    # platform rate removed from the axial gyro: what remains is its bias
    np.testing.assert_allclose(out.gyro_rad_s[:, 2], bw[2], atol=1e-6)


def test_continuous_after_a_gap_uses_the_nominal_period():
    """CONTRACT 1: the sample after a dropped stretch (0.3 s = 45 deg of spin) is the mean over
    its own nominal period only, so its joint-angle interval is one period of spin, not the
    gap's 45 deg (de-rotating over those would shrink it). Away from the gap (more than one
    revolution) the output is the noise-free one of the test above (1e-6)."""
    axis = np.array([0.0, 0.0, 1.0])
    f_b = np.array([0.3, -0.2, G])
    w_b = np.array([1e-3, -2e-3, 5e-4])
    bf = np.array([0.05, -0.08, 0.02])
    bw = np.array([3e-3, -2e-3, 1e-3])
    imu, joints = _data(axis, f_b, w_b, bf, bw, duration_s=20.0)
    keep = np.ones(len(imu), bool)
    keep[1000:1030] = False
    gapped = ImuBatch(imu.stamps_ns[keep], imu.gyro_rad_s[keep], imu.accel_m_s2[keep], 'imu')
    after = 1000  # index of the first sample after the gap in ``gapped``
    _, phi0, phi1, _ = modulation._setup(gapped, joints, _fixture(axis), None)
    np.testing.assert_allclose(phi1[after] - phi0[after], SPIN_RAD_S / RATE_HZ, rtol=1e-6)
    out = modulation.demodulate_continuous(gapped, joints, _fixture(axis))
    # the biases' revolution mean misses the lost 45 deg near the gap (the data is lost)
    rev = int(2 * np.pi / SPIN_RAD_S * RATE_HZ) + 5
    far = np.r_[50:after - rev, after + rev:len(out) - 50]
    np.testing.assert_allclose(out.accel_m_s2[far], np.broadcast_to(f_b + axis * (axis @ bf),
                                                                      (far.size, 3)), atol=1e-6)
    np.testing.assert_allclose(out.gyro_rad_s[far], np.broadcast_to(w_b + axis * (axis @ bw),
                                                                     (far.size, 3)), atol=1e-6)


def test_streaming_with_lost_samples_equals_offline_and_stays_near_the_full_data():
    """Bursts of lost IMU samples (10 %, 1-5 in a row) and joint states (up to 0.3 s): the
    streaming demodulator (the node's) equals the offline causal one on the same data, and
    at constant rate the accelerometers stay within 2 mg of the result without losses (a
    150 deg/s MEMS spin: the lost angles leave the revolution mean of a near-constant bias
    almost unchanged)."""
    import dataclasses
    from imu_calib_ros.core.fixture import load_fixture
    from imu_calib_ros.core.imu_grade import load_grade
    from imu_calib_ros.core.plans import build_profile, plan_from_dict
    from imu_calib_ros.core.simulator import SimConfig, simulate
    fx = load_fixture('three_axis')
    plan = plan_from_dict({'name': 'm', 'steps': [
        {'dwell': {'duration_s': 2}}, {'spin': {'joint': 'outer', 'rate_deg_s': 150,
                                               'duration_s': 30}}]})
    sim = simulate(fx, build_profile(plan, fx), load_grade('mems_mti1'),
                   SimConfig(imu_rate_hz=100, seed=7))
    imu, jb = sim.imu, sim.joints
    rng = np.random.default_rng(1)
    keep = np.ones(len(imu), bool)
    for s in rng.choice(len(imu) - 20, 110, replace=False):
        keep[s:s + rng.integers(1, 6)] = False
    keepj = np.ones(len(jb), bool)
    for s in rng.choice(len(jb) - 40, 100, replace=False):
        keepj[s:s + rng.integers(1, 30)] = False
    sub = dataclasses.replace(imu, stamps_ns=imu.stamps_ns[keep],
                              gyro_rad_s=imu.gyro_rad_s[keep], accel_m_s2=imu.accel_m_s2[keep])
    jsub = dataclasses.replace(jb, stamps_ns=jb.stamps_ns[keepj],
                               positions_rad=jb.positions_rad[keepj],
                               velocities_rad_s=None if jb.velocities_rad_s is None
                               else jb.velocities_rad_s[keepj])
    causal = modulation.DemodulationOptions(causal=True)
    full = modulation.demodulate(imu, jb, fx, causal)
    off = modulation.demodulate(sub, jsub, fx, causal)
    k = list(fx.joint_names).index('outer')
    q0 = jb.positions_rad[0].copy()
    q0[k] = 0.0
    d = modulation.StreamingDemodulator(fx.joint_axes_imu(q0)[k], 'outer', 'continuous')
    out, i, j = [], 0, 0
    while i < len(sub) or j < len(jsub):
        if j < len(jsub) and (i >= len(sub) or jsub.stamps_ns[j] <= sub.stamps_ns[i]):
            out += d.push_joint(jsub.sample(j))
            j += 1
        else:
            out += d.push_imu(sub.sample(i))
            i += 1
    assert d.counters['gaps'] > 50 and len(out) > 2000
    st = np.array([o.stamp_ns for o in out])
    io = np.searchsorted(off.stamps_ns, st)
    assert np.array_equal(off.stamps_ns[io], st)
    np.testing.assert_allclose([o.accel_m_s2 for o in out], off.accel_m_s2[io], rtol=0,
                               atol=1e-9)
    np.testing.assert_allclose([o.gyro_rad_s for o in out], off.gyro_rad_s[io], rtol=0,
                               atol=1e-9)
    # at constant rate (after the spin-up), interpolating the joint angle across the lost
    # joint states is exact: the losses leave the result near the loss-free one. (During
    # the spin-up and spin-down they cannot: the angle between joint states is then not
    # linear in time, and the platform rate taken from it is off.)
    t0 = imu.stamps_ns[0]
    steady = (st > t0 + 5_000_000_000) & (st < t0 + 29_000_000_000)
    jf = np.searchsorted(full.stamps_ns, st[steady])
    acc = np.array([o.accel_m_s2 for o in out])[steady]
    gyr = np.array([o.gyro_rad_s for o in out])[steady]
    assert np.abs(acc - full.accel_m_s2[jf]).max() < 2e-2
    # the horizontal gyro moves by up to 4e-4 rad/s (measured), more than the noise of the
    # lost samples explains: open (closing note), so not asserted here
    assert np.all(np.isfinite(gyr))


def test_bursts_of_lost_samples_leave_the_output_right_while_the_table_turns():
    """Issue 16 item 3, the cause: the bias of eq. 12 is the mean of the sensor-frame output
    over the last revolution; a lost stretch leaves the part turning with the platform
    (gravity across the axis, 9.8 m/s^2) out of balance, up to 2 sin(h/2) / (2 pi - h) of it
    for a hole of angle h. Inner axis horizontal, 150 deg/s, 7 % of the samples lost in
    bursts of 5-120 (up to 90 deg): with the plain mean 5010 of 10007 outputs were off the
    loss-free result by more than 0.01 m/s^2 (up to 5.5 m/s^2); the fitted bias keeps every
    one within 0.01 m/s^2. The bound: the fit's noise over a revolution with its holes,
    about 3 x 120 ug/sqrt(Hz) / sqrt(2.4 s) = 2.3e-3 m/s^2 at worst (measured largest
    4.6e-3 over 10,007 outputs)."""
    import dataclasses
    from imu_calib_ros.core.fixture import load_fixture
    from imu_calib_ros.core.imu_grade import load_grade
    from imu_calib_ros.core.plans import build_profile, plan_from_dict
    from imu_calib_ros.core.simulator import SimConfig, simulate
    fx = load_fixture('three_axis')
    plan = plan_from_dict({'name': 'm', 'steps': [
        {'dwell': {'duration_s': 2}},
        {'spin': {'joint': 'inner', 'rate_deg_s': 150, 'duration_s': 60}},
        {'dwell': {'duration_s': 2}}]})
    sim = simulate(fx, build_profile(plan, fx), load_grade('mems_mti1'),
                   SimConfig(imu_rate_hz=200, seed=7))
    imu, jb = sim.imu, sim.joints
    rng = np.random.default_rng(3)
    keep = np.ones(len(imu), bool)
    while (~keep).mean() < 0.07:
        s = rng.integers(0, len(imu) - 200)
        keep[s:s + rng.integers(5, 120)] = False
    sub = dataclasses.replace(imu, stamps_ns=imu.stamps_ns[keep],
                              gyro_rad_s=imu.gyro_rad_s[keep], accel_m_s2=imu.accel_m_s2[keep])
    opts = modulation.DemodulationOptions('continuous', joint='inner', causal=True)
    full = modulation.demodulate(imu, jb, fx, opts)
    lossy = modulation.demodulate(sub, jb, fx, opts)
    t0 = imu.stamps_ns[0]
    steady = (lossy.stamps_ns > t0 + 6_000_000_000) & (lossy.stamps_ns < t0 + 61_000_000_000)
    jf = np.searchsorted(full.stamps_ns, lossy.stamps_ns[steady])
    err = np.abs(lossy.accel_m_s2[steady] - full.accel_m_s2[jf]).max(axis=1)
    assert steady.sum() > 9000
    assert err.max() < 0.01, (int((err > 0.01).sum()), float(err.max()))
    # gyro: 3 x 1.2e-4 rad/s/sqrt(Hz) / sqrt(2.4 s) x 3 (holes, rotating terms) = 7e-4
    gerr = np.abs(lossy.gyro_rad_s[steady] - full.gyro_rad_s[jf]).max(axis=1)
    assert gerr.max() < 7e-4, float(gerr.max())
    # the streaming demodulator (the node's) withholds what covers < 75 % of a revolution
    k = list(fx.joint_names).index('inner')
    q0 = jb.positions_rad[0].copy()
    q0[k] = 0.0
    d = modulation.StreamingDemodulator(fx.joint_axes_imu(q0)[k], 'inner', 'continuous',
                                        min_coverage=0.75)
    out, i, j = [], 0, 0
    while i < len(sub) or j < len(jb):
        if j < len(jb) and (i >= len(sub) or jb.stamps_ns[j] <= sub.stamps_ns[i]):
            out += d.push_joint(jb.sample(j))
            j += 1
        else:
            out += d.push_imu(sub.sample(i))
            i += 1
    assert d.counters['lost_imu'] == int((~keep).sum())
    assert d.counters['fitted_after_loss'] > 3000  # measured 4368
    st = np.array([o.stamp_ns for o in out])
    io = np.searchsorted(lossy.stamps_ns, st)
    # the same fit; the normal equations' sums are added in another order (one sample at a
    # time against numpy's columns) and a window with a wide hole amplifies the rounding:
    # measured 1e-8 m/s^2 at most
    np.testing.assert_allclose([o.accel_m_s2 for o in out], lossy.accel_m_s2[io], rtol=0,
                               atol=1e-7)
