"""Plan objects and joint-angle profiles: what a plan is, and what it becomes on a fixture.

:class:`Plan` (a flat list of validated :class:`Step`) is what :mod:`.parse` reads from YAML;
:class:`JointProfile` is what :func:`.builder.build_profile` makes of it on a
:class:`~imu_calib_ros.core.fixture.Fixture`: piecewise analytic ``q(t), q'(t), q''(t)``
whose pieces (:class:`_Piece`) are

- ``hold``: at rest;
- ``quintic``: rest-to-rest move, ``q0 + dq (10 s^3 - 15 s^4 + 6 s^5)``, ``s = t / T``
  (acceleration continuous and zero at both ends);
- ``cosine``: Kozlov & Kapralov's harmonic oscillation in the from-rest form
  ``psi = psi_c + A cos(W t)``, ``W = 2 pi / T``, ``psi_c = psi_start - A``, whole cycles;
- ``ramp_up`` / ``const`` / ``ramp_down``: continuous rotation (rotation modulation) with a
  cubic-smoothstep rate ramp, so the acceleration is continuous.

The third derivative may jump only at :attr:`JointProfile.breakpoints_s`, which is where the
simulator splits its Gauss-Legendre integration, so the integrals are exact to rounding.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Mapping

import numpy as np

from ..types import FloatArray


@dataclass(frozen=True)
class Step:
    """One validated plan step: ``kind``, its parameters, and where it came from."""

    kind: str
    params: Mapping[str, Any]
    where: str  # e.g. "plans/x.yaml step 3" or "... step 2 > include y.yaml step 1"


@dataclass(frozen=True)
class Plan:
    """A loaded plan: includes and repeats already expanded into a flat step list."""

    name: str
    description: str
    steps: tuple[Step, ...]
    source: str = '<dict>'


@dataclass(frozen=True)
class Segment:
    """A labelled time window of a profile (``kind`` in dwell/move/oscillate/spin)."""

    t0_s: float
    t1_s: float
    kind: str
    label: str
    meta: dict[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class _Piece:
    t0: float
    t1: float
    kind: str  # hold | quintic | cosine | ramp_up | const | ramp_down
    q0: FloatArray  # (n,) joint angles at t0
    vec: FloatArray  # (n,) quintic: delta; ramps/const: rate; cosine: unit joint selector
    amp: float = 0.0  # cosine amplitude [rad]
    omega: float = 0.0  # cosine angular frequency W [rad/s]

    def end(self) -> FloatArray:
        T = self.t1 - self.t0
        if self.kind == 'quintic':
            return self.q0 + self.vec
        if self.kind in ('ramp_up', 'ramp_down'):
            return self.q0 + 0.5 * self.vec * T
        if self.kind == 'const':
            return self.q0 + self.vec * T
        return self.q0.copy()  # hold; cosine runs whole cycles

    def evaluate(self, t: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        T = self.t1 - self.t0
        u = np.clip(t - self.t0, 0.0, T)[:, None]
        s = u / T if T > 0 else np.zeros_like(u)
        q0, v = self.q0[None, :], self.vec[None, :]
        zero = np.zeros((t.shape[0], q0.shape[1]))
        if self.kind == 'hold':
            return q0 + zero, zero, zero.copy()
        if self.kind == 'quintic':
            pos = s**3 * (10.0 + s * (-15.0 + 6.0 * s))
            vel = 30.0 * s**2 * (1.0 - s) ** 2 / T
            acc = 60.0 * s * (1.0 - s) * (1.0 - 2.0 * s) / T**2
            return q0 + v * pos, v * vel, v * acc
        if self.kind == 'cosine':
            wu = self.omega * u
            a = self.amp
            return (q0 + v * a * (np.cos(wu) - 1.0), -v * a * self.omega * np.sin(wu),
                    -v * a * self.omega**2 * np.cos(wu))
        if self.kind == 'ramp_up':
            return (q0 + v * T * s**3 * (1.0 - 0.5 * s), v * s**2 * (3.0 - 2.0 * s),
                    v * 6.0 * s * (1.0 - s) / T)
        if self.kind == 'const':
            return q0 + v * u, v + zero, zero
        if self.kind == 'ramp_down':
            return (q0 + v * T * s * (1.0 - s**2 + 0.5 * s**3),
                    v * (1.0 - s**2 * (3.0 - 2.0 * s)), -v * 6.0 * s * (1.0 - s) / T)
        raise AssertionError(self.kind)


@dataclass(frozen=True)
class JointProfile:
    """Analytic joint-angle profile of a plan on one fixture (see module docstring)."""

    joint_names: tuple[str, ...]
    pieces: tuple[_Piece, ...]
    segments: tuple[Segment, ...]
    plan_name: str = ''

    @property
    def duration_s(self) -> float:
        """End time of the profile (it starts at 0)."""
        return self.pieces[-1].t1 if self.pieces else 0.0

    @property
    def breakpoints_s(self) -> FloatArray:
        """Times (K,) where the third derivative may jump, incl. 0 and the end."""
        t = [p.t0 for p in self.pieces] + [self.duration_s]
        return np.unique(np.asarray(t, dtype=float))

    @property
    def q_start(self) -> FloatArray:
        """Joint angles at t = 0."""
        return self.pieces[0].q0.copy()

    def evaluate(self, t_s: Any) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Joint angles, rates and accelerations at times ``t_s`` (N,), each (N, n).

        Times outside [0, duration] give the rest state at the nearest end. At a
        breakpoint the piece that starts there is used (all pieces join with continuous
        q, q' and q''; only an oscillation's start and end have an acceleration jump).
        """
        t = np.atleast_1d(np.asarray(t_s, dtype=float))
        n = len(self.joint_names)
        q = np.empty((t.shape[0], n))
        qd = np.empty_like(q)
        qdd = np.empty_like(q)
        starts = np.array([p.t0 for p in self.pieces])
        idx = np.clip(np.searchsorted(starts, t, side='right') - 1, 0, len(self.pieces) - 1)
        for k in np.unique(idx):
            sel = idx == k
            q[sel], qd[sel], qdd[sel] = self.pieces[k].evaluate(t[sel])
        return q, qd, qdd

    def stationary_windows(self, min_duration_s: float = 0.0) -> list[tuple[float, float]]:
        """Merged time windows (t0, t1) in which every joint is at rest."""
        out: list[tuple[float, float]] = []
        for p in self.pieces:
            if p.kind != 'hold':
                continue
            if out and abs(out[-1][1] - p.t0) < 1e-12:
                out[-1] = (out[-1][0], p.t1)
            else:
                out.append((p.t0, p.t1))
        return [w for w in out if w[1] - w[0] >= min_duration_s]

    def segments_labelled(self, prefix: str) -> list[Segment]:
        """Segments whose label starts with ``prefix`` (e.g. ``'srt:'``, ``'osc:'``)."""
        return [s for s in self.segments if s.label.startswith(prefix)]
