"""The evidence of a calibration run for the self-check (issue 17): :class:`RunLedger`.

The ledger sees the same input as the estimator (the caller hands it every batch it pushes)
and reads the estimator's counters at the end; :func:`.selfcheck.judge` turns the figures into
a verdict. What it keeps, in bounded memory:

- the IMU stream's span and nominal period (how many samples the recording should hold) and
  0.1 s bins of the raw sums (for the stationary-window means: ~70 bytes per second of data);
- the joint record thinned to one sample per 20 ms (fixture order, unwrapped), from which the
  stationary windows are found at the end (:func:`.coarse.static_windows`, the coarse start's
  rule; the spans of the runs that ended are kept between calls, :func:`.coarse.still_spans`);
The gate counts of every filter of the run come from the estimator
(``CalibrationEstimator.nis_totals()``; checked against ``counters['chunks']``: exactly one
velocity update per chunk), the assumed noise from ``assumed_noise()`` and the reported
covariance's factor from ``covariance_scale()``: the ledger reads no estimator internals.
"""
from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from .. import sensor_model as sm
from ..input_guard import IMU_REASONS
from ..rotation import skew
from ..types import ImuBatch, JointBatch, JointSample
from . import error_model as em
from .buffers import encoder_clause, encoder_noise_rad, encoder_quantum_rad
from .coarse import least_reach, pair_walk, settled, still_spans, walk_threshold
from .estimator import RAW_PRIOR
from .selfcheck import (NisTotals, RunEvidence, SelfCheckConfig, Verdict, WindowStatistics,
                        judge, window_statistics)

FloatArray = NDArray[np.float64]
BIN_NS = 100_000_000  # IMU sums per 0.1 s
JOINT_KEEP_NS = 20_000_000  # joint record thinned to one sample per 20 ms
MIN_WINDOW_S = 1.0  # stationary windows of at least this (after the coarse start's trim)
MAX_WINDOWS = 300  # the longest windows if there are more (a 1800 x 1800 covariance)
JUMP_BACK_NS = 1_000_000_000  # a stamp this much older than the newest: a new recording
SAME_POSE_RAD = 1e-3  # bias_walk: two windows at one pose (every joint within this)
WALK_SHORT_S = 600.0  # bias_walk: pairs this close in time for the short-range walk
WALK_CHECK_NS = 60_000_000_000  # bias_walk handed to the estimator every 60 s of data
#: the worst direction of :meth:`RunLedger.window_statistics` when the run's final sensor
#: errors cannot compensate a stationary window (``sensor_model.ImplausibleErrors``)
IMPLAUSIBLE_END = ('the sensor errors the run ended at, which no unit has (their compensation '
                   'of the stationary windows does not converge)')
PLAUSIBLE_GROUPS = ('gyro_scale', 'gyro_misalignment', 'accel_scale', 'accel_misalignment')



def raw_unit_ratio(values: FloatArray, sigmas: FloatArray, raw_sigma: float) -> FloatArray:
    """``|value| / sqrt(raw_sigma^2 + sigma^2)``: how many sigmas an estimate lies from zero
    if the unit is a raw one (its error drawn from ``N(0, raw_sigma^2)``) and the estimate
    carries its own error ``N(0, sigma^2)``; the plausibility check's statistic."""
    return np.abs(values) / np.hypot(raw_sigma, sigmas)  # type: ignore[no-any-return]

class RunLedger:
    """Whole-run evidence of one estimator (see the module docstring).

    Call :meth:`imu` and :meth:`joints` with every batch pushed to the estimator, then
    :meth:`evidence` or :meth:`verdict` after its ``flush()``; :meth:`reset` with the
    estimator's ``reset()``.
    """

    def __init__(self, estimator: Any) -> None:
        self.est = estimator
        self.reset()

    def reset(self) -> None:
        """Forget the run (with the estimator's ``reset()``)."""
        self._segments: list[int] = []  # expected samples of finished recordings
        self._walk_checked: int | None = None
        self._t_first: int | None = None
        self._t_last: int | None = None
        self._dt_ns: float = 0.0
        self._dts: list[NDArray[np.int64]] = []
        self._reset_windows()

    def _reset_windows(self) -> None:
        self._origin: int | None = None
        self._bins = np.zeros((0, 7))  # count, gyro sum (3), accel sum (3)
        # windows' cuts to rest (coarse.settled), by (t0, t1, bins, samples)
        self._settled: dict[tuple[int, int, int, float], tuple[Any, ...]] = {}
        # the kept joint record: the first _jn rows of _jt_buf (stamps) and _jq_buf (unwrapped)
        self._jt_buf = np.zeros(0, np.int64)
        self._jq_buf = np.zeros((0, self.est.fixture.n_joints))
        self._jn = 0
        self._jlast: FloatArray | None = None
        # still spans of the runs that ended before sample _span_from (they no longer change)
        self._spans: list[tuple[int, int, FloatArray]] = []
        self._span_from = 0
        self._span_tol = math.nan  # the tolerance they were found with

    # ------------------------------------------------------------------ input side
    def imu(self, batch: ImuBatch) -> None:
        """An IMU batch as pushed to the estimator."""
        t = np.asarray(batch.stamps_ns, np.int64)
        if not len(t):
            return
        w = np.asarray(batch.gyro_rad_s, float).reshape(-1, 3)
        f = np.asarray(batch.accel_m_s2, float).reshape(-1, 3)
        if self._t_last is not None and int(t.min()) < self._t_last - JUMP_BACK_NS:
            self._close_segment()  # a looping bag or a restarted simulation
            self._reset_windows()
        if self._t_first is None:
            self._t_first = int(t[0])
        self._t_last = max(int(t.max()), self._t_last or int(t[0]))
        if self._dt_ns == 0.0:
            d = np.diff(t)
            self._dts.append(d[d > 0])
            dd = np.concatenate(self._dts)
            if len(dd) >= 20:
                self._dt_ns = float(np.median(dd))
                self._dts = []
        ok = np.all(np.isfinite(w), axis=1) & np.all(np.isfinite(f), axis=1)
        if not ok.any():
            return
        t, w, f = t[ok], w[ok], f[ok]
        if self._origin is None:
            self._origin = int(t[0]) - int(t[0]) % BIN_NS
        k = (t - self._origin) // BIN_NS
        inside = k >= 0
        k, w, f = k[inside], w[inside], f[inside]
        if not len(k):
            return
        top = int(k.max()) + 1
        if top > len(self._bins):
            grown = np.zeros((max(top, 2 * len(self._bins)), 7))
            grown[:len(self._bins)] = self._bins
            self._bins = grown
        # one bincount over the bins this batch touches (bin, column flattened)
        lo = int(k.min())
        vals = np.column_stack([np.ones(len(k)), w, f])
        idx = ((k - lo)[:, None] * 7 + np.arange(7)).ravel()
        self._bins[lo:top] += np.bincount(idx, vals.ravel(), minlength=(top - lo) * 7
                                          ).reshape(top - lo, 7)
        self._check_walk()

    def joints(self, batch: JointBatch | JointSample) -> None:
        """Joint states as pushed to the estimator (a batch or one sample)."""
        if isinstance(batch, JointSample):
            t = np.array([batch.stamp_ns], np.int64)
            q = np.asarray(batch.positions_rad, float).reshape(1, -1)
        else:
            t = np.asarray(batch.stamps_ns, np.int64)
            q = np.asarray(batch.positions_rad, float).reshape(len(t), -1)
        try:
            idx = [list(batch.names).index(n) for n in self.est.fixture.joint_names]
        except ValueError:
            return
        q = q[:, idx]
        finite = np.all(np.isfinite(q), axis=1).tolist()
        # thinned in stamp order (a loop over Python ints: which sample is kept depends on
        # the last kept one); a jump back starts a new record
        last = int(self._jt_buf[self._jn - 1]) if self._jn else None
        kept: list[int] = []
        for i, ti in enumerate(t.tolist()):
            if not finite[i]:
                continue
            if last is not None and ti < last + JOINT_KEEP_NS:
                if ti < last - JUMP_BACK_NS:
                    self._keep_joints(t[kept], q[kept])
                    self._reset_windows()
                    kept = []
                else:
                    continue
            kept.append(i)
            last = ti
        self._keep_joints(t[kept], q[kept])

    def _keep_joints(self, t: NDArray[np.int64], q: FloatArray) -> None:
        """Append kept joint samples, each unwrapped against the previous kept one:
        ``q_k + 2 pi round((q'_{k-1} - q_k) / 2 pi)``, sample by sample. Computed at once
        (the whole turns as a cumulative sum) and checked sample by sample against that rule
        with the result's own previous rows: where every check holds, the result is the
        sequential one bit for bit (by induction); else the sequential loop."""
        if not len(t):
            return
        two_pi = 2 * np.pi
        last = self._jlast
        cur = q[1:] if last is None else q  # the rows unwrapped against a previous one
        prev_raw = q[:-1] if last is None else np.vstack([last[None], q[:-1]])
        turns = np.cumsum(np.round((prev_raw - cur) / two_pi), axis=0)
        out = q.copy()
        out[len(q) - len(cur):] = cur + two_pi * turns
        prev = out[:-1] if last is None else np.vstack([last[None], out[:-1]])
        if not np.array_equal(np.round((prev - cur) / two_pi), turns):
            for k, qi in enumerate(q):
                if last is not None:
                    qi = qi + two_pi * np.round((last - qi) / two_pi)
                out[k] = last = qi
        n = self._jn + len(t)
        if n > len(self._jt_buf):  # grown by doubling (the fixture's joints: fixed columns)
            cap = max(n, 2 * len(self._jt_buf), 1024)
            jt = np.zeros(cap, np.int64)
            jq = np.zeros((cap, q.shape[1]))
            jt[:self._jn] = self._jt_buf[:self._jn]
            jq[:self._jn] = self._jq_buf[:self._jn]
            self._jt_buf, self._jq_buf = jt, jq
        self._jt_buf[self._jn:n] = t
        self._jq_buf[self._jn:n] = out
        self._jn = n
        self._jlast = out[-1].copy()

    def _close_segment(self) -> None:
        if self._t_first is not None and self._t_last is not None and self._dt_ns > 0:
            self._segments.append(int(round((self._t_last - self._t_first) / self._dt_ns)) + 1)
        self._t_first = self._t_last = None

    # ------------------------------------------------------------------ evidence
    def nis_totals(self) -> tuple[dict[str, NisTotals], bool]:
        """Whole-run gate counts per measurement kind (the estimator's, over every filter of
        the run), and whether they cover every chunk (one velocity update per chunk, none at
        a chunk end inside an interpolated gap)."""
        out = {k: NisTotals(a, r, t) for k, (a, r, t) in self.est.nis_totals().items()}
        v = out.get('velocity')
        n_v = 0 if v is None else v.accepted + v.rejected
        c = self.est.counters
        return out, n_v == int(c.get('chunks', 0)) - int(c.get('updates_skipped_in_gaps', 0))

    def expected_samples(self) -> int:
        """IMU samples the recording's stamps span at the nominal rate."""
        n = sum(self._segments)
        if self._t_first is not None and self._t_last is not None and self._dt_ns > 0:
            n += int(round((self._t_last - self._t_first) / self._dt_ns)) + 1
        return n

    def evidence(self) -> RunEvidence:
        """The figures of the run so far (call after the estimator's ``flush()``)."""
        est = self.est
        c = est.counters
        h = est.health()
        nis, complete = self.nis_totals()
        raw, label, n_raw = self.raw_ratio()
        rejected = sum(int(h['rejected'].get(r, 0)) for r in IMU_REASONS)
        received = int(c.get('imu_samples', 0))
        return RunEvidence(
            imu_received=received, imu_expected=max(self.expected_samples(), received),
            imu_rejected=rejected,
            # samples filled into short gaps were lost, not used
            imu_used=int(c.get('imu_processed', 0)) - int(c.get('imu_interpolated', 0)),
            imu_before_first_alignment=int(self.est.first_filter_dropped or 0),
            restarts=int(c.get('restarts', 0)), realignments=int(c.get('realignments', 0)),
            reinitialisations=int(c.get('gaps_reinitialised', 0))
            + int(c.get('navigation_resets', 0)),
            gate_probability=float(est.config.gate_probability), nis=nis,
            windows=self.window_statistics(), nis_complete=complete, raw_ratio=raw,
            raw_label=label, raw_states=n_raw, covariance_scale=est.covariance_scale(),
            raw_priors=est.grade is None or est.grade.sigma is None,
            plan_poses=self.distinct_poses(),
            plan_axes_short=est.start is not None and any(
                'fewer than three' in n for n in est.start.notes),
            plan_accel_reach=self.accel_reach())

    def accel_reach(self) -> tuple[float, tuple[float, ...]]:
        """``(reach, direction)``: of the IMU directions, the one the stationary windows stood
        least near vertical (a unit vector) and the largest share of the specific force along
        it over the windows (1: stood up or down, 0: always horizontal; coarse.least_reach);
        ``(1.0, ())`` without windows."""
        f = np.array([w[4] for w in self.windows()]).reshape(-1, 3)
        if not len(f):
            return 1.0, ()
        reach, v = least_reach(f)
        return reach, tuple(float(x) for x in v)

    def longest_joint_gap_s(self) -> float:
        """The longest interval between the kept joint states [s] (0 with fewer than two)."""
        if self._jn < 2:
            return 0.0
        return float(np.diff(self._jt_buf[:self._jn]).max()) * 1e-9

    def encoder_hint(self) -> str:
        """A clause naming the joint encoders' noise at rest (the alignment window's) or their
        steps (the joint record's) when above what the plain command is checked on
        (:func:`.buffers.encoder_clause`), or ''."""
        step = float(np.max(encoder_quantum_rad(self._jq_buf[:self._jn]), initial=0.0))
        clause = encoder_clause(self.est.encoder_noise_at_rest_rad, step)
        return (f' ({clause}: check the table\'s encoder resolution and its joint state '
                'publisher)') if clause else ''

    def distinct_poses(self) -> int:
        """Distinct stationary poses of the run: its windows' joint angles, apart by more
        than 1 mrad in some joint (the plan check of the self-check, and the replay's hint)."""
        poses: list[FloatArray] = []
        for w in self.windows():
            if not any(np.max(np.abs(w[2] - p)) < 1e-3 for p in poses):
                poses.append(w[2])
        return len(poses)

    def raw_ratio(self) -> tuple[float, str, int]:
        """Largest ``|estimate| / sqrt(RAW_PRIOR^2 + sigma^2)`` over the scale and
        misalignment states (the estimator's raw-unit prior: 3 %, 30 mrad, the largest an
        uncalibrated unit is specified for), where a wrong sign (scale -2), axis order
        (misalignment ~1) or unit (57.3, 1/9.8) shows; biases, G and the size effect have no
        such signature. ``sigma`` is the estimate's own: an estimate of a raw unit is drawn
        from the raw prior plus its error, so a state the plan leaves undetermined (a scale
        factor 33 +- 15 % after three poses) is no evidence of a sign or a unit."""
        st = self.est.estimate_state()
        lay = self.est.layout
        sd = np.sqrt(np.clip(np.diag(st.covariance), 0.0, None))
        worst, where, n = 0.0, '', 0
        for g in lay.groups:
            if g not in PLAUSIBLE_GROUPS:
                continue
            sl = slice(lay.slices[g].start - 6, lay.slices[g].stop - 6)
            r = raw_unit_ratio(st.values[sl], sd[sl], RAW_PRIOR[g])
            n += len(r)
            j = int(np.argmax(r))
            if r[j] > worst or not math.isfinite(r[j]):
                worst, where = float(r[j]), st.labels[sl.start + j]
        return worst, where, n

    def verdict(self, config: SelfCheckConfig | None = None) -> Verdict:
        """:func:`.selfcheck.judge` of :meth:`evidence`."""
        return judge(self.evidence(), config)

    # ------------------------------------------------------------------ stationary windows
    def windows(self) -> list[tuple[int, int, FloatArray, FloatArray, FloatArray, int]]:
        """Stationary windows ``(t0_ns, t1_ns, q, gyro mean, accel mean, samples)``."""
        if self._jn < 2 or self._origin is None:
            return []
        cnt = self._bins[:, 0]
        k = np.nonzero(cnt > 0)[0]
        if not len(k):
            return []
        t_bin = self._origin + k * BIN_NS + BIN_NS // 2
        sums = self._bins[k]
        spans = self._still_spans()
        if not spans:
            return []
        t0s = np.array([x[0] for x in spans], np.int64)
        t1s = np.array([x[1] for x in spans], np.int64)
        # the coarse rule's IMU check (coarse.static_windows: 10 bins in the window), then
        # the whole bins inside the window (the coarse rule already trimmed 0.3 s); all spans
        # at once (a search per span was most of the walk check's time)
        k0, k1 = np.searchsorted(t_bin, t0s), np.searchsorted(t_bin, t1s)
        b0 = np.searchsorted(t_bin, t0s + BIN_NS // 2)
        b1 = np.searchsorted(t_bin, t1s - BIN_NS // 2, side='right')
        out = []
        for i in np.flatnonzero((k1 - k0 >= 10) & (b1 > b0)).tolist():
            t0, t1, q_win = spans[i]
            rows = sums[b0[i]:b1[i]]
            # and to where the gyros show rest (a move's tail within the joints' tolerance);
            # a closed window's bins no longer change: its cut is kept (the walk check reads
            # the windows every minute: 0.7 s of an hour's replay without)
            key = (t0, t1, len(rows), float(rows[:, 0].sum()))
            cut = self._settled.get(key)
            if cut is None:
                lo, hi = settled(rows[:, 1:4] / np.maximum(rows[:, 0:1], 1.0))
                if (lo, hi) == (0, len(rows)):
                    cut = (lo, hi, t0, t1, q_win)
                elif hi - lo < 1:
                    cut = (lo, hi, t0, t1, None)
                else:
                    t0c = max(t0, int(t_bin[b0[i] + lo]) - BIN_NS // 2)
                    t1c = min(t1, int(t_bin[b0[i] + hi - 1]) + BIN_NS // 2)
                    # the joint states inside the cut only (the next one is in the cut tail);
                    # a cut shorter than the least window is none (as coarse.static_windows)
                    j0, j1 = np.searchsorted(self._jt_buf[:self._jn], [t0c, t1c], side='right')
                    keep = j1 > j0 and (t1c - t0c) * 1e-9 >= MIN_WINDOW_S
                    cut = (lo, hi, t0c, t1c,
                           self._jq_buf[j0:j1].mean(axis=0) if keep else None)
                if len(self._settled) > 10_000:
                    self._settled.clear()
                self._settled[key] = cut
            lo, hi, t0, t1, q_win = cut
            if q_win is None:
                continue
            rows = rows[lo:hi]
            s = rows.sum(axis=0)
            if s[0] < 10:
                continue
            out.append((t0, t1, q_win, s[1:4] / s[0], s[4:7] / s[0], int(s[0])))
        if len(out) > MAX_WINDOWS:
            keep = sorted(sorted(range(len(out)), key=lambda i: -out[i][5])[:MAX_WINDOWS])
            out = [out[i] for i in keep]
        return out

    def _still_spans(self) -> list[tuple[int, int, FloatArray]]:
        """:func:`.coarse.still_spans` of the joint record: those of the runs that ended are
        kept (they depend on their own samples only), the rest is scanned again."""
        tol = float(self.est.still_tolerance_rad)
        if tol != self._span_tol:  # set at the first alignment: scanned anew
            self._spans, self._span_from, self._span_tol = [], 0, tol
        a = self._span_from
        tj = self._jt_buf[a:self._jn]
        spans, last_run = still_spans(tj, self._jq_buf[a:self._jn], MIN_WINDOW_S, tol)
        if len(tj) < 2:
            return self._spans + spans
        t_open = int(tj[last_run])
        closed = [x for x in spans if x[0] < t_open]
        self._spans.extend(closed)
        self._span_from = a + last_run
        return self._spans + spans[len(closed):]

    def bias_walk(self) -> tuple[float, float, int]:
        """The biases' random walk the stationary windows show (item 5, during the run):
        ``(q_gyro, q_accel, pairs)``, PSDs per second, 0 where it does not stand out.

        Only pairs of windows at the same pose (every joint within :data:`SAME_POSE_RAD`):
        there the compensation is the same function of the same input, so whatever the
        calibration's error, the difference of the two raw means is white noise plus the
        bias change between them, fitted as ``a + q |t_j - t_i|`` (:func:`.coarse.pair_walk`,
        the coarse start's fit over all pairs). A Gauss-Markov instability of ~100 s (MEMS)
        grows over the first pairs and then saturates, which a straight line through all
        pairs does not show; so also
        ``q = sum y / sum |t_j - t_i|`` over the pairs at most :data:`WALK_SHORT_S` apart
        (the walk that explains their scatter), counted when ``mean y`` stands out
        (:func:`.coarse.walk_threshold` standard errors: at 2, checked every minute, white
        noise alone raised the walk in 6 % (gyro) and 11 % (accelerometer) of 30-min runs, and
        a raised walk is held: a stable MEMS unit's gyro-bias sigma 3.4 deg/h for 0.7; now in
        1 % and 0 % of 200 runs); the larger of the two.
        Plans that never return to a pose give 0."""
        wins = self.windows()
        if len(wins) < 4 or self._dt_ns <= 0:
            return 0.0, 0.0, 0
        q = np.array([x[2] for x in wins])
        dq = np.abs((q[:, None, :] - q[None, :, :] + np.pi) % (2 * np.pi) - np.pi).max(axis=2)
        i, j = np.nonzero(np.triu(dq < SAME_POSE_RAD, 1))
        used = len(set(i.tolist()) | set(j.tolist()))
        if len(i) < 6 or used < 4:
            return 0.0, 0.0, int(len(i))
        n_g, n_a, _, _ = (float(v) for v in self.est.assumed_noise())
        T = np.array([x[5] for x in wins], float) * self._dt_ns * 1e-9
        tm = np.array([0.5 * (x[0] + x[1]) * 1e-9 for x in wins])
        out = []
        for k, white in ((3, n_g), (4, n_a)):
            q_line, y, dt = pair_walk(tm, T, np.array([x[k] for x in wins]), white, i, j)
            short = dt <= WALK_SHORT_S
            q_short = 0.0
            if short.sum() >= 6:
                ys = y[short]
                used_s = len(set(i[short].tolist()) | set(j[short].tolist()))
                # no more independent differences than pairs (disjoint pairs: an arm's
                # 180 deg blocks return once, each pair its own two windows)
                se_s = float(np.std(ys)) / math.sqrt(max(min(used_s, len(ys)), 1))
                if float(np.mean(ys)) > walk_threshold(min(used_s, len(ys))) * se_s:
                    q_short = float(ys.sum() / dt[short].sum())
            out.append(max(q_line, q_short))
        return out[0], out[1], int(len(i))

    def _check_walk(self) -> None:
        """Every :data:`WALK_CHECK_NS` of data while the filter runs: hand the walk the
        windows show to the estimator (``raise_bias_walk``), live and offline alike."""
        t = self._t_last
        if t is None or not getattr(self.est, 'is_running', False):
            return
        if self._walk_checked is not None and t - self._walk_checked < WALK_CHECK_NS:
            return
        self._walk_checked = t
        q_g, q_a, _ = self.bias_walk()
        if q_g > 0 or q_a > 0:
            self.est.raise_bias_walk(q_g, q_a)

    def window_statistics(self) -> WindowStatistics | None:
        """Residuals of the stationary windows against the current estimate (None if fewer
        than two windows or the filter never ran)."""
        est = self.est
        wins = self.windows()
        if len(wins) < 2 or not self.est.nis_totals() or self._dt_ns <= 0 or self._t_last is None:
            return None
        st = est.estimate_state()
        lay = est.layout
        m = lay.n - 6
        errors = em.errors_from_theta(st.theta_gyro, st.theta_accel, sm.SensorErrors)
        K = len(wins)
        wm = np.array([x[3] for x in wins])
        fm = np.array([x[4] for x in wins])
        q = np.array([x[2] for x in wins])
        n = np.array([x[5] for x in wins], float)
        t_mid = np.array([0.5 * (x[0] + x[1]) for x in wins])
        fx = est.fixture
        zero = np.zeros_like(wm)
        try:
            w_c, f_c = sm.compensate(errors, wm, fm, zero)
        except sm.ImplausibleErrors:
            # a run that ended at sensor errors no unit has (a filter re-aligned a hundred
            # times on 10 Hz joint states with bursts of both streams lost) took the command
            # down with a traceback here: a failed check naming it instead
            return WindowStatistics(K, math.inf, 0, math.inf, IMPLAUSIBLE_END, 1)
        n_g, n_a, q_g, q_a = (float(v) for v in est.assumed_noise())
        T = n * self._dt_ns * 1e-9
        # a quantised encoder's angle at rest is off by up to half a step whatever the
        # window's length: gravity seen at that attitude error (0.1 mrad steps: 29 urad rms,
        # 28 ug, where a navigation unit's 20 s window mean is good to 1 ug; its windows'
        # chi2/dof came out 5.56 and refused a calibration within 2.4 sigma of the truth)
        # and a noisy encoder's window mean is off by its noise over the window's joint
        # states (0.1 mrad at 100 Hz over 20 s: 2.2 urad, 2 ug, twice a navigation unit's
        # 20 s noise; its windows' chi2/dof came out 1.38 on srt_then_kozlov)
        jq = self._jq_buf[:self._jn]
        jt = self._jt_buf[:self._jn]
        m_j = (np.searchsorted(jt, [x[1] for x in wins], side='right')
               - np.searchsorted(jt, [x[0] for x in wins]))
        var_q = (encoder_quantum_rad(jq) ** 2 / 12.0
                 + encoder_noise_rad(jq) ** 2 / np.maximum(m_j, 1)[:, None])
        var_f = step_attitude_variance(fx, q, fm, var_q)
        sigma = np.column_stack([np.repeat((n_g / np.sqrt(T))[:, None], 3, 1),
                                 np.sqrt((n_a / np.sqrt(T))[:, None] ** 2 + var_f)])
        resid, nuis = window_nuisance_fit(
            fx, q + est.joint_offsets_rad(), st.mounting_rotvec_rad, w_c, f_c, sigma)
        Jg, Ja = em.compensated_jacobians(errors, w_c, zero, f_c)
        jac = np.zeros((K, 6, m))
        jac[:, 0:3, lay.gyro_state_idx - 6] = Jg[:, :, lay.gyro_cols]
        jac[:, 3:6, lay.accel_state_idx - 6] = Ja[:, :, lay.accel_cols]
        # what the filter assumed: its white noise (sigma above), its (adapted) bias walk
        tau = np.clip((self._t_last - t_mid) * 1e-9, 0.0, None)
        brown = np.minimum.outer(tau, tau)
        walk = np.concatenate([np.repeat((q_g * brown)[:, :, None], 3, 2),
                               np.repeat((q_a * brown)[:, :, None], 3, 2)], axis=2)
        if not (np.all(np.isfinite(resid)) and np.all(np.isfinite(st.covariance))):
            return WindowStatistics(K, math.inf, 6 * K - 6, math.inf, 'non-finite', 1)
        # the covariance the calibration file reports (x covariance_scale)
        return window_statistics(resid, jac, st.covariance * est.covariance_scale(), sigma,
                                 walk, nuis,
                                 tuple(st.labels), t_s=t_mid * 1e-9)


def step_attitude_variance(fixture: Any, q: FloatArray, f: FloatArray,
                           var_rad2: FloatArray) -> FloatArray:
    """Variance (K, 3) of each window's specific force ``f`` (K, 3, IMU frame) from the
    encoders' error at rest, ``var_rad2`` per joint (n,) or per window and joint (K, n): a
    step ``s`` leaves ``s^2 / 12``, noise ``sigma`` over ``m`` states ``sigma^2 / m``. Joint
    ``j`` off by ``dtheta_j`` about its axis ``u_j`` turns gravity in the IMU frame by
    ``dtheta x f``: ``[f x] C [f x]^T``, ``C = sum_j var_j u_j u_j^T`` (IMU frame at the
    window's angles ``q``)."""
    var = np.broadcast_to(np.asarray(var_rad2, float), (len(q), np.shape(q)[1]))
    if not np.any(var):
        return np.zeros_like(f)
    axes = fixture.angular_axes_enu(q)  # (K, n, 3), ENU
    u = np.einsum('kji,knj->kni', fixture.R_enu_imu(q), axes)  # R^T u: IMU frame
    C = np.einsum('kn,kni,knj->kij', var, u, u)
    S = skew(f)
    return np.einsum('kii->ki', S @ C @ np.swapaxes(S, 1, 2))  # type: ignore[no-any-return]


def window_nuisance_fit(fixture: Any, q: FloatArray, mounting_rotvec_rad: FloatArray,
                        w_c: FloatArray, f_c: FloatArray, sigma: FloatArray,
                        iterations: int = 3) -> tuple[FloatArray, FloatArray]:
    """Residuals of the stationary windows' compensated means against earth rate and gravity
    at the fixture's attitude, with the rotations that are not the calibration's fitted out:
    the table's base (left), the mounting (right) and the zero offsets of the revolute joints
    before the last (a table's encoder zeros are known to a fraction of a degree; each turns
    everything after its joint about its axis, ``R(q + d e_j) = Rot(u_j d) R(q)``). Fitted by
    Gauss-Newton on the windows' white noise, so that a zero error of a few mrad leaves no
    second-order residual (5e-5 g at 10 mrad, more than a navigation unit's window noise).

    Returns ``(resid (K, 6), nuisance (K, 6, r))``: residuals at the fit and their
    derivatives there by the nuisance rotations, which the self-check projects out.
    """
    g_enu = np.array([0.0, 0.0, fixture.site.gravity])
    om_enu = np.asarray(fixture.site.omega_ie_enu, float)
    joints = list(em.nuisance_offset_joints(fixture))
    R_base = np.eye(3)
    R_mount = Rotation.from_rotvec(mounting_rotvec_rad).as_matrix()
    dq = np.zeros(len(joints))
    w_s = 1.0 / sigma

    def at(R_base: FloatArray, R_mount: FloatArray, dq: FloatArray
           ) -> tuple[FloatArray, FloatArray, float]:
        qq = np.array(q, float)
        qq[:, joints] += dq
        R = R_base @ fixture.R_enu_imu(qq) @ R_mount
        Rt = np.swapaxes(R, 1, 2)
        w_pred = np.einsum('kji,j->ki', R, om_enu)
        f_pred = np.einsum('kji,j->ki', R, g_enu)
        resid = np.hstack([w_c - w_pred, f_c - f_pred])
        nuis = np.zeros((len(resid), 6, 6 + len(joints)))
        nuis[:, 0:3, 0:3] = skew(w_pred)  # mounting, a right rotation
        nuis[:, 3:6, 0:3] = skew(f_pred)
        left_w = Rt @ skew(om_enu)  # base, a left rotation (ENU)
        left_f = Rt @ skew(g_enu)
        nuis[:, 0:3, 3:6] = left_w
        nuis[:, 3:6, 3:6] = left_f
        if joints:
            u = np.einsum('ij,kdj->kdi', R_base, fixture.joint_axes_enu(qq)[:, joints])
            nuis[:, 0:3, 6:] = np.einsum('kij,kdj->kid', left_w, u)
            nuis[:, 3:6, 6:] = np.einsum('kij,kdj->kid', left_f, u)
        return resid, nuis, float(np.sum((resid * w_s) ** 2))

    resid, nuis, cost = at(R_base, R_mount, dq)
    for _ in range(iterations):
        A = (nuis * w_s[:, :, None]).reshape(resid.size, -1)
        dx = np.linalg.lstsq(A, (resid * w_s).reshape(-1), rcond=1e-10)[0]
        step = (Rotation.from_rotvec(dx[3:6]).as_matrix() @ R_base,
                R_mount @ Rotation.from_rotvec(dx[0:3]).as_matrix(), dq + dx[6:])
        trial = at(*step)
        if not trial[2] < cost:  # Gauss-Newton only while it lowers the misfit
            break
        (R_base, R_mount, dq), (resid, nuis, cost) = step, trial
    return resid, nuis
