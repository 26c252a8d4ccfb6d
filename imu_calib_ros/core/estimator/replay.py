"""Offline replay: a loop over a bag pushing samples into the streaming estimator.

Iteration (Savage, "Improved strapdown IMU calibration procedures", sect. 8; PSINS's passes):
each pass re-plays the whole bag with the compensation of the previous pass as the starting
point; the prior covariance is the grade's again, so the data are counted once. Memory is
bounded: the bag is streamed (``iter_bag``) and pushed in batches of ``batch`` IMU samples.
"""
from __future__ import annotations

from typing import Any, Callable

import numpy as np

from ..errors import InputError
from ..types import ImuBatch, ImuSample
from .config import EstimatorConfig
from .estimator import CalibrationEstimator, Estimate


def replay_pass(samples: Any, fixture: Any, grade: Any, config: EstimatorConfig,
                initial: Estimate | None = None, batch: int = 4000,
                progress: Callable[[int], None] | None = None) -> CalibrationEstimator:
    """Run one pass over ``samples`` (an iterable of ImuSample / JointSample in stamp order).

    Raises
    ------
    InputError
        No IMU samples, no joint states of the fixture's joints, no stationary window for the
        alignment, or no motion.
    """
    est = CalibrationEstimator(fixture, grade, config, initial=initial)
    buf: list[ImuSample] = []
    q_min = q_max = None
    for s in samples:
        if isinstance(s, ImuSample):
            buf.append(s)
            if len(buf) >= batch:
                est.push_imu_batch(ImuBatch.from_samples(buf))
                if progress is not None:
                    progress(len(buf))
                buf = []
        else:
            est.push_joint(s)
            if est._last_joint_q is not None:  # noqa: SLF001 - same package
                q = est._last_joint_q  # noqa: SLF001
                q_min = q.copy() if q_min is None else np.minimum(q_min, q)
                q_max = q.copy() if q_max is None else np.maximum(q_max, q)
    if buf:
        est.push_imu_batch(ImuBatch.from_samples(buf))
        if progress is not None:
            progress(len(buf))
    est.flush()
    c = est.counters
    if c['imu_samples'] == 0:
        raise InputError('no IMU samples in the input: check --imu-topic')
    if c['joint_samples'] == 0:
        names = ', '.join(fixture.joint_names)
        what = ('joint states lack the fixture joints ' + names if c['joint_missing_names']
                else 'no joint states in the input')
        raise InputError(f'{what}: check --joint-topic and the fixture file')
    if not est.is_running:
        raise InputError(f'no stationary window of {config.init_window_s:g} s with joint '
                         'states for the initial alignment: start the recording at rest')
    if q_min is None or float(np.max(q_max - q_min)) < 1e-2:
        raise InputError('no motion: the fixture joints did not move (less than 0.01 rad); '
                         'record a rotation plan')
    health = est.health()
    if health['status'] == 'ERROR':
        # A diverged filter never becomes a calibration file (issue 6).
        raise InputError(f'the estimator diverged ({health["message"]}); no calibration '
                         'written: check the IMU grade, units and the fixture file')
    return est


def replay(open_samples: Callable[[], Any], fixture: Any, grade: Any,
           config: EstimatorConfig, iterations: int = 2,
           progress: Callable[[int], None] | None = None) -> CalibrationEstimator:
    """``iterations`` passes over the data (``open_samples()`` gives a fresh iterator)."""
    init: Estimate | None = None
    est = None
    for _ in range(max(1, iterations)):
        est = replay_pass(open_samples(), fixture, grade, config, initial=init,
                          progress=progress)
        init = est.estimate_state()
    assert est is not None
    return est
