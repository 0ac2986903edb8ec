"""``galvo-sysid import``: your own data into a bag, as a user runs it; bad input one line."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import scipy.io

from galvo_sysid.cli import import_data
from galvo_sysid.cli.main import main
from galvo_sysid.field import importing
from galvo_sysid.field.bags.atomic import PARTIAL_PREFIX
from galvo_sysid.ident import identify_window, preprocess
from galvo_sysid.ident.warm import reference_start
from galvo_sysid.model import PAPER_MODEL
from galvo_sysid.sim.simulator import GalvoSimulator

VENV_BIN = Path(sys.executable).parent
ANGLE = 0.3
PERIOD = 1e-5


def run(*args: str | Path, timeout: float = 120) -> subprocess.CompletedProcess[str]:
    return subprocess.run([str(VENV_BIN / 'galvo-sysid'), *map(str, args)],
                          capture_output=True, text=True, timeout=timeout, check=False)


@pytest.fixture(scope='module')
def simulated() -> dict[str, Any]:
    """200 moves of the paper's scanner at +-0.3 deg, as plain arrays."""
    moves = list(GalvoSimulator(seed=5).moves(angles=[ANGLE], moves_per_angle=200))
    return {'current': np.array([m.current for m in moves]),
            'encoder': np.array([m.encoder for m in moves]),
            'target_angle': np.array([m.target_angle for m in moves])}


@pytest.fixture(scope='module')
def direct(simulated: dict[str, Any]) -> dict[float, float]:
    """omega_1 of each window (+0.3 deg: even moves, -0.3 deg: odd) identified directly (from
    the model's modes, as the first window of each of identify's chains)."""
    return {sign * ANGLE: identify_window(
        simulated['current'][i::2], simulated['encoder'][i::2], sample_period=PERIOD,
        target_angle=sign * ANGLE, model=PAPER_MODEL, na=15, nb=15,
        warm_start=reference_start(PAPER_MODEL)).natural_frequencies[0]
        for i, sign in enumerate((1, -1))}


def write(fmt: str, path: Path, arrays: dict[str, Any]) -> None:
    if fmt == 'npz':
        np.savez(path, **arrays)
    elif fmt == 'mat':
        scipy.io.savemat(path, arrays)
    else:
        rows = ['move,current,encoder,target_angle']
        for i, (cur, enc) in enumerate(zip(arrays['current'], arrays['encoder'], strict=True)):
            angle = float(arrays['target_angle'][i])
            rows.extend(f'{i},{float(c)!r},{float(e)!r},{angle!r}'
                        for c, e in zip(cur, enc, strict=True))
        path.write_text('\n'.join(rows) + '\n')


@pytest.mark.parametrize('fmt', ['csv', 'npz', 'mat'])
def test_import_then_identify(fmt: str, tmp_path: Path, simulated: dict[str, Any],
                              direct: dict[float, float]) -> None:
    """The command line end to end: the bag identifies as the arrays do, omega_1 within 0.1 %."""
    source = tmp_path / f'moves.{fmt}'
    write(fmt, source, dict(simulated) if fmt == 'csv'
          else {**simulated, 'sample_period': PERIOD})
    proc = run('import', source, '--out', tmp_path / 'bag',
               *(['--sample-period', '1e-5'] if fmt == 'csv' else []))
    assert proc.returncode == 0, proc.stderr
    assert proc.stderr.startswith(f'import: 200 moves from {source} ({fmt}), records of 512 '
                                  f'samples, sample period 10 us; target angles -0.3 deg x '
                                  f'100, +0.3 deg x 100 -> {tmp_path / "bag"}')
    proc = run('identify', tmp_path / 'bag', '--json')
    assert proc.returncode == 0, proc.stderr
    found = json.loads(proc.stdout)
    assert found['rejected'] == []
    assert {w['target_angle']: w['natural_frequencies'][0] for w in found['windows']} == direct
    omega_1 = found['pooled']['natural_frequencies'][0]
    assert omega_1 == pytest.approx(PAPER_MODEL.modal.natural_frequencies[0], rel=1e-3)


# --------------------------------------------------------------------------- bad input


def small(moves: int = 4, samples: int = 64) -> dict[str, Any]:
    ramp = np.minimum(np.linspace(0.0, 0.6, samples), 0.3)
    return {'current': np.ones((moves, samples)),
            'encoder': np.array([ramp if i % 2 == 0 else 0.3 - ramp for i in range(moves)]),
            'target_angle': np.array([0.3, -0.3] * (moves // 2)), 'sample_period': 1e-5}


def nan_encoder() -> dict[str, Any]:
    arrays = small()
    arrays['encoder'][3, 7] = np.nan
    return arrays


def without(name: str) -> dict[str, Any]:
    arrays = small()
    del arrays[name]
    return arrays


def v73(path: Path) -> None:
    path.write_bytes(b'MATLAB 7.3 MAT-file, HDF5 schema 1.00 .'.ljust(116) + bytes(8)
                     + b'\x00\x02IM' + b'\x89HDF\r\n\x1a\n' + bytes(400))


CASES: dict[str, tuple[str, Any, list[str], str]] = {
    # name: (file, its content, options, what the line says)
    'nan': ('m.npz', nan_encoder(), [], 'm.npz: NaN or infinity in encoder of move 3 (row 3, '
            'sample 7)'),
    'missing field': ('m.npz', without('encoder'), [], "m.npz: no array 'encoder'"),
    'wrong shape': ('m.mat', {**small(), 'target_angle': [0.3, -0.3, 0.3]}, [],
                    'm.mat: target_angle has shape (1, 3), expected 4 value(s), one per move'),
    'non-numeric cell': ('m.csv', 'move,current,encoder\n0,1.0,0.0\n0,1.5,zero\n', [],
                         "m.csv: line 3, column encoder: not a number: 'zero'"),
    'empty file': ('m.csv', '', [], 'm.csv: empty file'),
    'header only': ('m.csv', 'move,current,encoder\n', [], 'no rows after the header'),
    'period zero': ('m.npz', small(), ['--sample-period', '0'], "the file's sample period "
                    '1e-05 s differs from the one given, 0.0 s'),
    'period negative in the file': ('m.npz', {**small(), 'sample_period': -1e-5}, [],
                                    'sample period -1e-05 s must be within 1e-07..0.1 s'),
    'period absurd': ('m.npz', without('sample_period'), ['--sample-period', '20'],
                      'sample period 20.0 s must be within 1e-07..0.1 s (in seconds: 10 us '
                      'is 1e-05)'),
    'period nan': ('m.npz', without('sample_period'), ['--sample-period', 'nan'],
                   'sample period nan s must be within'),
    'no period': ('m.npz', without('sample_period'), [], 'no sample period: the file has none, '
                  'give it (--sample-period, in seconds)'),
    'too big': ('m.npz', small(), ['--max-bytes', '1000'], 'above the size limit of 1,000 bytes '
                '(--max-bytes)'),
    'v7.3': ('m.mat', v73, [], "a MATLAB v7.3 (HDF5) file, not read: save it with save(..., "
             "'-v7') or write an .npz file"),
    'not a file type': ('m.xlsx', 'x', [], "m.xlsx: unknown file type '.xlsx'"),
    'one angle for moves both ways': ('m.npz', without('target_angle'),
                                      ['--target-angle', '0.3'], 'm.npz: move 1 travels -0.3 '
                                      'deg against its target angle +0.3 deg'),
}


def make(tmp_path: Path, name: str, content: Any) -> Path:
    path = tmp_path / name
    if callable(content):
        content(path)
    elif isinstance(content, str):
        path.write_text(content)
    else:
        write(path.suffix[1:], path, content)
    return path


def assert_one_line(err: str, *needles: str) -> None:
    assert 'Traceback' not in err
    lines = err.splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith('galvo-sysid import: error: '), lines[0]
    for needle in needles:
        assert needle in lines[0], lines[0]


def assert_nothing_written(tmp_path: Path, source: Path) -> None:
    assert sorted(p.name for p in tmp_path.iterdir()) == [source.name]


@pytest.mark.parametrize('case', list(CASES))
def test_bad_input_is_one_line_exit_1_and_no_bag(case: str, tmp_path: Path,
                                                 capsys: pytest.CaptureFixture[str]) -> None:
    name, content, options, needle = CASES[case]
    source = make(tmp_path, name, content)
    assert main(['import', str(source), '--out', str(tmp_path / 'bag'), *options]) == 1
    captured = capsys.readouterr()
    assert captured.out == ''
    assert_one_line(captured.err, needle)
    assert_nothing_written(tmp_path, source)


def test_missing_file_and_existing_bag(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(['import', str(tmp_path / 'none.npz'), '--out', str(tmp_path / 'bag')]) == 1
    assert_one_line(capsys.readouterr().err, 'none.npz: no such file')
    assert not (tmp_path / 'bag').exists()
    source = make(tmp_path, 'm.npz', small())
    (tmp_path / 'bag').mkdir()
    assert main(['import', str(source), '--out', str(tmp_path / 'bag')]) == 1
    assert_one_line(capsys.readouterr().err, 'output bag exists already, not overwriting')
    assert list((tmp_path / 'bag').iterdir()) == []
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(PARTIAL_PREFIX)]


def test_a_real_process_prints_no_traceback(tmp_path: Path) -> None:
    source = make(tmp_path, 'm.npz', nan_encoder())
    proc = run('import', source, '--out', tmp_path / 'bag')
    assert proc.returncode == 1
    assert proc.stdout == ''
    assert_one_line(proc.stderr, 'NaN or infinity in encoder of move 3')
    assert_nothing_written(tmp_path, source)


@pytest.mark.parametrize('options', [['--target-angle', '0'], ['--max-bytes', '0'],
                                     ['--format', 'xlsx'], ['--sample-period', 'fast'], []])
def test_usage_errors_exit_2(options: list[str], tmp_path: Path) -> None:
    source = make(tmp_path, 'm.npz', small())
    out = ['--out', str(tmp_path / 'bag')] if options else []
    with pytest.raises(SystemExit) as info:
        main(['import', str(source), *out, *options])
    assert info.value.code == 2
    assert_nothing_written(tmp_path, source)


def test_help_states_the_layout_and_the_limits(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit):
        main(['import', '--help'])
    text = capsys.readouterr().out
    for words in ('current        (moves, samples)       current [A]', 'encoder [deg]',
                  'target_angle   (moves,) or one value', 'sample_period  one value',
                  'stamp          (moves,)', 'move_id', 'length', 'not v7.3/HDF5',
                  'move,current,encoder,target_angle', 'examples:', '--no-travel-check',
                  f'records under {importing.MIN_SAMPLES} samples',
                  'a sample period outside 1e-7..0.1 s',
                  f'one beyond {preprocess.MAX_ANGLE:g} deg', '1 GiB'):
        assert words in text, words
    assert '(default: None)' not in text
    assert importing.SAMPLE_PERIOD_RANGE == (1e-7, 0.1)  # as the help says
    assert import_data.FORMATS == importing.FORMATS  # written out to keep the parser light
    assert import_data.MAX_BYTES == importing.MAX_BYTES
    main_help = subprocess.run([str(VENV_BIN / 'galvo-sysid'), '--help'], capture_output=True,
                               text=True, check=True, timeout=60).stdout
    assert 'galvo-sysid import moves.npz --out' in main_help


def test_the_plugin_keeps_the_parser_light() -> None:
    """register() imports no numpy (the reading is imported when the command runs)."""
    code = ('import argparse, sys\nfrom galvo_sysid.cli import import_data\n'
            'import_data.register(argparse.ArgumentParser().add_subparsers())\n'
            'print("numpy" in sys.modules)\n')
    proc = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                          check=True, timeout=60)
    assert proc.stdout.strip() == 'False'
