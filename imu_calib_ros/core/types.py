"""The internal sample types that every source (rclpy, rosbags, simulator) maps onto.

Stamps are integer nanoseconds on the clock shared by IMU and joint states. IMU values
follow CONTRACT section 1: the mean over the interval since the previous sample, stamped
at the end of that interval, in the IMU body frame.
"""
from __future__ import annotations

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
