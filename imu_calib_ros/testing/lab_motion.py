"""A lab's own schedules and tables: joint motion and fixtures that do not come from our plans.

The world (:mod:`.world_sim`) takes its joint motion from ``core.plans`` (quintic rest-to-rest
moves, SRT sequences mapped by our builder) and its fixtures from ``config/fixtures``: the
estimator was built beside both. A lab writes its own: a turntable controller moves with a
**trapezoidal rate profile** (constant angular acceleration, so q'' jumps at every corner), the
schedule is a list of joint poses and rate tests written in joint space, and the table stands
wherever the lab is (southern hemisphere, equator, high latitude, a measured gravity) with its
own axis order and IMU mounting. This module writes such schedules and fixtures from CONTRACT 2
alone; it imports nothing from ``core``.

- :class:`TrapezoidProfile`: piecewise-constant joint acceleration, the interface the world
  takes (``joint_names``, ``duration_s``, ``breakpoints_s``, ``evaluate``); every corner is a
  breakpoint, so the world's Gauss-Legendre integrals stay exact;
- :class:`Schedule`: ``dwell``, ``move_to`` (all joints start and stop together, trapezoid of
  the joint that moves furthest, at the lab's rate and acceleration limits), ``spin`` (a rate
  test: one joint turned whole revolutions at a constant rate);
- :func:`lab_schedule`: a multi-position + rate-test schedule for any fixture, drawn from a
  seed: poses at multiples of 90 deg (some at 45), each IMU axis stood up and down where the
  table can, dwells of 10-40 s, then rate tests of each joint in both directions;
- :data:`LAB_FIXTURES` and :func:`write_fixture`: tables other than the shipped ones.
"""
from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

FloatArray = NDArray[np.float64]

_DEG = math.pi / 180.0


@dataclass(frozen=True)
class TrapezoidProfile:
    """Joint motion with piecewise-constant acceleration: on piece k (from ``t0[k]``)
    ``q = q0 + qd0 u + qdd u^2 / 2``, ``u = t - t0[k]``."""

    joint_names: tuple[str, ...]
    t0: FloatArray  # (K,) piece starts, t0[0] = 0
    q0: FloatArray  # (K, n)
    qd0: FloatArray  # (K, n)
    qdd: FloatArray  # (K, n)
    end_s: float
    plan_name: str = 'lab'
    stills: tuple[tuple[float, float], ...] = ()

    @property
    def duration_s(self) -> float:
        """End time (the profile starts at 0)."""
        return self.end_s

    @property
    def breakpoints_s(self) -> FloatArray:
        """Every corner of the rate profile, 0 and the end."""
        return np.unique(np.append(self.t0, self.end_s))

    def evaluate(self, t_s: Any) -> tuple[FloatArray, FloatArray, FloatArray]:
        """q, q', q'' at ``t_s`` (N,), each (N, n); at rest at the nearest end outside."""
        t = np.clip(np.atleast_1d(np.asarray(t_s, dtype=float)), 0.0, self.end_s)
        k = np.clip(np.searchsorted(self.t0, t, side='right') - 1, 0, len(self.t0) - 1)
        u = (t - self.t0[k])[:, None]
        a = self.qdd[k]
        at_end = t >= self.end_s
        a = np.where(at_end[:, None], 0.0, a)
        return (self.q0[k] + self.qd0[k] * u + 0.5 * self.qdd[k] * u * u,
                self.qd0[k] + self.qdd[k] * u, a)

    def stationary_windows(self, min_duration_s: float = 0.0) -> list[tuple[float, float]]:
        """The dwells (t0, t1) at least ``min_duration_s`` long."""
        return [w for w in self.stills if w[1] - w[0] >= min_duration_s]


@dataclass
class Schedule:
    """Builds a :class:`TrapezoidProfile` step by step (module docstring)."""

    joint_names: tuple[str, ...]
    q: FloatArray
    rate_limit_rad_s: float
    accel_limit_rad_s2: float
    name: str = 'lab'
    _t: float = 0.0
    _pieces: list[tuple[float, FloatArray, FloatArray, FloatArray]] = field(default_factory=list)
    _stills: list[tuple[float, float]] = field(default_factory=list)

    def _piece(self, T: float, qdd: FloatArray, qd0: FloatArray) -> None:
        if T <= 0.0:
            return
        self._pieces.append((self._t, self.q.copy(), qd0.copy(), qdd.copy()))
        self.q = self.q + qd0 * T + 0.5 * qdd * T * T
        self._t += T

    def dwell(self, T: float) -> 'Schedule':
        """Hold still for ``T`` seconds."""
        z = np.zeros_like(self.q)
        self._stills.append((self._t, self._t + T))
        self._piece(T, z, z)
        return self

    def _trapezoid(self, d: FloatArray, v: float, a: float) -> None:
        """Rest-to-rest by ``d`` (n,): the joint moving furthest at limits v, a; the others
        scaled so that all start and stop together."""
        dmax = float(np.max(np.abs(d)))
        if dmax == 0.0:
            return
        if dmax <= v * v / a:  # triangular: never reaches the rate limit
            ta = math.sqrt(dmax / a)
            tc = 0.0
        else:
            ta = v / a
            tc = dmax / v - ta
        vpk = d / (ta + tc)  # each joint's peak rate (n,)
        z = np.zeros_like(d)
        self._piece(ta, vpk / ta, z)
        self._piece(tc, z, vpk)
        self._piece(ta, -vpk / ta, vpk)

    def move_to(self, q_target: Any) -> 'Schedule':
        """Trapezoidal move to the joint angles ``q_target`` [rad]."""
        self._trapezoid(np.asarray(q_target, dtype=float) - self.q, self.rate_limit_rad_s,
                        self.accel_limit_rad_s2)
        return self

    def spin(self, joint: int, turns: float, rate_rad_s: float) -> 'Schedule':
        """Turn one joint ``turns`` revolutions (sign = direction) at ``rate_rad_s``."""
        d = np.zeros_like(self.q)
        d[joint] = 2.0 * math.pi * turns
        self._trapezoid(d, abs(rate_rad_s), self.accel_limit_rad_s2)
        return self

    def build(self) -> TrapezoidProfile:
        """The profile of the steps so far."""
        t0 = np.array([p[0] for p in self._pieces])
        return TrapezoidProfile(self.joint_names, t0, np.array([p[1] for p in self._pieces]),
                                np.array([p[2] for p in self._pieces]),
                                np.array([p[3] for p in self._pieces]), self._t, self.name,
                                tuple(self._stills))


# ------------------------------------------------------------------------------ fixtures
#: tables a lab might have, CONTRACT 2 mappings (not the shipped ones): other axis orders and
#: mountings, and sites from the southern hemisphere to the Arctic
LAB_FIXTURES: dict[str, dict[str, Any]] = {
    # three-axis, outer axis north (horizontal), IMU mounted upside down and turned, Sydney
    'south_ynz': {
        'site': {'latitude_deg': -33.87, 'height_m': 40.0},
        'joints': [{'name': 'roll_axis', 'axis': [0.0, 1.0, 0.0]},
                   {'name': 'pitch_axis', 'axis': [0.0, 0.0, 1.0]},
                   {'name': 'yaw_axis', 'axis': [1.0, 0.0, 0.0]}],
        'imu': {'rpy_deg': [180.0, 0.0, 90.0], 'xyz_m': [0.0, 0.0, 0.0]}},
    # two-axis, horizontal outer axis east, inner vertical at zero, on the equator
    'equator_2axis': {
        'site': {'latitude_deg': 0.3, 'height_m': 2800.0},
        'joints': [{'name': 'tilt', 'axis': [1.0, 0.0, 0.0]},
                   {'name': 'azimuth', 'axis': [0.0, 0.0, 1.0]}],
        'imu': {'rpy_deg': [0.0, 90.0, 0.0], 'xyz_m': [0.0, 0.0, 0.0]}},
    # three-axis in the Arctic with a measured gravity and an IMU 4 cm off the axes' point
    'arctic_3axis': {
        'site': {'latitude_deg': 78.2, 'height_m': 10.0, 'gravity_m_s2': 9.8297},
        'joints': [{'name': 'azimuth', 'axis': [0.0, 0.0, 1.0]},
                   {'name': 'elevation', 'axis': [0.0, 1.0, 0.0]},
                   {'name': 'roll', 'axis': [1.0, 0.0, 0.0]}],
        'imu': {'rpy_deg': [0.0, 0.0, 37.0], 'xyz_m': [0.01, -0.03, 0.02]}},
    # two-axis with a vertical outer axis and a horizontal inner one, IMU turned 45 deg, Cape Town
    'south_2axis_vh': {
        'site': {'latitude_deg': -33.9, 'height_m': 15.0},
        'joints': [{'name': 'heading', 'axis': [0.0, 0.0, 1.0]},
                   {'name': 'trunnion', 'axis': [1.0, 0.0, 0.0]}],
        'imu': {'rpy_deg': [0.0, 0.0, 45.0], 'xyz_m': [0.0, 0.0, 0.0]}},
}


def write_fixture(name: str, out_dir: str | os.PathLike[str]) -> Path:
    """Write ``LAB_FIXTURES[name]`` as ``out_dir/name.yaml``; returns its path."""
    out = Path(out_dir) / f'{name}.yaml'
    out.parent.mkdir(parents=True, exist_ok=True)
    with open(out, 'w', encoding='utf-8') as fh:
        yaml.safe_dump(LAB_FIXTURES[name], fh, sort_keys=False)
    return out


def _R_enu_imu(fixture: dict[str, Any], q: FloatArray) -> FloatArray:
    """Nominal CONTRACT 2 kinematics (a lab's own few lines)."""
    R = np.eye(3)
    for j, qj in zip(fixture['joints'], q):
        a = np.asarray(j['axis'], dtype=float)
        R = R @ Rotation.from_rotvec(a / np.linalg.norm(a) * qj).as_matrix()
    return R @ Rotation.from_euler('xyz', np.radians(fixture['imu']['rpy_deg'])).as_matrix()


def lab_schedule(fixture: dict[str, Any], seed: int, positions: int = 14,
                 dwell_s: tuple[float, float] = (10.0, 40.0),
                 one_joint_at_a_time: bool = False,
                 accel_limit_deg_s2: float | None = None) -> TrapezoidProfile:
    """A multi-position + rate-test schedule on ``fixture`` (a CONTRACT 2 mapping).

    Drawn from ``seed``: the lab's rate limit U(10, 60) deg/s and acceleration limit
    U(10, 200) deg/s^2; ``positions`` poses among the multiples of 90 deg of every joint (a
    quarter of them at an odd multiple of 45 deg on one joint), chosen so that each IMU axis
    is stood up and down where the table can do it; a first dwell of 60-120 s; then each
    joint turned 1-2 revolutions one way and back at U(5, 90) deg/s. ``one_joint_at_a_time``:
    each move turns the joints one after the other (else all start and stop together);
    ``accel_limit_deg_s2``: the lab's acceleration limit instead of the drawn one.
    """
    rng = np.random.default_rng(seed)
    n = len(fixture['joints'])
    names = tuple(str(j['name']) for j in fixture['joints'])
    grid = np.array(np.meshgrid(*[np.arange(4) * 90.0 * _DEG] * n)).reshape(n, -1).T
    # which IMU axis points up (+1..+3) or down (-1..-3) at each grid pose
    up = []
    for q in grid:
        col = _R_enu_imu(fixture, q)[2]  # ENU z in IMU coordinates
        k = int(np.argmax(np.abs(col)))
        up.append((k + 1) * int(np.sign(col[k])) if abs(col[k]) > 0.99 else 0)
    up_arr = np.array(up)
    chosen: list[FloatArray] = []
    for target in rng.permutation([1, -1, 2, -2, 3, -3]):
        cand = np.flatnonzero(up_arr == target)
        if cand.size:
            chosen.append(grid[rng.choice(cand)])
    while len(chosen) < positions:
        chosen.append(grid[rng.integers(len(grid))])
    poses = [chosen[i] for i in rng.permutation(len(chosen))]
    for i in rng.choice(len(poses), size=max(1, len(poses) // 4), replace=False):
        poses[i] = poses[i].copy()
        poses[i][rng.integers(n)] += 45.0 * _DEG * rng.choice([-1.0, 1.0])
    acc = rng.uniform(10.0, 200.0)
    sched = Schedule(names, poses[0].copy(), rng.uniform(10.0, 60.0) * _DEG,
                     (accel_limit_deg_s2 or acc) * _DEG, name=f'lab-{seed}')
    sched.dwell(rng.uniform(60.0, 120.0))
    for q in poses[1:]:
        # the way round a lab's controller takes: sometimes the long one
        d = (q - sched.q + math.pi) % (2.0 * math.pi) - math.pi
        long_way = rng.random(n) < 0.2
        d = np.where(long_way & (np.abs(d) > 1e-9), d - np.sign(d) * 2.0 * math.pi, d)
        if one_joint_at_a_time:  # a controller that moves one axis after the other
            for j in np.flatnonzero(d):
                step = np.zeros(n)
                step[j] = d[j]
                sched.move_to(sched.q + step)
        else:
            sched.move_to(sched.q + d)
        sched.dwell(rng.uniform(*dwell_s))
    for j in rng.permutation(n):
        turns = float(rng.integers(1, 3)) * rng.choice([-1.0, 1.0])
        rate = rng.uniform(5.0, 90.0) * _DEG
        sched.spin(int(j), turns, rate).dwell(rng.uniform(*dwell_s))
        sched.spin(int(j), -turns, rate).dwell(rng.uniform(*dwell_s))
    return sched.build()
