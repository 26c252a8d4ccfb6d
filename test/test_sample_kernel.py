"""The sampling kernels: point samples read as interval means, found by the data.

A point sample read as the interval mean of CONTRACT 1 is larger by ``(omega dt)^2 / 24`` of
the gravity turning through the body, and a point-sampled gyro leaves the attitude
``alpha dt^2 / 24`` off through a ramp (error_model.sample_kernel_column). A navigation unit
at 100 Hz on ``demo_short`` (turns at 1.5-2 rad/s): before the kernels were states, the plain
command exited 0 with its accelerometer scales 2.6-6.6 sigma off, every one positive (seed 8:
x +6.6, y +3.7), and the declared ``imu_sample_type: point`` (the trapezoid of each sample and
the one before, kernel -2) was refused, 8-13 sigma the other way. The kernels are now states
(0 interval mean, 1 point), so the plain command calibrates the unit either way and each
kernel comes out where the samples are: 1 for point samples, 0 for means, -2 for the
declared point samples' trapezoids.
"""
from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest
import yaml

from imu_calib_ros.core.estimator import load_estimator_config
from imu_calib_ros.core.estimator.priors import kernel_note, sample_kernel_mean
from imu_calib_ros.core.estimator.replay import replay_run
from imu_calib_ros.core.fixture import load_fixture
from imu_calib_ros.testing.world_cases import compare_calibration, make_case
from msg_adapters.bag import iter_bag

#: (sample type the bag holds, imu_sample_type declared, the kernel the samples then have,
#: the kernels estimated)
CASES = {'point read as mean': ('point', 'mean', 1.0, True),
         # point samples of a 5 ms first-order low-pass (a MEMS part's digital filter): the
         # kernel's variance tau^2, s = 1 - 12 (5 / 10)^2 = -2; before the kernels were
         # states its accelerometer scales came out -13.7, -8.0, -8.6 sigma, exit 0
         'low-pass 5 ms read as mean': ('lowpass', 'mean', -2.0, True),
         'mean': ('interval_mean', 'mean', 0.0, True),
         'point declared': ('point', 'point', -2.0, True),
         # assumed at the declared type's, not estimated: the trapezoid's kernel applied
         'point declared, kernels assumed': ('point', 'point', -2.0, False)}


@pytest.mark.parametrize('case', list(CASES))
def test_the_kernels_are_found_and_the_scales_stay_honest(tmp_path: Path, case: str) -> None:
    sample_type, declared, kernel, estimated = CASES[case]
    bag, truth = make_case(tmp_path, unit='nav', seed=8, sample_type=sample_type,
                           **({'lowpass_tau_s': 5e-3} if sample_type == 'lowpass' else {}))
    cfg = dataclasses.replace(load_estimator_config(None), imu_sample_type=declared,
                              estimate_sample_kernel=estimated)
    run = replay_run(lambda: iter_bag(bag), load_fixture(str(truth.fixture_path)), None, cfg)
    assert run.verdict.passed, run.verdict.line
    est = run.estimator.estimate_state()
    sd = np.sqrt(np.diag(est.covariance))
    for name in ('gyro_sample_kernel[0]', 'accel_sample_kernel[0]') if estimated else ():
        k = est.labels.index(name)
        # the kernel the samples have, within 3 of its sigmas (0.16 for the gyros, 0.09 for
        # the accelerometers here: the kernels are 1 apart, so a point sample is never taken
        # for a mean)
        assert abs(est.values[k] - kernel) < 3.0 * sd[k], (name, est.values[k], sd[k])
        assert sd[k] < 0.3, (name, sd[k])
    out = tmp_path / 'calib.yaml'
    calib = run.estimator.estimate()
    calib.save(out)
    # the command names samples that are not what was declared, and only those
    note = kernel_note(calib.extra['estimator'], cfg)
    assert (note is not None) == (kernel != sample_kernel_mean(cfg)), note
    rows = [r for r in compare_calibration(yaml.safe_load(out.read_text()),
                                           yaml.safe_load(truth.path.read_text()))
            if not r.fixed and r.sigma > 0]
    z = {r.name: r.z for r in rows}
    # the accelerometer scales (6.6, 3.7 and 2.6 sigma off before, read as means) within 3
    # sigma, and no parameter of the 45 beyond 4 (chance 0.3 % with honest sigmas)
    scales = [v for n, v in z.items() if n.startswith('accel_scale')]
    assert len(scales) == 3 and max(map(abs, scales)) < 3.0, scales
    worst = max(z, key=lambda n: abs(z[n]))
    assert abs(z[worst]) < 4.0, (worst, z[worst])


def test_a_noisy_gyro_s_kernel_is_no_state(tmp_path: Path,
                                           monkeypatch: pytest.MonkeyPatch) -> None:
    """The gyros' kernel regressor is the samples' own second difference, whose noise the
    attitude shares: for a consumer MEMS gyro the kernel of interval means came out near +10
    (the grid's 14 consumer runs: +9.1..+11.6, sigma 0.3-0.7), and one run's gyro scale 4.9
    sigma off with exit 0. So it is a state only for gyros quieter than
    ``priors.gyro_kernel_estimable``; here the mechanism, and the rule keeping it out."""
    import imu_calib_ros.core.estimator.priors as priors
    bag, truth = make_case(tmp_path, unit='consumer_mems', seed=1)
    fx = load_fixture(str(truth.fixture_path))
    cfg = dataclasses.replace(load_estimator_config(None), walk_profile=False)
    run = replay_run(lambda: iter_bag(bag), fx, None, cfg)
    assert 'gyro_sample_kernel' in run.estimator.dropped_groups
    assert run.verdict.passed, run.verdict.line
    monkeypatch.setattr(priors, 'KERNEL_GYRO_SAMPLE_NOISE_RAD_S', math.inf)
    est = replay_run(lambda: iter_bag(bag), fx, None, cfg).estimator.estimate_state()
    k = est.labels.index('gyro_sample_kernel[0]')
    sd = math.sqrt(est.covariance[k, k])
    # interval means (truth 0), pulled beyond a point sample's 1 and far beyond the kernel's
    # own sigma (8.3 +- 0.84 here)
    assert est.values[k] > 1.0 and est.values[k] / sd > 5.0, (est.values[k], sd)


def test_which_gyros_have_a_kernel_state() -> None:
    """Per-sample noise at most 1e-4 rad/s: navigation gyros (0.6-1.5e-6 rad/s/sqrt(Hz)) at
    100 Hz to 2 kHz, not tactical ones (1.5-4.4e-5) nor MEMS, nor a gyro nobody measured."""
    from imu_calib_ros.core.estimator.priors import gyro_kernel_estimable
    for dt in (0.01, 0.005, 0.001, 0.0005):
        assert gyro_kernel_estimable(1.5e-6, dt)
    assert gyro_kernel_estimable(9e-6, 0.01) and not gyro_kernel_estimable(1.5e-5, 0.01)
    assert not gyro_kernel_estimable(1.5e-5, 0.005)
    assert not gyro_kernel_estimable(3.5e-5, 0.01)  # industrial MEMS
    assert not gyro_kernel_estimable(math.nan, 0.01)
    assert gyro_kernel_estimable(0.0, 0.01)  # noise-free synthetic data


def test_the_note_asks_for_the_type_where_a_kernel_was_assumed() -> None:
    """A quiet gyro's kernel says point samples, the accelerometers' (an arm's) was no
    state: the calibration does not hold by itself, and the line says so."""
    cfg = load_estimator_config(None)
    both = {'gyro_sample_kernel': 0.97, 'gyro_sample_kernel_sigma': [0.1],
            'accel_sample_kernel': 1.02, 'accel_sample_kernel_sigma': [0.09]}
    note = kernel_note(both, cfg)
    assert note is not None and note.endswith('so the calibration holds')
    one = {'gyro_sample_kernel': 0.97, 'gyro_sample_kernel_sigma': [0.1],
           'accel_sample_kernel': 0.0}
    note = kernel_note(one, cfg)
    assert note is not None and "accelerometers' kernel was not estimated" in note \
        and 'imu_sample_type' in note and 'holds' not in note
    # within 4 sigma of the declared type's: no line
    assert kernel_note({**both, 'gyro_sample_kernel': 0.3, 'accel_sample_kernel': 0.3}, cfg) \
        is None


def test_the_world_s_low_pass_is_the_closed_form() -> None:
    """The world's first-order filter (testing.world_sim._Lowpass) on a sinusoid against
    ``H = 1 / (1 + i omega tau)``: off by ``(h omega)^2 / 12`` of the signal for its
    sub-steps ``h`` (7.5e-7 here), its state carried across blocks, settled from the start
    on a constant input; and its samples' noise at low frequency the unit's density."""
    from imu_calib_ros.testing.world_sim import LOWPASS_SUBSTEPS, _Lowpass

    class Quiet:
        gyro_noise_rad_s_rt_hz = accel_noise_m_s2_rt_hz = 0.0

    tau, dt, w = 5e-3, 0.01, 6.0
    lp = _Lowpass(tau, dt, Quiet(), np.random.default_rng(0))

    def inst(t: np.ndarray):
        x = np.sin(w * t)[:, None] * np.ones((1, 3))
        return x, 2.0 * x, None, None

    y = np.vstack([lp(inst, k0, k0 + 500) for k0 in range(0, 3000, 500)])
    t = np.arange(1, 3001) * dt
    exact = np.imag(np.exp(1j * w * t) / (1.0 + 1j * w * tau))
    h = dt / LOWPASS_SUBSTEPS
    tol = (h * w) ** 2 / 12.0 * 1.5
    np.testing.assert_allclose(y[1000:, :3], exact[1000:, None] * np.ones(3), atol=tol)
    np.testing.assert_allclose(y[1000:, 3:], 2.0 * exact[1000:, None] * np.ones(3), atol=2 * tol)

    # the accelerometers' own filter (another delay than the gyros')
    lp2 = _Lowpass(tau, dt, Quiet(), np.random.default_rng(0), tau_accel_s=2e-3)
    y2 = np.vstack([lp2(inst, k0, k0 + 500) for k0 in range(0, 3000, 500)])
    exact2 = np.imag(np.exp(1j * w * t) / (1.0 + 1j * w * 2e-3))
    np.testing.assert_allclose(y2[1000:, :3], y[1000:, :3], rtol=0, atol=0)
    np.testing.assert_allclose(y2[1000:, 3:], 2.0 * exact2[1000:, None] * np.ones(3),
                               atol=2 * tol)

    def still(t: np.ndarray):  # settled on a constant: no step at the start
        c = np.ones((len(t), 3))
        return c, 9.8 * c, None, None

    y0 = _Lowpass(tau, dt, Quiet(), np.random.default_rng(0))(still, 0, 50)
    np.testing.assert_allclose(y0, np.repeat([[1.0] * 3 + [9.8] * 3], 50, axis=0), rtol=1e-12)

    class Noisy:
        gyro_noise_rad_s_rt_hz = accel_noise_m_s2_rt_hz = 1.0

    def zero(t: np.ndarray):
        return np.zeros((len(t), 3)), np.zeros((len(t), 3)), None, None

    for tau in (2e-3, 10e-3):  # a 2 ms filter at 100 Hz aliases 1.5x the density uncorrected
        lp = _Lowpass(tau, dt, Noisy(), np.random.default_rng(1))
        y = np.vstack([lp(zero, k0, k0 + 4000) for k0 in range(0, 160000, 4000)])
        M = 100  # the variance of 1 s means is N^2 / 1 s; 6 x 1600 of them: 1.8 % (1 sigma)
        n_est = math.sqrt(y.reshape(-1, M, 6).mean(axis=1).var(axis=0).mean() * M * dt)
        assert abs(n_est - 1.0) < 0.06, (tau, n_est)


def test_the_note_names_a_smoothing_filter_where_a_kernel_was_assumed() -> None:
    """A kernel below 0 (a sensor's own filter) with the other one assumed: no type to
    declare covers it (declaring point samples would stack the trapezoid's -2 on it)."""
    cfg = load_estimator_config(None)
    note = kernel_note({'gyro_sample_kernel': 0.0,
                        'accel_sample_kernel': -5.24, 'accel_sample_kernel_sigma': [0.91]}, cfg)
    assert note is not None and 'smoothing filter' in note and 'imu_sample_type: point' \
        not in note


def test_the_report_draws_no_truth_for_the_kernels() -> None:
    """The kernels are not CONTRACT 4 parameters: no truth line (a point-sample bag's is 1)."""
    from imu_calib_ros.core.sensor_model import SensorErrors
    from imu_calib_ros.report.builder import _truth_by_label

    class Truth:
        def tracked_truth(self) -> SensorErrors:
            return SensorErrors.from_vector(np.arange(45.0))

    got = _truth_by_label(Truth(), ['gyro_bias[0]', 'gyro_sample_kernel[0]',
                                    'accel_sample_kernel[0]', 'time_offset[0]',
                                    'lever_arm[0]', 'joint_offset[0]'])
    assert set(got) == {'gyro_bias[0]'}


def test_the_kernel_correction_and_columns_row_by_row(monkeypatch: pytest.MonkeyPatch) -> None:
    """``propagate_block`` against a row-by-row expectation, at 100 Hz (one row of history
    and look-ahead) and 1 kHz (five): every row the navigation takes, and every row the
    chunk ends' rates take, is the sample plus ``s (x[r+1] - 2 x[r] + x[r-1]) / 24``, except
    where that stencil touches a gap, a copied row or (declared point samples) the raw sample
    after a gap; the kernels' Jacobian columns are 0 on exactly those rows."""
    from imu_calib_ros.core.earth import Site
    from imu_calib_ros.core.estimator import error_model as em
    from imu_calib_ros.core.estimator import propagation as pr
    from imu_calib_ros.core.sensor_model import SensorErrors
    from imu_calib_ros.core.strapdown import Strapdown

    cap: dict[str, np.ndarray] = {}
    inst, acc, gyr = pr._instant_rates, em.accel_jacobian, em.gyro_jacobian

    def rates(w_c, w_rows, *a):  # type: ignore[no-untyped-def]
        cap['w_rows'] = w_rows.copy()
        return inst(w_c, w_rows, *a)

    def accel_cols(*a):  # type: ignore[no-untyped-def]
        cap['f2'] = a[4].copy()
        return acc(*a)

    def gyro_cols(*a):  # type: ignore[no-untyped-def]
        cap['w2'] = a[2].copy()
        return gyr(*a)

    monkeypatch.setattr(pr, '_instant_rates', rates)
    monkeypatch.setattr(em, 'accel_jacobian', accel_cols)
    monkeypatch.setattr(em, 'gyro_jacobian', gyro_cols)

    class Recorded(Strapdown):
        def propagate(self, dt, w, f):  # type: ignore[no-untyped-def]
            cap['w_c'], cap['f_c'] = np.array(w), np.array(f)
            return super().propagate(dt, w, f)

    site = Site(45.0, 0.0)
    lay = em.StateLayout.build(('gyro_bias', 'accel_bias', 'gyro_sample_kernel',
                                'accel_sample_kernel'))
    errors = SensorErrors.from_vector(np.zeros(45))
    rng = np.random.default_rng(0)
    sg, sa = 0.7, -1.3
    for rate in (100.0, 1000.0):
        dt = 1.0 / rate
        h, n, B = pr.omega_dot_half_span(dt), 10, 3
        m, N = B * n, B * n + 2 * pr.omega_dot_half_span(dt)
        for prev_none, ahead, trap in np.ndindex(2, 2, 2):
            for gaps in ((), (h + 7,), (h + 3, h + 12), (h - 1,), (h + m - 1,)):
                if prev_none and h - 1 in gaps:
                    continue
                step = int(dt * 1e9)
                t = np.arange(N, dtype=np.int64) * step + 10 ** 9
                for g in gaps:  # the interval after row g is a gap
                    t[g + 1:] += 3 * step
                x = rng.normal(size=(N, 6)) * 0.1 + [0, 0, 0.5, 0, 0, 9.8]
                if prev_none:
                    x[:h] = x[h]
                    t[:h] = t[h] - step * np.arange(h, 0, -1)
                if ahead:
                    x[h + m:] = x[h + m - 1]
                gap = np.zeros(N - 1, bool)
                gap[list(gaps)] = True
                real = np.ones(N, bool)
                real[:h] = not prev_none
                if ahead:
                    real[h + m:] = False
                raw = np.zeros(N, bool)  # the raw point sample after a gap, among trapezoids
                if trap:
                    raw[1:][gap] = True
                want = x.copy()
                for r in range(1, N - 1):
                    if real[r - 1:r + 2].all() and not (gap[r - 1] or gap[r]) \
                            and not raw[r - 1:r + 2].any():
                        d2 = x[r + 1] - 2 * x[r] + x[r - 1]
                        want[r] += np.r_[sg * d2[:3], sa * d2[3:]] / 24
                prev = None if prev_none else (t[:h], x[:h, :3], x[:h, 3:])
                pr.propagate_block(Recorded(site, np.eye(3)), errors, 0.0, prev, t[h:],
                                   x[h:, :3], x[h:, 3:], dt, B, n, lay, site.omega_ie_enu,
                                   table=True, ahead_repeated=bool(ahead), trapezoid=bool(trap),
                                   sample_kernel=(sg, sa))
                case = (rate, prev_none, ahead, trap, gaps)
                np.testing.assert_allclose(cap['w_c'], want[h:h + m, :3], atol=1e-12,
                                           err_msg=str(case))
                np.testing.assert_allclose(cap['f_c'], want[h:h + m, 3:], atol=1e-12,
                                           err_msg=str(case))
                np.testing.assert_allclose(cap['w_rows'].T[1:-1], want[1:-1, :3], atol=1e-12,
                                           err_msg=str(case))
                corrected = np.abs(want[h:h + m] - x[h:h + m]).max(axis=1) > 0
                assert np.array_equal(np.abs(cap['w2']).max(axis=1) > 0, corrected), case
                assert not np.any((np.abs(cap['f2']).max(axis=1) > 0) & ~corrected), case
