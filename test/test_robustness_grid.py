"""Issue 11 item 8: small versions of the robustness grid, each a failure of the old estimator.

Every case is a bag of the independent world (``imu_calib_ros.testing``: its own kinematics,
sensor model and bag writer, CONTRACT 1-3 only), run through the PLAIN command
``imu-calib replay BAG --fixture F --output C`` (no --imu, no --config). Each asserts that the
run exits 0 and is honest: every estimated parameter within 4 sigma of the truth (45 values:
one beyond 3 sigma is expected in about 11 % of honest runs), plus the figure the handling
is for (latency measured, noise measured, ...). Before issue 11 every one of these aborted
with "the estimator diverged" (checked on the old code: the grade prior was nav_grade's,
the start the nominal mounting, joint stamps taken as they come).
"""
from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from imu_calib_ros.cli import main
from imu_calib_ros.testing.world_cases import (CaseTruth, Comparison, compare_calibration,
                                               make_case)

# (id, make_case arguments, what the case is for)
CASES = [
    ('nav-raw-10deg', dict(unit='nav', size=1.0, mount_deg=10.0, offset_mm=50.0, seed=1),
     'raw navigation-grade errors (scale 1 %, misalignment 10 mrad), 10 deg mounting, 5 cm'),
    ('tactical-latency', dict(unit='tactical', size=1.0, mount_deg=3.0, latency_ms=30.0,
                              seed=2), 'joint stamps 30 ms late'),
    ('industrial-point', dict(unit='industrial_mems', size=1.0, sample_type='point',
                              seed=3), 'point samples read as interval means'),
    ('consumer-slow-joints', dict(unit='consumer_mems', size=1.0, mount_deg=5.0,
                                  joint_rate_hz=20.0, seed=4), '20 Hz joint states'),
    ('tactical-six-position-turns', dict(unit='tactical', size=1.0, mount_deg=2.0,
                                         plan='six_position_turns', imu_rate_hz=200.0,
                                         seed=5),
     'the common six-position + turns plan: turns at 60 deg/s after orient moves; the joint '
     'latency from the rate magnitudes alone was 1.7 +- 1.6 ms off (a milliradian of encoder '
     'attitude): 89 gated updates, refused'),
    ('industrial-1khz', dict(unit='industrial_mems', size=1.0, mount_deg=5.0, offset_mm=40.0,
                             plan='six_position_turns', imu_rate_hz=1000.0, seed=6),
     'a 1 kHz MEMS IMU: omega_dot from neighbouring samples drowned the size effect in '
     'noise with a 4 cm lever arm (size effect 4.4 sigma off; 2.0 over +-5 ms)'),
    ('nav-1khz-joints', dict(unit='nav', size=1.0, mount_deg=3.0, joint_rate_hz=1000.0,
                             encoder_noise_rad=20e-6, imu_rate_hz=200.0, seed=7),
     'joint states at 1 kHz with 20 urad of encoder noise: the spline derivative\'s noise '
     '(0.03 rad/s) failed the "gyro rates do not follow the fixture" check'),
    ('industrial-static-6pos', dict(unit='industrial_mems', size=1.0, mount_deg=10.0,
                                    plan='static_6pos', seed=8),
     'six poses joined by quick 90-180 deg moves: the latency fitted once through a gyro fit '
     'made at the magnitudes\' 14 ms was still 4.4 ms off (gated updates, re-alignments)'),
    ('industrial-g-sensitivity', dict(unit='industrial_mems', size=1.0, mount_deg=4.0,
                                      plan='savage_srt', seed=7),
     'a raw MEMS gyro\'s G of ~300 deg/h/g on a 90 mg accelerometer bias: the coarse gyro fit '
     'took G on the raw accelerometer outputs, a start 28 deg/h and 9 deg/h/g off held by its '
     'fit\'s sigma (G 6.7 sigma off at the end, the true noise model\'s run alike)'),
    ('industrial-dropped-samples', dict(unit='industrial_mems', size=1.0, mount_deg=4.0,
                                        plan='savage_srt', drop_fraction_imu=0.02, seed=7),
     '2 % of the IMU samples lost in bursts (a driver dropping messages): window means across '
     'a gap moved the latency by 0.64 ms and each gap during a turn re-initialised the '
     'navigation (size effect 9 sigma off; with gated updates refused on other seeds)'),
    ('nav-encoder-zeros', dict(unit='nav', size=1.0, mount_deg=2.0, plan='savage_srt',
                               encoder_zero_rad=(4e-3, 3e-3, -2e-3), seed=8),
     'the table\'s encoder zeros 2-4 mrad off: the coarse start\'s fits took the middle zero '
     'for sensor errors, the first outer-axis turn gated 8 updates and the run was refused '
     '(every value within 2.6 sigma); the zeros are now fitted on the windows\' gravity'),
    ('industrial-encoder-zeros', dict(unit='industrial_mems', size=1.0, mount_deg=3.0,
                                      plan='savage_srt', encoder_zero_rad=(8e-3, -6e-3, 5e-3),
                                      seed=9),
     'the table\'s encoder zeros 5-8 mrad off (a fixture file knows none of it): with encoder '
     'attitude aiding the filter took the zeros for sensor errors, diverged three times and '
     'ended 109 sigma off in gyro bias; the zeros are now states there'),
    ('consumer-lever-arm-gyro-noise',
     dict(unit='consumer_mems', size=0.2, mount_deg=1.0, offset_mm=35.0, plan='savage_srt',
          fixture='savage_2axis', seed=1,
          unit_noise=dict(accel_noise_m_s2_rt_hz=1.6e-4, accel_quantum=0.0,
                          gyro_bias_instability_rad_s=0.0, accel_bias_instability_m_s2=0.0)),
     'a MEMS gyro (1.8e-3 rad/s per two samples) and a 35 mm lever arm: the lever arm\'s '
     'velocity took the gyros\' rate at the chunk end, whose noise is also the boundary term '
     'of the size effect\'s omega_dot regressor; the shared noise biased the size effect by '
     '~2 mm (57 sigma with this unit\'s quieter accelerometers), refused. The encoders\' rate '
     'now weighs in by the two noises'),
    ('nav-imu-receipt-stamps', dict(unit='nav', size=1.0, mount_deg=3.0, imu_rate_hz=200.0,
                                    seed=11, imu_stamp_jitter_s=2e-3),
     'IMU stamps taken on receipt, U(0, 2 ms) late: refused (23 of 1,794 updates gated) '
     'before core.stamp_clock put them back on the IMU\'s clock'),
    ('nav-joint-receipt-stamps', dict(unit='nav', size=1.0, mount_deg=3.0, seed=12,
                                      joint_stamp_jitter_s=1e-3),
     'joint states stamped on receipt, U(0, 1 ms) late at 100 Hz: encoder rates 5 % off, '
     'refused as "the gyro rates do not follow the fixture\'s joint rotations"'),
    ('nav-joint-receipt-half-period', dict(unit='nav', size=1.0, mount_deg=3.0, seed=13,
                                           joint_stamp_jitter_s=5e-3),
     'joint states stamped on receipt, U(0, 5 ms) late at 100 Hz (half a period: rounding '
     'intervals cannot count the periods), with the table turning while the clock learnt: '
     'refused as "the gyro rates do not follow the fixture\'s joint rotations"'),
    ('industrial-1khz-receipt-stamps', dict(unit='industrial_mems', size=1.0, mount_deg=5.0,
                                            plan='six_position_turns', imu_rate_hz=1000.0,
                                            imu_stamp_jitter_s=2e-3, seed=14),
     'a 1 kHz IMU stamped on receipt, U(0, 2 ms) late (two periods): every late interval a '
     '"gap", bridged one by one (a 10-minute bag ran 8+ minutes before it was killed)'),
    ('tactical-slow-joint-receipt-drops',
     dict(unit='tactical', size=0.2, mount_deg=3.0, joint_rate_hz=14.4, imu_rate_hz=200.0,
          joint_stamp_jitter_s=0.036, drop_fraction_joint=0.05, seed=15),
     '14.4 Hz joint states stamped on receipt, U(0, 36 ms) late (half a period), 5 % of them '
     'dropped in bursts: no learnt window free of drops, the clock gave up ("the gyro rates '
     'do not follow the fixture\'s joint rotations", 25 % left); counted by phase, a later '
     'pass still navigated the first 40 s on the stamps as given (177 updates gated, '
     'refused) until the passes shared the first one\'s revisions'),
    ('nav-1khz-joint-receipt-drops',
     dict(unit='nav', size=1.0, mount_deg=3.0, joint_rate_hz=1000.0, imu_rate_hz=200.0,
          joint_stamp_jitter_s=4.8e-3, drop_fraction_joint=0.03, seed=16),
     '1 kHz joint states stamped on receipt, U(0, 4.8 ms) late, 3 % dropped: the joint clock '
     'cannot count them and passes them as given; the coarse start\'s 10 ms groups left 3 % '
     'of the rates in timing noise: "the gyro rates do not follow the fixture\'s joint '
     'rotations", refused; groups now as long as the stamps\' scatter needs'),
    ('nav-1khz-joint-receipt-imu-drops',
     dict(unit='nav', size=1.0, mount_deg=3.0, joint_rate_hz=1000.0, imu_rate_hz=200.0,
          joint_stamp_jitter_s=4.8e-3, drop_fraction_joint=0.05, drop_fraction_imu=0.02,
          seed=17),
     'the same joint states with IMU samples lost in turns: the joint record held their stamps '
     'as given, several 1 ns apart with different angles, and the cubic spline through them '
     'swung by milliradians between two states; the motion bridges over the IMU gaps tilted '
     'the navigation by up to 0.14 rad (gated updates, re-alignments, a diverged run); the '
     'joint record now averages such states in groups'),
]


def _replay(bag: Path, fixture: Path, out: Path, capsys, *extra: str) -> str:
    rc = main(['replay', str(bag), '--fixture', str(fixture), '--output', str(out), '--quiet',
               *extra])
    err = capsys.readouterr().err
    assert rc == 0, err
    return err


def _calibrate(bag: Path, truth: CaseTruth, tmp_path: Path, capsys: Any,
               *extra: str) -> tuple[dict[str, Any], Comparison]:
    """The plain command on ``bag`` -> (the calibration file, its worst parameter)."""
    out = tmp_path / 'calib.yaml'
    _replay(bag, truth.fixture_path, out, capsys, *extra)
    calib = yaml.safe_load(out.read_text())
    rows = [r for r in compare_calibration(calib, truth.data) if not r.fixed]
    return calib, max(rows, key=lambda r: abs(r.z))


@pytest.mark.parametrize('name,kw,why', CASES, ids=[c[0] for c in CASES])
def test_plain_command_is_honest_on_a_world_unit(name: str, kw: dict, why: str,
                                                 tmp_path: Path, capsys) -> None:
    bag, truth = make_case(tmp_path, **kw)
    calib, worst = _calibrate(bag, truth, tmp_path, capsys)
    assert abs(worst.z) < 4.0, (why, worst)
    est = calib['imu_calibration']['estimator']
    cs = est['coarse_start']
    # the data chose the start: the mounting measured to a fraction of a degree
    assert abs(cs['mounting_deg'] - kw.get('mount_deg', 0.0)) < 0.3, cs
    # the joint latency measured (CONTRACT 1: up to +-50 ms) to 0.2 ms: 0.2 mrad of encoder
    # attitude at 1 rad/s, two of its sigmas (attitude_sigma_rad 1e-4); point samples read as
    # interval means describe the middle of the interval before their stamp: half a period
    # more latency, which the measurement takes up
    half = 0.5 / kw.get('imu_rate_hz', 100.0) if kw.get('sample_type') == 'point' else 0.0
    # joint stamps taken on receipt with delays over more than a period pass as given (no
    # clock can count them): their mean delay is a latency, somewhere within the delays
    jit = kw.get('joint_stamp_jitter_s', 0.0)
    late = jit if jit * kw.get('joint_rate_hz', 100.0) > 1.0 else 0.0
    lat = cs['joint_latency_s'] - kw.get('latency_ms', 0.0) * 1e-3 - half
    assert -2e-4 < lat < late + 2e-4, cs
    noise = truth.data['imu_calibration']['noise']
    # noise densities measured from the stationary windows (no grade given), within 20 %
    assert cs['gyro_noise_rad_s_rt_hz'] == pytest.approx(noise['gyro_noise_rad_s_rt_hz'],
                                                         rel=0.2)
    assert cs['accel_noise_m_s2_rt_hz'] == pytest.approx(noise['accel_noise_m_s2_rt_hz'],
                                                         rel=0.2)


def test_a_grade_the_data_contradict_is_named_in_one_line(tmp_path: Path, capsys) -> None:
    """A consumer MEMS bag given the navigation-grade hint: the tool says in one line that
    the data disagree (noise ~1000x), uses the measured noise, and still calibrates."""
    bag, truth = make_case(tmp_path, unit='consumer_mems', size=0.5, seed=5)
    out = tmp_path / 'calib.yaml'
    # --force: with nav-grade floors on what the data cannot measure, the run may fail its
    # self-check (issue 17); the warning line is what this test is about
    err = _replay(bag, truth.fixture_path, out, capsys, '--imu', 'nav_grade', '--force')
    lines = [ln for ln in err.splitlines() if 'disagree with the IMU grade nav_grade' in ln]
    assert len(lines) >= 1, err
    calib = yaml.safe_load(out.read_text())
    rows = [r for r in compare_calibration(calib, truth.data) if not r.fixed]
    assert np.isfinite([r.z for r in rows]).all()


def test_point_samples_declared_with_dropped_samples(tmp_path: Path, capsys) -> None:
    """Point samples declared as such (``imu_sample_type: point``), 2 % of them lost in
    bursts: their trapezoid means' noise is read as such (read as white noise, 55 % of the
    density: refused with NIS 1.7 per dof, with or without the drops)."""
    bag, truth = make_case(tmp_path, unit='industrial_mems', size=1.0, mount_deg=3.0,
                           sample_type='point', drop_fraction_imu=0.02, seed=3)
    cfg = tmp_path / 'point.yaml'
    cfg.write_text('imu_sample_type: point\n')
    calib, worst = _calibrate(bag, truth, tmp_path, capsys, '--config', str(cfg))
    assert abs(worst.z) < 4.0, worst
    # declared point samples: no half-period latency to take up
    assert abs(calib['imu_calibration']['estimator']['coarse_start']['joint_latency_s']) < 2e-4


def test_dropped_messages_during_turns_are_bridged(tmp_path: Path, capsys) -> None:
    """A driver that drops 2 % of the IMU messages and 5 % of the joint states in bursts of
    ~5 (a tactical unit at 200 Hz): every gap during a turn is carried across with the
    encoders. Re-initialising at each of them (the handling before) lost 43 % of this
    recording in 16 re-alignments; on the robustness grid's longer plans more than half,
    and the self-check refused 7 of 75 runs."""
    bag, truth = make_case(tmp_path, unit='tactical', size=1.0, mount_deg=3.0,
                           imu_rate_hz=200.0, drop_fraction_imu=0.02,
                           drop_fraction_joint=0.05, seed=11)
    calib, worst = _calibrate(bag, truth, tmp_path, capsys)
    assert abs(worst.z) < 4.0, worst
    health = calib['imu_calibration']['estimator']['health']
    assert health['gaps_bridged_in_motion'] > 20, health
    assert health['gaps_reinitialised'] == 0, health
    lost = calib['imu_calibration']['provenance']['self_check']['checks']['input.lost']
    assert lost['value'] < 0.05, lost  # the gaps themselves (~2 %), nothing more


#: a MEMS unit drifting far more than its white noise suggests: the consumer class's bias
#: instability (3-10 deg/h, 30-100 ug over ~100 s) with a tenth of its white noise (and no
#: quantization, which that little noise would no longer dither)
DRIFTING = dict(gyro_noise_rad_s_rt_hz=3e-5, accel_noise_m_s2_rt_hz=1.6e-4, gyro_quantum=0.0,
                accel_quantum=0.0)


@pytest.mark.parametrize('seed', [2, 3])
def test_a_drift_the_first_pass_did_not_assume_is_assumed_from_the_start(
        seed: int, tmp_path: Path, capsys) -> None:
    """Issue 11 item 5 across passes: the MEMS walk the plain command assumes (proportional
    to the white noise) is ~7x below this unit's in sigma. The stationary windows show it
    during the run and Q is raised there, but everything before was weighted with the small
    walk: in one pass, NEES 145 and 171 of 45 on these seeds, seed 2 written with an
    accelerometer asymmetry 5.0 sigma off, seed 3 refused by its self-check. The walk grew
    more than ``WALK_GROWTH``, so another pass assumes it from the coarse start."""
    bag, truth = make_case(tmp_path, unit='consumer_mems', size=1.0, mount_deg=3.0,
                           plan='savage_srt', unit_noise=DRIFTING, seed=seed)
    calib, worst = _calibrate(bag, truth, tmp_path, capsys)
    assert abs(worst.z) < 4.0, worst
    passes = calib['imu_calibration']['estimator']['passes']
    assert any('bias walk grew' in why for why in passes['extra_because']), passes


@pytest.mark.parametrize('unit,tilt_rad,seed', [('industrial_mems', 1e-2, 21),
                                                ('tactical', 1e-3, 21)])
def test_a_table_base_off_level_is_measured(unit: str, tilt_rad: float, seed: int,
                                            tmp_path: Path, capsys) -> None:
    """A table whose base stands 1-10 mrad off level (a bench, a desk; the fixture file says
    its first axis is in ENU): with encoder attitude aiding the tactical run was re-aligned
    8 times and refused, the MEMS one diverged ("state gyro_bias[2] beyond 50 prior
    sigmas"). The coarse start measures the tilt from the windows' gravity with the encoder
    zeros (within 4 of its sigmas) and the filter runs on the base as it stands: honest."""
    t = (0.6 * tilt_rad, -0.8 * tilt_rad)
    bag, truth = make_case(tmp_path, unit=unit, size=1.0, mount_deg=3.0, seed=seed,
                           imu_rate_hz=100.0 if 'mems' in unit else 200.0, plan='savage_srt',
                           base_tilt_rad=t)
    calib, worst = _calibrate(bag, truth, tmp_path, capsys)
    assert abs(worst.z) < 4.0, worst
    cs = calib['imu_calibration']['estimator']['coarse_start']
    err = np.array(cs['base_tilt_rad']) - np.array(t)
    assert np.all(np.abs(err) < 4.0 * np.array(cs['base_tilt_sigma_rad'])), cs


def test_a_base_tilt_the_windows_misjudge_is_refined_by_the_filter(tmp_path: Path,
                                                                  capsys) -> None:
    """A consumer MEMS unit on a lab's two-axis table whose outer axis points east, its base
    15 mrad off level (a desk). On the lab bench's case of this kind
    (``consumer_mems@equator_2axis_s0``) the windows' fit, whose model is the windows' alone,
    put the tilt about north 0.13 mrad off, 6 of its sigmas, and with the base fixed there
    the accelerometer bias ended 5.2 sigma off (NEES 137 over 45); with the tilt's residual
    as a state it passes (2.72). Here: the residual is a state under encoder aiding (about
    north only: about east is the outer joint's zero), the final tilt within 4 of its
    sigmas, the calibration honest."""
    from imu_calib_ros.testing import lab_motion
    from imu_calib_ros.testing.world_sim import (Mounting, WorldConfig, draw_unit,
                                                 simulate_to_files)
    fx = lab_motion.write_fixture('equator_2axis', tmp_path)
    rng = np.random.default_rng(31)
    unit = draw_unit('consumer_mems', 1.0, rng)
    tilt = (-13.3e-3, 6.3e-3)
    profile = lab_motion.lab_schedule(lab_motion.LAB_FIXTURES['equator_2axis'], 31)
    mounting = Mounting(np.radians([3.0, -4.0, 2.0]), np.array([0.01, -0.005, 0.0]))
    bag, truth_path, _ = simulate_to_files(tmp_path / 'case', fx, profile, unit, mounting,
                                           WorldConfig(base_tilt_rad=tilt), 31)
    out = tmp_path / 'calib.yaml'
    _replay(bag, fx, out, capsys)
    calib = yaml.safe_load(out.read_text())
    truth = yaml.safe_load(truth_path.read_text())
    rows = [r for r in compare_calibration(calib, truth) if not r.fixed]
    worst = max(rows, key=lambda r: abs(r.z))
    assert abs(worst.z) < 4.0, worst
    est = calib['imu_calibration']['estimator']
    names = est['joint_offset_joints']
    assert 'base tilt about north' in names  # (about east: the outer joint's zero)
    i = names.index('base tilt about north')
    assert abs(est['base_tilt_rad'][1] - tilt[1]) < 4.0 * est['joint_offset_sigma_rad'][i]


@pytest.mark.parametrize('unit,xyz_m', [('nav', (0.04, -0.027, 0.013)),
                                        ('tactical', (0.15, -0.10, 0.05))])
def test_an_imu_off_the_axes_under_kozlovs_oscillations(unit: str, xyz_m: tuple,
                                                        tmp_path: Path, capsys) -> None:
    """Kozlov's 90 deg heading oscillations (5 and 10 s) with the IMU 5 or 18 cm from the
    axes: the tangential ``omega_dot x rho`` (2.5 rad/s^2 x 18 cm) was missing from the
    table's specific-force regressor, so the poorly excited accelerometer scale's share of
    it fell on the size effect: the navigation unit refused (7 gated updates), the tactical
    one exited 0 with its size effect 5.6 sigma off. Both honest now."""
    src = Path(__file__).resolve().parents[1] / 'config' / 'fixtures' / 'three_axis.yaml'
    fx = tmp_path / 'off_axes.yaml'
    fx.write_text(src.read_text().replace('xyz_m: [0.0, 0.0, 0.0]',
                                          f'xyz_m: [{xyz_m[0]}, {xyz_m[1]}, {xyz_m[2]}]'))
    bag, truth = make_case(tmp_path, unit=unit, size=1.0, seed=17, plan='kozlov_oscillation',
                           fixture=str(fx))
    _, worst = _calibrate(bag, truth, tmp_path, capsys)
    assert abs(worst.z) < 4.0, worst
