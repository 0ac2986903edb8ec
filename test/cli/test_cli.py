"""The galvo-sysid command line, run as a subprocess like a user would."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import numpy as np
import pytest

from galvo_sysid.field.bags import CURRENT_TOPIC, ENCODER_TOPIC, BagWriter, stamp_to_ns
from galvo_sysid.field.simulate import write_moves
from galvo_sysid.interfaces.topics import MOVE_SAMPLES
from galvo_sysid.model import REFERENCE_MODEL
from galvo_sysid.sim.simulator import GalvoSimulator

SUBCOMMANDS = ('simulate', 'identify', 'info', 'record', 'replay', 'echo', 'topic', 'param')
WINDOW_FIELDS = {'target_angle', 'moves', 'input_delay', 'k0', 'residues',
                 'natural_frequencies', 'damping_ratios', 'k0_std', 'residues_std',
                 'natural_frequencies_std', 'damping_ratios_std', 'fit_percent', 'drift',
                 'partial', 'window_index'}


def run(venv_bin: Path, *args: str | Path,
        timeout: float = 120) -> subprocess.CompletedProcess[str]:
    return subprocess.run([str(venv_bin / 'galvo-sysid'), *map(str, args)], capture_output=True,
                          text=True, timeout=timeout, check=False)


def assert_one_line_error(proc: subprocess.CompletedProcess[str], *needles: str) -> None:
    assert proc.returncode == 1, proc.stdout + proc.stderr
    assert 'Traceback' not in proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1, proc.stderr
    assert lines[0].startswith('galvo-sysid ')
    for needle in needles:
        assert needle in lines[0]


@pytest.fixture(scope='module')
def sim_bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """1 psi x 200 moves (two complete windows), written by the command in-process."""
    from galvo_sysid.cli.main import main

    path = tmp_path_factory.mktemp('cli') / 'sim'
    assert main(['simulate', '--out', str(path), '--angles', '1psi', '--moves-per-angle',
                 '200', '--seed', '3']) == 0
    return path


@pytest.fixture(scope='module')
def combined_bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """One bag, 200 moves of 1 psi then 120 moves of 2 psi (partial windows at the end)."""
    sim = GalvoSimulator(seed=5)
    path = tmp_path_factory.mktemp('cli') / 'combined'
    with BagWriter(path) as bag:
        bag.add_topic(CURRENT_TOPIC, MOVE_SAMPLES)
        bag.add_topic(ENCODER_TOPIC, MOVE_SAMPLES)
        write_moves(bag, sim.moves(angles=[0.3], moves_per_angle=200))
        write_moves(bag, sim.moves(angles=[0.6], moves_per_angle=120))
    return path


@pytest.fixture(scope='module')
def identified(venv_bin_module: Path, combined_bag: Path) -> dict:
    proc = run(venv_bin_module, 'identify', combined_bag, '--json')
    assert proc.returncode == 0, proc.stderr
    assert proc.stderr == ''  # no progress bar when not on a terminal
    return json.loads(proc.stdout)


@pytest.fixture(scope='module')
def venv_bin_module() -> Path:
    import sys

    return Path(sys.executable).parent


def test_help_teaches_every_subcommand(venv_bin: Path) -> None:
    proc = run(venv_bin, '--help')
    assert proc.returncode == 0
    for name in SUBCOMMANDS:
        assert name in proc.stdout
    assert 'galvo-sysid simulate --out' in proc.stdout  # a worked example
    for name in SUBCOMMANDS:
        sub = run(venv_bin, name, '--help')
        assert sub.returncode == 0, sub.stderr
        assert 'examples:' in sub.stdout or name == 'info'
    for name in (*SUBCOMMANDS, 'commission', 'discrepancy'):  # one help formatter for all
        sub = run(venv_bin, name, '--help')
        assert '(default: None)' not in sub.stdout
        assert '(default: False)' not in sub.stdout


def test_usage_error_exit_code(venv_bin: Path) -> None:
    proc = run(venv_bin, 'identify')
    assert proc.returncode == 2
    proc = run(venv_bin, 'identify', 'x', '--method', 'magic')
    assert proc.returncode == 2


def test_identify_json_contract(identified: dict) -> None:
    assert set(identified) == {'windows', 'pooled', 'rejected', 'model', 'model_mismatch',
                               'mismatched_windows', 'measured_current_lag'}
    assert identified['measured_current_lag'] is None  # the current is the command
    assert identified['model'] == 'paper_table1 (packaged)'
    assert identified['model_mismatch'] is None
    assert identified['mismatched_windows'] == []
    windows = identified['windows']
    assert len(windows) == 4
    for w in windows:
        assert set(w) >= WINDOW_FIELDS
        assert w['drift']['level'] in {'OK', 'WARN', 'ERROR'}
        assert set(w['drift']['deviations']) == set(REFERENCE_MODEL.parameters())
    complete = [w for w in windows if not w['partial']]
    partial = [w for w in windows if w['partial']]
    assert sorted(w['target_angle'] for w in complete) == [-0.3, 0.3]
    assert sorted(w['target_angle'] for w in partial) == [-0.6, 0.6]
    assert all(w['moves'] == 100 for w in complete)
    assert all(w['moves'] == 60 for w in partial)
    assert identified['pooled']['moves'] == 320
    assert identified['pooled']['pooling'] == 'joint'
    assert identified['pooled']['pooled_windows'] == 4
    assert identified['pooled']['pooling_note'] is None
    assert identified['rejected'] == []


def test_simulate_then_identify_is_near_truth(identified: dict) -> None:
    truth = REFERENCE_MODEL
    pooled = identified['pooled']
    assert pooled['k0'] == pytest.approx(truth.k0, rel=0.01)
    for got, want in zip(pooled['natural_frequencies'][:2], truth.natural_frequencies[:2],
                         strict=True):
        assert got == pytest.approx(want, rel=0.002)
    for got, want in zip(pooled['residues'][:2], truth.residues[:2], strict=True):
        assert got == pytest.approx(want, rel=0.05)
    for got, want in zip(pooled['damping_ratios'][:2], truth.damping_ratios[:2], strict=True):
        assert got == pytest.approx(want, rel=0.1)
    for w in identified['windows']:
        assert w['natural_frequencies'][0] == pytest.approx(truth.natural_frequencies[0],
                                                            rel=0.003)
        assert w['drift']['level'] == 'OK'


def test_simulate_identify_table_plot_and_info(venv_bin: Path, sim_bag: Path,
                                               tmp_path: Path) -> None:
    plot = tmp_path / 'report.png'
    proc = run(venv_bin, 'identify', sim_bag, '--plot', plot)
    assert proc.returncode == 0, proc.stderr
    assert 'pooled over 2 window(s), 200 moves (one joint fit):' in proc.stdout
    for name in REFERENCE_MODEL.parameters():
        assert name in proc.stdout
    assert plot.read_bytes()[:8] == b'\x89PNG\r\n\x1a\n'
    info = run(venv_bin, 'info', sim_bag)
    assert info.returncode == 0
    assert '/galvo/current' in info.stdout
    assert '(200 messages)' in info.stdout


def test_sqlite3_storage(venv_bin: Path, tmp_path: Path) -> None:
    bag = tmp_path / 'sq'
    proc = run(venv_bin, 'simulate', '--out', bag, '--angles', '0.3', '--moves-per-angle',
               '100', '--storage', 'sqlite3')
    assert proc.returncode == 0, proc.stderr
    assert list(bag.glob('*.db3'))
    proc = run(venv_bin, 'identify', bag, '--json', '--min-partial', '50')
    assert proc.returncode == 0, proc.stderr
    windows = json.loads(proc.stdout)['windows']
    assert [w['moves'] for w in windows] == [50, 50]
    assert all(w['partial'] for w in windows)


def test_bad_moves_are_rejected_and_the_rest_used(venv_bin: Path, tmp_path: Path) -> None:
    sim = GalvoSimulator(seed=8)
    moves = list(sim.moves(angles=[0.3], moves_per_angle=212))
    path = tmp_path / 'bad'
    nan_id, dup_id, lonely_id, garbage_id = moves[4].move_id, moves[6].move_id, \
        moves[8].move_id, moves[10].move_id
    with BagWriter(path) as bag:
        bag.add_topic(CURRENT_TOPIC, MOVE_SAMPLES)
        bag.add_topic(ENCODER_TOPIC, MOVE_SAMPLES)
        for m in moves:
            ns = stamp_to_ns(m.stamp)
            enc = m.encoder.copy()
            if m.move_id == nan_id:
                enc[100] = np.nan
            cur_msg = bag.move_samples(stamp=m.stamp, move_id=m.move_id,
                                       target_angle=m.target_angle,
                                       sample_period=m.sample_period, data=m.current)
            bag.write(CURRENT_TOPIC, ns, cur_msg)
            if m.move_id == dup_id:
                bag.write(CURRENT_TOPIC, ns + 1, cur_msg)
            if m.move_id == lonely_id:
                continue
            if m.move_id == garbage_id:
                bag.write_raw(ENCODER_TOPIC, ns, b'\x00\x01\x00\x00\x07')
                continue
            bag.write(ENCODER_TOPIC, ns, bag.move_samples(
                stamp=m.stamp, move_id=m.move_id, target_angle=m.target_angle,
                sample_period=m.sample_period, data=enc))
    proc = run(venv_bin, 'identify', path, '--json')
    assert proc.returncode == 0, proc.stderr
    out = json.loads(proc.stdout)
    reasons = {r['move_id']: r['reason'] for r in out['rejected'] if r['move_id'] is not None}
    assert 'NaN' in reasons[nan_id]
    assert 'duplicate' in reasons[dup_id]
    assert 'unpaired' in reasons[lonely_id]
    assert 'unpaired' in reasons[garbage_id]
    undecodable = [r for r in out['rejected'] if r['move_id'] is None]
    assert len(undecodable) == 1
    assert 'undecodable' in undecodable[0]['reason']
    assert undecodable[0]['topic'] == ENCODER_TOPIC
    # 106 moves per sign, 3 of the + sign lost (ids 4, 8, 10 are even: +0.3), 1 duplicate ok
    assert sorted(w['moves'] for w in out['windows']) == [100, 100]
    assert all(not w['partial'] for w in out['windows'])


def test_missing_bag(venv_bin: Path, tmp_path: Path) -> None:
    assert_one_line_error(run(venv_bin, 'identify', tmp_path / 'none'), 'not found')
    assert_one_line_error(run(venv_bin, 'info', tmp_path / 'none'), 'not found')


def test_not_a_bag(venv_bin: Path, tmp_path: Path) -> None:
    (tmp_path / 'notes.txt').write_text('not a bag')
    assert_one_line_error(run(venv_bin, 'identify', tmp_path), 'not a rosbag2 bag')
    assert_one_line_error(run(venv_bin, 'identify', tmp_path / 'notes.txt'),
                          'not a rosbag2 bag')


def test_truncated_and_corrupt_bags(venv_bin: Path, sim_bag: Path, tmp_path: Path) -> None:
    import shutil

    cut = tmp_path / 'cut'
    shutil.copytree(sim_bag, cut)
    data = next(cut.glob('*.mcap'))
    with data.open('r+b') as f:
        f.truncate(data.stat().st_size * 2 // 3)
    assert_one_line_error(run(venv_bin, 'identify', cut, '--json'), 'truncated')
    bad = tmp_path / 'bad'
    shutil.copytree(sim_bag, bad)
    data = next(bad.glob('*.mcap'))
    data.write_bytes(b'\x00' * 4096)
    assert_one_line_error(run(venv_bin, 'identify', bad), 'cannot read bag')


def test_bag_without_galvo_topics(venv_bin: Path, tmp_path: Path) -> None:
    path = tmp_path / 'chatter'
    with BagWriter(path) as bag:
        bag.add_topic('/chatter', 'std_msgs/msg/String')
        bag.write('/chatter', 5, bag.typestore.types['std_msgs/msg/String'](data='hello'))
    assert_one_line_error(run(venv_bin, 'identify', path), 'no galvo/current', '/chatter')


def test_wrong_topic_type(venv_bin: Path, tmp_path: Path) -> None:
    path = tmp_path / 'wrong'
    with BagWriter(path) as bag:
        bag.add_topic(CURRENT_TOPIC, MOVE_SAMPLES)
        bag.add_topic(ENCODER_TOPIC, 'std_msgs/msg/Float64MultiArray')
    assert_one_line_error(run(venv_bin, 'identify', path, '--json'),
                          '/galvo/encoder', 'Float64MultiArray')


def test_too_few_moves(venv_bin: Path, tmp_path: Path) -> None:
    bag = tmp_path / 'few'
    assert run(venv_bin, 'simulate', '--out', bag, '--angles', '0.3', '--moves-per-angle',
               '20').returncode == 0
    proc = run(venv_bin, 'identify', bag, '--json')
    assert proc.returncode == 1
    out = json.loads(proc.stdout)
    assert out['windows'] == []
    assert out['pooled'] is None
    assert len(out['rejected']) == 20
    assert 'no window identified' in proc.stderr


def test_simulate_refuses_to_overwrite(venv_bin: Path, sim_bag: Path) -> None:
    assert_one_line_error(run(venv_bin, 'simulate', '--out', sim_bag), 'exists')


def test_simulate_bad_options(venv_bin: Path, tmp_path: Path) -> None:
    assert_one_line_error(run(venv_bin, 'simulate', '--out', tmp_path / 'a', '--drift',
                              'omega_1=fast'), 'bad drift')
    assert_one_line_error(run(venv_bin, 'simulate', '--out', tmp_path / 'b', '--effect',
                              'magic:x=1'), 'unknown effect')
    assert run(venv_bin, 'simulate', '--out', tmp_path / 'c', '--angles',
               'zero').returncode == 1


def test_bad_plot_name_is_said_before_the_work(venv_bin: Path, sim_bag: Path,
                                               tmp_path: Path) -> None:
    proc = run(venv_bin, 'identify', sim_bag, '--plot', tmp_path / 'plot.bmp')
    assert_one_line_error(proc, 'plot file must end in one of')
    assert proc.stdout == ''
    proc = run(venv_bin, 'identify', sim_bag, '--plot', tmp_path / 'no' / 'plot.png')
    assert_one_line_error(proc, 'does not exist')


def test_node_parameter_files(venv_bin: Path, sim_bag: Path, tmp_path: Path) -> None:
    from galvo_sysid.model import PAPER_MODEL, ModalModel, save_model

    sysid = tmp_path / 'sysid.yaml'
    sysid.write_text('/**:\n  ros__parameters:\n    window_size: 50\n    method: paper-A\n')
    reference = save_model(PAPER_MODEL.with_modal(ModalModel(
        k0=3.0e6, residues=REFERENCE_MODEL.residues,
        natural_frequencies=REFERENCE_MODEL.natural_frequencies,
        damping_ratios=REFERENCE_MODEL.damping_ratios)), tmp_path / 'reference.yaml')
    watchdog = tmp_path / 'watchdog.yaml'
    watchdog.write_text(f'/**:\n  ros__parameters:\n    model: {reference}\n')
    proc = run(venv_bin, 'identify', sim_bag, '--json', '--sysid-params', sysid,
               '--watchdog-params', watchdog, '--method', 'refined')
    assert proc.returncode == 0, proc.stderr
    windows = json.loads(proc.stdout)['windows']
    assert [w['moves'] for w in windows] == [50] * 4
    assert {w['method'] for w in windows} == {'refined'}  # the option wins over the file
    for w in windows:  # judged against the file's reference k0 = 3.0e6: +19 %
        assert w['drift']['deviations']['k0'] == pytest.approx(3.564 / 3.0 - 1, abs=0.01)
        assert w['drift']['level'] == 'ERROR'
    assert_one_line_error(run(venv_bin, 'identify', sim_bag, '--sysid-params',
                              tmp_path / 'missing.yaml'), 'cannot read parameter file')


def test_builtin_commands_register_no_plugin(sim_bag: Path) -> None:
    import argparse
    import sys

    from galvo_sysid.cli import main as cli

    parser = cli.build_parser(plugins=False)
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    assert set(sub.choices) == set(cli.COMMANDS)
    code = ('import sys\nfrom galvo_sysid.cli import main as cli\n'
            f'rc = cli.main(["info", {str(sim_bag)!r}])\n'
            'print(rc, sorted(m for m in sys.modules if m.startswith(tuple(cli.PLUGINS))))\n')
    proc = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                          check=False, timeout=60)
    assert proc.stdout.splitlines()[-1] == '0 []', proc.stdout + proc.stderr


def test_identify_and_commission_options_are_the_sysid_node_s() -> None:
    """The parser writes METHODS, POOLINGS and the sysid defaults out (to stay light): same."""
    import argparse
    import sys

    from galvo_sysid.cli.main import build_parser
    from galvo_sysid.field.pooling import POOLINGS
    from galvo_sysid.ident.methods import METHODS
    from galvo_sysid.monitor.parameters import defaults

    sub = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    options = {f'{name} {a.dest}': a for name in ('identify', 'commission')
               for a in sub.choices[name]._actions}
    assert tuple(options['identify method'].choices) == METHODS
    assert tuple(options['identify pooling'].choices) == POOLINGS
    sysid = defaults('sysid')
    for name in ('window_size', 'na', 'nb'):
        assert f'parameter {name}, {sysid[name]}' in options[f'identify {name}'].help, name
    assert options['commission window_size'].default == sysid['window_size']
    code = ('import sys\nfrom galvo_sysid.cli.main import build_parser\n'
            'build_parser(plugins=False)\nprint("numpy" in sys.modules)\n')
    proc = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                          check=True, timeout=60)
    assert proc.stdout.strip() == 'False'  # the parser of the built-in commands stays light

def test_importing_leaves_the_environment_alone_and_main_limits_blas(tmp_path: Path) -> None:
    """Only the entry point sets the BLAS thread count (before numpy is loaded), not an import."""
    import os
    import sys

    from galvo_sysid import BLAS_THREAD_VARIABLES

    code = ('import os, sys\n'
            'before = dict(os.environ)\n'
            'import galvo_sysid, galvo_sysid.cli.main, galvo_sysid.field.bags\n'
            'import galvo_sysid.field.live, galvo_sysid.field.simulate\n'
            'print(dict(os.environ) == before)\n'
            'from galvo_sysid.cli import main as cli\n'
            f'rc = cli.main(["info", {str(tmp_path / "none")!r}])\n'
            'print(rc, [os.environ.get(v) for v in galvo_sysid.BLAS_THREAD_VARIABLES])\n')
    env = {k: v for k, v in os.environ.items() if k not in BLAS_THREAD_VARIABLES}
    proc = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                          check=False, timeout=60, env=env)
    assert proc.stdout.splitlines() == ['True', "1 ['1', '1', '1']"], proc.stdout + proc.stderr
    env['OPENBLAS_NUM_THREADS'] = '2'  # a setting of the user's wins
    proc = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                          check=False, timeout=60, env=env)
    assert proc.stdout.splitlines()[-1] == "1 ['2', '1', '1']", proc.stdout + proc.stderr


def test_simulate_help_examples_run(tmp_path: Path, repo: Path, monkeypatch) -> None:
    """Every example of ``simulate --help`` runs as printed (outputs moved to tmp_path)."""
    import shlex

    from galvo_sysid.cli.main import build_parser, main

    monkeypatch.chdir(repo)  # the --model example names a file of the source checkout
    parser = build_parser(plugins=False)
    sub = next(a for a in parser._actions if hasattr(a, 'choices') and a.choices
               and 'simulate' in a.choices)
    text = sub.choices['simulate'].format_help().split('examples:\n', 1)[1]
    examples = [line.split('#')[0].strip() for line in text.replace('\\\n', ' ').splitlines()]
    examples = [e for e in examples if e]
    assert len(examples) >= 4
    assert any('--drift' in e for e in examples)
    assert any('--model' in e for e in examples)
    for example in examples:
        words = [w.replace('/tmp/', f'{tmp_path}/') for w in shlex.split(example)]
        assert words[0] == 'galvo-sysid'
        assert main(words[1:]) == 0, example


@pytest.fixture(scope='module')
def other_scanner(tmp_path_factory: pytest.TempPathFactory) -> tuple:
    """A bag of a scanner that is not the paper's (seed 35: 2 modes, 13.3 us, records of 451
    samples: fast) and its model file."""
    from galvo_sysid.field.simulate import simulate_bag
    from galvo_sysid.model import save_model
    from galvo_sysid.sim.family import random_scanner

    scanner = random_scanner(35)
    folder = tmp_path_factory.mktemp('other')
    model = save_model(scanner.model, folder / 'scanner35.yaml')
    bag = folder / 'bag'
    simulate_bag(bag, angles=[0.3, 1.0], moves_per_angle=40, seed=7, config=scanner.config)
    return scanner, model, bag


def test_identify_with_the_scanners_model(venv_bin: Path, other_scanner: tuple,
                                          tmp_path: Path) -> None:
    scanner, model, bag = other_scanner
    proc = run(venv_bin, 'identify', bag, '--model', model, '--window-size', '20', '--json')
    assert proc.returncode == 0, proc.stderr
    assert proc.stderr == ''
    out = json.loads(proc.stdout)
    assert out['model'] == str(model)
    assert out['model_mismatch'] is None
    assert len(out['windows']) == 4
    assert out['rejected'] == []
    truth = scanner.model.modal
    pooled = out['pooled']
    assert len(pooled['residues']) == truth.n_modes == 2
    assert pooled['k0'] == pytest.approx(truth.k0, rel=0.005)
    assert pooled['natural_frequencies'] == pytest.approx(truth.natural_frequencies, rel=0.002)
    assert pooled['residues'] == pytest.approx(truth.residues, rel=0.05)
    assert pooled['damping_ratios'] == pytest.approx(truth.damping_ratios, rel=0.1)
    for w in out['windows']:
        assert set(w['drift']['deviations']) == set(truth.parameters())
        assert w['drift']['level'] == 'OK', w['drift']['message']
    # the table: deviations from that model, not from Table I
    table = run(venv_bin, 'identify', bag, '--model', model, '--window-size', '20')
    assert table.returncode == 0, table.stderr
    assert f'deviation from the reference model {model} [%]' in table.stdout
    assert 'omega_3' not in table.stdout
    assert 'Table I' not in table.stdout
    # the model from the sysid parameter file; the command line wins over it
    params = tmp_path / 'sysid.yaml'
    params.write_text(f'/**:\n  ros__parameters:\n    model: {model}\n    window_size: 20\n')
    proc = run(venv_bin, 'identify', bag, '--sysid-params', params, '--json')
    assert proc.returncode == 0, proc.stderr
    assert json.loads(proc.stdout)['model'] == str(model)
    proc = run(venv_bin, 'identify', bag, '--sysid-params', params, '--model', '')
    assert proc.returncode == 1  # '' = the paper's model: another scanner


def test_identify_with_the_wrong_model_says_so_in_one_line(venv_bin: Path,
                                                          other_scanner: tuple) -> None:
    _, _, bag = other_scanner
    proc = run(venv_bin, 'identify', bag, '--window-size', '20')
    assert proc.returncode == 1, proc.stdout + proc.stderr
    assert 'Traceback' not in proc.stderr
    assert proc.stderr.splitlines() == [
        "the data do not match model paper_table1 (packaged): the data's sample period "
        "1.33e-05 s differs from the model's 1e-05 s; run galvo-sysid commission"]
    proc = run(venv_bin, 'identify', bag, '--window-size', '20', '--json')
    assert proc.returncode == 1
    out = json.loads(proc.stdout)
    assert out['model_mismatch'].startswith("the data's sample period 1.33e-05 s")
    assert out['windows'] == []
    assert len(proc.stderr.splitlines()) == 1
    missing = run(venv_bin, 'identify', bag, '--model', Path(bag) / 'none.yaml')
    assert_one_line_error(missing, 'none.yaml')


def test_simulate_with_a_model_file(venv_bin: Path, other_scanner: tuple,
                                    tmp_path: Path) -> None:
    scanner, model, _ = other_scanner
    out = tmp_path / 'sim'
    proc = run(venv_bin, 'simulate', '--out', out, '--model', model, '--angles', '0.3',
               '--moves-per-angle', '4', '--record-length', '300', '--dwell-length', '20')
    assert proc.returncode == 0, proc.stderr
    assert f'scanner {model}: sample period 13.3 us, records of 300 samples + 20 dwell' \
        in proc.stderr
    from galvo_sysid.field.bags import BagReader

    with BagReader(out) as reader:
        halves = list(reader.move_halves())
    assert len(halves) == 8
    assert {h.sample_period for h in halves} == {scanner.model.sample_period}
    assert {h.data.shape[0] for h in halves} == {300}
    assert halves[2].stamp - halves[0].stamp == pytest.approx(320 * 13.3e-6)
    default = run(venv_bin, 'simulate', '--out', tmp_path / 'paper', '--angles', '0.3',
                  '--moves-per-angle', '2')
    assert 'paper_table1 (packaged): sample period 10 us, records of 512 samples + 94' \
        in default.stderr
    assert_one_line_error(run(venv_bin, 'simulate', '--out', tmp_path / 'x', '--model',
                              tmp_path / 'none.yaml'), 'none.yaml')


def test_discrepancy_refuses_data_of_another_sample_period(venv_bin: Path,
                                                          other_scanner: tuple) -> None:
    _, _, bag = other_scanner
    proc = run(venv_bin, 'discrepancy', bag)  # the paper's model: 10 us
    assert_one_line_error(proc, 'sampled at 1.33e-05 s but the model at 1e-05 s')


def test_absolute_values_with_units_and_no_plot_without_a_window(
        venv_bin: Path, sim_bag: Path, tmp_path: Path) -> None:
    proc = run(venv_bin, 'identify', sim_bag, '--absolute')
    assert proc.returncode == 0, proc.stderr
    table = proc.stdout.split('identified values')[1].split('\n\n')[0].splitlines()
    assert '[rad/s]' in table[2]
    assert '[deg/(A s^2)]' in table[2]
    window = json.loads(run(venv_bin, 'identify', sim_bag, '--json').stdout)['windows'][0]
    row = next(line.split() for line in table if line.split()[:1] == ['0'])
    assert float(row[2]) == pytest.approx(window['k0'], rel=1e-5)
    pooled = [line for line in proc.stdout.splitlines() if line.startswith('  omega_1 ')]
    assert pooled
    assert 'rad/s' in pooled[0]
    tiny = tmp_path / 'tiny'
    assert run(venv_bin, 'simulate', '--out', tiny, '--angles', '0.3', '--moves-per-angle',
               '4').returncode == 0
    plot = tmp_path / 'none.png'
    proc = run(venv_bin, 'identify', tiny, '--plot', plot)
    assert proc.returncode == 1
    assert 'no plot written' in proc.stderr
    assert not plot.exists()
