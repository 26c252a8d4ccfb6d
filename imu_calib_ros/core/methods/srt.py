"""Savage's strapdown rotation test (SRT) as a processor.

P. G. Savage, "Improved strapdown IMU calibration procedures", IEEE/ION PLANS 2018
(seed ``003``). Pipeline:

1. stationary windows from the joint states and the IMU (:mod:`.windows`); every pair of
   consecutive windows with a rotation between them is a sequence;
2. start-frame accelerations ``a^BStrt = C_B^BStrt a^B`` with the gyro-integrated DCM
   including earth rate, eqs. (1)-(2): ``dC/dt = C (w x) - (w_e^BStrt x) C``, ``C(t0) = I``;
   its closed form ``C = Rot(-w_e^BStrt t) * prod(exp(w dt))`` is what is computed;
3. per sequence the horizontal change ``Delta a_H`` (two rows, in a horizontal basis of
   BStrt) and per window the down component ``u_dwn . a + g`` (eq. 1);
4. the linear model of eqs. (3)-(5) is not transcribed: each row's sensitivity to every
   error parameter is obtained by finite differences through steps 2-3 themselves (the
   error is added to the compensated stream), so any sequence set works and Table 2's
   ``H_k`` (2 pi g, 4 g, 2 g) comes out of the code (see :func:`design_sensitivities`);
5. weighted least squares with rank detection (QR with column pivoting): parameters the
   sequence set does not excite are fixed (CONTRACT 4) and reported; the sigmas are the
   noise covariance plus the consider covariance of everything held fixed (G, qa, size
   effect, unexcited parameters) at its assumed (grade) sigma, :func:`consider_covariance`;
6. iterate by re-playing the recording with the updated compensation (sect. 8).

Frames: Savage's B is the IMU frame, so ``Delta a_H`` components are the same in his
NED-based and our ENU-based formulation; only ``C_NED^BStrt`` of eq. (2) becomes
``R_imu_enu(q)`` from the fixture kinematics (earth rate and down vector), and the down
vector is ENU ``(0, 0, -1)``. Parameter correspondence (MARS B frame, Savage eqs. 8-11):
``kappa_ii = Kg[i][i]``, ``kappa_iii = ag_i``, ``v_ij = 2 Kg[i][j]``, ``mu_ij = Ka[i][j]``,
``lambda_ii = Ka[i][i]``, ``lambda_iii = aa_i``, ``lambda_i = ba_i``.
Gyro biases come from the stationary windows (sect. 9.4 mitigation: mean gyro minus the
earth rate of the window's attitude), not from the rotation sequences.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Callable, Sequence

import numpy as np
import scipy.linalg
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from .. import parameters as registry
from ..earth import EARTH_RATE_RAD_S
from ..errors import InputError
from ..sensor_model import KEY_OF_FIELD
from ..types import ImuBatch, JointBatch, sample_intervals_ns
from .windows import Window, stationary_windows

if TYPE_CHECKING:
    from ..calibration import CalibrationResult
    from ..fixture import Fixture
    from ..imu_grade import ImuGrade
    from ..sensor_model import SensorErrors

FloatArray = NDArray[np.float64]
AXES = 'xyz'

#: Estimated parameters: (name, SensorErrors field, index), from the parameter registry: Kg
#: (its six symmetric pairs), ag, Ka, aa, ba, each in 45-vector order.
PARAMS: tuple[tuple[str, str, tuple[int, ...]], ...] = registry.entries_of(
    'gyroscope.scale_misalignment', 'gyroscope.scale_asymmetry',
    'accelerometer.scale_misalignment', 'accelerometer.scale_asymmetry', 'accelerometer.bias')
PARAM_NAMES = tuple(p[0] for p in PARAMS)
#: the first 9 act on the gyros (they need the DCM re-integrated)
N_GYRO_PARAMS = sum(registry.PARAMETER_OF_FIELD[fld].section == 'gyroscope'
                    for _, fld, _ in PARAMS)
#: finite-difference step per parameter: dimensionless 1e-6, accel bias 1e-5 m/s^2
_EPS = np.array([1e-5 if fld == 'accel_bias_m_s2' else 1e-6 for _, fld, _ in PARAMS])

#: Savage's Table 1 (restated in METHODS.md): initial down axis, axis along the outer
#: fixture axis, and the sequential rotations about IMU axes (axis, degrees).
TABLE1: dict[str, tuple[str, str, tuple[tuple[str, float], ...]]] = {
    '1': ('z', 'y', (('y', 360),)), '2': ('z', 'x', (('x', 360),)),
    '3': ('x', 'y', (('z', 360),)),
    '1a': ('z', 'y', (('y', -360),)), '2a': ('z', 'x', (('x', -360),)),
    '3a': ('x', 'y', (('z', -360),)),
    '4': ('z', 'y', (('y', 180), ('z', 180), ('y', 180), ('z', 180))),
    '5': ('z', 'x', (('x', 180), ('z', 180), ('x', 180), ('z', 180))),
    '6': ('x', 'y', (('y', 180), ('z', 90), ('x', 180), ('z', 90),
                     ('y', 180), ('z', 90), ('x', 180), ('z', 90))),
    '7': ('y', 'x', (('x', 180),)), '8': ('z', 'x', (('x', 180),)),
    '9': ('x', 'y', (('z', 180),)), '10': ('y', 'x', (('z', 180),)),
    '11': ('z', 'y', (('y', 180),)), '12': ('x', 'y', (('y', 180),)),
    '13': ('z', 'y', (('z', 180), ('y', 180))), '14': ('z', 'x', (('z', 180), ('x', 180))),
}


# ----------------------------------------------------------------------------- error model
def add_errors(x: FloatArray, omega_rad_s: FloatArray, f_m_s2: FloatArray,
               which: str = 'both') -> tuple[FloatArray, FloatArray]:
    """Add the residual errors ``x`` (order :data:`PARAM_NAMES`) to compensated streams.

    CONTRACT 3 linear terms: ``w + Kg w + ag |w|`` and ``f + Ka f + aa |f| + ba``.
    """
    w = omega_rad_s
    f = f_m_s2
    if which in ('both', 'gyro'):
        Kg = np.diag(x[0:3]).astype(float)
        Kg[0, 1] = Kg[1, 0] = x[3]
        Kg[0, 2] = Kg[2, 0] = x[4]
        Kg[1, 2] = Kg[2, 1] = x[5]
        w = w + w @ Kg.T + x[6:9] * np.abs(w)
    if which in ('both', 'accel'):
        Ka = x[9:18].reshape(3, 3)
        f = f + f @ Ka.T + x[18:21] * np.abs(f) + x[21:24]
    return w, f


def _errors_from_vector(x: FloatArray) -> dict[str, FloatArray]:
    """The SensorErrors fields touched by ``x`` (the others are not included)."""
    out: dict[str, FloatArray] = {fld: np.zeros(registry.PARAMETER_OF_FIELD[fld].shape)
                                  for _, fld, _ in PARAMS}
    for v, (_, fld, idx) in zip(x, PARAMS):
        out[fld][idx] = v
        if registry.PARAMETER_OF_FIELD[fld].symmetric:
            out[fld][idx[::-1]] = v
    return out


# ----------------------------------------------------------------------------- attitude
def cumulative_dcm(omega_rad_s: FloatArray, dt_s: FloatArray) -> FloatArray:
    """``C_k = exp(w_1 dt_1) ... exp(w_k dt_k)`` for every k, shape ``(N, 3, 3)``.

    Exact for mean-over-interval rates about a fixed axis (SRT rotations are about one
    IMU axis at a time). scipy has no cumulative rotation product, hence the log-depth
    (Hillis-Steele) scan here.
    """
    C = Rotation.from_rotvec(omega_rad_s * dt_s[:, None]).as_matrix()
    shift = 1
    while shift < C.shape[0]:
        nxt = C.copy()
        nxt[shift:] = C[:-shift] @ C[shift:]
        C = nxt
        shift *= 2
    return C


# ----------------------------------------------------------------------------- sequences
@dataclass(frozen=True)
class SrtSequence:
    """A rotation sequence between two stationary windows.

    Attributes
    ----------
    index : int
        Order in the recording (0-based).
    start, end : Window
        Stationary windows before and after.
    rotations : tuple of (axis, deg)
        The rotations seen by the gyros (axis = dominant IMU axis of each rotation).
    down_axis : str
        IMU axis (with sign) pointing down at the start, e.g. ``'+z'``.
    label : str
        ``'srt:<id>'`` if it matches a Table 1 sequence, else ``'seq:<index>'``.
    """

    index: int
    start: Window
    end: Window
    rotations: tuple[tuple[str, float], ...]
    down_axis: str
    label: str


def _detect_rotations(omega: FloatArray, dt: FloatArray, thr_rad_s: float = 0.05,
                      ) -> tuple[tuple[str, float], ...]:
    """Split a sequence's gyro data into single-axis rotations (axis, degrees)."""
    moving = np.linalg.norm(omega, axis=1) > thr_rad_s
    rots: list[tuple[str, float]] = []
    m = np.concatenate([[False], moving, [False]]).astype(np.int8)
    d = np.diff(m)
    for a, b in zip(np.flatnonzero(d == 1), np.flatnonzero(d == -1)):
        ang = (omega[a:b] * dt[a:b, None]).sum(axis=0)
        k = int(np.argmax(np.abs(ang)))
        deg = float(np.degrees(ang[k]))
        if abs(deg) < 5.0:
            continue
        if rots and rots[-1][0] == AXES[k]:  # a pause inside one rotation
            rots[-1] = (AXES[k], rots[-1][1] + deg)
        else:
            rots.append((AXES[k], deg))
    return tuple((a, float(45.0 * np.round(v / 45.0))) for a, v in rots)


def _down_axis(R_enu_imu: FloatArray) -> str:
    u = R_enu_imu.T @ np.array([0.0, 0.0, -1.0])
    k = int(np.argmax(np.abs(u)))
    return ('+' if u[k] > 0 else '-') + AXES[k]


def _match_table1(down_axis: str, rotations: tuple[tuple[str, float], ...]) -> str | None:
    for sid, (down, _, rots) in TABLE1.items():
        if down_axis == '+' + down and tuple((a, float(d)) for a, d in rots) == rotations:
            return sid
    return None


def find_sequences(stamps_ns: NDArray[np.int64], omega_rad_s: FloatArray,
                   windows: Sequence[Window], R_enu_imu_windows: FloatArray,
                   min_rotation_deg: float = 20.0) -> list[SrtSequence]:
    """Pair consecutive stationary windows that have a rotation between them."""
    dt = _dt(stamps_ns)
    seqs: list[SrtSequence] = []
    for k in range(len(windows) - 1):
        w0, w1 = windows[k], windows[k + 1]
        rots = _detect_rotations(omega_rad_s[w0.i1:w1.i0], dt[w0.i1:w1.i0])
        if not rots or max(abs(d) for _, d in rots) < min_rotation_deg:
            continue
        down = _down_axis(R_enu_imu_windows[k])
        sid = _match_table1(down, rots)
        label = f'srt:{sid}' if sid else f'seq:{len(seqs)}'
        seqs.append(SrtSequence(len(seqs), w0, w1, rots, down, label))
    return seqs


def _dt(stamps_ns: NDArray[np.int64]) -> FloatArray:
    """Averaging interval of each sample [s] (CONTRACT 1: nominal period after a gap)."""
    return sample_intervals_ns(stamps_ns)[0] * 1e-9


# ----------------------------------------------------------------------------- measurements
@dataclass
class _Geometry:
    """Everything the measurement function needs besides the data (one recording)."""

    stamps_ns: NDArray[np.int64]
    sequences: list[SrtSequence]
    windows: list[Window]
    R_enu_imu_windows: FloatArray  # (W, 3, 3) nominal attitude per window
    g_m_s2: float
    omega_ie_enu: FloatArray
    seq_window_idx: list[tuple[int, int]] = field(default_factory=list)

    def __post_init__(self) -> None:
        ids = {id(w): i for i, w in enumerate(self.windows)}
        self.seq_window_idx = [(ids[id(s.start)], ids[id(s.end)]) for s in self.sequences]
        self.dt = _dt(self.stamps_ns)
        self.t_s = (self.stamps_ns - self.stamps_ns[0]) * 1e-9

    def horizontal_basis(self, k: int) -> FloatArray:
        """Two orthonormal horizontal directions in BStrt: the two most level IMU axes."""
        u = self.down(self.seq_window_idx[k][0])
        order = np.argsort(np.abs(u))[:2]
        order.sort()
        E: list[FloatArray] = []
        for j in order:
            e = np.eye(3)[j] - u * u[j]
            for prev in E:
                e = e - prev * (prev @ e)
            E.append(e / np.linalg.norm(e))
        return np.array(E)

    def down(self, w: int) -> FloatArray:
        """Unit down vector in the IMU frame at window ``w`` (ENU down = (0, 0, -1))."""
        return self.R_enu_imu_windows[w].T @ np.array([0.0, 0.0, -1.0])

    @property
    def row_names(self) -> list[str]:
        names = []
        for s, k in zip(self.sequences, range(len(self.sequences))):
            E = self.horizontal_basis(k)
            for e in E:
                j = int(np.argmax(np.abs(e)))
                names.append(f"{s.label} dA_{'-' if e[j] < 0 else '+'}{AXES[j]}")
        names += [f'window {w} down' for w in range(len(self.windows))]
        return names


def _sequence_dcms(geo: _Geometry, omega: FloatArray, k: int) -> FloatArray:
    """Mid-interval ``C_B^BStrt`` for samples ``start.i0 .. end.i1`` of sequence ``k`` (eq. 2)."""
    s = geo.sequences[k]
    a, b = s.start.i0, s.end.i1
    C = cumulative_dcm(omega[a:b], geo.dt[a:b])
    w_e = geo.R_enu_imu_windows[geo.seq_window_idx[k][0]].T @ geo.omega_ie_enu
    tau = np.cumsum(geo.dt[a:b])
    E = Rotation.from_rotvec(-tau[:, None] * w_e).as_matrix()
    C = E @ C
    prev = np.concatenate([np.eye(3)[None], C[:-1]])
    return 0.5 * (C + prev)


def measurements(geo: _Geometry, omega: FloatArray, f: FloatArray,
                 dcms: list[FloatArray] | None = None) -> tuple[FloatArray, list[FloatArray]]:
    """Measurement vector: per sequence the horizontal change (2 rows), per window the down
    component ``u_dwn . <f> + g`` (Savage eq. 1) as ``g - |<f>|``, in m/s^2. Returns
    ``(y, dcms)``."""
    if dcms is None:
        dcms = [_sequence_dcms(geo, omega, k) for k in range(len(geo.sequences))]
    rows = []
    for k, s in enumerate(geo.sequences):
        a = s.start.i0
        C = dcms[k]
        a_start = np.einsum('nij,nj->i', C[:s.start.i1 - a], f[a:s.start.i1]) / (
            s.start.i1 - a)
        a_end = np.einsum('nij,nj->i', C[s.end.i0 - a:], f[s.end.i0:s.end.i1]) / (
            s.end.i1 - s.end.i0)
        rows.extend(geo.horizontal_basis(k) @ (a_end - a_start))
    for win in geo.windows:
        # Savage's down component u_dwn . <f> + g, taken as g - |<f>| (equal to first order
        # with f along -u_dwn): the nominal u_dwn misses the mounting tilt, whose cosine
        # (1 - theta^2 / 2, ~5e-7 at 1 mrad) was absorbed by the accel scale factors
        rows.append(geo.g_m_s2 - np.linalg.norm(f[win.i0:win.i1].mean(axis=0)))
    return np.array(rows), dcms


def sensitivities(geo: _Geometry, omega: FloatArray, f: FloatArray) -> FloatArray:
    """``d y / d x`` by forward differences through :func:`measurements` (rows x params).

    The processing is linear in the errors to first order; steps of 1e-6 keep the
    second-order terms (< 1e-12 g) and the rounding (~1e-10 g) far below the noise.
    """
    y0, dcms = measurements(geo, omega, f)
    J = np.zeros((y0.size, len(PARAMS)))
    for j in range(len(PARAMS)):
        x = np.zeros(len(PARAMS))
        x[j] = _EPS[j]
        if j < N_GYRO_PARAMS:
            w1, _ = add_errors(x, omega, f, 'gyro')
            y1, _ = measurements(geo, w1, f)
        else:
            _, f1 = add_errors(x, omega, f, 'accel')
            y1, _ = measurements(geo, omega, f1, dcms)
        J[:, j] = (y1 - y0) / _EPS[j]
    return J


def measurement_sigmas(geo: _Geometry, gyro_noise_rad_s_rt_hz: float,
                       accel_noise_m_s2_rt_hz: float) -> FloatArray:
    """One-sigma of each row from white noise (Savage sect. 9.1-9.2): accelerometer noise
    averaged over the windows, gyro angle random walk over the sequence times g."""
    sig = []
    for k, s in enumerate(geo.sequences):
        t_s = 0.5 * (s.start.t0_s + s.start.t1_s)
        t_e = 0.5 * (s.end.t0_s + s.end.t1_s)
        var = (accel_noise_m_s2_rt_hz ** 2 * (1 / s.start.duration_s + 1 / s.end.duration_s)
               + (geo.g_m_s2 * gyro_noise_rad_s_rt_hz) ** 2 * (t_e - t_s))
        sig += [np.sqrt(var)] * 2
    sig += [accel_noise_m_s2_rt_hz / np.sqrt(w.duration_s) for w in geo.windows]
    return np.array(sig)


def drift_covariance(geo: _Geometry, accel_bias_instability_m_s2: float,
                     accel_bias_correlation_s: float) -> FloatArray:
    """Row covariance from a Gauss-Markov accelerometer bias (bias instability).

    The bias' deviation ``d(t)`` from its mean (the mean is what ``ba`` estimates) enters a
    down row as ``u_dwn . d(t_w)`` and a horizontal change as ``E (C_end d(t_e) - d(t_s))``
    with ``C_end = R_imu_enu(start) R_enu_imu(end)`` the nominal start-frame attitude at the
    end window (eq. 2 at rest). Per axis ``E[d(t_i) d(t_j)] = s^2 exp(-|t_i - t_j| / tau)``
    (first-order Gauss-Markov, the simulator's and the grade's model); each window is taken
    at its mid-time (windows of seconds against tau of an hour). Returns ``(rows, rows)``
    in (m/s^2)^2; zero when ``s`` is zero.
    """
    n_rows = 2 * len(geo.sequences) + len(geo.windows)
    if accel_bias_instability_m_s2 <= 0 or accel_bias_correlation_s <= 0:
        return np.zeros((n_rows, n_rows))
    W = len(geo.windows)
    t_mid = np.array([0.5 * (w.t0_s + w.t1_s) for w in geo.windows])
    K = accel_bias_instability_m_s2 ** 2 * np.exp(
        -np.abs(t_mid[:, None] - t_mid[None, :]) / accel_bias_correlation_s)
    M = np.zeros((n_rows, 3 * W))
    for k, (ws, we) in enumerate(geo.seq_window_idx):
        E = geo.horizontal_basis(k)
        C_end = geo.R_enu_imu_windows[ws].T @ geo.R_enu_imu_windows[we]
        M[2 * k:2 * k + 2, 3 * we:3 * we + 3] += E @ C_end
        M[2 * k:2 * k + 2, 3 * ws:3 * ws + 3] -= E
    for w in range(W):
        M[2 * len(geo.sequences) + w, 3 * w:3 * w + 3] = geo.down(w)
    return M @ np.kron(K, np.eye(3)) @ M.T


def noise_densities(stamps_ns: NDArray[np.int64], gyro: FloatArray, accel: FloatArray,
                    windows: Sequence[Window]) -> tuple[float, float]:
    """White-noise densities (gyro rad/s/rtHz, accel m/s^2/rtHz) from the windows.

    Per window, the sample standard deviation of first differences / sqrt(2) (immune to
    slow drift) times sqrt(dt); the median over windows and axes.
    """
    dt = float(np.median(np.diff(stamps_ns))) * 1e-9
    sg, sa = [], []
    for w in windows:
        sg.append(np.std(np.diff(gyro[w.i0:w.i1], axis=0), axis=0) / np.sqrt(2))
        sa.append(np.std(np.diff(accel[w.i0:w.i1], axis=0), axis=0) / np.sqrt(2))
    return (float(np.median(sg)) * np.sqrt(dt), float(np.median(sa)) * np.sqrt(dt))


@dataclass(frozen=True)
class LsqResult:
    """Weighted least squares with rank detection."""

    x: FloatArray  # (P,), zero where not estimated
    cov: FloatArray  # (P, P), zero rows/cols where not estimated
    estimated: NDArray[np.bool_]
    residual: FloatArray  # y - J x, m/s^2
    chi2: float
    dof: int


def solve(J: FloatArray, y: FloatArray, sigma: FloatArray, rtol: float = 1e-2,
          allowed: NDArray[np.bool_] | None = None) -> LsqResult:
    """Solve ``y = J x`` by weighted least squares; fix what the rows do not excite.

    Columns are normalised, then QR with column pivoting (scipy) ranks them; columns past
    the numerical rank, and columns not ``allowed``, are fixed at zero. The covariance is
    the noise one times ``max(1, chi2/dof)`` (the residual scatter when it exceeds the noise
    model).
    """
    Jw = J / sigma[:, None]
    yw = y / sigma
    norms = np.linalg.norm(Jw, axis=0)
    live = norms > 0
    if allowed is not None:
        live &= allowed
    Js = np.where(live, Jw / np.where(live, norms, 1.0), 0.0)
    _, R, piv = scipy.linalg.qr(Js, mode='economic', pivoting=True)
    d = np.abs(np.diag(R))
    rank = int(np.sum(d > rtol * d[0])) if d.size and d[0] > 0 else 0
    est = np.zeros(J.shape[1], bool)
    est[piv[:rank]] = True
    est &= live
    A = Jw[:, est]
    sol, *_ = np.linalg.lstsq(A, yw, rcond=None)
    x = np.zeros(J.shape[1])
    x[est] = sol
    r = y - J @ x
    chi2 = float(np.sum((r / sigma) ** 2))
    dof = int(y.size - est.sum())
    scale = max(1.0, chi2 / dof) if dof > 0 else 1.0
    cov = np.zeros((J.shape[1], J.shape[1]))
    cov[np.ix_(est, est)] = np.linalg.inv(A.T @ A) * scale
    return LsqResult(x, cov, est, r, chi2, dof)


# ----------------------------------------------------------------------------- consider
#: Parameters the SRT never estimates (CONTRACT 3 terms outside its linear model): (label,
#: SensorErrors field, index, finite-difference step). G's step moves the rate by ~1e-6 rad/s
#: (as Kg's); qa and r enter the specific force linearly, so their steps are exact.
_CONSIDER_STEP = {'gyro_g_sensitivity_rad_s_per_m_s2': 1e-7, 'accel_quadratic_per_m_s2': 1e-6,
                  'size_effect_m': 1e-3}
CONSIDER: tuple[tuple[str, str, tuple[int, ...], float], ...] = tuple(
    (name, fld, idx, _CONSIDER_STEP[fld]) for name, fld, idx in registry.entries_of(
        'gyroscope.g_sensitivity', 'accelerometer.quadratic', 'accelerometer.size_effect'))


def _window_mean(x: FloatArray, windows: Sequence[Window]) -> FloatArray:
    """Duration-weighted mean over the windows (the weights of :func:`gyro_bias_from_windows`)."""
    durs = np.array([w.duration_s for w in windows])
    means = np.array([x[w.i0:w.i1].mean(axis=0) for w in windows])
    return (durs / durs.sum()) @ means


def consider_sensitivities(geo: _Geometry, omega: FloatArray, f: FloatArray,
                           ) -> tuple[FloatArray, FloatArray]:
    """How the rows and the window gyro bias move with the parameters held fixed.

    Each :data:`CONSIDER` term is added to the compensated stream (CONTRACT 3 forward
    model: ``G f`` on the gyros, ``qa f^2`` and Kozlov eq. 1's size effect on the
    accelerometers); a gyro change also moves the window gyro bias (Savage 9.4), which is
    subtracted before the rows are formed, as in :func:`estimate`.

    Returns
    -------
    J_f : (rows, len(CONSIDER))
        ``d y / d x_f`` [m/s^2 per unit].
    B_f : (3, len(CONSIDER))
        ``d b_g / d x_f``, the window gyro bias [rad/s per unit].
    """
    from ..sensor_model import mean_rate_derivative, size_effect_term
    y0, dcms = measurements(geo, omega, f)
    omega_dot = mean_rate_derivative(geo.stamps_ns, omega)
    J_f = np.zeros((y0.size, len(CONSIDER)))
    B_f = np.zeros((3, len(CONSIDER)))
    for j, (_, fld, idx, eps) in enumerate(CONSIDER):
        if fld == 'gyro_g_sensitivity_rad_s_per_m_s2':
            dw = np.zeros_like(omega)
            dw[:, idx[0]] = eps * f[:, idx[1]]
            db = _window_mean(dw, geo.windows)
            y1, _ = measurements(geo, omega + dw - db, f)
            B_f[:, j] = db / eps
        else:
            if fld == 'accel_quadratic_per_m_s2':
                df = np.zeros_like(f)
                df[:, idx[0]] = eps * f[:, idx[0]] ** 2
            else:
                r = np.zeros((3, 3))
                r[idx] = eps
                df = size_effect_term(r, omega, omega_dot)
            y1, _ = measurements(geo, omega, f + df, dcms)
        J_f[:, j] = (y1 - y0) / eps
    return J_f, B_f


def consider_covariance(J: FloatArray, sigma_y: FloatArray, estimated: NDArray[np.bool_],
                        J_f: FloatArray, sigma_f: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Consider covariance of the estimated parameters (Schmidt; e.g. Bierman 1977, ch. 6).

    The weighted LS estimate ``x = (A^T W A)^-1 A^T W y`` absorbs whatever the fixed
    parameters ``x_f`` put into ``y = A x + J_f x_f + n``: ``S = -(A^T W A)^-1 A^T W J_f``,
    and ``P_consider = S diag(sigma_f^2) S^T`` adds to the noise covariance.

    Returns
    -------
    P_c : (P, P)
        Consider part (zero rows/columns for parameters not estimated).
    S : (P, F)
        Sensitivity of the estimate to the fixed parameters.
    """
    A = J[:, estimated] / sigma_y[:, None]
    Jf_w = J_f / sigma_y[:, None]
    S = np.zeros((J.shape[1], J_f.shape[1]))
    S[estimated] = -np.linalg.solve(A.T @ A, A.T @ Jf_w)
    return (S * sigma_f ** 2) @ S.T, S


# ----------------------------------------------------------------------------- design tool
def synthesize_sequence(seq_id: str, g_m_s2: float, omega_ie_enu: FloatArray, *,
                        rate_hz: float = 100.0, dwell_s: float = 10.0,
                        rate_rad_s: float = 1.0, outer_axis_enu: FloatArray | None = None,
                        ) -> tuple[NDArray[np.int64], FloatArray, FloatArray, FloatArray]:
    """Ideal (error- and noise-free) IMU data of one Table 1 sequence.

    The IMU starts with the Table 1 axis down and the named axis along the (horizontal)
    outer fixture axis (default north); each rotation about an IMU axis follows a
    ``1 - cos`` rate profile with peak ``2 * rate_rad_s``. Gyro: mean rate per interval
    (rotation + earth rate); accel: specific force ``R^T (0, 0, g)`` at mid-interval.

    Returns
    -------
    stamps_ns, gyro_rad_s, accel_m_s2, R_enu_imu0
    """
    down, along, rots = TABLE1[seq_id]
    o = np.array([0.0, 1.0, 0.0]) if outer_axis_enu is None else np.asarray(outer_axis_enu)
    cols = {down: np.array([0.0, 0.0, -1.0]), along: o}
    third = next(a for a in AXES if a not in cols)
    i_third = AXES.index(third)
    # right-handed: column of the third axis = cross of the other two in cyclic order
    nxt, prv = AXES[(i_third + 1) % 3], AXES[(i_third + 2) % 3]
    cols[third] = np.cross(cols[nxt], cols[prv])
    R0 = np.stack([cols[a] for a in AXES], axis=1)
    dt = 1.0 / rate_hz
    n_dw = int(round(dwell_s * rate_hz))
    incs = [np.zeros((n_dw, 3))]
    for axis, deg in rots:
        ang = np.radians(deg)
        T = abs(ang) / rate_rad_s
        n = int(np.ceil(T * rate_hz))
        t = np.arange(n + 1) * (T / n)
        theta = ang * (t / T - np.sin(2 * np.pi * t / T) / (2 * np.pi))
        inc = np.zeros((n, 3))
        inc[:, AXES.index(axis)] = np.diff(theta)
        incs.append(inc)
    incs.append(np.zeros((n_dw, 3)))
    dtheta = np.concatenate(incs)  # rotation increments about body axes, per sample
    N = dtheta.shape[0]
    R_body = np.concatenate([np.eye(3)[None], cumulative_dcm(dtheta, np.ones(N))])
    R = R0 @ R_body  # (N+1) attitudes at sample boundaries, earth-fixed
    R_mid = Rotation.from_matrix(R[:-1]) * Rotation.from_rotvec(0.5 * dtheta)
    Rm = R_mid.as_matrix()
    gyro = dtheta / dt + np.einsum('nji,j->ni', Rm, omega_ie_enu)
    accel = np.einsum('nji,j->ni', Rm, np.array([0.0, 0.0, g_m_s2]))
    stamps = (np.arange(1, N + 1) * dt * 1e9).round().astype(np.int64)
    return stamps, gyro, accel, R0


def design_sensitivities(seq_ids: Sequence[str], g_m_s2: float = 9.80665,
                         latitude_deg: float = 45.0, **kw: Any,
                         ) -> tuple[FloatArray, list[str]]:
    """Sensitivity matrix (rows x :data:`PARAM_NAMES`) of a set of Table 1 sequences,
    computed through the processing on ideal data (the "linear model of eqs. 3-5 in code").
    """
    lat = np.radians(latitude_deg)
    w_ie = EARTH_RATE_RAD_S * np.array([0.0, np.cos(lat), np.sin(lat)])
    Js, names = [], []
    for sid in seq_ids:
        stamps, gyro, accel, R0 = synthesize_sequence(sid, g_m_s2, w_ie, **kw)
        n_dw = int(round(kw.get('dwell_s', 10.0) * kw.get('rate_hz', 100.0)))
        t = (stamps - stamps[0]) * 1e-9
        N = len(stamps)
        w0 = Window(0, n_dw, float(t[0]), float(t[n_dw - 1]), np.zeros(0))
        w1 = Window(N - n_dw, N, float(t[N - n_dw]), float(t[-1]), np.zeros(0))
        R_end = R0
        for axis, deg in TABLE1[sid][2]:
            R_end = R_end @ Rotation.from_rotvec(np.radians(deg) * np.eye(3)[AXES.index(axis)]
                                                 ).as_matrix()
        seq = SrtSequence(0, w0, w1, TABLE1[sid][2], '+' + TABLE1[sid][0], f'srt:{sid}')
        geo = _Geometry(stamps, [seq], [w0, w1], np.stack([R0, R_end]), g_m_s2, w_ie)
        Js.append(sensitivities(geo, gyro, accel))
        names += geo.row_names
    return np.concatenate(Js), names


# ----------------------------------------------------------------------------- processor
def gyro_bias_from_windows(stamps_ns: NDArray[np.int64], gyro_rad_s: FloatArray,
                           windows: Sequence[Window], R_enu_imu_windows: FloatArray,
                           omega_ie_enu: FloatArray, gyro_noise_rad_s_rt_hz: float,
                           ) -> tuple[FloatArray, FloatArray]:
    """Gyro bias as the mean over all windows of gyro minus the earth rate (Savage 9.4).

    Returns ``(bias, sigma)``; sigma is the larger of the white-noise value over the total
    window time and the scatter of the per-window means (bias instability, mounting).
    """
    means, durs = [], []
    for w, R in zip(windows, R_enu_imu_windows):
        means.append(gyro_rad_s[w.i0:w.i1].mean(axis=0) - R.T @ omega_ie_enu)
        durs.append(w.duration_s)
    m = np.array(means)
    wts = np.array(durs) / np.sum(durs)
    bias = wts @ m
    sig_noise = gyro_noise_rad_s_rt_hz / np.sqrt(np.sum(durs))
    sig_scatter = (np.sqrt(wts @ (m - bias) ** 2 / max(len(m) - 1, 1)) if len(m) > 1
                   else np.zeros(3))
    return bias, np.maximum(sig_noise, sig_scatter)


def _grade_sigmas(grade: ImuGrade | None) -> dict[str, FloatArray]:
    """Assumed one-sigma of every SensorErrors field from an ImuGrade (zeros without one):
    :func:`~imu_calib_ros.core.parameters.grade_sigmas`."""
    return registry.grade_sigmas(grade)


#: SensorErrors field -> CONTRACT 4 key
FIELD_KEYS = KEY_OF_FIELD


def _fields(errors: Any) -> dict[str, FloatArray]:
    return {k: np.array(getattr(errors, k), float) for k in FIELD_KEYS}


@dataclass(frozen=True)
class SrtOptions:
    """Options of Savage's SRT (:func:`estimate`); a misspelt one is a TypeError.

    Attributes
    ----------
    iterations : int
        Re-plays with the updated compensation (Savage sect. 8); 2-3 suffice.
    min_window_s, window_margin_s : float
        Shortest stationary window and the margin cut from its ends
        (:func:`~.windows.stationary_windows`).
    rtol : float
        Relative tolerance of the rank detection (:func:`solve`).
    """

    iterations: int = 3
    min_window_s: float = 4.0
    window_margin_s: float = 0.5
    rtol: float = 1e-2


def calibrate(imu: ImuBatch, joints: JointBatch, fixture: Fixture,
              grade: ImuGrade | None = None, options: SrtOptions = SrtOptions(), *,
              initial: CalibrationResult | None = None) -> CalibrationResult:
    """Savage's SRT as a CalibrationResult (CONTRACT 4); arguments as :func:`estimate`."""
    from ..calibration import CalibrationResult
    errors, sigma, fixed, extra = estimate(imu, joints, fixture, grade, options,
                                           initial=initial)
    return CalibrationResult(errors=errors, sigma=sigma, frame_id=imu.frame_id or 'imu_link',
                             fixed=tuple(fixed), extra=extra)


def _consider_part(sol: LsqResult, J: FloatArray, J_f: FloatArray, prior_sd: FloatArray,
                   sig_f: FloatArray, whiten: Callable[[FloatArray], FloatArray]) -> FloatArray:
    """Consider covariance of ``sol``'s estimates from the fixed terms (:data:`CONSIDER`)
    and from the parameters it does not estimate, at their assumed sigmas (``prior_sd``;
    an unknown one, inf, counts as 0 here)."""
    not_est = ~sol.estimated
    J_all = np.concatenate([J_f, J[:, not_est]], axis=1)
    sig_all = np.concatenate([sig_f, np.where(np.isfinite(prior_sd[not_est]),
                                              prior_sd[not_est], 0.0)])
    if not sol.estimated.any():
        return np.zeros((J.shape[1], J.shape[1]))
    return consider_covariance(whiten(J), np.ones(J.shape[0]), sol.estimated, whiten(J_all),
                               sig_all)[0]


def estimate(imu: ImuBatch, joints: JointBatch, fixture: Fixture,
             grade: ImuGrade | None = None, options: SrtOptions = SrtOptions(), *,
             initial: CalibrationResult | None = None,
             ) -> tuple[SensorErrors, SensorErrors, list[str], dict[str, Any]]:
    """Savage's SRT on a recording: windows, eqs. (1)-(2), linear model, least squares.

    Parameters
    ----------
    imu, joints : ImuBatch, JointBatch
        Raw IMU data (CONTRACT 1) and the fixture's joint states.
    fixture : Fixture
        Nominal fixture (site, joints, nominal IMU mounting).
    grade : ImuGrade, optional
        Gives the assumed sigmas of the parameters the SRT does not estimate; the noise
        used for the sigmas is always measured from the stationary windows; its accelerometer
        bias instability and correlation time give the rows' drift covariance.
    options : SrtOptions
        Iterations, window lengths, rank tolerance.
    initial : CalibrationResult, optional
        Starting compensation (e.g. a previous SRT); its non-estimated values are kept.

    Returns
    -------
    errors, sigma : SensorErrors
    fixed : list of str
        CONTRACT 4 keys not estimated (written at their assumed value and sigma).
    extra : dict
        Estimated: gyro Kg, ag, bias (windows); accel Ka, aa, bias, as far as the sequence
        set excites them; the rest is written at its assumed value and listed as fixed.
        ``extra['srt']`` holds per-sequence measurements, residuals and sensitivities.
    """
    from ..sensor_model import SensorErrors, compensate

    iterations, min_window_s, rtol = options.iterations, options.min_window_s, options.rtol
    windows = stationary_windows(imu, joints, fixture, min_duration_s=min_window_s,
                                 margin_s=options.window_margin_s)
    if len(windows) < 2:
        raise InputError(f'SRT needs stationary windows of >= {min_window_s} s before and '
                         f'after each rotation; found {len(windows)}')
    R_w = fixture.R_enu_imu(np.stack([w.q_rad for w in windows]))
    site = fixture.site
    g = float(site.gravity)
    w_ie = np.asarray(site.omega_ie_enu, float)
    gyro_raw = np.asarray(imu.gyro_rad_s, float)
    accel_raw = np.asarray(imu.accel_m_s2, float)
    seqs = find_sequences(imu.stamps_ns, gyro_raw, windows, R_w)
    if not seqs:
        raise InputError('no rotation sequence between stationary windows in the recording')
    geo = _Geometry(imu.stamps_ns, seqs, list(windows), R_w, g, w_ie)
    ng, na = noise_densities(imu.stamps_ns, gyro_raw, accel_raw, windows)
    sig_y = measurement_sigmas(geo, ng, na)
    R_y = np.diag(sig_y ** 2) + drift_covariance(
        geo, float(getattr(grade, 'accel_bias_instability_m_s2', 0.0) or 0.0),
        float(getattr(grade, 'accel_bias_correlation_s', 0.0) or 0.0))
    L_y = np.linalg.cholesky(R_y)

    def whiten(a: FloatArray) -> FloatArray:
        return scipy.linalg.solve_triangular(L_y, a, lower=True)
    assumed = _grade_sigmas(grade)
    cur = _fields(initial.errors) if initial is not None else _fields(SensorErrors.zeros())
    start = {k: v.copy() for k, v in cur.items()}
    # what is known before the data: the starting calibration's sigmas, else the grade's
    known = _fields(initial.sigma) if initial is not None else assumed
    # sigma of each LS parameter (inf when unknown: never demoted) and of the CONSIDER terms
    prior_sd = np.array([known[fld][idx] if known[fld][idx] > 0 else np.inf
                         for _, fld, idx in PARAMS])
    sig_consider = np.array([known[fld][idx] for _, fld, idx, _ in CONSIDER])
    history = []
    for it in range(max(1, iterations)):
        errs = SensorErrors(**cur)
        omega, f = compensate(errs, gyro_raw, accel_raw)
        omega, f = np.asarray(omega, float), np.asarray(f, float)
        # gyro bias residual from the windows (sect. 9.4), then the SRT rows
        db, sig_bg = gyro_bias_from_windows(imu.stamps_ns, omega, windows, R_w, w_ie, ng)
        cur['gyro_bias_rad_s'] = cur['gyro_bias_rad_s'] + db
        omega = omega - db
        y, _ = measurements(geo, omega, f)
        J = sensitivities(geo, omega, f)
        # generalised LS with the bias-instability row covariance: whiten by its Cholesky
        # factor, then the weighted solver with unit sigmas
        sol = solve(whiten(J), whiten(y), np.ones(y.size), rtol)
        # a parameter the rows determine worse than it is known beforehand (noise and
        # consider sigma) is not estimated: it stays at its assumed value. Before this, two
        # merged sequences gave a -1.6 % accelerometer scale "estimate" with a 3.9 % sigma.
        J_f, B_f = consider_sensitivities(geo, omega, f)
        allowed = np.ones(J.shape[1], bool)
        for _ in range(J.shape[1]):
            sd_total = np.sqrt(np.diag(sol.cov + _consider_part(sol, J, J_f, prior_sd,
                                                                sig_consider, whiten)))
            ratio = np.where(sol.estimated, sd_total / prior_sd, 0.0)
            if not np.any(ratio > 1.0):
                break
            allowed[int(np.argmax(ratio))] = False  # the worst first: the others gain
            sol = solve(whiten(J), whiten(y), np.ones(y.size), rtol, allowed=allowed)
        residual = y - J @ sol.x
        if it == 0:
            y_first = y  # as measured with the initial compensation (the report plots it)
        for fld, val in _errors_from_vector(sol.x).items():
            cur[fld] = cur[fld] + val
        # what this solution does not estimate stays at its starting (assumed) value, also
        # when an earlier iteration had moved it
        for j in np.flatnonzero(~sol.estimated):
            _, fld, idx = PARAMS[j]
            cur[fld][idx] = start[fld][idx]
        history.append({'iteration': it, 'max_abs_correction': float(np.max(np.abs(sol.x))),
                        'gyro_bias_correction_rad_s': db.tolist(),
                        'chi2': sol.chi2, 'dof': sol.dof,
                        'rms_residual_m_s2': float(np.sqrt(np.mean(residual ** 2)))})
    sig = {k: v.copy() for k, v in known.items()}
    # consider covariance: what is held fixed but not zero in truth (G, qa, size effect,
    # and any parameter the sequence set does not excite) biases the estimate; its assumed
    # sigma goes into the estimated parameters' sigma (P += S P_f S^T). J_f, B_f: the last
    # iteration's, on the same compensated stream
    P_c = _consider_part(sol, J, J_f, prior_sd, sig_consider, whiten)
    sd = np.sqrt(np.diag(sol.cov + P_c))
    for fld, val in _errors_from_vector(sd).items():
        mask = _errors_from_vector(sol.estimated.astype(float))[fld] > 0
        sig[fld][mask] = val[mask]
    sig['gyro_bias_rad_s'] = np.sqrt(sig_bg ** 2 + (B_f ** 2) @ sig_consider ** 2)
    fixed = [registry.PARAMETER_OF_FIELD[fld].key for fld in _CONSIDER_STEP]  # G, qa, r
    not_est = [n for n, e in zip(PARAM_NAMES, sol.estimated) if not e]
    for fld, key in FIELD_KEYS.items():
        if any(PARAMS[i][1] == fld for i, n in enumerate(PARAM_NAMES) if n in not_est):
            fixed.append(key)
    row_names = geo.row_names
    seq_info = []
    n_h = 2 * len(seqs)
    for k, s in enumerate(seqs):
        rows = [2 * k, 2 * k + 1]
        seq_info.append({
            'label': s.label, 'down_axis': s.down_axis,
            'rotations': [[a, d] for a, d in s.rotations],
            'start_window_s': [s.start.t0_s, s.start.t1_s],
            'end_window_s': [s.end.t0_s, s.end.t1_s],
            'rows': [row_names[r] for r in rows],
            'delta_a_h_m_s2': [float(y_first[r]) for r in rows],
            'delta_a_h_final_m_s2': [float(y[r]) for r in rows],
            'residual_m_s2': [float(residual[r]) for r in rows],
            'sigma_m_s2': [float(sig_y[r]) for r in rows],
            'sensitivity': {row_names[r]: {PARAM_NAMES[j]: float(J[r, j])
                                           for j in range(J.shape[1])
                                           if abs(J[r, j]) > 1e-3 * g}
                            for r in rows},
        })
    windows_info = [{'t_s': [w.t0_s, w.t1_s], 'down_m_s2_plus_g': float(y_first[n_h + i]),
                     'residual_m_s2': float(residual[n_h + i])}
                    for i, w in enumerate(windows)]
    extra = {'method': 'srt',
             'srt': {'sequences': seq_info, 'windows': windows_info,
                     'not_estimated': not_est, 'iterations': history,
                     'noise': {'gyro_rad_s_rt_hz': ng, 'accel_m_s2_rt_hz': na},
                     'sigma_noise_only': {PARAM_NAMES[j]: float(np.sqrt(sol.cov[j, j]))
                                          for j in np.flatnonzero(sol.estimated)},
                     'consider': {'parameters': [c[0] for c in CONSIDER],
                                  'assumed_sigma': sig_consider.tolist()},
                     'gravity_m_s2': g}}
    return SensorErrors(**cur), SensorErrors(**sig), fixed, extra
