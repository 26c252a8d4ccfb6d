"""EstimatorConfig: which error states are estimated, update rates, noise, gating, initialisation.

The frozen dataclass is the single source of defaults and validation (STYLE 5); the shipped
``config/estimator.yaml`` (navigation grade) and ``config/estimator_mems.yaml`` hold the same
keys. Load a file with :func:`load_estimator_config`.
"""
from __future__ import annotations

import os
from dataclasses import dataclass
from typing import Literal

from .. import parameters as registry
from ..config import load_config, resolve_config_file, setting

__all__ = ['EstimatorConfig', 'load_estimator_config']




#: groups switched by another setting than ``estimate_<group>`` (one switch for both kernels)
_SWITCH = {'gyro_sample_kernel': 'estimate_sample_kernel',
           'accel_sample_kernel': 'estimate_sample_kernel'}


@dataclass(frozen=True)
class EstimatorConfig:
    """Configuration of :class:`~imu_calib_ros.core.estimator.CalibrationEstimator`.

    Groups switched off are held at their assumed value (zero) and written to the calibration
    file as fixed (CONTRACT 4).
    """

    # --- state groups (CONTRACT 3 names) -------------------------------------------------
    estimate_gyro_bias: bool = setting(True, 'estimate the gyro biases bg (3)')
    estimate_gyro_scale: bool = setting(True, 'estimate the gyro scale factors diag(Kg) (3)')
    estimate_gyro_asymmetry: bool = setting(True, 'estimate the gyro scale asymmetries ag (3)')
    estimate_gyro_misalignment: bool = setting(True,
                                               'estimate the symmetric gyro misalignments (3)')
    estimate_gyro_g_sensitivity: bool = setting(True, 'estimate the gyro g-sensitivity G (9); '
                                           'dropped when the grade gives it sigma 0')
    estimate_accel_bias: bool = setting(True, 'estimate the accelerometer biases ba (3)')
    estimate_accel_scale: bool = setting(True, 'estimate the accelerometer scale diag(Ka) (3)')
    estimate_accel_asymmetry: bool = setting(True,
                                             'estimate the accelerometer asymmetries aa (3)')
    estimate_accel_misalignment: bool = setting(True, 'estimate the accel misalignments (6)')
    estimate_accel_quadratic: bool = setting(True, 'estimate the accel quadratic terms qa (3)')
    estimate_size_effect: bool = setting(True, 'estimate the six size-effect coordinates r_ij')
    estimate_lever_arm: bool = setting(True,
                                       'estimate the reference point offset rho from the axes')
    estimate_time_offset: bool = setting(False, 'estimate the accel-minus-gyro time offset (1)')
    estimate_sample_kernel: bool = setting(
        True, "estimate the gyros' and the accelerometers' sampling kernels (2): 0 interval "
        'means, 1 point samples (a point sample read as a mean is (omega dt)^2 / 24 too large '
        'in a turn)')
    # --- measurements --------------------------------------------------------------------
    update_rate_hz: float = setting(10.0, 'rate of the zero-velocity (lever-arm) updates', 0.1,
                                    1000.0)
    # 1e-6: the pseudo-measurement itself is exact on a rigid fixture; with 5e-6 the mean NIS
    # of the velocity updates was 2.50 (of 3) on srt_then_kozlov at 200 Hz, with 1e-6 it is
    # 2.95 and every calibration sigma is unchanged to < 0.3 % (bench/bench_accuracy.py).
    velocity_sigma_m_s: float = setting(1e-6, 'one-sigma noise of the velocity measurement', 1e-9)
    attitude_aiding: bool = setting(False,
                                    'attitude updates from the joint encoders + mounting states')
    attitude_sigma_rad: float = setting(1e-4,
                                        'one-sigma noise of the encoder attitude measurement',
                                        1e-9)
    # --- general chains (issue 15: an arm as the turntable; no effect on a turntable) --------
    chain_joint_offset_sigma_rad: float = setting(
        1e-3, 'one sigma of the chain\'s joint zero offsets (uncalibrated arm: ~1 mrad): the '
        'prior of their states (or, with estimate_joint_offset off, their bound in the chain '
        'velocity and encoder attitude noise)', 0.0)
    estimate_joint_offset: bool = setting(
        True, 'general chains, and turntables with encoder attitude aiding: estimate the zero '
        'offsets of the revolute joints before the last (one state each; the last one is the '
        'mounting); off: bounded in the measurement noise (chains) or not modelled (tables)')
    chain_link_sigma_m: float = setting(
        2e-3, 'one sigma of the chain\'s joint-origin errors, per coordinate', 0.0)
    chain_encoder_sigma_rad: float = setting(
        1e-5, 'one sigma of the encoder noise, for the chain velocity from the joint states', 0.0)
    chain_error_correlation: float = setting(
        50.0, 'updates over which one arm error stays the same (its bound per update is '
        'multiplied by the square root of this: a systematic error is not averaged away)', 1.0)
    gate_probability: float = setting(0.99999, 'chi-square gate: innovations beyond this '
                                 'quantile count as gated (1 disables the gate)', 0.5, 1.0)
    level_coupling: bool = setting(
        False, 'P0 correlates the levelled tilt with the accelerometer errors (the tilt is what '
        'cancels them at the first pose: alignment.level_coupling); off (default, docs/'
        'ESTIMATOR.md "Init"): tilt independent')
    gate_action: Literal['deweight', 'reject'] = setting(
        'deweight', "a gated innovation: 'deweight' uses it with R inflated until its NIS meets "
        "the gate (Chang 2014: a bounded step, almost none for a gross outlier), 'reject' "
        'drops it (one marginal innovation could start a cascade of gated updates)')
    # 1 s blocks (10 updates), live and offline alike (issue 16 item 10: one computation; 5 s
    # blocks offline differed from the node's 1 s by up to 0.72 sigma, and on a 34 s plan of
    # 3 s flips they diverged or re-aligned in 3 of 3 seeds where 1 s blocks passed; they
    # cost 11-22 % more CPU than 5 s blocks: docs/ESTIMATOR.md)
    block_chunks: int = setting(10, 'updates per block between feedbacks to the navigator', 1,
                                1000)
    # --- initialisation --------------------------------------------------------------------
    init_window_s: float = setting(2.0, 'stationary window for coarse alignment', 0.1, 600.0)
    stationary_joint_tolerance_rad: float = setting(1e-4, 'joint travel allowed in the window',
                                                    0.0)
    initial_tilt_sigma_rad: float = setting(2e-3, 'prior sigma of the levelled tilt', 1e-9)
    initial_heading_sigma_rad: float = setting(5e-3, 'prior sigma of the fixture heading', 1e-9)
    initial_velocity_sigma_m_s: float = setting(1e-3, 'prior sigma of the initial velocity', 1e-9)
    lever_arm_sigma_m: float = setting(0.05, 'prior sigma of the reference point offset', 1e-9)
    mounting_sigma_rad: float = setting(3e-3, 'least prior sigma of the mounting rotation', 1e-9)
    time_offset_sigma_s: float = setting(1e-3, 'prior sigma of the time offset', 1e-12)
    sample_kernel_sigma: float = setting(
        2.0, "prior sigma of the sampling kernels about the declared imu_sample_type's (point "
        'samples are 1 from interval means)', 1e-6)
    prior_sigma_scale: float = setting(1.0, 'multiplies the grade sigmas used as the prior', 1e-3)
    noise_source: Literal['grade', 'data'] = setting(
        'data', "process noise measured from the stationary windows ('data', Allan deviation "
        "via allantools; needs auto_start), or taken from the IMU grade file ('grade')")
    noise_scale: float = setting(1.0, 'multiplies the white-noise densities used in Q', 0.01)
    # --- the data choose the start (issue 11) -----------------------------------------------
    auto_start: bool = setting(True, 'coarse start from the data before the filter: noise, '
                               'joint latency, gyro and accel errors and the mounting, priors '
                               'centred there (core/estimator/coarse.py)')
    bootstrap_min_s: float = setting(60.0, 'least data gathered for the coarse start before the '
                                     'filter starts (live: then as soon as it is determined)',
                                     1.0)
    bootstrap_max_s: float = setting(600.0, 'most data held for the coarse start', 10.0)
    prior_inflation: float = setting(3.0, 'prior sigma = this x the coarse start sigma (never '
                                     'below the grade hint)', 1.0)
    imu_sample_type: Literal['mean', 'point'] = setting(
        'mean', "IMU values are interval means stamped at the interval end (CONTRACT 1), or "
        "instantaneous 'point' samples")
    aiding_gyro_noise_rad_s_rt_hz: float = setting(
        1e-5, 'encoder attitude aiding switches itself on when the measured gyro white noise is '
        'above this (the gyros cannot hold attitude over a plan)', 0.0)
    walk_profile: bool = setting(True, 'offline replay of a MEMS unit without a grade: its gyro '
                                 'bias walk chosen by the innovations\' likelihood over whole '
                                 'passes (2-7 more passes, typically 4), not the assumed floor')
    max_restarts: int = setting(3, 'a diverged filter restarts from the coarse start with '
                                'inflated covariance this many times before giving up', 0, 100)
    settle_s: float = setting(30.0, 'after a re-alignment or restart (the filter left its linear '
                              'region), feedback after every update for this long', 0.0)
    cascade_updates: int = setting(10, 'this many gated updates in a row re-align the navigation '
                                   '(calibration states and covariance kept)', 2, 100000)
    max_pending_s: float = setting(2.0, 'longest wait for joint states before updating without '
                              'attitude aiding', 0.01)

    @property
    def estimated_groups(self) -> tuple[str, ...]:
        """The sensor-error and auxiliary groups switched on, in state order."""
        names = (g.name for g in registry.GROUPS if g.name != 'mounting')  # state order
        out = [n for n in names if getattr(self, _SWITCH.get(n, f'estimate_{n}'))]
        if self.attitude_aiding:
            out.append('mounting')
        return tuple(out)


def load_estimator_config(name_or_path: str | os.PathLike[str] | None) -> EstimatorConfig:
    """Load a config file (path, or a shipped name such as ``'estimator_mems'``).

    ``None`` gives the defaults. Errors are :class:`~imu_calib_ros.core.errors.ConfigError`.
    """
    if name_or_path is None:
        return EstimatorConfig()
    path = resolve_config_file(str(name_or_path), '.')
    return load_config(EstimatorConfig, path)
