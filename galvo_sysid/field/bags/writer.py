"""Writing rosbag2 bags with the message definitions stored: :class:`BagWriter`.

Writing::

    with BagWriter('out/run1', storage='mcap') as bag:
        bag.add_topic(CURRENT_TOPIC, MOVE_SAMPLES)
        bag.write_raw(CURRENT_TOPIC, timestamp_ns, cdr_bytes)

A recording (``flush_interval`` set) survives a crash and a full disk: messages reach the
file at least every ``flush_interval`` seconds (:mod:`galvo_sysid.field.bags.storage_mcap`,
:mod:`galvo_sysid.field.bags.storage_sqlite3`), an interim ``metadata.yaml`` marked as an
unfinished recording is kept up to date (atomically) so that readers say the bag is
incomplete and ``galvo-sysid bag recover`` can finish it, and a locked reserve file in the
bag holds the disk space that closing the bag needs. On a failed write
(:class:`BagWriteError`) the bag is closed with everything written before.
"""

from __future__ import annotations

import contextlib
import fcntl
import os
from pathlib import Path
from typing import TYPE_CHECKING, Literal

from rosbags.interfaces import (
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

from galvo_sysid.field.bags.base import BagFile
from galvo_sysid.field.bags.definitions import ensure_type, galvo_typestore, split_type, stamp_to_ns
from galvo_sysid.field.bags.errors import BagError, BagExistsError, BagWriteError, reason
from galvo_sysid.field.bags.metadata import StoredTopic, bag_metadata, metadata_text
from galvo_sysid.field.bags.storage_mcap import McapStorage
from galvo_sysid.field.bags.storage_sqlite3 import Sqlite3Storage
from galvo_sysid.interfaces.topics import MOVE_SAMPLES

if TYPE_CHECKING:
    from collections.abc import Mapping

    from numpy.typing import ArrayLike
    from rosbags.interfaces import Connection

__all__ = ['LOCK_NAME', 'RECORDING_KEY', 'BagWriter', 'RecordingLock']

RECORDING_KEY = 'galvo_sysid.recording'
"""``custom_data`` key of the interim ``metadata.yaml`` of a recording not closed yet."""

LOCK_NAME = '.galvo_sysid_recording'
"""The reserve file in a bag being recorded; locked (``flock``) by the recording process."""

RESERVE_BYTES = 256 * 1024
"""Least disk space held back for closing a recording [bytes]."""

_INFINITE = QosTime(2147483647, 4294967295)


def _qos(*, reliable: bool, transient_local: bool, depth: int | None) -> Qos:
    """The offered QoS as rosbag2 stores it (``depth`` 0: keep all; None: history unknown,
    as a publisher discovered on the graph reports it)."""  # noqa: D205, D209
    if depth is None:
        history, depth = QosHistory.UNKNOWN, 0
    else:
        history = QosHistory.KEEP_ALL if depth == 0 else QosHistory.KEEP_LAST
    return Qos(
        history=history,
        depth=depth,
        reliability=QosReliability.RELIABLE if reliable else QosReliability.BEST_EFFORT,
        durability=QosDurability.TRANSIENT_LOCAL if transient_local else QosDurability.VOLATILE,
        deadline=_INFINITE,
        lifespan=_INFINITE,
        liveliness=QosLiveliness.AUTOMATIC,
        liveliness_lease_duration=_INFINITE,
        avoid_ros_namespace_conventions=False,
    )


class _Writer(Writer):
    """rosbags' writer with the crash-safe McapStorage and Sqlite3Storage."""

    STORAGE_PLUGINS = {StoragePlugin.SQLITE3: Sqlite3Storage,  # noqa: RUF012
                       StoragePlugin.MCAP: McapStorage}

    @property
    def durable(self) -> McapStorage | Sqlite3Storage:
        """The open storage."""
        storage = self.storage
        if not isinstance(storage, McapStorage | Sqlite3Storage):
            msg = f'bag {self.path} is not open'
            raise BagError(msg)
        return storage

    def close(self) -> None:
        """Close the storage and write ``metadata.yaml`` with what the storage holds.

        The metadata (in the storage and in ``metadata.yaml``) is :func:`bag_metadata`'s, as
        the interim one and the recovery write it: ``ros_distro`` Jazzy, each topic's offered
        QoS as given to :meth:`BagWriter.add_topic`.
        """
        storage = self.durable
        storage.flush()
        # what reached the file (equal to what was written, unless a write failed)
        counts = storage.durable_counts
        topics = [StoredTopic(c.topic, c.msgtype, counts.get(c.id, 0),
                              list(getattr(c.ext, 'offered_qos_profiles', [])), c.digest)
                  for c in self.connections]
        info = bag_metadata(storage='mcap' if isinstance(storage, McapStorage) else 'sqlite3',
                            file_name=storage.path.name, topics=topics,
                            span=storage.durable_span)
        storage.close(self.version, metadata_text(info, inner=True).strip())
        self.storage = None
        tmp = self.metapath.with_suffix('.yaml.tmp')
        tmp.write_text(metadata_text(info), 'utf8')
        tmp.replace(self.metapath)


class RecordingLock:
    """The locked reserve file of a bag being recorded (see :data:`LOCK_NAME`).

    Holds disk space that closing the bag needs; :meth:`free` gives it back when the disk
    is full. Its ``flock`` tells other processes that the bag is still being written; the
    kernel drops the lock when the process ends, also when it is killed.
    """

    def __init__(self, bag: Path, size: int = RESERVE_BYTES) -> None:
        self.path = bag / LOCK_NAME
        self.size = 0
        self._fd = os.open(self.path, os.O_RDWR | os.O_CREAT | os.O_EXCL, 0o644)
        try:
            fcntl.flock(self._fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            self.grow(size)
        except OSError:
            self.close()
            raise

    def grow(self, size: int) -> None:
        """Hold at least ``size`` bytes (written, so that they are allocated)."""
        block = os.urandom(64 * 1024)  # incompressible: a compressing filesystem allocates it
        while self.size < size:
            self.size += os.pwrite(self._fd, block, self.size)

    def free(self) -> None:
        """Give the reserved space back (the lock stays)."""
        with contextlib.suppress(OSError):
            os.ftruncate(self._fd, 0)
        self.size = 0

    def close(self) -> None:
        """Remove the file and drop the lock (idempotent)."""
        fd, self._fd = self._fd, -1
        if fd >= 0:
            with contextlib.suppress(OSError):
                self.path.unlink()
            os.close(fd)

    @staticmethod
    def held(bag: Path) -> bool:
        """Whether a live process holds the lock of the bag ``bag``."""
        try:
            fd = os.open(bag / LOCK_NAME, os.O_RDONLY)
        except OSError:
            return False
        try:
            fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
        except OSError:
            return True
        finally:
            os.close(fd)
        return False


class BagWriter(BagFile):
    """Write a new rosbag2 bag with message definitions stored.

    Args:
        path: Bag directory to create (must not exist).
        storage: ``'mcap'`` (default, zstd-compressed chunks when ``compress``) or
            ``'sqlite3'``.
        compress: Compress mcap chunks with zstd (readable by ``ros2 bag`` and rosbags).
        flush_interval: A recording: write messages to the file at least every this many
            seconds, keep an interim ``metadata.yaml`` and a disk-space reserve (see the
            module docs); call :meth:`tick` now and then when no message comes. None: write
            by size only (1 MiB mcap chunks, one sqlite3 transaction), as rosbags does.

    Raises:
        BagExistsError: ``path`` exists.
        BagError: Unknown storage, or ``flush_interval`` not positive.
    """

    def __init__(self, path: str | os.PathLike[str], *,
                 storage: Literal['mcap', 'sqlite3'] | str = 'mcap',
                 compress: bool = True, flush_interval: float | None = None) -> None:
        self.path = Path(path)
        if storage not in {'mcap', 'sqlite3'}:
            msg = f'unknown storage {storage!r}: use mcap or sqlite3'
            raise BagError(msg)
        if flush_interval is not None and not flush_interval > 0:
            msg = f'flush interval must be positive, got {flush_interval}'
            raise BagError(msg)
        if self.path.exists():
            msg = f'output bag exists already, not overwriting: {self.path}'
            raise BagExistsError(msg)
        self.storage = storage
        self.flush_interval = flush_interval
        plugin = StoragePlugin.MCAP if storage == 'mcap' else StoragePlugin.SQLITE3
        self._writer = _Writer(self.path, version=Writer.VERSION_LATEST, storage_plugin=plugin)
        if storage == 'mcap' and compress:
            self._writer.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
        self.typestore = galvo_typestore()
        self._connections: dict[str, Connection] = {}
        self._types: dict[str, str] = {}
        self._open = False
        self._lock: RecordingLock | None = None
        self._flushes = 0
        self.error: BagWriteError | None = None
        self.count = 0

    def open(self) -> None:
        """Create the bag directory and storage file (and, for a recording, the interim
        ``metadata.yaml`` and the reserve).

        Raises:
            BagExistsError: The bag exists.
            BagWriteError: The bag cannot be written (e.g. the disk is full).
        """  # noqa: D205
        try:
            self._writer.open()
        except WriterError as err:
            raise BagExistsError(reason(err)) from None
        except OSError as err:  # the storage file (e.g. a full disk)
            with contextlib.suppress(OSError):
                self.path.rmdir()
            msg = f'cannot create bag {self.path}: {reason(err)}'
            raise BagWriteError(msg) from None
        self._open = True
        if self.flush_interval is None:
            return
        self._writer.durable.flush_interval = self.flush_interval
        try:
            self._lock = RecordingLock(self.path)
            self._write_interim()
        except OSError as err:
            self._fail(err)
            raise self._raised() from None

    def close(self) -> None:
        """Write the index and ``metadata.yaml`` (idempotent).

        Raises:
            BagWriteError: Writing failed; the bag keeps what was written before.
        """
        if not self._open:
            return
        self._open = False
        try:
            self._writer.close()
        except OSError as err:
            self._open = True
            self._fail(err)
            raise self._raised() from None
        finally:
            if self._lock is not None:
                self._lock.close()

    def tick(self) -> None:
        """Write pending messages that are ``flush_interval`` old (call when idle).

        Raises:
            BagWriteError: Writing failed: the bag is closed with what was written before.
        """
        if self._open and self.error is None and self._writer.durable.due():
            self.flush()

    def flush(self) -> None:
        """Write pending messages to the file now (an mcap chunk, an sqlite3 commit).

        Raises:
            BagWriteError: Writing failed: the bag is closed with what was written before.
        """
        self._check_writable()
        try:
            self._writer.durable.flush()
            self._after_write()
        except OSError as err:
            self._fail(err)
            raise self._raised() from None

    @property
    def kept(self) -> int:
        """Messages written to the file so far (fewer than :attr:`count` while some wait)."""
        storage = self._writer.storage
        if isinstance(storage, McapStorage | Sqlite3Storage):
            return sum(storage.durable_counts.values())
        return sum(self._writer.counts.values()) if self.error is None else self._kept

    _kept = 0

    @property
    def topics(self) -> dict[str, str]:
        """Topics added so far and their types."""
        return dict(self._types)

    def add_topic(self, topic: str, msgtype: str, *, reliable: bool = True,
                  transient_local: bool = False, depth: int | None = 10) -> None:
        """Add a topic; its type's definition is stored in the bag.

        Args:
            topic: Topic name.
            msgtype: ``pkg/msg/Name``; must be a standard Jazzy type, a ``galvo_sysid_msgs``
                type, or have its ``.msg`` installed under ``<prefix>/share``.
            reliable: The offered QoS was reliable (stored in the metadata for players).
            transient_local: The offered QoS was transient local.
            depth: The offered history depth (0: keep all; None: not known, as for a
                publisher discovered on a live graph: stored as history ``unknown``).

        Raises:
            BagError: Topic added twice, or the type's definition is not found.
        """
        package, name = split_type(msgtype)
        msgtype = f'{package}/msg/{name}'
        if topic in self._connections:
            msg = f'topic {topic} added twice'
            raise BagError(msg)
        ensure_type(self.typestore, msgtype)
        qos = _qos(reliable=reliable, transient_local=transient_local, depth=depth)
        self._check_writable()
        try:
            self._connections[topic] = self._writer.add_connection(
                topic, msgtype, typestore=self.typestore, offered_qos_profiles=[qos])
            self._types[topic] = msgtype
            if self.flush_interval is not None:
                self._write_interim()
        except OSError as err:
            self._fail(err)
            raise self._raised() from None

    def write_raw(self, topic: str, timestamp: int, data: bytes | memoryview) -> None:
        """Store already serialized CDR bytes at log time ``timestamp`` [ns].

        Raises:
            BagError: The topic was not added.
            BagWriteError: Writing failed (e.g. the disk is full): the bag is closed with
                everything written before, and every later call raises the same error.
        """
        conn = self._connections.get(topic)
        if conn is None:
            msg = f'topic {topic} was not added to bag {self.path}'
            raise BagError(msg)
        self._check_writable()
        try:
            self._writer.write(conn, timestamp, data)
            self.count += 1
            self._after_write()
        except OSError as err:
            self._fail(err)
            raise self._raised() from None

    def write(self, topic: str, timestamp: int, message: object) -> None:
        """Serialize a rosbags message object (see :attr:`typestore`) and store it."""
        data = self.typestore.serialize_cdr(message, self._types[topic])
        self.write_raw(topic, timestamp, data)

    # ------------------------------------------------------------------ recording, failures

    def _check_writable(self) -> None:
        if self.error is not None:
            raise self._raised()
        if not self._open:
            msg = f'bag {self.path} is not open'
            raise BagError(msg)

    def _raised(self) -> BagWriteError:
        assert self.error is not None
        return self.error

    def _after_write(self) -> None:
        """After a chunk or batch reached the file: interim metadata, a larger reserve."""
        storage = self._writer.durable
        if self.flush_interval is None or storage.flushes == self._flushes:
            return
        self._flushes = storage.flushes
        self._write_interim()
        if self._lock is not None:
            need = 64 * 1024 + 2 * storage.summary_bytes() + 4096 * len(self._types)
            if need > self._lock.size:
                self._lock.grow(need + RESERVE_BYTES // 2)

    def interim_metadata(self) -> Mapping[str, object]:
        """``metadata.yaml``'s content for what the storage holds now, marked unfinished."""
        storage = self._writer.durable
        counts = storage.durable_counts
        topics = [StoredTopic(c.topic, c.msgtype, counts.get(c.id, 0),
                              list(getattr(c.ext, 'offered_qos_profiles', [])), c.digest)
                  for c in self._writer.connections]
        custom = {RECORDING_KEY: 'unfinished',
                  f'{RECORDING_KEY}.flush_interval': f'{self.flush_interval}'}
        return bag_metadata(storage=self.storage, file_name=storage.path.name, topics=topics,
                            span=storage.durable_span, custom=custom)

    def _write_interim(self) -> None:
        """Replace ``metadata.yaml`` atomically (a crash leaves the old or the new one)."""
        target = self.path / 'metadata.yaml'
        tmp = target.with_suffix('.yaml.tmp')
        tmp.write_text(metadata_text(self.interim_metadata()), 'utf8')
        tmp.replace(target)

    def _fail(self, err: OSError) -> None:
        """A write failed: close the bag with what reached the file; set :attr:`error`."""
        if self.error is not None:
            return
        storage = self._writer.storage
        lost = 0
        if self._lock is not None:
            self._lock.free()  # room for the summary and metadata.yaml
        if isinstance(storage, McapStorage | Sqlite3Storage):
            lost = storage.discard_pending()
            kept = sum(storage.durable_counts.values())
            span = storage.durable_span
        else:
            kept, span = 0, None
        self._open = False
        try:
            self._writer.close()
            seconds = (span[1] - span[0]) * 1e-9 if span else 0.0
            what = (f'the bag is closed and keeps the {kept:,} messages written before '
                    f'({seconds:.1f} s)')
        except Exception as again:  # the disk is still full, or worse
            with contextlib.suppress(Exception):
                self._writer.abort()
            what = (f'the bag keeps the {kept:,} messages written before but could not be '
                    f'closed ({reason(again)}): run galvo-sysid bag recover {self.path} '
                    f'once there is space')
        finally:
            if self._lock is not None:
                self._lock.close()
        self._kept = kept
        gone = f'; {lost:,} messages not yet written are lost' if lost else ''
        msg = f'cannot write bag {self.path}: {err.strerror or reason(err)}; {what}{gone}'
        self.error = BagWriteError(msg)

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
