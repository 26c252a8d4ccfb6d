"""The fixture builder: a :class:`~.model.Plan` mapped onto a fixture as a
:class:`~.model.JointProfile` (see :mod:`.model` for the pieces).

Steps that name IMU axes are resolved through the fixture's kinematics at the attitude the
plan has reached; a step the fixture cannot do (or, on a URDF chain, one that would leave a
joint's limits) is a :class:`~imu_calib_ros.core.errors.PlanError` naming the step.
"""
from __future__ import annotations

import math
from typing import Any, Mapping

import numpy as np
from scipy.optimize import least_squares

from ..errors import PlanError
from ..fixture import Fixture
from ..types import FloatArray
from .model import JointProfile, Plan, Segment, Step, _Piece
from .parse import SRT_TABLE, _parse_axis

AXIS_TOL_RAD = math.radians(1.0)  # an IMU axis "lies along" a joint axis within this angle
DEFAULT_MAX_RATE_RAD_S = math.radians(30.0)  # peak rate of moves without a duration
MIN_MOVE_S = 2.0
DEFAULT_MAX_ACCEL_RAD_S2 = math.radians(100.0)  # peak acceleration of default spin ramps


class _Builder:
    """Accumulates pieces and segments while walking the steps."""

    def __init__(self, fixture: Fixture, q0: FloatArray):
        self.fx = fixture
        self.n = fixture.n_joints
        self.t = 0.0
        self.q = np.array(q0, dtype=float)
        self.pieces: list[_Piece] = []
        self.segments: list[Segment] = []
        self.limited = any(j.has_limits or j.velocity is not None for j in fixture.joints)
        self.where = ''

    # -- primitive pieces
    def _add(self, piece: _Piece, kind: str, label: str, meta: dict[str, Any]) -> None:
        if self.limited and piece.kind != 'hold':  # a URDF chain's limits (issue 15)
            t = np.linspace(piece.t0, piece.t1, 65)
            q, qd, _ = piece.evaluate(t)
            why = self.fx.check_limits(q, qd)
            if why is not None:
                raise PlanError(f'{self.where}: {why}')
        self.pieces.append(piece)
        self.segments.append(Segment(piece.t0, piece.t1, kind, label, meta))
        self.t = piece.t1
        self.q = piece.end()

    def dwell(self, duration: float, label: str, meta: dict[str, Any] | None = None) -> None:
        if duration <= 0:
            return
        self._add(_Piece(self.t, self.t + duration, 'hold', self.q.copy(), np.zeros(self.n)),
                  'dwell', label, dict(meta or {}))

    def move(self, dq: FloatArray, duration: float | None, label: str,
             meta: dict[str, Any] | None = None) -> None:
        dq = np.asarray(dq, dtype=float)
        if np.max(np.abs(dq)) < 1e-12:
            return
        if duration is None:
            duration = max(MIN_MOVE_S, 1.875 * float(np.max(np.abs(dq))) /
                           DEFAULT_MAX_RATE_RAD_S)  # quintic peak rate = 1.875 dq / T
        self._add(_Piece(self.t, self.t + duration, 'quintic', self.q.copy(), dq),
                  'move', label, dict(meta or {}))

    # -- geometry helpers
    def joint(self, name: Any, where: str, kind: str) -> int:
        if isinstance(name, int) and not isinstance(name, bool):
            if -self.n <= name < self.n:
                return name % self.n
            raise PlanError(f'{where} ({kind}): joint index {name} out of range for '
                            f'{self.n} joints')
        try:
            return self.fx.joint_index(str(name))
        except KeyError:
            raise PlanError(f'{where} ({kind}): the fixture has no joint {name!r} '
                            f'(joints: {", ".join(self.fx.joint_names)})') from None

    def joint_along(self, u_imu: FloatArray, where: str, kind: str) -> tuple[int, float]:
        """The joint whose axis lies along IMU axis ``u_imu`` now: (index, +1 or -1).

        The innermost such joint is used; a joint rotation by ``d`` turns the IMU by
        ``sign * d`` about ``u_imu`` because ``Rot(P a, d) P = P Rot(a, d)``.
        """
        R = self.fx.R_enu_imu(self.q)
        u_enu = R @ u_imu
        axes = self.fx.joint_axes_enu(self.q)
        cos = axes @ u_enu
        for j in range(self.n - 1, -1, -1):
            if abs(cos[j]) >= math.cos(AXIS_TOL_RAD):
                return j, float(np.sign(cos[j]))
        angles = np.degrees(np.arccos(np.clip(np.abs(cos), -1, 1)))
        desc = ', '.join(f'{nm} {a:.1f} deg' for nm, a in zip(self.fx.joint_names, angles))
        raise PlanError(f'{where} ({kind}): no fixture joint lies along IMU axis '
                        f'{_axis_name(u_imu)} at this attitude (angles to the joint axes: '
                        f'{desc}; need < {math.degrees(AXIS_TOL_RAD):.0f} deg)')

    def vertical_axis_name(self) -> str | None:
        """The IMU axis that points up now (e.g. '+x', '-z'), or None."""
        up_imu = self.fx.R_enu_imu(self.q).T @ np.array([0.0, 0.0, 1.0])
        k = int(np.argmax(np.abs(up_imu)))
        if abs(up_imu[k]) < math.cos(AXIS_TOL_RAD):
            return None
        return ('+' if up_imu[k] > 0 else '-') + 'xyz'[k]

    def solve_orientation(self, targets: list[tuple[FloatArray, FloatArray]],
                          along: list[tuple[FloatArray, list[int]]], where: str) -> FloatArray:
        """Joint angles nearest to the current ones meeting the attitude constraints.

        ``targets``: (IMU axis, ENU direction) pairs that must coincide; ``along``: (IMU axis,
        candidate joints) pairs of which the axis must be parallel to one candidate joint.
        Starts from a grid of multiples of 90 deg, refined by least squares (scipy).
        """
        import itertools
        n = self.n
        grid = np.array(list(itertools.product(np.radians([0.0, 90.0, 180.0, -90.0]),
                                               repeat=n)))
        best: FloatArray | None = None
        best_cost = math.inf
        choices = list(itertools.product(*[c for _, c in along])) if along else [()]
        for choice in choices:
            def resid(q: FloatArray, choice: tuple[int, ...] = choice) -> FloatArray:
                qb = q.reshape(-1, n)
                R = self.fx.R_enu_imu(qb)
                parts = [np.einsum('nij,j->ni', R, u) - t for u, t in targets]
                if along:
                    axes = self.fx.joint_axes_enu(qb)
                    for (u, _), j in zip(along, choice):
                        parts.append(np.cross(np.einsum('nij,j->ni', R, u), axes[:, j]))
                return np.concatenate(parts, axis=1)

            r = resid(grid.reshape(-1))
            norm = np.linalg.norm(r, axis=1)
            for k in np.argsort(norm)[:6]:
                if norm[k] > 1.0:
                    break
                x = grid[k]
                if norm[k] > 1e-12:  # refine a near miss (tilted axes or mounting)
                    x = least_squares(lambda q: resid(q)[0], grid[k], xtol=1e-15, ftol=1e-15,
                                      gtol=1e-15).x
                    if np.max(np.abs(resid(x))) > 1e-9:
                        continue
                target = self.q + np.mod(x - self.q + math.pi, 2 * math.pi) - math.pi
                cost = float(np.max(np.abs(target - self.q))) + 1e-9 * float(
                    np.sum(np.abs(target - self.q)))
                if cost < best_cost - 1e-9:
                    best, best_cost = target, cost
        if best is None:
            raise PlanError(f'{where} (orient): the fixture cannot reach that attitude')
        return best


def _axis_name(u: FloatArray) -> str:
    k = int(np.argmax(np.abs(u)))
    return ('+' if u[k] > 0 else '-') + 'xyz'[k]


def build_profile(plan: Plan, fixture: Fixture,
                  q_start_rad: Any | None = None) -> JointProfile:
    """Map ``plan`` onto ``fixture``: a :class:`JointProfile` starting at ``q_start_rad``.

    Raises
    ------
    PlanError
        Naming the step and the reason, if the fixture cannot do a step (unknown joint, no
        joint along the requested IMU axis, no vertical joint for a vertical oscillation,
        unreachable attitude), or, on a chain with URDF limits, naming the joint and the
        position or velocity limit the step would violate.
    """
    q0 = np.zeros(fixture.n_joints) if q_start_rad is None else np.asarray(q_start_rad, float)
    if q0.shape != (fixture.n_joints,):
        raise PlanError(f'q_start_rad must have {fixture.n_joints} values, got {q0.shape}')
    b = _Builder(fixture, q0)
    if b.limited:
        why = fixture.check_limits(q0)
        if why is not None:
            raise PlanError(f'{plan.source}: the start pose is outside the limits: {why}')
    for step in plan.steps:
        b.where = f'{step.where} ({step.kind})'
        _build_step(b, step)
    if not b.pieces:
        raise PlanError(f'{plan.source}: the plan has no motion and no dwell')
    return JointProfile(fixture.joint_names, tuple(b.pieces), tuple(b.segments), plan.name)


def _build_step(b: _Builder, step: Step) -> None:
    p, w, kind = step.params, step.where, step.kind
    label = p.get('label')
    if kind == 'dwell':
        b.dwell(float(p['duration_s']), label or 'dwell')
    elif kind == 'move':
        j = b.joint(p['joint'], w, kind)
        dq = np.zeros(b.n)
        if p['by_deg'] is not None:
            dq[j] = math.radians(p['by_deg'])
        else:
            dq[j] = math.radians(p['to_deg']) - b.q[j]
        b.move(dq, float(p['duration_s']), label or f'move:{b.fx.joint_names[j]}',
               {'joint': b.fx.joint_names[j]})
    elif kind == 'rotate_imu':
        _rotate_imu(b, _parse_axis(p['axis'], w, kind), math.radians(p['angle_deg']),
                    float(p['duration_s']), label, w)
    elif kind == 'set':
        q = b.q.copy()
        for name, deg in p['joints'].items():
            if isinstance(deg, bool) or not isinstance(deg, (int, float)):
                raise PlanError(f'{w} (set): angle of joint {name!r} must be a number')
            q[b.joint(name, w, kind)] = math.radians(deg)
        b.move(q - b.q, p['duration_s'], label or 'set', {})
    elif kind == 'orient':
        _orient(b, p, w)
    elif kind == 'oscillate':
        _oscillate(b, p, w)
    elif kind == 'spin':
        _spin(b, p, w)
    elif kind == 'srt_sequence':
        _srt(b, p, w)
    elif kind == 'random_moves':
        _random_moves(b, p, w)
    else:  # include and repeat are expanded while loading
        raise AssertionError(kind)


def _rotate_imu(b: _Builder, u_imu: FloatArray, angle: float, duration: float,
                label: str | None, where: str, meta: dict[str, Any] | None = None) -> None:
    j, sign = b.joint_along(u_imu, where, 'rotate_imu')
    dq = np.zeros(b.n)
    dq[j] = sign * angle
    name = _axis_name(u_imu)
    b.move(dq, duration, label or f'rot:{name}:{math.degrees(angle):+g}',
           {'imu_axis': name, 'angle_rad': angle, 'joint': b.fx.joint_names[j], **(meta or {})})


def _orient(b: _Builder, p: Mapping[str, Any], w: str) -> None:
    targets = []
    if p['down'] is not None:
        targets.append((_parse_axis(p['down'], w, 'orient'), np.array([0.0, 0.0, -1.0])))
    if p['up'] is not None:
        targets.append((_parse_axis(p['up'], w, 'orient'), np.array([0.0, 0.0, 1.0])))
    along = []
    for ax, jn in (p['along'] or {}).items():
        cands = (list(range(b.n)) if str(jn) == 'any' else [b.joint(jn, w, 'orient')])
        along.append((_parse_axis(ax, w, 'orient'), cands))
    q = b.solve_orientation(targets, along, w)
    desc = ','.join([f'{k}:{p[k]}' for k in ('down', 'up') if p[k] is not None])
    b.move(q - b.q, p['duration_s'], p['label'] or f'orient:{desc}', {})


def _oscillate(b: _Builder, p: Mapping[str, Any], w: str) -> None:
    if p['joint'] is not None:
        j = b.joint(p['joint'], w, 'oscillate')
    else:
        try:
            j, _ = b.joint_along(_parse_axis(p['imu_axis'], w, 'oscillate'), w, 'oscillate')
        except PlanError as exc:
            if p['vertical']:
                raise PlanError(f'{exc}; an oscillation about the vertical needs a joint '
                                'that can stand vertical along this IMU axis (e.g. a '
                                'three-axis table with a vertical outer axis)') from None
            raise
    axis_enu = b.fx.joint_axes_enu(b.q)[j]
    vertical = abs(axis_enu[2]) >= math.cos(AXIS_TOL_RAD)
    if p['vertical'] and not vertical:
        tilt_deg = math.degrees(math.acos(min(1.0, abs(axis_enu[2]))))
        raise PlanError(f'{w} (oscillate): needs a vertical axis, but joint '
                        f'{b.fx.joint_names[j]!r} is {tilt_deg:.1f} deg from vertical here '
                        '(a table with a vertical joint is needed)')
    amp = math.radians(p['amplitude_deg'])
    period = float(p['period_s'])
    up = b.vertical_axis_name()
    vec = np.zeros(b.n)
    vec[j] = 1.0
    label = p['label'] or (f'osc:{up[1]}-up:T{period:g}' if vertical and up
                           else f'osc:{b.fx.joint_names[j]}:T{period:g}')
    meta = {'joint': b.fx.joint_names[j], 'amplitude_rad': amp, 'period_s': period,
            'cycles': int(p['cycles']), 'center_rad': float(b.q[j] - amp),
            'up_axis': up, 'vertical': vertical}
    piece = _Piece(b.t, b.t + period * int(p['cycles']), 'cosine', b.q.copy(), vec, amp,
                   2.0 * math.pi / period)
    b._add(piece, 'oscillate', label, meta)


def _spin(b: _Builder, p: Mapping[str, Any], w: str) -> None:
    if p['joint'] is not None:
        j, sign = b.joint(p['joint'], w, 'spin'), 1.0
    else:
        j, sign = b.joint_along(_parse_axis(p['imu_axis'], w, 'spin'), w, 'spin')
    rate = sign * math.radians(p['rate_deg_s'])
    ramp = p['ramp_s']
    if ramp is None:  # cubic-smoothstep peak acceleration = 1.5 rate / ramp
        ramp = max(1.0, 1.5 * abs(rate) / DEFAULT_MAX_ACCEL_RAD_S2)
    vec = np.zeros(b.n)
    vec[j] = rate
    name = b.fx.joint_names[j]
    label = p['label'] or f'spin:{name}:{p["rate_deg_s"]:g}'
    meta = {'joint': name, 'rate_rad_s': rate}
    b._add(_Piece(b.t, b.t + ramp, 'ramp_up', b.q.copy(), vec), 'move', f'{label}:ramp_up', meta)
    b._add(_Piece(b.t, b.t + float(p['duration_s']), 'const', b.q.copy(), vec), 'spin', label,
           meta)
    b._add(_Piece(b.t, b.t + ramp, 'ramp_down', b.q.copy(), vec), 'move', f'{label}:ramp_down',
           meta)


def _srt(b: _Builder, p: Mapping[str, Any], w: str) -> None:
    """Savage's SRT sequence: orient, dwell, the rotations of Table 1, dwell."""
    sid = str(p['id'])
    down, _along_outer, rotations = SRT_TABLE[sid]
    # Savage's 'along the outer axis' column is specific to his fixture; in general the
    # first rotation axis (or, if that is the down axis, the next other one) must lie along
    # some joint; later rotations are checked as they come.
    axes = [ax for ax, _ in rotations]
    along = {axes[0]: 'any'}
    if axes[0] == down:
        along.update({ax: 'any' for ax in axes[1:2] if ax != down})
    _orient(b, {'down': down, 'up': None, 'along': along, 'duration_s': None,
                'label': f'orient:srt:{sid}'}, f'{w} (srt {sid})')
    label = f'srt:{sid}'
    dwell = float(p['dwell_s'])
    b.dwell(dwell, label, {'phase': 'before', 'sequence': sid})
    total = sum(abs(a) for _, a in rotations)
    for k, (ax, deg) in enumerate(rotations):
        _rotate_imu(b, _parse_axis(ax, w, 'srt_sequence'), math.radians(deg),
                    float(p['rotation_s']) * abs(deg) / total, label,
                    f'{w} (srt {sid} rotation {k + 1}: {deg:+g} about {ax})',
                    {'phase': 'rotation', 'sequence': sid, 'index': k})
    b.dwell(dwell, label, {'phase': 'after', 'sequence': sid})


def _random_moves(b: _Builder, p: Mapping[str, Any], w: str) -> None:
    rng = np.random.default_rng(int(p['seed']))
    names = p['joints'] if p['joints'] is not None else list(b.fx.joint_names)
    idx = [b.joint(nm, w, 'random_moves') for nm in names]
    for k in range(int(p['count'])):
        j = idx[int(rng.integers(len(idx)))]
        dq = np.zeros(b.n)
        dq[j] = math.radians(rng.uniform(-p['max_deg'], p['max_deg']))
        b.move(dq, float(rng.uniform(*p['duration_s'])), f'random:{k + 1}',
               {'joint': b.fx.joint_names[j]})
        b.dwell(float(rng.uniform(*p['dwell_s'])), f'random:{k + 1}')
