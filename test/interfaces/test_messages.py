"""Message conversions (galvo_sysid.interfaces.messages) on rclpy messages and rosbags messages
alike."""

from __future__ import annotations

import array
import math
from types import SimpleNamespace

import numpy as np
import pytest
from galvo_sysid_msgs.msg import DriftStatus, ModalParameters, MoveSamples

from galvo_sysid.errors import InvalidDataError
from galvo_sysid.ident.result import IdentificationResult
from galvo_sysid.interfaces.messages import (
    diagnostic_values,
    drift_status_fields,
    fill,
    fill_header,
    modal_parameters_fields,
    move_half_from_msg,
    move_samples_fields,
    read_move_samples,
    result_from_msg,
    seconds_to_stamp,
    stamp_to_seconds,
    status_from_msg,
    unidentified_fields,
    verdict_from_msg,
)
from galvo_sysid.model import REFERENCE_MODEL
from galvo_sysid.monitor.drift import DriftMonitor
from galvo_sysid.monitor.verdict import MISMATCH, STATUS_MISMATCH, STATUS_OK

RESULT = IdentificationResult(
    target_angle=-0.9, moves=100, input_delay=1.6e-5, lag_time_constant=6e-6,
    k0=3.5e6, residues=(2.0e6, -5.4e6, -4.0e5), natural_frequencies=(7.1e4, 1.19e5, 1.67e5),
    damping_ratios=(6e-3, 7.7e-3, 4.6e-3), k0_std=1e3, residues_std=(1e4, 2e4, 3e5),
    natural_frequencies_std=(3.0, 9.0, 2e4), damping_ratios_std=(5e-5, 9e-5, 1e-2),
    fit_percent=94.2, method='refined', resolved=(True, True, False))


def test_stamps_round_trip() -> None:
    assert seconds_to_stamp(12.000000001) == (12, 1)
    assert seconds_to_stamp(1795306078.322353128)[0] == 1795306078
    sec, ns = seconds_to_stamp(5.25)
    assert stamp_to_seconds(SimpleNamespace(sec=sec, nanosec=ns)) == pytest.approx(5.25)
    with pytest.raises(InvalidDataError):
        seconds_to_stamp(math.nan)
    with pytest.raises(InvalidDataError):
        stamp_to_seconds(object())


def test_move_samples_round_trip_through_rclpy_message() -> None:
    data = np.linspace(-1.0, 1.0, 512)
    msg = fill(MoveSamples(), move_samples_fields(move_id=42, target_angle=-0.3,
                                                  sample_period=1e-5, data=data))
    fill_header(msg, stamp=100.5)
    assert isinstance(msg.data, array.array)
    half = move_half_from_msg(msg, signal='encoder')
    assert half.signal == 'encoder'
    assert half.move_id == 42
    assert half.target_angle == -0.3
    assert half.sample_period == 1e-5
    assert half.stamp == pytest.approx(100.5)
    np.testing.assert_array_equal(half.data, data)


def test_move_half_from_a_rosbags_like_message() -> None:
    msg = SimpleNamespace(header=SimpleNamespace(stamp=SimpleNamespace(sec=3, nanosec=5)),
                          move_id=7, target_angle=0.6, sample_period=1e-5,
                          data=np.arange(4.0))
    half = move_half_from_msg(msg, signal='current')
    assert half.stamp == pytest.approx(3.000000005)
    np.testing.assert_array_equal(half.data, [0, 1, 2, 3])
    empty = fill(MoveSamples(), {})
    assert move_half_from_msg(empty, signal='current').data.shape == (0,)


@pytest.mark.parametrize('broken', [
    SimpleNamespace(move_id=1),  # no fields
    SimpleNamespace(header=SimpleNamespace(stamp=SimpleNamespace(sec=0, nanosec=0)),
                    move_id='x', target_angle=0.3, sample_period=1e-5, data=[1.0]),
    SimpleNamespace(header=SimpleNamespace(stamp=SimpleNamespace(sec=0, nanosec=0)),
                    move_id=1, target_angle=0.3, sample_period=1e-5, data=['a']),
])
def test_broken_move_samples_raise_invalid_data(broken: object) -> None:
    with pytest.raises(InvalidDataError):
        move_half_from_msg(broken, signal='current')
    with pytest.raises(InvalidDataError):
        move_half_from_msg(MoveSamples(), signal='velocity')


def test_modal_parameters_round_trip() -> None:
    msg = fill(ModalParameters(), modal_parameters_fields(RESULT, window_index=9,
                                                          model='scanners/s7.yaml'))
    assert msg.window_index == 9
    assert msg.moves == 100
    assert list(msg.natural_frequencies) == [7.1e4, 1.19e5, 1.67e5]
    assert list(msg.resolved) == [True, True, False]
    assert (msg.status, msg.status_message, msg.model) == (
        ModalParameters.STATUS_OK, '', 'scanners/s7.yaml')
    back = result_from_msg(msg, lag_time_constant=6e-6)
    assert back == RESULT
    status = status_from_msg(msg)
    assert status.ok
    assert status.model == 'scanners/s7.yaml'
    # a result that does not say which modes are resolved: every mode is
    plain = fill(ModalParameters(), modal_parameters_fields(
        IdentificationResult(**{**RESULT.__dict__, 'resolved': ()}), window_index=1))
    assert list(plain.resolved) == [True] * 3
    assert plain.model == ''
    msg.damping_ratios_std = [1.0]
    with pytest.raises(InvalidDataError, match='differ in length'):
        result_from_msg(msg)


def test_status_constants_match_the_messages() -> None:
    from galvo_sysid.monitor.verdict import LEVEL_NAMES, STATUS_FAILED

    assert (ModalParameters.STATUS_OK, ModalParameters.STATUS_MISMATCH,
            ModalParameters.STATUS_FAILED) == (STATUS_OK, STATUS_MISMATCH, STATUS_FAILED)
    assert DriftStatus.MISMATCH == MISMATCH
    assert [getattr(DriftStatus, n) for n in LEVEL_NAMES] == list(range(len(LEVEL_NAMES)))


def mismatch_fields() -> dict:
    return unidentified_fields(
        window_index=4, target_angle=-0.3, moves=20, n_modes=2, status=STATUS_MISMATCH,
        status_message='the data do not match model s.yaml: no physical mode 2 in the band; '
                       'run galvo-sysid commission', model='s.yaml')


def test_a_window_that_did_not_match_the_model_round_trips_and_is_a_mismatch_verdict() -> None:
    msg = fill(ModalParameters(), mismatch_fields())
    assert msg.status == ModalParameters.STATUS_MISMATCH
    assert len(msg.residues) == 2
    assert all(math.isnan(x) for x in msg.natural_frequencies)
    assert list(msg.resolved) == [False, False]
    status = status_from_msg(msg)
    assert (status.status, status.model) == (STATUS_MISMATCH, 's.yaml')
    assert 'no physical mode 2 in the band' in status.message
    result = result_from_msg(msg)
    assert math.isnan(result.k0)
    assert result.n_modes == 2
    verdict = DriftMonitor().assess(result, window_index=4, status=status.status,
                                    status_message=status.message)
    assert verdict.level == MISMATCH
    back = verdict_from_msg(fill(DriftStatus(), drift_status_fields(verdict)))
    assert back.level == DriftStatus.MISMATCH
    assert back.message == verdict.message
    assert dict(diagnostic_values(verdict))['verdict'] == 'MISMATCH'
    with pytest.raises(InvalidDataError, match='status'):
        unidentified_fields(window_index=0, target_angle=0.3, moves=1, n_modes=1,
                            status=STATUS_OK, status_message='')
    msg.status = 7
    with pytest.raises(InvalidDataError, match='unknown status'):
        status_from_msg(msg)


def test_modal_parameters_through_rosbags_messages() -> None:
    """The same conversions on rosbags message objects (what bags hold), serialized and back;
    a message of before the status fields reads as an identified window."""
    from galvo_sysid.field.bags import galvo_typestore
    from galvo_sysid.interfaces.topics import MODAL_PARAMETERS

    store = galvo_typestore([MODAL_PARAMETERS])
    cls = store.types[MODAL_PARAMETERS]
    header = store.types['std_msgs/msg/Header'](
        stamp=store.types['builtin_interfaces/msg/Time'](sec=1, nanosec=0), frame_id='')
    for fields in (modal_parameters_fields(RESULT, window_index=9, model='m.yaml'),
                   mismatch_fields()):
        fields = {**fields, 'resolved': np.array(fields['resolved'], dtype=bool)}
        msg = cls(header=header, **fields)
        back = store.deserialize_cdr(store.serialize_cdr(msg, MODAL_PARAMETERS),
                                     MODAL_PARAMETERS)
        status = status_from_msg(back)
        assert status.status == fields['status']
        assert status.model == fields['model']
        result = result_from_msg(back, lag_time_constant=6e-6)
        assert result.resolved == tuple(bool(x) for x in fields['resolved'])
        if status.ok:
            assert result == RESULT
    old = SimpleNamespace(**{k: v for k, v in modal_parameters_fields(
        RESULT, window_index=1).items() if k not in ('resolved', 'status', 'status_message',
                                                     'model')})
    assert status_from_msg(old).ok
    assert result_from_msg(old).resolved == ()


def test_drift_status_round_trip_and_diagnostics() -> None:
    verdict = DriftMonitor().assess(RESULT, window_index=5)
    msg = fill(DriftStatus(), drift_status_fields(verdict))
    back = verdict_from_msg(msg)
    assert back.level == verdict.level
    assert back.names == verdict.names
    assert back.relative_deviation == pytest.approx(verdict.relative_deviation, nan_ok=True)
    assert math.isnan(back.relative_deviation[3])  # k3: mode 3 unresolved, not judged
    assert back.message == verdict.message
    values = dict(diagnostic_values(verdict, extra={'age': '1.0'}))
    assert values['verdict'] == verdict.level_name
    dev = (RESULT.natural_frequencies[0] - REFERENCE_MODEL.natural_frequencies[0]) / \
        REFERENCE_MODEL.natural_frequencies[0]
    assert values['omega_1'].startswith(f'{100 * dev:+.3f} %')
    assert values['age'] == '1.0'
    stale = DriftMonitor().stale(window_index=5, age=None)
    assert dict(diagnostic_values(stale))['k0'] == 'n/a'
    msg.level = 9
    with pytest.raises(InvalidDataError):
        verdict_from_msg(msg)


# -- serialized MoveSamples read before decoding (issue 12, defect 3) --------------------------

def _serialized(n: int, *, frame_id: str = '', seed: int = 0) -> tuple[MoveSamples, bytes]:
    from rclpy.serialization import serialize_message

    rng = np.random.default_rng(seed)
    msg = fill(MoveSamples(), move_samples_fields(
        move_id=int(rng.integers(0, 2**63)), target_angle=float(rng.normal()),
        sample_period=float(rng.random()), data=rng.normal(size=n)))
    fill_header(msg, stamp=float(rng.uniform(-2e9, 2e9)), frame_id=frame_id)
    return msg, serialize_message(msg)


def test_read_move_samples_is_exactly_rclpys_decoding() -> None:
    from rclpy.serialization import deserialize_message

    for seed in range(300):  # lengths and frame_ids that shift every alignment
        n, pad = seed % 37, seed % 11
        _, raw = _serialized(n, frame_id='f' * pad, seed=seed)
        back = move_half_from_msg(deserialize_message(raw, MoveSamples), signal='encoder')
        read = read_move_samples(raw)
        assert read.samples == n
        half = read.half('encoder')
        assert (half.signal, half.move_id, half.target_angle, half.sample_period,
                half.stamp) == (back.signal, back.move_id, back.target_angle,
                                back.sample_period, back.stamp)
        assert half.data.dtype == np.float64
        np.testing.assert_array_equal(half.data, back.data)
        assert half.data.base is None or half.data.base is not raw  # a copy, not a view
        assert read.header_half('encoder').data.shape == (0,)


def test_read_move_samples_in_big_endian_cdr() -> None:
    import struct

    _, raw = _serialized(3, frame_id='ab', seed=1)
    little = read_move_samples(raw)
    # the same message in big-endian CDR, field by field
    big = bytearray(b'\x00\x00\x00\x00')
    big += struct.pack('>iI', *seconds_to_stamp(little.stamp)) + struct.pack('>I', 3) + b'ab\x00'
    big += b'\x00' * ((-(len(big) - 4)) % 8)
    big += struct.pack('>Qdd', little.move_id, little.target_angle, little.sample_period)
    big += struct.pack('>I', 3) + b'\x00' * 4 + struct.pack('>3d', *little.half('current').data)
    read = read_move_samples(bytes(big))
    assert read.half('current').stamp == little.half('current').stamp
    np.testing.assert_array_equal(read.half('current').data, little.half('current').data)


def test_read_move_samples_knows_the_length_before_decoding() -> None:
    import struct
    import tracemalloc

    _, raw = _serialized(64, seed=2)
    read = read_move_samples(raw)
    count_at = raw.rfind(struct.pack('<I', 64), 0, read.offset)  # the length, before data
    assert read.offset - 8 <= count_at <= read.offset - 4
    # a message claiming 2^31 doubles in 64 doubles' bytes: refused, nothing allocated
    lying = bytearray(raw)
    struct.pack_into('<I', lying, count_at, 2**31 - 1)
    tracemalloc.start()
    try:
        with pytest.raises(InvalidDataError, match='runs past the end'):
            read_move_samples(bytes(lying))
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 100_000
    for bad, match in ((raw[:3], 'too short'), (raw[:20], 'cut short'),
                       (b'\x00\x07' + raw[2:], 'unsupported CDR'),
                       (raw[:4] + b'\x00' * 8 + b'\xff\xff\xff\x7f', 'frame_id')):
        with pytest.raises(InvalidDataError, match=match):
            read_move_samples(bad)
    with pytest.raises(InvalidDataError, match='signal'):
        read.half('torque')
