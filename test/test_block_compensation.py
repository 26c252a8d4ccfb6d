"""The estimator's block compensation (propagation.BlockCompensation) against
sensor_model.compensate: the same fixed point to rounding, with and without a g-sensitivity
(coupled and rates-alone iterations), a size effect or none, and MEMS errors 40x too large."""
from __future__ import annotations

import numpy as np
import pytest

from imu_calib_ros.core.estimator.propagation import BlockCompensation
from imu_calib_ros.core.sensor_model import ImplausibleErrors, SensorErrors, compensate, measure
from test_sensor_model import mems_errors, random_motion


def _variants(e: SensorErrors) -> dict[str, SensorErrors]:
    v = e.as_vector()
    no_g = v.copy()
    no_g[12:21] = 0.0
    no_size = no_g.copy()
    no_size[39:45] = 0.0
    return {'all': e, 'no_g_sensitivity': SensorErrors.from_vector(no_g),
            'no_size_effect': SensorErrors.from_vector(no_size),
            'large': SensorErrors.from_vector(40 * v)}


@pytest.mark.parametrize('seed', [0, 1])
@pytest.mark.parametrize('kind', ['all', 'no_g_sensitivity', 'no_size_effect', 'large'])
def test_block_compensation_is_compensate_to_rounding(seed: int, kind: str) -> None:
    rng = np.random.default_rng(seed)
    e = _variants(mems_errors(rng))[kind]
    w, wd, f = random_motion(rng, 300)
    gm, am = measure(e, w, wd, f)
    comp = BlockCompensation.of(e)
    rates = comp.rates(gm, am)
    w0, _ = compensate(e, gm, am, np.zeros_like(wd))  # the rates without omega_dot
    np.testing.assert_allclose(rates.T, w0, rtol=0, atol=1e-15 * np.abs(w0).max())
    w1, f1 = comp.samples(gm, am, wd.T, rates)
    w2, f2 = compensate(e, gm, am, wd)
    np.testing.assert_allclose(w1.T, w2, rtol=0, atol=1e-15 * np.abs(w2).max())
    np.testing.assert_allclose(f1.T, f2, rtol=0, atol=1e-15 * np.abs(f2).max())
    np.testing.assert_allclose(f1.T, f, rtol=0, atol=1e-12 * np.abs(f).max())


def test_block_compensation_refuses_what_does_not_converge() -> None:
    rng = np.random.default_rng(3)
    v = mems_errors(rng).as_vector()
    v[9:12] = 1.5  # gyro asymmetry 150 %: no contraction
    e = SensorErrors.from_vector(v)
    w, _, f = random_motion(rng, 50)
    with pytest.raises(ImplausibleErrors), np.errstate(over='ignore', invalid='ignore'):
        BlockCompensation.of(e).rates(w, f)


def test_compensation_inverses_are_those_of_the_jacobians_matrices() -> None:
    """error_model.compensation_inverses: D_g^-1 by sign pattern (the same bits as one LAPACK
    inverse per sample, zero rates included) and D_a^-1 by its adjugate (to rounding)."""
    from imu_calib_ros.core.estimator.error_model import compensation_inverses
    rng = np.random.default_rng(4)
    e = mems_errors(rng)
    w, _, f = random_motion(rng, 200)
    w[5] = 0.0
    w[7, 1] = 0.0
    Dg_inv, Da_inv = compensation_inverses(e, w, f)
    eye = np.eye(3)
    Dg = eye + e.gyro_scale_misalignment + np.einsum(
        'ni,ij->nij', e.gyro_scale_asymmetry * np.sign(w), eye)
    Da = eye + e.accel_scale_misalignment + np.einsum(
        'ni,ij->nij', e.accel_scale_asymmetry * np.sign(f)
        + 2 * e.accel_quadratic_per_m_s2 * f, eye)
    assert np.array_equal(Dg_inv, np.linalg.inv(Dg))
    np.testing.assert_allclose(Da_inv, np.linalg.inv(Da), rtol=0, atol=1e-15)
