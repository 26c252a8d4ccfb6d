"""The fast filter steps of ekf.py against the dense textbook forms (filterpy).

``predict_rows`` (block form of ``Phi P Phi^T``) and ``update`` (Joseph form by rank-m
corrections, Cholesky of S) must agree with filterpy's dense ``predict``/``update`` to rounding:
tolerances are 1e-12 relative to the largest entry (46^2 products of O(1) numbers, double
precision ~1e-16 each), far below any statistical effect (a sigma changes by 1e-6 only at
1e-6 relative).
"""
from __future__ import annotations

import numpy as np
import pytest
from filterpy.kalman import predict as kf_predict
from filterpy.kalman import update as kf_update

from imu_calib_ros.core.estimator import error_model as em
from imu_calib_ros.core.estimator.ekf import (ErrorStateFilter, chunk_transition_rows,
                                              chunk_transitions)
from imu_calib_ros.core.rotation import rotvec_to_matrix, skew

ALL = tuple(g[0] for g in em.GROUPS if g[0] != 'mounting')


def _spd(rng: np.random.Generator, n: int) -> np.ndarray:
    """A covariance with eigenvalues over six decades (like the scaled filter's)."""
    Q, _ = np.linalg.qr(rng.normal(size=(n, n)))
    return (Q * np.logspace(-3, 3, n)) @ Q.T


@pytest.mark.parametrize('seed', [0, 1, 2])
def test_predict_rows_equals_dense_predict(seed: int) -> None:
    rng = np.random.default_rng(seed)
    lay = em.StateLayout.build(ALL)
    n = lay.n
    P0 = _spd(rng, n)
    phi = np.eye(n)
    phi[0:6] += rng.normal(size=(6, n))  # only the navigation rows differ from I
    q = rng.random(n)
    filt = ErrorStateFilter(lay, P0, 0.99)
    filt.x = rng.normal(size=n)
    x_ref, P_ref = kf_predict(filt.x.copy(), P0.copy(), phi, np.diag(q))
    filt.predict_rows(phi[0:6].copy(), q)
    scale = np.abs(P_ref).max()
    np.testing.assert_allclose(filt.P, P_ref, rtol=0, atol=1e-12 * scale)
    np.testing.assert_allclose(filt.x, x_ref, rtol=0, atol=1e-12 * np.abs(x_ref).max())


@pytest.mark.parametrize('seed', [0, 1, 2])
def test_update_equals_filterpy_joseph_update(seed: int) -> None:
    rng = np.random.default_rng(seed)
    lay = em.StateLayout.build(ALL)
    n = lay.n
    P0 = _spd(rng, n)
    H = np.zeros((3, n))
    cols = np.r_[0:6, lay.slices['lever_arm']]
    H[:, cols] = rng.normal(size=(3, cols.size))
    R = np.diag(rng.random(3) + 0.1)
    filt = ErrorStateFilter(lay, P0, 1.0)  # gate off
    filt.x = rng.normal(size=n)
    z = H @ filt.x + rng.normal(size=3)
    x_prior = filt.x.copy()
    x_ref, P_ref = kf_update(filt.x.copy(), P0.copy(), z, R, H)
    assert filt.update('velocity', z, H, R)
    np.testing.assert_allclose(filt.P, P_ref, rtol=0, atol=1e-12 * np.abs(P_ref).max())
    np.testing.assert_allclose(filt.x, x_ref, rtol=0, atol=1e-12 * np.abs(x_ref).max())
    assert np.array_equal(filt.P, filt.P.T)
    y = z - H @ x_prior
    nis_ref = float(y @ np.linalg.solve(H @ P0 @ H.T + R, y))
    assert np.isclose(filt.counters.last_nis['velocity'], nis_ref, rtol=1e-12)


def test_update_gate_and_non_positive_s_are_rejected() -> None:
    rng = np.random.default_rng(3)
    lay = em.StateLayout.build(ALL)
    n = lay.n
    P0 = _spd(rng, n)
    H = np.zeros((3, n))
    H[:, 0:3] = np.eye(3)
    R = np.eye(3)
    filt = ErrorStateFilter(lay, P0, 0.99)
    S = H @ P0 @ H.T + R
    # an innovation with NIS 3x the 99 % quantile of chi2(3) (11.34) is rejected, P untouched
    L = np.linalg.cholesky(S)
    z = L @ np.array([np.sqrt(34.0), 0.0, 0.0])
    P_before = filt.P.copy()
    assert not filt.update('velocity', z, H, R)
    assert filt.counters.rejected['velocity'] == 1
    assert np.isclose(filt.counters.last_nis['velocity'], 34.0, rtol=1e-10)
    assert np.array_equal(filt.P, P_before)
    # a measurement noise that makes S indefinite is rejected, not fed into the filter
    assert not filt.update('velocity', np.zeros(3), H, -10.0 * np.abs(P0).max() * np.eye(3))
    assert filt.counters.rejected['velocity'] == 2
    assert np.array_equal(filt.P, P_before)


def test_gated_innovation_is_deweighted_to_the_gate() -> None:
    """gate_action deweight (Chang 2014): an innovation beyond the gate is counted as gated
    and used with R scaled by the lam >= 1 that brings its NIS to the gate exactly; the step
    is the Kalman step of that inflated R (filterpy's update with lam R), bounded by the
    gate, and it falls off for a gross outlier (as 1/|y|)."""
    from scipy.stats import chi2
    from imu_calib_ros.core.estimator.ekf import deweight_factor
    rng = np.random.default_rng(5)
    lay = em.StateLayout.build(ALL)
    n = lay.n
    P0 = _spd(rng, n)
    H = np.zeros((3, n))
    H[:, 0:3] = np.eye(3)
    H[:, 3:6] = 0.1 * rng.normal(size=(3, 3))
    R = np.diag([0.3, 0.5, 0.8])
    gate = float(chi2.ppf(0.99, 3))
    S = H @ P0 @ H.T + R
    L = np.linalg.cholesky(S)
    steps = []
    for k in (2.0, 20.0, 2000.0):  # NIS = k^2 x gate / 1
        y = L @ np.array([1.0, -0.5, 0.3]) * k * np.sqrt(gate / 1.34)
        filt = ErrorStateFilter(lay, P0.copy(), 0.99, deweight=True)
        assert not filt.update('velocity', y, H, R)  # counted as gated
        assert filt.counters.rejected['velocity'] == 1
        assert filt.counters.deweighted['velocity'] == 1
        assert 'velocity' not in filt.counters.nis_sum  # the NIS statistics: gated apart
        lam = deweight_factor(H @ P0 @ H.T, R, y, gate)
        assert lam > 1.0
        nis_lam = float(y @ np.linalg.solve(H @ P0 @ H.T + lam * R, y))
        assert nis_lam == pytest.approx(gate, rel=1e-8)
        x_ref, P_ref = kf_update(np.zeros(n), P0.copy(), y, lam * R, H)
        np.testing.assert_allclose(filt.x, x_ref, rtol=0, atol=1e-10 * np.abs(x_ref).max())
        np.testing.assert_allclose(filt.P, P_ref, rtol=0, atol=1e-10 * np.abs(P_ref).max())
        steps.append(float(np.linalg.norm(filt.x)))
    assert steps[2] < 0.1 * steps[1]  # a gross outlier moves the state by almost nothing
    # reject: the state and P untouched, as before
    filt = ErrorStateFilter(lay, P0.copy(), 0.99, deweight=False)
    assert not filt.update('velocity', 3.0 * L @ np.ones(3) * np.sqrt(gate), H, R)
    assert not filt.x.any() and np.array_equal(filt.P, P0)
    # within the gate: the plain update (lam not used)
    filt = ErrorStateFilter(lay, P0.copy(), 0.99, deweight=True)
    assert filt.update('velocity', L @ np.array([0.5, 0.2, 0.1]), H, R)
    assert 'velocity' not in filt.counters.deweighted


def _random_chunks(rng: np.random.Generator, B: int = 3, m: int = 7):  # noqa: ANN202
    """Attitudes, specific forces, sensor Jacobians and intervals of B chunks of m samples."""
    R = rotvec_to_matrix(rng.normal(size=(B * m, 3))).reshape(B, m, 3, 3)
    f = rng.normal(size=(B, m, 3)) + [0.0, 0.0, 9.8]
    Mg = rng.normal(size=(B, m, 3, em.N_GYRO))
    Ma = rng.normal(size=(B, m, 3, em.N_ACCEL))
    return R, f, Mg, Ma, np.full((B, m), 0.005)


def _run(lay: em.StateLayout, x0: np.ndarray, P0: np.ndarray, steps: list, sens: bool
         ) -> ErrorStateFilter:
    """One filter through ``steps`` (predict_rows, dense predict and updates, in order)."""
    filt = ErrorStateFilter(lay, P0.copy(), 1.0)
    filt.x = x0.copy()
    if sens:
        filt.sens = np.zeros(lay.n)
        filt.sens[6:] = 1.0  # any direction: checked below against two runs' difference
    for kind, a, b in steps:
        if kind == 'rows':
            filt.predict_rows(a, b)
        elif kind == 'dense':
            filt.predict(a, np.diag(b))
        else:
            filt.update('velocity', a, b, np.eye(3) * 0.5)
    return filt


@pytest.mark.parametrize('seed', [0, 1])
def test_the_prior_sensitivity_is_the_estimate_s_derivative_along_the_initial_mean(
        seed: int) -> None:
    """``sens`` carries d x_end / d x_0 along its initial direction through predicts and
    updates: the difference of two filters whose initial means differ by that direction, to
    rounding (a de-weighted update's factor depends on its innovation, so there it is the
    derivative at the factor used), also where process noise on the parameter
    states (a bias walk) makes it differ from the constant-state ``P P0^-1`` shift
    (the information form's closed form), which it equals where there is none."""
    rng = np.random.default_rng(seed)
    lay = em.StateLayout.build(('gyro_bias', 'gyro_scale', 'accel_bias'))
    n = lay.n
    P0 = np.diag(np.r_[np.full(6, 1e-2), rng.uniform(0.5, 2.0, n - 6)])
    d = np.r_[np.zeros(6), np.ones(n - 6)]
    for q_par in (0.0, 0.05):
        steps: list = []
        for k in range(60):
            phi = np.eye(n)[0:6]
            phi[:, 6:] = rng.normal(scale=0.3, size=(6, n - 6))
            q = np.r_[np.full(6, 1e-3), np.full(n - 6, q_par)]
            steps.append(('rows' if k % 2 else 'dense',
                          phi if k % 2 else np.vstack([phi, np.eye(n)[6:]]), q))
            H = np.zeros((3, n))
            H[:, 0:3] = np.eye(3)
            steps.append(('update', rng.normal(size=3), H))
        a = _run(lay, np.zeros(n), P0, steps, sens=True)
        b = _run(lay, d, P0, steps, sens=False)
        assert a.sens is not None
        np.testing.assert_allclose(a.sens, b.x - a.x, atol=1e-10 * np.abs(a.sens).max())
        const = a.P[6:, 6:] @ (d[6:] / np.diag(P0)[6:])  # P P0^-1 shift
        if q_par == 0.0:
            assert not np.allclose(const, 0.0)
            np.testing.assert_allclose(a.sens[6:], const, atol=1e-10 * np.abs(const).max())
        else:
            assert np.abs(a.sens[6:] - const).max() > 0.1 * np.abs(const).max()


def test_transition_rows_are_the_rows_of_the_full_matrix() -> None:
    rng = np.random.default_rng(4)
    lay = em.StateLayout.build(ALL)
    B = 3
    R, f, Mg, Ma, dt = _random_chunks(rng, B)
    om = np.array([0.0, 5e-5, 5e-5])
    rows = chunk_transition_rows(lay, R, f, Mg, Ma, dt, om)
    phi = chunk_transitions(lay, R, f, Mg, Ma, dt, om)
    assert np.array_equal(phi[:, 0:6], rows)
    assert np.array_equal(phi[:, 6:], np.broadcast_to(np.eye(lay.n)[6:], (B, lay.n - 6, lay.n)))
    # the summation by parts equals the cumulative-sum form (trapezoid in the sample)
    rmg = R @ Mg[..., lay.gyro_cols] * dt[..., None, None]
    cum = np.cumsum(rmg, axis=1) - 0.5 * rmg
    ref = np.einsum('bnij,bnjp->bip', skew(f) * dt[..., None, None], cum)
    np.testing.assert_allclose(rows[:, 3:6, lay.gyro_state_idx], ref, rtol=0,
                               atol=1e-13 * np.abs(ref).max())


def test_transition_rows_with_the_compensation_inverses_on_the_left() -> None:
    """``chunk_transition_rows(..., M, ..., D_g^-1, D_a^-1)`` (what propagate_block passes)
    equals the rows of the compensated Jacobians ``D^-1 M`` to rounding."""
    rng = np.random.default_rng(5)
    lay = em.StateLayout.build(ALL)
    B, m = 3, 7
    R, f, Mg, Ma, dt = _random_chunks(rng, B, m)
    Dg_inv = np.eye(3) + 1e-3 * rng.normal(size=(B, m, 3, 3))
    Da_inv = np.eye(3) + 1e-3 * rng.normal(size=(B, m, 3, 3))
    om = np.array([0.0, 5e-5, 5e-5])
    ref = chunk_transition_rows(lay, R, f, Dg_inv @ Mg, Da_inv @ Ma, dt, om)
    rows = chunk_transition_rows(lay, R, f, Mg, Ma, dt, om, Dg_inv, Da_inv)
    np.testing.assert_allclose(rows, ref, rtol=0, atol=1e-14 * np.abs(ref).max())
