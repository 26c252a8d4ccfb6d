"""Fixtures from a URDF: any kinematic chain (a robot arm included) as the turntable (issue 15).

``fixture_from_urdf(urdf, base_link, imu_link)`` walks the URDF's joints from ``base_link``
down to ``imu_link`` and returns a :class:`~imu_calib_ros.core.fixture.Fixture`: every
revolute, continuous and prismatic joint on the way becomes a fixture joint (its ``<origin>``,
``<axis>`` and ``<limit>``), fixed joints are folded into the next moving joint's origin, and
what is left below the last moving joint is the IMU's nominal mounting (``imu.rpy``/``xyz``
of CONTRACT 2). The URDF is parsed with yourdfpy (meshes are never loaded; the scene graph is
not built). Floating and planar joints and mimic joints on the path are refused.

The URDF has no place for the site (latitude, height, gravity) nor for the base frame's
attitude in ENU (REP-103 ``base_link``: x forward, z up; its heading on the earth is not in
the robot description). Both come from an ``<imu_calib_site>`` element under ``<robot>``
(ignored by other URDF tools)::

    <imu_calib_site latitude_deg="55.70" height_m="200.0" gravity_m_s2="9.8155"
                    base_rpy_deg="0 0 90"/>

(``gravity_m_s2`` and ``base_rpy_deg`` optional; ``base_rpy_deg`` is ``R_enu_base`` as
roll, pitch, yaw, default level with x east), or from the caller (``--site-latitude-deg`` etc.
on the command line, node parameters), which take precedence.
"""
from __future__ import annotations

import dataclasses
import io
import math
import os
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .earth import Site
from .errors import ConfigError
from .fixture import Fixture, Joint
from .rotation import matrix_to_rpy, rpy_to_matrix

FloatArray = NDArray[np.float64]
SITE_ELEMENT = 'imu_calib_site'


@dataclass(frozen=True)
class UrdfOptions:
    """What a URDF fixture needs besides the file: the chain's ends and optional overrides
    of the ``<imu_calib_site>`` element (``None``: from the file)."""

    base_link: str = ''
    imu_link: str = ''
    latitude_deg: float | None = None
    height_m: float | None = None
    gravity_m_s2: float | None = None
    base_rpy_deg: tuple[float, float, float] | None = None


def is_urdf(name_or_path: str) -> bool:
    """True for a ``.urdf`` file name or URDF XML text."""
    s = str(name_or_path).lstrip()
    return s.startswith('<') or s.lower().endswith('.urdf')


def _xml_text(urdf: str | os.PathLike[str]) -> tuple[str, str]:
    """(XML text, source name for messages)."""
    s = str(urdf)
    if s.lstrip().startswith('<'):
        return s, '<robot_description>'
    try:
        with open(s, encoding='utf-8') as fh:
            return fh.read(), s
    except FileNotFoundError:
        raise ConfigError('file not found', source=s) from None
    except OSError as exc:
        raise ConfigError(f'cannot read file ({exc.strerror})', source=s) from None


def _site(root: ET.Element, opts: UrdfOptions, source: str) -> tuple[Site, FloatArray]:
    el = root.find(SITE_ELEMENT)
    attrs: dict[str, str] = {} if el is None else dict(el.attrib)

    def num(key: str, override: float | None) -> float | None:
        if override is not None:
            return float(override)
        if key not in attrs:
            return None
        try:
            v = float(attrs[key])
        except ValueError:
            raise ConfigError(f'expected a number, got {attrs[key]!r}', source,
                              f'{SITE_ELEMENT}.{key}') from None
        if not math.isfinite(v):
            raise ConfigError('not finite', source, f'{SITE_ELEMENT}.{key}')
        return v

    lat = num('latitude_deg', opts.latitude_deg)
    height = num('height_m', opts.height_m)
    if lat is None or height is None:
        raise ConfigError(f'a URDF fixture needs the site: add <{SITE_ELEMENT} latitude_deg="..." '
                          'height_m="..."/> under <robot>, or give --site-latitude-deg and '
                          '--site-height-m (node: site_latitude_deg, site_height_m)', source,
                          SITE_ELEMENT)
    d: dict[str, Any] = {'latitude_deg': lat, 'height_m': height}
    g = num('gravity_m_s2', opts.gravity_m_s2)
    if g is not None:
        d['gravity_m_s2'] = g
    site = Site.from_dict(d, source, SITE_ELEMENT)
    if opts.base_rpy_deg is not None:
        rpy = np.asarray(opts.base_rpy_deg, dtype=float)
    elif 'base_rpy_deg' in attrs:
        try:
            rpy = np.array([float(x) for x in attrs['base_rpy_deg'].split()])
        except ValueError:
            rpy = np.zeros(0)
        if rpy.shape != (3,) or not np.all(np.isfinite(rpy)):
            raise ConfigError(f'expected three numbers, got {attrs["base_rpy_deg"]!r}', source,
                              f'{SITE_ELEMENT}.base_rpy_deg')
    else:
        rpy = np.zeros(3)
    return site, rpy


def fixture_from_urdf(urdf: str | os.PathLike[str], opts: UrdfOptions) -> Fixture:
    """The fixture of the chain from ``opts.base_link`` to ``opts.imu_link`` (module docstring).

    Parameters
    ----------
    urdf : path or str
        A ``.urdf`` file, or the URDF XML itself (``robot_description``).
    opts : UrdfOptions

    Raises
    ------
    ConfigError
        Unreadable or malformed URDF; an unknown link; ``imu_link`` not below ``base_link``;
        a floating, planar or mimic joint on the path; no moving joint; no site.
    """
    text, source = _xml_text(urdf)
    try:
        root = ET.fromstring(text)
    except ET.ParseError as exc:
        raise ConfigError(f'malformed URDF: {exc}', source) from None
    if root.tag != 'robot':
        raise ConfigError(f'not a URDF: the root element is <{root.tag}>, not <robot>', source)
    import logging

    import yourdfpy  # imported here: it pulls in trimesh (~0.5 s), only URDF users pay
    logging.getLogger('yourdfpy').setLevel(logging.ERROR)
    try:
        model = yourdfpy.URDF.load(io.BytesIO(text.encode('utf-8')), build_scene_graph=False,
                                   load_meshes=False, build_collision_scene_graph=False,
                                   load_collision_meshes=False)
    except Exception as exc:  # yourdfpy raises assorted exceptions on bad input
        raise ConfigError(f'cannot parse the URDF ({type(exc).__name__}: {exc})', source) \
            from None
    site, base_rpy_deg = _site(root, opts, source)
    links = {lk.name for lk in model.robot.links}
    # without names, the conventional ones if the URDF has them (REP-105 base_link, imu_link)
    opts = dataclasses.replace(
        opts, base_link=opts.base_link or ('base_link' if 'base_link' in links else ''),
        imu_link=opts.imu_link or ('imu_link' if 'imu_link' in links else ''))
    for key, name in (('base_link', opts.base_link), ('imu_link', opts.imu_link)):
        if not name:
            raise ConfigError(f'a URDF fixture needs --{key.replace("_", "-")} (node: '
                              f'{key}); links: {", ".join(sorted(links))}', source, key)
        if name not in links:
            raise ConfigError(f'no link {name!r} (links: {", ".join(sorted(links))})', source,
                              key)
    parent_joint = {j.child: j for j in model.robot.joints}
    path = []
    link = opts.imu_link
    while link != opts.base_link:
        j = parent_joint.get(link)
        if j is None:
            raise ConfigError(f'link {opts.imu_link!r} is not below {opts.base_link!r} in the '
                              'kinematic tree', source, 'imu_link')
        path.append(j)
        link = j.parent
    path.reverse()
    T = np.eye(4)
    T[:3, :3] = rpy_to_matrix(np.radians(base_rpy_deg))
    joints: list[Joint] = []
    for j in path:
        origin = np.eye(4) if j.origin is None else np.asarray(j.origin, dtype=float)
        T = T @ origin
        if j.type == 'fixed':
            continue
        where = f'joint {j.name!r}'
        if j.type not in ('revolute', 'continuous', 'prismatic'):
            raise ConfigError(f'{j.type} joints cannot be part of a fixture chain', source,
                              where)
        if j.mimic is not None:
            raise ConfigError('mimic joints are not supported in a fixture chain', source,
                              where)
        axis = np.array([1.0, 0.0, 0.0]) if j.axis is None else np.asarray(j.axis, float)
        norm = float(np.linalg.norm(axis))
        if not math.isfinite(norm) or norm < 1e-9:
            raise ConfigError('zero or non-finite axis', source, f'{where}.axis')
        lim: dict[str, float] = {}
        if j.limit is not None:
            for k in ('lower', 'upper', 'velocity', 'effort'):
                v = getattr(j.limit, k)
                if v is not None and not (j.type == 'continuous' and k in ('lower', 'upper')):
                    lim[k] = float(v)
        try:
            joints.append(Joint(j.name, axis / norm, j.type, T[:3, 3].copy(),
                                T[:3, :3].copy(), **lim))
        except ValueError as exc:
            raise ConfigError(str(exc), source, where) from None
        T = np.eye(4)
    if not joints:
        raise ConfigError(f'no moving joint between {opts.base_link!r} and {opts.imu_link!r}',
                          source, 'imu_link')
    import warnings
    with warnings.catch_warnings():  # gimbal lock: any valid rpy of the matrix will do
        warnings.simplefilter('ignore', UserWarning)
        rpy = matrix_to_rpy(T[:3, :3])
    return Fixture(site, tuple(joints), rpy, T[:3, 3].copy(), source)
