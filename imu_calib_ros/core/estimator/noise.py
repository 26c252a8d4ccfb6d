"""Process noise of the filter: white noise, the biases' random walk, and its adaptation.

``Q`` per second (:func:`~.ekf.process_noise`) is built from the sensors' white-noise
densities (measured by the coarse start or on the alignment window with the Allan deviation,
or the grade's) and the biases' random walk: the grade's Gauss-Markov instability as
``q = 2 sigma^2 / tau`` plus its random walk, at least what the coarse start measured
(issue 11 item 5), and for a MEMS unit without a grade never zero (:data:`MEMS_BIAS_WALK`).
When the innovations say the biases drift more than that (covariance matching, Mehra 1972,
"Approaches to adaptive filtering", one way only), :class:`ProcessNoise` doubles the walk.
"""
from __future__ import annotations

import logging
import math
from typing import TYPE_CHECKING, Any, Mapping

import numpy as np
from numpy.typing import NDArray

from ..allan import overlapping_avar
from .coarse import CoarseStart
from .ekf import process_noise
from .error_model import StateLayout

if TYPE_CHECKING:
    from ..imu_grade import ImuGrade

FloatArray = NDArray[np.float64]
_LOG = logging.getLogger('imu_calib_ros.estimator')

# Least bias random walk of a unit without a grade, per sqrt(s), as a fraction of its
# white-noise density: gyro 0.022, MEMS only (real parts span 0.006-0.06: a Gauss-Markov
# instability sigma over 100 s is sqrt(2/100) sigma per sqrt(s), e.g. BMI088 2 deg/h at
# 0.014 deg/s/sqrt(Hz) is 0.006, ADIS16470 8 deg/h at 0.34 deg/sqrt(h) 0.055; the in-run walk
# of the stationary windows (RunLedger.bias_walk) raises it for the drifting ones. On the
# robustness grid's 32 MEMS runs, 0.035 gave gyro-bias sigmas 2.2x the true noise model's
# (passed 26/32, 6/1440 beyond 3 sigma), 0.022 passed 30/32 with 8/1440 and 0.015 31/32 with
# 10/1440 against 3.9 for an honest filter: 0.022 is the lowest fixed value that stays honest
# (a live run's; offline, replay.profile_gyro_walk lets the innovations raise the gyro's). A
# navigation gyro's is ~1e-4 and this floor would cost its bias accuracy), accelerometer
# 0.035 for MEMS (MTi-1: 30 ug over 100 s at 120 ug/sqrt(Hz) is 0.035; consumer parts
# 0.014-0.09: with 0.015 a world consumer unit's 80 ug over 100 s left its accelerometer
# biases 4-4.7 sigma off) and ACCEL_BIAS_WALK 0.015 for every other
# class (a navigation unit's 2-5 ug over an hour at 5-20 ug/sqrt(Hz) is 0.002-0.024: a drift
# the stationary windows cannot resolve, but that left a 0.6 ug sigma 5 sigma off on a
# 30-min world run).
MEMS_BIAS_WALK = (0.022, 0.035)
#: the walks' source when a MEMS floor sets them, and the gyro's when a replay chose it
#: (:func:`.replay.profile_gyro_walk`)
MEMS_FLOOR_SOURCE = 'MEMS floor'
LIKELIHOOD_SOURCE = 'innovation likelihood'
ACCEL_BIAS_WALK = 0.015  # the accelerometer's, any class without a grade

# Least white-noise density the filter assumes, (gyro rad/s/sqrt(Hz), accel m/s^2/sqrt(Hz)):
# 1/50 of the best navigation grade (0.002 deg/sqrt(h), 5 ug/sqrt(Hz)); a quieter stream (a
# noise-free simulation, a unit quantised below its noise) is modelled at this floor, so R, Q
# and the self-check's window covariance stay positive definite.
WHITE_NOISE_FLOOR = (1.2e-8, 1.0e-6)


def white_noise_densities(start: CoarseStart | None, grade: ImuGrade | None,
                          noise_source: str) -> tuple[float, float]:
    """White-noise densities ``(gyro rad/s/sqrt(Hz), accel m/s^2/sqrt(Hz))`` for Q: measured
    (coarse start) or the grade's (``noise_source``; the data's when there is no grade)."""
    if start is not None and (noise_source == 'data' or grade is None):
        n = (start.gyro_noise_rad_s_rt_hz, start.accel_noise_m_s2_rt_hz)
    elif grade is not None:
        n = (grade.gyro_noise_rad_s_rt_hz, grade.accel_noise_m_s2_rt_hz)
    else:
        n = (1e-4, 1e-3)  # nothing measured yet and no grade: MEMS-like until the start
    return max(n[0], WHITE_NOISE_FLOOR[0]), max(n[1], WHITE_NOISE_FLOOR[1])


def white_noise_from_window(w: FloatArray, f: FloatArray, dt_s: float,
                            point: bool = False) -> tuple[float, float]:
    """White-noise densities from a stationary window (Allan deviation at the shortest tau,
    where white noise dominates: ``N = sigma_A(tau) sqrt(tau)``, IEEE Std 952-1997 annex C).
    ``point``: trapezoid means of point samples, whose Allan variance at ``2 dt`` is 5/8 of
    white noise's (:func:`.coarse.white_noise_density`)."""
    out = []
    for x in (w, f):
        dens = np.sqrt(overlapping_avar(x, [2])[0] * 2.0 * dt_s)
        if point:
            dens = dens / math.sqrt(0.625)
        out.append(float(np.sqrt(np.mean(np.square(dens)))))
    return out[0], out[1]


def grade_bias_walk(grade: ImuGrade) -> tuple[float, float]:
    """Spectral densities ``(q_g, q_a)`` of a grade's bias walk [(rad/s)^2/s, (m/s^2)^2/s]:
    its Gauss-Markov instability as a random walk ``2 sigma^2 / tau`` plus its random walk."""
    return (2.0 * grade.gyro_bias_instability_rad_s ** 2 / grade.gyro_bias_correlation_s
            + grade.gyro_bias_random_walk_rad_s2_rt_hz ** 2,
            2.0 * grade.accel_bias_instability_m_s2 ** 2 / grade.accel_bias_correlation_s
            + grade.accel_bias_random_walk_m_s3_rt_hz ** 2)


def gyro_bias_floor_rad_s(grade: ImuGrade) -> float:
    """Least sigma of a tracked gyro bias [rad/s] that a unit's own noise allows (issue 3's
    note, restated by issue 11; the MEMS gyro-bias target is this floor, and <= 2 deg/h where
    it is lower): a random walk of PSD ``q`` (:func:`grade_bias_walk`) seen through white rate
    noise of density ``N`` has the steady-state sigma ``sqrt(N sqrt(q))`` even with the angle
    known (scalar Kalman-Bucy Riccati equation); zero for a unit without bias walk (then the
    turn-on constant alone limits, ``N / sqrt(T)`` over ``T`` seconds)."""
    return math.sqrt(grade.gyro_noise_rad_s_rt_hz * math.sqrt(grade_bias_walk(grade)[0]))


#: correlation time of a MEMS gyro's in-run bias instability (datasheets' "in-run bias
#: stability"; the world units' 100 s): the instability a walk of PSD ``q`` covers is
#: ``sqrt(q tau / 2)`` (:func:`instability_covered`)
MEMS_INSTABILITY_CORRELATION_S = 100.0


def bias_walk_terms(grade: ImuGrade | None, start: CoarseStart | None,
                    mems_gyro_noise_rad_s_rt_hz: float
                    ) -> tuple[dict[str, float], dict[str, float]]:
    """The candidates for the gyro and accelerometer bias random walk by where they come from
    (PSDs [(rad/s)^2/s, (m/s^2)^2/s]; :func:`bias_random_walk` takes the largest of each):
    ``grade`` (its Gauss-Markov ``2 sigma^2 / tau`` + random walk), ``stationary windows``
    (the walk the coarse start's windows showed, item 5, or an earlier pass's:
    ``replay.walk_grown``), and without a grade the
    floors: ``accelerometer floor`` (:data:`ACCEL_BIAS_WALK`, any class) and ``MEMS floor``
    (:data:`MEMS_BIAS_WALK`, a unit whose gyro noise is above ``mems_gyro_noise_rad_s_rt_hz``:
    the stationary windows of a short plan cannot show a 100 s instability); for that unit's
    gyro, once an offline replay has profiled it, ``innovation likelihood`` instead of the
    floor (``start.gyro_walk_to_noise_per_s``, :func:`.replay.profile_gyro_walk`)."""
    g: dict[str, float] = {}
    a: dict[str, float] = {}
    if grade is not None:
        g['grade'], a['grade'] = grade_bias_walk(grade)
    st = start
    if st is not None:
        g['stationary windows'] = st.gyro_bias_random_walk_rad_s2_rt_hz ** 2
        a['stationary windows'] = st.accel_bias_random_walk_m_s3_rt_hz ** 2
        if grade is None:
            # no grade: never assume the accelerometer biases constant (any class)
            a['accelerometer floor'] = (ACCEL_BIAS_WALK * st.accel_noise_m_s2_rt_hz) ** 2
        if grade is None and st.gyro_noise_rad_s_rt_hz > mems_gyro_noise_rad_s_rt_hz:
            # a MEMS unit and no grade: nor its gyro biases, and more of both; the gyro's
            # raised by the run's innovations once a replay has profiled it
            if st.gyro_walk_to_noise_per_s > 0.0:  # a profile pass may run below the floor
                g[LIKELIHOOD_SOURCE] = (st.gyro_walk_to_noise_per_s
                                        * st.gyro_noise_rad_s_rt_hz) ** 2
            else:
                g[MEMS_FLOOR_SOURCE] = (MEMS_BIAS_WALK[0] * st.gyro_noise_rad_s_rt_hz) ** 2
            a[MEMS_FLOOR_SOURCE] = (MEMS_BIAS_WALK[1] * st.accel_noise_m_s2_rt_hz) ** 2
    return g, a


def bias_random_walk(grade: ImuGrade | None, start: CoarseStart | None,
                     mems_gyro_noise_rad_s_rt_hz: float) -> tuple[float, float]:
    """Spectral densities of the gyro and accelerometer bias random walk ``(q_g, q_a)``
    [(rad/s)^2/s, (m/s^2)^2/s]: the largest of :func:`bias_walk_terms` (the grade's, at least
    the walk the coarse start measured, at least the floors of a unit without a grade, or for
    its gyro the walk a replay's profile chose)."""
    g, a = bias_walk_terms(grade, start, mems_gyro_noise_rad_s_rt_hz)
    return max(g.values(), default=0.0), max(a.values(), default=0.0)


def bias_walk_sources(grade: ImuGrade | None, start: CoarseStart | None,
                      mems_gyro_noise_rad_s_rt_hz: float) -> tuple[str, str]:
    """Which term of :func:`bias_walk_terms` sets each walk (gyro, accel); ``none`` if 0 (the
    first of equal terms: a grade before the data, the data before a floor)."""
    out = []
    for terms in bias_walk_terms(grade, start, mems_gyro_noise_rad_s_rt_hz):
        best = max(terms.values(), default=0.0)
        out.append(next((k for k, v in terms.items() if v == best), 'none') if best > 0
                   else 'none')
    return out[0], out[1]


def instability_covered(q: float) -> float:
    """The Gauss-Markov bias instability sigma (correlation time
    :data:`MEMS_INSTABILITY_CORRELATION_S`) whose short-term growth a random walk of PSD ``q``
    matches: ``sqrt(q tau / 2)`` (the inverse of :func:`grade_bias_walk`'s ``2 sigma^2 /
    tau``)."""
    return math.sqrt(max(q, 0.0) * MEMS_INSTABILITY_CORRELATION_S / 2.0)


def assumed_walk_note(extra: Mapping[str, Any], grade_option: str = '--imu') -> str | None:
    """One sentence when the gyro-bias sigmas rest on the assumed MEMS drift alone (no grade,
    and the plan's stationary windows showed none): the instability they cover and what to do
    for a less stable unit; or on the walk a replay chose by the innovations' likelihood
    (:func:`.replay.profile_gyro_walk`): that walk and what it covers; None otherwise.
    ``extra``: a calibration's extra mapping, whose
    ``estimator.bias_walk`` is :meth:`.estimator.CalibrationEstimator.bias_walk_summary`;
    ``grade_option``: how the caller takes a grade (the CLI's ``--imu``, the node's
    ``imu_grade``)."""
    walk = (extra.get('estimator') or {}).get('bias_walk') or {}
    deg_h = math.degrees(1.0) * 3600.0
    density = f'{walk.get("gyro_bias_random_walk_rad_s2_rt_hz", 0.0) * deg_h * 60.0:.2g}'
    covered = f'{walk.get("gyro_instability_covered_rad_s", 0.0) * deg_h:.2g} deg/h (over 100 s)'
    passes = len(walk.get('gyro_walk_profile', ()))
    bound = (f'the likelihood\'s one-sided 95 % upper bound over {passes} passes: '
             f'{walk.get("gyro_walk_likelihood_bound_per_s", 0.0):.2g} of the white noise')
    if walk.get('gyro_source') == LIKELIHOOD_SOURCE:
        return (f'no IMU grade: the run\'s innovations raised the gyro bias walk above the '
                f'MEMS floor to {density} deg/h/sqrt(h) ({bound}), an in-run bias '
                f'instability up to {covered}')
    if walk.get('gyro_source') != MEMS_FLOOR_SOURCE:
        return None
    if passes:
        return (f'no IMU grade: the gyro-bias sigmas assume the MEMS floor ({density} '
                f'deg/h/sqrt(h), an in-run bias instability up to {covered}), and the run\'s '
                f'innovations ask for no more ({bound})')
    return (f'no IMU grade, and the stationary windows showed no gyro bias drift: the gyro-bias '
            f'sigmas assume the MEMS floor ({density} deg/h/sqrt(h)), enough for an in-run bias '
            f'instability up to {covered}; for a less stable unit give {grade_option} with its '
            'datasheet\'s instability, or record a plan that returns to its poses minutes apart')


class ProcessNoise:
    """``Q`` per second of one estimator run, in the filter's scaled units (``q1_s``).

    ``white`` (gyro, accel densities) is set at the start and at each alignment; the biases'
    walk at each filter start (:meth:`start`). The adaptation (:meth:`adapt`: its seed and its
    doubling) is kept across re-alignments and restarts: the drift it found is the unit's.
    """

    def __init__(self, noise_scale: float) -> None:
        self.noise_scale = noise_scale  # multiplies the white-noise densities
        self.white = (0.0, 0.0)
        self.bias_q = (0.0, 0.0)
        self.seed = (0.0, 0.0)  # the walk the adaptation seeded, when none was known
        self.floor = (0.0, 0.0)  # the walk the run's stationary windows showed (raise_walk)
        self.scale = 1.0  # the adaptation's factor on the walk
        self.initial: tuple[float, float] | None = None  # the walk the run's first filter used
        self.measured = (0.0, 0.0)  # the largest walk the stationary windows showed (raise_walk)
        self.q1_s: FloatArray | None = None  # diagonal Q per second, scaled units
        self._layout: StateLayout | None = None

    def start(self, layout: StateLayout, bias_q: tuple[float, float]) -> None:
        """Q for a new filter: the bias walk ``bias_q``, at least the adaptation's seed."""
        self._layout = layout
        self.bias_q = (max(bias_q[0], self.seed[0], self.floor[0]),
                       max(bias_q[1], self.seed[1], self.floor[1]))
        if self.initial is None:
            self.initial = self.bias_q
        self._update()

    def grown(self) -> tuple[float, float, float, float]:
        """The walk the stationary windows showed (:meth:`raise_walk`) against the one the
        run's first filter started with: ``(q_gyro, q_accel, ratio_gyro, ratio_accel)``
        (PSDs; ratio inf from a zero start). Not the innovations' adaptation (:meth:`adapt`):
        it doubles both groups on evidence that names neither, and a pass started with it
        adapts again (a tactical unit's gyro-bias sigma 3.4x its noise limit)."""
        q0 = self.initial or (0.0, 0.0)
        q = self.measured
        ratio = tuple(q[i] / q0[i] if q0[i] > 0 else (math.inf if q[i] > 0 else 1.0)
                      for i in range(2))
        return q[0], q[1], ratio[0], ratio[1]

    def raise_walk(self, q: tuple[float, float], factor: float = 1.5) -> bool:
        """Item 5 in the run: the stationary windows at one pose drift apart by more than the
        assumed walk allows. Each of ``q`` (gyro, accel PSD) that exceeds the walk in use
        (``scale x bias_q``) by ``factor`` becomes the walk (kept across re-alignments, like
        the adaptation). Returns whether Q changed."""
        changed = False
        bq = list(self.bias_q)
        fl = list(self.floor)
        self.measured = (max(self.measured[0], q[0]), max(self.measured[1], q[1]))
        for i in range(2):
            if q[i] > factor * self.scale * bq[i]:
                bq[i] = q[i] / self.scale
                fl[i] = max(fl[i], bq[i])
                changed = True
        if changed:
            self.bias_q = (bq[0], bq[1])
            self.floor = (fl[0], fl[1])
            if self._layout is not None:
                self._update()
        return changed

    def _update(self) -> None:
        """Q per second (scaled) from the white noise and the bias walk x its adaptation."""
        lay = self._layout
        assert lay is not None
        k = self.noise_scale
        qg, qa = (q * self.scale for q in self.bias_q)
        q1 = process_noise(lay, 1.0, k * self.white[0], k * self.white[1], qg, qa)
        self.q1_s = np.diag(np.diag(q1) / lay.scale ** 2)

    def adapt(self, window: tuple[int, int, float] | None, nis_window: int) -> bool:
        """Item 5: a bias drift nobody declared shows as innovations larger than the filter
        predicts. ``window`` is ``(accepted, rejected, NIS sum)`` of the updates since the NIS
        window began (:class:`~.health.NisWindow`). When it spans ``nis_window`` updates and
        the mean NIS per dof stands out of its chi-square spread (4 sigma) or gated updates
        appear, the biases' random walk is doubled (seeded, when none was known, at 1e-3 of
        the white noise density per sqrt(s), gyro, and 1e-2, accelerometer). Returns whether
        Q changed (the caller then starts a fresh window)."""
        if window is None:
            return False
        acc, rej, nis_sum = window
        if acc + rej < nis_window:
            return False
        mean = nis_sum / max(acc, 1) / 3.0
        if mean < 1.0 + 4.0 * math.sqrt(2.0 / (3.0 * max(acc, 1))) and rej == 0:
            return False
        if not any(self.bias_q):  # kept across re-alignments, like the scale
            self.seed = ((1e-3 * self.white[0]) ** 2, (1e-2 * self.white[1]) ** 2)
            self.bias_q = self.seed
        elif self.scale < 2.0 ** 30:
            self.scale *= 2.0
        else:
            return False
        self._update()
        return True


def check_grade_hint(grade: ImuGrade | None, start: CoarseStart, noise_source: str) -> None:
    """Log one line when the data disagree with the grade the user gave (white noise more
    than a factor 2 away from the grade's)."""
    gr = grade
    if gr is None:
        return
    for what, got, hint in (('gyro', start.gyro_noise_rad_s_rt_hz, gr.gyro_noise_rad_s_rt_hz),
                            ('accelerometer', start.accel_noise_m_s2_rt_hz,
                             gr.accel_noise_m_s2_rt_hz)):
        if hint > 0 and not 0.5 <= got / hint <= 2.0:
            _LOG.warning('the data disagree with the IMU grade %s: %s white noise %.3g is '
                         '%.2g x the grade\'s %.3g (using %s)', gr.name, what, got,
                         got / hint, hint, 'the data\'s' if noise_source == 'data'
                         else 'the grade\'s')
