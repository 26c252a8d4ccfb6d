"""Issue 13 item 2: exports to Kalibr, OpenVINS, imu_calib and imu_tk, each proven by that
tool's own correction formula (written out here from its source) applied to raw samples."""
from __future__ import annotations

import numpy as np
import pytest
import yaml

from imu_calib_ros.core.calibration import CalibrationResult
from imu_calib_ros.core.exchange import export, import_text, not_held
from imu_calib_ros.core.sensor_model import SensorErrors, compensate, measure

RTOL = 1e-9


def _errors(rng: np.random.Generator, g_sens: bool = True) -> SensorErrors:
    """Large raw errors (percents, tens of mrad) in the part the models share."""
    kg = rng.normal(0, 0.02, (3, 3))
    return SensorErrors.zeros().replace(
        gyro_bias_rad_s=rng.normal(0, 0.01, 3), gyro_scale_misalignment=0.5 * (kg + kg.T),
        gyro_g_sensitivity_rad_s_per_m_s2=rng.normal(0, 1e-4, (3, 3)) * g_sens,
        accel_bias_m_s2=rng.normal(0, 0.1, 3),
        accel_scale_misalignment=rng.normal(0, 0.02, (3, 3)))


def _raw(errors: SensorErrors, rng: np.random.Generator, n: int = 200):
    """Raw outputs of random motion (rates to 3 rad/s, specific force to 2 g)."""
    w = rng.normal(0, 1.5, (n, 3))
    f = rng.normal(0, 10.0, (n, 3))
    gm, am = measure(errors, w, np.zeros_like(w), f)
    omega, force = compensate(errors, gm, am)
    return gm, am, omega, force


def _close(a, b) -> None:
    a, b = np.asarray(a), np.asarray(b)
    assert np.max(np.abs(a - b)) <= RTOL * np.max(np.abs(b))


def _is_rotation(R) -> None:
    R = np.asarray(R)
    assert np.allclose(R @ R.T, np.eye(3), atol=1e-12) and np.linalg.det(R) > 0


@pytest.fixture
def case():
    rng = np.random.default_rng(4)
    e = _errors(rng)
    return CalibrationResult.exact(e), _raw(e, rng)


def test_kalibr_formula_recovers_compensate(case) -> None:
    calib, (gm, am, omega, force) = case
    files, warn = export(calib, 'kalibr')
    d = yaml.safe_load(files[''])['imu0']
    assert d['model'] == 'scale-misalignment'
    M_a = np.array(d['accelerometers']['M'])
    M_g, A = np.array(d['gyroscopes']['M']), np.array(d['gyroscopes']['A'])
    C = np.array(d['gyroscopes']['C_gyro_i'])
    assert np.allclose(M_a, np.tril(M_a), atol=0) and np.allclose(M_g, np.tril(M_g), atol=0)
    _is_rotation(C)
    ours = d['imu_calib_ros']
    b_g, b_a, R_i_b = (np.array(ours[k]) for k in ('gyroscope_bias_rad_s',
                                                     'accelerometer_bias_m_s2', 'R_i_b'))
    _is_rotation(R_i_b)
    # Kalibr (IccScaledMisalignedImu): a = M (C_i_b f_b) + b_a ; w = M_g C_gyro_i w_i +
    # A C_gyro_i a_i + b_g  ->  f_i = M^-1 (a - b_a), w_i = C^T M_g^-1 (w - b_g - A C f_i)
    f_i = np.linalg.solve(M_a, (am - b_a).T).T
    w_i = (C.T @ np.linalg.solve(M_g, (gm - b_g - f_i @ (A @ C).T).T)).T
    _close(f_i, force @ R_i_b.T)
    _close(w_i, omega @ R_i_b.T)
    # Kalibr's file has no biases: named once; the frame i is within the misalignments of b
    assert warn == ('kalibr cannot hold gyroscope.bias, accelerometer.bias: dropped (Kalibr '
                    'estimates the biases itself (kept under imu_calib_ros); asymmetry, '
                    'quadratic and size effect have no place in its model)')
    assert np.degrees(np.arccos((np.trace(R_i_b) - 1) / 2)) < 5


@pytest.mark.parametrize('model', ['kalibr', 'rpng'])
def test_openvins_formula_recovers_compensate(case, model: str) -> None:
    calib, (gm, am, omega, force) = case
    files, _ = export(calib, 'openvins', openvins_model=model)
    text = files['']
    assert text.startswith('%YAML:1.0\n')  # OpenCV FileStorage wants its directive
    d = yaml.safe_load(text.split('\n', 1)[1])['imu0']
    assert d['model'] == model
    Tw, Ta, Tg = (np.array(d[k]) for k in ('Tw', 'Ta', 'Tg'))
    R_IMUtoGYRO, R_IMUtoACC = np.array(d['R_IMUtoGYRO']), np.array(d['R_IMUtoACC'])
    tri = np.tril if model == 'kalibr' else np.triu
    assert np.array_equal(Tw, tri(Tw)) and np.array_equal(Ta, tri(Ta))
    if model == 'kalibr':
        assert np.array_equal(R_IMUtoACC, np.eye(3))
    else:
        assert np.array_equal(R_IMUtoGYRO, np.eye(3))
    ours = d['imu_calib_ros']
    b_g, b_a, R_I_b = (np.array(ours[k]) for k in ('gyroscope_bias_rad_s',
                                                     'accelerometer_bias_m_s2', 'R_I_b'))
    # OpenVINS Propagator: Dw = Tw^-1, Da = Ta^-1, R_XtoIMU = R_IMUtoX^T
    #   a_I = R_ACCtoIMU Da (a - b_a) ; w_I = R_GYROtoIMU Dw (w - b_g - Tg a_I)
    Dw, Da = np.linalg.inv(Tw), np.linalg.inv(Ta)
    a_I = (R_IMUtoACC.T @ Da @ (am - b_a).T).T
    w_I = (R_IMUtoGYRO.T @ Dw @ (gm - b_g - a_I @ Tg.T).T).T
    _close(a_I, force @ R_I_b.T)
    _close(w_I, omega @ R_I_b.T)


def test_imu_calib_formula_recovers_compensate() -> None:
    rng = np.random.default_rng(5)
    e = _errors(rng).replace(gyro_scale_misalignment=np.zeros((3, 3)),
                             gyro_g_sensitivity_rad_s_per_m_s2=np.zeros((3, 3)))
    gm, am, omega, force = _raw(e, rng)
    files, warn = export(CalibrationResult.exact(e), 'imu_calib')
    d = yaml.safe_load(files[''])
    SM, bias = np.array(d['SM']).reshape(3, 3), np.array(d['bias'])  # row-major, as it reads
    # dpkoch/imu_calib AccelCalib::applyCalib: corrected = SM * raw - bias
    _close((SM @ am.T).T - bias, force)
    # apply_calib: the gyro bias it measured at start-up subtracted (the true one here)
    _close(gm - e.gyro_bias_rad_s, omega)
    assert warn is not None and 'gyroscope.bias' in warn
    full = _errors(rng)
    assert not_held(full, 'imu_calib') == ['gyroscope.g_sensitivity',
                                           'gyroscope.scale_misalignment', 'gyroscope.bias']


def test_imu_tk_formula_recovers_compensate() -> None:
    rng = np.random.default_rng(6)
    e = _errors(rng, g_sens=False)
    gm, am, omega, force = _raw(e, rng)
    files, warn = export(CalibrationResult.exact(e), 'imu_tk')
    assert warn is None
    for suffix, raw, want in (('_acc.calib', am, force), ('_gyro.calib', gm, omega)):
        # imu_tk CalibratedTriad::load reads 21 numbers with operator>>: T, K row-major, B
        nums = np.array(files[suffix].split('#')[0].split(), float)
        T, K, B = nums[:9].reshape(3, 3), nums[9:18].reshape(3, 3), nums[18:21]
        assert np.allclose(np.diag(T), 1.0) and np.array_equal(K, np.diag(np.diag(K)))
        # unbiasNormalize: X' = T K (X - B)
        _close((T @ K @ (raw - B).T).T, want)


def test_not_held_named_in_warning_and_file() -> None:
    rng = np.random.default_rng(7)
    e = _errors(rng).replace(gyro_scale_asymmetry=np.full(3, 1e-4),
                             accel_quadratic_per_m_s2=np.full(3, 1e-5),
                             size_effect_m=np.array([[0, 1e-3, 0], [0, 0, 0], [0, 0, 0]]))
    for fmt in ('kalibr', 'openvins', 'imu_calib', 'imu_tk'):
        files, warn = export(CalibrationResult.exact(e), fmt)
        assert warn is not None and '\n' not in warn
        for key in ('gyroscope.scale_asymmetry', 'accelerometer.quadratic',
                    'accelerometer.size_effect'):
            assert key in warn
        for text in files.values():
            assert f'# NOT HELD: {warn}' in text


@pytest.mark.parametrize('fmt', ['kalibr', 'openvins', 'imu_tk'])
def test_import_round_trip(case, fmt: str) -> None:
    calib, _ = case
    e = calib.errors if fmt != 'imu_tk' else calib.errors.replace(
        gyro_g_sensitivity_rad_s_per_m_s2=np.zeros((3, 3)))
    files, _ = export(CalibrationResult.exact(e), fmt)
    back, R_b_F = import_text(files, fmt, 'x')
    np.testing.assert_allclose(back.errors.as_vector(), e.as_vector(), rtol=0, atol=1e-12)
    assert back.extra['provenance']['imported_from']['format'] == fmt


def test_import_foreign_kalibr_file_compensates_like_kalibr() -> None:
    """A Kalibr result we did not write (C_gyro_i off identity, no biases): our compensate()
    of the imported calibration equals Kalibr's correction rotated into our frame b."""
    rng = np.random.default_rng(8)
    M_a = np.tril(np.eye(3) + rng.normal(0, 0.01, (3, 3)))
    M_g = np.tril(np.eye(3) + rng.normal(0, 0.01, (3, 3)))
    from scipy.spatial.transform import Rotation
    C = Rotation.from_rotvec([0.01, -0.02, 0.015]).as_matrix()
    A = rng.normal(0, 1e-4, (3, 3))
    text = yaml.safe_dump({'imu0': {'model': 'scale-misalignment',
                                    'accelerometers': {'M': M_a.tolist()},
                                    'gyroscopes': {'M': M_g.tolist(), 'A': A.tolist(),
                                                   'C_gyro_i': C.tolist()}}})
    calib, R_b_i = import_text({'': text}, 'kalibr', 'kalibr.yaml')
    gm, am = rng.normal(0, 1, (50, 3)), rng.normal(0, 10, (50, 3))
    f_i = np.linalg.solve(M_a, am.T).T
    w_i = (C.T @ np.linalg.solve(M_g, (gm - f_i @ (A @ C).T).T)).T
    omega, force = compensate(calib.errors, gm, am)
    _close(omega, w_i @ R_b_i.T)
    _close(force, f_i @ R_b_i.T)


def test_cli_export_import(tmp_path, capsys) -> None:
    from imu_calib_ros.cli import main
    rng = np.random.default_rng(9)
    e = _errors(rng).replace(accel_quadratic_per_m_s2=np.full(3, 1e-5))
    src = tmp_path / 'calib.yaml'
    CalibrationResult.exact(e).save(src)
    out = tmp_path / 'kalibr.yaml'
    assert main(['export', str(src), '--format', 'kalibr', '--output', str(out)]) == 0
    err = capsys.readouterr().err
    assert err.count('\n') == 1 and 'warning: kalibr cannot hold' in err
    assert 'accelerometer.quadratic' in err
    back = tmp_path / 'back.yaml'
    assert main(['import', str(out), '--format', 'kalibr', '--output', str(back)]) == 0
    got = CalibrationResult.load(back)
    np.testing.assert_allclose(got.errors.gyro_scale_misalignment, e.gyro_scale_misalignment,
                               atol=1e-12)
    assert 'accelerometer.quadratic' in got.fixed
    prefix = tmp_path / 'tk'
    assert main(['export', str(src), '--format', 'imu_tk', '--output', str(prefix)]) == 0
    assert (tmp_path / 'tk_acc.calib').exists() and (tmp_path / 'tk_gyro.calib').exists()
    assert main(['export', str(src), '--format', 'imu_calib']) == 0  # stdout
    assert 'SM:' in capsys.readouterr().out


def test_cli_format_lists_match_core() -> None:
    import importlib

    from imu_calib_ros.core import exchange
    assert importlib.import_module('imu_calib_ros.cli.export').FORMATS == exchange.FORMATS
    assert importlib.import_module('imu_calib_ros.cli.import').FORMATS == exchange.FORMATS
    assert (importlib.import_module('imu_calib_ros.cli.export').OPENVINS_MODELS
            == exchange.OPENVINS_MODELS)


def test_readme_after_calibration_commands_run(tmp_path) -> None:
    """The README's noise and export/import commands run on a simulated bag (the truth file
    stands in for run/calib.yaml) and write what they say."""
    import re
    import shlex
    from pathlib import Path

    from imu_calib_ros.cli import main
    readme = (Path(__file__).resolve().parents[1] / 'README.md').read_text()
    section = readme.split('## After calibration', 1)[1].split('\n## ', 1)[0]
    blocks = re.findall(r'```bash\n(.*?)```', section, re.S)
    cmds = [shlex.split(ln) for b in blocks for ln in re.sub(r'\\\n\s*', ' ', b).splitlines()
            if ln.strip()]
    assert [c[1] for c in cmds] == ['noise', 'export', 'export', 'export', 'import']
    run = tmp_path / 'run'
    run.mkdir()
    assert main(['simulate', '--fixture', 'three_axis', '--plan', 'demo_short', '--imu',
                 'mems_mti1', '--rate', '50', '--seed', '1', '--output', str(run / 'bag'),
                 '--truth', str(run / 'calib.yaml')]) == 0
    import os
    cwd = os.getcwd()
    os.chdir(tmp_path)
    try:
        for c in cmds:
            assert main(c[1:]) == 0, c
    finally:
        os.chdir(cwd)
    for f in ('noise.yaml', 'imu.yaml', 'noise.html', 'kalibr.yaml', 'kalibr_imu_chain.yaml',
              'imu_tk_acc.calib', 'imu_tk_gyro.calib', 'from_kalibr.yaml'):
        assert (run / f).is_file(), f
