"""Your own data into a bag (galvo_sysid.field.importing): CSV, .npz and .mat round trips
identified as the arrays themselves are, and every refusal one typed line, no bag left."""

from __future__ import annotations

import inspect
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import pytest
import scipy.io
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from galvo_sysid.errors import ConfigurationError, GalvoSysidError, InvalidDataError
from galvo_sysid.field import importing
from galvo_sysid.field.bags import BagExistsError, BagReader
from galvo_sysid.field.bags.atomic import PARTIAL_PREFIX
from galvo_sysid.field.importing import (
    MAX_BYTES,
    MIN_SAMPLES,
    held_from_measured,
    import_bag,
    lead_current,
    moves_from_arrays,
    read_moves,
)
from galvo_sysid.field.offline import identify_bag
from galvo_sysid.ident import identify_joint, identify_window
from galvo_sysid.ident.pool import pool_results
from galvo_sysid.ident.warm import reference_start
from galvo_sysid.model import PAPER_MODEL
from galvo_sysid.monitor.moves import MoveHalf
from galvo_sysid.monitor.pairing import MoveWindower
from galvo_sysid.sim.simulator import GalvoSimulator

if TYPE_CHECKING:
    from galvo_sysid.ident.result import IdentificationResult

ANGLE = 0.3
PERIOD = 1e-5
TRUE_OMEGA_1 = PAPER_MODEL.modal.natural_frequencies[0]


# --------------------------------------------------------------------------- writing files


def save_npz(path: Path, arrays: dict[str, Any]) -> Path:
    np.savez(path, **arrays)
    return path


def save_mat(path: Path, arrays: dict[str, Any]) -> Path:
    scipy.io.savemat(path, arrays)
    return path


def save_csv(path: Path, arrays: dict[str, Any]) -> Path:
    """One row per sample: move, current, encoder, target_angle (floats written exactly)."""
    current, encoder = np.atleast_2d(arrays['current']), np.atleast_2d(arrays['encoder'])
    angles = np.broadcast_to(arrays['target_angle'], (current.shape[0],))
    lines = ['move,current [A],encoder [deg],target_angle\n']
    for i, (cur, enc) in enumerate(zip(current, encoder, strict=True)):
        lines.extend(f'{i},{float(c)!r},{float(e)!r},{float(angles[i])!r}\n'
                     for c, e in zip(cur, enc, strict=True))
    path.write_text(''.join(lines))
    return path


SAVERS = {'npz': save_npz, 'mat': save_mat, 'csv': save_csv}


# --------------------------------------------------------------------------- round trips


@pytest.fixture(scope='module')
def simulated() -> dict[str, Any]:
    """200 moves of the paper's scanner at +-0.3 deg, as plain arrays."""
    moves = list(GalvoSimulator(seed=11).moves(angles=[ANGLE], moves_per_angle=200))
    assert {m.sample_period for m in moves} == {PERIOD}
    return {'current': np.array([m.current for m in moves]),
            'encoder': np.array([m.encoder for m in moves]),
            'target_angle': np.array([m.target_angle for m in moves]),
            'sample_period': PERIOD}


@pytest.fixture(scope='module')
def direct(simulated: dict[str, Any]) -> dict[str, IdentificationResult]:
    """The arrays identified directly, as identify_bag does with a bag's windows (the first
    window of each of its chains started from the model's modes)."""
    cur, enc = simulated['current'], simulated['encoder']
    windows = {sign * ANGLE: (cur[i::2], enc[i::2]) for i, sign in enumerate((1, -1))}
    out = {f'{angle:+g}': identify_window(c, e, sample_period=PERIOD, target_angle=angle,
                                          model=PAPER_MODEL, na=15, nb=15,
                                          warm_start=reference_start(PAPER_MODEL))
           for angle, (c, e) in windows.items()}
    combined = pool_results(list(out.values()))
    out['pooled'] = identify_joint(list(windows.values()), sample_period=PERIOD,
                                   initial=combined, target_angle=combined.target_angle,
                                   keep_initial_damping=True, model=PAPER_MODEL,
                                   noise_models=[r.noise_model for r in out.values()])
    return out


@pytest.mark.parametrize('fmt', ['npz', 'mat', 'csv'])
def test_round_trip_identifies_as_the_arrays_do(fmt: str, tmp_path: Path,
                                                simulated: dict[str, Any],
                                                direct: dict[str, IdentificationResult]) -> None:
    arrays = dict(simulated)
    options: dict[str, Any] = {}
    if fmt == 'csv':  # the layout has no file-wide values but a column: given as an option
        options['sample_period'] = arrays.pop('sample_period')
    source = SAVERS[fmt](tmp_path / f'moves.{fmt}', arrays)
    summary = import_bag(source, tmp_path / 'bag', **options)
    assert summary.moves == 200
    assert summary.shortest == summary.longest == 512
    assert summary.angles == {-ANGLE: 100, ANGLE: 100}
    assert summary.sample_period == PERIOD
    assert 'import: 200 moves' in str(summary)

    with BagReader(summary.path) as reader:  # the samples bit for bit
        halves = [h for h in reader.move_halves() if isinstance(h, MoveHalf)]
    assert len(halves) == 400
    for h in halves:
        np.testing.assert_array_equal(h.data, simulated[h.signal][h.move_id])
        assert h.target_angle == simulated['target_angle'][h.move_id]
        assert h.sample_period == PERIOD

    found = identify_bag(summary.path)
    assert len(found.windows) == 2
    assert not found.rejected
    for w in found.windows:  # each window: what the arrays give directly
        assert w.result.natural_frequencies == direct[f'{w.target_angle:+g}'].natural_frequencies
    assert found.pooled is not None
    assert found.pooled.natural_frequencies == direct['pooled'].natural_frequencies
    assert found.pooled.natural_frequencies[0] == pytest.approx(TRUE_OMEGA_1, rel=1e-3)


def test_unequal_records_and_every_optional_array(tmp_path: Path) -> None:
    """Records of different lengths (``length``), ids, stamps, one angle: as given in the bag."""
    rng = np.random.default_rng(0)
    lengths = np.array([64, 40, 64, 33])
    current = rng.normal(size=(4, 64))
    encoder = np.full((4, 64), np.nan)  # padding: ignored
    for i, n in enumerate(lengths):
        encoder[i, :n] = np.linspace(0, 0.6, n)
    arrays = {'current': current, 'encoder': encoder, 'target_angle': 0.6,
              'sample_period': [[2e-5]], 'stamp': [10.0, 10.5, 11.0, 12.0],
              'move_id': np.array([[7], [3], [9], [1]]), 'length': lengths, 'notes': [1, 2]}
    for fmt in ('npz', 'mat'):
        summary = import_bag(SAVERS[fmt](tmp_path / f'u.{fmt}', arrays), tmp_path / fmt)
        assert (summary.shortest, summary.longest) == (33, 64)
        assert summary.ignored == ('notes',)
        with BagReader(summary.path) as reader:
            halves = [h for h in reader.move_halves() if isinstance(h, MoveHalf)]
        assert [h.move_id for h in halves[::2]] == [7, 3, 9, 1]
        assert [h.stamp for h in halves[::2]] == pytest.approx([10.0, 10.5, 11.0, 12.0])
        for i, h in enumerate(halves[1::2]):
            np.testing.assert_array_equal(h.data, encoder[i, :lengths[i]])
            assert h.target_angle == 0.6
            assert h.sample_period == 2e-5


def test_csv_of_unequal_moves_with_stamps_and_comments(tmp_path: Path) -> None:
    rows = ['# exported by my DSP', '', 'stamp;encoder [deg];Move;current;sample_period;note']
    for move, n, stamp in ((5, 40, 0.5), (2, 36, 0.75)):
        rows.extend(f'{stamp};{0.3 * k / n};{move};{k * 1e-3};1e-5;x' for k in range(n))
    path = tmp_path / 'moves.txt'
    path.write_text('\n'.join(rows) + '\n')
    moves = read_moves(path, target_angle=0.3)
    assert [m.move_id for m in moves.moves] == [5, 2]
    assert [m.stamp for m in moves.moves] == [0.5, 0.75]
    assert [m.current.shape[0] for m in moves.moves] == [40, 36]
    assert moves.sample_period == 1e-5
    assert moves.ignored == ('note',)
    assert moves.moves[1].current[3] == 3e-3


def test_csv_as_a_spreadsheet_saves_it(tmp_path: Path) -> None:
    """A byte-order mark, CRLF line ends, quoted cells, ``move_id`` for ``move``."""
    rows = ['move_id,"current [A]",encoder,target_angle']
    rows.extend(f'{m},"{k}",{0.3 * k / 39},0.3' for m in (4, 8) for k in range(40))
    path = tmp_path / 'sheet.csv'
    path.write_bytes(b'\xef\xbb\xbf' + '\r\n'.join(rows).encode() + b'\r\n')
    moves = read_moves(path, sample_period=1e-5)
    assert [m.move_id for m in moves.moves] == [4, 8]
    assert moves.moves[1].current[39] == 39.0
    assert moves.moves[1].encoder[39] == pytest.approx(0.3)


def test_stamps_default_to_records_back_to_back() -> None:
    enc = np.tile(np.linspace(0, 0.3, 50), (3, 1))
    moves = moves_from_arrays(np.zeros((3, 50)), enc, sample_period=1e-4, target_angle=0.3)
    assert [m.stamp for m in moves.moves] == pytest.approx([0.0, 0.005, 0.01])
    assert [m.move_id for m in moves.moves] == [0, 1, 2]


def test_constants_are_the_windower_s() -> None:
    defaults = inspect.signature(MoveWindower).parameters
    assert defaults['min_samples'].default == MIN_SAMPLES
    assert defaults['angle_resolution'].default == importing._MIN_ANGLE


# --------------------------------------------------------------------------- refusals


def small(moves: int = 4, samples: int = 64) -> dict[str, Any]:
    """Valid arrays: moves alternating +-0.3 deg, the encoder a ramp to the target."""
    ramp = np.minimum(np.linspace(0.0, 0.6, samples), 0.3)  # there at half the record
    encoder = np.array([ramp if i % 2 == 0 else 0.3 - ramp for i in range(moves)])
    return {'current': np.ones((moves, samples)), 'encoder': encoder,
            'target_angle': np.array([0.3, -0.3] * (moves // 2)), 'sample_period': 1e-5}


def changed(**changes: Any) -> dict[str, Any]:
    arrays = small()
    for name, value in changes.items():
        if value is None:
            del arrays[name]
        else:
            arrays[name] = value(arrays) if callable(value) else value
    return arrays


def _with(name: str, index: tuple[int, int], value: float) -> Any:
    def change(arrays: dict[str, Any]) -> Any:
        out = np.array(arrays[name], dtype=float)
        out[index] = value
        return out
    return change


ARRAY_CASES = {
    'no encoder': (changed(encoder=None), "no array 'encoder' (it holds: current"),
    'shapes differ': (changed(encoder=lambda a: a['encoder'][:, :63]),
                      'current has shape (4, 64) but encoder (4, 63)'),
    '3-d': (changed(current=np.ones((4, 64, 2))), 'current has shape (4, 64, 2), expected'),
    'empty': (changed(current=np.ones((0, 64)), encoder=np.ones((0, 64))), 'current is empty'),
    'nan': (changed(encoder=_with('encoder', (2, 5), np.nan)),
            'NaN or infinity in encoder of move 2 (row 2, sample 5)'),
    'inf': (changed(current=_with('current', (1, 0), np.inf)),
            'NaN or infinity in current of move 1'),
    'angles too few': (changed(target_angle=[0.3, -0.3, 0.3]),
                       'expected 4 value(s), one per move, or one value'),
    'transposed': (changed(current=lambda a: a['current'].T, encoder=lambda a: a['encoder'].T,
                           target_angle=[0.3] * 4), 'transposed?'),
    'zero angle': (changed(target_angle=[0.3, -0.3, 0.0, -0.3]), 'of move 2 is zero'),
    'absurd angle': (changed(target_angle=100.0), 'must be within 90 deg'),
    'nan angle': (changed(target_angle=[0.3, np.nan, 0.3, 0.3]), 'NaN or infinity in '
                  'target_angle'),
    'period zero': (changed(sample_period=0.0), 'sample period 0.0 s must be within 1e-07..0.1'),
    'period negative': (changed(sample_period=-1e-5), 'sample period -1e-05 s must be within'),
    'period absurd': (changed(sample_period=10.0), 'in seconds: 10 us is 1e-05'),
    'period two values': (changed(sample_period=[1e-5, 2e-5]), 'expected one value'),
    'no period': (changed(sample_period=None), 'no sample period'),
    'too short': (changed(current=np.ones((4, 10)),
                          encoder=lambda a: a['encoder'][:, ::7]), 'at least 32'),
    'ids repeated': (changed(move_id=[1, 2, 1, 3]), 'move_id 1 appears twice'),
    'ids negative': (changed(move_id=[0, -1, 2, 3]), 'move_id -1 (move 1) must be within'),
    'ids fractional': (changed(move_id=[0, 1.5, 2, 3]), 'is not a whole number'),
    'stamps back': (changed(stamp=[0.0, 1.0, 0.5, 2.0]), 'stamps must increase'),
    'length beyond': (changed(length=[64, 70, 64, 64]), 'length 70 of move 1 (row 1) must be'),
    'booleans': (changed(current=np.ones((4, 64), dtype=bool)),
                 'current holds booleans, not real numbers'),
    'complex': (changed(encoder=lambda a: a['encoder'] + 0j), 'holds complex numbers'),
    'text': (changed(target_angle=np.array(['a', 'b', 'c', 'd'])), 'target_angle holds text'),
    'one angle, moves both ways': (changed(target_angle=0.3), 'move 1 travels -0.3 deg '
                                   'against its target angle +0.3 deg: give the target angle '
                                   'of each move'),
    'radians': (changed(encoder=lambda a: np.radians(a['encoder'])),
                'is the encoder in degrees?'),
}


@pytest.mark.parametrize('fmt', ['npz', 'mat'])
@pytest.mark.parametrize('case', list(ARRAY_CASES))
def test_bad_arrays_are_refused_in_one_line(case: str, fmt: str, tmp_path: Path) -> None:
    arrays, needle = ARRAY_CASES[case]
    source = SAVERS[fmt](tmp_path / f'bad.{fmt}', arrays)
    assert_refused(source, tmp_path / 'bag', needle)


def test_bad_arrays_given_directly() -> None:
    with pytest.raises(InvalidDataError, match=r'^arrays: NaN or infinity in current'):
        moves_from_arrays([[np.nan] * 40], [[0.3] * 40], sample_period=1e-5, target_angle=0.3)


def assert_refused(source: Path, out: Path, needle: str, **options: Any) -> str:
    with pytest.raises(GalvoSysidError) as info:
        import_bag(source, out, **options)
    text = str(info.value)
    assert '\n' not in text
    assert needle in text, text
    assert text.startswith(f'{source}: '), text
    assert not out.exists()
    assert not [p for p in out.parent.iterdir() if p.name.startswith(PARTIAL_PREFIX)]
    return text


CSV_HEAD = 'move,current,encoder,target_angle\n'


def csv_move(move: int, angle: float = 0.3, samples: int = 40) -> str:
    """The rows of a move whose encoder ramps from 0 to ``angle``."""
    return ''.join(f'{move},1.0,{angle * k / (samples - 1)},{angle}\n' for k in range(samples))


CSV_MOVE = csv_move(0)


@pytest.mark.parametrize(('text', 'needle'), [
    (CSV_HEAD + '0,1.0,0.0,0.3\n0,abc,0.0,0.3\n', 'line 3, column current: not a number: '
     "'abc'"),
    (CSV_HEAD + '0,1.0,0.0,0.3\n0,1.0,nan,0.3\n', "line 3, column encoder: 'nan' is not a "
     'finite number'),
    (CSV_HEAD + '0,1.0,0.0,0.3\n0,1.0,,0.3\n', "line 3, column encoder: not a number: ''"),
    ('move,current,target_angle\n0,1,0.3\n', "no column 'encoder' in the header"),
    ('move,current,encoder [rad],target_angle\n', "column 'encoder [rad]' is in [rad]; encoder "
     'must be in [deg]'),
    ('move,current,current,encoder\n', 'column current appears twice'),
    (CSV_HEAD + '0,1.0,0.0\n', 'line 2 has 3 cells, the header 4'),
    (CSV_HEAD + csv_move(0) + csv_move(1) + '0,1,0.3,0.3\n',
     'line 82: move 0 again after other moves (the rows of a move must be together)'),
    (CSV_HEAD + '-1,1.0,0.0,0.3\n', 'line 2, column move: -1 is not within'),
    (CSV_HEAD + '2.5,1.0,0.0,0.3\n', "line 2, column move: '2.5' is not a move id"),
    (CSV_HEAD + '0,1.0,0.0,0.3\n0,1.0,0.0,0.6\n', 'line 3: target_angle 0.6 differs from 0.3 '
     'on line 2'),
    (CSV_HEAD, 'no rows after the header'),
    ('# only a comment\n\n', 'no header line'),
    (CSV_HEAD + csv_move(3, samples=5), 'move 3 has 5 samples: identification needs at '
     'least 32'),
    ('move,current,encoder\n' + CSV_MOVE.replace(',0.3\n', '\n'), 'no target angle'),
])
def test_bad_csv_is_refused_in_one_line(text: str, needle: str, tmp_path: Path) -> None:
    source = tmp_path / 'bad.csv'
    source.write_text(text)
    assert_refused(source, tmp_path / 'bag', needle, sample_period=1e-5)


def test_bad_files_are_refused_in_one_line(tmp_path: Path) -> None:
    out = tmp_path / 'bag'
    empty = tmp_path / 'empty.npz'
    empty.write_bytes(b'')
    assert_refused(empty, out, 'empty file')
    assert_refused(tmp_path / 'missing.csv', out, 'no such file')
    (tmp_path / 'dir.npz').mkdir()
    assert_refused(tmp_path / 'dir.npz', out, 'not a file')
    text = tmp_path / 'notes.dat'
    text.write_text('hello')
    assert_refused(text, out, "unknown file type '.dat'")
    with pytest.raises(ConfigurationError, match='unknown format'):
        import_bag(text, out, format='xlsx')
    assert_refused(text, out, 'not a NumPy .npz file', format='npz')
    assert_refused(text, out, 'not a MATLAB .mat file', format='mat')
    binary = tmp_path / 'binary.csv'
    binary.write_bytes(b'move,current\n\xff\xfe\x00')
    assert_refused(binary, out, 'not a text file (UTF-8)')
    good = save_npz(tmp_path / 'good.npz', small())
    cut = tmp_path / 'cut.npz'
    cut.write_bytes(good.read_bytes()[:-200])
    assert_refused(cut, out, 'cut.npz: ')
    assert_refused(good, out, 'above the size limit of 1,000 bytes', max_bytes=1000)
    pickled = tmp_path / 'pickled.npz'
    np.savez(pickled, current=np.array([object()] * 3, dtype=object), encoder=[1.0])
    assert_refused(pickled, out, 'current holds Python objects (pickled), not read')
    out.mkdir()
    (out / 'mine').write_text('kept')
    with pytest.raises(BagExistsError, match=r'^output bag exists already, not overwriting'):
        import_bag(good, out)
    assert [p.name for p in out.iterdir()] == ['mine']


def test_a_compressed_npz_is_refused_from_its_headers(tmp_path: Path,
                                                      monkeypatch: pytest.MonkeyPatch) -> None:
    """32 MB of zeros in a few tens of kB: refused before a byte of it is decompressed."""
    source = tmp_path / 'bomb.npz'
    np.savez_compressed(source, current=np.zeros((2000, 2000)), encoder=np.zeros((1, 1)))
    assert source.stat().st_size < 1_000_000

    def never(*args: Any, **kwargs: Any) -> Any:
        raise AssertionError('loaded')

    monkeypatch.setattr(np.lib.format, 'read_array', never)
    assert_refused(source, tmp_path / 'bag', 'the arrays take 32,000,008 bytes as float64, '
                   'above the size limit of 1,000,000 bytes', max_bytes=1_000_000)
    assert MAX_BYTES == 1 << 30


def test_bad_mat_files_are_refused_in_one_line(tmp_path: Path,
                                               monkeypatch: pytest.MonkeyPatch) -> None:
    out = tmp_path / 'bag'
    v73 = tmp_path / 'v73.mat'  # the 128-byte header MATLAB writes before the HDF5 data
    v73.write_bytes(b'MATLAB 7.3 MAT-file, Platform: GLNXA64, Created on: Mon Jan 1 00:00:00 '
                    b'2024 HDF5 schema 1.00 .'.ljust(116) + bytes(8) + b'\x00\x02IM'
                    + b'\x89HDF\r\n\x1a\n' + bytes(400))
    assert_refused(v73, out, "a MATLAB v7.3 (HDF5) file, not read: save it with save(..., "
                   "'-v7')")
    cells = np.empty((1, 2), dtype=object)
    cells[0, 0], cells[0, 1] = np.ones(40), np.ones(50)
    assert_refused(save_mat(tmp_path / 'cells.mat', changed(current=cells)), out,
                   'current holds a cell array, not real numbers: put the records in a '
                   '(moves, samples) matrix, padded, with their lengths in length')
    assert_refused(save_mat(tmp_path / 'chars.mat', changed(target_angle='up')), out,
                   'target_angle holds text, not real numbers')
    assert_refused(save_mat(tmp_path / 'struct.mat', changed(encoder={'a': 1.0})), out,
                   'encoder holds a struct, not real numbers')
    big = tmp_path / 'big.mat'
    scipy.io.savemat(big, small(), do_compression=True)
    assert big.stat().st_size < 4000

    def never(*args: Any, **kwargs: Any) -> Any:
        raise AssertionError('loaded')

    monkeypatch.setattr(scipy.io, 'loadmat', never)
    assert_refused(big, out, 'the arrays take 4,136 bytes as float64, above the size limit '
                   'of 4,000 bytes', max_bytes=4000)


def test_a_failed_write_leaves_no_bag(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    source = save_npz(tmp_path / 'm.npz', small())
    calls = []

    def failing(*args: Any, **kwargs: Any) -> None:
        calls.append(1)
        if len(calls) == 3:
            raise OSError(28, 'No space left on device')

    monkeypatch.setattr(importing, 'write_move', failing)
    with pytest.raises(OSError, match='No space left'):
        import_bag(source, tmp_path / 'bag')
    assert sorted(p.name for p in tmp_path.iterdir()) == ['m.npz']


def test_options_must_agree_with_the_file(tmp_path: Path) -> None:
    source = save_npz(tmp_path / 'm.npz', small())
    assert_refused(source, tmp_path / 'b', "the file's sample period 1e-05 s differs from the "
                   'one given, 2e-05 s', sample_period=2e-5)
    assert_refused(source, tmp_path / 'b', "the file's target angles differ from the one given",
                   target_angle=0.3)
    moves = read_moves(source, sample_period=1e-5)  # the same value twice: fine
    assert moves.sample_period == 1e-5
    with pytest.raises(ConfigurationError, match='unknown storage'):
        import_bag(source, tmp_path / 'b', storage='zip')
    with pytest.raises(ConfigurationError, match='max_bytes must be'):
        read_moves(source, max_bytes=0)
    passed = read_moves(save_npz(tmp_path / 'one.npz', changed(target_angle=0.3)),
                        check_travel=False)
    assert {m.target_angle for m in passed.moves} == {0.3}


# --------------------------------------------------------------------------- any input


@settings(max_examples=150, deadline=None, derandomize=True,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.data())
def test_mutated_csv_gives_moves_or_one_typed_line(tmp_path: Path, data: st.DataObject) -> None:
    """A valid CSV changed in a few random places: moves, or one GalvoSysidError line."""
    chars = list(CSV_HEAD + csv_move(0) + csv_move(1, angle=-0.3))
    for _ in range(data.draw(st.integers(1, 4))):
        first = data.draw(st.sampled_from([len(CSV_HEAD), 0]))  # mostly the rows
        where = data.draw(st.integers(first, len(chars) - 1))
        chars[where:where + data.draw(st.integers(0, 3))] = data.draw(
            st.text(alphabet=',;\n#.-+e0123456789 naif[]x\t"', max_size=4))
    source = tmp_path / 'm.csv'
    source.write_text(''.join(chars))
    try:
        moves = read_moves(source, sample_period=1e-5, check_travel=data.draw(st.booleans()))
    except GalvoSysidError as err:
        message = str(err)
    else:
        assert all(np.isfinite(m.current).all() and m.current.shape == m.encoder.shape
                   for m in moves.moves)
        return
    assert '\n' not in message
    assert message.startswith(f'{source}: ')


@settings(max_examples=150, deadline=None, derandomize=True)
@given(data=st.data())
def test_any_arrays_give_moves_or_one_typed_line(data: st.DataObject) -> None:
    shape = st.tuples(st.integers(0, 3), st.integers(0, 40))
    values = st.one_of(
        st.floats(allow_nan=True, allow_infinity=True), st.integers(-2**70, 2**70),
        st.lists(st.floats(-1e3, 1e3), max_size=4),
        shape.map(lambda s: np.ones(s)), shape.map(lambda s: np.zeros(s, dtype=np.int64)),
        st.just(np.array([True])), st.just(np.array(['x'])), st.just(np.array([1j])))
    arrays = {name: data.draw(values) for name in ('current', 'encoder', 'target_angle',
                                                   'stamp', 'move_id', 'length')
              if data.draw(st.booleans())}
    try:
        moves_from_arrays(arrays.pop('current', np.ones((2, 40))),
                          arrays.pop('encoder', np.ones((2, 40))),
                          sample_period=data.draw(st.floats(allow_nan=True)), **arrays)
    except GalvoSysidError as err:
        message = str(err)
    else:
        return
    assert '\n' not in message
    assert message.startswith('arrays: ')


def test_a_current_that_leads_the_encoder_is_moved_earlier() -> None:
    # a coil current measured when the encoder is read: the current of sample k + 1 is the
    # one that flowed over sample k; each pair keeps the samples both records still cover
    cur = np.arange(2 * 40, dtype=float).reshape(2, 40)
    enc = np.cumsum(np.full((2, 40), 0.01), axis=1)
    moves = moves_from_arrays(cur, enc, sample_period=1e-5, target_angle=0.3,
                              stamp=[1.0, 2.0])
    led = lead_current(moves, 1)
    assert [m.current.shape[0] for m in led.moves] == [39, 39]
    np.testing.assert_array_equal(led.moves[1].current, cur[1, 1:])
    np.testing.assert_array_equal(led.moves[1].encoder, enc[1, :-1])
    assert [m.stamp for m in led.moves] == [1.0, 2.0]
    assert lead_current(moves, 0) is moves
    with pytest.raises(InvalidDataError, match='leaves records of 31 samples'):
        lead_current(moves, 9)
    for bad in (-1, 1000, True):
        with pytest.raises(ConfigurationError, match='current lead'):
            lead_current(moves, bad)


def test_a_measured_current_is_turned_into_the_held_current_that_drives_it(
        tmp_path: Path) -> None:
    # an amplifier's current i follows its held input v with a first-order lag: sampled when
    # the encoder is read, i[k + 1] = a i[k] + (1 - a) v[k]; the held input comes back
    t, lag = 1e-5, 7e-6
    a = np.exp(-t / lag)
    rng = np.random.default_rng(3)
    held = rng.normal(size=(2, 39))
    cur = np.zeros((2, 40))
    cur[:, 0] = rng.normal(size=2)
    for k in range(39):
        cur[:, k + 1] = a * cur[:, k] + (1 - a) * held[:, k]
    enc = np.cumsum(np.full((2, 40), 0.01), axis=1)
    moves = moves_from_arrays(cur, enc, sample_period=t, target_angle=0.3, stamp=[1.0, 2.0])
    out = held_from_measured(moves, lag=lag)
    for i in range(2):
        np.testing.assert_allclose(out.moves[i].current, held[i], rtol=1e-12, atol=1e-12)
        np.testing.assert_array_equal(out.moves[i].encoder, enc[i, :-1])
    assert [m.stamp for m in out.moves] == [1.0, 2.0]
    # no lag: the reading a sample later flowed over the sample, as a lead of one
    for got, led in zip(held_from_measured(moves, lag=0.0).moves, lead_current(moves, 1).moves,
                        strict=True):
        np.testing.assert_array_equal(got.current, led.current)
    for bad, needle in ((-1e-6, 'must be a time >= 0'), (float('nan'), 'must be a time >= 0'),
                        (True, 'must be a time >= 0'),
                        (3e-4, 'is 30 sample periods: above 20')):
        with pytest.raises(ConfigurationError, match=needle):
            held_from_measured(moves, lag=bad)
    short = moves_from_arrays(cur[:, :32], enc[:, :32], sample_period=t, target_angle=0.3)
    with pytest.raises(InvalidDataError, match='leaves records of 31 samples'):
        held_from_measured(short, lag=lag)
    # the importer: the held current in the bag, the lag checked before the file is read
    source = tmp_path / 'm.npz'
    np.savez(source, current=cur, encoder=enc, sample_period=t, target_angle=0.3)
    summary = import_bag(source, tmp_path / 'b', measured_lag=lag)
    assert summary.shortest == summary.longest == 39
    with BagReader(summary.path) as reader:
        halves = [h for h in reader.move_halves() if isinstance(h, MoveHalf)]
    got = {(h.signal, h.move_id): h.data for h in halves}
    for i in range(2):
        np.testing.assert_allclose(got['current', i], held[i], rtol=1e-12, atol=1e-12)
        np.testing.assert_array_equal(got['encoder', i], enc[i, :-1])
    with pytest.raises(ConfigurationError, match='the lag or a current lead, not both'):
        import_bag(tmp_path / 'missing.npz', tmp_path / 'c', measured_lag=lag, current_lead=1)
    with pytest.raises(ConfigurationError, match='above 20'):
        import_bag(tmp_path / 'missing.npz', tmp_path / 'c', measured_lag=1e-3,
                   sample_period=1e-5)


def test_an_encoder_in_radians_imported_unchecked_is_refused_by_identify_and_commission(
        tmp_path: Path) -> None:
    """The import's travel check turned off, a bag of an encoder in radians: each window is
    refused in words (it was identified and judged a 98 % drift of k0, and commissioned into a
    model with k0 57 times too small)."""
    from galvo_sysid.field.commission import commission_bag

    moves = list(GalvoSimulator(seed=3).moves(angles=[ANGLE], moves_per_angle=200))
    arrays = {'current': np.array([m.current for m in moves]),
              'encoder': np.radians(np.array([m.encoder for m in moves])),
              'target_angle': np.array([m.target_angle for m in moves]),
              'sample_period': PAPER_MODEL.sample_period}
    bag = tmp_path / 'radians'
    import_bag(save_npz(tmp_path / 'rad.npz', arrays), bag, check_travel=False)
    found = identify_bag(bag)
    assert not found.windows
    reasons = {r['reason'] for r in found.rejected}
    assert any('is the encoder in degrees (radians are 57.3 times smaller)' in r
               for r in reasons), reasons
    with pytest.raises(InvalidDataError, match=r'found 0 .*radians are 57\.3 times smaller'):
        commission_bag(bag)
