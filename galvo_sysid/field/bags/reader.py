"""Reading and writing rosbag2 bags of galvo topics with rosbags (no ROS install needed).

Bags are standard rosbag2 recordings (mcap by default, sqlite3 on request) that carry the
message definitions of every topic, so any rosbag2 reader (``ros2 bag``, rosbags'
``AnyReader``, Foxglove) decodes them without having ``galvo_sysid_msgs`` installed.

The ``galvo_sysid_msgs`` definitions are taken from the installed interface package
(``<prefix>/share/galvo_sysid_msgs/msg``) or, in a source checkout, from ``msg_defs/msg``.

Reading::

    with BagReader('bags/nominal') as bag:
        for item in bag.move_halves():
            ...  # MoveHalf, or SetAside for a message that could not be decoded

Writing::

    with BagWriter('out/run1', storage='mcap') as bag:
        bag.add_topic(CURRENT_TOPIC, MOVE_SAMPLES)
        bag.write_raw(CURRENT_TOPIC, timestamp_ns, cdr_bytes)

Errors on bad input are :class:`BagError` subclasses (themselves
:class:`~galvo_sysid.errors.InvalidDataError`) with one-line messages.
"""

from __future__ import annotations

import contextlib
import os
import re
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

from rosbags.highlevel import AnyReader, AnyReaderError
from rosbags.interfaces import (
    ConnectionExtRosbag2,
    Qos,
    QosDurability,
    QosHistory,
    QosLiveliness,
    QosReliability,
    QosTime,
)
from rosbags.rosbag2 import (
    CompressionFormat,
    CompressionMode,
    StoragePlugin,
    Writer,
    WriterError,
)
from rosbags.typesys import Stores, TypesysError, get_types_from_msg, get_typestore

from galvo_sysid.errors import GalvoSysidError, InvalidDataError

if TYPE_CHECKING:
    from collections.abc import Iterable, Iterator
    from types import TracebackType

    from numpy.typing import ArrayLike
    from rosbags.interfaces import Connection
    from rosbags.typesys.store import Typestore

    from galvo_sysid.monitor.pairing import MoveHalf

__all__ = [
    'CURRENT_TOPIC',
    'DRIFT_STATUS',
    'DRIFT_TOPIC',
    'ENCODER_TOPIC',
    'GALVO_TOPICS',
    'MODAL_PARAMETERS',
    'MODAL_PARAMETERS_TOPIC',
    'MOVE_SAMPLES',
    'BagError',
    'BagExistsError',
    'BagInfo',
    'BagNotFoundError',
    'BagReader',
    'BagWriter',
    'CorruptBagError',
    'NoGalvoTopicsError',
    'RawMessage',
    'SetAside',
    'TopicInfo',
    'WrongTopicTypeError',
    'find_message_definition',
    'galvo_typestore',
    'msg_search_dirs',
    'stamp_to_ns',
]

CURRENT_TOPIC = '/galvo/current'
ENCODER_TOPIC = '/galvo/encoder'
MODAL_PARAMETERS_TOPIC = '/galvo/modal_parameters'
DRIFT_TOPIC = '/galvo/drift'
GALVO_TOPICS = (CURRENT_TOPIC, ENCODER_TOPIC, MODAL_PARAMETERS_TOPIC, DRIFT_TOPIC)
"""The topics the galvo nodes publish (without namespace)."""

MOVE_SAMPLES = 'galvo_sysid_msgs/msg/MoveSamples'
MODAL_PARAMETERS = 'galvo_sysid_msgs/msg/ModalParameters'
DRIFT_STATUS = 'galvo_sysid_msgs/msg/DriftStatus'
_GALVO_MSGS = 'galvo_sysid_msgs'
_SIGNALS = {'current': 'galvo/current', 'encoder': 'galvo/encoder'}
_TYPE_RE = re.compile(r'^([A-Za-z][A-Za-z0-9_]*)/(?:msg/)?([A-Za-z][A-Za-z0-9_]*)$')


class BagError(InvalidDataError):
    """A bag cannot be used; the message is one line naming the bag and the reason."""


class BagNotFoundError(BagError, FileNotFoundError):
    """The bag path does not exist."""


class CorruptBagError(BagError):
    """The bag exists but cannot be read: not a bag, corrupt or truncated."""


class NoGalvoTopicsError(BagError):
    """The bag holds no ``galvo/current`` and ``galvo/encoder`` topics."""


class WrongTopicTypeError(BagError):
    """A galvo topic in the bag has another message type than expected."""


class BagExistsError(BagError, FileExistsError):
    """The output bag already exists (bags are never overwritten)."""


# --------------------------------------------------------------------------- definitions


def msg_search_dirs(package: str = _GALVO_MSGS) -> list[Path]:
    """Directories that may hold ``<package>``'s ``.msg`` files, most preferred first.

    The installed interface package (``sys.prefix``, then each ``AMENT_PREFIX_PATH`` entry)
    comes before the source checkout's ``msg_defs/msg`` (only for ``galvo_sysid_msgs``).
    """
    prefixes = [Path(sys.prefix)]
    prefixes += [Path(p) for p in os.environ.get('AMENT_PREFIX_PATH', '').split(os.pathsep) if p]
    dirs = [prefix / 'share' / package / 'msg' for prefix in prefixes]
    if package == _GALVO_MSGS:
        dirs.append(Path(__file__).resolve().parents[2] / 'msg_defs' / 'msg')
    unique: list[Path] = []
    for d in dirs:
        if d not in unique:
            unique.append(d)
    return unique


def _split_type(msgtype: str) -> tuple[str, str]:
    match = _TYPE_RE.match(msgtype)
    if not match:
        msg = f'not a ROS 2 message type name: {msgtype!r}'
        raise BagError(msg)
    return match.group(1), match.group(2)


def find_message_definition(msgtype: str) -> str | None:
    """Return the ``.msg`` text of ``msgtype`` (``pkg/msg/Name``) if installed, else None."""
    package, name = _split_type(msgtype)
    for d in msg_search_dirs(package):
        path = d / f'{name}.msg'
        if path.is_file():
            return path.read_text(encoding='utf-8')
    return None


def _ensure_type(typestore: Typestore, msgtype: str, _seen: set[str] | None = None) -> None:
    """Register ``msgtype`` (and unknown field types) in ``typestore`` from ``.msg`` files."""
    package, name = _split_type(msgtype)
    full = f'{package}/msg/{name}'
    if full in typestore.fielddefs:
        return
    seen = set() if _seen is None else _seen
    if full in seen:
        return
    seen.add(full)
    text = find_message_definition(full)
    if text is None:
        msg = (f'no message definition found for {full} (looked in '
               f'{", ".join(str(d) for d in msg_search_dirs(package))})')
        raise BagError(msg)
    try:
        types = get_types_from_msg(text, full)
    except TypesysError as err:
        msg = f'cannot parse the definition of {full}: {err}'
        raise BagError(msg) from None
    for _, fields in types.values():
        for _, desc in fields:
            for dep in _field_type_names(desc):
                if dep not in typestore.fielddefs and dep not in types:
                    _ensure_type(typestore, dep, seen)
    typestore.register(types)


def _field_type_names(desc: Any) -> list[str]:
    """Names of the message types a rosbags field description refers to."""
    names: list[str] = []
    if isinstance(desc, tuple):
        for part in desc:
            if isinstance(part, str) and '/' in part:
                names.append(part)
            elif isinstance(part, tuple):
                names.extend(_field_type_names(part))
    return names


def galvo_typestore(extra_types: Iterable[str] = ()) -> Typestore:
    """A rosbags typestore: ROS 2 Jazzy's standard types plus ``galvo_sysid_msgs``.

    Args:
        extra_types: Further ``pkg/msg/Name`` types to register from installed ``.msg``
            files (their unknown field types too).

    Raises:
        BagError: A definition cannot be found or parsed.
    """
    typestore = get_typestore(Stores.ROS2_JAZZY)
    for msgtype in (MOVE_SAMPLES, MODAL_PARAMETERS, DRIFT_STATUS, *extra_types):
        _ensure_type(typestore, msgtype)
    return typestore


def stamp_to_ns(stamp: float) -> int:
    """Seconds as float -> integer nanoseconds (rounded)."""
    return round(stamp * 1e9)


# --------------------------------------------------------------------------- records


@dataclass(frozen=True)
class RawMessage:
    """One serialized message as stored in a bag.

    Attributes:
        topic: Topic name.
        msgtype: ``pkg/msg/Name``.
        timestamp: Log time [ns] (receive time when recorded, simulated time when simulated).
        data: CDR bytes.
    """

    topic: str
    msgtype: str
    timestamp: int
    data: bytes


@dataclass(frozen=True)
class SetAside:
    """A message that could not be turned into a move half.

    Attributes:
        topic: Topic it came on.
        timestamp: Log time [s].
        reason: Short human text.
    """

    topic: str
    timestamp: float
    reason: str

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready form, same keys as a windower rejection plus ``topic``."""
        return {'move_id': None, 'target_angle': None, 'stamp': self.timestamp,
                'reason': self.reason, 'topic': self.topic}


@dataclass(frozen=True)
class TopicInfo:
    """One topic of a bag.

    Attributes:
        topic: Name.
        msgtype: Message type.
        count: Number of messages.
        transient_local: Whether the recorded publisher offered transient-local durability.
    """

    topic: str
    msgtype: str
    count: int
    transient_local: bool


@dataclass(frozen=True)
class BagInfo:
    """What a bag holds.

    Attributes:
        path: The bag (directory or storage file).
        storage: ``'mcap'`` or ``'sqlite3'``.
        topics: Topics, sorted by name.
        message_count: Total number of messages.
        start: Log time of the first message [ns] (0 for an empty bag).
        end: Log time of the last message [ns] (0 for an empty bag).
    """

    path: Path
    storage: str
    topics: tuple[TopicInfo, ...]
    message_count: int
    start: int
    end: int


# --------------------------------------------------------------------------- reading


def _one_line(err: BaseException) -> str:
    text = ' '.join(str(a) for a in err.args) if err.args else type(err).__name__
    text = ' '.join(text.split())
    return text.rstrip('.') or type(err).__name__


def _explain(err: BaseException) -> str:
    text = _one_line(err)
    if 'end magic' in text:  # an mcap file without its footer: cut off, or never closed
        return f'{text} (the mcap file is truncated: copy cut short or recording not closed)'
    if 'malformed' in text or 'not a database' in text:
        return f'{text} (the sqlite3 file is truncated or corrupt)'
    return text


def _storage_of(path: Path) -> str:
    if path.is_dir():
        files = [p.suffix for p in path.iterdir()]
        if '.db3' in files:
            return 'sqlite3'
        return 'mcap'
    return 'sqlite3' if path.suffix == '.db3' else 'mcap'


class BagReader:
    """Read a rosbag2 bag (directory, ``.mcap`` or ``.db3`` file) of galvo topics.

    Use as a context manager. Messages are decoded with the definitions stored in the bag;
    a bag without stored definitions is decoded with :func:`galvo_typestore`.

    Raises (on opening):
        BagNotFoundError: ``path`` does not exist.
        CorruptBagError: Not a readable rosbag2 bag.
    """

    def __init__(self, path: str | os.PathLike[str]) -> None:
        self.path = Path(path)
        self._reader: AnyReader | None = None

    def __enter__(self) -> BagReader:
        self.open()
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close()

    def open(self) -> None:
        """Open the bag (see the class for the errors)."""
        if not self.path.exists():
            msg = f'bag not found: {self.path}'
            raise BagNotFoundError(msg)
        if self.path.is_file() and self.path.name == 'metadata.yaml':
            self.path = self.path.parent
        if self.path.is_dir() and not (self.path / 'metadata.yaml').exists():
            storage_files = sorted([*self.path.glob('*.mcap'), *self.path.glob('*.db3')])
            if len(storage_files) != 1:
                msg = f'not a rosbag2 bag (no metadata.yaml): {self.path}'
                raise CorruptBagError(msg)
            self.path = storage_files[0]
        if self.path.is_file() and self.path.suffix not in {'.mcap', '.db3'}:
            msg = f'not a rosbag2 bag (expected a directory, .mcap or .db3): {self.path}'
            raise CorruptBagError(msg)
        try:
            try:
                reader = AnyReader([self.path])
                reader.open()
            except AnyReaderError as err:
                if 'no type definitions' not in str(err):
                    raise
                # an old bag without stored definitions: decode with our own (built lazily,
                # it costs a tenth of a second)
                reader = AnyReader([self.path], default_typestore=galvo_typestore())
                reader.open()
        except BagError:
            raise
        except Exception as err:  # rosbags raises many types on a bad file; all mean "corrupt"
            msg = f'cannot read bag {self.path}: {_explain(err)}'
            raise CorruptBagError(msg) from None
        self._reader = reader

    def close(self) -> None:
        """Close the bag (idempotent)."""
        reader, self._reader = self._reader, None
        if reader is not None:
            with contextlib.suppress(Exception):  # closing a broken bag must not mask its error
                reader.close()

    @property
    def reader(self) -> AnyReader:
        """The open rosbags reader."""
        if self._reader is None:
            msg = f'bag {self.path} is not open'
            raise BagError(msg)
        return self._reader

    @property
    def info(self) -> BagInfo:
        """Topics, counts and time range."""
        reader = self.reader
        topics: dict[str, TopicInfo] = {}
        for conn in reader.connections:
            old = topics.get(conn.topic)
            count = conn.msgcount + (old.count if old else 0)
            topics[conn.topic] = TopicInfo(conn.topic, conn.msgtype, count,
                                           _transient_local(conn) or bool(old and
                                                                          old.transient_local))
        count = sum(t.count for t in topics.values())
        return BagInfo(path=self.path, storage=_storage_of(self.path),
                       topics=tuple(topics[k] for k in sorted(topics)), message_count=count,
                       start=reader.start_time if count else 0,
                       end=reader.end_time - 1 if count else 0)

    def raw_messages(self, topics: Iterable[str] | None = None) -> Iterator[RawMessage]:
        """Yield the stored messages in log-time order (all topics, or only ``topics``).

        Raises:
            CorruptBagError: The bag is truncated or corrupt part-way.
        """
        reader = self.reader
        wanted = None if topics is None else set(topics)
        conns = [c for c in reader.connections if wanted is None or c.topic in wanted]
        if not conns:
            return
        iterator = reader.messages(connections=conns)
        while True:
            try:
                item = next(iterator)
            except StopIteration:
                return
            except Exception as err:  # any failure inside the storage reader = damaged bag
                msg = f'bag {self.path} is truncated or corrupt: {_one_line(err)}'
                raise CorruptBagError(msg) from None
            conn, timestamp, data = item
            yield RawMessage(conn.topic, conn.msgtype, timestamp, bytes(data))

    def deserialize(self, raw: RawMessage) -> object:
        """Decode one message with the bag's stored definitions.

        Raises:
            CorruptBagError: The bytes do not decode as ``raw.msgtype``.
        """
        try:
            return self.reader.deserialize(raw.data, raw.msgtype)
        except Exception as err:  # rosbags raises assorted error types on bad bytes
            msg = f'undecodable {raw.msgtype} message on {raw.topic}: {_one_line(err)}'
            raise CorruptBagError(msg) from None

    def galvo_topics(self, *, namespace: str | None = None) -> tuple[str, str]:
        """The bag's ``(current, encoder)`` topics, checked for type.

        Args:
            namespace: Pick the scanner with this namespace (e.g. ``/left``) when the bag
                holds several; ``None`` accepts exactly one scanner.

        Raises:
            NoGalvoTopicsError: No (or only one of the two) galvo sample topics.
            WrongTopicTypeError: A galvo topic has another type than ``MoveSamples``.
            BagError: Several scanners and no ``namespace``.
        """
        types = {t.topic: t.msgtype for t in self.info.topics}
        prefixes: dict[str, dict[str, str]] = {}
        for topic in types:
            for signal, suffix in _SIGNALS.items():
                if topic == '/' + suffix or topic.endswith('/' + suffix):
                    prefix = topic[: -len(suffix) - 1]
                    prefixes.setdefault(prefix, {})[signal] = topic
        if namespace is not None:
            ns = '/' + namespace.strip('/') if namespace.strip('/') else ''
            prefixes = {k: v for k, v in prefixes.items() if k == ns}
        if not prefixes:
            where = f' under namespace {namespace}' if namespace else ''
            have = ', '.join(sorted(types)) or 'no topics'
            msg = (f'bag {self.path} has no galvo/current and galvo/encoder topics{where} '
                   f'(it has: {have})')
            raise NoGalvoTopicsError(msg)
        if len(prefixes) > 1:
            names = ', '.join(p or '/' for p in sorted(prefixes))
            msg = f'bag {self.path} holds several scanners ({names}): choose one namespace'
            raise BagError(msg)
        found = next(iter(prefixes.values()))
        for signal in _SIGNALS:
            if signal not in found:
                other = next(iter(found.values()))
                msg = f'bag {self.path} has {other} but no matching {signal} topic'
                raise NoGalvoTopicsError(msg)
        for topic in found.values():
            if types[topic] != MOVE_SAMPLES:
                msg = f'topic {topic} in bag {self.path} has type {types[topic]}, ' \
                      f'expected {MOVE_SAMPLES}'
                raise WrongTopicTypeError(msg)
        return found['current'], found['encoder']

    def move_halves(self, *, namespace: str | None = None) -> Iterator[MoveHalf | SetAside]:
        """Yield each ``MoveSamples`` message as a :class:`~galvo_sysid.monitor.pairing.MoveHalf`.

        A message that cannot be decoded or converted is yielded as :class:`SetAside`
        instead; reading goes on.

        Raises:
            NoGalvoTopicsError, WrongTopicTypeError, CorruptBagError: see
                :meth:`galvo_topics` and :meth:`raw_messages`.
        """
        from galvo_sysid.interfaces.messages import move_half_from_msg

        current, encoder = self.galvo_topics(namespace=namespace)
        signals = {current: 'current', encoder: 'encoder'}
        for raw in self.raw_messages([current, encoder]):
            try:
                msg = self.deserialize(raw)
                half = move_half_from_msg(msg, signal=signals[raw.topic])
            except GalvoSysidError as err:
                yield SetAside(raw.topic, raw.timestamp * 1e-9, _one_line(err))
                continue
            yield half


def _transient_local(conn: Connection) -> bool:
    ext = conn.ext
    if not isinstance(ext, ConnectionExtRosbag2):
        return False
    return any(q.durability == QosDurability.TRANSIENT_LOCAL for q in ext.offered_qos_profiles)


# --------------------------------------------------------------------------- writing

_ZERO = QosTime(0, 0)
_INFINITE = QosTime(2147483647, 4294967295)


def _qos(*, reliable: bool, transient_local: bool, depth: int) -> Qos:
    return Qos(
        history=QosHistory.KEEP_LAST,
        depth=depth,
        reliability=QosReliability.RELIABLE if reliable else QosReliability.BEST_EFFORT,
        durability=QosDurability.TRANSIENT_LOCAL if transient_local else QosDurability.VOLATILE,
        deadline=_INFINITE,
        lifespan=_INFINITE,
        liveliness=QosLiveliness.AUTOMATIC,
        liveliness_lease_duration=_INFINITE,
        avoid_ros_namespace_conventions=False,
    )


class BagWriter:
    """Write a new rosbag2 bag with message definitions stored.

    Args:
        path: Bag directory to create (must not exist).
        storage: ``'mcap'`` (default, zstd-compressed chunks when ``compress``) or
            ``'sqlite3'``.
        compress: Compress mcap chunks with zstd (readable by ``ros2 bag`` and rosbags).

    Raises:
        BagExistsError: ``path`` exists.
        BagError: Unknown storage.
    """

    def __init__(self, path: str | os.PathLike[str], *,
                 storage: Literal['mcap', 'sqlite3'] | str = 'mcap',
                 compress: bool = True) -> None:
        self.path = Path(path)
        if storage not in {'mcap', 'sqlite3'}:
            msg = f'unknown storage {storage!r}: use mcap or sqlite3'
            raise BagError(msg)
        if self.path.exists():
            msg = f'output bag exists already, not overwriting: {self.path}'
            raise BagExistsError(msg)
        self.storage = storage
        plugin = StoragePlugin.MCAP if storage == 'mcap' else StoragePlugin.SQLITE3
        self._writer = Writer(self.path, version=Writer.VERSION_LATEST, storage_plugin=plugin)
        if storage == 'mcap' and compress:
            self._writer.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
        self.typestore = galvo_typestore()
        self._connections: dict[str, Connection] = {}
        self._types: dict[str, str] = {}
        self._open = False
        self.count = 0

    def __enter__(self) -> BagWriter:
        self.open()
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close()

    def open(self) -> None:
        """Create the bag directory and storage file."""
        try:
            self._writer.open()
        except WriterError as err:
            raise BagExistsError(_one_line(err)) from None
        self._open = True

    def close(self) -> None:
        """Write the index and ``metadata.yaml`` (idempotent)."""
        if self._open:
            self._open = False
            self._writer.close()

    @property
    def topics(self) -> dict[str, str]:
        """Topics added so far and their types."""
        return dict(self._types)

    def add_topic(self, topic: str, msgtype: str, *, reliable: bool = True,
                  transient_local: bool = False, depth: int = 10) -> None:
        """Add a topic; its type's definition is stored in the bag.

        Args:
            topic: Topic name.
            msgtype: ``pkg/msg/Name``; must be a standard Jazzy type, a ``galvo_sysid_msgs``
                type, or have its ``.msg`` installed under ``<prefix>/share``.
            reliable: The offered QoS was reliable (stored in the metadata for players).
            transient_local: The offered QoS was transient local.
            depth: The offered history depth.

        Raises:
            BagError: Topic added twice, or the type's definition is not found.
        """
        package, name = _split_type(msgtype)
        msgtype = f'{package}/msg/{name}'
        if topic in self._connections:
            msg = f'topic {topic} added twice'
            raise BagError(msg)
        _ensure_type(self.typestore, msgtype)
        qos = _qos(reliable=reliable, transient_local=transient_local, depth=depth)
        self._connections[topic] = self._writer.add_connection(
            topic, msgtype, typestore=self.typestore, offered_qos_profiles=[qos])
        self._types[topic] = msgtype

    def write_raw(self, topic: str, timestamp: int, data: bytes | memoryview) -> None:
        """Store already serialized CDR bytes at log time ``timestamp`` [ns]."""
        conn = self._connections.get(topic)
        if conn is None:
            msg = f'topic {topic} was not added to bag {self.path}'
            raise BagError(msg)
        self._writer.write(conn, timestamp, data)
        self.count += 1

    def write(self, topic: str, timestamp: int, message: object) -> None:
        """Serialize a rosbags message object (see :attr:`typestore`) and store it."""
        data = self.typestore.serialize_cdr(message, self._types[topic])
        self.write_raw(topic, timestamp, data)

    def move_samples(self, *, stamp: float, move_id: int, target_angle: float,
                     sample_period: float, data: ArrayLike, frame_id: str = '') -> object:
        """Build a rosbags ``MoveSamples`` message (header stamp from ``stamp`` [s])."""
        import numpy as np

        types = self.typestore.types
        sec, nanosec = divmod(stamp_to_ns(stamp), 1_000_000_000)
        header = types['std_msgs/msg/Header'](
            stamp=types['builtin_interfaces/msg/Time'](sec=sec, nanosec=nanosec),
            frame_id=frame_id)
        return types[MOVE_SAMPLES](header=header, move_id=move_id,
                                   target_angle=float(target_angle),
                                   sample_period=float(sample_period),
                                   data=np.ascontiguousarray(data, dtype=np.float64))

