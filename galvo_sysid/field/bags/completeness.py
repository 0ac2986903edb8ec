"""Whether a bag was closed by its writer: an interrupted recording is never read as empty.

:func:`check_complete` raises :class:`~galvo_sysid.field.bags.errors.IncompleteBagError` for a
bag that was never closed: the interim ``metadata.yaml`` of a recording (see
:mod:`galvo_sysid.field.bags.writer`) that still says "unfinished", an mcap file without its
footer, or an sqlite3 file with a hot journal or without its closing metadata row. The reader
calls it before opening a bag; :mod:`galvo_sysid.field.bags.recovery` makes such a bag
readable again.
"""

from __future__ import annotations

import sqlite3
import stat
from pathlib import Path
from typing import TYPE_CHECKING

from galvo_sysid.errors import ConfigurationError
from galvo_sysid.field.bags.errors import CorruptBagError, IncompleteBagError
from galvo_sysid.field.bags.mcap_records import MCAP_MAGIC
from galvo_sysid.field.bags.writer import RECORDING_KEY, RecordingLock
from galvo_sysid.schema import load_yaml

if TYPE_CHECKING:
    import os

__all__ = ['check_complete']


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
