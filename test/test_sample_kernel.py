"""The sampling kernels: point samples read as interval means, found by the data.

A point sample read as the interval mean of CONTRACT 1 is larger by ``(omega dt)^2 / 24`` of
the gravity turning through the body, and a point-sampled gyro leaves the attitude
``alpha dt^2 / 24`` off through a ramp (error_model.sample_kernel_column). A navigation unit
at 100 Hz on ``demo_short`` (turns at 1.5-2 rad/s): before the kernels were states, the plain
command exited 0 with its accelerometer scales 2.6-6.6 sigma off, every one positive (seed 8:
x +6.6, y +3.7), and the declared ``imu_sample_type: point`` (the trapezoid of each sample and
the one before, kernel -2) was refused, 8-13 sigma the other way. The kernels are now states
(0 interval mean, 1 point), so the plain command calibrates the unit either way and each
kernel comes out where the samples are: 1 for point samples, 0 for means, -2 for the
declared point samples' trapezoids.
"""
from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest
import yaml

from imu_calib_ros.core.estimator import load_estimator_config
from imu_calib_ros.core.estimator.priors import kernel_note
from imu_calib_ros.core.estimator.replay import replay_run
from imu_calib_ros.core.fixture import load_fixture
from imu_calib_ros.testing.world_cases import compare_calibration, make_case
from msg_adapters.bag import iter_bag

#: (sample type the bag holds, imu_sample_type declared, the kernel the samples then have)
CASES = {'point read as mean': ('point', 'mean', 1.0),
         'mean': ('interval_mean', 'mean', 0.0),
         'point declared': ('point', 'point', -2.0)}


@pytest.mark.parametrize('case', list(CASES))
def test_the_kernels_are_found_and_the_scales_stay_honest(tmp_path: Path, case: str) -> None:
    sample_type, declared, kernel = CASES[case]
    bag, truth = make_case(tmp_path, unit='nav', seed=8, sample_type=sample_type)
    cfg = dataclasses.replace(load_estimator_config(None), imu_sample_type=declared)
    run = replay_run(lambda: iter_bag(bag), load_fixture(str(truth.fixture_path)), None, cfg)
    assert run.verdict.passed, run.verdict.line
    est = run.estimator.estimate_state()
    sd = np.sqrt(np.diag(est.covariance))
    for name in ('gyro_sample_kernel[0]', 'accel_sample_kernel[0]'):
        k = est.labels.index(name)
        # the kernel the samples have, within 3 of its sigmas (0.09 and 0.16 here: the
        # kernels are 1 apart, so a point sample is never taken for a mean)
        assert abs(est.values[k] - kernel) < 3.0 * sd[k], (name, est.values[k], sd[k])
        assert sd[k] < 0.3, (name, sd[k])
    out = tmp_path / 'calib.yaml'
    calib = run.estimator.estimate()
    calib.save(out)
    # the command names samples that are not what was declared, and only those
    note = kernel_note(calib.extra['estimator'], cfg)
    assert (note is not None) == (case == 'point read as mean'), note
    rows = [r for r in compare_calibration(yaml.safe_load(out.read_text()),
                                           yaml.safe_load(truth.path.read_text()))
            if not r.fixed and r.sigma > 0]
    z = {r.name: r.z for r in rows}
    # the accelerometer scales (6.6, 3.7 and 2.6 sigma off before, read as means) within 3
    # sigma, and no parameter of the 45 beyond 4 (chance 0.3 % with honest sigmas)
    scales = [v for n, v in z.items() if n.startswith('accel_scale')]
    assert len(scales) == 3 and max(map(abs, scales)) < 3.0, scales
    worst = max(z, key=lambda n: abs(z[n]))
    assert abs(z[worst]) < 4.0, (worst, z[worst])
