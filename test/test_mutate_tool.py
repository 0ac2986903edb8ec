"""tools/mutate.py: the mutants it makes, and the module restored whatever happens."""

from __future__ import annotations

import importlib.util
import os
import sys
from pathlib import Path
from types import ModuleType

import pytest

SOURCE = '''"""Docstring with 3 numbers 1.5 and x < y."""
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    import os

LIMIT = 3
SCALE = 0.5
ZERO = 0.0


def f(x: float, y: float) -> str:
    """Say 2 < 3."""
    if x < y and y != LIMIT:
        return f'{x:.3g} < {y + 1}'   # µs: a non-ASCII comment shifts byte columns
    while x >= 1:
        x = x / 2
    return 'a' if x in (1, 2) or y is None else 'b'


if __name__ == '__main__':
    f(1.0, 2.0)
'''


def _tool() -> ModuleType:
    path = Path(__file__).resolve().parents[1] / 'tools' / 'mutate.py'
    spec = importlib.util.spec_from_file_location('mutate_tool', path)
    assert spec is not None
    assert spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules['mutate_tool'] = module
    spec.loader.exec_module(module)
    return module


mutate = _tool()


def test_every_kind_of_mutant_is_made_and_compiles() -> None:
    mutants = mutate.find_mutants(SOURCE)
    changes = {(m.line, m.change) for m in mutants}
    assert (14, '< -> <=') in changes
    assert (14, '!= -> ==') in changes
    assert (14, 'and -> or') in changes
    assert (7, '3 -> 4') in changes
    assert (7, '3 -> 2') in changes
    assert (8, '0.5 -> 0.6') in changes
    assert (16, '>= -> >') in changes
    assert (18, 'or -> and') in changes
    assert (18, 'in -> not in') in changes
    assert (18, 'is -> is not') in changes
    assert {m.kind for m in mutants} == {'compare', 'int', 'float', 'boolop', 'negate'}
    for m in mutants:
        mutated = m.apply(SOURCE)
        compile(mutated, '<mutant>', 'exec')
        assert mutated != SOURCE
    assert [m.index for m in mutants] == list(range(len(mutants)))


def test_docstrings_fstrings_zero_and_guards_are_left_alone() -> None:
    mutants = mutate.find_mutants(SOURCE)
    lines = {m.line for m in mutants}
    assert not lines & {1, 4, 5, 9, 13, 21, 22}   # docstrings, TYPE_CHECKING, 0.0, __main__
    assert all(m.line != 15 for m in mutants)   # inside the f-string
    negated = [m.apply(SOURCE) for m in mutants if m.kind == 'negate']
    assert any('if not (x < y and y != LIMIT):' in s for s in negated)
    assert any("return 'a' if not (x in (1, 2) or y is None) else 'b'" in s for s in negated)


def test_columns_after_non_ascii_text_are_right() -> None:
    src = 's = "µµ"; t = 1 < 2\n'
    (compare,) = (m for m in mutate.find_mutants(src) if m.kind == 'compare')
    assert compare.apply(src) == 's = "µµ"; t = 1 <= 2\n'


def test_the_module_is_restored_after_each_mutant_and_on_interruption(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    module = tmp_path / 'm.py'
    module.write_text(SOURCE, encoding='utf-8')
    os.utime(module, (1_000_000, 1_000_000))
    before = module.read_bytes(), module.stat().st_mtime_ns
    seen: list[tuple[str, float]] = []
    verdicts = iter(['passed', 'failed', 'timeout'])

    def fake_tests(tests: list[str], **kwargs: object) -> tuple[str, float]:
        seen.append((module.read_text(encoding='utf-8'), module.stat().st_mtime))
        assert module.with_name('m.py.mutate-orig').read_bytes() == before[0]
        return next(verdicts), 0.1

    monkeypatch.setattr(mutate, '_run_tests', fake_tests)
    mutants = mutate.find_mutants(SOURCE)[:3]
    outcomes = mutate.run(module, mutants, ['t.py'], keyword=None, timeout=1.0,
                          python=sys.executable)
    assert [o.result for o in outcomes] == ['survived', 'killed', 'timeout']
    assert [text for text, _ in seen] == [m.apply(SOURCE) for m in mutants]
    assert len({mtime for _, mtime in seen}) == 3   # no stale bytecode can match
    assert (module.read_bytes(), module.stat().st_mtime_ns) == before
    assert not module.with_name('m.py.mutate-orig').exists()

    def interrupted(tests: list[str], **kwargs: object) -> tuple[str, float]:
        raise KeyboardInterrupt

    monkeypatch.setattr(mutate, '_run_tests', interrupted)
    with pytest.raises(KeyboardInterrupt):
        mutate.run(module, mutants, ['t.py'], keyword=None, timeout=1.0, python=sys.executable)
    assert (module.read_bytes(), module.stat().st_mtime_ns) == before
    assert not module.with_name('m.py.mutate-orig').exists()


def test_a_backup_left_by_an_interrupted_run_stops_a_new_one(tmp_path: Path) -> None:
    module = tmp_path / 'm.py'
    module.write_text(SOURCE, encoding='utf-8')
    module.with_name('m.py.mutate-orig').write_text('x', encoding='utf-8')
    with pytest.raises(SystemExit, match='interrupted run'):
        mutate.run(module, mutate.find_mutants(SOURCE)[:1], ['t.py'], keyword=None,
                   timeout=1.0, python=sys.executable)
    assert module.read_text(encoding='utf-8') == SOURCE


def test_table_gives_the_share_killed() -> None:
    mutants = mutate.find_mutants(SOURCE)[:4]
    outcomes = [mutate.Outcome(m, r, 1.0)
                for m, r in zip(mutants, ['killed', 'survived', 'timeout', 'killed'],
                                strict=True)]
    text = mutate.table('m.py', ['t.py'], None, outcomes, len(mutants), seed=3)
    assert 'killed 3 of 4 (75 %)' in text
    assert f'survived: #{mutants[1].index}' in text
    assert '4 of 4 mutants (seed 3)' in text


def test_a_mutant_that_breaks_the_tests_import_counts_as_killed(tmp_path: Path) -> None:
    (tmp_path / 'broken_at_import.py').write_text('import numpy as np\nEMPTY = np.zeros((0, -1))\n',
                                                  encoding='utf-8')
    test = tmp_path / 'test_broken_at_import.py'
    test.write_text('from broken_at_import import EMPTY\n\n\ndef test_it():\n'
                    '    assert EMPTY.size == 0\n', encoding='utf-8')
    verdict, _ = mutate._run_tests([str(test)], keyword=None, timeout=60.0,
                                   python=sys.executable)
    assert verdict == 'failed'
