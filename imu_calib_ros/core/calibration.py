"""The calibration result and its file (CONTRACT section 4): atomic write, validated read.

Layout::

    imu_calibration:
      format_version: 1
      frame_id: imu_link
      gyroscope:     {bias, scale_misalignment, scale_asymmetry, g_sensitivity}
      accelerometer: {bias, scale_misalignment, scale_asymmetry, quadratic, size_effect}
      sigma:         {gyroscope: {...}, accelerometer: {...}}   # same keys and shapes
      fixed: [gyroscope.scale_asymmetry, ...]                  # not estimated
      <any other key>: ...                                     # extra (mounting, noise, ...)

Floats are written with ``repr`` precision, so save -> load is bit-exact. The simulator's
``truth.yaml`` uses the same layout with ``sigma`` zero and extra keys ``mounting``,
``noise`` and ``provenance``.
"""
from __future__ import annotations

import math
import os
import tempfile
import dataclasses
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from .config import load_yaml, require_mapping
from .errors import ConfigError
from .sensor_model import PARAMETER_KEYS, SensorErrors

#: The only file format version this code reads and writes.
FORMAT_VERSION = 1
#: Keys of ``imu_calibration`` with a meaning fixed by CONTRACT 4 (the rest is ``extra``).
RESERVED_KEYS = ('format_version', 'frame_id', 'gyroscope', 'accelerometer', 'sigma', 'fixed')


@dataclass(frozen=True, eq=False)
class CalibrationResult:
    """A calibration: error estimates, their one-sigma uncertainties and bookkeeping.

    Parameters
    ----------
    errors : SensorErrors
        The estimated (or, for truth files, true) sensor errors.
    sigma : SensorErrors
        One-sigma uncertainty of each value (same layout; non-negative).
    frame_id : str
        The IMU frame the calibration belongs to (``header.frame_id``).
    fixed : tuple of str
        Dotted keys (e.g. ``'gyroscope.scale_asymmetry'``) that were not estimated.
    extra : dict
        Further top-level keys of ``imu_calibration`` (mounting, noise, provenance, ...),
        plain YAML data; round-tripped as they are.
    """

    errors: SensorErrors
    sigma: SensorErrors
    frame_id: str
    fixed: tuple[str, ...] = ()
    extra: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        object.__setattr__(self, 'fixed', tuple(self.fixed))
        object.__setattr__(self, 'extra', dict(self.extra))
        if not isinstance(self.frame_id, str):
            raise ValueError(f'frame_id must be a string, got {self.frame_id!r}')
        for k in self.fixed:
            if k not in PARAMETER_KEYS:
                raise ValueError(f'unknown key {k!r} in fixed '
                                 f'(known: {", ".join(PARAMETER_KEYS)})')
        if len(set(self.fixed)) != len(self.fixed):
            raise ValueError(f'duplicate keys in fixed: {list(self.fixed)}')
        if np.any(self.sigma.as_vector() < 0):
            raise ValueError('sigma must be non-negative')
        for k in self.extra:
            if not isinstance(k, str) or k in RESERVED_KEYS:
                raise ValueError(f'extra key {k!r} is reserved or not a string')

    @classmethod
    def exact(cls, errors: SensorErrors, frame_id: str = 'imu_link',
              extra: dict[str, Any] | None = None) -> 'CalibrationResult':
        """A result known exactly (sigma 0): the simulator's truth."""
        return cls(errors, SensorErrors.zeros(), frame_id, (), extra or {})

    # ---------------------------------------------------------------------------- mapping
    def to_dict(self) -> dict[str, Any]:
        """The CONTRACT 4 mapping (plain Python types; extra values converted from numpy)."""
        body: dict[str, Any] = {'format_version': FORMAT_VERSION, 'frame_id': self.frame_id}
        body.update(self.errors.to_dict())
        body['sigma'] = self.sigma.to_dict()
        body['fixed'] = list(self.fixed)
        for k, v in self.extra.items():
            body[k] = _plain(v)
        return {'imu_calibration': body}

    @classmethod
    def from_dict(cls, data: Any, source: str | None = None) -> 'CalibrationResult':
        """Validate a CONTRACT 4 mapping.

        Raises
        ------
        ConfigError
            Naming ``source`` and the key: missing ``imu_calibration`` or other top-level
            keys, wrong ``format_version``, bad ``frame_id``, missing/unknown/misshapen
            error keys, NaN or inf anywhere, asymmetric Kg, non-zero size-effect diagonal,
            negative sigma, unknown or duplicate ``fixed`` entries.
        """
        top = require_mapping(data, source, None)
        for k in top:
            if k != 'imu_calibration':
                raise ConfigError('unknown top-level key (expected only imu_calibration)',
                                  source, str(k))
        if 'imu_calibration' not in top:
            raise ConfigError('missing required key', source, 'imu_calibration')
        p = 'imu_calibration'
        d = require_mapping(top[p], source, p)
        if 'format_version' not in d:
            raise ConfigError('missing required key', source, f'{p}.format_version')
        ver = d['format_version']
        if isinstance(ver, bool) or ver != FORMAT_VERSION:
            raise ConfigError(f'unsupported format_version {ver!r} (this version reads '
                              f'{FORMAT_VERSION})', source, f'{p}.format_version')
        if 'frame_id' not in d:
            raise ConfigError('missing required key', source, f'{p}.frame_id')
        frame_id = d['frame_id']
        if not isinstance(frame_id, str) or not frame_id:
            raise ConfigError(f'expected a non-empty string, got {frame_id!r}', source,
                              f'{p}.frame_id')
        errors = SensorErrors.from_dict(
            {k: d[k] for k in ('gyroscope', 'accelerometer') if k in d}, source, p)
        if 'sigma' not in d:
            raise ConfigError('missing required key', source, f'{p}.sigma')
        sigma = SensorErrors.from_dict(d['sigma'], source, f'{p}.sigma', nonnegative=True)
        fixed_raw = d.get('fixed', [])
        if fixed_raw is None:
            fixed_raw = []
        if not isinstance(fixed_raw, list):
            raise ConfigError(f'expected a list of keys, got {fixed_raw!r}', source,
                              f'{p}.fixed')
        for i, k in enumerate(fixed_raw):
            if k not in PARAMETER_KEYS:
                raise ConfigError(f'unknown key {k!r} (known: {", ".join(PARAMETER_KEYS)})',
                                  source, f'{p}.fixed[{i}]')
            if k in fixed_raw[:i]:
                raise ConfigError(f'duplicate key {k!r}', source, f'{p}.fixed[{i}]')
        extra = {}
        for k, v in d.items():
            if k in RESERVED_KEYS:
                continue
            if not isinstance(k, str):
                raise ConfigError('keys must be strings', source, f'{p}.{k}')
            _check_finite(v, source, f'{p}.{k}')
            extra[k] = v
        return cls(errors, sigma, frame_id, tuple(fixed_raw), extra)

    # ------------------------------------------------------------------------------- files
    def save(self, path: str | os.PathLike[str]) -> None:
        """Write the CONTRACT 4 file atomically.

        A temporary file in the same directory is written, flushed and fsync'ed, then
        renamed over ``path`` (``os.replace``), so readers see the old file or the new
        one, never a partial one. NaN or inf anywhere (incl. ``extra``) is refused with a
        :class:`ConfigError` naming the key, and nothing is written.
        """
        target = Path(path)
        data = self.to_dict()
        _check_finite(data, str(target), '')
        text = ('# IMU calibration (imu_calib_ros, CONTRACT section 4). SI units; '
                'sigma = one standard deviation.\n')
        # libyaml's emitter when PyYAML has it: the same text (the representer is Python's),
        # in half the time of the pure-Python one on a full covariance (0.1 s of a replay)
        text += yaml.dump(data, Dumper=getattr(yaml, 'CSafeDumper', yaml.SafeDumper),
                          sort_keys=False, default_flow_style=None, width=99,
                          allow_unicode=True)
        directory = target.parent
        if not directory.is_dir():
            raise ConfigError(f'directory {str(directory)!r} does not exist', str(target))
        try:
            fd, tmp = tempfile.mkstemp(prefix=f'.{target.name}.', suffix='.tmp',
                                       dir=directory)
        except OSError as exc:
            raise ConfigError(f'cannot write ({exc.strerror})', str(target)) from None
        try:
            with os.fdopen(fd, 'w', encoding='utf-8') as fh:
                fh.write(text)
                fh.flush()
                os.fsync(fh.fileno())
            os.chmod(tmp, 0o644)
            os.replace(tmp, target)
        except BaseException as exc:
            try:
                os.unlink(tmp)
            except OSError:
                pass
            if isinstance(exc, OSError):
                raise ConfigError(f'cannot write ({exc.strerror})', str(target)) from None
            raise
        _fsync_dir(directory)

    @classmethod
    def load(cls, path: str | os.PathLike[str]) -> 'CalibrationResult':
        """Read and validate a CONTRACT 4 file (:class:`ConfigError` naming file and key)."""
        return cls.from_dict(load_yaml(path), str(path))

    def tracked_truth(self) -> SensorErrors:
        """For a simulator truth file: the errors an estimator that tracks the total bias
        should end at, i.e. the biases replaced by ``extra.bias_at_end`` (turn-on value plus
        the simulated in-run drift at the last sample) when the file has it."""
        at_end = self.extra.get('bias_at_end') or {}
        repl = {f: np.asarray(at_end[k], float) for f, k in
                (('gyro_bias_rad_s', 'gyro_rad_s'), ('accel_bias_m_s2', 'accel_m_s2'))
                if k in at_end}
        return dataclasses.replace(self.errors, **repl) if repl else self.errors


def _fsync_dir(directory: Path) -> None:
    """Make the rename durable (POSIX); a no-op where directories cannot be opened."""
    try:
        fd = os.open(directory, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def _plain(v: Any) -> Any:
    """numpy arrays/scalars and tuples -> plain Python lists, floats, ints (YAML-safe)."""
    if isinstance(v, np.ndarray):
        return v.tolist()
    if isinstance(v, np.generic):
        return v.item()
    if isinstance(v, dict):
        return {k: _plain(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [_plain(x) for x in v]
    return v


def _check_finite(v: Any, source: str | None, key: str) -> None:
    """ConfigError at the first NaN or inf inside nested dicts/lists."""
    if isinstance(v, dict):
        for k, x in v.items():
            _check_finite(x, source, f'{key}.{k}' if key else str(k))
    elif isinstance(v, (list, tuple)):
        for i, x in enumerate(v):
            _check_finite(x, source, f'{key}[{i}]')
    elif isinstance(v, float) and not math.isfinite(v):
        raise ConfigError(f'value {v!r} is not finite', source, key)
