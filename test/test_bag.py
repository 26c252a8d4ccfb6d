"""msg_adapters.bag: ROS 2 bags written and read with rosbags (mcap dir, sqlite3 dir, .mcap).

Round trips are bit-exact; the numpy fast paths equal rosbags' own (de)serialisation; every
unusable bag gives one BagError line; a failed write leaves nothing behind.
"""
from __future__ import annotations

import os
import tracemalloc
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from rosbags.rosbag2 import Reader, StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore

from imu_calib_ros.core.errors import BagError
from imu_calib_ros.core.types import ImuBatch, ImuSample, JointBatch, JointSample
from msg_adapters import bag, cdr
from msg_adapters.convert import (IMU_MSGTYPE, JOINT_STATE_MSGTYPE,
                                  ImuCovariances, imu_msg_from_sample,
                                  joint_state_msg_from_sample)

STORE = get_typestore(Stores.ROS2_JAZZY)
T0_NS = 1_700_000_000 * 10 ** 9 - 7_500_000  # crosses a second boundary within the data
LAYOUTS = [('run', 'mcap'), ('run', 'sqlite3'), ('run.mcap', 'mcap')]


def make_batches(n_imu: int = 400, n_joint: int = 200, seed: int = 1,
                 velocities: bool = True) -> tuple[ImuBatch, JointBatch]:
    """IMU at 200 Hz, joints at 100 Hz offset by 1 ns and sharing some stamps exactly."""
    rng = np.random.default_rng(seed)
    imu_stamps = T0_NS + np.arange(n_imu, dtype=np.int64) * 5_000_000
    joint_stamps = T0_NS + np.arange(n_joint, dtype=np.int64) * 10_000_000
    joint_stamps[1::2] += 1
    # values spanning many binades, with exact ties to shared stamps
    gyro = rng.normal(size=(n_imu, 3)) * 10.0 ** rng.integers(-12, 3, size=(n_imu, 3))
    accel = rng.normal(size=(n_imu, 3)) * 10.0 ** rng.integers(-9, 4, size=(n_imu, 3))
    pos = rng.uniform(-10, 10, size=(n_joint, 3))
    vel = rng.normal(size=(n_joint, 3)) if velocities else None
    return (ImuBatch(imu_stamps, gyro, accel, 'imu_link'),
            JointBatch(joint_stamps, ('outer', 'middle', 'inner_axis'), pos, vel))


def assert_imu_equal(a: ImuBatch, b: ImuBatch) -> None:
    assert a.stamps_ns.dtype == np.int64 and b.stamps_ns.dtype == np.int64
    np.testing.assert_array_equal(a.stamps_ns, b.stamps_ns)
    assert a.gyro_rad_s.dtype == np.float64 == b.gyro_rad_s.dtype
    # bit-exact (view as integers) apart from NaN payloads
    for x, y in ((a.gyro_rad_s, b.gyro_rad_s), (a.accel_m_s2, b.accel_m_s2)):
        assert x.shape == y.shape
        nan = np.isnan(x)
        assert np.array_equal(nan, np.isnan(y))
        assert np.array_equal(x[~nan].view(np.int64), y[~nan].view(np.int64))


def assert_joints_equal(a: JointBatch, b: JointBatch) -> None:
    np.testing.assert_array_equal(a.stamps_ns, b.stamps_ns)
    assert a.names == b.names
    assert np.array_equal(a.positions_rad.view(np.int64), b.positions_rad.view(np.int64))
    if a.velocities_rad_s is None:
        assert b.velocities_rad_s is None
    else:
        assert b.velocities_rad_s is not None
        assert np.array_equal(a.velocities_rad_s, b.velocities_rad_s, equal_nan=True)


@pytest.mark.parametrize('name,storage', LAYOUTS)
def test_round_trip_is_bit_exact(tmp_path: Path, name: str, storage: str) -> None:
    imu, joints = make_batches()
    path = tmp_path / name
    assert bag.write_bag(path, imu, joints, storage=storage) == path  # type: ignore[arg-type]
    assert path.is_file() == (name.endswith('.mcap'))
    assert sorted(os.listdir(tmp_path)) == [name]  # no temporary leftovers
    imu2, joints2 = bag.read_bag(path)
    assert_imu_equal(imu, imu2)
    assert imu2.frame_id == 'imu_link'
    assert_joints_equal(joints, joints2)
    topics = bag.list_topics(path)
    assert topics == {'/imu/data_raw': bag.TopicInfo(IMU_MSGTYPE, len(imu)),
                      '/joint_states': bag.TopicInfo(JOINT_STATE_MSGTYPE, len(joints))}


@pytest.mark.parametrize('name,storage', LAYOUTS)
def test_stream_is_interleaved_in_stamp_order_with_log_time_equal_to_stamp(
        tmp_path: Path, name: str, storage: str) -> None:
    imu, joints = make_batches(60, 30)
    path = tmp_path / name
    bag.write_bag(path, imu, joints, storage=storage)  # type: ignore[arg-type]
    samples = list(bag.iter_bag(path))
    assert len(samples) == 90
    stamps = [s.stamp_ns for s in samples]
    assert stamps == sorted(stamps)
    # IMU first on equal stamps; both kinds present and interleaved
    kinds = ''.join('i' if isinstance(s, ImuSample) else 'j' for s in samples)
    assert kinds.startswith('ijiij') and kinds.count('j') == 30
    with Reader(path) as reader:
        for conn, t_ns, raw in reader.messages():
            msg = STORE.deserialize_cdr(raw, conn.msgtype)
            assert t_ns == msg.header.stamp.sec * 10 ** 9 + msg.header.stamp.nanosec
    # the streamed samples equal the batch read
    imu2 = ImuBatch.from_samples([s for s in samples if isinstance(s, ImuSample)])
    assert_imu_equal(imu, imu2)
    js = [s for s in samples if isinstance(s, JointSample)]
    assert [j.names for j in js] == [joints.names] * 30
    np.testing.assert_array_equal(np.array([j.positions_rad for j in js]), joints.positions_rad)


def test_nan_inf_and_missing_velocities_survive(tmp_path: Path) -> None:
    imu, joints = make_batches(20, 10, velocities=False)
    imu.gyro_rad_s[3] = [np.nan, np.inf, -np.inf]
    joints.positions_rad[2, 1] = np.nan
    bag.write_bag(tmp_path / 'b.mcap', imu, joints)
    imu2, joints2 = bag.read_bag(tmp_path / 'b.mcap')
    assert_imu_equal(imu, imu2)
    assert joints2.velocities_rad_s is None and np.isnan(joints2.positions_rad[2, 1])
    js = [s for s in bag.iter_bag(tmp_path / 'b.mcap') if isinstance(s, JointSample)]
    assert all(j.velocities_rad_s is None for j in js)


@settings(max_examples=40, deadline=None)
@given(frame_id=st.text(alphabet=st.characters(min_codepoint=33, max_codepoint=0x24F),
                        max_size=17),
       stamp=st.integers(-(2 ** 31) * 10 ** 9, 2 ** 31 * 10 ** 9 - 1),
       values=st.lists(st.floats(width=64), min_size=6, max_size=6),
       cov=st.lists(st.floats(allow_nan=False, width=64), min_size=18, max_size=18))
def test_numpy_imu_packer_gives_rosbags_bytes(frame_id: str, stamp: int, values: list[float],
                                              cov: list[float]) -> None:
    """Every frame_id length (all paddings), stamp sign and value: same bytes as rosbags."""
    covs = ImuCovariances(np.array(cov[:9]), np.array(cov[9:]))
    batch = ImuBatch(np.array([stamp], np.int64), np.array([values[:3]]),
                     np.array([values[3:]]), frame_id)
    rows = cdr.pack_imu(batch.stamps_ns, batch.gyro_rad_s, batch.accel_m_s2, frame_id,
                        covs.angular_velocity_rad2_s2, covs.linear_acceleration_m2_s4)
    ref = STORE.serialize_cdr(imu_msg_from_sample(batch.sample(0), STORE, covs), IMU_MSGTYPE)
    assert bytes(rows[0]) == bytes(ref)
    back = cdr.decode_imu(rows.reshape(-1), [0], [rows.shape[1]])
    assert back.ok.all() and back.frame_ids == [frame_id]
    assert_imu_equal(batch, ImuBatch(back.stamps_ns, back.gyro_rad_s, back.accel_m_s2))


@settings(max_examples=40, deadline=None)
@given(names=st.lists(st.text(alphabet='abcxyz_09', min_size=1, max_size=9), min_size=1,
                      max_size=4, unique=True),
       frame_id=st.text(alphabet='abc_/', max_size=7), with_vel=st.booleans(),
       n_msgs=st.integers(1, 4))
def test_numpy_joint_decoder_matches_rosbags(names: list[str], frame_id: str, with_vel: bool,
                                             n_msgs: int) -> None:
    rng = np.random.default_rng(len(names) + n_msgs)
    samples = [JointSample(k * 7_000_000_001, tuple(names), rng.normal(size=len(names)),
                           rng.normal(size=len(names)) if with_vel else None)
               for k in range(n_msgs)]
    raws = [bytes(STORE.serialize_cdr(joint_state_msg_from_sample(s, STORE, frame_id),
                                      JOINT_STATE_MSGTYPE)) for s in samples]
    assert raws[0] == cdr.joint_state_cdr(samples[0].stamp_ns, frame_id, names,
                                          samples[0].positions_rad,
                                          () if not with_vel else samples[0].velocities_rad_s)
    rows = np.frombuffer(b''.join(raws), np.uint8).reshape(n_msgs, -1)
    res = cdr.decode_joint_rows(rows)
    assert res is not None, 'fast path not taken for a fixed layout'
    batch = JointBatch(*res)
    np.testing.assert_array_equal(batch.stamps_ns, [s.stamp_ns for s in samples])
    np.testing.assert_array_equal(batch.positions_rad, [s.positions_rad for s in samples])
    if with_vel:
        np.testing.assert_array_equal(batch.velocities_rad_s,
                                      [s.velocities_rad_s for s in samples])
    else:
        assert batch.velocities_rad_s is None


def test_fast_and_slow_read_paths_agree(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    imu, joints = make_batches(300, 150)
    bag.write_bag(tmp_path / 'a', imu, joints)
    calls = {'imu': 0, 'joint': 0}
    real_imu, real_joint = cdr.decode_imu, cdr.decode_joint_rows

    def spy_imu(buf, starts, lengths):  # type: ignore[no-untyped-def]
        calls['imu'] += 1
        out = real_imu(buf, starts, lengths)
        assert out.ok.all()
        return out

    def spy_joint(rows):  # type: ignore[no-untyped-def]
        calls['joint'] += 1
        out = real_joint(rows)
        assert out is not None
        return out

    def none_ok(buf, starts, lengths):  # type: ignore[no-untyped-def]
        out = real_imu(buf, starts, lengths)
        out.ok[:] = False
        return out
    monkeypatch.setattr(cdr, 'decode_imu', spy_imu)
    monkeypatch.setattr(cdr, 'decode_joint_rows', spy_joint)
    fast = bag.read_bag(tmp_path / 'a')
    assert calls == {'imu': 1, 'joint': 1}
    monkeypatch.setattr(cdr, 'decode_imu', none_ok)
    monkeypatch.setattr(cdr, 'decode_joint_rows', lambda rows: None)
    slow = bag.read_bag(tmp_path / 'a')
    assert_imu_equal(fast[0], slow[0])
    assert_joints_equal(fast[1], slow[1])
    assert_imu_equal(imu, slow[0])


def _write_raw_bag(path: Path, msgs: list[tuple[str, str, int, object]],
                   storage: StoragePlugin = StoragePlugin.MCAP,
                   topics: dict[str, str] | None = None) -> None:
    """A bag written directly with rosbags (for inputs our writer never produces)."""
    with Writer(path, version=9, storage_plugin=storage) as w:
        conns = {}
        for topic, msgtype in (topics or {}).items():
            conns[topic] = w.add_connection(topic, msgtype, typestore=STORE)
        for topic, msgtype, t_ns, msg in msgs:
            if topic not in conns:
                conns[topic] = w.add_connection(topic, msgtype, typestore=STORE)
            w.write(conns[topic], t_ns, STORE.serialize_cdr(msg, msgtype))


def test_mixed_frame_ids_and_permuted_joint_names_use_the_general_path(tmp_path: Path) -> None:
    s1 = ImuSample(1000, np.array([1.0, 2, 3]), np.array([4.0, 5, 6]), 'a')
    s2 = ImuSample(2000, np.array([7.0, 8, 9]), np.array([1.0, 2, 3]), 'longer_frame')
    j1 = JointSample(1500, ('x', 'y'), np.array([0.1, 0.2]), None)
    j2 = JointSample(2500, ('y', 'x'), np.array([0.4, 0.3]), np.array([2.0, 1.0]))
    _write_raw_bag(tmp_path / 'm', [
        ('/imu/data_raw', IMU_MSGTYPE, 1000, imu_msg_from_sample(s1, STORE)),
        ('/joint_states', JOINT_STATE_MSGTYPE, 1500, joint_state_msg_from_sample(j1, STORE)),
        ('/imu/data_raw', IMU_MSGTYPE, 2000, imu_msg_from_sample(s2, STORE)),
        ('/joint_states', JOINT_STATE_MSGTYPE, 2500, joint_state_msg_from_sample(j2, STORE))])
    imu, joints = bag.read_bag(tmp_path / 'm')
    np.testing.assert_array_equal(imu.gyro_rad_s, [[1, 2, 3], [7, 8, 9]])
    assert joints.names == ('x', 'y')
    np.testing.assert_array_equal(joints.positions_rad, [[0.1, 0.2], [0.3, 0.4]])
    assert joints.velocities_rad_s is not None
    np.testing.assert_array_equal(joints.velocities_rad_s, [[np.nan, np.nan], [1.0, 2.0]])


@pytest.mark.parametrize('chunk', [1, 7, 64])
def test_chunked_read_equals_whole_read(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                        chunk: int) -> None:
    """read_bag decodes in chunks (bounded raw bytes): any chunk size gives the same batches,
    also when joint messages switch name order and velocity presence between chunks."""
    imu, joints = make_batches(150, 75)
    msgs = [('/imu/data_raw', IMU_MSGTYPE, int(s.stamp_ns), imu_msg_from_sample(s, STORE))
            for s in imu]
    for k, s in enumerate(joints):
        if k >= 40:  # permuted names, no velocities
            s = JointSample(s.stamp_ns, s.names[::-1], s.positions_rad[::-1], None)
        msgs.append(('/joint_states', JOINT_STATE_MSGTYPE, int(s.stamp_ns),
                     joint_state_msg_from_sample(s, STORE)))
    msgs.sort(key=lambda m: m[2])
    _write_raw_bag(tmp_path / 'p', msgs)
    whole = bag.read_bag(tmp_path / 'p')
    monkeypatch.setattr(bag, 'READ_WINDOW_MSGS', chunk)
    parts = bag.read_bag(tmp_path / 'p')
    assert_imu_equal(imu, whole[0])
    assert_imu_equal(imu, parts[0])
    for got in (whole[1], parts[1]):
        assert got.names == joints.names
        assert np.array_equal(got.positions_rad, joints.positions_rad)
        assert got.velocities_rad_s is not None and joints.velocities_rad_s is not None
        assert np.array_equal(got.velocities_rad_s[:40], joints.velocities_rad_s[:40])
        assert np.all(np.isnan(got.velocities_rad_s[40:]))


def test_changing_joint_set_is_an_error(tmp_path: Path) -> None:
    """Sets of joint names that no instant merges into one sample (session 20 merges those
    that do, ``test_joint_merge.py``): the change is named."""
    j1 = JointSample(1, ('x', 'y'), np.array([0.1, 0.2]))
    j2 = JointSample(2, ('x', 'z'), np.array([0.1, 0.2]))
    s = ImuSample(1, np.zeros(3), np.zeros(3), 'i')
    _write_raw_bag(tmp_path / 'm', [
        ('/imu/data_raw', IMU_MSGTYPE, 1, imu_msg_from_sample(s, STORE)),
        ('/joint_states', JOINT_STATE_MSGTYPE, 1, joint_state_msg_from_sample(j1, STORE)),
        ('/joint_states', JOINT_STATE_MSGTYPE, 2, joint_state_msg_from_sample(j2, STORE))])
    with pytest.raises(BagError, match=r"joint names on '/joint_states' change at stamp 2 ns"):
        bag.read_bag(tmp_path / 'm')


# ------------------------------------------------------------------ errors, one line each

def _one_line(exc: pytest.ExceptionInfo[BagError]) -> str:
    text = str(exc.value)
    assert '\n' not in text and text
    return text


def test_missing_path(tmp_path: Path) -> None:
    with pytest.raises(BagError) as exc:
        bag.read_bag(tmp_path / 'nope')
    assert 'no such bag' in _one_line(exc) and 'nope' in str(exc.value)


@pytest.mark.parametrize('make', ['dir', 'txt', 'fake_mcap'])
def test_not_a_bag(tmp_path: Path, make: str) -> None:
    if make == 'dir':
        p = tmp_path / 'd'
        p.mkdir()
        match = 'without metadata.yaml'
    elif make == 'txt':
        p = tmp_path / 'x.txt'
        p.write_text('hello')
        match = 'not a ROS 2 bag'
    else:
        p = tmp_path / 'x.mcap'
        p.write_bytes(b'this is not mcap at all' * 10)
        match = 'cannot open bag'
    with pytest.raises(BagError, match=match) as exc:
        list(bag.iter_bag(p))
    _one_line(exc)


@pytest.mark.parametrize('storage', [StoragePlugin.MCAP, StoragePlugin.SQLITE3])
def test_empty_bag(tmp_path: Path, storage: StoragePlugin) -> None:
    _write_raw_bag(tmp_path / 'e', [], storage,
                   topics={'/imu/data_raw': IMU_MSGTYPE, '/joint_states': JOINT_STATE_MSGTYPE})
    with pytest.raises(BagError, match='bag is empty') as exc:
        bag.read_bag(tmp_path / 'e')
    _one_line(exc)


def test_missing_topic_names_the_topics_that_exist(tmp_path: Path) -> None:
    imu, joints = make_batches(10, 5)
    bag.write_bag(tmp_path / 'b', imu, joints, imu_topic='/imu/raw')
    with pytest.raises(BagError) as exc:
        bag.read_bag(tmp_path / 'b')
    text = _one_line(exc)
    assert "no topic '/imu/data_raw'" in text
    assert '/imu/raw (sensor_msgs/msg/Imu, 10 msgs)' in text and '/joint_states' in text
    imu2, _ = bag.read_bag(tmp_path / 'b', imu_topic='/imu/raw')
    assert len(imu2) == 10


def test_wrong_message_type(tmp_path: Path) -> None:
    String = STORE.types['std_msgs/msg/String']
    j = JointSample(1, ('x',), np.array([0.0]))
    _write_raw_bag(tmp_path / 'w', [
        ('/imu/data_raw', 'std_msgs/msg/String', 1, String(data='hi')),
        ('/joint_states', JOINT_STATE_MSGTYPE, 1, joint_state_msg_from_sample(j, STORE))])
    with pytest.raises(BagError) as exc:
        bag.read_bag(tmp_path / 'w')
    assert "'/imu/data_raw' has type std_msgs/msg/String, expected sensor_msgs/msg/Imu" in \
        _one_line(exc)


@pytest.mark.parametrize('name,storage', LAYOUTS)
def test_truncated_bag(tmp_path: Path, name: str, storage: str) -> None:
    imu, joints = make_batches(3000, 1500)
    path = tmp_path / name
    bag.write_bag(path, imu, joints, storage=storage)  # type: ignore[arg-type]
    data_file = path if path.is_file() else next(f for f in path.iterdir()
                                                 if f.name != 'metadata.yaml')
    size = data_file.stat().st_size
    with open(data_file, 'r+b') as f:
        f.truncate(size // 2)
    with pytest.raises(BagError, match='truncated or corrupt') as exc:
        bag.read_bag(path)
    _one_line(exc)
    with pytest.raises(BagError, match='truncated or corrupt'):
        for _ in bag.iter_bag(path):
            pass


def test_corrupt_chunk_inside_mcap(tmp_path: Path) -> None:
    """Damaged records in the middle of the data are caught, not decoded as garbage.

    rosbags writes mcap chunks without a CRC, so damage confined to a float payload cannot be
    detected by any reader; 4 KiB of 0xFF always hits record headers (messages are ~350 B).
    """
    imu, joints = make_batches(6000, 3000)
    path = tmp_path / 'c.mcap'
    bag.write_bag(path, imu, joints)
    data = bytearray(path.read_bytes())
    mid = len(data) // 3
    data[mid:mid + 4096] = b'\xff' * 4096
    path.write_bytes(bytes(data))
    with pytest.raises(BagError, match='corrupt') as exc:
        bag.read_bag(path)
    _one_line(exc)


# ------------------------------------------------------------------ writing

def test_write_refuses_existing_and_overwrites_only_when_asked(tmp_path: Path) -> None:
    imu, joints = make_batches(10, 5)
    bag.write_bag(tmp_path / 'b', imu, joints)
    with pytest.raises(BagError, match='exists already'):
        bag.write_bag(tmp_path / 'b', imu, joints)
    imu.gyro_rad_s[:] = 42.0
    bag.write_bag(tmp_path / 'b', imu, joints, storage='sqlite3', overwrite=True)
    assert np.all(bag.read_bag(tmp_path / 'b')[0].gyro_rad_s == 42.0)
    assert sorted(os.listdir(tmp_path)) == ['b']


def test_failed_write_leaves_nothing(tmp_path: Path) -> None:
    imu, joints = make_batches(10, 5)
    imu.stamps_ns[-1] = 2 ** 62  # does not fit int32 seconds
    with pytest.raises(BagError, match='int32'):
        bag.write_bag(tmp_path / 'x.mcap', imu, joints)
    with pytest.raises(BagError, match='needs storage mcap'):
        bag.write_bag(tmp_path / 'y.mcap', imu, joints, storage='sqlite3')
    with pytest.raises(BagError, match='does not exist'):
        bag.write_bag(tmp_path / 'no' / 'z', imu, joints)

    def boom(n: int) -> None:
        raise RuntimeError('disk full')
    imu, joints = make_batches(20000, 10)
    with pytest.raises(BagError, match='disk full'):
        bag.write_bag(tmp_path / 'w', imu, joints, progress=boom)
    assert os.listdir(tmp_path) == []


def _iter_peak_bytes(path: Path) -> tuple[int, int]:
    it = bag.iter_bag(path)
    next(it)  # open, typestore etc. before measuring
    tracemalloc.start()
    n = 1 + sum(1 for _ in it)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    return n, peak


def test_iter_bag_memory_is_bounded(tmp_path: Path) -> None:
    """Streaming a 6x longer bag needs about the same memory (a window, not the bag)."""
    sizes = {}
    for n_imu in (6000, 36000):
        imu, joints = make_batches(n_imu, n_imu // 3)
        path = tmp_path / f'{n_imu}.mcap'
        bag.write_bag(path, imu, joints)
        n, peak = _iter_peak_bytes(path)
        assert n == n_imu + n_imu // 3
        sizes[n_imu] = (peak, path.stat().st_size)
    (peak_s, size_s), (peak_l, size_l) = sizes[6000], sizes[36000]
    assert size_l > 5.9 * size_s
    # the window is one 1 MiB mcap chunk plus iter_bag's 2048-message decode window; rosbags
    # keeps a small per-chunk index (measured: 3.7 MB peak at 2.6 MB, 4.9 MB at 23 MB)
    assert peak_l < 1.5 * peak_s, sizes
    assert peak_l < size_l / 3, sizes


def _flatten(batches: list) -> tuple[list, list, list]:
    """(IMU samples, joint samples, kinds per batch) of a batch stream."""
    imu, joints, kinds = [], [], []
    for b in batches:
        kinds.append('i' if isinstance(b, ImuBatch) else 'j')
        (imu if isinstance(b, ImuBatch) else joints).extend(list(b))
    return imu, joints, kinds


@pytest.mark.parametrize('window', [1, 50, 100000])
def test_batches_carry_the_samples_of_iter_bag(tmp_path: Path, window: int) -> None:
    """iter_bag_batches: the same samples as iter_bag, per topic in order; per window the
    joint states first, so no joint state comes after an IMU sample stamped later."""
    imu, joints = make_batches(300, 150)
    path = tmp_path / 'b.mcap'
    bag.write_bag(path, imu, joints)
    samples = list(bag.iter_bag(path))
    batches = list(bag.iter_bag(path).batches(window))
    got_i, got_j, kinds = _flatten(batches)
    assert_imu_equal(imu, ImuBatch.from_samples(got_i))
    assert all(b.frame_id == 'imu_link' for b in batches if isinstance(b, ImuBatch))
    ref_j = [s for s in samples if isinstance(s, JointSample)]
    assert [j.stamp_ns for j in got_j] == [j.stamp_ns for j in ref_j]
    np.testing.assert_array_equal([j.positions_rad for j in got_j], joints.positions_rad)
    n_windows = -(-450 // window)
    # per window a joint and an IMU batch at most, and at the end what the reorder window held
    assert len(batches) <= 2 * n_windows + 2 and kinds[0] == 'j'
    # joints never late, whatever the window: every joint stamp is pushed before any later
    # IMU stamp (IMU samples wait for the joint states stamped before them)
    seen_imu_max = -1
    for b in batches:
        if isinstance(b, JointBatch):
            assert int(b.stamps_ns.min()) > seen_imu_max
        else:
            seen_imu_max = max(seen_imu_max, int(b.stamps_ns.max()))


def test_batches_general_path_keeps_names_and_frame_ids(tmp_path: Path) -> None:
    """Mixed frame_ids / permuted or foreign joint names: runs, each with its own names."""
    s1 = ImuSample(1000, np.array([1.0, 2, 3]), np.array([4.0, 5, 6]), 'a')
    s2 = ImuSample(2000, np.array([7.0, 8, 9]), np.array([1.0, 2, 3]), 'longer_frame')
    j1 = JointSample(1500, ('x', 'y'), np.array([0.1, 0.2]), None)
    j2 = JointSample(2500, ('y', 'x'), np.array([0.4, 0.3]), np.array([2.0, 1.0]))
    j3 = JointSample(2600, ('y', 'x'), np.array([0.5, 0.3]), np.array([2.0, 1.0]))
    _write_raw_bag(tmp_path / 'm', [
        ('/imu/data_raw', IMU_MSGTYPE, 1000, imu_msg_from_sample(s1, STORE)),
        ('/joint_states', JOINT_STATE_MSGTYPE, 1500, joint_state_msg_from_sample(j1, STORE)),
        ('/imu/data_raw', IMU_MSGTYPE, 2000, imu_msg_from_sample(s2, STORE)),
        ('/joint_states', JOINT_STATE_MSGTYPE, 2500, joint_state_msg_from_sample(j2, STORE)),
        ('/joint_states', JOINT_STATE_MSGTYPE, 2600, joint_state_msg_from_sample(j3, STORE))])
    batches = list(bag.iter_bag_batches(tmp_path / 'm'))
    assert [type(b).__name__ for b in batches] == ['JointBatch', 'JointBatch', 'ImuBatch',
                                                   'ImuBatch']
    assert batches[0].names == ('x', 'y') and batches[1].names == ('y', 'x')
    np.testing.assert_array_equal(batches[1].positions_rad, [[0.4, 0.3], [0.5, 0.3]])
    np.testing.assert_array_equal(batches[1].stamps_ns, [2500, 2600])
    assert [b.frame_id for b in batches[2:]] == ['a', 'longer_frame']
    np.testing.assert_array_equal(batches[3].gyro_rad_s, [[7.0, 8, 9]])


def test_batches_errors_as_iter_bag(tmp_path: Path) -> None:
    imu, joints = make_batches(3000, 1500)
    path = tmp_path / 'c.mcap'
    bag.write_bag(path, imu, joints)
    with pytest.raises(BagError, match="no topic '/nope'"):
        list(bag.iter_bag_batches(path, joint_topic='/nope'))
    with open(path, 'r+b') as f:
        f.truncate(path.stat().st_size // 2)
    with pytest.raises(BagError, match='truncated or corrupt'):
        list(bag.iter_bag_batches(path))


def test_batches_memory_is_bounded(tmp_path: Path) -> None:
    """A 6x longer bag streams as batches in about the same memory (one window)."""
    peaks = {}
    for n_imu in (6000, 36000):
        imu, joints = make_batches(n_imu, n_imu // 3)
        path = tmp_path / f'{n_imu}.mcap'
        bag.write_bag(path, imu, joints)
        it = bag.iter_bag_batches(path, window_msgs=2048)
        next(it)
        tracemalloc.start()
        n = sum(len(b) for b in it)
        peaks[n_imu] = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
        assert n > 0.9 * (n_imu + n_imu // 3)
    assert peaks[36000] < 1.5 * peaks[6000], peaks
