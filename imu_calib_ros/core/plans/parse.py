"""Plan files: YAML step lists validated into a :class:`~.model.Plan`.

A plan (``config/plans/NAME.yaml``, format in ``docs/PLANS.md``) lists steps (dwell, move,
rotate_imu, orient, set, oscillate, spin, srt_sequence, random_moves, include, repeat);
includes and repeats are expanded here, so a :class:`~.model.Plan` is a flat step list.
Keys and values are checked here, before any fixture is involved; what a fixture cannot
do is found by :func:`~.builder.build_profile`.
"""
from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Any, Iterable, Mapping

import numpy as np

from ..config import load_yaml, resolve_config_file
from ..errors import ConfigError, PlanError
from ..types import FloatArray
from .model import Plan, Step

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
