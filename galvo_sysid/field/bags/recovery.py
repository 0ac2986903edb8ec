"""Bags whose recording was interrupted: make them readable again.

:func:`recover` (``galvo-sysid bag recover``) keeps what is on disk: for mcap, every chunk up
to the first damaged byte (checked: length, decompression, checksum, records;
:mod:`galvo_sysid.field.bags.mcap_scan`), cuts the rest (kept beside the file, byte for byte,
in ``<file>.cut``: a damaged chunk of a finished file may be followed by good ones) and writes
the summary and footer; for
sqlite3, what was committed (sqlite3 rolls the half-written batch back). Then it writes
``metadata.yaml`` from what the storage holds (what ``ros2 bag reindex`` does) and says what
it kept and what it dropped. Telling such a bag apart is
:func:`~galvo_sysid.field.bags.completeness.check_complete`.
"""

from __future__ import annotations

import contextlib
import sqlite3
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from rosbags.rosbag2.metadata import parse_qos

from galvo_sysid.errors import ConfigurationError
from galvo_sysid.field.bags.completeness import (
    _mcap_state,
    _recording_marker,
    _regular,
    _storage_files,
)
from galvo_sysid.field.bags.errors import (
    BagError,
    BagNotFoundError,
    CorruptBagError,
    reason,
)
from galvo_sysid.field.bags.mcap_scan import _scan_mcap
from galvo_sysid.field.bags.metadata import StoredTopic, bag_metadata, metadata_text
from galvo_sysid.field.bags.storage_mcap import McapStorage
from galvo_sysid.field.bags.writer import LOCK_NAME, RECORDING_KEY, RecordingLock
from galvo_sysid.schema import load_yaml

if TYPE_CHECKING:
    import os

__all__ = ['Recovered', 'recover']


@dataclass(frozen=True)
class Recovered:
    """What :func:`recover` kept.

    Attributes:
        path: The bag directory (the storage file, recovered ``alone``).
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
        cut_to: Where the bytes cut from the storage file were kept (None: none cut): a
            damaged chunk of a finished file may be followed by good ones, which are not
            thrown away.
        alone: The storage file was recovered on its own (its directory holds other bags'
            files, so no ``metadata.yaml`` was written there).
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
    cut_to: Path | None = None
    alone: bool = False

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
            kept = f' (kept in {self.cut_to})' if self.cut_to is not None else ''
            lost.append(f'cut {self.dropped_bytes:,} bytes from the first unfinished or '
                        f'damaged chunk on{kept}')
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
    # a storage file named among others of its directory (not a bag directory): that file
    alone = not path.is_dir() and path.suffix in {'.mcap', '.db3'} and len(files) > 1 \
        and not (bag / 'metadata.yaml').exists()
    if alone:
        files = [path]
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
    if not alone:
        tmp = bag / 'metadata.yaml.tmp'
        tmp.write_text(metadata_text(info), 'utf8')
        tmp.replace(bag / 'metadata.yaml')
        with contextlib.suppress(OSError):
            (bag / LOCK_NAME).unlink()
    interval = None
    if marker is not None:
        with contextlib.suppress(ValueError):
            interval = float(marker.get(f'{RECORDING_KEY}.flush_interval', ''))
    return Recovered(file if alone else bag, info['storage_identifier'],
                     sum(t.count for t in topics), len(topics),
                     span if topics and sum(t.count for t in topics) else None,
                     result.dropped, result.rolled_back, result.repaired, marker is not None,
                     interval, result.cut_to, alone)


@dataclass(frozen=True)
class _Result:
    topics: list[StoredTopic]
    span: tuple[int, int] | None
    dropped: int = 0
    rolled_back: bool = False
    repaired: bool = False
    cut_to: Path | None = None


def _keep_cut(file: Path, start: int) -> Path:
    """Copy the bytes of ``file`` from ``start`` on into a new file beside it (``<name>.cut``,
    or ``.cut.1``, ... where that exists); return its path."""  # noqa: D205, D209
    out = file.with_name(file.name + '.cut')
    n = 0
    while out.exists() or out.is_symlink():
        n += 1
        out = file.with_name(f'{file.name}.cut.{n}')
    with file.open('rb') as src, out.open('xb') as dst:
        src.seek(start)
        while block := src.read(1 << 20):
            dst.write(block)
    return out


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
    cut_to = None
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
        cut_to = _keep_cut(file, scan.end) if dropped else None
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
        return _Result(_topics(reader, hashes), _span(reader), dropped, repaired=repaired,
                       cut_to=cut_to)
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
