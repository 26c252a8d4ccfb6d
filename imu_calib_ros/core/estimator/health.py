"""Health of the filter: divergence checks, the NIS window, the status line, fallbacks.

After every block the estimator asks, in this order (the first answer wins): is anything
non-finite, has ``P`` lost positive definiteness (Cholesky), is the navigated velocity out of
range, has a calibration state left its prior by ``state_range_sigmas``, and over the last
``nis_window`` measurement updates, did too many fail the chi-square gate or is the mean NIS
per dof too high (Bar-Shalom, Li & Kirubarajan, "Estimation with applications to tracking
and navigation", sect. 5.4: filter consistency)? A healthy block is a snapshot; a diverged
filter restarts from the coarse start with its prior covariance inflated
(:func:`restart_covariance`), and after ``max_restarts`` rolls back to the oldest snapshot
(:func:`rollback_covariance`). Data lost in a gap widen the covariance instead
(:func:`widen_for_gaps`, :func:`bridge_gap`). This module judges and computes; the estimator
acts.
"""
from __future__ import annotations

from collections import deque
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.linalg.lapack import dpotrf as _potrf

from ..input_guard import GuardConfig, InputGuard
from ..rotation import skew
from .ekf import GateCounters
from .error_model import StateLayout

FloatArray = NDArray[np.float64]


def numerical_fault(P: FloatArray, x: FloatArray, values: FloatArray, v_enu_m_s: FloatArray,
                    max_velocity_m_s: float) -> str | None:
    """A non-finite state or covariance, a covariance that is not positive definite, or a
    navigated velocity above ``max_velocity_m_s``: the reason, else None."""
    if not (np.isfinite(P).all() and np.isfinite(x).all()
            and np.isfinite(values).all() and np.isfinite(v_enu_m_s).all()):
        return 'non-finite state or covariance'
    # Cholesky of the lower triangle (numpy.linalg.cholesky's test, without its wrapping)
    if _potrf(P, lower=1, clean=0, overwrite_a=0)[1] != 0:
        return ('covariance lost positive definiteness (min eigenvalue '
                f'{float(np.linalg.eigvalsh(P).min()):.3g})')
    speed = float(np.linalg.norm(v_enu_m_s))
    if speed > max_velocity_m_s:
        return f'navigated velocity {speed:.3g} m/s out of range'
    return None


def state_out_of_range(values: FloatArray, prior_mean: FloatArray, prior: FloatArray,
                       layout: StateLayout, range_sigmas: float) -> str | None:
    """A calibration state (``values``, no psi, dv) further than ``range_sigmas`` prior
    sigmas from its prior mean (the coarse start): the reason naming the worst state, else
    None."""
    dev = np.abs(values - prior_mean)
    over = dev > range_sigmas * prior
    if not over.any():
        return None
    i = int(np.argmax(dev / np.where(prior > 0, prior, np.inf)))
    return (f'state {layout.labels()[6 + i]} = {values[i]:.3g} beyond {range_sigmas:g} prior '
            'sigmas from its prior mean')


class NisWindow:
    """The filter's cumulative update counts at block ends, over the last ``size`` updates.

    Each entry is ``(accepted, rejected, NIS sum)`` over all measurement kinds; the window
    keeps the newest entry and the oldest one that still leaves ``size`` updates after it.
    """

    def __init__(self, size: int) -> None:
        self.size = size
        self._hist: deque[tuple[int, int, float]] = deque()

    def clear(self) -> None:
        """Start a new window (a new filter, or a new Q to judge on fresh updates)."""
        self._hist.clear()

    def push(self, c: GateCounters) -> None:
        """Record the filter's counters at a block end."""
        tot = (sum(c.accepted.values()), sum(c.rejected.values()), sum(c.nis_sum.values()))
        hist = self._hist
        hist.append(tot)
        n = tot[0] + tot[1]
        while len(hist) > 1 and n - (hist[1][0] + hist[1][1]) >= self.size:
            hist.popleft()

    def span(self) -> tuple[int, int, float] | None:
        """``(accepted, rejected, NIS sum)`` from the oldest to the newest entry, or None
        with fewer than two entries."""
        hist = self._hist
        if len(hist) < 2:
            return None
        a0, r0, s0 = hist[0]
        a1, r1, s1 = hist[-1]
        return a1 - a0, r1 - r0, s1 - s0

    def reason(self, max_rejected_fraction: float, max_mean_nis_per_dof: float) -> str | None:
        """Gate rejections or mean NIS over the window out of bounds: the reason, else None
        (also None until the window spans ``size`` updates)."""
        hist = self._hist
        tot = hist[-1]
        a0, r0, s0 = hist[0]
        n_win = tot[0] + tot[1] - a0 - r0
        if n_win < self.size:
            return None
        rej = tot[1] - r0
        if rej > max_rejected_fraction * n_win:
            return f'{rej} of the last {n_win} measurement updates failed the chi-square gate'
        acc = tot[0] - a0
        if acc:
            mean = (tot[2] - s0) / acc / 3.0  # all our measurements are 3-D
            if mean > max_mean_nis_per_dof:
                return f'mean NIS per dof {mean:.3g} over the last {acc} updates'
        return None


def snapshots(guard_config: GuardConfig, block_chunks: int) -> deque[Any]:
    """An empty deque for the healthy-block snapshots: deep enough that its oldest entry is
    from before the NIS window that declares a divergence."""
    return deque(maxlen=2 + -(-guard_config.nis_window // block_chunks))


def restart_covariance(prior: FloatArray, layout: StateLayout, restarts: int) -> FloatArray:
    """The calibration block of ``P`` (scaled) a restart starts from: the prior sigmas
    ``prior`` (SI, state order) inflated x2 per restart."""
    if not layout.groups:
        return np.zeros((0, 0))
    return np.diag((prior * 2.0 ** restarts / layout.scale[6:]) ** 2)


def rollback_covariance(layout: StateLayout, snapshot_cov: FloatArray | None,
                        prior: FloatArray) -> FloatArray:
    """``P`` (scaled) of a filter stopped at divergence: the snapshot's calibration block
    (SI; the prior ``prior`` without one), unit navigation block, no correlation."""
    P = np.zeros((layout.n, layout.n))
    s = layout.scale[6:]
    if snapshot_cov is not None:
        P[6:, 6:] = snapshot_cov / np.outer(s, s)
    else:
        P[6:, 6:] = np.diag((prior / s) ** 2) if layout.groups else 0.0
    P[0:6, 0:6] = np.eye(6)
    return P


def widen_for_gaps(P: FloatArray, layout: StateLayout, n_gaps: int) -> None:
    """Motion during a gap inside a block is lost (CONTRACT 1): widen the navigation block of
    ``P`` (scaled, in place) by 1 mrad and 10 mm/s per gap."""
    widen_navigation(P, layout, np.full(3, 1e-3 ** 2 * n_gaps), np.full(3, 1e-2 ** 2 * n_gaps))


def interpolated_gap_variance(w0: FloatArray, f0: FloatArray, w1: FloatArray, f1: FloatArray,
                              gap_s: float, period_s: float, gyro_noise_rad_s_rt_hz: float,
                              accel_noise_m_s2_rt_hz: float) -> tuple[FloatArray, FloatArray]:
    """Attitude [rad^2] and velocity [(m/s)^2] variances per axis that filling a gap of
    ``gap_s`` by linear interpolation between the samples ``(w0, f0)`` before and
    ``(w1, f1)`` after it can miss: a rate that moves monotonically from ``w0`` to ``w1``
    integrates to anywhere within ``|w1 - w0| gap_s / 2`` of the trapezoid (taken as one
    sigma: the end of a ramp inside the gap comes close to it), and the filled samples share
    the two end samples' noise instead of their own (``gap_s^2 / period_s N^2 / 2`` instead
    of ``gap_s N^2``)."""
    k = gap_s ** 2 / period_s / 2.0
    var_att = (np.abs(w1 - w0) * gap_s / 2.0) ** 2 + k * gyro_noise_rad_s_rt_hz ** 2
    var_vel = (np.abs(f1 - f0) * gap_s / 2.0) ** 2 + k * accel_noise_m_s2_rt_hz ** 2
    return var_att, var_vel


def widen_navigation(P: FloatArray, layout: StateLayout, var_att_rad2: FloatArray,
                     var_vel_m2_s2: FloatArray) -> None:
    """Add the attitude and velocity variances (per axis, SI) to ``P`` (scaled, in place)."""
    P[0:3, 0:3] += np.diag(var_att_rad2) / layout.scale[0] ** 2
    P[3:6, 3:6] += np.diag(var_vel_m2_s2) / layout.scale[3] ** 2


def bridge_gap(P: FloatArray, layout: StateLayout, q1_s: FloatArray, gap_s: float,
               guard_config: GuardConfig) -> None:
    """Carry the filter over a long gap at rest (policy ``'bridge'``): ``P`` (scaled, in
    place) widened by ``bridge_attitude_sigma_rad`` and ``bridge_velocity_sigma_m_s``, the
    biases by their random walk over the gap (``q1_s``: Q per second, scaled)."""
    s = layout.scale
    P[0:3, 0:3] += np.eye(3) * (guard_config.bridge_attitude_sigma_rad / s[0]) ** 2
    P[3:6, 3:6] += np.eye(3) * (guard_config.bridge_velocity_sigma_m_s / s[3]) ** 2
    _add_bias_walk(P, layout, q1_s, gap_s)


def _add_bias_walk(P: FloatArray, layout: StateLayout, q1_s: FloatArray, gap_s: float) -> None:
    """The biases' random walk over a gap (``q1_s``: Q per second, scaled), into ``P``."""
    for grp in ('gyro_bias', 'accel_bias'):
        if grp in layout.slices:
            sl = layout.slices[grp]
            P[sl, sl] += q1_s[sl, sl] * gap_s


def bridge_motion_covariance(P: FloatArray, layout: StateLayout, dF_enu: FloatArray,
                             Ru_enu_m_s: FloatArray, R_enu_imu: FloatArray,
                             omega_eb_imu_rad_s: FloatArray, var_att_rad2: float,
                             var_vel_m2_s2: FloatArray, q1_s: FloatArray, gap_s: float
                             ) -> FloatArray:
    """``P`` (scaled) after a gap during motion bridged with the encoders (issue 11).

    The navigator's attitude is carried across the gap by the fixture's rotation
    ``dF_enu = R_fix(q1) R_fix(q0)^T`` (the mounting cancels), so with
    ``R_hat = exp([psi x]) R`` the attitude error rotates with it and gains the encoder
    increment's error: ``psi1 = dF psi0 + e``, ``e ~ N(0, var_att I)``. The velocity is set to
    the fixture's (:func:`.measurements.zero_velocity`'s model at the first instant after the
    gap), so its error is what makes that model's innovation zero:
    ``dv1 = -[(R u) x] psi1 + R [omega_eb x] x_rho + n``, ``n ~ N(0, var_vel)`` (the old
    ``dv0`` is forgotten). The biases walk over the gap (``q1_s`` per second, scaled).
    """
    n = layout.n
    s = layout.scale
    A = np.eye(n)  # attitude: rotated, every other row kept
    A[0:3, 0:3] = dF_enu
    Q = np.zeros((n, n))
    Q[0:3, 0:3] = np.eye(3) * var_att_rad2
    Si = 1.0 / s
    P1 = (A * Si[:, None] * s[None, :]) @ P @ (A * Si[:, None] * s[None, :]).T \
        + Q * np.outer(Si, Si)
    V = np.eye(n)  # velocity: a function of the new attitude (and the lever arm)
    V[3:6, 3:6] = 0.0
    V[3:6, 0:3] = -skew(Ru_enu_m_s)
    if 'lever_arm' in layout.slices:
        V[3:6, layout.slices['lever_arm']] = R_enu_imu @ skew(omega_eb_imu_rad_s)
    Vs = V * Si[:, None] * s[None, :]
    Qv = np.zeros((n, n))
    Qv[3:6, 3:6] = np.diag(var_vel_m2_s2) / s[3] ** 2
    P2 = Vs @ P1 @ Vs.T + Qv
    _add_bias_walk(P2, layout, q1_s, gap_s)  # the bias random walk continues in the gap
    return 0.5 * (P2 + P2.T)


def status(diverged: str | None, guard: InputGuard, guard_config: GuardConfig,
           joint_samples: int, joint_names: tuple[str, ...],
           now_ns: int | None) -> tuple[str, str]:
    """``('OK'|'WARN'|'ERROR'|'STALE', one-line message)`` for diagnostics (issue 6).

    ERROR: diverged, or a latched units error; STALE: no IMU sample accepted within
    ``stale_after_s`` of ``now_ns``; WARN: joint states without the fixture joints, or bad
    input within the last ``warn_hold_s``.
    """
    g = guard
    cfg = guard_config
    if diverged is not None:
        return 'ERROR', f'filter diverged: {diverged}; use the last good calibration'
    if g.units_error is not None:
        return 'ERROR', g.units_error
    if g.stamps_error is not None:
        return 'ERROR', g.stamps_error
    if now_ns is not None and (g.last_kept_ns is None
                               or now_ns - g.last_kept_ns > cfg.stale_after_s * 1e9):
        return 'STALE', 'no IMU samples accepted recently'
    if g.rejected['joint_missing_names'] and joint_samples == 0:
        return 'WARN', ('joint states lack the fixture joints '
                        f'{", ".join(joint_names)} (got '
                        f'{", ".join(g.unknown_joint_names) or "none"})')
    newest = g.last_stamp_ns
    if g.last_event_ns is not None and newest is not None \
            and newest - g.last_event_ns <= cfg.warn_hold_s * 1e9:
        bad = {k: v for k, v in g.rejected.items() if v}
        what = ', '.join(f'{k} {v}' for k, v in sorted(bad.items())) or 'none'
        return 'WARN', f'bad input: rejected {what}; gaps {g.flagged["gap"]}'
    return 'OK', 'ok'
