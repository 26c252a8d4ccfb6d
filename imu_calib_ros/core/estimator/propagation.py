"""One block of IMU samples through the navigator: compensation, strapdown, transition rows.

A block is ``B`` chunks of ``n`` samples (plus one sample of look-ahead). Per block, all
vectorised:

1. intervals from the stamps; a gap (> 1.5 nominal periods) counts as one nominal period
   and resets the navigator's coning/sculling memory;
2. compensate the raw samples with the current estimate (``sensor_model.compensate``), the
   size effect with ``omega_dot`` from central differences of neighbouring compensated mean
   rates (Kozlov & Kapralov eq. 1; METHODS.md "cuts across"), the accelerometer time offset
   with the same differences of the specific force;
3. ``Strapdown.propagate`` over the whole block;
4. every chunk's 6 navigation rows of ``Phi`` (:func:`~.ekf.chunk_transition_rows`, with
   the sensor Jacobians of the compensated samples), scaled to the filter's units.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .. import sensor_model as sm
from ..strapdown import Strapdown
from . import error_model as em
from .ekf import chunk_transition_rows
from .error_model import StateLayout

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]


@dataclass(frozen=True)
class Block:
    """What the measurement updates of a block need from its propagation."""

    rows_s: FloatArray  # (B, 6, n) navigation rows of each chunk's Phi, scaled units
    T_s: FloatArray  # (B,) length of each chunk [s]
    ends: NDArray[np.intp]  # (B,) index of each chunk's last sample in the block
    R_enu_imu_end: FloatArray  # (B, 3, 3) navigated attitude at the chunk ends
    v_enu_end_m_s: FloatArray  # (B, 3) navigated velocity at the chunk ends
    omega_ib_end_rad_s: FloatArray  # (B, 3) compensated rate at the chunk-end instants
    n_gaps: int  # intervals longer than 1.5 nominal periods


def propagate_block(nav: Strapdown, errors: Any, time_offset_s: float,
                    prev: tuple[int, FloatArray, FloatArray] | None, t: IntArray,
                    w: FloatArray, f: FloatArray, nominal_dt_s: float, B: int, n: int,
                    layout: StateLayout, omega_ie_enu_rad_s: FloatArray) -> Block:
    """Propagate ``nav`` (in place) over ``B`` chunks of ``n`` samples.

    Parameters
    ----------
    nav :
        The navigator, at the end of the previous block.
    errors :
        :class:`~imu_calib_ros.core.sensor_model.SensorErrors`: the current estimate.
    time_offset_s :
        Accelerometer-minus-gyro time offset estimate (0 when not a state).
    prev :
        ``(stamp, raw gyro, raw accel)`` of the sample before ``t[0]``, or None at the first
        block after an alignment (then one nominal period before ``t[0]``).
    t, w, f : (B n + 1,), (B n + 1, 3), (B n + 1, 3)
        Stamps [ns], raw mean rates and specific forces; the last sample is the look-ahead.
    nominal_dt_s, B, n, layout, omega_ie_enu_rad_s :
        Sample period, chunks, samples per chunk, state layout, earth rate (ENU).
    """
    m = B * n
    nom = nominal_dt_s
    # intervals; a gap (> 1.5 nominal periods) is a sample of one nominal period
    if prev is None:
        t_prev, w_prev, f_prev = int(t[0]) - int(round(nom * 1e9)), w[0], f[0]
    else:
        t_prev, w_prev, f_prev = prev
    tt = np.concatenate([[t_prev], t]).astype(np.int64)
    dt_all = np.diff(tt) * 1e-9  # (m + 1,)
    gap = dt_all > 1.5 * nom
    n_gaps = int(gap[:m].sum())
    dt_all = np.where(gap, nom, dt_all)
    ww = np.vstack([w_prev, w])  # (m + 2, 3): previous, block, look-ahead
    ff = np.vstack([f_prev, f])
    # central differences of mean rates: omega_dot at the interval (Kozlov eq. 1 term)
    den = (dt_all[:-1] + dt_all[1:])[:, None]
    # of the compensated rates: with raw ones, a raw unit's 0.5 % scale error made the
    # size effect 1 % (6 sigma) wrong (issue 11); the gyro part needs no omega_dot
    ww = sm.compensate(errors, ww, ff, np.zeros_like(ww))[0]
    wd = (ww[2:] - ww[:-2]) / den  # (m, 3)
    fd = (ff[2:] - ff[:-2]) / den
    wd_all = np.vstack([wd, wd[-1:]])  # look-ahead: reuse
    w_c, f_c = sm.compensate(errors, w, f, wd_all)
    if time_offset_s != 0.0:
        f_c = f_c - time_offset_s * np.vstack([fd, fd[-1:]])
    dt = dt_all[:m]
    if n_gaps:
        nav.reset_memory()
    R_start = nav.R_enu_imu
    out = nav.propagate(dt, w_c[:m], f_c[:m])
    R_mid = 0.5 * (np.concatenate([R_start[None], out.R_enu_imu[:-1]]) + out.R_enu_imu)
    # sensor Jacobians on the compensated samples
    Mg, Ma = em.compensated_jacobians(errors, w_c[:m], wd, f_c[:m], fd)
    rows = chunk_transition_rows(layout, R_mid.reshape(B, n, 3, 3),
                                 out.f_enu_m_s2.reshape(B, n, 3),
                                 Mg.reshape(B, n, 3, em.N_GYRO),
                                 Ma.reshape(B, n, 3, em.N_ACCEL), dt.reshape(B, n),
                                 omega_ie_enu_rad_s)
    s = layout.scale
    rows_s = rows * (s[None, None, :] / s[None, 0:6, None])
    ends = np.arange(n - 1, m, n)
    return Block(rows_s=rows_s, T_s=dt.reshape(B, n).sum(axis=1), ends=ends,
                 R_enu_imu_end=out.R_enu_imu[ends], v_enu_end_m_s=out.v_enu_m_s[ends],
                 omega_ib_end_rad_s=0.5 * (w_c[ends] + w_c[ends + 1]), n_gaps=n_gaps)
