"""Diagnostics text (core/diagnostics.py) and the one owner of rejection labels
(core/input_guard.rejection_counts): pure functions, no ROS."""
from __future__ import annotations

import math

import numpy as np

from imu_calib_ros.core.calibration import CalibrationResult
from imu_calib_ros.core.diagnostics import frame_mismatch, health_values, last_good_values
from imu_calib_ros.core.input_guard import IMU_REASONS, JOINT_REASONS, rejection_counts
from imu_calib_ros.core.sensor_model import SensorErrors
from imu_calib_ros.core.units import DEG_H_RAD_S, UG_M_S2


def test_rejection_counts_label_each_source_once() -> None:
    guard = {r: 0 for r in IMU_REASONS + JOINT_REASONS}
    guard.update(all_zero=4, joint_duplicate_stamp=2)
    node = {'frame_id': 3, 'non_finite': 0}
    assert rejection_counts(guard, node) == {'node.frame_id': 3, 'guard.all_zero': 4,
                                             'guard.joint_duplicate_stamp': 2}
    assert rejection_counts(None) == {}


def test_health_values_hide_copies_zeros_and_reprs() -> None:
    errors = SensorErrors.zeros().replace(
        gyro_bias_rad_s=np.array([1.0, 2.0, -3.0]) * DEG_H_RAD_S,
        accel_bias_m_s2=np.array([10.0, 0.0, -5.0]) * UG_M_S2)
    good = CalibrationResult(errors, SensorErrors.zeros(), 'imu_link')
    health = {'imu_samples': 100, 'chunks': 0, 'imu_out_of_order': 2, 'gaps': 1,
              'rejected': {'out_of_order': 2, 'all_zero': 0}, 'rejected_total': 2,
              'flagged': {'gap': 1, 'long_gap': 0}, 'accepted': {'zupt': 5},
              'gate_accepted': {'zupt': 5}, 'gate_rejected': {'zupt': 0},
              'mean_nis': {'zupt': math.nan}, 'running': False, 'status': 'WARN',
              'divergence_reason': '', 'dropped_groups': [], 'last_good': good,
              'stopped_for_s': 0.0, 'covariance_asymmetry': 0.0, 'processed_s': 1.5}
    values = health_values(health)
    assert values == {
        'estimator.imu_samples': '100', 'estimator.flagged.gap': '1',
        'estimator.gate_accepted.zupt': '5', 'estimator.mean_nis.zupt': 'not finite',
        'estimator.running': 'False', 'estimator.status': 'WARN',
        'estimator.processed_s': '1.5',
        'estimator.last_good.gyro_bias_deg_h': '1, 2, -3',
        'estimator.last_good.gyro_scale_ppm': '0, 0, 0',
        'estimator.last_good.accel_bias_ug': '10, 0, -5',
        'estimator.last_good.accel_scale_ppm': '0, 0, 0'}, values
    assert last_good_values(None) == {}


def test_frame_mismatch_only_when_every_sample_was_rejected() -> None:
    assert frame_mismatch(0, 0, '', 'imu_link') == ''
    assert frame_mismatch(10, 9, 'imu_front', 'imu_link') == ''
    line = frame_mismatch(10, 10, 'imu_front', 'imu_link')
    assert '"imu_front" received' in line and '"imu_link" expected' in line
