"""Holding the first data until the coarse start is determined (issue 11).

Without a given start the estimator holds every input sample the guard kept, and measures the
coarse start (:func:`~.coarse.coarse_start`: noise, joint latency, gyro and accelerometer
errors, the mounting) on the data held so far at fixed data times: ``bootstrap_min_s``, then
every 20 s or 25 %, up to ``bootstrap_max_s``. Checking at data times, on the data up to then,
gives the same start whatever the push pattern (single samples, batches). Once the start is
determined (:meth:`~.coarse.CoarseStart.determined`), or at the end of the data, the held input
is handed back in push order: the filter sees exactly what it would have seen with the start
known. This module holds and measures; :mod:`.coarse` is the maths.
"""
from __future__ import annotations

from collections.abc import Callable, Iterator
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from ..errors import InputError
from .alignment import still_tolerance_rad
from .buffers import point_to_mean
from .coarse import CoarseStart, NoRotation, coarse_start, implausible
from .config import EstimatorConfig

if TYPE_CHECKING:
    from ..fixture import Fixture

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]
# held input, in push order: ('imu', t, w, f, gap indices, long-gap indices) or ('joints', t, q)
HeldItem = tuple[Any, ...]


class Bootstrap:
    """Input held for the coarse start, and when to measure it."""

    def __init__(self, config: EstimatorConfig) -> None:
        self.config = config
        self.items: list[HeldItem] = []
        self._span = (0, 0)  # first and newest IMU stamp held
        self._next_check_s = 0.0
        #: the scatter [s] of joint stamps the joint clock could not put back (set by the
        #: estimator before each measurement: coarse.thin_joint_states)
        self.joint_timing_sigma_s = 0.0

    def hold_joints(self, t: IntArray, q: FloatArray) -> None:
        """Hold joint states the guard accepted (fixture order, not yet unwrapped)."""
        self.items.append(('joints', t, q))

    def hold_imu(self, t: IntArray, w: FloatArray, f: FloatArray, gaps: Any,
                 long_gaps: Any) -> None:
        """Hold IMU samples the guard kept (with the guard's gap indices)."""
        self.items.append(('imu', t, w, f, gaps, long_gaps))
        t0 = self._span[0] or int(t[0])
        self._span = (t0, max(self._span[1], int(t[-1])))

    def checks_due(self) -> Iterator[tuple[bool, int]]:
        """``(final, t_cut_ns)`` of every check of the coarse start that the held IMU span has
        reached; the caller stops iterating once the start is taken."""
        t0 = self._span[0]
        span = (self._span[1] - t0) * 1e-9
        cfg = self.config
        while span >= max(cfg.bootstrap_min_s, self._next_check_s):
            at = max(cfg.bootstrap_min_s, self._next_check_s)
            self._next_check_s = max(at + 20.0, 1.25 * at)  # ~12 checks up to 600 s
            yield at >= cfg.bootstrap_max_s, t0 + int(at * 1e9)

    def revise_stamps(self, imu: Callable[[IntArray], IntArray] | None,
                      joints: Callable[[IntArray], IntArray] | None,
                      gap_indices: Callable[[int | None, IntArray], tuple[Any, Any]]) -> int:
        """Stamps held as the clocks gave them while learning, on the senders' clocks now
        (:meth:`~..stamp_clock.StampClock.revise`; None: no change), the IMU's gaps flagged
        again on them. Returns the change in the number of gaps."""
        change = 0
        prev: int | None = None
        for i, item in enumerate(self.items):
            if item[0] == 'joints':
                if joints is not None:
                    self.items[i] = ('joints', joints(item[1]), item[2])
            elif imu is not None:
                t = imu(item[1])
                long_gaps, gaps = gap_indices(prev, t)
                change += len(gaps) - len(item[4])
                self.items[i] = ('imu', t, item[2], item[3], gaps, long_gaps)
                prev = int(t[-1])
        return change

    def arrays(self, t_cut_ns: int | None = None
               ) -> tuple[IntArray, FloatArray, FloatArray, IntArray, FloatArray] | None:
        """The held input up to ``t_cut_ns`` as clean arrays for :func:`coarse_start`
        (finite, stamp order, fixture joints unwrapped, point samples as interval means), or
        None if too little."""
        imu = [b for b in self.items if b[0] == 'imu']
        jb = [b for b in self.items if b[0] == 'joints']
        if not imu or not jb:
            return None
        t = np.concatenate([b[1] for b in imu])
        w = np.concatenate([b[2] for b in imu])
        f = np.concatenate([b[3] for b in imu])
        if t_cut_ns is not None:
            k = int(np.searchsorted(t, t_cut_ns, side='right'))
            t, w, f = t[:k], w[:k], f[:k]
        if self.config.imu_sample_type == 'point':
            w, f = point_to_mean(w, f, None)
        tj = np.concatenate([b[1] for b in jb])
        qj = np.concatenate([b[2] for b in jb])
        if t_cut_ns is not None:
            k = int(np.searchsorted(tj, t_cut_ns, side='right'))
            tj, qj = tj[:k], qj[:k]
        qj = np.unwrap(qj[np.arange(len(tj))], axis=0)
        if len(t) < 100 or len(tj) < 4:
            return None
        return t, w, f, tj, qj

    def measure(self, fixture: Fixture, final: bool,
                t_cut_ns: int | None = None) -> tuple[bool, CoarseStart | None]:
        """Measure the coarse start on the held data up to ``t_cut_ns``.

        Returns ``(ready, start)``: ready when the start is determined, or at the end of the
        data (``final``; then ``start`` may be None: no rotation, the caller's "no motion"
        check names it).

        Raises
        ------
        InputError
            At the end of the data, when the data contradict the fixture (one line saying
            which): never a guess.
        """
        arrays = self.arrays(t_cut_ns)
        st = None
        if arrays is not None:
            try:
                # before the end only a determined start is taken: skip the gyro fits when
                # the accelerometers already show it is not (same outcome, 1/5 of the cost)
                cfg = self.config
                tol = still_tolerance_rad(arrays[3], arrays[4], cfg.init_window_s,
                                          cfg.stationary_joint_tolerance_rad)
                st = coarse_start(*arrays, fixture,
                                  tol_rad=cfg.stationary_joint_tolerance_rad if tol is None
                                  else tol,
                                  only_determined=not final,
                                  point_samples=self.config.imu_sample_type == 'point',
                                  joint_timing_sigma_s=self.joint_timing_sigma_s)
            except NoRotation:
                pass
            except (ValueError, np.linalg.LinAlgError) as exc:
                if final:
                    raise InputError(str(exc)) from None
        if st is None and not final:
            return False, None
        if st is not None and not final and not st.determined():
            return False, st  # not yet determined: gather more
        if st is not None and not final and implausible(st) is not None:
            # a start on part of the data that no unit can have: more data may show why (the
            # caller refuses it only at the end of the data)
            return False, None
        return True, st
