"""The mcap records a bag's file is made of, as bytes: schemas, channels, chunks, indexes.

What :mod:`~galvo_sysid.field.bags.storage_mcap` writes and
:mod:`galvo_sysid.field.bags.recovery` writes again for a file it repairs (mcap
specification: magic, opcode + length + body per record, little-endian).
"""

from __future__ import annotations

import struct
import sys
from binascii import crc32
from dataclasses import dataclass
from typing import TYPE_CHECKING

if sys.version_info >= (3, 14):  # pragma: no cover
    from compression import zstd
else:
    from backports import zstd

if TYPE_CHECKING:
    from collections.abc import Mapping, Sequence

__all__ = [
    'MCAP_MAGIC',
    'ChunkRecord',
    'McapChannel',
    'McapSchema',
    'chunk_and_indexes',
    'index_records',
    'mcap_record',
]

MCAP_MAGIC = b'\x89MCAP0\r\n'
"""The 8 bytes that open and close an mcap file."""

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
