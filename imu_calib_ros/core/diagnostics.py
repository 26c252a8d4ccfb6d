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
    joined, floats with 6 digits; zeros (counters and readings), empty texts and empty lists
    left out; the keys of :data:`HIDDEN_HEALTH_KEYS` (top level) left out, ``last_good`` as
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
        if v != 0.0:  # a zero reading (stopped_for_s of a running filter) like a zero counter
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


#: ``health()`` counters that each restart the navigation (the filter re-aligns at the next
#: stationary window; samples until then are not used): gaps that re-initialised it, resets
#: (a backward clock jump), re-alignments after a gate cascade, restarts after divergence.
NAVIGATION_RESTART_KEYS = ('gaps_reinitialised', 'navigation_resets', 'realignments',
                           'restarts')


def navigation_restarts(health: Mapping[str, Any]) -> int:
    """Navigation restarts of a run (:data:`NAVIGATION_RESTART_KEYS` summed)."""
    return sum(int(health.get(k, 0) or 0) for k in NAVIGATION_RESTART_KEYS)


def input_account(health: Mapping[str, Any], received_imu: int, lost_imu: int,
                  dropped_imu: int, rejected_imu: int, lost_joints: int,
                  stopped: str = '') -> dict[str, Any]:
    """What a live calibration was built from (issue 16 item 8), for the terminal and the file.

    Parameters
    ----------
    health : the estimator's ``health()`` (``imu_processed``: samples through the filter).
    received_imu : raw IMU samples the node received.
    lost_imu : samples lost before the node (stamp gaps: upstream or in DDS).
    dropped_imu : samples the node received but dropped before the estimator (its queue full).
    rejected_imu : samples the node rejected (frame, non-finite, out of order, ...).
    lost_joints : joint states lost before the node (stamp gaps).
    stopped : why the estimator stopped ('' = it did not).

    Returns
    -------
    dict
        ``samples`` (M: received + lost upstream), ``used_samples`` (N), ``lost_imu``,
        ``dropped_imu``, ``rejected_imu``, ``lost_joint_states``, ``navigation_restarts``
        (K), ``partial`` (any loss, drop or restart), ``stopped`` and ``summary``: ``partial:
        used N of M samples, K navigation restarts`` (``complete: ...`` otherwise).
    """
    m = int(received_imu) + int(lost_imu)
    n = int(health.get('imu_processed', 0) or 0)
    k = navigation_restarts(health)
    partial = bool(lost_imu or dropped_imu or rejected_imu or lost_joints or k or stopped)
    summary = f'{"partial" if partial else "complete"}: used {n} of {m} samples, {k} ' \
              f'navigation restart{"" if k == 1 else "s"}'
    if stopped:
        summary += f'; the estimator stopped ({stopped})'
    return {'partial': partial, 'summary': summary, 'used_samples': n, 'samples': m,
            'lost_imu': int(lost_imu), 'dropped_imu': int(dropped_imu),
            'rejected_imu': int(rejected_imu), 'lost_joint_states': int(lost_joints),
            'navigation_restarts': k, 'stopped': stopped}


class StampGapCounter:
    """Messages lost before a subscriber, counted from the gaps in their header stamps.

    The nominal period is the median of the first :attr:`INTERVALS` stamp intervals; after
    that an interval ``d`` longer than 1.5 periods (CONTRACT 1's gap rule) counts
    ``round(d / period) - 1`` lost messages (the intervals it was learnt from too).
    """

    INTERVALS = 20

    def __init__(self) -> None:
        self.reset()

    def reset(self) -> None:
        """Forget the last stamp (a time jump, a reset); the period is kept."""
        self._last: int | None = None
        if not hasattr(self, 'period_ns'):
            self.period_ns: float | None = None
            self._learning: list[int] = []

    def push(self, stamp_ns: int) -> int:
        """One stamp; returns how many messages it shows lost (0 until the period is known,
        then the learning intervals' losses all at once)."""
        last, self._last = self._last, int(stamp_ns)
        if last is None or stamp_ns <= last:
            return 0
        d = int(stamp_ns) - last
        if self.period_ns is None:
            self._learning.append(d)
            if len(self._learning) < self.INTERVALS:
                return 0
            self.period_ns = float(sorted(self._learning)[len(self._learning) // 2])
            lost = sum(self._lost(x) for x in self._learning)
            self._learning = []
            return lost
        return self._lost(d)

    def _lost(self, d: int) -> int:
        assert self.period_ns is not None
        return max(round(d / self.period_ns) - 1, 0) if d > 1.5 * self.period_ns else 0
