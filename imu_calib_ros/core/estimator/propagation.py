"""One block of IMU samples through the navigator: compensation, strapdown, transition rows.

A block is ``B`` chunks of ``n`` samples (plus ``h`` samples of look-ahead, one at 200 Hz and
below, :func:`omega_dot_half_span`). Per block, all
vectorised:

1. intervals from the stamps; a gap (> 1.5 nominal periods) counts as one nominal period
   and resets the navigator's coning/sculling memory;
2. compensate the raw samples with the current estimate (:class:`BlockCompensation`: the
   fixed point of ``sensor_model.compensate`` in matrix form, the asymmetry and quadratic
   terms of :class:`RowWindow` means against noise rectification), the size effect with
   ``omega_dot`` from central differences of neighbouring compensated mean rates (Kozlov &
   Kapralov eq. 1; METHODS.md "cuts across"), the accelerometer time offset with the same
   differences of the specific force;
3. ``Strapdown.propagate`` over the whole block;
4. every chunk's 6 navigation rows of ``Phi`` (:func:`~.ekf.chunk_transition_rows`, with
   the sensor Jacobians of the compensated samples, ``D^-1 M`` of
   :func:`~.error_model.compensated_jacobians` applied through the rows' left factors),
   scaled to the filter's units.
"""
from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import Any, Callable

import numpy as np
from numpy.typing import NDArray

from .. import sensor_model as sm
from ..strapdown import Strapdown
from . import error_model as em
from .ekf import chunk_transition_rows
from .error_model import StateLayout

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]
Window = Callable[[FloatArray], FloatArray]  # the nonlinear terms' argument (RowWindow)


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
    q_corner_s: FloatArray | None = None  # (B, 3) velocity variance at corners, scaled

    def chunk_noise_s(self, q1_diag_s: FloatArray, b: int) -> FloatArray:
        """Diagonal ``Q`` of chunk ``b`` (scaled): ``Q`` per second over its length, plus
        the velocity variance of the corners in it (:func:`corner_variance`)."""
        q = q1_diag_s * self.T_s[b]
        if self.q_corner_s is not None:
            q[3:6] += self.q_corner_s[b]
        return q


class RowWindow:
    """Centred means over ``+-k`` rows of ``(3, N)`` arrays, each window cut at the array's
    ends and at gaps: the argument of the compensation's ``|omega|``, ``|f|`` and ``f^2``.

    CONTRACT 3's asymmetry terms take the *true* rate's magnitude; a noisy sample's magnitude
    is biased (rectified): at rest ``E|n| = 0.8 sigma``, so ``ag |w|`` put ``ag 0.8 sigma``
    into every rate (5.3 deg/h on a consumer gyro at 1 kHz with ``ag`` 0.3 %, the gyro biases
    that much off, a third of their sigma; the accelerometer asymmetry likewise). The mean
    over ``2 k + 1`` samples has ``1 / sqrt(2 k + 1)`` of the noise, and a motion's rate is
    linear over ``+-k`` samples (``+-5 ms`` at 1 kHz, :func:`omega_dot_half_span`) except at
    its corners, whose ``ag`` share integrates to zero over a turn (a centred mean keeps the
    integral). Hand-written: a moving mean cut at gaps is a few cumulative sums, and
    ``scipy.ndimage.uniform_filter1d`` has no cut."""

    def __init__(self, n: int, k: int, gap: NDArray[np.bool_] | None = None) -> None:
        """``n`` rows, half-width ``k``; ``gap`` (n - 1,): True where row ``i + 1`` follows a
        gap (no window spans it)."""
        self.gapless = gap is None or not gap.any()
        if self.gapless:
            self.lo, self.hi1, self.count = _gapless_bounds(n, k)  # the same every block
        else:
            self.lo, self.hi1, self.count = _window_bounds(n, k, np.asarray(gap, bool))
        self.k = k

    def __call__(self, x: FloatArray) -> FloatArray:
        """The window means of ``x`` (3, n)."""
        k = self.k
        if k == 0:
            return x
        c = np.concatenate([np.zeros((x.shape[0], 1)), np.cumsum(x, axis=1)], axis=1)
        if not self.gapless or x.shape[1] <= 2 * k + 1:
            return (c[:, self.hi1] - c[:, self.lo]) / self.count
        out = np.empty_like(x)  # full windows by slices, the k rows at each end gathered
        out[:, k:-k] = (c[:, 2 * k + 1:] - c[:, :-2 * k - 1]) / (2 * k + 1)
        for j in (slice(0, k), slice(-k, None)):
            out[:, j] = (c[:, self.hi1[j]] - c[:, self.lo[j]]) / self.count[j]
        return out

    @staticmethod
    def none(x: FloatArray) -> FloatArray:
        """No window: each sample's own value (``sensor_model.compensate``'s argument)."""
        return x


def _window_bounds(n: int, k: int, gap: NDArray[np.bool_] | None
                   ) -> tuple[NDArray[np.intp], NDArray[np.intp], FloatArray]:
    """First row, last row + 1 and row count of each row's window (:class:`RowWindow`)."""
    i = np.arange(n)
    if gap is not None:
        brk = np.concatenate([[True], gap])
        seg = np.cumsum(brk) - 1
        starts = np.flatnonzero(brk)
        stops = np.append(starts[1:] - 1, n - 1)
        first, last = starts[seg], stops[seg]
    else:
        first, last = np.zeros(n, np.intp), np.full(n, n - 1)
    lo = np.maximum(i - k, first)
    hi1 = np.minimum(i + k, last) + 1
    return lo, hi1, (hi1 - lo).astype(float)


@functools.lru_cache(maxsize=8)
def _gapless_bounds(n: int, k: int) -> tuple[NDArray[np.intp], NDArray[np.intp], FloatArray]:
    out = _window_bounds(n, k, None)
    for a in out:
        a.flags.writeable = False
    return out


class _Settled:
    """A window evaluated on the first two iterates of a fixed point, then held: the
    nonlinear terms are ``ag`` times the window, whose argument moves by ``ag`` between
    iterates, so holding it after the second leaves ``ag^3`` of the rate (3e-8 for a raw
    MEMS gyro's 0.3 %), and the iteration spends no cumulative sums on the last digits."""

    def __init__(self, window: Window) -> None:
        self.window = window
        self.left = 2
        self.value: FloatArray | None = None

    def __call__(self, x: FloatArray) -> FloatArray:
        if self.left > 0 or self.value is None:
            self.left -= 1
            self.value = self.window(x)
        return self.value


def _settled(window: Window) -> Window:
    """:class:`_Settled` for a :class:`RowWindow` that averages; any other as it is (each
    sample's own value: ``compensate``'s exact fixed point)."""
    return _Settled(window) if isinstance(window, RowWindow) and window.k > 0 else window


#: Relative change at which the compensation has converged (``sensor_model``'s, a few ulps).
_TINY = 4.0 * float(np.finfo(float).eps)


@dataclass(frozen=True)
class BlockCompensation:
    """:func:`~imu_calib_ros.core.sensor_model.compensate` for the estimator's blocks.

    The same fixed point of the CONTRACT 3 equations::

        omega <- (I + Kg)^-1 (w_meas - bg - G f - ag |omega|)
        f     <- (I + Ka)^-1 (a_meas - ba - s(omega, omega_dot) - aa |f| - qa f^2)

    on ``(3, N)`` component rows with 3 x 3 matrix products, iterated until the largest
    relative change of the whole block is a few ulps (``compensate`` stops each sample on its
    own, in per-component arithmetic that gives a sample the same bits alone or in a batch:
    what the compensator node needs, at five times the numpy calls). The results agree with
    ``compensate`` to rounding (1e-15 of the largest value, ``test_block_compensation``). Without a
    g-sensitivity (``G = 0``) the rates do not depend on the specific force: they are iterated
    alone, once for the block and its margins, and the specific force with the rates fixed.
    Inputs must be finite (:func:`propagate_block` falls back to ``compensate`` otherwise).
    ``window``: the argument of the nonlinear terms (``|omega|``, ``|f|``, ``f^2``) is the
    :class:`RowWindow` mean of the iterate (default: the iterate itself, ``compensate``'s).
    """

    ig: FloatArray  # (I + Kg)^-1
    ia: FloatArray  # (I + Ka)^-1
    bg: FloatArray  # (3, 1) columns from here on
    ba: FloatArray
    G: FloatArray | None  # None: zero
    ag: FloatArray
    aa: FloatArray
    qa: FloatArray
    r: FloatArray | None  # (3, 3), row i = r_i; None: no size effect
    r_wd: FloatArray  # (3, 3): (omega_dot x r_i)_i = (r_wd @ omega_dot)_i

    @classmethod
    def of(cls, errors: Any) -> 'BlockCompensation':
        """The constants of a :class:`~imu_calib_ros.core.sensor_model.SensorErrors`."""
        G = np.asarray(errors.gyro_g_sensitivity_rad_s_per_m_s2, float)
        r = np.asarray(errors.size_effect_m, float)
        ig, ia = np.linalg.inv(np.eye(3) + np.stack([errors.gyro_scale_misalignment,
                                                     errors.accel_scale_misalignment]))
        return cls(ig, ia,
                   np.reshape(errors.gyro_bias_rad_s, (3, 1)),
                   np.reshape(errors.accel_bias_m_s2, (3, 1)),
                   G if np.any(G != 0.0) else None,
                   np.reshape(errors.gyro_scale_asymmetry, (3, 1)),
                   np.reshape(errors.accel_scale_asymmetry, (3, 1)),
                   np.reshape(errors.accel_quadratic_per_m_s2, (3, 1)),
                   r if np.any(r != 0.0) else None,
                   np.array([[0.0, r[0, 2], -r[0, 1]], [-r[1, 2], 0.0, r[1, 0]],
                             [r[2, 1], -r[2, 0], 0.0]]))

    def rates(self, w_raw: FloatArray, f_raw: FloatArray,
              window: Window = RowWindow.none) -> FloatArray:
        """Compensated rates ``(3, N)`` of raw ``(N, 3)`` samples with ``omega_dot = 0``."""
        wm = w_raw.T - self.bg
        if self.G is None:
            return self._rates_alone(wm, window)
        return self._coupled(wm, f_raw.T - self.ba, None, window)[0]

    def samples(self, w_raw: FloatArray, f_raw: FloatArray, omega_dot: FloatArray,
                rates: FloatArray, window: Window = RowWindow.none
                ) -> tuple[FloatArray, FloatArray]:
        """Compensated ``(3, N)`` rates and specific forces with ``omega_dot (3, N)``;
        ``rates``: :meth:`rates` of the same samples and window (used as they are when
        ``G = 0``)."""
        am = f_raw.T - self.ba
        if self.r is not None:
            am = am - self.r_wd @ omega_dot  # the omega_dot part of the size effect
        if self.G is None:
            return rates, self._forces_alone(am, rates, window)
        return self._coupled(w_raw.T - self.bg, am, omega_dot, window)

    def _gyro_step(self, wm: FloatArray, w: FloatArray, f: FloatArray | None,
                   window: Window) -> FloatArray:
        u = wm - self.ag * np.abs(window(w))
        if self.G is not None and f is not None:
            u = u - self.G @ f
        return self.ig @ u

    def _accel_step(self, am: FloatArray, w: FloatArray, f: FloatArray,
                    window: Window) -> FloatArray:
        fw = window(f)
        v = am - (self.aa * np.abs(fw) + self.qa * fw * fw)
        if self.r is not None:
            v = v - w * (self.r @ w)  # omega x (omega x r_i), i-th component
        return self.ia @ v

    @staticmethod
    def _iterate(x: FloatArray, step: Any, floor: float) -> FloatArray:
        """``x = step(x)`` until :class:`_Stop` (changes relative to the largest |x| per axis,
        at least ``floor``)."""
        scale = np.maximum(np.abs(x).max(axis=0), floor)
        stop = _Stop()
        while True:
            x_new = step(x)
            change = float((np.abs(x_new - x) / scale).max())
            x = x_new
            if stop(change):
                return x

    def _rates_alone(self, wm: FloatArray, window: Window) -> FloatArray:
        win = _settled(window)
        return self._iterate(self.ig @ wm, lambda w: self._gyro_step(wm, w, None, win), 1e-12)

    def _forces_alone(self, am: FloatArray, w: FloatArray, window: Window) -> FloatArray:
        win = _settled(window)
        return self._iterate(self.ia @ am, lambda f: self._accel_step(am, w, f, win), 1e-9)

    def _coupled(self, wm: FloatArray, am: FloatArray, omega_dot: FloatArray | None,
                 window: Window) -> tuple[FloatArray, FloatArray]:
        """Both (``omega_dot`` already in ``am``; None: zero)."""
        w, f = self.ig @ wm, self.ia @ am
        w_scale = np.maximum(np.abs(w).max(axis=0), 1e-12)
        f_scale = np.maximum(np.abs(f).max(axis=0), 1e-9)
        stop = _Stop()
        win_w, win_f = _settled(window), _settled(window)
        while True:
            w_new = self._gyro_step(wm, w, f, win_w)
            f_new = self._accel_step(am, w_new, f, win_f)
            change = max(float((np.abs(w_new - w) / w_scale).max()),
                         float((np.abs(f_new - f) / f_scale).max()))
            w, f = w_new, f_new
            if stop(change):
                return w, f


class _Stop:
    """The stopping rule of ``sensor_model.compensate`` for the largest relative change of a
    block: converged at a few ulps, or once a change below 1e-12 stopped shrinking (rounding
    can keep the last bit flickering); :class:`~..sensor_model.ImplausibleErrors` after
    ``max_iterations`` or on a non-finite change."""

    def __init__(self, max_iterations: int = 100) -> None:
        self.left = max_iterations
        self.last = math.inf
        self.stalled = 0

    def __call__(self, change: float) -> bool:
        if change <= _TINY:
            return True
        self.stalled = self.stalled + 1 if change >= self.last else 0
        if self.stalled >= 3 and change < 1e-12:
            return True
        self.last = change
        self.left -= 1
        if self.left <= 0 or not math.isfinite(change):
            raise sm.ImplausibleErrors(f'compensate did not converge (last relative change '
                                       f'{change:.3g}): implausible sensor errors')
        return False


#: half-width of the rate differences that give omega_dot for the size effect: the mean
#: rates of the ``h`` samples after an interval minus those of the ``h`` before it, ``h`` =
#: this span over the sample period (at least 1: at 200 Hz and below, neighbours). A
#: neighbour difference at 1 kHz has 1.1 rad/s^2 of noise on an industrial MEMS gyro, as
#: much as the table's angular accelerations: the size effect's regressor then drowns (its
#: z offsets 5 sigma off, the accelerometers 30 % noisier); over +-5 ms it is 0.17 rad/s^2.
OMEGA_DOT_SPAN_S = 0.005


def omega_dot_half_span(nominal_dt_s: float) -> int:
    """``h``: samples on each side of an interval for its omega_dot (:data:`OMEGA_DOT_SPAN_S`);
    also the look-ahead and the history a block needs."""
    return max(1, int(round(OMEGA_DOT_SPAN_S / nominal_dt_s))) if nominal_dt_s > 0 else 1


def _wide_differences(ww: FloatArray, ff: FloatArray, dt_all: FloatArray, h: int, m: int
                      ) -> tuple[FloatArray, FloatArray]:
    """``(mean of the h rows after - mean of the h rows before) / (their centroid times'
    difference)`` for the ``m`` block rows ``h .. h + m - 1`` of ``ww`` and ``ff``."""
    tau = np.concatenate([[0.0], np.cumsum(dt_all)])  # time of every row
    r = h + np.arange(m)
    out = []
    for x in (ww, ff, tau[:, None]):
        c = np.vstack([np.zeros((1, x.shape[1])), np.cumsum(x, axis=0)])
        out.append(((c[r + h + 1] - c[r + 1]) - (c[r] - c[r - h])) / h)
    span = out[2]
    return out[0] / span, out[1] / span


def _curvature(x: FloatArray, gap: NDArray[np.bool_]) -> FloatArray:
    """``f'' dt^2`` of every row of ``x (N, 3)``: its second difference, zero where it would
    take a row across a gap (``gap (N - 1,)``, of the intervals between rows) and the first
    and last rows the same as their neighbours'."""
    d2 = np.zeros_like(x)
    if len(x) < 3:
        return d2
    d2[1:-1] = np.where((gap[:-1] | gap[1:])[:, None], 0.0, x[2:] - 2.0 * x[1:-1] + x[:-2])
    d2[0], d2[-1] = d2[1], d2[-2]
    return d2


#: a third difference beyond this many sigmas of the noise's own (``sqrt(20)`` per-sample
#: sigmas) marks a corner of the motion (:func:`corner_variance`)
CORNER_SIGMAS = 5.0


def corner_variance(ff: FloatArray, R_enu_imu: FloatArray, dt: FloatArray, h: int, m: int,
                    sigma_f: float, gap: NDArray[np.bool_] | None = None,
                    trapezoid: bool = False) -> FloatArray | None:
    """Velocity variance per sample [(m/s)^2, ENU axes] (m, 3) that the increments carry at corners
    of the motion, or None when the block has none.

    A table's joint acceleration jumps at the corners of a trapezoidal rate profile, and the
    specific force of a point off the axes jumps with it (``alpha x r``: 0.1 m/s^2 at 2 rad/s^2 and
    45 mm). An interval mean holds the step exactly, but a point sample (a CONTRACT 1 option, and
    what the plain command reads as a mean, the measured latency taking up the half period of
    smooth motion) cannot say where in its interval the step fell: the velocity increment is off by
    up to ``|J| dt / 2``, variance ``J^2 dt^2 / 12`` for a step placed anywhere. Smooth motion
    curves the samples too (gravity turning through the IMU at 3 rad/s: second differences of 9e-3
    m/s^2 at 100 Hz, seven navigation-grade noise sigmas), which the trapezoid holds to the third
    derivative times dt^3; a step is what changes the curvature at once. So the third differences
    ``d3``: a step makes ``J/2 (1, -1, -1, 1)`` of the trapezoid means of declared point samples
    (``trapezoid``), ``J (1, -2, 1)`` of point samples read as means (the latency measured on
    smooth motion takes up their half period, which leaves ``J dt (s - 1/2)``), so ``sum (d3 dt)^2
    / 12``, respectively ``/ 72``, is the step's variance ``J^2 dt^2 / 12``. Interval means hold a
    step exactly, and one at a sample instant looks like a point sample's: it is widened too, by
    what a point sample would miss (the corners also strain the navigator's and the ``omega_dot``
    regressors' polynomial assumptions: a navigation unit's innovations there had doubled its bias
    walk before). Only components beyond :data:`CORNER_SIGMAS` of the noise's own third difference
    (``sqrt(20)`` per-sample sigmas ``sigma_f``) count: smooth motion adds nothing, white noise
    3e-5 of its own velocity variance (at 4 sigmas an industrial MEMS unit's heavier-tailed noise
    passed 13 times as often as a normal one's, and the widening moved its bias walk's adaptation).
    The rates are left alone: a kink of a rate costs a point sample ``a dt^2 / 8`` of angle, a
    second-order term the grid's point-sample runs never showed, while widening the attitude at
    every Kozlov oscillation's start (a rate kink that interval means, the CONTRACT default, hold
    exactly) kept a navigation unit's bias walk from adapting (accelerometer bias 3.1 sigma off in
    the grid). A corner within a sample of the block's edge is not seen (one sample in a block of
    hundreds). Found on a navigation unit at Svalbard (point samples, trapezoid moves): 10 of 7,500
    velocity updates gated, all at ramp corners, and the run refused; interval means of the same
    run gated none.

    ``ff``: the block's specific forces with ``h`` rows of history before and ``h`` of look-ahead
    after its ``m`` samples; ``R_enu_imu`` (m, 3, 3) the navigated attitude at each sample, ``dt``
    (m,) their intervals; ``gap`` (m + 2 h - 1,): the intervals between the rows that are gaps or
    made-up rows; differences across one are left out (what a gap loses is widened for by the gap
    handling; counted here too, a motion bridge's sigmas came out 22 % above those of the run
    without the gap)."""
    d3_all = np.diff(ff, n=3, axis=0)  # value k: rows k .. k + 3, intervals k .. k + 2
    if gap is not None and gap.any():
        d3_all[gap[:-2] | gap[1:-1] | gap[2:]] = 0.0
    # sample i (row h + i) takes the value of rows h + i - 2 .. h + i + 1
    d3 = np.zeros((m, 3))
    lo = max(0, 2 - h)
    hi = min(m, len(d3_all) - h + 2)
    d3[lo:hi] = d3_all[h + lo - 2:h + hi - 2]
    d3 *= d3
    hit = d3 > CORNER_SIGMAS ** 2 * 20.0 * sigma_f ** 2
    if not hit.any():
        return None
    k = 12.0 if trapezoid else 72.0  # J^2 dt^2 / 12 from either step pattern
    var = np.where(hit, d3, 0.0) * (dt * dt / k)[:, None]  # (m, 3) in the IMU frame
    return np.einsum('nij,nj->ni', R_enu_imu * R_enu_imu, var)  # diag(R diag(v) R^T)


def lever_acceleration(omega: FloatArray, omega_dot: FloatArray, rho: FloatArray) -> FloatArray:
    """``omega_dot x rho + omega x (omega x rho)`` for ``(N, 3)`` rates and accelerations and
    one ``rho (3,)``, ``(N, 3)``: the acceleration of a point of the body about a fixed one
    (written out: ``np.cross`` costs 30 us a call on a block)."""
    skew = np.array([[0.0, -rho[2], rho[1]], [rho[2], 0.0, -rho[0]], [-rho[1], rho[0], 0.0]])
    return (omega_dot @ skew + omega * (omega @ rho)[:, None]
            - np.outer(np.einsum('ij,ij->i', omega, omega), rho))


def table_specific_force(R_enu_imu: FloatArray, f_enu_m_s2: FloatArray,
                         lever_imu: FloatArray | None = None) -> FloatArray:
    """The specific-force regressor of the sensor Jacobians on a table: the mean over the
    block of the navigation-frame specific force ``f_enu (N, 3)``, in each sample's IMU frame
    (``R_enu_imu (N, 3, 3)``), ``(N, 3)``.

    Built from the samples themselves, the regressor of a scale factor, asymmetry, quadratic
    term or G carries the same noise that drives the chunk's velocity innovation: errors in
    variables, a bias of about (updates) x sigma^2 along a state the plan barely excites. An
    accelerometer axis kept within 5 deg of horizontal (|f| < 0.08 g at every dwell) had
    its scale 4.8 % off (truth 0.56 %, sigma 0.55 %) at 10 updates/s, 18 % at 50, and its row's
    misalignments 5-7 sigma, the self-check passing; noise-free data kept the truth. On a table
    the navigation-frame specific force is gravity plus the reference point's small
    acceleration, so its block mean (1 s, 10 chunks: a chunk's own noise a tenth of it) is
    the regressor to rounding at rest and to ``omega^2 |lever arm|`` in a turn; only the
    Jacobians use it, the navigation the samples. A general chain's arm accelerates the IMU
    by more: its Jacobians keep the samples.

    ``lever_imu (N, 3)``: the reference point's acceleration about the axes,
    ``omega_dot x rho + omega x (omega x rho)``, in each sample's IMU frame: its
    navigation-frame direction turns with the table (the block mean loses it), so it is
    taken out of the mean and added per sample (session 20). An IMU 31 cm from the axes,
    turns at up to 1 rad/s: a navigation unit's accelerometer x scale 9.6 ppm off (3.7
    sigma), 7.1 ppm with the centripetal part, 4.1 ppm at the axes. Kozlov's oscillations
    (2.5 rad/s^2) with the IMU 18 cm off: without the tangential part a tactical unit's
    poorly excited accelerometer scale passed its share to the size effect (5.6 sigma off),
    a navigation unit 5 cm off was refused; with it both are within 3 sigma."""
    if lever_imu is None:
        return np.einsum('nji,j->ni', R_enu_imu, f_enu_m_s2.mean(axis=0))
    rest = f_enu_m_s2 - np.einsum('nij,nj->ni', R_enu_imu, lever_imu)
    return np.einsum('nji,j->ni', R_enu_imu, rest.mean(axis=0)) + lever_imu


def _instant_rates(w_c: FloatArray, w_rows: FloatArray | None, ends: NDArray[np.intp], h: int,
                   gap: NDArray[np.bool_]) -> FloatArray:
    """The compensated rate at the chunk-end instants ``t_e`` (the lever arm's velocity there).

    The mean of the interval means either side, ``(w_e + w_e+1) / 2``, is exact for a rate
    linear in time; for ``omega = a + b t + c t^2`` it is ``c dt^2 / 3`` off. Kozlov's
    oscillations (90 deg at 5 s: ``d2 omega / dt2`` 3.1 rad/s^3) at 100 Hz: 5e-5 rad/s, with
    an IMU 31 cm from the axes 1.6e-5 m/s of velocity against the measurement's 1e-6: updates
    gated, the run refused (session 20). With the interval before,
    ``(-w_e-1 + 5 w_e + 2 w_e+1) / 6`` is exact for quadratics (``d3 omega / dt3 dt^3 / 12``
    off; its noise 0.91 of a sample's against 0.71). ``w_rows (3, m + 2 h)``: every
    compensated row of the block (history, block, look-ahead); None (a non-finite sample), or
    a gap before ``w_e``: the mean of two."""
    two = 0.5 * (w_c[ends] + w_c[ends + 1])
    if w_rows is None:
        return two
    e = h + ends  # the rows of w_e in w_rows
    three = (5.0 * w_rows[:, e] + 2.0 * w_rows[:, e + 1] - w_rows[:, e - 1]).T / 6.0
    return np.where(gap[e - 1][:, None], two, three)


def propagate_block(nav: Strapdown, errors: Any, time_offset_s: float,
                    prev: tuple[Any, FloatArray, FloatArray] | None, t: IntArray,
                    w: FloatArray, f: FloatArray, nominal_dt_s: float, B: int, n: int,
                    layout: StateLayout, omega_ie_enu_rad_s: FloatArray,
                    table: bool = False,
                    accel_sigma: float | None = None,
                    ahead_repeated: bool = False, trapezoid: bool = False,
                    lever_arm_imu_m: FloatArray | None = None,
                    sample_kernel: tuple[float, float] | None = None) -> Block:
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
        ``(stamps, raw gyro, raw accel)`` of the ``h`` samples before ``t[0]``
        (:func:`omega_dot_half_span`), or None at the first block after an alignment (then
        copies of the first sample, a nominal period apart).
    t, w, f : (B n + h,), (B n + h, 3), (B n + h, 3)
        Stamps [ns], raw mean rates and specific forces; the last ``h`` samples are the
        look-ahead.
    nominal_dt_s, B, n, layout, omega_ie_enu_rad_s :
        Sample period, chunks, samples per chunk, state layout, earth rate (ENU).
    table :
        The fixture is a table (concurrent axes): the Jacobians' specific force is
        :func:`table_specific_force`.
    accel_sigma :
        Per-sample white-noise sigma of the accelerometers [m/s^2]: with it, the velocity
        variance at corners of the motion (:func:`corner_variance`) in ``Block.q_corner_s``.
    ahead_repeated :
        The look-ahead rows repeat the last sample (no data after it yet): like the history
        rows copied at the first block after an alignment, not a corner of the motion.
    trapezoid :
        The samples are trapezoid means of declared point samples (:func:`corner_variance`;
        the raw sample after a gap has no curvature for the kernels).
    lever_arm_imu_m :
        The reference point from the axes' common point, IMU frame (a table's Jacobians
        take its acceleration about the axes, :func:`table_specific_force`); None: none.
    sample_kernel :
        The gyros' and the accelerometers' sampling kernels, estimated or assumed (0: interval
        means, 1: point samples; :func:`~.error_model.sample_kernel_column`); None: none.
    """
    m = B * n
    nom = nominal_dt_s
    h = len(t) - m  # look-ahead samples = history samples (omega_dot_half_span)
    # intervals; a gap (> 1.5 nominal periods) is a sample of one nominal period
    if prev is None:
        step = int(round(nom * 1e9))
        t_prev = int(t[0]) - step * np.arange(h, 0, -1, dtype=np.int64)
        w_prev, f_prev = np.repeat(w[:1], h, axis=0), np.repeat(f[:1], h, axis=0)
    else:
        t_prev, w_prev, f_prev = prev
    tt = np.concatenate([np.atleast_1d(t_prev), t]).astype(np.int64)
    dt_all = np.diff(tt) * 1e-9  # (m + 2 h - 1,)
    gap = dt_all > 1.5 * nom
    n_gaps = int(gap[h - 1:h - 1 + m].sum())
    dt_all = np.where(gap, nom, dt_all)
    ww = np.vstack([np.reshape(w_prev, (-1, 3)), w])  # (m + 2 h, 3): history, block, ahead
    ff = np.vstack([np.reshape(f_prev, (-1, 3)), f])
    w_in = ww
    # of the compensated rates: with raw ones, a raw unit's 0.5 % scale error made the
    # size effect 1 % (6 sigma) wrong (issue 11); the gyro part needs no omega_dot
    comp = BlockCompensation.of(errors) if np.isfinite(ww.sum() + ff.sum()) else None
    window = RowWindow(len(ww), h, gap)  # the nonlinear terms' argument (rectification)
    # the kernels' corrections of every row (gyros, accelerometers), the gyros' curvature
    # (their regressor) and the block rows that have one
    kern: tuple[FloatArray, FloatArray, FloatArray, NDArray[np.bool_]] | None = None
    if sample_kernel is not None:
        # the samples' own curvature, 0 across a gap and at copied rows (and, for declared
        # point samples, at the raw one after a gap among trapezoids): the navigation's
        # correction (at s = 1 the noise through (1, 22, 1) / 24, its sum unchanged) and the
        # gyros' regressor; the accelerometers' is the smooth one below (the navigation
        # can't wait for it)
        made_up = gap.copy()
        if prev is None:
            made_up[:h] = True
        if ahead_repeated:
            made_up[-h:] = True
        if trapezoid:
            made_up[1:] |= gap[:-1]
        d2w = _curvature(w_in, made_up)
        kern = (sample_kernel[0] * em.sample_kernel_column(d2w),
                sample_kernel[1] * em.sample_kernel_column(_curvature(ff, made_up)), d2w,
                ~(made_up[h - 1:h + m - 1] | made_up[h:h + m]))
    if comp is not None:
        w_raw = ww
        rates = comp.rates(ww, ff, window)  # (3, m + 2 h)
        ww = rates.T
    else:  # a non-finite sample: compensate's NaN rows (the navigator then refuses them)
        ww = sm.compensate(errors, ww, ff, np.zeros_like(ww))[0]
    # omega_dot at each interval (Kozlov eq. 1 term): central differences of mean rates
    if h == 1:
        den = (dt_all[:-1] + dt_all[1:])[:, None]
        wd = (ww[2:] - ww[:-2]) / den  # (m, 3)
        fd = (ff[2:] - ff[:-2]) / den
    else:
        wd, fd = _wide_differences(ww, ff, dt_all, h, m)
    wd_all = np.vstack([wd, wd[-1:]])  # the first look-ahead sample: reuse
    w, f = w[:m + 1], f[:m + 1]
    if comp is not None:
        # every row, so that the windows of the block's rows see their neighbours' forces
        # (omega_dot of the margins: their nearest block row's, for the size effect alone)
        wd_rows = np.vstack([np.repeat(wd[:1], h, axis=0), wd_all,
                             np.repeat(wd[-1:], h - 1, axis=0)])
        w_c3, f_c3 = comp.samples(w_raw, ff, wd_rows.T, rates, window)
        if kern is not None:  # every row: the chunk ends' rates take their means
            w_c3, f_c3 = w_c3 - kern[0].T, f_c3 - kern[1].T
        w_s = window(w_c3)[:, h:h + m].T  # the Jacobians' |omega| (rectification)
        w_c = np.ascontiguousarray(w_c3[:, h:h + m + 1].T)
        f_c = np.ascontiguousarray(f_c3[:, h:h + m + 1].T)
    else:
        w_c, f_c = sm.compensate(errors, w, f, wd_all)
        if kern is not None:
            w_c, f_c = w_c - kern[0][h:h + m + 1], f_c - kern[1][h:h + m + 1]
        w_s = w_c[:m]
    if time_offset_s != 0.0:
        f_c = f_c - time_offset_s * np.vstack([fd, fd[-1:]])
    dt = dt_all[h - 1:h - 1 + m]
    if n_gaps:
        nav.reset_memory()
    R_start = nav.R_enu_imu
    out = nav.propagate(dt, w_c[:m], f_c[:m])
    R_mid = 0.5 * (np.concatenate([R_start[None], out.R_enu_imu[:-1]]) + out.R_enu_imu)
    # sensor Jacobians on the compensated samples; on a table, their specific-force regressor
    # is the block's mean navigation-frame specific force in each sample's IMU frame
    # (:func:`table_specific_force`), not the sample itself
    f_turn = None  # the kernel's regressor: the table's turn of the mean specific force
    if table:
        acc = None  # the reference point's acceleration about the axes (IMU frame)
        if lever_arm_imu_m is not None and np.any(lever_arm_imu_m):
            acc = lever_acceleration(w_s, wd, np.asarray(lever_arm_imu_m, float))
        f_j = table_specific_force(R_mid, out.f_enu_m_s2, acc)
        # without the lever arm's acceleration: its omega_dot is a difference of noisy rates
        # (a tactical gyro's 0.02 rad/s^2 x 18 cm, 4e-3 m/s^2 a sample, as much as gravity's
        # curvature at 2 rad/s), errors in variables that took the kernel to -30 +- 0.6 under
        # Kozlov's oscillations 18 cm off the axes (truth 0; without it -0.06 +- 1.99: a
        # heading oscillation turns no gravity, and the reference point's own curvature, left
        # out, is ~1e-4 m/s^2 a sample there)
        f_turn = f_j if acc is None else table_specific_force(R_mid, out.f_enu_m_s2)
    else:
        f_j = f_c[:m]
    w2 = f2 = None
    if kern is not None:  # the rows the navigation corrected, alone
        w2 = kern[2][h:h + m]
        f2 = _curvature(f_j if f_turn is None else f_turn, np.zeros(m - 1, bool))
        f2[~kern[3]] = 0.0
    Mg = em.gyro_jacobian(w_s, f_j, w2)
    Ma = em.accel_jacobian(w_c[:m], wd, f_j, fd, f2)
    Dg_inv, Da_inv = em.compensation_inverses(errors, w_s, f_j)
    rows = chunk_transition_rows(layout, R_mid.reshape(B, n, 3, 3),
                                 out.f_enu_m_s2.reshape(B, n, 3),
                                 Mg.reshape(B, n, 3, em.N_GYRO),
                                 Ma.reshape(B, n, 3, em.N_ACCEL), dt.reshape(B, n),
                                 omega_ie_enu_rad_s, Dg_inv.reshape(B, n, 3, 3),
                                 Da_inv.reshape(B, n, 3, 3))
    s = layout.scale
    rows_s = rows * (s[None, None, :] / s[None, 0:6, None])
    ends = np.arange(n - 1, m, n)
    q_corner = None
    if accel_sigma is not None:
        made_up = gap.copy()  # rows that are copies, not samples: no corner across them
        if prev is None:
            made_up[:h] = True
        if ahead_repeated:
            made_up[-h:] = True
        var = corner_variance(ff, out.R_enu_imu, dt, h, m, accel_sigma, gap=made_up,
                              trapezoid=trapezoid)
        if var is not None:
            q_corner = var.reshape(B, n, 3).sum(axis=1) / (s[None, 3:6] ** 2)
    return Block(rows_s=rows_s, T_s=dt.reshape(B, n).sum(axis=1), ends=ends,
                 R_enu_imu_end=out.R_enu_imu[ends], v_enu_end_m_s=out.v_enu_m_s[ends],
                 omega_ib_end_rad_s=_instant_rates(w_c, w_c3 if comp is not None else None,
                                                   ends, h, gap), n_gaps=n_gaps,
                 q_corner_s=q_corner)
