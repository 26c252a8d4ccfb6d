"""The gate's and the self-check's quantiles (core/estimator/quantiles.py, from scipy.special)
equal scipy.stats' over the ranges they are used at."""
from __future__ import annotations

import pytest
from scipy import stats

from imu_calib_ros.core.estimator import quantiles as qt


@pytest.mark.parametrize('dof', [1, 3, 6, 45, 300, 110_000])
@pytest.mark.parametrize('p', [1e-12, 2e-3, 0.5, 0.99, 1 - 1e-5])
def test_chi2(dof: int, p: float) -> None:
    assert qt.chi2_ppf(p, dof) == pytest.approx(stats.chi2.ppf(p, dof), rel=1e-10)
    assert qt.chi2_isf(p, dof) == pytest.approx(stats.chi2.isf(p, dof), rel=1e-10)
    x = stats.chi2.ppf(p, dof)
    assert qt.chi2_sf(x, dof) == pytest.approx(stats.chi2.sf(x, dof), rel=1e-9, abs=1e-300)


@pytest.mark.parametrize('n', [1, 50, 3700, 40_000])
@pytest.mark.parametrize('p', [1e-9, 1e-5, 2e-3, 0.3])
@pytest.mark.parametrize('q', [2e-3, 0.05])
def test_binom_isf(n: int, p: float, q: float) -> None:
    assert qt.binom_isf(q, n, p) == int(stats.binom.isf(q, n, p))


@pytest.mark.parametrize('q', [1e-9, 1e-4, 0.0025, 0.3, 0.5])
def test_norm_isf(q: float) -> None:
    assert qt.norm_isf(q) == pytest.approx(stats.norm.isf(q), rel=1e-12, abs=1e-15)


@pytest.mark.parametrize('dof', [1, 4, 30, 1000])
@pytest.mark.parametrize('q', [1e-4, 1e-3, 0.05])
def test_t_isf(dof: int, q: float) -> None:
    assert qt.t_isf(q, dof) == pytest.approx(stats.t.isf(q, dof), rel=1e-9)


def test_the_replay_path_does_not_import_scipy_stats() -> None:
    """The estimator, its self-check and the replay CLI start without scipy.stats."""
    import subprocess
    import sys
    code = ('import sys, imu_calib_ros.core.estimator, imu_calib_ros.core.estimator.selfcheck, '
            'imu_calib_ros.cli.replay; print("scipy.stats" in sys.modules)')
    out = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                         check=True).stdout.strip()
    assert out == 'False'
