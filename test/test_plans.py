"""Motion plans: analytic profiles, geometry of the generated rotations, fixture refusals."""
import math
from pathlib import Path

import numpy as np
import pytest
from scipy.special import jv

from imu_calib_ros.core.errors import PlanError
from imu_calib_ros.core.fixture import load_fixture
from imu_calib_ros.core.plans import (SRT_TABLE, build_profile, load_plan, plan_from_dict,
                                      random_plan)
from imu_calib_ros.core.rotation import rot_axis_angle

ROOT = Path(__file__).resolve().parents[1]
PLANS = sorted(p.stem for p in (ROOT / 'config' / 'plans').glob('*.yaml'))
FIXTURES = sorted(p.stem for p in (ROOT / 'config' / 'fixtures').glob('*.yaml'))
# What each shipped fixture cannot run, and why (the PlanError must say so).
# savage_2axis: no joint can stand vertical along IMU x -> no Kozlov heading oscillation.
REFUSED = {
    ('savage_2axis', 'kozlov_oscillation'): 'vertical',
    ('savage_2axis', 'srt_then_kozlov'): 'vertical',
    ('savage_2axis', 'srt_kozlov_bias'): 'vertical',
    ('three_axis', 'arm6_excitation'): 'no joint',  # generated for config/fixtures/arm6.urdf
    ('savage_2axis', 'arm6_excitation'): 'no joint',
    # a turn about IMU x with x vertical: neither of its axes can stand vertical along x
    ('savage_2axis', 'six_position_turns'): 'no fixture joint lies along IMU axis',
}


def _plan(steps):
    return plan_from_dict({'name': 't', 'steps': steps}, '<test>')


@pytest.mark.parametrize('fixture_name', FIXTURES)
@pytest.mark.parametrize('plan_name', PLANS)
def test_shipped_plans_build_or_are_refused(plan_name: str, fixture_name: str) -> None:
    fx = load_fixture(fixture_name)
    plan = load_plan(plan_name)
    reason = REFUSED.get((fixture_name, plan_name))
    if reason is not None:
        with pytest.raises(PlanError, match=reason):
            build_profile(plan, fx)
        return
    prof = build_profile(plan, fx)
    assert prof.duration_s > 0
    _check_profile_is_consistent(prof)


def _check_profile_is_consistent(prof) -> None:
    """q' and q'' agree with central differences of q; q, q' continuous everywhere."""
    bps = prof.breakpoints_s
    rng = np.random.default_rng(0)
    t = np.sort(rng.uniform(0.0, prof.duration_s, 400))
    h = 1e-4
    q0, qd0, qdd0 = prof.evaluate(t)
    qp, qdp, _ = prof.evaluate(t + h)
    qm, qdm, _ = prof.evaluate(t - h)
    near = np.min(np.abs(t[:, None] - bps[None, :]), axis=1) < 2 * h
    ok = ~near
    scale = 1.0 + np.max(np.abs(qd0))
    assert np.max(np.abs((qp - qm)[ok] / (2 * h) - qd0[ok])) < 1e-5 * scale
    assert np.max(np.abs((qdp - qdm)[ok] / (2 * h) - qdd0[ok])) < 1e-4 * scale
    # continuity of q and q' across every breakpoint (pieces are rest-to-rest or matched)
    e = 1e-9
    a, ad, _ = prof.evaluate(bps[1:-1] - e)
    b, bd, _ = prof.evaluate(bps[1:-1] + e)
    assert np.max(np.abs(a - b), initial=0.0) < 1e-6
    assert np.max(np.abs(ad - bd), initial=0.0) < 1e-6


def test_quintic_move_is_rest_to_rest_with_continuous_acceleration() -> None:
    fx = load_fixture('three_axis')
    prof = build_profile(_plan([{'dwell': {'duration_s': 1}},
                                {'move': {'joint': 'outer', 'by_deg': 90, 'duration_s': 4}},
                                {'dwell': {'duration_s': 1}}]), fx)
    q, qd, qdd = prof.evaluate(np.array([1.0, 3.0, 5.0]))
    assert q[2, 0] == pytest.approx(math.pi / 2, abs=1e-15)
    np.testing.assert_allclose(qd[[0, 2]], 0.0, atol=1e-15)
    np.testing.assert_allclose(qdd[[0, 2]], 0.0, atol=1e-15)
    assert qd[1, 0] == pytest.approx(1.875 * (math.pi / 2) / 4.0, rel=1e-12)  # quintic peak


def test_rotate_imu_turns_about_that_imu_axis() -> None:
    for name in FIXTURES:
        fx = load_fixture(name)
        for ax, k in (('x', 0), ('y', 1), ('z', 2)):
            try:
                prof = build_profile(_plan([{'orient': {'up': ax}},
                                            {'rotate_imu': {'axis': f'-{ax}', 'angle_deg': 137,
                                                            'duration_s': 3}}]), fx)
            except PlanError as exc:
                assert 'no fixture joint lies along' in str(exc)
                continue
            q, _, _ = prof.evaluate(np.array([prof.segments[-1].t0_s, prof.duration_s]))
            R0, R1 = fx.R_enu_imu(q)
            u_enu = R0 @ -np.eye(3)[k]
            np.testing.assert_allclose(R1, rot_axis_angle(u_enu, math.radians(137)) @ R0,
                                       atol=1e-12)


def test_srt_sequences_start_with_the_tabulated_axis_down() -> None:
    fx = load_fixture('savage_2axis')
    prof = build_profile(load_plan('savage_srt'), fx)
    seen = set()
    for seg in prof.segments:
        if seg.kind == 'dwell' and seg.meta.get('phase') == 'before':
            sid = seg.meta['sequence']
            seen.add(sid)
            q, _, _ = prof.evaluate(np.array([0.5 * (seg.t0_s + seg.t1_s)]))
            down_imu = fx.R_enu_imu(q[0]).T @ np.array([0.0, 0.0, -1.0])
            np.testing.assert_allclose(down_imu, np.eye(3)['xyz'.index(SRT_TABLE[sid][0])],
                                       atol=1e-9)
            rot = [s for s in prof.segments if s.label == seg.label and s.kind == 'move']
            assert [s.meta['imu_axis'] for s in rot] == [f'+{a}' for a, _ in SRT_TABLE[sid][2]]
            np.testing.assert_allclose([math.degrees(s.meta['angle_rad']) for s in rot],
                                       [d for _, d in SRT_TABLE[sid][2]], rtol=1e-12)
    assert seen == set(SRT_TABLE)


def test_kozlov_oscillation_averages() -> None:
    """<psi'' sin psi> = -A W^2 J1(A) cos psi_c and <psi'' cos psi> = A W^2 J1(A) sin psi_c."""
    fx = load_fixture('three_axis')
    prof = build_profile(load_plan('kozlov_oscillation'), fx)
    osc = [s for s in prof.segments if s.kind == 'oscillate']
    assert sorted(s.label for s in osc) == sorted(
        f'osc:{a}-up:T{T}' for a in 'xyz' for T in (5, 10))
    nodes, weights = np.polynomial.legendre.leggauss(40)
    for seg in osc:
        j = fx.joint_names.index(seg.meta['joint'])
        A, T, c = seg.meta['amplitude_rad'], seg.meta['period_s'], seg.meta['center_rad']
        W = 2 * math.pi / T
        # Gauss-Legendre over each period (integrand smooth): exact to rounding
        edges = np.arange(seg.t0_s, seg.t1_s + 1e-9, T / 4)
        a, b = edges[:-1, None], edges[1:, None]
        t = (0.5 * (a + b) + 0.5 * (b - a) * nodes).ravel()
        w = (0.5 * (b - a) * weights).ravel()
        q, _, qdd = prof.evaluate(t)
        psi, psidd = q[:, j], qdd[:, j]
        mean_sin = np.sum(w * psidd * np.sin(psi)) / (seg.t1_s - seg.t0_s)
        mean_cos = np.sum(w * psidd * np.cos(psi)) / (seg.t1_s - seg.t0_s)
        assert mean_sin == pytest.approx(-A * W**2 * jv(1, A) * math.cos(c), abs=1e-10)
        assert mean_cos == pytest.approx(A * W**2 * jv(1, A) * math.sin(c), abs=1e-10)
        # the joint is vertical and the named IMU axis is up
        q0, _, _ = prof.evaluate(np.array([seg.t0_s]))
        assert abs(fx.joint_axes_enu(q0[0])[j][2]) == pytest.approx(1.0, abs=1e-12)
    c5 = 5.0**2 / (4 * math.pi**2 * (math.pi / 2) * jv(1, math.pi / 2))
    assert c5 == pytest.approx(0.711, abs=5e-4)  # Kozlov & Kapralov's c(A, T)


def test_spin_reaches_the_rate_and_the_angle() -> None:
    fx = load_fixture('savage_2axis')
    prof = build_profile(load_plan('rotation_modulation'), fx)
    spin = [s for s in prof.segments if s.kind == 'spin'][0]
    t = np.linspace(spin.t0_s, spin.t1_s, 7)
    q, qd, qdd = prof.evaluate(t)
    j = fx.joint_names.index(spin.meta['joint'])
    assert np.allclose(np.abs(qd[:, j]), math.radians(150), rtol=0, atol=1e-12)
    assert np.allclose(qdd, 0.0, atol=1e-12)
    assert spin.t1_s - spin.t0_s == pytest.approx(300.0)
    # about the IMU z axis: the joint axis is the IMU z axis
    assert abs(fx.joint_axes_imu(q[0])[j][2]) == pytest.approx(1.0, abs=1e-12)


def test_refusals_name_the_step() -> None:
    fx = load_fixture('savage_2axis')
    with pytest.raises(PlanError, match=r"step 2 \(move\).*no joint 'middle'"):
        build_profile(_plan([{'dwell': {'duration_s': 1}},
                             {'move': {'joint': 'middle', 'by_deg': 5, 'duration_s': 1}}]), fx)
    with pytest.raises(PlanError, match='unknown step kind'):
        _plan([{'wiggle': {'duration_s': 1}}])
    with pytest.raises(PlanError, match="missing key 'duration_s'"):
        _plan([{'dwell': {}}])
    with pytest.raises(PlanError, match='exactly one of to_deg and by_deg'):
        _plan([{'move': {'joint': 'outer', 'duration_s': 1}}])
    with pytest.raises(PlanError, match='vertical'):
        build_profile(_plan([{'oscillate': {'joint': 'outer', 'amplitude_deg': 90,
                                            'period_s': 5, 'cycles': 1, 'vertical': True}}]),
                      fx)


def test_include_cycle_and_repeat(tmp_path) -> None:
    (tmp_path / 'a.yaml').write_text('name: a\nsteps:\n  - include: {plan: b.yaml}\n')
    (tmp_path / 'b.yaml').write_text('name: b\nsteps:\n  - include: {plan: a.yaml}\n')
    with pytest.raises(PlanError, match='includes itself'):
        load_plan(tmp_path / 'a.yaml')
    p = _plan([{'repeat': {'count': 3, 'steps': [{'dwell': {'duration_s': 2}}]}}])
    assert len(p.steps) == 3


def test_random_moves_are_reproducible() -> None:
    fx = load_fixture('three_axis')
    a = build_profile(random_plan(5, 10), fx)
    b = build_profile(random_plan(5, 10), fx)
    c = build_profile(random_plan(6, 10), fx)
    t = np.linspace(0, a.duration_s, 50)
    np.testing.assert_array_equal(a.evaluate(t)[0], b.evaluate(t)[0])
    assert a.duration_s != c.duration_s
    assert len(a.stationary_windows()) >= 10
