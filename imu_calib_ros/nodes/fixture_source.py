"""Where a node's fixture comes from: a CONTRACT 2 YAML file, a URDF file, or the URDF on the
``robot_description`` topic (issue 15).

The owner of the node parameters that choose and shape a fixture (``fixture`` aside, whose
doc and default differ per node): the URDF chain's ends ``base_link`` and ``imu_link`` and
the site overrides of :class:`~imu_calib_ros.core.urdf_fixture.UrdfOptions`
(``site_latitude_deg``, ``site_height_m``, ``site_gravity_m_s2``, ``site_base_rpy_deg``), and
``robot_description_timeout_s``. A node's config dataclass derives from
:class:`UrdfFixtureFields`, which declares them once, so ``--help`` and the
unknown-parameter refusal of :mod:`.common` cover them like every other parameter.

``fixture: robot_description`` (:data:`ROBOT_DESCRIPTION`) waits for one
``std_msgs/String`` on the relative topic ``robot_description`` with the QoS
robot_state_publisher publishes it with (reliable, transient local, depth 1: a late
subscriber gets the latest), up to ``robot_description_timeout_s``, and builds the fixture
from that XML with the same :func:`~imu_calib_ros.core.urdf_fixture.fixture_from_urdf` the
``.urdf`` files go through. The node logs one line saying what it built
(:func:`describe_fixture`), or refuses to start with one line saying why (a
:class:`~imu_calib_ros.core.errors.ConfigError`: exit status 2). The calibration node
keeps listening (:class:`RobotDescriptionWatcher`) and decides what a changed chain
(:func:`fixture_changes`) does to its run (docs/NODES.md, "Robot arms").
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Any

from ..core.errors import ConfigError

#: The ``fixture`` value that takes the URDF from the ``robot_description`` topic.
ROBOT_DESCRIPTION = 'robot_description'
#: The topic (relative, remappable) robot_state_publisher publishes the URDF on.
ROBOT_DESCRIPTION_TOPIC = 'robot_description'

_URDF_FIELDS: dict[str, tuple[Any, dict[str, Any]]] = {
    'base_link': ('', {
        'doc': 'with a URDF fixture (.urdf file or robot_description): the link fixed to the '
               'earth, where the chain starts; empty = base_link if the URDF has it'}),
    'imu_link': ('', {
        'doc': 'with a URDF fixture: the link the IMU frame is, where the chain ends; empty = '
               'imu_link if the URDF has it'}),
    'site_latitude_deg': (None, {
        'doc': "with a URDF fixture: site latitude [deg] (overrides the URDF's "
               '<imu_calib_site latitude_deg>)', 'min': -90.0, 'max': 90.0}),
    'site_height_m': (None, {
        'doc': "with a URDF fixture: site ellipsoidal height [m] (overrides <imu_calib_site "
               'height_m>)'}),
    'site_gravity_m_s2': (None, {
        'doc': 'with a URDF fixture: measured local gravity [m/s^2] (overrides <imu_calib_site '
               'gravity_m_s2>; unset there too = WGS-84 normal gravity)'}),
    'site_base_rpy_deg': (None, {
        'doc': 'with a URDF fixture: attitude of base_link in ENU, roll pitch yaw [deg] '
               "(overrides <imu_calib_site base_rpy_deg>; unset there too = level, x east)"}),
    'robot_description_timeout_s': (30.0, {
        'doc': 'with fixture robot_description: longest wait for the URDF on the '
               'robot_description topic [s wall] before refusing to start', 'min': 0.1}),
}

#: The parameters :func:`urdf_field` declares, in the order nodes list them.
URDF_PARAMETERS = tuple(_URDF_FIELDS)


def urdf_field(name: str) -> Any:
    """The dataclass ``field`` of URDF parameter ``name`` (one of :data:`URDF_PARAMETERS`),
    as :class:`UrdfFixtureFields` declares it."""
    default, meta = _URDF_FIELDS[name]
    return field(default=default, metadata=dict(meta))


@dataclass(frozen=True)
class UrdfFixtureFields:
    """The :data:`URDF_PARAMETERS` of a node whose ``fixture`` may be a URDF (issue 15), once:
    the calibration, modulation, turntable_sim and turntable_driver configs derive from it."""

    base_link: str = urdf_field('base_link')
    imu_link: str = urdf_field('imu_link')
    site_latitude_deg: float | None = urdf_field('site_latitude_deg')
    site_height_m: float | None = urdf_field('site_height_m')
    site_gravity_m_s2: float | None = urdf_field('site_gravity_m_s2')
    site_base_rpy_deg: tuple[float, float, float] | None = urdf_field('site_base_rpy_deg')
    robot_description_timeout_s: float = urdf_field('robot_description_timeout_s')


def urdf_options(cfg: Any) -> Any:
    """The :class:`~imu_calib_ros.core.urdf_fixture.UrdfOptions` of a node config that
    declares the :data:`URDF_PARAMETERS`."""
    from ..core.urdf_fixture import UrdfOptions
    rpy = cfg.site_base_rpy_deg
    return UrdfOptions(cfg.base_link, cfg.imu_link, cfg.site_latitude_deg, cfg.site_height_m,
                       cfg.site_gravity_m_s2, None if rpy is None else tuple(rpy))


def _urdf_options_given(cfg: Any) -> list[str]:
    return [n for n in URDF_PARAMETERS if n != 'robot_description_timeout_s'
            and getattr(cfg, n) not in ('', None, ())]


def load_node_fixture(node: Any, cfg: Any) -> Any:
    """The :class:`~imu_calib_ros.core.fixture.Fixture` of ``cfg.fixture``: a shipped name or
    a file (YAML or ``.urdf``), or :data:`ROBOT_DESCRIPTION` (wait for the topic, see the
    module docstring). Logs one line saying what was built. See
    :func:`load_node_fixture_and_urdf`."""
    return load_node_fixture_and_urdf(node, cfg)[0]


def load_node_fixture_and_urdf(node: Any, cfg: Any) -> tuple[Any, str | None]:
    """:func:`load_node_fixture` and, with ``fixture: robot_description``, the URDF text it was
    built from (else None), for :class:`RobotDescriptionWatcher`.

    Raises
    ------
    ConfigError
        Unreadable or unsuitable fixture (names the file or ``<robot_description>`` and the
        reason: unknown link, no moving joint, no site, ...); no URDF on the topic within
        ``robot_description_timeout_s``; URDF parameters given with a YAML fixture.
    """
    from ..core.fixture import load_fixture
    from ..core.urdf_fixture import is_urdf
    source = cfg.fixture
    text = None
    if source == ROBOT_DESCRIPTION:
        source = text = wait_for_robot_description(node, cfg.robot_description_timeout_s)
    fixture = load_fixture(source, urdf_options(cfg))
    if not is_urdf(str(fixture.source or '')):
        given = _urdf_options_given(cfg)
        if given:
            verb = 'applies' if len(given) == 1 else 'apply'
            raise ConfigError(f'{", ".join(given)} {verb} to a URDF fixture only (.urdf file or'
                              f' robot_description); {cfg.fixture} is a CONTRACT 2 YAML '
                              'fixture', 'ROS parameters')
    node.get_logger().info(describe_fixture(fixture, cfg))
    return fixture, text


def describe_fixture(fixture: Any, cfg: Any) -> str:
    """One line: where the fixture came from, its joints (type), and the IMU's place."""
    from ..core.urdf_fixture import is_urdf
    kinds = ', '.join(f'{j.name} ({j.kind})' for j in fixture.joints)
    xyz = ', '.join(f'{v + 0.0:.4g}' for v in fixture.imu_xyz_m.round(6))
    if is_urdf(str(fixture.source or '')):
        opts = urdf_options(cfg)
        ends = (f'{opts.base_link or "base_link"} -> {opts.imu_link or "imu_link"}')
        return (f'fixture from URDF {fixture.source}: chain {ends}, {fixture.n_joints} '
                f'joints [{kinds}]; IMU link {opts.imu_link or "imu_link"} at [{xyz}] m from '
                f'the last joint {fixture.joints[-1].name}; site latitude '
                f'{fixture.site.latitude_deg:g} deg')
    return (f'fixture {fixture.source}: {fixture.n_joints} joints [{kinds}]; IMU at [{xyz}] '
            'm from the axes\' common point')


def wait_for_robot_description(node: Any, timeout_s: float) -> str:
    """The URDF XML of the first message on ``robot_description`` (transient local,
    reliable), spinning ``node`` in a private executor for at most ``timeout_s`` wall
    seconds; the subscription is removed afterwards.

    Raises
    ------
    ConfigError
        Nothing within ``timeout_s``, or an empty message.
    """
    from rclpy.executors import SingleThreadedExecutor
    from std_msgs.msg import String

    from .common import latched_qos
    got: list[str] = []
    sub = node.create_subscription(String, ROBOT_DESCRIPTION_TOPIC,
                                   lambda msg: got.append(msg.data), latched_qos())
    topic = sub.topic_name
    node.get_logger().info(f'fixture: waiting up to {timeout_s:g} s for the URDF on {topic}')
    ex = SingleThreadedExecutor(context=node.context)
    ex.add_node(node)
    end = time.monotonic() + timeout_s
    try:
        while not got and node.context.ok():
            left = end - time.monotonic()
            if left <= 0.0:
                break
            ex.spin_once(timeout_sec=min(left, 0.1))
    finally:
        ex.remove_node(node)
        ex.shutdown()
        node.destroy_subscription(sub)
    if not got:
        raise ConfigError(f'no URDF on {topic} within {timeout_s:g} s (robot_state_publisher '
                          'publishes it, transient local; is it running, in this '
                          'ROS_DOMAIN_ID and namespace?)', 'fixture robot_description')
    if not got[-1].strip():
        raise ConfigError(f'{topic} holds an empty string, not a URDF',
                          'fixture robot_description')
    return got[-1]



def _vec(v: Any, scale: float = 1.0) -> str:
    import numpy as np
    a = np.zeros(3) if v is None else np.asarray(v, float) * scale
    return '[' + ', '.join(f'{x + 0.0:.6g}' for x in a.round(9)) + ']'


def _num(x: float | None) -> str:
    return 'none' if x is None else f'{x:.6g}'


def fixture_changes(old: Any, new: Any) -> list[str]:
    """What differs between two fixtures' kinematics, one short text per difference (empty:
    the same chain; a URDF edit of meshes, colours or links off the chain changes nothing):
    the joints (names, order), per joint its type, axis, origin [mm, deg] and limits, the IMU
    on the last link, and the site."""
    import numpy as np

    from ..core.rotation import matrix_to_rpy
    out: list[str] = []
    s0, s1 = old.site, new.site
    for attr, unit in (('latitude_deg', 'deg'), ('height_m', 'm'), ('gravity_m_s2', 'm/s^2')):
        a, b = getattr(s0, attr), getattr(s1, attr)
        if a != b:
            out.append(f'site {attr.rsplit("_", 1)[0] if attr != "gravity_m_s2" else "gravity"}'
                       f' {a} -> {b} {unit}')
    if tuple(old.joint_names) != tuple(new.joint_names):
        out.append(f'joints [{", ".join(old.joint_names)}] -> [{", ".join(new.joint_names)}]')
    else:
        for j0, j1 in zip(old.joints, new.joints):
            if j0.kind != j1.kind:
                out.append(f'{j0.name} type {j0.kind} -> {j1.kind}')
            if not np.allclose(j0.axis, j1.axis, rtol=0, atol=1e-12):
                out.append(f'{j0.name} axis {_vec(j0.axis)} -> {_vec(j1.axis)}')
            x0 = np.zeros(3) if j0.origin_xyz_m is None else j0.origin_xyz_m
            x1 = np.zeros(3) if j1.origin_xyz_m is None else j1.origin_xyz_m
            if not np.allclose(x0, x1, rtol=0, atol=1e-12):
                out.append(f'{j0.name} origin xyz {_vec(x0, 1e3)} -> {_vec(x1, 1e3)} mm')
            R0 = np.eye(3) if j0.origin_R is None else j0.origin_R
            R1 = np.eye(3) if j1.origin_R is None else j1.origin_R
            if not np.allclose(R0, R1, rtol=0, atol=1e-12):
                out.append(f'{j0.name} origin rpy {_vec(np.degrees(matrix_to_rpy(R0)))} -> '
                           f'{_vec(np.degrees(matrix_to_rpy(R1)))} deg')
            rot = j0.kind != 'prismatic'
            for lim, unit in (('lower', 'deg' if rot else 'm'), ('upper', 'deg' if rot else 'm'),
                              ('velocity', 'deg/s' if rot else 'm/s')):
                a, b = getattr(j0, lim), getattr(j1, lim)
                if a != b:
                    a, b = (None if x is None else math.degrees(x) if rot else x for x in (a, b))
                    out.append(f'{j0.name} {lim} limit {_num(a)} -> {_num(b)} {unit}')
    if not np.allclose(old.imu_xyz_m, new.imu_xyz_m, rtol=0, atol=1e-12):
        out.append(f'IMU position {_vec(old.imu_xyz_m, 1e3)} -> {_vec(new.imu_xyz_m, 1e3)} mm')
    if not np.allclose(old.R_joint_imu, new.R_joint_imu, rtol=0, atol=1e-12):
        out.append(f'IMU rpy {_vec(np.degrees(old.imu_rpy_rad))} -> '
                   f'{_vec(np.degrees(new.imu_rpy_rad))} deg')
    return out


class RobotDescriptionWatcher:
    """Later messages on ``robot_description`` (robot_state_publisher republishes the URDF
    when it changes), after the node started with the first one.

    Each message whose text differs from the last one seen is built into a fixture with the
    node's URDF options and handed to ``on_change(fixture or None, changes, error)``:
    ``changes`` (:func:`fixture_changes`) against ``current()`` (the fixture the node runs
    on), ``error`` the one-line reason when the URDF cannot be built (``fixture`` None). A
    message with the same text (the latched one the subscription gets at once, or a republish
    of the same model) is ignored. Callbacks run in the node's executor.
    """

    def __init__(self, node: Any, cfg: Any, text: str, current: Any, on_change: Any) -> None:
        from std_msgs.msg import String

        from .common import latched_qos
        self._cfg, self._text = cfg, text
        self._current, self._on_change = current, on_change
        self.updates = 0  # messages with a different text
        self.sub = node.create_subscription(String, ROBOT_DESCRIPTION_TOPIC, self._on_msg,
                                            latched_qos())

    def _on_msg(self, msg: Any) -> None:
        if msg.data == self._text:
            return
        self._text = msg.data
        self.updates += 1
        from ..core.errors import ImuCalibError
        from ..core.fixture import load_fixture
        if not msg.data.strip():
            self._on_change(None, [], 'an empty string, not a URDF')
            return
        try:
            fixture = load_fixture(msg.data, urdf_options(self._cfg))
        except Exception as exc:  # whatever the model: never end a running calibration
            self._on_change(None, [], str(exc) if isinstance(exc, ImuCalibError)
                            else f'{type(exc).__name__}: {exc}')
            return
        self._on_change(fixture, fixture_changes(self._current(), fixture), '')
