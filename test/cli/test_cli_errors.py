"""Hostile and faulty input on the command line: one error line, never a traceback (issue 12).

The reproductions of ../shared/reliability_repro/07_tracebacks_and_yaml.sh and 08, 10 (the
file and command-line parts), run as a user would.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

BAGS = Path(__file__).resolve().parents[2] / 'bags'
NOMINAL = BAGS / 'nominal'
MODEL_HEAD = ('format: galvo_sysid/plant_model\nversion: 1\nmechanics: {k0: 3.564e6, modes: '
              '[{natural_frequency: 71080.0, damping_ratio: 0.006218, residue: 2069000.0}]}\n')


def run(*args: str | Path, timeout: float = 120,
        memory: int | None = None) -> subprocess.CompletedProcess[str]:
    """``galvo-sysid ARGS`` (with at most ``memory`` bytes of address space)."""
    def limit() -> None:
        import resource

        if memory is not None:
            resource.setrlimit(resource.RLIMIT_AS, (memory, memory))

    return subprocess.run([str(Path(sys.executable).parent / 'galvo-sysid'), *map(str, args)],
                          capture_output=True, text=True, timeout=timeout, check=False,
                          preexec_fn=limit)


def assert_error_line(proc: subprocess.CompletedProcess[str], command: str, *needles: str,
                      code: int = 1) -> str:
    assert 'Traceback' not in proc.stderr, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1, proc.stderr
    assert proc.returncode == code, proc.stderr
    assert lines[0].startswith(f'galvo-sysid {command}: error: '), lines[0]
    for needle in needles:
        assert needle in lines[0], lines[0]
    return lines[0]


# ------------------------------------------------------------------ the guard of every command

@pytest.mark.parametrize('error', [ValueError('bad'), MemoryError(), OverflowError('big'),
                                   ZeroDivisionError('zero'), RecursionError('deep'),
                                   OSError(28, 'No space left on device')])
def test_no_command_prints_a_traceback_for_bad_input(error: BaseException,
                                                     capsys: pytest.CaptureFixture[str],
                                                     monkeypatch: pytest.MonkeyPatch) -> None:
    """What a library deep below raises on input the checks let through: one line, exit 1."""
    from galvo_sysid.cli import info, main

    def explode(args: object) -> int:
        raise error

    monkeypatch.setattr(info, 'run', explode)
    assert main.main(['info', 'x']) == 1
    err = capsys.readouterr().err
    assert err.count('\n') == 1
    assert err.startswith('galvo-sysid info: error: ')
    assert 'Traceback' not in err


# ------------------------------------------------------------------ parameter files (defect 13)

@pytest.mark.parametrize(('option', 'value', 'needle'), [
    ('--watchdog-params', 'abc', 'warn_fraction must be a floating-point number, got text'),
    ('--watchdog-params', 'null', 'warn_fraction must be a floating-point number, got null'),
    ('--watchdog-params', '[0.5]', 'warn_fraction must be a floating-point number, got a list'),
    ('--sysid-params', 'abc', 'window_size must be an integer, got text'),
    ('--sysid-params', 'null', 'window_size must be an integer, got null'),
    ('--sysid-params', '[100]', 'window_size must be an integer, got a list'),
    ('--sysid-params', '10.7', 'window_size must be an integer, got a floating-point'),
])
def test_parameter_files_with_bad_values(tmp_path: Path, option: str, value: str,
                                         needle: str) -> None:
    name = 'warn_fraction' if option == '--watchdog-params' else 'window_size'
    path = tmp_path / 'p.yaml'
    path.write_text(f'/**:\n  ros__parameters:\n    {name}: {value}\n')
    proc = run('identify', NOMINAL, option, path)
    assert_error_line(proc, 'identify', needle, str(path))
    assert proc.stdout == ''


# ------------------------------------------------------------------ simulate (defects 11, 13)

def assert_usage_error(proc: subprocess.CompletedProcess[str], command: str,
                       *needles: str) -> None:
    """A usage error: exit 2, the parser's usage, then one error line."""
    assert 'Traceback' not in proc.stderr, proc.stderr
    assert proc.returncode == 2, proc.stderr
    last = proc.stderr.strip().splitlines()[-1]
    assert last.startswith(f'galvo-sysid {command}: error: argument '), last
    for needle in needles:
        assert needle in last, last


def test_simulate_seed_out_of_range(tmp_path: Path) -> None:
    proc = run('simulate', '--out', tmp_path / 's1', '--seed', '-1', '--moves-per-angle', '2')
    assert_usage_error(proc, 'simulate', '--seed', 'within 0..2147483647')
    assert not (tmp_path / 's1').exists()


def test_simulate_a_billion_moves_is_refused_at_once(tmp_path: Path) -> None:
    """It built every move in memory first (MemoryError after 2.7 GB under a 3 GB limit)."""
    proc = run('simulate', '--out', tmp_path / 'huge', '--moves-per-angle', '1000000000',
               memory=2_000_000_000, timeout=60)
    assert_usage_error(proc, 'simulate', '--moves-per-angle', 'within 2..1000000')
    assert not (tmp_path / 'huge').exists()


def test_simulate_a_record_longer_than_a_model_may_declare_is_refused_at_once(
        tmp_path: Path) -> None:
    """A record of 1e8 samples ran past two minutes with no output (a model file caps it
    at 1,000,000; the option did not)."""
    proc = run('simulate', '--out', tmp_path / 'long', '--moves-per-angle', '4',
               '--record-length', '100000000', timeout=60)
    assert_error_line(proc, 'simulate', 'record_length must be at most 1,000,000 samples')
    assert not (tmp_path / 'long').exists()


@pytest.mark.parametrize('change', [['--step', 'zeta_1=1000@1'],
                                    ['--drift', 'zeta_1=10/move']])
def test_simulate_refuses_a_change_that_overdamps_a_mode(tmp_path: Path,
                                                         change: list[str]) -> None:
    """`--step zeta_1=1000@1` simulated a damping ratio of 6.2 (two real poles, no resonance)
    that a model file would refuse; a drift crossing 1 the same."""
    proc = run('simulate', '--out', tmp_path / 'over', '--moves-per-angle', '20', *change)
    assert_error_line(proc, 'simulate', 'damping ratios must be at most 1, got zeta_1 = ')
    assert not (tmp_path / 'over').exists()


def test_simulate_absurd_effect_parameter(tmp_path: Path) -> None:
    proc = run('simulate', '--out', tmp_path / 's2', '--effect', 'input_delay:delay=1',
               '--moves-per-angle', '4')
    assert_error_line(proc, 'simulate', 'input_delay: delay must be > 0 and <= 0.01 s')
    assert not (tmp_path / 's2').exists()


def test_a_refused_simulate_leaves_no_bag_and_the_rerun_works(tmp_path: Path) -> None:
    """Defect 17 (repro 08): `simulate --angles 1e6` failed with the bag directory already
    made, and the re-run with a good angle was then refused because that empty bag existed."""
    out = tmp_path / 'd'
    proc = run('simulate', '--out', out, '--angles', '1e6', '--moves-per-angle', '4')
    assert_error_line(proc, 'simulate', '1000000.0 deg')
    assert list(tmp_path.iterdir()) == []
    proc = run('simulate', '--out', out, '--angles', '1', '--moves-per-angle', '4')
    assert proc.returncode == 0, proc.stderr
    assert sorted(p.name for p in out.iterdir()) == ['d.mcap', 'metadata.yaml']
    assert [p.name for p in tmp_path.iterdir()] == ['d']


def test_simulate_limits_are_the_drivers() -> None:
    """The parser writes the driver's ranges out (to stay light): the same."""
    from galvo_sysid.cli.simulate import LIMITS
    from galvo_sysid.field.simulate import schedule_limits

    assert schedule_limits() == LIMITS


# ------------------------------------------------------------------ model files for discrepancy

_BOMB = 'description:\n' + ''.join(
    f'  - &a{i} [{",".join([f"*a{i - 1}" if i else chr(34) + "lol" + chr(34)] * 10)}]\n'
    for i in range(9))


@pytest.mark.parametrize(('name', 'body', 'needles'), [
    ('eff_res_mild', MODEL_HEAD + 'effects:\n- {effect: unmodeled_resonance, parameters: '
     '{natural_frequency: 5.0e4, damping_ratio: 0.01, residue: 1.0e200}}\n',
     ('effects[1]: unmodeled_resonance: residue must be', '1e+200')),
    ('bigdelay', MODEL_HEAD + 'input_dynamics: {computation_delay: 100000000}\n',
     ('computation_delay must be within', '100000000')),
    ('bomb_description', MODEL_HEAD + _BOMB, ('aliases are not allowed',)),
])
def test_discrepancy_refuses_hostile_model_files(tmp_path: Path, name: str, body: str,
                                                 needles: tuple[str, ...]) -> None:
    """Repro 07's --model files, end to end: one line naming the file and the value, within a
    1 GiB address space (the alias bomb would expand to gigabytes; the delay allocated 60 GiB)."""
    path = tmp_path / f'{name}.yaml'
    path.write_text(body)
    proc = run('discrepancy', NOMINAL, '--max-moves-per-angle', '20', '--model', path,
               memory=1 << 30)
    assert_error_line(proc, 'discrepancy', str(path), *needles)


@pytest.mark.parametrize(('args', 'command', 'words'), [
    (('identify', '{bag}', '--window-size', '1'), 'identify',
     'window_size must be >= 4 (half a window'),
    (('simulate', '--out', '{file}/sub', '--moves-per-angle', '2'), 'simulate',
     'is a file, not a directory'),
])
def test_messages_name_the_value_given(tmp_path: Path, args: tuple[str, ...], command: str,
                                       words: str) -> None:
    """`--window-size 1` said 'min_partial must be >= 2, got 0' (an option not given); a bag
    under a file said 'File exists'."""
    (tmp_path / 'file').write_text('x')
    (tmp_path / 'bag').mkdir()
    proc = run(*(a.format(bag=tmp_path / 'bag', file=tmp_path / 'file') for a in args))
    assert_error_line(proc, command, words)
