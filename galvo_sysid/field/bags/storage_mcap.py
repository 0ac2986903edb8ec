"""The mcap storage writer, crash-safe: a killed recording keeps every chunk it closed.

It plugs into rosbags' rosbag2 :class:`~rosbags.rosbag2.Writer` (same storage protocol, same
files as rosbags and ``ros2 bag`` write) and differs in *when* bytes reach the file
(:class:`McapStorage`): the mcap header, then each schema and channel record as soon as its
topic is added, then messages in chunks. A chunk is closed when it holds 1 MiB or, if
``flush_interval`` is set, when its first message is that old; the chunk and its message
indexes go to the file in one write, so the file always ends at a complete unit. The summary
(schemas, channels, chunk indexes, statistics) and footer are written by
:meth:`McapStorage.close`. A killed recording keeps every closed chunk (no footer: see
:mod:`galvo_sysid.field.bags.recovery`, which adds one with :meth:`McapStorage.resume`).

A failed write (``OSError``: a full disk, a quota, an I/O error) cuts the file back to its
last complete unit and is raised; the storage can still be closed
(:meth:`~McapStorage.discard_pending`, then ``close``) so that everything written before
stays readable. The records themselves are :mod:`galvo_sysid.field.bags.mcap_records`.
"""

from __future__ import annotations

import contextlib
import os
import time
from io import BytesIO
from typing import TYPE_CHECKING

from rosbags.interfaces import ConnectionExtRosbag2, MessageDefinitionFormat
from rosbags.rosbag2.enums import CompressionMode

from galvo_sysid.field.bags.mcap_records import (
    _U16,
    _U32,
    _U64,
    MCAP_MAGIC,
    ChunkRecord,
    McapChannel,
    McapSchema,
    _string,
    chunk_and_indexes,
    mcap_record,
)

if TYPE_CHECKING:
    from collections.abc import Iterable, Sequence
    from pathlib import Path

    from rosbags.interfaces import Connection

__all__ = ['CHUNK_BYTES', 'McapStorage']

CHUNK_BYTES = 1 << 20
"""An mcap chunk is closed when its uncompressed messages exceed this many bytes."""


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
