"""Calibrations to and from the files of the tools people already use (issue 13 item 2).

Every tool's linear model is one case of: in some orthogonal frame F of the tool's own choice,

    w_meas - bg = Bg w_F + Gf f_F          a_meas - ba = Ba f_F

Ours (CONTRACT 3 without asymmetry, quadratic and size effect) is the case F = b with Bg
symmetric (``I + Kg``), ``Ba = I + Ka``, ``Gf = G``. A tool's file is converted to ours by the
polar decomposition ``Bg = (I + Kg) R_b_F`` (``R_b_F`` the rotation from F to our b); ours to a
tool's by the triangular-times-rotation factorisation its parametrisation needs. The models
(read in each tool's source; the tests write each tool's correction out again):

- **Kalibr** (ethz-asl/kalibr, ``IccSensors.py``, IccScaledMisalignedImu; Rehder et al.,
  ICRA 2016), frame i: ``a = M_a (C_i_b f_b) + b_a``, ``w = M_g C_gyro_i w_i + A C_gyro_i a_i
  + b_g`` with ``M_a``, ``M_g`` lower triangular, ``C_gyro_i`` a rotation, ``A`` full
  (g-sensitivity). Correction: ``f_i = M_a^-1 (a - b_a)``, ``w_i = C_gyro_i^T M_g^-1 (w - b_g
  - A C_gyro_i f_i)``. Kalibr estimates the biases itself: its file has none.
- **OpenVINS** (rpng/open_vins, ``Propagator.cpp``; ``kalibr_imu_chain.yaml``):
  ``a_I = R_ACCtoIMU Ta^-1 (a - b_a)``, ``w_I = R_GYROtoIMU Tw^-1 (w - b_g - Tg a_I)``
  (``R_XtoIMU = R_IMUtoX^T``). ``model: kalibr``: ``Tw``, ``Ta`` lower triangular,
  ``R_IMUtoACC = I``; ``model: rpng``: upper triangular, ``R_IMUtoGYRO = I``. Note ``Tg``
  multiplies the acceleration in the IMU frame, Kalibr's ``A`` in the gyro frame: ``Tg = A
  C_gyro_i`` (not ``A``, as OpenVINS' example comment says, unless ``C_gyro_i = I``).
- **imu_calib** (dpkoch/imu_calib, ``accel_calib.cpp``): ``f = SM a - bias`` (row-major
  ``SM``); its ``apply_calib`` only subtracts a gyro bias it measures at start-up.
- **imu_tk** (Kyle-ak/imu_tk, ``calibration.h``, CalibratedTriad): ``X' = T K (X - B)`` per
  triad, ``T`` unit-diagonal misalignment, ``K`` diagonal scale, ``B`` bias; saved as plain
  numbers (T, K row by row, then B), accelerometer and gyro in two files; no g-sensitivity.

What a target cannot hold (asymmetry, quadratic, size effect; g-sensitivity, gyro terms where
absent) is named by :func:`not_held`.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import yaml
from numpy.typing import NDArray
from scipy.linalg import polar, rq

from .calibration import CalibrationResult
from .errors import ConfigError
from .sensor_model import SensorErrors

FloatArray = NDArray[np.float64]
FORMATS = ('kalibr', 'openvins', 'imu_calib', 'imu_tk')
OPENVINS_MODELS = ('kalibr', 'rpng')
I3 = np.eye(3)


@dataclass(frozen=True)
class LinearModel:
    """``w - bg = Bg w_F + Gf f_F``, ``a - ba = Ba f_F`` in the tool's frame F."""

    Bg: FloatArray
    Ba: FloatArray
    Gf: FloatArray
    bg: FloatArray
    ba: FloatArray


def linear_of(errors: SensorErrors) -> LinearModel:
    """Our errors as a :class:`LinearModel` in frame b (the nonlinear terms dropped)."""
    e = errors
    return LinearModel(I3 + e.gyro_scale_misalignment, I3 + e.accel_scale_misalignment,
                       np.array(e.gyro_g_sensitivity_rad_s_per_m_s2), np.array(e.gyro_bias_rad_s),
                       np.array(e.accel_bias_m_s2))


def errors_of(m: LinearModel) -> tuple[SensorErrors, FloatArray]:
    """Ours from a tool's linear model: ``(errors, R_b_F)`` by the polar decomposition
    ``Bg = (I + Kg) R_b_F`` (CONTRACT 3: b is the frame where Kg is symmetric)."""
    u, p = polar(m.Bg, side='left')  # Bg = p u, p symmetric positive
    R_b_F = u
    kg = p - I3
    kg = 0.5 * (kg + kg.T)
    e = SensorErrors.zeros().replace(
        gyro_bias_rad_s=m.bg, gyro_scale_misalignment=kg,
        gyro_g_sensitivity_rad_s_per_m_s2=m.Gf @ R_b_F.T,
        accel_bias_m_s2=m.ba, accel_scale_misalignment=m.Ba @ R_b_F.T - I3)
    return e, R_b_F


def lower_times_rotation(A: FloatArray) -> tuple[FloatArray, FloatArray]:
    """``A = L R``: L lower triangular with a positive diagonal, R a rotation (det A > 0)."""
    q, u = np.linalg.qr(A.T)  # A^T = q u  ->  A = u^T q^T
    s = np.sign(np.diag(u))
    L, R = (u * s[:, None]).T, (q * s).T
    return L, R


def upper_times_rotation(A: FloatArray) -> tuple[FloatArray, FloatArray]:
    """``A = U R``: U upper triangular with a positive diagonal, R a rotation."""
    u, q = rq(A)
    s = np.sign(np.diag(u))
    return u * s, q * s[:, None]


def rotation_times_upper(A: FloatArray) -> tuple[FloatArray, FloatArray]:
    """``A = R U``: R a rotation, U upper triangular with a positive diagonal."""
    q, u = np.linalg.qr(A)
    s = np.sign(np.diag(u))
    return q * s, u * s[:, None]


def not_held(errors: SensorErrors, fmt: str) -> list[str]:
    """CONTRACT 4 keys with non-zero values the target format cannot hold."""
    e = errors
    out = []
    checks = [('gyroscope.scale_asymmetry', e.gyro_scale_asymmetry),
              ('accelerometer.scale_asymmetry', e.accel_scale_asymmetry),
              ('accelerometer.quadratic', e.accel_quadratic_per_m_s2),
              ('accelerometer.size_effect', e.size_effect_m)]
    if fmt in ('imu_calib', 'imu_tk'):
        checks.append(('gyroscope.g_sensitivity', e.gyro_g_sensitivity_rad_s_per_m_s2))
    if fmt == 'imu_calib':
        checks += [('gyroscope.scale_misalignment', e.gyro_scale_misalignment),
                   ('gyroscope.bias', e.gyro_bias_rad_s)]
    if fmt in ('kalibr', 'openvins'):
        checks += [('gyroscope.bias', e.gyro_bias_rad_s),
                   ('accelerometer.bias', e.accel_bias_m_s2)]
    for key, v in checks:
        if np.any(np.asarray(v) != 0.0):
            out.append(key)
    return out


_WHY = {'kalibr': 'Kalibr estimates the biases itself (kept under imu_calib_ros)',
        'openvins': 'OpenVINS estimates the biases itself (kept under imu_calib_ros)',
        'imu_calib': 'imu_calib corrects accelerometers only and measures the gyro bias at '
                     'start-up',
        'imu_tk': 'imu_tk has no g-sensitivity'}


def warning_line(errors: SensorErrors, fmt: str) -> str | None:
    """The one line naming what the target cannot hold, or None."""
    lost = not_held(errors, fmt)
    if not lost:
        return None
    return (f'{fmt} cannot hold {", ".join(lost)}: dropped ({_WHY[fmt]}; asymmetry, quadratic '
            'and size effect have no place in its model)')


def _m(a: FloatArray) -> list[list[float]]:
    return [[float(x) for x in row] for row in np.asarray(a)]


def _v(a: FloatArray) -> list[float]:
    return [float(x) for x in np.asarray(a)]


# ------------------------------------------------------------------------------- export
def kalibr_parameters(errors: SensorErrors) -> dict[str, FloatArray]:
    """Kalibr's ``M_a``, ``M_g``, ``A``, ``C_gyro_i`` and ``R_i_b`` (its frame i from our b)."""
    m = linear_of(errors)
    M_a, R_i_b = lower_times_rotation(m.Ba)  # a - ba = M_a (R_i_b f_b)
    M_g, C_gyro_i = lower_times_rotation(m.Bg @ R_i_b.T)  # M_g C_gyro_i R_i_b = Bg
    A = m.Gf @ R_i_b.T @ C_gyro_i.T
    return {'M_a': M_a, 'M_g': M_g, 'A': A, 'C_gyro_i': C_gyro_i, 'R_i_b': R_i_b}


def _noise_keys(noise: Any) -> dict[str, Any]:
    if noise is None:
        return {}
    return {'accelerometer_noise_density': float(noise.accel_noise_m_s2_rt_hz),
            'accelerometer_random_walk': float(noise.accel_bias_random_walk_m_s3_rt_hz),
            'gyroscope_noise_density': float(noise.gyro_noise_rad_s_rt_hz),
            'gyroscope_random_walk': float(noise.gyro_bias_random_walk_rad_s2_rt_hz)}


def export(calib: CalibrationResult, fmt: str, noise: Any = None, rostopic: str = '/imu0',
           update_rate_hz: float | None = None, openvins_model: str = 'kalibr'
           ) -> tuple[dict[str, str], str | None]:
    """The target's file(s) as ``{suffix: text}`` and the warning line (or None).

    ``suffix`` is ``''`` for a single file, ``'_acc.calib'``/``'_gyro.calib'`` for imu_tk.
    ``noise`` (an :class:`~.imu_grade.ImuGrade`, e.g. from ``imu-calib noise``) fills the
    Kalibr/OpenVINS noise keys.
    """
    if fmt not in FORMATS:
        raise ConfigError(f'unknown format {fmt!r} (known: {", ".join(FORMATS)})')
    e = calib.errors
    warn = warning_line(e, fmt)
    head = [f'exported by imu-calib export --format {fmt} from an imu_calib_ros calibration '
            f'(frame {calib.frame_id}, CONTRACT 4)']
    if warn:
        head.append(f'NOT HELD: {warn}')
    bias = {'gyroscope_bias_rad_s': _v(e.gyro_bias_rad_s),
            'accelerometer_bias_m_s2': _v(e.accel_bias_m_s2)}
    if fmt == 'kalibr':
        k = kalibr_parameters(e)
        head.append('model (Kalibr IccScaledMisalignedImu): a = M (C_i_b f) + b_a; '
                    'w = M_g C_gyro_i w_i + A C_gyro_i a_i + b_g')
        head.append("Kalibr's IMU frame i is R_i_b (under imu_calib_ros) times our frame b: "
                    'use it for the camera-IMU extrinsics')
        imu0: dict[str, Any] = {'model': 'scale-misalignment', **_noise_keys(noise),
                                'rostopic': rostopic}
        if update_rate_hz:
            imu0['update_rate'] = float(update_rate_hz)
        imu0['accelerometers'] = {'M': _m(k['M_a'])}
        imu0['gyroscopes'] = {'M': _m(k['M_g']), 'A': _m(k['A']), 'C_gyro_i': _m(k['C_gyro_i'])}
        imu0['imu_calib_ros'] = {**bias, 'R_i_b': _m(k['R_i_b'])}
        return {'': _yaml({'imu0': imu0}, head)}, warn
    if fmt == 'openvins':
        if openvins_model not in OPENVINS_MODELS:
            raise ConfigError(f'unknown OpenVINS model {openvins_model!r} (known: kalibr, rpng)')
        m = linear_of(e)
        if openvins_model == 'kalibr':
            k = kalibr_parameters(e)
            Tw, R_IMUtoGYRO, Ta, R_IMUtoACC = k['M_g'], k['C_gyro_i'], k['M_a'], I3
            Tg, R_I_b = k['A'] @ k['C_gyro_i'], k['R_i_b']
        else:
            # w_I = Tw^-1 (w - bg - Tg a_I) = R w_b: Bg^-1 = R^T Dw, Dw upper
            Rt, Dw = rotation_times_upper(np.linalg.inv(m.Bg))  # type: ignore[arg-type]
            R_I_b = Rt.T
            # a_I = R_ACCtoIMU Da (a - ba) = R Ba^-1 (a - ba)
            Q2, Da = rotation_times_upper(R_I_b @ np.linalg.inv(m.Ba))
            Tw, R_IMUtoGYRO, Ta, R_IMUtoACC = np.linalg.inv(Dw), I3, np.linalg.inv(Da), Q2.T  # type: ignore[assignment]
            Tg = m.Gf @ R_I_b.T
        head.append('OpenVINS (Propagator.cpp): a_I = R_IMUtoACC^T Ta^-1 (a - b_a), w_I = '
                    'R_IMUtoGYRO^T Tw^-1 (w - b_g - Tg a_I); Tg multiplies a_I (IMU frame)')
        head.append('the OpenVINS IMU frame I is R_I_b (under imu_calib_ros) times our frame b')
        imu0 = {'T_i_b': _m(np.eye(4)), **_noise_keys(noise), 'rostopic': rostopic,
                'time_offset': 0.0}
        if update_rate_hz:
            imu0['update_rate'] = float(update_rate_hz)
        imu0.update({'model': openvins_model, 'Tw': _m(Tw), 'R_IMUtoGYRO': _m(R_IMUtoGYRO),
                     'Ta': _m(Ta), 'R_IMUtoACC': _m(R_IMUtoACC), 'Tg': _m(Tg),
                     'imu_calib_ros': {**bias, 'R_I_b': _m(R_I_b)}})
        return {'': '%YAML:1.0\n' + _yaml({'imu0': imu0}, head)}, warn
    if fmt == 'imu_calib':
        SM = np.linalg.inv(linear_of(e).Ba)
        head.append('dpkoch/imu_calib apply_calib: corrected = SM * raw - bias (SM row-major)')
        return {'': _yaml({'SM': [float(x) for x in SM.ravel()],
                           'bias': _v(SM @ e.accel_bias_m_s2)}, head)}, warn
    # imu_tk: X' = T K (X - B), T unit diagonal, K diagonal
    m = linear_of(e)
    out = {}
    for suffix, B, bias_v in (('_acc.calib', m.Ba, e.accel_bias_m_s2),
                              ('_gyro.calib', m.Bg, e.gyro_bias_rad_s)):
        M = np.linalg.inv(B)
        K = np.diag(np.diag(M))
        T = M @ np.linalg.inv(K)
        text = ''.join(' '.join(repr(float(x)) for x in row) + '\n' for row in T) + '\n'
        text += ''.join(' '.join(repr(float(x)) for x in row) + '\n' for row in K) + '\n'
        text += ''.join(repr(float(x)) + '\n' for x in bias_v) + '\n'
        head_t = head + ["imu_tk CalibratedTriad: X' = T K (X - B); T, K row by row, then B "
                         '(these comment lines follow the 21 numbers imu_tk reads)']
        out[suffix] = text + ''.join(f'# {c}\n' for c in head_t)
    return out, warn


def _yaml(data: Any, comments: list[str]) -> str:
    return ''.join(f'# {c}\n' for c in comments) + yaml.safe_dump(
        data, sort_keys=False, default_flow_style=None, width=99)


# ------------------------------------------------------------------------------- import
def _mat(d: Any, key: str, source: str, shape: tuple[int, ...] = (3, 3)) -> FloatArray:
    try:
        a = np.array(d[key], dtype=float)
    except (KeyError, TypeError, ValueError):
        raise ConfigError(f'missing or not numbers (expected {shape})', source, key) from None
    if a.size == 9 and shape == (3, 3):
        a = a.reshape(3, 3)
    if a.shape != shape or not np.all(np.isfinite(a)):
        raise ConfigError(f'expected finite numbers of shape {shape}', source, key)
    return a


def import_text(texts: dict[str, str], fmt: str, source: str, frame_id: str = 'imu_link'
                ) -> tuple[CalibrationResult, FloatArray]:
    """A calibration from the target's file(s) (``{suffix: text}`` as :func:`export`), and
    ``R_b_F``: our frame b from the tool's frame. Not estimated here: every key the format
    cannot hold is zero and listed as fixed; sigmas are zero (the files hold none)."""
    if fmt not in FORMATS:
        raise ConfigError(f'unknown format {fmt!r} (known: {", ".join(FORMATS)})')
    zero3 = np.zeros(3)
    if fmt in ('kalibr', 'openvins'):
        text = texts['']
        if text.startswith('%YAML:'):  # OpenCV's directive, not YAML 1.1's
            text = text.split('\n', 1)[1]
        d = yaml.safe_load(text)
        if not isinstance(d, dict) or 'imu0' not in d:
            raise ConfigError('expected a top-level key imu0', source, 'imu0')
        imu0 = d['imu0']
        ours = imu0.get('imu_calib_ros') or {}
        bg = np.array(ours.get('gyroscope_bias_rad_s', zero3), float)
        ba = np.array(ours.get('accelerometer_bias_m_s2', zero3), float)
        if fmt == 'kalibr':
            g, acc = imu0.get('gyroscopes') or {}, imu0.get('accelerometers') or {}
            M_a = _mat(acc, 'M', source)
            M_g = _mat(g, 'M', source)
            C = _mat(g, 'C_gyro_i', source) if 'C_gyro_i' in g else I3
            A = _mat(g, 'A', source) if 'A' in g else np.zeros((3, 3))
            lm = LinearModel(M_g @ C, M_a, A @ C, bg, ba)
        else:
            Tw, Ta = _mat(imu0, 'Tw', source), _mat(imu0, 'Ta', source)
            Rg = _mat(imu0, 'R_IMUtoGYRO', source) if 'R_IMUtoGYRO' in imu0 else I3
            Ra = _mat(imu0, 'R_IMUtoACC', source) if 'R_IMUtoACC' in imu0 else I3
            Tg = _mat(imu0, 'Tg', source) if 'Tg' in imu0 else np.zeros((3, 3))
            # w - bg = Tw R_IMUtoGYRO w_I + Tg a_I ; a - ba = Ta R_IMUtoACC a_I
            lm = LinearModel(Tw @ Rg, Ta @ Ra, Tg, bg, ba)
    elif fmt == 'imu_calib':
        d = yaml.safe_load(texts[''])
        if not isinstance(d, dict):
            raise ConfigError('expected SM and bias', source)
        SM = _mat(d, 'SM', source)
        b = _mat(d, 'bias', source, (3,))
        Ba = np.linalg.inv(SM)  # f = SM a - bias = SM (a - Ba bias)
        lm = LinearModel(I3, Ba, np.zeros((3, 3)), zero3, Ba @ b)  # type: ignore[arg-type]
    else:
        mats = {}
        for suffix in ('_acc.calib', '_gyro.calib'):
            nums = []
            for line in texts[suffix].splitlines():
                if line.strip().startswith('#'):
                    break
                nums += [float(x) for x in line.split()]
            if len(nums) < 21:
                raise ConfigError(f'expected 21 numbers (T, K, B), got {len(nums)}',
                                  source + suffix)
            T, K = np.array(nums[:9]).reshape(3, 3), np.array(nums[9:18]).reshape(3, 3)
            mats[suffix] = (np.linalg.inv(T @ K), np.array(nums[18:21]))
        (Ba, ba), (Bg, bg) = mats['_acc.calib'], mats['_gyro.calib']
        lm = LinearModel(Bg, Ba, np.zeros((3, 3)), bg, ba)  # type: ignore[arg-type]
    errors, R_b_F = errors_of(lm)
    fixed = tuple(k for k in ('gyroscope.scale_asymmetry', 'accelerometer.scale_asymmetry',
                              'accelerometer.quadratic', 'accelerometer.size_effect'))
    if fmt in ('imu_calib', 'imu_tk'):
        fixed += ('gyroscope.g_sensitivity',)
    if fmt == 'imu_calib':
        fixed += ('gyroscope.scale_misalignment', 'gyroscope.bias')
    extra = {'provenance': {'imported_from': {'format': fmt, 'file': source,
                                              'R_b_tool': _m(R_b_F),
                                              'note': 'sigmas unknown (the file holds none): '
                                                      'written as 0'}}}
    return CalibrationResult(errors, SensorErrors.zeros(), frame_id, fixed, extra), R_b_F


def rotation_angle_rad(R: FloatArray) -> float:
    """Angle of a rotation matrix."""
    return math.acos(max(-1.0, min(1.0, (float(np.trace(R)) - 1.0) / 2.0)))
