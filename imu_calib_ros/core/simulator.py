"""Turntable/IMU simulator: fixture + joint profile + true errors + noise -> IMU and joint data.

The IMU output follows CONTRACT 1: each sample is the mean over its interval of the CONTRACT 3
forward model (:func:`~imu_calib_ros.core.sensor_model.measure`), evaluated on the exact
motion of the TRUE fixture (nominal mounting composed with a small random error), stamped at
the interval end. The mean is integrated with Gauss-Legendre quadrature, piecewise between the
profile's breakpoints (where the third derivative of the joint angles may jump), so the
integrand is smooth on every piece and the integral is exact to rounding for the rates and
angular accelerations of a turntable (8 nodes on a 5 ms piece: error far below 1e-12 relative).

Noise (IEEE Std 952 terms, values from :class:`~imu_calib_ros.core.imu_grade.ImuGrade`):

- white noise on each mean, standard deviation ``N / sqrt(dt)`` (angle/velocity random walk);
- bias instability as a first-order Gauss-Markov process and rate random walk, both exactly
  discretised at the IMU interval and held over each interval;
- optional quantisation of the increments ``mean * dt`` with the residual carried on, as an
  integrating IMU's pulse counter does.

Joint states come at their own rate with white encoder noise, optionally wrapped to
(-pi, pi]. Every random draw comes from ``numpy.random.SeedSequence(seed)`` children, so a
seed reproduces the run, and changing e.g. the noise does not change the drawn errors.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import cached_property
from typing import Any, Callable

import numpy as np
from numpy.typing import NDArray
from scipy.signal import lfilter

from .calibration import CalibrationResult
from .fixture import Fixture, Kinematics
from .imu_grade import ImuGrade, draw_errors
from .plans import JointProfile
from .sensor_model import SensorErrors, measure
from .types import ImuBatch, JointBatch

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class SimConfig:
    """Simulator settings (rates, quadrature, randomness, output options)."""

    imu_rate_hz: float = field(default=200.0, metadata={'min': 1.0, 'max': 1e5})
    joint_rate_hz: float = field(default=100.0, metadata={'min': 0.1, 'max': 1e5})
    oversample: int = field(default=8, metadata={'min': 2, 'max': 64,
                                                 'doc': 'Gauss-Legendre nodes per piece'})
    seed: int = field(default=0, metadata={'min': 0})
    encoder_noise_rad: float = field(default=1e-6, metadata={'min': 0.0})
    mounting_rpy_sigma_rad: float = field(default=1e-3, metadata={'min': 0.0})
    mounting_xyz_sigma_m: float = field(default=3e-3, metadata={'min': 0.0})
    noise: bool = True
    quantize: bool = True
    wrap_joint_positions: bool = False
    joint_velocities: bool = True
    start_stamp_ns: int = field(default=1_700_000_000_000_000_000, metadata={'min': 0})
    frame_id: str = 'imu_link'
    block_s: float = field(default=20.0, metadata={'min': 0.1})
    #: the errors of an uncalibrated arm (issue 15; :func:`~.fixture.perturbed_chain`): each
    #: revolute joint's zero off by N(0, joint_offset_sigma_rad), each joint origin by
    #: N(0, link_sigma_m) per coordinate (not on a concurrent turntable); 0 = the nominal chain
    joint_offset_sigma_rad: float = field(default=0.0, metadata={'min': 0.0})
    link_sigma_m: float = field(default=0.0, metadata={'min': 0.0})


@dataclass(frozen=True, eq=False)
class SimResult:
    """Simulated data and its truth.

    Attributes
    ----------
    imu : ImuBatch
        Mean rate and specific force per interval, stamped at the interval end.
    joints : JointBatch
        Joint states (encoder noise, optionally wrapped).
    truth : CalibrationResult
        True constant errors (sigma 0), ``extra`` with ``mounting``, ``noise``, ``provenance``.
    true_fixture : Fixture
        The fixture with the true IMU mounting.
    profile : JointProfile
    config : SimConfig
    bias_drift_gyro_rad_s, bias_drift_accel_m_s2 : (N, 3)
        The stochastic bias part (Gauss-Markov + random walk) held over each interval.
    """

    imu: ImuBatch
    joints: JointBatch
    truth: CalibrationResult
    true_fixture: Fixture
    profile: JointProfile
    config: SimConfig
    bias_drift_gyro_rad_s: FloatArray
    bias_drift_accel_m_s2: FloatArray

    @property
    def times_s(self) -> FloatArray:
        """IMU stamps as profile time [s] (interval ends)."""
        return (self.imu.stamps_ns - self.config.start_stamp_ns).astype(np.float64) * 1e-9

    @cached_property
    def nav(self) -> Kinematics:
        """Exact motion of the true fixture at the IMU stamps (navigator truth)."""
        q, qd, qdd = self.profile.evaluate(self.times_s)
        return self.true_fixture.kinematics(q, qd, qdd)


def draw_mounting(config: SimConfig, rng: np.random.Generator) -> tuple[FloatArray, FloatArray]:
    """Random mounting error (small rpy [rad], offset [m]) with the configured sigmas."""
    return (rng.normal(0.0, config.mounting_rpy_sigma_rad, 3),
            rng.normal(0.0, config.mounting_xyz_sigma_m, 3))


def draw_chain_errors(fixture: Fixture, rng: np.random.Generator, joint_offset_sigma_rad: float,
                      link_sigma_m: float) -> tuple[Fixture, dict[str, Any]]:
    """The true chain of an uncalibrated arm (:func:`~.fixture.perturbed_chain`) and its
    record for the truth file (``extra['chain_errors']``): the sigmas, and per joint its zero
    offset [rad] (the joint is at the encoder reading plus this) and origin error [m, parent
    frame]."""
    from .fixture import perturbed_chain
    true_chain, offsets, dxyz = perturbed_chain(fixture, rng, joint_offset_sigma_rad,
                                                link_sigma_m)
    return true_chain, {
        'joint_offset_sigma_rad': float(joint_offset_sigma_rad),
        'link_sigma_m': float(link_sigma_m),
        'joint_zero_offsets_rad': {j.name: float(o) for j, o in zip(fixture.joints, offsets)},
        'joint_origin_errors_m': {j.name: [float(x) for x in d]
                                  for j, d in zip(fixture.joints, dxyz)}}


def last_link_record(nominal: Fixture, true: Fixture) -> dict[str, Any]:
    """What the estimator reports as lever arm and mounting on a general chain, for the truth
    file (``extra['chain_errors']['last_link']``): the IMU on the last link as its encoder
    reads it (:func:`~.estimator.truth.last_link_truth`: the drawn mounting error, the last
    joint's zero offset and its origin error along its axis)."""
    from scipy.spatial.transform import Rotation

    from .estimator.truth import last_link_truth
    rho, R_m = last_link_truth(nominal, true)
    return {'lever_arm_m': [float(x) for x in rho],
            'mounting_rotvec_rad': [float(x) for x in Rotation.from_matrix(R_m).as_rotvec()]}


def simulate(fixture: Fixture, profile: JointProfile, grade: ImuGrade,
             config: SimConfig = SimConfig(), errors: SensorErrors | None = None,
             mounting: tuple[Any, Any] | None = None,
             progress: Callable[[float], None] | None = None) -> SimResult:
    """Simulate an IMU on ``fixture`` running ``profile``.

    Parameters
    ----------
    fixture : Fixture
        The nominal fixture (as in the user's file).
    profile : JointProfile
        From :func:`~imu_calib_ros.core.plans.build_profile` on that fixture.
    grade : ImuGrade
        Noise and error magnitudes (errors are drawn from it unless given).
    config : SimConfig
    errors : SensorErrors, optional
        True constant errors; drawn with :func:`draw_errors` if None.
    mounting : (drpy_rad (3,), dxyz_m (3,)), optional
        True mounting error; drawn with the config's sigmas if None.
    progress : callable, optional
        Called with the fraction done after each block.

    Returns
    -------
    SimResult
    """
    if tuple(profile.joint_names) != tuple(fixture.joint_names):
        raise ValueError(f'profile joints {profile.joint_names} do not match the fixture '
                         f'joints {fixture.joint_names}')
    ss = np.random.SeedSequence(config.seed)
    # a fifth child for the arm's errors: the first four (and so every draw of a run without
    # arm errors) are those of spawn(4)
    rng_err, rng_mount, rng_noise, rng_enc, rng_chain = (np.random.default_rng(s)
                                                         for s in ss.spawn(5))
    if errors is None:
        errors = draw_errors(grade, rng_err)
    if mounting is None:
        drpy, dxyz = draw_mounting(config, rng_mount)
    else:
        drpy, dxyz = (np.asarray(m, dtype=float).reshape(3) for m in mounting)
    chain_truth: dict[str, Any] = {}
    true_chain = fixture
    if config.joint_offset_sigma_rad > 0.0 or config.link_sigma_m > 0.0:
        true_chain, chain_truth = draw_chain_errors(fixture, rng_chain,
                                                    config.joint_offset_sigma_rad,
                                                    config.link_sigma_m)
    true_fx = true_chain.with_mounting(drpy, dxyz)
    if chain_truth and not fixture.concurrent:
        chain_truth['last_link'] = last_link_record(fixture, true_fx)

    dt_ns = int(round(1e9 / config.imu_rate_hz))
    dt = dt_ns * 1e-9
    n_imu = int(math.floor(profile.duration_s / dt + 1e-9))
    if n_imu < 1:
        raise ValueError('the profile is shorter than one IMU interval')
    stamps = config.start_stamp_ns + dt_ns * np.arange(1, n_imu + 1, dtype=np.int64)
    gyro = np.empty((n_imu, 3))
    accel = np.empty((n_imu, 3))
    nodes, weights = np.polynomial.legendre.leggauss(config.oversample)
    bps = profile.breakpoints_s
    block = max(1, int(config.block_s / dt))
    for k0 in range(0, n_imu, block):
        k1 = min(n_imu, k0 + block)
        edges = np.arange(k0, k1 + 1).astype(np.float64) * dt
        gyro[k0:k1], accel[k0:k1] = _interval_means(true_fx, profile, errors, edges, bps,
                                                    nodes, weights)
        if progress is not None:
            progress(k1 / n_imu)

    drift_g = np.zeros((n_imu, 3))
    drift_a = np.zeros((n_imu, 3))
    if config.noise:
        drift_g = _bias_drift(rng_noise, n_imu, dt, grade.gyro_bias_instability_rad_s,
                              grade.gyro_bias_correlation_s,
                              grade.gyro_bias_random_walk_rad_s2_rt_hz)
        drift_a = _bias_drift(rng_noise, n_imu, dt, grade.accel_bias_instability_m_s2,
                              grade.accel_bias_correlation_s,
                              grade.accel_bias_random_walk_m_s3_rt_hz)
        gyro += drift_g + rng_noise.normal(0.0, grade.gyro_noise_rad_s_rt_hz / math.sqrt(dt),
                                           (n_imu, 3))
        accel += drift_a + rng_noise.normal(0.0, grade.accel_noise_m_s2_rt_hz / math.sqrt(dt),
                                            (n_imu, 3))
    if config.quantize:
        gyro = quantize_means(gyro, dt, grade.gyro_quantization_rad)
        accel = quantize_means(accel, dt, grade.accel_quantization_m_s)

    joints = _joint_states(profile, config, rng_enc)
    truth = CalibrationResult(
        errors=errors, sigma=SensorErrors.zeros(), frame_id=config.frame_id,
        extra={
            'mounting': {'rpy_rad': [float(x) for x in drpy], 'xyz_m': [float(x) for x in dxyz]},
            **({'chain_errors': chain_truth} if chain_truth else {}),
            'noise': grade.noise_dict() if config.noise else {},
            # the turn-on biases above plus the simulated in-run drift at the last sample:
            # what an estimator that tracks the total bias should end at
            'bias_at_end': {
                'gyro_rad_s': [float(x) for x in errors.gyro_bias_rad_s + drift_g[-1]],
                'accel_m_s2': [float(x) for x in errors.accel_bias_m_s2 + drift_a[-1]]},
            'provenance': {'generator': 'imu_calib_ros.core.simulator', 'grade': grade.name,
                           'plan': profile.plan_name, 'fixture': fixture.source or '',
                           'seed': int(config.seed), 'imu_rate_hz': float(config.imu_rate_hz),
                           'joint_rate_hz': float(config.joint_rate_hz),
                           'oversample': int(config.oversample),
                           'duration_s': float(profile.duration_s)},
        })
    return SimResult(ImuBatch(stamps, gyro, accel, config.frame_id), joints, truth, true_fx,
                     profile, config, drift_g, drift_a)


def _interval_means(fx: Fixture, profile: JointProfile, errors: SensorErrors,
                    edges: FloatArray, bps: FloatArray, nodes: FloatArray,
                    weights: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Mean of the forward model over each interval ``[edges[i], edges[i+1]]``.

    Each interval is split at the profile breakpoints inside it and every piece gets its own
    Gauss-Legendre rule, so the integrand is smooth on every piece.
    """
    inner = bps[(bps > edges[0]) & (bps < edges[-1])]
    cuts = np.union1d(edges, inner)
    a, b = cuts[:-1], cuts[1:]
    keep = b - a > 1e-15
    a, b = a[keep], b[keep]
    owner = np.clip(np.searchsorted(edges, 0.5 * (a + b), side='right') - 1, 0,
                    len(edges) - 2)
    half = 0.5 * (b - a)
    t = (0.5 * (a + b))[:, None] + half[:, None] * nodes[None, :]  # (S, m)
    w = half[:, None] * weights[None, :]  # (S, m), sums to the piece length
    q, qd, qdd = profile.evaluate(t.ravel())
    kin = fx.kinematics(q, qd, qdd)
    g, f = measure(errors, kin.omega_ib_imu_rad_s, kin.omega_dot_ib_imu_rad_s2, kin.f_imu_m_s2)
    n_int = len(edges) - 1
    own = np.repeat(owner, len(nodes))
    wf = w.ravel()[:, None]
    g_sum = np.zeros((n_int, 3))
    f_sum = np.zeros((n_int, 3))
    np.add.at(g_sum, own, g * wf)
    np.add.at(f_sum, own, f * wf)
    length = np.diff(edges)[:, None]
    return g_sum / length, f_sum / length


def _bias_drift(rng: np.random.Generator, n: int, dt: float, sigma: float, tau_s: float,
                rw_density: float) -> FloatArray:
    """Gauss-Markov (steady state sigma, correlation tau) + random walk, exact at step dt."""
    out = np.zeros((n, 3))
    if sigma > 0:
        phi = math.exp(-dt / tau_s)
        drive = rng.normal(0.0, sigma * math.sqrt(1.0 - phi * phi), (n, 3))
        b0 = rng.normal(0.0, sigma, 3)  # start in the stationary distribution
        for i in range(3):  # b[k] = phi b[k-1] + w[k], via scipy's IIR filter
            out[:, i] = lfilter([1.0], [1.0, -phi], drive[:, i], zi=[phi * b0[i]])[0]
    if rw_density > 0:
        out += np.cumsum(rng.normal(0.0, rw_density * math.sqrt(dt), (n, 3)), axis=0)
    return out


def quantize_means(mean: FloatArray, dt: float, quantum: float) -> FloatArray:
    """Quantise the increments ``mean * dt`` to multiples of ``quantum``, carrying the residual.

    The running sum of output increments never differs from the true running sum by more
    than half a quantum (an integrating IMU's pulse counter). ``quantum <= 0``: unchanged.
    """
    if quantum <= 0:
        return mean
    total = np.cumsum(mean * dt, axis=0)
    counts = np.round(total / quantum)
    out = np.diff(np.vstack([np.zeros((1, mean.shape[1])), counts]), axis=0) * quantum
    return out / dt


def _joint_states(profile: JointProfile, config: SimConfig,
                  rng: np.random.Generator) -> JointBatch:
    dt_ns = int(round(1e9 / config.joint_rate_hz))
    m = int(math.floor(profile.duration_s / (dt_ns * 1e-9) + 1e-9)) + 1
    k = np.arange(m, dtype=np.int64)
    t = k * dt_ns * 1e-9
    q, qd, _ = profile.evaluate(t)
    if config.noise and config.encoder_noise_rad > 0:
        q = q + rng.normal(0.0, config.encoder_noise_rad, q.shape)
    if config.wrap_joint_positions:
        q = math.pi - np.mod(math.pi - q, 2.0 * math.pi)  # (-pi, pi]
    return JointBatch(config.start_stamp_ns + k * dt_ns, tuple(profile.joint_names), q,
                      qd.copy() if config.joint_velocities else None)
