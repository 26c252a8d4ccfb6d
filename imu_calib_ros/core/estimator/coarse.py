"""Coarse start from the data, before the filter runs (issue 11; METHODS.md section 4).

A unit on its first calibration has raw errors of percents and milliradians and a mounting
known to a few degrees; a filter linearised about "no errors, nominal mounting" leaves its
linear region in the first rotation. This module reads the first stretch of data (or all of
it) and returns a start point with honest sigmas:

1. stationary windows from the joint states (every joint still for ``min_static_s``);
2. white-noise densities of gyros and accelerometers in those windows (Allan deviation at the
   short taus, :func:`..allan.overlapping_avar`), and the bias random-walk level from how
   the window residuals wander with the time between windows (item 5);
3. the IMU-to-encoder time offset: the gyro rate magnitude against the encoder rate magnitude
   (both invariant to the unknown mounting and nearly to the scale errors), least squares
   over a grid of shifts refined by a parabola (METHODS.md: cross-correlation), then
   refined from the whole rate vector through the gyro fit of step 4 (:func:`refine_latency`,
   Gauss-Newton on the shift) and step 4 repeated at the refined latency;
4. gyros by linear least squares over every sample:
   ``w_meas_i = (B omega_nom)_i + ag_i |w_i| + G_i . f + bg_i`` with ``omega_nom`` the rate of
   the *nominal* IMU frame from the encoders (spline derivative) plus earth rate; the left
   polar decomposition ``B = (I + Kg) R_m^T`` gives the symmetric ``Kg`` (CONTRACT 3's
   definition of the body frame) and the mounting ``R_m`` (``R_enu_imu = R_nominal R_m``);
   the covariance is cluster-robust over 1 s blocks (the residuals are not white: model
   error and encoder interpolation);
5. accelerometers from the window means (Tedaldi et al.'s multi-position idea, linear here
   because the encoders give the attitude): ``f_meas = A g_nom + aa |f| + ba`` with
   ``A = (I + Ka) R_m^T`` (the quadratic term left to the filter).

Hand-written because no library fits gyro and accelerometer errors to encoder kinematics;
the pieces (CubicSpline, polar, lstsq) are scipy's; the Allan variance is allantools' estimator
(:mod:`..allan`, held to ``allantools.oadev`` by a test).
"""
from __future__ import annotations

import contextlib
import dataclasses
import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray
from scipy.interpolate import CubicSpline
from scipy.linalg import polar
from scipy.spatial.transform import Rotation

from .. import parameters as registry
from ..allan import overlapping_avar
from ..rotation import skew
from . import error_model as em
from .buffers import encoder_clause, encoder_noise_rad, encoder_quantum_rad
from .quantiles import t_isf

if TYPE_CHECKING:
    from ..fixture import Fixture

FloatArray = NDArray[np.float64]

STATIC_TRIM_S = 0.3  # dropped at both ends of a still window (settling, latency up to 50 ms)
MAX_LATENCY_S = 0.06  # searched joint-stamp latency (CONTRACT 1: up to +-50 ms)
BLOCK_S = 1.0  # cluster length of the robust covariance


class NoRotation(ValueError):
    """The data hold no rotation (the caller's own "no motion" check says it better)."""


@dataclass(frozen=True)
class StaticWindow:
    """One stationary window: mean IMU outputs, joint angles, span and sample count."""

    t0_ns: int
    t1_ns: int
    q_rad: FloatArray
    gyro_mean_rad_s: FloatArray
    accel_mean_m_s2: FloatArray
    n: int


#: |scale factor| beyond which a coarse start is refused: units are specified within 3 %
#: (MEMS); 20 % is no sensor error but axes, units or a fixture that do not match the data
#: (a tilted fixture axis once fitted an accelerometer scale of -99.99 %, where the output no
#: longer depends on the input and every later compensation diverged)
MAX_PLAUSIBLE_SCALE = 0.2


def implausible(start: 'CoarseStart') -> str | None:
    """One line naming the first measured scale factor beyond :data:`MAX_PLAUSIBLE_SCALE`,
    else None."""
    for side, name, theta, sig, cols in (
            ('gyro', 'scale', start.theta_gyro, start.sigma_gyro, em.gyro_cols('gyro_scale')),
            ('accelerometer', 'scale', start.theta_accel, start.sigma_accel,
             em.accel_cols('accel_scale'))):
        for a, (v, s) in enumerate(zip(theta[cols], sig[cols])):
            if np.isfinite(s) and abs(v) > MAX_PLAUSIBLE_SCALE:
                article = 'an' if side[0] in 'aeiou' else 'a'
                return (f'the stationary windows and rotations need {article} {side} {"xyz"[a]} '
                        f'{name} factor of {100 * v:+.1f} % (units are specified within 3 %): '
                        'the fixture file (axes, mounting), the joint names or signs, or the '
                        "IMU's axes or units do not match the data")
    return None


#: :meth:`CoarseStart.determined`: largest sigma of the gyro scale/misalignment and the
#: mounting [rad, ratio], and of the accelerometer scale/misalignment, of a determined start
GYRO_LIMIT = 2e-3
ACCEL_LIMIT = 5e-3


@dataclass(frozen=True)
class CoarseStart:
    """A start point for the filter measured from the data (SI, error_model theta order).

    ``sigma_*`` are one-sigma uncertainties of the coarse values (``inf`` where the data did
    not determine a value: the caller keeps a wide prior there).
    """

    theta_gyro: FloatArray
    theta_accel: FloatArray
    sigma_gyro: FloatArray
    sigma_accel: FloatArray
    mounting_rotvec_rad: FloatArray  # R_enu_imu = R_nominal(q) @ exp(mounting)
    mounting_sigma_rad: float
    joint_latency_s: float  # joint stamp minus the instant it describes
    joint_latency_sigma_s: float
    gyro_noise_rad_s_rt_hz: float
    accel_noise_m_s2_rt_hz: float
    gyro_bias_random_walk_rad_s2_rt_hz: float
    accel_bias_random_walk_m_s3_rt_hz: float
    n_static_windows: int
    duration_s: float
    notes: tuple[str, ...] = field(default=())
    #: a turntable's encoder zeros the windows' gravity shows (n,) [rad]: the joint is at
    #: ``q + joint_zero_rad`` when its encoder reads ``q`` (:func:`fit_joint_zeros`)
    joint_zero_rad: FloatArray = field(default_factory=lambda: np.zeros(0))
    #: their sigmas (n,) [rad]; inf where gravity does not show a zero (the last joint's is
    #: the mounting, a vertical one's a heading)
    joint_zero_sigma_rad: FloatArray = field(default_factory=lambda: np.zeros(0))
    #: a MEMS unit without a grade: its gyro bias walk density over its white-noise density
    #: [1/s] when the innovations' likelihood over whole passes raised it above the floor (an
    #: offline replay's decision carried to the later passes with the start:
    #: :func:`.replay.profile_gyro_walk`; its profile passes also run below the floor); 0:
    #: the MEMS floor
    gyro_walk_to_noise_per_s: float = 0.0
    #: the profile behind it: its one-sided 95 % upper bound [1/s] (below the floor too) and
    #: ``((ratio, NLL - least NLL), ...)``
    gyro_walk_bound_per_s: float = 0.0
    gyro_walk_profile: tuple[tuple[float, float], ...] = ()
    #: the least share of gravity the windows put along any IMU direction (least_reach)
    accel_reach: float = 1.0
    #: the table's base tilt from level, ``(t_e, t_n)`` [rad] (:func:`fit_joint_zeros`):
    #: the fixture the filter uses is ``fixture.with_base_tilt(base_tilt_rad)``; its sigmas
    base_tilt_rad: FloatArray = field(default_factory=lambda: np.zeros(2))
    base_tilt_sigma_rad: FloatArray = field(default_factory=lambda: np.full(2, np.inf))
    #: the (IMU, joint) stamp clocks' revisions of the held stamps the start was measured on
    #: (:class:`~..stamp_clock.StampRevisions`, None where none): carried to the later passes
    #: with the start, whose clocks apply them (:attr:`~..stamp_clock.StampClock.hindsight`)
    stamp_revisions: tuple[Any, Any] = (None, None)
    #: the IMU's sample period the start was measured at [s] (0: not known)
    imu_period_s: float = 0.0

    def determined(self, gyro_limit: float = GYRO_LIMIT, accel_limit: float = ACCEL_LIMIT
                   ) -> bool:
        """True when rotations about three axes and gravity along three directions pinned the
        gyro scale/misalignment and the mounting to ``gyro_limit`` (rad, ratio; they turn
        into attitude errors that multiply gravity) and the accelerometer scale/misalignment to
        ``accel_limit`` (linear in velocity; with only axis-up/down poses the scale stays
        within the asymmetry's 3e-3): a filter started there stays linear. Before that the
        live estimator gathers data."""
        gyro = max(self.mounting_sigma_rad,
                   float(np.max(self.sigma_gyro[em.gyro_cols('gyro_scale')])),
                   float(np.max(self.sigma_gyro[em.gyro_cols('gyro_misalignment')])))
        accel = max(float(np.max(self.sigma_accel[em.accel_cols('accel_scale')])),
                    float(np.max(self.sigma_accel[em.accel_cols('accel_misalignment')])))
        # a table's encoder zeros that gravity shows: the fits below them lean on them (a
        # start taken on 7 windows, the middle zero 4.6 +- 7.3 mrad and not applied, bent the
        # gyro and accelerometer fits; at 87 s the updates were gated and the filter diverged)
        zs = np.concatenate([np.asarray(self.joint_zero_sigma_rad, float),
                             np.asarray(self.base_tilt_sigma_rad, float)])
        zero = float(np.max(zs[np.isfinite(zs)])) if np.any(np.isfinite(zs)) else 0.0
        return bool(max(gyro, zero) < gyro_limit and accel < accel_limit
                    and self.accel_reach >= MIN_ACCEL_REACH)

    def summary(self) -> dict[str, Any]:
        """Plain values for provenance and logs."""
        return {
            'joint_latency_s': self.joint_latency_s,
            'mounting_rotvec_rad': [float(v) for v in self.mounting_rotvec_rad],
            'mounting_deg': float(np.degrees(np.linalg.norm(self.mounting_rotvec_rad))),
            'gyro_noise_rad_s_rt_hz': self.gyro_noise_rad_s_rt_hz,
            'accel_noise_m_s2_rt_hz': self.accel_noise_m_s2_rt_hz,
            'gyro_bias_random_walk_rad_s2_rt_hz': self.gyro_bias_random_walk_rad_s2_rt_hz,
            'accel_bias_random_walk_m_s3_rt_hz': self.accel_bias_random_walk_m_s3_rt_hz,
            'static_windows': self.n_static_windows, 'duration_s': self.duration_s,
            'base_tilt_rad': [float(v) for v in self.base_tilt_rad],
            # (None along an axis gravity does not show apart from a joint's zero)
            'base_tilt_sigma_rad': [float(v) if math.isfinite(v) else None
                                    for v in self.base_tilt_sigma_rad],
            'notes': list(self.notes)}


#: a still window's leading and trailing 0.1 s bins whose gyro means stand out from the
#: window's median by more than this many robust sigmas are a move's tail (:func:`settled`)
SETTLE_SIGMAS = 6.0
SETTLE_BIN_S = 0.1


def settled(g_bins: FloatArray) -> tuple[int, int]:
    """The bins ``[lo, hi)`` of a still window that the gyros show at rest: bins whose mean
    rate (``g_bins`` (n, 3), one row per :data:`SETTLE_BIN_S`) stand out from the window's
    median by more than :data:`SETTLE_SIGMAS` sigmas on any axis are motion, and the window
    is cut after the last of them in its first half and before the first in its second
    half, one bin of margin more (a ringing tail whose first bin crosses zero is cut whole).
    The sigma is 1.4826 MAD, at least half the bins' least step off the median (quantised
    gyros leave most bins on the median: the MAD alone was 0 and cut rest at one step). A
    cut may leave too little: the caller's least length decides.

    The joints' still test cannot see a move's last angle within its tolerance, and a
    tolerance raised by the encoders' own noise lets much of it in: at 0.2 mrad of noise
    (1.2 mrad tolerance) the windows took the last 0.1-0.4 s of the moves, 0.1-0.24 mrad of
    rotation, several deg/h on a navigation gyro's 10 s mean, and its windows' chi2/dof came
    out 7.5. A window of 100 bins at rest is cut about once in 3000 (the MAD read off 100
    bins scatters; at 5 sigmas 17 in 3000). The bins start at the window's start: the last
    samples short of a whole bin are not judged (the move that ends a window starts after
    its 0.3 s trim)."""
    n = len(g_bins)
    if n < 5:
        return 0, n
    med = np.median(g_bins, axis=0)
    dev = np.abs(g_bins - med)
    # a quantised gyro's bins sit on a lattice: half its least step is the least sigma
    step = np.min(np.where(dev > 0.0, dev, np.inf), axis=0)
    sig = np.maximum(1.4826 * np.median(dev, axis=0),
                     np.where(np.isfinite(step), 0.5 * step, 1e-12))
    out = np.flatnonzero(np.any(dev > SETTLE_SIGMAS * sig, axis=1))
    first, second = out[out < n // 2], out[out >= n // 2]
    lo = int(first[-1]) + 2 if len(first) else 0
    hi = int(second[0]) - 1 if len(second) else n
    return lo, max(hi, lo)


def static_windows(t_ns: NDArray[np.int64], q: FloatArray, t_imu_ns: NDArray[np.int64],
                   w: FloatArray, f: FloatArray, min_static_s: float, tol_rad: float
                   ) -> list[StaticWindow]:
    """Windows where every joint stays within ``tol_rad`` for ``min_static_s`` (trimmed by
    :data:`STATIC_TRIM_S` at both ends, and to where the gyros show rest: :func:`settled`),
    with the IMU and joint means over them."""
    out = []
    dt_ns = float(np.median(np.diff(t_imu_ns))) if len(t_imu_ns) > 1 else 1.0
    per_bin = max(1, int(round(SETTLE_BIN_S * 1e9 / dt_ns)))
    for t0, t1, q_mean in still_spans(t_ns, q, min_static_s, tol_rad)[0]:
        k0, k1 = np.searchsorted(t_imu_ns, [t0, t1])
        if k1 - k0 < 10:
            continue
        nb = (k1 - k0) // per_bin
        lo, hi = settled(w[k0:k0 + nb * per_bin].reshape(nb, per_bin, 3).mean(axis=1))
        if (lo, hi) != (0, nb):
            if hi - lo < 1:
                continue
            k0, k1 = k0 + lo * per_bin, k0 + hi * per_bin
            t0, t1 = int(t_imu_ns[k0]), int(t_imu_ns[k1 - 1])
            # the joint states inside the cut only (the next one is in the cut tail)
            j0, j1 = np.searchsorted(t_ns, [t0, t1], side='right')
            if (t1 - t0) * 1e-9 < min_static_s or j1 <= j0:
                continue
            q_mean = q[j0:j1].mean(axis=0)
        out.append(StaticWindow(t0, t1, q_mean, w[k0:k1].mean(axis=0), f[k0:k1].mean(axis=0),
                                int(k1 - k0)))
    return out


def still_spans(t_ns: NDArray[np.int64], q: FloatArray, min_static_s: float, tol_rad: float
                ) -> tuple[list[tuple[int, int, FloatArray]], int]:
    """The joint side of :func:`static_windows`: ``(t0_ns, t1_ns, mean q)`` of every still
    span, and the index where the record's last run of still samples starts.

    A span depends only on the samples of its run (between two moving samples), so the spans
    of the runs before that index stay as they are when samples are appended (what
    :class:`~.run_ledger.RunLedger` keeps between calls); a span of the last run starts
    after that sample's stamp, every earlier one before it.
    """
    if len(t_ns) < 2:
        return [], 0
    moving = np.any(np.abs(np.diff(q, axis=0)) > tol_rad, axis=1)
    mv = np.nonzero(moving)[0]
    starts = np.concatenate([[0], mv + 1])
    stops = np.concatenate([mv, [len(t_ns) - 1]])
    trim = int(STATIC_TRIM_S * 1e9)
    # the runs shorter than min_static_s (most of them: every moving sample is a run), at once
    long = (t_ns[stops] - t_ns[starts]) * 1e-9 >= min_static_s
    out = []
    for a, b in zip(starts[long].tolist(), stops[long].tolist()):
        # the longest stretch within tol of the run's median: a slow creep at either end
        # (a move's tail below tol per sample) is cut instead of losing the window
        near = np.all(np.abs(q[a:b + 1] - np.median(q[a:b + 1], axis=0)) <= tol_rad, axis=1)
        edges = np.diff(np.concatenate([[0], near.astype(np.int8), [0]]))
        ups, downs = np.nonzero(edges == 1)[0], np.nonzero(edges == -1)[0]
        if not len(ups):
            continue
        k = int(np.argmax(downs - ups))
        a, b = a + int(ups[k]), a + int(downs[k]) - 1
        t0, t1 = int(t_ns[a]) + trim, int(t_ns[b]) - trim
        if (t1 - t0) * 1e-9 < min_static_s:
            continue
        j0, j1 = np.searchsorted(t_ns, [t0, t1])
        qs = q[j0:j1 + 1]
        if np.ptp(qs, axis=0).max() > 2 * tol_rad:
            continue
        out.append((t0, t1, qs.mean(axis=0)))
    return out, int(starts[-1])


def white_noise_density(x: FloatArray, dt_s: float, point: bool = False) -> float:
    """White-noise density [unit/sqrt(Hz)] of a stationary record (N, 3); the rms over the axes.

    Overlapping Allan variance (:func:`..allan.overlapping_avar`) at the short taus ``dt .. 512
    dt`` (at most an eighth of the record), fitted by weighted least squares as
    ``N^2 / tau + 3 Q^2 / tau^2``: white noise plus the quantisation of an integrating output
    (IEEE Std 952-1997 annex C). At ``tau = dt`` alone a navigation gyro's increment
    quantisation read as white noise: at 2 kHz three times the unit's angle random walk, and
    every sigma of the run 1.2-1.5x the true noise model's. The longer terms (bias
    instability, rate random walk) are negligible this close to the sample period.

    The fit is unbiased (session 21). Each point is weighted by the inverse of the *model's*
    variance there (times its relative spread ``sqrt(m / n)``), refitted twice from a first
    fit, and ``Q^2`` is not held non-negative. Weighting by the point's own (noisy) value
    favours the points that came out low. Clamping ``Q^2 >= 0`` takes the white term down
    whenever noise makes the quantisation term look positive. Together they read white
    noise 3.4 % low in 500 samples and 2.2 % in 1000 (the window of a short stationary pose).
    Q and R were then too small, and a 50 Hz run showed a velocity NIS of 1.10 per dof and
    gated updates beyond its self-check's tolerance. The unconstrained fit spreads a little
    more (3.6 % against 2.9 % in 500 samples); the run takes the median over its windows.

    ``point``: ``x`` are point samples turned into interval means by the trapezoid
    (``buffers.point_to_mean``), whose neighbours share a point: their Allan variance at
    ``tau = m dt`` is ``N^2 (m - 3/4) / (m^2 dt)``, not ``N^2 / (m dt)`` (at ``dt`` a quarter;
    read as white noise, declared point samples came out at 55 % of their density and the run
    failed its self-check, NIS 1.7 per dof).
    """
    from scipy.optimize import nnls
    n = x.shape[0]
    m = np.array([k for k in (1, 2, 4, 8, 16, 32, 64, 128, 256, 512) if 8 * k <= n] or [1],
                 float)
    taus = m * dt_s
    A = np.column_stack([1.0 / taus - (0.75 * dt_s / taus ** 2 if point else 0.0),
                         3.0 / taus ** 2])
    avar_all = overlapping_avar(x, m.astype(np.int64))
    out = []
    for a in range(x.shape[1]):
        avar = avar_all[:, a]
        k = np.flatnonzero(np.isfinite(avar))
        avar = avar[k]
        if len(avar) < 2 or np.any(avar <= 0.0):
            # too short to fit, or a noise-free (synthetic, constant) record: the first point
            out.append(avar_all[0, a] * dt_s if np.isfinite(avar_all[0, a]) else math.nan)
            continue
        Ak, spread = A[k], np.sqrt(m[k] / n)  # a point's relative spread ~ sqrt(m / n)
        coef, _ = nnls(Ak / (avar * spread)[:, None], 1.0 / spread)  # the first fit
        for _ in range(2):
            model = Ak @ coef
            if not np.all(model > 0.0):
                break
            wgt = 1.0 / (model * spread)
            coef = np.linalg.lstsq(Ak * wgt[:, None], avar * wgt, rcond=None)[0]
        out.append(coef[0] if coef[0] > 0 else float(avar[0]) * dt_s)
    return float(np.sqrt(max(float(np.mean(out)), 0.0)))


def pair_walk(t_mid_s: FloatArray, T_s: FloatArray, means: FloatArray, white: float,
              i: NDArray[np.intp], j: NDArray[np.intp]) -> tuple[float, FloatArray, FloatArray]:
    """The bias random walk from pairs ``(i, j)`` of stationary-window means (item 5).

    Between two windows a mean changes by white noise (``white^2 / T`` each), by a constant
    scatter (a pose-dependent misfit, a misjudged white noise) and by the bias walk, growing
    with the time between: ``y = E[(m_j - m_i)^2] - s_i^2 - s_j^2 = a + q |t_j - t_i|``,
    fitted by least squares. Only a slope that stands out counts (its standard error that of
    the windows the pairs use, not of the pairs that share them; beyond the Student-t quantile
    :data:`WALK_FALSE_ALARM` for that many windows less two: with t > 3 over the few windows
    of a plan's first minutes, a run checked every minute took white noise for a walk in 1-2.5
    % of runs, which then held the walk for good).

    Returns ``(q or 0, y, |t_j - t_i|)`` per pair (PSD per second; ``y`` and the time
    differences for callers that fit more).
    """
    s2 = white ** 2 / T_s
    y = np.mean((means[j] - means[i]) ** 2, axis=1) - s2[i] - s2[j]
    dt = np.abs(t_mid_s[j] - t_mid_s[i])
    X = np.column_stack([np.ones(len(i)), dt])
    beta, *_ = np.linalg.lstsq(X, y, rcond=None)
    r = y - X @ beta
    used = len(set(i.tolist()) | set(j.tolist()))
    cov = (np.linalg.pinv(X.T @ X) * float(r @ r) / max(len(y) - 2, 1)
           * max(len(y) / used, 1.0))  # never more independent than the pairs
    q, sq = float(beta[1]), math.sqrt(max(float(cov[1, 1]), 0.0))
    return (q if q > 0 and q > walk_threshold(used) * sq else 0.0), y, dt


#: one-sided false-alarm probability of each test that a bias walk stands out (:func:`pair_walk`,
#: ``RunLedger.bias_walk``)
WALK_FALSE_ALARM = 3e-3


def walk_threshold(windows: int) -> float:
    """How many standard errors a walk estimate from ``windows`` stationary windows must
    stand out by: the Student-t quantile of :data:`WALK_FALSE_ALARM` with ``windows - 2``
    degrees of freedom (2.8 for many windows, 5.3 for six)."""
    return t_isf(WALK_FALSE_ALARM, max(windows - 2, 1))


def _random_walk(wins: list[StaticWindow], resid: FloatArray, white: float, dt: float) -> float:
    """Bias random-walk density [per sqrt(s)] from how the stationary-window residuals (mean
    output minus the coarse model) wander, over all pairs of windows (:func:`pair_walk`); a
    Gauss-Markov instability shows as the walk over the plan's length. 0 with fewer than
    four windows."""
    if len(wins) < 4:
        return 0.0
    tm = np.array([(w.t0_ns + w.t1_ns) * 0.5e-9 for w in wins])
    T = dt * np.array([w.n for w in wins], float)
    i, j = np.triu_indices(len(wins), 1)
    return math.sqrt(pair_walk(tm, T, resid, white, i, j)[0])


def _coarse_encoders(q_joint: FloatArray) -> str:
    """``' (or the joint encoders read ...)'`` when the joint record's steps or noise are
    above what the plain command is checked on (:func:`.buffers.encoder_clause`), else ''."""
    step = float(np.max(encoder_quantum_rad(q_joint))) if len(q_joint) > 2 else 0.0
    noise = float(np.min(encoder_noise_rad(q_joint))) if len(q_joint) > 2 else 0.0
    clause = encoder_clause(noise, step)
    return f' (or {clause})' if clause else ''


#: share of the moving windows whose encoder rate magnitude is 180/pi times the gyros' (within
#: 10 %) that says the joint positions are in degrees (:func:`_degrees_share`)
DEGREES_SHARE = 0.2


def _degrees_share(fixture: Fixture, spline: CubicSpline, t_a: FloatArray, t_b: FloatArray,
                   gyro_mag: FloatArray) -> float:
    """The share of the windows ``[t_a, t_b]`` in which the encoder rate magnitude is
    180/pi times the gyros' (``gyro_mag``) within 10 %, at the shift (within
    +-:data:`MAX_LATENCY_S`) where the most are. Frame-free; the encoder side from angle
    differences (a rotation vector would wrap at pi: degrees turn 57 times as far). Not one
    ratio: joint positions in degrees are unwrapped as if radians (a step above 3.14 deg
    between joint states jumps by 360/(2 pi) of them), and in windows that hold such a
    jump, or two joints whose axes the wrong angles turn apart, the ratio is anything (on a
    20 Hz bag 5 to 69, median 43); a run in radians has no such windows at all."""
    axes = fixture.angular_axes_enu(spline(0.5 * (t_a + t_b)))
    best = 0.0
    for s in np.arange(-MAX_LATENCY_S, MAX_LATENCY_S + 1e-12, 4e-3):
        e = _encoder_rate_magnitude(spline, axes, t_a, t_b, s)
        best = max(best, float(np.mean(np.abs(e / gyro_mag * math.pi / 180.0 - 1.0) < 0.1)))
    return best


def _encoder_rate_magnitude(spline: CubicSpline, axes: FloatArray, t_a: FloatArray,
                            t_b: FloatArray, s: float) -> FloatArray:
    """``|sum_j u_j (q_j(t_b + s) - q_j(t_a + s))| / T`` over each window, the joint axes
    ``axes`` (N, n, 3) fixed (frame-free; no rotation vector, which wraps at pi)."""
    dq = (spline(t_b + s) - spline(t_a + s)) / (t_b - t_a)[:, None]
    return np.linalg.norm(np.einsum('nj,njk->nk', dq, axes), axis=1)


#: longest step of :func:`window_rates`' sum of encoder rotations across a window: each step's
#: rotation vector misses what two joints turning at once cone over it, ~(omega dt)^2 of the
#: rate (40 ms: 5e-5 rad/s at 1 rad/s, 10 ms: 3e-6, 5 ms: 0.8e-6)
WINDOW_RATE_STEP_S = 0.005


def window_rates(fixture: Fixture, spline: CubicSpline, t_a: FloatArray, t_b: FloatArray,
                 s: float, tol_rad: float | None = None) -> FloatArray:
    """The nominal IMU frame's mean inertial rate over each window ``[t_a, t_b]`` from the
    encoders (joint stamps ``t + s``), as a gyro sums it: the rotation vectors
    ``rotvec(R_k^T R_k+1)`` of steps of at most :data:`WINDOW_RATE_STEP_S` across the
    window, over its length, plus the earth rate averaged over the steps' attitudes (at the
    window's end alone it was off by the window's turn times the earth rate: 15 ppm of a
    rate over 0.2 s at 1 rad/s, and a navigation unit's gyro scale came out 2.9 sigma off).
    One rotation vector across the whole window misses what two joints turning at once
    cone. No derivative of the encoder record (its noise would be a regressor error, and its
    variance changes with where an instant falls between joint stamps: see
    :func:`window_means`); the steps' noise cancels between them but at the window's ends.

    ``tol_rad``: a joint that stays within it over +-0.1 s of the window's middle is held still
    across the window: its encoder noise (0.4 mrad across 40 ms: 0.014 rad/s) would be a
    regressor error diluting the scale of an axis that only sees small rates (regression
    dilution: a gyro scale pulled towards zero on a one-axis plan)."""
    n_step = max(1, int(math.ceil(float(np.median(t_b - t_a)) / WINDOW_RATE_STEP_S - 1e-9))) \
        if len(t_a) else 1
    frac = np.arange(n_step + 1) / n_step
    t_k = t_a[:, None] + frac[None, :] * (t_b - t_a)[:, None] + s  # (N, n_step + 1)
    q = spline(t_k.ravel()).reshape(len(t_a), n_step + 1, -1)
    if tol_rad is not None:
        t_m = 0.5 * (t_a + t_b) + s
        still = np.abs(spline(t_m + 0.1) - spline(t_m - 0.1)) < tol_rad  # (N, joints)
        q = np.where(still[:, None, :], q[:, -1:, :], q)
    R = fixture.R_enu_imu(q.reshape(-1, q.shape[2])).reshape(len(t_a), n_step + 1, 3, 3)
    rel = np.swapaxes(R[:, :-1], 2, 3) @ R[:, 1:]
    rot = Rotation.from_matrix(rel.reshape(-1, 3, 3)).as_rotvec().reshape(len(t_a), n_step, 3)
    weight = np.full(n_step + 1, 1.0 / n_step)
    weight[[0, -1]] *= 0.5  # the trapezoid over the steps' attitudes
    earth = np.einsum('k,nkji,j->ni', weight, R, fixture.site.omega_ie_enu)
    return rot.sum(axis=1) / (t_b - t_a)[:, None] + earth  # type: ignore[no-any-return]


def encoder_rate_noise(q_joint: FloatArray, window_s: float) -> float:
    """The rms per IMU axis that the encoders' own noise (or steps: ``q / sqrt(12)``) puts on
    :func:`window_rates` over ``window_s`` (two ends, joints' noise spread over 3 axes)."""
    if len(q_joint) < 4:
        return 0.0
    sig = np.maximum(np.atleast_1d(encoder_noise_rad(q_joint)),
                     np.atleast_1d(encoder_quantum_rad(q_joint)) / math.sqrt(12.0))
    return math.sqrt(2.0 * float(np.sum(sig ** 2)) / 3.0) / window_s


LATENCY_WINDOW_S = 0.04  # rates compared as means over this many seconds (see below)
#: the gyro fit's windows (:func:`_fit_gyros`): the encoders' noise across a window is a
#: regressor error that dilutes the scale factors by its variance over the rates' (0.4 mrad
#: over 40 ms: -200 to -350 ppm on a consumer unit, 2 of the fit's sigmas), 25x less over
#: 0.2 s; the latency wants the short windows (its signal is the rates' change)
FIT_WINDOW_S = 0.2
LATENCY_ROUNDS = 6  # most rounds of the gyro fit and refine_latency at its latency


def whole_windows(t_end_s: FloatArray, dt_s: float, n_win: int, select: NDArray[np.intp]
                  ) -> tuple[FloatArray, NDArray[np.intp]]:
    """Each interval's length and the windows of ``select`` (ending at sample ``i``, ``n_win``
    intervals) that hold no gap. A sample after a gap (an interval > 1.5 nominal periods) is
    the mean over its own nominal period only (CONTRACT 1): a window mean across it would
    stand its rate in for the whole gap, off by the angular acceleration x half the gap,
    which correlates with the shift (2 % of a MEMS unit's samples dropped in bursts moved the
    latency by 0.64 ms, and the filter then gated updates through every turn). When fewer
    than half the windows are whole (a stream with a gap every few samples), all are kept:
    a biased shift then beats one from a handful of windows."""
    dtk = np.diff(t_end_s, prepend=t_end_s[0] - dt_s)
    gap = np.concatenate([[0], np.cumsum(dtk > 1.5 * dt_s)])  # gaps among intervals < k
    i = np.asarray(select, np.intp)
    i = i[i >= n_win]
    whole = i[gap[i + 1] == gap[i + 1 - n_win]]
    return dtk, whole if 2 * len(whole) >= len(i) else i


#: golden-ratio step of the window ends' sub-sample phases (:func:`window_means`)
_PHASE_STEP = 0.5 * (math.sqrt(5.0) - 1.0)


def window_means(t_end_s: FloatArray, dt_s: float, select: NDArray[np.intp],
                 *series: FloatArray, shift_rates: bool = False,
                 window_s: float = LATENCY_WINDOW_S
                 ) -> tuple[FloatArray, FloatArray, list[FloatArray]]:
    """Windows of about ``window_s`` over the IMU record for the latency and gyro
    fits: their start and end instants ``t_a``, ``t_b`` and each series' mean over
    ``[t_a, t_b]``; with ``shift_rates``, after the means, each mean's rate of change with a
    shift of the window, ``d/dh mean[t_a + h, t_b + h]`` (over ``h = +-dt/2``).

    The ends fall a sub-sample phase ``phi`` before IMU interval ends, ``phi`` spread evenly
    over [0, 1) of a period across the windows (golden-ratio sequence), and the means come
    from the cumulative integral of the interval means, interpolated by a cubic Hermite
    spline (node slopes: the neighbouring interval means). At whole interval ends the
    encoder instants ``t + s`` would sit at one phase between joint stamps in every window
    (IMU and joints on one clock at one rate), and the interpolated encoder record's noise
    depends on that phase: a term of the cost that moves with ``s`` and pulls its minimum
    (0.1 mrad of encoder noise at 100 Hz put an industrial unit's latency 3.7 ms off, 0.4 mrad
    a consumer unit's 4.2 ms). Spread evenly, the phases average that term to a constant; the
    gyro side's own interpolation noise does not depend on ``s`` at all.

    A window's ends lie inside whole intervals (:func:`whole_windows`), with one whole
    interval more on each side; ``select`` are indices of the intervals holding ``t_b``.
    """
    n_win = max(1, int(round(window_s / dt_s)))
    sel = np.asarray(select, np.intp)
    # windows ending in interval i (t_b) and starting in interval i - n_win (t_a), each end
    # +- dt/2 for the shift rates: intervals i - n_win - 1 .. i + 1 whole, i.e. the windows
    # of n_win + 3 intervals ending at i + 1 (whole_windows)
    dtk, j = whole_windows(t_end_s, dt_s, n_win + 3, sel[sel < len(t_end_s) - 1] + 1)
    i = j - 1
    nodes = np.concatenate([[t_end_s[0] - dtk[0]], t_end_s])
    # a node's slope: the mean of the intervals on both sides, one side next to a gap
    nxt_whole = np.concatenate([dtk[1:] <= 1.5 * dt_s, [False]])
    phi = (np.arange(len(i)) * _PHASE_STEP) % 1.0
    t_b = t_end_s[i] - phi * dtk[i]
    t_a = t_end_s[i - n_win] - phi * dtk[i - n_win]
    T = (t_b - t_a)[:, None]
    h = 0.5 * dt_s
    means, rates = [], []
    for x in series:
        x = np.asarray(x, dtype=float)
        c = np.vstack([np.zeros((1, x.shape[1])), np.cumsum(x * dtk[:, None], axis=0)])
        m = np.vstack([x[:1], np.where(nxt_whole[:, None],
                                       0.5 * (x + np.roll(x, -1, axis=0)), x)])

        def at(t: FloatArray) -> FloatArray:
            return _hermite_at(nodes, c, m, t)
        means.append((at(t_b) - at(t_a)) / T)
        if shift_rates:
            rates.append((at(t_b + h) - at(t_a + h) - at(t_b - h) + at(t_a - h))
                         / (2 * h * T))
    return t_a, t_b, means + rates


def _hermite_at(nodes: FloatArray, c: FloatArray, m: FloatArray, t: FloatArray
                ) -> FloatArray:
    """The cubic Hermite interpolant of values ``c`` (N, k) with slopes ``m`` at ``nodes``,
    at instants ``t`` inside them: the interval's two nodes only. By hand because scipy's
    ``CubicHermiteSpline`` builds every interval's coefficients, 440 MB and 1.2 s a call
    on a 1 kHz record of 17 minutes, where a few thousand windows are read."""
    k = np.clip(np.searchsorted(nodes, t, side='right') - 1, 0, len(nodes) - 2)
    d = (nodes[k + 1] - nodes[k])[:, None]
    u = ((t - nodes[k])[:, None]) / d
    u2, u3 = u * u, u * u * u
    return ((2 * u3 - 3 * u2 + 1) * c[k] + (u3 - 2 * u2 + u) * d * m[k]
            + (3 * u2 - 2 * u3) * c[k + 1] + (u3 - u2) * d * m[k + 1])


def measure_latency(fixture: Fixture, spline: CubicSpline, t_end_s: FloatArray, w: FloatArray,
                    bias: FloatArray, dt_s: float, select: NDArray[np.intp]
                    ) -> tuple[float, float]:
    """Shift ``s`` [s] with ``|mean w - bias| ~ |mean encoder rate|`` over the same window
    shifted by ``s`` (joint stamp = instant + ``s``), and its sigma.

    Both sides are means over the windows of :func:`window_means` (about
    :data:`LATENCY_WINDOW_S`, ends at evenly spread sub-sample phases): the gyro side from
    the integral of the interval means, the encoder side as the angle difference across the
    window, ``(q(t_b + s) - q(t_a + s)) / T``. A derivative of the interpolated encoder
    angles would not do: its noise variance changes with where ``t + s`` falls between two
    joint stamps, a term of the cost that moves its minimum (13.5 urad of encoder noise at
    100 Hz biased the shift by 1-3 ms, a milliradian of attitude at 1 rad/s); over a 40 ms
    window that term is 25x smaller than its signal, and the spread phases average it out.

    Parameters
    ----------
    t_end_s : (N,)
        End instants of every IMU interval (consecutive samples).
    w : (N, 3)
        Interval-mean rates.
    select : indices ``i`` of the windows to use, ending in interval ``i``
        (:func:`window_means`).
    """
    t_a, t_b, (wmv,) = window_means(t_end_s, dt_s, select, w - bias)
    wm = np.linalg.norm(wmv, axis=1)
    # the joint axes at the unshifted window middles: over +-60 ms they turn by a few
    # degrees at most, which changes |sum u_i dq_i| only where two joints move at once
    axes = fixture.angular_axes_enu(spline(0.5 * (t_a + t_b)))

    def cost(s: float) -> float:
        return float(np.mean((wm - _encoder_rate_magnitude(spline, axes, t_a, t_b, s)) ** 2))

    grid = np.arange(-MAX_LATENCY_S, MAX_LATENCY_S + 1e-12, 4e-3)
    cg = np.array([cost(s) for s in grid])
    s0 = float(grid[int(np.argmin(cg))])
    fine = s0 + np.arange(-4.5e-3, 4.5e-3 + 1e-12, 5e-4)
    cf = np.array([cost(s) for s in fine])
    k = int(np.clip(np.argmin(cf), 1, len(fine) - 2))
    a, b, cc = cf[k - 1], cf[k], cf[k + 1]
    h = fine[1] - fine[0]
    den = a - 2 * b + cc
    s = float(fine[k] + (0.5 * h * (a - cc) / den if den > 0 else 0.0))
    # sigma from the curvature of the cost: sigma^2 = 2 var(resid) / (N d2cost/ds2)
    curv = den / h ** 2 if den > 0 else 0.0
    # (x10: the residuals are correlated over many samples)
    sig = 10 * math.sqrt(2 * b / (len(t_a) * curv)) if curv > 0 else MAX_LATENCY_S
    return s, sig


#: weak prior of the gyro fit for an uncalibrated unit, beta = (B_i (3), ag_i, G_i (3), bg_i):
#: the raw-unit priors of the estimator (B = I + Kg: scale and misalignment, both 3 %)
_RAW = {g.name: float(g.raw_prior or 0.0) for g in registry.SENSOR_GROUPS}
GYRO_FIT_SD0 = np.array([*[_RAW['gyro_scale']] * 3, _RAW['gyro_asymmetry'],
                         *[_RAW['gyro_g_sensitivity']] * 3, _RAW['gyro_bias']])


def _fit_gyros(fixture: Any, spline: CubicSpline, win: tuple[FloatArray, ...], s: float,
               block: NDArray[np.intp], noise_g: float, tol_rad: float
               ) -> tuple[FloatArray, list[tuple[FloatArray, FloatArray]]]:
    """Per gyro axis ``w_i = B_i . w_nom + ag_i |w_i| + G_i . f + bg_i`` over the windows
    ``win = (t_a, t_b, w mean, f mean)`` of :func:`window_means` at the joint-stamp latency
    ``s``: ``B`` and each axis' (beta, var) of :func:`_cluster_lstsq`, beta = (B_i (3), ag_i,
    G_i (3), bg_i)."""
    t_a, t_b, wm, fm = win
    w_nom = window_rates(fixture, spline, t_a, t_b, s, tol_rad)
    n = len(t_a)
    X = np.hstack([w_nom, np.zeros((n, 1)), fm, np.ones((n, 1))])
    B = np.zeros((3, 3))
    s2_floor = noise_g ** 2 / float(np.median(t_b - t_a))  # a window mean's white noise
    # two rounds: the asymmetry regressor |omega_i| is the body rate the previous round
    # predicts (B w_nom), never the measured |w_i| (the target itself: with one rotation
    # direction it took half the scale factor)
    fits: list[tuple[FloatArray, FloatArray]] = []
    for _ in range(2):
        fits = []
        for i in range(3):
            X[:, 3] = np.abs(w_nom @ B[i]) if B.any() else np.abs(w_nom[:, i])
            beta0 = np.zeros(8)
            beta0[i] = 1.0
            fits.append(_cluster_lstsq(X, wm[:, i], block, beta0, GYRO_FIT_SD0, s2_floor))
        B = np.array([f_[0][0:3] for f_ in fits])
    return B, fits


def _gyro_model(B: FloatArray, fits: list[tuple[FloatArray, FloatArray]]
                ) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """(B, asymmetry (3,), G (3, 3), bias (3,)) of a gyro fit."""
    beta = np.array([f_[0] for f_ in fits])
    return B, beta[:, 3], beta[:, 4:7], beta[:, 7]


def refine_latency(fixture: Any, spline: CubicSpline, t_end_s: FloatArray, w: FloatArray,
                   f: FloatArray, dt_s: float, select: NDArray[np.intp], s0: float,
                   model: tuple[FloatArray, FloatArray, FloatArray, FloatArray],
                   iterations: int = 4) -> tuple[float, float]:
    """The joint-stamp latency ``s`` from the whole rate vector: Gauss-Newton on the shift of
    the encoder record that best explains the 40 ms window means of the gyros through the
    fitted gyro ``model`` (``B``, asymmetry, ``G``, bias). Returns ``(s, sigma)``; sigma is
    cluster-robust over 1 s blocks (model error and encoder interpolation are not white).

    Each window's nominal mean body rate is :func:`window_rates` (the encoder rotation
    across it, no derivative of the encoder record), plus the earth rate."""
    t_a, t_b, (wm, fm, Z, _) = window_means(t_end_s, dt_s, select, w, f, shift_rates=True)
    if len(t_a) < 50:
        return s0, math.inf
    B, asym, G, bias = model

    def pred(s: float) -> FloatArray:
        bw = window_rates(fixture, spline, t_a, t_b, s) @ B.T
        return bw + asym * np.abs(bw) + fm @ G.T + bias  # type: ignore[no-any-return]

    # Gauss-Newton with an instrument: the Jacobian of pred is the encoder record's
    # derivative, whose noise (0.4 mrad at 100 Hz: several rad/s^2 against a plan's ~1) both
    # shrank every step (the fixed point with the gyro fit then crept, 0.1 ms a round) and
    # the sigma; the gyros' own rate of change over a shifted window, Z, is what pred's
    # Jacobian is without that noise (the gyros' noise in it is independent of the encoders')
    h = 1e-3
    s = s0
    zj = 0.0
    for _ in range(iterations):
        p = pred(s)
        J = (pred(s + h) - pred(s - h)) / (2 * h)
        zj = float(np.sum(Z * J))
        if not zj > 0:
            return s0, math.inf
        step = float(np.sum(Z * (wm - p))) / zj
        s += step
        if abs(step) < 1e-7:
            break
    r = wm - pred(s)
    block = ((t_b - t_b[0]) // BLOCK_S).astype(np.intp)
    g = np.zeros(int(block.max()) + 1)
    np.add.at(g, block, np.sum(Z * r, axis=1))
    var = max(float(np.sum(g ** 2)), float(np.mean(r ** 2)) * float(np.sum(Z * Z))) / zj ** 2
    return s, math.sqrt(var)


def _cluster_lstsq(X: FloatArray, y: FloatArray, block: NDArray[np.intp], beta0: FloatArray,
                   sd0: FloatArray, s2_floor: float) -> tuple[FloatArray, FloatArray]:
    """Least squares with a weak Gaussian prior (``beta0``, ``sd0``: what an uncalibrated unit
    may be, so that directions the data do not excite keep the prior instead of a singular
    solve) and a cluster-robust (sandwich) covariance over blocks of samples."""
    # the prior as extra rows of an augmented least squares, solved by SVD (the normal
    # equations square a condition number of ~1e9: collinear columns under a tiny noise);
    # the data rows enter through the R factor of QR([X y]) (8 rows instead of N)
    Ry: FloatArray = np.linalg.qr(np.column_stack([X, y]), mode='r')  # type: ignore[assignment]
    n_p = X.shape[1]
    R, qty = Ry[:n_p, :n_p], Ry[:n_p, n_p]
    rss0 = float(Ry[n_p, n_p] ** 2) if Ry.shape[0] > n_p else 0.0
    prior_rows = np.diag(1.0 / sd0)
    s2 = s2_floor
    for _ in range(2):  # the residual variance, then the solution with it
        sig = math.sqrt(s2)
        beta, *_ = np.linalg.lstsq(np.vstack([R / sig, prior_rows]),
                                   np.concatenate([qty / sig, beta0 / sd0]), rcond=None)
        rss = float(np.sum((qty - R @ beta) ** 2)) + rss0
        s2 = max(rss / max(len(y) - n_p, 1), s2_floor)
    _, sv, Vt = np.linalg.svd(np.vstack([R / math.sqrt(s2), prior_rows]), full_matrices=False)
    M_inv = (Vt.T / sv ** 2) @ Vt
    r = y - X @ beta
    sums = np.zeros((int(block.max()) + 1, n_p))
    np.add.at(sums, block, X * r[:, None])  # sum over clusters of X_b^T r_b
    cov = M_inv @ (sums.T @ sums / s2 ** 2 + np.diag(1.0 / sd0 ** 2)) @ M_inv
    var = np.maximum(np.diag(cov), np.diag(M_inv))
    # what the data left at the weak prior is not measured: its prior mean, sigma inf (the
    # caller's prior: the grade hint or the raw-unit table)
    unmeasured = var > (0.5 * sd0) ** 2
    return np.where(unmeasured, beta0, beta), np.where(unmeasured, np.inf, var)


#: joint states closer than this are averaged in groups before the spline
#: (:func:`thin_joint_states`)
JOINT_BIN_S = 0.01
#: joint stamps that scatter (taken on receipt, not put back on the sender's clock): groups
#: long enough that their mean stamps' scatter is at most this share of a rate over one
#: group, up to JOINT_BIN_MAX_S
JOINT_RATE_TIMING_SHARE = 0.005
JOINT_BIN_MAX_S = 0.1


def timing_group_size(dt_s: float, timing_sigma_s: float) -> int:
    """States per group (:func:`thin_joint_states`) for joint stamps that scatter by
    ``timing_sigma_s`` about their instants at a period ``dt_s``: the least ``k`` whose group
    rate's timing error ``sqrt(2) sigma / (k^1.5 dt)`` is :data:`JOINT_RATE_TIMING_SHARE` of
    itself, at most :data:`JOINT_BIN_MAX_S` of states; 1 for exact stamps."""
    if not timing_sigma_s > 0.0 or not dt_s > 0.0:
        return 1
    k_t = (math.sqrt(2.0) * timing_sigma_s / (JOINT_RATE_TIMING_SHARE * dt_s)) ** (2 / 3)
    return max(1, min(int(math.ceil(k_t)), int(JOINT_BIN_MAX_S / dt_s)))


def thin_joint_states(t_ns: NDArray[np.int64], q: FloatArray, bin_s: float = JOINT_BIN_S,
                      timing_sigma_s: float = 0.0) -> tuple[NDArray[np.int64], FloatArray]:
    """Joint states faster than ``1 / bin_s`` averaged in groups of ``k`` consecutive
    states (stamps and angles alike), ``k`` the nearest whole number of periods per bin.

    The coarse start differentiates a cubic spline through the encoder angles; its noise
    grows with the joint rate (``sigma_q / dt``): 20 urad at 1 kHz is 0.03 rad/s of rate
    noise, which diluted the regressors and failed the "the gyro rates do not follow the
    fixture" check on a navigation unit. The mean of ``k`` states is the angle at their mean
    stamp to ``qdd dt^2 k^2 / 24`` (0.4 urad at 1 rad/s^2 over 10 ms) with ``1/sqrt(k)`` of
    the noise; at 100 Hz and below nothing changes.

    ``timing_sigma_s``: the scatter of the stamps about their instants (stamps taken on
    receipt that the joint clock could not put back: :attr:`~..stamp_clock.StampClock.
    timing_sigma_ns`). A group's mean stamp scatters by ``sigma / sqrt(k)``, a rate over
    ``k dt`` by ``sqrt(2) sigma / (k^1.5 dt)`` of itself: groups of at least
    ``(sqrt(2) sigma / (share dt))^(2/3)`` states (:data:`JOINT_RATE_TIMING_SHARE`, up to
    :data:`JOINT_BIN_MAX_S`): 1 kHz joint states 0-4.8 ms late left 3 % of the rates
    unexplained in 10 ms groups, and the plain command refused the fixture."""
    if len(t_ns) < 4:
        return t_ns, q
    dt = float(np.median(np.diff(t_ns))) * 1e-9
    k = int(round(bin_s / dt)) if dt > 0 else 1
    k = max(k, timing_group_size(dt, timing_sigma_s))
    if k < 2:
        return t_ns, q
    m = len(t_ns) // k
    t0 = int(t_ns[0])
    tb = (t_ns[:m * k] - t0).reshape(m, k).mean(axis=1)
    qb = q[:m * k].reshape(m, k, -1).mean(axis=1)
    return (np.round(tb).astype(np.int64) + t0), qb


#: the accelerometer window fit's weak prior per axis: matrix row (3 %), asymmetry (0.3 %),
#: bias (1 m/s^2), in :func:`_fit_accels` and :func:`fit_joint_zeros`
ACCEL_FIT_PRIOR_SD = np.array([3e-2, 3e-2, 3e-2, 3e-3, 1.0])
#: a start is determined only once the stationary windows put at least this share of gravity
#: along every IMU direction (within 60 deg of vertical: :func:`least_reach`); the self-check's
#: plan check uses the same share (``SelfCheckConfig.min_accel_reach``). Before that the few
#: per cent of gravity along an unreached direction weigh the nominal direction's errors
#: (encoder zeros, the mounting), not the accelerometers' response to it: a navigation unit
#: whose y axis had stayed horizontal for four windows, 0.03 m/s^2 of gravity along it from
#: 3 mrad encoder zeros, fitted a y scale of -104 % with a sigma of 0.04 %
MIN_ACCEL_REACH = 0.5


def _sphere(n: int = 4000) -> FloatArray:
    """``n`` unit vectors spread evenly over the upper half sphere (a Fibonacci lattice;
    ``v`` and ``-v`` have the same reach): 1.6 deg apart, 0.03 of reach near the threshold."""
    k = np.arange(n) + 0.5
    z = k / n
    phi = k * math.pi * (3.0 - math.sqrt(5.0))
    r = np.sqrt(1.0 - z * z)
    return np.column_stack([r * np.cos(phi), r * np.sin(phi), z])


_SPHERE = _sphere()


def least_reach(directions: FloatArray) -> tuple[float, FloatArray]:
    """``(reach, v)``: the IMU direction ``v`` (unit, (3,)) the windows' gravity directions
    (K, 3, any length) came least near, and the largest share of gravity along it, ``max_k
    |u_k . v|`` (1: stood up or down, 0: always horizontal). A table can leave a direction
    that is no axis unreached: a two-axis table with a vertical outer and a horizontal inner
    axis never stands its inner axis up, and an IMU mounted at 45 deg to it has every axis
    within 45 deg of vertical at some pose while the accelerometers' response along the inner
    axis is never seen (its scale and misalignment pair ended 13 sigma off, the self-check
    passing). ``(1.0, zeros)`` without windows. Searched on a lattice (:func:`_sphere`), then
    refined by a local search: no library minimises a max over a sphere."""
    u = np.asarray(directions, float).reshape(-1, 3)
    if not len(u):
        return 1.0, np.zeros(3)
    u = u / np.maximum(np.linalg.norm(u, axis=1), 1e-12)[:, None]
    reach = np.max(np.abs(u @ _SPHERE.T), axis=0)
    v = _SPHERE[int(np.argmin(reach))]
    best = float(np.min(reach))
    step = 0.03
    for _ in range(40):  # pattern search on the sphere around the lattice's best
        cand = v + step * np.vstack([np.eye(3), -np.eye(3)])
        cand /= np.linalg.norm(cand, axis=1)[:, None]
        r = np.max(np.abs(u @ cand.T), axis=0)
        j = int(np.argmin(r))
        if r[j] < best:
            best, v = float(r[j]), cand[j]
        else:
            step *= 0.5
    return best, v


def _fit_accels(fixture: Any, wins: list[StaticWindow], noise_a: float, dt: float
                ) -> tuple[FloatArray, list[tuple[FloatArray, FloatArray]]]:
    """The accelerometer fit on the window means, ``f = A g_nom + aa |f| + ba`` per axis:
    ``(A, [(beta, var) of each axis])`` (:func:`_cluster_lstsq`; beta = A row, aa, ba)."""
    g = fixture.site.gravity
    qw = np.array([win.q_rad for win in wins])
    g_nom = np.einsum('nki,k->ni', fixture.R_enu_imu(qw), np.array([0.0, 0.0, g]))
    fm = np.array([win.accel_mean_m_s2 for win in wins])
    nw = np.array([win.n for win in wins], float)
    A = np.zeros((3, 3))
    fits: list[tuple[FloatArray, FloatArray]] = []
    # window means weighted by their white noise; a weak prior (A = I +- 3 %, asymmetry
    # 0.3 %, bias 100 mg) keeps what the windows do not separate (with only the six
    # axis-up/down poses |f_i| is collinear with bias and scale: then the asymmetry stays
    # unmeasured); the quadratic term is left to the filter
    sd0 = ACCEL_FIT_PRIOR_SD
    rw = np.sqrt(nw)[:, None]  # rows of equal variance noise^2 / dt
    Xa = np.hstack([g_nom, np.zeros((len(wins), 1)), np.ones((len(wins), 1))])
    for _ in range(2):  # |f_i| regressor from the previous round's prediction
        fits = []
        for i in range(3):
            Xa[:, 3] = np.abs(g_nom @ A[i]) if A.any() else np.abs(g_nom[:, i])
            beta0 = np.zeros(5)
            beta0[i] = 1.0
            fits.append(_cluster_lstsq(Xa * rw, fm[:, i] * rw[:, 0], np.arange(len(wins)),
                                       beta0, sd0, noise_a ** 2 / dt))
        A = np.array([f_[0][0:3] for f_ in fits])
    return A, fits


def _accels_pinned(fits: list[tuple[FloatArray, FloatArray]], accel_limit: float) -> bool:
    """Whether the accelerometer fit leaves the scale and misalignment sigmas below
    ``accel_limit``: necessary for :meth:`CoarseStart.determined` (the misalignment's sigma
    adds the mounting's to these)."""
    return bool(max(float(np.max(np.sqrt(var[0:3]))) for _, var in fits) < accel_limit)


#: prior sigma of a table's encoder zero [rad] in :func:`fit_joint_zeros` (lab tables'
#: zero references: a fraction of a degree)
JOINT_ZERO_PRIOR_RAD = 0.01
#: a zero is applied when its fit stands out by this many sigmas (else it stays 0)
JOINT_ZERO_SIGNIFICANCE = 3.0
#: prior sigma of a table base's tilt from level [rad] (a desk or a bench: up to a degree
#: or two; a levelled rate table: arc seconds), in :func:`fit_joint_zeros`
BASE_TILT_PRIOR_RAD = 0.05


def fit_joint_zeros(fixture: Any, wins: list[StaticWindow], noise_a: float, dt: float,
                    rounds: int = 8
                    ) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """A turntable's encoder zeros and its base's tilt from the stationary windows'
    gravity: ``(zero (n,), sigma (n,), tilt (2,), sigma (2,))`` [rad], 0 and inf where not
    fitted (gravity does not show them), 0 and the prior sigma on fewer than six windows
    (not known yet). The tilt is the base's rotation vector ``(t_e, t_n)`` about ENU east
    and north (:meth:`~imu_calib_ros.core.fixture.Fixture.with_base_tilt`): a zero error
    of an axis fixed in ENU, fitted the same way (``u = e_e, e_n``). A table 0.1 deg off
    level moves gravity by 1.7 mg along directions that turn with the outer axis; a MEMS
    unit's encoder attitude aiding then fought its navigation (76 re-alignments, refused;
    at 0.6 deg it diverged), where a navigation unit's filter, which uses the encoders only
    for its windows, did not mind.

    The joint is at ``q + z`` when its encoder reads ``q``; a zero error of a joint before
    the last turns everything after it about the joint's axis, ``R(q + z_j e_j) = Rot(u_j z_j)
    R(q)``, so gravity in the IMU frame moves by ``R^T [g x] u_j z_j`` at each window. The
    last joint's zero is a mounting rotation and the outer (vertical) one's a heading,
    which gravity does not see; between them (a three-axis table's middle joint) the
    direction changes with the inner angle, which the accelerometers' constant matrix cannot
    absorb. Gauss-Newton on ``f = A g_nom(q + z) + aa |A g_nom| + ba`` per window, jointly in
    ``A`` (3 x 3), ``aa``, ``ba`` and ``z`` with the accelerometer fit's weak priors
    (:func:`_fit_accels`) and ``JOINT_ZERO_PRIOR_RAD``, so the zeros' sigmas are marginal
    over the accelerometer errors; a zero is kept where it stands out by
    ``JOINT_ZERO_SIGNIFICANCE`` sigmas. Without it a navigation unit on a table whose zeros
    were off (4, 3, -2 mrad) started from fits bent by them, and its first outer-axis turn
    gated its updates (the run refused, every value right).
    """
    n = fixture.n_joints
    zero, sig = np.zeros(n), np.full(n, np.inf)
    tilt, tilt_sig = np.zeros(2), np.full(2, np.inf)
    joints = list(em.nuisance_offset_joints(fixture))
    if not getattr(fixture, 'concurrent', False):
        return zero, sig, tilt, tilt_sig
    if len(wins) < 6:
        # too few windows to tell: the zeros are as unknown as their prior, so a start on
        # these windows is not determined (a tactical unit's start taken on three windows,
        # the table's zeros 4.4 and -2.2 mrad not fitted, bent the fits; every move through
        # the middle joint then gated the updates, 4 re-alignments, refused)
        sig[joints] = JOINT_ZERO_PRIOR_RAD
        return zero, sig, tilt, np.full(2, BASE_TILT_PRIOR_RAD)
    # the tilt's axes: east and north, but not about the first joint's axis when that is
    # horizontal (a rotation about it is that joint's zero, or the mounting of a one-joint
    # table): then the one horizontal axis across it (the zero and the tilt about one axis
    # cancelled each other's significance on a table whose outer axis points north, and
    # neither was applied: accel_scale 5.2 sigma off)
    u1 = fixture.joint_axes_enu(np.zeros(n))[0]
    h = np.array([u1[0], u1[1], 0.0])
    if np.linalg.norm(h) < 0.1:
        axes_t = np.eye(3)[:2]
    else:
        axes_t = np.cross([0.0, 0.0, 1.0], h / np.linalg.norm(h))[None, :]
    n_t = len(axes_t)
    m = len(joints) + n_t  # the zeros, then the tilt's angles
    tilt_axes = np.broadcast_to(axes_t, (len(wins), n_t, 3))
    g_enu = np.array([0.0, 0.0, fixture.site.gravity])
    qw = np.array([win.q_rad for win in wins])
    fm = np.array([win.accel_mean_m_s2 for win in wins])
    K = len(wins)
    rw = np.sqrt(np.array([win.n for win in wins], float)) / (noise_a / math.sqrt(dt))
    # parameters: A (row-major, 9), aa (3), ba (3), z (m); priors as _fit_accels' and the zeros'
    p = np.concatenate([np.eye(3).ravel(), np.zeros(6 + m)])
    p0 = p.copy()
    a_sd = ACCEL_FIT_PRIOR_SD
    sd = np.concatenate([np.tile(a_sd[0:3], 3), np.full(3, a_sd[3]), np.full(3, a_sd[4]),
                         np.full(m - n_t, JOINT_ZERO_PRIOR_RAD),
                         np.full(n_t, BASE_TILT_PRIOR_RAD)])
    cov = np.diag(sd ** 2)
    for _ in range(rounds):
        A, aa, ba, z = p[:9].reshape(3, 3), p[9:12], p[12:15], p[15:]
        qz = qw.copy()
        qz[:, joints] += z[:len(joints)]
        fx = fixture.with_base_tilt((z[len(joints):] @ axes_t)[:2])
        R = fx.R_enu_imu(qz)
        g_nom = np.einsum('kji,j->ki', R, g_enu)
        g_a = g_nom @ A.T
        r = (fm - (g_a + aa * np.abs(g_a) + ba)) * rw[:, None]  # (K, 3)
        J = np.zeros((K, 3, 15 + m))
        for i in range(3):
            J[:, i, 3 * i:3 * i + 3] = g_nom * (1.0 + aa[i] * np.sign(g_a[:, i]))[:, None]
            J[:, i, 9 + i] = np.abs(g_a[:, i])
            J[:, i, 12 + i] = 1.0
        u = np.concatenate([fx.joint_axes_enu(qz)[:, joints], tilt_axes], axis=1)  # (K, m, 3)
        d = np.einsum('kji,jl,kml->kim', R, skew(g_enu), u)  # d g_nom / d z
        J[:, :, 15:] = np.einsum('ab,kbm->kam', A, d) * (1.0 + aa * np.sign(g_a))[:, :, None]
        J *= rw[:, None, None]
        Jm = J.reshape(3 * K, -1)
        info = Jm.T @ Jm + np.diag(sd ** -2.0)
        cov = np.linalg.inv(info)
        step = cov @ (Jm.T @ r.reshape(-1) - (p - p0) / sd ** 2)
        p = p + step
        if np.all(np.abs(step[15:]) < 1e-8):
            break
    z, s_z = p[15:], np.sqrt(np.diag(cov)[15:])
    s_z = np.where(s_z > 0.9 * sd[15:], np.inf, s_z)  # gravity does not show it
    keep = np.abs(z) > JOINT_ZERO_SIGNIFICANCE * s_z
    k = len(joints)
    zero[joints] = np.where(keep, z, 0.0)[:k]
    sig[joints] = s_z[:k]
    tilt = (np.where(keep, z, 0.0)[k:] @ axes_t)[:2]
    # the sigma along east and north of the axes fitted; inf along one not fitted
    tilt_sig = np.array([min((s_z[k + i] / abs(axes_t[i, c]) for i in range(n_t)
                              if abs(axes_t[i, c]) > 0.5), default=np.inf) for c in range(2)])
    return zero, sig, tilt, tilt_sig


class _ZerosMisled(ValueError):
    """The fitted encoder zeros left the start implausible."""


def coarse_start(t_imu_ns: NDArray[np.int64], w: FloatArray, f: FloatArray,
                 t_joint_ns: NDArray[np.int64], q_joint: FloatArray, fixture: Fixture,
                 min_static_s: float = 1.0, tol_rad: float = 1e-4,
                 max_samples: int = 60_000, only_determined: bool = False,
                 point_samples: bool = False, joint_timing_sigma_s: float = 0.0
                 ) -> CoarseStart | None:
    """The start point (:func:`_coarse_start`), with a table's encoder zeros fitted first
    (:func:`fit_joint_zeros`); when the start with them is implausible or contradicts the
    data (a fixture error the zeros tried to explain: a 0.3 deg tilted axis fitted as a
    7 mrad zero, then an accelerometer scale of -85 %), the start without them, whose own
    checks name what is wrong."""
    args = (t_imu_ns, w, f, t_joint_ns, q_joint, fixture, min_static_s, tol_rad, max_samples,
            only_determined, point_samples)
    applied: list[bool] = []  # set by _coarse_start when it applied fitted zeros
    try:
        return _coarse_start(*args, joint_zeros=True, zeros_applied=applied,
                             joint_timing_sigma_s=joint_timing_sigma_s)
    except NoRotation:
        raise
    except (ValueError, np.linalg.LinAlgError):
        if not applied:  # the same start without zeros: the same error
            raise
        return _coarse_start(*args, joint_zeros=False, joint_timing_sigma_s=joint_timing_sigma_s)


def _coarse_start(t_imu_ns: NDArray[np.int64], w: FloatArray, f: FloatArray,
                  t_joint_ns: NDArray[np.int64], q_joint: FloatArray, fixture: Fixture,
                  min_static_s: float = 1.0, tol_rad: float = 1e-4,
                  max_samples: int = 60_000, only_determined: bool = False,
                  point_samples: bool = False, joint_zeros: bool = True,
                  zeros_applied: list[bool] | None = None, joint_timing_sigma_s: float = 0.0
                  ) -> CoarseStart | None:
    """The start point from interval-mean IMU samples and (unwrapped) joint states.

    ``only_determined``: None, before the gyro fits, when the accelerometer fit already shows
    that the start cannot be :meth:`~CoarseStart.determined` (the bootstrap's checks on too
    little data: the gyro fits cost ~0.3 s on 200 s of 200 Hz, the window fit milliseconds).

    Parameters
    ----------
    t_imu_ns, w, f
        IMU stamps (strictly increasing), mean rates [rad/s], mean specific forces [m/s^2].
    t_joint_ns, q_joint
        Joint stamps (strictly increasing) and unwrapped positions (M, n) in fixture order.
    fixture
        The nominal fixture (:class:`~imu_calib_ros.core.fixture.Fixture`).
    """
    notes: list[str] = []
    t0 = int(t_imu_ns[0])
    dt = float(np.median(np.diff(t_imu_ns))) * 1e-9
    ts = (t_imu_ns - t0).astype(np.float64) * 1e-9
    tj_ns, qj = thin_joint_states(t_joint_ns, q_joint, timing_sigma_s=joint_timing_sigma_s)
    tj = (tj_ns - t0).astype(np.float64) * 1e-9
    spline = CubicSpline(tj, qj, axis=0)
    wins = static_windows(t_joint_ns, q_joint, t_imu_ns, w, f, min_static_s, tol_rad)
    # --- noise (item 2): every window, Allan deviation at the sample period
    n_g, n_a = [], []
    for win in wins:
        k0, k1 = np.searchsorted(t_imu_ns, [win.t0_ns, win.t1_ns])
        if k1 - k0 >= 20:
            n_g.append(white_noise_density(w[k0:k1], dt, point_samples))
            n_a.append(white_noise_density(f[k0:k1], dt, point_samples))
    if n_g:
        noise_g, noise_a = float(np.median(n_g)), float(np.median(n_a))
    else:
        k = min(len(w), 2000)
        noise_g, noise_a = (white_noise_density(w[:k], dt, point_samples),
                            white_noise_density(f[:k], dt, point_samples))
        notes.append('no stationary window: noise from the first samples (motion included)')
    # --- a table's encoder zeros, from the windows' gravity: the joints from here on are at
    # q + zero (the fits below, and the filter's joint record)
    zero, zero_sig = np.zeros(fixture.n_joints), np.full(fixture.n_joints, np.inf)
    tilt, tilt_sig = np.zeros(2), np.full(2, np.inf)
    if joint_zeros:
        with contextlib.suppress(ValueError, np.linalg.LinAlgError):  # then none, as without
            zero, zero_sig, tilt, tilt_sig = fit_joint_zeros(fixture, wins, noise_a, dt)
    if (np.any(tilt) or np.any(zero)) and zeros_applied is not None:
        zeros_applied.append(True)
    if np.any(tilt):  # the fits below on the base as it stands
        fixture = fixture.with_base_tilt(tilt)
        notes.append('the table\'s base tilted from level (windows\' gravity): '
                     f'{np.linalg.norm(tilt) * 1e3:.3f} mrad, east {tilt[0] * 1e3:+.3f} +- '
                     f'{tilt_sig[0] * 1e3:.3f}, north {tilt[1] * 1e3:+.3f} +- '
                     f'{tilt_sig[1] * 1e3:.3f} mrad')
    if np.any(zero):
        qj = qj + zero
        spline = CubicSpline(tj, qj, axis=0)
        wins = [dataclasses.replace(win, q_rad=win.q_rad + zero) for win in wins]
        notes.append('encoder zeros from the windows\' gravity: ' + ', '.join(
            f'{fixture.joint_names[j]} {zero[j] * 1e3:+.3f} +- {zero_sig[j] * 1e3:.3f} mrad'
            for j in np.flatnonzero(zero)))
    # --- samples used by the regressions: inside the joint record, thinned if very many
    # (the gyro fit's windows start a window and a sample before theirs)
    inside = ((ts - 2 * dt - FIT_WINDOW_S > tj[0] + MAX_LATENCY_S)
              & (ts < tj[-1] - MAX_LATENCY_S))
    idx = np.nonzero(inside)[0]
    if len(idx) > max_samples:
        idx = idx[np.linspace(0, len(idx) - 1, max_samples).astype(np.intp)]
    wi = w[idx]
    bias0 = np.median([win.gyro_mean_rad_s for win in wins], axis=0) if wins \
        else np.zeros(3)
    # --- time offset (item 4)
    moving = np.linalg.norm(wi - bias0, axis=1) > max(20 * noise_g / math.sqrt(dt), 1e-3)
    if moving.sum() <= 50:
        raise NoRotation('no rotation in the data: nothing to calibrate the gyros from')
    # the accelerometers need only the windows: a caller that takes only a determined start
    # stops here when they already show it is not
    accel_fit = _fit_accels(fixture, wins, noise_a, dt) if only_determined and wins else None
    # ENU up in IMU axes at each window: row 2 of R_enu_imu
    reach = least_reach(fixture.R_enu_imu(np.array([win.q_rad for win in wins]))[:, 2])[0] \
        if wins else 0.0
    if only_determined and (accel_fit is None or not _accels_pinned(accel_fit[1], ACCEL_LIMIT)
                            or reach < MIN_ACCEL_REACH):
        return None
    mv = idx[np.nonzero(moving)[0]]
    mv = mv[np.linspace(0, len(mv) - 1, min(len(mv), 10_000)).astype(np.intp)]
    s, s_sig = measure_latency(fixture, spline, ts, w, bias0, dt, mv)
    # --- gyros (item 2): w_i = B_i . w_nom + ag_i |w_i| + G_i . f + bg_i, at the latency
    # the rate magnitudes gave; then the latency again from the whole rate vector through
    # that fit (refine_latency: the magnitudes are blind to what the scale factors and the
    # asymmetry do to them, 1.7 +- 1.6 ms off on a tactical unit turned at 60 deg/s), and
    # the gyros once more at the refined latency
    # the gyro fit on windows of FIT_WINDOW_S, one after another (window_means,
    # window_rates: no derivative of the encoder record, whose noise would be a regressor
    # error that moves with the latency); each one's white noise is the gyros' over its
    # length, independent of the next (windows ending at every sample overlapped 20-200
    # times, and the fit's information read that many times too high)
    n_fit = max(1, int(round(FIT_WINDOW_S / dt)))
    fit_sel = np.nonzero(inside)[0][::n_fit]
    if len(fit_sel) > max_samples:
        fit_sel = fit_sel[np.linspace(0, len(fit_sel) - 1, max_samples).astype(np.intp)]
    t_a, t_b, (wm, fm) = window_means(ts, dt, fit_sel, w, f, window_s=FIT_WINDOW_S)
    fit_win = (t_a, t_b, wm, fm)
    block = ((t_b - t_b[0]) // BLOCK_S).astype(np.intp)
    # the fixed point of "fit the gyros at s, refine s through that fit": a fit at a latency
    # far off (14 ms on a plan of quick 90 deg moves) is itself distorted, and one refinement
    # goes only part of the way (to 4.4 ms; each further round removes ~60 %), so the fixed
    # point is found by the secant method on g(s) = F(s) - s
    def F(x: float) -> tuple[float, float]:
        B_, fits_ = _fit_gyros(fixture, spline, fit_win, x, block, noise_g, tol_rad)
        return refine_latency(fixture, spline, ts, w, f, dt, mv, x, _gyro_model(B_, fits_))

    x0, g0 = s, 0.0
    x1 = s
    r, r_sig = F(x1)
    if math.isfinite(r_sig) and abs(r) < MAX_LATENCY_S:
        for k in range(LATENCY_ROUNDS):
            g1 = r - x1
            if abs(g1) < max(0.1 * r_sig, 1e-6):
                break
            # the first step is the plain fixed-point one, then secant steps
            x2 = r if k == 0 or g1 == g0 else x1 - g1 * (x1 - x0) / (g1 - g0)
            x2 = float(np.clip(x2, -MAX_LATENCY_S, MAX_LATENCY_S))
            r2, r2_sig = F(x2)
            if not (math.isfinite(r2_sig) and abs(r2) < MAX_LATENCY_S):
                break
            x0, g0 = x1, g1
            x1, r, r_sig = x2, r2, r2_sig
        s, s_sig = r, r_sig
    B, fits = _fit_gyros(fixture, spline, fit_win, s, block, noise_g, tol_rad)
    latency = s  # joint stamp = instant + latency
    w_nom = window_rates(fixture, spline, t_a, t_b, latency, tol_rad)
    theta_g = np.zeros(em.N_GYRO)
    sig_g = np.full(em.N_GYRO, np.inf)
    sB = np.zeros((3, 3))
    for i, (beta, var) in enumerate(fits):
        sd = np.sqrt(var)
        B[i] = beta[0:3]
        sB[i] = sd[0:3]
        theta_g[em.gyro_cols('gyro_asymmetry').start + i] = beta[3]
        sig_g[em.gyro_cols('gyro_asymmetry').start + i] = sd[3]
        c = em.gyro_cols('gyro_g_sensitivity').start + 3 * i
        theta_g[c:c + 3] = beta[4:7]
        sig_g[c:c + 3] = sd[4:7]
        theta_g[em.gyro_cols('gyro_bias').start + i] = beta[7]
        sig_g[em.gyro_cols('gyro_bias').start + i] = sd[7]
    # the fit must explain the rotations: a residual far above the white noise, above the
    # encoders' own noise over a window and above 2 % of the rates means the fixture (axes,
    # joint order) does not describe this table
    _, asym_g, G_g, bias_g = _gyro_model(B, fits)
    bw = w_nom @ B.T
    resid = wm - (bw + asym_g * np.abs(bw) + fm @ G_g.T + bias_g)
    mov_w = np.linalg.norm(wm - bias0, axis=1) > max(20 * noise_g / math.sqrt(dt), 1e-3)
    rms = float(np.sqrt(np.mean(resid[mov_w] ** 2))) if mov_w.any() else 0.0
    rate_rms = float(np.sqrt(np.mean(wm[mov_w] ** 2))) if mov_w.any() else 0.0
    base = max(20 * noise_g / math.sqrt(dt), 0.02 * rate_rms)
    # (the encoders' noise read off the whole joint record only when the rest is exceeded)
    if rms > base and rms > base + 3 * encoder_rate_noise(q_joint, float(np.median(t_b - t_a))):
        share = _degrees_share(fixture, spline, t_a[mov_w], t_b[mov_w],
                               np.linalg.norm(wm[mov_w] - bias0, axis=1))
        if share >= DEGREES_SHARE:  # frame-free, as the guard's deg/s test
            raise ValueError(f'the joint positions look like degrees, not radians (the encoder '
                             f'rates are 57.3 times the gyro rates in {100 * share:.0f} % of '
                             'the turns): publish JointState positions in rad')
        raise ValueError(f'the gyro rates do not follow the fixture\'s joint rotations '
                         f'({rms:.3g} rad/s rms left after the best linear fit, '
                         f'{100 * rms / rate_rms:.0f} % of the rates): check the fixture file\'s '
                         f'joint axes and names against the table{_coarse_encoders(q_joint)}')
    if np.linalg.det(B) <= 0 or not np.all(np.isfinite(B)):
        raise ValueError('the gyro outputs do not follow the encoder rotations (wrong '
                         'fixture axes, joint names or gyro units?)')
    if np.all(np.isfinite(sB)):
        U, P = polar(B, side='left')  # B = P U: P symmetric = I + Kg, U = R_m^T
        Kg = P - np.eye(3)
        R_m = U.T
    else:
        # rotations about fewer than three axes: the mounting is not separable from the
        # misalignment; keep the nominal mounting (the filter's prior covers it) and take
        # what is measured as scale (a half-measured misalignment pair stays unmeasured: a
        # polar split of it tilted the start by the half that was not measured)
        Kg = 0.5 * ((B - np.eye(3)) + (B - np.eye(3)).T)
        R_m = np.eye(3)
        notes.append('rotations about fewer than three IMU axes: mounting not measured')
    theta_g[em.gyro_cols('gyro_scale')] = np.diag(Kg)
    sig_g[em.gyro_cols('gyro_scale')] = np.diag(sB)
    c = em.gyro_cols('gyro_misalignment').start
    for k, (i, j) in enumerate(em.MIS_SYM):
        theta_g[c + k] = Kg[i, j]
        sig_g[c + k] = 0.5 * math.hypot(sB[i, j], sB[j, i])
    mount = Rotation.from_matrix(R_m).as_rotvec()
    mount_sig = float(np.max(sB[~np.eye(3, dtype=bool)]))  # inf where not measured
    # --- accelerometers (item 2): the window fit above (f = A g_nom + aa |f| + ba)
    theta_a = np.zeros(em.N_ACCEL)
    sig_a = np.full(em.N_ACCEL, np.inf)
    g = fixture.site.gravity
    if wins:
        A, fits = accel_fit if accel_fit is not None else _fit_accels(fixture, wins, noise_a, dt)
        sA = np.zeros((3, 3))
        for i, (beta, var) in enumerate(fits):
            sd = np.sqrt(var)
            sA[i] = sd[0:3]
            theta_a[em.accel_cols('accel_asymmetry').start + i] = beta[3]
            sig_a[em.accel_cols('accel_asymmetry').start + i] = sd[3]
            theta_a[em.accel_cols('accel_bias').start + i] = beta[4]
            sig_a[em.accel_cols('accel_bias').start + i] = sd[4]
        Ka = A @ R_m - np.eye(3)
        theta_a[em.accel_cols('accel_scale')] = np.diag(Ka)
        sig_a[em.accel_cols('accel_scale')] = np.diag(sA)
        c = em.accel_cols('accel_misalignment').start
        for k, (i, j) in enumerate(em.OFF6):
            theta_a[c + k] = Ka[i, j]
            sig_a[c + k] = math.hypot(sA[i, j], mount_sig)
    # --- bias random walk (item 5) from how the window residuals wander with time
    rw_g = rw_a = 0.0
    if wins:
        R_w = fixture.R_enu_imu(np.array([win.q_rad for win in wins]))
        pred_g = np.einsum('nki,k->ni', R_w, fixture.site.omega_ie_enu) @ B.T
        pred_a = np.einsum('nki,k->ni', R_w, np.array([0.0, 0.0, g])) @ A.T
        fm_w = np.array([w.accel_mean_m_s2 for w in wins])
        pred_g = pred_g + theta_g[em.gyro_cols('gyro_bias')] \
            + fm_w @ theta_g[em.gyro_cols('gyro_g_sensitivity')].reshape(3, 3).T
        pred_a = pred_a + theta_a[em.accel_cols('accel_bias')]
        rw_g = _random_walk(wins, np.array([w.gyro_mean_rad_s for w in wins]) - pred_g,
                            noise_g, dt)
        rw_a = _random_walk(wins, fm_w - pred_a, noise_a, dt)
    # the gyro fit took G on the raw accelerometer outputs f_raw = (I + Ka) f + ba; the
    # model's G acts on the specific force f: G f_raw = G (I + Ka) f + G ba, so G and the
    # bias move to that convention (a MEMS gyro's 300 deg/h/g on a raw 90 mg bias is
    # 28 deg/h of bias, on a 3 % scale error 9 deg/h/g: a start that far off, held by its
    # fit's small sigma, left G 6.7 sigma off at the end, the true noise model's run alike)
    cg = em.gyro_cols('gyro_g_sensitivity')
    G_raw = theta_g[cg].reshape(3, 3).copy()
    if wins and np.all(np.isfinite(sig_g[cg])):
        ba = theta_a[em.accel_cols('accel_bias')]
        Ka = A @ R_m - np.eye(3)
        theta_g[cg] = (G_raw @ (np.eye(3) + Ka)).ravel()
        theta_g[em.gyro_cols('gyro_bias')] += G_raw @ ba
    # an error the data did not measure starts at its prior mean (none), whatever the
    # mounting rotation mixed into it
    theta_g = np.where(np.isfinite(sig_g), theta_g, 0.0)
    theta_a = np.where(np.isfinite(sig_a), theta_a, 0.0)
    st = CoarseStart(theta_g, theta_a, sig_g, sig_a, mount, mount_sig, latency, s_sig,
                     noise_g, noise_a, rw_g, rw_a, len(wins), float(ts[-1] - ts[0]),
                     tuple(notes), zero, zero_sig, accel_reach=reach, base_tilt_rad=tilt,
                     base_tilt_sigma_rad=tilt_sig, imu_period_s=dt)
    why = implausible(st) if np.any(zero) or np.any(tilt) else None
    if why is not None:
        raise _ZerosMisled(why)
    return st
