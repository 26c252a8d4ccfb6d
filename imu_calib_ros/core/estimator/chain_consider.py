"""What an arm's own errors leave in the mounting and lever-arm estimates (issue 15 item 4).

On a general chain the encoder attitude and the encoder velocity of the IMU point are wrong by
the arm's joint zero offsets ``dq`` and joint-origin (link) errors ``dl``. The zero offsets are
filter states (``joint_offset``, issue 15 arm10): the estimator then asks for the link share
only (``covariance(0, sigma_l)``) and adds no attitude normal equations. With
``estimate_joint_offset`` off, the filter bounds both errors' effect per update in the
measurement noise (:func:`.measurements.chain_velocity_covariance`,
:func:`.measurements.chain_attitude_covariance`), but the mounting rotation ``mu`` and the lever
arm ``rho`` are fitted to those very measurements: a systematic ``dq``/``dl`` leaves in them
its weighted average over the poses (and motions) of the run. That share is a *consider*
covariance (Bierman, "Factorization Methods for Discrete Sequential Estimation", 1977, ch. VIII:
parameters not estimated but whose uncertainty is carried): with the measurements'
generalised least squares over the run,

    mu  = G_mu  [dq_j]          G_mu  = (sum H_a^T W H_a)^-1 sum H_a^T W [u_j]
    rho = G_rho [dq_j, dl_jk]   G_rho = (sum H_v^T W H_v)^-1 sum H_v^T W [dv/dq_j, dv/dl_jk]

``H_a = [e_up, R_enu_imu]`` (the navigated heading is free, the tilt is held by gravity; ``mu``
in the IMU frame), ``u_j`` joint j's axis in ENU (an offset turns the IMU by ``dq_j u_j``);
``H_v = R_enu_imu [omega_eb_imu x]`` over the chunks where the arm moves, ``dv/dq_j`` and
``dv/dl_jk`` (link j's origin moved along axis k of its parent frame) by differences of
``Fixture.anchor_velocity_enu_m_s``; ``W = I``: every update counts alike. The covariance added
to the reported ``mu`` and ``rho`` blocks is ``sigma_q^2 G_mu G_mu^T`` and
``sigma_q^2 G_q G_q^T + sigma_l^2 G_l G_l^T``.

Why equal weights and not the updates' ``R^-1``: the filter does not fit ``mu`` and ``rho``
alone; the navigation errors between updates take up much of what ``R^-1`` would put on the
precise updates. Measured on bench/bench_arm.py's arm (arm6_excitation, 1 mrad / 2 mm,
seeds 1-3): the equal-weight fit predicted the mounting-about-z errors the filter made
(-1177/-394/-1984 urad predicted, -856/-245/-1930 made, before the last joint's offset was
counted as mounting) and the lever arm's (e.g. seed 3: -1.48/-1.44/-3.77 mm predicted,
-1.46/-1.08/-4.03 made), the ``R^-1``-weighted one a third of the mounting's and none of the
lever arm's.

Not in it: the last joint's zero offset and the part of its origin error along its axis (all
of it for a prismatic last joint). Those are *exactly* a mounting rotation and a lever arm
(the IMU sits on the last link: whatever the joint angles, the last link's frame at its encoder
zero carries them), so the reported mounting and lever arm are the IMU's on the last link *as
its encoder reads it* (:func:`.truth.calibration_truth` compares them with that truth) and no
sigma is added for them.
"""
from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from .measurements import link_error_chains

FloatArray = NDArray[np.float64]
_UP = np.array([0.0, 0.0, 1.0])
_DL_M = 1e-3  # link perturbation for the velocity differences [m]
_DQ_RAD = 1e-6  # zero-offset perturbation [rad]


def _skew(v: FloatArray) -> FloatArray:
    S = np.zeros(v.shape[:-1] + (3, 3))
    S[..., 0, 1], S[..., 0, 2], S[..., 1, 2] = -v[..., 2], v[..., 1], -v[..., 0]
    S[..., 1, 0], S[..., 2, 0], S[..., 2, 1] = v[..., 2], -v[..., 1], v[..., 0]
    return S


class ChainConsider:
    """Normal equations of the mounting and lever-arm fits over a run (module docstring);
    data only, so they survive the filter's re-alignments and restarts."""

    def __init__(self, fixture: Any) -> None:
        self.fixture = fixture
        n = fixture.n_joints
        # zero offsets that are not the mounting: the revolute joints before the last
        self._q_joints = [j for j in range(n - 1) if fixture.joints[j].revolute]
        self._links = link_error_chains(fixture, _DL_M)[1:]
        m_q, m_l = len(self._q_joints), len(self._links)
        self.A_mu = np.zeros((4, 4))
        self.B_mu = np.zeros((4, m_q))
        self.A_rho = np.zeros((3, 3))
        self.B_rho = np.zeros((3, m_q + m_l))

    def add_attitude(self, q: FloatArray, R_enu_imu: FloatArray) -> None:
        """Encoder-attitude updates at joint angles ``q`` (B, n), navigated attitude
        (B, 3, 3)."""
        if not len(q):
            return
        H = np.concatenate([np.broadcast_to(_UP[None, :, None], (len(q), 3, 1)), R_enu_imu], 2)
        self.A_mu += np.einsum('bki,bkj->ij', H, H)
        if self._q_joints:
            U = self.fixture.angular_axes_enu(q)[:, self._q_joints, :]  # (B, m, 3)
            self.B_mu += np.einsum('bki,bmk->im', H, U)

    def add_velocity(self, q: FloatArray, qd: FloatArray, R_enu_imu: FloatArray) -> None:
        """Chain-velocity updates (only those where a joint moves count) at joint angles and
        rates ``q, qd`` (B, n), navigated attitude (B, 3, 3)."""
        moving = np.any(qd != 0.0, axis=1)
        if not moving.any():
            return
        q, qd, R = q[moving], qd[moving], R_enu_imu[moving]
        fx = self.fixture
        w_enu = np.einsum('bji,bj->bi', fx.angular_axes_enu(q), qd)
        w_imu = np.einsum('bji,bj->bi', R, w_enu)
        H = R @ _skew(w_imu)
        HtW = np.swapaxes(H, 1, 2)
        self.A_rho += np.einsum('bil,blj->ij', HtW, H)
        v0 = fx.anchor_velocity_enu_m_s(q, qd)
        cols = []
        for j in self._q_joints:
            dq = np.zeros(fx.n_joints)
            dq[j] = _DQ_RAD
            cols.append((fx.anchor_velocity_enu_m_s(q + dq, qd) - v0) / _DQ_RAD)
        for pert in self._links:
            cols.append((pert.anchor_velocity_enu_m_s(q, qd) - v0) / _DL_M)
        if cols:
            D = np.stack(cols, axis=2)  # (B, 3, m)
            self.B_rho += np.einsum('bil,blm->im', HtW, D)

    def covariance(self, joint_offset_sigma_rad: float,
                   link_sigma_m: float) -> tuple[FloatArray, FloatArray]:
        """Consider covariances (3, 3) of the mounting [rad^2] and the lever arm [m^2]; zero
        where nothing was accumulated."""
        C_mu = np.zeros((3, 3))
        C_rho = np.zeros((3, 3))
        # pinv: a direction no update constrains keeps its prior sigma in the filter
        if self.B_mu.size and self.A_mu.any():
            G = (np.linalg.pinv(self.A_mu, rcond=1e-9, hermitian=True) @ self.B_mu)[1:]
            C_mu = joint_offset_sigma_rad ** 2 * G @ G.T
        if self.B_rho.size and self.A_rho.any():
            G = np.linalg.pinv(self.A_rho, rcond=1e-9, hermitian=True) @ self.B_rho
            m_q = len(self._q_joints)
            C_rho = (joint_offset_sigma_rad ** 2 * G[:, :m_q] @ G[:, :m_q].T
                     + link_sigma_m ** 2 * G[:, m_q:] @ G[:, m_q:].T)
        return C_mu, C_rho
