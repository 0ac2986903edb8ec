"""Conversions between galvo_sysid_msgs messages and the plain values of the numerics.

No rclpy here: every function reads or writes messages by field name (duck typing), so the
same code serves rclpy messages in the nodes and rosbags-deserialized messages in
``galvo-sysid`` (bags). ``*_fields`` functions return plain field dictionaries (sequences as
float64 arrays, no header) that a rosbags message class accepts; :func:`fill` sets them on an
existing message (rclpy's float64[] fields get an ``array.array``).

- ``MoveSamples`` <-> :class:`~galvo_sysid.monitor.moves.MoveHalf`; from serialized (CDR)
  bytes, :func:`read_move_samples` reads the fields and the record's length before any
  sample is decoded (:class:`SerializedMoveSamples`), so an oversized record is refused
  without ever being built
- ``ModalParameters`` <-> :class:`~galvo_sysid.ident.result.IdentificationResult` plus its
  :class:`ResultStatus` (identified, or why not: the data do not match the model, the fit
  failed; the model file used)
- ``DriftStatus`` <-> :class:`~galvo_sysid.monitor.verdict.DriftVerdict`
- :func:`diagnostic_values`: the key/values of a verdict for ``diagnostic_msgs/KeyValue``.
"""

from __future__ import annotations

import array
import math
import struct
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from galvo_sysid.errors import InvalidDataError
from galvo_sysid.monitor.moves import SIGNALS, MoveHalf
from galvo_sysid.monitor.verdict import (
    LEVEL_NAMES,
    MISMATCH,
    STATUS_NAMES,
    STATUS_OK,
    DriftVerdict,
)

if TYPE_CHECKING:
    from collections.abc import Mapping

    from numpy.typing import NDArray

    from galvo_sysid.ident.result import IdentificationResult

__all__ = [
    'ResultStatus',
    'SerializedMoveSamples',
    'diagnostic_values',
    'drift_status_fields',
    'fill',
    'fill_header',
    'modal_parameters_fields',
    'move_half_from_msg',
    'move_samples_fields',
    'read_move_samples',
    'result_from_msg',
    'seconds_to_stamp',
    'stamp_to_seconds',
    'status_from_msg',
    'unidentified_fields',
    'verdict_from_msg',
]

_NS = 1_000_000_000


def stamp_to_seconds(stamp: Any) -> float:
    """Seconds of a ``builtin_interfaces/Time`` (anything with ``sec`` and ``nanosec``)."""
    try:
        return float(int(stamp.sec) + int(stamp.nanosec) * 1e-9)
    except (AttributeError, TypeError, ValueError, OverflowError) as err:
        raise InvalidDataError(f'not a time stamp: {err}') from err


def seconds_to_stamp(seconds: float) -> tuple[int, int]:
    """``(sec, nanosec)`` of a time in seconds (rounded to the nanosecond)."""
    if not math.isfinite(seconds):
        raise InvalidDataError(f'cannot stamp a non-finite time {seconds!r}')
    sec, nanosec = divmod(round(seconds * _NS), _NS)
    if not -(2**31) <= sec < 2**31:
        raise InvalidDataError(f'time {seconds!r} s does not fit a ROS stamp')
    return int(sec), int(nanosec)


def move_half_from_msg(msg: Any, *, signal: str) -> MoveHalf:
    """A ``MoveSamples`` message as a :class:`MoveHalf` (``signal``: 'current' or 'encoder').

    The samples are viewed, not copied, where the message allows it. The values are not
    judged here (NaN, lengths, ...): :class:`~galvo_sysid.monitor.pairing.MoveWindower` does that.

    Raises:
        InvalidDataError: The message lacks a field or a field has the wrong type.
    """
    if signal not in SIGNALS:
        raise InvalidDataError(f'signal must be one of {SIGNALS}, got {signal!r}')
    try:
        data = msg.data
        if isinstance(data, array.array) and data.typecode == 'd':
            values = np.frombuffer(data, dtype=np.float64) if len(data) else np.zeros(0)
        else:
            values = np.asarray(data, dtype=np.float64)
        return MoveHalf(signal=signal, move_id=int(msg.move_id),
                        target_angle=float(msg.target_angle),
                        sample_period=float(msg.sample_period),
                        stamp=stamp_to_seconds(msg.header.stamp), data=values)
    except (AttributeError, TypeError, ValueError, OverflowError) as err:
        raise InvalidDataError(f'bad MoveSamples message on {signal}: {err}') from err


_CDR_BYTE_ORDERS = {b'\x00\x00': '>', b'\x00\x01': '<'}
"""Encapsulation identifiers of plain CDR (XCDR1), big and little endian: what
``rmw_fastrtps`` and rosbag2 carry."""

_CDR_ORIGIN = 4
"""CDR alignment counts from the end of the 4-byte encapsulation header."""


@dataclass(frozen=True)
class SerializedMoveSamples:
    """A serialized ``MoveSamples`` message, its fields read, its samples not yet decoded.

    Made by :func:`read_move_samples` in constant time whatever the record's length: the
    length (:attr:`samples`) is known before any sample is decoded, so an oversized record is
    refused without being built (:meth:`header_half`), an acceptable one decoded
    (:meth:`half`).

    Attributes:
        move_id: ``move_id``.
        target_angle: ``target_angle`` [deg].
        sample_period: ``sample_period`` [s].
        stamp: ``header.stamp`` [s].
        samples: Number of samples in ``data``.
        raw: The serialized bytes.
        offset: Where the samples start in ``raw``.
        byte_order: ``'<'`` or ``'>'``.
    """

    move_id: int
    target_angle: float
    sample_period: float
    stamp: float
    samples: int
    raw: bytes | memoryview
    offset: int
    byte_order: str

    def half(self, signal: str) -> MoveHalf:
        """The message as a :class:`MoveHalf`: the samples decoded into a new float64 array
        (a copy: the half does not keep the message's bytes alive).

        Raises:
            InvalidDataError: ``signal`` is not one of ``SIGNALS``.
        """  # noqa: D205
        data = np.frombuffer(self.raw, dtype=np.dtype(f'{self.byte_order}f8'),
                             count=self.samples, offset=self.offset)
        return self._half(signal, data.astype(np.float64, copy=True))

    def header_half(self, signal: str) -> MoveHalf:
        """The message's fields as a :class:`MoveHalf` without samples (nothing decoded): what
        a refused record is set aside as."""  # noqa: D205, D209
        return self._half(signal, np.zeros(0))

    def _half(self, signal: str, data: NDArray[np.float64]) -> MoveHalf:
        if signal not in SIGNALS:
            raise InvalidDataError(f'signal must be one of {SIGNALS}, got {signal!r}')
        return MoveHalf(signal=signal, move_id=self.move_id, target_angle=self.target_angle,
                        sample_period=self.sample_period, stamp=self.stamp, data=data)


def read_move_samples(raw: bytes | memoryview) -> SerializedMoveSamples:
    """Read a serialized ``MoveSamples`` message (CDR, as a raw subscription or a bag gives
    it) without decoding its samples: constant time and memory whatever it holds.

    The layout is the message's (``msg_defs/msg/MoveSamples.msg``): header (stamp, frame_id),
    ``move_id``, ``target_angle``, ``sample_period``, ``data``; plain CDR in either byte
    order. The decoded values are exactly rclpy's (a test compares them).

    Raises:
        InvalidDataError: Not a ``MoveSamples`` in plain CDR: unknown encapsulation, cut
            short, or a length that runs past the end of the bytes.
    """  # noqa: D205
    view = memoryview(raw).cast('B') if not isinstance(raw, bytes) else raw
    size = len(view)
    if size < _CDR_ORIGIN:
        raise InvalidDataError(f'MoveSamples message of {size} bytes: too short for CDR')
    order = _CDR_BYTE_ORDERS.get(bytes(view[:2]))
    if order is None:
        raise InvalidDataError(f'MoveSamples message: unsupported CDR encapsulation '
                               f'0x{bytes(view[:2]).hex()} (plain CDR expected)')

    def at(pos: int, align: int, fmt: str) -> tuple[Any, int]:
        pos += (-(pos - _CDR_ORIGIN)) % align
        end = pos + struct.calcsize(fmt)
        if end > size:
            raise InvalidDataError(f'MoveSamples message cut short ({size} bytes)')
        return struct.unpack_from(order + fmt, view, pos)[0], end

    sec, pos = at(_CDR_ORIGIN, 4, 'i')
    nanosec, pos = at(pos, 4, 'I')
    frame_len, pos = at(pos, 4, 'I')
    if frame_len > size - pos:
        raise InvalidDataError(f'MoveSamples message: frame_id of {frame_len} bytes runs past '
                               f'the end ({size} bytes)')
    pos += frame_len
    move_id, pos = at(pos, 8, 'Q')
    target_angle, pos = at(pos, 8, 'd')
    sample_period, pos = at(pos, 8, 'd')
    count, pos = at(pos, 4, 'I')
    if count:
        pos += (-(pos - _CDR_ORIGIN)) % 8
    if count > (size - pos) // 8:
        raise InvalidDataError(f'MoveSamples message: data of {count} samples runs past the '
                               f'end ({size} bytes)')
    return SerializedMoveSamples(move_id=int(move_id), target_angle=float(target_angle),
                                 sample_period=float(sample_period),
                                 stamp=float(int(sec) + int(nanosec) * 1e-9),
                                 samples=int(count), raw=raw, offset=pos, byte_order=order)


def move_samples_fields(*, move_id: int, target_angle: float, sample_period: float,
                        data: Any) -> dict[str, Any]:
    """Fields of a ``MoveSamples`` message (without its header)."""
    return {'move_id': int(move_id), 'target_angle': float(target_angle),
            'sample_period': float(sample_period),
            'data': np.ascontiguousarray(data, dtype=np.float64)}


def _floats(values: Any) -> np.ndarray[Any, np.dtype[np.float64]]:
    return np.ascontiguousarray(np.asarray(values, dtype=np.float64).reshape(-1))


@dataclass(frozen=True)
class ResultStatus:
    """What a ``ModalParameters`` message says besides the parameters.

    Attributes:
        status: ``STATUS_OK`` (0), ``STATUS_MISMATCH`` (1) or ``STATUS_FAILED`` (2)
            (:data:`~galvo_sysid.monitor.verdict.STATUS_OK`, ...).
        message: Why the status is not OK ('' when OK).
        model: The plant-model file the window was identified with ('': the packaged model
            of the paper's scanner).
    """

    status: int = STATUS_OK
    message: str = ''
    model: str = ''

    @property
    def ok(self) -> bool:
        """Whether the window was identified."""
        return self.status == STATUS_OK


def modal_parameters_fields(result: IdentificationResult, *, window_index: int,
                            model: str = '') -> dict[str, Any]:
    """Fields of a ``ModalParameters`` message (without its header) for one window's result.

    ``model`` is the plant-model file the window was identified with ('': the packaged paper
    model); ``resolved`` is the result's (every mode resolved if the result does not say).
    """
    n = len(result.residues)
    resolved = [bool(r) for r in result.resolved] if len(result.resolved) == n else [True] * n
    return {
        'window_index': int(window_index),
        'target_angle': float(result.target_angle),
        'moves': int(result.moves),
        'input_delay': float(result.input_delay),
        'k0': float(result.k0),
        'residues': _floats(result.residues),
        'natural_frequencies': _floats(result.natural_frequencies),
        'damping_ratios': _floats(result.damping_ratios),
        'k0_std': float(result.k0_std),
        'residues_std': _floats(result.residues_std),
        'natural_frequencies_std': _floats(result.natural_frequencies_std),
        'damping_ratios_std': _floats(result.damping_ratios_std),
        'fit_percent': float(result.fit_percent),
        'resolved': resolved,
        'status': STATUS_OK,
        'status_message': '',
        'model': str(model),
    }


def unidentified_fields(*, window_index: int, target_angle: float, moves: int, n_modes: int,
                        status: int, status_message: str, model: str = '') -> dict[str, Any]:
    """Fields of a ``ModalParameters`` message for a window that was not identified.

    The parameters are NaN (lists of ``n_modes``, the model's), no mode is resolved, and
    ``status`` / ``status_message`` say why (e.g. ``STATUS_MISMATCH``: the data do not match
    the model).

    Raises:
        InvalidDataError: ``status`` is OK or unknown, or ``n_modes`` is negative.
    """
    if not 0 < int(status) < len(STATUS_NAMES):
        raise InvalidDataError(f'a window not identified needs a status other than OK, got '
                               f'{status!r}')
    if int(n_modes) < 0:
        raise InvalidDataError(f'n_modes must be >= 0, got {n_modes}')
    nan = np.full(int(n_modes), np.nan)
    return {
        'window_index': int(window_index),
        'target_angle': float(target_angle),
        'moves': int(moves),
        'input_delay': math.nan,
        'k0': math.nan,
        'residues': nan.copy(),
        'natural_frequencies': nan.copy(),
        'damping_ratios': nan.copy(),
        'k0_std': math.nan,
        'residues_std': nan.copy(),
        'natural_frequencies_std': nan.copy(),
        'damping_ratios_std': nan.copy(),
        'fit_percent': math.nan,
        'resolved': [False] * int(n_modes),
        'status': int(status),
        'status_message': ' '.join(str(status_message).split()),
        'model': str(model),
    }


def _uint(value: Any) -> int:
    """A ``uint8`` field's value (rclpy gives an int, some readers a byte)."""
    return int.from_bytes(value, 'little') if isinstance(value, bytes) else int(value)


def status_from_msg(msg: Any) -> ResultStatus:
    """The :class:`ResultStatus` of a ``ModalParameters`` message.

    Messages recorded before the status existed (no such fields) are identified windows of
    the packaged model.

    Raises:
        InvalidDataError: A field has the wrong type or the status is unknown.
    """
    try:
        status = _uint(getattr(msg, 'status', STATUS_OK))
        out = ResultStatus(status=status, message=str(getattr(msg, 'status_message', '')),
                           model=str(getattr(msg, 'model', '')))
    except (TypeError, ValueError, OverflowError) as err:
        raise InvalidDataError(f'bad ModalParameters message: {err}') from err
    if not 0 <= out.status < len(STATUS_NAMES):
        raise InvalidDataError(f'ModalParameters: unknown status {out.status}')
    return out


def _tuple(values: Any) -> tuple[float, ...]:
    return tuple(float(v) for v in values)


def result_from_msg(msg: Any, *, method: str = 'refined',
                    lag_time_constant: float = 0.0) -> IdentificationResult:
    """An :class:`~galvo_sysid.ident.result.IdentificationResult` from a ``ModalParameters``.

    The message does not carry the method or the amplifier lag; they are taken from the
    arguments. Its status is read by :func:`status_from_msg` (a window not identified gives
    NaN parameters here). ``resolved`` may be absent (older messages: not said).

    Raises:
        InvalidDataError: A field is missing or the mode arrays differ in length.
    """
    from galvo_sysid.ident.result import IdentificationResult

    try:
        residues = _tuple(msg.residues)
        frequencies = _tuple(msg.natural_frequencies)
        damping = _tuple(msg.damping_ratios)
        residues_std = _tuple(msg.residues_std)
        frequencies_std = _tuple(msg.natural_frequencies_std)
        damping_std = _tuple(msg.damping_ratios_std)
        resolved = tuple(bool(r) for r in getattr(msg, 'resolved', ()))
        if {len(frequencies), len(damping), len(residues_std), len(frequencies_std),
                len(damping_std)} != {len(residues)} or len(resolved) not in (0, len(residues)):
            raise InvalidDataError('ModalParameters: mode arrays differ in length')
        return IdentificationResult(
            target_angle=float(msg.target_angle), moves=int(msg.moves),
            input_delay=float(msg.input_delay), lag_time_constant=float(lag_time_constant),
            k0=float(msg.k0), residues=residues, natural_frequencies=frequencies,
            damping_ratios=damping, k0_std=float(msg.k0_std), residues_std=residues_std,
            natural_frequencies_std=frequencies_std, damping_ratios_std=damping_std,
            fit_percent=float(msg.fit_percent), method=method, resolved=resolved)
    except (AttributeError, TypeError, ValueError, OverflowError) as err:
        if isinstance(err, InvalidDataError):
            raise
        raise InvalidDataError(f'bad ModalParameters message: {err}') from err


def drift_status_fields(verdict: DriftVerdict) -> dict[str, Any]:
    """Fields of a ``DriftStatus`` message (without its header)."""
    return {
        'window_index': max(0, int(verdict.window_index)),
        'level': int(verdict.level),
        'names': list(verdict.names),
        'relative_deviation': _floats(verdict.relative_deviation),
        'tolerance': _floats(verdict.tolerance),
        'message': verdict.message,
    }


def verdict_from_msg(msg: Any) -> DriftVerdict:
    """A :class:`~galvo_sysid.monitor.verdict.DriftVerdict` from a ``DriftStatus`` message.

    Raises:
        InvalidDataError: A field is missing or the level is unknown.
    """
    try:
        level = _uint(msg.level)
        verdict = DriftVerdict(window_index=int(msg.window_index), level=level,
                               names=tuple(str(n) for n in msg.names),
                               relative_deviation=_tuple(msg.relative_deviation),
                               tolerance=_tuple(msg.tolerance), message=str(msg.message))
    except (AttributeError, TypeError, ValueError, OverflowError) as err:
        raise InvalidDataError(f'bad DriftStatus message: {err}') from err
    if not 0 <= verdict.level <= MISMATCH:
        raise InvalidDataError(f'DriftStatus: unknown level {verdict.level}')
    return verdict


def diagnostic_values(verdict: DriftVerdict, *,
                      extra: Mapping[str, str] | None = None) -> list[tuple[str, str]]:
    """Key/value pairs describing a verdict, for ``diagnostic_msgs/KeyValue``.

    One entry per parameter: ``'omega_1': '-0.21 % (tolerance 1 %, std 0.02 %)'``, after
    ``verdict``, ``window_index`` and ``target_angle [deg]`` and before ``extra``.
    """
    out = [('verdict', LEVEL_NAMES[verdict.level]), ('window_index', str(verdict.window_index))]
    if math.isfinite(verdict.target_angle):
        out.append(('target_angle [deg]', f'{verdict.target_angle:g}'))
    stds = verdict.relative_std or (math.nan,) * len(verdict.names)
    for name, d, t, s in zip(verdict.names, verdict.relative_deviation, verdict.tolerance,
                             stds, strict=False):
        if not math.isfinite(d):
            out.append((name, 'n/a'))
            continue
        text = f'{100 * d:+.3f} % (tolerance {100 * t:g} %'
        text += f', std {100 * s:.3f} %)' if math.isfinite(s) else ')'
        if name in verdict.flagged:
            text += ' FLAGGED'
        out.append((name, text))
    out.extend((extra or {}).items())
    return out


def fill_header(msg: Any, *, stamp: float, frame_id: str = '') -> None:
    """Set ``msg.header`` (stamp in seconds) on a message whose header already exists."""
    sec, nanosec = seconds_to_stamp(stamp)
    msg.header.stamp.sec = sec
    msg.header.stamp.nanosec = nanosec
    msg.header.frame_id = frame_id


def fill(msg: Any, fields: Mapping[str, Any]) -> Any:
    """Set ``fields`` on ``msg`` and return it; float64 arrays go in as rclpy expects them."""
    for name, value in fields.items():
        current = getattr(msg, name)
        if isinstance(value, np.ndarray) and isinstance(current, array.array):
            buf = array.array(current.typecode)
            buf.frombytes(np.ascontiguousarray(value, dtype=np.float64).tobytes())
            value = buf
        setattr(msg, name, value)
    return msg
