"""The earth at a fixed site: WGS-84 normal gravity, earth rate, the local-level ENU frame.

The ENU frame of a fixed site is earth-fixed, so relative to inertial space it turns with
the earth rate ``omega_ie``; in ENU coordinates ``omega_ie_enu = Omega (0, cos lat, sin lat)``.
Gravity (``g_enu = (0, 0, -g)``) is the normal gravity of the WGS-84 ellipsoid, which
already contains the centrifugal acceleration of the earth's rotation, or a measured value.

References
----------
NIMA TR8350.2, "Department of Defense World Geodetic System 1984", 3rd ed. (2000):
eq. 4-1 (Somigliana's closed formula), eq. 4-3 (normal gravity above the ellipsoid,
second-order Taylor series in the height), Table 3.1-3.3 (constants).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .config import require_mapping
from .errors import ConfigError

FloatArray = NDArray[np.float64]

#: Earth rotation rate relative to inertial space [rad/s] (WGS-84, TR8350.2 Table 3.1).
EARTH_RATE_RAD_S = 7.2921151467e-5
#: WGS-84 semi-major axis a [m].
WGS84_A_M = 6378137.0
#: WGS-84 flattening f.
WGS84_F = 1.0 / 298.257223563
#: Normal gravity at the equator gamma_e [m/s^2] (TR8350.2 Table 3.3).
WGS84_GAMMA_E_M_S2 = 9.7803253359
#: Somigliana's constant k = (b gamma_p) / (a gamma_e) - 1 (TR8350.2 Table 3.3).
WGS84_K_SOMIGLIANA = 0.00193185265241
#: First eccentricity squared e^2 (TR8350.2 Table 3.3).
WGS84_E2 = 6.69437999013e-3
#: m = omega^2 a^2 b / GM (TR8350.2 Table 3.3).
WGS84_M = 0.00344978650684

#: Plausible range of local gravity for a fixture file [m/s^2].
GRAVITY_RANGE_M_S2 = (9.7, 9.9)
#: Plausible range of the site's ellipsoidal height [m] (Dead Sea shore .. high mountains).
HEIGHT_RANGE_M = (-1000.0, 10000.0)


def normal_gravity_m_s2(latitude_rad: ArrayLike, height_m: ArrayLike = 0.0) -> Any:
    """WGS-84 normal gravity magnitude at a geodetic latitude and ellipsoidal height.

    ``g_0 = gamma_e (1 + k sin^2 lat) / sqrt(1 - e^2 sin^2 lat)`` (Somigliana,
    TR8350.2 eq. 4-1), then the second-order free-air correction (TR8350.2 eq. 4-3)::

        g_h = g_0 [1 - 2/a (1 + f + m - 2 f sin^2 lat) h + 3 h^2 / a^2]

    Parameters
    ----------
    latitude_rad : array_like
        Geodetic latitude [rad].
    height_m : array_like
        Height above the ellipsoid [m].

    Returns
    -------
    float or ndarray
        Normal gravity [m/s^2] (includes the centrifugal term of the earth's rotation).
    """
    s2 = np.sin(np.asarray(latitude_rad, dtype=float)) ** 2
    h = np.asarray(height_m, dtype=float)
    g0 = WGS84_GAMMA_E_M_S2 * (1.0 + WGS84_K_SOMIGLIANA * s2) / np.sqrt(1.0 - WGS84_E2 * s2)
    a = WGS84_A_M
    g = g0 * (1.0 - 2.0 / a * (1.0 + WGS84_F + WGS84_M - 2.0 * WGS84_F * s2) * h
              + 3.0 * h * h / (a * a))
    return float(g) if np.ndim(g) == 0 else g


@dataclass(frozen=True)
class Site:
    """A fixed site on the earth (CONTRACT section 2, ``site:`` block).

    Parameters
    ----------
    latitude_deg : float
        Geodetic latitude [deg], in [-90, 90].
    height_m : float
        Ellipsoidal height [m].
    gravity_m_s2 : float or None
        Measured local gravity magnitude [m/s^2]; ``None`` -> WGS-84 normal gravity.
    """

    latitude_deg: float
    height_m: float
    gravity_m_s2: float | None = None

    def __post_init__(self) -> None:
        if not (math.isfinite(self.latitude_deg) and -90.0 <= self.latitude_deg <= 90.0):
            raise ValueError(f'latitude_deg {self.latitude_deg!r} outside [-90, 90]')
        if not math.isfinite(self.height_m):
            raise ValueError(f'height_m {self.height_m!r} is not finite')
        g = self.gravity_m_s2
        if g is not None and not (math.isfinite(g) and
                                  GRAVITY_RANGE_M_S2[0] <= g <= GRAVITY_RANGE_M_S2[1]):
            raise ValueError(f'gravity_m_s2 {g!r} outside {list(GRAVITY_RANGE_M_S2)}')

    @property
    def latitude_rad(self) -> float:
        """Geodetic latitude [rad]."""
        return math.radians(self.latitude_deg)

    @property
    def normal_gravity(self) -> float:
        """WGS-84 normal gravity at this site [m/s^2] (whatever ``gravity_m_s2`` says)."""
        return float(normal_gravity_m_s2(self.latitude_rad, self.height_m))

    @property
    def gravity(self) -> float:
        """Gravity magnitude used everywhere [m/s^2]: the measured value if given, else normal."""
        return float(self.gravity_m_s2) if self.gravity_m_s2 is not None else self.normal_gravity

    @property
    def g_enu(self) -> FloatArray:
        """Gravity vector in ENU [m/s^2]: ``(0, 0, -g)``."""
        return np.array([0.0, 0.0, -self.gravity])

    @property
    def omega_ie_enu(self) -> FloatArray:
        """Earth rate relative to inertial space, ENU [rad/s]: ``Omega (0, cos lat, sin lat)``."""
        lat = self.latitude_rad
        return EARTH_RATE_RAD_S * np.array([0.0, math.cos(lat), math.sin(lat)])

    def to_dict(self) -> dict[str, Any]:
        """The fixture file's ``site:`` block."""
        d: dict[str, Any] = {'latitude_deg': float(self.latitude_deg),
                             'height_m': float(self.height_m)}
        if self.gravity_m_s2 is not None:
            d['gravity_m_s2'] = float(self.gravity_m_s2)
        return d

    @classmethod
    def from_dict(cls, data: Any, source: str | None = None, key: str = 'site') -> 'Site':
        """Build from a fixture file's ``site:`` block, strictly.

        Raises
        ------
        ConfigError
            Unknown or missing keys, non-numbers, latitude outside [-90, 90], height
            outside :data:`HEIGHT_RANGE_M`, gravity outside :data:`GRAVITY_RANGE_M_S2`;
            the message names ``source`` and the key (e.g. ``site.latitude_deg``).
        """
        d = require_mapping(data, source, key)
        known = ('latitude_deg', 'height_m', 'gravity_m_s2')
        for k in d:
            if k not in known:
                raise ConfigError(f'unknown key (known keys: {", ".join(known)})', source,
                                  f'{key}.{k}')
        vals: dict[str, float | None] = {}
        for k in known:
            if k not in d or (k == 'gravity_m_s2' and d[k] is None):
                if k == 'gravity_m_s2':
                    vals[k] = None
                    continue
                raise ConfigError('missing required key', source, f'{key}.{k}')
            v = d[k]
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise ConfigError(f'expected a finite number, got {v!r}', source, f'{key}.{k}')
            vals[k] = float(v)
        lat, h, g = vals['latitude_deg'], vals['height_m'], vals['gravity_m_s2']
        assert lat is not None and h is not None
        if not -90.0 <= lat <= 90.0:
            raise ConfigError(f'{lat!r} is outside [-90, 90] degrees', source,
                              f'{key}.latitude_deg')
        if not HEIGHT_RANGE_M[0] <= h <= HEIGHT_RANGE_M[1]:
            raise ConfigError(f'{h!r} m is outside {list(HEIGHT_RANGE_M)} m', source,
                              f'{key}.height_m')
        if g is not None and not GRAVITY_RANGE_M_S2[0] <= g <= GRAVITY_RANGE_M_S2[1]:
            raise ConfigError(f'{g!r} m/s^2 is outside {list(GRAVITY_RANGE_M_S2)} m/s^2 '
                              '(local gravity on the earth)', source, f'{key}.gravity_m_s2')
        return cls(lat, h, g)
