"""Rotation modulation of IMU errors: the MEMS paper's averaging schemes and a continuous mode.

Seed ``004`` (rotation modulation of a MEMS IMU on a platform turning about its Z axis).
Frames: ``s`` = IMU (sensor) frame; ``b`` = platform-base ("body") frame, defined as the IMU
frame when the modulation joint is at zero (the platform base; control points at joint
angles that are multiples of 360/n deg). With ``u`` the joint axis in the IMU frame
(constant) and ``phi = q``: ``R_b_s = Rot(u, phi)`` (one convention, tested; the paper's eqs. 5-6 mix C_S^B and C_B^S).

- :func:`demodulate_points` (paper eqs. 12-14): the X/Y (perpendicular to ``u``) error
  estimate is the mean of the raw sensor-frame output over the last complete revolution,
  weighted by angle (eq. 12); at each control point (every 360/n deg, n = 1, 2, 4) one
  body-frame sample is output: the raw sample at the control point minus that estimate,
  rotated with the control point's exactly known ``R_b_s`` (eq. 13/14), and the platform
  rate (mean over the last interval, from the joint) removed from the gyro. Output rate =
  n times the rotation frequency (the paper's limitation).
- :func:`demodulate_continuous` (METHODS.md sect. 3): every sample is de-rotated with the
  joint angle, and the modulated biases are tracked at full rate as the angle-weighted mean
  of the sensor-frame output over one revolution around (offline) or before (causal) each
  sample. Output at the full IMU rate.
"""
from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..errors import InputError
from ..rotation import rot_axis_angle
from ..types import ImuBatch, JointBatch
from .windows import joint_positions

FloatArray = NDArray[np.float64]
MODES = {'one': 1, 'two': 2, 'four': 4}


def _setup(imu: ImuBatch, joints: JointBatch, fixture: Any, joint: str | None,
           ) -> tuple[int, FloatArray, FloatArray, FloatArray]:
    """Modulation joint index, its angle at the IMU stamps and at the interval starts, and
    its axis in the IMU frame."""
    names = tuple(fixture.joint_names)
    q = joint_positions(joints, names)
    if joint is None:
        k = int(np.argmax(np.abs(q[-1] - q[0])))
    else:
        if joint not in names:
            raise InputError(f'--joint {joint!r} is not a fixture joint (have {list(names)})')
        k = names.index(joint)
    tj = (joints.stamps_ns - joints.stamps_ns[0]) * 1e-9
    ti = (imu.stamps_ns - joints.stamps_ns[0]) * 1e-9
    dt = np.diff(ti, prepend=ti[0] - float(np.median(np.diff(ti))))
    phi_end = np.interp(ti, tj, q[:, k])
    phi_start = np.interp(ti - dt, tj, q[:, k])
    if abs(phi_end[-1] - phi_end[0]) < 2 * np.pi:
        raise InputError(f'joint {names[k]!r} turns less than one revolution: no modulation')
    q_ax = q[0].copy()
    q_ax[k] = 0.0
    u = fixture.joint_axes_imu(q_ax)[k]
    return k, phi_start, phi_end, u / np.linalg.norm(u)


def _revolution_mean(x: FloatArray, phi0: FloatArray, phi1: FloatArray, centre: FloatArray,
                     causal: bool) -> FloatArray:
    """Angle-weighted mean of ``x`` over one revolution (eq. 12), for each ``centre`` angle.

    Sample k covers the angle interval ``[phi0_k, phi1_k]``; the revolution is
    ``(c - 2 pi, c]`` (causal) or ``(c - pi, c + pi]``; it is clamped into the recording.
    """
    sgn = 1.0 if phi1[-1] >= phi1[0] else -1.0
    a0, a1 = sgn * phi0, sgn * phi1
    c = sgn * centre
    w = a1 - a0
    cw = np.concatenate([[0.0], np.cumsum(w)])
    cx = np.concatenate([np.zeros((1, x.shape[1])), np.cumsum(x * w[:, None], axis=0)])
    hi = c if causal else c + np.pi
    hi = np.clip(hi, a0[0] + 2 * np.pi, a1[-1])
    lo = hi - 2 * np.pi
    # the cumulative sums are piecewise linear in angle (x constant over a sample): exact
    # partial samples at both ends by interpolation (end angles of a turning platform are
    # monotonic; np.maximum.accumulate guards against encoder jitter)
    edges = np.maximum.accumulate(np.concatenate([[a0[0]], a1]))
    wsum = np.interp(hi, edges, cw) - np.interp(lo, edges, cw)
    xs = np.stack([np.interp(hi, edges, cx[:, k]) - np.interp(lo, edges, cx[:, k])
                   for k in range(x.shape[1])], axis=1)
    return xs / np.where(wsum > 0, wsum, 1.0)[:, None]


def _derotate(u: FloatArray, phi0: FloatArray, phi1: FloatArray, v_s: FloatArray) -> FloatArray:
    """Body-frame mean of a body-fixed vector from its sensor-frame interval mean.

    For a rotation at constant rate within the interval, the mean of ``R_s_b`` is
    ``R_s_b(phi_mid) (u u^T + sinc(dphi/2) (I - u u^T))``; invert it exactly.
    """
    mid = 0.5 * (phi0 + phi1)
    half = 0.5 * (phi1 - phi0)
    s = np.sinc(half / np.pi)
    v_b = np.einsum('nij,nj->ni', rot_axis_angle(u, mid), v_s)
    ax = (v_b @ u)[:, None] * u
    return ax + (v_b - ax) / s[:, None]


def demodulate_continuous(imu: ImuBatch, joints: JointBatch, fixture: Any, *,
                          joint: str | None = None, causal: bool = False,
                          frame_id: str | None = None) -> ImuBatch:
    """Full-rate body-frame stream with the modulated biases removed (continuous mode).

    Parameters
    ----------
    imu, joints, fixture
        Raw IMU data, joint states, fixture (modulation joint axis from its kinematics).
    joint : str, optional
        The modulation joint (default: the joint that turns most).
    causal : bool
        Bias over the preceding revolution only (live use) instead of a centred one.

    Returns
    -------
    ImuBatch
        Same stamps; gyro = body rate relative to inertial space minus the platform rate,
        accel = specific force, both in the body frame ``b``.
    """
    _, phi0, phi1, u = _setup(imu, joints, fixture, joint)
    P = np.eye(3) - np.outer(u, u)
    gyro = np.asarray(imu.gyro_rad_s, float)
    accel = np.asarray(imu.accel_m_s2, float)
    centre = 0.5 * (phi0 + phi1)
    bg = _revolution_mean(gyro, phi0, phi1, centre, causal) @ P
    ba = _revolution_mean(accel, phi0, phi1, centre, causal) @ P
    dt = np.diff(imu.stamps_ns, prepend=imu.stamps_ns[0] - np.median(np.diff(imu.stamps_ns)))
    rate = ((phi1 - phi0) / (dt * 1e-9))[:, None] * u  # platform rate, same in s and b
    w_b = _derotate(u, phi0, phi1, gyro - bg - rate)
    f_b = _derotate(u, phi0, phi1, accel - ba)
    return ImuBatch(imu.stamps_ns.copy(), w_b, f_b, frame_id or f'{imu.frame_id}_body')


def demodulate_points(imu: ImuBatch, joints: JointBatch, fixture: Any, mode: str = 'one', *,
                      joint: str | None = None, frame_id: str | None = None) -> ImuBatch:
    """The paper's one-, two- or four-point scheme (eqs. 12-14): output at the control points.

    Parameters
    ----------
    mode : {'one', 'two', 'four'}
        Control points every 360, 180 or 90 degrees.

    Returns
    -------
    ImuBatch
        One sample per control-point crossing after the first complete revolution, stamped
        at the raw sample that crosses it; values in the body frame ``b``.
    """
    if mode not in MODES:
        raise InputError(f'--mode must be one of {sorted(MODES)} or continuous, got {mode!r}')
    n = MODES[mode]
    _, phi0, phi1, u = _setup(imu, joints, fixture, joint)
    P = np.eye(3) - np.outer(u, u)
    gyro = np.asarray(imu.gyro_rad_s, float)
    accel = np.asarray(imu.accel_m_s2, float)
    sgn = 1.0 if phi1[-1] >= phi1[0] else -1.0
    step = 2 * np.pi / n
    # raw samples whose interval contains a control point (angle = multiple of the step)
    k0 = np.floor(sgn * phi0 / step)
    k1 = np.floor(sgn * phi1 / step)
    idx = np.flatnonzero((k1 > k0) & (sgn * (phi1 - phi0[0]) >= 2 * np.pi))
    if idx.size < 2:
        raise InputError('fewer than two control points after the first revolution')
    cp = sgn * k1[idx] * step  # the control point's angle (exact R_b_s there: eq. 14)
    bg = _revolution_mean(gyro, phi0, phi1, cp, True) @ P
    ba = _revolution_mean(accel, phi0, phi1, cp, True) @ P
    t = imu.stamps_ns[idx]
    # platform rate = control-point step / time between crossings (the paper's "indirect
    # estimate from the rotation period"); crossing times interpolated inside the sample
    dt = np.diff(imu.stamps_ns, prepend=imu.stamps_ns[0] - np.median(np.diff(imu.stamps_ns)))
    frac = (cp - phi0[idx]) / (phi1[idx] - phi0[idx])
    t_cross = (t - dt[idx] * (1.0 - frac)) * 1e-9
    rate = np.diff(cp) / np.diff(t_cross)
    rate = np.concatenate([[rate[0]], rate])
    R = rot_axis_angle(u, cp)
    w_b = np.einsum('nij,nj->ni', R, gyro[idx] - bg - rate[:, None] * u)
    f_b = np.einsum('nij,nj->ni', R, accel[idx] - ba)
    return ImuBatch(t.copy(), w_b, f_b, frame_id or f'{imu.frame_id}_body')


def demodulate(imu: ImuBatch, joints: JointBatch, fixture: Any, mode: str, **kw: Any,
               ) -> ImuBatch:
    """Dispatch on ``mode`` in ``one | two | four | continuous``."""
    if mode == 'continuous':
        return demodulate_continuous(imu, joints, fixture, **kw)
    return demodulate_points(imu, joints, fixture, mode, **kw)
