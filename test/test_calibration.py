"""calibration.py: CONTRACT 4 layout, bit-exact round trip, atomic write, strict loading."""
import copy
import os
from pathlib import Path

import numpy as np
import pytest
import yaml

from imu_calib_ros.core import calibration as calmod
from imu_calib_ros.core.calibration import CalibrationResult
from imu_calib_ros.core.errors import ConfigError
from imu_calib_ros.core.sensor_model import N_PARAMETERS, PARAMETER_KEYS, SensorErrors


def random_result(seed: int = 0) -> CalibrationResult:
    rng = np.random.default_rng(seed)
    # awkward floats: many digits, tiny and huge exponents, negative zero
    x = rng.normal(size=N_PARAMETERS) * 10.0 ** rng.integers(-12, 3, size=N_PARAMETERS)
    x[5] = -0.0
    x[7] = 1e-300
    s = np.abs(rng.normal(size=N_PARAMETERS)) * 1e-6
    extra = {'mounting': {'rpy_rad': np.array([1e-3, -2e-4, 3.3e-4]),
                          'xyz_m': (0.002, -0.001, 0.0)},
             'noise': {'gyro_noise_rad_s_rt_hz': np.float64(1.2e-6), 'seed': np.int64(3)},
             'provenance': {'tool': 'imu-calib simulate', 'plan': 'srt', 'ok': True,
                            'stamps': [1, 2, 3]}}
    return CalibrationResult(SensorErrors.from_vector(x), SensorErrors.from_vector(s),
                             'imu_link', ('gyroscope.g_sensitivity', 'accelerometer.quadratic'),
                             extra)


def test_layout_matches_contract(tmp_path: Path) -> None:
    p = tmp_path / 'c.yaml'
    random_result().save(p)
    d = yaml.safe_load(p.read_text())
    assert list(d) == ['imu_calibration']
    body = d['imu_calibration']
    assert body['format_version'] == 1 and body['frame_id'] == 'imu_link'
    assert list(body['gyroscope']) == ['bias', 'scale_misalignment', 'scale_asymmetry',
                                       'g_sensitivity']
    assert list(body['accelerometer']) == ['bias', 'scale_misalignment', 'scale_asymmetry',
                                           'quadratic', 'size_effect']
    assert set(body['sigma']) == {'gyroscope', 'accelerometer'}
    assert np.shape(body['gyroscope']['scale_misalignment']) == (3, 3)
    assert np.shape(body['accelerometer']['size_effect']) == (3, 3)
    assert np.all(np.diag(body['sigma']['accelerometer']['size_effect']) == 0)
    assert body['fixed'] == ['gyroscope.g_sensitivity', 'accelerometer.quadratic']
    assert body['mounting']['xyz_m'] == [0.002, -0.001, 0.0]


def test_round_trip_is_bit_exact(tmp_path: Path) -> None:
    for seed in range(3):
        r = random_result(seed)
        p = tmp_path / f'c{seed}.yaml'
        r.save(p)
        r2 = CalibrationResult.load(p)
        v1, v2 = r.errors.as_vector(), r2.errors.as_vector()
        assert v1.tobytes() == v2.tobytes()  # bit-exact, incl. -0.0
        assert r.sigma.as_vector().tobytes() == r2.sigma.as_vector().tobytes()
        assert r2.frame_id == r.frame_id and r2.fixed == r.fixed
        assert r2.extra == {k: r.to_dict()['imu_calibration'][k] for k in r.extra}
        assert r2.extra['mounting']['rpy_rad'] == r.extra['mounting']['rpy_rad'].tolist()
        assert r2.extra['noise']['seed'] == 3 and r2.extra['provenance']['ok'] is True
        assert r2.to_dict() == r.to_dict()
        r2.save(tmp_path / 'again.yaml')
        assert (tmp_path / 'again.yaml').read_bytes() == p.read_bytes()


def test_exact_truth_has_zero_sigma(tmp_path: Path) -> None:
    t = CalibrationResult.exact(random_result().errors, extra={'provenance': {'seed': 1}})
    assert np.all(t.sigma.as_vector() == 0) and t.fixed == ()
    t.save(tmp_path / 'truth.yaml')
    assert CalibrationResult.load(tmp_path / 'truth.yaml').extra == {'provenance': {'seed': 1}}


def test_save_refuses_nan_and_writes_nothing(tmp_path: Path) -> None:
    p = tmp_path / 'c.yaml'
    r = random_result()
    bad = CalibrationResult(r.errors, r.sigma, 'imu', (), {'noise': {'arw': float('nan')}})
    with pytest.raises(ConfigError, match=r'imu_calibration\.noise\.arw: value nan'):
        bad.save(p)
    assert list(tmp_path.iterdir()) == []
    # an existing file is left untouched
    r.save(p)
    before = p.read_bytes()
    with pytest.raises(ConfigError):
        bad.save(p)
    assert p.read_bytes() == before
    assert [q.name for q in tmp_path.iterdir()] == ['c.yaml']
    with pytest.raises(ConfigError, match='does not exist'):
        r.save(tmp_path / 'no' / 'c.yaml')


def test_save_is_atomic_replace_with_fsync(tmp_path: Path, monkeypatch) -> None:
    """The file is written to a temp file in the same directory, fsync'ed, then renamed."""
    calls = []
    real_fsync, real_replace = os.fsync, os.replace
    monkeypatch.setattr(calmod.os, 'fsync', lambda fd: (calls.append('fsync'), real_fsync(fd)))

    def replace(src, dst):
        calls.append(('replace', Path(src).parent == Path(dst).parent, Path(dst).exists()))
        return real_replace(src, dst)
    monkeypatch.setattr(calmod.os, 'replace', replace)
    p = tmp_path / 'c.yaml'
    random_result().save(p)
    assert calls[0] == 'fsync'
    assert calls[1] == ('replace', True, False)
    # a failure while writing leaves neither a partial target nor a temp file
    def boom(src, dst):
        raise OSError(28, 'No space left on device')
    monkeypatch.setattr(calmod.os, 'replace', boom)
    with pytest.raises(ConfigError, match='No space left'):
        random_result(1).save(tmp_path / 'd.yaml')
    assert sorted(q.name for q in tmp_path.iterdir()) == ['c.yaml']


def _dump(tmp_path: Path, d: dict) -> Path:
    p = tmp_path / 'in.yaml'
    p.write_text(yaml.safe_dump(d))
    return p


def _mutations():
    def setp(path, value):
        def f(d):
            node = d['imu_calibration']
            for k in path[:-1]:
                node = node[k]
            if value is None:
                del node[path[-1]]
            else:
                node[path[-1]] = value
        return f
    P = 'imu_calibration'
    return [
        (setp(['format_version'], 2), f'{P}.format_version', 'unsupported'),
        (setp(['format_version'], None), f'{P}.format_version', 'missing'),
        (setp(['frame_id'], 3), f'{P}.frame_id', 'string'),
        (setp(['gyroscope', 'bias'], [0.0, 0.0]), f'{P}.gyroscope.bias', 'list of 3'),
        (setp(['gyroscope', 'bias'], [0.0, float('nan'), 0.0]), f'{P}.gyroscope.bias',
         'not finite'),
        (setp(['accelerometer', 'bias'], [0.0, float('inf'), 0.0]), f'{P}.accelerometer.bias',
         'not finite'),
        (setp(['gyroscope', 'scale_misalignment'], [[0, 1e-6, 0], [0, 0, 0], [0, 0, 0]]),
         f'{P}.gyroscope.scale_misalignment', 'symmetric'),
        (setp(['accelerometer', 'size_effect'], [[1e-3, 0, 0], [0, 0, 0], [0, 0, 0]]),
         f'{P}.accelerometer.size_effect', 'diagonal'),
        (setp(['sigma', 'accelerometer', 'bias'], [1e-3, -1e-3, 0]),
         f'{P}.sigma.accelerometer.bias', 'negative'),
        (setp(['sigma', 'gyroscope'], None), f'{P}.sigma.gyroscope', 'missing'),
        (setp(['sigma'], None), f'{P}.sigma', 'missing'),
        (setp(['accelerometer'], None), f'{P}.accelerometer', 'missing'),
        (setp(['gyroscope', 'drift'], [0, 0, 0]), f'{P}.gyroscope.drift', 'unknown'),
        (setp(['fixed'], ['gyroscope.bias', 'gyro.scale']), f'{P}.fixed[1]', 'unknown key'),
        (setp(['fixed'], ['gyroscope.bias', 'gyroscope.bias']), f'{P}.fixed[1]', 'duplicate'),
        (setp(['fixed'], 'gyroscope.bias'), f'{P}.fixed', 'list'),
        (setp(['noise'], {'arw': float('nan')}), f'{P}.noise.arw', 'not finite'),
        (lambda d: d.update(other=1), 'other', 'unknown top-level'),
        (lambda d: d.pop(P), P, 'missing'),
    ]


@pytest.mark.parametrize('i', range(len(_mutations())))
def test_load_refuses_bad_files(tmp_path: Path, i: int) -> None:
    mutate, key, words = _mutations()[i]
    d = copy.deepcopy(random_result().to_dict())
    mutate(d)
    p = _dump(tmp_path, d)
    with pytest.raises(ConfigError) as ei:
        CalibrationResult.load(p)
    assert ei.value.source == str(p) and ei.value.key == key, str(ei.value)
    assert words in str(ei.value)
    assert str(ei.value).startswith(f'{p}: {key}: ')


def test_load_missing_and_malformed_files(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match='file not found'):
        CalibrationResult.load(tmp_path / 'nope.yaml')
    p = tmp_path / 'x.yaml'
    p.write_text('imu_calibration: [1, 2\n')
    with pytest.raises(ConfigError, match='malformed YAML'):
        CalibrationResult.load(p)


def test_constructor_checks() -> None:
    r = random_result()
    with pytest.raises(ValueError, match='unknown key'):
        CalibrationResult(r.errors, r.sigma, 'imu', ('gyroscope.nope',))
    with pytest.raises(ValueError, match='non-negative'):
        CalibrationResult(r.errors, r.errors, 'imu')
    with pytest.raises(ValueError, match='reserved'):
        CalibrationResult(r.errors, r.sigma, 'imu', (), {'sigma': 1})
    assert set(PARAMETER_KEYS) >= set(r.fixed)
