"""Writing a bag atomically: it appears complete under its name, or not at all.

:func:`atomic_bag` hands out a place to write a bag next to where it should appear and
renames it into place when the writing succeeded; on any failure (an error, Ctrl-C) the
partial bag is removed. Used by every command that writes a bag from start to end
(``galvo-sysid simulate``); a live recording is written in place instead, so that a killed
recording keeps what it had.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
from pathlib import Path
from typing import TYPE_CHECKING

from galvo_sysid.field.bags.errors import BagError, BagExistsError

if TYPE_CHECKING:
    from collections.abc import Iterator

__all__ = ['PARTIAL_PREFIX', 'atomic_bag']

PARTIAL_PREFIX = '.partial-'
"""Start of the name of the hidden directory a bag is written in (``.partial-<name>-XXXX``).
A process killed outright (SIGKILL, power cut) leaves only such a directory: it never
blocks a re-run, and may be removed."""


@contextlib.contextmanager
def atomic_bag(path: str | os.PathLike[str]) -> Iterator[Path]:
    """Write a bag directory atomically: yield where to write it, rename it into place.

    The bag is written as ``<parent>/.partial-<name>-XXXX/<name>`` (the same file system, so
    the rename is atomic, and the storage file inside keeps its usual name ``<name>.mcap``)
    and renamed to ``path`` when the block ends without an exception. On an exception
    (including Ctrl-C) the partial bag is removed and the exception goes on: nothing is left
    under ``path`` to block a re-run.

    Raises:
        BagExistsError: ``path`` exists (before the writing, or when the bag is complete:
            then the new bag is removed, the existing one kept).
        BagError: The parent directory cannot be created or written.
    """
    final = Path(path)
    if final.exists() or final.is_symlink():
        msg = f'output bag exists already, not overwriting: {final}'
        raise BagExistsError(msg)
    parent = final.parent
    above = next((p for p in (parent, *parent.parents) if p.exists() or p.is_symlink()), None)
    if above is not None and not above.is_dir():
        msg = f'cannot write bag {final}: {above} is a file, not a directory'
        raise BagError(msg)
    try:
        parent.mkdir(parents=True, exist_ok=True)
        work = Path(tempfile.mkdtemp(prefix=f'{PARTIAL_PREFIX}{final.name}-', dir=parent))
    except OSError as err:
        msg = f'cannot write bag {final}: {err.strerror or err}'
        raise BagError(msg) from None
    try:
        yield work / final.name
        if final.exists() or final.is_symlink():
            msg = f'output bag exists already, not overwriting: {final}'
            raise BagExistsError(msg)
        os.rename(work / final.name, final)
    finally:
        shutil.rmtree(work, ignore_errors=True)
