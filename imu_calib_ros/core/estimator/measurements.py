"""Measurement models of the filter: zero velocity with the lever arm, encoder attitude.

Pure functions of their inputs, vectorised over the ``B`` chunk ends of a block. Each
returns the innovation ``z`` (predicted from the navigator minus what the fixture says) and
its Jacobian ``H`` with respect to the error state (estimate minus truth, the layout of
:class:`~.error_model.StateLayout`, SI units), so that ``z = H x + noise`` to first order;
:func:`to_filter_units` scales both for the filter (velocities in um/s, attitudes in urad,
states in the layout's engineering units). ``test/test_measurements.py`` checks every
Jacobian column against finite differences of ``z``.

Conventions (``error_model``, ``strapdown``): ``R_hat = exp([psi x]) R``, ``v_hat = v + dv``,
``rho_hat = rho + x_rho``, the mounting ``exp(mu_hat) = exp(mu) exp(x_mu)`` (the feedback
applies ``exp(mu) = exp(mu_hat) exp(-x_mu)``) and, on a general chain, the joint zero offsets
``o_hat = o + x_o`` (the joint is at ``q + o`` when its encoder reads ``q``; the chain's
kinematics are evaluated at ``q + o_hat``).
"""
from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from ..rotation import skew
from .error_model import StateLayout

if TYPE_CHECKING:
    from ..fixture import Fixture

FloatArray = NDArray[np.float64]
MEAS_SCALE = 1e-6  # velocity measurements in um/s, attitude in urad inside the filter
MEASUREMENT_DOF = 3  # every measurement update is 3-D (velocity, attitude)


def zero_velocity(v_enu_m_s: FloatArray, R_enu_imu: FloatArray, omega_ib_imu_rad_s: FloatArray,
                  omega_ie_enu_rad_s: FloatArray, rho_imu_m: FloatArray,
                  layout: StateLayout, v_anchor_enu_m_s: FloatArray | None = None,
                  dv_anchor_do: FloatArray | None = None) -> tuple[FloatArray, FloatArray]:
    """Zero velocity of the turntable with the lever arm (METHODS.md, "cuts across"), or the
    chain velocity of a general fixture (issue 15: a robot arm).

    On a rigid fixture the IMU reference point, ``rho`` from the axes' common point, moves
    with ``v_enu = R_enu_imu (omega_eb_imu x rho)``, ``omega_eb = omega_ib - R^T omega_ie``.
    On a general chain ``rho`` is measured from the anchor (the innermost joint frame's
    origin), which itself moves with ``v_anchor`` (``Fixture.anchor_velocity_enu_m_s`` at the
    encoder angles and rates): ``v_enu = v_anchor + R_enu_imu (omega_eb_imu x rho)``, the same
    ``H``, plus the joint zero offsets' columns: ``v_anchor`` is evaluated at ``q + o_hat``, so
    ``v_anchor(q + o_hat) = v_anchor(q + o) + (dv_anchor/dq) x_o`` and ``H_o = -dv_anchor/dq``
    over the offset joints (``Fixture.anchor_velocity_jacobian_q``).
    The innovation is the navigated velocity minus that:
    ``z = v_hat - R_hat (omega_eb x rho_hat) = dv + [(R u) x] psi - R [omega_eb x] x_rho``,
    ``u = omega_eb x rho``. Not in ``H``: the earth-rate part of ``omega_eb`` through psi
    (``|Omega_ie| |rho|`` per radian, < 1e-5 m/s/rad) and the gyro errors through ``omega``
    (the rate error times ``rho``): both second order at the filter's working point.

    Parameters
    ----------
    v_enu_m_s : (B, 3)
        Navigated velocity at the chunk ends.
    v_anchor_enu_m_s : (B, 3), optional
        Velocity of the anchor from the joint encoders (general chains); None: zero.
    dv_anchor_do : (B, 3, k), optional
        ``d v_anchor / d q`` of the ``k`` joints whose zero offsets are states (the layout's
        ``joint_offset`` group, in its order); None: no such columns.
    R_enu_imu : (B, 3, 3)
        Navigated attitude at the chunk ends.
    omega_ib_imu_rad_s : (B, 3)
        Compensated angular rate at the chunk-end instants, IMU frame.
    omega_ie_enu_rad_s : (3,)
        Earth rate in ENU.
    rho_imu_m : (3,)
        Lever arm estimate, IMU frame.
    layout :
        The state layout (``H`` columns; the lever-arm column only if it is a state).

    Returns
    -------
    z : (B, 3) [m/s]
    H : (B, 3, n) [m/s per SI state unit]
    """
    w_eb = omega_ib_imu_rad_s - omega_ie_enu_rad_s @ R_enu_imu  # R^T omega_ie per chunk end
    u = w_eb @ skew(rho_imu_m)  # omega_eb x rho (np.cross costs 10x on (B, 3))
    Ru = (R_enu_imu @ u[:, :, None])[:, :, 0]
    z = v_enu_m_s - Ru
    if v_anchor_enu_m_s is not None:
        z = z - v_anchor_enu_m_s
    H = np.zeros((len(z), 3, layout.n))
    H[:, :, 3:6] = np.eye(3)
    H[:, :, 0:3] = skew(Ru)
    if 'lever_arm' in layout.slices:
        H[:, :, layout.slices['lever_arm']] = -R_enu_imu @ skew(w_eb)
    if dv_anchor_do is not None and layout.n_joint_offsets:
        H[:, :, layout.slices['joint_offset']] = -dv_anchor_do
    return z, H


def encoder_attitude(R_enu_imu: FloatArray, R_enu_imu_fixture: FloatArray,
                     mounting_rotvec_rad: FloatArray,
                     layout: StateLayout, offset_axes_enu: FloatArray | None = None
                     ) -> tuple[FloatArray, FloatArray]:
    """Attitude from the joint encoders with the mounting rotation (issue 11 aiding).

    The fixture kinematics at the encoder angles give ``R_fix(q)``; with the mounting
    ``R_pred = R_fix(q) exp(mu_hat)``. The innovation is the rotation vector of
    ``R_hat R_pred^T = exp([psi x]) exp(-[(R x_mu) x])``: ``z = psi - R x_mu`` to first order.
    On a general chain with zero-offset states ``R_fix`` is taken at ``q + o_hat``; turning
    joint ``j`` by ``x_j`` turns every frame beyond it about its ENU axis ``u_j``:
    ``R_fix(q + o_hat) = exp([(sum_j u_j x_j) x]) R_fix(q + o)``, so ``z = psi - R x_mu -
    sum_j u_j x_j`` (``H_o = -u_j``).

    Parameters
    ----------
    R_enu_imu : (B, 3, 3)
        Navigated attitude at the chunk ends.
    R_enu_imu_fixture : (B, 3, 3)
        ``fixture.R_enu_imu(q)`` at the encoder angles of the same instants (nominal
        mounting).
    mounting_rotvec_rad : (3,)
        Mounting rotation estimate, IMU frame.
    layout :
        The state layout (the mounting column only if it is a state).
    offset_axes_enu : (B, k, 3), optional
        ENU axes of the ``k`` joints whose zero offsets are states (``joint_offset`` order),
        at ``q + o_hat``; None: no such columns.

    Returns
    -------
    z : (B, 3) [rad]
    H : (B, 3, n) [rad per SI state unit]
    """
    R_pred = R_enu_imu_fixture @ Rotation.from_rotvec(mounting_rotvec_rad).as_matrix()
    z = Rotation.from_matrix(R_enu_imu @ np.swapaxes(R_pred, 1, 2)).as_rotvec()
    H = np.zeros((len(z), 3, layout.n))
    H[:, :, 0:3] = np.eye(3)
    if 'mounting' in layout.slices:
        H[:, :, layout.slices['mounting']] = -R_enu_imu
    if offset_axes_enu is not None and layout.n_joint_offsets:
        H[:, :, layout.slices['joint_offset']] = -np.swapaxes(offset_axes_enu, 1, 2)
    return z, H


def to_filter_units(z: FloatArray, H: FloatArray,
                    scale: FloatArray) -> tuple[FloatArray, FloatArray]:
    """``z`` and ``H`` (SI) in the filter's units: ``z / MEAS_SCALE``; ``H`` per scaled state
    (``H * scale / MEAS_SCALE``, in place)."""
    H *= scale[None, None, :] / MEAS_SCALE
    return z / MEAS_SCALE, H


def noise_covariance(sigma: float) -> FloatArray:
    """``R`` of a 3-D measurement with one-sigma ``sigma`` (SI) in the filter's units."""
    return np.eye(3) * (sigma / MEAS_SCALE) ** 2


def chain_velocity_covariance(fixtures: tuple[Any, ...], q: FloatArray, qd: FloatArray,
                              joint_offset_sigma_rad: float, link_sigma_m: float,
                              qd_sigma_rad_s: float, correlation: float) -> FloatArray:
    """Covariance (B, 3, 3) [m^2/s^2] of a general chain's anchor velocity from the encoders
    (issue 15 item 4): what the arm's errors and the encoder noise can do to it.

    ``fixtures[0]`` is the nominal chain, ``fixtures[1:]`` the same chain with one joint
    origin moved by 1 mm along one coordinate each (:func:`link_error_chains`: three per
    joint origin; along the link only, the bound was 0.57 mm/s rms over arm6's generated
    plan where the simulated 2 mm arm errors made 1.0-1.7 mm/s). Zero-offset sensitivities
    are ``dv/dq_j`` (a zero offset is an angle error), link ones ``dv/dl_jk``, both by
    differences of ``anchor_velocity_enu_m_s`` (exactly linear in qd, so they vanish at
    rest); the rate noise enters through ``dv/dqd_j`` for joints that move. The arm errors
    are systematic over a move: their share is multiplied by ``correlation`` (the number of
    updates one error spans), so that the filter, which takes updates as independent,
    cannot average them away.
    """
    fx = fixtures[0]
    B, n = q.shape
    v0 = fx.anchor_velocity_enu_m_s(q, qd)
    C = np.zeros((B, 3, 3))
    h = 1e-6
    if joint_offset_sigma_rad > 0:
        for j in range(n):
            if not fx.joints[j].revolute:
                continue
            dq = np.zeros(n)
            dq[j] = h
            D = (fx.anchor_velocity_enu_m_s(q + dq, qd) - v0) / h
            C += joint_offset_sigma_rad ** 2 * D[:, :, None] * D[:, None, :]
    if link_sigma_m > 0:
        for pert in fixtures[1:]:
            D = (pert.anchor_velocity_enu_m_s(q, qd) - v0) / 1e-3
            C += link_sigma_m ** 2 * D[:, :, None] * D[:, None, :]
    C *= correlation
    if qd_sigma_rad_s > 0:
        moving = qd != 0.0
        for j in range(n):
            if not moving[:, j].any():
                continue
            e = np.zeros((B, n))
            e[:, j] = 1.0
            D = fx.anchor_velocity_enu_m_s(q, e) * moving[:, j, None]
            C += qd_sigma_rad_s ** 2 * D[:, :, None] * D[:, None, :]
    return C


def chain_attitude_covariance(fixture: Fixture, q: FloatArray, joint_offset_sigma_rad: float,
                              correlation: float) -> FloatArray:
    """Covariance (B, 3, 3) [rad^2] of the encoder attitude of a general chain from its joint
    zero offsets: an offset ``dq_j`` turns the IMU by ``dq_j u_j`` (ENU); systematic over a
    dwell, hence ``correlation`` as in :func:`chain_velocity_covariance`. Only with
    ``estimate_joint_offset`` off: the offset error is constant over a whole dwell and
    repeats at each return to a pose, which no correlation factor describes (a 3.3 sigma
    gyro g-sensitivity on bench_arm, docs/ESTIMATOR.md arm9); as states they have none."""
    u = fixture.angular_axes_enu(q)  # (B, n, 3)
    return (joint_offset_sigma_rad ** 2 * correlation) * np.einsum('bni,bnj->bij', u, u)


def last_link_directions(fixture: Any) -> FloatArray:
    """Unit directions (k, 3) in the last joint's parent frame along which its origin error is
    *not* a lever arm: the two perpendicular to its axis (revolute), none (prismatic)."""
    jn = fixture.joints[-1]
    if not jn.revolute:
        return np.zeros((0, 3))
    a = np.asarray(jn.axis, dtype=float)
    if jn.origin_R is not None:
        a = np.asarray(jn.origin_R) @ a
    P = np.eye(3) - np.outer(a, a)
    w, V = np.linalg.eigh(P)
    return V[:, w > 0.5].T  # type: ignore[no-any-return]


def link_error_chains(fixture: Fixture, dl_m: float = 1e-3) -> tuple[Any, ...]:
    """``(fixture, copies with one joint origin moved by dl_m along one coordinate ...)``:
    every joint with an origin, along the three axes of its parent frame (an uncalibrated
    arm's origin errors are per coordinate, ``fixture.perturbed_chain``), the last joint only
    along :func:`last_link_directions` (the rest of its origin error is a lever arm, a state).
    The link sensitivities of :func:`chain_velocity_covariance` and
    :class:`.chain_consider.ChainConsider`."""
    from dataclasses import replace
    out = [fixture]
    n = fixture.n_joints
    for j, joint in enumerate(fixture.joints):
        if joint.origin_xyz_m is None:
            continue
        dirs = last_link_directions(fixture) if j == n - 1 else np.eye(3)
        for d in dirs:
            joints = list(fixture.joints)
            joints[j] = replace(joint, origin_xyz_m=np.asarray(joint.origin_xyz_m) + dl_m * d)
            out.append(fixture.with_joints(tuple(joints)))
    return tuple(out)
