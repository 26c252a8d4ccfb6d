"""Shell helpers shared by the nodes: parameters from config dataclasses, QoS, start/stop.

Nothing here computes physics except :class:`StreamCompensation`, which wraps the core's
:func:`imu_calib_ros.core.sensor_model.compensate` for one sample at a time so that the
compensator node and the calibration node use literally the same code.
"""
from __future__ import annotations

import dataclasses
import math
import sys
import types
import typing
from pathlib import Path
from typing import Any, Callable, Mapping, TypeVar

import numpy as np
import rclpy
from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rclpy.exceptions import InvalidParameterTypeException, InvalidParameterValueException
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import (DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy)

from ..core.config import from_mapping, load_yaml
from ..core.errors import ConfigError, ImuCalibError
from ..core.types import FloatArray, ImuSample
from ..msg_adapters.convert import stamp_ns_from_time, time_fields_from_ns  # noqa: F401

T = TypeVar('T')

# ---------------------------------------------------------------------------------------------
# QoS


def sensor_qos(depth: int = 5) -> QoSProfile:
    """Sensor-data QoS (best effort, volatile, keep last ``depth``), rclpy's sensor profile.

    rclpy's ``qos_profile_sensor_data`` has depth 5; at 1 kHz a deeper queue absorbs the
    scheduling jitter of a loaded machine without changing compatibility.
    """
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=depth,
                      reliability=ReliabilityPolicy.BEST_EFFORT,
                      durability=DurabilityPolicy.VOLATILE)


def latched_qos() -> QoSProfile:
    """Reliable, transient-local, depth 1: a late subscriber gets the latest value."""
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1,
                      reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.TRANSIENT_LOCAL)


def reliable_qos(depth: int = 10) -> QoSProfile:
    """Reliable, volatile, keep last ``depth``: for our publishers (a reliable writer serves
    both best-effort and reliable readers) and for commands such as trajectories."""
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=depth,
                      reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.VOLATILE)


# ---------------------------------------------------------------------------------------------
# Parameters declared from a frozen config dataclass (the same one the CLI and YAML use)


def _strip_optional(tp: Any) -> tuple[Any, bool]:
    origin = typing.get_origin(tp)
    if origin in (typing.Union, types.UnionType):
        args = [a for a in typing.get_args(tp) if a is not type(None)]
        if len(args) == 1:
            return args[0], True
    return tp, False


def _param_type(tp: Any) -> Parameter.Type:
    tp, _ = _strip_optional(tp)
    origin = typing.get_origin(tp)
    if origin is typing.Literal:
        first = typing.get_args(tp)[0]
        return _param_type(type(first))
    if origin is tuple:
        elem = typing.get_args(tp)[0]
        return {float: Parameter.Type.DOUBLE_ARRAY, int: Parameter.Type.INTEGER_ARRAY,
                str: Parameter.Type.STRING_ARRAY, bool: Parameter.Type.BOOL_ARRAY}[elem]
    return {bool: Parameter.Type.BOOL, int: Parameter.Type.INTEGER,
            float: Parameter.Type.DOUBLE, str: Parameter.Type.STRING}[tp]


def _descriptor(f: dataclasses.Field[Any], tp: Any, name: str) -> ParameterDescriptor:
    meta = f.metadata
    desc = ParameterDescriptor(name=name, type=_param_type(tp).value,
                               description=str(meta.get('doc', '')),
                               read_only=not meta.get('dynamic', False))
    base, optional = _strip_optional(tp)
    constraints = []
    if typing.get_origin(base) is typing.Literal:
        constraints.append(f'one of {list(typing.get_args(base))}')
    if 'choices' in meta:
        constraints.append(f'one of {list(meta["choices"])}')
    lo, hi = meta.get('min'), meta.get('max')
    if lo is not None or hi is not None:
        constraints.append(f'range [{lo if lo is not None else "-inf"}, '
                           f'{hi if hi is not None else "inf"}]')
        # ROS ranges need both ends; a one-sided bound is checked by from_mapping instead.
        if lo is not None and hi is not None and base is float:
            desc.floating_point_range = [FloatingPointRange(
                from_value=float(lo), to_value=float(hi), step=0.0)]
        elif lo is not None and hi is not None and base is int:
            desc.integer_range = [IntegerRange(from_value=int(lo), to_value=int(hi), step=0)]
    if optional:
        constraints.append('empty/unset = none')
    desc.additional_constraints = '; '.join(constraints)
    return desc


def _default(f: dataclasses.Field[Any]) -> Any:
    if f.default is not dataclasses.MISSING:
        return f.default
    if f.default_factory is not dataclasses.MISSING:
        return f.default_factory()
    return None


def declare_config(node: Node, cls: type[T], prefix: str = '') -> T:
    """Declare one ROS parameter per field of ``cls`` (recursing into nested dataclasses).

    Names are the dotted field paths (``estimator.gate_sigma``), descriptors carry the
    field's ``metadata['doc']`` and range, so ``ros2 param describe`` shows them. The
    values (defaults, ``--params-file`` YAML, ``-p`` overrides) are then validated by
    :func:`imu_calib_ros.core.config.from_mapping`, the same check the YAML files get.

    Raises
    ------
    ConfigError
        A parameter has a wrong type or value (names the parameter).
    """
    return from_mapping(cls, _declare_mapping(node, cls, prefix), 'ROS parameters',
                        prefix=prefix.rstrip('.'))


def _declare_mapping(node: Node, cls: type[Any], prefix: str) -> dict[str, Any]:
    hints = typing.get_type_hints(cls)
    out: dict[str, Any] = {}
    for f in dataclasses.fields(cls):
        name = f'{prefix}{f.name}'
        tp = hints[f.name]
        base, optional = _strip_optional(tp)
        if dataclasses.is_dataclass(base):
            out[f.name] = _declare_mapping(node, base, f'{name}.')
            continue
        default = _default(f)
        desc = _descriptor(f, tp, name)
        if isinstance(default, tuple):
            default = list(default)
        initial = _param_type(tp) if default in (None, []) else default
        try:
            value = node.declare_parameter(name, initial, desc).value
        except (InvalidParameterValueException, InvalidParameterTypeException) as exc:
            reason = str(exc).split('Reason: ')[-1]
            raise ConfigError(f'invalid value ({reason})', 'ROS parameters', name) from None
        if value is None or (optional and value in ('', [])):
            if optional or default is None:
                continue
        if isinstance(value, (list, tuple)) or hasattr(value, 'tolist'):
            value = list(value.tolist() if hasattr(value, 'tolist') else value)
        out[f.name] = value
    return out


def flatten_mapping(data: Mapping[str, Any], prefix: str = '') -> dict[str, Any]:
    """Nested mapping -> dotted keys (the form ROS parameter files take when loaded)."""
    out: dict[str, Any] = {}
    for k, v in data.items():
        if isinstance(v, Mapping):
            out.update(flatten_mapping(v, f'{prefix}{k}.'))
        else:
            out[f'{prefix}{k}'] = v
    return out


def load_params_file(path: str | Path, cls: type[T], node_name: str) -> T:
    """Validate a ROS ``--params-file`` YAML (``node_name`` or ``/**`` section) against ``cls``.

    The ``use_sim_time`` key (a ROS built-in) is ignored. Used by the tests that keep
    ``config/*.yaml`` in step with the dataclasses, and by nothing at run time (there rcl
    parses the file).
    """
    data = load_yaml(path)
    if not isinstance(data, Mapping):
        raise ConfigError('expected a mapping of node names', str(path))
    section = None
    for key in (node_name, f'/{node_name}', '/**', '**'):
        if key in data:
            section = data[key]
            break
    if not isinstance(section, Mapping) or 'ros__parameters' not in section:
        raise ConfigError(f'no "{node_name}: ros__parameters:" (or "/**") section', str(path))
    params = dict(section['ros__parameters'] or {})
    params.pop('use_sim_time', None)
    return from_mapping(cls, params, str(path))


# ---------------------------------------------------------------------------------------------
# Start / stop


def run_node(make_node: Callable[[], Node], args: list[str] | None = None,
             multithreaded: bool = False) -> int:
    """The Jazzy start/stop form around ``make_node()``; returns the exit status.

    A :class:`ImuCalibError` while building the node (bad parameter, file) is printed as one
    line on stderr and gives exit status 2.
    """
    rclpy.init(args=args if args is not None else sys.argv)
    node: Node | None = None
    status = 0
    try:
        node = make_node()
        if multithreaded:
            from rclpy.executors import MultiThreadedExecutor
            executor = MultiThreadedExecutor(num_threads=2)
            executor.add_node(node)
            executor.spin()
        else:
            rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except ImuCalibError as exc:
        print(f'{getattr(node, "get_name", lambda: "node")()}: error: {exc}', file=sys.stderr)
        status = 2
    except SystemExit as exc:  # a node asked to stop (e.g. plan finished)
        status = int(exc.code or 0)
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    return status


# ---------------------------------------------------------------------------------------------
# Stamps (TODO-move: a Time-message builder belongs in msg_adapters/convert.py)


def stamp_msg(stamp_ns: int) -> Any:
    """``builtin_interfaces/Time`` from integer nanoseconds."""
    from builtin_interfaces.msg import Time
    sec, nanosec = time_fields_from_ns(stamp_ns)
    return Time(sec=sec, nanosec=nanosec)


# ---------------------------------------------------------------------------------------------
# Streaming compensation (shared by the compensator and the calibration node)


class StreamCompensation:
    """Compensate one raw IMU sample at a time with a calibration; covariances for the message.

    The values are those of :func:`imu_calib_ros.core.sensor_model.compensate` called with
    ``(1, 3)`` arrays and ``omega_dot_imu`` from :func:`causal_rate_derivative` (the backward
    difference of mean rates, Kozlov & Kapralov eq. 1 needs the angular acceleration for the
    size effect; a causal difference keeps the output latency at zero samples).

    Covariances (diagonal, rad^2/s^2 and m^2/s^4): white noise of the mean over one interval,
    ``N^2 / dt`` (CONTRACT 1: values are interval means), plus the first-order propagation of
    the calibration's one-sigma values through the model of CONTRACT 3, treating the sigmas as
    independent.

    Parameters
    ----------
    result:
        The calibration (``errors`` and ``sigma``), a :class:`CalibrationResult`.
    gyro_noise_rad_s_rt_hz, accel_noise_m_s2_rt_hz:
        White-noise densities (ARW, VRW) of the sensor.
    nominal_period_s:
        Used for the noise variance before two samples have been seen, and as the gap
        threshold (1.5 periods, CONTRACT 1) for the rate derivative.
    """

    def __init__(self, result: Any, gyro_noise_rad_s_rt_hz: float = 0.0,
                 accel_noise_m_s2_rt_hz: float = 0.0, nominal_period_s: float = 0.005):
        from ..core import sensor_model
        self._compensate = sensor_model.compensate
        self._gyro_n2 = float(gyro_noise_rad_s_rt_hz) ** 2
        self._accel_n2 = float(accel_noise_m_s2_rt_hz) ** 2
        self.nominal_period_s = float(nominal_period_s)
        self._prev: tuple[int, FloatArray] | None = None
        self.update(result)

    def update(self, result: Any) -> None:
        """Use a new calibration from the next sample on (keeps the rate-derivative memory).

        One attribute assignment swaps everything, so a callback thread reading it
        concurrently sees either the old or the new calibration, never a mix.
        """
        s = result.sigma
        sq = [np.asarray(x, float) ** 2 for x in (
            s.gyro_bias_rad_s, s.gyro_scale_misalignment, s.gyro_scale_asymmetry,
            s.gyro_g_sensitivity_rad_s_per_m_s2, s.accel_bias_m_s2, s.accel_scale_misalignment,
            s.accel_scale_asymmetry, s.accel_quadratic_per_m_s2, s.size_effect_m)]
        self._cal = (result, *sq)

    @property
    def result(self) -> Any:
        """The calibration in use."""
        return self._cal[0]

    def reset(self) -> None:
        """Forget the previous sample (after a gap or a new calibration)."""
        self._prev = None

    def __call__(self, sample: ImuSample) -> tuple[FloatArray, FloatArray, FloatArray,
                                                   FloatArray]:
        """Compensated ``(omega (3,), f (3,), gyro_var (3,), accel_var (3,))`` of one sample."""
        omega, f, gvar, avar = self.batch([sample])
        return omega[0], f[0], gvar[0], avar[0]

    def batch(self, samples: list[ImuSample]) -> tuple[FloatArray, FloatArray, FloatArray,
                                                       FloatArray]:
        """Compensate consecutive samples with one core call: ``(omega, f, gyro_var,
        accel_var)``, each ``(N, 3)``; the rate-derivative memory carries across calls."""
        cal = self._cal
        n = len(samples)
        stamps = np.fromiter((s.stamp_ns for s in samples), np.int64, n)
        gyro = np.array([s.gyro_rad_s for s in samples], float).reshape(n, 3)
        accel = np.array([s.accel_m_s2 for s in samples], float).reshape(n, 3)
        if self._prev is not None:
            omega_dot = causal_rate_derivative(np.concatenate([[self._prev[0]], stamps]),
                                               np.vstack([self._prev[1], gyro]),
                                               self.nominal_period_s)[1:]
            prev_stamp = self._prev[0]
        else:
            omega_dot = causal_rate_derivative(stamps, gyro, self.nominal_period_s)
            prev_stamp = None
        self._prev = (int(stamps[-1]), gyro[-1].copy())
        dt_s = np.diff(np.concatenate([[prev_stamp if prev_stamp is not None else
                                        stamps[0] - int(self.nominal_period_s * 1e9)],
                                       stamps])) * 1e-9
        dt_s = np.where((dt_s > 0) & (dt_s <= 1.5 * self.nominal_period_s), dt_s,
                        self.nominal_period_s)
        # One core call per sample: the core's compensate converges on a batch-wide criterion
        # and its matmul is not row-independent, so only per-sample calls give the same bits
        # whatever the batching (the offline reference in test_nodes does the same).
        omega = np.empty_like(gyro)
        f = np.empty_like(accel)
        errors = cal[0].errors
        for k in range(n):
            omega[k:k + 1], f[k:k + 1] = self._compensate(
                errors, gyro[k:k + 1], accel[k:k + 1], omega_dot_imu_rad_s2=omega_dot[k:k + 1])
        gvar, avar = self._variances(cal, omega, f, omega_dot, dt_s)
        return omega, f, gvar, avar

    def _variances(self, cal: tuple[Any, ...], omega: FloatArray, f: FloatArray,
                   omega_dot: FloatArray, dt_s: Any) -> tuple[FloatArray, FloatArray]:
        """Diagonal variances of the compensated rate and specific force (see class doc).

        Vectorised: ``omega, f, omega_dot`` are ``(..., 3)``, ``dt_s`` broadcasts to ``(...)``.
        """
        _, g_b2, g_k2, g_a2, g_g2, a_b2, a_k2, a_a2, a_q2, a_r2 = cal
        dt = np.asarray(dt_s, float)[..., None]
        w2 = omega * omega
        f2 = f * f
        gvar = self._gyro_n2 / dt + g_b2 + w2 @ g_k2.T + g_a2 * w2 + f2 @ g_g2.T
        # d f_i / d r_ij = (skew(omega_dot) + skew(omega)^2)[i, j]  (CONTRACT 3 size effect)
        m = _skew_batch(omega_dot) + _skew_batch(omega) @ _skew_batch(omega)
        avar = (self._accel_n2 / dt + a_b2 + f2 @ a_k2.T + a_a2 * f2 + a_q2 * f2 * f2
                + np.sum(a_r2 * m * m, axis=-1))
        return gvar, avar


def causal_rate_derivative(stamps_ns: np.ndarray, gyro_rad_s: FloatArray,
                           nominal_period_s: float) -> FloatArray:
    """Backward difference of mean-over-interval rates, ``(N, 3)``, for the size effect.

    ``out[k] = (w_k - w_{k-1}) / (t_k - t_{k-1})``: consecutive interval means sit one
    period apart. Row 0, and any row after a gap longer than 1.5 nominal periods
    (CONTRACT 1) or a non-increasing stamp, is zero. Hand-written: numpy's ``gradient`` is
    central, not causal, and knows no gaps.
    """
    gyro = np.asarray(gyro_rad_s, float)
    out = np.zeros_like(gyro)
    if gyro.shape[0] < 2:
        return out
    dt_s = np.diff(np.asarray(stamps_ns, np.int64)) * 1e-9
    ok = (dt_s > 0.0) & (dt_s <= 1.5 * nominal_period_s)
    out[1:][ok] = (gyro[1:][ok] - gyro[:-1][ok]) / dt_s[ok, None]
    return out


def _skew_batch(v: FloatArray) -> FloatArray:
    from ..core.rotation import skew
    return skew(v)


def diag9(var3: FloatArray) -> FloatArray:
    """Row-major 3x3 diagonal covariance (the message layout) from three variances."""
    out = np.zeros(9)
    out[[0, 4, 8]] = var3
    return out


def finite(*arrays: FloatArray) -> bool:
    """True when every value is finite (nothing NaN goes into a filter or out of a publisher)."""
    return all(bool(np.all(np.isfinite(a))) for a in arrays)


def as_float(x: Any) -> float:
    """``float(x)``, NaN for None (for diagnostics values)."""
    return math.nan if x is None else float(x)


class CompensationWorker:
    """A thread that compensates queued raw samples and hands them to ``publish``.

    The subscription callback only queues (microseconds); the worker takes everything queued
    so far and compensates it with :meth:`StreamCompensation.batch` (per-sample core calls,
    vectorised covariances), so the executor never waits for the compensation.
    ``publish(samples, omega, f, gyro_var, accel_var)`` runs in this
    thread; rclpy publishers are thread-safe.
    """

    def __init__(self, compensation: StreamCompensation,
                 publish: Callable[..., None], max_batch: int = 200):
        import collections
        import threading
        self.compensation = compensation
        self._publish = publish
        self._max_batch = max_batch
        self._queue: 'collections.deque[ImuSample]' = collections.deque()
        self._wake = threading.Event()
        self._stop = False
        self.batches = 0
        self.samples = 0
        self._thread = threading.Thread(target=self._run, name='compensation', daemon=True)
        self._thread.start()

    def put(self, sample: ImuSample) -> None:
        """Queue one raw sample (called from the subscription callback)."""
        self._queue.append(sample)
        self._wake.set()

    def reset(self) -> None:
        """Drop queued samples and the rate-derivative memory."""
        self._queue.clear()
        self.compensation.reset()

    def stop(self) -> None:
        """Stop the thread (the queue is dropped)."""
        self._stop = True
        self._wake.set()
        self._thread.join(timeout=2.0)

    def _run(self) -> None:
        while not self._stop:
            self._wake.wait(0.1)
            self._wake.clear()
            while self._queue and not self._stop:
                n = min(len(self._queue), self._max_batch)
                items = [self._queue.popleft() for _ in range(n)]
                omega, f, gvar, avar = self.compensation.batch(items)
                self.batches += 1
                self.samples += n
                self._publish(items, omega, f, gvar, avar)
