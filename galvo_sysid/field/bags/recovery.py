"""Bags whose recording was interrupted: tell them apart, and make them readable again.

- :func:`check_complete` raises :class:`~galvo_sysid.field.bags.errors.IncompleteBagError`
  for a bag that was never closed: the interim ``metadata.yaml`` of a recording (see
  :mod:`galvo_sysid.field.bags.writer`) that still says "unfinished", an mcap file without
  its footer, or an sqlite3 file with a hot journal or without its closing metadata row. The
  reader calls it before opening a bag, so an interrupted recording is never read as empty.
- :func:`recover` (``galvo-sysid bag recover``) keeps what is on disk: for mcap, every chunk
  up to the first damaged byte (checked: length, decompression, checksum, records), cuts the
  rest and writes the summary and footer; for sqlite3, what was committed (sqlite3 rolls the
  half-written batch back). Then it writes ``metadata.yaml`` from what the storage holds
  (what ``ros2 bag reindex`` does) and says what it kept and what it dropped.
"""

from __future__ import annotations

import contextlib
import sqlite3
import stat
import struct
import sys
from binascii import crc32
from dataclasses import dataclass
from io import BytesIO
from pathlib import Path
from typing import TYPE_CHECKING, Any, BinaryIO

from lz4.frame import decompress as lz4_decompress  # type: ignore[import-untyped]
from rosbags.rosbag2.metadata import parse_qos

from galvo_sysid.errors import ConfigurationError
from galvo_sysid.field.bags.errors import (
    BagError,
    BagNotFoundError,
    CorruptBagError,
    IncompleteBagError,
    reason,
)
from galvo_sysid.field.bags.mcap_records import (
    MCAP_MAGIC,
    ChunkRecord,
    McapChannel,
    McapSchema,
    index_records,
)
from galvo_sysid.field.bags.metadata import StoredTopic, bag_metadata, metadata_text
from galvo_sysid.field.bags.storage_mcap import McapStorage
from galvo_sysid.field.bags.writer import LOCK_NAME, RECORDING_KEY, RecordingLock
from galvo_sysid.schema import load_yaml

if sys.version_info >= (3, 14):  # pragma: no cover
    from compression import zstd
else:
    from backports import zstd

if TYPE_CHECKING:
    import os

__all__ = ['Recovered', 'check_complete', 'recover']

_U16 = struct.Struct('<H')
_U32 = struct.Struct('<I')
_U64 = struct.Struct('<Q')


# --------------------------------------------------------------------------- detection


def _storage_files(path: Path) -> list[Path]:
    if path.is_dir():
        return sorted([*path.glob('*.mcap'), *path.glob('*.db3')])
    return [path] if path.suffix in {'.mcap', '.db3'} else []


def _regular(path: Path) -> bool:
    try:
        return stat.S_ISREG(path.stat().st_mode)
    except OSError:
        return False


def _recording_marker(bag: Path) -> dict[str, str] | None:
    """The interim metadata's ``custom_data`` if it marks an unfinished recording."""
    meta = bag / 'metadata.yaml'
    if not _regular(meta):
        return None
    try:
        data = load_yaml(meta, what='bag metadata')
    except (ConfigurationError, OSError):
        return None  # the reader says what is wrong with it
    info = data.get('rosbag2_bagfile_information') if isinstance(data, dict) else None
    custom = info.get('custom_data') if isinstance(info, dict) else None
    if isinstance(custom, dict) and custom.get(RECORDING_KEY) == 'unfinished':
        return {str(k): str(v) for k, v in custom.items()}
    return None


def _mcap_state(path: Path) -> str:
    """'complete', 'cut' (mcap magic at the start, no footer) or 'foreign' (no magic)."""
    with path.open('rb') as f:
        size = f.seek(0, 2)
        f.seek(0)
        if f.read(8) != MCAP_MAGIC[:min(size, 8)] or size == 0:
            return 'foreign'
        if size < 8 + 37:
            return 'cut'
        f.seek(-8, 2)
        return 'complete' if f.read(8) == MCAP_MAGIC else 'cut'


def _sqlite_unfinished(path: Path, *, has_metadata: bool) -> str | None:
    """Why an sqlite3 file looks unfinished, or None."""
    for suffix in ('-journal', '-wal'):
        side = path.with_name(path.name + suffix)
        if _regular(side) and side.stat().st_size > 0:
            return f'sqlite3 left a {suffix[1:]} file: its writer did not finish'
    if has_metadata:
        return None
    try:
        conn = sqlite3.connect(f'file:{path}?immutable=1', uri=True)
        try:
            tables = {r[0] for r in conn.execute(
                "SELECT name FROM sqlite_master WHERE type='table'")}
            if 'metadata' in tables and conn.execute(
                    'SELECT count(*) FROM metadata').fetchone()[0] == 0:
                return 'the sqlite3 file has no closing metadata'
        finally:
            conn.close()
    except sqlite3.Error:
        return None  # not a database: the reader says so
    return None


def check_complete(path: str | os.PathLike[str]) -> None:
    """Raise if the bag (directory or storage file) was not closed by its writer.

    Raises:
        IncompleteBagError: One line: the bag is incomplete, why, and to run
            ``galvo-sysid bag recover``; or that it is still being recorded.
    """
    path = Path(path)
    if path.name == 'metadata.yaml':
        path = path.parent
    bag = path if path.is_dir() else path.parent
    shown = path
    fix = f'run galvo-sysid bag recover {shown}'
    if _recording_marker(bag) is not None:
        if RecordingLock.held(bag):
            msg = (f'bag {shown} is still being recorded (by a running process); it is '
                   f'readable once the recording stops')
            raise IncompleteBagError(msg)
        msg = f'bag {shown} is incomplete (recording was interrupted); {fix}'
        raise IncompleteBagError(msg)
    has_metadata = (bag / 'metadata.yaml').exists()
    for file in _storage_files(path):
        if not _regular(file):
            continue
        state = _mcap_state(file) if file.suffix == '.mcap' else 'complete'
        if state == 'foreign':
            msg = (f'cannot read bag {shown}: {file.name} is not an mcap file (no mcap magic '
                   f'at its start)')
            raise CorruptBagError(msg)
        if state == 'cut':
            msg = (f'bag {shown} is incomplete (the mcap file {file.name} has no footer: '
                   f'the recording was interrupted or the file was cut short); {fix}')
            raise IncompleteBagError(msg)
        if file.suffix == '.db3':
            why = _sqlite_unfinished(file, has_metadata=has_metadata)
            if why is not None:
                msg = f'bag {shown} is incomplete ({why}); {fix}'
                raise IncompleteBagError(msg)


# --------------------------------------------------------------------------- mcap scan


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


# --------------------------------------------------------------------------- recovery


@dataclass(frozen=True)
class Recovered:
    """What :func:`recover` kept.

    Attributes:
        path: The bag directory.
        storage: ``'mcap'`` or ``'sqlite3'``.
        messages: Messages the bag holds now.
        topics: Topics it holds.
        span: Log times of its first and last message [ns] (None: no message).
        dropped_bytes: Bytes cut from the end of the storage file (an unfinished or damaged
            record; its messages are lost).
        rolled_back: sqlite3 undid a batch that was being written (its messages are lost).
        repaired: The storage file was changed (else only ``metadata.yaml`` was written).
        interrupted: The bag was an unfinished recording.
        flush_interval: The recording's flush interval [s] (None: unknown): the messages
            received in about that time before the interruption were not yet written.
    """

    path: Path
    storage: str
    messages: int
    topics: int
    span: tuple[int, int] | None
    dropped_bytes: int = 0
    rolled_back: bool = False
    repaired: bool = False
    interrupted: bool = False
    flush_interval: float | None = None

    @property
    def seconds(self) -> float:
        """Time from the first to the last message kept [s]."""
        return (self.span[1] - self.span[0]) * 1e-9 if self.span else 0.0

    def summary(self) -> str:
        """One line: what was kept and what was lost."""
        held = (f'{self.messages:,} messages of {self.topics} topic'
                f'{"" if self.topics == 1 else "s"}, {self.seconds:.1f} s')
        if not (self.repaired or self.interrupted):
            return f'nothing to recover: {held} (metadata.yaml written from the storage file)'
        text = f'recovered {held}'

        lost = []
        if self.dropped_bytes:
            lost.append(f'cut {self.dropped_bytes:,} bytes of an unfinished chunk')
        if self.rolled_back:
            lost.append('rolled back the batch being written')
        if self.interrupted and self.flush_interval is not None:
            lost.append(f'messages of the last {self.flush_interval:g} s before the '
                        f'interruption (the flush interval) may be lost')
        return text + ('; ' + '; '.join(lost) if lost else '')


def recover(path: str | os.PathLike[str]) -> Recovered:
    """Make an interrupted (or unindexed) bag readable with what is on disk.

    Args:
        path: The bag directory, its ``metadata.yaml`` or its storage file.

    Raises:
        BagNotFoundError: No such path.
        CorruptBagError: Not a bag (no single ``.mcap`` or ``.db3`` file), or nothing
            readable in it.
        BagError: The bag is still being recorded.
    """
    path = Path(path)
    if not path.exists():
        msg = f'bag not found: {path}'
        raise BagNotFoundError(msg)
    bag = path if path.is_dir() else path.parent
    files = [f for f in _storage_files(bag) if _regular(f)]
    if len(files) != 1:
        msg = (f'not a rosbag2 bag: {bag} should hold one .mcap or .db3 file, '
               f'it holds {len(files)}')
        raise CorruptBagError(msg)
    if RecordingLock.held(bag):
        msg = f'bag {bag} is still being recorded by a running process: not recovering it'
        raise BagError(msg)
    marker = _recording_marker(bag)
    hashes = _old_hashes(bag)
    file = files[0]
    try:
        if file.suffix == '.mcap':
            result = _recover_mcap(file, hashes)
        else:
            result = _recover_sqlite(file, hashes)
    except OSError as err:
        msg = f'cannot recover bag {bag}: {reason(err)}'
        raise BagError(msg) from None
    topics, span = result.topics, result.span
    info = bag_metadata(storage='mcap' if file.suffix == '.mcap' else 'sqlite3',
                        file_name=file.name, topics=topics, span=span)
    tmp = bag / 'metadata.yaml.tmp'
    tmp.write_text(metadata_text(info), 'utf8')
    tmp.replace(bag / 'metadata.yaml')
    with contextlib.suppress(OSError):
        (bag / LOCK_NAME).unlink()
    interval = None
    if marker is not None:
        with contextlib.suppress(ValueError):
            interval = float(marker.get(f'{RECORDING_KEY}.flush_interval', ''))
    return Recovered(bag, info['storage_identifier'], sum(t.count for t in topics),
                     len(topics), span if topics and sum(t.count for t in topics) else None,
                     result.dropped, result.rolled_back, result.repaired, marker is not None,
                     interval)


@dataclass(frozen=True)
class _Result:
    topics: list[StoredTopic]
    span: tuple[int, int] | None
    dropped: int = 0
    rolled_back: bool = False
    repaired: bool = False


def _old_hashes(bag: Path) -> dict[str, str]:
    """Type hashes per topic from an existing ``metadata.yaml`` (if readable)."""
    meta = bag / 'metadata.yaml'
    if not _regular(meta):
        return {}
    try:
        data = load_yaml(meta, what='bag metadata')
        topics = data['rosbag2_bagfile_information']['topics_with_message_count']
        return {str(t['topic_metadata']['name']): str(t['topic_metadata'].get(
            'type_description_hash', '')) for t in topics}
    except (ConfigurationError, OSError, KeyError, TypeError, AttributeError):
        return {}


def _topics(reader: Any, hashes: dict[str, str]) -> list[StoredTopic]:
    return [StoredTopic(c.topic, c.msgtype, c.msgcount,
                        list(getattr(c.ext, 'offered_qos_profiles', [])),
                        c.digest or hashes.get(c.topic, ''),
                        getattr(c.ext, 'serialization_format', 'cdr'))
            for c in reader.connections]


def _span(reader: Any) -> tuple[int, int] | None:
    meta = reader.metadata
    return (meta.start_time, meta.end_time - 1) if meta.message_count else None


def _recover_mcap(file: Path, hashes: dict[str, str]) -> _Result:
    from rosbags.rosbag2.storage_mcap import McapReader

    scan = _scan_mcap(file)
    size = file.stat().st_size
    for channel in scan.channels.values():
        if channel.meta('topic_type_hash'):
            hashes.setdefault(channel.topic, channel.meta('topic_type_hash'))
    repaired = False
    dropped = 0
    if not (scan.complete and _mcap_state(file) == 'complete' and _reads(file)):
        if scan.loose:
            msg = (f'cannot recover {file}: it holds messages outside chunks (not a '
                   f'recording of galvo-sysid or rosbag2)')
            raise CorruptBagError(msg)
        counts: dict[int, int] = {}
        for chunk in scan.chunks:
            for cid, n in chunk.counts:
                counts[cid] = counts.get(cid, 0) + n
        schemas = sorted(scan.schemas.values(), key=lambda s: s.id)
        channels = sorted(scan.channels.values(), key=lambda c: c.id)
        names = {s.id: s.name for s in schemas}
        topics = [StoredTopic(c.topic, names.get(c.schema_id, ''), counts.get(c.id, 0),
                              parse_qos(c.meta('offered_qos_profiles') or []),
                              hashes.get(c.topic, ''), c.message_encoding)
                  for c in channels]
        times = [(c.start_time, c.end_time) for c in scan.chunks]
        span = (min(t[0] for t in times), max(t[1] for t in times)) if times else None
        inner = bag_metadata(storage='mcap', file_name=file.name, topics=topics, span=span)
        dropped = size - scan.end
        storage = McapStorage.resume(file, end=scan.end, schemas=schemas, channels=channels,
                                     chunks=scan.chunks)
        try:
            storage.append_raw(scan.tail)
            storage.close(9, metadata_text(inner, inner=True).strip())
        finally:
            storage.abort()
        repaired = True
    reader = McapReader(file)
    try:
        reader.open()
    except Exception as err:  # rosbags raises many types on a bad file
        msg = f'cannot recover {file}: the repaired file does not read back: {reason(err)}'
        raise CorruptBagError(msg) from None
    try:
        return _Result(_topics(reader, hashes), _span(reader), dropped, repaired=repaired)
    finally:
        reader.close()


def _reads(file: Path) -> bool:
    from rosbags.rosbag2.storage_mcap import McapReader

    reader = McapReader(file)
    try:
        reader.open()
    except Exception:  # any failure: repair it
        return False
    reader.close()
    return True


def _recover_sqlite(file: Path, hashes: dict[str, str]) -> _Result:
    from rosbags.rosbag2.storage_sqlite3 import Sqlite3Reader

    journal = any(_regular(file.with_name(file.name + s)) for s in ('-journal', '-wal'))
    try:
        conn = sqlite3.connect(file)  # read-write: sqlite3 rolls a hot journal back here
        try:
            check = conn.execute('PRAGMA quick_check').fetchone()
            if not check or check[0] != 'ok':
                msg = f'cannot recover {file}: the sqlite3 file is corrupt ({check})'
                raise CorruptBagError(msg)
            tables = {r[0] for r in conn.execute(
                "SELECT name FROM sqlite_master WHERE type='table'")}
            if not {'messages', 'topics'} <= tables:
                msg = f'cannot recover {file}: it has no bag tables (messages, topics)'
                raise CorruptBagError(msg)
        finally:
            conn.close()
        reader = Sqlite3Reader(file)
        reader.open()
        try:
            topics, span = _topics(reader, hashes), _span(reader)
        finally:
            reader.close()
        if 'metadata' in tables:  # what rosbag2 writes on closing: the bag is closed now
            inner = bag_metadata(storage='sqlite3', file_name=file.name, topics=topics,
                                 span=span)
            conn = sqlite3.connect(file)
            try:
                if conn.execute('SELECT count(*) FROM metadata').fetchone()[0] == 0:
                    conn.execute('INSERT INTO metadata(metadata_version, metadata) '
                                 'VALUES(?, ?)', (9, metadata_text(inner, inner=True).strip()))
                    conn.commit()
            finally:
                conn.close()
    except sqlite3.Error as err:
        msg = f'cannot recover {file}: {reason(err)}'
        raise CorruptBagError(msg) from None
    return _Result(topics, span, 0, rolled_back=journal, repaired=journal)
