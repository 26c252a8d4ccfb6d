"""msg_adapters.cdr and the bag decoder against rosbags' own (de)serialisation, bit for bit.

The codec (one message and many) against ``Typestore.serialize_cdr`` / ``deserialize_cdr``;
the reader (mcap read chunk by chunk, sqlite3 through rosbags) against rosbags' ``Reader``
plus ``deserialize_cdr`` of every message, on bags of our simulator and of the world
simulator (wrapped joints, reversed and shuffled names, an extra joint, no velocities, 2 kHz
with receipt-time log stamps out of header order).
"""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from rosbags.rosbag2 import Reader, StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore

from imu_calib_ros.core.types import ImuBatch, ImuSample, JointBatch, JointSample
from msg_adapters import bag, bag_raw, cdr
from msg_adapters.convert import (IMU_MSGTYPE, JOINT_STATE_MSGTYPE,
                                  ImuCovariances, imu_msg_from_sample,
                                  joint_state_msg_from_sample)

STORE = get_typestore(Stores.ROS2_JAZZY)
ROOT = Path(__file__).resolve().parents[1]


def _bits(x: Any) -> np.ndarray:
    return np.asarray(x, np.float64).view(np.int64)


def _joined(raws: list[bytes]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    lengths = np.array([len(r) for r in raws], np.int64)
    starts = np.concatenate([[0], np.cumsum(lengths)[:-1]]).astype(np.int64)
    return np.frombuffer(b''.join(raws), np.uint8), starts, lengths


# ----------------------------------------------------------------------------- codec
@settings(max_examples=30, deadline=None)
@given(frame_ids=st.lists(st.text(alphabet=st.characters(min_codepoint=32,
                                                         max_codepoint=0x24F), max_size=11),
                          min_size=1, max_size=4),
       stamps=st.lists(st.integers(-(2 ** 31) * 10 ** 9, 2 ** 31 * 10 ** 9 - 1), min_size=1,
                       max_size=6),
       values=st.lists(st.floats(width=64), min_size=6, max_size=6))
def test_imu_codec_one_and_many_equal_rosbags(frame_ids: list[str], stamps: list[int],
                                              values: list[float]) -> None:
    """Pack one (imu_cdr) and many (pack_imu) give rosbags' bytes; decode one
    (imu_fields_from_cdr) and many (decode_imu, mixed frame_id lengths) give rosbags'
    values, bit for bit (NaN payloads included)."""
    cov = ImuCovariances.from_sigmas(1e-3, 2e-2)
    raws, ref = [], []
    for k, t in enumerate(stamps):
        fid = frame_ids[k % len(frame_ids)]
        s = ImuSample(t, np.array(values[:3]), np.array(values[3:]), fid)
        data = bytes(STORE.serialize_cdr(imu_msg_from_sample(s, STORE, cov), IMU_MSGTYPE))
        assert cdr.imu_cdr(t, fid, s.gyro_rad_s, s.accel_m_s2, cov.angular_velocity_rad2_s2,
                           cov.linear_acceleration_m2_s4) == data
        rows = cdr.pack_imu([t], s.gyro_rad_s[None], s.accel_m_s2[None], fid,
                            cov.angular_velocity_rad2_s2, cov.linear_acceleration_m2_s4)
        assert rows[0].tobytes() == data
        stamp, fid1, g, a = cdr.imu_fields_from_cdr(data)
        assert (stamp, fid1) == (t, fid) and _bits(g).tolist() == _bits(values[:3]).tolist()
        raws.append(data)
        ref.append(STORE.deserialize_cdr(data, IMU_MSGTYPE))
    cols = cdr.decode_imu(*_joined(raws))
    assert cols.ok.all()
    for k, m in enumerate(ref):
        assert cols.stamps_ns[k] == m.header.stamp.sec * 10 ** 9 + m.header.stamp.nanosec
        assert cols.frame_ids[cols.frame[k]] == m.header.frame_id
        w, f = m.angular_velocity, m.linear_acceleration
        assert _bits(cols.gyro_rad_s[k]).tolist() == _bits([w.x, w.y, w.z]).tolist()
        assert _bits(cols.accel_m_s2[k]).tolist() == _bits([f.x, f.y, f.z]).tolist()


def test_decode_imu_flags_what_is_not_the_fixed_layout() -> None:
    """Big-endian, cut short, padded, empty or non-UTF-8 frame_id: not ok (rosbags decodes
    those or says what is wrong); the good messages around them still decode."""
    good = cdr.imu_cdr(5, 'imu', (1.0, 2.0, 3.0), (4.0, 5.0, 6.0), np.zeros(9), np.zeros(9))
    bad = [b'\x00\x00' + good[2:], good[:-8], good + b'\x00' * 8, good[:12],
           good[:12] + b'\x00' * 4 + good[16:], good[:16] + b'\xff' + good[17:]]
    cols = cdr.decode_imu(*_joined([good, *bad, good]))
    assert cols.ok.tolist() == [True] + [False] * len(bad) + [True]
    assert cols.frame_ids == ['imu'] and cols.gyro_rad_s[-1].tolist() == [1.0, 2.0, 3.0]


@settings(max_examples=30, deadline=None)
@given(names=st.lists(st.text(alphabet='abcxyz_09ä', min_size=1, max_size=9), min_size=1,
                      max_size=4, unique=True),
       frame_id=st.text(alphabet='abc_/', max_size=7), with_vel=st.booleans(),
       n_eff=st.booleans(), n_msgs=st.integers(1, 4))
def test_joint_state_codec_one_and_many_equal_rosbags(names: list[str], frame_id: str,
                                                      with_vel: bool, n_eff: bool,
                                                      n_msgs: int) -> None:
    rng = np.random.default_rng(len(names) * 7 + n_msgs)
    raws = []
    for k in range(n_msgs):
        pos, vel = rng.normal(size=len(names)), rng.normal(size=len(names))
        eff = rng.normal(size=len(names)) if n_eff else np.zeros(0)
        msg = STORE.types[JOINT_STATE_MSGTYPE](
            header=STORE.types['std_msgs/msg/Header'](
                stamp=STORE.types['builtin_interfaces/msg/Time'](sec=k - 2, nanosec=k * 999),
                frame_id=frame_id),
            name=names, position=pos, velocity=vel if with_vel else np.zeros(0), effort=eff)
        data = bytes(STORE.serialize_cdr(msg, JOINT_STATE_MSGTYPE))
        assert cdr.joint_state_cdr((k - 2) * 10 ** 9 + k * 999, frame_id, names, pos,
                                   vel if with_vel else (), eff) == data
        one = cdr.joint_state_fields_from_cdr(data)
        assert one[:3] == ((k - 2) * 10 ** 9 + k * 999, frame_id, tuple(names))
        assert _bits(one[3]).tolist() == _bits(pos).tolist() and one[5] == len(eff)
        raws.append(data)
    rows = np.frombuffer(b''.join(raws), np.uint8).reshape(n_msgs, -1)
    res = cdr.decode_joint_rows(rows)
    assert res is not None
    for k, data in enumerate(raws):
        m = STORE.deserialize_cdr(data, JOINT_STATE_MSGTYPE)
        assert res[0][k] == m.header.stamp.sec * 10 ** 9 + m.header.stamp.nanosec
        assert res[1] == tuple(m.name)
        assert _bits(res[2][k]).tolist() == _bits(m.position).tolist()
        if with_vel:
            assert res[3] is not None
            assert _bits(res[3][k]).tolist() == _bits(m.velocity).tolist()
        else:
            assert res[3] is None


# ------------------------------------------------------------------ reader vs rosbags
def _rosbags_messages(path: Path) -> dict[str, list[tuple[int, Any]]]:
    """Per topic: (log time, deserialised message), in ``Reader.messages`` order."""
    out: dict[str, list[tuple[int, Any]]] = {}
    with Reader(path) as r:
        for conn, t, raw in r.messages():
            out.setdefault(conn.topic, []).append((t, STORE.deserialize_cdr(raw, conn.msgtype)))
    return out


def _stamp(m: Any) -> int:
    return int(m.header.stamp.sec) * 10 ** 9 + int(m.header.stamp.nanosec)


def _check_against_rosbags(path: Path, window_s: float, imu_topic: str = '/imu/data_raw',
                           joint_topic: str = '/joint_states') -> None:
    """iter_bag_batches (and read_bag) give rosbags' messages: in log order with a zero
    reorder window, in (stamp, log order) with a window wider than the jitter."""
    ref = _rosbags_messages(path)
    imu_ref = [m for _, m in ref[imu_topic]]
    joint_ref = [m for _, m in ref[joint_topic]]
    if window_s > 0:
        imu_ref.sort(key=_stamp)  # stable: equal stamps stay in log order
        joint_ref.sort(key=_stamp)
    batches = list(bag.iter_bag_batches(path, imu_topic, joint_topic, window_msgs=5000,
                                        reorder_window_s=window_s))
    imu = [b for b in batches if isinstance(b, ImuBatch)]
    joints = [b for b in batches if isinstance(b, JointBatch)]
    stamps = np.concatenate([b.stamps_ns for b in imu])
    assert stamps.tolist() == [_stamp(m) for m in imu_ref]
    gyro = np.concatenate([b.gyro_rad_s for b in imu])
    accel = np.concatenate([b.accel_m_s2 for b in imu])
    frames = [b.frame_id for b in imu for _ in range(len(b))]
    assert frames == [m.header.frame_id for m in imu_ref]
    assert np.array_equal(_bits(gyro), _bits([[m.angular_velocity.x, m.angular_velocity.y,
                                              m.angular_velocity.z] for m in imu_ref]))
    assert np.array_equal(_bits(accel), _bits([[m.linear_acceleration.x,
                                               m.linear_acceleration.y,
                                               m.linear_acceleration.z] for m in imu_ref]))
    k = 0
    for b in joints:
        for i in range(len(b)):
            m = joint_ref[k]
            assert b.stamps_ns[i] == _stamp(m) and b.names == tuple(m.name)
            assert _bits(b.positions_rad[i]).tolist() == _bits(m.position).tolist()
            if len(m.velocity):
                assert b.velocities_rad_s is not None
                assert _bits(b.velocities_rad_s[i]).tolist() == _bits(m.velocity).tolist()
            else:
                assert b.velocities_rad_s is None
            k += 1
    assert k == len(joint_ref)
    ib, jb = bag.read_bag(path, imu_topic, joint_topic, reorder_window_s=window_s)
    assert ib.stamps_ns.tolist() == stamps.tolist()
    assert np.array_equal(_bits(ib.gyro_rad_s), _bits(gyro))
    assert jb.stamps_ns.tolist() == [_stamp(m) for m in joint_ref]
    order = [list(joint_ref[0].name).index(n) for n in jb.names]
    assert np.array_equal(_bits(jb.positions_rad),
                          _bits([np.asarray(m.position)[order] for m in joint_ref]))


@pytest.mark.parametrize('storage', ['mcap', 'sqlite3'])
def test_reader_equals_rosbags_on_our_simulator_bag(tmp_path: Path, storage: str) -> None:
    from imu_calib_ros.core.fixture import load_fixture
    from imu_calib_ros.core.imu_grade import load_grade
    from imu_calib_ros.core.plans import build_profile, plan_from_dict
    from imu_calib_ros.core.simulator import SimConfig, simulate
    fx = load_fixture('three_axis')
    plan = plan_from_dict({'name': 't', 'steps': [
        {'dwell': {'duration_s': 1.0}},
        {'move': {'joint': 'outer', 'by_deg': 400.0, 'duration_s': 3.0}},
        {'move': {'joint': 'inner', 'by_deg': -300.0, 'duration_s': 3.0}}]})
    sim = simulate(fx, build_profile(plan, fx), load_grade('mems_mti1'),
                   SimConfig(imu_rate_hz=1000, seed=3, wrap_joint_positions=True))
    path = tmp_path / 'sim'
    bag.write_bag(path, sim.imu, sim.joints, storage=storage)  # type: ignore[arg-type]
    for window in (0.0, 0.5):
        _check_against_rosbags(path, window)


@pytest.mark.parametrize('storage', ['mcap', 'sqlite3'])
@pytest.mark.parametrize('case', ['reversed_no_velocities_2khz_jitter', 'shuffled_wrapped'])
def test_reader_equals_rosbags_on_world_simulator_bags(tmp_path: Path, storage: str,
                                                       case: str) -> None:
    """Another writer (rosbags' message classes), receipt-time log stamps out of header
    order at 2 kHz, names not in fixture order, an extra joint, no velocities, wrapped."""
    from imu_calib_ros.core.plans import plan_from_dict
    from imu_calib_ros.testing.world_sim import (Mounting, WorldConfig, draw_unit,
                                                 fixture_path, joint_profile,
                                                 simulate_to_files)
    fxp = fixture_path('three_axis')
    prof = joint_profile(plan_from_dict({'name': 't', 'steps': [
        {'dwell': {'duration_s': 0.5}},
        {'move': {'joint': 'outer', 'by_deg': 270.0, 'duration_s': 2.0}},
        {'move': {'joint': 'middle', 'by_deg': -200.0, 'duration_s': 1.5}}]}), fxp)
    if case.startswith('reversed'):
        cfg = WorldConfig(imu_rate_hz=2000.0, joint_rate_hz=100.0, joint_order='reversed',
                          extra_joint=True, joint_velocities=False,
                          receipt_delay_s=(0.0015, 0.0025), storage=storage)
    else:
        cfg = WorldConfig(imu_rate_hz=400.0, joint_rate_hz=50.0, joint_order='shuffled',
                          wrap_joints=True, joint_latency_s=0.004, storage=storage)
    unit = draw_unit('consumer_mems', 1.0, np.random.default_rng(5))
    path, _, data = simulate_to_files(tmp_path, fxp, prof, unit, Mounting(), cfg, seed=4)
    ref = _rosbags_messages(path)
    log = np.array([t for t, _ in ref['/imu/data_raw']])
    stamps = np.array([_stamp(m) for _, m in ref['/imu/data_raw']])
    if cfg.receipt_delay_s:
        assert np.all(np.diff(log) >= 0) and np.any(np.diff(stamps) < 0)  # out of order
    for window in (0.0, 0.5):
        _check_against_rosbags(path, window)


def test_mcap_is_read_in_bulk_and_sqlite3_through_rosbags(tmp_path: Path,
                                                          monkeypatch: pytest.MonkeyPatch) -> None:
    """Indexed mcap never goes through Reader.messages (chunks + message index + numpy);
    sqlite3 does."""
    imu = ImuBatch(10 ** 9 + 5_000_000 * np.arange(3000, dtype=np.int64),
                   np.ones((3000, 3)), np.ones((3000, 3)), 'imu_link')
    joints = JointBatch(10 ** 9 + 10_000_000 * np.arange(1500, dtype=np.int64), ('a', 'b'),
                        np.zeros((1500, 2)))
    bag.write_bag(tmp_path / 'm.mcap', imu, joints)
    bag.write_bag(tmp_path / 'm', imu, joints)
    bag.write_bag(tmp_path / 's', imu, joints, storage='sqlite3')
    real = bag_raw.rosbags_windows
    used = []

    def spy(*a: Any, **k: Any) -> Any:
        used.append(a[1])
        return real(*a, **k)
    monkeypatch.setattr(bag_raw, 'rosbags_windows', spy)
    for name in ('m.mcap', 'm', 's'):
        i, j = bag.read_bag(tmp_path / name)
        assert len(i) == 3000 and len(j) == 1500
    assert used == [tmp_path / 's']


def test_mcap_chunks_overlapping_in_log_time_fall_back_to_rosbags_order(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Chunks whose log times overlap (a writer that did not sort): Reader.messages merges
    them, so the reader leaves it to rosbags; the result equals rosbags'."""
    j = JointSample(0, ('a',), np.array([0.5]))
    jdata = bytes(STORE.serialize_cdr(joint_state_msg_from_sample(j, STORE),
                                      JOINT_STATE_MSGTYPE))
    path = tmp_path / 'o'
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as w:
        ci = w.add_connection('/imu/data_raw', IMU_MSGTYPE, typestore=STORE)
        cj = w.add_connection('/joint_states', JOINT_STATE_MSGTYPE, typestore=STORE)
        n = 7000  # > two 1 MiB chunks; the second chunk starts back in log time
        for k in range(n):
            t = k if k < n // 2 else k - n // 3
            w.write(ci, t * 1000, cdr.imu_cdr(t * 1000, 'imu_link', (k, 0.0, 0.0),
                                              (0.0, 0.0, 9.8), np.zeros(9), np.zeros(9)))
            if k % 10 == 0:
                w.write(cj, t * 1000, jdata)
    used = []
    real = bag_raw.rosbags_windows
    monkeypatch.setattr(bag_raw, 'rosbags_windows',
                        lambda *a, **k: used.append(1) or real(*a, **k))
    _check_against_rosbags(path, 0.0)
    assert used


# ----------------------------------------------------------------------------- CLI
def test_help_imports_no_numpy_heavy_module() -> None:
    """``imu-calib --help`` and ``imu-calib replay --help`` print their help without
    importing numpy, scipy, yaml, rosbags, rclpy or the core's numerical modules."""
    code = ('import sys, contextlib, io\n'
            'from imu_calib_ros.cli import main\n'
            'for argv in (["--help"], ["replay", "--help"], ["simulate", "--help"]):\n'
            '    with contextlib.redirect_stdout(io.StringIO()) as out:\n'
            '        try:\n'
            '            main(argv)\n'
            '        except SystemExit:\n'
            '            pass\n'
            '    assert "usage" in out.getvalue(), argv\n'
            'heavy = ("numpy", "scipy", "yaml", "rosbags", "rclpy", "mcap", "yourdfpy",\n'
            '         "imu_calib_ros.core.estimator", "msg_adapters.bag")\n'
            'print(sorted(m for m in sys.modules if m.startswith(heavy)))\n')
    out = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                         timeout=60, cwd=ROOT)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == '[]', out.stdout


@pytest.mark.parametrize('mode', ['STORAGE', 'FILE', 'MESSAGE'])
def test_compressed_bags_equal_rosbags(tmp_path: Path, mode: str,
                                       monkeypatch: pytest.MonkeyPatch) -> None:
    """zstd chunks (STORAGE) and a zstd-compressed file are read chunk by chunk; per-message
    compression goes through Reader.messages; all equal rosbags."""
    from rosbags.rosbag2.enums import CompressionFormat, CompressionMode
    path = tmp_path / mode
    w = Writer(path, version=9, storage_plugin=StoragePlugin.MCAP)
    w.set_compression(getattr(CompressionMode, mode), CompressionFormat.ZSTD)
    with w:
        ci = w.add_connection('/imu/data_raw', IMU_MSGTYPE, typestore=STORE)
        cj = w.add_connection('/joint_states', JOINT_STATE_MSGTYPE, typestore=STORE)
        for k in range(6000):
            t = 10 ** 9 + k * 500_000
            w.write(ci, t, cdr.imu_cdr(t, 'imu_link', (k * 1e-3, 0.5, -0.25), (0.0, 0.1, 9.8),
                                       np.zeros(9), np.zeros(9)))
            if k % 20 == 0:
                w.write(cj, t + 1, cdr.joint_state_cdr(t + 1, '', ('a', 'b'), (k * 1e-2, 0.0),
                                                       (0.1, 0.2)))
    used = []
    real = bag_raw.rosbags_windows
    monkeypatch.setattr(bag_raw, 'rosbags_windows',
                        lambda *a, **k: used.append(1) or real(*a, **k))
    _check_against_rosbags(path, 0.0)
    assert bool(used) == (mode == 'MESSAGE')
