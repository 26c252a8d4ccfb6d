"""core/reorder.py (issue 17): the stamp-order window, per message and on arrays."""
from __future__ import annotations

import numpy as np
import pytest

from imu_calib_ros.core.reorder import BatchReorder, ReorderBuffer, ReorderStats

T0 = 1_700_000_000_000_000_000
MS = 1_000_000


def receipt_jitter(n: int, period_ns: int, lo_ns: int, hi_ns: int,
                   seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Exact stamps, arrival clock = stamp + uniform delay; both in arrival order."""
    rng = np.random.default_rng(seed)
    stamps = T0 + period_ns * np.arange(n, dtype=np.int64)
    clocks = stamps + rng.integers(lo_ns, hi_ns + 1, n)
    order = np.argsort(clocks, kind='stable')
    return stamps[order], clocks[order]


def out_of_order(stamps: np.ndarray) -> int:
    """Messages older than the newest before them (what the input guard rejects)."""
    return int((stamps[1:] < np.maximum.accumulate(stamps)[:-1]).sum())


def run_buffer(stamps: np.ndarray, clocks: np.ndarray, window_s: float
               ) -> tuple[np.ndarray, ReorderStats]:
    buf: ReorderBuffer[int] = ReorderBuffer(window_s)
    out: list[int] = []
    for k in range(len(stamps)):
        out += [i for _, i in buf.push(int(stamps[k]), k, int(clocks[k]))]
    out += [i for _, i in buf.flush()]
    return np.array(out, np.int64), buf.stats


def run_batch(stamps: np.ndarray, clocks: np.ndarray, window_s: float,
              cuts: list[int]) -> tuple[np.ndarray, ReorderStats]:
    b = BatchReorder(window_s)
    edges = [0, *sorted(cuts), len(stamps)]
    out = [b.push(stamps[a:z], clocks[a:z]) for a, z in zip(edges[:-1], edges[1:])]
    out.append(b.flush())
    assert len(b.pending_ids) == 0
    return np.concatenate(out), b.stats


@pytest.mark.parametrize('window_s', [0.5, 0.005, 0.0011])
def test_2khz_receipt_jitter_comes_out_in_stamp_order(window_s: float) -> None:
    """rosbag2's log time = receipt time (stamp + 1.5..2.5 ms) at 2 kHz: one message in
    eight is behind a newer one; any window over the 1 ms jitter span restores the order
    and counts exactly those."""
    s, c = receipt_jitter(40_000, MS // 2, 3 * MS // 2, 5 * MS // 2)
    n_bad = out_of_order(s)
    assert 0.11 < n_bad / len(s) < 0.14  # the 12.6 %
    for ids, stats in (run_batch(s, c, window_s, list(range(0, len(s), 16384))),
                       run_buffer(s, c, window_s)):
        assert len(ids) == len(s) and np.all(np.diff(s[ids]) > 0)
        assert stats == ReorderStats(len(s), n_bad, 0, 0, MS // 2)


def test_a_window_shorter_than_the_jitter_passes_the_late_ones_on_in_place() -> None:
    s, c = receipt_jitter(4000, MS // 2, 0, 4 * MS, seed=2)
    ids, stats = run_batch(s, c, 0.001, [1000])
    assert stats.late > 0 and stats.reordered > 0
    assert stats.reordered + stats.late == out_of_order(s)
    # every message comes out once; apart from the late ones, in stamp order
    assert sorted(ids.tolist()) == list(range(len(s)))
    late = s[ids] < np.maximum.accumulate(s[ids])
    assert int(late.sum()) == stats.late
    assert np.all(np.diff(s[ids][~late]) >= 0)


def test_a_looping_stream_keeps_its_backward_jump() -> None:
    """A bag that loops: the second pass is not sorted into the first one."""
    s1, c1 = receipt_jitter(3000, MS, 0, 2 * MS, seed=3)
    s2 = s1.copy()
    c2 = c1 + (c1[-1] - c1[0]) + 10 * MS
    s, c = np.concatenate([s1, s2]), np.concatenate([c1, c2])
    ids, stats = run_batch(s, c, 0.5, [100, 2999, 3001, 5000])
    assert stats.backward_jumps == 1 and stats.late == 0
    assert np.all(ids[:3000] < 3000) and np.all(ids[3000:] >= 3000)
    assert np.all(np.diff(s[ids[:3000]]) > 0) and np.all(np.diff(s[ids[3000:]]) > 0)
    assert stats.reordered == out_of_order(s1) + out_of_order(s2)


def test_duplicates_are_kept_next_to_each_other() -> None:
    s = T0 + MS * np.array([0, 2, 1, 2, 3, 3, 5, 4], np.int64)
    c = T0 + MS * np.arange(8, dtype=np.int64)
    ids, stats = run_batch(s, c, 0.1, [3])
    assert s[ids].tolist() == (T0 + MS * np.array([0, 1, 2, 2, 3, 3, 4, 5])).tolist()
    assert ids.tolist() == [0, 2, 1, 3, 4, 5, 7, 6]  # equal stamps keep arrival order
    assert stats.reordered == 2 and stats.late == 0


def _random_stream(rng: np.random.Generator, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Jitter, duplicates, stragglers and backward jumps."""
    stamps = T0 + MS * np.cumsum(rng.integers(0, 3, n))
    stamps = stamps + rng.integers(-2 * MS, 2 * MS, n) * (rng.random(n) < 0.3)
    stamps[rng.random(n) < 0.02] -= 30 * MS  # stragglers
    for k in rng.integers(0, n, 2):
        stamps[k:] -= int(rng.integers(1500, 4000)) * MS  # backward jumps
    clocks = np.sort(T0 + MS * np.cumsum(rng.integers(0, 3, n)))
    return stamps, clocks


@pytest.mark.parametrize('seed', range(6))
def test_array_and_per_message_forms_agree_however_the_stream_is_cut(seed: int) -> None:
    rng = np.random.default_rng(seed)
    s, c = _random_stream(rng, 3000)
    window = (0.0, 0.002, 0.01, 0.05)[seed % 4]
    ref, ref_stats = run_buffer(s, c, window)
    assert sorted(ref.tolist()) == list(range(len(s)))
    assert ref_stats.backward_jumps >= 1 and (ref_stats.reordered > 0) == (window > 0)
    assert (ref_stats.late > 0) == (window < 0.03)  # the stragglers are 30 ms late
    if window == 0:  # no wait: the arrival order
        np.testing.assert_array_equal(ref, np.arange(len(s)))
    for cuts in ([], list(range(1, len(s))), sorted(rng.integers(1, len(s), 40).tolist())):
        ids, stats = run_batch(s, c, window, cuts)
        assert np.array_equal(ids, ref) and stats == ref_stats


def test_release_lets_messages_out_when_the_stream_pauses() -> None:
    buf: ReorderBuffer[str] = ReorderBuffer(0.005)
    assert buf.push(T0 + 2 * MS, 'b', 0) == []
    assert buf.push(T0 + 1 * MS, 'a', 1 * MS) == []
    assert buf.release(5 * MS - 1) == [] and len(buf) == 2
    assert buf.due_ns() == 5 * MS  # 'b' has waited its window: 'a' goes with it
    assert buf.release(5 * MS) == [(T0 + MS, 'a'), (T0 + 2 * MS, 'b')]
    assert buf.due_ns() is None
    assert buf.push(T0 + 1 * MS, 'late', 7 * MS) == [(T0 + MS, 'late')]
    assert buf.stats == ReorderStats(3, 1, 1, 0, MS)
    buf.push(T0 + 3 * MS, 'c', 8 * MS)
    buf.reset()
    assert len(buf) == 0 and buf.flush() == []


def test_memory_is_one_window() -> None:
    s, c = receipt_jitter(100_000, MS // 2, 3 * MS // 2, 5 * MS // 2, seed=5)
    b = BatchReorder(0.05)
    most = 0
    for k in range(0, len(s), 1000):
        b.push(s[k:k + 1000], c[k:k + 1000])
        most = max(most, len(b.pending_ids), len(b._s))  # noqa: SLF001 - the carried arrays
    assert most <= 1000 + 0.05 / 0.0005 + 10


def test_bad_windows_are_refused() -> None:
    for bad in (-1.0, float('nan'), float('inf')):
        with pytest.raises(ValueError):
            ReorderBuffer(bad)
        with pytest.raises(ValueError):
            BatchReorder(bad)
