"""The estimate: calibration-state values and covariance, and its CONTRACT 4 result.

:class:`Estimate` holds the full parameter arrays the navigator compensates with and the
calibration states (everything but psi and dv) with their SI covariance. The conversions
between the two views and the calibration file's layout (CONTRACT 4: estimated groups carry
their filter sigma, the others their assumed value, zero, and prior sigma, listed as fixed)
live here.
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, cast

import numpy as np
from numpy.typing import NDArray

from .. import parameters as registry
from .. import sensor_model as sm
from ..calibration import CalibrationResult
from . import error_model as em
from .error_model import StateLayout
from .priors import WorkingPoint

FloatArray = NDArray[np.float64]

# CONTRACT 4 keys and the state groups that make them up (the registry's)
CONTRACT_KEYS: dict[str, tuple[str, ...]] = dict(registry.GROUPS_OF_KEY)


@dataclass(frozen=True)
class Estimate:
    """Full estimate in SI: sensor parameters, auxiliary states and their covariance."""

    theta_gyro: FloatArray  # (22,) full gyro parameter vector (error_model order)
    theta_accel: FloatArray  # (26,) full accel parameter vector
    lever_arm_imu_m: FloatArray  # (3,) reference point offset from the axes, IMU frame
    mounting_rotvec_rad: FloatArray  # (3,) mounting rotation estimate, IMU frame
    labels: tuple[str, ...]  # labels of the calibration states (no psi, dv)
    values: FloatArray  # (m,) SI values of those states
    covariance: FloatArray  # (m, m) SI covariance of those states


def values_of(layout: StateLayout, tg: FloatArray, ta: FloatArray, rho: FloatArray,
              mount: FloatArray, joint_offsets: FloatArray | None = None) -> FloatArray:
    """Calibration-state values (no psi, dv) of a working point's parameter arrays (and a
    general chain's joint zero offsets; None: zero)."""
    out = np.zeros(layout.n)
    out[layout.gyro_state_idx] = tg[layout.gyro_cols]
    out[layout.accel_state_idx] = ta[layout.accel_cols]
    if 'lever_arm' in layout.slices:
        out[layout.slices['lever_arm']] = rho
    if 'mounting' in layout.slices:
        out[layout.slices['mounting']] = mount
    if layout.n_joint_offsets and joint_offsets is not None:
        out[layout.slices[em.CHAIN_GROUP]] = joint_offsets
    return out[6:]


def with_values(layout: StateLayout, values: FloatArray, tg: FloatArray, ta: FloatArray,
                rho: FloatArray, mount: FloatArray) -> WorkingPoint:
    """The parameter arrays with the calibration states set to ``values`` (the inverse of
    :func:`values_of`; entries that are not states keep their values)."""
    full = np.concatenate([np.zeros(6), values])
    tg, ta = tg.copy(), ta.copy()
    tg[layout.gyro_cols] = full[layout.gyro_state_idx]
    ta[layout.accel_cols] = full[layout.accel_state_idx]
    if 'lever_arm' in layout.slices:
        rho = full[layout.slices['lever_arm']].copy()
    if 'mounting' in layout.slices:
        mount = full[layout.slices['mounting']].copy()
    return tg, ta, rho, mount


def calibration_result(st: Estimate, layout: StateLayout, prior: dict[str, FloatArray],
                       frame_id: str,
                       extra_of: Callable[[FloatArray], dict[str, Any]]) -> CalibrationResult:
    """An estimate as a :class:`~imu_calib_ros.core.calibration.CalibrationResult`.

    Estimated groups carry their sigma, the others their prior sigma and are listed as fixed
    (CONTRACT 4); ``extra_of(sd)``, ``sd`` the calibration states' sigmas, gives the extra
    keys.
    """
    sig_g = np.zeros(em.N_GYRO)
    sig_a = np.zeros(em.N_ACCEL)
    for grp in em.GYRO_GROUPS:
        sig_g[em.gyro_cols(grp)] = prior[grp]
    for grp in em.ACCEL_GROUPS:
        sig_a[em.accel_cols(grp)] = prior[grp]
    sd = np.sqrt(np.clip(np.diag(st.covariance), 0.0, None))
    for grp in layout.groups:
        sl = slice(layout.slices[grp].start - 6, layout.slices[grp].stop - 6)
        if grp in em.GYRO_GROUPS:
            sig_g[em.gyro_cols(grp)] = sd[sl]
        elif grp in em.ACCEL_GROUPS:
            sig_a[em.accel_cols(grp)] = sd[sl]
    errors = cast(sm.SensorErrors,
                  em.errors_from_theta(st.theta_gyro, st.theta_accel, sm.SensorErrors))
    sigma = cast(sm.SensorErrors, em.errors_from_theta(sig_g, sig_a, sm.SensorErrors))
    fixed = tuple(k for k, gs in CONTRACT_KEYS.items()
                  if not any(grp in layout.groups for grp in gs))
    return CalibrationResult(errors=errors, sigma=sigma, frame_id=frame_id, fixed=fixed,
                             extra=extra_of(sd))


_PARAMETER_MAPS: dict[tuple[str, ...], FloatArray] = {}


def _parameter_map(layout: StateLayout) -> FloatArray:
    """``d SensorErrors.as_vector() / d (calibration states)`` (45, n - 6), built once per
    layout column by column through :func:`with_values` and ``errors_from_theta`` (every
    live snapshot asks for it; the layout never changes within a run)."""
    key = tuple(layout.state_labels)
    J = _PARAMETER_MAPS.get(key)
    if J is None:
        zg, za, z3 = np.zeros(em.N_GYRO), np.zeros(em.N_ACCEL), np.zeros(3)
        m = layout.n - 6
        J = np.zeros((sm.N_PARAMETERS, m))
        for j in range(m):
            e = np.zeros(m)
            e[j] = 1.0
            tg, ta, _, _ = with_values(layout, e, zg, za, z3, z3)
            J[:, j] = em.errors_from_theta(tg, ta, sm.SensorErrors).as_vector()
        J.setflags(write=False)
        _PARAMETER_MAPS[key] = J
    return J


def parameter_covariance(st: Estimate, layout: StateLayout,
                         prior: dict[str, FloatArray]) -> FloatArray:
    """Covariance (45, 45) of ``SensorErrors.as_vector()`` (CONTRACT 4 order): the filter's
    for the estimated groups (their correlations included), the prior variance on the
    diagonal for groups held fixed. The map from the calibration states is linear (a
    selection; the gyro misalignment pair is one state, :func:`_parameter_map`)."""
    J = _parameter_map(layout)
    cov = J @ st.covariance @ J.T
    sig_g, sig_a = np.zeros(em.N_GYRO), np.zeros(em.N_ACCEL)
    for grp in em.GYRO_GROUPS:
        if grp not in layout.groups:
            sig_g[em.gyro_cols(grp)] = prior[grp]
    for grp in em.ACCEL_GROUPS:
        if grp not in layout.groups:
            sig_a[em.accel_cols(grp)] = prior[grp]
    fixed = em.errors_from_theta(sig_g, sig_a, sm.SensorErrors).as_vector()
    cov[np.diag_indices_from(cov)] += fixed ** 2
    return 0.5 * (cov + cov.T)


def estimator_extra(est: Estimate, sd: FloatArray, layout: StateLayout,
                    health: dict[str, Any], attitude_aiding: bool = False,
                    start: Any = None) -> dict[str, Any]:
    """The ``estimator`` extra key of a result: auxiliary states with their sigmas, the
    estimated groups, whether encoder aiding ran, what the coarse start measured (issue 11:
    what the data chose) and the plain values of ``health`` (CalibrationEstimator.health)."""
    out: dict[str, Any] = {
        'lever_arm_imu_m': [float(v) for v in est.lever_arm_imu_m],
        'mounting_rotvec_rad': [float(v) for v in est.mounting_rotvec_rad],
        'time_offset_s': float(est.theta_accel[em.accel_cols('time_offset')][0]),
        'gyro_sample_kernel': float(est.theta_gyro[em.gyro_cols('gyro_sample_kernel')][0]),
        'accel_sample_kernel': float(est.theta_accel[em.accel_cols('accel_sample_kernel')][0]),
        'estimated_groups': list(layout.groups),
        'attitude_aiding': bool(attitude_aiding),
    }
    if start is not None:
        out['coarse_start'] = start.summary()
    for g in ('lever_arm', 'mounting', 'time_offset', 'gyro_sample_kernel',
              'accel_sample_kernel'):
        if g in layout.slices:
            sl = slice(layout.slices[g].start - 6, layout.slices[g].stop - 6)
            out[f'{g}_sigma'] = [float(v) for v in sd[sl]]
    if layout.n_joint_offsets:  # a general chain's joint zero offsets (issue 15), not CONTRACT
        sl = slice(layout.slices[em.CHAIN_GROUP].start - 6, layout.slices[em.CHAIN_GROUP].stop - 6)
        out['joint_offset_rad'] = [float(v) for v in est.values[sl]]
        out['joint_offset_sigma_rad'] = [float(v) for v in sd[sl]]
    out['health'] = {k: v for k, v in health.items()
                     if isinstance(v, (int, float, bool, str))}
    # the input guard's rejections by reason (the report's verdict names them)
    rejected = {str(k): int(v) for k, v in (health.get('rejected') or {}).items() if v}
    if rejected:
        out['health']['rejected'] = rejected
    return out


def snapshot_extra(est: Estimate, layout: StateLayout) -> dict[str, Any]:
    """The ``estimator`` extra key of the last good snapshot's result."""
    return {'last_good_snapshot': True,
            'lever_arm_imu_m': [float(v) for v in est.lever_arm_imu_m],
            'estimated_groups': list(layout.groups)}
