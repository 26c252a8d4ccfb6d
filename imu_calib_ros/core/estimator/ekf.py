"""Filter maths of the calibration EKF: chunk transition matrices, measurements, gated update.

Error dynamics (the convention of :mod:`imu_calib_ros.core.strapdown`, all errors estimate
minus truth: ``R_hat = exp([psi x]) R``, ``dv = v_hat - v``; cf. Titterton & Weston ch. 12):
with the compensated-sample errors ``omega_hat - omega = -M_g x_g`` and
``f_hat - f = -M_a x_a`` and the local-level frame turning at ``Omega`` (earth rate, ENU)::

    psi_dot = -Omega x psi - R M_g x_g
    dv_dot  = -(R f) x psi - 2 Omega x dv - R M_a x_a

Over a chunk of ``n`` samples between two updates the transition matrix is built by
vectorised sums over the samples (no per-sample Python): ``Phi_psi,g = -sum R_k M_g,k dt``,
``Phi_v,a = -sum R_k M_a,k dt``, ``Phi_v,psi = -[(sum R_k f_k dt) x]`` and the second-order
term ``Phi_v,g = sum [(R f)_k x] C_k dt``, ``C_k = sum_{j<=k} R_j M_g,j dt`` (cumulative
sum, trapezoid inside the sample).
All matrices returned here are in the scaled units of the :class:`StateLayout`.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray
from scipy.linalg.lapack import dpotrf as _potrf
from scipy.linalg.lapack import dpotrs as _potrs

from ..rotation import skew
from .quantiles import chi2_ppf
from .error_model import StateLayout

_LOG_2PI = math.log(2.0 * math.pi)

FloatArray = NDArray[np.float64]


def chunk_transition_rows(layout: StateLayout, R_enu_imu: FloatArray, f_enu_m_s2: FloatArray,
                          Mg: FloatArray, Ma: FloatArray, dt_s: FloatArray,
                          omega_ie_enu: FloatArray, Dg_inv: FloatArray | None = None,
                          Da_inv: FloatArray | None = None) -> FloatArray:
    """The six navigation rows of the transition matrices of ``B`` chunks (SI units).

    The rows of the calibration states are those of the identity (constants and random
    walks), so ``Phi = [[Phi_rows], [0 I]]``; :meth:`ErrorStateFilter.predict_rows` uses that.
    Arguments as :func:`chunk_transitions`; returns ``(B, 6, N)``. With ``Dg_inv`` and
    ``Da_inv`` ``(B, n, 3, 3)`` (:func:`.error_model.compensation_inverses`), ``Mg`` and
    ``Ma`` are the raw Jacobians ``M`` of the sensor model and the compensated ones
    ``D^-1 M`` are applied through the left factors of the sums (``(L D^-1) M``: a 6 x 3 and a
    3 x 3 product per sample instead of 3 x 21 and 3 x 25 ones).

    The second-order term is summed by parts, ``sum_k [(R f)_k x] C_k dt =
    sum_j W_j R_j M_g,j dt`` with ``W_j = sum_{k>=j} [(R f)_k x] dt - [(R f)_j x] dt / 2``
    (the same trapezoid), so that both gyro row blocks come out of one batched product
    ``[R dt; W R dt] @ M_g`` over the chunk's samples (``einsum`` was 3x slower here).
    """
    B, n = dt_s.shape
    N = layout.n
    T = dt_s.sum(axis=1)  # (B,)
    rows = np.zeros((B, 6, N))
    Om = skew(omega_ie_enu)
    rows[:, 0:3, 0:3] = np.eye(3) - Om[None] * T[:, None, None]
    rows[:, 3:6, 3:6] = np.eye(3) - 2.0 * Om[None] * T[:, None, None]
    dv_f = (dt_s[:, None, :] @ f_enu_m_s2)[:, 0]  # (B, 3): sum_k (R f)_k dt_k
    rows[:, 3:6, 0:3] = -skew(dv_f)
    gi, ai = layout.gyro_state_idx, layout.accel_state_idx
    if not (gi.size or ai.size):
        return rows
    r_dt = R_enu_imu * dt_s[..., None, None]  # (B, n, 3, 3)
    if gi.size:
        sk = skew(f_enu_m_s2) * dt_s[..., None, None]
        w = np.cumsum(sk[:, ::-1], axis=1)[:, ::-1] - 0.5 * sk  # W_j
        left = np.concatenate([r_dt, w @ r_dt], axis=2)  # (B, n, 6, 3)
        if Dg_inv is not None:
            left = left @ Dg_inv
        left = left.transpose(0, 2, 1, 3).reshape(B, 6, 3 * n)
        g = left @ Mg.reshape(B, 3 * n, Mg.shape[-1])  # (B, 6, 22)
        g = g[..., layout.gyro_cols]
        rows[:, 0:3, gi] = -g[:, 0:3]
        rows[:, 3:6, gi] = g[:, 3:6]
    if ai.size:
        left = (r_dt if Da_inv is None else r_dt @ Da_inv).transpose(0, 2, 1, 3).reshape(
            B, 3, 3 * n)
        a = left @ Ma.reshape(B, 3 * n, Ma.shape[-1])  # (B, 3, 26)
        rows[:, 3:6, ai] = -a[..., layout.accel_cols]
    return rows


def chunk_transitions(layout: StateLayout, R_enu_imu: FloatArray, f_enu_m_s2: FloatArray,
                      Mg: FloatArray, Ma: FloatArray, dt_s: FloatArray,
                      omega_ie_enu: FloatArray) -> FloatArray:
    """Transition matrices of ``B`` chunks of ``n`` samples each (SI units).

    Parameters
    ----------
    layout:
        State layout.
    R_enu_imu:
        ``(B, n, 3, 3)`` navigator attitude at the middle of each sample interval (the mean
        of the attitudes at its ends is enough: at 7 rad/s and 200 Hz the end attitude would
        be off by 1.7 % in every column).
    f_enu_m_s2:
        ``(B, n, 3)`` mean specific force per sample in ENU (``R f``).
    Mg, Ma:
        ``(B, n, 3, 22)``, ``(B, n, 3, 26)`` sensor Jacobians (:mod:`.error_model`) on the
        compensated samples.
    dt_s:
        ``(B, n)`` sample intervals.
    omega_ie_enu:
        ``(3,)`` earth rate in ENU.

    Returns
    -------
    Phi ``(B, N, N)`` in SI units of the error state (see :func:`scale_matrices`); the
    filter itself only uses the six rows of :func:`chunk_transition_rows`.
    """
    rows = chunk_transition_rows(layout, R_enu_imu, f_enu_m_s2, Mg, Ma, dt_s, omega_ie_enu)
    B, N = rows.shape[0], layout.n
    phi = np.broadcast_to(np.eye(N), (B, N, N)).copy()
    phi[:, 0:6, :] = rows
    return phi


def process_noise(layout: StateLayout, T_s: float, gyro_noise_rad_s_rt_hz: float,
                  accel_noise_m_s2_rt_hz: float, gyro_bias_q_rad2_s3: float,
                  accel_bias_q_m2_s5: float) -> FloatArray:
    """Process noise of one chunk of length ``T_s`` in SI units (diagonal).

    White rate/specific-force noise of density N integrates to ``N^2 T`` on psi and dv
    (isotropic, so the rotation R drops out); bias drifts are random walks of PSD q.
    The psi-dv cross term, ``g^2 N_g^2 T^3 / 3``, is below 1e-6 of ``N_a^2 T`` for the shipped
    grades at 10 Hz updates and is left out.
    """
    q = np.zeros(layout.n)
    q[0:3] = gyro_noise_rad_s_rt_hz ** 2 * T_s
    q[3:6] = accel_noise_m_s2_rt_hz ** 2 * T_s
    if 'gyro_bias' in layout.slices:
        q[layout.slices['gyro_bias']] = gyro_bias_q_rad2_s3 * T_s
    if 'accel_bias' in layout.slices:
        q[layout.slices['accel_bias']] = accel_bias_q_m2_s5 * T_s
    return np.diag(q)


def scale_matrices(layout: StateLayout, phi: FloatArray, q: FloatArray) -> tuple[
        FloatArray, FloatArray]:
    """SI ``Phi``, ``Q`` -> scaled units: ``Phi_s = S^-1 Phi S``, ``Q_s = S^-1 Q S^-1``."""
    s = layout.scale
    return phi * (s[None, :] / s[:, None]), q / np.outer(s, s)


@dataclass
class GateCounters:
    """Counts of accepted and rejected measurement updates, by measurement kind."""

    accepted: dict[str, int] = field(default_factory=dict)
    rejected: dict[str, int] = field(default_factory=dict)
    last_nis: dict[str, float] = field(default_factory=dict)
    nis_sum: dict[str, float] = field(default_factory=dict)
    deweighted: dict[str, int] = field(default_factory=dict)  # of the rejected: used, R inflated
    # accepted updates: sums of the normalised innovations y_i / sqrt(S_ii) and of their
    # squares, per component (the history's innovation plot)
    innov_sum: dict[str, FloatArray] = field(default_factory=dict)
    innov_sq: dict[str, FloatArray] = field(default_factory=dict)
    # every update with a positive definite S: the innovations' negative log-likelihood
    # 0.5 (min(NIS, gate) + log det S + m log 2 pi) (a gated one counts at the gate: one
    # outlier must not choose a noise model), and how many updates it sums (runs that sum
    # different numbers of terms are not compared: replay.profile_gyro_walk)
    nll_sum: float = 0.0
    nll_updates: int = 0


class ErrorStateFilter:
    """Scaled error-state Kalman filter: block-form predict, Joseph-form update + chi^2 gate.

    ``x`` and ``P`` are in the scaled units of ``layout``. After every update ``P`` is
    symmetrised. The state is fed back (and zeroed) by the owner, :class:`CalibrationEstimator`.
    :meth:`predict` (filterpy) takes a full ``Phi``; the estimator uses the equivalent
    :meth:`predict_rows`, which is ~3x cheaper for 46 states (only 6 rows of ``Phi`` differ
    from the identity).
    """

    def __init__(self, layout: StateLayout, P0_scaled: FloatArray, gate_probability: float,
                 deweight: bool = False):
        self.layout = layout
        self.x = np.zeros(layout.n)
        self.P = np.array(P0_scaled, float)
        self.gate_probability = gate_probability
        self.deweight = deweight
        self._gate: dict[int, float] = {}
        self._diag = np.arange(layout.n) * (layout.n + 1)  # flat indices of diag(P)
        self.counters = GateCounters()
        # the estimate's derivative along a shift of the initial mean (scaled units), carried
        # through every predict and update as x is (the filter is linear in its initial
        # mean): None unless the owner sets it (a pass started from a previous estimate)
        self.sens: FloatArray | None = None

    def _threshold(self, m: int) -> float:
        if m not in self._gate:
            self._gate[m] = (chi2_ppf(self.gate_probability, m)
                             if self.gate_probability < 1.0 else np.inf)
        return self._gate[m]

    def predict(self, phi_s: FloatArray, q_s: FloatArray) -> None:
        """Propagate ``x`` and ``P`` over one chunk with a full ``Phi`` (filterpy ``predict``)."""
        # imported here: filterpy.kalman imports matplotlib (~1 s at CLI start-up), and the
        # estimator itself only uses predict_rows
        from filterpy.kalman import predict as kf_predict
        self.x, self.P = kf_predict(self.x, self.P, phi_s, q_s)
        if self.sens is not None:
            self.sens = phi_s @ self.sens

    def predict_rows(self, phi_rows_s: FloatArray, q_diag_s: FloatArray) -> None:
        """Same as :meth:`predict` for ``Phi = [[phi_rows_s], [0 I]]`` and ``Q = diag(q)``.

        ``Phi P Phi^T`` by blocks (``A = phi_rows_s``, ``T = A P``): the navigation block is
        ``T A^T``, the navigation-parameter block ``T[:, 6:]``, the parameter block is kept;
        hand-written because filterpy's dense ``F P F^T`` costs two 46^3 products.
        """
        P = self.P
        T = phi_rows_s @ P  # (6, N): rows 0..5 of Phi P
        P[0:6, 6:] = T[:, 6:]
        P[6:, 0:6] = T[:, 6:].T
        P[0:6, 0:6] = T @ phi_rows_s.T
        P.flat[self._diag] += q_diag_s
        self.x[0:6] = phi_rows_s @ self.x
        if self.sens is not None:
            self.sens[0:6] = phi_rows_s @ self.sens

    def update(self, kind: str, z: FloatArray, H_s: FloatArray, R: FloatArray) -> bool:
        """Gated Joseph-form update; returns whether the innovation passed the gate.

        ``P = (I - K H) P (I - K H)^T + K R K^T``, evaluated as one rank-``2m`` correction
        (``M = P - K (P H^T)^T``, ``P = M - (M H^T - K R) K^T`` with ``M H^T - K R = P H^T -
        K S``: the same product without the dense ``I - K H`` or another ``N x N`` product);
        ``S^-1`` through its Cholesky factor (LAPACK ``potrf/potrs``, 2 us
        against 18 us for ``numpy.linalg.inv`` on 3x3). Hand-written instead of filterpy
        ``update``, which recomputes ``S`` and its inverse after our gate and forms the dense
        ``I - K H`` products: it took twice the time of this, a quarter of the filter's time.
        An ``S`` that is not positive definite is rejected like a gated innovation.

        An innovation beyond the gate is counted as gated (``False``) and, with ``deweight``,
        still used with ``R`` inflated by the factor that brings its NIS down to the gate
        (:func:`deweight_factor`; G. Chang, "Robust Kalman filtering based on Mahalanobis
        distance as outlier judging criterion", J. Geodesy 88, 2014): a marginal innovation
        corrects the navigation by a bounded step, a gross outlier by almost nothing (the step
        falls as 1/|y|). Rejected outright, one marginal innovation after the alignment left the
        navigation uncorrected, the next ones beyond the gate too: a cascade and a re-alignment
        (a MEMS unit on the arm: one NIS of 26.0 at a gate of 25.9, then 27 gated in a row).
        """
        P = self.P
        PHt = P @ H_s.T  # (N, m)
        HPHt = H_s @ PHt
        S = HPHt + R
        c = self.counters
        chol, info = _potrf(S)
        y = z - H_s @ self.x
        gate = self._threshold(len(z))
        if info == 0:
            S_inv_y = _potrs(chol, y)[0]
            nis = float(y @ S_inv_y)
            # log det S from the Cholesky factor's diagonal (scaled units: the same offset
            # for every run of one layout)
            c.nll_sum += 0.5 * (min(nis, gate) + len(z) * _LOG_2PI
                                + 2.0 * float(np.log(chol.diagonal()).sum()))
            c.nll_updates += 1
        else:
            nis = np.inf
        c.last_nis[kind] = nis
        passed = bool(np.isfinite(nis) and nis <= gate)
        if not passed:
            c.rejected[kind] = c.rejected.get(kind, 0) + 1
            lam = (deweight_factor(HPHt, R, y, gate)
                   if self.deweight and np.isfinite(nis) else np.inf)
            if not np.isfinite(lam):
                return False
            R = lam * R
            chol, info = _potrf(HPHt + R)
            if info != 0:
                return False
            S_inv_y = _potrs(chol, y)[0]
            c.deweighted[kind] = c.deweighted.get(kind, 0) + 1
        else:
            c.accepted[kind] = c.accepted.get(kind, 0) + 1
            c.nis_sum[kind] = c.nis_sum.get(kind, 0.0) + nis
            e = y / np.sqrt(S.diagonal())
            if kind in c.innov_sum:
                c.innov_sum[kind] += e
                c.innov_sq[kind] += e * e
            else:
                c.innov_sum[kind], c.innov_sq[kind] = e.copy(), e * e
        K = _potrs(chol, PHt.T)[0].T  # P H^T S^-1
        self.x = self.x + PHt @ S_inv_y
        if self.sens is not None:
            self.sens = self.sens - K @ (H_s @ self.sens)
        # Joseph form: with M = (I - K H) P = P - K (P H^T)^T (P symmetric up to rounding),
        # M H^T - K R = P H^T - K S, so P <- M - (P H^T - K S) K^T: one rank-2m product
        X = PHt - K @ (HPHt + R)
        P = P - np.concatenate([K, X], axis=1) @ np.concatenate([PHt, K], axis=1).T
        self.P = 0.5 * (P + P.T)
        return passed


def deweight_factor(HPHt: FloatArray, R: FloatArray, y: FloatArray, gate: float) -> float:
    """The ``lam >= 1`` with ``y^T (H P H^T + lam R)^-1 y = gate`` (Chang 2014), inf if none.

    With ``R = L L^T`` and ``L^-1 H P H^T L^-T = U diag(a) U^T`` the NIS is
    ``sum_i u_i^2 / (a_i + lam)``, ``u = U^T L^-1 y``: decreasing in ``lam``, solved by
    Brent's method on ``log lam``.
    """
    from scipy.optimize import brentq
    try:
        L = np.linalg.cholesky(R)
    except np.linalg.LinAlgError:
        return np.inf
    Li = np.linalg.inv(L)
    a, U = np.linalg.eigh(Li @ HPHt @ Li.T)
    a = np.clip(a, 0.0, None)
    u2 = (U.T @ (Li @ y)) ** 2

    def excess(log_lam: float) -> float:
        return float(np.sum(u2 / (a + math.exp(log_lam)))) - gate

    hi = 60.0  # lam = 1e26: any finite innovation is within the gate there
    if not (np.all(np.isfinite(u2)) and excess(0.0) > 0.0 and excess(hi) < 0.0):
        return np.inf
    return math.exp(brentq(excess, 0.0, hi, xtol=1e-10))
