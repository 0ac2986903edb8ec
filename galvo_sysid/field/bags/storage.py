"""Storage writers that keep what they wrote when the process dies or the disk fills up.

They plug into rosbags' rosbag2 :class:`~rosbags.rosbag2.Writer` (same storage protocol, same
files as rosbags and ``ros2 bag`` write) and differ in *when* bytes reach the file:

- :class:`McapStorage`: the mcap header, then each schema and channel record as soon as its
  topic is added, then messages in chunks. A chunk is closed when it holds 1 MiB or, if
  ``flush_interval`` is set, when its first message is that old; the chunk and its message
  indexes go to the file in one write, so the file always ends at a complete unit. The
  summary (schemas, channels, chunk indexes, statistics) and footer are written by
  :meth:`McapStorage.close`. A killed recording keeps every closed chunk (no footer: see
  :mod:`galvo_sysid.field.bags.recovery`, which adds one with :meth:`McapStorage.resume`).
- :class:`Sqlite3Storage`: rosbags' sqlite3 schema, messages committed in batches (1 s of
  messages or 4 MiB, whichever first, when ``flush_interval`` is set); a killed recording
  keeps every committed batch (sqlite3's journal undoes the half-written one).

A failed write (``OSError``: a full disk, a quota, an I/O error; sqlite3's "database or disk
is full" becomes one) cuts the file back to its last complete unit and is raised; the
storage can still be closed (:meth:`~McapStorage.discard_pending`, then ``close``) so that
everything written before stays readable. :func:`bag_metadata` builds the ``metadata.yaml``
content rosbag2 readers expect, from what a storage has durably written (used while
recording and by the recovery).
"""

from __future__ import annotations

import contextlib
import errno
import os
import sqlite3
import struct
import sys
import time
from binascii import crc32
from dataclasses import dataclass, field
from io import BytesIO
from typing import TYPE_CHECKING, Any

import yaml  # type: ignore[import-untyped]  # PyYAML ships no stubs here
from rosbags.interfaces import ConnectionExtRosbag2, MessageDefinitionFormat
from rosbags.rosbag2.enums import CompressionMode
from rosbags.rosbag2.metadata import dump_qos_v9
from rosbags.rosbag2.storage_sqlite3 import Sqlite3Writer

if sys.version_info >= (3, 14):  # pragma: no cover
    from compression import zstd
else:
    from backports import zstd

if TYPE_CHECKING:
    from collections.abc import Iterable, Mapping, Sequence
    from pathlib import Path

    from rosbags.interfaces import Connection, Qos

__all__ = [
    'CHUNK_BYTES',
    'MCAP_MAGIC',
    'SQLITE_BATCH_BYTES',
    'ChunkRecord',
    'McapChannel',
    'McapSchema',
    'McapStorage',
    'Sqlite3Storage',
    'StoredTopic',
    'bag_metadata',
    'chunk_and_indexes',
    'index_records',
    'mcap_record',
    'metadata_text',
]

MCAP_MAGIC = b'\x89MCAP0\r\n'
"""The 8 bytes that open and close an mcap file."""

CHUNK_BYTES = 1 << 20
"""An mcap chunk is closed when its uncompressed messages exceed this many bytes."""

SQLITE_BATCH_BYTES = 4 << 20
"""An sqlite3 batch is committed when its messages exceed this many bytes."""

_U16 = struct.Struct('<H')
_U32 = struct.Struct('<I')
_U64 = struct.Struct('<Q')


def _string(text: str | bytes) -> bytes:
    data = text.encode() if isinstance(text, str) else text
    return _U32.pack(len(data)) + data


def mcap_record(opcode: int, body: bytes) -> bytes:
    """One mcap record: opcode, length, body."""
    return bytes((opcode,)) + _U64.pack(len(body)) + body


@dataclass(frozen=True)
class McapSchema:
    """An mcap schema record (a message definition)."""

    id: int
    name: str
    encoding: str
    data: bytes

    def record(self) -> bytes:
        """The record's bytes."""
        return mcap_record(0x03, _U16.pack(self.id) + _string(self.name)
                           + _string(self.encoding) + _string(self.data))


@dataclass(frozen=True)
class McapChannel:
    """An mcap channel record (a topic), with its metadata (QoS, type hash)."""

    id: int
    schema_id: int
    topic: str
    message_encoding: str
    metadata: tuple[tuple[str, str], ...]

    def record(self) -> bytes:
        """The record's bytes."""
        entries = b''.join(_string(k) + _string(v) for k, v in self.metadata)
        return mcap_record(0x04, _U16.pack(self.id) + _U16.pack(self.schema_id)
                           + _string(self.topic) + _string(self.message_encoding)
                           + _string(entries))

    def meta(self, key: str) -> str:
        """A metadata value ('' if absent)."""
        return next((v for k, v in self.metadata if k == key), '')


@dataclass(frozen=True)
class ChunkRecord:
    """Where a chunk is in the file and what it holds: its summary's chunk index.

    Attributes:
        start_time, end_time: Log times of its first and last message [ns].
        offset, length: The chunk record's place in the file [bytes].
        index_offsets: ``(channel id, offset)`` of each of its message index records.
        index_length: Bytes of its message index records.
        compression, compressed_size, uncompressed_size: Of the chunk's data.
        counts: Messages per channel id.
    """

    start_time: int
    end_time: int
    offset: int
    length: int
    index_offsets: tuple[tuple[int, int], ...]
    index_length: int
    compression: str
    compressed_size: int
    uncompressed_size: int
    counts: tuple[tuple[int, int], ...]

    def index_record(self) -> bytes:
        """The summary's chunk index record."""
        offsets = b''.join(_U16.pack(c) + _U64.pack(o) for c, o in self.index_offsets)
        return mcap_record(0x08, _U64.pack(self.start_time) + _U64.pack(self.end_time)
                           + _U64.pack(self.offset) + _U64.pack(self.length)
                           + _string(offsets) + _U64.pack(self.index_length)
                           + _string(self.compression) + _U64.pack(self.compressed_size)
                           + _U64.pack(self.uncompressed_size))


def index_records(messages: Mapping[int, Sequence[tuple[int, int]]], *,
                  offset: int) -> tuple[bytes, tuple[tuple[int, int], ...]]:
    """A chunk's message index records (one per channel) and where each starts.

    Args:
        messages: Per channel id, ``(log time, offset in the chunk's data)`` of each message.
        offset: Where the records will start in the file.
    """
    out: list[bytes] = []
    offsets: list[tuple[int, int]] = []
    at = offset
    for cid, msgs in sorted(messages.items()):
        entries = b''.join(_U64.pack(t) + _U64.pack(o) for t, o in msgs)
        offsets.append((cid, at))
        out.append(mcap_record(0x07, _U16.pack(cid) + _string(entries)))
        at += len(out[-1])
    return b''.join(out), tuple(offsets)


def chunk_and_indexes(messages: Mapping[int, Sequence[tuple[int, int]]], data: bytes, *,
                      offset: int, compression: str) -> tuple[bytes, ChunkRecord]:
    """A chunk record and its message index records, and their chunk index.

    Args:
        messages: Per channel id, ``(log time, offset in data)`` of each message.
        data: The chunk's records, uncompressed.
        offset: Where the chunk will start in the file.
        compression: ``'zstd'`` or ``''``.
    """
    times = [t for msgs in messages.values() for t, _ in msgs]
    start, end = (min(times), max(times)) if times else (0, 0)
    packed = zstd.compress(data) if compression == 'zstd' else data
    chunk = mcap_record(0x06, _U64.pack(start) + _U64.pack(end) + _U64.pack(len(data))
                        + _U32.pack(crc32(data)) + _string(compression)
                        + _U64.pack(len(packed)) + packed)
    indexes, offsets = index_records(messages, offset=offset + len(chunk))
    return chunk + indexes, ChunkRecord(
        start, end, offset, len(chunk), offsets, len(indexes), compression, len(packed),
        len(data), tuple((c, len(m)) for c, m in sorted(messages.items())))


def _full(err: sqlite3.Error) -> OSError:
    """An sqlite3 write error as the OSError it stands for."""
    text = str(err)
    code = errno.ENOSPC if 'full' in text else errno.EIO
    return OSError(code, f'{os.strerror(code)} ({text})')


class McapStorage:
    """The mcap storage of rosbags' writer protocol, written so that a crash keeps its chunks.

    See the module docs. ``flush_interval`` (seconds, None: by size only) is set by the
    owner after the writer opened the storage.
    """

    def __init__(self, path: Path, compression: CompressionMode) -> None:
        self.path = path / f'{path.name}.mcap'
        self.compression = 'zstd' if compression == CompressionMode.STORAGE else ''
        self.flush_interval: float | None = None
        self.schemas: list[McapSchema] = []
        self.channels: list[McapChannel] = []
        self.chunks: list[ChunkRecord] = []
        self.flushes = 0
        self._fd = os.open(self.path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644)
        self._end = 0
        self._reset_pending()
        self._append(MCAP_MAGIC + mcap_record(0x01, _string('ros2') + _string('galvo_sysid')))

    @classmethod
    def resume(cls, path: Path, *, end: int, schemas: Sequence[McapSchema],
               channels: Sequence[McapChannel], chunks: Sequence[ChunkRecord],
               compression: str = 'zstd') -> McapStorage:
        """Reopen an mcap file whose first ``end`` bytes are good, to close it properly.

        The file is cut to ``end`` bytes; :meth:`close` then adds the summary and footer.
        """
        self = cls.__new__(cls)
        self.path = path
        self.compression = compression
        self.flush_interval = None
        self.schemas = list(schemas)
        self.channels = list(channels)
        self.chunks = list(chunks)
        self.flushes = 0
        self._fd = os.open(path, os.O_WRONLY)
        os.ftruncate(self._fd, end)
        self._end = end
        self._reset_pending()
        return self

    # ----------------------------------------------------------------- what is on disk

    @property
    def durable_counts(self) -> dict[int, int]:
        """Messages per channel id in closed chunks."""
        counts = {c.id: 0 for c in self.channels}
        for chunk in self.chunks:
            for cid, n in chunk.counts:
                counts[cid] = counts.get(cid, 0) + n
        return counts

    @property
    def durable_span(self) -> tuple[int, int] | None:
        """Log times of the first and last message in closed chunks (None: none yet)."""
        if not self.chunks:
            return None
        return (min(c.start_time for c in self.chunks), max(c.end_time for c in self.chunks))

    @property
    def pending_messages(self) -> int:
        """Messages not yet in the file."""
        return sum(len(m) for m in self._msgs.values())

    def summary_bytes(self) -> int:
        """About the bytes :meth:`close` still has to write (for a disk-space reserve)."""
        defs = sum(len(s.data) + 64 for s in self.schemas)
        chans = sum(len(c.topic) + 256 for c in self.channels)
        return 2 * defs + 2 * chans + 140 * len(self.chunks) + 8192

    # ----------------------------------------------------------------- writer protocol

    def add_msgtype(self, connection: Connection) -> None:
        """Store a message definition (written at once)."""
        fmt = 'ros2msg' if connection.msgdef.format == MessageDefinitionFormat.MSG else 'ros2idl'
        schema = McapSchema(len(self.schemas) + 1, connection.msgtype, fmt,
                            connection.msgdef.data.encode())
        self._append(schema.record())
        self.schemas.append(schema)

    def add_connection(self, connection: Connection, offered_qos_profiles: str) -> None:
        """Store a topic (written at once)."""
        ext = connection.ext
        encoding = ext.serialization_format if isinstance(ext, ConnectionExtRosbag2) else 'cdr'
        schema_id = next(s.id for s in self.schemas if s.name == connection.msgtype)
        channel = McapChannel(connection.id, schema_id, connection.topic, encoding,
                              (('offered_qos_profiles', offered_qos_profiles),
                               ('topic_type_hash', connection.digest)))
        self._append(channel.record())
        self.channels.append(channel)

    def write(self, connection: Connection, timestamp: int, data: bytes | memoryview) -> None:
        """Add a message to the open chunk; close the chunk when it is full or old enough."""
        if not self._msgs:
            self._since = time.monotonic()
        self._msgs.setdefault(connection.id, []).append((timestamp, self._buf.tell()))
        head = (_U16.pack(connection.id) + _U32.pack(0) + _U64.pack(timestamp)
                + _U64.pack(timestamp))
        self._buf.write(bytes((0x05,)) + _U64.pack(len(head) + len(data)) + head)
        self._buf.write(data)
        if self._buf.tell() > CHUNK_BYTES or self.due():
            self.flush()

    def due(self) -> bool:
        """Whether the open chunk is older than ``flush_interval``."""
        return (self.flush_interval is not None and bool(self._msgs)
                and time.monotonic() - self._since >= self.flush_interval)

    def flush(self) -> None:
        """Close the open chunk: write it and its message indexes to the file.

        Raises:
            OSError: The write failed; the file is cut back to its last complete chunk and
                the chunk stays pending.
        """
        if not self._msgs:
            return
        blob, record = chunk_and_indexes(self._msgs, self._buf.getvalue(), offset=self._end,
                                         compression=self.compression)
        self._append(blob)
        self.chunks.append(record)
        self.flushes += 1
        self._reset_pending()

    def append_raw(self, data: bytes) -> None:
        """Write records as they are at the end of the file (all or nothing)."""
        self._append(data)

    def discard_pending(self) -> int:
        """Drop the messages not yet written (after a failed write); return how many."""
        lost = self.pending_messages
        self._reset_pending()
        return lost

    def close(self, version: int, metadata: str) -> None:
        """Write the last chunk, the summary and the footer; close the file."""
        _ = version
        self.flush()
        start = self._end
        rec = _string('rosbag2') + _string(_string('serialized_metadata') + _string(metadata))
        parts = [mcap_record(0x0C, rec)]
        metadata_end = start + len(parts[0])
        parts.append(mcap_record(0x0F, _U32.pack(0)))  # data end
        at = metadata_end + len(parts[1])
        groups: list[tuple[int, int, int]] = []

        def group(opcode: int, records: Iterable[bytes]) -> None:
            nonlocal at
            blob = b''.join(records)
            if blob:
                groups.append((opcode, at, len(blob)))
                parts.append(blob)
                at += len(blob)

        summary_start = at
        group(0x03, (s.record() for s in self.schemas))
        group(0x04, (c.record() for c in self.channels))
        group(0x08, (c.index_record() for c in self.chunks))
        group(0x0D, [mcap_record(0x0D, _U64.pack(start) + _U64.pack(metadata_end - start)
                                 + _string('rosbag2'))])
        counts = self.durable_counts
        span = self.durable_span or (0, 0)
        stats = (_U64.pack(sum(counts.values())) + _U16.pack(len(self.schemas))
                 + _U32.pack(len(self.channels)) + _U32.pack(0) + _U32.pack(1)
                 + _U32.pack(len(self.chunks)) + _U64.pack(span[0]) + _U64.pack(span[1])
                 + _string(b''.join(_U16.pack(c) + _U64.pack(n)
                                    for c, n in sorted(counts.items()))))
        group(0x0B, [mcap_record(0x0B, stats)])
        offsets_start = at
        parts.extend(mcap_record(0x0E, bytes((op,)) + _U64.pack(s) + _U64.pack(n))
                     for op, s, n in groups)
        parts.append(mcap_record(0x02, _U64.pack(summary_start) + _U64.pack(offsets_start)
                                 + _U32.pack(0)))
        parts.append(MCAP_MAGIC)
        self._append(b''.join(parts))
        self.abort()

    def abort(self) -> None:
        """Close the file as it is (idempotent)."""
        fd, self._fd = self._fd, -1
        if fd >= 0:
            os.close(fd)

    # ----------------------------------------------------------------- internals

    def _reset_pending(self) -> None:
        self._buf = BytesIO()
        self._msgs: dict[int, list[tuple[int, int]]] = {}
        self._since = 0.0

    def _append(self, data: bytes) -> None:
        """Write ``data`` at the end of the good part of the file, all or nothing."""
        view = memoryview(data)
        done = 0
        try:
            while done < len(view):
                done += os.pwrite(self._fd, view[done:], self._end + done)
        except OSError:
            if done:
                with contextlib.suppress(OSError):
                    os.ftruncate(self._fd, self._end)
            raise
        self._end += len(view)


class Sqlite3Storage(Sqlite3Writer):
    """rosbags' sqlite3 storage, committed in batches (see the module docs).

    ``flush_interval`` (seconds, None: commit at close only, as rosbags does) is set by the
    owner after the writer opened the storage.
    """

    def __init__(self, path: Path, compression: CompressionMode) -> None:
        try:
            super().__init__(path, compression)
        except sqlite3.Error as err:
            raise _full(err) from None
        self.flush_interval: float | None = None
        self.flushes = 0
        self._durable: dict[int, int] = {}
        self._span: tuple[int, int] | None = None
        self._pending: dict[int, int] = {}
        self._pending_span: tuple[int, int] | None = None
        self._bytes = 0
        self._since = 0.0

    @property
    def durable_counts(self) -> dict[int, int]:
        """Messages per topic id committed."""
        return dict(self._durable)

    @property
    def durable_span(self) -> tuple[int, int] | None:
        """Log times of the first and last committed message (None: none yet)."""
        return self._span

    @property
    def pending_messages(self) -> int:
        """Messages not yet committed."""
        return sum(self._pending.values())

    def summary_bytes(self) -> int:
        """About the bytes closing still needs (the metadata row and its journal)."""
        return 64 * 1024

    def add_msgtype(self, connection: Connection) -> None:
        """Store a message definition (committed at once)."""
        self._run(super().add_msgtype, connection)

    def add_connection(self, connection: Connection, offered_qos_profiles: str) -> None:
        """Store a topic (committed at once)."""
        self._run(super().add_connection, connection, offered_qos_profiles)
        self._durable.setdefault(connection.id, 0)

    def write(self, connection: Connection, timestamp: int, data: bytes | memoryview) -> None:
        """Insert a message; commit the batch when it is large or old enough."""
        if not self._pending:
            self._since = time.monotonic()
        try:
            super().write(connection, timestamp, data)
        except sqlite3.Error as err:
            raise _full(err) from None
        self._pending[connection.id] = self._pending.get(connection.id, 0) + 1
        lo, hi = self._pending_span or (timestamp, timestamp)
        self._pending_span = (min(lo, timestamp), max(hi, timestamp))
        self._bytes += len(data)
        if self._bytes > SQLITE_BATCH_BYTES or self.due():
            self.flush()

    def due(self) -> bool:
        """Whether the open batch is older than ``flush_interval``."""
        return (self.flush_interval is not None and bool(self._pending)
                and time.monotonic() - self._since >= self.flush_interval)

    def flush(self) -> None:
        """Commit the open batch.

        Raises:
            OSError: The commit failed (the batch is rolled back, the database keeps every
                batch committed before).
        """
        if not self._pending:
            return
        try:
            self.conn.commit()
        except sqlite3.Error as err:
            raise _full(err) from None
        for cid, n in self._pending.items():
            self._durable[cid] = self._durable.get(cid, 0) + n
        if self._pending_span is not None:
            lo, hi = self._pending_span
            old = self._span or (lo, hi)
            self._span = (min(old[0], lo), max(old[1], hi))
        self.flushes += 1
        self._reset_pending()

    def discard_pending(self) -> int:
        """Roll the open batch back (after a failed write); return how many it held."""
        lost = self.pending_messages
        with contextlib.suppress(sqlite3.Error):
            self.conn.rollback()
        self._reset_pending()
        return lost

    def close(self, version: int, metadata: str) -> None:
        """Commit the last batch and the metadata row; close the database."""
        self.flush()
        try:
            self.cursor.execute(
                'INSERT INTO metadata(metadata_version, metadata) VALUES(?, ?)',
                (version, metadata))
            self.conn.commit()
            self.conn.close()
        except sqlite3.Error as err:
            raise _full(err) from None

    def _run(self, method: Any, *args: Any) -> None:
        try:
            method(*args)
            self.conn.commit()
        except sqlite3.Error as err:
            raise _full(err) from None

    def _reset_pending(self) -> None:
        self._pending = {}
        self._pending_span = None
        self._bytes = 0
        self._since = 0.0


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
        'ros_distro': 'rosbags',
    }


def metadata_text(info: Mapping[str, Any], *, inner: bool = False) -> str:
    """``metadata.yaml``'s text (``inner``: without the top key, as stored in the file)."""
    data = info if inner else {'rosbag2_bagfile_information': info}
    text: str = yaml.safe_dump(data, default_flow_style=False, sort_keys=False)
    return text
