"""Reading rosbag2 bags of galvo topics: :class:`BagReader` and what it yields.

Reading::

    with BagReader('bags/nominal') as bag:
        for item in bag.move_halves():
            ...  # MoveHalf, or SetAside for a message that could not be decoded

Messages are decoded with the definitions stored in the bag; a bag without them is decoded
with :func:`~galvo_sysid.field.bags.definitions.galvo_typestore`.

Before a library opens anything, a bag's ``metadata.yaml`` is read strictly
(:func:`~galvo_sysid.field.bags.metadata.read_metadata`) and every storage file must be a
regular file (a FIFO named ``run.mcap`` would block the reader forever). The message counts
and time range of :attr:`BagReader.info` are the storage files' own (sqlite3 counts its rows,
mcap its statistics or its records); where ``metadata.yaml`` claims otherwise,
:attr:`BagInfo.claims` says so.
"""

from __future__ import annotations

import contextlib
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from rosbags.highlevel import AnyReader, AnyReaderError
from rosbags.interfaces import ConnectionExtRosbag2, QosDurability

from galvo_sysid.errors import GalvoSysidError
from galvo_sysid.field.bags.base import BagFile
from galvo_sysid.field.bags.completeness import check_complete
from galvo_sysid.field.bags.definitions import galvo_typestore
from galvo_sysid.field.bags.errors import (
    BagError,
    BagNotFoundError,
    CorruptBagError,
    NoGalvoTopicsError,
    WrongTopicTypeError,
    reason,
)
from galvo_sysid.field.bags.metadata import BagMetadata, check_storage_files, read_metadata
from galvo_sysid.interfaces.topics import MOVE_SAMPLES, SIGNAL_TOPICS

if TYPE_CHECKING:
    import os
    from collections.abc import Iterable, Iterator

    from rosbags.interfaces import Connection

    from galvo_sysid.monitor.moves import MoveHalf, Window
    from galvo_sysid.monitor.pairing import MoveWindower

__all__ = ['BagInfo', 'BagReader', 'RawMessage', 'SetAside', 'TopicInfo']


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
        half: For a record refused before decoding (too long): its fields as a
            :class:`~galvo_sysid.monitor.moves.MoveHalf` without samples, so that its move
            can be set aside as one (:meth:`~galvo_sysid.monitor.pairing.MoveWindower.refuse`);
            else None.
    """

    topic: str
    timestamp: float
    reason: str
    half: MoveHalf | None = None

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready form, same keys as a windower rejection plus ``topic``."""
        h = self.half
        if h is not None:
            return {'move_id': h.move_id, 'target_angle': h.target_angle, 'stamp': h.stamp,
                    'reason': self.reason, 'topic': self.topic}
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
        claims: Where the bag's ``metadata.yaml`` disagrees with its storage files (one line
            each; the counts and times above are the storage files'), else empty.
    """

    path: Path
    storage: str
    topics: tuple[TopicInfo, ...]
    message_count: int
    start: int
    end: int
    claims: tuple[str, ...] = ()


def _explain(err: BaseException) -> str:
    text = reason(err)
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


class BagReader(BagFile):
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
        self._metadata: BagMetadata | None = None

    def open(self) -> None:
        """Open the bag (see the class for the errors)."""
        if not self.path.exists():
            msg = f'bag not found: {self.path}'
            raise BagNotFoundError(msg)
        if self.path.is_file() and self.path.name == 'metadata.yaml':
            self.path = self.path.parent
        check_complete(self.path)  # an unfinished recording is not read as empty
        if self.path.is_dir() and not (self.path / 'metadata.yaml').exists():
            storage_files = sorted([*self.path.glob('*.mcap'), *self.path.glob('*.db3')])
            if len(storage_files) != 1:
                msg = f'not a rosbag2 bag (no metadata.yaml): {self.path}'
                raise CorruptBagError(msg)
            self.path = storage_files[0]
        if not self.path.is_dir() and self.path.suffix not in {'.mcap', '.db3'}:
            msg = f'not a rosbag2 bag (expected a directory, .mcap or .db3): {self.path}'
            raise CorruptBagError(msg)
        # strictly, before rosbags trusts it; then no FIFO, device or socket gets opened
        self._metadata = read_metadata(self.path) if self.path.is_dir() else None
        check_storage_files(self.path, self._metadata)
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
        """Topics, counts and time range, as the storage files hold them.

        A bag directory's ``metadata.yaml`` only claims its counts: they are checked against
        the storage files (their own index or rows), which are shown; a disagreement is said
        in :attr:`BagInfo.claims`.
        """
        reader = self.reader
        topics: dict[str, TopicInfo] = {}
        for conn in reader.connections:
            old = topics.get(conn.topic)
            count = conn.msgcount + (old.count if old else 0)
            topics[conn.topic] = TopicInfo(conn.topic, conn.msgtype, count,
                                           _transient_local(conn) or bool(old and
                                                                          old.transient_local))
        start, end = reader.start_time, reader.end_time
        claims: list[str] = []
        held = _storage_counts(reader)
        if held is not None:
            counts, start, end = held
            for name, t in sorted(topics.items()):
                if counts.get(name, 0) != t.count:
                    claims.append(f'metadata.yaml claims {t.count} messages on {name}, the '
                                  f'storage holds {counts.get(name, 0)} (shown)')
                    topics[name] = TopicInfo(t.topic, t.msgtype, counts.get(name, 0),
                                             t.transient_local)
        count = sum(t.count for t in topics.values())
        meta = self._metadata
        if meta is not None and meta.message_count != count:
            held_by = 'the storage holds' if held is not None else 'its topics hold'
            claims.append(f'metadata.yaml claims {meta.message_count} messages in all, '
                          f'{held_by} {count} (shown)')
        return BagInfo(path=self.path, storage=_storage_of(self.path),
                       topics=tuple(topics[k] for k in sorted(topics)), message_count=count,
                       start=start if count else 0, end=end - 1 if count else 0,
                       claims=tuple(claims))

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
                msg = f'bag {self.path} is truncated or corrupt: {reason(err)}'
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
            msg = f'undecodable {raw.msgtype} message on {raw.topic}: {reason(err)}'
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
            for signal, suffix in SIGNAL_TOPICS.items():
                if topic == '/' + suffix or topic.endswith('/' + suffix):
                    prefix = topic[: -len(suffix) - 1]
                    prefixes.setdefault(prefix, {})[signal] = topic
        if namespace is not None:
            ns = '/' + namespace.strip('/') if namespace.strip('/') else ''
            prefixes = {k: v for k, v in prefixes.items() if k == ns}
        if not prefixes:
            where = f' under namespace {namespace}' if namespace else ''
            have = ', '.join(sorted(types)) or 'no topics'
            msg = (f'bag {self.path} has no {" and ".join(SIGNAL_TOPICS.values())} '
                   f'topics{where} (it has: {have})')
            raise NoGalvoTopicsError(msg)
        if len(prefixes) > 1:
            names = ', '.join(p or '/' for p in sorted(prefixes))
            msg = f'bag {self.path} holds several scanners ({names}): choose one namespace'
            raise BagError(msg)
        found = next(iter(prefixes.values()))
        for signal in SIGNAL_TOPICS:
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

    def move_halves(self, *, namespace: str | None = None,
                    max_samples: int | None = None) -> Iterator[MoveHalf | SetAside]:
        """Yield each ``MoveSamples`` message as a :class:`~galvo_sysid.monitor.moves.MoveHalf`.

        A message in plain CDR (what rosbag2 records) is read by
        :func:`~galvo_sysid.interfaces.messages.read_move_samples`, its samples straight into
        an array (the values rosbags' deserializer gives, without building a message); any
        other by rosbags. A message that cannot be decoded or converted is yielded as
        :class:`SetAside` instead; reading goes on. With ``max_samples``, a record longer
        than that is refused before its samples are decoded (its length is read from the
        serialized bytes): a :class:`SetAside` carrying the record's fields.

        Raises:
            NoGalvoTopicsError, WrongTopicTypeError, CorruptBagError: see
                :meth:`galvo_topics` and :meth:`raw_messages`.
        """
        from galvo_sysid.interfaces.messages import move_half_from_msg, read_move_samples
        from galvo_sysid.monitor.moves import too_long

        current, encoder = self.galvo_topics(namespace=namespace)
        signals = {current: 'current', encoder: 'encoder'}
        for raw in self.raw_messages([current, encoder]):
            signal = signals[raw.topic]
            try:
                head = read_move_samples(raw.data)
            except GalvoSysidError:
                head = None  # not plain CDR: decoded below, or set aside with the reason
            if head is not None:  # plain CDR: its samples straight into an array
                if max_samples is not None and head.samples > max_samples:
                    yield SetAside(raw.topic, raw.timestamp * 1e-9,
                                   too_long(signal, head.samples, max_samples),
                                   half=head.header_half(signal))
                else:
                    yield head.half(signal)
                continue
            try:
                msg = self.deserialize(raw)
                half = move_half_from_msg(msg, signal=signals[raw.topic])
            except GalvoSysidError as err:
                yield SetAside(raw.topic, raw.timestamp * 1e-9, reason(err))
                continue
            yield half

    def feed(self, windower: MoveWindower, *, namespace: str | None = None
             ) -> Iterator[tuple[MoveHalf | None, list[Window], SetAside | None]]:
        """Feed every move half of the bag to ``windower``, message by message.

        Records longer than ``windower.max_samples`` are refused before decoding and set
        aside by the windower as their move (:meth:`MoveWindower.refuse`).

        Yields:
            Per message: the half taken (None if it was not), the windows it completed, and
            the message if it could not be read at all (else None).

        Raises:
            NoGalvoTopicsError, WrongTopicTypeError, CorruptBagError: as
                :meth:`move_halves`.
        """
        for item in self.move_halves(namespace=namespace, max_samples=windower.max_samples):
            if not isinstance(item, SetAside):
                yield item, windower.add(item), None
            elif item.half is not None:  # refused before decoding: its move set aside
                windower.refuse(item.half, item.reason)
                yield None, [], None
            else:
                yield None, [], item


def _storage_counts(reader: AnyReader) -> tuple[dict[str, int], int, int] | None:
    """Messages per topic, first and (one past the) last log time, as the storage files of
    bag directories hold them (``metadata.yaml`` only claims its counts); None if the bag
    has no ``metadata.yaml`` (the counts already are the storage's) or rosbags' internals
    are not as expected."""  # noqa: D205, D209
    counts: dict[str, int] = {}
    start, end = 2**63 - 1, 0
    found = False
    for bag in getattr(reader, 'readers', ()):
        storages = getattr(getattr(bag, 'storage', None), 'storages', None)
        if storages is None:  # a bare storage file: its counts are its own
            return None
        found = True
        for storage in storages:
            for conn in getattr(storage, 'connections', ()):
                counts[conn.topic] = counts.get(conn.topic, 0) + int(conn.msgcount)
            meta = getattr(storage, 'metadata', None)
            if meta is not None and meta.message_count:
                start, end = min(start, int(meta.start_time)), max(end, int(meta.end_time))
    return (counts, start, end) if found else None


def _transient_local(conn: Connection) -> bool:
    ext = conn.ext
    if not isinstance(ext, ConnectionExtRosbag2):
        return False
    return any(q.durability == QosDurability.TRANSIENT_LOCAL for q in ext.offered_qos_profiles)

