"""Writing rosbag2 bags with the message definitions stored: :class:`BagWriter`.

Writing::

    with BagWriter('out/run1', storage='mcap') as bag:
        bag.add_topic(CURRENT_TOPIC, MOVE_SAMPLES)
        bag.write_raw(CURRENT_TOPIC, timestamp_ns, cdr_bytes)
"""

from __future__ import annotations

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
from galvo_sysid.field.bags.errors import BagError, BagExistsError, reason
from galvo_sysid.interfaces.topics import MOVE_SAMPLES

if TYPE_CHECKING:
    import os

    from numpy.typing import ArrayLike
    from rosbags.interfaces import Connection

__all__ = ['BagWriter']

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


class BagWriter(BagFile):
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

    def open(self) -> None:
        """Create the bag directory and storage file."""
        try:
            self._writer.open()
        except WriterError as err:
            raise BagExistsError(reason(err)) from None
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
        package, name = split_type(msgtype)
        msgtype = f'{package}/msg/{name}'
        if topic in self._connections:
            msg = f'topic {topic} added twice'
            raise BagError(msg)
        ensure_type(self.typestore, msgtype)
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
