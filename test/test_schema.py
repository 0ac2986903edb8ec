"""galvo_sysid.schema: the one reader of the YAML files the tools are given (issue 12)."""

from __future__ import annotations

import os
import socket
import threading
from pathlib import Path

import pytest

from galvo_sysid.errors import ConfigurationError, InvalidDataError
from galvo_sysid.schema import MAX_FILE_BYTES, Section, check_number, load_yaml, parse_yaml

BOMB = '\n'.join(['a0: &a0 ["lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol"]'] + [
    f'a{i}: &a{i} [{", ".join([f"*a{i - 1}"] * 9)}]' for i in range(1, 8)])


def one_line(err: pytest.ExceptionInfo[BaseException]) -> str:
    text = str(err.value)
    assert '\n' not in text
    return text


def test_a_fifo_is_refused_without_blocking(tmp_path: Path) -> None:
    """Defect 16's root: opening a FIFO for reading blocks until a writer comes."""
    fifo = tmp_path / 'model.yaml'
    os.mkfifo(fifo)
    done = threading.Event()
    errors: list[BaseException] = []

    def read() -> None:
        try:
            load_yaml(fifo)
        except BaseException as err:  # kept for the assertions below
            errors.append(err)
        done.set()

    threading.Thread(target=read, daemon=True).start()
    if not done.wait(20):  # blocked in open(): unblock it by opening the other end
        with open(fifo, 'w'):
            pass
        done.wait(20)
        pytest.fail('load_yaml blocked on a FIFO')
    assert len(errors) == 1
    assert isinstance(errors[0], InvalidDataError)
    assert 'a FIFO, not a regular file' in str(errors[0])


def test_other_non_regular_files_are_named(tmp_path: Path) -> None:
    from galvo_sysid.schema import check_regular_file

    with pytest.raises(InvalidDataError, match='a directory, not a regular file'):
        load_yaml(tmp_path)
    with pytest.raises(InvalidDataError, match='a character device, not a regular file'):
        load_yaml('/dev/zero')
    sock = socket.socket(socket.AF_UNIX)
    try:
        sock.bind(str(tmp_path / 's.yaml'))
        with pytest.raises(InvalidDataError, match='a socket, not a regular file'):
            check_regular_file(tmp_path / 's.yaml', what='bag')
    finally:
        sock.close()
    with pytest.raises(InvalidDataError, match='no such file'):
        check_regular_file(tmp_path / 'none.mcap')
    link = tmp_path / 'link.yaml'
    (tmp_path / 'real.yaml').write_text('a: 1\n')
    link.symlink_to(tmp_path / 'real.yaml')
    assert load_yaml(link) == {'a': 1}  # a link to a regular file is one


def test_size_is_bounded_by_what_is_read_not_what_is_claimed(tmp_path: Path) -> None:
    big = tmp_path / 'big.yaml'
    big.write_text('a: ' + 'x' * MAX_FILE_BYTES + '\n')
    with pytest.raises(ConfigurationError, match='larger than'):
        load_yaml(big)
    claims_nothing = Path('/proc/sys/kernel/ostype')  # size 0 on stat: read, not trusted
    if claims_nothing.exists():
        assert load_yaml(claims_nothing) == 'Linux'


def test_alias_bomb_is_refused_before_it_expands() -> None:
    with pytest.raises(ConfigurationError, match='aliases are not allowed') as err:
        parse_yaml(BOMB, source='bomb.yaml')
    assert one_line(err).startswith('bomb.yaml: ')


@pytest.mark.parametrize(('text', 'value'), [
    ('a: 3.564e6', 3.564e6),     # a float, as ROS reads it (YAML 1.1: text)
    ('a: 1:20', '1:20'),         # no base-60 number
    ('a: 2024-01-01', '2024-01-01'),  # no date
    ('a: 12', 12),
    ('a: .inf', float('inf')),
])
def test_scalars_as_ros_reads_them(text: str, value: object) -> None:
    assert parse_yaml(text, source='x') == {'a': value}


@pytest.mark.parametrize('text', [
    'a: ' + '1' * 5000,                      # int() refuses it: was a ValueError traceback
    'a: !!python/object:os.system x',        # no custom tags
    '? [1, 2]\n: 3',                         # unhashable key
    'a: [' * 5000,                           # nested too deeply / unterminated
    '\x00',
])
def test_bad_yaml_is_one_configuration_error(text: str) -> None:
    with pytest.raises(ConfigurationError) as err:
        parse_yaml(text, source='f.yaml')
    assert one_line(err).startswith('f.yaml: ')


def test_section_refuses_unknown_keys_wrong_types_and_ranges() -> None:
    s = Section({'n': 10.7, 'x': 'abc', 'b': 1e400, 'big': 10**300, 'ok': 5}, 'f.yaml: top',
                keys=('n', 'x', 'b', 'big', 'ok'))
    with pytest.raises(ConfigurationError, match=r'whole number, got 10\.7'):
        s.integer('n')
    with pytest.raises(ConfigurationError, match="must be a number, got 'abc'"):
        s.number('x')
    with pytest.raises(ConfigurationError, match='finite'):
        s.number('b')
    with pytest.raises(ConfigurationError, match='<= 1e\\+06') as err:
        s.number('big', high=1e6)
    assert len(one_line(err)) < 200  # the value is cut, not printed in full
    assert s.integer('ok', low=0, high=9) == 5
    with pytest.raises(ConfigurationError, match=r"unknown key\(s\) \['typo'\]"):
        Section({'typo': 1}, 'f.yaml', keys=('type',))
    with pytest.raises(ConfigurationError, match='must be a number'):
        check_number('123', 'residue')
    with pytest.raises(ConfigurationError, match='<= 1'):
        check_number(10**400, 'x', high=1.0)  # beyond any float: said, no OverflowError
