"""Streaming augmented-state error EKF for turntable IMU calibration (issue 3).

See docs/ESTIMATOR.md for the design, the state vector and the measurements.
"""
from .config import EstimatorConfig, load_estimator_config
from .estimator import CalibrationEstimator, Estimate

__all__ = ['CalibrationEstimator', 'Estimate', 'EstimatorConfig', 'load_estimator_config']
