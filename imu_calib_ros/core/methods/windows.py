"""Stationary-window detection from joint states and from the IMU itself.

Savage's SRT (sect. 4) averages the accelerometers over ~10 s stationary periods before and
after each rotation sequence; the same windows give the gyro-bias mitigation of his sect. 9.4
and the noise densities used for the sigmas. A sample is stationary when (a) every fixture
joint rate is below ``joint_rate_tol_rad_s`` (joint rates from the positions, unwrapped, so
wrapped and continuous encoders both work) and (b) the gyro, averaged over
``imu_smooth_s``, minus the earth rate seen in the IMU frame is below ``gyro_tol_rad_s``.
Runs shorter than ``min_duration_s`` after trimming ``margin_s`` at both ends are dropped.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray
from scipy.ndimage import binary_erosion, uniform_filter1d

from ..errors import InputError
from ..types import ImuBatch, JointBatch

if TYPE_CHECKING:
    from ..fixture import Fixture

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class Window:
    """A stationary window: IMU samples ``i0 <= i < i1`` and the mean joint angles.

    Attributes
    ----------
    i0, i1 : int
        IMU sample index range (half open).
    t0_s, t1_s : float
        Times of the first and last sample, seconds from the first IMU stamp.
    q_rad : (n,) ndarray
        Mean fixture joint positions over the window, in ``fixture.joint_names`` order.
    """

    i0: int
    i1: int
    t0_s: float
    t1_s: float
    q_rad: FloatArray

    @property
    def duration_s(self) -> float:
        """Length of the window in seconds."""
        return self.t1_s - self.t0_s


def joint_positions(joints: JointBatch, joint_names: tuple[str, ...]) -> FloatArray:
    """Positions of the named joints, unwrapped, as ``(M, n)`` in ``joint_names`` order.

    Raises
    ------
    InputError
        If a fixture joint is missing from the joint states.
    """
    idx = []
    for name in joint_names:
        if name not in joints.names:
            raise InputError(f'joint states lack fixture joint {name!r} '
                             f'(have {list(joints.names)}): check --joint-topic and the fixture')
        idx.append(joints.names.index(name))
    return np.unwrap(np.asarray(joints.positions_rad, float)[:, idx], axis=0)


def joints_at(stamps_ns: NDArray[np.int64], joints: JointBatch,
              joint_names: tuple[str, ...]) -> FloatArray:
    """Joint positions linearly interpolated to the given stamps, ``(N, n)``."""
    q = joint_positions(joints, joint_names)
    t_ref = joints.stamps_ns[0]
    tj = (joints.stamps_ns - t_ref) * 1e-9
    ti = (np.asarray(stamps_ns) - t_ref) * 1e-9
    return np.stack([np.interp(ti, tj, q[:, k]) for k in range(q.shape[1])], axis=1)


def _runs(mask: NDArray[np.bool_]) -> list[tuple[int, int]]:
    """Half-open index ranges of the True runs of a boolean array."""
    m = np.concatenate([[False], mask, [False]]).astype(np.int8)
    d = np.diff(m)
    return list(zip(np.flatnonzero(d == 1).tolist(), np.flatnonzero(d == -1).tolist()))


def stationary_windows(imu: ImuBatch, joints: JointBatch, fixture: Fixture, *,
                       joint_rate_tol_rad_s: float = 2e-3, gyro_tol_rad_s: float = 5e-3,
                       imu_smooth_s: float = 0.5, min_duration_s: float = 4.0,
                       margin_s: float = 0.5) -> list[Window]:
    """Find the stationary windows of a recording.

    Parameters
    ----------
    imu, joints : ImuBatch, JointBatch
        The recording (IMU in its body frame; joint states of the fixture).
    fixture : Fixture
        Gives the joint names, the kinematics ``R_enu_imu(q)`` and the site's earth rate.
    joint_rate_tol_rad_s, gyro_tol_rad_s : float
        Thresholds on every joint rate and on the norm of the smoothed gyro minus earth rate.
    imu_smooth_s : float
        Moving-average length applied to the gyro before thresholding (noise).
    min_duration_s, margin_s : float
        Minimum kept length after trimming ``margin_s`` at both ends of each run.

    Returns
    -------
    list of Window
        In time order.
    """
    n_imu = len(imu)
    if n_imu < 2 or len(joints) < 2:
        raise InputError('too few IMU or joint samples to find stationary windows')
    names = tuple(fixture.joint_names)
    qj = joint_positions(joints, names)
    tj = (joints.stamps_ns - joints.stamps_ns[0]) * 1e-9
    t_imu = (imu.stamps_ns - joints.stamps_ns[0]) * 1e-9
    dt_imu = float(np.median(np.diff(imu.stamps_ns))) * 1e-9
    # (a) joints at rest: rate from positions over ~0.1 s to beat encoder noise
    qdot = np.gradient(qj, tj, axis=0)
    k_j = max(1, int(round(0.1 / max(float(np.median(np.diff(tj))), 1e-6))))
    qdot = uniform_filter1d(qdot, k_j, axis=0, mode='nearest')
    still_j = np.all(np.abs(qdot) < joint_rate_tol_rad_s, axis=1).astype(float)
    still_j_imu = np.interp(t_imu, tj, still_j) > 0.999
    still_j_imu &= (t_imu >= tj[0]) & (t_imu <= tj[-1])
    # (b) IMU at rest: gyro minus the earth rate in the IMU frame
    q_imu = np.stack([np.interp(t_imu, tj, qj[:, k]) for k in range(qj.shape[1])], axis=1)
    R_enu_imu = fixture.R_enu_imu(q_imu)
    w_e_imu = np.einsum('nji,j->ni', R_enu_imu, np.asarray(fixture.site.omega_ie_enu, float))
    k_i = max(1, int(round(imu_smooth_s / dt_imu)))
    w_s = uniform_filter1d(np.asarray(imu.gyro_rad_s, float) - w_e_imu, k_i, axis=0,
                           mode='nearest')
    still_i = np.linalg.norm(w_s, axis=1) < gyro_tol_rad_s
    still = still_j_imu & still_i
    k_m = int(round(margin_s / dt_imu))
    if k_m > 0:
        still = binary_erosion(still, np.ones(2 * k_m + 1, bool), border_value=0)
    out = []
    t0_ns = imu.stamps_ns[0]
    for i0, i1 in _runs(still):
        t0 = (imu.stamps_ns[i0] - t0_ns) * 1e-9
        t1 = (imu.stamps_ns[i1 - 1] - t0_ns) * 1e-9
        if t1 - t0 + dt_imu < min_duration_s:
            continue
        out.append(Window(i0, i1, t0, t1, q_imu[i0:i1].mean(axis=0)))
    return out
