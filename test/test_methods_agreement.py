"""The EKF and each of the papers' processors agree on the same simulated bag.

End to end through the command line (CONTRACT 5): ``imu-calib simulate`` writes one bag per
shipped plan (100 Hz to stay fast), ``imu-calib replay --method ekf|srt|oscillation`` writes
the CONTRACT 4 files, and for every value that both methods estimate (not listed as fixed by
either, sigma > 0) the difference must lie within 4 combined sigmas,
``|x_a - x_b| < 4 sqrt(s_a^2 + s_b^2)``. The two estimates come from the same data, so
their errors are positively correlated and the combined sigma over-states the spread of the
difference: 4 is a loose but noise-derived bound (a false alarm needs a > 4 sigma event).
The comparison is only meaningful if both are informative, so the combined sigma must also
be well below the grade's prior sigma (the parameter is really estimated by both).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from imu_calib_ros.cli import main
from imu_calib_ros.core.calibration import CalibrationResult
from imu_calib_ros.core.imu_grade import load_grade
from imu_calib_ros.core.methods.srt import FIELD_KEYS, _grade_sigmas


def _simulate_and_replay(tmp: Path, fixture: str, plan: str, methods: tuple[str, ...],
                         seed: int, extra: tuple[str, ...] = ()) -> dict[str, CalibrationResult]:
    bag = tmp / 'bag'
    assert main(['simulate', '--fixture', fixture, '--plan', plan, '--imu', 'nav_grade',
                 '--output', str(bag), '--rate', '100', '--joint-rate', '50',
                 '--seed', str(seed)]) == 0
    out = {}
    for m in methods:
        path = tmp / f'{m}.yaml'
        assert main(['replay', str(bag), '--fixture', fixture, '--imu', 'nav_grade',
                     '--method', m, '--iterations', '1', '--output', str(path),
                     '--quiet', *(extra if m == 'ekf' else ())]) == 0
        out[m] = CalibrationResult.load(path)
    return out


def _compare(a: CalibrationResult, b: CalibrationResult) -> tuple[list[str], float]:
    """Check every value both estimate; return the fields both determine well (combined
    sigma below a third of the prior) and the largest |difference| / combined sigma."""
    prior = _grade_sigmas(load_grade('nav_grade'))
    both, worst = [], 0.0
    for fld, key in FIELD_KEYS.items():
        if key in a.fixed or key in b.fixed:
            continue
        va, vb = np.asarray(getattr(a.errors, fld)), np.asarray(getattr(b.errors, fld))
        sa, sb = np.asarray(getattr(a.sigma, fld)), np.asarray(getattr(b.sigma, fld))
        comb = np.hypot(sa, sb)
        m = comb > 0
        if fld == 'gyro_scale_misalignment':
            m &= np.triu(np.ones((3, 3), bool))  # symmetric: count each value once
        z = np.abs(va - vb)[m] / comb[m]
        assert np.all(z < 4.0), (fld, z)
        worst = max(worst, float(z.max()))
        if np.all(comb[m] < prior[fld][m] / 3):
            both.append(fld)
    return both, worst


def test_ekf_and_oscillation_agree_on_size_effect(tmp_path: Path) -> None:
    # A methods cross-check on Kozlov's plan alone, with the grade's prior (no coarse start).
    # Open (issue 11 note): from the coarse start this plan separates neither accelerometer
    # scale from asymmetry (collinear at the three vertical poses) and the filter re-aligns
    # 19-24 times, leaving the size effect at its prior; with the grade-centred start it does not.
    cfg = tmp_path / 'grade_start.yaml'
    cfg.write_text('auto_start: false\nnoise_source: grade\n')
    # --force: the self-check (issue 17) refuses this EKF run too (gated updates, window
    # residuals): open, see the issue 11/17 notes; the cross-check of the size effect stands
    res = _simulate_and_replay(tmp_path, 'three_axis', 'kozlov_oscillation',
                               ('ekf', 'oscillation'), seed=7,
                               extra=('--config', str(cfg), '--force'))
    both, worst = _compare(res['ekf'], res['oscillation'])
    assert both == ['size_effect_m']


def test_ekf_and_srt_agree(tmp_path: Path) -> None:
    """Savage's 17 sequences with 6 s dwells and 10 s rotations (half the shipped plan's
    length, for CI time). The nav-grade gyro bias is compared but not required to be well
    determined: in ~8 minutes neither method gets below a third of its 0.01 deg/h prior
    (ARW / sqrt(T) physics, see test_estimator.py); nor is the EKF's accelerometer
    asymmetry (|f| and f^2 are equal at +-1 g: it shares the data with the quadratic term,
    which the SRT fixes)."""
    ids = ['1', '1a', '2', '2a', '3', '3a'] + [str(i) for i in range(4, 15)]
    plan = tmp_path / 'srt_short.yaml'
    plan.write_text('name: srt_short\nsteps:\n' + ''.join(
        f"  - srt_sequence: {{id: '{i}', dwell_s: 6, rotation_s: 10}}\n" for i in ids))
    res = _simulate_and_replay(tmp_path, 'savage_2axis', str(plan), ('ekf', 'srt'), seed=4)
    both, worst = _compare(res['ekf'], res['srt'])
    assert set(both) == {'gyro_scale_misalignment', 'gyro_scale_asymmetry',
                         'accel_bias_m_s2', 'accel_scale_misalignment'}
