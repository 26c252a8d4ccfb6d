"""Self-check of a calibration run: does the run's own evidence say it can be trusted (issue 17)?

A pure function of plain figures (:class:`RunEvidence`) to a :class:`Verdict`; nothing here
knows the estimator, ROS or files (:mod:`.run_ledger` gathers the figures from a run).

The checks and their thresholds
-------------------------------
Statistical checks, each a one-sided test at the false-alarm probability ``alpha`` per check,
with ``alpha = 1 - (1 - false_alarm) ** (1 / STATISTICAL_CHECKS)`` (Sidak), so that a run whose
model holds fails the whole self-check with probability at most ``false_alarm`` (1 % by
default; ``alpha`` = 0.2 %; checks that do not apply to a run keep their share):

``nis.velocity``, ``nis.attitude``
    The sum of the normalised innovation squares of every accepted update of that kind over
    the whole run (all filters: re-alignments and restarts start new ones) against
    ``chi2(3 n)``: a consistent Kalman filter's innovations are white with covariance ``S``
    (Bar-Shalom, Li & Kirubarajan, *Estimation with Applications to Tracking and Navigation*,
    sect. 5.4). Upper tail only: a sum below its band means the stated measurement noise is
    pessimistic (the sigmas are conservative), which is reported but not a reason to refuse.
    A ratio ``c`` (NIS per dof) above the bound but at most ``max_nis_ratio`` (1.5) is taken
    as a noise level the filter under-stated: the reported covariance is ``c P``
    (``CalibrationEstimator.covariance_scale``, exact when every noise is off by the same
    factor: the gains are unchanged and the NIS is ``c`` per dof), the check passes and
    says so. Real units are never exactly their noise model (world MEMS units: 1.02-1.05 over
    5,000-12,000 updates, where the bound is 1.02-1.03); a larger ratio is a model error.
``gate``
    Gated (rejected) updates over all updates against ``Binomial(n, p)``, ``p`` the gate's
    tail probability under the scaled noise model (``1 - gate_probability`` at scale 1):
    the number a consistent filter rejects by chance (the gated NIS are not in the sums);
    up to ``max_gated_fraction`` (0.1 %) of the updates is tolerated as outliers, which the
    gate keeps out of the fit.
``windows.chi2``
    The stationary windows (every joint still for >= 1 s): the compensated mean rate and
    specific force of each window minus the earth rate and gravity at the fixture's attitude,
    i.e. the attitude and velocity drift rates there, against the covariance the reported
    calibration predicts (window noise from the white-noise densities, the bias random walk
    between the window and the end of the run, ``J P J^T``); the mounting and the table's
    base orientation are nuisance rotations projected out (``chi2(6 K - 6)``). A failed
    chi2 that a drift of the biases in time explains (:func:`window_drift`, the rules of
    :func:`drift_clause`) says so in its line, with the drift's size: a unit still warming
    up (a navigation unit settling by 0.1 deg/h and 100 ug over its first two minutes) was
    refused naming only the chi2, and the user could not tell a warm-up from a wrong fixture.
``windows.worst``
    The same residuals resolved along the directions the calibration covariance predicts
    (generalised eigenvectors of ``J P J^T`` against the rest): each is N(0, 1) for an honest
    calibration, and one parameter off by many sigmas shows in one of them, where the
    omnibus ``chi2`` over hundreds of degrees of freedom would dilute it. Largest ``|y|``
    against the Sidak bound over the number of directions.

Counted evidence, with no false alarms when the model holds (the estimator's own triggers
have probabilities below 1e-40 then):

``restarts``
    A divergence restart (mean NIS per dof above 20 over 50 updates, half of them gated, or
    a state beyond 50 prior sigmas) means the filter left its model.
``realignments``
    A run of ``cascade_updates`` gated updates in a row (10: ``(1e-5) ** 10`` by chance).
``input.rejected``
    The fraction of IMU samples the input guard rejected (every reason is a violation of
    CONTRACT 1: non-finite, duplicate or out-of-order stamps, ...): above
    ``max_rejected_fraction`` (1 %, the level at which the calibration node already warns,
    ``warn_rejected_fraction``) the stream is systematically not what the contract says (the
    issue's bag: 12.6 % out of order, a calibration 20 sigma off).
``input.lost``
    The fraction of the recording the filter did not use (samples missing in gaps, rejected,
    dropped at gaps and while re-aligning after the first alignment): above
    ``max_lost_fraction`` (1/2) the filter's evidence covers less of the run than it missed.
``plan``
    An uncalibrated unit (no grade with a ``sigma:`` block: raw priors) on a plan that turns
    it about fewer than three IMU axes (the coarse start's note: the mounting is then not
    separable from the misalignments). Such a plan cannot determine a raw unit, and the
    covariance does not show it: linearised at the moving estimate, the filter takes
    information along directions the plan does not excite (a three-pose plan: misalignments
    24 sigma off; a one-axis rate table: a gyro scale 153 sigma off, both with every
    statistical check passed). Counted, not statistical. Fewer than ``min_plan_poses`` (6)
    distinct stationary poses alone is named in the text, not refused: the dishonest runs
    lacked an axis, and a live run saved after seconds has a pose or two.
    Likewise a plan of two or more poses that never stands an accelerometer axis within
    60 deg of vertical (``min_accel_reach``: the largest share of gravity along it at any
    stationary window below 0.5): its scale factor and the misalignments acting on it rest
    on small components, and a random plan that kept the IMU z axis within 5 deg of
    horizontal left a consumer unit's misalignments and an x scale 24 sigma off, every
    statistical check passed.

The verdict is the list of checks; :attr:`Verdict.line` names the failed evidence in one line.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.linalg import cho_factor, cho_solve

from ..parameters import DEG_H_RAD_S, UG_M_S2
from .coarse import MIN_ACCEL_REACH
from .measurements import MEASUREMENT_DOF
from .quantiles import binom_isf, chi2_isf, chi2_ppf, chi2_sf, norm_isf

FloatArray = NDArray[np.float64]

#: the statistical checks the false-alarm probability is shared between (Sidak)
STATISTICAL_CHECKS = ('nis.velocity', 'nis.attitude', 'gate', 'windows.chi2', 'windows.worst',
                      'plausible')
#: windows.chi2's drift clause: the settling time constants tried, as shares of the span
DRIFT_TAU_SHARES = (0.05, 0.1, 0.2, 0.4)
MIN_CALIBRATION_SHARE = 1.0  # windows.worst: directions where J P J^T >= the window noise


@dataclass(frozen=True)
class SelfCheckConfig:
    """The design of the self-check (see the module docstring for each figure)."""

    false_alarm: float = 0.01  # probability that an honest run fails the whole self-check
    max_rejected_fraction: float = 0.01
    max_lost_fraction: float = 0.5
    max_restarts: int = 0
    max_realignments: int = 0
    # the largest whole-run NIS per dof taken as a noise level (the reported covariance is
    # scaled by it, CalibrationEstimator.covariance_scale); above it the filter's model, not
    # its noise level, is wrong (sigmas would be 1.22x at this ratio)
    max_nis_ratio: float = 1.5
    # gated updates are excluded from the fit (robust estimation): a handful beyond the
    # binomial bound, at most this fraction of the updates, is an outlier, not a wrong
    # calibration (a world MEMS run gated 3 of 15,174 with every parameter honest)
    max_gated_fraction: float = 1e-3
    # fewer distinct stationary poses than the six-position test has: named by the plan
    # check (and the replay's refusal hint), not refused on its own
    min_plan_poses: int = 6
    # the least share of gravity every IMU direction must see at some stationary window of a
    # plan with two or more poses (0.5: within 60 deg of vertical; the plan check)
    min_accel_reach: float = MIN_ACCEL_REACH

    def __post_init__(self) -> None:
        if not 0.0 < self.false_alarm < 0.5:
            raise ValueError(f'false_alarm must be in (0, 0.5), got {self.false_alarm}')

    @property
    def alpha(self) -> float:
        """False-alarm probability of one statistical check (Sidak share)."""
        return 1.0 - (1.0 - self.false_alarm) ** (1.0 / len(STATISTICAL_CHECKS))


@dataclass(frozen=True)
class NisTotals:
    """Whole-run gate counts of one measurement kind."""

    accepted: int
    rejected: int
    nis_sum: float
    dof: int = MEASUREMENT_DOF


@dataclass(frozen=True)
class WindowDrift:
    """The windows' misfit with a bias drift over the run projected out (:func:`window_drift`)."""

    chi2: float
    dof: int
    gyro_rad_s: tuple[float, ...]  # the drift's change from the first window to the last
    accel_m_s2: tuple[float, ...]
    gyro_se_rad_s: tuple[float, ...]  # their standard errors under the windows' model
    accel_se_m_s2: tuple[float, ...]


@dataclass(frozen=True)
class WindowStatistics:
    """Stationary-window residual statistics (:func:`window_statistics`)."""

    windows: int
    chi2: float
    dof: int
    worst: float  # largest |y| along the calibration directions
    worst_direction: str  # the calibration state that direction loads on most
    directions: int
    drift: WindowDrift | None = None  # only where the windows misfit (chi2 > dof)


@dataclass(frozen=True)
class RunEvidence:
    """Plain figures of one run, as :mod:`.run_ledger` gathers them."""

    imu_received: int  # IMU samples pushed to the estimator
    imu_expected: int  # samples the stamps' span holds at the nominal rate (>= received)
    imu_rejected: int  # rejected by the input guard
    imu_used: int  # processed by the filter
    imu_before_first_alignment: int  # dropped before the filter first started (not lost)
    restarts: int
    realignments: int
    reinitialisations: int  # navigation re-initialised at gaps or time jumps (information)
    gate_probability: float
    nis: dict[str, NisTotals] = field(default_factory=dict)
    windows: WindowStatistics | None = None
    raw_ratio: float = 0.0  # largest |sensor error estimate| / raw-unit prior sigma
    raw_label: str = ''  # the state it belongs to
    raw_states: int = 0  # sensor-error states compared
    nis_complete: bool = True  # every filter of the run was seen (else the sums are partial)
    covariance_scale: float = 1.0  # factor on the reported covariance (whole-run NIS per dof)
    raw_priors: bool = False  # the unit had no grade sigma: its priors are the raw unit's
    plan_poses: int = -1  # distinct stationary poses of the run (-1: not counted)
    plan_axes_short: bool = False  # the plan turns the IMU about fewer than three axes
    # (reach, direction): the IMU direction (unit vector) stood least near vertical, the
    # largest share of gravity it saw at a stationary window (RunLedger.accel_reach); an
    # empty direction: not counted
    plan_accel_reach: tuple[float, tuple[float, ...]] = (1.0, ())


@dataclass(frozen=True)
class Check:
    """One piece of evidence: its figure, the limit it is held to, and a one-line reading."""

    name: str
    passed: bool
    value: float
    limit: float
    text: str


@dataclass(frozen=True)
class Verdict:
    """Pass or fail, and every check with its figure."""

    passed: bool
    checks: tuple[Check, ...]
    false_alarm: float
    alpha: float

    @property
    def failed(self) -> tuple[Check, ...]:
        """The checks that failed."""
        return tuple(c for c in self.checks if not c.passed)

    @property
    def line(self) -> str:
        """One line: 'self-check passed' or the failed evidence."""
        if self.passed:
            return (f'self-check passed ({len(self.checks)} checks, false-alarm rate '
                    f'{100 * self.false_alarm:g} %)')
        return 'self-check failed: ' + '; '.join(c.text for c in self.failed)

    def as_dict(self) -> dict[str, Any]:
        """Plain YAML data for the calibration file's provenance."""
        return {'passed': self.passed, 'summary': self.line,
                'false_alarm': self.false_alarm, 'alpha_per_check': self.alpha,
                'checks': {c.name: {'passed': c.passed, 'value': _plain(c.value),
                                    'limit': _plain(c.limit), 'text': c.text}
                           for c in self.checks}}


def _plain(x: float) -> float | None:
    return float(x) if math.isfinite(x) else None


def direction_name(v: tuple[float, ...]) -> str:
    """'accelerometer x' for a direction within 1 deg of an IMU axis, else 'the IMU direction
    (0.71, -0.71, 0.00)' (the accelerometers' response along it), with ', near
    accelerometer z,' when within 15 deg of one."""
    a = np.abs(np.asarray(v, float))
    i = int(np.argmax(a))
    if a[i] >= math.cos(math.radians(1.0)):
        return f'accelerometer {"xyz"[i]}'
    near = f', near accelerometer {"xyz"[i]},' if a[i] >= math.cos(math.radians(15.0)) else ''
    return 'the IMU direction (' + ', '.join(f'{x:.2f}' for x in v) + ')' + near


def judge(ev: RunEvidence, config: SelfCheckConfig | None = None) -> Verdict:
    """The verdict on ``ev`` (pure)."""
    cfg = config or SelfCheckConfig()
    a = cfg.alpha
    checks: list[Check] = []
    # --- counted evidence
    checks.append(Check('restarts', ev.restarts <= cfg.max_restarts, ev.restarts,
                        cfg.max_restarts, f'the filter diverged and restarted {ev.restarts} '
                        'time(s)'))
    checks.append(Check('realignments', ev.realignments <= cfg.max_realignments,
                        ev.realignments, cfg.max_realignments,
                        f'the navigation was re-aligned {ev.realignments} time(s) after runs '
                        'of gated updates'))
    rej = ev.imu_rejected / max(ev.imu_received, 1)
    checks.append(Check('input.rejected', rej <= cfg.max_rejected_fraction, rej,
                        cfg.max_rejected_fraction,
                        f'{100 * rej:.3g} % of the IMU samples rejected by the input guard '
                        f'(limit {100 * cfg.max_rejected_fraction:g} %)'))
    plan = max(ev.imu_expected - ev.imu_before_first_alignment, 1)
    lost = min(max(1.0 - ev.imu_used / plan, 0.0), 1.0)
    checks.append(Check('input.lost', lost <= cfg.max_lost_fraction, lost,
                        cfg.max_lost_fraction,
                        f'{100 * lost:.3g} % of the recording after the first alignment not '
                        f'used by the filter (gaps, rejections, {ev.reinitialisations} '
                        f'navigation re-initialisation(s); limit {100 * cfg.max_lost_fraction:g}'
                        ' %)'))
    if ev.raw_priors and ev.plan_poses >= 0:
        few = f'has {ev.plan_poses} stationary poses and ' \
            if ev.plan_poses < cfg.min_plan_poses else ''
        reach, v = ev.plan_accel_reach
        flat = ev.plan_poses >= 2 and len(v) == 3 and reach < cfg.min_accel_reach
        lacks = (['turns about fewer than three IMU axes'] if ev.plan_axes_short else []) + (
            [f'never stands {direction_name(v)} within 60 deg of vertical (at most '
             f'{reach:.2g} of gravity along it)'] if flat else [])
        checks.append(Check('plan', not lacks, ev.plan_poses, cfg.min_plan_poses,
                            f'an uncalibrated unit on a plan that {few}{" and ".join(lacks)}: '
                            'too little to determine its errors, whatever the sigmas say'
                            if lacks else f'{ev.plan_poses} stationary poses'))
    # --- statistical checks, each at alpha
    for kind in ('velocity', 'attitude'):
        t = ev.nis.get(kind)
        if t is None or t.accepted == 0:
            continue
        dof = t.dof * t.accepted
        limit = chi2_isf(a, dof)
        low = chi2_ppf(a, dof)
        note = ' (below its band: pessimistic noise)' if t.nis_sum < low else ''
        partial = '' if ev.nis_complete else ' (sums of the filters seen; some missed)'
        ratio = t.nis_sum / dof
        # above the chi-square bound but within max_nis_ratio: a noise level, which the
        # reported covariance carries (x covariance_scale >= ratio); beyond: a wrong model
        bound = max(limit / dof, cfg.max_nis_ratio) if ev.covariance_scale >= ratio \
            else limit / dof
        scaled = (f' (covariance scaled by {ev.covariance_scale:.3g})'
                  if ratio > limit / dof and ratio <= bound else '')
        checks.append(Check(f'nis.{kind}', ratio <= bound, ratio, bound,
                            f'{kind} NIS per dof {ratio:.3g} over {t.accepted} updates'
                            + (f', above {bound:.3g}' if ratio > bound else scaled)
                            + f'{note}{partial}'))
    n_upd = sum(t.accepted + t.rejected for t in ev.nis.values())
    n_rej = sum(t.rejected for t in ev.nis.values())
    if n_upd:
        # the gate's false-alarm probability under the scaled noise model (NIS x scale)
        q_gate = chi2_isf(max(1.0 - ev.gate_probability, 1e-300), MEASUREMENT_DOF)
        p0 = chi2_sf(q_gate / max(ev.covariance_scale, 1.0), MEASUREMENT_DOF) \
            if ev.gate_probability < 1.0 else 0.0
        # the smallest count whose upper-tail probability is below alpha
        limit_r = binom_isf(a, n_upd, p0) if p0 > 0 else 0
        tolerated = max(limit_r, int(cfg.max_gated_fraction * n_upd))
        checks.append(Check('gate', n_rej <= tolerated, n_rej, tolerated,
                            f'{n_rej} of {n_upd} measurement updates gated (a consistent filter '
                            f'gates at most {limit_r} at this false-alarm rate, '
                            f'{100 * cfg.max_gated_fraction:g} % tolerated as outliers)'))
    if ev.raw_states:
        bound = worst_bound(a, ev.raw_states)
        checks.append(Check('plausible', ev.raw_ratio <= bound, ev.raw_ratio, bound,
                            f'{ev.raw_label} is {ev.raw_ratio:.3g} raw-unit sigmas from zero '
                            f'(bound {bound:.3g}): a sign, axis order or unit the sensor '
                            'model does not describe'))
    w = ev.windows
    if w is not None and w.dof > 0:
        limit = chi2_isf(a, w.dof)
        checks.append(Check('windows.chi2', w.chi2 <= limit, w.chi2 / w.dof, limit / w.dof,
                            f'stationary-window residuals chi2/dof {w.chi2 / w.dof:.3g} over '
                            f'{w.windows} windows, above {limit / w.dof:.3g}'
                            + drift_clause(w, a)))
    if w is not None and w.directions > 0:
        bound = worst_bound(a, w.directions)
        checks.append(Check('windows.worst', w.worst <= bound, w.worst, bound,
                            f'a stationary-window residual {w.worst:.3g} sigma along '
                            f'{w.worst_direction} (bound {bound:.3g} over {w.directions} '
                            'directions)'))
    return Verdict(all(c.passed for c in checks), tuple(checks), cfg.false_alarm, a)


def drift_clause(w: WindowStatistics, alpha: float) -> str:
    """Where the windows' misfit is a drift of the biases over the run, a clause naming it and
    its size, else '': the drift taken out, their chi2 passes at ``alpha``; taking it out
    lowered the chi2 by more than chance would over its added rank (at ``alpha`` shared by
    the time constants tried: more columns always lower a chi2, and noise the model
    understates lowers it more); and some component's change is beyond 3 of its standard
    errors. A unit still warming up (a navigation unit's biases settling by 0.1 deg/h and
    100 ug over the first minutes) was refused naming only the chi2. Without the last two
    conditions, honest windows whose chi2 failed by chance were named a drift in 26-44 of
    66-79 such failures, and windows with 1.25-1.4x the modelled noise in 12-53 %."""
    d = w.drift
    if d is None or d.dof <= 0 or d.chi2 > chi2_isf(alpha, d.dof):
        return ''
    if w.chi2 - d.chi2 <= chi2_isf(alpha / len(DRIFT_TAU_SHARES), max(w.dof - d.dof, 1)):
        return ''
    # a change within 3 of its standard errors is what the windows' model spreads: not named
    g = max((abs(x) for x, e in zip(d.gyro_rad_s, d.gyro_se_rad_s) if abs(x) > 3.0 * e),
            default=0.0) / DEG_H_RAD_S
    f = max((abs(x) for x, e in zip(d.accel_m_s2, d.accel_se_m_s2) if abs(x) > 3.0 * e),
            default=0.0) / UG_M_S2
    if g == 0.0 and f == 0.0:
        return ''

    def two(x: float) -> str:  # two digits, never 7e+02
        return f'{float(f"{x:.2g}"):g}'

    sizes = ([f'gyro biases by up to {two(g)} deg/h'] if g > 0 else []) + (
        ['accelerometer biases by up to ' + (f'{two(f / 1e3)} mg' if f >= 1e3 else
                                              f'{two(f)} ug')] if f > 0 else [])
    return (f'; they follow a drift of the biases over the run ({", ".join(sizes)} from the '
            f'first window to the last; chi2/dof {d.chi2 / d.dof:.3g} with it taken out): '
            'the unit had not settled (warming up?); record once its biases are steady')


def worst_bound(alpha: float, n: int) -> float:
    """``|y|`` bound of the largest of ``n`` independent N(0, 1) at false alarm ``alpha``."""
    per = 1.0 - (1.0 - alpha) ** (1.0 / max(n, 1))
    return norm_isf(per / 2.0)


def _by_component(x: FloatArray) -> FloatArray:
    """Per-window rows ``(K, 6, ...)`` stacked by component, ``(6 K, ...)``: all windows'
    component 0, then 1, ... (the order :func:`window_statistics` works in)."""
    return np.ascontiguousarray(np.swapaxes(x, 0, 1)).reshape((6 * x.shape[0],) + x.shape[2:])


def _range_basis(A: FloatArray) -> FloatArray:
    """Orthonormal basis (n, rank) of the columns of ``A`` (n, r); (n, 0) for none."""
    U, sv, _ = np.linalg.svd(A, full_matrices=False)
    rank = int(np.sum(sv > sv.max() * max(A.shape) * np.finfo(float).eps)) if sv.size else 0
    return U[:, :rank]


def window_drift(resid: FloatArray, jac: FloatArray, P: FloatArray, sigma: FloatArray,
                 walk_cov: FloatArray, nuisance: FloatArray, t_s: FloatArray) -> WindowDrift:
    """The windows' chi-square with a drift of the biases in time projected out as well:
    per component, a straight line and a settling ``exp(-t / tau)`` (twelve more nuisance
    columns), ``tau`` the one of :data:`DRIFT_TAU_SHARES` of the windows' span that fits
    best (a warm-up's time constant is the unit's). The drift's change from the first window
    to the last is the least-squares fit of those shapes with the nuisance projected out
    (weighted by the window noise; a figure for the line, named where it is beyond 3 of its
    standard errors under the windows' noise, walk and calibration covariance)."""
    K = resid.shape[0]
    t = np.asarray(t_s, float) - float(np.min(t_s))
    span = max(float(np.ptp(t_s)), 1e-9)
    fits = []
    for frac in DRIFT_TAU_SHARES:
        shapes = np.column_stack([t / span - 0.5, np.exp(-t / (frac * span))])
        cols = np.zeros((K, 6, 12))
        for c in range(6):
            cols[:, c, 2 * c:2 * c + 2] = shapes
        fits.append((window_statistics(resid, jac, P, sigma, walk_cov,
                                       np.concatenate([nuisance, cols], axis=2)), shapes, cols))
    w, shapes, cols = min(fits, key=lambda f: f[0].chi2)
    s = _by_component(sigma)
    r = _by_component(resid) / s
    D = _by_component(cols) / s[:, None]
    Qa = _range_basis(_by_component(nuisance) / s[:, None])
    r, D = r - Qa @ (Qa.T @ r), D - Qa @ (Qa.T @ D)
    coef, C = np.linalg.lstsq(D, r, rcond=None)[0], np.linalg.pinv(D.T @ D)
    # the fit's covariance under the windows' model: noise, walk and the calibration's
    # J P J^T (whitened as r; never formed at 6K x 6K)
    J = _by_component(jac) / s[:, None]
    DJ = D.T @ J
    V = D.T @ D + DJ @ P @ DJ.T
    for c in range(6):
        rows = slice(c * K, (c + 1) * K)
        Dc = D[rows]
        V += Dc.T @ (walk_cov[:, :, c] / np.outer(s[rows], s[rows])) @ Dc
    cov = C @ V @ C
    d = shapes[int(np.argmax(t))] - shapes[int(np.argmin(t))]
    change, se = np.zeros(6), np.zeros(6)
    for c in range(6):
        k = slice(2 * c, 2 * c + 2)
        change[c] = float(d @ coef[k])  # SI: r and D were whitened alike
        se[c] = math.sqrt(max(float(d @ cov[k, k] @ d), 0.0))
    return WindowDrift(w.chi2, w.dof, tuple(map(float, change[:3])),
                       tuple(map(float, change[3:])), tuple(map(float, se[:3])),
                       tuple(map(float, se[3:])))


def window_statistics(resid: FloatArray, jac: FloatArray, P: FloatArray, sigma: FloatArray,
                      walk_cov: FloatArray, nuisance: FloatArray,
                      labels: tuple[str, ...] = (), t_s: FloatArray | None = None
                      ) -> WindowStatistics:
    """Chi-square and directed statistics of stationary-window residuals.

    Parameters
    ----------
    resid : (K, 6)
        Per window, compensated mean rate and specific force minus their predictions (SI).
    jac : (K, 6, m)
        ``d resid / d x`` up to sign, ``x`` the calibration states (estimate minus truth).
    P : (m, m)
        Covariance of the calibration states (SI).
    sigma : (K, 6)
        White-noise sigma of each window mean (density / sqrt(duration)).
    walk_cov : (K, K, 6)
        Covariance of the bias random walk between the windows and the estimate's instant,
        per component.
    nuisance : (K, 6, r)
        Derivatives of the prediction by nuisance parameters (rotations) projected out.
    labels : m names of the calibration states (for the worst direction).
    t_s : (K,)
        The windows' times (s): where the windows misfit (chi2 above its dof) and there are
        at least four, :func:`window_drift` of them.
    """
    K = resid.shape[0]
    m = jac.shape[2]
    n = 6 * K
    # rows ordered by component (all windows' component 0, then 1, ...): the window noise
    # N = I + W is then block diagonal, one K x K block per component (the walk of one
    # component is independent of the others'); the statistics do not depend on the order
    s = _by_component(sigma)
    r = _by_component(resid) / s
    # the states in units of their sigmas (x = D u, P = D Pu D): the same figures, but the
    # products and the eigenproblem below of order one (P's own scales span decades)
    sd = np.sqrt(np.clip(np.diag(P), 1e-300, None))
    Pu = P / np.outer(sd, sd)
    J = _by_component(jac) * (sd[None, :] / s[:, None])
    # orthonormal basis of what the nuisance produces (the rest, Z, is what it cannot)
    Qa = _range_basis(_by_component(nuisance) / s[:, None])
    rank_a = Qa.shape[1]
    # N^-1 [r J Qa] by the Cholesky factors of the six blocks; r and J first without their
    # part in range(A) (G below ignores it: the same figures, but without the rounding of a
    # large nuisance part that would cancel in G)
    RJ = np.column_stack([r, J])
    RJ -= Qa @ (Qa.T @ RJ)
    X = np.column_stack([RJ, Qa])
    NiX = np.empty_like(X)
    for c in range(6):
        rows = slice(c * K, (c + 1) * K)
        sc = s[rows]
        Nc = np.eye(K) + walk_cov[:, :, c] / np.outer(sc, sc)
        NiX[rows] = cho_solve(cho_factor(Nc, lower=True), X[rows])
    # with Z an orthonormal basis of the complement of range(A) and G = Z (Z^T N Z)^-1 Z^T
    # = N^-1 - N^-1 Qa (Qa^T N^-1 Qa)^-1 Qa^T N^-1, every figure is a product of
    # [r J]^T G [r J]: the (n - rank) x (n - rank) matrices of the definition are not formed
    X1, Ni1, NiQ = X[:, :m + 1], NiX[:, :m + 1], NiX[:, m + 1:]
    M = X1.T @ Ni1
    if rank_a:
        QNQ = Qa.T @ NiQ
        F = Qa.T @ Ni1
        M = M - F.T @ cho_solve(cho_factor(0.5 * (QNQ + QNQ.T)), F)
    M = 0.5 * (M + M.T)
    rGr, JGr, JGJ = float(M[0, 0]), M[1:, 0], M[1:, 1:]
    dof = n - rank_a
    # Pu = R R^T; the pencil (Jz P Jz^T, Nz) has the nonzero eigenvalues of
    # H = R^T Jz^T Nz^-1 Jz R = R^T (J^T G J) R, with the Nz-normalised eigenvectors
    # v = Nz^-1 Jz R e / sqrt(lambda) (e: H's unit eigenvectors)
    d, E = np.linalg.eigh(0.5 * (Pu + Pu.T))
    R = E * np.sqrt(np.clip(d, 0.0, None))
    H = R.T @ JGJ @ R
    lam, Ev = np.linalg.eigh(0.5 * (H + H.T))
    g = Ev.T @ (R.T @ JGr)  # e^T R^T J^T G r
    # chi2 = rz^T (Nz + Jz P Jz^T)^-1 rz (Woodbury)
    stat = rGr - float(np.sum(g * g / (1.0 + lam)))
    # directions of the calibration covariance: B v = lambda N v, y = v^T r / sqrt(1 + lambda)
    # only where the calibration's share is at least the window noise's (lambda >= 1): the
    # noise-dominated directions test the noise model, not the calibration (and their
    # eigenvectors are ill-determined at lambda ~ 0)
    keep = lam >= MIN_CALIBRATION_SHARE
    worst, where, n_dir = 0.0, '', int(keep.sum())
    if n_dir:
        lam_k = lam[keep]
        y = g[keep] / np.sqrt(lam_k * (1.0 + lam_k))
        j = int(np.argmax(np.abs(y)))
        worst = float(abs(y[j]))
        # the state this direction loads on most, in units of its sigma: P Jz^T v / sd
        load = (Pu @ (JGJ @ (R @ Ev[:, keep][:, j]))) / np.sqrt(lam_k[j])
        where = labels[int(np.argmax(np.abs(load)))] if labels else str(int(np.argmax(
            np.abs(load))))
    drift = (window_drift(resid, jac, P, sigma, walk_cov, nuisance, t_s)
             if t_s is not None and K >= 4 and stat > dof else None)
    return WindowStatistics(K, stat, dof, worst, where, n_dir, drift)


def evidence_dict(ev: RunEvidence) -> dict[str, Any]:
    """Plain data of the evidence (provenance)."""
    d = asdict(ev)
    d['nis'] = {k: asdict(v) for k, v in ev.nis.items()}
    return d


# ---------------------------------------------------------------------------- the file side
#: where the verdict goes in a calibration file: ``imu_calibration.provenance.self_check``
PROVENANCE_KEY = 'self_check'


def with_verdict(extra: dict[str, Any], verdict: dict[str, Any],
                 forced: bool = False) -> dict[str, Any]:
    """``extra`` (a calibration's extra keys) with the verdict under
    ``provenance.self_check``; ``forced`` marks a file written although it failed."""
    out = dict(extra)
    prov = dict(out.get('provenance', {}) or {})
    v = dict(verdict)
    if forced and not v.get('passed', False):
        v['forced'] = True
        v['summary'] = 'FAILED, written with force: ' + str(v.get('summary', ''))
    prov[PROVENANCE_KEY] = v
    out['provenance'] = prov
    return out


def verdict_of(extra: dict[str, Any]) -> dict[str, Any] | None:
    """The verdict a calibration's extra keys carry, or None."""
    v = (extra.get('provenance', {}) or {}).get(PROVENANCE_KEY)
    return v if isinstance(v, dict) else None


def saved_extra(extra: dict[str, Any], verdict: dict[str, Any] | None,
                force: bool) -> tuple[dict[str, Any] | None, str]:
    """The rule for writing a calibration (the node's save service and save on shutdown; the
    CLI's ``--force``): ``(extra with the verdict, '')`` when it passed or ``force`` is set
    (marked), else ``(None, why)``. A missing verdict counts as failed."""
    v = verdict if verdict is not None else {
        'passed': False, 'summary': 'no self-check verdict (the estimator diverged or failed)'}
    if not v.get('passed', False) and not force:
        return None, str(v.get('summary', 'self-check failed'))
    return with_verdict(extra, v, forced=force), ''
