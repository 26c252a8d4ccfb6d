"""Shell helpers shared by the nodes: parameters from config dataclasses, QoS, start/stop.

Nothing here computes physics: the per-sample compensation both IMU nodes use is the core's
:class:`imu_calib_ros.core.stream_compensation.StreamCompensation`, and the input threads
built on rclpy internals are in :mod:`imu_calib_ros.nodes.input_thread`.
"""
from __future__ import annotations

import dataclasses
import difflib
import faulthandler
import math
import os
import signal
import sys
import textwrap
import threading
import types
import typing
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Mapping, TypeVar

import numpy as np
import rclpy
from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rclpy.exceptions import InvalidParameterTypeException, InvalidParameterValueException
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.event_handler import PublisherEventCallbacks
from rclpy.qos import (DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy)

from msg_adapters.convert import imu_cdr, stamp_ns_from_time, time_msg_from_ns  # noqa: F401

from ..core.config import from_mapping, load_yaml
from ..core.errors import ConfigError, ImuCalibError

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


def quiet_publisher(node: Node, msg_type: Any, topic: str, qos: QoSProfile | int) -> Any:
    """A publisher without rclpy's default QoS-event handlers.

    Each default handler is a waitable the Python executor re-adds to its wait set on every
    spin (measured: 33 estimate publishers made the wait-set rebuild the node's largest
    cost at 1 kHz). For secondary outputs (estimates, diagnostics) only.
    """
    return node.create_publisher(msg_type, topic, qos, event_callbacks=PublisherEventCallbacks(
        use_default_callbacks=False))


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
    An integer given for a float field (``-p rate:=4``) is taken as that float.

    Raises
    ------
    ConfigError
        A parameter has a wrong type or value (names the parameter); a parameter was given
        (``-p``, ``--params-file``) that the node does not have (names the nearest one); a
        field marked ``metadata['required']`` is empty (no silent default).
    """
    overrides = parameter_overrides(node)
    config = from_mapping(cls, _declare_mapping(node, cls, prefix, overrides=overrides),
                          'ROS parameters', prefix=prefix.rstrip('.'))
    check_unknown_parameters(node, overrides)
    _check_required(cls, config, prefix)
    return config


def parameter_overrides(node: Node) -> dict[str, Parameter]:
    """The parameter values given to ``node`` from outside (``-p``, ``--params-file``,
    ``parameter_overrides=``), by name, declared or not.

    rclpy (Jazzy) keeps them in ``Node._parameter_overrides`` and has no public getter; the
    one place this package reads that attribute.
    """
    return dict(getattr(node, '_parameter_overrides', {}) or {})


def check_unknown_parameters(node: Node, overrides: Mapping[str, Parameter]) -> None:
    """Refuse parameters the node has not declared (a misspelt ``-p fixtur:=...`` would
    otherwise be ignored and the default used), naming the nearest declared name.

    ``qos_overrides.*`` are rclpy's own (declared when a publisher or subscription with
    QoS overriding options is created) and left to it.
    """
    unknown = [k for k in overrides
               if not node.has_parameter(k) and not k.startswith('qos_overrides.')]
    if not unknown:
        return
    names = sorted(node._parameters)  # noqa: SLF001 - rclpy has no list of declared names
    hints = []
    for k in unknown:
        near = difflib.get_close_matches(k, names, n=1, cutoff=0.0)
        hints.append(f'{k} (did you mean {near[0]}?)' if near else k)
    what = 'unknown parameter' if len(unknown) == 1 else 'unknown parameters'
    raise ConfigError(f'{what} {", ".join(hints)}; --help lists them', 'ROS parameters')


def _check_required(cls: type[Any], config: Any, prefix: str) -> None:
    """Fields with ``metadata['required']`` (True, or the reason) must be set (non-empty):
    no silent default."""
    for f in dataclasses.fields(cls):
        if f.metadata.get('required') and getattr(config, f.name) in ('', None, ()):
            name = f'{prefix}{f.name}'
            why = f.metadata['required']
            why = f' ({why})' if isinstance(why, str) else ''
            raise ConfigError(f'{name} is required: set -p {name}:=VALUE, the '
                              f'{f.metadata.get("doc", name)}; there is no default{why}',
                              'ROS parameters')


def _field_default(f: dataclasses.Field[Any], defaults: Any) -> Any:
    """The default of field ``f``: from the parent's default instance if given (a nested
    field's ``default_factory`` may differ from ``cls()``), else the field's own."""
    return getattr(defaults, f.name) if defaults is not None else _default(f)


def _declare_mapping(node: Node, cls: type[Any], prefix: str, defaults: Any = None,
                     overrides: Mapping[str, Parameter] | None = None) -> dict[str, Any]:
    """Declare ``cls``'s fields; the values as a nested mapping for ``from_mapping``."""
    hints = typing.get_type_hints(cls)
    overrides = parameter_overrides(node) if overrides is None else overrides
    out: dict[str, Any] = {}
    for f in dataclasses.fields(cls):
        name = f'{prefix}{f.name}'
        tp = hints[f.name]
        base, optional = _strip_optional(tp)
        default = _field_default(f, defaults)
        if isinstance(base, type) and dataclasses.is_dataclass(base):
            out[f.name] = _declare_mapping(node, base, f'{name}.', default, overrides)
            continue
        desc = _descriptor(f, tp, name)
        if isinstance(default, tuple):
            default = list(default)
        initial = _param_type(tp) if default in (None, []) else default
        coerced = _int_as_float(overrides.get(name), _param_type(tp))
        try:
            if coerced is not None:
                value = node.declare_parameter(name, coerced, desc, ignore_override=True).value
            else:
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


def _int_as_float(given: Parameter | None, wanted: Parameter.Type) -> Any:
    """An integer (array) given for a double (array) parameter, as floats; else None.

    ``-p rate:=4`` arrives as INTEGER; a statically typed DOUBLE parameter would refuse it
    ("Wrong parameter type"), though 4 is a perfectly good rate.
    """
    if given is None:
        return None
    if wanted == Parameter.Type.DOUBLE and given.type_ == Parameter.Type.INTEGER:
        return float(given.value)
    if wanted == Parameter.Type.DOUBLE_ARRAY and given.type_ == Parameter.Type.INTEGER_ARRAY:
        return [float(v) for v in given.value]
    return None


# ---------------------------------------------------------------------------------------------
# --help: usage generated from the node's interface and its config dataclass


@dataclass(frozen=True)
class Endpoint:
    """A topic or service of a node, for its ``--help``."""

    name: str
    type: str
    doc: str = ''


@dataclass(frozen=True)
class NodeInterface:
    """What a node does, subscribes, publishes and serves, and its config dataclass: the
    ``--help`` text (:func:`node_usage`). The parameters are listed from ``config`` with the
    descriptors :func:`declare_config` declares, so they cannot drift from the node."""

    name: str
    summary: str
    config: type[Any]
    subscribes: tuple[Endpoint, ...] = ()
    publishes: tuple[Endpoint, ...] = ()
    services: tuple[Endpoint, ...] = ()
    params_file: str = ''  # e.g. config/calibration_node.yaml
    notes: str = ''


#: Where every node's --help sends the reader.
DOCS_NOTE = ('Details: docs/NODES.md. "CONTRACT n" is section n of the external contract, '
             'docs/CONTRACT.md (installed as share/imu_calib_ros/docs/CONTRACT.md).')

_TYPE_NAMES = {Parameter.Type.BOOL: 'bool', Parameter.Type.INTEGER: 'integer',
               Parameter.Type.DOUBLE: 'double', Parameter.Type.STRING: 'string',
               Parameter.Type.BOOL_ARRAY: 'bool[]', Parameter.Type.INTEGER_ARRAY: 'integer[]',
               Parameter.Type.DOUBLE_ARRAY: 'double[]', Parameter.Type.STRING_ARRAY: 'string[]'}


def parameter_help(cls: type[Any], prefix: str = '', defaults: Any = None) -> list[str]:
    """One entry per parameter :func:`declare_config` declares for ``cls``: name, type,
    default (or ``required``), the descriptor's constraints, then its description."""
    hints = typing.get_type_hints(cls)
    lines: list[str] = []
    for f in dataclasses.fields(cls):
        name = f'{prefix}{f.name}'
        tp = hints[f.name]
        base, _ = _strip_optional(tp)
        default = _field_default(f, defaults)
        if isinstance(base, type) and dataclasses.is_dataclass(base):
            lines += parameter_help(base, f'{name}.', default)
            continue
        desc = _descriptor(f, tp, name)
        shown = 'required' if f.metadata.get('required') else \
            'unset by default' if default is None else f'default {_ros_text(default)}'
        head = f'{name} ({_TYPE_NAMES[Parameter.Type(desc.type)]}, {shown}'
        head += f'; {desc.additional_constraints})' if desc.additional_constraints else ')'
        text = desc.description
        if isinstance(f.metadata.get('required'), str):
            text += f'; no default: {f.metadata["required"]}'
        body = textwrap.fill(text, 99, initial_indent=' ' * 8, subsequent_indent=' ' * 8)
        lines += [f'  {head}', body] if text else [f'  {head}']
    return lines


def _ros_text(value: Any) -> str:
    """A default as it is written after ``-p NAME:=`` (YAML: true, 1.5, '', [1.0, 2.0])."""
    if value is None or value == '':
        return "''"
    if isinstance(value, bool):
        return 'true' if value else 'false'
    if isinstance(value, (tuple, list)):
        return '[' + ', '.join(_ros_text(v) for v in value) + ']'
    return repr(value) if isinstance(value, float) else str(value)


def node_usage(interface: NodeInterface, prog: str | None = None) -> str:
    """The ``--help`` text of a node (see :class:`NodeInterface`)."""
    prog = prog or interface.name
    out = [f'usage: {prog} [-h] [--ros-args -p NAME:=VALUE ... -r FROM:=TO ... '
           '--params-file FILE]', '', textwrap.fill(interface.summary, 99), '']
    for title, items in (('subscribes', interface.subscribes),
                         ('publishes', interface.publishes),
                         ('services', interface.services)):
        if not items:
            continue
        out.append(f'{title}:')
        for e in items:
            out.append(f'  {e.name} ({e.type})')
            if e.doc:
                out.append(textwrap.fill(e.doc, 99, initial_indent=' ' * 8,
                                         subsequent_indent=' ' * 8))
        out.append('')
    src = f'; defaults in {interface.params_file}' if interface.params_file else ''
    out.append(textwrap.fill(f'parameters (-p NAME:=VALUE or --params-file FILE{src}; an '
                             'unknown name is refused):', 99))
    out += parameter_help(interface.config)
    out += ['  use_sim_time (bool, default false)',
            '        ROS built-in: follow /clock instead of the system clock']
    out.append('')
    if interface.notes:
        out += [textwrap.fill(interface.notes, 99), '']
    out.append(textwrap.fill(DOCS_NOTE, 99))
    return '\n'.join(out)


def user_arguments(argv: list[str]) -> list[str]:
    """``argv[1:]`` without the ROS arguments (``--ros-args ... [--]``, possibly several)."""
    out: list[str] = []
    in_ros = False
    for a in argv[1:]:
        if a == '--ros-args':
            in_ros = True
        elif in_ros and a == '--':
            in_ros = False
        elif not in_ros:
            out.append(a)
    return out


def help_requested(argv: list[str]) -> bool:
    """``-h`` or ``--help`` among the user arguments (not inside ``--ros-args``)."""
    return any(a in ('-h', '--help') for a in user_arguments(argv))


def print_help_if_asked(interface: NodeInterface, argv: list[str] | None) -> bool:
    """Print the node's usage and return True when ``argv`` asks for help (nothing of ROS
    is started: no ``rclpy.init``, no node)."""
    argv = list(argv) if argv is not None else sys.argv
    if not help_requested(argv):
        return False
    prog = os.path.basename(argv[0]) if argv and argv[0] and not argv[0].endswith('.py') \
        else interface.name
    print(node_usage(interface, prog))
    return True


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


def log_at_exit(node: Node, message: str) -> None:
    """Log ``message`` (INFO) while shutting down: through the node's logger while the
    context is up, else on stderr (after SIGINT/SIGTERM the context is gone, and the logger's
    /rosout publisher would add "Failed to publish log message to rosout")."""
    if node.context.ok():
        node.get_logger().info(message)
    else:
        print(f'{node.get_name()}: {message}', file=sys.stderr, flush=True)



# the longest a node's executor waits before it looks at its context again (add_shutdown_wake)
SPIN_WAKE_S = 1.0


def add_shutdown_wake(node: Node, period_s: float = SPIN_WAKE_S) -> Any:
    """A steady-clock timer on ``node`` that does nothing but end every executor wait within
    ``period_s``: the executor checks its context after each wait, so the spin ends at most
    ``period_s`` after a shutdown.

    rclpy's signal thread triggers the executors' SIGINT guard condition *before* it shuts the
    contexts down. An executor woken in between sees its context still valid and waits again,
    with no timeout; if nothing else wakes it (``use_sim_time`` with the ``/clock`` publisher
    gone stops every ROS-time timer), the node ignores SIGINT until it is killed. Seen once in
    CI: the calibration node in test_nodes_selfcheck.py, its stack in ``rcl_wait``, killed
    after 120 s. A timer rather than ``spin_once(timeout_sec)``, which builds a timeout timer
    for every wait (once per callback batch at IMU rates).
    """
    from rclpy.clock import Clock, ClockType
    return node.create_timer(period_s, lambda: None, clock=Clock(clock_type=ClockType.STEADY_TIME))


def run_node(make_node: Callable[[], Node], args: list[str] | None = None,
             interface: NodeInterface | None = None) -> int:
    """The Jazzy start/stop form around ``make_node()``; returns the exit status.

    ``-h``/``--help`` (with ``interface``) prints the usage and returns 0 before anything of
    ROS starts.

    Spins a SingleThreadedExecutor (rclpy's experimental C++ EventsExecutor delivered no
    callbacks at all in this Jazzy build; the MultiThreadedExecutor costs more per callback).
    rclpy's default signal handlers turn SIGINT and SIGTERM into a context shutdown; after
    the spin ends, ``node.on_shutdown()`` (if the node has one) runs before the node is
    destroyed (e.g. to save the latest estimate). A :class:`ImuCalibError` while building
    the node (bad parameter, file) is printed as one line on stderr and gives exit status 2.
    """
    # SIGINT: rclpy's handler shuts the context down (the spin then ends) and chains to the
    # Python handler; Python's default raises KeyboardInterrupt wherever the main thread is,
    # e.g. half-way through building an executor Task ("Exception ignored in
    # Future.__del__ ... 'Task' object has no attribute '_exception'" at shutdown). A no-op
    # Python handler leaves the shutdown to rclpy alone.
    if interface is not None and print_help_if_asked(interface, args):
        return 0
    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGINT, lambda signum, frame: None)
        # `kill -USR1 <pid>`: every thread's Python stack on stderr (a node that does not
        # stop can be asked where it is; the tests do so before they kill one)
        faulthandler.register(signal.SIGUSR1, all_threads=True)
    rclpy.init(args=args if args is not None else sys.argv)
    node: Node | None = None
    status = 0
    try:
        node = make_node()
        from rclpy.executors import SingleThreadedExecutor
        ex = SingleThreadedExecutor()
        ex.add_node(node)
        add_shutdown_wake(node)
        try:
            ex.spin()
        finally:
            ex.shutdown()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except ImuCalibError as exc:
        name = node.get_name() if node is not None else (
            os.path.splitext(os.path.basename(sys.argv[0]))[0] or 'node')  # console script
        print(f'{name}: error: {exc}', file=sys.stderr, flush=True)
        status = 2
    except SystemExit as exc:  # a node asked to stop (e.g. plan finished)
        status = int(exc.code or 0)
    except Exception:  # noqa: BLE001 - see below
        # a callback that was publishing when a signal shut the context down raises
        # RCLError ("publisher's context is invalid"): that is the requested stop
        if rclpy.ok():
            raise
    finally:
        if node is not None:
            hook = getattr(node, 'on_shutdown', None)
            if hook is not None:
                try:
                    hook()
                except Exception as exc:  # noqa: BLE001 - report, still destroy the node
                    print(f'{node.get_name()}: error at shutdown: {exc}', file=sys.stderr,
                          flush=True)
                    status = status or 1
            node.destroy_node()
        rclpy.try_shutdown()
    return status


# ---------------------------------------------------------------------------------------------
# Message values


def diag9(var3: Any) -> tuple[float, ...]:
    """Row-major 3x3 diagonal covariance (the message layout) from three variances."""
    return (var3[0], 0.0, 0.0, 0.0, var3[1], 0.0, 0.0, 0.0, var3[2])


def publish_corrected(pub: Any, c: Any) -> bool:
    """Publish one sample an :class:`~imu_calib_ros.core.imu_stream.ImuStream` step accepted,
    compensated, with its diagonal covariances (serialised ``sensor_msgs/Imu``); False when
    its compensation was not finite (the stream counted it; nothing goes out)."""
    if c.values is None:
        return False
    omega, f, gvar, avar = c.values
    pub.publish(imu_cdr(c.stamp_ns, c.frame_id, omega, f, diag9(gvar), diag9(avar)))
    return True


def finite(*arrays: Any) -> bool:
    """True when every value is finite (nothing NaN goes into a filter or out of a publisher)."""
    return all(bool(np.all(np.isfinite(a))) for a in arrays)


def finite3(*vectors: tuple[float, ...]) -> bool:
    """:func:`finite` for a few 3-tuples of floats, without numpy (the per-sample path)."""
    return all(math.isfinite(v[0] + v[1] + v[2]) for v in vectors)


def as_float(x: Any) -> float:
    """``float(x)``, NaN for None (for diagnostics values)."""
    return math.nan if x is None else float(x)
