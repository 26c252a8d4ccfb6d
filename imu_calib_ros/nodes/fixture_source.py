"""Where a node's fixture comes from: a CONTRACT 2 YAML file, a URDF file, or the URDF on the
``robot_description`` topic (issue 15).

The owner of the node parameters that choose and shape a fixture (``fixture`` aside, whose
doc and default differ per node): the URDF chain's ends ``base_link`` and ``imu_link`` and
the site overrides of :class:`~imu_calib_ros.core.urdf_fixture.UrdfOptions`
(``site_latitude_deg``, ``site_height_m``, ``site_gravity_m_s2``, ``site_base_rpy_deg``), and
``robot_description_timeout_s``. A node's config dataclass declares them with
:func:`urdf_field`, so ``--help`` and the unknown-parameter refusal of
:mod:`.common` cover them like every other parameter.

``fixture: robot_description`` (:data:`ROBOT_DESCRIPTION`) waits for one
``std_msgs/String`` on the relative topic ``robot_description`` with the QoS
robot_state_publisher publishes it with (reliable, transient local, depth 1: a late
subscriber gets the latest), up to ``robot_description_timeout_s``, and builds the fixture
from that XML with the same :func:`~imu_calib_ros.core.urdf_fixture.fixture_from_urdf` the
``.urdf`` files go through. The node logs one line saying what it built
(:func:`describe_fixture`), or refuses to start with one line saying why (a
:class:`~imu_calib_ros.core.errors.ConfigError`: exit status 2).
"""
from __future__ import annotations

import time
from dataclasses import field
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
    """The dataclass ``field`` of URDF parameter ``name`` (one of :data:`URDF_PARAMETERS`)
    for a node's config: ``base_link: str = urdf_field('base_link')``."""
    default, meta = _URDF_FIELDS[name]
    return field(default=default, metadata=dict(meta))


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
    module docstring). Logs one line saying what was built.

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
    if source == ROBOT_DESCRIPTION:
        source = wait_for_robot_description(node, cfg.robot_description_timeout_s)
    fixture = load_fixture(source, urdf_options(cfg))
    if not is_urdf(str(fixture.source or '')):
        given = _urdf_options_given(cfg)
        if given:
            verb = 'applies' if len(given) == 1 else 'apply'
            raise ConfigError(f'{", ".join(given)} {verb} to a URDF fixture only (.urdf file or'
                              f' robot_description); {cfg.fixture} is a CONTRACT 2 YAML '
                              'fixture', 'ROS parameters')
    node.get_logger().info(describe_fixture(fixture, cfg))
    return fixture


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

