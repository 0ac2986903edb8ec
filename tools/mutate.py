r"""A small mutation runner: do the tests notice when the code changes? (issue 16).

For one module and a few test files it makes simple mutants of the module, one at a time,
runs the tests on each and prints which mutants the tests killed (failed) and which survived:

- comparisons flipped: ``<`` <-> ``<=``, ``>`` <-> ``>=``, ``==`` <-> ``!=``, ``is`` <->
  ``is not``, ``in`` <-> ``not in``;
- whole numbers +1 and -1;
- non-zero floats scaled by 1.2;
- ``and`` <-> ``or``;
- the condition of an ``if``, ``while`` or conditional expression negated.

Mutations are made with :mod:`ast` and written into the source text at the node's position
(the rest of the file untouched); every mutant is compiled first, and the original bytes and
modification time are restored after each run (also on Ctrl-C; a backup beside the module
stays until the run ends, and a run refuses to start while one exists). Left alone: f-strings,
docstrings, the ``if TYPE_CHECKING`` and ``if __name__ == '__main__'`` blocks. A mutant's
tests run in a child process with a timeout (a timeout counts as killed, as does a mutant
that makes the tests' imports fail); the unmutated module must pass them first. Only the
standard library is used (no mutmut, no cosmic-ray).

Usage (from the repository root, with the project's Python)::

    python tools/mutate.py galvo_sysid/monitor/drift.py test/monitor/test_drift.py \
        --max 40 --seed 16
    python tools/mutate.py galvo_sysid/ident/delay.py test/ident/test_delay.py -k estimate
    python tools/mutate.py galvo_sysid/monitor/pairing.py --list
    python tools/mutate.py MODULE TESTS --only 3 17        # rerun mutants 3 and 17

Mutant numbers are stable for a given module text (they number every site in source order);
``--max`` picks that many of them at random with ``--seed``. Exit status: 0 when every mutant
run was killed, 1 when some survived, 2 on a usage error or a failing baseline.
"""

from __future__ import annotations

import argparse
import ast
import os
import random
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]

_FLIP: dict[type[ast.cmpop], type[ast.cmpop]] = {
    ast.Lt: ast.LtE, ast.LtE: ast.Lt, ast.Gt: ast.GtE, ast.GtE: ast.Gt,
    ast.Eq: ast.NotEq, ast.NotEq: ast.Eq, ast.Is: ast.IsNot, ast.IsNot: ast.Is,
    ast.In: ast.NotIn, ast.NotIn: ast.In,
}
_SYMBOL: dict[type[ast.cmpop], str] = {
    ast.Lt: '<', ast.LtE: '<=', ast.Gt: '>', ast.GtE: '>=', ast.Eq: '==', ast.NotEq: '!=',
    ast.Is: 'is', ast.IsNot: 'is not', ast.In: 'in', ast.NotIn: 'not in',
}
FLOAT_FACTOR = 1.2


@dataclass(frozen=True)
class Mutant:
    """One mutation of a module's source.

    Attributes:
        index: Number of the mutant among all sites of the module (source order).
        line: First line of the mutated expression.
        kind: ``compare``, ``int``, ``float``, ``boolop`` or ``negate``.
        change: What changes, for the table (``'< -> <='``).
        start: Offset of the replaced text in the source (characters).
        end: Offset just past it.
        replacement: The new text.
        context: The mutated line as it was (stripped), for the table.
    """

    index: int
    line: int
    kind: str
    change: str
    start: int
    end: int
    replacement: str
    context: str = ''

    def apply(self, source: str) -> str:
        """The source with this mutation."""
        return source[: self.start] + self.replacement + source[self.end:]


def _offsets(source: str) -> list[int]:
    """Character offset of the start of every line (1-based line numbers: index - 1)."""
    starts = [0]
    for line in source.splitlines(keepends=True):
        starts.append(starts[-1] + len(line))
    return starts


def _span(node: ast.expr, source_lines: list[str], starts: list[int]) -> tuple[int, int]:
    """Character offsets of an expression (ast gives UTF-8 byte columns)."""
    def char_col(lineno: int, byte_col: int) -> int:
        return len(source_lines[lineno - 1].encode()[:byte_col].decode())

    end_lineno, end_col = node.end_lineno, node.end_col_offset
    assert end_lineno is not None
    assert end_col is not None
    return (starts[node.lineno - 1] + char_col(node.lineno, node.col_offset),
            starts[end_lineno - 1] + char_col(end_lineno, end_col))


def _short(text: str, width: int = 40) -> str:
    text = ' '.join(text.split())
    return text if len(text) <= width else text[: width - 3] + '...'


def _skipped_test(test: ast.expr) -> bool:
    """Blocks left alone: ``if TYPE_CHECKING`` and the ``__main__`` guard."""
    text = ast.unparse(test)
    return 'TYPE_CHECKING' in text or '__name__' in text


def _docstring_nodes(tree: ast.AST) -> set[int]:
    out: set[int] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Module | ast.ClassDef | ast.FunctionDef | ast.AsyncFunctionDef):
            body = node.body
            if body and isinstance(body[0], ast.Expr) and isinstance(body[0].value,
                                                                      ast.Constant):
                out.add(id(body[0].value))
    return out


def find_mutants(source: str) -> list[Mutant]:
    """Every mutant of ``source`` that compiles, in source order.

    Args:
        source: A module's text.

    Returns:
        The mutants, numbered from 0.
    """
    tree = ast.parse(source)
    lines = source.splitlines(keepends=True)
    starts = _offsets(source)
    left_alone: set[int] = set()   # f-strings, the TYPE_CHECKING and __main__ blocks
    for node in ast.walk(tree):
        if isinstance(node, ast.JoinedStr) or (isinstance(node, ast.If)
                                               and _skipped_test(node.test)):
            left_alone.update(id(n) for n in ast.walk(node))
    docstrings = _docstring_nodes(tree)
    found: list[tuple[int, int, str, str, int, int, str]] = []

    def add(node: ast.expr, kind: str, change: str, replacement: str) -> None:
        start, end = _span(node, lines, starts)
        found.append((start, end, kind, change, node.lineno, len(found), replacement))

    for node in ast.walk(tree):
        if id(node) in left_alone or id(node) in docstrings:
            continue
        if isinstance(node, ast.Compare):
            for i, op in enumerate(node.ops):
                new_op = _FLIP.get(type(op))
                if new_op is None:
                    continue
                ops = list(node.ops)
                ops[i] = new_op()
                mutated = ast.Compare(left=node.left, ops=ops, comparators=node.comparators)
                which = f' (operator {i + 1} of {len(ops)})' if len(ops) > 1 else ''
                add(node, 'compare', f'{_SYMBOL[type(op)]} -> {_SYMBOL[new_op]}{which}',
                    ast.unparse(mutated))
        elif isinstance(node, ast.Constant) and type(node.value) is int:
            for step in (1, -1):
                add(node, 'int', f'{node.value} -> {node.value + step}', repr(node.value + step))
        elif isinstance(node, ast.Constant) and type(node.value) is float and node.value != 0:
            new = node.value * FLOAT_FACTOR
            add(node, 'float', f'{node.value!r} -> {new!r}', repr(new))
        elif isinstance(node, ast.BoolOp):
            swapped = ast.Or() if isinstance(node.op, ast.And) else ast.And()
            names = ('and', 'or') if isinstance(node.op, ast.And) else ('or', 'and')
            add(node, 'boolop', f'{names[0]} -> {names[1]}',
                f'({ast.unparse(ast.BoolOp(op=swapped, values=node.values))})')
        if isinstance(node, ast.If | ast.While | ast.IfExp):
            start, end = _span(node.test, lines, starts)
            add(node.test, 'negate', f'not ({_short(source[start:end], 30)})',
                f'not ({source[start:end]})')
    found.sort(key=lambda f: (f[0], f[5]))
    mutants: list[Mutant] = []
    for start, end, kind, change, line, _, replacement in found:
        mutant = Mutant(index=len(mutants), line=line, kind=kind, change=change, start=start,
                        end=end, replacement=replacement, context=lines[line - 1].strip())
        try:
            compile(mutant.apply(source), '<mutant>', 'exec')
        except SyntaxError:
            continue
        mutants.append(mutant)
    return mutants


@dataclass(frozen=True)
class Outcome:
    """The tests' verdict on one mutant: ``killed``, ``survived`` or ``timeout``."""

    mutant: Mutant
    result: str
    seconds: float


_COLLECTION_ERROR = 'during collection'
"""What pytest says when a test module cannot be imported: with the unmutated module the
tests were collected, so a mutant that makes the import fail (a mutated constant raising at
import time) is one the tests notice."""


def _run_tests(tests: list[str], *, keyword: str | None, timeout: float,
               python: str) -> tuple[str, float]:
    """Run pytest on ``tests`` in a child: ``passed``, ``failed`` or ``timeout``."""
    env = dict(os.environ)
    env['PYTHONPATH'] = os.pathsep.join([str(REPO), *filter(None, [env.get('PYTHONPATH')])])
    env['PYTHONDONTWRITEBYTECODE'] = '1'
    cmd = [python, '-m', 'pytest', '-q', '-x', '-p', 'no:cacheprovider', '--no-header',
           '-o', 'addopts=', *tests]
    if keyword:
        cmd += ['-k', keyword]
    t0 = time.monotonic()
    try:
        proc = subprocess.run(cmd, cwd=REPO, env=env, capture_output=True, text=True,
                              timeout=timeout, check=False)
    except subprocess.TimeoutExpired:
        return 'timeout', time.monotonic() - t0
    seconds = time.monotonic() - t0
    if proc.returncode == 5:
        raise SystemExit(f'mutate: no tests collected by {" ".join(cmd)}')
    if proc.returncode == 2 and _COLLECTION_ERROR in proc.stdout + proc.stderr:
        return 'failed', seconds  # the mutant breaks the import the tests need: noticed
    if proc.returncode not in (0, 1):
        tail = (proc.stdout + proc.stderr).strip().splitlines()[-3:]
        raise SystemExit(f'mutate: pytest exited with {proc.returncode}: {" | ".join(tail)}')
    return ('passed' if proc.returncode == 0 else 'failed'), seconds


def run(module: Path, mutants: list[Mutant], tests: list[str], *, keyword: str | None,
        timeout: float, python: str) -> list[Outcome]:
    """Run the tests on every mutant, restoring the module after each.

    Raises:
        SystemExit: A backup of an interrupted run exists, or pytest cannot run the tests.
    """
    backup = module.with_name(module.name + '.mutate-orig')
    if backup.exists():
        raise SystemExit(f'mutate: {backup} exists (an interrupted run?): restore the module '
                         f'from it, delete it, and run again')
    original = module.read_bytes()
    stat = module.stat()
    source = original.decode()
    backup.write_bytes(original)
    outcomes = []
    try:
        for i, mutant in enumerate(mutants):
            module.write_text(mutant.apply(source), encoding='utf-8')
            # a unique modification time: no stale bytecode of another mutant can match
            fake = stat.st_mtime + 1000 + i
            os.utime(module, (fake, fake))
            verdict, seconds = _run_tests(tests, keyword=keyword, timeout=timeout,
                                          python=python)
            result = {'passed': 'survived', 'failed': 'killed', 'timeout': 'timeout'}[verdict]
            outcomes.append(Outcome(mutant, result, seconds))
            print(f'  [{i + 1}/{len(mutants)}] #{mutant.index} line {mutant.line} '
                  f'{mutant.change}: {result} ({seconds:.1f} s)', file=sys.stderr, flush=True)
    finally:
        module.write_bytes(original)
        os.utime(module, ns=(stat.st_atime_ns, stat.st_mtime_ns))
        backup.unlink()
    return outcomes


def table(module: str, tests: list[str], keyword: str | None, outcomes: list[Outcome],
          total: int, *, seed: int | None) -> str:
    """The results as a Markdown table with the share killed."""
    picked = f'{len(outcomes)} of {total} mutants'
    if seed is not None:
        picked += f' (seed {seed})'
    lines = [f'module `{module}`; tests `{" ".join(tests)}`'
             + (f' -k `{keyword}`' if keyword else '') + f'; {picked}', '',
             '| # | line | code | change | result | s |', '| --- | --- | --- | --- | --- | --- |']
    for o in outcomes:
        m = o.mutant
        code = _short(m.context, 48).replace('|', '\\|').replace('`', "'")
        change = m.change.replace('|', '\\|').replace('`', "'")
        lines.append(f'| {m.index} | {m.line} | `{code}` | {change} | {o.result} | '
                     f'{o.seconds:.1f} |')
    killed = sum(o.result != 'survived' for o in outcomes)
    share = 100.0 * killed / len(outcomes) if outcomes else float('nan')
    lines += ['', f'killed {killed} of {len(outcomes)} ({share:.0f} %); survived: '
              + (', '.join(f'#{o.mutant.index}' for o in outcomes if o.result == 'survived')
                 or 'none')]
    return '\n'.join(lines)


def main(argv: list[str] | None = None) -> int:
    """Entry point (see the module docs)."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('module', type=Path, help='the module to mutate (a .py file)')
    parser.add_argument('tests', nargs='*', help='test files (or node ids) to run on each')
    parser.add_argument('-k', dest='keyword', help="pytest's -k expression")
    parser.add_argument('--max', type=int, default=None, help='mutants to run at most')
    parser.add_argument('--seed', type=int, default=0, help='seed of the --max pick')
    parser.add_argument('--only', type=int, nargs='+', help='run these mutant numbers')
    parser.add_argument('--timeout', type=float, default=None,
                        help='seconds per test run (default: 3 x the baseline + 10)')
    parser.add_argument('--list', action='store_true', help='list the mutants, run nothing')
    parser.add_argument('--python', default=sys.executable, help='Python that runs pytest')
    args = parser.parse_args(argv)
    module = args.module.resolve()
    if module.suffix != '.py' or not module.is_file():
        parser.error(f'{args.module} is not a Python file')
    try:
        shown = str(module.relative_to(REPO))
    except ValueError:
        shown = str(module)
    mutants = find_mutants(module.read_text(encoding='utf-8'))
    total = len(mutants)
    if args.only:
        chosen = [m for m in mutants if m.index in set(args.only)]
    elif args.max is not None and args.max < total:
        chosen = sorted(random.Random(args.seed).sample(mutants, args.max),
                        key=lambda m: m.index)
    else:
        chosen = mutants
    if args.list:
        for m in chosen:
            print(f'#{m.index} line {m.line} {m.kind}: {m.change}    [{_short(m.context, 60)}]')
        return 0
    if not args.tests:
        parser.error('give the test files to run')
    print(f'baseline: {shown} unmutated ...', file=sys.stderr, flush=True)
    verdict, seconds = _run_tests(args.tests, keyword=args.keyword, timeout=600.0,
                                  python=args.python)
    if verdict != 'passed':
        print(f'mutate: the tests do not pass on the unmutated module ({verdict})',
              file=sys.stderr)
        return 2
    timeout = args.timeout if args.timeout is not None else 3 * seconds + 10
    print(f'baseline passed in {seconds:.1f} s; {len(chosen)} mutants, timeout {timeout:.0f} s',
          file=sys.stderr, flush=True)
    outcomes = run(module, chosen, args.tests, keyword=args.keyword, timeout=timeout,
                   python=args.python)
    print(table(shown, args.tests, args.keyword, outcomes, total,
                seed=args.seed if args.max is not None and not args.only else None))
    return 0 if all(o.result != 'survived' for o in outcomes) else 1


if __name__ == '__main__':
    raise SystemExit(main())
