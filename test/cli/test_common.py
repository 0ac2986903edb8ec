"""The pieces every subcommand shares (galvo_sysid.cli.common), called directly."""

from __future__ import annotations

import argparse
import io
import math
from pathlib import Path

import pytest

from galvo_sysid.cli.common import (
    HelpFormatter,
    Parser,
    Progress,
    add_subcommand,
    check_output,
    finite_float,
    nonnegative_int,
    parse_angle,
    positive,
    print_json,
)
from galvo_sysid.errors import ConfigurationError


def test_progress_bar_only_on_a_terminal_and_only_when_slow() -> None:
    class Tty(io.StringIO):
        def isatty(self) -> bool:
            return True

    quiet = io.StringIO()
    bar = Progress(quiet, 'identify', enabled=True, delay=0.0)
    bar(5, 10)
    assert quiet.getvalue() == ''  # not a terminal
    tty = Tty()
    bar = Progress(tty, 'identify', enabled=True, delay=0.0)
    bar(10, 10)
    assert '100 %' in tty.getvalue()
    assert '(10/10 messages' in tty.getvalue()
    bar.close()
    assert tty.getvalue().endswith('\r\033[K')
    fast = Tty()
    bar = Progress(fast, 'identify', enabled=True, delay=60.0)
    bar(10, 10)
    bar.close()
    assert fast.getvalue() == ''  # a short run draws nothing
    off = Tty()
    Progress(off, 'identify', enabled=False, delay=0.0)(1, 2)  # --json
    assert off.getvalue() == ''


def test_angles_in_degrees_or_psi() -> None:
    assert parse_angle('0.6') == 0.6
    assert parse_angle('2psi') == 0.6
    assert parse_angle(' -1PSI ') == -0.3
    assert parse_angle('psi') == 0.3
    for bad in ('zero', '0', 'nan', 'inf', '0psi'):
        with pytest.raises(argparse.ArgumentTypeError):
            parse_angle(bad)


def test_number_argument_types_say_what_is_wrong() -> None:
    assert positive(int)('3') == 3
    assert isinstance(positive(int)('3'), int)
    assert positive(float)('inf') == math.inf  # replay --rate inf
    assert nonnegative_int('0') == 0
    assert finite_float('-2.5') == -2.5
    cases = [(positive(int), '0', 'must be > 0'), (positive(int), '1.5', 'not a number'),
             (positive(float), 'nan', 'must be > 0'), (nonnegative_int, '-1', 'must be >= 0'),
             (nonnegative_int, 'x', 'not a whole number'), (finite_float, 'inf', 'must be finite'),
             (finite_float, 'nan', 'must be finite'), (finite_float, 'x', 'not a number')]
    for parse, text, message in cases:
        with pytest.raises(argparse.ArgumentTypeError, match=message):
            parse(text)


@pytest.mark.parametrize('text', ['-1e-6', '-2.5E+3', '-.5e-3', '-1', '-0.25'])
def test_a_negative_number_is_a_value_in_scientific_notation_too(text: str) -> None:
    """`--measured-current -1e-6` was read as an unknown option ("expected one argument")."""
    parser = Parser(prog='p')
    sub = parser.add_subparsers(dest='command', required=True)
    child = sub.add_parser('identify')
    child.add_argument('--lag', type=float)
    assert isinstance(child, Parser)
    assert parser.parse_args(['identify', '--lag', text]).lag == float(text)
    with pytest.raises(SystemExit):  # an option is still an option
        parser.parse_args(['identify', '--lag', '-x'])


def test_help_shows_only_defaults_that_say_something() -> None:
    parser = argparse.ArgumentParser(prog='x')
    sub = parser.add_subparsers()
    p = add_subcommand(sub, 'cmd', help='a command', description='line one\nline two')
    assert p.formatter_class is HelpFormatter
    p.add_argument('bag', help='the bag')
    p.add_argument('--n', type=int, default=5, help='how many')
    p.add_argument('--m', type=int, default=7, help='how many (default: %(default)s, or so)')
    p.add_argument('--name', default=None, help='a name')
    p.add_argument('--flag', action='store_true', help='a flag')
    p.add_argument('--items', action='append', default=[], help='items')
    text = ' '.join(p.format_help().split())
    assert 'line one\nline two' in p.format_help()  # the description's line breaks are kept
    assert 'how many (default: 5)' in text
    assert 'how many (default: 7, or so)' in text
    assert '(default: None)' not in text
    assert '(default: False)' not in text
    assert '(default: [])' not in text


def test_print_json_is_one_line_of_strict_json(capsys: pytest.CaptureFixture[str]) -> None:
    print_json({'a': math.nan, 'b': (1.5, math.inf), 'c': 'x'})
    assert capsys.readouterr().out == '{"a": null, "b": [1.5, null], "c": "x"}\n'


def _bag(tmp_path: Path) -> Path:
    bag = tmp_path / 'bag'
    bag.mkdir()
    (bag / 'bag.mcap').write_bytes(b'data')
    (bag / 'metadata.yaml').write_text('x')
    return bag


@pytest.mark.parametrize('where', ['bag', 'bag/bag.mcap', 'bag/metadata.yaml', 'bag/new.yaml'])
@pytest.mark.parametrize('reads', ['bag', 'bag/bag.mcap'])
def test_an_output_is_never_written_into_the_bag_it_reads(tmp_path: Path, where: str,
                                                          reads: str) -> None:
    bag = _bag(tmp_path)
    with pytest.raises(ConfigurationError, match='into the bag it reads'):
        check_output(tmp_path / where, reads=tmp_path / reads, force=True, what='model file')
    assert (bag / 'bag.mcap').read_bytes() == b'data'


def test_an_existing_output_is_replaced_only_with_force(tmp_path: Path) -> None:
    bag = _bag(tmp_path)
    model = tmp_path / 'model.yaml'
    assert check_output(model, reads=bag, force=False, what='model file') == model
    model.write_text('old')
    with pytest.raises(ConfigurationError, match='exists already; give --force'):
        check_output(model, reads=bag, force=False, what='model file')
    assert check_output(model, reads=bag, force=True, what='model file') == model
    with pytest.raises(ConfigurationError, match='is a directory'):
        check_output(tmp_path, reads=bag, force=True, what='model file')
    with pytest.raises(ConfigurationError, match='does not exist'):
        check_output(tmp_path / 'no' / 'm.yaml', reads=bag, force=True, what='model file')


def test_a_report_directory_is_new_empty_or_forced(tmp_path: Path) -> None:
    bag = _bag(tmp_path)
    report = tmp_path / 'report'
    assert check_output(report, reads=bag, force=False, what='report', directory=True) == report
    report.mkdir()
    assert check_output(report, reads=bag, force=False, what='report', directory=True) == report
    (report / 'summary.txt').write_text('old')
    with pytest.raises(ConfigurationError, match='holds files already; give --force'):
        check_output(report, reads=bag, force=False, what='report', directory=True)
    assert check_output(report, reads=bag, force=True, what='report', directory=True) == report
    with pytest.raises(ConfigurationError, match='not a directory'):
        check_output(report / 'summary.txt', reads=bag, force=True, what='report',
                     directory=True)
    deep = tmp_path / 'new' / 'deeper' / 'report'  # made with its parents
    assert check_output(deep, reads=bag, force=False, what='report', directory=True) == deep
    with pytest.raises(ConfigurationError, match='is a file, not a directory'):
        check_output(report / 'summary.txt' / 'sub', reads=bag, force=False, what='report',
                     directory=True)
