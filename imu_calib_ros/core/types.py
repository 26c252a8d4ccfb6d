"""The internal sample types that every source (rclpy, rosbags, simulator) maps onto.

Stamps are integer nanoseconds on the clock shared by IMU and joint states. IMU values
follow CONTRACT section 1: the mean over the interval since the previous sample, stamped
at the end of that interval, in the IMU body frame.
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]


@dataclass(frozen=True, slots=True)
class ImuSample:
    """One IMU sample: mean angular rate [rad/s] and mean specific force [m/s^2]."""

    stamp_ns: int
    gyro_rad_s: FloatArray  # (3,), rate relative to inertial space, body frame
    accel_m_s2: FloatArray  # (3,), specific force, body frame
    frame_id: str = ''


@dataclass(frozen=True, slots=True)
class JointSample:
    """One joint-state sample of the fixture (names as in the message, any order)."""

    stamp_ns: int
    names: tuple[str, ...]
    positions_rad: FloatArray  # (len(names),)
    velocities_rad_s: FloatArray | None = None  # (len(names),) or None when empty


@dataclass(slots=True)
class ImuBatch:
    """Many IMU samples as arrays (simulator output, bag contents, replay chunks)."""

    stamps_ns: NDArray[np.int64]  # (N,)
    gyro_rad_s: FloatArray  # (N, 3)
    accel_m_s2: FloatArray  # (N, 3)
    frame_id: str = ''

    def __len__(self) -> int:
        return int(self.stamps_ns.shape[0])

    def sample(self, i: int) -> ImuSample:
        """The i-th sample as an :class:`ImuSample`."""
        return ImuSample(int(self.stamps_ns[i]), self.gyro_rad_s[i], self.accel_m_s2[i],
                         self.frame_id)

    def __iter__(self):
        for i in range(len(self)):
            yield self.sample(i)

    @classmethod
    def from_samples(cls, samples: list[ImuSample]) -> 'ImuBatch':
        """Stack samples (keeps their order; the frame_id of the first)."""
        if not samples:
            return cls(np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros((0, 3)))
        return cls(np.array([s.stamp_ns for s in samples], np.int64),
                   np.array([s.gyro_rad_s for s in samples], float),
                   np.array([s.accel_m_s2 for s in samples], float),
                   samples[0].frame_id)

    @classmethod
    def from_rows(cls, rows: Sequence[tuple[int, Sequence[float], Sequence[float]]],
                  frame_id: str = '') -> 'ImuBatch':
        """Stack ``(stamp_ns, gyro (3,), accel (3,))`` rows, sorted by stamp (stable)."""
        stamps = np.array([r[0] for r in rows], np.int64)
        order = np.argsort(stamps, kind='stable')
        return cls(stamps[order], np.array([r[1] for r in rows], float).reshape(-1, 3)[order],
                   np.array([r[2] for r in rows], float).reshape(-1, 3)[order], frame_id)


@dataclass(slots=True)
class JointBatch:
    """Many joint-state samples for one fixed list of joint names."""

    stamps_ns: NDArray[np.int64]  # (M,)
    names: tuple[str, ...]
    positions_rad: FloatArray  # (M, len(names))
    velocities_rad_s: FloatArray | None = None  # (M, len(names)) or None

    def __len__(self) -> int:
        return int(self.stamps_ns.shape[0])

    def sample(self, i: int) -> JointSample:
        """The i-th sample as a :class:`JointSample`."""
        vel = None if self.velocities_rad_s is None else self.velocities_rad_s[i]
        return JointSample(int(self.stamps_ns[i]), self.names, self.positions_rad[i], vel)

    def __iter__(self):
        for i in range(len(self)):
            yield self.sample(i)

    @classmethod
    def runs(cls, samples: Sequence[JointSample]) -> list['JointBatch']:
        """Samples sorted by stamp (stable), one batch per run of one name list (positions
        only, as the estimator takes them)."""
        ordered = sorted(samples, key=lambda j: j.stamp_ns)
        out = []
        start = 0
        for k in range(1, len(ordered) + 1):
            if k == len(ordered) or ordered[k].names != ordered[start].names or \
                    len(ordered[k].positions_rad) != len(ordered[start].positions_rad):
                run = ordered[start:k]
                out.append(cls(np.array([j.stamp_ns for j in run], np.int64),
                               tuple(run[0].names),
                               np.array([np.asarray(j.positions_rad, float)
                                         for j in run]).reshape(len(run), -1)))
                start = k
        return out


#: CONTRACT 1: an interval longer than this many nominal periods follows a gap.
GAP_PERIODS = 1.5


def sample_intervals_ns(stamps_ns: NDArray[np.int64], nominal_ns: float | None = None,
                        gap_periods: float = GAP_PERIODS,
                        ) -> tuple[FloatArray, NDArray[np.bool_]]:
    """The averaging interval of each sample, with CONTRACT 1's gap rule.

    A sample whose interval to the previous sample is longer than ``gap_periods`` nominal
    periods follows a gap: it is the mean over its own nominal period only, so its interval
    is the nominal one. The first sample, with no predecessor, also gets the nominal period.
    Differences are taken in int64 first: absolute stamps (~1.7e18 ns) in float64 resolve
    only 256 ns.

    Parameters
    ----------
    stamps_ns : (N,) int
        Increasing stamps [ns].
    nominal_ns : float, optional
        Nominal sample period [ns]; default the median stamp difference.
    gap_periods : float
        Gap threshold in nominal periods (CONTRACT 1: 1.5).

    Returns
    -------
    intervals_ns : ndarray, shape (N,), float
        Interval of each sample [ns].
    is_gap : ndarray, shape (N,), bool
        True for the samples that follow a gap.
    """
    stamps = np.asarray(stamps_ns, np.int64)
    if stamps.ndim != 1:
        raise ValueError(f'stamps (N,) expected, got shape {stamps.shape}')
    d = np.diff(stamps).astype(float)
    if nominal_ns is None:
        if d.size == 0:
            if stamps.size == 0:
                return np.zeros(0), np.zeros(0, bool)
            raise ValueError('one stamp: give nominal_ns, its interval is unknown')
        nominal_ns = float(np.median(d))
    nominal_ns = float(nominal_ns)
    is_gap = np.concatenate([[False], d > gap_periods * nominal_ns])[:stamps.size]
    intervals = np.concatenate([[nominal_ns], d])[:stamps.size]
    intervals[is_gap] = nominal_ns
    return intervals, is_gap
