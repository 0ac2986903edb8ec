"""Bag reading/writing: round trips, stored definitions, set-aside messages, typed bag errors."""

from __future__ import annotations

import json
import shutil
import sys
from pathlib import Path

import numpy as np
import pytest
from rosbags.highlevel import AnyReader

from galvo_sysid.errors import InvalidDataError
from galvo_sysid.field.bags import (
    CURRENT_TOPIC,
    ENCODER_TOPIC,
    BagError,
    BagExistsError,
    BagNotFoundError,
    BagReader,
    BagWriter,
    CorruptBagError,
    NoGalvoTopicsError,
    SetAside,
    WrongTopicTypeError,
    galvo_typestore,
    msg_search_dirs,
    stamp_to_ns,
)
from galvo_sysid.interfaces.topics import MOVE_SAMPLES
from galvo_sysid.monitor.moves import MoveHalf

PERIOD = 1e-5


def _records(n_moves: int, n: int = 64, seed: int = 0) -> list[tuple[int, float, float, np.ndarray,
                                                                       np.ndarray]]:
    rng = np.random.default_rng(seed)
    out = []
    for i in range(n_moves):
        angle = 0.3 if i % 2 == 0 else -0.3
        out.append((i, 0.25 + 0.006 * i, angle, rng.normal(size=n), rng.normal(size=n)))
    return out


def _write(path: Path, records: list, *, storage: str = 'mcap', prefix: str = '',
           compress: bool = True) -> Path:
    with BagWriter(path, storage=storage, compress=compress) as bag:
        bag.add_topic(prefix + CURRENT_TOPIC, MOVE_SAMPLES)
        bag.add_topic(prefix + ENCODER_TOPIC, MOVE_SAMPLES)
        for mid, stamp, angle, cur, enc in records:
            for topic, data in ((CURRENT_TOPIC, cur), (ENCODER_TOPIC, enc)):
                msg = bag.move_samples(stamp=stamp, move_id=mid, target_angle=angle,
                                       sample_period=PERIOD, data=data)
                bag.write(prefix + topic, stamp_to_ns(stamp), msg)
    return path


@pytest.mark.parametrize('storage', ['mcap', 'sqlite3'])
def test_round_trip_both_storages(tmp_path: Path, storage: str) -> None:
    records = _records(6)
    bag = _write(tmp_path / 'bag', records, storage=storage)
    with BagReader(bag) as reader:
        info = reader.info
        assert info.storage == storage
        assert info.message_count == 12
        assert {t.topic: t.count for t in info.topics} == {CURRENT_TOPIC: 6, ENCODER_TOPIC: 6}
        assert info.start == stamp_to_ns(records[0][1])
        assert info.end == stamp_to_ns(records[-1][1])
        halves = list(reader.move_halves())
    assert all(isinstance(h, MoveHalf) for h in halves)
    by_key = {(h.move_id, h.signal): h for h in halves if isinstance(h, MoveHalf)}
    for mid, stamp, angle, cur, enc in records:
        c, e = by_key[mid, 'current'], by_key[mid, 'encoder']
        np.testing.assert_array_equal(c.data, cur)
        np.testing.assert_array_equal(e.data, enc)
        assert c.stamp == pytest.approx(stamp, abs=1e-9)
        assert c.target_angle == angle
        assert c.sample_period == PERIOD


def test_plain_rosbags_reader_needs_no_registered_types(tmp_path: Path) -> None:
    records = _records(3)
    bag = _write(tmp_path / 'bag', records)
    # AnyReader without a default typestore: decodable only through the stored definitions
    with AnyReader([bag]) as reader:
        conns = {c.topic: c for c in reader.connections}
        assert conns[CURRENT_TOPIC].msgtype == MOVE_SAMPLES
        assert 'float64[] data' in conns[CURRENT_TOPIC].msgdef.data
        decoded = [reader.deserialize(raw, c.msgtype) for c, _, raw in reader.messages()]
    assert len(decoded) == 6
    first = decoded[0]
    assert first.move_id == 0  # type: ignore[attr-defined]
    np.testing.assert_array_equal(first.data, records[0][3])  # type: ignore[attr-defined]


def test_sqlite_single_file_and_metadata_path(tmp_path: Path) -> None:
    bag = _write(tmp_path / 'bag', _records(2), storage='sqlite3')
    db3 = next(bag.glob('*.db3'))
    for path in (db3, bag / 'metadata.yaml'):
        with BagReader(path) as reader:
            assert sum(1 for _ in reader.raw_messages()) == 4


def test_stored_bytes_decode_with_rclpy(tmp_path: Path) -> None:
    from galvo_sysid_msgs.msg import MoveSamples
    from rclpy.serialization import deserialize_message

    records = _records(2)
    bag = _write(tmp_path / 'bag', records)
    with BagReader(bag) as reader:
        raw = next(iter(reader.raw_messages([ENCODER_TOPIC])))
    msg = deserialize_message(raw.data, MoveSamples)
    assert msg.move_id == 0
    assert msg.target_angle == 0.3
    np.testing.assert_array_equal(np.asarray(msg.data), records[0][4])


def test_type_hash_matches_rosidl() -> None:
    installed = Path(sys.prefix) / 'share' / 'galvo_sysid_msgs' / 'msg' / 'MoveSamples.json'
    if not installed.exists():
        pytest.skip('galvo_sysid_msgs not installed in this prefix')
    hashes = json.loads(installed.read_text())['type_hashes']
    expected = next(h['hash_string'] for h in hashes if h['type_name'] == MOVE_SAMPLES)
    assert galvo_typestore().hash_rihs01(MOVE_SAMPLES) == expected


def test_definitions_found_in_source_tree() -> None:
    repo_defs = Path(__file__).resolve().parents[2] / 'msg_defs' / 'msg'
    assert repo_defs in msg_search_dirs()


def test_mcap_is_compressed(tmp_path: Path) -> None:
    records = [(i, 0.1 * i, 0.3, np.zeros(512), np.ones(512)) for i in range(20)]
    small = _write(tmp_path / 'z', records)
    big = _write(tmp_path / 'plain', records, compress=False)
    size = sum(p.stat().st_size for p in small.glob('*.mcap'))
    plain = sum(p.stat().st_size for p in big.glob('*.mcap'))
    assert size < plain / 5


def test_undecodable_message_is_set_aside(tmp_path: Path) -> None:
    path = tmp_path / 'bag'
    with BagWriter(path) as bag:
        bag.add_topic(CURRENT_TOPIC, MOVE_SAMPLES)
        bag.add_topic(ENCODER_TOPIC, MOVE_SAMPLES)
        good = bag.move_samples(stamp=1.0, move_id=7, target_angle=0.3, sample_period=PERIOD,
                                data=np.arange(4.0))
        bag.write(CURRENT_TOPIC, 1_000_000_000, good)
        bag.write_raw(ENCODER_TOPIC, 1_000_000_001, b'\x00\x01\x00\x00garbage')
    with BagReader(path) as reader:
        items = list(reader.move_halves())
    assert isinstance(items[0], MoveHalf)
    assert isinstance(items[1], SetAside)
    assert items[1].topic == ENCODER_TOPIC
    assert 'undecodable' in items[1].reason
    assert items[1].to_dict()['move_id'] is None


def test_missing_bag(tmp_path: Path) -> None:
    with pytest.raises(BagNotFoundError, match='not found'), BagReader(tmp_path / 'nope'):
        pass


def test_directory_that_is_not_a_bag(tmp_path: Path) -> None:
    (tmp_path / 'x.txt').write_text('hello')
    with pytest.raises(CorruptBagError, match='not a rosbag2 bag'), BagReader(tmp_path):
        pass


@pytest.mark.parametrize('storage', ['mcap', 'sqlite3'])
def test_truncated_bag(tmp_path: Path, storage: str) -> None:
    bag = _write(tmp_path / 'bag', _records(40, n=512), storage=storage)
    data = next(p for p in bag.iterdir() if p.suffix in {'.mcap', '.db3'})
    size = data.stat().st_size
    with data.open('r+b') as f:
        f.truncate(size // 2)
    with pytest.raises(CorruptBagError) as info, BagReader(bag) as reader:
        for _ in reader.raw_messages():
            pass
    assert str(bag) in str(info.value)
    assert '\n' not in str(info.value)


def test_corrupt_bag(tmp_path: Path) -> None:
    bag = _write(tmp_path / 'bag', _records(4))
    data = next(bag.glob('*.mcap'))
    data.write_bytes(np.random.default_rng(1).bytes(data.stat().st_size))
    with pytest.raises(CorruptBagError), BagReader(bag) as reader:
        list(reader.raw_messages())


def test_broken_metadata(tmp_path: Path) -> None:
    bag = _write(tmp_path / 'bag', _records(2))
    (bag / 'metadata.yaml').write_text('rosbag2_bagfile_information: {version: 9}\n')
    with pytest.raises(CorruptBagError, match='cannot read bag'), BagReader(bag):
        pass


def test_no_galvo_topics(tmp_path: Path) -> None:
    path = tmp_path / 'bag'
    with BagWriter(path) as bag:
        bag.add_topic('/chatter', 'std_msgs/msg/String')
        msg = bag.typestore.types['std_msgs/msg/String'](data='hi')
        bag.write('/chatter', 1, msg)
    with BagReader(path) as reader, pytest.raises(NoGalvoTopicsError, match='/chatter'):
        reader.galvo_topics()


def test_only_one_galvo_topic(tmp_path: Path) -> None:
    path = tmp_path / 'bag'
    with BagWriter(path) as bag:
        bag.add_topic(CURRENT_TOPIC, MOVE_SAMPLES)
    with BagReader(path) as reader, pytest.raises(NoGalvoTopicsError, match='encoder'):
        reader.galvo_topics()


def test_wrong_topic_type(tmp_path: Path) -> None:
    path = tmp_path / 'bag'
    with BagWriter(path) as bag:
        bag.add_topic(CURRENT_TOPIC, 'std_msgs/msg/Float64MultiArray')
        bag.add_topic(ENCODER_TOPIC, MOVE_SAMPLES)
    with BagReader(path) as reader, pytest.raises(WrongTopicTypeError,
                                                  match='Float64MultiArray'):
        reader.galvo_topics()


def test_namespaces(tmp_path: Path) -> None:
    path = tmp_path / 'bag'
    with BagWriter(path) as bag:
        for ns in ('/left', '/right'):
            bag.add_topic(ns + CURRENT_TOPIC, MOVE_SAMPLES)
            bag.add_topic(ns + ENCODER_TOPIC, MOVE_SAMPLES)
    with BagReader(path) as reader:
        with pytest.raises(BagError, match='several scanners'):
            reader.galvo_topics()
        assert reader.galvo_topics(namespace='right') == ('/right/galvo/current',
                                                          '/right/galvo/encoder')
        with pytest.raises(NoGalvoTopicsError):
            reader.galvo_topics(namespace='/middle')


def test_writer_never_overwrites(tmp_path: Path) -> None:
    (tmp_path / 'bag').mkdir()
    with pytest.raises(BagExistsError):
        BagWriter(tmp_path / 'bag')


def test_writer_errors(tmp_path: Path) -> None:
    with pytest.raises(BagError, match='storage'):
        BagWriter(tmp_path / 'a', storage='rosbag1')
    with BagWriter(tmp_path / 'b') as bag:
        with pytest.raises(BagError, match='no message definition'):
            bag.add_topic('/x', 'nonexistent_pkg/msg/Thing')
        with pytest.raises(BagError, match='not added'):
            bag.write_raw('/y', 0, b'')


def test_bag_errors_are_invalid_data() -> None:
    assert issubclass(BagError, InvalidDataError)


def test_copied_bag_reads_the_same(tmp_path: Path) -> None:
    bag = _write(tmp_path / 'bag', _records(3))
    copy = tmp_path / 'copy'
    shutil.copytree(bag, copy)
    with BagReader(bag) as a, BagReader(copy) as b:
        assert [r.data for r in a.raw_messages()] == [r.data for r in b.raw_messages()]


def test_bag_without_stored_definitions_uses_ours(tmp_path: Path) -> None:
    import sqlite3

    records = _records(2)
    bag = _write(tmp_path / 'old', records, storage='sqlite3')
    db = sqlite3.connect(next(bag.glob('*.db3')))
    with db:  # what a bag recorded before message definitions were stored looks like
        db.execute('DELETE FROM message_definitions')
    db.close()
    from rosbags.highlevel import AnyReaderError

    with pytest.raises(AnyReaderError, match='no type definitions'), AnyReader([bag]):
        pass
    with BagReader(bag) as reader:
        halves = [h for h in reader.move_halves() if isinstance(h, MoveHalf)]
    assert len(halves) == 4
    np.testing.assert_array_equal(halves[0].data, records[0][3])


def test_offered_qos_is_stored_as_given(tmp_path: Path) -> None:
    from rosbags.interfaces import QosDurability, QosHistory, QosReliability
    from rosbags.rosbag2 import Reader

    with BagWriter(tmp_path / 'b') as bag:
        bag.add_topic('/last', 'std_msgs/msg/String', depth=1000)
        bag.add_topic('/all', 'std_msgs/msg/String', depth=0, reliable=False)
        bag.add_topic('/discovered', 'std_msgs/msg/String', depth=None, transient_local=True)
    with Reader(tmp_path / 'b') as reader:
        qos = {c.topic: c.ext.offered_qos_profiles[0] for c in reader.connections}
        assert reader.ros_distro == 'jazzy'
    assert (qos['/last'].history, qos['/last'].depth) == (QosHistory.KEEP_LAST, 1000)
    assert (qos['/all'].history, qos['/all'].depth) == (QosHistory.KEEP_ALL, 0)
    assert qos['/all'].reliability == QosReliability.BEST_EFFORT
    assert (qos['/discovered'].history, qos['/discovered'].depth) == (QosHistory.UNKNOWN, 0)
    assert qos['/discovered'].durability == QosDurability.TRANSIENT_LOCAL
