"""Input guard: a small, fast, pure classifier of incoming IMU and joint samples (issue 6).

Every sample is either accepted or rejected with exactly one reason, and every reason has a
counter (STYLE 9: count, drop and report; never let a NaN into the filter). Rejected samples
never reach the estimator's buffers, so they never touch the filter state.

IMU reasons, in the order they are tested (the first that applies is counted):

``duplicate_stamp``, ``out_of_order``, ``time_jump_backward``
    stamp equal to / older than the newest stamp seen so far (``time_jump_backward`` when
    older by more than ``time_jump_backward_s``: a looping bag or a ``use_sim_time`` jump);
``frame_id``
    ``header.frame_id`` other than the configured one (when one is configured);
``non_finite``, ``all_zero``, ``saturated``
    NaN/inf; all six values exactly zero (a dead driver); any axis at or beyond the
    configured full-scale range;
``accel_units_g``
    specific force magnitude near 1 instead of near the site gravity: the accelerometers
    report g, not m/s^2 (on a turntable the IMU reference point stays within centimetres of
    the fixed axes, so ``|f| = g`` to within ``omega^2 r``, always "at rest" translationally);
``accel_magnitude``
    ``| |f| / g - 1 |`` above ``accel_magnitude_tolerance`` (not a turntable-mounted IMU
    in m/s^2);
``gyro_units_deg``
    the gyro rate magnitude is ``180/pi`` times the rate magnitude derived from the joint
    encoders (``|omega_ib| = |sum_i u_i qdot_i + Omega_ie|``, frame-free, so the mounting
    does not matter): the gyros report deg/s. Once ``units_latch_count`` samples agree and
    outnumber the consistent ones four to one, the guard latches :attr:`units_error` and
    rejects every later IMU sample with this reason.

Accepted samples may be *flagged* (counted in :attr:`InputGuard.flagged`, not rejected):
``gap`` (interval > ``gap_periods`` nominal periods, CONTRACT 1's 1.5-period rule: the
sample is the mean over its own nominal period) and ``long_gap`` (interval >
``max_gap_s``: the estimator applies ``gap_policy``).

Joint reasons: ``joint_missing_names`` (a message without all fixture joints),
``joint_non_finite``, ``joint_duplicate_stamp``, ``joint_out_of_order``.
"""
from __future__ import annotations

import logging
import math
import time
from collections import deque
from dataclasses import dataclass, field
from typing import Any, Callable, Literal, Mapping

import numpy as np
from numpy.typing import NDArray

from .config import setting
from .stamp_clock import StampClock

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

__all__ = ['GuardConfig', 'ImuVerdict', 'InputGuard', 'IMU_REASONS', 'JOINT_REASONS',
           'rejection_counts']

IMU_REASONS = ('duplicate_stamp', 'out_of_order', 'time_jump_backward', 'frame_id', 'non_finite',
               'all_zero', 'saturated', 'accel_units_g', 'accel_magnitude', 'gyro_units_deg',
               'filter_diverged', 'stamp_scatter')
JOINT_REASONS = ('joint_missing_names', 'joint_non_finite', 'joint_duplicate_stamp',
                 'joint_out_of_order')
RAD_PER_DEG = math.pi / 180.0
#: share of the IMU intervals flagged as gaps, over at least SCATTER_MIN_SAMPLES kept samples
#: since the stamp clock found the stream not periodic, beyond which the stream is refused
#: (:attr:`InputGuard.stamps_error`): a sample after a gap is the mean over its own period only
#: (CONTRACT 1), and bridging one gap after another takes the estimator minutes per minute
SCATTER_GAP_SHARE = 0.05
SCATTER_MIN_SAMPLES = 4096
PEND_MAX = 8193  # newest accepted joint samples kept for the encoder rates
_LOG = logging.getLogger('imu_calib_ros.input')


def rejection_counts(guard: Mapping[str, int] | None,
                     before_guard: Mapping[str, int] | None = None) -> dict[str, int]:
    """Rejected input by reason, each sample once, for reports: ``{'<source>.<reason>': n}``.

    The guard owns the counts of the samples it saw (:attr:`InputGuard.rejected`, in an
    estimator's ``health()['rejected']``): labelled ``guard.<reason>``. ``before_guard``
    holds what a caller dropped before the guard ever saw it (a node's own checks: never in
    the guard's counts), labelled ``node.<reason>``. Zero counters are left out. Not
    rejections, so never here: the ``flagged`` gaps (accepted samples), the filter's gate
    (measurement updates, not input samples), and counters derived from the guard's.
    """
    out = {f'node.{k}': int(v) for k, v in (before_guard or {}).items() if v}
    out.update({f'guard.{k}': int(v) for k, v in (guard or {}).items() if v})
    return out


@dataclass(frozen=True)
class GuardConfig:
    """Limits for bad input, gaps and divergence (single source of defaults, STYLE 5).

    Load from a mapping with :func:`imu_calib_ros.core.config.from_mapping` (strict keys).
    """

    frame_id: str = setting('', "expected IMU header.frame_id; '' accepts any")
    gyro_saturation_rad_s: float = setting(34.906585, 'a sample with any |gyro axis| at or above '
                                      'this is saturated (default 2000 deg/s)', 1e-3)
    accel_saturation_m_s2: float = setting(156.9064, 'a sample with any |accel axis| at or above '
                                      'this is saturated (default 16 g)', 1e-3)
    accel_magnitude_tolerance: float = setting(0.5, 'reject |f| outside g (1 +- this); 0 disables',
                                          0.0, 10.0)
    units_min_rate_rad_s: float = setting(0.05, 'encoder rate above which gyro units are checked',
                                     1e-4)
    units_ratio_tolerance: float = setting(0.3, 'relative tolerance of the 180/pi (deg/s) and 1 '
                                      '(g) signatures', 0.01, 0.9)
    units_latch_count: int = setting(20, 'deg/s-signature samples before the units error latches',
                                1, 100000)
    time_jump_backward_s: float = setting(1.0, 'a stamp older than the newest by more than this '
                                     'is a backward time jump (looping bag)', 0.0)
    gap_periods: float = setting(1.5, 'an interval longer than this many nominal periods is a gap '
                            '(CONTRACT 1)', 1.0)
    max_gap_s: float = setting(1.0, 'a gap longer than this triggers gap_policy', 1e-3)
    interpolate_gap_s: float = setting(
        0.0, 'a shorter gap while the filter runs (a driver dropping a few samples) is filled '
        'by interpolating its neighbours, the navigation covariance widened by what that can '
        'miss (up to 2.4x smaller sigmas on a MEMS unit; off by default: it set off the '
        'bias-noise adaptation on a navigation unit); 0 re-initialises at every gap during '
        'motion', 0.0)
    gap_policy: Literal['reinitialise', 'bridge'] = setting(
        'reinitialise', "long gap: 'reinitialise' the navigation states at the next "
        "stationary window keeping the calibration states and their covariance, or 'bridge' "
        "with inflated covariance (only if the joints did not move across the gap; else "
        "reinitialise)")
    bridge_motion: bool = setting(
        True, 'a gap shorter than max_gap_s while the joints turn is bridged with the rotation '
        'the joint encoders measured across it (attitude error carried, velocity from the '
        'fixture kinematics); False re-initialises the navigation at the next stationary window')
    bridge_encoder_sigma_rad: float = setting(
        1e-6, 'least one-sigma error of an encoder angle in a motion bridge (raised to the '
        'encoder noise the alignment measured at rest)', 0.0)
    bridge_attitude_sigma_rad: float = setting(1e-4, 'attitude sigma added when bridging', 0.0)
    bridge_velocity_sigma_m_s: float = setting(1e-4, 'velocity sigma added when bridging', 0.0)
    nis_window: int = setting(50, 'measurement updates in the divergence window', 5, 100000)
    max_rejected_fraction: float = setting(0.5, 'gate rejections in the window above this '
                                      'fraction: diverged', 0.01, 1.0)
    max_mean_nis_per_dof: float = setting(20.0, 'mean NIS per measurement dof in the window above '
                                     'this: diverged', 1.0)
    state_range_sigmas: float = setting(50.0, 'a calibration state beyond this many prior '
                                        'sigmas has left its physical range: diverged', 3.0)
    max_velocity_m_s: float = setting(1.0, 'navigated velocity above this: diverged (the IMU '
                                      'point stays within centimetres of the axes)', 1e-3)
    warn_hold_s: float = setting(10.0, 'health stays WARN this long (data time) after a rejection '
                            'or gap', 0.0)
    stale_after_s: float = setting(1.0, "health is STALE when no IMU sample was accepted for this "
                              "long before health(now_ns)", 1e-3)
    log_period_s: float = setting(5.0, 'at most one rejection log line per this period (wall)',
                             0.0)


@dataclass(frozen=True)
class ImuVerdict:
    """The outcome of :meth:`InputGuard.check_imu` for one batch."""

    keep: NDArray[np.bool_]  # (N,) accepted samples
    long_gaps: IntArray  # indices into the *accepted* samples that follow a long gap
    gaps: IntArray = field(default_factory=lambda: np.zeros(0, np.int64))  # after any gap
    #: the accepted samples' stamps on the IMU's own clock (:class:`~.stamp_clock.StampClock`:
    #: stamps taken on receipt), or None when they are the stamps given
    stamps_ns: IntArray | None = None


class InputGuard:
    """Classify IMU and joint samples; count rejections by reason (see module docstring).

    Parameters
    ----------
    config:
        :class:`GuardConfig`.
    gravity_m_s2:
        Site gravity (``fixture.site.gravity``): the expected specific-force magnitude.
    joint_names:
        The fixture joints, in fixture order.
    axes_enu:
        ``q (..., n) -> (..., n, 3)`` joint axes in ENU (``Fixture.joint_axes_enu``) for the
        encoder-derived rate; ``None`` disables the gyro units check.
    """

    def __init__(self, config: GuardConfig, gravity_m_s2: float, joint_names: tuple[str, ...],
                 axes_enu: Callable[[FloatArray], FloatArray] | None = None) -> None:
        self.config = config
        self.gravity_m_s2 = float(gravity_m_s2)
        self.joint_names = tuple(joint_names)
        self._axes_enu = axes_enu
        self.rejected: dict[str, int] = {r: 0 for r in IMU_REASONS + JOINT_REASONS}
        self.flagged: dict[str, int] = {'gap': 0, 'long_gap': 0}
        self.units_error: str | None = None
        #: latched when the IMU stamps scatter so that a large share of its intervals look
        #: like gaps (SCATTER_GAP_SHARE): every later sample is rejected ('stamp_scatter')
        self.stamps_error: str | None = None
        self._scatter_kept = 0
        self._scatter_gaps = 0
        self.last_stamp_ns: int | None = None  # newest IMU stamp seen (accepted or not)
        self.last_kept_ns: int | None = None  # newest accepted IMU stamp
        self.last_event_ns: int | None = None  # data time of the newest rejection or gap
        self.unknown_joint_names: tuple[str, ...] = ()
        self._dts: list[int] = []  # first accepted intervals -> nominal period
        self.nominal_period_ns: int | None = None
        # stamps taken on receipt, back on the sender's clock (accepted samples only)
        self.imu_clock = StampClock()
        self.joint_clock = StampClock()
        self._deg_votes = 0
        self._ok_votes = 0
        self._g_votes = 0
        self._last_joint: tuple[int, FloatArray] | None = None  # the stamp as given
        self.last_joint_clock_ns = 0  # the last accepted joint stamp on the sender's clock
        # accepted joint samples not yet turned into rates (done lazily, vectorised): chunks
        # of (stamps (k,), positions (k, n)); only the newest PEND_MAX rows are kept
        self._pend: deque[tuple[IntArray, FloatArray]] = deque()
        self._pend_rows = 0
        self._rate_t = np.zeros(0)  # joint interval mid stamps
        self._rate_v = np.zeros(0)  # |omega_eb_enu| there (encoder-derived)
        self._logged: dict[str, int] = {}
        self._logged_total = 0
        self._logged_units = False
        self._log_wall = -math.inf

    # ----------------------------------------------------------------------------- IMU
    def check_imu(self, stamps_ns: IntArray, gyro_rad_s: FloatArray, accel_m_s2: FloatArray,
                  frame_id: str = '', diverged: bool = False) -> ImuVerdict:
        """Classify a batch (vectorised). Updates the counters and the stamp memory."""
        cfg = self.config
        t = np.asarray(stamps_ns, np.int64)
        w = np.asarray(gyro_rad_s, float).reshape(-1, 3)
        f = np.asarray(accel_m_s2, float).reshape(-1, 3)
        n = len(t)
        if n == 1 and not diverged and self.units_error is None and self.stamps_error is None:
            fast = self._check_one(int(t[0]), w[0], f[0], frame_id)
            if fast is not None:
                return fast
        reason = np.full(n, -1, np.int64)  # index into IMU_REASONS, -1 = accepted

        def mark(mask: NDArray[np.bool_], name: str) -> None:
            reason[(reason < 0) & mask] = IMU_REASONS.index(name)

        first = np.iinfo(np.int64).min if self.last_stamp_ns is None else self.last_stamp_ns
        prev_max = np.maximum.accumulate(np.concatenate([[first], t]))[:-1]
        mark(t == prev_max, 'duplicate_stamp')
        back = t < prev_max
        # prev_max - t computed in float: prev_max may be int64 min
        jump = back & ((prev_max.astype(float) - t) > cfg.time_jump_backward_s * 1e9)
        mark(jump, 'time_jump_backward')
        mark(back, 'out_of_order')
        if cfg.frame_id and frame_id != cfg.frame_id:
            mark(np.ones(n, bool), 'frame_id')
        if diverged:
            mark(np.ones(n, bool), 'filter_diverged')
        if self.stamps_error is not None:
            mark(np.ones(n, bool), 'stamp_scatter')
        finite = np.isfinite(w).all(axis=1) & np.isfinite(f).all(axis=1)
        mark(~finite, 'non_finite')
        with np.errstate(invalid='ignore'):
            mark((w == 0).all(axis=1) & (f == 0).all(axis=1), 'all_zero')
            mark((np.abs(w) >= cfg.gyro_saturation_rad_s).any(axis=1)
                 | (np.abs(f) >= cfg.accel_saturation_m_s2).any(axis=1), 'saturated')
            fmag = np.linalg.norm(f, axis=1)
            g_units = np.abs(fmag - 1.0) < cfg.units_ratio_tolerance
            open_ = reason < 0
            self._g_votes += int((g_units & open_).sum())
            mark(g_units, 'accel_units_g')
            if cfg.accel_magnitude_tolerance > 0:
                mark(np.abs(fmag / self.gravity_m_s2 - 1.0) > cfg.accel_magnitude_tolerance,
                     'accel_magnitude')
        if self._g_votes >= cfg.units_latch_count and self.units_error is None:
            self.units_error = ('accelerometer values look like g, not m/s^2 (|f| ~ 1 instead '
                                f'of {self.gravity_m_s2:.3f}): fix the driver units')
        self._check_gyro_units(t, w, reason)
        if self.units_error is not None and self.units_error.startswith('gyro'):
            mark(np.ones(n, bool), 'gyro_units_deg')
        keep = reason < 0
        self.last_stamp_ns = int(max(first, int(t.max()))) if n else self.last_stamp_ns
        if n and not keep.all():
            counts = np.bincount(reason[~keep], minlength=len(IMU_REASONS))
            for i in np.nonzero(counts)[0]:
                self.rejected[IMU_REASONS[i]] += int(counts[i])
            self.last_event_ns = int(np.maximum(t, prev_max)[~keep].max())
        kt = self.imu_clock(t[keep])
        long_gaps, gaps = self._gaps(kt)
        self._watch_scatter(len(kt), len(gaps))
        self._log()
        c = self.imu_clock
        return ImuVerdict(keep, long_gaps, gaps,
                          kt if c.smoothing or c.hindsight is not None else None)

    def _check_one(self, t: int, w: FloatArray, f: FloatArray,
                   frame_id: str) -> ImuVerdict | None:
        """Scalar fast path for the common single good sample (~10x faster than the arrays);
        None: let the vectorised path classify it (any doubt, a gap, or motion)."""
        cfg = self.config
        last = self.last_stamp_ns
        if (last is not None and t <= last) or not self.imu_clock.decided \
                or self.imu_clock.smoothing:  # the clock learns, or replaces the stamps
            return None
        if cfg.frame_id and frame_id != cfg.frame_id:
            return None
        wx, wy, wz = float(w[0]), float(w[1]), float(w[2])
        fx, fy, fz = float(f[0]), float(f[1]), float(f[2])
        wmax = max(abs(wx), abs(wy), abs(wz))
        fmax = max(abs(fx), abs(fy), abs(fz))
        if not (wmax < cfg.gyro_saturation_rad_s and 0.0 < fmax < cfg.accel_saturation_m_s2):
            return None  # NaN, zero, saturated (NaN fails every comparison)
        fmag = math.sqrt(fx * fx + fy * fy + fz * fz)
        if abs(fmag - 1.0) < cfg.units_ratio_tolerance or (
                cfg.accel_magnitude_tolerance > 0
                and abs(fmag / self.gravity_m_s2 - 1.0) > cfg.accel_magnitude_tolerance):
            return None
        if math.sqrt(wx * wx + wy * wy + wz * wz) > 0.5 * cfg.units_min_rate_rad_s \
                and self._axes_enu is not None:
            return None
        lk = self.last_kept_ns
        if lk is not None and (self.nominal_period_ns is None or t - lk > min(
                cfg.gap_periods * self.nominal_period_ns, cfg.max_gap_s * 1e9)):
            return None
        self.last_stamp_ns = t
        self.last_kept_ns = t
        return ImuVerdict(np.ones(1, bool), np.zeros(0, np.int64))

    def _gaps(self, kt: IntArray) -> tuple[IntArray, IntArray]:
        """Flag gaps among the accepted stamps ``kt``; indices of the long ones and of all."""
        none = np.zeros(0, np.int64)
        if not len(kt):
            return none, none
        if self.nominal_period_ns is None:
            prev = self.last_kept_ns
            dt = np.diff(kt) if prev is None else np.diff(np.concatenate([[prev], kt]))
            self._dts.extend(int(x) for x in dt[:32 - len(self._dts)])
            if len(self._dts) >= 8:
                self.nominal_period_ns = int(np.median(self._dts))
        long_, all_ = self.gap_indices(self.last_kept_ns, kt)
        self.last_kept_ns = int(kt[-1])
        if all_.size:
            self.flagged['gap'] += int(all_.size)
            self.last_event_ns = int(kt[all_[-1]])
        if long_.size:
            self.flagged['long_gap'] += int(long_.size)
            self.last_event_ns = int(kt[long_[-1]])
        return long_, all_

    def _watch_scatter(self, kept: int, gaps: int) -> None:
        """Latch :attr:`stamps_error` when, since the IMU clock found its stamps not
        periodic, more than :data:`SCATTER_GAP_SHARE` of the kept samples followed a gap."""
        c = self.imu_clock
        if not c.irregular or self.stamps_error is not None:
            return
        self._scatter_kept += kept
        self._scatter_gaps += gaps
        share = self._scatter_gaps / max(self._scatter_kept, 1)
        if self._scatter_kept < SCATTER_MIN_SAMPLES or share <= SCATTER_GAP_SHARE:
            return
        self.stamps_error = (
            f'{share:.0%} of the IMU intervals are gaps (longer than '
            f'{self.config.gap_periods:g} periods: the data of a gap is lost, CONTRACT 1), as '
            f'the IMU stamps scatter about a {1e9 / c.period_ns:.4g} Hz rate (by '
            f'{c.jitter_ns * 1e-6:.2g} ms or more): stamped on receipt by the host, with '
            'messages dropped? Stamp each message at its sample instant (CONTRACT 1)')
        _LOG.error('%s', self.stamps_error)

    def gap_indices(self, prev_ns: int | None, kt: IntArray) -> tuple[IntArray, IntArray]:
        """Indices in ``kt`` of the samples after a long gap and after any gap (an interval
        beyond ``gap_periods`` nominal periods), ``prev_ns`` the stamp before them (None: the
        first sample follows nothing). Pure: also for stamps revised later
        (:meth:`~.stamp_clock.StampClock.revise`)."""
        cfg = self.config
        none = np.zeros(0, np.int64)
        if not len(kt):
            return none, none
        dt = np.diff(kt) if prev_ns is None else np.diff(np.concatenate([[prev_ns], kt]))
        off = 1 if prev_ns is None else 0
        long_ = (np.nonzero(dt > cfg.max_gap_s * 1e9)[0] + off).astype(np.int64)
        all_ = none
        if self.nominal_period_ns is not None:
            all_ = (np.nonzero(dt > cfg.gap_periods * self.nominal_period_ns)[0]
                    + off).astype(np.int64)
        return long_, all_

    def _check_gyro_units(self, t: IntArray, w: FloatArray, reason: NDArray[np.int64]) -> None:
        """Compare |gyro| with the encoder-derived rate magnitude (deg/s signature = 180/pi)."""
        cfg = self.config
        if self.units_error is not None or self._axes_enu is None:
            return
        wmag = np.linalg.norm(w, axis=1)
        cand = (reason < 0) & (wmag > 0.5 * cfg.units_min_rate_rad_s)
        if not cand.any():
            return
        self._update_rates()
        rt, rv = self._rate_t, self._rate_v
        if len(rt) < 2:
            return
        tc = t[cand].astype(float)
        inside = (tc >= rt[0]) & (tc <= rt[-1])
        if not inside.any():
            return
        enc = np.interp(tc[inside], rt, rv)
        wm = wmag[cand][inside]
        moving = enc > cfg.units_min_rate_rad_s
        ratio = wm[moving] / enc[moving]
        tol = cfg.units_ratio_tolerance
        self._deg_votes += int((np.abs(ratio * RAD_PER_DEG - 1.0) < tol).sum())
        self._ok_votes += int((np.abs(ratio - 1.0) < tol).sum())
        if self._deg_votes >= cfg.units_latch_count and self._deg_votes > 4 * self._ok_votes:
            self.units_error = ('gyro values look like deg/s, not rad/s (|gyro| is 57.3 times '
                                'the encoder rate): fix the driver units')

    # --------------------------------------------------------------------------- joints
    def check_joint(self, stamp_ns: int, names: tuple[str, ...] | list[str],
                    positions_rad: Any) -> FloatArray | None:
        """The fixture-ordered positions of an accepted joint sample, or None (counted)."""
        try:
            idx = [list(names).index(n) for n in self.joint_names]
        except ValueError:
            self.unknown_joint_names = tuple(names)
            self._reject_joint('joint_missing_names')
            return None
        q = np.asarray(positions_rad, float)
        if q.ndim != 1 or q.shape[0] != len(names):
            self._reject_joint('joint_missing_names')
            return None
        q = q[idx]
        if not np.all(np.isfinite(q)):
            self._reject_joint('joint_non_finite')
            return None
        if self._last_joint is not None:
            t0, q0 = self._last_joint
            if stamp_ns == t0:
                self._reject_joint('joint_duplicate_stamp')
                return None
            if stamp_ns < t0:
                self._reject_joint('joint_out_of_order')
                return None
        self._last_joint = (int(stamp_ns), q)
        t = self.joint_clock(np.array([stamp_ns], np.int64))
        self.last_joint_clock_ns = int(t[0])
        self._add_pending(t, q[None, :])
        return q

    def check_joint_batch(self, stamps_ns: Any, names: tuple[str, ...] | list[str],
                          positions_rad: Any) -> tuple[IntArray, FloatArray]:
        """Classify many joint samples of one name list (vectorised, same verdicts and
        counters as :meth:`check_joint` one by one).

        Returns
        -------
        (stamps (K,), positions (K, n)) of the accepted samples, positions in fixture order.
        """
        t = np.asarray(stamps_ns, np.int64).reshape(-1)
        m = len(t)
        n = len(self.joint_names)
        empty = (np.zeros(0, np.int64), np.zeros((0, n)))
        if m == 0:
            return empty
        try:
            idx = [list(names).index(x) for x in self.joint_names]
        except ValueError:
            self.unknown_joint_names = tuple(names)
            return self._reject_joints('joint_missing_names', m, empty)
        q_all = np.asarray(positions_rad, float)
        if q_all.ndim != 2 or q_all.shape != (m, len(names)):
            return self._reject_joints('joint_missing_names', m, empty)
        q = q_all[:, idx]
        finite = np.isfinite(q).all(axis=1)
        n_bad = m - int(finite.sum())
        if n_bad:
            self.rejected['joint_non_finite'] += n_bad
            t, q = t[finite], q[finite]
        # the newest accepted stamp before each sample is the running maximum of the finite
        # stamps before it (a finite sample is rejected only if it is not above that maximum)
        first = np.iinfo(np.int64).min if self._last_joint is None else self._last_joint[0]
        prev_max = np.maximum.accumulate(np.concatenate([[first], t]))[:-1]
        dup = int((t == prev_max).sum())
        old = int((t < prev_max).sum())
        if dup:
            self.rejected['joint_duplicate_stamp'] += dup
        if old:
            self.rejected['joint_out_of_order'] += old
        if dup or old:
            ok = t > prev_max
            t, q = t[ok], q[ok]
        if n_bad or dup or old:
            self._log()
        if len(t):
            self._last_joint = (int(t[-1]), q[-1])
            t = self.joint_clock(t)
            self._add_pending(t, q)
        return t, q

    def _add_pending(self, t: IntArray, q: FloatArray) -> None:
        """Queue accepted joint samples for the encoder rates; keep the newest PEND_MAX."""
        self._pend.append((t, q))
        self._pend_rows += len(t)
        while self._pend_rows - len(self._pend[0][0]) >= PEND_MAX:
            self._pend_rows -= len(self._pend.popleft()[0])

    def _reject_joints(self, name: str, count: int,
                       empty: tuple[IntArray, FloatArray]) -> tuple[IntArray, FloatArray]:
        self.rejected[name] += count
        self._log()
        return empty

    def count_rejected(self, name: str, count: int) -> None:
        """Count ``count`` samples rejected for reason ``name`` elsewhere (joint states merged
        from one axis at a time: :class:`~.joint_merge.JointMerger`)."""
        if count:
            self.rejected[name] += count
            self._log()

    def _reject_joint(self, name: str) -> None:
        self.rejected[name] += 1
        self._log()
        return None

    def _update_rates(self) -> None:
        """Encoder-derived rate magnitude over each joint interval (vectorised, lazily).

        ``|omega_ib| = |sum_i u_i(q) qdot_i + Omega_ie|`` is frame-free; Omega_ie (7e-5 rad/s)
        is far below ``units_min_rate_rad_s`` and left out.
        """
        if self._pend_rows < 2:
            return
        t = np.concatenate([c[0] for c in self._pend])[-PEND_MAX:]
        q = np.concatenate([c[1] for c in self._pend])[-PEND_MAX:]
        dq = np.diff(q, axis=0)
        dq -= 2 * np.pi * np.round(dq / (2 * np.pi))  # wrapped encoders (CONTRACT 1)
        qd = dq / (np.diff(t) * 1e-9)[:, None]
        axes_enu = self._axes_enu
        assert axes_enu is not None  # the caller checks
        u = axes_enu(q[:-1] + 0.5 * dq)  # (M, n, 3) at the interval middles
        rate = np.linalg.norm(np.einsum('mi,mij->mj', qd, u), axis=1)
        mid = 0.5 * (t[:-1] + t[1:]).astype(float)
        self._rate_t = np.concatenate([self._rate_t, mid])[-8192:]
        self._rate_v = np.concatenate([self._rate_v, rate])[-8192:]
        self._pend.clear()
        self._pend.append((t[-1:], q[-1:]))
        self._pend_rows = 1

    def reset_stamps(self) -> None:
        """Forget the stamp memory (IMU and joints) after a backward time jump (a looping bag,
        ``use_sim_time``), so that the earlier stamps that follow are not rejected as
        ``time_jump_backward``/``out_of_order``. The rejection counters, the units votes and
        the nominal period are kept (same sensor); the encoder rates (indexed by the old
        stamps) are dropped."""
        self.last_stamp_ns = None
        self.last_kept_ns = None
        self.last_event_ns = None  # a data time of the old time base
        self.imu_clock.reset()
        self.joint_clock.reset()
        self._last_joint = None
        self._pend.clear()
        self._pend_rows = 0
        self._rate_t = np.zeros(0)
        self._rate_v = np.zeros(0)

    # ---------------------------------------------------------------------------- misc
    @property
    def rejected_total(self) -> int:
        """All rejected samples (IMU and joint)."""
        return int(sum(self.rejected.values()))

    def _log(self) -> None:
        """One throttled log line with the counts that changed since the last one."""
        if self.rejected_total == self._logged_total and (
                self.units_error is None or self._logged_units):
            return
        now = time.monotonic()
        if now - self._log_wall < self.config.log_period_s:
            return
        new = {k: v - self._logged.get(k, 0) for k, v in self.rejected.items()
               if v != self._logged.get(k, 0)}
        if not new and self.units_error is None:
            return
        self._log_wall = now
        self._logged = dict(self.rejected)
        self._logged_total = self.rejected_total
        self._logged_units = self.units_error is not None
        if new:
            _LOG.warning('rejected input samples: %s',
                         ', '.join(f'{k} {v}' for k, v in sorted(new.items())))
        if self.units_error is not None:
            _LOG.error('%s', self.units_error)
