"""The coarse gyro fit on noisy table encoders (session 22).

The fit regresses the gyros' window means on the encoders' rotation across each window
(``coarse.window_rates``). The encoders' noise at the window's two ends is a regressor error,
which pulls every scale factor towards zero by its variance over the rates' (regression
dilution): with 0.4 mrad of noise over 40 ms windows a consumer unit's scales came out
-200 to -350 ppm (about 2 of the fit's sigmas, all three the same way). Over
``FIT_WINDOW_S`` (0.2 s) that variance is 25 times smaller.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from imu_calib_ros.core.estimator import error_model as em
from imu_calib_ros.core.estimator.alignment import still_tolerance_rad
from imu_calib_ros.core.estimator.coarse import coarse_start
from imu_calib_ros.core.fixture import load_fixture
from imu_calib_ros.testing.world_cases import make_case
from msg_adapters.bag import read_bag


def _scales(tmp_path: Path, encoder_noise_rad: float, **kw: object
            ) -> tuple[np.ndarray, np.ndarray]:
    bag, truth = make_case(tmp_path / f'e{encoder_noise_rad:g}', mount_deg=3.0, size=1.0,
                           encoder_noise_rad=encoder_noise_rad, **kw)
    fx = load_fixture(str(truth.fixture_path))
    imu, js = read_bag(bag)
    q = np.unwrap(js.positions_rad[:, [js.names.index(n) for n in fx.joint_names]], axis=0)
    st = coarse_start(imu.stamps_ns, imu.gyro_rad_s, imu.accel_m_s2, js.stamps_ns, q, fx,
                      tol_rad=still_tolerance_rad(js.stamps_ns, q, 2.0, 1e-4))
    assert st is not None
    c = em.gyro_cols('gyro_scale')
    return st.theta_gyro[c], st.sigma_gyro[c]


def test_noisy_encoders_do_not_dilute_the_gyro_scales(tmp_path: Path) -> None:
    """The same IMU record with and without encoder noise (a consumer unit, 0.4 mrad, and an
    industrial one on savage_srt, 0.2 mrad): the scales' shifts in the noisy fit's sigmas
    average above -1 over the six axes (their mean's own scatter: 0.41; 40 ms windows gave
    -1.7, the 0.2 s windows -0.55)."""
    z = []
    for enc, kw in ((4e-4, dict(unit='consumer_mems', seed=21)),
                    (2e-4, dict(unit='industrial_mems', seed=68, plan='savage_srt',
                                fixture='savage_2axis'))):
        clean, _ = _scales(tmp_path, 0.0, **kw)
        noisy, sig = _scales(tmp_path, enc, **kw)
        z.extend((noisy - clean) / sig)
    assert float(np.mean(z)) > -1.0, np.round(z, 2)


def test_window_rates_are_the_mean_body_rate() -> None:
    """``window_rates`` against the mean of the nominal IMU frame's inertial rate over a
    0.2 s window, integrated finely from the joint motion: two joints turning at once (0.8
    and -0.6 rad/s, which cone) and the earth rate. Within 2e-7 rad/s (0.2 ppm of the
    rates); one rotation vector across the window with the earth rate at its end was off by
    the coning (~1e-3 rad/s here) and by the window's turn times the earth rate (~1e-5)."""
    from scipy.interpolate import CubicSpline

    from imu_calib_ros.core.estimator.coarse import window_rates
    fx = load_fixture('three_axis')
    rates = np.array([0.8, 0.0, -0.6])
    t = np.arange(0.0, 3.0, 0.01)
    spline = CubicSpline(t, 0.1 + t[:, None] * rates[None, :], axis=0)
    t_a = np.array([1.0, 1.37])
    t_b = t_a + 0.2
    got = window_rates(fx, spline, t_a, t_b, 0.0)
    for k in range(2):
        tt = np.linspace(t_a[k], t_b[k], 4001)
        q = 0.1 + tt[:, None] * rates[None, :]
        R = fx.R_enu_imu(q)
        axes = fx.angular_axes_enu(q)
        w_enu = np.einsum('nj,njk->nk', np.repeat(rates[None, :], len(tt), 0), axes)
        w_b = np.einsum('nki,nk->ni', R, w_enu + fx.site.omega_ie_enu)
        exact = np.trapezoid(w_b, tt, axis=0) / 0.2
        np.testing.assert_allclose(got[k], exact, atol=1e-6)
