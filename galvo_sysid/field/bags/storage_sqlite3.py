"""rosbags' sqlite3 storage writer, crash-safe: a killed recording keeps its committed batches.

rosbags' sqlite3 storage (:class:`Sqlite3Storage`: same schema, same files as rosbags and
``ros2 bag`` write), messages committed in batches (1 s of messages or 4 MiB, whichever
first, when ``flush_interval`` is set); a killed recording keeps every committed batch
(sqlite3's journal undoes the half-written one).

A failed write (``OSError``: a full disk, a quota, an I/O error; sqlite3's "database or disk
is full" becomes one) is raised; the storage can still be closed
(:meth:`~Sqlite3Storage.discard_pending`, then ``close``) so that everything committed before
stays readable.
"""

from __future__ import annotations

import contextlib
import errno
import os
import sqlite3
import time
from typing import TYPE_CHECKING, Any

from rosbags.rosbag2.storage_sqlite3 import Sqlite3Writer

from galvo_sysid.field.bags.metadata import ROS_DISTRO

if TYPE_CHECKING:
    from pathlib import Path

    from rosbags.interfaces import Connection
    from rosbags.rosbag2.enums import CompressionMode

__all__ = ['SQLITE_BATCH_BYTES', 'Sqlite3Storage']

SQLITE_BATCH_BYTES = 4 << 20
"""An sqlite3 batch is committed when its messages exceed this many bytes."""


def _full(err: sqlite3.Error) -> OSError:
    """An sqlite3 write error as the OSError it stands for."""
    text = str(err)
    code = errno.ENOSPC if 'full' in text else errno.EIO
    return OSError(code, f'{os.strerror(code)} ({text})')


class Sqlite3Storage(Sqlite3Writer):
    """rosbags' sqlite3 storage, committed in batches (see the module docs).

    ``flush_interval`` (seconds, None: commit at close only, as rosbags does) is set by the
    owner after the writer opened the storage.
    """

    SQLITE_SCHEMA = Sqlite3Writer.SQLITE_SCHEMA.replace(
        "ros_distro) VALUES (4, 'rosbags')", f"ros_distro) VALUES (4, '{ROS_DISTRO}')")
    """rosbags' schema with the bag's ``ros_distro`` (the ``schema`` table ``ros2 bag`` writes)."""

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
