"""An mcap file read record by record up to its first damaged byte (for the recovery).

:func:`_scan_mcap` keeps every chunk that checks (length, decompression, checksum, records)
with its message indexes (rebuilt when they are missing or damaged), and the schemas and
channels before it; :mod:`galvo_sysid.field.bags.recovery` cuts the rest and closes the file.
"""

from __future__ import annotations

import struct
import sys
from binascii import crc32
from dataclasses import dataclass
from io import BytesIO
from typing import TYPE_CHECKING, Any, BinaryIO

from lz4.frame import decompress as lz4_decompress  # type: ignore[import-untyped]

from galvo_sysid.field.bags.errors import CorruptBagError
from galvo_sysid.field.bags.mcap_records import (
    MCAP_MAGIC,
    ChunkRecord,
    McapChannel,
    McapSchema,
    index_records,
)

if sys.version_info >= (3, 14):  # pragma: no cover
    from compression import zstd
else:
    from backports import zstd

if TYPE_CHECKING:
    from pathlib import Path

__all__: list[str] = []

_U16 = struct.Struct('<H')
_U32 = struct.Struct('<I')
_U64 = struct.Struct('<Q')


class _DamagedError(Exception):
    """A record that cannot be used: the good part of the file ends before it."""


def _take(buf: BinaryIO, n: int) -> bytes:
    data = buf.read(n)
    if len(data) != n:
        raise _DamagedError
    return data


def _string(buf: BinaryIO) -> bytes:
    return _take(buf, _U32.unpack(_take(buf, 4))[0])


def _schema(body: bytes) -> McapSchema:
    b = BytesIO(body)
    sid = _U16.unpack(_take(b, 2))[0]
    return McapSchema(sid, _string(b).decode(), _string(b).decode(), _string(b))


def _channel(body: bytes) -> McapChannel:
    b = BytesIO(body)
    cid, sid = _U16.unpack(_take(b, 2))[0], _U16.unpack(_take(b, 2))[0]
    topic, encoding = _string(b).decode(), _string(b).decode()
    entries = BytesIO(_string(b))
    meta = []
    while entries.tell() < len(entries.getbuffer()):
        meta.append((_string(entries).decode(), _string(entries).decode()))
    return McapChannel(cid, sid, topic, encoding, tuple(meta))


_DECOMPRESS: dict[str, Any] = {'': lambda d: d, 'zstd': zstd.decompress,
                               'lz4': lz4_decompress}


@dataclass
class _Chunk:
    body_at: int
    length: int
    compression: str
    compressed_size: int
    messages: dict[int, list[tuple[int, int]]]
    data: bytes


def _chunk(body: bytes, at: int, schemas: dict[int, McapSchema],
           channels: dict[int, McapChannel]) -> _Chunk:
    """Check and parse a chunk record's body (schemas and channels inside it are kept)."""
    b = BytesIO(body)
    _take(b, 16)  # start, end: recomputed from the messages
    size = _U64.unpack(_take(b, 8))[0]
    crc = _U32.unpack(_take(b, 4))[0]
    compression = _string(b).decode()
    packed = _string_u64(b)
    if compression not in _DECOMPRESS or b.read(1):
        raise _DamagedError
    try:
        data = bytes(_DECOMPRESS[compression](packed))
    except Exception as err:
        raise _DamagedError from err
    if len(data) != size or (crc and crc32(data) != crc):
        raise _DamagedError
    inner = BytesIO(data)
    messages: dict[int, list[tuple[int, int]]] = {}
    while inner.tell() < size:
        where = inner.tell()
        op = _take(inner, 1)[0]
        rec = _take(inner, _U64.unpack(_take(inner, 8))[0])
        if op == 0x03:
            s = _schema(rec)
            schemas[s.id] = s
        elif op == 0x04:
            c = _channel(rec)
            channels[c.id] = c
        elif op == 0x05:
            if len(rec) < 22:
                raise _DamagedError
            cid = _U16.unpack_from(rec, 0)[0]
            log_time = _U64.unpack_from(rec, 6)[0]
            messages.setdefault(cid, []).append((log_time, where))
    if any(cid not in channels for cid in messages):
        raise _DamagedError
    return _Chunk(at, len(body), compression, len(packed), messages, data)


def _string_u64(buf: BinaryIO) -> bytes:
    return _take(buf, _U64.unpack(_take(buf, 8))[0])


def _index(body: bytes) -> tuple[int, list[tuple[int, int]]]:
    b = BytesIO(body)
    cid = _U16.unpack(_take(b, 2))[0]
    raw = _string(b)
    if len(raw) % 16 or b.read(1):
        raise _DamagedError
    return cid, [(_U64.unpack_from(raw, i)[0], _U64.unpack_from(raw, i + 8)[0])
                 for i in range(0, len(raw), 16)]


@dataclass
class _McapScan:
    end: int  # bytes kept
    schemas: dict[int, McapSchema]
    channels: dict[int, McapChannel]
    chunks: list[ChunkRecord]
    tail: bytes  # message indexes to write at ``end`` (for a chunk that lost its own)
    complete: bool  # the data section ended properly (a summary follows)
    loose: int  # messages outside chunks (not recovered)


_SUMMARY_OPS = {0x02, 0x08, 0x0A, 0x0B, 0x0D, 0x0E, 0x0F}


def _scan_mcap(path: Path) -> _McapScan:
    """Walk the file's records up to the first damaged byte."""
    scan = _McapScan(8, {}, {}, [], b'', complete=False, loose=0)
    with path.open('rb') as f:
        size = f.seek(0, 2)
        f.seek(0)
        if f.read(8) != MCAP_MAGIC:
            msg = f'{path} is not an mcap file (no mcap magic at its start)'
            raise CorruptBagError(msg)
        while True:
            f.seek(scan.end)
            head = f.read(9)
            if len(head) < 9:
                break
            op, length = head[0], _U64.unpack_from(head, 1)[0]
            if op in _SUMMARY_OPS:
                scan.complete = op == 0x0F
                break
            if scan.end + 9 + length > size or (op == 0x01 and scan.end != 8):
                break
            body = f.read(length)
            try:
                if op == 0x03:
                    schema = _schema(body)
                    scan.schemas[schema.id] = schema
                elif op == 0x04:
                    channel = _channel(body)
                    scan.channels[channel.id] = channel
                elif op == 0x05:
                    scan.loose += 1
                elif op == 0x06:
                    chunk = _chunk(body, scan.end, scan.schemas, scan.channels)
                    if not _add_chunk(f, chunk, size, scan):
                        break
                    continue
            except _DamagedError:
                break
            scan.end += 9 + length
    return scan


def _add_chunk(f: BinaryIO, chunk: _Chunk, size: int, scan: _McapScan) -> bool:
    """Add a good chunk with the message index records after it; False if these are missing
    or damaged (new ones go to ``scan.tail``; the file is kept up to the chunk's end)."""  # noqa: D205, D209
    chunk_end = chunk.body_at + 9 + chunk.length
    at = chunk_end
    found: dict[int, list[tuple[int, int]]] = {}
    offsets: list[tuple[int, int]] = []
    while True:
        f.seek(at)
        head = f.read(9)
        if len(head) < 9 or head[0] != 0x07:
            break
        length = _U64.unpack_from(head, 1)[0]
        if at + 9 + length > size:
            break
        try:
            cid, entries = _index(f.read(length))
        except _DamagedError:
            break
        found[cid] = entries
        offsets.append((cid, at))
        at += 9 + length
    times = [t for m in chunk.messages.values() for t, _ in m]
    counts = tuple((c, len(m)) for c, m in sorted(chunk.messages.items()))
    good = {c: sorted(m) for c, m in found.items()} == {c: sorted(m) for c, m in
                                                          chunk.messages.items()}
    if good:
        index_length = at - chunk_end
        scan.end = at
    else:
        scan.tail, rebuilt = index_records(chunk.messages, offset=chunk_end)
        offsets = list(rebuilt)
        index_length = len(scan.tail)
        scan.end = chunk_end
    scan.chunks.append(ChunkRecord(min(times, default=0), max(times, default=0), chunk.body_at,
                                   9 + chunk.length, tuple(offsets), index_length,
                                   chunk.compression, chunk.compressed_size, len(chunk.data),
                                   counts))
    return good
