"""Your own scanner data into a bag: what ``galvo-sysid import`` runs (no ROS needed).

Moves recorded by other means than a rosbag2 recording (a DSP log, a data-acquisition
program, MATLAB) are read from a CSV, NumPy ``.npz`` or MATLAB ``.mat`` file, checked, and
written into a standard rosbag2 bag exactly as ``galvo-sysid simulate`` writes its bags
(:func:`~galvo_sysid.field.simulate.write_move`): per move one ``MoveSamples`` on
``/galvo/current`` and one on ``/galvo/encoder`` with the same ``move_id``, header stamp and
log time the time of the move's first sample. Every tool then reads it (``identify``,
``commission``, ``discrepancy``, ``replay``, ``info``).

Units: current [A] (the current command, as the DSP computes it; a coil current measured
when the encoder is read is turned into the held current that drives it, given the
amplifier's lag: ``measured_lag``, :func:`held_from_measured`; or moved a sample earlier:
``current_lead``, :func:`lead_current`),
encoder [deg] (the raw angle; each record's first sample is its start angle), target angle
[deg] (the signed commanded rotation of the move, e.g. +0.3 forward and -0.3 back), sample
period [s], stamp [s].

NumPy ``.npz`` (``numpy.savez`` / ``savez_compressed``) and MATLAB ``.mat`` (v4, v6 and v7,
``save -v7``; v7.3 files, which are HDF5, are refused: save with ``-v7`` or write an .npz)
hold named arrays of real numbers (integers or floats)::

    name            shape                  meaning
    current         (moves, samples)       current [A], one row per move       (required)
    encoder         (moves, samples)       encoder [deg], one row per move     (required)
    target_angle    (moves,) or one value  signed target angle [deg] of each move, or of all
    sample_period   one value              sample period [s]
    stamp           (moves,)               time of each move's first sample [s], increasing
    move_id         (moves,)               whole numbers >= 0, all different
    length          (moves,)               samples used of each row: records of unequal
                                           length, padded to one width (the padding, even
                                           NaN, is ignored)

A one-dimensional ``current`` / ``encoder`` is one move. Vectors may be rows or columns
(MATLAB's (1, n) and (n, 1)). Other arrays in the file are ignored (the summary names them).

CSV (comma-separated; tab or semicolon if the header line uses it): a header line naming the
columns, then one row per sample, the rows of a move together and in sample order::

    move,current,encoder,target_angle
    0,0.1622,-3.8147e-05,0.3
    0,0.4851,-3.8147e-05,0.3
    ...
    1,-0.1617,0.30004,-0.3

Columns (any order; a name may carry its unit in brackets, ``current [A]``, which must be
the one below): ``move`` (or ``move_id``: the move's id, a whole number >= 0; required),
``current`` [A] and ``encoder`` [deg] (required), ``target_angle`` [deg], ``stamp`` [s]
(both the same on every row of a move) and ``sample_period`` [s] (the same on every row).
Every row has a number in every column; lines starting with ``#`` and blank lines are
skipped; other columns are ignored (the summary names them). The moves may have records of
different lengths.

Given as options instead (:func:`read_moves`' ``sample_period`` and ``target_angle``): the
sample period (required if the file has none) and one target angle for every move (used if
the file has none; given both ways, the two must agree). Without stamps the records are put
back to back from time 0 (a move's stamp: the samples before it times the sample period).
The windows ``identify`` forms depend only on the target angles; stamps matter there
through the sysid node's timeouts (``pair_timeout``, ``window_timeout``: a window not
complete 300 s after its first move, by stamps, is set aside).

Checks (each refusal is one :class:`~galvo_sysid.errors.InvalidDataError` line naming the
file, and the row, line or move): a required array or column missing; wrong shapes;
non-numeric cells or arrays (text, booleans, complex, cell arrays, objects); NaN or infinity;
an empty file or record; records shorter than :data:`MIN_SAMPLES`; current and encoder of
different lengths; a sample period outside :data:`SAMPLE_PERIOD_RANGE`; a target angle zero
(below 1e-6 deg) or beyond :data:`~galvo_sysid.ident.preprocess.MAX_ANGLE`; move ids
repeated or negative; stamps not increasing. And, unless turned off, the encoder's travel
against the target angles: a move that travels against its target angle (one target angle
given for moves that go both ways), or a median travel more than 10 times off the target
angle (an encoder in radians or counts).

Memory is bounded: a file larger than ``max_bytes`` (default :data:`MAX_BYTES`) is refused
from its size before it is read, and the arrays of an .npz or .mat file whose float64 size
would exceed it are refused from their headers before they are loaded (a compressed file
cannot expand beyond). The records are held in memory (about that much at most), then
written move by move into a bag that appears under its name only when complete
(:func:`~galvo_sysid.field.bags.atomic.atomic_bag`): a refused or failed import leaves no bag.
"""

from __future__ import annotations

import csv
import math
import time
import zipfile
import zlib
from collections import Counter
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from galvo_sysid.errors import ConfigurationError, InvalidDataError, one_line
from galvo_sysid.field.bags import CURRENT_TOPIC, ENCODER_TOPIC, BagExistsError, BagWriter
from galvo_sysid.field.bags.atomic import atomic_bag
from galvo_sysid.field.simulate import check_space, write_move
from galvo_sysid.ident.preprocess import MAX_ANGLE, TRAVEL_FACTOR, travels
from galvo_sysid.interfaces.topics import MOVE_SAMPLES

if TYPE_CHECKING:
    import os
    from collections.abc import Iterator, Mapping, Sequence

    from numpy.typing import ArrayLike, NDArray

__all__ = [
    'ARRAY_NAMES',
    'CSV_COLUMNS',
    'FORMATS',
    'MAX_BYTES',
    'MIN_SAMPLES',
    'SAMPLE_PERIOD_RANGE',
    'ImportSummary',
    'ImportedMove',
    'ImportedMoves',
    'held_from_measured',
    'import_bag',
    'lead_current',
    'moves_from_arrays',
    'read_moves',
    'write_bag',
]

FORMATS = ('csv', 'npz', 'mat')
"""The file formats read; by default told by the file's suffix (``.csv``/``.txt``/``.tsv``,
``.npz``, ``.mat``)."""

ARRAY_NAMES = ('current', 'encoder', 'target_angle', 'sample_period', 'stamp', 'move_id',
               'length')
"""The arrays an .npz or .mat file may hold (see the module docs); others are ignored."""

CSV_COLUMNS = {'move': '', 'current': 'A', 'encoder': 'deg', 'target_angle': 'deg',
               'stamp': 's', 'sample_period': 's'}
"""The CSV columns and their units (see the module docs); others are ignored."""

MAX_BYTES = 1 << 30
"""Default size limit [bytes]: of the file, and of the arrays read as float64 (1 GiB)."""

MIN_SAMPLES = 32
"""Fewest samples a record may have: the windower's ``min_samples``
(:class:`~galvo_sysid.monitor.pairing.MoveWindower` sets shorter records aside)."""

SAMPLE_PERIOD_RANGE = (1e-7, 0.1)
"""Sample periods accepted [s] (10 MHz to 10 Hz); a galvo's DSP samples at 10-100 kHz."""


_MIN_ANGLE = 1e-6
"""Smaller target angles [deg] are zero (the windower's ``angle_resolution``)."""

_MAX_STAMP = 2.0**31
"""Stamps must fit a ROS time (int32 seconds)."""


_MAT_NUMERIC = ('double', 'single', 'int8', 'uint8', 'int16', 'uint16', 'int32', 'uint32',
                'int64', 'uint64')


@dataclass(frozen=True)
class ImportedMove:
    """One move as it goes into the bag.

    Attributes:
        move_id: The move's id (>= 0).
        target_angle: Signed commanded rotation [deg].
        stamp: Time of the move's first sample [s].
        sample_period: Sampling period [s].
        current: Current [A], shape (N,).
        encoder: Encoder angle [deg], shape (N,).
    """

    move_id: int
    target_angle: float
    stamp: float
    sample_period: float
    current: NDArray[np.float64]
    encoder: NDArray[np.float64]


@dataclass(frozen=True)
class ImportedMoves:
    """The checked moves of a file (:func:`read_moves`) or of arrays (:func:`moves_from_arrays`).

    Attributes:
        moves: The moves, in the file's order.
        sample_period: Their sampling period [s].
        source: Where they came from (a file name, or ``'arrays'``).
        format: ``'csv'``, ``'npz'``, ``'mat'`` or ``'arrays'``.
        ignored: Arrays or columns of the file that were not read.
    """

    moves: tuple[ImportedMove, ...]
    sample_period: float
    source: str
    format: str
    ignored: tuple[str, ...] = ()

    @property
    def samples(self) -> int:
        """Samples per signal over all moves."""
        return sum(m.current.shape[0] for m in self.moves)

    @property
    def angles(self) -> dict[float, int]:
        """Moves per signed target angle, by angle."""
        return dict(sorted(Counter(m.target_angle for m in self.moves).items()))


@dataclass(frozen=True)
class ImportSummary:
    """What :func:`import_bag` wrote.

    Attributes:
        path: The bag.
        source: The file read.
        format: Its format.
        moves: Moves written.
        shortest: Samples of the shortest record.
        longest: Samples of the longest record.
        sample_period: The sample period [s].
        angles: Moves per signed target angle [deg].
        size: Bytes on disk.
        seconds: Wall-clock time taken [s].
        ignored: Arrays or columns of the file not read.
    """

    path: Path
    source: str
    format: str
    moves: int
    shortest: int
    longest: int
    sample_period: float
    angles: dict[float, int] = field(default_factory=dict)
    size: int = 0
    seconds: float = 0.0
    ignored: tuple[str, ...] = ()

    def __str__(self) -> str:
        records = (f'{self.shortest}' if self.shortest == self.longest
                   else f'{self.shortest} to {self.longest}')
        angles = ', '.join(f'{a:+g} deg x {n}' for a, n in self.angles.items())
        extra = f'; ignored: {", ".join(self.ignored)}' if self.ignored else ''
        return (f'import: {self.moves} moves from {self.source} ({self.format}), records of '
                f'{records} samples, sample period {self.sample_period * 1e6:.6g} us; target '
                f'angles {angles}{extra} -> {self.path} ({self.size / 1e6:.2f} MB) in '
                f'{self.seconds:.2f} s')


# --------------------------------------------------------------------------- entry points


def import_bag(source: str | os.PathLike[str], out: str | os.PathLike[str], *,
               format: str | None = None, sample_period: float | None = None,
               target_angle: float | None = None, storage: str = 'mcap',
               max_bytes: int = MAX_BYTES, check_travel: bool = True,
               frame_id: str = '', current_lead: int = 0,
               measured_lag: float | None = None) -> ImportSummary:
    """Read the moves of a CSV, .npz or .mat file and write them into a new bag.

    Args:
        source: The file (layouts: see the module docs).
        out: Bag directory to create.
        format: One of :data:`FORMATS`; default from the file's suffix.
        sample_period: Sample period [s] if the file has none (else it must agree).
        target_angle: One target angle [deg] for every move if the file has none (else it
            must agree).
        storage: ``'mcap'`` or ``'sqlite3'``.
        max_bytes: Size limit of the file and of its arrays as float64 [bytes].
        check_travel: Check the encoder's travel against the target angles.
        frame_id: Header frame id of the messages.
        current_lead: Samples by which the current record leads the encoder (see
            :func:`lead_current`); 0 as recorded.
        measured_lag: The current records are the coil current measured when the encoder
            is read, behind an amplifier lag of this time constant [s]: each is turned into
            the held current that drives it (:func:`held_from_measured`); None: the current
            is the command as recorded. Not with ``current_lead``.

    Raises:
        InvalidDataError: The file cannot be read or its data are refused (see the module
            docs); one line naming the file.
        ConfigurationError: Bad options; the bag would not fit on its disk.
        BagExistsError: ``out`` exists.
        OSError: Writing failed; nothing is left under ``out``.
    """
    start = time.perf_counter()
    path = Path(out)
    if path.exists() or path.is_symlink():  # before reading a large file
        msg = f'output bag exists already, not overwriting: {path}'
        raise BagExistsError(msg)
    if storage not in {'mcap', 'sqlite3'}:
        msg = f'unknown storage {storage!r}: use mcap or sqlite3'
        raise ConfigurationError(msg)
    _check_lead(current_lead)  # before reading a large file
    if measured_lag is not None:
        if current_lead:
            msg = ('a measured current is aligned with its encoder by its amplifier lag: '
                   'give the lag or a current lead, not both')
            raise ConfigurationError(msg)
        from galvo_sysid.ident.measured import check_lag

        check_lag(measured_lag, sample_period)  # before reading a large file
    moves = lead_current(read_moves(source, format=format, sample_period=sample_period,
                                    target_angle=target_angle, max_bytes=max_bytes,
                                    check_travel=check_travel), current_lead)
    if measured_lag is not None:
        moves = held_from_measured(moves, lag=measured_lag)
    write_bag(path, moves, storage=storage, frame_id=frame_id)
    size = sum(p.stat().st_size for p in path.rglob('*') if p.is_file())
    lengths = [m.current.shape[0] for m in moves.moves]
    return ImportSummary(path=path, source=moves.source, format=moves.format,
                         moves=len(moves.moves), shortest=min(lengths), longest=max(lengths),
                         sample_period=moves.sample_period, angles=moves.angles, size=size,
                         seconds=time.perf_counter() - start, ignored=moves.ignored)


def lead_current(moves: ImportedMoves, lead: int) -> ImportedMoves:
    """The moves with each current record ``lead`` samples earlier against its encoder.

    A coil current measured at the instant the encoder is read is the current that flowed
    before it; the model takes the current that flows over the next sample period (a
    command, held by the amplifier), which is the measured one a sample later.
    ``galvo-sysid commission`` says when data look like that. Each pair keeps the samples
    both records still cover: the current's from ``lead`` on, the encoder's up to its last
    ``lead``; the stamp stays the encoder's first sample's.

    Raises:
        ConfigurationError: ``lead`` is negative or not below 1000.
        InvalidDataError: A record would be left shorter than :data:`MIN_SAMPLES`.
    """
    _check_lead(lead)
    if not lead:
        return moves
    shortest = min(m.current.shape[0] for m in moves.moves)
    if shortest - lead < MIN_SAMPLES:
        msg = (f'{moves.source}: a current lead of {lead} samples leaves records of '
               f'{shortest - lead} samples; identification needs at least {MIN_SAMPLES}')
        raise InvalidDataError(msg)
    return replace(moves, moves=tuple(replace(m, current=m.current[lead:],
                                              encoder=m.encoder[:-lead])
                                      for m in moves.moves))


def held_from_measured(moves: ImportedMoves, *, lag: float) -> ImportedMoves:
    """The moves with each measured coil current made into the held current that drives it.

    A coil current read when the encoder is read, behind an amplifier lag of time constant
    ``lag`` [s] (0: none), becomes the held current the model takes, behind no computation
    delay and that lag (:func:`galvo_sysid.ident.measured.held_current`); each pair keeps
    the samples both records still cover (a sample fewer), the stamp stays.
    ``galvo-sysid commission --measured-current`` finds the lag where it is not known.

    Raises:
        ConfigurationError: A bad lag (:func:`~galvo_sysid.ident.measured.check_lag`).
        InvalidDataError: A record would be left shorter than :data:`MIN_SAMPLES`.
    """
    from galvo_sysid.ident.measured import check_lag, held_current  # numerics when asked

    t = moves.sample_period
    check_lag(lag, t)
    shortest = min(m.current.shape[0] for m in moves.moves)
    if shortest - 1 < MIN_SAMPLES:
        msg = (f'{moves.source}: a measured current leaves records of {shortest - 1} samples; '
               f'identification needs at least {MIN_SAMPLES}')
        raise InvalidDataError(msg)
    held = [held_current(m.current, sample_period=t, lag=lag) for m in moves.moves]
    return replace(moves, moves=tuple(replace(m, current=h, encoder=m.encoder[:-1])
                                      for m, h in zip(moves.moves, held, strict=True)))


def _check_lead(lead: int) -> None:
    if isinstance(lead, bool) or not isinstance(lead, int) or not 0 <= lead < 1000:
        msg = f'current lead must be a whole number of samples within 0..999, got {lead!r}'
        raise ConfigurationError(msg)


def write_bag(out: str | os.PathLike[str], moves: ImportedMoves, *, storage: str = 'mcap',
              frame_id: str = '') -> int:
    """Write checked moves into a new bag, as ``galvo-sysid simulate`` does; return how many.

    The bag appears under ``out`` only when complete (nothing is left on an error).

    Raises:
        BagExistsError: ``out`` exists.
        ConfigurationError: The bag would not fit on its disk.
        BagError: Unknown storage.
        OSError: Writing failed.
    """
    path = Path(out)
    check_space(path, moves=1, samples=moves.samples)
    count = 0
    with atomic_bag(path) as partial, BagWriter(partial, storage=storage) as bag:
        bag.add_topic(CURRENT_TOPIC, MOVE_SAMPLES)
        bag.add_topic(ENCODER_TOPIC, MOVE_SAMPLES)
        for move in moves.moves:
            write_move(bag, move_id=move.move_id, target_angle=move.target_angle,
                       stamp=move.stamp, sample_period=move.sample_period,
                       current=move.current, encoder=move.encoder, frame_id=frame_id)
            count += 1
    return count


def read_moves(source: str | os.PathLike[str], *, format: str | None = None,
               sample_period: float | None = None, target_angle: float | None = None,
               max_bytes: int = MAX_BYTES, check_travel: bool = True) -> ImportedMoves:
    """Read and check the moves of a CSV, .npz or .mat file (see the module docs).

    Args:
        source: The file.
        format: One of :data:`FORMATS`; default from the file's suffix.
        sample_period: Sample period [s] if the file has none (else it must agree).
        target_angle: One target angle [deg] for every move if the file has none.
        max_bytes: Size limit of the file and of its arrays as float64 [bytes].
        check_travel: Check the encoder's travel against the target angles.

    Raises:
        InvalidDataError: The file cannot be read or its data are refused.
        ConfigurationError: Unknown format, bad ``max_bytes``.
    """
    path = Path(source)
    fmt = _format(path, format)
    if isinstance(max_bytes, bool) or not isinstance(max_bytes, int) or max_bytes < 1:
        msg = f'max_bytes must be a whole number >= 1, got {max_bytes!r}'
        raise ConfigurationError(msg)
    where = str(path)
    _check_file(path, where, max_bytes)
    if fmt == 'csv':
        raw = _read_csv(path, where)
    else:
        arrays, ignored = (_read_npz if fmt == 'npz' else _read_mat)(path, where, max_bytes)
        raw = _raw_from_arrays(arrays, where, ignored)
    return _checked(raw, where=where, fmt=fmt, sample_period=sample_period,
                    target_angle=target_angle, check_travel=check_travel)


def moves_from_arrays(current: ArrayLike, encoder: ArrayLike, *,
                      sample_period: float | None = None,
                      target_angle: ArrayLike | None = None, stamp: ArrayLike | None = None,
                      move_id: ArrayLike | None = None, length: ArrayLike | None = None,
                      check_travel: bool = True) -> ImportedMoves:
    """Check moves given as arrays, laid out as in an .npz file (see the module docs).

    Args:
        current: Current [A], shape (moves, samples).
        encoder: Encoder [deg], shape (moves, samples).
        sample_period: Sample period [s].
        target_angle: Signed target angle [deg], per move or one value.
        stamp: Time of each move's first sample [s].
        move_id: The moves' ids.
        length: Samples used of each row.
        check_travel: Check the encoder's travel against the target angles.

    Raises:
        InvalidDataError: The data are refused (see the module docs).
    """
    given = {'current': current, 'encoder': encoder, 'target_angle': target_angle,
             'stamp': stamp, 'move_id': move_id, 'length': length}
    arrays = {k: np.asarray(v) for k, v in given.items() if v is not None}
    raw = _raw_from_arrays(arrays, 'arrays', ())
    return _checked(raw, where='arrays', fmt='arrays', sample_period=sample_period,
                    target_angle=None, check_travel=check_travel)


# --------------------------------------------------------------------------- common checks


@dataclass
class _Raw:
    """What a file gave, before the common checks (per-move values where the file has them)."""

    move_ids: list[int]
    currents: list[NDArray[np.float64]]
    encoders: list[NDArray[np.float64]]
    target_angles: list[float] | None = None
    stamps: list[float] | None = None
    sample_period: float | None = None
    ignored: tuple[str, ...] = ()


def _format(path: Path, format: str | None) -> str:
    """The file's format: ``format`` if given, else from the suffix."""
    if format is not None:
        if format not in FORMATS:
            msg = f'unknown format {format!r}: use one of {", ".join(FORMATS)}'
            raise ConfigurationError(msg)
        return format
    suffix = path.suffix.lower()
    found = {'.csv': 'csv', '.txt': 'csv', '.tsv': 'csv', '.npz': 'npz', '.mat': 'mat'}.get(
        suffix)
    if found is None:
        msg = (f'{path}: unknown file type {suffix or "(no suffix)"!r}: expected .csv, .npz '
               f'or .mat (or give the format)')
        raise InvalidDataError(msg)
    return found


def _check_file(path: Path, where: str, max_bytes: int) -> None:
    """Refuse a missing, empty or too large file (from its size, before reading it)."""
    try:
        info = path.stat()
    except FileNotFoundError:
        raise InvalidDataError(f'{where}: no such file') from None
    except OSError as err:
        raise InvalidDataError(f'{where}: cannot read: {err.strerror or err}') from None
    if not path.is_file():
        raise InvalidDataError(f'{where}: not a file')
    if info.st_size == 0:
        raise InvalidDataError(f'{where}: empty file')
    if info.st_size > max_bytes:
        raise InvalidDataError(f'{where}: {info.st_size:,} bytes, above the size limit of '
                               f'{max_bytes:,} bytes (--max-bytes)')


def _checked(raw: _Raw, *, where: str, fmt: str, sample_period: float | None,
             target_angle: float | None, check_travel: bool) -> ImportedMoves:
    """The checks every format shares; the moves as they go into the bag."""
    n = len(raw.move_ids)
    if n == 0:
        raise InvalidDataError(f'{where}: no moves')
    period = _sample_period(raw.sample_period, sample_period, where)
    angles = _target_angles(raw.target_angles, target_angle, n, where)
    ids = raw.move_ids
    seen: dict[int, int] = {}
    for i, move_id in enumerate(ids):
        if move_id < 0 or move_id >= 2**63:
            raise InvalidDataError(f'{where}: move_id {move_id} (move {i}) must be within '
                                   f'0..2**63-1')
        if move_id in seen:
            raise InvalidDataError(f'{where}: move_id {move_id} appears twice (moves '
                                   f'{seen[move_id]} and {i})')
        seen[move_id] = i
    for i, (cur, enc) in enumerate(zip(raw.currents, raw.encoders, strict=True)):
        if cur.shape[0] != enc.shape[0]:
            raise InvalidDataError(f'{where}: move {ids[i]}: current has {cur.shape[0]} '
                                   f'samples, encoder {enc.shape[0]}')
        if cur.shape[0] < MIN_SAMPLES:
            raise InvalidDataError(f'{where}: move {ids[i]} has {cur.shape[0]} samples: '
                                   f'identification needs at least {MIN_SAMPLES} per record')
    for i, a in enumerate(angles):
        if not math.isfinite(a) or not _MIN_ANGLE <= abs(a) <= MAX_ANGLE:
            what = 'is zero' if math.isfinite(a) and abs(a) < _MIN_ANGLE else \
                f'must be within {MAX_ANGLE:g} deg and non-zero'
            raise InvalidDataError(f'{where}: target angle {a!r} deg of move {ids[i]} {what}')
    stamps = _stamps(raw.stamps, raw.currents, period, ids, where)
    moves = tuple(ImportedMove(move_id=ids[i], target_angle=angles[i], stamp=stamps[i],
                               sample_period=period, current=raw.currents[i],
                               encoder=raw.encoders[i]) for i in range(n))
    if check_travel:
        _check_travel(moves, where)
    return ImportedMoves(moves=moves, sample_period=period, source=where, format=fmt,
                         ignored=raw.ignored)


def _sample_period(found: float | None, given: float | None, where: str) -> float:
    """The sample period of the file or the option (both: they agree), within range."""
    if found is None and given is None:
        raise InvalidDataError(f'{where}: no sample period: the file has none, give it '
                               f'(--sample-period, in seconds)')
    if found is not None and given is not None and not (
            math.isfinite(found) and math.isfinite(given)
            and abs(found - given) <= 1e-9 * abs(given)):
        raise InvalidDataError(f"{where}: the file's sample period {found!r} s differs from "
                               f'the one given, {given!r} s')
    period = float(found) if found is not None else float(given or 0.0)
    low, high = SAMPLE_PERIOD_RANGE
    if not (math.isfinite(period) and low <= period <= high):
        hint = f' (in seconds: 10 us is {1e-5:g})' if math.isfinite(period) and period > 0 \
            else ''
        raise InvalidDataError(f'{where}: sample period {period!r} s must be within '
                               f'{low:g}..{high:g} s{hint}')
    return period


def _target_angles(found: list[float] | None, given: float | None, n: int,
                   where: str) -> list[float]:
    """Per-move target angles of the file or the option (both: they agree)."""
    if found is None:
        if given is None:
            raise InvalidDataError(f'{where}: no target angle: the file has none, give one '
                                   f'for every move (--target-angle, in degrees)')
        return [float(given)] * n
    if given is not None and any(a != float(given) for a in found):
        raise InvalidDataError(f"{where}: the file's target angles differ from the one "
                               f'given, {given!r} deg')
    return found


def _stamps(found: list[float] | None, currents: Sequence[NDArray[np.float64]],
            period: float, ids: Sequence[int], where: str) -> list[float]:
    """The file's stamps (checked), or the records back to back from 0."""
    if found is None:
        starts = np.concatenate(([0], np.cumsum([c.shape[0] for c in currents[:-1]])))
        return [float(s * period) for s in starts]
    last = -math.inf
    for i, s in enumerate(found):
        if not (math.isfinite(s) and 0 <= s < _MAX_STAMP):
            raise InvalidDataError(f'{where}: stamp {s!r} s of move {ids[i]} must be within '
                                   f'0..2**31 s')
        if s <= last:
            raise InvalidDataError(f'{where}: stamps must increase: move {ids[i]} at {s!r} s '
                                   f'follows {last!r} s')
        last = s
    return list(found)


def _check_travel(moves: Sequence[ImportedMove], where: str) -> None:
    """Refuse moves that travel against their target angle, or an encoder in other units.

    A move's travel is the mean of its record's last sixteenth minus its first sample (how
    :func:`~galvo_sysid.ident.identify.identify_window` estimates an angle).
    """
    ratios = []
    for m in moves:
        travel = float(travels(m.encoder))
        ratio = travel / m.target_angle
        if ratio < -0.5:
            raise InvalidDataError(
                f'{where}: move {m.move_id} travels {travel:+.4g} deg against its target '
                f'angle {m.target_angle:+g} deg: give the target angle of each move (moves '
                f'that go back have a negative one)')
        ratios.append(ratio)
    median = float(np.median(ratios))
    if not 1 / TRAVEL_FACTOR <= median <= TRAVEL_FACTOR:
        raise InvalidDataError(
            f'{where}: the encoder travels {median:.4g} times the target angle (median over '
            f'the moves): is the encoder in degrees? (radians are 57.3 times smaller); the '
            f'check can be turned off')


# --------------------------------------------------------------------------- arrays


def _raw_from_arrays(arrays: Mapping[str, Any], where: str,
                     ignored: Sequence[str]) -> _Raw:
    """The moves of named arrays laid out as in an .npz file."""
    for name in ('current', 'encoder'):
        if name not in arrays:
            have = ', '.join(sorted(arrays)) or 'no arrays'
            raise InvalidDataError(f'{where}: no array {name!r} (it holds: {have})')
    current = _records('current', arrays['current'], where)
    encoder = _records('encoder', arrays['encoder'], where)
    if current.shape != encoder.shape:
        raise InvalidDataError(f'{where}: current has shape {current.shape} but encoder '
                               f'{encoder.shape}: both (moves, samples)')
    moves, width = current.shape

    def vector(name: str, *, one: bool = False) -> NDArray[Any] | None:
        """A per-move array (rows or columns alike), or one value if ``one``."""
        if name not in arrays:
            return None
        value = _numeric(name, arrays[name], where)
        flat = value.reshape(-1) if _is_vector(value) else None
        if flat is not None and (flat.shape[0] == moves or (one and flat.shape[0] == 1)):
            return flat
        need = f'{moves} value(s), one per move' + (', or one value' if one else '')
        hint = ''
        if flat is not None and flat.shape[0] == width != moves:
            hint = '; current and encoder hold one row per move, (moves, samples): transposed?'
        raise InvalidDataError(f'{where}: {name} has shape {value.shape}, expected {need}{hint}')

    angles = vector('target_angle', one=True)
    stamps = vector('stamp')
    ids = vector('move_id')
    lengths = vector('length')
    period = None
    if 'sample_period' in arrays:
        value = _numeric('sample_period', arrays['sample_period'], where)
        if value.size != 1:
            raise InvalidDataError(f'{where}: sample_period has shape {value.shape}, expected '
                                   f'one value')
        period = float(value.reshape(-1)[0])
    move_ids = list(range(moves)) if ids is None else _whole('move_id', ids, where)
    used = [width] * moves if lengths is None else _whole('length', lengths, where)
    currents: list[NDArray[np.float64]] = []
    encoders: list[NDArray[np.float64]] = []
    for row in range(moves):
        n = used[row]
        if not 1 <= n <= width:
            raise InvalidDataError(f'{where}: length {n} of move {move_ids[row]} (row {row}) '
                                   f'must be within 1..{width}')
        for name, data, out in (('current', current, currents),
                                ('encoder', encoder, encoders)):
            record = np.ascontiguousarray(data[row, :n], dtype=np.float64)
            bad = np.flatnonzero(~np.isfinite(record))
            if bad.size:
                raise InvalidDataError(f'{where}: NaN or infinity in {name} of move '
                                       f'{move_ids[row]} (row {row}, sample {bad[0]})')
            out.append(record)
    target_angles = None
    if angles is not None:
        target_angles = [float(a) for a in (np.repeat(angles, moves) if angles.shape[0] == 1
                                            else angles)]
    return _Raw(move_ids=move_ids, currents=currents, encoders=encoders,
                target_angles=target_angles,
                stamps=None if stamps is None else [float(s) for s in stamps],
                sample_period=period, ignored=tuple(ignored))


def _is_vector(value: Any) -> bool:
    """A (1, n) or (n, 1) array (MATLAB's vectors)."""
    return sum(int(d) != 1 for d in np.shape(value)) <= 1


def _numeric(name: str, value: Any, where: str) -> NDArray[Any]:
    """``value`` as an array of real numbers, else refused with what it is."""
    arr = np.asarray(value)
    kind = arr.dtype.kind
    if kind not in 'iuf':
        what = {'b': 'booleans', 'c': 'complex numbers', 'U': 'text', 'S': 'text',
                'O': 'objects (a cell array?)', 'V': 'records (a struct?)'}.get(
                    kind, f'of type {arr.dtype}')
        raise InvalidDataError(f'{where}: {name} holds {what}, not real numbers')
    if kind == 'f' and name not in {'current', 'encoder'}:
        bad = np.flatnonzero(~np.isfinite(arr.reshape(-1)))
        if bad.size:
            raise InvalidDataError(f'{where}: NaN or infinity in {name} (value {bad[0]})')
    return arr


def _records(name: str, value: Any, where: str) -> NDArray[Any]:
    """A (moves, samples) array of records; one dimension is one move."""
    arr = _numeric(name, value, where)
    if arr.ndim == 1:
        arr = arr.reshape(1, -1)
    if arr.ndim != 2:
        raise InvalidDataError(f'{where}: {name} has shape {arr.shape}, expected (moves, '
                               f'samples)')
    if arr.size == 0:
        raise InvalidDataError(f'{where}: {name} is empty (shape {arr.shape})')
    return arr


def _whole(name: str, values: NDArray[Any], where: str) -> list[int]:
    """Whole numbers (integers, or floats without a fraction)."""
    if values.dtype.kind == 'f':
        bad = np.flatnonzero(values != np.round(values))
        if bad.size:
            raise InvalidDataError(f'{where}: {name} {float(values[bad[0]])!r} (move {bad[0]}) '
                                   f'is not a whole number')
        if values.size and np.abs(values).max() >= 2.0**63:
            raise InvalidDataError(f'{where}: {name} too large')
    return [int(v) for v in values]


def _read_npz(path: Path, where: str, max_bytes: int) -> tuple[dict[str, Any], list[str]]:
    """The named arrays of an .npz file, and the names of the others.

    The arrays :data:`ARRAY_NAMES` names are checked from their headers (shape, type, size)
    before any is loaded.
    """
    if not zipfile.is_zipfile(path):
        raise InvalidDataError(f'{where}: not a NumPy .npz file (not a zip archive)')
    arrays: dict[str, Any] = {}
    try:
        with zipfile.ZipFile(path) as archive:
            members = {i.filename.removesuffix('.npy'): i for i in archive.infolist()
                       if i.filename.endswith('.npy')}
            ignored = sorted(set(members) - set(ARRAY_NAMES))
            wanted = [name for name in ARRAY_NAMES if name in members]
            total = 0
            for name in wanted:
                with archive.open(members[name]) as stream:
                    version = np.lib.format.read_magic(stream)
                    if version == (1, 0):
                        shape, _, dtype = np.lib.format.read_array_header_1_0(stream)
                    elif version == (2, 0):
                        shape, _, dtype = np.lib.format.read_array_header_2_0(stream)
                    else:
                        raise InvalidDataError(f'{where}: array {name!r} has .npy format '
                                               f'version {version}, not read (1.0 or 2.0)')
                if dtype.hasobject:
                    raise InvalidDataError(f'{where}: {name} holds Python objects (pickled), '
                                           f'not read: save arrays of numbers')
                total += math.prod(shape) * 8
            if total > max_bytes:
                raise InvalidDataError(f'{where}: the arrays take {total:,} bytes as float64, '
                                       f'above the size limit of {max_bytes:,} bytes '
                                       f'(--max-bytes)')
            for name in wanted:
                with archive.open(members[name]) as stream:
                    arrays[name] = np.lib.format.read_array(stream, allow_pickle=False)
    except InvalidDataError:
        raise
    except (zipfile.BadZipFile, zipfile.LargeZipFile, zlib.error, EOFError, ValueError,
            NotImplementedError, OSError) as err:
        raise InvalidDataError(f'{where}: cannot read the .npz file: {one_line(err)}') from None
    return arrays, ignored


def _read_mat(path: Path, where: str, max_bytes: int) -> tuple[dict[str, Any], list[str]]:
    """The named arrays of a MATLAB .mat file (v4 to v7), and the names of the others.

    The arrays :data:`ARRAY_NAMES` names are checked from the file's listing (class, size)
    before any is loaded.
    """
    from scipy.io import loadmat, whosmat
    from scipy.io.matlab import matfile_version

    try:
        major, _ = matfile_version(str(path))
    except MemoryError:
        raise
    except Exception as err:  # scipy raises many kinds on a file that is not a .mat
        raise InvalidDataError(f'{where}: not a MATLAB .mat file: {one_line(err)}') from None
    if major == 2:
        raise InvalidDataError(f'{where}: a MATLAB v7.3 (HDF5) file, not read: save it with '
                               f"save(..., '-v7') or write an .npz file")
    try:
        listing = whosmat(str(path))
    except MemoryError:
        raise
    except Exception as err:  # a damaged file
        raise InvalidDataError(f'{where}: cannot read the .mat file: {one_line(err)}') from None
    found = {name: (shape, cls) for name, shape, cls in listing}
    ignored = sorted(set(found) - set(ARRAY_NAMES))
    wanted = [name for name in ARRAY_NAMES if name in found]
    total = 0
    for name in wanted:
        shape, cls = found[name]
        if cls not in _MAT_NUMERIC:
            what = {'logical': 'booleans', 'char': 'text', 'struct': 'a struct',
                    'cell': 'a cell array'}.get(cls, f'a {cls} array')
            hint = ': put the records in a (moves, samples) matrix, padded, with their ' \
                'lengths in length' if cls == 'cell' else ''
            raise InvalidDataError(f'{where}: {name} holds {what}, not real numbers{hint}')
        total += math.prod(shape) * 8
    if total > max_bytes:
        raise InvalidDataError(f'{where}: the arrays take {total:,} bytes as float64, above the '
                               f'size limit of {max_bytes:,} bytes (--max-bytes)')
    if not wanted:
        return {}, ignored
    try:
        data = loadmat(str(path), variable_names=wanted, squeeze_me=False)
    except MemoryError:
        raise
    except Exception as err:  # a damaged file
        raise InvalidDataError(f'{where}: cannot read the .mat file: {one_line(err)}') from None
    return {name: data[name] for name in wanted if name in data}, ignored



# --------------------------------------------------------------------------- CSV


def _read_csv(path: Path, where: str) -> _Raw:
    """The moves of a CSV file (see the module docs), read row by row."""
    try:
        with path.open(encoding='utf-8-sig', newline='') as f:
            return _parse_csv(f, where)
    except UnicodeDecodeError as err:
        raise InvalidDataError(f'{where}: not a text file (UTF-8): byte {err.start} cannot be '
                               f'decoded') from None
    except csv.Error as err:
        raise InvalidDataError(f'{where}: bad CSV: {one_line(err)}') from None


def _parse_csv(lines: Iterator[str], where: str) -> _Raw:
    line = 0

    def content() -> Iterator[str]:
        nonlocal line
        for line, text in enumerate(lines, start=1):  # noqa: B007 (line is read outside)
            stripped = text.strip()
            if stripped and not stripped.startswith('#'):
                yield text

    rows = content()
    header_text = next(rows, None)
    if header_text is None:
        raise InvalidDataError(f'{where}: no header line (an empty CSV file)')
    delimiter = next((d for d in (',', '\t', ';') if d in header_text), ',')
    header = next(csv.reader([header_text], delimiter=delimiter))
    columns = _columns(header, where, line)
    width = len(header)
    ignored = tuple(h.strip() for i, h in enumerate(header) if i not in columns.values())

    move_ids: list[int] = []
    currents: list[NDArray[np.float64]] = []
    encoders: list[NDArray[np.float64]] = []
    angles: list[float] = []
    stamps: list[float] = []
    period: tuple[float, int] | None = None  # value, line
    seen: set[int] = set()
    cur: list[float] = []
    enc: list[float] = []
    first: dict[str, tuple[float, int]] = {}  # the move's per-move values and their line

    def close() -> None:
        currents.append(np.array(cur, dtype=np.float64))
        encoders.append(np.array(enc, dtype=np.float64))
        if 'target_angle' in first:
            angles.append(first['target_angle'][0])
        if 'stamp' in first:
            stamps.append(first['stamp'][0])

    def number(row: list[str], name: str) -> float:
        cell = row[columns[name]]
        try:
            value = float(cell)
        except ValueError:
            raise InvalidDataError(f'{where}: line {line}, column {name}: not a number: '
                                   f'{cell.strip()[:40]!r}') from None
        if not math.isfinite(value):
            raise InvalidDataError(f'{where}: line {line}, column {name}: {cell.strip()!r} is '
                                   f'not a finite number')
        return value

    reader = csv.reader(rows, delimiter=delimiter)
    move: int | None = None
    for row in reader:
        if len(row) != width:
            raise InvalidDataError(f'{where}: line {line} has {len(row)} cells, the header '
                                   f'{width}')
        this = _move_id(row[columns['move']], where, line)
        if this != move:
            if move is not None:
                close()
            if this in seen:
                raise InvalidDataError(f'{where}: line {line}: move {this} again after other '
                                       f'moves (the rows of a move must be together)')
            seen.add(this)
            move_ids.append(this)
            move, cur, enc, first = this, [], [], {}
        cur.append(number(row, 'current'))
        enc.append(number(row, 'encoder'))
        for name in ('target_angle', 'stamp'):
            if name not in columns:
                continue
            v = number(row, name)
            if name not in first:
                first[name] = (v, line)
            elif v != first[name][0]:
                raise InvalidDataError(f'{where}: line {line}: {name} {v!r} differs from '
                                       f'{first[name][0]!r} on line {first[name][1]}, the same '
                                       f'move (one value per move)')
        if 'sample_period' in columns:
            v = number(row, 'sample_period')
            if period is None:
                period = (v, line)
            elif v != period[0]:
                raise InvalidDataError(f'{where}: line {line}: sample_period {v!r} differs from '
                                       f'{period[0]!r} on line {period[1]} (one for the file)')
    if move is None:
        raise InvalidDataError(f'{where}: no rows after the header')
    close()
    return _Raw(move_ids=move_ids, currents=currents, encoders=encoders,
                target_angles=angles if 'target_angle' in columns else None,
                stamps=stamps if 'stamp' in columns else None,
                sample_period=period[0] if period is not None else None, ignored=ignored)


def _move_id(cell: str, where: str, line: int) -> int:
    """A move id cell: a whole number >= 0 (``3`` or ``3.0``)."""
    text = cell.strip()
    try:
        value = int(text)
    except ValueError:
        try:
            number = float(text)
        except ValueError:
            number = math.nan
        if not (math.isfinite(number) and number == round(number)):
            raise InvalidDataError(f'{where}: line {line}, column move: {text[:40]!r} is not a '
                                   f'move id (a whole number >= 0)') from None
        value = int(number)
    if not 0 <= value < 2**63:
        raise InvalidDataError(f'{where}: line {line}, column move: {value} is not within '
                               f'0..2**63-1')
    return value


def _columns(header: list[str], where: str, line: int) -> dict[str, int]:
    """Column index of each known column of the header (units in brackets checked)."""
    columns: dict[str, int] = {}
    for i, cell in enumerate(header):
        text = cell.strip()
        name, _, unit = text.partition('[')
        name = name.strip().lower()
        name = 'move' if name == 'move_id' else name  # as the arrays call it
        if name not in CSV_COLUMNS:
            continue
        if unit:
            unit = unit.rstrip().removesuffix(']').strip()
            expected = CSV_COLUMNS[name]
            if unit != expected:
                need = f'[{expected}]' if expected else 'no unit'
                raise InvalidDataError(f'{where}: line {line}: column {text!r} is in [{unit}]; '
                                       f'{name} must be in {need}')
        if name in columns:
            raise InvalidDataError(f'{where}: line {line}: column {name} appears twice')
        columns[name] = i
    for name in ('move', 'current', 'encoder'):
        if name not in columns:
            raise InvalidDataError(f'{where}: line {line}: no column {name!r} in the header '
                                   f'{",".join(h.strip() for h in header)[:120]!r} (needed: '
                                   f'move, current, encoder)')
    return columns
