"""Plans an arm can run (issue 15 item 3): an SRT-like excitation plan and a random plan,
generated for any chain from its kinematics and URDF limits.

:func:`excitation_plan` turns the IMU about each of its axes in three attitudes of that axis
(horizontal, up, down), each time with a joint whose axis lies along the IMU axis there
(Savage's SRT idea, "Improved strapdown IMU calibration procedures", sect. 3: rotations
about each axis between dwells, every axis through up and down, without a turntable whose
axes meet). For every (IMU axis, attitude) it searches the joint angles by bounded least
squares (scipy) from the home pose and from seeded random starts, for each candidate joint
(innermost first: the smallest sweep of the arm), so that

- the IMU axis is parallel to the joint's axis (then turning that joint turns the IMU about
  that axis, whatever the other joints do);
- the joint axis is horizontal, or the IMU axis points up or down;
- every joint stays within its limits (less a margin) over the whole rotation, and the IMU
  and every joint origin stay ``min_height_m`` above the base origin (a crude floor), over
  the rotation and the move there. The floor is a term of the search itself (a hinge on the
  heights), and every pose found is tried, nearest first: the pose nearest home with a UR5's
  tool pointing down is below the floor, so "y down" and "z down" were once reported
  impossible on arm6.urdf although its wrist turns the tool about both.

A joint whose axis can never lie along the IMU axis (e.g. the last joint for an IMU axis
perpendicular to it: that angle is fixed) is skipped with that reason.

What no joint can produce is listed in the returned :class:`ExcitationRow` table ("what the
arm cannot excite"). The plan is an ordinary plan (``set``, ``move``, ``dwell`` steps), so it
can be saved (:func:`plan_to_dict`), inspected and run by ``turntable_driver``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import least_squares

from .errors import PlanError
from .fixture import Fixture
from .plans import Plan, build_profile, plan_from_dict

FloatArray = NDArray[np.float64]
UP = np.array([0.0, 0.0, 1.0])
CASES = ('horizontal', 'up', 'down')


@dataclass(frozen=True)
class ExcitationRow:
    """One (IMU axis, attitude) of the excitation plan: the joint used and the rotation, or
    why none could be found."""

    imu_axis: str
    attitude: str
    joint: str | None
    rotation_deg: float
    reason: str = ''


def _limits(fx: Fixture, margin: float) -> tuple[FloatArray, FloatArray]:
    lo = np.array([-math.inf if j.lower is None else j.lower + margin for j in fx.joints])
    hi = np.array([math.inf if j.upper is None else j.upper - margin for j in fx.joints])
    return lo, hi


def _heights_ok(fx: Fixture, q: FloatArray, min_height_m: float) -> bool:
    """IMU point and every joint origin at least ``min_height_m`` above the base origin."""
    q = np.atleast_2d(q)
    z = fx.p_enu_m(q)[..., 2]
    if fx.concurrent:
        return True
    O = fx._origins(q)[2][..., 2]  # noqa: SLF001 (the chain's own helper)
    return bool(z.min() >= min_height_m and O[:, 2:].min() >= min_height_m)


def _floor_points(fx: Fixture, q: FloatArray) -> FloatArray:
    """Heights above the base origin of the IMU point and of every joint origin but the first
    two (those on the base), (..., n - 1); empty for a turntable (no floor)."""
    if fx.concurrent:
        return np.zeros(q.shape[:-1] + (0,))
    z = fx.p_enu_m(q)[..., 2:3]
    O = fx._origins(q)[2][..., 2:, 2]  # noqa: SLF001 (the chain's own helper)
    return np.concatenate([z, O], axis=-1)


def _solve(fx: Fixture, k: int, case: str, j: int, q_home: FloatArray, lo: FloatArray,
           hi: FloatArray, rng: np.random.Generator, starts: int,
           min_height_m: float) -> list[FloatArray]:
    """Poses with IMU axis ``k`` along joint ``j``'s axis in attitude ``case`` and above the
    floor, nearest ``q_home`` first (empty: none found). The floor is part of the search: a
    hinge residual on the heights (:func:`_floor_points`, 2 cm of clearance) at the pose and,
    for a horizontal axis (the turn changes the heights), at 12 angles of a full turn of
    joint ``j``; the pose nearest home with the tool pointing down is otherwise below the
    floor on an outstretched arm and the case was reported impossible."""
    e_k = np.eye(3)[k]
    lo_f = np.where(np.isfinite(lo), lo, -2 * math.pi)
    hi_f = np.where(np.isfinite(hi), hi, 2 * math.pi)
    turns = (np.linspace(0.0, 2 * math.pi, 12, endpoint=False) if case == 'horizontal'
             else np.zeros(1))
    floor = min_height_m + 0.02

    def constraint(q: FloatArray) -> FloatArray:
        R = fx.R_enu_imu(q)
        u = fx.joint_axes_enu(q)[j]
        a = R @ e_k
        parts = [np.cross(a, u)]
        if case == 'horizontal':
            parts.append(np.array([u @ UP]))
        else:
            parts.append(a - (UP if case == 'up' else -UP))
        qs = np.repeat(q[None, :], len(turns), axis=0)
        qs[:, j] += turns
        parts.append(np.maximum(0.0, floor - _floor_points(fx, qs)).ravel())
        return np.concatenate(parts)

    def resid(q: FloatArray) -> FloatArray:
        return np.concatenate([10.0 * constraint(q), 0.02 * (q - q_home)])

    x0s = [np.clip(q_home, lo_f, hi_f)] if starts == 0 else []
    for _ in range(starts):
        x0s.append(np.clip(q_home + rng.uniform(-math.pi, math.pi, len(q_home)), lo_f, hi_f))
    found: list[tuple[float, FloatArray]] = []
    for x0 in x0s:
        x0 = np.clip(x0, lo_f + 1e-9, hi_f - 1e-9)
        sol = least_squares(resid, x0, bounds=(lo_f, hi_f), xtol=1e-10, ftol=1e-10,
                            max_nfev=60)
        if np.abs(constraint(sol.x)).max() > 1e-2:  # not near a solution: give up early
            continue
        sol = least_squares(constraint, np.clip(sol.x, lo_f + 1e-9, hi_f - 1e-9),
                            bounds=(lo_f, hi_f), xtol=1e-14, ftol=1e-14, gtol=1e-14,
                            max_nfev=60)
        if np.abs(constraint(sol.x)).max() > 1e-9:
            continue
        found.append((float(np.sum((sol.x - q_home) ** 2)), sol.x))
    return [q for _, q in sorted(found, key=lambda c: c[0])]


def _sweep_start(q_j: float, lo: float, hi: float, angle: float) -> float | None:
    """A start angle for joint j (equivalent to ``q_j`` for the constraint: any turn about
    its own axis keeps it) from which ``q_j + angle`` stays within ``[lo, hi]``, nearest to
    ``q_j``; None if the range is too small."""
    a0, a1 = (0.0, angle) if angle >= 0 else (angle, 0.0)
    lo_s, hi_s = lo - a0, hi - a1  # start must lie in [lo_s, hi_s]
    if lo_s > hi_s:
        return None
    return float(min(max(q_j, lo_s), hi_s))


def _sweep(fx: Fixture, j: int, q: FloatArray, q_now: FloatArray, lo: FloatArray,
           hi: FloatArray, angle: float, min_height_m: float) -> tuple[FloatArray, float] | None:
    """The start pose and sign of a turn of joint ``j`` by ``angle`` from pose ``q`` that
    stays within the joint's range and above the floor, reached from ``q_now`` above the
    floor (a ``set`` step: a straight line in joint space); None if neither sign does."""
    for sgn in (1.0, -1.0):
        start = _sweep_start(q[j], lo[j], hi[j], sgn * angle)
        if start is None:
            continue
        qs = q.copy()
        qs[j] = start
        sweep = np.repeat(qs[None, :], 73, axis=0)
        sweep[:, j] += np.linspace(0.0, sgn * angle, 73)
        transit = q_now[None, :] + np.linspace(0.0, 1.0, 49)[:, None] * (qs - q_now)[None, :]
        if _heights_ok(fx, sweep, min_height_m) and _heights_ok(fx, transit, min_height_m):
            return qs, sgn
    return None


def _can_align(fx: Fixture, j: int, k: int, rng: np.random.Generator) -> bool:
    """Whether joint ``j``'s axis can lie along IMU axis ``k`` at all (it depends on the
    joints after ``j`` only): False if over 4096 random poses ``|u_j . e_k|`` stays below
    0.9, e.g. always 0 for an IMU axis perpendicular to the last joint's (that joint's
    axis in the IMU frame is constant)."""
    q = rng.uniform(-math.pi, math.pi, (4096, fx.n_joints))
    return bool(np.abs(fx.joint_axes_imu(q)[:, j, k]).max() >= 0.9)


def excitation_plan(fx: Fixture, q_home_rad: Any | None = None, rotation_deg: float = 360.0,
                    vertical_rotation_deg: float = 180.0, rotation_s: float = 20.0,
                    dwell_s: float = 10.0, max_rate_rad_s: float = math.radians(30.0),
                    margin_rad: float = 0.05, min_height_m: float = 0.15, seed: int = 0,
                    starts: int = 12, gyro_noise_rad_s_rt_hz: float | None = None,
                    gyro_bias_sigma_rad_s: float | None = None
                    ) -> tuple[Plan, list[ExcitationRow]]:
    """The SRT-like excitation plan of a chain (module docstring) and its table.

    Every dwell lasts ``dwell_s``, or longer when the unit's white rate noise
    ``gyro_noise_rad_s_rt_hz`` and the wanted gyro-bias sigma ``gyro_bias_sigma_rad_s`` are
    both given: then the dwells share :func:`stationary_time_for_gyro_bias` equally.

    Returns
    -------
    plan : Plan
        Starts at ``q_home_rad`` (default: the middle of every limited joint's range, zero
        for unlimited ones) with a dwell; per (IMU axis, attitude): move there, dwell,
        rotate by +angle, dwell, by -angle, dwell.
    rows : list of ExcitationRow
        The joint used per (axis, attitude), or the reason none could.

    Raises
    ------
    PlanError
        The home pose violates a limit, or the chain can excite nothing at all.
    """
    n = fx.n_joints
    lo, hi = _limits(fx, margin_rad)
    q_home = (home_pose(fx, margin_rad, min_height_m, seed) if q_home_rad is None
              else np.asarray(q_home_rad, dtype=float))
    why = fx.check_limits(q_home)
    if why is not None:
        raise PlanError(f'excitation plan: the home pose is outside the limits: {why}')
    rng = np.random.default_rng(seed)
    names = fx.joint_names
    steps: list[dict[str, Any]] = [_home_step(names, q_home, max_rate_rad_s),
                                   {'dwell': {'duration_s': dwell_s, 'label': 'home'}}]
    rows: list[ExcitationRow] = []
    q_now = q_home.copy()
    aligns = np.array([[fx.joints[j].revolute and _can_align(fx, j, k, rng) for k in range(3)]
                       for j in range(n)])
    for k in range(3):
        for case in CASES:
            angle = math.radians(rotation_deg if case == 'horizontal' else vertical_rotation_deg)
            axis = 'xyz'[k]
            found = None
            reasons: list[str] = []
            # innermost joint first (the smallest sweep of the arm), from the current pose;
            # then seeded random starts
            tries = [(j, 0) for j in range(n - 1, -1, -1)] + \
                [(j, starts) for j in range(n - 1, -1, -1)]
            for j, n_starts in tries:
                if not fx.joints[j].revolute:
                    continue
                if not aligns[j, k]:
                    reasons.append(f'{names[j]}: its axis is never along the IMU {axis} axis')
                    continue
                poses = _solve(fx, k, case, j, q_now, lo, hi, rng, n_starts, min_height_m)
                if not poses:
                    reasons.append(f'{names[j]}: no pose within the limits and above the floor')
                    continue
                for q in poses:
                    found = _sweep(fx, j, q, q_now, lo, hi, angle, min_height_m)
                    if found:
                        break
                if found:
                    break
                reasons.append(f'{names[j]}: the turn leaves its range or goes below the '
                               'floor')
            reasons = sorted(set(reasons))
            if found is None:
                rows.append(ExcitationRow(axis, case, None, 0.0,
                                          '; '.join(reasons) or 'no revolute joint'))
                continue
            qs, sgn = found
            travel = float(np.max(np.abs(qs - q_now)))
            steps.append({'set': {'joints': {nm: math.degrees(v) for nm, v in zip(names, qs)},
                                  'duration_s': max(2.0, 1.875 * travel / max_rate_rad_s),
                                  'label': f'orient:{axis}:{case}'}})
            label = f'srt:{axis}-{case}'
            steps.append({'dwell': {'duration_s': dwell_s, 'label': label}})
            for d in (sgn, -sgn):
                deg = math.degrees(d * angle)
                steps.append({'move': {'joint': names[j], 'by_deg': deg,
                                       'duration_s': rotation_s * abs(deg) / 360.0,
                                       'label': f'rot:{axis}:{deg:+g}'}})
                steps.append({'dwell': {'duration_s': dwell_s, 'label': label}})
            rows.append(ExcitationRow(axis, case, names[j], math.degrees(sgn * angle)))
            q_now = qs
    if len(steps) == 2:
        raise PlanError('excitation plan: no joint of this chain can turn the IMU about any of '
                        'its axes within the limits')
    if gyro_noise_rad_s_rt_hz is not None and gyro_bias_sigma_rad_s is not None:
        dwells = [st['dwell'] for st in steps if 'dwell' in st]
        need = stationary_time_for_gyro_bias(gyro_noise_rad_s_rt_hz, gyro_bias_sigma_rad_s)
        each = max(dwell_s, math.ceil(need / len(dwells)))
        for d in dwells:
            d['duration_s'] = float(each)
    plan = plan_from_dict({'name': 'chain_excitation', 'description': (
        'SRT-like excitation generated for the chain (imu_calib_ros.core.chain_plans); '
        'start pose: ' + ', '.join(f'{nm} {math.degrees(v):.1f} deg'
                                   for nm, v in zip(names, q_home))),
        'steps': steps}, '<excitation plan>')
    build_profile(plan, fx, q_home)  # every step within the limits (PlanError otherwise)
    return plan, rows


def stationary_time_for_gyro_bias(gyro_noise_rad_s_rt_hz: float,
                                  gyro_bias_sigma_rad_s: float) -> float:
    """Stationary time [s] an excitation plan needs for a gyro-bias sigma on a unit of white
    rate noise ``N`` (angle random walk) and no bias instability: ``(N / sigma)^2``, the
    bias of each axis being the mean rate over the dwells (the rotations between them add
    little). Measured on arm6.urdf with mems_mti1's noise (0.007 deg/s/sqrt(Hz)) without
    its instability, replayed with that grade (bench/bench_arm.py, seeds 1-3): sigmas
    1.44, 0.93 and 0.72-0.74 deg/h with 280, 820 and 1400 s of dwells, where ``N /
    sqrt(T)`` is 1.50, 0.88 and 0.67. A unit with a bias instability has a floor no plan
    length lowers (:func:`imu_calib_ros.core.estimator.noise.gyro_bias_floor_rad_s`)."""
    if gyro_bias_sigma_rad_s <= 0.0:
        raise PlanError('stationary_time_for_gyro_bias: the wanted sigma must be positive')
    return (gyro_noise_rad_s_rt_hz / gyro_bias_sigma_rad_s) ** 2


def random_chain_plan(fx: Fixture, seed: int, count: int = 20,
                      q_home_rad: Any | None = None, max_rate_rad_s: float = math.radians(30.0),
                      dwell_s: tuple[float, float] = (3.0, 8.0), margin_rad: float = 0.05,
                      min_height_m: float = 0.15, max_step_rad: float = math.pi) -> Plan:
    """Random poses within the limits (and above the floor), reached by joint-space moves at
    most ``max_rate_rad_s`` fast, with random dwells (reproducible from ``seed``)."""
    lo, hi = _limits(fx, margin_rad)
    q = (home_pose(fx, margin_rad, min_height_m, seed) if q_home_rad is None
         else np.asarray(q_home_rad, dtype=float))
    rng = np.random.default_rng(seed)
    names = fx.joint_names
    steps: list[dict[str, Any]] = [_home_step(names, q, max_rate_rad_s),
                                   {'dwell': {'duration_s': dwell_s[1]}}]
    made = 0
    for _ in range(count * 50):
        if made >= count:
            break
        target = np.clip(q + rng.uniform(-max_step_rad, max_step_rad, len(q)), lo, hi)
        path = q[None, :] + np.linspace(0, 1, 33)[:, None] * (target - q)[None, :]
        if not _heights_ok(fx, path, min_height_m):
            continue
        travel = float(np.max(np.abs(target - q)))
        steps.append({'set': {'joints': {nm: math.degrees(v) for nm, v in zip(names, target)},
                              'duration_s': max(2.0, 1.875 * travel / max_rate_rad_s),
                              'label': f'random:{made + 1}'}})
        steps.append({'dwell': {'duration_s': float(rng.uniform(*dwell_s)),
                                'label': f'random:{made + 1}'}})
        q = target
        made += 1
    return plan_from_dict({'name': f'chain_random_{seed}', 'description':
                           'random poses within the chain limits', 'steps': steps},
                          f'<random chain plan {seed}>')


def _home_step(names: tuple[str, ...], q: FloatArray, max_rate_rad_s: float) -> dict[str, Any]:
    """Go to the home pose from wherever the chain is (the plan runs from any start pose; the
    move takes at least 2 s and never more than ``max_rate_rad_s`` for a full turn)."""
    return {'set': {'joints': {nm: math.degrees(v) for nm, v in zip(names, q)},
                    'duration_s': max(4.0, 1.875 * 2 * math.pi / max_rate_rad_s),
                    'label': 'home'}}


def plan_to_dict(plan: Plan) -> dict[str, Any]:
    """A generated plan as a plan-file mapping (``config/plans`` format, docs/PLANS.md)."""
    return {'name': plan.name, 'description': plan.description,
            'steps': [{s.kind: {k: v for k, v in s.params.items() if v is not None}}
                      for s in plan.steps]}


def home_pose(fx: Fixture, margin_rad: float = 0.05, min_height_m: float = 0.15,
              seed: int = 0) -> FloatArray:
    """The default start pose of the generated plans: the middle of every limited joint's
    range (0 for unlimited ones) if it is above the floor, else the nearest of seeded random
    poses within the limits that is."""
    lo, hi = _limits(fx, margin_rad)
    fin = np.isfinite(lo) & np.isfinite(hi)
    mid = np.where(fin, 0.5 * (np.where(fin, lo, 0.0) + np.where(fin, hi, 0.0)), 0.0)
    if _heights_ok(fx, mid, min_height_m):
        return mid
    rng = np.random.default_rng(seed)
    lo_f = np.where(np.isfinite(lo), lo, mid - math.pi)
    hi_f = np.where(np.isfinite(hi), hi, mid + math.pi)
    best, best_d = None, math.inf
    for scale in (0.25, 0.5, 1.0):
        cand = np.clip(mid + scale * rng.uniform(-math.pi, math.pi, (4000, len(mid))), lo_f,
                       hi_f)
        z = fx.p_enu_m(cand)[:, 2]
        O = fx._origins(cand)[2][:, 2:, 2]  # noqa: SLF001
        ok = (z >= min_height_m) & (O.min(axis=1) >= min_height_m)
        if ok.any():
            d = np.abs(cand[ok] - mid).max(axis=1)
            i = int(np.argmin(d))
            if d[i] < best_d:
                best, best_d = cand[ok][i], float(d[i])
            break
    if best is None:
        raise PlanError('no pose within the limits keeps the IMU above the floor '
                        f'({min_height_m} m above the base origin)')
    return best
