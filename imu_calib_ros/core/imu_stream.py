"""One raw IMU stream, sample by sample: checked, put in stamp order, compensated (issue 14).

:class:`ImuStream` is what the calibration node and the compensator node do with every raw
IMU sample after decoding its message (they had near copies of it): the frame check (adopt
the first frame when none is configured, or require the calibration's), the finite check,
the reorder window (:class:`~imu_calib_ros.core.reorder.ReorderBuffer`), the out-of-order
check of the ordered stream, the count of samples missing upstream (stamp gaps against the
measured or configured period) and the compensation
(:class:`~imu_calib_ros.core.stream_compensation.StreamCompensation`). Each call returns a
:class:`Step`: the corrected samples to publish and the rejected ones, each with its reason;
:attr:`ImuStream.rejected` counts by reason. Plain Python floats, no rclpy, no numpy on the
per-sample path.

Reasons (the nodes' ``node.*`` counters): ``bad_message`` (counted by :meth:`reject`: the
caller could not decode the message), ``frame_id``, ``non_finite``, ``out_of_order`` (not
after the previous ordered sample: later than the reorder window, or a duplicate),
``compensation_non_finite`` (the compensated values or their variances are not finite:
never published; the raw sample is still accepted).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

from .reorder import ReorderBuffer
from .stream_compensation import StreamCompensation
from .types import GAP_PERIODS

__all__ = ['Corrected', 'ImuStream', 'Rejected', 'STREAM_REASONS', 'Step']

#: The reasons :class:`ImuStream` counts, in the order of its checks.
STREAM_REASONS = ('bad_message', 'frame_id', 'non_finite', 'out_of_order',
                  'compensation_non_finite')

Vec3 = tuple[float, float, float]


@dataclass(frozen=True, slots=True)
class Corrected:
    """An accepted raw sample in stamp order and, when finite, its compensated values.

    ``values`` is ``(omega [rad/s], f [m/s^2], gyro_var, accel_var)``, 3 floats each, or
    None when the compensation was not finite (counted as ``compensation_non_finite``:
    nothing to publish; the raw sample itself was accepted).
    """

    stamp_ns: int
    frame_id: str
    gyro: Vec3  # raw
    accel: Vec3  # raw
    values: tuple[tuple[float, ...], ...] | None = None


@dataclass(frozen=True, slots=True)
class Rejected:
    """A raw sample dropped for ``reason`` (one of :data:`STREAM_REASONS`)."""

    reason: str
    stamp_ns: int | None = None
    frame_id: str = ''


class Step(NamedTuple):
    """What one call of :class:`ImuStream` produced."""

    #: accepted samples in stamp order (those with ``omega`` None are not to be published)
    accepted: list[Corrected]
    rejected: list[Rejected]
    #: the frame adopted by this call ('' if none)
    adopted_frame: str = ''
    #: True on the call after which the IMU period became known (measured_period_s)
    rate_known: bool = False


def _finite3(*vectors: tuple[float, ...]) -> bool:
    return all(math.isfinite(v[0] + v[1] + v[2]) for v in vectors)


class ImuStream:
    """Raw IMU samples in, checked, ordered and compensated samples out (see module doc).

    Parameters
    ----------
    compensation:
        The per-sample compensation (its calibration may be swapped by its owner).
    frame_id:
        The frame to accept; with ``adopt_frame`` and an empty ``frame_id``, the first
        sample's frame becomes it.
    reorder_window_s:
        Longest wait of a sample to put the stream back in stamp order (0 = no wait).
    adopt_frame:
        Adopt the first frame when ``frame_id`` is empty (the calibration node); False: an
        exact match is required (the compensator: the calibration's frame).

    Thread use: :meth:`push`, :meth:`release` and :meth:`due_ns` from one thread (the IMU
    input thread); :meth:`restart` from any (the reorder window is forgotten at the next
    push or release, in the input thread).
    """

    def __init__(self, compensation: StreamCompensation, frame_id: str = '',
                 reorder_window_s: float = 0.0, adopt_frame: bool = False) -> None:
        self.compensation = compensation
        self.frame_id = frame_id
        self.adopt_frame = adopt_frame
        self.reorder: ReorderBuffer[tuple[str, Vec3, Vec3]] = ReorderBuffer(reorder_window_s)
        self.rejected: dict[str, int] = {k: 0 for k in STREAM_REASONS}
        #: samples missing upstream (stamp gaps of the ordered stream, period known)
        self.missing = 0
        self.rejected_frame = ''  # header.frame_id of the last sample rejected for its frame
        self.first_ns: int | None = None  # stamp of the first ordered sample (kept)
        self.last_ns: int | None = None  # stamp of the newest ordered sample
        self._rate_known = False
        self._reorder_reset = False

    # ------------------------------------------------------------------ control
    def restart(self) -> None:
        """A time jump or a reset: forget the ordering state, the previous sample of the
        compensation and (in the input thread, at the next call) the reorder window."""
        self._reorder_reset = True
        self.last_ns = None
        self.compensation.reset()

    def reset_counts(self) -> None:
        """Zero the rejection counts (in place)."""
        for k in self.rejected:
            self.rejected[k] = 0

    def reject(self, reason: str, stamp_ns: int | None = None, frame_id: str = '') -> Step:
        """Count a rejection found by the caller (``bad_message``)."""
        self.rejected[reason] += 1
        return Step([], [Rejected(reason, stamp_ns, frame_id)])

    def due_ns(self) -> int | None:
        """The clock at which :meth:`release` may let a held sample out (None: none held)."""
        return self.reorder.due_ns()

    def seconds_to_due(self, clock_ns: int) -> float | None:
        """Seconds from ``clock_ns`` until :meth:`due_ns` (None: none held)."""
        due = self.reorder.due_ns()
        return None if due is None else (due - clock_ns) * 1e-9

    # ------------------------------------------------------------------ samples
    def push(self, stamp_ns: int, frame_id: str, gyro: Vec3, accel: Vec3,
             clock_ns: int) -> Step:
        """One decoded raw sample arriving at ``clock_ns`` (monotonic): checked, held in the
        reorder window; returns what came out of the window in stamp order."""
        adopted = ''
        if frame_id != self.frame_id:
            if self.frame_id or not self.adopt_frame:
                self.rejected_frame = frame_id
                return self.reject('frame_id', stamp_ns, frame_id)
            self.frame_id = adopted = frame_id
        if not _finite3(gyro, accel):
            return self.reject('non_finite', stamp_ns, frame_id)
        self._check_reorder_reset()
        step = self._ordered(self.reorder.push(stamp_ns, (frame_id, gyro, accel), clock_ns))
        return step._replace(adopted_frame=adopted) if adopted else step

    def release(self, clock_ns: int) -> Step:
        """The held samples whose wait is over at ``clock_ns`` (the stream paused)."""
        self._check_reorder_reset()
        return self._ordered(self.reorder.release(clock_ns))

    def _check_reorder_reset(self) -> None:
        if self._reorder_reset:  # the clock jumped back, or a reset: forget what was held
            self._reorder_reset = False
            self.reorder.reset()

    def _ordered(self, items: list[tuple[int, tuple[str, Vec3, Vec3]]]) -> Step:
        accepted: list[Corrected] = []
        rejected: list[Rejected] = []
        rate_known = False
        comp = self.compensation
        for ns, (frame, gyro, accel) in items:
            last = self.last_ns
            if last is not None:
                if ns <= last:
                    self.rejected['out_of_order'] += 1
                    rejected.append(Rejected('out_of_order', ns, frame))
                    continue
                period = comp.nominal_period_s  # None until detected
                if period is not None and ns - last > GAP_PERIODS * 1e9 * period:
                    self.missing += round((ns - last) * 1e-9 / period) - 1  # lost upstream
            else:
                self.first_ns = self.first_ns or ns
            self.last_ns = ns
            omega, f, gvar, avar = comp(ns, gyro, accel)
            if _finite3(omega, f, gvar, avar):  # never a NaN out of a publisher
                accepted.append(Corrected(ns, frame, gyro, accel, (omega, f, gvar, avar)))
            else:
                self.rejected['compensation_non_finite'] += 1
                rejected.append(Rejected('compensation_non_finite', ns, frame))
                accepted.append(Corrected(ns, frame, gyro, accel))
            if not self._rate_known and comp.measured_period_s is not None:
                self._rate_known = rate_known = True
                self._count_learning_gaps()
        return Step(accepted, rejected, '', rate_known)

    def _count_learning_gaps(self) -> None:
        """Once the period is measured (not configured): the samples missing among the
        intervals it was measured from."""
        comp = self.compensation
        period = comp.nominal_period_s
        if comp.configured_period_s == 0.0 and period:
            self.missing += sum(round(d * 1e-9 / period) - 1 for d in comp.intervals_ns
                                if d > GAP_PERIODS * 1e9 * period)
