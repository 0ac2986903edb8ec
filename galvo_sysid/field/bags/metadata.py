"""A bag's ``metadata.yaml``: read strictly before any library trusts it, and written.

rosbag2 describes a bag directory in ``metadata.yaml``: its storage files, its topics and
how many messages each holds. It is a claim, written by whoever made the bag, and read here
like every YAML file galvo_sysid is given (:func:`galvo_sysid.schema.load_yaml`: regular file,
at most 1 MB, no aliases) and checked against the rosbag2 layout (versions 1-9): unknown keys
are refused at every level, every value has its type and a bounded size, every storage file
is a plain name in the bag's directory. The message counts it claims are not shown as fact:
:class:`~galvo_sysid.field.bags.reader.BagReader` takes the counts from the storage files and
says where ``metadata.yaml`` disagrees.

Written: :func:`bag_metadata` builds its content from what a storage has durably written (used
while recording and when a bag is closed, :mod:`galvo_sysid.field.bags.writer`, and by the
recovery, :mod:`galvo_sysid.field.bags.recovery`); :func:`metadata_text` is its text. It names
ROS 2 Jazzy as the bag's ``ros_distro`` (:data:`ROS_DISTRO`) and each topic's offered QoS as the
writer was given it.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path, PurePath
from typing import TYPE_CHECKING, Any

import yaml  # type: ignore[import-untyped]  # PyYAML ships no stubs here
from rosbags.rosbag2.metadata import dump_qos_v9

from galvo_sysid.errors import ConfigurationError, InvalidDataError, one_line
from galvo_sysid.field.bags.errors import CorruptBagError
from galvo_sysid.schema import Section, check_regular_file, load_yaml, parse_yaml

if TYPE_CHECKING:
    import os
    from collections.abc import Mapping, Sequence

    from rosbags.interfaces import Qos

__all__ = ['MAX_FILES', 'MAX_TOPICS', 'ROS_DISTRO', 'BagMetadata', 'ClaimedTopic', 'StoredTopic',
           'bag_metadata', 'check_storage_files', 'metadata_text', 'read_metadata']

ROS_DISTRO = 'jazzy'
"""The ``ros_distro`` the bags written here name: their message definitions are ROS 2 Jazzy's
(:func:`~galvo_sysid.field.bags.definitions.galvo_typestore`), as ``ros2 bag`` on Jazzy writes."""

MAX_TOPICS = 10_000
"""Most topics a ``metadata.yaml`` may list."""

MAX_FILES = 10_000
"""Most storage files a ``metadata.yaml`` may list."""

_MAX_COUNT = 2**63 - 1  # rosbag2 counts are uint64; a log time is an int64 of nanoseconds
_TEXT = 4096  # longest name, type, hash, path or custom value

_TOP = ('version', 'storage_identifier', 'relative_file_paths', 'duration', 'starting_time',
        'message_count', 'topics_with_message_count', 'compression_format',
        'compression_mode', 'files', 'custom_data', 'ros_distro')
_TOPIC = ('name', 'type', 'serialization_format', 'offered_qos_profiles',
          'type_description_hash')
_QOS = ('history', 'depth', 'reliability', 'durability', 'deadline', 'lifespan', 'liveliness',
        'liveliness_lease_duration', 'avoid_ros_namespace_conventions')
_QOS_TIMES = ('deadline', 'lifespan', 'liveliness_lease_duration')
_FILE = ('path', 'starting_time', 'duration', 'message_count')


@dataclass(frozen=True)
class ClaimedTopic:
    """A topic as ``metadata.yaml`` lists it.

    Attributes:
        name: Topic name.
        msgtype: Message type.
        count: The message count it claims.
    """

    name: str
    msgtype: str
    count: int


@dataclass(frozen=True)
class BagMetadata:
    """What a bag's ``metadata.yaml`` says (checked, not yet compared with the storage).

    Attributes:
        path: The file.
        version: rosbag2 metadata version (1-9).
        storage: ``storage_identifier`` (``'mcap'``, ``'sqlite3'``).
        files: The storage files, in the bag's directory.
        topics: The topics with the counts they claim.
        message_count: The total count it claims.
    """

    path: Path
    version: int
    storage: str
    files: tuple[Path, ...]
    topics: tuple[ClaimedTopic, ...]
    message_count: int


def read_metadata(bag: str | os.PathLike[str]) -> BagMetadata:
    """Read and check the ``metadata.yaml`` of the bag directory ``bag``.

    Raises:
        CorruptBagError: Not readable (not a regular file, over 1 MB, not YAML, an alias) or
            not the rosbag2 layout (an unknown key, a wrong type, a value out of range, a
            storage file outside the directory); one line naming the file and the key.
    """
    path = Path(bag) / 'metadata.yaml'
    where = str(path)
    try:
        doc = load_yaml(path, what='bag metadata')
        top = Section(doc, where, keys=('rosbag2_bagfile_information',))
        info = top.section('rosbag2_bagfile_information', keys=_TOP)
        assert info is not None
        return _metadata(info, path)
    except (ConfigurationError, InvalidDataError) as err:
        raise CorruptBagError(f'cannot read bag {Path(bag)}: {one_line(err)}') from None


def check_storage_files(bag: Path, metadata: BagMetadata | None) -> list[Path]:
    """The storage files of a bag (directory or file), each checked to be a regular file.

    A FIFO, device or socket named like a storage file is refused before anything opens it
    (opening a FIFO for reading blocks until a writer comes).

    Raises:
        CorruptBagError: A storage file is missing or not a regular file.
    """
    files = [bag] if not bag.is_dir() else list(metadata.files) if metadata else []
    for file in files:
        try:
            check_regular_file(file, what='bag' if file == bag else 'bag storage file')
        except InvalidDataError as err:
            raise CorruptBagError(one_line(err)) from None
    return files


def _metadata(info: Section, path: Path) -> BagMetadata:
    version = info.integer('version', low=1, high=9)
    storage = info.text('storage_identifier', max_length=64)
    names = [_text(p, f'{info.where}: relative_file_paths[{i}]')
             for i, p in enumerate(info.items('relative_file_paths', max_items=MAX_FILES,
                                              optional=False), start=1)]
    files = []
    for i, name in enumerate(names, start=1):
        plain = PurePath(name).name  # as rosbag2 and rosbags: the file in the bag's directory
        if not plain or plain in {'.', '..'}:
            raise ConfigurationError(f'{info.where}: relative_file_paths[{i}] {name!r} is no '
                                     f'file name')
        files.append(path.parent / plain)
    _nanoseconds(info, 'duration', 'nanoseconds')
    _nanoseconds(info, 'starting_time', 'nanoseconds_since_epoch')
    total = info.integer('message_count', low=0, high=_MAX_COUNT)
    topics = []
    for i, raw in enumerate(info.items('topics_with_message_count', max_items=MAX_TOPICS,
                                       optional=False), start=1):
        entry = Section(raw, f'{info.where}: topics_with_message_count[{i}]',
                        keys=('topic_metadata', 'message_count'))
        count = entry.integer('message_count', low=0, high=_MAX_COUNT)
        meta = entry.section('topic_metadata', keys=_TOPIC)
        assert meta is not None
        name = meta.text('name', max_length=_TEXT)
        msgtype = meta.text('type', max_length=_TEXT)
        meta.text('serialization_format', max_length=64)
        meta.text('type_description_hash', '', max_length=_TEXT)
        if 'offered_qos_profiles' in meta:
            _qos(meta.data['offered_qos_profiles'], f'{meta.where}: offered_qos_profiles')
        topics.append(ClaimedTopic(name, msgtype, count))
    for key in ('compression_format', 'compression_mode', 'ros_distro'):
        info.text(key, '', max_length=64)
    for i, raw in enumerate(info.items('files', max_items=MAX_FILES), start=1):
        entry = Section(raw, f'{info.where}: files[{i}]', keys=_FILE)
        entry.text('path', max_length=_TEXT)
        _nanoseconds(entry, 'duration', 'nanoseconds')
        _nanoseconds(entry, 'starting_time', 'nanoseconds_since_epoch')
        entry.integer('message_count', low=0, high=_MAX_COUNT)
    custom = info.section('custom_data', optional=True)
    if custom is not None:
        if len(custom.data) > MAX_TOPICS:
            raise ConfigurationError(f'{custom.where}: more than {MAX_TOPICS} entries')
        for key in custom.data:
            _text(key, f'{custom.where}: key')
            custom.text(str(key), max_length=_TEXT)
    return BagMetadata(path=path, version=version, storage=storage, files=tuple(files),
                       topics=tuple(topics), message_count=total)


def _text(value: Any, where: str) -> str:
    if not isinstance(value, str) or len(value) > _TEXT:
        raise ConfigurationError(f'{where} must be text of at most {_TEXT} characters')
    return value


def _nanoseconds(section: Section, key: str, inner: str) -> None:
    """``key: {inner: N}``, N a whole number of nanoseconds (int64)."""
    value = section.section(key, keys=(inner,))
    assert value is not None
    value.integer(inner, low=-_MAX_COUNT - 1, high=_MAX_COUNT)


def _qos(value: Any, where: str) -> None:
    """Offered QoS profiles: a list of mappings (version 8 on: YAML text of one, parsed by
    the same safe loader)."""  # noqa: D205, D209
    if isinstance(value, str):
        value = parse_yaml(value, source=where) if value.strip() else []
    if value is None:
        return
    if not isinstance(value, list) or len(value) > 100:
        raise ConfigurationError(f'{where} must be a list of at most 100 QoS profiles')
    for i, raw in enumerate(value, start=1):
        qos = Section(raw, f'{where}[{i}]', keys=_QOS)
        for key in ('history', 'reliability', 'durability', 'liveliness'):
            if key in qos and not isinstance(qos.data[key], str | int):
                raise ConfigurationError(f'{qos.where}: {key} must be a name or a number')
            if isinstance(qos.data.get(key), str):
                qos.text(key, max_length=64)
        if 'depth' in qos:
            qos.integer('depth', low=0, high=2**32)
        for key in _QOS_TIMES:
            if key in qos:
                t = qos.section(key, keys=('sec', 'nsec'))
                assert t is not None
                t.integer('sec', low=-(2**63), high=2**64)
                t.integer('nsec', low=0, high=2**64)
        if 'avoid_ros_namespace_conventions' in qos and not isinstance(
                qos.data['avoid_ros_namespace_conventions'], bool):
            raise ConfigurationError(f'{qos.where}: avoid_ros_namespace_conventions must be '
                                     f'true or false')


# --------------------------------------------------------------------------- writing


@dataclass(frozen=True)
class StoredTopic:
    """A topic as ``metadata.yaml`` describes it."""

    name: str
    msgtype: str
    count: int
    qos: list[Qos] = field(default_factory=list)
    digest: str = ''
    serialization_format: str = 'cdr'


def bag_metadata(*, storage: str, file_name: str, topics: Sequence[StoredTopic],
                 span: tuple[int, int] | None, custom: Mapping[str, str] | None = None,
                 compression: str = '') -> dict[str, Any]:
    """The ``rosbag2_bagfile_information`` of ``metadata.yaml`` (rosbag2 version 9).

    Args:
        storage: ``'mcap'`` or ``'sqlite3'``.
        file_name: The storage file's name.
        topics: The topics with their message counts.
        span: Log times of the first and last message [ns] (None: no message).
        custom: ``custom_data`` entries.
        compression: ``compression_format`` (``''``: none, or per mcap chunk).
    """
    count = sum(t.count for t in topics)
    start, end = span if span is not None and count else (0, 0)
    duration = max(0, end - start)
    return {
        'version': 9,
        'storage_identifier': storage,
        'relative_file_paths': [file_name],
        'duration': {'nanoseconds': duration},
        'starting_time': {'nanoseconds_since_epoch': start},
        'message_count': count,
        'topics_with_message_count': [
            {'topic_metadata': {'name': t.name, 'type': t.msgtype,
                                'serialization_format': t.serialization_format,
                                'offered_qos_profiles': dump_qos_v9(list(t.qos)),
                                'type_description_hash': t.digest},
             'message_count': t.count}
            for t in topics],
        'compression_format': compression,
        'compression_mode': '',
        'files': [{'path': file_name, 'starting_time': {'nanoseconds_since_epoch': start},
                   'duration': {'nanoseconds': duration}, 'message_count': count}],
        'custom_data': dict(custom) if custom else None,
        'ros_distro': ROS_DISTRO,
    }


def metadata_text(info: Mapping[str, Any], *, inner: bool = False) -> str:
    """``metadata.yaml``'s text (``inner``: without the top key, as stored in the file)."""
    data = info if inner else {'rosbag2_bagfile_information': info}
    text: str = yaml.safe_dump(data, default_flow_style=False, sort_keys=False)
    return text
