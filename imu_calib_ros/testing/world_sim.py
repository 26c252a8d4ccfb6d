"""The "world": an independent turntable/IMU bag generator that follows CONTRACT sections 1-3.

This is a test oracle written from ``docs/CONTRACT.md`` alone. It shares no code
with ``core/simulator.py``, ``core/fixture.py``, ``core/sensor_model.py``,
``core/strapdown.py`` or ``core/estimator``, so an assumption those modules share cannot hide
here. The only imports from the package are ``core.plans`` (the joint motion q(t) is the
input, not the assumption at risk; ``build_profile`` needs a ``core.fixture.Fixture`` to map a
plan's IMU-axis steps onto the joints, and that object is used for nothing else). Bags are
written with ``rosbags`` directly, not with ``msg_adapters``.

Physics (CONTRACT 2, 3), all at the level an estimator resolves (urad, ppm, 0.1 mm):

- Attitude: ``R_enu_imu = Rot(a_1, q_1) ... Rot(a_n, q_n) R_rpy R_mount`` with the nominal
  ``R_rpy = Rz(yaw) Ry(pitch) Rx(roll)`` of the fixture file and a mounting error
  ``R_mount`` (any rotation, in the IMU frame). The IMU reference point is at
  ``Rot(a_1, q_1) ... Rot(a_n, q_n) (xyz_nominal + offset)`` from the axes' common point.
- Rates: the angular rate and acceleration relative to inertial space are propagated
  outward through the joint frames, starting from the earth rate
  ``Omega (0, cos lat, sin lat)`` of the ENU frame (which is constant in ENU coordinates)::

      omega_i = R_i^T omega_{i-1} + a_i qd_i
      alpha_i = R_i^T alpha_{i-1} + (R_i^T omega_{i-1}) x a_i qd_i + a_i qdd_i

  (``R_i = Rot(a_i, q_i)`` maps frame i to frame i-1), then rotated into the IMU frame.
- Specific force of a body point y (IMU frame), rigid-body form: the axes' common point is
  earth-fixed and feels ``+g`` up (normal gravity contains the centrifugal term), so
  ``f(y) = R_imu_enu (0, 0, g) + alpha x y + omega x (omega x y)``, with the INERTIAL omega
  and alpha. Expanded, this is ``a + 2 Omega x v + Omega x (Omega x p) - g_enu`` of the
  point (Coriolis and the earth's centripetal term of the offset included). Gravity is the
  fixture's ``gravity_m_s2`` or WGS-84 normal gravity (Somigliana, 2nd-order free-air),
  written here from TR8350.2.
- Sensors (CONTRACT 3): gyros ``omega + Kg omega + ag |omega| + G f + bg``; accelerometer i
  reads component i of ``f`` at its own point ``x + r_i`` (this IS
  ``f_i + (omega_dot x r_i + omega x (omega x r_i))_i``, computed as a second body point), plus
  ``Ka f + aa |f| + qa f^2 + ba`` of the reference-point ``f``.
- Samples (CONTRACT 1): ``interval_mean`` (default: the mean over ``(t_{k-1}, t_k]``,
  stamped at ``t_k``; Gauss-Legendre per piece between the plan's breakpoints, and the
  pieces that hold a zero crossing of a component under ``|.|`` are split at the root found
  by bisection, so the asymmetry terms are integrated exactly too) or ``point`` (the
  instantaneous value at the stamp).
- Noise: white (per-sample std ``N / sqrt(dt)`` for either sample type), Gauss-Markov bias
  instability (stationary start) plus bias random walk, continuing across the run and held
  over each interval; optional quantisation (increments with carried residual, or values).
- Joint states at their own rate; ``stamp = true time + latency`` (CONTRACT 1: up to +-50 ms);
  encoder noise; optional wrapping to (-pi, pi], velocities, joint-name order and an extra
  joint; optional burst drops of IMU samples and joint states; optional rosbag2-like log
  times (``log = stamp + U(1.5, 2.5) ms`` receipt delay, so 2 kHz data are logged out of
  header-stamp order; the header keeps the true stamp).

Truth file: CONTRACT 4 layout (``imu_calibration:`` with ``gyroscope``, ``accelerometer``,
all-zero ``sigma``, ``fixed: []``), the turn-on biases in ``bias``, plus ``bias_at_end``
(turn-on + drift at the last sample, what a filter tracking the total bias reports),
``mounting``, ``reference_point``, ``time``, ``noise``, ``unit`` and ``provenance``.

Entry points: :func:`generate` (arrays), :func:`write_bag`, :func:`write_truth`,
:func:`simulate_to_files`; :func:`joint_profile` for a plan on a fixture file.
"""
from __future__ import annotations

import math
import os
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np
import yaml
from numpy.typing import ArrayLike, NDArray
from scipy.signal import lfilter
from scipy.spatial.transform import Rotation

from .world_units import UNIT_KINDS, Unit, UnitErrors, UnitNoise, draw_unit

FloatArray = NDArray[np.float64]

__all__ = ['EARTH_RATE_RAD_S', 'UNIT_KINDS', 'BodyMotion', 'Mounting', 'Unit', 'UnitErrors',
           'UnitNoise', 'WorldConfig', 'WorldData', 'WorldFixture', 'body_motion',
           'draw_mounting', 'draw_unit', 'generate', 'joint_profile', 'normal_gravity',
           'sensor_outputs', 'simulate_to_files', 'specific_force_imu', 'write_bag',
           'write_truth']

#: WGS-84 defining earth rotation rate [rad/s] (NIMA TR8350.2, Table 3.1). ``core.earth``
#: uses 7.2921151467e-5 (GRS-80); the 2e-8 relative difference is 1.5e-12 rad/s (3e-7 deg/h).
EARTH_RATE_RAD_S = 7.292115e-5
# WGS-84 (TR8350.2 Tables 3.1-3.3)
_A_M = 6378137.0
_F = 1.0 / 298.257223563
_GM_M3_S2 = 3.986004418e14
_GAMMA_E = 9.7803253359
_GAMMA_P = 9.8321849378
_B_M = _A_M * (1.0 - _F)
_E2 = _F * (2.0 - _F)
_M = EARTH_RATE_RAD_S ** 2 * _A_M ** 2 * _B_M / _GM_M3_S2
_K = _B_M * _GAMMA_P / (_A_M * _GAMMA_E) - 1.0

SAMPLE_TYPES = ('interval_mean', 'point', 'lowpass')
#: sub-steps per sample period of the ``'lowpass'`` filter (its input linear across each)
LOWPASS_SUBSTEPS = 20
GENERATOR = 'imu_calib_ros.testing.world_sim'


def normal_gravity(latitude_rad: float, height_m: float) -> float:
    """WGS-84 normal gravity [m/s^2] (TR8350.2 eq. 4-1 Somigliana, eq. 4-3 free-air).

    ``g0 = gamma_e (1 + k sin^2 lat) / sqrt(1 - e^2 sin^2 lat)``,
    ``g = g0 (1 - 2 h / a (1 + f + m - 2 f sin^2 lat) + 3 h^2 / a^2)``.
    """
    s2 = math.sin(latitude_rad) ** 2
    g0 = _GAMMA_E * (1.0 + _K * s2) / math.sqrt(1.0 - _E2 * s2)
    h = height_m
    return g0 * (1.0 - 2.0 * h / _A_M * (1.0 + _F + _M - 2.0 * _F * s2)
                 + 3.0 * h * h / (_A_M * _A_M))


# ------------------------------------------------------------------------------ fixture
@dataclass(frozen=True)
class WorldFixture:
    """A fixture file (CONTRACT 2), parsed here on its own.

    ``earth_rate_rad_s`` is a field only so that self-checks can switch the earth off.
    """

    latitude_rad: float
    height_m: float
    gravity_m_s2: float | None
    joint_names: tuple[str, ...]
    joint_axes: FloatArray  # (n, 3) unit vectors, each in its parent frame
    rpy_nominal_rad: FloatArray  # (3,) roll, pitch, yaw
    xyz_nominal_m: FloatArray  # (3,) in the innermost joint frame
    source: str = ''
    earth_rate_rad_s: float = EARTH_RATE_RAD_S

    @classmethod
    def from_yaml(cls, path: str | os.PathLike[str]) -> 'WorldFixture':
        """Read a CONTRACT 2 fixture file."""
        with open(path, encoding='utf-8') as fh:
            d = yaml.safe_load(fh)
        return cls.from_dict(d, str(path))

    @classmethod
    def from_dict(cls, d: dict[str, Any], source: str = '') -> 'WorldFixture':
        """From the CONTRACT 2 mapping (degrees in the file)."""
        site, imu = d['site'], d['imu']
        axes = np.array([j['axis'] for j in d['joints']], dtype=float)
        axes /= np.linalg.norm(axes, axis=1, keepdims=True)
        g = site.get('gravity_m_s2')
        return cls(math.radians(float(site['latitude_deg'])), float(site['height_m']),
                   None if g is None else float(g), tuple(str(j['name']) for j in d['joints']),
                   axes, np.radians(np.asarray(imu['rpy_deg'], dtype=float)),
                   np.asarray(imu['xyz_m'], dtype=float), source)

    @property
    def n_joints(self) -> int:
        """Number of joints."""
        return len(self.joint_names)

    @property
    def gravity(self) -> float:
        """Gravity magnitude [m/s^2]: the file's ``gravity_m_s2``, else normal gravity."""
        if self.gravity_m_s2 is not None:
            return self.gravity_m_s2
        return normal_gravity(self.latitude_rad, self.height_m)

    @property
    def omega_ie_enu(self) -> FloatArray:
        """Earth rate in ENU [rad/s]."""
        return self.earth_rate_rad_s * np.array(
            [0.0, math.cos(self.latitude_rad), math.sin(self.latitude_rad)])

    @property
    def R_joint_imu_nominal(self) -> Rotation:
        """``Rz(yaw) Ry(pitch) Rx(roll)`` (extrinsic x, y, z)."""
        return Rotation.from_euler('xyz', self.rpy_nominal_rad)


@dataclass(frozen=True)
class Mounting:
    """True mounting error: ``R_mount = exp([rotvec x])`` (IMU frame), reference-point offset.

    ``offset_m`` is in the innermost joint frame (added to the fixture's ``xyz_m``).
    """

    rotvec_rad: FloatArray = field(default_factory=lambda: np.zeros(3))
    offset_m: FloatArray = field(default_factory=lambda: np.zeros(3))

    @property
    def rotation(self) -> Rotation:
        """``R_mount`` as a scipy rotation."""
        return Rotation.from_rotvec(np.asarray(self.rotvec_rad, dtype=float))


def draw_mounting(max_angle_deg: float, max_offset_m: float, rng: np.random.Generator,
                  min_angle_deg: float = 0.0, min_offset_m: float = 0.0) -> Mounting:
    """A mounting error about a uniformly random axis, offset in a uniformly random direction.

    Angle uniform in ``[min_angle_deg, max_angle_deg]``, offset length uniform in
    ``[min_offset_m, max_offset_m]``.
    """
    def direction() -> FloatArray:
        v = rng.normal(size=3)
        return v / np.linalg.norm(v)
    ang = math.radians(rng.uniform(min_angle_deg, max_angle_deg))
    return Mounting(direction() * ang, direction() * rng.uniform(min_offset_m, max_offset_m))


# --------------------------------------------------------------------------- kinematics
@dataclass(frozen=True)
class BodyMotion:
    """Motion of the IMU body frame at N instants (CONTRACT 3 quantities, IMU frame)."""

    R_enu_imu: Rotation  # N rotations
    omega_ib_imu_rad_s: FloatArray  # (N, 3) rate relative to inertial space
    omega_dot_ib_imu_rad_s2: FloatArray  # (N, 3) its time derivative
    f_origin_imu_m_s2: FloatArray  # (N, 3) specific force at the axes' common point
    ref_imu_m: FloatArray  # (3,) the reference point from the common point, IMU frame


def body_motion(fx: WorldFixture, mounting: Mounting, q: ArrayLike, qd: ArrayLike,
                qdd: ArrayLike, base: Rotation | None = None) -> BodyMotion:
    """Attitude, inertial rate and angular acceleration of the IMU (module docstring).

    Parameters
    ----------
    fx : WorldFixture
    mounting : Mounting
    q, qd, qdd : (N, n) array_like
        Joint angles [rad], rates [rad/s], accelerations [rad/s^2].
    base : Rotation, optional
        The table's base (the first joint's parent frame) in ENU: a table not levelled
        (``WorldConfig.base_tilt_rad``); None: the base is ENU, as the fixture file says.
    """
    q, qd, qdd = (np.atleast_2d(np.asarray(x, dtype=float)) for x in (q, qd, qdd))
    n_t = q.shape[0]
    omega = np.tile(fx.omega_ie_enu, (n_t, 1))  # ENU frame: inertial rate, constant in ENU
    if base is not None:
        omega = base.inv().apply(omega)  # in the base frame
    alpha = np.zeros((n_t, 3))
    chain: Rotation | None = None
    for i in range(fx.n_joints):
        a = fx.joint_axes[i]
        R_i = Rotation.from_rotvec(q[:, i:i + 1] * a[None, :])
        w_in = R_i.inv().apply(omega)
        rate = qd[:, i:i + 1] * a[None, :]
        omega = w_in + rate
        alpha = R_i.inv().apply(alpha) + np.cross(w_in, rate) + qdd[:, i:i + 1] * a[None, :]
        chain = R_i if chain is None else chain * R_i
    assert chain is not None
    R_n_imu = fx.R_joint_imu_nominal * mounting.rotation
    R_enu_imu = chain * R_n_imu if base is None else base * chain * R_n_imu
    ref_imu = R_n_imu.inv().apply(fx.xyz_nominal_m + np.asarray(mounting.offset_m, float))
    f0 = R_enu_imu.inv().apply(np.array([0.0, 0.0, fx.gravity]))
    return BodyMotion(R_enu_imu, R_n_imu.inv().apply(omega), R_n_imu.inv().apply(alpha),
                      np.atleast_2d(f0), ref_imu)


def specific_force_imu(m: BodyMotion, point_imu_m: ArrayLike) -> FloatArray:
    """Specific force [m/s^2] of a body point (IMU frame, from the axes' common point), (N, 3).

    Rigid body: ``f(y) = f(0) + alpha x y + omega x (omega x y)`` (Kozlov & Kapralov eq. 1
    is this relation between two points of the body).
    """
    y = np.broadcast_to(np.asarray(point_imu_m, dtype=float), m.omega_ib_imu_rad_s.shape)
    w = m.omega_ib_imu_rad_s
    return m.f_origin_imu_m_s2 + np.cross(m.omega_dot_ib_imu_rad_s2, y) + \
        np.cross(w, np.cross(w, y))


def sensor_outputs(e: UnitErrors, m: BodyMotion) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Noise-free instantaneous outputs (CONTRACT 3): gyro [rad/s], accel [m/s^2], f_ref.

    Returns
    -------
    gyro_rad_s, accel_m_s2, f_ref_imu_m_s2 : (N, 3)
    """
    w = m.omega_ib_imu_rad_s
    f = specific_force_imu(m, m.ref_imu_m)
    gyro = (w + w @ e.gyro_scale_misalignment.T + e.gyro_scale_asymmetry * np.abs(w)
            + f @ e.gyro_g_sensitivity_rad_s_per_m_s2.T + e.gyro_bias_rad_s)
    f_own = np.empty_like(f)
    for i in range(3):  # accelerometer i at its own point x + r_i
        f_own[:, i] = specific_force_imu(m, m.ref_imu_m + e.size_effect_m[i])[:, i]
    accel = (f_own + f @ e.accel_scale_misalignment.T + e.accel_scale_asymmetry * np.abs(f)
             + e.accel_quadratic_per_m_s2 * f * f + e.accel_bias_m_s2)
    return gyro, accel, f


# ------------------------------------------------------------------------------ config
@dataclass(frozen=True)
class WorldConfig:
    """Sampling, timing and output options of one generated bag (see module docstring).

    ``joint_latency_s``: joint stamp = true time + latency. ``drop_fraction_*``: fraction of
    messages lost in bursts of geometric length (mean ``drop_burst_mean``).
    ``receipt_delay_s``: None (log time = header stamp) or (lo, hi) uniform receipt delay.
    ``imu_stamp_jitter_s``, ``joint_stamp_jitter_s``: header stamps taken on receipt by the
    host, ``U(0, jitter)`` after the true instant (kept increasing); the values stay those of
    the true instants (an IMU's interval mean is over its own clock's interval).
    ``joint_on_change_rad``: > 0 publishes a joint state only when some joint moved by more
    than this since the last one published (a driver that is silent while the table stands).
    ``joint_order``: 'fixture', 'reversed' or 'shuffled'; ``extra_joint``: add a joint the
    fixture does not know (CONTRACT 1: ignored by consumers). ``encoder_zero_rad``: each
    joint's encoder reads its true angle minus this (a table whose zero references are off:
    the fixture file knows none of it), one value per fixture joint, or empty for none.
    ``base_tilt_rad``: the table's base not levelled, a rotation about ENU east and north
    [rad] of the first joint's parent frame (the fixture file says it is ENU).
    ``sample_type`` ``'lowpass'``: point samples of the sensors' output through a first-order
    low-pass filter of time constant ``lowpass_tau_s`` (a MEMS part's digital filter;
    ``lowpass_tau_accel_s`` > 0: the accelerometers' own, another delay than the gyros'), the
    white noise filtered with it (its density kept at low frequencies); bias drifts and
    quantisation after the filter.
    """

    imu_rate_hz: float = 100.0
    sample_type: str = 'interval_mean'
    joint_rate_hz: float = 100.0
    joint_latency_s: float = 0.0
    encoder_noise_rad: float = 1e-6
    encoder_zero_rad: tuple[float, ...] = ()
    base_tilt_rad: tuple[float, float] = (0.0, 0.0)
    lowpass_tau_s: float = 0.0
    lowpass_tau_accel_s: float = 0.0
    wrap_joints: bool = False
    joint_velocities: bool = True
    joint_order: str = 'fixture'
    extra_joint: bool = False
    noise: bool = True
    quantize: bool = True
    drop_fraction_imu: float = 0.0
    drop_fraction_joint: float = 0.0
    drop_burst_mean: float = 5.0
    receipt_delay_s: tuple[float, float] | None = None
    imu_stamp_jitter_s: float = 0.0
    joint_stamp_jitter_s: float = 0.0
    joint_on_change_rad: float = 0.0
    gl_nodes: int = 6
    start_stamp_ns: int = 1_715_000_000_123_456_789
    frame_id: str = 'imu_link'
    imu_topic: str = '/imu/data_raw'
    joint_topic: str = '/joint_states'
    storage: str = 'mcap'
    block: int = 4096

    def __post_init__(self) -> None:
        if self.sample_type not in SAMPLE_TYPES:
            raise ValueError(f'sample_type must be one of {SAMPLE_TYPES}')
        if (self.sample_type == 'lowpass') != (self.lowpass_tau_s > 0.0):
            raise ValueError("lowpass_tau_s > 0 goes with sample_type 'lowpass' (only)")
        if self.joint_order not in ('fixture', 'reversed', 'shuffled'):
            raise ValueError('joint_order must be fixture, reversed or shuffled')
        if not 0.0 <= self.drop_fraction_imu < 0.5 or not 0.0 <= self.drop_fraction_joint < 0.5:
            raise ValueError('drop fractions must be in [0, 0.5)')
        if min(self.imu_stamp_jitter_s, self.joint_stamp_jitter_s,
               self.joint_on_change_rad) < 0.0:
            raise ValueError('stamp jitters and joint_on_change_rad must be >= 0')


@dataclass(frozen=True, eq=False)
class WorldData:
    """Generated messages (after drops) and the truth mapping (truth file content)."""

    imu_stamps_ns: NDArray[np.int64]
    gyro_rad_s: FloatArray
    accel_m_s2: FloatArray
    imu_log_ns: NDArray[np.int64]
    joint_stamps_ns: NDArray[np.int64]
    joint_names: tuple[str, ...]
    joint_position_rad: FloatArray  # (M, len(joint_names)) in message order
    joint_velocity_rad_s: FloatArray | None
    joint_log_ns: NDArray[np.int64]
    gyro_drift_rad_s: FloatArray  # (N, 3) stochastic bias part, kept samples
    accel_drift_m_s2: FloatArray
    truth: dict[str, Any]
    config: WorldConfig


# ------------------------------------------------------------------------- generation
class _Instant:
    """Noise-free instantaneous outputs at profile times (profile + fixture + unit)."""

    def __init__(self, fx: WorldFixture, profile: Any, mounting: Mounting, errors: UnitErrors,
                 base: Rotation | None = None):
        self.fx, self.profile, self.mounting, self.errors = fx, profile, mounting, errors
        self.base = base

    def __call__(self, t_s: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
        q, qd, qdd = self.profile.evaluate(np.asarray(t_s, dtype=float).ravel())
        m = body_motion(self.fx, self.mounting, q, qd, qdd, self.base)
        g, a, f = sensor_outputs(self.errors, m)
        return g, a, m.omega_ib_imu_rad_s, f


def _kink_components(e: UnitErrors) -> list[tuple[int, int]]:
    """(which, axis) under |.| with a non-zero coefficient; which 0 = omega, 1 = f."""
    out = [(0, i) for i in range(3) if e.gyro_scale_asymmetry[i] != 0.0]
    return out + [(1, i) for i in range(3) if e.accel_scale_asymmetry[i] != 0.0]


#: a sign change of a component below this magnitude is not worth splitting for
_KINK_FLOOR = (1e-13, 1e-11)  # rad/s, m/s^2


def _interval_means(inst: _Instant, edges: FloatArray, bps: FloatArray, nodes: FloatArray,
                    weights: FloatArray) -> FloatArray:
    """Mean of (gyro, accel) over each ``[edges[k], edges[k+1]]`` -> (K, 6).

    Pieces between the edges and the profile breakpoints get a Gauss-Legendre rule; a piece
    in which a component under ``|.|`` changes sign between its sample points is split at
    the root (bisection to 1e-15 s) and each part integrated on its own.
    """
    inner = bps[(bps > edges[0]) & (bps < edges[-1])]
    cuts = np.union1d(edges, inner)
    a, b = cuts[:-1], cuts[1:]
    keep = b - a > 1e-13
    a, b = a[keep], b[keep]
    kinks = _kink_components(inst.errors)

    def gl(a: FloatArray, b: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        half = 0.5 * (b - a)
        t = 0.5 * (a + b)[:, None] + half[:, None] * nodes[None, :]
        g, acc, w, f = inst(t)
        out = np.concatenate([g, acc], axis=1).reshape(len(a), len(nodes), 6)
        contrib = np.einsum('sm,smk->sk', half[:, None] * weights[None, :], out)
        comp = np.stack([w, f]).reshape(2, len(a), len(nodes), 3)
        return contrib, t, comp

    contrib, t_nodes, comp = gl(a, b)
    n_int = len(edges) - 1
    owner = np.clip(np.searchsorted(edges, 0.5 * (a + b), side='right') - 1, 0, n_int - 1)
    flagged = np.zeros(len(a), dtype=bool)
    brackets: list[tuple[NDArray[np.intp], FloatArray, FloatArray, int, int]] = []
    if kinks:
        _, _, w_e, f_e = inst(np.concatenate([a, b[-1:]]))
        ends = np.stack([w_e, f_e])  # (2, S+1, 3)
        for which, ax in kinks:
            vals = np.concatenate([ends[which, :-1, ax][:, None], comp[which, :, :, ax],
                                   ends[which, 1:, ax][:, None]], axis=1)  # (S, m+2)
            times = np.concatenate([a[:, None], t_nodes, b[:, None]], axis=1)
            big = np.max(np.abs(vals), axis=1) > _KINK_FLOOR[which]
            change = (np.sign(vals[:, :-1]) * np.sign(vals[:, 1:]) < 0) & big[:, None]
            s_idx, j_idx = np.nonzero(change)
            if len(s_idx):
                flagged[s_idx] = True
                brackets.append((s_idx, times[s_idx, j_idx], times[s_idx, j_idx + 1],
                                 which, ax))
    total = np.zeros((n_int, 6))
    np.add.at(total, owner[~flagged], contrib[~flagged])
    if flagged.any():
        roots = [_bisect(inst, s, lo, hi, which, ax) for s, lo, hi, which, ax in brackets]
        s_all = np.concatenate([r[0] for r in roots])
        t_all = np.concatenate([r[1] for r in roots])
        sub_a, sub_b, sub_o = [], [], []
        for s in np.nonzero(flagged)[0]:
            pts = np.unique(np.concatenate([[a[s]], t_all[s_all == s], [b[s]]]))
            pts = pts[(pts >= a[s]) & (pts <= b[s])]
            sub_a.append(pts[:-1])
            sub_b.append(pts[1:])
            sub_o.append(np.full(len(pts) - 1, owner[s]))
        sa, sb, so = (np.concatenate(x) for x in (sub_a, sub_b, sub_o))
        ok = sb - sa > 0.0
        c2, _, _ = gl(sa[ok], sb[ok])
        np.add.at(total, so[ok], c2)
    return total / np.diff(edges)[:, None]


def _bisect(inst: _Instant, s: NDArray[np.intp], lo: FloatArray, hi: FloatArray, which: int,
            ax: int) -> tuple[NDArray[np.intp], FloatArray]:
    """Roots of component ``ax`` of omega (which 0) or f (which 1) in brackets [lo, hi]."""
    lo, hi = lo.copy(), hi.copy()

    def val(t: FloatArray) -> FloatArray:
        _, _, w, f = inst(t)
        return (w if which == 0 else f)[:, ax]
    v_lo = val(lo)
    for _ in range(64):
        mid = 0.5 * (lo + hi)
        if np.all(hi - lo < 1e-15):
            break
        v_mid = val(mid)
        left = np.sign(v_mid) == np.sign(v_lo)
        lo = np.where(left, mid, lo)
        v_lo = np.where(left, v_mid, v_lo)
        hi = np.where(left, hi, mid)
    return s, 0.5 * (lo + hi)


def _bias_drift(rng: np.random.Generator, n: int, dt: float, sigma: float, tau: float,
                rw: float) -> FloatArray:
    """Gauss-Markov (stationary start, exact step ``dt``) plus random walk, (n, 3)."""
    out = np.zeros((n, 3))
    if sigma > 0.0:
        phi = math.exp(-dt / tau)
        x0 = rng.normal(0.0, sigma, 3)
        drive = rng.normal(0.0, sigma * math.sqrt(1.0 - phi * phi), (n, 3))
        for i in range(3):
            out[:, i] = lfilter([1.0], [1.0, -phi], drive[:, i], zi=[phi * x0[i]])[0]
    if rw > 0.0:
        out += np.cumsum(rng.normal(0.0, rw * math.sqrt(dt), (n, 3)), axis=0)
    return out


class _Lowpass:
    """Point samples of a first-order low-pass filter, ``tau y' = x - y``, of the sensors'
    output ``x`` (with its white noise, the samples' density at low frequency kept at the
    unit's: aliasing compensated), state carried across blocks; the
    filter starts settled on the first input. Exact for ``x`` linear across each of
    :data:`LOWPASS_SUBSTEPS` sub-steps a period (off by ``(h omega)^2 / 12`` of the signal
    for a sub-step ``h``: 8e-8 at 2 rad/s and 100 Hz; 7.5e-7 measured on a sinusoid at
    6 rad/s against the closed form)."""

    def __init__(self, tau_s: float, dt: float, noise: Any, rng: np.random.Generator,
                 tau_accel_s: float = 0.0) -> None:
        from scipy.signal import lfilter
        self._lfilter = lfilter
        h = dt / LOWPASS_SUBSTEPS
        self.h, self.dt = h, dt
        # (b, a, noise sd of the sub-steps) of the gyros' filter, then the accelerometers'
        # (``tau_accel_s`` 0: the gyros' tau; another: a relative delay between the sensors)
        self.filters = [self._coefficients(t, dt, h, nd) for t, nd in (
            (tau_s, noise.gyro_noise_rad_s_rt_hz),
            (tau_accel_s or tau_s, noise.accel_noise_m_s2_rt_hz))]
        self.sd = np.repeat([f[2] for f in self.filters], 3)
        self.rng = rng
        self.zi: list[FloatArray] | None = None  # lfilter's states, carried across blocks

    @staticmethod
    def _coefficients(tau_s: float, dt: float, h: float, density: float
                      ) -> tuple[FloatArray, FloatArray, float]:
        a = math.exp(-h / tau_s)
        b0 = tau_s * (1.0 - a) / h - a  # weight of the sub-step's start, then its end
        b1 = 1.0 - tau_s * (1.0 - a) / h
        # the samples' noise density at low frequency is N (the truth's): point samples of
        # filtered noise fold its high frequencies down, sum_m R(m) = sd^2 sum_r G_r^2 with
        # G_r the impulse response summed over every sub-step r (mod the period), so the
        # sub-steps' noise is N / sqrt(dt sum_r G_r^2) (N / sqrt(h) without aliasing)
        sub = LOWPASS_SUBSTEPS
        tail = (b0 + a * b1) * a ** np.arange(sub) / (1.0 - a ** sub)  # i = r + j sub, r >= 1
        g_r = np.concatenate([[b1 + tail[-1]], tail[:-1]])
        return (np.array([b1, b0]), np.array([1.0, -a]),
                density / math.sqrt(dt * float(np.sum(g_r ** 2))))

    def __call__(self, inst: Any, k0: int, k1: int) -> FloatArray:
        """Samples ``k0 + 1 .. k1`` (instants ``k dt``) of the output, ``(k1 - k0, 6)``."""
        sub = LOWPASS_SUBSTEPS
        t = np.arange(k0 * sub + 1, k1 * sub + 1, dtype=np.float64) * self.h
        g, acc, _, _ = inst(t)
        x = np.concatenate([g, acc], axis=1) + self.rng.normal(0.0, 1.0, (len(t), 6)) * self.sd
        if self.zi is None:  # settled on the first input: y = x0, no step
            g0, a0, _, _ = inst(np.array([k0 * self.dt]))
            x0 = np.concatenate([g0, a0], axis=1)[0]
            # b0 x0 + a y0 with y0 = x0 (a + b0 + b1 = 1)
            self.zi = [(1.0 - b[0]) * x0[3 * i:3 * i + 3]
                       for i, (b, _, _) in enumerate(self.filters)]
        out = np.empty((len(t), 6))
        for i, (b, a, _) in enumerate(self.filters):
            # y[n] = a y[n-1] + b1 x[n] + b0 x[n-1] over the sub-steps
            out[:, 3 * i:3 * i + 3], zf = self._lfilter(b, a, x[:, 3 * i:3 * i + 3], axis=0,
                                                         zi=self.zi[i][None, :])
            self.zi[i] = zf[0]
        return np.asarray(out[sub - 1::sub])


def _quantize(x: FloatArray, dt: float, kind: str, quantum: float, point: bool) -> FloatArray:
    if quantum <= 0.0:
        return x
    if kind == 'value' or point:
        lsb = quantum if kind == 'value' else quantum / dt
        return np.round(x / lsb) * lsb
    counts = np.round(np.cumsum(x * dt, axis=0) / quantum)
    return np.diff(np.vstack([np.zeros((1, 3)), counts]), axis=0) * quantum / dt


def _drop_mask(n: int, fraction: float, mean_burst: float,
               rng: np.random.Generator) -> NDArray[np.bool_]:
    """Keep-mask with about ``fraction`` of ``n`` lost in bursts; first and last kept."""
    keep = np.ones(n, dtype=bool)
    target = int(round(fraction * n))
    while n > 2 and (~keep).sum() < target:
        start = int(rng.integers(1, n - 1))
        length = int(rng.geometric(1.0 / max(mean_burst, 1.0)))
        keep[start:min(start + length, n - 1)] = False
    return keep


def _receipt_stamps(stamps: NDArray[np.int64], jitter_s: float,
                    rng: np.random.Generator) -> NDArray[np.int64]:
    """Stamps taken on receipt: ``U(0, jitter)`` late, kept strictly increasing."""
    if jitter_s <= 0.0:
        return stamps
    late = stamps + np.round(rng.uniform(0.0, jitter_s, len(stamps)) * 1e9).astype(np.int64)
    k_us = np.arange(len(late), dtype=np.int64) * 1000  # at least 1 us apart
    return np.maximum.accumulate(late - k_us) + k_us


def _on_change(q: FloatArray, threshold_rad: float) -> NDArray[np.bool_]:
    """Publish-on-change mask: a state is kept when some joint moved by more than
    ``threshold_rad`` since the last kept one (the first is kept)."""
    keep = np.zeros(len(q), dtype=bool)
    last = None
    for i in range(len(q)):  # sequential by nature: each decision depends on the last kept
        if last is None or np.max(np.abs(q[i] - last)) > threshold_rad:
            keep[i] = True
            last = q[i]
    return keep


def generate(fx: WorldFixture, profile: Any, unit: Unit, mounting: Mounting,
             config: WorldConfig = WorldConfig(), seed: int = 0,
             provenance: dict[str, Any] | None = None,
             progress: Callable[[float], None] | None = None) -> WorldData:
    """Generate IMU samples and joint states of ``unit`` on ``fx`` running ``profile``.

    Parameters
    ----------
    fx : WorldFixture
        The fixture file (nominal mounting); the truth adds ``mounting``.
    profile : core.plans.JointProfile
        Joint motion (``evaluate(t) -> q, qd, qdd``, ``breakpoints_s``, ``duration_s``).
    unit : Unit
        From :func:`draw_unit` (or built by hand).
    mounting : Mounting
    config : WorldConfig
    seed : int
        Seeds noise, encoder noise, drops, receipt delays (independent streams).
    provenance : dict, optional
        Extra provenance keys for the truth (plan name, ...).

    Returns
    -------
    WorldData
    """
    if tuple(profile.joint_names) != fx.joint_names:
        raise ValueError(f'profile joints {profile.joint_names} != fixture {fx.joint_names}')
    cfg = config
    rng_noise, rng_enc, rng_drop, rng_log, rng_names, rng_jit = (
        np.random.default_rng(s) for s in np.random.SeedSequence(seed).spawn(6))
    dt_ns = int(round(1e9 / cfg.imu_rate_hz))
    dt = dt_ns * 1e-9
    n = int(math.floor(profile.duration_s / dt + 1e-9))
    if n < 2:
        raise ValueError('the profile is shorter than two IMU intervals')
    k = np.arange(1, n + 1, dtype=np.int64)
    stamps = cfg.start_stamp_ns + k * dt_ns
    base = None if not any(cfg.base_tilt_rad) else Rotation.from_rotvec(
        [cfg.base_tilt_rad[0], cfg.base_tilt_rad[1], 0.0])
    inst = _Instant(fx, profile, mounting, unit.errors, base)
    out = np.empty((n, 6))
    nodes, weights = np.polynomial.legendre.leggauss(cfg.gl_nodes)
    bps = np.asarray(profile.breakpoints_s, dtype=float)
    nz = unit.noise if cfg.noise else UnitNoise()
    lowpass = _Lowpass(cfg.lowpass_tau_s, dt, nz, rng_noise, cfg.lowpass_tau_accel_s) \
        if cfg.sample_type == 'lowpass' else None
    for k0 in range(0, n, cfg.block):
        k1 = min(n, k0 + cfg.block)
        if cfg.sample_type == 'point':
            g, acc, _, _ = inst(np.arange(k0 + 1, k1 + 1).astype(np.float64) * dt)
            out[k0:k1] = np.concatenate([g, acc], axis=1)
        elif lowpass is not None:
            out[k0:k1] = lowpass(inst, k0, k1)
        else:
            out[k0:k1] = _interval_means(inst, np.arange(k0, k1 + 1).astype(np.float64) * dt,
                                         bps, nodes, weights)
        if progress is not None:
            progress(k1 / n)
    gyro, accel = out[:, :3].copy(), out[:, 3:].copy()
    drift_g = _bias_drift(rng_noise, n, dt, nz.gyro_bias_instability_rad_s,
                          nz.gyro_bias_correlation_s, nz.gyro_bias_random_walk_rad_s2_rt_hz)
    drift_a = _bias_drift(rng_noise, n, dt, nz.accel_bias_instability_m_s2,
                          nz.accel_bias_correlation_s, nz.accel_bias_random_walk_m_s3_rt_hz)
    gyro += drift_g
    accel += drift_a
    if lowpass is None:  # the filter's noise went through it
        gyro += rng_noise.normal(0.0, nz.gyro_noise_rad_s_rt_hz / math.sqrt(dt), (n, 3))
        accel += rng_noise.normal(0.0, nz.accel_noise_m_s2_rt_hz / math.sqrt(dt), (n, 3))
    if cfg.quantize and cfg.noise:
        point = cfg.sample_type != 'interval_mean'
        gyro = _quantize(gyro, dt, unit.noise.quantization, unit.noise.gyro_quantum, point)
        accel = _quantize(accel, dt, unit.noise.quantization, unit.noise.accel_quantum, point)

    # joint states: stamps on their own grid over the IMU span; true time = stamp - latency
    dtj_ns = int(round(1e9 / cfg.joint_rate_hz))
    m = int((n * dt_ns) // dtj_ns) + 1
    j = np.arange(m, dtype=np.int64)
    j_stamps = cfg.start_stamp_ns + j * dtj_ns
    q, qd, _ = profile.evaluate(j * dtj_ns * 1e-9 - cfg.joint_latency_s)
    if cfg.encoder_noise_rad > 0.0 and cfg.noise:
        q = q + rng_enc.normal(0.0, cfg.encoder_noise_rad, q.shape)
    if cfg.encoder_zero_rad:
        if len(cfg.encoder_zero_rad) != q.shape[1]:
            raise ValueError(f'encoder_zero_rad: {len(cfg.encoder_zero_rad)} values for '
                             f'{q.shape[1]} joints')
        q = q - np.asarray(cfg.encoder_zero_rad, float)
    if cfg.wrap_joints:
        q = math.pi - np.mod(math.pi - q, 2.0 * math.pi)  # (-pi, pi]
    names = list(fx.joint_names)
    order = list(range(len(names)))
    if cfg.joint_order == 'reversed':
        order = order[::-1]
    elif cfg.joint_order == 'shuffled':
        order = [int(i) for i in rng_names.permutation(len(names))]
    names = [names[i] for i in order]
    q, qd = q[:, order], qd[:, order]
    if cfg.extra_joint:
        names.append('gripper_extra')
        q = np.concatenate([q, np.full((m, 1), 0.25)], axis=1)
        qd = np.concatenate([qd, np.zeros((m, 1))], axis=1)

    keep_i = _drop_mask(n, cfg.drop_fraction_imu, cfg.drop_burst_mean, rng_drop)
    keep_j = _drop_mask(m, cfg.drop_fraction_joint, cfg.drop_burst_mean, rng_drop)
    if cfg.joint_on_change_rad > 0.0:
        keep_j &= _on_change(q, cfg.joint_on_change_rad)
    stamps = _receipt_stamps(stamps, cfg.imu_stamp_jitter_s, rng_jit)
    j_stamps = _receipt_stamps(j_stamps, cfg.joint_stamp_jitter_s, rng_jit)
    if cfg.receipt_delay_s is None:
        log_i, log_j = stamps.copy(), j_stamps.copy()
    else:
        lo, hi = cfg.receipt_delay_s
        log_i = stamps + np.round(rng_log.uniform(lo, hi, n) * 1e9).astype(np.int64)
        log_j = j_stamps + np.round(rng_log.uniform(lo, hi, m) * 1e9).astype(np.int64)

    truth = _truth(fx, profile, unit, mounting, cfg, seed, drift_g[keep_i][-1],
                   drift_a[keep_i][-1], n, int(keep_i.sum()), m, int(keep_j.sum()),
                   provenance or {})
    return WorldData(stamps[keep_i], gyro[keep_i], accel[keep_i], log_i[keep_i],
                     j_stamps[keep_j], tuple(names), q[keep_j],
                     qd[keep_j] if cfg.joint_velocities else None, log_j[keep_j],
                     drift_g[keep_i], drift_a[keep_i], truth, cfg)


def _truth(fx: WorldFixture, profile: Any, unit: Unit, mounting: Mounting, cfg: WorldConfig,
           seed: int, drift_g: FloatArray, drift_a: FloatArray, n: int, n_kept: int, m: int,
           m_kept: int, provenance: dict[str, Any]) -> dict[str, Any]:
    """The truth file mapping (CONTRACT 4 layout plus the world's extra keys)."""
    def fl(x: ArrayLike) -> list[float]:
        return [float(v) for v in np.ravel(x)]
    e = unit.errors
    contract = e.to_contract()
    zeros = UnitErrors.zeros().to_contract()
    R_mount = mounting.rotation
    R_true = fx.R_joint_imu_nominal * R_mount
    xyz_true = fx.xyz_nominal_m + np.asarray(mounting.offset_m, float)
    cal: dict[str, Any] = {
        'format_version': 1,
        'frame_id': cfg.frame_id,
        **contract,
        'sigma': zeros,
        'fixed': [],
        'bias_at_end': {'gyro_rad_s': fl(e.gyro_bias_rad_s + drift_g),
                        'accel_m_s2': fl(e.accel_bias_m_s2 + drift_a)},
        'mounting': {
            # R_joint_imu_true = R_rpy_nominal @ Rz Ry Rx(rpy_rad) (error in the IMU frame)
            'rpy_rad': fl(R_mount.as_euler('xyz')),
            'rotvec_rad': fl(mounting.rotvec_rad),
            'angle_deg': float(np.degrees(np.linalg.norm(mounting.rotvec_rad))),
            'xyz_m': fl(mounting.offset_m),
            'rpy_true_rad': fl(R_true.as_euler('xyz')),
            'R_joint_imu_true': [fl(r) for r in R_true.as_matrix()],
        },
        'reference_point': {'xyz_joint_m': fl(xyz_true),
                            'xyz_imu_m': fl(R_true.inv().apply(xyz_true))},
        'time': {'sample_type': cfg.sample_type, 'lowpass_tau_s': float(cfg.lowpass_tau_s),
                 'lowpass_tau_accel_s': float(cfg.lowpass_tau_accel_s or cfg.lowpass_tau_s),
                 'imu_rate_hz': float(cfg.imu_rate_hz),
                 'joint_rate_hz': float(cfg.joint_rate_hz),
                 'joint_latency_s': float(cfg.joint_latency_s),
                 'joint_stamp_is': 'true time + joint_latency_s',
                 'start_stamp_ns': int(cfg.start_stamp_ns),
                 'receipt_delay_s': None if cfg.receipt_delay_s is None
                 else fl(cfg.receipt_delay_s),
                 'imu_stamp_jitter_s': float(cfg.imu_stamp_jitter_s),
                 'joint_stamp_jitter_s': float(cfg.joint_stamp_jitter_s),
                 'joint_on_change_rad': float(cfg.joint_on_change_rad)},
        'noise': unit.noise.to_dict() if cfg.noise else UnitNoise().to_dict(),
        'unit': {'kind': unit.kind, 'size': float(unit.size)},
        'provenance': {
            'generator': GENERATOR, 'seed': int(seed), 'plan': getattr(profile, 'plan_name', ''),
            'fixture': fx.source, 'duration_s': float(profile.duration_s),
            'gravity_m_s2': float(fx.gravity), 'earth_rate_rad_s': float(fx.earth_rate_rad_s),
            'imu_samples': n, 'imu_samples_written': n_kept, 'joint_states': m,
            'joint_states_written': m_kept, 'encoder_noise_rad': float(cfg.encoder_noise_rad),
            'encoder_zero_rad': [float(v) for v in cfg.encoder_zero_rad],
            'base_tilt_rad': [float(v) for v in cfg.base_tilt_rad],
            'wrap_joints': bool(cfg.wrap_joints), 'joint_velocities': bool(cfg.joint_velocities),
            'joint_order': cfg.joint_order, 'extra_joint': bool(cfg.extra_joint),
            'quantize': bool(cfg.quantize and cfg.noise), 'gl_nodes': int(cfg.gl_nodes),
            **provenance},
    }
    return {'imu_calibration': cal}


# ---------------------------------------------------------------------------- output
def write_bag(path: str | os.PathLike[str], data: WorldData) -> Path:
    """Write ``data`` as a ROS 2 Jazzy bag (version 9) with rosbags, in log-time order.

    ``sensor_msgs/Imu`` (REP-145: ``orientation_covariance[0] = -1``, other covariances
    zero = unknown) and ``sensor_msgs/JointState``; a message's log time is its receipt time
    (``WorldData.*_log_ns``), its header the true stamp.
    """
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore
    ts = get_typestore(Stores.ROS2_JAZZY)
    T = ts.types
    Imu, JointState = T['sensor_msgs/msg/Imu'], T['sensor_msgs/msg/JointState']
    Header, Time = T['std_msgs/msg/Header'], T['builtin_interfaces/msg/Time']
    Vector3, Quaternion = T['geometry_msgs/msg/Vector3'], T['geometry_msgs/msg/Quaternion']
    cfg = data.config
    plugin = StoragePlugin.MCAP if cfg.storage == 'mcap' else StoragePlugin.SQLITE3
    out = Path(path)
    zeros9 = np.zeros(9)
    ocov = np.zeros(9)
    ocov[0] = -1.0
    quat = Quaternion(x=0.0, y=0.0, z=0.0, w=1.0)
    n_i, n_j = len(data.imu_stamps_ns), len(data.joint_stamps_ns)
    log = np.concatenate([data.joint_log_ns, data.imu_log_ns])
    kind = np.concatenate([np.zeros(n_j, np.int8), np.ones(n_i, np.int8)])
    idx = np.concatenate([np.arange(n_j), np.arange(n_i)])
    order = np.lexsort((kind, log))

    def stamp(ns: int) -> Any:
        return Time(sec=int(ns // 1_000_000_000), nanosec=int(ns % 1_000_000_000))
    with Writer(out, version=9, storage_plugin=plugin) as w:
        c_imu = w.add_connection(cfg.imu_topic, Imu.__msgtype__, typestore=ts)
        c_js = w.add_connection(cfg.joint_topic, JointState.__msgtype__, typestore=ts)
        names = list(data.joint_names)
        empty = np.zeros(0)
        for o in order:
            i = int(idx[o])
            if kind[o]:
                g, a = data.gyro_rad_s[i], data.accel_m_s2[i]
                msg = Imu(header=Header(stamp=stamp(int(data.imu_stamps_ns[i])),
                                        frame_id=cfg.frame_id),
                          orientation=quat, orientation_covariance=ocov,
                          angular_velocity=Vector3(x=float(g[0]), y=float(g[1]), z=float(g[2])),
                          angular_velocity_covariance=zeros9,
                          linear_acceleration=Vector3(x=float(a[0]), y=float(a[1]),
                                                      z=float(a[2])),
                          linear_acceleration_covariance=zeros9)
                w.write(c_imu, int(data.imu_log_ns[i]), ts.serialize_cdr(msg, Imu.__msgtype__))
            else:
                vel = (np.asarray(data.joint_velocity_rad_s[i], dtype=np.float64)
                       if data.joint_velocity_rad_s is not None else empty)
                msg = JointState(header=Header(stamp=stamp(int(data.joint_stamps_ns[i])),
                                               frame_id=''),
                                 name=names,
                                 position=np.asarray(data.joint_position_rad[i], np.float64),
                                 velocity=vel, effort=empty)
                w.write(c_js, int(data.joint_log_ns[i]),
                        ts.serialize_cdr(msg, JointState.__msgtype__))
    return out


def write_truth(path: str | os.PathLike[str], data: WorldData) -> Path:
    """Write the truth mapping as plain YAML (floats at repr precision)."""
    out = Path(path)
    tmp = out.with_name(out.name + '.tmp')
    with open(tmp, 'w', encoding='utf-8') as fh:
        fh.write(f'# truth written by {GENERATOR} (CONTRACT 4 layout + extra keys)\n')
        yaml.safe_dump(data.truth, fh, sort_keys=False, default_flow_style=None, width=99)
    os.replace(tmp, out)
    return out


# ------------------------------------------------------------------------ convenience
_PROFILES: dict[tuple[str, str, float], Any] = {}


def joint_profile(plan: Any, fixture_path: str | os.PathLike[str]) -> Any:
    """``core.plans.build_profile`` of ``plan`` (name, path or Plan) on a fixture file.

    The nominal fixture maps the plan's IMU-axis steps onto joints (as an operator would,
    without knowing the mounting error); only the joint motion q(t) is used. Profiles of
    plans given by name or path are kept per (plan, fixture file, its mtime): mapping an
    SRT plan solves every orientation by least squares (seconds).
    """
    from ..core.fixture import load_fixture
    from ..core.plans import Plan, build_profile, load_plan
    if isinstance(plan, Plan):
        return build_profile(plan, load_fixture(str(fixture_path)))
    key = (str(plan), str(Path(fixture_path).resolve()), Path(fixture_path).stat().st_mtime)
    if key not in _PROFILES:
        _PROFILES[key] = build_profile(load_plan(plan), load_fixture(str(fixture_path)))
    return _PROFILES[key]


def fixture_path(name_or_path: str) -> Path:
    """A shipped fixture name (``three_axis``) or a path -> the file's path."""
    p = Path(name_or_path)
    if p.suffix in ('.yaml', '.yml') or p.exists():
        return p
    return Path(__file__).resolve().parents[2] / 'config' / 'fixtures' / f'{name_or_path}.yaml'


def simulate_to_files(out_dir: str | os.PathLike[str], fixture: str | os.PathLike[str],
                      profile: Any, unit: Unit, mounting: Mounting,
                      config: WorldConfig = WorldConfig(), seed: int = 0,
                      provenance: dict[str, Any] | None = None,
                      bag_name: str = 'bag') -> tuple[Path, Path, WorldData]:
    """Generate and write ``out_dir/bag_name`` (bag) and ``out_dir/truth.yaml``.

    Returns
    -------
    (bag_path, truth_path, data)
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    fx = WorldFixture.from_yaml(fixture_path(str(fixture)))
    data = generate(fx, profile, unit, mounting, config, seed, provenance)
    bag = write_bag(out / bag_name, data)
    return bag, write_truth(out / 'truth.yaml', data), data


def with_config(config: WorldConfig, **changes: Any) -> WorldConfig:
    """``dataclasses.replace`` for :class:`WorldConfig`."""
    return replace(config, **changes)


def stamps_to_times(stamps_ns: Sequence[int], start_ns: int) -> FloatArray:
    """Profile time [s] of stamps (exact integer difference first)."""
    return (np.asarray(stamps_ns, dtype=np.int64) - start_ns).astype(np.float64) * 1e-9
