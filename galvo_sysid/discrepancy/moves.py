"""The moves compared: commanded current and encoder angle of each move, and their history.

:class:`MoveSet` holds the records (one row per move, grouped by signed target angle);
:func:`read_moves` reads them from a bag, paired by move id like ``galvo-sysid identify``.
Back-to-back moves do not start quite at rest: :func:`_extended_inputs` puts before each
record the moves that ran just before it (known from move ids and stamps), whose ringing the
comparison (:mod:`galvo_sysid.discrepancy.compare`) carries over into the record.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from galvo_sysid.errors import ConfigurationError, InvalidDataError
from galvo_sysid.ident.preprocess import MAX_SAMPLE_MAGNITUDE, TRAVEL_FACTOR, travels

if TYPE_CHECKING:
    import os

    from numpy.typing import ArrayLike, NDArray

__all__ = ['MoveSet', 'implausible_samples', 'read_moves']



def implausible_samples(current: ArrayLike, encoder: ArrayLike) -> str | None:
    """Why a move's records are no measurement (NaN/Inf, or beyond
    :data:`~galvo_sysid.ident.preprocess.MAX_SAMPLE_MAGNITUDE`), or None."""  # noqa: D205, D209
    for name, values in (('current', current), ('encoder', encoder)):
        x = np.asarray(values, dtype=float)
        if not np.all(np.isfinite(x)):
            return f'NaN or Inf in {name}'
        if x.size and float(np.max(np.abs(x))) > MAX_SAMPLE_MAGNITUDE:
            return (f'{name} reaches {float(np.max(np.abs(x))):.3g}, beyond '
                    f'+-{MAX_SAMPLE_MAGNITUDE:g}: no measurement of a scanner')
    return None


@dataclass(frozen=True)
class MoveSet:
    """Recorded moves: commanded current and encoder angle, one row per move.

    Attributes:
        current: Commanded current [A], (M, N).
        encoder: Encoder angle [deg], (M, N); each record starts at rest at its start angle.
        target_angle: Signed commanded rotation of each move [deg], (M,).
        move_id: Move ids, (M,).
        sample_period: Sampling period [s].
        stamp: Time of each record's first sample [s], (M,); NaN where unknown. With stamps
            and consecutive move ids the moves before a record are known, and the ringing
            they leave is part of the comparison (see :class:`Comparison`).
    """

    current: NDArray[np.float64]
    encoder: NDArray[np.float64]
    target_angle: NDArray[np.float64]
    move_id: NDArray[np.int64]
    sample_period: float
    stamp: NDArray[np.float64]

    @classmethod
    def create(cls, current: ArrayLike, encoder: ArrayLike, target_angle: ArrayLike, *,
               sample_period: float, move_id: ArrayLike | None = None,
               stamp: ArrayLike | None = None) -> MoveSet:
        """Check and build a move set.

        Raises:
            InvalidDataError: Wrong shapes, NaN/Inf or samples beyond
                :data:`~galvo_sysid.ident.preprocess.MAX_SAMPLE_MAGNITUDE`, fewer than 16
                samples, zero angles.
            ConfigurationError: Bad sample period.
        """
        cur = np.atleast_2d(np.asarray(current, dtype=float))
        enc = np.atleast_2d(np.asarray(encoder, dtype=float))
        if cur.ndim != 2 or cur.shape != enc.shape:
            raise InvalidDataError(
                f'current and encoder must both be (moves, samples), got {cur.shape} and '
                f'{enc.shape}')
        if cur.shape[1] < 16:
            raise InvalidDataError(f'records need at least 16 samples, got {cur.shape[1]}')
        why = implausible_samples(cur, enc)
        if why is not None:
            raise InvalidDataError(f'moves cannot be compared: {why}')
        angles = np.broadcast_to(np.asarray(target_angle, dtype=float), (cur.shape[0],)).copy()
        if not np.all(np.isfinite(angles)) or np.any(angles == 0):
            raise InvalidDataError('target angles must be finite and non-zero')
        if not (math.isfinite(sample_period) and sample_period > 0):
            raise ConfigurationError(f'sample_period must be positive, got {sample_period!r}')
        ids = (np.arange(cur.shape[0]) if move_id is None
               else np.asarray(move_id, dtype=np.int64).reshape(-1))
        if ids.shape != (cur.shape[0],):
            raise InvalidDataError('move_id must have one id per move')
        stamps = (np.full(cur.shape[0], np.nan) if stamp is None
                  else np.asarray(stamp, dtype=float).reshape(-1))
        if stamps.shape != (cur.shape[0],):
            raise InvalidDataError('stamp must have one value per move')
        return cls(current=cur, encoder=enc, target_angle=angles, move_id=ids,
                   sample_period=float(sample_period), stamp=stamps)

    @classmethod
    def from_moves(cls, moves: Iterable[Any]) -> MoveSet:
        """Build from move objects (e.g. :class:`galvo_sysid.sim.config.Move`).

        Each needs ``current``, ``encoder``, ``target_angle``, ``sample_period`` and
        ``move_id``; ``stamp`` is used if present.

        Raises:
            InvalidDataError: No moves, records of different lengths or sample periods.
        """
        items = list(moves)
        if not items:
            raise InvalidDataError('no moves')
        periods = {float(m.sample_period) for m in items}
        if len(periods) != 1:
            raise InvalidDataError(f'moves have different sample periods: {sorted(periods)}')
        lengths = {len(m.current) for m in items} | {len(m.encoder) for m in items}
        if len(lengths) != 1:
            raise InvalidDataError(f'records have different lengths: {sorted(lengths)}')
        return cls.create([m.current for m in items], [m.encoder for m in items],
                          [m.target_angle for m in items], sample_period=periods.pop(),
                          move_id=[m.move_id for m in items],
                          stamp=[float(getattr(m, 'stamp', math.nan)) for m in items])

    @property
    def moves(self) -> int:
        """Number of moves."""
        return int(self.current.shape[0])

    @property
    def samples(self) -> int:
        """Samples per record."""
        return int(self.current.shape[1])

    def subset(self, rows: ArrayLike) -> MoveSet:
        """The moves of some rows."""
        idx = np.asarray(rows, dtype=np.intp)
        return MoveSet(current=self.current[idx], encoder=self.encoder[idx],
                       target_angle=self.target_angle[idx], move_id=self.move_id[idx],
                       sample_period=self.sample_period, stamp=self.stamp[idx])

    def groups(self, *, resolution: float = 1e-6) -> list[tuple[float, NDArray[np.intp]]]:
        """(signed angle, row indices) of each target angle, ascending angle."""
        keys = np.round(self.target_angle / resolution).astype(np.int64)
        out = []
        for key in np.unique(keys):
            idx = np.flatnonzero(keys == key)
            out.append((float(np.mean(self.target_angle[idx])), idx))
        return out


def read_moves(bag: str | os.PathLike[str], *, namespace: str | None = None,
               max_moves_per_angle: int | None = None, min_moves: int = 3,
               measured_lag: float | None = None) -> tuple[MoveSet, list[dict[str, Any]]]:
    """Read the moves of a bag (paired by move id like ``galvo-sysid identify``).

    Args:
        bag: rosbag2 bag (directory, .mcap or .db3).
        namespace: Scanner namespace when the bag holds several.
        max_moves_per_angle: Keep at most this many moves of each signed angle (the first).
        min_moves: Target angles with fewer usable moves are set aside (a noise floor needs
            at least 3).
        measured_lag: The bag's current is the coil current measured when the encoder is
            read, behind an amplifier lag of this time constant [s]: each move's current is
            made into the held current that drives it, a sample shorter
            (:meth:`~galvo_sysid.monitor.moves.Window.held`); None: the command.

    Returns:
        (moves, set-aside moves as JSON-ready dicts with a ``reason``).

    Raises:
        BagError: Missing, corrupt or unreadable bag.
        InvalidDataError: No usable move.
    """
    from galvo_sysid.field.bags import BagReader
    from galvo_sysid.field.results import rejection_to_dict
    from galvo_sysid.monitor.pairing import MoveWindower

    windower = MoveWindower(window_size=1000)
    rejected: list[dict[str, Any]] = []
    windows = []
    stamps: dict[int, float] = {}
    with BagReader(bag) as reader:
        for half, completed, unread in reader.feed(windower, namespace=namespace):
            if unread is not None:
                rejected.append(unread.to_dict())
            if half is not None and half.signal == 'current':
                stamps[int(half.move_id)] = float(half.stamp)
            windows.extend(completed)
            rejected.extend(rejection_to_dict(r) for r in windower.pop_rejections())
    windows.extend(windower.flush(min_moves=1))
    rejected.extend(rejection_to_dict(r) for r in windower.pop_rejections())
    if not windows:
        raise InvalidDataError(f'no usable move in {bag}')
    if measured_lag is not None:
        windows = [w.held(measured_lag) for w in windows]
    # one record length and sample period: the most common (by moves); the rest set aside
    shares: dict[tuple[int, float], int] = {}
    for w in windows:
        shape = (w.current.shape[1], w.sample_period)
        shares[shape] = shares.get(shape, 0) + w.moves
    (length, period), _ = max(shares.items(), key=lambda kv: kv[1])
    for w in windows:
        if (w.current.shape[1], w.sample_period) != (length, period):
            rejected.extend({'move_id': int(mid), 'target_angle': w.target_angle,
                             'stamp': stamps.get(int(mid)),
                             'reason': f'record of {w.current.shape[1]} samples at '
                                       f'{w.sample_period:g} s, most moves have {length} at '
                                       f'{period:g} s'}
                            for mid in w.move_ids)
    windows = [w for w in windows if (w.current.shape[1], w.sample_period) == (length, period)]
    # a move whose samples no scanner measures (corrupt, rescaled) is set aside, alone
    usable: dict[int, list[int]] = {}
    for w in windows:
        usable[id(w)] = []
        for row, mid in enumerate(w.move_ids):
            why = implausible_samples(w.current[row], w.encoder[row])
            travel = float(travels(w.encoder[row])) if why is None else math.nan
            if why is None and not 1.0 / TRAVEL_FACTOR <= travel / w.target_angle <= \
                    TRAVEL_FACTOR:  # a closed loop travels its target angle whatever the plant
                why = (f'the move travels {travel:+.4g} deg for a target angle of '
                       f'{w.target_angle:+g} deg: the encoder in other units, the sign of the '
                       f'angle or the topics wrong')
            if why is None:
                usable[id(w)].append(row)
            else:
                rejected.append({'move_id': int(mid), 'target_angle': w.target_angle,
                                 'stamp': stamps.get(int(mid)), 'reason': why})
    counts: dict[float, int] = {}
    for w in windows:
        counts[w.target_angle] = counts.get(w.target_angle, 0) + len(usable[id(w)])
    cur, enc, ang, ids = [], [], [], []
    taken: dict[float, int] = {}
    for w in sorted(windows, key=lambda w: w.first_stamp):
        if counts[w.target_angle] < min_moves:
            rejected.extend({'move_id': int(mid), 'target_angle': w.target_angle,
                             'stamp': stamps.get(int(mid)),
                             'reason': f'only {counts[w.target_angle]} move(s) of this target '
                                       f'angle (a noise floor needs {min_moves})'}
                            for mid in (w.move_ids[row] for row in usable[id(w)]))
            continue
        for row in usable[id(w)]:
            mid = w.move_ids[row]
            n = taken.get(w.target_angle, 0)
            if max_moves_per_angle is not None and n >= max_moves_per_angle:
                continue
            taken[w.target_angle] = n + 1
            cur.append(w.current[row])
            enc.append(w.encoder[row])
            ang.append(w.target_angle)
            ids.append(mid)
    if not ids:
        why = f" (set aside, e.g.: {rejected[0]['reason']})" if rejected else ''
        raise InvalidDataError(f'{bag}: no target angle has {min_moves} usable moves{why}')
    order = np.argsort(ids, kind='stable')
    id_arr = np.array(ids)[order]
    return MoveSet.create(np.array(cur)[order], np.array(enc)[order], np.array(ang)[order],
                          sample_period=period, move_id=id_arr,
                          stamp=[stamps.get(int(i), math.nan) for i in id_arr]), rejected


def _extended_inputs(moves: MoveSet, history: int) -> tuple[NDArray[np.float64],
                                                             NDArray[np.bool_]]:
    """Each record preceded by up to ``history`` previous moves (M, L), right-aligned.

    A previous move counts if its move id is one less and the stamps put it at most four
    record lengths before; the dwell between records holds the last current. Where no
    previous move is known the record stands alone (zeros before it).
    """
    n = moves.samples
    t = moves.sample_period
    pos = {int(mid): i for i, mid in enumerate(moves.move_id)}
    chains: list[list[tuple[int, int]]] = []       # per row: [(row, dwell after it), ...]
    for i, mid in enumerate(moves.move_id):
        chain: list[tuple[int, int]] = []
        cur = i
        for _ in range(history):
            prev = pos.get(int(moves.move_id[cur]) - 1)
            if prev is None:
                break
            gap = (moves.stamp[cur] - moves.stamp[prev]) / t - n
            if not (math.isfinite(gap) and -0.5 <= gap <= 4 * n):
                break
            chain.append((prev, max(round(gap), 0)))
            cur = prev
        chains.append(chain)
        del mid
    lengths = [n + sum(n + d for _, d in c) for c in chains]
    width = max(lengths)
    ext = np.zeros((moves.moves, width))
    for i, chain in enumerate(chains):
        end = width
        ext[i, end - n:end] = moves.current[i]
        end -= n
        for prev, dwell in chain:
            ext[i, end - dwell:end] = moves.current[prev, -1]
            end -= dwell
            ext[i, end - n:end] = moves.current[prev]
            end -= n
    return ext, np.array([bool(c) for c in chains])
