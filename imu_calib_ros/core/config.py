"""Strict YAML loading into frozen, typed dataclasses: the one place for defaults and validation.

Every component (simulator, estimator, nodes) has one frozen config dataclass. Its fields
(with their defaults and ``metadata={'doc': ..., 'min': ..., 'max': ..., 'choices': ...}``)
are the single source of truth for the CLI, the node parameters and the YAML files in
``config/``. :func:`from_mapping` refuses unknown keys, missing required keys, wrong types
and out-of-range values with one :class:`ConfigError` naming the file and the key.
"""
from __future__ import annotations

import dataclasses
import math
import os
import types
import typing
from pathlib import Path
from typing import Any, Mapping, TypeVar

import yaml

from .errors import ConfigError

T = TypeVar('T')


def setting(default: Any, doc: str, lo: float | None = None, hi: float | None = None) -> Any:
    """A config dataclass field with its default, documentation and range (checked by
    :func:`from_mapping`, declared as node-parameter descriptors by the nodes)."""
    meta: dict[str, object] = {'doc': doc}
    if lo is not None:
        meta['min'] = lo
    if hi is not None:
        meta['max'] = hi
    return dataclasses.field(default=default, metadata=meta)


def load_yaml(path: str | os.PathLike[str]) -> Any:
    """Read a YAML file; a missing, unreadable or malformed file is a :class:`ConfigError`."""
    p = Path(path)
    try:
        text = p.read_text(encoding='utf-8')
    except FileNotFoundError:
        raise ConfigError('file not found', source=str(p)) from None
    except OSError as exc:
        raise ConfigError(f'cannot read file ({exc.strerror})', source=str(p)) from None
    try:
        return yaml.safe_load(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, 'problem_mark', None)
        where = f' at line {mark.line + 1}, column {mark.column + 1}' if mark else ''
        problem = getattr(exc, 'problem', None) or 'not valid YAML'
        raise ConfigError(f'malformed YAML{where}: {problem}', source=str(p)) from None


def require_mapping(value: Any, source: str | None, key: str | None) -> Mapping[str, Any]:
    """Check that ``value`` is a mapping (YAML dict)."""
    if not isinstance(value, Mapping):
        raise ConfigError(f'expected a mapping, got {type(value).__name__}', source, key)
    return value


def vector(value: Any, n: int, source: str | None, key: str,
           finite: bool = True) -> tuple[float, ...]:
    """A list of ``n`` real numbers."""
    if not isinstance(value, (list, tuple)) or len(value) != n:
        raise ConfigError(f'expected a list of {n} numbers, got {value!r}', source, key)
    out = []
    for v in value:
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            raise ConfigError(f'expected numbers, got {v!r}', source, key)
        if finite and not math.isfinite(v):
            raise ConfigError(f'value {v!r} is not finite', source, key)
        out.append(float(v))
    return tuple(out)


def matrix(value: Any, rows: int, cols: int, source: str | None, key: str) -> tuple[
        tuple[float, ...], ...]:
    """A ``rows`` x ``cols`` nested list of real numbers."""
    if not isinstance(value, (list, tuple)) or len(value) != rows:
        raise ConfigError(f'expected a {rows}x{cols} matrix (list of {rows} rows)', source, key)
    return tuple(vector(r, cols, source, f'{key}[{i}]') for i, r in enumerate(value))


def _check_type(tp: Any, value: Any, source: str | None, key: str) -> Any:
    origin = typing.get_origin(tp)
    args = typing.get_args(tp)
    if origin in (typing.Union, types.UnionType):
        if value is None and type(None) in args:
            return None
        options = [a for a in args if a is not type(None)]
        if len(options) == 1:  # X | None: X's own error (it names the inner key)
            return _check_type(options[0], value, source, key)
        for a in options:
            try:
                return _check_type(a, value, source, key)
            except ConfigError:
                continue
        raise ConfigError(f'invalid value {value!r}', source, key)
    if origin is typing.Literal:
        if value not in args:
            raise ConfigError(f'must be one of {list(args)}, got {value!r}', source, key)
        return value
    if origin is tuple:
        if not isinstance(value, (list, tuple)):
            raise ConfigError(f'expected a list, got {value!r}', source, key)
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(_check_type(args[0], v, source, f'{key}[{i}]')
                         for i, v in enumerate(value))
        if len(args) != len(value):
            raise ConfigError(f'expected a list of {len(args)} values, got {value!r}', source,
                              key)
        return tuple(_check_type(a, v, source, f'{key}[{i}]')
                     for i, (a, v) in enumerate(zip(args, value)))
    if isinstance(tp, type) and dataclasses.is_dataclass(tp):
        return from_mapping(tp, value, source, prefix=key)
    if tp is bool:
        if not isinstance(value, bool):
            raise ConfigError(f'expected true or false, got {value!r}', source, key)
        return value
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f'expected an integer, got {value!r}', source, key)
        return value
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(f'expected a number, got {value!r}', source, key)
        if not math.isfinite(value):
            raise ConfigError(f'value {value!r} is not finite', source, key)
        return float(value)
    if tp is str:
        if not isinstance(value, str):
            raise ConfigError(f'expected a string, got {value!r}', source, key)
        return value
    return value


def _check_range(field: dataclasses.Field[Any], value: Any, source: str | None,
                 key: str) -> None:
    lo = field.metadata.get('min')
    hi = field.metadata.get('max')
    if value is None or isinstance(value, (tuple, str, bool)):
        return
    if lo is not None and value < lo:
        raise ConfigError(f'{value!r} is below the minimum {lo}', source, key)
    if hi is not None and value > hi:
        raise ConfigError(f'{value!r} is above the maximum {hi}', source, key)


def from_mapping(cls: type[T], data: Any, source: str | None = None, prefix: str = '') -> T:
    """Build the frozen dataclass ``cls`` from a mapping, strictly.

    Unknown keys, missing required keys, wrong types and values outside the field's
    ``metadata['min'|'max']`` raise :class:`ConfigError` naming ``source`` and the key.
    """
    data = require_mapping({} if data is None else data, source, prefix or None)
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls)}  # type: ignore[arg-type]
    for k in data:
        if k not in fields:
            known = ', '.join(sorted(fields))
            name = str(k) if str(k).isprintable() else repr(k)  # keep the error one line
            raise ConfigError(f'unknown key (known keys: {known})', source,
                              f'{prefix}.{name}' if prefix else name)
    kwargs: dict[str, Any] = {}
    for name, f in fields.items():
        key = f'{prefix}.{name}' if prefix else name
        if name in data:
            value = _check_type(hints[name], data[name], source, key)
            _check_range(f, value, source, key)
            kwargs[name] = value
        elif f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING:
            raise ConfigError('missing required key', source, key)
    return cls(**kwargs)


def load_config(cls: type[T], path: str | os.PathLike[str]) -> T:
    """Load ``cls`` from a YAML file (see :func:`from_mapping`)."""
    return from_mapping(cls, load_yaml(path), str(path))


def to_mapping(obj: Any) -> dict[str, Any]:
    """The inverse of :func:`from_mapping` (tuples become lists) for writing YAML."""
    def conv(v: Any) -> Any:
        if dataclasses.is_dataclass(v):
            return {f.name: conv(getattr(v, f.name)) for f in dataclasses.fields(v)}
        if isinstance(v, (tuple, list)):
            return [conv(x) for x in v]
        return v
    return conv(obj)


def share_dir() -> Path:
    """Directory holding ``config/`` (source tree, or the ament share dir when installed)."""
    here = Path(__file__).resolve().parents[2]
    if (here / 'config').is_dir():
        return here
    try:  # an installed ament package
        from ament_index_python.packages import get_package_share_directory
        return Path(get_package_share_directory('imu_calib_ros'))
    except Exception:  # noqa: BLE001 - no ament index: fall back to the source tree
        return here


def resolve_config_file(name_or_path: str, kind: str) -> Path:
    """Resolve ``name_or_path`` to a file: an existing path, or a shipped one by name.

    ``kind`` is the sub-folder of ``config/`` (``'fixtures'``, ``'plans'``, ``'imus'``);
    ``'nav_grade'`` finds ``config/imus/nav_grade.yaml``.
    """
    p = Path(name_or_path)
    if p.is_file():
        return p
    shipped = share_dir() / 'config' / kind / f'{name_or_path}.yaml'
    if shipped.is_file():
        return shipped
    avail = sorted(q.stem for q in (share_dir() / 'config' / kind).glob('*.yaml'))
    raise ConfigError(f'no such file, and no shipped {kind} of that name '
                      f'(shipped: {", ".join(avail) or "none"})', source=name_or_path)
