"""Motion plans: YAML step lists mapped onto a fixture as analytic joint-angle profiles.

A plan (``config/plans/NAME.yaml``, format in ``docs/PLANS.md``) lists steps (dwell, move,
rotate_imu, orient, set, oscillate, spin, srt_sequence, random_moves, include, repeat).
:func:`build_profile` maps it onto a :class:`~imu_calib_ros.core.fixture.Fixture` and returns
a :class:`JointProfile`: piecewise analytic ``q(t), q'(t), q''(t)`` whose pieces are

- ``hold``: at rest;
- ``quintic``: rest-to-rest move, ``q0 + dq (10 s^3 - 15 s^4 + 6 s^5)``, ``s = t / T``
  (acceleration continuous and zero at both ends);
- ``cosine``: Kozlov & Kapralov's harmonic oscillation in the from-rest form
  ``psi = psi_c + A cos(W t)``, ``W = 2 pi / T``, ``psi_c = psi_start - A``, whole cycles;
- ``ramp_up`` / ``const`` / ``ramp_down``: continuous rotation (rotation modulation) with a
  cubic-smoothstep rate ramp, so the acceleration is continuous.

The third derivative may jump only at :attr:`JointProfile.breakpoints_s`, which is where the
simulator splits its Gauss-Legendre integration, so the integrals are exact to rounding.
"""
from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable, Mapping

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import least_squares

from .config import load_yaml, resolve_config_file
from .errors import ConfigError, PlanError
from .fixture import Fixture

FloatArray = NDArray[np.float64]

AXIS_TOL_RAD = math.radians(1.0)  # an IMU axis "lies along" a joint axis within this angle
DEFAULT_MAX_RATE_RAD_S = math.radians(30.0)  # peak rate of moves without a duration
MIN_MOVE_S = 2.0
DEFAULT_MAX_ACCEL_RAD_S2 = math.radians(100.0)  # peak acceleration of default spin ramps
_IMU_AXES = {'x': 0, 'y': 1, 'z': 2}

# Savage, "Improved strapdown IMU calibration procedures", Table 1 (as restated in
# METHODS.md): id -> (IMU axis down, IMU axis along the outer axis, rotations (axis, deg)).
SRT_TABLE: dict[str, tuple[str, str, tuple[tuple[str, float], ...]]] = {
    '1': ('z', 'y', (('y', 360.0),)),
    '2': ('z', 'x', (('x', 360.0),)),
    '3': ('x', 'y', (('z', 360.0),)),
    '1a': ('z', 'y', (('y', -360.0),)),
    '2a': ('z', 'x', (('x', -360.0),)),
    '3a': ('x', 'y', (('z', -360.0),)),
    '4': ('z', 'y', (('y', 180.0), ('z', 180.0), ('y', 180.0), ('z', 180.0))),
    '5': ('z', 'x', (('x', 180.0), ('z', 180.0), ('x', 180.0), ('z', 180.0))),
    '6': ('x', 'y', (('y', 180.0), ('z', 90.0), ('x', 180.0), ('z', 90.0),
                     ('y', 180.0), ('z', 90.0), ('x', 180.0), ('z', 90.0))),
    '7': ('y', 'x', (('x', 180.0),)),
    '8': ('z', 'x', (('x', 180.0),)),
    '9': ('x', 'y', (('z', 180.0),)),
    '10': ('y', 'x', (('z', 180.0),)),
    '11': ('z', 'y', (('y', 180.0),)),
    '12': ('x', 'y', (('y', 180.0),)),
    '13': ('z', 'y', (('z', 180.0), ('y', 180.0))),
    '14': ('z', 'x', (('z', 180.0), ('x', 180.0))),
}

# kind -> (required keys, optional keys with defaults)
_SCHEMA: dict[str, tuple[tuple[str, ...], dict[str, Any]]] = {
    'dwell': (('duration_s',), {'label': None}),
    'move': (('joint', 'duration_s'), {'to_deg': None, 'by_deg': None, 'label': None}),
    'rotate_imu': (('axis', 'angle_deg', 'duration_s'), {'label': None}),
    'orient': ((), {'down': None, 'up': None, 'along': None, 'duration_s': None,
                    'label': None}),
    'set': (('joints',), {'duration_s': None, 'label': None}),
    'oscillate': (('amplitude_deg', 'period_s', 'cycles'),
                  {'joint': None, 'imu_axis': None, 'vertical': False, 'label': None}),
    'spin': (('rate_deg_s', 'duration_s'),
             {'joint': None, 'imu_axis': None, 'ramp_s': None, 'label': None}),
    'srt_sequence': (('id',), {'dwell_s': 10.0, 'rotation_s': 20.0}),
    'random_moves': (('seed', 'count'),
                     {'joints': None, 'max_deg': 180.0, 'duration_s': [2.0, 6.0],
                      'dwell_s': [5.0, 15.0]}),
    'include': (('plan',), {}),
    'repeat': (('count', 'steps'), {}),
}


# --------------------------------------------------------------------------- plan objects
@dataclass(frozen=True)
class Step:
    """One validated plan step: ``kind``, its parameters, and where it came from."""

    kind: str
    params: Mapping[str, Any]
    where: str  # e.g. "plans/x.yaml step 3" or "... step 2 > include y.yaml step 1"


@dataclass(frozen=True)
class Plan:
    """A loaded plan: includes and repeats already expanded into a flat step list."""

    name: str
    description: str
    steps: tuple[Step, ...]
    source: str = '<dict>'


@dataclass(frozen=True)
class Segment:
    """A labelled time window of a profile (``kind`` in dwell/move/oscillate/spin)."""

    t0_s: float
    t1_s: float
    kind: str
    label: str
    meta: dict[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class _Piece:
    t0: float
    t1: float
    kind: str  # hold | quintic | cosine | ramp_up | const | ramp_down
    q0: FloatArray  # (n,) joint angles at t0
    vec: FloatArray  # (n,) quintic: delta; ramps/const: rate; cosine: unit joint selector
    amp: float = 0.0  # cosine amplitude [rad]
    omega: float = 0.0  # cosine angular frequency W [rad/s]

    def end(self) -> FloatArray:
        T = self.t1 - self.t0
        if self.kind == 'quintic':
            return self.q0 + self.vec
        if self.kind in ('ramp_up', 'ramp_down'):
            return self.q0 + 0.5 * self.vec * T
        if self.kind == 'const':
            return self.q0 + self.vec * T
        return self.q0.copy()  # hold; cosine runs whole cycles

    def evaluate(self, t: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        T = self.t1 - self.t0
        u = np.clip(t - self.t0, 0.0, T)[:, None]
        s = u / T if T > 0 else np.zeros_like(u)
        q0, v = self.q0[None, :], self.vec[None, :]
        zero = np.zeros((t.shape[0], q0.shape[1]))
        if self.kind == 'hold':
            return q0 + zero, zero, zero.copy()
        if self.kind == 'quintic':
            pos = s**3 * (10.0 + s * (-15.0 + 6.0 * s))
            vel = 30.0 * s**2 * (1.0 - s) ** 2 / T
            acc = 60.0 * s * (1.0 - s) * (1.0 - 2.0 * s) / T**2
            return q0 + v * pos, v * vel, v * acc
        if self.kind == 'cosine':
            wu = self.omega * u
            a = self.amp
            return (q0 + v * a * (np.cos(wu) - 1.0), -v * a * self.omega * np.sin(wu),
                    -v * a * self.omega**2 * np.cos(wu))
        if self.kind == 'ramp_up':
            return (q0 + v * T * s**3 * (1.0 - 0.5 * s), v * s**2 * (3.0 - 2.0 * s),
                    v * 6.0 * s * (1.0 - s) / T)
        if self.kind == 'const':
            return q0 + v * u, v + zero, zero
        if self.kind == 'ramp_down':
            return (q0 + v * T * s * (1.0 - s**2 + 0.5 * s**3),
                    v * (1.0 - s**2 * (3.0 - 2.0 * s)), -v * 6.0 * s * (1.0 - s) / T)
        raise AssertionError(self.kind)


@dataclass(frozen=True)
class JointProfile:
    """Analytic joint-angle profile of a plan on one fixture (see module docstring)."""

    joint_names: tuple[str, ...]
    pieces: tuple[_Piece, ...]
    segments: tuple[Segment, ...]
    plan_name: str = ''

    @property
    def duration_s(self) -> float:
        """End time of the profile (it starts at 0)."""
        return self.pieces[-1].t1 if self.pieces else 0.0

    @property
    def breakpoints_s(self) -> FloatArray:
        """Times (K,) where the third derivative may jump, incl. 0 and the end."""
        t = [p.t0 for p in self.pieces] + [self.duration_s]
        return np.unique(np.asarray(t, dtype=float))

    @property
    def q_start(self) -> FloatArray:
        """Joint angles at t = 0."""
        return self.pieces[0].q0.copy()

    def evaluate(self, t_s: Any) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Joint angles, rates and accelerations at times ``t_s`` (N,), each (N, n).

        Times outside [0, duration] give the rest state at the nearest end. At a
        breakpoint the piece that starts there is used (all pieces join with continuous
        q, q' and q''; only an oscillation's start and end have an acceleration jump).
        """
        t = np.atleast_1d(np.asarray(t_s, dtype=float))
        n = len(self.joint_names)
        q = np.empty((t.shape[0], n))
        qd = np.empty_like(q)
        qdd = np.empty_like(q)
        starts = np.array([p.t0 for p in self.pieces])
        idx = np.clip(np.searchsorted(starts, t, side='right') - 1, 0, len(self.pieces) - 1)
        for k in np.unique(idx):
            sel = idx == k
            q[sel], qd[sel], qdd[sel] = self.pieces[k].evaluate(t[sel])
        return q, qd, qdd

    def stationary_windows(self, min_duration_s: float = 0.0) -> list[tuple[float, float]]:
        """Merged time windows (t0, t1) in which every joint is at rest."""
        out: list[tuple[float, float]] = []
        for p in self.pieces:
            if p.kind != 'hold':
                continue
            if out and abs(out[-1][1] - p.t0) < 1e-12:
                out[-1] = (out[-1][0], p.t1)
            else:
                out.append((p.t0, p.t1))
        return [w for w in out if w[1] - w[0] >= min_duration_s]

    def segments_labelled(self, prefix: str) -> list[Segment]:
        """Segments whose label starts with ``prefix`` (e.g. ``'srt:'``, ``'osc:'``)."""
        return [s for s in self.segments if s.label.startswith(prefix)]


# ------------------------------------------------------------------------------ loading
def load_plan(name_or_path: str | os.PathLike[str]) -> Plan:
    """Load a plan by shipped name (``'savage_srt'``) or path; expands include and repeat.

    Raises
    ------
    ConfigError
        Missing file or malformed YAML.
    PlanError
        Unknown step kind, unknown or missing key, bad value (names file and step).
    """
    path = resolve_config_file(str(name_or_path), 'plans')
    return plan_from_dict(load_yaml(path), str(path), _stack=(str(Path(path).resolve()),))


def plan_from_dict(data: Any, source: str = '<dict>', _stack: tuple[str, ...] = ()) -> Plan:
    """Validate a plan mapping (``name``, ``description``, ``steps``) into a :class:`Plan`."""
    if not isinstance(data, Mapping):
        raise PlanError(f'{source}: a plan file must be a mapping with name and steps')
    unknown = set(data) - {'name', 'description', 'steps'}
    if unknown:
        raise PlanError(f'{source}: unknown top-level key {sorted(unknown)[0]!r} '
                        '(known: name, description, steps)')
    if not isinstance(data.get('steps'), list) or not data['steps']:
        raise PlanError(f'{source}: steps: expected a non-empty list of steps')
    steps = _parse_steps(data['steps'], source, source, _stack)
    return Plan(str(data.get('name', Path(source).stem)), str(data.get('description', '')),
                tuple(steps), source)


def _parse_steps(raw: list[Any], source: str, prefix: str,
                 stack: tuple[str, ...]) -> list[Step]:
    out: list[Step] = []
    for i, item in enumerate(raw, start=1):
        where = f'{prefix} step {i}'
        if not isinstance(item, Mapping) or len(item) != 1:
            raise PlanError(f'{where}: a step is a mapping with exactly one key, the step '
                            f'kind ({", ".join(_SCHEMA)}), got {item!r}')
        kind, params = next(iter(item.items()))
        if kind not in _SCHEMA:
            raise PlanError(f'{where}: unknown step kind {kind!r} '
                            f'(known: {", ".join(_SCHEMA)})')
        if params is None:
            params = {}
        if not isinstance(params, Mapping):
            raise PlanError(f'{where} ({kind}): parameters must be a mapping, got {params!r}')
        required, optional = _SCHEMA[kind]
        for k in params:
            if k not in required and k not in optional:
                raise PlanError(f'{where} ({kind}): unknown key {k!r} '
                                f'(known: {", ".join([*required, *optional])})')
        for k in required:
            if k not in params:
                raise PlanError(f'{where} ({kind}): missing key {k!r}')
        p = {**optional, **params}
        _check_values(kind, p, where)
        if kind == 'include':
            path = resolve_plan_path(str(p['plan']), source, where)
            key = str(path.resolve())
            if key in stack:
                raise PlanError(f'{where} (include): {path} includes itself')
            try:
                data = load_yaml(path)
            except ConfigError as exc:
                raise PlanError(f'{where} (include): {exc}') from None
            sub = plan_from_dict(data, str(path), (*stack, key))
            out.extend(Step(s.kind, s.params, f'{where} > {s.where}') for s in sub.steps)
        elif kind == 'repeat':
            if not isinstance(p['steps'], list) or not p['steps']:
                raise PlanError(f'{where} (repeat): steps must be a non-empty list')
            inner = _parse_steps(p['steps'], source, f'{where} (repeat)', stack)
            for r in range(int(p['count'])):
                out.extend(Step(s.kind, s.params, f'{s.where} [pass {r + 1}]') for s in inner)
        else:
            out.append(Step(kind, dict(p), where))
    return out


def resolve_plan_path(name: str, source: str, where: str) -> Path:
    """An included plan: a path relative to the including file, or a shipped name."""
    here = Path(source).parent / name
    if here.is_file():
        return here
    try:
        return resolve_config_file(name, 'plans')
    except ConfigError as exc:
        raise PlanError(f'{where} (include): {exc}') from None


def _num(p: Mapping[str, Any], key: str, where: str, kind: str, positive: bool = False,
         nonneg: bool = False) -> None:
    v = p[key]
    if v is None:
        return
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        raise PlanError(f'{where} ({kind}): {key} must be a finite number, got {v!r}')
    if positive and v <= 0:
        raise PlanError(f'{where} ({kind}): {key} must be > 0, got {v!r}')
    if nonneg and v < 0:
        raise PlanError(f'{where} ({kind}): {key} must be >= 0, got {v!r}')


def _check_values(kind: str, p: dict[str, Any], where: str) -> None:
    for key in ('duration_s', 'period_s', 'rotation_s'):
        if key in p and not (kind == 'random_moves' and key == 'duration_s'):
            _num(p, key, where, kind, positive=True)
    for key in ('to_deg', 'by_deg', 'angle_deg', 'rate_deg_s', 'amplitude_deg', 'max_deg'):
        if key in p:
            _num(p, key, where, kind)
    if 'dwell_s' in p and kind == 'srt_sequence':
        _num(p, 'dwell_s', where, kind, nonneg=True)
    if 'ramp_s' in p:
        _num(p, 'ramp_s', where, kind, positive=True)
    for key in ('cycles', 'count', 'seed'):
        if key in p and (isinstance(p[key], bool) or not isinstance(p[key], int)
                         or p[key] < (0 if key == 'seed' else 1)):
            raise PlanError(f'{where} ({kind}): {key} must be a positive integer, '
                            f'got {p[key]!r}')
    if kind == 'move' and (p['to_deg'] is None) == (p['by_deg'] is None):
        raise PlanError(f'{where} (move): give exactly one of to_deg and by_deg')
    if kind in ('oscillate', 'spin') and (p['joint'] is None) == (p['imu_axis'] is None):
        raise PlanError(f'{where} ({kind}): give exactly one of joint and imu_axis')
    if kind == 'oscillate' and p['amplitude_deg'] <= 0:
        raise PlanError(f'{where} (oscillate): amplitude_deg must be > 0')
    if kind == 'srt_sequence' and str(p['id']) not in SRT_TABLE:
        raise PlanError(f'{where} (srt_sequence): unknown id {p["id"]!r} '
                        f'(known: {", ".join(SRT_TABLE)})')
    if kind == 'rotate_imu' or (kind in ('oscillate', 'spin') and p['imu_axis'] is not None):
        _parse_axis(p['axis' if kind == 'rotate_imu' else 'imu_axis'], where, kind)
    if kind == 'orient':
        if p['down'] is None and p['up'] is None and p['along'] is None:
            raise PlanError(f'{where} (orient): give down or up (and optionally along)')
        if p['down'] is not None and p['up'] is not None:
            raise PlanError(f'{where} (orient): give only one of down and up')
        for key in ('down', 'up'):
            if p[key] is not None:
                _parse_axis(p[key], where, kind)
        if p['along'] is not None:
            if not isinstance(p['along'], Mapping):
                raise PlanError(f'{where} (orient): along must map IMU axes to joint names '
                                "(or 'any'), e.g. {y: outer}")
            for ax in p['along']:
                _parse_axis(ax, where, kind)
    if kind == 'set' and (not isinstance(p['joints'], Mapping) or not p['joints']):
        raise PlanError(f'{where} (set): joints must map joint names to angles in degrees')
    if kind == 'random_moves':
        for key in ('duration_s', 'dwell_s'):
            v = p[key]
            if (not isinstance(v, (list, tuple)) or len(v) != 2
                    or not all(isinstance(x, (int, float)) for x in v) or not 0 <= v[0] <= v[1]
                    or (key == 'duration_s' and v[0] <= 0)):
                raise PlanError(f'{where} (random_moves): {key} must be [min, max] seconds')


def _parse_axis(text: Any, where: str, kind: str) -> FloatArray:
    """'x', '+y', '-z' -> signed unit vector in the IMU frame."""
    s = str(text).strip().lower()
    sign = -1.0 if s.startswith('-') else 1.0
    s = s.lstrip('+-')
    if s not in _IMU_AXES:
        raise PlanError(f'{where} ({kind}): IMU axis must be x, y or z with an optional sign, '
                        f'got {text!r}')
    e = np.zeros(3)
    e[_IMU_AXES[s]] = sign
    return e


def random_plan(seed: int, count: int, joints: Iterable[str] | None = None,
                max_deg: float = 180.0, duration_s: tuple[float, float] = (2.0, 6.0),
                dwell_s: tuple[float, float] = (5.0, 15.0)) -> Plan:
    """A plan of ``count`` random moves of random joints with random dwells (reproducible)."""
    params = {'seed': seed, 'count': count, 'joints': None if joints is None else list(joints),
              'max_deg': max_deg, 'duration_s': list(duration_s), 'dwell_s': list(dwell_s)}
    return plan_from_dict({'name': f'random_{seed}', 'steps': [{'dwell': {'duration_s':
                           dwell_s[1]}}, {'random_moves': params}]}, f'<random seed {seed}>')


# ----------------------------------------------------------------------------- building
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
