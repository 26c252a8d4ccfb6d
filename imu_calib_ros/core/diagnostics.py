"""Diagnostics a person reads: an estimator's ``health()`` as short key/value text.

Pure (no ROS): the calibration node puts these values into its ``/diagnostics`` status. The
rules (issue 16): every counter once, under one name; zero counters and empty texts left
out; no long reprs (the last good estimate as a few values in engineering units); never the
text ``nan``. Rejected input is counted once, by the input guard
(:func:`imu_calib_ros.core.input_guard.rejection_counts`), so the ``health()`` keys that
repeat those counts are not shown here.
"""
from __future__ import annotations

import math
from typing import Any, Mapping

from .units import DEG_H_RAD_S, PPM, UG_M_S2

#: ``health()`` keys never shown: the guard's rejection counts (reported once, as
#: ``rejected.guard.<reason>``), the estimator's copies derived from them
#: (``imu_out_of_order``, ``imu_non_finite``, ``joint_*``), its own gap count (the guard's
#: ``flagged.gap`` is shown), ``accepted`` (= ``gate_accepted``) and ``last_good`` (shown
#: by :func:`last_good_values`).
HIDDEN_HEALTH_KEYS = frozenset({
    'rejected', 'rejected_total', 'imu_out_of_order', 'imu_non_finite', 'joint_out_of_order',
    'joint_missing_names', 'joint_non_finite', 'gaps', 'accepted', 'last_good'})

#: (label, SensorErrors field, flat indices, SI value of the unit) of :func:`last_good_values`
_LAST_GOOD = (('gyro_bias_deg_h', 'gyro_bias_rad_s', (0, 1, 2), DEG_H_RAD_S),
              ('gyro_scale_ppm', 'gyro_scale_misalignment', (0, 4, 8), PPM),
              ('accel_bias_ug', 'accel_bias_m_s2', (0, 1, 2), UG_M_S2),
              ('accel_scale_ppm', 'accel_scale_misalignment', (0, 4, 8), PPM))


def number_text(value: float) -> str:
    """``value`` with 6 significant digits; ``not finite`` for NaN/inf (never ``nan``)."""
    return f'{value:.6g}' if math.isfinite(value) else 'not finite'


def last_good_values(result: Any, prefix: str = 'estimator.last_good.') -> dict[str, str]:
    """The last good estimate (a ``CalibrationResult``) as four short values: gyro and
    accelerometer biases [deg/h, ug] and scale factors [ppm], x, y, z. Nothing for None."""
    errors = getattr(result, 'errors', None)
    if errors is None:
        return {}
    out = {}
    for label, attr, idx, unit in _LAST_GOOD:
        flat = [float(v) for row in _rows(getattr(errors, attr)) for v in row]
        out[f'{prefix}{label}'] = ', '.join(f'{flat[i] / unit:.4g}' for i in idx)
    return out


def _rows(value: Any) -> list[list[float]]:
    """A 3-vector or 3x3 (numpy or nested lists) as rows, without importing numpy."""
    rows = value.tolist() if hasattr(value, 'tolist') else list(value)
    return [r if isinstance(r, list) else [r] for r in rows]


def health_values(health: Mapping[str, Any], prefix: str = 'estimator.') -> dict[str, str]:
    """``health()`` flattened into ``{key: text}``: nested mappings as dotted keys, lists
    joined, floats with 6 digits; zero counters (integers), empty texts and empty lists left
    out; the keys of :data:`HIDDEN_HEALTH_KEYS` (top level) left out, ``last_good`` as
    :func:`last_good_values`."""
    out: dict[str, str] = {}
    for k, v in health.items():
        if k in HIDDEN_HEALTH_KEYS:
            continue
        _add(out, f'{prefix}{k}', v)
    out.update(last_good_values(health.get('last_good'), f'{prefix}last_good.'))
    return out


def _add(out: dict[str, str], key: str, v: Any) -> None:
    if isinstance(v, Mapping):
        for k, x in v.items():
            _add(out, f'{key}.{k}', x)
    elif isinstance(v, bool):
        out[key] = str(v)
    elif isinstance(v, int):
        if v:
            out[key] = str(v)
    elif isinstance(v, float):
        out[key] = number_text(v)
    elif isinstance(v, (list, tuple)):
        if v:
            out[key] = ', '.join(number_text(x) if isinstance(x, float) else str(x) for x in v)
    elif v is not None and str(v):
        out[key] = str(v)


def frame_mismatch(imu_received: int, rejected_for_frame: int, received_frame: str,
                   expected_frame: str) -> str:
    """The ERROR line when every one of ``imu_received`` (> 0) IMU samples was rejected for
    its ``header.frame_id``; ``''`` otherwise. Naming both frames says what to fix: the
    driver's frame or the ``frame_id`` parameter."""
    if imu_received <= 0 or rejected_for_frame < imu_received:
        return ''
    return (f'every IMU sample rejected: header.frame_id "{received_frame}" received, '
            f'"{expected_frame}" expected (fix the driver\'s frame or set frame_id)')
