"""Rotation modulation of IMU errors: the MEMS paper's averaging schemes and a continuous mode.

Seed ``004`` (rotation modulation of a MEMS IMU on a platform turning about its Z axis).
Frames: ``s`` = IMU (sensor) frame; ``b`` = platform-base ("body") frame, defined as the IMU
frame when the modulation joint is at zero (the platform base; control points at joint
angles that are multiples of 360/n deg). With ``u`` the joint axis in the IMU frame
(constant) and ``phi = q``: ``R_b_s = Rot(u, phi)`` (one convention, tested; the paper's
eqs. 5-6 mix C_S^B and C_B^S).

- :func:`demodulate_points` (paper eqs. 12-14): the X/Y (perpendicular to ``u``) error
  estimate is the mean of the raw sensor-frame output over the last complete revolution,
  weighted by angle (eq. 12); at each control point (every 360/n deg, n = 1, 2, 4) one
  body-frame sample is output: the raw sample at the control point minus that estimate,
  rotated with the control point's exactly known ``R_b_s`` (eq. 13/14), and the platform
  rate (mean over that sample's interval, from the joint angles) removed from the gyro.
  Output rate = n times the rotation frequency (the paper's limitation).
- :func:`demodulate_continuous` (METHODS.md sect. 3): every sample is de-rotated with the
  joint angle, and the modulated biases are tracked at full rate as the angle-weighted mean
  of the sensor-frame output over one revolution around (offline) or before (causal) each
  sample. Output at the full IMU rate.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from ..errors import InputError
from ..rotation import rot_axis_angle
from ..types import GAP_PERIODS, ImuBatch, JointBatch, sample_intervals_ns
from .windows import joint_positions

if TYPE_CHECKING:
    from ..fixture import Fixture

FloatArray = NDArray[np.float64]
MODES = {'one': 1, 'two': 2, 'four': 4}


def _setup(imu: ImuBatch, joints: JointBatch, fixture: Fixture, joint: str | None,
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
    dt = _intervals_ns(imu.stamps_ns) * 1e-9
    phi_end = np.interp(ti, tj, q[:, k])
    phi_start = np.interp(ti - dt, tj, q[:, k])
    if abs(phi_end[-1] - phi_end[0]) < 2 * np.pi:
        raise InputError(f'joint {names[k]!r} turns less than one revolution: no modulation')
    q_ax = q[0].copy()
    q_ax[k] = 0.0
    u = fixture.joint_axes_imu(q_ax)[k]
    return k, phi_start, phi_end, u / np.linalg.norm(u)


def _intervals_ns(stamps_ns: NDArray[np.int64]) -> FloatArray:
    """Sample averaging intervals [ns] as floats: the first sample and a sample after a gap
    get the nominal (median) period (CONTRACT 1)."""
    return sample_intervals_ns(stamps_ns)[0]


def _plane_basis(u: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Unit vectors ``e1, e2`` with ``e1 x e2 = u``: the plane the modulation turns in."""
    a = np.eye(3)[int(np.argmin(np.abs(u)))]
    e1 = np.cross(u, a)
    e1 /= np.linalg.norm(e1)
    return e1, np.cross(u, e1)


def _rotating_mean(phi0: FloatArray, phi1: FloatArray) -> NDArray[np.complex128]:
    """Mean of ``exp(-i phi)`` over each sample's angle interval ``[phi0, phi1]``.

    In plane coordinates (``z = x.e1 + i x.e2``) a body-fixed vector ``v`` reads
    ``v exp(-i phi)`` in the sensor frame (``R_s_b = Rot(u, -phi)``), so a sample (an interval
    mean) holds ``v`` times this: ``exp(-i mid) sin(h)/h`` with ``h`` the half-interval.
    """
    mid = 0.5 * (phi0 + phi1)
    half = 0.5 * (phi1 - phi0)
    return np.exp(-1j * mid) * np.sinc(half / np.pi)


def _features(x: FloatArray, m: NDArray[np.complex128], e1: FloatArray, e2: FloatArray,
              ) -> NDArray[np.complex128]:
    """Per-sample terms of the revolution fit's normal equations (:func:`_fit_bias`):
    ``1, m, m^2, |m|^2``, then per sensor (gyro, accel) ``z, conj(m) z, m z``."""
    cols = [np.ones_like(m), m, m * m, (m * m.conj()).real.astype(complex)]
    for k in (0, 3):
        z = x[:, k:k + 3] @ e1 + 1j * (x[:, k:k + 3] @ e2)
        cols += [z, m.conj() * z, m * z]
    return np.stack(cols, axis=1)


def _fit_bias(S: NDArray[np.complex128], e1: FloatArray, e2: FloatArray,
              ) -> tuple[FloatArray, FloatArray]:
    """Bias perpendicular to the axis (gyro and accel, ``(N, 3)`` each) from the window sums.

    ``S`` holds the angle-weighted sums of :func:`_features` over one revolution window. The
    paper's estimate (eq. 12) is the plain mean ``sum(w z) / sum(w)``: exact when the window
    covers the revolution, but a lost stretch (samples lost in transport, CONTRACT 1 gaps)
    leaves the rotating part of the signal (gravity, earth rate, in the sensor frame a
    vector turning with ``exp(-i phi)``) out of balance: a hole of angle ``h`` biases the mean
    by up to ``|v| 2 sin(h/2) / (2 pi - h)``, 2.5 m/s^2 for 60 deg of gravity (issue 16 item
    3). Here each sample is modelled as ``b + v m + c conj(m)`` (bias, the body-fixed vector,
    and the counter-rotating part any scale or misalignment error adds) and ``b`` fitted by
    weighted least squares over the samples present: the same value as the mean on a
    complete revolution (the rotating sums vanish), exact with holes for a constant body
    vector and any linear sensor error.
    """
    n = S.shape[0]
    w, sm, sm2, smm = S[:, 0], S[:, 1], S[:, 2], S[:, 3]
    A = np.empty((n, 3, 3), complex)
    A[:, 0] = np.stack([w, sm, sm.conj()], axis=1)
    A[:, 1] = np.stack([sm.conj(), smm, sm2.conj()], axis=1)
    A[:, 2] = np.stack([sm, sm2, smm], axis=1)
    rhs = np.stack([S[:, 4:7], S[:, 7:10]], axis=2)  # (n, 3, 2): gyro, accel
    wr = np.where(w.real != 0, w.real, 1.0)  # all sums may carry the turning's sign
    b = rhs[:, 0, :] / wr[:, None]  # the plain mean (no angle covered: zero)
    # the fit where the window is well conditioned (a platform at rest has no rotation)
    scale = wr[:, None, None]
    ok = (w.real != 0) & (np.abs(np.linalg.det(A / scale)) > 1e-9)
    if ok.any():
        b[ok] = np.linalg.solve(A[ok], rhs[ok])[:, 0, :]
    out = [np.outer(b[:, k].real, e1) + np.outer(b[:, k].imag, e2) for k in (0, 1)]
    return out[0], out[1]


def _revolution_bias(x: FloatArray, phi0: FloatArray, phi1: FloatArray, centre: FloatArray,
                     causal: bool, u: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Gyro and accel bias perpendicular to ``u`` over one revolution (eq. 12, fitted as in
    :func:`_fit_bias`) for each ``centre`` angle, and the fraction of the revolution the
    samples present cover (1 = no loss).

    Sample k covers the angle interval ``[phi0_k, phi1_k]``; the revolution is
    ``(c - 2 pi, c]`` (causal) or ``(c - pi, c + pi]``; it is clamped into the recording.
    """
    sgn = 1.0 if phi1[-1] >= phi1[0] else -1.0
    a0, a1 = sgn * phi0, sgn * phi1
    c = sgn * centre
    w = a1 - a0
    e1, e2 = _plane_basis(u)
    F = _features(x, _rotating_mean(phi0, phi1), e1, e2)
    cum = np.cumsum(F * w[:, None], axis=0)
    # knots at both ends of every sample: the cumulative sums rise inside a sample and stay
    # flat over the angle a lost stretch (a gap, CONTRACT 1) would have covered. (One knot
    # per sample end spread each sample after a gap over the gap's angle too.)
    prev = np.concatenate([np.zeros((1, F.shape[1]), complex), cum[:-1]])
    ck = np.stack([prev, cum], axis=1).reshape(-1, F.shape[1])
    hi = c if causal else c + np.pi
    hi = np.clip(hi, a0[0] + 2 * np.pi, a1[-1])
    lo = hi - 2 * np.pi
    # the cumulative sums are piecewise linear in angle (x constant over a sample): exact
    # partial samples at both ends by interpolation (end angles of a turning platform are
    # monotonic; np.maximum.accumulate guards against encoder jitter)
    edges = np.maximum.accumulate(np.stack([a0, a1], axis=1).ravel())
    S = np.stack([np.interp(hi, edges, ck[:, k]) - np.interp(lo, edges, ck[:, k])
                  for k in range(F.shape[1])], axis=1)
    bg, ba = _fit_bias(S, e1, e2)
    return bg, ba, np.abs(S[:, 0].real) / (2 * np.pi)


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


def demodulate_continuous(imu: ImuBatch, joints: JointBatch, fixture: Fixture, *,
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
    gyro = np.asarray(imu.gyro_rad_s, float)
    accel = np.asarray(imu.accel_m_s2, float)
    centre = 0.5 * (phi0 + phi1)
    bg, ba, _ = _revolution_bias(np.hstack([gyro, accel]), phi0, phi1, centre, causal, u)
    dt = _intervals_ns(imu.stamps_ns)
    rate = ((phi1 - phi0) / (dt * 1e-9))[:, None] * u  # platform rate, same in s and b
    w_b = _derotate(u, phi0, phi1, gyro - bg - rate)
    f_b = _derotate(u, phi0, phi1, accel - ba)
    return ImuBatch(imu.stamps_ns.copy(), w_b, f_b, frame_id or f'{imu.frame_id}_body')


def demodulate_points(imu: ImuBatch, joints: JointBatch, fixture: Fixture, mode: str = 'one', *,
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
    gyro = np.asarray(imu.gyro_rad_s, float)
    accel = np.asarray(imu.accel_m_s2, float)
    sgn = 1.0 if phi1[-1] >= phi1[0] else -1.0
    step = 2 * np.pi / n
    # raw samples whose interval contains a control point (angle = multiple of the step)
    k0 = np.floor(sgn * phi0 / step)
    k1 = np.floor(sgn * phi1 / step)
    cross = np.flatnonzero(k1 > k0)
    out = sgn * (phi1[cross] - phi0[0]) >= 2 * np.pi  # outputs after the first revolution
    if out.sum() < 2:
        raise InputError('fewer than two control points after the first revolution')
    idx = cross[out]
    cp = sgn * k1[idx] * step  # the control point's angle (exact R_b_s there: eq. 14)
    # platform rate: mean over the crossing sample's interval from the joint angles (the
    # gyro's own averaging interval). The paper's step / time between crossings assumes a
    # constant rate: after a spin-up the first output was off by ~50 deg/s (one-point mode)
    rate = (phi1[idx] - phi0[idx]) / (_intervals_ns(imu.stamps_ns)[idx] * 1e-9)
    bg, ba, _ = _revolution_bias(np.hstack([gyro, accel]), phi0, phi1, cp, True, u)
    t = imu.stamps_ns[idx]
    R = rot_axis_angle(u, cp)
    w_b = np.einsum('nij,nj->ni', R, gyro[idx] - bg - rate[:, None] * u)
    f_b = np.einsum('nij,nj->ni', R, accel[idx] - ba)
    return ImuBatch(t.copy(), w_b, f_b, frame_id or f'{imu.frame_id}_body')


@dataclass(frozen=True)
class DemodulationOptions:
    """Options of :func:`demodulate`; a misspelt one is a TypeError.

    Attributes
    ----------
    mode : {'continuous', 'one', 'two', 'four'}
        Full-rate stream (:func:`demodulate_continuous`) or the paper's control points
        (:func:`demodulate_points`).
    joint : str, optional
        The modulation joint (default: the joint that turns most).
    causal : bool
        Continuous mode only: the bias over the preceding revolution (live use) instead of a
        centred one (the point modes are causal by construction).
    frame_id : str, optional
        Frame of the output (default: the input's with ``_body``).
    """

    mode: str = 'continuous'
    joint: str | None = None
    causal: bool = False
    frame_id: str | None = None


def demodulate(imu: ImuBatch, joints: JointBatch, fixture: Fixture,
               options: DemodulationOptions | str) -> ImuBatch:
    """Dispatch on the mode (``one | two | four | continuous``); ``options`` may be just the
    mode, with the other options at their defaults."""
    o = DemodulationOptions(options) if isinstance(options, str) else options
    if o.mode == 'continuous':
        return demodulate_continuous(imu, joints, fixture, joint=o.joint, causal=o.causal,
                                     frame_id=o.frame_id)
    if o.causal:
        raise InputError(f'--causal applies to --mode continuous only, not {o.mode}')
    return demodulate_points(imu, joints, fixture, o.mode, joint=o.joint, frame_id=o.frame_id)


class StreamingDemodulator:
    """Causal sample-by-sample demodulation for live use (the ``modulation`` node).

    Same arithmetic as :func:`demodulate_continuous` with ``causal=True`` (mode
    ``'continuous'``) or :func:`demodulate_points` (``'one' | 'two' | 'four'``), fed one joint
    state and one IMU sample at a time: an IMU sample is processed once a joint state at or
    after its stamp has arrived (the joint angle at both ends of its interval is then
    interpolated, as offline); output starts after the first complete revolution (the bias
    is the angle-weighted mean over the preceding revolution, eq. 12). After that its values
    equal the offline causal ones (test_node_modulation.py).

    Parameters
    ----------
    axis_imu : (3,) array_like
        Modulation joint axis in the IMU frame (unit after normalisation).
    joint_name : str
        Name of the modulation joint in the joint states.
    mode : {'continuous', 'one', 'two', 'four'}
    max_pending : int
        IMU samples kept while waiting for joint states; older ones are dropped (counted).
    max_history : int
        Cap on the accumulated samples (the history is trimmed to the last 1.5 revolutions
        by angle; the cap only bounds a long stop). Must exceed twice the samples in one
        revolution (200 000: 1 kHz down to 3.6 deg/s).
    min_coverage : float
        Withhold (count in ``withheld_low_coverage``, return nothing for) an output whose
        revolution window the samples present cover less than this fraction of (lost
        samples, CONTRACT 1 gaps): the fitted bias (:func:`_fit_bias`) is exact for a constant
        body vector but its noise grows as the hole widens. 0 withholds nothing (the offline
        functions). Outputs fitted over a window with a loss are counted in
        ``fitted_after_loss``; :attr:`last_coverage` is the latest output's coverage.
    """

    def __init__(self, axis_imu: Any, joint_name: str, mode: str = 'continuous',
                 max_pending: int = 2000, max_history: int = 200_000,
                 min_coverage: float = 0.0) -> None:
        if mode != 'continuous' and mode not in MODES:
            raise InputError(f'mode must be continuous, one, two or four, got {mode!r}')
        u = np.asarray(axis_imu, float).reshape(3)
        self.u = u / np.linalg.norm(u)
        self._e1, self._e2 = _plane_basis(self.u)
        self.min_coverage = float(min_coverage)
        self.last_coverage = 1.0
        self.joint_name = joint_name
        self.mode = mode
        self._step = None if mode == 'continuous' else 2 * np.pi / MODES[mode]
        self.max_pending = int(max_pending)
        self.max_history = int(max_history)
        self._tj: list[int] = []
        self._qj: list[float] = []
        self._pending: list[Any] = []
        self._last_stamp: int | None = None
        self._first: Any = None
        self._dt_nom_ns: float | None = None
        self._edges: list[float] = []  # raw joint angle at each accumulated sample's end
        # cumulative angle-weighted fit terms (_features) at each knot (both ends per sample)
        self._ck: list[NDArray[np.complex128]] = []
        self._acc = np.zeros(10, complex)
        self._first_angle: float | None = None
        self._t_base_ns: int | None = None
        self.counters = {'imu_in': 0, 'joint_in': 0, 'published': 0, 'warming_up': 0,
                         'dropped_no_joint_states': 0, 'out_of_order': 0, 'gaps': 0,
                         'lost_imu': 0, 'fitted_after_loss': 0, 'withheld_low_coverage': 0}

    # ------------------------------------------------------------------ input
    def push_joint(self, sample: Any) -> list[Any]:
        """Add a joint state; returns the output samples it releases (maybe none)."""
        if self.joint_name not in sample.names:
            return []
        q = float(sample.positions_rad[sample.names.index(self.joint_name)])
        if self._tj and sample.stamp_ns <= self._tj[-1]:
            self.counters['out_of_order'] += 1
            return []
        if self._qj:  # unwrap against the previous position (np.unwrap's rule)
            q = self._qj[-1] + (q - self._qj[-1] + np.pi) % (2 * np.pi) - np.pi
        self.counters['joint_in'] += 1
        self._tj.append(int(sample.stamp_ns))
        self._qj.append(q)
        out = self._drain()
        if len(self._tj) > 4 * self.max_pending:  # bounded joint history
            del self._tj[:-2 * self.max_pending], self._qj[:-2 * self.max_pending]
        return out

    def push_imu(self, sample: Any) -> list[Any]:
        """Add a raw IMU sample; returns the output samples it releases (maybe none)."""
        self.counters['imu_in'] += 1
        if self._last_stamp is not None and sample.stamp_ns <= self._last_stamp:
            self.counters['out_of_order'] += 1
            return []
        if self._last_stamp is None:
            self._last_stamp = int(sample.stamp_ns)  # interval unknown until the next one
            self._first = sample
            return []
        dt = int(sample.stamp_ns) - self._last_stamp
        if self._dt_nom_ns is None:
            self._dt_nom_ns = float(dt)
            # the first sample gets the first interval (offline: the median interval)
            self._pending.append((self._first, dt))
            self._first = None
        elif dt > GAP_PERIODS * self._dt_nom_ns:  # CONTRACT 1: after a gap, its own period only
            self.counters['gaps'] += 1
            self.counters['lost_imu'] += max(round(dt / self._dt_nom_ns) - 1, 1)
            dt = int(round(self._dt_nom_ns))
        self._last_stamp = int(sample.stamp_ns)
        self._pending.append((sample, dt))
        if len(self._pending) > self.max_pending:
            del self._pending[0]
            self.counters['dropped_no_joint_states'] += 1
        return self._drain()

    # ------------------------------------------------------------------ processing
    def _drain(self) -> list[Any]:
        out = []
        while self._pending and self._tj and self._tj[-1] >= self._pending[0][0].stamp_ns:
            s, dt = self._pending.pop(0)
            # an interval starting before the first joint state takes its first angle
            # (np.interp clamps, as offline): a zero or partial angle weight
            r = self._process(s, dt)
            if r is not None:
                out.append(r)
        return out

    def _revolution_bias(self, centre: float, sgn: float) -> tuple[FloatArray, FloatArray]:
        """Gyro and accel bias perpendicular to the axis over ``(centre - 2 pi, centre]``
        (eq. 12, fitted: :func:`_fit_bias`); sets :attr:`last_coverage`."""
        edges = np.maximum.accumulate(sgn * np.asarray(self._edges))
        ck = np.asarray(self._ck)
        hi = sgn * centre
        ends = np.array([hi - 2 * np.pi, hi])
        S = np.array([np.interp(ends, edges, ck[:, k]) for k in range(ck.shape[1])])
        S = (S[:, 1] - S[:, 0])[None, :]
        self.last_coverage = abs(float(S[0, 0].real)) / (2 * np.pi)
        bg, ba = _fit_bias(S, self._e1, self._e2)
        return bg[0], ba[0]

    def _withhold(self) -> bool:
        """Count the latest output by its coverage; True if it is withheld."""
        if self.last_coverage < self.min_coverage:
            self.counters['withheld_low_coverage'] += 1
            return True
        if self.last_coverage < 1.0 - 1e-6:
            self.counters['fitted_after_loss'] += 1
        return False

    def _process(self, s: Any, dt_ns: int) -> Any:
        from ..types import ImuSample
        # times relative to a fixed joint stamp in integer ns first (1.7e9 s in float64 has
        # only ~0.2 us resolution: 0.4 urad of angle at 150 deg/s)
        if self._t_base_ns is None:
            self._t_base_ns = self._tj[0]
        tj = (np.asarray(self._tj) - self._t_base_ns) * 1e-9
        t1 = (int(s.stamp_ns) - self._t_base_ns) * 1e-9
        phi0 = float(np.interp(t1 - dt_ns * 1e-9, tj, self._qj))
        phi1 = float(np.interp(t1, tj, self._qj))
        gyro = np.asarray(s.gyro_rad_s, float)
        accel = np.asarray(s.accel_m_s2, float)
        if self._first_angle is None:
            self._first_angle = phi0
        w = phi1 - phi0
        # knots at both ends of the sample, flat over lost stretches (as offline); the
        # weight is the signed angle (offline: times the recording's direction; the fit
        # and the coverage do not depend on the sign of all the sums)
        sgn = 1.0 if w >= 0 else -1.0
        f = _features(np.concatenate([gyro, accel])[None], _rotating_mean(
            np.array([phi0]), np.array([phi1])), self._e1, self._e2)[0]
        acc = self._acc + f * w
        self._edges += [phi0, phi1]
        self._ck += [self._acc, acc]
        self._acc = acc
        # bounded history: only the last revolution is ever read; trim by angle (a count
        # derived from the current step grew without bound while the platform stood still)
        # and cap the count (a long stop between spins adds samples but no angle)
        if len(self._edges) > 64 and abs(phi1 - self._edges[len(self._edges) // 2]) > 3 * np.pi:
            half = len(self._edges) // 4 * 2  # whole samples (knot pairs)
            del self._edges[:half], self._ck[:half]
        elif len(self._edges) > 2 * self.max_history:
            keep = self.max_history // 2 * 2
            del self._edges[:-keep], self._ck[:-keep]
        full = sgn * (phi1 - self._first_angle) >= 2 * np.pi
        if self._step is None:
            centre = 0.5 * (phi0 + phi1)
            if not (full and sgn * (centre - self._first_angle) >= 2 * np.pi):
                self.counters['warming_up'] += 1
                return None
            bg, ba = self._revolution_bias(centre, sgn)
            if self._withhold():
                return None
            rate = w / (dt_ns * 1e-9) * self.u
            w_b = _derotate(self.u, np.array([phi0]), np.array([phi1]),
                            (gyro - bg - rate)[None])[0]
            f_b = _derotate(self.u, np.array([phi0]), np.array([phi1]), (accel - ba)[None])[0]
            self.counters['published'] += 1
            return ImuSample(int(s.stamp_ns), w_b, f_b, s.frame_id)
        k0 = np.floor(sgn * phi0 / self._step)
        k1 = np.floor(sgn * phi1 / self._step)
        if k1 <= k0:
            return None
        cp = float(sgn * k1 * self._step)
        if not full:
            self.counters['warming_up'] += 1
            return None
        bg, ba = self._revolution_bias(cp, sgn)
        if self._withhold():
            return None
        rate = w / (dt_ns * 1e-9)  # as offline: joint-angle rate over the sample interval
        R = rot_axis_angle(self.u, np.array(cp))
        w_b = R @ (gyro - bg - rate * self.u)
        f_b = R @ (accel - ba)
        self.counters['published'] += 1
        return ImuSample(int(s.stamp_ns), w_b, f_b, s.frame_id)
